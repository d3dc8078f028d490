"""The joint fit (IDIM-IV, then the sampled-data output-error fit) on drawn scenarios.

Each test draws a truth and a protocol from the shared scenario generator, simulates it, fits the data
without looking at the truth, and compares. Tolerances are the issue's targets (3 % on Jc, bc, K, Jl,
0.5 ms on Td) except where stated.
"""

import math

import numpy as np
import pytest

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import Chirp, record
from iiwa_ident.ident._idim import fit_idim
from iiwa_ident.ident._joint_fit import fit_joint
from iiwa_ident.ident._records import held_windows, prepare_record
from iiwa_ident.ident._tf_fit import fit_transfer_function
from iiwa_ident.model import resonance_hz
from iiwa_ident.sim import SimulatedJoint, default_plant, plant_from_model
from iiwa_ident.sim._effects import TransmissionRipple
from iiwa_ident.testing import draw_scenario, simulate_scenario

_REL = 0.03
_TD_S = 0.5e-3


def _errors(result, truth):
    return {k: (result.parameters[k] - truth[k]) if k == "Td" else result.parameters[k] / truth[k] - 1.0
            for k in truth}


def _accurate(err):
    return all(abs(err[k]) <= _REL for k in ("Jc", "bc", "K", "Jl")) and abs(err["Td"]) <= _TD_S


# A seeded subset of the benchmark's draws, shortened to 12 s so that make test stays fast.
_SUBSET = list(range(1000, 1010))


@pytest.fixture(scope="module")
def subset_outcomes():
    out = []
    for seed in _SUBSET:
        sc = draw_scenario(seed, duration_s=12.0)
        ds = simulate_scenario(sc)
        try:
            res = fit_joint([ds])
        except IiwaIdentError as err:
            out.append((sc, "refused", str(err)))
            continue
        out.append((sc, "fitted", _errors(res, sc.truth)))
    return out


def test_subset_never_a_traceback_and_mostly_accurate(subset_outcomes):
    fitted = [o for o in subset_outcomes if o[1] == "fitted"]
    passed = [o for o in fitted if _accurate(o[2])]
    # The target is 95 % (bench/bench_robustness.py fit, 10-60 s records); 8 of these 10 short records pass
    # (seed 1004: K -3.4 % under Coulomb and Stribeck friction; seed 1008: Jl +4.4 % on a 200 Hz chirp of an
    # 18.7 kg m^2 link). The bound stays loose: a seeded subset of 10 is a smoke test, the benchmark the measure.
    assert len(passed) >= 0.8 * len(subset_outcomes), "\n".join(
        f"{sc.describe()}: {res}" for sc, kind, res in subset_outcomes if kind != "fitted" or not _accurate(res))


def test_subset_no_silent_nonsense(subset_outcomes):
    # A miss may be a few percent; an estimate off by a quarter or more must be a refusal instead.
    for sc, kind, err in subset_outcomes:
        if kind == "fitted":
            assert all(abs(err[k]) < 0.25 for k in ("Jc", "bc", "K", "Jl")), f"{sc.describe()}: {err}"
            assert abs(err["Td"]) < 2e-3, f"{sc.describe()}: {err}"


def test_subset_refusals_name_a_parameter(subset_outcomes):
    for _sc, kind, msg in subset_outcomes:
        if kind == "refused":
            assert msg.split(":")[0] in ("Jc", "bc", "K", "Jl", "Td") or "dataset" in msg, msg


def test_a_chirp_below_the_resonance_is_refused_naming_k():
    # Below the resonance K and Jl do not separate: at 0.4 of it the estimates were off by 10-40 %
    # with a std of 1-2 %. The refusal names K and the band, and says how far to chirp.
    sc = draw_scenario(1001, duration_s=10.0)
    t = sc.truth
    f_res = resonance_hz(t["Jc"], t["K"], t["Jl"])
    sc.protocol["f1_hz"] = 0.4 * f_res
    with pytest.raises(IiwaIdentError, match=r"^K: the chirp's band .* stays below the resonance near"):
        fit_joint([simulate_scenario(sc)])
    sc.protocol["f1_hz"] = 2.0 * f_res  # the same joint, chirped past the resonance, fits
    fit_joint([simulate_scenario(sc)])


@pytest.fixture(scope="module")
def friction_chirp():
    """A 1 kHz chirp of a link with 4.4 Nm of Coulomb friction, viscous friction and a sensor offset."""
    sc = draw_scenario(7, nuisances=["coulomb", "viscous", "offset"], duration_s=20.0, rate_hz=1000.0)
    return sc, simulate_scenario(sc)


