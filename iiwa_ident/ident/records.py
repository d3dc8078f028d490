"""The joint fit's data: one dataset prepared as a record (command, outputs, band, drift basis, noise blocks).

Both estimators of the joint model read their data through here: the
output-error fit (:mod:`iiwa_ident.ident.tf_fit`) and the instrumental-variable
inverse dynamics (:mod:`iiwa_ident.ident.idim`). A record is refused, in one
line naming the dataset, when it has no torque command, is too short, too
little excited, sampled too slowly for its sweep or has lost too many robot
cycles (a few lost FRI cycles are filled: the robot held the command).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.interpolate import BSpline

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import frf as _frf
from iiwa_ident.model import sample_means

__all__ = ["MIN_DURATION_S", "MIN_COMMAND_STD_NM", "BLOCK_S", "MAX_LOST_SHARE", "MAX_LOST_RUN", "FitRecord",
           "prepare_record", "prepare_records", "check_joints", "fill_lost_cycles", "record_label", "spline_basis"]

#: Shortest record the fit accepts [s].
MIN_DURATION_S = 2.0
#: Least variation of the torque command the fit accepts (std after removing the mean) [Nm].
MIN_COMMAND_STD_NM = 0.5
#: Length of the blocks with their own noise level [s].
BLOCK_S = 0.25


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

    @property
    def n(self) -> int:
        return self.u.shape[0]

    def ripple_inputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The ripple basis as input matrices (n, columns), built once: deflection, reaction and their
        :func:`~iiwa_ident.model.sample_means` (the inputs the sampled model sees, for every parameter set)."""
        if self._ripple_inputs is None:
            D = np.asfortranarray(np.column_stack([d for d, _ in self.ripple_basis]))
            RX = np.asfortranarray(np.column_stack([rx for _, rx in self.ripple_basis]))
            self._ripple_inputs = (D, RX, np.asfortranarray(sample_means(D)), np.asfortranarray(sample_means(RX)))
        return self._ripple_inputs


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
    return FitRecord(label=label, T=T, u=u, tau=tau_j, q=q - q[0], f_lo=f_lo, f_hi=f_hi,
                   sweep=sweep, drift_basis=spline_basis(n, T, knot), block=block, n_blocks=int(block.max()) + 1,
                   joint=int(ds.joint), filled_cycles=filled, q0=float(q[0]))


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
