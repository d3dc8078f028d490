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
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats
from scipy.interpolate import BSpline
from scipy.ndimage import maximum_filter1d, median_filter

from iiwa_ident._defaults import PERIOD_MAX_RAD, PERIOD_MIN_RAD  # one definition, light for the CLI's help
from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError

__all__ = [
    "ENCODER_TICK_RAD",
    "PERIOD_MIN_RAD",
    "PERIOD_MAX_RAD",
    "FAMILY_HARMONICS",
    "MIN_SUBHARMONIC_POWER",
    "Pass",
    "MethodResult",
    "RippleResult",
    "find_passes",
    "deflection",
    "identify_ripple",
]

#: Harmonics summed per candidate fundamental in the family search.
FAMILY_HARMONICS = 5
#: Least power, as a share of the family's strongest line, of the strongest line that only a subharmonic
#: k0/m explains, for k0/m to be the period: lines down to a tenth of the dominant one's amplitude.
MIN_SUBHARMONIC_POWER = 0.01
#: Motor encoder quantisation of the iiwa (section III.B) [rad].
ENCODER_TICK_RAD = 5.989e-8


@dataclass
class Pass:
    """One stretch of constant-speed motion in one direction, without gaps.

    Attributes
    ----------
    dataset : int
        Index of the dataset it comes from.
    method : str
        ``"static"`` or ``"dynamic"``.
    speed : float
        Median signed speed [rad/s].
    theta : numpy.ndarray
        Motor position q_m of the kept samples [rad].
    f : numpy.ndarray
        Deflection estimate at those samples [rad].
    t : numpy.ndarray
        Sample times [s].
    tau_hp : numpy.ndarray
        High-passed joint torque [Nm] (for eq (6) checks).
    nuisance : numpy.ndarray
        Orthonormal basis of what is slow in time (projected out of ``f``);
        fits project it out of their regressors too, so the estimate is the
        joint least-squares one.
    period_max : float
        Longest period this pass resolves: half its travel, at most the search limit [rad].
    weight : float
        Inverse noise standard deviation of the pass [1/rad], set by the fit.
    """

    dataset: int
    method: str
    speed: float
    theta: np.ndarray
    f: np.ndarray
    t: np.ndarray
    tau_hp: np.ndarray
    nuisance: np.ndarray
    period_max: float
    weight: float = 1.0


@dataclass
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


