"""Import ROS 2 bags of lbr_fri_ros2_stack: ``LBRState`` on ``/lbr/state`` or ``JointState`` on ``/lbr/joint_states``.

The bag is read with ``rosbags`` (pure Python, no ROS installation; sqlite3
and MCAP storage). The stack's state message, ``lbr_fri_idl/msg/LBRState``
(``lbr_fri_msgs/msg/LBRState`` in its older releases), is registered from its
definition, :data:`LBR_STATE_MSG`; ``sensor_msgs/msg/JointState`` is ROS's own.

Signals
-------
``LBRState``: ``measured_joint_position`` -> q_m, ``measured_torque`` -> tau_j,
``commanded_joint_position`` -> q_cmd, ``external_torque`` -> tau_ext_fri,
``commanded_torque`` -> tau_c where the client commanded torque
(``client_command_mode`` TORQUE); time from the robot's own stamp
(``time_stamp_sec``, ``time_stamp_nano_sec``), the bag's receive time where
the stamp is zero. With ``split_runs`` a run is each stretch in which the
session is ``COMMANDING_ACTIVE``.

``JointState``: ``position`` -> q_m, ``velocity`` -> dq_m, ``effort`` -> tau_j;
time from the header's stamp, the bag's receive time where it is zero.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from iiwa_ident.datasets._format import Dataset
from iiwa_ident.datasets._import import MIN_MESSAGE_RATE_HZ, _assemble, _check_metadata, _check_robot
from iiwa_ident.errors import DatasetError

__all__ = ["LBR_STATE_MSG", "LBR_STATE_TYPES", "JOINT_STATE_TYPE", "ros_typestore", "import_rosbag"]

#: The definition of the stack's state message (field names and types, in order).
LBR_STATE_MSG = """float64 sample_time
int8 session_state
int8 connection_quality
int8 safety_state
int8 operation_mode
int8 drive_state
int8 client_command_mode
int8 overlay_type
int8 control_mode
uint32 time_stamp_sec
uint32 time_stamp_nano_sec
float64[7] measured_joint_position
float64[7] commanded_joint_position
float64[7] measured_torque
float64[7] commanded_torque
float64[7] external_torque
float64[7] ipo_joint_position
float64 tracking_performance
"""
#: The state message's type in the stack's current and older releases.
LBR_STATE_TYPES = ("lbr_fri_idl/msg/LBRState", "lbr_fri_msgs/msg/LBRState")
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
#: FRI's session state COMMANDING_ACTIVE and client command mode TORQUE.
_COMMANDING_ACTIVE = 4
_TORQUE_MODE = 3


def ros_typestore():
    """A rosbags type store with ROS 2's messages and the stack's ``LBRState`` (both names)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    for name in LBR_STATE_TYPES:
        store.register(get_types_from_msg(LBR_STATE_MSG, name))
    return store


def _connection(reader: Any, topic: str | None, path: Path):
    """The connection to read: the topic asked for, else the LBRState topic, else the JointState one."""
    conns = list(reader.connections)
    listed = ", ".join(f"{c.topic} ({c.msgtype})" for c in conns) or "none"
    if topic is not None:
        chosen = [c for c in conns if c.topic == topic]
        if not chosen:
            raise DatasetError(f"{path}: no topic {topic!r} in the bag (topics: {listed})")
        if chosen[0].msgtype not in (*LBR_STATE_TYPES, JOINT_STATE_TYPE):
            raise DatasetError(f"{path}: topic {topic} carries {chosen[0].msgtype}, not LBRState or JointState")
        return chosen
    for types in (LBR_STATE_TYPES, (JOINT_STATE_TYPE,)):
        chosen = [c for c in conns if c.msgtype in types]
        if chosen:
            topics = sorted({c.topic for c in chosen})
            if len(topics) > 1:
                raise DatasetError(f"{path}: several topics carry {chosen[0].msgtype} ({', '.join(topics)}): "
                                   "choose one with --topic")
            return chosen
    raise DatasetError(f"{path}: no LBRState or JointState topic in the bag (topics: {listed})")


def _stamp_ns(sec: int, nanosec: int, received_ns: int) -> int:
    """A message's time [ns]: its stamp, or the bag's receive time where the stamp is zero (integers: epoch
    seconds in a float lose the microseconds)."""
    return sec * 1_000_000_000 + nanosec if (sec or nanosec) else received_ns


def _read(path: Path, topic: str | None) -> tuple[str, list[tuple[int, Any]]]:
    from rosbags.rosbag2 import Reader

    store = ros_typestore()
    try:
        with Reader(path) as reader:
            conns = _connection(reader, topic, path)
            msgtype = conns[0].msgtype
            out = [(ns, store.deserialize_cdr(raw, msgtype)) for _, ns, raw in reader.messages(connections=conns)]
    except DatasetError:
        raise
    except Exception as err:  # noqa: BLE001  (rosbags, sqlite3, the MCAP and CDR readers each raise their own)
        text = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise DatasetError(f"{path}: not a readable ROS 2 bag ({text})") from None
    if not out:
        raise DatasetError(f"{path}: no message on {conns[0].topic}")
    return msgtype, out


class _LbrState(NamedTuple):
    """The signals of LBRState messages, the 7 measured positions and the session states."""

    raw: dict[str, np.ndarray]
    positions: np.ndarray
    session_states: np.ndarray


