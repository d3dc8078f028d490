"""Transfer-function fit: the sampled model, the start values, the ML fit and the model file.

The accuracy tests draw a random truth within +-40 % of Table I, simulate a
30 s chirp with the default noise and the default transmission ripple, and
fit the file with the library and with the CLI.
"""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest
from scipy.linalg import expm
from typer.testing import CliRunner

from conftest import quiet, smooth_command
from iiwa_ident.cli import app
from iiwa_ident.datasets import Dataset, read_dataset, sha256_file, write_dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import Chirp, record
from iiwa_ident.ident import read_model, write_model
from iiwa_ident.ident._initial import initial_estimate
from iiwa_ident.ident._joint_fit import fit_joint, fit_model
from iiwa_ident.ident._tf_fit import cramer_rao_std, fit_transfer_function
from iiwa_ident.model import PARAMETER_NAMES, discretize, frequency_response, simulate_outputs, table1_model
from iiwa_ident.sim import SimulatedJoint, TorqueLogFilter, default_plant, make_effect

TABLE1 = {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}
REL_TOL = 0.03  # required accuracy of Jc, bc, K, Jl
TD_TOL_S = 0.5e-3  # required accuracy of Td
runner = CliRunner()


def random_truth(seed: int) -> dict[str, float]:
    """Each parameter uniform in [0.6, 1.4] x its Table I value."""
    rng = np.random.default_rng(seed)
    return {k: v * rng.uniform(0.6, 1.4) for k, v in TABLE1.items()}


def simulate_chirp(truth: dict[str, float], seed: int, ripple: bool = True, log_filter_hz: float | None = None,
                   **chirp) -> Dataset:
    plant = default_plant() if ripple else default_plant().without_effects()
    if log_filter_hz is not None:  # the logged torque through a first-order low-pass
        plant = plant.with_effects(make_effect("torque_log_filter", {"cutoff_hz": log_filter_hz}))
    plant.dynamics.update(truth)
    return record(SimulatedJoint(plant, seed=seed), Chirp(**chirp))


def assert_accurate(values: dict[str, float], truth: dict[str, float]) -> None:
    for name in ("Jc", "bc", "K", "Jl"):
        assert values[name] == pytest.approx(truth[name], rel=REL_TOL, abs=0), name
    assert values["Td"] == pytest.approx(truth["Td"], rel=0, abs=TD_TOL_S)


def reference_outputs(params: dict[str, float], u: np.ndarray, T: float) -> np.ndarray:
    """Brute-force state recursion with the fractional-delay ZOH integrals (scipy expm)."""
    Jc, bc, K, Jl, Td = (params[k] for k in PARAMETER_NAMES)
    A = np.array([[-bc / Jc, 1 / Jc, bc / Jc, 0], [-K, 0, K, 0], [0, 0, 0, 1], [K / Jl, 0, -K / Jl, 0]])
    B = np.array([bc / (K * Jc), 1, 0, 0])

    def zoh(h):
        M = np.zeros((5, 5))
        M[:4, :4], M[:4, 4] = A * h, B * h
        E = expm(M)
        return E[:4, :4], E[:4, 4]

    d = int(np.floor(Td / T))
    tau = Td - d * T
    Ea, G0 = zoh(T - tau)
    _, I1 = zoh(tau)
    G1 = Ea @ I1
    Phi, _ = zoh(T)
    x = np.zeros(4)
    out = np.zeros((2, len(u)))
    for k in range(len(u)):
        out[:, k] = K * (x[0] - x[2]), x[0]
        x = Phi @ x + G0 * (u[k - d] if k >= d else 0.0) + G1 * (u[k - d - 1] if k >= d + 1 else 0.0)
    return out


# --------------------------------------------------------------------------
# model


