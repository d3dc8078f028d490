"""The reference signals of the toolkit, written once: square wave, sine, exponential sweep, odd multisine.

Experiments (:mod:`iiwa_ident.excite`), the FRI runtime's tasks, the
closed-loop analysis and the pipeline's validation all draw their
references from here, so a step or a chirp means the same signal in each.
Each function takes a time [s] as a float (the 1 kHz loop: plain float
arithmetic, no array) or an array, and returns the same kind.

Examples
--------
>>> square(0.2, 3.0, 1.0), square(0.7, 3.0, 1.0)
(3.0, -3.0)
>>> round(sine(0.25, 2.0, 1.0, bias=1.0), 12)
3.0
>>> round(float(exponential_sweep(0.0, 1.0, 100.0, 10.0)), 12)
0.0
"""

from __future__ import annotations

import math

import numpy as np

from iiwa_ident.errors import IiwaIdentError

__all__ = ["square", "sine", "sweep_rate", "exponential_sweep", "odd_lines", "crest_factor", "odd_multisine"]

_SCALAR = (int, float)


def square(t, amplitude: float, period_s: float):
    """Square wave between ``+amplitude`` and ``-amplitude``, ``+amplitude`` over the first half period.

    Parameters
    ----------
    t : float or array_like
        Time [s], from 0.
    amplitude : float
        Level [Nm].
    period_s : float
        Period [s].
    """
    if isinstance(t, _SCALAR):
        return amplitude if (t % period_s) < 0.5 * period_s else -amplitude
    return np.where(np.mod(np.asarray(t, float), period_s) < 0.5 * period_s, amplitude, -amplitude)


def sine(t, amplitude: float, frequency_hz: float, bias: float = 0.0):
    """``bias + amplitude sin(2 pi f t)`` [Nm] at time ``t`` [s]."""
    if isinstance(t, _SCALAR):
        return bias + amplitude * math.sin(2.0 * math.pi * frequency_hz * t)
    return bias + amplitude * np.sin(2.0 * np.pi * frequency_hz * np.asarray(t, float))


def sweep_rate(f0_hz: float, f1_hz: float, duration_s: float) -> float:
    """The exponential sweep's time constant ``L = T / ln(f1 / f0)`` [s]."""
    return duration_s / math.log(f1_hz / f0_hz)


def exponential_sweep(t, f0_hz: float, f1_hz: float, duration_s: float):
    """Unit-amplitude exponential sine sweep ``sin(2 pi f0 L (exp(t / L) - 1))`` from ``f0`` to ``f1`` [Hz].

    The instantaneous frequency is ``f0 exp(t / L)``: ``f1`` at ``t = duration_s``
    (:func:`sweep_rate`); beyond it the sweep goes on rising.
    """
    L = sweep_rate(f0_hz, f1_hz, duration_s)
    if isinstance(t, _SCALAR):
        return math.sin(2.0 * math.pi * f0_hz * L * math.expm1(t / L))
    return np.sin(2.0 * np.pi * f0_hz * L * np.expm1(np.asarray(t, float) / L))


def odd_lines(n_samples: int, sample_rate_hz: float, f_lo_hz: float, f_hi_hz: float) -> np.ndarray:
    """Odd line numbers ``k`` (frequency ``k fs / N``) within ``[f_lo, f_hi]``."""
    df = sample_rate_hz / n_samples
    k = np.arange(1, n_samples // 2, 2)
    f = k * df
    return k[(f >= f_lo_hz - 1e-9 * df) & (f <= f_hi_hz + 1e-9 * df)]


def crest_factor(x: np.ndarray) -> float:
    """``max |x - mean| / rms(x - mean)`` [-]."""
    x = np.asarray(x, float) - np.mean(x)
    return float(np.max(np.abs(x)) / np.sqrt(np.mean(x * x)))


def odd_multisine(n_samples: int, lines: np.ndarray, rng: np.random.Generator, *,
                  crest_iterations: int = 100) -> np.ndarray:
    """One period of a flat-spectrum multisine on ``lines`` with random phases, crest factor reduced.

    Parameters
    ----------
    n_samples : int
        Samples per period N.
    lines : array of int
        Excited line numbers, ``0 < k < N / 2``.
    rng : numpy.random.Generator
        Source of the random phases.
    crest_iterations : int
        Clipping iterations (0: plain random phases).

    Returns
    -------
    numpy.ndarray
        One period, zero mean, peak 1.

    Notes
    -----
    Clipping changes the phases only: the amplitude spectrum stays flat on
    ``lines`` and zero elsewhere (to rounding), so every period is exactly
    periodic and the excited lines are the only ones with power.
    """
    lines = np.asarray(lines, int)
    if len(lines) == 0 or lines.min() < 1 or lines.max() >= n_samples / 2:
        raise IiwaIdentError("multisine: no line in the band, or a line at DC or beyond Nyquist")
    X = np.zeros(n_samples // 2 + 1, complex)
    X[lines] = np.exp(2j * np.pi * rng.random(len(lines)))
    x = np.fft.irfft(X, n_samples)
    best, best_cf = x, crest_factor(x)
    for _ in range(crest_iterations):
        rms = np.sqrt(np.mean(x * x))
        # Clip at a level a little below the current peak, then put the flat spectrum back.
        level = 0.9 * np.max(np.abs(x)) if best_cf > 1.4 else 1.4 * rms
        Y = np.fft.rfft(np.clip(x, -level, level))
        X = np.zeros_like(X)
        X[lines] = np.exp(1j * np.angle(Y[lines]))
        x = np.fft.irfft(X, n_samples)
        cf = crest_factor(x)
        if cf < best_cf:
            best, best_cf = x, cf
    return best / np.max(np.abs(best))
