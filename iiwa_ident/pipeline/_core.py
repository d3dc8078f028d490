"""The whole pipeline: experiments, identification, design, deployment, validation, diagnosis and report.

Stages run in order; each names the stages whose results it needs. A stage
that raises is recorded as failed with its one-line message, the stages
that depend on it are skipped, the others still run, and the report is
written in every case (it says what failed instead of drawing empty axes).
Every intermediate file goes to the work folder under a fixed name
(:data:`FILES`), ``pipeline.json`` records the stages and the headline
figures, ``report.pdf`` the pages.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from iiwa_ident._toml import write_atomic
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.pipeline._saved import save_results
from iiwa_ident.pipeline._validation import ValidationSettings
from iiwa_ident.runtime import SweepSettings

__all__ = ["FILES", "PipelineSettings", "Stage", "StageRecord", "StageSkipped", "PipelineContext",
           "PipelineResult", "STAGES", "run_pipeline", "run_stages", "record_diagnosis", "parameter_rows",
           "format_summary", "read_pipeline_json"]

#: File names in the work folder, by role.
FILES = {
    "chirp": "chirp.h5", "model": "model.toml", "fit_json": "fit.json", "fit_result": "fit_result.h5",
    "ripple_result": "ripple_result.h5",
    "cv": "constant_velocity.h5", "qs": "quasi_static.h5", "hand": "hand_guided.h5",
    "model_ripple": "model_ripple.toml", "model_start": "model_start.toml", "ripple_json": "ripple.json", "fit_ripple_json": "fit_ripple.json",
    "design": "design.toml", "design_json": "design.json", "observers_json": "observers.json",
    "controller": "controller.toml", "controller_json": "controller.json",
    "validation_dir": "validation", "validation_json": "validation.json",
    "diagnose_json": "diagnose.json", "model_ext": "model_ext.toml", "runs_dir": "runs", "held_out_json": "held_out.json",
    "pipeline_json": "pipeline.json", "report": "report.pdf", "plant": "plant.toml",
}


@dataclass(frozen=True, kw_only=True)
class PipelineSettings:
    """Experiment lengths of one pipeline run (:meth:`full` or :meth:`short`).

    Attributes
    ----------
    chirp_s, chirp_f0_hz, chirp_f1_hz, chirp_nm : float
        Exponential chirp: duration [s], start and end frequency [Hz], amplitude [Nm].
    cv_speeds : tuple of float
        Constant-velocity speeds [rad/s].
    cv_range_rad : float
        Travel of each constant-velocity pass [rad].
    qs_torques : tuple of float
        Quasi-static loads [Nm] for the static lookup-table method (empty: dynamic method only).
    hand_s : float
        Hand-guided record [s].
    validation : ValidationSettings
        The closed-loop runs.
    seed : int
        First noise seed (each experiment adds its own offset).
    """

    chirp_s: float = 30.0
    chirp_f0_hz: float = 0.5
    chirp_f1_hz: float = 200.0
    chirp_nm: float = 10.0
    cv_speeds: tuple[float, ...] = (0.3, 0.6, 1.2)
    cv_range_rad: float = 1.0
    qs_torques: tuple[float, ...] = (5.0, 10.0)
    hand_s: float = 20.0
    validation: ValidationSettings = field(default_factory=ValidationSettings)
    seed: int = 1

    @classmethod
    def full(cls) -> PipelineSettings:
        """The default: the paper's experiments at the lengths the documented figures were measured with."""
        return cls()

    @classmethod
    def short(cls) -> PipelineSettings:
        """A quick run for tests: shorter experiments, dynamic lookup table only, short closed-loop runs."""
        return cls(chirp_s=8.0, chirp_f1_hz=150.0, cv_speeds=(0.6, 1.2), cv_range_rad=0.6, qs_torques=(),
                   hand_s=8.0, validation=ValidationSettings(
                       step_cycles=1, sine_s=0.6, kappa_sources=("ft",),
                       kappa=SweepSettings(start=5.0, factor=1.25, max=45.0, hold_s=1.25)))


class StageSkipped(Exception):
    """Raised by a stage that has nothing to do with the data it was given (its message says why); the stage
    is recorded as skipped, and so are the stages that need it."""


@dataclass
class Stage:
    """One step of the pipeline.

    Attributes
    ----------
    name : str
        Identifier (also the ``--stage`` of ``iiwa-ident report``).
    title : str
        What it does, for progress output and the report.
    needs : tuple of str
        Stages whose success it requires.
    outputs : tuple of str
        Keys of :data:`FILES` it writes.
    run : callable
        ``run(ctx) -> dict`` of headline figures; raises on failure.
    """

    name: str
    title: str
    needs: tuple[str, ...]
    outputs: tuple[str, ...]
    run: Callable[[PipelineContext], dict[str, Any]]


@dataclass(kw_only=True)
class StageRecord:
    """Outcome of one stage: ``status`` is ``ok``, ``failed`` or ``skipped``; ``duration_s`` in s."""

    name: str
    title: str
    status: str
    duration_s: float = 0.0
    error: str = ""
    outputs: list[str] = field(default_factory=list)
    headline: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "title": self.title, "status": self.status, "duration_s": self.duration_s,
                "error": self.error, "outputs": self.outputs, "headline": self.headline}


