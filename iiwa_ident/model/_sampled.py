"""Eqs (1)-(4) sampled exactly, with the fractional input delay.

FRI sends ``tau_c[k]`` at ``t = kT``; the robot applies it from ``kT + Td``
to ``(k+1)T + Td`` (zero-order hold) and reports ``tau_J[k]``, ``q_m[k]`` at
``kT``. The sampled model is the exact discretisation of this: with
``Td = dT + tau`` (``0 <= tau < T``, a fractional delay; modified
z-transform)::

    x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]
    Phi    = e^{AT}
    Gamma0 = int_0^{T-tau} e^{As} ds B
    Gamma1 = e^{A(T-tau)} int_0^{tau} e^{As} ds B

the zero-order holds over ``T - tau`` and ``tau`` taken from
:func:`scipy.signal.cont2discrete`. Without the fractional part ``Td`` would
come out about half a cycle off. The state splits exactly into the resonant
pair of eq (4) and the rigid-body double integrator (a Jordan block at
``s = 0``); each part is run as a recursive filter, the double integrator
with the exact coefficients ``(1 - z^-1)^2`` so that it cannot drift
numerically.

An input that is a function of the motion (the ripple's deflection and
reaction) is not held: over each sample it is described by its mean and
its slope (first moment), ``u(kT + s) = m[k] + g[k] (s / T - 1/2)``, and the
slope enters through ``Gamma_g = int_0^T e^{A(T-s)} B (s / T - 1/2) ds``.
The mean alone leaves an error that grows with the sample's share of the
loop's time constants (0.2 % of the ripple's response on the default
joint); with the slope it is of the input's curvature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.linalg import expm
from scipy.signal import cont2discrete, lfilter

from iiwa_ident.model._eq4 import INPUTS
from iiwa_ident.model._matrices import StrictlyProperMatrices
from iiwa_ident.model._parameters import ParameterSource, parameter_values

__all__ = ["zoh", "delayed_hold", "sample_means", "sample_slopes", "state_matrices", "DiscreteModel", "discretize",
           "simulate_outputs"]


def zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``(e^{Ah}, int_0^h e^{As} ds B)``: ``x' = A x + B u`` with ``u`` held over ``h`` [s].

    ``B`` of shape ``(n,)`` gives a vector, of shape ``(n, m)`` a matrix; ``h = 0`` the identity and zero.
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    Bm = B.reshape(A.shape[0], -1)
    if h <= 0.0:
        return np.eye(A.shape[0]), np.zeros(B.shape)
    Phi, G, *_ = cont2discrete((A, Bm, np.eye(A.shape[0]), np.zeros((A.shape[0], Bm.shape[1]))), h, method="zoh")
    return Phi, G.reshape(B.shape)


def split_delay(delay: float, T: float) -> tuple[int, float]:
    """``delay = d T + tau``: whole samples ``d`` and the fraction ``0 <= tau < T`` [s] (0 within 1e-9 T)."""
    d = int(math.floor(delay / T + 1e-9))
    tau = max(delay - d * T, 0.0)
    return d, (0.0 if tau < 1e-9 * T else tau)


class DelayedHold(NamedTuple):
    """The sampled system of :func:`delayed_hold`: ``x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]``."""

    Phi: np.ndarray
    Gamma0: np.ndarray
    Gamma1: np.ndarray  #: zero without a fraction of a sample
    d: int  #: whole samples of the delay


def delayed_hold(A: np.ndarray, B: np.ndarray, T: float, delay: float
                 ) -> DelayedHold:
    """``x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]`` for ``x' = A x + B u(t - delay)``, ``u`` held.

    ``delay = d T + tau`` with ``0 <= tau < T`` (module docstring); ``Gamma1`` is zero without a fraction.

    Returns
    -------
    Phi, Gamma0, Gamma1 : numpy.ndarray
    d : int
        Whole samples of the delay.
    """
    d, tau = split_delay(delay, T)
    Phi, G = zoh(A, B, T)
    if tau == 0.0:
        return DelayedHold(Phi, G, np.zeros_like(G), d)
    Pa, Ga = zoh(A, B, T - tau)
    return DelayedHold(Phi, Ga, Pa @ zoh(A, B, tau)[1], d)


@dataclass(kw_only=True)
class DiscreteModel:
    """The ZOH-sampled eq (1)-(4) model with a fractional input delay.

    Each output is ``z^-d (Nr(z^-1) / Dr(z^-1) + Nj(z^-1) / (1 - z^-1)^2)``
    applied to ``tau_c``, starting from rest.

    Attributes
    ----------
    sample_time_s : float
        Sample time T [s].
    delay_samples : int
        Whole-sample part d of the delay.
    den_resonant : numpy.ndarray
        ``Dr``: 1, -trace(Phi_r), det(Phi_r).
    num_resonant, num_rigid : numpy.ndarray
        ``Nr`` and ``Nj`` per output, shape ``(2, 4)``; output 0 is ``tau_j``
        [Nm], output 1 is ``theta_m`` [rad].
    feedthrough : numpy.ndarray
        Direct path per output (``-K`` to ``tau_j`` for the deflection input,
        else zero).
    sampled_motion : bool
        The input is a sampled function of the motion (the deflection, the
        reaction), not a command held over each sample: the dynamics see its
        mean over each sample (:func:`sample_means`) and its slope there.
    num_resonant_slope, num_rigid_slope : numpy.ndarray
        ``Nr`` and ``Nj`` of the slope (module docstring), shape ``(2, 4)``;
        zero for a held input.
    """

    sample_time_s: float
    delay_samples: int
    den_resonant: np.ndarray
    num_resonant: np.ndarray
    num_rigid: np.ndarray
    feedthrough: np.ndarray = field(default_factory=lambda: np.zeros(2))
    sampled_motion: bool = False
    num_resonant_slope: np.ndarray = field(default_factory=lambda: np.zeros((2, 4)))
    num_rigid_slope: np.ndarray = field(default_factory=lambda: np.zeros((2, 4)))

    def simulate(self, tau_c: np.ndarray, means: np.ndarray | None = None,
                 slopes: np.ndarray | None = None) -> np.ndarray:
        """Outputs for the command ``tau_c`` [Nm] from rest: array ``(2, n)`` of ``tau_j`` [Nm], ``theta_m`` [rad].

        ``tau_c`` of shape ``(n, m)`` simulates ``m`` inputs at once (outputs ``(2, n, m)``). For a
        :attr:`sampled_motion` input (no delay), ``means`` and ``slopes`` may give its mean and slope over
        each sample (default :func:`sample_means` and :func:`sample_slopes` of it), computed once where one
        input is simulated through many parameter sets (a fit), or from the motion between samples.
        """
        u = np.asarray(tau_c, float)
        n = u.shape[0]
        d = self.delay_samples
        if d == 0:
            ud = u
        else:
            ud = np.zeros_like(u)
            if d < n:
                ud[d:] = u[:n - d]
        uh = ud
        if not self.sampled_motion:
            out = np.empty((2,) + u.shape)
            for i in range(2):
                out[i] = lfilter(self.num_resonant[i], self.den_resonant, uh, axis=0)
                if i == 1:  # tau_j does not see the rigid-body mode
                    out[i] += lfilter(self.num_rigid[i], (1.0, -2.0, 1.0), uh, axis=0)
            return out
        if d or means is None:
            means, slopes = sample_means(ud), sample_slopes(ud)
        g = np.zeros_like(ud) if slopes is None else np.asarray(slopes, float)
        out = np.empty((2,) + u.shape)
        for i in range(2):
            # Mean and slope share the denominators: their numerators are applied first, one recursion each.
            out[i] = lfilter((1.0,), self.den_resonant,
                             _fir2(self.num_resonant[i], means, self.num_resonant_slope[i], g), axis=0)
            if i == 1:
                out[i] += lfilter((1.0,), (1.0, -2.0, 1.0),
                                  _fir2(self.num_rigid[i], means, self.num_rigid_slope[i], g), axis=0)
            if self.feedthrough[i]:
                out[i] += self.feedthrough[i] * ud
        return out

    def frequency_response(self, f_hz: np.ndarray) -> np.ndarray:
        """Sampled-data responses at ``f_hz`` [Hz].

        Returns
        -------
        numpy.ndarray
            Shape ``(2, n)``, complex: ``tau_j / tau_c`` [Nm/Nm] and
            ``theta_m / tau_c`` [rad/Nm], the delay included.
        """
        zi = np.exp(-2j * np.pi * np.asarray(f_hz, float) * self.sample_time_s)  # z^-1
        powers = zi[None, :] ** np.arange(4)[:, None]
        den_r = self.den_resonant @ powers[:3]
        den_j = np.array([1.0, -2.0, 1.0]) @ powers[:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.array([(self.num_resonant[i] @ powers) / den_r + self.feedthrough[i]
                            + (0.0 if i == 0 else (self.num_rigid[i] @ powers) / den_j) for i in range(2)])
        return out * zi[None, :] ** self.delay_samples


def sample_means(u: np.ndarray) -> np.ndarray:
    """Each sample interval's mean of a sampled smooth signal (cubic through the samples), along axis 0.

    Held as a command instead, a 50 Hz ripple would lag by half a sample (9 degrees at 1 kHz).
    """
    u = np.asarray(u, float)
    if u.shape[0] < 2:
        return u
    up = np.concatenate([u[:1], u, u[-1:], u[-1:]])
    return (13.0 * (up[1:-2] + up[2:-1]) - up[:-3] - up[3:]) / 24.0


def _fir2(b: np.ndarray, x: np.ndarray, c: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``sum_j b[j] x[k - j] + c[j] g[k - j]`` along axis 0, from rest."""
    out = np.zeros_like(x)
    n = x.shape[0]
    for j in range(len(b)):
        if j >= n or not (b[j] or c[j]):
            continue
        tap = b[j] * x[:n - j]
        if c[j]:
            tap += c[j] * g[:n - j]
        out[j:] += tap
    return out