class TestEq4FrequencyResponse:
    def test_dc_gain(self):
        # At DC the link and the motor share the command: Jl / (Jc + Jl).
        H = frequency_response(TABLE1, np.array([1e-6]))
        np.testing.assert_allclose(H, TABLE1["Jl"] / (TABLE1["Jc"] + TABLE1["Jl"]), rtol=1e-6, atol=0)

    def test_delay_is_pure_phase(self):
        f = np.array([3.0, 30.0, 150.0])
        no_delay = dict(TABLE1, Td=0.0)
        ratio = frequency_response(TABLE1, f) / frequency_response(no_delay, f)
        np.testing.assert_allclose(ratio, np.exp(-2j * np.pi * f * TABLE1["Td"]), rtol=1e-12, atol=0)

    def test_high_frequency_asymptote(self):
        # |H| -> bc / (Jc w) well above the resonance.
        f = 5000.0
        H = frequency_response(TABLE1, np.array([f]))
        np.testing.assert_allclose(abs(H), TABLE1["bc"] / (TABLE1["Jc"] * 2 * np.pi * f), rtol=1e-2, atol=0)


    def test_other_inputs(self):
        f = np.array([1e-6])
        Jc, Jl = TABLE1["Jc"], TABLE1["Jl"]
        # At DC a torque on the link is shared the other way round: -Jc / (Jc + Jl) reaches tau_j.
        np.testing.assert_allclose(frequency_response(TABLE1, f, "link"), -Jc / (Jc + Jl), rtol=1e-6, atol=0)
        g = np.array([3.0, 30.0, 150.0])
        np.testing.assert_allclose(frequency_response(TABLE1, g, "motor"),
                                   frequency_response(dict(TABLE1, Td=0.0), g), rtol=1e-12, atol=0)
        # The exact sampled model with the same input agrees well below the sampling rate (the hold's
        # half-sample lag is the difference).
        T = 1e-3
        for kind in ("link", "motor"):
            dm = discretize(TABLE1, T, kind)
            got = dm.frequency_response(np.array([0.5, 1.0, 2.0]))[0]
            want = frequency_response(TABLE1, np.array([0.5, 1.0, 2.0]), kind)
            np.testing.assert_allclose(got, want, rtol=1e-2, atol=0)