def _lbr_state(msgs: list[tuple[int, Any]], joint: int) -> _LbrState:
    """The signals of LBRState messages, the 7 measured positions, and the session states."""
    j = joint - 1

    def col(field: str) -> np.ndarray:
        return np.array([np.asarray(getattr(m, field), float) for _, m in msgs])

    positions = col("measured_joint_position")
    raw = {"t": np.array([_stamp_ns(m.time_stamp_sec, m.time_stamp_nano_sec, ns) for ns, m in msgs], np.int64),
           "q_m": positions[:, j], "tau_j": col("measured_torque")[:, j],
           "q_cmd": col("commanded_joint_position")[:, j], "tau_ext_fri": col("external_torque")[:, j]}
    modes = np.array([m.client_command_mode for _, m in msgs])
    tau_c = col("commanded_torque")[:, j]
    if np.any(modes == _TORQUE_MODE) and np.any(tau_c):
        raw["tau_c"] = tau_c
    return _LbrState(raw, positions, np.array([m.session_state for _, m in msgs]))


def _joint_state(msgs: list[tuple[int, Any]], joint: int, path: Path) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    j = joint - 1
    sizes = {len(m.position) for _, m in msgs}
    if min(sizes) <= j:
        raise DatasetError(f"{path}: the JointState messages carry {min(sizes)} joints; joint {joint} is not among them")
    if any(len(m.effort) <= j for _, m in msgs):
        raise DatasetError(f"{path}: the JointState messages carry no effort for joint {joint}: no joint torque")
    positions = np.array([np.asarray(m.position, float) for _, m in msgs]) if sizes == {7} else None
    raw = {"t": np.array([_stamp_ns(m.header.stamp.sec, m.header.stamp.nanosec, ns) for ns, m in msgs], np.int64),
           "q_m": np.array([m.position[j] for _, m in msgs], float),
           "tau_j": np.array([m.effort[j] for _, m in msgs], float)}
    if all(len(m.velocity) > j for _, m in msgs):
        raw["dq_m"] = np.array([m.velocity[j] for _, m in msgs], float)
    return raw, positions


def _active_runs(states: np.ndarray) -> list[tuple[int, int]]:
    """``[start, end)`` of each stretch of COMMANDING_ACTIVE."""
    active = np.concatenate([[False], states == _COMMANDING_ACTIVE, [False]])
    edges = np.flatnonzero(np.diff(active.astype(int)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def import_rosbag(path: Path, joint: int, experiment: str, topic: str | None = None, split_runs: bool = False,
                  robot_model: str | None = None) -> Dataset | list[Dataset]:
    """Import the ``LBRState`` or ``JointState`` messages of a ROS 2 bag (lbr_fri_ros2_stack).

    Parameters
    ----------
    path : pathlib.Path
        The bag: its folder (with ``metadata.yaml``), sqlite3 or MCAP storage.
    joint : int
        Joint the experiment moved, 1..7 (its entry of the joint arrays).
    experiment : str
        Kind of excitation, e.g. ``"constant_velocity"``.
    topic : str, optional
        The topic to read (default: the one carrying LBRState, else JointState).
    split_runs : bool
        LBRState only: one dataset per stretch in which the session was COMMANDING_ACTIVE (the messages
        outside them are left out).
    robot_model : str, optional
        The arm (``iiwa14``, ``iiwa7``), kept in the dataset.

    Returns
    -------
    Dataset, or list of Dataset with ``split_runs``
        Signals as in the module docstring; the pose and each joint's travel from the 7 measured positions.
        Publish rates down to :data:`~iiwa_ident.datasets.MIN_MESSAGE_RATE_HZ` are accepted.

    Raises
    ------
    DatasetError
        One line naming the bag: not a readable bag (missing, corrupted, cut), no state topic (the topics
        are named), a joint beyond the messages', no torque, no COMMANDING_ACTIVE stretch to split at.
    """
    path = Path(path)
    _check_metadata(joint, experiment)
    _check_robot(robot_model)
    if not path.exists():
        raise DatasetError(f"{path}: file not found")
    msgtype, msgs = _read(path, topic)
    where = f"{path} ({msgtype})"
    if msgtype == JOINT_STATE_TYPE:
        if split_runs:
            raise DatasetError(f"{path}: JointState messages carry no session state to split runs at")
        raw, positions = _joint_state(msgs, joint, path)
        states = None
    else:
        raw, positions, states = _lbr_state(msgs, joint)
    origin = {name: f"{name} ({where})" for name in raw}
    if not split_runs:
        return _assemble({**raw, "t": (raw["t"] - raw["t"][0]) * 1e-9}, origin, joint, experiment, None, {}, where,
                         robot_model=robot_model, positions=positions, min_rate_hz=MIN_MESSAGE_RATE_HZ)
    if states is None or positions is None:  # LBRState messages carry both
        raise DatasetError(f"{path}: no session states to split runs at")
    runs = _active_runs(states)
    if not runs:
        raise DatasetError(f"{path}: the session is never COMMANDING_ACTIVE: no run to split out")
    # Each run's time from its first message, as a recorder started for it would have it.
    return [_assemble({**{k: v[a:b] for k, v in raw.items()}, "t": (raw["t"][a:b] - raw["t"][a]) * 1e-9},
                      {k: f"{text}, run {i} (messages {a}-{b - 1})" for k, text in origin.items()}, joint, experiment,
                      None, {}, f"{where}, run {i}", robot_model=robot_model, positions=positions[a:b],
                      min_rate_hz=MIN_MESSAGE_RATE_HZ)
            for i, (a, b) in enumerate(runs, start=1)]
