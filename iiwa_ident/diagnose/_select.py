"""Choosing effects by held-out evidence: blocked cross-validation and greedy forward selection.

Every residual channel of every dataset is one *block*, weighted by the
inverse of its baseline residual RMS so every block counts alike. Each block
is cut into :data:`FOLDS` contiguous stretches in time; fold k holds the
k-th stretch of every block (blocked k-fold: neighbouring samples are
correlated, so random folds would leak). All coefficients are fitted jointly
on the other folds and the held-out residual is kept.

Greedy forward selection tries every remaining candidate (its nonlinear
parameters searched again on the current in-sample residual) together with
the already selected ones and keeps the best if all of these hold:

``gain``        held-out SSE falls by at least :data:`MIN_GAIN` (relative);
``BIC``         ``n_eff ln(SSE_new / SSE_old) + p ln(n_eff) < 0`` on the held-out
                SSE, with ``p`` the effect's linear and searched parameters and
                ``n_eff`` the sample count discounted by the lag-one correlation
                of the held-out residual with the effect, ``(1 - r1) / (1 + r1)``
                per block;
``plausible``   the effect's own fitted parameters are physically possible
                (:meth:`CandidateEffect.plausible`), or, for an effect that
                removes at least :data:`MIN_GAIN_OTHER_SHAPE` of the held-out
                residual, they describe its family in another shape
                (:meth:`CandidateEffect.other_shape`, e.g. Stribeck friction
                as a negative viscous slope): it is named with that note;
``relevant``    the change the effect describes matters (:meth:`CandidateEffect.relevant`:
                a refit of the model's own parameters by less than the
                identification's accuracy on real joints is not a finding);
``material``    the effect itself, with its total coefficients (a correction
                of an effect the model has included; for ``model_parameters``
                the change of the predictions), is larger than the noise: its
                RMS on the residual channels it acts on at least
                :data:`NOISE_FACTOR` times the noise floor of what is left
                there with it (:func:`noise_floor`: the white part of the
                residual, from its sample-to-sample differences). A few
                hundredths of a Nm that a held-out test still favours are what
                the other effects' small errors leave, not an effect of their
                own. Judged in the whole band only, where a slow misfit finds
                such a proxy; the fast band and an effect's own evidence
                channel leave the slow part out;
``confidence``  a one-sided t-test on the relative held-out SSE reductions
                per (block, segment) (:data:`SEGMENTS` contiguous held-out
                segments per block), over the blocks the effect acts on, gives
                at least :data:`MIN_CONFIDENCE`; this probability is the
                effect's reported confidence.

When no candidate passes alone but some failed on the confidence only (whole band), the best
:data:`PAIR_CANDIDATES` of those are tried in pairs, each pair scored as one effect by the same tests and
each of its two judged plausible, relevant and material within it (:func:`_pair`): an offset and a friction
on long passes back and forth, where every held-out stretch holds mostly one direction of travel, pass only
together.

Each test is made twice: on the whole band and on the fast band (residual
and regressors high-passed at :data:`FAST_BAND_HZ`, zero phase). A large
slow misfit nothing in the library explains (an unmodelled trajectory
dependence on a real arm) would otherwise hide a small fast effect such
as the ripple.

A candidate may bring an evidence channel of its own
(:meth:`CandidateEffect.evidence`, e.g. the ripple's deflection in the
motor position): a residual with its own blocks and the effect's regressors
there, scored by the very same tests (held-out gain, BIC, t-test; its
blocks are already weighted and the other effects do not act on it). When
the channel carries a calibrated detection probability, the confidence is
at most one minus its false-alarm probability. It is reported as the band
named after the channel. Own evidence counts only when the residual
channels do not contradict it: in at least one band the effect must lower
the held-out SSE there (gain > 0) with a t-test probability above one half.
An effect already in the model and corrected only slightly (a table a few
per cent off) can be plain in a noise-free own channel and yet make the
torque prediction no better.

At each step the candidates passing on the whole band compete first
(largest gain wins, unless a simpler candidate whose shape the winner's holds,
:attr:`CandidateEffect.contains`, gains less than :data:`MIN_GAIN` less; once one of the two is
named the other is not tried); only when none passes do those passing on the fast
band, and only when none passes there do those passing on their own
evidence channel. Selection stops at the first step where no candidate
passes; on data the model explains, the first step already fails and
nothing is named.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import signal, stats

from iiwa_ident.diagnose._candidates import Block, CandidateEffect, EvidenceChannel, block_columns

__all__ = ["FOLDS", "MIN_GAIN", "NOISE_FACTOR", "FAST_BAND_HZ", "BANDS", "MIN_CONFIDENCE", "MAX_EFFECTS",
           "MIN_GAIN_OTHER_SHAPE", "Step", "Selection", "noise_floor", "cv_residuals", "select_effects"]

#: Number of contiguous folds per block.
FOLDS = 5
#: Held-out segments per block for the confidence test (a multiple of FOLDS).
SEGMENTS = 4 * FOLDS
#: Least relative reduction of the held-out SSE for an effect to be named.
MIN_GAIN = 0.03
#: Least confidence (one-sided t-test over block-folds) for an effect to be named.
MIN_CONFIDENCE = 0.999
#: Most effects named.
MAX_EFFECTS = 4
#: Least held-out reduction for an effect whose fit is not physically possible to be named as its family in
#: another shape (a large effect must be named, not hidden by the shape of its candidate).
MIN_GAIN_OTHER_SHAPE = 0.5
#: Least ratio of an effect's RMS on the residual channels to their noise floor for it to be named.
NOISE_FACTOR = 2.0
#: Lower edge of the fast band [Hz].
FAST_BAND_HZ = 3.0
#: Bands an effect is judged in, in order of precedence.
BANDS = ("full", "fast")


def _fold_ids(m: int) -> np.ndarray:
    return np.minimum((np.arange(m) * FOLDS) // max(m, 1), FOLDS - 1)


def cv_residuals(Xs: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Held-out residual of each block under blocked k-fold least squares.

    Parameters
    ----------
    Xs : list of numpy.ndarray
        Weighted regressors per block (samples x p); p may be 0.
    ys : list of numpy.ndarray
        Weighted residual per block.

    Returns
    -------
    list of numpy.ndarray
        ``y - X coef_(-k)`` with the coefficients fitted without the sample's fold.
    """
    out = [y.copy() for y in ys]
    p = Xs[0].shape[1] if Xs else 0
    if p == 0:
        return out
    folds = [_fold_ids(len(y)) for y in ys]
    X, y = np.vstack(Xs), np.concatenate(ys)
    f = np.concatenate(folds)
    for k in range(FOLDS):
        train = f != k
        coef = np.linalg.lstsq(X[train], y[train], rcond=None)[0]
        for i, (Xb, fb) in enumerate(zip(Xs, folds)):
            test = fb == k
            out[i][test] = ys[i][test] - Xb[test] @ coef
    return out


