"""Progress on long commands: shown on a terminal's standard error, never on a pipe, never with --quiet."""

from __future__ import annotations

import io

from typer.testing import CliRunner

from iiwa_ident.cli import _progress, app


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_shown_on_a_terminal_with_the_phase_and_the_work_done(monkeypatch):
    err = _Terminal()
    monkeypatch.setattr("sys.stderr", err)
    _progress.set_quiet(False)
    with _progress.progress("fitting chirp.h5") as shown:
        shown.say("drawing the figures")
        shown.advance(50, 100)
    assert "drawing the figures" in err.getvalue()


def test_quiet_on_a_pipe_and_with_quiet(monkeypatch):
    for err, quiet in ((io.StringIO(), False), (_Terminal(), True)):
        monkeypatch.setattr("sys.stderr", err)
        _progress.set_quiet(quiet)
        with _progress.progress("fitting chirp.h5") as shown:
            shown.say("drawing the figures")
        assert err.getvalue() == ""
    _progress.set_quiet(False)


def test_the_quiet_option(tmp_path):
    res = CliRunner().invoke(app, ["--quiet", "plant", "--help"])
    assert res.exit_code == 0
    assert _progress._quiet
    CliRunner().invoke(app, ["plant", "--help"])
    assert not _progress._quiet
