"""The connection quality the robot side judges and reports to the client.

Judged every cycle over the last ``window`` cycles in which an answer was
due (:class:`QualityThresholds`): the loss is the fraction of those cycles
without a new answer, the latency the mean time from a monitoring message
being handed to the socket (before any injected delay) to the arrival of
its answer. The defaults:

============  ==========  ==================
quality       loss        mean latency
============  ==========  ==================
EXCELLENT     <= 1 %      < 0.3 ms
GOOD          <= 15 %     < 0.8 ms
FAIR          <= 30 %     < 1 send period
POOR          otherwise   (and with fewer than 10 cycles judged)
============  ==========  ==================

The loss thresholds are wide on purpose: a lost datagram costs the robot
one cycle on the held command, and it is silence (``timeout_s``) that ends
a session, so a session survives a few percent of independent loss in each
direction (the round trip loses about twice that) over a 500-cycle window.
"""

from __future__ import annotations

import math
from collections import deque

from iiwa_ident.emulator._config import QualityThresholds
from iiwa_ident.fri import ConnectionQuality

__all__ = ["connection_quality", "QualityWindow"]

_DEFAULT_QUALITY = QualityThresholds()


def connection_quality(answered: int, due: int, mean_latency_s: float | None, period_s: float,
                       thresholds: QualityThresholds | None = None) -> ConnectionQuality:
    """The connection quality of a window of cycles (module docstring).

    Parameters
    ----------
    answered : int
        Cycles of the window in which a new answer arrived.
    due : int
        Cycles of the window in which an answer was due.
    mean_latency_s : float or None
        Mean latency of the answers [s] (None: no answers).
    period_s : float
        Send period [s].
    thresholds : QualityThresholds, optional
        The limits (default: the defaults).

    Returns
    -------
    ConnectionQuality
    """
    q = thresholds or _DEFAULT_QUALITY
    if due < q.min_samples or mean_latency_s is None:
        return ConnectionQuality.POOR
    loss = 1.0 - answered / due
    if loss <= q.excellent_loss and mean_latency_s < q.excellent_latency_s:
        return ConnectionQuality.EXCELLENT
    if loss <= q.good_loss and mean_latency_s < q.good_latency_s:
        return ConnectionQuality.GOOD
    fair_latency = period_s if q.fair_latency_s is None else q.fair_latency_s
    if loss <= q.fair_loss and mean_latency_s < fair_latency:
        return ConnectionQuality.FAIR
    return ConnectionQuality.POOR


class QualityWindow:
    """The last ``thresholds.window`` cycles in which an answer was due, judged in O(1) per cycle.

    Parameters
    ----------
    thresholds : QualityThresholds
        The limits and the window's length.
    period_s : float
        Send period [s].
    """

    def __init__(self, thresholds: QualityThresholds, period_s: float) -> None:
        self.thresholds, self.period_s = thresholds, period_s
        self._window: deque[tuple[int, float]] = deque()
        self._answered = 0
        self._latency = 0.0
        self._pushes = 0

    def add(self, answered: int, latency_s: float) -> None:
        """Add one cycle with an answer due: 1 if a new one arrived, with its latency [s]."""
        w = self._window
        w.append((answered, latency_s))
        self._answered += answered
        self._latency += latency_s
        if len(w) > self.thresholds.window:
            a, lat = w.popleft()
            self._answered -= a
            self._latency -= lat
        self._pushes += 1
        if self._pushes % 10_000 == 0:  # keep rounding errors of the running sum from piling up
            self._latency = math.fsum(lat for _, lat in w)

    def quality(self) -> ConnectionQuality:
        """The quality of the window now."""
        n = self._answered
        mean = self._latency / n if n else None
        return connection_quality(n, len(self._window), mean, self.period_s, self.thresholds)
