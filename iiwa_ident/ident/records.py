"""The joint fit's data: one dataset prepared as a record (command, outputs, band, drift basis, noise blocks).

Both estimators of the joint model read their data through here: the
output-error fit (:mod:`iiwa_ident.ident.tf_fit`) and the instrumental-variable
inverse dynamics (:mod:`iiwa_ident.ident.idim`). A record is refused, in one
line naming the dataset, when it has no torque command, is too short, too
little excited, sampled too slowly for its sweep or has lost too many robot
cycles (a few lost FRI cycles are filled: the robot held the command).

Where the robot held the motor because torque and speed were small (section
II.A: torque control is suppressed when starting from zero velocity below
1 Nm; a chirp meets it where the motor stands almost still, at the
antiresonance), no linear model follows the joint: a record keeps those
windows (:func:`held_windows`) so the fit can leave them out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.sparse
from numpy.lib.stride_tricks import sliding_window_view
from scipy.interpolate import BSpline

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import frf as _frf
from iiwa_ident.model import sample_means

__all__ = ["MIN_DURATION_S", "MIN_COMMAND_STD_NM", "BLOCK_S", "MAX_LOST_SHARE", "MAX_LOST_RUN", "FitRecord",
           "prepare_record", "prepare_records", "check_joints", "fill_lost_cycles", "record_label", "spline_basis",
           "STANDSTILL_TORQUE_NM", "HELD_SPEED_RAD_S", "HELD_MARGIN", "MAX_HELD_SHARE", "held_windows",
           "held_share"]

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


@dataclass
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
    _ripple_inputs: tuple[np.ndarray, ...] | None = field(default=None, repr=False)
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

    def ripple_inputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The :attr:`input_basis` as input matrices (n, columns), built once: deflection, reaction and their
        :func:`~iiwa_ident.model.sample_means` (the inputs the sampled model sees, for every parameter set)."""
        if self._ripple_inputs is None:
            basis = self.input_basis
            D = np.asfortranarray(np.column_stack([d for d, _ in basis]))
            RX = np.asfortranarray(np.column_stack([rx for _, rx in basis]))
            self._ripple_inputs = (D, RX, np.asfortranarray(sample_means(D)), np.asfortranarray(sample_means(RX)))
        return self._ripple_inputs


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


def fill_lost_cycles(t: np.ndarray, T: float, u: np.ndarray, tau_j: np.ndarray, q: np.ndarray,
                      label: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
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
    return (u[held], np.interp(grid, k, tau_j), np.interp(grid, k, q), lost)


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
