"""Subcommand ``report``: the PDF report of a pipeline work folder or of one of its stages."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident.cli._app import app, fail
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

__all__ = ["report_cmd"]


@app.command("report")
def report_cmd(
    workdir: Annotated[Path, typer.Option("--workdir", help="Pipeline work folder (from 'iiwa-ident pipeline', also with --logs).")],
    out: Annotated[Optional[Path], typer.Option("--out", help="PDF to write (default: WORKDIR/report.pdf, or "
                                                "WORKDIR/report_STAGE.pdf with --stage).")] = None,
    stage: Annotated[Optional[str], typer.Option("--stage", help="Only this stage: fit | ripple | design | "
                                                 "validation | diagnose.")] = None,
) -> None:
    """Build the PDF report from the files of a work folder (no experiment is repeated).

    Page 1 is the verdict: one row per stage (its key figure, the reference
    it is judged by, PASS / WARN / FAIL or SKIPPED), the warnings and the page index;
    then per stage its figures, each with a caption saying what to look at
    (a stage that failed gets a page saying what failed), and an appendix
    with the inputs and every file's sha256. Every page says whether its data are SIMULATED
    or MEASURED; the report of a 'pipeline --logs' folder adds the runs with
    the warnings of their import and each run's held-out prediction. A
    folder without pipeline results is refused. The fit's and the ripple
    stage's results are the ones the pipeline kept (fit_result.h5,
    ripple_result.h5; computed again where the data changed since); the
    diagnosis is run again.

    Examples:
      iiwa-ident report --workdir run1
      iiwa-ident report --workdir run1 --stage ripple --out ripple.pdf
    """
    from iiwa_ident.report import build_report

    try:
        target = out or workdir / ("report.pdf" if stage is None else f"report_{stage}.pdf")
        if target.is_dir():
            raise IiwaIdentError(f"{target}: is a directory, not a file")
        with progress(f"building the report of {workdir} "):
            titles = build_report(target, workdir, stage=stage)
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    for i, title in enumerate(titles, 1):
        typer.echo(f"page {i:2d}: {title}")
    typer.echo(f"wrote {target}")
