"""KUKA Fast Robot Interface (FRI): the messages, the client, the controller runtime and the robot emulator.

Public API
----------
The names of :mod:`iiwa_ident.fri.protocol` (the messages on the protobuf
library and the checks protobuf does not make; the schema is
``messages.proto``), and:

DEFAULT_PORT, COMMANDING_STATES, FriConnection, parse_host_port
    The client end of a session (:mod:`iiwa_ident.fri.connection`).
FriRobot, required_settings
    One joint behind FRI as a robot interface (:mod:`iiwa_ident.fri.robot`).
ControllerRuntime, Watchdog, RunReport, run_controller
    The deployed controller's 1 kHz cycle and run (:mod:`iiwa_ident.fri.runtime`).
Task, TaskInput, TASKS, make_task
    What the runtime tracks (:mod:`iiwa_ident.fri.tasks`).
EmulatorConfig, EmulatorReport, Faults, QualityThresholds, RobotEmulator, EmulatorProcess, spawn_emulator, AGENTS,
DEFAULT_JOINT_POSITIONS
    The robot side, for tests and runs without a robot (:mod:`iiwa_ident.fri.emulator`).

The modules beyond the protocol are imported when one of their names is
first used, so a process that only exchanges messages (the emulator's, a
codec benchmark) does not load the controller design.
"""

from importlib import import_module

from iiwa_ident.fri import protocol as _protocol
from iiwa_ident.fri.protocol import *  # noqa: F401,F403  (the names of protocol.__all__)

_LAZY = {
    "connection": ("DEFAULT_PORT", "COMMANDING_STATES", "FriConnection", "parse_host_port"),
    "robot": ("FriRobot", "required_settings"),
    "runtime": ("ControllerRuntime", "Watchdog", "RunReport", "run_controller"),
    "tasks": ("Task", "TaskInput", "TASKS", "make_task"),
    "emulator": ("EmulatorConfig", "EmulatorReport", "Faults", "QualityThresholds", "RobotEmulator",
                 "EmulatorProcess", "spawn_emulator", "AGENTS", "DEFAULT_JOINT_POSITIONS"),
}
_MODULE_OF = {name: module for module, names in _LAZY.items() for name in names}

__all__ = list(_protocol.__all__) + list(_MODULE_OF)


def __getattr__(name: str):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
