"""Inverse dynamic identification of the joint with its link-side effects (IDIM-IV).

Model
-----
Eqs (1)-(3) of the paper with the link-side effects of
:mod:`iiwa_ident.sim._effects` (the simulator's own names and parameters):
the motor side under the internal torque loop, which regulates the torque
*reading* ``tau_s = tau_j + offset`` to the command after the delay and
the robot's own gravity model ``g_m``::

    Jc q_m'' = beta (e)' + e,      e = tau_c(t - Td) - g_m(q_m) - tau_s,   beta = bc / K      (1)
    Jl theta_l'' = tau_j + tau_f(omega_l) + tau_g(theta_l)                                    (2)
    theta_l = q_m - tau_j / K                                                           (3), (9)

with link friction ``tau_f = -F_c tanh(omega_l / v_s) - F_v omega_l`` and
a position-dependent load ``tau_g = A sin(theta_l + phi) + c``. Both
equations are linear in their parameters::

    tau_c(t - Td) - tau_s = Jc q_m'' - beta (tau_c(t - Td) - tau_s)' + g_m + beta g_m'
    tau_s = Jl q_m'' - (Jl / K) tau_s'' + (offset - c) + F_c tanh(omega_l / v_s) + F_v omega_l
            - A cos(phi) sin(theta_l) - A sin(phi) cos(theta_l)

(Gautier and Janot's inverse dynamic identification model). ``K = Jl / (Jl /
K)`` and ``bc = beta K``. A sensor offset and a constant link load enter
the link equation only as their difference; the fit reports it as the
offset.

Transmission ripple
-------------------
The ripple of eq (5), ``theta_l = q_m - f(q_m) - tau_j / K`` with ``f`` a
Fourier series of period ``rho``, adds ``-Jl f''`` to the link equation and
the reaction ``-tau_s f'`` to the motor equation, both linear in ``f``'s
coefficients once ``rho`` is known. Unmodelled, the paper's ripple biased
``K`` and ``Jl`` by 2-6 %. ``rho`` is given or searched in the link
equation's residual (:func:`_ripple_search`); the ripple's columns stay only
if their Wald statistic clears :data:`RIPPLE_CHI2`.

Spectral lines
--------------
A disturbance of the torque reading periodic in time (mains hum, a PWM's
lines), ``tau_s = tau_j + h``, enters the link equation as
``(1 - Jl w^2 / K) h`` and the motor equation through the torque loop:
at each line one free sine and cosine per record in both equations. The
lines are searched in the link equation's residual (:func:`_line_search`,
:mod:`iiwa_ident.ident._lines`), their frequencies refined on the reading,
and the link's angle and speed of eq (9) are computed from the reading
without them (a hum in ``tau_s' / K`` passes through the friction's tanh).

Derivatives
-----------
Every signal is extended evenly (so its periodic continuation has no jump),
low-passed without phase by ``1 / sqrt(1 + (f / f_c)^8)`` with ``f_c``
just above the excited band, and differentiated exactly in the frequency
domain (``(j w)^k``): no finite-difference gain error at high frequency.
The command is the robot's zero-order hold: its spectrum gets the hold's
``sinc`` and half-sample lag, and the delay ``Td`` is applied as an exact
fractional shift. Samples within a quarter second and a few filter time
constants of either end are not used (the extension's kinks ring there).

Instrumental variables
----------------------
``tau_s''`` and ``(tau_s)'`` are noisy regressors, which biases least
squares (noise in a regressor pulls its coefficient towards zero). Their
instruments are the same derivatives of the joint torque the current model
predicts from the command and the estimated link torques, computed in the
frequency domain from eq (4)'s two transfer functions; three IV
iterations. ``Td`` by a 1-D search on the motor equation's residual (0-50 ms,
a 1 ms grid, then Brent's method), re-done after each iteration.

Aliasing, sticking, identifiability
-----------------------------------
The hold's images above the Nyquist limit drive the joint too and fold back
onto the samples; after the first pass their predicted response is taken
out of ``tau_j`` and ``q_m`` (:func:`dealiased`). Where Coulomb friction
shows, a link slower than :data:`STICK_VELOCITY_RAD_S` may stick and its
friction is then whatever balances the other torques: a second fit leaves
those samples out, and the fit with the smaller relative std of ``K`` and
``Jl`` is kept. A chirp that stays below the resonance, or a parameter with
a std above half its value, is refused, naming the parameter.

Uncertainty
-----------
A block sandwich (quarter-second blocks of both equations' scores; ``Td``
as an extra column of the motor equation) gives the covariance, robust to
the residuals' colour and to unmodelled effects that vary slower than a
block; ``K`` and ``bc`` by the delta method.

References
----------
M. Gautier, A. Janot, P.-O. Vandanjon, "A new closed-loop output error
method for parameter identification of robot dynamics", IEEE TCST 21(2),
2013; A. Janot, P.-O. Vandanjon, M. Gautier, "A generic instrumental
variable approach for industrial robot identification", IEEE TCST 22(1), 2014.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._idim_rows import (
    Lines,
    Narrowband,
    Prepared,
    dealiased,
    motor_delayed,
    motor_rows,
    motor_static,
    prepare_like,
    prepare_rows,
    ripple_basis,
    ripple_link_columns,
)
from iiwa_ident.ident._initial import MAX_DELAY_S
from iiwa_ident.ident._lines import (
    BACKGROUND_CELLS,
    block_weights,
    fit_sinusoid,
    line_ratio,
)
from iiwa_ident.ident._records import FitRecord, prepare_records
from iiwa_ident.model import PARAMETER_NAMES, frequency_response, resonance_hz

__all__ = ["LinkEffectEstimate", "IdimResult", "fit_idim", "FRICTION_SMOOTHING_RAD_S", "LOAD_MIN_RANGE_RAD",
           "STICK_VELOCITY_RAD_S", "STICK_COULOMB_NM", "STICK_MIN_SHARE", "MIN_BAND_OVER_RESONANCE", "MAX_RELATIVE_STD",
           "RIPPLE_CYCLES_PER_REV", "RIPPLE_HARMONICS", "RIPPLE_MIN_SHARE", "RIPPLE_HALF_SHARE",
           "RIPPLE_CHI2", "LINE_RATIO", "MAX_LINES"]

#: Velocity scale of the fitted Coulomb tanh [rad/s] (the simulator's default smoothing).
FRICTION_SMOOTHING_RAD_S = 0.005
#: Link speed below which the link may stick; those samples leave the link equation [rad/s].
STICK_VELOCITY_RAD_S = 0.02
#: Coulomb friction from which sticking samples are left out [Nm] (about five times a torque sensor's noise).
STICK_COULOMB_NM = 0.1
#: Least share of the samples that must remain for a fit without the sticking samples.
STICK_MIN_SHARE = 0.05
#: Least top of the chirp's band, as a share of the fitted resonance, for K and Jl to separate.
MIN_BAND_OVER_RESONANCE = 0.6
#: Largest std of Jc, bc, K or Jl, as a share of its value, of a parameter the data determine.
MAX_RELATIVE_STD = 0.5
#: Least span of link angles over which a load's amplitude and phase are fitted [rad].
LOAD_MIN_RANGE_RAD = 0.5
#: Fundamentals searched for the transmission ripple [cycles per motor revolution].
RIPPLE_CYCLES_PER_REV = (50.0, 2000.0)
#: Harmonics of the ripple's fundamental fitted in both equations.
RIPPLE_HARMONICS = 3
#: Least share of the link equation's residual power the searched ripple must explain to be fitted.
RIPPLE_MIN_SHARE = 0.02
#: Least share, of what the searched family explains, that the half frequency's other lines must add
#: for the fit with twice the period to be tried.
RIPPLE_HALF_SHARE = 0.01
#: Wald statistic (2 x RIPPLE_HARMONICS degrees of freedom) above which the fitted ripple is kept; far in the
#: tail (chi-square p about 1e-6) because its period was searched over some hundred candidates.
RIPPLE_CHI2 = 38.0
#: Least ratio of the link equation residual's periodogram to its running median (geometric mean over the
#: records) for a spectral line to be fitted as a free sinusoid; white noise exceeds it with probability
#: 1e-15 per cell, a chirp's model error (broadband) does not reach it.
LINE_RATIO = 50.0
#: Most spectral lines fitted (a hum and its harmonics).
MAX_LINES = 6
_K0 = 1e4  # stiffness [Nm/rad] of eq (9) in the link equation's first pass (a joint's order; refined after it)
_STICK_REACH = 1.0  # filter time constants around a sticking sample that its error reaches
_IV_ITERATIONS = 3


@dataclass
class LinkEffectEstimate:
    """One fitted effect in the simulator's vocabulary.

    Attributes
    ----------
    name : str
        Effect name in :data:`iiwa_ident.sim.EFFECTS`.
    values, std : dict of str to float
        Parameter values and their std (the effect's units).
    significant : bool
        The effect's main parameter exceeds 3 std.
    note : str
        Why a parameter is missing or what it includes.
    """

    name: str
    values: dict[str, float]
    std: dict[str, float]
    significant: bool
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        # A std that is not known is null (strict JSON has no NaN).
        out: dict[str, Any] = {}
        for k, v in self.values.items():
            s = self.std.get(k, math.nan)
            out[k] = {"value": v, "std": s if math.isfinite(s) else None}
        out["significant"] = self.significant
        if self.note:
            out["note"] = self.note
        return out


@dataclass(kw_only=True)
class IdimResult:
    """Outcome of :func:`fit_idim`.

    Attributes
    ----------
    parameters, std : dict of str to float
        ``Jc, bc, K, Jl`` [SI], ``Td`` [s] and their std (block sandwich).
    effects : list of LinkEffectEstimate
        Link friction, position-dependent load (or its local gradient) and torque-sensor offset.
    residual_rms : dict of str to float
        RMS equation errors of the motor and the link equation [Nm].
    method : str
    """

    parameters: dict[str, float]
    std: dict[str, float]
    effects: list[LinkEffectEstimate]
    residual_rms: dict[str, float]
    labels: list[str]
    method: str = "IDIM-IV"
    warnings: list[str] = field(default_factory=list)
    #: Per dataset, the estimated torques besides the command as ``(input, signal [Nm])`` for
    #: :func:`iiwa_ident.ident._tf_fit.fit_transfer_function`: link friction and load on the link,
    #: the robot's gravity model on the motor side. Each signal is the mean over its sample (the
    #: model holds an input over the sample).
    known_inputs: list[list[tuple[str, np.ndarray]]] = field(default_factory=list)
    #: Spectral lines of the torque reading [Hz] fitted as free sinusoids in both equations (a hum and its
    #: harmonics; see :func:`_line_search`), strongest first.
    lines_hz: tuple[float, ...] = ()

    def effect(self, name: str) -> LinkEffectEstimate | None:
        return next((e for e in self.effects if e.name == name), None)


class _DelayCost:
    """The motor equation's IV residual sum of squares as a function of the delay, for one record.

    Only beta's column and ``y`` change with the delay: the products of the other columns are formed once,
    so each delay costs two inverse FFTs and a few matrix-vector products instead of the whole regression.
    """

    def __init__(self, p: Prepared, tau_hat: tuple[np.ndarray, np.ndarray] | None) -> None:
        self.p, self.tau_hat = p, tau_hat
        self.S = motor_static(p)
        self.gram = self.S.T @ self.S
        self.scale = _column_scale(self.S)

    def __call__(self, td: float) -> float:
        y, c, z = motor_delayed(self.p, td, self.tau_hat)
        S = self.S
        m = S.shape[1]
        St_c = S.T @ c
        A = np.empty((m + 1, m + 1))
        A[:m, :m] = self.gram
        A[:m, m] = St_c
        A[m, :m] = St_c if z is c else S.T @ z
        A[m, m] = z @ c
        x = _iv_solve(A, np.append(S.T @ y, z @ y), np.append(self.scale, _column_scale(c[:, None])))
        e = y - S @ x[:m] - c * x[m]
        return float(e @ e)


class _LinkRows(NamedTuple):
    """The link equation's rows: ``y``, regressors, instruments, their names and the samples they are of."""

    y: np.ndarray
    Phi: np.ndarray
    Z: np.ndarray
    names: list[str]
    samples: np.ndarray


def _link_rows(p: Prepared, K: float, load: str, tau_hat: tuple[np.ndarray, np.ndarray] | None = None,
               moving: np.ndarray | None = None) -> _LinkRows:
    """(y, Phi, Z, names, samples) of the link equation, ``theta_l`` and ``omega_l`` from eq (9) at stiffness ``K``.

    ``moving``: the samples to use besides ``p.keep`` (default all).
    """
    theta = p.q_w - p.tau_w / K
    omega = p.dq_w - p.dtau_w / K
    k = p.keep & moving if moving is not None else p.keep
    flt = p.sp.filtered
    cols = [p.ddq[k], -p.ddtau_s[k], np.ones(int(k.sum())), flt(np.tanh(omega / FRICTION_SMOOTHING_RAD_S))[k],
            flt(omega)[k]] + [c[k] for c in p.rl_cols]
    names = ["Jl", "Jl_over_K", "offset", "coulomb", "viscous"]
    names += [f"ripple_{ab}{j // 2 + 1}" for j, ab in zip(range(len(p.rl_cols)), "ab" * len(p.rl_cols))]
    if load == "sinusoid":
        cols += [-flt(np.sin(theta))[k], -flt(np.cos(theta))[k]]
        names += ["load_a", "load_b"]
    elif load == "gradient":
        cols += [-(flt(theta)[k] - float(np.mean(theta[k])))]
        names += ["load_gradient"]
    Phi = np.column_stack(cols)
    if p.lines is not None:
        Phi = np.column_stack([Phi, p.lines.block(p.line_cols, k)])
        names += p.lines.names()
    Z = Phi.copy()
    if tau_hat is not None:
        Z[:, 1] = -tau_hat[1][k]
    return _LinkRows(p.tau_s[k], Phi, Z, names, k)


def _moving(omega: np.ndarray, p: Prepared) -> np.ndarray:
    """Samples far from a sticking link: the friction model says nothing about the torque of a link at rest.

    A link slower than :data:`STICK_VELOCITY_RAD_S` may stick, and its friction is then whatever balances
    the other torques; those samples, and the low-pass's reach around them, leave the link equation.
    """
    slow = np.abs(omega) < STICK_VELOCITY_RAD_S
    reach = int(math.ceil(_STICK_REACH / (p.fc * p.rec.T)))
    if slow.any() and reach > 0:
        slow = np.convolve(slow.astype(float), np.ones(2 * reach + 1), mode="same") > 0
    return ~slow


def _stick_masks(preps: list[Prepared], K: float) -> list[np.ndarray] | None:
    """Per record, the samples far from sticking, or ``None`` when too few would remain.

    Fixed once (at the stiffness of the fit on every sample) so that the link equation's rows do not
    change between passes; below :data:`STICK_MIN_SHARE` kept, the samples are too few to try.
    """
    masks = [_moving(p.dq_w - p.dtau_w / K, p) for p in preps]
    kept = sum(int((m & p.keep).sum()) for m, p in zip(masks, preps))
    total = sum(int(p.keep.sum()) for p in preps)
    return masks if kept >= STICK_MIN_SHARE * total else None


def _iv(y: np.ndarray, Phi: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """IV estimate ``(Z^T Phi)^-1 Z^T y`` with column scaling (LS when ``Z is Phi``)."""
    return _iv_solve(Z.T @ Phi, Z.T @ y, _column_scale(Phi))


def _column_scale(Phi: np.ndarray) -> np.ndarray:
    """RMS of each column (1 for a zero column): the IV solve's scaling."""
    scale = np.sqrt(np.mean(Phi**2, axis=0))
    scale[scale == 0] = 1.0
    return scale


def _iv_solve(ZtPhi: np.ndarray, Zty: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The IV estimate from its products ``Z^T Phi`` and ``Z^T y``, solved with the columns scaled to unit RMS."""
    x, *_ = np.linalg.lstsq(ZtPhi / np.outer(scale, scale), Zty / scale, rcond=1e-12)
    return x / scale


def _delay(preps: list[Prepared], tau_hat: list | None, lo: float = 0.0, hi: float = MAX_DELAY_S) -> float:
    """Delay minimising the motor equation's residual, summed over the records."""

    costs_of = [_DelayCost(p, None if tau_hat is None else tau_hat[i]) for i, p in enumerate(preps)]

    def cost(td: float) -> float:
        return sum(c(td) for c in costs_of)

    # The residual's structure in Td is no finer than a period of the chirp's top frequency (4 ms or more
    # for chirps up to 250 Hz): the grid brackets the minimum, Brent's method refines it.
    grid = np.arange(lo, hi + 1e-12, 1e-3 if hi - lo > 0.01 else 0.5e-3)
    costs = np.array([cost(t) for t in grid])
    i = int(np.argmin(costs))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if b <= a:
        return float(grid[i])
    best = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 1e-6})
    return float(best.x) if best.fun <= costs[i] else float(grid[i])


def _gravity_model(xm: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The robot's gravity model g_m(q) [Nm] from the motor equation's coefficients (sin q, cos q, 1)."""
    return xm[2] * np.sin(q) + xm[3] * np.cos(q) + xm[4]


def _predicted_torque(p: Prepared, prm: dict[str, float], td: float, xm: np.ndarray, link_torque: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(tau_j', tau_j'') the model predicts from the command and the estimated link and gravity torques."""
    U = p.sp.held_delayed(p.U, td) - p.sp.spectrum(_gravity_model(xm, p.q_w))  # delayed already: as a torque added inside the robot
    D = p.sp.spectrum(link_torque)
    model = {**prm, "Td": td}  # the two inputs here have no delay of their own
    TJ = frequency_response(model, p.sp.f, "motor") * U + frequency_response(model, p.sp.f, "link") * D
    return p.sp.back(TJ, 1), p.sp.back(TJ, 2)


def fit_idim(datasets: Sequence[Dataset], ripple_period_rad: float | None = None) -> IdimResult:
    """Fit eqs (1)-(3) with link friction, load, sensor offset and transmission ripple by IDIM-IV.

    Parameters
    ----------
    datasets : sequence of Dataset
        Torque-commanded runs of one joint with ``tau_c``, ``tau_j`` and
        ``q_m`` sampled once per command.
    ripple_period_rad : float, optional
        The ripple's period ``rho`` [rad] when it is known (for example from
        ``iiwa-ident ripple``); by default it is searched in the link
        equation's residual (:data:`RIPPLE_CYCLES_PER_REV`).

    Returns
    -------
    IdimResult

    Raises
    ------
    IiwaIdentError
        A dataset cannot be fitted, or a parameter is not identifiable from
        the data; the message names the file or the parameter and the reason.
    """
    if not datasets:
        raise IiwaIdentError("fit needs at least one dataset")
    records = prepare_records(datasets)
    preps = [prepare_rows(r) for r in records]
    span = max(float(np.ptp(p.q[p.keep])) for p in preps)
    load = "sinusoid" if span >= LOAD_MIN_RANGE_RAD else "gradient"
    lines = _line_search(preps, load)
    if lines:
        preps = [prepare_rows(r, None, Lines(lines, i, len(records))) for i, r in enumerate(records)]
    result = _without_sticking(_solve(records, preps, load, span, None), records, preps, load, span)
    found = (ripple_period_rad, None) if ripple_period_rad is not None else \
        _ripple_search(preps, result.parameters["K"], load)
    if found is not None:
        period, double_period = found
        # The ripple's columns only where it shows: each adds its own noise to the fit.
        td0 = result.parameters["Td"]
        rippled = _with_ripple(records, preps, load, span, float(period), RIPPLE_HARMONICS, td0)
        if rippled is not None:
            result = rippled
            if double_period is not None:
                # The searched family may be the second harmonic's: with twice the period and twice the
                # harmonics the odd ones are new; they are the fundamental's family if they show.
                double = _with_ripple(records, preps, load, span, double_period, 2 * RIPPLE_HARMONICS, td0)
                odd = None if double is None else double.effect("transmission_ripple")
                if double is not None and odd is not None and _odd_wald(odd) > RIPPLE_CHI2:
                    result = double
    result.lines_hz = lines
    if lines:
        result.warnings.append("spectral lines in the torque reading at " + ", ".join(f"{f:.6g}" for f in lines)
                               + " Hz (a hum?) fitted as free sinusoids in both equations")
    return _identified(result, records)


class _LinkResidual(NamedTuple):
    """The link equation's rows per record, stacked ``y`` and ``Phi``, and the residual of the fit."""

    rows: list
    y: np.ndarray
    Phi: np.ndarray
    residual: np.ndarray


def _link_residual(preps: list[Prepared], K: float, load: str) -> _LinkResidual:
    """The link equation's rows per record at stiffness ``K``, stacked ``y`` and ``Phi``, and the residual of
    their least-squares fit (no physical check: a search only needs what the columns leave)."""
    rows = [_link_rows(p, K, load) for p in preps]
    y = np.concatenate([r[0] for r in rows])
    Phi = np.concatenate([r[1] for r in rows])
    return _LinkResidual(rows, y, Phi, y - Phi @ _iv(y, Phi, Phi))


def _line_search(preps: list[Prepared], load: str) -> tuple[float, ...]:
    """Frequencies [Hz] of the spectral lines in the link equation's residual, strongest first.

    A disturbance of the torque reading periodic in time (a hum ``h``) enters the link equation as
    ``(1 - Jl w^2 / K) h`` (``tau_s - h`` obeys eq (2)), amplified above the link's resonance by the
    ``tau_s''`` regressor: 0.15-0.4 Nm at 50-90 Hz made ``Jl`` negative. Each line is one free sine
    and cosine per record in both equations.

    The residual of a least-squares fit of the link equation (no physical check: it only has to
    expose the lines); a line is a cell whose periodogram over its running median
    (:func:`~iiwa_ident.ident.line_ratio`), geometric mean over the records, exceeds
    :data:`LINE_RATIO`; its frequency refined by the power a sinusoid explains, it is projected out and
    the next is searched, up to :data:`MAX_LINES`.
    """
    rows, _, _, e = _link_residual(preps, _K0, load)
    res, start = [], 0
    for r in rows:
        res.append(e[start:start + len(r[0])])
        start += len(r[0])
    times = [np.nonzero(r[4])[0] * p.rec.T for r, p in zip(rows, preps)]
    # The chirp's model error passes each frequency briefly and loudly (at 117 Hz it pulled a line's
    # frequency by 0.01 Hz, which over 8 s turns its phase by half a radian): the sinusoids are fitted with
    # each block weighted by the inverse of its residual power.
    weights = [block_weights(x, p.block[r[4]]) for x, r, p in zip(res, rows, preps)]
    readings = [p.sp.spectrum(p.rec.tau, wide=True) for p in preps]
    longest = max(len(t) * p.rec.T for t, p in zip(times, preps))
    # Up to the Nyquist limit: the low-pass attenuates a line above the chirp's band, but the tau_s''
    # regressor amplifies it by (Jl / K) w^2 (a 0.4 Nm hum at 114 Hz, 2.4 times the cut-off: 1.8 Nm).
    hi = min(0.45 / p.rec.T for p in preps)
    grid = np.arange(1.0, hi, 0.25 / longest)
    if len(grid) < 10 or min(len(x) for x in res) < 4 * BACKGROUND_CELLS:
        return ()

    def without(f: float) -> list[np.ndarray]:
        """Per record, the residual without its sinusoid at ``f``."""
        out = []
        for x, t, w in zip(res, times, weights):
            (a, c), _ = fit_sinusoid(x, w, t, f)
            out.append(x - a * np.sin(2 * np.pi * f * t) - c * np.cos(2 * np.pi * f * t))
        return out

    found: list[float] = []
    for _ in range(MAX_LINES):
        score = np.mean([np.log(line_ratio(x, p.rec.T, grid)) for x, p in zip(res, preps)], axis=0)
        for f in found:
            # What a line leaves in its neighbour cells is its amplitude's slow variation, not another line.
            score[np.abs(grid - f) < 3.0 / longest] = 0.0
        i = int(np.argmax(score))
        if not score[i] > math.log(LINE_RATIO):
            break
        # The frequency from the reading itself: in the residual the line also passed through the
        # friction's tanh, whose intermodulation pulled it by 0.007 Hz (0.6 rad over a 13 s record).
        step = 1.0 / longest
        bands = [Narrowband(p.sp, X, float(grid[i]), p.keep, p.block) for p, X in zip(preps, readings)]
        best = minimize_scalar(lambda f, bands=bands: -sum(nb.fit(f)[1] for nb in bands),
                               bounds=(grid[i] - step, grid[i] + step), method="bounded",
                               options={"xatol": 1e-4 * step})
        f = float(best.x)
        found.append(f)
        res = without(f)
    return tuple(found)


def _with_ripple(records: list[FitRecord], like: list[Prepared], load: str, span: float, period: float,
                 harmonics: int, td0: float) -> IdimResult | None:
    """The fit with the ripple's columns, or ``None`` when the ripple is not significant in it.

    ``like``: the records prepared without them (their line columns are kept); ``td0``: the delay without
    them (the ripple barely moves it; searched only around it).
    """
    ripple = (period, harmonics)
    preps = [prepare_rows(r, ripple, p.lines) for r, p in zip(records, like)]
    try:
        res = _without_sticking(_solve(records, preps, load, span, None, td0), records, preps, load, span)
    except IiwaIdentError:
        return None
    found = res.effect("transmission_ripple")
    return res if found is not None and found.significant else None


def _odd_wald(effect: LinkEffectEstimate) -> float:
    """Sum of the odd harmonics' squared amplitude-to-std ratios (about a Wald statistic of their
    coefficients, with their correlations left out)."""
    total, k = 0.0, 1
    while f"amplitude{k}_rad" in effect.values:
        a, s = effect.values[f"amplitude{k}_rad"], effect.std[f"amplitude{k}_rad"]
        total += (a / s) ** 2 if s > 0 else math.inf
        k += 2
    return total


def _ripple_search(preps: list[Prepared], K: float, load: str) -> tuple[float, float | None] | None:
    """The ripple's period [rad] from the link equation's residual, or ``None`` when it explains little;
    with it, twice that period refined with twice the harmonics, where its other lines add at least
    :data:`RIPPLE_HALF_SHARE` (else ``None``).

    1. Harmonic summation on a grid of fundamentals (a quarter of the resolution ``1 / span`` apart):
       the residual power the first two harmonics' ``-f''`` columns explain, each alone, summed
       (unfiltered columns: cheap, and only the peak is wanted).
    2. Brent's method refines it on the filtered columns of :data:`RIPPLE_HARMONICS` harmonics fitted
       together, the columns the fit then uses.

    The strongest family may be the second harmonic's (``f''`` weighs harmonic ``k`` by ``k^2``):
    :func:`fit_idim` tests the half period's odd harmonics in the full fit.

    Periods longer than the motor's travel are not searched: over less than one period a ripple cannot
    be told from a load.
    """
    rows, y, Phi, e = _link_residual(preps, K, load)
    masks = [r[4] for r in rows]
    q, dq, ddq = (np.concatenate([getattr(p, a)[k] for p, k in zip(preps, masks)]) for a in ("q_w", "dq_w", "ddq_w"))
    span = max(float(np.ptp(p.q_w[k])) for p, k in zip(preps, masks))
    lo = max(RIPPLE_CYCLES_PER_REV[0] / (2 * math.pi), 1.0 / span) if span > 0 else math.inf
    hi = RIPPLE_CYCLES_PER_REV[1] / (2 * math.pi)
    total = float(e @ e)
    if not (lo < hi and total > 0):
        return None
    scale = np.sqrt(np.mean(Phi**2, axis=0))
    scale[scale == 0] = 1.0
    Phi_s, y_s = Phi / scale, y

    def summed(nu: float) -> float:
        out = 0.0
        for _, _, _, ddc, dds in ripple_basis(q, dq, ddq, 1.0 / nu, 2):
            G = np.array([[ddc @ ddc, ddc @ dds], [ddc @ dds, dds @ dds]])
            b = np.array([ddc @ e, dds @ e])
            if np.linalg.det(G) > 0:
                out += float(b @ np.linalg.solve(G, b))
        return out

    def columns(nu: float, harmonics: int) -> np.ndarray:
        return np.concatenate([np.column_stack(ripple_link_columns(p, 1.0 / nu, harmonics))[k]
                               for p, k in zip(preps, masks)])

    def joint(nu: float, harmonics: int = RIPPLE_HARMONICS) -> float:
        """Residual power explained by the filtered columns of the harmonics of ``nu``, together."""
        # With the equation's own columns: the ripple's overlap with them (with q'' above all) is not
        # credited to the ripple, and the period lands where the full fit's residual is least.
        X = np.column_stack([Phi_s, columns(nu, harmonics)])
        coef, *_ = np.linalg.lstsq(X, y_s, rcond=None)
        r = y_s - X @ coef
        return total - float(r @ r)

    def refined(nu: float, width: float, harmonics: int = RIPPLE_HARMONICS) -> tuple[float, float]:
        ref = minimize_scalar(lambda v: -joint(v, harmonics), bounds=(nu - width, nu + width), method="bounded",
                              options={"xatol": 1e-3 * width})
        start = joint(nu, harmonics)
        return (float(ref.x), -float(ref.fun)) if -ref.fun > start else (nu, start)

    step = 0.25 / span
    grid = np.arange(lo, hi + step, step)
    nu, best = refined(float(grid[int(np.argmax([summed(v) for v in grid]))]), step)
    if best < RIPPLE_MIN_SHARE * total:
        return None
    # The half frequency's family, refined on its own: its period is the candidate fit_idim tests.
    half = None
    if 0.5 * nu >= lo:
        # Measured: a real fundamental below the strongest family added 4-10 % to what the family
        # explains, the half frequency's other lines on a family that is the fundamental's 0.01-0.1 %.
        half, more = refined(0.5 * nu, 0.5 * step, 2 * RIPPLE_HARMONICS)
        if more - best < RIPPLE_HALF_SHARE * best:
            half = None
    return 1.0 / nu, None if half is None else 1.0 / half


def _without_sticking(everything: IdimResult, records: list[FitRecord], preps: list[Prepared], load: str,
                      span: float) -> IdimResult:
    coulomb = everything.effect("link_friction")
    if coulomb is None or not coulomb.values["coulomb_nm"] > STICK_COULOMB_NM:
        return everything
    # Coulomb friction shows: the same fit without the samples where the link may stick. A link at rest
    # makes its friction whatever balances the other torques, so those samples bias the link equation; but
    # leaving out most of a record costs precision. The fit with the smaller relative std of K and Jl wins.
    final = [prepare_like(dealiased(r, everything.parameters, everything.parameters["Td"]), p)
             for r, p in zip(records, preps)]
    masks = _stick_masks(final, everything.parameters["K"])
    if masks is None:
        return everything
    try:
        moving = _solve(records, preps, load, span, masks, everything.parameters["Td"])
    except IiwaIdentError:
        return everything
    return min((everything, moving), key=_relative_std)


def _identified(res: IdimResult, records: list[FitRecord]) -> IdimResult:
    """``res``, or a refusal naming the parameter the data do not determine and why.

    ``K`` and ``Jl`` separate only where the joint's compliance shows, at and above the resonance: a chirp
    that stops below :data:`MIN_BAND_OVER_RESONANCE` of it leaves ``Jl / K`` to the friction and noise
    (measured: ``K`` off by 14-36 % with a std of 1-2 %, at 0.5 and 0.3 of the resonance). Any of ``Jc,
    bc, K, Jl`` with a std above :data:`MAX_RELATIVE_STD` of its value is not determined either.
    """
    prm = res.parameters
    f_res = resonance_hz(prm["Jc"], prm["K"], prm["Jl"])
    rec = max(records, key=lambda r: r.f_hi)
    if rec.f_hi < MIN_BAND_OVER_RESONANCE * f_res:
        raise IiwaIdentError(
            f"K: the chirp's band {rec.f_lo:.3g}-{rec.f_hi:.3g} Hz stays below the resonance near {f_res:.3g} Hz "
            f"(it must reach at least {MIN_BAND_OVER_RESONANCE:g} of it; chirp to {2 * f_res:.3g} Hz or beyond)")
    for k in PARAMETER_NAMES[:4]:
        if not res.std[k] <= MAX_RELATIVE_STD * abs(prm[k]):
            raise IiwaIdentError(f"{k}: not determined by the data in the band {rec.f_lo:.3g}-{rec.f_hi:.3g} Hz "
                                 f"(std {res.std[k]:.3g} against the value {prm[k]:.3g}); a stronger or longer chirp may "
                                 f"determine it")
    return res


def _relative_std(res: IdimResult) -> float:
    """The larger relative std of ``K`` and ``Jl``: how well a fit pins down the link side."""
    return max(res.std["K"] / res.parameters["K"], res.std["Jl"] / res.parameters["Jl"])


def _solve(records: list[FitRecord], preps: list[Prepared], load: str, span: float,
           stick: list[np.ndarray] | None, td0: float | None = None) -> IdimResult:
    """IV iterations with the delay search and the alias correction; ``stick``: per record the samples the
    link equation uses (``None``: all); ``td0``: a delay found before (searched only around it)."""
    tau_hat: list | None = None
    K = _K0
    td = _delay(preps, None) if td0 is None else _delay(preps, None, max(td0 - 2e-3, 0.0), min(td0 + 2e-3, MAX_DELAY_S))
    for it in range(_IV_ITERATIONS + 1):
        # Motor equation over all records.
        rows = [motor_rows(p, td, None if tau_hat is None else tau_hat[i]) for i, p in enumerate(preps)]
        y_m, Phi_m, Z_m = (np.concatenate(z) for z in zip(*rows))
        xm = _iv(y_m, Phi_m, Z_m)
        # Link equation; K enters theta_l and omega_l through eq (9): a few fixed-point passes.
        for _ in range(3):
            lrows = [_link_rows(p, K, load, None if tau_hat is None else tau_hat[i],
                                None if stick is None else stick[i])
                     for i, p in enumerate(preps)]
            names = lrows[0][3]
            y_l = np.concatenate([r[0] for r in lrows])
            Phi_l = np.concatenate([r[1] for r in lrows])
            Z_l = np.concatenate([r[2] for r in lrows])
            xl = _iv(y_l, Phi_l, Z_l)
            if not (xl[0] > 0 and xl[1] > 0):
                break
            K = float(xl[0] / xl[1])
        prm = _physical(xm, xl, records)
        if it == _IV_ITERATIONS:
            break
        if it < 2:  # the hold's aliased images out of the samples, at the estimate so far
            preps = [prepare_like(dealiased(r, prm, td), p) for r, p in zip(records, preps)]
        tau_hat = []
        for p in preps:
            lt = _link_torque(p, prm["K"], xl, names, load)
            tau_hat.append(_predicted_torque(p, prm, td, xm, lt))
        td = _delay(preps, tau_hat, max(td - 2e-3, 0.0), min(td + 2e-3, MAX_DELAY_S))
    prm["Td"] = td
    return _finish(preps, records, prm, xm, xl, names, load, tau_hat, span, stick)


def _physical(xm: np.ndarray, xl: np.ndarray, records: list[FitRecord]) -> dict[str, float]:
    """Jc, bc, K, Jl from the two equations' coefficients, or a refusal naming the parameter."""
    rec = max(records, key=lambda r: r.n * r.T)
    band = f"{rec.f_lo:.3g}-{rec.f_hi:.3g} Hz"
    Jc, beta, Jl, a = float(xm[0]), float(xm[1]), float(xl[0]), float(xl[1])
    if not Jl > 0:
        raise IiwaIdentError(f"Jl: the link's acceleration does not follow the joint torque in the chirp's band "
                             f"{band} (fitted {Jl:.3g} kg m^2); the link may be blocked or the excitation too weak")
    if not a > 0:
        raise IiwaIdentError(f"K: the joint's compliance is not visible in the chirp's band {band} (fitted Jl/K "
                             f"= {a:.3g}): the band must reach the resonance")
    K = Jl / a
    if not Jc > 0:
        raise IiwaIdentError(f"Jc: the motor's acceleration does not follow the torque error in the chirp's band "
                             f"{band} (fitted {Jc:.3g} kg m^2)")
    return {"Jc": Jc, "bc": max(beta, 0.0) * K, "K": K, "Jl": Jl}


def _link_torque(p: Prepared, K: float, xl: np.ndarray, names: list[str], load: str) -> np.ndarray:
    """The estimated friction and load torque on the link over the whole record [Nm]."""
    theta = p.q_w - p.tau_w / K
    omega = p.dq_w - p.dtau_w / K
    c = dict(zip(names, xl))
    out = -c["coulomb"] * np.tanh(omega / FRICTION_SMOOTHING_RAD_S) - c["viscous"] * omega
    if load == "sinusoid":
        out += c["load_a"] * np.sin(theta) + c["load_b"] * np.cos(theta)
    elif load == "gradient":
        out += c["load_gradient"] * (theta - float(np.mean(theta[p.keep])))
    return out


def _finish(preps: list[Prepared], records: list[FitRecord], prm: dict[str, float], xm: np.ndarray, xl: np.ndarray,
            names: list[str], load: str, tau_hat: list | None, span: float, stick: list[np.ndarray] | None) -> IdimResult:
    td = prm["Td"]
    K = prm["K"]
    # Joint sandwich over both equations, Td as an extra motor column (d e / d Td = -(u' + beta u'')).
    ym, Pm, Zm, yl, Pl, Zl, blocks, blocks_l = [], [], [], [], [], [], [], []
    offset = 0
    for i, p in enumerate(preps):
        th = None if tau_hat is None else tau_hat[i]
        y, Phi, Z = motor_rows(p, td, th)
        Ud = p.sp.held_delayed(p.U, td)
        du, ddu = p.sp.back(Ud, 1)[p.keep], p.sp.back(Ud, 2)[p.keep]
        col = -(du + xm[1] * ddu)  # d(model - y)/dTd with the sign of a regressor
        Phi = np.column_stack([Phi, col])
        Z = np.column_stack([Z, col])
        ym.append(y)
        Pm.append(Phi)
        Zm.append(Z)
        y2, P2, Z2, _, k2 = _link_rows(p, K, load, th, None if stick is None else stick[i])
        yl.append(y2)
        Pl.append(P2)
        Zl.append(Z2)
        blocks.append(p.block[p.keep] + offset)
        blocks_l.append(p.block[k2] + offset)
        offset += int(p.block.max()) + 1
    Pm_, Zm_, Pl_, Zl_ = (np.concatenate(v) for v in (Pm, Zm, Pl, Zl))
    em = np.concatenate(ym) - Pm_[:, :-1] @ xm
    el = np.concatenate(yl) - Pl_ @ xl
    b, b_l = np.concatenate(blocks), np.concatenate(blocks_l)
    nm, nl = Pm_.shape[1], Pl_.shape[1]
    A = np.zeros((nm + nl, nm + nl))
    A[:nm, :nm] = Zm_.T @ Pm_
    A[nm:, nm:] = Zl_.T @ Pl_
    scores = np.zeros((offset, nm + nl))
    np.add.at(scores[:, :nm], b, Zm_ * em[:, None])
    np.add.at(scores[:, nm:], b_l, Zl_ * el[:, None])
    S = scores.T @ scores
    Ainv = np.linalg.pinv(A)
    cov = Ainv @ S @ Ainv.T
    # Parameter order in cov: motor (Jc, beta, 5 g_m terms, Td), link (Jl, Jl/K, ...).
    i_jc, i_beta, i_td, i_jl, i_a = 0, 1, nm - 1, nm, nm + 1
    Jl = prm["Jl"]
    a, beta = Jl / K, prm["bc"] / K
    grads = {
        "Jc": {i_jc: 1.0},
        "Jl": {i_jl: 1.0},
        "K": {i_jl: 1.0 / a, i_a: -Jl / a**2},
        "bc": {i_beta: K, i_jl: beta / a, i_a: -beta * Jl / a**2},
        "Td": {i_td: 1.0},
    }
    std = {}
    for name in PARAMETER_NAMES:
        g = np.zeros(nm + nl)
        for j, v in grads[name].items():
            g[j] = v
        std[name] = float(math.sqrt(max(g @ cov @ g, 0.0)))
    cl = {nme: (float(xl[j]), float(math.sqrt(max(cov[nm + j, nm + j], 0.0)))) for j, nme in enumerate(names)}
    effects = _effects(cl, xm, cov, nm, load, span)
    if preps[0].ripple is not None:
        effects.append(_ripple_effect(preps[0].ripple[0], xl, names, cov[nm:, nm:], Jl))
    # Only what the data show goes on as a known torque: an effect within its noise would carry that
    # noise into the output-error fit (and triple its cost) for nothing.
    shown = {e.name for e in effects if e.significant}
    xl_known = np.array([0.0 if _EFFECT_OF.get(nme, nme) not in shown else v for nme, v in zip(names, xl)])
    # The robot's model compensates a load the link feels: without a load on the link, sin/cos terms in
    # the motor equation are its own approximation error (on a clean joint they moved the output-error
    # fit's Jl by 185 std).
    gravity_model = "position_dependent_load" in shown and any(
        abs(xm[j]) > 3.0 * math.sqrt(max(cov[j, j], 0.0)) for j in (2, 3))
    known = []
    for p in preps:
        inputs = []
        if np.any(xl_known):
            inputs.append(("link", _sample_mean(_link_torque(p, K, xl_known, names, load))))
        if gravity_model:  # the robot subtracts its gravity model
            inputs.append(("motor", _sample_mean(-_gravity_model(xm, p.q_w))))
        known.append(inputs)
    return IdimResult(parameters={k: float(prm[k]) for k in PARAMETER_NAMES}, std=std, effects=effects,
                      residual_rms={"motor_nm": float(np.sqrt(np.mean(em**2))), "link_nm": float(np.sqrt(np.mean(el**2)))},
                      labels=[r.label for r in records], known_inputs=known)


def _ripple_effect(period: float, xl: np.ndarray, names: list[str], cov: np.ndarray, Jl: float) -> LinkEffectEstimate:
    """The fitted ripple in :class:`~iiwa_ident.sim.TransmissionRipple`'s terms.

    ``cov``: the link equation's covariance. Harmonic ``k`` has the amplitude ``A_k`` [rad] and phase
    ``phi_k`` [rad] of ``A_k sin(2 pi k q_m / rho + phi_k)``; the link equation's coefficients are ``Jl``
    times its cosine and sine coefficients (their std is for this period). Kept (significant) when the
    coefficients' Wald statistic exceeds :data:`RIPPLE_CHI2`.

    The period has no std: a chirp around a held position travels over a few periods only, and then
    another period (twice, half, or one a few resolution cells away) may explain the residual almost as
    well. Measured on the 75 draws of the robustness benchmark with the ripple: 12 of the 70 periods
    found were off by more than 2 %, by 20-2600 times a local (curvature) std; every one of those fits
    still met the parameters' targets. The period is that of the columns that explain the chirp best,
    not an identification of ``rho``.
    """
    idx = [j for j, n in enumerate(names) if n.startswith("ripple_")]
    x = xl[idx]
    C = cov[np.ix_(idx, idx)]
    try:
        wald = float(x @ np.linalg.solve(C, x))
    except np.linalg.LinAlgError:
        wald = 0.0
    values = {"period_rad": period}
    std = {"period_rad": math.nan}
    for k in range(len(idx) // 2):
        a, b = x[2 * k] / Jl, x[2 * k + 1] / Jl
        sa, sb = (math.sqrt(max(C[j, j], 0.0)) / Jl for j in (2 * k, 2 * k + 1))
        amp = math.hypot(a, b)
        values[f"amplitude{k + 1}_rad"] = amp
        values[f"phase{k + 1}_rad"] = math.atan2(a, b)
        std[f"amplitude{k + 1}_rad"] = math.sqrt((a * sa) ** 2 + (b * sb) ** 2) / amp if amp > 0 else math.hypot(sa, sb)
        std[f"phase{k + 1}_rad"] = math.sqrt((b * sa) ** 2 + (a * sb) ** 2) / amp**2 if amp > 0 else math.pi
    return LinkEffectEstimate("transmission_ripple", values, std, significant=wald > RIPPLE_CHI2,
                              note=f"fitted so that it does not bias the joint's parameters (Wald statistic "
                                   f"{wald:.3g}); the period is the one that explains the chirps best, not an "
                                   "identification of rho (a chirp travels over few periods): identify rho and "
                                   "the table with the ripple command, from runs at constant speed")


#: The effect each link-equation coefficient belongs to.
_EFFECT_OF = {"coulomb": "link_friction", "viscous": "link_friction", "load_a": "position_dependent_load",
              "load_b": "position_dependent_load", "load_gradient": "position_dependent_load"}


def _sample_mean(x: np.ndarray) -> np.ndarray:
    """Mean of a smooth signal over each sample interval (trapezoid), the last one held."""
    out = x.copy()
    out[:-1] = 0.5 * (x[:-1] + x[1:])
    return out


def _effects(cl: dict[str, tuple[float, float]], xm: np.ndarray, cov: np.ndarray, nm: int, load: str,
             span: float) -> list[LinkEffectEstimate]:
    out = []
    fc, sfc = cl["coulomb"]
    fv, sfv = cl["viscous"]
    out.append(LinkEffectEstimate(
        "link_friction", {"coulomb_nm": fc, "viscous_nms_rad": fv, "smoothing_rad_s": FRICTION_SMOOTHING_RAD_S},
        {"coulomb_nm": sfc, "viscous_nms_rad": sfv, "smoothing_rad_s": 0.0},
        significant=abs(fc) > 3 * sfc or abs(fv) > 3 * sfv))
    off, soff = cl["offset"]
    out.append(LinkEffectEstimate("torque_sensor_offset", {"offset_nm": off}, {"offset_nm": soff},
                                  significant=abs(off) > 3 * soff,
                                  note="includes the negative of any constant link load: on the link the two are "
                                       "one term"))
    if load == "sinusoid":
        (la, sa), (lb, sb) = cl["load_a"], cl["load_b"]
        amp = math.hypot(la, lb)
        phase = math.atan2(lb, la)
        s_amp = math.sqrt((la * sa) ** 2 + (lb * sb) ** 2) / amp if amp > 0 else math.hypot(sa, sb)
        s_ph = math.sqrt((lb * sa) ** 2 + (la * sb) ** 2) / amp**2 if amp > 0 else math.pi
        # The robot's model: the motor equation's sin/cos coefficients over the link's.
        ma, mb = float(xm[2]), float(xm[3])
        comp = (ma * la + mb * lb) / amp**2 if amp > 0 else 0.0
        out.append(LinkEffectEstimate(
            "position_dependent_load", {"amplitude_nm": amp, "phase_rad": phase, "compensated": comp},
            {"amplitude_nm": s_amp, "phase_rad": s_ph, "compensated": math.nan},
            significant=amp > 3 * s_amp))
    else:
        g, sg = cl["load_gradient"]
        out.append(LinkEffectEstimate(
            "position_dependent_load", {"gradient_nm_rad": g}, {"gradient_nm_rad": sg}, significant=abs(g) > 3 * sg,
            note=f"the link moved over {span:.2g} rad only (amplitude and phase need {LOAD_MIN_RANGE_RAD:g} rad): "
                 "the load's local gradient is fitted instead"))
    return out
