"""The pipeline on a robot's own logs (``iiwa-ident pipeline --logs``).

Stages: import (every run, with the provenance checks of ``import``), ripple from all runs of the joint,
the diagnosis from the joint's starting model (the robot's description at the logged pose), held-out
validation (each run predicted by the model the diagnosis extended on the other runs) and, where a
torque-commanded record is among the logs, fit, design and deploy; then the report. Stage table,
``pipeline.json`` and exit codes are the simulated pipeline's (:mod:`iiwa_ident.pipeline._core`).

A log is a dataset file (``.h5``), a folder of column files in the layout of Drake's iiwa driver
(:data:`LOG_FILES`: one text file per signal, one column per joint), or a folder of such folders.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident._toml import write_atomic
from iiwa_ident.datasets import COLUMN_LOG_MARK
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.pipeline._core import (
    FILES,
    PipelineContext,
    PipelineResult,
    Stage,
    StageRecord,
    StageSkipped,
    _headline,
    _num,
    _stage_deploy,
    _stage_design,
    fit_warnings,
    parameter_rows,
    record_diagnosis,
    run_stages,
)
from iiwa_ident.pipeline._saved import save_results

__all__ = ["LOG_FILES", "RUNS_DIR", "LogRun", "find_log_runs", "LOG_STAGES", "run_log_pipeline"]

#: Column files of a log folder and the signal each holds (Drake's iiwa driver names them so).
LOG_FILES = {
    "cur_traj_time_s.txt": "t",
    "joint_position_measured.txt": "q_m",
    "joint_torque_measured.txt": "tau_j",
    "joint_velocity_measured.txt": "dq_m",
    "joint_position_commanded.txt": "q_cmd",
    "joint_torque_commanded.txt": "tau_c",
    "joint_torque_external.txt": "tau_ext_fri",
}
#: The file that makes a folder a log run.
_RUN_MARK = COLUMN_LOG_MARK  # a folder with this file is one run of column logs
#: Imported runs go here in the work folder, one dataset per run.
RUNS_DIR = FILES["runs_dir"]
#: Folders searched below a given path for runs.
_MAX_DEPTH = 3
#: A run whose moving speeds keep within this ratio (90th over 10th percentile) is a constant-velocity run.
_CONSTANT_SPEED_RATIO = 1.5


@dataclass
class LogRun:
    """One run found under a ``--logs`` path: its name in the work folder and where it is."""

    name: str
    path: Path
    kind: str  # "dataset" (an .h5 file) or "columns" (a folder of column files)


def find_log_runs(paths: Sequence[str | Path]) -> list[LogRun]:
    """Every run under ``paths``: dataset files, column-file folders (:data:`LOG_FILES`), and such files and
    folders up to three folders below. Names are the runs' paths from the folder given (``/`` as ``_``).

    Raises
    ------
    IiwaIdentError
        A path that does not exist or holds no run.
    """
    runs: list[LogRun] = []
    for given in paths:
        given = Path(given)
        if not given.exists():
            raise IiwaIdentError(f"{given}: no such file or folder")
        found: list[LogRun] = []

        def visit(p: Path, depth: int, found: list[LogRun] = found, given: Path = given) -> None:
            if p.is_file():
                if p.suffix == ".h5":
                    found.append(LogRun(_run_name(p.with_suffix(""), given), p, "dataset"))
                return
            if (p / _RUN_MARK).is_file():
                found.append(LogRun(_run_name(p, given), p, "columns"))
                return
            if depth < _MAX_DEPTH:
                for child in sorted(p.iterdir()):
                    if not child.name.startswith("."):
                        visit(child, depth + 1)

        visit(given, 0)
        if not found:
            raise IiwaIdentError(f"{given}: no run found (a dataset file .h5, or a folder with {_RUN_MARK} and "
                                 "the other column files, up to three folders down)")
        runs += found
    seen: dict[str, int] = {}
    for r in runs:
        k = seen[r.name] = seen.get(r.name, 0) + 1
        if k > 1:
            r.name = f"{r.name}_{k}"
    return runs


def _run_name(p: Path, given: Path) -> str:
    # A run given itself is named with its folder's parent too: "joint6" alone says little.
    rel = p.relative_to(given.parent) if p != given else Path(p.parent.name) / p.name
    return "_".join(x for x in rel.parts if x)


def _moving_speeds(ds) -> np.ndarray:
    """The run's speeds [rad/s] where it moves at more than half its top speed (its 95th percentile)."""
    from iiwa_ident.datasets import joint_velocity

    w = np.abs(joint_velocity(ds))
    return w[w > 0.5 * np.percentile(w, 95)] if w.size else w


