"""``diagnose``: what the model gets wrong, which effects explain it, and what they gain.

1. Every dataset is predicted with the model (:mod:`~iiwa_ident.diagnose._predict`);
   the effects the model file already lists are part of the prediction (an
   ``input_delay`` as a longer ``Td``; the ripple through the ``[ripple]``
   table only, not as an ``[[effects]]`` entry).
2. The candidate library (:mod:`~iiwa_ident.diagnose._candidates`) is tested
   by blocked cross-validation and greedy selection (:mod:`~iiwa_ident.diagnose._select`).
3. The named effects are refitted on all data and added to a copy of the
   model: the ripple as a :class:`~iiwa_ident.model.RippleTable`,
   a delay as a corrected ``Td``, the others as ``[[effects]]`` tables the
   simulator runs (:func:`~iiwa_ident.sim.plant_from_model`).
4. The gain is measured on held-out data: residual RMS [Nm] before and after
   per dataset and channel, and per effect (with and without it, on the
   blocks it acts on). The link channel's RMS is the error of a model-based
   external-torque estimate; the command channel's is the part of the joint
   torque the model cannot predict from the command.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar

from iiwa_ident.datasets import Dataset, torque_sign_problem
from iiwa_ident.diagnose._candidates import (
    CANDIDATES,
    LOG_FILTER_DAMPINGS,
    LOG_FILTER_MIN_HZ,
    LOG_FILTER_OTHER_SHAPE,
    Block,
    CandidateEffect,
    TorqueLogFilterCandidate,
    block_columns,
    block_sse,
    contribution,
    make_candidate,
)
from iiwa_ident.diagnose._channels import ChannelComparison, channel_comparison
from iiwa_ident.diagnose._predict import Context, build_context
from iiwa_ident.diagnose._select import (
    BANDS,
    MIN_GAIN,
    NOISE_FACTOR,
    Selection,
    Step,
    cv_residuals,
    noise_floor,
    select_effects,
)
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import PhysicalRanges, against_description, check_model_matches, payload_of_load, physical_ranges
from iiwa_ident.model import JointModel
from iiwa_ident.sim import TorqueLogFilter

__all__ = ["ACROSS_RUNS_WORSE_PCT", "LARGE_GAIN", "OTHER_SHAPE_LEFT_PCT", "SIGN_RMS_RATIO", "reversed_sign", "undecided_sentence", "EffectReport", "ChannelReport", "Diagnosis", "diagnose",
           "residual_rms"]

_LINK_POINTS_PER_CUTOFF = 4.0  # link-channel samples kept per period of its cut-off (it is low-passed)
#: Held-out reduction of the residual's power a candidate that failed the other tests must not reach for
#: the model to count as explaining the data.
LARGE_GAIN = 0.3
#: ``shape_left_pct`` from which a named effect counts as being in another shape of its family (its freer
#: shape removes that much of what the named effects leave); another named effect that the freer shape
#: makes redundant is then reported as ambiguous, not named.
OTHER_SHAPE_LEFT_PCT = 20.0
#: A run the model predicts with at most this share of the RMS once its torque is turned over reads the other way
#: round (where the import's own check of the sign does not decide).
SIGN_RMS_RATIO = 0.5
_REDUNDANT_SHARE = 0.25  # of its own held-out gain, at most, that an ambiguous effect keeps beyond the other's shape


@dataclass(kw_only=True)
class EffectReport:
    """One named effect.

    Attributes
    ----------
    name : str
    confidence : float
        Probability (one-sided t-test over held-out block-folds) that the effect reduces the residual.
    parameters : dict of str to float
        Reported parameters (units in :mod:`iiwa_ident.diagnose._candidates`).
    rms_before, rms_after : float
        Held-out residual RMS [Nm] without and with the effect (all other named
        effects included), on the channels it acts on.
    gain_pct : float
        ``100 (1 - rms_after / rms_before)``.
    detail : dict
        Extra figures of the effect (compensated fraction, false-alarm probability, ...) and
        ``selected_in``, the band or evidence channel it passed the selection's tests in.
    """

    name: str
    confidence: float
    parameters: dict[str, float]
    rms_before: float
    rms_after: float
    gain_pct: float
    detail: dict[str, Any] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        return {"name": self.name, "confidence": self.confidence, "parameters": self.parameters,
                "rms_before": self.rms_before, "rms_after": self.rms_after, "gain_pct": self.gain_pct,
                "detail": self.detail}


@dataclass(kw_only=True)
class ChannelReport:
    """Held-out residual RMS of one channel of one dataset [Nm]; the model's prediction of it, before and
    after the named effects (in-sample: fit %, residual tests), as ``compare`` gives it."""

    dataset: str
    experiment: str
    channel: str
    rms_before: float
    rms_after: float
    before: ChannelComparison | None = None
    after: ChannelComparison | None = None

    @property
    def gain_pct(self) -> float:
        return 100.0 * (1 - self.rms_after / self.rms_before) if self.rms_before > 0 else 0.0


@dataclass
class _Naming:
    """One naming of the effects: the selection, its effect reports, the model extended by them and the
    held-out residuals with them; from :func:`_named` also the ambiguous and undecided effects (the keys of
    :attr:`Diagnosis.ambiguous` and :attr:`Diagnosis.undecided`)."""

    selection: Selection
    effects: list[EffectReport]
    extended: JointModel
    after: list[np.ndarray]
    ambiguous: list[dict[str, Any]] = field(default_factory=list)
    undecided: list[dict[str, Any]] = field(default_factory=list)

    @property
    def heldout_sse(self) -> float:
        """The held-out residual's sum of squares over every block."""
        return _sse(self.after, range(len(self.after)))


