"""Cost of :meth:`LogWriter.append` as seen by the 1 kHz loop.

Times each call with ``perf_counter_ns`` while the writer process runs, for
a 10-signal row given as a list and as a numpy array:

* burst: 200 000 appends back to back (the writer drains concurrently);
* paced: 3 s at 1 kHz, as in the real loop, so the writer's polls and
  flushes fall between and during the appends. A loop that sleeps between
  cycles finds its code and data cold, so the same copy into a private
  numpy array (no shared memory, no writer) is timed the same way as a
  control: the difference to it is what the ring costs.

Also prints the time of ``start()`` (spawning the writer) and ``close()``
(final rewrite of the file). Figures only, no pass/fail.

Run: ``.venv/bin/python bench/bench_logwriter.py``
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from iiwa_ident.datasets import LogWriter

SIGNALS = [
    "t", "q_m", "tau_j", "tau_c", "tau_r", "tau_j_filt", "tau_ext_est", "tau_add", "watchdog", "cycle_us",
]
N_BURST = 200_000
PACED_S = 3.0
RATE_HZ = 1000.0


def summary(label: str, ns: np.ndarray) -> None:
    us = ns / 1e3
    print(
        f"{label:34s} n={us.size:7d}  median {np.median(us):6.2f}  p99 {np.percentile(us, 99):6.2f}  "
        f"p99.9 {np.percentile(us, 99.9):6.2f}  max {us.max():8.2f}  [us]"
    )


def timer_floor(n: int) -> np.ndarray:
    """Cost of two perf_counter_ns calls, included in every figure below."""
    out = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        a = clock()
        out[i] = clock() - a
    return out


def burst(log: LogWriter, as_array: bool, t0: float) -> np.ndarray:
    rng = np.random.default_rng(1)
    values = rng.normal(size=(N_BURST, len(SIGNALS)))
    values[:, 0] = t0 + np.arange(N_BURST) / RATE_HZ
    rows = list(values) if as_array else values.tolist()
    out = np.empty(N_BURST)
    clock = time.perf_counter_ns
    append = log.append
    for i, row in enumerate(rows):
        a = clock()
        append(row)
        out[i] = clock() - a
    return out


class _PrivateCopy:
    """The control: what append does, into process-private memory."""

    def __init__(self, capacity: int) -> None:
        self.rows = np.zeros((capacity, len(SIGNALS)))
        self.head = memoryview(bytearray(8)).cast("q")
        self.n = 0

    def append(self, row) -> bool:
        self.rows[self.n % self.rows.shape[0]] = row
        self.n += 1
        self.head[0] = self.n
        return True


def paced(log: LogWriter | _PrivateCopy, t0: float) -> np.ndarray:
    n = int(PACED_S * RATE_HZ)
    out = np.empty(n)
    clock = time.perf_counter_ns
    append = log.append
    start = time.perf_counter()
    for i in range(n):
        row = [t0 + i / RATE_HZ] + [0.001 * i] * (len(SIGNALS) - 1)
        a = clock()
        append(row)
        out[i] = clock() - a
        delay = start + (i + 1) / RATE_HZ - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    return out


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.h5"
        log = LogWriter(path, SIGNALS, experiment="free", source="robot", joint=1,
                        sample_rate_hz=RATE_HZ, capacity_rows=2 * N_BURST + 10_000)
        t = time.perf_counter()
        log.start()
        t_start = time.perf_counter() - t

        summary("timer floor", timer_floor(N_BURST))
        summary("append, burst, list row", burst(log, as_array=False, t0=0.0))
        summary("append, burst, ndarray row", burst(log, as_array=True, t0=1000.0))
        summary("append, paced 1 kHz, list row", paced(log, t0=2000.0))
        summary("control: private copy, paced 1 kHz", paced(_PrivateCopy(60_000), t0=0.0))

        t = time.perf_counter()
        stats = log.close()
        t_close = time.perf_counter() - t
        size_mb = path.stat().st_size / 1e6
    print(f"start() {t_start * 1e3:.0f} ms; close() {t_close * 1e3:.0f} ms for {stats.written} rows "
          f"x {len(SIGNALS)} signals ({size_mb:.1f} MB); lost {stats.lost}")


if __name__ == "__main__":
    main()