def _import_columns(run: LogRun, joint: int | None, robot_model: str, split_runs: bool = False) -> list:
    """The run's datasets: one, or with ``split_runs`` one per stretch whose time does not go back."""
    from iiwa_ident.datasets import import_columns

    files = {sig: run.path / name for name, sig in LOG_FILES.items() if (run.path / name).is_file()}
    if "t" not in files or "tau_j" not in files:
        raise IiwaIdentError(f"{run.path}: a log folder needs cur_traj_time_s.txt, {_RUN_MARK} and "
                             "joint_torque_measured.txt")

    imported: dict[int, list] = {}

    def read(j: int) -> list:
        if j not in imported:  # each joint's import once, however many runs the log holds
            got = import_columns(files, joint=j, experiment="free", robot_model=robot_model, split_runs=split_runs)
            imported[j] = got if isinstance(got, list) else [got]
        return imported[j]

    out = []
    for k, ds in enumerate(read(joint or 1)):
        travel = ds.experiment_attrs.get("joint_travel_rad")
        if joint is None:
            if travel is None:
                raise IiwaIdentError(f"{run.path}: the position file has no column per joint: give --joint")
            moved = int(np.argmax(travel)) + 1
            if moved != ds.joint:
                ds = read(moved)[k]
        # The experiment the log was: a torque-commanded record, constant speeds back and forth, or free motion.
        if ds.has("tau_c"):
            ds.experiment = "chirp"
        else:
            w = _moving_speeds(ds)
            steady = w.size > 10 and np.percentile(w, 90) < _CONSTANT_SPEED_RATIO * np.percentile(w, 10)
            ds.experiment = "constant_velocity" if steady else "free"
        out.append(ds)
    return out


# --------------------------------------------------------------------------- stages
def _runs(ctx: PipelineContext) -> list:
    return ctx.results["runs"]


