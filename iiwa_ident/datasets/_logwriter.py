"""Background HDF5 logging of a 1 kHz control loop in dataset format v1.

The control loop calls :meth:`LogWriter.append` once per cycle. The row is
copied into a ring buffer in shared memory and a separate writer *process*
moves it to the file, so the loop never waits on disk nor on the GIL that
h5py holds while it writes (a writer thread would share that GIL).

Ring buffer
-----------
One :class:`multiprocessing.shared_memory.SharedMemory` block (named
``iiwa-ident-log-<pid>-<random>``, unlinked on every way out) holds a
header of int64 slots (``head`` = rows appended, ``tail`` = rows taken by
the writer, ``lost`` = rows refused because the ring was full, writer
state) and ``capacity_rows`` x ``n_signals`` float64 rows. There is one
producer (the loop) and one consumer (the writer): the producer writes the
row, then publishes it by storing ``head``; the consumer copies rows, then
frees them by storing ``tail``. The writer only takes rows up to the
``head`` it saw one poll earlier (20-50 ms), so a row is never read before
its own stores are visible, even on CPUs that may reorder stores.

Writer process
--------------
Started with the ``spawn`` method: a fresh interpreter that imports only
numpy, h5py and this module, so it inherits neither the loop's memory nor
its threads or locks (``fork`` could copy a lock held by another thread).
``forkserver`` is no faster for the one writer per run, as it first has to
start its server the same way. As for any ``spawn`` child, the program's
main module must be safe to import (guarded by ``if __name__ ==
"__main__":``). The writer ignores SIGINT (Ctrl-C goes to the whole process
group; the loop decides when to stop) and drops a real-time scheduling
policy inherited from the loop. It does not change the CPU affinity, so
call :meth:`LogWriter.start` before pinning the loop to an isolated CPU.

File life cycle and crashes
---------------------------
:meth:`LogWriter.start` creates the file with all root attributes, the
``/experiment`` attributes known at start, empty resizable ``/signals/*``
arrays, the root attribute ``in_progress = 1`` and a root array
``/rows_flushed``. The writer reopens it in HDF5 SWMR mode, in which the
file on disk stays consistent between flushes, appends new rows every poll
and flushes at least every ``flush_interval_s``: first the signals, then
``/rows_flushed``, then again, so the count never exceeds the rows on disk.
:func:`~iiwa_ident.datasets.read_dataset` opens such a file (live or left
by a killed writer) as a SWMR reader, keeps the counted rows and sets
``experiment_attrs["incomplete"] = True``.

On :meth:`LogWriter.close`, or when the writer sees that the loop's process
has died (EOF on its pipe, or a new parent pid), or on SIGTERM, the writer
takes every row left in the ring, closes the SWMR file and replaces it
atomically with a complete dataset written by
:func:`~iiwa_ident.datasets.write_dataset` (no ``in_progress``, no
``/rows_flushed``). The file under the path is therefore always either a
readable recording in progress or the complete dataset. The final rewrite
needs the whole run in the writer's memory and briefly twice its size on
disk (about 80 kB per signal per 10 s at 1 kHz). ``/experiment`` then also
holds ``lost_rows`` (int) and, if the loop's process died or the writer
was terminated, ``interrupted = True``.
"""

from __future__ import annotations

import atexit
import math
import multiprocessing
import multiprocessing.connection
import os
import secrets
import signal
import time
import warnings
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from multiprocessing.shared_memory import SharedMemory
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from iiwa_ident.datasets import _format
from iiwa_ident.datasets._format import SIGNAL_UNITS, Dataset, write_dataset
from iiwa_ident.errors import DatasetError, IiwaIdentError

__all__ = ["SHM_PREFIX", "LogStats", "LogWriter"]

# Header slots (int64); head and tail sit on separate 64-byte cache lines
# so the two processes do not invalidate each other's line on every store.
_HEAD = 0
_TAIL = 8
_LOST = 16
_STATE = 17
_HEADER_SLOTS = 32
_ROWS_OFFSET = _HEADER_SLOTS * 8  # bytes
#: Name prefix of the ring buffers in /dev/shm, followed by the loop's pid.
SHM_PREFIX = "iiwa-ident-log-"

# Writer states in the header, for diagnostics.
_STARTING, _RUNNING, _FINISHED, _FAILED = 0, 1, 2, 3

