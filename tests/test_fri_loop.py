"""The FRI runtime against the robot emulator over loopback: the whole protocol, in lockstep.

Each test starts the emulator in its own process and a client in this
process or as the ``iiwa-ident`` command. The emulator runs in lockstep (it
waits for each answer on a virtual clock), so every outcome is exact and
does not depend on the machine's load; ``bench/bench_fri_runtime.py``
measures the real-time behaviour.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import wait_for
from iiwa_ident.datasets import LOG_SHM_PREFIX as SHM_PREFIX
from iiwa_ident.datasets import read_dataset
from iiwa_ident.deploy import deploy, write_config
from iiwa_ident.design._additive import design_controller
from iiwa_ident.design._analysis import identified_model
from iiwa_ident.design._design_file import make_record
from iiwa_ident.design._margins import outer_loop_margins
from iiwa_ident.emulator import EmulatorConfig, Faults, spawn_emulator
from iiwa_ident.errors import IiwaIdentError, SafetyStop
from iiwa_ident.excite import Chirp, record
from iiwa_ident.fri._protocol import ClientCommandMode, SessionState, decode_monitoring
from iiwa_ident.fri._robot import FriRobot
from iiwa_ident.model import JointParameters
from iiwa_ident.robot import Command
from iiwa_ident.runtime import make_task, run_controller
from iiwa_ident.sim import SimulatedJoint, default_plant

CLI = [str(Path(sys.executable).with_name("iiwa-ident"))]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def config():
    """The default design on Table I with an identified ripple table, deployed with default limits."""
    model = identified_model(seed=1)
    design = design_controller(JointParameters.from_model(model))
    return deploy(make_record(design, outer_loop_margins(design), model), "iiwa14", 1)


@pytest.fixture(scope="module")
def config_file(config, tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "controller.toml"
    write_config(path, config)
    return path


def _emulator(port, **kw):
    """The robot side in lockstep, with the robot's own 5 ms answer timeout (of virtual time).

    The long guard time: a client that has finished is not taken for gone (and its session not dropped)
    before the test stops the emulator, however long the client takes to close its log.
    """
    return spawn_emulator(EmulatorConfig(client=("127.0.0.1", port), **{"lockstep": True, "lockstep_guard_s": 60.0,
                                                                         **kw}))


def _client(port) -> FriRobot:
    # In lockstep the robot is never silent while the session lasts; the long timeout only covers a
    # machine that stalls the emulator process.
    return FriRobot("127.0.0.1", 1, port=port, connect_timeout_s=60.0, message_timeout_s=30.0)


class TestChirpOnTheRobotTarget:
    def test_records_what_the_simulation_records(self, tmp_path):
        # Same plant, same seed, same program: over FRI the dataset equals the simulated one, since
        # the emulator applies each answer in the next cycle as the simulated joint applies the
        # command of a step; and every row is what the robot side measured and applied in that cycle.
        port = free_port()
        chirp = Chirp(1.0, 20.0, 1.5, 5.0, 3.0, 30.0)
        robot_log = tmp_path / "robot.h5"
        with _emulator(port, duration_s=3.0, seed=4, record=robot_log) as emu:
            ds = record(_client(port), chirp)
            emu.stop()
            report = emu.join(60.0)
        sim = record(SimulatedJoint(default_plant(), seed=4), chirp)
        assert ds.source == "robot" and ds.experiment == "chirp"
        assert len(ds["t"]) == len(sim["t"]) == 1500, ds.experiment_attrs.get("stopped_reason")
        assert report.session_drops == [] and report.missed_commanding == 0 and report.late_answers == 0
        np.testing.assert_allclose(np.diff(ds["t"]), 1e-3, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(ds["tau_j"], sim["tau_j"])
        np.testing.assert_array_equal(ds["q_m"], sim["q_m"])
        np.testing.assert_array_equal(ds["tau_c"], sim["tau_c"])
        rs = read_dataset(robot_log)
        k = int(rs.experiment_attrs["commanding_start_index"]) + np.arange(len(ds["t"]))
        np.testing.assert_array_equal(rs["tau_j"][k], ds["tau_j"])
        np.testing.assert_array_equal(rs["tau_c"][k], ds["tau_c"])


class TestRunAgainstTheEmulator:
    def test_tracks_25_hz_through_the_protocol(self, config, tmp_path):
        port = free_port()
        robot_log = tmp_path / "robot.h5"
        with _emulator(port, duration_s=3.5, seed=0, record=robot_log) as emu:
            rep = run_controller(config, _client(port), make_task("sine", 15.0, 25.0), 3.0, tmp_path / "run.h5")
            emu.stop()
            emu_report = emu.join(60.0)
        assert rep.stop_reason == "duration" and rep.watchdog_events == []
        assert rep.lost_log_rows == 0 and rep.logged == rep.cycles + 1
        assert emu_report.session_drops == [] and emu_report.missed_commanding == 0
        log = read_dataset(tmp_path / "run.h5")
        t, tau_j, tau_r = log["t"], log["tau_j"], log["tau_r"]
        assert np.all(log["watchdog"] == 1.0)
        ref = np.interp(t - 0.005, t, tau_r)  # Td = 5 ms, which no client-side controller removes
        steady = (t > 1.0) & (t < 2.9)
        err = np.abs(tau_j - ref)[steady]
        assert np.percentile(err, 99) < 10.0  # section V.C: < 10 Nm on the raw torque
        assert robot_log.exists()

    @pytest.mark.realtime
    def test_tracks_25_hz_in_real_time(self, config, tmp_path):
        """The same run with the emulator on the wall clock and the robot's own 5 ms timeout.

        Passes on an idle machine; a loaded one may lose the session (which is what
        ``bench/bench_fri_runtime.py`` measures).
        """
        port = free_port()
        with spawn_emulator(EmulatorConfig(client=("127.0.0.1", port), duration_s=3.5, seed=0)) as emu:
            robot = FriRobot("127.0.0.1", 1, port=port, connect_timeout_s=30.0)
            rep = run_controller(config, robot, make_task("sine", 15.0, 25.0), 3.0, tmp_path / "run.h5")
            emu.stop()
            emu_report = emu.join(60.0)
        assert rep.stop_reason == "duration", rep.stop_reason
        assert rep.lost_log_rows == 0 and rep.logged == rep.cycles + 1
        assert all(t > 3.0 for t, _ in emu_report.session_drops), emu_report.session_drops
        log = read_dataset(tmp_path / "run.h5")
        t, tau_j, tau_r = log["t"], log["tau_j"], log["tau_r"]
        steady = (t > 1.0) & (t < 2.9) & (log["watchdog"] == 1.0)
        err = np.abs(tau_j - np.interp(t - 0.005, t, tau_r))[steady]
        assert np.percentile(err, 99) < 10.0

    def test_survives_loss_jitter_duplicates_and_reordering(self, config, tmp_path):
        port = free_port()
        # No corruption of answers here: the robot drops a session on an inconsistent command, by design.
        faults = Faults(loss=0.05, jitter_s=0.0003, duplicate=0.05, reorder=0.05, seed=3)
        with _emulator(port, duration_s=3.0, seed=0, faults=faults) as emu:
            rep = run_controller(config, _client(port), make_task("sine", 5.0, 1.0), 2.5, tmp_path / "run.h5")
            emu.stop()
            emu_report = emu.join(60.0)
        c = rep.connection
        assert c["stale"] > 0 and c["lost"] > 0  # every fault reached the client
        assert emu_report.faults["loss"] > 0
        log = read_dataset(tmp_path / "run.h5")
        assert np.isfinite(log["tau_c"]).all()
        assert rep.cycles > 2000
        # The session survives 5 % loss: a lost answer costs one held cycle, only silence ends it.
        assert rep.stop_reason == "duration", rep.stop_reason

    def test_a_30_ms_robot_stall_is_ridden_out(self, config, tmp_path):
        # The robot's own cycle slips for 30 ms at 1 s of commanding: no message, no answer awaited, the
        # sequence counter does not jump (only the time stamps show the silence).
        port = free_port()
        with _emulator(port, duration_s=2.5, seed=0, stalls=((1.0, 0.03),)) as emu:
            rep = run_controller(config, _client(port), make_task("sine", 5.0, 2.0), 2.0, tmp_path / "run.h5")
            emu.stop()
            emu_report = emu.join(60.0)
        assert emu_report.stalled_cycles == 30
        assert emu_report.session_drops == [] and emu_report.missed_commanding == 0
        assert rep.stop_reason == "duration"
        # Every message that arrived was answered (but the one that came after the final ramp-out).
        assert rep.connection["received"] - rep.connection["sent"] == 1 and rep.connection["lost"] == 0
        (t_trip, trip), (t_back, back) = rep.watchdog_events
        assert trip == "tripped: 31 cycles since the previous robot message" and back.startswith("recovered")
        assert t_trip == pytest.approx(1.030, abs=1e-9) and t_back == pytest.approx(t_trip + 0.1, abs=1e-9)
        log = read_dataset(tmp_path / "run.h5")
        t, w, tau_c = log["t"], log["watchdog"], log["tau_c"]
        gap = np.flatnonzero(np.diff(t) > 1.5e-3)
        assert len(gap) == 1 and np.diff(t)[gap[0]] == pytest.approx(0.031, abs=1e-9)
        k = gap[0] + 1  # the first message after the stall
        # The additive torque ramps to zero over 20 ms, stays there, and ramps back in after recovery.
        assert w[k - 1] == 1.0 and w[k] == pytest.approx(0.95)
        assert np.all(w[k + 20:k + 100] == 0.0) and np.all(tau_c[k + 20:k + 100] == 0.0)
        assert np.all(np.abs(np.diff(tau_c[k - 1:k + 21])) <= config.limits.torque_rate_nm_s * 1e-3 + 1e-9)
        assert np.all(w[k + 120:] == 1.0) and np.abs(tau_c[k + 120:]).max() > 1.0

    def test_a_safety_stop_ends_the_run_with_its_reason(self, config, tmp_path):
        # 10 Nm from near the end of joint 1's range: the robot side stops the joint inside the range, the
        # session leaves COMMANDING_ACTIVE and the run ends on the robot's safety state.
        port = free_port()
        pose = (2.6, 0.5, 0.0, -1.5, 0.0, 1.0, 0.0)
        with _emulator(port, duration_s=10.0, seed=0, joint_positions=pose) as emu:
            rep = run_controller(config, _client(port), make_task("constant", 10.0), 8.0, tmp_path / "run.h5")
            emu.stop()
            emu_report = emu.join(60.0)
        assert emu_report.end_reason == "safety_stop" and "would pass the end of its range" in emu_report.safety_stop
        assert "SAFETY_STOP_LEVEL_1" in rep.stop_reason and rep.cycles < 8000
        log = read_dataset(tmp_path / "run.h5")
        assert np.abs(log["q_m"]).max() < default_plant().limits.position_rad

    def test_refuses_a_robot_in_the_wrong_command_mode(self, config, tmp_path):
        port = free_port()
        with _emulator(port, duration_s=1.0, client_command_mode=ClientCommandMode.POSITION) as emu:
            with pytest.raises(IiwaIdentError, match="client command mode POSITION .need TORQUE."):
                run_controller(config, _client(port), make_task("zero"), 1.0, tmp_path / "run.h5")
            emu.stop()
            emu.join(60.0)


#: Longest wait for the first rows in the live log [s]: the log writer starts beside the session.
FIRST_FLUSH_S = 300.0


def _start_run(config_file, port, log, duration, *extra, silence="30"):
    """``iiwa-ident run`` against the emulator; returns once it prints that it is commanding.

    Not under a real-time policy: a lockstep session never idles, so under SCHED_FIFO it would own a CPU
    and starve the log writer and the emulator on a two-core machine.
    """
    proc = subprocess.Popen(CLI + ["run", "--config", str(config_file), "--robot", "127.0.0.1", "--port", str(port),
                                   "--duration", str(duration), "--log", str(log), "--silence-limit", silence,
                                   "--no-realtime", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    for line in proc.stdout:  # blocks until the command prints, or ends
        lines.append(line)
        if line.startswith("commanding:"):
            return proc
    proc.wait(60)
    pytest.fail("'iiwa-ident run' ended before commanding:\n" + "".join(lines))


def _state_after_commanding(port: int, timeout_s: float = 60.0) -> SessionState:
    """Listen on the client's port (its process has gone): the state of the first message not in COMMANDING_ACTIVE."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", port))
        s.settimeout(timeout_s)
        while True:
            state = decode_monitoring(s.recvfrom(4096)[0]).connection_info.session_state
            if state != SessionState.COMMANDING_ACTIVE:
                return state


