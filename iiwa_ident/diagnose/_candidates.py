"""The library of candidate effects that may explain what the model gets wrong.

Each candidate is a :class:`CandidateEffect` subclass (in the spirit of a
feature library of sparse regression): it knows

* its *columns*: signals it injects at a physical point of the joint
  (:data:`iiwa_ident.diagnose._predict.INJECTIONS`), each scaled by one
  unknown coefficient; :func:`~iiwa_ident.diagnose._predict.channel_columns`
  turns them into regressors of the residual channels, so the residual is
  linear in the coefficients;
* how to find its few *nonlinear* parameters (period, frequency, delay) by a
  search on the current residual (:meth:`CandidateEffect.prepare`);
* how coefficients become the reported parameters and how they extend a
  :class:`~iiwa_ident.model.JointModel`;
* optionally, an *evidence channel* of its own (:meth:`CandidateEffect.evidence`):
  a residual outside the torque channels where the effect shows more
  plainly, with the effect's regressors there (the transmission ripple's
  deflection in the motor position of a position-controlled arm, where its
  torque signature is hundredths of a Nm). The selection judges it by the
  same held-out tests as the residual channels (:mod:`~iiwa_ident.diagnose._select`).

The physics of every candidate but the model's own parameters is the plant
effect of the same name (:mod:`iiwa_ident.sim._effects`): its regressors,
the coefficients of a known effect, the values an estimate extends a model
with and the parameters it reports. A candidate adds only what the
diagnosis needs beyond the effect: the search for its nonlinear parameters,
the freer shapes of its family, plausibility, and evidence of its own. A
new effect is one plant effect and one candidate subclass decorated with
:func:`register_candidate`; selection, diagnosis, report and CLI pick it up
unchanged.

Conventions of the reported parameters (JSON ``parameters``):

transmission_ripple
    ``period_rad`` rho [rad] and ``amplitude_rad``, the half peak-to-peak of
    the fitted deflection f(theta_m mod rho) [rad] (as ``iiwa-ident ripple``).
link_friction
    ``tau = -coulomb_nm sign(omega_l) - viscous_nms_rad omega_l`` [Nm, Nm s/rad].
position_dependent_load
    ``tau = amplitude_nm sin(theta_l + phase_rad)`` acting on the link, with
    amplitude >= 0 and the phase in (-pi, pi].
torque_sensor_offset, torque_sensor_scale
    ``reading = scale * tau_J + offset_nm``; ``logged_nm`` the part of the offset the internal
    loop does not see (in the logged reading only).
periodic_disturbance
    ``amplitude_nm sin(2 pi frequency_hz t + phase)`` on the torque reading
    (the amplitude is the median over datasets; the phase is per dataset).
model_parameters
    ``Jc_kgm2``, ``bc_nms_rad``, ``K_nm_rad``, ``Jl_kgm2``, ``Td_s``: the model's
    own eq (1)-(4) parameters refitted together (a parameter error rather than
    an extra effect: Table I used on another joint, a biased fit, an extra
    input delay); ``detail`` keeps the model's values as ``model_<name>``.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any, ClassVar, NamedTuple

import numpy as np
from scipy import optimize, signal

from iiwa_ident.datasets import Dataset
from iiwa_ident.diagnose._predict import Context, channel_columns, logged_change, predict_channel
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import LOG_FILTER_MIN_HZ, LOG_ONLY, PhysicalRanges, line_ratio
from iiwa_ident.model import JointModel, RippleTable
from iiwa_ident.sim import (
    EFFECTS,
    Column,
    Effect,
    EffectSignals,
    PeriodicDisturbance,
    TorqueLogFilter,
    TransmissionRipple,
    make_effect,
    own_dataset_columns,
)

__all__ = [
    "Block",
    "Column",
    "EvidenceChannel",
    "CandidateEffect",
    "CANDIDATES",
    "register_candidate",
    "make_candidate",
    "block_sse",
    "context_columns",
    "contribution",
    "TransmissionRippleCandidate",
    "LinkFrictionCandidate",
    "PositionDependentLoadCandidate",
    "LinkSpringCandidate",
    "SPRING_MAX_NM_RAD",
    "SPRING_MIN_SLOPE_SHARE",
    "SPRING_CURVED_MAX_LOAD_NM",
    "TorqueSensorOffsetCandidate",
    "TorqueSensorScaleCandidate",
    "SCALE_RELEVANT",
    "TorqueLogFilterCandidate",
    "LOG_FILTER_SHAPES",
    "LOG_FILTER_DAMPINGS",
    "RIPPLE_MAX_AMPLITUDE_RAD",
    "LOG_FILTER_OTHER_SHAPE",
    "LOG_FILTER_DETERMINED",
    "LOG_FILTER_MIN_HZ",
    "PeriodicDisturbanceCandidate",
    "ModelParametersCandidate",
    "MODEL_PARAMETER_FACTOR",
    "MODEL_PARAMETER_TD_S",
    "MODEL_PARAMETER_RELEVANT",
    "MODEL_PARAMETER_RELEVANT_TD_S",
    "MIN_GAIN_MODEL",
]

class Block:
    """One residual channel of one dataset, as the selection sees it.

    Attributes
    ----------
    ctx : Context
    channel : str
    mask : numpy.ndarray of bool
        Samples used (decimated where the channel is low-passed).
    weight : float
        1 / (baseline residual RMS) [1/Nm]: every block counts alike.
    """

    def __init__(self, ctx: Context, channel: str, mask: np.ndarray, weight: float) -> None:
        self.ctx, self.channel, self.mask, self.weight = ctx, channel, mask, weight


class EvidenceChannel:
    """An effect's own evidence: a residual of its own and the effect's regressors in it.

    Attributes
    ----------
    name : str
        What the residual is (reported as the band the effect was judged in).
    X : list of numpy.ndarray
        Per block (samples x columns), the effect's regressors, weighted like ``y``.
    y : list of numpy.ndarray
        Per block, the residual without the effect, weighted so blocks count alike.
    false_alarm : float or None
        Calibrated probability that noise alone gives evidence this strong (from a
        detection test of the effect's own), or None; the effect's confidence in this
        channel is at most ``1 - false_alarm``.
    """

    def __init__(self, name: str, X: list[np.ndarray], y: list[np.ndarray],
                 false_alarm: float | None = None) -> None:
        self.name, self.X, self.y, self.false_alarm = name, X, y, false_alarm


def context_columns(ctx: Context, columns: Callable[[Context], list[Column]], n: int) -> list[dict[str, np.ndarray]]:
    """Each of a candidate's ``n`` columns in ``ctx`` as the change it makes to each residual channel [Nm per unit
    coefficient] (every sample, unweighted)."""
    per_col = []
    for col in columns(ctx):
        acc: dict[str, np.ndarray] = {}
        for injection, phi in col:
            for ch, v in channel_columns(ctx, injection, phi).items():
                acc[ch] = acc.get(ch, 0.0) + v
        per_col.append(acc)
    if len(per_col) != n:
        raise ValueError("a candidate returned the wrong number of columns")
    return per_col


def contribution(cand: CandidateEffect, coef: np.ndarray, ctx: Context) -> dict[str, np.ndarray]:
    """What a candidate with coefficients ``coef`` adds to each residual channel of ``ctx`` [Nm], full length."""
    out: dict[str, np.ndarray] = {}
    for c, col in zip(coef, context_columns(ctx, cand.columns, cand.n_columns())):
        for ch, v in col.items():
            out[ch] = out.get(ch, 0.0) + c * v
    return out


def block_columns(blocks: Sequence[Block], columns: Callable[[Context], list[Column]], n: int) -> list[np.ndarray]:
    """Weighted regressor matrix (samples x n) of each block for a candidate's columns."""
    cache: dict[int, list[dict[str, np.ndarray]]] = {}
    out = []
    for b in blocks:
        if b.ctx.index not in cache:
            cache[b.ctx.index] = context_columns(b.ctx, columns, n)
        m = np.count_nonzero(b.mask)
        X = np.zeros((m, n))
        for j, acc in enumerate(cache[b.ctx.index]):
            if b.channel in acc:
                X[:, j] = acc[b.channel][b.mask] * b.weight
        out.append(X)
    return out


