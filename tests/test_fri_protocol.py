"""The FRI message codec: byte-level references, round trips, proto2 parsing rules and a fuzz test."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from iiwa_ident.fri import (
    COMMAND_MESSAGE_ID,
    MAX_DATAGRAM_BYTES,
    MONITORING_MESSAGE_ID,
    ClientCommandMode,
    CommandData,
    CommandMessage,
    ConnectionInfo,
    ConnectionQuality,
    ControlMode,
    DriveState,
    FriDecodeError,
    IpoData,
    MessageHeader,
    MonitorData,
    MonitoringMessage,
    OperationMode,
    OverlayType,
    RobotInfo,
    SafetyState,
    SessionState,
    decode_command,
    decode_monitoring,
    encode_command,
    encode_monitoring,
)

# --------------------------------------------------------------------------- wire-format helpers
# A minimal protobuf writer, independent of the codec under test, for hand-built datagrams.


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


# --------------------------------------------------------------------------- messages

Q = (0.1, -0.2, 0.3, -0.4, 0.5, -0.6, 0.7)
TAU = (1.5, -2.5, 3.5, -4.5, 5.5, -6.5, 7.5)


def full_monitoring() -> MonitoringMessage:
    return MonitoringMessage(
        header=MessageHeader(MONITORING_MESSAGE_ID, 4294967295, 123456),
        robot_info=RobotInfo(
            number_of_joints=7,
            safety_state=SafetyState.SAFETY_STOP_LEVEL_1,
            drive_state=(DriveState.ACTIVE,) * 6 + (DriveState.TRANSITIONING,),
            operation_mode=OperationMode.AUT,
            control_mode=ControlMode.JOINT_IMPEDANCE,
        ),
        monitor_data=MonitorData(
            measured_joint_position=Q,
            measured_torque=TAU,
            commanded_joint_position=tuple(q + 1e-3 for q in Q),
            commanded_torque=tuple(-t for t in TAU),
            external_torque=tuple(0.01 * t for t in TAU),
            timestamp=(1700000000, 999999999),
        ),
        connection_info=ConnectionInfo(SessionState.COMMANDING_ACTIVE, ConnectionQuality.EXCELLENT, 1, 2),
        ipo_data=IpoData(Q, ClientCommandMode.TORQUE, OverlayType.JOINT, 0.75),
        requested_transformations=(b"\x0a\x03abc", b""),
        end_of_message_data=b"\x08\x01",
    )


def full_command() -> CommandMessage:
    return CommandMessage(
        header=MessageHeader(COMMAND_MESSAGE_ID, 42, 41),
        command_data=CommandData(
            joint_position=Q,
            joint_torque=TAU,
            cartesian_wrench_feed_forward=(1.0, 2.0, 3.0, 0.1, 0.2, 0.3),
        ),
        end_of_message_data=b"",
    )


# --------------------------------------------------------------------------- encoders


class TestEncodeCommand:
    def test_header_only_reference_bytes(self):
        # 0a 08        field 1 (header), wire type 2: tag 1 << 3 | 2 = 0x0a; body of 8 bytes
        # 08 81 80 0d  field 1 (messageIdentifier), varint: 0x34001 = 0b1101_0000000_0000001,
        #              7-bit groups from the low end 0x01, 0x00, 0x0d, continuation bit on all but the last
        # 10 05        field 2 (sequenceCounter), varint 5
        # 18 07        field 3 (reflectedSequenceCounter), varint 7
        msg = CommandMessage(MessageHeader(0x34001, 5, 7))
        assert encode_command(msg) == bytes.fromhex("0a08 0881800d 1005 1807")

    def test_unpacked_joint_values_reference_bytes(self):
        # header as above, then
        # 12 1f        field 2 (commandData), 31 bytes:
        #   0a 12      field 1 (jointPosition), 18 bytes: two values, each tag 0x09
        #              (field 1, wire type 1 = fixed64) and 8 little-endian bytes
        #     09 000000000000f03f   1.0  = 0x3ff0000000000000
        #     09 00000000000000c0  -2.0  = 0xc000000000000000
        #   1a 09      field 3 (jointTorque), 9 bytes
        #     09 000000000000e03f   0.5  = 0x3fe0000000000000
        msg = CommandMessage(MessageHeader(0x34001, 5, 7), CommandData(joint_position=(1.0, -2.0), joint_torque=(0.5,)))
        expected = bytes.fromhex(
            "0a08 0881800d 1005 1807"
            "121f"
            "0a12 09000000000000f03f 0900000000000000c0"
            "1a09 09000000000000e03f"
        )
        assert encode_command(msg) == expected

    def test_seven_joints_layout(self):
        out = encode_command(CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 1, 1), CommandData(joint_torque=TAU)))
        body = out[-63:]
        assert out[-65:-63] == b"\x1a\x3f"
        assert body[::9] == b"\x09" * 7
        assert struct.unpack("<" + "xd" * 7, body) == TAU

    def test_field_order_and_wrench(self):
        out = encode_command(full_command())
        cmd = out[len(header_bytes(COMMAND_MESSAGE_ID, 42, 41)):]
        # commandData: jointPosition (0x0a), wrench (0x12), jointTorque (0x1a), each 2 + 9 n bytes,
        # 65 + 56 + 65 = 186 bytes, a two-byte length varint; then an empty endOfMessageData (0x7a 00)
        assert cmd[:3] == b"\x12" + varint(186)
        body = cmd[3:-2]
        assert len(body) == 186
        assert body[0] == 0x0A and body[65] == 0x12 and body[65 + 56] == 0x1A
        assert cmd[-2:] == b"\x7a\x00"

    def test_empty_command_data_and_empty_joint_values(self):
        out = encode_command(CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData()))
        assert out == bytes.fromhex("0a08 0881800d 1000 1800 1200")
        out = encode_command(CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData(joint_torque=())))
        assert out.endswith(bytes.fromhex("1202 1a00"))

    def test_identifier_written_as_given(self):
        out = encode_command(CommandMessage(MessageHeader(0x1234, 0, 0)))
        assert out[2:6] == b"\x08" + varint(0x1234) + b"\x10"

    def test_accepts_numpy_values(self):
        q = np.array(Q)
        msg = CommandMessage(MessageHeader(np.uint32(COMMAND_MESSAGE_ID), np.int64(3), 2), CommandData(joint_position=q))
        assert encode_command(msg) == encode_command(
            CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 3, 2), CommandData(joint_position=Q))
        )

    @pytest.mark.parametrize(
        "header, match",
        [
            (MessageHeader(COMMAND_MESSAGE_ID, -1, 0), "sequence_counter = -1 is outside the uint32 range"),
            (MessageHeader(COMMAND_MESSAGE_ID, 0, 2**32), "reflected_sequence_counter = 4294967296"),
            (MessageHeader(2**40, 0, 0), "message_identifier"),
            (MessageHeader(COMMAND_MESSAGE_ID, 1.5, 0), "sequence_counter must be an integer"),
            (None, "header is required"),
        ],
    )
    def test_header_validation(self, header, match):
        with pytest.raises(ValueError, match=match):
            encode_command(CommandMessage(header))

    def test_wrench_at_most_six(self):
        msg = CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData(cartesian_wrench_feed_forward=(0.0,) * 7))
        with pytest.raises(ValueError, match="has 7 elements, at most 6"):
            encode_command(msg)

    def test_datagram_too_large(self):
        msg = CommandMessage(
            MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData(joint_position=(0.0,) * 100, joint_torque=(0.0,) * 100)
        )
        with pytest.raises(ValueError, match="exceeds the 1500-byte datagram limit"):
            encode_command(msg)
        with pytest.raises(ValueError, match="more than a 1500-byte datagram holds"):
            encode_command(CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData(joint_torque=[0.0] * 10**6)))

    def test_values_must_be_numbers(self):
        with pytest.raises(ValueError, match="joint_torque must be a sequence of floats"):
            encode_command(CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData(joint_torque=("a",))))
        with pytest.raises(ValueError, match="joint_position must be a sequence of floats"):
            encode_command(CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0), CommandData(joint_position=3.0)))


class TestEncodeMonitoring:
    def test_header_reference_bytes(self):
        # 0x245142 = 0b1_0010001_0100010_1000010, 7-bit groups from the low end: 0x42, 0x22, 0x11, 0x01
        # -> c2 a2 91 01; header body 08 c2a29101 10 05 18 07 = 9 bytes
        msg = MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 5, 7))
        assert encode_monitoring(msg) == bytes.fromhex("0a09 08c2a29101 1005 1807")

    def test_negative_int32_is_ten_bytes(self):
        # robotInfo (field 2): numberOfJoints (field 1) = -1 as the 64-bit two's complement varint
        # 0xffffffffffffffff: nine bytes ff and a final 01.
        msg = MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 5, 7), robot_info=RobotInfo(number_of_joints=-1))
        assert encode_monitoring(msg) == MON_HEADER + bytes.fromhex("120b 08ffffffffffffffffff01")

    def test_drive_states_unpacked(self):
        msg = MonitoringMessage(
            MessageHeader(MONITORING_MESSAGE_ID, 5, 7),
            robot_info=RobotInfo(drive_state=(DriveState.ACTIVE, DriveState.OFF, 7)),
        )
        assert encode_monitoring(msg) == MON_HEADER + bytes.fromhex("1206 2802 2800 2807")

    def test_ipo_and_connection_reference_bytes(self):
        msg = MonitoringMessage(
            MessageHeader(MONITORING_MESSAGE_ID, 5, 7),
            connection_info=ConnectionInfo(SessionState.MONITORING_READY, ConnectionQuality.GOOD, 5),
            ipo_data=IpoData(client_command_mode=ClientCommandMode.TORQUE, overlay_type=OverlayType.JOINT,
                             tracking_performance=1.0),
        )
        # connectionInfo (0x22): 08 02, 10 02, 18 05; ipoData (0x2a): 50 03 (field 10), 58 01 (field 11),
        # 61 + 8 bytes (field 12, fixed64) 1.0
        expected = MON_HEADER + bytes.fromhex("2206 0802 1002 1805") + bytes.fromhex("2a0d 5003 5801 61000000000000f03f")
        assert encode_monitoring(msg) == expected

    def test_timestamp_reference_bytes(self):
        msg = MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 5, 7), monitor_data=MonitorData(timestamp=(1, 300)))
        # monitorData (0x1a) 6 bytes: timestamp field 15 (0x7a), 4 bytes: 08 01, 10 ac02 (300 = 0b10_0101100)
        assert encode_monitoring(msg) == MON_HEADER + bytes.fromhex("1a07 7a05 0801 10ac02")

    @pytest.mark.parametrize(
        "msg, match",
        [
            (MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 0, 0), connection_info=ConnectionInfo(0, 0, -5)),
             "send_period_ms = -5 is outside the uint32 range"),
            (MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 0, 0), robot_info=RobotInfo(number_of_joints=2**31)),
             "number_of_joints = 2147483648 is outside the int32 range"),
            (MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 0, 0), monitor_data=MonitorData(timestamp=(0, 2**32))),
             "nanosec = 4294967296 is outside the uint32 range"),
            (MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 0, 0), ipo_data=IpoData(tracking_performance="x")),
             "tracking_performance must be a float"),
            (MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 0, 0), end_of_message_data=b"\x00" * 1500),
             "exceeds the 1500-byte datagram limit"),
        ],
    )
    def test_validation(self, msg, match):
        with pytest.raises(ValueError, match=match):
            encode_monitoring(msg)


# --------------------------------------------------------------------------- decoders


class TestDecodeCommand:
    def test_round_trip_full(self):
        msg = full_command()
        assert decode_command(encode_command(msg)) == msg

    def test_round_trip_minimal(self):
        msg = CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 0, 0))
        assert decode_command(encode_command(msg)) == msg
        msg = CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 1, 2), CommandData(joint_torque=()))
        assert decode_command(encode_command(msg)) == msg

    def test_reference_bytes(self):
        data = bytes.fromhex("0a08 0881800d 1005 1807 1214 0a12 09000000000000f03f 0900000000000000c0")
        msg = decode_command(data)
        assert msg == CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 5, 7), CommandData(joint_position=(1.0, -2.0)))
        assert all(type(v) is float for v in msg.command_data.joint_position)

    def test_bytes_like_inputs(self):
        data = encode_command(full_command())
        assert decode_command(bytearray(data)) == decode_command(memoryview(data)) == full_command()
        assert decode_command(np.frombuffer(data, dtype=np.uint8)) == full_command()

    def test_packed_equals_unpacked(self):
        for values in [Q, (), (1.0,), tuple(range(30))]:
            a = decode_command(CMD_HEADER + ld(2, ld(3, unpacked(values))))
            b = decode_command(CMD_HEADER + ld(2, ld(3, packed(values))))
            assert a == b
            assert a.command_data.joint_torque == tuple(float(v) for v in values)

    def test_mixed_packed_unpacked_concatenates(self):
        body = unpacked((1.0, 2.0)) + packed((3.0, 4.0)) + unpacked((5.0,)) + packed(())
        msg = decode_command(CMD_HEADER + ld(2, ld(1, body)))
        assert msg.command_data.joint_position == (1.0, 2.0, 3.0, 4.0, 5.0)

    def test_unknown_fields_skipped(self):
        unknown = vfield(9, 2**63) + dfield(10, 1.0) + tag(11, 5) + b"abcd" + ld(12, b"\xff\xff") + ld(1000, b"")
        data = unknown + CMD_HEADER + unknown + ld(2, unknown + ld(3, unknown + unpacked((1.0,)) + unknown))
        msg = decode_command(data)
        assert msg == CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 5, 7), CommandData(joint_torque=(1.0,)))

    def test_known_field_with_other_wire_type_is_skipped(self):
        # commandData (field 2) as a varint and jointTorque (field 3) as fixed64: unknown fields for protobuf
        data = CMD_HEADER + vfield(2, 1) + ld(2, dfield(3, 1.0) + ld(1, vfield(1, 3)))
        assert decode_command(data) == CommandMessage(MessageHeader(COMMAND_MESSAGE_ID, 5, 7), CommandData(joint_position=()))

    def test_wrong_identifier(self):
        with pytest.raises(FriDecodeError, match="message identifier 0x245142 is not a command message"):
            decode_command(MON_HEADER)
        with pytest.raises(FriDecodeError, match="message identifier 0x1234 is not a command message"):
            decode_command(header_bytes(0x1234))

    def test_wrench_more_than_six(self):
        data = CMD_HEADER + ld(2, ld(2, unpacked((0.0,) * 4)) + ld(2, packed((0.0,) * 3)))
        with pytest.raises(FriDecodeError, match="cartesianWrenchFeedForward has 7 elements, at most 6"):
            decode_command(data)

    def test_repeated_scalar_last_wins(self):
        data = CMD_HEADER + ld(1, vfield(2, 99))
        assert decode_command(data).header == MessageHeader(COMMAND_MESSAGE_ID, 99, 7)

    def test_repeated_sub_message_merges(self):
        first = ld(2, ld(1, unpacked((1.0,))) + ld(3, unpacked((5.0,))))
        second = ld(2, ld(1, unpacked((2.0,))))
        msg = decode_command(CMD_HEADER + first + second + ld(15, b"\x08\x01") + ld(15, b"\x10\x02"))
        assert msg.command_data == CommandData(joint_position=(1.0, 2.0), joint_torque=(5.0,))
        assert msg.end_of_message_data == b"\x08\x01\x10\x02"

    def test_non_finite_values_kept(self):
        data = CMD_HEADER + ld(2, ld(3, unpacked((math.nan, math.inf, -math.inf))))
        tau = decode_command(data).command_data.joint_torque
        assert math.isnan(tau[0]) and tau[1] == math.inf and tau[2] == -math.inf

    def test_uint32_varint_truncated_like_protobuf(self):
        data = ld(1, vfield(1, COMMAND_MESSAGE_ID) + vfield(2, 2**32 + 5) + vfield(3, 2**64 - 1))
        assert decode_command(data).header == MessageHeader(COMMAND_MESSAGE_ID, 5, 2**32 - 1)


class TestDecodeMonitoring:
    def test_round_trip_full(self):
        msg = full_monitoring()
        out = decode_monitoring(encode_monitoring(msg))
        assert out == msg
        assert isinstance(out.connection_info.session_state, SessionState)
        assert out.robot_info.drive_state[6] is DriveState.TRANSITIONING
        assert out.ipo_data.client_command_mode is ClientCommandMode.TORQUE

    def test_round_trip_minimal(self):
        for msg in [
            MonitoringMessage(MessageHeader(MONITORING_MESSAGE_ID, 0, 0)),
            MonitoringMessage(
                MessageHeader(MONITORING_MESSAGE_ID, 1, 0),
                robot_info=RobotInfo(),
                monitor_data=MonitorData(),
                connection_info=ConnectionInfo(SessionState.IDLE, ConnectionQuality.POOR),
                ipo_data=IpoData(),
                requested_transformations=(b"",),
                end_of_message_data=b"",
            ),
        ]:
            assert decode_monitoring(encode_monitoring(msg)) == msg

    def test_negative_int32_round_trip(self):
        msg = MonitoringMessage(
            MessageHeader(MONITORING_MESSAGE_ID, 0, 0),
            robot_info=RobotInfo(number_of_joints=-2**31, safety_state=-1, drive_state=(-7, 2**31 - 1)),
            ipo_data=IpoData(overlay_type=-3),
        )
        out = decode_monitoring(encode_monitoring(msg))
        assert out == msg
        assert out.robot_info.number_of_joints == -2**31
        # a 5-byte, sign-truncated encoding of -1 reads the same (low 32 bits)
        data = MON_HEADER + ld(2, vfield(1, 0xFFFFFFFF))
        assert decode_monitoring(data).robot_info.number_of_joints == -1

    def test_unknown_enum_kept_as_int(self):
        data = MON_HEADER + ld(4, vfield(1, 9) + vfield(2, 200)) + ld(2, vfield(5, 5) + vfield(7, 2))
        msg = decode_monitoring(data)
        assert msg.connection_info.session_state == 9 and type(msg.connection_info.session_state) is int
        assert msg.connection_info.quality == 200
        assert msg.robot_info.drive_state == (5,)
        assert msg.robot_info.control_mode is ControlMode.JOINT_IMPEDANCE

    def test_packed_equals_unpacked(self):
        def message(jv) -> bytes:
            return MON_HEADER + ld(3, b"".join(ld(f, jv(Q)) for f in range(1, 6))) + ld(5, ld(1, jv(TAU)))

        a, b = decode_monitoring(message(unpacked)), decode_monitoring(message(packed))
        assert a == b
        assert a.monitor_data.external_torque == Q and a.ipo_data.joint_position == TAU

    def test_packed_drive_states(self):
        data = MON_HEADER + ld(2, vfield(5, 2) + ld(5, varint(0) + varint(1) + varint(2**64 - 1)) + vfield(5, 1))
        assert decode_monitoring(data).robot_info.drive_state == (2, 0, 1, -1, 1)

    def test_mixed_joint_values_and_merged_sub_messages(self):
        data = (
            MON_HEADER
            + ld(3, ld(1, unpacked((1.0,)) + packed((2.0,))) + ld(15, vfield(1, 10) + vfield(2, 20)))
            + ld(3, ld(1, packed((3.0,))) + ld(15, vfield(2, 21)))
            + ld(4, vfield(1, 1)) + ld(4, vfield(2, 3))
        )
        msg = decode_monitoring(data)
        assert msg.monitor_data.measured_joint_position == (1.0, 2.0, 3.0)
        assert msg.monitor_data.timestamp == (10, 21)
        assert msg.connection_info == ConnectionInfo(SessionState.MONITORING_WAIT, ConnectionQuality.EXCELLENT)

    def test_requested_transformations_and_end_of_message_raw(self):
        data = MON_HEADER + ld(6, b"\x0a\x01x") + ld(6, b"") + ld(6, b"\xff\xff") + ld(15, b"\x01\x02")
        msg = decode_monitoring(data)
        assert msg.requested_transformations == (b"\x0a\x01x", b"", b"\xff\xff")
        assert msg.end_of_message_data == b"\x01\x02"

    def test_unknown_fields_skipped(self):
        unknown = vfield(8, 1) + dfield(9, 2.0) + tag(13, 5) + b"1234" + ld(14, b"xyz") + vfield(536870911, 3)
        data = (
            unknown
            + MON_HEADER
            + ld(3, unknown + ld(2, unknown + unpacked(TAU)) + ld(15, unknown + vfield(1, 1) + vfield(2, 2)))
            + ld(5, unknown + dfield(12, 0.5))
            + unknown
        )
        msg = decode_monitoring(data)
        assert msg.monitor_data == MonitorData(measured_torque=TAU, timestamp=(1, 2))
        assert msg.ipo_data == IpoData(tracking_performance=0.5)

    def test_wrong_identifier(self):
        with pytest.raises(FriDecodeError, match="message identifier 0x34001 is not a monitoring message"):
            decode_monitoring(encode_command(full_command()))

    def test_non_finite_tracking_performance(self):
        data = MON_HEADER + ld(5, dfield(12, math.nan))
        assert math.isnan(decode_monitoring(data).ipo_data.tracking_performance)

    def test_largest_datagram(self):
        # 1500 bytes: header and one unknown field filling the rest
        pad = MAX_DATAGRAM_BYTES - len(MON_HEADER) - 3
        data = MON_HEADER + tag(14, 2) + varint(pad) + b"\x00" * pad
        assert len(data) == MAX_DATAGRAM_BYTES
        assert decode_monitoring(data).header.sequence_counter == 5


# Malformed datagrams: (decoder, datagram, expected message)
_CMD_BODY = ld(2, ld(1, unpacked((1.0,))))
MALFORMED = [
    ("empty", decode_command, b"", "empty datagram: field 1 \\(header\\) missing"),
    ("too long", decode_monitoring, MON_HEADER + ld(14, b"\x00" * 1490), "datagram of 1504 bytes exceeds the 1500-byte"),
    ("too long bytearray", decode_command, bytearray(1501), "datagram of 1501 bytes exceeds"),
    ("not bytes", decode_command, "0a08", "must be bytes-like, not str"),
    ("truncated varint", decode_command, CMD_HEADER + b"\x08\x80", "truncated varint at byte 11"),
    ("truncated tag", decode_command, CMD_HEADER + b"\x80", "truncated varint at byte 10"),
    ("truncated header varint", decode_command, bytes.fromhex("0a02 0881"), "truncated varint at byte 3"),
    ("varint of 11 bytes", decode_command, CMD_HEADER + b"\x20" + b"\xff" * 10 + b"\x01",
     "varint at byte 11 is longer than 10 bytes"),
    ("length past the end", decode_command, CMD_HEADER + b"\x12\x05\x0a", "field 2 at byte 10: length 5 runs past the end"),
    ("huge length", decode_command, CMD_HEADER + b"\x12" + varint(2**63), "runs past the end"),
    ("nested length past its message", decode_command, CMD_HEADER + b"\x12\x02\x0a\x05" + ld(14, b"\x00" * 10),
     "field 1 at byte 12: length 5 runs past the end of its message \\(0 bytes left\\)"),
    ("group start", decode_command, CMD_HEADER + b"\x1b", "field 3 at byte 10 has wire type 3 \\(group\\)"),
    ("group end", decode_command, CMD_HEADER + b"\x1c", "wire type 4 \\(group\\)"),
    ("wire type 6", decode_command, CMD_HEADER + b"\x1e", "field 3 at byte 10 has invalid wire type 6"),
    ("wire type 7", decode_monitoring, MON_HEADER + b"\x1f", "invalid wire type 7"),
    ("field number 0", decode_command, CMD_HEADER + b"\x00\x00", "invalid field number 0 at byte 10"),
    ("field number 0 in sub-message", decode_command, CMD_HEADER + ld(2, b"\x02\x00"), "invalid field number 0"),
    ("field number too large", decode_command, CMD_HEADER + varint(1 << 32) + b"\x00", "is out of range"),
    ("truncated fixed64", decode_command, CMD_HEADER + b"\x79\x00\x00\x00", "8-byte value runs past the end"),
    ("truncated fixed32", decode_command, CMD_HEADER + b"\x25\x00", "4-byte value runs past the end"),
    ("truncated double", decode_command, CMD_HEADER + ld(2, ld(1, b"\x09\x00\x00\x00\x00")),
     "jointPosition value at byte 14 runs past the end"),
    ("truncated tracking performance", decode_monitoring, MON_HEADER + ld(5, b"\x61\x00\x00"),
     "trackingPerformance at byte 13 runs past the end"),
    ("packed length not multiple of 8", decode_command, CMD_HEADER + ld(2, ld(3, ld(1, b"\x00" * 12))),
     "packed jointTorque at byte 14 has length 12, not a multiple of 8"),
    ("packed in monitor data", decode_monitoring, MON_HEADER + ld(3, ld(5, ld(1, b"\x00" * 7))),
     "packed externalTorque .* length 7, not a multiple of 8"),
    ("truncated packed drive state", decode_monitoring, MON_HEADER + ld(2, ld(5, b"\x01\x80")), "truncated varint"),
    ("header missing", decode_command, _CMD_BODY, "field 1 \\(header\\) missing"),
    ("header with wrong wire type", decode_command, vfield(1, 3) + _CMD_BODY, "field 1 \\(header\\) missing"),
    ("identifier missing", decode_command, ld(1, vfield(2, 1) + vfield(3, 1)), "field 1 \\(messageIdentifier\\) missing"),
    ("sequence counter missing", decode_command, ld(1, vfield(1, COMMAND_MESSAGE_ID) + vfield(3, 1)),
     "field 2 \\(sequenceCounter\\) missing"),
    ("reflected counter missing", decode_monitoring, ld(1, vfield(1, MONITORING_MESSAGE_ID) + vfield(2, 1)),
     "field 3 \\(reflectedSequenceCounter\\) missing"),
    ("session state missing", decode_monitoring, MON_HEADER + ld(4, vfield(2, 1)), "connectionInfo field 1 \\(sessionState\\)"),
    ("quality missing", decode_monitoring, MON_HEADER + ld(4, vfield(1, 1) + vfield(3, 1)),
     "connectionInfo field 2 \\(quality\\) missing"),
    ("timestamp sec missing", decode_monitoring, MON_HEADER + ld(3, ld(15, vfield(2, 1))), "timestamp field 1 \\(sec\\)"),
    ("timestamp nanosec missing", decode_monitoring, MON_HEADER + ld(3, ld(15, b"")), "timestamp field 1 \\(sec\\)"),
    ("timestamp only sec", decode_monitoring, MON_HEADER + ld(3, ld(15, vfield(1, 1))), "timestamp field 2 \\(nanosec\\)"),
    ("wrong identifier", decode_monitoring, header_bytes(0x1234), "message identifier 0x1234 is not a monitoring message"),
]


class TestMalformed:
    @pytest.mark.parametrize("decode, data, match", [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED])
    def test_raises_decode_error(self, decode, data, match):
        with pytest.raises(FriDecodeError, match=match) as info:
            decode(data)
        assert "\n" not in str(info.value)

    def test_decode_error_is_value_error(self):
        assert issubclass(FriDecodeError, ValueError)

    def test_every_truncation_of_valid_messages(self):
        for data, decode in ((encode_monitoring(full_monitoring()), decode_monitoring),
                             (encode_command(full_command()), decode_command)):
            for n in range(len(data)):
                try:
                    decode(data[:n])
                except FriDecodeError:
                    pass


# --------------------------------------------------------------------------- fuzz


def random_doubles(rng: np.random.Generator, n: int) -> tuple[float, ...]:
    values = rng.normal(0.0, 3.0, n)
    if n and rng.random() < 0.05:
        values[rng.integers(n)] = rng.choice([np.nan, np.inf, -np.inf])
    return tuple(float(v) for v in values)


def random_monitoring(rng: np.random.Generator) -> bytes:
    def maybe(p: float = 0.7) -> bool:
        return rng.random() < p

    n = int(rng.integers(0, 8))
    u32 = lambda: int(rng.integers(0, 2**32))  # noqa: E731
    enum = lambda k: int(rng.integers(-2, k + 2))  # noqa: E731  (includes unknown numbers)
    jv = lambda: random_doubles(rng, n) if maybe() else None  # noqa: E731
    msg = MonitoringMessage(
        MessageHeader(MONITORING_MESSAGE_ID, u32(), u32()),
        robot_info=RobotInfo(n, enum(4), tuple(enum(3) for _ in range(n)), enum(3), enum(4)) if maybe() else None,
        monitor_data=MonitorData(jv(), jv(), jv(), jv(), jv(), (u32(), u32()) if maybe() else None) if maybe() else None,
        connection_info=ConnectionInfo(enum(5), enum(4), u32() if maybe() else None, u32() if maybe() else None)
        if maybe() else None,
        ipo_data=IpoData(jv(), enum(4), enum(3), float(rng.random())) if maybe() else None,
        requested_transformations=tuple(rng.bytes(int(rng.integers(0, 20))) for _ in range(int(rng.integers(0, 3)))),
        end_of_message_data=rng.bytes(int(rng.integers(0, 10))) if maybe(0.3) else None,
    )
    return encode_monitoring(msg)


def random_command(rng: np.random.Generator) -> bytes:
    n = int(rng.integers(0, 8))
    data = None
    if rng.random() < 0.8:
        data = CommandData(
            random_doubles(rng, n) if rng.random() < 0.7 else None,
            random_doubles(rng, n) if rng.random() < 0.7 else None,
            random_doubles(rng, int(rng.integers(0, 7))) if rng.random() < 0.3 else None,
        )
    header = MessageHeader(COMMAND_MESSAGE_ID, int(rng.integers(0, 2**32)), int(rng.integers(0, 2**32)))
    return encode_command(CommandMessage(header, data, rng.bytes(3) if rng.random() < 0.2 else None))


def top_level_fields(data: bytes) -> list[tuple[int, int]]:
    """Spans of the top-level fields of a valid encoded message (all length-delimited, short tags)."""
    spans, pos = [], 0
    while pos < len(data):
        start = pos
        pos += 1
        n = shift = 0
        while True:
            b = data[pos]
            pos += 1
            n |= (b & 0x7F) << shift
            shift += 7
            if b < 0x80:
                break
        pos += n
        spans.append((start, pos))
    return spans


def mutate(rng: np.random.Generator, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(0, 6))
        n = len(buf)
        if kind == 0 and n:  # bit flip
            buf[int(rng.integers(n))] ^= 1 << int(rng.integers(8))
        elif kind == 1:  # truncation
            del buf[int(rng.integers(0, n + 1)):]
        elif kind == 2:  # byte insertion
            buf.insert(int(rng.integers(0, n + 1)), int(rng.integers(256)))
        elif kind == 3 and n:  # byte deletion
            del buf[int(rng.integers(n))]
        elif kind == 4:  # duplicated top-level field, at a random field boundary
            try:
                spans = top_level_fields(bytes(buf))
            except IndexError:  # already mutated beyond the simple layout
                continue
            if spans:
                a, b = spans[int(rng.integers(len(spans)))]
                at = spans[int(rng.integers(len(spans)))][1]
                buf[at:at] = buf[a:b]
        elif kind == 5 and n:  # duplicated random slice
            a = int(rng.integers(n))
            b = int(rng.integers(a, min(n, a + 40) + 1))
            buf[b:b] = buf[a:b]
    return bytes(buf)


class TestFuzz:
    TOTAL = 100_000

    def test_random_and_mutated_datagrams(self):
        rng = np.random.default_rng(20240607)
        bases = [(random_monitoring(rng), decode_monitoring) for _ in range(150)]
        bases += [(random_command(rng), decode_command) for _ in range(150)]
        for data, decode in bases:  # every base is valid
            decode(data)

        runs = 0
        random_ok = random_err = mutated_ok = mutated_err = 0
        half = self.TOTAL // 2
        lengths = rng.integers(0, 1601, half)
        for i in range(half):
            data = rng.bytes(int(lengths[i]))
            if i % 20 == 0 and len(data) > 2:  # random tails after a valid header reach the sub-message parsers
                data = (MON_HEADER if i % 40 == 0 else CMD_HEADER) + data
            for decode in (decode_monitoring, decode_command):
                try:
                    decode(data)
                    random_ok += 1
                except FriDecodeError:
                    random_err += 1
            runs += 1
        picks = rng.integers(0, len(bases), half)
        for i in range(half):
            base, decode = bases[int(picks[i])]
            data = mutate(rng, base)
            try:
                decode(data)
                mutated_ok += 1
            except FriDecodeError:
                mutated_err += 1
            other = decode_command if decode is decode_monitoring else decode_monitoring
            try:
                other(data)
            except FriDecodeError:
                pass
            runs += 1

        assert runs == self.TOTAL
        assert random_ok + random_err == 2 * half
        assert mutated_ok + mutated_err == half
        assert mutated_ok > 0 and mutated_err > 0
        assert random_err > 0
        print(f"fuzz: {runs} datagrams; random ok/err {random_ok}/{random_err}, "
              f"mutated ok/err {mutated_ok}/{mutated_err}")
