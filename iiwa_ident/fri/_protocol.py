"""The KUKA Fast Robot Interface (FRI) UDP messages, on the protobuf library.

The robot controller and the FRI client exchange one protobuf message per
UDP datagram of at most :data:`MAX_DATAGRAM_BYTES` bytes: the robot sends a
:class:`MonitoringMessage` every cycle and the client answers with a
:class:`CommandMessage`. The schema is ``messages.proto`` in this package,
wire-compatible with KUKA's ``FRIMonitoringMessage`` and
``FRICommandMessage``; the message classes are the ones ``protoc`` generated
from it (:mod:`iiwa_ident.fri.messages_pb2`), built with keyword arguments
the protobuf way::

    CommandMessage(header=MessageHeader(message_identifier=COMMAND_MESSAGE_ID,
                                        sequence_counter=5, reflected_sequence_counter=4),
                   command_data=CommandData(joint_position=JointValues(value=q)))

This module adds what protobuf does not check, in two levels:

*Form*, checked by every decoder and encoder: the datagram size, the
required fields (protobuf's parser does not enforce proto2 ``required``;
:meth:`IsInitialized` does), the header's message identifier and at most
:data:`MAX_WRENCH_ELEMENTS` wrench elements.

*Content* (:func:`message_problem`): every joint array holds exactly
:data:`N_JOINTS` values, as do the drive states, and every number is finite.
The decoders check it unless ``check=False`` (the robot emulator, which
reacts to a bad command the way the controller does, not by ignoring the
datagram); the encoders always.

Enum fields keep numbers the schema does not list (the schema's enums are
open): such a field reads as a plain ``int``; known numbers compare equal
to the members of :class:`SessionState` and the other enums here.

Units: joint positions in rad, joint torques in Nm, the Cartesian wrench in
N and Nm, periods in ms.
"""

from __future__ import annotations

import math
import re
from enum import IntEnum

from google.protobuf.message import DecodeError

from iiwa_ident.fri import messages_pb2 as _pb

__all__ = [
    "MONITORING_MESSAGE_ID",
    "COMMAND_MESSAGE_ID",
    "MAX_DATAGRAM_BYTES",
    "MAX_WRENCH_ELEMENTS",
    "N_JOINTS",
    "FriDecodeError",
    "SessionState",
    "ConnectionQuality",
    "SafetyState",
    "OperationMode",
    "DriveState",
    "ControlMode",
    "ClientCommandMode",
    "OverlayType",
    "JointValues",
    "CartesianVector",
    "TimeStamp",
    "MessageHeader",
    "ConnectionInfo",
    "RobotInfo",
    "MonitorData",
    "IpoData",
    "MonitoringMessage",
    "CommandData",
    "CommandMessage",
    "message_problem",
    "encode_monitoring",
    "decode_monitoring",
    "encode_command",
    "decode_command",
]

MONITORING_MESSAGE_ID = 0x245142
"""Header message identifier of a monitoring message (robot to client)."""

COMMAND_MESSAGE_ID = 0x34001
"""Header message identifier of a command message (client to robot)."""

MAX_DATAGRAM_BYTES = 1500
"""Largest FRI datagram in bytes, for both directions."""

MAX_WRENCH_ELEMENTS = 6
"""Largest number of elements of the Cartesian wrench (force, then torque)."""

N_JOINTS = 7
"""Joints of an LBR iiwa: the length of every joint array."""

JointValues = _pb.JointValues
CartesianVector = _pb.CartesianVector
TimeStamp = _pb.TimeStamp
MessageHeader = _pb.MessageHeader
ConnectionInfo = _pb.ConnectionInfo
RobotInfo = _pb.RobotInfo
MonitorData = _pb.MonitorData
IpoData = _pb.IpoData
MonitoringMessage = _pb.MonitoringMessage
CommandData = _pb.CommandData
CommandMessage = _pb.CommandMessage


class FriDecodeError(ValueError):
    """A datagram is not a valid FRI message; ``str(err)`` says what is wrong in one line."""


class SessionState(IntEnum):
    """State of the FRI session (``ConnectionInfo.session_state``)."""

    IDLE = 0
    MONITORING_WAIT = 1
    MONITORING_READY = 2
    COMMANDING_WAIT = 3
    COMMANDING_ACTIVE = 4


class ConnectionQuality(IntEnum):
    """Quality of the connection as the robot controller judges it."""

    POOR = 0
    FAIR = 1
    GOOD = 2
    EXCELLENT = 3