@dataclass(kw_only=True)
class PipelineContext:
    """What the stages share: the work folder, the target and the in-memory results by key."""

    workdir: Path
    target: str = "sim"
    plant_file: Path | None = None
    robot: str | None = None
    port: int = 30200
    robot_model: str = "iiwa14"
    joint: int = 1
    realtime: bool = False
    settings: PipelineSettings = field(default_factory=PipelineSettings.full)
    progress: Callable[[str], None] = print
    results: dict[str, Any] = field(default_factory=dict)
    records: list[StageRecord] = field(default_factory=list)

    def path(self, key: str) -> Path:
        return self.workdir / FILES[key]

    @property
    def plant(self):
        """The simulated plant (sim target only)."""
        if "plant" not in self.results:
            from iiwa_ident.sim import default_plant, load_plant

            self.results["plant"] = load_plant(self.plant_file) if self.plant_file else default_plant()
        return self.results["plant"]

    def robot_interface(self, mode: str = "torque", seed: int = 0):
        """A fresh simulated joint or FRI robot for one experiment."""
        if self.target == "sim":
            from iiwa_ident.sim import SimulatedJoint

            return SimulatedJoint(self.plant, seed=seed)
        from iiwa_ident.fri import FriRobot, parse_host_port

        host, port = parse_host_port(self.robot or "", self.port)
        return FriRobot(host, self.joint, self.robot_model, port=port, mode=mode)


@dataclass
class PipelineResult:
    """Outcome of :func:`run_pipeline`: stage records, headline figures, files and wall time [s]."""

    workdir: Path
    stages: list[StageRecord]
    headline: dict[str, Any]
    report: Path | None
    wall_s: float
    inputs: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        # A stage skipped on request is not a failure; one skipped for a failed dependency comes with one.
        return not any(s.status == "failed" for s in self.stages)

    def as_json(self) -> dict[str, Any]:
        return {"format": "iiwa-ident-pipeline", "format_version": 1, "workdir": str(self.workdir),
                "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
                "wall_s": self.wall_s, "ok": self.ok, "inputs": self.inputs,
                "stages": [s.as_dict() for s in self.stages], "headline": self.headline,
                "report": None if self.report is None else str(self.report.name)}


def _num(x: Any) -> Any:
    """JSON-safe number: NaN and inf become None."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _record(ctx: PipelineContext, experiment, key: str, seed: int, mode: str = "torque") -> Path:
    """Run one experiment on the target and write its dataset under ``FILES[key]``."""
    from iiwa_ident.datasets import write_dataset
    from iiwa_ident.excite import record

    ds = record(ctx.robot_interface(mode, seed), experiment)
    if "stopped_reason" in ds.experiment_attrs:
        ctx.progress(f"  warning: {experiment.name} stopped early: {ds.experiment_attrs['stopped_reason']}")
    ctx.results[key] = ds
    ds.path = write_dataset(ctx.path(key), ds)  # the diagnosis and the report name it by its file
    return ds.path


# --------------------------------------------------------------------------- stages
def _stage_chirp(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.excite import Chirp

    s = ctx.settings
    _record(ctx, Chirp(s.chirp_f0_hz, s.chirp_f1_hz, s.chirp_s, s.chirp_nm, 3.0, 30.0), "chirp", s.seed)
    return {"duration_s": s.chirp_s, "f0_hz": s.chirp_f0_hz, "f1_hz": s.chirp_f1_hz, "amplitude_nm": s.chirp_nm}


def _truth_dynamics(ctx: PipelineContext) -> dict[str, float] | None:
    """The simulated plant's parameters (the pipeline knows what it simulated; no dataset truth is read)."""
    return dict(ctx.plant.dynamics) if ctx.target == "sim" else None


