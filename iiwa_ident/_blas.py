"""One BLAS thread for the pipeline.

The design's margin search and the fits call small linear-algebra routines
thousands of times. With OpenBLAS's worker threads on a busy 2-core machine
each call waits for threads the other processes hold: the kappa search took
15 s instead of 0.35 s. The loaded OpenBLAS libraries are found in the
process's memory map and set to one thread for the block (a no-op where that
is not possible); child processes inherit ``OPENBLAS_NUM_THREADS=1``.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Iterator
from typing import Any

__all__ = ["single_threaded_blas"]

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
            "openblas_set_num_threads")


def _openblas_libraries() -> list[str]:
    try:
        with open("/proc/self/maps") as maps:
            return sorted({line.split()[-1] for line in maps
                           if "openblas" in line.lower() and ".so" in line.split()[-1]})
    except OSError:
        return []


def _set_threads(n: int) -> list[tuple[Any, int]]:
    """Set every loaded OpenBLAS to ``n`` threads; return (setter, previous count) pairs to restore."""
    import numpy  # noqa: F401  (load every BLAS the stages use before looking for them)
    import scipy.linalg  # noqa: F401  (as numpy)

    changed = []
    for path in _openblas_libraries():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SETTERS:
            setter = getattr(lib, name, None)
            getter = getattr(lib, name.replace("set_", "get_"), None)
            if setter is None:
                continue
            before = int(getter()) if getter is not None else 0
            setter(ctypes.c_int(n))
            changed.append((setter, before))
            break
    return changed


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with one OpenBLAS thread (restored afterwards)."""
    old_env = os.environ.get("OPENBLAS_NUM_THREADS")
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    changed = _set_threads(1)
    try:
        yield
    finally:
        for setter, before in changed:
            if before > 0:
                setter(ctypes.c_int(before))
        if old_env is None:
            os.environ.pop("OPENBLAS_NUM_THREADS", None)
        else:
            os.environ["OPENBLAS_NUM_THREADS"] = old_env
