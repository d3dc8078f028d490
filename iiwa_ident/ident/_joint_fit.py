"""The joint fit: inverse dynamics for the link-side effects, then the sampled-data output-error fit.

Two estimators of eqs (1)-(4) exist, each strong where the other is weak:

- :func:`iiwa_ident.ident._idim.fit_idim` (IDIM-IV) uses every channel, is
  linear in the parameters, fits link friction, a position-dependent load and
  a sensor offset, and needs no start values; but its continuous-time
  equations on sampled data are approximate near the Nyquist frequency.
- :func:`iiwa_ident.ident._tf_fit.fit_transfer_function` is exact for the
  sampled, delayed data and reaches the Cramer-Rao bound on clean data; but
  it needs start values and has no link friction or load.

:func:`fit_joint` runs the first, then the second from its values with the
estimated friction, load and gravity-model torques as known inputs. What
each step gives is measured by ``bench/bench_robustness.py fit``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from iiwa_ident.datasets import Dataset, band_limited_problem, dataset_pose, read_dataset, sha256_file
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._bla import BlaFit, best_linear_approximation, fit_bla
from iiwa_ident.ident._idim import (
    STICK_COULOMB_NM,
    IdimResult,
    LinkEffectEstimate,
    fit_idim,
)
from iiwa_ident.ident._initial import initial_estimate
from iiwa_ident.ident._log_filter import LOG_ONLY, LogFilterEstimate, estimate_log_filter, log_filter_text, unfiltered
from iiwa_ident.ident._model_file import read_model
from iiwa_ident.ident._records import prepare_records
from iiwa_ident.ident._starting_model import check_model_matches
from iiwa_ident.ident._tf_fit import (
    FitResult,
    RippleTerms,
    fit_transfer_function,
    output_residual_rms,
)
from iiwa_ident.model import PARAMETER_NAMES, PARAMETER_UNITS, JointModel, Parameter, RippleTable, Source, table1_model
from iiwa_ident.sim import TorqueLogFilter

__all__ = ["METHODS", "fit_joint", "fit_model", "model_effects"]

#: ``auto``: ``idim`` when the link shows Coulomb friction, else ``joint``; ``joint``: IDIM-IV, then the
#: output-error fit with its effects as known inputs and the transmission ripple's terms; ``idim``: IDIM-IV
#: alone; ``eq4``: the output-error fit of eq (4) alone (no link-side effects, no ripple).
METHODS: tuple[str, ...] = ("auto", "joint", "idim", "eq4")
_METHOD_TEXT = {
    "joint": "inverse dynamics (IDIM-IV) for the link-side effects, then time-domain output-error maximum "
             "likelihood; ZOH-sampled eqs (1)-(4) with fractional delay and the effects' torques as known inputs; "
             "outputs tau_j and q_m; per-block noise levels",
    "joint+ripple": "inverse dynamics (IDIM-IV) for the link-side effects, then time-domain output-error maximum "
                    "likelihood; ZOH-sampled eqs (1)-(5) with fractional delay, the effects' torques as known "
                    "inputs and the transmission ripple's deflection and reaction (its table, and the "
                    "coefficients of its first harmonics fitted alongside); outputs tau_j and q_m; per-block "
                    "noise levels",
    "idim": "inverse dynamics (IDIM-IV): eqs (1)-(3) with link friction, load and sensor offset, exact spectral "
            "derivatives, predicted-torque instruments, block sandwich std",
    "eq4": "time-domain output-error maximum likelihood; ZOH-sampled eqs (1)-(4) with fractional delay; "
           "outputs tau_j and q_m; per-block noise levels",
}


def _from_idim(idim: IdimResult, datasets: Sequence[Dataset], log_filter: TorqueLogFilter | None = None
               ) -> FitResult:
    """The IDIM-IV estimate with the output-error fit's diagnostics at its values (no search; a log filter at
    its start value)."""
    result = fit_transfer_function(datasets, initial=dict(idim.parameters), known=idim.known_inputs, refine=False,
                                   log_filter=log_filter)
    result.std = dict(idim.std)
    result.std_sandwich = dict(idim.std)
    result.std_method = ("block sandwich of the inverse-dynamics (IDIM-IV) estimating equations over quarter-second "
                         "blocks; describes the noise and slow residuals, not effects of another shape")
    result.covariance = np.diag([idim.std[k] ** 2 for k in PARAMETER_NAMES])
    result.correlation = np.eye(len(PARAMETER_NAMES))
    # The output-error std is of no use here; its warnings about it are replaced by IDIM's own.
    result.warnings = [w for w in result.warnings if "std" not in w] + list(idim.warnings)
    return result


#: Largest factor by which the output-error fit may move Jc, bc, K or Jl away from IDIM-IV's values.
MAX_DEPARTURE_FACTOR = 1.5
#: Largest shift of the delay between the two [s].
MAX_DEPARTURE_TD_S = 2e-3


def _departure(fitted: dict[str, float], start: dict[str, float]) -> str:
    """What moved too far between the two estimates ('' when nothing did)."""
    for k in PARAMETER_NAMES[:4]:
        ratio = fitted[k] / start[k]
        if not 1.0 / MAX_DEPARTURE_FACTOR <= ratio <= MAX_DEPARTURE_FACTOR:
            return f"{k} by a factor {ratio:.3g}"
    if abs(fitted["Td"] - start["Td"]) > MAX_DEPARTURE_TD_S:
        return f"Td by {1e3 * (fitted['Td'] - start['Td']):.2g} ms"
    return ""


def _nll(rms: Sequence[dict[str, float]], datasets: Sequence[Dataset]) -> float:
    """Gaussian negative log-likelihood of residuals of these RMS levels (per dataset and output), less constants.

    Comparable between models with different known inputs, unlike a fit's ``cost``, whose weights are
    re-estimated from its own residuals.
    """
    return float(sum(ds.n_samples * (math.log(n["tau_j_nm"]) + math.log(n["q_m_rad"]))
                     for ds, n in zip(datasets, rms)))


def fit_joint(datasets: Sequence[Dataset], *, method: str = "auto",
              ripple_table: RippleTable | None = None) -> FitResult:
    """Fit a joint's chirps: eqs (1)-(4) with delay, link friction, load and sensor offset.

    Parameters
    ----------
    datasets : sequence of Dataset
        Torque-commanded chirps of one joint.
    method : {"auto", "joint", "idim", "eq4"}
        See :data:`METHODS`.
    ripple_table : RippleTable, optional
        The ripple's lookup table (from the ripple command), which also gives
        its period (without one IDIM-IV searches the period, see
        :func:`~iiwa_ident.ident._idim.fit_idim`): the output-error fit takes its deflection as known and
        fits the first harmonics' coefficients on top
        (:class:`~iiwa_ident.ident._tf_fit.RippleTerms`). Without a table, a
        ripple IDIM-IV finds is fitted by those coefficients alone.

    Returns
    -------
    FitResult
        With ``method`` (``"joint+ripple"`` when the ripple was in the
        output-error model) and ``effects`` (the link-side effects, from
        IDIM-IV).

    Raises
    ------
    IiwaIdentError
        The data cannot identify a parameter (the message names it and
        why) or a file cannot be fitted.
    """
    if method not in METHODS:
        raise IiwaIdentError(f"unknown fit method {method!r} (known: {', '.join(METHODS)})")
    prepare_records(datasets)  # a record the fit cannot take is refused before any estimate is tried on it
    candidate = _log_filter_candidate(datasets)
    if candidate is None:
        return _fit_joint(datasets, method, ripple_table, None)
    # The data ask for a filter before the log: fitted through it, and without it where that fits at all;
    # the likelihood (BIC: the cut-off is one more parameter) decides.
    try:
        plain: FitResult | None = _fit_joint(datasets, method, ripple_table, None)
        refusal = None
    except IiwaIdentError as err:
        plain, refusal = None, err
    try:
        filtered = _fit_joint(datasets, method, ripple_table, candidate.effect())
    except IiwaIdentError:
        if plain is None:
            assert refusal is not None  # plain is None only where its fit was refused
            raise refusal from None
        return plain
    assert filtered.log_filter is not None
    moved = filtered.log_filter["cutoff_hz"] / candidate.cutoff_hz - 1.0
    if abs(moved) > _REFIT_CUTOFF_SHARE:
        # The starts came from the torque undone with the phase's cut-off: once more with the fitted one.
        again = TorqueLogFilter({"cutoff_hz": filtered.log_filter["cutoff_hz"], "order": float(candidate.order)})
        try:
            filtered = _fit_joint(datasets, method, ripple_table, again)
        except IiwaIdentError:
            pass
    penalty = 0.5 * math.log(sum(2 * ds.n_samples for ds in datasets))
    if plain is not None and _nll(plain.noise, datasets) - _nll(filtered.noise, datasets) <= penalty:
        return plain
    lf = filtered.log_filter
    assert lf is not None
    # The phase's estimate and the output-error fit's weigh the data differently: where the model misses
    # part of the response, their difference is added to the std, as for the parameters (_model_error_std).
    lf["std_robust"] = math.hypot(lf["std"], lf["cutoff_hz"] - candidate.cutoff_hz) if filtered.model_rejected \
        else lf["std"]
    filtered.warnings.insert(0, f"tau_j was low-pass filtered before it was logged: {log_filter_text(lf)}, fitted "
                                f"with the parameters; {LOG_ONLY}")
    return filtered


#: Relative change of the cut-off between the phase's estimate and the fit above which the starts are made again.
_REFIT_CUTOFF_SHARE = 0.01


def _log_filter_candidate(datasets: Sequence[Dataset]) -> LogFilterEstimate | None:
    """A filter before the log the data ask for: the import's check calls a run band-limited
    (:func:`~iiwa_ident.datasets.band_limited_problem`) or the phase of ``tau_j`` against ``q_m`` shows one
    (:func:`~iiwa_ident.ident._log_filter.estimate_log_filter`), and the phase has a filter's shape; None
    otherwise."""
    try:
        estimate = estimate_log_filter(prepare_records(datasets))
    except IiwaIdentError:
        return None  # the fit itself says what is wrong with the data
    if estimate is None or not estimate.filter_shaped:
        return None
    if estimate.shown or any(band_limited_problem(ds) for ds in datasets):
        return estimate
    return None


def _fit_joint(datasets: Sequence[Dataset], method: str, ripple_table: RippleTable | None,
               log_filter: TorqueLogFilter | None) -> FitResult:
    """:func:`fit_joint` with or without a filter before the log: the starts (inverse dynamics, eq (4)'s
    start values) from the torque with the filter undone (:func:`~iiwa_ident.ident._log_filter.unfiltered`), every
    output-error fit through it."""
    starts = datasets
    if log_filter is not None:
        tops = [r.f_hi for r in prepare_records(datasets)]
        starts = [unfiltered(ds, log_filter, top) for ds, top in zip(datasets, tops)]
    if method == "eq4":
        return _eq4_only(datasets, starts, log_filter)
    idim = fit_idim(starts, None if ripple_table is None else ripple_table.period_rad)
    ripple = idim.effect("transmission_ripple")
    terms = None
    if ripple_table is not None:
        terms = RippleTerms(ripple_table.period_rad, table=ripple_table)
    elif ripple is not None:
        terms = RippleTerms(ripple.values["period_rad"])
    if method == "auto":
        # A sticking link makes the friction torque unknown while it sticks; the output-error
        # fit would have to simulate through it, the inverse dynamics leave those samples out.
        friction = idim.effect("link_friction")
        sticks = friction is not None and friction.significant and friction.values["coulomb_nm"] > STICK_COULOMB_NM
        method = "idim" if sticks else "joint"
    oe: FitResult | None = None  # the output-error estimate, to compare with IDIM-IV's
    if method == "idim":
        if log_filter is not None:
            # The inverse dynamics do not fit the cut-off: the output-error fit from their values does.
            try:
                oe = fit_transfer_function(datasets, initial=dict(idim.parameters), known=idim.known_inputs,
                                           ripple=terms, log_filter=log_filter)
                assert oe.log_filter is not None
                log_filter = TorqueLogFilter({"cutoff_hz": oe.log_filter["cutoff_hz"],
                                              "order": log_filter.values["order"]})
            except IiwaIdentError:
                pass
        result = _from_idim(idim, datasets, log_filter)
        if oe is not None:
            result.log_filter = oe.log_filter
    else:
        start = dict(idim.parameters)
        result = fit_transfer_function(datasets, initial=start, known=idim.known_inputs, ripple=terms,
                                       log_filter=log_filter)
        if terms is not None and terms.table is None and ripple is not None:
            # The output-error fit refined the searched period: the later fits and the effect start there.
            period = result.ripple_period_rad
            assert period is not None  # a fit with a searched period reports it
            terms = replace(terms, period_rad=period, search=False)
            ripple.values["period_rad"] = period
        if any(idim.known_inputs):
            result = _best_known_inputs(datasets, idim, result, terms)
        if terms is not None:
            method = "joint+ripple"
        oe = result
        if _departure(result.parameters, idim.parameters):
            result = _against_idim(datasets, starts, idim, result, terms, log_filter)
            method = "idim" if result.method == "idim" else method
    if method != "idim":
        _model_error_std(result, idim.parameters, idim.std, "the inverse-dynamics (IDIM-IV) estimate")
    else:
        if oe is None and result.model_rejected:  # the output-error estimate only where the std needs it
            try:
                oe = fit_transfer_function(datasets, initial=dict(idim.parameters), known=idim.known_inputs,
                                           ripple=terms, log_filter=log_filter)
            except IiwaIdentError:
                pass
        _model_error_std(result, None if oe is None else oe.parameters, None if oe is None else oe.std,
                         "the output-error estimate")
    result.method = method
    result.effects = idim.effects
    result.lines_hz = idim.lines_hz
    return result


def _eq4_only(datasets: Sequence[Dataset], starts: Sequence[Dataset],
              log_filter: TorqueLogFilter | None) -> FitResult:
    """Eq (4) alone (``method="eq4"``); the inverse dynamics only where the std needs a second estimate."""
    result = fit_transfer_function(datasets, log_filter=log_filter,
                                   initial=None if log_filter is None else initial_estimate(starts)[0])
    result.method = "eq4"
    other = None
    if result.model_rejected:  # a second estimate only where the std needs it
        try:
            other = fit_idim(starts)
        except IiwaIdentError:
            pass
    _model_error_std(result, None if other is None else other.parameters, None if other is None else other.std,
                     "the inverse-dynamics (IDIM-IV) estimate")
    return result


def _best_known_inputs(datasets: Sequence[Dataset], idim: IdimResult, result: FitResult,
                       terms: RippleTerms | None) -> FitResult:
    """The output-error fit with the inverse dynamics' effect torques, those without the gravity model, or none.

    The inverse dynamics' effect terms can absorb its own approximation error (the gravity-model terms did so
    at 20-40 std on joints without any) or a disturbance it has no term for (a hum became a load gradient and
    moved Jl by 7 %); the exact output-error model decides. Compared at the fitted values first, so that a
    second fit runs only when it may win.
    """
    link_only = [[(kind, s) for kind, s in inputs if kind != "motor"] for inputs in idim.known_inputs]
    options = [idim.known_inputs] + ([link_only] if link_only != idim.known_inputs else []) + \
        [[[] for _ in datasets]]
    here = result.parameters
    fitted_filter = None if result.log_filter is None else TorqueLogFilter(
        {"cutoff_hz": result.log_filter["cutoff_hz"], "order": float(result.log_filter["order"])})
    nll = [_nll(output_residual_rms(datasets, here, known, terms, fitted_filter), datasets) for known in options]
    best = int(np.argmin(nll))
    if not best:
        return result
    return fit_transfer_function(datasets, initial=here, known=options[best], ripple=terms, log_filter=fitted_filter)


def _against_idim(datasets: Sequence[Dataset], starts: Sequence[Dataset], idim: IdimResult, result: FitResult,
                  terms: RippleTerms | None, log_filter: TorqueLogFilter | None) -> FitResult:
    """The output-error fit that moved far from the inverse dynamics, or the inverse dynamics' (``method``
    ``"idim"``): whichever eq (4) alone, searched from the data, agrees with.

    Both estimate the same parameters; a large disagreement usually means the output-error search went astray
    (it is local and simulates through the effects). But a disturbance in the torque signal (a hum) can throw
    the inverse dynamics off instead.
    """
    moved = _departure(result.parameters, idim.parameters)
    try:
        alone = fit_transfer_function(datasets, ripple=terms, log_filter=log_filter,
                                      initial=None if log_filter is None else initial_estimate(starts)[0])
    except IiwaIdentError:
        alone = None
    if alone is not None and not _departure(result.parameters, alone.parameters) \
            and _departure(idim.parameters, alone.parameters):
        result.warnings.append(f"the output-error fit moved {moved} from the inverse-dynamics estimate; "
                               "kept, as the fit of eq (4) alone agrees with it")
        return result
    fallback = _from_idim(idim, datasets, log_filter)
    fallback.warnings.append(f"the output-error fit moved {moved} from the inverse-dynamics estimate; "
                             "the inverse-dynamics values are kept")
    fallback.method = "idim"
    return fallback


def _model_error_std(result: FitResult, other: dict[str, float] | None, other_std: dict[str, float] | None,
                     other_name: str) -> None:
    """Set ``result.std_robust``: its std where the model holds, else widened by the estimators' disagreement.

    Where the residual follows the command the model misses part of the response, and the Fisher or
    sandwich std (which describe the noise) say nothing of the bias this causes. The inverse dynamics and
    the output-error fit weigh the data differently (equation error on every channel against the
    simulated torque and position), so a missing effect biases them differently: their difference is a
    measure of the model error. Under a complete model it is at most the less efficient estimate's
    spread, so ``std_robust^2 = std^2 + std_other^2 + (value - other)^2`` widens the interval by what the
    data cannot tell apart (a Hausman-type comparison; Hausman, Econometrica 46, 1978). Its coverage is
    measured by ``bench/bench_robustness.py coverage``. Without a second estimate the block sandwich
    std is the fallback.
    """
    if not result.model_rejected:
        result.std_robust = dict(result.std)
        result.std_robust_method = "equal to std: the residual is independent of the command"
        if "ripple" in result.method:
            # The residual this speaks of is the fit's own: a model file without a table lacks those terms.
            result.std_robust_method = ("equal to std: the fit's residual, with the ripple's harmonics fitted "
                                        "alongside, is independent of the command")
        return
    if other is None or other_std is None:
        result.std_robust = {k: max(result.std[k], result.std_sandwich[k]) for k in PARAMETER_NAMES}
        result.std_robust_method = ("the residual follows the command; no second estimate: the larger of std and "
                                    "the block sandwich std, which does not cover the bias of a missing effect")
        return
    result.std_robust = {k: math.sqrt(result.std[k] ** 2 + other_std[k] ** 2 + (result.parameters[k] - other[k]) ** 2)
                         for k in PARAMETER_NAMES}
    result.std_robust_method = ("the residual follows the command: std, the std of " + other_name
                                + " and the two estimates' difference added in quadrature")


def model_effects(effects: Sequence[LinkEffectEstimate]) -> list[dict[str, Any]]:
    """The significant fitted effects as model-file ``[[effects]]`` tables (the simulator's parameters).

    Values are clipped into the simulator's ranges (a friction is not negative, a compensated
    fraction lies in [0, 1]); a load whose amplitude could not be fitted (its local gradient only)
    has no simulator form and stays in the fit's JSON.
    """
    out = []
    for e in effects:
        if not e.significant or not all(math.isfinite(v) for v in e.values.values()):
            continue
        if e.name == "link_friction":
            out.append({"name": e.name, "coulomb_nm": max(e.values["coulomb_nm"], 0.0),
                        "viscous_nms_rad": max(e.values["viscous_nms_rad"], 0.0),
                        "smoothing_rad_s": e.values["smoothing_rad_s"]})
        elif e.name == "position_dependent_load" and "amplitude_nm" in e.values:
            out.append({"name": e.name, "amplitude_nm": e.values["amplitude_nm"], "phase_rad": e.values["phase_rad"],
                        "compensated": min(max(e.values["compensated"], 0.0), 1.0)})
        elif e.name == "torque_sensor_offset":
            out.append({"name": e.name, "offset_nm": e.values["offset_nm"]})
    return out


class _FitInputs(NamedTuple):
    """A fit's base model, datasets, their sources (with sha256) and the joint."""

    base: JointModel
    datasets: list[Dataset]
    sources: list[Source]
    joint: int


