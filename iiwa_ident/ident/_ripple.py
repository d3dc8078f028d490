"""Identification of the transmission nonlinearity of eq (5): period rho and lookup table.

Both methods of section III.B estimate the deflection ``f = theta_m - theta_j``
along the motor position and look for a component that is periodic in
position:

static (quasi-static runs with the external link reference)
    ``f = q_m - q_l_ref - tau_j / K``, from eqs (3) and (5) directly.
dynamic (constant-velocity runs)
    ``f = q_m - theta_l - tau_j / K`` with the link position unknown but
    held by the link inertia: its slow part is removed with a high-pass and
    its fast part, the small link motion of eq (7), is restored from the
    torque as ``theta_l'' = tau_j / J_l`` (eq (2) without external torque). This keeps the estimate unbiased at
    low speeds, where eq (7)'s approximation fails (at 0.3 rad/s and rho =
    0.0196 rad about 37% of the deflection reaches the link).

Every run is cut into passes (constant speed, one direction, no gaps) and
the passes into chunks. A position-periodic deflection is phase-locked to
the absolute motor position in every chunk, whatever the speed or
direction; noise, friction, gravity and time-periodic oscillations are not.
So the test statistic at spatial frequency k is Hotelling's T^2 of the
chunks' complex Fourier coefficients ``c_i(k)``: the squared magnitude of
their mean over its standard error. Under "no periodic deflection" it
follows an F(2, 2(n-1)) law, which gives a false-alarm probability corrected
for the number of independent frequencies searched (after calibrating the
statistic's floor on the data, for noise that is not independent between
chunks). The period is refined
by maximising the explained variance of a Fourier series in theta_m, and the
table f(x_i), ``x_i = i rho / N``, is that series sampled.

The passes and their deflection are :mod:`iiwa_ident.ident._ripple_passes`, the
spectrum and its harmonic families :mod:`iiwa_ident.ident._ripple_spectrum`;
here the period is refined, the table fitted and the runs combined.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy import optimize, stats

from iiwa_ident._defaults import PERIOD_MAX_RAD, PERIOD_MIN_RAD  # one definition, light for the CLI's help
from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._ripple_detect import sensitivity
from iiwa_ident.ident._ripple_lines import CrossRunLines, RunLines, cross_run_lines, pass_speed
from iiwa_ident.ident._ripple_passes import Pass, deflection, spread_repeated_stamps
from iiwa_ident.ident._ripple_spectrum import (
    FAMILY_HARMONICS,
    SEARCH_TRIES_PER_POINT,
    LineSpectrum,
    cut_chunks,
    false_alarm_probability,
    hotelling,
    line_search,
    taper,
)
from iiwa_ident.model import RIPPLE_PERIOD_RAD, JointModel, RippleTable, Source

__all__ = [
    "ENCODER_TICK_RAD",
    "PERIOD_MIN_RAD",
    "PERIOD_MAX_RAD",
    "MethodResult",
    "RippleResult",
    "identify_ripple",
    "ripple_model",
]

#: Motor encoder quantisation of the iiwa (section III.B) [rad].
ENCODER_TICK_RAD = 5.989e-8


@dataclass(kw_only=True)
class MethodResult:
    """Lookup table and fit of one method (or of all passes together)."""

    method: str
    lut: np.ndarray
    harmonics: int
    amplitude_rad: float
    rms_rad: float
    residual_rms_rad: float
    n_passes: int
    n_samples: int
    shift_rad: float = 0.0
    #: Standard error of ``amplitude_rad`` [rad]: delete-a-group jackknife over the passes (nan below 3 passes).
    amplitude_std_rad: float = math.nan


@dataclass(kw_only=True)
class RippleResult:
    """Outcome of :func:`identify_ripple` (all angles in rad, at the motor side)."""

    detected: bool
    period_rad: float | None
    period_std_rad: float | None
    false_alarm: float
    statistic: float
    lut: np.ndarray | None
    amplitude_rad: float | None
    methods: dict[str, MethodResult]
    spectrum_k: np.ndarray
    spectrum_stat: np.ndarray
    spectrum_power: np.ndarray
    velocity_table: list[dict]
    passes: list[Pass]
    warnings: list[str] = field(default_factory=list)
    K: float = 0.0
    Jl: float = 0.0
    link_motion: str = ""
    #: Per-run estimates when several runs were given (each analysed alone), and their agreement.
    runs: list[dict] = field(default_factory=list)
    agreement: dict = field(default_factory=dict)
    #: Every candidate line tested in every run (several runs only): :class:`~iiwa_ident.ident._ripple_lines.
    #: CrossRunLines`, None with one run.
    lines: CrossRunLines | None = None
    #: What each run detects at the period (the paper's rho where none is detected):
    #: :class:`~iiwa_ident.ident.RunSensitivity` per run.
    sensitivity: list = field(default_factory=list)
    #: Standard error of ``amplitude_rad`` [rad] (the combined table's jackknife; None without a detection or
    #: below three passes).
    amplitude_std_rad: float | None = None

    @property
    def cycles_per_rev(self) -> float | None:
        """Ripple cycles per joint revolution, 2 pi / rho."""
        return None if self.period_rad is None else 2 * math.pi / self.period_rad

    @property
    def period_ticks(self) -> float | None:
        """The period in encoder ticks (5.989e-8 rad a tick)."""
        return None if self.period_rad is None else self.period_rad / ENCODER_TICK_RAD

    def table(self):
        """The model file's ripple table of this result (:class:`~iiwa_ident.ident.RippleTable`: the period,
        the lookup table and how they were found), or None when nothing was detected."""
        if not self.detected:
            return None
        return RippleTable(self.period_rad, self.lut, {
            "period_std_rad": self.period_std_rad, "amplitude_rad": self.amplitude_rad,
            "cycles_per_rev": self.cycles_per_rev, "period_ticks": self.period_ticks,
            "false_alarm_probability": self.false_alarm, "methods": sorted(self.methods),
            "link_motion": self.link_motion})

    def to_json(self) -> dict:
        """The ``--json`` document (SI units)."""
        return {
            "detected": self.detected,
            "period_rad": self.period_rad,
            "period_std_rad": self.period_std_rad,
            "cycles_per_rev": self.cycles_per_rev,
            "period_ticks": self.period_ticks,
            "amplitude_rad": self.amplitude_rad,
            "amplitude_std_rad": self.amplitude_std_rad,
            "lut": None if self.lut is None else self.lut.tolist(),
            "lut_bins": None if self.lut is None else len(self.lut),
            "false_alarm_probability": self.false_alarm,
            "statistic": self.statistic,
            "methods": {name: {"amplitude_rad": m.amplitude_rad,
                               "amplitude_std_rad": _finite_or_none(m.amplitude_std_rad),
                               "rms_rad": m.rms_rad,
                               "residual_rms_rad": m.residual_rms_rad, "harmonics": m.harmonics,
                               "passes": m.n_passes, "samples": m.n_samples, "shift_rad": m.shift_rad,
                               "lut": m.lut.tolist()}
                        for name, m in self.methods.items()},
            "velocity_frequency": self.velocity_table,
            "K_used": self.K,
            "Jl_used": self.Jl,
            "link_motion": self.link_motion,
            "runs": self.runs,
            "agreement": self.agreement,
            "lines": None if self.lines is None else self.lines.to_json(),
            "sensitivity": [x.to_json() for x in self.sensitivity],
            "warnings": self.warnings,
        }


# --------------------------------------------------------------------------- refinement

def _best_k(passes: list[Pass], k_c: float, half: float, harmonics: int, rtol: float, grid: int = 9) -> float:
    """Spatial frequency in ``k_c +- half`` that minimises the grouped Fourier fit's residual [cycles/rad].

    The residual has a local minimum per higher harmonic's resolution cell, so a coarse grid picks
    the basin before a bounded Brent search refines it.
    """
    def cost(kk: float) -> float:
        return _fourier_fit(passes, 1.0 / kk, harmonics, grouped=True)[1]

    ks = np.linspace(k_c - half, k_c + half, grid)
    i = int(np.argmin([cost(kk) for kk in ks]))
    step = ks[1] - ks[0]
    lo, hi = max(ks[0], ks[i] - step), min(ks[-1], ks[i] + step)
    return float(optimize.minimize_scalar(cost, bounds=(lo, hi), method="bounded",
                                          options={"xatol": rtol * k_c}).x)


def _period_std(passes: list[Pass], k_hat: float, harmonics: int, half: float, parts: int = 8) -> float:
    """Standard error of the spatial frequency by a delete-a-group jackknife over the passes [cycles/rad].

    The residual is not white (double-integrated torque noise, slow leftovers), so the
    curvature of the least-squares cost would understate the error.
    """
    groups = np.array_split(np.arange(len(passes)), min(parts, len(passes)))
    if len(groups) < 3:
        return float("nan")

    def without(group: np.ndarray) -> list[Pass]:
        drop = set(group.tolist())
        return [p for i, p in enumerate(passes) if i not in drop]

    estimates = np.asarray([_best_k(without(g), k_hat, half, harmonics, 1e-8, grid=5) for g in groups])
    m = len(estimates)
    std = float(math.sqrt((m - 1) / m * np.sum((estimates - estimates.mean()) ** 2)))
    if np.any(np.abs(np.abs(estimates - k_hat) - half) < 1e-3 * half):
        # A subset's best period lies on the bracket: the data place the line only within it, and
        # estimates stopped by the same bound agree for that reason alone (a 3e-6 rad ripple got a std
        # of 1e-10 rad for an error of 4e-4 rad).
        std = max(std, half)
    return std


# --------------------------------------------------------------------------- fits

def _design(theta: np.ndarray, period: float, harmonics: int) -> np.ndarray:
    """Columns ``cos(k x)`` then ``sin(k x)``, ``k = 1..harmonics``, ``x = 2 pi theta / period``.

    The harmonics by complex multiplication from the fundamental (one complex exponential instead of two
    trigonometric functions per harmonic: the period searches form these thousands of times).
    """
    e1 = np.exp(1j * (2 * np.pi / period) * np.asarray(theta, float))
    out = np.empty((len(e1), 2 * harmonics))
    z = e1
    for k in range(harmonics):
        if k:
            z = z * e1
        out[:, k] = z.real
        out[:, harmonics + k] = z.imag
    return out


class _PassGroup(NamedTuple):
    """Passes that see the deflection through the same dynamics: one dataset, method, direction and speed."""

    dataset: Any
    method: str
    speed: float  #: [rad/s], to 0.1


def _group(p: Pass) -> _PassGroup:
    """Passes of one dataset, method, direction and speed see the deflection through the same dynamics."""
    return _PassGroup(p.dataset, p.method, round(p.speed, 1))


class _FourierFit(NamedTuple):
    """The joint least squares of :func:`_fourier_fit`: coefficients, residual sum of squares, covariance."""

    coef: np.ndarray
    ss: float
    cov: np.ndarray


def _fourier_fit(passes: list[Pass], period: float, harmonics: int,
                 grouped: bool = False, ss_only: bool = False) -> _FourierFit:
    """Joint least squares of a Fourier series in theta and each pass's slow nuisance.

    By Frisch-Waugh-Lovell the nuisance is projected out of the regressors of
    each pass as it was out of the data. Each pass is weighted by its
    ``weight`` and tapered (Hann), which keeps slow leftovers from leaking
    into the fit as in the detection. With ``grouped`` each group of passes
    (same dataset, method, speed and direction) gets its own coefficients:
    the dynamic method sees the ripple through speed-dependent link dynamics
    (eq (7)), which then cannot bias the common period; only the residual sum
    of squares is meaningful then. Returns the Fourier coefficients (cos then
    sin), the weighted residual sum of squares and the coefficients' covariance. With ``ss_only``
    (the period searches' cost) the covariance is left empty and the normal equations solve it
    (:func:`_normal_solve`).
    """
    if grouped:
        ss = 0.0
        for g in sorted({_group(p) for p in passes}):
            ss += _fourier_fit([p for p in passes if _group(p) == g], period, harmonics, ss_only=True)[1]
        return _FourierFit(np.zeros(0), ss, np.zeros((0, 0)))
    blocks, data = [], []
    for p in passes:
        A = _design(p.theta, period, harmonics)
        w = p.weight * np.sqrt(taper(len(p.f)))
        blocks.append(w[:, None] * (A - p.nuisance @ (p.nuisance.T @ A)))
        data.append(w * p.f)
    A = np.vstack(blocks)
    f = np.concatenate(data)
    coef = _normal_solve(A, f) if ss_only else None
    if coef is None:
        coef, *_ = np.linalg.lstsq(A, f, rcond=None)
    resid = f - A @ coef
    ss = float(resid @ resid)
    if ss_only:
        return _FourierFit(coef, ss, np.zeros((0, 0)))
    dof = max(1, len(f) - A.shape[1] - sum(p.nuisance.shape[1] for p in passes))
    cov = np.linalg.pinv(A.T @ A) * ss / dof
    return _FourierFit(coef, ss, cov)


def _normal_solve(A: np.ndarray, f: np.ndarray) -> np.ndarray | None:
    """Least squares by the column-scaled normal equations, or ``None`` where they are ill-conditioned.

    Several times faster than an SVD for these tall, nearly orthogonal Fourier columns; the residual,
    formed from the data, is stationary in the coefficients, so its sum of squares keeps full accuracy.
    """
    scale = np.sqrt(np.einsum("ij,ij->j", A, A))
    if not np.all(scale > 0):
        return None
    G = (A.T @ A) / np.outer(scale, scale)
    try:
        L = np.linalg.cholesky(G)
    except np.linalg.LinAlgError:
        return None
    d = np.diag(L)
    if d.min() < 1e-6 * d.max():  # condition number of the scaled columns above about 1e6
        return None
    y = np.linalg.solve(L, (A.T @ f) / scale)
    return np.linalg.solve(L.T, y) / scale


def _set_weights(passes: list[Pass], period: float, harmonics: int) -> None:
    """Weight each pass by the inverse noise level of its residual around the ripple's frequencies.

    The residual is far from white (the dynamic method's torque-integrated link
    term amplifies torque noise as 1/f^2), so the level is taken where it
    matters: in the band of the pass's ripple frequency |v| / rho and its harmonics.
    """
    for p in passes:
        p.weight = 1.0
    coef, _, _ = _fourier_fit(passes, period, harmonics)
    for p in passes:
        r = _residual([p], period, harmonics, coef)
        dt = float(np.median(np.diff(p.t)))
        spec = np.abs(np.fft.rfft(r * taper(len(r)))) ** 2
        freqs = np.fft.rfftfreq(len(r), dt)
        f_r = abs(p.speed) / period
        band = (freqs >= 0.7 * f_r) & (freqs <= min(1.3 * harmonics * f_r, freqs[-1]))
        if band.sum() < 3:
            band = freqs >= 0.5 * f_r
        level = float(np.mean(spec[band])) if band.any() else float(r @ r)
        p.weight = 1.0 / max(math.sqrt(level), 1e-300)


def _choose_harmonics(passes: list[Pass], period: float, max_harmonics: int) -> int:
    """Most harmonics whose amplitude is at least 4 standard errors (at least 1)."""
    coef, _, cov = _fourier_fit(passes, period, max_harmonics)
    h = max_harmonics
    a, b = coef[:h], coef[h:]
    amp = np.hypot(a, b)
    se = np.sqrt(np.maximum(np.diag(cov)[:h] + np.diag(cov)[h:], 1e-300) / 2)
    significant = np.nonzero(amp > 4 * se)[0]
    return int(significant.max() + 1) if len(significant) else 1


def _table(coef: np.ndarray, period: float, harmonics: int, bins: int) -> np.ndarray:
    x = np.arange(bins) * period / bins
    lut = _design(x, period, harmonics) @ coef
    return lut - lut.mean()


def _amplitude(passes: list[Pass], period: float, harmonics: int, bins: int) -> float:
    """Half the peak-to-peak of the table fitted to ``passes`` [rad]."""
    lut = _table(_fourier_fit(passes, period, harmonics)[0], period, harmonics, bins)
    return float((lut.max() - lut.min()) / 2)


def _amplitude_std(passes: list[Pass], period: float, harmonics: int, bins: int, parts: int = 8) -> float:
    """Standard error of the table's amplitude [rad]: the passes' scatter and the speeds' disagreement.

    The scatter by a delete-a-group jackknife over the passes (as for the period, :func:`_period_std`: the
    residual is not white, so the least-squares covariance would understate it). Every pass of a run sees the
    deflection through the same link dynamics, so their scatter misses an error the dynamics make alike in all
    of them; the spread of the amplitudes fitted to each speed and run alone (:func:`_group`, eq (7): the
    dynamics differ with the speed) stands for it, added in quadrature. Nan below three passes.
    """
    groups = np.array_split(np.arange(len(passes)), min(parts, len(passes)))
    if len(groups) < 3:
        return math.nan
    estimates = np.array([_amplitude([p for i, p in enumerate(passes) if not g[0] <= i <= g[-1]], period,
                                     harmonics, bins) for g in groups])
    m = len(estimates)
    jackknife = math.sqrt((m - 1) / m * np.sum((estimates - estimates.mean()) ** 2))
    by_speed = [_amplitude([p for p in passes if _group(p) == g], period, harmonics, bins)
                for g in sorted({_group(p) for p in passes})]
    spread = float(np.std(by_speed, ddof=1)) if len(by_speed) > 1 else 0.0
    return float(math.hypot(jackknife, spread))


def _residual(passes: list[Pass], period: float, harmonics: int, coef: np.ndarray) -> np.ndarray:
    """What the Fourier series ``coef`` leaves of the passes' deflection [rad], all passes in a row."""
    resid = []
    for p in passes:
        A = _design(p.theta, period, harmonics)
        resid.append(p.f - (A - p.nuisance @ (p.nuisance.T @ A)) @ coef)
    return np.concatenate(resid)


def _residual_rms(passes: list[Pass], period: float, max_harmonics: int) -> float:
    """RMS of what the table's series leaves of the passes [rad] (the harmonics chosen as for the table)."""
    h = _choose_harmonics(passes, period, max_harmonics)
    return float(np.sqrt(np.mean(_residual(passes, period, h, _fourier_fit(passes, period, h)[0]) ** 2)))


def _method_result(name: str, passes: list[Pass], period: float, max_harmonics: int, bins: int) -> MethodResult:
    h = _choose_harmonics(passes, period, max_harmonics)
    coef, _, _ = _fourier_fit(passes, period, h)
    lut = _table(coef, period, h, bins)
    resid = _residual(passes, period, h, coef)
    return MethodResult(method=name, lut=lut, harmonics=h, amplitude_rad=float((lut.max() - lut.min()) / 2),
                        rms_rad=float(np.sqrt(np.mean(lut ** 2))), residual_rms_rad=float(np.sqrt(np.mean(resid ** 2))),
                        n_passes=len(passes), n_samples=len(resid),
                        amplitude_std_rad=_amplitude_std(passes, period, h, bins))


def _circular_shift(reference: np.ndarray, other: np.ndarray) -> int:
    """Shift (in bins) that best aligns ``other`` to ``reference`` (circular cross-correlation)."""
    xc = np.fft.irfft(np.fft.rfft(reference) * np.conj(np.fft.rfft(other)), n=len(reference))
    return int(np.argmax(xc))


# --------------------------------------------------------------------------- main entry

@dataclass(frozen=True, kw_only=True)
class _Search:
    """What :func:`identify_ripple` was asked for (its arguments, same names and units)."""

    K: float
    Jl: float
    period_min: float
    period_max: float
    bins: int
    max_harmonics: int
    min_speed: float
    false_alarm: float
    link_motion: str


@dataclass(kw_only=True)
class _Candidate:
    """One deflection estimate (a choice of link motion) with its line and refined period."""

    name: str
    passes: list[Pass]
    spectrum: LineSpectrum
    period: float | None = None
    period_std: float = math.inf
    #: Why the line found is not a detection although it is significant ('' when it is one).
    not_decided: str = ""
    #: How the dynamic method treated the link's own motion: ``"restored"`` or ``"neglected"``.
    link_motion: str = "neglected"

    def refine(self, harmonics: int) -> None:
        """Pick the fundamental of the harmonic family and refine its period by a grouped, weighted Fourier fit."""
        spec = self.spectrum
        k, dk = spec.k, spec.dk
        fam = spec.family
        assert fam is not None  # line_search names the family of every spectrum
        k_star, half = fam.bracket(k, dk)
        # The harmonics the data show (as for the table), at least up to the strongest line: an unmodelled
        # harmonic above a pass's Nyquist limit leaves its mirror image next to a modelled one and pulls the
        # period. Not all of ``harmonics`` regardless: on a weak line the insignificant ones fit noise and
        # aliases (a 1.4 µrad 256-cycle line at 200 Hz was refined to 257.9 with 8 harmonics, std 0.04).
        harmonics = max(_choose_harmonics(self.passes, 1.0 / k_star, harmonics), fam.h_strong)
        # The period that best explains the deflection with a Fourier series (tapered, nuisance
        # projected, one set of coefficients per group of passes so that what is left of the
        # speed-dependent link dynamics cannot bias it), each pass weighted by its noise level.

        def refine() -> float:
            return _best_k(self.passes, k_star, half, harmonics, 1e-7)

        k_hat = refine()
        _set_weights(self.passes, 1.0 / k_hat, harmonics)
        k_hat = refine()
        if not k[0] + dk <= k_hat <= k[-1] - dk:
            self.not_decided = (f"the best period, {1 / k_hat:.4g} rad, lies at the edge of the searched range "
                                f"{1 / k[-1]:.4g}-{1 / k[0]:.4g} rad: not a detection; widen the range")
            return
        self.period = 1.0 / k_hat
        std = _period_std(self.passes, k_hat, harmonics, half) / k_hat ** 2
        self.period_std = std if math.isfinite(std) else math.inf


def _beyond_range(datasets: list[Dataset], period: float, link_motion: str, o: _Search) -> str:
    """Why the line at ``period`` [rad] is a harmonic of a period beyond ``o.period_max`` ('' when it is not).

    The passes were high-passed for the searched range, which takes such a fundamental out: they are
    made again for periods up to three times the line's, and the line's halves and thirds tested with
    the same law (four tries, at least a tenth of the line's power), T^2 calibrated by its median over
    the neighbouring frequencies as in the search.
    """
    passes: list[Pass] = []
    for i, ds in enumerate(datasets):
        passes += deflection(ds, i, o.K, o.Jl, 3.0 * period, o.min_speed, 4.0 * o.period_min,
                             link_motion=link_motion)
    if not passes:
        return ""
    span = max(p.theta.max() for p in passes) - min(p.theta.min() for p in passes)
    chunks = cut_chunks(passes, span)
    dk = 1.0 / (4.0 * span)
    k_line = 1.0 / period
    _, power_line, _ = hotelling(chunks, np.array([k_line]))
    for m in (2, 3):
        kk = k_line / m
        if 1.0 / kk <= o.period_max or 1.0 / kk > max(p.period_max for p in passes):
            continue
        grid = kk + dk * np.arange(-25, 26)
        t2, power, chunks_counted = hotelling(chunks, grid[grid > 0])
        centre = int(np.argmin(np.abs(grid[grid > 0] - kk)))
        floor = float(np.median(t2))
        t2_c = float(t2[centre]) * min(1.0, math.log(2.0) / max(floor, 1e-300))
        if (false_alarm_probability(t2_c, int(chunks_counted[centre]), 4.0) < o.false_alarm
                and power[centre] >= 0.1 * power_line[0]):
            return (f"the line at {period:.4g} rad looks like harmonic {m} of a period of {1 / kk:.4g} rad, "
                    f"longer than the longest searched ({o.period_max:.4g} rad): not a detection; widen "
                    "--period-max")
    return ""


def identify_ripple(datasets: list[Dataset], K: float = 18500.0, Jl: float = 5.6,
                    period_min: float = PERIOD_MIN_RAD, period_max: float = PERIOD_MAX_RAD, bins: int = 256,
                    max_harmonics: int = 8, min_speed: float = 0.003, false_alarm: float = 1e-3,
                    link_motion: str = "auto", amplitude_of_interest: float = 10e-6) -> RippleResult:
    """Decide whether a position-periodic deflection exists; find its period and lookup table.

    All runs are used together for the detection, the period and the table. With several runs each is
    also analysed alone: the result lists the per-run estimates (``runs``) and their agreement
    (``agreement``): a run agrees when its period is a harmonic of the pooled one (1/h of it) within
    three combined std and 0.1 %; the pooled period's std is at least the spread of the runs'
    fundamentals (their weighted mean's std times the Birge ratio sqrt(chi2 / dof)) and half the
    distance between that mean and the pooled period. Then every candidate line (each run's own lines
    times 1/4..4, the paper's rho) is tested in every run (:mod:`iiwa_ident.ident._ripple_lines`): the period
    compensated is the shortest whose harmonics are the lines reproduced at two speeds or more, refined on
    the runs that show them (``lines``); where no line is reproduced the joint analysis stands, withdrawn when
    a line of its family is periodic in time, and where the runs disagree the data do not decide.

    Parameters
    ----------
    datasets : list of Dataset
        Constant-velocity runs (dynamic method) and/or quasi-static runs with
        the link reference (static method), used together: both directions,
        all speeds.
    K : float
        Series-elastic stiffness [Nm/rad] (Table I: 18500).
    Jl : float
        Link inertia [kg m^2] for the dynamic method's link-motion term (Table I: 5.6).
    period_min, period_max : float
        Search range of the period [rad] (default 2000 to 50 cycles per
        motor revolution). A best period at an edge of the range, or a line
        that is a harmonic of a period beyond it, is a warning and not a
        detection.
    bins : int
        Lookup-table size.
    max_harmonics : int
        Most Fourier harmonics in the table.
    min_speed : float
        Slowest motion used [rad/s].
    false_alarm : float
        Largest false-alarm probability accepted as a detection.
    link_motion : {"auto", "restored", "neglected"}
        Dynamic method: restore the link's fast motion from the torque
        (eq (2)), neglect it (eq (7)), or keep whichever gives the more
        consistent line.
    amplitude_of_interest : float
        Deflection amplitude [rad] for which the result's ``sensitivity`` says, per run that does not detect it
        with probability 0.95, what run would: at its speed or the fastest slower one
        (:mod:`iiwa_ident.ident._ripple_detect`).

    Returns
    -------
    RippleResult

    Raises
    ------
    IiwaIdentError
        When no usable motion is found (too short, too slow, standing still).
    """
    options = _Search(K=K, Jl=Jl, period_min=period_min, period_max=period_max, bins=bins, max_harmonics=max_harmonics,
                      min_speed=min_speed, false_alarm=false_alarm, link_motion=link_motion)
    pooled = _identify_pooled(datasets, options)
    if len(datasets) < 2:
        speed = pass_speed(pooled.passes) if pooled.passes else _median_speed(datasets[0]) if datasets else 0.0
        beyond = _beyond_nyquist(pooled, datasets[0], speed) if datasets else None
        if beyond:
            pooled.warnings.append(f"{beyond}: an alias is possible; runs at other speeds would decide")
        return _with_sensitivity(pooled, amplitude_of_interest, options)
    runs, run_lines = [], []
    for i, ds in enumerate(datasets):
        name = str(ds.path) if ds.path else f"run {i + 1}"
        speed = _median_speed(ds)
        try:
            r = _identify_pooled([ds], options)
        except IiwaIdentError as err:
            runs.append({"run": name, "speed_rad_s": speed, "detected": False, "usable": False, "reason": str(err)})
            run_lines.append(_run_lines(name, ds, None, speed, options))
            continue
        run_lines.append(_run_lines(name, ds, r, speed, options))
        speed = run_lines[-1].speed
        # The spatial Nyquist limit at this run's speed: lines beyond it are aliases.
        nyquist_cpr = math.pi * ds.sample_rate_hz / max(speed, 1e-9)
        row = {"run": name, "speed_rad_s": speed, "detected": r.detected, "usable": True,
               "period_rad": r.period_rad, "period_std_rad": r.period_std_rad,
               "cycles_per_rev": r.cycles_per_rev, "false_alarm_probability": r.false_alarm,
               "amplitude_rad": r.amplitude_rad, "warnings": r.warnings, "link_motion": r.link_motion,
               "nyquist_cycles_per_rev": nyquist_cpr}
        beyond = _beyond_nyquist(r, ds, speed)
        cpr = r.cycles_per_rev
        if beyond and cpr is not None and cpr > nyquist_cpr:
            row.update(detected=False, reason=f"{beyond}: an alias; this run does not decide the period")
        elif beyond:
            # The fundamental's own line is below the limit: the run votes, and says what its estimate rests on.
            row["note"] = f"{beyond}: its period rests mostly on that line, where an alias is possible"
        runs.append(row)
    result = _combine_runs(pooled, runs)
    extra = [(1.0 / RIPPLE_PERIOD_RAD, "the paper's rho")]
    lines = cross_run_lines(run_lines, false_alarm, 1.0 / period_max, 1.0 / period_min, extra)
    return _with_sensitivity(_decide(result, lines, runs, datasets, options), amplitude_of_interest, options)


def _with_sensitivity(result: RippleResult, amplitude_rad: float, options: _Search) -> RippleResult:
    """The result with what each run detects at its period (the paper's rho where none is detected), for the
    search as it was asked (false-alarm probability, period range)."""
    period = result.period_rad if result.detected else None
    cycles = 2 * math.pi / (RIPPLE_PERIOD_RAD if period is None else period)
    passes = result.passes
    if period is not None and result.lut is not None:
        # The noise is read off what the table leaves: a strong line's sidelobes would pass for noise.
        rho, lut = float(period), result.lut
        x = np.arange(len(lut)) * rho / len(lut)
        passes = [dataclasses.replace(p, f=p.f - np.interp(p.theta, x, lut, period=rho)) for p in passes]
    result.sensitivity = sensitivity(passes, cycles, amplitude_rad, options.false_alarm,
                                     options.period_min, options.period_max) if passes else []
    return result


def ripple_model(base: JointModel, datasets: list[Dataset], sources: Sequence[Source] = (),
                 **options: Any) -> tuple[JointModel, RippleResult]:
    """The ripple stage of ``iiwa-ident ripple`` and both pipelines: search with the model's K and Jl, and the
    model with the lookup table found.

    Parameters
    ----------
    base : JointModel
        The joint's model (its K and Jl restore the link's motion); not changed.
    datasets : list of Dataset
        Constant-velocity or quasi-static runs of that joint.
    sources : sequence of Source
        The runs as the model file names them (role ``"ripple"``); they replace earlier ripple sources.
    **options
        Passed to :func:`identify_ripple` (period range, bins, link motion, ...).

    Returns
    -------
    model : JointModel
        A copy of ``base`` with :meth:`RippleResult.table` (None when nothing was detected) and the sources.
    result : RippleResult
    """
    result = identify_ripple(datasets, K=base.value("K"), Jl=base.value("Jl"), **options)
    model = copy.deepcopy(base)
    model.ripple = result.table()
    model.sources = [s for s in model.sources if s.role != "ripple"] + list(sources)
    return model, result


def _median_speed(ds: Dataset) -> float:
    """The run's median speed [rad/s]."""
    return float(np.median(np.abs(np.diff(ds["q_m"]) / np.diff(spread_repeated_stamps(ds["t"])))))


def _beyond_nyquist(r: RippleResult, ds: Dataset, speed: float) -> str:
    """Why a detected family may be an alias, or '': the family's strongest line (of its table) lies beyond
    the spatial Nyquist limit at the ``speed`` of the run's passes [rad/s], pi x rate / speed cycles per
    revolution."""
    cpr = r.cycles_per_rev
    if not r.detected or r.lut is None or cpr is None:
        return ""
    nyquist = math.pi * ds.sample_rate_hz / max(speed, 1e-9)
    h = int(np.argmax(np.abs(np.fft.rfft(r.lut))[1:FAMILY_HARMONICS + 4])) + 1
    line = h * cpr
    if line <= nyquist:
        return ""
    which = "its line" if h == 1 else f"its strongest line, harmonic {h} of {r.cycles_per_rev:.1f},"
    return (f"{which} at {line:.1f} cycles per revolution lies beyond the Nyquist limit at its passes' speed "
            f"{speed:.2f} rad/s ({nyquist:.0f} cycles per revolution at {ds.sample_rate_hz:.0f} Hz)")


def _combine_runs(pooled: RippleResult, runs: list[dict]) -> RippleResult:
    """Attach the per-run estimates to the pooled result, test their agreement and widen its std (where they
    disagree, :func:`_decide` may still find a family reproduced at several speeds)."""
    detected = [r for r in runs if r["detected"]]
    pooled.warnings += [f"{r['run']}: {r['note']}" for r in runs if r.get("note")]
    # verdict: "agree", "disagree" (the data do not decide) or "none" (no run detects anything).
    agreement: dict = {"runs": len(runs), "detected": len(detected), "agree": [], "disagree": [],
                       "chi2": None, "dof": None, "p_value": None, "birge_ratio": None}
    pooled.runs, pooled.agreement = runs, agreement
    if not detected:
        agreement["verdict"] = "none"
        return pooled
    period, period_std = pooled.period_rad, pooled.period_std_rad
    if not pooled.detected or period is None or period_std is None:  # (a detection has both)
        agreement["verdict"] = "disagree"
        agreement["disagree"] = [r["run"] for r in detected]
        pooled.warnings.append("the runs disagree: " + "; ".join(
            f"{r['run']} alone gives {r['cycles_per_rev']:.1f} cycles per revolution" for r in detected)
            + (f"; {len(runs) - len(detected)} of {len(runs)} detect nothing" if len(detected) < len(runs) else "")
            + "; together they detect nothing: the data do not decide")
        return pooled
    k0, s0 = 1.0 / period, period_std / period ** 2
    fund, stds = [], []
    for r in detected:
        k, sk = 1.0 / r["period_rad"], r["period_std_rad"] / r["period_rad"] ** 2
        h = max(1, int(round(k / k0)))
        tol = 3.0 * math.hypot(sk, h * s0) + 1e-3 * k
        if abs(k - h * k0) <= tol:
            r["harmonic"] = h
            agreement["agree"].append(r["run"])
            fund.append(k / h)
            stds.append(sk / h)
        else:
            agreement["disagree"].append(r["run"])
    if agreement["disagree"]:
        pooled.detected = False
        pooled.warnings.append("the runs disagree: " + "; ".join(
            f"{r['run']} gives {r['cycles_per_rev']:.1f} cycles per revolution" for r in detected)
            + f"; together they give {pooled.cycles_per_rev:.1f}: the data do not decide, nothing is reported")
        agreement["verdict"] = "disagree"
        return pooled
    agreement["verdict"] = "agree"
    if len(fund) >= 2:
        mean, spread_std, chi2, dof = _runs_mean(np.asarray(fund), np.asarray(stds))
        if chi2 is not None and dof is not None:
            birge = math.sqrt(max(1.0, chi2 / dof))
            agreement.update(chi2=chi2, dof=dof, p_value=float(stats.chi2.sf(chi2, dof)), birge_ratio=birge)
        else:
            pooled.warnings.append("the runs' own period std is unknown (fewer than 3 passes each to jackknife): "
                                   "their agreement is not tested, the std is their scatter")
        std_k = max(s0, spread_std, abs(mean - k0) / 2.0)
        pooled.period_std_rad = std_k / k0 ** 2
    return pooled


class _RunsMean(NamedTuple):
    """The runs' estimates combined: mean, its std, and the spread's chi^2 and degrees of freedom where tested."""

    mean: float
    std: float
    chi2: float | None
    dof: int | None


def _runs_mean(values: np.ndarray, stds: np.ndarray) -> _RunsMean:
    """The runs' estimates combined: ``(mean, std, chi2, dof)``.

    Runs with a known std are weighted by it and their std is widened by the Birge ratio; a run's std is
    unknown (infinite) when it has fewer than 3 passes to jackknife: such runs count only when no run has
    a known one, then with equal weights, the std from their scatter and no chi2 (None).
    """
    known = np.isfinite(stds) & (stds > 0)
    if np.any(known):
        v, w = values[known], 1.0 / np.maximum(stds[known], 1e-12 * np.abs(values[known])) ** 2
        mean = float(np.sum(w * v) / np.sum(w))
        if len(v) < 2:
            return _RunsMean(mean, float(1.0 / math.sqrt(float(np.sum(w)))), None, None)
        chi2 = float(np.sum(w * (v - mean) ** 2))
        dof = len(v) - 1
        return _RunsMean(mean, math.sqrt(max(1.0, chi2 / dof)) / math.sqrt(float(np.sum(w))), chi2, dof)
    mean = float(np.mean(values))
    spread = float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) >= 2 else math.inf
    return _RunsMean(mean, spread, None, None)


