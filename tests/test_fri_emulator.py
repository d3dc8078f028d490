"""The robot-side FRI emulator: session states, drops, commands reaching the simulated joint, faults, CLI.

A small client in this module answers over loopback. Most tests run the
emulator in this process's main thread and the client in a thread; one test
runs it through :func:`spawn_emulator`. The emulator runs in lockstep (it
waits for each answer, on a virtual clock), so counts, sequences and the
simulated joint are exact whatever the machine's load; the one test of the
real-time loop is marked ``realtime`` (``make test-realtime``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import threading

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import wait_for
from iiwa_ident.cli import app
from iiwa_ident.datasets import read_dataset, read_truth
from iiwa_ident.emulator import (
    DEFAULT_JOINT_POSITIONS,
    EmulatorConfig,
    Faults,
    QualityThresholds,
    RobotEmulator,
    check_config,
    connection_quality,
    spawn_emulator,
)
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.fri._protocol import (
    COMMAND_MESSAGE_ID,
    ClientCommandMode,
    CommandData,
    CommandMessage,
    ConnectionQuality,
    ControlMode,
    DriveState,
    FriDecodeError,
    JointValues,
    SafetyState,
    SessionState,
    decode_monitoring,
)
from iiwa_ident.sim import SimulatedJoint, default_plant

S = SessionState
COMMANDING = (S.COMMANDING_WAIT, S.COMMANDING_ACTIVE)
FULL_SEQUENCE = [S.IDLE, S.MONITORING_WAIT, S.MONITORING_READY, S.COMMANDING_WAIT, S.COMMANDING_ACTIVE,
                 S.MONITORING_READY, S.IDLE]
# Short phases for tests that are not about the default timing.
FAST = dict(monitoring_s=0.05, ready_s=0.02, commanding_wait_s=0.02, closing_s=0.02)
# The real-time loop's test: a patient robot, since a loaded machine can stall a thread for tens of ms.
PATIENT = dict(timeout_s=0.25, max_wall_s=60.0,
               quality=QualityThresholds(good_loss=0.5, fair_loss=0.9, good_latency_s=0.05, fair_latency_s=0.1))
END = b"end of test"  # sent to the client after the run: everything the robot sent came before it
SILENT = object()  # a policy's "do not answer"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --------------------------------------------------------------------------- the test client


class Client:
    """A minimal FRI client: decodes each monitoring message and answers it as ``policy`` says.

    ``policy(client, msg)`` returns the ``CommandData`` to send (None: header
    only) or ``SILENT``. Nothing is sent in IDLE, as the protocol requires.
    """

    def __init__(self, policy=None) -> None:
        self.policy = policy or torque_policy(0.0)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.address = self.sock.getsockname()
        self.seq = 0
        self.messages = []  # decoded monitoring messages, in arrival order
        self.answered = []  # for each message: whether it was answered
        self.decode_errors = 0
        self.header_only = 0
        self.commands = 0
        self.active_seen = 0
        self.emulator = None  # set by tests whose policy stops the emulator
        self._stop = threading.Event()
        self._settled = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Client:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.sock.close()

    def settle(self) -> None:
        """Wait until the client has handled every datagram the robot sent before now."""
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(END, self.address)
        assert self._settled.wait(60.0), "the client thread did not get the end marker"

    def states(self) -> list[SessionState]:
        """Session states seen, consecutive repeats collapsed."""
        out = []
        for m in self.messages:
            s = m.connection_info.session_state
            if not out or out[-1] != s:
                out.append(s)
        return out

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(4096)
            except (TimeoutError, OSError):
                continue
            if data == END:
                self._settled.set()
                continue
            try:
                msg = decode_monitoring(data)
            except FriDecodeError:
                self.decode_errors += 1
                continue
            if not msg.HasField("connection_info"):  # a corrupted datagram can still parse: nothing to answer
                self.decode_errors += 1
                continue
            self.messages.append(msg)
            state = msg.connection_info.session_state
            if state == S.COMMANDING_ACTIVE:
                self.active_seen += 1
            reply = SILENT if state == S.IDLE else self.policy(self, msg)
            self.answered.append(reply is not SILENT)
            if reply is SILENT:
                continue
            answer = CommandMessage(header=dict(message_identifier=COMMAND_MESSAGE_ID, sequence_counter=self.seq,
                                                reflected_sequence_counter=msg.header.sequence_counter))
            if reply is not None:
                answer.command_data.CopyFrom(reply)
            # Serialized without encode_command's checks: some policies send invalid commands on purpose.
            self.sock.sendto(answer.SerializeToString(), addr)
            self.seq += 1
            if reply is None:
                self.header_only += 1
            else:
                self.commands += 1


def command(q, tau) -> CommandData:
    """Command data of joint positions ``q`` [rad] and torques ``tau`` [Nm] (None: left out)."""
    data = CommandData(joint_position=JointValues(value=q))
    if tau is not None:
        data.joint_torque.value[:] = tau
    return data


def torque_policy(tau: float, joint: int = 1):
    """Header only while monitoring; the interpolator's positions and ``tau`` on ``joint`` while commanding."""

    def policy(client: Client, msg):
        state = msg.connection_info.session_state
        if state not in COMMANDING:
            return None
        torques = [0.0] * 7
        if state == S.COMMANDING_ACTIVE:
            torques[joint - 1] = tau
        return command(msg.ipo_data.joint_position.value, torques)

    return policy


