"""Start-up of the command line: the libraries a command needs are imported where it uses them, so that
``iiwa-ident --help`` and a command's help print at once. Counted in a fresh interpreter, not timed."""

from __future__ import annotations

import json
import subprocess
import sys

#: Imported by nothing at start-up: together they took 1.4 s before each command imported what it uses.
NOT_AT_START = ("control", "matplotlib", "numpy", "scipy", "casadi", "h5py", "mujoco")


def _imported_by(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport json, sys; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout
    return set(json.loads(out.strip().splitlines()[-1]))


def test_help_imports_no_numerical_library():
    commands = ["import", "info", "chirp", "simulate", "plant", "fit", "ripple", "design", "deploy", "run",
                "diagnose", "compare", "model", "emulate", "pipeline", "report", "fleet"]
    mods = _imported_by("from typer.testing import CliRunner\nfrom iiwa_ident.cli import app\n"
                        "assert CliRunner().invoke(app, ['--help']).exit_code == 0\n"
                        f"for c in {commands!r}:\n"
                        "    r = CliRunner().invoke(app, [c, '--help'])\n"
                        "    assert r.exit_code == 0 and 'Usage' in r.output, (c, r.output)")
    assert "iiwa_ident.cli._design_cmd" in mods
    for name in NOT_AT_START:
        assert name not in mods, name


def test_the_emulator_process_does_not_load_the_controller_design():
    """The robot side (its own process in every closed-loop test) needs the messages and the simulator only."""
    mods = _imported_by("import iiwa_ident.emulator")
    for name in ("iiwa_ident.design", "iiwa_ident.deploy", "iiwa_ident.runtime", "iiwa_ident.ident", "control",
                 "matplotlib"):
        assert name not in mods, name


def _help(*args: str) -> list[str]:
    """The help as an 80-column terminal shows it."""
    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    res = CliRunner().invoke(app, [*args, "--help"], env={"COLUMNS": "80", "TERMINAL_WIDTH": "80"}, color=False)
    assert res.exit_code == 0, res.output
    return [line.rstrip() for line in res.output.splitlines()]


def _body(lines: list[str]) -> list[str]:
    """The help's text above its option panels, stripped."""
    end = next((i for i, x in enumerate(lines) if x.strip().startswith("╭")), len(lines))
    return [x.strip() for x in lines[:end]]


def _examples_whole(name: str, body: list[str]) -> int:
    """Check that every example in ``body`` is whole on its lines; the number of examples of ``name``."""
    in_example = False
    for a, b in zip(body, body[1:]):
        in_example = a.startswith("iiwa-ident ") or (in_example and a.startswith("-"))
        # After an example's line, a line that starts with an option continues it only after a backslash: else
        # the terminal wrapped the example mid-argument.
        if in_example and b.startswith("-"):
            assert a.endswith("\\"), (name, a, b)
        if in_example and a.endswith("\\"):
            assert b.startswith("-"), (name, a, b)
    return sum(x.startswith(f"iiwa-ident {name} ") for x in body)


def test_every_help_reads_on_an_80_column_terminal():
    # Examples broke mid-argument and prose broke twice per line: the docstrings' line breaks were kept.
    import typer

    from iiwa_ident.cli import app
    from iiwa_ident.cli._app import WORKFLOW

    group = typer.main.get_command(app)
    assert list(group.list_commands(None)) == list(WORKFLOW)
    top = [x.strip() for x in _help()]
    shown = [x.split()[1] for x in top[top.index("One example of each, in the order of the work:"):]
             if x.startswith("iiwa-ident ")]
    assert shown == list(WORKFLOW)
    _examples_whole("", top)
    for name in WORKFLOW:
        body = _body(_help(name))
        assert _examples_whole(name, body) >= 1, name
        # Prose fills the lines: a line of a paragraph other than its last is not cut short.
        for a, b in zip(body, body[1:]):
            if a and b and not a.startswith(("Usage", "iiwa-ident", "-", "D=")) and a[-1] != ":" and \
                    not b.startswith(("iiwa-ident", "-", "D=")):
                assert len(a) >= 50, (name, a, b)
