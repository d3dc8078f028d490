"""The rigid-body description: MuJoCo's mass matrix and gravity torques against values computed by hand and
by a forward kinematics written here apart from the engine."""

import math

import numpy as np
import pytest

from iiwa_ident.description import (
    ARM_LINKS,
    GRAVITY_M_S2,
    JOINT_TURNS_RPY,
    ROBOTS,
    check_pose,
    describe_joint,
    gravity_sinusoid,
    gravity_torques,
    link_inertia,
    mass_matrix,
)
from iiwa_ident.errors import IiwaIdentError


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _frames(robot: str, q: np.ndarray):
    """World origin and rotation of each link frame (URDF convention: origin, then rpy, then the joint's turn
    about z)."""
    p, R, out = np.zeros(3), np.eye(3), []
    for link, (r, pi, y), qi in zip(ARM_LINKS[robot], JOINT_TURNS_RPY, q):
        p = p + R @ np.array(link.origin_m)
        R = R @ _rot("z", y) @ _rot("y", pi) @ _rot("x", r) @ _rot("z", qi)
        out.append((p.copy(), R.copy()))
    return out


def _reference(robot: str, joint: int, q: np.ndarray) -> tuple[float, float]:
    """Jl = sum over the carried links of the inertia about the joint's axis (parallel axes); g = the torque
    that holds their weight."""
    frames = _frames(robot, q)
    pj, Rj = frames[joint - 1]
    axis = Rj[:, 2]
    Jl = g = 0.0
    for (p, R), link in list(zip(frames, ARM_LINKS[robot]))[joint - 1:]:
        c = p + R @ np.array(link.com_m)
        I_world = R @ np.diag(link.inertia_kgm2) @ R.T
        r = c - pj
        Jl += axis @ I_world @ axis + link.mass_kg * float(np.sum(np.cross(axis, r) ** 2))
        weight = np.array([0.0, 0.0, -link.mass_kg * GRAVITY_M_S2])
        g -= axis @ np.cross(r, weight)  # the holding torque opposes gravity's
    return Jl, g


@pytest.mark.parametrize("robot", ROBOTS)
def test_against_a_forward_kinematics_written_apart(robot):
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, 7)
        M, g = mass_matrix(robot, q), gravity_torques(robot, q)
        assert np.allclose(M, M.T, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(M) > 0)
        for j in range(1, 8):
            Jl, gj = _reference(robot, j, q)
            assert M[j - 1, j - 1] == pytest.approx(Jl, rel=1e-9, abs=1e-12)
            assert g[j - 1] == pytest.approx(gj, rel=1e-9, abs=1e-9)


def test_hand_computed_values_straight_up():
    q = np.zeros(7)
    # Link 7 turns about its own centre of mass, on the axis: its own moment.
    assert link_inertia("iiwa14", 7, q) == pytest.approx(0.001, abs=1e-12)
    # Joint 6 carries link 7 (1.2 kg, 0.081 + 0.02 m from the axis) and its own link's 0.6 mm offset.
    amp, phase = gravity_sinusoid("iiwa14", 6, q)
    assert amp == pytest.approx(GRAVITY_M_S2 * (1.2 * 0.101 + 1.8 * 0.0006), rel=1e-9)
    # Joint 1's axis is vertical whatever the pose: no gravity torque.
    rng = np.random.default_rng(1)
    for _ in range(3):
        assert gravity_torques("iiwa14", rng.uniform(-1, 1, 7))[0] == pytest.approx(0.0, abs=1e-9)
    # The same joint tipped by a quarter turn holds its whole weight: the value at q_j = pi/2.
    amp2, phase2 = gravity_sinusoid("iiwa14", 2, q)
    q2 = q.copy()
    q2[1] = math.pi / 2
    assert abs(gravity_torques("iiwa14", q2)[1]) == pytest.approx(amp2, rel=1e-6)


