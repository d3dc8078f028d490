"""A given spatial line tested in a given run: the cross-run evidence of the ripple search.

A run's own search (:func:`~iiwa_ident.ident._ripple_spectrum.line_search`) looks at every frequency and pays
for it in its false-alarm probability; a line that another run predicts is tested at that one frequency,
far more sensitively. :func:`line_test` does it: the Hann-tapered Fourier coefficient of the run's
deflection ``f`` at ``k`` [cycles/rad] of the motor position, pooled over the run's passes (a position-periodic
deflection is phase-locked to ``theta_m`` whatever the direction), against the same coefficient at
:data:`NEIGHBOURS` frequencies two resolution cells apart on both sides. Their median stands for the local
noise level: it follows coloured noise (the dynamic method's torque-integrated term rises as 1/f^2; a
torque filtered before logging falls), a median of a monotone spectrum over a symmetric set being its value at
the centre, and a temporal line among the neighbours moves it little. Under "no line" the ratio
``S = |c|^2 / (median / ln 2)`` is exceeded with about the probability of an F(2, J) law, J neighbours (a
Monte Carlo of exponential powers puts the true tail at 0.5-0.9 times that: conservative).

A candidate's frequency is known only to its std (or to a resolution cell of the run it came from), so ``k``
is searched over a window of that width, and the probability corrected for the independent cells in it.

Examples
--------
>>> import numpy as np
>>> from iiwa_ident.ident._ripple_passes import Pass
>>> rng = np.random.default_rng(1)
>>> theta = 0.5 * np.arange(4000) / 1000.0                    # 0.5 rad/s for 4 s at 1 kHz
>>> f = 2e-6 * np.sin(2 * np.pi * 51.0 * theta) + 2e-6 * rng.standard_normal(theta.size)
>>> p = Pass(dataset=0, method="dynamic", speed=0.5, theta=theta, f=f, t=theta / 0.5, tau_hp=f,
...          nuisance=np.ones((theta.size, 1)) / 63.25, period_max=0.2)
>>> line_test([p], 51.0, 1000.0).p_value < 1e-6, line_test([p], 37.0, 1000.0).p_value > 1e-3
(True, True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from iiwa_ident.ident._ripple_passes import Pass
from iiwa_ident.ident._ripple_spectrum import MIN_SUBHARMONIC_POWER, sidak, taper

__all__ = ["span", "pass_speed", "NEIGHBOURS", "RATIOS", "SAME_SPEED_RATIO", "FAMILY_MAX_HARMONIC", "LineTest", "line_test", "RunLines", "Candidate",
           "CrossRunLines", "cross_run_lines", "distinct_speeds"]

#: Neighbouring frequencies (half on each side) whose median coefficient power is the local noise level.
NEIGHBOURS = 24
#: Spacing of the neighbours and their nearest distance to the line, in resolution cells (1 / span):
#: a Hann-tapered line leaks over +-2 cells, coefficients 2 cells apart are nearly uncorrelated.
_SPACING_CELLS = 2.0
_GAP_CELLS = 4.0
#: Highest tested frequency as a share of the run's Nyquist limit (beyond it a line may be an alias).
NYQUIST_SHARE = 0.9
#: Widest window, as a share of the line's frequency: a run whose passes place a line no better than this
#: (short stretches of a chirp or a hand-guided run) does not test it.
WINDOW_MAX = 0.05


@dataclass(frozen=True)
class LineTest:
    """A line's test in one run.

    Attributes
    ----------
    k : float
        The tested spatial frequency (the strongest in the window) [cycles/rad].
    amplitude_rad : float
        Amplitude of the deflection's sine at ``k`` [rad] (0 when not tested).
    amplitude_std_rad : float
        Its standard error from the local noise level [rad] (inf when not tested).
    p_value : float
        Probability that noise alone gives a line this strong in the window (1 when not tested).
    frequency_hz : float
        The line's temporal frequency at the median speed of the run's passes, ``k |v|`` [Hz].
    reason : str
        Why the line was not tested ('' when it was): beyond the Nyquist limit, too slow for the passes'
        high-pass, or too few neighbouring frequencies.
    """

    k: float
    amplitude_rad: float
    amplitude_std_rad: float
    p_value: float
    frequency_hz: float
    reason: str = ""

    @property
    def tested(self) -> bool:
        return not self.reason


def span(passes: list[Pass]) -> float:
    """The motor positions the passes span [rad]: the coefficients are summed coherently over the passes (the
    deflection is phase-locked to the position), so a line is resolved to one over this, however the span is
    cut into passes (back and forth, or between gaps)."""
    return float(max(p.theta.max() for p in passes) - min(p.theta.min() for p in passes)) if passes else 0.0


def pass_speed(passes: list[Pass]) -> float:
    """The speed the passes hold most of their travel at [rad/s]: the travel-weighted median of their speeds.

    A run's median sample speed counts its ramps and dwells: three runs at 1.2 rad/s over 1 rad read 0.67-0.78,
    and two of them looked like two speeds (a temporal line then passed for a spatial one).
    """
    if not passes:
        return 0.0
    v = np.array([abs(p.speed) for p in passes])
    travel = np.array([abs(float(p.theta[-1] - p.theta[0])) for p in passes])
    order = np.argsort(v)
    cum = np.cumsum(travel[order])
    return float(v[order][np.searchsorted(cum, 0.5 * cum[-1])])


def _coefficients(passes: list[Pass], k: float, g: float, js: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The passes' pooled Hann-tapered Fourier coefficients of ``f`` at ``k + j g`` [cycles/rad] for ``j`` in
    ``js`` (increasing), scaled to a sine's amplitude, after the lines at ``known`` are fitted (one sine each,
    common to the passes, tapered least squares) and removed: a strong line's side lobes would otherwise stand
    for lines a few cells away. The phasors advance from one ``j`` to the next by a product (one complex
    exponential per distinct step, not per frequency)."""
    ws = [taper(len(p.f)) for p in passes]
    theta = np.concatenate([p.theta for p in passes])
    w = np.concatenate(ws)
    x = np.concatenate([p.f - np.average(p.f, weights=wp) for p, wp in zip(passes, ws)])
    if len(known):
        cols = np.exp(2j * np.pi * np.outer(theta, known))
        A = np.hstack([cols.real, cols.imag])
        beta = np.linalg.lstsq(A * np.sqrt(w)[:, None], x * np.sqrt(w), rcond=None)[0]
        x = x - A @ beta
    xw = x * w
    e = np.exp(-2j * np.pi * (k + js[0] * g) * theta)
    steps: dict[int, np.ndarray] = {}
    out = np.empty(len(js), dtype=complex)
    for n, j in enumerate(js):
        if n:
            d = int(j - js[n - 1])
            if d not in steps:
                steps[d] = np.exp(-2j * np.pi * d * g * theta)
            e *= steps[d]
        out[n] = e @ xw
    return 2.0 * out / max(float(w.sum()), 1e-300)


