"""Robot side of the FRI protocol: a real-time emulator with the simulated joint behind it.

:class:`RobotEmulator` plays the KUKA robot controller towards an FRI client
over UDP, so that a client runtime can be tested without a robot. It sends a
``FRIMonitoringMessage`` every send period (1 ms), collects the client's
``FRICommandMessage`` answers, runs the FRI session states and steps one
:class:`~iiwa_ident.sim.joint.SimulatedJoint` per cycle with the client's
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

Real time
---------
Cycle ``k`` starts at ``t0 + k * period`` (:func:`time.perf_counter`). Between
cycles the emulator waits in :func:`select.select` on its socket (so answers
are time-stamped when they arrive) until :attr:`EmulatorConfig.spin_s`
before the deadline and then polls. A cycle that starts more than
:data:`OVERRUN_S` late is an *overrun*; when a whole period has been lost the
missed deadlines are skipped (not caught up in a burst) and counted as
``skipped_cycles``. The simulated joint is stepped once per executed cycle.
For the run, the objects that already exist are frozen out of the garbage
collector (:func:`gc.freeze`), whose full collections of a large process
would stall the loop for tens of milliseconds. Run the emulator in its own
process (:func:`spawn_emulator`) when the client under test is Python, so
the two do not share the interpreter lock.

Lockstep
--------
With :attr:`EmulatorConfig.lockstep` the emulator runs on a clock of its
own instead of the wall clock: cycle ``k`` is at virtual time ``k * period``
and before each cycle the robot side waits until the client has answered
every monitoring message it was sent (a datagram lost, corrupted or still
delayed by the injected faults is not waited for). Each answer is taken to
arrive :attr:`~EmulatorConfig.lockstep_latency_s` after its message was
delivered; injected jitter delays datagrams in virtual time. A client that
answers within :attr:`~EmulatorConfig.lockstep_guard_s` of wall time sees
every cycle in order and never a late, missed or skipped one, however
loaded the machine is, so runs are exactly repeatable. A client that does
not answer within the guard is taken for gone: the cycles run on without
waiting (a commanding session drops after ``timeout_s`` of virtual
silence, as on the robot; its messages in that time are not sent, so that
a client started meanwhile meets the dropped session, as it would on the
robot, whatever the machine's load) and in a monitoring state the emulator
stops the clock and sends the current message again every :data:`RESEND_S` until a
client answers. The first monitoring message is sent that way too, so a
client may start after the emulator. Use it for tests, and for runs whose
figures must not depend on the machine's load; the real-time mode is what a
client meets on the robot. Both modes run the same loop, sockets, protocol
and session logic; only the clock object differs (when a cycle runs, what
its time stamps say, which answers are awaited), so lockstep does not show
answer latency (``bench/bench_fri_runtime.py`` measures it).

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

Safety
------
Every cycle of ``COMMANDING_ACTIVE`` the robot side checks the simulated
joint against its robot model's data-sheet limits
(:attr:`Plant.limits <iiwa_ident.sim.plant.Plant>`, from
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

Connection quality
------------------
Judged every cycle over the last ``window`` cycles in which an answer was
due (:class:`QualityThresholds`): the loss is the fraction of those cycles
without a new answer, the latency the mean time from a monitoring message
being handed to the socket (before any injected delay) to the arrival of
its answer. The defaults:

============  ==========  ==================
quality       loss        mean latency
============  ==========  ==================
EXCELLENT     <= 1 %      < 0.3 ms
GOOD          <= 15 %     < 0.8 ms
FAIR          <= 30 %     < 1 send period
POOR          otherwise   (and with fewer than 10 cycles judged)
============  ==========  ==================

The loss thresholds are wide on purpose: a lost datagram costs the robot
one cycle on the held command, and it is silence (``timeout_s``) that ends
a session, so a session survives a few percent of independent loss in each
direction (the round trip loses about twice that) over a 500-cycle window.

Fault injection
---------------
:class:`Faults` drops, delays, duplicates, reorders and corrupts datagrams
with a seeded random generator; :attr:`EmulatorReport.faults` counts each
injected fault.

Units: seconds, rad, Nm unless a name says otherwise.
"""

from __future__ import annotations

import gc
import heapq
import math
import multiprocessing
import random
import select
import signal
import socket
import threading
import time
from array import array
from collections import deque
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable

import numpy as np

from iiwa_ident.datasets import Dataset, write_dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import HandGuided
from iiwa_ident.fri.protocol import (
    MONITORING_MESSAGE_ID,
    N_JOINTS,
    ClientCommandMode,
    CommandMessage,
    ConnectionQuality,
    ControlMode,
    DriveState,
    FriDecodeError,
    MonitoringMessage,
    OperationMode,
    OverlayType,
    RobotInfo,
    SafetyState,
    SessionState,
    decode_command,
    encode_monitoring,
    message_problem,
)
from iiwa_ident.robot import Command, Measurement, joint_limits
from iiwa_ident.sim import SimulatedJoint
from iiwa_ident.sim import Plant, default_plant

__all__ = [
    "DEFAULT_JOINT_POSITIONS",
    "OVERRUN_S",
    "RESEND_S",
    "AGENTS",
    "Faults",
    "QualityThresholds",
    "EmulatorConfig",
    "EmulatorReport",
    "RobotEmulator",
    "EmulatorProcess",
    "spawn_emulator",
    "check_config",
    "connection_quality",
]

#: Default arm pose [rad]: 0, 30, 0, -90, 0, 60, 0 degrees.
DEFAULT_JOINT_POSITIONS: tuple[float, ...] = tuple(
    math.radians(d) for d in (0.0, 30.0, 0.0, -90.0, 0.0, 60.0, 0.0)
)
#: A cycle that starts later than this after its deadline is an overrun [s].
OVERRUN_S = 0.5e-3
#: Lockstep: a monitoring message nobody answered is sent again after this wall time [s].
RESEND_S = 0.05
#: After a safety stop's braking ramp, the session stays open this long for the joint to settle [s].
BRAKE_SETTLE_S = 0.2
#: Values of :attr:`EmulatorConfig.agent`.
AGENTS = ("hand",)

