"""A filter between the torque sensor and the log, seen in a chirp: its start value and the unfiltered torque.

A driver that low-passes the logged ``tau_j`` (a ROS state topic's filter) leaves ``q_m`` as it was, so the
two outputs of one chirp disagree in phase by the filter's lag. From eqs (2)-(3) ``q_m / tau_j = 1/K +
1/(Jl s^2)`` is real at every frequency (negative below the link's antiresonance ``sqrt(K/Jl)``, positive above):
the phase of ``H_tau / H_q``, both H1 from the command, is the filter's phase modulo pi, whatever the joint's
parameters, the delay or the torque loop. :func:`estimate_log_filter` fits the cut-off of one or two
first-order stages to it (weighted by the H1's phase std); the output-error fit refines it with the
parameters (:func:`~iiwa_ident.ident._tf_fit.fit_transfer_function`).

The inverse-dynamics start (:func:`~iiwa_ident.ident._idim.fit_idim`) needs the torque itself:
:func:`unfiltered` undoes the filter in the frequency domain up to the excitation's top and holds the inverse's
gain beyond it, so that the sensor's noise is not amplified without bound.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from iiwa_ident.datasets import Dataset
from iiwa_ident.ident._initial import record_frf
from iiwa_ident.ident._records import FitRecord
from iiwa_ident.sim import TorqueLogFilter

__all__ = ["LogFilterEstimate", "estimate_log_filter", "unfiltered", "unfiltered_torque", "log_filter_text", "LOG_FILTER_MIN_LAG_SIGMA", "LOG_FILTER_MIN_EXPLAINED",
           "LOG_FILTER_MIN_HZ", "LOG_FILTER_MAX_HZ", "LOG_ONLY", "lowest_cutoff_hz"]

#: Lowest cut-off of a log filter searched [Hz] (a time constant of 0.8 s): slower, a lag is a misfit of the
#: motion, not a filter. The real iiwa 14 logs at 200 Hz show filters at 0.85-2.6 Hz.
LOG_FILTER_MIN_HZ = 0.2
#: Highest cut-off searched [Hz] (below 0.45 of the rate too): the simulator's effect's range.
LOG_FILTER_MAX_HZ = next(p.upper for p in TorqueLogFilter.params if p.name == "cutoff_hz")

#: What a filter before the log means for the robot (said wherever it is named).
LOG_ONLY = ("the log only: the robot's torque loop, its observer and a controller the runtime runs use the "
            "unfiltered torque; the model's other parameters and effects are of the unfiltered joint")

#: How clearly the phase must show a filter to make it a candidate: the square root of the weighted squared
#: phase error it removes (a chi-square of one degree of freedom), in std.
LOG_FILTER_MIN_LAG_SIGMA = 5.0
#: Least share of the weighted squared phase a filter must explain to be one (a filter leaves the noise only:
#: 0.9999 in simulation; link damping, a load or the apart data path's model leave 0.03-0.83).
LOG_FILTER_MIN_EXPLAINED = 0.95
_TOP_SHARE = 0.45  # the highest cut-off considered, as a share of the sampling rate
_AT_TOP = 0.8  # a cut-off above this share of the highest is the search's bound, not a filter the data show


def lowest_cutoff_hz(records: Sequence[FitRecord]) -> float:
    """The lowest cut-off [Hz] a fit of ``records`` searches: :data:`LOG_FILTER_MIN_HZ`, or the chirps' lowest
    frequency where that is higher (below its band a chirp does not determine a filter: two stages far below
    it fit a chirp's ratio as well as the true one above it)."""
    return max(LOG_FILTER_MIN_HZ, min(float(r.f_lo) for r in records))


@dataclass(frozen=True)
class LogFilterEstimate:
    """The phase's fit of a log filter (:func:`estimate_log_filter`).

    Attributes
    ----------
    cutoff_hz : float
        Cut-off of each stage [Hz].
    order : int
        First-order stages (1 or 2).
    lag_sigma : float
        How clearly the phase shows it: the square root of the weighted squared phase error the filter
        removes [std].
    explained : float
        The share of the weighted squared phase the filter explains: near 1 for a filter; a link's damping or
        a load turns the phase with another shape, which a filter explains in part only.
    at_bound : bool
        The cut-off is at either end of the search (a filter faster than the sampling shows, or a slow
        misfit).
    """

    cutoff_hz: float
    order: int
    lag_sigma: float
    explained: float
    at_bound: bool

    @property
    def filter_shaped(self) -> bool:
        """Whether the phase has a filter's shape (:data:`LOG_FILTER_MIN_EXPLAINED`) within the search's ends."""
        return self.explained >= LOG_FILTER_MIN_EXPLAINED and not self.at_bound

    @property
    def shown(self) -> bool:
        """Whether the data show a filter: of its shape and clearly (:data:`LOG_FILTER_MIN_LAG_SIGMA`)."""
        return self.filter_shaped and self.lag_sigma >= LOG_FILTER_MIN_LAG_SIGMA

    def effect(self) -> TorqueLogFilter:
        """The simulator's effect with these values (the fit's start)."""
        return TorqueLogFilter({"cutoff_hz": self.cutoff_hz, "order": float(self.order)})


def log_filter_text(fit: dict[str, float]) -> str:
    """A fitted log filter (:attr:`~iiwa_ident.ident.FitResult.log_filter`) in words: its stages and
    cut-off with its std."""
    stages = "one first-order stage" if int(fit["order"]) == 1 else f"{int(fit['order'])} first-order stages"
    text = f"{stages} at {fit['cutoff_hz']:.4g} +- {fit['std']:.2g} Hz"
    if fit.get("std_robust", fit["std"]) > fit["std"]:
        text += f" (+- {fit['std_robust']:.2g} Hz with the model's error)"
    return text


def _link_misfit(Y: np.ndarray, s: np.ndarray, scale: np.ndarray) -> float:
    """Weighted squared error of the best ``Y = 1/K + 1/L(s)``, ``L = Jl s^2 + c s + k`` (the link's
    impedance: inertia, damping, a spring or a hold), for the measured ``Y = q_m / tau_j`` at ``s = 2 pi j f``;
    ``scale``: each point's std [same unit as ``Y``].

    Alternating least squares: ``1/K`` given ``L`` is a weighted mean; ``L = 1 / (Y - 1/K)`` given ``K`` is
    linear in ``(Jl, c, k)``, its rows weighted by ``1 / |dL/dY|`` so that the error stays the output's.
    """
    w2 = 1.0 / scale**2
    top = np.argsort(np.abs(s))[-max(3, len(s) // 8):]
    kappa = float(np.average(Y[top].real, weights=w2[top]))  # above the link's resonance Y -> 1/K
    cost = math.inf
    for _ in range(12):
        Z = 1.0 / (Y - kappa)
        w = 1.0 / (scale * np.abs(Z) ** 2)  # dY = -dZ / Z^2
        A = np.column_stack([s**2, s, np.ones_like(s)]) * w[:, None]
        M = np.vstack([A.real, A.imag])
        rhs = np.concatenate([(Z * w).real, (Z * w).imag])
        norm = np.linalg.norm(M, axis=0)
        norm[norm == 0] = 1.0
        try:
            theta = np.linalg.lstsq(M / norm, rhs, rcond=None)[0] / norm
        except np.linalg.LinAlgError:  # non-finite ratios: no fit there
            return math.inf
        L = theta[0] * s**2 + theta[1] * s + theta[2]
        if not np.all(np.isfinite(L)) or np.any(L == 0):
            return math.inf
        kappa = float(np.sum(w2 * (Y - 1.0 / L).real) / np.sum(w2))
        new = float(np.sum(w2 * np.abs(Y - kappa - 1.0 / L) ** 2))
        if not math.isfinite(new):
            return math.inf
        if new >= cost * (1 - 1e-6):
            return min(new, cost)
        cost = new
    return cost


def estimate_log_filter(records: Sequence[FitRecord]) -> LogFilterEstimate | None:
    """The cut-off of a filter before the log, from ``q_m`` against ``tau_j`` (module docstring).

    Parameters
    ----------
    records : sequence of FitRecord
        Chirps of one joint (:func:`~iiwa_ident.ident._records.prepare_records`).

    Returns
    -------
    LogFilterEstimate or None
        The best of one and two first-order stages (cut-off searched from :func:`lowest_cutoff_hz` to
        0.45 of the sampling rate); None where no band has both outputs.
    """
    parts = []
    for rec in records:
        est_t, est_q = record_frf(rec)
        ok = np.isfinite(est_t.H) & np.isfinite(est_q.H) & (np.abs(est_t.H) > 0)
        # The ratio's relative std: the two H1's phase std (a complex estimate's relative std) together.
        rel = np.sqrt(est_t.std_phase_rad**2 + est_q.std_phase_rad**2)
        ok &= np.isfinite(rel) & (rel > 0)
        Y = est_q.H[ok] / est_t.H[ok]
        parts.append((est_t.f_mean_hz[ok], Y, rel[ok] * np.abs(Y), rec.T))
    f = np.concatenate([p[0] for p in parts])
    if len(f) < 8:
        return None
    s_all = np.concatenate([2j * np.pi * p[0] for p in parts])
    scale = np.concatenate([p[2] for p in parts])

    def cost_of(lf: TorqueLogFilter | None) -> float:
        # With the filter, the torque before it is the logged one over F: q / tau = Y F.
        Y = np.concatenate([p[1] * (1.0 if lf is None else lf.frequency_response(p[0], p[3])) for p in parts])
        return _link_misfit(Y, s_all, scale)

    def cost(log_fc: float, order: int) -> float:
        return cost_of(TorqueLogFilter({"cutoff_hz": math.exp(log_fc), "order": float(order)}))

    T_max = max(p[3] for p in parts)
    lo, hi = math.log(lowest_cutoff_hz(records)), math.log(min(_TOP_SHARE / T_max, LOG_FILTER_MAX_HZ))
    if hi <= lo + 0.1:  # sampled too slowly to show a filter above the search's bottom
        return None
    best: tuple[float, float, int] | None = None
    for order in (1, 2):
        grid = np.linspace(lo, hi, 25)
        costs = [cost(x, order) for x in grid]
        k = int(np.argmin(costs))
        a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        res = minimize_scalar(lambda x, order=order: cost(x, order), bounds=(a, b), method="bounded",
                              options={"xatol": 1e-4})
        if best is None or res.fun < best[0]:
            best = (float(res.fun), float(res.x), order)
    assert best is not None
    sse, log_fc, order = best
    total = cost_of(None)
    gain = total - sse
    return LogFilterEstimate(cutoff_hz=math.exp(log_fc), order=order, lag_sigma=math.sqrt(max(gain, 0.0)),
                             explained=gain / total if total > 0 else 0.0,
                             at_bound=log_fc > hi + math.log(_AT_TOP) or log_fc < lo + 0.01)


def unfiltered(ds: Dataset, log_filter: TorqueLogFilter, top_hz: float) -> Dataset:
    """``ds`` with its logged ``tau_j`` put back through the inverse of ``log_filter`` (the sampled filter's own
    response), exactly up to ``top_hz`` [Hz] and with the inverse's gain held at its value there above (its
    phase kept), so the sensor's noise is amplified at most that much."""
    back = unfiltered_torque(np.asarray(ds["tau_j"], float), 1.0 / float(ds.sample_rate_hz), log_filter, top_hz)
    return dataclasses.replace(ds, signals={**ds.signals, "tau_j": back})


def unfiltered_torque(tau: np.ndarray, T: float, log_filter: TorqueLogFilter, top_hz: float) -> np.ndarray:
    """The torque ``tau`` [Nm] sampled every ``T`` [s] before ``log_filter``, as :func:`unfiltered`."""
    n = len(tau)
    # Even extension: the periodic continuation has no jump to ring.
    x = np.concatenate([tau, tau[::-1]])
    f = np.fft.rfftfreq(len(x), T)
    inverse = 1.0 / log_filter.frequency_response(f, T)
    cap = abs(1.0 / log_filter.frequency_response(np.array([top_hz]), T)[0])
    inverse = np.where(np.abs(inverse) > cap, inverse / np.abs(inverse) * cap, inverse)
    return np.fft.irfft(np.fft.rfft(x) * inverse, len(x))[:n]
