"""The shared scenario generator: seeded, in range, and the effects it switches on reach the data."""

import math

import numpy as np
import pytest

from iiwa_ident.model import resonance_hz
from iiwa_ident.sim._plant import default_plant
from iiwa_ident.testing import (
    HIDDEN_OTHER_SHAPES,
    HIDDEN_RANGES,
    NUISANCES,
    RIPPLE_NUISANCES,
    draw_hidden_effects,
    draw_ripple_scenario,
    draw_scenario,
    hidden_effect_plant,
    scenario_plant,
    simulate_ripple_scenario,
    simulate_scenario,
)


def test_same_seed_same_scenario():
    a, b = draw_scenario(11), draw_scenario(11)
    assert a.truth == b.truth and a.protocol == b.protocol and a.effects == b.effects
    assert draw_scenario(12).truth != a.truth


@pytest.mark.parametrize("seed", range(40))
def test_draws_stay_in_their_ranges(seed):
    sc = draw_scenario(seed)
    t, p = sc.truth, sc.protocol
    assert 0.3 <= t["Jl"] <= 20 and 3000 <= t["K"] <= 40000
    assert 0.4 * 1.03 <= t["Jc"] <= 1.6 * 1.03 and 0.4 * 0.005 - 1e-4 <= t["Td"] <= 1.6 * 0.005 + 1e-4
    assert p["rate_hz"] in (200.0, 500.0, 1000.0) and 10 <= p["duration_s"] <= 60
    assert 0 < p["f0_hz"] < p["f1_hz"] < 0.5 * p["rate_hz"]
    assert set(sc.nuisances) <= set(NUISANCES)
    plant = scenario_plant(sc)
    assert plant.cycle_s == pytest.approx(1.0 / p["rate_hz"])
    assert {e.name for e in plant.effects} == set(sc.effects)


def test_chosen_nuisances_and_other_shapes():
    sc = draw_scenario(3, nuisances=["stribeck", "load_harmonic", "offset_drift"])
    assert sc.effects["link_friction"]["stribeck_nm"] > 0
    assert sc.effects["position_dependent_load"]["harmonic2_nm"] != 0
    assert sc.effects["torque_sensor_offset"]["drift_nm_s"] != 0
    with pytest.raises(ValueError):
        draw_scenario(3, nuisances=["nonsense"])


def test_offset_reaches_the_reading():
    sc = draw_scenario(5, nuisances=["offset"], duration_s=3.0, rate_hz=500.0)
    ds = simulate_scenario(sc)
    # Before the chirp has moved anything the joint carries no torque: the reading is the offset.
    assert ds["tau_j"][0] == pytest.approx(sc.effects["torque_sensor_offset"]["offset_nm"], abs=0.1)
    assert ds.sample_rate_hz == pytest.approx(500.0)
    assert "stopped_reason" not in ds.experiment_attrs
    assert math.isfinite(resonance_hz(1.03, 18500.0, 5.6)) and 22 < resonance_hz(1.03, 18500.0, 5.6) < 24


def test_ripple_scenarios_seeded_and_null_without_ripple():
    a, b = draw_ripple_scenario(21), draw_ripple_scenario(21)
    assert a == b and a.ripple is not None and 100 <= a.cycles_per_rev <= 800
    null = draw_ripple_scenario(21, null=True)
    assert null.ripple is None and null.runs == a.runs and null.effects == a.effects
    for seed in range(20):
        sc = draw_ripple_scenario(seed)
        assert 2 <= len(sc.runs) <= 3 and sc.rate_hz in (200.0, 500.0, 1000.0)
        assert all(0.05 <= r["speed_rad_s"] <= 1.3 for r in sc.runs)
        assert set(sc.nuisances) <= set(RIPPLE_NUISANCES)


def test_ripple_scenario_nuisances_reach_the_logs():
    sc = draw_ripple_scenario(3, null=True, nuisances=["gaps"])
    for ds in simulate_ripple_scenario(sc):
        dt = np.diff(ds["t"])
        assert dt.max() > 5 / sc.rate_hz and np.median(dt) == pytest.approx(1 / sc.rate_hz)
    # Hum and coloured noise are added to the torque reading: against the same runs without them the
    # difference has the hum's line and the noise's spread.
    quiet = simulate_ripple_scenario(draw_ripple_scenario(3, null=True, nuisances=[]))
    sc = draw_ripple_scenario(3, null=True, nuisances=["hum", "coloured_noise"])
    for a, b in zip(simulate_ripple_scenario(sc), quiet):
        d = a["tau_j"] - b["tau_j"]
        hum = sc.after["hum_harmonics"][0]
        fs = sc.rate_hz
        spec = np.abs(np.fft.rfft(d * np.hanning(len(d))))
        f = np.fft.rfftfreq(len(d), 1 / fs)
        near = np.abs(f - hum[1]) < 1.0
        assert spec[near].max() > 5 * np.median(spec)
        assert np.std(d) > 0.5 * hum[0]


def test_hidden_effects_seeded_in_range_and_simulatable():
    draws = [draw_hidden_effects(seed, shapes=True) for seed in range(60)]
    again = draw_hidden_effects(7, shapes=True)
    assert again.hidden == draws[7].hidden and again.dynamics == draws[7].dynamics
    counts = {len(d.hidden) for d in draws}
    assert counts == {0, 1, 2}
    seen = {name for d in draws for name in d.hidden}
    assert seen == set(HIDDEN_RANGES)
    assert {name for d in draws for name in d.reshaped} == set(HIDDEN_OTHER_SHAPES)
    for d in draws:
        assert set(d.reshaped) <= set(d.hidden)
        table1 = default_plant().dynamics
        for k, v in d.dynamics.items():
            assert 0.7 * table1[k] - 1e-4 <= v <= 1.3 * table1[k] + 1e-4, (k, v)
        assert abs(d.dynamics["Td"] / 1e-4 - round(d.dynamics["Td"] / 1e-4)) < 1e-9
        plant = hidden_effect_plant(d)  # every table is a valid plant effect of the simulator
        assert {e.name for e in plant.effects} == set(d.hidden)
        assert plant.dynamics["K"] == d.dynamics["K"]
    plain = draw_hidden_effects(7)
    assert plain.reshaped == [] and plain.dynamics["K"] == 18500.0
