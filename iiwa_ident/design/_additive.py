"""Design of the additive joint-torque controller of section V.B.

The controller it designs runs one sample at a time in :mod:`iiwa_ident.design._controller`; its
outer-loop gain margin is :mod:`iiwa_ident.design._margins`.

The plant seen from the FRI is eq (4): the commanded torque ``tau_c`` reaches
the joint torque ``tau_J`` through the built-in torque loop and the 5 ms
input delay,

``G(s) = e^{-Td s} Jl (bc s + K) / (Jc Jl s^2 + Jl bc s + (Jc + Jl) K)``.

(The paper prints it with an extra ``s^2`` in numerator and denominator,
which cancels.) For the design the delay is replaced by the second-order
Padé approximation ``(s^2 - c1 s + c2) / (s^2 + c1 s + c2)`` with
``c1 = 6 / Td`` and ``c2 = 12 / Td^2``, giving a fourth-order model.

Realisation, eqs (19)-(21)
--------------------------
Observable canonical form with ``C = [0 0 0 1]``: ``A`` has ones on the
sub-diagonal and ``-a_0 .. -a_3`` (the normalised denominator coefficients,
constant term first) in its last column, ``B = [b_0 .. b_3]`` holds the
normalised numerator coefficients. The state is then
``x_4 = tau_J`` [Nm], ``x_3`` [Nm/s], ``x_2`` [Nm/s^2], ``x_1`` [Nm/s^3],
so ``K_FSF`` has units [s^3, s^2, s, 1] and ``L`` [s^-4, s^-3, s^-2, s^-1].
The printed ``A`` of eq (19) agrees with this; the printed ``B_1 = K/Jc`` of
eq (20) lacks the factor ``c2``: the transfer function requires
``b_0 = c2 K / Jc`` (see :mod:`iiwa_ident.design._paper`).

Control law, eqs (16)-(18), at the 1 kHz cycle
----------------------------------------------
The continuous gains ``K_FSF`` and ``L`` place the requested poles on
``(A, B, C)``. The implementation runs at the robot cycle ``T``: the model
is discretised with a zero-order hold (the FRI holds each command for one
cycle) to ``(Ad, Bd, C)`` and the discrete gains ``Kd``, ``Ld`` place the
mapped poles ``z = exp(p T)``, so the sampled loop has exactly the designed
poles on the model. Per cycle ``k`` (predictor-form observer, so that
``tau_c[k]`` does not wait for a computation on ``tau_J[k]``)::

    tau_fb = -Kd x_hat + Kr_d tau_r                            (16)
    x_hat <- Ad x_hat + Bd tau_fb + Ld (tau_J,filt - y_ref - C x_hat)   (17)
    tau_c  = tau_fb + tau_ff                                   (18)

The feed-forward of eq (22)
---------------------------
``F(s) = (Jc Jl s^2 + Jl bc s + (Jc + Jl) K) / (Jl (bc s + K))`` is the
inverse of the delay-free model and improper (relative degree -1). It is
realised causally by a reference pre-filter
``P(s) = w_f^2 / (s^2 + 2 zeta w_f s + w_f^2)`` (default 250 Hz, critically
damped): ``tau_ff = F(s) P(s) tau_r``, strictly proper, discretised with the
bilinear (Tustin) map, which adds no half-cycle lag to the sampled
reference. Consequence: the inversion holds only below about ``w_f``;
a step of ``tau_r`` produces the torque ``P(s) e^{-Td s} tau_r`` at best, a
critically damped rise of ~10 ms after the 5 ms delay, and ``tau_ff`` peaks
at a few times the step while it drives the plant through its resonance.

Unit DC gain with feed-forward
------------------------------
``F(0) = 1 / G(0) = (Jc + Jl) / Jl`` already makes ``tau_ff`` alone produce
``tau_J = tau_r`` at DC, while the paper's ``Kr`` (0.9636) is the gain that
gives the *feedback* path alone unit DC gain. Used together as printed they
double-count the reference: on the Table I model eqs (16)-(18) with
``Kr = 0.9656`` give a DC gain of 2.68 from ``tau_r`` to ``tau_J``.
Three ways of combining them are offered (``feedforward=``):

``"reference"`` (default)
    Two-degree-of-freedom form: the model, driven by ``tau_ff``, generates
    the reference torque ``y_ref``; eq (17) observes the *deviation*
    ``tau_J,filt - y_ref`` and eq (16) runs with ``Kr_d = 0``. On the model
    the feedback then stays at rest and ``tau_J = P e^{-Td s} tau_r``, so the
    DC gain is ``F(0) G(0) = 1`` by construction; the feedback only acts on
    what the model does not predict (ripple, errors, Padé mismatch). This
    equals eq (16) with ``Kr tau_r`` replaced by ``K_FSF x_ref``, whose DC
    value is ``(Kr - 1/G(0)) tau_r``: exactly the reduced ``Kr`` unit DC gain
    needs once ``tau_ff`` carries ``1/G(0)``.
``"paper"``
    Eqs (16)-(18) literally (the observer sees ``tau_J,filt`` and only
    ``tau_fb``), with ``Kr_d`` solved for unit DC gain of the whole loop.
    ``Kr`` turns negative (about -0.74 at 1 kHz on Table I) because ``tau_ff``
    is an input the observer does not know, and the step response is slower.
``"none"``
    No feed-forward; ``Kr_d`` gives the feedback loop unit DC gain (the
    paper's ``Kr`` in continuous time).

Numerics
--------
The canonical-form entries span 1e-1 .. 1e10. Pole placement, discretisation
and loop analysis are done on the diagonally rescaled state
``x = S x_s``, ``S = diag(w0^3, w0^2, w0, 1)`` with ``w0 = a_0^(1/4)``, and
transformed back; this keeps the placed poles exact to ~1e-9 relative.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import matrix_balance
from scipy.signal import cont2discrete

from iiwa_ident._defaults import DEFAULT_PREFILTER_HZ, FEEDFORWARD_MODES  # one definition, light for the CLI's help
from iiwa_ident.design._controller import AdditiveController
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model import (
    JointParameters,
    StateSpaceMatrices,
    StrictlyProperMatrices,
    coefficients,
    pade_coefficients,
    zoh,
)

if TYPE_CHECKING:
    import control as ct  # imported where used: python-control is slow to import

__all__ = [
    "DesignError",
    "AdditiveDesign",
    "PAPER_POLES",
    "PAPER_OBSERVER_POLES",
    "FEEDFORWARD_MODES",
    "SAMPLE_TIME_S",
    "DEFAULT_PREFILTER_HZ",
    "DEFAULT_PREFILTER_ZETA",
    "realisation",
    "builtin_poles",
    "natural_frequency_damping",
    "check_poles",
    "feedforward_transfer_function",
    "design_controller",
]

#: Full-state-feedback poles of section V.B [rad/s].
PAPER_POLES: tuple[complex, ...] = (-180 + 30j, -180 - 30j, -500 + 1j, -500 - 1j)
#: Observer poles of section V.B [rad/s].
PAPER_OBSERVER_POLES: tuple[complex, ...] = (-620 + 0j, -630 + 0j, -1000 + 0j, -1010 + 0j)
#: FRI cycle [s].
SAMPLE_TIME_S = 1e-3
#: Damping ratio of the feed-forward's reference pre-filter (its frequency: DEFAULT_PREFILTER_HZ).
DEFAULT_PREFILTER_ZETA = 1.0


class DesignError(IiwaIdentError):
    """Invalid design input: poles, parameters or settings (message names the culprit)."""


# ---------------------------------------------------------------------------
# Model (eq (4) itself: iiwa_ident.model)
# ---------------------------------------------------------------------------
def realisation(params: JointParameters) -> StrictlyProperMatrices:
    """Observable canonical realisation of the Padé-delayed eq (4), eqs (19)-(21).

    Returns
    -------
    A : ndarray (4, 4)
        Ones on the sub-diagonal, ``-a_0, -a_1, -a_2, -a_3`` in the last column
        (monic denominator ``s^4 + a_3 s^3 + ... + a_0``).
    B : ndarray (4,)
        ``b_0 .. b_3`` of the numerator ``b_3 s^3 + ... + b_0``; ``b_0 = c2 K/Jc``.
    C : ndarray (4,)
        ``[0, 0, 0, 1]``: the fourth state is ``tau_J`` [Nm].
    """
    num, den = coefficients(params, delay="pade")
    a = den[1:][::-1]  # a_0 .. a_3
    b = num[::-1]  # b_0 .. b_3
    A = np.zeros((4, 4))
    A[1, 0] = A[2, 1] = A[3, 2] = 1.0
    A[:, 3] = -a
    return StrictlyProperMatrices(A, b.copy(), np.array([0.0, 0.0, 0.0, 1.0]))


def builtin_poles(params: JointParameters) -> np.ndarray:
    """Closed-loop poles of the built-in controller, roots of ``Jc Jl s^2 + Jl bc s + (Jc + Jl) K`` [rad/s].

    About ``-26.7 +- 143.4j`` for Table I (the paper quotes -27.5 +- 143i).
    The pair with positive imaginary part comes first.

    Examples
    --------
    >>> from iiwa_ident.design import table1_parameters
    >>> p = builtin_poles(table1_parameters()[0])[0]
    >>> round(float(p.real), 1), round(float(p.imag), 1)
    (-26.7, 143.4)
    >>> [round(float(x), 2) for x in natural_frequency_damping(p)]  # Hz, damping ratio
    [23.21, 0.18]
    """
    r = np.roots([params.Jc * params.Jl, params.Jl * params.bc, (params.Jc + params.Jl) * params.K])
    return np.array(sorted(r.astype(complex), key=lambda z: (-z.imag, z.real)))


def natural_frequency_damping(pole: complex) -> tuple[float, float]:
    """Natural frequency [Hz] and damping ratio of a continuous pole [rad/s].

    Examples
    --------
    >>> [round(x, 3) for x in natural_frequency_damping(-3 + 4j)]
    [0.796, 0.6]
    """
    wn = abs(pole)
    return wn / (2 * math.pi), (-pole.real / wn if wn > 0 else 1.0)


def check_poles(poles: Iterable[complex], what: str = "poles", sample_time_s: float | None = SAMPLE_TIME_S,
                count: int = 4) -> np.ndarray:
    """Validate requested continuous poles [rad/s] and return them as a complex array.

    Parameters
    ----------
    poles : iterable of complex
        The poles.
    what : str
        Name used in error messages (``"poles"``, ``"observer poles"``).
    sample_time_s : float or None
        If given, poles must lie below the Nyquist frequency ``pi / T``.
    count : int
        Required number of poles.

    Raises
    ------
    DesignError
        Wrong count, non-finite, not strictly stable, not in conjugate pairs,
        or oscillating above the Nyquist frequency.
    """
    try:
        p = np.array([complex(x) for x in poles], dtype=complex)
    except (TypeError, ValueError):
        raise DesignError(f"{what}: expected complex numbers") from None
    if len(p) != count:
        raise DesignError(f"{what}: expected {count} poles, got {len(p)}")
    if not np.all(np.isfinite(p)):
        raise DesignError(f"{what}: poles must be finite")
    for z in p:
        if z.real >= 0:
            raise DesignError(f"{what}: {_fmt(z)} is not stable (real part must be negative)")
    # Each complex pole needs its conjugate: the gains must be real.
    scale = max(1.0, float(np.abs(p).max()))
    unmatched = list(p[np.abs(p.imag) > 1e-12 * scale])
    while unmatched:
        z = unmatched.pop(0)
        partner = [i for i, w in enumerate(unmatched) if abs(w - z.conjugate()) <= 1e-9 * scale]
        if not partner:
            raise DesignError(f"{what}: {_fmt(z)} has no conjugate partner {_fmt(z.conjugate())}")
        unmatched.pop(partner[0])
    p = np.where(np.abs(p.imag) > 1e-12 * scale, p, p.real + 0j)
    if sample_time_s is not None:
        nyquist = math.pi / sample_time_s
        for z in p:
            if abs(z.imag) >= nyquist:
                raise DesignError(f"{what}: {_fmt(z)} oscillates above the Nyquist frequency "
                                  f"{nyquist:.0f} rad/s of the {1 / sample_time_s:g} Hz cycle")
    return p


def _fmt(z: complex) -> str:
    return f"{z.real:g}{z.imag:+g}j" if z.imag else f"{z.real:g}"


# ---------------------------------------------------------------------------
# Linear-algebra helpers
# ---------------------------------------------------------------------------
def _scaling(A: np.ndarray) -> np.ndarray:
    """Diagonal ``S`` that brings the canonical form to entries of similar size."""
    w0 = abs(A[0, 3]) ** 0.25 if A[0, 3] != 0 else 1.0
    return np.diag([w0 ** 3, w0 ** 2, w0, 1.0])


def _acker(A: np.ndarray, B: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """Single-input pole placement (Ackermann, python-control); repeated poles allowed."""
    import control as ct  # here: python-control takes a quarter of a second to import

    k = np.atleast_2d(np.asarray(ct.acker(A, B.reshape(-1, 1), poles), dtype=float))
    return k.ravel()


def _place_scaled(A: np.ndarray, B: np.ndarray, C: np.ndarray, S: np.ndarray,
                  poles: np.ndarray, observer_poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state feedback ``gain`` with eig(A - B gain) = poles and ``L`` with eig(A - L C) = observer_poles,
    placed on ``x = S x_s``."""
    Si = np.linalg.inv(S)
    As, Bs, Cs = Si @ A @ S, Si @ B, C @ S
    Ks = _acker(As, Bs, poles)
    Ls = _acker(As.T, Cs, observer_poles)
    return Ks @ Si, S @ Ls