def block_sse(Xs: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> tuple[float, np.ndarray]:
    """SSE of the joint least-squares fit of stacked blocks, and the coefficients."""
    X, y = np.vstack(Xs), np.concatenate(ys)
    coef = np.linalg.lstsq(X, y, rcond=None)[0]
    return float(np.sum((y - X @ coef) ** 2)), coef


class CandidateEffect:
    """Base class of candidate effects (see the module docstring).

    Subclasses set :attr:`name`, implement :meth:`columns`, :meth:`parameters`
    and :meth:`extend`, and may override :meth:`prepare`, :meth:`from_values`,
    :meth:`evidence` and :meth:`evidence_axis`.

    Evidence: every effect is judged on the residual channels (its columns).
    An effect whose signature there may be too small to judge, while another
    measured quantity shows it plainly, can bring that quantity as its own
    evidence channel (:meth:`evidence`). The selection then scores that
    channel with the same held-out gain, BIC and confidence tests, and names
    the effect on it only when it passes none of the residual-channel bands
    and they do not contradict it (a positive held-out gain there in at
    least one band);
    the fitted coefficients, the reported parameters and the per-channel
    gains still come from the residual channels.
    """

    #: Name, as in the JSON output and the plant-effect vocabulary.
    name: ClassVar[str] = ""
    #: One line of meaning.
    summary: ClassVar[str] = ""
    #: Parameters found by search rather than least squares (counted by the information criterion); a
    #: candidate whose search frees more or fewer of them sets its own.
    n_nonlinear: int = 0

    #: Whether the candidate is the plant effect of its name (:attr:`effect`); False for the model's own parameters.
    is_effect: ClassVar[bool] = True

    #: Least held-out gain for the effect to be named, beyond the selection's own
    #: (:data:`~iiwa_ident.diagnose._select.MIN_GAIN`).
    min_gain: ClassVar[float] = 0.0

    #: Candidates whose shape this one's holds with more parameters (a spring's constant is a sensor offset on
    #: the link): the selection prefers them unless this one gains the selection's least gain more.
    contains: ClassVar[tuple[str, ...]] = ()

    #: Candidates that predict the data alike over a short travel (another cause of the same shape there): a
    #: named effect is reported undecided against one of them that, in its place, predicts the held-out data
    #: as well and is physically possible.
    alike: ClassVar[tuple[str, ...]] = ()

    def __init__(self) -> None:
        self.n_datasets = 0
        self.detail: dict[str, Any] = {}
        #: Coefficients of the same effect the model already has (its columns then fit a correction), or None.
        self.base_coef: np.ndarray | None = None
        #: What the robot's description makes physically possible for the joint (None: judged by sign only).
        self.ranges: PhysicalRanges | None = None
        #: The plant effect at the current nonlinear parameters (defaults until found).
        self.effect: Effect | None = self._default_effect() if self.is_effect else None
        #: The effects named before this candidate is tried, with their coefficients in the current fit (set by
        #: the selection at each step, before :meth:`prepare`).
        self.beside: list[tuple[CandidateEffect, np.ndarray]] = []

    def _default_effect(self) -> Effect:
        return make_effect(self.name)

    @property
    def plant(self) -> Effect:
        """The plant effect at the current nonlinear parameters (:attr:`effect`); TypeError for a candidate that
        is none (the model's own parameters)."""
        if self.effect is None:
            raise TypeError(f"{self.name} is not a plant effect")
        return self.effect

    def signals(self, ctx: Context) -> EffectSignals:
        """The dataset's signals as the effects' regressors take them (the wide-band link velocity)."""
        return EffectSignals(t=ctx.t, q_m=ctx.q_m, theta_l=ctx.theta_l, omega_l=ctx.omega_fast, tau_j=ctx.tau,
                             dataset=ctx.index, n_datasets=max(self.n_datasets, 1))

    # -- structure ---------------------------------------------------------
    #: Whether the effect has coefficients of each dataset's own (a phase per recording).
    per_dataset: ClassVar[bool] = False

    def n_columns(self) -> int:
        """Number of linear coefficients (after :meth:`prepare`): the effect's, per dataset where it has its own."""
        return len(self.plant.coefficients()) * (self.n_datasets if self.per_dataset else 1)

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        """Find nonlinear parameters on the current (weighted, masked) residuals.

        Returns False when the data cannot show this effect (it is then not tested).
        """
        self.n_datasets = 1 + max(b.ctx.index for b in blocks)
        return True

    def columns(self, ctx: Context) -> list[Column]:
        """The effect's columns for one dataset (exactly :meth:`n_columns` of them): the plant effect's."""
        return self.plant.columns(self.signals(ctx))

    # -- results -------------------------------------------------------------
    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        """The reported parameters (module docstring) from fitted coefficients: the plant effect's."""
        return self.plant.reported(coef)

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        """Add the effect with these coefficients to ``model`` (in place), brought into the plant-file ranges."""
        self._replace_effect(model, self.plant.clip(self.plant.values_from(coef)))

    def total(self, coef: np.ndarray) -> np.ndarray:
        """Fitted coefficients (a correction where the model has the effect) with the model's own values added."""
        base = self.base_coef
        return coef + base if base is not None and len(base) == len(coef) else coef

    def plausible(self, coef: np.ndarray) -> bool:
        """Whether fitted coefficients describe a physically possible effect (default: always)."""
        return True

    #: The freer shape of the family :meth:`free_columns` describes ('' when there is none).
    free_shape: ClassVar[str] = ""

    def free_columns(self, ctx: Context) -> list[Column]:
        """Columns of the effect's family in a freer shape (the effect's own columns first, then more), for the
        shape-fit measure of :func:`~iiwa_ident.diagnose.diagnose`; [] when there is none."""
        return []

    def relevant(self, coef: np.ndarray) -> bool:
        """Whether the fitted change matters enough to be named (default: always; a refit of the model's own
        parameters only when it exceeds the identification's accuracy)."""
        return True

    def other_shape(self, coef: np.ndarray) -> str:
        """For coefficients that are not :meth:`plausible`: how they still describe this family of effect in
        another shape ('' when they do not; default: never)."""
        return ""

    def carried(self, coef: np.ndarray) -> np.ndarray:
        """The coefficients the extended model carries for fitted ``coef`` (default: the same; an effect whose
        written parameters do not hold its coefficient gives back what they imply)."""
        return coef

    def from_values(self, values: dict[str, Any]) -> np.ndarray | None:
        """Coefficients of an effect the model already has (plant-effect values), or None.

        The candidate takes the effect's nonlinear parameters from ``values``.
        """
        if self.effect is None:
            return None
        self.effect = make_effect(self.name, values)
        return self.plant.coefficients()

    def evidence(self, blocks: Sequence[Block]) -> EvidenceChannel | None:
        """The effect's own evidence channel at its current nonlinear parameters (after :meth:`prepare`).

        Default: none (the effect is judged on the residual channels only). The
        channel must not depend on the residual channels, so the other selected
        effects do not act on it.
        """
        return None

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        """The variable the effect's partial residual is plotted against, and its label."""
        return ctx.t, "time [s]"

    # -- helpers -------------------------------------------------------------
    def _replace_effect(self, model: JointModel, values: dict[str, Any]) -> None:
        model.effects = [e for e in model.effects if e.get("name") != self.name] + [{"name": self.name, **values}]


#: Registry of candidate classes by name, in the order they are tried.
CANDIDATES: dict[str, type[CandidateEffect]] = {}


def register_candidate(cls: type[CandidateEffect]) -> type[CandidateEffect]:
    """Class decorator adding a :class:`CandidateEffect` subclass to :data:`CANDIDATES`."""
    if not cls.name:
        raise ValueError("a candidate effect needs a name")
    if cls.is_effect and not cls.summary:
        cls.summary = EFFECTS[cls.name].summary
    CANDIDATES[cls.name] = cls
    return cls


def make_candidate(name: str) -> CandidateEffect:
    """A fresh candidate ``name``."""
    if name not in CANDIDATES:
        raise IiwaIdentError(f"diagnose: unknown effect {name!r} (known: {', '.join(CANDIDATES)})")
    return CANDIDATES[name]()


def _search_1d(fn: Callable[[float], float], grid: np.ndarray) -> float:
    """Minimise ``fn`` on a grid, then refine between the neighbours of the best point."""
    values = [fn(x) for x in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if hi <= lo:
        return float(grid[i])
    res = optimize.minimize_scalar(fn, bounds=(lo, hi), method="bounded", options={"xatol": (hi - lo) * 1e-3})
    return float(res.x) if res.fun <= values[i] else float(grid[i])


def _sse_of(blocks: Sequence[Block], residuals: Sequence[np.ndarray], columns, n: int) -> float:
    Xs = block_columns(blocks, columns, n)
    return block_sse(Xs, residuals)[0]


# ----------------------------------------------------------------------------- ripple

#: Largest deflection ripple named [rad] (half its peak-to-peak): three times a strain-wave gear's catalogued
#: transmission error of about one arcminute (3e-4 rad), ten times the real iiwa 14's (4e-5-1e-4 rad).
RIPPLE_MAX_AMPLITUDE_RAD = 1e-3


class _Identified(NamedTuple):
    """Section III.B's identification on the contexts."""

    period_rad: float  #: 0.0: none
    detail: dict[str, Any]
    passes: list
    false_alarm: float | None


@register_candidate
class TransmissionRippleCandidate(CandidateEffect):
    """Position-periodic transmission deflection f(theta_m mod rho), eq (5).

    The period comes from :func:`iiwa_ident.ident.identify_ripple`
    (section III.B; on the motor position corrected by the model's own table,
    so only what the table misses is looked for) and is refined by the
    residual fit; the deflection is a Fourier series of :attr:`harmonics`
    harmonics injected at the ``deflection`` point.

    Evidence channel ``deflection`` (:meth:`evidence`): the deflection
    estimate of the identification, ``q_m - tau_J / K - theta_l`` with the
    slow part of each constant-speed pass projected out (its passes, its
    noise weights), band-passed around the fundamental line ``|v| / rho``
    (:attr:`evidence_band`), against the fundamental of the series in
    ``q_m``. Only the fundamental: the harmonics of the dynamic estimate pass
    through the speed- and direction-dependent link response of eq (7),
    which one set of coefficients cannot follow. Its confidence is capped by
    the identification's calibrated false-alarm probability. On a
    position-controlled arm the torque signature of the ripple is
    hundredths of a Nm while its deflection is plain in q_m; the period is
    refined on both (the sum of the relative residual sums of squares).
    """

    name = "transmission_ripple"
    n_nonlinear = 1
    harmonics = 3
    #: Band of the evidence channel, in units of the fundamental's frequency |v| / rho.
    evidence_band = (0.7, 1.3)

    def __init__(self) -> None:
        super().__init__()
        self.period = 0.0
        self.base_table: RippleTable | None = None
        self._found: float | None = None
        self._passes: list = []
        self._false_alarm: float | None = None
        self._bands: list[tuple[np.ndarray, np.ndarray] | None] | None = None

    def _default_effect(self) -> Effect:
        return TransmissionRipple.shape(TransmissionRipple.params[0].default, self.harmonics)


    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        if self._found is None:
            self._found = self._identify(blocks)
        if not self._found:
            return False
        rho0 = self._found
        sse0 = max(sum(float(np.sum(r ** 2)) for r in residuals), 1e-300)
        ev0 = self._evidence_at(rho0)
        own0 = sum(float(np.sum(y ** 2)) for y in ev0.y) if ev0 is not None else 0.0

        def sse(rho: float) -> float:
            self.period = rho
            total = _sse_of(blocks, residuals, self.columns, self.n_columns()) / sse0
            ev = self._evidence_at(rho) if own0 > 0 else None  # (None only where ev0 was)
            if ev is not None:
                total += block_sse(ev.X, ev.y)[0] / own0
            return total

        self.period = _search_1d(sse, rho0 * (1 + np.linspace(-3e-3, 3e-3, 13)))
        return True

    def evidence(self, blocks: Sequence[Block]) -> EvidenceChannel | None:
        return self._evidence_at(self.period) if self.period > 0 else None

    def _evidence_at(self, period: float) -> EvidenceChannel | None:
        """The ``deflection`` channel (class docstring) with the fundamental at ``period``; one block per dataset.

        None when no pass resolves the line (too short, or the line above the band a pass can show).
        """
        if self._bands is None:
            self._bands = self._evidence_bands()
        per_ds: dict[int, tuple[list, list]] = {}
        for ps, band in zip(self._passes, self._bands):
            if band is None:
                continue
            sos, y_band = band
            x = 2 * np.pi * ps.theta / period
            A = np.column_stack([np.cos(x), np.sin(x)])
            A = A - ps.nuisance @ (ps.nuisance.T @ A)
            Xs, ys = per_ds.setdefault(ps.dataset, ([], []))
            Xs.append(signal.sosfiltfilt(sos, A, axis=0) * ps.weight)
            ys.append(y_band)
        X = [np.vstack(Xs) for Xs, _ in per_ds.values()]
        y = [np.concatenate(ys) for _, ys in per_ds.values()]
        if not X:
            return None
        return EvidenceChannel("deflection", X, y, self._false_alarm)

    def _evidence_bands(self) -> list[tuple[np.ndarray, np.ndarray] | None]:
        """Per pass, the band-pass round the identified line and the pass's deflection through it, weighted (None:
        the pass does not resolve the line); they do not depend on the period searched."""
        lo, hi = self.evidence_band
        out: list[tuple[np.ndarray, np.ndarray] | None] = []
        for ps in self._passes:
            dt = float(np.median(np.diff(ps.t)))
            f_line = abs(ps.speed) / self._found
            if len(ps.f) < 32 or hi * f_line >= 0.45 / dt:
                out.append(None)
                continue
            sos = signal.butter(2, [lo * f_line, hi * f_line], btype="bandpass", fs=1.0 / dt, output="sos")
            out.append((sos, signal.sosfiltfilt(sos, ps.f) * ps.weight))
        return out

    def _identify(self, blocks) -> float:
        """The period by section III.B's identification (0.0: none found); it does not depend on the residual."""
        ctxs = {b.ctx.index: b.ctx for b in blocks}.values()
        base, p = self.base_table, next(iter(ctxs)).params
        # The identification depends on the motion, K, Jl and the model's table only: once per diagnosis.
        key = ("transmission_ripple", tuple(c.index for c in ctxs), p["K"], p["Jl"],
               None if base is None else (base.period_rad, base.lut.tobytes()))
        memo = next(iter(ctxs)).memo
        if key not in memo:
            memo[key] = self._identified(ctxs)
        period, self.detail, passes, false_alarm = memo[key]
        self._passes, self._false_alarm, self._bands = list(passes), false_alarm, None
        self.detail = dict(self.detail)
        return period

    def _identified(self, ctxs) -> _Identified:
        """Section III.B's identification on the contexts: the period (0.0: none), the detail, the passes and
        the false-alarm probability."""
        from iiwa_ident.ident import identify_ripple

        p = next(iter(ctxs)).params
        data = []
        for c in ctxs:
            q = c.q_m - (self.base_table(c.q_m) if self.base_table is not None else 0.0)
            data.append(Dataset(signals={"t": c.t, "q_m": q, "tau_j": c.tau}, experiment=c.experiment,
                                source="import", joint=1, sample_rate_hz=1.0 / c.dt))
        try:
            r = identify_ripple(data, K=p["K"], Jl=p["Jl"])
        except IiwaIdentError:
            # No constant-speed motion: a deflection cannot be told from other effects.
            return _Identified(0.0, {}, [], None)
        if not r.detected or r.period_rad is None:
            return _Identified(0.0, {}, [], None)
        return _Identified(float(r.period_rad), {"false_alarm_probability": r.false_alarm,
                                                 "period_from_identification_rad": r.period_rad},
                           list(r.passes), float(r.false_alarm))

    def columns(self, ctx: Context) -> list[Column]:
        return TransmissionRipple.shape(self.period, self.harmonics).columns(self.signals(ctx))

    free_shape = "harmonics 1-6 of the period"

    def free_columns(self, ctx: Context) -> list[Column]:
        return TransmissionRipple.shape(self.period, 6).columns(self.signals(ctx))  # the own three first

    def from_values(self, values: dict[str, Any]) -> np.ndarray | None:
        return None  # the model's deflection is its ripple table, corrected on the motor position already

    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        return TransmissionRipple.shape(self.period, self.harmonics).reported(coef)

    def plausible(self, coef: np.ndarray) -> bool:
        # A strain-wave gear's transmission error is about an arcminute: a deflection ripple many times that is
        # some other torque at the line's frequency (a log filter's column of a fast line, divided by its gain).
        return self.parameters(coef)["amplitude_rad"] <= RIPPLE_MAX_AMPLITUDE_RAD

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        lut = TransmissionRipple.table(coef, 256)
        old = model.ripple
        if old is not None and abs(old.period_rad / self.period - 1) < 2e-3:
            # Same period: the correction adds to the existing table (resampled onto its bins).
            x = np.arange(len(old.lut)) * self.period / len(old.lut)
            base = old.lut.copy()
            lut = base + np.interp(x, np.arange(256) * self.period / 256, lut, period=self.period)
        lut = lut - lut.mean()
        model.ripple = RippleTable(float(self.period), lut, {
            "amplitude_rad": float(np.ptp(lut) / 2), "method": "diagnose",
            **{k: float(v) for k, v in self.detail.items() if v is not None}})

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        return np.mod(ctx.q_m, self.period), f"q_m mod {self.period:.5f} rad [rad]"


# ----------------------------------------------------------------------------- link torques

#: Speeds below this do not count as moving for the one-speed test of the friction [rad/s].
ONE_SPEED_MOVING_RAD_S = 0.02
#: Moving samples whose 90th speed percentile is below this multiple of the 10th are at one speed.
ONE_SPEED_RATIO = 1.5


@register_candidate
class LinkFrictionCandidate(CandidateEffect):
    """Coulomb and viscous friction on the link: ``-F_c tanh(omega_l / v_s) - F_v omega_l`` (the plant effect's
    shape without its Stribeck term)."""

    name = "link_friction"


    free_shape = "Coulomb, viscous, breakaway at 0.01, 0.03, 0.1 and 0.3 rad/s, and quadratic drag"

    def __init__(self) -> None:
        super().__init__()
        #: The one speed the data move at [rad/s], where their speeds do not separate Coulomb from viscous.
        self.one_speed: float | None = None

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        # Runs at one speed (back and forth) show the friction at that speed only: the Coulomb and viscous
        # columns are then nearly proportional, and their split is set by the reversals' few samples (a large
        # negative Coulomb beside a large viscous slope). One column, the friction at that speed as Coulomb.
        w = np.concatenate([np.abs(b.ctx.omega_l[b.mask]) for b in blocks])
        moving = w[w > ONE_SPEED_MOVING_RAD_S]
        self.one_speed = None
        self.detail.pop("one_speed_rad_s", None)
        if len(moving) >= 0.5 * len(w) and len(moving) > 10:
            lo, hi = np.percentile(moving, [10, 90])
            if hi < ONE_SPEED_RATIO * lo:
                self.one_speed = float(np.median(moving))
                self.detail["one_speed_rad_s"] = self.one_speed
        return True

    def n_columns(self) -> int:
        return 1 if self.one_speed is not None else 2

    def columns(self, ctx: Context) -> list[Column]:
        cols = super().columns(ctx)
        return cols[:1] if self.one_speed is not None else cols

    def total(self, coef: np.ndarray) -> np.ndarray:
        base = self.base_coef
        if self.one_speed is not None and base is not None and len(base) == 2 and len(coef) == 1:
            # The model's friction at that speed, as Coulomb, plus the correction.
            return np.asarray(coef, float) + (base[0] + base[1] * self.one_speed)
        return super().total(coef)

    @staticmethod
    def _two(coef) -> np.ndarray:
        """Coulomb and viscous from the one-speed fit's single coefficient (viscous 0), or as they are."""
        coef = np.asarray(coef, float)
        return np.array([coef[0], 0.0]) if len(coef) == 1 else coef

    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        return super().parameters(self._two(coef))

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        super().extend(model, self._two(coef))

    def free_columns(self, ctx: Context) -> list[Column]:
        w = ctx.omega_fast
        sign = np.tanh(w / self.plant.values["smoothing_rad_s"])
        return self.columns(ctx) + [[("link", -sign * np.exp(-(w / vs) ** 2))] for vs in (0.01, 0.03, 0.1, 0.3)] \
            + [[("link", -w * np.abs(w))]]

    def plausible(self, coef: np.ndarray) -> bool:
        # Friction dissipates: a clearly negative level is some other misfit.
        coef = self._two(coef)
        return coef[0] > -0.05 and coef[1] > -0.05

    def other_shape(self, coef: np.ndarray) -> str:
        # A friction that is larger at standstill than the Coulomb-plus-viscous line: a negative slope.
        coef = self._two(coef)
        if coef[0] > 0.05 and coef[1] <= -0.05:
            return ("friction that falls with speed (negative viscous slope): breakaway (Stribeck) friction, "
                    "which the Coulomb-plus-viscous shape does not have")
        return ""

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        return ctx.omega_l, "link velocity [rad/s]"


@register_candidate
class PositionDependentLoadCandidate(CandidateEffect):
    """Gravity-like load ``A sin(theta_l + phi)`` on the link.

    Two columns act on the link (``A cos phi``, ``A sin phi``); two more are
    the robot's own compensation ``-c A sin(theta_m + phi)`` added to the
    loop's target, from which the compensated fraction ``c`` follows (1 when
    no torque-commanded data shows it).
    """

    name = "position_dependent_load"


    free_shape = "harmonics 1-3 of the link angle"

    def free_columns(self, ctx: Context) -> list[Column]:
        th = ctx.theta_l
        return self.columns(ctx) + [[("link", fn(k * th))] for k in (2, 3) for fn in (np.sin, np.cos)]

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        super().extend(model, coef)
        self.detail["compensated"] = self.plant.values_from(coef)["compensated"]

    def plausible(self, coef: np.ndarray) -> bool:
        # The robot compensates a fraction c in [0, 1] of the load it knows: its columns carry -c times the
        # link's. Far more there than on the link is a constant or a slope of the command channel, not a load.
        # Where the robot is described, the amplitude must be a gravity load the arm can have at its pose
        # (PhysicalRanges: within a factor 2 of the description, up to the rated payload).
        a, b = np.asarray(coef[:2], float), np.asarray(coef[2:4], float)
        norm = float(np.hypot(*a))
        if self.ranges is not None and not self.ranges.load_nm[0] <= norm <= self.ranges.load_nm[1]:
            return False
        if norm == 0.0:
            return not np.any(b)
        c = -float(a @ b) / norm ** 2
        return -0.2 <= c <= 1.2 and float(np.hypot(*(b + c * a))) <= 0.2 * norm

    alike = ("link_spring",)

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        return ctx.theta_l, "link position [rad]"


#: The stiffest spring cables and hoses make [Nm/rad]; beyond it a torque linear in the position is some
#: other misfit (a hard stop, a wrong model).
SPRING_MAX_NM_RAD = 200.0
#: Largest gravity amplitude the description allows (with the rated payload) on a joint whose spring is fitted
#: with a curvature [Nm]: below it gravity's cosine makes no curvature a joint-torque sensor shows.
SPRING_CURVED_MAX_LOAD_NM = 0.01
#: Least share of its torque at mid-travel the spring's slope must change over the travel: a spring whose
#: slope the travel barely shows is a constant, the torque sensor offset's shape.
SPRING_MIN_SLOPE_SHARE = 0.1


@register_candidate
class LinkSpringCandidate(CandidateEffect):
    """A spring on the link, ``-k (theta_l - theta_0)``: cables and hoses (on any axis, vertical ones too).

    Over a long travel its straight line is told from gravity's sine by the shape; over a short one a load
    predicts the data alike (:attr:`alike`): the diagnosis then reports the two undecided.
    """

    name = "link_spring"
    alike = ("position_dependent_load",)
    contains = ("torque_sensor_offset",)

    def __init__(self) -> None:
        super().__init__()
        self._travel = (0.0, 0.0)
        #: Whether the curvature is fitted (a spring the model carries acts with all its terms).
        self.curved = True

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        th = np.concatenate([b.ctx.theta_l[b.mask] for b in blocks])
        self._travel = (float(th.min()), float(th.max())) if len(th) else (0.0, 0.0)
        # A curvature looks like gravity's cosine on any travel: it is fitted only where the description says
        # gravity exerts no torque the sensor shows (a vertical axis), where a curved position torque can only be
        # the cables'.
        self.curved = self.ranges is not None and self.ranges.load_nm[1] <= SPRING_CURVED_MAX_LOAD_NM
        return self._travel[1] > self._travel[0]

    def n_columns(self) -> int:
        return 3 if self.curved else 2

    def columns(self, ctx: Context) -> list[Column]:
        return super().columns(ctx)[:self.n_columns()]

    def total(self, coef: np.ndarray) -> np.ndarray:
        base = self.base_coef
        return coef + base[:len(coef)] if base is not None else coef

    def _full(self, coef: np.ndarray) -> np.ndarray:
        """The effect's three coefficients from a total of the fitted ones (the model's curvature, or none, where
        the curvature is not fitted)."""
        if len(coef) == 3:
            return np.asarray(coef, float)
        return np.array([*coef, float(self.base_coef[2]) if self.base_coef is not None else 0.0])

    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        return self.plant.reported(self._full(coef))

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        super().extend(model, self._full(coef))

    def plausible(self, coef: np.ndarray) -> bool:
        # A spring that restores at its rest angle, no stiffer than cables make, the rest angle one the model file
        # holds (beyond, it is an offset and a slope).
        v = self.plant.values_from(self._full(coef))
        rest = next(p for p in self.plant.params if p.name == "rest_rad")
        return 0.0 < v["stiffness_nm_rad"] <= SPRING_MAX_NM_RAD and rest.lower <= v["rest_rad"] <= rest.upper

    def relevant(self, coef: np.ndarray) -> bool:
        # Its slope must show over the travel beside its torque there; else it is a constant (an offset's shape).
        k, c = float(coef[0]), float(coef[1])
        lo, hi = self._travel
        mid = -k * 0.5 * (lo + hi) + c
        return abs(k) * (hi - lo) >= SPRING_MIN_SLOPE_SHARE * abs(mid)

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        return ctx.theta_l, "link position [rad]"


# ----------------------------------------------------------------------------- sensor

@register_candidate
class TorqueSensorOffsetCandidate(CandidateEffect):
    """Constant offset of the torque reading [Nm]."""

    name = "torque_sensor_offset"

    _split = True  # both columns, until prepare() finds no command channel

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        # Where the loop sees the offset and where it does not differ only in the torque response to a
        # command: without one, the whole offset is taken as the loop's (the second column left empty).
        self._split = any(b.channel == "command" for b in blocks)
        return True

    def columns(self, ctx: Context) -> list[Column]:
        cols = super().columns(ctx)
        return cols if self._split else [cols[0], [("logged", np.zeros_like(ctx.t))]]

    free_shape = "an offset and a drift of its own in each dataset"

    def free_columns(self, ctx: Context) -> list[Column]:
        return self.columns(ctx) + own_dataset_columns(self.signals(ctx), "sensor",
                                                       [np.ones_like(ctx.t), ctx.t - ctx.t[0]])


#: Least relative scale error of the torque reading that is named [1].
SCALE_RELEVANT = 0.005


@register_candidate
class TorqueSensorScaleCandidate(CandidateEffect):
    """Scale error of the torque reading, ``reading = s tau_J``.

    The column is the reading at the ``reading_scale`` point, with
    coefficient ``(s - 1) / s`` (the reading exceeds the true torque by that
    fraction of itself; on the link channel the model's torque prediction
    stands in for the true torque, which makes the coefficient ``s - 1``
    there, the same to first order).
    """

    name = "torque_sensor_scale"


    def relevant(self, coef: np.ndarray) -> bool:
        # A scale within SCALE_RELEVANT of 1 is below a torque sensor's calibration (and the 1 % the diagnosis is
        # held to): what a filter's or a table's small misfit leaves in the fast band, not a finding.
        return abs(self.plant.values_from(coef)["scale"] - 1.0) >= SCALE_RELEVANT

    def plausible(self, coef: np.ndarray) -> bool:
        # A torque sensor off by more than a factor 1.5 is not a calibration error.
        return coef[0] < 1 and 0.67 <= self.plant.values_from(coef)["scale"] <= 1.5

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        return ctx.tau, "measured joint torque [Nm]"



#: Largest residual SSE, relative to the first order's, at which another shape of the log's filter is preferred.
LOG_FILTER_OTHER_SHAPE = 0.8

#: Least share of the residual a filter removes at its cut-off that it must lose at the slowest cut-off searched
#: (:data:`LOG_FILTER_MIN_HZ`) for the cut-off to be one the data determine.
LOG_FILTER_DETERMINED = 0.1

#: The shapes of a filter before the log the diagnosis compares, each with one searched parameter: one or two
#: first-order stages at a cut-off, or a pure delay.
LOG_FILTER_SHAPES = ("first order", "second order", "pure delay")

#: The damping ratios of a second-order filter before the log searched once the other effects are named (1: two
#: equal first-order stages; 0.71: Butterworth, the usual driver's second order).
LOG_FILTER_DAMPINGS = (1.0, 0.85, 0.71, 0.55, 0.4)


@register_candidate
class TorqueLogFilterCandidate(CandidateEffect):
    """A low-pass between the torque sensor and the log: the logged torque is the true one filtered.

    The column is what the filter does to the model's own predictions, ``F(p) - p`` on each channel (the
    prediction with the model's own effects, its gravity above all, is the model's estimate of the unfiltered
    torque), with a coefficient near 1. The cut-off is searched on a logarithmic grid from
    :data:`LOG_FILTER_MIN_HZ` to 0.4 of the logging rate and refined; it must be one the data determine
    (:data:`LOG_FILTER_DETERMINED`). Three shapes are compared at their best parameter
    (:data:`LOG_FILTER_SHAPES`; the second order here two equal stages): the first order is kept unless another
    leaves at most :data:`LOG_FILTER_OTHER_SHAPE` of its residual (``detail``: ``shape``, and each shape's
    residual SSE relative to the smallest). The diagnosis searches the shape again, the second order's damping
    with it, once the other effects are named through the filter (:meth:`set_shape`). A pure delay extends the
    model as itself (the filter's order 0). It acts on the log only: the robot's loop, its observer and a
    controller the runtime runs see the unfiltered torque.
    """

    name = "torque_log_filter"
    n_nonlinear = 1
    effect: TorqueLogFilter

    def __init__(self) -> None:
        super().__init__()
        self.shape = LOG_FILTER_SHAPES[0]
        self._named: dict[int, dict[str, np.ndarray]] = {}

    def _set(self, shape: str, value: float, damping: float = 1.0) -> None:
        """The shape at its parameter: a cut-off [Hz] (filters) or a delay [s]; not range checked."""
        self.shape = shape
        if shape == "pure delay":
            self.effect = TorqueLogFilter({"order": 0.0, "delay_s": 1e-3})
            self.effect.values["delay_s"] = value
        else:
            second = shape == "second order"
            self.effect = TorqueLogFilter({"order": 2.0 if second else 1.0, "damping": damping if second else 1.0})
            self.effect.values["cutoff_hz"] = value

    @property
    def cutoff_hz(self) -> float:
        """The cut-off [Hz]; of a pure delay, the first order's of the same low-frequency lag."""
        if self.shape == "pure delay":
            return 1.0 / (2.0 * math.pi * self.lag_s)
        return float(self.effect.values["cutoff_hz"])

    def set_cutoff(self, cutoff_hz: float) -> None:
        """The filter's shape at another cut-off [Hz] (a pure delay at the same low-frequency lag)."""
        self.set_shape(self.shape, cutoff_hz, float(self.effect.values["damping"]))

    def set_shape(self, shape: str, cutoff_hz: float, damping: float = 1.0) -> None:
        """The filter as ``shape`` (one of :data:`LOG_FILTER_SHAPES`) at the cut-off ``cutoff_hz`` [Hz] (a pure delay
        of the first order's low-frequency lag there) and, for the second order, the damping ratio ``damping``."""
        self._set(shape, 1.0 / (2.0 * math.pi * cutoff_hz) if shape == "pure delay" else cutoff_hz, damping)

    @property
    def lag_s(self) -> float:
        """The shape's low-frequency lag [s] (:attr:`TorqueLogFilter.lag_s`)."""
        return self.effect.lag_s

    def n_columns(self) -> int:
        return 1

    def columns(self, ctx: Context) -> list[Column]:
        col: Column = []
        named = self._named.get(ctx.index, {}) if ctx.log_filter is None else {}
        for ch, point in (("command", "command_raw"), ("link", "link_raw")):
            if ch in ctx.predicted:
                # The model's own effects where they did not pass the filter already (the model carries it), and
                # what the effects named so far add: the filter acts on the whole torque.
                p = ctx.predicted[ch] if ctx.effects_filtered else ctx.with_effects.get(ch, ctx.predicted[ch])
                p = p + named.get(ch, 0.0)
                col.append((point, logged_change(ctx, ch, p, self.effect) - p))
        return [col]

    def _sum_named(self, blocks: Sequence[Block]) -> dict[int, dict[str, np.ndarray]]:
        """Per dataset and channel, the torque the effects named so far add to the model's (:attr:`beside`),
        where their columns did not pass a filter already (a context carrying one filters them itself)."""
        out: dict[int, dict[str, np.ndarray]] = {}
        for ctx in {b.ctx.index: b.ctx for b in blocks}.values():
            if ctx.log_filter is not None:
                continue
            acc: dict[str, np.ndarray] = {}
            for cand, coef in self.beside:
                for ch, v in contribution(cand, coef, ctx).items():
                    acc[ch] = acc.get(ch, 0.0) + v
            out[ctx.index] = acc
        return out

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        self._named = self._sum_named(blocks)
        fs = 1.0 / max(b.ctx.dt for b in blocks)
        top = 0.4 * fs
        if top <= 2.0:
            return False
        best: dict[str, tuple[float, float]] = {}
        for shape in LOG_FILTER_SHAPES:
            def sse(log_x: float, shape: str = shape) -> float:
                # The whole filter (coefficient 1): with the coefficient free, a slow motion shows only the
                # lag, coefficient over cut-off, and the cut-off drifts.
                x = math.exp(log_x)
                self._set(shape, 1.0 / (2.0 * math.pi * x) if shape == "pure delay" else x)
                Xs = block_columns(blocks, self.columns, 1)
                return float(sum(np.sum((r - X[:, 0]) ** 2) for X, r in zip(Xs, residuals)))

            grid = np.linspace(math.log(LOG_FILTER_MIN_HZ), math.log(top), 24)
            lx = _search_1d(sse, grid)
            best[shape] = (lx, sse(lx))
        # A driver's filter is first order (an exponential smoothing); another shape only where the data ask for
        # it clearly: the same number of parameters, a residual at most LOG_FILTER_OTHER_SHAPE of the first order's.
        shape = min(best, key=lambda k: best[k][1])
        if best[shape][1] > LOG_FILTER_OTHER_SHAPE * best[LOG_FILTER_SHAPES[0]][1]:
            shape = LOG_FILTER_SHAPES[0]
        lx = best[shape][0]
        # The cut-off must be determined: the slowest one searched must lose a share of what the best explains
        # (far below the motion's band a filter only attenuates, the shape of a fast torque the model predicts too
        # large, and the fit improves towards the bound).
        none = float(sum(np.sum(r ** 2) for r in residuals))
        slowest = sse(math.log(LOG_FILTER_MIN_HZ), shape)
        if slowest - best[shape][1] < LOG_FILTER_DETERMINED * (none - best[shape][1]):
            return False
        self._set(shape, 1.0 / (2.0 * math.pi * math.exp(lx)) if shape == "pure delay" else math.exp(lx))
        low = best[shape][1]
        self.detail = {"shape": shape, "log_only": LOG_ONLY,
                       **{f"sse_{k.replace(' ', '_')}_vs_best": v[1] / low if low > 0 else 1.0 for k, v in best.items()}}
        return True

    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        return self.effect.reported(coef)

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        self._replace_effect(model, self.effect.clip(self.effect.to_dict()))

    def plausible(self, coef: np.ndarray) -> bool:
        # The column is the filter's whole action: a coefficient far from 1 is some other lag or misfit. Named
        # after other effects, their unfiltered columns trade with it (1.32-1.57 on the real joint 1, whose second
        # pass, the filter held whole, then predicts the held-out runs at 9-10 %): the screen is that wide.
        return 0.5 <= float(coef[0]) <= 1.5

    def carried(self, coef: np.ndarray) -> np.ndarray:
        # The model file holds the cut-off: the filter acts whole.
        return np.ones_like(coef)

    def from_values(self, values: dict[str, Any]) -> np.ndarray | None:
        self.effect = TorqueLogFilter(values, f"effects.{self.name}")
        self.shape = {0.0: "pure delay", 1.0: "first order", 2.0: "second order"}[self.effect.values["order"]]
        return np.array([1.0])

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        return ctx.t, "time [s]"


@register_candidate
class PeriodicDisturbanceCandidate(CandidateEffect):
    """Time-periodic disturbance of the torque reading at one frequency (mains hum).

    The frequency is the strongest spectral line common to all datasets
    (geometric mean over datasets of the residual periodogram relative to
    its running median), refined by the residual fit; amplitude and phase
    are fitted per dataset (recordings do not share a time origin).
    """

    name = "periodic_disturbance"
    n_nonlinear = 1
    effect: PeriodicDisturbance

    @property
    def frequency(self) -> float:
        """The disturbance's frequency [Hz] (the effect's)."""
        return self.effect.values["frequency_hz"]

    @frequency.setter
    def frequency(self, f: float) -> None:
        # Not range checked: the plant file's range is the simulator's band, a log's may be wider.
        self.effect = PeriodicDisturbance()
        self.effect.values["frequency_hz"] = float(f)

    per_dataset = True

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        # Per dataset, the fullest-band channel: the command channel when there is one.
        best: dict[int, tuple[Block, np.ndarray]] = {}
        for b, r in zip(blocks, residuals):
            if b.ctx.index not in best or b.channel == "command":
                best[b.ctx.index] = (b, r)
        grid_hi = min(0.45 / b.ctx.dt if b.channel == "command" else 1.5 * b.ctx.cutoff_hz for b, _ in best.values())
        grid = np.arange(1.0, grid_hi, 0.02)
        if len(grid) < 10:
            return False
        score = np.zeros_like(grid)
        for b, r in best.values():
            dt = b.ctx.dt * (np.median(np.diff(np.nonzero(b.mask)[0])) if np.count_nonzero(b.mask) > 1 else 1)
            score += np.log(line_ratio(r, dt, grid))
        i0 = int(np.argmax(score))
        f0 = grid[i0]
        # A hum that is not a pure sinusoid: its strongest line relative to the background may be a harmonic.
        # The fundamental is the lowest f0 / k that is itself a clear line (half the peak's log-ratio or more).
        for k in (3, 2):
            near = np.abs(grid - f0 / k) <= 0.1
            if near.any() and score[near].max() >= 0.5 * score[i0] > 0:
                f0 = grid[near][int(np.argmax(score[near]))]
                break

        def sse(f: float) -> float:
            self.frequency = f
            return _sse_of(blocks, residuals, self.columns, self.n_columns())

        span = 0.3
        self.frequency = _search_1d(sse, f0 + np.linspace(-span, span, 13))
        return True

    free_shape = "harmonics 1-3 of the frequency"

    def free_columns(self, ctx: Context) -> list[Column]:
        sig = self.signals(ctx)
        return self.columns(ctx) + self.effect.harmonic_columns(sig, 2) + self.effect.harmonic_columns(sig, 3)

    def from_values(self, values: dict[str, Any]) -> np.ndarray | None:
        coef = super().from_values(values)
        return None if coef is None else np.tile(coef, self.n_datasets)

    def evidence_axis(self, ctx: Context) -> tuple[np.ndarray, str]:
        period = 1.0 / self.frequency
        return np.mod(ctx.t - ctx.t[0], period), f"time mod {period * 1e3:.2f} ms [s]"


#: Tolerated change of each of Jc, bc, K, Jl by the model_parameters refit (a factor), and of Td [s].
MODEL_PARAMETER_FACTOR = 2.0
MODEL_PARAMETER_TD_S = 0.01
#: Least change for model_parameters to be named: the fit's accuracy on joints with real effects (the
#: robustness target of ``fit``: 3 % of Jc, bc, K, Jl and 0.5 ms of Td). Smaller corrections are what
#: the named effects' shape errors leave behind, not a wrong model.
MODEL_PARAMETER_RELEVANT = 0.03
MODEL_PARAMETER_RELEVANT_TD_S = 5e-4
#: Least held-out reduction of the residual for ``model_parameters`` to be named: a refit of eq (4) absorbs
#: a few per cent of any misfit, which is no evidence that the parameters are off.
MIN_GAIN_MODEL = 0.10
_MODEL_KEYS = ("Jc", "bc", "K", "Jl", "Td")
_CHANNEL_PARAMETERS = {"link": ("K", "Jl"), "command": _MODEL_KEYS}  # what each channel's prediction depends on
_MODEL_JSON = {"Jc": "Jc_kgm2", "bc": "bc_nms_rad", "K": "K_nm_rad", "Jl": "Jl_kgm2", "Td": "Td_s"}


def _state_digest(blocks: Sequence[Block], residuals: Sequence[np.ndarray], ctxs: Iterable[Context]) -> str:
    """A digest of what a search on the blocks' residuals depends on: the residuals, the blocks (channel, weight,
    mask) and each context's model, prediction, table and filter before the log."""
    h = hashlib.blake2b(digest_size=16)
    for b, r in zip(blocks, residuals):
        h.update(repr((b.ctx.index, b.channel, float(b.weight))).encode())
        h.update(np.ascontiguousarray(b.mask).tobytes())
        h.update(np.ascontiguousarray(r, float).tobytes())
    for ctx in ctxs:
        lf = ctx.log_filter
        h.update(repr((ctx.index, sorted(ctx.params.items()), ctx.link_from_eq9,
                       None if lf is None else sorted(lf.to_dict().items()))).encode())
        for a in (*(ctx.predicted[ch] for ch in sorted(ctx.predicted)), ctx.f0, ctx.reaction):
            if a is not None:
                h.update(np.ascontiguousarray(a, float).tobytes())
    return h.hexdigest()


@register_candidate
class ModelParametersCandidate(CandidateEffect):
    """The model's own eq (1)-(4) parameters are off: Jc, bc, K, Jl and Td refitted together.

    A wrong parameter is not an extra effect, and explaining it by one (a
    sensor scale for a wrong K, a delay for a wrong bc) names something the
    joint does not have. The parameters are searched on the current residual
    through the exact predictions of both channels
    (:func:`~iiwa_ident.diagnose._predict.predict_channel`): first the delay
    alone on a grid (a delay error of a few ms is far from linear on a
    chirp), then all of them by nonlinear least squares, each within a factor
    :data:`MODEL_PARAMETER_FACTOR` of the model's and the delay within
    :data:`MODEL_PARAMETER_TD_S`. It is named only when a parameter moves by
    more than :data:`MODEL_PARAMETER_RELEVANT` (Td: :data:`MODEL_PARAMETER_RELEVANT_TD_S`).
    Without a command channel (position-controlled
    runs) only Jl and K are searched. The one column is the change of the
    predictions, with a coefficient close to 1.
    """

    name = "model_parameters"
    summary = "the model's own parameters Jc, bc, K, Jl, Td are off"
    n_nonlinear = 5
    min_gain = MIN_GAIN_MODEL
    is_effect = False

    def __init__(self) -> None:
        super().__init__()
        self.refit: dict[str, float] = {}
        self._model: dict[str, float] = {}
        self._cache: dict[int, dict[str, np.ndarray]] = {}
        self._predictions: dict[tuple, np.ndarray] = {}


    def n_columns(self) -> int:
        return 1

    def _changes(self, ctx: Context, params: dict[str, float]) -> dict[str, np.ndarray]:
        out = {}
        for ch in ctx.channels:
            # The link channel depends on K and Jl only: the delay's grid and its finite differences reuse it.
            lf = ctx.log_filter
            key = (ctx.index, ch, None if lf is None else tuple(lf.to_dict().items()),
                   *(params[k] for k in _CHANNEL_PARAMETERS[ch]))
            if key not in self._predictions:
                if len(self._predictions) >= 16:  # a few recent ones are all the reuse there is
                    del self._predictions[next(iter(self._predictions))]
                change = predict_channel(ctx, ch, params) - ctx.predicted[ch]
                self._predictions[key] = logged_change(ctx, ch, change)
            out[ch] = self._predictions[key]
        return out

    def prepare(self, blocks: Sequence[Block], residuals: Sequence[np.ndarray]) -> bool:
        super().prepare(blocks, residuals)
        self._predictions = {}
        self._model = dict(blocks[0].ctx.params)
        self.detail.update({f"model_{_MODEL_JSON[k]}": v for k, v in self._model.items()})
        has_command = any(b.channel == "command" for b in blocks)
        free = list(_MODEL_KEYS) if has_command else ["K", "Jl"]
        self.n_nonlinear = len(free)
        ctxs = {b.ctx.index: b.ctx for b in blocks}
        # The search is the diagnosis's costliest step, and a diagnosis that names again (through another filter
        # start, without a suspect) meets the same residual again: once per residual and state of the contexts.
        key = ("model_parameters", _state_digest(blocks, residuals, ctxs.values()))
        memo = blocks[0].ctx.memo
        if key in memo:
            self.refit, self.n_nonlinear = dict(memo[key]), len(free)
            self._cache = {}
            return True

        def params_of(x: np.ndarray) -> dict[str, float]:
            p = dict(self._model)
            for k, v in zip(free, x):
                p[k] = self._model["Td"] + v if k == "Td" else self._model[k] * math.exp(v)
            return p

        def residual_vector(x: np.ndarray) -> np.ndarray:
            p = params_of(x)
            changes = {i: self._changes(c, p) for i, c in ctxs.items()}
            parts = [r - changes[b.ctx.index][b.channel][b.mask] * b.weight for b, r in zip(blocks, residuals)]
            return np.concatenate(parts)

        x0 = np.zeros(len(free))
        if has_command:
            # The delay first, alone, on a grid: a chirp's phase wraps within a few ms.
            Td = self._model["Td"]
            dt = min(b.ctx.dt for b in blocks)
            it = free.index("Td")

            def sse_td(change: float) -> float:
                x = x0.copy()
                x[it] = change
                return float(np.sum(residual_vector(x) ** 2))

            grid = np.arange(-min(Td, MODEL_PARAMETER_TD_S), MODEL_PARAMETER_TD_S + 1e-9, max(dt / 2, 2.5e-4))
            x0[it] = _search_1d(sse_td, grid)
        span = math.log(MODEL_PARAMETER_FACTOR)
        lo = np.array([-self._model["Td"] if k == "Td" else -span for k in free])
        hi = np.array([MODEL_PARAMETER_TD_S if k == "Td" else span for k in free])
        x0 = np.clip(x0, lo + 1e-12, hi - 1e-12)
        scale = np.array([1e-4 if k == "Td" else 1e-2 for k in free])
        try:
            sol = optimize.least_squares(residual_vector, x0, bounds=(lo, hi), x_scale=scale, diff_step=1e-6,
                                         max_nfev=40 * len(free), method="trf")
            x = sol.x if np.sum(sol.fun ** 2) <= np.sum(residual_vector(x0) ** 2) else x0
        except (ValueError, np.linalg.LinAlgError):
            x = x0
        self.refit = params_of(x)
        memo[key] = dict(self.refit)
        self._cache = {}
        return True

    def columns(self, ctx: Context) -> list[Column]:
        if ctx.index not in self._cache:
            changes = self._changes(ctx, self.refit) if self.refit else {}
            self._cache[ctx.index] = changes
        ch = self._cache[ctx.index]
        col: Column = []
        if "command" in ch:
            col.append(("command_raw", ch["command"]))
        if "link" in ch:
            col.append(("link_raw", ch["link"]))
        return [col]

    def _values(self, coef) -> dict[str, float]:
        # The coefficient scales the change of the predictions; to first order it scales each parameter's change
        # (a coefficient far from 1 that would take a parameter below zero says the change is something else).
        c = float(coef[0]) if len(coef) else 1.0
        return {k: self._model[k] + c * (self.refit[k] - self._model[k]) for k in _MODEL_KEYS}

    def parameters(self, coef: np.ndarray) -> dict[str, float]:
        return {_MODEL_JSON[k]: v for k, v in self._values(coef).items()}

    def relevant(self, coef: np.ndarray) -> bool:
        values = self._values(coef)
        if abs(values["Td"] - self._model["Td"]) > MODEL_PARAMETER_RELEVANT_TD_S:
            return True
        return any(abs(values[k] / self._model[k] - 1.0) > MODEL_PARAMETER_RELEVANT for k in ("Jc", "bc", "K", "Jl"))

    def plausible(self, coef: np.ndarray) -> bool:
        # Positive; and where the robot is described, a link inertia the arm can have at its pose.
        values = self._values(coef)
        if self.ranges is not None and not self.ranges.Jl_kgm2[0] <= values["Jl"] <= self.ranges.Jl_kgm2[1]:
            return False
        return all(v > 0 for v in values.values())

    def extend(self, model: JointModel, coef: np.ndarray) -> None:
        for k, v in self._values(coef).items():
            model.parameters[k].value = float(v)
            model.parameters[k].std = None
        model.effects = [e for e in model.effects if e.get("name") != "input_delay"]
