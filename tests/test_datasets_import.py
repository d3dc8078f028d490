"""Tests of importing column files and CSVs, on synthetic files and the real iiwa 14 logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from iiwa_ident.datasets import import_columns, import_csv, read_dataset, write_dataset
from iiwa_ident.errors import DatasetError

REAL = Path(__file__).resolve().parents[2] / "shared/data/real/iiwa14-constant-velocity"

N = 30
RATE = 500.0


def write_columns(path: Path, data: np.ndarray) -> Path:
    """Write a 2-D array (rows x columns) or 1-D array as a whitespace column file."""
    data = np.atleast_2d(data.T).T if data.ndim == 1 else data
    path.write_text("".join("\t".join(f"{v:.17g}" for v in row) + "\t\n" for row in data))
    return path


@pytest.fixture
def column_files(tmp_path):
    """Seven-column position, torque and velocity files plus a time file."""
    t = np.arange(N) / RATE
    # Column c of every file holds 100*c + sample index, so the column read is identifiable.
    grid = np.arange(N)[:, None] + 100.0 * np.arange(7)[None, :]
    files = {
        "t": write_columns(tmp_path / "time.txt", t),
        "q_m": write_columns(tmp_path / "pos.txt", grid * 1e-3),
        "tau_j": write_columns(tmp_path / "trq.txt", grid * 1e-2),
        "dq_m": write_columns(tmp_path / "vel.txt", grid * 1e-1),
    }
    return files, t, grid


def one_line(excinfo: pytest.ExceptionInfo, *fragments: str) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


def _real_files(joint: int) -> dict[str, Path]:
    folder = REAL / f"joint{joint}" / "vel_p3"
    if not folder.is_dir():
        pytest.skip(f"real iiwa 14 logs not found at {folder} (expected ../shared beside the checkout)")
    return {
        "t": folder / "cur_traj_time_s.txt",
        "q_m": folder / "joint_position_measured.txt",
        "tau_j": folder / "joint_torque_measured.txt",
        "dq_m": folder / "joint_velocity_measured.txt",
    }


class TestImportColumns:
    def test_picks_joint_column_and_estimates_rate(self, column_files):
        files, t, grid = column_files
        ds = import_columns(files, joint=3, experiment="constant_velocity")
        assert ds.source == "import" and ds.joint == 3 and ds.experiment == "constant_velocity"
        assert list(ds.signals) == ["t", "q_m", "tau_j", "dq_m"]
        np.testing.assert_allclose(ds.t, t, rtol=0, atol=1e-15)
        np.testing.assert_allclose(ds["q_m"], grid[:, 2] * 1e-3, rtol=1e-15, atol=0)
        np.testing.assert_allclose(ds["tau_j"], grid[:, 2] * 1e-2, rtol=1e-15, atol=0)
        assert ds.sample_rate_hz == pytest.approx(RATE, rel=1e-9, abs=0)

    def test_explicit_column(self, column_files):
        files, _, grid = column_files
        ds = import_columns(files, joint=3, experiment="free", column=6)
        np.testing.assert_allclose(ds["q_m"], grid[:, 6] * 1e-3, rtol=1e-15, atol=0)

    def test_generates_time_from_rate(self, column_files):
        files, _, _ = column_files
        del files["t"]
        ds = import_columns(files, joint=1, experiment="free", sample_rate_hz=250.0)
        np.testing.assert_allclose(ds.t, np.arange(N) / 250.0, rtol=0, atol=1e-15)
        assert ds.sample_rate_hz == pytest.approx(250.0, rel=0, abs=0)

    def test_median_rate_ignores_jitter(self, column_files, tmp_path):
        files, t, _ = column_files
        jittered = t.copy()
        jittered[10:] += 0.0015  # one late sample must not change the rate
        files["t"] = write_columns(tmp_path / "time.txt", jittered)
        ds = import_columns(files, joint=1, experiment="free")
        assert ds.sample_rate_hz == pytest.approx(RATE, rel=1e-9, abs=0)

    def test_scale_flips_torque_and_converts_ms(self, column_files, tmp_path):
        files, t, grid = column_files
        files["t"] = write_columns(tmp_path / "time_ms.txt", t * 1e3)
        ds = import_columns(files, joint=2, experiment="free", scale={"tau_j": -1.0, "t": 1e-3})
        np.testing.assert_allclose(ds["tau_j"], -grid[:, 1] * 1e-2, rtol=1e-15, atol=0)
        np.testing.assert_allclose(ds.t, t, rtol=1e-12, atol=1e-15)

    def test_time_signal_key(self, column_files):
        files, t, _ = column_files
        files["time"] = files.pop("t")
        ds = import_columns(files, joint=1, experiment="free", time_signal="time")
        np.testing.assert_allclose(ds.t, t, rtol=0, atol=1e-15)

    def test_skips_blank_and_comment_lines(self, tmp_path):
        pos = tmp_path / "pos.txt"
        trq = tmp_path / "trq.txt"
        pos.write_text("# position\n0.1\n\n0.2\n0.3\n")
        trq.write_text("1\n2\n3\n")
        ds = import_columns({"q_m": pos, "tau_j": trq}, joint=4, experiment="step", sample_rate_hz=1000)
        np.testing.assert_allclose(ds["q_m"], [0.1, 0.2, 0.3], rtol=0, atol=0)

    def test_round_trips_through_file(self, column_files, tmp_path):
        files, _, _ = column_files
        ds = import_columns(files, joint=5, experiment="constant_velocity")
        back = read_dataset(write_dataset(tmp_path / "out.h5", ds))
        assert back.source == "import" and back.joint == 5
        for name in ds.signals:
            np.testing.assert_allclose(back[name], ds[name], rtol=0, atol=0)

    def test_rate_out_of_range_refused(self, column_files, tmp_path):
        files, t, _ = column_files
        files["t"] = write_columns(tmp_path / "time_ms.txt", t * 1e3)  # milliseconds, not seconds
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free")
        one_line(excinfo, "0.5 Hz", "outside 200 Hz..1 kHz")

    @pytest.mark.parametrize(("rate", "ok"), [(195.0, False), (197.0, True), (1019.0, True), (1021.0, False)])
    def test_rate_tolerance_two_percent(self, column_files, rate, ok):
        files, _, _ = column_files
        del files["t"]
        if ok:
            ds = import_columns(files, joint=1, experiment="free", sample_rate_hz=rate)
            assert ds.sample_rate_hz == pytest.approx(rate, rel=0, abs=0)
        else:
            with pytest.raises(DatasetError, match="outside 200 Hz"):
                import_columns(files, joint=1, experiment="free", sample_rate_hz=rate)

    def test_missing_file(self, column_files, tmp_path):
        files, _, _ = column_files
        files["tau_j"] = tmp_path / "nope.txt"
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free")
        one_line(excinfo, f"{tmp_path / 'nope.txt'}: file not found")

    @staticmethod
    def _edit_line(path, index: int, edit) -> None:
        lines = path.read_text().splitlines()
        lines[index] = edit(lines[index])
        path.write_text("\n".join(lines) + "\n")

    @pytest.mark.parametrize("signal, line, edit, message", [
        ("q_m", 4, lambda text: text.replace("4", "4x", 1), "cannot parse"),  # an unparsable number
        ("tau_j", N, None, "expected 7 columns, found 3"),  # a ragged row appended
        ("tau_j", 2, lambda text: "\t".join(["nan"] * 7), "non-finite"),
    ])
    def test_bad_number_or_row_names_file_and_line(self, column_files, signal, line, edit, message):
        files, _, _ = column_files
        if edit is None:
            with files[signal].open("a") as fh:
                fh.write("1 2 3\n")
        else:
            self._edit_line(files[signal], line, edit)
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free")
        one_line(excinfo, str(files[signal]), f"line {line + 1}", message)

    def test_column_out_of_range(self, column_files):
        files, _, _ = column_files
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free", column=7)
        one_line(excinfo, "column 7 out of range", "7 columns")

    def test_unequal_lengths(self, column_files, tmp_path):
        files, _, grid = column_files
        files["dq_m"] = write_columns(tmp_path / "vel.txt", grid[:-2])
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free")
        one_line(excinfo, "unequal length", f"has {N - 2} rows", "vel.txt")

    @pytest.mark.parametrize("rename, message", [(("tau_j", "torque"), "unknown signal 'torque'"),
                                                 (("tau_j", None), "missing required signal 'tau_j'")])
    def test_unknown_or_missing_signal(self, column_files, rename, message):
        files, _, _ = column_files
        old, new = rename
        path = files.pop(old)
        if new is not None:
            files[new] = path
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free")
        one_line(excinfo, message)

    def test_no_time_and_no_rate(self, column_files):
        files, _, _ = column_files
        del files["t"]
        with pytest.raises(DatasetError, match="no time signal"):
            import_columns(files, joint=1, experiment="free")

    def test_time_not_increasing(self, column_files, tmp_path):
        files, t, _ = column_files
        t = t.copy()
        t[7] = t[6]
        files["t"] = write_columns(tmp_path / "time.txt", t)
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free", sample_rate_hz=RATE)
        one_line(excinfo, "time.txt", "not strictly increasing at sample 7")

    @pytest.mark.parametrize(
        ("kwargs", "fragment"),
        [
            ({"joint": 0}, "joint 0"),
            ({"experiment": "dance"}, "experiment 'dance'"),
            ({"scale": {"tau_c": 2.0}}, "'tau_c', which is not imported"),
            ({"scale": {"tau_j": 0.0}}, "non-zero"),
            ({"column": -1}, "column must be"),
        ],
    )
    def test_bad_arguments(self, column_files, kwargs, fragment):
        files, _, _ = column_files
        args = {"joint": 1, "experiment": "free", **kwargs}
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, **args)
        one_line(excinfo, fragment)

    @pytest.mark.parametrize(
        ("joint", "n", "q_range"),
        [(2, 16053, (-0.795, 0.795)), (4, 7138, (-0.535, 0.535))],
    )
    def test_real_log(self, joint, n, q_range, tmp_path):
        files = _real_files(joint)
        ds = import_columns(files, joint=joint, experiment="constant_velocity")
        assert ds.n_samples == n
        assert ds.sample_rate_hz == pytest.approx(200.0, rel=1e-9, abs=0)
        assert not ds.has("tau_c")  # position-controlled: no torque command
        assert ds["q_m"].min() == pytest.approx(q_range[0], rel=0, abs=2e-3)
        assert ds["q_m"].max() == pytest.approx(q_range[1], rel=0, abs=2e-3)
        # Right column: the moving joint's column equals q_m; the others barely move.
        table = np.loadtxt(files["q_m"])
        np.testing.assert_allclose(ds["q_m"], table[:, joint - 1], rtol=0, atol=0)
        others = np.delete(table, joint - 1, axis=1)
        assert np.ptp(others, axis=0).max() < 0.05
        np.testing.assert_allclose(ds["tau_j"], np.loadtxt(files["tau_j"])[:, joint - 1], rtol=0, atol=0)
        back = read_dataset(write_dataset(tmp_path / "real.h5", ds))
        assert back.n_samples == n


def write_csv(path: Path, header: list[str], rows, delimiter: str = ",") -> Path:
    lines = [delimiter.join(header)] + [delimiter.join(str(v) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def csv_file(tmp_path):
    t = np.arange(N) / RATE
    rows = [(f"{ti:.6f}", f"{0.01 * i:.4f}", f"{-0.5 * i:.3f}", "label") for i, ti in enumerate(t)]
    return write_csv(tmp_path / "log.csv", ["time", "pos", "torque", "note"], rows), t


class TestImportCsv:
    MAPPING = {"t": "time", "q_m": "pos", "tau_j": "torque"}

    def test_comma_csv(self, csv_file):
        path, t = csv_file
        ds = import_csv(path, self.MAPPING, joint=2, experiment="sine")
        assert ds.source == "import" and ds.joint == 2
        np.testing.assert_allclose(ds.t, t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ds["q_m"], 0.01 * np.arange(N), rtol=0, atol=1e-12)
        np.testing.assert_allclose(ds["tau_j"], -0.5 * np.arange(N), rtol=0, atol=1e-12)
        assert ds.sample_rate_hz == pytest.approx(RATE, rel=1e-6, abs=0)

    def test_semicolon_with_decimal_comma(self, tmp_path):
        rows = [(f"{i / 200:.3f}".replace(".", ","), f"{0.1 * i:.2f}".replace(".", ","), "1,5") for i in range(N)]
        path = write_csv(tmp_path / "eu.csv", ["time", "pos", "torque"], rows, delimiter=";")
        ds = import_csv(path, self.MAPPING, joint=1, experiment="free")
        np.testing.assert_allclose(ds["q_m"], 0.1 * np.arange(N), rtol=0, atol=1e-12)
        np.testing.assert_allclose(ds["tau_j"], np.full(N, 1.5), rtol=0, atol=0)
        assert ds.sample_rate_hz == pytest.approx(200.0, rel=1e-6, abs=0)

    def test_rate_without_time_column_and_scale(self, csv_file):
        path, _ = csv_file
        ds = import_csv(path, {"q_m": "pos", "tau_j": "torque"}, joint=1, experiment="free",
                        sample_rate_hz=1000.0, scale={"tau_j": -1.0})
        np.testing.assert_allclose(ds.t, np.arange(N) / 1000.0, rtol=0, atol=1e-15)
        np.testing.assert_allclose(ds["tau_j"], 0.5 * np.arange(N), rtol=0, atol=1e-12)

    def test_missing_column(self, csv_file):
        path, _ = csv_file
        with pytest.raises(DatasetError) as excinfo:
            import_csv(path, {**self.MAPPING, "tau_j": "trq"}, joint=1, experiment="free")
        one_line(excinfo, str(path), "no column 'trq'", "time, pos, torque, note")

    def test_unparsable_number(self, csv_file):
        path, _ = csv_file
        lines = path.read_text().splitlines()
        lines[3] = lines[3].replace(lines[3].split(",")[1], "oops")
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(DatasetError) as excinfo:
            import_csv(path, self.MAPPING, joint=1, experiment="free")
        one_line(excinfo, str(path), "line 4", "'pos'", "'oops'")

    def test_short_row(self, csv_file):
        path, _ = csv_file
        with path.open("a") as fh:
            fh.write("0.9,0.1\n")
        with pytest.raises(DatasetError) as excinfo:
            import_csv(path, self.MAPPING, joint=1, experiment="free")
        one_line(excinfo, str(path), f"line {N + 2}", "no column 'torque'")

    def test_missing_file(self, tmp_path):
        with pytest.raises(DatasetError) as excinfo:
            import_csv(tmp_path / "none.csv", self.MAPPING, joint=1, experiment="free")
        one_line(excinfo, "none.csv: file not found")

    def test_unknown_signal(self, csv_file):
        path, _ = csv_file
        with pytest.raises(DatasetError) as excinfo:
            import_csv(path, {**self.MAPPING, "note": "note"}, joint=1, experiment="free")
        one_line(excinfo, "unknown signal 'note'")

    def test_missing_required_signal(self, csv_file):
        path, _ = csv_file
        with pytest.raises(DatasetError) as excinfo:
            import_csv(path, {"t": "time", "q_m": "pos"}, joint=1, experiment="free")
        one_line(excinfo, "missing required signal 'tau_j'")

    def test_header_only(self, tmp_path):
        path = write_csv(tmp_path / "empty.csv", ["time", "pos", "torque"], [])
        with pytest.raises(DatasetError) as excinfo:
            import_csv(path, self.MAPPING, joint=1, experiment="free")
        one_line(excinfo, str(path), "no data rows")


class TestSplitRuns:
    """A log whose time restarts holds several runs: refused as one, split on request."""

    @pytest.fixture
    def two_runs(self, tmp_path):
        rng = np.random.default_rng(5)
        n1, n2 = int(rng.integers(20, 40)), int(rng.integers(20, 40))
        t = np.concatenate([np.arange(n1), np.arange(n2)]) / RATE + rng.uniform(0.0, 1.0)
        q = rng.normal(size=(n1 + n2, 7))
        tau = rng.normal(size=(n1 + n2, 7))
        files = {"t": write_columns(tmp_path / "time.txt", t), "q_m": write_columns(tmp_path / "pos.txt", q),
                 "tau_j": write_columns(tmp_path / "trq.txt", tau)}
        return files, n1, n2, q, tau

    def test_refused_naming_the_sample_and_the_option(self, two_runs):
        files, n1, *_ = two_runs
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=3, experiment="free")
        one_line(excinfo, "time.txt", f"time goes back at sample {n1}", "--split-runs")

    def test_split_into_runs(self, two_runs):
        files, n1, n2, q, tau = two_runs
        runs = import_columns(files, joint=3, experiment="free", split_runs=True)
        assert [r.n_samples for r in runs] == [n1, n2]
        np.testing.assert_array_equal(runs[1]["q_m"], q[n1:, 2])
        np.testing.assert_array_equal(runs[0]["tau_j"], tau[:n1, 2])
        assert all(r.sample_rate_hz == pytest.approx(RATE) for r in runs)

    def test_one_run_is_a_list_of_one(self, column_files):
        files, t, _ = column_files
        runs = import_columns(files, joint=1, experiment="free", split_runs=True)
        assert len(runs) == 1 and runs[0].n_samples == len(t)

    def test_a_run_of_one_sample_is_left_out_and_named(self, two_runs, tmp_path):
        # A stray row where the time restarts is no run: the others are imported, each saying what was left out
        # (it made the whole log fail before).
        files, n1, n2, *_ = two_runs
        t = np.concatenate([np.arange(n1) + 10.0, [5.0], np.arange(n2)]) / RATE
        files["t"] = write_columns(tmp_path / "time.txt", t)
        for name in ("q_m", "tau_j"):
            files[name] = write_columns(tmp_path / f"{name}.txt", np.zeros((n1 + n2 + 1, 7)))
        runs = import_columns(files, joint=1, experiment="free", split_runs=True)
        assert [ds.n_samples for ds in runs] == [n1, n2]
        assert all(ds.experiment_attrs["split_left_out"] == f"one sample, not a run: run 2 (sample {n1})"
                   for ds in runs)
        files["t"] = write_columns(tmp_path / "time.txt", np.array([3.0, 2.0, 1.0]))
        for name in ("q_m", "tau_j"):
            files[name] = write_columns(tmp_path / f"{name}.txt", np.zeros((3, 7)))
        with pytest.raises(DatasetError) as excinfo:
            import_columns(files, joint=1, experiment="free", split_runs=True)
        one_line(excinfo, "no run of 2 samples or more")

    def test_cli_writes_every_run_or_none(self, two_runs, tmp_path):
        from typer.testing import CliRunner

        from iiwa_ident.cli import app

        files, n1, n2, *_ = two_runs
        args = ["import", "--joint", "3", "--experiment", "free", "--columns", f"t={files['t']}",
                "--columns", f"q_m={files['q_m']}", "--columns", f"tau_j={files['tau_j']}"]
        out = tmp_path / "runs" / "j3.h5"
        out.parent.mkdir()
        res = CliRunner().invoke(app, [*args, "--split-runs", "--out", str(out)])
        assert res.exit_code == 0, res.output
        assert [read_dataset(out.parent / f"j3_run{k}.h5").n_samples for k in (1, 2)] == [n1, n2]
        assert sorted(p.name for p in out.parent.iterdir()) == ["j3_run1.h5", "j3_run2.h5"]
        # Without the option: one line, exit 2, nothing written.
        res = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "one.h5")])
        assert res.exit_code != 0 and "--split-runs" in res.output and not (tmp_path / "one.h5").exists()