def _realised(num: np.ndarray, den: np.ndarray) -> StateSpaceMatrices:
    """A balanced state-space realisation of ``num/den`` (proper)."""
    import control as ct  # here: python-control takes a quarter of a second to import

    sys = ct.tf2ss(ct.tf(num, den))
    A, B, C, D = (np.asarray(m, float) for m in (sys.A, sys.B, sys.C, sys.D))
    # Diagonal balancing only: keeps the realisation, evens out the entry sizes.
    _, (scale, _perm) = matrix_balance(A, permute=False, separate=True)
    A = A * scale[None, :] / scale[:, None]
    return StateSpaceMatrices(A, B.ravel() / scale, C.ravel() * scale, float(D.ravel()[0]))


def feedforward_transfer_function(params: JointParameters, prefilter_hz: float = DEFAULT_PREFILTER_HZ,
                                  prefilter_zeta: float = DEFAULT_PREFILTER_ZETA) -> ct.TransferFunction:
    """``F(s) P(s)``: eq (22) behind the reference pre-filter [Nm/Nm].

    ``F(s) = (Jc Jl s^2 + Jl bc s + (Jc + Jl) K) / (Jl (bc s + K))`` inverts the
    delay-free model; ``P(s) = w_f^2 / (s^2 + 2 zeta w_f s + w_f^2)`` with
    ``w_f = 2 pi prefilter_hz`` makes the product strictly proper (for
    ``bc > 0``). ``F(0) P(0) = (Jc + Jl) / Jl``.
    """
    wf = 2 * math.pi * prefilter_hz
    p = params
    num = np.polymul([p.Jc * p.Jl, p.Jl * p.bc, (p.Jc + p.Jl) * p.K], [wf ** 2])
    den = np.polymul([p.Jl * p.bc, p.Jl * p.K], [1.0, 2 * prefilter_zeta * wf, wf ** 2])
    import control as ct  # here: python-control takes a quarter of a second to import

    return ct.tf(num, den)


