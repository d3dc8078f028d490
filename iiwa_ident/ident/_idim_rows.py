"""The inverse-dynamics fit's regression rows: a record filtered, differentiated exactly and turned into columns.

Each record (:class:`~iiwa_ident.ident._records.FitRecord`) is extended
evenly, low-passed without phase and differentiated in the frequency domain
(:class:`Spectral`); :func:`prepare_rows` keeps the samples away from its
ends and builds the motor equation's and the link equation's columns (the
robot's gravity model, the ripple's reaction and link acceleration,
spectral lines fitted as free sinusoids). :func:`dealiased` takes the
hold's aliased images out of a record at the current estimate. The
equations are those of :mod:`iiwa_ident.ident._idim`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from scipy import fft as _fft
from scipy.fft import next_fast_len

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._initial import MAX_DELAY_S
from iiwa_ident.ident._lines import block_weights, fit_sinusoid
from iiwa_ident.ident._records import BLOCK_S, FitRecord
from iiwa_ident.model import frequency_response

__all__ = ["FILTER_ORDER", "FC_MAX", "EDGE_S", "LINE_BAND_HZ", "Spectral", "Prepared", "Lines", "prepare_rows",
           "prepare_like", "Narrowband", "line_of", "ripple_basis", "ripple_link_columns", "ripple_terms",
           "robot_model_terms", "dealiased", "motor_rows", "motor_delayed", "motor_static"]

#: Samples this long at each end of a record are left out of the regression (filter transients) [s].
EDGE_S = 0.25
#: Order of the zero-phase Butterworth-magnitude low-pass [-].
FILTER_ORDER = 4
#: Highest filter cut-off [fs]: above it the hold's images alias onto the samples.
FC_MAX = 0.2


class Spectral:
    """Even extension, zero-phase low-pass and exact differentiation of one record's signals."""

    def __init__(self, n: int, T: float, fc: float) -> None:
        self.n, self.T = n, T
        # The even extension ends where it starts, so padding with the first value keeps it continuous.
        self.N = next_fast_len(2 * n, real=True)
        f = _fft.rfftfreq(self.N, T)
        self.f = f
        self.jw = 2j * np.pi * f
        self.hold = np.sinc(f * T)  # the zero-order hold's gain
        self.lp = 1.0 / np.sqrt(1.0 + (f / fc) ** (2 * FILTER_ORDER))
        # A wider low-pass for the signals nonlinear regressors are computed from: the regressor
        # is filtered afterwards, like every other term (tanh(L w) is not L tanh(w)).
        self.wide = 1.0 / np.sqrt(1.0 + (f / min(2.0 * fc, 0.45 / T)) ** (2 * FILTER_ORDER))

    def spectrum(self, x: np.ndarray, wide: bool = False) -> np.ndarray:
        ext = np.concatenate([x, x[::-1], np.full(self.N - 2 * self.n, x[0])])
        return _fft.rfft(ext) * (self.wide if wide else self.lp)

    def filtered(self, x: np.ndarray) -> np.ndarray:
        """``x`` through the low-pass (for regressors computed sample by sample)."""
        return self.back(self.spectrum(x))

    def back(self, X: np.ndarray, order: int = 0) -> np.ndarray:
        if order:
            X = X * self.jw ** order
        return _fft.irfft(X, self.N)[:self.n]

    def held_delayed(self, U: np.ndarray, delay_s: float) -> np.ndarray:
        """Spectrum of a zero-order-held command, delayed by ``delay_s``."""
        return U * self.hold * np.exp(-self.jw * (delay_s + 0.5 * self.T))


