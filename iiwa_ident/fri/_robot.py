"""One joint of a real LBR iiwa (or of the emulator) behind FRI, as a :class:`~iiwa_ident.robot.RobotInterface`.

Every program that runs on the simulated joint runs unchanged on
:class:`FriRobot`: :meth:`~FriRobot.start` follows the session up to
COMMANDING_ACTIVE and returns the first measurement; each
:meth:`~FriRobot.step` answers the current monitoring message with the
command and returns the measurement of the next one.

What each answer carries is what KUKA's own client (``LBRClient``) sends:
in the monitoring states the robot's commanded joint positions; in the
commanding states the interpolator's joint positions (``ipoData``) for every
joint, zero torque for the six not under test, and the command for the
joint under test (its torque in torque mode, where its position too is the
interpolator's; its position in position mode). The joints not overlaid so
keep the robot's own setpoint: in torque mode the joint impedance holds
them around the interpolator's pose, which the measured positions would
not (their spring would vanish).
"""

from __future__ import annotations

import time

from iiwa_ident.errors import IiwaIdentError, SafetyStop
from iiwa_ident.fri._connection import COMMANDING_STATES, DEFAULT_PORT, FriConnection
from iiwa_ident.fri._protocol import (
    N_JOINTS,
    ClientCommandMode,
    ControlMode,
    DriveState,
    MonitoringMessage,
    SafetyState,
    SessionState,
)
from iiwa_ident.robot import Command, Measurement, RobotInterface, joint_limits

__all__ = ["FriRobot", "required_settings"]

_N_JOINTS = N_JOINTS


def _field(msg: MonitoringMessage, part: str, name: str):
    """``msg.part.name``, or None when the robot did not send it."""
    if not msg.HasField(part):
        return None
    sub = getattr(msg, part)
    return getattr(sub, name) if sub.HasField(name) else None


def _name(enum, value) -> str:
    try:
        return enum(value).name
    except ValueError:
        return str(value)


def required_settings(mode: str) -> tuple[ControlMode, ClientCommandMode]:
    """(control mode, client command mode) the robot must run for ``mode`` ``"torque"`` or ``"position"``."""
    if mode == "torque":
        return ControlMode.JOINT_IMPEDANCE, ClientCommandMode.TORQUE
    if mode == "position":
        return ControlMode.POSITION, ClientCommandMode.POSITION
    raise IiwaIdentError(f"FRI mode must be 'torque' or 'position', got {mode!r}")


