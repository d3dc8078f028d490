"""The arm's mass matrix and gravity torques, computed by MuJoCo from the published figures.

MuJoCo (``mujoco``, DeepMind's rigid-body engine) does the recursive dynamics; this module only writes the
figures of :mod:`._figures` as an MJCF model and reads back ``M(q)`` and the bias force at rest.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from iiwa_ident.description._figures import ARM_LINKS, FLANGE_M, JOINT_TURNS_RPY, SOURCES
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.robot import JointLimits, joint_limits

__all__ = ["ROBOTS", "GRAVITY_M_S2", "JointDescription", "mass_matrix", "gravity_torques", "link_inertia",
           "gravity_torque", "gravity_sinusoid", "describe_joint", "check_pose", "flange_axis"]

#: The arms described.
ROBOTS: tuple[str, ...] = tuple(sorted(ARM_LINKS))

#: Standard gravity [m/s^2], downwards along the base's z axis (the arm standing on the floor).
GRAVITY_M_S2 = 9.80665


def _quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, ...]:
    """(w, x, y, z) of ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def _mjcf(robot: str, payload_kg: float = 0.0) -> str:
    """The arm as an MJCF document: nested bodies, one hinge about each body's z axis; ``payload_kg`` as a
    point mass at the flange."""
    def num(xs) -> str:
        return " ".join(f"{x:.17g}" for x in xs)

    body = f'<site name="flange" pos="0 0 {FLANGE_M!r}"/>'
    if payload_kg > 0:
        body += (f'<body name="payload" pos="0 0 {FLANGE_M!r}"><inertial pos="0 0 0" mass="{payload_kg!r}" '
                 'diaginertia="1e-9 1e-9 1e-9"/></body>')
    for i in reversed(range(7)):
        link, rpy = ARM_LINKS[robot][i], JOINT_TURNS_RPY[i]
        lim = joint_limits(robot, i + 1)
        body = (f'<body name="link{i + 1}" pos="{num(link.origin_m)}" quat="{num(_quaternion(*rpy))}">'
                f'<joint name="joint{i + 1}" type="hinge" axis="0 0 1" limited="true" '
                f'range="{-lim.position_rad!r} {lim.position_rad!r}"/>'
                f'<inertial pos="{num(link.com_m)}" mass="{link.mass_kg!r}" diaginertia="{num(link.inertia_kgm2)}"/>'
                f'{body}</body>')
    return (f'<mujoco model="{robot}"><compiler angle="radian"/>'
            f'<option gravity="0 0 {-GRAVITY_M_S2!r}"/><worldbody>{body}</worldbody></mujoco>')


@functools.cache
def _model(robot: str, payload_kg: float = 0.0):
    if robot not in ARM_LINKS:
        raise IiwaIdentError(f"no rigid-body description of robot {robot!r} (described: {', '.join(ROBOTS)})")
    if not (math.isfinite(payload_kg) and payload_kg >= 0):
        raise IiwaIdentError(f"a payload is a mass >= 0 kg, got {payload_kg!r}")
    import mujoco  # imported here: the engine's load is paid only by the commands that need it

    return mujoco.MjModel.from_xml_string(_mjcf(robot, payload_kg))


def check_pose(q: Sequence[float] | np.ndarray, robot: str | None = None) -> np.ndarray:
    """``q`` as 7 joint positions [rad], or a one-line refusal (wrong length, not finite, beyond a limit of
    ``robot``)."""
    arr = np.asarray(q, dtype=float).reshape(-1)
    if arr.shape != (7,) or not np.all(np.isfinite(arr)):
        raise IiwaIdentError(f"a pose is 7 finite joint positions in rad, got {np.asarray(q).tolist()}")
    if robot is not None:
        for j, x in enumerate(arr, start=1):
            lim = joint_limits(robot, j).position_rad
            if abs(x) > lim + 1e-9:
                raise IiwaIdentError(f"pose: joint {j} at {x:.4g} rad is beyond the {robot}'s limit of "
                                     f"{lim:.4g} rad")
    return arr


class _MjState(NamedTuple):
    """MuJoCo, the compiled model and its data."""

    mujoco: Any
    model: Any
    data: Any


def _state(robot: str, q: Sequence[float] | np.ndarray, payload_kg: float = 0.0):
    import mujoco

    model = _model(robot, float(payload_kg))
    data = mujoco.MjData(model)
    data.qpos[:] = check_pose(q)
    mujoco.mj_forward(model, data)
    return _MjState(mujoco, model, data)


def mass_matrix(robot: str, q: Sequence[float] | np.ndarray, payload_kg: float = 0.0) -> np.ndarray:
    """The arm's joint-space mass matrix ``M(q)`` [kg m^2], 7 x 7, links only (no rotor inertia), with
    ``payload_kg`` as a point mass at the flange.

    Examples
    --------
    >>> from iiwa_ident.description import mass_matrix
    >>> M = mass_matrix("iiwa14", [0.0] * 7)
    >>> bool(abs(M[6, 6] - 0.001) < 1e-12)  # link 7 turns about its own centre of mass
    True
    """
    mujoco, model, data = _state(robot, q, payload_kg)
    out = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, out)
    return out