@dataclass(kw_only=True)
class Diagnosis:
    """Outcome of :func:`diagnose` (see the module docstring)."""

    explained: bool
    effects: list[EffectReport]
    channels: list[ChannelReport]
    model: JointModel
    extended: JointModel
    contexts: list[Context]
    blocks: list[Block]
    selection: Selection
    heldout_before: list[np.ndarray]
    heldout_after: list[np.ndarray]
    model_out: str | None = None
    #: Candidates of the last selection step that would remove at least :data:`LARGE_GAIN` of the held-out
    #: residual but failed another test (BIC, confidence, plausibility): the model does not explain the data
    #: even when nothing is named.
    suspects: list[dict[str, Any]] = field(default_factory=list)
    #: Effects the selection named that a named effect's other shape explains as well (the data do not
    #: decide between them): not named, not in the extended model; each with ``name``, ``or_shape_of``,
    #: ``gain_pct`` (its held-out gain when named) and ``gain_beyond_pct`` (beyond the other's freer shape).
    ambiguous: list[dict[str, Any]] = field(default_factory=list)
    #: Effects of the given model that the data contradict, each replaced by what the data name in its place:
    #: ``old`` (its name), ``new`` (the effects named in its place), ``gain_pct`` (held-out RMS gain of the
    #: model without it over the model with it, both with what the data name; or over the effects named
    #: without it fitted with it kept, where that is better and physically possible), ``old_parameters`` and
    #: ``or_shape_of`` (the named effect whose other shape makes it redundant, or None when the data predict
    #: better without it). Not in the extended model.
    replaced: list[dict[str, Any]] = field(default_factory=list)
    #: Named effects that a named effect's freer shape could also explain, without evidence of that shape:
    #: kept (the simpler explanation), each with the keys of ``ambiguous``; more travel of the link decides.
    #: With ``alike``: another cause of the same shape over this travel (a spring for a load) predicts the data
    #: as well in the named effect's place; with ``beside`` (the named effect) as well, a cause of that kind
    #: that the data neither ask for nor refuse beside it, with its fitted ``parameters``
    #: (:func:`undecided_sentence` says each in words).
    undecided: list[dict[str, Any]] = field(default_factory=list)
    #: Runs whose torque reading has the other sign than the toolkit's convention (:func:`reversed_sign`), each
    #: with ``dataset`` and ``why``: the rest of the diagnosis is of those runs with the torque turned over.
    sign_reversed: list[dict[str, str]] = field(default_factory=list)

    def contribution(self, ctx: Context, channel: str, only: str | None = None) -> np.ndarray:
        """What the named effects (or only the effect ``only``) add to a channel of ``ctx`` [Nm], full length, as
        the extended model carries them (:meth:`~iiwa_ident.diagnose.CandidateEffect.carried`)."""
        total = np.zeros_like(ctx.t)
        for cand, sl in zip(self.selection.selected, self.selection.slices):
            if only is None or cand.name == only:
                total = total + contribution(cand, cand.carried(self.selection.coef[sl]), ctx).get(channel, 0.0)
        return total

    def residual_after(self, ctx: Context, channel: str) -> np.ndarray:
        """The channel's residual with the named effects added to the model (in-sample) [Nm]."""
        return ctx.residual[channel] - self.contribution(ctx, channel)

    @property
    def unexplained_channels(self) -> list[ChannelReport]:
        """Channels the model with the named effects does not explain: their residual fails the tests that judge the
        model and is above the sensor noise (:attr:`~iiwa_ident.diagnose.ChannelComparison.explained`);
        what is left there is not in the library or not in its shape."""
        return [c for c in self.channels if c.after is not None and not c.after.explained]

    def effect(self, name: str) -> EffectReport | None:
        """The named effect ``name``, or None."""
        return next((e for e in self.effects if e.name == name), None)

    def as_json(self) -> dict[str, Any]:
        """The ``--json`` document."""
        datasets: dict[str, dict[str, Any]] = {}
        for c in self.channels:
            d = datasets.setdefault(c.dataset, {"file": c.dataset, "experiment": c.experiment})
            key = {"link": "ext_torque_error", "command": "command_error"}[c.channel]
            d[f"{key}_rms_before"] = c.rms_before
            d[f"{key}_rms_after"] = c.rms_after
            d[f"{key}_gain_pct"] = c.gain_pct
            for when, cmp in (("before", c.before), ("after", c.after)):
                if cmp is not None:
                    d[f"{key}_fit_pct_{when}"] = cmp.fit_pct
                    d[f"{key}_tests_passed_{when}"] = cmp.passed
                    d[f"{key}_tests_{when}"] = cmp.tests.summary()
        return {
            "explained": self.explained,
            "sign_reversed": self.sign_reversed,
            "unexplained_channels": [f"{c.dataset}/{c.channel}" for c in self.unexplained_channels],
            "effects": [e.as_json() for e in self.effects],
            "suspects": self.suspects,
            "ambiguous": self.ambiguous,
            "replaced": self.replaced,
            "undecided": self.undecided,
            "model_out": self.model_out,
            "datasets": list(datasets.values()),
            "tried": [{"step": s.step, "name": s.name, "gain": s.gain, "delta_bic": s.delta_bic,
                       "confidence": s.confidence, "accepted": s.accepted} for s in self.selection.steps],
        }

    def summary(self) -> str:
        """Readable summary for the terminal."""
        lines = []
        for r in self.sign_reversed:
            lines.append(f"the torque's sign: {r['dataset']}: {r['why']} (diagnosed below with the torque turned over)")
        for rep in self.replaced:
            old = ", ".join(f"{k} = {v:.6g}" for k, v in rep["old_parameters"].items())
            why = (f"is part of {r['or_shape_of']} in another shape: beyond that shape it adds nothing on held-out "
                   f"data" if r["or_shape_of"] else f"is contradicted by the data: without it the held-out RMS is "
                   f"{r['gain_pct']:.1f} % lower")
            lines.append(f"replaced: {r['old']} -> {' + '.join(r['new'])} (the model's {r['old']}, {old}, {why})")
        if self.explained:
            lines.append("the model explains the data: no candidate effect reduces the held-out residual enough, "
                         "and every channel's residual passes its tests")
        elif not self.effects and not self.suspects and not self.ambiguous and not self.replaced \
                and not self.unexplained_channels:
            lines.append("with the torque turned over the model explains the data: no candidate effect reduces the "
                         "held-out residual enough, and every channel's residual passes its tests")
        elif not self.effects and not self.suspects and not self.ambiguous and not self.replaced:
            lines.append("the model does not explain the data: no candidate effect reduces the held-out residual "
                         "enough, yet the residual fails its tests on " + _channel_list(self.unexplained_channels)
                         + " (what is left is not an effect of the library, or not in its shape)")
        elif self.effects:
            lines.append(f"named {len(self.effects)} effect(s):")
            for e in self.effects:
                lines += _effect_lines(e)
        for x in self.ambiguous:
            lines.append(f"  not named: {x['name']} (held-out gain {x['gain_pct']:.0f} %) or the other shape of "
                         f"{x['or_shape_of']}: the data do not decide between them (beyond that shape it gains "
                         f"{x['gain_beyond_pct']:.1f} %)")
        for x in self.undecided:
            lines.append(f"  undecided: {undecided_sentence(x)}")
        if self.effects and self.unexplained_channels:
            lines.append("  with them the residual still fails its tests on " + _channel_list(self.unexplained_channels)
                         + ": the extended model does not explain everything")
        if self.suspects:
            lines.append("the model does not explain the data: " + ("besides, " if self.effects else "")
                         + "these would remove a large part of the residual but failed a test (not named):")
            for x in self.suspects:
                lines.append(f"  {x['name']:<24} would remove {100 * x['gain']:.0f} % of the held-out residual "
                             f"({x['band']} band) but {x['failed']}")
        lines.append("")
        lines.append(f"  {'dataset':<28}{'channel':<10}{'RMS before [Nm]':>16}{'after [Nm]':>12}{'gain':>8}"
                     f"{'fit before':>12}{'after':>8}  residual tests before -> after")
        for c in self.channels:
            fits = tests = ""
            if c.before is not None and c.after is not None:
                fits = f"{c.before.fit_pct:>11.1f}%{c.after.fit_pct:>7.1f}%"
                tests = f"  {c.before.verdict} -> {c.after.verdict}"
            lines.append(f"  {c.dataset[:27]:<28}{c.channel:<10}{c.rms_before:>16.4f}{c.rms_after:>12.4f}"
                         f"{c.gain_pct:>7.1f}%{fits}{tests}")
        lines.append("  (link: error of a model-based external-torque estimate; command: joint-torque response "
                     "the model cannot predict from the command; RMS held out, fit % and residual tests in-sample; '-': not "
                     "judged, too short or a command computed from the measurements)")
        return "\n".join(lines)


def _effect_lines(e: EffectReport) -> list[str]:
    """The summary's lines of one named effect: its parameters, held-out gain and what its detail says."""
    lines: list[str] = []
    pars = ", ".join(f"{k} = {v:.6g}" for k, v in e.parameters.items())
    lines.append(f"  {e.name:<24} confidence {e.confidence:.4f}  {pars}")
    lines.append(f"  {'':<24} held-out RMS {e.rms_before:.4f} -> {e.rms_after:.4f} Nm "
                 f"({e.gain_pct:.1f}% lower)")
    if "shape_fit" in e.detail:
        lines.append(f"  {'':<24} its shape reaches {100 * e.detail['shape_fit']:.1f} % of the reduction "
                     f"of {e.detail['free_shape']}; those remove {e.detail['shape_left_pct']:.0f} % "
                     f"of what it leaves ({e.detail['shape_left_in']})")
    if "other_shape" in e.detail:
        lines.append(f"  {'':<24} in another shape than the model's: {e.detail['other_shape']}")
    if "one_speed_rad_s" in e.detail:
        lines.append(f"  {'':<24} the data move at one speed ({e.detail['one_speed_rad_s']:.2g} rad/s): the "
                     f"friction at that speed, as Coulomb; runs at other speeds separate the viscous part")
    if "log_only" in e.detail:
        others = ", ".join(f"{k[4:-8].replace('_', ' ')} x{v:.3g}" for k, v in e.detail.items()
                           if k.startswith("sse_") and k.endswith("_vs_best") and v > 1.0)
        on = f" on {e.detail['own_run']}, whose filter predicts the other runs best" \
            if "own_run" in e.detail else ""
        lines.append(f"  {'':<24} shape: {e.detail['shape']} (residual SSE of the others{on}: {others}); "
                     f"{e.detail['log_only']}")
    if e.detail.get("against_description"):
        lines.append(f"  {'':<24} against the robot's description: {e.detail['against_description']}")
    if e.detail.get("payload"):
        lines.append(f"  {'':<24} {e.detail['payload']}")
    if e.detail.get("across_runs_pct"):
        worse = [r for r, g in e.detail["across_runs_pct"].items() if g < -ACROSS_RUNS_WORSE_PCT]
        gains = ", ".join(f"{r} {g:.0f} %" for r, g in e.detail["across_runs_pct"].items())
        # Each of two runs is predicted from the other alone, whose fit may not fix the effect.
        why = "not a cause every run shows" if len(e.detail["across_runs_pct"]) > 2 else \
            "from the other run alone, which may not fix it"
        lines.append(f"  {'':<24} each run predicted from the others, RMS lower with it: {gains}"
                     + (f" (worse on {', '.join(worse)}: {why})" if worse else ""))
    return lines


