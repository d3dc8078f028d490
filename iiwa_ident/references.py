"""The reference signals of the toolkit, written once: square wave, sine, exponential sweep.

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

__all__ = ["square", "sine", "sweep_rate", "exponential_sweep"]

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