def _inputs(paths: Sequence[str | os.PathLike], base_model: str | os.PathLike | JointModel | None
            ) -> _FitInputs:
    """The base model, the datasets, the sources (with sha256) and the joint of a fit's input files."""
    if not paths:
        raise IiwaIdentError("fit needs at least one dataset file")
    base_path = None
    if base_model is None:
        base = table1_model()
    elif isinstance(base_model, JointModel):
        base = base_model
    else:
        base_path = Path(base_model)
        base = read_model(base_path)
    datasets = [read_dataset(p) for p in paths]
    sources = [Source(str(p), sha256_file(p), "fit") for p in paths]
    if base_path is not None:
        sources.append(Source(str(base_path), sha256_file(base_path), "base"))
    joint = int(datasets[0].joint)
    if base_model is not None:
        check_model_matches(base, datasets, f"{base_path}: " if base_path else "base model: ")
    return _FitInputs(base, datasets, sources, joint)


def _multisine_model(paths: Sequence[str | os.PathLike], datasets: list[Dataset], base: JointModel,
                     sources: list[Source], joint: int) -> tuple[JointModel, BlaFit]:
    """The model file content from multisine datasets, fitted through their best linear approximation."""
    labels = [str(p) for p in paths]
    if any(int(ds.joint) != joint for ds in datasets):
        raise IiwaIdentError("the datasets are of different joints: " + ", ".join(
            f"{label} joint {ds.joint}" for label, ds in zip(labels, datasets)))
    blas = []
    for label, ds in zip(labels, datasets):
        try:
            blas.append(best_linear_approximation(ds))
        except IiwaIdentError as err:
            raise IiwaIdentError(str(err).replace("the dataset", label, 1)) from None
    result = fit_bla(blas, [1.0 / ds.sample_rate_hz for ds in datasets], labels=labels)
    params = {k: Parameter(result.parameters[k], result.std[k], PARAMETER_UNITS[k], "measured")
              for k in PARAMETER_NAMES}
    ki = base.parameters["KI"]
    params["KI"] = Parameter(ki.value, ki.std, PARAMETER_UNITS["KI"], ki.origin)
    bands = result.variance_bands()
    fit_table: dict[str, Any] = {
        "method": "best linear approximation of random-phase odd multisines (robust method), eq (1)-(4) with "
                  "fractional delay fitted to it for tau_j and q_m, weighted by its total variance",
        "std_method": result.std_method,
        "datasets": len(datasets),
        "chi2_dof": result.chi2_dof,
        "band_dataset": [labels.index(b["dataset"]) for b in bands],
        "band_output": [b["output"] for b in bands],
        "band_lo_hz": [b["lo_hz"] for b in bands],
        "band_hi_hz": [b["hi_hz"] for b in bands],
        "band_noise_rel": [b["noise_rel"] for b in bands],
        "band_nonlinear_rel": [b["nonlinear_rel"] for b in bands],
    }
    std = np.sqrt(np.diag(result.covariance))
    model = JointModel(
        parameters=params, correlation_names=list(PARAMETER_NAMES),
        correlation=result.covariance / np.outer(std, std), ripple=base.ripple, fit=fit_table, sources=sources,
        joint=joint, robot_model=dataset_pose(datasets[0])[0] or base.robot_model,
        description="Eq (4) with delay fitted to the BLA of " + ", ".join(Path(p).name for p in paths))
    return model, result


