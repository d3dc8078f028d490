"""The runtime's per-cycle controller, its watchdog, tasks and the client end of the FRI connection."""

from __future__ import annotations

import dataclasses
import math
import socket
import threading
from pathlib import Path

import numpy as np
import pytest

from iiwa_ident.deploy import deploy
from iiwa_ident.design._additive import design_controller
from iiwa_ident.design._analysis import identified_model
from iiwa_ident.design._design_file import make_record
from iiwa_ident.design._margins import outer_loop_margins
from iiwa_ident.design._spatial_filter import SpatialFilter
from iiwa_ident.errors import IiwaIdentError, SafetyStop
from iiwa_ident.fri._connection import FriConnection, parse_host_port
from iiwa_ident.fri._protocol import (
    COMMAND_MESSAGE_ID,
    MONITORING_MESSAGE_ID,
    ClientCommandMode,
    ConnectionQuality,
    ControlMode,
    DriveState,
    MonitoringMessage,
    SafetyState,
    SessionState,
    decode_command,
    encode_monitoring,
)
from iiwa_ident.fri._robot import FriRobot
from iiwa_ident.ident._model_file import read_model
from iiwa_ident.model import JointParameters
from iiwa_ident.robot import Command, Measurement
from iiwa_ident.runtime import TASKS, ControllerRuntime, KappaTask, TaskInput, Watchdog, make_task
from iiwa_ident.sim import SimulatedJoint, default_plant

TABLE1 = Path(__file__).resolve().parents[1] / "datasets" / "paper-table1.toml"
DT = 1e-3


def _config(model):
    design = design_controller(JointParameters.from_model(model))
    return deploy(make_record(design, outer_loop_margins(design), model), "iiwa14", 1)


@pytest.fixture(scope="module")
def config():
    """Table I, default design and limits (no ripple table)."""
    return _config(read_model(TABLE1))


@pytest.fixture(scope="module")
def ripple_config():
    """Table I with the ripple table identified from a simulated constant-velocity run."""
    return _config(identified_model(seed=1))


def _meas(t=0.0, q=0.0, tau=0.0):
    return Measurement(t=t, q_m=q, tau_j=tau, tau_ext_fri=0.0)


def _closed_loop(cfg, task, n, seed=0):
    """Run the runtime against the simulated joint (ripple on) for n cycles; rows of (t, tau_j, tau_r, tau_j_filt, tau_c)."""
    rt = ControllerRuntime(cfg, task)
    robot = SimulatedJoint(default_plant(), seed=seed)
    m = robot.start()
    rows = []
    for _ in range(n):
        tau = rt.cycle(m)
        rows.append((m.t, m.tau_j, rt.tau_r, rt.tau_j_filt, tau))
        m = robot.step(Command(tau_c=tau))
    return rt, np.array(rows)


class TestWatchdog:
    def test_trips_after_three_lost_cycles_and_ramps_to_zero(self):
        wd = Watchdog(DT, trip_cycles=3, ramp_s=0.02)
        assert not wd.update(0.0, 2.0) and wd.scale == 1.0  # two cycles late: tolerated
        wd.update(0.001, 3.0)
        assert wd.tripped and wd.scale == pytest.approx(1 - 1 / 20)
        for _ in range(18):
            wd.update(0.0, 1.0)
        assert wd.scale == pytest.approx(1 / 20, abs=1e-12)
        wd.update(0.0, 1.0)
        assert wd.scale == 0.0  # 20 ms after the trip
        assert "tripped: 3 cycles" in wd.events[0][1]

    def test_recovers_after_good_cycles_and_ramps_back(self):
        wd = Watchdog(DT, trip_cycles=3, ramp_s=0.01, recover_cycles=50)
        wd.update(0.0, 5.0)
        recovered = [wd.update(0.0, 1.0) for _ in range(49)]
        assert not any(recovered) and wd.scale == 0.0
        assert wd.update(0.05, 1.0) and not wd.tripped
        for _ in range(9):
            wd.update(0.0, 1.0)
        assert wd.scale == pytest.approx(1.0)
        assert [e[1].split(":")[0].split(" ")[0] for e in wd.events] == ["tripped", "recovered"]

    def test_a_loss_during_recovery_restarts_the_count(self):
        wd = Watchdog(DT, trip_cycles=3, recover_cycles=10)
        wd.update(0.0, 3.0)
        for _ in range(9):
            wd.update(0.0, 1.0)
        wd.update(0.0, 4.0)
        assert not any(wd.update(0.0, 1.0) for _ in range(9)) and wd.tripped

    def test_bad_settings_refused(self):
        with pytest.raises(IiwaIdentError):
            Watchdog(DT, trip_cycles=0)