#: Strongest lines of a run's own spectrum offered as candidates beside its detected period.
_SEEDS_PER_RUN = 3


def _run_lines(name: str, ds: Dataset, r: RippleResult | None, speed: float, options: _Search) -> RunLines:
    """A run for the cross-run test: its passes (those of its own search, or made here when the search found
    too little motion for itself: a short run still tests a line another run predicts) and its own lines."""
    o = options
    if r is not None:
        passes = r.passes
    else:
        try:
            passes = deflection(ds, 0, o.K, o.Jl, o.period_max, o.min_speed,
                                min_travel=4.0 * o.period_min,
                                link_motion="restored" if o.link_motion == "auto" else o.link_motion)
        except IiwaIdentError:
            passes = []
    seeds: list[tuple[float, float]] = []
    searched = 1.0
    if r is not None and len(r.spectrum_k):
        k, t2 = r.spectrum_k, r.spectrum_stat
        searched = SEARCH_TRIES_PER_POINT * len(k)
        if r.period_rad is not None:
            seeds.append((1.0 / r.period_rad, (r.period_std_rad or 0.0) / r.period_rad ** 2
                          if math.isfinite(r.period_std_rad or math.inf) else 0.0))
        # Local maxima of T^2, strongest first, a resolution cell (4 grid points) apart.
        for i in np.argsort(t2)[::-1]:
            if len(seeds) >= _SEEDS_PER_RUN + (r.period_rad is not None):
                break
            if all(abs(k[i] - s) > 4 * (k[1] - k[0] if len(k) > 1 else 0.0) for s, _ in seeds):
                seeds.append((float(k[i]), 0.0))
    detected = int(r is not None and r.detected and r.period_rad is not None)
    return RunLines(name=name, passes=passes, speed=pass_speed(passes) if passes else speed, rate_hz=ds.sample_rate_hz,
                    seeds=seeds, searched=searched, detected=detected)