def fit_model(paths: Sequence[str | os.PathLike], base_model: str | os.PathLike | JointModel | None = None,
              *, method: str = "auto") -> tuple[JointModel, FitResult | BlaFit]:
    """Fit dataset files and build the joint model file content.

    Chirps go to :func:`fit_joint`; multisines
    (:class:`~iiwa_ident.excite.Multisine`, all files) through their best
    linear approximation to :func:`~iiwa_ident.ident.fit_bla`, whose
    ``[fit]`` table carries the std's method, chi2/dof and the BLA's noise and
    nonlinear variance per output and octave band.

    Parameters
    ----------
    paths : sequence of path
        Chirp dataset files (HDF5) of one joint, or multisine files.
    base_model : path or JointModel, optional
        Model whose other parts are kept: ``KI`` (default 25 rad/s, Table I,
        without std), the ripple table (whose period the fit then uses) and
        the robot model.
    method : str
        Estimator (:data:`METHODS`).

    Returns
    -------
    (JointModel, FitResult)
        The model carries ``Jc, bc, K, Jl, Td`` with std, ``KI``, the
        correlation of the five, the significant link-side effects as
        ``[[effects]]`` (their std in ``[fit]``), a ``[fit]`` table of
        diagnostics, and the sha256 of every input file.
    """
    base, datasets, sources, joint = _inputs(paths, base_model)
    kinds = {ds.experiment for ds in datasets}
    if "multisine" in kinds:
        if kinds != {"multisine"}:
            raise IiwaIdentError("fit multisines alone, not together with chirps or other data")
        if method != "auto":
            raise IiwaIdentError(f"method {method!r} is a chirp estimator; multisines are fitted through their best "
                                 "linear approximation")
        return _multisine_model(paths, datasets, base, sources, joint)
    # A ripple table in the base model (from the ripple command) gives its period and shape.
    result = fit_joint(datasets, method=method, ripple_table=base.ripple)

    params = {k: Parameter(result.parameters[k], result.std[k], PARAMETER_UNITS[k], "measured")
              for k in PARAMETER_NAMES}
    ki = base.parameters["KI"]
    params["KI"] = Parameter(ki.value, ki.std, PARAMETER_UNITS["KI"], ki.origin)
    fit_table: dict[str, Any] = {
        "method": _METHOD_TEXT[result.method],
        "std_method": result.std_method,
        "datasets": len(datasets),
        "cost": result.cost,
        "evaluations": result.n_evaluations,
        "std_sandwich": [result.std_sandwich[k] for k in PARAMETER_NAMES],
        "std_robust": [result.std_robust.get(k, result.std[k]) for k in PARAMETER_NAMES],
        "std_robust_method": result.std_robust_method or "equal to std",
        "model_rejected": result.model_rejected,
        "noise_tau_j_nm": [n["tau_j_nm"] for n in result.noise],
        "noise_q_m_rad": [n["q_m_rad"] for n in result.noise],
        "start": [float(result.initial[0][k]) for k in PARAMETER_NAMES],
        "band_dataset": [result.labels.index(b.dataset) for b in result.bands],
        "band_lo_hz": [b.lo_hz for b in result.bands],
        "band_hi_hz": [b.hi_hz for b in result.bands],
        "band_rel_error": [b.rel_error for b in result.bands],
        "band_z_rms": [b.z_rms for b in result.bands],
        "band_coherence": [b.coherence for b in result.bands],
    }
    nl = [(i, b) for i, bands in enumerate(result.nonlinear) for b in bands]
    if nl:
        fit_table.update({
            "nonlinear_dataset": [i for i, _ in nl],
            "nonlinear_lo_hz": [b.lo_hz for _, b in nl],
            "nonlinear_hi_hz": [b.hi_hz for _, b in nl],
            "nonlinear_share": [b.share for _, b in nl],
        })
    effects = model_effects(result.effects)
    std_of = {(e.name, k): s for e in result.effects for k, s in e.std.items()}
    if result.log_filter is not None:  # the logged torque's filter, for compare and diagnose to simulate
        lf = result.log_filter
        effects.append({"name": "torque_log_filter", "cutoff_hz": lf["cutoff_hz"], "order": float(lf["order"])})
        std_of[("torque_log_filter", "cutoff_hz")] = lf.get("std_robust", lf["std"])
        std_of[("torque_log_filter", "order")] = 0.0
    if effects:
        fit_table["effect_std_names"] = [f"{e['name']}.{k}" for e in effects for k in e if k != "name"]
        fit_table["effect_std"] = [std_of[tuple(n.split(".", 1))] for n in fit_table["effect_std_names"]]
    if result.warnings:
        fit_table["warnings"] = list(result.warnings)
    names = ", ".join(Path(p).name for p in paths)
    model = JointModel(
        parameters=params,
        correlation_names=list(PARAMETER_NAMES),
        correlation=result.correlation,
        ripple=base.ripple,
        fit=fit_table,
        sources=sources,
        joint=joint,
        robot_model=dataset_pose(datasets[0])[0] or base.robot_model,
        effects=effects,
        description=f"Eq (4) with delay fitted to {names}",
    )
    return model, result
