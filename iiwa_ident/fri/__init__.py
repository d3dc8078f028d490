"""KUKA Fast Robot Interface (FRI): the UDP message codec.

:mod:`iiwa_ident.fri.protocol` encodes and decodes the monitoring messages
the robot sends and the command messages a client answers with.
"""

from iiwa_ident.fri.protocol import (
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
