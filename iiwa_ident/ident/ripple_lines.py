"""A given spatial line tested in a given run: the cross-run evidence of the ripple search.

A run's own search (:func:`~iiwa_ident.ident.ripple_spectrum.line_search`) looks at every frequency and pays
for it in its false-alarm probability; a line that another run predicts is tested at that one frequency,
far more sensitively. :func:`line_test` does it: the Hann-tapered Fourier coefficient of the run's
deflection ``f`` at ``k`` [cycles/rad] of the motor position, pooled over the run's passes (a position-periodic
deflection is phase-locked to ``theta_m`` whatever the direction), against the same coefficient at
:data:`NEIGHBOURS` frequencies two resolution cells apart on both sides. Their median stands for the local
noise level: it follows coloured noise (the dynamic method's torque-integrated term rises as 1/f^2; a
torque filtered before logging falls), a median of a monotone spectrum over a symmetric set being its value at
the centre, and a temporal line among the neighbours moves it little. Under "no line" the ratio
``S = |c|^2 / (median / ln 2)`` is exceeded with about the probability of an F(2, J) law, J neighbours (a
Monte Carlo of exponential powers puts the true tail at 0.5-0.9 times that: conservative).

A candidate's frequency is known only to its std (or to a resolution cell of the run it came from), so ``k``
is searched over a window of that width, and the probability corrected for the independent cells in it.

Examples
--------
>>> import numpy as np
>>> from iiwa_ident.ident.ripple_passes import Pass
>>> rng = np.random.default_rng(1)
>>> theta = 0.5 * np.arange(4000) / 1000.0                    # 0.5 rad/s for 4 s at 1 kHz
>>> f = 2e-6 * np.sin(2 * np.pi * 51.0 * theta) + 2e-6 * rng.standard_normal(theta.size)
>>> p = Pass(0, "dynamic", 0.5, theta, f, theta / 0.5, f, np.ones((theta.size, 1)) / 63.25, 0.2)
>>> line_test([p], 51.0, 1000.0).p_value < 1e-6, line_test([p], 37.0, 1000.0).p_value > 1e-3
(True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from iiwa_ident.ident.ripple_passes import Pass
from iiwa_ident.ident.ripple_spectrum import taper

__all__ = ["NEIGHBOURS", "LineTest", "line_test"]

#: Neighbouring frequencies (half on each side) whose median coefficient power is the local noise level.
NEIGHBOURS = 24
#: Spacing of the neighbours and their nearest distance to the line, in resolution cells (1 / travel):
#: a Hann-tapered line leaks over +-2 cells, coefficients 2 cells apart are nearly uncorrelated.
_SPACING_CELLS = 2.0
_GAP_CELLS = 4.0
#: Highest tested frequency as a share of the run's Nyquist limit (beyond it a line may be an alias).
NYQUIST_SHARE = 0.9


@dataclass(frozen=True)
class LineTest:
    """A line's test in one run.

    Attributes
    ----------
    k : float
        The tested spatial frequency (the strongest in the window) [cycles/rad].
    amplitude_rad : float
        Amplitude of the deflection's sine at ``k`` [rad] (0 when not tested).
    amplitude_std_rad : float
        Its standard error from the local noise level [rad] (inf when not tested).
    p_value : float
        Probability that noise alone gives a line this strong in the window (1 when not tested).
    frequency_hz : float
        The line's temporal frequency at the run's median speed, ``k |v|`` [Hz].
    reason : str
        Why the line was not tested ('' when it was): beyond the Nyquist limit, too slow for the passes'
        high-pass, or too few neighbouring frequencies.
    """

    k: float
    amplitude_rad: float
    amplitude_std_rad: float
    p_value: float
    frequency_hz: float
    reason: str = ""

    @property
    def tested(self) -> bool:
        return not self.reason


def _coefficients(passes: list[Pass], ks: np.ndarray) -> np.ndarray:
    """The passes' pooled Hann-tapered Fourier coefficients of ``f`` at ``ks`` [cycles/rad], scaled to a sine's
    amplitude."""
    num = np.zeros(len(ks), dtype=complex)
    den = 0.0
    for p in passes:
        w = taper(len(p.f))
        x = (p.f - np.average(p.f, weights=w)) * w
        num += np.exp(-2j * np.pi * np.outer(ks, p.theta)) @ x
        den += w.sum()
    return 2.0 * num / max(den, 1e-300)


def line_test(passes: list[Pass], k: float, rate_hz: float, k_std: float = 0.0) -> LineTest:
    """Test the run's passes for a line at ``k +- 3 k_std`` [cycles/rad] (module docstring).

    Parameters
    ----------
    passes : list of Pass
        One run's passes (one speed).
    k : float
        The line's spatial frequency [cycles/rad] (``1 / period``).
    rate_hz : float
        The run's sample rate [Hz]: lines above :data:`NYQUIST_SHARE` of its Nyquist limit are not tested.
    k_std : float
        Standard error of ``k`` [cycles/rad]; the window is at least half a resolution cell each side.

    Returns
    -------
    LineTest
    """
    speed = float(np.median([abs(p.speed) for p in passes])) if passes else 0.0
    f_hz = k * speed
    if not passes:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "no passes")
    travel = float(np.median([abs(p.theta[-1] - p.theta[0]) for p in passes]))
    cell = 1.0 / max(travel, 1e-12)
    half = max(0.5 * cell, 3.0 * k_std)
    step = cell * _SPACING_CELLS
    k_low = max(1.0 / p.period_max for p in passes)
    k_high = NYQUIST_SHARE * 0.5 * rate_hz / max(speed, 1e-12)
    if k + half > k_high:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, f"beyond {NYQUIST_SHARE:.0%} of the Nyquist limit "
                                                     f"({f_hz:.1f} Hz at {speed:.2f} rad/s)")
    if k - half < k_low:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "longer than the passes resolve")
    j = np.arange(1, NEIGHBOURS // 2 + 1)
    offsets = half + _GAP_CELLS * cell - step + step * j
    nb = np.concatenate([k - offsets, k + offsets])
    nb = nb[(nb >= k_low) & (nb <= k_high)]
    if len(nb) < NEIGHBOURS // 3:
        return LineTest(k, 0.0, math.inf, 1.0, f_hz, "too few neighbouring frequencies to tell its noise level")
    cells = 1 + int(math.ceil(2.0 * half / cell))
    window = k + np.linspace(-half, half, 4 * cells + 1)
    c = _coefficients(passes, np.concatenate([window, nb]))
    power = np.abs(c[:len(window)]) ** 2
    level = float(np.median(np.abs(c[len(window):]) ** 2)) / math.log(2.0)
    i = int(np.argmax(power))
    s = float(power[i]) / max(level, 1e-300)
    p1 = float(stats.f.sf(s, 2, len(nb)))
    p = float(min(1.0, -math.expm1(cells * math.log1p(-min(p1, 1.0 - 1e-16)))))
    return LineTest(float(window[i]), float(math.sqrt(power[i])), math.sqrt(level / 2.0), p, float(window[i]) * speed)