def _left_behind(pid: int, folder: Path) -> list[str]:
    """Shared-memory segments of process ``pid`` and temporary files in ``folder``."""
    shm = [f for f in os.listdir("/dev/shm") if f.startswith(f"{SHM_PREFIX}{pid}-")] if os.path.isdir("/dev/shm") else []
    return shm + [f.name for f in folder.iterdir() if f.name.endswith(".tmp")]


def _rows(path: Path) -> int:
    """Rows readable from a log (live or finished); 0 while there is none."""
    try:
        return read_dataset(path).n_samples
    except IiwaIdentError:
        return 0


class TestRunCommand:
    # The runs are long (1000 s of virtual time) and end early, by a signal or a vanishing robot: the log
    # writer starts beside the session, and on a loaded machine its new interpreter may take long to start
    # while the lockstep session (never idle: it runs as fast as the two sides answer) runs ahead.
    @pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
    def test_a_signal_ramps_out_and_closes_the_log(self, config_file, tmp_path, sig):
        port = free_port()
        log = tmp_path / "run.h5"
        with _emulator(port, duration_s=1200.0) as emu:
            proc = _start_run(config_file, port, log, 1000, "--task", "sine", "--amplitude", "3", "--frequency", "5")
            proc.send_signal(getattr(signal, sig))
            out = proc.communicate(timeout=120)[0]
            emu.stop()
            emu.join(60.0)
        assert proc.returncode == 0, out
        assert f"ended: {sig}" in out
        ds = read_dataset(log)
        assert "incomplete" not in ds.experiment_attrs
        assert ds.experiment_attrs["stop_reason"] == sig
        assert len(ds["t"]) >= 20  # the 20 ms ramp
        assert abs(ds["tau_c"][-1]) < 1e-9  # ramped out before the session ended
        assert _left_behind(proc.pid, tmp_path) == []

    def test_a_vanishing_robot_ends_the_run_cleanly(self, config_file, tmp_path):
        port = free_port()
        log = tmp_path / "run.h5"
        with _emulator(port, duration_s=1200.0) as emu:
            # A silence long enough that no stall of a loaded machine ends the run before the robot goes.
            proc = _start_run(config_file, port, log, 1000, "--task", "sine", "--amplitude", "3", "--frequency", "5",
                              silence="2")
            wait_for(lambda: _rows(log) >= 100, FIRST_FLUSH_S, what="100 rows flushed to the live log")
            if os.path.isdir("/dev/shm"):  # the log's ring buffer, while the run lasts (Linux)
                assert len(_left_behind(proc.pid, tmp_path)) == 1
            emu.kill()  # the robot is gone: not one more message
            out = proc.communicate(timeout=120)[0]
        # Written and reported, and a failure for the script that started it: the run did not go its course.
        assert proc.returncode == 1, out
        assert "ended: FRI: no message from the robot for 2000 ms" in out and "Traceback" not in out
        assert out.strip().splitlines()[-1].startswith("error: the run ended after ")
        assert out.strip().endswith(" of 1000 s: FRI: no message from the robot for 2000 ms")
        ds = read_dataset(log)
        assert "incomplete" not in ds.experiment_attrs and "interrupted" not in ds.experiment_attrs
        assert ds.experiment_attrs["stop_reason"] == "FRI: no message from the robot for 2000 ms"
        assert len(ds["t"]) >= 100 and np.all(np.diff(ds["t"]) > 0)
        assert _left_behind(proc.pid, tmp_path) == []

    def test_a_session_the_robot_ends_before_the_duration_fails_the_run(self, config_file, tmp_path):
        # The robot side's commanding lasts 0.3 s, the run asks for 5: the run ramps out on the robot's
        # word, keeps its log, and exits non-zero saying when and why.
        port = free_port()
        log = tmp_path / "run.h5"
        with _emulator(port, duration_s=0.3) as emu:
            proc = _start_run(config_file, port, log, 5, "--task", "zero")
            out = proc.communicate(timeout=120)[0]
            emu.stop()
            emu.join(60.0)
        assert proc.returncode == 1, out
        assert re.fullmatch(r"error: the run ended after 0\.(29|30)\d s of 5 s: FRI: the robot left "
                            r"COMMANDING_ACTIVE \(now MONITORING_READY\)", out.strip().splitlines()[-1]), out
        assert read_dataset(log).n_samples >= 300

    def test_a_robot_that_never_connects_leaves_nothing(self, config_file, tmp_path):
        log = tmp_path / "run.h5"
        proc = subprocess.Popen(CLI + ["run", "--config", str(config_file), "--robot", "127.0.0.1", "--port",
                                       str(free_port()), "--connect-timeout", "0.2", "--log", str(log)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 2, out + err
        assert "no session reached COMMANDING_ACTIVE within 0.2 s" in err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert not log.exists()
        assert _left_behind(proc.pid, tmp_path) == []

    def test_kill_9_leaves_a_readable_log(self, config_file, tmp_path):
        port = free_port()
        log = tmp_path / "run.h5"
        # The guard: the robot takes the killed client for gone after 5 s, long enough that a stall of a
        # loaded machine does not end the live client's session before the kill.
        with _emulator(port, duration_s=1200.0, lockstep_guard_s=5.0) as emu:
            proc = _start_run(config_file, port, log, 1000, "--task", "zero")
            flushed = wait_for(lambda: _rows(log) >= 100 and _rows(log), FIRST_FLUSH_S,
                               what="100 rows flushed to the live log")
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=60)
            # The robot notices the silence, drops the session and waits for a client in MONITORING_WAIT.
            assert _state_after_commanding(port) == SessionState.MONITORING_WAIT
            emu.stop()
            emu_report = emu.join(60.0)
        assert [reason for _, reason in emu_report.session_drops] == ["no answer for 5.0 ms"]

        def finished():  # the writer finishes the file once it sees the runtime gone
            try:
                ds = read_dataset(log)
            except IiwaIdentError:
                return None
            return None if ds.experiment_attrs.get("incomplete") else ds

        ds = wait_for(finished, what="the log writer finishing the file")
        wait_for(lambda: not _left_behind(proc.pid, tmp_path), what="the writer unlinking the ring buffer")
        assert ds.experiment_attrs["interrupted"] is True
        assert len(ds["t"]) >= flushed
        assert np.all(np.diff(ds["t"]) > 0)

    def test_tampered_config_refused(self, config_file, tmp_path):
        bad = tmp_path / "bad.toml"
        bad.write_text(Path(config_file).read_text().replace("torque_nm = 320.0", "torque_nm = 300.0", 1))
        res = subprocess.run(CLI + ["run", "--config", str(bad), "--robot", "127.0.0.1", "--log",
                                    str(tmp_path / "x.h5")], capture_output=True, text=True, timeout=60)
        assert res.returncode == 2
        assert "sha256" in res.stderr and "Traceback" not in res.stderr
        assert not (tmp_path / "x.h5").exists()


def test_session_states_seen_by_the_client(tmp_path):
    """The client answers through the whole state sequence and the robot never drops it."""
    port = free_port()
    with _emulator(port, duration_s=0.3) as emu:
        robot = _client(port)
        robot.start()
        n = 0
        with pytest.raises(SafetyStop, match="left COMMANDING_ACTIVE"):
            while True:
                robot.step(Command(tau_c=0.0))
                n += 1
        robot.stop()
        emu.stop()
        report = emu.join(60.0)
    # 300 messages in COMMANDING_ACTIVE: start() returns the first, each step answers one and gets the next, and
    # the step that answers the last gets MONITORING_READY.
    assert n == 299
    seq = report.state_sequence()
    assert seq[:5] == [SessionState.IDLE, SessionState.MONITORING_WAIT, SessionState.MONITORING_READY,
                       SessionState.COMMANDING_WAIT, SessionState.COMMANDING_ACTIVE]
    assert report.session_drops == []
