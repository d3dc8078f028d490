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
    assert "iiwa_ident.cli.design_cmd" in mods
    for name in NOT_AT_START:
        assert name not in mods, name


def test_the_emulator_process_does_not_load_the_controller_design():
    """The robot side (its own process in every closed-loop test) needs the messages and the simulator only."""
    mods = _imported_by("import iiwa_ident.emulator")
    for name in ("iiwa_ident.design", "iiwa_ident.deploy", "iiwa_ident.runtime", "iiwa_ident.ident", "control",
                 "matplotlib"):
        assert name not in mods, name
