"""The FRI runtime: a deployed controller config executed once per 1 kHz cycle.

Per cycle, for the controlled joint (:meth:`ControllerRuntime.cycle`):

1. eqs (8)-(15) of the one control cycle, :class:`~iiwa_ident.design.ControlCycle`
   (position correction, spatial filter, improved observer);
2. the task's reference ``tau_r``, limited in rate and size;
3. the additive controller, eqs (16)-(18), again by the control cycle;
4. the watchdog / shutdown scale, then limits on torque rate and torque,
   and a last check that the number is finite.

:func:`run_controller` drives the cycle against any
:class:`~iiwa_ident.robot.RobotInterface` (the robot through
:class:`~iiwa_ident.fri.FriRobot`, the emulator the same way, or the
simulated joint directly), logs every cycle through the background
:class:`~iiwa_ident.datasets.LogWriter` and stops cleanly on SIGINT
and SIGTERM.

Choices
-------
* Torque offset: the control cycle regulates ``tau_J`` relative to its value
  at the first cycle (gravity on a joint whose load does not change during
  the run, sensor offset). For a joint whose gravity load changes with the
  motion, command that joint's gravity model on top.
* Watchdog: when ``watchdog_cycles`` (default 3) or more robot messages in a
  row were lost, or arrived that late, the additive torque ramps to zero
  over ``ramp_s`` (default 20 ms) and stays there until the link has been
  good for ``recover_cycles`` (default 100); the controller then restarts
  from rest and ramps back in. Each trip and recovery is reported. The run
  ends when the robot interface reports a longer silence (FRI: its
  ``message_timeout_s``, ``iiwa-ident run --silence-limit``, default 1 s) or the
  robot leaves the commanding state.
* Shutdown (end of the duration, SIGINT, SIGTERM, over-speed, a non-finite
  controller output): the additive torque ramps to zero over ``ramp_s``
  while the session goes on, then the run ends and the log is closed.
"""

from __future__ import annotations

import contextlib
import math
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from iiwa_ident._defaults import LOOPS, TAU_EXT_SOURCES
from iiwa_ident._realtime import no_gc_pauses, realtime_process, stop_signals
from iiwa_ident.datasets import LogWriter
from iiwa_ident.deploy import ControllerConfig, controller_from_config
from iiwa_ident.description import flange_axis
from iiwa_ident.design import ControlCycle
from iiwa_ident.errors import IiwaIdentError, SafetyStop
from iiwa_ident.netft import JointAxisProjection, NetFtSensor
from iiwa_ident.robot import Command, Measurement, RobotInterface
from iiwa_ident.runtime._tasks import Task, TaskInput

__all__ = ["LOG_SIGNALS", "Watchdog", "ControllerRuntime", "RunReport", "run_controller"]

#: Signals of a run log, in column order (dataset format v1 names).
LOG_SIGNALS = ("t", "q_m", "tau_j", "tau_ext_fri", "tau_c", "tau_r", "tau_j_filt", "tau_ext_est", "tau_ext_loop",
               "watchdog", "cycle_us")


class Watchdog:
    """Scale of the additive torque under lost or late robot messages.

    Parameters
    ----------
    dt : float
        Cycle [s].
    trip_cycles : int
        Lost or late cycles in a row that trip it [cycles].
    ramp_s : float
        Time to ramp the scale from 1 to 0 (and back) [s].
    recover_cycles : int
        Good cycles after which a tripped watchdog ramps back in [cycles].
    """

    def __init__(self, dt: float = 1e-3, trip_cycles: int = 3, ramp_s: float = 0.02, recover_cycles: int = 100) -> None:
        if trip_cycles < 1 or ramp_s < 0 or recover_cycles < 1:
            raise IiwaIdentError("watchdog: trip cycles and recover cycles must be >= 1, the ramp >= 0")
        self.dt, self.trip_cycles, self.recover_cycles = dt, int(trip_cycles), int(recover_cycles)
        self.step_per_cycle = 1.0 if ramp_s == 0 else min(1.0, dt / ramp_s)
        self.scale = 1.0
        self.tripped = False
        self._good = 0
        self.events: list[tuple[float, str]] = []  #: (time [s], what happened)

    def update(self, t: float, gap_cycles: float) -> bool:
        """Advance one cycle; ``gap_cycles`` = robot cycles since the previous message (1 normally).

        Returns True when the watchdog recovered in this cycle (the controller should restart).
        """
        recovered = False
        if gap_cycles >= self.trip_cycles:
            self._good = 0
            if not self.tripped:
                self.tripped = True
                self.events.append((t, f"tripped: {gap_cycles:.0f} cycles since the previous robot message"))
        elif self.tripped:
            self._good += 1
            if self._good >= self.recover_cycles:
                self.tripped = False
                recovered = True
                self.events.append((t, f"recovered after {self.recover_cycles} good cycles"))
        target = 0.0 if self.tripped else 1.0
        if self.scale < target:
            self.scale = min(target, self.scale + self.step_per_cycle)
        elif self.scale > target:
            self.scale = max(target, self.scale - self.step_per_cycle)
        return recovered


