"""Spectral lines in a residual: a disturbance at fixed frequencies (a hum) among broadband content.

A chirp's response is spread over its band and a model's error follows it; a
disturbance periodic in time (mains hum, a PWM's or a rectifier's lines) puts
its power into a few periodogram cells. :func:`line_ratio` measures a cell
against its neighbours (the periodogram over its running median), the
quantity both the inverse-dynamics fit and the diagnosis search. A line's
sinusoid is fitted by least squares weighted per block
(:func:`block_weights`, :func:`fit_sinusoid`): a chirp passes a line's
frequency once and loudly, and the blocks where it does weigh little.

For white noise the periodogram over its median is about an exponential
variable over ``ln 2``: a ratio ``r`` is exceeded with probability
``exp(-r ln 2)`` per cell (``r = 50``: 8e-16).

Examples
--------
>>> import numpy as np
>>> t = np.arange(5000) * 1e-3
>>> x = np.random.default_rng(0).normal(size=t.size) + 0.3 * np.sin(2 * np.pi * 50.0 * t)
>>> r = line_ratio(x, 1e-3, np.array([30.0, 50.0, 70.0]))
>>> bool(r[1] > 50 > r[0]) and bool(r[2] < 50)
True
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

__all__ = ["line_ratio", "block_weights", "fit_sinusoid", "BACKGROUND_CELLS"]

#: Periodogram cells of the running median that stands for the background around a line.
BACKGROUND_CELLS = 41


def line_ratio(x: np.ndarray, dt: float, freqs: np.ndarray) -> np.ndarray:
    """Periodogram of ``x`` over its running median, at ``freqs`` [Hz] (linear interpolation).

    Parameters
    ----------
    x : ndarray
        Evenly sampled signal (its mean is removed; Hann window).
    dt : float
        Sample interval [s].
    freqs : ndarray
        Frequencies [Hz] at which the ratio is wanted.

    Returns
    -------
    ndarray
        The ratio (1 or so where there is no line).
    """
    x = np.asarray(x, float)
    w = (x - x.mean()) * np.hanning(len(x))
    spec = np.abs(np.fft.rfft(w)) ** 2
    f = np.fft.rfftfreq(len(w), dt)
    background = median_filter(spec, size=BACKGROUND_CELLS, mode="nearest") + 1e-30
    return np.interp(freqs, f, spec / background)


def block_weights(x: np.ndarray, block: np.ndarray) -> np.ndarray:
    """Per sample, the square root of the inverse of its block's mean power in ``x``.

    ``block``: each sample's block number (non-decreasing).
    """
    b = np.asarray(block) - block[0]
    power = np.bincount(b, weights=x * x) / np.maximum(np.bincount(b), 1)
    return np.sqrt(1.0 / np.maximum(power, 1e-12 * power.max() + 1e-300))[b]


def fit_sinusoid(x: np.ndarray, w: np.ndarray, t: np.ndarray, f: float) -> tuple[np.ndarray, float]:
    """Coefficients of ``sin(2 pi f t)`` and ``cos(2 pi f t)`` in ``x`` by least squares weighted by ``w``
    (``t`` [s], ``f`` [Hz]), and the weighted power they explain."""
    S = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)]) * w[:, None]
    coef = np.linalg.lstsq(S, x * w, rcond=None)[0]
    fit = S @ coef
    return coef, float(fit @ fit)
