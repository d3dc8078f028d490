"""Closed-loop validation through the FRI runtime: built-in against additive, tracking and the kappa margin.

Every run goes through the FRI protocol: against the robot emulator over
loopback (simulated target) or against the robot (robot target). The
built-in controller is the robot's own torque loop, driven by the task's
reference as the torque command (``record`` of a :class:`StepTorque` or
:class:`SineTorque`); the additive controller is the deployed config run by
:func:`iiwa_ident.runtime.run_controller` with the same reference. The
kappa margins are measured live by the sweep of :mod:`iiwa_ident.pipeline._kappa` (the Net F/T source,
and the runtime's own estimate for comparison), each beside its linear prediction.
"""

from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident.datasets import Dataset, read_dataset, write_dataset
from iiwa_ident.deploy import ControllerConfig
from iiwa_ident.design import DesignRecord
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import SineTorque, StepTorque, record
from iiwa_ident.pipeline._kappa import run_kappa_sweep
from iiwa_ident.pipeline._session import LOCKSTEP_GUARD_S, LateFriRobot, free_udp_port, fri_robot
from iiwa_ident.references import sine, square
from iiwa_ident.runtime import SweepSettings, Watchdog, make_task, run_controller
from iiwa_ident.sim import Plant

__all__ = ["ValidationSettings", "run_validation", "tracking_metrics", "reference_of", "free_udp_port"]


@dataclass(frozen=True, kw_only=True)
class ValidationSettings:
    """Lengths and amplitudes of the validation runs.

    Attributes
    ----------
    step_nm, step_period_s, step_cycles : float, float, int
        Square wave: height [Nm], period [s], number of periods.
    sine_nm, sine_hz, sine_s : float
        Fast sine (Fig. 9): amplitude [Nm], frequency [Hz], duration [s].
    kappa : SweepSettings
        The live kappa sweeps' steps and judgement.
    kappa_sources : tuple of str
        The external-torque sources swept (sim target; none skips the sweeps).
    """

    step_nm: float = 10.0
    step_period_s: float = 0.5
    step_cycles: int = 2
    sine_nm: float = 15.0
    sine_hz: float = 25.0
    sine_s: float = 1.0
    kappa: SweepSettings = field(default_factory=SweepSettings)
    kappa_sources: tuple[str, ...] = ("ft", "estimate")


def reference_of(task: str, t: np.ndarray, amplitude_nm: float, period_s: float = 1.0,
                 frequency_hz: float = 1.0) -> np.ndarray:
    """The reference torque [Nm] of a ``"step"`` or ``"sine"`` task at times ``t`` [s] (both start at t = 0)."""
    if task == "step":
        return square(np.asarray(t, float), amplitude_nm, period_s)
    if task == "sine":
        return sine(np.asarray(t, float), amplitude_nm, frequency_hz)
    raise IiwaIdentError(f"validation: no reference for task {task!r}")


def _delayed(t: np.ndarray, x: np.ndarray, delay_s: float) -> np.ndarray:
    return np.interp(t - delay_s, t, x, left=x[0])


def tracking_metrics(t: np.ndarray, tau_j: np.ndarray, tau_r: np.ndarray, task: str, delay_s: float,
                     amplitude_nm: float, period_s: float = 1.0, settle_s: float = 0.5) -> dict[str, float]:
    """Tracking errors of one run against the reference delayed by ``delay_s`` (no client removes Td).

    Parameters
    ----------
    t, tau_j, tau_r : ndarray
        Time [s], measured joint torque [Nm], reference [Nm].
    task : str
        ``"step"`` or ``"sine"``.
    delay_s : float
        FRI delay Td [s].
    amplitude_nm : float
        Step height or sine amplitude [Nm].
    period_s : float
        Square-wave period [s] (steps only).
    settle_s : float
        Start of the steady part the sine errors are taken on [s].

    Returns
    -------
    dict
        ``peak_error_nm`` and ``rms_error_nm`` on the steady part; for steps
        also ``overshoot_pct`` (largest overshoot past the new level after an
        edge, in % of the edge height 2A, first edge excluded).
    """
    ref = _delayed(t, tau_r, delay_s)
    err = tau_j - ref
    out: dict[str, float] = {}
    if task == "step":
        half = 0.5 * period_s
        edges = np.arange(half, t[-1] - 0.1, half)
        # Steady part: away from the edges, where the response has settled.
        since = np.mod(t - delay_s, half)
        steady = (since > 0.3 * half) & (t > half)
        overs = []
        for e in edges:
            after = (t >= e + delay_s) & (t < e + delay_s + min(0.3, 0.9 * half))
            if not after.any():
                continue
            level = np.median(ref[after][-5:])
            sign = np.sign(level)
            overs.append(max(0.0, float(np.max(sign * (tau_j[after] - level)))) / (2 * abs(amplitude_nm)))
        out["overshoot_pct"] = 100.0 * max(overs) if overs else math.nan
    else:
        steady = t >= min(settle_s, 0.5 * t[-1])
    if not steady.any():
        steady = np.ones_like(t, bool)
    out["peak_error_nm"] = float(np.max(np.abs(err[steady])))
    out["rms_error_nm"] = float(np.sqrt(np.mean(err[steady] ** 2)))
    return out