def _decide(result: RippleResult, lines: CrossRunLines, runs: list[dict], datasets: list[Dataset],
            options: _Search) -> RippleResult:
    """The period to compensate where lines are reproduced at two speeds or more; else the joint analysis.

    The cross-run test's family (:attr:`CrossRunLines.k0`) is the shortest period whose harmonics are all the
    reproduced lines. Where the runs' joint analysis already found that family it stands (its period refined on
    every pass); otherwise the period is refined on the passes of the runs that show the family's lines.
    """
    result.lines = lines
    if lines.k0 is None:
        if result.detected and result.period_rad is not None:
            lines.k_ref = 1.0 / result.period_rad
            hum = lines.temporal_at(lines.k_ref)
            if hum is not None:
                # No line of the joint analysis's family is reproduced at two speeds, and one of them keeps its
                # frequency in Hz across speeds: a disturbance periodic in time, not a deflection in position.
                result.detected = False
                result.agreement["verdict"] = "temporal"
                result.warnings.append(f"the family found at {result.cycles_per_rev:.1f} cycles per revolution has "
                                       f"a line periodic in time ({hum:.1f} Hz at every speed) and none reproduced "
                                       "in position: nothing is reported as a ripple table")
                lines.k_ref = None
        result.warnings += _line_warnings(lines)
        return result

    def said(k: float) -> str:
        family = ", ".join(f"{2 * math.pi * h * k:.1f} (harmonic {h})" for _, h in sorted(lines.harmonics,
                                                                                         key=lambda x: x[1]))
        return (f"the period compensated is the shortest whose harmonics are all the lines reproduced at two "
                f"speeds or more: {2 * math.pi * k:.2f} cycles per revolution (lines at {family})")

    found = _family_result(result, lines, lines.k0, runs, datasets, options)
    assert found.period_rad is not None  # the family's result is a detection
    lines.k_ref = 1.0 / found.period_rad
    found.warnings += [said(lines.k_ref)] + _line_warnings(lines)
    return found


