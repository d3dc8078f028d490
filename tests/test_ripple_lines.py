"""The test of a given line in a given run (:func:`iiwa_ident.ident._ripple_lines.line_test`): its false-alarm
probability on realistic null data (white, coloured, a torque filtered before logging, a temporal line nearby),
its amplitude std against Monte Carlo, and its windows and limits.

The runs come from a generator of their own (the motor at one constant speed, the torque a constant load, noise
and an optional sine in the motor position, the position quantised like the iiwa's encoder), through the same
pass construction as the search.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal as sg

from iiwa_ident.datasets import Dataset
from iiwa_ident.ident._ripple_lines import line_test
from iiwa_ident.ident._ripple_passes import deflection

TICK = 5.989e-8


def _passes(seed, noise="white", rate=1000.0, speed=0.5, duration=3.0, amplitude=0.0, cpr=320.0, hum_hz=None,
            noise_scale=1.0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * rate)) / rate
    q = 0.1 + speed * t
    e = rng.standard_normal(len(t))
    if noise == "coloured":
        e = 0.3 * sg.lfilter([1.0], [1.0, -0.95], e)
    tau = 3.0 + 0.02 * noise_scale * e + 185.0 * amplitude * np.sin(cpr * q + rng.uniform(0, 2 * math.pi))
    if hum_hz is not None:
        tau += 0.05 * np.sin(2 * math.pi * hum_hz * t + 1.0)
    if noise == "filtered":
        b, a = sg.butter(1, 12.0 / (rate / 2))
        tau = sg.lfilter(b, a, tau)
    ds = Dataset(signals={"t": t, "q_m": np.round(q / TICK) * TICK, "tau_j": tau}, experiment="constant_velocity",
                 source="simulation", joint=1, sample_rate_hz=rate)
    return deflection(ds, 0, 18500.0, 5.6, 2 * math.pi / 50, 0.003, 4 * 2 * math.pi / 2000)


@pytest.mark.parametrize("noise", ["white", "coloured", "filtered"])
def test_false_alarm_holds_on_null_runs(noise):
    # 40 runs x 5 frequencies; in half of them a temporal line at 37 Hz (465 cycles per revolution at 0.5 rad/s)
    # sits among the neighbours of 407 and 520.
    p = np.array([line_test(_passes(s, noise, hum_hz=37.0 if s % 2 else None), cpr / (2 * math.pi), 1000.0).p_value
                  for s in range(40) for cpr in (150.0, 233.3, 320.0, 407.0, 520.0)])
    assert np.mean(p < 0.1) <= 0.16, np.mean(p < 0.1)
    assert np.mean(p < 0.01) <= 0.03, np.mean(p < 0.01)


def test_amplitude_and_its_std_cover_the_truth():
    # The deflection's line as the noise-free run shows it: the torque carries 185 x the generator's sine.
    k = 320.0 / (2 * math.pi)
    truth = line_test(_passes(0, amplitude=6e-5, noise_scale=0.0), k, 1000.0).amplitude_rad
    z = []
    for s in range(40):
        r = line_test(_passes(s, "coloured", amplitude=6e-5), k, 1000.0)
        assert r.p_value < 0.05
        z.append((r.amplitude_rad - truth) / r.amplitude_std_rad)
    z = np.array(z)
    assert np.mean(np.abs(z) < 3.0) >= 0.95, z
    assert 0.4 < np.std(z) < 2.0, np.std(z)


def test_a_line_known_only_to_its_std_is_found_in_its_window():
    k = 320.0 / (2 * math.pi)
    passes = _passes(1, amplitude=3e-5)
    off = line_test(passes, k * 1.033, 1000.0)       # 2.5 resolution cells (1 / 1.5 rad) away
    found = line_test(passes, k * 1.033, 1000.0, k_std=0.012 * k)
    assert found.amplitude_rad > 3.0 * off.amplitude_rad and found.p_value < 1e-4 < off.p_value
    assert found.k == pytest.approx(k, rel=5e-3)


def test_a_temporal_line_is_where_the_speed_puts_it():
    passes = _passes(2, hum_hz=37.0)
    r = line_test(passes, 37.0 / 0.5, 1000.0)
    assert r.p_value < 1e-6 and r.frequency_hz == pytest.approx(37.0, rel=1e-2)


def test_lines_beyond_the_nyquist_limit_or_the_passes_are_not_tested():
    passes = _passes(3, rate=200.0, speed=1.0)
    r = line_test(passes, 400.0 / (2 * math.pi), 200.0)   # 64 Hz of a 100 Hz Nyquist limit: 0.9 x 100 = 90 > 64
    assert r.tested
    r = line_test(passes, 600.0 / (2 * math.pi), 200.0)   # 95 Hz
    assert not r.tested and "Nyquist" in r.reason and r.p_value == 1.0
    assert not line_test(passes, 2.0 / (2 * math.pi), 200.0).tested
    assert not line_test([], 50.0, 200.0).tested
