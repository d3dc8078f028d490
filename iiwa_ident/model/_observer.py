"""External-torque observer of eq (13) (generalised-momentum disturbance observer).

``tau_ext_hat(t) = KI [ p(t) - int_0^t (tau_J + tau_model + tau_ext_hat) dt - p(0) ]``
with ``p = Jl * velocity``. The robot's built-in observer feeds it the
motor-side velocity; ``tau_model`` is the torque the robot's own model
assigns to the link (gravity), zero for a joint without one.

Discretised at the sample time ``dt`` with a forward-Euler integral, the
form a 1 kHz controller runs: ``S_{k+1} = S_k + dt (tau_J,k + tau_model,k + tau_hat,k)``.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

__all__ = ["MomentumObserver"]


class MomentumObserver:
    """Eq (13), usable sample by sample (:meth:`update`) or on whole arrays (:meth:`filter`).

    Parameters
    ----------
    KI : float
        Observer gain [rad/s] (25 on the iiwa).
    Jl : float
        Link inertia [kg m^2].
    dt : float
        Sample time [s].
    """

    def __init__(self, KI: float, Jl: float, dt: float) -> None:
        self.KI, self.Jl, self.dt = float(KI), float(Jl), float(dt)
        self.reset()

    def reset(self) -> None:
        """Forget the past: the next :meth:`update` sets ``p(0)``."""
        self._p0: float | None = None
        self._S = 0.0

    def update(self, velocity: float, tau_j: float, tau_model: float = 0.0) -> float:
        """One sample: link velocity [rad/s], joint torque [Nm], model torque [Nm] -> estimate [Nm]."""
        p = self.Jl * velocity
        if self._p0 is None:
            self._p0 = p
        tau_hat = self.KI * (p - self._p0 - self._S)
        self._S += self.dt * (tau_j + tau_model + tau_hat)
        return tau_hat

    def filter(self, velocity: np.ndarray, tau_j: np.ndarray, tau_model: np.ndarray | float = 0.0) -> np.ndarray:
        """The estimate for whole arrays (same result as :meth:`update` sample by sample, from reset)."""
        velocity = np.asarray(velocity, float)
        p = self.Jl * velocity
        a = self.KI * (p - p[0])
        drive = self.dt * (np.asarray(tau_j, float) + tau_model + a)
        # S_{k+1} = (1 - KI dt) S_k + drive_k, S_0 = 0  ->  S_k is the filter output delayed by one.
        S_next = lfilter([1.0], [1.0, -(1.0 - self.KI * self.dt)], drive)
        S = np.concatenate([[0.0], S_next[:-1]])
        return a - self.KI * S
