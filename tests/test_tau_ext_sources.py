"""The runtime's external-torque sources through FRI against the emulator in lockstep: the runtime's
estimate, KUKA's estimate, and a Net F/T read over RDT; the built-in loop (the reference as the command)."""

from __future__ import annotations

import numpy as np
import pytest

from iiwa_ident.datasets import read_dataset
from iiwa_ident.deploy import deploy, write_config
from iiwa_ident.design import design_controller, make_record, outer_loop_margins
from iiwa_ident.design._analysis import identified_model
from iiwa_ident.emulator import EmulatorConfig, spawn_emulator
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.fri import FriRobot
from iiwa_ident.model import JointParameters
from iiwa_ident.netft import JointAxisProjection, NetFtSensor, NetFtSettings
from iiwa_ident.pipeline._session import free_udp_port
from iiwa_ident.runtime import ControllerRuntime, make_task, run_controller


@pytest.fixture(scope="module")
def config():
    model = identified_model(seed=1)
    design = design_controller(JointParameters.from_model(model))
    return deploy(make_record(design, outer_loop_margins(design), model), "iiwa14", 1)


def _run(config, tmp_path, kappa, tau_ext, loop="additive", duration=1.5, ft=NetFtSettings(), lever=None):
    port, ft_port = free_udp_port(), free_udp_port()
    cfg = EmulatorConfig(client=("127.0.0.1", port), lockstep=True, lockstep_guard_s=60.0, agent="hand",
                         ft_port=ft_port, ft=ft, ft_lever_m=lever, record=tmp_path / "robot.h5")
    with spawn_emulator(cfg) as emu:
        robot = FriRobot("127.0.0.1", 1, port=port, connect_timeout_s=60.0, message_timeout_s=30.0)
        # The client's geometry: the same lever arm, or the description at the pose FRI reports.
        proj = JointAxisProjection.from_lever_arm(lever) if lever is not None else None
        sensor = NetFtSensor("127.0.0.1", proj, ft_port) if tau_ext == "ft" else None
        rep = run_controller(config, robot, make_task("kappa", kappa=kappa), duration, tmp_path / "log.h5",
                             tau_ext=tau_ext, sensor=sensor, loop=loop)
        emu.stop()
        emu.join(30.0)
    return rep, read_dataset(tmp_path / "log.h5"), read_dataset(tmp_path / "robot.h5")


def _ft_seen(robot, ft: NetFtSettings, n: int):
    """The emulated sensor's output, rebuilt from the robot side's record: the F/T reference through the
    sensor's first-order filter, biased at the first commanding cycle."""
    start = int(robot.experiment_attrs["commanding_start_index"])
    x = np.asarray(robot["tau_ext_ref"], float)[start:start + n]
    a = ft.filter_pole()
    y = np.empty_like(x)
    acc = x[0]
    for i, v in enumerate(x):
        acc = a * acc + (1 - a) * v
        y[i] = acc
    return y


@pytest.mark.parametrize("lever", [None, 0.4])
def test_the_ft_source_is_the_sensor_about_the_axis(config, tmp_path, lever):
    ft = NetFtSettings(cutoff_hz=80.0)
    rep, log, robot = _run(config, tmp_path, 2.0, "ft", ft=ft, lever=lever)
    assert rep.stop_reason == "duration"
    assert rep.sensor["lost"] == 0 and rep.sensor["silent_cycles"] == 0
    got = np.asarray(log["tau_ext_loop"], float)
    want = _ft_seen(robot, ft, len(got))
    # Both are relative to a bias taken at rest; the hand then pushes several Nm.
    assert np.ptp(want) > 2.0
    np.testing.assert_allclose(got[5:] - got[5], want[5:] - want[5], rtol=0, atol=2e-3)
    ref = np.asarray(log["tau_r"], float)
    np.testing.assert_allclose(ref[5:], np.clip(2.0 * got[5:], -1e9, 1e9), atol=1e-9)


