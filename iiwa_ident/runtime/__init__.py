"""The deployed controller's runtime: a controller config executed once per 1 kHz cycle.

Public API
----------
ControllerRuntime, Watchdog, RunReport, run_controller, LOG_SIGNALS
    The cycle, the link watchdog and the run with its log
    (:mod:`iiwa_ident.runtime._run`).
Task, TaskInput, TASKS, make_task, and the task classes
    What the runtime tracks (:mod:`iiwa_ident.runtime._tasks`).
KappaSweep, SweepSettings, InstabilityDetector
    The outer loop's gain margin measured live (:mod:`iiwa_ident.runtime._kappa`).

The runtime drives any :class:`~iiwa_ident.robot.RobotInterface`: the robot
through :class:`iiwa_ident.fri.FriRobot`, the emulator the same way, or the
simulated joint directly.
"""

from iiwa_ident.runtime._kappa import InstabilityDetector, KappaSweep, SweepSettings
from iiwa_ident.runtime._run import LOG_SIGNALS, ControllerRuntime, RunReport, Watchdog, run_controller
from iiwa_ident.runtime._tasks import (
    TASKS,
    ChirpTask,
    ConstantTask,
    KappaTask,
    MultisineTask,
    SineTask,
    StepTask,
    Task,
    TaskInput,
    ZeroTask,
    make_task,
)

__all__ = ["LOG_SIGNALS", "ControllerRuntime", "RunReport", "Watchdog", "run_controller", "TASKS", "ChirpTask",
           "ConstantTask", "KappaTask", "MultisineTask", "SineTask", "StepTask", "Task", "TaskInput", "ZeroTask",
           "make_task", "KappaSweep", "SweepSettings", "InstabilityDetector"]
