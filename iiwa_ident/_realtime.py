"""Keep a 1 kHz loop on time: no collector pauses, one CPU, real-time priority, memory locked."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import gc
import os
import signal
import threading
from collections.abc import Callable, Iterator

from iiwa_ident.errors import IiwaIdentError

__all__ = ["no_gc_pauses", "realtime_process", "stop_signals", "GRANT_HINT"]

#: How a user gets the rights for SCHED_FIFO and mlockall without running as root.
GRANT_HINT = ("to grant them, add '<user> - rtprio 99' and '<user> - memlock unlimited' to "
              "/etc/security/limits.conf and log in again")

_MCL_CURRENT, _MCL_FUTURE = 1, 2

_gc_lock = threading.Lock()
_gc_depth = 0  # no_gc_pauses blocks open now (in any thread)
_gc_was_enabled = True


@contextlib.contextmanager
def no_gc_pauses() -> Iterator[None]:
    """Freeze the objects that exist now out of the collector and disable it for the block.

    A full collection of a large heap (a test session, a notebook) stalls the
    interpreter for tens of milliseconds: over FRI that is a dropped session.
    The loops allocate little, so memory stays bounded for runs of minutes.
    Blocks may overlap (loops in several threads): the first in takes the
    collector's state, the last out gives it back.
    """
    global _gc_depth, _gc_was_enabled
    with _gc_lock:
        if _gc_depth == 0:
            _gc_was_enabled = gc.isenabled()
            gc.freeze()
            gc.disable()
        _gc_depth += 1
    try:
        yield
    finally:
        with _gc_lock:
            _gc_depth -= 1
            if _gc_depth == 0:
                gc.unfreeze()
                if _gc_was_enabled:
                    gc.enable()


@contextlib.contextmanager
def stop_signals(handler: Callable[[int, object], None]) -> Iterator[None]:
    """For the block, SIGINT and SIGTERM call ``handler(signum, frame)`` instead of ending the process.

    Installed only in the main thread (Python allows no other). At the end the
    previous handlers come back; one installed from C, which Python reads as
    None and cannot put back, gives way to the default action, and nothing here
    raises over the block's own end.
    """
    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, previous in old.items():
            try:
                signal.signal(sig, signal.SIG_DFL if previous is None else previous)
            except (TypeError, ValueError, OSError):
                pass


def _libc_call(name: str) -> Callable[..., int] | None:
    path = ctypes.util.find_library("c")
    if path is None:
        return None
    try:
        fn = getattr(ctypes.CDLL(path, use_errno=True), name)
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_int
    return fn


def _mlockall() -> str:
    """Lock the process's pages in RAM (no page fault in the loop); "" or why not."""
    fn = _libc_call("mlockall")
    if fn is None:
        return "mlockall unavailable"
    if fn(ctypes.c_int(_MCL_CURRENT | _MCL_FUTURE)) == 0:
        return ""
    err = ctypes.get_errno()
    return "mlockall not permitted" if err in (errno.EPERM, errno.ENOMEM) else f"mlockall: {os.strerror(err)}"


def _munlockall() -> None:
    fn = _libc_call("munlockall")
    if fn is not None:
        fn()


@contextlib.contextmanager
def realtime_process(cpu: int | None = None, priority: int = 80,
                     say: Callable[[str], None] | None = None) -> Iterator[str]:
    """Run the block pinned to one CPU, under ``SCHED_FIFO`` and with its memory locked, where permitted.

    Everything is undone on exit (the caller may be a test session or a
    notebook). Start helper processes (the log writer) before the block: they
    inherit the affinity and the policy of the moment they start.

    Parameters
    ----------
    cpu : int, optional
        CPU to pin the calling process to (default: the highest one it may run
        on, where isolated CPUs usually are); -1 leaves the affinity alone.
    priority : int
        ``SCHED_FIFO`` priority, 1-99; 0 leaves the scheduling policy alone.
    say : callable, optional
        Receives one line: what was set and, if something was not permitted,
        what and how to grant it.

    Yields
    ------
    str
        That line.
    """
    done: list[str] = []
    missing: list[str] = []
    old_affinity: set[int] | None = None
    old_policy: int | None = None
    old_param: os.sched_param | None = None
    locked = False
    has_sched = hasattr(os, "sched_setaffinity") and hasattr(os, "sched_setscheduler")
    try:
        if not has_sched:
            missing.append("CPU affinity and SCHED_FIFO unavailable on this system")
        else:
            if cpu != -1:
                allowed = os.sched_getaffinity(0)
                target = max(allowed) if cpu is None else int(cpu)
                if target not in allowed:
                    raise IiwaIdentError(f"CPU {target} is not one this process may run on "
                                         f"({', '.join(map(str, sorted(allowed)))})")
                old_affinity = allowed
                os.sched_setaffinity(0, {target})
                done.append(f"pinned to CPU {target}")
            if priority:
                if not 1 <= priority <= 99:
                    raise IiwaIdentError(f"SCHED_FIFO priority must be 1-99, got {priority}")
                policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
                try:
                    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
                except PermissionError:
                    missing.append("SCHED_FIFO not permitted")
                else:
                    old_policy, old_param = policy, param
                    done.append(f"SCHED_FIFO priority {priority}")
        why = _mlockall()
        if why:
            missing.append(why)
        else:
            locked = True
            done.append("memory locked")
        line = "real time: " + (", ".join(done) or "nothing set")
        if missing:
            line += "; " + ", ".join(missing) + ("; " + GRANT_HINT if any("permitted" in m for m in missing) else "")
        if say is not None:
            say(line)
        yield line
    finally:
        if locked:
            _munlockall()
        if old_policy is not None and old_param is not None:
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old_policy, old_param)
        if old_affinity is not None:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, old_affinity)
