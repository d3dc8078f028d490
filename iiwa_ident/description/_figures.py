"""Published rigid-body figures of the LBR iiwa 14 R820 and iiwa 7 R800: kinematics and link inertials.

Sources (figures carried over, in this module's own layout):

* Kinematics, masses, centres of mass and inertias: Drake's iiwa descriptions (RobotLocomotion/drake,
  ``manipulation/models/iiwa_description``): ``urdf/iiwa14_no_collision.urdf`` for the iiwa 14 (its masses
  of links 1-5 and 7 raised above KUKA's CAD values 3.95, 3.18, 2.74, 1.69, 0.31 kg to match a real arm's
  torques, as its comments say) and ``iiwa7/iiwa7_no_collision.sdf`` for the iiwa 7.
* Limits: KUKA's data sheets (:data:`iiwa_ident.robot.ROBOT_MODELS`).

Both arms share one kinematic structure (every joint turns about its own frame's z axis; the frames' turns
below) and differ in the link lengths. Gear ratios are not published by KUKA and are not given here: the
ripple's period is identified from the data (``ripple``), never taken from a ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Link", "ARM_LINKS", "JOINT_TURNS_RPY", "FLANGE_M", "RATED_PAYLOAD_KG", "SOURCES"]

_PI2 = math.pi / 2

#: The fixed turn of each joint's frame against its parent's at zero position, as roll-pitch-yaw [rad]
#: (fixed axes x, y, z; ``R = Rz(yaw) Ry(pitch) Rx(roll)``), the same on both arms.
JOINT_TURNS_RPY: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (_PI2, 0.0, math.pi),
    (_PI2, 0.0, math.pi),
    (_PI2, 0.0, 0.0),
    (-_PI2, math.pi, 0.0),
    (_PI2, 0.0, 0.0),
    (-_PI2, math.pi, 0.0),
)


@dataclass(frozen=True)
class Link:
    """One joint and the link it moves.

    Attributes
    ----------
    origin_m : tuple of float
        The joint frame's origin in its parent link's frame at zero position [m].
    mass_kg : float
        The link's mass [kg].
    com_m : tuple of float
        Its centre of mass in its own frame [m].
    inertia_kgm2 : tuple of float
        Its principal moments of inertia about the centre of mass, along its frame's axes [kg m^2].
    """

    origin_m: tuple[float, float, float]
    mass_kg: float
    com_m: tuple[float, float, float]
    inertia_kgm2: tuple[float, float, float]


#: Links 1-7 of each arm, base to flange.
ARM_LINKS: dict[str, tuple[Link, ...]] = {
    "iiwa14": (
        Link((0.0, 0.0, 0.1575), 5.76, (0.0, -0.03, 0.12), (0.033, 0.0333, 0.0123)),
        Link((0.0, 0.0, 0.2025), 6.35, (0.0003, 0.059, 0.042), (0.0305, 0.0304, 0.011)),
        Link((0.0, 0.2045, 0.0), 3.5, (0.0, 0.03, 0.13), (0.025, 0.0238, 0.0076)),
        Link((0.0, 0.0, 0.2155), 3.5, (0.0, 0.067, 0.034), (0.017, 0.0164, 0.006)),
        Link((0.0, 0.1845, 0.0), 3.5, (0.0001, 0.021, 0.076), (0.01, 0.0087, 0.00449)),
        Link((0.0, 0.0, 0.2155), 1.8, (0.0, 0.0006, 0.0004), (0.0049, 0.0047, 0.0036)),
        Link((0.0, 0.081, 0.0), 1.2, (0.0, 0.0, 0.02), (0.001, 0.001, 0.001)),
    ),
    "iiwa7": (
        Link((0.0, 0.0, 0.1575), 2.7025, (0.0, -0.0347, 0.113), (0.0171, 0.0163, 0.006)),
        Link((0.0, 0.0, 0.183), 2.7258, (0.0, 0.0668, 0.0344), (0.017, 0.0162, 0.0061)),
        Link((0.0, 0.184, 0.0), 3.175, (0.0, 0.0296, 0.1265), (0.025, 0.0238, 0.0076)),
        Link((0.0, 0.0, 0.2155), 2.73, (0.0, 0.067, 0.034), (0.017, 0.0162, 0.0061)),
        Link((0.0, 0.184, 0.0), 1.69, (0.0001, 0.021, 0.076), (0.01, 0.0087, 0.00449)),
        Link((0.0, 0.0, 0.2155), 1.8, (0.0, 0.0026, 0.0005), (0.0051, 0.0049, 0.0035)),
        Link((0.0, 0.0805, 0.0), 0.4, (0.0, 0.0, 0.0294), (0.0004, 0.0004, 0.0005)),
    ),
}

#: The flange's distance from joint 7's frame along its axis [m].
FLANGE_M = 0.045

#: The rated payload of each arm (KUKA's data sheets: 14 kg and 7 kg) [kg].
RATED_PAYLOAD_KG: dict[str, float] = {"iiwa14": 14.0, "iiwa7": 7.0}

#: Where each arm's figures come from, as written into the files that use them.
SOURCES: dict[str, str] = {
    "iiwa14": "Drake iiwa14_no_collision.urdf (RobotLocomotion/drake); limits: KUKA LBR iiwa 14 R820 data sheet",
    "iiwa7": "Drake iiwa7_no_collision.sdf (RobotLocomotion/drake); limits: KUKA LBR iiwa 7 R800 data sheet",
}
