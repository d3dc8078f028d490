"""Robot side of the FRI protocol: a real-time emulator with the simulated joint behind it.

:class:`RobotEmulator` plays the KUKA robot controller towards an FRI client
over UDP, so that a client runtime can be tested without a robot. It sends a
``FRIMonitoringMessage`` every send period (1 ms), collects the client's
``FRICommandMessage`` answers, runs the FRI session states and steps one
:class:`~iiwa_ident.sim.SimulatedJoint` per cycle with the client's
command. The six other joints of the arm stand still at
:attr:`EmulatorConfig.joint_positions`.

The robot's own motion is a position hold: its interpolator's positions
(``ipoData.jointPosition``, and the commanded joint positions while no
client commands) are that pose, the simulated joint held where it stood
when the current ``COMMANDING_ACTIVE`` phase began (or ended). A client
overlays its command on them, as KUKA's clients do (a joint position overlay
sends the interpolator's position plus its offset). The tracking
performance is 1 in ``COMMANDING_ACTIVE`` and 0 in every other state, as
KUKA documents it.

The robot side's clock (real time or lockstep) is :mod:`iiwa_ident.emulator._clocks`,
the link with its injected faults :mod:`iiwa_ident.emulator._faults`, the
connection quality :mod:`iiwa_ident.emulator._quality`.

Reproducibility
---------------
Until commanding first becomes active the joint stands still (zero torque
or position hold at its start position). When the session first enters
``COMMANDING_ACTIVE`` the simulation is restarted from that same rest state
(:meth:`SimulatedJoint.start`, noise generator reseeded) and the first
``COMMANDING_ACTIVE`` message carries its first measurement. From there on
a client whose every answer arrives within its cycle sees exactly what
``SimulatedJoint(plant, seed, q0)`` returns for the same commands: the
answer to message ``k`` is applied in cycle ``k + 1``, as ``step`` applies
its command. The recorded dataset's ``commanding_start_index`` marks that
row.

One cycle
---------
1. Take every datagram that arrived since the last cycle: datagrams from an
   address other than the client's are *foreign*, ones that do not decode as
   a command message are *invalid*, ones whose client sequence counter is
   not newer than the last accepted one are *stale* and ignored. The newest
   remaining answer is this cycle's answer; an answer to an older monitoring
   message than the newest one sent when it arrived is *late*. No new answer
   (while one was due) is a *missed* cycle.
2. Run the session logic (below).
3. Apply the command: in ``COMMANDING_ACTIVE`` the client's
   ``jointTorque[j-1]`` (torque mode) or ``jointPosition[j-1]`` (position
   mode), held from the last answer when none arrived; otherwise zero torque
   (torque mode) or the hold position (position mode).
4. Step the simulated joint and send the monitoring message of the new
   measurement (nothing is sent in the initial ``IDLE`` phase).

Session rules
-------------
* ``IDLE`` for :attr:`~EmulatorConfig.idle_s`, nothing sent, then
  ``MONITORING_WAIT``. The client answers monitoring states with a header
  (KUKA's client adds the commanded joint positions).
* ``MONITORING_WAIT`` -> ``MONITORING_READY`` once the quality has been at
  least ``GOOD`` for :attr:`~EmulatorConfig.monitoring_s` without a break.
* ``MONITORING_READY`` -> ``MONITORING_WAIT`` when the quality falls below
  ``GOOD``; -> ``COMMANDING_WAIT`` after :attr:`~EmulatorConfig.ready_s`.
* ``COMMANDING_WAIT`` -> ``COMMANDING_ACTIVE`` after
  :attr:`~EmulatorConfig.commanding_wait_s`. Torques are ignored while
  waiting, but every answer is checked as in ``COMMANDING_ACTIVE``.
* In both commanding states the session **drops** (back to
  ``MONITORING_WAIT``; the joint runs on with the idle command) when an
  answer to a commanding-state message lacks ``commandData``, has fewer or
  more than 7 joint positions (and, in torque mode, 7 joint torques), holds
  a non-finite value, or commands a position farther than
  :attr:`~EmulatorConfig.max_position_error_rad` from the interpolator's
  (torque mode) or the measured one (position mode);
  when no new answer arrived for :attr:`~EmulatorConfig.timeout_s` worth of
  cycles ("no answer for 5.0 ms"); or when the quality is ``POOR``.
  Answers to monitoring-state messages that arrive after commanding began
  (header only) are accepted.
* After :attr:`~EmulatorConfig.duration_s` of ``COMMANDING_ACTIVE``:
  ``MONITORING_READY`` for :attr:`~EmulatorConfig.closing_s`, then
  ``IDLE`` (sent for ``idle_s``, so the client sees the session close) and
  the run ends. :meth:`RobotEmulator.stop` goes to that final ``IDLE`` at
  once.
* With :attr:`~EmulatorConfig.idle_timeout_s`, a run whose client was heard
  and has sent nothing for that long outside the commanding states (its
  session over or dropped, no client back) goes to that final ``IDLE`` too
  (``end_reason`` ``"client_gone"``), whatever ``duration_s`` still counts.

Safety
------
Every cycle of ``COMMANDING_ACTIVE`` the robot side checks the simulated
joint against its robot model's data-sheet limits
(:attr:`Plant.limits <iiwa_ident.sim.Plant>`, from
:func:`~iiwa_ident.robot.joint_limits`): the speed (from the last two
measured positions), the joint torque, and the range, watched ahead by the
distance the joint still covers when stopped now (the reaction, one cycle
and the joint's input delay, at the present speed, then the braking ramp at
:attr:`~EmulatorConfig.brake_decel_rad_s2`), so a joint driven at the end
of its range comes to rest inside it. A violation stops the robot as its
safety controller does: the safety state becomes ``SAFETY_STOP_LEVEL_1``,
the joint brakes under position control along a ramp to rest (whatever the
client sends; the interpolator holds the ramp's end), the session leaves
``COMMANDING_ACTIVE`` for ``MONITORING_READY`` until the joint has come to
rest (:data:`BRAKE_SETTLE_S` after the ramp), then ``IDLE``, and the run
ends. The report names the violated limit (:attr:`EmulatorReport.safety_stop`,
``end_reason`` ``"safety_stop"``). The six joints that stand still are not
checked; their commanded positions only by ``max_position_error_rad``.

Units: seconds, rad, Nm unless a name says otherwise.
"""

