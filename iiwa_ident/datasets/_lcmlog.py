"""Import Drake's iiwa driver logs: LCM event logs of ``lcmt_iiwa_status``.

Drake's ``kuka_iiwa_driver`` publishes the arm's state on ``IIWA_STATUS`` as
``drake.lcmt_iiwa_status``::

    int64_t utime;                                  time [us]
    int32_t num_joints;
    double joint_position_measured[num_joints];     q_m [rad]
    double joint_velocity_estimated[num_joints];    dq_m [rad/s] (the driver's low-passed estimate)
    double joint_position_commanded[num_joints];    q_cmd [rad]
    double joint_position_ipo[num_joints];          (the interpolator's; not kept)
    double joint_torque_measured[num_joints];       tau_j [Nm]
    double joint_torque_commanded[num_joints];      tau_c [Nm] (kept where it is not zero throughout)
    double joint_torque_external[num_joints];       tau_ext_fri [Nm]

An LCM message is its type's 8-byte fingerprint followed by its fields,
big-endian. The fingerprint is computed here from the type definition as the
LCM type specification defines it (a hash over the member names, primitive
types and array dimensions), so a message of another type on the channel is
refused rather than misread. The event log is read with the ``lcm`` package's
own reader.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from iiwa_ident.datasets._format import Dataset
from iiwa_ident.datasets._import import MIN_MESSAGE_RATE_HZ, _assemble, _check_metadata, _check_robot
from iiwa_ident.errors import DatasetError

__all__ = ["IIWA_STATUS_CHANNEL", "IIWA_STATUS_FIELDS", "lcm_fingerprint", "decode_iiwa_status", "import_lcm"]

#: The channel Drake's driver publishes the status on.
IIWA_STATUS_CHANNEL = "IIWA_STATUS"
#: The joint arrays of ``lcmt_iiwa_status``, in message order.
IIWA_STATUS_FIELDS = ("joint_position_measured", "joint_velocity_estimated", "joint_position_commanded",
                      "joint_position_ipo", "joint_torque_measured", "joint_torque_commanded",
                      "joint_torque_external")
#: Dataset signal of each array (None: not kept).
_SIGNAL_OF = {"joint_position_measured": "q_m", "joint_velocity_estimated": "dq_m",
              "joint_position_commanded": "q_cmd", "joint_position_ipo": None, "joint_torque_measured": "tau_j",
              "joint_torque_commanded": "tau_c", "joint_torque_external": "tau_ext_fri"}
_MASK = (1 << 64) - 1


def _hash_update(v: int, c: int) -> int:
    """One step of LCM's type hash on a signed 64-bit value and a (signed) char."""
    c = c - 256 if c > 127 else c
    v = (((v << 8) ^ (v >> 55)) + c) & _MASK
    return v - (1 << 64) if v >> 63 else v


def _hash_string(v: int, s: str) -> int:
    v = _hash_update(v, len(s))
    for byte in s.encode():
        v = _hash_update(v, byte)
    return v


def lcm_fingerprint(members: Iterable[tuple[str, str, tuple[str, ...]]]) -> int:
    """The 64-bit fingerprint of an LCM struct of primitive members, as it leads every encoded message.

    Parameters
    ----------
    members : iterable of (name, type, dimensions)
        In declaration order; ``dimensions`` names the member that sizes each variable array dimension
        (``()`` for a scalar).

    Examples
    --------
    >>> hex(lcm_fingerprint([("utime", "int64_t", ())]))
    '0x4d0d41c1f105b12f'
    """
    v = 0x12345678
    for name, type_name, dims in members:
        v = _hash_string(v, name)
        v = _hash_string(v, type_name)
        v = _hash_update(v, len(dims))
        for size in dims:
            v = _hash_update(v, 1)  # a variable-length dimension (LCM_VAR)
            v = _hash_string(v, size)
    v &= _MASK
    return ((v << 1) & _MASK) + (v >> 63)  # no nested types: the base hash rotated by one bit


_STATUS_FINGERPRINT = lcm_fingerprint([("utime", "int64_t", ()), ("num_joints", "int32_t", ())]
                                      + [(name, "double", ("num_joints",)) for name in IIWA_STATUS_FIELDS])


