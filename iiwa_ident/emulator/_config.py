"""Settings of the robot emulator and their checks.

:class:`EmulatorConfig` holds everything a run is set up with: the addresses,
the simulated joint, the FRI modes, the session's phase lengths, the
injected network faults (:class:`Faults`, applied by
:mod:`iiwa_ident.emulator._faults`), how the connection quality is judged
(:class:`QualityThresholds`, :mod:`iiwa_ident.emulator._quality`), the hand
that moves the link, the recording and the clock. :func:`check_config`
refuses a bad setting with one line naming it.

Units: seconds, rad, Nm unless a name says otherwise.
"""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.fri import N_JOINTS, ClientCommandMode, ControlMode, OperationMode
from iiwa_ident.netft import NetFtSettings
from iiwa_ident.robot import joint_limits
from iiwa_ident.sim import Plant, default_plant

__all__ = ["DEFAULT_JOINT_POSITIONS", "AGENTS", "Faults", "QualityThresholds", "EmulatorConfig", "check_config",
           "resolve_address"]

#: Default arm pose [rad]: 0, 30, 0, -90, 0, 60, 0 degrees.
DEFAULT_JOINT_POSITIONS: tuple[float, ...] = tuple(
    math.radians(d) for d in (0.0, 30.0, 0.0, -90.0, 0.0, 60.0, 0.0)
)
#: Values of :attr:`EmulatorConfig.agent`.
AGENTS = ("hand",)


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


@dataclass(frozen=True, kw_only=True)
class QualityThresholds:
    """How the emulator judges the connection quality (:mod:`iiwa_ident.emulator._quality`).

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


@dataclass(kw_only=True)
class EmulatorConfig:
    """Settings of a :class:`RobotEmulator`.

    Attributes
    ----------
    client : (str, int)
        Address the FRI client listens on (IPv4 host or name, port).
    bind : (str, int)
        Address of the robot-side socket; port 0 picks a free port.
    plant : Plant or None
        The simulated joint (default: :func:`~iiwa_ident.sim.default_plant`);
        its cycle must equal the send period.
    seed : int
        Seed of the simulated sensor noise.
    control_mode : int
        :class:`~iiwa_ident.fri.ControlMode` reported; torque mode
        needs ``JOINT_IMPEDANCE``.
    client_command_mode : int
        ``ClientCommandMode.TORQUE`` or ``ClientCommandMode.POSITION``.
    operation_mode : int
        :class:`~iiwa_ident.fri.OperationMode` reported.
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
        Deceleration of the robot's safety stop [rad/s^2] (:mod:`iiwa_ident.emulator._robot_side`,
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
        Run on a virtual clock, waiting for each answer (:mod:`iiwa_ident.emulator._clocks`,
        "Lockstep") instead of in real time.
    lockstep_latency_s : float
        Lockstep: time from a monitoring message's delivery to its answer's
        arrival [s], below one send period.
    lockstep_guard_s : float
        Lockstep: wall time after which a client that has not answered is
        taken for gone [s].
    idle_timeout_s : float or None
        End the run once a client has been heard and nothing has come from it
        for this long outside the commanding states [s] (its session over, or
        dropped, and no client back); None waits for a client for ever. In
        lockstep the silence is wall time (the virtual clock stops while no
        client answers), counted once the client was taken for gone
        (``lockstep_guard_s``).
    stalls : tuple of (float, float)
        Robot-side stalls ``(start, length)`` [s], the start counted in time
        of ``COMMANDING_ACTIVE``: for ``length`` the robot sends no
        monitoring message and awaits no answer, as when the controller
        cabinet's own cycle slips. The joint moves on under the last command,
        the messages' time stamps keep the time, and the sequence counter
        does not jump (it counts messages sent), so a client sees the
        silence only in the time stamps (or on its own clock).
    ft_port : int or None
        Serve a Net F/T over RDT on this UDP port of the bind host (0: any free port), streaming
        the simulated joint's external torque (its F/T reference, with the plant's F/T noise) as
        the wrench of a hand pushing at a sensor on the flange (:mod:`iiwa_ident.netft`).
    ft : NetFtSettings
        The emulated sensor's output rate, filter, calibration and own noise (seeded by ``seed``).
    ft_lever_m : float or None
        The sensor's lever arm about the joint's axis [m]; None: the flange's geometry from the
        robot's description at ``joint_positions``.
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
    idle_timeout_s: float | None = None
    stalls: tuple[tuple[float, float], ...] = ()
    ft_port: int | None = None
    ft: NetFtSettings = field(default_factory=NetFtSettings)
    ft_lever_m: float | None = None


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
    _finite("idle_timeout_s", config.idle_timeout_s, allow_none=True, strict=True)
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
    if len(pose) != N_JOINTS or not all(isinstance(q, (int, float)) and math.isfinite(q) for q in pose):
        raise IiwaIdentError(f"joint_positions must be {N_JOINTS} finite angles [rad], got {config.joint_positions!r}")
    plant = config.plant or default_plant()
    if abs(plant.cycle_s - config.send_period_ms * 1e-3) > 1e-12:
        raise IiwaIdentError(
            f"the plant's cycle {plant.cycle_s * 1e3:g} ms differs from send_period_ms {config.send_period_ms}")
    for i, q in enumerate(pose):
        limit = joint_limits(plant.robot_model, i + 1).position_rad
        if abs(q) > limit:
            raise IiwaIdentError(f"joint_positions[{i}] = {q:g} rad is outside joint {i + 1}'s range +-{limit:.3f} rad")
    resolve_address(config.client, "client", allow_any_port=False)
    resolve_address(config.bind, "bind", allow_any_port=True)
    if config.ft_port is not None:
        if not isinstance(config.ft_port, int) or not 0 <= config.ft_port <= 65535:
            raise IiwaIdentError(f"ft_port must be a UDP port 0-65535, got {config.ft_port!r}")
        if not plant.ft_sensor:
            raise IiwaIdentError("an F/T sensor needs a plant with sensors.ft_sensor = true")
        if not isinstance(config.ft, NetFtSettings):
            raise IiwaIdentError("ft must be a NetFtSettings instance")
        _finite("ft_lever_m", config.ft_lever_m, allow_none=True)


def resolve_address(address: Any, name: str, allow_any_port: bool) -> tuple[str, int]:
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
    return str(info[0][4][0]), port

