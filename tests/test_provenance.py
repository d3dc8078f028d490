"""Checks of a run against the robot's description: the torque reading's sign, the joint that moved."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from iiwa_ident.datasets import Dataset, dataset_warnings, torque_sign_problem
from iiwa_ident.description import gravity_sinusoid
from iiwa_ident.excite import ConstantVelocity, record
from iiwa_ident.ident import starting_model
from iiwa_ident.sim import SimulatedJoint, plant_from_model


def _sweep(joint: int, pose, sign: float, seed: int = 0) -> Dataset:
    """A constant-velocity sweep written apart from the simulator: tau_j = sign (g(q) + friction) + noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 20, 5e-3)
    q = 0.6 * np.sin(2 * np.pi * t / 10)  # about 0.38 rad/s at the middle
    w = np.gradient(q, t)
    amp, phase = gravity_sinusoid("iiwa14", joint, pose)
    tau = sign * (amp * np.sin(q + phase) + 1.5 * np.tanh(w / 0.01) + 3.0 * w) + rng.normal(0, 0.3, t.size)
    pose_arr = np.array(pose, float)
    return Dataset(signals={"t": t, "q_m": q, "tau_j": tau}, experiment="constant_velocity", source="import", joint=joint,
                   sample_rate_hz=200.0,
                   experiment_attrs={"robot_model": "iiwa14", "pose_rad": pose_arr,
                                     "joint_travel_rad": np.eye(7)[joint - 1] * 1.2})


@pytest.mark.parametrize("joint", [2, 4, 6])
def test_a_reading_of_the_other_sign_is_named(joint):
    pose = [0.0] * 7
    assert torque_sign_problem(_sweep(joint, pose, +1.0)) is None
    warning = torque_sign_problem(_sweep(joint, pose, -1.0))
    assert warning is not None and "--scale tau_j=-1" in warning
    assert re.search(r"factor -(0\.9\d|1\.0\d)", warning), warning
    assert dataset_warnings(_sweep(joint, pose, -1.0)) == [warning]


@pytest.mark.parametrize("joint", [1, 3])
def test_on_a_vertical_axis_friction_decides(joint):
    # No gravity torque: the friction the reading shows must drive the link against its motion.
    assert torque_sign_problem(_sweep(joint, [0.0] * 7, +1.0)) is None
    warning = torque_sign_problem(_sweep(joint, [0.0] * 7, -1.0))
    assert warning is not None and "pushes the link along its motion" in warning and "--scale tau_j=-1" in warning
    # 1.5 Nm Coulomb and 3 Nm s/rad at about 0.3 rad/s on average, read the other way round.
    assert re.search(r"\(-(1\.[6-9]|2\.\d)\d Nm on average", warning), warning


def test_friction_of_another_shape_and_coloured_noise_decide_the_same():
    # Written apart from the check's own regressors: Stribeck friction (breakaway 2 Nm falling to 1.2 Nm), a
    # smooth sign of 0.05 rad/s, coloured noise and a slow drift; the reading flipped is named, as logged not.
    from scipy import signal

    rng = np.random.default_rng(4)
    t = np.arange(0, 30, 2e-3)
    q = 0.5 * np.sin(2 * np.pi * t / 7.5)
    w = np.gradient(q, t)
    friction = (1.2 + 0.8 * np.exp(-np.abs(w) / 0.05)) * np.tanh(w / 0.05) + 0.5 * w
    noise = signal.lfilter([1.0], [1.0, -0.95], rng.normal(0, 0.05, t.size)) + 0.2 * np.sin(2 * np.pi * t / 30)
    for sign, named in ((+1.0, False), (-1.0, True)):
        ds = Dataset(signals={"t": t, "q_m": q, "tau_j": sign * friction + noise}, experiment="free", source="import",
                     joint=1, sample_rate_hz=500.0)
        assert (torque_sign_problem(ds) is not None) == named