def misbehave_at(n_active: int, bad, state=S.COMMANDING_ACTIVE):
    """Well-behaved, except that the ``n_active``-th message in ``state`` is answered with ``bad(msg)``."""
    good = torque_policy(0.0)
    seen = {"n": 0}

    def policy(client: Client, msg):
        if msg.connection_info.session_state == state:
            seen["n"] += 1
            if seen["n"] == n_active:
                return bad(msg)
        return good(client, msg)

    return policy


def stop_after(n: int, policy):
    """``policy``, and a stop request to the emulator at the ``n``-th message."""

    def stopping(client: Client, msg):
        if len(client.messages) == n:
            client.emulator.stop()
        return policy(client, msg)

    return stopping


def run(client: Client, **kw):
    """Run an emulator in lockstep for ``client`` in this thread; the report once the client has seen it all."""
    # max_wall_s: a client thread that died fails the test instead of hanging it. The guard: a client the
    # loaded machine stalls for seconds is still waited for (a test about silence sets a short one).
    defaults = {"lockstep": True, "max_wall_s": 60.0, "lockstep_guard_s": 5.0}
    emu = RobotEmulator(EmulatorConfig(client=client.address, **{**defaults, **kw}))
    client.emulator = emu
    report = emu.run()
    client.settle()
    return report


# --------------------------------------------------------------------------- session