_N_JOINTS = N_JOINTS
_U32 = 0xFFFFFFFF
# Sent messages remembered for latency and state look-up (a power of two).
_RING = 4096
# A client sequence counter this far behind the last one is taken for a
# restarted client rather than a stale answer.
_STALE_WINDOW = 1000
_COMMANDING = (SessionState.COMMANDING_WAIT, SessionState.COMMANDING_ACTIVE)
_FAULT_KINDS = ("loss", "jitter", "duplicate", "reorder", "corrupt", "loss_out", "loss_in", "corrupt_out",
                "corrupt_in")


# --------------------------------------------------------------------------- configuration


def _probability(name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
        raise IiwaIdentError(f"{name} must be a probability in [0, 1], got {value!r}")


@dataclass(frozen=True)
class Faults:
    """Faults injected into the UDP traffic, per datagram.

    Attributes
    ----------
    loss : float
        Probability of dropping a datagram, both directions.
    jitter_s : float
        Extra delay of robot-to-client datagrams, uniform in ``[0, jitter_s]`` [s].
    duplicate : float
        Probability of sending a robot-to-client datagram twice.
    reorder : float
        Probability of holding a robot-to-client datagram back and sending
        it after the next one.
    corrupt : float
        Probability of flipping 1-3 random bytes of a datagram, both directions.
    seed : int
        Seed of the fault generator.
    """

    loss: float = 0.0
    jitter_s: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder", "corrupt"):
            _probability(f"faults.{name}", getattr(self, name))
        if not isinstance(self.jitter_s, (int, float)) or not 0.0 <= self.jitter_s <= 1.0:
            raise IiwaIdentError(f"faults.jitter_s must be in [0, 1] s, got {self.jitter_s!r}")

    @property
    def any(self) -> bool:
        """Whether any fault is switched on."""
        return bool(self.loss or self.jitter_s or self.duplicate or self.reorder or self.corrupt)


@dataclass(frozen=True)
class QualityThresholds:
    """How the emulator judges the connection quality (see the module docstring).

    Attributes
    ----------
    window : int
        Cycles with an answer due over which loss and latency are judged.
    min_samples : int
        Fewer judged cycles give POOR.
    excellent_loss, good_loss, fair_loss : float
        Largest loss fraction of each quality.
    excellent_latency_s, good_latency_s : float
        Mean latency of each quality must stay below this [s].
    fair_latency_s : float or None
        Same for FAIR [s]; None: one send period.
    """

    window: int = 500
    min_samples: int = 10
    excellent_loss: float = 0.01
    good_loss: float = 0.15
    fair_loss: float = 0.30
    excellent_latency_s: float = 0.3e-3
    good_latency_s: float = 0.8e-3
    fair_latency_s: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.window, int) or not 1 <= self.window <= 100_000:
            raise IiwaIdentError(f"quality.window must be an integer 1..100000, got {self.window!r}")
        if not isinstance(self.min_samples, int) or not 1 <= self.min_samples <= self.window:
            raise IiwaIdentError(f"quality.min_samples must be an integer 1..window, got {self.min_samples!r}")
        for name in ("excellent_loss", "good_loss", "fair_loss"):
            _probability(f"quality.{name}", getattr(self, name))
        for name in ("excellent_latency_s", "good_latency_s", "fair_latency_s"):
            v = getattr(self, name)
            if v is None and name == "fair_latency_s":
                continue
            if not isinstance(v, (int, float)) or not 0.0 < v < math.inf:
                raise IiwaIdentError(f"quality.{name} must be a positive number of seconds, got {v!r}")


@dataclass
class EmulatorConfig:
    """Settings of a :class:`RobotEmulator`.

    Attributes
    ----------
    client : (str, int)
        Address the FRI client listens on (IPv4 host or name, port).
    bind : (str, int)
        Address of the robot-side socket; port 0 picks a free port.
    plant : Plant or None
        The simulated joint (default: :func:`~iiwa_ident.sim.plant.default_plant`);
        its cycle must equal the send period.
    seed : int
        Seed of the simulated sensor noise.
    control_mode : int
        :class:`~iiwa_ident.fri.protocol.ControlMode` reported; torque mode
        needs ``JOINT_IMPEDANCE``.
    client_command_mode : int
        ``ClientCommandMode.TORQUE`` or ``ClientCommandMode.POSITION``.
    operation_mode : int
        :class:`~iiwa_ident.fri.protocol.OperationMode` reported.
    send_period_ms : int
        Send period [ms].
    idle_s : float
        ``IDLE`` phase at the start (nothing sent) and at the end [s].
    monitoring_s : float
        Time with quality >= GOOD before ``MONITORING_READY`` [s].
    ready_s : float
        Time in ``MONITORING_READY`` before ``COMMANDING_WAIT`` [s].
    commanding_wait_s : float
        Time in ``COMMANDING_WAIT`` before ``COMMANDING_ACTIVE`` [s].
    duration_s : float or None
        Length of the ``COMMANDING_ACTIVE`` phase [s], after which the run
        closes and ends; None runs until stopped.
    closing_s : float
        ``MONITORING_READY`` phase after ``duration_s`` [s].
    timeout_s : float
        Silence in commanding states that drops the session [s].
    max_position_error_rad : float
        Largest allowed distance of a commanded joint position from the
        interpolator's (torque mode) or the measured one (position mode) [rad].
    brake_decel_rad_s2 : float
        Deceleration of the robot's safety stop [rad/s^2] (module docstring,
        "Safety"): the braking ramp's, and the one the range is watched with.
    faults : Faults
        Injected network faults.
    quality : QualityThresholds
        How the connection quality is judged.
    agent : str or None
        None, or ``"hand"``: a human arm (the ``hand_*`` settings) moves the
        link while commanding is active.
    hand_peak_speed_rad_s, hand_range_rad : float
        Peak speed [rad/s] and largest excursion [rad] of the hand.
    hand_stiffness_nm_rad, hand_damping_nms_rad : float
        Arm impedance [Nm/rad], [Nm s/rad].
    record : Path or None
        Write the robot-side dataset here when the run ends.
    joint_positions : tuple of float
        Pose of all 7 joints [rad]: the simulated joint starts at its entry,
        the other six stay there.
    max_wall_s : float or None
        End the run after this wall time whatever the state [s].
    spin_s : float
        Busy-wait this long before each deadline instead of sleeping [s].
    lockstep : bool
        Run on a virtual clock, waiting for each answer (module docstring,
        "Lockstep") instead of in real time.
    lockstep_latency_s : float
        Lockstep: time from a monitoring message's delivery to its answer's
        arrival [s], below one send period.
    lockstep_guard_s : float
        Lockstep: wall time after which a client that has not answered is
        taken for gone [s].
    stalls : tuple of (float, float)
        Robot-side stalls ``(start, length)`` [s], the start counted in time
        of ``COMMANDING_ACTIVE``: for ``length`` the robot sends no
        monitoring message and awaits no answer, as when the controller
        cabinet's own cycle slips. The joint moves on under the last command,
        the messages' time stamps keep the time, and the sequence counter
        does not jump (it counts messages sent), so a client sees the
        silence only in the time stamps (or on its own clock).
    """

    client: tuple[str, int] = ("127.0.0.1", 30200)
    bind: tuple[str, int] = ("127.0.0.1", 0)
    plant: Plant | None = None
    seed: int = 0
    control_mode: int = ControlMode.JOINT_IMPEDANCE
    client_command_mode: int = ClientCommandMode.TORQUE
    operation_mode: int = OperationMode.AUT
    send_period_ms: int = 1
    idle_s: float = 0.01
    monitoring_s: float = 0.2
    ready_s: float = 0.1
    commanding_wait_s: float = 0.05
    duration_s: float | None = None
    closing_s: float = 0.1
    timeout_s: float = 0.005
    max_position_error_rad: float = 0.1
    brake_decel_rad_s2: float = 5.0
    faults: Faults = field(default_factory=Faults)
    quality: QualityThresholds = field(default_factory=QualityThresholds)
    agent: str | None = None
    hand_peak_speed_rad_s: float = 0.5
    hand_range_rad: float = 0.5
    hand_stiffness_nm_rad: float = 300.0
    hand_damping_nms_rad: float = 40.0
    record: Path | None = None
    joint_positions: tuple[float, ...] = DEFAULT_JOINT_POSITIONS
    max_wall_s: float | None = None
    spin_s: float = 0.3e-3
    lockstep: bool = False
    lockstep_latency_s: float = 0.2e-3
    lockstep_guard_s: float = 1.0
    stalls: tuple[tuple[float, float], ...] = ()