def test_the_real_vertical_joints_read_the_other_way_round():
    from iiwa_ident.datasets import import_columns

    for joint in (1, 3):
        run = _real(REAL / "iiwa14-constant-velocity" / f"joint{joint}" / "vel_p2")
        files = {"t": run / "cur_traj_time_s.txt", "q_m": run / "joint_position_measured.txt",
                 "tau_j": run / "joint_torque_measured.txt"}
        ds = import_columns(files, joint=joint, experiment="constant_velocity", robot_model="iiwa14")
        assert "pushes the link along its motion" in (torque_sign_problem(ds) or ""), joint
        flipped = import_columns(files, joint=joint, experiment="constant_velocity", robot_model="iiwa14",
                                 scale={"tau_j": -1.0})
        assert torque_sign_problem(flipped) is None


def test_without_gravity_or_friction_nothing_decides():
    ds = _sweep(1, [0.0] * 7, -1.0)
    q = np.asarray(ds["q_m"])
    ds.signals["tau_j"] = np.random.default_rng(1).normal(0, 0.3, q.size)  # noise alone, either sign
    assert torque_sign_problem(ds) is None


def test_a_hand_guided_run_is_not_judged_by_friction():
    # The hand moves the link: friction there says nothing of the reading's sign (the simulated joint's
    # hand-guided run with Stribeck friction, of the convention's sign, read -0.30 Nm pushing along the motion).
    from iiwa_ident.testing import Case, simulate_case

    hidden = {"link_friction": {"coulomb_nm": 2.9, "viscous_nms_rad": 1.2, "stribeck_nm": 1.16,
                                "stribeck_velocity_rad_s": 0.05}}
    for ds in simulate_case(Case(62, hidden=hidden)):
        assert torque_sign_problem(ds) is None, ds.experiment


def test_the_simulator_reads_the_convention():
    # The project's simulator, running the description's joint 4 (its gravity load, which the robot's model
    # compensates), logs a torque of the convention's sign.
    model = starting_model("iiwa14", 4)
    ds = record(SimulatedJoint(plant_from_model(model), seed=2), ConstantVelocity([0.4], range_rad=1.0, mode="position"),
                record_every=5)
    ds.joint = 4  # the simulated joint stands for joint 4 here
    ds.experiment_attrs.update(robot_model="iiwa14", pose_rad=np.zeros(7))
    assert torque_sign_problem(ds) is None
    ds.signals["tau_j"] = -ds.signals["tau_j"]
    assert "reads the other way round" in torque_sign_problem(ds)


# ----------------------------------------------------------------------------- what a log's recording did to it
def _sim_log(tmp_path, every: int = 1, seed: int = 3):
    """A simulated constant-velocity record written in the column layout of a driver's log."""
    from iiwa_ident.sim import default_plant

    ds = record(SimulatedJoint(default_plant(), seed=seed), ConstantVelocity([0.6], range_rad=0.6),
                record_every=every)
    folder = tmp_path / "run"
    folder.mkdir()
    np.savetxt(folder / "t.txt", ds["t"])
    np.savetxt(folder / "q.txt", ds["q_m"])
    np.savetxt(folder / "tau.txt", ds["tau_j"])
    return ds, folder


def _import(folder, t=None, tau=None):
    from iiwa_ident.datasets import import_columns

    if t is not None:
        np.savetxt(folder / "t.txt", t)
    if tau is not None:
        np.savetxt(folder / "tau.txt", tau)
    return import_columns({"t": folder / "t.txt", "q_m": folder / "q.txt", "tau_j": folder / "tau.txt"},
                          joint=1, experiment="constant_velocity")


def test_lost_samples_are_counted(tmp_path):
    from iiwa_ident.datasets import time_gaps_problem

    ds, folder = _sim_log(tmp_path)
    assert time_gaps_problem(_import(folder)) is None
    rng = np.random.default_rng(5)
    drop = np.zeros(ds.n_samples, bool)
    starts = rng.choice(np.arange(100, ds.n_samples - 100), 7, replace=False)
    lengths = [3, 9, 2, 17, 5, 4, 11]
    for s, n in zip(starts, lengths):
        drop[s:s + n] = True
    keep = ~drop
    for name, sig in (("q.txt", ds["q_m"]),):
        np.savetxt(folder / name, sig[keep])
    gappy = _import(folder, t=ds["t"][keep], tau=ds["tau_j"][keep])
    w = time_gaps_problem(gappy)
    t = np.asarray(gappy.t)
    gaps = np.diff(t)[np.diff(t) > 1.5e-3]
    assert w is not None and f"{gaps.size} gaps" in w, w
    assert f"longest {1e3 * gaps.max():.1f} ms" in w, w


