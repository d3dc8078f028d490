"""A joint's starting model from the robot's rigid-body description, before anything is measured on it.

The link side comes from the description at the pose of the other joints: ``Jl`` and the gravity load
``A sin(theta_l + phi)`` (which the robot's own model compensates). The torque loop's parameters (``Jc``,
``bc``, ``K``, ``Td``, ``KI``) are not in any published description: they are borrowed from the paper's
Table I (joint 1 of an iiwa 14) until a chirp fit measures them, and the file says so, parameter by parameter.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from iiwa_ident.datasets import Dataset, dataset_pose
from iiwa_ident.description import GRAVITY_M_S2, describe_joint
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._model_file import read_model
from iiwa_ident.model import JointModel, Parameter, table1_model

__all__ = ["starting_model", "dataset_model", "check_model_matches", "model_for", "PhysicalRanges", "physical_ranges",
           "against_description", "Payload", "payload_of_load", "PAYLOAD_LEVER_MIN_M", "LOAD_NEGLIGIBLE_NM", "POSE_TOLERANCE_RAD", "DESCRIPTION_FACTOR"]

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
    model = _borrowed(int(joint), robot)
    model.parameters["Jl"] = Parameter(d.Jl_kgm2, None, model.parameters["Jl"].unit, "description")
    if d.gravity_nm > LOAD_NEGLIGIBLE_NM:
        # The description gives the torque that holds the link; the effect is gravity's torque on it.
        phase = math.remainder(d.gravity_phase_rad + math.pi, 2 * math.pi)
        model.effects = [{"name": "position_dependent_load", "amplitude_nm": d.gravity_nm, "phase_rad": phase,
                          "compensated": 1.0}]
    model.pose_rad = list(d.pose_rad)
    model.description = (f"starting model of {robot} joint {joint} at pose [" + ", ".join(f"{x:.4g}" for x in d.pose_rad)
                         + f"] rad: Jl and the gravity load from the rigid-body description ({d.source}); Jc, bc, K, "
                           f"Td, KI borrowed from the paper's Table I (joint 1), to be measured by a chirp fit")
    return model


def _borrowed(joint: int, robot: str | None) -> JointModel:
    """A new model of ``joint`` of ``robot`` with Table I's values, every one marked borrowed."""
    table = table1_model()
    return JointModel(parameters={k: Parameter(p.value, None, p.unit, "borrowed") for k, p in table.parameters.items()},
                      joint=joint, robot_model=robot)


#: Runs whose other joints stand further apart than this [rad] were recorded at different poses.
POSE_TOLERANCE_RAD = 0.05


def dataset_model(datasets: Sequence[Dataset], borrow: bool = False) -> JointModel:
    """The starting model (:func:`starting_model`) of the datasets' robot, joint and pose.

    ``borrow``: where the datasets do not say their pose, Table I for their joint, every value marked
    borrowed (for a command that needs only rough ``K`` and ``Jl``), instead of a refusal.

    Raises
    ------
    IiwaIdentError
        One line naming the file: no dataset, datasets of different joints or robots, a dataset that does
        not say its pose (imported without all joint columns), runs at different poses of the other joints.
    """
    if not datasets:
        raise IiwaIdentError("no dataset given")
    first = datasets[0]
    robots, poses = [], []
    for ds in datasets:
        name = ds.path or f"dataset of joint {ds.joint}"
        if ds.joint != first.joint:
            raise IiwaIdentError(f"{name}: a run of joint {ds.joint} among runs of joint {first.joint}")
        robot, pose = dataset_pose(ds)
        if pose is None and borrow:
            model = _borrowed(first.joint, robot)
            model.description = (f"the paper's Table I (joint 1 of an iiwa 14) borrowed for joint {first.joint}: "
                                 "the datasets do not say their pose")
            return model
        if pose is None:
            raise IiwaIdentError(f"{name}: the dataset does not say the other joints' positions, so the "
                                 "description cannot give its starting model: give --model, or import the log "
                                 "with a position file of all 7 joints")
        robots.append(robot or "iiwa14")
        poses.append(np.asarray(pose))
    if len(set(robots)) > 1:
        raise IiwaIdentError(f"the datasets are of different robots ({', '.join(sorted(set(robots)))})")
    others = [j for j in range(7) if j != first.joint - 1]
    spread = np.ptp(np.array(poses)[:, others], axis=0) if len(poses) > 1 else np.zeros(len(others))
    if np.any(spread > POSE_TOLERANCE_RAD):
        j = others[int(np.argmax(spread))] + 1
        raise IiwaIdentError(f"the runs were recorded at different poses (joint {j} differs by "
                             f"{math.degrees(float(spread.max())):.1f} deg): the link inertia and the gravity load "
                             "differ too; use the runs of one pose together")
    return starting_model(robots[0], first.joint, poses[0])


