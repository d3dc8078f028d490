"""Running an experiment program on a robot interface and recording it.

An :class:`Experiment` decides each cycle's command from the time and the
client-side state estimate; :func:`record` drives any
:class:`~iiwa_ident.robot.RobotInterface` with it under a
:class:`~iiwa_ident.excite.LimitGuard` and returns the dataset.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from iiwa_ident._realtime import no_gc_pauses
from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError, SafetyStop
from iiwa_ident.excite._safety import LimitGuard
from iiwa_ident.robot import Command, Measurement, RobotInterface

__all__ = ["Experiment", "ClientState", "record", "velocity_filter_coefficient"]


@dataclass
class ClientState:
    """What the client knows at a cycle.

    Attributes
    ----------
    t : float
        Time since the start [s].
    q : float
        Measured joint position ``q_m`` [rad].
    v : float
        Joint velocity from ``q_m`` differences, low-pass filtered [rad/s].
    q0 : float
        Position at the start [rad].
    meas : Measurement
        The raw measurement of this cycle.
    """

    t: float
    q: float
    v: float
    q0: float
    meas: Measurement


class Experiment:
    """Base class of experiment programs.

    Subclasses set :attr:`name` (the dataset's ``experiment``), implement
    :meth:`command` and :meth:`attrs`, and may provide an external agent for
    simulation (:meth:`agent`) or a position-mode reference.
    """

    #: The dataset's ``experiment`` attribute.
    name: str = "free"
    #: Duration [s].
    duration_s: float = 1.0
    #: ``"torque"`` or ``"position"``: the robot-side command mode the program needs.
    mode: str = "torque"

    def command(self, s: ClientState) -> Command:
        """This cycle's command from the client state."""
        raise NotImplementedError

    def attrs(self) -> dict:
        """Attributes of the dataset's ``/experiment`` group."""
        return {"duration_s": self.duration_s}

    def agent(self, q0: float):
        """External agent acting on a simulated link (None: nobody touches the link)."""
        return None

    def check(self, robot: RobotInterface) -> None:
        """Refuse settings the robot cannot run safely (raise IiwaIdentError)."""


def velocity_filter_coefficient(dt: float, cutoff_hz: float = 40.0) -> float:
    """Coefficient of the client's first-order velocity low-pass at ``cutoff_hz`` for sample time ``dt`` [s]."""
    return 1.0 - math.exp(-2 * math.pi * cutoff_hz * dt)


def record(robot: RobotInterface, experiment: Experiment, *, record_every: int = 1,
           guard: LimitGuard | None = None, progress: Callable[[int, int], None] | None = None,
           q0: float | None = None) -> Dataset:
    """Run ``experiment`` on ``robot`` and return the recorded dataset.

    Parameters
    ----------
    robot : RobotInterface
        The simulated joint or the FRI runtime.
    experiment : Experiment
        The program.
    record_every : int
        Keep every n-th cycle (5 gives a 200 Hz log of a 1 kHz robot).
    guard : LimitGuard, optional
        Safety supervisor (default: the robot's data-sheet limits).
    progress : callable, optional
        Called as ``progress(done, total)`` every 1000 cycles.
    q0 : float, optional
        Position [rad] an external agent starts from (default: the first measured position).

    Returns
    -------
    Dataset
        Signals ``t``, ``q_m``, ``tau_j``, ``tau_ext_fri``, ``tau_c`` (torque
        mode) or ``q_cmd`` (position mode), and the references the robot
        reports. If the guard stopped the run, ``/experiment`` has
        ``stopped_reason`` and the data up to the stop.
    """
    if record_every < 1:
        raise IiwaIdentError("record_every must be at least 1")
    experiment.check(robot)
    guard = guard or LimitGuard(robot.limits)
    dt = robot.sample_time_s
    n = int(round(experiment.duration_s / dt))
    alpha = velocity_filter_coefficient(dt)
    rows: list[tuple] = []
    stopped = ""
    meas = robot.start()
    quiet = no_gc_pauses()
    quiet.__enter__()  # a collection pause mid-run is a dropped FRI session
    try:
        # The external agent starts where the joint is (the first measurement), on any robot.
        robot.set_agent(experiment.agent(meas.q_m if q0 is None else q0))
        state = ClientState(t=0.0, q=meas.q_m, v=0.0, q0=meas.q_m, meas=meas)
        q_prev = meas.q_m
        for k in range(n):
            cmd = experiment.command(state)
            cmd, reason = guard.filter(cmd, state)
            if k % record_every == 0:
                rows.append((state.t, meas.q_m, meas.tau_j, meas.tau_ext_fri, meas.q_l_ref, meas.tau_ext_ref,
                             cmd.tau_c, cmd.q_cmd))
            if reason:
                stopped = reason
                break
            try:
                meas = robot.step(cmd)
            except SafetyStop as err:  # the robot ended the session (FRI): keep what was recorded
                stopped = str(err)
                break
            v_raw = (meas.q_m - q_prev) / dt
            q_prev = meas.q_m
            state = ClientState(t=meas.t, q=meas.q_m, v=state.v + alpha * (v_raw - state.v), q0=state.q0, meas=meas)
            if progress and k % 1000 == 0:
                progress(k, n)
        if stopped:
            try:
                stopped = guard.brake(robot, state, cmd.q_cmd is not None) or stopped
            except SafetyStop:
                pass  # no session left to brake through; the robot's own controller holds the joint
    finally:
        quiet.__exit__(None, None, None)
        robot.stop()
        robot.set_agent(None)
    if progress:
        progress(n, n)
    return _dataset(robot, experiment, rows, dt * record_every, stopped)


def _dataset(robot: RobotInterface, experiment: Experiment, rows: list[tuple], period: float,
             stopped: str) -> Dataset:
    if len(rows) < 2:
        raise IiwaIdentError(f"{experiment.name}: stopped before anything was recorded ({stopped or 'too short'})")
    cols = list(zip(*rows))
    signals = {"t": np.array(cols[0]), "q_m": np.array(cols[1]), "tau_j": np.array(cols[2]),
               "tau_ext_fri": np.array(cols[3])}
    for name, col in (("q_l_ref", cols[4]), ("tau_ext_ref", cols[5]), ("tau_c", cols[6]), ("q_cmd", cols[7])):
        if all(v is not None for v in col):
            signals[name] = np.array(col, dtype=float)
    attrs = experiment.attrs()
    if stopped:
        attrs["stopped_reason"] = stopped
    truth = robot.truth()
    return Dataset(signals=signals, experiment=experiment.name, source=robot.source, joint=robot.joint,
                   sample_rate_hz=1.0 / period, experiment_attrs=attrs, truth=truth)
