"""The robot interface every experiment drives, and the joint limits.

An experiment sends one cycle's :class:`Command` and receives the next
:class:`Measurement`. The simulated joint (:mod:`iiwa_ident.sim`) and the FRI
runtime implement the same :class:`RobotInterface`, so an experiment runs
unchanged on either.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

from iiwa_ident.errors import IiwaIdentError

__all__ = [
    "Command",
    "Measurement",
    "JointLimits",
    "RobotInterface",
    "joint_limits",
    "ROBOT_MODELS",
]


@dataclass(frozen=True)
class JointLimits:
    """Data-sheet limits of one joint.

    Attributes
    ----------
    position_rad : float
        Symmetric range of motion, ``|q| <= position_rad`` [rad].
    velocity_rad_s : float
        Maximum joint speed [rad/s].
    torque_nm : float
        Maximum joint torque [Nm].
    """

    position_rad: float
    velocity_rad_s: float
    torque_nm: float


def _limits(deg: float, deg_s: float, nm: float) -> JointLimits:
    return JointLimits(math.radians(deg), math.radians(deg_s), nm)


# KUKA data sheets (LBR iiwa 7 R800, LBR iiwa 14 R820): range, speed, torque per axis.
ROBOT_MODELS: dict[str, tuple[JointLimits, ...]] = {
    "iiwa7": (
        _limits(170, 98, 176), _limits(120, 98, 176), _limits(170, 100, 110),
        _limits(120, 130, 110), _limits(170, 140, 110), _limits(120, 180, 40),
        _limits(175, 180, 40),
    ),
    "iiwa14": (
        _limits(170, 85, 320), _limits(120, 85, 320), _limits(170, 100, 176),
        _limits(120, 75, 176), _limits(170, 130, 110), _limits(120, 135, 40),
        _limits(175, 135, 40),
    ),
}


def joint_limits(model: str, joint: int) -> JointLimits:
    """Return the data-sheet limits of ``joint`` (1-7) of robot ``model``."""
    if model not in ROBOT_MODELS:
        raise IiwaIdentError(f"unknown robot model {model!r} (known: {', '.join(ROBOT_MODELS)})")
    if not 1 <= joint <= 7:
        raise IiwaIdentError(f"joint must be 1..7, got {joint}")
    return ROBOT_MODELS[model][joint - 1]


@dataclass(frozen=True)
class Command:
    """One cycle's command to the joint.

    Exactly one of the two is set: ``tau_c`` in torque mode, ``q_cmd`` in
    position mode.

    Attributes
    ----------
    tau_c : float or None
        Commanded joint torque [Nm], added to the robot's own gravity model.
    q_cmd : float or None
        Commanded joint position [rad] for the robot's position controller.
    """

    tau_c: float | None = None
    q_cmd: float | None = None

    def __post_init__(self) -> None:
        if (self.tau_c is None) == (self.q_cmd is None):
            raise IiwaIdentError("a command sets exactly one of tau_c and q_cmd")


@dataclass(frozen=True)
class Measurement:
    """What the robot reports once per cycle (FRI monitoring data).

    Attributes
    ----------
    t : float
        Time since the start [s].
    q_m : float
        Measured joint position, motor side, encoder-quantised [rad].
    tau_j : float
        Measured joint torque [Nm].
    tau_ext_fri : float
        The robot's own external-torque estimate, eq (13) [Nm].
    q_l_ref : float or None
        External precision link-position measurement, if fitted [rad].
    tau_ext_ref : float or None
        External F/T-sensor torque about the joint axis, if fitted [Nm].
    """

    t: float
    q_m: float
    tau_j: float
    tau_ext_fri: float
    q_l_ref: float | None = None
    tau_ext_ref: float | None = None


class RobotInterface(ABC):
    """One joint of a robot, commanded once per cycle.

    Subclasses: :class:`iiwa_ident.sim.SimulatedJoint` and the FRI runtime.
    ``start`` returns the first measurement; each ``step`` sends one command
    and returns the measurement of the next cycle.
    """

    #: ``"simulation"`` or ``"robot"``, as recorded in datasets.
    source: str = "robot"
    #: Joint number 1-7.
    joint: int
    #: Cycle time [s] (1e-3 for FRI at 1 kHz).
    sample_time_s: float
    #: Data-sheet limits of the joint.
    limits: JointLimits
    #: Cycles the robot sent but the client never saw before the latest measurement
    #: (0 on a simulated joint; FRI counts gaps in the robot's sequence counter).
    missed_cycles: int = 0
    #: Time from receiving the latest measurement to sending the command that answered it [ns],
    #: if the interface measures it (FRI); 0 otherwise.
    last_compute_ns: int = 0

    @abstractmethod
    def start(self) -> Measurement:
        """Begin a session and return the first measurement."""

    @abstractmethod
    def step(self, command: Command) -> Measurement:
        """Send one cycle's command and return the next measurement."""

    def stop(self) -> None:  # noqa: B027  (optional: an interface without a session has nothing to end)
        """End the session (the default does nothing)."""

    def describe(self) -> dict:
        """Facts about the robot worth recording with a dataset."""
        return {}

    def set_agent(self, agent) -> None:  # noqa: B027  (optional: a real robot's outside is the operator)
        """Attach what acts on the link from outside (a simulated arm or drive).

        On a real robot that is the operator or the test rig, so the default does nothing.
        """

    def truth(self) -> dict | None:
        """Ground truth to store with a dataset (simulation only; None for a real robot)."""
        return None

    def __enter__(self) -> RobotInterface:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