@dataclass(kw_only=True)
class Prepared:
    """A record through the inverse dynamics' low-passes: the signals its rows are built from."""

    rec: FitRecord
    sp: Spectral
    fc: float
    U: np.ndarray
    keep: np.ndarray
    block: np.ndarray
    tau_s: np.ndarray
    dtau_s: np.ndarray
    ddtau_s: np.ndarray
    q: np.ndarray  # absolute motor position, filtered [rad]
    dq: np.ndarray
    ddq: np.ndarray
    q_w: np.ndarray  # motor position, velocity, acceleration, torque reading and its rate through the wider low-pass
    dq_w: np.ndarray
    ddq_w: np.ndarray
    tau_w: np.ndarray
    dtau_w: np.ndarray
    g_cols: list[np.ndarray] = field(default_factory=list)  # the robot model's terms, filtered (see motor_rows)
    ripple: tuple[float, int] | None = None  # (period [rad], harmonics) of the ripple columns below
    rm_cols: list[np.ndarray] = field(default_factory=list)  # the ripple's motor-side reaction, filtered
    rl_cols: list[np.ndarray] = field(default_factory=list)  # the ripple's link acceleration, filtered
    lines: Lines | None = None  # spectral lines fitted as free sinusoids (see _line_search)
    line_cols: list[np.ndarray] = field(default_factory=list)  # their sin, cos through the low-pass
    motor_static: np.ndarray | None = field(default=None, repr=False)  # see motor_static


@dataclass(frozen=True)
class Lines:
    """Spectral lines [Hz] of the torque reading, with the record's slot among ``count`` records (each record
    has its own amplitudes and phases: recordings share no time origin)."""

    freqs: tuple[float, ...]
    slot: int
    count: int

    def block(self, cols: list[np.ndarray], k: np.ndarray) -> np.ndarray:
        """The rows ``k`` of every record's line columns: this record's filled, the others' zero."""
        out = np.zeros((int(np.count_nonzero(k)), 2 * len(self.freqs) * self.count))
        if cols:
            w = 2 * len(self.freqs)
            out[:, self.slot * w:(self.slot + 1) * w] = np.column_stack([c[k] for c in cols])
        return out

    def names(self) -> list[str]:
        return [f"line{j + 1}_{sc}_{r + 1}" for r in range(self.count) for j in range(len(self.freqs)) for sc in "sc"]


def prepare_rows(rec: FitRecord, ripple: tuple[float, int] | None = None, lines: Lines | None = None) -> Prepared:
    fs = 1.0 / rec.T
    fc = min(1.3 * rec.f_hi, FC_MAX * fs)
    sp = Spectral(rec.n, rec.T, fc)
    TS = sp.spectrum(rec.tau)
    Q = sp.spectrum(rec.q)
    edge = int(math.ceil((EDGE_S + 4.0 / fc + MAX_DELAY_S) / rec.T))
    keep = np.zeros(rec.n, bool)
    keep[edge:rec.n - edge] = True
    if keep.sum() < 10:
        raise IiwaIdentError(f"{rec.label}: too short for the inverse-dynamics fit")
    per_block = max(1, int(round(BLOCK_S / rec.T)))
    block = np.arange(rec.n) // per_block
    TSw, Qw = sp.spectrum(rec.tau, wide=True), sp.spectrum(rec.q, wide=True)
    q_w, dq_w, ddq_w, tau_w = rec.q0 + sp.back(Qw), sp.back(Qw, 1), sp.back(Qw, 2), sp.back(TSw)
    dtau_w = sp.back(TSw, 1)
    if lines is not None:
        # The link's angle and speed (eq (9)) from the reading without its lines: a 0.4 Nm hum at 114 Hz
        # adds 0.08 rad/s to omega_l through tau_s' / K, and the friction's tanh turned it into a
        # torque of its own (K 15 % off).
        for f in lines.freqs:
            h, dh = line_of(sp, TSw, f, keep, block)
            tau_w, dtau_w = tau_w - h, dtau_w - dh
    p = Prepared(rec=rec, sp=sp, fc=fc, U=sp.spectrum(rec.u), keep=keep, block=block, tau_s=sp.back(TS),
                 dtau_s=sp.back(TS, 1), ddtau_s=sp.back(TS, 2), q=rec.q0 + sp.back(Q), dq=sp.back(Q, 1),
                 ddq=sp.back(Q, 2), q_w=q_w, dq_w=dq_w, ddq_w=ddq_w, tau_w=tau_w, dtau_w=dtau_w,
                 g_cols=robot_model_terms(sp, q_w, dq_w))
    if ripple is not None:
        p.ripple = ripple
        p.rm_cols, p.rl_cols = ripple_terms(p, *ripple)
    if lines is not None and lines.freqs:
        p.lines = lines
        t = np.arange(rec.n) * rec.T
        for f in lines.freqs:
            p.line_cols += [sp.filtered(np.sin(2 * np.pi * f * t)), sp.filtered(np.cos(2 * np.pi * f * t))]
    return p


