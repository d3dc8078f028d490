"""The ripple search's predicted detection probability against the search itself, on runs written apart from it.

The runs: the motor at one constant speed, the joint torque a load plus ``K f`` (``f`` one sine of a random
period and phase) plus white noise, the position quantised like the iiwa's encoder.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import numpy as np
import pytest

from iiwa_ident.datasets import Dataset
from iiwa_ident.ident._ripple import identify_ripple
from iiwa_ident.ident._ripple_detect import (
    RunSensitivity,
    detectable_amplitude,
    detection_probability,
    noise_psd,
    pooled_detection_probability,
    required_travel,
)
from iiwa_ident.ident._ripple_passes import deflection

_K, _SIGMA_NM, _RATE = 18500.0, 0.05, 200.0
_PSD = 2.0 * (_SIGMA_NM / _K) ** 2 / _RATE  # one-sided, of the deflection's white noise [rad^2/Hz]


def _run(rng, travel, speed, cpr, amplitude):
    t = np.arange(int(travel / speed * _RATE)) / _RATE
    q = 0.3 + speed * t
    tau = 4.0 + _K * amplitude * np.sin(cpr * q + rng.uniform(0, 2 * math.pi)) + _SIGMA_NM * rng.standard_normal(t.size)
    tick = 5.989e-8
    return Dataset(signals={"t": t, "q_m": np.round(q / tick) * tick, "tau_j": tau}, experiment="constant_velocity",
                   source="import", joint=1, sample_rate_hz=_RATE)


@functools.cache
def _outcomes(probability, draws=30, travel=2.0, speed=0.1):
    """(detected, period right within 0.5 %) per draw at the amplitude predicted to be detected with probability."""
    rng = np.random.default_rng(int(100 * probability))
    out = []
    for _ in range(draws):
        cpr = rng.uniform(250.0, 400.0)
        amp = detectable_amplitude(travel, speed, _PSD, _RATE, cpr, probability=probability)
        assert detection_probability(amp, travel, speed, _PSD, _RATE, cpr) == pytest.approx(probability, abs=1e-6)
        r = identify_ripple([_run(rng, travel, speed, cpr, amp)])
        out.append((bool(r.detected), bool(r.detected and abs(r.cycles_per_rev / cpr - 1) < 5e-3)))
    return out


@pytest.mark.parametrize("probability", [0.3, 0.95])
def test_the_predicted_probability_holds_on_the_search(probability):
    detected = sum(d for d, _ in _outcomes(probability))
    # The prediction leaves out what only adds sensitivity (the line read between grid points, the family
    # test): it may be low, not high; 30 draws put 2 binomial std at 0.17 at most.
    assert probability - 0.17 <= detected / 30 <= probability + 0.45, detected


def test_a_detected_line_is_reported_at_its_period():
    out = _outcomes(0.95)
    assert sum(right for _, right in out) >= sum(d for d, _ in out) - 1


def test_the_noise_level_is_read_off_the_run():
    rng = np.random.default_rng(3)
    ds = _run(rng, 2.0, 0.2, 320.0, 2e-6)
    passes = deflection(ds, 0, _K, 5.6, 2 * math.pi / 50, 0.003, 0.0126, link_motion="neglected")
    for f_hz in (5.0, 10.2, 30.0):  # the line itself at 10.2 Hz moves a median little
        assert noise_psd(passes, f_hz) == pytest.approx(_PSD, rel=0.3)
    # A line 100 times the noise's on a pass short enough that it fills most of the +-30 % band: left out.
    strong = _run(rng, 1.3, 0.3, 320.0, 40e-6)
    passes = deflection(strong, 0, _K, 5.6, 2 * math.pi / 50, 0.003, 0.0126, link_motion="neglected")
    assert noise_psd(passes, 0.3 * 320.0 / (2 * math.pi)) == pytest.approx(_PSD, rel=0.3)


def test_longer_runs_detect_smaller_lines_and_too_short_or_too_fast_none():
    a = [detectable_amplitude(travel, 0.2, _PSD, 1000.0, 320.0) for travel in (0.8, 1.2, 2.0, 4.0)]
    assert all(x > y for x, y in zip(a, a[1:]))
    assert detectable_amplitude(0.5, 0.2, _PSD, 1000.0, 320.0) == math.inf  # fewer than three chunks
    assert detectable_amplitude(2.0, 2.0, _PSD, 200.0, 320.0) == math.inf   # 102 Hz beyond 0.9 x 100 Hz
    travel = required_travel(a[1], 0.2, _PSD, 1000.0, 320.0)
    assert travel is not None and travel <= 1.2 * 1.03
    assert required_travel(a[-1] / 100.0, 0.2, _PSD, 1000.0, 320.0) is None


def test_ripple_says_what_each_run_detects_and_what_run_would(tmp_path):
    import json

    from typer.testing import CliRunner

    from iiwa_ident.cli import app
    from iiwa_ident.datasets import write_dataset

    rng = np.random.default_rng(1)
    files = []
    for i, (travel, speed) in enumerate(((1.2, 0.2), (0.9, 0.5))):
        files.append(str(tmp_path / f"run{i}.h5"))
        write_dataset(files[-1], _run(rng, travel, speed, rng.uniform(250, 400), 0.0))
    res = CliRunner().invoke(app, ["ripple", *files, "--amplitude-of-interest", "10", "--json", str(tmp_path / "r.json")])
    assert res.exit_code == 0, res.output
    rows = json.loads((tmp_path / "r.json").read_text())["sensitivity"]
    assert [r["dataset"] for r in rows] == [0, 1] and all(r["false_alarm"] == 1e-3 for r in rows)
    assert "(one run alone, false-alarm probability 0.001)" in res.output
    # Nothing detected: the paper's 320 cycles per revolution. The 1.2 rad run detects below 10 µrad; the 0.9 rad
    # run (4 chunks) does not, and is told the longer run at its speed that would.
    assert all(abs(r["cycles_per_rev"] - 320.0) < 1.0 for r in rows)
    assert rows[0]["detectable_rad"] < 10e-6 and rows[0]["required_travel_rad"] is None
    assert rows[1]["detectable_rad"] > 10e-6 and 0.9 < rows[1]["required_travel_rad"] < 20.0
    assert detection_probability(10e-6, rows[1]["required_travel_rad"], 0.5, rows[1]["psd_rad2_hz"], _RATE,
                                 320.0) >= 0.95
    assert f"detects {rows[0]['detectable_rad'] * 1e6:.3g} µrad" in res.output
    assert f"a {rows[1]['required_travel_rad']:.2g} rad run at 0.50 rad/s" in res.output


def test_a_run_too_fast_for_the_line_is_told_a_slower_one():
    from iiwa_ident.ident._ripple_detect import sensitivity

    rng = np.random.default_rng(5)
    ds = _run(rng, 4.0, 2.0, 300.0, 0.0)  # 320 cycles at 2 rad/s: 102 Hz, beyond 0.9 x 100 Hz
    passes = deflection(ds, 0, _K, 5.6, 2 * math.pi / 50, 0.003, 0.0126, link_motion="neglected")
    (s,) = sensitivity(passes, 320.0, 10e-6)
    assert s.detectable_rad == math.inf and s.required_speed_rad_s is not None
    assert s.required_speed_rad_s * 320.0 / (2 * math.pi) <= 0.9 * _RATE / 2
    assert detection_probability(10e-6, s.required_travel_rad, s.required_speed_rad_s, s.psd_rad2_hz, _RATE,
                                 320.0) >= 0.95
    assert f"rad run at {s.required_speed_rad_s:.2f} rad/s" in s.sentence("run 1")


def _sensitivity(travels, speed, cpr=320.0, span=None):
    return RunSensitivity(dataset=0, speed_rad_s=speed, travel_rad=max(travels), rate_hz=_RATE, cycles_per_rev=cpr,
                          psd_rad2_hz=_PSD, detectable_rad=math.inf, amplitude_rad=0.0, required_travel_rad=None,
                          pass_travel_rad=list(travels), pass_speed_rad_s=[speed] * len(travels),
                          span_rad=max(travels) if span is None else span)


def test_the_pooled_prediction_of_one_pass_is_the_single_run_one():
    for amp in (2e-6, 5e-6, 1e-5):
        one = detection_probability(amp, 1.2, 0.2, _PSD, _RATE, 320.0)
        np.testing.assert_allclose(pooled_detection_probability(amp, [_sensitivity([1.2], 0.2)]), one, rtol=1e-12)


def test_pooled_passes_detect_more_and_short_ones_together_at_all():
    amp = 3e-6
    one = pooled_detection_probability(amp, [_sensitivity([1.2], 0.2)])
    four = pooled_detection_probability(amp, [_sensitivity([1.2, 1.2], 0.2), _sensitivity([1.2, 1.2], 0.2)])
    assert 0.0 < one < four <= 1.0
    # 0.2 rad passes are one chunk each: alone none is judged, eight together are.
    assert detection_probability(amp, 0.2, 0.2, _PSD, _RATE, 320.0) == 0.0
    assert pooled_detection_probability(1e-5, [_sensitivity([0.2] * 8, 0.2)]) > 0.5
    # Beyond the Nyquist share a pass adds nothing; a run without a noise level is left out.
    fast = _sensitivity([1.2], 5.0)
    assert pooled_detection_probability(amp, [fast]) == 0.0
    none = dataclasses.replace(_sensitivity([1.2], 0.2), psd_rad2_hz=math.nan)
    assert pooled_detection_probability(amp, [none, _sensitivity([1.2], 0.2)]) == pytest.approx(one, rel=1e-12)


def test_a_run_s_sensitivity_holds_its_passes_and_reads_back_from_json():
    rng = np.random.default_rng(7)
    r = identify_ripple([_run(rng, 1.5, 0.2, 320.0, 2e-5)])
    (s,) = r.sensitivity
    assert s.pass_travel_rad and len(s.pass_travel_rad) == len(s.pass_speed_rad_s)
    assert max(s.pass_travel_rad) == pytest.approx(s.travel_rad) and s.span_rad >= s.travel_rad - 1e-12
    back = RunSensitivity.from_json(json.loads(json.dumps(s.to_json())))
    assert pooled_detection_probability(5e-6, [back]) == pytest.approx(pooled_detection_probability(5e-6, [s]))
