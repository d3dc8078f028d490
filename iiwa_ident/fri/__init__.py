"""KUKA Fast Robot Interface (FRI): the UDP messages on the protobuf library.

The public names are those of :mod:`iiwa_ident.fri.protocol`, which decodes
and encodes the monitoring messages the robot sends and the command messages
a client answers with, and checks what protobuf does not (identifiers, size,
required fields, joint counts, finite numbers); the schema is
``messages.proto``. The client (:mod:`~iiwa_ident.fri.connection`,
:mod:`~iiwa_ident.fri.robot`), the controller runtime
(:mod:`~iiwa_ident.fri.runtime`) and the robot emulator
(:mod:`~iiwa_ident.fri.emulator`) are imported from their modules.
"""

from iiwa_ident.fri import protocol as _protocol
from iiwa_ident.fri.protocol import *  # noqa: F401,F403  (the names of protocol.__all__)

__all__ = list(_protocol.__all__)
