"""Subcommand ``model``: a joint's starting model from the robot's rigid-body description."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident.cli._app import app, check_joint, fail, parse_pose
from iiwa_ident.errors import IiwaIdentError

__all__ = ["model_cmd"]


@app.command("model")
def model_cmd(
    out: Annotated[Path, typer.Option("--out", help="Model file to write.")],
    robot: Annotated[Optional[str], typer.Option("--robot", help="iiwa14 or iiwa7 (default: the dataset's, "
                                                                 "else iiwa14).")] = None,
    joint: Annotated[Optional[int], typer.Option("--joint", help="Joint 1-7 (default: the dataset's).")] = None,
    pose: Annotated[Optional[str], typer.Option("--pose", help="The 7 joint angles in degrees, comma-separated "
                                                               "(default: the dataset's, else all 0: the arm "
                                                               "straight up).")] = None,
    data: Annotated[Optional[Path], typer.Option("--data", help="A dataset whose robot, joint and pose to "
                                                                "take.")] = None,
) -> None:
    """Write the starting model of one joint: Jl and the gravity load from the robot's description at the
    pose of the other joints, the torque loop's parameters borrowed from the paper's Table I until a chirp
    fit measures them (the file says which is which).

    Example:
      iiwa-ident model --robot iiwa14 --joint 6 --pose 0,0,0,0,0,0,0 --out joint6.toml
      iiwa-ident model --data run.h5 --out start.toml
    """
    from iiwa_ident.datasets import dataset_pose, read_dataset
    from iiwa_ident.ident import starting_model, write_model

    try:
        check_joint(joint)
        q = None if pose is None else parse_pose(pose, "--pose")
        if data is not None:
            ds = read_dataset(data)
            if joint is not None and joint != ds.joint:
                raise IiwaIdentError(f"{data}: the dataset is of joint {ds.joint}, not --joint {joint}")
            joint = ds.joint
            robot_ds, pose_ds = dataset_pose(ds)
            if robot is not None and robot_ds is not None and robot != robot_ds:
                raise IiwaIdentError(f"{data}: the dataset is of robot {robot_ds}, not --robot {robot}")
            robot = robot or robot_ds
            if q is None:
                if pose_ds is None:
                    raise IiwaIdentError(f"{data}: the dataset does not say the other joints' positions (import "
                                         "it with all joint columns, or give --pose)")
                q = pose_ds
        if joint is None:
            raise IiwaIdentError("model: give --joint N or --data run.h5")
        m = starting_model(robot or "iiwa14", joint, q)
        write_model(out, m)
        load = next((e for e in m.effects if e["name"] == "position_dependent_load"), None)
        typer.echo(f"{m.robot_model} joint {m.joint}: Jl {m.value('Jl'):.4g} kg m^2 (description), gravity load "
                   + (f"{load['amplitude_nm']:.4g} Nm" if load else "none (the axis is vertical at this pose)")
                   + "; Jc, bc, K, Td, KI borrowed from Table I")
        typer.echo(f"wrote {out}")
    except IiwaIdentError as err:
        raise fail(str(err)) from None
