"""What a constant-speed run can detect: the ripple search's detection probability, predicted.

A deflection line of amplitude ``A`` [rad] in a run of duration ``T`` [s] over noise of one-sided power
spectral density ``S`` [rad^2/Hz] at the line's frequency gives the search's mean chunk coefficient
(:func:`~iiwa_ident.ident._ripple_spectrum.hotelling`, Hann-tapered chunks) a signal-to-noise ratio

    lambda = 2 A^2 T / (3 S)

(white noise of variance ``sigma^2 = S fs / 2`` over ``N = T fs`` samples leaves each real component of a
Hann-tapered coefficient a variance ``3 sigma^2 / N``). Its Hotelling T^2 then follows a noncentral
F(2, 2(n - 1), lambda) law over the ``n`` chunks the run is cut into; the search detects when that line's
p-value, corrected for the frequencies searched and the two deflection estimates, is below the false-alarm
probability. :func:`detection_probability` evaluates this; :func:`detectable_amplitude` and
:func:`required_travel` invert it; :func:`noise_psd` reads ``S`` off a run's deflection.

The prediction is for one pass in one direction (a constant-velocity run); it leaves out what only adds
sensitivity (harmonics, the family test, other runs' line tests), so a line of several harmonics is
detected somewhat more often. ``bench/bench_ripple_detection.py`` measures it against the search on runs
written apart from it.

Examples
--------
A 1.2 rad run at 0.2 rad/s and 1 kHz, its deflection's noise 1e-13 rad^2/Hz at the line's 10 Hz (0.13 Nm of
white torque noise through 18500 Nm/rad):

>>> round(detection_probability(5e-6, travel_rad=1.2, speed_rad_s=0.2, psd_rad2_hz=1e-13, rate_hz=1000.0,
...                             cycles_per_rev=320.0), 2)
0.45
>>> round(detectable_amplitude(1.2, 0.2, 1e-13, 1000.0, 320.0) * 1e6, 1)     # µrad, with probability 0.95
8.0
>>> round(required_travel(5e-6, 0.2, 1e-13, 1000.0, 320.0), 2)              # rad, to detect 5 µrad
1.28
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal, stats

from iiwa_ident._defaults import PERIOD_MAX_RAD, PERIOD_MIN_RAD
from iiwa_ident.ident._ripple_lines import NYQUIST_SHARE
from iiwa_ident.ident._ripple_lines import span as span_of
from iiwa_ident.ident._ripple_passes import Pass
from iiwa_ident.ident._ripple_spectrum import SEARCH_TRIES_PER_POINT, chunks_in

__all__ = ["DETECTION_PROBABILITY", "detection_probability", "detectable_amplitude", "required_travel",
           "noise_psd", "line_frequency_hz", "RunSensitivity", "sensitivity", "pooled_detection_probability"]

#: The probability with which a run is said to detect an amplitude.
DETECTION_PROBABILITY = 0.95
#: Deflection estimates the search chooses between (the link's motion restored or neglected).
_ESTIMATES = 2


def line_frequency_hz(speed_rad_s: float, cycles_per_rev: float) -> float:
    """Temporal frequency [Hz] of a line of ``cycles_per_rev`` per joint revolution at ``speed_rad_s``."""
    return abs(speed_rad_s) * cycles_per_rev / (2.0 * math.pi)


def _threshold(travel_rad: float, false_alarm: float, period_min: float, period_max: float) -> tuple[int, float]:
    """Chunks of a single pass and the per-frequency p-value the search's detection asks for."""
    longest = min(period_max, travel_rad / 2.0)
    n = chunks_in(travel_rad, longest, travel_rad)
    # The search's grid has 4 points per resolution cell 1 / travel.
    tries = max(1.0, SEARCH_TRIES_PER_POINT * 4.0 * (1.0 / period_min - 1.0 / longest) * travel_rad)
    p_line = -math.expm1(math.log1p(-false_alarm / (2.0 * _ESTIMATES)) / tries)
    return n, p_line


def _snr(amplitude_rad: float, duration_s: float, psd_rad2_hz: float) -> float:
    """The mean chunk coefficient's signal-to-noise ratio, lambda = 2 A^2 T / (3 S) (module docstring)."""
    return 2.0 * amplitude_rad ** 2 * duration_s / (3.0 * psd_rad2_hz)


