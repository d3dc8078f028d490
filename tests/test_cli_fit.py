"""CLI ``iiwa-ident fit``: outputs, JSON keys, figures, base model and one-line refusals."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.cli._fit_cmd import format_fit
from iiwa_ident.datasets import Dataset, read_dataset, sha256_file, write_dataset
from iiwa_ident.excite import Chirp, record
from iiwa_ident.ident import read_model, write_model
from iiwa_ident.ident._tf_fit import fit_transfer_function
from iiwa_ident.model import PARAMETER_NAMES, table1_model
from iiwa_ident.sim import SimulatedJoint, default_plant

runner = CliRunner()
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def chirps(tmp_path_factory):
    """Two short chirps (default plant, ripple on) of joint 1, and one relabelled as joint 2."""
    folder = tmp_path_factory.mktemp("cli_fit")
    paths = []
    for seed in (1, 2):
        ds = record(SimulatedJoint(default_plant(), seed=seed), Chirp(f0_hz=1.0, duration_s=10.0))
        paths.append(write_dataset(folder / f"chirp{seed}.h5", ds))
    ds = read_dataset(paths[0])
    other = Dataset(signals=dict(ds.signals), experiment="chirp", source="simulation", joint=2,
                    sample_rate_hz=ds.sample_rate_hz, experiment_attrs=dict(ds.experiment_attrs))
    paths.append(write_dataset(folder / "joint2.h5", other))
    return paths


class TestFitCommand:
    def test_writes_model_json_and_figures(self, chirps, tmp_path):
        out, js, figs = tmp_path / "m.toml", tmp_path / "m.json", tmp_path / "figs"
        res = invoke("fit", chirps[0], "--out", out, "--json", js, "--figures", figs)
        assert res.exit_code == 0, res.output
        model = read_model(out)
        assert model.sources[0].sha256 == sha256_file(chirps[0])
        assert model.parameters["KI"].value == 25.0
        doc = json.loads(js.read_text())
        assert {"parameters", "correlation", "bands", "nonlinear_share", "warnings"} <= set(doc)
        # The std names how it was computed (and that it describes the noise only).
        assert "noise" in doc["std_method"] and model.fit["std_method"] == doc["std_method"]
        assert set(doc["parameters"]) == set(PARAMETER_NAMES)
        for name in PARAMETER_NAMES:
            entry = doc["parameters"][name]
            assert entry["value"] > 0 and entry["std"] > 0
            assert entry["value"] == pytest.approx(model.value(name), rel=1e-12, abs=0)
            # The model-error aware std: the same where the residual tests pass, wider where they fail.
            assert entry["std_robust"] == entry["std"] if not doc["model_rejected"] else \
                entry["std_robust"] >= entry["std"]
        assert model.fit["std_robust"] == [doc["parameters"][k]["std_robust"] for k in PARAMETER_NAMES]
        assert doc["parameters"]["Td"]["value"] == pytest.approx(0.005, rel=0, abs=0.5e-3)  # seconds
        assert doc["correlation"]["names"] == list(PARAMETER_NAMES)
        assert np.asarray(doc["correlation"]["matrix"]).shape == (5, 5)
        assert {"lo_hz", "hi_hz", "rel_error", "z_rms", "coherence"} <= set(doc["bands"][0])
        assert {"lo_hz", "hi_hz", "share", "harmonics"} <= set(doc["nonlinear_share"][0])
        assert all(isinstance(w, str) for w in doc["warnings"])
        for name in ("bode.png", "harmonics.png"):
            assert (figs / name).read_bytes()[:8] == PNG_MAGIC

    def test_prints_tables(self, chirps, tmp_path):
        res = invoke("fit", chirps[0], "--out", tmp_path / "m.toml")
        assert res.exit_code == 0, res.output
        text = res.output
        for needle in ("parameter", "rel. std", "delay Td =", " ms", "fit quality per octave band",
                       "nonlinear share per octave band", "wrote"):
            assert needle in text
        lines = {line.split()[0]: line for line in text.splitlines() if line.split()}
        assert "kg m^2" in lines["Jc"] and "Nm/rad" in lines["K"] and "ms" in lines["Td"]
        # Every number shown is one: no "+- nan" for the ripple's searched period, no std of 0.000 ms for a
        # delay known to microseconds, no warning cut short.
        assert "nan" not in text and "period_rad = 0.01" in text and "(searched, no std)" in text
        td = re.search(r"delay Td = (\S+) \+- (\S+) ms", text)
        assert float(td.group(2)) > 0.0, td.group(0)
        assert "the std holds only for the first" not in text

    def test_two_files(self, chirps, tmp_path):
        out, figs = tmp_path / "m.toml", tmp_path / "figs"
        res = invoke("fit", chirps[0], chirps[1], "--out", out, "--figures", figs)
        assert res.exit_code == 0, res.output
        assert "chirp1.h5" in res.output and "chirp2.h5" in res.output
        assert {s.file for s in read_model(out).sources} == {str(chirps[0]), str(chirps[1])}
        assert sorted(p.name for p in figs.iterdir()) == ["bode_1.png", "bode_2.png", "harmonics_1.png",
                                                         "harmonics_2.png"]

    def test_base_model(self, chirps, tmp_path):
        base = table1_model()
        base.parameters["KI"].value = 40.0
        base_path = write_model(tmp_path / "base.toml", base)
        out = tmp_path / "m.toml"
        res = invoke("fit", chirps[0], "--out", out, "--model", base_path)
        assert res.exit_code == 0, res.output
        model = read_model(out)
        assert model.value("KI") == 40.0
        assert [s.role for s in model.sources] == ["fit", "base"]

    def test_help_has_example(self):
        res = invoke("fit", "--help")
        assert res.exit_code == 0
        assert "Example" in res.output and "iiwa-ident fit chirp.h5" in res.output


class TestFitErrors:
    def assert_refused(self, res, message, *unwritten):
        assert res.exit_code == 2, res.output
        assert message in res.output
        assert "Traceback" not in res.output
        assert len([ln for ln in res.output.splitlines() if ln.startswith("error:")]) == 1
        for path in unwritten:
            assert not path.exists()

    def test_no_torque_command(self, chirps, tmp_path):
        ds = read_dataset(chirps[0])
        signals = {k: v for k, v in ds.signals.items() if k != "tau_c"}
        path = write_dataset(tmp_path / "no_tau_c.h5", Dataset(signals=signals, experiment="chirp", source="simulation",
                                                               joint=1, sample_rate_hz=1000.0))
        out, js = tmp_path / "m.toml", tmp_path / "m.json"
        res = invoke("fit", path, "--out", out, "--json", js)
        self.assert_refused(res, f"{path}: no torque command: fit needs a torque-commanded chirp", out, js)
        # What such a log still gives, and how to record what the fit needs.
        for say in ("chirp --target robot", "'ripple'", "'diagnose'", "'pipeline --logs'"):
            assert say in res.output, res.output

    def test_missing_file(self, tmp_path):
        out = tmp_path / "m.toml"
        res = invoke("fit", tmp_path / "nope.h5", "--out", out)
        self.assert_refused(res, "nope.h5", out)

    def test_inconsistent_joints(self, chirps, tmp_path):
        out = tmp_path / "m.toml"
        res = invoke("fit", chirps[0], chirps[2], "--out", out)
        self.assert_refused(res, "joint2.h5: joint 2", out)

    def test_out_is_a_folder(self, chirps, tmp_path):
        js = tmp_path / "m.json"
        res = invoke("fit", chirps[0], "--out", tmp_path, "--json", js)
        self.assert_refused(res, "is a directory", js)

    def test_bad_base_model(self, chirps, tmp_path):
        bad = tmp_path / "bad.toml"
        bad.write_text("format = 'something else'\n")
        out = tmp_path / "m.toml"
        res = invoke("fit", chirps[0], "--out", out, "--model", bad)
        self.assert_refused(res, f"{bad}: format", out)

    def test_a_chirp_too_weak_to_free_the_motor_is_refused_naming_the_robot_s_1_nm(self, tmp_path):
        # Below 1 Nm of command and torque the robot does not move a motor from standstill (section II.A): the
        # motor stays held from the first sample to the last. Was refused naming Jl, after many lines of
        # LAPACK's "DLASCL parameter 4" on stderr.
        amplitude = float(np.random.default_rng().uniform(0.75, 0.95))  # its std above the 0.5 Nm the fit needs
        chirp = tmp_path / "weak.h5"
        assert invoke("chirp", "--target", "sim", "--duration", 4, "--amplitude", amplitude, "--bias", 0,
                      "--out", chirp).exit_code == 0
        out = tmp_path / "m.toml"
        res = subprocess.run([str(Path(sys.executable).with_name("iiwa-ident")), "fit", str(chirp), "--out", str(out)],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 2, res.stderr
        assert res.stderr.strip().splitlines() == [res.stderr.strip()], res.stderr
        assert f"{chirp}: the robot held the motor still for 100 % of the record" in res.stderr
        assert "below the 1 Nm" in res.stderr and not out.exists()

    def test_existing_output_untouched_on_error(self, chirps, tmp_path):
        out = tmp_path / "m.toml"
        out.write_text("keep me\n")
        res = invoke("fit", tmp_path / "nope.h5", "--out", out)
        assert res.exit_code == 2
        assert out.read_text() == "keep me\n"


class TestFormatFit:
    def test_parameter_rows_and_units(self, chirps):
        result = fit_transfer_function([read_dataset(chirps[0])])
        text = format_fit(result)
        td_line = next(line for line in text.splitlines() if line.startswith("Td "))
        value_ms = float(td_line.split()[1])
        assert value_ms == pytest.approx(result.parameters["Td"] * 1e3, rel=1e-5, abs=0)
        assert text.count(" Hz") >= len(result.bands)


@pytest.fixture(scope="module")
def multisine(tmp_path_factory):
    from iiwa_ident.excite import Multisine

    exp = Multisine(1.0, 100.0, period_s=1.0, periods=2, realisations=3, amplitude_nm=10.0, seed=3)
    ds = record(SimulatedJoint(default_plant().without_effects(), seed=3), exp)
    return write_dataset(tmp_path_factory.mktemp("ms") / "ms.h5", ds)


class TestFitMultisine:
    def test_fits_through_the_bla_and_reports_both_variances(self, multisine, tmp_path):
        out, js = tmp_path / "m.toml", tmp_path / "m.json"
        res = runner.invoke(app, ["fit", str(multisine), "--out", str(out), "--json", str(js)])
        assert res.exit_code == 0, res.output
        assert "chi2/dof" in res.output and "nonlinear" in res.output
        doc = json.loads(js.read_text())
        assert doc["method"] == "bla" and "total variance" in doc["std_method"]
        outputs = {b["output"] for b in doc["variance_bands"]}
        assert outputs == {"tau_j", "q_m"}
        assert all(b["noise_rel"] >= 0 and b["nonlinear_rel"] >= 0 for b in doc["variance_bands"])
        model = read_model(out)
        truth = default_plant().dynamics
        for k in PARAMETER_NAMES:
            p = model.parameters[k]
            assert abs(p.value - truth[k]) <= 4 * p.std, (k, p.value, truth[k], p.std)
        assert model.fit["chi2_dof"] == pytest.approx(doc["chi2_dof"])
        assert model.sources[0].sha256 == sha256_file(multisine)

    def test_not_together_with_a_chirp(self, multisine, tmp_path):
        chirp = write_dataset(tmp_path / "c.h5", record(SimulatedJoint(default_plant()), Chirp(duration_s=3.0)))
        res = runner.invoke(app, ["fit", str(multisine), str(chirp), "--out", str(tmp_path / "m.toml")])
        assert res.exit_code == 2 and "fit multisines alone" in res.output
        assert "Traceback" not in res.output and not (tmp_path / "m.toml").exists()

    @pytest.mark.parametrize("extra, message", [(["--method", "idim"], "method 'idim' is a chirp estimator"),
                                                (["--figures", "figs"], "--figures: the plots are of chirp fits")])
    def test_chirp_only_options_refused(self, multisine, tmp_path, extra, message):
        res = runner.invoke(app, ["fit", str(multisine), "--out", str(tmp_path / "m.toml"), *extra])
        assert res.exit_code == 2 and message in res.output
        assert len(res.output.strip().splitlines()) == 1


def test_the_analysis_commands_run_with_one_blas_thread(monkeypatch):
    """fit, ripple, diagnose, design, deploy and report run inside single_threaded_blas; the others do not."""
    import contextlib

    import typer

    import iiwa_ident._blas as blas
    from iiwa_ident.cli._app import ANALYSIS_COMMANDS

    entered = []

    @contextlib.contextmanager
    def spy():
        entered.append(True)
        yield

    monkeypatch.setattr(blas, "single_threaded_blas", spy)
    group = typer.main.get_command(app)
    for name, command in group.commands.items():
        entered.clear()
        monkeypatch.setattr(command, "callback", lambda *a, **k: None)
        ctx = command.make_context(name, [], resilient_parsing=True)
        command.invoke(ctx)
        assert entered == ([True] if name in ANALYSIS_COMMANDS else []), name
    assert set(ANALYSIS_COMMANDS) <= set(group.commands)
