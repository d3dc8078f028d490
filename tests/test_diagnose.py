"""Discrepancy diagnosis: hidden effects found, clean data left alone, real logs, model file, CLI, batch."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import real_constant_velocity
from iiwa_ident.cli import app
from iiwa_ident.datasets import write_dataset
from iiwa_ident.diagnose import CANDIDATES, CandidateEffect, build_context, diagnose, residual_rms
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import ConstantVelocity, record
from iiwa_ident.ident import dataset_model, model_from_dict, read_model, write_model
from iiwa_ident.model import ModelError, table1_model
from iiwa_ident.sim import SimulatedJoint, plant_from_model
from iiwa_ident.sim._effects import make_effect
from iiwa_ident.testing import Case, case_model, score_case, simulate_case

PAPER_RHO = 0.01963

# One hidden effect each: (plant table, expected JSON parameters).
SINGLE = {
    "transmission_ripple": ({"period_rad": 0.02, "harmonics": [[5e-5, 0.4]]},
                            {"period_rad": 0.02, "amplitude_rad": 5e-5}),
    "link_friction": ({"coulomb_nm": 1.5, "viscous_nms_rad": 2.0}, {"coulomb_nm": 1.5, "viscous_nms_rad": 2.0}),
    "position_dependent_load": ({"amplitude_nm": 6.0, "phase_rad": 0.7, "compensated": 1.0},
                                {"amplitude_nm": 6.0, "phase_rad": 0.7}),
    "torque_sensor_offset": ({"offset_nm": -0.8}, {"offset_nm": -0.8}),
    "torque_sensor_scale": ({"scale": 1.06}, {"scale": 1.06}),
    "periodic_disturbance": ({"amplitude_nm": 0.25, "frequency_hz": 50.0, "phase_rad": 0.3},
                             {"amplitude_nm": 0.25, "frequency_hz": 50.0}),
}


def _case(seed: int, **effects: str) -> Case:
    case = Case(seed)
    for name in effects.values():
        case.hidden[name], case.expected[name] = SINGLE[name]
    return case


def _named(d) -> dict:
    return {e.name: e.parameters for e in d.effects}




class TestPrediction:
    def test_clean_residuals_are_noise(self):
        # Table I plant without effects: both channels are at the sensor noise (0.02 Nm), whatever the experiment.
        for ds in simulate_case(Case(5)):
            ctx = build_context(ds, table1_model())
            assert set(ctx.channels) == {"link", "command"}
            for ch in ctx.channels:
                r = ctx.residual[ch][ctx.masks[ch]]
                assert np.sqrt(np.mean(r ** 2)) < 0.08, (ds.experiment, ch)

    def test_cached_filters_and_columns_are_the_computed_ones(self):
        # The link low-pass equals scipy's sosfiltfilt, and a column met again (the cache) equals one computed
        # afresh, also through a filter before the log set after it was cached.
        from scipy import signal

        from iiwa_ident.diagnose._predict import channel_columns
        from iiwa_ident.sim import TorqueLogFilter

        ds = simulate_case(Case(6))[0]
        ctx, fresh = build_context(ds, table1_model()), build_context(ds, table1_model())
        x = np.random.default_rng(0).standard_normal(len(ctx.t))
        # (the channel's second-order Butterworth at its cut-off, as the module docstring states it)
        sos = signal.butter(2, ctx.cutoff_hz, fs=1.0 / ctx.dt, output="sos")
        np.testing.assert_allclose(ctx.lowpass(x), signal.sosfiltfilt(sos, x), rtol=0, atol=1e-12)
        phi = np.sin(ctx.q_m / 0.02)
        for log_filter in (None, TorqueLogFilter({"cutoff_hz": 12.0})):
            for c in (ctx, fresh):
                c.log_filter = log_filter
            first = channel_columns(ctx, "sensor", phi)
            again, other = channel_columns(ctx, "sensor", phi), channel_columns(ctx, "sensor", 2 * phi)
            fresh.memo.clear()
            expected = channel_columns(fresh, "sensor", phi)
            for ch in expected:
                np.testing.assert_array_equal(again[ch], expected[ch])
                np.testing.assert_array_equal(first[ch], expected[ch])
                np.testing.assert_allclose(other[ch], 2 * expected[ch], rtol=1e-9, atol=1e-12)

    def test_eq9_through_a_filter_before_the_log_is_the_links_own_response(self):
        # A filter F before the log: eq (9) places the link by the logged torque, so the link channel's torque v
        # shows as v + (F - 1)(1 + P) / (1 + P (1 - F)) v, P = (Jl s^2 + 2 zeta sqrt(K Jl) s) / K. Steady
        # sinusoids below, near and above the link's resonance against that response written here in
        # continuous time (the sampled derivatives and filter differ by well under 1 % at 1 kHz up to 30 Hz).
        from iiwa_ident.diagnose._predict import EQ9_LINK_DAMPING, logged_change
        from iiwa_ident.sim import TorqueLogFilter

        ctx = build_context(simulate_case(Case(6))[0], table1_model())
        ctx.link_from_eq9 = True
        Jl, K = ctx.params["Jl"], ctx.params["K"]
        fc = 6.0
        log_filter = TorqueLogFilter({"cutoff_hz": fc})
        n = len(ctx.t)
        middle = slice(n // 3, 2 * n // 3)
        for f in (0.5, 5.0, 0.8 * np.sqrt(K / Jl) / (2 * np.pi), 30.0):
            s = 2j * np.pi * f
            F = 1.0 / (1.0 + s / (2 * np.pi * fc))
            P = (Jl * s ** 2 + 2 * EQ9_LINK_DAMPING * np.sqrt(K * Jl) * s) / K
            H = 1.0 + (F - 1.0) * (1.0 + P) / (1.0 + P * (1.0 - F))
            v = np.sin(2 * np.pi * f * ctx.t)
            expected = abs(H) * np.sin(2 * np.pi * f * ctx.t + np.angle(H))
            got = logged_change(ctx, "link", v, log_filter)
            np.testing.assert_allclose(got[middle], expected[middle], rtol=0, atol=0.01 * max(abs(H), 1.0))
        # Far below the resonance it is the first-order account: F v + Jl/K (F v - v)''.
        v = np.sin(2 * np.pi * 0.5 * ctx.t)
        fv = log_filter.apply(v, ctx.dt)
        first = fv + Jl / K * ctx.ddt(ctx.ddt(fv - v))
        np.testing.assert_allclose(logged_change(ctx, "link", v, log_filter)[middle], first[middle], atol=2e-3)

    def test_a_record_too_short_is_refused_in_one_line(self):
        # (a simulated hand-guided run of joint 7 once ended after 3 samples and the diagnosis raised a filter's
        # ValueError)
        ds = simulate_case(Case(5))[0]
        n = int(0.4 * ds.sample_rate_hz)
        short = dataclasses.replace(ds, signals={k: np.asarray(v)[:n] for k, v in ds.signals.items()})
        with pytest.raises(IiwaIdentError, match=r"too short to diagnose \(at least 0.5 s"):
            diagnose([ds, short], table1_model())

    def test_position_mode_has_link_channel_only(self):
        ds = record(SimulatedJoint(plant_from_model(table1_model()).without_effects(), seed=1),
                    ConstantVelocity([0.5], range_rad=0.4, mode="position"), record_every=5)
        ctx = build_context(ds, table1_model())
        assert ctx.channels == ["link"] and ctx.dt == pytest.approx(0.005)


class TestSingleEffects:
    @pytest.mark.parametrize("name", list(SINGLE))
    def test_found_alone_with_parameters(self, name):
        case = _case(7, a=name)
        d = diagnose(simulate_case(case), table1_model())
        score = score_case(case, _named(d))
        assert score["hit"], (score, _named(d))
        e = d.effects[0]
        assert e.confidence >= 0.999
        assert e.rms_after < e.rms_before and e.gain_pct > 0

    def test_clean_data_names_nothing(self):
        d = diagnose(simulate_case(Case(11)), table1_model())
        assert d.explained and d.effects == []
        doc = d.as_json()
        assert doc["explained"] is True and doc["effects"] == []
        # The extended model is the model itself.
        assert d.extended.effects == [] and d.extended.ripple is None

    def test_two_effects_at_once(self):
        case = _case(12, a="link_friction", b="periodic_disturbance")
        d = diagnose(simulate_case(case), table1_model())
        assert score_case(case, _named(d))["hit"], _named(d)

    def test_position_controlled_200hz(self):
        # A position-mode run at 200 Hz (no command channel) with an unknown payload.
        plant = plant_from_model(table1_model()).without_effects().with_effects(
            make_effect("position_dependent_load", {"amplitude_nm": 5.0, "phase_rad": -0.5, "compensated": 0.0}))
        ds = record(SimulatedJoint(plant, seed=3), ConstantVelocity([0.3, 0.8], range_rad=1.0, mode="position"),
                    record_every=5)
        d = diagnose([ds], table1_model())
        assert [e.name for e in d.effects] == ["position_dependent_load"]
        p = d.effects[0].parameters
        assert p["amplitude_nm"] == pytest.approx(5.0, rel=0.1)
        assert abs(p["phase_rad"] + 0.5) < 0.1


class TestExtendedModel:
    def test_extension_removes_the_discrepancy(self):
        # Diagnosing again with the extended model finds nothing more.
        case = _case(13, a="link_friction", b="transmission_ripple")
        data = simulate_case(case)
        d = diagnose(data, table1_model())
        assert {e.name for e in d.effects} == {"link_friction", "transmission_ripple"}
        ext = d.extended
        assert ext.ripple is not None and abs(ext.ripple.period_rad / 0.02 - 1) < 2e-3
        assert [e["name"] for e in ext.effects] == ["link_friction"]
        again = diagnose(data, ext)
        assert again.explained, [e.name for e in again.effects]

    def test_an_effect_the_model_does_not_carry_is_a_suspect(self, monkeypatch):
        # A candidate whose fit the extended model does not reproduce (here made so: the model gets the friction
        # three times too strong) would show figures of a model nobody gets: the extended model predicts the runs
        # worse with it than without it, so it is a suspect that says so and the rest is named without it.
        from iiwa_ident.diagnose import CANDIDATES

        friction = CANDIDATES["link_friction"]
        carried = friction.extend

        def tripled(self, model, coef):
            carried(self, model, coef)
            entry = next(e for e in model.effects if e["name"] == "link_friction")
            entry["coulomb_nm"] = 3.0 * entry["coulomb_nm"]

        data = simulate_case(_case(13, a="link_friction", b="transmission_ripple"))
        monkeypatch.setattr(friction, "extend", tripled)
        d = diagnose(data, table1_model())
        assert d.effect("link_friction") is None and d.effect("transmission_ripple") is not None
        suspect = next(s for s in d.suspects if s["name"] == "link_friction")
        assert "predicts the runs worse than without it" in suspect["failed"] and not d.explained

    def test_delay_corrects_td(self):
        # An extra 2 ms of input delay in the plant is the model's Td being off: named as model_parameters.
        case = Case(14, hidden={"input_delay": {"extra_s": 0.002}})
        d = diagnose(simulate_case(case), table1_model())
        assert [e.name for e in d.effects] == ["model_parameters"]
        p = d.effects[0].parameters
        assert p["Td_s"] == pytest.approx(0.007, abs=3e-4)
        assert p["K_nm_rad"] == pytest.approx(18500.0, rel=0.03) and p["Jl_kgm2"] == pytest.approx(5.6, rel=0.05)
        assert d.extended.value("Td") == pytest.approx(0.007, abs=3e-4)
        assert d.extended.effects == []

    @pytest.mark.parametrize("seed, hidden", [
        (31, {}), (32, {}),
        (71, {"link_friction": {"coulomb_nm": 2.5, "viscous_nms_rad": 1.0, "stribeck_nm": 1.0,
                                "stribeck_velocity_rad_s": 0.05}}),
        (72, {"position_dependent_load": {"amplitude_nm": 12.0, "phase_rad": 0.4, "compensated": 1.0}}),
        (73, {"periodic_disturbance": {"amplitude_nm": 0.3, "frequency_hz": 37.0, "phase_rad": 0.2,
                                       "harmonic3_nm": 0.1}})])
    def test_wrong_model_parameters_are_refitted_not_explained_by_an_effect(self, seed, hidden):
        # The model's K, Jl and Td off by a few per cent and up to 1.5 ms (hidden from the diagnosis), alone or
        # next to an effect in a shape no candidate has: the finding is model_parameters with values near the
        # plant's (besides the effect's family), not a sensor scale or another invented effect.
        rng = np.random.default_rng(seed)
        case = Case(seed, hidden=hidden, dynamics={"Jc": 1.03 * rng.uniform(0.8, 1.2), "bc": 55.0 * rng.uniform(0.8, 1.2),
                                    "K": 18500.0 * rng.uniform(0.7, 1.3), "Jl": 5.6 * rng.uniform(0.7, 1.3),
                                    "Td": round(rng.uniform(0.003, 0.007), 4)})
        data = simulate_case(case)
        model = case_model(case)
        off = {"K": rng.choice([-1, 1]) * rng.uniform(0.04, 0.08), "Jl": rng.choice([-1, 1]) * rng.uniform(0.06, 0.12)}
        for k, v in off.items():
            model.parameters[k].value *= 1.0 + v
        model.parameters["Td"].value += rng.choice([-1, 1]) * rng.uniform(0.0007, 0.0015)
        d = diagnose(data, model)
        assert {e.name for e in d.effects} == {"model_parameters", *hidden}, _named(d)
        p = d.effect("model_parameters").parameters
        assert p["K_nm_rad"] == pytest.approx(case.dynamics["K"], rel=0.02)
        assert p["Jl_kgm2"] == pytest.approx(case.dynamics["Jl"], rel=0.03)
        assert p["Td_s"] == pytest.approx(case.dynamics["Td"], abs=2e-4)
        assert d.effect("model_parameters").gain_pct > 20
        if not hidden:
            # Nothing more to name; "explained" is stronger: the refit is within the fit's accuracy, not exact, and
            # the chirp's command channel shows what is left (3x the sensor noise, its independence test fails).
            again = diagnose(data, d.extended)
            assert not again.effects and not again.suspects, _named(again)
            assert {c.channel for c in again.unexplained_channels} <= {"command"}

    def test_model_file_effects_round_trip(self, tmp_path):
        m = table1_model()
        m.effects = [{"name": "link_friction", "coulomb_nm": 1.0, "viscous_nms_rad": 0.5},
                     {"name": "torque_sensor_offset", "offset_nm": 0.3}]
        write_model(tmp_path / "m.toml", m)
        back = read_model(tmp_path / "m.toml")
        assert back.effects == m.effects
        plant = plant_from_model(back)
        assert plant.effect("link_friction").values["coulomb_nm"] == 1.0
        trace = SimulatedJoint(plant, seed=1).run_open_loop(tau_c=np.full(500, 3.0))
        assert np.all(np.isfinite(trace.measured["tau_j"]))

    def test_old_model_files_still_read_and_write_unchanged(self, tmp_path):
        m = table1_model()
        assert "effects" not in m.to_dict()
        write_model(tmp_path / "m.toml", m)
        assert "effects" not in (tmp_path / "m.toml").read_text()
        assert read_model(tmp_path / "m.toml").effects == []

    @pytest.mark.parametrize("effects, match", [
        ([{"name": "no_such_effect"}], "unknown effect"),
        ([{"name": "link_friction", "coulomb_nm": -1.0}], "coulomb_nm"),
        ([{"coulomb_nm": 1.0}], "name"),
        ("friction", "list"),
    ])
    def test_invalid_effects_rejected(self, effects, match):
        doc = table1_model().to_dict()
        doc["effects"] = effects
        with pytest.raises(ModelError, match=match):
            model_from_dict(doc, where="m.toml: ")


class TestRealLogs:
    def test_a_model_of_another_joint_is_refused(self):
        with pytest.raises(IiwaIdentError, match="a model of joint 1 on data of joint 2"):
            diagnose([real_constant_velocity(2)], table1_model())

    def test_joint2_filter_gravity_and_the_ripple_in_its_deflection(self):
        # 200 Hz, position-controlled, gravity and friction present, the description's starting model.
        ds = real_constant_velocity(2)
        d = diagnose([ds], dataset_model([ds]))
        # The log's lag of the arm's 80 Nm gravity torque is the largest discrepancy of the described model on
        # joint 2; the gravity load is named beside it, within 5 % of the description's.
        assert [e.name for e in d.effects][:2] == ["torque_log_filter", "position_dependent_load"]
        assert d.effect("position_dependent_load").parameters["amplitude_nm"] == pytest.approx(80.55, rel=0.05)
        # The extended model predicts the run (eq (9)'s link through the filter, above the link's resonance
        # too) within the Panda's 1.0 Nm held-out figure; a first-order account of eq (9) left 1.8 Nm.
        # (the log's torque reads the other way round: the diagnosis says so and turns it over; so does this)
        assert "reads the other way round" in d.summary()
        turned = dataclasses.replace(ds, signals={**ds.signals, "tau_j": -np.asarray(ds["tau_j"], float)})
        [(_, _, rms)] = residual_rms([turned], d.extended)
        assert rms < 0.6, rms
        # The ripple's deflection is plain in q_m at the paper's period; its 15 Hz torque line is not in a log
        # filtered at a few Hz: named, or a suspect that says so.
        own = [s for s in d.selection.steps if s.name == "transmission_ripple" and s.band == "deflection"]
        assert own and all(s.gain > 0.3 and s.confidence >= 0.999 for s in own)
        ripple = d.effect("transmission_ripple")
        if ripple is not None:
            assert abs(ripple.parameters["period_rad"] / PAPER_RHO - 1) < 2e-3
        else:
            suspect = next(s for s in d.suspects if s["name"] == "transmission_ripple")
            assert suspect["band"] == "deflection" and "logged torque" in suspect["failed"]

    def test_joint4_ripple_named_and_plain_in_its_deflection(self):
        # Position-controlled: the ripple's torque signature is hundredths of a Nm, its deflection in q_m is plain:
        # the candidate's own evidence channel shows it (the torque's fast band names it too once the log's lag
        # of the gravity torque is named).
        # Where the log's filter is of the second order, the ripple's line would need, through it, a deflection
        # beyond a transmission's: not named, a suspect that says so.
        d = diagnose([real_constant_velocity(4)], dataset_model([real_constant_velocity(4)]))
        own = [s for s in d.selection.steps if s.name == "transmission_ripple" and s.band == "deflection"]
        assert own and all(s.gain > 0.3 and s.delta_bic < 0 and s.confidence >= 0.999 for s in own)
        ripple = d.effect("transmission_ripple")
        if ripple is not None:
            assert abs(ripple.parameters["period_rad"] / PAPER_RHO - 1) < 1e-3
            assert ripple.detail["selected_in"] in ("fast", "deflection")
            assert ripple.confidence >= 0.999
        else:
            assert d.effect("torque_log_filter").parameters["order"] == 2.0
            suspect = next(s for s in d.suspects if s["name"] == "transmission_ripple")
            assert suspect["band"] == "deflection" and "not physically possible" in suspect["failed"]
        assert "position_dependent_load" in [e.name for e in d.effects][:2]


class TestLibrary:
    def test_registry_has_the_required_effects(self):
        for name in ("transmission_ripple", "link_friction", "position_dependent_load", "torque_sensor_offset",
                     "torque_sensor_scale", "periodic_disturbance", "model_parameters"):
            assert name in CANDIDATES and issubclass(CANDIDATES[name], CandidateEffect)

    def test_a_reversed_sign_without_gravity_is_told_by_the_model(self):
        # A chirp of a joint without a described pose: the import's check has no gravity to go by; the model
        # predicts the run turned over far better (a scale of -1), and that is named before any effect.
        import dataclasses

        from iiwa_ident.datasets import torque_sign_problem

        case = _case(15, a="torque_sensor_offset")
        data = simulate_case(case)
        k = next(i for i, ds in enumerate(data) if ds.experiment == "chirp")
        turned = dataclasses.replace(data[k], signals={**data[k].signals, "tau_j": -data[k]["tau_j"]})
        assert torque_sign_problem(turned) is None
        d = diagnose(data[:k] + [turned] + data[k + 1:], table1_model())
        assert [r["dataset"] for r in d.sign_reversed] == [f"dataset {k}"]
        assert "a torque scale of -1); import the log with --scale tau_j=-1" in d.sign_reversed[0]["why"]
        assert [e.name for e in d.effects] == ["torque_sensor_offset"] and not d.explained

    def test_subset_of_candidates(self):
        case = _case(15, a="torque_sensor_offset")
        d = diagnose(simulate_case(case), table1_model(), candidates=["link_friction"])
        # The offset is not among the candidates: named or not, the model does not explain the data.
        assert [e.name for e in d.effects] in ([], ["link_friction"]) and not d.explained
        assert d.unexplained_channels and "the model explains the data" not in d.summary()
        assert "yet the residual fails its tests on" in d.summary() or d.effects
        assert d.as_json()["unexplained_channels"] == [f"{c.dataset}/{c.channel}" for c in d.unexplained_channels]

    def test_errors(self):
        with pytest.raises(IiwaIdentError, match="no dataset"):
            diagnose([], table1_model())

    def test_residual_rms_of_a_model_with_and_without_the_hidden_effect(self):
        # A hidden 6 Nm load: Table I alone leaves it in the link channel; the model carrying the true load
        # predicts every channel to the noise (0.02 Nm sensor noise; eq (9)'s link estimate a few times it).
        case = _case(17, a="position_dependent_load")
        data = simulate_case(case)
        plain = residual_rms(data, table1_model())
        right = table1_model()
        right.effects = [{"name": "position_dependent_load", **SINGLE["position_dependent_load"][0]}]
        with_load = residual_rms(data, right)
        assert [r[:2] for r in plain] == [r[:2] for r in with_load]
        assert max(r[2] for r in plain if r[1] == "link") > 1.0
        assert max(r[2] for r in with_load) < 0.1


def test_residual_tests_before_and_after_the_named_effect():
    # A load Table I lacks: its residual fails the tests on every link channel; with the named load each passes
    # and fits above 99 %. The constant-velocity run's command comes from a tracking PD: not judged.
    d = diagnose(simulate_case(_case(7, a="position_dependent_load")), table1_model())
    assert [e.name for e in d.effects] == ["position_dependent_load"]
    for c in d.channels:
        assert c.before is not None and c.after is not None and c.after.fit_pct > c.before.fit_pct
        if c.channel == "link":
            assert c.before.passed is False and c.after.passed is True, c.after.tests.summary()
            assert c.after.fit_pct > 99.0
        elif c.experiment == "constant_velocity":
            assert c.before.passed is None and c.after.passed is None
    doc = d.as_json()["datasets"]
    assert all(x["ext_torque_error_tests_passed_before"] is False and x["ext_torque_error_tests_passed_after"]
               for x in doc)
    assert "residual tests before -> after" in d.summary() and "FAIL -> pass" in d.summary()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Three simulated runs with a hidden sensor offset and a Table I model file."""
    tmp = tmp_path_factory.mktemp("diag")
    case = _case(16, a="torque_sensor_offset")
    paths = []
    for i, ds in enumerate(simulate_case(case)):
        paths.append(str(write_dataset(tmp / f"d{i}.h5", ds)))
    write_model(tmp / "model.toml", table1_model())
    return tmp, paths


