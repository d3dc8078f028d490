"""Residual tests of a model against data: is what the model leaves white, and independent of the input?

Two tests, as an identification engineer runs them after every fit (Ljung, *System Identification*, 2nd
ed., section 16.6; the ``resid`` of MATLAB's System Identification Toolbox):

- **whiteness**: the residual's normalised autocorrelation ``r_ee(k)``, ``k = 1..M``; under "white" each is
  about normal with variance ``1/N``, and the Ljung-Box statistic ``Q = N (N + 2) sum r_ee(k)^2 / (N - k)``
  is chi-square with ``M`` degrees of freedom;
- **independence of the input**: the normalised cross-correlation ``r_eu(k)``, ``k = -M..M``; under "the
  residual is white and independent of the input" the vector ``sqrt(N) r_eu`` is normal with the input's
  normalised autocorrelation as its covariance (a Toeplitz matrix), so ``Q = N r' C^-1 r`` is chi-square with
  ``2M + 1`` degrees of freedom whatever the input's colour.

Each test's verdict is its chi-square test at the level (1 % by default: one false alarm in a hundred white
residuals, checked by simulation in the tests); the lags outside the per-lag bounds are listed for the
figure, as ``resid`` draws them (per lag, so some lags of a white residual fall outside by chance).

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> u = rng.normal(size=4000)
>>> residual_tests(rng.normal(size=4000), u).passed
True
>>> e = np.convolve(rng.normal(size=4000), np.ones(5) / 5, mode="same")  # a coloured residual
>>> residual_tests(e, u).tests[0].passed
False
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import linalg, stats

__all__ = ["MAX_LAG", "LEVEL", "WHITENESS", "INDEPENDENCE", "ResidualTest", "ResidualTests", "residual_tests"]

#: The tests' names.
WHITENESS = "whiteness"
INDEPENDENCE = "independence of the input"

#: Lags tested each way, as ``resid``'s default.
MAX_LAG = 25
#: Confidence level of the per-lag bounds and of the verdicts.
LEVEL = 0.99


@dataclass(kw_only=True)
class ResidualTest:
    """One test: its correlations at ``lags``, the per-lag bound, the lags outside it and the verdict.

    Attributes
    ----------
    name : str
        ``whiteness`` or ``independence of the input``.
    lags : numpy.ndarray
        Lags [samples].
    correlation : numpy.ndarray
        Normalised correlation at each lag (1 = identical).
    bound : numpy.ndarray
        Per-lag bound at the level (the band ``resid`` draws).
    failing : list of int
        Lags whose correlation lies outside its bound.
    statistic, dof, p_value : float
        The chi-square test of all lags together.
    passed : bool
        ``p_value`` at least ``1 - level``.
    """

    name: str
    lags: np.ndarray
    correlation: np.ndarray
    bound: np.ndarray
    failing: list[int]
    statistic: float
    dof: int
    p_value: float
    passed: bool

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "passed": self.passed, "p_value": self.p_value, "statistic": self.statistic,
                "dof": self.dof, "failing_lags": self.failing, "lags": self.lags.tolist(),
                "correlation": self.correlation.tolist(), "bound": self.bound.tolist()}


@dataclass
class ResidualTests:
    """The tests of one residual: ``passed`` when every test passes; ``n`` samples, ``level``."""

    n: int
    level: float
    tests: list[ResidualTest] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(t.passed for t in self.tests)

    def passed_test(self, name: str) -> bool | None:
        """Whether the test ``name`` passed (None when it was not run)."""
        return next((t.passed for t in self.tests if t.name == name), None)

    def summary(self) -> str:
        """One line: each test's verdict with its p-value and the lags that fail."""
        if not self.tests:
            return f"not tested ({self.n} samples: too few)"
        parts = []
        for t in self.tests:
            lags = "" if not t.failing else f", lags {_lags(t.failing)} outside the {100 * self.level:g} % bounds"
            parts.append(f"{t.name} {'passed' if t.passed else 'FAILED'} (p = {t.p_value:.2g}{lags})")
        return "; ".join(parts)

    def to_json(self) -> dict[str, Any]:
        return {"passed": self.passed, "n": self.n, "level": self.level, "tests": [t.to_json() for t in self.tests]}


