"""The robot side's clocks: the wall clock of a real robot, or a virtual one in lockstep with the client.

Real time
---------
Cycle ``k`` starts at ``t0 + k * period`` (:func:`time.perf_counter`). Between
cycles the emulator waits in :func:`select.select` on its socket (so answers
are time-stamped when they arrive) until :attr:`EmulatorConfig.spin_s`
before the deadline and then polls. A cycle that starts more than
:data:`OVERRUN_S` late is an *overrun*; when a whole period has been lost the
missed deadlines are skipped (not caught up in a burst) and counted as
``skipped_cycles``. The simulated joint is stepped once per executed cycle.
For the run, the objects that already exist are frozen out of the garbage
collector (:func:`gc.freeze`), whose full collections of a large process
would stall the loop for tens of milliseconds. Run the emulator in its own
process (:func:`spawn_emulator`) when the client under test is Python, so
the two do not share the interpreter lock.

Lockstep
--------
With :attr:`EmulatorConfig.lockstep` the emulator runs on a clock of its
own instead of the wall clock: cycle ``k`` is at virtual time ``k * period``
and before each cycle the robot side waits until the client has answered
every monitoring message it was sent (a datagram lost, corrupted or still
delayed by the injected faults is not waited for). Each answer is taken to
arrive :attr:`~EmulatorConfig.lockstep_latency_s` after its message was
delivered; injected jitter delays datagrams in virtual time. A client that
answers within :attr:`~EmulatorConfig.lockstep_guard_s` of wall time sees
every cycle in order and never a late, missed or skipped one, however
loaded the machine is, so runs are exactly repeatable. A client that does
not answer within the guard is taken for gone: the cycles run on without
waiting (a commanding session drops after ``timeout_s`` of virtual
silence, as on the robot; its messages in that time are not sent, so that
a client started meanwhile meets the dropped session, as it would on the
robot, whatever the machine's load) and in a monitoring state the emulator
stops the clock and sends the current message again every :data:`RESEND_S` until a
client answers. The first monitoring message is sent that way too, so a
client may start after the emulator. Use it for tests, and for runs whose
figures must not depend on the machine's load; the real-time mode is what a
client meets on the robot. Both modes run the same loop, sockets, protocol
and session logic; only the clock object differs (when a cycle runs, what
its time stamps say, which answers are awaited), so lockstep does not show
answer latency (``bench/bench_fri_runtime.py`` measures it).
"""

from __future__ import annotations

import heapq
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from iiwa_ident.emulator._config import EmulatorConfig
from iiwa_ident.emulator._report import EmulatorReport, Histogram
from iiwa_ident.fri import FriDecodeError, SessionState, decode_command

__all__ = ["OVERRUN_S", "RESEND_S", "RING", "SentRing", "SessionView", "ClockPort", "RealTimeClock",
           "LockstepClock"]

#: A cycle that starts later than this after its deadline is an overrun [s].
OVERRUN_S = 0.5e-3
#: Lockstep: a monitoring message nobody answered is sent again after this wall time [s].
RESEND_S = 0.05
#: Sent messages remembered for latency and state look-up (a power of two).
RING = 4096
_COMMANDING = (SessionState.COMMANDING_WAIT, SessionState.COMMANDING_ACTIVE)


@dataclass
class SentRing:
    """The newest :data:`RING` monitoring messages sent, by slot (sequence counter modulo :data:`RING`): their
    sequence counter, send time in the clock's time [s] and session state."""

    seq: list[int] = field(default_factory=lambda: [-1] * RING)
    t: list[float] = field(default_factory=lambda: [0.0] * RING)
    state: list[SessionState] = field(default_factory=lambda: [SessionState.IDLE] * RING)


@dataclass(frozen=True)
class SessionView:
    """What a clock needs to know of the session: a stop was asked for, the session is closing, a client
    commands (``COMMANDING_WAIT`` or ``COMMANDING_ACTIVE``)."""

    stop_requested: bool
    ending: bool
    commanding: bool


class _Link(Protocol):
    """The faulty link as a clock uses it: datagrams the faults delay, delivering one, sending again."""

    pending: list[tuple[float, int, Any]]

    def deliver(self, item: Any, due: float | None = None) -> None: ...

    def sendto(self, data: bytes) -> None: ...