def _level(ks: np.ndarray, power: np.ndarray, k: float) -> float:
    """The noise level at ``k`` from the neighbours' powers: a robust straight line in log power against log
    frequency (Theil-Sen: a line among the neighbours moves it little) read at ``k``, its median residual
    taken as an exponential variable's median (``ln 2`` times the level). On a flat spectrum this is the
    neighbours' median over ln 2; near the passes' high-pass, where the neighbours lie on one side only, it
    follows a coloured floor's slope instead of reading the lower side's level."""
    x, y = np.log(ks / k), np.log(np.maximum(power, 1e-300))
    slope = float(stats.theilslopes(y, x)[0]) if len(np.unique(x)) > 1 else 0.0
    return float(math.exp(float(np.median(y - slope * x)))) / math.log(2.0)


def line_test(passes: list[Pass], k: float, rate_hz: float, k_std: float = 0.0,
              known: Sequence[float] = (), window_max: float = WINDOW_MAX) -> LineTest:
    """Test the run's passes for a line at ``k +- 3 k_std`` [cycles/rad] (module docstring).

    Parameters
    ----------
    passes : list of Pass
        One run's passes (one speed).
    k : float
        The line's spatial frequency [cycles/rad] (``1 / period``).
    rate_hz : float
        The run's sample rate [Hz]: lines above :data:`NYQUIST_SHARE` of its Nyquist limit are not tested.
    k_std : float
        Standard error of ``k`` [cycles/rad]; the window is at least half a resolution cell each side.
    known : sequence of float
        Lines already known [cycles/rad], fitted and removed first (those within a cell of the window are
        left: the line itself).
    window_max : float
        Widest window tested, relative to ``k``: a wider one (short passes) could hold another line.

    Returns
    -------
    LineTest
    """
    speed = float(np.median([abs(p.speed) for p in passes])) if passes else 0.0
    f_hz = k * speed
    if not passes:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "no passes")
    k_high = NYQUIST_SHARE * 0.5 * rate_hz / max(speed, 1e-12)
    # Only the passes that resolve the line (their high-pass keeps periods up to half their travel).
    passes = [p for p in passes if 1.0 / p.period_max < k * (1.0 - WINDOW_MAX)]
    if not passes:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "longer than the passes resolve")
    travel = span(passes)
    cell = 1.0 / max(travel, 1e-12)
    half = max(0.5 * cell, 3.0 * k_std)
    k_low = max(1.0 / p.period_max for p in passes)
    if k + half > k_high:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, f"beyond {NYQUIST_SHARE:.0%} of the Nyquist limit "
                                                     f"({f_hz:.1f} Hz at {speed:.2f} rad/s)")
    if half > window_max * k:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, f"the passes ({travel:.2g} rad) place a line only within "
                                                     f"+-{half / k:.0%}")
    if k - half < k_low:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "longer than the passes resolve")
    # Every frequency on one grid of a quarter cell: the window (+-half), a cell beyond it on each side (a line
    # whose power keeps rising past the window's edge is a neighbour's lobe, not a line in the window), and the
    # neighbours.
    g = cell / 4.0
    m = max(2, int(math.ceil(half / g)))
    first = m + int(round(4 * _GAP_CELLS))
    j_nb = first + int(round(4 * _SPACING_CELLS)) * np.arange(NEIGHBOURS // 2)
    j_nb = np.r_[-j_nb[::-1], j_nb]
    nb = k + g * j_nb
    keep = (nb >= k_low) & (nb <= k_high)
    j_nb, nb = j_nb[keep], nb[keep]
    if len(nb) < NEIGHBOURS // 3:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "too few neighbouring frequencies to tell its noise level")
    cells = 1 + int(math.ceil(2.0 * half / cell))
    j_in = np.arange(-m, m + 1)
    j_ring = np.r_[np.arange(-m - 4, -m), np.arange(m + 1, m + 5)]
    js = np.concatenate([j_in, j_ring, j_nb])
    order = np.argsort(js)
    kn = np.array([x for x in known if abs(x - k) > half + cell and x < k_high], dtype=float)
    c = np.empty(len(js), dtype=complex)
    c[order] = _coefficients(passes, k, g, js[order], kn)
    n_in = len(j_in)
    power = np.abs(c[:n_in]) ** 2
    outside = float(np.max(np.abs(c[n_in:n_in + len(j_ring)]) ** 2))
    level = _level(nb, np.abs(c[n_in + len(j_ring):]) ** 2, k)
    i = int(np.argmax(power))
    s = float(power[i]) / max(level, 1e-300)
    p1 = float(stats.f.sf(s, 2, len(nb)))
    p = sidak(p1, cells)
    if i in (0, n_in - 1) and outside > power[i]:
        p = 1.0
    window = k + g * j_in
    return LineTest(float(window[i]), float(math.sqrt(power[i])), math.sqrt(level / 2.0), p, float(window[i]) * speed)


# --------------------------------------------------------------------------- the runs' joint evidence

#: Ratios m / n (m, n = 1..4) by which a run's line gives candidates: its harmonics and subharmonics.
RATIOS = tuple(sorted({m / n for m in range(1, 5) for n in range(1, 5)}))
#: Runs whose speeds differ by less than this ratio count as one speed: a line periodic in time and one
#: periodic in position are told apart only by runs at different speeds.
SAME_SPEED_RATIO = 1.1
#: Highest harmonic of the compensated family that a reproduced line may be.
FAMILY_MAX_HARMONIC = 8
#: Relative tolerance of a line being harmonic h of the family (the runs' lines scatter by a few 0.1 %).
FAMILY_RTOL = 3e-3


@dataclass(kw_only=True)
class RunLines:
    """One run as the cross-run test sees it.

    Attributes
    ----------
    name : str
        The run's file (or ``run i``).
    passes : list of Pass
        Its passes.
    speed : float
        The speed its passes hold most of their travel at [rad/s] (:func:`pass_speed`).
    rate_hz : float
        Its sample rate [Hz].
    seeds : list of (float, float)
        Its own strongest lines ``(k, std)`` [cycles/rad].
    searched : float
        How many independent frequencies its own search picked them from: in this run a seed's p-value is
        corrected for them (it was chosen for being small there), in the others it is not.
    detected : int
        How many of the seeds (the first) its own search detected, with its own false-alarm probability: those
        need no further correction in this run.
    """

    name: str
    passes: list[Pass]
    speed: float
    rate_hz: float
    seeds: list[tuple[float, float]]
    searched: float = 1.0
    detected: int = 0

    @property
    def cell(self) -> float:
        """The run's resolution cell, one over the motor positions its passes span [cycles/rad]."""
        return 1.0 / max(span(self.passes), 1e-12)


@dataclass(kw_only=True)
class Candidate:
    """A candidate spatial line, tested in every run."""

    k: float
    k_std: float
    origin: str
    #: Runs whose own search picked it, with the independent frequencies it was picked from: its p-value there
    #: is corrected for them.
    looked: dict = field(default_factory=dict)
    #: A run's own line or an extra one (not a harmonic or subharmonic of one).
    own: bool = True
    #: Runs whose detected line (or a ratio of it) it is: a frequency they predict, whatever another run's
    #: search picked there.
    predicted: set = field(default_factory=set)
    tests: list[LineTest] = field(default_factory=list)
    significant: list[bool] = field(default_factory=list)
    #: The line's temporal frequency where it is significant in runs at one speed only and the other runs show
    #: it at that frequency in Hz, not at that position frequency: a temporal line [Hz], else None.
    temporal_hz: float | None = None

    @property
    def cycles_per_rev(self) -> float:
        return 2.0 * math.pi * self.k

    def p_value(self, i: int) -> float:
        """Its p-value in run ``i``, corrected for the search where that run's search picked it, unless another
        run's detected line predicts it there (a test at one frequency: the prediction's false alarm is its
        own detection's)."""
        p, m = self.tests[i].p_value, self.looked.get(i, 1.0)
        return sidak(p, m) if m > 1 and not self.predicted - {i} else p

    def speeds(self, runs: list[RunLines]) -> int:
        """How many different speeds (apart by :data:`SAME_SPEED_RATIO`) the runs where it is significant have."""
        return distinct_speeds([runs[i].speed for i, s in enumerate(self.significant) if s])

    def false_alarm(self, tries: float) -> float:
        """Bonferroni bound of a noise line being significant in two runs at different speeds: ``tries`` times
        the product of its two smallest p-values there (1 when it is not)."""
        ps = sorted(self.p_value(i) for i, s in enumerate(self.significant) if s)
        return min(1.0, tries * ps[0] * ps[1]) if len(ps) >= 2 else 1.0


def distinct_speeds(speeds: list[float]) -> int:
    """How many speeds apart by more than :data:`SAME_SPEED_RATIO` the list holds."""
    s = sorted(abs(v) for v in speeds)
    return sum(1 for a, b in zip(s, s[1:]) if b > SAME_SPEED_RATIO * a) + 1 if s else 0


@dataclass
class CrossRunLines:
    """Every candidate line tested in every run, and the family they decide.

    Attributes
    ----------
    runs : list of RunLines
    candidates : list of Candidate
    alpha : float
        The per-run significance level: two runs at ``alpha`` make a false reproduction less likely than the
        search's false-alarm probability over all candidates and run pairs.
    k0 : float or None
        The compensated family's fundamental [cycles/rad]: the shortest period whose harmonics (1 to
        :data:`FAMILY_MAX_HARMONIC`) are all the reproduced lines; None when no line is reproduced.
    harmonics : list of (Candidate, int)
        The reproduced lines with their harmonic number in that family.
    """

    runs: list[RunLines]
    candidates: list[Candidate]
    alpha: float
    k0: float | None = None
    harmonics: list[tuple[Candidate, int]] = field(default_factory=list)
    #: The fundamental of the period compensated [cycles/rad] (``k0``, or the runs' joint analysis's where no
    #: line is reproduced): lines of its family are not reported as other lines.
    k_ref: float | None = None

    @property
    def reproduced(self) -> list[Candidate]:
        return [c for c, _ in self.harmonics]

    @property
    def support(self) -> list[int]:
        """Indices of the runs in which a reproduced line is significant."""
        return sorted({i for c in self.reproduced for i, s in enumerate(c.significant) if s})

    def false_alarm(self) -> float:
        """The family's false-alarm probability: its most significant reproduced line's bound."""
        tries = len(self.candidates) * max(1, len(self.runs) * (len(self.runs) - 1) // 2)
        return min((c.false_alarm(tries) for c in self.reproduced), default=1.0)

    def one_speed(self) -> list[Candidate]:
        """Lines significant at one speed only (spatial or temporal: the data do not say), outside the family
        compensated, one per line seen (candidates whose windows caught the same line count once)."""
        return self._distinct([c for c in self.candidates if c.temporal_hz is None and c.speeds(self.runs) == 1])

    def outside(self) -> list[Candidate]:
        """Lines reproduced at two speeds or more that the family compensated does not explain."""
        return self._distinct([c for c in self.candidates if c.speeds(self.runs) >= 2])

    def temporal(self) -> list[Candidate]:
        """Lines periodic in time, one per frequency in Hz."""
        out: list[Candidate] = []
        seen: list[float] = []
        for c in self.candidates:
            f = c.temporal_hz
            if f is not None and all(abs(f / g - 1) > 0.01 for g in seen):
                out.append(c)
                seen.append(f)
        return out

    def temporal_at(self, k: float) -> float | None:
        """The frequency [Hz] of a temporal line that the runs place within a cell of a harmonic of ``k`` (1 to
        :data:`FAMILY_MAX_HARMONIC`), or None."""
        for c in self.candidates:
            if c.temporal_hz is not None:
                cell = max((self.runs[i].cell for i, s in enumerate(c.significant) if s), default=0.0)
                h = max(1, int(round(self.seen_k(c) / k)))
                if h <= FAMILY_MAX_HARMONIC and abs(self.seen_k(c) - h * k) <= cell:
                    return c.temporal_hz
        return None

    def seen_k(self, c: Candidate) -> float:
        """Where the runs that show the line place it: the median of their tests' frequencies [cycles/rad]."""
        ks = [t.k for t, s in zip(c.tests, c.significant) if s]
        return float(np.median(ks)) if ks else c.k

    def _distinct(self, cands: list[Candidate]) -> list[Candidate]:
        """``cands`` that are not the family's lines (within a cell of the runs that show them) nor the same line
        as a more significant one, most significant first."""
        family = [h * self.k_ref for h in range(1, FAMILY_MAX_HARMONIC + 1)] if self.k_ref else []
        out: list[Candidate] = []
        for c in sorted(cands, key=lambda c: min(c.p_value(i) for i in range(len(c.tests)))):
            cell = max((self.runs[i].cell for i, s in enumerate(c.significant) if s), default=0.0)
            k = self.seen_k(c)
            if all(abs(k - x) > cell for x in family + [self.seen_k(d) for d in out]):
                out.append(c)
        return out

    def shown(self, most: int = 8) -> list[Candidate]:
        """The candidates worth a row: the family's lines, then those significant somewhere, most significant
        first."""
        fam = [c for c, _ in sorted(self.harmonics, key=lambda x: x[1])]
        rest = sorted((c for c in self.candidates if any(c.significant) and all(c is not f for f in fam)),
                      key=lambda c: min(t.p_value for t in c.tests))
        return (fam + rest)[:most]

    def to_json(self) -> dict:
        """The ``lines`` part of ``ripple --json``: every shown candidate with its test in every run."""
        h_of = {id(c): h for c, h in self.harmonics}
        return {
            "alpha": self.alpha,
            "candidates_tested": len(self.candidates),
            "family_cycles_per_rev": None if self.k0 is None else 2 * math.pi * self.k0,
            "false_alarm_probability": self.false_alarm() if self.k0 is not None else None,
            "runs": [{"run": r.name, "speed_rad_s": r.speed, "rate_hz": r.rate_hz} for r in self.runs],
            "lines": [{"cycles_per_rev": 2 * math.pi * (h_of[id(c)] * self.k_ref if id(c) in h_of and self.k_ref
                                                         else self.seen_k(c)),
                       "candidate_cycles_per_rev": c.cycles_per_rev, "origin": c.origin, "harmonic": h_of.get(id(c)),
                       "temporal_hz": c.temporal_hz, "speeds_significant": c.speeds(self.runs),
                       "tests": [{"run": r.name, "amplitude_rad": t.amplitude_rad,
                                  "amplitude_std_rad": None if math.isinf(t.amplitude_std_rad) else t.amplitude_std_rad,
                                  "p_value": c.p_value(i), "frequency_hz": t.frequency_hz, "significant": s,
                                  "picked_by_its_search": i in c.looked, "not_tested": t.reason or None}
                                 for i, (r, t, s) in enumerate(zip(self.runs, c.tests, c.significant))]}
                      for c in self.shown(most=len(self.candidates))],
        }


def _candidates(runs: list[RunLines], extra: list[tuple[float, str]], k_min: float, k_max: float) -> list[Candidate]:
    """Every run's lines times :data:`RATIOS`, and ``extra`` lines, merged where they test the same line."""
    raw: list[Candidate] = []
    for i, r in enumerate(runs):
        for n, (k, std) in enumerate(r.seeds):
            picked = {i: r.searched} if n >= r.detected else {}
            predicted = {i} if n < r.detected else set()
            for q in RATIOS:
                if k_min <= q * k <= k_max:
                    origin = r.name if q == 1 else f"{r.name} x {_fraction(q)}"
                    raw.append(Candidate(k=q * k, k_std=q * std, origin=origin, looked=picked if q == 1 else {},
                                         own=q == 1, predicted=set(predicted)))
    for k, origin in extra:
        if k_min <= k <= k_max:
            raw.append(Candidate(k=k, k_std=0.0, origin=origin))
    if not raw:
        return []
    finest = min(r.cell for r in runs if r.passes) if any(r.passes for r in runs) else 0.0
    raw.sort(key=lambda c: c.k)
    merged = [raw[0]]
    for c in raw[1:]:
        m = merged[-1]
        if abs(c.k - m.k) <= max(0.5 * finest, 3.0 * math.hypot(c.k_std, m.k_std)):
            keep, drop = (m, c) if (m.k_std, len(m.looked)) <= (c.k_std, len(c.looked)) else (c, m)
            # Picked by either search: corrected in each (two noise maxima can meet by chance).
            for i, n in drop.looked.items():
                keep.looked[i] = max(n, keep.looked.get(i, 1.0))
            keep.own = keep.own or drop.own
            keep.predicted |= drop.predicted
            merged[-1] = keep
        else:
            merged.append(c)
    return merged


def _fraction(q: float) -> str:
    for n in range(1, 5):
        if abs(q * n - round(q * n)) < 1e-9:
            return f"{int(round(q * n))}/{n}" if n > 1 else f"{int(round(q * n))}"
    return f"{q:.3g}"


def cross_run_lines(runs: list[RunLines], false_alarm: float, k_min: float, k_max: float,
                    extra: Sequence[tuple[float, str]] = ()) -> CrossRunLines:
    """Test every candidate line in every run and decide the family to compensate (module docstring).

    Parameters
    ----------
    runs : list of RunLines
        The runs, each with its passes and its own lines.
    false_alarm : float
        The search's false-alarm probability; the per-run level is ``sqrt(false_alarm / (candidates x run
        pairs))``, at most 0.01.
    k_min, k_max : float
        The searched spatial frequencies [cycles/rad] (``1 / period_max``, ``1 / period_min``).
    extra : list of (float, str)
        Candidates from elsewhere (the pooled search, the paper's period) with their origin.

    Returns
    -------
    CrossRunLines
    """
    cands = _candidates(runs, list(extra), k_min, k_max)
    pairs = max(1, len(runs) * (len(runs) - 1) // 2)
    alpha = min(0.01, math.sqrt(false_alarm / max(1, 2 * len(cands) * pairs)))

    def test(which: list[Candidate], known: list[float]) -> None:
        for c in which:
            c.tests = [_test_in_run(r, c, known) for r in runs]
            c.significant = [t.tested and c.p_value(i) < alpha for i, t in enumerate(c.tests)]

    # The strongest lines (among the runs' own lines and the extra ones: the strongest line of the data is one
    # of them) are fitted and removed before every candidate is tested: their side lobes would stand for lines a
    # few cells away (the line itself is never removed from its own test).
    test([c for c in cands if c.own], [])
    test(cands, _dominant(cands, runs))
    _explain_by_time(cands, runs, alpha)
    out = CrossRunLines(runs, cands, alpha)
    out.k0, out.harmonics = _family([c for c in cands if c.speeds(runs) >= 2], k_min, runs)
    out.k_ref = out.k0
    fam = [h * out.k0 for h in range(1, FAMILY_MAX_HARMONIC + 1)] if out.k0 is not None else []
    # A line significant at one speed only, found at the same frequency in Hz in a run at another speed:
    # periodic in time (at the other run's position frequency k v_a / v_b), unless that lands on the family.
    for c in cands:
        if c.speeds(runs) != 1:
            continue
        a = next(i for i, s in enumerate(c.significant) if s)
        if _temporal_elsewhere(c, a, runs, fam, alpha, known=fam):
            c.temporal_hz = c.tests[a].frequency_hz
    return out


def _test_in_run(r: RunLines, c: Candidate, known: list[float]) -> LineTest:
    """``c`` tested in run ``r``; where the run's passes are too short to place a window on it but the run's
    own search detected a line there (within the two stds and a grid step), that line is tested: its own
    window is the one the run's search placed (a 0.4 rad run at 0.08 rad/s detected 133.3 cycles by itself,
    and 133.1 predicted by another run was not tested in it)."""
    t = line_test(r.passes, c.k, r.rate_hz, c.k_std, known)
    if t.tested or not r.detected or not r.seeds:
        return t
    k_det, std_det = r.seeds[0]
    if abs(c.k - k_det) > 3.0 * math.hypot(c.k_std, std_det) + r.cell / 8.0:
        return t
    return line_test(r.passes, k_det, r.rate_hz, std_det, known, window_max=math.inf)


def _explain_by_time(cands: list[Candidate], runs: list[RunLines], alpha: float) -> None:
    """Withdraw a run's support from a line reproduced at two speeds where a temporal line explains it there.

    A strong hum with harmonics is significant in every run; at two speeds two of its lines can land in one
    position frequency's windows (a short run's cell is tens of cycles per revolution wide). The line in run
    ``a`` at ``f`` Hz is then also significant at ``f / v_b`` in a run at another speed ``v_b``, where no
    harmonic of a reproduced line lies: that run's evidence is as well a temporal line's. Where that holds in
    every run the line is significant in, it is not reproduced (the one-speed check may then name it temporal).
    """
    reproduced = [c for c in cands if c.speeds(runs) >= 2]
    spatial = [h * d.k for d in reproduced for h in range(1, FAMILY_MAX_HARMONIC + 1)]
    for c in reproduced:
        explained = [a for a, s in enumerate(c.significant) if s and _temporal_elsewhere(c, a, runs, spatial, alpha)]
        # A line that some run shows only at its position frequency is not a temporal line's coincidence.
        if explained and len(explained) == sum(c.significant):
            c.significant = [False] * len(c.significant)


def _temporal_elsewhere(c: Candidate, a: int, runs: list[RunLines], spatial: list[float], alpha: float,
                        known: Sequence[float] = ()) -> bool:
    """Whether line ``c`` of run ``a`` is significant at its frequency in Hz in a run at another speed (its
    position frequency there ``k v_a / v_b``), away from the spatial lines ``spatial`` [cycles/rad]; ``known``
    lines are removed first (:func:`line_test`)."""
    f_hz = c.tests[a].frequency_hz
    for b, r in enumerate(runs):
        if b == a or not r.passes or distinct_speeds([runs[a].speed, r.speed]) < 2:
            continue
        kb = f_hz / max(r.speed, 1e-12)
        if any(abs(kb - x) < 2.0 * r.cell for x in spatial):
            continue
        t = line_test(r.passes, kb, r.rate_hz, c.k_std * runs[a].speed / r.speed, known)
        if t.tested and t.p_value < alpha:
            return True
    return False


def _dominant(cands: list[Candidate], runs: list[RunLines], most: int = 3) -> list[float]:
    """The strongest significant lines (by their smallest p-value), at least two cells apart [cycles/rad]."""
    cell = max((r.cell for r in runs if r.passes), default=0.0)
    out: list[float] = []
    for c in sorted((c for c in cands if c.tests and any(c.significant)),
                    key=lambda c: min(c.p_value(i) for i, s in enumerate(c.significant) if s)):
        if len(out) >= most:
            break
        if all(abs(c.k - x) > 2.0 * cell for x in out):
            out.append(c.tests[int(np.argmin([t.p_value for t in c.tests]))].k)
    return out


def _family(lines: list[Candidate], k_min: float, runs: list[RunLines]) -> tuple[float | None,
                                                                             list[tuple[Candidate, int]]]:
    """The family to compensate: the largest fundamental k0 >= k_min of which the most significant line and as
    many other lines as possible are harmonics 1..:data:`FAMILY_MAX_HARMONIC` (more lines first, then the
    shortest period). A fundamental below the most significant line needs its own line among the reproduced
    ones and lines of its own with power (:data:`MIN_SUBHARMONIC_POWER` of the strongest's)."""
    if not lines:
        return None, []
    lines = sorted(lines, key=lambda c: min(c.p_value(i) for i, s in enumerate(c.significant) if s))
    first = lines[0]

    def power(c: Candidate) -> float:
        # Its power where it is significant, as a share of the strongest line's power in those runs.
        shares = [c.tests[i].amplitude_rad ** 2 / max(first.tests[i].amplitude_rad ** 2, 1e-300)
                  for i, s in enumerate(c.significant) if s and first.tests[i].tested]
        return max(shares, default=0.0)

    # The lines are tested on a grid a quarter of the finest run's cell apart: each is placed within half a step
    # of its own (a 160-cycle line at 159.85 and its 320-cycle harmonic at 321.0 are one family).
    grid = min((r.cell for r in runs), default=0.0) / 8.0
    best: tuple[int, float, list] = (0, 0.0, [])
    for h in range(1, FAMILY_MAX_HARMONIC + 1):
        k0 = first.k / h
        if k0 < k_min:
            break
        hs = []
        for d in lines:
            hd = int(round(d.k / k0))
            if 1 <= hd <= FAMILY_MAX_HARMONIC and \
                    abs(d.k - hd * k0) <= FAMILY_RTOL * d.k + 3.0 * math.hypot(d.k_std, hd * first.k_std / h) \
                    + math.hypot(grid, hd * grid / h):
                hs.append((d, hd))
        # A longer period only for lines of its own that carry power: a share of the strongest line's, as the
        # search's family requires (weak lines at its subharmonics are reported, not compensated).
        own = [d for d, hd in hs if hd % h != 0]
        if h > 1 and (max((power(d) for d in own), default=0.0) < MIN_SUBHARMONIC_POWER
                      or not any(hd == 1 for _, hd in hs)):
            continue  # and only where its own fundamental line is reproduced: a period the data show
        if (len(hs), k0) > (best[0], best[1]):
            best = (len(hs), k0, hs)
    return (best[1], best[2]) if best[2] else (None, [])
