"""The joint fit's data: one dataset prepared as a record (command, outputs, band, drift basis, noise blocks).

Both estimators of the joint model read their data through here: the
output-error fit (:mod:`iiwa_ident.ident._tf_fit`) and the instrumental-variable
inverse dynamics (:mod:`iiwa_ident.ident._idim`). A record is refused, in one
line naming the dataset, when it has no torque command, is too short, too
little excited, sampled too slowly for its sweep or has lost too many robot
cycles (a few lost FRI cycles are filled: the robot held the command).

Where the robot held the motor because torque and speed were small (section
II.A: torque control is suppressed when starting from zero velocity below
1 Nm; a chirp meets it where the motor stands almost still, at the
antiresonance), no linear model follows the joint: a record keeps those
windows (:func:`held_windows`) so the fit can leave them out.

The transmission ripple's inputs are functions of the motion between the
samples (:class:`Motion`): there the motor's speed jumps wherever a new
command arrives (eq (1): the loop's damping passes the command straight to
the speed), so the motion is smooth only piecewise and a cubic through the
samples misplaces it; with the delay a whole number of samples every jump
falls on a sample and the error follows the command's steps, which the fit
took for ``Td`` (-100 ns at 5 ms on the default joint without noise).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse
from numpy.lib.stride_tricks import sliding_window_view
from scipy.interpolate import BSpline, CubicSpline

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import _frf
from iiwa_ident.model import ParameterSource, discretize, sample_means, sample_slopes

__all__ = ["MIN_DURATION_S", "MIN_COMMAND_STD_NM", "BLOCK_S", "MAX_LOST_SHARE", "MAX_LOST_RUN", "FitRecord",
           "prepare_record", "prepare_records", "check_joints", "fill_lost_cycles", "record_label", "spline_basis",
           "STANDSTILL_TORQUE_NM", "HELD_SPEED_RAD_S", "HELD_MARGIN", "MAX_HELD_SHARE", "held_windows",
           "held_share", "MOTION_SUBSTEPS", "Motion", "SampledInputs", "MotionSignals", "record_motion"]

#: Shortest record the fit accepts [s].
MIN_DURATION_S = 2.0
#: Least variation of the torque command the fit accepts (std after removing the mean) [Nm].
MIN_COMMAND_STD_NM = 0.5
#: Length of the blocks with their own noise level [s].
BLOCK_S = 0.25
#: Torque below which the robot suppresses torque control from standstill (section II.A) [Nm].
STANDSTILL_TORQUE_NM = 1.0
#: Motor speed below which a sample counts as held [rad/s]: a tenth of what the simulated robot calls
#: standing, so a motor passing slowly through zero speed is not taken for held.
HELD_SPEED_RAD_S = 2e-4
#: Samples left out on either side of a held stretch: the switch falls between samples [samples].
HELD_MARGIN = 3
#: Longest command delay looked back over for the held command [s] (the fit's bound on ``Td``).
HELD_LOOKBACK_S = 0.05
#: Largest share of a record the robot may have held the motor and the record still be fitted [-].
MAX_HELD_SHARE = 0.5


#: Points per sample at which :class:`Motion` resolves the motion between samples [-] (even: Simpson's rule).
MOTION_SUBSTEPS = 8

#: Deflection [rad] and reaction [Nm] columns of the motion ``(q_m [rad], tau_j [Nm])`` at any points:
#: ``signals(q_m, tau_j) -> (deflection (points, m), reaction (points, m))``.
MotionSignals = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Motion:
    """The motor position and the carried joint torque between a record's samples.

    Attributes
    ----------
    q : numpy.ndarray
        ``q_m`` [rad] (absolute) at ``k T + j T / substeps`` from the first sample to the last.
    tau : numpy.ndarray
        The joint torque the transmission carries [Nm], at the same points.
    substeps : int
        Points per sample.
    """

    q: np.ndarray
    tau: np.ndarray
    substeps: int


@dataclass(frozen=True, kw_only=True)
class SampledInputs:
    """Deflection [rad] and reaction [Nm] columns as a model sampled ``substeps`` times per sample sees them:
    values at its points, means and slopes over its intervals (:class:`~iiwa_ident.model.DiscreteModel`),
    shape ``(n * substeps, columns)`` each (Fortran order: one column through many parameter sets)."""

    D: np.ndarray
    RX: np.ndarray
    D_means: np.ndarray
    RX_means: np.ndarray
    D_slopes: np.ndarray
    RX_slopes: np.ndarray
    substeps: int

    @classmethod
    def of(cls, parts: Sequence[np.ndarray], substeps: int) -> SampledInputs:
        """From ``(D, D_means, D_slopes, RX, RX_means, RX_slopes)``, each in Fortran order."""
        D, D_means, D_slopes, RX, RX_means, RX_slopes = map(np.asfortranarray, parts)
        return cls(D=D, RX=RX, D_means=D_means, RX_means=RX_means, D_slopes=D_slopes, RX_slopes=RX_slopes,
                   substeps=substeps)


def record_motion(u: np.ndarray, q: np.ndarray, tau: np.ndarray, T: float, params: ParameterSource) -> Motion:
    """The motion between samples: the command's modelled response at ``params`` (its speed jumps exact,
    :func:`~iiwa_ident.model.discretize` at ``T / MOTION_SUBSTEPS``) plus a cubic through what it leaves at
    the samples (smooth: the response to the ripple, the link's torques, the drift).

    Parameters
    ----------
    u : numpy.ndarray
        The torque command [Nm], one per sample.
    q : numpy.ndarray
        ``q_m`` [rad] at the samples (absolute).
    tau : numpy.ndarray
        The carried joint torque [Nm] at the samples.
    T : float
        Sample time [s].
    params : JointParameters, mapping or sequence
        ``Jc, bc, K, Jl`` [SI], ``Td`` [s]: an estimate (the jumps are a small correction; their size and
        place need no more than the estimate's accuracy).

    Examples
    --------
    >>> params = (1.0, 50.0, 1e4, 4.0, 0.002)
    >>> u = np.r_[np.zeros(10), np.ones(40)]
    >>> from iiwa_ident.model import simulate_outputs
    >>> tau, q = simulate_outputs(params, u, 1e-3)
    >>> fine = simulate_outputs(params, np.repeat(u, 8), 1e-3 / 8)
    >>> m = record_motion(u, q, tau, 1e-3, params)
    >>> bool(np.allclose(m.q, fine[1][:len(m.q)], atol=1e-15) and np.allclose(m.tau, fine[0][:len(m.q)]))
    True
    """
    M = MOTION_SUBSTEPS
    n = len(u)
    points = (n - 1) * M + 1
    with np.errstate(all="ignore"):
        y = discretize(params, T / M).simulate(np.repeat(np.asarray(u, float), M))[:, :points]
    if not np.all(np.isfinite(y)):
        y = np.zeros((2, points))
    k = np.arange(n)
    fine = np.arange(points) / M
    q_rest = CubicSpline(k, q - q[0] - y[1, ::M])(fine)
    tau_rest = CubicSpline(k, tau - y[0, ::M])(fine)
    return Motion(q=q[0] + y[1] + q_rest, tau=y[0] + tau_rest, substeps=M)


def _simpson(G: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and slope (``12 int_0^1 (s - 1/2) G ds``) of ``G`` (rows at equal spacing) over each run of
    ``step`` intervals (``step`` even), by Simpson's rule."""
    count = (G.shape[0] - 1) // step
    w = np.ones(step + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    w /= 3.0 * step
    lever = 12.0 * (np.arange(step + 1) / step - 0.5)
    means = np.zeros((count,) + G.shape[1:])
    slopes = np.zeros_like(means)
    for j, wj in enumerate(w):
        part = wj * G[j:j + count * step:step]
        means += part
        slopes += lever[j] * part
    return means, slopes


class _Fine(NamedTuple):
    """A signal at ``substeps`` points per sample, with its means and slopes between them."""

    values: np.ndarray
    means: np.ndarray
    slopes: np.ndarray


def _sampled(G: np.ndarray, n: int, M: int, substeps: int) -> _Fine:
    """Values at ``substeps`` points per sample and the means and slopes between them from ``G`` at ``M``
    points per sample; past the last sample the last value, no slope (it reaches no output in the record)."""
    step = M // substeps
    vals = G[::step]
    means, slopes = _simpson(G, step)
    rows = n * substeps
    last = np.repeat(vals[-1:], rows - len(means), axis=0)
    return _Fine(np.concatenate([vals, last[:rows - len(vals)]]), np.concatenate([means, last]),
                 np.concatenate([slopes, np.zeros_like(last)]))


def _fine_signal(signal: np.ndarray, substeps: int) -> _Fine:
    """A signal known at the samples only, ``substeps`` times finer (cubic), and its
    :func:`~iiwa_ident.model.sample_means` and :func:`~iiwa_ident.model.sample_slopes` there."""
    n = signal.shape[0]
    fine = signal if substeps == 1 else CubicSpline(np.arange(n), signal, axis=0)(np.arange(n * substeps) / substeps)
    return _Fine(fine, sample_means(fine), sample_slopes(fine))


@dataclass(kw_only=True)
class FitRecord:
    """One dataset prepared for the joint fit (:func:`prepare_record`)."""

    label: str
    T: float
    u: np.ndarray
    tau: np.ndarray
    q: np.ndarray
    f_lo: float
    f_hi: float
    sweep: dict | None
    drift_basis: Any  # scipy.sparse matrix (n, n_knots + 2)
    block: np.ndarray
    n_blocks: int
    joint: int
    spectra: list[_frf.CrossSpectra] | None = None
    filled_cycles: int = 0
    q0: float = 0.0  # the motor position at the first sample [rad] (``q`` starts at 0)
    #: Known torques besides the command, as ``(input, signal [Nm])`` (see :data:`INPUTS`): the link-side
    #: effects and the robot's gravity model, estimated beforehand from the measured motion.
    known: list[tuple[str, np.ndarray]] = field(default_factory=list)
    #: The ripple's Fourier basis as ``(deflection [rad], reaction [Nm])`` pairs, one per coefficient; their
    #: coefficients are fitted with the parameters (projected out of the residual), see :class:`RippleTerms`.
    ripple_basis: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    #: The ripple basis' columns as functions of the motion (their first-sample deflection not taken off).
    ripple_signals: MotionSignals | None = None
    #: The ripple's lookup table as a known input (one column each), a function of the motion as above.
    table_signals: MotionSignals | None = None
    #: The motion between samples (:func:`record_motion`), once the fit has an estimate; before, the
    #: ripple's inputs are interpolated from their samples.
    motion: Motion | None = None
    #: The torque the transmission carries where the log's filter changed it (undone) [Nm]; else ``tau``.
    tau_carried: np.ndarray | None = None
    _inputs: dict[tuple[str, int], SampledInputs] = field(default_factory=dict, init=False, repr=False)
    #: Sample ranges ``[start, stop)`` where the robot held the motor (:func:`held_windows`), margins
    #: included: the fit gives them no weight and restarts its model's state after each.
    held: list[tuple[int, int]] = field(default_factory=list)

    @property
    def mask(self) -> np.ndarray:
        """1 where the record counts, 0 in its :attr:`held` windows."""
        m = np.ones(self.n)
        for a, b in self.held:
            m[a:b] = 0.0
        return m

    @property
    def n(self) -> int:
        return self.u.shape[0]

    @property
    def fits_inputs(self) -> bool:
        """Whether the record has an :attr:`input_basis` (a ripple or a hold)."""
        return bool(self.ripple_basis or self.held)

    @property
    def input_basis(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The inputs whose coefficients the fit estimates alongside the parameters, as ``(deflection [rad],
        reaction [Nm])`` pairs: the :attr:`ripple_basis`, then three per :attr:`held` window that restart the
        model's state where the robot let go of the motor (a deflection step moves the link, a deflection
        ramp its speed, a reaction pulse the torque loop's integral; the position step is in the drift
        basis)."""
        out = list(self.ripple_basis)
        k = np.arange(self.n)
        zero = np.zeros(self.n)
        for _, b in self.held:
            free = b - HELD_MARGIN  # the first sample after the hold
            after = (k >= free).astype(float)
            out += [(after, zero), ((k - free) * self.T * after, zero), (zero, (k == free).astype(float))]
        return out

    def restore_motion(self, motion: Motion | None) -> None:
        """Put back a motion :meth:`set_motion` replaced."""
        self.motion = motion
        self._inputs.clear()

    @property
    def carried(self) -> np.ndarray:
        """The torque the transmission carries [Nm] (:attr:`tau_carried`, else ``tau``)."""
        return self.tau if self.tau_carried is None else self.tau_carried

    def set_ripple(self, signals: MotionSignals | None, table: MotionSignals | None = None) -> None:
        """The ripple's basis (and table) as functions of the motion; the basis' samples kept in
        :attr:`ripple_basis`."""
        self.ripple_signals, self.table_signals = signals, table
        self.ripple_basis = []
        if signals is not None:
            D, RX = signals(self.q + self.q0, self.carried)
            D = D - D[:1]
            self.ripple_basis = [(D[:, j], RX[:, j]) for j in range(D.shape[1])]
        self._inputs.clear()

    def set_motion(self, params: ParameterSource, q: np.ndarray | None = None, tau: np.ndarray | None = None) -> None:
        """Resolve the motion between samples from the command's response at ``params``
        (:func:`record_motion`), through ``q`` [rad] (absolute) and the carried ``tau`` [Nm] at the samples
        (default: the measured ones)."""
        self.motion = record_motion(self.u, self.q + self.q0 if q is None else q,
                                    self.carried if tau is None else tau, self.T, params)
        self._inputs.clear()

    def ripple_inputs(self, substeps: int = 1) -> SampledInputs:
        """The :attr:`input_basis` as a model ``substeps`` times finer than the samples sees it, built once:
        the ripple's columns from the :attr:`motion` where it is known, the holds' restarts (and the ripple
        before) interpolated from their samples."""
        key = ("basis", substeps)
        if key not in self._inputs:
            basis = self.input_basis
            D, D_means, D_slopes = _fine_signal(np.column_stack([d for d, _ in basis]), substeps)
            RX, RX_means, RX_slopes = _fine_signal(np.column_stack([rx for _, rx in basis]), substeps)
            if self.motion is not None and self.ripple_signals is not None:
                m = len(self.ripple_basis)
                parts = self._from_motion(self.ripple_signals, substeps)
                for whole, part in zip((D, D_means, D_slopes, RX, RX_means, RX_slopes), parts):
                    whole[:, :m] = part
            self._inputs[key] = SampledInputs.of((D, D_means, D_slopes, RX, RX_means, RX_slopes), substeps)
        return self._inputs[key]

    def table_inputs(self, substeps: int = 1) -> SampledInputs | None:
        """The ripple table's deflection and reaction (one column each) as :meth:`ripple_inputs`; None
        without a table."""
        if self.table_signals is None:
            return None
        key = ("table", substeps)
        if key not in self._inputs:
            if self.motion is not None:
                parts = self._from_motion(self.table_signals, substeps)
            else:
                D, RX = self.table_signals(self.q + self.q0, self.carried)
                parts = (*_fine_signal(D - D[:1], substeps), *_fine_signal(RX, substeps))
            self._inputs[key] = SampledInputs.of(parts, substeps)
        return self._inputs[key]

    def _from_motion(self, signals: MotionSignals, substeps: int) -> tuple[np.ndarray, ...]:
        """``signals`` over the :attr:`motion`: deflection values, means and slopes (less the first sample's
        deflection: the record starts at rest, the link there), then the reaction's."""
        motion = self.motion
        assert motion is not None
        D, RX = signals(motion.q, motion.tau)
        return (*_sampled(D - D[:1], self.n, motion.substeps, substeps),
                *_sampled(RX, self.n, motion.substeps, substeps))


def held_windows(q_m: np.ndarray, tau_c: np.ndarray, tau_j: np.ndarray, T: float) -> list[tuple[int, int]]:
    """Sample ranges ``[start, stop)`` where the robot held the motor, :data:`HELD_MARGIN` added each side.

    Held: the motor moved slower than :data:`HELD_SPEED_RAD_S` while the joint torque and the command at
    some moment of the last :data:`HELD_LOOKBACK_S` (the command acts after the delay) were below
    :data:`STANDSTILL_TORQUE_NM`, for at least two samples in a row.

    Examples
    --------
    >>> q = np.r_[np.linspace(0, 1e-3, 50), np.full(5, 1e-3), np.linspace(1e-3, 2e-3, 50)]
    >>> held_windows(q, np.zeros(105), np.zeros(105), 1e-3)
    [(46, 59)]
    """
    n = len(q_m)
    if n < 3:
        return []
    held = _held_steps(q_m, tau_c, tau_j, T)
    out: list[tuple[int, int]] = []
    k = 0
    while k < n - 1:
        if not held[k]:
            k += 1
            continue
        j = k
        while j < n - 1 and held[j]:
            j += 1
        if j - k >= 2 and k > 0:  # the record's first samples are the rest before the command
            a, b = max(0, k - HELD_MARGIN), min(n, j + 1 + HELD_MARGIN)
            if out and a <= out[-1][1]:
                a = out.pop()[0]
            out.append((a, b))
        k = j
    return out


def held_share(q_m: np.ndarray, tau_c: np.ndarray, tau_j: np.ndarray, T: float) -> float:
    """Share of the record's steps between samples during which the robot held the motor [-].

    Counted as in :func:`held_windows`, but from the first sample on: a command too weak to ever free
    the motor leaves it held from the rest before the command to the end.
    """
    if len(q_m) < 2:
        return 0.0
    return float(np.mean(_held_steps(q_m, tau_c, tau_j, T)))


def _held_steps(q_m: np.ndarray, tau_c: np.ndarray, tau_j: np.ndarray, T: float) -> np.ndarray:
    """Whether the motor was held between samples k and k + 1 (:func:`held_windows`' criterion)."""
    q_m, tau_c, tau_j = (np.asarray(a, float) for a in (q_m, tau_c, tau_j))
    lag = max(1, int(round(HELD_LOOKBACK_S / T)))
    recent = sliding_window_view(np.concatenate([np.full(lag, np.inf), np.abs(tau_c)]), lag + 1).min(axis=1)
    still = np.abs(np.diff(q_m)) <= HELD_SPEED_RAD_S * T
    small = (np.abs(tau_j) < STANDSTILL_TORQUE_NM) & (recent < STANDSTILL_TORQUE_NM)
    return still & small[:-1] & small[1:]


def record_label(ds: Dataset, index: int) -> str:
    """The dataset's file, or its number where it has none."""
    return str(ds.path) if ds.path is not None else f"dataset {index + 1}"


def spline_basis(n: int, T: float, knot_s: float) -> np.ndarray:
    """Cubic B-spline basis with knots every ``knot_s`` seconds over the record."""
    t = np.arange(n) * T
    span = t[-1]
    n_int = max(1, int(math.ceil(span / knot_s)))
    inner = np.linspace(0.0, span, n_int + 1)
    knots = np.concatenate([[0.0] * 3, inner, [span] * 3])
    return BSpline.design_matrix(t, knots, 3).tocsr()


def prepare_record(ds: Dataset, index: int) -> FitRecord:
    """Dataset number ``index`` (from 0, for its label) as a record; a bad one is refused in one line."""
    label = record_label(ds, index)
    if not ds.has("tau_c"):
        # Say what such a log can give and how to record what the fit needs.
        raise IiwaIdentError(f"{label}: no torque command: fit needs a torque-commanded chirp (record one with "
                             f"'iiwa-ident chirp --target robot --robot HOST --joint N'); a log without one still "
                             f"gives 'ripple', 'diagnose' and 'pipeline --logs'")
    t = np.asarray(ds.t, float)
    if ds.duration_s < MIN_DURATION_S:
        raise IiwaIdentError(f"{label}: too short for a fit ({ds.duration_s:.2f} s; need at least "
                             f"{MIN_DURATION_S:g} s)")
    dt = np.diff(t)
    T = float(np.median(dt))
    u = np.asarray(ds["tau_c"], float)
    tau_j, q = np.asarray(ds["tau_j"], float), np.asarray(ds["q_m"], float)
    filled = 0
    if T <= 0 or np.max(np.abs(dt - T)) > 1e-3 * T:
        u, tau_j, q, filled = fill_lost_cycles(t, T, u, tau_j, q, label)
    spread = float(np.std(u))
    if spread < MIN_COMMAND_STD_NM:
        raise IiwaIdentError(f"{label}: too little excitation: the torque command varies by only {spread:.3g} Nm "
                             f"(std; need at least {MIN_COMMAND_STD_NM:g} Nm)")
    attrs = ds.experiment_attrs
    fs = 1.0 / T
    sweep = None
    keys = ("f0_hz", "f1_hz", "duration_s", "amplitude_nm")
    if attrs.get("sweep") == "exponential" and all(k in attrs for k in keys):
        sweep = {k: float(attrs[k]) for k in keys}
        if sweep["f1_hz"] >= 0.5 * fs:
            # A log decimated below the sweep's Nyquist rate has lost the command between samples.
            raise IiwaIdentError(f"{label}: recorded at {fs:g} Hz, too slow for a sweep up to {sweep['f1_hz']:g} Hz: "
                                 "fit needs the command of every robot cycle")
        f_lo, f_hi = sweep["f0_hz"], min(sweep["f1_hz"], 0.45 * fs)
    else:
        f_lo, f_hi = 4.0 / ds.duration_s, 0.45 * fs
    if not 0 < f_lo < f_hi:
        raise IiwaIdentError(f"{label}: the excitation band {f_lo:g}-{f_hi:g} Hz is empty at {fs:g} Hz sampling")
    knot = min(max(0.25 / f_lo, 0.1), 2.0)  # drift slower than a quarter of the lowest excitation
    n = u.shape[0]
    per_block = max(1, int(round(BLOCK_S / T)))
    block = np.minimum(np.arange(n) // per_block, max(n // per_block - 1, 0))
    share = held_share(q, u, tau_j, T)
    if share > MAX_HELD_SHARE:
        raise IiwaIdentError(f"{label}: the robot held the motor still for {100 * share:.0f} % of the record: command "
                             f"and joint torque stayed below the {STANDSTILL_TORQUE_NM:g} Nm under which it does not "
                             f"move a motor from standstill (section II.A); record again with a larger amplitude or "
                             f"a bias of a few Nm")
    held = held_windows(q, u, tau_j, T)
    drift = spline_basis(n, T, knot)
    if held:
        # After a hold the motor has lost ground for good: a step of the position for each.
        steps = np.column_stack([(np.arange(n) >= b).astype(float) for _, b in held])
        drift = scipy.sparse.hstack([drift, scipy.sparse.csr_matrix(steps)]).tocsr()
    return FitRecord(label=label, T=T, u=u, tau=tau_j, q=q - q[0], f_lo=f_lo, f_hi=f_hi,
                     sweep=sweep, drift_basis=drift, block=block, n_blocks=int(block.max()) + 1,
                     joint=int(ds.joint), filled_cycles=filled, q0=float(q[0]), held=held)


#: Largest share of robot cycles a record may have lost and still be fitted [-].
MAX_LOST_SHARE = 0.01
#: Longest run of lost cycles that is filled [cycles].
MAX_LOST_RUN = 5


class FilledRecord(NamedTuple):
    """A record back on the uniform grid (:func:`fill_lost_cycles`): command, torque, position, cycles filled in."""

    u: np.ndarray
    tau_j: np.ndarray
    q: np.ndarray
    lost: int


def fill_lost_cycles(t: np.ndarray, T: float, u: np.ndarray, tau_j: np.ndarray, q: np.ndarray,
                      label: str) -> FilledRecord:
    """Put a record with a few lost robot cycles (FRI) back on the uniform grid.

    Over FRI a lost or late message leaves a gap of whole cycles in the log while the robot goes on
    with the command it holds. The command is therefore known in the gap (the previous one) and the
    measurements are interpolated linearly; at most :data:`MAX_LOST_SHARE` of the cycles and runs of
    at most :data:`MAX_LOST_RUN` are accepted, so the interpolation stays far below the band fitted.
    """
    steps = np.diff(t) / T
    whole = np.round(steps)
    if T <= 0 or np.any(whole < 1) or np.max(np.abs(steps - whole)) > 0.05:
        raise IiwaIdentError(f"{label}: sample times are not uniform; fit needs one command per sample")
    lost = int(np.sum(whole - 1))
    n = len(t) + lost
    if whole.max() - 1 > MAX_LOST_RUN or lost > MAX_LOST_SHARE * n:
        raise IiwaIdentError(f"{label}: {lost} robot cycles lost ({100 * lost / n:.2g} %, longest run "
                             f"{int(whole.max()) - 1}); fit accepts at most {100 * MAX_LOST_SHARE:g} % in runs of "
                             f"at most {MAX_LOST_RUN}: record again")
    k = np.concatenate([[0], np.cumsum(whole)]).astype(int)
    grid = np.arange(n)
    held = np.searchsorted(k, grid, side="right") - 1  # the last recorded cycle at or before each cycle
    return FilledRecord(u[held], np.interp(grid, k, tau_j), np.interp(grid, k, q), lost)


def check_joints(records: list[FitRecord]) -> None:
    """Refuse records of more than one joint."""
    first = records[0]
    for r in records[1:]:
        if r.joint != first.joint:
            raise IiwaIdentError(f"{r.label}: joint {r.joint}, but {first.label} is joint {first.joint}: "
                                 "fit one joint at a time")


def prepare_records(datasets: Sequence[Dataset]) -> list[FitRecord]:
    """Every dataset prepared (:func:`prepare_record`), all of one joint (:func:`check_joints`)."""
    records = [prepare_record(ds, i) for i, ds in enumerate(datasets)]
    check_joints(records)
    return records