def undecided_sentence(x: dict[str, Any]) -> str:
    """What one entry of :attr:`Diagnosis.undecided` says, in words (the summary, the pipeline's headline)."""
    if x.get("beside"):
        pars = ", ".join(f"{k} = {v:.3g}" for k, v in x["parameters"].items())
        return (f"{x['beside']} alone, or with a {x['name']} beside it ({pars}; held-out {x['gain_pct']:.1f} % "
                f"lower): over this travel the data do not decide; a longer travel of the link does")
    if x.get("alike"):
        return (f"{x['name']} or {x['or_shape_of']}: over this travel both predict the held-out data alike "
                f"({x['name']} {x['gain_beyond_pct']:.1f} % lower); {x['name']} kept, a longer travel of the link "
                f"decides")
    return (f"{x['name']} or {x['or_shape_of']} in {x['free_shape']}: both predict the held-out data alike (beyond "
            f"that shape it gains {x['gain_beyond_pct']:.1f} %); kept as the simpler explanation, a longer travel of "
            f"the link decides")


def _channel_list(channels: Sequence[ChannelReport]) -> str:
    """``dataset/channel`` of each, joined (the first three, then a count)."""
    names = [f"{c.dataset}/{c.channel}" for c in channels]
    return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def reversed_sign(dataset: Dataset, model: JointModel, logged_rms: float | None = None) -> str | None:
    """Why ``dataset``'s torque reading has the other sign than the toolkit's convention, or None.

    First the check ``import`` makes (:func:`~iiwa_ident.datasets.torque_sign_problem`: the description's gravity,
    or the friction, read with a factor near -1), so the two say the same; where it does not decide, the model:
    the run reads the other way round when the model predicts it with the torque turned over at most
    :data:`SIGN_RMS_RATIO` times the residual RMS as logged (a scale near -1); ``logged_rms``: that RMS [Nm] where
    the caller has it (:func:`_channels_rms`).
    """
    why = torque_sign_problem(dataset)
    if why is not None or not dataset.has("tau_j"):
        return why
    try:
        logged = _rms([np.array([r.rms_nm for r in residual_rms([dataset], model)])]) if logged_rms is None \
            else logged_rms
        turned = _rms([np.array([r.rms_nm for r in residual_rms([_turned_over(dataset)], model)])])
    except IiwaIdentError:
        return None
    if logged > 0 and turned <= SIGN_RMS_RATIO * logged:
        return (f"tau_j reads the other way round: the model predicts it at {turned:.3g} Nm RMS turned over against "
                f"{logged:.3g} Nm as logged (a torque scale of -1); import the log with --scale tau_j=-1")
    return None


def _channels_rms(ctx: Context) -> float:
    """The RMS over a context's channels of their residual RMS [Nm] (as :func:`reversed_sign` judges it)."""
    return _rms([np.array([_rms([ctx.residual[ch][ctx.masks[ch]]]) for ch in ctx.channels])])


def _turned_over(dataset: Dataset) -> Dataset:
    """``dataset`` with its torque reading turned over (what ``import --scale tau_j=-1`` gives)."""
    return dataclasses.replace(dataset, signals={**dataset.signals, "tau_j": -np.asarray(dataset["tau_j"], float)})


def _known_effects(model: JointModel, contexts: list[Context]) -> dict[str, tuple[CandidateEffect, np.ndarray]]:
    """Subtract the model's own extra effects from the residuals; return them by name with coefficients. A filter
    before the log goes into the contexts first: the other effects' torques reach the log through it."""
    for entry in model.effects:
        if entry["name"] == "torque_log_filter":
            lf = TorqueLogFilter({k: v for k, v in entry.items() if k != "name"}, "effects.torque_log_filter")
            for ctx in contexts:
                ctx.log_filter, ctx.effects_filtered = lf, True
    known = {}
    for entry in model.effects:
        name = entry["name"]
        if name not in CANDIDATES or name == "input_delay":
            continue
        cand = make_candidate(name)
        cand.n_datasets = len(contexts)
        coef = cand.from_values({k: v for k, v in entry.items() if k != "name"})
        if coef is None:
            continue
        for ctx in contexts:
            for ch, v in contribution(cand, coef, ctx).items():
                ctx.residual[ch] = ctx.residual[ch] - v
                ctx.with_effects[ch] = ctx.with_effects.get(ch, ctx.predicted[ch]) + v
        known[name] = (cand, coef)
    return known


class ChannelRms(NamedTuple):
    """One residual channel of one dataset as a model predicts it (:func:`residual_rms`)."""

    dataset: str
    channel: str
    rms_nm: float


def residual_rms(datasets: Sequence[Dataset], model: JointModel) -> list[ChannelRms]:
    """How well ``model`` (with its effects and ripple table) predicts each dataset: the RMS [Nm] per residual
    channel, over the samples the diagnosis uses (nothing is fitted)."""
    _, contexts, _ = _residuals(datasets, model)
    return [ChannelRms(ctx.name, ch, _rms([ctx.residual[ch][ctx.masks[ch]]]))
            for ctx in contexts for ch in ctx.channels]


class _Residuals(NamedTuple):
    """The model as it predicts, each dataset's context, and the effects the model already holds."""

    work: JointModel
    contexts: list[Context]
    known: dict[str, tuple[CandidateEffect, np.ndarray]]


def _residuals(datasets: Sequence[Dataset], model: JointModel
               ) -> _Residuals:
    """The model as it predicts (an extra-delay effect in its total delay), each dataset's context with the
    residual left by the model and its effects, and those effects (:func:`_known_effects`)."""
    check_model_matches(model, datasets)
    work = copy.deepcopy(model)
    extra = sum(float(e.get("extra_s", 0.0)) for e in work.effects if e.get("name") == "input_delay")
    work.parameters["Td"].value += extra
    contexts = [build_context(ds, work, i) for i, ds in enumerate(datasets)]
    return _Residuals(work, contexts, _known_effects(work, contexts))


def _blocks(contexts: list[Context]) -> list[Block]:
    blocks = []
    for ctx in contexts:
        for ch in ctx.channels:
            mask = ctx.masks[ch].copy()
            if ch == "link":
                step = max(1, int(1.0 / (ctx.dt * _LINK_POINTS_PER_CUTOFF * ctx.cutoff_hz)))
                keep = np.zeros_like(mask)
                keep[::step] = True
                mask &= keep
            r = ctx.residual[ch][mask]
            rms = float(np.sqrt(np.mean(r ** 2))) if len(r) else 0.0
            if len(r) < 10 * 5 or rms <= 0:
                continue
            blocks.append(Block(ctx, ch, mask, 1.0 / rms))
    return blocks


def _rms(parts: list[np.ndarray]) -> float:
    x = np.concatenate(parts) if parts else np.zeros(1)
    return float(np.sqrt(np.mean(x ** 2)))