def test_full_session_with_constant_torque(tmp_path):
    """IDLE -> ... -> COMMANDING_ACTIVE -> MONITORING_READY -> IDLE; 5 Nm reaches the joint as in simulation."""
    out = tmp_path / "robot.h5"
    with Client(torque_policy(5.0)) as client:
        report = run(client, duration_s=0.1, record=out, seed=3)
    assert report.state_sequence() == FULL_SEQUENCE, report.states
    assert report.session_drops == []
    assert report.end_reason == "duration"
    assert [t for t, _ in report.states] == sorted(t for t, _ in report.states)
    # The client sees every state but the silent first IDLE; the final IDLE is sent so it sees the end.
    assert client.states() == FULL_SEQUENCE[1:]
    # Header-only answers in the monitoring states are accepted.
    assert client.header_only > 100 and client.commands > 100
    assert report.answers_invalid == 0 and report.answers_foreign == 0
    assert report.answers_received == client.seq
    assert report.missed_cycles == 0 and report.late_answers == 0 and report.resent == 0
    # Headers: the robot counts from 0 without gaps and reflects the client's latest counter.
    seqs = [m.header.sequence_counter for m in client.messages]
    assert seqs == list(range(len(seqs))) and report.monitoring_sent == len(seqs)
    reflected = [m.header.reflected_sequence_counter for m in client.messages]
    assert np.all(np.diff(reflected) >= 0) and max(reflected) < client.seq
    # Message content.
    active = [m for m in client.messages if m.connection_info.session_state == S.COMMANDING_ACTIVE]
    m = active[-1]
    assert m.robot_info.number_of_joints == 7
    assert tuple(m.robot_info.drive_state) == (DriveState.ACTIVE,) * 7
    assert m.robot_info.control_mode == ControlMode.JOINT_IMPEDANCE
    assert m.ipo_data.client_command_mode == ClientCommandMode.TORQUE
    assert m.connection_info.send_period_ms == 1 and m.connection_info.receive_multiplier == 1
    q = tuple(m.monitor_data.measured_joint_position.value)
    assert len(q) == 7 and q[1:] == DEFAULT_JOINT_POSITIONS[1:]
    # The interpolator holds the pose where commanding began while the pushed joint moves away from it.
    start = tuple(active[0].monitor_data.measured_joint_position.value)
    assert all(tuple(a.ipo_data.joint_position.value) == start for a in active)
    assert q[0] != start[0]
    assert all(a.ipo_data.tracking_performance == 1.0 for a in active)
    others = [a for a in client.messages if a.connection_info.session_state != S.COMMANDING_ACTIVE]
    assert others and all(a.ipo_data.tracking_performance == 0.0 for a in others)
    assert tuple(m.monitor_data.commanded_torque.value) == (5.0, 0, 0, 0, 0, 0, 0)
    assert m.monitor_data.timestamp.sec > 1_600_000_000
    # The robot-side dataset: the joint moved under 5 Nm exactly as the simulated joint does.
    ds = read_dataset(out)
    assert ds.experiment == "free" and ds.source == "simulation" and ds.sample_rate_hz == 1000.0
    for name in ("t", "q_m", "tau_j", "tau_ext_fri", "q_l_ref", "tau_ext_ref", "tau_c"):
        assert ds.has(name)
    assert np.all(np.diff(ds["t"]) > 0)
    assert read_truth(out)["dynamics"]["K"] == default_plant().dynamics["K"]
    k0 = int(ds.experiment_attrs["commanding_start_index"])
    assert 100 < k0 < ds.n_samples
    tau_c = ds["tau_c"][k0:]
    assert np.all(ds["tau_c"][:k0] == 0.0) and np.count_nonzero(tau_c == 5.0) == 99
    sim = SimulatedJoint(default_plant(), seed=3, q0=DEFAULT_JOINT_POSITIONS[0]).run_open_loop(tau_c=tau_c)
    n = len(tau_c)
    np.testing.assert_allclose(ds["tau_j"][k0:], sim.measured["tau_j"][:n], rtol=0, atol=1e-9)
    np.testing.assert_allclose(ds["q_m"][k0:], sim.measured["q_m"][:n], rtol=0, atol=1e-12)
    pushed = np.flatnonzero(ds["tau_c"] == 5.0)
    assert ds["tau_j"][pushed[30:]].mean() > 3.0  # the commanded torque reached the joint (Td = 5 ms)
    assert np.all(ds["q_m"][:k0] == ds["q_m"][0])  # at rest before commanding


def test_silent_client_drops_the_session():
    """No answers in COMMANDING_ACTIVE: the robot drops the session after 5 ms of silence."""

    def policy(client: Client, msg):
        state = msg.connection_info.session_state
        if client.active_seen >= 30:
            if state == S.MONITORING_WAIT:
                client.emulator.stop()
            return SILENT
        return torque_policy(0.0)(client, msg)

    with Client(policy) as client:
        report = run(client, **dict(FAST, timeout_s=0.005, lockstep_guard_s=0.5))
    assert [r for _, r in report.session_drops] == ["no answer for 5.0 ms"]
    assert report.client_gone == 1
    assert report.state_sequence()[:6] == FULL_SEQUENCE[:5] + [S.MONITORING_WAIT]
    assert report.end_reason == "stopped"
    # Messages the client received after its last answer, up to the drop: the one it left
    # unanswered; the robot side then waited out the guard time and ran the other cycles of the
    # five of silence unsent (a client taken for gone hears nothing of its old session).
    last = max(i for i, a in enumerate(client.answered) if a)
    after = [m.connection_info.session_state for m in client.messages[last + 1:]]
    n_active = after.index(S.MONITORING_WAIT)
    assert after[:n_active] == [S.COMMANDING_ACTIVE] * n_active
    assert (n_active, report.unsent) == (1, 4)
    drop_t = report.session_drops[0][0]
    active_t = next(t for t, s in report.states if s == S.COMMANDING_ACTIVE)
    assert drop_t > active_t


def _offset(msg, joint=3, by=0.2):
    q = list(msg.ipo_data.joint_position.value)
    q[joint - 1] += by
    return command(q, (0.0,) * 7)


def _short(msg):
    return command(msg.monitor_data.measured_joint_position.value, (0.0,) * 6)


def _nan(msg):
    return command(msg.monitor_data.measured_joint_position.value, (math.nan,) + (0.0,) * 6)