def decode_iiwa_status(data: bytes) -> tuple[int, dict[str, np.ndarray]]:
    """Decode one encoded ``lcmt_iiwa_status``: its ``utime`` [us] and the joint arrays by field name.

    Raises
    ------
    ValueError
        For a message of another type (fingerprint) or of the wrong length.
    """
    if len(data) < 20:
        raise ValueError(f"{len(data)} bytes, too short for lcmt_iiwa_status")
    fingerprint, utime, n = struct.unpack_from(">QqI", data, 0)
    if fingerprint != _STATUS_FINGERPRINT:
        raise ValueError(f"fingerprint {fingerprint:#018x} is not lcmt_iiwa_status's ({_STATUS_FINGERPRINT:#018x})")
    if n > 64 or len(data) != 20 + 8 * n * len(IIWA_STATUS_FIELDS):
        raise ValueError(f"{len(data)} bytes do not hold {n} joints of lcmt_iiwa_status")
    values = np.frombuffer(data, dtype=">f8", offset=20).astype(np.float64).reshape(len(IIWA_STATUS_FIELDS), n)
    return utime, dict(zip(IIWA_STATUS_FIELDS, values))


class _Events(NamedTuple):
    """The status messages of an LCM log: their times [us], their fields, and every channel seen."""

    times: list[int]
    rows: list[dict[str, np.ndarray]]
    seen: set[str]


def _events(path: Path, channel: str) -> _Events:
    import lcm  # here: only this importer needs the LCM library

    times, rows, seen = [], [], set()
    try:
        log = lcm.EventLog(str(path), "r")
    except (OSError, ValueError) as err:
        raise DatasetError(f"{path}: cannot open as an LCM log ({err})") from None
    end = 0  # where the last whole event ends [byte]
    try:
        k = -1
        while (event := log.read_next_event()) is not None:
            k += 1
            end = log.tell()
            seen.add(event.channel)
            if event.channel != channel:
                continue
            try:
                utime, arrays = decode_iiwa_status(event.data)
            except ValueError as err:
                raise DatasetError(f"{path}: event {k} on {channel}: {err}") from None
            times.append(utime)
            rows.append(arrays)
        # The reader stops quietly at a cut event; a log that does not end where its last event ends was cut.
        size = log.size()
    except (OSError, ValueError) as err:  # the reader's word for a broken event
        raise DatasetError(f"{path}: not a readable LCM log ({err})") from None
    finally:
        log.close()
    if end < size:
        raise DatasetError(f"{path}: the log ends inside an event (byte {end} of {size} read; a cut or corrupted "
                           f"recording)" if seen else f"{path}: not an LCM event log (no event in {size} bytes)")
    return _Events(times, rows, seen)


def import_lcm(path: Path, joint: int, experiment: str, channel: str = IIWA_STATUS_CHANNEL,
               robot_model: str | None = None) -> Dataset:
    """Import the ``lcmt_iiwa_status`` messages of an LCM event log (Drake's iiwa driver).

    Parameters
    ----------
    path : pathlib.Path
        The log (``lcm-logger``'s event log).
    joint : int
        Joint the experiment moved, 1..7 (its entry of the joint arrays).
    experiment : str
        Kind of excitation, e.g. ``"constant_velocity"``.
    channel : str
        The status channel (default ``IIWA_STATUS``).
    robot_model : str, optional
        The arm (``iiwa14``, ``iiwa7``), kept in the dataset.

    Returns
    -------
    Dataset
        Time from ``utime``; ``q_m``, ``tau_j``, ``dq_m``, ``q_cmd``, ``tau_ext_fri`` and ``tau_c`` (where
        the driver commanded a torque); the pose and each joint's travel from the measured positions.
        Publish rates down to :data:`~iiwa_ident.datasets.MIN_MESSAGE_RATE_HZ` are accepted.

    Raises
    ------
    DatasetError
        One line naming the file: not an LCM log, truncated or corrupted, no message on the channel (the
        channels found are named), a message of another type, a joint beyond the messages' joints.
    """
    path = Path(path)
    _check_metadata(joint, experiment)
    _check_robot(robot_model)
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    times, rows, seen = _events(path, channel)
    if not rows:
        found = ", ".join(sorted(seen)) or "none"
        raise DatasetError(f"{path}: no message on channel {channel!r} (channels in the log: {found})")
    n_joints = {len(r["joint_position_measured"]) for r in rows}
    if len(n_joints) > 1 or joint > min(n_joints):
        raise DatasetError(f"{path}: the messages carry {sorted(n_joints)} joints; joint {joint} is not among them")
    stacked = {name: np.array([r[name] for r in rows]) for name in IIWA_STATUS_FIELDS}
    raw = {"t": (np.asarray(times, np.int64) - times[0]) * 1e-6}
    for name, signal in _SIGNAL_OF.items():
        if signal is not None:
            raw[signal] = stacked[name][:, joint - 1]
    if not np.any(raw["tau_c"]):
        del raw["tau_c"]  # position control: no torque was commanded
    origin = {name: f"{name} ({path}, channel {channel})" for name in raw}
    positions = stacked["joint_position_measured"] if min(n_joints) == 7 else None
    return _assemble(raw, origin, joint, experiment, None, {}, str(path), robot_model=robot_model,
                     positions=positions, min_rate_hz=MIN_MESSAGE_RATE_HZ)
