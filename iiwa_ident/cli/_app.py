"""The typer application and the error convention shared by all subcommands."""

from __future__ import annotations

import inspect
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

import typer

from iiwa_ident._toml import write_atomic
from iiwa_ident.errors import IiwaIdentError

__all__ = ["app", "fail", "json_text", "write_json", "parse_pose", "json_option", "figures_option",
           "datasets_argument", "model_option", "plant_option", "STARTING_MODEL"]

#: Width the help is laid out for: a terminal of 80 columns, less the margins rich keeps.
HELP_WIDTH = 78


def _command_lines(line: str, indent: str, width: int) -> list[str]:
    """An example command, broken before its options (a ``\\`` continuation) to fit ``width``."""
    if len(indent) + len(line) <= width:
        return [indent + line]
    words = re.split(r" (?=--?\w)", line)
    out: list[str] = []
    cur = words[0]
    for w in words[1:]:
        lead = indent if not out else indent + "    "
        if len(lead) + len(cur) + len(w) + 3 > width:
            out.append(lead + cur + " \\")
            cur = w
        else:
            cur += " " + w
    out.append((indent if not out else indent + "    ") + cur)
    return out


def reflow_help(text: str, width: int = HELP_WIDTH) -> str:
    """A docstring laid out for the terminal: each prose paragraph one line (the terminal wraps it), indented
    lines (examples, code) kept as they are, an example command too long for ``width`` broken before an option.

    Examples
    --------
    >>> print(reflow_help('''Fit the joint.
    ...
    ...     Reads the chirp and
    ...     writes a model.
    ...
    ...     Example:
    ...       iiwa-ident fit chirp.h5 --out model.toml --json fit.json''', width=50))
    Fit the joint.
    <BLANKLINE>
    Reads the chirp and writes a model.
    <BLANKLINE>
    Example:
      iiwa-ident fit chirp.h5 --out model.toml \\
          --json fit.json
    """
    out = []
    for para in re.split(r"\n\s*\n", inspect.cleandoc(text)):
        block: list[str] = []
        prose: list[str] = []
        command: list[str] = []  # the example being read: its indent, then its text

        def flush(block: list[str] = block, prose: list[str] = prose, command: list[str] = command) -> None:
            if prose:
                block.append(" ".join(prose))
                prose.clear()
            if command:
                block.extend(_command_lines(command[1], command[0], width))
                command.clear()

        for line in para.split("\n"):
            stripped = line.lstrip()
            if command and line.startswith(" ") and stripped.startswith("-"):
                # The example goes on, on its own line (with or without a backslash): one command.
                command[1] = command[1].removesuffix("\\").rstrip() + " " + stripped
                continue
            if not line.startswith(" "):
                if command:
                    flush()
                prose.append(line.strip())
                continue
            flush()
            indent = line[:len(line) - len(stripped)]
            if stripped.startswith("iiwa-ident "):
                command[:] = [indent, stripped]
            else:
                block.append(line)
        flush()
        out.append("\n".join(block))
    return "\n\n".join(out)


class _BracketsAsWritten(typer.core.TyperCommand):
    """A command whose help reads well on an 80-column terminal and shows square brackets as written.

    The help is rendered with rich markup, which keeps a docstring's line breaks (prose broke twice per
    line, examples mid-argument: :func:`reflow_help` lays it out) and takes ``[s]`` or ``[rad]`` for a
    style tag and drops it ("Run length [s]." came out as "Run length ."): the brackets are escaped.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        from rich.markup import escape

        if self.help:
            self.help = escape(reflow_help(self.help))
        for param in self.params:
            option: Any = param  # click's options carry a help text, its arguments not
            if getattr(option, "help", None):
                option.help = escape(option.help)


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


#: The commands in the order of the work: everything at once; experiments and data; identification; the
#: controller from design to the live run; reports and fleets.
WORKFLOW = ("pipeline", "chirp", "simulate", "plant", "import", "info", "model", "fit", "ripple", "compare",
            "diagnose", "design", "deploy", "emulate", "run", "kappa", "report", "fleet")


def first_example(name: str, help_text: str) -> str | None:
    """The first example of command ``name`` in its help, its continued lines joined (None: it has none).

    Examples
    --------
    >>> first_example("fit", "Fit.\\n\\nExample:\\n  iiwa-ident fit a.h5 \\\\\\n      --out m.toml\\n")
    'iiwa-ident fit a.h5 --out m.toml'
    """
    lines = [line.strip() for line in inspect.cleandoc(help_text or "").splitlines()]
    found = []
    for k, line in enumerate(lines):
        if line.startswith(f"iiwa-ident {name} "):
            parts = [line]
            while parts[-1].endswith("\\") and k + 1 < len(lines):
                parts[-1] = parts[-1].removesuffix("\\").rstrip()
                k += 1
                parts.append(lines[k])
            found.append(" ".join(parts))
    # One that stands alone: no shell variable set in the help's text around it.
    return next((x for x in found if "$" not in x), found[0] if found else None)


class _WorkflowGroup(typer.core.TyperGroup):
    """The top level: commands listed in :data:`WORKFLOW` order, then one example of each, in that order."""

    def list_commands(self, ctx) -> list[str]:
        names = list(self.commands)
        return sorted(names, key=lambda n: (WORKFLOW.index(n) if n in WORKFLOW else len(WORKFLOW), names.index(n)))

    def format_help(self, ctx, formatter) -> None:
        if self.epilog is None:
            lines = []
            for name in self.list_commands(ctx):
                example = first_example(name, self.commands[name].help or "")
                if example is not None:
                    lines += _command_lines(example, "  ", HELP_WIDTH)
            self.epilog = "One example of each, in the order of the work:\n" + "\n".join(lines)
        super().format_help(ctx, formatter)


class _App(typer.Typer):
    """The typer application, its commands showing units such as ``[s]`` in their help."""

    def __init__(self, **kwargs) -> None:
        super().__init__(cls=_WorkflowGroup, **kwargs)

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


#: Where a command that checks a model against datasets takes it from without ``--model``.
STARTING_MODEL = "the joint's starting model from the robot's description at the datasets' pose"


def datasets_argument(what: str):
    """The DATA argument of an analysis command: dataset files of ``what``, or folders of them."""
    return typer.Argument(help=f"{what}, or folders of them.")


def model_option(what: str, default: str = STARTING_MODEL):
    """The ``--model FILE`` option of a command: the model file ``what``, else ``default``."""
    return typer.Option("--model", help=f"{what} (default: {default}).")


def plant_option(condition: str = ""):
    """The ``--plant FILE`` option of a command that simulates the joint (``condition``: when it applies)."""
    return typer.Option("--plant", help=f"{condition}{'plant' if condition else 'Plant'} TOML file of the simulated "
                                        "joint (default: the shipped default plant).")


def figures_option(what: str = "PNG figures"):
    """The ``--figures DIR`` option of a command: a folder for ``what``."""
    return typer.Option("--figures", help=f"Folder for {what}.")


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print ``error: message`` on stderr and return the exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def check_joint(joint: int | None, option: str = "--joint") -> None:
    """Refuse a joint number outside 1-7 in one line naming the option (None: not given)."""
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
