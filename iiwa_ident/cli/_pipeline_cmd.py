"""Subcommand ``pipeline``: every stage from the first chirp to the report, into one work folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident.cli._app import app, check_joint, fail, model_option, plant_option
from iiwa_ident.errors import IiwaIdentError

__all__ = ["pipeline_cmd"]


@app.command("pipeline")
def pipeline_cmd(
    workdir: Annotated[Path, typer.Option("--workdir", help="Folder for every intermediate file and report.pdf.")],
    target: Annotated[str, typer.Option("--target", help="'sim' (simulated joint, validation against the FRI "
                                        "emulator) or 'robot' (FRI).")] = "sim",
    logs: Annotated[Optional[list[Path]], typer.Option("--logs", help="Your own logs instead of experiments: "
                                                       "dataset files, folders of column files "
                                                       "(joint_position_measured.txt, ...) or folders of such "
                                                       "folders: --logs A B C, or --logs repeated.")] = None,
    more_logs: Annotated[Optional[list[Path]], typer.Argument(help="More --logs paths.", show_default=False,
                                                              metavar="[PATHS]...")] = None,
    split_runs: Annotated[bool, typer.Option("--split-runs", help="--logs: a column log whose time goes back "
                                             "holds several runs: import each (else it is dropped, the "
                                             "others go on).")] = False,
    model: Annotated[Optional[Path], model_option("--logs: a model file of the joint to start from", "its starting "
                                                  "model from the robot's description at the logged pose")] = None,
    torque_sign: Annotated[str, typer.Option("--torque-sign", help="--logs: auto (flip the column logs' torque "
                                             "when gravity says it reads the other way round), +1 or -1.")]
    = "auto",
    plant: Annotated[Optional[Path], plant_option("--target sim: ")] = None,
    robot: Annotated[Optional[str], typer.Option("--robot", help="--target robot: robot controller HOST[:PORT].")]
    = None,
    port: Annotated[int, typer.Option("--port", help="--target robot: local FRI UDP port.")] = 30200,
    robot_model: Annotated[str, typer.Option("--robot-model", help="--target robot and --logs: iiwa7 | iiwa14.")]
    = "iiwa14",
    joint: Annotated[Optional[int], typer.Option("--joint", help="Joint under test, 1-7 (--target robot: default "
                                                 "1; --logs: default the joint that moved).")] = None,
    short: Annotated[bool, typer.Option("--short", help="Short experiments (a quick check, not for the "
                                        "figures).")] = False,
    skip: Annotated[Optional[str], typer.Option("--skip", help="Comma-separated stages not to run, e.g. "
                                                "'validation' (the stages that need them are skipped too).")] = None,
    no_report: Annotated[bool, typer.Option("--no-report", help="Skip report.pdf.")] = False,
    realtime: Annotated[bool, typer.Option("--realtime", help="--target sim: run the validation's robot emulator "
                                           "in real time instead of in lockstep (figures then depend on the "
                                           "machine's load).")] = False,
) -> None:
    """Run chirp, fit, experiments, ripple, design, deploy, FRI validation, diagnose and the report;
    or, with --logs, import, ripple, diagnose, held-out validation (fit, design, deploy where a
    torque-commanded record is among the logs) and the report on your own logs.

    Prints one line per stage, writes every file into the work folder
    (chirp.h5, model.toml, fit.json, constant_velocity.h5, hand_guided.h5,
    model_ripple.toml, ripple.json, design.toml, design.json, controller.toml,
    controller.json, validation/*.h5, validation.json, diagnose.json,
    model_ext.toml, pipeline.json, report.pdf) and ends with the headline
    figures. A failed stage is reported and skips the stages that need it;
    the exit code is then 1.

    With --target sim the validation runs the deployed config through the
    FRI runtime and the protocol against the robot emulator in lockstep: the
    robot side waits for each answer, so the figures are exactly repeatable
    on a loaded machine; it does not measure answer latency
    (bench/bench_fri_runtime.py does). --realtime runs the emulator on the
    wall clock instead.

    Examples:
      iiwa-ident pipeline --target sim --workdir run1
      iiwa-ident pipeline --target sim --plant my_plant.toml --workdir run2
      iiwa-ident pipeline --target sim --realtime --workdir run3
      iiwa-ident pipeline --target robot --robot 192.170.10.2 --joint 1 --workdir robot1
      iiwa-ident pipeline --logs my_logs/joint6 --workdir j6
      iiwa-ident pipeline --logs j5/vel_p3 j5/vel_1 j5/chirp --split-runs --workdir j5
    """
    from iiwa_ident.pipeline import format_summary, run_log_pipeline, run_pipeline
    from iiwa_ident.report import build_report

    skipped = tuple(x.strip() for x in (skip or "").split(",") if x.strip())
    try:
        check_joint(joint)
        if more_logs and not logs:
            raise IiwaIdentError(f"{more_logs[0]}: paths are log runs of --logs (--logs {more_logs[0]} ...)")
        logs = [*(logs or []), *(more_logs or [])]
        if split_runs and not logs:
            raise IiwaIdentError("--split-runs applies to --logs")
        if logs:
            given = [name for name, value in (("--plant", plant), ("--robot", robot), ("--short", short or None),
                                              ("--realtime", realtime or None)) if value is not None]
            if target != "sim" or given:
                raise IiwaIdentError(f"--logs runs on the logs alone: drop {', '.join(given) or '--target'}")
            result = run_log_pipeline(workdir, logs, robot_model=robot_model, joint=joint, torque_sign=torque_sign,
                                      model=model, split_runs=split_runs,
                                      progress=lambda m: typer.echo(m), report=None if no_report else build_report,
                                      skip=skipped)
        else:
            if model is not None:
                raise IiwaIdentError("--model applies to --logs (the simulated pipeline fits its own)")
            result = run_pipeline(workdir, target=target, plant=plant, robot=robot, short=short,
                                  progress=lambda m: typer.echo(m), port=port, robot_model=robot_model,
                                  joint=1 if joint is None else joint, report=None if no_report else build_report,
                                  realtime=realtime, skip=skipped)
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    typer.echo(format_summary(result))
    typer.echo(f"wrote {workdir / 'pipeline.json'}")
    if not result.ok:
        failed = [s.name for s in result.stages if s.status == "failed"]
        typer.echo(f"error: stages failed: {', '.join(failed)} (see above and pipeline.json)", err=True)
        raise typer.Exit(1)
