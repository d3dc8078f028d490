"""The best linear approximation from multisines: exact on linear systems, honest variances, nonlinearity seen."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import freqz, lfilter

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import Multisine, record
from iiwa_ident.ident._bla import BestLinearApproximation, best_linear_approximation, bla_from_arrays
from iiwa_ident.references import odd_lines, odd_multisine
from iiwa_ident.sim import SimulatedJoint, default_plant

N, FS = 256, 1000.0
LINES = odd_lines(N, FS, 10.0, 300.0)


def _system(rng):
    """A random stable second-order resonance (b, a)."""
    r, th = rng.uniform(0.8, 0.95), rng.uniform(0.3, 1.5)
    a = np.array([1.0, -2 * r * np.cos(th), r * r])
    return np.array([rng.uniform(0.2, 1.0), rng.uniform(-0.5, 0.5)]), a


def _experiment(b, a, M, P, rng, noise=0.0, cubic=0.0):
    """u, y of shape (M, P, N) in steady state (one transient period run and dropped)."""
    u_all, y_all = [], []
    for _ in range(M):
        x = odd_multisine(N, LINES, rng)
        u = np.tile(x, P + 1)
        v = lfilter(b, a, u)
        y = v + cubic * v**3 + noise * rng.standard_normal(len(u))
        u_all.append(u.reshape(P + 1, N)[1:])
        y_all.append(y.reshape(P + 1, N)[1:])
    return np.array(u_all), np.array(y_all)[None]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_on_a_linear_noiseless_system(seed):
    rng = np.random.default_rng(seed)
    b, a = _system(rng)
    u, y = _experiment(b, a, 3, 2, rng)
    bla = bla_from_arrays(u, y, LINES, N / FS)
    _, h = freqz(b, a, worN=bla.f_hz, fs=FS)
    # The transient period is not exactly zero for a lightly damped pole; 1e-6 relative is far below any noise.
    np.testing.assert_allclose(bla.G[0], h, rtol=1e-6, atol=0)
    assert np.all(bla.var_total[0] < 1e-10 * np.abs(h) ** 2)


def test_variances_hold_their_promise_by_monte_carlo():
    # Noise only: the BLA's spread over 200 experiments matches the variance the method reports, and the
    # total and the noise variance agree (no nonlinear distortion).
    rng = np.random.default_rng(7)
    b, a = _system(rng)
    runs = [bla_from_arrays(*_experiment(b, a, 4, 3, rng, noise=0.05), LINES, N / FS) for _ in range(200)]
    G = np.array([r.G[0] for r in runs])
    empirical = np.mean(np.abs(G - G.mean(axis=0)) ** 2, axis=0)
    total = np.mean([r.var_total[0] for r in runs], axis=0)
    noise = np.mean([r.var_noise[0] for r in runs], axis=0)
    ratio_t, ratio_n = np.median(total / empirical), np.median(noise / empirical)
    assert 0.8 < ratio_t < 1.25 and 0.8 < ratio_n < 1.25, (ratio_t, ratio_n)


def test_a_static_nonlinearity_shows_as_nonlinear_variance():
    rng = np.random.default_rng(3)
    b, a = _system(rng)
    u, y = _experiment(b, a, 8, 2, rng, noise=0.01, cubic=0.5)
    bla = bla_from_arrays(u, y, LINES, N / FS)
    assert np.median(bla.var_nonlinear[0] / bla.var_noise[0]) > 10.0
    u, y = _experiment(b, a, 8, 2, rng, noise=0.01)
    linear = bla_from_arrays(u, y, LINES, N / FS)
    assert np.median(linear.var_nonlinear[0] / linear.var_noise[0]) < 2.0


def test_dataset_from_the_simulated_joint():
    exp = Multisine(2.0, 80.0, period_s=0.5, periods=2, realisations=3, amplitude_nm=8.0, seed=1)
    ds = record(SimulatedJoint(default_plant(), seed=2), exp)
    bla = best_linear_approximation(ds)
    assert bla.outputs == ("tau_j", "q_m") and bla.G.shape == (2, len(exp.design(1e-3)[0]))
    assert np.all(np.isfinite(bla.G)) and np.all(bla.var_total >= 0) and np.all(bla.var_noise > 0)
    # Below the joint's resonance (about 23 Hz) tau_j follows tau_c: |G| near 1 at the lowest lines.
    assert 0.5 < abs(bla.G[0, 0]) < 2.0
    rows = bla.bands(np.array([2.0, 8.0, 32.0, 80.0]))
    assert {r["output"] for r in rows} == {"tau_j", "q_m"} and all(r["lines"] > 0 for r in rows)


def test_refuses_what_is_not_a_multisine():
    from iiwa_ident.excite import Chirp

    ds = record(SimulatedJoint(default_plant()), Chirp(duration_s=1.0))
    with pytest.raises(IiwaIdentError, match="a chirp dataset, not a multisine"):
        best_linear_approximation(ds)
    with pytest.raises(IiwaIdentError, match="at least 2 realisations"):
        bla_from_arrays(np.ones((1, 2, N)), np.ones((1, 1, 2, N)), LINES, N / FS)


class TestFitBla:
    @pytest.mark.parametrize("seed", [0, 1])
    def test_recovers_a_random_joint_within_its_std(self, seed):
        # A random truth within +-40 % of Table I on a joint the model describes exactly (no ripple, no
        # friction): every parameter within 3 std, and chi2/dof near 1 (the weights are the BLA's variance).
        from iiwa_ident.ident._bla import fit_bla

        rng = np.random.default_rng(100 + seed)
        plant = default_plant().without_effects()
        truth = {k: v * rng.uniform(0.6, 1.4) for k, v in plant.dynamics.items() if k in ("Jc", "bc", "K", "Jl")}
        truth["Td"] = float(rng.choice([3e-3, 4e-3, 5e-3, 6e-3]))  # the simulator realises whole substeps
        plant.dynamics.update(truth)  # a fresh copy: without_effects() deep-copies
        exp = Multisine(1.0, 100.0, period_s=2.0, periods=2, realisations=4, amplitude_nm=10.0, seed=seed)
        fit = fit_bla(best_linear_approximation(record(SimulatedJoint(plant, seed=seed), exp)), 1e-3)
        assert 0.7 < fit.chi2_dof < 1.4
        for k, v in truth.items():
            assert abs(fit.parameters[k] - v) <= 3.0 * fit.std[k], (k, fit.parameters[k], v, fit.std[k])
            if k != "Td":
                assert fit.std[k] < 0.02 * v


def test_sampled_response_is_the_fit_models_and_adds_the_link_terms():
    from iiwa_ident.ident._bla import sampled_response
    from iiwa_ident.model import discretize

    p = {"Jc": 1.03, "bc": 55.0, "K": 18000.0, "Jl": 5.6, "Td": 0.0053}
    f = np.linspace(0.5, 400.0, 60)
    np.testing.assert_allclose(sampled_response(p, f, 1e-3), discretize(p, 1e-3).frequency_response(f),
                               rtol=1e-10, atol=0)
    # A stiff link spring: far below the resonance, q_m / tau_j tends to 1/K + 1/kl (a static deflection).
    stiff = sampled_response({**p, "kl": 500.0, "bl": 0.0}, np.array([0.01]), 1e-3)
    assert (stiff[1] / stiff[0])[0] == pytest.approx(1 / 18000.0 + 1 / 500.0, rel=1e-3)


def test_warnings_name_a_misfit_and_a_nonlinear_band():
    from iiwa_ident.ident._bla import BlaFit

    f = np.array([1.0, 2.0, 3.0, 5.0])
    G = np.ones((2, 4), complex)
    bla = BestLinearApproximation(f_hz=f, lines=np.arange(4), outputs=("tau_j", "q_m"), G=G,
                                  var_total=np.array([[1e-6, 1e-6, 0.05, 0.05], [1e-6] * 4]),
                                  var_noise=np.full((2, 4), 1e-6), realisations=4, periods=2)
    fit = BlaFit(parameters={}, std={}, covariance=np.eye(5), chi2_dof=5.0, blas=[bla], labels=["ms.h5"])
    w = fit.warnings()
    assert any("chi2/dof 5" in x for x in w)
    assert any("not linear in 2-4 Hz" in x for x in w) and not any("1-2 Hz" in x for x in w)
    quiet = BlaFit(parameters={}, std={}, covariance=np.eye(5), chi2_dof=1.0,
                   blas=[BestLinearApproximation(f_hz=f, lines=np.arange(4), outputs=("tau_j", "q_m"), G=G,
                                                 var_total=np.full((2, 4), 1e-6), var_noise=np.full((2, 4), 1e-6),
                                                 realisations=4, periods=2)], labels=["ms.h5"])
    assert quiet.warnings() == []
