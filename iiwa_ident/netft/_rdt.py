"""ATI Net F/T Raw Data Transfer (RDT): the UDP records a Net F/T streams, encoded and decoded.

A client sends an 8-byte request to the sensor's UDP port 49152::

    uint16 command_header = 0x1234
    uint16 command        (0x0000 stop streaming, 0x0002 start real-time streaming, ...)
    uint32 sample_count   (records to send; 0 = until stopped)

and the sensor answers each of its output samples with a 36-byte record::

    uint32 rdt_sequence   (one per RDT record sent)
    uint32 ft_sequence    (the sensor's internal sample counter)
    uint32 status         (0: healthy; any bit set: a fault the sensor reports)
    int32  Fx, Fy, Fz, Tx, Ty, Tz   (counts)

all in network byte order (ATI, "Net F/T Installation and Operation Manual", 9620-05-NET FT, section 9:
"Raw Data Transfer"). Counts become newtons and newton-metres by dividing by the sensor's counts per
force and counts per torque (its calibration, :class:`Calibration`; 1 000 000 per unit in the sensor's
default configuration).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from iiwa_ident.errors import IiwaIdentError

__all__ = ["RDT_PORT", "RDT_HEADER", "REQUEST_BYTES", "RECORD_BYTES", "RdtCommand", "RdtError", "RdtRecord",
           "Calibration", "encode_request", "decode_request", "encode_record", "decode_record"]

#: The Net F/T's UDP port for RDT.
RDT_PORT = 49152
#: First field of every request.
RDT_HEADER = 0x1234
_REQUEST = struct.Struct("!HHI")
_RECORD = struct.Struct("!III6i")
REQUEST_BYTES = _REQUEST.size  #: 8
RECORD_BYTES = _RECORD.size  #: 36
_I32 = (-(1 << 31), (1 << 31) - 1)


class RdtCommand(IntEnum):
    """RDT request commands (the manual's table of RDT commands)."""

    STOP_STREAMING = 0x0000
    START_REALTIME = 0x0002
    START_BUFFERED = 0x0003
    START_MULTI_UNIT = 0x0004
    RESET_THRESHOLD_LATCH = 0x0041
    SET_SOFTWARE_BIAS = 0x0042


class RdtError(IiwaIdentError):
    """A datagram that is not a valid RDT request or record."""


@dataclass(frozen=True)
class RdtRecord:
    """One RDT record.

    Attributes
    ----------
    rdt_sequence, ft_sequence, status : int
        The record's counters and status word (uint32).
    counts : tuple of 6 int
        Fx, Fy, Fz, Tx, Ty, Tz in counts (int32).
    """

    rdt_sequence: int
    ft_sequence: int
    status: int
    counts: tuple[int, ...]


@dataclass(frozen=True)
class Calibration:
    """Counts per unit of a sensor (its configuration's "counts per force" and "counts per torque").

    Attributes
    ----------
    counts_per_force : float
        Counts per newton (> 0).
    counts_per_torque : float
        Counts per newton-metre (> 0).

    Examples
    --------
    >>> cal = Calibration(1e6, 1e6)
    >>> cal.counts([1.0, 0, 0, 0, 0, -0.5])
    (1000000, 0, 0, 0, 0, -500000)
    >>> cal.wrench((1000000, 0, 0, 0, 0, -500000))[[0, 5]].tolist()
    [1.0, -0.5]
    """

    counts_per_force: float = 1e6
    counts_per_torque: float = 1e6

    def __post_init__(self) -> None:
        for name in ("counts_per_force", "counts_per_torque"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise IiwaIdentError(f"F/T calibration: {name} must be a positive number, got {v!r}")

    def _scale(self) -> np.ndarray:
        return np.array([self.counts_per_force] * 3 + [self.counts_per_torque] * 3)

    def wrench(self, counts) -> np.ndarray:
        """Counts -> ``[Fx, Fy, Fz]`` [N] and ``[Tx, Ty, Tz]`` [Nm] as one array of 6."""
        return np.asarray(counts, dtype=float) / self._scale()

    def counts(self, wrench) -> tuple[int, ...]:
        """A wrench [N, Nm] -> counts, rounded and clipped to int32 (what the sensor's range saturates at)."""
        c = np.clip(np.rint(np.asarray(wrench, dtype=float) * self._scale()), *_I32)
        return tuple(int(x) for x in c)


def encode_request(command: int, sample_count: int = 0) -> bytes:
    """The 8-byte request ``command`` for ``sample_count`` records (0: until stopped)."""
    if not 0 <= int(sample_count) <= 0xFFFFFFFF:
        raise RdtError(f"RDT request: sample count {sample_count!r} is not a uint32")
    return _REQUEST.pack(RDT_HEADER, int(command) & 0xFFFF, int(sample_count))


def decode_request(data: bytes) -> tuple[int, int]:
    """``(command, sample_count)`` of a request; RdtError if it is not one."""
    if len(data) != REQUEST_BYTES:
        raise RdtError(f"RDT request of {len(data)} bytes, expected {REQUEST_BYTES}")
    header, command, count = _REQUEST.unpack(data)
    if header != RDT_HEADER:
        raise RdtError(f"RDT request header 0x{header:04x}, expected 0x{RDT_HEADER:04x}")
    return command, count


def encode_record(record: RdtRecord) -> bytes:
    """The 36-byte record."""
    return _RECORD.pack(record.rdt_sequence & 0xFFFFFFFF, record.ft_sequence & 0xFFFFFFFF,
                        record.status & 0xFFFFFFFF, *record.counts)


def decode_record(data: bytes) -> RdtRecord:
    """A record from its 36 bytes; RdtError for any other length."""
    if len(data) != RECORD_BYTES:
        raise RdtError(f"RDT record of {len(data)} bytes, expected {RECORD_BYTES}")
    rdt, ft, status, *counts = _RECORD.unpack(data)
    return RdtRecord(rdt, ft, status, tuple(counts))