def gravity_torques(robot: str, q: Sequence[float] | np.ndarray, payload_kg: float = 0.0) -> np.ndarray:
    """The joint torques ``g(q)`` [Nm] that hold the arm (and ``payload_kg`` at the flange) at rest at ``q``
    against gravity, 7 values."""
    _, _, data = _state(robot, q, payload_kg)
    return np.array(data.qfrc_bias, dtype=float)


def _joint(joint: int) -> int:
    if not 1 <= int(joint) <= 7:
        raise IiwaIdentError(f"joint must be 1..7, got {joint}")
    return int(joint) - 1


def link_inertia(robot: str, joint: int, q: Sequence[float] | np.ndarray, payload_kg: float = 0.0) -> float:
    """The inertia ``Jl`` [kg m^2] that ``joint`` (1-7) moves at pose ``q``: the diagonal entry of ``M(q)``.

    It depends only on the joints beyond ``joint`` (the ones it carries), not on its own position.
    """
    return float(mass_matrix(robot, q, payload_kg)[_joint(joint), _joint(joint)])


def gravity_torque(robot: str, joint: int, q: Sequence[float] | np.ndarray, payload_kg: float = 0.0) -> float:
    """The gravity torque [Nm] on ``joint`` (1-7) at pose ``q`` (the torque that holds it)."""
    return float(gravity_torques(robot, q, payload_kg)[_joint(joint)])


def gravity_sinusoid(robot: str, joint: int, pose: Sequence[float] | np.ndarray,
                     payload_kg: float = 0.0) -> tuple[float, float]:
    """``(A, phi)``: with the other joints held at ``pose``, the gravity torque on ``joint`` is
    ``A sin(q_j + phi)`` [Nm] over the joint's own position ``q_j`` [rad], ``A >= 0``.

    It is exactly a sinusoid: the centre of mass the joint carries turns about the joint's axis, and the
    torque of a fixed force about that axis is linear in the turn's cosine and sine.
    """
    j = _joint(joint)
    q = check_pose(pose).copy()
    q[j] = 0.0
    g0 = gravity_torque(robot, joint, q, payload_kg)   # A sin(phi)
    q[j] = math.pi / 2
    g90 = gravity_torque(robot, joint, q, payload_kg)  # A cos(phi)
    return math.hypot(g0, g90), math.atan2(g0, g90)


def flange_axis(robot: str, joint: int, q: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(axis, lever)`` of ``joint`` (1-7) seen from the flange at pose ``q``, both in the flange's frame.

    ``axis`` is the joint's unit axis, ``lever`` [m] the flange's origin relative to the joint's origin on
    that axis: a force ``F`` [N] and moment ``M`` [Nm] acting at the flange load the joint with
    ``axis . (lever x F + M)`` [Nm] (an F/T sensor mounted on the flange, its frame the flange's).

    Examples
    --------
    >>> from iiwa_ident.description import flange_axis
    >>> axis, lever = flange_axis("iiwa14", 7, [0.0] * 7)
    >>> axis.round(12).tolist(), bool(abs(lever[:2]).max() < 1e-12)  # joint 7 turns the flange about its own z
    ([0.0, 0.0, 1.0], True)
    """
    j = _joint(joint)
    mujoco, model, data = _state(robot, q)
    R = np.array(data.site_xmat[0], dtype=float).reshape(3, 3)  # flange -> world
    axis_w = np.array(data.xaxis[j], dtype=float)
    lever_w = np.array(data.site_xpos[0], dtype=float) - np.array(data.xanchor[j], dtype=float)
    return R.T @ axis_w, R.T @ lever_w


@dataclass(frozen=True, kw_only=True)
class JointDescription:
    """What the description says about one joint at one pose of the others.

    Attributes
    ----------
    robot, joint : str, int
        The arm (``iiwa14``, ``iiwa7``) and the joint (1-7).
    pose_rad : tuple of float
        The 7 joint positions it is taken at (the joint's own one does not matter) [rad].
    Jl_kgm2 : float
        The link-side inertia the joint moves [kg m^2].
    gravity_nm, gravity_phase_rad : float
        The gravity torque ``gravity_nm sin(q_j + gravity_phase_rad)`` [Nm, rad].
    limits : JointLimits
        The data sheet's limits.
    source : str
        Where the figures come from.
    """

    robot: str
    joint: int
    pose_rad: tuple[float, ...]
    Jl_kgm2: float
    gravity_nm: float
    gravity_phase_rad: float
    limits: JointLimits
    source: str


def describe_joint(robot: str, joint: int, pose: Sequence[float] | np.ndarray | None = None) -> JointDescription:
    """The description of ``joint`` of ``robot`` with the other joints at ``pose`` (default: all at zero, the
    arm straight up).

    Examples
    --------
    >>> from iiwa_ident.description import describe_joint
    >>> d = describe_joint("iiwa14", 1)
    >>> round(d.gravity_nm, 9)  # joint 1's axis is vertical: gravity exerts no torque about it
    0.0
    """
    q = check_pose(np.zeros(7) if pose is None else pose, robot)
    amp, phase = gravity_sinusoid(robot, joint, q)
    return JointDescription(robot=robot, joint=int(joint), pose_rad=tuple(float(x) for x in q),
                            Jl_kgm2=link_inertia(robot, joint, q), gravity_nm=amp, gravity_phase_rad=phase,
                            limits=joint_limits(robot, joint), source=SOURCES[robot])
