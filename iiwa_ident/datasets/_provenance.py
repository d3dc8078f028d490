"""What a log says about itself: checks of an imported run against the robot's description.

Each check returns one line for the user, or None; :func:`dataset_warnings` gathers them for ``import`` and
``info``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from iiwa_ident.datasets._format import Dataset, dataset_pose
from iiwa_ident.datasets._import import MIN_RATE_HZ, moving_joint_problem
from iiwa_ident.model import RIPPLE_PERIOD_RAD

__all__ = ["joint_velocity", "torque_sign_problem", "time_gaps_problem", "band_limited_problem", "substituted_position_problem",
           "low_rate_problem", "dataset_warnings", "SIGN_MIN_GRAVITY_NM", "SIGN_MIN_FRICTION_NM", "GAP_FACTOR", "BAND_LIMITED_DB_PER_DECADE",
           "BAND_LIMITED_FLOOR_DB", "IMPORT_WARNINGS_ATTR", "note_warnings"]

#: The experiment attribute where ``import`` keeps what the checks found (one warning per line).
IMPORT_WARNINGS_ATTR = "import_warnings"

#: The gravity torque must change by at least this much over the run to tell the reading's sign [Nm].
SIGN_MIN_GRAVITY_NM = 0.5
#: Where gravity does not decide, the friction the reading shows must be this strong to tell the sign [Nm].
SIGN_MIN_FRICTION_NM = 0.05
#: ... and its coefficient be this many standard errors from zero.
_SIGN_MIN_T = 10.0
_MOVING_RAD_S = 0.02  # samples slower than this are left out (stiction, reversal)
#: A sample period longer than this many times the median one is a gap (samples lost).
GAP_FACTOR = 1.5
#: A torque spectrum whose floor falls faster than this over the top of the band [dB/decade] ...
BAND_LIMITED_DB_PER_DECADE = -15.0
#: ... down to below this level at its top [dB re 1 Nm^2/Hz] was filtered before it was logged: a sensor's
#: own noise is flat there (the simulated joint's: about -60 dB at 1 kHz), a first-order low-pass far below
#: the band falls by 20 dB/decade; signals rich in fast motion fall too, but stay far above this level.
BAND_LIMITED_FLOOR_DB = -80.0
#: The top of the band the slope is measured over, as fractions of the Nyquist frequency.
_TOP_BAND = (0.5, 0.95)
_FLOOR_BANDS = 6


def joint_velocity(dataset: Dataset) -> np.ndarray:
    """The joint's velocity [rad/s] from ``q_m`` by central differences over about 40 ms (the encoder's steps
    average out), one value per sample, 0 within 20 ms of either end."""
    q, t = np.asarray(dataset["q_m"], float), np.asarray(dataset.t, float)
    k = max(1, int(round(0.02 * dataset.sample_rate_hz)))
    w = np.zeros_like(q)
    if len(q) > 2 * k:
        w[k:-k] = (q[2 * k:] - q[:-2 * k]) / (t[2 * k:] - t[:-2 * k])
    return w


def torque_sign_problem(dataset: Dataset) -> str | None:
    """A warning when the torque reading's sign is opposite to the toolkit's convention, or None.

    The convention: ``tau_j`` is the torque the joint exerts on its link, so holding the link against
    gravity reads as the description's gravity torque ``g(q)``, and moving it against friction reads with
    the sign of its velocity (the joint does positive work on the link). Over the run, ``tau_j`` is
    regressed on ``g(q_j)`` at the dataset's pose (:mod:`iiwa_ident.description`), a friction
    ``tanh(omega / 0.01)``, a viscous term and a constant, on the samples where the joint moves.

    Gravity decides first: a coefficient of ``g`` near -1 (below -0.5, at least 10 standard errors from
    zero) is a reading of the other sign (the real iiwa 14 logs of Drake's driver read -0.94 to -1.29 on
    joints 2, 4 and 6). Where gravity does not change by :data:`SIGN_MIN_GRAVITY_NM` over the run (a
    vertical axis), friction decides: its mean over the moving samples, signed with the motion, below
    -:data:`SIGN_MIN_FRICTION_NM` at 10 standard errors is a reading of the other sign (the same logs' joints
    1 and 3 read -1.0 and -0.14 Nm). Datasets without robot and pose decide by friction alone; a hand-guided run
    not at all by friction (the hand moves the link, against the joint as much as with it: the simulated joint's
    hand-guided run read -0.30 Nm with the convention's sign).
    """
    if not dataset.has("q_m") or not dataset.has("tau_j"):
        return None
    q = np.asarray(dataset["q_m"], float)
    if len(q) < 10:
        return None
    robot, pose = dataset_pose(dataset)
    g = np.zeros_like(q)
    if pose is not None:
        from iiwa_ident.description import ROBOTS, gravity_sinusoid

        if (robot or "iiwa14") in ROBOTS:
            amp, phase = gravity_sinusoid(robot or "iiwa14", dataset.joint, pose)
            g = amp * np.sin(q + phase)
    w = joint_velocity(dataset)
    moving = np.abs(w) > _MOVING_RAD_S
    if moving.sum() < 10:
        return None
    by_gravity = np.ptp(g) >= SIGN_MIN_GRAVITY_NM
    if not by_gravity and dataset.experiment == "hand_guided":
        return None
    cols = ([g] if by_gravity else []) + [np.tanh(w / 0.01), w, np.ones_like(q)]
    X = np.column_stack(cols)[moving]
    y = np.asarray(dataset["tau_j"], float)[moving]
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    try:
        cov = float(r @ r) / max(len(y) - X.shape[1], 1) * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return None
    if by_gravity:
        a, se = float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0)))
        if a < -0.5 and abs(a) >= _SIGN_MIN_T * se:
            return (f"tau_j reads the other way round: it follows the description's gravity torque with the factor "
                    f"{a:.2f} (the convention: the torque the joint exerts on its link, +1); import the log with "
                    "--scale tau_j=-1")
        return None
    # The friction's mean over the moving samples, signed with the motion: a linear combination of the
    # Coulomb and viscous coefficients, with its standard error.
    wm = w[moving]
    c = np.array([np.mean(np.tanh(wm / 0.01) * np.sign(wm)), np.mean(np.abs(wm)), 0.0])
    f, se = float(c @ coef), float(np.sqrt(max(c @ cov @ c, 0.0)))
    if f < -SIGN_MIN_FRICTION_NM and abs(f) >= _SIGN_MIN_T * se:
        return (f"tau_j reads the other way round: the friction it shows pushes the link along its motion "
                f"({f:.2f} Nm on average; the convention: the torque the joint exerts on its link, which moves it "
                "against friction); import the log with --scale tau_j=-1")
    return None


def time_gaps_problem(dataset: Dataset) -> str | None:
    """A warning when samples were lost: sample periods longer than :data:`GAP_FACTOR` times the median one
    (their number, the longest, and the share of the run's time they cover), or None."""
    t = np.asarray(dataset.t, float)
    if len(t) < 3:
        return None
    dt = np.diff(t)
    period = float(np.median(dt))
    gaps = dt[dt > GAP_FACTOR * period]
    if not gaps.size:
        return None
    lost = float(np.sum(gaps - period))
    return (f"time has {gaps.size} gap{'s' if gaps.size > 1 else ''} (longest {1e3 * gaps.max():.1f} ms against a "
            f"{1e3 * period:.3g} ms period; {100 * lost / (t[-1] - t[0]):.2g} % of the run's time): samples were "
            "lost; the analyses take the samples as they are, across each gap")


class _BandFloor(NamedTuple):
    """The spectrum's floor over the top of the band: a line in log-log."""

    slope_db_decade: float
    level_lo_db: float  #: at the band's lower end
    level_hi_db: float  #: at its upper end


def _top_band_slope(x: np.ndarray, fs: float) -> _BandFloor | None:
    """The floor of the spectrum over the top of the band: its slope [dB/decade] and its level at the band's
    two ends [dB]. The floor of each of :data:`_FLOOR_BANDS` sub-bands is the lower quartile of the Welch
    spectrum there (lines of the motion, a ripple's harmonics, stand above it); a line through the floors in
    log-log over :data:`_TOP_BAND`."""
    from scipy import signal

    nper = min(1024, len(x) // 8)
    if nper < 64:
        return None
    f, p = signal.welch(signal.detrend(x), fs=fs, nperseg=nper)
    edges = np.geomspace(_TOP_BAND[0], _TOP_BAND[1], _FLOOR_BANDS + 1) * fs / 2
    centres, floors = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (f >= a) & (f < b) & (p > 0)
        if sel.sum() < 3:
            return None
        centres.append(np.sqrt(a * b))
        floors.append(10 * np.log10(np.percentile(p[sel], 25)))
    lf = np.log10(centres)
    slope, icpt = np.polyfit(lf, floors, 1)
    return _BandFloor(float(slope), float(icpt + slope * lf[0]), float(icpt + slope * lf[-1]))


def band_limited_problem(dataset: Dataset) -> str | None:
    """A warning when ``tau_j`` was low-pass filtered before it was logged, or None.

    A torque sensor's own noise is flat at the top of the band; a driver's filter (a first-order low-pass
    below the band falls by 20 dB/decade, steeper ones more) makes the spectrum fall there. The slope of
    the Welch spectrum over 0.4-0.95 of the Nyquist frequency below :data:`BAND_LIMITED_DB_PER_DECADE` names
    it when the floor ends below :data:`BAND_LIMITED_FLOOR_DB` (motion content falls too, but above that):
    such a torque lags the motion, and the torque loop's response above the filter's corner cannot be fitted
    from it. The real iiwa 14 logs of Drake's driver at 200 Hz fall by 80-130 dB/decade to -108 to -137 dB.
    """
    if not dataset.has("tau_j"):
        return None
    fs = float(dataset.sample_rate_hz)
    got = _top_band_slope(np.asarray(dataset["tau_j"], float), fs)
    if got is None or got[0] >= BAND_LIMITED_DB_PER_DECADE or got[2] >= BAND_LIMITED_FLOOR_DB:
        return None
    slope, lo, hi = got
    ny = fs / 2
    return (f"tau_j looks low-pass filtered before it was logged: its spectrum's floor falls by {lo - hi:.0f} dB "
            f"from {_TOP_BAND[0] * ny:.0f} to {_TOP_BAND[1] * ny:.0f} Hz ({slope:.0f} dB/decade, to {hi:.0f} dB re "
            "1 Nm^2/Hz; a sensor's noise is flat there): the torque lags the motion, and the torque loop's response cannot be fitted above the "
            "filter's corner (record without the driver's torque filter)")


#: Measured and commanded positions closer than this everywhere are one signal [rad].
_SAME_RAD = 1e-9


def substituted_position_problem(dataset: Dataset) -> str | None:
    """A warning when the measured position ``q_m`` is the commanded one ``q_cmd`` sample for sample (a
    driver that substitutes the command for the measurement), or None."""
    if not (dataset.has("q_m") and dataset.has("q_cmd")):
        return None
    q, c = np.asarray(dataset["q_m"], float), np.asarray(dataset["q_cmd"], float)
    if np.ptp(q) == 0.0 or np.max(np.abs(q - c)) > _SAME_RAD:
        return None
    return ("q_m equals q_cmd at every sample: the driver logged the commanded position as the measured one "
            "(an open-loop or simulated mode?); the joint's deflection, the ripple and the link motion cannot be "
            "identified from it")


def low_rate_problem(dataset: Dataset) -> str | None:
    """A warning when the run was sampled below the robot's cycle (a message log published at 100-200 Hz, say):
    what such data can and cannot give, or None at 200 Hz and above."""
    fs = float(dataset.sample_rate_hz)
    if fs >= MIN_RATE_HZ:
        return None
    nyquist = fs / 2
    return (f"sampled at {fs:.4g} Hz, below the robot's 1 kHz cycle: nothing above {nyquist:.3g} Hz is seen "
            f"(fit needs the command of every robot cycle and refuses the run; a ripple of the paper's period is "
            f"seen at joint speeds up to {nyquist * RIPPLE_PERIOD_RAD:.2g} rad/s; the torque loop's resonance "
            "is not; whether a driver low-passed the torque, as lbr_fri_ros2_stack can, cannot be told at this "
            "rate); record the robot's cycle where the recorder allows it")


def dataset_warnings(dataset: Dataset) -> list[str]:
    """Every check's warning for ``dataset``: sampled below the robot's cycle, the joint given did not move,
    the torque's sign, samples lost,
    a torque filtered before it was logged, a measured position that is the commanded one."""
    checks = (low_rate_problem, moving_joint_problem, torque_sign_problem, time_gaps_problem, band_limited_problem,
              substituted_position_problem)
    return [w for w in (check(dataset) for check in checks) if w]


def note_warnings(dataset: Dataset) -> list[str]:
    """Run every check on ``dataset``, keep the warnings in its attributes (:data:`IMPORT_WARNINGS_ATTR`, one
    per line; removed when there are none) and return them."""
    found = dataset_warnings(dataset)
    if found:
        dataset.experiment_attrs[IMPORT_WARNINGS_ATTR] = "\n".join(found)
    else:
        dataset.experiment_attrs.pop(IMPORT_WARNINGS_ATTR, None)
    return found
