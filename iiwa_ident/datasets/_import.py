"""Convert logs recorded by other tools into :class:`Dataset` objects.

Two layouts are supported:

* column files (:func:`import_columns`): one whitespace-separated text file
  per signal, one row per sample and one column per joint, as exported by
  many iiwa drivers;
* a CSV with a header row (:func:`import_csv`), one column per signal.

The result has ``source="import"`` and is validated like any dataset, so it
can be written with :func:`iiwa_ident.datasets.write_dataset` directly.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from iiwa_ident.datasets._format import (
    SIGNAL_UNITS,
    Dataset,
    _metadata_problem,
    validate_dataset,
)
from iiwa_ident.errors import DatasetError
from iiwa_ident.robot import ROBOT_MODELS

__all__ = ["MIN_RATE_HZ", "MAX_RATE_HZ", "MIN_MESSAGE_RATE_HZ", "import_columns", "import_csv", "moving_joint_problem"]

#: FRI runs at 200 Hz to 1 kHz; other rates mean a wrong time column or
#: a wrong unit, so they are refused. A 2 % tolerance absorbs clock jitter
#: in the median sample period.
MIN_RATE_HZ = 200.0 * 0.98
MAX_RATE_HZ = 1000.0 * 1.02
#: Message logs (ROS 2 bags, LCM) are often published below the robot's cycle (100-200 Hz); they are taken down
#: to this rate, with a warning of what they cannot give (:func:`~iiwa_ident.datasets.low_rate_problem`).
MIN_MESSAGE_RATE_HZ = 50.0 * 0.98

# Signals an import must provide; t can be generated from a rate.
_REQUIRED_IMPORTED = ("q_m", "tau_j")


def _check_names(names: list[str], what: str) -> None:
    """Refuse unknown signal names and missing required ones."""
    for name in names:
        if name not in SIGNAL_UNITS:
            raise DatasetError(
                f"unknown signal {name!r} in {what} (known: {', '.join(SIGNAL_UNITS)})"
            )
    for name in _REQUIRED_IMPORTED:
        if name not in names:
            raise DatasetError(f"missing required signal {name!r} in {what}")


def _check_metadata(joint: int, experiment: str) -> None:
    # source and rate are checked later; a placeholder rate isolates joint/experiment.
    problem = _metadata_problem(experiment, "import", joint, 1.0)
    if problem:
        raise DatasetError(problem)


def _check_robot(robot_model: str | None) -> None:
    if robot_model is not None and robot_model not in ROBOT_MODELS:
        raise DatasetError(f"unknown robot model {robot_model!r} (known: {', '.join(ROBOT_MODELS)})")


def _check_scale(scale: Mapping[str, float] | None, names: list[str]) -> dict[str, float]:
    scale = dict(scale or {})
    for name, factor in scale.items():
        if name not in names:
            raise DatasetError(
                f"scale given for signal {name!r}, which is not imported (imported: {', '.join(names)})"
            )
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not math.isfinite(factor) or factor == 0:
            raise DatasetError(f"scale factor for {name!r} must be a finite non-zero number, got {factor!r}")
    return scale


def _read_text(path: Path, kind: str) -> str:
    """A text file's content; unreadable files raise a one-line DatasetError naming them."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            return fh.read()
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a directory, not {kind}") from None
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not a text file") from None
    except OSError as err:
        raise DatasetError(f"{path}: cannot read: {err.strerror or err}") from err