class FriRobot(RobotInterface):
    """A joint of the LBR iiwa commanded over FRI at the robot's send period.

    Parameters
    ----------
    host : str
        Robot controller address; only its datagrams are accepted.
    joint : int
        Joint under test, 1-7.
    robot_model : str
        ``"iiwa7"`` or ``"iiwa14"`` (data-sheet limits).
    port : int
        Local UDP port (KUKA's default 30200).
    mode : str
        ``"torque"`` (JOINT_IMPEDANCE control, TORQUE client command mode) or
        ``"position"`` (POSITION control and client command mode).
    connect_timeout_s : float
        How long :meth:`start` waits for COMMANDING_ACTIVE [s].
    message_timeout_s : float
        Silence of the robot after which a running session counts as lost [s].
    bind_host : str
        Local address to bind (all interfaces by default).
    """

    source = "robot"
    sample_time_s = 1e-3

    def __init__(self, host: str, joint: int, robot_model: str = "iiwa14", port: int = DEFAULT_PORT,
                 mode: str = "torque", connect_timeout_s: float = 60.0, message_timeout_s: float = 0.1,
                 bind_host: str = "") -> None:
        self.limits = joint_limits(robot_model, joint)
        self.joint, self.robot_model, self.host = int(joint), robot_model, host
        self.mode = mode
        self._settings = required_settings(mode)
        self.port, self.bind_host = int(port), bind_host
        self.connect_timeout_s, self.message_timeout_s = float(connect_timeout_s), float(message_timeout_s)
        # Listen from now on: the robot may already be sending, and a closed port makes it judge the link poor.
        self.connection: FriConnection | None = FriConnection(host, self.port, bind_host)
        self.stats = self.connection.stats  # the connection's counters, kept after it is closed
        self._msg: MonitoringMessage | None = None
        self._cycles = 0  # robot cycles since COMMANDING_ACTIVE began
        self._prev_stamp_ns: int | None = None

    # ------------------------------------------------------------------ helpers
    def describe(self) -> dict:
        out = {"interface": "FRI", "robot_address": self.host, "port": self.port, "robot_model": self.robot_model,
               "mode": self.mode}
        if self.stats is not None:
            out["connection"] = self.stats.as_dict()
            out["first_answer_s"] = self.stats.first_answer_s
        return out

    @property
    def pose(self) -> tuple[float, ...] | None:
        """The measured positions of all joints in the current message [rad] (None before the first)."""
        if self._msg is None:
            return None
        return tuple(float(q) for q in self._values(self._msg, "measured_joint_position"))

    def _state(self, msg: MonitoringMessage) -> int:
        return msg.connection_info.session_state if msg.HasField("connection_info") else SessionState.IDLE

    def _check_settings(self, msg: MonitoringMessage) -> None:
        """Refuse a session whose robot-side settings do not fit the program (before the first command)."""
        want_control, want_client = self._settings
        problems = []
        control = _field(msg, "robot_info", "control_mode")
        if control != want_control:
            got = "unknown" if control is None else _name(ControlMode, control)
            problems.append(f"control mode {got} (need {want_control.name})")
        client = _field(msg, "ipo_data", "client_command_mode")
        if client != want_client:
            got = "unknown" if client is None else _name(ClientCommandMode, client)
            problems.append(f"client command mode {got} (need {want_client.name})")
        period = _field(msg, "connection_info", "send_period_ms")
        if period is not None and period != round(self.sample_time_s * 1e3):
            problems.append(f"send period {period} ms (need {self.sample_time_s * 1e3:g} ms)")
        multiplier = _field(msg, "connection_info", "receive_multiplier")
        if multiplier not in (None, 1):
            problems.append(f"receive multiplier {multiplier} (need 1)")
        if problems:
            raise IiwaIdentError("FRI: the robot runs " + ", ".join(problems) + "; change the robot application")
        self._check_health(msg)

    def _check_health(self, msg: MonitoringMessage) -> None:
        safety = _field(msg, "robot_info", "safety_state")
        if safety not in (None, SafetyState.NORMAL_OPERATION):
            raise SafetyStop(f"FRI: the robot stopped itself: safety state {_name(SafetyState, safety)}, "
                             f"session {_name(SessionState, self._state(msg))} (its controller names the cause)")
        drives = msg.robot_info.drive_state
        if drives and drives[self.joint - 1] != DriveState.ACTIVE:
            raise SafetyStop(f"FRI: drive of joint {self.joint} is {_name(DriveState, drives[self.joint - 1])}")

    def _values(self, msg: MonitoringMessage, name: str):
        """One of the monitor data's joint arrays (the decoder checked: 7 finite values) [rad] or [Nm]."""
        values = _field(msg, "monitor_data", name)
        if values is None:
            raise SafetyStop(f"FRI: the robot's message lacks {name} for {_N_JOINTS} joints")
        return values.value

    @staticmethod
    def _stamp_ns(msg: MonitoringMessage) -> int | None:
        stamp = _field(msg, "monitor_data", "timestamp")
        return None if stamp is None else stamp.sec * 1_000_000_000 + stamp.nanosec

    def _missed(self, msg: MonitoringMessage, answered: int) -> int:
        """Robot cycles between the answered message and ``msg`` that brought no message to this client.

        The larger of the gap in the sequence counter (messages lost, or skipped because the client was
        late) and the gap in the time stamps (the robot's cycle slipped: it counts messages sent, so its
        counter does not jump). A time-stamp gap longer than the silence limit is the robot's clock being
        set, not a stall, and is ignored.
        """
        missed = (msg.header.sequence_counter - answered - 1) % (1 << 32)
        stamp, prev = self._stamp_ns(msg), self._prev_stamp_ns
        self._prev_stamp_ns = stamp
        if stamp is not None and prev is not None:
            # Rounded to whole cycles: the time stamps carry the sender's jitter.
            cycles = round((stamp - prev) / (self.sample_time_s * 1e9)) - 1
            if missed < cycles <= self.message_timeout_s / self.sample_time_s:
                missed = cycles
        return missed

    def _measurement(self, msg: MonitoringMessage) -> Measurement:
        j = self.joint - 1
        # Time counts the robot's cycles, not its time stamps: the controller runs one cycle per send
        # period, so the log is on a uniform grid, with a lost message or a stall a gap of whole cycles,
        # which is what identification needs; the time stamps carry the sender's jitter.
        t = self._cycles * self.sample_time_s
        ext = _field(msg, "monitor_data", "external_torque")
        return Measurement(t=t, q_m=self._values(msg, "measured_joint_position")[j],
                           tau_j=self._values(msg, "measured_torque")[j],
                           tau_ext_fri=ext.value[j] if ext is not None else float("nan"))

    def _answer(self, msg: MonitoringMessage, command: Command | None) -> None:
        """Answer ``msg`` as KUKA's client does (module docstring), with ``command`` when commanding is active."""
        assert self.connection is not None
        if self._state(msg) not in COMMANDING_STATES:
            commanded = _field(msg, "monitor_data", "commanded_joint_position")
            self.connection.answer(msg, None if commanded is None else commanded.value)
            return
        ipo = _field(msg, "ipo_data", "joint_position")
        if ipo is None:
            raise SafetyStop(f"FRI: the robot's message lacks the interpolator's joint positions for {_N_JOINTS} "
                             "joints")
        positions = list(ipo.value)
        # Torques only in torque mode, as KUKA's client (which refuses to set them in any other mode).
        torques = [0.0] * _N_JOINTS if self.mode == "torque" else None
        if command is not None and self._state(msg) == SessionState.COMMANDING_ACTIVE:
            if command.q_cmd is not None:
                if self.mode != "position":
                    raise SafetyStop("FRI: a position command in torque mode")
                positions[self.joint - 1] = command.q_cmd
            else:
                if self.mode != "torque":
                    raise SafetyStop("FRI: a torque command in position mode")
                # Torque mode allocated the torques; a Command without a position holds a torque.
                assert torques is not None and command.tau_c is not None
                torques[self.joint - 1] = command.tau_c
        self.connection.answer(msg, positions, torques)

    # ------------------------------------------------------------------ RobotInterface
    def start(self) -> Measurement:
        """Open the session and wait for COMMANDING_ACTIVE, answering as the states require."""
        if self.connection is None:
            raise IiwaIdentError("FRI: the connection was closed; create a new FriRobot")
        deadline = time.perf_counter() + self.connect_timeout_s
        while True:
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                raise IiwaIdentError(f"FRI: no session reached COMMANDING_ACTIVE within {self.connect_timeout_s:g} s "
                                     f"(listening on UDP port {self.port} for {self.host}); start the robot's "
                                     "FRI application")
            msg = self.connection.receive(min(remaining, 0.5))
            if msg is None:
                continue
            if self._state(msg) == SessionState.COMMANDING_ACTIVE:
                self._check_settings(msg)
                self._msg = msg
                self._cycles = 0
                self._prev_stamp_ns = self._stamp_ns(msg)
                self.missed_cycles = 0
                return self._measurement(msg)
            if self._state(msg) == SessionState.COMMANDING_WAIT:
                self._check_settings(msg)
            self._answer(msg, None)

    def step(self, command: Command) -> Measurement:
        """Answer the current message with ``command`` and return the next measurement.

        Raises
        ------
        SafetyStop
            When the robot leaves COMMANDING_ACTIVE, falls silent for
            ``message_timeout_s``, or reports a safety stop or an inactive drive.
        """
        if self.connection is None:
            raise IiwaIdentError("FRI: step() before start()")
        if self._msg is None:
            raise SafetyStop("FRI: the session has ended")
        self._answer(self._msg, command)
        self.last_compute_ns = self.connection.last_compute_ns
        answered = self._msg.header.sequence_counter
        msg = self.connection.receive(self.message_timeout_s)
        if msg is None:
            self._msg = None
            raise SafetyStop(f"FRI: no message from the robot for {self.message_timeout_s * 1e3:g} ms")
        self.missed_cycles = self._missed(msg, answered)
        self._cycles += 1 + self.missed_cycles
        state = self._state(msg)
        if state != SessionState.COMMANDING_ACTIVE:
            self._msg = None
            # A safety stop ends the session too: say so rather than only that the state changed.
            self._check_health(msg)
            raise SafetyStop(f"FRI: the robot left COMMANDING_ACTIVE (now {_name(SessionState, state)})")
        self._check_health(msg)
        self._msg = msg
        return self._measurement(msg)

    def stop(self) -> None:
        """Close the connection; the robot ends the session when the answers stop."""
        if self.connection is not None:
            self.connection.close()
            self.connection = None
        self._msg = None
