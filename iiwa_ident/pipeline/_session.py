"""An FRI session for one closed-loop run: the robot, or the emulator on loopback (shared by the validation
runs and the kappa sweep)."""

from __future__ import annotations

import socket

from iiwa_ident.fri import FriRobot

__all__ = ["LOCKSTEP_GUARD_S", "free_udp_port", "fri_robot", "LateFriRobot"]


def free_udp_port() -> int:
    """A UDP port on the loopback interface that is free right now and not handed out before by this process (the
    system may give a port just closed again: two calls for one session's FRI and F/T sockets, opened later,
    must not get the same one)."""
    for _ in range(64):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port not in _HANDED:
            _HANDED.add(port)
            return port
    return port


#: The ports :func:`free_udp_port` gave.
_HANDED: set[int] = set()


#: Lockstep: the emulator takes a client that has not answered for this long [s] for gone. Each run has
#: its own emulator, stopped when the run has ended, so this only ends a run whose client hangs.
LOCKSTEP_GUARD_S = 30.0


def fri_robot(host: str, port: int, joint: int, robot_model: str, lockstep: bool) -> FriRobot:
    # In lockstep the robot is never silent during a session: only a stalled machine delays a message.
    return FriRobot(host, joint, robot_model, port=port, connect_timeout_s=30.0,
                    message_timeout_s=LOCKSTEP_GUARD_S if lockstep else 0.1)


class LateFriRobot:
    """An FRI robot whose socket opens only when the run starts.

    :func:`run_controller` starts its log-writer process before the session;
    a socket opened earlier would queue the robot's messages meanwhile and the
    loop would start behind by that backlog.
    """

    source = "robot"
    sample_time_s = 1e-3

    def __init__(self, host: str, port: int, joint: int, robot_model: str, lockstep: bool) -> None:
        self._args = (host, port, joint, robot_model, lockstep)
        self.joint = joint
        self._robot: FriRobot | None = None

    def start(self):
        self._robot = fri_robot(*self._args)
        return self._robot.start()

    @property
    def pose(self) -> tuple[float, ...] | None:
        """The arm's measured pose once the session runs (:attr:`FriRobot.pose`)."""
        return self._robot.pose if self._robot is not None else None

    def stop(self) -> None:
        if self._robot is not None:
            self._robot.stop()

    def describe(self) -> dict:
        return self._robot.describe() if self._robot is not None else {}

    def __getattr__(self, name: str):
        if self._robot is None:
            raise AttributeError(name)
        return getattr(self._robot, name)