class SafetyState(IntEnum):
    """Safety state of the robot."""

    NORMAL_OPERATION = 0
    SAFETY_STOP_LEVEL_0 = 1
    SAFETY_STOP_LEVEL_1 = 2
    SAFETY_STOP_LEVEL_2 = 3


class OperationMode(IntEnum):
    """Operation mode selected on the smartPAD."""

    T1 = 0
    T2 = 1
    AUT = 2


class DriveState(IntEnum):
    """State of one joint drive."""

    OFF = 0
    TRANSITIONING = 1
    ACTIVE = 2


class ControlMode(IntEnum):
    """Controller running on the robot."""

    POSITION = 0
    CARTESIAN_IMPEDANCE = 1
    JOINT_IMPEDANCE = 2
    NO_CONTROL = 3


class ClientCommandMode(IntEnum):
    """What the client is expected to command."""

    NO_COMMAND = 0
    POSITION = 1
    WRENCH = 2
    TORQUE = 3


class OverlayType(IntEnum):
    """Kind of FRI overlay the robot program started."""

    NO_OVERLAY = 0
    JOINT = 1
    CARTESIAN = 2


def _schema_members(name: str) -> dict[str, int]:
    """The schema's enum ``name`` as {member: number}, the members without the schema's ``NAME_`` prefix."""
    prefix = re.sub(r"(?<!^)(?=[A-Z])", "_", name).upper() + "_"
    return {v.name.removeprefix(prefix): v.number for v in _pb.DESCRIPTOR.enum_types_by_name[name].values}


def _check_enums_match_schema() -> None:
    # The enums are written out so a type checker sees their members; the schema stays the authority.
    enums = (SessionState, ConnectionQuality, SafetyState, OperationMode, DriveState, ControlMode,
             ClientCommandMode, OverlayType)
    for enum in enums:
        if {m.name: m.value for m in enum} != _schema_members(enum.__name__):
            raise ImportError(f"{__name__}: enum {enum.__name__} disagrees with messages.proto")
    names = {e.__name__ for e in enums}
    if names != set(_pb.DESCRIPTOR.enum_types_by_name):
        raise ImportError(f"{__name__}: the schema's enums are not those written here")


_check_enums_match_schema()

_MONITOR_ARRAYS = ("measured_joint_position", "measured_torque", "commanded_joint_position", "commanded_torque",
                   "external_torque")
_COMMAND_ARRAYS = ("joint_position", "joint_torque")


# --------------------------------------------------------------------------- checks


def _arrays_problem(arrays: list[tuple[str, list[float]]]) -> str | None:
    """The first joint array without exactly N_JOINTS finite values, in one line, or None."""
    total = 0.0
    for name, values in arrays:
        if len(values) != N_JOINTS:
            return f"{name} has {len(values)} values, expected {N_JOINTS}"
        total += sum(values)
    if math.isfinite(total):  # the common case, at C speed; a sum of finite values may still overflow
        return None
    for name, values in arrays:
        if not all(map(math.isfinite, values)):
            return f"{name} has a non-finite value"
    return None


def _present(sub, names: tuple[str, ...], prefix: str = "") -> list[tuple[str, list[float]]]:
    return [(prefix + name, getattr(sub, name).value[:]) for name in names if sub.HasField(name)]


def message_problem(msg: MonitoringMessage | CommandMessage) -> str | None:
    """What is wrong with the content of a message, in one line, or None.

    Every joint array present must hold exactly :data:`N_JOINTS` finite
    values, the drive states (if any) one per joint, the wrench's elements
    finite (its size is form, checked by the decoders and encoders), the tracking performance a
    finite number, and the joint count (if given) :data:`N_JOINTS`.
    """
    if isinstance(msg, CommandMessage):
        if not msg.HasField("command_data"):
            return None
        cd = msg.command_data
        # The wrench's size is part of the form (_form_problem), checked before this.
        if cd.HasField("cartesian_wrench_feed_forward") and not all(
                map(math.isfinite, cd.cartesian_wrench_feed_forward.element)):
            return "cartesian_wrench_feed_forward has a non-finite value"
        return _arrays_problem(_present(cd, _COMMAND_ARRAYS))
    arrays = _present(msg.monitor_data, _MONITOR_ARRAYS) if msg.HasField("monitor_data") else []
    if msg.HasField("ipo_data"):
        ipo = msg.ipo_data
        arrays += _present(ipo, ("joint_position",), "ipo_data.")
        if ipo.HasField("tracking_performance") and not math.isfinite(ipo.tracking_performance):
            return "tracking_performance is not finite"
    if msg.HasField("robot_info"):
        info = msg.robot_info
        if info.HasField("number_of_joints") and info.number_of_joints != N_JOINTS:
            return f"number_of_joints is {info.number_of_joints}, expected {N_JOINTS}"
        drives = len(info.drive_state)
        if drives and drives != N_JOINTS:
            return f"drive_state has {drives} values, expected {N_JOINTS}"
    return _arrays_problem(arrays)