def check_model_matches(model: JointModel, datasets: Sequence[Dataset], where: str = "") -> None:
    """Refuse (one line) a model of another joint or robot than the datasets'.

    ``where``: the model file, for the message. A model that does not say its joint or robot, or a dataset
    that does not say its robot, is not judged on that.
    """
    for ds in datasets:
        name = ds.path or f"the dataset of joint {ds.joint}"
        robot, _ = dataset_pose(ds)
        if model.joint is not None and model.joint != ds.joint:
            start = f"`iiwa-ident model --data {ds.path}`" if ds.path else "`iiwa-ident model`"
            raise IiwaIdentError(f"{where}a model of joint {model.joint} on data of joint {ds.joint} ({name}): "
                                 f"every joint has its own; start from {start}")
        if model.robot_model and robot and model.robot_model != robot:
            raise IiwaIdentError(f"{where}a model of an {model.robot_model} on data of an {robot} ({name})")


def model_for(datasets: Sequence[Dataset], path: str | os.PathLike | None = None, borrow: bool = False) -> JointModel:
    """The model a command checks or extends with the datasets: the model file at ``path``, refused (one line
    naming it) when it is of another joint or robot (:func:`check_model_matches`); without a file, the datasets'
    starting model (:func:`dataset_model`, ``borrow`` as there)."""
    if path is None:
        return dataset_model(datasets, borrow=borrow)
    model = read_model(path)
    check_model_matches(model, datasets, f"{path}: ")
    return model


#: A described value may be off by this factor either way and still be physical (figures from CAD and a
#: published description, not a measurement of this arm: Drake's iiwa 14 links weigh 1-4 times KUKA's CAD).
DESCRIPTION_FACTOR = 2.0


@dataclass(frozen=True, kw_only=True)
class PhysicalRanges:
    """What is physically possible for one joint at one pose, from the robot's description.

    ``Jl_kgm2``: from half the described link inertia to twice the inertia with the arm's rated payload at
    the flange; ``load_nm``: the gravity amplitude likewise (on a vertical axis, where gravity exerts no
    torque, both bounds are 0: a load there is not gravity). The torque loop's ``Jc``, ``bc``, ``K`` are not
    described: positive is all that is asked of them.
    """

    Jl_kgm2: tuple[float, float]
    load_nm: tuple[float, float]
    Jl_described_kgm2: float
    load_described_nm: float
    robot: str
    joint: int
    #: The 7 joint positions the ranges hold at [rad].
    pose_rad: tuple[float, ...] = ()


def physical_ranges(model: JointModel) -> PhysicalRanges | None:
    """The :class:`PhysicalRanges` of the model's joint at its pose; None for a model that does not say its
    robot, joint and pose (such as Table I), whose parameters are then judged by sign only."""
    if model.robot_model is None or model.joint is None or model.pose_rad is None:
        return None
    from iiwa_ident.description import RATED_PAYLOAD_KG, ROBOTS, gravity_sinusoid, link_inertia

    if model.robot_model not in ROBOTS:
        return None
    robot, joint, pose = model.robot_model, model.joint, model.pose_rad
    payload = RATED_PAYLOAD_KG[robot]
    jl, jl_p = link_inertia(robot, joint, pose), link_inertia(robot, joint, pose, payload)
    a, a_p = gravity_sinusoid(robot, joint, pose)[0], gravity_sinusoid(robot, joint, pose, payload)[0]
    a = a if a > LOAD_NEGLIGIBLE_NM else 0.0
    a_p = a_p if a_p > LOAD_NEGLIGIBLE_NM else 0.0
    return PhysicalRanges(Jl_kgm2=(jl / DESCRIPTION_FACTOR, DESCRIPTION_FACTOR * jl_p),
                          load_nm=(a / DESCRIPTION_FACTOR, DESCRIPTION_FACTOR * a_p), Jl_described_kgm2=jl,
                          load_described_nm=a, robot=robot, joint=joint, pose_rad=tuple(float(x) for x in pose))


#: Shortest lever of the flange about the joint's axis (horizontal part, at the pose) that determines a payload
#: [m]: nearer the axis a flange mass makes no torque the load could show.
PAYLOAD_LEVER_MIN_M = 0.01