def _stage_import(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.datasets import note_warnings, read_dataset, torque_sign_problem, write_dataset

    found = find_log_runs(ctx.results["log_paths"])
    joint = ctx.results.get("log_joint")
    split = bool(ctx.results.get("split_runs"))
    runs, datasets, dropped = [], [], []
    for run in found:
        # A run that cannot be read is dropped with its reason; the others go on.
        try:
            got = [read_dataset(run.path)] if run.kind == "dataset" else _import_columns(run, joint, ctx.robot_model,
                                                                                         split)
        except IiwaIdentError as err:
            dropped.append({"run": run.name, "source": str(run.path), "reason": str(err)})
            ctx.progress(f"  dropped {run.name}: {err}")
            continue
        left_out = got[0].experiment_attrs.get("split_left_out")
        if left_out:
            dropped.append({"run": run.name, "source": str(run.path), "reason": left_out})
            ctx.progress(f"  {run.name}: {left_out}")
        for k, ds in enumerate(got, start=1):
            runs.append(run if len(got) == 1 else LogRun(f"{run.name}_run{k}", run.path, run.kind))
            datasets.append(ds)
    if not datasets:
        raise IiwaIdentError(f"no run could be read ({len(dropped)} dropped: {dropped[0]['reason']})" if dropped
                             else "no run found")
    joints = {ds.joint for ds in datasets}
    if len(joints) > 1:
        listed = ", ".join(f"{r.name} (joint {ds.joint})" for r, ds in zip(runs, datasets))
        raise IiwaIdentError(f"the runs move different joints: {listed}; give --joint N or one joint's runs")
    ctx.joint = joints.pop()
    # One driver wrote every run: where a run's gravity decides that the torque reads the other way round,
    # all column logs are read with the sign flipped (dataset files were imported by the user already).
    sign = ctx.results.get("torque_sign", "auto")
    deciding = [r.name for r, ds in zip(runs, datasets) if r.kind == "columns" and torque_sign_problem(ds)]
    flip = sign == "-1" or (sign == "auto" and bool(deciding))
    rows = []
    out_dir = ctx.workdir / RUNS_DIR
    out_dir.mkdir(exist_ok=True)
    for run, ds in zip(runs, datasets):
        if flip and run.kind == "columns":
            ds.signals["tau_j"] = -np.asarray(ds["tau_j"], float)
        warnings = note_warnings(ds)
        path = write_dataset(out_dir / f"{run.name}.h5", ds)
        ds.path = path
        for w in warnings:
            ctx.progress(f"  warning: {run.name}: {w}")
        speeds = _moving_speeds(ds)
        rows.append({"run": run.name, "source": str(run.path), "file": f"{RUNS_DIR}/{path.name}",
                     "experiment": ds.experiment, "samples": ds.n_samples, "rate_hz": ds.sample_rate_hz,
                     "speed_rad_s": _num(float(np.median(speeds))) if speeds.size else None, "warnings": warnings})
    ctx.results["runs"] = datasets
    how = ("as logged" if not flip else
           "flipped (--torque-sign -1)" if sign == "-1" else
           f"flipped: the gravity of {', '.join(deciding)} reads the other way round")
    ctx.progress(f"  {len(datasets)} run(s) of joint {ctx.joint}; torque sign {how}")
    return {"runs": rows, "dropped": dropped, "joint": ctx.joint, "robot_model": ctx.robot_model,
            "torque_sign": how}


def _stage_ripple(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.datasets import sha256_file
    from iiwa_ident.ident import dataset_model, model_for, ripple_model, write_model
    from iiwa_ident.model import Source

    runs = _runs(ctx)
    given = ctx.results.get("log_model")
    if given is not None:
        model = model_for(runs, given)
    else:
        try:
            model = dataset_model(runs)
        except IiwaIdentError as err:
            # Rough K and Jl do for the ripple search; the diagnosis refuses to judge a joint by another's model.
            model, ctx.results["start_problem"] = dataset_model(runs, borrow=True), str(err)
    model, r = ripple_model(model, runs, [Source(f"{RUNS_DIR}/{ds.path.name}", sha256_file(ds.path), "ripple")
                                          for ds in runs])
    # The starting model with the table: what the diagnosis starts from (a fit replaces model_ripple later).
    write_model(ctx.path("model_start"), model)
    write_model(ctx.path("model_ripple"), model)
    write_atomic(ctx.path("ripple_json"), json.dumps(r.to_json(), indent=2) + "\n")
    # K and Jl of the search are the starting model's.
    save_results(ctx.path("ripple_result"), ctx.workdir, [ds.path for ds in runs] + [ctx.path("model_start")],
                 ripple=r)
    ctx.results.update(ripple=r, model_ripple=model, model_start=model)
    for w in r.warnings:
        ctx.progress(f"  warning: {w}")
    # A period the runs do not agree on is no answer (ripple.json keeps what each run saw).
    got = r.detected
    return {"detected": got, "period_rad": _num(r.period_rad) if got else None,
            "period_std_rad": _num(r.period_std_rad) if got else None,
            "cycles_per_rev": _num(r.cycles_per_rev) if got else None,
            "amplitude_rad": _num(r.amplitude_rad) if got else None,
            "methods": sorted(r.methods), "verdict": r.agreement.get("verdict"), "warnings": list(r.warnings)}


def _start(ctx: PipelineContext):
    """The model the diagnosis starts from, or the one-line reason there is none."""
    if "start_problem" in ctx.results:
        raise IiwaIdentError(ctx.results["start_problem"])
    return ctx.results["model_start"]


def _stage_diagnose(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.diagnose import diagnose

    runs = _runs(ctx)
    return record_diagnosis(ctx, diagnose(runs, _start(ctx)), [ds.path for ds in runs])


def _rms(rms_nm: list[float]) -> float:
    """The RMS of the channels' RMS [Nm]; NaN of none."""
    return float(np.sqrt(np.mean(np.square(rms_nm)))) if rms_nm else float("nan")


def _stage_held_out(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.diagnose import compare, diagnose, residual_rms

    runs = _runs(ctx)
    if len(runs) < 2:
        raise StageSkipped("one run: no other run to predict it from")
    start = _start(ctx)
    rows = []
    for k, ds in enumerate(runs):
        rest = runs[:k] + runs[k + 1:]
        extended = diagnose(rest, start).extended
        # As an identification engineer checks a model on held-out data: the RMS, the fit and the residual tests.
        checks = compare([ds], extended)
        before = _rms([r.rms_nm for r in residual_rms([ds], start)])
        after = _rms([c.rms_nm for c in checks])
        rows.append({"run": ds.path.stem, "before_nm": before, "after_nm": after,
                     "ratio": after / before if before > 0 else None,
                     "fit_pct": {c.channel: c.fit_pct for c in checks},
                     "residual_tests_passed": {c.channel: c.passed for c in checks},
                     "named_by_others": sorted(e["name"] for e in extended.effects
                                               if e["name"] not in {x["name"] for x in start.effects})})
        ctx.progress(f"  {ds.path.stem}: predicted from the other runs {before:.3g} -> {after:.3g} Nm RMS; "
                     + "; ".join(f"{c.channel} fit {c.fit_pct:.1f} %, residual tests "
                                 f"{c.verdict}" for c in checks))
    write_atomic(ctx.path("held_out_json"), json.dumps({"runs": rows}, indent=2) + "\n")
    return {"runs": rows}


def _stage_fit(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.ident import fit_model, model_from_dict, write_model

    chirps = [ds for ds in _runs(ctx) if ds.has("tau_c")]
    if not chirps:
        raise StageSkipped("no torque-commanded record among the logs (no tau_c): fit, design and deploy need "
                           "one (record it with 'iiwa-ident chirp --target robot --robot HOST --joint N')")
    model, result = fit_model([ds.path for ds in chirps], base_model=ctx.results["model_ripple"])
    model.joint, model.robot_model = ctx.joint, ctx.robot_model
    write_model(ctx.path("model"), model)
    write_atomic(ctx.path("fit_json"), json.dumps(result.to_json(), indent=2) + "\n")
    save_results(ctx.path("fit_result"), ctx.workdir, [ds.path for ds in chirps] + [ctx.path("model_start")],
                 fit=result)
    with_table = model_from_dict(model.to_dict())
    with_table.ripple = ctx.results["model_ripple"].ripple
    write_model(ctx.path("model_ripple"), with_table)
    ctx.results.update(model=model, fit=result, model_ripple=with_table)
    return {"parameters": parameter_rows(ctx, result), "method": result.method, "warnings": fit_warnings(result)}


#: The stages of a pipeline on logs, in the order they run.
LOG_STAGES: tuple[Stage, ...] = (
    Stage("import", "the logs, with the provenance checks", (), ("runs_dir",), _stage_import),
    Stage("ripple", "ripple period and lookup table from all runs", ("import",),
          ("model_start", "model_ripple", "ripple_json", "ripple_result"), _stage_ripple),
    Stage("diagnose", "diagnosis from the joint's starting model", ("ripple",), ("diagnose_json", "model_ext"),
          _stage_diagnose),
    Stage("held_out", "each run predicted by the model extended on the others", ("ripple",), ("held_out_json",),
          _stage_held_out),
    Stage("fit", "transfer-function fit of the torque-commanded records", ("ripple",),
          ("model", "fit_json", "fit_result"), _stage_fit),
    Stage("design", "additive controller, kappa margins", ("fit",), ("design", "design_json"), _stage_design),
    Stage("deploy", "controller config and safety checks", ("design",), ("controller", "controller_json"),
          _stage_deploy),
)


def _log_headline(records: list[StageRecord]) -> dict[str, Any]:
    out = {"data": "measured", **_headline(records)}
    by = {r.name: r for r in records if r.status == "ok"}
    if "import" in by:
        out["runs"] = [r["run"] for r in by["import"].headline["runs"]]
    if "ripple" in by:
        out["ripple_decided"] = bool(by["ripple"].headline["detected"])
    if "held_out" in by:
        out["held_out"] = [{k: r[k] for k in ("run", "before_nm", "after_nm")} for r in by["held_out"].headline["runs"]]
    return out


def run_log_pipeline(workdir: str | Path, logs: Sequence[str | Path], *, robot_model: str = "iiwa14",
                     joint: int | None = None, torque_sign: str = "auto", model: str | Path | None = None,
                     progress: Callable[[str], None] = print,
                     report: Callable[..., list] | None = None, skip: tuple[str, ...] = (),
                     split_runs: bool = False) -> PipelineResult:
    """Run :data:`LOG_STAGES` on the runs under ``logs`` into ``workdir``; write ``pipeline.json``.

    Parameters
    ----------
    workdir : path
        Work folder (created): ``runs/*.h5``, ``model_start.toml`` (the starting model with the ripple table),
        ``model_ripple.toml``, ``ripple.json``, ``diagnose.json``,
        ``model_ext.toml``, ``held_out.json``, (``model.toml``, ``design.toml``, ``controller.toml``),
        ``pipeline.json``, ``report.pdf``.
    logs : paths
        Dataset files, column-log folders or folders of them (:func:`find_log_runs`).
    robot_model : str
        The arm the column logs come from (``iiwa14``, ``iiwa7``).
    joint : int, optional
        The joint under test; by default the one that moved furthest in each run (they must agree).
    torque_sign : str
        ``auto`` (flip the column logs' torque when a run's gravity says it reads the other way round),
        ``+1`` or ``-1``.
    model : path, optional
        A model file of the joint to start from instead of its starting model from the robot's description
        (needed where the logs do not say the other joints' positions).
    progress, report, skip
        As :func:`~iiwa_ident.pipeline.run_pipeline`.
    split_runs : bool
        A column log whose time goes back holds several runs: import each (named ``<run>_run1``, ...)
        instead of dropping the log. A run that cannot be read is dropped with its reason (the import
        stage's ``dropped``); the others go on.

    Raises
    ------
    IiwaIdentError
        A bad argument; failures inside stages are recorded instead.
    """
    from iiwa_ident._blas import single_threaded_blas
    from iiwa_ident.description import ROBOTS

    t_start = time.perf_counter()
    if not logs:
        raise IiwaIdentError("--logs: give at least one dataset file or log folder")
    if robot_model not in ROBOTS:
        raise IiwaIdentError(f"--robot-model {robot_model}: expected one of {', '.join(ROBOTS)}")
    if joint is not None and not 1 <= joint <= 7:
        raise IiwaIdentError(f"--joint {joint}: expected 1-7")
    if torque_sign not in ("auto", "+1", "-1"):
        raise IiwaIdentError(f"--torque-sign {torque_sign}: expected auto, +1 or -1")
    unknown = [name for name in skip if name not in {st.name for st in LOG_STAGES}]
    if unknown:
        raise IiwaIdentError(f"--skip {unknown[0]}: unknown stage (known: {', '.join(s.name for s in LOG_STAGES)})")
    if model is not None and not Path(model).is_file():
        raise IiwaIdentError(f"{model}: no such file")
    for p in logs:
        if not Path(p).exists():
            raise IiwaIdentError(f"{p}: no such file or folder")
    workdir = Path(workdir)
    if workdir.exists() and not workdir.is_dir():
        raise IiwaIdentError(f"{workdir}: exists and is not a folder")
    workdir.mkdir(parents=True, exist_ok=True)
    ctx = PipelineContext(workdir=workdir, target="logs", robot_model=robot_model, joint=joint or 0,
                          progress=progress)
    ctx.results.update(log_paths=[Path(p) for p in logs], log_joint=joint, torque_sign=torque_sign,
                       split_runs=split_runs,
                       log_model=None if model is None else Path(model))
    inputs = {"logs": ", ".join(str(p) for p in logs), "robot_model": robot_model,
              "joint": "the one that moved" if joint is None else str(joint),
              "model": "the joint's starting model (the robot's description)" if model is None else str(model)}
    with single_threaded_blas():
        return run_stages(ctx, LOG_STAGES, inputs, skip=skip, report=report, t_start=t_start,
                          headline=_log_headline)
