"""What an emulator run reports: counters, session transitions, timing, injected faults."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from iiwa_ident.fri import ConnectionQuality, SessionState

__all__ = ["EmulatorReport", "Histogram", "FAULT_KINDS"]

#: Injected faults counted by :attr:`EmulatorReport.faults`.
FAULT_KINDS = ("loss", "jitter", "duplicate", "reorder", "corrupt", "loss_out", "loss_in", "corrupt_out",
               "corrupt_in")


class Histogram:
    """Counts of durations in 1 us bins up to 50 ms, with the exact maximum (bounded memory)."""

    _BINS = 50_000

    def __init__(self) -> None:
        self.counts = [0] * (self._BINS + 1)
        self.n = 0
        self.max = 0.0

    def add(self, x: float) -> None:
        i = int(x * 1e6) if x > 0.0 else 0
        self.counts[i if i < self._BINS else self._BINS] += 1
        self.n += 1
        if x > self.max:
            self.max = x

    def quantile(self, q: float) -> float | None:
        if not self.n:
            return None
        rank = q * (self.n - 1)
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen > rank:
                # The bin's centre, but never beyond the largest value seen.
                return min((i + 0.5) * 1e-6, self.max)
        return self.max


@dataclass(kw_only=True)
class EmulatorReport:
    """What happened during an emulator run.

    Times ``t`` are the scheduled cycle times since the start of the run [s].

    Attributes
    ----------
    cycles : int
        Executed cycles (simulation steps).
    skipped_cycles : int
        Deadlines skipped because the emulator fell a whole period behind.
    monitoring_sent : int
        Monitoring messages produced (before injected faults).
    answers_received : int
        Command messages from the client that decoded.
    answers_invalid : int
        Datagrams from the client that did not decode as a command message
        (malformed, wrong message identifier).
    answers_foreign : int
        Datagrams from other addresses (ignored).
    answers_stale : int
        Answers whose client sequence counter was not newer than the last
        accepted one (ignored).
    late_answers : int
        Answers that arrived after the next monitoring message was produced.
    missed_cycles : int
        Cycles in which an answer was due and no new one had arrived.
    missed_commanding : int
        The part of ``missed_cycles`` in COMMANDING_WAIT and COMMANDING_ACTIVE.
    send_errors : int
        Datagrams the operating system refused to send.
    session_drops : list of (float, str)
        Time and reason of each session drop.
    states : list of (float, SessionState)
        Session state transitions, starting with ``IDLE`` at 0.
    quality : dict of str to int
        Cycles spent at each connection quality (outside ``IDLE``).
    latency_median_s, latency_p99_s, latency_max_s : float or None
        Latency from a monitoring message leaving the cycle to its answer [s].
    cycle_delay_median_s, cycle_delay_p99_s, cycle_delay_max_s : float or None
        How late cycles started after their deadline [s].
    overruns : int
        Cycles that started more than :data:`~iiwa_ident.emulator.OVERRUN_S` late.
    resent : int
        Lockstep: monitoring messages sent again to a client that was not
        (yet) answering.
    resent_answers : int
        Lockstep: answers to a message sent again beyond the first (ignored).
    client_gone : int
        Lockstep: times the client did not answer within the guard time.
    unsent : int
        Lockstep: commanding messages not sent while the session of a client
        taken for gone ran out its timeout.
    stalled_cycles : int
        Cycles of an injected robot-side stall (:attr:`EmulatorConfig.stalls`),
        in which no message was sent.
    safety_stop : str
        The limit whose violation stopped the robot ("" when none was).
    safety_stop_t_s : float or None
        When it did [s].
    faults : dict of str to int
        Injected faults, named as the :class:`Faults` fields: ``loss``,
        ``jitter`` (datagrams delayed), ``duplicate``, ``reorder``,
        ``corrupt``; and by direction ``loss_out``, ``loss_in`` (robot to
        client, client to robot), ``corrupt_out``, ``corrupt_in``.
    commanding_s : float
        Total time in ``COMMANDING_ACTIVE`` [s].
    wall_s : float
        Wall time of the run [s].
    end_reason : str
        ``"duration"``, ``"stopped"``, ``"max_wall"``, ``"client_gone"`` (silent for
        :attr:`~iiwa_ident.emulator.EmulatorConfig.idle_timeout_s`) or ``"safety_stop"``.
    lockstep : bool
        Whether the run was in lockstep (times are then virtual).
    dataset : Path or None
        The robot-side dataset written, if any.
    dataset_error : str or None
        Why the dataset could not be written, if it could not.
    """

    cycles: int = 0
    skipped_cycles: int = 0
    monitoring_sent: int = 0
    answers_received: int = 0
    answers_invalid: int = 0
    answers_foreign: int = 0
    answers_stale: int = 0
    late_answers: int = 0
    missed_cycles: int = 0
    missed_commanding: int = 0
    send_errors: int = 0
    session_drops: list[tuple[float, str]] = field(default_factory=list)
    states: list[tuple[float, SessionState]] = field(default_factory=list)
    quality: dict[str, int] = field(default_factory=lambda: {q.name: 0 for q in ConnectionQuality})
    latency_median_s: float | None = None
    latency_p99_s: float | None = None
    latency_max_s: float | None = None
    cycle_delay_median_s: float | None = None
    cycle_delay_p99_s: float | None = None
    cycle_delay_max_s: float | None = None
    overruns: int = 0
    resent: int = 0
    resent_answers: int = 0
    client_gone: int = 0
    unsent: int = 0
    stalled_cycles: int = 0
    safety_stop: str = ""
    safety_stop_t_s: float | None = None
    faults: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FAULT_KINDS, 0))
    commanding_s: float = 0.0
    wall_s: float = 0.0
    end_reason: str = ""
    dataset: Path | None = None
    dataset_error: str | None = None
    lockstep: bool = False

    def state_sequence(self) -> list[SessionState]:
        """The session states in the order they were entered."""
        return [s for _, s in self.states]

    def as_dict(self) -> dict[str, Any]:
        """The report as plain JSON types (states by name, paths as strings)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "states":
                value = [{"t_s": t, "state": SessionState(s).name} for t, s in value]
            elif f.name == "session_drops":
                value = [{"t_s": t, "reason": r} for t, r in value]
            elif isinstance(value, Path):
                value = str(value)
            elif isinstance(value, dict):
                value = dict(value)
            elif isinstance(value, float) and not math.isfinite(value):
                value = None
            out[f.name] = value
        return out
