"""The additive controller of section V.B, one call per 1 kHz cycle: eqs (16)-(18) of a design.

The design (gains, feed-forward, reference model) is :mod:`iiwa_ident.design._additive`;
what runs on the robot is :class:`AdditiveController`, stepped by the control
cycle (:class:`~iiwa_ident.design.ControlCycle`) in the closed-loop analysis and
the FRI runtime alike.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

__all__ = ["AdditiveController", "DiscreteDesign"]


class DiscreteDesign(Protocol):
    """What :class:`AdditiveController` runs on: the discrete model and gains of a design
    (:class:`~iiwa_ident.design.AdditiveDesign`, or a controller config, which holds no continuous data)."""

    Ad: Any  # [4x4] discrete model of eqs (19)-(21)
    Bd: Any  # [4]
    Kd: Any  # [4] state feedback
    Ld: Any  # [4] observer gain
    Kr_d: float  # reference gain
    feedforward: str  # the feed-forward mode
    ffd: Any  # discrete pre-filter (A, B, C, D), or None


class AdditiveController:
    """The discrete additive controller, one call per 1 kHz cycle.

    ``tau_c = step(tau_r, tau_j_filt)`` runs eqs (16)-(18) of the design's
    feed-forward mode (:mod:`iiwa_ident.design._additive`). Feed the spatially filtered joint
    torque of eq (15) as ``tau_j_filt`` and send the returned ``tau_c`` in
    the same cycle.

    The cycle is plain float arithmetic on lists allocated once (the 4-state
    model of eqs (19)-(21) written out, the pre-filter as short loops): no
    array is built per call, which in NumPy costs about 1 µs per operation
    and made this 8 µs of a 13 µs runtime cycle.

    Parameters
    ----------
    design : DiscreteDesign
        The design (from :func:`design_controller` or a design file) or a controller config's part of it.
    """

    def __init__(self, design: DiscreteDesign) -> None:
        self.design = design
        Ad, Bd = np.array(design.Ad, float), np.array(design.Bd, float).ravel()
        Kd, Ld = np.array(design.Kd, float).ravel(), np.array(design.Ld, float).ravel()
        if Ad.shape != (4, 4) or any(v.shape != (4,) for v in (Bd, Kd, Ld)):
            raise ValueError(f"additive controller: a 4-state model is expected, got Ad of shape {Ad.shape}")
        self._A = [float(v) for v in Ad.ravel()]  # row-major
        self._B, self._Kd, self._L = ([float(v) for v in m] for m in (Bd, Kd, Ld))
        self._kr = float(design.Kr_d)
        self._reference = design.feedforward == "reference"
        if design.ffd is not None:
            Af, Bf, Cf, Df = design.ffd
            Af = np.atleast_2d(np.array(Af, float))
            self._Af: list[list[float]] | None = [[float(v) for v in row] for row in Af]
            self._Bf = [float(v) for v in np.array(Bf, float).ravel()]
            self._Cf = [float(v) for v in np.array(Cf, float).ravel()]
            self._Df = float(Df)
            self._nf = range(Af.shape[0])
        else:
            self._Af = None
            self._nf = range(0)
        self.x_hat = [0.0] * 4  #: observer state of eq (17)
        self.x_ref = [0.0] * 4  #: reference model's state (feed-forward "reference")
        self.x_ff = [0.0] * len(self._nf)  #: pre-filter state
        self._ff_next = [0.0] * len(self._nf)

    def reset(self) -> None:
        """Zero all states (observer, reference model, pre-filter), in place."""
        for x in (self.x_hat, self.x_ref, self.x_ff):
            for i in range(len(x)):
                x[i] = 0.0

    @staticmethod
    def _advance(x: list[float], A: list[float], B: list[float], u: float, L: list[float] | None = None,
                 e: float = 0.0) -> None:
        """``x <- A x + B u (+ L e)`` in place for the 4-state model."""
        x0, x1, x2, x3 = x
        if L is None:
            L0 = L1 = L2 = L3 = 0.0
        else:
            L0, L1, L2, L3 = L
        x[0] = A[0] * x0 + A[1] * x1 + A[2] * x2 + A[3] * x3 + B[0] * u + L0 * e
        x[1] = A[4] * x0 + A[5] * x1 + A[6] * x2 + A[7] * x3 + B[1] * u + L1 * e
        x[2] = A[8] * x0 + A[9] * x1 + A[10] * x2 + A[11] * x3 + B[2] * u + L2 * e
        x[3] = A[12] * x0 + A[13] * x1 + A[14] * x2 + A[15] * x3 + B[3] * u + L3 * e

    def step(self, tau_r: float, tau_j_filt: float) -> float:
        """One cycle: reference [Nm] and filtered joint torque [Nm] -> commanded torque [Nm]."""
        r = float(tau_r)
        x = self.x_hat
        Kd = self._Kd
        tau_fb = self._kr * r - (Kd[0] * x[0] + Kd[1] * x[1] + Kd[2] * x[2] + Kd[3] * x[3])  # eq (16)
        tau_ff = 0.0
        y_ref = 0.0
        if self._Af is not None:
            xf, nxt, Af, Bf, Cf = self.x_ff, self._ff_next, self._Af, self._Bf, self._Cf
            tau_ff = self._Df * r  # eq (22) behind the pre-filter
            for i in self._nf:
                tau_ff += Cf[i] * xf[i]
            for i in self._nf:
                row = Af[i]
                acc = Bf[i] * r
                for j in self._nf:
                    acc += row[j] * xf[j]
                nxt[i] = acc
            for i in self._nf:
                xf[i] = nxt[i]
            if self._reference:
                y_ref = self.x_ref[3]
                self._advance(self.x_ref, self._A, self._B, tau_ff)
        innovation = float(tau_j_filt) - y_ref - x[3]
        self._advance(x, self._A, self._B, tau_fb, self._L, innovation)  # eq (17)
        return tau_fb + tau_ff  # eq (18)
