"""The sensor end of RDT: a Net F/T emulated from a simulated joint's external torque.

:class:`RdtServer` answers RDT requests on a UDP port as the sensor does (start and stop streaming, a
software bias) and streams records to whoever asked. :class:`EmulatedNetFt` puts a sensor behind it:
each control cycle it takes the external torque about the joint's axis, turns it into the wrench a hand
pushing at the sensor applies (:meth:`JointAxisProjection.wrench`), passes it through the sensor's
low-pass filter at the sensor's own output rate, and streams the records of that cycle. The emulated
sensor's filter is first order (the Net F/T's filter settings name cut-offs; the order is not
documented), its noise the simulated joint's F/T noise and, per channel, its own (seeded), its output
rate any up to 7 kHz.
"""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass

import numpy as np

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.netft._projection import JointAxisProjection
from iiwa_ident.netft._rdt import Calibration, RdtCommand, RdtError, RdtRecord, decode_request, encode_record

__all__ = ["NetFtSettings", "RdtServer", "EmulatedNetFt"]


@dataclass(frozen=True)
class NetFtSettings:
    """An emulated sensor's settings.

    Attributes
    ----------
    rate_hz : float
        RDT output rate [Hz] (the Net F/T's range: up to 7000).
    cutoff_hz : float or None
        Cut-off of the sensor's low-pass filter [Hz] (None: no filter).
    calibration : Calibration
        Counts per force and torque.
    force_noise_n, torque_noise_nm : float
        Std of the sensor's own noise per force [N] and torque [Nm] channel, per record, on top of the
        simulated joint's F/T noise.
    seed : int
        Seed of that noise.
    """

    rate_hz: float = 1000.0
    cutoff_hz: float | None = 152.0
    calibration: Calibration = Calibration()
    force_noise_n: float = 0.0
    torque_noise_nm: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 7000.0):
            raise IiwaIdentError(f"F/T rate must be 1-7000 Hz, got {self.rate_hz!r}")
        if self.cutoff_hz is not None and not (math.isfinite(self.cutoff_hz) and 0 < self.cutoff_hz):
            raise IiwaIdentError(f"F/T filter cut-off must be a positive frequency, got {self.cutoff_hz!r}")
        for name in ("force_noise_n", "torque_noise_nm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise IiwaIdentError(f"F/T {name} must be a std >= 0, got {v!r}")

    def filter_pole(self) -> float:
        """The discrete pole of the filter at the output rate (0: no filter)."""
        if self.cutoff_hz is None:
            return 0.0
        return math.exp(-2.0 * math.pi * self.cutoff_hz / self.rate_hz)


class RdtServer:
    """A UDP endpoint that behaves as a Net F/T's RDT server.

    Parameters
    ----------
    bind : (str, int)
        Address to listen on (port 0: any free port; :attr:`address` tells which).
    """

    def __init__(self, bind: tuple[str, int]) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind(bind)
        except OSError as err:
            self._sock.close()
            raise IiwaIdentError(f"cannot bind the F/T sensor's socket to {bind[0]}:{bind[1]}: "
                                 f"{err.strerror or err}") from None
        self._sock.setblocking(False)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self.client: tuple[str, int] | None = None
        self.remaining = 0  #: records still to stream (-1: until stopped)
        self.bias_requested = False  #: set by a bias request, cleared by the owner
        self.rdt_sequence = 0
        self.ft_sequence = 0
        self.requests_invalid = 0

    def poll_requests(self) -> None:
        """Handle the requests that arrived."""
        while True:
            try:
                data, addr = self._sock.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue
            try:
                command, count = decode_request(data)
            except RdtError:
                self.requests_invalid += 1
                continue
            if command in (RdtCommand.START_REALTIME, RdtCommand.START_BUFFERED):
                self.client, self.remaining = addr[:2], (count if count else -1)
            elif command == RdtCommand.STOP_STREAMING:
                self.remaining = 0
            elif command == RdtCommand.SET_SOFTWARE_BIAS:
                self.bias_requested = True

    def publish(self, counts: tuple[int, ...], status: int = 0) -> None:
        """One sensor sample: streamed as a record while a client asked for them."""
        self.ft_sequence += 1
        if self.client is None or self.remaining == 0:
            return
        rec = RdtRecord(self.rdt_sequence, self.ft_sequence, status, counts)
        self.rdt_sequence += 1
        if self.remaining > 0:
            self.remaining -= 1
        try:
            self._sock.sendto(encode_record(rec), self.client)
        except OSError:
            pass

    def close(self) -> None:
        self._sock.close()


class EmulatedNetFt:
    """A Net F/T on the flange, fed each control cycle with the external torque about the joint's axis.

    Parameters
    ----------
    server : RdtServer
        Where the records go.
    projection : JointAxisProjection
        The sensor's geometry (the wrench a torque about the axis comes from).
    settings : NetFtSettings
        Rate, filter, calibration.
    cycle_s : float
        The control cycle [s].
    """

    def __init__(self, server: RdtServer, projection: JointAxisProjection, settings: NetFtSettings = NetFtSettings(),
                 cycle_s: float = 1e-3) -> None:
        self.server, self.projection, self.settings = server, projection, settings
        self._a = settings.filter_pole()
        self._per_s = settings.rate_hz
        self._cycle_s = cycle_s
        self._k = 0
        self._y = np.zeros(6)
        self._bias = np.zeros(6)
        self._biased = False
        self._started = False
        self._noise = np.array([settings.force_noise_n] * 3 + [settings.torque_noise_nm] * 3)
        self._rng = np.random.default_rng(settings.seed) if self._noise.any() else None

    def restart(self, tau_ext: float) -> None:
        """The simulation restarted from rest at ``tau_ext`` [Nm]: the filter settles there, and a bias the
        client asked for is taken again (the emulator restarts its joint when commanding first becomes
        active; without this the bias would depend on when the request arrived)."""
        self._y = self.projection.wrench(tau_ext)
        self._started = True
        if self._biased:
            self._bias = self._y.copy()

    def cycle(self, tau_ext: float) -> None:
        """One control cycle with ``tau_ext`` [Nm] about the axis: the records of that cycle."""
        srv = self.server
        srv.poll_requests()
        w = self.projection.wrench(tau_ext)
        if not self._started:
            self._y[:] = w
            self._started = True
        # Records this cycle at the sensor's own rate: floor((k+1) r T) - floor(k r T).
        k, rT = self._k, self._per_s * self._cycle_s
        n = int(math.floor((k + 1) * rT + 1e-9)) - int(math.floor(k * rT + 1e-9))
        self._k += 1
        for _ in range(n):
            self._y = self._a * self._y + (1.0 - self._a) * w
            if srv.bias_requested:
                srv.bias_requested = False
                self._bias = self._y.copy()
                self._biased = True
            w_out = self._y - self._bias
            if self._rng is not None:
                w_out = w_out + self._noise * self._rng.standard_normal(6)
            srv.publish(self.settings.calibration.counts(w_out))