class TestTasks:
    def test_references(self):
        s = lambda t, ext=0.0: TaskInput(t, 0.0, ext)  # noqa: E731  (a one-line helper)
        assert make_task("zero").reference(s(1.0)) == 0.0
        assert make_task("constant", 4.0).reference(s(3.0)) == 4.0
        step = make_task("step", 10.0, period_s=2.0)
        assert [step.reference(s(t)) for t in (0.0, 0.99, 1.0, 2.5)] == [10.0, 10.0, -10.0, 10.0]
        sine = make_task("sine", 5.0, 0.25)
        assert sine.reference(s(1.0)) == pytest.approx(5.0)
        assert KappaTask(3.0).reference(s(0.0, ext=2.0)) == 6.0

    def test_chirp_is_the_exponential_sweep(self):
        from scipy.signal import chirp as scipy_chirp

        task = make_task("chirp", 2.0, 1.0, f1_hz=10.0, sweep_s=10.0)
        t = np.arange(0, 10, DT)
        y = np.array([task.reference(TaskInput(x, 0.0, 0.0)) for x in t])
        expected = 2.0 * scipy_chirp(t, 1.0, 10.0, 10.0, method="logarithmic", phi=-90)
        np.testing.assert_allclose(y, expected, rtol=0, atol=1e-9)

    def test_multisine_is_periodic_and_on_its_odd_lines(self):
        period, dt = 2.0, DT
        task = make_task("multisine", 3.0, 1.0, period_s=period, f1_hz=40.0, sample_time_s=dt)
        n = int(round(period / dt))
        y = np.array([task.reference(TaskInput(k * dt, 0.0, 0.0)) for k in range(3 * n)])
        np.testing.assert_array_equal(y[:n], y[n:2 * n])
        assert np.max(np.abs(y)) == pytest.approx(3.0, rel=1e-12)
        power = np.abs(np.fft.rfft(y[:n])) ** 2
        k = np.arange(len(power))
        f = k / period
        on = (k % 2 == 1) & (f >= 1.0) & (f <= 40.0)
        assert on.sum() == 39 and power[~on].sum() < 1e-20 * power[on].sum()
        np.testing.assert_allclose(power[on], power[on].mean(), rtol=1e-9)  # a flat spectrum

    @pytest.mark.parametrize("kw, message", [
        ({"name": "multisine", "frequency_hz": 10.0, "f1_hz": 5.0}, "must exceed"),
        ({"name": "multisine", "frequency_hz": 600.0, "f1_hz": 700.0}, "no odd line"),
        ({"name": "dance"}, "unknown task"),
        ({"name": "sine", "frequency_hz": 0.0}, "frequency must be positive"),
        ({"name": "kappa", "kappa": -1.0}, "kappa must not be negative"),
        ({"name": "chirp", "frequency_hz": 10.0, "f1_hz": 5.0}, "must exceed"),
        ({"name": "constant", "amplitude_nm": math.nan}, "amplitude must be finite"),
    ])
    def test_bad_parameters(self, kw, message):
        with pytest.raises(IiwaIdentError, match=message):
            make_task(**kw)

    def test_every_name_builds(self):
        assert [make_task(n).name for n in TASKS] == list(TASKS)


