"""An ATI Net F/T force/torque sensor over its Raw Data Transfer (RDT) UDP protocol.

The paper measures the outer loop's gain margin with an F/T sensor on the end effector: ``tau_r =
kappa tau_ext`` with the hand's torque about the joint's axis. This package reads such a sensor in
the 1 kHz loop, and emulates one for runs without a robot.

Public API
----------
RDT_PORT, RdtCommand, RdtRecord, RdtError, Calibration, encode_request, decode_request, encode_record,
decode_record
    The protocol's datagrams (:mod:`iiwa_ident.netft._rdt`).
JointAxisProjection
    The sensor's wrench about a joint's axis, from the robot's description or a lever arm
    (:mod:`iiwa_ident.netft._projection`).
NetFtSensor, SensorStats
    The client: one torque per control cycle, lost and late records counted, a fault past a limit
    (:mod:`iiwa_ident.netft._sensor`).
NetFtSettings, RdtServer, EmulatedNetFt
    The sensor side, for the emulator (:mod:`iiwa_ident.netft._server`).
"""

from iiwa_ident.netft._projection import JointAxisProjection
from iiwa_ident.netft._rdt import (
    RDT_PORT,
    RECORD_BYTES,
    REQUEST_BYTES,
    Calibration,
    RdtCommand,
    RdtError,
    RdtRecord,
    decode_record,
    decode_request,
    encode_record,
    encode_request,
)
from iiwa_ident.netft._sensor import NetFtSensor, SensorStats
from iiwa_ident.netft._server import EmulatedNetFt, NetFtSettings, RdtServer

__all__ = ["RDT_PORT", "RECORD_BYTES", "REQUEST_BYTES", "RdtCommand", "RdtRecord", "RdtError", "Calibration",
           "encode_request", "decode_request", "encode_record", "decode_record", "JointAxisProjection",
           "NetFtSensor", "SensorStats", "NetFtSettings", "RdtServer", "EmulatedNetFt"]
