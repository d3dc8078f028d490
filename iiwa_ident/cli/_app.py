"""The typer application and the error convention shared by all subcommands."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import typer

from iiwa_ident._toml import write_atomic
from iiwa_ident.errors import IiwaIdentError

__all__ = ["app", "fail", "json_text", "write_json", "parse_pose", "json_option", "figures_option"]

class _BracketsAsWritten(typer.core.TyperCommand):
    """A command whose help shows square brackets as written.

    The help is rendered with rich markup, which takes ``[s]`` or ``[rad]`` for a style tag and
    drops it ("Run length [s]." came out as "Run length ."): the brackets are escaped.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        from rich.markup import escape

        if self.help:
            self.help = escape(self.help)
        for param in self.params:
            if getattr(param, "help", None):
                param.help = escape(param.help)


class _Analysis(_BracketsAsWritten):
    """A command of heavy linear algebra: run with one BLAS thread (:mod:`iiwa_ident._blas`).

    Thousands of small products: OpenBLAS's worker threads only wait for each other, and for the
    cores other processes hold (the pipeline's fits ran 1.5-2 times slower with them).
    """

    def invoke(self, ctx):
        from iiwa_ident._blas import single_threaded_blas

        with single_threaded_blas():
            return super().invoke(ctx)


#: The commands that run with one BLAS thread (see :class:`_Analysis`).
ANALYSIS_COMMANDS = ("fit", "ripple", "diagnose", "design", "deploy", "report")


class _App(typer.Typer):
    """The typer application, its commands showing units such as ``[s]`` in their help."""

    def command(self, name=None, *args, cls=None, **kwargs):
        default = _Analysis if name in ANALYSIS_COMMANDS else _BracketsAsWritten
        return super().command(name, *args, cls=cls or default, **kwargs)


app = _App(
    name="iiwa-ident",
    help="Identify and tune the joint torque control of a KUKA LBR iiwa.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from iiwa_ident import tool_version

        typer.echo(f"iiwa-ident {tool_version()}")
        raise typer.Exit()


@app.callback()
def _main(
    show_version: bool = typer.Option(False, "--version", help="Print the version and exit.", callback=_version,
                                      is_eager=True),
    quiet: bool = typer.Option(False, "--quiet", help="No progress display on long commands (it shows only on a "
                                                      "terminal anyway)."),
) -> None:
    """Identify and tune the joint torque control of a KUKA LBR iiwa."""
    from iiwa_ident.cli._progress import set_quiet

    set_quiet(quiet)


def json_option(what: str):
    """The ``--json OUT`` option of a command: write ``what`` as JSON."""
    return typer.Option("--json", help=f"Write {what} as JSON.")


def figures_option(what: str = "PNG figures"):
    """The ``--figures DIR`` option of a command: a folder for ``what``."""
    return typer.Option("--figures", help=f"Folder for {what}.")


def fail(message: str, code: int = 2) -> "typer.Exit":
    """Print ``error: message`` on stderr and return the exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def check_joint(joint: int | None, option: str = "--joint") -> None:
    """Refuse a joint number outside 1-7 in one line naming the option (None: not given)."""
    from iiwa_ident.errors import IiwaIdentError

    if joint is not None and not 1 <= joint <= 7:
        raise IiwaIdentError(f"{option} {joint}: an iiwa joint is 1-7")


def json_text(doc: dict) -> str:
    """The ``--json`` document as every command writes it."""
    return json.dumps(doc, indent=2) + "\n"


def write_json(path: Path, doc: dict) -> Path:
    """Write a ``--json`` document atomically and say so."""
    write_atomic(path, json_text(doc))
    typer.echo(f"wrote {path}")
    return path


def parse_pose(text: str, option: str) -> tuple[float, ...]:
    """A pose option (7 comma-separated joint angles in degrees) -> the joint positions [rad]."""
    try:
        degrees = [float(part) for part in text.split(",")]
    except ValueError:
        degrees = []
    if len(degrees) != 7 or not all(math.isfinite(d) for d in degrees):
        raise IiwaIdentError(f"{option} {text!r}: expected 7 comma-separated joint angles in degrees "
                             "(e.g. 0,30,0,-90,0,60,0)")
    return tuple(math.radians(d) for d in degrees)


def run_app(argv: list[str] | None = None) -> None:
    """Run the CLI; user errors become one line on stderr and exit code 2."""
    try:
        app(args=argv, standalone_mode=True)
    except IiwaIdentError as err:  # raised outside a command's own handler
        typer.echo(f"error: {err}", err=True)
        sys.exit(2)