def _lags(lags: list[int], most: int = 8) -> str:
    shown = ", ".join(str(k) for k in lags[:most])
    return shown + (f" (+{len(lags) - most} more)" if len(lags) > most else "")


def _correlation(a: np.ndarray, b: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation sum_t a(t) b(t - k) / sqrt(sum a^2 sum b^2) at each lag k."""
    n = len(a)
    scale = math.sqrt(float(a @ a) * float(b @ b)) or 1.0
    out = np.empty(len(lags))
    for i, k in enumerate(lags):
        out[i] = (a[k:] @ b[:n - k] if k >= 0 else a[:n + k] @ b[-k:]) / scale
    return out


def residual_tests(residual: np.ndarray, u: np.ndarray | None = None, max_lag: int = MAX_LAG,
                   level: float = LEVEL) -> ResidualTests:
    """Whiteness of ``residual`` and its independence of the input ``u`` (see the module docstring).

    Parameters
    ----------
    residual : array
        Measured minus predicted output, uniformly sampled (its mean is removed).
    u : array, optional
        The input, same samples (its mean is removed); without it only whiteness is tested.
    max_lag : int
        Lags tested each way [samples].
    level : float
        Confidence level of the bounds and verdicts (0.99: a white residual fails 1 % of the time).

    Returns
    -------
    ResidualTests

    Raises
    ------
    ValueError
        Fewer than ``4 max_lag`` samples, or ``u`` of another length.

    Examples
    --------
    A residual that still holds the input three samples late fails independence at lag 3:

    >>> rng = np.random.default_rng(0)
    >>> u, e = rng.normal(size=4000), rng.normal(size=4000)
    >>> [t.passed for t in residual_tests(e, u).tests]
    [True, True]
    >>> late = residual_tests(e + 0.5 * np.roll(u, 3), u).tests[1]
    >>> late.passed, late.failing
    (False, [3])
    """
    e = np.asarray(residual, float)
    e = e - e.mean()
    n = len(e)
    if n < 4 * max_lag:
        raise ValueError(f"residual tests need at least {4 * max_lag} samples, got {n}")
    z = stats.norm.ppf(0.5 + level / 2)
    out = ResidualTests(n=n, level=level)
    lags = np.arange(1, max_lag + 1)
    r = _correlation(e, e, lags)
    q = float(n * (n + 2) * np.sum(r ** 2 / (n - lags)))
    p = float(stats.chi2.sf(q, max_lag))
    bound = np.full(max_lag, z / math.sqrt(n))
    out.tests.append(ResidualTest(name=WHITENESS, lags=lags, correlation=r, bound=bound,
                                  failing=[int(k) for k in lags[np.abs(r) > bound]], statistic=q, dof=max_lag,
                                  p_value=p, passed=p >= 1 - level))
    if u is not None:
        x = np.asarray(u, float)
        if len(x) != n:
            raise ValueError(f"the input has {len(x)} samples, the residual {n}")
        x = x - x.mean()
        lags2 = np.arange(-max_lag, max_lag + 1)
        r2 = _correlation(e, x, lags2)
        # Under H0 the covariance of sqrt(N) r_eu is the input's normalised autocorrelation (Toeplitz).
        ruu = np.r_[1.0, _correlation(x, x, np.arange(1, 2 * max_lag + 1))]
        cov = linalg.toeplitz(ruu)
        try:
            q2 = float(n * r2 @ linalg.solve(cov, r2, assume_a="pos"))
        except (linalg.LinAlgError, ValueError):
            q2 = float(n * r2 @ np.linalg.pinv(cov) @ r2)
        dof = len(lags2)
        p2 = float(stats.chi2.sf(q2, dof))
        bound2 = np.full(dof, z / math.sqrt(n))
        out.tests.append(ResidualTest(name=INDEPENDENCE, lags=lags2, correlation=r2, bound=bound2,
                                      failing=[int(k) for k in lags2[np.abs(r2) > bound2]], statistic=q2, dof=dof,
                                      p_value=p2, passed=p2 >= 1 - level))
    return out
