"""Residual tests: the false-alarm rate on white residuals is the level's, coloured or input-dependent residuals
fail, checked by simulation."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
from scipy import signal, stats

from iiwa_ident.ident import _resid as resid
from iiwa_ident.ident import residual_tests


def _ar1(rng, n, a):
    return signal.lfilter([1.0], [1.0, -a], rng.normal(size=n))


@pytest.mark.parametrize("input_colour", [0.0, 0.9])
def test_white_residuals_fail_one_time_in_a_hundred(input_colour):
    # 600 white residuals against a white or strongly coloured input independent of them: each test's
    # false alarms lie within the binomial 99.9 % limits of 1 %.
    rng = np.random.default_rng(7 if input_colour else 8)
    draws, n = 600, 2000
    fails = np.zeros(2, int)
    for _ in range(draws):
        res = residual_tests(rng.normal(size=n), _ar1(rng, n, input_colour))
        fails += [not t.passed for t in res.tests]
    lo, hi = stats.binom.ppf([0.0005, 0.9995], draws, 0.01)
    assert lo <= fails[0] <= hi and lo <= fails[1] <= hi, fails


def test_coloured_or_input_dependent_residuals_fail():
    rng = np.random.default_rng(9)
    n = 3000
    u = _ar1(rng, n, 0.5)
    coloured = _ar1(rng, n, 0.3)
    res = residual_tests(coloured, u)
    assert not res.tests[0].passed and res.tests[1].passed
    assert 1 in res.tests[0].failing
    # A residual that carries the input three samples late (a model with the wrong delay).
    e = rng.normal(size=n) + 0.3 * np.r_[np.zeros(3), u[:-3]]
    res = residual_tests(e, u)
    assert not res.tests[1].passed and 3 in res.tests[1].failing, res.tests[1].failing
    assert "independence of the input FAILED" in res.summary() and "lags" in res.summary()


def test_analytic_correlations():
    # A residual equal to the input: whiteness of a white input passes, the cross-correlation is 1 at lag 0.
    rng = np.random.default_rng(1)
    u = rng.normal(size=1000)
    res = residual_tests(u, u, max_lag=5)
    t = res.tests[1]
    np.testing.assert_allclose(t.correlation[t.lags == 0], 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(t.bound, stats.norm.ppf(0.995) / np.sqrt(1000), rtol=1e-12)
    assert res.tests[0].dof == 5 and t.dof == 11
    with pytest.raises(ValueError, match="at least 100 samples"):
        residual_tests(np.zeros(50))


def test_doctests():
    assert doctest.testmod(resid).failed == 0