# ---------------------------------------------------------------------------
# The design
# ---------------------------------------------------------------------------
@dataclass(kw_only=True)
class AdditiveDesign:
    """A complete additive controller design: continuous and 1 kHz matrices.

    Vectors are 1-D arrays; ``K_fsf @ x`` is a scalar. Units: see the module
    docstring (states of the canonical form in Nm/s^3 .. Nm).

    Attributes
    ----------
    params : JointParameters
        Model the design is based on.
    sample_time_s : float
        Controller cycle T [s].
    feedforward : str
        One of :data:`FEEDFORWARD_MODES`.
    poles, observer_poles : ndarray of complex (4,)
        Requested continuous poles [rad/s].
    prefilter_hz, prefilter_zeta : float
        Reference pre-filter of the feed-forward [Hz], [-].
    c1, c2 : float
        Padé coefficients [1/s], [1/s^2].
    A, B, C : ndarray
        Continuous realisation, eqs (19)-(21) (with the corrected ``B_1``).
    K_fsf, L : ndarray (4,)
        Continuous gains placing ``poles`` and ``observer_poles``.
    Kr : float
        Paper's ``Kr``: unit DC gain of the continuous feedback loop alone.
    Kr_c : float
        ``Kr`` used with the continuous controller in this feed-forward mode.
    Ad, Bd : ndarray
        Zero-order-hold discretisation of ``(A, B)`` over ``T``.
    Kd, Ld : ndarray (4,)
        Discrete gains placing ``exp(poles T)`` and ``exp(observer_poles T)``.
    Kr_d : float
        Gain on ``tau_r`` in the discrete eq (16) for this mode.
    ff, ffd : tuple (A, B, C, D) or None
        Continuous and discrete realisation of ``F(s) P(s)`` (None without feed-forward).
    builtin_poles : ndarray (2,)
        Built-in controller closed-loop poles [rad/s].
    additive_poles : ndarray (8,)
        Eigenvalues of the continuous feedback loop on the Padé model [rad/s]
        (``poles`` and ``observer_poles`` by separation).
    additive_poles_discrete : ndarray (8,)
        Eigenvalues of the sampled feedback loop on ``(Ad, Bd, C)`` (z-plane).
    """

    params: JointParameters
    sample_time_s: float
    feedforward: str
    poles: np.ndarray
    observer_poles: np.ndarray
    prefilter_hz: float
    prefilter_zeta: float
    c1: float
    c2: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    K_fsf: np.ndarray
    L: np.ndarray
    Kr: float
    Kr_c: float
    Ad: np.ndarray
    Bd: np.ndarray
    Kd: np.ndarray
    Ld: np.ndarray
    Kr_d: float
    ff: tuple | None
    ffd: tuple | None
    builtin_poles: np.ndarray
    additive_poles: np.ndarray
    additive_poles_discrete: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))

    # -- realisations of the whole controller ----------------------------------
    def controller_matrices(self, discrete: bool = True, kr: float | None = None,
                            scaled: bool = True) -> StateSpaceMatrices:
        """The controller as one LTI system from ``[tau_r, tau_J,filt]`` to ``tau_c``.

        States ``[x_hat (4), x_ref (4, "reference" mode), x_ff (feed-forward)]``;
        the same equations :meth:`AdditiveController.step` runs.

        Parameters
        ----------
        discrete : bool
            The 1 kHz controller (matrices of ``x[k+1] = ...``) or its
            continuous counterpart (``x' = ...``).
        kr : float, optional
            Override the gain on ``tau_r`` in eq (16) (default: ``Kr_d``/``Kr_c``).
        scaled : bool
            Express ``x_hat`` and ``x_ref`` in the rescaled state (better
            conditioned; same input-output behaviour).

        Returns
        -------
        Ac, Bc, Cc, Dc : ndarray
            ``Bc`` is (n, 2), ``Cc`` (n,), ``Dc`` (2,).
        """
        if discrete:
            A, B, gain, L, ff = self.Ad, self.Bd, self.Kd, self.Ld, self.ffd
            kr = self.Kr_d if kr is None else kr
        else:
            A, B, gain, L, ff = self.A, self.B, self.K_fsf, self.L, self.ff
            kr = self.Kr_c if kr is None else kr
        C = self.C
        if scaled:
            S = _scaling(self.A)
            Si = np.linalg.inv(S)
            A, B, C, gain, L = Si @ A @ S, Si @ B, C @ S, gain @ S, Si @ L
        return _compose(A, B, C, gain, L, kr, ff, self.feedforward == "reference")

    def model_matrices(self, discrete: bool = True, scaled: bool = True) -> StrictlyProperMatrices:
        """The design model ``(A, B, C)`` (Padé-delayed eq (4)), continuous or ZOH at T."""
        A, B, C = (self.Ad, self.Bd, self.C) if discrete else (self.A, self.B, self.C)
        if scaled:
            S = _scaling(self.A)
            Si = np.linalg.inv(S)
            A, B, C = Si @ A @ S, Si @ B, C @ S
        return StrictlyProperMatrices(A, B, C)

    def closed_loop(self, discrete: bool = True, kr: float | None = None) -> ct.StateSpace:
        """The controller on its own design model: ``tau_r`` -> ``[tau_J, tau_c]``.

        A python-control system, discrete with ``dt = T`` or continuous.
        """
        ctrl = self.controller_matrices(discrete, kr)
        model = self.model_matrices(discrete)
        A, B, C, D = _close_on_model(ctrl, model)
        import control as ct  # here: python-control takes a quarter of a second to import

        return ct.ss(A, B, C, D, self.sample_time_s if discrete else 0)

    def dc_gain(self, discrete: bool = True) -> float:
        """DC gain ``tau_r -> tau_J`` of :meth:`closed_loop` [Nm/Nm] (1 by design)."""
        return _dc(_close_on_model(self.controller_matrices(discrete), self.model_matrices(discrete)), discrete)

    def controller(self) -> AdditiveController:
        """A fresh per-sample controller running this design."""
        return AdditiveController(self)


