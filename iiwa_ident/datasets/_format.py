"""The on-disk dataset format, version 1 (HDF5 via h5py).

Layout of a file::

    /                      attrs: format, format_version, experiment, source,
                                  joint, sample_rate_hz, created_utc
    /signals/<name>        1-D float64 arrays of one length, attr ``unit``
    /experiment            attrs describing the excitation (f0_hz, ...)
    /truth                 simulated data only: nested groups and attrs

:func:`read_dataset` never opens ``/truth``: identification code must work
on real data, where no ground truth exists, so only evaluation code (through
:func:`read_truth`) may look at it.

Recordings in progress
----------------------
A file that is still being written by a background logger
(:class:`iiwa_ident.datasets.LogWriter`), or whose logger was killed,
carries the root attribute ``in_progress = 1`` and a root array
``/rows_flushed`` (int64, shape (1,)) holding how many rows of every signal
are known to be on disk; complete files carry neither. Such a file is
written in HDF5 SWMR mode, so its consistency flags stay set while the
writer runs and after it is killed: :func:`read_dataset` then opens it as a
SWMR reader, keeps only the first ``min(rows_flushed, shortest signal)``
samples of every signal (the signals are separate arrays and may have been
extended one by one) and reports this with ``experiment_attrs["incomplete"]
= True``.
"""

from __future__ import annotations

import hashlib
import math
import numbers
import os
import re
import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from iiwa_ident.errors import DatasetError

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "EXPERIMENTS",
    "SOURCES",
    "SIGNAL_UNITS",
    "ROBOT_NAME_ATTR",
    "set_robot_name",
    "robot_name",
    "REQUIRED_SIGNALS",
    "Dataset",
    "validate_dataset",
    "write_dataset",
    "read_dataset",
    "dataset_files",
    "COLUMN_LOG_MARK",
    "read_truth",
    "sha256_file",
]

#: Value of the root attribute ``format``.
FORMAT_NAME = "iiwa-ident-dataset"
#: The only ``format_version`` this code reads and writes.
FORMAT_VERSION = 1

#: Allowed values of the root attribute ``experiment``.
EXPERIMENTS: tuple[str, ...] = (
    "chirp",
    "multisine",
    "constant_velocity",
    "quasi_static",
    "hand_guided",
    "step",
    "sine",
    "free",
)
#: Allowed values of the root attribute ``source``.
SOURCES: tuple[str, ...] = ("robot", "simulation", "import")

#: Every signal the format knows, in canonical order, with its required unit.
SIGNAL_UNITS: dict[str, str] = {
    "t": "s",  # sample time
    "q_m": "rad",  # measured motor-side joint position, as FRI reports it
    "tau_j": "Nm",  # measured joint torque
    "tau_c": "Nm",  # torque command sent (present whenever torque-commanded)
    "tau_ext_fri": "Nm",  # external torque estimate reported by FRI
    "q_l_ref": "rad",  # external link-position measurement
    "tau_ext_ref": "Nm",  # external F/T torque about the joint axis
    "q_cmd": "rad",  # commanded position
    "dq_m": "rad/s",  # measured joint velocity, as some drivers export
    "tau_r": "Nm",  # reference torque of the controller
    "tau_j_filt": "Nm",  # spatially filtered joint torque (eq 15)
    "tau_ext_est": "Nm",  # client-side external torque estimate (eq 14)
    "tau_ext_loop": "Nm",  # the external torque a run log's task saw (its --tau-ext source)
    "tau_add": "Nm",  # additive torque sent on top of the robot's controller
    "watchdog": "-",  # watchdog scale 0..1, 1 = normal
    "cycle_us": "us",  # compute time of the control cycle
}
#: Signals every dataset must contain.
REQUIRED_SIGNALS: tuple[str, ...] = ("t", "q_m", "tau_j")

_MIN_SAMPLES = 2

# Markers of a recording in progress (see the module docstring); private
# because only the background logger writes them.
_IN_PROGRESS_ATTR = "in_progress"
_ROWS_FLUSHED = "rows_flushed"


