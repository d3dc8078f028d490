"""The outer-loop gain margin of section V.C: ``tau_r = kappa tau_ext`` with a human hand on the link.

Section V.C closes ``tau_r = kappa tau_ext`` with the F/T torque of a human
hand holding the link. :func:`kappa_max` finds the largest such ``kappa``
keeping the sampled loop stable: plant of eqs (1)-(3) with the link, a hand
``tau_ext = -(K_h theta_l + D_h theta_l' + J_h theta_l'')``, zero-order hold,
the exact input delay (five cycles at Td = 5 ms, no Padé) and either the
built-in controller (``tau_c = tau_r``) or the discrete additive controller.
The spatial filter of eqs (10)-(12) is linear time-varying and speed
dependent; this linear analysis takes ``tau_J,filt = tau_J``. On Table I with
the default arm (K_h = 300 Nm/rad, D_h = 40 Nm s/rad, no hand inertia) and
the default design (paper poles, "reference" mode, 250 Hz pre-filter) the
model gives the margins of the example below, a ratio of about 4 (about 3 with
a 50 Hz pre-filter); the paper measured 4.6 and stability up to 15. The
margins depend strongly on the arm, above all on its damping.

Examples
--------
>>> from iiwa_ident.design import design_controller, table1_parameters
>>> params, _ = table1_parameters()
>>> m = outer_loop_margins(design_controller(params))
>>> round(m.builtin, 1), round(m.additive, 1)
(7.8, 32.9)
>>> round(kappa_max(params, design_controller(params, prefilter_hz=50.0)), 1)
23.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from iiwa_ident.design.additive import SAMPLE_TIME_S, AdditiveDesign, DesignError
from iiwa_ident.model import JointParameters, coefficients, delayed_hold

__all__ = ["HumanArm", "OuterLoopMargins", "arm_plant", "outer_loop_matrix", "exact_delay_spectral_radius",
           "kappa_max", "outer_loop_margins"]


@dataclass(frozen=True)
class HumanArm:
    """A hand holding the link: ``tau_ext = -(K_h theta_l + D_h theta_l' + J_h theta_l'')``.

    Attributes
    ----------
    stiffness : float
        Arm stiffness K_h about the joint axis [Nm/rad] (> 0).
    damping : float
        Arm damping D_h [Nm s/rad].
    inertia : float
        Hand/arm inertia J_h moving with the link, outboard of the F/T sensor [kg m^2].
    """

    stiffness: float = 300.0
    damping: float = 40.0
    inertia: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.stiffness) and self.stiffness > 0):
            raise DesignError(f"arm stiffness must be positive, got {self.stiffness!r}")
        for name in ("damping", "inertia"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise DesignError(f"arm {name} must be non-negative, got {v!r}")


def arm_plant(params: JointParameters, arm: HumanArm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eqs (1)-(3) with the link and the hand, without the delay.

    State ``[theta_j, z, theta_l, omega_l]`` with eq (1) integrated once,
    ``Jc theta_j' = (bc/K)(tau_c - tau_j) + z``, ``z' = tau_c - tau_j``.

    Returns
    -------
    A : ndarray (4, 4)
    B : ndarray (4,)
        Input ``tau_c`` [Nm].
    C : ndarray (2, 4)
        Outputs ``tau_j`` and ``tau_ext`` [Nm] (the F/T torque).
    """
    Jc, bc, K, Jl = params.Jc, params.bc, params.K, params.Jl
    Kh, Dh, Jh = arm.stiffness, arm.damping, arm.inertia
    Jt = Jl + Jh
    A = np.array([
        [-bc / Jc, 1.0 / Jc, bc / Jc, 0.0],
        [-K, 0.0, K, 0.0],
        [0.0, 0.0, 0.0, 1.0],
        [K / Jt, 0.0, -(K + Kh) / Jt, -Dh / Jt],
    ])
    B = np.array([bc / (K * Jc), 1.0, 0.0, 0.0])
    accel = A[3]
    C = np.vstack([[K, 0.0, -K, 0.0], -(np.array([0.0, 0.0, Kh, Dh]) + Jh * accel)])
    return A, B, C


def _sampled_loop(A: np.ndarray, B: np.ndarray, C_j: np.ndarray, C_r: np.ndarray, T: float, delay: float,
                  design: AdditiveDesign | None) -> np.ndarray:
    """State matrix of a ZOH plant with input delay under ``tau_c = controller(C_r x, C_j x)``.

    ``C_j x`` is the joint torque the controller measures, ``C_r x`` the
    reference ``tau_r`` (already multiplied by the outer-loop gain).
    """
    Phi, G0, G1, d = delayed_hold(A, B, T, delay)
    m = d + (1 if np.any(G1) else 0)  # stored past commands u[k-1] .. u[k-m]
    if design is None:
        Ac, Bc, Cc, Dc = np.zeros((0, 0)), np.zeros((0, 2)), np.zeros(0), np.array([1.0, 0.0])
    else:
        Ac, Bc, Cc, Dc = design.controller_matrices(discrete=True)
    n, nc = A.shape[0], Ac.shape[0]
    N = n + m + nc
    # u[k] = Cc xc + Dc_r tau_r  (no feed-through from tau_j)
    U = np.zeros(N)
    U[:n] = Dc[0] * C_r
    U[n + m:] = Cc
    M = np.zeros((N, N))
    M[:n, :n] = Phi
    for lag, gain in ((d, G0), (d + 1, G1)):
        if not np.any(gain):
            continue
        if lag == 0:
            M[:n] += np.outer(gain, U)
        else:
            M[:n, n + lag - 1] += gain
    if m:
        M[n] = U
        for i in range(1, m):
            M[n + i, n + i - 1] = 1.0
    if nc:
        M[n + m:, :n] = np.outer(Bc[:, 0], C_r) + np.outer(Bc[:, 1], C_j)
        M[n + m:, n + m:] = Ac
    return M


def outer_loop_matrix(params: JointParameters, kappa: float, design: AdditiveDesign | None = None,
                      arm: HumanArm = HumanArm(), sample_time_s: float | None = None) -> np.ndarray:
    """State matrix of the sampled loop ``tau_r = kappa tau_ext``.

    Parameters
    ----------
    params : JointParameters
        The plant (eqs (1)-(3), delay ``params.Td`` exactly).
    kappa : float
        Outer-loop gain [-].
    design : AdditiveDesign, optional
        The additive controller; None: the built-in controller (``tau_c = tau_r``).
    arm : HumanArm
        The hand holding the link.
    sample_time_s : float, optional
        Cycle [s] (default: the design's, or 1 ms).

    Returns
    -------
    ndarray
        ``M`` with ``X[k+1] = M X[k]``, ``X = [plant (4), past commands, controller]``;
        the loop is stable iff all eigenvalues lie inside the unit circle.
    """
    T = sample_time_s or (design.sample_time_s if design is not None else SAMPLE_TIME_S)
    A, B, C = arm_plant(params, arm)
    return _sampled_loop(A, B, C[0], kappa * C[1], T, params.Td, design)


def exact_delay_spectral_radius(design: AdditiveDesign, params: JointParameters | None = None) -> float:
    """Spectral radius of the 1 kHz additive loop on eq (4) with the exact delay instead of Padé.

    Below 1 the design survives the Padé approximation; poles too fast for
    the delay give values >= 1. ``tau_r = 0``; the link is free (the
    rigid-body mode of the link, which eq (4) cancels, is left out).

    Parameters
    ----------
    design : AdditiveDesign
        The controller.
    params : JointParameters, optional
        The plant (default: the design's model).
    """
    num, den = coefficients(params or design.params)
    import control as ct  # here: python-control takes a quarter of a second to import

    sys = ct.tf2ss(ct.tf(num, den))
    A, B, C = np.asarray(sys.A, float), np.asarray(sys.B, float).ravel(), np.asarray(sys.C, float).ravel()
    M = _sampled_loop(A, B, C, np.zeros_like(C), design.sample_time_s, (params or design.params).Td, design)
    return _spectral_radius(M)


def _spectral_radius(M: np.ndarray) -> float:
    return float(np.abs(np.linalg.eigvals(M)).max())


def kappa_max(params: JointParameters, design: AdditiveDesign | None = None, arm: HumanArm = HumanArm(),
              kappa_limit: float = 100.0, resolution: float = 0.05, tol: float = 1e-4) -> float:
    """Largest outer-loop gain ``kappa`` for which ``tau_r = kappa tau_ext`` is stable.

    Scans ``kappa`` upward from 0 in steps of ``resolution`` until the
    spectral radius of :func:`outer_loop_matrix` reaches 1, then bisects to
    ``tol``. An unstable window narrower than ``resolution`` can be missed.

    Parameters
    ----------
    params : JointParameters
        The plant.
    design : AdditiveDesign, optional
        Additive controller; None for the built-in one.
    arm : HumanArm
        The hand.
    kappa_limit : float
        Search limit [-]; ``math.inf`` is returned if still stable there.
    resolution, tol : float
        Scan step and final accuracy [-].

    Returns
    -------
    float
        ``kappa_max`` (0.0 if the loop is unstable already at ``kappa = 0``).
    """
    def stable(k: float) -> bool:
        return _spectral_radius(outer_loop_matrix(params, k, design, arm)) < 1.0

    if not stable(0.0):
        return 0.0
    lo = 0.0
    for k in np.arange(resolution, kappa_limit + resolution / 2, resolution):
        if not stable(float(k)):
            hi = float(k)
            while hi - lo > tol:
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if stable(mid) else (lo, mid)
            return lo
        lo = float(k)
    return math.inf


@dataclass(frozen=True)
class OuterLoopMargins:
    """``kappa_max`` of the built-in and the additive controller for one arm.

    Attributes
    ----------
    builtin, additive : float
        Largest stable outer-loop gains [-] (``inf``: stable up to ``kappa_limit``).
    arm : HumanArm
        The hand model used.
    kappa_limit : float
        Search limit [-].
    """

    builtin: float
    additive: float
    arm: HumanArm
    kappa_limit: float = 100.0

    @property
    def ratio(self) -> float:
        """``additive / builtin`` (paper: 15 / 4.6 > 3.3 measured)."""
        return self.additive / self.builtin if self.builtin > 0 else math.inf


def outer_loop_margins(design: AdditiveDesign, arm: HumanArm = HumanArm(),
                       kappa_limit: float = 100.0) -> OuterLoopMargins:
    """:func:`kappa_max` for the built-in controller and for ``design`` on the design's model."""
    return OuterLoopMargins(
        builtin=kappa_max(design.params, None, arm, kappa_limit),
        additive=kappa_max(design.params, design, arm, kappa_limit),
        arm=arm, kappa_limit=kappa_limit,
    )