@dataclass(kw_only=True)
class ClockPort:
    """The robot side as its clock sees it: its socket, link, report, sent messages and client, and the two
    calls the clock needs: ``drain()`` collects the answers that arrived, ``session()`` looks at the session."""

    sock: socket.socket
    link: _Link
    report: EmulatorReport
    ring: SentRing
    client: tuple[str, int]
    drain: Callable[[], None]
    session: Callable[[], SessionView]
    on_event: Callable[[float, str], None] | None = None


class RealTimeClock:
    """The robot side on the wall clock: cycle ``k`` at ``t0 + k * period``.

    Between deadlines it collects answers and sends the datagrams the faults
    delayed; a cycle more than a period late skips the lost deadlines.
    """

    def __init__(self, config: EmulatorConfig) -> None:
        self.config = config
        self.period = config.send_period_ms * 1e-3
        self.t0 = 0.0
        #: How late each cycle started after its deadline [s].
        self.delay = Histogram()
        self._port: ClockPort | None = None

    def connect(self, port: ClockPort) -> None:
        """Give the clock the robot side it drives (the link it uses is built with the clock)."""
        self._port = port

    @property
    def port(self) -> ClockPort:
        """The robot side this clock drives (:meth:`connect`)."""
        if self._port is None:
            raise RuntimeError("the clock is not connected to a robot side (connect() first)")
        return self._port

    def start(self) -> None:
        self.t0 = time.perf_counter() + 1e-3

    def wait(self, k: int) -> int:
        """Wait for cycle ``k``'s deadline; the cycle to run (later than ``k`` after a stall)."""
        period = self.period
        deadline = self.t0 + k * period
        self._wait_until(deadline)
        late = time.perf_counter() - deadline
        rep = self.port.report
        if late > OVERRUN_S:
            rep.overruns += 1
        self.delay.add(late)
        if late >= period:
            # Fell a whole period behind: skip the lost deadlines rather than burst.
            skip = int(late / period)
            rep.skipped_cycles += skip
            k += skip
        return k

    def _wait_until(self, deadline: float) -> None:
        port = self.port
        perf = time.perf_counter
        spin = self.config.spin_s
        sock = port.sock
        pending = port.link.pending
        while True:
            port.drain()
            now = perf()
            while pending and pending[0][0] <= now:
                port.link.deliver(heapq.heappop(pending)[2])
            remaining = deadline - now
            if remaining <= 0.0:
                return
            session = port.session()
            if session.stop_requested and not session.ending:
                return
            wake = deadline - spin
            if pending and pending[0][0] < wake:
                wake = pending[0][0]
            if wake - now > 20e-6:
                select.select((sock,), (), (), wake - now)

    def now(self) -> float:
        """The robot side's time now [s] (send times, fault delays)."""
        return time.perf_counter()

    def silence_s(self, k: int, heard_k: int) -> float:
        """How long the client has been silent at cycle ``k``, last heard at cycle ``heard_k`` [s]."""
        return (k - heard_k) * self.period

    def wall(self) -> float:
        """Wall time since the start [s]."""
        return time.perf_counter() - self.t0

    def stamp_ns(self) -> int:
        """The monitoring message's timestamp [ns since the epoch]."""
        return time.time_ns()

    def arrival(self, data: bytes, addr: Any) -> float | None:
        """Arrival time of a received datagram [s]; None: ignore it."""
        return time.perf_counter()

    def sends(self, slot: int, state: SessionState) -> bool:
        """Whether the message just built (ring ``slot``, in ``state``) goes out."""
        return True

    def delivered(self, data: bytes, seq: int, due: float | None) -> None:
        """A message that expects an answer went to the socket (``due``: when the faults let it)."""


