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
    (:func:`~iiwa_ident.design.controller.exact_delay_spectral_radius`),
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
    limits of the joint (and of the torque-rate limit to its default).
    Threshold 1: limits may be tighter, never looser.
``reference_range``
    The runtime clamps the reference ``tau_r`` to
    ``reference_nm = torque_nm / g_peak``, where ``g_peak`` is the peak of
    ``|tau_c|`` in the response to a unit reference step on the design model
    (feed-forward overshoot and feedback gain included), so that a reference
    step anywhere in that range never commands more than the torque limit
    (smoother references, as the rate limit enforces, command less). The
    value is ``reference_nm / torque_nm = 1 / g_peak``; threshold
    :data:`MIN_REFERENCE_FRACTION` = 0.5: a design that amplifies a
    reference step more than twice at its peak leaves less than half of the
    joint's torque range usable and is refused. (The literal test "a
    reference step at the torque limit stays within the limit" would refuse
    every design with feed-forward: eq (22) alone has the DC gain
    ``(Jc + Jl)/Jl`` > 1, 1.18 on Table I, with a peak of 1.46.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from iiwa_ident.design.controller import SAMPLE_TIME_S, exact_delay_spectral_radius, kappa_max
from iiwa_ident.design.design_file import DesignRecord
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
    "default_rate_limit",
    "step_peak_gain",
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
#: Samples of the step response used for its peak (2 s at 1 kHz; the accepted loops settle in < 1 s).
_STEP_SAMPLES = 2000


class DeployError(IiwaIdentError):
    """A design was refused for deployment, or a deployment setting is invalid."""


@dataclass(frozen=True)
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
        Clamp of the rate of ``tau_r`` and ``tau_c`` [Nm/s].
    velocity_rad_s : float
        The runtime stops above this joint speed [rad/s].
    reference_nm : float
        Clamp of the reference ``|tau_r|`` [Nm] (see ``reference_range``).
    """

    torque_nm: float
    torque_rate_nm_s: float
    velocity_rad_s: float
    reference_nm: float = math.nan


def default_rate_limit(data_sheet: JointLimits) -> float:
    """Default torque-rate limit [Nm/s]: the data-sheet torque in :data:`DEFAULT_RATE_RISE_TIME_S`."""
    return data_sheet.torque_nm / DEFAULT_RATE_RISE_TIME_S


def _non_finite(record: DesignRecord) -> int:
    """Number of non-finite numbers anywhere in the design record."""
    d = record.design
    parts: list = [list(d.params.as_dict().values()), d.sample_time_s, d.c1, d.c2, d.A, d.B, d.C, d.K_fsf, d.L,
                   d.Kr, d.Kr_c, d.Ad, d.Bd, d.Kd, d.Ld, d.Kr_d, d.poles, d.observer_poles, d.builtin_poles,
                   d.additive_poles, d.additive_poles_discrete, record.KI, record.filter.beta,
                   record.filter.v_min_rad_s, record.filter.period_rad]
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


def step_peak_gain(record: DesignRecord, samples: int = _STEP_SAMPLES) -> float:
    """Peak ``|tau_c|`` [Nm/Nm] for a unit step of ``tau_r`` with the design on its own (Padé) model."""
    sys = record.design.closed_loop(discrete=True)
    A, B = np.asarray(sys.A, float), np.asarray(sys.B, float)[:, 0]
    c, dd = np.asarray(sys.C, float)[1], float(np.asarray(sys.D, float)[1, 0])
    x = np.zeros(A.shape[0])
    peak = 0.0
    for _ in range(samples):
        peak = max(peak, abs(float(c @ x) + dd))
        x = A @ x + B
    return peak


def check_design(record: DesignRecord, limits: ControllerLimits | None = None,
                 data_sheet: JointLimits | None = None) -> list[Check]:
    """Evaluate every deployment check of ``record`` (module docstring).

    Parameters
    ----------
    record : DesignRecord
        The design (from :func:`~iiwa_ident.design.design_file.read_design`).
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
    checks.append(Check("finite", float(bad), 0.0, bad == 0, "<=", "entries",
                        "" if bad == 0 else "the design holds NaN or infinite numbers"))
    T = record.design.sample_time_s
    ok_T = math.isfinite(T) and abs(T - SAMPLE_TIME_S) <= 1e-12
    checks.append(Check("sample_time", T, SAMPLE_TIME_S, ok_T, "==", "s",
                        "" if ok_T else "the FRI runs at 1 ms; redesign at that cycle"))
    finite = bad == 0

    rho = _closed_loop_radius(record) if finite else math.nan
    ok = rho <= MAX_SPECTRAL_RADIUS
    checks.append(Check("closed_loop_spectral_radius", rho, MAX_SPECTRAL_RADIUS, ok, "<=", "-",
                        "" if ok else ("the 1 kHz closed loop is unstable" if rho >= 1 else
                                       "the 1 kHz closed loop is too close to instability")))
    rho_x = exact_delay_spectral_radius(record.design) if finite else math.nan
    ok = rho_x <= MAX_SPECTRAL_RADIUS
    checks.append(Check("exact_delay_spectral_radius", rho_x, MAX_SPECTRAL_RADIUS, ok, "<=", "-",
                        "" if ok else "unstable or nearly so with the exact delay instead of Pade"))

    stable = finite and rho < 1.0 and rho_x < 1.0
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
    checks.append(Check("outer_loop_kappa_margin", value, need, ok, ">=", "-",
                        "" if ok else "the outer loop tau_r = kappa tau_ext is not stable up to the required gain "
                                      "(minimum 1 and the built-in controller's kappa_max)"))

    if limits is not None and data_sheet is not None:
        ratios = [limits.torque_nm / data_sheet.torque_nm, limits.velocity_rad_s / data_sheet.velocity_rad_s,
                  limits.torque_rate_nm_s / default_rate_limit(data_sheet)]
        worst = max(ratios) if all(math.isfinite(r) for r in ratios) else math.nan
        ok = worst <= 1.0
        names = ("torque", "velocity", "torque rate")
        which = ", ".join(n for n, r in zip(names, ratios) if not r <= 1.0)
        checks.append(Check("limits_within_data_sheet", worst, 1.0, ok, "<=", "-",
                            "" if ok else f"{which} limit above the joint's data sheet"))
        peak = step_peak_gain(record) if stable else math.nan
        frac = 1.0 / peak if peak > 0 else math.nan
        ok = frac >= MIN_REFERENCE_FRACTION
        checks.append(Check("reference_range", frac, MIN_REFERENCE_FRACTION, ok, ">=", "-",
                            "" if ok else f"a reference step commands up to {peak:.3g} times its size, so less "
                                          "than half the torque limit is usable as reference"))
    return checks


def failed_checks(checks: list[Check]) -> list[Check]:
    """The checks that did not pass."""
    return [c for c in checks if not c.passed]
