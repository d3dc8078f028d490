"""Encoder and decoder of the KUKA Fast Robot Interface (FRI) UDP messages.

The robot controller and the FRI client exchange one protobuf (proto2)
message per UDP datagram of at most :data:`MAX_DATAGRAM_BYTES` bytes: the
robot sends a ``FRIMonitoringMessage`` (:class:`MonitoringMessage`) every
cycle and the client answers with a ``FRICommandMessage``
(:class:`CommandMessage`). This module reads and writes the protobuf wire
format directly with :mod:`struct`, without the ``protobuf`` package.

Wire format in brief
--------------------
Every field is a *tag* ``(field_number << 3) | wire_type`` written as a
varint, followed by its value: wire type 0 is a varint (integers, enums),
1 is 8 little-endian bytes (``double``), 2 is a varint length followed by
that many bytes (sub-messages, packed repeated scalars), 5 is 4 bytes.

Encoder
-------
Fields are written in field-number order. Repeated doubles (``JointValues``,
the wrench ``CartesianVector``) and the repeated drive states are written
unpacked, one tag per element, as KUKA's client SDK does. Values are
checked (uint32 / int32 ranges, at most 6 wrench elements, the datagram
size) and a violation raises :class:`ValueError`. The header's message
identifier is written as given; the caller sets it.

Decoder
-------
The decoders take untrusted datagrams: for any byte string they either
return a message or raise :class:`FriDecodeError` (a :class:`ValueError`),
in time and memory bounded by the datagram size. They follow proto2 parsing
rules:

* Unknown fields of a valid wire type (0, 1, 2, 5) are skipped. A known
  field number arriving with an unexpected wire type is treated the same
  way, as protobuf treats it as an unknown field. Group wire types (3, 4),
  the invalid wire types 6 and 7 and field number 0 are errors.
* Repeated doubles and repeated enums are accepted packed (wire type 2) and
  unpacked, also mixed within one message; the elements are concatenated.
* A non-repeated scalar field that occurs several times: the last one wins.
* A non-repeated sub-message that occurs several times is **merged**, as
  protobuf does: its scalar fields take the last value, its repeated fields
  (e.g. the values of a ``JointValues``) are concatenated. The raw
  ``endOfMessageData`` bytes of several occurrences are concatenated, which
  is the serialized form of their merge.
* Required fields (the header and its three counters, ``sessionState`` and
  ``quality`` of ``connectionInfo``, ``sec`` and ``nanosec`` of the
  timestamp) must be present.
* Integers are reduced to their declared width the way protobuf does:
  uint32 fields keep the low 32 bits of the varint, int32 and enum fields
  the low 32 bits read as two's complement. An enum number outside the
  known members is kept as a plain ``int``; known numbers are returned as
  members of the enum class.
* Doubles are returned as they are, including NaN and infinities.
* The message identifier in the header must be :data:`MONITORING_MESSAGE_ID`
  for :func:`decode_monitoring` and :data:`COMMAND_MESSAGE_ID` for
  :func:`decode_command`.

Units: joint positions in rad, joint torques in Nm, the Cartesian wrench in
N and Nm, periods in ms.
"""

from __future__ import annotations

import operator
import struct
from dataclasses import dataclass
from enum import IntEnum

__all__ = [
    "MONITORING_MESSAGE_ID",
    "COMMAND_MESSAGE_ID",
    "MAX_DATAGRAM_BYTES",
    "FriDecodeError",
    "SessionState",
    "ConnectionQuality",
    "SafetyState",
    "OperationMode",
    "DriveState",
    "ControlMode",
    "ClientCommandMode",
    "OverlayType",
    "MessageHeader",
    "ConnectionInfo",
    "RobotInfo",
    "MonitorData",
    "IpoData",
    "MonitoringMessage",
    "CommandData",
    "CommandMessage",
    "encode_monitoring",
    "decode_monitoring",
    "encode_command",
    "decode_command",
]

MONITORING_MESSAGE_ID = 0x245142
"""Header message identifier of a ``FRIMonitoringMessage`` (robot to client)."""

COMMAND_MESSAGE_ID = 0x34001
"""Header message identifier of a ``FRICommandMessage`` (client to robot)."""

MAX_DATAGRAM_BYTES = 1500
"""Largest FRI datagram in bytes, for both directions."""

MAX_WRENCH_ELEMENTS = 6

_U32_MAX = 0xFFFFFFFF
_U64_MASK = 0xFFFFFFFFFFFFFFFF
_I32_MIN = -0x80000000
_I32_MAX = 0x7FFFFFFF


class FriDecodeError(ValueError):
    """A datagram is not a valid FRI message; ``str(err)`` says what is wrong in one line."""


# --------------------------------------------------------------------------- enums


class SessionState(IntEnum):
    """State of the FRI session (``ConnectionInfo.sessionState``)."""

    IDLE = 0
    MONITORING_WAIT = 1
    MONITORING_READY = 2
    COMMANDING_WAIT = 3
    COMMANDING_ACTIVE = 4


class ConnectionQuality(IntEnum):
    """Quality of the FRI connection as judged by the robot controller."""

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


def _members(enum: type[IntEnum]) -> dict[int, IntEnum]:
    return {int(m): m for m in enum}


_SESSION_STATES = _members(SessionState)
_QUALITIES = _members(ConnectionQuality)
_SAFETY_STATES = _members(SafetyState)
_OPERATION_MODES = _members(OperationMode)
_DRIVE_STATES = _members(DriveState)
_CONTROL_MODES = _members(ControlMode)
_CLIENT_COMMAND_MODES = _members(ClientCommandMode)
_OVERLAY_TYPES = _members(OverlayType)