def diagnose(datasets: Sequence[Dataset], model: JointModel, candidates: Sequence[str] | None = None,
             **selection_options: Any) -> Diagnosis:
    """Diagnose what ``model`` gets wrong on ``datasets`` and extend it.

    Parameters
    ----------
    datasets : list of Dataset
        Measured runs of one joint (any experiment of format v1).
    model : JointModel
        The model to check (e.g. from ``fit``, or Table I).
    candidates : list of str, optional
        Names of the effects to test (default: the whole library, :data:`CANDIDATES`).
    **selection_options
        ``min_gain``, ``min_confidence``, ``max_effects`` of
        :func:`~iiwa_ident.diagnose._select.select_effects`.

    Returns
    -------
    Diagnosis

    Raises
    ------
    IiwaIdentError
        No dataset, datasets of different joints, or nothing usable to compare.
    """
    if not datasets:
        raise IiwaIdentError("diagnose: no dataset given")
    joints = {ds.joint for ds in datasets}
    if len(joints) > 1:
        raise IiwaIdentError(f"diagnose: the datasets are from different joints ({sorted(joints)})")
    original, given = model, list(datasets)
    # The sign before anything: a reversed reading makes every other effect (a load of twice the gravity at
    # phase pi, a friction that pushes) an artefact of it.
    sign_reversed = []
    turned = list(datasets)
    work, contexts, known = _residuals(datasets, model)
    for i, (ds, ctx) in enumerate(zip(datasets, contexts)):
        why = reversed_sign(ds, model, _channels_rms(ctx))
        if why is not None:
            sign_reversed.append({"dataset": str(ds.path.name) if ds.path else f"dataset {i}", "why": why})
            turned[i] = _turned_over(ds)
    if sign_reversed:
        datasets = turned
        work, contexts, known = _residuals(datasets, model)
    tested = {(ctx.index, ch): channel_comparison(ctx, ch, ctx.residual[ch]) for ctx in contexts for ch in ctx.channels}
    blocks = _blocks(contexts)
    if not blocks:
        files = ", ".join(str(ds.path or f"dataset {i}") for i, ds in enumerate(datasets))
        raise IiwaIdentError(f"{files}: nothing to compare (too short, or contact without a measured external torque)")
    ys = ys0 = [b.ctx.residual[b.channel][b.mask] * b.weight for b in blocks]
    names = list(candidates) if candidates is not None else list(CANDIDATES)
    ranges = physical_ranges(model)
    for cand, _ in known.values():
        cand.ranges = ranges
    entry_filters = [ctx.log_filter for ctx in contexts]
    named = _named(names, work, model, known, blocks, ys, selection_options, ranges)
    # The filters before the log the contexts carry for the outcome kept (a named one passes the others).
    st = _Search(names=names, work=work, blocks=blocks, contexts=contexts, options=selection_options, ranges=ranges,
                 entry_filters=entry_filters, model=model, known=known, ys=ys, named=named,
                 named_filters=[ctx.log_filter for ctx in contexts])
    replaced = _replace_own_effects(st)
    named, ys = st.named, st.ys
    sel, effects, extended, after = named.selection, named.effects, named.extended, named.after
    before = cv_residuals([np.zeros((len(y), 0)) for y in ys0], ys0)
    by_run = _across_runs(sel, blocks, ys)
    for e in effects:
        gains = by_run.get(e.name)
        if gains is not None:
            e.detail["across_runs_pct"] = gains
    suspects = _suspects(sel)
    if replaced:
        extended.description += " | replaced: " + ", ".join(f"{r['old']} -> {' + '.join(r['new'])}"
                                                              for r in replaced)
    diag = Diagnosis(explained=False, effects=effects,
                     channels=[], model=original, extended=extended, replaced=replaced, contexts=contexts,
                     blocks=blocks, selection=sel,
                     heldout_before=before, heldout_after=after, suspects=suspects, ambiguous=named.ambiguous,
                     undecided=named.undecided, sign_reversed=sign_reversed)
    for b, rb, ra in zip(blocks, before, after):
        key = (b.ctx.index, b.channel)
        changed = bool(effects) or bool(replaced)
        diag.channels.append(ChannelReport(
            dataset=b.ctx.name, experiment=b.ctx.experiment, channel=b.channel, rms_before=_rms([rb / b.weight]),
            rms_after=_rms([ra / b.weight]), before=tested[key],
            after=(channel_comparison(b.ctx, b.channel, diag.residual_after(b.ctx, b.channel)) if changed
                   else tested[key])))
    # One meaning of "explained" everywhere: nothing left for the library to name, and every channel's
    # residual passes the tests that judge the model (or is not judged).
    diag.explained = not effects and not suspects and not named.ambiguous and not replaced and not sign_reversed \
        and not diag.unexplained_channels
    carried = _not_carried(diag, datasets)
    if carried:
        # Named again without them: the others' fit must not lean on a column the model cannot carry.
        again = diagnose(given, original, [n for n in names if n not in carried], **selection_options)
        again.suspects = _carried_suspects(carried) + again.suspects
        again.explained = False
        return again
    return diag


@dataclass(kw_only=True)
class _Search:
    """The diagnosis while the model's own effects are judged (:func:`_replace_own_effects`): what stays, and
    the outcome kept so far (the model, its known effects, the residuals, the naming and its filters)."""

    names: list[str]
    work: JointModel
    blocks: list[Block]
    contexts: list[Context]
    options: dict[str, Any]
    ranges: PhysicalRanges | None
    entry_filters: list[Any]
    model: JointModel
    known: dict
    ys: list[np.ndarray]
    named: _Naming
    named_filters: list[Any]


def _replace_own_effects(st: _Search) -> list[dict[str, Any]]:
    """The model without one of its effects (then without all of them: a fit can take one effect for two
    others), judged like the model: when the data then predict the held-out runs better, or a named
    effect's other shape makes the effect redundant, that outcome is kept (in ``st``); each effect left out is
    replaced by what the data name in its place (the entries of :attr:`Diagnosis.replaced`), or refitted where
    they name it again."""
    replaced: list[dict[str, Any]] = []
    for drop in [[n] for n in st.known] + [None]:
        if drop is None:  # all the effects the model still has, when more than one is left
            drop = list(st.known) if len(st.known) > 1 else []
        if drop:
            replaced += _without(st, drop)
    return replaced


def _without(st: _Search, drop: list[str]) -> list[dict[str, Any]]:
    """The naming without the model's effects ``drop``; kept in ``st`` where it is better, with the entries
    of :attr:`Diagnosis.replaced` it makes (none where it is not kept)."""
    blocks, contexts, known, named = st.blocks, st.contexts, st.known, st.named
    back: dict[int, dict[str, np.ndarray]] = {ctx.index: {} for ctx in contexts}
    for n in drop:
        for ctx in contexts:
            cand, coef = known[n]
            for ch, v in contribution(cand, coef, ctx).items():
                back[ctx.index][ch] = back[ctx.index].get(ch, 0.0) + v
    ys_b = [y + back[b.ctx.index].get(b.channel, np.zeros_like(b.ctx.t))[b.mask] * b.weight
            for y, b in zip(st.ys, blocks)]
    others = {k: v for k, v in known.items() if k not in drop}
    without = copy.deepcopy(st.model)
    without.effects = [e for e in without.effects if e.get("name") not in drop]
    _carry(contexts, st.entry_filters)
    trial = _named(st.names, st.work, without, others, blocks, ys_b, st.options, st.ranges)
    trial_filters = [ctx.log_filter for ctx in contexts]
    renamed = {c.name for c in trial.selection.selected} & set(drop)
    sse_b, sse = trial.heldout_sse, named.heldout_sse
    if not renamed >= set(drop) and trial.selection.selected:
        # An effect left out: the gain must come from leaving it out, not from what the trial names besides
        # (those effects fitted with it kept are the reference too, where they are physically possible).
        cols = trial.selection.columns(blocks)
        coef = np.linalg.lstsq(np.vstack(cols), np.concatenate(st.ys), rcond=None)[0]
        if all(c.plausible(c.total(coef[sl])) for c, sl in zip(trial.selection.selected, trial.selection.slices)):
            keep = cv_residuals(cols, st.ys)
            sse = min(sse, _sse(keep, range(len(keep))))
    _carry(contexts, st.named_filters)
    # Better held out; or not worse with no effect the model's selection did not name anyway (the dropped
    # effect is not needed beside them).
    better = sse_b <= (1.0 - MIN_GAIN) * sse or \
        (sse_b <= sse and {c.name for c in trial.selection.selected} <= {c.name for c in named.selection.selected})
    shape_of = None if better or renamed or len(drop) > 1 else \
        _redundant_beside(known[drop[0]][0], named.selection, named.effects, blocks, ys_b)
    if not trial.effects or not (better or shape_of):
        return []
    named_before = {e.name for e in named.effects}
    new = [shape_of] if shape_of is not None else \
        [e.name for e in trial.effects if e.name not in named_before] or [e.name for e in trial.effects]
    replaced = [{"old": n, "new": [x for x in new if x != n], "gain_pct": 100.0 * (1.0 - math.sqrt(sse_b / sse)),
                 "old_parameters": known[n][0].parameters(known[n][1]), "or_shape_of": shape_of}
                for n in drop if n not in renamed]
    # What the data do not decide about an effect of the model refitted whole stays undecided (a load beyond
    # the described gravity that a spring predicts alike is still so when the whole load is refitted).
    kept = [u for u in named.undecided if u.get("alike") and u["name"] in renamed
            and not any(x["name"] == u["name"] and x["or_shape_of"] == u["or_shape_of"] for x in trial.undecided)]
    trial.undecided = trial.undecided + kept
    st.named, st.named_filters = trial, trial_filters
    _carry(contexts, st.named_filters)
    st.known, st.model, st.ys = others, without, ys_b
    for ctx in contexts:
        for ch, v in back[ctx.index].items():
            ctx.residual[ch] = ctx.residual[ch] + v
    return replaced


#: Most a model's simulated prediction of the diagnosed runs may exceed the diagnosis's own fit of them
#: (relative to the residual before; the effects are linearised columns, the model simulates them whole).
CARRIED_TOLERANCE = 0.25


def _not_carried(diag: Diagnosis, datasets: Sequence[Dataset]) -> dict[str, tuple[float, float]]:
    """The named effects the extended model does not carry as the diagnosis fitted them: where the model, simulated
    again, predicts the runs worse than the fit by more than :data:`CARRIED_TOLERANCE` of the residual before,
    the effect whose leaving out of the model predicts them better; by name, the relative SSE with and without
    it (the one that predicts best when left out; none where leaving out none predicts better)."""
    if not diag.effects:
        return {}
    base = {(n, ch): r for n, ch, r in residual_rms(datasets, diag.model)}

    def score(model: JointModel) -> float:
        return sum((r / base[n, ch]) ** 2 for n, ch, r in residual_rms(datasets, model) if base[n, ch] > 0)

    fitted = sum(float(np.mean(diag.residual_after(ctx, ch)[ctx.masks[ch]] ** 2)) / base[ctx.name, ch] ** 2
                 for ctx in diag.contexts for ch in ctx.channels if base[ctx.name, ch] > 0)
    simulated = score(diag.extended)
    if math.sqrt(simulated) <= math.sqrt(fitted) + CARRIED_TOLERANCE * math.sqrt(len(base)):
        return {}
    # The one whose leaving out predicts best (the others' fit leans on it: it may be what spoils them).
    alone = {e.name: score(_left_out(diag.extended, diag.model, e.name)) for e in diag.effects}
    worst = min(alone, key=lambda n: alone[n])
    return {worst: (simulated / len(base), alone[worst] / len(base))} if alone[worst] < simulated else {}


