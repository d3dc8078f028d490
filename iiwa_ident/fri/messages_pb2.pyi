from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SessionState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SESSION_STATE_IDLE: _ClassVar[SessionState]
    SESSION_STATE_MONITORING_WAIT: _ClassVar[SessionState]
    SESSION_STATE_MONITORING_READY: _ClassVar[SessionState]
    SESSION_STATE_COMMANDING_WAIT: _ClassVar[SessionState]
    SESSION_STATE_COMMANDING_ACTIVE: _ClassVar[SessionState]

class ConnectionQuality(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CONNECTION_QUALITY_POOR: _ClassVar[ConnectionQuality]
    CONNECTION_QUALITY_FAIR: _ClassVar[ConnectionQuality]
    CONNECTION_QUALITY_GOOD: _ClassVar[ConnectionQuality]
    CONNECTION_QUALITY_EXCELLENT: _ClassVar[ConnectionQuality]

class SafetyState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SAFETY_STATE_NORMAL_OPERATION: _ClassVar[SafetyState]
    SAFETY_STATE_SAFETY_STOP_LEVEL_0: _ClassVar[SafetyState]
    SAFETY_STATE_SAFETY_STOP_LEVEL_1: _ClassVar[SafetyState]
    SAFETY_STATE_SAFETY_STOP_LEVEL_2: _ClassVar[SafetyState]

class OperationMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    OPERATION_MODE_T1: _ClassVar[OperationMode]
    OPERATION_MODE_T2: _ClassVar[OperationMode]
    OPERATION_MODE_AUT: _ClassVar[OperationMode]

class DriveState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DRIVE_STATE_OFF: _ClassVar[DriveState]
    DRIVE_STATE_TRANSITIONING: _ClassVar[DriveState]
    DRIVE_STATE_ACTIVE: _ClassVar[DriveState]

class ControlMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CONTROL_MODE_POSITION: _ClassVar[ControlMode]
    CONTROL_MODE_CARTESIAN_IMPEDANCE: _ClassVar[ControlMode]
    CONTROL_MODE_JOINT_IMPEDANCE: _ClassVar[ControlMode]
    CONTROL_MODE_NO_CONTROL: _ClassVar[ControlMode]

class ClientCommandMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CLIENT_COMMAND_MODE_NO_COMMAND: _ClassVar[ClientCommandMode]
    CLIENT_COMMAND_MODE_POSITION: _ClassVar[ClientCommandMode]
    CLIENT_COMMAND_MODE_WRENCH: _ClassVar[ClientCommandMode]
    CLIENT_COMMAND_MODE_TORQUE: _ClassVar[ClientCommandMode]

class OverlayType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    OVERLAY_TYPE_NO_OVERLAY: _ClassVar[OverlayType]
    OVERLAY_TYPE_JOINT: _ClassVar[OverlayType]
    OVERLAY_TYPE_CARTESIAN: _ClassVar[OverlayType]
SESSION_STATE_IDLE: SessionState
SESSION_STATE_MONITORING_WAIT: SessionState
SESSION_STATE_MONITORING_READY: SessionState
SESSION_STATE_COMMANDING_WAIT: SessionState
SESSION_STATE_COMMANDING_ACTIVE: SessionState
CONNECTION_QUALITY_POOR: ConnectionQuality
CONNECTION_QUALITY_FAIR: ConnectionQuality
CONNECTION_QUALITY_GOOD: ConnectionQuality
CONNECTION_QUALITY_EXCELLENT: ConnectionQuality
SAFETY_STATE_NORMAL_OPERATION: SafetyState
SAFETY_STATE_SAFETY_STOP_LEVEL_0: SafetyState
SAFETY_STATE_SAFETY_STOP_LEVEL_1: SafetyState
SAFETY_STATE_SAFETY_STOP_LEVEL_2: SafetyState
OPERATION_MODE_T1: OperationMode
OPERATION_MODE_T2: OperationMode
OPERATION_MODE_AUT: OperationMode
DRIVE_STATE_OFF: DriveState
DRIVE_STATE_TRANSITIONING: DriveState
DRIVE_STATE_ACTIVE: DriveState
CONTROL_MODE_POSITION: ControlMode
CONTROL_MODE_CARTESIAN_IMPEDANCE: ControlMode
CONTROL_MODE_JOINT_IMPEDANCE: ControlMode
CONTROL_MODE_NO_CONTROL: ControlMode
CLIENT_COMMAND_MODE_NO_COMMAND: ClientCommandMode
CLIENT_COMMAND_MODE_POSITION: ClientCommandMode
CLIENT_COMMAND_MODE_WRENCH: ClientCommandMode
CLIENT_COMMAND_MODE_TORQUE: ClientCommandMode
OVERLAY_TYPE_NO_OVERLAY: OverlayType
OVERLAY_TYPE_JOINT: OverlayType
OVERLAY_TYPE_CARTESIAN: OverlayType

class JointValues(_message.Message):
    __slots__ = ("value",)
    VALUE_FIELD_NUMBER: _ClassVar[int]
    value: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, value: _Optional[_Iterable[float]] = ...) -> None: ...

