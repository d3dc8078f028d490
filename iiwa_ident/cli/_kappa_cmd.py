"""Subcommand ``kappa``: the outer loop's gain margin measured live, both controllers, beside the prediction."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from iiwa_ident._defaults import DEFAULT_PORT, TAU_EXT_SOURCES
from iiwa_ident.cli._app import app, fail, json_option, plant_option, write_json
from iiwa_ident.cli._run_cmd import FtCpfOpt, FtCptOpt, FtHostOpt, FtLeverOpt
from iiwa_ident.errors import IiwaIdentError

__all__ = ["kappa_cmd", "format_sweep"]



def _f(x: Any) -> str:
    return "-" if x is None else f"{x:.2f}"


def format_sweep(out: dict[str, Any]) -> str:
    """The sweep's table: per controller the live margin, the first unstable kappa and the prediction."""
    lines = [f"kappa sweep, tau_ext from {out['tau_ext']} ({out['target']}, {out['clock']}):",
             f"  {'loop':9} {'stable up to':>12} {'unstable at':>12} {'linear':>8} {'error':>7}  judgement"]
    for loop in ("builtin", "additive"):
        r = out[loop]
        err = "-" if r.get("linear_error_pct") is None else f"{r['linear_error_pct']:+.0f} %"
        lines.append(f"  {loop:9} {_f(r['live_limit']):>12} {_f(r['unstable_at']):>12} {_f(r['linear_limit']):>8} "
                     f"{err:>7}  {r['reason'] or r['stop_reason']}")
    lines.append(f"  ratio additive / built-in: live {_f(out['ratio_live'])}, linear {_f(out['ratio_linear'])}")
    for loop in ("builtin", "additive"):
        k = out[loop].get("rate_limited_from")
        if k is not None and (out[loop]["unstable_at"] is None or k < out[loop]["unstable_at"]):
            lines.append(f"  {loop}: the command sat at its rate limit from kappa {k:.2f} on; the linear "
                         "prediction has no rate limits and does not describe the loop there")
    lines.append("  (error: how far the linear prediction lies outside the live bracket, from the last stable to "
                 "the first unstable kappa; 0 inside)")
    return "\n".join(lines)


