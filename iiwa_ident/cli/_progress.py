"""What a long command is doing, shown on the terminal while it runs.

A spinner, the phase and the time elapsed, on standard error, erased when the command ends (rich's
progress display, installed with typer). Quiet where nobody watches it: when standard error is not a
terminal (a pipe, a log file, the tests) or after ``iiwa-ident --quiet``. The command's own output
(standard output) is never touched.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["Progress", "progress", "set_quiet"]

_quiet = False


def set_quiet(quiet: bool) -> None:
    """Switch the progress display off (``--quiet``) or back on."""
    global _quiet
    _quiet = quiet


class Progress:
    """The display of one command: :meth:`say` names the phase, :meth:`advance` counts work of a known size
    (the display then shows a bar and the time left). Every call is a no-op when quiet."""

    def __init__(self, bar=None, task=None) -> None:
        self._bar, self._task = bar, task

    def say(self, text: str) -> None:
        if self._bar is not None:
            self._bar.update(self._task, description=text)

    def advance(self, done: int, total: int) -> None:
        if self._bar is not None:
            self._bar.update(self._task, completed=done, total=total)


@contextmanager
def progress(phase: str) -> Iterator[Progress]:
    """Show ``phase`` with a spinner and the elapsed time (with a bar and the time left once the work's size is
    known) until the block ends.

    Examples
    --------
    >>> with progress("fitting chirp.h5") as shown:  # quiet here: standard error is not a terminal
    ...     shown.say("drawing the figures")
    """
    if _quiet or not sys.stderr.isatty():
        yield Progress()
        return
    from rich.console import Console
    from rich.progress import BarColumn, SpinnerColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
    from rich.progress import Progress as RichProgress

    with RichProgress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                      TextColumn("left"), TimeRemainingColumn(), console=Console(file=sys.stderr),
                      transient=True) as bar:
        yield Progress(bar, bar.add_task(phase, total=None))