def _builtin_run(host: str, port: int, config: ControllerConfig, experiment, path: Path, lockstep: bool) -> Dataset:
    """The robot's own loop: the reference goes out as the torque command (with the weak position hold)."""
    ds = record(fri_robot(host, port, config.joint, config.robot_model, lockstep), experiment)
    write_dataset(path, ds)
    return ds


def _tracking_run(kind: str, host: str, port: int, config: ControllerConfig, experiment, task, duration_s: float,
                  path: Path, trip_cycles: int, lockstep: bool):
    """One tracking run: the built-in loop (its dataset, None) or the additive runtime (its log, its report)."""
    if kind == "builtin":
        return _builtin_run(host, port, config, experiment, path, lockstep), None
    rep = _additive_run(host, port, config, task, duration_s, path, trip_cycles, lockstep)
    return read_dataset(path), rep


def _additive_run(host: str, port: int, config: ControllerConfig, task, duration_s: float, path: Path,
                  trip_cycles: int, lockstep: bool):
    robot = LateFriRobot(host, port, config.joint, config.robot_model, lockstep)
    return run_controller(config, robot, task, duration_s, path,  # type: ignore[arg-type]  # a FriRobot once started
                          watchdog=Watchdog(config.sample_time_s, trip_cycles=trip_cycles))


def run_validation(config: ControllerConfig, outdir: Path, *, kappa_margins: tuple[float, float],
                   delay_s: float, target: str = "sim", plant: Plant | None = None,
                   robot: tuple[str, int] | None = None, settings: ValidationSettings = ValidationSettings(),
                   say: Callable[[str], None] = lambda _m: None, lockstep: bool = True,
                   record: DesignRecord | None = None) -> dict[str, Any]:
    """Run the validation: step and fast sine with both controllers, then the live kappa sweeps.

    Parameters
    ----------
    config : ControllerConfig
        The deployed additive controller.
    outdir : Path
        Folder of the run logs (``builtin_step.h5``, ``additive_step.h5``,
        ``builtin_sine.h5``, ``additive_sine.h5``, ``kappa_<controller>_<source>.h5``).
    kappa_margins : (float, float)
        Linear ``kappa_max`` of the built-in and the additive controller [-] (from the design).
    delay_s : float
        The model's FRI delay Td [s]; errors are taken against the reference delayed by it.
    target : str
        ``"sim"``: against the robot emulator on loopback, running ``plant``;
        ``"robot"``: against the robot at ``robot`` = (host, local port).
    plant : Plant, optional
        The emulator's simulated joint (default plant when None).
    settings : ValidationSettings
        Run lengths and amplitudes.
    say : callable
        Progress messages.
    lockstep : bool
        Sim target: the emulator runs in lockstep (it waits for each answer,
        on a virtual clock; :mod:`iiwa_ident.emulator`), so the figures
        are exactly repeatable and do not depend on the machine's load; the
        runs, each with its own emulator, then go two at a time. False:
        in real time, as the robot would; a loaded machine then shows up as
        late answers, watchdog trips and lost sessions.
    record : DesignRecord, optional
        The design the config came from: the sweeps' linear predictions (none without it).

    Returns
    -------
    dict
        JSON-ready: ``clock`` (``"lockstep"`` or ``"realtime"``), ``runs`` (per
        run: ``name``, ``controller``, ``task``, ``file``, parameters and
        metrics), ``tracking`` (per task: built-in and additive peak errors),
        ``kappa`` (the design's linear margins of section V.C and their ratio, and ``sweeps``: per
        source the result of :func:`~iiwa_ident.pipeline.run_kappa_sweep`), ``emulator`` (sim target: per
        run, what the robot side saw), ``compute_us_median`` (per
        additive run: the runtime's median compute time per cycle [us], the
        one figure that depends on the machine).
    """
    if target != "sim" and robot is None:
        raise IiwaIdentError("validation on the robot needs the robot's address")
    outdir.mkdir(parents=True, exist_ok=True)
    lockstep = lockstep and target == "sim"
    v = _Validation(config=config, outdir=outdir, delay_s=delay_s, target=target, plant=plant, robot=robot,
                    settings=settings, say=say, lockstep=lockstep, record=record)
    kb, ka = kappa_margins
    kappa_row: dict[str, Any] = {"linear_builtin": _num(kb), "linear_additive": _num(ka),
                                 "linear_ratio": _num(ka / kb) if kb > 0 else None, "sweeps": {}}
    runs: list[dict[str, Any]] = []
    compute_us: dict[str, float] = {}
    emulator_reports: list[dict[str, Any]] = []
    for job in v.run_all(v.jobs()):
        emulator_reports.extend(job.reports)
        if job.sweep_source is not None:
            kappa_row["sweeps"][job.sweep_source] = job.row
            continue
        runs.append(job.row)
        if job.compute_us is not None:
            compute_us[job.row["name"]] = job.compute_us
    if target != "sim":
        kappa_row["live_skipped"] = ("needs a person holding the arm: run 'iiwa-ident kappa --robot HOST "
                                     "--tau-ext ft --ft SENSOR --i-am-holding-the-arm'")
    return {"target": target, "clock": "lockstep" if lockstep else "realtime", "delay_s": delay_s, "runs": runs,
            "tracking": _tracking_summary(runs), "kappa": kappa_row, "watchdog_trip_cycles": v.trip_cycles,
            "emulator": emulator_reports, "compute_us_median": compute_us, "settings": asdict(settings)}