def _form_problem(msg: MonitoringMessage | CommandMessage, ident: int, kind: str) -> str | None:
    """Required fields, the message identifier and the wrench's size: what the parser does not check."""
    if not msg.IsInitialized():
        return "required field missing: " + ", ".join(msg.FindInitializationErrors())
    if msg.header.message_identifier != ident:
        return (f"message identifier {msg.header.message_identifier:#x} is not a {kind} message"
                f" (expected {ident:#x})")
    if kind == "command":
        n = len(msg.command_data.cartesian_wrench_feed_forward.element)
        if n > MAX_WRENCH_ELEMENTS:
            return f"cartesian_wrench_feed_forward has {n} elements, at most {MAX_WRENCH_ELEMENTS}"
    return None


# --------------------------------------------------------------------------- decoding and encoding


def _decode(data: bytes, cls, ident: int, kind: str, check: bool):
    if not isinstance(data, bytes):
        try:
            data = memoryview(data).tobytes()  # any buffer (bytearray, memoryview, numpy), never an int's zeros
        except TypeError:
            raise FriDecodeError(f"a datagram is bytes, not {type(data).__name__}") from None
    if len(data) > MAX_DATAGRAM_BYTES:
        raise FriDecodeError(f"datagram of {len(data)} bytes, more than {MAX_DATAGRAM_BYTES}")
    msg = cls()
    try:
        msg.ParseFromString(data)
    except DecodeError as err:
        raise FriDecodeError(f"not a protobuf {kind} message ({err})") from None
    problem = _form_problem(msg, ident, kind) or (message_problem(msg) if check else None)
    if problem:
        raise FriDecodeError(problem)
    return msg


def _encode(msg, cls, ident: int, kind: str) -> bytes:
    if not isinstance(msg, cls):
        raise ValueError(f"a {kind} message is a {cls.__name__}, not {type(msg).__name__}")
    problem = _form_problem(msg, ident, kind) or message_problem(msg)
    if problem:
        raise ValueError(f"{kind} message: {problem}")
    data = msg.SerializeToString()  # cannot fail: IsInitialized was checked
    if len(data) > MAX_DATAGRAM_BYTES:
        raise ValueError(f"{kind} message of {len(data)} bytes, more than {MAX_DATAGRAM_BYTES}")
    return data


def decode_monitoring(data: bytes, *, check: bool = True) -> MonitoringMessage:
    """Decode a monitoring datagram received from the robot.

    Parameters
    ----------
    data : bytes-like
        One UDP datagram, at most :data:`MAX_DATAGRAM_BYTES` bytes.
    check : bool
        Also check the content (:func:`message_problem`).

    Returns
    -------
    MonitoringMessage
        Joint positions in rad, torques in Nm.

    Raises
    ------
    FriDecodeError
        If ``data`` is not a valid monitoring message; no other exception
        for any input.
    """
    return _decode(data, MonitoringMessage, MONITORING_MESSAGE_ID, "monitoring", check)


def decode_command(data: bytes, *, check: bool = True) -> CommandMessage:
    """Decode a command datagram sent by an FRI client; as :func:`decode_monitoring`."""
    return _decode(data, CommandMessage, COMMAND_MESSAGE_ID, "command", check)


def encode_monitoring(msg: MonitoringMessage) -> bytes:
    """One datagram of a monitoring message; :class:`ValueError` if its form or content is invalid."""
    return _encode(msg, MonitoringMessage, MONITORING_MESSAGE_ID, "monitoring")


def encode_command(msg: CommandMessage) -> bytes:
    """One datagram of a command message; :class:`ValueError` if its form or content is invalid."""
    return _encode(msg, CommandMessage, COMMAND_MESSAGE_ID, "command")
