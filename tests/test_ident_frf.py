"""Non-parametric FRF: Welch H1 with uncertainty, and the exponential-sweep deconvolution.

Reference cases are analytic: H1 of a known discrete filter driven by white
noise, and the harmonics of a static polynomial driven by the sweep
(``x^2 = A^2/2 (1 - cos 2phi)``, ``x^3 = A^3/4 (3 sin phi - sin 3phi)``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import freqz, lfilter

from iiwa_ident.ident._frf import (
    cross_spectra,
    ess_harmonics,
    h1_estimate,
    log_bands,
    multi_resolution_spectra,
    nonlinear_share,
    octave_bands,
    sweep_signal,
    welch_segment_length,
)
from iiwa_ident.references import exponential_sweep, sweep_rate

FS = 1000.0
B, A = [0.05, 0.03], [1.0, -1.6, 0.7]  # a resonant discrete filter (poles at 0.84 e^{+-j0.31})


def filter_response(f_hz):
    return freqz(B, A, worN=2 * np.pi * np.asarray(f_hz) / FS)[1]


def noisy_filter_data(seed, n=30000, noise=0.2):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    return u, lfilter(B, A, u) + noise * rng.standard_normal(n)


class TestWelchSegmentLength:
    def test_resolves_a_quarter_of_f0(self):
        nper = welch_segment_length(30000, FS, 0.5)
        assert nper == 8192
        assert FS / nper <= 0.5 / 4

    def test_capped_by_record(self):
        assert welch_segment_length(3000, FS, 0.5) == 3000


class TestCrossSpectra:
    def test_segments_tile_the_whole_record(self):
        # A burst in the last 50 samples must be seen although 30000 is no multiple of the hop.
        u = np.zeros(30000)
        u[-50:] = 1.0
        sp = cross_spectra(u, u, FS, 8192)
        assert sp.n_segments == 7
        assert sp.puu[1:].sum() > 0

    def test_output_shapes(self):
        u, y = noisy_filter_data(0, n=5000)
        sp = cross_spectra(u, np.vstack([y, 2 * y]), FS, 1024)
        assert sp.pyy.shape == (2, 513) and sp.puy.shape == (2, 513)
        np.testing.assert_allclose(sp.puy[1], 2 * sp.puy[0], rtol=1e-12, atol=0)

    def test_multi_resolution_lengths(self):
        u, y = noisy_filter_data(0, n=30000)
        lengths = [sp.nperseg for sp in multi_resolution_spectra(u, y, FS, 0.5)]
        assert lengths == [8192, 2048]


class TestBands:
    def test_log_bands_cover_range(self):
        edges = log_bands(0.5, 200.0, 12)
        assert edges[0] == pytest.approx(0.5, rel=1e-12, abs=0)
        assert edges[-1] == pytest.approx(200.0, rel=1e-12, abs=0)
        np.testing.assert_allclose(np.diff(np.log2(edges)), np.log2(400) / (len(edges) - 1), rtol=1e-9, atol=0)

    def test_octaves(self):
        bands = octave_bands(0.5, 200.0)
        assert bands[0] == (0.5, 1.0) and bands[-1] == (128.0, 200.0)
        assert len(bands) == 9

    def test_sliver_folds_into_last_octave(self):
        bands = octave_bands(1.0, 8.5)
        assert bands[-1] == (4.0, 8.5)


class TestH1Estimate:
    def test_noise_free_matches_filter(self):
        u, _ = noisy_filter_data(1)
        y = lfilter(B, A, u)
        est = h1_estimate(u, y, FS, 0.5, 200.0)
        expected = est.band_average(filter_response)
        # Only leakage of the filter's memory at segment ends remains.
        np.testing.assert_allclose(est.H, expected, rtol=5e-3, atol=0)
        assert est.coherence.min() > 0.998

    def test_error_within_reported_uncertainty(self):
        u, y = noisy_filter_data(2)
        est = h1_estimate(u, y, FS, 0.5, 200.0, per_octave=6)
        z = np.abs(est.H - est.band_average(filter_response)) / est.std_complex
        assert np.sqrt(np.mean(z**2)) < 1.5
        assert z.max() < 4.5

    def test_uncertainty_calibrated_by_monte_carlo(self):
        # The std formula from coherence and averages against the spread over 60 noise draws.
        H, std_mag, std_ph = [], [], []
        for seed in range(60):
            u, y = noisy_filter_data(100 + seed)
            est = h1_estimate(u, y, FS, 1.0, 200.0, per_octave=3)
            H.append(est.H)
            std_mag.append(est.std_mag)
            std_ph.append(est.std_phase_rad)
        H = np.array(H)
        truth = est.band_average(filter_response)
        ratio_mag = np.std(np.abs(H), axis=0) / np.mean(std_mag, axis=0)
        ratio_ph = np.std(np.angle(H / truth), axis=0) / np.mean(std_ph, axis=0)
        np.testing.assert_allclose(np.median(ratio_mag), 1.0, rtol=0.2, atol=0)
        np.testing.assert_allclose(np.median(ratio_ph), 1.0, rtol=0.2, atol=0)
        assert ratio_mag.max() < 1.6 and ratio_mag.min() > 0.6

    def test_band_average_of_constant(self):
        u, y = noisy_filter_data(3, n=8000)
        est = h1_estimate(u, y, FS, 1.0, 100.0)
        np.testing.assert_allclose(est.band_average(lambda f: np.full(len(f), 2.0 + 1.0j)), 2.0 + 1.0j,
                                   rtol=1e-12, atol=0)

    def test_select_keeps_bins_consistent(self):
        u, y = noisy_filter_data(4, n=8000)
        est = h1_estimate(u, y, FS, 1.0, 100.0)
        mask = est.coherence > 0
        mask[::2] = False
        sub = est.select(mask)
        np.testing.assert_allclose(sub.band_average(filter_response), est.band_average(filter_response)[mask],
                                   rtol=1e-12, atol=0)

    def test_pure_gain_and_delay(self):
        # y[k] = 0.5 u[k-3]: |H| = 0.5 and the phase is -3 samples of delay.
        rng = np.random.default_rng(5)
        u = rng.standard_normal(20000)
        y = 0.5 * np.concatenate([np.zeros(3), u[:-3]])
        response = lambda f: 0.5 * np.exp(-2j * np.pi * f * 3 / FS)  # noqa: E731  (a one-line helper)
        plain = h1_estimate(u, y, FS, 2.0, 300.0)
        # Pooling turns phasors: the band average of the true response is what H1 estimates.
        np.testing.assert_allclose(plain.H, plain.band_average(response), rtol=2e-3, atol=0)
        assert np.abs(plain.H).min() < 0.499
        # With the delay as reference the pooled estimate is the response itself.
        est = h1_estimate(u, y, FS, 2.0, 300.0, delay_s=3 / FS)
        np.testing.assert_allclose(est.H, response(est.f_mean_hz), rtol=2e-3, atol=0)
        np.testing.assert_allclose(est.band_average(response), response(est.f_mean_hz), rtol=1e-9, atol=0)
        assert est.coherence.min() > 0.999


class TestSweepSignal:
    def test_matches_the_excitation_module(self):
        t = np.arange(3000) / FS
        np.testing.assert_allclose(sweep_signal(3000, FS, 0.5, 200.0, 3.0, 2.0),
                                   2.0 * exponential_sweep(t, 0.5, 200.0, 3.0), rtol=0, atol=1e-12)

    def test_zero_after_end(self):
        x = sweep_signal(4000, FS, 1.0, 100.0, 3.0)
        assert np.all(x[3000:] == 0.0)


def polynomial_case(a2=0.1, a3=0.05, amplitude=2.0, duration=30.0, f0=0.5, f1=200.0):
    n = int(duration * FS)
    x = sweep_signal(n, FS, f0, f1, duration, amplitude)
    return x, x + a2 * x**2 + a3 * x**3


class TestEssHarmonics:
    def test_static_polynomial_harmonic_amplitudes(self):
        a2, a3, A = 0.1, 0.05, 2.0
        _, y = polynomial_case(a2, a3, A)
        h = ess_harmonics(y, FS, 0.5, 200.0, 30.0, A, n_harmonics=5)
        f = np.geomspace(3.0, 35.0, 20)  # inside the sweep for all five harmonics
        np.testing.assert_allclose(np.abs(h.at_input(1, f)), 1 + 0.75 * a3 * A**2, rtol=1e-2, atol=0)
        np.testing.assert_allclose(np.abs(h.at_input(2, f)), a2 * A / 2, rtol=1e-2, atol=0)
        np.testing.assert_allclose(np.abs(h.at_input(3, f)), a3 * A**2 / 4, rtol=1e-2, atol=0)
        np.testing.assert_allclose(np.abs(h.at_input(4, f)), 0.0, rtol=0, atol=1e-3)
        np.testing.assert_allclose(np.abs(h.at_input(5, f)), 0.0, rtol=0, atol=1e-3)

    def test_harmonic_delays(self):
        L = sweep_rate(0.5, 200.0, 30.0)
        h = ess_harmonics(polynomial_case()[1], FS, 0.5, 200.0, 30.0, 2.0, n_harmonics=4)
        np.testing.assert_allclose(h.delays_s, -L * np.log([1, 2, 3, 4]), rtol=1e-12, atol=0)

    def test_linear_filter_has_no_harmonics(self):
        x = sweep_signal(30000, FS, 0.5, 200.0, 30.0, 3.0)
        y = lfilter(B, A, x)
        h = ess_harmonics(y, FS, 0.5, 200.0, 30.0, 3.0)
        f = np.geomspace(3.0, 30.0, 15)  # the band edge's ringing is cut by the window closer to f0
        np.testing.assert_allclose(h.at_input(1, f), filter_response(f), rtol=1e-2, atol=0)
        for k in (2, 3):
            assert np.abs(h.at_input(k, f)).max() < 1e-3

    def test_outside_sweep_is_nan(self):
        h = ess_harmonics(polynomial_case()[1], FS, 0.5, 200.0, 30.0, 2.0)
        assert np.isnan(h.at_input(2, np.array([150.0]))[0])
        assert np.isfinite(h.at_input(2, np.array([50.0]))[0])


class TestNonlinearShare:
    def test_polynomial_share_matches_theory(self):
        a2, a3, A = 0.1, 0.05, 2.0
        _, y = polynomial_case(a2, a3, A)
        bands = nonlinear_share(ess_harmonics(y, FS, 0.5, 200.0, 30.0, A))
        p1, p2, p3 = (1 + 0.75 * a3 * A**2) ** 2, (a2 * A / 2) ** 2, (a3 * A**2 / 4) ** 2
        expected = (p2 + p3) / (p1 + p2 + p3)
        for b in bands:
            if b.lo_hz >= 2.0 and b.harmonics == [1, 2, 3, 4, 5]:
                assert b.share == pytest.approx(expected, rel=0.03, abs=0)
                assert b.harmonic_share[1] == pytest.approx(p2 / (p1 + p2 + p3), rel=0.03, abs=0)

    def test_unmeasurable_harmonics_are_reported(self):
        bands = nonlinear_share(ess_harmonics(polynomial_case()[1], FS, 0.5, 200.0, 30.0, 2.0))
        top = bands[-1]
        assert top.harmonics == [1] and math.isnan(top.share)
        assert bands[-3].harmonics == [1, 2, 3]  # 32-64 Hz: up to 3 x 64 = 192 Hz < f1

    def test_linear_system_share_is_small(self):
        rng = np.random.default_rng(7)
        x = sweep_signal(30000, FS, 0.5, 200.0, 30.0, 5.0)
        y = lfilter(B, A, x) + 0.02 * rng.standard_normal(30000)
        bands = nonlinear_share(ess_harmonics(y, FS, 0.5, 200.0, 30.0, 5.0))
        shares = [b.share for b in bands if math.isfinite(b.share)]
        assert max(shares) < 1e-3