def test_link_effects_recovered_in_the_simulator_s_names(friction_chirp):
    sc, ds = friction_chirp
    res = fit_idim([ds])
    fr = res.effect("link_friction")
    truth = sc.effects["link_friction"]
    assert fr.values["coulomb_nm"] == pytest.approx(truth["coulomb_nm"], rel=0.1, abs=0.05)
    assert fr.values["viscous_nms_rad"] == pytest.approx(truth["viscous_nms_rad"], rel=0.2, abs=0.1)
    off = res.effect("torque_sensor_offset")
    assert off.values["offset_nm"] == pytest.approx(sc.effects["torque_sensor_offset"]["offset_nm"], abs=0.05)
    assert off.significant and fr.significant
    for e in res.effects:  # each reported with a std, in the effect's own parameter names
        assert set(e.values) == set(e.std)


def test_band_quality_is_judged_with_the_fitted_effects(friction_chirp):
    # 4.4 Nm of Coulomb friction: eq (4) alone misses H1 by about 60 %; with the effects' response
    # taken out of the data, the fitted model matches it within a few per cent in every band.
    res = fit_joint([friction_chirp[1]])
    assert res.bands and all(b.rel_error < 0.05 for b in res.bands), [(b.lo_hz, b.rel_error) for b in res.bands]
    assert not [w for w in res.warnings if "misses the measured response" in w]


def test_no_effect_is_called_significant_on_a_clean_joint():
    sc = draw_scenario(8, nuisances=[], duration_s=15.0, rate_hz=1000.0)
    res = fit_idim([simulate_scenario(sc)])
    fr = res.effect("link_friction")
    assert abs(fr.values["coulomb_nm"]) < 0.1 and abs(fr.values["viscous_nms_rad"]) < 0.3
    assert abs(res.effect("torque_sensor_offset").values["offset_nm"]) < 0.05
    assert res.effect("transmission_ripple") is None  # searched, not found


@pytest.mark.parametrize("seed", [41, 42])
def test_a_ripple_of_unknown_period_is_found_and_leaves_the_fit_unbiased(seed):
    # Not the paper's ripple: a period and two harmonics drawn here, unknown to the fit. Unmodelled,
    # the paper's ripple biased K and Jl by 2-6 % at 10-120 std; in the output-error model with the
    # period IDIM-IV finds, every parameter is within 0.2 % and 4 std.
    rng = np.random.default_rng(seed)
    sc = draw_scenario(seed, nuisances=["ripple"], duration_s=12.0, rate_hz=float(rng.choice([200.0, 1000.0])))
    period = rng.uniform(0.008, 0.04)
    amplitude = rng.uniform(2e-5, 8e-5)
    sc.effects["transmission_ripple"] = {"period_rad": period, "harmonics": [
        [amplitude, rng.uniform(-math.pi, math.pi)], [rng.uniform(0.2, 1.0) * amplitude, rng.uniform(-math.pi, math.pi)]]}
    res = fit_joint([simulate_scenario(sc)])
    ripple = next(e for e in res.effects if e.name == "transmission_ripple")
    assert ripple.significant and res.method == "joint+ripple"
    assert ripple.values["period_rad"] == pytest.approx(period, rel=0.01)
    assert ripple.values["amplitude1_rad"] == pytest.approx(amplitude, rel=0.15)
    err = _errors(res, sc.truth)
    assert all(abs(err[k]) <= 0.002 for k in ("Jc", "bc", "K", "Jl")) and abs(err["Td"]) <= 0.02e-3, (sc.describe(), err)
    realised_td = round(sc.truth["Td"] / 1e-4) * 1e-4  # the simulator's delay, to the nearest substep
    for k in ("Jc", "bc", "K", "Jl", "Td"):
        value = realised_td if k == "Td" else sc.truth[k]
        assert abs(res.parameters[k] - value) < 4 * res.std[k], (k, sc.describe())


@pytest.mark.parametrize("seed", [41, 43])
def test_holds_at_the_antiresonance_and_a_searched_period_leave_the_std_honest(seed):
    # A 30 s chirp at 1 kHz with sensor noise: near the antiresonance the motor stands almost still and the
    # robot holds it where command and torque pass below 1 Nm (section II.A); the ripple's period, searched
    # by the inverse dynamics, was 7.6e-4 off in noise. Either biased K by 40-130 ppm at 5-10 std on the
    # default plant; the fit leaves the holds out and refines the period on its own residual.
    rng = np.random.default_rng(seed)
    sc = draw_scenario(seed, nuisances=["ripple"], duration_s=30.0, rate_hz=1000.0)
    period = rng.uniform(0.015, 0.025)
    sc.effects["transmission_ripple"] = {"period_rad": period, "harmonics": [
        [rng.uniform(3e-5, 6e-5), rng.uniform(-math.pi, math.pi)], [1e-5, rng.uniform(-math.pi, math.pi)]]}
    ds = simulate_scenario(sc)
    assert prepare_record(ds, 0).held, "the draw must meet the robot's hold"
    res = fit_joint([ds])
    ripple = next(e for e in res.effects if e.name == "transmission_ripple")
    assert ripple.values["period_rad"] == pytest.approx(period, rel=1e-4)
    assert res.ripple_period_rad == ripple.values["period_rad"]
    for k in ("Jc", "bc", "K", "Jl"):
        assert abs(res.parameters[k] - sc.truth[k]) < 3 * res.std[k], (k, sc.describe(), _errors(res, sc.truth))