def _family_result(pooled: RippleResult, lines: CrossRunLines, k0: float, runs: list[dict],
                   datasets: list[Dataset], options: _Search) -> RippleResult:
    """The family's period refined (grouped, weighted Fourier fit) on the passes of the runs that show its
    lines, its std the larger of the passes' jackknife and the scatter of the runs' own refined periods, and
    its table."""
    o = options
    support = lines.support
    names = [lines.runs[i].name for i in support]
    h_max = max(h for _, h in lines.harmonics)
    harmonics = max(1, min(o.max_harmonics, h_max))
    # A run whose link is measured (static passes) chose nothing: its link motion is neither restored nor neglected.
    chosen = (str(r.get("link_motion")) for r in runs if r["run"] in names and r.get("usable", True))
    motions = [m if m in ("restored", "neglected") else "restored" for m in chosen]
    # The link motion most supporting runs chose; a tie is decided as one run's choice is, by the smaller
    # residual of the family's table (not by a set's order, which changes with the interpreter's hash seed).
    most = max((motions.count(m) for m in motions), default=0)
    tied = sorted({m for m in motions if motions.count(m) == most}) or ["restored"]
    if o.link_motion != "auto":
        tied = [o.link_motion]
    # The family's fundamental as the runs' tests place its lines (each within its window), and a bracket of
    # half the finest run's resolution cell.
    ks = [t.k / h for c, h in lines.harmonics for t, s in zip(c.tests, c.significant) if s]
    k_c = float(np.median(ks)) if ks else k0

    def support_passes(motion: str) -> list[Pass]:
        out: list[Pass] = []
        for j, i in enumerate(support):
            out += deflection(datasets[i], j, o.K, o.Jl, o.period_max, o.min_speed,
                              min_travel=4.0 * o.period_min, link_motion=motion)
        return out

    options_passes = {m: support_passes(m) for m in tied}
    motion = min(tied, key=lambda m: _residual_rms(options_passes[m], 1.0 / k_c, o.max_harmonics)
                 if options_passes[m] else math.inf)
    passes = options_passes[motion]
    half = 0.5 * min(lines.runs[i].cell for i in support)
    k_hat = _best_k(passes, k_c, half, harmonics, 1e-8)
    _set_weights(passes, 1.0 / k_hat, harmonics)
    k_hat = _best_k(passes, k_c, half, harmonics, 1e-8)
    std_k = _period_std(passes, k_hat, harmonics, half)
    own = [_best_k([p for p in passes if p.dataset == j], k_hat, half, harmonics, 1e-8)
           for j in range(len(support)) if any(p.dataset == j for p in passes)]
    if len(own) >= 2:
        _, spread, _, _ = _runs_mean(np.asarray(own), np.full(len(own), math.inf))
        std_k = max(std_k, spread) if math.isfinite(std_k) else spread
    if not math.isfinite(std_k):
        std_k = half / math.sqrt(3.0)  # placed only within the bracket
    # Where the runs' own periods already agreed on this family, their agreement stands and its std (widened by
    # the Birge ratio) is kept when it is the larger.
    p, p_std = pooled.period_rad, pooled.period_std_rad
    agreed = False
    if pooled.detected and p is not None and p_std is not None and pooled.agreement.get("verdict") == "agree":
        s_pooled = p_std / p ** 2  # [cycles/rad]
        agreed = abs(1.0 / p - k_hat) <= 3e-3 * k_hat + 3.0 * s_pooled
        if agreed:
            std_k = max(std_k, s_pooled)
    period = 1.0 / k_hat
    methods, combined = _methods(passes, period, o.max_harmonics, o.bins)
    for r in runs:
        r.pop("harmonic", None)  # set against the joint analysis's period, which this one replaces
        if r["run"] in names and r["detected"]:
            h = r["cycles_per_rev"] / (2 * math.pi * k_hat)
            if round(h) >= 1 and abs(h - round(h)) <= 0.01 * h:
                r["harmonic"] = int(round(h))  # the run's own line is this harmonic of the family (not a fraction)
    agreement = dict(pooled.agreement, verdict="agree" if agreed else "reproduced", agree=names,
                     disagree=[r["run"] for r in runs if r["detected"] and r["run"] not in names],
                     supporting_speeds_rad_s=sorted(lines.runs[i].speed for i in support),
                     family_cycles_per_rev=2 * math.pi * k_hat,
                     lines_cycles_per_rev=[c.cycles_per_rev for c in lines.reproduced])
    table = _velocity_table(passes, period)
    # The pooled fit's own consistency warnings are of its table: the family's replace them.
    warnings = [w for w in pooled.warnings if "disagree" not in w and not w.startswith(_CONSISTENCY)] + \
        _consistency_warnings(table, combined)
    return RippleResult(detected=True, period_rad=period, period_std_rad=std_k / k_hat ** 2,
                        false_alarm=lines.false_alarm(), statistic=pooled.statistic, lut=combined.lut,
                        amplitude_rad=combined.amplitude_rad, methods=methods, spectrum_k=pooled.spectrum_k,
                        spectrum_stat=pooled.spectrum_stat, spectrum_power=pooled.spectrum_power,
                        velocity_table=table, passes=passes, warnings=warnings, K=pooled.K, Jl=pooled.Jl,
                        link_motion=motion, runs=runs, agreement=agreement, lines=lines,
                        amplitude_std_rad=_finite_or_none(combined.amplitude_std_rad))


