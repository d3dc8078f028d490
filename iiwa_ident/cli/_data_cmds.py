"""Subcommands ``import`` and ``info``: bring logs into the dataset format and inspect files."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from iiwa_ident.cli._app import app, check_joint, fail
from iiwa_ident.errors import IiwaIdentError

__all__ = ["import_cmd", "info_cmd", "parse_pairs"]


def parse_pairs(items: list[str] | None, option: str, value_name: str) -> dict[str, str]:
    """Parse repeated ``KEY=VALUE`` options into a dict.

    Parameters
    ----------
    items : list of str or None
        Raw option values, e.g. ``["q_m=pos.txt", "tau_j=trq.txt"]``.
    option : str
        Option name for messages, e.g. ``"--columns"``.
    value_name : str
        What the value is, for messages, e.g. ``"FILE"``.

    Returns
    -------
    dict of str to str
        Keys and values with surrounding blanks removed.

    Raises
    ------
    IiwaIdentError
        On an item without ``=``, with an empty side, or a repeated key.
    """
    pairs: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise IiwaIdentError(f"{option} expects SIGNAL={value_name}, got {item!r}")
        if key in pairs:
            raise IiwaIdentError(f"{option} gives {key!r} twice")
        pairs[key] = value
    return pairs


def _parse_scale(items: list[str] | None) -> dict[str, float]:
    scale: dict[str, float] = {}
    for key, text in parse_pairs(items, "--scale", "FACTOR").items():
        try:
            factor = float(text)
        except ValueError:
            raise IiwaIdentError(f"--scale {key}={text}: {text!r} is not a number") from None
        if not math.isfinite(factor):
            raise IiwaIdentError(f"--scale {key}={text}: factor must be finite")
        scale[key] = factor
    return scale


@app.command("import")
def import_cmd(
    out: Annotated[Path, typer.Option("--out", help="Dataset file to write (.h5); replaced atomically if it exists.")],
    joint: Annotated[int, typer.Option("--joint", help="Joint that moved, 1..7.")],
    experiment: Annotated[
        str,
        typer.Option(
            "--experiment",
            help="chirp, constant_velocity, quasi_static, hand_guided, step, sine or free.",
        ),
    ],
    columns: Annotated[
        Optional[list[str]],
        typer.Option(
            "--columns",
            metavar="SIGNAL=FILE",
            help="Whitespace-separated column file of one signal (repeat per signal).",
        ),
    ] = None,
    csv_file: Annotated[
        Optional[Path], typer.Option("--csv", metavar="FILE", help="CSV file with a header row.")
    ] = None,
    mapping: Annotated[
        Optional[list[str]],
        typer.Option("--map", metavar="SIGNAL=COLUMN", help="CSV column of a signal (repeat per signal)."),
    ] = None,
    rate: Annotated[
        Optional[float],
        typer.Option("--rate", help="Sample rate in Hz; default 1/median period of the time signal."),
    ] = None,
    column: Annotated[
        Optional[int],
        typer.Option("--column", help="0-based column of multi-column files; default: the joint's own column "
                                      "(joint 1 reads column 0, joint 7 column 6)."),
    ] = None,
    robot: Annotated[
        str, typer.Option("--robot", help="The arm the log is of: iiwa14 or iiwa7 (kept in the dataset).")
    ] = "iiwa14",
    scale: Annotated[
        Optional[list[str]],
        typer.Option("--scale", metavar="SIGNAL=FACTOR", help="Multiply a signal, e.g. tau_j=-1 (repeatable)."),
    ] = None,
    split_runs: Annotated[
        bool,
        typer.Option("--split-runs", help="The log holds several runs (its time restarts; --rosbag: each stretch "
                                          "of COMMANDING_ACTIVE): write one dataset per run, named like --out with "
                                          "_run1, _run2, ... before the suffix."),
    ] = False,
    rosbag: Annotated[Optional[Path], typer.Option(
        "--rosbag", metavar="BAG", help="ROS 2 bag of lbr_fri_ros2_stack (LBRState or JointState).")] = None,
    topic: Annotated[Optional[str], typer.Option(
        "--topic", help="--rosbag: the topic (default: the LBRState one, else JointState).")] = None,
    lcm_log: Annotated[Optional[Path], typer.Option(
        "--lcm", metavar="LOG", help="LCM event log of Drake's iiwa driver (lcmt_iiwa_status messages).")] = None,
    channel: Annotated[str, typer.Option("--channel", help="--lcm: the status channel.")] = "IIWA_STATUS",
    robot_name: Annotated[Optional[str], typer.Option(
        "--robot-name", help="Name of the robot the log is of (kept in the dataset; a fleet's key).")] = None,
) -> None:
    r"""Convert a recorded log into an iiwa-ident dataset file.

    Signals and units: t (s), q_m (rad), tau_j (Nm) are required (t may be
    replaced by --rate); optional tau_c, tau_ext_fri, tau_ext_ref (Nm),
    q_l_ref, q_cmd (rad), dq_m (rad/s). Give either --columns files (one row
    per sample, one column per joint), --csv with --map, or a message log:
    --rosbag (lbr_fri_ros2_stack's LBRState or JointState) or --lcm (Drake's
    lcmt_iiwa_status). Message logs are taken down to 50 Hz, with a warning
    of what a rate below the robot's cycle cannot give.

    Example, a joint-2 constant-velocity log as common iiwa drivers export it
    (position-controlled, 200 Hz, so no tau_c):

        D=logs/joint2/vel_p3

        iiwa-ident import --joint 2 --experiment constant_velocity \
          --columns t=$D/cur_traj_time_s.txt \
          --columns q_m=$D/joint_position_measured.txt \
          --columns tau_j=$D/joint_torque_measured.txt \
          --columns dq_m=$D/joint_velocity_measured.txt \
          --out runs/j2_vel_p3.h5

    lbr_fri_ros2_stack, recorded with ros2 bag record /lbr/state; --split-runs
    writes one dataset per stretch in which the session was COMMANDING_ACTIVE:

        iiwa-ident import --joint 2 --experiment constant_velocity --rosbag rosbag2_2026_11_26 --out j2.h5

    Drake's driver, logged with lcm-logger:

        iiwa-ident import --joint 2 --experiment constant_velocity --lcm lcmlog-2026-11-26.00 --out j2.h5

    A log whose time restarts holds several runs; --split-runs writes
    runs/j2_run1.h5, runs/j2_run2.h5, ...:

        iiwa-ident import --joint 2 --experiment constant_velocity \
          --csv log.csv --map t=time --map q_m=q2 --map tau_j=tau2 \
          --split-runs --out runs/j2.h5
    """
    from iiwa_ident.datasets import dataset_pose, note_warnings, set_robot_name

    try:
        check_joint(joint)
        datasets = _read_log(
            joint=joint, experiment=experiment, column_files=parse_pairs(columns, "--columns", "FILE"),
            csv_file=csv_file, csv_map=parse_pairs(mapping, "--map", "COLUMN"), rate=rate, column=column,
            robot=robot, scale=scale, split_runs=split_runs, rosbag=rosbag, topic=topic, lcm_log=lcm_log,
            channel=channel)
        if not split_runs:
            datasets = [datasets]
            targets = [out]
        else:
            targets = [out.with_name(f"{out.stem}_run{k}{out.suffix or '.h5'}") for k in range(1, len(datasets) + 1)]
        for ds in datasets:
            set_robot_name(ds, robot_name)
        warnings = [note_warnings(ds) for ds in datasets]
        _write_all_or_none(targets, datasets)
        written = targets
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    for path, dataset, problems in zip(written, datasets, warnings):
        robot_model, pose = dataset_pose(dataset)
        typer.echo(
            f"wrote {path}: {dataset.experiment}, {robot_model} joint {dataset.joint}"
            f"{f' of {robot_name}' if robot_name else ''}, "
            f"{dataset.n_samples} samples at {dataset.sample_rate_hz:.6g} Hz "
            f"({dataset.duration_s:.3f} s); signals: {', '.join(dataset.signals)}"
            + ("" if pose is None else "; pose " + ", ".join(f"{math.degrees(x):.1f}" for x in pose) + " deg")
        )
        for problem in problems:
            typer.echo(f"warning: {path}: {problem}", err=True)
    left_out = datasets[0].experiment_attrs.get("split_left_out") if split_runs and datasets else None
    if left_out:
        typer.echo(f"warning: {out}: {left_out}", err=True)


def _read_log(*, joint: int, experiment: str, column_files: dict[str, str], csv_file: Path | None,
              csv_map: dict[str, str], rate: float | None, column: int | None, robot: str, scale: list[str] | None,
              split_runs: bool, rosbag: Path | None, topic: str | None, lcm_log: Path | None, channel: str) -> Any:
    """The dataset (a list of them with ``split_runs``) of the one source ``import`` was given."""
    from iiwa_ident.datasets import import_columns, import_csv, import_lcm, import_rosbag

    factors = _parse_scale(scale)
    given = [name for name, v in (("--columns", column_files), ("--csv", csv_file), ("--rosbag", rosbag),
                                  ("--lcm", lcm_log)) if v]
    if len(given) > 1:
        raise IiwaIdentError(f"give one of --columns, --csv, --rosbag or --lcm: {' and '.join(given)} given, not "
                             f"{'both' if len(given) == 2 else 'all'}")
    if rosbag is not None or lcm_log is not None:
        option = "--rosbag" if rosbag is not None else "--lcm"
        for value, other in ((csv_map, "--map"), (column, "--column"), (rate, "--rate"), (scale, "--scale"),
                             (split_runs and lcm_log is not None, "--split-runs"),
                             (topic and lcm_log is not None, "--topic")):
            if value:
                raise IiwaIdentError(f"{other} does not apply to {option} (the messages carry time and units)")
        if rosbag is not None:
            return import_rosbag(rosbag, joint=joint, experiment=experiment, topic=topic, split_runs=split_runs,
                                 robot_model=robot)
        if lcm_log is not None:
            return import_lcm(lcm_log, joint=joint, experiment=experiment, channel=channel, robot_model=robot)
    if csv_file is not None:
        if not csv_map:
            raise IiwaIdentError("--csv needs at least one --map SIGNAL=COLUMN")
        if column is not None:
            raise IiwaIdentError("--column applies to --columns files, not to --csv")
        return import_csv(csv_file, csv_map, joint=joint, experiment=experiment, sample_rate_hz=rate, scale=factors,
                          split_runs=split_runs, robot_model=robot)
    if column_files:
        if csv_map:
            raise IiwaIdentError("--map applies to --csv; use --columns SIGNAL=FILE for column files")
        return import_columns({name: Path(p) for name, p in column_files.items()}, joint=joint,
                              experiment=experiment, sample_rate_hz=rate, column=column, scale=factors,
                              split_runs=split_runs, robot_model=robot)
    raise IiwaIdentError("nothing to import: give --columns SIGNAL=FILE, --csv FILE --map SIGNAL=COLUMN, "
                         "--rosbag BAG or --lcm LOG")


def _write_all_or_none(targets: list[Path], datasets: list) -> None:
    """All runs or none, and no file already there lost: each run goes to a hidden file first and the files
    are renamed over their targets only when every run is written."""
    from iiwa_ident.datasets import write_dataset

    staged: list[Path] = []
    try:
        for target in targets:
            staged.append(write_dataset(target.with_name(f".{target.name}.{os.getpid()}.staged"),
                                        datasets[len(staged)]))
    except BaseException:
        for path in staged:
            path.unlink(missing_ok=True)
        raise
    for tmp, target in zip(staged, targets):
        os.replace(tmp, target)


@app.command("info")
def info_cmd(
    file: Annotated[Path, typer.Argument(help="Dataset file (.h5).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Show a dataset's metadata and per-signal statistics.

    Examples:
      iiwa-ident info chirp.h5
      iiwa-ident info chirp.h5 --json
    """
    from iiwa_ident.datasets import dataset_info, format_info, read_dataset

    try:
        info = dataset_info(read_dataset(file))
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    typer.echo(json.dumps(info, indent=2) if as_json else format_info(info))