def _now_utc() -> str:
    """Current UTC time as an ISO 8601 string with second resolution."""
    return datetime.now(UTC).isoformat(timespec="seconds")


@dataclass(eq=False, kw_only=True)  # eq on numpy arrays would be ambiguous, so compare explicitly
class Dataset:
    """One recorded or simulated experiment on one joint.

    Parameters
    ----------
    signals : dict of str to numpy.ndarray
        Sampled signals by name (see :data:`SIGNAL_UNITS` for names and
        units): ``t`` [s], ``q_m`` [rad], ``tau_j`` [Nm], ... All 1-D and of
        one length.
    experiment : str
        Kind of excitation, one of :data:`EXPERIMENTS`.
    source : str
        Where the data came from, one of :data:`SOURCES`.
    joint : int
        Joint number, 1..7.
    sample_rate_hz : float
        Nominal sample rate [Hz].
    experiment_attrs : dict, optional
        Parameters of the excitation (e.g. ``f0_hz`` [Hz],
        ``velocity_rad_s`` [rad/s]); values are scalars, strings or 1-D
        numeric arrays.
    created_utc : str, optional
        Creation time, ISO 8601; defaults to now.
    truth : dict or None, optional
        Ground truth of a simulated plant; only used when writing. Reading a
        file always leaves this ``None``.
    path : pathlib.Path or None, optional
        File the dataset was read from, if any.
    """

    signals: dict[str, np.ndarray]
    experiment: str
    source: str
    joint: int
    sample_rate_hz: float
    experiment_attrs: dict[str, Any] = field(default_factory=dict)
    created_utc: str = field(default_factory=_now_utc)
    truth: dict[str, Any] | None = None
    path: Path | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        """Return signal ``name``; raises ``KeyError`` naming what exists."""
        try:
            return self.signals[name]
        except KeyError:
            have = ", ".join(self.signals) or "none"
            raise KeyError(f"dataset has no signal {name!r} (has: {have})") from None

    def has(self, name: str) -> bool:
        """Return whether the dataset contains signal ``name``."""
        return name in self.signals

    @property
    def t(self) -> np.ndarray:
        """Sample times [s]."""
        return self["t"]

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(np.asarray(self.t).shape[0])

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample [s]."""
        t = np.asarray(self.t)
        return float(t[-1] - t[0]) if t.size else 0.0


# --------------------------------------------------------------------------
# validation


def _is_real(value: Any) -> bool:
    """True for int/float (Python or numpy), but not bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def _metadata_problem(experiment: Any, source: Any, joint: Any, sample_rate_hz: Any) -> str | None:
    """Describe what is wrong with the root metadata, or return None."""
    if not isinstance(experiment, str) or experiment not in EXPERIMENTS:
        return f"experiment {experiment!r} is not one of {', '.join(EXPERIMENTS)}"
    if not isinstance(source, str) or source not in SOURCES:
        return f"source {source!r} is not one of {', '.join(SOURCES)}"
    if not _is_int(joint) or not 1 <= int(joint) <= 7:
        return f"joint {joint!r} is not an integer from 1 to 7"
    if not _is_real(sample_rate_hz) or not math.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
        return f"sample_rate_hz {sample_rate_hz!r} is not a finite number > 0"
    return None


def _signal_names_problem(names: list[str]) -> str | None:
    """Describe an unknown or missing signal name, or return None."""
    for name in names:
        if name not in SIGNAL_UNITS:
            return f"unknown signal {name!r} (known: {', '.join(SIGNAL_UNITS)})"
    for name in REQUIRED_SIGNALS:
        if name not in names:
            return f"missing required signal {name!r}"
    return None