@pytest.mark.parametrize("robot", ROBOTS)
def test_the_gravity_load_of_one_joint_is_a_sinusoid(robot):
    pose = np.array([0.3, -0.4, 0.2, 0.9, -0.5, 0.6, 0.1])
    for j in (2, 4, 6):
        amp, phase = gravity_sinusoid(robot, j, pose)
        for qj in np.linspace(-2, 2, 7):
            q = pose.copy()
            q[j - 1] = qj
            assert gravity_torques(robot, q)[j - 1] == pytest.approx(amp * math.sin(qj + phase), abs=1e-9)


def test_iiwa7_link_origins_as_published():
    # The SDF's link heights at zero (0.1575 ... 1.22 m) from the chain the module writes.
    heights = [p[2] for p, _ in _frames("iiwa7", np.zeros(7))]
    assert heights == pytest.approx([0.1575, 0.3405, 0.5245, 0.74, 0.924, 1.1395, 1.22], abs=1e-12)


def test_every_joint_is_its_own():
    d1, d6 = describe_joint("iiwa14", 1), describe_joint("iiwa14", 6)
    assert d6.Jl_kgm2 < d1.Jl_kgm2 / 5
    assert d6.limits.torque_nm == 40.0 and d1.limits.torque_nm == 320.0
    assert "Drake" in d1.source
    # Jl does not depend on the joint's own position.
    q = np.zeros(7)
    q[3] = 1.0
    assert link_inertia("iiwa14", 4, q) == pytest.approx(link_inertia("iiwa14", 4, np.zeros(7)), rel=1e-12)


def test_refusals():
    with pytest.raises(IiwaIdentError, match="no rigid-body description of robot 'iiwa99'"):
        mass_matrix("iiwa99", np.zeros(7))
    with pytest.raises(IiwaIdentError, match="7 finite joint positions"):
        check_pose([0.0] * 6)
    with pytest.raises(IiwaIdentError, match="joint 2 at 2.5 rad is beyond"):
        check_pose([0, 2.5, 0, 0, 0, 0, 0], "iiwa14")
    with pytest.raises(IiwaIdentError, match="joint must be 1..7"):
        link_inertia("iiwa14", 8, np.zeros(7))


def test_doctests():
    import doctest

    from iiwa_ident.description import _dynamics

    assert doctest.testmod(_dynamics).failed == 0


def test_the_docs_quote_the_description_as_computed():
    from pathlib import Path

    text = " ".join((Path(__file__).resolve().parents[1] / "docs" / "diagnose.md").read_text().split())
    d2, d4, d6 = (describe_joint("iiwa14", j) for j in (2, 4, 6))
    quoted = (f"joint 2 `Jl` {d2.Jl_kgm2:.3g} kg m² and an {d2.gravity_nm:.3g} Nm gravity amplitude, joint 4 "
              f"{d4.Jl_kgm2:.2g} kg m² and {d4.gravity_nm:.3g} Nm, joint 6 {d6.Jl_kgm2:.2g} kg m² and "
              f"{d6.gravity_nm:.2g} Nm")
    assert quoted in text


def test_a_payload_at_the_flange_by_hand():
    # 14 kg at the flange, 0.42 + 0.4 + 0.081 + 0.045 m above joint 2, straight up: m r^2 more inertia; tipped,
    # m g r more torque.
    r = 0.42 + 0.4 + 0.081 + 0.045
    q = np.zeros(7)
    assert link_inertia("iiwa14", 2, q, 14.0) - link_inertia("iiwa14", 2, q) == pytest.approx(14.0 * r ** 2, rel=1e-9)
    a0, _ = gravity_sinusoid("iiwa14", 2, q)
    a14, _ = gravity_sinusoid("iiwa14", 2, q, 14.0)
    assert a14 - a0 == pytest.approx(14.0 * GRAVITY_M_S2 * r, rel=1e-6)
    with pytest.raises(IiwaIdentError, match="a payload is a mass"):
        mass_matrix("iiwa14", q, -1.0)
