"""Start values of the joint fit from the data alone: H1, the delay candidates and the parameters they imply.

The frequency response of the command to the joint torque (H1 on a log grid
of the record's band) is fitted by eq (4)'s rational part after removing a
trial delay (:func:`~iiwa_ident.ident._frf.levy_fit`); the delays whose
residual is a local minimum are the candidates, and the ratio of the motor
position's response to the torque's gives the inertia scale.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import _frf
from iiwa_ident.ident._frf import levy_fit
from iiwa_ident.ident._records import FitRecord, prepare_records
from iiwa_ident.model import discretize
from iiwa_ident.sim import TorqueLogFilter

__all__ = ["MIN_COHERENCE", "MAX_DELAY_S", "initial_estimate", "initial_candidates", "delay_candidates", "record_frf",
           "coherent_bands", "without_known"]

#: A band with less coherence than this carries no usable information [-].
MIN_COHERENCE = 0.5
#: Upper bound of the delay search [s].
MAX_DELAY_S = 0.05


class DelayCandidate(NamedTuple):
    """A delay and the rational part of eq (4) it lets explain H1 (:func:`~iiwa_ident.ident._frf.levy_fit`)."""

    Td: float  # [s]
    levy: np.ndarray  # (a, b0, a0)
    error: float  # relative RMS error of the fit


def delay_candidates(est: _frf.FRFEstimate, T: float) -> list[DelayCandidate]:
    """Delays whose phase best lets eq (4)'s rational part explain H1, best first."""
    f = est.f_mean_hz
    s = 2j * np.pi * f
    # Undo the hold's half-sample lag and sinc gain so the rest is continuous-time.
    G0 = est.H / np.sinc(f * T) * np.exp(s * T / 2)

    def score(td: float) -> tuple[float, np.ndarray | None]:
        out = levy_fit(G0 * np.exp(s * td), s)
        return (math.inf, None) if out is None else (out[1], out[0])

    coarse = np.arange(0.0, MAX_DELAY_S + 1e-12, 0.25e-3)
    scores = np.array([score(td)[0] for td in coarse])
    # Local minima of the coarse score, refined on a fine grid.
    order = [i for i in np.argsort(scores) if np.isfinite(scores[i])
             and (i == 0 or scores[i] <= scores[i - 1]) and (i == len(coarse) - 1 or scores[i] <= scores[i + 1])]
    out: list[DelayCandidate] = []
    for i in order[:3]:
        fine = np.linspace(max(coarse[i] - 0.25e-3, 0.0), coarse[i] + 0.25e-3, 11)
        best = min(((score(td), td) for td in fine), key=lambda z: z[0][0])
        (err, x), td = best
        if x is not None:
            out.append(DelayCandidate(float(td), x, float(err)))
    out.sort(key=lambda z: z.error)
    return out


def initial_estimate(datasets: Sequence[Dataset]) -> list[dict[str, float]]:
    """Start values from the data alone: delay candidates with the parameters they imply.

    Parameters
    ----------
    datasets : sequence of Dataset
        Torque-commanded chirps of one joint.

    Returns
    -------
    list of dict
        Up to three candidate parameter sets (``Jc, bc, K, Jl`` [SI],
        ``Td`` [s]), best first, each with ``"levy_error"``: the relative
        RMS error of the linear fit to H1.
    """
    return initial_candidates(prepare_records(datasets))


def without_known(rec: FitRecord, params: dict[str, float], log_filter: TorqueLogFilter | None = None) -> FitRecord:
    """``rec`` with the response to its known torques taken out of ``tau_j`` and ``q_m`` (itself without);
    the torque's response through ``log_filter`` where the log
    has one."""
    table = rec.table_inputs()
    if not rec.known and table is None:
        return rec
    y = sum((discretize(params, rec.T, kind).simulate(signal) for kind, signal in rec.known), np.zeros((2, rec.n)))
    if table is not None:  # the ripple's table, a known deflection with its reaction
        y = y + discretize(params, rec.T, "deflection").simulate(table.D[:, 0], table.D_means[:, 0],
                                                                 table.D_slopes[:, 0]) \
            + discretize(params, rec.T, "reaction").simulate(table.RX[:, 0], table.RX_means[:, 0], table.RX_slopes[:, 0])
    if log_filter is not None:
        y[0] = log_filter.apply(y[0], rec.T)
    return replace(rec, tau=rec.tau - y[0], q=rec.q - y[1], spectra=None, known=[], table_signals=None)


