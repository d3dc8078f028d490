"""The multisine experiment (the signal itself: :func:`iiwa_ident.references.odd_multisine`).

A multisine period of ``N`` samples at rate ``fs`` has its lines on the grid
``k fs / N``. An *odd* multisine excites only odd ``k`` within the band:
even-order nonlinear distortions then fall on the even lines, and odd-order
ones on the odd lines, where they add to the response like noise that does
not average out over periods (Pintelon and Schoukens, *System
Identification: A Frequency Domain Approach*, 2nd ed., Wiley 2012, ch. 3).
Each realisation draws new random phases, so the nonlinear distortions differ
from realisation to realisation while the linear response does not: that is
what separates the two in the best linear approximation
(:mod:`iiwa_ident.ident._bla`).

The crest factor (peak over RMS) of random phases is about 3-4; the clipping
algorithm of Van der Ouderaa, Schoukens and Renneboog (IEEE Trans. Instrum.
Meas. 37(2), 1988) lowers it to about 1.5-1.8 by clipping the time signal and
restoring the amplitude spectrum in turn, so that more power fits under the
joint's torque limit.

:class:`Multisine` commands ``bias + x(t)`` with a weak position hold, like
the chirp's but damped beyond critical. A lead-in ramps the bias in and lets the link settle where the
hold balances it (a free link drifts to that equilibrium, slowly: with the
default hold its time constant is about a second, and a drift left in the
periods would leak into the low lines of ``q_m``). Then it runs ``M``
realisations, each of transient periods (at least 4 s, in which the
transient of the new phases dies out) and ``P`` steady-state periods, and
records the design in the dataset: lead-in, period, transient and
steady-state periods, realisations, excited lines and the phases' seed.
With one transient period of 2 s and the chirp's lighter hold damping, the
link's slow mode still rang in the steady-state periods: ``q_m``'s noise
variance was 30-40 times larger and the inertia scale's spread 4-7 times.
"""

from __future__ import annotations

import math

import numpy as np

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite._runner import ClientState, Experiment
from iiwa_ident.references import crest_factor, odd_lines, odd_multisine
from iiwa_ident.robot import Command, RobotInterface

__all__ = ["Multisine"]


