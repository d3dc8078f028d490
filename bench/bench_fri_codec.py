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
    CommandData,
    CommandMessage,
    ConnectionInfo,
    ConnectionQuality,
    ControlMode,
    DriveState,
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

N = 20000
JOINTS = 7


def full_monitoring() -> MonitoringMessage:
    q = tuple(0.1 * (i + 1) for i in range(JOINTS))
    tau = tuple(-2.5 * (i + 1) for i in range(JOINTS))
    return MonitoringMessage(
        header=MessageHeader(MONITORING_MESSAGE_ID, 123456, 123455),
        robot_info=RobotInfo(JOINTS, SafetyState.NORMAL_OPERATION, (DriveState.ACTIVE,) * JOINTS,
                             OperationMode.T1, ControlMode.JOINT_IMPEDANCE),
        monitor_data=MonitorData(q, tau, q, tau, tau, (1700000000, 999000000)),
        connection_info=ConnectionInfo(SessionState.COMMANDING_ACTIVE, ConnectionQuality.EXCELLENT, 1, 1),
        ipo_data=IpoData(q, ClientCommandMode.TORQUE, OverlayType.JOINT, 1.0),
    )


def command() -> CommandMessage:
    return CommandMessage(
        MessageHeader(COMMAND_MESSAGE_ID, 123456, 123456),
        CommandData(joint_position=tuple(0.1 * i for i in range(JOINTS)),
                    joint_torque=tuple(0.5 * i for i in range(JOINTS))),
    )


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
    ):
        median, p99 = timed(fn, arg)
        print(f"{label:30s} median {median:6.2f} us   p99 {p99:6.2f} us")


if __name__ == "__main__":
    main()
