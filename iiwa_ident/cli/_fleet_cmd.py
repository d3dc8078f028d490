"""``iiwa-ident fleet``: one stage on every robot's joints, in parallel on Dask."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident._toml import write_atomic
from iiwa_ident.cli._app import app, fail, json_option
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

__all__ = ["fleet_cmd"]


@app.command("fleet")
def fleet_cmd(
    stage: Annotated[str, typer.Argument(help="ripple | diagnose | fit")],
    data: Annotated[list[Path], typer.Argument(help="Datasets of any robots and joints (named with --robot-name).")],
    scheduler: Annotated[Optional[str], typer.Option(
        "--scheduler", help="Address of a running Dask scheduler (tcp://HOST:8786); default: a local cluster.")] = None,
    workers: Annotated[int, typer.Option("--workers", help="Worker processes of the local cluster.")] = 2,
    out: Annotated[Path, typer.Option("--out", help="Folder for each group's result (a re-run skips the "
                                                    "finished groups).")] = Path("fleet"),
    json_out: Annotated[Optional[Path], json_option("the fleet's results (and the table beside it, .csv)")] = None,
) -> None:
    """Run a stage on every (robot, joint) group of datasets as Dask tasks, and write a fleet table.

    Each group is one task; a bad file or a failing group is a row with its
    one-line error, never the end of the fleet. Results are kept per group
    under OUT/groups (named by the sha256 of the stage and the inputs), so a
    second run does only what is new or failed. The table (CSV) is written
    beside the --json file, or as OUT/fleet.csv without one.

    Examples:
      iiwa-ident fleet ripple runs/*.h5 --workers 4 --out fleet --json fleet.json
      iiwa-ident fleet ripple runs/*.h5 --scheduler tcp://10.0.0.5:8786 --out fleet
    """
    from iiwa_ident.fleet import fleet_table, run_fleet

    try:
        with progress(f"fleet {stage}: {len(data)} dataset(s)") as shown:
            def step(done: int, total: int, label: str) -> None:
                shown.say(f"fleet {stage}: {label}")
                shown.advance(done, total)

            doc = run_fleet(stage, data, out, scheduler=scheduler, workers=workers, progress=step)
        table = fleet_table(doc)
        # The table beside the JSON (in OUT without one).
        table_path = Path(out) / "fleet.csv" if json_out is None else Path(json_out).with_suffix(".csv")
        write_atomic(table_path, table)
        if json_out is not None:
            write_atomic(json_out, json.dumps(doc, indent=2, default=str) + "\n")
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    failed = sum(1 for g in doc["groups"] if g["error"])
    typer.echo(table.rstrip("\n"))
    typer.echo(f"{len(doc['groups'])} group(s) on {doc['engine']['workers']} worker(s), {doc['resumed']} taken from "
               f"an earlier run, {failed} failed; {doc['wall_s']:.1f} s; table {table_path}")
    if "wear" in doc:
        typer.echo(_wear_line(doc))
    if failed:
        raise typer.Exit(1)


def _wear_line(doc: dict) -> str:
    """What the fleet's comparison found: the worn joints, or why none is flagged."""
    from iiwa_ident.fleet import MIN_GROUPS

    wear = doc["wear"]
    if not wear["compared"]:
        return (f"worn joints: none judged (a joint needs a detected ripple with its std on at least "
                f"{MIN_GROUPS} robots for a fleet median)")
    head = (f"worn joints (ripple above the fleet's median for the joint beyond the uncertainties; healthy spread "
            f"x{math.exp(wear['sigma_fleet']):.2f}, false-alarm probability {wear['false_alarm']:g} over "
            f"{wear['compared']} joints): ")
    rows = [(g, g["wear"]) for g in doc["groups"] if g.get("wear", {}).get("worn")]
    if not rows:
        return head + "none"
    return head + "; ".join(f"{g['robot']} joint {g['joint']} ({w['ratio']:.1f}x the median, p = {w['p']:.1e})"
                            for g, w in rows)