def _left_out(extended: JointModel, model: JointModel, name: str) -> JointModel:
    """``extended`` with the effect ``name`` as ``model`` has it (or without it)."""
    out = copy.deepcopy(extended)
    if name == "transmission_ripple":
        out.ripple = copy.deepcopy(model.ripple)
    elif name == "model_parameters":
        for k, p in model.parameters.items():
            if k != "Td":
                out.parameters[k] = copy.deepcopy(p)
    else:
        out.effects = [e for e in out.effects if e.get("name") != name] + \
            [copy.deepcopy(e) for e in model.effects if e.get("name") == name]
    return out


def _carried_suspects(carried: dict[str, tuple[float, float]]) -> list[dict[str, Any]]:
    """Suspects of :func:`_not_carried`'s effects, with the keys of :func:`_suspects`."""
    return [{"name": n, "gain": 0.0, "band": "full", "confidence": 0.0, "delta_bic": 0.0,
             "failed": f"the model extended by it predicts the runs worse than without it (relative SSE {w:.3g} "
                       f"against {wo:.3g}): its fit is not the effect the model simulates"}
            for n, (w, wo) in carried.items()]


def _carry(contexts: list[Context], filters: list[Any]) -> None:
    """The contexts carry ``filters`` before the log (one each, or None): an outcome's, or the model's own."""
    for ctx, lf in zip(contexts, filters):
        ctx.log_filter = lf


def _named(names: list[str], work: JointModel, model: JointModel, known: dict, blocks: list[Block],
           ys: list[np.ndarray], selection_options: dict[str, Any], ranges: PhysicalRanges | None = None
           ) -> _Naming:
    """:func:`_selected`, named again without the effects another one's shape makes ambiguous; those, and the
    undecided ones (:func:`_ambiguous`)."""
    ambiguous: list[dict[str, Any]] = []
    left = list(names)
    contexts = list({b.ctx.index: b.ctx for b in blocks}.values())
    carried = [ctx.log_filter for ctx in contexts]
    while True:
        # Each naming starts from the model's own filter (a filter named in the last one is named again or not).
        _carry(contexts, carried)
        named = _selected(left, work, model, known, blocks, ys, selection_options, ranges)
        more, undecided = _ambiguous(named.selection, named.effects, blocks, ys)
        if not more:
            break
        # Named again without them: the others' coefficients and gains must not lean on them (and what takes
        # their place is judged alike: a spring for an offset a load's other shape explains).
        ambiguous += more
        left = [n for n in left if n not in {a["name"] for a in more}]
    named.ambiguous = ambiguous
    named.undecided = undecided + _alike(named.selection, named.effects, left, known, blocks, ys, named.after, ranges)
    return named


def _alike(sel: Selection, effects: list[EffectReport], names: list[str], known: dict, blocks: list[Block],
           ys: list[np.ndarray], after: list[np.ndarray], ranges: PhysicalRanges | None) -> list[dict[str, Any]]:
    """Named effects that another cause of the same shape over this travel (:attr:`CandidateEffect.alike`), not
    named, predicts as well in their place: undecided, with the keys of :attr:`Diagnosis.undecided`
    (``free_shape``: that cause's summary). The other cause must be physically possible there (a load on a
    vertical axis is not) and its held-out SSE, on the blocks the named effect acts on, within the selection's
    least gain of the named effect's."""
    reports = {e.name: e for e in effects}
    selected = {c.name for c in sel.selected}
    out = []
    for cand in sel.selected:
        if cand.name not in reports or sel.band.get(cand.name) not in BANDS:
            continue
        acts = _acting(cand, blocks)
        for other_name in cand.alike:
            if other_name in selected or other_name not in names or not acts:
                continue
            other = make_candidate(other_name)
            other.ranges = ranges
            if other_name in known:
                other.base_coef = known[other_name][1]
            if not other.prepare(blocks, ys):
                continue
            other_cols = block_columns(blocks, other.columns, other.n_columns())
            sse_named = _sse(after, acts)
            # In its place: the other cause predicts the held-out data as well.
            cols = [np.hstack([a, b]) for a, b in zip(sel.columns(blocks, skip=cand.name), other_cols)]
            own = np.linalg.lstsq(np.vstack(cols), np.concatenate(ys), rcond=None)[0][-other.n_columns():]
            if other.plausible(other.total(own)) and other.relevant(own):
                sse_other = _sse(cv_residuals(cols, ys), acts)
                if sse_other <= (1.0 + MIN_GAIN) * sse_named:
                    out.append({"name": cand.name, "or_shape_of": other_name, "gain_pct": reports[cand.name].gain_pct,
                                "gain_beyond_pct": 100.0 * (1.0 - sse_named / sse_other) if sse_other > 0 else 0.0,
                                "free_shape": f"its own shape ({other.summary})", "alike": True})
                    continue
            # Beside it: the other cause fits a physically possible torque larger than the noise, which the held-out
            # data neither ask for nor refuse (a spring beside a load over a travel of a radian).
            cols = [np.hstack([a, b]) for a, b in zip(sel.columns(blocks), other_cols)]
            coef = np.linalg.lstsq(np.vstack(cols), np.concatenate(ys), rcond=None)[0]
            own = coef[-other.n_columns():]
            if not (other.plausible(other.total(own)) and other.relevant(own)):
                continue
            left = [(y - X @ coef) / b.weight for y, X, b in zip(ys, cols, blocks)]
            size = _rms([other_cols[i] @ own / blocks[i].weight for i in acts])
            if size >= NOISE_FACTOR * noise_floor([left[i] for i in acts]):
                beside = 1.0 - _sse(cv_residuals(cols, ys), acts) / sse_named if sse_named > 0 else 0.0
                out.append({"name": other_name, "beside": cand.name, "or_shape_of": cand.name,
                            "gain_pct": 100.0 * beside,
                            "parameters": other.parameters(own), "alike": True})
    return out


def _selected(names: list[str], work: JointModel, model: JointModel, known: dict, blocks: list[Block],
              ys: list[np.ndarray], selection_options: dict[str, Any], ranges: PhysicalRanges | None = None,
              first: Sequence[tuple[CandidateEffect, Step]] = (), refine: bool = True
              ) -> _Naming:
    """The selection among the candidates ``names``, its effect reports, the extended model and the held-out
    residuals with the named effects; ``ranges``: what the robot's description makes physically possible;
    ``first``: effects named before the search (:func:`~iiwa_ident.diagnose._select.select_effects`)."""
    cands = [make_candidate(n) for n in names]
    for c in cands:
        c.ranges = ranges
        if hasattr(c, "base_table"):
            c.base_table = work.ripple
        if c.name in known:
            c.base_coef = known[c.name][1]
    sel = select_effects(blocks, ys, cands, **selection_options, first=first)
    contexts = list({b.ctx.index: b.ctx for b in blocks}.values())
    held = first[0][0] if refine and first else None
    if isinstance(held, TorqueLogFilterCandidate) and contexts[0].log_filter is not None:
        _refine_log_filter(sel, held, blocks, ys)
    # A named effect whose shape holds a simpler one's must still be more than that in the final fit: a spring
    # that later effects turned into an offset (a slope of nothing or of the wrong sign) is not named, and the
    # rest named again without it (the offset then stands on its own).
    given = {c.name for c, _ in first}
    stale = [c.name for c, sl in zip(sel.selected, sel.slices) if c.contains and c.name not in given and
             c.name not in sel.other_shape and not (c.plausible(c.total(sel.coef[sl])) and c.relevant(sel.coef[sl]))]
    if stale:
        return _selected([n for n in names if n not in stale], work, model, known, blocks, ys, selection_options,
                         ranges, first, refine)
    again = _named_through_filter(sel, names, work, model, known, blocks, ys, selection_options, ranges)
    if again is not None:
        return again
    before = cv_residuals([np.zeros((len(y), 0)) for y in ys], ys)
    after = cv_residuals(sel.columns(blocks), ys) if sel.selected else list(before)
    extended = copy.deepcopy(model)
    extended.parameters["Td"].value = work.parameters["Td"].value
    extended.effects = [e for e in extended.effects if e.get("name") != "input_delay"]
    effects = []
    cov: np.ndarray | None = None
    for cand, sl in zip(sel.selected, sel.slices):
        coef = sel.coef[sl]
        without = cv_residuals(sel.columns(blocks, skip=cand.name), ys)
        acts = _acting(cand, blocks)
        rb = _rms([without[i] / blocks[i].weight for i in acts])
        ra = _rms([after[i] / blocks[i].weight for i in acts])
        total = cand.total(coef)
        cand.extend(extended, total)
        params = cand.parameters(total)
        shape = _shape_fit(cand, blocks, ys, sel, without, after, acts)
        physical: dict[str, Any] = {}
        if ranges is not None and cand.name in ("position_dependent_load", "model_parameters"):
            physical["against_description"] = against_description(
                ranges, load_nm=params.get("amplitude_nm"), Jl_kgm2=params.get("Jl_kgm2"))
        if ranges is not None and cand.name == "position_dependent_load" and ranges.load_described_nm > 0:
            # The extra gravity as the payload (or centre-of-mass shift) users of a load-data calibration ask for.
            if cov is None:
                cov = _coefficient_cov(sel, blocks, ys)
            pay = payload_of_load(ranges, params["amplitude_nm"], params["phase_rad"], cov[sl][:, sl][:2, :2])
            physical.update(payload=pay.text(), payload_kg=pay.mass_kg, payload_std_kg=pay.mass_std_kg,
                            payload_lever_m=pay.lever_m, com_moment_kgm=pay.moment_kgm,
                            com_moment_std_kgm=pay.moment_std_kgm)
        effects.append(EffectReport(name=cand.name, confidence=sel.confidence[cand.name], parameters=params,
                                    rms_before=rb, rms_after=ra,
                                    gain_pct=100.0 * (1 - ra / rb) if rb > 0 else 0.0,
                                    detail={**{k: v for k, v in cand.detail.items() if isinstance(v, (int, float, str))},
                                     **physical,
                                     "selected_in": sel.band[cand.name],
                                     **shape,
                                     **({"other_shape": sel.other_shape[cand.name]}
                                        if cand.name in sel.other_shape else {})}))
    if effects:
        extended.description = (extended.description + " | " if extended.description else "") + \
            "extended by diagnose: " + ", ".join(e.name for e in effects)
    return _Naming(sel, effects, extended, after)


