"""Fit of the joint transfer function, eq (4), with delay and uncertainties.

Model
-----
Eqs (1)-(3) of the paper with no external torque (the link is free during a
chirp), written as a state-space model with the state
``x = (theta_m, z, theta_l, omega_l)``::

    Jc theta_m' = (bc / K)(tau_c - tau_j) + z      # eq (1), integrated once
    z'          = tau_c - tau_j
    Jl omega_l' = tau_j,  theta_l' = omega_l       # eq (2)
    tau_j       = K (theta_m - theta_l)            # eq (3)

``theta_m`` is the motor-side position ``q_m`` (the paper's theta_j without
the transmission ripple). Its transfer function ``tau_j / tau_c`` is eq (4),
including the input delay ``exp(-Td s)``.

Why two outputs
---------------
Eq (4) is unchanged when ``Jc, bc, K, Jl`` are all scaled by one factor:
from ``tau_c -> tau_j`` alone only their ratios are identifiable. The scale
comes from the motor position: eqs (2)-(3) give ``theta_m = theta_l +
tau_j / K`` and ``Jl theta_l'' = tau_j``, i.e.
``q_m / tau_j = 1/K + 1/(Jl s^2)``. Both outputs, ``tau_j`` and
``q_m - q_m[0]``, are therefore fitted from the one input ``tau_c``.

Sampling
--------
FRI sends ``tau_c[k]`` at ``t = kT``; the robot applies it from ``kT + Td``
to ``(k+1)T + Td`` (zero-order hold) and reports ``tau_j[k]``, ``q_m[k]`` at
``kT``. The model is the exact discretisation of this: with ``Td = dT +
tau`` (``0 <= tau < T``, a fractional delay; modified z-transform)::

    x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]
    Phi    = e^{AT}
    Gamma0 = int_0^{T-tau} e^{As} ds B
    Gamma1 = e^{A(T-tau)} int_0^{tau} e^{As} ds B

Without the fractional part ``Td`` would come out about half a cycle off.
The state splits exactly into the resonant pair of eq (4) and the rigid-body
double integrator (a Jordan block at ``s = 0``); each part is run as a
recursive filter, the double integrator with the exact coefficients
``(1 - z^-1)^2`` so that it cannot drift numerically.

Estimator
---------
Time-domain output-error maximum likelihood over both outputs
(Levenberg-Marquardt on ``log Jc, log bc, log K, log Jl`` and ``Td``). The
run starts from rest, so the simulation starts from the zero state and
transients are modelled, not windowed away.
Unknown noise levels are estimated from the residuals, per output and per
quarter-second block (heteroscedastic ML, iterated): the torque sensor's
white noise, the encoder's quantisation and, with the transmission ripple,
the position-periodic torque and position ripple that no linear model
predicts, all differ in size along a sweep. Two nuisance terms are
estimated with each fit, by projection: a torque-sensor offset, and a
smooth position drift (a cubic spline with knots every ``1 / (4 f0)``), the
motion an unmodelled slowly varying torque (friction, ripple) gives the
free double integrator.

Limitation: the transmission ripple of eq (5) changes the local
transmission ratio ``1 - f'(theta_m)`` at the operating point, and with it
the small-signal dynamics; eq (4) fitted to such data is off by a few
percent (in simulation with the default ripple ``K`` comes out about 2 %
low, ``bc`` and ``Jc`` about 1 % off). The std does not include this; the
fit-quality table and the warnings show the mismatch.

Start values come from the data only: the delay from a grid search on the
phase of the non-parametric H1, the ratios from a linear (Levy,
Sanathanan-Koerner) fit of eq (4)'s rational part to H1, and the scale
``Jl`` from a linear least squares of ``q_m / tau_j = 1/K + 1/(Jl s^2)``
(both H1 taken from ``tau_c``). The best few delay candidates are each
refined and the best fit kept.

The covariance is the inverse Fisher information from the weighted
Jacobian at the optimum (the noise levels being the estimated ones). A
block-wise sandwich estimate, robust to coloured residuals, is computed
alongside: when it is much larger, the residuals are not white (ripple,
feasibility filter) and a warning says so, since the model's systematic
errors are then in neither. Fit quality is reported per octave band against
the H1 estimate and its uncertainty (:mod:`iiwa_ident.ident._frf`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import minimize_scalar

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import _frf
from iiwa_ident.ident._initial import (
    MAX_DELAY_S,
    MIN_COHERENCE,
    coherent_bands,
    initial_candidates,
    record_frf,
    without_known,
)
from iiwa_ident.ident._log_filter import LOG_FILTER_MAX_HZ, lowest_cutoff_hz, unfiltered_torque
from iiwa_ident.ident._records import FitRecord, SampledInputs, prepare_record, prepare_records
from iiwa_ident.ident._resid import INDEPENDENCE, residual_tests
from iiwa_ident.model import (
    INPUTS,
    PARAMETER_NAMES,
    PARAMETER_UNITS,
    ParameterSource,
    RippleTable,
    discretize,
    simulate_outputs,
)
from iiwa_ident.model import parameter_values as _as_values
from iiwa_ident.sim import TorqueLogFilter

__all__ = [
    "BandQuality",
    "FitResult",
    "output_residual_rms",
    "fit_transfer_function",
    "cramer_rao_std",
    "STD_FISHER",
    "RIPPLE_HARMONICS",
    "RippleTerms",
]

#: :attr:`FitResult.std_method` of the output-error fit.
STD_FISHER = ("inverse Fisher information of the output-error fit, weighted by per-block noise levels "
              "estimated from the residuals; describes the noise, not unmodelled effects")
#: What the transmission ripple's terms add to :data:`STD_FISHER`.
STD_RIPPLE = ("; with the transmission ripple's coefficients fitted alongside, plus the sampled model's own error "
              "for the ripple's inputs (estimated by step doubling) and the estimates' change with the measured "
              "torque in the ripple's reaction instead of the model's, and at least the block sandwich std")
_SIGMA_FLOOR = 0.1  # a block's noise level is at least this fraction of its channel's RMS
_LOW_COHERENCE = 0.8  # warn below this mean coherence in an octave band
_NONLINEAR_WARN = 0.05  # warn when harmonics 2..5 carry more than this share of the output power
_MISFIT_WARN = 5.0  # warn when the model misses H1 by more than this many standard deviations (RMS)
_REL_STD_WARN = 0.05  # warn when a parameter's relative std exceeds this
_TD_STD_WARN_S = 0.5e-3  # ... or the delay's std exceeds this
_CONVERGED_SIGMA = 0.05  # the search stops when its Gauss-Newton step is below this many std
_COLOURED_WARN = 3.0  # warn when the sandwich std exceeds the Fisher std by this factor (median)
# Physical bounds of Jc, bc, K, Jl [SI] for the search: far outside any joint, but finite, so that
# the sampled model can neither overflow nor become singular.
_LOWER = (1e-4, 1e-3, 1.0, 1e-4)
_UPPER = (1e4, 1e6, 1e8, 1e5)


# --------------------------------------------------------------------------
# model



#: Harmonics of the ripple's period whose coefficients the output-error fit estimates with the parameters.
RIPPLE_HARMONICS = 4


@dataclass(frozen=True)
class RippleTerms:
    """The transmission ripple of eq (5) in the output-error fit.

    The deflection ``f(theta_m)`` enters the spring (``tau_j = K (theta_m - f -
    theta_l)``) and the motor side feels the joint torque through the
    transmission's ratio ``1 - f'`` (the reaction ``tau_j f'``); both are
    computed from the measured ``q_m`` and ``tau_j``. A ``table`` (from the
    ripple command) gives ``f`` as a known input; the Fourier coefficients of
    harmonics ``1..harmonics`` of the period are fitted on top of it, as
    nuisance parameters whose uncertainty the parameters' std includes (a
    table's error, or a ripple without a table, is absorbed there).

    Attributes
    ----------
    period_rad : float
        The ripple's period rho [rad].
    harmonics : int
        Harmonics fitted (2 per harmonic: cosine and sine).
    table : RippleTable, optional
        The identified lookup table, taken as known.
    search : bool
        Without a table the period is searched: True refines it on the output-error residual first (see
        :func:`fit_transfer_function`), False takes it as already refined; either way its uncertainty is in
        the parameters' std.
    """

    period_rad: float
    harmonics: int = RIPPLE_HARMONICS
    table: RippleTable | None = None
    search: bool = True

    def table_signals(self, q_m: np.ndarray, tau_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The table's deflection [rad] and reaction [Nm] at the motion ``(q_m, tau_j)``, one column each."""
        assert self.table is not None
        f = np.asarray(self.table(q_m), float)
        return f[:, None], (tau_j * self.table.slope(q_m))[:, None]

    def signals(self, q_m: np.ndarray, tau_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Deflection [rad] and reaction [Nm] of each cosine and sine of the fitted harmonics at the motion
        ``(q_m, tau_j)``: columns ``(points, 2 * harmonics)``."""
        w = 2.0 * np.pi / self.period_rad
        phase = w * np.asarray(q_m, float)
        tau = np.asarray(tau_j, float)
        D = np.empty((len(phase), 2 * self.harmonics))
        RX = np.empty_like(D)
        c1, s1 = np.cos(phase), np.sin(phase)
        c, s = c1, s1
        for k in range(1, self.harmonics + 1):
            if k > 1:  # the next harmonic by the angle sum: one cosine and sine for all of them
                c, s = c * c1 - s * s1, s * c1 + c * s1
            D[:, 2 * k - 2], D[:, 2 * k - 1] = c, s
            RX[:, 2 * k - 2], RX[:, 2 * k - 1] = -k * w * s * tau, k * w * c * tau
        return D, RX


def _input_response(params: ParameterSource, T: float, kind: str, signal: np.ndarray) -> np.ndarray:
    """Outputs ``(2, n)`` for one known torque (no delay, so ``Td`` does not enter)."""
    return discretize(params, T, kind).simulate(signal)


def _motion_response(params: ParameterSource, T: float, inputs: SampledInputs) -> np.ndarray:
    """Outputs ``(2, n, columns)`` of deflection and reaction columns (:class:`SampledInputs`) through the
    model sampled as finely as they are."""
    s = inputs.substeps
    Y = discretize(params, T / s, "deflection").simulate(inputs.D, inputs.D_means, inputs.D_slopes)
    Y += discretize(params, T / s, "reaction").simulate(inputs.RX, inputs.RX_means, inputs.RX_slopes)
    return Y[:, ::s] if s > 1 else Y


def _simulate_record(params: ParameterSource, rec: FitRecord, substeps: int = 1, known: np.ndarray | None = None) -> np.ndarray:
    """Outputs for a record's command and its known torques; a non-physical ``params`` gives NaN.

    ``known``: the known torques' response at ``params`` when the caller has it (:func:`_known_response`).
    """
    return _outputs(rec, lambda: simulate_outputs(params, rec.u, rec.T)) \
        + (_known_response(params, rec, substeps) if known is None else known)


def _known_response(params: ParameterSource, rec: FitRecord, substeps: int = 1) -> np.ndarray:
    """The outputs ``(2, n)`` of a record's known torques (zero without; NaN for a non-physical ``params``):
    no delay in them, so ``Td`` does not enter."""
    def simulate() -> np.ndarray:
        y = sum((_input_response(params, rec.T, kind, signal) for kind, signal in rec.known), np.zeros((2, rec.n)))
        table = rec.table_inputs(substeps)
        return y if table is None else y + _motion_response(params, rec.T, table)[:, :, 0]

    return _outputs(rec, simulate)


def _outputs(rec: FitRecord, simulate: Callable[[], np.ndarray]) -> np.ndarray:
    """``simulate()``, or NaN outputs ``(2, n)`` where the parameters describe no model."""
    try:
        with np.errstate(all="ignore"):
            return simulate()
    except (ValueError, OverflowError, ZeroDivisionError, np.linalg.LinAlgError):
        return np.full((2, rec.n), np.nan)


# --------------------------------------------------------------------------
# maximum likelihood


class _RippleFit(NamedTuple):
    """A record's ripple coefficients, their weighted projected response and their response in signal units."""

    coef: np.ndarray
    weighted: np.ndarray
    response: np.ndarray  #: (2, n)


class _RippleColumns(NamedTuple):
    """The ripple columns' weighted projected responses (tau_j, q_m), their Gram matrix and their response in
    signal units."""

    C_t: np.ndarray
    C_q: np.ndarray
    gram: np.ndarray
    Y: np.ndarray  #: (2, n, columns)


class _Problem:
    """Weighted, nuisance-projected output-error residuals of all records.

    For each record and output the residual is ``w (data - model)`` with
    ``w = 1 / sigma`` per block, minus its weighted least-squares fit by the
    nuisance basis (a constant for ``tau_j``, the drift spline for ``q_m``).
    The spline basis is sparse, so the projection costs a sparse product
    and a small Cholesky solve per evaluation.
    """

    def __init__(self, records: list[FitRecord], nuisance: bool = True, log_filter_order: int = 0) -> None:
        self.records = records
        self.nuisance = nuisance
        #: Stages of a filter between the torque sensor and the log, whose cut-off is the sixth parameter
        #: (``x[5] = log cutoff_hz``); 0 without.
        self.log_filter_order = log_filter_order
        # Per record and channel: per-block noise std (starts uniform).
        self.sigma = [[np.ones(r.n_blocks), np.ones(r.n_blocks)] for r in records]
        self._weights: list[tuple[np.ndarray, np.ndarray, float, Any]] = []
        self.n_evaluations = 0
        #: Model steps per sample for the inputs that are functions of the motion (see
        #: :meth:`~iiwa_ident.ident._records.FitRecord.ripple_inputs`); 2 only to estimate the error of the usual 1.
        self.substeps = 1
        self.update_projections()

    @staticmethod
    def x_to_params(x: np.ndarray) -> tuple[float, ...]:
        return (*np.exp(x[:4]), x[4] * 1e-3)

    @staticmethod
    def params_to_x(p: Sequence[float], cutoff_hz: float | None = None) -> np.ndarray:
        x = [*np.log(np.asarray(p[:4], float)), p[4] * 1e3]
        return np.array(x if cutoff_hz is None else [*x, math.log(cutoff_hz)])

    def log_filter(self, x: np.ndarray) -> TorqueLogFilter | None:
        """The log's filter at ``x`` (None without one)."""
        if not self.log_filter_order:
            return None
        return TorqueLogFilter({"cutoff_hz": float(np.exp(x[5])), "order": float(self.log_filter_order)})

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The search's bounds on ``x``: the physical ones, the delay in ``[0, 50 ms]``, a log filter's cut-off
        from :func:`~iiwa_ident.ident._log_filter.lowest_cutoff_hz` to :data:`LOG_FILTER_MAX_HZ` and 0.45 of the
        fastest record's sampling rate."""
        lower, upper = [*np.log(_LOWER), 0.0], [*np.log(_UPPER), MAX_DELAY_S * 1e3]
        if self.log_filter_order:
            lower.append(math.log(lowest_cutoff_hz(self.records)))
            upper.append(math.log(min(0.45 / min(r.T for r in self.records), LOG_FILTER_MAX_HZ)))
        return np.array(lower), np.array(upper)

    def update_projections(self) -> None:
        """Weights and the factorised normal equations of the nuisance fits."""
        self._weights = []
        for r, (s_t, s_q) in zip(self.records, self.sigma):
            mask = r.mask  # a held window has no weight
            w_t = mask / s_t[r.block]
            w_q = mask / s_q[r.block]
            Bw = r.drift_basis.multiply(w_q[:, None]).tocsr()
            gram = (Bw.T @ Bw).toarray()
            gram += 1e-12 * np.trace(gram) / len(gram) * np.eye(len(gram))
            self._weights.append((w_t, w_q, float(np.sum(w_t**2)), cho_factor(gram)))
        self._responses: dict[tuple[int, str], tuple[tuple, Any]] = {}

    def _project(self, r: FitRecord, e_t: np.ndarray, e_q: np.ndarray, weights: tuple) -> None:
        """Remove the weighted nuisance fits from ``e_t`` and ``e_q`` in place (vectors, or matrices of columns)."""
        if not self.nuisance:
            return
        w_t, w_q, sum_wt2, chol = weights
        if e_t.ndim == 2:
            w_t, w_q = w_t[:, None], w_q[:, None]
        e_t -= w_t * (np.sum(w_t * e_t, axis=0) / sum_wt2)
        c = cho_solve(chol, r.drift_basis.T @ (w_q * e_q))
        e_q -= w_q * (r.drift_basis @ c)

    def residual(self, x: np.ndarray) -> np.ndarray:
        self.n_evaluations += 1
        parts: list[np.ndarray] = []
        p, lf = self.x_to_params(x), self.log_filter(x)
        for i, (r, weights) in enumerate(zip(self.records, self._weights)):
            y = self._outputs(i, p, lf)
            if not np.all(np.isfinite(y)):  # no model there: a cost no step can accept
                return np.full(2 * sum(rec.n for rec in self.records), 1e150)
            e_t = weights[0] * (r.tau - y[0])
            e_q = weights[1] * (r.q - y[1])
            self._project(r, e_t, e_q, weights)
            if r.fits_inputs:
                fitted = self._ripple_fit(p, i, e_t, e_q, lf)
                if fitted is None:
                    return np.full(2 * sum(rec.n for rec in self.records), 1e150)
                e_t -= fitted[1][:r.n]
                e_q -= fitted[1][r.n:]
            parts.extend((e_t, e_q))
        return np.concatenate(parts)

    def _outputs(self, i: int, p: Sequence[float], lf: TorqueLogFilter | None = None) -> np.ndarray:
        """Record ``i``'s model outputs ``(2, n)`` for its command and known torques at ``p``, the torque
        through the log's filter ``lf``."""
        r = self.records[i]
        known = self._delay_free(i, p, "known", lambda: _known_response(p, r, self.substeps))
        y = _simulate_record(p, r, self.substeps, known)
        if lf is not None:
            y[0] = lf.apply(y[0], r.T)
        return y

    def _delay_free(self, i: int, p: Sequence[float], what: str, make: Callable[[], Any],
                    lf: TorqueLogFilter | None = None) -> Any:
        """``make()``: record ``i``'s response to inputs without delay (``what``: the known torques, the
        ripple's columns) at ``p`` (and the log filter ``lf`` where ``make`` applies it). It does not depend on
        ``Td``, so the Jacobian's ``Td`` column and the steps that move only ``Td`` reuse it. One entry per
        record and kind; emptied when the weights change."""
        key = (self.substeps, tuple(p[:4]), None if lf is None else lf.values["cutoff_hz"])
        hit = self._responses.get((i, what))
        if hit is None or hit[0] != key:
            hit = self._responses[(i, what)] = (key, make())
        return hit[1]

    def _ripple_fit(self, p: Sequence[float], i: int, e_t: np.ndarray, e_q: np.ndarray,
                    lf: TorqueLogFilter | None = None) -> _RippleFit | None:
        """Record ``i``'s ripple coefficients fitted to its weighted residual: (coefficients, their weighted
        projected response, their response in signal units ``(2, n)``), or ``None`` where the model does
        not exist."""
        r, weights = self.records[i], self._weights[i]
        columns = self._delay_free(i, p, "ripple", lambda: self._ripple_columns(p, r, weights, lf), lf)
        if columns is None:
            return None
        C_t, C_q, gram, Y = columns
        # Normal equations: a handful of columns against two outputs of every sample.
        coef, *_ = np.linalg.lstsq(gram, C_t.T @ e_t + C_q.T @ e_q, rcond=None)
        return _RippleFit(coef, np.concatenate([C_t @ coef, C_q @ coef]), Y @ coef)

    def _ripple_columns(self, p: Sequence[float], r: FitRecord, weights: tuple, lf: TorqueLogFilter | None = None
                        ) -> _RippleColumns | None:
        """The ripple columns' weighted, projected responses (tau_j, q_m), their Gram matrix and their
        response in signal units ``(2, n, columns)``; ``None`` where the model does not exist."""
        try:
            with np.errstate(all="ignore"):
                Y = _motion_response(p, r.T, r.ripple_inputs(self.substeps))  # every column at once
                if lf is not None:
                    Y[0] = lf.apply(Y[0], r.T)
                w_t, w_q = weights[0], weights[1]
                C_t, C_q = w_t[:, None] * Y[0], w_q[:, None] * Y[1]
                self._project(r, C_t, C_q, weights)  # every column at once
        except (ValueError, OverflowError, ZeroDivisionError, np.linalg.LinAlgError):
            return None
        if not (np.all(np.isfinite(C_t)) and np.all(np.isfinite(C_q))):
            return None
        return _RippleColumns(C_t, C_q, C_t.T @ C_t + C_q.T @ C_q, Y)

    def ripple_response(self, x: np.ndarray) -> list[np.ndarray | None]:
        """Per record, the fitted ripple's output response ``(2, n)`` in signal units (``None`` without)."""
        p, lf = self.x_to_params(x), self.log_filter(x)
        out: list[np.ndarray | None] = []
        for i, (r, weights) in enumerate(zip(self.records, self._weights)):
            if not r.fits_inputs:
                out.append(None)
                continue
            y = self._outputs(i, p, lf)
            e_t, e_q = weights[0] * (r.tau - y[0]), weights[1] * (r.q - y[1])
            self._project(r, e_t, e_q, weights)
            fitted = self._ripple_fit(p, i, e_t, e_q, lf)
            out.append(None if fitted is None else fitted[2])
        return out

    def unweighted(self, x: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Residuals with the nuisance removed, in signal units, per record: (tau_j [Nm], q_m [rad])."""
        res = self.residual(x)
        out, k = [], 0
        for r, weights in zip(self.records, self._weights):
            # A held window (no weight) reads as zero.
            out.append(tuple(np.divide(res[k + j * r.n:k + (j + 1) * r.n], weights[j], out=np.zeros(r.n),
                                       where=weights[j] > 0) for j in range(2)))
            k += 2 * r.n
        return out

    def reweight(self, x: np.ndarray, per_block: bool) -> None:
        """Noise levels from the residuals: per channel, or per channel and block (with a floor)."""
        new = []
        for r, (e_t, e_q) in zip(self.records, self.unweighted(x)):
            chans = []
            for e, floor in ((e_t, 1e-4), (e_q, 1e-9)):
                overall = max(float(np.sqrt(np.sum(e**2) / max(float(np.sum(r.mask)), 1.0))), floor)
                if per_block:
                    counted = np.bincount(r.block, weights=r.mask, minlength=r.n_blocks)
                    ms = np.bincount(r.block, weights=e**2, minlength=r.n_blocks) / np.maximum(counted, 1.0)
                    ms[counted == 0] = overall**2
                    # A floor keeps a few lucky blocks from taking over the fit.
                    chans.append(np.maximum(np.sqrt(ms), _SIGMA_FLOOR * overall))
                else:
                    chans.append(np.full(r.n_blocks, overall))
            new.append(chans)
        self.sigma = new
        self.update_projections()

    def jacobian(self, x: np.ndarray, central: bool = True, r0: np.ndarray | None = None) -> np.ndarray:
        """Finite-difference Jacobian of the weighted residual."""
        steps = np.array([1e-6, 1e-6, 1e-6, 1e-6, 1e-4, 1e-6][:len(x)])  # relative for the logs, ms for Td
        if r0 is None and not central:
            r0 = self.residual(x)
        cols = []
        for i, h in enumerate(steps):
            xp = x.copy()
            xp[i] += h
            if central and not (i == 4 and x[i] - h < 0):
                xm = x.copy()
                xm[i] -= h
                cols.append((self.residual(xp) - self.residual(xm)) / (2 * h))
            else:
                cols.append((self.residual(xp) - (self.residual(x) if r0 is None else r0)) / h)
        return np.column_stack(cols)

    def block_ids(self) -> np.ndarray:
        """A block number for each residual (records and channels get their own blocks)."""
        ids, offset = [], 0
        for r in self.records:
            ids.append(r.block + offset)
            ids.append(r.block + offset)  # the two channels of one time block share it
            offset += r.n_blocks
        return np.concatenate(ids)


@dataclass
class _Solution:
    x: np.ndarray
    cost: float
    iterations: int


def _solve(problem: _Problem, x0: np.ndarray, max_iterations: int = 40) -> _Solution:
    """Levenberg-Marquardt on the five parameters, the delay kept in ``[0, 50 ms]``.

    Written out (rather than scipy's solvers) because it needs only the 5x5
    normal equations: no factorisation of the tall Jacobian per step.
    Converged when the Gauss-Newton step is below :data:`_CONVERGED_SIGMA`
    standard deviations (the residual is weighted by its noise, so ``J^T J``
    is the Fisher information): closer than that, the finite-difference
    Jacobian's own error decides the steps, which then mostly fail.
    """
    lower, upper = problem.bounds()
    x = np.clip(np.asarray(x0, float), lower, upper)
    r = problem.residual(x)
    cost = 0.5 * float(np.sum(r * r))
    lam = 1e-3
    it = 0
    for it in range(1, max_iterations + 1):
        J = problem.jacobian(x, central=False, r0=r)
        # einsum keeps these small products off the threaded BLAS (slow on a busy machine).
        A = np.einsum("ki,kj->ij", J, J)
        g = np.einsum("ki,k->i", J, r)
        diag = np.maximum(np.diag(A), 1e-30)
        try:
            newton = np.linalg.solve(A, -g)
            if float(newton @ A @ newton) < _CONVERGED_SIGMA**2:
                it -= 1  # no step taken
                break
        except np.linalg.LinAlgError:
            pass
        improved = False
        while lam < 1e10:
            step = np.linalg.solve(A + lam * np.diag(diag), -g)
            xn = np.clip(x + step, lower, upper)
            rn = problem.residual(xn)
            cn = 0.5 * float(np.sum(rn * rn))
            if cn < cost:
                improved = True
                lam = max(lam / 5.0, 1e-9)
                break
            lam *= 4.0
        if not improved:
            break
        gain = cost - cn
        moved = np.max(np.abs(xn - x))
        x, r, cost = xn, rn, cn
        if gain <= 1e-10 * max(cost, 1e-300) or moved < 1e-9:
            break
    return _Solution(x, cost, it)


# --------------------------------------------------------------------------
# results


@dataclass
class BandQuality:
    """How well the fitted model matches H1 in one octave band of one dataset.

    Attributes
    ----------
    dataset : str
        The dataset's file (or ``dataset N``).
    lo_hz, hi_hz : float
        Band [Hz].
    rel_error : float
        RMS of ``|H1 - H_model| / |H_model|`` over the band's grid points.
    z_rms : float
        RMS of ``|H1 - H_model| / std(H1)``: about 1 when the model explains
        the data within its uncertainty.
    coherence : float
        Mean coherence ``tau_c -> tau_j``.
    """

    dataset: str
    lo_hz: float
    hi_hz: float
    rel_error: float
    z_rms: float
    coherence: float


@dataclass(kw_only=True)
class FitResult:
    """Outcome of :func:`fit_transfer_function`.

    Attributes
    ----------
    parameters : dict of str to float
        ``Jc`` [kg m^2], ``bc`` [Nm s/rad], ``K`` [Nm/rad], ``Jl`` [kg m^2],
        ``Td`` [s].
    std : dict of str to float
        Standard deviations from the Fisher information (inverse of
        ``J^T J`` of the weighted residual at the optimum).
    std_sandwich : dict of str to float
        Block-wise sandwich estimate ``F^-1 (sum_b g_b g_b^T) F^-1``, robust
        to residuals correlated within a quarter-second block; much larger
        than :attr:`std` when the residuals are not white.
    std_robust : dict of str to float
        The model-error aware std (see
        :func:`iiwa_ident.ident.fit_joint`): equal to :attr:`std`
        where the residual is independent of the command, wider where it is
        not; empty until the joint fit sets it (then :attr:`std` applies).
    correlation : numpy.ndarray
        Correlation matrix in the order of :data:`PARAMETER_NAMES`.
    covariance : numpy.ndarray
        Covariance [SI units squared], same order.
    noise : list of dict
        Per dataset: RMS residual ``tau_j_nm`` [Nm] and ``q_m_rad`` [rad].
    frf : list of FRFEstimate
        Per dataset: H1 of ``tau_c -> tau_j``.
    model_frf : list of numpy.ndarray
        Per dataset: the fitted sampled-data model averaged over H1's bands.
    bands : list of BandQuality
        Fit quality per dataset and octave band.
    harmonics : list of HarmonicResponses or None
        Per dataset: the sweep deconvolution (None when not an exponential sweep).
    nonlinear : list of list of NonlinearBand
        Per dataset: non-linear share of the output power per octave band.
    warnings : list of str
        Things a user should know before trusting the result.
    initial : list of dict
        The start candidates (see :func:`~iiwa_ident.ident._initial.initial_estimate`).
    labels : list of str
        The datasets' files.
    cost : float
        Final ``0.5 * sum(weighted residual^2)``.
    n_evaluations : int
        Model simulations spent by the optimiser.
    """

    parameters: dict[str, float]
    std: dict[str, float]
    std_sandwich: dict[str, float]
    correlation: np.ndarray
    covariance: np.ndarray
    noise: list[dict[str, float]]
    frf: list[_frf.FRFEstimate]
    model_frf: list[np.ndarray]
    bands: list[BandQuality]
    harmonics: list[_frf.HarmonicResponses | None]
    nonlinear: list[list[_frf.NonlinearBand]]
    warnings: list[str]
    initial: list[dict[str, float]]
    labels: list[str]
    cost: float
    n_evaluations: int
    sample_times_s: list[float] = field(default_factory=list)
    #: Which estimator (:data:`iiwa_ident.ident.METHODS`).
    method: str = "eq4"
    #: Fitted link-side effects (:class:`iiwa_ident.ident._idim.LinkEffectEstimate`), if any.
    effects: list[Any] = field(default_factory=list)
    #: How :attr:`std` was computed (named in the JSON).
    std_method: str = STD_FISHER
    #: Spectral lines of the torque reading [Hz] the inverse dynamics fitted as free sinusoids (a hum).
    lines_hz: tuple[float, ...] = ()
    #: Per dataset, the residual tests of the torque's residual against the command
    #: (:func:`iiwa_ident.ident.residual_tests`); the model is judged by the independence of the command (in
    #: closed loop the residual is coloured by the loop even where the model is complete).
    residual_tests: list[Any] = field(default_factory=list)
    std_robust: dict[str, float] = field(default_factory=dict)
    #: How :attr:`std_robust` was computed (named in the JSON).
    std_robust_method: str = ""
    #: A filter between the torque sensor and the log fitted with the parameters: ``cutoff_hz`` [Hz], its
    #: ``std`` [Hz], ``order`` (stages) and, from the joint fit, ``std_robust`` [Hz] (as :attr:`std_robust`);
    #: None when the model has none.
    log_filter: dict[str, float] | None = None
    #: The ripple's period the fit used [rad]: a searched one refined on the fit's residual (None without).
    ripple_period_rad: float | None = None

    @property
    def model_rejected(self) -> bool:
        """True when the torque's residual follows the command in some dataset (the model misses part of
        the response); whiteness alone does not reject it, as the torque loop colours the noise."""
        return any(t.passed_test(INDEPENDENCE) is False for t in self.residual_tests)

    @property
    def relative_std(self) -> dict[str, float]:
        """``std / |value|`` per parameter."""
        return {k: self.std[k] / abs(v) if v else math.inf for k, v in self.parameters.items()}

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` document (SI units, ``Td`` in seconds; NaN becomes null)."""

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        nonlinear = []
        for label, bands in zip(self.labels, self.nonlinear):
            for b in bands:
                nonlinear.append({"dataset": label, "lo_hz": b.lo_hz, "hi_hz": b.hi_hz, "share": num(b.share),
                                  "harmonics": b.harmonics,
                                  "harmonic_share": [num(v) for v in b.harmonic_share]})
        return {
            "parameters": {k: {"value": self.parameters[k], "std": self.std[k],
                               "std_robust": self.std_robust.get(k, self.std[k]), "unit": PARAMETER_UNITS[k]}
                           for k in PARAMETER_NAMES},
            "correlation": {"names": list(PARAMETER_NAMES), "matrix": np.asarray(self.correlation).tolist()},
            "noise": self.noise,
            "bands": [{"dataset": b.dataset, "lo_hz": b.lo_hz, "hi_hz": b.hi_hz, "rel_error": num(b.rel_error),
                       "z_rms": num(b.z_rms), "coherence": num(b.coherence)} for b in self.bands],
            "nonlinear_share": nonlinear,
            "warnings": list(self.warnings),
            "method": self.method,
            "std_method": self.std_method,
            "model_rejected": self.model_rejected,
            "std_robust_method": self.std_robust_method or "equal to std",
            "effects": {e.name: e.to_json() for e in self.effects},
            "spectral_lines_hz": [float(f) for f in self.lines_hz],
            "log_filter": None if self.log_filter is None else dict(self.log_filter),
            "residual_tests": [{"dataset": label, "passed": t.passed,
                                "tests": [{k: v for k, v in x.to_json().items()
                                           if k not in ("lags", "correlation", "bound")} for x in t.tests]}
                               for label, t in zip(self.labels, self.residual_tests)],
        }


def _band_quality(label: str, est: _frf.FRFEstimate, model: np.ndarray, f_lo: float, f_hi: float) -> list[BandQuality]:
    out = []
    for lo, hi in _frf.octave_bands(f_lo, f_hi):
        m = (est.f_hz >= lo) & (est.f_hz < hi) if hi < f_hi else (est.f_hz >= lo) & (est.f_hz <= hi)
        if not m.any():
            continue
        diff = np.abs(est.H[m] - model[m])
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = float(np.sqrt(np.mean((diff / np.abs(model[m])) ** 2)))
            z = float(np.sqrt(np.mean((diff / est.std_complex[m]) ** 2)))
        out.append(BandQuality(label, float(lo), float(hi), rel, z, float(np.mean(est.coherence[m]))))
    return out


def _fmt_band(lo: float, hi: float) -> str:
    return f"{lo:.3g}-{hi:.3g} Hz"


def _warnings(result_std: dict[str, float], values: dict[str, float], bands: list[BandQuality],
              nonlinear: list[list[_frf.NonlinearBand]], labels: list[str]) -> list[str]:
    out = []
    for name in PARAMETER_NAMES:
        if name == "Td":
            if result_std[name] > _TD_STD_WARN_S:
                out.append(f"too little excitation to trust Td (std {result_std[name] * 1e3:.2g} ms)")
        elif result_std[name] > _REL_STD_WARN * abs(values[name]):
            out.append(f"too little excitation to trust {name} (relative std "
                       f"{100 * result_std[name] / abs(values[name]):.1f} %)")
    for b in bands:
        where = f"{b.dataset}: " if len(labels) > 1 else ""
        if b.coherence < _LOW_COHERENCE:
            out.append(f"{where}low coherence ({b.coherence:.2f}) in band {_fmt_band(b.lo_hz, b.hi_hz)}: "
                       "little excitation or much noise there")
        if math.isfinite(b.z_rms) and b.z_rms > _MISFIT_WARN and b.coherence >= _LOW_COHERENCE:
            out.append(f"{where}the model misses the measured response in band {_fmt_band(b.lo_hz, b.hi_hz)} "
                       f"by {b.z_rms:.1f} times its uncertainty ({100 * b.rel_error:.1f} % RMS)")
    for label, bands_nl in zip(labels, nonlinear):
        where = f"{label}: " if len(labels) > 1 else ""
        for nb in bands_nl:
            if math.isfinite(nb.share) and nb.share > _NONLINEAR_WARN:
                ks = [k for k in nb.harmonics if k > 1]
                out.append(f"{where}the joint is not linear in band {_fmt_band(nb.lo_hz, nb.hi_hz)}: "
                           f"{100 * nb.share:.0f} % of the output power is in harmonics {ks[0]}-{ks[-1]}")
    return out


def _records(datasets: Sequence[Dataset], known: Sequence[Sequence[tuple[str, np.ndarray]]] | None,
             ripple: RippleTerms | None = None, log_filter: TorqueLogFilter | None = None) -> list[FitRecord]:
    """The fit's records of ``datasets`` with their known inputs and ripple terms (see
    :func:`fit_transfer_function`); the ripple's reaction from the torque before ``log_filter`` (the
    transmission carries the torque, not its log)."""
    if not datasets:
        raise IiwaIdentError("fit needs at least one dataset")
    records = prepare_records(datasets)
    if known is not None:
        for rec, inputs in zip(records, known):
            for kind, signal in inputs:
                if kind not in INPUTS or np.shape(signal) != (rec.n,):
                    raise ValueError(f"{rec.label}: known input {kind!r} needs one value per sample")
            rec.known = [(kind, np.asarray(signal, float)) for kind, signal in inputs]
    if ripple is not None:
        for rec in records:
            if log_filter is not None:
                rec.tau_carried = unfiltered_torque(rec.tau, rec.T, log_filter, rec.f_hi)
        _set_ripple_basis(records, ripple)
    return records


def _set_ripple_basis(records: list[FitRecord], ripple: RippleTerms) -> None:
    """Each record's ripple basis (and table) at ``ripple``'s period."""
    for rec in records:
        rec.set_ripple(ripple.signals, None if ripple.table is None else ripple.table_signals)


def _set_motion(problem: _Problem, x: np.ndarray, model_torque: bool = False) -> None:
    """Each record's motion between samples from the command's response at ``x``, where the ripple's inputs
    need it (:func:`~iiwa_ident.ident._records.record_motion`).

    With ``model_torque`` the torque through it is the model's at ``x`` (the measured one less the residual),
    not the measured one: the reaction multiplies the torque, and the sensor's noise in it drives the motor's
    modelled position at low frequencies, where the position's residual weighs most (on the default joint
    it spread ``Td`` over 30 ns, three times its std). The model's torque needs the period refined first: a
    period 1e-3 off misses the ripple by 0.1 Nm where the motor travels far.
    """
    params = _Problem.x_to_params(x)
    residuals = problem.unweighted(x) if model_torque else [(None, None)] * len(problem.records)
    for rec, (e_t, _) in zip(problem.records, residuals):
        if rec.ripple_signals is not None or rec.table_signals is not None:
            rec.set_motion(params, tau=None if e_t is None else rec.carried - e_t)
    problem._responses.clear()


def _measured_torque_step(problem: _Problem, x: np.ndarray, J: np.ndarray, r: np.ndarray,
                          Finv: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step of the fit at ``x`` (Jacobian ``J``, weighted residual ``r``, inverse Fisher
    information ``Finv``) when the ripple's reaction takes the measured torque instead of the model's
    (:func:`_set_motion`); the records' motion is left as it was."""
    saved = [rec.motion for rec in problem.records]
    _set_motion(problem, x)
    step = -Finv @ (J.T @ (problem.residual(x) - r))
    for rec, motion in zip(problem.records, saved):
        rec.restore_motion(motion)
    problem._responses.clear()
    return step


#: Relative half-width of the search for a searched ripple period around its start [-]: well inside the cost's
#: main lobe (about the period over the motion's range and the harmonics', more than 1 % on a chirp).
PERIOD_SEARCH = 5e-3


def _period_column(problem: _Problem, x: np.ndarray, ripple: RippleTerms) -> np.ndarray:
    """The weighted residual's derivative by the ripple's period [1/rad] at ``x`` (central difference); the
    records' basis is left at ``ripple``'s period."""
    h = ripple.period_rad * 1e-6
    cols = []
    for period in (ripple.period_rad + h, ripple.period_rad - h):
        _set_ripple_basis(problem.records, replace(ripple, period_rad=period))
        problem._responses.clear()
        cols.append(problem.residual(x))
    _set_ripple_basis(problem.records, ripple)
    problem._responses.clear()
    return (cols[0] - cols[1]) / (2 * h)


def _refined_period(problem: _Problem, x: np.ndarray, ripple: RippleTerms) -> RippleTerms:
    """``ripple`` at the period that minimises the fit's cost at ``x``, its basis set in the records.

    A period searched by the inverse dynamics is off by a few 1e-4 in noise, which biases the stiffness by
    several std; the output-error residual pins it down.
    """
    def cost(period: float) -> float:
        _set_ripple_basis(problem.records, replace(ripple, period_rad=period))
        problem._responses.clear()
        return float(np.sum(problem.residual(x) ** 2))

    p0 = ripple.period_rad
    found = minimize_scalar(cost, bounds=(p0 * (1 - PERIOD_SEARCH), p0 * (1 + PERIOD_SEARCH)), method="bounded",
                            options={"xatol": p0 * 1e-6})
    best = replace(ripple, period_rad=float(found.x) if found.fun <= cost(p0) else p0)
    cost(best.period_rad)
    return best


def _stages(log_filter: TorqueLogFilter | None) -> int:
    """The equal first-order stages of a filter the fit searches through (0: none); a pure delay or an
    underdamped second order is not one it searches."""
    if log_filter is None:
        return 0
    if log_filter.values["order"] == 0.0 or log_filter.values["damping"] != 1.0:
        raise IiwaIdentError(f"torque_log_filter {log_filter.to_dict()}: the fit searches one or two equal "
                             "first-order stages only")
    return int(log_filter.values["order"])


def output_residual_rms(datasets: Sequence[Dataset], params: dict[str, float],
                        known: Sequence[Sequence[tuple[str, np.ndarray]]] | None = None,
                        ripple: RippleTerms | None = None, log_filter: TorqueLogFilter | None = None
                        ) -> list[dict[str, float]]:
    """RMS output errors of eq (4) at ``params``, per dataset, after the nuisance fits (unweighted).

    Parameters
    ----------
    datasets : sequence of Dataset
        As for :func:`fit_transfer_function`.
    params : dict
        ``Jc, bc, K, Jl`` [SI] and ``Td`` [s].
    known : sequence, optional
        Known torques besides the command, as for :func:`fit_transfer_function`.
    ripple : RippleTerms, optional
        As for :func:`fit_transfer_function` (its coefficients fitted at ``params``).
    log_filter : TorqueLogFilter, optional
        A filter before the log the modelled torque passes (at its cut-off).

    Returns
    -------
    list of dict
        ``{"tau_j_nm": ..., "q_m_rad": ...}`` per dataset: the simulated outputs' errors less a constant
        (``tau_j``) and the drift spline (``q_m``). Compares models that differ in their known inputs.
    """
    order = _stages(log_filter)
    problem = _Problem(_records(datasets, known, ripple, log_filter), log_filter_order=order)
    x = _Problem.params_to_x([params[k] for k in PARAMETER_NAMES],
                             None if log_filter is None else float(log_filter.values["cutoff_hz"]))
    _set_motion(problem, x)
    return [{"tau_j_nm": float(np.sqrt(np.mean(e_t**2))), "q_m_rad": float(np.sqrt(np.mean(e_q**2)))}
            for e_t, e_q in problem.unweighted(x)]


@dataclass
class _Covariance:
    """The estimates' covariance [SI units squared, the log filter's cut-off after the parameters where it was
    fitted], the block sandwich's in log space, the scaling ``D`` from log space, how the std was computed
    (:attr:`FitResult.std_method`) and the log filter's fit (:attr:`FitResult.log_filter`)."""

    cov: np.ndarray
    cov_s: np.ndarray
    D: np.ndarray
    method: str
    log_filter_fit: dict[str, float] | None


def _covariance(problem: _Problem, x: np.ndarray, ripple: RippleTerms | None, order: int) -> _Covariance:
    """The covariance at the estimate ``x``; ``ripple``: the ripple's terms whose period was searched with the
    parameters (None where it was not), so that their std carry its uncertainty."""
    # Covariance: Fisher information of the weighted, projected residual; a block sandwich
    # estimate tells whether the residuals are white enough for it to hold.
    J = problem.jacobian(x)
    r = problem.residual(x)
    searched = ripple is not None and ripple.table is None
    if ripple is not None and searched:
        # The period was fitted too: its column, so that the parameters' std carry its uncertainty.
        J = np.column_stack([J, _period_column(problem, x, ripple)])
    F = np.einsum("ki,kj->ij", J, J)
    Finv = np.linalg.pinv(F)
    ids = problem.block_ids()
    scores = np.zeros((int(ids.max()) + 1, J.shape[1]))
    np.add.at(scores, ids, J * r[:, None])
    S = scores.T @ scores
    cov_s = Finv @ S @ Finv
    p = np.array(_Problem.x_to_params(x))
    lf = problem.log_filter(x)
    D = np.diag([*p[:4], 1e-3] + ([] if lf is None else [lf.values["cutoff_hz"]]) + ([1.0] if searched else []))
    cov = D @ Finv @ D
    std_method = STD_FISHER
    if any(rec.table_signals is not None or rec.ripple_basis for rec in problem.records):
        # The ripple's inputs are known at the samples only; between them the model interpolates, with
        # an error that matters at this signal-to-noise ratio. Step doubling estimates it: the fit's
        # step to a model twice as fine is 3/4 of the usual model's error (the error goes as the square).
        problem.substeps = 2
        shift = -Finv @ (J.T @ (problem.residual(x) - r))
        problem.substeps = 1
        err = D @ (shift * 4.0 / 3.0)
        cov = cov + np.outer(err, err)
        # The reaction multiplies the torque: the model's carries no sensor noise, the measured one no
        # model error; the estimates' step from one to the other bounds what the choice leaves in them.
        other = D @ _measured_torque_step(problem, x, J, r, Finv)
        cov = cov + np.outer(other, other)
        # What the model still misses (the sandwich sees it in slow residuals) shows first in Td: each
        # std is at least the block sandwich's, the correlations kept.
        widen = np.maximum(np.sqrt(np.diag(D @ cov_s @ D) / np.diag(cov)), 1.0)
        cov = cov * np.outer(widen, widen)
        std_method = STD_FISHER + STD_RIPPLE
    if searched:  # the period's own std is not reported; the others are marginal over it
        cov, cov_s, D = cov[:-1, :-1], cov_s[:-1, :-1], D[:-1, :-1]
    log_filter_fit = None
    if lf is not None:
        # The cut-off's std from the full covariance; the parameters' (5 x 5) block is their marginal one.
        log_filter_fit = {"cutoff_hz": float(lf.values["cutoff_hz"]), "std": float(math.sqrt(cov[5, 5])),
                          "order": order}
        cov, cov_s, D = cov[:5, :5], cov_s[:5, :5], D[:5, :5]
    return _Covariance(cov, cov_s, D, std_method, log_filter_fit)


@dataclass(kw_only=True)
class _RecordChecks:
    """Per record at the estimate: the residuals' RMS, H1 and the model over its bands, the band quality, the
    sweep's harmonics and nonlinear share, the residual tests (None where the lengths differ)."""

    noise: list[dict[str, float]]
    frf: list[_frf.FRFEstimate]
    model_frf: list[np.ndarray]
    bands: list[BandQuality]
    harmonics: list[_frf.HarmonicResponses | None]
    nonlinear: list[list[_frf.NonlinearBand]]
    tests: list[Any]


def _record_checks(problem: _Problem, x: np.ndarray, records: list[FitRecord], values: dict[str, float],
                   lf: TorqueLogFilter | None) -> _RecordChecks:
    """What each record says of the fit at ``x`` (:class:`_RecordChecks`)."""
    checks = _RecordChecks(noise=[], frf=[], model_frf=[], bands=[], harmonics=[], nonlinear=[], tests=[])
    noise, frfs, model_frfs, bands = checks.noise, checks.frf, checks.model_frf, checks.bands
    harmonics, nonlinear, tests = checks.harmonics, checks.nonlinear, checks.tests
    for rec, (e_t, e_q), y_ripple in zip(records, problem.unweighted(x), problem.ripple_response(x)):
        noise.append({"tau_j_nm": float(np.sqrt(np.mean(e_t**2))), "q_m_rad": float(np.sqrt(np.mean(e_q**2)))})
        tests.append(residual_tests(e_t, rec.u) if len(e_t) == len(rec.u) else None)
        # With known torques (the fitted link-side effects) the model's linear part is compared with the
        # data less those torques' response: eq (4) alone is not the model then.
        plain = without_known(rec, values, lf)
        if y_ripple is not None:
            plain = replace(plain, tau=plain.tau - y_ripple[0], q=plain.q - y_ripple[1], spectra=None)
        est_t, _ = record_frf(plain, delay_s=values["Td"])
        dm = discretize(values, rec.T)

        def response(f: np.ndarray, dm: Any = dm, T: float = rec.T) -> np.ndarray:
            return dm.frequency_response(f)[0] * (1.0 if lf is None else lf.frequency_response(f, T))

        model = est_t.band_average(response)
        frfs.append(est_t)
        model_frfs.append(model)
        bands.extend(_band_quality(rec.label, est_t, model, rec.f_lo, rec.f_hi))
        if rec.sweep is not None:
            sw = rec.sweep
            h = _frf.ess_harmonics(rec.tau, 1.0 / rec.T, sw["f0_hz"], sw["f1_hz"], sw["duration_s"],
                                   sw["amplitude_nm"])
            harmonics.append(h)
            nonlinear.append(_frf.nonlinear_share(h, _frf.octave_bands(rec.f_lo, rec.f_hi)))
        else:
            harmonics.append(None)
            nonlinear.append([])
    return checks


def _fit_warnings(records: list[FitRecord], checks: _RecordChecks, std_d: dict[str, float],
                  std_s: dict[str, float], values: dict[str, float]) -> list[str]:
    """What a user should know before trusting the fit (:attr:`FitResult.warnings`)."""
    labels = [r.label for r in records]
    bands, nonlinear, tests = checks.bands, checks.nonlinear, checks.tests
    warnings = _warnings(std_d, values, bands, nonlinear, labels)
    widening = float(np.median([std_s[k] / std_d[k] for k in PARAMETER_NAMES]))
    if widening > _COLOURED_WARN:
        warnings.append(f"the residuals are far from white noise (a block sandwich estimate gives {widening:.0f} "
                        "times the std): unmodelled effects such as the transmission ripple or the feasibility "
                        "filter; the std does not cover their systematic errors")
    for rec, t in zip(records, tests):
        ind = next((x for x in t.tests if x.name == INDEPENDENCE), None) if t is not None else None
        if ind is not None and not ind.passed:
            warnings.append(f"{rec.label}: the residual follows the torque command ({t.summary()}): the model "
                            "misses part of the response, and the std, which assumes a complete model, is not to "
                            "be trusted; 'iiwa-ident diagnose' names what is missing")
        elif t is not None and not t.passed:
            # In closed loop the residual is coloured by the loop even where the model is complete (the
            # benchmark's draws without any nuisance: whiteness failed on 3 of 4): said, not judged.
            warnings.append(f"{rec.label}: the residual is not white ({t.summary()}): the torque loop colours "
                            "the noise, and so does an effect the model lacks that does not follow the command "
                            "(the ripple); the std covers the loop's colouring, not such an effect")
    for r in records:
        if r.filled_cycles:
            warnings.append(f"{r.label}: {r.filled_cycles} lost robot cycles filled (command held, measurements "
                            "interpolated)")
    if any(r.sweep is None for r in records):
        warnings.append("no exponential sweep in " + ", ".join(r.label for r in records if r.sweep is None)
                        + ": harmonic distortion not analysed")
    return warnings


def fit_transfer_function(datasets: Sequence[Dataset], *, initial: dict[str, float] | None = None,
                          max_starts: int = 3, outer_iterations: int = 4,
                          known: Sequence[Sequence[tuple[str, np.ndarray]]] | None = None,
                          ripple: RippleTerms | None = None, refine: bool = True,
                          log_filter: TorqueLogFilter | None = None) -> FitResult:
    """Fit eq (4) with delay to one or more torque-commanded chirps of one joint.

    Parameters
    ----------
    datasets : sequence of Dataset
        Chirps with ``tau_c``, ``tau_j`` and ``q_m`` sampled once per command.
    initial : dict, optional
        Start values ``Jc, bc, K, Jl`` [SI], ``Td`` [s]; default
        :func:`~iiwa_ident.ident._initial.initial_estimate` (from the data only).
    max_starts : int
        How many delay candidates to refine before keeping the best.
    outer_iterations : int
        Re-estimations of the noise levels (heteroscedastic ML).
    known : sequence, optional
        Per dataset, known torques besides the command as ``(input, signal
        [Nm])`` pairs (:data:`INPUTS`), one value per sample: the link-side
        effects and the robot's gravity model estimated beforehand
        (:func:`iiwa_ident.ident.fit_joint`).
    ripple : RippleTerms, optional
        The transmission ripple: its table (if any) as a known input and the
        coefficients of its first harmonics fitted with the parameters, so
        that neither biases them and the std includes their uncertainty.
    refine : bool
        False: no search; the fit's diagnostics (noise levels, fit quality,
        harmonics, Fisher std) at ``initial``.
    log_filter : TorqueLogFilter, optional
        A filter between the torque sensor and the log: the modelled
        ``tau_j`` passes it (``q_m`` does not) and its cut-off is fitted as
        a sixth parameter, starting from this one's (the number of stages
        kept); the result's :attr:`FitResult.log_filter` holds it.

    Returns
    -------
    FitResult

    Raises
    ------
    IiwaIdentError
        A dataset has no torque command, is shorter than 2 s, is barely
        excited, has no coherent band, or the joints differ; the message
        names the file.
    """
    records = _records(datasets, known, ripple, log_filter)
    for rec in records:  # every file must carry information, not just the first
        est_t, _ = record_frf(rec)
        if int(np.sum(coherent_bands(est_t))) < 4:
            raise IiwaIdentError(f"{rec.label}: no band with coherence above {MIN_COHERENCE} between tau_c and tau_j: "
                                 "nothing to fit")
    starts = initial_candidates(records) if initial is None else [dict(initial)]
    order = _stages(log_filter)
    fc0 = None if log_filter is None else float(log_filter.values["cutoff_hz"])
    problem = _Problem(records, log_filter_order=order)

    # Noise levels for comparing the starts: from the best start's residuals.
    x_first = _Problem.params_to_x([starts[0][k] for k in PARAMETER_NAMES], fc0)
    problem.reweight(x_first, per_block=False)
    sols = [_solve(problem, _Problem.params_to_x([cand[k] for k in PARAMETER_NAMES], fc0),
                   max_iterations=40 if refine else 0) for cand in starts[:max_starts]]
    x = min(sols, key=lambda sol: sol.cost).x  # the first of equal costs, as the starts are ordered
    _set_motion(problem, x)  # the ripple's inputs between samples, from the command's response at the estimate
    if refine and ripple is not None and ripple.table is None and ripple.search:
        ripple = _refined_period(problem, x, ripple)  # the outer iterations solve at it
    if not refine:
        problem.reweight(x, per_block=True)
        sol = _solve(problem, x, max_iterations=0)
    for it in range(outer_iterations if refine else 0):
        problem.reweight(x, per_block=True)
        sol = _solve(problem, x)
        step = np.max(np.abs(sol.x - x))
        x = sol.x
        if it == 0:
            _set_motion(problem, x, model_torque=True)  # the later iterations solve with the model's torque
        elif step < 1e-6:
            break
    cost = float(sol.cost)
    n_eval = problem.n_evaluations

    c = _covariance(problem, x, ripple if refine else None, order)
    lf = problem.log_filter(x)
    p = np.array(_Problem.x_to_params(x))
    std = np.sqrt(np.diag(c.cov))
    corr = c.cov / np.outer(std, std)
    np.fill_diagonal(corr, 1.0)
    corr = np.clip(0.5 * (corr + corr.T), -1.0, 1.0)

    values = dict(zip(PARAMETER_NAMES, map(float, p)))
    std_d = dict(zip(PARAMETER_NAMES, map(float, std)))
    std_s = dict(zip(PARAMETER_NAMES, map(float, np.sqrt(np.diag(c.D @ c.cov_s @ c.D)))))

    checks = _record_checks(problem, x, records, values, lf)
    labels = [r.label for r in records]
    warnings = _fit_warnings(records, checks, std_d, std_s, values)
    tests = [t for t in checks.tests if t is not None]
    return FitResult(parameters=values, std=std_d, std_sandwich=std_s, std_method=c.method, correlation=corr,
                     covariance=c.cov, noise=checks.noise, frf=checks.frf, model_frf=checks.model_frf,
                     bands=checks.bands, harmonics=checks.harmonics, nonlinear=checks.nonlinear,
                     warnings=warnings, initial=starts, labels=labels, cost=cost, n_evaluations=n_eval,
                     sample_times_s=[r.T for r in records], residual_tests=tests, log_filter=c.log_filter_fit,
                     ripple_period_rad=None if ripple is None else ripple.period_rad)


# --------------------------------------------------------------------------
# Cramer-Rao bound


def cramer_rao_std(params: ParameterSource, datasets: Sequence[Dataset], tau_noise_nm: float, q_noise_rad: float,
                   *, nuisance: bool = True) -> dict[str, float]:
    """Cramer-Rao lower bound of the parameters' std for white noise of known level.

    Fisher information of the output-error model at ``params`` for the
    commands of ``datasets``: ``F = sum J^T J`` with the Jacobian of
    ``(tau_j / tau_noise, q_m / q_noise)`` with respect to the parameters.

    Parameters
    ----------
    params : mapping, JointModel or sequence
        Where to evaluate (usually the true parameters).
    datasets : sequence of Dataset
        Supply the commands ``tau_c`` and the sample times.
    tau_noise_nm : float
        White noise of ``tau_j`` [Nm].
    q_noise_rad : float
        White noise of ``q_m`` [rad] (quantisation: ``tick / sqrt(12)``).
    nuisance : bool
        Also estimate the fit's nuisance terms (torque offset, position
        drift); the bound then applies to :func:`fit_transfer_function`.

    Returns
    -------
    dict of str to float
        Bound on the std of ``Jc, bc, K, Jl`` [SI] and ``Td`` [s].
    """
    records = [prepare_record(ds, i) for i, ds in enumerate(datasets)]
    problem = _Problem(records, nuisance=nuisance)
    problem.sigma = [[np.full(r.n_blocks, tau_noise_nm), np.full(r.n_blocks, q_noise_rad)] for r in records]
    problem.update_projections()
    x = _Problem.params_to_x(_as_values(params))
    J = problem.jacobian(x)
    cov_x = np.linalg.pinv(np.einsum("ki,kj->ij", J, J))
    p = np.array(_as_values(params))
    D = np.diag([*p[:4], 1e-3])
    std = np.sqrt(np.diag(D @ cov_x @ D))
    return dict(zip(PARAMETER_NAMES, map(float, std)))