_POLL_S = 0.025  # writer poll period [s]
_CHUNK_ROWS = 8192  # HDF5 chunk of a signal: 64 kB, 8 s at 1 kHz
_START_TIMEOUT_S = 60.0  # spawn + imports, generous for a loaded machine [s]
_CLOSE_TIMEOUT_S = 300.0  # final rewrite of a long run [s]
_MAX_FLUSH_INTERVAL_S = 1.0

# Writers still open at interpreter exit are closed first, so the file is
# finished and multiprocessing does not wait forever on a writer that still
# expects a close message.
_OPEN_WRITERS: weakref.WeakSet[LogWriter] = weakref.WeakSet()


@atexit.register
def _close_open_writers() -> None:
    for writer in list(_OPEN_WRITERS):
        try:
            writer.close()
        except Exception as err:  # at exit there is no caller left to raise to
            warnings.warn(f"closing log writer at exit: {err}", RuntimeWarning, stacklevel=1)


@dataclass(frozen=True)
class LogStats:
    """Counts of one run of a :class:`LogWriter`.

    Parameters
    ----------
    appended : int
        Rows accepted by :meth:`LogWriter.append`.
    written : int
        Rows in the file after closing (rows taken from the ring if the
        writer failed before finishing).
    lost : int
        Rows refused because the ring buffer was full.
    path : pathlib.Path
        The dataset file.
    """

    appended: int
    written: int
    lost: int
    path: Path


