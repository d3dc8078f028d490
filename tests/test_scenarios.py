"""The shared scenario generator: seeded, in range, and the effects it switches on reach the data."""

import math

import numpy as np
import pytest

from iiwa_ident.excite.scenarios import NUISANCES, draw_scenario, scenario_plant, simulate_scenario
from iiwa_ident.sim.plant import resonance_hz


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