def _signal_values_problem(signals: Mapping[str, Any]) -> str | None:
    """Check shapes, lengths, finiteness and time order; return a problem or None."""
    arrays: dict[str, np.ndarray] = {}
    for name, values in signals.items():
        arr = np.asarray(values)
        if arr.dtype == np.bool_ or not (
            np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
        ):
            return f"signal {name!r} has non-numeric dtype {arr.dtype}"
        if arr.ndim != 1:
            return f"signal {name!r} is not 1-D (shape {arr.shape})"
        arrays[name] = arr
    lengths = {name: arr.shape[0] for name, arr in arrays.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{name} has {n}" for name, n in lengths.items())
        return f"signals have unequal lengths ({listed})"
    n = next(iter(lengths.values()), 0)
    if n < _MIN_SAMPLES:
        return f"dataset is empty: {n} sample(s), need at least {_MIN_SAMPLES}"
    for name, arr in arrays.items():
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            i = int(bad[0])
            return f"signal {name!r} has a non-finite value ({arr[i]}) at index {i}"
    dt = np.diff(arrays["t"].astype(np.float64))
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        t = arrays["t"]
        return f"t is not strictly increasing at index {i} (t[{i}]={t[i]!r} after t[{i - 1}]={t[i - 1]!r})"
    return None


def _attr_value_problem(value: Any) -> str | None:
    """Check one experiment attribute value (scalar, str or 1-D numeric)."""
    if isinstance(value, (str, bool, np.bool_)) or _is_real(value):
        return None
    if isinstance(value, (list, tuple, np.ndarray)):
        arr = np.asarray(value)
        numeric = arr.dtype != np.bool_ and (
            np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
        )
        if arr.ndim == 1 and (numeric or arr.size == 0):
            return None
        return "must be a 1-D numeric array"
    return f"has unsupported type {type(value).__name__}"


def _key_problem(key: Any) -> str | None:
    # '/' would be read by HDF5 as a path separator and '.' names the group itself.
    if not isinstance(key, str) or not key or "/" in key or key == ".":
        return f"key {key!r} must be a non-empty string without '/'"
    return None


def _truth_problem(tree: Any, where: str = "truth") -> str | None:
    """Check a nested truth dict; return a problem naming the key, or None."""
    if not isinstance(tree, Mapping):
        return f"{where} must be a dict, got {type(tree).__name__}"
    for key, value in tree.items():
        problem = _key_problem(key)
        if problem:
            return f"{where}: {problem}"
        here = f"{where}[{key!r}]"
        if isinstance(value, Mapping):
            problem = _truth_problem(value, here)
            if problem:
                return problem
        elif isinstance(value, (list, tuple)):
            # Truth may hold tables (e.g. harmonics as [amplitude, phase] rows): any rectangular numeric array.
            try:
                arr = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                return f"{here} must be a (nested) list of numbers"
            if arr.size and not np.all(np.isfinite(arr)):
                return f"{here} must be finite"
        else:
            value_problem = _attr_value_problem(value)
            if value_problem:
                return f"{here} {value_problem}"
    return None


def _experiment_attrs_problem(attrs: Any) -> str | None:
    """Check the ``/experiment`` attributes; return a problem naming the key, or None."""
    if not isinstance(attrs, Mapping):
        return "experiment_attrs must be a dict"
    for key, value in attrs.items():
        key_problem = _key_problem(key)
        if key_problem:
            return f"experiment attribute {key_problem}"
        value_problem = _attr_value_problem(value)
        if value_problem:
            return f"experiment attribute {key!r} {value_problem}"
    pose = attrs.get("pose_rad")
    if pose is not None and (np.ndim(pose) != 1 or len(pose) != 7 or not np.all(np.isfinite(np.asarray(pose, float)))):
        return "experiment attribute 'pose_rad' must be the 7 joint positions [rad]"
    robot = attrs.get("robot_model")
    if robot is not None and not isinstance(robot, str):
        return "experiment attribute 'robot_model' must be a string"
    return None


#: The experiment attribute naming the robot a run was recorded on (a fleet's key, with the joint).
ROBOT_NAME_ATTR = "robot_name"
_ROBOT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def set_robot_name(dataset: Dataset, name: str | None) -> None:
    """Name the robot ``dataset`` was recorded on (None: leave it unnamed).

    A name is 1-64 letters, digits, ``.``, ``_`` or ``-`` starting with a letter or digit (it becomes part
    of file names and table rows).

    Examples
    --------
    >>> ds = Dataset(signals={"t": np.arange(3) * 1e-3, "q_m": np.zeros(3), "tau_j": np.zeros(3)},
    ...              experiment="free", source="import", joint=2, sample_rate_hz=1000.0)
    >>> set_robot_name(ds, "cell-3.left")
    >>> robot_name(ds)
    'cell-3.left'
    """
    if name is None:
        return
    if not isinstance(name, str) or not _ROBOT_NAME.fullmatch(name):
        raise DatasetError(f"robot name {name!r}: expected 1-64 letters, digits, '.', '_' or '-', starting with a "
                           "letter or digit")
    dataset.experiment_attrs[ROBOT_NAME_ATTR] = name


def robot_name(dataset: Dataset) -> str | None:
    """The name of the robot the run was recorded on, or None where the dataset does not say."""
    name = dataset.experiment_attrs.get(ROBOT_NAME_ATTR)
    return None if name is None else str(name)


def dataset_pose(dataset: Dataset) -> tuple[str | None, tuple[float, ...] | None]:
    """The robot model (``iiwa14``, ``iiwa7``) and the 7 joint positions [rad] the run was recorded at (the
    other joints' medians; the moving joint's own entry is its median too), each None where the dataset does
    not say (experiment attributes ``robot_model`` and ``pose_rad``)."""
    attrs = dataset.experiment_attrs
    pose = attrs.get("pose_rad")
    robot = attrs.get("robot_model")
    return (str(robot) if robot is not None else None,
            None if pose is None else tuple(float(x) for x in np.asarray(pose, float)))


def validate_dataset(dataset: Dataset, where: str) -> None:
    """Check a dataset against format version 1.

    Used both before writing and after reading, so a file written by
    :func:`write_dataset` always reads back.

    Parameters
    ----------
    dataset : Dataset
        The dataset to check.
    where : str
        Prefix of the error message, normally the file path.

    Raises
    ------
    DatasetError
        With a one-line message ``"<where>: <problem>"``.
    """
    problem = _metadata_problem(
        dataset.experiment, dataset.source, dataset.joint, dataset.sample_rate_hz
    )
    if problem is None and not isinstance(dataset.created_utc, str):
        problem = f"created_utc {dataset.created_utc!r} is not a string"
    if problem is None:
        try:
            datetime.fromisoformat(dataset.created_utc)
        except ValueError:
            problem = f"created_utc {dataset.created_utc!r} is not an ISO 8601 time"
    if problem is None and not isinstance(dataset.signals, Mapping):
        problem = "signals must be a dict of name to array"
    if problem is None:
        problem = _signal_names_problem(list(dataset.signals))
    if problem is None:
        problem = _signal_values_problem(dataset.signals)
    if problem is None:
        problem = _experiment_attrs_problem(dataset.experiment_attrs)
    if problem is None and dataset.truth is not None:
        problem = _truth_problem(dataset.truth)
    if problem is not None:
        raise DatasetError(f"{where}: {problem}")


# --------------------------------------------------------------------------
# writing


def _write_attr_value(attrs: h5py.AttributeManager, key: str, value: Any) -> None:
    if isinstance(value, (list, tuple)):
        arr = np.asarray(value)
        # An empty list has no element type; store it as an empty float array.
        value = arr if arr.size else np.zeros(0, dtype=np.float64)
    attrs[key] = value


def _write_tree(group: h5py.Group, tree: Mapping[str, Any]) -> None:
    """Store a nested dict: dicts become groups, everything else attrs."""
    for key, value in tree.items():
        if isinstance(value, Mapping):
            _write_tree(group.create_group(key, track_order=True), value)
        else:
            _write_attr_value(group.attrs, key, value)


def _write_root_attrs(h5: h5py.File, dataset: Dataset) -> None:
    """Write the root attributes of a dataset (its signals are not looked at)."""
    h5.attrs["format"] = FORMAT_NAME
    h5.attrs["format_version"] = np.int64(FORMAT_VERSION)
    h5.attrs["experiment"] = dataset.experiment
    h5.attrs["source"] = dataset.source
    h5.attrs["joint"] = np.int64(dataset.joint)
    h5.attrs["sample_rate_hz"] = np.float64(dataset.sample_rate_hz)
    h5.attrs["created_utc"] = dataset.created_utc


def _write_contents(h5: h5py.File, dataset: Dataset) -> None:
    """Write a validated dataset into an open, empty HDF5 file."""
    _write_root_attrs(h5, dataset)
    signals = h5.create_group("signals")
    for name in SIGNAL_UNITS:  # canonical order, for readers that list in order
        if name in dataset.signals:
            dset = signals.create_dataset(
                name, data=np.asarray(dataset.signals[name], dtype=np.float64)
            )
            dset.attrs["unit"] = SIGNAL_UNITS[name]
    experiment = h5.create_group("experiment", track_order=True)
    for key, value in dataset.experiment_attrs.items():
        _write_attr_value(experiment.attrs, key, value)
    if dataset.truth is not None:
        _write_tree(h5.create_group("truth", track_order=True), dataset.truth)


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable; not every platform can open a directory."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_dataset(path: str | os.PathLike[str], dataset: Dataset) -> Path:
    """Validate and write a dataset atomically.

    The data go to a temporary file in the target directory, which is synced
    and then renamed over ``path``; a failed or interrupted write therefore
    never leaves a partial file under ``path`` nor damages a file already
    there. Signals are stored as float64.

    Parameters
    ----------
    path : str or os.PathLike
        Target file (conventionally ``*.h5``). Missing parent directories
        are created.
    dataset : Dataset
        Dataset to write; its ``truth`` is stored under ``/truth`` if given.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    DatasetError
        If the dataset is invalid or the file cannot be written.
    """
    path = Path(path)
    validate_dataset(dataset, str(path))
    tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Mode "x" refuses to clobber and gives the normal umask permissions.
        with h5py.File(tmp, "x") as h5:
            _write_contents(h5, dataset)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as err:  # also KeyboardInterrupt: never leave the temp file
        try:
            tmp.unlink()
        except OSError:
            pass
        if isinstance(err, OSError):
            reason = err.strerror or _first_line(err)
            raise DatasetError(f"{path}: cannot write: {reason}") from err
        raise
    _fsync_dir(path.parent)
    return path


# --------------------------------------------------------------------------
# reading


def _first_line(err: BaseException) -> str:
    """The first line of an exception message, so errors stay one line."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def _plain(value: Any) -> Any:
    """Turn an h5py attribute value into a plain Python/numpy value."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in ("S", "O", "U"):
            return [_plain(v) for v in value.tolist()]
        return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def _open_swmr(path: Path) -> h5py.File | None:
    """Open a file as a SWMR reader, or return None if that fails too."""
    try:
        return h5py.File(path, "r", swmr=True)
    except OSError:
        return None


def _open(path: Path) -> h5py.File:
    """Open a dataset file read-only, with one-line errors."""
    if not path.exists():
        raise DatasetError(f"{path}: file not found")
    if path.is_dir():
        raise DatasetError(f"{path}: is a directory, not a dataset file")
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as err:
        raise DatasetError(f"{path}: cannot read: {err.strerror or err}") from err
    if not is_hdf5:
        raise DatasetError(f"{path}: not an HDF5 file")
    try:
        h5 = h5py.File(path, "r")
    except OSError as err:
        # A SWMR writer that is running or was killed leaves the file's
        # consistency flags set, which only a SWMR reader may ignore.
        h5 = _open_swmr(path)
        if h5 is None:
            raise DatasetError(f"{path}: cannot open as HDF5 ({_first_line(err)})") from err
    try:
        fmt = _plain(h5.attrs.get("format"))
        if fmt is None:
            raise DatasetError(f"{path}: missing root attribute 'format' (not an iiwa-ident dataset)")
        if fmt != FORMAT_NAME:
            raise DatasetError(f"{path}: format is {fmt!r} (expected {FORMAT_NAME!r})")
        version = _plain(h5.attrs.get("format_version"))
        if version is None:
            raise DatasetError(f"{path}: missing root attribute 'format_version'")
        if not _is_int(version) or version != FORMAT_VERSION:
            raise DatasetError(
                f"{path}: unsupported format_version {version!r} (this version reads {FORMAT_VERSION})"
            )
    except BaseException:
        h5.close()
        raise
    return h5


def _read_group_attrs(group: h5py.Group) -> dict[str, Any]:
    return {key: _plain(value) for key, value in group.attrs.items()}


def _rows_flushed(h5: h5py.File) -> int | None:
    """Rows a logger marked as on disk, or None if the file does not say."""
    node = h5.get(_ROWS_FLUSHED)
    if not isinstance(node, h5py.Dataset) or node.shape != (1,) or node.dtype.kind not in ("i", "u"):
        return None
    return int(node[0])


#: The file that marks a folder as a log of column files (one run), not a folder of datasets.
COLUMN_LOG_MARK = "joint_position_measured.txt"


def dataset_files(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """The dataset files ``paths`` name: each file as given, each folder's ``.h5`` files (sorted by name).

    Raises
    ------
    DatasetError
        A folder that holds no dataset file (one that holds column logs says how to import them).

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> for name in ("b.h5", "a.h5", "notes.txt"):
    ...     _ = (d / name).write_text("")
    >>> [p.name for p in dataset_files([d])]
    ['a.h5', 'b.h5']
    """
    out: list[Path] = []
    for given in map(Path, paths):
        if not given.is_dir():
            out.append(given)
            continue
        found = sorted(p for p in given.iterdir() if p.suffix == ".h5" and p.is_file())
        if not found:
            if (given / COLUMN_LOG_MARK).is_file():
                raise DatasetError(f"{given}: a folder of column logs, not of dataset files: import it first "
                                   "('iiwa-ident import --columns ...', or 'iiwa-ident pipeline --logs' for a "
                                   "whole joint)")
            raise DatasetError(f"{given}: a folder with no dataset file (.h5) in it")
        out += found
    return out


def _signal_nodes(group: h5py.Group, where: str) -> dict[str, h5py.Dataset]:
    """The arrays of ``/signals`` in canonical order, each checked for its unit, shape and type."""
    nodes: dict[str, h5py.Dataset] = {}
    for name in SIGNAL_UNITS:
        if name not in group:
            continue
        node = group[name]
        if not isinstance(node, h5py.Dataset):
            raise DatasetError(f"{where}: '/signals/{name}' is a group, expected an array")
        expected = SIGNAL_UNITS[name]
        unit = _plain(node.attrs.get("unit"))
        if unit is None:
            raise DatasetError(f"{where}: signal {name!r} has no unit (expected {expected!r})")
        if unit != expected:
            raise DatasetError(f"{where}: signal {name!r} has unit {unit!r} (expected {expected!r})")
        if node.ndim != 1:
            raise DatasetError(f"{where}: signal {name!r} is not 1-D (shape {node.shape})")
        if node.dtype.kind not in ("f", "i", "u"):
            raise DatasetError(f"{where}: signal {name!r} has non-numeric dtype {node.dtype}")
        nodes[name] = node
    return nodes


def read_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read and validate a dataset file.

    Ground truth, if the file has any, is not read (``truth`` stays None);
    use :func:`read_truth` in evaluation code.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.h5`` file.

    A recording still in progress, or left by a killed logger (root
    attribute ``in_progress`` set), is opened as a SWMR reader and cut to the
    rows every signal has on disk; ``experiment_attrs["incomplete"]`` is then
    True. See the module docstring.

    Returns
    -------
    Dataset
        Signals as float64 arrays in canonical order, ``path`` set.

    Raises
    ------
    DatasetError
        One-line message starting with the path, naming the problem.
    """
    path = Path(path)
    where = str(path)
    try:
        with _open(path) as h5:
            attrs = h5.attrs
            root: dict[str, Any] = {}
            for key in ("experiment", "source", "joint", "sample_rate_hz", "created_utc"):
                if key not in attrs:
                    raise DatasetError(f"{where}: missing root attribute {key!r}")
                root[key] = _plain(attrs[key])
            problem = _metadata_problem(
                root["experiment"], root["source"], root["joint"], root["sample_rate_hz"]
            )
            if problem:
                raise DatasetError(f"{where}: {problem}")
            marker = _plain(attrs.get(_IN_PROGRESS_ATTR, 0))
            in_progress = isinstance(marker, numbers.Real) and marker != 0
            # Read before the signals are opened: a live writer only raises it
            # after the rows it counts are on disk, and signals only grow.
            flushed = _rows_flushed(h5) if in_progress else None

            group = h5.get("signals")
            if not isinstance(group, h5py.Group):
                raise DatasetError(f"{where}: missing group '/signals'")
            names = list(group.keys())
            problem = _signal_names_problem(names)
            if problem:
                raise DatasetError(f"{where}: {problem}")
            nodes = _signal_nodes(group, where)
            signals: dict[str, np.ndarray] = {}
            if in_progress:
                lengths = [node.shape[0] for node in nodes.values()]
                n_rows = max(0, min(lengths + ([] if flushed is None else [flushed])))
                if n_rows < _MIN_SAMPLES:
                    raise DatasetError(
                        f"{where}: dataset is empty: {n_rows} sample(s) flushed so far, need at "
                        f"least {_MIN_SAMPLES} (recording still in progress or interrupted)"
                    )
                for name, node in nodes.items():
                    signals[name] = np.asarray(node[:n_rows], dtype=np.float64)
            else:
                for name, node in nodes.items():
                    signals[name] = np.asarray(node[()], dtype=np.float64)

            exp_group = h5.get("experiment")
            experiment_attrs = _read_group_attrs(exp_group) if isinstance(exp_group, h5py.Group) else {}
            if in_progress:
                experiment_attrs["incomplete"] = True
    except OSError as err:  # damaged internals surface only when a node is read
        raise DatasetError(f"{where}: cannot read ({_first_line(err)})") from err

    dataset = Dataset(
        signals=signals,
        experiment=root["experiment"],
        source=root["source"],
        joint=int(root["joint"]),
        sample_rate_hz=float(root["sample_rate_hz"]),
        experiment_attrs=experiment_attrs,
        created_utc=root["created_utc"],
        path=path,
    )
    validate_dataset(dataset, where)
    return dataset


def _read_tree(group: h5py.Group) -> dict[str, Any]:
    """Inverse of :func:`_write_tree`: arrays come back as lists."""
    tree: dict[str, Any] = {}
    for key, value in group.attrs.items():
        value = _plain(value)
        tree[key] = value.tolist() if isinstance(value, np.ndarray) else value
    for key, node in group.items():
        if isinstance(node, h5py.Group):
            tree[key] = _read_tree(node)
    return tree


def read_truth(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read the ground truth stored in a simulated dataset.

    Only for evaluation code and tests: identification must never see it.

    Parameters
    ----------
    path : str or os.PathLike
        A dataset file written with ``Dataset.truth`` set.

    Returns
    -------
    dict
        The nested truth dict; numeric arrays come back as lists.

    Raises
    ------
    DatasetError
        If the file is not a dataset or has no ``/truth`` group.
    """
    path = Path(path)
    try:
        with _open(path) as h5:
            group = h5.get("truth")
            if not isinstance(group, h5py.Group):
                raise DatasetError(f"{path}: no ground truth in this file (no '/truth' group)")
            return _read_tree(group)
    except OSError as err:
        raise DatasetError(f"{path}: cannot read ({_first_line(err)})") from err


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Return the SHA-256 hex digest of a file's bytes.

    Raises
    ------
    DatasetError
        If the file cannot be read.
    """
    path = Path(path)
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
    except FileNotFoundError as err:
        raise DatasetError(f"{path}: file not found") from err
    except OSError as err:
        raise DatasetError(f"{path}: cannot read: {err.strerror or err}") from err
    return digest.hexdigest()
