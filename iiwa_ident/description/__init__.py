"""The rigid-body description of the LBR iiwa 14 R820 and iiwa 7 R800: each joint's own physics.

Every joint of the arm moves its own link inertia and carries its own gravity load, both depending on the
pose of the others: the paper's Table I is joint 1's. This package holds the published figures (links'
masses, centres of mass, inertias, the kinematics) and computes from them, with MuJoCo, the mass matrix and
the gravity torques, and for one joint at a pose its ``Jl`` and its gravity load ``A sin(q_j + phi)``.

Public API
----------
ROBOTS, GRAVITY_M_S2
    The arms described; gravity.
JointDescription, describe_joint
    One joint at a pose: ``Jl``, gravity load, limits, the figures' source.
mass_matrix, gravity_torques, link_inertia, gravity_torque, gravity_sinusoid, check_pose, flange_axis
    The arm's dynamics at a pose (:mod:`iiwa_ident.description._dynamics`).
Link, ARM_LINKS, JOINT_TURNS_RPY, FLANGE_M, RATED_PAYLOAD_KG, SOURCES
    The published figures (:mod:`iiwa_ident.description._figures`).
"""

from iiwa_ident.description._dynamics import (
    GRAVITY_M_S2,
    ROBOTS,
    JointDescription,
    check_pose,
    describe_joint,
    flange_axis,
    gravity_sinusoid,
    gravity_torque,
    gravity_torques,
    link_inertia,
    mass_matrix,
)
from iiwa_ident.description._figures import ARM_LINKS, FLANGE_M, JOINT_TURNS_RPY, RATED_PAYLOAD_KG, SOURCES, Link

__all__ = ["ROBOTS", "GRAVITY_M_S2", "JointDescription", "describe_joint", "mass_matrix", "gravity_torques",
           "link_inertia", "gravity_torque", "gravity_sinusoid", "check_pose", "flange_axis", "Link", "ARM_LINKS",
           "JOINT_TURNS_RPY", "FLANGE_M", "RATED_PAYLOAD_KG", "SOURCES"]
