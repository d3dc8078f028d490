"""Tests of the ``import`` and ``info`` subcommands through typer's CliRunner."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.datasets import Dataset, read_dataset, write_dataset

REAL = Path(__file__).resolve().parents[2] / "shared/data/real/iiwa14-constant-velocity"


def invoke(*args: str):
    return CliRunner().invoke(app, list(args))


def assert_one_line_error(result, *fragments: str) -> str:
    """Exit code 2, a single ``error:`` line on stderr, no traceback."""
    assert result.exit_code == 2, (result.stdout, result.stderr)
    err = result.stderr
    assert "Traceback" not in err and "Traceback" not in result.stdout
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    for fragment in fragments:
        assert fragment in lines[0], err
    return lines[0]


def real_joint2_args() -> list[str]:
    folder = REAL / "joint2" / "vel_p3"
    if not folder.is_dir():
        pytest.skip(f"real iiwa 14 logs not found at {folder} (expected ../shared beside the checkout)")
    return [
        "--columns", f"t={folder / 'cur_traj_time_s.txt'}",
        "--columns", f"q_m={folder / 'joint_position_measured.txt'}",
        "--columns", f"tau_j={folder / 'joint_torque_measured.txt'}",
        "--columns", f"dq_m={folder / 'joint_velocity_measured.txt'}",
    ]


@pytest.fixture
def small_dataset(tmp_path) -> Path:
    n = 50
    ds = Dataset(
        signals={"t": np.arange(n) / 1000.0, "q_m": np.linspace(-0.1, 0.1, n), "tau_j": np.full(n, 2.0)},
        experiment="chirp",
        source="simulation",
        joint=6,
        sample_rate_hz=1000.0,
        experiment_attrs={"f0_hz": 0.5, "f1_hz": 40.0},
    )
    return write_dataset(tmp_path / "small.h5", ds)


class TestImportCmd:
    def test_imports_real_joint2_log(self, tmp_path):
        out = tmp_path / "runs" / "j2.h5"
        result = invoke("import", *real_joint2_args(), "--joint", "2",
                        "--experiment", "constant_velocity", "--out", str(out))
        assert result.exit_code == 0, result.stderr
        assert "16053 samples" in result.stdout and "200 Hz" in result.stdout
        ds = read_dataset(out)
        assert ds.n_samples == 16053 and ds.joint == 2 and ds.source == "import"
        assert ds.sample_rate_hz == pytest.approx(200.0, rel=1e-9, abs=0)
        assert ds["q_m"].max() == pytest.approx(0.795, rel=0, abs=2e-3)

    def test_scale_and_rate(self, tmp_path):
        (tmp_path / "pos.txt").write_text("0.1 0.2\n0.3 0.4\n0.5 0.6\n")
        (tmp_path / "trq.txt").write_text("1 2\n3 4\n5 6\n")
        out = tmp_path / "o.h5"
        result = invoke("import", "--columns", f"q_m={tmp_path / 'pos.txt'}",
                        "--columns", f"tau_j={tmp_path / 'trq.txt'}", "--joint", "2",
                        "--experiment", "step", "--rate", "500", "--scale", "tau_j=-1", "--out", str(out))
        assert result.exit_code == 0, result.stderr
        ds = read_dataset(out)
        np.testing.assert_allclose(ds["tau_j"], [-2.0, -4.0, -6.0], rtol=0, atol=0)
        np.testing.assert_allclose(ds.t, [0.0, 0.002, 0.004], rtol=0, atol=1e-15)

    def test_csv(self, tmp_path):
        csv = tmp_path / "log.csv"
        csv.write_text("time;pos;trq\n" + "".join(f"{i / 1000};{i * 0.01};{-i}\n" for i in range(20)))
        out = tmp_path / "o.h5"
        result = invoke("import", "--csv", str(csv), "--map", "t=time", "--map", "q_m=pos",
                        "--map", "tau_j=trq", "--joint", "1", "--experiment", "free", "--out", str(out))
        assert result.exit_code == 0, result.stderr
        np.testing.assert_allclose(read_dataset(out)["tau_j"], -np.arange(20.0), rtol=0, atol=0)

    def test_help_shows_real_log_example(self):
        result = CliRunner().invoke(app, ["import", "--help"], terminal_width=120)
        assert result.exit_code == 0
        assert "joint2/vel_p3" in result.stdout and "--columns" in result.stdout

    @pytest.mark.parametrize(
        ("args", "fragment"),
        [
            (["--columns", "foo"], "--columns expects SIGNAL=FILE, got 'foo'"),
            (["--columns", "q_m="], "--columns expects SIGNAL=FILE"),
            (["--csv", "x.csv", "--map", "q_m"], "--map expects SIGNAL=COLUMN"),
            (["--columns", "q_m=a.txt", "--scale", "q_m=abc"], "'abc' is not a number"),
            (["--columns", "q_m=a.txt", "--csv", "b.csv"], "not both"),
            (["--csv", "b.csv"], "--csv needs at least one --map"),
            ([], "nothing to import"),
            (["--columns", "q_m=a.txt", "--columns", "q_m=b.txt"], "gives 'q_m' twice"),
        ],
    )
    def test_bad_option_syntax(self, tmp_path, args, fragment):
        result = invoke("import", *args, "--joint", "2", "--experiment", "free", "--out", str(tmp_path / "o.h5"))
        assert_one_line_error(result, fragment)
        assert not (tmp_path / "o.h5").exists()

    def test_missing_input_file(self, tmp_path):
        result = invoke("import", "--columns", f"q_m={tmp_path / 'none.txt'}",
                        "--columns", f"tau_j={tmp_path / 'none.txt'}", "--joint", "2",
                        "--experiment", "free", "--rate", "200", "--out", str(tmp_path / "o.h5"))
        assert_one_line_error(result, "none.txt: file not found")

    def test_bad_joint(self, tmp_path):
        result = invoke("import", *real_joint2_args(), "--joint", "8",
                        "--experiment", "constant_velocity", "--out", str(tmp_path / "o.h5"))
        assert_one_line_error(result, "joint 8")


class TestInfoCmd:
    def test_table(self, small_dataset):
        result = invoke("info", str(small_dataset))
        assert result.exit_code == 0, result.stderr
        out = result.stdout
        for fragment in ("chirp", "simulation", "joint         6", "samples       50", "f0_hz", "q_m", "Nm"):
            assert fragment in out, out

    def test_json(self, small_dataset):
        result = invoke("info", str(small_dataset), "--json")
        assert result.exit_code == 0, result.stderr
        info = json.loads(result.stdout)
        assert info["n_samples"] == 50 and info["joint"] == 6
        assert info["duration_s"] == pytest.approx(0.049, rel=1e-12, abs=0)
        assert info["experiment_attrs"]["f1_hz"] == pytest.approx(40.0, rel=0, abs=0)
        q = info["signals"]["q_m"]
        assert q["unit"] == "rad"
        assert q["min"] == pytest.approx(-0.1, rel=1e-12, abs=0)
        assert q["max"] == pytest.approx(0.1, rel=1e-12, abs=0)
        assert info["signals"]["tau_j"]["std"] == pytest.approx(0.0, rel=0, abs=1e-15)

    def test_real_import_then_info(self, tmp_path):
        out = tmp_path / "j2.h5"
        assert invoke("import", *real_joint2_args(), "--joint", "2", "--experiment",
                      "constant_velocity", "--out", str(out)).exit_code == 0
        info = json.loads(invoke("info", str(out), "--json").stdout)
        assert info["n_samples"] == 16053 and info["source"] == "import"
        assert set(info["signals"]) == {"t", "q_m", "tau_j", "dq_m"}

    def test_not_hdf5(self, tmp_path):
        bad = tmp_path / "bad.h5"
        bad.write_text("not hdf5\n")
        assert_one_line_error(invoke("info", str(bad)), f"{bad}: not an HDF5 file")

    def test_missing_file(self, tmp_path):
        assert_one_line_error(invoke("info", str(tmp_path / "nope.h5"), "--json"), "file not found")

    def test_invalid_dataset(self, small_dataset):
        import h5py

        with h5py.File(small_dataset, "r+") as h5:
            h5["signals"]["tau_j"].attrs["unit"] = "N"
        assert_one_line_error(invoke("info", str(small_dataset)), "signal 'tau_j' has unit 'N' (expected 'Nm')")


class TestHelpShowsUnits:
    def test_every_bracketed_unit_is_shown_as_written(self):
        # Rich markup took "[s]" for a style tag and dropped it: "Run length ." instead of "Run length [s].".
        import re

        import typer

        group = typer.main.get_command(app)
        checked = 0
        for name, command in group.commands.items():
            res = CliRunner().invoke(app, [name, "--help"], env={"COLUMNS": "400", "TERMINAL_WIDTH": "400"})
            assert res.exit_code == 0, res.output
            for param in command.params:
                for unit in re.findall(r"\[[^\]\[]+\]", getattr(param, "help", None) or ""):
                    unit = unit.replace("\\[", "[")
                    assert unit in res.output, (name, param.name, unit)
                    checked += 1
        assert checked >= 30


def test_version():
    from importlib.metadata import version

    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output == f"iiwa-ident {version('iiwa-ident')}\n"


class TestRobotName:
    """A fleet's key: the robot a run was recorded on, named on import and by the experiments, shown by info."""

    def test_import_and_simulate_keep_the_name_and_info_shows_it(self, tmp_path):
        from iiwa_ident.datasets import read_dataset, robot_name

        out = tmp_path / "cv.h5"
        result = invoke("simulate", "constant_velocity", "--velocity", "0.3", "--range", "0.2", "--robot-name",
                        "cell-3.left", "--out", str(out))
        assert result.exit_code == 0, result.output
        assert robot_name(read_dataset(out)) == "cell-3.left"
        result = invoke("info", str(out))
        assert "robot         cell-3.left" in result.stdout
        result = invoke("info", str(out), "--json")
        assert json.loads(result.stdout)["robot"] == "cell-3.left"

    @pytest.mark.parametrize("name", ["", "../x", "a b", "x" * 65, "-lead"])
    def test_bad_name_refused(self, tmp_path, name):
        result = invoke("import", *real_joint2_args(), "--joint", "2", "--experiment", "constant_velocity",
                        "--robot-name", name, "--out", str(tmp_path / "o.h5"))
        assert_one_line_error(result, "robot name")
        assert not (tmp_path / "o.h5").exists()