class LogWriter:
    """Background HDF5 writer of one run in dataset format v1.

    Parameters
    ----------
    path : str or os.PathLike
        Target ``.h5`` file; missing parent directories are created and an
        existing file is replaced, as :func:`~iiwa_ident.datasets.write_dataset`
        does.
    signals : sequence of str
        Signal names, in the order of the values of every row; names and
        units as in :data:`~iiwa_ident.datasets.SIGNAL_UNITS` (``t`` [s],
        ``q_m`` [rad] and ``tau_j`` [Nm] are required).
    experiment : str
        Kind of experiment, one of :data:`~iiwa_ident.datasets.EXPERIMENTS`.
    source : str
        One of :data:`~iiwa_ident.datasets.SOURCES` (``"robot"`` for a run).
    joint : int
        Joint number, 1..7.
    sample_rate_hz : float
        Nominal sample rate [Hz].
    experiment_attrs : mapping, optional
        ``/experiment`` attributes known at the start (scalars, strings or
        1-D numeric arrays); stored in the file from the start.
    capacity_rows : int, optional
        Rows the ring buffer holds (60 s at 1 kHz by default); when the
        writer falls this far behind, :meth:`append` refuses rows.
    flush_interval_s : float, optional
        Longest time between two flushes of the file [s], in (0, 1].

    Raises
    ------
    DatasetError
        If a signal name, the metadata or an experiment attribute violates
        the dataset format.
    ValueError
        If ``capacity_rows`` or ``flush_interval_s`` is out of range.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from iiwa_ident.datasets import read_dataset
    >>> path = Path(tempfile.mkdtemp()) / "run.h5"
    >>> with LogWriter(path, ["t", "q_m", "tau_j"], experiment="free",
    ...                source="robot", joint=3, sample_rate_hz=1000.0) as log:
    ...     kept = [log.append((k / 1000.0, 0.0, 0.0)) for k in range(1000)]
    >>> all(kept), read_dataset(path).n_samples
    (True, 1000)
    >>> import shutil; shutil.rmtree(path.parent)
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        signals: Sequence[str],
        *,
        experiment: str,
        source: str,
        joint: int,
        sample_rate_hz: float,
        experiment_attrs: Mapping[str, Any] | None = None,
        capacity_rows: int = 60_000,
        flush_interval_s: float = 0.5,
    ) -> None:
        self._path = Path(path)
        where = str(self._path)
        names = [str(name) for name in signals]
        problem = _format._signal_names_problem(names)
        if problem is None and len(set(names)) != len(names):
            problem = f"signal names repeat ({', '.join(names)})"
        if problem is None:
            problem = _format._metadata_problem(experiment, source, joint, sample_rate_hz)
        attrs = dict(experiment_attrs or {})
        if problem is None:
            problem = _format._experiment_attrs_problem(attrs)
        if problem is not None:
            raise DatasetError(f"{where}: {problem}")
        if isinstance(capacity_rows, bool) or not isinstance(capacity_rows, int) or capacity_rows < 2:
            raise ValueError(f"capacity_rows must be an integer >= 2, got {capacity_rows!r}")
        if not (isinstance(flush_interval_s, (int, float)) and math.isfinite(flush_interval_s)
                and 0 < flush_interval_s <= _MAX_FLUSH_INTERVAL_S):
            raise ValueError(
                f"flush_interval_s must be in (0, {_MAX_FLUSH_INTERVAL_S}] s, got {flush_interval_s!r}"
            )
        self._names = names
        self._n = len(names)
        self._meta = Dataset(
            signals={},
            experiment=experiment,
            source=source,
            joint=int(joint),
            sample_rate_hz=float(sample_rate_hz),
            experiment_attrs=attrs,
        )
        self._capacity = capacity_rows
        self._flush_interval_s = float(flush_interval_s)

        # State of the loop side; append() reads only plain attributes.
        self._head = 0
        self._tail_seen = 0
        self._lost = 0
        self._rows: np.ndarray | None = None
        self._hdr: memoryview | None = None
        self._shm: SharedMemory | None = None
        self._conn: multiprocessing.connection.Connection | None = None
        self._proc: multiprocessing.process.BaseProcess | None = None
        self._starting = False  # launched, its "ready" not yet received
        self._stats: LogStats | None = None

    # ------------------------------------------------------------------
    # the hot path

    def append(self, row: Sequence[float]) -> bool:
        """Queue one row (one control cycle) for writing; never blocks.

        Parameters
        ----------
        row : sequence of float
            One value per signal, in the order given at construction, each
            in its signal's unit.

        Returns
        -------
        bool
            True if queued; False if the ring buffer is full (the row is
            counted in :attr:`lost`).

        Raises
        ------
        ValueError
            If ``row`` does not hold one number per signal.
        RuntimeError
            If the writer is not started or already closed.
        """
        head = self._head
        if head - self._tail_seen >= self._capacity:
            # Refresh the consumer's position only when the ring looks full,
            # which keeps the common path free of shared-memory reads.
            hdr = self._hdr
            if hdr is None:
                raise RuntimeError("LogWriter.append() after close()")
            self._tail_seen = hdr[_TAIL]
            if head - self._tail_seen >= self._capacity:
                self._lost += 1
                hdr[_LOST] = self._lost
                return False
        rows = self._rows
        if rows is None:
            raise RuntimeError("LogWriter.append() before start() or after close()")
        if len(row) != self._n:  # numpy would silently broadcast a 1-element row
            raise ValueError(f"row has {len(row)} value(s), expected {self._n} ({', '.join(self._names)})")
        rows[head % self._capacity] = row
        head += 1
        self._head = head
        self._hdr[_HEAD] = head  # type: ignore[index]  # publishes the row; set with _rows, checked above
        return True

    @property
    def appended(self) -> int:
        """Rows accepted by :meth:`append` so far."""
        return self._head

    @property
    def lost(self) -> int:
        """Rows refused by :meth:`append` because the ring buffer was full."""
        return self._lost

    @property
    def path(self) -> Path:
        """The dataset file."""
        return self._path

    @property
    def writer_pid(self) -> int | None:
        """Process id of the writer, e.g. to set its CPU affinity; None before :meth:`start`."""
        return None if self._proc is None else self._proc.pid

    # ------------------------------------------------------------------
    # start and close

    def start(self, wait: bool = True) -> LogWriter:
        """Create the file and start the writer process.

        With ``wait`` it blocks until the writer has the file open (a new
        interpreter imports numpy and h5py: a fraction of a second on an idle
        machine, seconds on a loaded one), so call it before the control loop
        starts. Without, it returns once the file and the ring exist and the
        process is launched: rows can be appended at once (the ring holds
        them until the writer takes them), and the writer's start is checked
        by :meth:`ready` and at the latest by :meth:`close`.

        Parameters
        ----------
        wait : bool
            Wait for the writer to have the file open.

        Returns
        -------
        LogWriter
            ``self``.

        Raises
        ------
        DatasetError
            One-line message naming the file if it cannot be created or the
            writer cannot open it.
        IiwaIdentError
            If the shared-memory ring cannot be created.
        RuntimeError
            If called twice or after :meth:`close`.
        """
        if self._proc is not None or self._stats is not None:
            raise RuntimeError("LogWriter.start() may be called only once")
        self._meta.created_utc = _format._now_utc()
        _create_skeleton(self._path, self._meta, self._names)
        try:
            self._start_writer(wait)
        except BaseException:
            try:  # an empty recording that no writer will fill
                self._path.unlink()
            except OSError:
                pass
            raise
        return self

    def _start_writer(self, wait: bool) -> None:
        """Create the ring and the writer process; wait until it has the file open."""
        nbytes = _ROWS_OFFSET + self._capacity * self._n * 8
        # Named after the process, so that a segment left by a crash (SIGKILL of both processes) can be told
        # apart in /dev/shm: iiwa-ident-log-<pid of the loop>-<random>.
        name = f"{SHM_PREFIX}{os.getpid()}-{secrets.token_hex(8)}"
        try:
            shm = SharedMemory(create=True, size=nbytes, name=name)
        except OSError as err:
            raise IiwaIdentError(
                f"{self._path}: cannot create a {nbytes / 1e6:.1f} MB shared-memory ring buffer "
                f"({err.strerror or err})"
            ) from err
        self._shm = shm
        self._hdr = _shared_buffer(shm)[:_ROWS_OFFSET].cast("q")
        rows = np.ndarray((self._capacity, self._n), dtype=np.float64, buffer=shm.buf, offset=_ROWS_OFFSET)
        rows.fill(0.0)  # touch every page now, not as page faults inside the loop
        self._rows = rows
        ctx = multiprocessing.get_context("spawn")
        parent_end, child_end = ctx.Pipe(duplex=True)
        proc = ctx.Process(
            target=_writer_main,
            name=f"iiwa-logwriter-{self._path.name}",
            args=(child_end, shm.name, str(self._path), self._names, self._meta,
                  self._capacity, self._flush_interval_s, os.getpid()),
        )
        try:
            proc.start()
        except BaseException:
            child_end.close()
            parent_end.close()
            self._release_ring(unlink=True)
            raise
        # Only the writer may hold this end, so it sees EOF when we die.
        child_end.close()
        self._conn = parent_end
        self._proc = proc
        _OPEN_WRITERS.add(self)
        self._starting = True
        if wait:
            self._await_start()

    def ready(self, timeout_s: float = 0.0) -> bool:
        """Whether the writer has the file open, waiting up to ``timeout_s`` [s] to know.

        Raises
        ------
        DatasetError
            If the writer failed to start (once; the recording is then abandoned).
        RuntimeError
            Before :meth:`start`.
        """
        if self._proc is None:
            raise RuntimeError("LogWriter.ready() before start()")
        if not self._starting:
            return True
        proc, conn = self._proc, self._conn
        if conn is None:
            raise RuntimeError("LogWriter.ready() before start()")
        try:
            arrived = conn.poll(timeout_s)
        except (EOFError, OSError):
            arrived = True
        if not arrived and proc.is_alive():
            return False
        reply = _receive(conn, 0.0)
        self._starting = False
        if reply is None or reply[0] != "ready":
            self._abort()
            if reply is not None and reply[0] == "error":
                raise DatasetError(reply[1])
            raise DatasetError(f"{self._path}: log writer process did not start (exit code {proc.exitcode})")
        return True

    def _await_start(self) -> None:
        """Wait for the writer to have the file open; raise DatasetError if it does not."""
        if not self.ready(_START_TIMEOUT_S):
            self._starting = False
            self._abort()
            raise DatasetError(f"{self._path}: log writer process did not start within {_START_TIMEOUT_S:g} s")

    def close(self, experiment_attrs: Mapping[str, Any] | None = None) -> LogStats:
        """Finish the file and stop the writer; idempotent.

        Waits until every row appended so far is in the file and the file
        has been replaced by a complete dataset. A run of fewer than 2 rows
        cannot be a valid dataset, so its file is removed.

        Parameters
        ----------
        experiment_attrs : mapping, optional
            ``/experiment`` attributes known only at the end; they update
            those given at construction. ``lost_rows`` is added.

        Returns
        -------
        LogStats
            Rows appended, written and lost; later calls return the same.

        Raises
        ------
        DatasetError
            If an attribute violates the format (nothing is closed then;
            call again with valid attributes), or, once, if the writer failed
            or the data are not a valid dataset (e.g. a non-finite value or a
            time that does not increase); the file then stays the recording
            in progress, readable with :func:`~iiwa_ident.datasets.read_dataset`
            as far as it is valid.
        """
        if self._stats is not None:
            return self._stats
        attrs = dict(experiment_attrs or {})
        problem = _format._experiment_attrs_problem(attrs)
        if problem is not None:
            raise DatasetError(f"{self._path}: {problem}")
        if self._proc is None:
            self._stats = LogStats(self._head, 0, self._lost, self._path)
            return self._stats
        if self._starting:
            try:
                self._await_start()
            except DatasetError:
                try:  # an empty recording that no writer filled
                    self._path.unlink()
                except OSError:
                    pass
                raise

        conn, hdr = self._conn, self._hdr
        if conn is None or hdr is None:
            raise RuntimeError("LogWriter.close(): the writer was started without its pipe and ring")
        try:
            conn.send(("close", attrs))
        except OSError:  # the writer already exited; its last message may still be queued
            pass
        reply = _receive(conn, _CLOSE_TIMEOUT_S)
        written = int(hdr[_TAIL])
        error = None
        if reply is not None and reply[0] == "closed":
            written = int(reply[1])
        elif reply is not None and reply[0] == "error":
            error = reply[1]
        else:
            self._proc.join(1.0)
            error = (
                f"{self._path}: log writer process ended without finishing the file "
                f"(exit code {self._proc.exitcode}); the file holds the rows flushed before"
            )
        self._stats = LogStats(self._head, written, self._lost, self._path)
        self._abort()
        if error is not None:
            raise DatasetError(error)
        return self._stats

    def __enter__(self) -> LogWriter:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
            return
        # The exception in flight matters more than a failure to finish.
        try:
            self.close()
        except IiwaIdentError as err:
            warnings.warn(str(err), RuntimeWarning, stacklevel=2)

    def __repr__(self) -> str:
        state = "closed" if self._stats is not None else "running" if self._proc else "not started"
        return f"LogWriter({str(self._path)!r}, {self._n} signals, {state}, appended={self._head})"

    # ------------------------------------------------------------------

    def _abort(self) -> None:
        """Stop the writer (if still running) and release every resource."""
        _OPEN_WRITERS.discard(self)
        proc, conn = self._proc, self._conn
        if proc is not None:
            proc.join(5.0)
            if proc.is_alive():
                proc.terminate()  # SIGTERM: the writer still tries to finish the file
                proc.join(5.0)
            if proc.is_alive():
                proc.kill()
                proc.join(1.0)
        if conn is not None:
            conn.close()
        self._release_ring(unlink=True)
        if self._stats is None:
            self._stats = LogStats(self._head, 0, self._lost, self._path)
        # Leave append() raising rather than writing to freed memory.
        self._tail_seen = self._head - self._capacity

    def _release_ring(self, unlink: bool) -> None:
        self._rows = None
        if self._hdr is not None:
            self._hdr.release()
            self._hdr = None
        if self._shm is not None:
            self._shm.close()
            if unlink:
                try:
                    self._shm.unlink()
                except FileNotFoundError:  # the writer unlinked it when it saw us gone
                    pass
            self._shm = None


def _receive(conn: multiprocessing.connection.Connection, timeout_s: float) -> tuple | None:
    """Next message from the writer, or None on EOF or timeout."""
    try:
        if conn.poll(timeout_s):
            return conn.recv()
    except (EOFError, OSError):
        pass
    return None


def _create_skeleton(path: Path, meta: Dataset, names: Sequence[str]) -> None:
    """Create the file of a recording in progress, atomically, with zero rows."""
    tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # SWMR needs the latest file format; it is readable by HDF5 >= 1.10.
        with h5py.File(tmp, "x", libver="latest") as h5:
            _format._write_root_attrs(h5, meta)
            h5.attrs[_format._IN_PROGRESS_ATTR] = np.int64(1)
            signals = h5.create_group("signals")
            for name in SIGNAL_UNITS:  # canonical order, as write_dataset
                if name in names:
                    dset = signals.create_dataset(
                        name, shape=(0,), maxshape=(None,), chunks=(_CHUNK_ROWS,),
                        dtype=np.float64, fillvalue=np.nan,  # a row never written reads as NaN, not 0
                    )
                    dset.attrs["unit"] = SIGNAL_UNITS[name]
            experiment = h5.create_group("experiment", track_order=True)
            for key, value in meta.experiment_attrs.items():
                _format._write_attr_value(experiment.attrs, key, value)
            h5.create_dataset(_format._ROWS_FLUSHED, data=np.zeros(1, dtype=np.int64))
        os.replace(tmp, path)
    except OSError as err:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise DatasetError(f"{path}: cannot write: {err.strerror or _format._first_line(err)}") from err


# --------------------------------------------------------------------------
# the writer process


def _drop_realtime() -> None:
    """Leave a real-time policy inherited from the loop and take the lowest priority.

    Disk I/O must not preempt the loop: on a machine with few cores the writer
    competes with the loop (and, in tests, the emulator) for CPU, and the ring
    holds a minute of rows, so it can always wait.
    """
    try:
        if os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):  # not Linux, or not permitted: keep going
        pass
    try:
        os.nice(19 - os.nice(0))
    except (AttributeError, OSError):
        pass


def _shared_buffer(shm: SharedMemory) -> memoryview:
    """The shared memory's buffer (there while it is open)."""
    if shm.buf is None:
        raise OSError(f"shared memory {shm.name} is closed")
    return shm.buf