def _compose(A, B, C, gain, L, kr, ff, reference) -> StateSpaceMatrices:
    """Stack eqs (16)-(18) (+ reference model, + feed-forward) into one system ``[r, y] -> tau_c``."""
    n = A.shape[0]
    nf = 0 if ff is None else ff[0].shape[0]
    nr = n if reference else 0
    N = n + nr + nf
    Ac, Bc, Cc, Dc = np.zeros((N, N)), np.zeros((N, 2)), np.zeros(N), np.zeros(2)
    # Observer (17) fed with tau_fb = -gain x_hat + kr r and the measured (minus reference) torque.
    Ac[:n, :n] = A - np.outer(B, gain) - np.outer(L, C)
    Bc[:n, 0] = B * kr
    Bc[:n, 1] = L
    Cc[:n] = -gain
    Dc[0] = kr
    if ff is not None:
        Af, Bf, Cf, Df = ff
        i = n + nr
        Ac[i:, i:] = Af
        Bc[i:, 0] = Bf
        Cc[i:] = Cf
        Dc[0] += Df
        if reference:
            # x_ref' = A x_ref + B tau_ff;  the observer sees y - C x_ref.
            Ac[n:i, n:i] = A
            Ac[n:i, i:] = np.outer(B, Cf)
            Bc[n:i, 0] = B * Df
            Ac[:n, n:i] = -np.outer(L, C)
    return StateSpaceMatrices(Ac, Bc, Cc, Dc)