class TestControllerRuntime:
    def test_first_cycle_sends_nothing_and_takes_the_torque_offset(self, config):
        rt = ControllerRuntime(config, make_task("zero"))
        assert rt.cycle(_meas(tau=7.0)) == 0.0
        # At rest with the start torque and a zero reference, nothing to correct.
        for k in range(1, 50):
            assert abs(rt.cycle(_meas(t=k * DT, tau=7.0))) < 1e-9

    def test_reference_limited_in_rate_and_size(self, config):
        lim = config.limits
        rt = ControllerRuntime(config, make_task("constant", 10 * lim.torque_nm))
        rt.cycle(_meas())
        refs = []
        for k in range(1, 100):
            rt.cycle(_meas(t=k * DT))
            refs.append(rt.tau_r)
        assert np.diff(refs).max() <= lim.reference_rate_nm_s * DT * (1 + 1e-12)
        assert refs[-1] == pytest.approx(lim.reference_nm)
        assert max(abs(r) for r in refs) <= lim.reference_nm

    def test_command_limited_in_rate_and_size(self, config):
        tight = dataclasses.replace(config, limits=dataclasses.replace(config.limits, torque_nm=20.0,
                                                                          torque_rate_nm_s=2000.0))
        rt = ControllerRuntime(tight, make_task("constant", 15.0))
        out = [rt.cycle(_meas(t=k * DT, tau=-50.0 * (k > 0))) for k in range(300)]  # the joint never follows
        assert max(abs(o) for o in out) <= 20.0
        assert np.abs(np.diff(out)).max() <= 2.0 * (1 + 1e-12)

    def test_never_returns_a_non_finite_torque(self, config):
        rt = ControllerRuntime(config, make_task("sine", 5.0, 1.0))
        rt.cycle(_meas())
        out = [rt.cycle(_meas(t=k * DT, tau=math.nan if k == 20 else 0.0)) for k in range(1, 100)]
        assert all(math.isfinite(o) for o in out)
        assert "non-finite" in rt.stop_reason
        assert rt.finished and out[-1] == 0.0

    def test_stop_ramps_out_within_the_ramp_time(self, config):
        rt = ControllerRuntime(config, make_task("constant", 10.0))
        for k in range(200):
            rt.cycle(_meas(t=k * DT, tau=0.0))
        assert abs(rt.tau_c) > 5.0
        rt.request_stop("SIGINT")
        n = 0
        while not rt.finished:
            rt.cycle(_meas(t=(200 + n) * DT))
            n += 1
        assert n <= 21 and rt.stop_reason == "SIGINT"  # 20 ms ramp at 1 kHz

    def test_over_speed_stops(self, config):
        rt = ControllerRuntime(config, make_task("zero"))
        v = 1.2 * config.limits.velocity_rad_s
        for k in range(200):
            rt.cycle(_meas(t=k * DT, q=v * k * DT))
        assert "joint speed" in rt.stop_reason and rt.finished

    def test_watchdog_gap_scales_the_output(self, config):
        rt = ControllerRuntime(config, make_task("constant", 10.0))
        for k in range(100):
            rt.cycle(_meas(t=k * DT))
        before = rt.tau_c
        rt.cycle(_meas(t=0.104), gap_cycles=4.0)
        assert rt.watchdog.tripped and abs(rt.tau_c) < abs(before)
        for k in range(25):
            rt.cycle(_meas(t=0.105 + k * DT))
        assert rt.tau_c == 0.0 and rt.watchdog.scale == 0.0

    def test_a_cycle_builds_no_array(self, ripple_config):
        # Every piece of the cycle is plain float arithmetic: at most a few small objects live at once
        # (CPython's iterators and floats), where one NumPy array alone takes over 100 bytes.
        import tracemalloc

        rt = ControllerRuntime(ripple_config, make_task("sine", 5.0, 2.0))
        meas = [_meas(k * DT, 0.3 * math.sin(k * DT), 2.0 * math.sin(3 * k * DT)) for k in range(400)]
        for m in meas[:200]:
            rt.cycle(m)
        peaks = []
        tracemalloc.start()
        try:
            for m in meas[200:]:
                base = tracemalloc.get_traced_memory()[0]
                tracemalloc.reset_peak()
                rt.cycle(m)
                peaks.append(tracemalloc.get_traced_memory()[1] - base)
            net = tracemalloc.get_traced_memory()[0] - base
        finally:
            tracemalloc.stop()
        assert max(peaks) <= 256 and net <= 64, (max(peaks), net)

    def test_tracks_25_hz_on_the_simulated_joint(self, ripple_config):
        # Section V.C: 15 Nm at 25 Hz; targets < 10 Nm raw and < 5 Nm filtered (errors against the
        # reference delayed by Td = 5 ms, which no client-side controller can remove).
        _, a = _closed_loop(ripple_config, make_task("sine", 15.0, 25.0), 3000)
        ref = np.roll(a[:, 2], 5)
        steady = slice(1000, None)
        assert np.abs(a[steady, 1] - ref[steady]).max() < 10.0
        assert np.abs(a[steady, 3] - ref[steady]).max() < 5.0

    def test_feedback_is_the_spatial_filter_of_eq_15_along_theta_j(self, ripple_config):
        # Offline: the same filter over the same run, along eq (8)'s theta_j, on tau_J minus its start value.
        cfg = ripple_config
        rt = ControllerRuntime(cfg, make_task("sine", 5.0, 0.5))
        robot = SimulatedJoint(default_plant(), seed=2)
        m = robot.start()
        q, tau, filt = [], [], []
        for _ in range(1500):
            rt.cycle(m)
            q.append(m.q_m), tau.append(m.tau_j), filt.append(rt.tau_j_filt)
            m = robot.step(Command(tau_c=rt.tau_c))
        q, tau = np.array(q), np.array(tau)
        theta = q - cfg.ripple(q)
        f = SpatialFilter.from_settings(cfg.filter, cfg.ripple)
        f.step(0.0, theta[0])  # the runtime starts the filter at rest with the offset removed
        expected = [f.step(x, th) for x, th in zip(tau[1:] - tau[0], theta[1:])]
        np.testing.assert_allclose(filt[1:], expected, rtol=0, atol=1e-12)
        assert np.ptp(theta) > 0.05  # the joint moved, so the filter was active