def _line_warnings(lines: CrossRunLines) -> list[str]:
    """What the cross-run test found outside the family: temporal lines, and lines seen at one speed only."""
    out = []
    for c in lines.temporal():
        out.append(f"a line at {c.temporal_hz:.1f} Hz is periodic in time, not in position (it stays at that "
                   f"frequency across speeds; {c.cycles_per_rev:.1f} cycles per revolution in the run it was seen "
                   "in): not a transmission ripple")
    for c in sorted(lines.outside(), key=lambda c: min(t.p_value for t in c.tests))[:3]:
        out.append(f"a line at {c.cycles_per_rev:.1f} cycles per revolution is significant at two speeds or more "
                   f"but is not a harmonic of the family compensated (amplitude up to "
                   f"{1e6 * max(t.amplitude_rad for t, s in zip(c.tests, c.significant) if s):.2f} µrad): a second "
                   "periodic effect, or a sideband of the family's lines; it is not in the table")
    for c in sorted(lines.one_speed(), key=lambda c: min(t.p_value for t in c.tests))[:4]:
        where = [lines.runs[i] for i, s in enumerate(c.significant) if s]
        speeds = sorted({round(r.speed, 2) for r in where})
        out.append(f"a line at {c.cycles_per_rev:.1f} cycles per revolution is significant at "
                   f"{', '.join(f'{v:.2f}' for v in speeds)} rad/s only ({', '.join(r.name for r in where)}): "
                   "spatial or temporal, not decided by this data; it does not set the period")
    return out