@pytest.mark.parametrize("bad, reason", [
    (_offset, "commanded position of joint 3 is 0.200 rad from the interpolator's (limit 0.1 rad)"),
    (_short, "joint_torque has 6 values, expected 7"),
    (_nan, "joint_torque has a non-finite value"),
    (lambda msg: None, "command without commandData"),
], ids=["inconsistent-position", "short-torques", "nan-torque", "header-only"])
def test_bad_command_drops_the_session_and_the_client_can_come_back(bad, reason):
    with Client(misbehave_at(20, bad)) as client:
        report = run(client, duration_s=0.05, **FAST)
    assert [r for _, r in report.session_drops] == [reason]
    seq = report.state_sequence()
    assert seq[:6] == FULL_SEQUENCE[:5] + [S.MONITORING_WAIT]
    assert seq.count(S.COMMANDING_ACTIVE) == 2  # a new session after the drop, to the end
    assert seq[-2:] == [S.MONITORING_READY, S.IDLE] and report.end_reason == "duration"


def test_inconsistent_position_while_waiting_never_activates():
    with Client(misbehave_at(1, _offset, state=S.COMMANDING_WAIT)) as client:
        report = run(client, duration_s=0.05, **FAST)
    assert len(report.session_drops) == 1 and "joint 3" in report.session_drops[0][1]
    assert report.state_sequence()[:5] == [S.IDLE, S.MONITORING_WAIT, S.MONITORING_READY, S.COMMANDING_WAIT,
                                           S.MONITORING_WAIT]


def position_overlay(offset):
    """Header only while monitoring; the interpolator's positions while commanding, joint 1's plus
    ``offset(n)`` [rad] in the ``n``-th COMMANDING_ACTIVE message, as KUKA's joint position overlays do."""
    seen = {"n": 0}

    def policy(client: Client, msg):
        state = msg.connection_info.session_state
        if state not in COMMANDING:
            return None
        q = list(msg.ipo_data.joint_position.value)
        if state == S.COMMANDING_ACTIVE:
            seen["n"] += 1
            q[0] += offset(seen["n"])
        return command(q, None)

    return policy


def test_position_mode_follows_the_commanded_position(tmp_path):
    policy = position_overlay(lambda n: 0.05)
    out = tmp_path / "pos.h5"
    with Client(policy) as client:
        report = run(client, duration_s=0.4, control_mode=ControlMode.POSITION,
                     client_command_mode=ClientCommandMode.POSITION, record=out, **FAST)
    assert report.session_drops == [] and report.end_reason == "duration"
    ds = read_dataset(out)
    assert ds.has("q_cmd") and not ds.has("tau_c")
    active = [m for m in client.messages if m.connection_info.session_state == S.COMMANDING_ACTIVE]
    assert abs(ds["q_m"][-1] - (active[0].ipo_data.joint_position.value[0] + 0.05)) < 0.01


def test_joint_position_overlay_swings_about_the_interpolator_s_pose():
    """KUKA's joint sine overlay (interpolator position + 0.04 rad sine) swings the joint by 0.04 rad, no more."""
    amplitude, frequency = 0.04, 2.0
    policy = position_overlay(lambda n: amplitude * math.sin(2 * math.pi * frequency * n * 1e-3))

    with Client(policy) as client:
        report = run(client, duration_s=1.0, control_mode=ControlMode.POSITION,
                     client_command_mode=ClientCommandMode.POSITION, **FAST)
    assert report.session_drops == [] and report.end_reason == "duration"
    active = [m for m in client.messages if m.connection_info.session_state == S.COMMANDING_ACTIVE]
    ipo = np.array([m.ipo_data.joint_position.value[0] for m in active])
    q = np.array([m.monitor_data.measured_joint_position.value[0] for m in active])
    assert np.ptp(ipo) == 0.0
    excursion = q - ipo[0]
    # Two periods: the position loop follows with a small lag and gain, never beyond the amplitude.
    assert 0.035 < excursion.max() < 0.045 and -0.045 < excursion.min() < -0.035