class CartesianVector(_message.Message):
    __slots__ = ("element",)
    ELEMENT_FIELD_NUMBER: _ClassVar[int]
    element: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, element: _Optional[_Iterable[float]] = ...) -> None: ...

class TimeStamp(_message.Message):
    __slots__ = ("sec", "nanosec")
    SEC_FIELD_NUMBER: _ClassVar[int]
    NANOSEC_FIELD_NUMBER: _ClassVar[int]
    sec: int
    nanosec: int
    def __init__(self, sec: _Optional[int] = ..., nanosec: _Optional[int] = ...) -> None: ...

class MessageHeader(_message.Message):
    __slots__ = ("message_identifier", "sequence_counter", "reflected_sequence_counter")
    MESSAGE_IDENTIFIER_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_COUNTER_FIELD_NUMBER: _ClassVar[int]
    REFLECTED_SEQUENCE_COUNTER_FIELD_NUMBER: _ClassVar[int]
    message_identifier: int
    sequence_counter: int
    reflected_sequence_counter: int
    def __init__(self, message_identifier: _Optional[int] = ..., sequence_counter: _Optional[int] = ..., reflected_sequence_counter: _Optional[int] = ...) -> None: ...

class ConnectionInfo(_message.Message):
    __slots__ = ("session_state", "quality", "send_period_ms", "receive_multiplier")
    SESSION_STATE_FIELD_NUMBER: _ClassVar[int]
    QUALITY_FIELD_NUMBER: _ClassVar[int]
    SEND_PERIOD_MS_FIELD_NUMBER: _ClassVar[int]
    RECEIVE_MULTIPLIER_FIELD_NUMBER: _ClassVar[int]
    session_state: SessionState
    quality: ConnectionQuality
    send_period_ms: int
    receive_multiplier: int
    def __init__(self, session_state: _Optional[_Union[SessionState, str]] = ..., quality: _Optional[_Union[ConnectionQuality, str]] = ..., send_period_ms: _Optional[int] = ..., receive_multiplier: _Optional[int] = ...) -> None: ...

class RobotInfo(_message.Message):
    __slots__ = ("number_of_joints", "safety_state", "drive_state", "operation_mode", "control_mode")
    NUMBER_OF_JOINTS_FIELD_NUMBER: _ClassVar[int]
    SAFETY_STATE_FIELD_NUMBER: _ClassVar[int]
    DRIVE_STATE_FIELD_NUMBER: _ClassVar[int]
    OPERATION_MODE_FIELD_NUMBER: _ClassVar[int]
    CONTROL_MODE_FIELD_NUMBER: _ClassVar[int]
    number_of_joints: int
    safety_state: SafetyState
    drive_state: _containers.RepeatedScalarFieldContainer[DriveState]
    operation_mode: OperationMode
    control_mode: ControlMode
    def __init__(self, number_of_joints: _Optional[int] = ..., safety_state: _Optional[_Union[SafetyState, str]] = ..., drive_state: _Optional[_Iterable[_Union[DriveState, str]]] = ..., operation_mode: _Optional[_Union[OperationMode, str]] = ..., control_mode: _Optional[_Union[ControlMode, str]] = ...) -> None: ...

class MonitorData(_message.Message):
    __slots__ = ("measured_joint_position", "measured_torque", "commanded_joint_position", "commanded_torque", "external_torque", "timestamp")
    MEASURED_JOINT_POSITION_FIELD_NUMBER: _ClassVar[int]
    MEASURED_TORQUE_FIELD_NUMBER: _ClassVar[int]
    COMMANDED_JOINT_POSITION_FIELD_NUMBER: _ClassVar[int]
    COMMANDED_TORQUE_FIELD_NUMBER: _ClassVar[int]
    EXTERNAL_TORQUE_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    measured_joint_position: JointValues
    measured_torque: JointValues
    commanded_joint_position: JointValues
    commanded_torque: JointValues
    external_torque: JointValues
    timestamp: TimeStamp
    def __init__(self, measured_joint_position: _Optional[_Union[JointValues, _Mapping]] = ..., measured_torque: _Optional[_Union[JointValues, _Mapping]] = ..., commanded_joint_position: _Optional[_Union[JointValues, _Mapping]] = ..., commanded_torque: _Optional[_Union[JointValues, _Mapping]] = ..., external_torque: _Optional[_Union[JointValues, _Mapping]] = ..., timestamp: _Optional[_Union[TimeStamp, _Mapping]] = ...) -> None: ...

