"""Command-line interface: a thin layer over the library.

Each ``*_cmds`` module registers its subcommands on :data:`app`.
"""

from iiwa_ident.cli import (
    _compare_cmd,
    _data_cmds,
    _deploy_cmd,
    _design_cmd,
    _diagnose_cmd,
    _emulate_cmd,
    _fit_cmd,
    _fleet_cmd,
    _kappa_cmd,
    _model_cmd,
    _pipeline_cmd,
    _report_cmd,
    _ripple_cmd,
    _run_cmd,
    _sim_cmds,
)
from iiwa_ident.cli._app import app, fail, run_app

__all__ = ["app", "fail", "main"]


def main() -> None:
    """Console-script entry point ``iiwa-ident``."""
    run_app()
