"""The client end of an FRI session: receive each monitoring message, answer it.

KUKA's robot controller sends a monitoring message every send period; the
client answers each one to the address it came from (section "Protocol" of
docs/fri.md). :class:`FriConnection` owns the UDP socket and the client's
half of the message headers:

* Only datagrams from the configured robot address are accepted; the rest
  are counted as ``foreign`` and dropped. Undecodable ones (or with the
  wrong message identifier) are counted as ``invalid``.
* The robot's sequence counter orders the messages: one that is not newer
  than the last accepted one (a duplicate or a reordered datagram) is
  counted as ``stale`` and dropped. When several new messages are queued
  (the client was late), only the newest is answered and the older ones
  are counted as ``skipped``: answering an old measurement with a command
  computed for it would only add latency.
* The client counts its own sequence from 0, one per command sent, and
  reflects the sequence counter of the message it answers.
* What an answer carries follows the session state: nothing in IDLE; in
  MONITORING_WAIT / MONITORING_READY the header, with joint positions when
  the caller gives them (KUKA's client sends the robot's commanded ones);
  joint positions for every joint in COMMANDING_WAIT / COMMANDING_ACTIVE,
  and joint torques when given (torque mode). Non-finite numbers are never
  sent.
"""

from __future__ import annotations

import select
import socket
import time
from dataclasses import dataclass, field

from iiwa_ident._defaults import DEFAULT_PORT  # one definition, light for the CLI's help
from iiwa_ident.errors import IiwaIdentError, SafetyStop
from iiwa_ident.fri._protocol import (
    COMMAND_MESSAGE_ID,
    MAX_DATAGRAM_BYTES,
    CommandMessage,
    FriDecodeError,
    MonitoringMessage,
    SessionState,
    decode_monitoring,
    encode_command,
)

__all__ = ["DEFAULT_PORT", "COMMANDING_STATES", "ConnectionStats", "FriConnection", "parse_host_port"]

#: Session states in which every answer carries joint positions and torques.
COMMANDING_STATES = frozenset({SessionState.COMMANDING_WAIT, SessionState.COMMANDING_ACTIVE})
_UINT32 = 1 << 32


def parse_host_port(text: str, default_port: int | None = DEFAULT_PORT, what: str = "address",
                    allow_any_port: bool = False) -> tuple[str, int]:
    """``"HOST"`` or ``"HOST:PORT"`` -> (host, port); raises IiwaIdentError with a one-line message.

    Parameters
    ----------
    text : str
        The address as typed.
    default_port : int or None
        Port when ``text`` has none; None: the port is required.
    what : str
        Name of the address in the error message (e.g. ``"--client"``).
    allow_any_port : bool
        Accept port 0 (bind to any free port).
    """
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port = text, default_port
    else:
        port = int(port_text) if port_text.isdigit() else None
    low = 0 if allow_any_port else 1
    if not host or port is None or not low <= port <= 65535:
        form = "HOST:PORT" if default_port is None else "HOST or HOST:PORT"
        raise IiwaIdentError(f"{what} {text!r}: expected {form} with a port {low}-65535")
    return host, port


def _newer(seq: int, last: int) -> bool:
    """Whether uint32 sequence counter ``seq`` comes after ``last`` (modulo wrap-around)."""
    return 0 < (seq - last) % _UINT32 < _UINT32 // 2


@dataclass(kw_only=True)
class ConnectionStats:
    """Datagram counters of a session.

    Attributes
    ----------
    received : int
        Monitoring messages accepted.
    foreign : int
        Datagrams from an address other than the robot's.
    invalid : int
        Datagrams that did not decode as a monitoring message.
    stale : int
        Messages not newer than the last accepted one (duplicates, reordering).
    skipped : int
        Newer messages superseded by an even newer one before they were answered.
    lost : int
        Gaps in the robot's sequence counter (messages never received) once the
        client has answered: what queued up or overflowed the socket before
        the client was reading is not a loss of the session.
    sent : int
        Answers sent.
    first_answer_s : float or None
        Time from opening the socket to the first answer [s].
    """

    received: int = 0
    foreign: int = 0
    invalid: int = 0
    stale: int = 0
    skipped: int = 0
    lost: int = 0
    sent: int = 0
    first_answer_s: float | None = None
    last_error: str = field(default="", repr=False)

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {k: getattr(self, k) for k in ("received", "foreign", "invalid", "stale", "skipped", "lost", "sent")}