class ControllerRuntime:
    """One joint's controller cycle from a deployed config (module docstring).

    Parameters
    ----------
    config : ControllerConfig
        The deployed controller (from :func:`~iiwa_ident.deploy.read_config`).
    task : Task
        The reference program.
    watchdog : Watchdog, optional
        Default: 3 cycles, 20 ms ramp, 100 cycles to recover.
    tau_ext : str
        The external torque the task sees: ``"estimate"`` (the runtime's eq (14)), ``"fri"`` (KUKA's
        estimate in the monitoring message, relative to its value at the start: it carries the
        robot model's static error) or ``"ft"`` (``sensor``'s torque about the joint's axis).
    sensor : NetFtSensor, optional
        The F/T sensor of ``tau_ext="ft"``, started by the caller and polled once per cycle; its
        fault (records missing or bad past its limit) ramps the output out and ends the run.
    loop : str
        ``"additive"``: the deployed controller, eqs (16)-(18); ``"builtin"``: the reference itself
        is the command (the robot's own torque loop), with the same limits, watchdog and log.
    """

    def __init__(self, config: ControllerConfig, task: Task, watchdog: Watchdog | None = None, *,
                 tau_ext: str = "estimate", sensor: NetFtSensor | None = None, loop: str = "additive") -> None:
        if tau_ext not in TAU_EXT_SOURCES:
            raise IiwaIdentError(f"unknown external-torque source {tau_ext!r} (known: {', '.join(TAU_EXT_SOURCES)})")
        if (tau_ext == "ft") != (sensor is not None):
            raise IiwaIdentError("the F/T source needs a sensor, and a sensor is only read with the F/T source")
        if loop not in LOOPS:
            raise IiwaIdentError(f"unknown loop {loop!r} (known: {', '.join(LOOPS)})")
        self.tau_ext_source, self.sensor, self.loop = tau_ext, sensor, loop
        self._fri_offset = 0.0
        self.tau_ext_loop = 0.0  #: the last cycle's external torque from the run's source [Nm]
        self.config, self.task = config, task
        self.dt = config.sample_time_s
        self.watchdog = watchdog or Watchdog(self.dt)
        lim = config.limits
        self._tau_max, self._ref_max = lim.torque_nm, lim.reference_nm
        self._dtau_max, self._dref_max = lim.torque_rate_nm_s * self.dt, lim.reference_rate_nm_s * self.dt
        self._v_max = lim.velocity_rad_s
        self.control = ControlCycle(controller_from_config(config), filter=config.filter, dt=self.dt,
                                    ripple=config.ripple, K=config.K, KI=config.KI, Jl=config.Jl)
        self.stop_reason = ""  #: why the output is ramping out ("" while running)
        self._shutdown = 1.0  # scale of the shutdown ramp
        self._ref_prev = 0.0
        self._input = TaskInput(0.0, 0.0, 0.0)  # updated in place each cycle
        # Last cycle's values, for the log.
        self.tau_c = self.tau_r = 0.0

    @property
    def tau_j_filt(self) -> float:
        """The last cycle's filtered joint torque, offset removed [Nm]."""
        return self.control.tau_j_filt

    @property
    def tau_ext(self) -> float:
        """The last cycle's filtered external-torque estimate [Nm]."""
        return self.control.tau_ext

    def request_stop(self, reason: str) -> None:
        """Ramp the additive torque out and end the run (the first reason is kept)."""
        if not self.stop_reason:
            self.stop_reason = reason

    @property
    def finished(self) -> bool:
        """True once a requested stop has ramped the output to zero."""
        return bool(self.stop_reason) and self._shutdown == 0.0 and self.tau_c == 0.0

    def _restart(self, meas: Measurement) -> None:
        """Start (or restart after a watchdog trip) from rest at this measurement."""
        self.control.restart(meas)
        self._ref_prev = 0.0
        self._fri_offset = meas.tau_ext_fri

    def cycle(self, meas: Measurement, gap_cycles: float = 1.0) -> float:
        """One cycle: measurement -> additive torque to send [Nm] (finite, within the limits).

        Parameters
        ----------
        meas : Measurement
            This cycle's measurement of the controlled joint.
        gap_cycles : float
            Robot cycles since the previous measurement (1 when none was lost or late).
        """
        control = self.control
        if not control.started:
            self._restart(meas)
            self.tau_c = 0.0
            return 0.0
        control.observe(meas, gap_cycles)  # eqs (8)-(15)
        if abs(control.speed) > self._v_max:
            self.request_stop(f"joint speed {control.speed:.3g} rad/s above the limit {self._v_max:.3g}")

        if self.watchdog.update(meas.t, gap_cycles):
            self._restart(meas)
        src = self.tau_ext_source
        if src == "estimate":
            tau_ext = control.tau_ext
        elif src == "fri":
            tau_ext = meas.tau_ext_fri - self._fri_offset
        else:
            sensor = self.sensor
            assert sensor is not None  # the constructor refuses the F/T source without its sensor
            sensor.poll()
            tau_ext = sensor.tau
            if sensor.fault:
                self.request_stop(sensor.fault)
        self.tau_ext_loop = tau_ext
        task_in = self._input
        task_in.t, task_in.theta_j, task_in.tau_ext = meas.t, control.theta_j, tau_ext
        task_in.tau_j = meas.tau_j - control.tau_offset
        ref = self.task.reference(task_in)
        if self.task.done:
            self.request_stop(self.task.done)
        if not math.isfinite(ref):
            self.request_stop("the task gave a non-finite reference")
            ref = 0.0
        # Reference limits: rate, then size (the deploy check's reference_range assumes both).
        ref = min(max(ref, self._ref_prev - self._dref_max), self._ref_prev + self._dref_max)
        ref = min(max(ref, -self._ref_max), self._ref_max)
        self._ref_prev = self.tau_r = ref
        out = control.command(ref) if self.loop == "additive" else ref  # eqs (16)-(18), or the built-in loop
        if not math.isfinite(out):
            self.request_stop("the controller gave a non-finite torque")
            control.controller.reset()
            out = 0.0
        if self.stop_reason:
            self._shutdown = max(0.0, self._shutdown - self.watchdog.step_per_cycle)
        out *= self.watchdog.scale * self._shutdown
        # Command limits: rate against what was sent last, then size.
        prev = self.tau_c
        out = min(max(out, prev - self._dtau_max), prev + self._dtau_max)
        out = min(max(out, -self._tau_max), self._tau_max)
        if self._shutdown == 0.0 and abs(out) <= self._dtau_max:
            out = 0.0
        self.tau_c = out if math.isfinite(out) else 0.0
        return self.tau_c