def _power(lam: float, n: int, p_line: float) -> float:
    dof = 2 * (n - 1)
    # The search scales T^2 by ln 2 over its local median (never up): under white noise, by this factor.
    scale = min(1.0, math.log(2.0) / float(stats.f.median(2, dof)))
    crit = float(stats.f.isf(p_line, 2, dof)) / scale
    return float(stats.ncf.sf(crit, 2, dof, lam)) if lam > 0 else p_line


def detection_probability(amplitude_rad: float, travel_rad: float, speed_rad_s: float, psd_rad2_hz: float,
                          rate_hz: float, cycles_per_rev: float, false_alarm: float = 1e-3,
                          period_min: float = PERIOD_MIN_RAD, period_max: float = PERIOD_MAX_RAD) -> float:
    """Probability that the ripple search detects a deflection line in one constant-speed run.

    Parameters
    ----------
    amplitude_rad : float
        Amplitude of the line in the deflection [rad].
    travel_rad, speed_rad_s : float
        The run's travel [rad] and speed [rad/s] (its duration is their ratio).
    psd_rad2_hz : float
        One-sided power spectral density of the deflection's noise at the line's frequency [rad^2/Hz]
        (:func:`noise_psd`).
    rate_hz : float
        Sample rate [Hz]: a line beyond NYQUIST_SHARE of the Nyquist limit is not detected.
    cycles_per_rev : float
        The line's cycles per joint revolution.
    false_alarm : float
        The search's false-alarm probability (``identify_ripple``'s, 1e-3).
    period_min, period_max : float
        The search's period range [rad].

    Returns
    -------
    float
        Detection probability; 0 where the run is too short to be cut into three chunks or the line lies
        beyond the Nyquist share.
    """
    if amplitude_rad < 0 or travel_rad <= 0 or speed_rad_s == 0 or psd_rad2_hz <= 0 or rate_hz <= 0:
        raise ValueError("need amplitude >= 0, travel > 0, speed != 0, psd > 0 and rate > 0")
    if line_frequency_hz(speed_rad_s, cycles_per_rev) > NYQUIST_SHARE * rate_hz / 2.0:
        return 0.0
    n, p_line = _threshold(travel_rad, false_alarm, period_min, period_max)
    if n < 3:
        return 0.0
    duration = travel_rad / abs(speed_rad_s)
    return _power(_snr(amplitude_rad, duration, psd_rad2_hz), n, p_line)


def detectable_amplitude(travel_rad: float, speed_rad_s: float, psd_rad2_hz: float, rate_hz: float,
                         cycles_per_rev: float, probability: float = DETECTION_PROBABILITY,
                         false_alarm: float = 1e-3, period_min: float = PERIOD_MIN_RAD,
                         period_max: float = PERIOD_MAX_RAD) -> float:
    """Smallest deflection amplitude [rad] the run detects with ``probability`` (inf where it detects none:
    too short for three chunks, or the line beyond the Nyquist share)."""
    if line_frequency_hz(speed_rad_s, cycles_per_rev) > NYQUIST_SHARE * rate_hz / 2.0:
        return math.inf
    n, p_line = _threshold(travel_rad, false_alarm, period_min, period_max)
    if n < 3:
        return math.inf
    lam = optimize.brentq(lambda x: _power(x, n, p_line) - probability, 1e-9, 1e7)
    duration = travel_rad / abs(speed_rad_s)
    return math.sqrt(lam / _snr(1.0, duration, psd_rad2_hz))


def required_travel(amplitude_rad: float, speed_rad_s: float, psd_rad2_hz: float, rate_hz: float,
                    cycles_per_rev: float, probability: float = DETECTION_PROBABILITY, false_alarm: float = 1e-3,
                    longest_rad: float = 20.0, period_min: float = PERIOD_MIN_RAD,
                    period_max: float = PERIOD_MAX_RAD) -> float | None:
    """Shortest travel [rad] at ``speed_rad_s`` whose run detects ``amplitude_rad`` with ``probability``
    (None when no run up to ``longest_rad`` does)."""
    for travel in np.geomspace(0.05, longest_rad, 241):
        if detection_probability(amplitude_rad, float(travel), speed_rad_s, psd_rad2_hz, rate_hz, cycles_per_rev,
                                 false_alarm, period_min, period_max) >= probability:
            return float(travel)
    return None


