"""Command-line interface: a thin layer over the library.

Each ``*_cmds`` module registers its subcommands on :data:`app`.
"""

from iiwa_ident.cli import compare_cmd as _compare_cmd
from iiwa_ident.cli import data_cmds as _data_cmds
from iiwa_ident.cli import deploy_cmd as _deploy_cmd
from iiwa_ident.cli import design_cmd as _design_cmd
from iiwa_ident.cli import diagnose_cmd as _diagnose_cmd
from iiwa_ident.cli import emulate_cmd as _emulate_cmd
from iiwa_ident.cli import fit_cmd as _fit_cmd
from iiwa_ident.cli import fleet_cmd as _fleet_cmd
from iiwa_ident.cli import kappa_cmd as _kappa_cmd
from iiwa_ident.cli import model_cmd as _model_cmd
from iiwa_ident.cli import pipeline_cmd as _pipeline_cmd
from iiwa_ident.cli import report_cmd as _report_cmd
from iiwa_ident.cli import ripple_cmd as _ripple_cmd
from iiwa_ident.cli import run_cmd as _run_cmd
from iiwa_ident.cli import sim_cmds as _sim_cmds
from iiwa_ident.cli._app import app, fail, run_app

__all__ = ["app", "fail", "main"]


def main() -> None:
    """Console-script entry point ``iiwa-ident``."""
    run_app()