# --------------------------------------------------------------------------- messages


@dataclass(slots=True)
class MessageHeader:
    """Header of every FRI message.

    Attributes
    ----------
    message_identifier : int
        :data:`MONITORING_MESSAGE_ID` or :data:`COMMAND_MESSAGE_ID` (uint32).
    sequence_counter : int
        Counter of the sender, incremented every message (uint32).
    reflected_sequence_counter : int
        The last sequence counter received from the other side (uint32).
    """

    message_identifier: int
    sequence_counter: int
    reflected_sequence_counter: int


@dataclass(slots=True)
class ConnectionInfo:
    """State and quality of the FRI connection.

    Attributes
    ----------
    session_state : int
        A :class:`SessionState` (or the raw number of an unknown state).
    quality : int
        A :class:`ConnectionQuality` (or the raw number of an unknown quality).
    send_period_ms : int or None
        Period of the robot's monitoring messages [ms] (uint32).
    receive_multiplier : int or None
        The robot expects a command every ``receive_multiplier`` monitoring
        messages (uint32).
    """

    session_state: int
    quality: int
    send_period_ms: int | None = None
    receive_multiplier: int | None = None


@dataclass(slots=True)
class RobotInfo:
    """Static and slowly changing state of the robot.

    Attributes
    ----------
    number_of_joints : int or None
        Number of joints (int32).
    safety_state : int or None
        A :class:`SafetyState`.
    drive_state : tuple of int
        One :class:`DriveState` per joint.
    operation_mode : int or None
        An :class:`OperationMode`.
    control_mode : int or None
        A :class:`ControlMode`.

    Enum fields hold the raw number when it is not a known member.
    """

    number_of_joints: int | None = None
    safety_state: int | None = None
    drive_state: tuple[int, ...] = ()
    operation_mode: int | None = None
    control_mode: int | None = None


@dataclass(slots=True)
class MonitorData:
    """Measurements of one robot cycle.

    Attributes
    ----------
    measured_joint_position : tuple of float or None
        Measured joint positions [rad], one per joint.
    measured_torque : tuple of float or None
        Measured joint torques [Nm].
    commanded_joint_position : tuple of float or None
        Joint positions commanded to the robot's controller [rad].
    commanded_torque : tuple of float or None
        Joint torques commanded to the robot's controller [Nm].
    external_torque : tuple of float or None
        Estimated external joint torques [Nm].
    timestamp : tuple of (int, int) or None
        Time of the measurement as ``(sec, nanosec)`` [s, ns] (both uint32).
    """

    measured_joint_position: tuple[float, ...] | None = None
    measured_torque: tuple[float, ...] | None = None
    commanded_joint_position: tuple[float, ...] | None = None
    commanded_torque: tuple[float, ...] | None = None
    external_torque: tuple[float, ...] | None = None
    timestamp: tuple[int, int] | None = None


@dataclass(slots=True)
class IpoData:
    """Interpolator state of the robot program.

    Attributes
    ----------
    joint_position : tuple of float or None
        Joint positions of the robot's interpolator [rad].
    client_command_mode : int or None
        A :class:`ClientCommandMode`.
    overlay_type : int or None
        An :class:`OverlayType`.
    tracking_performance : float or None
        Tracking performance, 0 (none) to 1 (full).
    """

    joint_position: tuple[float, ...] | None = None
    client_command_mode: int | None = None
    overlay_type: int | None = None
    tracking_performance: float | None = None


@dataclass(slots=True)
class MonitoringMessage:
    """``FRIMonitoringMessage``: what the robot sends every cycle.

    Attributes
    ----------
    header : MessageHeader
        Identifier :data:`MONITORING_MESSAGE_ID` and the sequence counters.
    robot_info : RobotInfo or None
        Joint count, safety, drive, operation and control state.
    monitor_data : MonitorData or None
        Measured and commanded joint positions [rad] and torques [Nm].
    connection_info : ConnectionInfo or None
        Session state and connection quality.
    ipo_data : IpoData or None
        Interpolator state.
    requested_transformations : tuple of bytes
        Serialized bodies of the requested-transformation sub-messages,
        not interpreted.
    end_of_message_data : bytes or None
        Serialized body of the end-of-message sub-message, not interpreted.
    """

    header: MessageHeader
    robot_info: RobotInfo | None = None
    monitor_data: MonitorData | None = None
    connection_info: ConnectionInfo | None = None
    ipo_data: IpoData | None = None
    requested_transformations: tuple[bytes, ...] = ()
    end_of_message_data: bytes | None = None


@dataclass(slots=True)
class CommandData:
    """Commands of one client cycle.

    Attributes
    ----------
    joint_position : tuple of float or None
        Commanded joint positions [rad].
    joint_torque : tuple of float or None
        Commanded (additional) joint torques [Nm].
    cartesian_wrench_feed_forward : tuple of float or None
        Feed-forward Cartesian wrench, at most 6 elements (force [N],
        then torque [Nm]).
    """

    joint_position: tuple[float, ...] | None = None
    joint_torque: tuple[float, ...] | None = None
    cartesian_wrench_feed_forward: tuple[float, ...] | None = None