@pytest.mark.parametrize("joint, tau, q0, limit", [
    (1, 10.0, 2.6, "range"), (1, -25.0, -2.2, "speed"), (1, 5.0, 2.85, "range"),
    (6, 8.0, 1.75, "range"), (6, -45.0, 0.0, "torque"),  # joint 6: +-120 deg, 40 Nm (iiwa 14 data sheet)
], ids=["range", "speed", "range-slow", "joint6-range", "joint6-torque"])
def test_safety_stop_brakes_the_joint_inside_its_range(tmp_path, joint, tau, q0, limit):
    """A torque client that would drive the joint out of its range (or over its speed or torque) is stopped inside it.

    The limits are the joint's own, from the robot model: joint 6's range and torque are not joint 1's.
    """
    plant = dataclasses.replace(default_plant(), joint=joint)
    lim = plant.limits
    pose = list(DEFAULT_JOINT_POSITIONS)
    pose[joint - 1] = q0
    out = tmp_path / "robot.h5"
    with Client(torque_policy(tau, joint)) as client:
        report = run(client, duration_s=5.0, plant=plant, joint_positions=tuple(pose), record=out, **FAST)
    assert report.end_reason == "safety_stop" and report.session_drops == []
    assert report.safety_stop.startswith(f"joint {joint} ") and limit in report.safety_stop
    assert report.commanding_s < 5.0
    # The client sees the session leave COMMANDING_ACTIVE and the safety state from that message on.
    assert client.states() == FULL_SEQUENCE[1:]
    active = max(i for i, m in enumerate(client.messages) if m.connection_info.session_state == S.COMMANDING_ACTIVE)
    safety = [m.robot_info.safety_state for m in client.messages]
    assert set(safety[:active + 1]) == {SafetyState.NORMAL_OPERATION}
    assert set(safety[active + 1:]) == {SafetyState.SAFETY_STOP_LEVEL_1}
    q = np.array([m.monitor_data.measured_joint_position.value[joint - 1] for m in client.messages])
    tau_j = np.array([m.monitor_data.measured_torque.value[joint - 1] for m in client.messages])
    v = np.diff(q) / 1e-3
    assert np.all(np.abs(q) < lim.position_rad)
    assert np.all(np.abs(tau_j[:active]) <= lim.torque_nm)  # the last active message shows any violation
    assert np.all(np.abs(v[:active - 1]) <= lim.velocity_rad_s)  # the last active message shows the violation
    assert np.all(np.abs(v[-20:]) < 0.1)  # braked (settling at a few hundredths of a rad/s) before the session closed
    # It ends where the interpolator holds it (the end of the braking ramp).
    assert abs(q[-1] - client.messages[-1].ipo_data.joint_position.value[joint - 1]) < 0.01
    ds = read_dataset(out)
    assert ds.experiment_attrs["end_reason"] == "safety_stop" and ds.experiment_attrs["safety_stop"] == report.safety_stop


def test_hand_moves_the_link(tmp_path):
    out = tmp_path / "hand.h5"
    with Client(torque_policy(0.0)) as client:
        report = run(client, duration_s=0.6, agent="hand", hand_peak_speed_rad_s=1.0, record=out, **FAST)
    assert report.session_drops == []
    ds = read_dataset(out)
    k0 = int(ds.experiment_attrs["commanding_start_index"])
    q = ds["q_m"]
    assert np.ptp(q[:k0]) == 0.0  # nobody touches the link before commanding
    assert np.ptp(q[k0:]) > 2e-3
    assert np.abs(ds["tau_ext_ref"][k0:]).max() > 0.5
    # The robot reports its external-torque estimate to the client.
    ext = [m.monitor_data.external_torque.value[0] for m in client.messages
           if m.connection_info.session_state == S.COMMANDING_ACTIVE]
    assert max(abs(e) for e in ext) > 0.2


@pytest.mark.realtime
def _silent_after(n_active: int):
    """Well-behaved until ``n_active`` messages of COMMANDING_ACTIVE, then never another answer."""
    good = torque_policy(0.0)

    def policy(client: Client, msg):
        return SILENT if client.active_seen >= n_active else good(client, msg)

    return policy