@dataclass(frozen=True, kw_only=True)
class Payload:
    """The payload a gravity load beyond the description's stands for, at the pose (:func:`payload_of_load`).

    Attributes
    ----------
    determined : bool
        Whether the pose determines it (the flange's lever about the axis at least :data:`PAYLOAD_LEVER_MIN_M`).
    mass_kg, mass_std_kg : float
        The point mass at the flange that produces the extra load's part in the flange's phase, and its std.
    lever_m : float
        The flange's lever about the joint's axis at the pose (the gravity torque of 1 kg there over g).
    moment_kgm, moment_std_kgm : float
        The extra load's amplitude over g: mass times lever wherever the mass sits (a centre-of-mass shift).
    other_phase_nm : float
        The extra load's amplitude at the other phase, which no flange mass produces [Nm].
    """

    determined: bool
    mass_kg: float
    mass_std_kg: float
    lever_m: float
    moment_kgm: float
    moment_std_kgm: float
    other_phase_nm: float

    def text(self) -> str:
        """In words, as the diagnosis says it."""
        if not self.determined:
            return (f"the pose does not determine a payload (the flange's lever about this axis is "
                    f"{self.lever_m * 1e3:.0f} mm); as a centre-of-mass shift: {self.moment_kgm:.3g} "
                    f"± {self.moment_std_kgm:.2g} kg m")
        return (f"as a payload at the flange: {self.mass_kg:.3g} ± {self.mass_std_kg:.2g} kg on a lever of "
                f"{self.lever_m:.3g} m; as a centre-of-mass shift: {self.moment_kgm:.3g} ± {self.moment_std_kgm:.2g} "
                f"kg m" + (f" ({self.other_phase_nm:.2g} Nm of it at another phase than a flange mass's)"
                           if self.other_phase_nm > 0.05 * max(abs(self.mass_kg) * self.lever_m * GRAVITY_M_S2, 1e-9)
                           else ""))


def payload_of_load(ranges: PhysicalRanges, amplitude_nm: float, phase_rad: float,
                    cov: np.ndarray | None = None) -> Payload:
    """The payload (or centre-of-mass shift) that turns the description's gravity load into the named one.

    The load ``amplitude_nm sin(theta + phase_rad)`` and the description's are vectors ``(A cos phi, A sin phi)``;
    1 kg at the flange adds the vector ``u`` (:func:`~iiwa_ident.description.gravity_sinusoid` with and without
    it; the load on the link is the negative of the holding torque). The extra load ``e`` gives the mass ``e.u / |u|^2``, the moment ``|e| / g`` and the part of ``e`` across
    ``u``. ``cov``: the 2 x 2 covariance of the named load's vector [Nm^2] (its std's source), or None (std 0).
    """
    from iiwa_ident.description import gravity_sinusoid

    pose = list(ranges.pose_rad)
    a0, p0 = gravity_sinusoid(ranges.robot, ranges.joint, pose)
    a1, p1 = gravity_sinusoid(ranges.robot, ranges.joint, pose, 1.0)
    def vec(a: float, p: float) -> np.ndarray:
        return np.array([a * math.cos(p), a * math.sin(p)])

    # The load acts on the link: the negative of the torque that holds the arm (as the starting model has it).
    d, u = -vec(a0, p0), vec(a0, p0) - vec(a1, p1)
    e = vec(amplitude_nm, phase_rad) - d
    c = np.zeros((2, 2)) if cov is None else np.asarray(cov, float)
    nu = float(np.hypot(*u))
    lever = nu / GRAVITY_M_S2
    ne = float(np.hypot(*e))
    moment_std = math.sqrt(max(float(e @ c @ e), 0.0)) / ne / GRAVITY_M_S2 if ne > 0 else \
        math.sqrt(max(float(np.trace(c)) / 2, 0.0)) / GRAVITY_M_S2
    if lever < PAYLOAD_LEVER_MIN_M:
        return Payload(determined=False, mass_kg=float("nan"), mass_std_kg=float("nan"), lever_m=lever,
                       moment_kgm=ne / GRAVITY_M_S2, moment_std_kgm=moment_std, other_phase_nm=ne)
    m = float(e @ u) / nu ** 2
    m_std = math.sqrt(max(float(u @ c @ u), 0.0)) / nu ** 2
    across = abs(float(e[0] * u[1] - e[1] * u[0])) / nu
    return Payload(determined=True, mass_kg=m, mass_std_kg=m_std, lever_m=lever, moment_kgm=ne / GRAVITY_M_S2,
                   moment_std_kgm=moment_std, other_phase_nm=across)


def against_description(ranges: PhysicalRanges, Jl_kgm2: float | None = None,
                        load_nm: float | None = None) -> str:
    """The model's error against the description in physical terms, e.g. "gravity load 7 % above the
    description's 80.6 Nm: payload or centre-of-mass error"; '' when nothing is given."""
    parts = []
    if load_nm is not None and ranges.load_described_nm > 0:
        pct = 100.0 * (load_nm / ranges.load_described_nm - 1.0)
        cause = ": payload or centre-of-mass error" if pct > 0 else ": lighter links or a centre of mass nearer the axis"
        parts.append(f"gravity load {abs(pct):.0f} % {'above' if pct >= 0 else 'below'} the description's "
                     f"{ranges.load_described_nm:.3g} Nm" + (cause if abs(pct) >= 5 else ""))
    elif load_nm is not None:
        parts.append(f"a load of {load_nm:.3g} Nm on an axis the description gives no gravity torque at this pose")
    if Jl_kgm2 is not None:
        parts.append(f"link inertia {Jl_kgm2:.3g} kg m^2 against {ranges.Jl_described_kgm2:.3g} described")
    return "; ".join(parts)