def _close_on_model(ctrl, model) -> StateSpaceMatrices:
    """Controller ``[r, y] -> u`` (no direct feed-through from y) around ``y = C x``, ``x' = A x + B u``."""
    Ac, Bc, Cc, Dc = ctrl
    Am, Bm, Cm = model
    if Dc[1] != 0:
        raise ValueError("controller with feed-through from the measurement")
    n, m = Am.shape[0], Ac.shape[0]
    A = np.zeros((n + m, n + m))
    A[:n, :n] = Am
    A[:n, n:] = np.outer(Bm, Cc)
    A[n:, :n] = np.outer(Bc[:, 1], Cm)
    A[n:, n:] = Ac
    B = np.concatenate([Bm * Dc[0], Bc[:, 0]]).reshape(-1, 1)
    C = np.zeros((2, n + m))
    C[0, :n] = Cm
    C[1, n:] = Cc
    D = np.array([[0.0], [Dc[0]]])
    return StateSpaceMatrices(A, B, C, D)


def _dc(system, discrete: bool) -> float:
    A, B, C, D = system
    M = np.eye(A.shape[0]) - A if discrete else -A
    return float((C[0] @ np.linalg.solve(M, B[:, 0])) + D[0, 0])


def _solve_kr(make, discrete: bool) -> float:
    """The ``kr`` giving unit DC gain; the loop's DC gain is affine in ``kr``."""
    g0, g1 = _dc(make(0.0), discrete), _dc(make(1.0), discrete)
    if abs(g1 - g0) < 1e-12:
        raise DesignError("Kr has no influence on the DC gain: the design model has a zero at DC")
    return (1.0 - g0) / (g1 - g0)


