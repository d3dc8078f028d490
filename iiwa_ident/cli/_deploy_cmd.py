"""``iiwa-ident deploy``: check a design and export the controller config for the FRI runtime."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from iiwa_ident.cli._app import app, check_joint, fail, json_option, write_json
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    from iiwa_ident.design import DesignRecord
    from iiwa_ident.model import JointModel

__all__ = ["deploy_cmd", "find_model"]


def find_model(record: DesignRecord, design_path: Path) -> tuple[JointModel | None, Path | None]:
    """The model file the design records, if it can be found, checked against its recorded sha256.

    The recorded path is tried as given, then relative to the design file.

    Raises
    ------
    DeployError
        If the file is found but differs from the one the design was made from.
    """
    from iiwa_ident.datasets import sha256_file
    from iiwa_ident.deploy import DeployError
    from iiwa_ident.ident import read_model

    if not record.model_file:
        return None, None
    recorded = Path(record.model_file)
    for path in (recorded, design_path.parent / recorded):
        if path.is_file():
            if record.model_sha256 and sha256_file(path) != record.model_sha256:
                raise DeployError(f"{path}: model file changed since the design was made (sha256 differs from "
                                  f"the design's model.sha256); redesign or restore it")
            return read_model(path), path
    return None, None


def _positive(value: float | None, option: str) -> None:
    from iiwa_ident.deploy import DeployError

    if value is not None and not (math.isfinite(value) and value > 0):
        raise DeployError(f"{option} must be a positive number, got {value:g}")


@app.command("deploy")
def deploy_cmd(
    design: Annotated[Path, typer.Option("--design", help="Design TOML file (from 'iiwa-ident design').")],
    out: Annotated[Path, typer.Option("--out", help="Controller config TOML file to write.")],
    json_out: Annotated[Optional[Path], json_option("a summary")] = None,
    torque_limit: Annotated[Optional[float], typer.Option("--torque-limit", help="Torque clamp [Nm] "
                                                          "(default: data sheet; may only be tighter).")] = None,
    rate_limit: Annotated[Optional[float], typer.Option("--rate-limit", help="Torque-rate clamp [Nm/s] "
                                                        "(default: data-sheet torque per 10 ms).")] = None,
    velocity_limit: Annotated[Optional[float], typer.Option("--velocity-limit", help="Stop above this joint "
                                                            "speed, rad/s (default: data sheet).")] = None,
    reference_rate: Annotated[Optional[float], typer.Option("--reference-rate", help="Reference-rate clamp "
                                                            "[Nm/s] (default: data-sheet torque per 40 ms).")] = None,
    robot_model: Annotated[Optional[str], typer.Option("--robot-model", help="iiwa7 | iiwa14, if the design's "
                                                       "model file does not say.")] = None,
    joint: Annotated[Optional[int], typer.Option("--joint", help="Joint 1-7, if the design's model file "
                                                 "does not say.")] = None,
) -> None:
    """Check a design and export the controller config an FRI runtime executes at 1 kHz.

    Refused (exit 2, nothing written) if the closed loop is unstable or has a
    spectral radius above 0.999 (also with the exact delay), the outer-loop
    kappa margin is below max(1, built-in kappa_max), a number is NaN/inf,
    a limit exceeds the data sheet, or less than half the torque limit is
    usable as reference (a rate-limited reference reversal within the range
    must keep the command within the torque limit).

    Examples:
      iiwa-ident deploy --design design.toml --out controller.toml
      iiwa-ident deploy --design design.toml --out controller.toml --torque-limit 100 --json deploy.json
    """
    from iiwa_ident.datasets import sha256_file
    from iiwa_ident.deploy import config_json, deploy, deploy_target, write_config
    from iiwa_ident.design import read_design

    try:
        check_joint(joint)
        for value, option in ((torque_limit, "--torque-limit"), (rate_limit, "--rate-limit"),
                              (velocity_limit, "--velocity-limit"), (reference_rate, "--reference-rate")):
            _positive(value, option)
        record = read_design(design)
        model, _ = find_model(record, design)
        robot_model, joint = deploy_target(model, robot_model, joint)
        config = deploy(record, robot_model, joint, torque_limit=torque_limit, rate_limit=rate_limit,
                        velocity_limit=velocity_limit, reference_rate_limit=reference_rate, design_file=str(design), design_sha256=sha256_file(design),
                        model=model)
        write_config(out, config)
        for c in config.checks:
            typer.echo(f"pass  {c.describe()}")
        lim = config.limits
        typer.echo(f"limits: torque {lim.torque_nm:g} Nm, rate {lim.torque_rate_nm_s:g} Nm/s, "
                   f"velocity {lim.velocity_rad_s:.4g} rad/s, reference {lim.reference_nm:.4g} Nm "
                   f"at up to {lim.reference_rate_nm_s:g} Nm/s")
        typer.echo(f"robot: {config.robot.control_mode}, {config.robot.client_command_mode}, send period "
                   f"{config.robot.send_period_ms} ms, receive multiplier {config.robot.receive_multiplier}, "
                   f"watchdog {config.robot.watchdog_timeout_s * 1e3:g} ms")
        typer.echo(f"wrote {out} (sha256 {config.sha256})")
        if json_out is not None:
            write_json(json_out, config_json(config, out))
    except IiwaIdentError as err:
        raise fail(str(err)) from None