def record_frf(rec: FitRecord, delay_s: float = 0.0) -> tuple[_frf.FRFEstimate, _frf.FRFEstimate]:
    """H1 of tau_c -> tau_j and tau_c -> q_m on the log grid of the record's band.

    The record starts from rest with nothing commanded before, the same
    assumption the time-domain model makes; half a long segment of that rest
    is put in front, so the first segment sees the start as a step in both
    input and output instead of an unexplained output transient.
    """
    fs = 1.0 / rec.T
    if rec.spectra is None:
        pad = _frf.welch_segment_length(rec.n, fs, rec.f_lo) // 2
        u = np.concatenate([np.zeros(pad), rec.u])
        ys = np.vstack([np.concatenate([np.full(pad, rec.tau[0]), rec.tau]),
                        np.concatenate([np.zeros(pad), rec.q])])
        rec.spectra = _frf.multi_resolution_spectra(u, ys, fs, rec.f_lo)
    est_t = _frf.h1_estimate(None, None, fs, rec.f_lo, rec.f_hi, spectra=rec.spectra, output=0, delay_s=delay_s)
    est_q = _frf.h1_estimate(None, None, fs, rec.f_lo, rec.f_hi, spectra=rec.spectra, output=1, delay_s=delay_s)
    return est_t, est_q


def coherent_bands(est: _frf.FRFEstimate) -> np.ndarray:
    """Bands whose coherence is above 0.5 and significant at 1 % for their number of averages.

    Between unrelated signals the pooled coherence of n independent terms
    exceeds ``1 - alpha^(1/(n-1))`` with probability alpha only.
    """
    n = np.maximum(est.n_terms, 1.0 + 1e-9)
    significant = 1.0 - 0.01 ** (1.0 / (n - 1.0))
    return est.coherence > np.maximum(MIN_COHERENCE, significant)


def initial_candidates(records: list[FitRecord]) -> list[dict[str, float]]:
    """Up to three start candidates from the longest record (see :func:`initial_estimate`)."""
    rec = max(records, key=lambda r: r.n * r.T)
    est_t, est_q = record_frf(rec)
    good = coherent_bands(est_t)
    if good.sum() < 4:
        raise IiwaIdentError(f"{rec.label}: no band with coherence above {MIN_COHERENCE} between tau_c and tau_j: "
                             "nothing to fit")
    sub = est_t.select(good)
    cands = delay_candidates(sub, rec.T)
    if not cands:
        raise IiwaIdentError(f"{rec.label}: the measured response does not look like eq (4) at any delay "
                             "up to 50 ms; nothing to fit")
    # Scale from q_m / tau_j = 1/K - 1/(Jl w^2) (real), using tau_c as the common instrument.
    both = good & coherent_bands(est_q)
    if both.sum() < 3:
        raise IiwaIdentError(f"{rec.label}: q_m is not coherent with tau_c in enough bands to find the inertia scale")
    R = est_q.H[both] / est_t.H[both]
    w = 2 * np.pi * est_t.f_mean_hz[both]
    M = np.column_stack([np.ones_like(w), -1.0 / w**2]) / np.abs(R)[:, None]
    x, *_ = np.linalg.lstsq(M, R.real / np.abs(R), rcond=None)
    inv_K, inv_Jl = x
    if not inv_Jl > 0:
        raise IiwaIdentError(f"{rec.label}: q_m does not follow the joint torque as a free link would "
                             "(q_m / tau_j != 1/K + 1/(Jl s^2)); cannot find the inertia scale")
    Jl = 1.0 / inv_Jl
    out = []
    for td, (a, b0, a0), err in cands:
        Jc = Jl * (a0 / b0 - 1.0)
        out.append({"Jc": float(Jc), "bc": float(a * Jc), "K": float(b0 * Jc), "Jl": float(Jl), "Td": float(td),
                    "levy_error": float(err), "K_from_q_m": float(1.0 / inv_K) if inv_K > 0 else math.nan})
    return out