def _finite(name: str, value: Any, low: float = 0.0, allow_none: bool = False, strict: bool = False) -> None:
    if value is None and allow_none:
        return
    ok = isinstance(value, (int, float)) and math.isfinite(value) and (value > low if strict else value >= low)
    if not ok:
        raise IiwaIdentError(f"{name} must be a finite number {'>' if strict else '>='} {low:g}, got {value!r}")


def check_config(config: EmulatorConfig) -> None:
    """Check an emulator configuration.

    Parameters
    ----------
    config : EmulatorConfig
        The settings.

    Raises
    ------
    IiwaIdentError
        Naming the first bad setting.
    """
    if not isinstance(config.faults, Faults):
        raise IiwaIdentError("faults must be a Faults instance")
    if not isinstance(config.quality, QualityThresholds):
        raise IiwaIdentError("quality must be a QualityThresholds instance")
    if not isinstance(config.send_period_ms, int) or not 1 <= config.send_period_ms <= 100:
        raise IiwaIdentError(f"send_period_ms must be an integer 1..100, got {config.send_period_ms!r}")
    for name in ("idle_s", "monitoring_s", "ready_s", "commanding_wait_s", "closing_s", "spin_s"):
        _finite(name, getattr(config, name))
    _finite("duration_s", config.duration_s, allow_none=True, strict=True)
    _finite("max_wall_s", config.max_wall_s, allow_none=True, strict=True)
    _finite("timeout_s", config.timeout_s, strict=True)
    _finite("lockstep_guard_s", config.lockstep_guard_s, strict=True)
    _finite("lockstep_latency_s", config.lockstep_latency_s)
    if config.lockstep_latency_s >= config.send_period_ms * 1e-3:
        raise IiwaIdentError(f"lockstep_latency_s must be below the send period, got {config.lockstep_latency_s!r}")
    _finite("max_position_error_rad", config.max_position_error_rad, strict=True)
    _finite("brake_decel_rad_s2", config.brake_decel_rad_s2, strict=True)
    try:
        stalls = [(float(a), float(b)) for a, b in config.stalls]
    except (TypeError, ValueError):
        raise IiwaIdentError(f"stalls must be (start, length) pairs of seconds, got {config.stalls!r}") from None
    for start, length in stalls:
        _finite("a stall's start", start)
        _finite("a stall's length", length, strict=True)
    for name in ("hand_peak_speed_rad_s", "hand_range_rad"):
        _finite(name, getattr(config, name), strict=True)
    for name in ("hand_stiffness_nm_rad", "hand_damping_nms_rad"):
        _finite(name, getattr(config, name))
    if config.client_command_mode not in (ClientCommandMode.TORQUE, ClientCommandMode.POSITION):
        raise IiwaIdentError(
            f"client_command_mode must be TORQUE or POSITION, got {config.client_command_mode!r}")
    if config.control_mode not in set(ControlMode):
        raise IiwaIdentError(f"control_mode {config.control_mode!r} is not a ControlMode")
    if config.operation_mode not in set(OperationMode):
        raise IiwaIdentError(f"operation_mode {config.operation_mode!r} is not an OperationMode")
    if config.client_command_mode == ClientCommandMode.TORQUE and config.control_mode != ControlMode.JOINT_IMPEDANCE:
        raise IiwaIdentError("torque mode needs control_mode JOINT_IMPEDANCE")
    if config.agent is not None and config.agent not in AGENTS:
        raise IiwaIdentError(f"agent must be None or one of {', '.join(AGENTS)}, got {config.agent!r}")
    pose = tuple(config.joint_positions)
    if len(pose) != _N_JOINTS or not all(isinstance(q, (int, float)) and math.isfinite(q) for q in pose):
        raise IiwaIdentError(f"joint_positions must be {_N_JOINTS} finite angles [rad], got {config.joint_positions!r}")
    plant = config.plant or default_plant()
    if abs(plant.cycle_s - config.send_period_ms * 1e-3) > 1e-12:
        raise IiwaIdentError(
            f"the plant's cycle {plant.cycle_s * 1e3:g} ms differs from send_period_ms {config.send_period_ms}")
    for i, q in enumerate(pose):
        limit = joint_limits(plant.robot_model, i + 1).position_rad
        if abs(q) > limit:
            raise IiwaIdentError(f"joint_positions[{i}] = {q:g} rad is outside joint {i + 1}'s range +-{limit:.3f} rad")
    _resolve(config.client, "client", allow_any_port=False)
    _resolve(config.bind, "bind", allow_any_port=True)