def _read_column_file(path: Path, column: int | None, every: bool = False) -> np.ndarray:
    """Read one column of a whitespace-separated numeric text file (``every``: all its columns, rows x columns).

    Blank lines and lines starting with ``#`` are skipped. A file with a single
    column is used whatever ``column`` says (a time file, for example).
    """
    text = _read_text(path, "a column file")
    rows: list[list[float]] = []

    values: list[float] = []
    n_cols: int | None = None
    use: int = 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if n_cols is None:
            n_cols = len(tokens)
            if n_cols > 1 and column is not None:
                use = column
            if n_cols > 1 and not 0 <= use < n_cols:
                raise DatasetError(
                    f"{path}: column {use} out of range (file has {n_cols} columns, 0..{n_cols - 1})"
                )
        elif len(tokens) != n_cols:
            raise DatasetError(f"{path}, line {lineno}: expected {n_cols} columns, found {len(tokens)}")
        # Every field is parsed, not just the used one: garbage anywhere means a corrupt log.
        if every:
            rows.append([])
        for col, token in enumerate(tokens):
            try:
                value = float(token)
            except ValueError:
                raise DatasetError(
                    f"{path}, line {lineno}, column {col}: cannot parse {token!r} as a number"
                ) from None
            if col == use:
                values.append(value)
            if every:
                rows[-1].append(value)
        if not math.isfinite(values[-1]):
            raise DatasetError(f"{path}, line {lineno}: non-finite value {values[-1]}")
    if not values:
        raise DatasetError(f"{path}: no data rows")
    return np.asarray(rows if every else values, dtype=np.float64)


#: Attribute of a run split from a log: the stretches of the log left out (one sample each).
SPLIT_LEFT_OUT_ATTR = "split_left_out"


def _assemble_log(raw: dict[str, np.ndarray], origin: dict[str, str], joint: int, experiment: str,
                  sample_rate_hz: float | None, scale: dict[str, float], where: str, split_runs: bool,
                  robot_model: str | None = None, positions: np.ndarray | None = None) -> Dataset | list[Dataset]:
    """A log's dataset (:func:`_assemble`), or with ``split_runs`` one per run: a run ends where the time
    goes back."""
    if not split_runs:
        return _assemble(raw, origin, joint, experiment, sample_rate_hz, scale, where, robot_model=robot_model,
                         positions=positions)
    runs = []
    for part in _runs(raw, origin, where, positions):
        runs.append(_assemble(part.raw, part.origin, joint, experiment, sample_rate_hz, scale, part.where,
                              robot_model=robot_model, positions=part.positions))
        if part.left_out:
            runs[-1].experiment_attrs[SPLIT_LEFT_OUT_ATTR] = part.left_out
    return runs


