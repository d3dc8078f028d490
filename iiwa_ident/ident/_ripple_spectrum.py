"""The ripple search's spectrum: Hotelling's T^2 of the passes' chunks and the harmonic families in it.

Passes are cut into chunks; at each spatial frequency the chunks' tapered
Fourier coefficients of the deflection are tested for a common phase-locked
component (Hotelling's T^2, an F(2, 2(n-1)) law under "no line", calibrated
on the data's floor). :func:`line_search` gives the spectrum with its most
significant harmonic family (:func:`family`), from which
:mod:`iiwa_ident.ident._ripple` refines the period.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy import stats
from scipy.ndimage import maximum_filter1d, median_filter

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._ripple_passes import Pass

__all__ = ['FAMILY_HARMONICS', 'MIN_SUBHARMONIC_POWER', 'SEARCH_TRIES_PER_POINT', 'Chunk', 'Family', 'LineSpectrum', 'chunk_coefficients', 'chunks_in', 'cut_chunks', 'false_alarm_probability', 'harmonic_family', 'hotelling', 'line_pvalues', 'line_search', 'lines_logp', 'lobe_reach', 'peak_power', 'sidak', 'taper', 'window_logp']

#: Harmonics summed per candidate fundamental in the family search.
FAMILY_HARMONICS = 5
#: Least power, as a share of the family's strongest line, of the strongest line that only a subharmonic
#: k0/m explains, for k0/m to be the period: lines down to a tenth of the dominant one's amplitude.
MIN_SUBHARMONIC_POWER = 0.01
#: Log of the Fisher p-value below which a family's own lines are significant.
_ALPHA = math.log(1e-3)
#: Strongest grid points of the search whose T^2 is re-read between grid points.
_REFINED = 32
#: Independent tries the search counts per grid point (4 per resolution cell 1/span).
SEARCH_TRIES_PER_POINT = 1.0


class Chunk(NamedTuple):
    """A piece of a pass: it speaks only for spatial frequencies above ``k_min`` = 1 / (its pass's longest
    period) [cycles/rad]."""

    theta: np.ndarray  # motor angle [rad]
    f: np.ndarray  # deflection [rad]
    k_min: float


def cut_chunks(passes: list[Pass], span: float) -> list[Chunk]:
    """Cut passes into chunks of at least two of their longest periods (about span / 8)."""
    out = []
    for p in passes:
        n = chunks_in(abs(p.theta[-1] - p.theta[0]), p.period_max, span)
        for idx in np.array_split(np.arange(len(p.theta)), n):
            if len(idx) >= 8:
                out.append(Chunk(p.theta[idx], p.f[idx], 1.0 / p.period_max))
    return out


def chunks_in(travel: float, period_max: float, span: float) -> int:
    """Chunks a pass of ``travel`` [rad] is cut into: each at least two of its longest periods
    ``period_max`` [rad] and about an eighth of the runs' ``span`` [rad]."""
    return max(1, int(travel // max(2.0 * period_max, span / 8)))


def chunk_coefficients(chunks: list[Chunk], k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
        w = taper(len(f))
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


class Hotelling(NamedTuple):
    """Hotelling's T^2 per spatial frequency, the mean coefficient's power and the chunks counted."""

    t2: np.ndarray
    power: np.ndarray
    chunks: np.ndarray


def hotelling(chunks: list[Chunk], k: np.ndarray) -> Hotelling:
    """Hotelling T^2 of the chunks' Fourier coefficients at ``k`` [cycles/rad].

    Returns T^2, the power of the mean coefficient, and the number of chunks
    that speak for each k (chunks of short passes are left out at long periods).
    """
    coefs, valid = chunk_coefficients(chunks, k)
    count = valid.sum(axis=0)
    n = np.maximum(count, 1)
    mean = coefs.sum(axis=0) / n
    spread = np.where(valid, np.abs(coefs - mean) ** 2, 0.0).sum(axis=0)
    var = spread / np.maximum(count - 1, 1) / n
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = np.where(count >= 3, np.abs(mean) ** 2 / var, 0.0)
    return Hotelling(np.nan_to_num(t2, nan=0.0, posinf=0.0), np.abs(mean) ** 2, count)


@functools.lru_cache(maxsize=256)
def taper(n: int) -> np.ndarray:
    """Hann window of n samples without its zero end points (read-only: one array per length, shared)."""
    w = np.hanning(n + 2)[1:-1]
    w.flags.writeable = False
    return w


def false_alarm_probability(t2: float, n: int, m_eff: float) -> float:
    """Probability that noise alone gives a maximum statistic this large among m_eff frequencies.

    With n chunks of independent circular noise, T^2 = |mean|^2 / (s^2 / n) follows F(2, 2(n-1)).
    """
    p = float(stats.f.sf(t2, 2, 2 * (n - 1))) if n > 1 else 1.0
    return sidak(p, m_eff)


def sidak(p: float, tries: float) -> float:
    """Probability that the smallest of ``tries`` independent p-values is at most ``p``: 1 - (1 - p)^tries."""
    return float(min(1.0, -math.expm1(tries * math.log1p(-min(p, 1 - 1e-16)))))


@dataclass(kw_only=True)
class LineSpectrum:
    """Hotelling spectrum of a set of passes over the searched spatial frequencies."""

    k: np.ndarray
    t2: np.ndarray
    power: np.ndarray
    count: np.ndarray
    dk: float
    i_best: int
    warnings: list[str]
    #: The most significant harmonic family (see :func:`harmonic_family`).
    family: Family | None = None
    #: Grid steps to one and a half over the chunk length (:func:`lobe_reach`).
    lobe_reach: int = 0

    @property
    def tries(self) -> float:
        """Independent frequencies the search stands for: its grid points, 4 per resolution cell (a line's T^2
        is read between them too, and the maximum of a continuous search exceeds that of one point a cell)."""
        return SEARCH_TRIES_PER_POINT * len(self.k)

    def false_alarm(self, j: int, tries: float | None = None) -> float:
        """False-alarm probability of the line at index j among ``tries`` frequencies (default: all searched)."""
        return false_alarm_probability(float(self.t2[j]), int(self.count[j]), self.tries if tries is None else tries)

    def detection_false_alarm(self, estimates: int = 1) -> float:
        """False-alarm probability of the search: the strongest line or the strongest family, whichever is
        the more significant, each corrected for the frequencies searched, then (Bonferroni) for the two
        tests and for the ``estimates`` deflection estimates the strongest is chosen from."""
        tries = self.tries
        p_fam = math.exp(self.family.log_p) if self.family is not None else 1.0
        fam = sidak(p_fam, tries) if p_fam > 0 else 0.0
        return min(1.0, 2.0 * estimates * min(self.false_alarm(self.i_best), fam))


def line_search(passes: list[Pass], period_min: float, period_max: float) -> LineSpectrum:
    warnings = []
    # A period is told from a slow trend only within a pass that travels two of them.
    longest = max(p.period_max for p in passes)
    if longest < period_max:
        warnings.append(f"the longest pass travels {2 * longest:.3g} rad: periods searched up to {longest:.3g} rad")
        period_max = longest
    # Sampled at even steps of the motor position, a pass cannot tell a line from its aliases about multiples
    # of its sampling frequency in position; passes at other speeds alias elsewhere and can. Periods shorter
    # than two steps of the finest-sampled pass are not searched (a 310-cycle line of one 1 rad/s run at
    # 200 Hz was reported at its alias 1567).
    nyquist = max(0.5 / max(float(np.median(np.abs(np.diff(p.theta)))), 1e-12) for p in passes)
    if 1.0 / nyquist > period_min:
        period_min = 1.0 / nyquist
        warnings.append(f"at these speeds and rates the motor position is sampled every {0.5 / nyquist:.3g} rad: "
                        f"periods searched down to {period_min:.3g} rad ({2 * math.pi * nyquist:.0f} cycles per "
                        "revolution); shorter ones alias, runs slower or at a higher rate would resolve them")
        if period_min >= period_max:
            raise IiwaIdentError(f"ripple: the runs are sampled too coarsely in position (every {0.5 / nyquist:.3g} "
                                 f"rad) for the periods searched (up to {period_max:.3g} rad); run slower or at a "
                                 "higher rate")
    span = max(p.theta.max() for p in passes) - min(p.theta.min() for p in passes)
    chunks = cut_chunks(passes, span)
    if len(chunks) < 3:
        raise IiwaIdentError(f"ripple: too little motion: {len(chunks)} usable stretches (need 3 or more); "
                             "record longer runs, both directions or more speeds")
    # Spatial frequency grid: 4 points per resolution cell 1/span.
    dk = 1.0 / (4.0 * span)
    k = np.arange(1.0 / period_max, 1.0 / period_min + dk, dk)
    t2_raw, power, count = hotelling(chunks, k)
    # A strong line's T^2 is narrower than the grid (off its frequency the chunks' phases drift apart, and the
    # spread between them is the signal's): the grid point next to it can hold a quarter of its value. The
    # strongest points are re-read at their maximum within half a grid step.
    for j in np.argsort(t2_raw)[-_REFINED:]:
        fine = k[j] + dk * np.linspace(-0.5, 0.5, 9)
        t2_raw[j] = max(t2_raw[j], float(np.max(hotelling(chunks, fine)[0])))
    # Real logs have noise that is correlated between neighbouring chunks (slow oscillations,
    # gravity and friction leftovers), which lifts the whole T^2 floor above its F(2, 2(n-1))
    # law. Calibrate with the local median (ln 2 under that law), never making a line more
    # significant than the law says.
    reach = lobe_reach(chunks, dk)
    floor = median_filter(t2_raw, size=max(51, len(k) // 10) | 1, mode="nearest")
    t2 = t2_raw * np.minimum(1.0, math.log(2.0) / np.maximum(floor, 1e-300))
    spec = LineSpectrum(k=k, t2=t2, power=power, count=count, dk=dk, i_best=int(np.argmax(t2)), warnings=warnings,
                        lobe_reach=reach)
    spec.family = harmonic_family(spec)
    return spec


def lobe_reach(chunks, dk: float) -> int:
    """Grid steps to a line's neighbours one and a half over the chunk length away (see :func:`harmonic_family`)."""
    length = float(np.median([np.ptp(th) for th, _, _ in chunks]))
    return int(math.ceil(1.5 / max(length, 1e-12) / dk))


def line_pvalues(spec: LineSpectrum) -> np.ndarray:
    """Per-frequency p-value of the calibrated T^2 under "no line" (F(2, 2(n-1)), 1 where too few chunks)."""
    n = spec.count
    with np.errstate(invalid="ignore"):
        p = np.where(n >= 3, stats.f.sf(spec.t2, 2, 2 * np.maximum(n - 1, 1)), 1.0)
    return np.clip(np.nan_to_num(p, nan=1.0), 1e-300, 1.0)


def window_logp(log_p: np.ndarray, half: int) -> np.ndarray:
    """Best log p within +-half grid points, corrected for the window's ~(2 half + 1) / 4 independent cells."""
    best = -maximum_filter1d(-log_p, size=2 * half + 1, mode="nearest")
    cells = max(1.0, (2 * half + 1) / 4.0)
    with np.errstate(divide="ignore"):
        corrected = np.log(-np.expm1(cells * np.log1p(-np.exp(np.minimum(best, -1e-12)))))
    return np.maximum(corrected, best)


def lines_logp(spec: LineSpectrum, log_p: np.ndarray, ks: list[float], hs: list[int]) -> float:
    """Fisher log p-value of the lines at spatial frequencies ``ks`` (harmonic numbers ``hs`` set their
    windows); 0 when none lies in the band."""
    total, dof = 0.0, 0
    for kk, h in zip(ks, hs):
        i = int(round((kk - spec.k[0]) / spec.dk))
        if 0 <= i < len(spec.k):
            total += -2.0 * float(window_logp(log_p[max(0, i - 4):i + 5], 1 + h // 2)[min(i, 4)])
            dof += 2
    return float(stats.chi2.logsf(total, dof)) if dof else 0.0


def peak_power(spec: LineSpectrum, kk: float, half: int) -> float:
    """Largest power of the mean coefficient within +-half grid points of ``kk``."""
    i = int(round((kk - spec.k[0]) / spec.dk))
    lo, hi = max(0, i - half), min(len(spec.k), i + half + 1)
    return float(spec.power[lo:hi].max()) if lo < hi else 0.0


def harmonic_family(spec: LineSpectrum) -> Family:
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
    s = _FamilySearch(spec)
    fam_logp = s.summed()
    k0 = s.recentre(s.off_lobe(fam_logp))
    k0, weak_up = s.moved_up(k0)
    k0, weak_sub = s.moved_down(k0, weak_up)
    k0 = s.through_top_line(k0)
    h_strong, i_strong = s.strongest_line(k0)
    return Family(h_strong, i_strong, float(np.min(fam_logp)), weak_sub)


class _FamilySearch:
    """The steps of :func:`harmonic_family` on one spectrum: its lines' log p-values (local peaks only)."""

    def __init__(self, spec: LineSpectrum) -> None:
        self.spec = spec
        self.k, self.dk, self.n_k, self.k_lo = spec.k, spec.dk, len(spec.k), spec.k[0]
        log_p = np.log(line_pvalues(spec))
        # Only local peaks count as lines: a strong line is consistent across chunks on its flanks too (its
        # T^2 is broad), and a family of flank points would otherwise beat it. Nor does a peak whose
        # power is below 1e-3 of the strongest (the taper's sidelobes are at 7e-4).
        peak = log_p <= -maximum_filter1d(-log_p, size=5, mode="nearest")
        peak &= spec.power >= 1e-3 * spec.power[int(np.argmin(log_p))]
        self.log_p = np.where(peak, log_p, 0.0)
        # The same holds for a single line: T^2 at its neighbours one over the chunk length away can exceed
        # its own (a 320-cycle line of a 2 rad run located at 342).
        self.grating = max(1, int(round(spec.lobe_reach / 1.5)))

    def summed(self) -> np.ndarray:
        """Fisher's log p-value of the family of every grid point as a fundamental."""
        k, n_k = self.k, self.n_k
        score = np.zeros(n_k)
        dof = np.zeros(n_k)
        for h in range(1, FAMILY_HARMONICS + 1):
            idx = np.round((h * k - self.k_lo) / self.dk).astype(int)
            inside = idx < n_k
            if not inside.any():
                break
            lp = window_logp(self.log_p, 1 + h // 2)
            score[inside] += -2.0 * lp[idx[inside]]
            dof[inside] += 2.0
        return stats.chi2.logsf(score, np.maximum(dof, 2.0))

    def strongest(self, kk: float) -> float:
        """The largest power among the harmonics of ``kk`` inside the band."""
        return max(peak_power(self.spec, h * kk, 1 + h // 2) for h in range(1, FAMILY_HARMONICS + 1)
                   if h * kk <= self.k[-1])

    def off_lobe(self, fam_logp: np.ndarray) -> float:
        """The most significant fundamental, moved off the taper's first neighbours onto the line.

        A line's chunk coefficients are phase-aligned one over the chunk length from it too (the Hann
        taper's first neighbours, at half its amplitude). On a clean line, whose spread between chunks is
        its own, T^2 cannot tell these neighbours from the line: of fundamentals there about as significant
        (half the log p-value or more), the one whose lines carry the most power is the line.
        """
        j0 = int(np.argmin(fam_logp))
        reach = self.spec.lobe_reach
        if reach:
            lo, hi = max(0, j0 - reach), min(self.n_k, j0 + reach + 1)
            near = [j for j in range(lo, hi) if fam_logp[j] <= 0.5 * fam_logp[j0] < 0]
            if len(near) > 1:
                j0 = max(near, key=lambda j: self.strongest(float(self.k[j])))
        return float(self.k[j0])

    def own_lines(self, kk: float, m: int) -> tuple[bool, float]:
        """Whether the lines of kk that m kk does not explain are significant, and their largest power."""
        own = [h for h in range(1, m * FAMILY_HARMONICS + 1) if h % m and h * kk <= self.k[-1]][:FAMILY_HARMONICS]
        if not own:
            return False, 0.0
        significant = lines_logp(self.spec, self.log_p, [h * kk for h in own], own) < _ALPHA
        return significant, max(peak_power(self.spec, h * kk, 1 + h // 2) for h in own)

    def peaks(self, kk: float, h_last: int) -> Iterator[tuple[int, int]]:
        """(h, index of the best line in its window) for the harmonics of kk inside the band."""
        for h in range(1, h_last + 1):
            i = int(round((h * kk - self.k_lo) / self.dk))
            if i >= self.n_k:
                return
            half = 1 + h // 2
            lo = max(0, i - half)
            yield h, lo + int(np.argmin(self.log_p[lo:i + half + 1]))

    def on_line(self, j: int) -> int:
        """Of the line at ``j`` and its neighbours one over the chunk length away about as significant, the
        one with the most power."""
        log_p, power, g = self.log_p, self.spec.power, self.grating
        best = j
        for m in (-2, -1, 1, 2):
            c = j + m * g
            lo, hi = max(0, c - g // 4 - 1), min(self.n_k, c + g // 4 + 2)
            if lo >= hi:
                continue
            c = lo + int(np.argmin(log_p[lo:hi]))
            if log_p[c] <= 0.5 * log_p[j] < 0 and power[c] > power[best]:
                best = c
        return best

    def recentre(self, kk: float) -> float:
        """kk moved onto its family's most significant line (divided by its harmonic number): a
        fundamental on the grid is off by up to half a step, and its multiples by h times that."""
        best_lp, best_k = 0.0, kk
        for h, j in self.peaks(kk, FAMILY_HARMONICS):
            if self.log_p[j] < best_lp:
                best_lp, best_k = float(self.log_p[j]), float(self.k[j]) / h
        return best_k

    def moved_up(self, k0: float) -> tuple[float, tuple[float, float] | None]:
        """Up to m k0 while k0's own lines are not significant or carry less than MIN_SUBHARMONIC_POWER of
        the family's strongest line; with the last significant but weak subharmonic passed on the way."""
        weak_sub = None
        moved = True
        while moved:
            moved = False
            for m in (2, 3, 5):
                if m * k0 > self.k[-1]:
                    continue
                significant, power = self.own_lines(k0, m)
                if not significant or power < MIN_SUBHARMONIC_POWER * self.strongest(m * k0):
                    if significant:
                        weak_sub = (k0, power / self.strongest(m * k0))
                    k0, moved = self.recentre(m * k0), True
                    break
        return k0, weak_sub

    def moved_down(self, k0: float, weak_sub: tuple[float, float] | None
                   ) -> tuple[float, tuple[float, float] | None]:
        """Down once to k0 / m where the subharmonic's own lines are significant and strong enough; a
        significant one too weak is the note kept."""
        for m in (2, 3):
            kk = k0 / m
            if kk < self.k_lo:
                continue
            significant, power = self.own_lines(kk, m)
            if significant:
                if power >= MIN_SUBHARMONIC_POWER * self.strongest(k0):
                    return self.recentre(kk), None
                weak_sub = (kk, power / self.strongest(k0))
        return k0, weak_sub

    def through_top_line(self, k0: float) -> float:
        """k0, or the spectrum's most significant line where k0's harmonics miss it.

        A family whose harmonics miss that line is not the period (slow leftovers of the restored link
        motion made a family at 59 cycles, moved up through 294 to 1468, of a clean 272-cycle line): the
        period starts again from that line.
        """
        k, dk = self.k, self.dk
        j_top = self.on_line(int(np.argmin(self.log_p)))
        h_top = max(1, int(round(k[j_top] / k0)))
        if abs(k[j_top] - h_top * k0) > (1 + h_top // 2) * dk:
            return float(k[j_top])
        return k0

    def strongest_line(self, k0: float) -> tuple[int, int]:
        """(h, grid index) of the family's most significant line among its first 8 harmonics: where the
        period is best located."""
        h_strong, i_strong = 1, int(np.clip(round((k0 - self.k_lo) / self.dk), 0, self.n_k - 1))
        for h, j in self.peaks(k0, 8):
            if h == 1 or self.log_p[j] < self.log_p[i_strong]:
                h_strong, i_strong = h, j
        return h_strong, self.on_line(i_strong)


@dataclass
class Family:
    """A harmonic family found by :func:`harmonic_family` (indices into the spectrum's grid)."""

    h_strong: int
    i_strong: int
    log_p: float
    #: A significant subharmonic family too weak to be the period: (spatial frequency, power share).
    weak_subharmonic: tuple[float, float] | None = None

    def bracket(self, k: np.ndarray, dk: float) -> tuple[float, float]:
        """Centre and half-width [cycles/rad] of the fundamental's refinement: the strongest line, located
        to about a grid step, divided by its harmonic number."""
        return float(k[self.i_strong] / self.h_strong), 1.5 * dk / self.h_strong