class IpoData(_message.Message):
    __slots__ = ("joint_position", "client_command_mode", "overlay_type", "tracking_performance")
    JOINT_POSITION_FIELD_NUMBER: _ClassVar[int]
    CLIENT_COMMAND_MODE_FIELD_NUMBER: _ClassVar[int]
    OVERLAY_TYPE_FIELD_NUMBER: _ClassVar[int]
    TRACKING_PERFORMANCE_FIELD_NUMBER: _ClassVar[int]
    joint_position: JointValues
    client_command_mode: ClientCommandMode
    overlay_type: OverlayType
    tracking_performance: float
    def __init__(self, joint_position: _Optional[_Union[JointValues, _Mapping]] = ..., client_command_mode: _Optional[_Union[ClientCommandMode, str]] = ..., overlay_type: _Optional[_Union[OverlayType, str]] = ..., tracking_performance: _Optional[float] = ...) -> None: ...

class Transformation(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class EndOfMessageData(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class MonitoringMessage(_message.Message):
    __slots__ = ("header", "robot_info", "monitor_data", "connection_info", "ipo_data", "requested_transformations", "end_of_message_data")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    ROBOT_INFO_FIELD_NUMBER: _ClassVar[int]
    MONITOR_DATA_FIELD_NUMBER: _ClassVar[int]
    CONNECTION_INFO_FIELD_NUMBER: _ClassVar[int]
    IPO_DATA_FIELD_NUMBER: _ClassVar[int]
    REQUESTED_TRANSFORMATIONS_FIELD_NUMBER: _ClassVar[int]
    END_OF_MESSAGE_DATA_FIELD_NUMBER: _ClassVar[int]
    header: MessageHeader
    robot_info: RobotInfo
    monitor_data: MonitorData
    connection_info: ConnectionInfo
    ipo_data: IpoData
    requested_transformations: _containers.RepeatedCompositeFieldContainer[Transformation]
    end_of_message_data: EndOfMessageData
    def __init__(self, header: _Optional[_Union[MessageHeader, _Mapping]] = ..., robot_info: _Optional[_Union[RobotInfo, _Mapping]] = ..., monitor_data: _Optional[_Union[MonitorData, _Mapping]] = ..., connection_info: _Optional[_Union[ConnectionInfo, _Mapping]] = ..., ipo_data: _Optional[_Union[IpoData, _Mapping]] = ..., requested_transformations: _Optional[_Iterable[_Union[Transformation, _Mapping]]] = ..., end_of_message_data: _Optional[_Union[EndOfMessageData, _Mapping]] = ...) -> None: ...

class CommandData(_message.Message):
    __slots__ = ("joint_position", "cartesian_wrench_feed_forward", "joint_torque")
    JOINT_POSITION_FIELD_NUMBER: _ClassVar[int]
    CARTESIAN_WRENCH_FEED_FORWARD_FIELD_NUMBER: _ClassVar[int]
    JOINT_TORQUE_FIELD_NUMBER: _ClassVar[int]
    joint_position: JointValues
    cartesian_wrench_feed_forward: CartesianVector
    joint_torque: JointValues
    def __init__(self, joint_position: _Optional[_Union[JointValues, _Mapping]] = ..., cartesian_wrench_feed_forward: _Optional[_Union[CartesianVector, _Mapping]] = ..., joint_torque: _Optional[_Union[JointValues, _Mapping]] = ...) -> None: ...

class CommandMessage(_message.Message):
    __slots__ = ("header", "command_data", "end_of_message_data")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    COMMAND_DATA_FIELD_NUMBER: _ClassVar[int]
    END_OF_MESSAGE_DATA_FIELD_NUMBER: _ClassVar[int]
    header: MessageHeader
    command_data: CommandData
    end_of_message_data: EndOfMessageData
    def __init__(self, header: _Optional[_Union[MessageHeader, _Mapping]] = ..., command_data: _Optional[_Union[CommandData, _Mapping]] = ..., end_of_message_data: _Optional[_Union[EndOfMessageData, _Mapping]] = ...) -> None: ...
