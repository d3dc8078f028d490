"""Subcommand ``diagnose``: what the model gets wrong, the effect that causes it, and the gain of adding it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident.cli._app import app, datasets_argument, fail, figures_option, json_option, model_option, write_json
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

__all__ = ["diagnose_cmd"]


@app.command("diagnose")
def diagnose_cmd(
    data: Annotated[list[Path], datasets_argument("Datasets of one joint (any experiment, torque or position mode)")],
    model: Annotated[Optional[Path], model_option("Model file to check (e.g. from fit or ripple)")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", help="Extended model file to write.")] = None,
    json_out: Annotated[Optional[Path], json_option("the diagnosis")] = None,
    figures: Annotated[Optional[Path], figures_option()] = None,
) -> None:
    """Compare the model with measurements, name the effects it misses, extend it and measure the gain.

    Candidate effects: transmission_ripple, link_friction, position_dependent_load,
    link_spring, torque_sensor_offset, torque_sensor_scale, torque_log_filter,
    periodic_disturbance, and model_parameters (the model's own Jc, bc, K, Jl
    and Td refitted together, e.g. an extra input delay or Table I on another
    joint). A torque read the other way round is named first. An effect is named
    only when it lowers the held-out residual
    (blocked cross-validation, BIC, t-test confidence) and is at least twice
    the residual's noise; on data the model explains, nothing is named. Each
    effect the model already carries (e.g. from fit) is tested too: one the
    data contradict is replaced ("replaced: torque_sensor_offset ->
    position_dependent_load") and left out of the extended model.

    Without --model, the joint's starting model: Jl and the gravity load from the
    robot's description at the pose the datasets were recorded at (see
    `iiwa-ident model`).

    Example:
      iiwa-ident diagnose --model model.toml --json diagnose.json --out model_ext.toml chirp.h5 cv.h5 hand.h5
    """
    from iiwa_ident.datasets import dataset_files, read_dataset, sha256_file
    from iiwa_ident.diagnose import diagnose
    from iiwa_ident.ident import model_for, write_model
    from iiwa_ident.model import Source

    try:
        data = dataset_files(data)
        datasets = [read_dataset(p) for p in data]
        base = model_for(datasets, model)
        if model is None:
            typer.echo(f"model: {base.description}")
        with progress(f"diagnosing {len(datasets)} dataset(s): testing the candidate effects"):
            result = diagnose(datasets, base)
        typer.echo(result.summary())
        if out:
            ext = result.extended
            ext.sources = [s for s in ext.sources if s.role != "diagnose"] + [
                Source(str(p), sha256_file(p), "diagnose") for p in data]
            write_model(out, ext)
            result.model_out = str(out)
            typer.echo(f"wrote {out}")
        if json_out:
            write_json(json_out, result.as_json())
        if figures:
            import matplotlib.pyplot as plt

            from iiwa_ident.report import figure_set

            figures.mkdir(parents=True, exist_ok=True)
            for name, fig in figure_set(result).items():
                fig.savefig(figures / f"{name}.png", dpi=110)
                plt.close(fig)
            typer.echo(f"figures in {figures}")
    except IiwaIdentError as err:
        raise fail(str(err)) from None
