"""External agents acting on a simulated link (a human arm, an external drive).

An agent maps substep times to rows ``(tau, pos, vel, k, d)``; the link
feels ``tau_ext = tau + k (pos - theta_l) + d (vel - omega_l)`` [Nm].
"""

from __future__ import annotations

import numpy as np

__all__ = ["ImpedanceAgent"]


class ImpedanceAgent:
    """A spring-damper pulling the link along a sampled trajectory.

    Parameters
    ----------
    t_grid : array
        Sample times of the trajectory [s]; held at the last sample beyond.
    position, velocity : array
        Trajectory [rad], [rad/s].
    stiffness, damping : float
        Impedance [Nm/rad], [Nm s/rad].
    torque : array, optional
        Additional torque profile on the same grid [Nm].
    """

    def __init__(self, t_grid, position, velocity, stiffness: float, damping: float, torque=None) -> None:
        self.t = np.asarray(t_grid, float)
        self.position = np.asarray(position, float)
        self.velocity = np.asarray(velocity, float)
        self.torque = None if torque is None else np.asarray(torque, float)
        self.stiffness, self.damping = float(stiffness), float(damping)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        out = np.empty((len(t), 5))
        out[:, 0] = 0.0 if self.torque is None else np.interp(t, self.t, self.torque)
        out[:, 1] = np.interp(t, self.t, self.position)
        out[:, 2] = np.interp(t, self.t, self.velocity)
        out[:, 3] = self.stiffness
        out[:, 4] = self.damping
        return out
