"""Deployment library: checks, the controller config format and the rebuilt controller."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from iiwa_ident._toml import dumps_toml
from iiwa_ident.deploy import (
    MAX_SPECTRAL_RADIUS,
    ConfigError,
    DeployError,
    Provenance,
    check_design,
    config_to_dict,
    content_sha256,
    controller_from_config,
    deploy,
    read_config,
    reference_limit,
    step_peak_gain,
    write_config,
)
from iiwa_ident.design._additive import design_controller
from iiwa_ident.design._design_file import make_record
from iiwa_ident.design._margins import outer_loop_margins
from iiwa_ident.ident import read_model
from iiwa_ident.model import JointParameters, RippleTable, Source

TABLE1 = Path(__file__).resolve().parents[1] / "datasets" / "paper-table1.toml"


@pytest.fixture(scope="module")
def record():
    model = read_model(TABLE1)
    design = design_controller(JointParameters.from_model(model))
    return make_record(design, outer_loop_margins(design), model, TABLE1)


@pytest.fixture(scope="module")
def config(record):
    return deploy(record, "iiwa14", 1, design_file="design.toml", design_sha256="a" * 64)


def _refusal(record, name, **kw):
    with pytest.raises(DeployError, match=name) as err:
        deploy(record, "iiwa14", 1, **kw)
    assert "\n" not in str(err.value)


class TestChecks:
    def test_good_design_passes_all(self, config):
        names = [c.name for c in config.checks]
        assert names == ["finite", "sample_time", "closed_loop_spectral_radius", "exact_delay_spectral_radius",
                         "outer_loop_kappa_margin", "limits_within_data_sheet", "reference_range"]
        assert all(c.passed for c in config.checks)
        rho = {c.name: c.value for c in config.checks}
        assert rho["closed_loop_spectral_radius"] < MAX_SPECTRAL_RADIUS
        # Linear outer-loop margin with the default 250 Hz pre-filter (design.analysis docstring: 32.9).
        assert rho["outer_loop_kappa_margin"] == pytest.approx(32.9, abs=0.1)

    def test_default_limits_are_the_data_sheet(self, config):
        assert config.limits.torque_nm == 320.0
        assert config.limits.velocity_rad_s == pytest.approx(math.radians(85))
        assert config.limits.torque_rate_nm_s == pytest.approx(32000.0)
        assert config.limits.reference_rate_nm_s == pytest.approx(8000.0)
        # The reference clamp keeps the peak command of a rate-limited reversal at the torque limit.
        assert 0.5 * 320 < config.limits.reference_nm < 320


class TestReferenceLimit:
    def test_reversal_at_the_clamp_peaks_at_the_torque_limit(self, record):
        from iiwa_ident.deploy._checks import _reversal_peak, _step_response
        ref = reference_limit(record, 320.0, 8000.0)
        step, dc = _step_response(record, 2000)
        # Bisection to 0.1 %: at the clamp the peak is at the limit, a little above it is beyond.
        assert _reversal_peak(step, dc, ref, 8.0) == pytest.approx(320.0, rel=2e-3)
        assert _reversal_peak(step, dc, ref * 1.01, 8.0) > 320.0

    def test_slow_reversal_peaks_at_the_dc_gain(self, record):
        from iiwa_ident.deploy._checks import _reversal_peak, _step_response
        step, dc = _step_response(record, 4000)
        # Eq (22) has the DC gain (Jc + Jl) / Jl: 1.184 on Table I; a slow ramp barely overshoots it.
        assert dc == pytest.approx((1.03 + 5.6) / 5.6, rel=1e-3)
        assert _reversal_peak(step, dc, 100.0, 0.1) == pytest.approx(100.0 * dc, rel=0.01)

    def test_ideal_step_refused_rate_limited_accepted(self, record):
        # 250 Hz pre-filter: an unlimited step peaks at ~6.6x, so less than half the range is usable.
        assert step_peak_gain(record) > 5.0
        assert reference_limit(record, 320.0, 1e9) < 0.5 * 320
        assert reference_limit(record, 320.0, 8000.0) >= 0.5 * 320

    def test_unstable_poles_refused(self, record):
        bad = copy.deepcopy(record)
        bad.design.Kd = -bad.design.Kd  # positive feedback
        checks = {c.name: c for c in check_design(bad)}
        assert checks["closed_loop_spectral_radius"].value >= 1
        assert not checks["closed_loop_spectral_radius"].passed
        _refusal(bad, "closed_loop_spectral_radius.*unstable")

    def test_nan_refused(self, record):
        bad = copy.deepcopy(record)
        bad.design.Ld = bad.design.Ld.copy()
        bad.design.Ld[2] = np.nan
        _refusal(bad, "finite = 1 ")

    def test_inf_in_ripple_refused(self, record):
        bad = copy.deepcopy(record)
        bad.ripple = RippleTable(0.01963, np.array([0.0, 1e-5, np.inf, -1e-5]))
        _refusal(bad, "finite")

    def test_kappa_margin_below_builtin_refused(self, record):
        bad = copy.deepcopy(record)
        bad.margins = type(record.margins)(builtin=record.margins.builtin, additive=2.0, arm=record.margins.arm)
        _refusal(bad, "outer_loop_kappa_margin")

    def test_limits_above_data_sheet_refused(self, record):
        _refusal(record, "limits_within_data_sheet.*torque", torque_limit=321.0)
        _refusal(record, "limits_within_data_sheet.*velocity", velocity_limit=2.0)

    def test_feedforward_gain_too_large_refused(self, record):
        bad = copy.deepcopy(record)
        Af, Bf, Cf, Df = bad.design.ffd
        bad.design.ffd = (Af, Bf, 5 * Cf, 5 * Df)
        _refusal(bad, "reference_range")

    def test_wrong_sample_time_refused(self, record):
        bad = copy.deepcopy(record)
        bad.design.sample_time_s = 0.002
        _refusal(bad, "sample_time")


class TestConfigFile:
    def test_round_trip(self, config, tmp_path):
        config = copy.deepcopy(config)
        config.ripple = RippleTable(0.01963, np.array([0.0, 1e-5, 0.0, -1e-5]))
        config.provenance = Provenance("d.toml", "b" * 64, "m.toml", "c" * 64, (Source("x.h5", "d" * 64, "fit"),))
        path = write_config(tmp_path / "c.toml", config)
        back = read_config(path)
        assert back.sha256 == config.sha256 and len(back.sha256) == 64
        assert config_to_dict(back) == config_to_dict(config)
        assert back.robot.control_mode == "JOINT_IMPEDANCE" and back.robot.client_command_mode == "TORQUE"
        assert back.robot.send_period_ms == 1 and back.robot.receive_multiplier == 1
        assert back.robot.watchdog_timeout_s == 0.005
        assert back.provenance.datasets[0].file == "x.h5"
        np.testing.assert_array_equal(back.ripple.lut, config.ripple.lut)

    def test_rebuilt_controller_equals_design(self, record, config, tmp_path):
        back = read_config(write_config(tmp_path / "c.toml", config))
        a, b = record.design.controller(), controller_from_config(back)
        rng = np.random.default_rng(1)
        for tau_r, tau_j in rng.normal(scale=50.0, size=(2000, 2)):
            assert b.step(tau_r, tau_j) == pytest.approx(a.step(tau_r, tau_j), abs=1e-12)

    def test_tampered_file_refused(self, config, tmp_path):
        path = write_config(tmp_path / "c.toml", config)
        text = path.read_text()
        assert "torque_nm = 320.0" in text
        path.write_text(text.replace("torque_nm = 320.0", "torque_nm = 300.0", 1))
        with pytest.raises(ConfigError, match=r"c\.toml: sha256: .*modified.*'iiwa-ident deploy .*--torque-limit NM'"):
            read_config(path)  # the refusal says how such a change is made

    @pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
    def test_written_with_the_users_file_mode(self, config, tmp_path, umask):
        # As any file the user writes (the datasets are 0644 under umask 022): the lab's other accounts read it.
        import os
        import stat

        old = os.umask(umask)
        try:
            path = write_config(tmp_path / f"c{umask:o}.toml", config)
        finally:
            os.umask(old)
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask

    @pytest.mark.parametrize("key", ["limits.torque_nm", "controller.Kd", "robot.watchdog_timeout_s", "joint"])
    def test_missing_key_named(self, config, tmp_path, key):
        data = config_to_dict(config)
        node = data
        *parents, leaf = key.split(".")
        for p in parents:
            node = node[p]
        del node[leaf]
        data["sha256"] = content_sha256(data)  # a consistent hash: the key check itself must catch it
        path = tmp_path / "c.toml"
        path.write_text(dumps_toml(data))
        with pytest.raises(ConfigError, match=rf"c\.toml: {key}: missing"):
            read_config(path)

    def test_one_ripple_period(self, config, tmp_path):
        # The file holds rho once (ripple.period_rad, the filter's and the table's); a second one, in a
        # file with a consistent hash, is refused.
        config = copy.deepcopy(config)
        config.ripple = RippleTable(0.01963, np.array([0.0, 1e-5, 0.0, -1e-5]))
        data = config_to_dict(config)
        data["filter"]["period_rad"] = 0.0197
        data["sha256"] = content_sha256(data)
        path = tmp_path / "c.toml"
        path.write_text(dumps_toml(data))
        with pytest.raises(ConfigError, match=r"c\.toml: filter\.period_rad: unknown key"):
            read_config(path)

    @pytest.mark.parametrize("lut, message", [
        ([0.0, 1e-5], r"ripple\.lut: expected a list of at least 4 deflections"),
        ([0.0, "x", 0.0, 0.0], r"ripple\.lut\[1\]: expected a number"),
        ([0.0, 1e-5, 0.0, 1e999], r"ripple\.lut\[3\]: must be finite"),
    ])
    def test_ripple_table_read_as_the_model_file_reads_it(self, config, tmp_path, lut, message):
        # One reader of a ripple table (RippleTable.from_mapping) for the model, design and controller files.
        from iiwa_ident.ident import model_from_dict
        from iiwa_ident.model import ModelError, table1_model

        config = copy.deepcopy(config)
        config.ripple = RippleTable(0.01963, np.array([0.0, 1e-5, 0.0, -1e-5]))
        data = config_to_dict(config)
        data["ripple"]["lut"] = lut
        data["sha256"] = content_sha256(data)
        path = tmp_path / "c.toml"
        path.write_text(dumps_toml(data))
        with pytest.raises(ConfigError, match=r"c\.toml: " + message):
            read_config(path)
        model = table1_model().to_dict()
        model["ripple"] = {"period_rad": 0.0196, "lut": lut}
        with pytest.raises(ModelError, match=r"m\.toml: " + message):
            model_from_dict(model, "m.toml: ")

    def test_wrong_robot_setting_refused(self, config, tmp_path):
        data = config_to_dict(config)
        data["robot"]["client_command_mode"] = "POSITION"
        data["sha256"] = content_sha256(data)
        path = tmp_path / "c.toml"
        path.write_text(dumps_toml(data))
        with pytest.raises(ConfigError, match="robot.client_command_mode"):
            read_config(path)


class TestDeployTarget:
    """One rule for the robot model and joint, used by `deploy` and the pipeline."""

    def test_the_model_decides_and_requests_must_agree(self):
        from iiwa_ident.deploy import DeployError, deploy_target
        from iiwa_ident.model import table1_model

        model = table1_model()
        model.robot_model, model.joint = "iiwa7", 6
        assert deploy_target(model) == ("iiwa7", 6)
        assert deploy_target(model, "iiwa7", 6) == ("iiwa7", 6)
        with pytest.raises(DeployError, match="--robot-model iiwa14 contradicts the model file"):
            deploy_target(model, "iiwa14")
        with pytest.raises(DeployError, match=r"--joint 1 contradicts the model file \(joint 6\)"):
            deploy_target(model, joint=1)
        model.robot_model = model.joint = None
        with pytest.raises(DeployError, match="pass --robot-model and --joint"):
            deploy_target(model, "iiwa7")
        assert deploy_target(None, "iiwa7", 3) == ("iiwa7", 3)
