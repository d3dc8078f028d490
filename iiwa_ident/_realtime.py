"""Keep the garbage collector out of a 1 kHz loop."""

from __future__ import annotations

import contextlib
import gc
from typing import Iterator

__all__ = ["no_gc_pauses"]


@contextlib.contextmanager
def no_gc_pauses() -> Iterator[None]:
    """Freeze the objects that exist now out of the collector and disable it for the block.

    A full collection of a large heap (a test session, a notebook) stalls the
    interpreter for tens of milliseconds: over FRI that is a dropped session.
    The loops allocate little, so memory stays bounded for runs of minutes.
    """
    enabled = gc.isenabled()
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        if enabled:
            gc.enable()
