"""The FRI messages: byte-level references, proto2 parsing rules, the checks protobuf does not make, fuzzing."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from google.protobuf.descriptor import FieldDescriptor
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from iiwa_ident.fri import (
    COMMAND_MESSAGE_ID,
    MAX_DATAGRAM_BYTES,
    MONITORING_MESSAGE_ID,
    N_JOINTS,
    ClientCommandMode,
    CommandData,
    CommandMessage,
    ConnectionQuality,
    ControlMode,
    DriveState,
    FriDecodeError,
    JointValues,
    MonitoringMessage,
    OperationMode,
    OverlayType,
    SafetyState,
    SessionState,
    decode_command,
    decode_monitoring,
    encode_command,
    encode_monitoring,
    message_problem,
    messages_pb2,
)

# Derandomized: the same examples on every machine, so a red CI is a real defect, not a new draw.
FUZZ = settings(derandomize=True, deadline=None, database=None, max_examples=400,
                suppress_health_check=[HealthCheck.too_slow])

# --------------------------------------------------------------------------- wire-format helpers
# A minimal protobuf writer, independent of the library under test, for hand-built datagrams.


def varint(v: int) -> bytes:
    v &= (1 << 64) - 1
    out = bytearray()
    while v > 0x7F:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def tag(field: int, wire: int) -> bytes:
    return varint(field << 3 | wire)


def vfield(field: int, value: int) -> bytes:
    return tag(field, 0) + varint(value)


def ld(field: int, body: bytes) -> bytes:
    return tag(field, 2) + varint(len(body)) + body


def dfield(field: int, value: float) -> bytes:
    return tag(field, 1) + struct.pack("<d", value)


def unpacked(values) -> bytes:
    return b"".join(dfield(1, v) for v in values)


def packed(values) -> bytes:
    return ld(1, struct.pack(f"<{len(values)}d", *values))


def header_bytes(ident: int, seq: int = 5, reflected: int = 7) -> bytes:
    return ld(1, vfield(1, ident) + vfield(2, seq) + vfield(3, reflected))


CMD_HEADER = header_bytes(COMMAND_MESSAGE_ID)
MON_HEADER = header_bytes(MONITORING_MESSAGE_ID)

Q = (0.1, -0.2, 0.3, -0.4, 0.5, -0.6, 0.7)
TAU = (1.5, -2.5, 3.5, -4.5, 5.5, -6.5, 7.5)


def header(ident: int, seq: int = 5, reflected: int = 7) -> dict:
    return dict(message_identifier=ident, sequence_counter=seq, reflected_sequence_counter=reflected)


def full_monitoring() -> MonitoringMessage:
    msg = MonitoringMessage(
        header=header(MONITORING_MESSAGE_ID, 4294967295, 123456),
        robot_info=dict(number_of_joints=7, safety_state=SafetyState.SAFETY_STOP_LEVEL_1,
                        drive_state=(DriveState.ACTIVE,) * 6 + (DriveState.TRANSITIONING,),
                        operation_mode=OperationMode.AUT, control_mode=ControlMode.JOINT_IMPEDANCE),
        monitor_data=dict(measured_joint_position=dict(value=Q), measured_torque=dict(value=TAU),
                          commanded_joint_position=dict(value=[q + 1e-3 for q in Q]),
                          commanded_torque=dict(value=[-t for t in TAU]),
                          external_torque=dict(value=[0.01 * t for t in TAU]),
                          timestamp=dict(sec=1700000000, nanosec=999999999)),
        connection_info=dict(session_state=SessionState.COMMANDING_ACTIVE, quality=ConnectionQuality.EXCELLENT,
                             send_period_ms=1, receive_multiplier=2),
        ipo_data=dict(joint_position=dict(value=Q), client_command_mode=ClientCommandMode.TORQUE,
                      overlay_type=OverlayType.JOINT, tracking_performance=0.75),
    )
    msg.requested_transformations.add().MergeFromString(b"\x0a\x03abc")
    msg.end_of_message_data.MergeFromString(b"\x08\x01")
    return msg


def full_command() -> CommandMessage:
    return CommandMessage(
        header=header(COMMAND_MESSAGE_ID, 42, 41),
        command_data=dict(joint_position=dict(value=Q), joint_torque=dict(value=TAU),
                          cartesian_wrench_feed_forward=dict(element=(1.0, 2.0, 3.0, 0.1, 0.2, 0.3))),
    )


# --------------------------------------------------------------------------- reference bytes


class TestReferenceBytes:
    def test_header_only_command(self):
        # 0a 08        field 1 (header), wire type 2: tag 1 << 3 | 2 = 0x0a; body of 8 bytes
        # 08 81 80 0d  field 1 (message identifier), varint: 0x34001 in 7-bit groups from the low end
        # 10 05        field 2 (sequence counter), varint 5
        # 18 07        field 3 (reflected sequence counter), varint 7
        assert encode_command(CommandMessage(header=header(COMMAND_MESSAGE_ID))) == bytes.fromhex("0a08 0881800d 1005 1807")

    def test_monitoring_header(self):
        # 0x245142 in 7-bit groups from the low end: 0x42, 0x22, 0x11, 0x01 -> c2 a2 91 01
        msg = MonitoringMessage(header=header(MONITORING_MESSAGE_ID))
        assert encode_monitoring(msg) == bytes.fromhex("0a09 08c2a29101 1005 1807")

    def test_joint_values_unpacked_as_kukas_sdk_writes_them(self):
        out = encode_command(CommandMessage(header=header(COMMAND_MESSAGE_ID),
                                            command_data=dict(joint_torque=dict(value=TAU))))
        # commandData (0x12) of 65 bytes: jointTorque (field 3, 0x1a) of 63 bytes: 7 x (tag 0x09, 8 bytes)
        assert out[len(CMD_HEADER):len(CMD_HEADER) + 4] == b"\x12\x41\x1a\x3f"
        body = out[-63:]
        assert body[::9] == b"\x09" * 7
        assert struct.unpack("<" + "xd" * 7, body) == TAU

    def test_wrench_packed_as_kukas_sdk_writes_it(self):
        wrench = (1.0, 2.0, 3.0, 0.1, 0.2, 0.3)
        out = encode_command(CommandMessage(header=header(COMMAND_MESSAGE_ID),
                                            command_data=dict(cartesian_wrench_feed_forward=dict(element=wrench))))
        # commandData (0x12): cartesianWrenchFeedForward (field 2, 0x12): element (field 1, 0x0a) of 48 bytes
        assert out == CMD_HEADER + ld(2, ld(2, packed(wrench)))
        assert decode_command(CMD_HEADER + ld(2, ld(2, unpacked(wrench)))).command_data == \
            decode_command(out).command_data  # unpacked is read too

    def test_drive_states_unpacked(self):
        msg = MonitoringMessage(header=header(MONITORING_MESSAGE_ID), robot_info=dict(drive_state=(2,) * 7))
        assert encode_monitoring(msg) == MON_HEADER + ld(2, vfield(5, 2) * 7)

    def test_timestamp(self):
        msg = MonitoringMessage(header=header(MONITORING_MESSAGE_ID), monitor_data=dict(timestamp=dict(sec=1, nanosec=300)))
        # monitorData (0x1a): timestamp field 15 (0x7a) of 5 bytes: 08 01, 10 ac02 (300 = 0b10_0101100)
        assert encode_monitoring(msg) == MON_HEADER + bytes.fromhex("1a07 7a05 0801 10ac02")

    def test_decode_hand_built(self):
        data = CMD_HEADER + ld(2, ld(1, unpacked(Q)) + ld(3, unpacked(TAU)))
        msg = decode_command(data)
        assert (msg.header.sequence_counter, msg.header.reflected_sequence_counter) == (5, 7)
        assert tuple(msg.command_data.joint_position.value) == Q
        assert tuple(msg.command_data.joint_torque.value) == TAU


# --------------------------------------------------------------------------- round trips and proto2 rules


class TestRoundTrip:
    def test_full_messages(self):
        for msg, encode, decode in ((full_monitoring(), encode_monitoring, decode_monitoring),
                                    (full_command(), encode_command, decode_command)):
            assert decode(encode(msg)) == msg

    def test_uninterpreted_parts_written_back_as_they_came(self):
        data = encode_monitoring(full_monitoring())
        assert ld(6, b"\x0a\x03abc") in data and data.endswith(ld(15, b"\x08\x01"))
        assert encode_monitoring(decode_monitoring(data)) == data

    def test_bytes_like_inputs(self):
        data = encode_command(full_command())
        assert decode_command(bytearray(data)) == decode_command(memoryview(data)) == full_command()
        assert decode_command(np.frombuffer(data, dtype=np.uint8)) == full_command()

    def test_enums_compare_with_the_members(self):
        msg = decode_monitoring(encode_monitoring(full_monitoring()))
        assert msg.connection_info.session_state == SessionState.COMMANDING_ACTIVE
        assert msg.robot_info.drive_state[6] == DriveState.TRANSITIONING
        assert SessionState(msg.connection_info.session_state) is SessionState.COMMANDING_ACTIVE


class TestProto2Rules:
    def test_packed_equals_unpacked(self):
        a = decode_command(CMD_HEADER + ld(2, ld(3, unpacked(TAU))))
        b = decode_command(CMD_HEADER + ld(2, ld(3, packed(TAU))))
        assert a == b and tuple(a.command_data.joint_torque.value) == TAU

    def test_mixed_packed_unpacked_concatenates(self):
        body = unpacked(Q[:2]) + packed(Q[2:5]) + unpacked(Q[5:]) + packed(())
        assert tuple(decode_command(CMD_HEADER + ld(2, ld(1, body))).command_data.joint_position.value) == Q

    def test_unknown_fields_skipped(self):
        unknown = vfield(9, 2**63) + dfield(10, 1.0) + tag(11, 5) + b"abcd" + ld(12, b"\xff\xff") + ld(1000, b"")
        data = unknown + CMD_HEADER + unknown + ld(2, unknown + ld(3, unknown + unpacked(TAU) + unknown))
        assert tuple(decode_command(data).command_data.joint_torque.value) == TAU

    def test_repeated_sub_message_merges(self):
        first = ld(2, ld(1, unpacked(Q[:3])) + ld(3, unpacked(TAU)))
        second = ld(2, ld(1, unpacked(Q[3:])))
        msg = decode_command(CMD_HEADER + first + second)
        assert tuple(msg.command_data.joint_position.value) == Q
        assert tuple(msg.command_data.joint_torque.value) == TAU

    def test_repeated_scalar_last_wins(self):
        assert decode_command(CMD_HEADER + ld(1, vfield(2, 99))).header.sequence_counter == 99

    def test_unknown_enum_numbers_kept(self):
        data = MON_HEADER + ld(4, vfield(1, 9) + vfield(2, 200)) + ld(2, vfield(7, 2) + vfield(6, 77))
        msg = decode_monitoring(data)
        assert msg.connection_info.session_state == 9 and msg.connection_info.quality == 200
        assert msg.robot_info.operation_mode == 77
        assert msg.robot_info.control_mode == ControlMode.JOINT_IMPEDANCE
        assert decode_monitoring(encode_monitoring(msg)).robot_info.operation_mode == 77  # and written back

    def test_largest_datagram(self):
        pad = MAX_DATAGRAM_BYTES - len(MON_HEADER) - 3
        data = MON_HEADER + tag(14, 2) + varint(pad) + b"\x00" * pad
        assert len(data) == MAX_DATAGRAM_BYTES
        assert decode_monitoring(data).header.sequence_counter == 5


# --------------------------------------------------------------------------- the checks protobuf does not make

_CMD_BODY = ld(2, ld(1, unpacked(Q)))
# (decoder, datagram): each one invalid in one way
INVALID = {
    "empty": (decode_command, b""),
    "too long": (decode_monitoring, MON_HEADER + ld(14, b"\x00" * 1490)),
    "not bytes": (decode_command, "0a08"),
    "none": (decode_monitoring, None),
    "truncated varint": (decode_command, CMD_HEADER + b"\x08\x80"),
    "length past the end": (decode_command, CMD_HEADER + b"\x12\x05\x0a"),
    "wire type 7": (decode_monitoring, MON_HEADER + b"\x1f"),
    "field number 0": (decode_command, CMD_HEADER + b"\x00\x00"),
    "header missing": (decode_command, _CMD_BODY),
    "identifier missing": (decode_command, ld(1, vfield(2, 1) + vfield(3, 1))),
    "reflected counter missing": (decode_monitoring, ld(1, vfield(1, MONITORING_MESSAGE_ID) + vfield(2, 1))),
    "session state missing": (decode_monitoring, MON_HEADER + ld(4, vfield(2, 1))),
    "timestamp nanosec missing": (decode_monitoring, MON_HEADER + ld(3, ld(15, vfield(1, 1)))),
    "monitoring id to the command decoder": (decode_command, MON_HEADER),
    "other id": (decode_monitoring, header_bytes(0x1234)),
    "seven wrench elements": (decode_command, CMD_HEADER + ld(2, ld(2, unpacked((0.0,) * 7)))),
    "six torques": (decode_command, CMD_HEADER + ld(2, ld(3, unpacked(TAU[:6])))),
    "eight positions": (decode_monitoring, MON_HEADER + ld(3, ld(1, unpacked(Q + (0.0,))))),
    "nan torque": (decode_command, CMD_HEADER + ld(2, ld(3, unpacked((math.nan,) + TAU[1:])))),
    "inf external torque": (decode_monitoring, MON_HEADER + ld(3, ld(5, unpacked((math.inf,) + TAU[1:])))),
    "nan tracking performance": (decode_monitoring, MON_HEADER + ld(5, dfield(12, math.nan))),
    "three drive states": (decode_monitoring, MON_HEADER + ld(2, vfield(5, 2) * 3)),
    "six joints": (decode_monitoring, MON_HEADER + ld(2, vfield(1, 6))),
}


class TestChecks:
    @pytest.mark.parametrize("case", list(INVALID))
    def test_invalid_datagram_is_a_one_line_decode_error(self, case):
        decode, data = INVALID[case]
        with pytest.raises(FriDecodeError) as info:
            decode(data)
        assert str(info.value) and "\n" not in str(info.value)
        assert isinstance(info.value, ValueError)

    def test_content_unchecked_on_request(self):
        """The emulator reads a bad command as a command, to react as the controller does."""
        msg = decode_command(INVALID["six torques"][1], check=False)
        assert len(msg.command_data.joint_torque.value) == 6
        assert message_problem(msg) == "joint_torque has 6 values, expected 7"
        with pytest.raises(FriDecodeError):  # the form is always checked
            decode_command(INVALID["header missing"][1], check=False)

    @pytest.mark.parametrize("mutate", [
        lambda m: m.command_data.joint_torque.value.append(0.0),
        lambda m: m.command_data.joint_position.value.__setitem__(3, math.nan),
        lambda m: m.command_data.cartesian_wrench_feed_forward.element.append(0.0),
        lambda m: m.header.ClearField("sequence_counter"),
        lambda m: m.header.__setattr__("message_identifier", MONITORING_MESSAGE_ID),
        lambda m: m.command_data.joint_position.value.extend([0.0] * 200),
    ], ids=["eight-torques", "nan", "seven-wrench", "no-counter", "wrong-id", "too-large"])
    def test_encoder_refuses_and_leaves_the_message(self, mutate):
        msg = full_command()
        mutate(msg)
        before = msg.SerializePartialToString()
        with pytest.raises(ValueError) as info:
            encode_command(msg)
        assert "\n" not in str(info.value)
        assert msg.SerializePartialToString() == before

    def test_encoder_takes_only_its_message(self):
        with pytest.raises(ValueError, match="CommandMessage"):
            encode_command(full_monitoring())


# --------------------------------------------------------------------------- property-based fuzzing


def violations(msg) -> list[str]:
    """Everything invalid in a decoded message, found by walking its descriptor (independent of the checks)."""
    out = []
    desc = msg.DESCRIPTOR
    for f in desc.fields:
        present = f.is_repeated or msg.HasField(f.name)
        if f.is_required and not msg.HasField(f.name):
            out.append(f"{desc.name}.{f.name} missing")
        if not present:
            continue
        value = getattr(msg, f.name)
        items = list(value) if f.is_repeated else [value]
        if f.message_type is not None:
            for sub in items:
                out += violations(sub)
        elif f.type == FieldDescriptor.TYPE_DOUBLE and not all(math.isfinite(v) for v in items):
            out.append(f"{desc.name}.{f.name} not finite")
    if desc.name == "JointValues" and len(msg.value) != N_JOINTS:
        out.append(f"{len(msg.value)} joint values")
    if desc.name == "CartesianVector" and len(msg.element) > 6:
        out.append(f"{len(msg.element)} wrench elements")
    if desc.name == "RobotInfo":
        if msg.drive_state and len(msg.drive_state) != N_JOINTS:
            out.append(f"{len(msg.drive_state)} drive states")
        if msg.HasField("number_of_joints") and msg.number_of_joints != N_JOINTS:
            out.append(f"{msg.number_of_joints} joints")
    if desc.name in ("MonitoringMessage", "CommandMessage") and msg.HasField("header"):
        want = MONITORING_MESSAGE_ID if desc.name == "MonitoringMessage" else COMMAND_MESSAGE_ID
        if msg.header.message_identifier != want:
            out.append("wrong identifier")
    return out


u32 = st.integers(0, 2**32 - 1)
enum = st.integers(-(2**31), 2**31 - 1)  # known members and unknown numbers
finite = st.floats(allow_nan=False, allow_infinity=False)
joints = st.lists(finite, min_size=N_JOINTS, max_size=N_JOINTS).map(lambda v: dict(value=v))


def maybe(strategy):
    return st.one_of(st.none(), strategy)


def _drop_none(**fields) -> dict:
    return {k: v for k, v in fields.items() if v is not None}


monitorings = st.builds(
    lambda seq, ref, info, data, conn, ipo, n_tr: _with_transformations(MonitoringMessage(**_drop_none(
        header=header(MONITORING_MESSAGE_ID, seq, ref), robot_info=info, monitor_data=data,
        connection_info=conn, ipo_data=ipo)), n_tr),
    u32, u32,
    maybe(st.builds(_drop_none, number_of_joints=maybe(st.just(7)), safety_state=maybe(enum),
                    drive_state=maybe(st.lists(enum, min_size=7, max_size=7)), operation_mode=maybe(enum),
                    control_mode=maybe(enum))),
    maybe(st.builds(_drop_none, measured_joint_position=maybe(joints), measured_torque=maybe(joints),
                    commanded_joint_position=maybe(joints), commanded_torque=maybe(joints),
                    external_torque=maybe(joints), timestamp=maybe(st.builds(dict, sec=u32, nanosec=u32)))),
    maybe(st.builds(_drop_none, session_state=enum, quality=enum, send_period_ms=maybe(u32),
                    receive_multiplier=maybe(u32))),
    maybe(st.builds(_drop_none, joint_position=maybe(joints), client_command_mode=maybe(enum),
                    overlay_type=maybe(enum), tracking_performance=maybe(finite))),
    st.integers(0, 2),
)


def _with_transformations(msg: MonitoringMessage, n: int) -> MonitoringMessage:
    for i in range(n):  # carried as unknown fields
        msg.requested_transformations.add().MergeFromString(ld(1, b"frame%d" % i) + dfield(2, 1.0))
    return msg


commands = st.builds(
    lambda seq, ref, data: CommandMessage(**_drop_none(header=header(COMMAND_MESSAGE_ID, seq, ref),
                                                       command_data=data)),
    u32, u32,
    maybe(st.builds(_drop_none, joint_position=maybe(joints), joint_torque=maybe(joints),
                    cartesian_wrench_feed_forward=maybe(st.lists(finite, max_size=6).map(
                        lambda e: dict(element=e))))),
)

messages = st.one_of(monitorings.map(lambda m: (m, encode_monitoring, decode_monitoring)),
                     commands.map(lambda m: (m, encode_command, decode_command)))


def decoded_or_refused(decode, data: bytes):
    """The decoded message, which must then be valid, or None when refused with a one-line FriDecodeError."""
    try:
        msg = decode(data)
    except FriDecodeError as err:
        assert "\n" not in str(err)
        return None
    assert violations(msg) == [], violations(msg)
    assert len(data) <= MAX_DATAGRAM_BYTES
    return msg


class TestFuzz:
    @FUZZ
    @given(messages)
    def test_valid_messages_round_trip(self, case):
        msg, encode, decode = case
        assert violations(msg) == []
        data = encode(msg)
        assert decode(data) == msg
        assert encode(decode(data)) == data

    @FUZZ
    @given(st.binary(max_size=MAX_DATAGRAM_BYTES + 100), st.sampled_from([b"", CMD_HEADER, MON_HEADER]))
    def test_random_bytes(self, data, prefix):
        for decode in (decode_monitoring, decode_command):
            decoded_or_refused(decode, prefix + data)

    @FUZZ
    @given(messages, st.data())
    def test_truncations_and_mutations(self, case, draw):
        msg, encode, decode = case
        data = encode(msg)
        cut = draw.draw(st.integers(0, len(data)))
        decoded_or_refused(decode, data[:cut])
        buf = bytearray(data)
        for _ in range(draw.draw(st.integers(1, 3))):
            at = draw.draw(st.integers(0, len(buf) - 1))
            buf[at] = draw.draw(st.integers(0, 255))
        decoded_or_refused(decode, bytes(buf))

    @FUZZ
    @given(messages, st.sampled_from(["six", "nan", "inf", "eight"]))
    def test_invalid_content_never_passes(self, case, how):
        """A message made invalid in one joint array is refused by the encoder and by the decoder."""
        msg, encode, decode = case
        arrays = [sub for sub in _joint_arrays(msg)]
        if not arrays:
            return
        values = arrays[0].value
        if how == "six":
            del values[-1]
        elif how == "eight":
            values.append(0.0)
        else:
            values[0] = math.nan if how == "nan" else -math.inf
        with pytest.raises(ValueError):
            encode(msg)
        assert decoded_or_refused(decode, msg.SerializeToString()) is None


def _joint_arrays(msg) -> list[JointValues]:
    out = []
    for f in msg.DESCRIPTOR.fields:
        if f.message_type is None or f.is_repeated or not msg.HasField(f.name):
            continue
        sub = getattr(msg, f.name)
        out += [sub] if isinstance(sub, JointValues) else _joint_arrays(sub)
    return out


def test_message_classes_are_the_schema_s():
    assert CommandData is messages_pb2.CommandData and MonitoringMessage is messages_pb2.MonitoringMessage
