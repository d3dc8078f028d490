"""Start-up of the command line: the libraries a command needs are imported where it uses them, so that
``iiwa-ident --help`` and a command's help print at once. Counted in a fresh interpreter, not timed."""

from __future__ import annotations

import json
import subprocess
import sys

#: Imported by nothing at start-up (each took a quarter to most of a second to import).
NOT_AT_START = ("control", "matplotlib")


def _imported_by(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport json, sys; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout
    return set(json.loads(out.strip().splitlines()[-1]))


def test_help_imports_neither_python_control_nor_matplotlib():
    mods = _imported_by("from typer.testing import CliRunner\nfrom iiwa_ident.cli import app\n"
                        "assert CliRunner().invoke(app, ['--help']).exit_code == 0\n"
                        "assert CliRunner().invoke(app, ['design', '--help']).exit_code == 0")
    assert "iiwa_ident.cli.design_cmd" in mods
    for name in NOT_AT_START:
        assert name not in mods, name
