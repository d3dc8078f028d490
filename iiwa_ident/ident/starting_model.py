"""A joint's starting model from the robot's rigid-body description, before anything is measured on it.

The link side comes from the description at the pose of the other joints: ``Jl`` and the gravity load
``A sin(theta_l + phi)`` (which the robot's own model compensates). The torque loop's parameters (``Jc``,
``bc``, ``K``, ``Td``, ``KI``) are not in any published description: they are borrowed from the paper's
Table I (joint 1 of an iiwa 14) until a chirp fit measures them, and the file says so, parameter by parameter.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from iiwa_ident.description import describe_joint
from iiwa_ident.ident.model_file import JointModel, Parameter, table1_model

__all__ = ["starting_model", "LOAD_NEGLIGIBLE_NM"]

#: A gravity amplitude below this is no load (a vertical axis) [Nm]: numerical zero of the description.
LOAD_NEGLIGIBLE_NM = 1e-6


def starting_model(robot: str, joint: int, pose: Sequence[float] | np.ndarray | None = None) -> JointModel:
    """The model ``diagnose`` and ``ripple`` start from on ``joint`` of ``robot`` at ``pose``.

    Parameters
    ----------
    robot : str
        ``iiwa14`` or ``iiwa7``.
    joint : int
        1-7.
    pose : sequence of 7 float, optional
        The joint positions [rad] (the joint's own does not matter); default: all zero, the arm straight up.

    Returns
    -------
    JointModel
        ``Jl`` (origin ``description``), the other parameters of Table I (origin ``borrowed``), the gravity
        load as a ``position_dependent_load`` effect known to the robot (``compensated = 1``) where the joint
        carries one, and the pose.

    Examples
    --------
    >>> from iiwa_ident.ident import starting_model
    >>> m = starting_model("iiwa14", 6)
    >>> m.joint, m.parameters["Jl"].origin, m.parameters["K"].origin
    (6, 'description', 'borrowed')
    """
    d = describe_joint(robot, joint, pose)
    model = table1_model()
    for p in model.parameters.values():
        p.std, p.origin = None, "borrowed"
    model.parameters["Jl"] = Parameter(d.Jl_kgm2, None, model.parameters["Jl"].unit, "description")
    if d.gravity_nm > LOAD_NEGLIGIBLE_NM:
        # The description gives the torque that holds the link; the effect is gravity's torque on it.
        phase = math.remainder(d.gravity_phase_rad + math.pi, 2 * math.pi)
        model.effects = [{"name": "position_dependent_load", "amplitude_nm": d.gravity_nm, "phase_rad": phase,
                          "compensated": 1.0}]
    model.joint, model.robot_model, model.pose_rad = int(joint), robot, list(d.pose_rad)
    model.created_utc = JointModel(parameters={}).created_utc
    model.description = (f"starting model of {robot} joint {joint} at pose [" + ", ".join(f"{x:.4g}" for x in d.pose_rad)
                         + f"] rad: Jl and the gravity load from the rigid-body description ({d.source}); Jc, bc, K, "
                           f"Td, KI borrowed from the paper's Table I (joint 1), to be measured by a chirp fit")
    return model