@pytest.mark.parametrize("lockstep", [True, pytest.param(False, marks=pytest.mark.realtime)])
def test_a_client_that_has_gone_ends_the_run(lockstep):
    """The client's session ends (it stops answering) long before the duration: the robot drops the session and,
    nothing heard for idle_timeout_s, the run ends (before, it waited for another client until max_wall_s).
    In real time a client the machine stalls for idle_timeout_s before commanding would end the run too: that
    variant runs with the real-time tests."""
    kw = dict(FAST, duration_s=600.0, idle_timeout_s=0.5, max_wall_s=30.0)
    with Client(_silent_after(30)) as client:
        if lockstep:
            report = run(client, **dict(kw, lockstep_guard_s=1.0))
        else:
            emu = RobotEmulator(EmulatorConfig(client=client.address, **{**PATIENT, **kw}))
            report = emu.run()
            client.settle()
    assert report.end_reason == "client_gone", report.end_reason
    assert [r for _, r in report.session_drops] == [f"no answer for {1e3 * (0.005 if lockstep else 0.25):.1f} ms"]
    assert report.state_sequence()[-2:] == [S.MONITORING_WAIT, S.IDLE]
    assert client.states()[-1] == S.IDLE  # told the session ended, had it come back


def test_a_client_that_has_not_come_yet_is_waited_for():
    """The idle timeout counts only after a client was heard: a robot side started first keeps waiting."""
    with Client(lambda client, msg: SILENT) as client:
        report = run(client, **dict(FAST, idle_timeout_s=0.05, max_wall_s=0.5))
    assert report.end_reason == "max_wall"


def test_stop_from_another_thread_in_real_time():
    def policy(client: Client, msg):
        if len(client.messages) == 100:  # never answers; stops the robot from its own thread
            client.emulator.stop()
        return SILENT

    with Client(policy) as client:
        emu = RobotEmulator(EmulatorConfig(client=client.address, **PATIENT))
        client.emulator = emu
        report = emu.run()
        client.settle()
    assert report.end_reason == "stopped" and not report.lockstep
    assert report.state_sequence() == [S.IDLE, S.MONITORING_WAIT, S.IDLE]
    assert client.states()[-1] == S.IDLE  # the client is told the session ended
    assert report.missed_cycles > 20 and report.quality["POOR"] > 20
    json.dumps(report.as_dict())  # plain JSON types
    with pytest.raises(IiwaIdentError, match="runs only once"):
        emu.run()


def test_spawned_emulator():
    """In its own process: the address is known at once, stop() ends the session, join() returns the report."""
    with Client(torque_policy(0.0)) as client:
        with spawn_emulator(EmulatorConfig(client=client.address, lockstep=True, **FAST)) as emu:
            host, port = emu.address
            assert host == "127.0.0.1" and port > 0
            wait_for(lambda: client.active_seen >= 50, what="50 messages in COMMANDING_ACTIVE")
            emu.stop()
            report = emu.join(60.0)
    assert client.active_seen >= 50
    assert report.end_reason == "stopped"
    assert report.state_sequence() == [S.IDLE, S.MONITORING_WAIT, S.MONITORING_READY, S.COMMANDING_WAIT,
                                       S.COMMANDING_ACTIVE, S.IDLE]
    assert report.session_drops == []
    assert report.answers_received > 100


def test_spawned_emulator_reports_a_bind_failure():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        with pytest.raises(IiwaIdentError, match="cannot bind the robot-side socket"):
            spawn_emulator(EmulatorConfig(bind=s.getsockname()))


# --------------------------------------------------------------------------- faults


@pytest.mark.parametrize("kind, faults", [
    ("loss", Faults(loss=0.2, seed=1)),
    ("jitter", Faults(jitter_s=0.0005, seed=1)),
    ("duplicate", Faults(duplicate=0.2, seed=1)),
    ("reorder", Faults(reorder=0.2, seed=1)),
    ("corrupt", Faults(corrupt=0.3, seed=1)),
])
def test_each_fault_is_injected_and_counted(kind, faults):
    # Corrupted answers drop the session, so the run ends after a number of messages, not of commanding time.
    with Client(stop_after(400, torque_policy(0.0))) as client:
        # The loss in both directions is above the default quality's: the robot must not drop the session.
        report = run(client, faults=faults, quality=QualityThresholds(good_loss=0.5, fair_loss=0.9), **FAST)
    counts = report.faults
    assert counts[kind] > 10, counts
    assert all(v == 0 for k, v in counts.items() if k != kind and k.split("_")[0] != kind), counts
    seqs = [m.header.sequence_counter for m in client.messages]
    steps = np.diff(seqs)
    if kind == "loss":
        assert counts["loss_in"] + counts["loss_out"] == counts["loss"]
        assert counts["loss_out"] > 0 and counts["loss_in"] > 0
        assert np.any(steps > 1)  # gaps at the client
        assert report.missed_cycles >= counts["loss"] // 2
    elif kind == "jitter":
        # Delayed, all delivered (two cycles closer together than the jitter may swap).
        assert sorted(seqs) == list(range(report.monitoring_sent))
    elif kind == "duplicate":
        assert np.count_nonzero(steps == 0) == counts["duplicate"]
    elif kind == "reorder":
        assert np.count_nonzero(steps < 0) >= counts["reorder"] - 1
    elif kind == "corrupt":
        assert counts["corrupt_in"] > 0 and counts["corrupt_out"] > 0
        assert client.decode_errors > 0 and report.answers_invalid > 0


