"""Subcommand ``compare``: a model against datasets, as ``compare`` and ``resid`` show it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident.cli._app import app, datasets_argument, fail, json_option, model_option, write_json
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

__all__ = ["compare_cmd", "format_comparison"]



def format_comparison(rows) -> str:
    """The table ``compare`` prints: per dataset and channel the fit, the RMS and the residual tests."""
    lines = [f"  {'dataset':<32}{'channel':<9}{'fit [%]':>9}{'RMS [Nm]':>10}  {'model':<8}residual tests (99 %)"]
    for r in rows:
        name = r.dataset if len(r.dataset) <= 30 else "..." + r.dataset[-27:]
        lines.append(f"  {name:<32}{r.channel:<9}{r.fit_pct:>9.1f}{r.rms_nm:>10.4g}  "
                     f"{r.verdict:<8}{r.tests.summary()}")
    if any(r.channel == "command" for r in rows):
        lines.append("command channel: an output-error residual carries the sensor noise through the torque loop, "
                     "coloured even for an exact model: its whiteness is shown, the model is judged by its "
                     "independence of the input; not judged ('-') where the command is computed from the "
                     "measurements (constant velocity in torque mode, hand guiding): the residual feeds back into it")
    if any(r.passed is False for r in rows):
        lines.append("a residual that fails the model's tests holds what the model misses: its fit's standard "
                     "deviations assume a complete model; 'iiwa-ident diagnose' names the effect")
    return "\n".join(lines)


@app.command("compare")
def compare_cmd(
    data: Annotated[list[Path], datasets_argument("Datasets of the model's joint (simulated, imported, held out; "
                                                  "a work folder's runs/)")],
    model: Annotated[Optional[Path], model_option("Model file from fit, ripple, diagnose or model")] = None,
    json_out: Annotated[Optional[Path], json_option("the comparison")] = None,
    figures: Annotated[Optional[Path], typer.Option("--figures", help="Folder for one PNG per dataset and "
                                                    "channel: measured and predicted, and the residual's "
                                                    "correlations with their bounds.")] = None,
) -> None:
    """Run a model against measured data: the fit percentage, the RMS and the residual tests per channel.

    The channels: 'command' (the joint torque's response to the torque command, where the data hold one)
    and 'link' (the link equation's torque). The fit is 100 (1 - ||y - yhat|| / ||y - mean(y)||) %. The
    residual tests are the autocorrelation of the residual (whiteness) and its cross-correlation with the
    input (the command, or the link's velocity), over 25 lags each way at 99 % (a white residual
    independent of the input fails 1 % of the time). Nothing is fitted.

    Examples:
      iiwa-ident compare --model model.toml chirp.h5
      iiwa-ident compare --model model_ext.toml run1.h5 run2.h5 --json compare.json --figures cmp
    """
    from iiwa_ident.datasets import dataset_files, read_dataset
    from iiwa_ident.diagnose import compare
    from iiwa_ident.ident import model_for

    try:
        data = dataset_files(data)
        datasets = [read_dataset(p) for p in data]
        base = model_for(datasets, model)
        with progress(f"running the model on {len(datasets)} dataset(s)"):
            rows = compare(datasets, base)
        if not rows:
            raise IiwaIdentError(f"{data[0]}: no channel the model can predict (too short?)")
        typer.echo(format_comparison(rows))
        if json_out:
            write_json(json_out, {"model": str(model) if model else "starting model",
                                  "channels": [r.to_json() for r in rows]})
        if figures:
            from iiwa_ident.report import comparison_figure

            figures.mkdir(parents=True, exist_ok=True)
            for r in rows:
                fig = comparison_figure(r)
                path = figures / f"compare_{Path(r.dataset).stem}_{r.channel}.png"
                fig.savefig(path, dpi=100)
            typer.echo(f"figures in {figures}")
    except IiwaIdentError as err:
        raise fail(str(err)) from None