@pytest.mark.parametrize("seed", [5, 8])
def test_a_delay_on_the_sample_grid_is_fitted_without_bias_through_the_ripple(seed):
    # With the delay a whole number of samples every speed jump of the command falls on a sample; the
    # ripple's inputs interpolated through the samples then followed the command's steps, and the fit took
    # that for Td: -45 ns on average at 17 ns std, -100 ns without noise. A random joint and ripple of the
    # default plant's kind, a 30 s chirp with the sensors' noise.
    rng = np.random.default_rng(seed)
    plant = default_plant()
    truth = {k: plant.dynamics[k] * rng.uniform(0.8, 1.25) for k in ("Jc", "bc", "K", "Jl")}
    truth["Td"] = 1e-3 * int(rng.integers(2, 9))
    plant.dynamics.update(truth)
    plant = plant.with_effects(TransmissionRipple({"period_rad": float(rng.uniform(0.015, 0.025)), "harmonics": [
        [rng.uniform(3e-5, 6e-5), rng.uniform(-math.pi, math.pi)], [1e-5, rng.uniform(-math.pi, math.pi)]]}))
    ds = record(SimulatedJoint(plant, seed=seed), Chirp(duration_s=30.0))
    res = fit_joint([ds])
    assert res.method == "joint+ripple"
    err = _errors(res, truth)
    assert abs(err["Td"]) < 20e-9, err
    for k in truth:
        assert abs(res.parameters[k] - truth[k]) < 3 * res.std[k], (k, err)


def test_the_robot_s_holds_are_found_where_the_motor_stands_with_small_torques():
    # Held: two samples without motion at small command and torque; a reversal at 10 Nm is not held.
    n = 200
    q = np.r_[np.linspace(0.0, 1e-3, 100), np.full(4, 1e-3), np.linspace(1e-3, 0.0, 96)]
    small, large = np.zeros(n), np.full(n, 10.0)
    assert held_windows(q, small, small, 1e-3) == [(96, 108)]
    assert held_windows(q, large, small, 1e-3) == []
    assert held_windows(q, small, large, 1e-3) == []
    # The command acts after the delay: a small command up to 50 ms before counts.
    late = np.where(np.arange(n) < 60, 0.0, 5.0)
    assert held_windows(q, late, small, 1e-3) == [(96, 108)]
    assert held_windows(q, np.where(np.arange(n) < 40, 0.0, 5.0), small, 1e-3) == []


@pytest.mark.parametrize("seed, rate, lo, hi", [(61, 1000.0, 0.045, 0.09), (64, 200.0, 0.1, 0.18)])
def test_a_hum_with_harmonics_is_fitted_as_lines_and_leaves_the_fit_unbiased(seed, rate, lo, hi):
    # A time-periodic disturbance of the torque reading (not a link-side effect), with 2nd and 3rd
    # harmonics (at 200 Hz the 3rd folds below the Nyquist limit), next to link friction. Unfitted, such
    # hums (0.15-0.4 Nm at 50-90 Hz at 1 kHz) made IDIM-IV's Jl negative and the fit refused, or left it
    # 4-36 % off; with each line a free sinusoid the fit meets its targets.
    rng = np.random.default_rng(seed)
    sc = draw_scenario(seed, nuisances=["coulomb", "viscous"], duration_s=10.0, rate_hz=rate)
    f0 = rng.uniform(lo, hi) * rate
    sc.effects["periodic_disturbance"] = {
        "amplitude_nm": rng.uniform(0.15, 0.4), "frequency_hz": f0, "phase_rad": rng.uniform(-math.pi, math.pi),
        "harmonic2_nm": rng.uniform(0.05, 0.2), "harmonic2_phase_rad": rng.uniform(-math.pi, math.pi),
        "harmonic3_nm": rng.uniform(0.05, 0.2), "harmonic3_phase_rad": rng.uniform(-math.pi, math.pi)}
    res = fit_joint([simulate_scenario(sc)])
    lines = res.lines_hz
    assert lines and res.to_json()["spectral_lines_hz"] == list(lines), res.warnings
    aliases = [abs((k * f0 + rate / 2) % rate - rate / 2) for k in (1, 2, 3)]
    for f in lines:  # each a harmonic of the hum (or its alias), to a small fraction of the resolution (0.1 Hz)
        assert min(abs(f - a) for a in aliases) < 0.01, (lines, f0)
    err = _errors(res, sc.truth)
    assert _accurate(err), (sc.describe(), err)


