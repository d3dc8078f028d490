"""Tests of the background HDF5 log writer: round trip, live reading, overflow, crashes."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import wait_for
from iiwa_ident.datasets import SIGNAL_UNITS, LogStats, LogWriter, read_dataset
from iiwa_ident.errors import DatasetError, IiwaIdentError

RATE = 1000.0
SIGNALS = [
    "t", "q_m", "tau_j", "tau_c", "tau_r", "tau_j_filt", "tau_ext_est", "tau_add", "watchdog", "cycle_us",
]
REPO = Path(__file__).resolve().parents[1]


def make_writer(path: Path, signals=SIGNALS, **kwargs) -> LogWriter:
    kwargs.setdefault("experiment", "free")
    kwargs.setdefault("source", "robot")
    kwargs.setdefault("joint", 4)
    kwargs.setdefault("sample_rate_hz", RATE)
    return LogWriter(path, signals, **kwargs)


def random_rows(n: int, n_signals: int = len(SIGNALS), seed: int = 0) -> np.ndarray:
    """Rows with an increasing time in column 0 and arbitrary float64 elsewhere."""
    rows = np.random.default_rng(seed).normal(scale=1e3, size=(n, n_signals))
    rows[:, 0] = np.arange(n) / RATE
    return rows


class TestRoundTrip:
    def test_rows_equal_what_was_appended(self, tmp_path):
        path = tmp_path / "run.h5"
        rows = random_rows(5000)
        with make_writer(path, experiment_attrs={"controller": "pd", "gains": [1.0, 2.0]}) as log:
            for k, row in enumerate(rows):
                # Both row types the loop may hand over.
                assert log.append(row if k % 2 else row.tolist())
            stats = log.close({"duration_s": 5.0})
        assert stats == LogStats(appended=5000, written=5000, lost=0, path=path)
        assert log.close() is stats  # idempotent

        ds = read_dataset(path)
        assert list(ds.signals) == [name for name in SIGNAL_UNITS if name in SIGNALS]
        for j, name in enumerate(SIGNALS):
            assert ds[name].dtype == np.float64
            assert np.array_equal(ds[name], rows[:, j]), name  # exact, no rounding
        assert (ds.experiment, ds.source, ds.joint, ds.sample_rate_hz) == ("free", "robot", 4, RATE)
        attrs = ds.experiment_attrs
        assert attrs["controller"] == "pd" and attrs["duration_s"] == 5.0
        assert list(attrs["gains"]) == [1.0, 2.0]
        assert attrs["lost_rows"] == 0
        assert "incomplete" not in attrs and "interrupted" not in attrs

    def test_rows_appended_before_the_writer_is_ready(self, tmp_path):
        path = tmp_path / "run.h5"
        rows = random_rows(3000)
        log = make_writer(path).start(wait=False)
        for row in rows:  # at once: the ring holds them until the new interpreter has the file open
            assert log.append(row)
        stats = log.close()
        assert stats.written == 3000 and stats.lost == 0
        assert np.array_equal(read_dataset(path)["tau_j"], rows[:, SIGNALS.index("tau_j")])
        assert log.ready()

    def test_a_reader_holding_the_file_as_the_writer_starts(self, tmp_path):
        """A reader (``info``, a live view) that has the new file open when the writer comes to open it:
        HDF5's lock refuses the writer until the reader lets go; the writer tries again and every row
        arrives (before, the writer gave up and the run's log was lost)."""
        path = tmp_path / "run.h5"
        rows = random_rows(2000)
        log = make_writer(path).start(wait=False)
        reader = h5py.File(path, "r")  # the writer's new interpreter is still importing numpy and h5py
        try:
            for row in rows[:1000]:
                assert log.append(row)
            assert not log.ready(timeout_s=0.5)  # it cannot open the file while the reader has it
        finally:
            reader.close()
        for row in rows[1000:]:
            assert log.append(row)
        stats = log.close()
        assert stats.written == 2000 and stats.lost == 0
        assert np.array_equal(read_dataset(path)["tau_j"], rows[:, SIGNALS.index("tau_j")])

    def test_complete_file_has_no_progress_markers(self, tmp_path):
        path = tmp_path / "run.h5"
        with make_writer(path) as log:
            for row in random_rows(10):
                log.append(row)
        with h5py.File(path, "r") as h5:  # a plain, non-SWMR open works
            assert "in_progress" not in h5.attrs
            assert "rows_flushed" not in h5
            assert h5.attrs["format"] == "iiwa-ident-dataset" and h5.attrs["format_version"] == 1
            for name in SIGNALS:
                assert h5["signals"][name].attrs["unit"] == SIGNAL_UNITS[name]


class TestReadWhileRunning:
    def test_flushed_rows_are_readable(self, tmp_path):
        path = tmp_path / "live.h5"
        rows = random_rows(1500)
        log = make_writer(path, flush_interval_s=0.2).start()
        try:
            for row in rows[:1000]:
                log.append(row)
            # The writer flushes within a flush interval; a loaded machine may take longer, so wait for it.
            live = wait_for(lambda: _live(path, 1000), what="the first 1000 rows flushed")
            with pytest.raises(OSError):
                h5py.File(path, "r")  # the SWMR writer holds the consistency flags
            assert live.experiment_attrs["incomplete"] is True
            assert live.n_samples == 1000
            for j, name in enumerate(SIGNALS):
                assert np.array_equal(live[name], rows[:1000, j])
            for row in rows[1000:]:
                log.append(row)
        finally:
            stats = log.close()
        assert stats.written == 1500
        assert "incomplete" not in read_dataset(path).experiment_attrs

    def test_zero_rows_while_starting_is_a_clear_error(self, tmp_path):
        path = tmp_path / "empty.h5"
        with make_writer(path):
            with pytest.raises(DatasetError) as excinfo:
                read_dataset(path)
        message = str(excinfo.value)
        assert message.startswith(f"{path}: dataset is empty: 0 sample(s)")
        assert "in progress" in message and "\n" not in message


class TestRingOverflow:
    def test_full_ring_refuses_rows_without_blocking(self, tmp_path):
        path = tmp_path / "overflow.h5"
        n = 100_000
        with make_writer(path, signals=["t", "q_m", "tau_j"], capacity_rows=100) as log:
            accepted = sum(log.append((k / RATE, 0.0, 1.0)) for k in range(n))
            stats = log.close()
        # A blocking append would have waited for the writer and lost nothing.
        assert stats.lost > 0 and stats.appended == accepted
        assert stats.appended + stats.lost == n
        assert stats.written == stats.appended
        ds = read_dataset(path)
        assert ds.n_samples == stats.appended
        assert ds.experiment_attrs["lost_rows"] == stats.lost


# ---------------------------------------------------------------------------
# crashes: a child Python process runs a 1 kHz "loop" that logs every cycle

LOOP_SCRIPT = textwrap.dedent(
    """
    import sys
    from iiwa_ident.datasets import LogWriter

    log = LogWriter(sys.argv[1], ["t", "q_m", "tau_j"], experiment="free", source="robot",
                    joint=1, sample_rate_hz=1000.0, flush_interval_s=0.5).start(wait=sys.argv[4] == "wait")
    print("writer", log.writer_pid, flush=True)
    rows = int(sys.argv[2])
    for k in range(rows):  # far below the ring's capacity: nothing is lost however slow the writer
        log.append((k / 1000.0, 0.001 * k, float(k % 7)))
    print("running", rows, flush=True)
    if sys.argv[3] == "hold":
        sys.stdin.read()  # a loop that is still running when it is killed: blocks until the test ends it
    print("done", rows, flush=True)  # leaves without close(): the exit hook must finish the file
    """
)


class _Loop:
    """The loop process and its output lines.

    The loop appends ``rows`` rows, says so, and with ``hold`` waits (alive, its writer running)
    until it is killed; without, it exits without closing the log. Nothing is paced by the clock.
    """

    def __init__(self, path: Path, tmp_path: Path, rows: int, hold: bool, wait: bool = True) -> None:
        self.stderr = open(tmp_path / "loop.stderr", "w+")
        self.proc = subprocess.Popen(
            [sys.executable, "-c", LOOP_SCRIPT, str(path), str(rows), "hold" if hold else "exit",
             "wait" if wait else "nowait"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr, cwd=REPO,
        )
        self._buffer = b""

    def expect(self, word: str, timeout_s: float = 60.0) -> int:
        """Wait for the line ``<word> <int>`` and return the int."""
        deadline = time.monotonic() + timeout_s
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([fd], [], [], max(left, 0.0))
            chunk = os.read(fd, 4096) if ready else b""
            if not chunk:
                self.stderr.seek(0)
                pytest.fail(f"loop process gave no {word!r} line; stderr:\n{self.stderr.read()}")
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        got, value = line.decode().split()
        assert got == word, line
        return int(value)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(60)
        self.proc.stdin.close()
        self.proc.stdout.close()
        self.stderr.close()


def _live(path: Path, n_min: int):
    """The file as read while it is written, once it holds ``n_min`` rows (else None)."""
    try:
        ds = read_dataset(path)
    except DatasetError:
        return None
    return ds if ds.n_samples >= n_min else None


def wait_for_complete(path: Path):
    """The file once the writer has finished it (no longer incomplete)."""

    def complete():
        try:
            ds = read_dataset(path)
        except DatasetError:
            return None
        return None if "incomplete" in ds.experiment_attrs else ds

    return wait_for(complete, what=f"the writer finishing {path}")


def check_rows(ds, n_min: int) -> None:
    """At least n_min rows, exactly the values the loop appended, in order."""
    n = ds.n_samples
    assert n >= n_min, (n, n_min)
    k = np.arange(n)
    assert np.array_equal(ds.t, k / 1000.0)
    assert np.all(np.diff(ds.t) > 0)
    assert np.array_equal(ds["q_m"], 0.001 * k)
    assert np.array_equal(ds["tau_j"], (k % 7).astype(float))


class TestParentKilled:
    @pytest.mark.parametrize("wait", [True, False], ids=["started", "ready-unread"])
    def test_writer_finishes_the_file(self, tmp_path, wait):
        # Without waiting for the start, the loop dies with the writer's "ready" unread in its socket: the
        # writer then reads a reset, not an end of file, and must still finish.
        path = tmp_path / "killed.h5"
        loop = _Loop(path, tmp_path, rows=1500, hold=True, wait=wait)
        try:
            loop.expect("writer")
            appended = loop.expect("running")
            if not wait:
                wait_for(lambda: _live(path, appended), what="the writer taking the rows")
            os.kill(loop.proc.pid, signal.SIGKILL)  # the loop only, not its writer
            loop.proc.wait(60)
            ds = wait_for_complete(path)
        finally:
            loop.stop()
        check_rows(ds, appended)  # every row appended before the kill
        assert ds.experiment_attrs["interrupted"] is True
        assert ds.experiment_attrs["lost_rows"] == 0


class TestBothKilled:
    def test_last_flush_is_readable(self, tmp_path):
        path = tmp_path / "both.h5"
        loop = _Loop(path, tmp_path, rows=1500, hold=True)
        try:
            writer_pid = loop.expect("writer")
            loop.expect("running")
            # Kill both once a flush is on disk (how soon it comes depends on the machine's load).
            flushed = wait_for(lambda: _live(path, 1000), what="1000 rows flushed").n_samples
            os.kill(writer_pid, signal.SIGKILL)
            os.kill(loop.proc.pid, signal.SIGKILL)
            loop.proc.wait(60)
        finally:
            loop.stop()
        with pytest.raises(OSError):
            h5py.File(path, "r")  # left with the SWMR writer's flags set
        ds = read_dataset(path)
        assert ds.experiment_attrs["incomplete"] is True
        # Every row that was flushed before the kill is there.
        check_rows(ds, flushed)


class TestUnclosedAtExit:
    def test_exit_hook_finishes_the_file(self, tmp_path):
        path = tmp_path / "exit.h5"
        loop = _Loop(path, tmp_path, rows=300, hold=False)
        try:
            loop.expect("writer")
            assert loop.expect("running") == 300
            assert loop.expect("done") == 300
            assert loop.proc.wait(60) == 0
        finally:
            loop.stop()
        ds = read_dataset(path)
        check_rows(ds, 300)
        assert ds.n_samples == 300
        assert "incomplete" not in ds.experiment_attrs and "interrupted" not in ds.experiment_attrs


# ---------------------------------------------------------------------------


class TestErrors:
    def test_unwritable_path(self, tmp_path):
        blocker = tmp_path / "file"
        blocker.write_text("x")
        log = make_writer(blocker / "run.h5")  # parent is a file
        with pytest.raises(IiwaIdentError) as excinfo:
            log.start()
        message = str(excinfo.value)
        assert message.startswith(f"{blocker / 'run.h5'}: cannot write") and "\n" not in message
        assert log.close() == LogStats(0, 0, 0, blocker / "run.h5")

    def test_close_without_start(self, tmp_path):
        log = make_writer(tmp_path / "never.h5")
        assert log.close() == LogStats(0, 0, 0, tmp_path / "never.h5")
        assert not (tmp_path / "never.h5").exists()
        with pytest.raises(RuntimeError):
            log.start()

    @pytest.mark.parametrize(
        ("signals", "fragment"),
        [
            (["t", "q_m", "torque"], "unknown signal 'torque'"),
            (["t", "q_m"], "missing required signal 'tau_j'"),
            (["t", "q_m", "tau_j", "q_m"], "repeat"),
        ],
    )
    def test_bad_signals(self, tmp_path, signals, fragment):
        with pytest.raises(DatasetError, match=fragment):
            make_writer(tmp_path / "a.h5", signals=signals)

    def test_bad_metadata_and_options(self, tmp_path):
        with pytest.raises(DatasetError, match="joint 9"):
            make_writer(tmp_path / "a.h5", joint=9)
        with pytest.raises(DatasetError, match="experiment attribute 'm'"):
            make_writer(tmp_path / "a.h5", experiment_attrs={"m": {"x": 1}})
        with pytest.raises(ValueError, match="flush_interval_s"):
            make_writer(tmp_path / "a.h5", flush_interval_s=2.0)
        with pytest.raises(ValueError, match="capacity_rows"):
            make_writer(tmp_path / "a.h5", capacity_rows=0)

    def test_append_misuse(self, tmp_path):
        log = make_writer(tmp_path / "a.h5", signals=["t", "q_m", "tau_j"])
        with pytest.raises(RuntimeError):
            log.append((0.0, 0.0, 0.0))
        log.start()
        try:
            with pytest.raises(ValueError, match="expected 3"):
                log.append((0.0,))  # numpy alone would broadcast it
            with pytest.raises(RuntimeError):
                log.start()
            assert log.append((0.0, 0.0, 0.0)) and log.append((0.001, 0.0, 0.0))
        finally:
            log.close()
        with pytest.raises(RuntimeError):
            log.append((0.002, 0.0, 0.0))
        assert read_dataset(tmp_path / "a.h5").n_samples == 2

    def test_too_short_run_leaves_no_file(self, tmp_path):
        path = tmp_path / "short.h5"
        with make_writer(path) as log:
            log.append(random_rows(1)[0])
        assert log.close().written == 1
        assert not path.exists()

    def test_invalid_data_keeps_recording(self, tmp_path):
        path = tmp_path / "bad.h5"
        log = make_writer(path, signals=["t", "q_m", "tau_j"]).start()
        for t in (0.0, 0.001, 0.001, 0.002):
            log.append((t, 0.0, 0.0))
        with pytest.raises(DatasetError, match="t is not strictly increasing at index 2"):
            log.close()
        assert log.close().written == 4  # raised once, then the stats
        with h5py.File(path, "r") as h5:  # the recording stays, closed cleanly
            assert h5.attrs["in_progress"] == 1
            assert h5["signals"]["t"].shape == (4,)

    def test_bad_close_attrs_keep_writer_running(self, tmp_path):
        path = tmp_path / "a.h5"
        log = make_writer(path, signals=["t", "q_m", "tau_j"]).start()
        try:
            log.append((0.0, 0.0, 0.0))
            with pytest.raises(DatasetError, match="experiment attribute 'bad'"):
                log.close({"bad": None})
            assert log.append((0.001, 0.0, 0.0))
        finally:
            stats = log.close({"good": 1})
        assert stats.written == 2
        assert read_dataset(path).experiment_attrs["good"] == 1