class FriConnection:
    """UDP endpoint of the FRI client.

    Parameters
    ----------
    robot_host : str
        Host name or address of the robot controller; only its datagrams are accepted.
    port : int
        Local UDP port to listen on (KUKA's default 30200).
    bind_host : str
        Local address to bind (all interfaces by default).
    spin_s : float
        How long :meth:`receive` polls before it sleeps [s] (0: always sleep).
    """

    def __init__(self, robot_host: str, port: int = DEFAULT_PORT, bind_host: str = "", *,
                 spin_s: float = 0.0) -> None:
        try:
            self.robot_ip = socket.gethostbyname(robot_host)
        except OSError as err:
            raise IiwaIdentError(f"robot host {robot_host!r}: {err.strerror or err}") from None
        self.port, self.spin_s = int(port), float(spin_s)
        self.stats = ConnectionStats()
        self.sequence = 0  #: the client's next sequence counter
        self._last_seq: int | None = None
        self._reply_to: tuple[str, int] | None = None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((bind_host, self.port))
        except OSError as err:
            self._sock.close()
            raise IiwaIdentError(f"cannot listen on UDP port {self.port}: {err.strerror or err}") from None
        self._sock.setblocking(False)
        self._opened_ns = time.perf_counter_ns()
        self._buffer = bytearray(MAX_DATAGRAM_BYTES + 1)
        self.rx_ns = 0  #: perf_counter_ns when the newest accepted message was read from the socket
        self.last_compute_ns = 0  #: from reading a message to having sent its answer [ns]

    @property
    def address(self) -> tuple[str, int]:
        """The local (host, port) the client listens on."""
        return self._sock.getsockname()

    def close(self) -> None:
        """Close the socket (the robot drops the session when answers stop)."""
        self._sock.close()

    def __enter__(self) -> FriConnection:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ receive
    def _accept(self, data: bytes, addr: tuple[str, int]) -> MonitoringMessage | None:
        st = self.stats
        if addr[0] != self.robot_ip:
            st.foreign += 1
            return None
        try:
            msg = decode_monitoring(data)
        except FriDecodeError as err:
            st.invalid += 1
            st.last_error = str(err)
            return None
        seq = msg.header.sequence_counter
        if self._last_seq is not None and not _newer(seq, self._last_seq):
            st.stale += 1
            return None
        if self._last_seq is not None and st.sent:
            st.lost += (seq - self._last_seq) % _UINT32 - 1
        self._last_seq = seq
        self._reply_to = addr
        st.received += 1
        return msg

    def _drain(self) -> MonitoringMessage | None:
        """Read every queued datagram; return the newest accepted message."""
        newest = None
        while True:
            try:
                n, addr = self._sock.recvfrom_into(self._buffer)
            except (BlockingIOError, InterruptedError):
                return newest
            rx_ns = time.perf_counter_ns()
            msg = self._accept(bytes(self._buffer[:n]), addr)
            if msg is not None:
                self.rx_ns = rx_ns
                if newest is not None:
                    self.stats.skipped += 1
                newest = msg

    def receive(self, timeout_s: float) -> MonitoringMessage | None:
        """Wait up to ``timeout_s`` [s] for the next monitoring message; None on timeout.

        The first ``spin_s`` of the wait poll the socket instead of sleeping in
        ``select``: a process that sleeps between 1 kHz messages wakes on a cold
        (often descheduled) CPU and loses tens of microseconds per cycle.
        """
        now = time.perf_counter()
        deadline = now + timeout_s
        spin_until = now + min(self.spin_s, timeout_s)
        while True:
            msg = self._drain()
            if msg is not None:
                return msg
            now = time.perf_counter()
            if now < spin_until:
                continue
            remaining = deadline - now
            if remaining <= 0:
                return None
            try:
                select.select([self._sock], [], [], remaining)
            except InterruptedError:  # a signal; the caller decides whether to go on
                return None

    # ------------------------------------------------------------------ answer
    def answer(self, msg: MonitoringMessage, joint_positions=None, joint_torques=None) -> bool:
        """Answer ``msg`` as its session state requires; returns whether anything was sent.

        Parameters
        ----------
        msg : MonitoringMessage
            The message being answered (its sequence counter is reflected).
        joint_positions, joint_torques : sequence of float, optional
            One per joint [rad], [Nm]. The positions are required in the commanding
            states and sent when given in the monitoring states; the torques are sent
            when given in the commanding states (torque mode needs them), never while
            monitoring.

        Raises
        ------
        SafetyStop
            If a commanding answer lacks a value per joint or holds a non-finite number
            (:func:`~iiwa_ident.fri.message_problem`).
        """
        state = msg.connection_info.session_state if msg.HasField("connection_info") else SessionState.IDLE
        if state == SessionState.IDLE or self._reply_to is None:
            return False
        answer = CommandMessage(header=dict(message_identifier=COMMAND_MESSAGE_ID,
                                            sequence_counter=self.sequence % _UINT32,
                                            reflected_sequence_counter=msg.header.sequence_counter))
        if state in COMMANDING_STATES:
            if joint_positions is None:
                raise SafetyStop("FRI: a commanding answer needs joint positions")
        else:
            joint_torques = None  # never sent while monitoring
        try:
            if joint_positions is not None:
                answer.command_data.joint_position.value[:] = joint_positions
            if joint_torques is not None:
                answer.command_data.joint_torque.value[:] = joint_torques
        except TypeError:
            raise SafetyStop("FRI: joint positions and torques must be numbers") from None
        try:
            # The protocol's checks (7 values per joint array, finite numbers) are the only ones in the loop.
            data = encode_command(answer)
        except ValueError as err:
            raise SafetyStop(f"FRI: refusing to send: {err}") from None
        self._sock.sendto(data, self._reply_to)
        now = time.perf_counter_ns()
        self.last_compute_ns = now - self.rx_ns
        self.sequence += 1
        if not self.stats.sent:
            self.stats.first_answer_s = (now - self._opened_ns) * 1e-9
        self.stats.sent += 1
        return True