class Multisine(Experiment):
    """Torque-commanded random-phase odd multisines, P steady-state periods times M realisations.

    ``tau_c = bias + A x_m(t) - k_h (q - q0) - d_h v`` in realisation ``m``;
    each realisation runs one transient period and ``periods`` steady-state
    ones.

    Parameters
    ----------
    f_lo_hz, f_hi_hz : float
        Band of the excited odd lines [Hz].
    period_s : float
        Period [s]; the frequency resolution is ``1 / period_s``, the lowest
        odd line ``1 / period_s`` as well.
    periods : int
        Steady-state periods P per realisation (at least 2: the noise
        variance comes from their differences).
    realisations : int
        Realisations M with new random phases (at least 2: the nonlinear
        distortion's variance comes from their differences).
    amplitude_nm : float
        Peak of the multisine A [Nm].
    bias_nm : float
        Constant torque added [Nm].
    hold_stiffness, hold_damping : float
        Weak position hold against drift [Nm/rad], [Nm s/rad]; damped beyond
        critical on a base joint, so that the link's slow mode does not ring
        from one realisation into the next.
    seed : int
        Seed of the random phases.
    lead_in_s : float
        Time before the first realisation [s]: the bias ramps in over its
        first 60 % (raised cosine), then holds while the link settles.
    transient_periods : int, optional
        Periods run first in each realisation and left out of the analysis
        (default: enough for 4 s; a transient of the new phases left in the
        steady-state periods shows in ``q_m`` as noise at every line).
    """

    name = "multisine"

    def __init__(self, f_lo_hz: float = 1.0, f_hi_hz: float = 100.0, period_s: float = 2.0, periods: int = 2,
                 realisations: int = 4, amplitude_nm: float = 10.0, bias_nm: float = 3.0,
                 hold_stiffness: float = 30.0, hold_damping: float = 40.0, seed: int = 0,
                 lead_in_s: float = 6.0, transient_periods: int | None = None) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise IiwaIdentError(f"multisine: the period must be positive, got {period_s!r} s")
        if not 0 < f_lo_hz < f_hi_hz:
            raise IiwaIdentError(f"multisine: need 0 < f_lo < f_hi, got {f_lo_hz} and {f_hi_hz} Hz")
        if int(periods) != periods or periods < 2 or int(realisations) != realisations or realisations < 2:
            raise IiwaIdentError("multisine: at least 2 periods and 2 realisations (the noise and the nonlinear "
                                 "distortion are estimated from their differences)")
        if not amplitude_nm > 0:
            raise IiwaIdentError("multisine: the amplitude must be positive")
        if hold_stiffness < 0 or hold_damping < 0:
            raise IiwaIdentError("multisine: hold stiffness and damping must not be negative")
        if not (math.isfinite(lead_in_s) and lead_in_s >= 0):
            raise IiwaIdentError(f"multisine: the lead-in must be a non-negative time, got {lead_in_s!r} s")
        self.f_lo_hz, self.f_hi_hz, self.period_s = float(f_lo_hz), float(f_hi_hz), float(period_s)
        self.periods, self.realisations = int(periods), int(realisations)
        self.amplitude_nm, self.bias_nm = float(amplitude_nm), float(bias_nm)
        self.hold_stiffness, self.hold_damping = float(hold_stiffness), float(hold_damping)
        self.seed = int(seed)
        self.lead_in_s = float(lead_in_s)
        if transient_periods is None:
            transient_periods = max(1, math.ceil(4.0 / self.period_s - 1e-9))
        if int(transient_periods) != transient_periods or transient_periods < 1:
            raise IiwaIdentError("multisine: at least 1 transient period per realisation")
        self.transient_periods = int(transient_periods)
        self.duration_s = self.lead_in_s + self.realisations * (self.periods + self.transient_periods) * self.period_s
        self._signals: np.ndarray | None = None
        self._dt = 0.0

    def design(self, sample_time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(excited lines, one period per realisation, shape (M, N), peak 1) at this sample time."""
        n = int(round(self.period_s / sample_time_s))
        if abs(n * sample_time_s - self.period_s) > 1e-9 * self.period_s:
            raise IiwaIdentError(f"multisine: the period {self.period_s:g} s is not a whole number of "
                                 f"{sample_time_s * 1e3:g} ms cycles")
        lines = odd_lines(n, 1.0 / sample_time_s, self.f_lo_hz, self.f_hi_hz)
        if len(lines) < 2:
            raise IiwaIdentError(f"multisine: fewer than 2 odd lines of a {self.period_s:g} s period in "
                                 f"{self.f_lo_hz:g}-{self.f_hi_hz:g} Hz")
        rng = np.random.default_rng(self.seed)
        return lines, np.array([odd_multisine(n, lines, rng) for _ in range(self.realisations)])

    def check(self, robot: RobotInterface) -> None:
        nyquist = 0.5 / robot.sample_time_s
        if self.f_hi_hz >= nyquist:
            raise IiwaIdentError(f"multisine: f_hi = {self.f_hi_hz:g} Hz must be below the Nyquist frequency "
                                 f"{nyquist:g} Hz")
        peak = abs(self.bias_nm) + self.amplitude_nm
        if peak > robot.limits.torque_nm:
            raise IiwaIdentError(f"multisine: bias + amplitude = {peak:g} Nm exceeds the joint's torque limit "
                                 f"{robot.limits.torque_nm:g} Nm")
        self._dt = robot.sample_time_s
        self._lead = int(round(self.lead_in_s / self._dt))
        if abs(self._lead * self._dt - self.lead_in_s) > 1e-9 * max(self.lead_in_s, 1.0):
            raise IiwaIdentError(f"multisine: the lead-in {self.lead_in_s:g} s is not a whole number of "
                                 f"{self._dt * 1e3:g} ms cycles")
        self._lines, self._signals = self.design(self._dt)

    def command(self, s: ClientState) -> Command:
        assert self._signals is not None, "check() sets up the signals"
        n = self._signals.shape[1]
        k = int(round(s.t / self._dt)) - self._lead
        hold = -self.hold_stiffness * (s.q - s.q0) - self.hold_damping * s.v
        if k < 0:  # lead-in: the bias ramps in, then the link settles
            ramp = 0.6 * self._lead
            share = 1.0 if k + self._lead >= ramp else 0.5 - 0.5 * math.cos(math.pi * (k + self._lead) / ramp)
            return Command(tau_c=share * self.bias_nm + hold)
        m = min(k // (n * (self.periods + self.transient_periods)), self.realisations - 1)
        x = self._signals[m, k % n]
        tau = self.bias_nm + self.amplitude_nm * x + hold
        return Command(tau_c=tau)

    def attrs(self) -> dict:
        out = {"multisine": "random-phase odd", "f_lo_hz": self.f_lo_hz, "f_hi_hz": self.f_hi_hz,
               "period_s": self.period_s, "periods": self.periods, "transient_periods": self.transient_periods,
               "realisations": self.realisations, "amplitude_nm": self.amplitude_nm, "bias_nm": self.bias_nm,
               "phase_seed": self.seed, "duration_s": self.duration_s, "lead_in_s": self.lead_in_s,
               "hold_stiffness_nm_rad": self.hold_stiffness, "hold_damping_nms_rad": self.hold_damping}
        if self._signals is not None:
            out["excited_lines"] = np.asarray(self._lines, dtype=np.int64)
            out["crest_factor"] = float(max(crest_factor(x) for x in self._signals))
        return out