def _assemble(
    raw: dict[str, np.ndarray],
    origin: dict[str, str],
    joint: int,
    experiment: str,
    sample_rate_hz: float | None,
    scale: dict[str, float],
    where: str,
    robot_model: str | None = None,
    positions: np.ndarray | None = None,
    min_rate_hz: float = MIN_RATE_HZ,
) -> Dataset:
    """Scale, add or check time, check the rate (``min_rate_hz`` .. :data:`MAX_RATE_HZ`) and build the dataset.

    ``raw`` maps signal names (time under ``"t"``) to arrays and ``origin``
    maps them to a description of where they came from, for messages.
    ``positions``: all 7 joints' positions (samples x 7) [rad], kept as the run's pose (the medians,
    ``pose_rad``) and each joint's travel (``joint_travel_rad``).
    """
    lengths = {name: arr.shape[0] for name, arr in raw.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{origin[name]} has {n} rows" for name, n in lengths.items())
        raise DatasetError(f"files of unequal length: {listed}")
    n = next(iter(lengths.values()))
    if n < 2:
        raise DatasetError(f"{where}: only {n} sample, need at least 2")

    signals = {name: arr * scale.get(name, 1.0) for name, arr in raw.items()}
    signals, rate = _time_and_rate(signals, origin, n, sample_rate_hz, where, min_rate_hz)

    # Canonical order makes printed summaries and files predictable.
    ordered = {name: signals[name] for name in SIGNAL_UNITS if name in signals}
    attrs: dict = {}
    if robot_model is not None:
        attrs["robot_model"] = robot_model
    if positions is not None:
        attrs["pose_rad"] = np.median(positions, axis=0)
        attrs["joint_travel_rad"] = np.ptp(positions, axis=0)
    dataset = Dataset(
        signals=ordered,
        experiment=experiment,
        source="import",
        joint=joint,
        sample_rate_hz=rate,
        experiment_attrs=attrs,
    )
    validate_dataset(dataset, where)
    return dataset


@dataclass
class _Run:
    """One run of a log that holds several: its rows of every signal, and where they came from."""

    raw: dict[str, np.ndarray]
    origin: dict[str, str]
    where: str
    positions: np.ndarray | None
    left_out: str = ""


def _runs(raw: dict[str, np.ndarray], origin: dict[str, str], where: str, positions: np.ndarray | None
          ) -> list[_Run]:
    """The runs of a log: a run ends where the time goes back."""
    if "t" not in raw:
        raise DatasetError("splitting into runs needs a time signal (where the time restarts)")
    starts = [0, *(np.flatnonzero(np.diff(raw["t"]) < 0) + 1).tolist(), len(raw["t"])]
    # A stretch of one sample (a stray row where the time restarts) is no run: left out, and said in
    # every run of the log (SPLIT_LEFT_OUT_ATTR).
    short = [f"run {k} (sample {a})" for k, (a, b) in enumerate(zip(starts[:-1], starts[1:]), start=1)
             if b - a < 2]
    if len(short) == len(starts) - 1:
        raise DatasetError(f"{where}: no run of 2 samples or more between the times it goes back")
    runs = []
    for k, (a, b) in enumerate(zip(starts[:-1], starts[1:]), start=1):
        if b - a < 2:
            continue
        # Samples are numbered from 0 in the whole log, so a message points at the rows of the file.
        runs.append(_Run({name: arr[a:b] for name, arr in raw.items()},
                         {name: f"{text}, run {k} (samples {a}-{b - 1})" for name, text in origin.items()},
                         f"{where}, run {k}", None if positions is None else positions[a:b],
                         f"one sample, not a run: {', '.join(short)}" if short else ""))
    return runs


def _time_and_rate(signals: dict[str, np.ndarray], origin: dict[str, str], n: int, sample_rate_hz: float | None,
                   where: str, min_rate_hz: float) -> tuple[dict[str, np.ndarray], float]:
    """The signals with a time signal (checked, or made from the rate) and the sample rate [Hz] (given, or
    estimated from the time), within ``min_rate_hz`` .. :data:`MAX_RATE_HZ`."""
    if sample_rate_hz is not None and (
        isinstance(sample_rate_hz, bool)
        or not isinstance(sample_rate_hz, (int, float))
        or not math.isfinite(sample_rate_hz)
        or sample_rate_hz <= 0
    ):
        raise DatasetError(f"sample rate {sample_rate_hz!r} is not a finite number > 0")

    given_rate = sample_rate_hz is not None
    if "t" in signals:
        t = signals["t"]
        dt = np.diff(t)
        back = np.flatnonzero(dt < 0)
        if back.size:
            i = int(back[0]) + 1
            raise DatasetError(
                f"{origin['t']}: time goes back at sample {i} ({float(t[i])!r} after {float(t[i - 1])!r}): "
                f"the log holds several runs; import them with --split-runs (split_runs=True)"
            )
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise DatasetError(
                f"{origin['t']}: time is not strictly increasing at sample {i} "
                f"({float(t[i])!r} after {float(t[i - 1])!r})"
            )
        if sample_rate_hz is None:
            # The median ignores the odd dropped or late packet.
            sample_rate_hz = float(1.0 / np.median(dt))
    elif sample_rate_hz is None:
        raise DatasetError("no time signal given: give a time file/column or the sample rate")
    else:
        signals = {"t": np.arange(n, dtype=np.float64) / float(sample_rate_hz), **signals}

    rate = float(sample_rate_hz)
    if not min_rate_hz <= rate <= MAX_RATE_HZ:
        hint = "" if given_rate else " (estimated from the time signal; check its unit or give the rate)"
        raise DatasetError(f"{where}: sample rate {rate:.6g} Hz is outside {min_rate_hz / 0.98:.0f} Hz..1 kHz "
                           f"(±2%){hint}")
    return signals, rate


def import_columns(
    files: Mapping[str, Path],
    joint: int,
    experiment: str,
    sample_rate_hz: float | None = None,
    column: int | None = None,
    scale: Mapping[str, float] | None = None,
    time_signal: str = "t",
    split_runs: bool = False,
    robot_model: str | None = None,
) -> Dataset | list[Dataset]:
    """Import whitespace-separated column files, one file per signal.

    Parameters
    ----------
    files : mapping of str to pathlib.Path
        Signal name (see :data:`~iiwa_ident.datasets.SIGNAL_UNITS`) to file.
        The file under ``time_signal`` holds sample times [s]. Each file has
        one row per sample and either a single column or one column per joint.
        Values must already be in the signal's unit (rad, Nm, rad/s, s) up to
        the factors in ``scale``.
    joint : int
        Joint the experiment moved, 1..7.
    experiment : str
        Kind of excitation, e.g. ``"constant_velocity"``.
    sample_rate_hz : float or None, optional
        Sample rate [Hz]. Required without a time file; with one, it
        defaults to 1 / median sample period.
    column : int or None, optional
        0-based column to read from multi-column files; defaults to
        ``joint - 1``.
    scale : mapping of str to float, optional
        Factor applied to a signal after reading, e.g. ``{"tau_j": -1.0}``
        for a log with flipped torque sign or ``{"t": 1e-3}`` for a time
        file in milliseconds.
    time_signal : str, optional
        Key of ``files`` that holds the time stamps (stored as ``t``).
    split_runs : bool, optional
        The log holds several runs, each starting where the time goes back
        (a recorder restarted without a new file): return one dataset per
        run. Without it such a log is refused, naming the sample.
    robot_model : str, optional
        The arm (``iiwa14``, ``iiwa7``), kept in the dataset (``robot_model``).

    Returns
    -------
    Dataset, or list of Dataset with ``split_runs``
        With ``source="import"``, not yet written. When the ``q_m`` file has a column per joint (7), the
        experiment attributes keep the pose (``pose_rad``: each joint's median [rad]) and each joint's travel
        (``joint_travel_rad``); see :func:`moving_joint_problem`.

    Raises
    ------
    DatasetError
        One-line message for a missing file, an unparsable number (file and
        line), a column out of range, files of unequal length, an unknown or
        missing signal, or a sample rate outside 200 Hz..1 kHz (±2 %).
    """
    files = {name: Path(p) for name, p in files.items()}
    if not files:
        raise DatasetError("no column files given")
    if time_signal != "t" and time_signal in files:
        if "t" in files:
            raise DatasetError(f"both 't' and time_signal {time_signal!r} given as time files")
        # Rename so the rest of the code only knows 't'.
        files = {("t" if name == time_signal else name): p for name, p in files.items()}
    names = list(files)
    _check_names(names, "the column files")
    _check_metadata(joint, experiment)
    factors = _check_scale(scale, names)
    if column is not None and (isinstance(column, bool) or not isinstance(column, int) or column < 0):
        raise DatasetError(f"column must be an integer >= 0, got {column!r}")

    _check_robot(robot_model)
    use = joint - 1 if column is None else column
    raw, positions = {}, None
    for name, path in files.items():
        if name == "q_m":
            every = _read_column_file(path, use, every=True)
            if every.ndim == 2 and every.shape[1] == 7:
                positions = every
            raw[name] = every[:, use if every.shape[1] > 1 else 0]
        else:
            raw[name] = _read_column_file(path, use)
    origin = {name: f"{name} ({path})" for name, path in files.items()}
    where = str(files.get("q_m", next(iter(files.values()))).parent)
    return _assemble_log(raw, origin, joint, experiment, sample_rate_hz, factors, where, split_runs,
                         robot_model=robot_model, positions=positions)


#: A joint whose travel in a run is below this share of another joint's did not move in it.
_MOVED_SHARE = 0.5
#: ... when that other joint travelled at least this far [rad].
_MOVED_MIN_RAD = 0.02


def moving_joint_problem(dataset: Dataset) -> str | None:
    """A warning when the dataset's joint barely moved while another did (``joint_travel_rad`` from the
    import), naming the joint that moved; None when the joint moved or the dataset does not say."""
    travel = dataset.experiment_attrs.get("joint_travel_rad")
    if travel is None:
        return None
    travel = np.asarray(travel, float)
    best = int(np.argmax(travel))
    own = float(travel[dataset.joint - 1])
    if best != dataset.joint - 1 and travel[best] >= _MOVED_MIN_RAD and own < _MOVED_SHARE * travel[best]:
        return (f"joint {dataset.joint} moved {own:.3g} rad in this run, joint {best + 1} {travel[best]:.3g} rad: "
                f"is it a run of joint {best + 1} (--joint {best + 1})?")
    return None


def _sniff_delimiter(header: str) -> str:
    """Pick ``;`` or ``,`` by which splits the header into more fields."""
    return ";" if header.count(";") > header.count(",") else ","


def _parse_csv_number(token: str, delimiter: str) -> float:
    token = token.strip()
    try:
        return float(token)
    except ValueError:
        # Semicolon CSVs usually come from locales that write 1,5 for 1.5.
        if delimiter == ";" and token.count(",") == 1 and "." not in token:
            return float(token.replace(",", "."))
        raise


def import_csv(
    path: Path,
    mapping: Mapping[str, str],
    joint: int,
    experiment: str,
    sample_rate_hz: float | None = None,
    scale: Mapping[str, float] | None = None,
    split_runs: bool = False,
    robot_model: str | None = None,
) -> Dataset | list[Dataset]:
    """Import a CSV file with a header row (``robot_model`` kept as in :func:`import_columns`).

    Parameters
    ----------
    path : pathlib.Path
        The CSV; comma or semicolon delimited (detected from the header).
        With semicolons, a decimal comma (``1,5``) is accepted.
    mapping : mapping of str to str
        Signal name to column name in the header, e.g.
        ``{"t": "time", "q_m": "pos2", "tau_j": "trq2"}``. A ``t`` column
        holds times [s]; without one, ``sample_rate_hz`` is required.
    joint : int
        Joint the experiment moved, 1..7.
    experiment : str
        Kind of excitation, e.g. ``"chirp"``.
    sample_rate_hz : float or None, optional
        Sample rate [Hz]; defaults to 1 / median sample period of ``t``.
    scale : mapping of str to float, optional
        Factor applied to a signal after reading (e.g. ``{"tau_j": -1.0}``).
    split_runs : bool, optional
        One dataset per run, a run starting where the time goes back (see
        :func:`import_columns`).

    Returns
    -------
    Dataset, or list of Dataset with ``split_runs``
        With ``source="import"``, not yet written.

    Raises
    ------
    DatasetError
        One-line message for a missing file or column, an unparsable number
        (file and line), an unknown or missing signal, or a bad sample rate.
    """
    path = Path(path)
    mapping = dict(mapping)
    names = list(mapping)
    _check_names(names, f"the mapping for {path}")
    _check_metadata(joint, experiment)
    factors = _check_scale(scale, names)
    lines = _read_text(path, "a CSV file").splitlines()

    numbered = [(i, line) for i, line in enumerate(lines, start=1) if line.strip()]
    if not numbered:
        raise DatasetError(f"{path}: empty file (expected a header row)")
    delimiter = _sniff_delimiter(numbered[0][1])
    rows = csv.reader((line for _, line in numbered), delimiter=delimiter)
    header = [h.strip() for h in next(rows)]
    index: dict[str, int] = {}
    for name, col_name in mapping.items():
        if col_name not in header:
            raise DatasetError(
                f"{path}: no column {col_name!r} (for {name}) in the header; columns: {', '.join(header)}"
            )
        index[name] = header.index(col_name)

    values: dict[str, list[float]] = {name: [] for name in mapping}
    for (lineno, _), row in zip(numbered[1:], rows):
        for name, col in index.items():
            if col >= len(row):
                raise DatasetError(
                    f"{path}, line {lineno}: row has {len(row)} fields, no column {mapping[name]!r}"
                )
            try:
                value = _parse_csv_number(row[col], delimiter)
            except ValueError:
                raise DatasetError(
                    f"{path}, line {lineno}, column {mapping[name]!r}: cannot parse {row[col]!r} as a number"
                ) from None
            if not math.isfinite(value):
                raise DatasetError(f"{path}, line {lineno}, column {mapping[name]!r}: non-finite value {value}")
            values[name].append(value)
    if not values[names[0]]:
        raise DatasetError(f"{path}: no data rows after the header")
    raw = {name: np.asarray(v, dtype=np.float64) for name, v in values.items()}
    origin = {name: f"column {mapping[name]!r}" for name in mapping}
    _check_robot(robot_model)
    return _assemble_log(raw, origin, joint, experiment, sample_rate_hz, factors, str(path), split_runs,
                         robot_model=robot_model)
