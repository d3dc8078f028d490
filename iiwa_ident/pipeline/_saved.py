"""What a stage computed, kept in the work folder for the report (``fit_result.h5``, ``ripple_result.h5``).

The report draws the stage's own result from these files instead of running the analysis again, so
``iiwa-ident report --workdir`` shows what the pipeline computed, in the time of drawing. Each file names
the files its result was computed from with their sha256; where one of them changed since, the file no
longer stands for them and the report computes the result again.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from iiwa_ident._h5tree import read_tree, write_tree
from iiwa_ident.errors import IiwaIdentError

__all__ = ["RESULT_PACKAGES", "save_results", "load_saved_results"]

#: Packages whose result dataclasses the kept files may hold (nothing else is built when they are read).
RESULT_PACKAGES = ("iiwa_ident.ident",)


def _digests(workdir: Path, inputs: Iterable[Path]) -> dict[str, str]:
    from iiwa_ident.datasets import sha256_file

    return {str(Path(p).resolve().relative_to(workdir.resolve())): sha256_file(p) for p in inputs}


def save_results(path: str | Path, workdir: str | Path, inputs: Iterable[Path], **results: Any) -> None:
    """Keep a stage's results in ``path`` with the sha256 of the work folder's files they were computed from.

    Parameters
    ----------
    path : path
        The HDF5 file to write (atomically).
    workdir : path
        The work folder; ``inputs`` are in it.
    inputs : iterable of path
        The files the results were computed from.
    **results
        The results by name: dataclasses of :data:`RESULT_PACKAGES` (``fit=FitResult``, ...).
    """
    write_tree(path, {"inputs": _digests(Path(workdir), inputs), **results})


def load_saved_results(path: str | Path, workdir: str | Path) -> dict[str, Any] | None:
    """The results kept in ``path`` by :func:`save_results`, or None where there are none that stand for
    the work folder's files (the file is absent or unreadable, or an input changed since)."""
    path, workdir = Path(path), Path(workdir)
    if not path.is_file():
        return None
    try:
        tree = read_tree(path, RESULT_PACKAGES)
        inputs = tree.pop("inputs")
        if _digests(workdir, (workdir / name for name in inputs)) != inputs:
            return None
    except (IiwaIdentError, KeyError, OSError, ValueError):
        return None
    return tree