def _identify_pooled(datasets: list[Dataset], o: _Search) -> RippleResult:
    """identify_ripple on all runs together, without the per-run analysis."""
    K, Jl, period_min, period_max, bins = o.K, o.Jl, o.period_min, o.period_max, o.bins
    max_harmonics, min_speed, false_alarm, link_motion = o.max_harmonics, o.min_speed, o.false_alarm, o.link_motion
    if not 0 < period_min < period_max:
        raise IiwaIdentError("ripple: need 0 < period_min < period_max")
    if bins < 16:
        raise IiwaIdentError("ripple: the lookup table needs at least 16 bins")
    joints = {ds.joint for ds in datasets}
    if len(joints) > 1:
        raise IiwaIdentError(f"ripple: the datasets are from different joints ({sorted(joints)}); "
                             "a deflection is identified one joint at a time")
    # The dynamic method restores the link's own fast motion from the torque (eq (2)); on a real arm
    # other torques act on the link too, and the term can add more noise than it removes. Both
    # estimates are tried, and the one its table explains better (smaller residual RMS) is kept. Not the
    # smaller period std: it can be small for the wrong reason (a neglected link motion in position mode put a
    # simulated 256-cycle line at 258.2 with a std of 1e-7 rad, 1 % off, its residual 50 times the restored
    # one's); nor the larger T^2, which moved two of 30 scenario draws to a harmonic.
    if link_motion not in ("auto", "restored", "neglected"):
        raise IiwaIdentError(f"ripple: link_motion must be auto, restored or neglected, got {link_motion!r}")
    motions = ("restored", "neglected") if link_motion == "auto" else (link_motion,)
    candidates = []
    for motion in motions:
        passes: list[Pass] = []
        for i, ds in enumerate(datasets):
            passes += deflection(ds, i, K, Jl, period_max, min_speed, min_travel=4.0 * period_min,
                                 link_motion=motion)
        if not passes:
            names = ", ".join(str(ds.path or f"dataset {i}") for i, ds in enumerate(datasets))
            raise IiwaIdentError(f"{names}: no stretch of constant-speed motion (at least {min_speed} rad/s over "
                                 f"{4 * period_min:g} rad) to identify a position-periodic deflection from")
        dynamic = any(p.method == "dynamic" for p in passes)
        name = motion if dynamic else "measured"
        candidates.append(_Candidate(name=name, passes=passes, spectrum=line_search(passes, period_min, period_max),
                                     link_motion=motion))
        if not dynamic:
            break  # static passes only: the link is measured, nothing to choose
    for c in candidates:
        if c.spectrum.detection_false_alarm(len(candidates)) <= false_alarm:
            c.refine(max_harmonics)
    for c in candidates:
        if c.period is not None and 2.0 * c.period > period_max:
            beyond = _beyond_range(datasets, c.period, c.link_motion, o)
            if beyond:
                c.period, c.not_decided = None, beyond
    detected = [c for c in candidates if c.period is not None]

    def misfit(c: _Candidate) -> float:
        return math.inf if c.period is None else _residual_rms(c.passes, c.period, max_harmonics)

    best = min(detected, key=misfit) if len(detected) > 1 \
        else detected[0] if detected else \
        min(candidates, key=lambda c: c.spectrum.detection_false_alarm(len(candidates)))
    passes, spec = best.passes, best.spectrum
    warnings = list(spec.warnings) + [c.not_decided for c in candidates if c.not_decided and not detected][:1]
    directions = {np.sign(p.speed) for p in passes}
    speeds = [abs(p.speed) for p in passes]
    if len(directions) == 1 and max(speeds) <= 1.1 * min(speeds):
        warnings.append("one direction at one speed only: a disturbance periodic in time at speed/rho Hz "
                        "cannot be told apart from a position-periodic one; run both directions or two speeds")
    if best.period is not None and spec.family is not None and spec.family.weak_subharmonic is not None:
        k_sub, share = spec.family.weak_subharmonic
        warnings.append(f"weaker lines at multiples of {1 / k_sub:.4g} rad ({2 * math.pi * k_sub:.0f} cycles per "
                        f"revolution, {share:.1%} of the strongest line's power) are significant too: a slower "
                        "periodic effect (once per motor revolution?) below what the table needs")
    fap = spec.detection_false_alarm(len(candidates))
    stat = float(spec.t2[spec.i_best])
    period, period_std = best.period, best.period_std
    if period is None:
        return RippleResult(detected=False, period_rad=None, period_std_rad=None, false_alarm=fap, statistic=stat,
                            lut=None, amplitude_rad=None, methods={}, spectrum_k=spec.k, spectrum_stat=spec.t2,
                            spectrum_power=spec.power, velocity_table=[], passes=passes, warnings=warnings, K=K,
                            Jl=Jl, link_motion=best.name)
    methods, combined = _methods(passes, period, max_harmonics, bins)
    table = _velocity_table(passes, period)
    return RippleResult(detected=True, period_rad=period, period_std_rad=period_std, false_alarm=fap,
                        statistic=stat, lut=combined.lut, amplitude_rad=combined.amplitude_rad, methods=methods,
                        spectrum_k=spec.k, spectrum_stat=spec.t2, spectrum_power=spec.power, velocity_table=table,
                        passes=passes, warnings=warnings + _consistency_warnings(table, combined), K=K, Jl=Jl,
                        link_motion=best.name, amplitude_std_rad=_finite_or_none(combined.amplitude_std_rad))


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _methods(passes: list[Pass], period: float, max_harmonics: int, bins: int) -> tuple[dict, MethodResult]:
    """Each method's table (the dynamic one aligned to the static one, which is measured directly) and the
    table written to the model, from every pass weighted by its noise."""
    methods = {}
    for name in ("static", "dynamic"):
        ps = [p for p in passes if p.method == name]
        if ps:
            methods[name] = _method_result(name, ps, period, max_harmonics, bins)
    if len(methods) == 2:
        shift = _circular_shift(methods["static"].lut, methods["dynamic"].lut)
        if shift > bins // 2:
            shift -= bins
        methods["dynamic"].shift_rad = shift * period / bins
        methods["dynamic"].lut = np.roll(methods["dynamic"].lut, shift)
    return methods, _method_result("combined", passes, period, max_harmonics, bins)