def design_controller(params: JointParameters, poles: Sequence[complex] | np.ndarray = PAPER_POLES,
                      observer_poles: Sequence[complex] | np.ndarray = PAPER_OBSERVER_POLES,
                      sample_time_s: float = SAMPLE_TIME_S, feedforward: str = "reference",
                      prefilter_hz: float = DEFAULT_PREFILTER_HZ,
                      prefilter_zeta: float = DEFAULT_PREFILTER_ZETA) -> AdditiveDesign:
    """Design the additive controller of section V.B for ``params``.

    Parameters
    ----------
    params : JointParameters
        Model (Table I: ``JointParameters(1.03, 55, 18500, 5.6, 0.005)``).
    poles : sequence of 4 complex
        Continuous full-state-feedback poles [rad/s] (paper: -180+-30j, -500+-1j).
    observer_poles : sequence of 4 complex
        Continuous observer poles [rad/s] (paper: -620, -630, -1000, -1010).
    sample_time_s : float
        Controller cycle [s] (FRI: 1 ms).
    feedforward : {"reference", "paper", "none"}
        How ``Kr`` and ``tau_ff`` of eq (22) are combined (module docstring).
    prefilter_hz, prefilter_zeta : float
        Natural frequency [Hz] and damping of the reference pre-filter that
        makes eq (22) causal; below the Nyquist frequency.

    Returns
    -------
    AdditiveDesign

    Raises
    ------
    DesignError
        Invalid poles or settings.
    """
    if feedforward not in FEEDFORWARD_MODES:
        raise DesignError(f"feedforward must be one of {', '.join(FEEDFORWARD_MODES)}, got {feedforward!r}")
    if not (math.isfinite(sample_time_s) and sample_time_s > 0):
        raise DesignError(f"sample time must be positive, got {sample_time_s!r}")
    T = float(sample_time_s)
    p = check_poles(poles, "poles", T)
    o = check_poles(observer_poles, "observer poles", T)
    use_ff = feedforward != "none"
    if use_ff:
        if not (math.isfinite(prefilter_hz) and 0 < prefilter_hz < 0.5 / T):
            raise DesignError(f"pre-filter frequency must lie in (0, {0.5 / T:g}) Hz, got {prefilter_hz!r}")
        if not (math.isfinite(prefilter_zeta) and prefilter_zeta > 0):
            raise DesignError(f"pre-filter damping must be positive, got {prefilter_zeta!r}")
        if params.bc <= 0:
            raise DesignError("the feed-forward of eq (22) needs bc > 0 (use feedforward='none')")

    A, B, C = realisation(params)
    S = _scaling(A)
    Si = np.linalg.inv(S)
    K_fsf, L = _place_scaled(A, B, C, S, p, o)
    # Continuous feedback-only Kr (the paper's): 1 / (C (B K_fsf - A)^-1 B), on the scaled state.
    As, Bs, Cs, Ks = Si @ A @ S, Si @ B, C @ S, K_fsf @ S
    Kr = float(1.0 / (Cs @ np.linalg.solve(np.outer(Bs, Ks) - As, Bs)))

    Ads, Bds = zoh(As, Bs, T)
    Ad, Bd = S @ Ads @ Si, S @ Bds.ravel()
    Kd, Ld = _place_scaled(Ad, Bd, C, S, np.exp(p * T), np.exp(o * T))

    ff = ffd = None
    if use_ff:
        tf = feedforward_transfer_function(params, prefilter_hz, prefilter_zeta)
        Af, Bf, Cf, Df = _realised(np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float))
        ff = (Af, Bf, Cf, Df)
        # Tustin, not ZOH: tau_r is a sampled reference, not a held actuator signal, and the
        # bilinear map adds no half-cycle lag on top of the hold the FRI already applies to tau_c.
        Afd, Bfd, Cfd, Dfd, _ = cont2discrete((Af, Bf.reshape(-1, 1), Cf.reshape(1, -1), [[Df]]), T, "bilinear")
        ffd = (np.asarray(Afd, float), np.asarray(Bfd, float).ravel(), np.asarray(Cfd, float).ravel(),
               float(np.asarray(Dfd).ravel()[0]))

    design = AdditiveDesign(
        params=params, sample_time_s=T, feedforward=feedforward, poles=p, observer_poles=o,
        prefilter_hz=float(prefilter_hz), prefilter_zeta=float(prefilter_zeta),
        c1=pade_coefficients(params.Td)[0], c2=pade_coefficients(params.Td)[1],
        A=A, B=B, C=C, K_fsf=K_fsf, L=L, Kr=Kr, Kr_c=Kr, Ad=Ad, Bd=Bd, Kd=Kd, Ld=Ld, Kr_d=0.0,
        ff=ff, ffd=ffd, builtin_poles=builtin_poles(params), additive_poles=np.zeros(0, complex),
    )
    if feedforward == "reference":
        design.Kr_c = design.Kr_d = 0.0
    else:
        for discrete in (False, True):
            def make(kr, discrete=discrete):
                return _close_on_model(design.controller_matrices(discrete, kr), design.model_matrices(discrete))
            kr = _solve_kr(make, discrete)
            if discrete:
                design.Kr_d = kr
            else:
                design.Kr_c = kr
    design.additive_poles = _feedback_poles(design, discrete=False)
    design.additive_poles_discrete = _feedback_poles(design, discrete=True)
    return design


def _feedback_poles(design: AdditiveDesign, discrete: bool) -> np.ndarray:
    """Eigenvalues of model + observer-based feedback (reference and feed-forward excluded)."""
    A, B, C = design.model_matrices(discrete)
    S = _scaling(design.A)
    gain = (design.Kd if discrete else design.K_fsf) @ S
    L = np.linalg.inv(S) @ (design.Ld if discrete else design.L)
    M = np.block([[A, -np.outer(B, gain)], [np.outer(L, C), A - np.outer(B, gain) - np.outer(L, C)]])
    ev = np.linalg.eigvals(M)
    return np.array(sorted(ev, key=lambda z: (round(abs(z), 9), z.imag)))