@dataclass
class _Job:
    """One validation run's outcome: its row, what the robot side saw, the runtime's median compute time [us]
    (additive tracking runs), the source of a kappa sweep (None: a tracking run)."""

    row: dict[str, Any]
    reports: list[dict[str, Any]] = field(default_factory=list)
    compute_us: float | None = None
    sweep_source: str | None = None


@dataclass(frozen=True, kw_only=True)
class _Validation:
    """The runs of :func:`run_validation` (its arguments, see there)."""

    config: ControllerConfig
    outdir: Path
    delay_s: float
    target: str
    plant: Plant | None
    robot: tuple[str, int] | None
    settings: ValidationSettings
    say: Callable[[str], None]
    lockstep: bool
    record: DesignRecord | None

    @property
    def trip_cycles(self) -> int:
        """The watchdog's cycles: in real time the emulator shares this machine with the client; on a loaded
        VM it is late now and then, which the default watchdog (3 cycles) reads as a lost link. In lockstep
        no cycle is late."""
        return 5 if self.target == "sim" and not self.lockstep else 3

    def jobs(self) -> list[Callable[[], _Job]]:
        """Step and sine with both controllers, then (sim target) the kappa sweep of each source."""
        s = self.settings
        plan = [
            ("step", {"amplitude_nm": s.step_nm, "period_s": s.step_period_s},
             StepTorque(s.step_nm, s.step_period_s, s.step_cycles),
             make_task("step", s.step_nm, period_s=s.step_period_s), s.step_period_s * s.step_cycles),
            ("sine", {"amplitude_nm": s.sine_nm, "frequency_hz": s.sine_hz},
             SineTorque(s.sine_nm, s.sine_hz, s.sine_s), make_task("sine", s.sine_nm, s.sine_hz), s.sine_s),
        ]
        jobs: list[Callable[[], _Job]] = [
            functools.partial(self.tracking_run, *item, kind) for item in plan for kind in ("builtin", "additive")]
        if self.target == "sim":
            jobs += [functools.partial(self.kappa_sweep, source) for source in s.kappa_sources]
        return jobs

    def run_all(self, jobs: list[Callable[[], _Job]]) -> list[_Job]:
        """The jobs' outcomes in order: in lockstep each run has its own emulator process on a virtual clock,
        so they are independent and go two at a time (one per core; this process mostly waits for the
        emulators' answers); on the robot or in real time one at a time, as on the robot."""
        if self.lockstep:
            with ThreadPoolExecutor(max_workers=min(2, os.cpu_count() or 1)) as pool:
                return list(pool.map(lambda job: job(), jobs))
        return [job() for job in jobs]

    @contextmanager
    def robot_side(self, what: str, seed: int, reports: list) -> Iterator[tuple[str, int]]:
        """The address of the robot side for one run: the robot, or an emulator of its own."""
        from iiwa_ident.emulator import EmulatorConfig, spawn_emulator

        if self.target != "sim":
            yield self.robot  # type: ignore[misc]  # run_validation refuses the robot target without it
            return
        port = free_udp_port()
        with spawn_emulator(EmulatorConfig(client=("127.0.0.1", port), plant=self.plant, seed=seed,
                                           lockstep=self.lockstep, lockstep_guard_s=LOCKSTEP_GUARD_S)) as emu:
            try:
                yield "127.0.0.1", port
            finally:
                emu.stop()
                reports.append(_emulator_summary(what, emu.join(30.0)))

    def tracking_run(self, task: str, params: dict, experiment, rt_task, duration: float, kind: str) -> _Job:
        """One tracking run of controller ``kind`` (``"builtin"`` or ``"additive"``)."""
        path = self.outdir / f"{kind}_{task}.h5"
        t_run = time.perf_counter()
        job = _Job({"name": f"{kind}_{task}", "controller": kind, "task": task, "file": str(path.name),
                    "duration_s": duration, **params})
        row = job.row
        # A session the loaded machine lost (late messages) says nothing about the controller: retry once.
        for attempt in (1, 2):
            with self.robot_side(row["name"], 11, job.reports) as (host, port):
                ds, rep = _tracking_run(kind, host, port, self.config, experiment, rt_task, duration, path,
                                        self.trip_cycles, self.lockstep)
            t = np.asarray(ds["t"], float)
            t = t - t[0]
            if kind == "builtin":
                row["stop_reason"] = ds.experiment_attrs.get("stopped_reason", "duration")
                ref = reference_of(task, t, params["amplitude_nm"], params.get("period_s", 1.0),
                                   params.get("frequency_hz", 1.0))
            else:
                row["stop_reason"] = rep.stop_reason
                row["watchdog_events"] = len(rep.watchdog_events)
                job.compute_us = rep.compute_us.get("median", math.nan)
                ref = np.asarray(ds["tau_r"], float)
            row["attempts"] = attempt
            if not _lost_session(row["stop_reason"]):
                break
        row.update(tracking_metrics(t, np.asarray(ds["tau_j"], float), ref, task, self.delay_s,
                                    params["amplitude_nm"], params.get("period_s", 1.0)))
        self.say(f"  {kind} {task}: {duration:g} s through FRI, {row['stop_reason']}, peak error "
                 f"{row['peak_error_nm']:.1f} Nm ({time.perf_counter() - t_run:.1f} s)")
        return job

    def kappa_sweep(self, source: str) -> _Job:
        """The live kappa sweep of both controllers with the external torque from ``source``."""
        t_run = time.perf_counter()
        out = run_kappa_sweep(self.config, self.outdir, record=self.record, tau_ext=source, target="sim",
                              plant=self.plant, settings=self.settings.kappa, lockstep=self.lockstep, say=self.say)
        self.say(f"  kappa sweep ({source}): live ratio {_fmt(out['ratio_live'])}, linear "
                 f"{_fmt(out['ratio_linear'])} ({time.perf_counter() - t_run:.1f} s)")
        return _Job(out, sweep_source=source)


