"""Checks of a run against the robot's description: the torque reading's sign, the joint that moved."""

from __future__ import annotations

import re

import numpy as np
import pytest

from iiwa_ident.datasets import Dataset, dataset_warnings, torque_sign_problem
from iiwa_ident.description import gravity_sinusoid
from iiwa_ident.excite import ConstantVelocity, record
from iiwa_ident.ident import starting_model
from iiwa_ident.sim import SimulatedJoint


def _sweep(joint: int, pose, sign: float, seed: int = 0) -> Dataset:
    """A constant-velocity sweep written apart from the simulator: tau_j = sign (g(q) + friction) + noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 20, 5e-3)
    q = 0.6 * np.sin(2 * np.pi * t / 10)  # about 0.38 rad/s at the middle
    w = np.gradient(q, t)
    amp, phase = gravity_sinusoid("iiwa14", joint, pose)
    tau = sign * (amp * np.sin(q + phase) + 1.5 * np.tanh(w / 0.01) + 3.0 * w) + rng.normal(0, 0.3, t.size)
    pose_arr = np.array(pose, float)
    return Dataset({"t": t, "q_m": q, "tau_j": tau}, "constant_velocity", "import", joint, 200.0,
                   {"robot_model": "iiwa14", "pose_rad": pose_arr, "joint_travel_rad": np.eye(7)[joint - 1] * 1.2})


@pytest.mark.parametrize("joint", [2, 4, 6])
def test_a_reading_of_the_other_sign_is_named(joint):
    pose = [0.0] * 7
    assert torque_sign_problem(_sweep(joint, pose, +1.0)) is None
    warning = torque_sign_problem(_sweep(joint, pose, -1.0))
    assert warning is not None and "--scale tau_j=-1" in warning
    assert re.search(r"factor -(0\.9\d|1\.0\d)", warning), warning
    assert dataset_warnings(_sweep(joint, pose, -1.0)) == [warning]


def test_a_vertical_axis_does_not_decide():
    assert torque_sign_problem(_sweep(1, [0.0] * 7, -1.0)) is None
    assert torque_sign_problem(_sweep(3, [0.0] * 7, -1.0)) is None


def test_the_simulator_reads_the_convention():
    # The project's simulator, running the description's joint 4 (its gravity load, which the robot's model
    # compensates), logs a torque of the convention's sign.
    model = starting_model("iiwa14", 4)
    ds = record(SimulatedJoint(model.to_plant(), seed=2), ConstantVelocity([0.4], range_rad=1.0, mode="position"),
                record_every=5)
    ds.joint = 4  # the simulated joint stands for joint 4 here
    ds.experiment_attrs.update(robot_model="iiwa14", pose_rad=np.zeros(7))
    assert torque_sign_problem(ds) is None
    ds.signals["tau_j"] = -ds.signals["tau_j"]
    assert "reads the other way round" in torque_sign_problem(ds)