class TestCli:
    def test_help_names_every_candidate(self):
        # The help's list of candidate effects is the library's (a new candidate must be added to both).
        res = CliRunner().invoke(app, ["diagnose", "--help"], terminal_width=200)
        assert res.exit_code == 0
        text = " ".join(res.output.split())
        missing = [name for name in CANDIDATES if name not in text]
        assert not missing, missing

    def test_json_and_extended_model(self, files):
        tmp, paths = files
        res = CliRunner().invoke(app, ["diagnose", "--model", str(tmp / "model.toml"), "--json", str(tmp / "d.json"),
                                       "--out", str(tmp / "ext.toml"), "--figures", str(tmp / "fig"), *paths])
        assert res.exit_code == 0, res.output
        doc = json.loads((tmp / "d.json").read_text())
        assert set(doc) >= {"explained", "effects", "model_out"}
        assert doc["explained"] is False and doc["model_out"] == str(tmp / "ext.toml")
        e = doc["effects"][0]
        assert set(e) >= {"name", "confidence", "parameters", "rms_before", "rms_after", "gain_pct"}
        assert e["name"] == "torque_sensor_offset" and abs(e["parameters"]["offset_nm"] + 0.8) < 0.05
        ext = read_model(tmp / "ext.toml")
        # Torque-commanded runs tell where the loop sees the offset: here all of it (none on the log only).
        assert ext.effects == [{"name": "torque_sensor_offset", "offset_nm": pytest.approx(-0.8, abs=0.05),
                                "logged_nm": pytest.approx(0.0, abs=0.05)}]
        trace = SimulatedJoint(plant_from_model(ext), seed=1).run_open_loop(tau_c=np.full(300, 2.0))
        assert np.all(np.isfinite(trace.measured["tau_j"]))
        figs = {p.name for p in (tmp / "fig").iterdir()}
        assert {"diagnose_gain_table.png", "diagnose_evidence_torque_sensor_offset.png"} <= figs

    @pytest.mark.parametrize("kind", ["missing_data", "missing_model", "bad_model"])
    def test_one_line_errors(self, files, kind):
        tmp, paths = files
        (tmp / "bad.toml").write_text("format = 'iiwa-ident-model'\nformat_version = 1\n[parameters]\n")
        model = {"missing_model": tmp / "nope.toml", "bad_model": tmp / "bad.toml"}.get(kind, tmp / "model.toml")
        data = [str(tmp / "nope.h5")] if kind == "missing_data" else paths[:1]
        res = CliRunner().invoke(app, ["diagnose", "--model", str(model), *data])
        assert res.exit_code == 2
        lines = [ln for ln in res.output.strip().splitlines() if ln]
        assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in res.output
        assert ("nope" in lines[0]) or ("bad.toml" in lines[0])


# Fast subset of the randomised batch (the whole batch: bench/bench_diagnose.py).
