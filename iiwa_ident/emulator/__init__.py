"""The robot side of FRI for tests and runs without a robot: a KUKA controller emulated over UDP.

:class:`RobotEmulator` plays the robot controller towards an FRI client,
with one :class:`~iiwa_ident.sim.SimulatedJoint` behind it, the session
states, the robot's safety stop, injected network faults and a recorded
dataset; :func:`spawn_emulator` runs it in a process of its own.

Public API
----------
EmulatorConfig, Faults, QualityThresholds, check_config, DEFAULT_JOINT_POSITIONS, AGENTS
    The settings (:mod:`iiwa_ident.emulator._config`).
RobotEmulator, BRAKE_SETTLE_S
    The robot side: session, safety, cycle (:mod:`iiwa_ident.emulator._robot_side`).
OVERRUN_S, RESEND_S
    Real time or lockstep (:mod:`iiwa_ident.emulator._clocks`).
connection_quality
    How the quality is judged (:mod:`iiwa_ident.emulator._quality`).
EmulatorReport
    What a run reports (:mod:`iiwa_ident.emulator._report`).
EmulatorProcess, spawn_emulator
    The emulator in its own process (:mod:`iiwa_ident.emulator._process`).

The injected faults are applied by :mod:`iiwa_ident.emulator._faults`.
"""

from iiwa_ident.emulator._clocks import OVERRUN_S, RESEND_S
from iiwa_ident.emulator._config import (
                                        AGENTS,
                                        DEFAULT_JOINT_POSITIONS,
                                        EmulatorConfig,
                                        Faults,
                                        QualityThresholds,
                                        check_config,
)
from iiwa_ident.emulator._process import EmulatorProcess, spawn_emulator
from iiwa_ident.emulator._quality import connection_quality
from iiwa_ident.emulator._report import EmulatorReport
from iiwa_ident.emulator._robot_side import BRAKE_SETTLE_S, RobotEmulator

__all__ = ["AGENTS", "BRAKE_SETTLE_S", "DEFAULT_JOINT_POSITIONS", "OVERRUN_S", "RESEND_S", "EmulatorConfig",
           "EmulatorProcess", "EmulatorReport", "Faults", "QualityThresholds", "RobotEmulator", "check_config",
           "connection_quality", "spawn_emulator"]