# --------------------------------------------------------------------------- settings and helpers


@pytest.mark.parametrize("make, message", [
    (lambda: Faults(loss=1.5), "faults.loss must be a probability"),
    (lambda: Faults(jitter_s=-0.001), "faults.jitter_s"),
    (lambda: check_config(EmulatorConfig(client_command_mode=ClientCommandMode.WRENCH)), "TORQUE or POSITION"),
    (lambda: check_config(EmulatorConfig(control_mode=ControlMode.POSITION)), "JOINT_IMPEDANCE"),
    (lambda: check_config(EmulatorConfig(joint_positions=(0.0,) * 6)), "7 finite angles"),
    (lambda: check_config(EmulatorConfig(joint_positions=(0.0, 3.0, 0, 0, 0, 0, 0))), "joint 2's range"),
    (lambda: check_config(EmulatorConfig(agent="dog")), "agent"),
    (lambda: check_config(EmulatorConfig(send_period_ms=2)), "differs from send_period_ms"),
    (lambda: check_config(EmulatorConfig(timeout_s=0.0)), "timeout_s"),
    (lambda: check_config(EmulatorConfig(client=("127.0.0.1", 0))), "client"),
    (lambda: QualityThresholds(good_loss=2.0), "quality.good_loss"),
    (lambda: check_config(EmulatorConfig(stalls=((1.0, 0.0),))), "a stall's length"),
    (lambda: check_config(EmulatorConfig(stalls=((1.0,),))), "stalls must be .start, length. pairs"),
])
def test_bad_settings_are_refused(make, message):
    with pytest.raises(IiwaIdentError, match=message):
        make()


def test_bind_failure_is_a_user_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        with pytest.raises(IiwaIdentError, match="cannot bind"):
            RobotEmulator(EmulatorConfig(bind=s.getsockname()))


def test_connection_quality_thresholds():
    T = 1e-3
    assert connection_quality(500, 500, 0.1e-3, T) == ConnectionQuality.EXCELLENT
    assert connection_quality(497, 500, 0.2e-3, T) == ConnectionQuality.EXCELLENT
    assert connection_quality(500, 500, 0.5e-3, T) == ConnectionQuality.GOOD
    assert connection_quality(450, 500, 0.2e-3, T) == ConnectionQuality.GOOD  # 10 % round-trip loss
    assert connection_quality(400, 500, 0.2e-3, T) == ConnectionQuality.FAIR
    assert connection_quality(500, 500, 0.9e-3, T) == ConnectionQuality.FAIR
    assert connection_quality(300, 500, 0.2e-3, T) == ConnectionQuality.POOR
    assert connection_quality(500, 500, 1.5e-3, T) == ConnectionQuality.POOR
    assert connection_quality(5, 5, 0.1e-3, T) == ConnectionQuality.POOR  # too few samples
    strict = QualityThresholds(window=100, good_loss=0.02, fair_loss=0.10)
    assert connection_quality(95, 100, 0.2e-3, T, strict) == ConnectionQuality.FAIR


# --------------------------------------------------------------------------- CLI

runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_cli_help_has_examples():
    res = invoke("emulate", "--help")
    assert res.exit_code == 0
    assert "Examples" in res.output and "iiwa-ident emulate --client" in res.output