def _resolve(address: Any, name: str, allow_any_port: bool) -> tuple[str, int]:
    """The numeric IPv4 ``(host, port)`` of a configured address."""
    try:
        host, port = address
    except (TypeError, ValueError):
        raise IiwaIdentError(f"{name} must be (host, port), got {address!r}") from None
    low = 0 if allow_any_port else 1
    if not isinstance(host, str) or not host or not isinstance(port, int) or not low <= port <= 65535:
        raise IiwaIdentError(f"{name} {address!r}: expected a host and a port {low}-65535")
    try:
        info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as err:
        raise IiwaIdentError(f"{name} host {host!r} does not resolve to an IPv4 address "
                             f"({getattr(err, 'strerror', None) or err})") from None
    return info[0][4][0], port


def connection_quality(answered: int, due: int, mean_latency_s: float | None, period_s: float,
                       thresholds: QualityThresholds | None = None) -> ConnectionQuality:
    """The connection quality of a window of cycles (see the module docstring).

    Parameters
    ----------
    answered : int
        Cycles of the window in which a new answer arrived.
    due : int
        Cycles of the window in which an answer was due.
    mean_latency_s : float or None
        Mean latency of the answers [s] (None: no answers).
    period_s : float
        Send period [s].
    thresholds : QualityThresholds, optional
        The limits (default: the defaults).

    Returns
    -------
    ConnectionQuality
    """
    q = thresholds or _DEFAULT_QUALITY
    if due < q.min_samples or mean_latency_s is None:
        return ConnectionQuality.POOR
    loss = 1.0 - answered / due
    if loss <= q.excellent_loss and mean_latency_s < q.excellent_latency_s:
        return ConnectionQuality.EXCELLENT
    if loss <= q.good_loss and mean_latency_s < q.good_latency_s:
        return ConnectionQuality.GOOD
    fair_latency = period_s if q.fair_latency_s is None else q.fair_latency_s
    if loss <= q.fair_loss and mean_latency_s < fair_latency:
        return ConnectionQuality.FAIR
    return ConnectionQuality.POOR


_DEFAULT_QUALITY = QualityThresholds()


# --------------------------------------------------------------------------- report


class _Histogram:
    """Counts of durations in 1 us bins up to 50 ms, with the exact maximum (bounded memory)."""

    _BINS = 50_000

    def __init__(self) -> None:
        self.counts = [0] * (self._BINS + 1)
        self.n = 0
        self.max = 0.0

    def add(self, x: float) -> None:
        i = int(x * 1e6) if x > 0.0 else 0
        self.counts[i if i < self._BINS else self._BINS] += 1
        self.n += 1
        if x > self.max:
            self.max = x

    def quantile(self, q: float) -> float | None:
        if not self.n:
            return None
        rank = q * (self.n - 1)
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen > rank:
                # The bin's centre, but never beyond the largest value seen.
                return min((i + 0.5) * 1e-6, self.max)
        return self.max


