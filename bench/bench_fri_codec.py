"""Per-message time of the FRI codec, as run in the 1 kHz loop.

Times decoding a full monitoring message (5 JointValues of 7 joints, robot
info with 7 drive states, connection info, ipo data, timestamp) and encoding
a command with 7 positions and 7 torques, plus the two opposite directions.

Run: ``.venv/bin/python bench/bench_fri_codec.py``
"""

from __future__ import annotations

import time

from iiwa_ident.fri import (
    COMMAND_MESSAGE_ID,
    MONITORING_MESSAGE_ID,
    ClientCommandMode,
    CommandMessage,
    ConnectionQuality,
    ControlMode,
    DriveState,
    MonitoringMessage,
    OperationMode,
    OverlayType,
    SafetyState,
    SessionState,
    decode_command,
    decode_monitoring,
    encode_command,
    encode_monitoring,
)

N = 20000
JOINTS = 7


def full_monitoring() -> MonitoringMessage:
    q = [0.1 * (i + 1) for i in range(JOINTS)]
    tau = [-2.5 * (i + 1) for i in range(JOINTS)]
    return MonitoringMessage(
        header=dict(message_identifier=MONITORING_MESSAGE_ID, sequence_counter=123456,
                    reflected_sequence_counter=123455),
        robot_info=dict(number_of_joints=JOINTS, safety_state=SafetyState.NORMAL_OPERATION,
                        drive_state=(DriveState.ACTIVE,) * JOINTS, operation_mode=OperationMode.T1,
                        control_mode=ControlMode.JOINT_IMPEDANCE),
        monitor_data=dict(measured_joint_position=dict(value=q), measured_torque=dict(value=tau),
                          commanded_joint_position=dict(value=q), commanded_torque=dict(value=tau),
                          external_torque=dict(value=tau), timestamp=dict(sec=1700000000, nanosec=999000000)),
        connection_info=dict(session_state=SessionState.COMMANDING_ACTIVE, quality=ConnectionQuality.EXCELLENT,
                             send_period_ms=1, receive_multiplier=1),
        ipo_data=dict(joint_position=dict(value=q), client_command_mode=ClientCommandMode.TORQUE,
                      overlay_type=OverlayType.JOINT, tracking_performance=1.0),
    )


def command() -> CommandMessage:
    return CommandMessage(
        header=dict(message_identifier=COMMAND_MESSAGE_ID, sequence_counter=123456, reflected_sequence_counter=123456),
        command_data=dict(joint_position=dict(value=[0.1 * i for i in range(JOINTS)]),
                          joint_torque=dict(value=[0.5 * i for i in range(JOINTS)])),
    )


def parse_only(data: bytes) -> MonitoringMessage:
    """protobuf's parser alone, without the checks: what the checks cost is the difference."""
    msg = MonitoringMessage()
    msg.ParseFromString(data)
    return msg


def timed(fn, arg) -> tuple[float, float]:
    """Median and 99th percentile of ``fn(arg)`` over N calls [us]."""
    clock = time.perf_counter_ns
    for _ in range(1000):
        fn(arg)
    times = []
    append = times.append
    for _ in range(N):
        t0 = clock()
        fn(arg)
        append(clock() - t0)
    times.sort()
    return times[N // 2] / 1e3, times[min(N - 1, int(0.99 * N))] / 1e3


def main() -> None:
    mon = full_monitoring()
    cmd = command()
    mon_bytes = encode_monitoring(mon)
    cmd_bytes = encode_command(cmd)
    print(f"monitoring message {len(mon_bytes)} bytes, command message {len(cmd_bytes)} bytes, {N} iterations")
    for label, fn, arg in (
        ("decode_monitoring (full)", decode_monitoring, mon_bytes),
        ("encode_command (7 q + 7 tau)", encode_command, cmd),
        ("encode_monitoring (full)", encode_monitoring, mon),
        ("decode_command (7 q + 7 tau)", decode_command, cmd_bytes),
        ("ParseFromString only (full)", parse_only, mon_bytes),
    ):
        median, p99 = timed(fn, arg)
        print(f"{label:30s} median {median:6.2f} us   p99 {p99:6.2f} us")


if __name__ == "__main__":
    main()
