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
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.signal import tf2ss

from iiwa_ident._defaults import TAU_EXT_SOURCES
from iiwa_ident.design._additive import SAMPLE_TIME_S, AdditiveDesign, DesignError
from iiwa_ident.design._spatial_filter import FilterSettings, gamma_weight, ripple_bandpass_coefficients
from iiwa_ident.model import (
    RIPPLE_PERIOD_RAD,
    JointParameters,
    StateSpaceMatrices,
    StrictlyProperMatrices,
    coefficients,
    delayed_hold,
)

__all__ = ["HumanArm", "OuterLoopMargins", "arm_plant", "outer_loop_matrix", "exact_delay_spectral_radius",
           "kappa_max", "outer_loop_margins", "DeployedLoop", "deployed_loop_matrix", "deployed_kappa_max",
           "DeployedMargin", "deployed_margin"]


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


def arm_plant(params: JointParameters, arm: HumanArm) -> StrictlyProperMatrices:
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
    return StrictlyProperMatrices(A, B, C)


class _Measurement(NamedTuple):
    """A discrete system from the plant's state ``x`` to ``[tau_j seen, r]``: ``xf+ = Af xf + Bf x``,
    ``y = Cf xf + Df x``."""

    Af: np.ndarray
    Bf: np.ndarray
    Cf: np.ndarray
    Df: np.ndarray


def _sampled_loop(A: np.ndarray, B: np.ndarray, C_j: np.ndarray, C_r: np.ndarray, T: float, delay: float,
                  design: AdditiveDesign | None, meas: _Measurement | None = None) -> np.ndarray:
    """State matrix of a ZOH plant with input delay under ``tau_c = controller(r, tau_j)``.

    Without ``meas`` the controller sees ``C_j x`` as the joint torque and ``C_r x`` as the reference
    ``tau_r`` (already multiplied by the outer-loop gain). With ``meas``, a discrete system from the
    plant's state to ``[tau_j seen, r]`` (sensors, observers, filters) stands between them.
    """
    Phi, G0, G1, d = delayed_hold(A, B, T, delay)
    m = d + (1 if np.any(G1) else 0)  # stored past commands u[k-1] .. u[k-m]
    if design is None:
        Ac, Bc, Cc, Dc = np.zeros((0, 0)), np.zeros((0, 2)), np.zeros(0), np.array([1.0, 0.0])
    else:
        Ac, Bc, Cc, Dc = design.controller_matrices(discrete=True)
    if meas is None:
        meas = _Measurement(np.zeros((0, 0)), np.zeros((0, A.shape[0])), np.zeros((2, 0)), np.vstack([C_j, C_r]))
    Af, Bf, Cf, Df = meas
    n, nc, nf = A.shape[0], Ac.shape[0], Af.shape[0]
    N = n + m + nc + nf
    i_c, i_f = n + m, n + m + nc
    # The controller's inputs [r, tau_j seen] as rows over X: y = Cf xf + Df x.
    Y = np.zeros((2, N))
    Y[:, :n] = Df[[1, 0]]
    Y[:, i_f:] = Cf[[1, 0]]
    # u[k] = Cc xc + Dc [r, tau_j]
    U = Dc @ Y
    U[i_c:i_f] += Cc
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
        M[i_c:i_f] = Bc @ Y
        M[i_c:i_f, i_c:i_f] += Ac
    if nf:
        M[i_f:, :n] = Bf
        M[i_f:, i_f:] = Af
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
    return _largest_stable(lambda k: _spectral_radius(outer_loop_matrix(params, k, design, arm)) < 1.0,
                           kappa_limit, resolution, tol)


def _largest_stable(stable, kappa_limit: float, resolution: float, tol: float) -> float:
    """Scan ``kappa`` upward in steps of ``resolution`` to the first unstable one, then bisect to ``tol``."""
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