class LockstepClock(RealTimeClock):
    """The robot side on a virtual clock that waits for the answers (module docstring, "Lockstep").

    Cycle ``k`` is at ``k * period``; an answer arrives ``lockstep_latency_s``
    after its message was delivered. The bookkeeping: the newest delivered
    message that expects an answer, the newest one answered, and whether the
    client has answered at all or was taken for gone.
    """

    def __init__(self, config: EmulatorConfig) -> None:
        super().__init__(config)
        self.vt = 0.0  # virtual time of the current cycle [s]
        self.epoch_ns = time.time_ns()  # wall-clock stamp of virtual time 0 for the messages' timestamps
        self.await_seq = -1  # newest delivered message that expects an answer
        self.await_data = b""
        self.heard_seq = -1  # newest message an answer reflected
        self.heard_any = False
        self.heard_wall = 0.0  # wall time of the newest answer [s]
        self.gone = False
        self.resent_seq = -1
        self.resent_heard = False
        self.ring_delay = [0.0] * RING  # injected delivery delay of each message [s]

    def start(self) -> None:
        self.t0 = time.perf_counter()

    def wait(self, k: int) -> int:
        """Deliver what the faults delayed until cycle ``k``, then wait for the outstanding answers."""
        port = self.port
        cfg = self.config
        self.vt = k * self.period
        pending = port.link.pending
        limit = self.vt - cfg.lockstep_latency_s + 1e-12  # answers to these can still arrive by this cycle
        while pending and pending[0][0] <= limit:
            due, _, item = heapq.heappop(pending)
            port.link.deliver(item, due)
        port.drain()
        if self.await_seq <= self.heard_seq:
            return k
        session = port.session()
        if self.gone and (session.commanding or session.ending):
            return k  # silence runs its course: the session drops after timeout_s, or the run closes
        resend = self.gone or not self.heard_any  # no client (yet): stop the clock until one answers
        perf = time.perf_counter
        max_wall = cfg.max_wall_s
        idle = cfg.idle_timeout_s
        now = perf()
        deadline = now + cfg.lockstep_guard_s
        next_resend = now + RESEND_S
        while True:
            if port.session().stop_requested:  # the session closes without waiting for a client that has finished
                return k
            if max_wall is not None and now - self.t0 >= max_wall:
                return k
            if resend and idle is not None and self.heard_any and now - self.heard_wall >= idle:
                return k  # a client that had answered fell silent: the run decides whether it ends
            if resend:
                if now >= next_resend:
                    self._resend()
                    next_resend = now + RESEND_S
                wake = next_resend
            elif now >= deadline:
                self.gone = True
                port.report.client_gone += 1
                if port.on_event is not None:
                    port.on_event(self.vt, f"no answer within {cfg.lockstep_guard_s:g} s: client taken for gone")
                return k
            else:
                wake = deadline
            # Short sleeps keep stop requests from other threads and signal handlers prompt.
            select.select((port.sock,), (), (), min(max(wake - now, 0.0), 0.05))
            port.drain()
            if self.await_seq <= self.heard_seq:
                return k
            now = perf()

    def _resend(self) -> None:
        """Send the newest awaited message again (a client that starts late, or came back)."""
        self.port.report.resent += 1
        if self.resent_seq != self.await_seq:
            self.resent_seq, self.resent_heard = self.await_seq, False
        self.port.link.sendto(self.await_data)

    def now(self) -> float:
        return self.vt

    def stamp_ns(self) -> int:
        return self.epoch_ns + int(round(self.vt * 1e9))

    def silence_s(self, k: int, heard_k: int) -> float:
        # The virtual clock stops while no client answers: the silence is the wall's, counted once the client
        # was taken for gone (a client the machine's load slows is waited for, as everywhere in lockstep).
        return time.perf_counter() - self.heard_wall if self.gone else 0.0

    def arrival(self, data: bytes, addr: Any) -> float | None:
        """Virtual arrival time of an answer; None for a second answer to a message sent again."""
        port = self.port
        if addr[:2] != port.client:
            return self.vt
        try:
            reflected = decode_command(data, check=False).header.reflected_sequence_counter
        except FriDecodeError:
            return self.vt  # the cycle logic counts it as invalid
        if reflected == self.resent_seq:
            if self.resent_heard:
                port.report.resent_answers += 1
                return None
            self.resent_heard = True
        self.heard_any = True
        self.heard_wall = time.perf_counter()
        self.gone = False
        slot = reflected & (RING - 1)
        if port.ring.seq[slot] != reflected:
            # Not a recent message of ours (a corrupted counter the client reflected): it answers nothing awaited.
            return self.vt
        if reflected > self.heard_seq:
            self.heard_seq = reflected
        return port.ring.t[slot] + self.ring_delay[slot] + self.config.lockstep_latency_s

    def sends(self, slot: int, state: SessionState) -> bool:
        self.ring_delay[slot] = 0.0
        # The session of a client taken for gone runs out its timeout unheard: a client started since
        # (while the robot side waited out the guard time) must meet the dropped session, as it would
        # on the robot seconds later, and not pick up the old one at a machine-dependent cycle.
        return not (self.gone and state in _COMMANDING)

    def delivered(self, data: bytes, seq: int, due: float | None) -> None:
        ring = self.port.ring
        slot = seq & (RING - 1)
        if ring.seq[slot] == seq:
            self.ring_delay[slot] = (self.vt if due is None else due) - ring.t[slot]
        if seq > self.await_seq:
            self.await_seq, self.await_data = seq, data