class _Sink:
    """The writer's side: SWMR file, ring consumer and flush bookkeeping."""

    def __init__(self, shm: SharedMemory, path: str, names: Sequence[str], capacity: int) -> None:
        self.path = path
        self.capacity = capacity
        buf = _shared_buffer(shm)
        self.hdr = buf[:_ROWS_OFFSET].cast("q")
        self.rows = np.ndarray((capacity, len(names)), dtype=np.float64, buffer=buf, offset=_ROWS_OFFSET)
        self.tail = int(self.hdr[_TAIL])
        self.written = 0
        self.flushed = 0
        self.h5: h5py.File | None = None
        try:
            self.h5 = _open_for_append(path)
            self.dsets = [self.h5["signals"][name] for name in names]
            self.progress = self.h5[_format._ROWS_FLUSHED]
            self.h5.swmr_mode = True
        except BaseException:
            self.release()
            raise

    def drain(self, limit: int) -> None:
        """Move rows ``tail .. limit-1`` from the ring to the file (not flushed)."""
        k = limit - self.tail
        if k <= 0:
            return
        start = self.tail % self.capacity
        stop = start + k
        if stop <= self.capacity:
            block = self.rows[start:stop].T.copy()
        else:
            block = np.concatenate((self.rows[start:], self.rows[: stop - self.capacity])).T.copy()
        self.tail = limit
        self.hdr[_TAIL] = limit  # the copy is done: the loop may reuse the slots
        n0, n1 = self.written, self.written + k
        for dset, column in zip(self.dsets, block):
            dset.resize((n1,))
            dset[n0:n1] = column
        self.written = n1

    def flush(self) -> None:
        """Flush signals, then the row count, so the count is never ahead of the data."""
        if self.flushed == self.written or self.h5 is None:
            return
        self.h5.flush()
        self.progress[0] = self.written
        self.h5.flush()
        self.flushed = self.written

    def read_all(self) -> list[np.ndarray]:
        return [dset[()] for dset in self.dsets]

    def close_file(self) -> None:
        """Close the SWMR file; clears its consistency flags."""
        if self.h5 is not None and self.h5.id.valid:
            self.h5.close()

    def release(self) -> None:
        """Close the file and drop every view of the shared memory."""
        self.close_file()
        self.rows = np.zeros((0, 0))  # drops the view of the shared memory
        self.hdr.release()