class TestDiscretize:
    @pytest.mark.parametrize("Td", [0.005, 0.0053, 0.00749, 0.0])
    def test_matches_bruteforce_recursion(self, Td):
        params = dict(TABLE1, Td=Td)
        u = smooth_command(600) + np.sin(np.arange(600) * 0.7)  # rich up to Nyquist
        np.testing.assert_allclose(simulate_outputs(params, u, 1e-3), reference_outputs(params, u, 1e-3),
                                   rtol=1e-7, atol=1e-9)

    def test_matches_control_c2d_for_whole_delay(self):
        d = TABLE1
        G = ct.tf([d["Jl"] * d["bc"], d["Jl"] * d["K"]],
                  [d["Jc"] * d["Jl"], d["Jl"] * d["bc"], (d["Jc"] + d["Jl"]) * d["K"]])
        Gd = ct.c2d(G, 1e-3, "zoh")
        f = np.array([1.0, 23.0, 150.0])
        z = np.exp(2j * np.pi * f * 1e-3)
        np.testing.assert_allclose(discretize(TABLE1, 1e-3).frequency_response(f)[0], Gd(z) * z**-5,
                                   rtol=1e-8, atol=0)

    def test_frequency_response_matches_simulation(self):
        # Steady sine through the recursion against the model's sampled-data response.
        dm = discretize(dict(TABLE1, Td=0.0047), 1e-3)
        f = 37.0
        n = 4000
        u = np.sin(2 * np.pi * f * np.arange(n) * 1e-3)
        y = dm.simulate(u)[0][2000:]
        t = np.arange(2000, n) * 1e-3
        e = np.exp(-2j * np.pi * f * t)
        H_sim = 2 * np.mean(y * e) / (-1j)  # u = sin: its phasor is -j
        np.testing.assert_allclose(H_sim, dm.frequency_response(np.array([f]))[0][0], rtol=1e-3, atol=0)

    def test_torque_channel_is_scale_invariant_position_channel_is_not(self):
        u = smooth_command(800)
        scaled = {k: (v * 1.7 if k != "Td" else v) for k, v in TABLE1.items()}
        a, b = simulate_outputs(TABLE1, u, 1e-3), simulate_outputs(scaled, u, 1e-3)
        np.testing.assert_allclose(a[0], b[0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a[1], 1.7 * b[1], rtol=1e-9, atol=1e-12)

    def test_position_obeys_free_link(self):
        # q_m = theta_l + tau_j / K with Jl theta_l'' = tau_j: check the second difference.
        u = smooth_command(2000)
        tau, q = simulate_outputs(TABLE1, u, 1e-3)
        theta_l = q - tau / TABLE1["K"]
        acc = np.diff(theta_l, 2) / 1e-6
        np.testing.assert_allclose(TABLE1["Jl"] * acc, tau[1:-1], rtol=0, atol=0.02 * np.abs(tau).max())

    def test_rejects_bad_parameters(self):
        with pytest.raises(ValueError):
            discretize(dict(TABLE1, K=-1.0), 1e-3)


class TestSimulateOutputs:
    def test_matches_simulated_joint(self):
        # The simulator without effects or noise, a command within the slew limit and clear
        # of the standstill threshold: the sampled model reproduces it (fractional delay 5.3 ms).
        plant = quiet(default_plant().without_effects())
        plant.dynamics["Td"] = 0.0053
        u = smooth_command(3000)
        meas = SimulatedJoint(plant).run_open_loop(u).measured
        y = simulate_outputs(plant.dynamics, u, 1e-3)
        np.testing.assert_allclose(meas["tau_j"][:-1], y[0], rtol=0, atol=1e-8 * np.abs(y[0]).max())
        q = meas["q_m"][:-1] - meas["q_m"][0]
        np.testing.assert_allclose(q, y[1], rtol=0, atol=1e-8 * np.abs(y[1]).max())
        # A whole-sample delay (what an integer-delay model would use) is visibly worse.
        y5 = simulate_outputs(dict(plant.dynamics, Td=0.005), u, 1e-3)
        assert np.abs(meas["tau_j"][:-1] - y5[0]).max() > 1e-3 * np.abs(y[0]).max()


# --------------------------------------------------------------------------
# fits on simulated chirps


@pytest.fixture(scope="module")
def ripple_files(tmp_path_factory):
    """Three random truths, ripple and noise on, 15 s chirps: (path, truth) per seed."""
    out = []
    for seed in (11, 12, 13):
        truth = random_truth(seed)
        path = tmp_path_factory.mktemp("fit") / f"chirp_{seed}.h5"
        write_dataset(path, simulate_chirp(truth, seed, duration_s=15.0))
        out.append((path, truth))
    return out


class TestInitialEstimate:
    def test_start_values_from_data(self, ripple_files):
        path, truth = ripple_files[0]
        starts = initial_estimate([read_dataset(path)])
        assert 1 <= len(starts) <= 3
        best = starts[0]
        for name in ("Jc", "bc", "K", "Jl"):
            assert best[name] == pytest.approx(truth[name], rel=0.15, abs=0), name
        assert best["Td"] == pytest.approx(truth["Td"], rel=0, abs=0.3e-3)


class TestFitTransferFunction:
    def test_random_truths_library_and_cli(self, ripple_files, tmp_path):
        from iiwa_ident._blas import single_threaded_blas

        for i, (path, truth) in enumerate(ripple_files):
            with single_threaded_blas():  # as the command runs it: the same rounding, the same search path
                joint = fit_joint([read_dataset(path)])
            assert_accurate(joint.parameters, truth)
            if i:
                continue
            # Once: eq (4) alone, and the command against the library.
            assert_accurate(fit_transfer_function([read_dataset(path)]).parameters, truth)
            out, js = tmp_path / f"{path.stem}.toml", tmp_path / f"{path.stem}.json"
            res = runner.invoke(app, ["fit", str(path), "--out", str(out), "--json", str(js)])
            assert res.exit_code == 0, res.output
            doc = json.loads(js.read_text())
            cli_values = {k: doc["parameters"][k]["value"] for k in PARAMETER_NAMES}
            assert doc["method"] == joint.method
            for k in PARAMETER_NAMES:
                assert cli_values[k] == pytest.approx(joint.parameters[k], rel=1e-9, abs=0)
            model = read_model(out)
            assert model.value("K") == pytest.approx(joint.parameters["K"], rel=1e-12, abs=0)

    def test_result_contents(self, ripple_files):
        result = fit_transfer_function([read_dataset(ripple_files[1][0])])
        assert set(result.std) == set(PARAMETER_NAMES)
        assert all(result.std[k] > 0 and result.std_sandwich[k] > 0 for k in PARAMETER_NAMES)
        np.testing.assert_allclose(np.diag(result.correlation), 1.0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(result.correlation, result.correlation.T, rtol=0, atol=1e-12)
        assert [(b.lo_hz, b.hi_hz) for b in result.bands][0] == (0.5, 1.0)
        assert len(result.nonlinear[0]) == 9
        # The ripple makes the torque residual far larger than the 0.02 Nm sensor noise.
        assert result.noise[0]["tau_j_nm"] > 0.05
        assert any("far from white noise" in w for w in result.warnings)

    def test_ripple_off(self, tmp_path):
        truth = random_truth(21)
        ds = simulate_chirp(truth, 21, ripple=False)
        result = fit_transfer_function([ds])
        assert_accurate(result.parameters, truth)
        # Without the ripple the fit is much closer than required.
        for name in ("Jc", "bc", "K", "Jl"):
            assert result.parameters[name] == pytest.approx(truth[name], rel=0.005, abs=0), name
        assert result.noise[0]["tau_j_nm"] < 0.06

    def test_two_files_together(self, tmp_path):
        truth = random_truth(31)
        datasets = [simulate_chirp(truth, seed, duration_s=15.0) for seed in (31, 32)]
        result = fit_transfer_function(datasets)
        assert_accurate(result.parameters, truth)
        assert len(result.frf) == 2 and len(result.noise) == 2
        assert {b.dataset for b in result.bands} == {"dataset 1", "dataset 2"}
        single = fit_transfer_function(datasets[:1])
        # Two files carry more information than one.
        assert result.std["K"] < single.std["K"]

    def test_through_a_log_filter(self):
        # The logged torque passed a first-order low-pass: with the filter in the model (its cut-off a sixth
        # parameter, started 30 % off) the parameters come out as without one (the simulator's own delay error
        # aside, the same with and without), the cut-off within 0.5 %.
        rng = np.random.default_rng(41)
        truth, fc = random_truth(41), float(rng.uniform(8.0, 15.0))
        ds = simulate_chirp(truth, 41, ripple=False, log_filter_hz=fc)
        start = {k: v * (1.2 if k != "Td" else 1.0) for k, v in truth.items()}
        result = fit_transfer_function([ds], initial=start, log_filter=TorqueLogFilter({"cutoff_hz": 0.7 * fc}))
        for name in ("Jc", "bc", "K", "Jl"):
            assert result.parameters[name] == pytest.approx(truth[name], rel=0.005, abs=0), name
        assert result.parameters["Td"] == pytest.approx(truth["Td"], rel=0, abs=0.1e-3)
        got = result.log_filter
        assert got["order"] == 1 and 0 < got["std"] and got["cutoff_hz"] == pytest.approx(fc, rel=0.005), (got, fc)
        assert result.noise[0]["tau_j_nm"] < 0.03
        # Without the filter in the model the same data are fitted far worse.
        plain = fit_transfer_function([ds], initial=start)
        assert plain.noise[0]["tau_j_nm"] > 3 * result.noise[0]["tau_j_nm"]

    def test_given_start_values(self, ripple_files):
        path, truth = ripple_files[2]
        start = {k: v * (1.2 if k != "Td" else 1.0) for k, v in truth.items()}
        result = fit_transfer_function([read_dataset(path)], initial=start)
        assert_accurate(result.parameters, truth)


class TestRefusals:
    @pytest.fixture(scope="class")
    @classmethod
    def short_chirp(cls):
        return simulate_chirp(TABLE1, 1, ripple=False, duration_s=3.0, f0_hz=2.0, f1_hz=100.0)

    def test_no_torque_command(self, short_chirp):
        ds = Dataset(signals={k: v for k, v in short_chirp.signals.items() if k != "tau_c"}, experiment="chirp",
                     source="simulation", joint=1, sample_rate_hz=1000.0)
        with pytest.raises(IiwaIdentError, match="dataset 1: no torque command: fit needs a torque-commanded chirp"):
            fit_transfer_function([ds])

    def test_too_short(self, short_chirp):
        ds = Dataset(signals={k: v[:1500] for k, v in short_chirp.signals.items()}, experiment="chirp",
                     source="simulation", joint=1, sample_rate_hz=1000.0,
                     experiment_attrs=dict(short_chirp.experiment_attrs))
        with pytest.raises(IiwaIdentError, match="too short for a fit"):
            fit_transfer_function([ds])

    def test_too_little_excitation(self, short_chirp):
        signals = dict(short_chirp.signals)
        signals["tau_c"] = 3.0 + 0.01 * np.sin(np.arange(len(signals["t"])) * 0.1)
        ds = Dataset(signals=signals, experiment="chirp", source="simulation", joint=1, sample_rate_hz=1000.0)
        with pytest.raises(IiwaIdentError, match="too little excitation"):
            fit_transfer_function([ds])

    def test_no_coherent_band(self, short_chirp):
        rng = np.random.default_rng(0)
        signals = dict(short_chirp.signals)
        signals["tau_c"] = rng.standard_normal(len(signals["t"]))  # unrelated to tau_j
        ds = Dataset(signals=signals, experiment="chirp", source="simulation", joint=1, sample_rate_hz=1000.0,
                     experiment_attrs=dict(short_chirp.experiment_attrs))
        with pytest.raises(IiwaIdentError, match="no band with coherence"):
            fit_transfer_function([ds])

    def test_inconsistent_joints(self, short_chirp, tmp_path):
        other = Dataset(signals=dict(short_chirp.signals), experiment="chirp", source="simulation", joint=2,
                        sample_rate_hz=1000.0, experiment_attrs=dict(short_chirp.experiment_attrs))
        a, b = write_dataset(tmp_path / "a.h5", short_chirp), write_dataset(tmp_path / "b.h5", other)
        with pytest.raises(IiwaIdentError, match=r"b\.h5: joint 2, but .*a\.h5 is joint 1"):
            fit_model([a, b])

    def test_decimated_log(self, short_chirp):
        # Every fifth cycle of a sweep up to 100 Hz: the command between samples is lost.
        signals = {k: v[::5] for k, v in short_chirp.signals.items()}
        ds = Dataset(signals=signals, experiment="chirp", source="simulation", joint=1, sample_rate_hz=200.0,
                     experiment_attrs=dict(short_chirp.experiment_attrs))
        with pytest.raises(IiwaIdentError, match="recorded at 200 Hz, too slow for a sweep up to 100 Hz"):
            fit_transfer_function([ds])

    def test_non_uniform_time(self, short_chirp):
        signals = dict(short_chirp.signals)
        t = signals["t"].copy()
        t[100:] += 0.0004
        signals["t"] = t
        with pytest.raises(IiwaIdentError, match="not uniform"):
            fit_transfer_function([Dataset(signals=signals, experiment="chirp", source="simulation", joint=1,
                                           sample_rate_hz=1000.0)])


class TestLostCycles:
    """Over FRI a lost message leaves a gap in the log while the robot holds its command."""

    @staticmethod
    def _fri_like(lost: np.ndarray, seed: int = 3) -> Dataset:
        chirp = simulate_chirp(TABLE1, seed, ripple=False, duration_s=8.0, f0_hz=1.0, f1_hz=100.0)
        u = chirp["tau_c"].copy()
        for k in lost:  # the robot repeats the previous command in a cycle it got no answer for
            u[k] = u[k - 1]
        plant = default_plant().without_effects()
        trace = SimulatedJoint(plant, seed=seed).run_open_loop(tau_c=u)
        keep = np.setdiff1d(np.arange(len(u)), lost)
        signals = {"t": chirp["t"][keep], "q_m": trace.measured["q_m"][keep], "tau_j": trace.measured["tau_j"][keep],
                   "tau_c": u[keep]}
        return Dataset(signals=signals, experiment="chirp", source="robot", joint=1, sample_rate_hz=1000.0,
                       experiment_attrs=dict(chirp.experiment_attrs))

    def test_few_lost_cycles_are_filled_and_reported(self):
        rng = np.random.default_rng(0)
        lost = np.sort(rng.choice(np.arange(100, 7900), 40, replace=False))  # 0.5 %, single cycles
        result = fit_transfer_function([self._fri_like(lost)])
        assert_accurate(result.parameters, TABLE1)
        assert any("40 lost robot cycles filled" in w for w in result.warnings)

    def test_too_many_lost_cycles_refused(self):
        lost = np.arange(1000, 1200, 2)[:100]  # 1.25 % of the cycles
        with pytest.raises(IiwaIdentError, match="100 robot cycles lost"):
            fit_transfer_function([self._fri_like(lost)])


class TestFitModel:
    def test_model_file_round_trip(self, ripple_files, tmp_path):
        path, _ = ripple_files[0]
        model, result = fit_model([path])
        assert model.parameters["KI"].value == 25.0 and model.parameters["KI"].std is None
        assert model.correlation_names == list(PARAMETER_NAMES)
        assert model.sources[0].sha256 == sha256_file(path) and model.sources[0].role == "fit"
        assert model.joint == 1
        out = write_model(tmp_path / "m.toml", model)
        back = read_model(out)
        for k in PARAMETER_NAMES:
            assert back.value(k) == pytest.approx(result.parameters[k], rel=1e-12, abs=0)
            assert back.parameters[k].std == pytest.approx(result.std[k], rel=1e-12, abs=0)
        np.testing.assert_allclose(back.correlation, result.correlation, rtol=0, atol=1e-12)
        assert back.fit["band_lo_hz"][0] == 0.5
        assert len(back.fit["nonlinear_share"]) == 9
        assert back.sources[0].sha256 == sha256_file(path)

    def test_base_model_supplies_ki(self, ripple_files, tmp_path):
        path, _ = ripple_files[0]
        base = table1_model()
        base.parameters["KI"].value, base.parameters["KI"].std = 31.0, 2.0
        base_path = write_model(tmp_path / "base.toml", base)
        model, _ = fit_model([path], base_model=base_path)
        assert model.parameters["KI"].value == 31.0 and model.parameters["KI"].std == 2.0
        roles = {s.role: s for s in model.sources}
        assert roles["base"].sha256 == sha256_file(base_path)


class TestCramerRao:
    def test_bound_with_nuisance_is_wider(self, ripple_files):
        ds = read_dataset(ripple_files[0][0])
        plain = cramer_rao_std(TABLE1, [ds], 0.02, 5.989e-8 / math.sqrt(12), nuisance=False)
        with_nuisance = cramer_rao_std(TABLE1, [ds], 0.02, 5.989e-8 / math.sqrt(12))
        for k in PARAMETER_NAMES:
            assert 0 < plain[k] <= with_nuisance[k] * (1 + 1e-6)