from __future__ import annotations

import dataclasses
import gc
import math
import socket
from array import array
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from iiwa_ident.datasets import Dataset, write_dataset
from iiwa_ident.emulator._clocks import RING, ClockPort, LockstepClock, RealTimeClock, SentRing, SessionView
from iiwa_ident.emulator._config import EmulatorConfig, check_config, resolve_address
from iiwa_ident.emulator._faults import FaultyLink
from iiwa_ident.emulator._quality import QualityWindow
from iiwa_ident.emulator._report import EmulatorReport, Histogram
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import HandGuided
from iiwa_ident.fri import (
    MONITORING_MESSAGE_ID,
    N_JOINTS,
    ClientCommandMode,
    CommandMessage,
    ConnectionQuality,
    ControlMode,
    DriveState,
    FriDecodeError,
    MonitoringMessage,
    OverlayType,
    RobotInfo,
    SafetyState,
    SessionState,
    decode_command,
    encode_monitoring,
    message_problem,
)
from iiwa_ident.netft import EmulatedNetFt, JointAxisProjection, RdtServer
from iiwa_ident.robot import Command, Measurement
from iiwa_ident.sim import SimulatedJoint, default_plant

__all__ = ["RobotEmulator", "BRAKE_SETTLE_S"]

#: After a safety stop's braking ramp, the session stays open this long for the joint to settle [s].
BRAKE_SETTLE_S = 0.2
_U32 = 0xFFFFFFFF
# A client sequence counter this far behind the last one is taken for a
# restarted client rather than a stale answer.
_STALE_WINDOW = 1000
_COMMANDING = (SessionState.COMMANDING_WAIT, SessionState.COMMANDING_ACTIVE)


class _Brake(NamedTuple):
    """Where a safety stop's braking ramp began."""

    q: float  # position [rad]
    v: float  # speed [rad/s]
    step: int  # simulation step


class _Answer(NamedTuple):
    """A client's answer as the robot side takes it."""

    msg: CommandMessage
    latency_s: float | None  # since the message it reflects was sent; None: not one of the ring's
    state: SessionState | None  # the session state of the message it reflects


class _ShiftedAgent:
    """An external agent made for time 0 and position 0, started at time ``t0`` from position ``q0``.

    The simulation's clock runs from the start of the run, the agent's from
    the moment it is attached.
    """

    def __init__(self, agent: Callable[[np.ndarray], np.ndarray], t0: float, q0: float) -> None:
        self.agent, self.t0, self.q0 = agent, t0, q0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        out = self.agent(t - self.t0)
        out[:, 1] += self.q0
        return out