@pytest.mark.parametrize("args, message", [
    (("--client", "localhost"), "--client 'localhost': expected HOST:PORT"),
    (("--bind", "1.2.3.4:99999"), "--bind '1.2.3.4:99999': expected HOST:PORT"),
    (("--loss", "1.5"), "--loss 1.5: must be a probability in [0, 1]"),
    (("--corrupt", "-0.1"), "--corrupt -0.1: must be a probability"),
    (("--jitter-ms", "-1"), "--jitter-ms -1"),
    (("--mode", "fast"), "--mode 'fast'"),
    (("--agent", "dog"), "--agent 'dog'"),
    (("--duration", "0"), "--duration 0"),
    (("--idle-timeout", "-1"), "--idle-timeout -1: must be a number of seconds >= 0"),
    (("--plant", "missing.toml"), "missing.toml: no such file"),
    (("--stall", "2.0"), "--stall '2.0': expected START:LENGTH"),
    (("--stall", "2.0:-5"), "--stall '2.0:-5': expected START:LENGTH"),
    (("--pose", "0,30,0"), "--pose '0,30,0': expected 7 comma-separated joint angles in degrees"),
    (("--pose", "175,30,0,-90,0,60,0"), "joint_positions[0] = 3.05433 rad is outside joint 1's range"),
])
def test_cli_bad_options_are_one_line_errors(args, message):
    res = invoke("emulate", *args)
    assert res.exit_code == 2
    assert message in res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1


def test_cli_runs_and_writes_report_and_record(tmp_path):
    out, rec = tmp_path / "report.json", tmp_path / "robot.h5"
    res = invoke("emulate", "--client", f"127.0.0.1:{free_port()}", "--max-time", "0.3", "--json", out,
                 "--record", rec, "--seed", "2")
    assert res.exit_code == 0, res.output
    assert "MONITORING_WAIT" in res.output and "session: IDLE -> MONITORING_WAIT -> IDLE" in res.output
    assert "ended: max_wall" in res.output and "missed cycles" in res.output
    doc = json.loads(out.read_text())
    assert doc["end_reason"] == "max_wall" and doc["states"][1]["state"] == "MONITORING_WAIT"
    assert doc["dataset"] == str(rec)
    ds = read_dataset(rec)
    assert ds.experiment_attrs["commanding_start_index"] == -1 and ds.n_samples > 50


def emulate_for(client: Client, *args):
    """``iiwa-ident emulate --lockstep`` serving ``client``; the result once the client has seen it all."""
    res = invoke("emulate", "--client", f"{client.address[0]}:{client.address[1]}", "--lockstep", *args)
    client.settle()
    return res


def test_cli_lockstep_serves_a_client_exactly():
    with Client(torque_policy(2.0)) as client:
        res = emulate_for(client, "--duration", "0.2", "--seed", "3")
    assert res.exit_code == 0, res.output
    assert "lockstep (times are virtual)" in res.output and "ended: duration" in res.output
    assert "session drops: 0" in res.output and "late" in res.output
    assert client.states() == FULL_SEQUENCE[1:]
    assert [m.connection_info.session_state for m in client.messages].count(S.COMMANDING_ACTIVE) == 200


def test_cli_names_a_safety_stop():
    with Client(torque_policy(10.0)) as client:
        res = emulate_for(client, "--duration", "5", "--pose", "150,30,0,-90,0,60,0")
    assert res.exit_code == 0, res.output
    assert "safety stop: joint 1 at " in res.output and "SAFETY STOP at " in res.output
    assert "ended: safety_stop" in res.output


def test_cli_ends_once_its_client_has_gone():
    # The quick start's case: a client whose run is shorter than --duration; the emulator no longer waits
    # in MONITORING_WAIT for ever.
    with Client(_silent_after(50)) as client:
        res = emulate_for(client, "--duration", "20", "--idle-timeout", "0.3", "--max-time", "30")
    assert res.exit_code == 0, res.output
    assert "no answer for 0.3 s: the client has gone, the run ends" in res.output  # after the 1 s guard
    assert "ended: client_gone" in res.output


def test_cli_stall_sends_nothing_and_keeps_the_time():
    # 30 ms from 50 ms of commanding: 30 fewer messages, the counter does not jump, the time stamps do.
    with Client(torque_policy(2.0)) as client:
        res = emulate_for(client, "--duration", "0.2", "--stall", "0.05:30")
    assert res.exit_code == 0, res.output
    assert "robot-side stalls: 30 cycles without a message" in res.output and "session drops: 0" in res.output
    active = [m for m in client.messages if m.connection_info.session_state == S.COMMANDING_ACTIVE]
    assert len(active) == 170
    seq = np.array([m.header.sequence_counter for m in active])
    stamp = np.array([m.monitor_data.timestamp.sec * 10**9 + m.monitor_data.timestamp.nanosec for m in active])
    assert np.all(np.diff(seq) == 1)
    np.testing.assert_array_equal(np.diff(stamp), np.where(np.arange(169) == 49, 31_000_000, 1_000_000))
