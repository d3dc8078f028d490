"""Safety checks a design must pass before it is exported as a controller config.

:func:`check_design` returns one :class:`Check` per criterion, each with its
value, threshold and verdict, so that a refusal and the ``--json`` report
can show all of them. The thresholds and why they were chosen:

``finite``
    Every number of the design (model, matrices, gains, pre-filter, filter
    settings, ripple table, observer gain) is finite. Threshold: 0 bad entries.
``sample_time``
    The design's cycle equals the FRI send period, 1 ms; the discrete
    matrices are only valid at the cycle they were computed for.
``closed_loop_spectral_radius``
    Spectral radius of the complete 1 kHz loop (controller, observer,
    reference model and pre-filter on the Padé design model), recomputed from
    the stored matrices rather than trusting the stored poles. Threshold
    :data:`MAX_SPECTRAL_RADIUS` = 0.999: at 1 kHz this is a mode decaying
    with a time constant of about 1 s; anything slower is practically an
    integrator that drifts on the real robot, so it is refused although it is
    formally stable.
``exact_delay_spectral_radius``
    The same loop on eq (4) with the exact input delay instead of Padé
    (:func:`~iiwa_ident.design.exact_delay_spectral_radius`),
    same threshold: poles too fast for the delay pass the Padé check only.
``outer_loop_kappa_margin``
    Outer-loop gain margin ``kappa_max`` of ``tau_r = kappa tau_ext`` with the
    design's human-arm model (section V.C). Required: the additive loop is
    stable for every ``kappa`` up to ``max(MIN_KAPPA_MARGIN, kappa_max of the
    built-in controller)``, i.e. at least unit amplification of the human
    torque, and no worse than the robot's own controller; a design that lowers
    the margin below the built-in one defeats its purpose. Both bounds are
    recomputed (the additive one by scanning up to the threshold); the value
    reported is the design file's ``kappa_max_additive``.
``limits_within_data_sheet``
    Ratio of the requested torque and velocity limits to the data-sheet
    limits of the joint (and of the torque- and reference-rate limits to
    the default torque-rate limit).
    Threshold 1: limits may be tighter, never looser.
``reference_range``
    The runtime clamps the reference to ``|tau_r| <= reference_nm`` and its
    rate to ``reference_rate_nm_s``. ``reference_nm`` is the largest value
    (at most the torque limit) for which the worst reference move inside
    that range, a rate-limited reversal from ``-reference_nm`` to
    ``+reference_nm`` starting in steady state, keeps ``|tau_c|`` within the
    torque limit on the design model (feed-forward, pre-filter and feedback
    included; :func:`reference_limit`). The value is
    ``reference_nm / torque_nm``; threshold :data:`MIN_REFERENCE_FRACTION`
    = 0.5: a design that leaves less than half of the joint's torque range
    usable as reference is refused. The rate limit is what lets a fast
    feed-forward pre-filter pass: an ideal step through eq (22) behind a
    250 Hz pre-filter commands 6.6 times its size at the peak, the same step
    rate-limited to the default 8000 Nm/s (Table I, iiwa 14 A1) only the
    DC gain ``(Jc + Jl)/Jl`` = 1.18 of eq (22), while a 15 Nm sine at 25 Hz
    (2356 Nm/s) passes the rate limit untouched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from iiwa_ident.design import SAMPLE_TIME_S, DesignRecord, exact_delay_spectral_radius, kappa_max
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.robot import JointLimits

__all__ = [
    "Check",
    "ControllerLimits",
    "DeployError",
    "MAX_SPECTRAL_RADIUS",
    "MIN_KAPPA_MARGIN",
    "MIN_REFERENCE_FRACTION",
    "DEFAULT_RATE_RISE_TIME_S",
    "DEFAULT_REFERENCE_RISE_TIME_S",
    "default_rate_limit",
    "default_reference_rate",
    "step_peak_gain",
    "reference_limit",
    "check_design",
    "failed_checks",
]

#: Largest spectral radius accepted for the 1 kHz closed loop [-] (time constant ~1 s).
MAX_SPECTRAL_RADIUS = 0.999
#: Smallest accepted outer-loop gain margin kappa_max of the additive controller [-].
MIN_KAPPA_MARGIN = 1.0
#: Smallest accepted usable reference range, as a fraction of the torque limit [-].
MIN_REFERENCE_FRACTION = 0.5
#: The default torque-rate limit lets the command traverse the full torque limit in this time [s]
#: (about what the built-in loop and the 5 ms delay need to follow such a step anyway; the data
#: sheet gives no torque rate).
DEFAULT_RATE_RISE_TIME_S = 0.01
#: The default reference-rate limit lets ``tau_r`` traverse the full torque limit in this time [s]:
#: 8000 Nm/s on the iiwa 14 A1, above the 2356 Nm/s of the paper's 15 Nm / 25 Hz tracking test.
DEFAULT_REFERENCE_RISE_TIME_S = 0.04
#: Samples of the step response used for its peak (2 s at 1 kHz; the accepted loops settle in < 1 s).
_STEP_SAMPLES = 2000


class DeployError(IiwaIdentError):
    """A design was refused for deployment, or a deployment setting is invalid."""


@dataclass(frozen=True, kw_only=True)
class Check:
    """One deployment check.

    Attributes
    ----------
    name : str
        Identifier (see the module docstring).
    value : float
        Measured value (nan if it could not be evaluated).
    threshold : float
        Limit the value is compared with.
    passed : bool
        Verdict.
    comparison : str
        ``"<="``, ``">="`` or ``"=="``: how ``value`` must relate to ``threshold``.
    unit : str
        Unit of value and threshold.
    detail : str
        One-line explanation shown with a failure.
    """

    name: str
    value: float
    threshold: float
    passed: bool
    comparison: str
    unit: str = "-"
    detail: str = ""

    def describe(self) -> str:
        """``name value (must be <= threshold): detail``, one line."""
        text = f"{self.name} = {self.value:.6g} {self.unit} (must be {self.comparison} {self.threshold:.6g})"
        return f"{text}: {self.detail}" if self.detail else text


@dataclass(frozen=True)
class ControllerLimits:
    """Limits the runtime enforces.

    Attributes
    ----------
    torque_nm : float
        Clamp of the commanded torque ``|tau_c|`` [Nm].
    torque_rate_nm_s : float
        Clamp of the rate of the command ``tau_c`` [Nm/s].
    velocity_rad_s : float
        The runtime stops above this joint speed [rad/s].
    reference_rate_nm_s : float
        Clamp of the rate of the reference ``tau_r`` [Nm/s] (see ``reference_range``).
    reference_nm : float
        Clamp of the reference ``|tau_r|`` [Nm] (see ``reference_range``).
    """

    torque_nm: float
    torque_rate_nm_s: float
    velocity_rad_s: float
    reference_rate_nm_s: float
    reference_nm: float = math.nan


def default_rate_limit(data_sheet: JointLimits) -> float:
    """Default torque-rate limit [Nm/s]: the data-sheet torque in :data:`DEFAULT_RATE_RISE_TIME_S`."""
    return data_sheet.torque_nm / DEFAULT_RATE_RISE_TIME_S


def default_reference_rate(data_sheet: JointLimits) -> float:
    """Default reference-rate limit [Nm/s]: the data-sheet torque in :data:`DEFAULT_REFERENCE_RISE_TIME_S`."""
    return data_sheet.torque_nm / DEFAULT_REFERENCE_RISE_TIME_S


def _non_finite(record: DesignRecord) -> int:
    """Number of non-finite numbers anywhere in the design record."""
    d = record.design
    parts: list = [list(d.params.as_dict().values()), d.sample_time_s, d.c1, d.c2, d.A, d.B, d.C, d.K_fsf, d.L,
                   d.Kr, d.Kr_c, d.Ad, d.Bd, d.Kd, d.Ld, d.Kr_d, d.poles, d.observer_poles, d.builtin_poles,
                   d.additive_poles, d.additive_poles_discrete, record.KI, record.filter.beta,
                   record.filter.v_min_rad_s]
    if d.ff is not None:
        parts += list(d.ff) + [d.prefilter_hz, d.prefilter_zeta]
    if d.ffd is not None:
        parts += list(d.ffd)
    if record.ripple is not None:
        parts += [record.ripple.period_rad, record.ripple.lut]
    bad = 0
    for p in parts:
        a = np.asarray(p, dtype=complex)
        bad += int(np.count_nonzero(~np.isfinite(a)))
    return bad


def _closed_loop_radius(record: DesignRecord) -> float:
    A = np.asarray(record.design.closed_loop(discrete=True).A, float)
    return float(np.abs(np.linalg.eigvals(A)).max())


def _step_response(record: DesignRecord, samples: int) -> tuple[np.ndarray, float]:
    """``tau_c`` [Nm/Nm] of the design on its own (Padé) model for a unit step of ``tau_r``, and its DC gain."""
    sys = record.design.closed_loop(discrete=True)
    A, B = np.asarray(sys.A, float), np.asarray(sys.B, float)[:, 0]
    c, dd = np.asarray(sys.C, float)[1], float(np.asarray(sys.D, float)[1, 0])
    x = np.zeros(A.shape[0])
    out = np.empty(samples)
    for k in range(samples):
        out[k] = float(c @ x) + dd
        x = A @ x + B
    dc = float(c @ np.linalg.solve(np.eye(A.shape[0]) - A, B)) + dd
    return out, dc


def step_peak_gain(record: DesignRecord, samples: int = _STEP_SAMPLES) -> float:
    """Peak ``|tau_c|`` [Nm/Nm] for an ideal unit step of ``tau_r`` with the design on its own (Padé) model."""
    return float(np.abs(_step_response(record, samples)[0]).max())


def _reversal_peak(step: np.ndarray, dc: float, size: float, increment: float) -> float:
    """Peak ``|tau_c|`` [Nm] for ``tau_r`` moving from ``-size`` (steady state) to ``+size`` by ``increment`` per cycle."""
    # Superposition of unit steps: u_k = min((k + 1) increment, 2 size) - size.
    n = len(step)
    du = np.diff(np.minimum(increment * np.arange(n + 1), 2.0 * size))
    y = -size * dc + np.convolve(du, step)[:n]
    return float(np.abs(y).max())


def reference_limit(record: DesignRecord, torque_nm: float, reference_rate_nm_s: float,
                    samples: int = _STEP_SAMPLES) -> float:
    """Largest reference clamp [Nm] whose worst rate-limited move keeps ``|tau_c|`` within ``torque_nm``.

    Parameters
    ----------
    record : DesignRecord
        The design.
    torque_nm : float
        Torque limit [Nm].
    reference_rate_nm_s : float
        Rate limit of the reference [Nm/s].
    samples : int
        Length of the simulated response [cycles].

    Returns
    -------
    float
        ``reference_nm`` [Nm] in ``[0, torque_nm]`` (module docstring, ``reference_range``).
    """
    step, dc = _step_response(record, samples)
    increment = reference_rate_nm_s * record.design.sample_time_s
    if _reversal_peak(step, dc, torque_nm, increment) <= torque_nm:
        return float(torque_nm)
    lo, hi = 0.0, float(torque_nm)
    # The peak grows with the size of the move (longer ramps, larger levels): bisect to 0.1 %.
    while hi - lo > 1e-3 * torque_nm:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _reversal_peak(step, dc, mid, increment) <= torque_nm else (lo, mid)
    return lo


def check_design(record: DesignRecord, limits: ControllerLimits | None = None,
                 data_sheet: JointLimits | None = None) -> list[Check]:
    """Evaluate every deployment check of ``record`` (module docstring).

    Parameters
    ----------
    record : DesignRecord
        The design (from :func:`~iiwa_ident.design.read_design`).
    limits : ControllerLimits, optional
        The requested limits; with ``data_sheet`` enables the limit checks.
    data_sheet : JointLimits, optional
        Data-sheet limits of the joint.

    Returns
    -------
    list of Check
        All checks, passed or not, in a fixed order. Checks that cannot be
        evaluated (non-finite numbers, unstable loop) fail with value nan.
    """
    checks: list[Check] = []
    bad = _non_finite(record)
    checks.append(Check(name="finite", value=float(bad), threshold=0.0, passed=bad == 0, comparison="<=",
                        unit="entries", detail="" if bad == 0 else "the design holds NaN or infinite numbers"))
    T = record.design.sample_time_s
    ok_T = math.isfinite(T) and abs(T - SAMPLE_TIME_S) <= 1e-12
    checks.append(Check(name="sample_time", value=T, threshold=SAMPLE_TIME_S, passed=ok_T, comparison="==", unit="s",
                        detail="" if ok_T else "the FRI runs at 1 ms; redesign at that cycle"))
    finite = bad == 0

    radius = _closed_loop_radius(record) if finite else math.nan
    ok = radius <= MAX_SPECTRAL_RADIUS
    checks.append(Check(name="closed_loop_spectral_radius", value=radius, threshold=MAX_SPECTRAL_RADIUS, passed=ok,
                        comparison="<=", unit="-",
                        detail="" if ok else ("the 1 kHz closed loop is unstable" if radius >= 1 else
                                              "the 1 kHz closed loop is too close to instability")))
    radius_exact = exact_delay_spectral_radius(record.design) if finite else math.nan
    ok = radius_exact <= MAX_SPECTRAL_RADIUS
    checks.append(Check(name="exact_delay_spectral_radius", value=radius_exact, threshold=MAX_SPECTRAL_RADIUS,
                        passed=ok, comparison="<=", unit="-",
                        detail="" if ok else "unstable or nearly so with the exact delay instead of Pade"))

    stable = finite and radius < 1.0 and radius_exact < 1.0
    m = record.margins
    if stable:
        builtin = kappa_max(record.design.params, None, m.arm, m.kappa_limit)
        need = max(MIN_KAPPA_MARGIN, builtin if math.isfinite(builtin) else m.kappa_limit)
        # Scan only up to the threshold: inf means stable on all of [0, need].
        verified = kappa_max(record.design.params, record.design, m.arm, kappa_limit=need)
        value = float(m.additive) if math.isinf(verified) else verified
        ok = math.isinf(verified) and m.additive >= need
    else:
        need, value, ok = MIN_KAPPA_MARGIN, math.nan, False
    checks.append(Check(name="outer_loop_kappa_margin", value=value, threshold=need, passed=ok, comparison=">=",
                        unit="-",
                        detail="" if ok else "the outer loop tau_r = kappa tau_ext is not stable up to the required "
                                             "gain (minimum 1 and the built-in controller's kappa_max)"))

    if limits is not None and data_sheet is not None:
        ratios = [limits.torque_nm / data_sheet.torque_nm, limits.velocity_rad_s / data_sheet.velocity_rad_s,
                  limits.torque_rate_nm_s / default_rate_limit(data_sheet),
                  limits.reference_rate_nm_s / default_rate_limit(data_sheet)]
        worst = max(ratios) if all(math.isfinite(r) for r in ratios) else math.nan
        ok = worst <= 1.0
        names = ("torque", "velocity", "torque rate", "reference rate")
        which = ", ".join(n for n, r in zip(names, ratios) if not r <= 1.0)
        checks.append(Check(name="limits_within_data_sheet", value=worst, threshold=1.0, passed=ok, comparison="<=",
                            unit="-", detail="" if ok else f"{which} limit above the joint's data sheet"))
        ref = reference_limit(record, limits.torque_nm, limits.reference_rate_nm_s) if stable else math.nan
        frac = ref / limits.torque_nm
        ok = frac >= MIN_REFERENCE_FRACTION
        checks.append(Check(name="reference_range", value=frac, threshold=MIN_REFERENCE_FRACTION, passed=ok,
                            comparison=">=", unit="-",
                            detail="" if ok else f"references beyond {ref:.3g} Nm at {limits.reference_rate_nm_s:g} "
                                                 "Nm/s would command more than the torque limit, less than half of it"))
    return checks


def failed_checks(checks: list[Check]) -> list[Check]:
    """The checks that did not pass."""
    return [c for c in checks if not c.passed]