@dataclass(slots=True)
class CommandMessage:
    """``FRICommandMessage``: what the client answers.

    Attributes
    ----------
    header : MessageHeader
        Identifier :data:`COMMAND_MESSAGE_ID` and the sequence counters.
    command_data : CommandData or None
        The commands; absent while the session is only monitoring.
    end_of_message_data : bytes or None
        Serialized body of the end-of-message sub-message, not interpreted.
    """

    header: MessageHeader
    command_data: CommandData | None = None
    end_of_message_data: bytes | None = None


# --------------------------------------------------------------------------- struct tables

_DOUBLE = struct.Struct("<d")
_unpack_double = _DOUBLE.unpack_from
_pack_double = _DOUBLE.pack

# Every table is indexed by an element count that a datagram of at most
# MAX_DATAGRAM_BYTES bytes can hold, so they are built once, up front.
_MAX_UNPACKED = MAX_DATAGRAM_BYTES // 9
_MAX_PACKED = MAX_DATAGRAM_BYTES // 8
# n unpacked doubles: (tag byte, 8 bytes) n times; the tag bytes are skipped.
_UNPACKED = tuple(struct.Struct("<" + "xd" * n) for n in range(_MAX_UNPACKED + 1))
_PACKED = tuple(struct.Struct(f"<{n}d") for n in range(_MAX_PACKED + 1))
_TAG_RUNS = tuple(b"\x09" * n for n in range(_MAX_UNPACKED + 1))
_SMALL_VARINTS = tuple(bytes((i,)) for i in range(0x80))

# Tags, ``field_number << 3 | wire_type``, are written as literals in the
# parsers below (a literal costs less than a global lookup in CPython); the
# comment next to each names the field. Wire types: 0 varint, 1 fixed64,
# 2 length-delimited, 5 fixed32.


# --------------------------------------------------------------------------- decoding primitives


def _read_varint(buf: bytes, pos: int, end: int) -> tuple[int, int]:
    """The varint at ``pos`` (reduced to 64 bits) and the position after it."""
    if end - pos >= 5:
        # Unrolled for varints of up to 5 bytes (every uint32).
        b = buf[pos]
        if b < 0x80:
            return b, pos + 1
        r = b & 0x7F
        b = buf[pos + 1]
        if b < 0x80:
            return r | b << 7, pos + 2
        r |= (b & 0x7F) << 7
        b = buf[pos + 2]
        if b < 0x80:
            return r | b << 14, pos + 3
        r |= (b & 0x7F) << 14
        b = buf[pos + 3]
        if b < 0x80:
            return r | b << 21, pos + 4
        r |= (b & 0x7F) << 21
        b = buf[pos + 4]
        if b < 0x80:
            return r | b << 28, pos + 5
    return _read_long_varint(buf, pos, end)


def _read_long_varint(buf: bytes, pos: int, end: int) -> tuple[int, int]:
    """:func:`_read_varint` for varints near the end of a message or longer than 5 bytes."""
    start = pos
    result = 0
    shift = 0
    while pos < end:
        b = buf[pos]
        pos += 1
        if b < 0x80:
            return (result | (b << shift)) & _U64_MASK, pos
        result |= (b & 0x7F) << shift
        shift += 7
        if shift == 70:
            raise FriDecodeError(f"varint at byte {start} is longer than 10 bytes")
    raise FriDecodeError(f"truncated varint at byte {start}")


def _overrun(tag: int, tagpos: int, start: int, stop: int, end: int) -> FriDecodeError:
    """The error for a length-delimited value ``[start, stop)`` running past ``end``."""
    return FriDecodeError(
        f"field {tag >> 3} at byte {tagpos}: length {stop - start} runs past the end of its message"
        f" ({end - start} bytes left)"
    )


def _read_length(buf: bytes, pos: int, end: int, tag: int, tagpos: int) -> tuple[int, int]:
    """Start and end of the length-delimited value whose length varint is at ``pos``."""
    n, pos = _read_varint(buf, pos, end)
    if n > end - pos:
        raise _overrun(tag, tagpos, pos, pos + n, end)
    return pos, pos + n


def _skip_field(buf: bytes, pos: int, end: int, tag: int, tagpos: int) -> int:
    """Check and skip the value of a field that is not interpreted; return the position after it."""
    field = tag >> 3
    wire = tag & 7
    if field == 0:
        raise FriDecodeError(f"invalid field number 0 at byte {tagpos}")
    if tag > _U32_MAX:
        raise FriDecodeError(f"field number {field} at byte {tagpos} is out of range")
    if wire == 0:
        return _read_varint(buf, pos, end)[1]
    if wire == 2:
        return _read_length(buf, pos, end, tag, tagpos)[1]
    if wire == 1 or wire == 5:
        size = 8 if wire == 1 else 4
        if end - pos < size:
            raise FriDecodeError(
                f"field {field} at byte {tagpos}: {size}-byte value runs past the end of its message"
                f" ({end - pos} bytes left)"
            )
        return pos + size
    if wire == 3 or wire == 4:
        raise FriDecodeError(f"field {field} at byte {tagpos} has wire type {wire} (group), which FRI does not use")
    raise FriDecodeError(f"field {field} at byte {tagpos} has invalid wire type {wire}")


def _int32(v: int) -> int:
    """Low 32 bits of a varint read as two's complement (protobuf's int32 and enum)."""
    v &= _U32_MAX
    return v - 0x100000000 if v & 0x80000000 else v


def _enum(v: int | None, members: dict[int, IntEnum]) -> int | None:
    """The enum member of a varint, or the raw int32 if the number is unknown."""
    if v is None:
        return None
    if v > 0x7F:
        v = _int32(v)
    return members.get(v, v)


