"""From the F/T sensor's wrench to the torque about one joint's axis, and back.

A sensor on the flange measures the force ``F`` [N] and moment ``M`` [Nm] a hand applies, in its own
frame. About joint ``j`` that is ``tau = axis . (lever x F + M)`` [Nm] with the joint's axis and the
sensor's origin relative to the joint (``lever`` [m]) in the sensor's frame: from the robot's
description at the pose the arm holds (:func:`~iiwa_ident.description.flange_axis`; the sensor's frame
taken as the flange's), or from a lever arm measured by hand.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from iiwa_ident.description import flange_axis
from iiwa_ident.errors import IiwaIdentError

__all__ = ["JointAxisProjection"]


@dataclass(frozen=True)
class JointAxisProjection:
    """``tau = axis . (lever x F + M)``: a sensor wrench about one joint's axis.

    Attributes
    ----------
    axis : tuple of 3 float
        The joint's unit axis in the sensor's frame.
    lever : tuple of 3 float
        The sensor's origin relative to a point on the joint's axis, in the sensor's frame [m].
    source : str
        Where the geometry comes from (for logs and reports).

    Examples
    --------
    >>> p = JointAxisProjection.from_lever_arm(0.5)
    >>> p.torque([0.0, 10.0, 0.0, 0.0, 0.0, 1.0])  # 10 N across a 0.5 m arm and 1 Nm about the axis
    6.0
    >>> p.torque(p.wrench(3.0))
    3.0
    """

    axis: tuple[float, float, float]
    lever: tuple[float, float, float]
    source: str = ""

    def __post_init__(self) -> None:
        a, r = np.asarray(self.axis, float), np.asarray(self.lever, float)
        if a.shape != (3,) or r.shape != (3,) or not (np.all(np.isfinite(a)) and np.all(np.isfinite(r))):
            raise IiwaIdentError("F/T projection: the axis and the lever are 3 finite numbers each")
        if abs(float(np.linalg.norm(a)) - 1.0) > 1e-6:
            raise IiwaIdentError(f"F/T projection: the axis must be a unit vector, got {a.tolist()}")

    @classmethod
    def from_description(cls, robot: str, joint: int, pose: Sequence[float]) -> JointAxisProjection:
        """The geometry of ``joint`` from the description of ``robot`` at ``pose`` [rad], sensor on the flange."""
        axis, lever = flange_axis(robot, joint, pose)
        return cls(tuple(float(x) for x in axis), tuple(float(x) for x in lever),  # type: ignore[arg-type]  # 3 each
                   f"{robot} description, joint {joint}, pose [" + ", ".join(f"{q:.4f}" for q in pose) + "] rad")

    @classmethod
    def from_lever_arm(cls, lever_m: float) -> JointAxisProjection:
        """A sensor ``lever_m`` [m] from the axis along its x, its z parallel to the axis."""
        if not (math.isfinite(lever_m) and lever_m >= 0):
            raise IiwaIdentError(f"F/T lever arm must be a distance >= 0 m, got {lever_m!r}")
        return cls((0.0, 0.0, 1.0), (float(lever_m), 0.0, 0.0), f"lever arm {lever_m:g} m")

    def torque(self, wrench: Sequence[float] | np.ndarray) -> float:
        """Torque about the axis [Nm] of a wrench ``[Fx, Fy, Fz, Tx, Ty, Tz]`` [N, Nm]."""
        w = np.asarray(wrench, float)
        a, r = np.asarray(self.axis), np.asarray(self.lever)
        return float(a @ (np.cross(r, w[:3]) + w[3:]))

    def coefficients(self, calibration_scale: Sequence[float] = (1.0,) * 6) -> tuple[float, ...]:
        """The torque as a weighted sum of the six channels, ``tau = sum(c_i w_i)``, each ``c_i`` divided by
        its channel's ``calibration_scale`` (counts per unit) so that raw counts go in: plain floats for
        the 1 kHz loop. ``axis . (lever x F) = (axis x lever) . F``."""
        a, r = np.asarray(self.axis), np.asarray(self.lever)
        c = np.concatenate([np.cross(a, r), a]) / np.asarray(calibration_scale, float)
        return tuple(float(x) for x in c)

    def wrench(self, tau: float) -> np.ndarray:
        """A wrench that loads the joint with ``tau`` [Nm]: a force at the sensor across the lever when it
        has one (a hand pushing at the sensor), else a moment about the axis."""
        a, r = np.asarray(self.axis), np.asarray(self.lever)
        t = np.cross(a, r)
        n2 = float(t @ t)
        out = np.zeros(6)
        if n2 > 1e-4:  # 1 cm off the axis
            out[:3] = tau * t / n2
        else:
            out[3:] = tau * a
        return out
