"""KUKA Fast Robot Interface (FRI): the messages and the client end of a session.

Public API
----------
The names of :mod:`iiwa_ident.fri._protocol` (the messages on the protobuf
library and the checks protobuf does not make; the schema is
``messages.proto``), and:

DEFAULT_PORT, COMMANDING_STATES, ConnectionStats, FriConnection, parse_host_port
    The client end of a session (:mod:`iiwa_ident.fri._connection`).
FriRobot, required_settings
    One joint behind FRI as a robot interface (:mod:`iiwa_ident.fri._robot`).

The deployed controller that runs over it is :mod:`iiwa_ident.runtime`; the
robot side, for tests and runs without a robot, :mod:`iiwa_ident.emulator`.
"""

from iiwa_ident.fri import _protocol
from iiwa_ident.fri._connection import COMMANDING_STATES, DEFAULT_PORT, ConnectionStats, FriConnection, parse_host_port
from iiwa_ident.fri._protocol import *  # noqa: F401,F403  (the names of _protocol.__all__)
from iiwa_ident.fri._robot import FriRobot, required_settings

__all__ = list(_protocol.__all__) + ["DEFAULT_PORT", "COMMANDING_STATES", "ConnectionStats", "FriConnection",
                                     "parse_host_port", "FriRobot", "required_settings"]