def _named_through_filter(sel: Selection, names: list[str], work: JointModel, model: JointModel, known: dict,
                          blocks: list[Block], ys: list[np.ndarray], selection_options: dict[str, Any],
                          ranges: PhysicalRanges | None
                          ) -> _Naming | None:
    """:func:`_selected` again where ``sel`` named a filter before the log (or a delay) and the contexts carry
    none: the filter held whole, every other effect named again with its columns through it; None where that
    does not hold (the contexts and the filter then as they were).

    Of several runs, also through each run's own filter (:func:`_own_filters`), held as it is; the naming kept
    is, of three runs or more, the one that predicts each run best from the others (:func:`_run_sse`), of one
    or two the one with the least held-out residual: one run at one speed does not split a friction into its
    Coulomb and viscous parts, and predicts the other run's speed from an arbitrary split."""
    named_filter = next((c for c in sel.selected if isinstance(c, TorqueLogFilterCandidate)), None)
    contexts = list({b.ctx.index: b.ctx for b in blocks}.values())
    if named_filter is None or any(ctx.log_filter is not None for ctx in contexts):
        return None
    # Named after the others, the filter finds effects fitted to what it explains (a spring to the inertia's
    # torque the log does not show). A refit of the model's own parameters the first pass did not name stays
    # out: beside the filter's column its delay trades with the cut-off.
    chosen = {c.name for c in sel.selected}
    # (named alone or in a pair: "a + b")
    record = next(s for s in sel.steps if s.accepted and named_filter.name in s.name.split(" + "))
    first_shape = _FilterShape.of(named_filter)
    # A delay, the fast band as it is, and the first order of its lag, which attenuates it, lead the others to
    # different fits there: both tried, the one whose naming predicts the held-out data better kept (the shape is
    # searched again once the others are named).
    starts = [first_shape] if first_shape.shape != "pure delay" else \
        [_FilterShape("first order", first_shape.cutoff_hz, 1.0), first_shape]
    names = [n for n in names if n != "model_parameters" or n in chosen]
    if len(contexts) > 1:
        starts += _own_filters(names, work, model, known, blocks, ys, selection_options, ranges)
    best: tuple[float, Any, list[Any]] | None = None
    tried: list[_FilterShape] = []
    for shape in starts:
        if shape.own_run is not None and any(_alike_filter(shape, t) for t in tried):
            continue  # a run's own filter another start reached already
        trial_filter = copy.copy(named_filter)  # the first pass's filter stays as it is
        trial_filter.detail = dict(named_filter.detail)
        trial_filter.set_shape(shape.shape, shape.cutoff_hz, shape.damping)
        if shape.own_run is not None:
            # A run's own filter, held: its shapes compared on that run, not the first pass's comparison.
            trial_filter.detail = {**{k: v for k, v in trial_filter.detail.items() if not k.endswith("_vs_best")},
                                   **shape.own_run}
        for ctx in contexts:
            ctx.log_filter = trial_filter.effect
        again = _selected(names, work, model, known, blocks, ys, selection_options, ranges,
                          first=[(trial_filter, record)], refine=shape.own_run is None)
        # Kept where the filter, whole, still explains the data beside the others: they fit better through it
        # than without it.
        sse_filtered = block_sse(again.selection.columns(blocks, held=1), _without_filter(ys, blocks, trial_filter))[0]
        kept = [ctx.log_filter for ctx in contexts]
        for ctx in contexts:
            ctx.log_filter = None
        trial = again.selection
        tried.append(_FilterShape.of(trial_filter))  # held first: the selection's first
        possible = all(c.plausible(c.total(trial.coef[sl]))
                       for c, sl in zip(trial.selected[1:], trial.slices[1:]) if c.name not in trial.other_shape)
        if possible and sse_filtered < block_sse(again.selection.columns(blocks, held=1), ys)[0]:
            heldout = again.heldout_sse if len(contexts) < 3 else \
                sum(_run_sse(again.selection.columns(blocks, held=1), _without_filter(ys, blocks, trial_filter),
                             blocks).values())
            if best is None or heldout < best[0]:
                best = (heldout, again, kept)
    if best is None:
        return None
    for ctx, f in zip(contexts, best[2]):
        ctx.log_filter = f
    return best[1]


#: A run predicted from the others by at least this much higher RMS with an effect than without it [%] is said
#: to be made worse by it (less is a refit's noise).
ACROSS_RUNS_WORSE_PCT = 1.0


def _across_runs(sel: Selection, blocks: list[Block], ys: list[np.ndarray]) -> dict[str, dict[str, float]]:
    """Per named effect, how much lower each run's RMS is when the run is predicted by the effects fitted on
    the other runs with it than without it [%] (negative: worse with it); empty for one run.

    A cause of the joint lowers every run's prediction; an effect fitted to what one run alone shows does not.
    A filter before the log held whole (the contexts carry it) is judged by the others' columns through it and
    without it."""
    contexts = list({b.ctx.index: b.ctx for b in blocks}.values())
    if len(contexts) < 2:
        return {}
    held = int(bool(sel.selected) and sel.selected[0].name == "torque_log_filter"
               and contexts[0].log_filter is not None)
    through = _without_filter(ys, blocks, sel.selected[0]) if held else ys
    full = _run_sse(sel.columns(blocks, held=held), through, blocks)
    out = {}
    for k, cand in enumerate(sel.selected):
        if k < held:
            carried = [ctx.log_filter for ctx in contexts]
            _carry(contexts, [None] * len(contexts))
            without = _run_sse(sel.columns(blocks, held=held), ys, blocks)
            _carry(contexts, carried)
        else:
            without = _run_sse(sel.columns(blocks, skip=cand.name, held=held), through, blocks)
        out[cand.name] = {ctx.name: 100.0 * (1.0 - math.sqrt(full[ctx.index] / without[ctx.index]))
                          if without[ctx.index] > 0 else 0.0 for ctx in contexts}
    return out


def _run_sse(Xs: list[np.ndarray], ys: list[np.ndarray], blocks: list[Block]) -> dict[int, float]:
    """Per run (context index), the SSE of its blocks predicted by the columns ``Xs`` fitted on the other runs."""
    out = {}
    for index in {b.ctx.index for b in blocks}:
        test = [i for i, b in enumerate(blocks) if b.ctx.index == index]
        train = [i for i, b in enumerate(blocks) if b.ctx.index != index]
        coef = np.linalg.lstsq(np.vstack([Xs[i] for i in train]), np.concatenate([ys[i] for i in train]),
                               rcond=None)[0]
        out[index] = sum(float(np.sum((ys[i] - Xs[i] @ coef) ** 2)) for i in test)
    return out