def test_a_torque_filtered_before_logging_is_named(tmp_path):
    from scipy import signal

    from iiwa_ident.datasets import band_limited_problem

    ds, folder = _sim_log(tmp_path)
    assert band_limited_problem(_import(folder)) is None
    # A driver's 10 Hz low-pass (exponential smoothing, as ROS drivers do) on the same log.
    alpha = 1 - np.exp(-2 * np.pi * 10 / 1000)
    smoothed = signal.lfilter([alpha], [1, alpha - 1], ds["tau_j"], zi=[ds["tau_j"][0] * (1 - alpha)])[0]
    w = band_limited_problem(_import(folder, tau=smoothed))
    assert w is not None and "low-pass filtered" in w, w
    # Decimated to 200 Hz without a filter, fast motion content falls at the top too, but stays loud.
    (tmp_path / "5").mkdir()
    _, folder5 = _sim_log(tmp_path / "5", every=5)
    assert band_limited_problem(_import(folder5)) is None


def test_a_position_that_is_the_command_is_named():
    from iiwa_ident.datasets import substituted_position_problem

    t = np.arange(0, 2, 1e-3)
    q = 0.3 * np.sin(t)
    ds = Dataset(signals={"t": t, "q_m": q, "tau_j": np.zeros_like(t), "q_cmd": q.copy()}, experiment="sine",
                 source="import", joint=2, sample_rate_hz=1000.0)
    assert "q_m equals q_cmd" in substituted_position_problem(ds)
    ds.signals["q_m"] = q + 1e-6 * np.random.default_rng(0).normal(size=t.size)
    assert substituted_position_problem(ds) is None


REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def _real(folder: Path) -> Path:
    if not folder.is_dir():
        pytest.skip(f"real iiwa 14 logs not found at {folder} (expected ../shared beside the checkout)")
    return folder


def test_import_and_info_report_the_real_chirps_gaps_and_the_filtered_torque(tmp_path):
    from typer.testing import CliRunner

    from iiwa_ident.cli import app
    from iiwa_ident.datasets import IMPORT_WARNINGS_ATTR, read_dataset

    chirp = _real(REAL / "iiwa14-position-chirp" / "joint6")
    args = ["import", "--joint", "6", "--experiment", "free", "--scale", "tau_j=-1",
            "--columns", f"t={chirp / 'cur_traj_time_s.txt'}", "--columns", f"q_m={chirp / 'joint_position_measured.txt'}",
            "--columns", f"tau_j={chirp / 'joint_torque_measured.txt'}", "--out", str(tmp_path / "chirp.h5")]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.stderr
    assert "time has 33 gaps (longest 38.0 ms" in res.stderr
    assert "33 gaps" in read_dataset(tmp_path / "chirp.h5").experiment_attrs[IMPORT_WARNINGS_ATTR]
    info = CliRunner().invoke(app, ["info", str(tmp_path / "chirp.h5")])
    assert info.exit_code == 0 and "warning: time has 33 gaps" in info.stdout
    assert IMPORT_WARNINGS_ATTR not in info.stdout  # printed once, as a warning
    cv = _real(REAL / "iiwa14-constant-velocity" / "joint1" / "vel_p4")
    args = ["import", "--joint", "1", "--experiment", "constant_velocity",
            "--columns", f"t={cv / 'cur_traj_time_s.txt'}", "--columns", f"q_m={cv / 'joint_position_measured.txt'}",
            "--columns", f"tau_j={cv / 'joint_torque_measured.txt'}", "--out", str(tmp_path / "cv.h5")]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0 and "low-pass filtered before it was logged" in res.stderr, res.stderr