#: Half-width of the band around a line in which its sinusoid is fitted to the reading [Hz].
LINE_BAND_HZ = 1.0


class Narrowband:
    """A signal's band within :data:`LINE_BAND_HZ` of a frequency, on the kept samples, with block weights:
    the chirp passes the band once and loudly, a line stays; weighted by the inverse of each block's power
    there, the chirp's passage does not pull the line's frequency or amplitude."""

    def __init__(self, sp: Spectral, X: np.ndarray, f: float, keep: np.ndarray, block: np.ndarray) -> None:
        self.x = sp.back(np.where(np.abs(sp.f - f) <= LINE_BAND_HZ, X, 0.0))[keep]
        self.w = block_weights(self.x, block[keep])
        self.t = np.nonzero(keep)[0] * sp.T

    def fit(self, f: float) -> tuple[np.ndarray, float]:
        return fit_sinusoid(self.x, self.w, self.t, f)


def line_of(sp: Spectral, X: np.ndarray, f: float, keep: np.ndarray, block: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """The sinusoid at ``f`` [Hz] in the signal of spectrum ``X`` (see :class:`Narrowband`), over the whole
    record, and its derivative."""
    (a, c), _ = Narrowband(sp, X, f, keep, block).fit(f)
    t = np.arange(sp.n) * sp.T
    s, co = np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)
    return a * s + c * co, 2 * np.pi * f * (a * co - c * s)


def prepare_like(rec: FitRecord, like: Prepared) -> Prepared:
    """``rec`` prepared with the same ripple and line columns as ``like``."""
    return prepare_rows(rec, like.ripple, like.lines)


def ripple_basis(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, period: float, harmonics: int):
    """Per harmonic k: (w_k, cos, sin, (cos)'', (sin)'') of ``w_k q_m`` with ``w_k = 2 pi k / period``.

    The second time derivatives by the chain rule from the motor's motion, so that they are exact at the
    samples even where the ripple's lines lie above the filter's cut-off or the Nyquist limit.
    """
    w1 = 2.0 * math.pi / period
    c1, s1 = np.cos(w1 * q), np.sin(w1 * q)
    c, s = c1, s1
    dq2 = dq * dq
    for k in range(1, harmonics + 1):
        w = k * w1
        yield w, c, s, -w * s * ddq - w * w * c * dq2, w * c * ddq - w * w * s * dq2
        c, s = c * c1 - s * s1, s * c1 + c * s1


def ripple_link_columns(p: Prepared, period: float, harmonics: int) -> list[np.ndarray]:
    """The link equation's ripple columns alone (see :func:`ripple_terms`)."""
    flt = p.sp.filtered
    cols = []
    for _, _, _, ddc, dds in ripple_basis(p.q_w, p.dq_w, p.ddq_w, period, harmonics):
        cols += [-flt(ddc), -flt(dds)]
    return cols


