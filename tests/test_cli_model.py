"""The ``model`` subcommand: a joint's starting model from the rigid-body description."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.datasets import Dataset, write_dataset
from iiwa_ident.description import describe_joint
from iiwa_ident.ident import read_model, starting_model
from iiwa_ident.model import table1_model
from iiwa_ident.sim import make_effect


def invoke(*args: str):
    return CliRunner().invoke(app, list(args))


def _one_line_error(result, fragment: str) -> None:
    assert result.exit_code == 2, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and fragment in lines[0], result.stderr
    assert "Traceback" not in result.stderr + result.stdout


def test_starting_model_takes_the_link_side_from_the_description():
    pose = [0.2, 0.5, -0.3, 0.8, 0.1, -0.4, 0.0]
    m = starting_model("iiwa14", 4, pose)
    d = describe_joint("iiwa14", 4, pose)
    assert m.joint == 4 and m.robot_model == "iiwa14" and m.pose_rad == pytest.approx(pose)
    assert m.value("Jl") == pytest.approx(d.Jl_kgm2, rel=1e-12)
    assert m.parameters["Jl"].origin == "description"
    t1 = table1_model()
    for k in ("Jc", "bc", "K", "Td", "KI"):
        assert m.value(k) == t1.value(k) and m.parameters[k].origin == "borrowed"
    # The load effect is gravity's torque on the link: the joint holds its negative, the description's value.
    (load,) = m.effects
    effect = make_effect(load["name"], {k: v for k, v in load.items() if k != "name"})
    for q4 in (-1.0, 0.3, 1.2):
        held = d.gravity_nm * math.sin(q4 + d.gravity_phase_rad)
        tau = effect.values["amplitude_nm"] * math.sin(q4 + effect.values["phase_rad"])
        assert -tau == pytest.approx(held, abs=1e-9)
    assert load["compensated"] == 1.0


def test_a_vertical_axis_carries_no_load():
    assert starting_model("iiwa14", 1).effects == []
    assert starting_model("iiwa7", 7).effects == []


def test_model_command_writes_a_file_that_says_where_each_value_comes_from(tmp_path):
    out = tmp_path / "j6.toml"
    r = invoke("model", "--robot", "iiwa14", "--joint", "6", "--out", str(out))
    assert r.exit_code == 0, r.stderr
    assert "iiwa14 joint 6: Jl" in r.stdout and "borrowed from Table I" in r.stdout
    m = read_model(out)
    assert m.joint == 6 and m.parameters["Jl"].origin == "description" and m.parameters["K"].origin == "borrowed"
    assert m.value("Jl") == pytest.approx(describe_joint("iiwa14", 6).Jl_kgm2)
    text = out.read_text()
    assert 'origin = "description"' in text and "pose_rad" in text


def test_model_command_takes_robot_joint_and_pose_from_a_dataset(tmp_path):
    rng = np.random.default_rng(3)
    pose = [0.0, 0.4, 0.0, -0.6, 0.0, 0.3, 0.0]
    n = 200
    ds = Dataset(signals={"t": np.arange(n) * 1e-3, "q_m": rng.normal(0, 0.01, n), "tau_j": rng.normal(0, 1, n)},
                 experiment="constant_velocity", source="import", joint=4, sample_rate_hz=1000.0,
                 experiment_attrs={"robot_model": "iiwa7", "pose_rad": np.array(pose)})
    path = write_dataset(tmp_path / "run.h5", ds)
    out = tmp_path / "m.toml"
    r = invoke("model", "--data", str(path), "--out", str(out))
    assert r.exit_code == 0, r.stderr
    m = read_model(out)
    assert (m.robot_model, m.joint) == ("iiwa7", 4)
    assert m.value("Jl") == pytest.approx(describe_joint("iiwa7", 4, pose).Jl_kgm2)
    _one_line_error(invoke("model", "--data", str(path), "--joint", "2", "--out", str(out)), "not --joint 2")
    _one_line_error(invoke("model", "--data", str(path), "--robot", "iiwa14", "--out", str(out)),
                    "not --robot iiwa14")


def test_model_command_refusals(tmp_path):
    out = str(tmp_path / "m.toml")
    _one_line_error(invoke("model", "--out", out), "give --joint N or --data")
    _one_line_error(invoke("model", "--joint", "2", "--pose", "0,1,2", "--out", out), "expected 7 comma-separated")
    _one_line_error(invoke("model", "--joint", "2", "--pose", "0,130,0,0,0,0,0", "--out", out), "beyond the iiwa14's limit")
    _one_line_error(invoke("model", "--joint", "9", "--out", out), "--joint 9: an iiwa joint is 1-7")
    _one_line_error(invoke("model", "--robot", "ur5", "--joint", "2", "--out", out), "unknown robot model")
    assert not (tmp_path / "m.toml").exists()


REAL = __import__("pathlib").Path(__file__).resolve().parents[2] / "shared/data/real/iiwa14-constant-velocity"


def _import_real(tmp_path, joint_dir: int, joint: int, run: str = "vel_p3"):
    d = REAL / f"joint{joint_dir}" / run
    if not d.is_dir():
        pytest.skip(f"real iiwa 14 logs not found at {d}")
    out = tmp_path / f"j{joint}.h5"
    r = invoke("import", "--joint", str(joint), "--experiment", "constant_velocity",
               "--columns", f"t={d / 'cur_traj_time_s.txt'}", "--columns", f"q_m={d / 'joint_position_measured.txt'}",
               "--columns", f"tau_j={d / 'joint_torque_measured.txt'}", "--out", str(out))
    assert r.exit_code == 0, r.stderr
    return out, r


def test_import_keeps_the_pose_and_warns_when_another_joint_moved(tmp_path):
    from iiwa_ident.datasets import dataset_pose, read_dataset

    path, r = _import_real(tmp_path, 2, 2)
    robot, pose = dataset_pose(read_dataset(path))
    assert robot == "iiwa14" and len(pose) == 7 and max(abs(x) for x in pose) < 0.05  # straight up
    assert "moved" not in r.stderr
    # Drake's driver logs the torque of the other sign (its notes say so): the description's gravity shows it.
    assert "tau_j reads the other way round" in r.stderr
    wrong, r = _import_real(tmp_path, 2, 3)
    assert "warning:" in r.stderr and "joint 3 moved" in r.stderr and "--joint 2" in r.stderr
    info = invoke("info", str(wrong))
    assert "warning: joint 3 moved" in info.stdout


def test_diagnose_and_ripple_start_from_the_joints_own_model(tmp_path):
    path, _ = _import_real(tmp_path, 1, 1, "vel_1")
    r = invoke("diagnose", str(path), "--out", str(tmp_path / "ext.toml"))
    assert r.exit_code == 0, r.stderr
    assert "starting model of iiwa14 joint 1" in r.stdout
    ext = read_model(tmp_path / "ext.toml")
    assert ext.joint == 1 and ext.value("Jl") == pytest.approx(describe_joint("iiwa14", 1).Jl_kgm2, rel=1e-3)
    r = invoke("ripple", str(path), "--out", str(tmp_path / "rip.toml"))
    assert r.exit_code == 0, r.stderr
    rip = read_model(tmp_path / "rip.toml")
    assert rip.joint == 1 and rip.parameters["Jl"].origin == "description"
    # A model of another joint is refused, by both.
    j2 = tmp_path / "j2.toml"
    assert invoke("model", "--joint", "2", "--out", str(j2)).exit_code == 0
    for cmd in ("diagnose", "ripple"):
        _one_line_error(invoke(cmd, str(path), "--model", str(j2)), "a model of joint 2 on data of joint 1")


def test_dataset_model_refusals():
    from iiwa_ident.errors import IiwaIdentError
    from iiwa_ident.ident import dataset_model

    def ds(joint, pose, robot="iiwa14"):
        n = 50
        attrs = {"robot_model": robot} if pose is None else {"robot_model": robot, "pose_rad": np.array(pose)}
        return Dataset(signals={"t": np.arange(n) * 1e-3, "q_m": np.zeros(n), "tau_j": np.zeros(n)},
                       experiment="constant_velocity", source="import", joint=joint, sample_rate_hz=1000.0,
                       experiment_attrs=attrs)

    zero = [0.0] * 7
    tilted = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0]
    with pytest.raises(IiwaIdentError, match="does not say the other joints' positions"):
        dataset_model([ds(2, None)])
    with pytest.raises(IiwaIdentError, match="different poses .joint 4 differs by 28.6 deg"):
        dataset_model([ds(2, zero), ds(2, tilted)])
    with pytest.raises(IiwaIdentError, match="different robots"):
        dataset_model([ds(2, zero), ds(2, zero, "iiwa7")])
    with pytest.raises(IiwaIdentError, match="a run of joint 3 among runs of joint 2"):
        dataset_model([ds(2, zero), ds(3, zero)])
    # The joint's own position differs between runs: that is the same pose.
    own = [0.0, 0.7, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert dataset_model([ds(2, zero), ds(2, own)]).joint == 2
    borrowed = dataset_model([ds(5, None)], borrow=True)
    assert borrowed.joint == 5 and all(p.origin == "borrowed" for p in borrowed.parameters.values())


def test_fit_refuses_a_base_model_of_another_joint(tmp_path):
    n = 500
    ds = Dataset(signals={"t": np.arange(n) * 1e-3, "q_m": np.zeros(n), "tau_j": np.zeros(n), "tau_c": np.zeros(n)},
                 experiment="chirp", source="import", joint=1, sample_rate_hz=1000.0,
                 experiment_attrs={"robot_model": "iiwa14", "pose_rad": np.zeros(7)})
    path = write_dataset(tmp_path / "chirp.h5", ds)
    j4 = tmp_path / "j4.toml"
    assert invoke("model", "--joint", "4", "--out", str(j4)).exit_code == 0
    _one_line_error(invoke("fit", str(path), "--model", str(j4), "--out", str(tmp_path / "m.toml")),
                    "a model of joint 4 on data of joint 1")
    assert not (tmp_path / "m.toml").exists()


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["parameters"]["K"].update(sdt=10.0), "parameters.K.sdt: unknown key (known: value, std, unit, "
                                                       "origin)"),
    (lambda d: d.update(correlation={"names": [], "matrix": [], "rho": 1}), "correlation.rho: unknown key"),
    (lambda d: d.update(sources=[{"file": "a.h5", "sha256": "0", "rolle": "fit"}]), "sources[0].rolle: unknown key"),
])
def test_a_misspelt_key_in_a_model_file_is_refused(edit, message, tmp_path):
    # Misspelt, the std was dropped without a word and the model read as if it had none.
    import re

    from iiwa_ident._toml import dumps_toml
    from iiwa_ident.model import ModelError

    data = table1_model().to_dict()
    edit(data)
    path = tmp_path / "model.toml"
    path.write_text(dumps_toml(data))
    with pytest.raises(ModelError, match="^" + re.escape(f"{path}: {message}")):
        read_model(path)