def test_the_builtin_loop_sends_the_reference(config, tmp_path):
    rep, log, _ = _run(config, tmp_path, 2.0, "estimate", loop="builtin", duration=1.0)
    assert rep.stop_reason == "duration"
    tau_c, tau_r = np.asarray(log["tau_c"], float), np.asarray(log["tau_r"], float)
    ramp = int(0.03 / 1e-3)  # the final ramp-out
    np.testing.assert_allclose(tau_c[1:-ramp], tau_r[1:-ramp], atol=1e-9)
    assert log.experiment_attrs["loop"] == "builtin" and log.experiment_attrs["tau_ext_source"] == "estimate"


def test_the_fri_source_is_kukas_estimate_from_its_start_value(config, tmp_path):
    rep, log, _ = _run(config, tmp_path, 1.0, "fri", duration=1.0)
    fri = np.asarray(log["tau_ext_fri"], float)
    loop = np.asarray(log["tau_ext_loop"], float)
    np.testing.assert_allclose(loop[1:], fri[1:] - fri[0], atol=1e-12)


def test_a_silent_sensor_ramps_the_loop_down(config, tmp_path):
    """The sensor's address answers nothing: after the fault limit the run ramps out and names it."""
    port = free_udp_port()
    dead = free_udp_port()  # nobody serves RDT here
    with spawn_emulator(EmulatorConfig(client=("127.0.0.1", port), lockstep=True, lockstep_guard_s=60.0,
                                       agent="hand")) as emu:
        robot = FriRobot("127.0.0.1", 1, port=port, connect_timeout_s=60.0, message_timeout_s=30.0)
        sensor = NetFtSensor("127.0.0.1", JointAxisProjection.from_lever_arm(0.5), dead, fault_cycles=10)
        rep = run_controller(config, robot, make_task("kappa", kappa=3.0), 2.0, tmp_path / "log.h5",
                             tau_ext="ft", sensor=sensor)
        emu.stop()
        emu.join(30.0)
    assert rep.stop_reason == "F/T sensor: no record for 10 cycles"
    assert rep.duration_s < 0.1
    log = read_dataset(tmp_path / "log.h5")
    assert np.asarray(log["tau_c"], float)[-1] == 0.0


def test_refusals(config, tmp_path):
    with pytest.raises(IiwaIdentError, match="unknown external-torque source"):
        ControllerRuntime(config, make_task("zero"), tau_ext="hand")
    with pytest.raises(IiwaIdentError, match="needs a sensor"):
        ControllerRuntime(config, make_task("zero"), tau_ext="ft")
    with pytest.raises(IiwaIdentError, match="unknown loop"):
        ControllerRuntime(config, make_task("zero"), loop="outer")
    path = tmp_path / "controller.toml"
    write_config(path, config)
    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    base = ["run", "--config", str(path), "--log", str(tmp_path / "x.h5"), "--task", "kappa"]
    for extra, msg in [(["--target", "sim", "--tau-ext", "ft", "--ft", "127.0.0.1"], "run against the emulator"),
                       (["--target", "sim", "--tau-ext", "ft"], "--tau-ext ft needs the sensor's address"),
                       (["--target", "sim", "--ft", "127.0.0.1"], "--ft is read only with --tau-ext ft"),
                       (["--target", "sim", "--tau-ext", "wrist"], "--tau-ext 'wrist'"),
                       (["--target", "sim", "--loop", "outer"], "--loop 'outer'")]:
        out = CliRunner().invoke(app, base + extra)
        assert out.exit_code == 2 and msg in out.stderr and "Traceback" not in out.stderr, out.stderr
        assert len(out.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("extra, msg", [(["--ft-port", "70000"], "ft_port must be a UDP port"),
                                        (["--ft-port", "0", "--ft-rate", "9000"], "F/T rate must be 1-7000 Hz"),
                                        (["--ft-port", "0", "--ft-lever", "-1"], "ft_lever_m must be")])
def test_emulate_refuses_bad_sensor_settings(extra, msg):
    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    out = CliRunner().invoke(app, ["emulate", "--duration", "1", *extra])
    assert out.exit_code == 2 and msg in out.stderr and "Traceback" not in out.stderr, out.stderr
