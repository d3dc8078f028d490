"""Tests of the HDF5 dataset format: round trip, validation, atomic writes, truth isolation."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from iiwa_ident.datasets import (
    SIGNAL_UNITS,
    Dataset,
    _format,
    read_dataset,
    read_truth,
    sha256_file,
    validate_dataset,
    write_dataset,
)
from iiwa_ident.errors import DatasetError, IiwaIdentError

N = 40
RATE = 1000.0


def make_dataset(n: int = N, **overrides) -> Dataset:
    """A valid dataset with every known signal, experiment attrs and truth."""
    t = np.arange(n) / RATE
    rng = np.random.default_rng(0)
    signals = {name: rng.normal(size=n) for name in SIGNAL_UNITS}
    signals["t"] = t
    fields = dict(
        signals=signals,
        experiment="chirp",
        source="simulation",
        joint=3,
        sample_rate_hz=RATE,
        experiment_attrs={
            "f0_hz": 0.5,
            "f1_hz": 20.0,
            "n_periods": 3,
            "closed_loop": True,
            "note": "test chirp",
            "amplitudes_nm": np.array([1.0, 2.0, 3.0]),
        },
        created_utc="2024-05-01T12:00:00+00:00",
        truth={
            "plant": {"k_nm_rad": 5000.0, "n_poles": 4, "stable": True, "poles": [-1.0, -2.5]},
            "model": "two-mass",
            "friction": {"coulomb": {"fc_nm": 1.2}},
        },
    )
    fields.update(overrides)
    return Dataset(**fields)


def one_line_error(excinfo: pytest.ExceptionInfo, path: Path | str, *fragments: str) -> str:
    """Assert a DatasetError message is one line, starts with the path and names the problem."""
    message = str(excinfo.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: "), message
    for fragment in fragments:
        assert fragment in message, message
    return message


class TestDataset:
    def test_accessors(self):
        ds = make_dataset()
        np.testing.assert_allclose(ds["q_m"], ds.signals["q_m"], rtol=0, atol=0)
        np.testing.assert_allclose(ds.t, np.arange(N) / RATE, rtol=0, atol=0)
        assert ds.has("tau_c")
        assert not ds.has("nope")
        assert ds.n_samples == N
        assert ds.duration_s == pytest.approx((N - 1) / RATE, rel=1e-12, abs=0)

    def test_missing_signal_names_what_exists(self):
        ds = make_dataset()
        del ds.signals["tau_c"]
        with pytest.raises(KeyError, match="tau_c"):
            ds["tau_c"]

    def test_defaults(self):
        ds = Dataset(
            signals={"t": np.arange(3.0), "q_m": np.zeros(3), "tau_j": np.zeros(3)},
            experiment="free",
            source="robot",
            joint=1,
            sample_rate_hz=500.0,
        )
        assert ds.experiment_attrs == {}
        assert ds.truth is None and ds.path is None
        validate_dataset(ds, "x")  # default created_utc is valid ISO 8601


class TestWriteDataset:
    def test_round_trip_all_signals_attrs(self, tmp_path):
        ds = make_dataset()
        ds.signals["q_cmd"] = np.arange(N)  # integers are stored as float64
        out = write_dataset(tmp_path / "a.h5", ds)
        assert out == tmp_path / "a.h5"
        back = read_dataset(out)
        assert list(back.signals) == list(SIGNAL_UNITS)
        for name, values in ds.signals.items():
            assert back[name].dtype == np.float64
            np.testing.assert_allclose(back[name], values, rtol=0, atol=0)
        assert (back.experiment, back.source, back.joint) == ("chirp", "simulation", 3)
        assert back.sample_rate_hz == pytest.approx(RATE, rel=0, abs=0)
        assert back.created_utc == ds.created_utc
        assert back.path == out
        attrs = back.experiment_attrs
        assert attrs["f0_hz"] == pytest.approx(0.5, rel=0, abs=0)
        assert attrs["n_periods"] == 3 and isinstance(attrs["n_periods"], int)
        assert attrs["closed_loop"] is True
        assert attrs["note"] == "test chirp"
        np.testing.assert_allclose(attrs["amplitudes_nm"], [1.0, 2.0, 3.0], rtol=0, atol=0)

    def test_units_and_types_on_disk(self, tmp_path):
        out = write_dataset(tmp_path / "a.h5", make_dataset())
        with h5py.File(out, "r") as h5:
            assert h5.attrs["format"] == "iiwa-ident-dataset"
            assert h5.attrs["format_version"] == 1
            for name, unit in SIGNAL_UNITS.items():
                assert h5["signals"][name].attrs["unit"] == unit
                assert h5["signals"][name].dtype == np.float64

    def test_truth_round_trip(self, tmp_path):
        ds = make_dataset()
        out = write_dataset(tmp_path / "a.h5", ds)
        assert read_truth(out) == ds.truth

    def test_creates_parent_directories(self, tmp_path):
        out = write_dataset(tmp_path / "runs" / "deep" / "a.h5", make_dataset())
        assert out.is_file()

    def test_overwrites_existing(self, tmp_path):
        target = tmp_path / "a.h5"
        write_dataset(target, make_dataset(joint=2))
        write_dataset(target, make_dataset(joint=5))
        assert read_dataset(target).joint == 5
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]

    def test_invalid_write_leaves_existing_file_untouched(self, tmp_path):
        target = tmp_path / "a.h5"
        write_dataset(target, make_dataset())
        before = target.read_bytes()
        bad = make_dataset()
        bad.signals["tau_j"][5] = np.nan
        with pytest.raises(DatasetError) as excinfo:
            write_dataset(target, bad)
        one_line_error(excinfo, target, "'tau_j'", "index 5")
        assert target.read_bytes() == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]

    @pytest.mark.parametrize("exc_type", [RuntimeError, KeyboardInterrupt])
    def test_failure_mid_write_leaves_existing_file_and_no_temp(self, tmp_path, monkeypatch, exc_type):
        target = tmp_path / "a.h5"
        write_dataset(target, make_dataset())
        before = target.read_bytes()
        real = _format._write_contents

        def half_write(h5, dataset):
            real(h5, dataset)
            raise exc_type("interrupted")

        monkeypatch.setattr(_format, "_write_contents", half_write)
        with pytest.raises(exc_type):
            write_dataset(target, make_dataset(joint=6))
        assert target.read_bytes() == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]

    def test_failed_new_file_leaves_nothing(self, tmp_path):
        bad = make_dataset(experiment="walk")
        with pytest.raises(DatasetError):
            write_dataset(tmp_path / "new.h5", bad)
        assert list(tmp_path.iterdir()) == []

    @pytest.mark.parametrize(
        ("overrides", "fragment"),
        [
            ({"truth": {"plant": {"k": None}}}, "truth['plant']['k']"),
            ({"truth": {"poles": [1.0, "a"]}}, "truth['poles']"),
            ({"truth": {"a/b": 1.0}}, "'a/b'"),
            ({"experiment_attrs": {"m": np.zeros((2, 2))}}, "experiment attribute 'm'"),
            ({"experiment_attrs": {"d": {"x": 1}}}, "experiment attribute 'd'"),
            ({"created_utc": "yesterday"}, "created_utc"),
        ],
    )
    def test_rejects_bad_metadata(self, tmp_path, overrides, fragment):
        with pytest.raises(DatasetError) as excinfo:
            write_dataset(tmp_path / "a.h5", make_dataset(**overrides))
        one_line_error(excinfo, tmp_path / "a.h5", fragment)

    def test_unwritable_target_is_dataset_error(self, tmp_path):
        blocker = tmp_path / "file"
        blocker.write_text("x")
        with pytest.raises(DatasetError) as excinfo:
            write_dataset(blocker / "a.h5", make_dataset())  # parent is a file
        one_line_error(excinfo, blocker / "a.h5", "cannot write")


# ---------------------------------------------------------------------------
# corrupting a valid file in place, one problem at a time


def _replace_signal(h5: h5py.File, name: str, data, unit: str | None = "same") -> None:
    group = h5["signals"]
    old_unit = group[name].attrs.get("unit") if name in group else None
    if name in group:
        del group[name]
    dset = group.create_dataset(name, data=data)
    unit = old_unit if unit == "same" else unit
    if unit is not None:
        dset.attrs["unit"] = unit


def _set_root(key, value):
    def mutate(h5):
        h5.attrs[key] = value

    return mutate


def _del_root(key):
    def mutate(h5):
        del h5.attrs[key]

    return mutate


def _nan_at(name, index, value):
    def mutate(h5):
        data = h5["signals"][name][()]
        data[index] = value
        _replace_signal(h5, name, data)

    return mutate


def _t_repeat(h5):
    t = h5["signals"]["t"][()]
    t[5] = t[4]
    _replace_signal(h5, "t", t)


def _all_length(n):
    def mutate(h5):
        for name in list(h5["signals"]):
            _replace_signal(h5, name, h5["signals"][name][:n])

    return mutate


BAD_FILES: list[tuple[str, Callable[[h5py.File], None], tuple[str, ...]]] = [
    ("missing format", _del_root("format"), ("missing root attribute 'format'",)),
    ("wrong format", _set_root("format", "something-else"), ("format is 'something-else'",)),
    ("missing format_version", _del_root("format_version"), ("format_version",)),
    ("unknown format_version", _set_root("format_version", 2), ("unsupported format_version 2",)),
    ("bad experiment", _set_root("experiment", "walk"), ("experiment 'walk'",)),
    ("bad source", _set_root("source", "guess"), ("source 'guess'",)),
    ("joint 0", _set_root("joint", 0), ("joint 0",)),
    ("joint 8", _set_root("joint", 8), ("joint 8",)),
    ("joint float", _set_root("joint", 2.5), ("joint 2.5",)),
    ("rate 0", _set_root("sample_rate_hz", 0.0), ("sample_rate_hz 0.0",)),
    ("rate nan", _set_root("sample_rate_hz", np.nan), ("sample_rate_hz nan",)),
    ("missing joint", _del_root("joint"), ("missing root attribute 'joint'",)),
    ("bad created_utc", _set_root("created_utc", "soon"), ("created_utc 'soon'",)),
    ("no signals group", lambda h5: h5.__delitem__("signals"), ("missing group '/signals'",)),
    ("missing tau_j", lambda h5: h5["signals"].__delitem__("tau_j"), ("missing required signal 'tau_j'",)),
    ("missing t", lambda h5: h5["signals"].__delitem__("t"), ("missing required signal 't'",)),
    ("unknown signal", lambda h5: _replace_signal(h5, "foo", np.zeros(N), "Nm"), ("unknown signal 'foo'",)),
    ("signal is a group", lambda h5: (h5["signals"].__delitem__("q_cmd"), h5["signals"].create_group("q_cmd")), ("'/signals/q_cmd' is a group",)),
    ("2-D signal", lambda h5: _replace_signal(h5, "q_m", np.zeros((N, 2))), ("'q_m' is not 1-D", "(40, 2)")),
    ("text signal", lambda h5: _replace_signal(h5, "q_m", np.array([b"a"] * N)), ("'q_m' has non-numeric dtype",)),
    ("unequal lengths", lambda h5: _replace_signal(h5, "tau_c", np.zeros(N - 1)), ("unequal lengths", "tau_c has 39")),
    ("nan", _nan_at("tau_j", 7, np.nan), ("signal 'tau_j'", "nan", "index 7")),
    ("inf", _nan_at("q_m", 3, np.inf), ("signal 'q_m'", "inf", "index 3")),
    ("t not increasing", _t_repeat, ("t is not strictly increasing at index 5",)),
    ("missing unit", lambda h5: h5["signals"]["q_m"].attrs.__delitem__("unit"), ("signal 'q_m' has no unit", "'rad'")),
    ("wrong unit", lambda h5: h5["signals"]["tau_j"].attrs.__setitem__("unit", "N"), ("signal 'tau_j' has unit 'N' (expected 'Nm')",)),
    ("one sample", _all_length(1), ("empty", "1 sample")),
    ("no samples", _all_length(0), ("empty", "0 sample")),
]


class TestReadDataset:
    @pytest.mark.parametrize(
        ("mutate", "fragments"),
        [(m, f) for _, m, f in BAD_FILES],
        ids=[case for case, _, _ in BAD_FILES],
    )
    def test_bad_file(self, tmp_path, mutate, fragments):
        path = write_dataset(tmp_path / "bad.h5", make_dataset())
        with h5py.File(path, "r+") as h5:
            mutate(h5)
        with pytest.raises(DatasetError) as excinfo:
            read_dataset(path)
        one_line_error(excinfo, path, *fragments)

    def test_message_starts_with_path_as_given(self, tmp_path, monkeypatch):
        monkeypatch.chdir(tmp_path)
        write_dataset("runs/a.h5", make_dataset())
        with h5py.File("runs/a.h5", "r+") as h5:
            h5["signals"]["tau_j"].attrs["unit"] = "N"
        with pytest.raises(DatasetError) as excinfo:
            read_dataset("runs/a.h5")
        assert str(excinfo.value) == "runs/a.h5: signal 'tau_j' has unit 'N' (expected 'Nm')"

    def test_missing_file(self, tmp_path):
        with pytest.raises(DatasetError) as excinfo:
            read_dataset(tmp_path / "nope.h5")
        one_line_error(excinfo, tmp_path / "nope.h5", "file not found")

    def test_not_hdf5(self, tmp_path):
        path = tmp_path / "text.h5"
        path.write_text("t q_m tau_j\n0 0 0\n")
        with pytest.raises(DatasetError) as excinfo:
            read_dataset(path)
        one_line_error(excinfo, path, "not an HDF5 file")

    def test_truncated_file(self, tmp_path):
        good = write_dataset(tmp_path / "good.h5", make_dataset(n=5000))
        path = tmp_path / "cut.h5"
        data = good.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        with pytest.raises(DatasetError) as excinfo:
            read_dataset(path)
        one_line_error(excinfo, path, "cannot")

    def test_directory(self, tmp_path):
        with pytest.raises(DatasetError) as excinfo:
            read_dataset(tmp_path)
        one_line_error(excinfo, tmp_path, "directory")

    def test_dataset_error_is_iiwa_ident_error(self, tmp_path):
        with pytest.raises(IiwaIdentError):
            read_dataset(tmp_path / "nope.h5")

    def test_minimal_file_without_experiment_group(self, tmp_path):
        path = tmp_path / "min.h5"
        ds = Dataset(
            signals={"t": np.arange(3) / 200.0, "q_m": np.zeros(3), "tau_j": np.ones(3)},
            experiment="free",
            source="robot",
            joint=7,
            sample_rate_hz=200.0,
        )
        write_dataset(path, ds)
        with h5py.File(path, "r+") as h5:
            del h5["experiment"]
        back = read_dataset(path)
        assert back.experiment_attrs == {}
        assert list(back.signals) == ["t", "q_m", "tau_j"]

    def test_does_not_expose_truth(self, tmp_path):
        path = write_dataset(tmp_path / "sim.h5", make_dataset())
        back = read_dataset(path)
        assert back.truth is None
        flat = repr(back.experiment_attrs) + repr(vars(back).keys())
        assert "k_nm_rad" not in flat and "two-mass" not in flat

    def test_never_opens_truth_group(self, tmp_path, monkeypatch):
        path = write_dataset(tmp_path / "sim.h5", make_dataset())
        seen: list[str] = []
        real_getitem, real_get = h5py.Group.__getitem__, h5py.Group.get

        def spy_getitem(self, name):
            seen.append(f"{self.name}|{name}")
            return real_getitem(self, name)

        def spy_get(self, name, *args, **kwargs):
            seen.append(f"{self.name}|{name}")
            return real_get(self, name, *args, **kwargs)

        monkeypatch.setattr(h5py.Group, "__getitem__", spy_getitem)
        monkeypatch.setattr(h5py.Group, "get", spy_get)
        read_dataset(path)
        assert seen, "the spy saw no access at all"
        assert not [s for s in seen if "truth" in s], seen


class TestValidateDataset:
    def test_valid_passes(self):
        validate_dataset(make_dataset(), "mem")

    @pytest.mark.parametrize(
        ("change", "fragment"),
        [
            (lambda ds: ds.signals.pop("q_m"), "missing required signal 'q_m'"),
            (lambda ds: ds.signals.__setitem__("bogus", np.zeros(N)), "unknown signal 'bogus'"),
            (lambda ds: ds.signals.__setitem__("tau_c", np.zeros(N + 1)), "unequal lengths"),
            (lambda ds: ds.signals.__setitem__("q_m", np.zeros((N, 1))), "not 1-D"),
            (lambda ds: ds.signals["t"].__setitem__(10, 0.0), "t is not strictly increasing at index 10"),
            (lambda ds: ds.signals["dq_m"].__setitem__(2, -np.inf), "'dq_m' has a non-finite value (-inf) at index 2"),
            (lambda ds: setattr(ds, "joint", True), "joint True"),
            (lambda ds: setattr(ds, "sample_rate_hz", -5.0), "sample_rate_hz -5.0"),
            (lambda ds: setattr(ds, "source", "robotic"), "source 'robotic'"),
        ],
    )
    def test_problem_named_after_where(self, change, fragment):
        ds = make_dataset()
        change(ds)
        with pytest.raises(DatasetError) as excinfo:
            validate_dataset(ds, "somewhere")
        one_line_error(excinfo, "somewhere", fragment)

    def test_empty(self):
        ds = make_dataset(n=1)
        with pytest.raises(DatasetError) as excinfo:
            validate_dataset(ds, "w")
        one_line_error(excinfo, "w", "empty")


class TestReadTruth:
    def test_reads_nested_dict(self, tmp_path):
        ds = make_dataset()
        path = write_dataset(tmp_path / "sim.h5", ds)
        truth = read_truth(path)
        assert truth["plant"]["k_nm_rad"] == pytest.approx(5000.0, rel=0, abs=0)
        assert truth["plant"]["n_poles"] == 4 and isinstance(truth["plant"]["n_poles"], int)
        assert truth["plant"]["stable"] is True
        assert truth["plant"]["poles"] == [-1.0, -2.5]
        assert truth["friction"]["coulomb"]["fc_nm"] == pytest.approx(1.2, rel=0, abs=0)
        assert truth["model"] == "two-mass"

    def test_no_truth(self, tmp_path):
        path = write_dataset(tmp_path / "real.h5", make_dataset(truth=None, source="robot"))
        with pytest.raises(DatasetError) as excinfo:
            read_truth(path)
        one_line_error(excinfo, path, "no ground truth")

    def test_missing_file(self, tmp_path):
        with pytest.raises(DatasetError) as excinfo:
            read_truth(tmp_path / "nope.h5")
        one_line_error(excinfo, tmp_path / "nope.h5", "file not found")


class TestSha256File:
    def test_digest(self, tmp_path):
        path = tmp_path / "x.bin"
        path.write_bytes(b"abc" * 1000)
        assert sha256_file(path) == hashlib.sha256(b"abc" * 1000).hexdigest()

    def test_missing_file(self, tmp_path):
        with pytest.raises(DatasetError) as excinfo:
            sha256_file(tmp_path / "nope")
        one_line_error(excinfo, tmp_path / "nope", "file not found")


def test_folders_name_their_dataset_files_and_a_log_folder_says_how_to_import(tmp_path):
    from typer.testing import CliRunner

    from iiwa_ident.cli import app
    from iiwa_ident.datasets import dataset_files

    (tmp_path / "runs").mkdir()
    for name in ("b.h5", "a.h5"):
        (tmp_path / "runs" / name).write_bytes(b"")
    assert dataset_files([tmp_path / "x.h5", tmp_path / "runs"]) == [tmp_path / "x.h5", tmp_path / "runs" / "a.h5",
                                                                      tmp_path / "runs" / "b.h5"]
    log = tmp_path / "vel_p3"
    log.mkdir()
    (log / "joint_position_measured.txt").write_text("0 0 0 0 0 0 0\n")
    for command in ("compare", "diagnose", "ripple"):
        res = CliRunner().invoke(app, [command, str(log)])
        assert res.exit_code == 2 and res.stderr.strip() == (
            f"error: {log}: a folder of column logs, not of dataset files: import it first ('iiwa-ident import "
            "--columns ...', or 'iiwa-ident pipeline --logs' for a whole joint)"), res.output
        res = CliRunner().invoke(app, [command, str(tmp_path / "runs" / "..")])
        assert res.exit_code == 2 and "a folder with no dataset file (.h5) in it" in res.stderr
