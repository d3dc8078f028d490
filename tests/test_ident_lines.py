"""Spectral lines against a broadband background (:mod:`iiwa_ident.ident._lines`)."""

import math

import numpy as np
import pytest

from iiwa_ident.ident._lines import line_ratio


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_line_stands_out_of_white_noise_and_the_rest_does_not(seed):
    rng = np.random.default_rng(seed)
    dt = 1e-3
    t = np.arange(8000) * dt
    f0 = rng.uniform(20.0, 200.0)
    x = rng.normal(size=t.size) + 0.4 * np.sin(2 * np.pi * f0 * t + rng.uniform(-math.pi, math.pi))
    grid = np.arange(1.0, 450.0, 0.125)
    r = line_ratio(x, dt, grid)
    assert r[np.argmin(np.abs(grid - f0))] > 50.0
    # Away from the line the ratio is the periodogram's spread over its median: exponential over ln 2,
    # exceeding 50 with probability 1e-15 per cell.
    far = np.abs(grid - f0) > 0.5
    assert r[far].max() < 50.0
    assert np.median(r[far]) == pytest.approx(1.0, abs=0.15)


def test_a_chirp_is_no_line():
    # A sweep's power is spread over its band: no cell of it stands out of its neighbours.
    dt = 1e-3
    t = np.arange(10000) * dt
    f0, f1, T = 0.5, 150.0, t[-1]
    phase = 2 * np.pi * f0 * T / math.log(f1 / f0) * (np.exp(t / T * math.log(f1 / f0)) - 1.0)
    x = 5.0 * np.sin(phase) + np.random.default_rng(3).normal(scale=0.01, size=t.size)
    r = line_ratio(x, dt, np.arange(2.0, 140.0, 0.1))
    assert r.max() < 50.0