#: How long the writer retries opening its file while a reader holds the file's lock [s].
_OPEN_RETRY_S = 10.0


def _open_for_append(path: str) -> h5py.File:
    """Open the skeleton for writing; while a reader has it open (``iiwa-ident info``, a live view polling
    the log just as the run starts) HDF5's file lock refuses the writer: that reader holds it for
    milliseconds, so the open is tried again rather than the recording given up."""
    deadline = time.monotonic() + _OPEN_RETRY_S
    while True:
        try:
            return h5py.File(path, "r+", libver="latest")
        except OSError as err:
            if "lock" not in str(err) or time.monotonic() > deadline:
                raise
        time.sleep(0.01)


def _writer_main(
    conn: multiprocessing.connection.Connection,
    shm_name: str,
    path: str,
    names: list[str],
    meta: Dataset,
    capacity: int,
    flush_interval_s: float,
    parent_pid: int,
) -> None:
    """Body of the writer process; reports ``ready``, then ``closed`` or ``error``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    terminated: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: terminated.append(signum))
    _drop_realtime()
    shm = SharedMemory(name=shm_name)
    sink = None
    parent_gone = False

    def send(message: tuple) -> None:
        try:
            conn.send(message)
        except OSError:  # the loop's process is gone; nobody to tell
            pass

    try:
        try:
            sink = _Sink(shm, path, names, capacity)
        except (OSError, KeyError) as err:
            send(("error", f"{path}: log writer cannot open the file ({_format._first_line(err)})"))
            sink = None
            return
        sink.hdr[_STATE] = _RUNNING
        send(("ready",))
        final_attrs, parent_gone = _follow(sink, conn, parent_pid, flush_interval_s, terminated)
        written = _finish(sink, path, names, meta, final_attrs, interrupted=parent_gone or bool(terminated))
        sink.hdr[_STATE] = _FINISHED
        send(("closed", written))
    except Exception as err:  # report any failure as one line, then exit
        if sink is not None:
            try:
                sink.hdr[_STATE] = _FAILED
                sink.close_file()
            except Exception:
                pass
        message = str(err) if isinstance(err, DatasetError) else (
            f"{path}: log writer failed: {type(err).__name__}: {_format._first_line(err)}"
        )
        send(("error", message))
    finally:
        if sink is not None:
            try:
                sink.release()
            except Exception:
                pass
        conn.close()
        shm.close()
        if parent_gone:
            # The loop cannot unlink the ring any more; doing it here also
            # keeps the resource tracker from reporting a leak.
            try:
                shm.unlink()
            except FileNotFoundError:
                pass


def _follow(sink: _Sink, conn: multiprocessing.connection.Connection, parent_pid: int, flush_interval_s: float,
            terminated: list[int]) -> tuple[dict[str, Any], bool]:
    """Drain the ring into the file until the loop closes the log, dies or the writer is terminated.

    Returns the attributes the loop's ``close`` message adds (none without one) and whether the loop's
    process is gone.
    """
    seen_head = sink.tail
    last_flush = time.monotonic()
    while True:
        if conn.poll(_POLL_S):
            try:
                message = conn.recv()
            except (EOFError, OSError):  # reset, not EOF, when the loop died with a reply unread
                return {}, True
            if message[0] == "close":
                return dict(message[1]), False
        if os.getppid() != parent_pid:  # covers a copy of the pipe inherited by a grandchild
            return {}, True
        if terminated:
            return {}, False
        head = int(sink.hdr[_HEAD])
        sink.drain(min(head, seen_head))  # see "Ring buffer" in the module docstring
        seen_head = head
        now = time.monotonic()
        if now - last_flush >= flush_interval_s:
            sink.flush()
            last_flush = now


def _finish(sink: _Sink, path: str, names: list[str], meta: Dataset, final_attrs: dict[str, Any], *,
            interrupted: bool) -> int:
    """Write the whole log as a dataset once the loop has stopped or died; the number of rows written.

    Every published row is visible now. A log shorter than any dataset may be leaves no file.
    """
    sink.drain(int(sink.hdr[_HEAD]))
    sink.flush()
    columns = sink.read_all()
    lost = int(sink.hdr[_LOST])
    sink.close_file()
    written = sink.written
    if written < _format._MIN_SAMPLES:
        try:
            os.unlink(path)
        except OSError:
            pass
        return written
    attrs = dict(meta.experiment_attrs)
    attrs.update(final_attrs)
    attrs["lost_rows"] = lost
    if interrupted:
        attrs["interrupted"] = True
    write_dataset(path, Dataset(signals=dict(zip(names, columns)), experiment=meta.experiment, source=meta.source,
                                joint=meta.joint, sample_rate_hz=meta.sample_rate_hz, experiment_attrs=attrs,
                                created_utc=meta.created_utc))
    return written