@dataclass
class EmulatorReport:
    """What happened during an emulator run.

    Times ``t`` are the scheduled cycle times since the start of the run [s].

    Attributes
    ----------
    cycles : int
        Executed cycles (simulation steps).
    skipped_cycles : int
        Deadlines skipped because the emulator fell a whole period behind.
    monitoring_sent : int
        Monitoring messages produced (before injected faults).
    answers_received : int
        Command messages from the client that decoded.
    answers_invalid : int
        Datagrams from the client that did not decode as a command message
        (malformed, wrong message identifier).
    answers_foreign : int
        Datagrams from other addresses (ignored).
    answers_stale : int
        Answers whose client sequence counter was not newer than the last
        accepted one (ignored).
    late_answers : int
        Answers that arrived after the next monitoring message was produced.
    missed_cycles : int
        Cycles in which an answer was due and no new one had arrived.
    missed_commanding : int
        The part of ``missed_cycles`` in COMMANDING_WAIT and COMMANDING_ACTIVE.
    send_errors : int
        Datagrams the operating system refused to send.
    session_drops : list of (float, str)
        Time and reason of each session drop.
    states : list of (float, SessionState)
        Session state transitions, starting with ``IDLE`` at 0.
    quality : dict of str to int
        Cycles spent at each connection quality (outside ``IDLE``).
    latency_median_s, latency_p99_s, latency_max_s : float or None
        Latency from a monitoring message leaving the cycle to its answer [s].
    cycle_delay_median_s, cycle_delay_p99_s, cycle_delay_max_s : float or None
        How late cycles started after their deadline [s].
    overruns : int
        Cycles that started more than :data:`OVERRUN_S` late.
    resent : int
        Lockstep: monitoring messages sent again to a client that was not
        (yet) answering.
    resent_answers : int
        Lockstep: answers to a message sent again beyond the first (ignored).
    client_gone : int
        Lockstep: times the client did not answer within the guard time.
    unsent : int
        Lockstep: commanding messages not sent while the session of a client
        taken for gone ran out its timeout.
    stalled_cycles : int
        Cycles of an injected robot-side stall (:attr:`EmulatorConfig.stalls`),
        in which no message was sent.
    safety_stop : str
        The limit whose violation stopped the robot ("" when none was).
    safety_stop_t_s : float or None
        When it did [s].
    faults : dict of str to int
        Injected faults, named as the :class:`Faults` fields: ``loss``,
        ``jitter`` (datagrams delayed), ``duplicate``, ``reorder``,
        ``corrupt``; and by direction ``loss_out``, ``loss_in`` (robot to
        client, client to robot), ``corrupt_out``, ``corrupt_in``.
    commanding_s : float
        Total time in ``COMMANDING_ACTIVE`` [s].
    wall_s : float
        Wall time of the run [s].
    end_reason : str
        ``"duration"``, ``"stopped"``, ``"max_wall"`` or ``"safety_stop"``.
    lockstep : bool
        Whether the run was in lockstep (times are then virtual).
    dataset : Path or None
        The robot-side dataset written, if any.
    dataset_error : str or None
        Why the dataset could not be written, if it could not.
    """

    cycles: int = 0
    skipped_cycles: int = 0
    monitoring_sent: int = 0
    answers_received: int = 0
    answers_invalid: int = 0
    answers_foreign: int = 0
    answers_stale: int = 0
    late_answers: int = 0
    missed_cycles: int = 0
    missed_commanding: int = 0
    send_errors: int = 0
    session_drops: list[tuple[float, str]] = field(default_factory=list)
    states: list[tuple[float, SessionState]] = field(default_factory=list)
    quality: dict[str, int] = field(default_factory=lambda: {q.name: 0 for q in ConnectionQuality})
    latency_median_s: float | None = None
    latency_p99_s: float | None = None
    latency_max_s: float | None = None
    cycle_delay_median_s: float | None = None
    cycle_delay_p99_s: float | None = None
    cycle_delay_max_s: float | None = None
    overruns: int = 0
    resent: int = 0
    resent_answers: int = 0
    client_gone: int = 0
    unsent: int = 0
    stalled_cycles: int = 0
    safety_stop: str = ""
    safety_stop_t_s: float | None = None
    faults: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_FAULT_KINDS, 0))
    commanding_s: float = 0.0
    wall_s: float = 0.0
    end_reason: str = ""
    dataset: Path | None = None
    dataset_error: str | None = None
    lockstep: bool = False

    def state_sequence(self) -> list[SessionState]:
        """The session states in the order they were entered."""
        return [s for _, s in self.states]

    def as_dict(self) -> dict[str, Any]:
        """The report as plain JSON types (states by name, paths as strings)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "states":
                value = [{"t_s": t, "state": SessionState(s).name} for t, s in value]
            elif f.name == "session_drops":
                value = [{"t_s": t, "reason": r} for t, r in value]
            elif isinstance(value, Path):
                value = str(value)
            elif isinstance(value, dict):
                value = dict(value)
            elif isinstance(value, float) and not math.isfinite(value):
                value = None
            out[f.name] = value
        return out


# --------------------------------------------------------------------------- the emulator


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


class _RealTimeClock:
    """The robot side on the wall clock: cycle ``k`` at ``t0 + k * period``.

    Between deadlines it collects answers and sends the datagrams the faults
    delayed; a cycle more than a period late skips the lost deadlines.
    """

    def __init__(self, emu: "RobotEmulator") -> None:
        self.emu = emu
        self.t0 = 0.0

    def start(self) -> None:
        self.t0 = time.perf_counter() + 1e-3

    def wait(self, k: int) -> int:
        """Wait for cycle ``k``'s deadline; the cycle to run (later than ``k`` after a stall)."""
        emu = self.emu
        period = emu._period
        deadline = self.t0 + k * period
        self._wait_until(deadline)
        late = time.perf_counter() - deadline
        rep = emu._report
        if late > OVERRUN_S:
            rep.overruns += 1
        emu._delay.add(late)
        if late >= period:
            # Fell a whole period behind: skip the lost deadlines rather than burst.
            skip = int(late / period)
            rep.skipped_cycles += skip
            k += skip
        return k

    def _wait_until(self, deadline: float) -> None:
        emu = self.emu
        perf = time.perf_counter
        spin = emu.config.spin_s
        sock = emu._sock
        pending = emu._pending
        while True:
            emu._drain()
            now = perf()
            while pending and pending[0][0] <= now:
                emu._deliver(heapq.heappop(pending)[2])
            remaining = deadline - now
            if remaining <= 0.0 or (emu._stop_requested and not emu._ending):
                return
            wake = deadline - spin
            if pending and pending[0][0] < wake:
                wake = pending[0][0]
            if wake - now > 20e-6:
                select.select((sock,), (), (), wake - now)

    def now(self) -> float:
        """The robot side's time now [s] (send times, fault delays)."""
        return time.perf_counter()

    def wall(self) -> float:
        """Wall time since the start [s]."""
        return time.perf_counter() - self.t0

    def stamp_ns(self) -> int:
        """The monitoring message's timestamp [ns since the epoch]."""
        return time.time_ns()

    def arrival(self, data: bytes, addr: Any) -> float | None:
        """Arrival time of a received datagram [s]; None: ignore it."""
        return time.perf_counter()

    def sends(self, slot: int, state: SessionState) -> bool:
        """Whether the message just built (ring ``slot``, in ``state``) goes out."""
        return True

    def delivered(self, data: bytes, seq: int, due: float | None) -> None:
        """A message that expects an answer went to the socket (``due``: when the faults let it)."""