def ripple_terms(p: Prepared, period: float, harmonics: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The ripple's columns of the motor and the link equation, through the low-pass.

    With ``f(q_m) = sum_k a_k cos(w_k q_m) + b_k sin(w_k q_m)`` (eq (5)), the link angle is
    ``theta_l = q_m - f(q_m) - tau_j / K``, which adds ``-Jl f''`` to the link equation (coefficients
    ``Jl a_k, Jl b_k``), and the motor feels the reaction ``tau_j f'(q_m)``, which adds ``-tau_s f'`` to
    the motor equation (coefficients ``a_k, b_k``).
    """
    flt = p.sp.filtered
    motor, link = [], []
    for w, c, s, ddc, dds in ripple_basis(p.q_w, p.dq_w, p.ddq_w, period, harmonics):
        motor += [flt(p.tau_w * w * s), flt(-p.tau_w * w * c)]
        link += [-flt(ddc), -flt(dds)]
    return motor, link


def robot_model_terms(sp: Spectral, q: np.ndarray, dq: np.ndarray) -> list[np.ndarray]:
    """sin q, cos q, q' cos q, -q' sin q through the low-pass: the motor equation's gravity-model columns."""
    sq, cq = np.sin(q), np.cos(q)
    return [sp.filtered(r) for r in (sq, cq, dq * cq, -dq * sq)]


def dealiased(rec: FitRecord, prm: dict[str, float], td: float) -> FitRecord:
    """``rec`` with the model's prediction of the hold's aliased images taken out of ``tau_j`` and ``q_m``.

    The robot holds its command over a cycle; the hold's images at ``f + k fs`` drive the joint too, and
    sampling folds their response back onto ``f``. A continuous-time equation fitted to the samples sees
    them as a gain and phase error that grows towards the Nyquist limit (a few per cent of ``bc`` when the
    chirp reaches ``0.2 fs``). Their size follows from the sampled command and eq (4)'s two transfer
    functions at the current estimate (terms ``k = +-1 .. +-4``); the link-side torques are slow and are not
    folded back.
    """
    K, Jl = prm["K"], prm["Jl"]
    T, n = rec.T, rec.n
    N = next_fast_len(2 * n, real=True)
    f = _fft.rfftfreq(N, T)
    fs = 1.0 / T
    U = _fft.rfft(rec.u - float(np.mean(rec.u)), N)
    A_tau = np.zeros_like(U)
    A_q = np.zeros_like(U)
    delayed = {**prm, "Td": td}
    for k in (-4, -3, -2, -1, 1, 2, 3, 4):
        fk = f + k * fs
        s = 2j * np.pi * fk
        h_tau = frequency_response(delayed, fk) * np.sinc(fk * T) * np.exp(-0.5 * s * T)
        A_tau += h_tau
        A_q += h_tau * (1.0 / K + 1.0 / (Jl * s**2))  # eqs (2)-(3): q_m = tau_j / K + theta_l
    tau_alias = _fft.irfft(A_tau * U, N)[:n]
    q_alias = _fft.irfft(A_q * U, N)[:n]
    return replace(rec, tau=rec.tau - tau_alias, q=rec.q - q_alias)


class MotorRows(NamedTuple):
    """The motor equation's ``y``, regressors and instruments on the kept samples."""

    y: np.ndarray
    Phi: np.ndarray
    Z: np.ndarray


def motor_rows(p: Prepared, td: float, tau_hat: tuple[np.ndarray, np.ndarray] | None = None
                ) -> MotorRows:
    """(y, Phi, Z) of the motor equation at delay ``td`` on the kept samples.

    Columns: Jc, beta, then the robot model's g_m: sin q, cos q, 1, and beta g_m': q' cos q, -q' sin q.
    """
    y, c, z = motor_delayed(p, td, tau_hat)
    S = motor_static(p)
    Phi = np.column_stack([S[:, :1], c, S[:, 1:]])
    Z = Phi.copy()
    Z[:, 1] = z
    return MotorRows(y, Phi, Z)


class MotorDelayed(NamedTuple):
    """The motor equation's parts that depend on the delay: ``y``, the beta column and its instrument."""

    y: np.ndarray
    beta: np.ndarray
    instrument: np.ndarray


def motor_delayed(p: Prepared, td: float, tau_hat: tuple[np.ndarray, np.ndarray] | None
                   ) -> MotorDelayed:
    """The motor equation's parts that depend on the delay ``td``: ``y``, the beta column and its instrument."""
    Ud = p.sp.held_delayed(p.U, td)
    u, du = p.sp.back(Ud), p.sp.back(Ud, 1)
    k = p.keep
    c = (p.dtau_s - du)[k]
    z = c if tau_hat is None else (tau_hat[0] - du)[k]
    return MotorDelayed((u - p.tau_s)[k], c, z)


def motor_static(p: Prepared) -> np.ndarray:
    """The motor equation's columns that do not depend on the delay (all but beta's), built once per prepared
    record: Jc, the robot model's g_m and beta g_m', the ripple's reaction and the lines."""
    if p.motor_static is None:
        k = p.keep
        g = [c[k] for c in p.g_cols]
        cols = [p.ddq[k], g[0], g[1], np.ones(int(k.sum())), g[2], g[3]] + [c[k] for c in p.rm_cols]
        S = np.column_stack(cols)
        if p.lines is not None:
            S = np.column_stack([S, p.lines.block(p.line_cols, k)])
        p.motor_static = S
    return p.motor_static