def _stage_fit(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.ident import fit_model, write_model

    model, result = fit_model([ctx.path("chirp")])
    model.joint = ctx.plant.joint if ctx.target == "sim" else ctx.joint
    model.robot_model = ctx.plant.robot_model if ctx.target == "sim" else ctx.robot_model
    write_model(ctx.path("model"), model)
    write_atomic(ctx.path("fit_json"), json.dumps(result.to_json(), indent=2) + "\n")
    save_results(ctx.path("fit_result"), ctx.workdir, [ctx.path("chirp")], fit=result)
    ctx.results.update(model=model, fit=result)
    return {"parameters": parameter_rows(ctx, result), "method": result.method, "warnings": fit_warnings(result),
            "model_rejected": model_rejected(result), **residual_level(ctx, result)}


def fit_warnings(result: Any) -> list[str]:
    """A fit's warnings: a chirp's fit holds them, a multisine's best linear approximation computes them."""
    from iiwa_ident.ident import BlaFit

    return result.warnings() if isinstance(result, BlaFit) else list(result.warnings)


def model_rejected(result: Any) -> bool:
    """Whether the fit rejected eq (4) (only a chirp's fit judges that)."""
    from iiwa_ident.ident import FitResult

    return isinstance(result, FitResult) and bool(result.model_rejected)


def residual_level(ctx: PipelineContext, result: Any) -> dict[str, float]:
    """The fit's torque residual [Nm RMS] and, on the simulator, the sensor noise it simulated (its floor)."""
    out = {"residual_tau_j_nm": max(n["tau_j_nm"] for n in result.noise)}
    if ctx.target == "sim":
        out["sensor_noise_nm"] = float(ctx.plant.sensors["tau_noise_nm"])
    return out


def parameter_rows(ctx: PipelineContext, result: Any) -> dict[str, dict[str, Any]]:
    """A fit's parameters with std and, on the simulator, their error against the simulated plant."""
    from iiwa_ident.model import PARAMETER_NAMES

    truth = _truth_dynamics(ctx)
    out: dict[str, dict[str, Any]] = {}
    for name in PARAMETER_NAMES:
        v, sd = result.parameters[name], result.std[name]
        row = {"value": v, "std": sd, "rel_std_pct": 100 * sd / abs(v) if v else None}
        if truth is not None and name in truth:
            row["simulated"] = truth[name]
            row["error_pct"] = 100 * (v - truth[name]) / truth[name]
            row["error_std"] = (v - truth[name]) / sd if sd > 0 else None
        out[name] = row
    return out


def _stage_cv(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.excite import ConstantVelocity, QuasiStatic

    s = ctx.settings
    _record(ctx, ConstantVelocity(list(s.cv_speeds), range_rad=s.cv_range_rad), "cv", s.seed + 1)
    out: dict[str, Any] = {"speeds_rad_s": list(s.cv_speeds), "quasi_static": False}
    # The static method needs an external drive moving the link: only the simulation has one.
    if s.qs_torques and ctx.target == "sim":
        _record(ctx, QuasiStatic(list(s.qs_torques)), "qs", s.seed + 2)
        out["quasi_static"] = True
        out["quasi_static_torques_nm"] = list(s.qs_torques)
    return out


def _stage_hand(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.excite import HandGuided

    _record(ctx, HandGuided(duration_s=ctx.settings.hand_s), "hand", ctx.settings.seed + 3)
    return {"duration_s": ctx.settings.hand_s}


def _stage_ripple(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.datasets import sha256_file
    from iiwa_ident.ident import fit_model, ripple_model, write_model
    from iiwa_ident.model import Source

    base = ctx.results["model"]
    data = [ctx.results["cv"]] + ([ctx.results["qs"]] if "qs" in ctx.results else [])
    files = [ctx.path("cv")] + ([ctx.path("qs")] if "qs" in ctx.results else [])
    model, r = ripple_model(base, data, [Source(str(p.name), sha256_file(p), "ripple") for p in files])
    refit = None
    if r.detected:
        # The chirp again, with the table's deflection in the output-error model (eq (5)): the first
        # fit had only the period it could find in the chirp itself.
        refitted, refit = fit_model([ctx.path("chirp")], base_model=model)
        refitted.joint, refitted.robot_model = model.joint, model.robot_model
        refitted.sources = model.sources
        model = refitted
        write_atomic(ctx.path("fit_ripple_json"), json.dumps(refit.to_json(), indent=2) + "\n")
    write_model(ctx.path("model_ripple"), model)
    write_atomic(ctx.path("ripple_json"), json.dumps(r.to_json(), indent=2) + "\n")
    # K and Jl of the search come from the fit's model.
    save_results(ctx.path("ripple_result"), ctx.workdir, files + [ctx.path("model")], ripple=r)
    ctx.results.update(ripple=r, model_ripple=model)
    for w in r.warnings:
        ctx.progress(f"  warning: {w}")
    if refit is not None:
        ctx.results["fit_ripple"] = refit
    out: dict[str, Any] = {"detected": r.detected, "period_rad": _num(r.period_rad),
                           "period_std_rad": _num(r.period_std_rad), "period_ticks": _num(r.period_ticks),
                           "amplitude_rad": _num(r.amplitude_rad), "methods": sorted(r.methods),
                           "warnings": list(r.warnings)}
    if refit is not None:
        out["refit"] = {"parameters": parameter_rows(ctx, refit), "method": refit.method,
                        "warnings": fit_warnings(refit), "model_rejected": model_rejected(refit),
                        **residual_level(ctx, refit)}
    if ctx.target == "sim":
        true = [e for e in ctx.plant.effects if e.name == "transmission_ripple"]
        if true:
            out["simulated_period_rad"] = true[0].values["period_rad"]
            if r.detected:
                out["period_rel_error"] = (r.period_rad - out["simulated_period_rad"]) / out["simulated_period_rad"]
    return out


def _stage_design(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.design import (
        design_controller,
        design_json,
        make_record,
        outer_loop_margins,
        write_design,
    )
    from iiwa_ident.model import JointParameters

    model = ctx.results["model_ripple"]
    design = design_controller(JointParameters.from_model(model))
    margins = outer_loop_margins(design)
    record = make_record(design, margins, model, ctx.path("model_ripple"))  # the design's filter
    write_design(ctx.path("design"), record)
    write_atomic(ctx.path("design_json"), json.dumps(design_json(design, margins), indent=2) + "\n")
    ctx.results.update(design=record)
    out: dict[str, Any] = {"kappa_max_builtin": _num(margins.builtin), "kappa_max_additive": _num(margins.additive),
                           "kappa_ratio": _num(margins.ratio), "beta": record.filter.beta}
    hand = ctx.results.get("hand")
    if hand is not None and hand.has("tau_ext_ref"):
        from iiwa_ident.design import compare_observers

        obs = compare_observers(hand, model, filter=record.filter)  # as deployed
        write_atomic(ctx.path("observers_json"), json.dumps(_jsonable(obs), indent=2) + "\n")
        ctx.results["observers"] = obs
        rows = obs["observers"]
        out["observer"] = {"builtin_rms_nm": rows["builtin"]["rms_lagged_fast_nm"],
                           "improved_rms_nm": rows["improved"]["rms_lagged_fast_nm"],
                           "filtered_rms_nm": rows["filtered"]["rms_lagged_fast_nm"],
                           "improvement": _num(obs["ratio_lagged_fast"]),
                           # Against the F/T torque itself, the observers' common lag (1/K_I) dominates.
                           "builtin_rms_raw_nm": rows["builtin"]["rms_fast_nm"],
                           "improved_rms_raw_nm": rows["improved"]["rms_fast_nm"],
                           "speed_threshold_rad_s": obs["speed_threshold_rad_s"]}
    else:
        out["observer"] = None
        ctx.progress("  observer comparison skipped: no hand-guided record with an F/T reference")
    return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if hasattr(x, "item") and not hasattr(x, "__len__"):
        x = x.item()
    if isinstance(x, float):
        return _num(x)
    return x


def _stage_deploy(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.datasets import sha256_file
    from iiwa_ident.deploy import config_json, deploy, deploy_target, write_config

    model = ctx.results["model_ripple"]
    # The rule of `deploy`: on the robot the joint asked for must be the model's (on the simulator the plant's).
    asked = (ctx.robot_model, ctx.joint) if ctx.target == "robot" else (None, None)
    robot_model, joint = deploy_target(model, *asked)
    config = deploy(ctx.results["design"], robot_model, joint, design_file=FILES["design"],
                    design_sha256=sha256_file(ctx.path("design")), model=model)
    write_config(ctx.path("controller"), config)
    write_atomic(ctx.path("controller_json"),
                 json.dumps(config_json(config, Path(FILES["controller"])), indent=2) + "\n")
    ctx.results["config"] = config
    return {"checks_passed": sum(c.passed for c in config.checks), "checks": len(config.checks),
            "torque_limit_nm": config.limits.torque_nm, "reference_limit_nm": config.limits.reference_nm}


def _stage_validation(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.fri import parse_host_port
    from iiwa_ident.pipeline._validation import run_validation

    record = ctx.results["design"]
    model = ctx.results["model_ripple"]
    robot = parse_host_port(ctx.robot or "", ctx.port) if ctx.target == "robot" else None
    doc = run_validation(ctx.results["config"], ctx.path("validation_dir"),
                         kappa_margins=(record.margins.builtin, record.margins.additive), delay_s=model.value("Td"),
                         target=ctx.target, plant=ctx.plant if ctx.target == "sim" else None, robot=robot,
                         settings=ctx.settings.validation, say=ctx.progress, lockstep=not ctx.realtime,
                         record=record)
    write_atomic(ctx.path("validation_json"), json.dumps(_jsonable(doc), indent=2) + "\n")
    ctx.results["validation"] = doc
    live = {source: {"ratio_live": sw["ratio_live"], "ratio_linear": sw["ratio_linear"],
                     **{loop: {k: sw[loop].get(k) for k in ("live_limit", "unstable_at", "linear_limit",
                                                             "linear_error_pct", "rate_limited_from")}
                        for loop in ("builtin", "additive")}}
            for source, sw in doc["kappa"]["sweeps"].items()}
    return {"tracking": doc["tracking"], "sine_hz": ctx.settings.validation.sine_hz,
            "kappa_linear_ratio": doc["kappa"]["linear_ratio"], "kappa_live": live or None,
            **({"kappa_live_skipped": doc["kappa"]["live_skipped"]} if "live_skipped" in doc["kappa"] else {})}


def _stage_diagnose(ctx: PipelineContext) -> dict[str, Any]:
    from iiwa_ident.diagnose import diagnose

    keys = [k for k in ("chirp", "cv", "hand") if k in ctx.results]
    result = diagnose([ctx.results[k] for k in keys], ctx.results["model_ripple"])
    return record_diagnosis(ctx, result, [ctx.path(k) for k in keys])


def record_diagnosis(ctx: PipelineContext, result: Any, data: list[Path]) -> dict[str, Any]:
    """Write a diagnosis's extended model (its sources: the diagnosed files, named from the work folder) and
    ``diagnose.json``; keep it in the context; return its headline figures."""
    from iiwa_ident.datasets import sha256_file
    from iiwa_ident.ident import write_model
    from iiwa_ident.model import Source

    ext = result.extended
    ext.sources = [s for s in ext.sources if s.role != "diagnose"] + [
        Source(str(p.relative_to(ctx.workdir)), sha256_file(p), "diagnose") for p in data]
    write_model(ctx.path("model_ext"), ext)
    result.model_out = FILES["model_ext"]
    write_atomic(ctx.path("diagnose_json"), json.dumps(_jsonable(result.as_json()), indent=2) + "\n")
    ctx.results["diagnosis"] = result
    return diagnosis_headline(result)


def diagnosis_headline(result: Any) -> dict[str, Any]:
    """The diagnose stage's headline figures of a :class:`~iiwa_ident.diagnose.Diagnosis`."""
    from iiwa_ident.diagnose import undecided_sentence

    return {"explained": result.explained,
            "unexplained_channels": [f"{c.dataset}/{c.channel}" for c in result.unexplained_channels],
            "sign_reversed": list(result.sign_reversed),
            "effects": [{"name": e.name, "gain_pct": e.gain_pct, "confidence": e.confidence} for e in result.effects],
            "ambiguous": [{"name": a["name"], "or_shape_of": a["or_shape_of"], "gain_pct": a["gain_pct"]}
                          for a in result.ambiguous],
            "replaced": [{"old": r["old"], "new": r["new"]} for r in result.replaced],
            "undecided": [{"name": u["name"], "or_shape_of": u["or_shape_of"], "said": undecided_sentence(u)}
                          for u in result.undecided],
            "channels": [{"dataset": c.dataset, "channel": c.channel, "gain_pct": c.gain_pct} for c in result.channels]}


#: The stages in the order they run.
STAGES: tuple[Stage, ...] = (
    Stage("chirp", "exponential chirp", (), ("chirp",), _stage_chirp),
    Stage("fit", "transfer-function fit, eq (4)", ("chirp",), ("model", "fit_json", "fit_result"), _stage_fit),
    Stage("constant_velocity", "constant-velocity (and quasi-static) runs", (), ("cv", "qs"), _stage_cv),
    Stage("hand_guided", "hand-guided record", (), ("hand",), _stage_hand),
    Stage("ripple", "ripple period and lookup table, and the fit with it", ("fit", "constant_velocity"),
          ("model_ripple", "ripple_json", "fit_ripple_json", "ripple_result"), _stage_ripple),
    Stage("design", "additive controller, kappa margins, observers", ("ripple",),
          ("design", "design_json", "observers_json"), _stage_design),
    Stage("deploy", "controller config and safety checks", ("design",), ("controller", "controller_json"),
          _stage_deploy),
    Stage("validation", "closed loop through FRI: built-in against additive", ("deploy",),
          ("validation_dir", "validation_json"), _stage_validation),
    Stage("diagnose", "discrepancy diagnosis", ("ripple",), ("diagnose_json", "model_ext"), _stage_diagnose),
)


def _headline(records: list[StageRecord]) -> dict[str, Any]:
    """The figures the summary prints, from the stage records."""
    by = {r.name: r for r in records}
    out: dict[str, Any] = {}

    def ok(name: str) -> dict[str, Any] | None:
        r = by.get(name)
        return r.headline if r is not None and r.status == "ok" else None

    if (h := ok("fit")) is not None:
        out["fit"] = {k: {kk: v[kk] for kk in ("value", "std", "rel_std_pct", "error_pct") if kk in v}
                      for k, v in h["parameters"].items()}
    if (h := ok("ripple")) is not None:
        if "refit" in h:
            out["fit_ripple"] = {k: {kk: v[kk] for kk in ("value", "std", "rel_std_pct", "error_pct", "error_std")
                                     if kk in v} for k, v in h["refit"]["parameters"].items()}
        out["ripple_period_rad"] = h["period_rad"]
        out["ripple_period_std_rad"] = h["period_std_rad"]
        if "period_rel_error" in h:
            out["ripple_period_rel_error"] = h["period_rel_error"]
    if (h := ok("design")) is not None:
        out["kappa_linear"] = {"builtin": h["kappa_max_builtin"], "additive": h["kappa_max_additive"],
                               "ratio": h["kappa_ratio"]}
        if h.get("observer"):
            out["observer_improvement"] = h["observer"]["improvement"]
    if (h := ok("validation")) is not None:
        out["tracking"] = h["tracking"]
        out["kappa_live"] = h["kappa_live"]
    if (h := ok("diagnose")) is not None:
        out["named_effects"] = h["effects"]
        out["model_explained"] = h["explained"]
        out["unexplained_channels"] = h.get("unexplained_channels", [])
        out["sign_reversed"] = h.get("sign_reversed", [])
        out["ambiguous_effects"] = h.get("ambiguous", [])
        out["replaced_effects"] = h.get("replaced", [])
        out["undecided_effects"] = h.get("undecided", [])
    return out


def _diagnosis_lines(h: dict[str, Any]) -> list[str]:
    """The summary's lines of the diagnosis (from the headline)."""
    lines: list[str] = []
    for r in h.get("sign_reversed", []):
        lines.append(f"diagnosis: the torque's sign is reversed in {r['dataset']} (re-import it with --scale "
                     f"tau_j=-1)")
    for r in h.get("replaced_effects", []):
        lines.append(f"diagnosis: the model's {r['old']} contradicted by the data, replaced by "
                     f"{' + '.join(r['new'])}")
    left = h.get("unexplained_channels", [])
    if not h["named_effects"] and not h.get("replaced_effects"):
        lines.append("diagnosis: the model explains the data, no effect named" if h["model_explained"] else
                     "diagnosis: the model does not explain the data, but no effect passed every test "
                     "(diagnose.json: suspects, unexplained_channels)")
    for e in h["named_effects"]:
        lines.append(f"diagnosis: {e['name']} named, held-out residual {e['gain_pct']:.1f} % lower")
    for u in h.get("undecided_effects", []):
        lines.append(f"diagnosis: undecided: {u['said']}" if "said" in u else
                     f"diagnosis: {u['name']} kept, but another shape of {u['or_shape_of']} predicts the data as "
                     f"well (a longer travel of the link decides)")
    if left:
        lines.append(f"diagnosis: the residual fails its tests on {len(left)} channel(s) (" + ", ".join(left[:3])
                     + (", ..." if len(left) > 3 else "") + ")")
    for a in h.get("ambiguous_effects", []):
        lines.append(f"diagnosis: {a['name']} not named: the data do not tell it from another shape of "
                     f"{a['or_shape_of']} ({a['gain_pct']:.1f} % lower with it)")
    return lines


def format_summary(result: PipelineResult) -> str:
    """The summary printed at the end of ``iiwa-ident pipeline``: stages and headline figures."""
    lines = ["", "stage               status    time [s]  note"]
    for s in result.stages:
        note = s.error if s.status != "ok" else ""
        lines.append(f"  {s.name:<18}{s.status:<10}{s.duration_s:>8.1f}  {note}")
    h = result.headline
    lines.append("")
    for key, title in (("fit", "fit"), ("fit_ripple", "fit with the ripple table")):
        if key not in h:
            continue
        parts = []
        for k, v in h[key].items():
            if "error_pct" in v:
                parts.append(f"{k} {v['error_pct']:+.3f} % (std {v['rel_std_pct']:.3f} %)")
            else:
                parts.append(f"{k} std {v['rel_std_pct']:.3f} %")
        lines.append(f"{title}: " + ", ".join(parts) + (" (error against the simulated plant)" if any(
            "error_pct" in v for v in h[key].values()) else ""))
    if h.get("ripple_period_rad") is not None:
        extra = f", error {h['ripple_period_rel_error']:+.1e} relative" if "ripple_period_rel_error" in h else ""
        lines.append(f"ripple period rho = {h['ripple_period_rad']:.6f} rad (std {h['ripple_period_std_rad']:.1e}{extra}; paper 0.01963)")
    if "observer_improvement" in h:
        lines.append(f"observer: built-in over filtered RMS error (fast motion, lag-matched) = "
                     f"{h['observer_improvement']:.2f}x")
    if "kappa_linear" in h:
        k = h["kappa_linear"]
        lines.append(f"kappa_max (linear, exact delay): built-in {k['builtin']:.2f}, additive "
                     f"{k['additive'] if k['additive'] is None else round(k['additive'], 2)}, ratio "
                     f"{k['ratio'] if k['ratio'] is None else round(k['ratio'], 2)} (paper: 4.6 and stable at 15)")
    for source, kl in (h.get("kappa_live") or {}).items():
        def f(x):
            return "-" if x is None else f"{x:.2f}"
        b, a = kl["builtin"], kl["additive"]
        lines.append(f"kappa live through FRI ({source}): built-in stable to {f(b['live_limit'])} (linear "
                     f"{f(b['linear_limit'])}), additive to {f(a['live_limit'])} (linear {f(a['linear_limit'])}); "
                     f"ratio live {f(kl['ratio_live'])}, linear {f(kl['ratio_linear'])} (paper: 15 / 4.6 = 3.3)")
    for task, row in h.get("tracking", {}).items():
        if task == "step" and row.get("builtin_overshoot_pct") is not None \
                and row.get("additive_overshoot_pct") is not None:
            # Steps are judged by their overshoot, as in Fig. 8; the peak error mixes in the ringing after it.
            lines.append(f"step: overshoot built-in {row['builtin_overshoot_pct']:.0f} %, additive "
                         f"{row['additive_overshoot_pct']:.0f} % (RMS error {row['builtin_rms_error_nm']:.1f} "
                         f"against {row['additive_rms_error_nm']:.1f} Nm)")
        else:
            lines.append(f"{task}: peak error built-in {row['builtin_peak_error_nm']:.1f} Nm, additive "
                         f"{row['additive_peak_error_nm']:.1f} Nm (RMS {row['builtin_rms_error_nm']:.1f} against "
                         f"{row['additive_rms_error_nm']:.1f} Nm)")
    if "named_effects" in h:
        lines += _diagnosis_lines(h)
    if h.get("data") == "measured":
        lines.append(f"measured data: {len(h.get('runs', []))} run(s): {', '.join(h.get('runs', []))}")
        if "ripple_decided" in h:
            lines.append("ripple: " + ("period decided from the runs" if h["ripple_decided"] else
                                       "no period decided from these runs (ripple.json says why)"))
        for r in h.get("held_out", []):
            lines.append(f"held out: {r['run']} predicted from the other runs, RMS {r['before_nm']:.3g} -> "
                         f"{r['after_nm']:.3g} Nm (starting model -> extended)")
    if result.report is not None:
        lines.append(f"report: {result.report}")
    lines.append(f"wall time {result.wall_s:.1f} s")
    return "\n".join(lines)


def read_pipeline_json(workdir: Path) -> dict[str, Any] | None:
    """``pipeline.json`` of a work folder, or None when there is none."""
    path = Path(workdir) / FILES["pipeline_json"]
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise IiwaIdentError(f"{path}: cannot read ({err})") from None


def _sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _inputs(ctx: PipelineContext) -> dict[str, str]:
    """The inputs and their sha256: the plant file (or the shipped default plant's text) or the robot address."""
    if ctx.target == "robot":
        return {"robot": f"{ctx.robot} ({ctx.robot_model}, joint {ctx.joint})"}
    if ctx.plant_file is not None:
        return {"plant": str(ctx.plant_file), "plant_sha256": _sha256_bytes(Path(ctx.plant_file).read_bytes())}
    from importlib import resources

    text = resources.files("iiwa_ident").joinpath("data/default_plant.toml").read_bytes()
    return {"plant": "default plant (iiwa_ident/data/default_plant.toml)", "plant_sha256": _sha256_bytes(text)}


def run_pipeline(workdir: str | Path, target: str = "sim", plant: str | Path | None = None,
                 robot: str | None = None, short: bool = False, progress: Callable[[str], None] = print, *,
                 port: int = 30200, robot_model: str = "iiwa14", joint: int = 1,
                 settings: PipelineSettings | None = None, report: Callable[..., list] | None = None,
                 skip: tuple[str, ...] = (), realtime: bool = False) -> PipelineResult:
    """Run every stage in order, write ``pipeline.json`` (and with ``report``, ``report.pdf``) into ``workdir``.

    Parameters
    ----------
    workdir : path
        Work folder (created); every intermediate file goes there under the
        names of :data:`FILES`.
    target : str
        ``"sim"`` (simulated joint, validation against the FRI emulator) or
        ``"robot"`` (every experiment and the validation over FRI on ``robot``).
    plant : path, optional
        Plant file of the simulated joint (default plant when None).
    robot : str, optional
        ``HOST[:PORT]`` of the robot controller (robot target).
    short : bool
        Use :meth:`PipelineSettings.short` (tests) instead of :meth:`PipelineSettings.full`.
    progress : callable
        Receives one line per stage and per closed-loop run.
    port, robot_model, joint
        Local FRI port, robot model and joint under test (robot target).
    settings : PipelineSettings, optional
        Overrides ``short``.
    report : callable, optional
        Builds ``report.pdf`` at the end, called as ``report(pdf_path, workdir,
        pipeline_json, results)`` and returning its pages
        (:func:`iiwa_ident.report.build_report`, passed in by the caller: the
        report reads the pipeline's files, so it sits above the pipeline).
    skip : tuple of str
        Stages not to run (recorded as skipped, as are the stages that need them).
    realtime : bool
        Sim target: run the validation's robot emulator in real time instead
        of in lockstep (:mod:`iiwa_ident.emulator._clocks`, "Lockstep"). Lockstep
        figures are exactly repeatable and independent of the machine's load;
        real time adds what a loaded machine does to the loop.

    Returns
    -------
    PipelineResult

    Raises
    ------
    IiwaIdentError
        For a bad argument (unknown target, missing robot address, a plant
        file that does not load); failures inside stages are recorded instead.
    """
    from iiwa_ident._blas import single_threaded_blas

    with single_threaded_blas():
        return _run_pipeline(workdir, target, plant, robot, short, progress, port, robot_model, joint, settings,
                             report, skip, realtime)


def _run_pipeline(workdir, target, plant, robot, short, progress, port, robot_model, joint, settings, report,
                  skip, realtime) -> PipelineResult:
    t_start = time.perf_counter()
    if target not in ("sim", "robot"):
        raise IiwaIdentError(f"--target {target}: expected 'sim' or 'robot'")
    if target == "robot" and not robot:
        raise IiwaIdentError("--target robot needs --robot HOST (the robot controller's address)")
    if target == "robot" and plant is not None:
        raise IiwaIdentError("--plant only applies to --target sim")
    if target == "robot" and realtime:
        raise IiwaIdentError("--realtime only applies to --target sim (the robot is always real time)")
    unknown = [name for name in skip if name not in {st.name for st in STAGES}]
    if unknown:
        raise IiwaIdentError(f"--skip {unknown[0]}: unknown stage (known: {', '.join(st.name for st in STAGES)})")
    workdir = Path(workdir)
    if workdir.exists() and not workdir.is_dir():
        raise IiwaIdentError(f"{workdir}: exists and is not a folder")
    workdir.mkdir(parents=True, exist_ok=True)
    settings = settings or (PipelineSettings.short() if short else PipelineSettings.full())
    ctx = PipelineContext(workdir=workdir, target=target, plant_file=Path(plant) if plant else None, robot=robot,
                          port=port, robot_model=robot_model, joint=joint, realtime=realtime, settings=settings,
                          progress=progress)
    if target == "sim":
        ctx.plant  # noqa: B018  (a bad plant file is an argument error, reported before anything runs)
    return run_stages(ctx, STAGES, _inputs(ctx), skip=skip, report=report, t_start=t_start)


def run_stages(ctx: PipelineContext, stages: tuple[Stage, ...], inputs: dict[str, Any], *, skip: tuple[str, ...] = (),
               report: Callable[..., list] | None = None, t_start: float | None = None,
               headline: Callable[[list[StageRecord]], dict[str, Any]] | None = None) -> PipelineResult:
    """Run ``stages`` in order on ``ctx``, then the report; write ``pipeline.json``.

    A stage that raises is recorded as failed with its one-line message (:class:`StageSkipped`: skipped, with
    its reason), and the stages that need it are skipped. ``headline`` turns the records into the headline
    figures (default: the simulated pipeline's).
    """
    t_start = time.perf_counter() if t_start is None else t_start
    progress = ctx.progress
    n = len(stages) + (1 if report else 0)
    status: dict[str, str] = {}
    for i, stage in enumerate(stages, 1):
        blocked = [d for d in stage.needs if status.get(d) != "ok"]
        if stage.name in skip:
            rec = StageRecord(name=stage.name, title=stage.title, status="skipped", error="skipped on request")
            progress(f"[{i}/{n}] {stage.name}: skipped on request")
        elif blocked:
            rec = StageRecord(name=stage.name, title=stage.title, status="skipped",
                              error=f"skipped: needs {', '.join(blocked)}, which did not succeed")
            progress(f"[{i}/{n}] {stage.name}: skipped ({', '.join(blocked)} did not succeed)")
        else:
            progress(f"[{i}/{n}] {stage.name}: {stage.title} ...")
            t0 = time.perf_counter()
            try:
                headline_ = stage.run(ctx)
                rec = StageRecord(name=stage.name, title=stage.title, status="ok", headline=_jsonable(headline_))
            except StageSkipped as why:
                rec = StageRecord(name=stage.name, title=stage.title, status="skipped", error=f"skipped: {why}")
            except IiwaIdentError as err:
                rec = StageRecord(name=stage.name, title=stage.title, status="failed", error=str(err))
            except Exception as err:  # noqa: BLE001  (a bug in one stage must not cost the report)
                where = traceback.extract_tb(err.__traceback__)[-1]
                rec = StageRecord(name=stage.name, title=stage.title, status="failed",
                                  error=f"{type(err).__name__}: {err} ({Path(where.filename).name}:{where.lineno})")
            rec.duration_s = time.perf_counter() - t0
            rec.outputs = [FILES[k] for k in stage.outputs if ctx.path(k).exists()]
            progress(f"[{i}/{n}] {stage.name}: {rec.error}" if rec.status == "skipped" else
                     f"[{i}/{n}] {stage.name}: {rec.status} in {rec.duration_s:.1f} s"
                     + (f": {rec.error}" if rec.status == "failed" else ""))
        status[stage.name] = rec.status
        ctx.records.append(rec)
    result = PipelineResult(ctx.workdir, ctx.records, (headline or _headline)(ctx.records), None, 0.0, inputs)
    if report is not None:
        progress(f"[{n}/{n}] report: PDF of every stage ...")
        t0 = time.perf_counter()
        rec = StageRecord(name="report", title="PDF report", status="ok")
        try:
            result.wall_s = time.perf_counter() - t_start
            pages = report(ctx.path("report"), ctx.workdir, result.as_json(), ctx.results)
            rec.headline = {"pages": len(pages)}
            result.report = ctx.path("report")
        except IiwaIdentError as err:
            rec.status, rec.error = "failed", str(err)
        except Exception as err:  # noqa: BLE001  (a bug in the report must not cost the stages' files)
            rec.status, rec.error = "failed", f"{type(err).__name__}: {err}"
        rec.duration_s = time.perf_counter() - t0
        rec.outputs = [FILES["report"]] if ctx.path("report").exists() else []
        progress(f"[{n}/{n}] report: {rec.status} in {rec.duration_s:.1f} s"
                 + (f": {rec.error}" if rec.error else f" ({rec.headline['pages']} pages)"))
        ctx.records.append(rec)
    result.wall_s = time.perf_counter() - t_start
    write_atomic(ctx.path("pipeline_json"), json.dumps(_jsonable(result.as_json()), indent=2) + "\n")
    return result
