"""CLI: chirp, simulate and plant through typer's runner."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.datasets import read_dataset

runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


class TestChirpCommand:
    def test_writes_dataset(self, tmp_path):
        out = tmp_path / "chirp.h5"
        res = invoke("chirp", "--target", "sim", "--duration", 2, "--f1", 50, "--seed", 3, "--out", out)
        assert res.exit_code == 0, res.output
        assert "wrote" in res.output
        ds = read_dataset(out)
        assert ds.experiment == "chirp" and ds.experiment_attrs["f1_hz"] == 50.0

    def test_with_plant_file(self, tmp_path):
        plant = tmp_path / "plant.toml"
        assert invoke("plant", "--write-default", plant).exit_code == 0
        plant.write_text(plant.read_text().replace("Jl = 5.6", "Jl = 3.0"))
        res = invoke("chirp", "--plant", plant, "--duration", 1, "--out", tmp_path / "c.h5")
        assert res.exit_code == 0, res.output

    @pytest.mark.parametrize("args, message", [
        (("--target", "robot"), "needs --robot HOST"),
        (("--target", "robot", "--robot", "host:notaport"), "expected HOST or HOST:PORT"),
        (("--target", "moon"), "expected 'sim' or 'robot'"),
        (("--f0", "0"), "0 < f0 < f1"),
        (("--rate", "300"), "--rate"),
        (("--plant", "missing.toml"), "missing.toml: no such file"),
    ])
    def test_errors_are_one_line(self, tmp_path, args, message):
        out = tmp_path / "c.h5"
        res = invoke("chirp", "--duration", 1, *args, "--out", out)
        assert res.exit_code == 2
        assert message in res.output
        assert "Traceback" not in res.output
        assert not out.exists()

    def test_bad_plant_names_key(self, tmp_path):
        plant = tmp_path / "p.toml"
        plant.write_text("[dynamics]\nJc = -1.0\n")
        res = invoke("chirp", "--plant", plant, "--out", tmp_path / "c.h5")
        assert res.exit_code == 2
        assert f"{plant}: dynamics.Jc" in res.output


class TestSimulateCommand:
    @pytest.mark.parametrize("args", [
        ("constant_velocity", "--velocity", "0.6", "--range", "0.3"),
        ("constant_velocity", "--velocity", "0.6", "--range", "0.3", "--mode", "position", "--rate", "200"),
        ("quasi_static", "--torque", "5", "--velocity", "0.05", "--range", "0.03"),
        ("hand_guided", "--duration", "2"),
        ("step", "--amplitude", "5", "--period", "0.5", "--cycles", "1"),
        ("sine", "--amplitude", "5", "--frequency", "2", "--duration", "1"),
    ])
    def test_each_experiment(self, tmp_path, args):
        out = tmp_path / "x.h5"
        res = invoke("simulate", *args, "--out", out)
        assert res.exit_code == 0, res.output
        ds = read_dataset(out)
        assert ds.experiment == args[0]
        assert np.isfinite(ds["tau_j"]).all()

    def test_unknown_experiment(self, tmp_path):
        res = invoke("simulate", "dance", "--out", tmp_path / "x.h5")
        assert res.exit_code == 2 and "unknown experiment" in res.output


class TestPlantCommand:
    def test_lists_effects(self):
        res = invoke("plant", "--effects")
        for name in ("transmission_ripple", "link_friction", "position_dependent_load", "torque_sensor_offset",
                     "torque_sensor_scale", "periodic_disturbance", "input_delay"):
            assert name in res.output

    def test_shows_default(self):
        res = invoke("plant")
        assert res.exit_code == 0 and "K=18500" in res.output and "transmission_ripple" in res.output