def _monitoring(seq, state=SessionState.MONITORING_WAIT, q=0.0):
    return encode_monitoring(MonitoringMessage(
        header=dict(message_identifier=MONITORING_MESSAGE_ID, sequence_counter=seq, reflected_sequence_counter=0),
        monitor_data=dict(measured_joint_position=dict(value=(q,) * 7), measured_torque=dict(value=(0.0,) * 7),
                          timestamp=dict(sec=100 + seq // 1000, nanosec=(seq % 1000) * 1_000_000)),
        connection_info=dict(session_state=state, quality=ConnectionQuality.EXCELLENT, send_period_ms=1,
                             receive_multiplier=1)))


#: How long a test waits for a datagram on loopback: it returns as soon as one arrives; the length only
#: ends a test whose datagram never comes (a loaded machine may delay one for a while).
WAIT_S = 30.0


@pytest.fixture
def link():
    """A client listening on a free port and a 'robot' socket on 127.0.0.1."""
    robot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    robot.bind(("127.0.0.1", 0))
    robot.settimeout(WAIT_S)
    client = FriConnection("127.0.0.1", 0, "127.0.0.1")
    yield client, robot
    client.close()
    robot.close()


class TestFriConnection:
    def test_answers_header_only_while_monitoring(self, link):
        client, robot = link
        robot.sendto(_monitoring(7), client.address)
        msg = client.receive(WAIT_S)
        assert msg.header.sequence_counter == 7
        assert client.answer(msg)
        answer = decode_command(robot.recv(2000))
        assert answer.header.message_identifier == COMMAND_MESSAGE_ID
        assert (answer.header.sequence_counter, answer.header.reflected_sequence_counter) == (0, 7)
        assert not answer.HasField("command_data")

    def test_commanding_answers_carry_all_joints(self, link):
        client, robot = link
        robot.sendto(_monitoring(1, SessionState.COMMANDING_ACTIVE), client.address)
        msg = client.receive(WAIT_S)
        client.answer(msg, [0.1] * 7, [0, 0, 0, 0, 0, 0, 2.5])
        answer = decode_command(robot.recv(2000))
        assert tuple(answer.command_data.joint_torque.value) == (0, 0, 0, 0, 0, 0, 2.5)
        assert tuple(answer.command_data.joint_position.value) == (0.1,) * 7
        with pytest.raises(SafetyStop, match="non-finite"):
            client.answer(msg, [0.1] * 7, [math.inf] + [0.0] * 6)
        with pytest.raises(SafetyStop, match="6 values, expected 7"):
            client.answer(msg, [0.1] * 6, [0.0] * 6)
        with pytest.raises(SafetyStop, match="needs joint positions"):
            client.answer(msg)

    def test_nothing_sent_in_idle(self, link):
        client, robot = link
        robot.sendto(_monitoring(1, SessionState.IDLE), client.address)
        assert not client.answer(client.receive(WAIT_S))

    def test_stale_invalid_and_foreign_datagrams_dropped(self, link):
        client, robot = link
        robot.sendto(_monitoring(2), client.address)
        assert client.receive(WAIT_S).header.sequence_counter == 2
        robot.sendto(_monitoring(5), client.address)  # 3 and 4 never seen, but before the client answered
        msg = client.receive(WAIT_S)
        assert msg.header.sequence_counter == 5 and client.stats.lost == 0
        client.answer(msg)
        robot.recv(2000)
        robot.sendto(_monitoring(5), client.address)  # duplicate
        robot.sendto(_monitoring(4), client.address)  # reordered
        robot.sendto(b"\x0a\x02\x08", client.address)  # truncated
        stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        stranger.bind(("127.0.0.2", 0))
        stranger.sendto(_monitoring(9), client.address)
        stranger.close()
        robot.sendto(_monitoring(8), client.address)  # 6 and 7 lost
        msg = client.receive(WAIT_S)
        assert msg.header.sequence_counter == 8
        s = client.stats
        assert (s.stale, s.invalid, s.foreign, s.lost, s.received) == (2, 1, 1, 2, 3)
        assert s.first_answer_s is not None and s.first_answer_s > 0

    def test_only_the_newest_queued_message_is_answered(self, link):
        client, robot = link
        for seq in (1, 2, 3):
            robot.sendto(_monitoring(seq), client.address)
        # Loopback delivery is done inside sendto (Linux), so all three are queued now, as in the tests above.
        assert client.receive(WAIT_S).header.sequence_counter == 3
        assert client.stats.skipped == 2

    def test_sequence_counter_wraps(self, link):
        client, robot = link
        robot.sendto(_monitoring(2**32 - 1), client.address)
        client.receive(WAIT_S)
        robot.sendto(_monitoring(0), client.address)
        assert client.receive(WAIT_S).header.sequence_counter == 0 and client.stats.stale == 0

    def test_timeout_returns_none(self, link):
        client, _ = link
        assert client.receive(0.01) is None


class TestParseHostPort:
    def test_forms(self):
        assert parse_host_port("10.0.0.2") == ("10.0.0.2", 30200)
        assert parse_host_port("robot:30201") == ("robot", 30201)
        assert parse_host_port("localhost:0", None, "--bind", allow_any_port=True) == ("localhost", 0)

    @pytest.mark.parametrize("text", ["host:", "host:x", ":30200", "host:70000", "host:0"])
    def test_bad(self, text):
        with pytest.raises(IiwaIdentError, match="address .*: expected HOST or HOST:PORT with a port 1-65535"):
            parse_host_port(text)

    def test_port_required(self):
        with pytest.raises(IiwaIdentError, match="--client '30200': expected HOST:PORT"):
            parse_host_port("30200", None, "--client")


class TestRealtimeProcess:
    def test_sets_and_undoes(self):
        import os

        from iiwa_ident._realtime import realtime_process
        affinity, policy = os.sched_getaffinity(0), os.sched_getscheduler(0)
        lines = []
        with realtime_process(say=lines.append) as line:
            assert os.sched_getaffinity(0) == {max(affinity)}
            assert line.startswith(f"real time: pinned to CPU {max(affinity)}")
            if "SCHED_FIFO priority 80" in line:
                assert os.sched_getscheduler(0) == os.SCHED_FIFO
        assert lines == [line] and "\n" not in line
        assert os.sched_getaffinity(0) == affinity and os.sched_getscheduler(0) == policy

    def test_not_permitted_says_how_to_grant(self, monkeypatch):
        import os

        from iiwa_ident import _realtime

        def refuse(*args):
            raise PermissionError(1, "Operation not permitted")

        monkeypatch.setattr(os, "sched_setscheduler", refuse)
        monkeypatch.setattr(_realtime, "_mlockall", lambda: "mlockall not permitted")
        with _realtime.realtime_process(cpu=-1) as line:
            pass
        assert line == ("real time: nothing set; SCHED_FIFO not permitted, mlockall not permitted; "
                        + _realtime.GRANT_HINT)
        assert "limits.conf" in line

    def test_bad_cpu_is_a_user_error(self):
        from iiwa_ident._realtime import realtime_process

        with pytest.raises(IiwaIdentError, match="CPU 4096 is not one this process may run on"):
            with realtime_process(cpu=4096):
                pass


def test_report_says_when_no_log_file_was_kept(tmp_path):
    # A robot that vanished after one cycle: the writer keeps no file of one row, and the summary said
    # "log: 1 rows in run.h5" for a file that was not there.
    from iiwa_ident.cli._run_cmd import format_report
    from iiwa_ident.runtime import RunReport

    gone = RunReport(cycles=0, duration_s=0.0, stop_reason="FRI: no message from the robot for 500 ms", logged=1,
                     log=str(tmp_path / "run.h5"))
    assert "too few for a dataset: no file written" in format_report(gone)
    (tmp_path / "kept.h5").write_bytes(b"")
    kept = dataclasses.replace(gone, logged=200, log=str(tmp_path / "kept.h5"))
    assert "log: 200 rows in" in format_report(kept)


# --------------------------------------------------------------------------- what FriRobot sends

Q_MEASURED = (0.10, -0.20, 0.30, -0.40, 0.50, -0.60, 0.70)
Q_IPO = (0.11, -0.19, 0.31, -0.35, 0.52, -0.58, 0.71)  # the interpolator's pose: not the measured one
Q_COMMANDED = (0.12, -0.18, 0.32, -0.36, 0.53, -0.57, 0.72)


def _robot_message(seq, state, mode="torque"):
    control, client = ((ControlMode.JOINT_IMPEDANCE, ClientCommandMode.TORQUE) if mode == "torque"
                       else (ControlMode.POSITION, ClientCommandMode.POSITION))
    return encode_monitoring(MonitoringMessage(
        header=dict(message_identifier=MONITORING_MESSAGE_ID, sequence_counter=seq, reflected_sequence_counter=0),
        robot_info=dict(number_of_joints=7, safety_state=SafetyState.NORMAL_OPERATION,
                        drive_state=(DriveState.ACTIVE,) * 7, control_mode=control),
        monitor_data=dict(measured_joint_position=dict(value=Q_MEASURED), measured_torque=dict(value=(1.0,) * 7),
                          commanded_joint_position=dict(value=Q_COMMANDED),
                          timestamp=dict(sec=100, nanosec=seq * 1_000_000)),
        connection_info=dict(session_state=state, quality=ConnectionQuality.EXCELLENT, send_period_ms=1,
                             receive_multiplier=1),
        ipo_data=dict(joint_position=dict(value=Q_IPO), client_command_mode=client)))


@pytest.mark.parametrize("mode", ["torque", "position"])
def test_fri_robot_sends_the_interpolator_s_positions(mode):
    """KUKA's client: commanded positions while monitoring, the interpolator's (plus the overlay) while commanding."""
    robot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    robot.bind(("127.0.0.1", 0))
    robot.settimeout(WAIT_S)
    client = FriRobot("127.0.0.1", joint=4, port=0, mode=mode, bind_host="127.0.0.1", connect_timeout_s=WAIT_S)
    try:
        address = client.connection.address
        S = SessionState
        answers = []
        robot.sendto(_robot_message(1, S.MONITORING_READY, mode), address)
        robot.sendto(_robot_message(2, S.COMMANDING_WAIT, mode), address)
        # Both are queued; start() answers the newest one and goes on waiting: answer it, then activate.
        started = []
        worker = threading.Thread(target=lambda: started.append(client.start()), daemon=True)
        worker.start()
        answers.append(decode_command(robot.recv(2000)))
        robot.sendto(_robot_message(3, S.MONITORING_READY, mode), address)
        answers.append(decode_command(robot.recv(2000)))
        robot.sendto(_robot_message(4, S.COMMANDING_ACTIVE, mode), address)
        worker.join(WAIT_S)
        assert started and started[0].q_m == Q_MEASURED[3]
        command = Command(tau_c=2.5) if mode == "torque" else Command(q_cmd=-0.3)
        # step() answers message 4, then waits for message 5.
        robot_thread = threading.Thread(target=lambda: client.step(command), daemon=True)
        robot_thread.start()
        answers.append(decode_command(robot.recv(2000)))
        robot.sendto(_robot_message(5, S.COMMANDING_ACTIVE, mode), address)
        robot_thread.join(WAIT_S)
    finally:
        client.stop()
        robot.close()
    waiting, monitoring, active = answers
    assert tuple(waiting.command_data.joint_position.value) == Q_IPO
    assert tuple(monitoring.command_data.joint_position.value) == Q_COMMANDED
    assert not monitoring.command_data.HasField("joint_torque")
    expected = list(Q_IPO)
    if mode == "torque":
        assert tuple(active.command_data.joint_torque.value) == (0.0, 0.0, 0.0, 2.5, 0.0, 0.0, 0.0)
        assert tuple(waiting.command_data.joint_torque.value) == (0.0,) * 7
    else:  # no torques in position mode, as KUKA's client
        expected[3] = -0.3
        assert not active.command_data.HasField("joint_torque") and not waiting.command_data.HasField("joint_torque")
    assert tuple(active.command_data.joint_position.value) == tuple(expected)


def test_restoring_a_handler_installed_from_c_never_raises(monkeypatch):
    """Python reads a handler installed from C as None, which signal.signal refuses: the default takes its place."""
    import signal

    from iiwa_ident._realtime import stop_signals

    real = signal.signal
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    installed = []

    def from_c(sig, handler):
        if handler is None:
            raise TypeError("signal handler must be signal.SIG_IGN, signal.SIG_DFL, or a callable object")
        installed.append((sig, handler))
        real(sig, handler)
        return None  # what Python reports for a handler it did not install

    monkeypatch.setattr(signal, "signal", from_c)
    try:
        with stop_signals(lambda *_: None):
            pass
        assert installed[2:] == [(signal.SIGINT, signal.SIG_DFL), (signal.SIGTERM, signal.SIG_DFL)]
    finally:
        for sig, handler in before.items():
            real(sig, handler)


def test_overlapping_no_gc_blocks_give_the_collector_back_once_all_have_ended():
    """Two loops in two threads (the lockstep validation's parallel runs): the collector stays off while
    either runs and comes back on only when both have ended, in whichever order they end."""
    import gc
    import threading

    from iiwa_ident._realtime import no_gc_pauses

    assert gc.isenabled()
    first_in, second_in, first_may_end, first_out = (threading.Event() for _ in range(4))
    seen = {}

    def first():
        with no_gc_pauses():
            first_in.set()
            first_may_end.wait(10)
        first_out.set()

    t = threading.Thread(target=first)
    t.start()
    try:
        assert first_in.wait(10)
        with no_gc_pauses():  # the second starts while the first runs ...
            second_in.set()
            first_may_end.set()  # ... and the first ends before it
            assert first_out.wait(10)
            seen["after_first_ended"] = gc.isenabled()
        seen["after_both"] = gc.isenabled()
    finally:
        first_may_end.set()
        t.join(10)
    assert seen == {"after_first_ended": False, "after_both": True}