@dataclass(kw_only=True)
class RunReport:
    """Outcome of :func:`run_controller`.

    Attributes
    ----------
    cycles : int
        Cycles executed.
    duration_s : float
        Time covered [s].
    stop_reason : str
        Why the run ended ("duration" when it ran its course).
    ended_early : bool
        Whether the run ended before its duration for a fault: the robot side ended the session (left
        COMMANDING_ACTIVE, fell silent, stopped itself) or the runtime's own limits did (over-speed, a
        non-finite value, the F/T sensor); not when the task finished or a signal stopped it.
    watchdog_events : list of (float, str)
        Watchdog trips and recoveries (time [s], text).
    compute_us : dict
        Per-cycle compute time from receiving a message to sending its answer:
        median, p99, p99.9 and max [us].
    logged : int
        Rows written to the log.
    lost_log_rows : int
        Rows the background writer could not take.
    connection : dict
        Datagram counters of the FRI connection (empty on a simulated joint).
    log : str
        Log file.
    first_answer_s : float or None
        FRI: time from opening the socket to the first answer to the robot [s].
    sensor : dict
        The F/T sensor's record counters (:class:`~iiwa_ident.netft.SensorStats`; empty without one).
    """

    cycles: int
    duration_s: float
    stop_reason: str
    ended_early: bool = False
    watchdog_events: list[tuple[float, str]] = field(default_factory=list)
    compute_us: dict[str, float] = field(default_factory=dict)
    logged: int = 0
    lost_log_rows: int = 0
    connection: dict[str, int] = field(default_factory=dict)
    log: str = ""
    first_answer_s: float | None = None
    sensor: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready form."""
        return {"cycles": self.cycles, "duration_s": self.duration_s, "stop_reason": self.stop_reason,
                "ended_early": self.ended_early, "watchdog_events": [[t, e] for t, e in self.watchdog_events], "compute_us": self.compute_us,
                "logged": self.logged, "lost_log_rows": self.lost_log_rows, "connection": self.connection,
                "log": self.log, "first_answer_s": self.first_answer_s, "sensor": self.sensor}


def _percentiles(ns: np.ndarray) -> dict[str, float]:
    if len(ns) == 0:
        return {}
    us = ns / 1e3
    return {"median": float(np.median(us)), "p99": float(np.percentile(us, 99)),
            "p99_9": float(np.percentile(us, 99.9)), "max": float(us.max())}


class _StopFlag:
    """SIGINT/SIGTERM set a flag instead of raising, so the loop can ramp out and flush the log."""

    def __init__(self) -> None:
        self.flag = ""

    def __call__(self, signum, frame) -> None:
        self.flag = signal.Signals(signum).name


def _check_run(config: ControllerConfig, robot: RobotInterface, duration_s: float,
               sensor: NetFtSensor | None) -> None:
    """Refuse a run the config does not fit (another joint, another cycle), of no length, or with a sensor
    whose projection cannot be had; load the description's model a sensor will need."""
    if robot.joint != config.joint:
        raise IiwaIdentError(f"the config controls joint {config.joint}, the robot interface joint {robot.joint}")
    if abs(robot.sample_time_s - config.sample_time_s) > 1e-12:
        raise IiwaIdentError(f"the config runs at {config.sample_time_s * 1e3:g} ms, the robot at "
                             f"{robot.sample_time_s * 1e3:g} ms")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise IiwaIdentError(f"duration must be positive, got {duration_s!r}")
    if sensor is not None and sensor.projection is None:
        if not hasattr(robot, "pose"):
            raise IiwaIdentError("the F/T sensor's projection needs the arm's pose, which this robot interface "
                                 "does not report: give the sensor's lever arm")
        # Load the description's model now: at the first commanding message only its kinematics run.
        flange_axis(config.robot_model, config.joint, [0.0] * 7)