def _fold_sse(res: Sequence[np.ndarray]) -> np.ndarray:
    """SSE per (block, segment): :data:`SEGMENTS` contiguous segments, each inside one fold."""
    out = np.zeros((len(res), SEGMENTS))
    for i, r in enumerate(res):
        seg = np.minimum((np.arange(len(r)) * SEGMENTS) // max(len(r), 1), SEGMENTS - 1)
        out[i] = np.bincount(seg, weights=r ** 2, minlength=SEGMENTS)
    return out


def _n_eff(res: Sequence[np.ndarray]) -> float:
    total = 0.0
    for r in res:
        r = r - r.mean()
        denom = float(np.dot(r, r))
        r1 = float(np.dot(r[1:], r[:-1]) / denom) if denom > 0 and len(r) > 2 else 0.0
        r1 = min(max(r1, 0.0), 0.98)
        total += len(r) * (1 - r1) / (1 + r1)
    return max(total, 10.0)


@dataclass(kw_only=True)
class Step:
    """One candidate tried at one greedy step, in one band (``full``, ``fast``, or its own evidence channel's name)."""

    step: int
    name: str
    gain: float
    delta_bic: float
    confidence: float
    accepted: bool = False
    band: str = "full"
    implausible: bool = False
    #: Passed the tests, but the change it describes is too small to matter (:meth:`CandidateEffect.relevant`).
    irrelevant: bool = False
    #: Passed the tests, but the effect is below the noise (see ``material`` in the module docstring).
    negligible: bool = False
    #: How the effect's fit departs from its candidate's shape, when it was named in another shape.
    other_shape: str = ""
    #: On an effect's own evidence channel: no band of the residual channels lowered the held-out SSE with it
    #: (they do not confirm it, and it is not named on its own evidence).
    unconfirmed: bool = False


@dataclass(kw_only=True)
class Selection:
    """Outcome of :func:`select_effects`.

    Attributes
    ----------
    selected : list of CandidateEffect
        Named effects, in order of selection.
    slices : list of slice
        Each selected effect's columns in the joint coefficient vector.
    coef : numpy.ndarray
        Joint least-squares coefficients on all data.
    confidence, gain : dict of str to float
        Per named effect, at the step it was selected.
    steps : list of Step
        Every candidate tried, for the report.
    """

    selected: list[CandidateEffect] = field(default_factory=list)
    slices: list[slice] = field(default_factory=list)
    coef: np.ndarray = field(default_factory=lambda: np.zeros(0))
    confidence: dict[str, float] = field(default_factory=dict)
    gain: dict[str, float] = field(default_factory=dict)
    band: dict[str, str] = field(default_factory=dict)
    #: Per effect named in another shape than its candidate's, how (see :class:`Step`).
    other_shape: dict[str, str] = field(default_factory=dict)
    steps: list[Step] = field(default_factory=list)

    def columns(self, blocks: Sequence[Block], skip: str | None = None, held: int = 0) -> list[np.ndarray]:
        """Weighted regressors of the selected effects (optionally without one, or without the first ``held``)."""
        mats = [[np.zeros((np.count_nonzero(b.mask), 0))] for b in blocks]
        for cand in self.selected[held:]:
            if cand.name == skip:
                continue
            for i, X in enumerate(block_columns(blocks, cand.columns, cand.n_columns())):
                mats[i].append(X)
        return [np.hstack(m) for m in mats]


def noise_floor(residuals: Sequence[np.ndarray]) -> float:
    """White noise [Nm RMS] of residuals: their sample-to-sample differences over sqrt(2), robustly (the median
    absolute difference), the largest over the residuals given."""
    out = 0.0
    for r in residuals:
        if len(r) > 2:
            out = max(out, float(np.median(np.abs(np.diff(r)))) / (0.6745 * math.sqrt(2.0)))
    return out


def _material(blocks: Sequence[Block], Xc: list[np.ndarray], total: np.ndarray, left: list[np.ndarray]) -> bool:
    """Whether an effect's RMS [Nm] on the blocks it acts on reaches :data:`NOISE_FACTOR` times the noise floor
    of what is left there with it (``left``: weighted in-sample residuals per block)."""
    acts = [i for i, X in enumerate(Xc) if np.any(X)]
    if not acts:
        return False
    parts = [Xc[i] @ total / blocks[i].weight for i in acts]
    rms = float(np.sqrt(np.mean(np.concatenate(parts) ** 2)))
    return rms >= NOISE_FACTOR * noise_floor([left[i] / blocks[i].weight for i in acts])


def _band_filters(blocks: Sequence[Block]) -> list:
    """Per block, the zero-phase high-pass of the fast band (on the block's own sample spacing)."""
    out = []
    for b in blocks:
        idx = np.nonzero(b.mask)[0]
        dt = b.ctx.dt * (float(np.median(np.diff(idx))) if len(idx) > 1 else 1.0)
        out.append(signal.butter(2, FAST_BAND_HZ, btype="highpass", fs=1.0 / dt, output="sos"))
    return out


def _in_band(band: str, filters: list, arrays: Sequence[np.ndarray]) -> list[np.ndarray]:
    if band == "full":
        return list(arrays)
    return [signal.sosfiltfilt(f, a, axis=0) if a.size else a for f, a in zip(filters, arrays)]


def _score(step: int, name: str, band: str, Xs: list[np.ndarray], Xc: list[np.ndarray], ys: list[np.ndarray],
           cur_res: list[np.ndarray], n_nonlinear: int) -> tuple[Step, list[np.ndarray]] | None:
    """Held-out gain, BIC change and confidence of adding columns ``Xc`` (all in one band)."""
    sse_old = sum(float(np.sum(r ** 2)) for r in cur_res)
    res = cv_residuals(Xs, ys)
    sse = sum(float(np.sum(r ** 2)) for r in res)
    gain = 1 - sse / sse_old if sse_old > 0 else 0.0
    p = sum(1 for j in range(Xc[0].shape[1]) if any(np.any(X[:, j]) for X in Xc)) + n_nonlinear
    n_eff = _n_eff(res)
    dbic = n_eff * math.log(max(sse, 1e-300) / max(sse_old, 1e-300)) + p * math.log(n_eff)
    # Relative reduction per (block, fold), on the blocks the effect acts on.
    acts = [i for i, X in enumerate(Xc) if np.any(X)]
    old = _fold_sse(cur_res)[acts]
    diff = ((old - _fold_sse(res)[acts]) / np.maximum(old, 1e-300)).ravel()
    if len(diff) < 2:
        return None
    sd = diff.std(ddof=1)
    t = diff.mean() / (sd / math.sqrt(len(diff))) if sd > 0 else (math.inf if diff.mean() > 0 else 0.0)
    conf = float(stats.t.cdf(t, len(diff) - 1)) if math.isfinite(t) else 1.0
    return Step(step=step, name=name, gain=gain, delta_bic=dbic, confidence=conf, band=band), res


_OWN = "own evidence channel"


def _score_own(step: int, cand: CandidateEffect, ev: EvidenceChannel) -> Step | None:
    """:func:`_score` on a candidate's own evidence channel (nothing else acts on it), confidence capped."""
    if not ev.X or any(len(y) < 2 * SEGMENTS for y in ev.y):
        return None
    scored = _score(step, cand.name, ev.name, ev.X, ev.X, ev.y, list(ev.y), cand.n_nonlinear)
    if scored is None:
        return None
    record = scored[0]
    if ev.false_alarm is not None:
        record.confidence = min(record.confidence, 1.0 - float(ev.false_alarm))
    return record


#: Candidates of a step tried in pairs when none passes alone (the best ones by held-out gain).
PAIR_CANDIDATES = 3


def _pair(step: int, near: list, blocks: Sequence[Block], ys: Sequence[np.ndarray], ys_full: list[np.ndarray],
          cur_X: list[np.ndarray], cur_res: list[np.ndarray], min_gain: float, min_confidence: float
          ) -> tuple[Step, list[tuple[CandidateEffect, list[np.ndarray]]]] | None:
    """Two effects named together where neither passes alone on its confidence; None when no pair passes.

    An offset beside a friction on runs back and forth: each held-out fold, a stretch of time, holds mostly
    one direction of travel, where the other effect's missing part dominates, so each alone gains on some
    folds and loses on others; together they gain on all. Tried only among effects that passed every test
    but the confidence in the whole band (:data:`PAIR_CANDIDATES` best by gain); the pair must pass every
    test as one effect, and each of the two its own plausibility, relevance and materiality within it.
    """
    near = sorted(near, key=lambda x: -x[2].gain)[:PAIR_CANDIDATES]
    best = None
    for i in range(len(near)):
        for k in range(i + 1, len(near)):
            (c1, X1, _), (c2, X2, _) = near[i], near[k]
            if c1.name in c2.contains or c2.name in c1.contains:
                continue  # one holds the other's shape: no pair
            Xp = [np.hstack([a, b]) for a, b in zip(X1, X2)]
            joint = [np.hstack([a, b]) for a, b in zip(cur_X, Xp)]
            scored = _score(step, f"{c1.name} + {c2.name}", "full", joint, Xp, ys_full, cur_res,
                            c1.n_nonlinear + c2.n_nonlinear)
            if scored is None:
                continue
            record = scored[0]
            if not (_passes_but_confidence(record, min_gain) and record.confidence >= min_confidence):
                continue
            coef = np.linalg.lstsq(np.vstack(joint), np.concatenate(ys), rcond=None)[0]
            left = [y - X @ coef for y, X in zip(ys, joint)]
            n1, n2 = c1.n_columns(), c2.n_columns()
            fits = [(c1, X1, coef[len(coef) - n1 - n2:len(coef) - n2]), (c2, X2, coef[len(coef) - n2:])]
            if all(c.plausible(c.total(f)) and c.relevant(f) and _material(blocks, X, c.total(f), left)
                   for c, X, f in fits) and (best is None or record.gain > best[0].gain):
                best = (record, [(c1, X1), (c2, X2)])
    return best


def _passes_but_confidence(record: Step, min_gain: float) -> bool:
    """Whether a scored step passes the gain and BIC tests (``min_gain``: the candidate's own minimum)."""
    return record.gain >= min_gain and record.delta_bic < 0


def _accept(sel: Selection, cand: CandidateEffect, record: Step, width: int) -> None:
    """Name ``cand`` in ``sel`` on ``record``, its columns after the first ``width`` ones."""
    record.accepted = True
    sel.selected.append(cand)
    sel.slices.append(slice(width, width + cand.n_columns()))
    sel.confidence[cand.name] = record.confidence
    sel.gain[cand.name] = record.gain
    sel.band[cand.name] = record.band
    if record.other_shape:
        sel.other_shape[cand.name] = record.other_shape


class _Tried(NamedTuple):
    """A candidate that passed a step's tests in one band: its columns and the step that scored it."""

    cand: CandidateEffect
    Xc: list[np.ndarray]
    record: Step


@dataclass
class _EffectFit:
    """A candidate's own least-squares fit beside the effects named so far, on the residual channels."""

    coef: np.ndarray  #: the candidate's coefficients
    total: np.ndarray  #: :meth:`CandidateEffect.total` of them
    left: list[np.ndarray]  #: the residual per block after the joint fit


def select_effects(blocks: Sequence[Block], ys: Sequence[np.ndarray], candidates: Sequence[CandidateEffect],
                   min_gain: float = MIN_GAIN, min_confidence: float = MIN_CONFIDENCE,
                   max_effects: int = MAX_EFFECTS, first: Sequence[tuple[CandidateEffect, Step]] = ()) -> Selection:
    """Greedy forward selection of candidate effects (see the module docstring).

    Parameters
    ----------
    blocks : list of Block
    ys : list of numpy.ndarray
        Weighted baseline residual per block.
    candidates : list of CandidateEffect
    min_gain, min_confidence : float
        Acceptance thresholds.
    max_effects : int
        Most effects named.
    first : list of (CandidateEffect, Step)
        Effects named before the search, with the step that named them (prepared: their searched parameters
        stay), held whole: their columns, at coefficient 1 (as the model carries a filter), leave the residual
        before the search and their coefficients stay 1.

    Returns
    -------
    Selection
    """
    sel = Selection()
    given = {cand.name for cand, _ in first}
    remaining = [c for c in candidates if c.name not in given]
    ys = list(ys)
    n0 = 0  # the columns held whole, first in the coefficient vector
    for cand, record in first:
        for i, X in enumerate(block_columns(blocks, cand.columns, cand.n_columns())):
            ys[i] = ys[i] - X.sum(axis=1)
        _accept(sel, cand, record, n0)
        n0 += cand.n_columns()
    g = _Greedy(blocks=blocks, ys=ys, sel=sel, n0=n0, min_gain=min_gain, min_confidence=min_confidence,
                max_effects=max_effects)
    while remaining and len(sel.selected) < max_effects and g.name_next(remaining):
        pass
    coef = g.coef
    if len(sel.selected) > len(first):
        # Searched parameters may have moved after later selections: rebuild the columns once more.
        cur_X = sel.columns(blocks, held=len(first))
        coef = np.linalg.lstsq(np.vstack(cur_X), np.concatenate(ys), rcond=None)[0]
    sel.coef = np.concatenate([np.ones(n0), coef]) if sel.selected else coef
    return sel


class _Greedy:
    """The greedy steps of :func:`select_effects` after the effects held whole (``n0`` columns)."""

    def __init__(self, *, blocks: Sequence[Block], ys: list[np.ndarray], sel: Selection, n0: int,
                 min_gain: float, min_confidence: float, max_effects: int) -> None:
        self.blocks, self.ys, self.sel, self.n0 = blocks, ys, sel, n0
        self.min_gain, self.min_confidence, self.max_effects = min_gain, min_confidence, max_effects
        self.filters = _band_filters(blocks)
        self.ys_band = {band: _in_band(band, self.filters, ys) for band in BANDS}
        self.cur_X = [np.zeros((len(y), 0)) for y in ys]
        self.in_sample = list(ys)
        self.coef = np.zeros(0)
        self.step = 0

    def name_next(self, remaining: list[CandidateEffect]) -> bool:
        """One step: try every remaining candidate, name the best (or the best pair); False when none passes."""
        self.step += 1
        cur_band = {band: _in_band(band, self.filters, self.cur_X) for band in BANDS}
        cur_res = {band: cv_residuals(cur_band[band], self.ys_band[band]) for band in BANDS}
        passed: dict[str, list[_Tried]] = {band: [] for band in BANDS + (_OWN,)}
        near: list[_Tried] = []  # failed on the confidence alone
        for cand in remaining:
            self._try(cand, cur_band, cur_res, passed, near)
        # The whole band first (it judges the effect everywhere); the fast band only when nothing passes there;
        # an effect's own evidence channel last.
        choice = next((passed[band] for band in BANDS + (_OWN,) if passed[band]), None)
        if choice:
            best = max(choice, key=lambda x: x.record.gain)
            # A candidate whose shape holds a simpler one's (a spring's constant is an offset) must gain the least
            # gain more than that one, else the simpler explanation stands.
            simpler = [c for c in choice if c.cand.name in best.cand.contains
                       and c.record.gain > best.record.gain - self.min_gain]
            if simpler:
                best = max(simpler, key=lambda x: x.record.gain)
            record, named = best.record, [(best.cand, best.Xc)]
        else:
            pair = _pair(self.step, near, self.blocks, self.ys, self.ys_band["full"], self.cur_X, cur_res["full"],
                         self.min_gain, self.min_confidence) if len(self.sel.selected) + 2 <= self.max_effects else None
            if pair is None:
                return False
            record, named = pair
            self.sel.steps.append(record)
        for cand, Xc in named:
            _accept(self.sel, cand, record, self.n0 + self.cur_X[0].shape[1])
            remaining.remove(cand)
            self.cur_X = [np.hstack([a, b]) for a, b in zip(self.cur_X, Xc)]
        self.coef = np.linalg.lstsq(np.vstack(self.cur_X), np.concatenate(self.ys), rcond=None)[0]
        self.in_sample = [yb - Xb @ self.coef for yb, Xb in zip(self.ys, self.cur_X)]
        return True

    def _try(self, cand: CandidateEffect, cur_band: dict, cur_res: dict, passed: dict[str, list[_Tried]],
             near: list[_Tried]) -> None:
        """Score ``cand`` in every band and on its own evidence; what passes goes to ``passed`` by band, what
        fails on the confidence alone (whole band) to ``near``; every score to the selection's steps."""
        sel = self.sel
        # Two candidates one of which holds the other's shape share a column: once one is named, the other
        # is not tried (their shared part would be split at random between them).
        if any(cand.name in c.contains or c.name in cand.contains for c in sel.selected):
            return
        full = np.concatenate([np.ones(self.n0), self.coef])
        cand.beside = [(c, full[sl]) for c, sl in zip(sel.selected, sel.slices)]
        if not cand.prepare(self.blocks, self.in_sample):
            return
        Xc = block_columns(self.blocks, cand.columns, cand.n_columns())
        records = self._band_records(cand, Xc, cur_band, cur_res)
        ev = cand.evidence(self.blocks)
        own = _score_own(self.step, cand, ev) if ev is not None else None
        # Own evidence counts only where the residual channels do not contradict it.
        agrees = any(r.gain > 0 and r.confidence > 0.5 for _, r in records)
        if own is not None:
            records.append((_OWN, own))
        fit = None
        for band, record in records:
            sel.steps.append(record)
            if band == _OWN and not agrees:
                record.unconfirmed = True
                continue
            if not _passes_but_confidence(record, max(self.min_gain, cand.min_gain)):
                continue
            if record.confidence < self.min_confidence:
                if band == "full" and cand.is_effect:  # tried in pairs where nothing passes alone
                    near.append(_Tried(cand, Xc, record))
                continue
            fit = fit or self._effect_fit(cand, Xc)
            if self._possible(cand, Xc, band, record, fit):
                passed[band].append(_Tried(cand, Xc, record))

    def _band_records(self, cand: CandidateEffect, Xc: list[np.ndarray], cur_band: dict, cur_res: dict
                      ) -> list[tuple[str, Step]]:
        """``cand``'s score in each band where its columns hold anything."""
        full_norm = np.sqrt(sum(np.sum(X ** 2, axis=0) for X in Xc))
        records: list[tuple[str, Step]] = []
        for band in BANDS:
            Xc_b = _in_band(band, self.filters, Xc)
            # A column with (almost) nothing in the band says nothing there; left in, it only adds rounding noise.
            band_norm = np.sqrt(sum(np.sum(X ** 2, axis=0) for X in Xc_b))
            dead = band_norm <= 1e-3 * np.maximum(full_norm, 1e-300)
            if dead.all():
                continue
            Xc_b = [np.where(dead, 0.0, X) for X in Xc_b]
            Xs_b = [np.hstack([a, b]) for a, b in zip(cur_band[band], Xc_b)]
            scored = _score(self.step, cand.name, band, Xs_b, Xc_b, self.ys_band[band], cur_res[band],
                            cand.n_nonlinear)
            if scored is not None:
                records.append((band, scored[0]))
        return records

    def _effect_fit(self, cand: CandidateEffect, Xc: list[np.ndarray]) -> _EffectFit:
        """``cand``'s least-squares fit beside the effects named so far."""
        joint = [np.hstack([a, b]) for a, b in zip(self.cur_X, Xc)]
        coef_all = np.linalg.lstsq(np.vstack(joint), np.concatenate(self.ys), rcond=None)[0]
        fit = coef_all[-cand.n_columns():]
        return _EffectFit(fit, cand.total(fit), [y - X @ coef_all for y, X in zip(self.ys, joint)])

    def _possible(self, cand: CandidateEffect, Xc: list[np.ndarray], band: str, record: Step,
                  fit: _EffectFit) -> bool:
        """Whether the effect's own fit is physically possible (a negative friction is a symptom of something
        else), relevant and material; ``record`` is marked with why not, or with the other shape it took."""
        plausible = cand.plausible(fit.total)
        note = "" if plausible or record.gain < MIN_GAIN_OTHER_SHAPE else cand.other_shape(fit.total)
        if plausible and not cand.relevant(fit.coef):
            record.irrelevant = True
        elif (plausible or note) and band == "full" and not _material(self.blocks, Xc, fit.total, fit.left):
            record.negligible = True
        elif plausible or note:
            record.other_shape = note
            return True
        else:
            record.implausible = True
        return False