def noise_psd(passes: list[Pass], frequency_hz: float, band: float = 0.3) -> float:
    """One-sided noise spectral density of the passes' deflection [rad^2/Hz] about ``frequency_hz``.

    Welch's estimate of each pass (in time), the median over ``frequency_hz * (1 +- band)`` and the passes,
    divided by the median of its chi-square law. The line itself is left out: the bins within three of Welch's
    resolution of ``frequency_hz`` (a Hann window's main lobe is two wide; on a short pass a 20 µrad line filled
    most of the band and was taken for noise), the band widened to three resolutions beyond them where it is
    narrower. NaN where no pass resolves the band.
    """
    values = []
    for p in passes:
        if len(p.t) < 64:
            continue
        fs = 1.0 / float(np.median(np.diff(p.t)))
        nper = int(min(len(p.f), max(64, 2 ** int(math.log2(len(p.f) / 4)))))
        f, pxx = signal.welch(p.f - np.mean(p.f), fs=fs, nperseg=nper)
        df = fs / nper
        away = np.abs(f - frequency_hz)
        sel = (away > 3.0 * df) & (away <= max(band * frequency_hz, 6.0 * df)) & (f > 0)
        if sel.sum() >= 3:
            segments = max(1, 2 * len(p.f) // nper - 1)
            dof = 2 * segments
            values.append(float(np.median(pxx[sel])) / (float(stats.chi2.median(dof)) / dof))
    return float(np.median(values)) if values else math.nan


@dataclass(kw_only=True)
class RunSensitivity:
    """What one run can detect: its longest pass, the noise at the line's frequency and the amplitudes."""

    dataset: int
    speed_rad_s: float
    travel_rad: float
    rate_hz: float
    cycles_per_rev: float
    psd_rad2_hz: float
    #: Amplitude the run detects with DETECTION_PROBABILITY [rad] (inf: none).
    detectable_rad: float
    #: The amplitude asked about [rad] and, where this run does not detect it, the travel [rad] at the fastest
    #: speed up to this run's that would (None: none up to 20 rad down to 0.02 rad/s), and that speed [rad/s].
    amplitude_rad: float
    required_travel_rad: float | None
    required_speed_rad_s: float | None = None
    #: The search's false-alarm probability the prediction is for.
    false_alarm: float = 1e-3
    #: Every pass of the run: its travel [rad] and speed [rad/s] (the pooled prediction's input).
    pass_travel_rad: list = field(default_factory=list)
    pass_speed_rad_s: list = field(default_factory=list)
    #: Motor positions all the search's passes span [rad]: it sets the chunks' length.
    span_rad: float = math.nan

    def to_json(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_json(cls, doc: dict) -> RunSensitivity:
        """The run's sensitivity from :meth:`to_json`'s dictionary (null numbers read as nan, inf where a
        detectable amplitude is none)."""
        out = dict(doc)
        for k in ("psd_rad2_hz", "span_rad"):
            out[k] = math.nan if out.get(k) is None else out[k]
        out["detectable_rad"] = math.inf if out.get("detectable_rad") is None else out["detectable_rad"]
        return cls(**out)

    def sentence(self, name: str) -> str:
        """One line for the console."""
        head = (f"{name} ({abs(self.speed_rad_s):.2f} rad/s over {self.travel_rad:.2f} rad at {self.rate_hz:.0f} Hz): ")
        if not math.isfinite(self.psd_rad2_hz):
            return head + "no noise level at the line's frequency; nothing predicted"
        if math.isfinite(self.detectable_rad):
            head += (f"detects {self.detectable_rad * 1e6:.3g} µrad at {self.cycles_per_rev:.0f} cycles per revolution "
                     f"with probability {DETECTION_PROBABILITY:g}")
        else:
            head += f"detects no line at {self.cycles_per_rev:.0f} cycles per revolution (too short or too fast)"
        if self.detectable_rad <= self.amplitude_rad:
            return head
        if self.required_travel_rad is None or self.required_speed_rad_s is None:
            return head + f"; no run up to 20 rad at this speed or slower detects {self.amplitude_rad * 1e6:.3g} µrad"
        return head + (f"; a {self.required_travel_rad:.2g} rad run at {self.required_speed_rad_s:.2f} rad/s "
                       f"({self.required_travel_rad / self.required_speed_rad_s:.2g} s) detects "
                       f"{self.amplitude_rad * 1e6:.3g} µrad with probability {DETECTION_PROBABILITY:g}")


def sensitivity(passes: list[Pass], cycles_per_rev: float, amplitude_rad: float, false_alarm: float = 1e-3,
                period_min: float = PERIOD_MIN_RAD, period_max: float = PERIOD_MAX_RAD) -> list[RunSensitivity]:
    """What each run (its longest pass) detects of a line at ``cycles_per_rev``, and what run would detect
    ``amplitude_rad`` [rad] where it does not; the noise is read off the run's passes (:func:`noise_psd`)."""
    out = []
    span = span_of(passes)
    for index in sorted({p.dataset for p in passes}):
        own = [p for p in passes if p.dataset == index]
        longest = max(own, key=lambda p: abs(p.theta[-1] - p.theta[0]))
        travel = float(abs(longest.theta[-1] - longest.theta[0]))
        speed = float(longest.speed)
        rate = 1.0 / float(np.median(np.diff(longest.t)))
        psd = noise_psd(own, line_frequency_hz(speed, cycles_per_rev))
        need, at = None, None
        if math.isfinite(psd) and psd > 0:
            search = dict(false_alarm=false_alarm, period_min=period_min, period_max=period_max)
            detectable = detectable_amplitude(travel, speed, psd, rate, cycles_per_rev, **search)
            # Too fast (the line beyond the Nyquist share) or too noisy at this speed: slower runs, the noise
            # taken as the one measured (its level at the slower run's line frequency is not known).
            for v in abs(speed) * 0.8 ** np.arange(40):
                if detectable <= amplitude_rad or v < 0.02:
                    break
                need = required_travel(amplitude_rad, float(v), psd, rate, cycles_per_rev, **search)
                if need is not None:
                    at = float(v)
                    break
        else:
            detectable = math.inf
        out.append(RunSensitivity(dataset=index, speed_rad_s=speed, travel_rad=travel, rate_hz=rate,
                                  cycles_per_rev=cycles_per_rev, psd_rad2_hz=psd, detectable_rad=detectable,
                                  amplitude_rad=amplitude_rad, required_travel_rad=need, required_speed_rad_s=at,
                                  false_alarm=false_alarm,
                                  pass_travel_rad=[float(abs(p.theta[-1] - p.theta[0])) for p in own],
                                  pass_speed_rad_s=[float(p.speed) for p in own], span_rad=span))
    return out


def pooled_detection_probability(amplitude_rad: float, runs: list[RunSensitivity],
                                 period_min: float = PERIOD_MIN_RAD, period_max: float = PERIOD_MAX_RAD) -> float:
    """Probability that the search over every pass of ``runs`` together detects a line of ``amplitude_rad``.

    The search pools the chunks of all passes: their signal-to-noise ratios add (each pass's from its
    duration and its run's noise level, as in :func:`detection_probability`), the chunks add to the
    Hotelling test's degrees of freedom, and its frequency grid is set by the positions all passes span.
    Passes whose line lies beyond the Nyquist share add nothing; runs without a noise level are left out.
    Chunks of unequal noise are taken as equal, and every chunk as seeing the line alike: where runs at
    different speeds see it with different amplitudes or phases (link dynamics, a filter before logging) and
    chunks are few, the search detects less than predicted (docs/ripple.md measures how much).
    """
    runs = [r for r in runs if math.isfinite(r.psd_rad2_hz) and r.psd_rad2_hz > 0 and r.pass_travel_rad]
    if not runs or amplitude_rad < 0:
        return 0.0
    span = max((r.span_rad for r in runs if math.isfinite(r.span_rad)), default=max(r.travel_rad for r in runs))
    lam, n = 0.0, 0
    for r in runs:
        for travel, speed in zip(r.pass_travel_rad, r.pass_speed_rad_s):
            if speed == 0 or travel <= 0 or \
                    line_frequency_hz(speed, r.cycles_per_rev) > NYQUIST_SHARE * r.rate_hz / 2.0:
                continue
            n += chunks_in(travel, min(period_max, travel / 2.0), span)
            lam += _snr(amplitude_rad, travel / abs(speed), r.psd_rad2_hz)
    if n < 3:
        return 0.0
    _, p_line = _threshold(span, runs[0].false_alarm, period_min, period_max)
    return _power(lam, n, p_line)
