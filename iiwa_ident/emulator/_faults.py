"""The UDP link to the client, with the injected faults of :class:`~iiwa_ident.emulator.Faults`.

:class:`FaultyLink` drops, delays, duplicates, reorders and corrupts
datagrams with seeded random generators (one per direction, so that which
cycle an answer falls into cannot change the faults injected into the
robot's messages) and counts each injected fault in the run's
:attr:`EmulatorReport.faults <iiwa_ident.emulator.EmulatorReport>`.
Without faults a message goes straight to the socket.
"""

from __future__ import annotations

import heapq
import random
import socket
from typing import TYPE_CHECKING

from iiwa_ident.emulator._config import Faults
from iiwa_ident.emulator._report import EmulatorReport

if TYPE_CHECKING:
    from iiwa_ident.emulator._clocks import RealTimeClock

__all__ = ["FaultyLink"]

#: A datagram to the client: (bytes, sequence counter, whether an answer is expected).
Datagram = tuple[bytes, int, bool]


class FaultyLink:
    """The robot side's datagrams to and from the client, through the fault injection.

    Parameters
    ----------
    sock : socket.socket
        The robot-side socket (non-blocking).
    client : (str, int)
        The client's numeric address.
    faults : Faults
        What to inject.
    report : EmulatorReport
        Where the faults and send errors are counted.
    clock : RealTimeClock
        The run's clock: delays are in its time, and it learns of each
        delivered message that expects an answer.
    """

    def __init__(self, sock: socket.socket, client: tuple[str, int], faults: Faults, report: EmulatorReport,
                 clock: RealTimeClock) -> None:
        self.sock, self.client, self.faults, self.report, self.clock = sock, client, faults, report, clock
        self._rng = random.Random(faults.seed)
        self._rng_in = random.Random(f"{faults.seed}:answers")
        #: Datagrams the jitter delays: a heap of (due, order, datagram).
        self.pending: list[tuple[float, int, Datagram]] = []
        self._order = 0
        self._held: list[Datagram] | None = None

    def send(self, data: bytes, seq: int, expects_answer: bool) -> None:
        """Send one robot-to-client datagram through the fault injection."""
        faults = self.faults
        if not faults.any:
            self.deliver((data, seq, expects_answer))
            return
        rng = self._rng
        counts = self.report.faults
        if faults.loss and rng.random() < faults.loss:
            self._count("loss", "loss_out")
            return
        if faults.corrupt and rng.random() < faults.corrupt:
            self._count("corrupt", "corrupt_out")
            data = self._corrupt(data)
            expects_answer = False  # the client cannot decode it
        item = (data, seq, expects_answer)
        group = [item]
        if faults.duplicate and rng.random() < faults.duplicate:
            counts["duplicate"] += 1
            group.append(item)
        if self._held is not None:
            group += self._held
            self._held = None
        elif faults.reorder and rng.random() < faults.reorder:
            counts["reorder"] += 1
            self._held = group
            return
        if faults.jitter_s:
            counts["jitter"] += 1
            due = self.clock.now() + rng.uniform(0.0, faults.jitter_s)
            for d in group:
                self._order += 1
                heapq.heappush(self.pending, (due, self._order, d))
        else:
            for d in group:
                self.deliver(d)

    def receive(self, data: bytes) -> bytes | None:
        """An answer as it reaches the robot: None when the faults drop it, possibly corrupted."""
        faults = self.faults
        rng = self._rng_in
        if faults.loss and rng.random() < faults.loss:
            self._count("loss", "loss_in")
            return None
        if faults.corrupt and rng.random() < faults.corrupt:
            self._count("corrupt", "corrupt_in")
            data = self._corrupt(data)
        return data

    def deliver(self, item: Datagram, due: float | None = None) -> None:
        """Hand a datagram to the socket; in lockstep its answer is now awaited (``due``: virtual delivery time)."""
        data, seq, expects_answer = item
        self.sendto(data)
        if expects_answer:
            self.clock.delivered(data, seq, due)

    def sendto(self, data: bytes) -> None:
        """Send a datagram as it is, counting a refusal of the operating system."""
        try:
            self.sock.sendto(data, self.client)
        except OSError:
            self.report.send_errors += 1

    def flush(self) -> None:
        """At the end of a run: send what is held back or delayed."""
        for d in self._held or ():
            self.sendto(d[0])
        self._held = None
        while self.pending:
            self.sendto(heapq.heappop(self.pending)[2][0])

    def _count(self, kind: str, direction: str) -> None:
        counts = self.report.faults
        counts[kind] += 1
        counts[direction] += 1

    def _corrupt(self, data: bytes) -> bytes:
        # One generator corrupts both directions (as it always has: the seeded runs stay the same).
        rng = self._rng
        buf = bytearray(data)
        if buf:
            for _ in range(rng.randint(1, 3)):
                buf[rng.randrange(len(buf))] ^= rng.randint(1, 255)
        return bytes(buf)
