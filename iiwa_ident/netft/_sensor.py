"""The client end of a Net F/T's RDT stream: one joint-axis torque per control cycle.

:class:`NetFtSensor` asks the sensor to bias itself and to stream records without end, then, once per
control cycle, takes every record that arrived (:meth:`NetFtSensor.poll`) and returns the newest good
one as a torque about the joint's axis (:class:`~iiwa_ident.netft.JointAxisProjection`).
What it counts, per :class:`SensorStats`:

* records from another address (``foreign``), datagrams that are no record (``invalid``);
* records whose RDT sequence is not newer than the last one (``stale``: duplicates, reordering), and
  gaps in it (``lost``: records the network dropped), counted from the second poll on (what queued up
  or overflowed the socket before the loop read it is no loss of the stream);
* records with a status word other than 0 (``bad_status``): the sensor reports a fault (saturation, a
  broken gauge, ...) and the record is not used;
* cycles without a new good record (``silent_cycles``). After ``fault_cycles`` of them in a row
  :attr:`NetFtSensor.fault` says why, and the runtime ramps its loop down.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.netft._projection import JointAxisProjection
from iiwa_ident.netft._rdt import (
    RDT_PORT,
    RECORD_BYTES,
    Calibration,
    RdtCommand,
    RdtError,
    decode_record,
    encode_request,
)

__all__ = ["SensorStats", "NetFtSensor"]

_U32 = 1 << 32


@dataclass(kw_only=True)
class SensorStats:
    """Counters of an RDT stream (module docstring)."""

    received: int = 0
    foreign: int = 0
    invalid: int = 0
    stale: int = 0
    lost: int = 0
    bad_status: int = 0
    silent_cycles: int = 0
    longest_silence: int = 0
    last_status: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return dict(self.__dict__)


class NetFtSensor:
    """A Net F/T read over RDT, as a torque about one joint's axis.

    Parameters
    ----------
    host : str
        The sensor's address.
    projection : JointAxisProjection or None
        The sensor-to-axis geometry; None until the caller sets :attr:`projection` (the runtime sets
        it from the robot's description at the pose the arm holds when commanding starts).
    port : int
        The sensor's RDT port (49152).
    calibration : Calibration
        Counts per force and torque of the sensor's configuration.
    fault_cycles : int
        Cycles in a row without a new good record after which :attr:`fault` is set.
    bias : bool
        Ask the sensor for a software bias at :meth:`start` (the hand is off the arm then).
    """

    def __init__(self, host: str, projection: JointAxisProjection | None, port: int = RDT_PORT,
                 calibration: Calibration = Calibration(), fault_cycles: int = 20, bias: bool = True) -> None:
        if int(fault_cycles) < 1:
            raise IiwaIdentError(f"F/T sensor: fault cycles must be >= 1, got {fault_cycles!r}")
        try:
            self.address = (socket.gethostbyname(host), int(port))
        except OSError as err:
            raise IiwaIdentError(f"F/T sensor host {host!r}: {err.strerror or err}") from None
        self.calibration = calibration
        self.projection = projection
        self.fault_cycles, self.bias = int(fault_cycles), bool(bias)
        self.stats = SensorStats()
        self.tau = 0.0  #: the newest good record about the axis [Nm], held while none arrives
        self.fault = ""  #: why the stream is no longer trusted ("" while it is)
        self._silent = 0
        self._last_seq: int | None = None
        self._polled = False
        self._sock: socket.socket | None = None

    @property
    def projection(self) -> JointAxisProjection | None:
        """The sensor-to-axis geometry (setting it prepares the per-record weights of the counts)."""
        return self._projection

    @projection.setter
    def projection(self, value: JointAxisProjection | None) -> None:
        self._projection = value
        cal = self.calibration
        self._weights = None if value is None else value.coefficients(
            (cal.counts_per_force,) * 3 + (cal.counts_per_torque,) * 3)

    def start(self) -> None:
        """Open the socket and ask for the bias and the stream."""
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        try:
            if self.bias:
                self._sock.sendto(encode_request(RdtCommand.SET_SOFTWARE_BIAS), self.address)
            self._sock.sendto(encode_request(RdtCommand.START_REALTIME, 0), self.address)
        except OSError as err:
            self.stop()
            raise IiwaIdentError(f"F/T sensor at {self.address[0]}:{self.address[1]}: "
                                 f"{err.strerror or err}") from None

    def flush(self) -> int:
        """Discard what queued up before the loop starts reading (records older than its first cycle).

        Returns the number of datagrams discarded; the next poll's records start the sequence anew.
        """
        n = 0
        while self._sock is not None:
            try:
                self._sock.recvfrom(256)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                continue
            n += 1
        self._last_seq = None
        self._polled = False
        return n

    def poll(self) -> float | None:
        """Take what arrived since the last cycle: the newest good record's torque [Nm], or None.

        Called once per control cycle; a cycle without a good record counts as silent.
        """
        st = self.stats
        newest = None
        sock = self._sock
        while sock is not None:
            try:
                data, addr = sock.recvfrom(256)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # an ICMP error (nobody listening): nothing received
                continue
            if addr[:2] != self.address:
                st.foreign += 1
                continue
            if len(data) != RECORD_BYTES:
                st.invalid += 1
                continue
            try:
                rec = decode_record(data)
            except RdtError:
                st.invalid += 1
                continue
            if self._last_seq is not None:
                ahead = (rec.rdt_sequence - self._last_seq) % _U32
                if ahead == 0 or ahead >= _U32 // 2:
                    st.stale += 1
                    continue
                if self._polled:
                    st.lost += ahead - 1
            self._last_seq = rec.rdt_sequence
            st.received += 1
            if rec.status != 0:
                st.bad_status += 1
                st.last_status = rec.status
                continue
            newest = rec
        self._polled = True
        if newest is None:
            self._silent += 1
            st.silent_cycles += 1
            st.longest_silence = max(st.longest_silence, self._silent)
            if self._silent >= self.fault_cycles and not self.fault:
                what = (f"status 0x{st.last_status:08x}" if st.bad_status and st.last_status
                        else "no record")
                self.fault = f"F/T sensor: {what} for {self._silent} cycles"
            return None
        self._silent = 0
        w = self._weights
        if w is None:
            raise IiwaIdentError("F/T sensor: no projection onto the joint's axis was set")
        c = newest.counts  # plain floats in the 1 kHz loop: the weights of the counts are prepared
        self.tau = w[0] * c[0] + w[1] * c[1] + w[2] * c[2] + w[3] * c[3] + w[4] * c[4] + w[5] * c[5]
        return self.tau

    def stop(self) -> None:
        """Ask the sensor to stop streaming and close the socket."""
        if self._sock is None:
            return
        try:
            self._sock.sendto(encode_request(RdtCommand.STOP_STREAMING), self.address)
        except OSError:
            pass
        self._sock.close()
        self._sock = None