class RobotEmulator:
    """The robot controller's side of an FRI session, in real time, with a simulated joint.

    Parameters
    ----------
    config : EmulatorConfig
        Settings; checked with :func:`check_config`.
    on_event : callable, optional
        Called as ``on_event(t, text)`` at each state transition and drop
        (from the real-time loop: keep it short).

    Raises
    ------
    IiwaIdentError
        For a bad setting or when the robot-side socket cannot be bound.

    Notes
    -----
    The socket is bound in the constructor, so :attr:`address` is known
    before :meth:`run`. :meth:`run` can be called once; it closes the socket.
    """

    def __init__(self, config: EmulatorConfig, on_event: Callable[[float, str], None] | None = None) -> None:
        check_config(config)
        self.config = config
        self._on_event = on_event
        self._plant = config.plant or default_plant()
        self._period = config.send_period_ms * 1e-3
        self._torque_mode = config.client_command_mode == ClientCommandMode.TORQUE
        self._j = self._plant.joint - 1
        self._pose = [float(q) for q in config.joint_positions]
        self._client = resolve_address(config.client, "client", allow_any_port=False)
        bind = resolve_address(config.bind, "bind", allow_any_port=True)
        self._hand_agent: Callable[[np.ndarray], np.ndarray] | None = None
        self._robot = SimulatedJoint(self._plant, seed=config.seed, q0=self._pose[self._j])
        if config.agent == "hand":
            # The trajectory is precomputed; beyond its length the hand holds still.
            hand = HandGuided(
                duration_s=config.duration_s or 120.0, peak_speed_rad_s=config.hand_peak_speed_rad_s,
                range_rad=config.hand_range_rad, arm_stiffness=config.hand_stiffness_nm_rad,
                arm_damping=config.hand_damping_nms_rad, seed=config.seed)
            hand.check(self._robot)
            # Built here, not when commanding starts: it takes milliseconds, too long for one cycle.
            self._hand_agent = hand.agent(0.0)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind(bind)
        except OSError as err:
            self._sock.close()
            raise IiwaIdentError(f"cannot bind the robot-side socket to {bind[0]}:{bind[1]}: {err.strerror}") from None
        self._sock.setblocking(False)
        self._address: tuple[str, int] = self._sock.getsockname()[:2]
        self._ft: EmulatedNetFt | None = None
        if config.ft_port is not None:
            projection = (JointAxisProjection.from_lever_arm(config.ft_lever_m) if config.ft_lever_m is not None
                          else JointAxisProjection.from_description(self._plant.robot_model, self._plant.joint,
                                                                    self._pose))
            try:
                server = RdtServer((bind[0], config.ft_port))
            except IiwaIdentError:
                self._sock.close()
                raise
            # The sensor's own noise is seeded by the emulator's seed, as the joint's.
            self._ft = EmulatedNetFt(server, projection, dataclasses.replace(config.ft, seed=config.seed),
                                     self._period)
        self._stop_requested = False
        self._ran = False

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` of the robot-side socket, the address the client answers to."""
        return self._address

    @property
    def ft_address(self) -> tuple[str, int] | None:
        """``(host, port)`` of the emulated F/T sensor (None without one)."""
        return self._ft.server.address if self._ft is not None else None

    def stop(self) -> None:
        """Ask :meth:`run` to close the session and return (thread- and signal-safe)."""
        # A single attribute store: safe from signal handlers and other threads.
        self._stop_requested = True

    def close(self) -> None:
        """Close the sockets (done by :meth:`run`; needed only if it never runs)."""
        self._sock.close()
        if self._ft is not None:
            self._ft.server.close()

    # -- run --------------------------------------------------------------
    def run(self) -> EmulatorReport:
        """Run the session in real time until it ends.

        The run ends after ``duration_s`` of ``COMMANDING_ACTIVE`` and the
        closing phases, on :meth:`stop`, or after ``max_wall_s``.

        Returns
        -------
        EmulatorReport
            Counters, transitions, timing; the dataset path if recorded.
        """
        if self._ran:
            raise IiwaIdentError("an emulator runs only once; create a new one")
        self._ran = True
        # A full collection of a large process (a test runner, say) stalls for tens of ms; the
        # loop makes no reference cycles, so what exists now is frozen out of the collector for the run.
        freeze = gc.isenabled()
        if freeze:
            gc.collect()
            gc.freeze()
        try:
            self._setup_run()
            self._loop()
            self._finish()
        finally:
            self.close()
            if freeze:
                gc.unfreeze()
        return self._report

    def _setup_run(self) -> None:
        cfg = self.config
        T = self._period
        self._report = EmulatorReport(lockstep=cfg.lockstep)
        self._inbox: list[tuple[float, bytes, Any, int]] = []
        self._clock: RealTimeClock | LockstepClock = (LockstepClock if cfg.lockstep else RealTimeClock)(cfg)
        self._link = FaultyLink(self._sock, self._client, cfg.faults, self._report, self._clock)
        self._ring = SentRing()
        self._clock.connect(ClockPort(sock=self._sock, link=self._link, report=self._report, ring=self._ring,
                                      client=self._client, drain=self._drain, session=self._session_view,
                                      on_event=self._on_event))
        self._seq = 0  # next own sequence counter
        self._client_seq: int | None = None  # newest accepted client sequence counter
        self._window = QualityWindow(cfg.quality, T)
        self._latency = Histogram()
        self._due = False  # an answer is due this cycle
        self._silent = 0  # consecutive cycles without a new answer while one was due
        self._heard_k: int | None = None  # cycle of the newest answer
        self._timeout_cycles = max(1, int(round(cfg.timeout_s / T)))
        # Stalls as [first, end) counts of COMMANDING_ACTIVE cycles.
        self._stalls = [(int(round(a / T)), int(round(a / T)) + max(1, int(round(b / T)))) for a, b in cfg.stalls]
        self._state = SessionState.IDLE
        self._state_k = 0
        self._good_cycles = 0
        self._active_cycles = 0
        self._ending = False
        self._finished = False
        self._quality = ConnectionQuality.POOR
        self._report.states.append((0.0, SessionState.IDLE))
        # Commands the robot holds: the client's last 7 positions and torques in COMMANDING_ACTIVE.
        self._cmd_pos: tuple[float, ...] | None = None
        self._cmd_tau: tuple[float, ...] | None = None
        self._zero7 = (0.0,) * N_JOINTS
        self._robot_info = self._info(SafetyState.NORMAL_OPERATION)
        self._meas = self._robot.start()
        self._hold(self._meas.q_m)
        self._positions = self._measured_positions(self._meas)
        self._q_prev = self._meas.q_m  # the previous measurement's position, for the speed [rad]
        self._limits = self._plant.limits
        self._brake: _Brake | None = None  # the safety stop's ramp
        # The robot's reaction: this cycle, then the input delay of its commands (the simulated joint's).
        self._reaction_s = T + self._robot.delay_substeps * T / self._plant.substeps
        self._closing_s = cfg.closing_s
        self._sim_k = 0  # steps since the simulation (re)started
        self._t_offset = 0.0  # recorded time of the simulation's t = 0 [s]
        self._commanding_start: int | None = None
        self._restart_now = False
        if cfg.record is not None:
            self._rows: dict[str, array] | None = {name: array("d") for name in self._record_names()}
        else:
            self._rows = None

    def _info(self, safety: SafetyState) -> RobotInfo:
        """The robot info the messages carry, in safety state ``safety``."""
        cfg = self.config
        # protobuf takes an enum field's number; its stubs name only protobuf's own enum types.
        return RobotInfo(number_of_joints=N_JOINTS, safety_state=safety,  # type: ignore[arg-type]
                         drive_state=(DriveState.ACTIVE,) * N_JOINTS,  # type: ignore[arg-type]
                         operation_mode=cfg.operation_mode, control_mode=cfg.control_mode)  # type: ignore[arg-type]

    def _record_names(self) -> list[str]:
        names = ["t", "q_m", "tau_j", "tau_ext_fri"]
        if self._meas.q_l_ref is not None:
            names.append("q_l_ref")
        if self._meas.tau_ext_ref is not None:
            names.append("tau_ext_ref")
        names.append("tau_c" if self._torque_mode else "q_cmd")
        return names

    def _loop(self) -> None:
        cfg = self.config
        clock = self._clock
        clock.start()
        max_wall = cfg.max_wall_s
        k = 0
        while True:
            k = clock.wait(k)
            if not self._ending or self._state != SessionState.IDLE:
                if self._stop_requested:
                    self._end("stopped", k)
                elif max_wall is not None and clock.wall() >= max_wall:
                    self._end("max_wall", k)
                elif self._client_left(k):
                    if self._on_event is not None:
                        self._on_event(k * self._period, f"no answer for {cfg.idle_timeout_s:g} s: the client has "
                                       "gone, the run ends")
                    self._end("client_gone", k)
            self._cycle(k)
            if self._finished:
                return
            k += 1

    def _client_left(self, k: int) -> bool:
        """Whether a client that was heard has been silent for ``idle_timeout_s`` outside commanding."""
        idle = self.config.idle_timeout_s
        return (idle is not None and self._heard_k is not None and self._state not in _COMMANDING
                and self._clock.silence_s(k, self._heard_k) >= idle)

    def _session_view(self) -> SessionView:
        """The session as the clock sees it."""
        return SessionView(self._stop_requested, self._ending, self._state in _COMMANDING)

    def _drain(self) -> None:
        sock = self._sock
        inbox = self._inbox
        latest = self._seq - 1
        while True:
            try:
                data, addr = sock.recvfrom(4096)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                # ICMP errors reported on the socket (some platforms): nothing was received.
                continue
            t = self._clock.arrival(data, addr)
            if t is not None:
                inbox.append((t, data, addr, latest))

    # -- one cycle ----------------------------------------------------------
    def _cycle(self, k: int) -> None:
        rep = self._report
        rep.cycles += 1
        answer, error = self._take_answers()
        state = self._state
        if self._due:
            if answer is None:
                rep.missed_cycles += 1
                if state in _COMMANDING:
                    rep.missed_commanding += 1
                self._silent += 1
                self._window.add(0, 0.0)
            else:
                self._silent = 0
                self._window.add(1, answer.latency_s or 0.0)
        elif answer is not None:
            self._silent = 0
        if answer is not None:
            self._heard_k = k
        if state != SessionState.IDLE:
            self._quality = self._window.quality()
            rep.quality[self._quality.name] += 1
        self._session(k, error)
        state = self._state
        if state == SessionState.COMMANDING_ACTIVE:
            violation = self._limit_violation()
            if violation:
                self._safety_stop(k, violation)
                state = self._state
        if state == SessionState.COMMANDING_ACTIVE and answer is not None and answer.state == state:
            cd = answer.msg.command_data
            self._cmd_pos = tuple(cd.joint_position.value)
            self._cmd_tau = tuple(cd.joint_torque.value) if cd.HasField("joint_torque") else None
        if self._restart_now:
            # This cycle's message carries the restarted simulation's first measurement.
            self._restart_now = False
            meas = self._meas
        else:
            command = self._command(state)
            if self._rows is not None:
                self._record(self._rows, self._meas, command)
            self._q_prev = self._meas.q_m
            self._meas = meas = self._robot.step(command)
            self._sim_k += 1
        self._positions = self._measured_positions(meas)
        if self._ft is not None:
            # The sensor streams on its own, before this cycle's monitoring message leaves.
            self._ft.cycle(meas.tau_ext_ref if meas.tau_ext_ref is not None else 0.0)
        stalled = False
        if state == SessionState.COMMANDING_ACTIVE:
            n = self._active_cycles
            stalled = bool(self._stalls) and any(a <= n < b for a, b in self._stalls)
            self._active_cycles += 1
        if self._ending and state == SessionState.IDLE:
            if (k - self._state_k) * self._period >= self.config.idle_s:
                self._finished = True
                return
        elif state == SessionState.IDLE:
            self._due = False
            return
        if stalled:
            rep.stalled_cycles += 1
            self._due = False
            return
        self._send_monitoring(meas, state)
        self._due = state != SessionState.IDLE

    def _take_answers(self) -> tuple[_Answer | None, str | None]:
        """This cycle's newest answer and the first command problem."""
        rep = self._report
        link = self._link
        answer = None
        error = None
        commanding = self._state in _COMMANDING
        inbox, self._inbox = self._inbox, []
        for t_arrival, data, addr, latest in inbox:
            received = link.receive(data)
            if received is None:
                continue
            if addr[:2] != self._client:
                rep.answers_foreign += 1
                continue
            try:
                msg = decode_command(received, check=False)  # content: see _check_command
            except FriDecodeError:
                rep.answers_invalid += 1
                continue
            rep.answers_received += 1
            seq = msg.header.sequence_counter
            last = self._client_seq
            if last is not None and 0 <= last - seq < _STALE_WINDOW:
                rep.answers_stale += 1
                continue
            self._client_seq = seq
            reflected = msg.header.reflected_sequence_counter
            slot = reflected & (RING - 1)
            latency: float | None
            answered_state: SessionState | None
            if self._ring.seq[slot] == reflected:
                latency = t_arrival - self._ring.t[slot]
                answered_state = self._ring.state[slot]
                self._latency.add(latency)
                if reflected < latest:
                    rep.late_answers += 1
            else:
                latency = answered_state = None
            answer = _Answer(msg, latency, answered_state)
            if error is None and commanding and (answered_state is None or answered_state in _COMMANDING):
                error = self._check_command(msg)
        return answer, error

    def _check_command(self, msg: CommandMessage) -> str | None:
        """What is wrong with a command in a commanding state, or None."""
        if not msg.HasField("command_data"):
            return "command without commandData"
        cd = msg.command_data
        for name in ("joint_position", "joint_torque") if self._torque_mode else ("joint_position",):
            if not cd.HasField(name):
                return f"command without {name}"
        problem = message_problem(msg)
        if problem:
            return problem
        limit = self.config.max_position_error_rad
        # Torque mode: the positions are the joint impedance's setpoints, which a client takes from the
        # interpolator; position mode: the path the joints follow, which may not jump away from them.
        reference, name = (self._ipo, "the interpolator's") if self._torque_mode else (self._positions,
                                                                                       "the measured one")
        for i, (q_cmd, q) in enumerate(zip(cd.joint_position.value, reference)):
            if abs(q_cmd - q) > limit:
                return (f"commanded position of joint {i + 1} is {abs(q_cmd - q):.3f} rad from {name} "
                        f"(limit {limit:g} rad)")
        return None

    def _session(self, k: int, error: str | None) -> None:
        """Session drops and state transitions of cycle ``k``."""
        cfg = self.config
        T = self._period
        state = self._state
        in_state = (k - self._state_k) * T
        if state in _COMMANDING:
            if error is not None:
                self._drop(k, error)
            elif self._silent >= self._timeout_cycles:
                self._drop(k, f"no answer for {self._silent * T * 1e3:.1f} ms")
            elif self._quality == ConnectionQuality.POOR:
                self._drop(k, "connection quality POOR")
            elif state == SessionState.COMMANDING_WAIT:
                if in_state >= cfg.commanding_wait_s - 1e-9:
                    self._enter(k, SessionState.COMMANDING_ACTIVE)
            elif cfg.duration_s is not None and self._active_time() >= cfg.duration_s - 1e-9:
                self._ending = True
                self._enter(k, SessionState.MONITORING_READY)
        elif state == SessionState.IDLE:
            if not self._ending and in_state >= cfg.idle_s - 1e-9:
                self._enter(k, SessionState.MONITORING_WAIT)
        elif self._ending:
            if in_state >= self._closing_s - 1e-9:
                self._enter(k, SessionState.IDLE)
        elif state == SessionState.MONITORING_WAIT:
            self._good_cycles = self._good_cycles + 1 if self._quality >= ConnectionQuality.GOOD else 0
            if self._good_cycles * T >= cfg.monitoring_s - 1e-9:
                self._enter(k, SessionState.MONITORING_READY)
        elif state == SessionState.MONITORING_READY:
            if self._quality < ConnectionQuality.GOOD:
                self._enter(k, SessionState.MONITORING_WAIT)
            elif in_state >= cfg.ready_s - 1e-9:
                self._enter(k, SessionState.COMMANDING_WAIT)

    def _enter(self, k: int, state: SessionState) -> None:
        old = self._state
        t = k * self._period
        if old == SessionState.COMMANDING_ACTIVE:
            self._report.commanding_s += self._active_time()
            self._robot.set_agent(None)
            # Leaving torque or position control: the robot holds where the joint is.
            self._hold(self._meas.q_m)
            self._cmd_pos = self._cmd_tau = None
        if state == SessionState.COMMANDING_ACTIVE:
            if self._commanding_start is None:
                self._restart()
            self._active_start = self._active_cycles
            # The overlaid motion starts: the interpolator holds the pose the joint is at.
            self._hold(self._meas.q_m)
            if self._hand_agent is not None:
                self._robot.set_agent(_ShiftedAgent(self._hand_agent, self._sim_k * self._period, self._meas.q_m))
        if state == SessionState.MONITORING_WAIT:
            self._good_cycles = 0
        self._state = state
        self._state_k = k
        self._report.states.append((t, state))
        if self._on_event is not None:
            self._on_event(t, state.name)

    def _restart(self) -> None:
        """Restart the simulation from rest when commanding first becomes active (see Reproducibility)."""
        self._commanding_start = self._sim_k  # = rows recorded so far
        self._t_offset = self._sim_k * self._period
        self._meas = self._robot.start()
        self._q_prev = self._meas.q_m
        self._sim_k = 0
        self._restart_now = True
        if self._ft is not None:
            self._ft.restart(self._meas.tau_ext_ref or 0.0)
        self._positions = self._measured_positions(self._meas)

    def _active_time(self) -> float:
        return (self._active_cycles - self._active_start) * self._period

    def _drop(self, k: int, reason: str) -> None:
        t = k * self._period
        self._report.session_drops.append((t, reason))
        if self._on_event is not None:
            self._on_event(t, f"session dropped: {reason}")
        # A client that comes back may have restarted its sequence counter.
        self._client_seq = None
        self._enter(k, SessionState.MONITORING_WAIT)

    def _end(self, reason: str, k: int) -> None:
        """Close the session at once (stop request, wall-time limit, a client gone)."""
        self._report.end_reason = self._report.end_reason or reason
        self._ending = True
        if self._state != SessionState.IDLE:
            self._enter(k, SessionState.IDLE)
        else:
            self._state_k = k

    # -- safety -------------------------------------------------------------
    def _limit_violation(self) -> str:
        """Which of the joint's limits the last measurement violates ("" for none; module docstring, "Safety")."""
        meas = self._meas
        lim = self._limits
        n = self._plant.joint
        q = meas.q_m
        v = self._speed()
        if abs(v) > lim.velocity_rad_s:
            return f"joint {n} speed {abs(v):.3f} rad/s above its limit {lim.velocity_rad_s:.3f} rad/s"
        q_stop = q + v * self._reaction_s + v * abs(v) / (2.0 * self.config.brake_decel_rad_s2)
        if abs(q_stop) > lim.position_rad:
            return (f"joint {n} at {q:.3f} rad and {v:+.3f} rad/s would pass the end of its range "
                    f"+-{lim.position_rad:.3f} rad")
        if abs(meas.tau_j) > lim.torque_nm:
            return f"joint {n} torque {meas.tau_j:.1f} Nm beyond its limit +-{lim.torque_nm:g} Nm"
        return ""

    def _speed(self) -> float:
        """The joint's speed over the last cycle, from the measured positions [rad/s]."""
        return (self._meas.q_m - self._q_prev) / self._period

    def _safety_stop(self, k: int, reason: str) -> None:
        """Stop the robot as its safety controller does: brake on a ramp, end the session, report why."""
        rep = self._report
        t = k * self._period
        rep.safety_stop, rep.safety_stop_t_s, rep.end_reason = reason, t, "safety_stop"
        v = self._speed()
        self._brake = brake = _Brake(self._meas.q_m, v, self._sim_k)
        self._robot_info = self._info(SafetyState.SAFETY_STOP_LEVEL_1)
        if self._on_event is not None:
            self._on_event(t, f"safety stop: {reason}")
        self._ending = True
        # The session closes once the joint has braked to rest (the ramp, the delay, time to settle).
        self._closing_s = max(self.config.closing_s,
                              abs(v) / self.config.brake_decel_rad_s2 + self._reaction_s + BRAKE_SETTLE_S)
        self._enter(k, SessionState.MONITORING_READY)
        self._hold(self._brake_position(brake, math.inf))

    def _brake_position(self, brake: _Brake, t: float) -> float:
        """The braking ramp's position ``t`` [s] after the safety stop began [rad]."""
        q, v = brake.q, brake.v
        a = math.copysign(self.config.brake_decel_rad_s2, v)
        t = min(t, abs(v) / self.config.brake_decel_rad_s2)
        return q + v * t - 0.5 * a * t * t

    def _command(self, state: SessionState) -> Command:
        brake = self._brake
        if brake is not None:
            return Command(q_cmd=self._brake_position(brake, (self._sim_k - brake.step) * self._period))
        if state == SessionState.COMMANDING_ACTIVE:
            if self._torque_mode:
                return Command(tau_c=self._cmd_tau[self._j] if self._cmd_tau is not None else 0.0)
            return Command(q_cmd=self._cmd_pos[self._j] if self._cmd_pos is not None else self._hold_q)
        return Command(tau_c=0.0) if self._torque_mode else Command(q_cmd=self._hold_q)

    def _hold(self, q: float) -> None:
        """The robot's own motion holds the simulated joint at ``q`` [rad]: the interpolator's pose."""
        self._hold_q = q
        pose = list(self.config.joint_positions)
        pose[self._j] = q
        self._ipo = tuple(float(v) for v in pose)

    def _measured_positions(self, meas: Measurement) -> tuple[float, ...]:
        pose = self._pose
        pose[self._j] = meas.q_m
        return tuple(pose)

    def _record(self, rows: dict[str, array], meas: Measurement, command: Command) -> None:
        rows["t"].append(self._t_offset + meas.t)
        rows["q_m"].append(meas.q_m)
        rows["tau_j"].append(meas.tau_j)
        rows["tau_ext_fri"].append(meas.tau_ext_fri)
        if "q_l_ref" in rows:
            rows["q_l_ref"].append(meas.q_l_ref)
        if "tau_ext_ref" in rows:
            rows["tau_ext_ref"].append(meas.tau_ext_ref)
        if self._torque_mode:
            # After a safety stop the robot brakes under position control: no torque is commanded.
            rows["tau_c"].append(0.0 if command.tau_c is None else command.tau_c)
        else:
            rows["q_cmd"].append(command.q_cmd)

    # -- sending ------------------------------------------------------------
    def _send_monitoring(self, meas: Measurement, state: SessionState) -> None:
        cfg = self.config
        j = self._j
        seq = self._seq & _U32
        positions = self._positions
        tau = [0.0] * N_JOINTS
        tau[j] = meas.tau_j
        ext = [0.0] * N_JOINTS
        ext[j] = meas.tau_ext_fri
        sec, nsec = divmod(self._clock.stamp_ns(), 1_000_000_000)
        msg = MonitoringMessage(
            header=dict(message_identifier=MONITORING_MESSAGE_ID, sequence_counter=seq,
                        reflected_sequence_counter=self._client_seq or 0),
            robot_info=self._robot_info,
            monitor_data=dict(
                measured_joint_position=dict(value=positions),
                measured_torque=dict(value=tau),
                commanded_joint_position=dict(value=self._cmd_pos if self._cmd_pos is not None else self._ipo),
                commanded_torque=dict(value=self._cmd_tau if self._cmd_tau is not None else self._zero7),
                external_torque=dict(value=ext),
                timestamp=dict(sec=sec & _U32, nanosec=nsec),
            ),
            connection_info=dict(session_state=state, quality=self._quality, send_period_ms=cfg.send_period_ms,
                                 receive_multiplier=1),
            ipo_data=dict(joint_position=dict(value=self._ipo), client_command_mode=cfg.client_command_mode,
                          overlay_type=OverlayType.JOINT,
                          tracking_performance=1.0 if state == SessionState.COMMANDING_ACTIVE else 0.0),
        )
        data = encode_monitoring(msg)
        slot = seq & (RING - 1)
        self._ring.seq[slot] = seq
        self._ring.t[slot] = self._clock.now()
        self._ring.state[slot] = state
        self._seq = seq + 1
        if not self._clock.sends(slot, state):
            self._report.unsent += 1
            return
        self._report.monitoring_sent += 1
        self._link.send(data, seq, state != SessionState.IDLE)

    # -- end ------------------------------------------------------------------
    def _finish(self) -> None:
        rep = self._report
        self._link.flush()
        if not rep.end_reason:
            rep.end_reason = "duration"
        rep.wall_s = self._clock.wall()
        rep.latency_median_s = self._latency.quantile(0.5)
        rep.latency_p99_s = self._latency.quantile(0.99)
        rep.latency_max_s = self._latency.max if self._latency.n else None
        rep.cycle_delay_median_s = self._clock.delay.quantile(0.5)
        rep.cycle_delay_p99_s = self._clock.delay.quantile(0.99)
        rep.cycle_delay_max_s = self._clock.delay.max if self._clock.delay.n else None
        rows, record = self._rows, self.config.record
        if rows is not None and record is not None:
            try:
                rep.dataset = write_dataset(record, self._dataset(rows))
            except IiwaIdentError as err:
                rep.dataset_error = str(err)

    def _dataset(self, rows: dict[str, array]) -> Dataset:
        cfg = self.config
        rep = self._report
        signals = {name: np.frombuffer(col, dtype=np.float64).copy() for name, col in rows.items()}
        attrs: dict[str, Any] = {
            "emulator": "fri",
            "client_command_mode": ClientCommandMode(cfg.client_command_mode).name,
            "control_mode": ControlMode(cfg.control_mode).name,
            "seed": cfg.seed,
            "agent": cfg.agent or "none",
            "joint_positions_rad": np.array(cfg.joint_positions, dtype=float),
            "commanding_s": rep.commanding_s,
            "commanding_start_index": -1 if self._commanding_start is None else self._commanding_start,
            "state_t_s": np.array([t for t, _ in rep.states], dtype=float),
            "state": np.array([int(s) for _, s in rep.states], dtype=np.int64),
            "drop_t_s": np.array([t for t, _ in rep.session_drops], dtype=float),
            "end_reason": rep.end_reason,
            "safety_stop": rep.safety_stop,
        }
        if cfg.duration_s is not None:
            attrs["duration_s"] = cfg.duration_s
        if cfg.faults.any:
            for name in ("loss", "jitter_s", "duplicate", "reorder", "corrupt"):
                attrs[f"fault_{name}"] = float(getattr(cfg.faults, name))
        return Dataset(signals=signals, experiment="free", source=self._robot.source, joint=self._plant.joint,
                       sample_rate_hz=1.0 / self._period, experiment_attrs=attrs, truth=self._robot.truth())