class _LockstepClock(_RealTimeClock):
    """The robot side on a virtual clock that waits for the answers (module docstring, "Lockstep").

    Cycle ``k`` is at ``k * period``; an answer arrives ``lockstep_latency_s``
    after its message was delivered. The bookkeeping: the newest delivered
    message that expects an answer, the newest one answered, and whether the
    client has answered at all or was taken for gone.
    """

    def __init__(self, emu: "RobotEmulator") -> None:
        super().__init__(emu)
        self.vt = 0.0  # virtual time of the current cycle [s]
        self.epoch_ns = time.time_ns()  # wall-clock stamp of virtual time 0 for the messages' timestamps
        self.await_seq = -1  # newest delivered message that expects an answer
        self.await_data = b""
        self.heard_seq = -1  # newest message an answer reflected
        self.heard_any = False
        self.gone = False
        self.resent_seq = -1
        self.resent_heard = False
        self.ring_delay = [0.0] * _RING  # injected delivery delay of each message [s]

    def start(self) -> None:
        self.t0 = time.perf_counter()

    def wait(self, k: int) -> int:
        """Deliver what the faults delayed until cycle ``k``, then wait for the outstanding answers."""
        emu = self.emu
        cfg = emu.config
        self.vt = k * emu._period
        pending = emu._pending
        limit = self.vt - cfg.lockstep_latency_s + 1e-12  # answers to these can still arrive by this cycle
        while pending and pending[0][0] <= limit:
            due, _, item = heapq.heappop(pending)
            emu._deliver(item, due)
        emu._drain()
        if self.await_seq <= self.heard_seq:
            return k
        if self.gone and (emu._state in _COMMANDING or emu._ending):
            return k  # silence runs its course: the session drops after timeout_s, or the run closes
        resend = self.gone or not self.heard_any  # no client (yet): stop the clock until one answers
        perf = time.perf_counter
        max_wall = cfg.max_wall_s
        now = perf()
        deadline = now + cfg.lockstep_guard_s
        next_resend = now + RESEND_S
        while True:
            if emu._stop_requested:  # the session closes without waiting for a client that has finished
                return k
            if max_wall is not None and now - self.t0 >= max_wall:
                return k
            if resend:
                if now >= next_resend:
                    self._resend()
                    next_resend = now + RESEND_S
                wake = next_resend
            elif now >= deadline:
                self.gone = True
                emu._report.client_gone += 1
                if emu._on_event is not None:
                    emu._on_event(self.vt, f"no answer within {cfg.lockstep_guard_s:g} s: client taken for gone")
                return k
            else:
                wake = deadline
            # Short sleeps keep stop requests from other threads and signal handlers prompt.
            select.select((emu._sock,), (), (), min(max(wake - now, 0.0), 0.05))
            emu._drain()
            if self.await_seq <= self.heard_seq:
                return k
            now = perf()

    def _resend(self) -> None:
        """Send the newest awaited message again (a client that starts late, or came back)."""
        self.emu._report.resent += 1
        if self.resent_seq != self.await_seq:
            self.resent_seq, self.resent_heard = self.await_seq, False
        self.emu._sendto(self.await_data)

    def now(self) -> float:
        return self.vt

    def stamp_ns(self) -> int:
        return self.epoch_ns + int(round(self.vt * 1e9))

    def arrival(self, data: bytes, addr: Any) -> float | None:
        """Virtual arrival time of an answer; None for a second answer to a message sent again."""
        emu = self.emu
        if addr[:2] != emu._client:
            return self.vt
        try:
            reflected = decode_command(data, check=False).header.reflected_sequence_counter
        except FriDecodeError:
            return self.vt  # the cycle logic counts it as invalid
        if reflected == self.resent_seq:
            if self.resent_heard:
                emu._report.resent_answers += 1
                return None
            self.resent_heard = True
        self.heard_any = True
        self.gone = False
        slot = reflected & (_RING - 1)
        if emu._ring_seq[slot] != reflected:
            # Not a recent message of ours (a corrupted counter the client reflected): it answers nothing awaited.
            return self.vt
        if reflected > self.heard_seq:
            self.heard_seq = reflected
        return emu._ring_t[slot] + self.ring_delay[slot] + emu.config.lockstep_latency_s

    def sends(self, slot: int, state: SessionState) -> bool:
        self.ring_delay[slot] = 0.0
        # The session of a client taken for gone runs out its timeout unheard: a client started since
        # (while the robot side waited out the guard time) must meet the dropped session, as it would
        # on the robot seconds later, and not pick up the old one at a machine-dependent cycle.
        return not (self.gone and state in _COMMANDING)

    def delivered(self, data: bytes, seq: int, due: float | None) -> None:
        emu = self.emu
        slot = seq & (_RING - 1)
        if emu._ring_seq[slot] == seq:
            self.ring_delay[slot] = (self.vt if due is None else due) - emu._ring_t[slot]
        if seq > self.await_seq:
            self.await_seq, self.await_data = seq, data


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
        self._client = _resolve(config.client, "client", allow_any_port=False)
        bind = _resolve(config.bind, "bind", allow_any_port=True)
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
        self._stop_requested = False
        self._ran = False

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` of the robot-side socket, the address the client answers to."""
        return self._address

    def stop(self) -> None:
        """Ask :meth:`run` to close the session and return (thread- and signal-safe)."""
        # A single attribute store: safe from signal handlers and other threads.
        self._stop_requested = True

    def close(self) -> None:
        """Close the socket (done by :meth:`run`; needed only if it never runs)."""
        self._sock.close()

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
            self._sock.close()
            if freeze:
                gc.unfreeze()
        return self._report

    def _setup_run(self) -> None:
        cfg = self.config
        T = self._period
        self._report = EmulatorReport(lockstep=cfg.lockstep)
        # Separate generators for each direction: which cycle an answer falls into must not change the
        # faults injected into the messages (it can vary in real time).
        self._rng = random.Random(cfg.faults.seed)
        self._rng_in = random.Random(f"{cfg.faults.seed}:answers")
        self._inbox: list[tuple[float, bytes, Any, int]] = []
        # Datagrams to the client: (bytes, sequence counter, whether an answer is expected).
        self._pending: list[tuple[float, int, tuple[bytes, int, bool]]] = []  # heap of (due, order, datagram)
        self._order = 0
        self._held: list[tuple[bytes, int, bool]] | None = None
        self._clock: _RealTimeClock | _LockstepClock = (_LockstepClock if cfg.lockstep else _RealTimeClock)(self)
        self._seq = 0  # next own sequence counter
        self._client_seq: int | None = None  # newest accepted client sequence counter
        self._ring_seq = [-1] * _RING
        self._ring_t = [0.0] * _RING
        self._ring_state = [0] * _RING
        self._window: deque[tuple[int, float]] = deque()
        self._w_answered = 0
        self._w_latency = 0.0
        self._w_pushes = 0
        self._latency = _Histogram()
        self._delay = _Histogram()
        self._due = False  # an answer is due this cycle
        self._silent = 0  # consecutive cycles without a new answer while one was due
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
        self._zero7 = (0.0,) * _N_JOINTS
        self._robot_info = self._info(SafetyState.NORMAL_OPERATION)
        self._meas = self._robot.start()
        self._hold(self._meas.q_m)
        self._positions = self._measured_positions(self._meas)
        self._q_prev = self._meas.q_m  # the previous measurement's position, for the speed [rad]
        self._limits = self._plant.limits
        self._brake: tuple[float, float, int] | None = None  # safety stop: (q, v, simulation step) at its start
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
        return RobotInfo(number_of_joints=_N_JOINTS, safety_state=safety, drive_state=(DriveState.ACTIVE,) * _N_JOINTS,
                         operation_mode=cfg.operation_mode, control_mode=cfg.control_mode)

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
            self._cycle(k)
            if self._finished:
                return
            k += 1

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
                self._judged(0, 0.0)
            else:
                self._silent = 0
                self._judged(1, answer[1] or 0.0)
        elif answer is not None:
            self._silent = 0
        if state != SessionState.IDLE:
            self._quality = self._judge_quality()
            rep.quality[self._quality.name] += 1
        self._session(k, answer, error)
        state = self._state
        if state == SessionState.COMMANDING_ACTIVE:
            violation = self._limit_violation()
            if violation:
                self._safety_stop(k, violation)
                state = self._state
        if state == SessionState.COMMANDING_ACTIVE and answer is not None and answer[2] == state:
            cd = answer[0].command_data
            self._cmd_pos = tuple(cd.joint_position.value)
            self._cmd_tau = tuple(cd.joint_torque.value) if cd.HasField("joint_torque") else None
        if self._restart_now:
            # This cycle's message carries the restarted simulation's first measurement.
            self._restart_now = False
            meas = self._meas
        else:
            command = self._command(state)
            if self._rows is not None:
                self._record(self._meas, command)
            self._q_prev = self._meas.q_m
            self._meas = meas = self._robot.step(command)
            self._sim_k += 1
        self._positions = self._measured_positions(meas)
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

    def _take_answers(self) -> tuple[tuple[CommandMessage, float | None, int | None] | None, str | None]:
        """This cycle's newest answer ``(message, latency, state it answers)`` and the first command problem."""
        rep = self._report
        faults = self.config.faults
        rng = self._rng_in
        answer = None
        error = None
        commanding = self._state in _COMMANDING
        inbox, self._inbox = self._inbox, []
        for t_arrival, data, addr, latest in inbox:
            if faults.loss and rng.random() < faults.loss:
                self._count_fault("loss", "loss_in")
                continue
            if faults.corrupt and rng.random() < faults.corrupt:
                self._count_fault("corrupt", "corrupt_in")
                data = self._corrupt(data)
            if addr[:2] != self._client:
                rep.answers_foreign += 1
                continue
            try:
                msg = decode_command(data, check=False)  # content: see _check_command
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
            slot = reflected & (_RING - 1)
            if self._ring_seq[slot] == reflected:
                latency = t_arrival - self._ring_t[slot]
                answered_state = self._ring_state[slot]
                self._latency.add(latency)
                if reflected < latest:
                    rep.late_answers += 1
            else:
                latency = answered_state = None
            answer = (msg, latency, answered_state)
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

    def _judged(self, answered: int, latency: float) -> None:
        """Add one cycle with an answer due to the quality window (running sums, O(1))."""
        w = self._window
        w.append((answered, latency))
        self._w_answered += answered
        self._w_latency += latency
        if len(w) > self.config.quality.window:
            a, lat = w.popleft()
            self._w_answered -= a
            self._w_latency -= lat
        self._w_pushes += 1
        if self._w_pushes % 10_000 == 0:  # keep rounding errors of the running sum from piling up
            self._w_latency = math.fsum(lat for _, lat in w)

    def _judge_quality(self) -> ConnectionQuality:
        n = self._w_answered
        mean = self._w_latency / n if n else None
        return connection_quality(n, len(self._window), mean, self._period, self.config.quality)

    def _session(self, k: int, answer, error: str | None) -> None:
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
        """Close the session at once (stop request or wall-time limit)."""
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
        self._brake = (self._meas.q_m, v, self._sim_k)
        self._robot_info = self._info(SafetyState.SAFETY_STOP_LEVEL_1)
        if self._on_event is not None:
            self._on_event(t, f"safety stop: {reason}")
        self._ending = True
        # The session closes once the joint has braked to rest (the ramp, the delay, time to settle).
        self._closing_s = max(self.config.closing_s,
                              abs(v) / self.config.brake_decel_rad_s2 + self._reaction_s + BRAKE_SETTLE_S)
        self._enter(k, SessionState.MONITORING_READY)
        self._hold(self._brake_position(math.inf))

    def _brake_position(self, t: float) -> float:
        """The braking ramp's position ``t`` [s] after the safety stop began [rad]."""
        q, v, _ = self._brake
        a = math.copysign(self.config.brake_decel_rad_s2, v)
        t = min(t, abs(v) / self.config.brake_decel_rad_s2)
        return q + v * t - 0.5 * a * t * t

    def _command(self, state: SessionState) -> Command:
        if self._brake is not None:
            return Command(q_cmd=self._brake_position((self._sim_k - self._brake[2]) * self._period))
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

    def _record(self, meas: Measurement, command: Command) -> None:
        rows = self._rows
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
        tau = [0.0] * _N_JOINTS
        tau[j] = meas.tau_j
        ext = [0.0] * _N_JOINTS
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
        slot = seq & (_RING - 1)
        self._ring_seq[slot] = seq
        self._ring_t[slot] = self._clock.now()
        self._ring_state[slot] = state
        self._seq = seq + 1
        if not self._clock.sends(slot, state):
            self._report.unsent += 1
            return
        self._report.monitoring_sent += 1
        self._emit(data, seq, state != SessionState.IDLE)

    def _emit(self, data: bytes, seq: int, expects_answer: bool) -> None:
        """Send one robot-to-client datagram through the fault injection."""
        faults = self.config.faults
        if not faults.any:
            self._deliver((data, seq, expects_answer))
            return
        rng = self._rng
        counts = self._report.faults
        if faults.loss and rng.random() < faults.loss:
            self._count_fault("loss", "loss_out")
            return
        if faults.corrupt and rng.random() < faults.corrupt:
            self._count_fault("corrupt", "corrupt_out")
            data = self._corrupt(data)
            expects_answer = False  # the client cannot decode it
        item = (data, seq, expects_answer)
        group = [item]
        if faults.duplicate and rng.random() < faults.duplicate:
            counts["duplicate"] += 1
            group.append(item)
        if self._held is not None:
            group += self._held
            self._held = None
        elif faults.reorder and rng.random() < faults.reorder:
            counts["reorder"] += 1
            self._held = group
            return
        if faults.jitter_s:
            counts["jitter"] += 1
            due = self._clock.now() + rng.uniform(0.0, faults.jitter_s)
            for d in group:
                self._order += 1
                heapq.heappush(self._pending, (due, self._order, d))
        else:
            for d in group:
                self._deliver(d)

    def _deliver(self, item: tuple[bytes, int, bool], due: float | None = None) -> None:
        """Hand a datagram to the socket; in lockstep its answer is now awaited (``due``: virtual delivery time)."""
        data, seq, expects_answer = item
        self._sendto(data)
        if expects_answer:
            self._clock.delivered(data, seq, due)

    def _count_fault(self, kind: str, direction: str) -> None:
        counts = self._report.faults
        counts[kind] += 1
        counts[direction] += 1

    def _sendto(self, data: bytes) -> None:
        try:
            self._sock.sendto(data, self._client)
        except OSError:
            self._report.send_errors += 1

    def _corrupt(self, data: bytes) -> bytes:
        rng = self._rng
        buf = bytearray(data)
        if buf:
            for _ in range(rng.randint(1, 3)):
                buf[rng.randrange(len(buf))] ^= rng.randint(1, 255)
        return bytes(buf)

    # -- end ------------------------------------------------------------------
    def _finish(self) -> None:
        rep = self._report
        for d in self._held or ():
            self._sendto(d[0])
        self._held = None
        while self._pending:
            self._sendto(heapq.heappop(self._pending)[2][0])
        if not rep.end_reason:
            rep.end_reason = "duration"
        rep.wall_s = self._clock.wall()
        rep.latency_median_s = self._latency.quantile(0.5)
        rep.latency_p99_s = self._latency.quantile(0.99)
        rep.latency_max_s = self._latency.max if self._latency.n else None
        rep.cycle_delay_median_s = self._delay.quantile(0.5)
        rep.cycle_delay_p99_s = self._delay.quantile(0.99)
        rep.cycle_delay_max_s = self._delay.max if self._delay.n else None
        if self._rows is not None:
            try:
                rep.dataset = write_dataset(self.config.record, self._dataset())
            except IiwaIdentError as err:
                rep.dataset_error = str(err)

    def _dataset(self) -> Dataset:
        cfg = self.config
        rep = self._report
        signals = {name: np.frombuffer(col, dtype=np.float64).copy() for name, col in self._rows.items()}
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


# --------------------------------------------------------------------------- separate process


def _watch_stop(conn, emulator: RobotEmulator) -> None:
    """Stop the emulator on a message from the parent, or when the parent has gone (EOF)."""
    try:
        conn.recv()
    except (EOFError, OSError):
        pass
    emulator.stop()


def _child_main(config: EmulatorConfig, conn, stop_conn) -> None:
    """Entry point of the emulator process: report the address, run, send the report."""
    try:
        emulator = RobotEmulator(config)
    except Exception as err:  # noqa: BLE001  (any failure must reach the parent as a message)
        conn.send(("error", str(err) if isinstance(err, IiwaIdentError) else f"{type(err).__name__}: {err}"))
        conn.close()
        return
    # Ctrl-C reaches the whole process group: close the session cleanly instead of dying.
    signal.signal(signal.SIGINT, lambda *_: emulator.stop())
    signal.signal(signal.SIGTERM, lambda *_: emulator.stop())
    threading.Thread(target=_watch_stop, args=(stop_conn, emulator), daemon=True).start()
    conn.send(("address", emulator.address))
    try:
        report = emulator.run()
    except Exception as err:  # noqa: BLE001
        message = ("error", f"emulator failed: {type(err).__name__}: {err}")
    else:
        message = ("report", report)
    try:
        conn.send(message)
    except OSError:
        pass  # the parent has gone
    conn.close()


class EmulatorProcess:
    """A :class:`RobotEmulator` running in its own process (see :func:`spawn_emulator`).

    Attributes
    ----------
    address : (str, int)
        The robot-side socket's address.
    """

    def __init__(self, config: EmulatorConfig, start_timeout_s: float = 60.0) -> None:
        check_config(config)
        ctx = multiprocessing.get_context("spawn")
        # Two one-way pipes: the child's messages, and the stop request. (A multiprocessing
        # Event would hang the parent's set() once the waiting child has exited.)
        self._conn, child_conn = ctx.Pipe(duplex=False)
        stop_reader, self._stop_conn = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=_child_main, args=(config, child_conn, stop_reader),
                                    name="iiwa-fri-emulator", daemon=True)
        self._process.start()
        child_conn.close()
        stop_reader.close()
        self._report: EmulatorReport | None = None
        try:
            kind, value = self._receive(start_timeout_s, "start")
        except IiwaIdentError:
            self._shut_down()
            raise
        if kind != "address":
            self._shut_down()
            raise IiwaIdentError(value)
        self.address: tuple[str, int] = tuple(value)

    def _shut_down(self) -> None:
        """End the process if it still runs (SIGTERM stops the emulator cleanly) and close the pipes."""
        self._process.join(5.0 if self._report is not None else 0.5)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(5.0)
        self._conn.close()
        self._stop_conn.close()

    def _receive(self, timeout: float | None, what: str) -> tuple[str, Any]:
        try:
            ready = self._conn.poll(timeout)
        except (OSError, EOFError):
            ready = True
        if not ready:
            raise IiwaIdentError(f"the emulator process did not {what} within {timeout:g} s")
        try:
            return self._conn.recv()
        except (EOFError, OSError):
            self._process.join(5.0)
            raise IiwaIdentError(f"the emulator process exited (code {self._process.exitcode}) "
                                 f"before it could {what}") from None

    def stop(self) -> None:
        """Ask the emulator to close the session and end."""
        try:
            self._stop_conn.send("stop")
        except (OSError, ValueError):
            pass  # the process has ended already (or the pipe is closed)

    def join(self, timeout: float | None = None) -> EmulatorReport:
        """Wait for the run to end and return its report.

        Parameters
        ----------
        timeout : float or None
            Longest wait [s]; None waits as long as it takes.

        Raises
        ------
        IiwaIdentError
            If the run does not end in time or the process fails.
        """
        if self._report is None:
            kind, value = self._receive(timeout, "finish")
            if kind != "report":
                self._process.join(5.0)
                raise IiwaIdentError(value)
            self._report = value
            self._process.join(5.0)
        return self._report

    def kill(self) -> None:
        """End the emulator process at once (SIGKILL), as a robot that vanishes: nothing more is sent.

        No report follows; :meth:`join` then raises.
        """
        self._process.kill()
        self._process.join(5.0)

    @property
    def alive(self) -> bool:
        """Whether the emulator process is still running."""
        return self._process.is_alive()

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        try:
            self.join(10.0)
        except IiwaIdentError:
            pass
        finally:
            self._shut_down()


def spawn_emulator(config: EmulatorConfig, start_timeout_s: float = 60.0) -> EmulatorProcess:
    """Start a :class:`RobotEmulator` in a separate process.

    The emulator gets its own interpreter (``spawn`` start method), so it
    does not share the GIL with the client under test.

    Parameters
    ----------
    config : EmulatorConfig
        Settings (must be picklable; the default plant is).
    start_timeout_s : float
        Longest wait for the process to import and bind its socket [s].

    Returns
    -------
    EmulatorProcess
        Running; its ``address`` is known. Use it as a context manager, or
        call ``stop()`` and ``join()``.

    Raises
    ------
    IiwaIdentError
        For a bad setting, a socket that cannot be bound, or a process that
        does not start.
    """
    return EmulatorProcess(config, start_timeout_s)