def _velocity_table(passes: list[Pass], period: float) -> list[dict]:
    """Eq (6) per speed: predicted ripple frequency |v| / rho against the torque spectrum's peak."""
    # Passes within 10% of each other's speed form one row.
    groups: dict[float, list[Pass]] = {}
    for p in sorted(passes, key=lambda p: abs(p.speed)):
        for speed in groups:
            if abs(abs(p.speed) - speed) <= 0.1 * speed:
                groups[speed].append(p)
                break
        else:
            groups[abs(p.speed)] = [p]
    groups = {float(np.median([abs(p.speed) for p in ps])): ps for ps in groups.values()}
    rows = []
    for speed, ps in sorted(groups.items()):
        f_pred = speed / period
        best = (0.0, float("nan"))
        resolution = float("nan")
        for p in ps:
            dt = np.median(np.diff(p.t))
            if f_pred >= 0.5 / dt or len(p.t) < 16:
                continue
            spec = np.abs(np.fft.rfft((p.tau_hp - p.tau_hp.mean()) * np.hanning(len(p.t))))
            freqs = np.fft.rfftfreq(len(p.t), dt)
            band = np.abs(freqs - f_pred) <= 0.2 * f_pred
            if band.any():
                j = np.nonzero(band)[0][np.argmax(spec[band])]
                if spec[j] > best[0]:
                    best = (spec[j], float(freqs[j]))
                    resolution = float(freqs[1])
        rows.append({"speed_rad_s": speed, "predicted_hz": f_pred, "measured_hz": best[1], "passes": len(ps),
                     "resolution_hz": resolution})
    return rows