@dataclass
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
        from iiwa_ident.model import RippleTable

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
            "lut": None if self.lut is None else self.lut.tolist(),
            "lut_bins": None if self.lut is None else len(self.lut),
            "false_alarm_probability": self.false_alarm,
            "statistic": self.statistic,
            "methods": {name: {"amplitude_rad": m.amplitude_rad, "rms_rad": m.rms_rad,
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
            "warnings": self.warnings,
        }


# --------------------------------------------------------------------------- passes

def _smooth_velocity(t: np.ndarray, q: np.ndarray, window_s: float = 0.05) -> np.ndarray:
    dt = np.median(np.diff(t))
    v = np.gradient(q, t)
    n = max(1, int(round(window_s / dt)))
    if n > 1:
        kernel = np.ones(n) / n
        v = np.convolve(np.pad(v, (n // 2, n - 1 - n // 2), mode="edge"), kernel, mode="valid")
    return v


def find_passes(t: np.ndarray, q: np.ndarray, min_speed: float, min_travel: float,
                tolerance: float = 0.15) -> list[tuple[int, int]]:
    """Index ranges ``[i0, i1)`` of constant-speed motion in one direction without time gaps.

    A sample belongs to a pass when the smoothed speed is above ``min_speed``
    [rad/s] and within ``tolerance`` of the move's plateau speed; a pass
    must travel at least ``min_travel`` [rad].
    """
    dt = np.median(np.diff(t))
    v = _smooth_velocity(t, q)
    gap = np.r_[False, np.diff(t) > 1.5 * dt]
    moving = np.abs(v) >= min_speed
    out = []
    i = 0
    n = len(t)
    while i < n:
        if not moving[i]:
            i += 1
            continue
        j = i + 1
        sgn = np.sign(v[i])
        while j < n and moving[j] and np.sign(v[j]) == sgn and not gap[j]:
            j += 1
        # Keep the constant-speed core: samples within tolerance of the plateau speed (the
        # median would be pulled down by the acceleration ramps of a short move).
        seg = v[i:j]
        plateau = sgn * np.percentile(np.abs(seg), 90)
        ok = np.abs(seg - plateau) <= tolerance * abs(plateau)
        k = 0
        while k < len(seg):
            if not ok[k]:
                k += 1
                continue
            m = k
            while m < len(seg) and ok[m]:
                m += 1
            if abs(q[i + m - 1] - q[i + k]) >= min_travel:
                out.append((i + k, i + m))
            k = m
        i = j
    return out


def _smooth_basis(t: np.ndarray, knot_spacing: float) -> np.ndarray:
    """Cubic B-spline basis over ``t`` with knots about ``knot_spacing`` apart (plus a constant)."""
    t0, t1 = float(t[0]), float(t[-1])
    n_int = max(1, int(math.ceil((t1 - t0) / knot_spacing)))
    inner = np.linspace(t0, t1, n_int + 1)
    knots = np.r_[[t0] * 3, inner, [t1] * 3]
    return BSpline.design_matrix(np.clip(t, t0, t1), knots, 3).toarray()


def _pass_deflection(t: np.ndarray, q: np.ndarray, tau: np.ndarray, q_l: np.ndarray | None, K: float,
                     Jl: float | None, f_cut: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Deflection estimate, high-passed torque and nuisance basis of one pass.

    ``q - tau/K - theta_l`` with theta_l the measured link position (static)
    or the double integral of tau/J_l (dynamic: the link's own motion under
    the joint torque, eq (2); zero when ``Jl`` is None, the link's motion
    neglected); whatever is slow in time (integration
    constants, friction, gravity, the tracking controller) lies in the span
    of a cubic spline with knots 1/f_cut apart, which is projected out. It
    passes every period shorter than the search limit essentially untouched.
    """
    Q, _ = np.linalg.qr(_smooth_basis(t, 1.0 / f_cut))
    if q_l is None and Jl is None:
        theta_l = np.zeros_like(q)
    elif q_l is None:
        tc = t - t[0]
        acc = (tau - tau.mean()) / Jl
        vel = np.r_[0.0, np.cumsum(0.5 * (acc[1:] + acc[:-1]) * np.diff(tc))]
        theta_l = np.r_[0.0, np.cumsum(0.5 * (vel[1:] + vel[:-1]) * np.diff(tc))]
    else:
        theta_l = q_l
    raw = q - tau / K - theta_l
    return raw - Q @ (Q.T @ raw), tau - Q @ (Q.T @ tau), Q


def _spread_repeated_stamps(t: np.ndarray) -> np.ndarray:
    """Time stamps with each run of repeated stamps spread evenly towards the next distinct one.

    Real 200 Hz logs stamp a few consecutive samples alike (the logger, not the robot, repeats a
    stamp); the samples were taken a period apart, and a velocity or an integral over a zero time
    step would be infinite.
    """
    t = np.asarray(t, dtype=float)
    same = np.r_[False, np.diff(t) <= 0.0]
    if not same.any():
        return t
    out = t.copy()
    i, n = 1, len(t)
    while i < n:
        if not same[i]:
            i += 1
            continue
        j = i
        while j < n and same[j]:
            j += 1
        # Samples i-1 .. j-1 share a stamp; spread them up to the next distinct one (or one period on).
        t0 = out[i - 1]
        t1 = t[j] if j < n else t0 + (j - i + 1) * float(np.median(np.diff(t[~same])))
        out[i - 1:j] = t0 + (t1 - t0) * np.arange(j - i + 1) / (j - i + 1)
        i = j
    return out


def deflection(dataset: Dataset, index: int, K: float, Jl: float, period_max: float, min_speed: float,
               min_travel: float, method: str | None = None, link_motion: str = "restored") -> list[Pass]:
    """The passes of one dataset with their deflection estimates.

    Parameters
    ----------
    dataset : Dataset
        Constant-velocity run (dynamic method) or quasi-static run with
        ``q_l_ref`` (static method).
    K, Jl : float
        Stiffness [Nm/rad] and link inertia [kg m^2] of the model.
    period_max : float
        Longest period searched [rad]; a pass resolves periods up to half
        its travel, and its high-pass keeps every period it resolves.
    min_speed : float
        Slowest motion used [rad/s].
    min_travel : float
        Shortest pass kept [rad].
    method : str, optional
        Force ``"static"`` or ``"dynamic"`` (default: static for quasi_static runs).
    link_motion : str
        Dynamic method: ``"restored"`` (the link's own motion from the torque and ``Jl``, eq (2))
        or ``"neglected"`` (theta_l taken as constant over the pass).
    """
    if link_motion not in ("restored", "neglected"):
        raise IiwaIdentError(f"ripple: link_motion must be restored or neglected, got {link_motion!r}")
    t, q, tau = _spread_repeated_stamps(dataset["t"]), dataset["q_m"], dataset["tau_j"]
    if method is None:
        method = "static" if dataset.experiment == "quasi_static" else "dynamic"
    if method == "static" and not dataset.has("q_l_ref"):
        raise IiwaIdentError(f"{dataset.path or 'dataset'}: the static method needs the link reference q_l_ref")
    q_l = dataset["q_l_ref"] if method == "static" else None
    out = []
    for i0, i1 in find_passes(t, q, min_speed, min_travel=min_travel):
        if i1 - i0 < 16:
            continue
        speed = float(np.median(np.diff(q[i0:i1]) / np.diff(t[i0:i1])))
        longest = min(period_max, abs(q[i1 - 1] - q[i0]) / 2)
        f_cut = 0.5 * abs(speed) / longest
        f, th, Q = _pass_deflection(t[i0:i1], q[i0:i1], tau[i0:i1], None if q_l is None else q_l[i0:i1], K,
                                    Jl if link_motion == "restored" else None, f_cut)
        out.append(Pass(index, method, speed, q[i0:i1], f, t[i0:i1], th, Q, longest))
    return out


# --------------------------------------------------------------------------- spectrum

def _chunks(passes: list[Pass], span: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Cut passes into chunks of at least two of their longest periods (about span / 8).

    Each chunk is ``(theta, f, k_min)``: it speaks only for spatial
    frequencies above ``k_min`` = 1 / (its pass's longest period).
    """
    out = []
    for p in passes:
        travel = abs(p.theta[-1] - p.theta[0])
        n = max(1, int(travel // max(2.0 * p.period_max, span / 8)))
        for idx in np.array_split(np.arange(len(p.theta)), n):
            if len(idx) >= 8:
                out.append((p.theta[idx], p.f[idx], 1.0 / p.period_max))
    return out


def _chunk_coefficients(chunks, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hann-tapered complex Fourier coefficients of each chunk at ``k`` [cycles/rad], and validity.

    The taper keeps strong slow leftovers from leaking into the ripple band;
    a chunk is valid at k only above its pass's ``k_min``. ``k`` must be a
    uniform grid: the phasors are advanced by one grid step at a time.
    """
    sizes = [len(f) for _, f, _ in chunks]
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    theta = np.concatenate([th for th, _, _ in chunks])
    x = np.empty(len(theta))
    norm = np.empty(len(chunks))
    for i, (_, f, _) in enumerate(chunks):
        w = _taper(len(f))
        x[starts[i]:starts[i] + len(f)] = (f - np.average(f, weights=w)) * w
        norm[i] = 2.0 / w.sum()
    dk = k[1] - k[0] if len(k) > 1 else 0.0
    phasor = np.exp(-2j * np.pi * k[0] * theta)
    step = np.exp(-2j * np.pi * dk * theta)
    coefs = np.empty((len(chunks), len(k)), dtype=complex)
    for m in range(len(k)):
        if m and m % 256 == 0:  # re-anchor to keep rounding from accumulating
            phasor = np.exp(-2j * np.pi * k[m] * theta)
        coefs[:, m] = np.add.reduceat(x * phasor, starts) * norm
        phasor *= step
    valid = k[None, :] >= np.array([k_min for _, _, k_min in chunks])[:, None]
    coefs[~valid] = 0.0
    return coefs, valid


def _hotelling(chunks, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hotelling T^2 of the chunks' Fourier coefficients at ``k`` [cycles/rad].

    Returns T^2, the power of the mean coefficient, and the number of chunks
    that speak for each k (chunks of short passes are left out at long periods).
    """
    coefs, valid = _chunk_coefficients(chunks, k)
    count = valid.sum(axis=0)
    n = np.maximum(count, 1)
    mean = coefs.sum(axis=0) / n
    spread = np.where(valid, np.abs(coefs - mean) ** 2, 0.0).sum(axis=0)
    var = spread / np.maximum(count - 1, 1) / n
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = np.where(count >= 3, np.abs(mean) ** 2 / var, 0.0)
    return np.nan_to_num(t2, nan=0.0, posinf=0.0), np.abs(mean) ** 2, count


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
    estimates = []
    for g in groups:
        drop = set(g.tolist())
        keep = [p for i, p in enumerate(passes) if i not in drop]
        estimates.append(_best_k(keep, k_hat, half, harmonics, 1e-8, grid=5))
    estimates = np.asarray(estimates)
    m = len(estimates)
    std = float(math.sqrt((m - 1) / m * np.sum((estimates - estimates.mean()) ** 2)))
    if np.any(np.abs(np.abs(estimates - k_hat) - half) < 1e-3 * half):
        # A subset's best period lies on the bracket: the data place the line only within it, and
        # estimates stopped by the same bound agree for that reason alone (a 3e-6 rad ripple got a std
        # of 1e-10 rad for an error of 4e-4 rad).
        std = max(std, half)
    return std


def _false_alarm(t2: float, n: int, m_eff: float) -> float:
    """Probability that noise alone gives a maximum statistic this large among m_eff frequencies.

    With n chunks of independent circular noise, T^2 = |mean|^2 / (s^2 / n) follows F(2, 2(n-1)).
    """
    p = float(stats.f.sf(t2, 2, 2 * (n - 1))) if n > 1 else 1.0
    return float(min(1.0, -math.expm1(m_eff * math.log1p(-min(p, 1 - 1e-16)))))


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


@functools.lru_cache(maxsize=256)
def _taper(n: int) -> np.ndarray:
    """Hann window of n samples without its zero end points (read-only: one array per length, shared)."""
    w = np.hanning(n + 2)[1:-1]
    w.flags.writeable = False
    return w


def _group(p: Pass) -> tuple:
    """Passes of one dataset, method, direction and speed see the deflection through the same dynamics."""
    return (p.dataset, p.method, round(p.speed, 1))


def _fourier_fit(passes: list[Pass], period: float, harmonics: int,
                 grouped: bool = False, ss_only: bool = False) -> tuple[np.ndarray, float, np.ndarray]:
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
        return np.zeros(0), ss, np.zeros((0, 0))
    blocks, data = [], []
    for p in passes:
        A = _design(p.theta, period, harmonics)
        w = p.weight * np.sqrt(_taper(len(p.f)))
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
        return coef, ss, np.zeros((0, 0))
    dof = max(1, len(f) - A.shape[1] - sum(p.nuisance.shape[1] for p in passes))
    cov = np.linalg.pinv(A.T @ A) * ss / dof
    return coef, ss, cov


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
        A = _design(p.theta, period, harmonics)
        r = p.f - (A - p.nuisance @ (p.nuisance.T @ A)) @ coef
        dt = float(np.median(np.diff(p.t)))
        spec = np.abs(np.fft.rfft(r * _taper(len(r)))) ** 2
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


def _method_result(name: str, passes: list[Pass], period: float, max_harmonics: int, bins: int) -> MethodResult:
    h = _choose_harmonics(passes, period, max_harmonics)
    coef, _, _ = _fourier_fit(passes, period, h)
    lut = _table(coef, period, h, bins)
    resid = []
    for p in passes:
        A = _design(p.theta, period, h)
        resid.append(p.f - (A - p.nuisance @ (p.nuisance.T @ A)) @ coef)
    resid = np.concatenate(resid)
    return MethodResult(name, lut, h, float((lut.max() - lut.min()) / 2), float(np.sqrt(np.mean(lut ** 2))),
                        float(np.sqrt(np.mean(resid ** 2))), len(passes), len(resid))


def _circular_shift(reference: np.ndarray, other: np.ndarray) -> int:
    """Shift (in bins) that best aligns ``other`` to ``reference`` (circular cross-correlation)."""
    xc = np.fft.irfft(np.fft.rfft(reference) * np.conj(np.fft.rfft(other)), n=len(reference))
    return int(np.argmax(xc))


# --------------------------------------------------------------------------- main entry

@dataclass
class _LineSpectrum:
    """Hotelling spectrum of a set of passes over the searched spatial frequencies."""

    k: np.ndarray
    t2: np.ndarray
    power: np.ndarray
    count: np.ndarray
    dk: float
    i_best: int
    warnings: list[str]
    #: The most significant harmonic family (see :func:`_family`).
    family: "_Family | None" = None
    #: Grid steps to one and a half over the chunk length (:func:`_lobe_reach`).
    lobe_reach: int = 0

    def false_alarm(self, j: int, tries: float | None = None) -> float:
        """False-alarm probability of the line at index j among ``tries`` frequencies (default: all searched)."""
        return _false_alarm(float(self.t2[j]), int(self.count[j]), len(self.k) / 4.0 if tries is None else tries)

    def detection_false_alarm(self, estimates: int = 1) -> float:
        """False-alarm probability of the search: the strongest line or the strongest family, whichever is
        the more significant, each corrected for the frequencies searched, then (Bonferroni) for the two
        tests and for the ``estimates`` deflection estimates the strongest is chosen from."""
        tries = len(self.k) / 4.0
        p_fam = math.exp(self.family.log_p) if self.family is not None else 1.0
        fam = float(min(1.0, -math.expm1(tries * math.log1p(-min(p_fam, 1 - 1e-16))))) if p_fam > 0 else 0.0
        return min(1.0, 2.0 * estimates * min(self.false_alarm(self.i_best), fam))


def _line_search(passes: list[Pass], period_min: float, period_max: float) -> _LineSpectrum:
    warnings = []
    # A period is told from a slow trend only within a pass that travels two of them.
    longest = max(p.period_max for p in passes)
    if longest < period_max:
        warnings.append(f"the longest pass travels {2 * longest:.3g} rad: periods searched up to {longest:.3g} rad")
        period_max = longest
    span = max(p.theta.max() for p in passes) - min(p.theta.min() for p in passes)
    chunks = _chunks(passes, span)
    if len(chunks) < 3:
        raise IiwaIdentError(f"ripple: too little motion: {len(chunks)} usable stretches (need 3 or more); "
                             "record longer runs, both directions or more speeds")
    # Spatial frequency grid: 4 points per resolution cell 1/span.
    dk = 1.0 / (4.0 * span)
    k = np.arange(1.0 / period_max, 1.0 / period_min + dk, dk)
    t2_raw, power, count = _hotelling(chunks, k)
    # Real logs have noise that is correlated between neighbouring chunks (slow oscillations,
    # gravity and friction leftovers), which lifts the whole T^2 floor above its F(2, 2(n-1))
    # law. Calibrate with the local median (ln 2 under that law), never making a line more
    # significant than the law says.
    floor = median_filter(t2_raw, size=max(51, len(k) // 10) | 1, mode="nearest")
    t2 = t2_raw * np.minimum(1.0, math.log(2.0) / np.maximum(floor, 1e-300))
    spec = _LineSpectrum(k, t2, power, count, dk, int(np.argmax(t2)), warnings, lobe_reach=_lobe_reach(chunks, dk))
    spec.family = _family(spec)
    return spec


def _lobe_reach(chunks, dk: float) -> int:
    """Grid steps to a line's neighbours one and a half over the chunk length away (see :func:`_family`)."""
    length = float(np.median([np.ptp(th) for th, _, _ in chunks]))
    return int(math.ceil(1.5 / max(length, 1e-12) / dk))


def _line_pvalues(spec: _LineSpectrum) -> np.ndarray:
    """Per-frequency p-value of the calibrated T^2 under "no line" (F(2, 2(n-1)), 1 where too few chunks)."""
    n = spec.count
    with np.errstate(invalid="ignore"):
        p = np.where(n >= 3, stats.f.sf(spec.t2, 2, 2 * np.maximum(n - 1, 1)), 1.0)
    return np.clip(np.nan_to_num(p, nan=1.0), 1e-300, 1.0)


def _window_logp(log_p: np.ndarray, half: int) -> np.ndarray:
    """Best log p within +-half grid points, corrected for the window's ~(2 half + 1) / 4 independent cells."""
    best = -maximum_filter1d(-log_p, size=2 * half + 1, mode="nearest")
    cells = max(1.0, (2 * half + 1) / 4.0)
    with np.errstate(divide="ignore"):
        corrected = np.log(-np.expm1(cells * np.log1p(-np.exp(np.minimum(best, -1e-12)))))
    return np.maximum(corrected, best)


def _lines_logp(spec: "_LineSpectrum", log_p: np.ndarray, ks: list[float], hs: list[int]) -> float:
    """Fisher log p-value of the lines at spatial frequencies ``ks`` (harmonic numbers ``hs`` set their
    windows); 0 when none lies in the band."""
    total, dof = 0.0, 0
    for kk, h in zip(ks, hs):
        i = int(round((kk - spec.k[0]) / spec.dk))
        if 0 <= i < len(spec.k):
            total += -2.0 * float(_window_logp(log_p[max(0, i - 4):i + 5], 1 + h // 2)[min(i, 4)])
            dof += 2
    return float(stats.chi2.logsf(total, dof)) if dof else 0.0


def _peak_power(spec: "_LineSpectrum", kk: float, half: int) -> float:
    """Largest power of the mean coefficient within +-half grid points of ``kk``."""
    i = int(round((kk - spec.k[0]) / spec.dk))
    lo, hi = max(0, i - half), min(len(spec.k), i + half + 1)
    return float(spec.power[lo:hi].max()) if lo < hi else 0.0


def _family(spec: "_LineSpectrum") -> "_Family":
    """The most significant harmonic family of the spectrum.

    Harmonic summation: for each candidate fundamental k0 the lines at h k0 (h = 1 ..
    FAMILY_HARMONICS, inside the band) are combined by Fisher's method, each line's p-value the
    best within the harmonic's uncertainty (h k0 is known to about h/2 grid steps) and corrected
    for that window. A fundamental weaker than its harmonics, or absent, still collects them. Lines
    are measured at the exact motor positions, so a harmonic above a pass's Nyquist limit is
    unfolded by the pass's own speed, and its mirror images form no family.

    A family and its subharmonic k0/m can collect the same lines; so the fundamental is then moved
    up to m k0 (m = 2, 3, 5) while the lines that only k0 explains are not jointly significant, and
    down to k0 / m when the lines that only k0 / m explains are (Fisher p below 1e-3 both ways) and
    carry at least MIN_SUBHARMONIC_POWER of the family's strongest line; a weaker significant
    subharmonic family is kept as a note (a once-per-motor-revolution effect, for example).
    """
    k, dk = spec.k, spec.dk
    log_p = np.log(_line_pvalues(spec))
    # Only local peaks count as lines: a strong line is consistent across chunks on its flanks too (its
    # T^2 is broad), and a family of flank points would otherwise beat it. Nor does a peak whose
    # power is below 1e-3 of the strongest (the taper's sidelobes are at 7e-4).
    peak = log_p <= -maximum_filter1d(-log_p, size=5, mode="nearest")
    peak &= spec.power >= 1e-3 * spec.power[int(np.argmin(log_p))]
    log_p = np.where(peak, log_p, 0.0)
    n_k = len(k)
    k_lo = k[0]
    score = np.zeros(n_k)
    dof = np.zeros(n_k)
    for h in range(1, FAMILY_HARMONICS + 1):
        idx = np.round((h * k - k_lo) / dk).astype(int)
        inside = idx < n_k
        if not inside.any():
            break
        lp = _window_logp(log_p, 1 + h // 2)
        score[inside] += -2.0 * lp[idx[inside]]
        dof[inside] += 2.0
    fam_logp = stats.chi2.logsf(score, np.maximum(dof, 2.0))
    j0 = int(np.argmin(fam_logp))
    alpha = math.log(1e-3)

    def strongest(kk: float) -> float:
        return max(_peak_power(spec, h * kk, 1 + h // 2) for h in range(1, FAMILY_HARMONICS + 1)
                   if h * kk <= k[-1])

    # A line's chunk coefficients are phase-aligned one over the chunk length from it too (the Hann
    # taper's first neighbours, at half its amplitude). On a clean line, whose spread between chunks is
    # its own, T^2 cannot tell these neighbours from the line: of fundamentals there about as significant
    # (half the log p-value or more), the one whose lines carry the most power is the line.
    if spec.lobe_reach:
        lo, hi = max(0, j0 - spec.lobe_reach), min(n_k, j0 + spec.lobe_reach + 1)
        near = [j for j in range(lo, hi) if fam_logp[j] <= 0.5 * fam_logp[j0] < 0]
        if len(near) > 1:
            j0 = max(near, key=lambda j: strongest(float(k[j])))
    k0 = float(k[j0])

    def own_lines(kk: float, m: int) -> tuple[bool, float]:
        """Whether the lines of kk that m kk does not explain are significant, and their largest power."""
        own = [h for h in range(1, m * FAMILY_HARMONICS + 1) if h % m and h * kk <= k[-1]][:FAMILY_HARMONICS]
        if not own:
            return False, 0.0
        significant = _lines_logp(spec, log_p, [h * kk for h in own], own) < alpha
        return significant, max(_peak_power(spec, h * kk, 1 + h // 2) for h in own)

    def peaks(kk: float, h_last: int):
        """(h, window half-width, index of the best line) for the harmonics of kk inside the band."""
        for h in range(1, h_last + 1):
            i = int(round((h * kk - k_lo) / dk))
            if i >= n_k:
                return
            half = 1 + h // 2
            lo = max(0, i - half)
            yield h, half, lo + int(np.argmin(log_p[lo:i + half + 1]))

    def recentre(kk: float) -> float:
        """kk moved onto its family's most significant line (divided by its harmonic number): a
        fundamental on the grid is off by up to half a step, and its multiples by h times that."""
        best_lp, best_k = 0.0, kk
        for h, _, j in peaks(kk, FAMILY_HARMONICS):
            if log_p[j] < best_lp:
                best_lp, best_k = float(log_p[j]), float(k[j]) / h
        return best_k

    k0 = recentre(k0)
    # Up while k0's own lines are not significant or carry less than MIN_SUBHARMONIC_POWER of the
    # family's strongest line, then down once where a subharmonic's own lines are and do.
    weak_sub = None
    moved = True
    while moved:
        moved = False
        for m in (2, 3, 5):
            if m * k0 > k[-1]:
                continue
            significant, power = own_lines(k0, m)
            if not significant or power < MIN_SUBHARMONIC_POWER * strongest(m * k0):
                if significant:
                    weak_sub = (k0, power / strongest(m * k0))
                k0, moved = recentre(m * k0), True
                break
    for m in (2, 3):
        kk = k0 / m
        if kk < k_lo:
            continue
        significant, power = own_lines(kk, m)
        if significant:
            if power >= MIN_SUBHARMONIC_POWER * strongest(k0):
                k0, weak_sub = recentre(kk), None
                break
            weak_sub = (kk, power / strongest(k0))
    # The family's most significant line among its first 8 harmonics: where the period is best located.
    h_strong, i_strong = 1, int(np.clip(round((k0 - k_lo) / dk), 0, n_k - 1))
    for h, _, j in peaks(k0, 8):
        if h == 1 or log_p[j] < log_p[i_strong]:
            h_strong, i_strong = h, j
    return _Family(h_strong, i_strong, float(np.min(fam_logp)), weak_sub)


@dataclass
class _Family:
    """A harmonic family found by :func:`_family` (indices into the spectrum's grid)."""

    h_strong: int
    i_strong: int
    log_p: float
    #: A significant subharmonic family too weak to be the period: (spatial frequency, power share).
    weak_subharmonic: tuple[float, float] | None = None

    def bracket(self, k: np.ndarray, dk: float) -> tuple[float, float]:
        """Centre and half-width [cycles/rad] of the fundamental's refinement: the strongest line, located
        to about a grid step, divided by its harmonic number."""
        return float(k[self.i_strong] / self.h_strong), 1.5 * dk / self.h_strong


@dataclass
class _Candidate:
    """One deflection estimate (a choice of link motion) with its line and refined period."""

    name: str
    passes: list[Pass]
    spectrum: _LineSpectrum
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
        k_star, half = fam.bracket(k, dk)
        # At least up to the strongest line: an unmodelled harmonic above a pass's Nyquist limit leaves
        # its mirror image next to a modelled one and pulls the period.
        harmonics = max(harmonics, fam.h_strong)
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


def _beyond_range(datasets: list[Dataset], c: _Candidate, K: float, Jl: float, period_max: float, min_speed: float,
                  min_travel: float, false_alarm: float) -> str:
    """Why ``c``'s line is a harmonic of a period beyond ``period_max`` ('' when it is not).

    The passes were high-passed for the searched range, which takes such a fundamental out: they are
    made again for periods up to three times the line's, and the line's halves and thirds tested with
    the same law (four tries, at least a tenth of the line's power), T^2 calibrated by its median over
    the neighbouring frequencies as in the search.
    """
    passes: list[Pass] = []
    for i, ds in enumerate(datasets):
        passes += deflection(ds, i, K, Jl, 3.0 * c.period, min_speed, min_travel, link_motion=c.link_motion)
    if not passes:
        return ""
    span = max(p.theta.max() for p in passes) - min(p.theta.min() for p in passes)
    chunks = _chunks(passes, span)
    dk = 1.0 / (4.0 * span)
    k_line = 1.0 / c.period
    _, power_line, _ = _hotelling(chunks, np.array([k_line]))
    for m in (2, 3):
        kk = k_line / m
        if 1.0 / kk <= period_max or 1.0 / kk > max(p.period_max for p in passes):
            continue
        grid = kk + dk * np.arange(-25, 26)
        t2, power, count = _hotelling(chunks, grid[grid > 0])
        centre = int(np.argmin(np.abs(grid[grid > 0] - kk)))
        floor = float(np.median(t2))
        t2_c = float(t2[centre]) * min(1.0, math.log(2.0) / max(floor, 1e-300))
        if _false_alarm(t2_c, int(count[centre]), 4.0) < false_alarm and power[centre] >= 0.1 * power_line[0]:
            return (f"the line at {c.period:.4g} rad looks like harmonic {m} of a period of {1 / kk:.4g} rad, "
                    f"longer than the longest searched ({period_max:.4g} rad): not a detection; widen "
                    "--period-max")
    return ""


def identify_ripple(datasets: list[Dataset], K: float = 18500.0, Jl: float = 5.6,
                    period_min: float = PERIOD_MIN_RAD, period_max: float = PERIOD_MAX_RAD, bins: int = 256,
                    max_harmonics: int = 8, min_speed: float = 0.003, false_alarm: float = 1e-3,
                    link_motion: str = "auto") -> RippleResult:
    """Decide whether a position-periodic deflection exists; find its period and lookup table.

    All runs are used together for the detection, the period and the table. With several runs each is
    also analysed alone: the result lists the per-run estimates (``runs``) and their agreement
    (``agreement``): a run agrees when its period is a harmonic of the pooled one (1/h of it) within
    three combined std and 0.1 %; the pooled period's std is at least the spread of the runs'
    fundamentals (their weighted mean's std times the Birge ratio sqrt(chi2 / dof)) and half the
    distance between that mean and the pooled period. When a run that
    detects a line disagrees, the data do not decide and nothing is reported as detected; the verdict
    names the runs.

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

    Returns
    -------
    RippleResult

    Raises
    ------
    IiwaIdentError
        When no usable motion is found (too short, too slow, standing still).
    """
    options = dict(K=K, Jl=Jl, period_min=period_min, period_max=period_max, bins=bins, max_harmonics=max_harmonics,
                   min_speed=min_speed, false_alarm=false_alarm, link_motion=link_motion)
    pooled = _identify_pooled(datasets, **options)
    if len(datasets) < 2:
        beyond = _beyond_nyquist(pooled, datasets[0], _median_speed(datasets[0])) if datasets else None
        if beyond:
            pooled.warnings.append(f"{beyond}: an alias is possible; runs at other speeds would decide")
        return pooled
    runs = []
    for i, ds in enumerate(datasets):
        name = str(ds.path) if ds.path else f"run {i + 1}"
        speed = _median_speed(ds)
        try:
            r = _identify_pooled([ds], **options)
        except IiwaIdentError as err:
            runs.append({"run": name, "speed_rad_s": speed, "detected": False, "usable": False, "reason": str(err)})
            continue
        # The spatial Nyquist limit at this run's speed: lines beyond it are aliases.
        nyquist_cpr = math.pi * ds.sample_rate_hz / max(speed, 1e-9)
        row = {"run": name, "speed_rad_s": speed, "detected": r.detected, "usable": True,
               "period_rad": r.period_rad, "period_std_rad": r.period_std_rad,
               "cycles_per_rev": r.cycles_per_rev, "false_alarm_probability": r.false_alarm,
               "amplitude_rad": r.amplitude_rad, "warnings": r.warnings, "link_motion": r.link_motion,
               "nyquist_cycles_per_rev": nyquist_cpr}
        beyond = _beyond_nyquist(r, ds, speed)
        if beyond and r.cycles_per_rev > nyquist_cpr:
            row.update(detected=False, reason=f"{beyond}: an alias; this run does not decide the period")
        elif beyond:
            # The fundamental's own line is below the limit: the run votes, and says what its estimate rests on.
            row["note"] = f"{beyond}: its period rests mostly on that line, where an alias is possible"
        runs.append(row)
    return _combine_runs(pooled, runs, datasets, options)


def _median_speed(ds: Dataset) -> float:
    """The run's median speed [rad/s]."""
    return float(np.median(np.abs(np.diff(ds["q_m"]) / np.diff(_spread_repeated_stamps(ds["t"])))))


def _beyond_nyquist(r: RippleResult, ds: Dataset, speed: float) -> str:
    """Why a detected family may be an alias, or '': the family's strongest line (of its table) lies beyond
    the spatial Nyquist limit at the run's median ``speed`` [rad/s], pi x rate / speed cycles per revolution."""
    if not r.detected or r.lut is None:
        return ""
    nyquist = math.pi * ds.sample_rate_hz / max(speed, 1e-9)
    h = int(np.argmax(np.abs(np.fft.rfft(r.lut))[1:FAMILY_HARMONICS + 4])) + 1
    line = h * r.cycles_per_rev
    if line <= nyquist:
        return ""
    which = "its line" if h == 1 else f"its strongest line, harmonic {h} of {r.cycles_per_rev:.1f},"
    return (f"{which} at {line:.1f} cycles per revolution lies beyond the Nyquist limit at its median speed "
            f"{speed:.2f} rad/s ({nyquist:.0f} cycles per revolution at {ds.sample_rate_hz:.0f} Hz)")


def _combine_runs(pooled: RippleResult, runs: list[dict], datasets: list[Dataset] | None = None,
                  options: dict | None = None) -> RippleResult:
    """Attach the per-run estimates to the pooled result, test their agreement and widen its std; where they
    disagree, the family reproduced at several speeds decides (:func:`_reproduced`)."""
    detected = [r for r in runs if r["detected"]]
    pooled.warnings += [f"{r['run']}: {r['note']}" for r in runs if r.get("note")]
    # verdict: "agree", "disagree" (the data do not decide) or "none" (no run detects anything).
    agreement: dict = {"runs": len(runs), "detected": len(detected), "agree": [], "disagree": [],
                       "chi2": None, "dof": None, "p_value": None, "birge_ratio": None}
    pooled.runs, pooled.agreement = runs, agreement
    if not detected:
        agreement["verdict"] = "none"
        return pooled
    if not pooled.detected:
        if datasets is not None and (found := _reproduced(pooled, runs, datasets, options)) is not None:
            return found
        agreement["verdict"] = "disagree"
        agreement["disagree"] = [r["run"] for r in detected]
        pooled.warnings.append("the runs disagree: " + "; ".join(
            f"{r['run']} alone gives {r['cycles_per_rev']:.1f} cycles per revolution" for r in detected)
            + (f"; {len(runs) - len(detected)} of {len(runs)} detect nothing" if len(detected) < len(runs) else "")
            + "; together they detect nothing: the data do not decide")
        return pooled
    k0, s0 = 1.0 / pooled.period_rad, pooled.period_std_rad / pooled.period_rad ** 2
    fund, weights = [], []
    for r in detected:
        k, sk = 1.0 / r["period_rad"], r["period_std_rad"] / r["period_rad"] ** 2
        h = max(1, int(round(k / k0)))
        tol = 3.0 * math.hypot(sk, h * s0) + 1e-3 * k
        if abs(k - h * k0) <= tol:
            r["harmonic"] = h
            agreement["agree"].append(r["run"])
            fund.append(k / h)
            weights.append((h / max(sk, 1e-12 * k)) ** 2)
        else:
            agreement["disagree"].append(r["run"])
    if agreement["disagree"]:
        if datasets is not None and (found := _reproduced(pooled, runs, datasets, options)) is not None:
            return found
        pooled.detected = False
        pooled.warnings.append("the runs disagree: " + "; ".join(
            f"{r['run']} gives {r['cycles_per_rev']:.1f} cycles per revolution" for r in detected)
            + f"; together they give {pooled.cycles_per_rev:.1f}: the data do not decide, nothing is reported")
        agreement["verdict"] = "disagree"
        return pooled
    # Runs that agree as harmonics of the pooled period may still see that period's own line at one speed only
    # (a 160-cycle family at 0.4 rad/s, 320 elsewhere): then the line reproduced at several speeds decides.
    if datasets is not None and _speeds([(r, 1) for r in detected]) >= 2 \
            and _speeds(_support(pooled.period_rad, pooled.period_std_rad, detected)) < 2:
        found = _reproduced(pooled, runs, datasets, options)
        if found is not None:
            return found
    agreement["verdict"] = "agree"
    if len(fund) >= 2:
        fund, weights = np.asarray(fund), np.asarray(weights)
        mean = float(np.sum(weights * fund) / np.sum(weights))
        chi2 = float(np.sum(weights * (fund - mean) ** 2))
        dof = len(fund) - 1
        birge = math.sqrt(max(1.0, chi2 / dof))
        spread_std = birge / math.sqrt(float(np.sum(weights)))
        agreement.update(chi2=chi2, dof=dof, p_value=float(stats.chi2.sf(chi2, dof)), birge_ratio=birge)
        std_k = max(s0, spread_std, abs(mean - k0) / 2.0)
        pooled.period_std_rad = std_k / k0 ** 2
    return pooled


#: Runs whose speeds differ by less than this ratio count as one speed for the reproducibility test.
SAME_SPEED_RATIO = 1.1
#: A run's line supports a period when it is its h-th harmonic within this many combined std and ...
_SUPPORT_STD = 3.0
#: ... this relative tolerance (the runs' periods scatter by a few 0.1 % on real joints).
_SUPPORT_RTOL = 3e-3


def _support(period: float, period_std: float, detected: list[dict]) -> list[tuple[dict, int]]:
    """The runs whose line family contains the period's line, with its harmonic number in each."""
    c0, s0 = 2 * math.pi / period, 2 * math.pi * period_std / period ** 2
    out = []
    for r in detected:
        h = int(round(c0 / r["cycles_per_rev"]))
        if not 1 <= h <= FAMILY_HARMONICS:
            continue
        sc = 2 * math.pi * r["period_std_rad"] / r["period_rad"] ** 2
        if abs(c0 - h * r["cycles_per_rev"]) <= _SUPPORT_STD * math.hypot(h * sc, s0) + _SUPPORT_RTOL * c0:
            out.append((r, h))
    return out


def _speeds(support: list[tuple[dict, int]]) -> int:
    """How many different speeds (apart by :data:`SAME_SPEED_RATIO`) the supporting runs have."""
    speeds = sorted(r["speed_rad_s"] for r, _ in support)
    return sum(1 for a, b in zip(speeds, speeds[1:]) if b > SAME_SPEED_RATIO * a) + 1 if speeds else 0


def _reproduced(pooled: RippleResult, runs: list[dict], datasets: list[Dataset], options: dict) -> RippleResult | None:
    """The compensation period when the runs disagree: the family reproduced at different speeds.

    A run supports the period ``c`` (cycles per revolution) when ``c`` is a harmonic ``h`` (1 to
    :data:`FAMILY_HARMONICS`) of the run's own fundamental: a run whose strongest family is a subharmonic
    (160 cycles where the others see 320) still shows ``c`` as its second harmonic. Only a line seen in runs
    at two speeds or more (differing by :data:`SAME_SPEED_RATIO`) is phase-locked to the motor position,
    since its frequency in Hz differs between them; of such candidates (each run's fundamental), the one
    with the most supporting runs is the compensation period, its value the supporters' weighted mean (std
    widened by the Birge ratio), its table fitted on their passes. The other runs' lines are reported with
    their run, frequency and amplitude as seen at one speed only (spatial or temporal: not decided). None
    when no line is reproduced.
    """
    detected = [r for r in runs if r["detected"]]
    one_run: list[dict] = []
    best = None
    for cand in detected:
        support = _support(cand["period_rad"], cand["period_std_rad"], detected)
        if _speeds(support) >= 2 and (best is None or len(support) > len(best[1])):
            best = (cand, support)
    if best is None:
        return None
    _, support = best
    c = np.array([h * r["cycles_per_rev"] for r, h in support])
    sc = np.array([h * 2 * math.pi * r["period_std_rad"] / r["period_rad"] ** 2 for r, h in support])
    w = 1.0 / np.maximum(sc, 1e-9 * c) ** 2
    mean = float(np.sum(w * c) / np.sum(w))
    chi2 = float(np.sum(w * (c - mean) ** 2))
    dof = max(len(c) - 1, 1)
    std = math.sqrt(max(1.0, chi2 / dof)) / math.sqrt(float(np.sum(w)))
    period = 2 * math.pi / mean
    period_std = 2 * math.pi * std / mean ** 2
    names = [r["run"] for r, _ in support]
    used = [ds for ds, r in zip(datasets, runs) if r["run"] in names]
    motion = max((r.get("link_motion") or "restored" for r, _ in support),
                 key=lambda m: sum((r.get("link_motion") or "restored") == m for r, _ in support))
    o = options
    passes: list[Pass] = []
    for i, ds in enumerate(used):
        passes += deflection(ds, i, o["K"], o["Jl"], o["period_max"], o["min_speed"],
                             min_travel=4.0 * o["period_min"], link_motion=motion)
    combined = _method_result("combined", passes, period, o["max_harmonics"], o["bins"])
    methods = {"dynamic": combined} if any(p.method == "dynamic" for p in passes) else {"static": combined}
    fap = float(max(r["false_alarm_probability"] for r, _ in support))
    for r in runs:
        if r["run"] in names:
            h = r["harmonic"] = next(h for rr, h in support if rr is r)
            if h > 1 and _speeds(_support(r["period_rad"], r["period_std_rad"], detected)) < 2:
                # The run's strongest family is a subharmonic of the period, seen at this speed only.
                f_hz = r["speed_rad_s"] * r["cycles_per_rev"] / (2 * math.pi)
                one_run.append({"run": r["run"], "cycles_per_rev": r["cycles_per_rev"],
                                "speed_rad_s": r["speed_rad_s"], "frequency_hz": f_hz,
                                "amplitude_rad": r["amplitude_rad"], "subharmonic": h,
                                "note": f"1/{h} of the period's cycles, seen at this speed only: spatial or "
                                        "temporal, not decided by this data"})
            continue
        if r["detected"]:
            f_hz = r["speed_rad_s"] * r["cycles_per_rev"] / (2 * math.pi)
            one_run.append({"run": r["run"], "cycles_per_rev": r["cycles_per_rev"], "speed_rad_s": r["speed_rad_s"],
                            "frequency_hz": f_hz, "amplitude_rad": r["amplitude_rad"],
                            "note": "seen at this speed only: spatial or temporal, not decided by this data"})
    warnings = [w for w in pooled.warnings if "disagree" not in w]
    for x in one_run:
        sub = f" (1/{x['subharmonic']} of the period's)" if "subharmonic" in x else ""
        warnings.append(f"{x['run']} alone shows a line at {x['cycles_per_rev']:.1f} cycles per revolution{sub} "
                        f"({x['frequency_hz']:.1f} Hz at {x['speed_rad_s']:.2f} rad/s, "
                        f"{1e6 * (x['amplitude_rad'] or 0):.1f} µrad), seen at this speed only: spatial or temporal, "
                        "not decided by this data; it does not set the period")
    for r in runs:
        if r.get("reason") and r.get("usable", True):
            warnings.append(f"{r['run']}: {r['reason']}")
    agreement = dict(pooled.agreement, verdict="reproduced", agree=names,
                     disagree=[x["run"] for x in one_run if "subharmonic" not in x], one_run_lines=one_run,
                     supporting_speeds_rad_s=sorted(r["speed_rad_s"] for r, _ in support),
                     chi2=chi2 if len(c) > 1 else None, dof=dof if len(c) > 1 else None,
                     p_value=float(stats.chi2.sf(chi2, dof)) if len(c) > 1 else None,
                     birge_ratio=math.sqrt(max(1.0, chi2 / dof)) if len(c) > 1 else None)
    return RippleResult(True, period, period_std, fap, pooled.statistic, combined.lut, combined.amplitude_rad,
                        methods, pooled.spectrum_k, pooled.spectrum_stat, pooled.spectrum_power,
                        _velocity_table(passes, period), passes, warnings, pooled.K, pooled.Jl, motion,
                        runs=runs, agreement=agreement)


def _identify_pooled(datasets: list[Dataset], K: float, Jl: float, period_min: float, period_max: float, bins: int,
                     max_harmonics: int, min_speed: float, false_alarm: float, link_motion: str) -> RippleResult:
    """identify_ripple on all runs together, without the per-run analysis."""
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
    # estimates are tried, and the one whose period is the more reproducible across passes (smaller
    # jackknife error) is kept.
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
        candidates.append(_Candidate(name, passes, _line_search(passes, period_min, period_max),
                                     link_motion=motion))
        if not dynamic:
            break  # static passes only: the link is measured, nothing to choose
    for c in candidates:
        if c.spectrum.detection_false_alarm(len(candidates)) <= false_alarm:
            c.refine(max_harmonics)
    for c in candidates:
        if c.period is not None and 2.0 * c.period > period_max:
            beyond = _beyond_range(datasets, c, K, Jl, period_max, min_speed, 4.0 * period_min, false_alarm)
            if beyond:
                c.period, c.not_decided = None, beyond
    detected = [c for c in candidates if c.period is not None]
    best = min(detected, key=lambda c: c.period_std / c.period) if detected else \
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
    base = dict(spectrum_k=spec.k, spectrum_stat=spec.t2, spectrum_power=spec.power, passes=passes,
                warnings=warnings, K=K, Jl=Jl, link_motion=best.name)
    if best.period is None:
        return RippleResult(False, None, None, fap, stat, None, None, {}, velocity_table=[], **base)
    period, period_std = best.period, best.period_std

    methods = {}
    by_method = {m: [p for p in passes if p.method == m] for m in ("static", "dynamic")}
    for name, ps in by_method.items():
        if ps:
            methods[name] = _method_result(name, ps, period, max_harmonics, bins)
    if len(methods) == 2:
        # The static table is measured directly: align the dynamic one to it and record the shift.
        shift = _circular_shift(methods["static"].lut, methods["dynamic"].lut)
        if shift > bins // 2:
            shift -= bins
        methods["dynamic"].shift_rad = shift * period / bins
        methods["dynamic"].lut = np.roll(methods["dynamic"].lut, shift)
    # The table written to the model uses every pass, weighted by its noise.
    combined = _method_result("combined", passes, period, max_harmonics, bins)
    lut = combined.lut

    velocity_table = _velocity_table(passes, period)
    return RippleResult(True, period, period_std, fap, stat, lut, combined.amplitude_rad, methods,
                        velocity_table=velocity_table, **base)


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
        rows.append({"speed_rad_s": speed, "predicted_hz": f_pred, "measured_hz": best[1], "passes": len(ps)})
    return rows
