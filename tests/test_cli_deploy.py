"""CLI: ``iiwa-ident deploy`` through typer's runner."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.deploy import read_config
from iiwa_ident.design._additive import design_controller
from iiwa_ident.design._design_file import make_record, write_design
from iiwa_ident.design._margins import HumanArm, OuterLoopMargins, outer_loop_margins
from iiwa_ident.ident._model_file import read_model
from iiwa_ident.model import JointParameters

runner = CliRunner()
TABLE1 = Path(__file__).resolve().parents[1] / "datasets" / "paper-table1.toml"


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def one_error_line(res) -> str:
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return lines[0]


@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    """Table I design with the paper's poles, the model file next to it."""
    tmp = tmp_path_factory.mktemp("deploy")
    model_path = tmp / "model.toml"
    shutil.copy(TABLE1, model_path)
    model = read_model(model_path)
    design = design_controller(JointParameters.from_model(model))
    path = tmp / "design.toml"
    write_design(path, make_record(design, outer_loop_margins(design), model, model_path))
    return path


@pytest.fixture(scope="module")
def good_run(design_file, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("out")
    out, js = tmp / "controller.toml", tmp / "deploy.json"
    res = invoke("deploy", "--design", design_file, "--out", out, "--json", js, "--torque-limit", 200)
    return res, out, js


def test_deploy_writes_valid_config(good_run):
    res, out, _ = good_run
    assert res.exit_code == 0, res.output
    config = read_config(out)
    assert config.robot_model == "iiwa14" and config.joint == 1
    assert config.limits.torque_nm == 200.0
    assert config.provenance.design_sha256 and config.provenance.model_sha256
    assert f"sha256 {config.sha256}" in res.output


def test_json_keys(good_run):
    res, out, js = good_run
    data = json.loads(js.read_text())
    assert set(data) >= {"config", "robot_model", "joint", "limits", "robot", "sha256", "checks"}
    assert set(data["limits"]) >= {"torque_nm", "torque_rate_nm_s", "velocity_rad_s", "reference_nm"}
    assert data["robot"] == {"control_mode": "JOINT_IMPEDANCE", "client_command_mode": "TORQUE",
                             "send_period_ms": 1, "receive_multiplier": 1, "watchdog_timeout_s": 0.005}
    assert set(data["sha256"]) == {"config", "design", "model", "datasets"}
    assert data["sha256"]["config"] == read_config(out).sha256
    for c in data["checks"]:
        assert set(c) == {"name", "value", "threshold", "comparison", "unit", "passed"} and c["passed"]


def _assert_refused(res, out, reason):
    assert res.exit_code == 2, res.output
    assert reason in one_error_line(res)
    assert not out.exists() or out.read_text() == "keep me\n"


def test_limits_above_data_sheet_refused_and_existing_file_kept(design_file, tmp_path):
    out = tmp_path / "c.toml"
    out.write_text("keep me\n")
    res = invoke("deploy", "--design", design_file, "--out", out, "--torque-limit", 500, "--json", tmp_path / "j")
    _assert_refused(res, out, "limits_within_data_sheet")
    assert out.read_text() == "keep me\n" and not (tmp_path / "j").exists()


def test_unstable_design_refused(tmp_path):
    # Poles too fast for the 5 ms delay: stable on the Pade model, unstable with the exact delay.
    model = read_model(TABLE1)
    design = design_controller(JointParameters.from_model(model), (-300 + 30j, -300 - 30j, -800, -900),
                               (-1500, -1600, -1700, -1800))
    margins = OuterLoopMargins(builtin=7.8, additive=0.0, arm=HumanArm())  # not needed: refused first
    path = tmp_path / "d.toml"
    write_design(path, make_record(design, margins, model, TABLE1))
    out = tmp_path / "c.toml"
    res = invoke("deploy", "--design", path, "--out", out)
    _assert_refused(res, out, "exact_delay_spectral_radius")


def test_nan_design_refused(design_file, tmp_path):
    path = tmp_path / "d.toml"
    text = design_file.read_text()
    start = text.index("Kd = [") + len("Kd = [")
    path.write_text(text[:start] + "nan, " + text[text.index(",", start) + 1:])
    out = tmp_path / "c.toml"
    res = invoke("deploy", "--design", path, "--out", out)
    _assert_refused(res, out, "gains.Kd")


def test_changed_model_refused(design_file, tmp_path):
    tmp = tmp_path / "x"
    tmp.mkdir()
    shutil.copy(design_file, tmp / "design.toml")
    (tmp / "model.toml").write_text(TABLE1.read_text().replace("Jl = { value = 5.6", "Jl = { value = 5.7"))
    out = tmp / "c.toml"
    # The design records the model by its original absolute path; point it at the changed copy.
    text = (tmp / "design.toml").read_text().replace(str(design_file.parent / "model.toml"), "model.toml")
    (tmp / "design.toml").write_text(text)
    res = invoke("deploy", "--design", tmp / "design.toml", "--out", out)
    _assert_refused(res, out, "model file changed")


def test_missing_design(tmp_path):
    res = invoke("deploy", "--design", tmp_path / "none.toml", "--out", tmp_path / "c.toml")
    _assert_refused(res, tmp_path / "c.toml", "none.toml: no such file")


def test_robot_and_joint_needed_without_model_file(tmp_path):
    model = read_model(TABLE1)
    design = design_controller(JointParameters.from_model(model))
    path = tmp_path / "d.toml"
    write_design(path, make_record(design, OuterLoopMargins(7.8, 23.0, HumanArm()), model))  # no model path
    out = tmp_path / "c.toml"
    res = invoke("deploy", "--design", path, "--out", out)
    _assert_refused(res, out, "pass --robot-model and --joint")
    res = invoke("deploy", "--design", path, "--out", out, "--robot-model", "iiwa14", "--joint", 9)
    _assert_refused(res, out, "--joint 9: an iiwa joint is 1-7")