#: Largest relative miss of eq (6) (the torque spectrum's peak against |v| / rho) said nothing of, beyond twice
#: the spectrum's resolution.
EQ6_MISS = 0.1
#: Largest ratio of the deflection's residual about the table to the table's amplitude said nothing of.
TABLE_RESIDUAL_RATIO = 2.0


#: How the warnings of :func:`_consistency_warnings` begin.
_CONSISTENCY = ("eq (6): ", "the deflection about the table ")


def _consistency_warnings(velocity_table: list[dict], combined: MethodResult) -> list[str]:
    """What the found period and table fail to explain: a torque peak away from eq (6)'s frequency, a
    deflection the table leaves mostly unexplained."""
    out = []
    for r in velocity_table:
        f, m, res = r["predicted_hz"], r["measured_hz"], r.get("resolution_hz", 0.0)
        if math.isfinite(m) and abs(m - f) > max(EQ6_MISS * f, 2.0 * res):
            out.append(f"eq (6): at {r['speed_rad_s']:.3g} rad/s the torque spectrum peaks at {m:.3g} Hz where "
                       f"|v| / rho predicts {f:.3g} Hz ({100 * (m / f - 1):+.0f} %): that line is not the "
                       "ripple's (a filter before the log, another periodic torque)")
    amp, resid = combined.amplitude_rad, combined.residual_rms_rad
    if amp > 0 and resid > TABLE_RESIDUAL_RATIO * amp:
        out.append(f"the deflection about the table is {resid * 1e6:.3g} µrad RMS, {resid / amp:.1f} times the "
                   f"table's amplitude ({amp * 1e6:.3g} µrad): the period may hold, the table's shape is uncertain "
                   "and the position correction of eq (9) removes a small part of what varies")
    return out