class _FilterShape(NamedTuple):
    """A filter before the log to start a naming from."""

    shape: str  # one of LOG_FILTER_SHAPES
    cutoff_hz: float
    damping: float
    #: A run's own filter: its shapes compared on that run (:attr:`EffectReport.detail` keys); None otherwise.
    own_run: dict[str, Any] | None = None

    @classmethod
    def of(cls, f: TorqueLogFilterCandidate, own_run: dict[str, Any] | None = None) -> _FilterShape:
        return cls(f.shape, f.cutoff_hz, float(f.effect.values["damping"]), own_run)


def _alike_filter(a: _FilterShape, b: _FilterShape) -> bool:
    """Two filters the same shape within 5 % of the cut-off and 0.05 of the damping."""
    return a.shape == b.shape and abs(math.log(a.cutoff_hz / b.cutoff_hz)) < 0.05 and abs(a.damping - b.damping) < 0.05


def _own_filters(names: list[str], work: JointModel, model: JointModel, known: dict, blocks: list[Block],
                 ys: list[np.ndarray], selection_options: dict[str, Any], ranges: PhysicalRanges | None
                 ) -> list[_FilterShape]:
    """Each run's own filter before the log (shape, cut-off [Hz], damping, and its shapes compared on that run,
    as :attr:`EffectReport.detail` keys): the one its naming alone holds."""
    out = []
    # Without a refit of the model's own parameters: beside a filter its delay trades with the cut-off, and on
    # one run more so.
    names = [n for n in names if n != "model_parameters"]
    for index in sorted({b.ctx.index for b in blocks}):
        idx = [i for i, b in enumerate(blocks) if b.ctx.index == index]
        own = [blocks[i] for i in idx]
        # Once per run and candidates in a diagnosis: a start, not a result (the model without one of its
        # effects, named again, starts from the filter the run named with it).
        key = ("own_filter", tuple(names))
        if key not in own[0].ctx.memo:
            sel = _selected(names, work, model, known, own, [ys[i] for i in idx], selection_options, ranges).selection
            own[0].ctx.log_filter = None
            f = next((c for c in sel.selected if isinstance(c, TorqueLogFilterCandidate)), None)
            compared = {} if f is None else {k: v for k, v in f.detail.items() if k.endswith("_vs_best")}
            own[0].ctx.memo[key] = None if f is None else _FilterShape.of(
                f, {**compared, "shape": f.shape, "own_run": own[0].ctx.name})
        if own[0].ctx.memo[key] is not None:
            out.append(own[0].ctx.memo[key])
    return out


def _without_filter(ys: list[np.ndarray], blocks: list[Block], log_filter: CandidateEffect) -> list[np.ndarray]:
    """The weighted residuals ``ys`` with a filter's whole column (coefficient 1) taken out."""
    return [y - X[:, 0] for y, X in zip(ys, block_columns(blocks, log_filter.columns, 1))]


def _refine_log_filter(sel: Selection, cand: TorqueLogFilterCandidate, blocks: list[Block], ys: list[np.ndarray]
                       ) -> None:
    """The shape and cut-off of the filter ``cand`` the selection holds first, searched again with every named effect's
    columns through it, and the selection's coefficients refitted there: the first pass searched it beside the
    others' fit without the filter, which lends the filter some of their torque's shape.

    Each shape's cut-off is searched within a factor 4 of the first pass's low-frequency lag: the first order, the
    second order at each damping ratio of :data:`LOG_FILTER_DAMPINGS` (the best one refined between its
    neighbours) and the pure delay (the delay at the cut-off's lag). The first order (the delay, where the
    others were named through it) is kept unless another leaves at most :data:`LOG_FILTER_OTHER_SHAPE` of its
    residual with every named effect physically possible through it (the one of least residual that does)."""
    contexts = list({b.ctx.index: b.ctx for b in blocks}.values())
    top = math.log(0.4 / max(ctx.dt for ctx in contexts))
    lag = cand.lag_s

    def sse(shape: str, damping: float, log_fc: float) -> float:
        # The filter whole (coefficient 1, as the model carries it), the others fitted beside it.
        cand.set_shape(shape, math.exp(log_fc), damping)
        for ctx in contexts:
            ctx.log_filter = cand.effect
        return block_sse(sel.columns(blocks, held=1), _without_filter(ys, blocks, cand))[0]

    def at_best_cutoff(shape: str, damping: float) -> tuple[float, float]:
        x0 = math.log((2.0 * damping if shape == "second order" else 1.0) / (2.0 * math.pi * lag))
        lo, hi = max(x0 - math.log(4.0), math.log(LOG_FILTER_MIN_HZ)), min(x0 + math.log(4.0), top)
        best = minimize_scalar(lambda x: sse(shape, damping, x), bounds=(lo, hi), method="bounded",
                               options={"xatol": 1e-3})
        return float(best.fun), float(best.x)

    first = at_best_cutoff("first order", 1.0)
    second = {z: at_best_cutoff("second order", z) for z in LOG_FILTER_DAMPINGS}
    z0 = min(second, key=lambda z: second[z][0])
    i = LOG_FILTER_DAMPINGS.index(z0)
    zs = LOG_FILTER_DAMPINGS[max(i - 1, 0)], LOG_FILTER_DAMPINGS[min(i + 1, len(LOG_FILTER_DAMPINGS) - 1)]
    if zs[0] != zs[1]:
        z = minimize_scalar(lambda z: at_best_cutoff("second order", z)[0], bounds=(min(zs), max(zs)),
                            method="bounded", options={"xatol": 0.01})
        if z.fun < second[z0][0]:
            z0 = float(z.x)
            second[z0] = at_best_cutoff("second order", z0)
    shapes = {"first order": (1.0, *first), "second order": (z0, *second[z0]),
              "pure delay": (1.0, *at_best_cutoff("pure delay", 1.0))}

    def refitted() -> np.ndarray:
        return np.concatenate([[1.0], block_sse(sel.columns(blocks, held=1), _without_filter(ys, blocks, cand))[1]])

    # The reference is the first order; the delay where the others were named through it.
    chosen = "pure delay" if cand.shape == "pure delay" else "first order"
    for shape in sorted((k for k in shapes if k != chosen), key=lambda k: shapes[k][1]):
        damping, sse_shape, log_fc = shapes[shape]
        if sse_shape > LOG_FILTER_OTHER_SHAPE * shapes[chosen][1]:
            break
        # Not where an effect through it becomes physically impossible (a fast line divided by its small gain).
        sse(shape, damping, log_fc)
        coef = refitted()
        if all(c.plausible(c.total(coef[sl])) for c, sl in zip(sel.selected[1:], sel.slices[1:])):
            chosen = shape
            break
    sse(chosen, *shapes[chosen][::2])
    # The shapes compared here, each relative to the best (the first pass's comparison is replaced).
    low = min(v[1] for v in shapes.values())
    cand.detail = {**{k: v for k, v in cand.detail.items() if not k.endswith("_vs_best")}, "shape": cand.shape,
                   **{f"sse_{k.replace(' ', '_')}_vs_best": v[1] / low if low > 0 else 1.0
                      for k, v in shapes.items()}}
    sel.coef = refitted()


def _coefficient_cov(sel: Selection, blocks: list[Block], ys: list[np.ndarray]) -> np.ndarray:
    """Covariance of the selection's coefficients [their units squared]: least squares on the weighted blocks,
    the residual's variance inflated by ``(1 + r1) / (1 - r1)`` for its lag-one correlation ``r1`` (pooled over
    the blocks: neighbouring samples of a low-passed channel are not independent)."""
    Xs = sel.columns(blocks)
    X, y = np.vstack(Xs), np.concatenate(ys)
    r = y - X @ sel.coef
    parts = np.split(r, np.cumsum([len(v) for v in ys])[:-1])
    num = sum(float(p[1:] @ p[:-1]) for p in parts if len(p) > 1)
    r1 = float(np.clip(num / max(float(r @ r), 1e-300), 0.0, 0.99))
    sigma2 = float(r @ r) / max(len(r) - X.shape[1], 1) * (1 + r1) / (1 - r1)
    return sigma2 * np.linalg.pinv(X.T @ X)


def _acting(cand: CandidateEffect, blocks: list[Block]) -> list[int]:
    """The blocks a candidate's columns act on."""
    return [i for i, X in enumerate(block_columns(blocks, cand.columns, cand.n_columns())) if np.any(X)]


def _sse(parts: list[np.ndarray], idx: Iterable[int]) -> float:
    """Sum of squares of the blocks ``idx`` of held-out residuals."""
    return sum(float(np.sum(parts[i] ** 2)) for i in idx)