def _cubic_weights(weight) -> np.ndarray:
    """``int_0^1 weight(s) p(s) ds`` for the cubic ``p`` through samples at s = -1, 0, 1, 2, as weights of
    those samples (three-point Gauss-Legendre: exact for the quartic)."""
    nodes, w = np.polynomial.legendre.leggauss(3)
    s, w = 0.5 * (nodes + 1.0), 0.5 * w
    pts = np.array([-1.0, 0.0, 1.0, 2.0])
    out = np.zeros(4)
    for j in range(4):
        others = np.delete(pts, j)
        L = np.prod([(s - o) / (pts[j] - o) for o in others], axis=0)
        out[j] = float(np.sum(w * weight(s) * L))
    return out


_SLOPE_WEIGHTS = _cubic_weights(lambda s: 12.0 * (s - 0.5))


def sample_slopes(u: np.ndarray) -> np.ndarray:
    """Each sample interval's slope of a sampled smooth signal (cubic through the samples), along axis 0:
    ``12 int_0^1 (s - 1/2) u(k + s) ds``, the ``g`` of ``u(k + s) = m + g (s - 1/2)`` that has the same first
    moment (the module docstring).

    Examples
    --------
    >>> np.round(sample_slopes(np.arange(6.0) ** 2)[1:4], 12).tolist()  # u = k^2: slope 2 k + 1 over [k, k + 1]
    [3.0, 5.0, 7.0]
    """
    u = np.asarray(u, float)
    if u.shape[0] < 2:
        return np.zeros_like(u)
    up = np.concatenate([u[:1], u, u[-1:], u[-1:]])
    w = _SLOPE_WEIGHTS
    return w[0] * up[:-3] + w[1] * up[1:-2] + w[2] * up[2:-1] + w[3] * up[3:]