def run_controller(config: ControllerConfig, robot: RobotInterface, task: Task, duration_s: float,
                   log: str | Path, *, watchdog: Watchdog | None = None,
                   progress: Callable[[str], None] | None = None, realtime: bool = False,
                   cpu: int | None = None, tau_ext: str = "estimate", sensor: NetFtSensor | None = None,
                   loop: str = "additive") -> RunReport:
    """Run ``task`` through the deployed controller on ``robot`` for ``duration_s`` [s], logging every cycle.

    Parameters
    ----------
    config : ControllerConfig
        The deployed controller; its joint must be the robot's.
    robot : RobotInterface
        :class:`~iiwa_ident.fri.FriRobot` (robot or emulator) or a simulated joint.
    task : Task
        The reference program.
    duration_s : float
        Run length [s], not counting the final ramp-out.
    log : path
        Log file (dataset format v1, experiment ``free``, written in the background).
    watchdog : Watchdog, optional
        Default: :class:`Watchdog` with its defaults.
    progress : callable, optional
        Called with one-line status messages (start, watchdog events, stop).
    realtime : bool
        For the run, pin the process to one CPU, run it under ``SCHED_FIFO``
        and lock its memory where permitted (:func:`iiwa_ident._realtime.realtime_process`;
        one line through ``progress`` says what was set and what was not).
        Undone when the run ends.
    cpu : int, optional
        With ``realtime``: the CPU (default: the highest one allowed; -1 leaves
        the affinity alone).
    tau_ext, sensor, loop : str, NetFtSensor or None, str
        The external-torque source, its F/T sensor and the torque loop (:class:`ControllerRuntime`);
        the sensor is started with the run and stopped when it ends. A sensor without a projection
        gets the flange's geometry from the robot's description at the pose the robot reports when
        commanding starts (an interface without a pose is refused).

    Returns
    -------
    RunReport
    """
    _check_run(config, robot, duration_s, sensor)
    say = progress or (lambda _msg: None)
    runtime = ControllerRuntime(config, task, watchdog, tau_ext=tau_ext, sensor=sensor, loop=loop)
    dt = config.sample_time_s
    attrs = {"controller_sha256": config.sha256, "duration_s": float(duration_s), "tau_ext_source": tau_ext,
             "loop": loop, **task.attrs()}
    if sensor is not None:
        attrs["ft_sensor"] = f"{sensor.address[0]}:{sensor.address[1]}"
    writer = LogWriter(log, LOG_SIGNALS, experiment="free", source=robot.source, joint=config.joint,
                       sample_rate_hz=1.0 / dt, experiment_attrs=attrs)
    n_max = int(round(duration_s / dt))
    compute = np.zeros(n_max + 1000, dtype=np.int64)  # the final ramp-out adds at most ramp_s
    k = 0
    reason = ""
    events_seen = 0
    # The writer's process starts beside the session: the robot is answered from its first message (it
    # may be sending already) while a new interpreter imports numpy and h5py; the ring keeps the rows.
    writer.start(wait=False)
    try:
        signals = _StopFlag()
        with stop_signals(signals), no_gc_pauses(), \
                (realtime_process(cpu, say=say) if realtime else contextlib.nullcontext()):
            if sensor is not None:
                sensor.start()
            meas = robot.start()
            if sensor is not None:
                if sensor.projection is None:
                    sensor.projection = JointAxisProjection.from_description(
                        config.robot_model, config.joint, robot.pose)  # type: ignore[attr-defined]  # _check_run: it has one
                sensor.flush()  # records of the wait for commanding are no measurement of this run
            say(f"commanding: {task.name} for {duration_s:g} s ({loop} loop, external torque: {tau_ext})")
            last_ns = time.perf_counter_ns()
            while True:
                # Robot cycles since the previous message: lost, or skipped because they came late.
                gap = 1.0 + robot.missed_cycles
                if signals.flag:
                    runtime.request_stop(signals.flag)
                elif k >= n_max:
                    runtime.request_stop("duration")
                tau = runtime.cycle(meas, gap)
                if len(runtime.watchdog.events) > events_seen:
                    for t_ev, text in runtime.watchdog.events[events_seen:]:
                        say(f"watchdog at {t_ev:.3f} s: {text}")
                    events_seen = len(runtime.watchdog.events)
                writer.append((meas.t, meas.q_m, meas.tau_j, meas.tau_ext_fri, tau, runtime.tau_r,
                               runtime.tau_j_filt, runtime.tau_ext, runtime.tau_ext_loop, runtime.watchdog.scale,
                               compute[k - 1] / 1e3 if k else 0.0))
                if runtime.finished or k >= len(compute):
                    break
                own_ns = time.perf_counter_ns() - last_ns
                try:
                    meas = robot.step(Command(tau_c=tau))
                except SafetyStop as err:
                    reason = str(err)
                    say(f"stopped: {reason}")
                    break
                last_ns = time.perf_counter_ns()
                # The interface's own receive-to-send time when it measures one (FRI), else the loop's.
                compute[k] = robot.last_compute_ns or own_ns
                k += 1
    finally:
        robot.stop()
        if sensor is not None:
            sensor.stop()
        stats = writer.close({"stop_reason": reason or runtime.stop_reason,
                              "watchdog_events": "; ".join(f"{t:.3f} s {e}" for t, e in runtime.watchdog.events),
                              **({"ft_projection": sensor.projection.source}
                                 if sensor is not None and sensor.projection is not None else {}),
                              **task.result_attrs()})
    # Ended early: before the duration, the task's end or a signal asked the runtime to stop, the robot ended the
    # session (`reason`, from its SafetyStop) or the runtime's own limits stopped it.
    early = not (runtime.stop_reason and runtime.stop_reason in ("duration", task.done, signals.flag))
    reason = reason or runtime.stop_reason
    facts = robot.describe()
    return RunReport(cycles=k, duration_s=k * dt, stop_reason=reason, ended_early=early,
                     watchdog_events=list(runtime.watchdog.events), compute_us=_percentiles(compute[:k]),
                     logged=stats.written, lost_log_rows=stats.lost, connection=facts.get("connection", {}),
                     log=str(log), first_answer_s=facts.get("first_answer_s"),
                     sensor=sensor.stats.as_dict() if sensor is not None else {})