def test_no_lines_are_fitted_without_a_hum():
    # Friction, a load with a 2nd harmonic, a drifting offset and the ripple: broadband or slow, no line.
    sc = draw_scenario(63, nuisances=["stribeck", "viscous", "load_harmonic", "offset_drift", "ripple"],
                       duration_s=12.0, rate_hz=1000.0)
    assert fit_idim([simulate_scenario(sc)]).lines_hz == ()


def test_cli_reports_effects_and_the_model_file_keeps_them(tmp_path):
    import json

    from typer.testing import CliRunner

    from iiwa_ident.cli import app
    from iiwa_ident.datasets import write_dataset
    from iiwa_ident.ident import read_model

    sc = draw_scenario(21, nuisances=["offset", "viscous"], duration_s=12.0, rate_hz=1000.0)
    path = tmp_path / "chirp.h5"
    write_dataset(path, simulate_scenario(sc))
    out, js = tmp_path / "m.toml", tmp_path / "m.json"
    res = CliRunner().invoke(app, ["fit", str(path), "--out", str(out), "--json", str(js)])
    assert res.exit_code == 0, res.output
    assert "link-side effects" in res.output
    doc = json.loads(js.read_text())
    off = doc["effects"]["torque_sensor_offset"]["offset_nm"]
    assert off["value"] == pytest.approx(sc.effects["torque_sensor_offset"]["offset_nm"], abs=0.05)
    assert off["std"] > 0
    model = read_model(out)
    kept = {e["name"]: e for e in model.effects}
    assert kept["torque_sensor_offset"]["offset_nm"] == pytest.approx(off["value"])
    # The fitted model file simulates with its effects, in the simulator's own vocabulary.
    plant = plant_from_model(model)
    assert plant.effect("torque_sensor_offset").values["offset_nm"] == pytest.approx(off["value"])
    names = model.fit["effect_std_names"]
    assert "torque_sensor_offset.offset_nm" in names
    assert model.fit["effect_std"][names.index("torque_sensor_offset.offset_nm")] == pytest.approx(off["std"])


def test_cli_refuses_an_unknown_method_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    res = CliRunner().invoke(app, ["fit", str(tmp_path / "x.h5"), "--out", str(tmp_path / "m.toml"),
                                   "--method", "magic"])
    assert res.exit_code != 0
    assert "--method" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "m.toml").exists()


@pytest.mark.parametrize("method", ["joint", "idim", "eq4"])
def test_every_method_fits_a_clean_joint(method):
    sc = draw_scenario(31, nuisances=[], duration_s=12.0, rate_hz=1000.0)
    res = fit_joint([simulate_scenario(sc)], method=method)
    assert res.method == method
    assert _accurate(_errors(res, sc.truth)), (sc.describe(), _errors(res, sc.truth))


def test_a_clean_joint_gets_no_gravity_model_input():
    # The inverse dynamics' gravity-model terms absorb its own approximation error (here at > 3 std on a
    # joint without any); passed on as a known torque they moved K by 4 std of the output-error fit.
    sc = draw_scenario(31, nuisances=[], duration_s=12.0, rate_hz=1000.0)
    ds = simulate_scenario(sc)
    joint, eq4 = fit_joint([ds], method="joint"), fit_joint([ds], method="eq4")
    for k in ("Jc", "bc", "K", "Jl", "Td"):
        assert abs(joint.parameters[k] - eq4.parameters[k]) < 0.2 * eq4.std[k], k


def test_a_compensated_load_is_decided_by_the_output_error_model():
    # The other side of the choice: a 1 kHz chirp of a held link under a 37 Nm load the robot compensates
    # by 96 %. The load's link torque and the robot's compensation nearly cancel: the exact model's
    # residuals are smallest with neither (q_m 3.2e-6 rad against 8.5e-6 with both), and that fit is
    # the more accurate one (within 0.17 % against 0.28 %).
    sc = draw_scenario(40, nuisances=["gravity"], duration_s=12.0, rate_hz=1000.0)
    ds = simulate_scenario(sc)
    idim = fit_idim([ds])
    assert any(kind == "motor" for kind, _ in idim.known_inputs[0])
    with_model = fit_transfer_function([ds], initial=idim.parameters, known=idim.known_inputs)
    res = fit_joint([ds], method="joint")
    assert _accurate(_errors(res, sc.truth)), (sc.describe(), _errors(res, sc.truth))
    def worst(r):
        return max(abs(v) for k, v in _errors(r, sc.truth).items() if k != "Td")

    assert worst(res) < worst(with_model)