@app.command("kappa")
def kappa_cmd(
    config: Annotated[Path, typer.Option("--config", help="Controller config TOML (from 'iiwa-ident deploy').")],
    robot: Annotated[Optional[str], typer.Option("--robot", help="Robot controller HOST[:PORT] (FRI).")] = None,
    port: Annotated[int, typer.Option("--port", help="Local FRI UDP port.")] = DEFAULT_PORT,
    target: Annotated[str, typer.Option("--target", help="'robot' (FRI, a person holding the arm) or 'sim' "
                                        "(the emulator in lockstep with a hand holding the arm).")] = "robot",
    tau_ext: Annotated[str, typer.Option("--tau-ext", help="The external torque kappa multiplies: "
                                         f"{' | '.join(TAU_EXT_SOURCES)}.")] = "ft",
    design: Annotated[Optional[Path], typer.Option("--design", help="Design file of the linear prediction "
                                                   "(default: the one the config names).")] = None,
    plant: Annotated[Optional[Path], plant_option("--target sim: ")] = None,
    start: Annotated[float, typer.Option("--start", help="First kappa.")] = 1.0,
    factor: Annotated[float, typer.Option("--factor", help="Ratio of successive kappas.")] = 1.1,
    kmax: Annotated[float, typer.Option("--max", help="Largest kappa.")] = 40.0,
    hold: Annotated[float, typer.Option("--hold-s", help="Time each kappa is held [s].")] = 2.0,
    limit: Annotated[float, typer.Option("--limit-nm", help="RMS of the band-passed joint torque that counts "
                                         "as a limit cycle [Nm].")] = 5.0,
    holding: Annotated[bool, typer.Option("--i-am-holding-the-arm", help="--target robot: a person holds the "
                                          "arm (the sweep drives the loop until it oscillates).")] = False,
    ft: FtHostOpt = None,
    ft_lever: FtLeverOpt = None,
    ft_cpf: FtCpfOpt = 1e6,
    ft_cpt: FtCptOpt = 1e6,
    ft_rate: Annotated[float, typer.Option("--ft-rate", help="The sensor's output rate [Hz] (emulated on "
                                           "--target sim; the prediction's on the robot).")] = 1000.0,
    ft_cutoff: Annotated[float, typer.Option("--ft-cutoff", help="The sensor's low-pass cut-off [Hz], 0: "
                                             "none (as --ft-rate).")] = 152.0,
    log_dir: Annotated[Optional[Path], typer.Option("--log", help="Folder of the run logs (default: "
                                                    "kappa_logs beside --json, or ./kappa_logs).")] = None,
    json_out: Annotated[Optional[Path], json_option("the sweep's figures")] = None,
) -> None:
    """Measure the gain margin of tau_r = kappa tau_ext live through FRI,
    built-in loop then additive controller, beside its linear prediction.

    kappa is raised stepwise (--start, --factor, --max, each held --hold-s);
    the run itself judges the onset of instability (a growing oscillation of
    the band-passed joint torque over successive windows, or a limit cycle
    above --limit-nm), then kappa is ramped to zero and the run ends. The
    live margin is the largest kappa held stable. The prediction models the
    source's dynamics (the F/T sensor's filter, or the observer of eq (13)),
    FRI's delay, the spatial filter at the speeds the run passed through and
    the arm's impedance.

    On the robot the loop amplifies what a person applies at the end
    effector, until it oscillates: a person must hold the arm
    (--i-am-holding-the-arm) and be ready to stop it (Ctrl-C ramps out).

    Examples:
      iiwa-ident kappa --config controller.toml --target sim --json k.json
      iiwa-ident kappa --config controller.toml --target sim
        --tau-ext estimate --json k_est.json
      iiwa-ident kappa --config controller.toml --robot 192.170.10.2
        --tau-ext ft --ft 192.168.1.1 --i-am-holding-the-arm --json k.json
    """
    from iiwa_ident.deploy import read_config
    from iiwa_ident.design import read_design
    from iiwa_ident.fri import parse_host_port
    from iiwa_ident.netft import RDT_PORT, Calibration, JointAxisProjection, NetFtSettings
    from iiwa_ident.pipeline import run_kappa_sweep
    from iiwa_ident.runtime import SweepSettings
    from iiwa_ident.sim import load_plant

    try:
        if tau_ext not in TAU_EXT_SOURCES:
            raise IiwaIdentError(f"--tau-ext {tau_ext!r}: expected one of {', '.join(TAU_EXT_SOURCES)}")
        if target not in ("robot", "sim"):
            raise IiwaIdentError(f"--target {target}: expected 'robot' or 'sim'")
        if target == "robot" and not holding:
            raise IiwaIdentError("kappa on the robot drives the loop until it oscillates: a person must hold the "
                                 "arm; say so with --i-am-holding-the-arm")
        cfg = read_config(config)
        settings = SweepSettings(start=start, factor=factor, max=kmax, hold_s=hold, limit_nm=limit)
        ft_settings = NetFtSettings(rate_hz=ft_rate, cutoff_hz=ft_cutoff or None,
                                    calibration=Calibration(ft_cpf, ft_cpt))
        design_path = design
        if design_path is None and cfg.provenance.design_file:
            named = Path(cfg.provenance.design_file)
            design_path = named if named.is_absolute() else config.parent / named
            if not design_path.exists():
                typer.echo(f"note: the design file the config names ({design_path}) is not there: no linear "
                           "prediction (--design FILE gives one)")
                design_path = None
        record = read_design(design_path) if design_path is not None else None
        robot_addr = ft_addr = None
        the_plant = None
        if target == "robot":
            if not robot:
                raise IiwaIdentError("--robot HOST is required with --target robot")
            host, robot_port = parse_host_port(robot, port, "--robot")
            robot_addr = (host, robot_port)
            if tau_ext == "ft":
                if not ft:
                    raise IiwaIdentError("--tau-ext ft needs the sensor's address: --ft HOST[:PORT]")
                ft_addr = parse_host_port(ft, RDT_PORT, "--ft")
        else:
            if robot or ft:
                raise IiwaIdentError("--robot and --ft apply to --target robot (the emulator serves both on sim)")
            the_plant = load_plant(plant) if plant else None
            if the_plant is not None and (the_plant.robot_model, the_plant.joint) != (cfg.robot_model, cfg.joint):
                raise IiwaIdentError(f"the plant is {the_plant.robot_model} A{the_plant.joint}, the config "
                                     f"{cfg.robot_model} A{cfg.joint}")
        if tau_ext != "ft" and (ft or ft_lever is not None):
            raise IiwaIdentError("--ft and --ft-lever are read only with --tau-ext ft")
        projection = JointAxisProjection.from_lever_arm(ft_lever) if ft_lever is not None else None
        logs = log_dir or ((json_out.parent if json_out is not None else Path(".")) / "kappa_logs")
        out = run_kappa_sweep(cfg, logs, record=record, tau_ext=tau_ext, target=target, plant=the_plant,
                              robot=robot_addr, ft=ft_addr, ft_settings=ft_settings, ft_projection=projection,
                              settings=settings, holding_the_arm=holding, say=typer.echo)
        out["config"], out["logs"] = str(config), str(logs)
        typer.echo(format_sweep(out))
        if json_out is not None:
            write_json(json_out, out)
    except IiwaIdentError as err:
        raise fail(str(err)) from None