def _tracking_summary(runs: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per task, the built-in's and the additive's peak and RMS errors (and the step's overshoots)."""
    by = {r["name"]: r for r in runs}
    summary = {}
    for task in ("step", "sine"):
        b, a = by.get(f"builtin_{task}"), by.get(f"additive_{task}")
        if b and a:
            summary[task] = {"builtin_peak_error_nm": b["peak_error_nm"], "additive_peak_error_nm": a["peak_error_nm"],
                             "builtin_rms_error_nm": b["rms_error_nm"], "additive_rms_error_nm": a["rms_error_nm"]}
            if task == "step":
                summary[task]["builtin_overshoot_pct"] = b["overshoot_pct"]
                summary[task]["additive_overshoot_pct"] = a["overshoot_pct"]
    return summary


def _emulator_summary(what: str, report) -> dict[str, Any]:
    """What the robot side saw: session drops with their reasons, missed and late answers."""
    return {"runs": what, "session_drops": [[float(t), str(r)] for t, r in report.session_drops],
            "missed_commanding": int(report.missed_commanding), "late_answers": int(report.late_answers),
            "skipped_cycles": int(report.skipped_cycles)}


def _lost_session(reason: str) -> bool:
    """The FRI session ended early (late or lost messages), as opposed to a full run or a safety stop."""
    return reason.startswith("FRI")


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"