def _doubles(buf: bytes, start: int, end: int, name: str) -> tuple[float, ...]:
    """Values of a ``JointValues`` / ``CartesianVector`` body (field 1, repeated double)."""
    size = end - start
    if size % 9 == 0:
        # The layout KUKA writes, tag 0x09 and 8 bytes per value, read at once.
        n = size // 9
        if buf[start:end:9] == _TAG_RUNS[n]:
            return _UNPACKED[n].unpack_from(buf, start)
    values: list[float] = []
    pos = start
    while pos < end:
        tagpos = pos
        tag = buf[pos]
        if tag < 0x80:
            pos += 1
        else:
            tag, pos = _read_varint(buf, pos, end)
        if tag == 0x09:  # value, unpacked
            if end - pos < 8:
                raise FriDecodeError(
                    f"{name} value at byte {tagpos} runs past the end of its message ({end - pos} bytes left)"
                )
            values.append(_unpack_double(buf, pos)[0])
            pos += 8
        elif tag == 0x0A:  # value, packed
            a, pos = _read_length(buf, pos, end, tag, tagpos)
            k = pos - a
            if k % 8:
                raise FriDecodeError(f"packed {name} at byte {tagpos} has length {k}, not a multiple of 8")
            values.extend(_PACKED[k // 8].unpack_from(buf, a))
        else:
            pos = _skip_field(buf, pos, end, tag, tagpos)
    return tuple(values)


Spans = list[tuple[int, int]]


def _split(buf: bytes, end: int, wanted: frozenset[int]) -> dict[int, Spans]:
    """Body spans of the top-level length-delimited fields whose tag is in ``wanted``.

    Every other field is checked and skipped.
    """
    spans: dict[int, Spans] = {}
    pos = 0
    while pos < end:
        tagpos = pos
        tag = buf[pos]
        if tag < 0x80:
            pos += 1
        else:
            tag, pos = _read_varint(buf, pos, end)
        if tag in wanted:
            if pos < end and buf[pos] < 0x80:
                a = pos + 1
                pos = a + buf[pos]
                if pos > end:
                    raise _overrun(tag, tagpos, a, pos, end)
            else:
                a, pos = _read_length(buf, pos, end, tag, tagpos)
            lst = spans.get(tag)
            if lst is None:
                spans[tag] = [(a, pos)]
            else:
                lst.append((a, pos))
        else:
            pos = _skip_field(buf, pos, end, tag, tagpos)
    return spans


def _as_bytes(data: object) -> bytes:
    """The datagram as ``bytes``, checked for size."""
    if type(data) is bytes:
        buf = data
    else:
        try:
            view = memoryview(data)  # type: ignore[arg-type]
        except TypeError:
            raise FriDecodeError(f"a datagram must be bytes-like, not {type(data).__name__}") from None
        if view.nbytes > MAX_DATAGRAM_BYTES:
            raise FriDecodeError(f"datagram of {view.nbytes} bytes exceeds the {MAX_DATAGRAM_BYTES}-byte limit")
        buf = view.tobytes()
    n = len(buf)
    if n > MAX_DATAGRAM_BYTES:
        raise FriDecodeError(f"datagram of {n} bytes exceeds the {MAX_DATAGRAM_BYTES}-byte limit")
    if n == 0:
        raise FriDecodeError("empty datagram: field 1 (header) missing")
    return buf


# --------------------------------------------------------------------------- sub-message decoders
#
# Each takes the spans of every occurrence of its sub-message and parses them
# into one set of locals: that is protobuf's merge (scalars: last wins,
# repeated fields: concatenated).


def _decode_header(buf: bytes, spans: Spans | None, expected: int, kind: str) -> MessageHeader:
    if spans is None:
        raise FriDecodeError("field 1 (header) missing")
    ident = seq = reflected = None
    for pos, end in spans:
        while pos < end:
            tagpos = pos
            tag = buf[pos]
            if tag < 0x80:
                pos += 1
            else:
                tag, pos = _read_varint(buf, pos, end)
            if tag == 0x08:  # 1 messageIdentifier
                ident, pos = _read_varint(buf, pos, end)
            elif tag == 0x10:  # 2 sequenceCounter
                seq, pos = _read_varint(buf, pos, end)
            elif tag == 0x18:  # 3 reflectedSequenceCounter
                reflected, pos = _read_varint(buf, pos, end)
            else:
                pos = _skip_field(buf, pos, end, tag, tagpos)
    if ident is None:
        raise FriDecodeError("header field 1 (messageIdentifier) missing")
    if seq is None:
        raise FriDecodeError("header field 2 (sequenceCounter) missing")
    if reflected is None:
        raise FriDecodeError("header field 3 (reflectedSequenceCounter) missing")
    ident &= _U32_MAX
    if ident != expected:
        raise FriDecodeError(f"message identifier {ident:#x} is not a {kind} message (expected {expected:#x})")
    return MessageHeader(ident, seq & _U32_MAX, reflected & _U32_MAX)


def _decode_connection_info(buf: bytes, spans: Spans) -> ConnectionInfo:
    state = quality = period = multiplier = None
    for pos, end in spans:
        while pos < end:
            tagpos = pos
            tag = buf[pos]
            if tag < 0x80:
                pos += 1
            else:
                tag, pos = _read_varint(buf, pos, end)
            if tag == 0x08:  # 1 sessionState
                state, pos = _read_varint(buf, pos, end)
            elif tag == 0x10:  # 2 quality
                quality, pos = _read_varint(buf, pos, end)
            elif tag == 0x18:  # 3 sendPeriod
                period, pos = _read_varint(buf, pos, end)
            elif tag == 0x20:  # 4 receiveMultiplier
                multiplier, pos = _read_varint(buf, pos, end)
            else:
                pos = _skip_field(buf, pos, end, tag, tagpos)
    if state is None:
        raise FriDecodeError("connectionInfo field 1 (sessionState) missing")
    if quality is None:
        raise FriDecodeError("connectionInfo field 2 (quality) missing")
    return ConnectionInfo(
        _enum(state, _SESSION_STATES),
        _enum(quality, _QUALITIES),
        None if period is None else period & _U32_MAX,
        None if multiplier is None else multiplier & _U32_MAX,
    )


def _decode_robot_info(buf: bytes, spans: Spans) -> RobotInfo:
    joints = safety = operation = control = None
    drives: list[int] = []
    drive_states = _DRIVE_STATES
    for pos, end in spans:
        while pos < end:
            tagpos = pos
            tag = buf[pos]
            if tag < 0x80:
                pos += 1
            else:
                tag, pos = _read_varint(buf, pos, end)
            if tag == 0x28:  # 5 driveState, unpacked
                if pos < end and buf[pos] < 0x80:
                    v = buf[pos]
                    pos += 1
                else:
                    v, pos = _read_varint(buf, pos, end)
                    v = _int32(v)
                drives.append(drive_states.get(v, v))
            elif tag == 0x2A:  # 5 driveState, packed
                a, pos = _read_length(buf, pos, end, tag, tagpos)
                while a < pos:
                    v, a = _read_varint(buf, a, pos)
                    v = _int32(v)
                    drives.append(drive_states.get(v, v))
            elif tag == 0x08:  # 1 numberOfJoints
                joints, pos = _read_varint(buf, pos, end)
            elif tag == 0x10:  # 2 safetyState
                safety, pos = _read_varint(buf, pos, end)
            elif tag == 0x30:  # 6 operationMode
                operation, pos = _read_varint(buf, pos, end)
            elif tag == 0x38:  # 7 controlMode
                control, pos = _read_varint(buf, pos, end)
            else:
                pos = _skip_field(buf, pos, end, tag, tagpos)
    return RobotInfo(
        None if joints is None else _int32(joints),
        _enum(safety, _SAFETY_STATES),
        tuple(drives),
        _enum(operation, _OPERATION_MODES),
        _enum(control, _CONTROL_MODES),
    )


_MONITOR_DATA_NAMES = (
    "",
    "measuredJointPosition",
    "measuredTorque",
    "commandedJointPosition",
    "commandedTorque",
    "externalTorque",
)


def _decode_monitor_data(buf: bytes, spans: Spans) -> MonitorData:
    joint_values: list[tuple[float, ...] | None] = [None] * 6  # indexed by field number 1..5
    sec = nanosec = None
    has_timestamp = False
    tag_runs = _TAG_RUNS
    unpacked = _UNPACKED
    for pos, end in spans:
        while pos < end:
            tagpos = pos
            tag = buf[pos]
            if tag < 0x80:
                pos += 1
            else:
                tag, pos = _read_varint(buf, pos, end)
            if tag & 7 == 2 and 0x0A <= tag <= 0x2A:  # 1..5 JointValues
                if pos < end and buf[pos] < 0x80:
                    a = pos + 1
                    pos = a + buf[pos]
                    if pos > end:
                        raise _overrun(tag, tagpos, a, pos, end)
                else:
                    a, pos = _read_length(buf, pos, end, tag, tagpos)
                field = tag >> 3
                size = pos - a
                n = size // 9
                if size == 9 * n and buf[a:pos:9] == tag_runs[n]:  # the fast path of _doubles, inlined
                    new = unpacked[n].unpack_from(buf, a)
                else:
                    new = _doubles(buf, a, pos, _MONITOR_DATA_NAMES[field])
                old = joint_values[field]
                joint_values[field] = new if old is None else old + new
            elif tag == 0x7A:  # 15 timestamp
                a, pos = _read_length(buf, pos, end, tag, tagpos)
                has_timestamp = True
                while a < pos:
                    ttag_pos = a
                    ttag = buf[a]
                    if ttag < 0x80:
                        a += 1
                    else:
                        ttag, a = _read_varint(buf, a, pos)
                    if ttag == 0x08:  # 1 sec
                        sec, a = _read_varint(buf, a, pos)
                    elif ttag == 0x10:  # 2 nanosec
                        nanosec, a = _read_varint(buf, a, pos)
                    else:
                        a = _skip_field(buf, a, pos, ttag, ttag_pos)
            else:
                pos = _skip_field(buf, pos, end, tag, tagpos)
    timestamp = None
    if has_timestamp:
        if sec is None:
            raise FriDecodeError("timestamp field 1 (sec) missing")
        if nanosec is None:
            raise FriDecodeError("timestamp field 2 (nanosec) missing")
        timestamp = (sec & _U32_MAX, nanosec & _U32_MAX)
    _, q, tau, q_cmd, tau_cmd, tau_ext = joint_values
    return MonitorData(q, tau, q_cmd, tau_cmd, tau_ext, timestamp)


def _concat(old: tuple[float, ...] | None, new: tuple[float, ...]) -> tuple[float, ...]:
    return new if old is None else old + new


def _decode_ipo_data(buf: bytes, spans: Spans) -> IpoData:
    joints = None
    mode = overlay = tracking = None
    for pos, end in spans:
        while pos < end:
            tagpos = pos
            tag = buf[pos]
            if tag < 0x80:
                pos += 1
            else:
                tag, pos = _read_varint(buf, pos, end)
            if tag == 0x0A:  # 1 jointPosition
                a, pos = _read_length(buf, pos, end, tag, tagpos)
                joints = _concat(joints, _doubles(buf, a, pos, "ipoData.jointPosition"))
            elif tag == 0x50:  # 10 clientCommandMode
                mode, pos = _read_varint(buf, pos, end)
            elif tag == 0x58:  # 11 overlayType
                overlay, pos = _read_varint(buf, pos, end)
            elif tag == 0x61:  # 12 trackingPerformance
                if end - pos < 8:
                    raise FriDecodeError(
                        f"trackingPerformance at byte {tagpos} runs past the end of its message"
                        f" ({end - pos} bytes left)"
                    )
                tracking = _unpack_double(buf, pos)[0]
                pos += 8
            else:
                pos = _skip_field(buf, pos, end, tag, tagpos)
    return IpoData(joints, _enum(mode, _CLIENT_COMMAND_MODES), _enum(overlay, _OVERLAY_TYPES), tracking)


def _decode_command_data(buf: bytes, spans: Spans) -> CommandData:
    position = torque = wrench = None
    for pos, end in spans:
        while pos < end:
            tagpos = pos
            tag = buf[pos]
            if tag < 0x80:
                pos += 1
            else:
                tag, pos = _read_varint(buf, pos, end)
            if tag == 0x0A:  # 1 jointPosition
                a, pos = _read_length(buf, pos, end, tag, tagpos)
                position = _concat(position, _doubles(buf, a, pos, "jointPosition"))
            elif tag == 0x1A:  # 3 jointTorque
                a, pos = _read_length(buf, pos, end, tag, tagpos)
                torque = _concat(torque, _doubles(buf, a, pos, "jointTorque"))
            elif tag == 0x12:  # 2 cartesianWrenchFeedForward (same layout as JointValues)
                a, pos = _read_length(buf, pos, end, tag, tagpos)
                wrench = _concat(wrench, _doubles(buf, a, pos, "cartesianWrenchFeedForward"))
            else:
                pos = _skip_field(buf, pos, end, tag, tagpos)
    if wrench is not None and len(wrench) > MAX_WRENCH_ELEMENTS:
        raise FriDecodeError(
            f"cartesianWrenchFeedForward has {len(wrench)} elements, at most {MAX_WRENCH_ELEMENTS} allowed"
        )
    return CommandData(position, torque, wrench)


def _raw(buf: bytes, spans: Spans | None) -> bytes | None:
    """Concatenated bodies of an uninterpreted sub-message (the serialized form of their merge)."""
    if spans is None:
        return None
    if len(spans) == 1:
        a, b = spans[0]
        return buf[a:b]
    return b"".join(buf[a:b] for a, b in spans)


# --------------------------------------------------------------------------- public decoders

# Top-level length-delimited fields: 1 header, 2 robotInfo, 3 monitorData,
# 4 connectionInfo, 5 ipoData, 6 requestedTransformations, 15 endOfMessageData.
_MONITORING_FIELDS = frozenset((0x0A, 0x12, 0x1A, 0x22, 0x2A, 0x32, 0x7A))
# 1 header, 2 commandData, 15 endOfMessageData.
_COMMAND_FIELDS = frozenset((0x0A, 0x12, 0x7A))


def decode_monitoring(data: bytes) -> MonitoringMessage:
    """Decode a ``FRIMonitoringMessage`` datagram received from the robot.

    Parameters
    ----------
    data : bytes-like
        One UDP datagram, at most :data:`MAX_DATAGRAM_BYTES` bytes.

    Returns
    -------
    MonitoringMessage
        The message; joint positions in rad, torques in Nm.

    Raises
    ------
    FriDecodeError
        If ``data`` is not a valid monitoring message (malformed wire
        format, a required field missing, a message identifier other than
        :data:`MONITORING_MESSAGE_ID`, more than the size limit). No other
        exception is raised for any input.
    """
    buf = _as_bytes(data)
    spans = _split(buf, len(buf), _MONITORING_FIELDS)
    get = spans.get
    header = _decode_header(buf, get(0x0A), MONITORING_MESSAGE_ID, "monitoring")
    s = get(0x12)
    robot_info = None if s is None else _decode_robot_info(buf, s)
    s = get(0x1A)
    monitor_data = None if s is None else _decode_monitor_data(buf, s)
    s = get(0x22)
    connection_info = None if s is None else _decode_connection_info(buf, s)
    s = get(0x2A)
    ipo_data = None if s is None else _decode_ipo_data(buf, s)
    s = get(0x32)
    transformations = () if s is None else tuple([buf[a:b] for a, b in s])
    return MonitoringMessage(
        header, robot_info, monitor_data, connection_info, ipo_data, transformations, _raw(buf, get(0x7A))
    )


def decode_command(data: bytes) -> CommandMessage:
    """Decode a ``FRICommandMessage`` datagram sent by an FRI client.

    Parameters
    ----------
    data : bytes-like
        One UDP datagram, at most :data:`MAX_DATAGRAM_BYTES` bytes.

    Returns
    -------
    CommandMessage
        The message; joint positions in rad, torques in Nm.

    Raises
    ------
    FriDecodeError
        If ``data`` is not a valid command message (malformed wire format,
        a required field missing, a message identifier other than
        :data:`COMMAND_MESSAGE_ID`, more than 6 wrench elements, more than
        the size limit). No other exception is raised for any input.
    """
    buf = _as_bytes(data)
    spans = _split(buf, len(buf), _COMMAND_FIELDS)
    get = spans.get
    header = _decode_header(buf, get(0x0A), COMMAND_MESSAGE_ID, "command")
    s = get(0x12)
    command_data = None if s is None else _decode_command_data(buf, s)
    return CommandMessage(header, command_data, _raw(buf, get(0x7A)))


# --------------------------------------------------------------------------- encoding primitives


def _varint(v: int) -> bytes:
    """Varint of a non-negative integer below 2**64."""
    if v < 0x80:
        return _SMALL_VARINTS[v]
    out = bytearray()
    while v > 0x7F:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def _as_int(value: object, name: str) -> int:
    try:
        return operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{name} must be an integer, got {value!r}") from None


def _uint32(value: object, name: str) -> bytes:
    v = _as_int(value, name)
    if not 0 <= v <= _U32_MAX:
        raise ValueError(f"{name} = {v} is outside the uint32 range 0..{_U32_MAX}")
    return _varint(v)


def _int32_varint(value: object, name: str) -> bytes:
    """Varint of an int32 or enum value; a negative value takes 10 bytes, as in protobuf."""
    v = _as_int(value, name)
    if not _I32_MIN <= v <= _I32_MAX:
        raise ValueError(f"{name} = {v} is outside the int32 range {_I32_MIN}..{_I32_MAX}")
    return _varint(v & _U64_MASK)


def _double(value: object, name: str) -> bytes:
    try:
        return _pack_double(value)
    except (struct.error, TypeError, OverflowError) as exc:
        raise ValueError(f"{name} must be a float, got {value!r} ({exc})") from None


def _length_delimited(tag: bytes, body: bytes) -> bytes:
    return tag + _varint(len(body)) + body


def _unpacked_doubles(tag: bytes, values: object, name: str, max_count: int | None = None) -> bytes:
    """A ``JointValues`` / ``CartesianVector`` field with the values written unpacked (tag 0x09 per value)."""
    try:
        n = len(values)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{name} must be a sequence of floats, got {values!r}") from None
    if max_count is not None and n > max_count:
        raise ValueError(f"{name} has {n} elements, at most {max_count} allowed")
    if n > _MAX_UNPACKED:
        raise ValueError(f"{name} has {n} values, more than a {MAX_DATAGRAM_BYTES}-byte datagram holds")
    try:
        body = bytearray(_UNPACKED[n].pack(*values))  # type: ignore[misc]
    except (struct.error, TypeError, OverflowError) as exc:
        raise ValueError(f"{name} must be a sequence of floats ({exc})") from None
    body[::9] = _TAG_RUNS[n]
    return tag + _varint(9 * n) + body


def _encode_header(header: MessageHeader) -> bytes:
    if header is None:
        raise ValueError("header is required")
    body = (
        b"\x08"
        + _uint32(header.message_identifier, "header.message_identifier")
        + b"\x10"
        + _uint32(header.sequence_counter, "header.sequence_counter")
        + b"\x18"
        + _uint32(header.reflected_sequence_counter, "header.reflected_sequence_counter")
    )
    return b"\x0a" + _varint(len(body)) + body


def _check_size(out: bytes) -> bytes:
    if len(out) > MAX_DATAGRAM_BYTES:
        raise ValueError(f"encoded message of {len(out)} bytes exceeds the {MAX_DATAGRAM_BYTES}-byte datagram limit")
    return out


def _encode_robot_info(info: RobotInfo) -> bytes:
    parts = []
    if info.number_of_joints is not None:
        parts += (b"\x08", _int32_varint(info.number_of_joints, "robot_info.number_of_joints"))
    if info.safety_state is not None:
        parts += (b"\x10", _int32_varint(info.safety_state, "robot_info.safety_state"))
    try:
        drives = tuple(info.drive_state)
    except TypeError:
        raise ValueError(f"robot_info.drive_state must be a sequence of integers, got {info.drive_state!r}") from None
    if len(drives) > MAX_DATAGRAM_BYTES:
        raise ValueError(f"robot_info.drive_state has {len(drives)} values, more than a datagram holds")
    for d in drives:
        parts += (b"\x28", _int32_varint(d, "robot_info.drive_state"))
    if info.operation_mode is not None:
        parts += (b"\x30", _int32_varint(info.operation_mode, "robot_info.operation_mode"))
    if info.control_mode is not None:
        parts += (b"\x38", _int32_varint(info.control_mode, "robot_info.control_mode"))
    return b"".join(parts)


def _encode_monitor_data(data: MonitorData) -> bytes:
    parts = []
    for tag, values, name in (
        (b"\x0a", data.measured_joint_position, "monitor_data.measured_joint_position"),
        (b"\x12", data.measured_torque, "monitor_data.measured_torque"),
        (b"\x1a", data.commanded_joint_position, "monitor_data.commanded_joint_position"),
        (b"\x22", data.commanded_torque, "monitor_data.commanded_torque"),
        (b"\x2a", data.external_torque, "monitor_data.external_torque"),
    ):
        if values is not None:
            parts.append(_unpacked_doubles(tag, values, name))
    if data.timestamp is not None:
        try:
            sec, nanosec = data.timestamp
        except (TypeError, ValueError):
            raise ValueError(f"monitor_data.timestamp must be (sec, nanosec), got {data.timestamp!r}") from None
        body = (
            b"\x08"
            + _uint32(sec, "monitor_data.timestamp sec")
            + b"\x10"
            + _uint32(nanosec, "monitor_data.timestamp nanosec")
        )
        parts.append(_length_delimited(b"\x7a", body))
    return b"".join(parts)


def _encode_connection_info(info: ConnectionInfo) -> bytes:
    parts = [
        b"\x08",
        _int32_varint(info.session_state, "connection_info.session_state"),
        b"\x10",
        _int32_varint(info.quality, "connection_info.quality"),
    ]
    if info.send_period_ms is not None:
        parts += (b"\x18", _uint32(info.send_period_ms, "connection_info.send_period_ms"))
    if info.receive_multiplier is not None:
        parts += (b"\x20", _uint32(info.receive_multiplier, "connection_info.receive_multiplier"))
    return b"".join(parts)


def _encode_ipo_data(ipo: IpoData) -> bytes:
    parts = []
    if ipo.joint_position is not None:
        parts.append(_unpacked_doubles(b"\x0a", ipo.joint_position, "ipo_data.joint_position"))
    if ipo.client_command_mode is not None:
        parts += (b"\x50", _int32_varint(ipo.client_command_mode, "ipo_data.client_command_mode"))
    if ipo.overlay_type is not None:
        parts += (b"\x58", _int32_varint(ipo.overlay_type, "ipo_data.overlay_type"))
    if ipo.tracking_performance is not None:
        parts += (b"\x61", _double(ipo.tracking_performance, "ipo_data.tracking_performance"))
    return b"".join(parts)


def _raw_bytes(value: object, name: str) -> bytes:
    try:
        return bytes(memoryview(value))  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{name} must be bytes, got {type(value).__name__}") from None


# --------------------------------------------------------------------------- public encoders


def encode_monitoring(msg: MonitoringMessage) -> bytes:
    """Encode a ``FRIMonitoringMessage`` (what the robot sends; used by emulators and tests).

    Parameters
    ----------
    msg : MonitoringMessage
        The message; the header's identifier is written as given (normally
        :data:`MONITORING_MESSAGE_ID`). Joint positions in rad, torques in Nm.

    Returns
    -------
    bytes
        The datagram, fields in field-number order, repeated doubles and
        drive states unpacked.

    Raises
    ------
    ValueError
        If a value is out of its range (uint32, int32), not a number, or the
        datagram would exceed :data:`MAX_DATAGRAM_BYTES`.
    """
    parts = [_encode_header(msg.header)]
    if msg.robot_info is not None:
        parts.append(_length_delimited(b"\x12", _encode_robot_info(msg.robot_info)))
    if msg.monitor_data is not None:
        parts.append(_length_delimited(b"\x1a", _encode_monitor_data(msg.monitor_data)))
    if msg.connection_info is not None:
        parts.append(_length_delimited(b"\x22", _encode_connection_info(msg.connection_info)))
    if msg.ipo_data is not None:
        parts.append(_length_delimited(b"\x2a", _encode_ipo_data(msg.ipo_data)))
    for raw in msg.requested_transformations:
        raw = _raw_bytes(raw, "requested_transformations element")
        if len(raw) > MAX_DATAGRAM_BYTES:
            raise ValueError(f"a requested transformation of {len(raw)} bytes exceeds the datagram limit")
        parts.append(_length_delimited(b"\x32", raw))
    if msg.end_of_message_data is not None:
        parts.append(_length_delimited(b"\x7a", _raw_bytes(msg.end_of_message_data, "end_of_message_data")))
    return _check_size(b"".join(parts))


def encode_command(msg: CommandMessage) -> bytes:
    """Encode a ``FRICommandMessage`` to send to the robot.

    Parameters
    ----------
    msg : CommandMessage
        The message; the header's identifier is written as given (normally
        :data:`COMMAND_MESSAGE_ID`). Joint positions in rad, joint torques
        in Nm, the wrench in N and Nm.

    Returns
    -------
    bytes
        The datagram, fields in field-number order, repeated doubles
        unpacked (tag ``0x09`` and 8 little-endian bytes per value) as
        KUKA's client SDK writes them.

    Raises
    ------
    ValueError
        If a value is out of its range, not a number, the wrench has more
        than 6 elements, or the datagram would exceed
        :data:`MAX_DATAGRAM_BYTES`.
    """
    out = _encode_header(msg.header)
    cmd = msg.command_data
    if cmd is not None:
        body = b""
        if cmd.joint_position is not None:
            body += _unpacked_doubles(b"\x0a", cmd.joint_position, "command_data.joint_position")
        if cmd.cartesian_wrench_feed_forward is not None:
            body += _unpacked_doubles(
                b"\x12",
                cmd.cartesian_wrench_feed_forward,
                "command_data.cartesian_wrench_feed_forward",
                MAX_WRENCH_ELEMENTS,
            )
        if cmd.joint_torque is not None:
            body += _unpacked_doubles(b"\x1a", cmd.joint_torque, "command_data.joint_torque")
        out += b"\x12" + _varint(len(body)) + body
    if msg.end_of_message_data is not None:
        out += _length_delimited(b"\x7a", _raw_bytes(msg.end_of_message_data, "end_of_message_data"))
    return _check_size(out)
