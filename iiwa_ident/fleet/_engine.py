"""A fleet run on Dask: every (robot, joint) group a task, on a local cluster or a running scheduler.

Each group's result is kept as ``OUT/groups/<key>.json``, the key the sha256
of the stage and the group's inputs (:func:`~iiwa_ident.fleet.group_key`): a
run again skips the finished groups and retries the failed ones. A group that
fails (a bad file, an analysis error, a worker lost) is a row with its
one-line error; the fleet goes on.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from iiwa_ident._toml import write_atomic
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.fleet._groups import STAGES, Group, group_datasets, group_key, run_group
from iiwa_ident.fleet._wear import flag_worn

__all__ = ["run_fleet", "fleet_table", "DEFAULT_WORKERS"]

#: Worker processes of the local cluster by default.
DEFAULT_WORKERS = 2


@contextlib.contextmanager
def _engine(scheduler: str | None, workers: int) -> Iterator[tuple[Any, dict[str, Any]]]:
    """A Dask client: on a running scheduler at ``scheduler``, else on a local cluster of ``workers`` processes."""
    from distributed import Client, LocalCluster  # here: only a fleet run needs Dask

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=10)
        except (OSError, TimeoutError) as err:
            raise IiwaIdentError(f"cannot reach the Dask scheduler at {scheduler} ({err})") from None
        with client:
            n = len(client.scheduler_info().get("workers", {}))
            yield client, {"scheduler": scheduler, "workers": n}
        return
    if not isinstance(workers, int) or workers < 1:
        raise IiwaIdentError(f"--workers must be a positive integer, got {workers!r}")
    # One thread per process and one BLAS thread each: the analyses are numpy-bound, and a BLAS pool per
    # worker would oversubscribe the cores.
    single = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      env=single) as cluster, Client(cluster) as client:
        yield client, {"scheduler": cluster.scheduler_address, "workers": workers}


def _row(group: Group, stage: str, result: dict[str, Any]) -> dict[str, Any]:
    return {"robot": group.robot, "joint": group.joint, "datasets": [str(p) for p in group.datasets],
            stage: result.get(stage), "error": result.get("error")}


def run_fleet(stage: str, paths: Sequence[str | Path], out_dir: str | Path, scheduler: str | None = None,
              workers: int = DEFAULT_WORKERS, progress: Callable[[int, int, str], None] | None = None
              ) -> dict[str, Any]:
    """Run ``stage`` on every (robot, joint) group of ``paths`` as Dask tasks.

    Parameters
    ----------
    stage : {"ripple", "diagnose", "fit"}
        What each group gets.
    paths : sequence of path
        Dataset files (the workers read them from these paths).
    out_dir : path
        Where each group's result is kept (``groups/``); the caller writes the fleet's JSON and table.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); default a local cluster.
    workers : int
        Worker processes of the local cluster.
    progress : callable, optional
        ``progress(done, total, label)`` after each group.

    Returns
    -------
    dict
        ``{"stage", "engine": {"scheduler", "workers"}, "groups": [{"robot", "joint", "datasets", "<stage>",
        "error"}], "resumed": groups taken from earlier runs, "wall_s"}``; the ripple stage also judges every
        group's amplitude against the fleet's for its joint (:func:`~iiwa_ident.fleet.flag_worn`): ``"wear"``
        in each group (``fleet_median_rad``, ``ratio``, ``z``, ``p``, ``worn``) and in the document (the
        flagged groups and the fleet's spread).
    """
    if stage not in STAGES:
        raise IiwaIdentError(f"stage must be one of {', '.join(STAGES)}, got {stage!r}")
    t0 = time.perf_counter()
    cache = Path(out_dir) / "groups"
    cache.mkdir(parents=True, exist_ok=True)
    groups = group_datasets(paths)
    rows: list[dict[str, Any] | None] = [None] * len(groups)
    todo: list[tuple[int, Group, str]] = []
    resumed = 0
    for i, g in enumerate(groups):
        if g.error is not None:
            rows[i] = _row(g, stage, {"error": g.error})
            continue
        key = group_key(stage, g)
        kept = cache / f"{key}.json"
        if kept.exists():
            rows[i] = _row(g, stage, json.loads(kept.read_text()))
            resumed += 1
            continue
        todo.append((i, g, key))
    done, total = len(groups) - len(todo), len(groups)
    engine: dict[str, Any] = {"scheduler": None, "workers": 0}
    if todo:
        from distributed import as_completed

        with _engine(scheduler, workers) as (client, engine):
            # Absolute paths: a worker started elsewhere does not share this process's working folder.
            futures = {client.submit(run_group, stage, [str(p.resolve()) for p in g.datasets],
                                     key=f"{stage}-{key}", pure=False): (i, g, key) for i, g, key in todo}
            for future in as_completed(futures):
                i, g, key = futures[future]
                try:
                    result = future.result()
                except Exception as err:  # noqa: BLE001  (a lost worker or a task that could not run)
                    result = {"error": f"{type(err).__name__}: {err}".splitlines()[0]}
                if "error" not in result:
                    write_atomic(cache / f"{key}.json", json.dumps(result) + "\n")
                rows[i] = _row(g, stage, result)
                done += 1
                if progress is not None:
                    progress(done, total, g.label)
    doc: dict[str, Any] = {"stage": stage, "engine": engine, "groups": rows, "resumed": resumed}
    if stage == "ripple":
        wear = flag_worn(rows)  # type: ignore[arg-type]  # every row is set by now
        for row, judged in zip(rows, wear.pop("rows")):
            row["wear"] = judged  # type: ignore[index]  # every row is set by now
        doc["wear"] = wear
    doc["wall_s"] = time.perf_counter() - t0
    return doc


#: The figures of each stage in the fleet table, as (column, path into the stage's JSON).
_COLUMNS = {
    "ripple": (("detected", ("detected",)), ("period_rad", ("period_rad",)), ("period_std_rad", ("period_std_rad",)),
               ("amplitude_rad", ("amplitude_rad",)), ("amplitude_std_rad", ("amplitude_std_rad",)),
               ("cycles_per_rev", ("cycles_per_rev",)), ("fleet_median_rad", ("/wear", "fleet_median_rad")),
               ("ratio_to_fleet", ("/wear", "ratio")), ("worn_p", ("/wear", "p")), ("worn", ("/wear", "worn"))),
    "diagnose": (("explained", ("explained",)), ("effects", ("effects",))),
    "fit": (("K", ("parameters", "K", "value")), ("Jl", ("parameters", "Jl", "value")),
            ("Td", ("parameters", "Td", "value")), ("bc", ("parameters", "bc", "value"))),
}


def _at(doc: Any, path: tuple[str, ...]) -> Any:
    for part in path:
        if not isinstance(doc, dict) or part not in doc:
            return None
        doc = doc[part]
    if isinstance(doc, list):  # diagnose's effects: their names
        return ";".join(str(e.get("name", e)) if isinstance(e, dict) else str(e) for e in doc)
    if isinstance(doc, float) and not math.isfinite(doc):
        return None
    return doc


def fleet_table(doc: dict[str, Any]) -> str:
    """The fleet's CSV table: one row per group (robot, joint, datasets, the stage's figures, error)."""
    stage = doc["stage"]
    columns = _COLUMNS[stage]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["robot", "joint", "datasets", *(c for c, _ in columns), "error"])
    for row in doc["groups"]:
        # A path starting with "/" is read from the group's row, the others from the stage's document.
        figures = [_at(row.get(path[0][1:]), path[1:]) if path[0].startswith("/") else _at(row.get(stage), path)
                   for _, path in columns]
        writer.writerow([row["robot"], "" if row["joint"] is None else row["joint"], len(row["datasets"]),
                         *("" if v is None else v for v in figures), row["error"] or ""])
    return out.getvalue()