def _gain(with_it: list[np.ndarray], without: list[np.ndarray], acts: list[int]) -> float:
    """Relative reduction of the held-out sum of squares on the blocks ``acts`` from ``without`` to ``with_it``."""
    sse_without = _sse(without, acts)
    return 1.0 - _sse(with_it, acts) / sse_without if sse_without > 0 else 0.0


def _redundant(beyond: float, gain: float) -> bool:
    """Whether an effect is redundant beside another's freer shape: beyond that shape it gains (``beyond``) less
    than the selection's least gain and less than :data:`_REDUNDANT_SHARE` of its own ``gain`` (fractions)."""
    return beyond < MIN_GAIN and beyond < _REDUNDANT_SHARE * gain


def _ambiguous(sel: Selection, effects: list[EffectReport], blocks: list[Block], ys: list[np.ndarray]
               ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Named effects that another named effect's freer shape makes redundant: ambiguous, and undecided.

    A named effect in another shape of its family (``shape_left_pct`` at least
    :data:`OTHER_SHAPE_LEFT_PCT`) leaves a remainder that a second effect may remove: over
    a short link travel a load's second harmonic is nearly a constant, which a sensor offset also is (a 37
    Nm load with a 3.5 Nm second harmonic came out as a 24 Nm load and a 9.6 Nm offset), and a drifting
    offset next to a load is nearly a load in another shape. When the second effect gains less than the
    selection's least gain beyond the first one's freer shape (:meth:`CandidateEffect.free_columns`; held
    out, on the blocks it acts on) and keeps less than a quarter of its own gain, the data do not decide
    between the two: it is *ambiguous*, reported, not named. An effect named on its own evidence channel
    (the ripple's deflection) is not judged by the residual channels.

    Without the evidence of another shape the simpler explanation stands: a freer shape (six columns for a
    load) can stand for a small offset (one) over a short travel too, and then would have swallowed real
    offsets next to sinusoidal loads. Such a second effect is *undecided*: named and kept in the model (the
    simpler explanation), and reported as one the data could also explain by the first's other shape.
    """
    reports = {e.name: e for e in effects}
    ambiguous: list[dict[str, Any]] = []
    undecided: list[dict[str, Any]] = []
    for first in sel.selected:
        n = len(first.free_columns(blocks[0].ctx))
        if n == 0 or any(a["name"] == first.name for a in ambiguous):
            continue
        other_shape = reports[first.name].detail.get("shape_left_pct", 0.0) >= OTHER_SHAPE_LEFT_PCT
        free = block_columns(blocks, first.free_columns, n)
        with_it = cv_residuals([np.hstack([a, b]) for a, b in zip(sel.columns(blocks), free)], ys)
        for second in sel.selected:
            if second is first or any(a["name"] == second.name for a in ambiguous + undecided) or \
                    sel.band[second.name] not in BANDS:
                continue  # (an effect named on its own evidence channel is not judged by the residual's)
            acts = _acting(second, blocks)
            if not acts:
                continue
            without = cv_residuals([np.hstack([a, b]) for a, b in zip(sel.columns(blocks, skip=second.name), free)],
                                   ys)
            beyond = _gain(with_it, without, acts)
            if _redundant(beyond, reports[second.name].gain_pct / 100.0):
                (ambiguous if other_shape else undecided).append(
                    {"name": second.name, "or_shape_of": first.name, "gain_pct": reports[second.name].gain_pct,
                     "gain_beyond_pct": 100.0 * beyond, "free_shape": first.free_shape})
    return ambiguous, undecided


def _redundant_beside(known: CandidateEffect, sel: Selection, effects: list[EffectReport], blocks: list[Block],
                      ys: list[np.ndarray]) -> str | None:
    """The named effect in another shape of its family whose freer shape makes an effect of the model redundant
    (as :func:`_ambiguous` judges two named effects), or None.

    ``ys``: the residual without the model's effect. A sensor offset fitted to a chirp whose link hardly moved is
    a load's value at that position; when the load named on moving runs is not a plain sinusoid, a constant
    still helps the sinusoid over a short travel, yet adds nothing beyond the load's freer shape.
    """
    reports = {e.name: e for e in effects}
    own = block_columns(blocks, known.columns, known.n_columns())
    acts = [i for i, X in enumerate(own) if np.any(X)]
    if not acts:
        return None
    base = sel.columns(blocks)
    gain_own = _gain(cv_residuals([np.hstack([a, b]) for a, b in zip(base, own)], ys), cv_residuals(base, ys), acts)
    for first in sel.selected:
        n = len(first.free_columns(blocks[0].ctx))
        if n == 0 or reports[first.name].detail.get("shape_left_pct", 0.0) < OTHER_SHAPE_LEFT_PCT:
            continue
        free = [np.hstack([a, b]) for a, b in zip(base, block_columns(blocks, first.free_columns, n))]
        beyond = _gain(cv_residuals([np.hstack([a, b]) for a, b in zip(free, own)], ys), cv_residuals(free, ys), acts)
        if _redundant(beyond, max(gain_own, 0.0)):
            return first.name
    return None


def _shape_fit(cand: CandidateEffect, blocks: list[Block], ys: list[np.ndarray], sel: Selection,
               without: list[np.ndarray], after: list[np.ndarray], acts: list[int]) -> dict[str, Any]:
    """How well the candidate's shape fits, against a freer shape of its family
    (:meth:`CandidateEffect.free_columns`), on held-out data; {} when it has none.

    ``shape_fit``: the share of the freer shape's reduction of the held-out residual that the candidate
    reaches (blocks weighted alike, as in the selection), in [0, 1]. ``shape_left_pct``: on the block where
    it is largest (``shape_left_in``), the share of the residual left with the candidate that the freer shape
    removes besides [%]. A large effect in another shape (a Stribeck friction, a load that is not a sinusoid,
    a hum with harmonics) has a shape_fit near 1 and yet a large shape_left_pct.
    """
    n = len(cand.free_columns(blocks[0].ctx))
    if n == 0 or not acts:
        return {}
    free = block_columns(blocks, cand.free_columns, n)
    res = cv_residuals([np.hstack([a, b]) for a, b in zip(sel.columns(blocks, skip=cand.name), free)], ys)

    reach = _sse(without, acts) - _sse(res, acts)
    share = 1.0 if reach <= 0 else (_sse(without, acts) - _sse(after, acts)) / reach
    left = {i: 1.0 - _sse(res, [i]) / _sse(after, [i]) for i in acts if _sse(after, [i]) > 0}
    worst = max(left, key=lambda i: left[i]) if left else acts[0]
    return {"shape_fit": float(np.clip(share, 0.0, 1.0)), "free_shape": cand.free_shape,
            "shape_left_pct": float(100.0 * max(left.get(worst, 0.0), 0.0)),
            "shape_left_in": f"{blocks[worst].ctx.name} {blocks[worst].channel}"}


def _suspects(sel: Selection) -> list[dict[str, Any]]:
    """Large held-out reductions of the selection's last step that were not accepted, best first per name."""
    if not sel.steps:
        return []
    last = max(s.step for s in sel.steps)
    out: dict[str, dict[str, Any]] = {}
    for s in sel.steps:
        # Only the residual channels: an effect's own evidence channel can show a small correction of an
        # effect the model already has plainly, while the torque prediction gains nothing from it; unless the
        # torque's fit of what that channel shows is not physically possible (a ripple through a filter before
        # the log that would need a deflection beyond a transmission's).
        # Nor where the torque does not show it at all (a ripple's line above a filter before the log).
        own_impossible = s.band not in BANDS and s.implausible
        own_unconfirmed = s.band not in BANDS and s.unconfirmed and s.delta_bic < 0
        if s.step != last or s.accepted or s.gain < LARGE_GAIN or (s.band not in BANDS and not own_impossible
                                                                   and not own_unconfirmed):
            continue
        if own_impossible:
            failed = (f"its fit to the torque is not physically possible, though its own evidence ({s.band}) shows "
                      f"it (a filter before the log named beside it may not act on it)")
        elif own_unconfirmed:
            failed = (f"no band of the logged torque is predicted better with it, though its own evidence "
                      f"({s.band}) shows it (a filter before the log named beside it may hide it there)")
        elif s.implausible:
            failed = "its fitted parameters are not physically possible"
        elif s.irrelevant:
            failed = "the change it describes is below the identification's accuracy"
        elif s.negligible:
            failed = "it is below the noise of the residual"
        elif s.delta_bic >= 0:
            failed = "the information criterion does not favour it"
        else:
            failed = f"its held-out confidence is {s.confidence:.3f}"
        if s.name not in out or s.gain > out[s.name]["gain"]:
            out[s.name] = {"name": s.name, "gain": s.gain, "band": s.band, "confidence": s.confidence,
                           "delta_bic": s.delta_bic, "failed": failed}
    return sorted(out.values(), key=lambda x: -x["gain"])