def _slope_hold(A: np.ndarray, B: np.ndarray, T: float) -> np.ndarray:
    """``int_0^T e^{A(T-s)} B (s / T - 1/2) ds``: the state a unit slope over one sample leaves."""
    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n], M[n, n + 1] = A, B, 1.0 / T
    E = expm(M * T)
    return -0.5 * E[:n, n] + E[:n, n + 1]


def state_matrices(p: ParameterSource, input: str = "command") -> StrictlyProperMatrices:
    """``(A, B, C)`` of eqs (1)-(3), state ``(theta_m, z, theta_l, omega_l)``, outputs ``(tau_J, theta_m)``.

    Eq (1) integrated once: ``Jc theta_m' = (bc / K)(tau_c - tau_J) + z``,
    ``z' = tau_c - tau_J``; eq (2): ``Jl omega_l' = tau_J``; eq (3):
    ``tau_J = K (theta_m - theta_l)``. ``B`` is the column of ``input``
    (:data:`~iiwa_ident.model.INPUTS`; the command's delay is not in it).
    """
    Jc, bc, K, Jl, _ = parameter_values(p)
    A = np.array([[-bc / Jc, 1.0 / Jc, bc / Jc, 0.0],
                  [-K, 0.0, K, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [K / Jl, 0.0, -K / Jl, 0.0]])
    if input in ("command", "motor"):
        B = np.array([bc / (K * Jc), 1.0, 0.0, 0.0])
    elif input == "link":
        B = np.array([0.0, 0.0, 0.0, 1.0 / Jl])
    elif input == "deflection":
        # tau_J gains -K f: the motor side's torque error, the integral state and the link all see it.
        B = np.array([bc / Jc, K, 0.0, -K / Jl])
    elif input == "reaction":
        B = np.array([0.0, 1.0, 0.0, 0.0])
    else:
        raise ValueError(f"input must be one of {INPUTS}")
    C = np.array([[K, 0.0, -K, 0.0], [1.0, 0.0, 0.0, 0.0]])
    return StrictlyProperMatrices(A, B, C)


def discretize(params: ParameterSource, sample_time_s: float, input: str = "command") -> DiscreteModel:
    """Exact ZOH discretisation of eqs (1)-(3) with the fractional delay ``Td``.

    Parameters
    ----------
    params : mapping, JointModel or sequence
        ``Jc, bc, K, Jl`` [SI] and ``Td`` [s], ``Td >= 0``.
    sample_time_s : float
        Sample time T [s] (the input is held over each sample).
    input : {"command", "motor", "link", "deflection"}
        Which input (:data:`INPUTS`): the command ``tau_c`` (delayed by
        ``Td``), a torque added to it inside the robot, a torque on the
        link [Nm], or the transmission's deflection ``f(theta_m)`` of
        eq (5) [rad] (the last three without delay; the deflection's direct
        path ``-K f`` to ``tau_j`` is :attr:`DiscreteModel.feedthrough`).

    Returns
    -------
    DiscreteModel
    """
    Jc, bc, K, Jl, Td = parameter_values(params)
    if min(Jc, K, Jl) <= 0 or bc < 0 or Td < 0:
        raise ValueError("need Jc, K, Jl > 0 and bc, Td >= 0")
    if input not in INPUTS:
        raise ValueError(f"input must be one of {INPUTS}")
    T = float(sample_time_s)
    A, B, C = state_matrices((Jc, bc, K, Jl, Td), input)
    if input != "command":
        Td = 0.0
    # Modal split: range(A^2) is the resonant pair, null(A^2) the rigid-body Jordan chain
    # v1 (displacement, A v1 = 0) and v2 (velocity, A v2 = v1).
    left, _, _ = np.linalg.svd(A @ A)
    V = np.column_stack([left[:, :2], [1.0, 0.0, 1.0, 0.0], [0.0, Jc, 0.0, 1.0]])
    Vi = np.linalg.inv(V)
    Ar = (Vi @ A @ V)[:2, :2]
    Bm = Vi @ B
    Cm = C @ V
    Phi, g0, g1, d = delayed_hold(Ar, Bm[:2], T, Td)
    tau = split_delay(Td, T)[1]
    h0 = T - tau
    tr, det = Phi[0, 0] + Phi[1, 1], Phi[0, 0] * Phi[1, 1] - Phi[0, 1] * Phi[1, 0]
    P = tr * np.eye(2) - Phi  # adj(zI - Phi) = zI - P for 2x2 matrices
    num_r = np.array([[0.0, c @ g0, c @ g1 - c @ P @ g0, -(c @ P @ g1)] for c in Cm[:, :2]])

    b1, b2 = Bm[2], Bm[3]

    def rigid(h: float) -> np.ndarray:
        return np.array([h * b1 + 0.5 * h * h * b2, h * b2])

    gj0 = rigid(h0)
    gj1 = np.array([[1.0, h0], [0.0, 1.0]]) @ rigid(tau)
    num_j = []
    for c in Cm[:, 2:]:
        a0, a1 = c @ gj0, c @ gj1
        s0, s1 = c[0] * T * gj0[1], c[0] * T * gj1[1]
        num_j.append([0.0, a0, a1 - a0 + s0, s1 - a1])
    feed = np.array([-K, 0.0]) if input == "deflection" else np.zeros(2)
    motion = input in ("deflection", "reaction")
    num_rg, num_jg = np.zeros((2, 4)), np.zeros((2, 4))
    if motion:
        # The slope's state: the resonant pair's by the exponential, the double integrator's by hand (its
        # speed gains nothing over the sample, its position -b2 T^2 / 12).
        gr = _slope_hold(Ar, Bm[:2], T)
        num_rg = np.array([[0.0, c @ gr, -(c @ P @ gr), 0.0] for c in Cm[:, :2]])
        a = -Bm[3] * T * T / 12.0
        num_jg = np.array([[0.0, c[0] * a, -c[0] * a, 0.0] for c in Cm[:, 2:]])
    return DiscreteModel(sample_time_s=T, delay_samples=d, den_resonant=np.array([1.0, -tr, det]), num_resonant=num_r,
                         num_rigid=np.array(num_j), feedthrough=feed, sampled_motion=motion, num_resonant_slope=num_rg,
                         num_rigid_slope=num_jg)


def simulate_outputs(params: ParameterSource, tau_c: np.ndarray, sample_time_s: float) -> np.ndarray:
    """``tau_j`` [Nm] and ``theta_m - theta_m(0)`` [rad] for the command ``tau_c`` [Nm], from rest.

    Returns
    -------
    numpy.ndarray
        Shape ``(2, len(tau_c))``.
    """
    return discretize(params, sample_time_s).simulate(tau_c)
