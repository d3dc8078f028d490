"""Spatial filter of the transmission ripple, eqs (10)-(12).

The ripple of eq (5) repeats every rho along the joint position, so in time
its frequency follows the speed (eq (6)). The paper removes it with a filter
defined along the position rather than in time:

``H_ripple(p) = beta omega p / (p^2 + beta omega p + omega^2)``     (10)
``H_filt = 1 - (gamma H_ripple)^2``                                  (11)
``gamma = 1 if |dtheta_j/dt| >= v_min else |dtheta_j/dt| / v_min``  (12)

with ``p`` the Laplace variable of d/dx (x the joint position [rad]) and
``omega = 2 pi / rho`` [rad^-1]. At a constant speed v it is the temporal
filter obtained by ``p = s / |v|``: a notch at ``omega |v|`` rad/s, i.e. at
the ripple frequency ``|v| / rho`` Hz of eq (6), wherever the speed goes.

Discretisation
--------------
Samples are uniform in time, not in position. Each sample advances the
position by ``Delta_k = |theta_k - theta_{k-1}|`` and the filter takes one
trapezoidal (Tustin) step of that length in x. For a fixed ``Delta`` this is
exactly the paper's

``N(z) = 2 beta omega Delta (1 - z^-2)``,
``D(z) = (4 + 2 beta omega Delta + omega^2 Delta^2) + (2 omega^2 Delta^2 - 8) z^-1
+ (4 - 2 beta omega Delta + omega^2 Delta^2) z^-2``

(:func:`ripple_bandpass_coefficients`). Because ``Delta`` changes every
sample, the step is taken on a state-space realisation of eq (10) rather
than on the difference equation of N/D: both agree for a constant
``Delta``, but only the state-space step keeps the state still when the
joint stands (``Delta = 0`` gives the identity), whereas the difference
equation with ``Delta = 0`` becomes ``y_k = 2 y_{k-1} - y_{k-2}`` and drifts.

Choices left open by the paper
------------------------------
* gamma scales the subtracted signal, ``y = tau - gamma^2 bp(bp(tau))``, with
  the two band-pass sections themselves never scaled. Their state then
  depends only on the torque along the path travelled, not on the speed
  history, so once the joint is faster than ``v_min`` the full correction
  applies at once; scaling each section by gamma instead would feed the
  second section a gamma-weighted past and bring the correction in one
  spatial period late after every slow phase. For a constant gamma both
  are the same transfer function ``1 - (gamma H_ripple)^2``, and gamma = 0
  passes the torque through unchanged whatever the state.
* The speed in gamma is the position difference per sample smoothed by a
  first-order low-pass (``velocity_cutoff_hz``, 20 Hz by default) of the
  signed velocity: signed, so that encoder dither at standstill averages
  out instead of adding up; 20 Hz, so that gamma lags the hand by only
  ~8 ms while a single encoder tick or sensor-noise step cannot move it.
  It starts at zero (the joint is assumed at rest before the first sample).
* The band-pass sections start in their steady state for the first torque
  sample, so a constant torque (gravity, a held load) causes no start
  transient.
* The position may be the motor position q_m or the joint position of
  eq (8): the ripple is exactly periodic in q_m, and ``theta_j`` is a
  monotone reparametrisation of it with the same period (their speeds
  differ by ``|f'| < 2 %`` on the iiwa).

Passband
--------
``1 - H^2 = (1 - H)(1 + H)``: a notch times a broad boost, so below the
notch the gain rises above one, ``|H_filt| ~ 1 + (beta f / f_ripple)^2``
for ``f << f_ripple``. With the paper's beta = 5 at 0.3 rad/s (ripple at
15.3 Hz) a 2 Hz torque is amplified by 1.2 dB; a smaller beta narrows both
the notch and the boost (:func:`spatial_filter_response`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from iiwa_ident._defaults import DESIGN_BETA  # one definition, light for the CLI's help
from iiwa_ident.ident import find_passes
from iiwa_ident.model import RIPPLE_PERIOD_RAD

if TYPE_CHECKING:
    from iiwa_ident.model import JointModel, RippleTable

#: The paper's beta of the spatial filter, eq (14) [-]: the default of the filter and of the paper's
#: observer comparison (Fig. 7); what a design deploys is :data:`DESIGN_BETA`.
PAPER_BETA = 5.0
#: Speed below which the filter fades out, gamma of eq (12) [rad/s].
V_MIN_RAD_S = 0.2

__all__ = [
    "RIPPLE_PERIOD_RAD",
    "DESIGN_BETA",
    "PAPER_BETA",
    "V_MIN_RAD_S",
    "FilterSettings",
    "filter_period",
    "PAPER_FILTER",
    "SpatialFilter",
    "ripple_bandpass_coefficients",
    "gamma_weight",
    "spatial_filter_response",
    "line_amplitude",
    "ripple_line_cut",
]


@dataclass(frozen=True)
class FilterSettings:
    """The spatial filter's settings of eqs (10)-(12), passed as one object wherever a filter is built.

    Attributes
    ----------
    beta : float
        Band-pass sharpness [-] (paper: :data:`PAPER_BETA`; default :data:`DESIGN_BETA`).
    v_min_rad_s : float
        Speed below which the filter fades out [rad/s] (:data:`V_MIN_RAD_S`).

    The period is not a setting: the filter works at the lookup table's rho (:func:`filter_period`), so
    one period serves the filter and the position correction.

    Examples
    --------
    >>> FilterSettings(beta=5.0)
    FilterSettings(beta=5.0, v_min_rad_s=0.2)
    """

    beta: float = DESIGN_BETA
    v_min_rad_s: float = V_MIN_RAD_S


def filter_period(table: RippleTable | None) -> float:
    """The ripple period rho [rad] the spatial filter works at: the lookup table's; the paper's without one.

    Examples
    --------
    >>> from iiwa_ident.model import RippleTable
    >>> filter_period(RippleTable(0.0196, np.zeros(8)))
    0.0196
    >>> filter_period(None) == RIPPLE_PERIOD_RAD
    True
    """
    return float(table.period_rad) if table is not None else RIPPLE_PERIOD_RAD


#: The paper's filter (Fig. 7's observer comparison): :data:`PAPER_BETA`, :data:`V_MIN_RAD_S`, the table's period.
PAPER_FILTER = FilterSettings(beta=PAPER_BETA)


def ripple_bandpass_coefficients(period_rad: float, beta: float, delta_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """The paper's discrete band-pass N(z)/D(z) of eq (10) for one position step.

    Parameters
    ----------
    period_rad : float
        Ripple period rho [rad]; omega = 2 pi / rho.
    beta : float
        Bandwidth parameter of eq (10) [-].
    delta_rad : float
        Absolute position change per sample Delta [rad].

    Returns
    -------
    b, a : numpy.ndarray
        Numerator and denominator in powers of z^-1 (not normalised, as printed in the paper).
    """
    w = 2.0 * math.pi / period_rad
    bw = beta * w * delta_rad
    w2 = (w * delta_rad) ** 2
    b = np.array([2.0 * bw, 0.0, -2.0 * bw])
    a = np.array([4.0 + 2.0 * bw + w2, 2.0 * w2 - 8.0, 4.0 - 2.0 * bw + w2])
    return b, a


def gamma_weight(speed_rad_s: np.ndarray | float, v_min: float = V_MIN_RAD_S) -> np.ndarray | float:
    """Eq (12): the weight gamma of the filter from the joint speed [rad/s] (``v_min`` [rad/s]).

    Examples
    --------
    >>> gamma_weight(0.1), gamma_weight(0.5)  # half-way to the fade-out speed; above it
    (0.5, 1.0)
    """
    if v_min <= 0:
        return np.ones_like(np.asarray(speed_rad_s, float)) if np.ndim(speed_rad_s) else 1.0
    g = np.minimum(1.0, np.abs(np.asarray(speed_rad_s, float)) / v_min)
    return g if np.ndim(g) else float(g)


def spatial_filter_response(freq_hz: np.ndarray | float, speed_rad_s: float, dt: float = 1e-3,
                            period_rad: float = RIPPLE_PERIOD_RAD, beta: float = PAPER_BETA,
                            v_min: float = V_MIN_RAD_S) -> np.ndarray:
    """Frequency response of the discrete filter in time, at a constant speed.

    At a constant speed every sample advances ``Delta = |v| dt`` and the
    filter is time-invariant: ``1 - gamma^2 H(z)^2`` with H the paper's
    N(z)/D(z) and gamma from eq (12).

    Parameters
    ----------
    freq_hz : array_like
        Temporal frequencies [Hz].
    speed_rad_s : float
        Joint speed [rad/s].
    dt : float
        Sample time [s].
    period_rad, beta, v_min : float
        Filter parameters (rho [rad], beta [-], v_min [rad/s]).

    Returns
    -------
    numpy.ndarray
        Complex response H_filt(e^{j 2 pi f dt}) [-].

    Examples
    --------
    At 0.3 rad/s the paper's ripple is at 0.3 / 0.01963 = 15.3 Hz: cut by about 64 dB there, while
    1 Hz is lifted a little by the boost below the notch (module docstring), with the paper's beta:

    >>> h = spatial_filter_response(np.array([1.0, 0.3 / 0.01963]), 0.3)
    >>> [round(float(x), 1) for x in 20 * np.log10(np.abs(h))]
    [0.7, -64.2]
    """
    b, a = ripple_bandpass_coefficients(period_rad, beta, abs(speed_rad_s) * dt)
    z1 = np.exp(-2j * np.pi * np.asarray(freq_hz, float) * dt)
    h = (b[0] + b[1] * z1 + b[2] * z1 ** 2) / (a[0] + a[1] * z1 + a[2] * z1 ** 2)
    g = gamma_weight(speed_rad_s, v_min)
    return 1.0 - (g * h) ** 2


class _Section:
    """One band-pass of eq (10) as a state-space system along x, stepped by the trapezoidal rule.

    ``s1' = omega s2``, ``s2' = -omega s1 - beta omega s2 + beta omega u``, ``y = s2``
    (derivatives along x) has the transfer function of eq (10). Plain floats: one call per
    sample of a 1 kHz loop must not allocate arrays.
    """

    __slots__ = ("w", "beta", "s1", "s2", "u_prev")

    def __init__(self, omega: float, beta: float) -> None:
        self.w, self.beta = omega, beta
        self.s1 = self.s2 = self.u_prev = 0.0

    def settle(self, u: float) -> None:
        """Steady state for a constant input u: zero output, no transient."""
        self.s1, self.s2, self.u_prev = self.beta * u, 0.0, u

    def step(self, u: float, delta: float) -> float:
        a = 0.5 * self.w * delta
        ab = a * self.beta
        r1 = self.s1 + a * self.s2
        r2 = -a * self.s1 + (1.0 - ab) * self.s2 + ab * (u + self.u_prev)
        det = 1.0 + ab + a * a
        self.s1 = ((1.0 + ab) * r1 + a * r2) / det
        self.s2 = (r2 - a * r1) / det
        self.u_prev = u
        return self.s2


class SpatialFilter:
    """H_filt of eqs (10)-(12): removes the position-periodic ripple from a torque signal.

    Parameters
    ----------
    period_rad : float
        Ripple period rho [rad] (the identified one, e.g. ``model.ripple.period_rad``).
    beta : float
        Bandwidth of the band-pass, eq (10) [-] (paper: 5).
    v_min : float
        Speed below which the filtering fades out, eq (12) [rad/s] (paper: 0.2).
    dt : float
        Sample time of :meth:`step` [s].
    velocity_cutoff_hz : float
        Cutoff of the low-pass on the speed used for gamma [Hz].

    Notes
    -----
    See the module docstring for the discretisation and how gamma enters.
    :meth:`step` runs the filter one sample at a time; :meth:`apply` runs a
    whole record from a fresh state and gives the same numbers.
    """

    def __init__(self, period_rad: float = RIPPLE_PERIOD_RAD, beta: float = PAPER_BETA, v_min: float = V_MIN_RAD_S,
                 dt: float = 1e-3, velocity_cutoff_hz: float = 20.0) -> None:
        if period_rad <= 0 or beta <= 0 or v_min < 0 or dt <= 0 or velocity_cutoff_hz <= 0:
            raise ValueError("spatial filter: period, beta, dt and the cutoff must be positive, v_min >= 0")
        self.period_rad, self.beta, self.v_min = float(period_rad), float(beta), float(v_min)
        self.dt, self.velocity_cutoff_hz = float(dt), float(velocity_cutoff_hz)
        self.omega = 2.0 * math.pi / self.period_rad
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * self.velocity_cutoff_hz * self.dt)
        self._bp1 = _Section(self.omega, self.beta)
        self._bp2 = _Section(self.omega, self.beta)
        self.reset()

    @classmethod
    def from_settings(cls, settings: FilterSettings, table: RippleTable | None, dt: float = 1e-3,
                      **kwargs: float) -> SpatialFilter:
        """The filter of ``settings`` at the period of the lookup table ``table`` (:func:`filter_period`)."""
        return cls(filter_period(table), beta=settings.beta, v_min=settings.v_min_rad_s, dt=dt, **kwargs)

    @classmethod
    def from_model(cls, model: JointModel, dt: float = 1e-3, **kwargs: float) -> SpatialFilter:
        """A filter at the period of ``model.ripple`` (a :class:`~iiwa_ident.model.JointModel`)."""
        if model.ripple is None:
            raise ValueError("spatial filter: the model has no ripple table, so no period to filter at")
        return cls(model.ripple.period_rad, dt=dt, **kwargs)

    def reset(self) -> None:
        """Forget the past: the next :meth:`step` starts the filter afresh."""
        self._theta_prev: float | None = None
        self.speed = 0.0  #: smoothed joint speed of the last step [rad/s]
        self.gamma = 0.0  #: gamma of eq (12) at the last step [-]
        self.ripple = 0.0  #: the band-passed-twice torque bp(bp(tau)) of the last step [Nm]

    def step(self, tau: float, theta: float) -> float:
        """One sample: torque [Nm] at joint position [rad] -> filtered torque [Nm]."""
        if self._theta_prev is None:
            self._bp1.settle(tau)
            self._bp2.settle(0.0)
            self._theta_prev = theta
            self.ripple = 0.0
            return tau
        d = theta - self._theta_prev
        self._theta_prev = theta
        delta = abs(d)
        self.speed += self._alpha * (d / self.dt - self.speed)
        g = abs(self.speed) / self.v_min if self.v_min > 0 else 1.0
        self.gamma = g if g < 1.0 else 1.0
        self.ripple = self._bp2.step(self._bp1.step(tau, delta), delta)
        return tau - self.gamma * self.gamma * self.ripple

    def apply(self, tau: np.ndarray, theta: np.ndarray, dt: float | None = None) -> np.ndarray:
        """Filter a whole record from a fresh state (this filter's own state is left untouched).

        Parameters
        ----------
        tau : array_like
            Torque [Nm], uniformly sampled.
        theta : array_like
            Joint (or motor) position at the same samples [rad].
        dt : float, optional
            Sample time [s] (default: this filter's).

        Returns
        -------
        numpy.ndarray
            The filtered torque [Nm].
        """
        tau = np.asarray(tau, float)
        theta = np.asarray(theta, float)
        if tau.shape != theta.shape or tau.ndim != 1:
            raise ValueError("spatial filter: tau and theta must be 1-D arrays of one length")
        f = SpatialFilter(self.period_rad, self.beta, self.v_min, self.dt if dt is None else dt,
                          self.velocity_cutoff_hz)
        out = np.empty_like(tau)
        step = f.step
        for k, (u, x) in enumerate(zip(tau.tolist(), theta.tolist())):
            out[k] = step(u, x)
        return out


def line_amplitude(t: np.ndarray, x: np.ndarray, freq_hz: float, trend_order: int = 2) -> float:
    """Amplitude of the spectral line at ``freq_hz`` [Hz] in ``x`` (same unit as ``x``).

    Least-squares fit of ``a cos(2 pi f t) + b sin(2 pi f t)`` on top of a
    polynomial trend of ``trend_order`` (slow torque changes along a pass);
    returns ``hypot(a, b)``. Over a whole number of periods this is the
    peak of a rectangular-window spectrum, without its leakage.
    """
    t = np.asarray(t, float)
    tc = (t - t.mean()) / max(np.ptp(t), 1e-12)
    arg = 2.0 * np.pi * freq_hz * t
    cols = [np.cos(arg), np.sin(arg)] + [tc ** k for k in range(trend_order + 1)]
    coef = np.linalg.lstsq(np.column_stack(cols), np.asarray(x, float), rcond=None)[0]
    return float(np.hypot(coef[0], coef[1]))


def ripple_line_cut(t: np.ndarray, theta: np.ndarray, tau: np.ndarray, tau_filtered: np.ndarray,
                    period_rad: float = RIPPLE_PERIOD_RAD, min_speed: float = 0.1, min_periods: float = 5.0,
                    tolerance: float = 0.05, trim_s: float = 0.05) -> list[dict[str, float]]:
    """How much a filter removed of the ripple line at ``|v| / rho`` (eq (6)), per constant-speed pass.

    Parameters
    ----------
    t : array_like
        Sample times [s].
    theta : array_like
        Joint or motor position [rad].
    tau, tau_filtered : array_like
        The torque before and after filtering [Nm].
    period_rad : float
        Ripple period rho [rad].
    min_speed : float
        Slowest pass considered [rad/s].
    min_periods : float
        Shortest pass considered, in ripple periods.
    tolerance : float
        Relative speed variation allowed within a pass.
    trim_s : float
        Time dropped at both ends of a pass [s].

    Returns
    -------
    list of dict
        Per pass: ``speed_rad_s`` (signed mean), ``freq_hz`` (``|v| / rho``),
        ``raw_nm`` and ``filtered_nm`` (line amplitudes), ``cut_db``
        (``20 log10(raw / filtered)``), ``start_s``, ``stop_s``.
    """
    t, theta = np.asarray(t, float), np.asarray(theta, float)
    tau, tau_filtered = np.asarray(tau, float), np.asarray(tau_filtered, float)
    dt = float(np.median(np.diff(t)))
    trim = int(round(trim_s / dt))
    rows = []
    for i0, i1 in find_passes(t, theta, min_speed, min_periods * period_rad, tolerance):
        i0, i1 = i0 + trim, i1 - trim
        if i1 - i0 < 10 or abs(theta[i1 - 1] - theta[i0]) < min_periods * period_rad:
            continue
        sl = slice(i0, i1)
        v = (theta[i1 - 1] - theta[i0]) / (t[i1 - 1] - t[i0])
        f = abs(v) / period_rad
        raw, filt = line_amplitude(t[sl], tau[sl], f), line_amplitude(t[sl], tau_filtered[sl], f)
        rows.append({"speed_rad_s": float(v), "freq_hz": float(f), "raw_nm": raw, "filtered_nm": filt,
                     "cut_db": float(20.0 * np.log10(raw / max(filt, 1e-300))),
                     "start_s": float(t[i0]), "stop_s": float(t[i1 - 1])})
    return rows