# ---------------------------------------------------------------------------------------------------------
# The loop as deployed: where tau_ext comes from, the spatial filter, the F/T sensor's filter
# ---------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class DeployedLoop:
    """What the deployed outer loop adds to the model of :func:`outer_loop_matrix`.

    Attributes
    ----------
    source : str
        Where ``tau_ext`` comes from: ``"ideal"`` (the true torque, the model of section V.C),
        ``"ft"`` (a Net F/T: first-order low-pass at ``ft_cutoff_hz``, ``ft_rate_hz`` records per
        second, the newest one read each cycle), ``"estimate"`` (the runtime's observer of eq (13)
        on the link velocity of eq (9) with gain ``KI``, spatially filtered, eq (14)) or ``"fri"``
        (the robot's own observer: eq (13) on the motor velocity with gain ``KI``).
    ft_cutoff_hz : float or None
        The F/T sensor's filter cut-off [Hz] (None: no filter).
    ft_rate_hz : float
        The F/T sensor's output rate [Hz]; at or above the loop's rate the filter runs on the samples
        of one cycle, below it the hold is not modelled.
    KI : float
        Observer gain of ``"estimate"`` and ``"fri"`` [1/s].
    filter : FilterSettings or None
        The spatial filter of eqs (10)-(12) on the additive controller's torque feedback, eq (15), and
        on the estimate, eq (14); None: no spatial filter (the model of section V.C).
    speed_rad_s : float
        The joint speed the spatial filter is taken at [rad/s]: at a constant speed it is a linear
        time-invariant filter (a notch at the ripple frequency ``|v| / rho``, weighted by gamma).
    ripple_period_rad : float
        The ripple period rho the spatial filter works at [rad]: the lookup table's
        (:func:`~iiwa_ident.design.filter_period`).
    """

    source: str = "ideal"
    ft_cutoff_hz: float | None = None
    ft_rate_hz: float = 1000.0
    KI: float = 25.0
    filter: FilterSettings | None = None
    speed_rad_s: float = 0.0
    ripple_period_rad: float = RIPPLE_PERIOD_RAD

    def __post_init__(self) -> None:
        if self.source not in ("ideal", *TAU_EXT_SOURCES):
            raise DesignError(f"unknown external-torque source {self.source!r}")


def _series(first: tuple, second: tuple) -> StateSpaceMatrices:
    """``second(first(x))``: ``first`` maps the plant's state to one signal (``B`` a matrix over it, ``D`` a
    row), ``second`` is a discrete SISO filter (1-D ``B`` and ``C``); the result maps the state the same way."""
    A1, B1, C1, D1 = first
    A2, B2, C2, D2 = second
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = A1
    A[n1:, :n1] = np.outer(B2, C1)
    A[n1:, n1:] = A2
    B = np.vstack([B1, np.outer(B2, D1)])
    C = np.concatenate([D2 * C1, C2])
    return StateSpaceMatrices(A, B, C, D2 * D1)


def _static(row: np.ndarray) -> StateSpaceMatrices:
    """The signal ``row . x`` as a system without states (the start of a :func:`_series`)."""
    return StateSpaceMatrices(np.zeros((0, 0)), np.zeros((0, len(row))), np.zeros(0), np.asarray(row, float))


def _siso(b: np.ndarray, a: np.ndarray) -> StateSpaceMatrices:
    A, B, C, D = tf2ss(b, a)
    return StateSpaceMatrices(np.atleast_2d(A), np.asarray(B, float).ravel(), np.asarray(C, float).ravel(),
                              float(np.ravel(D)[0]))


_ONE = StateSpaceMatrices(np.zeros((0, 0)), np.zeros(0), np.zeros(0), 1.0)


def _spatial_filter(settings: FilterSettings | None, period_rad: float, speed: float, T: float) -> StateSpaceMatrices:
    """Eqs (10)-(12) at a constant speed: ``1 - gamma^2 H_bp(z)^2`` with the Tustin step ``|v| T``."""
    if settings is None:
        return _ONE
    g = float(gamma_weight(abs(speed), settings.v_min_rad_s))
    delta = abs(speed) * T
    if g == 0.0 or delta == 0.0:
        return _ONE
    b, a = ripple_bandpass_coefficients(period_rad, settings.beta, delta)
    num = np.polysub(np.polymul(a, a), g * g * np.polymul(b, b))
    return _siso(num, np.polymul(a, a))


def _observer(KI: float, Jl: float, T: float) -> StateSpaceMatrices:
    """Eq (13) as the runtime runs it (:class:`~iiwa_ident.model.MomentumObserver`): inputs ``[theta,
    tau_j]``, states ``[theta_prev, S]``, output the estimate, velocity by the backward difference."""
    A = np.array([[0.0, 0.0], [-KI * Jl, 1.0 - T * KI]])
    B = np.array([[1.0, 0.0], [KI * Jl, T]])
    C = np.array([-KI * Jl / T, -KI])
    D = np.array([KI * Jl / T, 0.0])
    return StateSpaceMatrices(A, B, C, D)


