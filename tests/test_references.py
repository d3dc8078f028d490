"""The reference vocabulary: one square wave, sine and exponential sweep, scalar and array alike."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
from scipy import signal

import iiwa_ident.references as references
from iiwa_ident.references import exponential_sweep, sine, square, sweep_rate


def test_doctests():
    assert doctest.testmod(references).failed == 0


def test_square_matches_scipy_and_the_scalar_path():
    t = np.arange(0.0, 3.0, 1e-3) + 1e-7  # off the edges, where the two conventions may round differently
    want = 2.5 * signal.square(2 * np.pi * t / 0.8)
    np.testing.assert_array_equal(square(t, 2.5, 0.8), want)
    np.testing.assert_array_equal([square(float(x), 2.5, 0.8) for x in t], want)


def test_sine_and_bias():
    t = np.linspace(0.0, 2.0, 101)
    np.testing.assert_allclose(sine(t, 3.0, 1.5, bias=-1.0), -1.0 + 3.0 * np.sin(3 * np.pi * t), rtol=0, atol=1e-14)
    assert sine(0.1, 3.0, 1.5) == pytest.approx(float(sine(np.array([0.1]), 3.0, 1.5)[0]), abs=1e-15)


def test_sweep_matches_scipy_logarithmic_chirp():
    t = np.arange(0.0, 4.0, 1e-3)
    want = signal.chirp(t, 0.5, 4.0, 200.0, method="logarithmic", phi=-90)
    np.testing.assert_allclose(exponential_sweep(t, 0.5, 200.0, 4.0), want, rtol=0, atol=1e-8)
    np.testing.assert_allclose([exponential_sweep(float(x), 0.5, 200.0, 4.0) for x in t[::97]], want[::97],
                               rtol=0, atol=1e-8)
    assert sweep_rate(1.0, np.e, 3.0) == pytest.approx(3.0, rel=1e-15)