def _measurement(params: JointParameters, arm: HumanArm, loop: DeployedLoop, T: float, additive: bool,
                 C_j: np.ndarray, C_e: np.ndarray) -> _Measurement:
    """The deployed loop's sensors, observers and filters as one :class:`_Measurement`."""
    spatial = _spatial_filter(loop.filter, loop.ripple_period_rad, loop.speed_rad_s, T)
    # tau_j as the controller sees it: spatially filtered in the additive controller's feedback, eq (15).
    seen_j = _series(_static(C_j), spatial if additive else _ONE)
    if loop.source in ("ideal", "ft"):
        pole = 0.0
        if loop.source == "ft" and loop.ft_cutoff_hz is not None:
            records = max(1.0, loop.ft_rate_hz * T)
            pole = math.exp(-2.0 * math.pi * loop.ft_cutoff_hz / loop.ft_rate_hz) ** records
        sensor = (np.array([[pole]]), np.array([1.0 - pole]), np.array([pole]), 1.0 - pole) if pole > 0 else _ONE
        seen_e = _series(_static(C_e), sensor)
    else:
        theta = np.array([0.0, 0.0, 1.0, 0.0]) if loop.source == "estimate" else np.array([1.0, 0.0, 0.0, 0.0])
        Ao, Bo, Co, Do = _observer(loop.KI, params.Jl, T)
        inputs = np.vstack([theta, C_j])  # the observer's inputs over x
        # The runtime's estimate is spatially filtered, eq (14); the robot's is not.
        seen_e = _series((Ao, Bo @ inputs, Co, Do @ inputs), spatial if loop.source == "estimate" else _ONE)
    (Aj, Bj, Cj, Dj), (Ae, Be, Ce, De) = seen_j, seen_e
    nj, ne = Aj.shape[0], Ae.shape[0]
    Af = np.zeros((nj + ne, nj + ne))
    Af[:nj, :nj], Af[nj:, nj:] = Aj, Ae
    Cf = np.zeros((2, nj + ne))
    Cf[0, :nj], Cf[1, nj:] = Cj, Ce
    return _Measurement(Af, np.vstack([Bj, Be]), Cf, np.vstack([Dj, De]))


def deployed_loop_matrix(params: JointParameters, kappa: float, design: AdditiveDesign | None = None,
                         arm: HumanArm = HumanArm(), loop: DeployedLoop = DeployedLoop(),
                         sample_time_s: float | None = None) -> np.ndarray:
    """State matrix of ``tau_r = kappa tau_ext`` as deployed (:class:`DeployedLoop`).

    As :func:`outer_loop_matrix`, with the external torque measured by the loop's source and the
    additive controller's torque feedback through the spatial filter at ``loop.speed_rad_s``.
    ``DeployedLoop()`` (the true torque, no filter) gives :func:`outer_loop_matrix`.
    """
    T = sample_time_s or (design.sample_time_s if design is not None else SAMPLE_TIME_S)
    A, B, C = arm_plant(params, arm)
    meas = _measurement(params, arm, loop, T, design is not None, C[0], C[1])
    meas = meas._replace(Cf=meas.Cf * np.array([[1.0], [kappa]]), Df=meas.Df * np.array([[1.0], [kappa]]))
    return _sampled_loop(A, B, C[0], kappa * C[1], T, params.Td, design, meas)


def deployed_kappa_max(params: JointParameters, design: AdditiveDesign | None = None, arm: HumanArm = HumanArm(),
                       loop: DeployedLoop = DeployedLoop(), kappa_limit: float = 100.0,
                       resolution: float = 0.05, tol: float = 1e-4) -> float:
    """:func:`kappa_max` of the loop as deployed (:func:`deployed_loop_matrix`)."""
    return _largest_stable(lambda k: _spectral_radius(deployed_loop_matrix(params, k, design, arm, loop)) < 1.0,
                           kappa_limit, resolution, tol)


@dataclass(frozen=True)
class DeployedMargin:
    """The deployed loop's ``kappa_max`` over the speeds a run passes through.

    Attributes
    ----------
    kappa_max : float
        The smallest ``kappa_max`` over ``speeds`` [-]: the spatial filter varies with the speed, and a
        loop that lingers where its margin is least goes unstable there.
    at_speed_rad_s : float
        The speed of that smallest margin [rad/s].
    speeds_rad_s, by_speed : tuple of float
        The speeds looked at and the margin at each.
    """

    kappa_max: float
    at_speed_rad_s: float
    speeds_rad_s: tuple[float, ...]
    by_speed: tuple[float, ...]


def deployed_margin(params: JointParameters, design: AdditiveDesign | None, arm: HumanArm, loop: DeployedLoop,
                    speeds_rad_s: Sequence[float] = (0.0,), kappa_limit: float = 100.0) -> DeployedMargin:
    """:func:`deployed_kappa_max` at each of ``speeds_rad_s`` [rad/s] and the least of them.

    Without a spatial filter in the loop (or for the built-in loop with a source that does not use
    it) the speed does not matter and one speed is computed.
    """
    uses_speed = loop.filter is not None and (design is not None or loop.source == "estimate")
    speeds = tuple(float(v) for v in speeds_rad_s) if uses_speed else (0.0,)
    values = tuple(deployed_kappa_max(params, design, arm, replace(loop, speed_rad_s=v), kappa_limit) for v in speeds)
    i = int(np.argmin(values))
    return DeployedMargin(values[i], speeds[i], speeds, values)
