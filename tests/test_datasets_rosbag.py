"""ROS 2 bags of lbr_fri_ros2_stack, written by rosbags' writer in both storages, read back exactly."""

from __future__ import annotations

import os

import numpy as np
import pytest

from iiwa_ident.datasets import import_rosbag, note_warnings, ros_typestore
from iiwa_ident.errors import DatasetError

pytest.importorskip("rosbags")

STORAGES = ("sqlite3", "mcap")


def _writer(path, storage: str):
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Writer(path, version=9, storage_plugin=plugin)


def _draw(rng, n: int, rate_hz: float) -> dict[str, np.ndarray]:
    t = np.arange(n) / rate_hz
    out = {"ns": 1_764_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)}  # stamps as ROS keeps them
    out["position"] = 0.4 * np.sin(2 * np.pi * 0.3 * t)[:, None] + rng.normal(0, 0.3, 7)
    for name in ("commanded_position", "torque", "commanded_torque", "external_torque", "velocity"):
        out[name] = rng.normal(0, 4, (n, 7))
    return out


def _write_lbr_state(path, storage: str, truth: dict, states: np.ndarray, mode: int = 3,
                     msgtype: str = "lbr_fri_idl/msg/LBRState", topic: str = "/lbr/state") -> None:
    store = ros_typestore()
    State = store.types[msgtype]
    with _writer(path, storage) as writer:
        conn = writer.add_connection(topic, msgtype, typestore=store)
        for k, ns in enumerate(truth["ns"]):
            sec, nsec = divmod(int(ns), 1_000_000_000)
            msg = State(sample_time=0.001, session_state=int(states[k]), connection_quality=3, safety_state=0,
                        operation_mode=2, drive_state=1, client_command_mode=mode, overlay_type=1, control_mode=1,
                        time_stamp_sec=sec, time_stamp_nano_sec=nsec,
                        measured_joint_position=truth["position"][k], commanded_joint_position=truth["commanded_position"][k],
                        measured_torque=truth["torque"][k], commanded_torque=truth["commanded_torque"][k],
                        external_torque=truth["external_torque"][k], ipo_joint_position=truth["commanded_position"][k],
                        tracking_performance=1.0)
            writer.write(conn, int(ns) + 150_000, store.serialize_cdr(msg, msgtype))  # received 0.15 ms later


def _write_joint_state(path, storage: str, truth: dict, stamped: bool = True) -> None:
    store = ros_typestore()
    JointState = store.types["sensor_msgs/msg/JointState"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    with _writer(path, storage) as writer:
        conn = writer.add_connection("/lbr/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        for k, ns in enumerate(truth["ns"]):
            sec, nsec = divmod(int(ns), 1_000_000_000) if stamped else (0, 0)
            msg = JointState(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=""),
                             name=[f"lbr_A{i + 1}" for i in range(7)], position=truth["position"][k],
                             velocity=truth["velocity"][k], effort=truth["torque"][k])
            writer.write(conn, int(ns), store.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


@pytest.mark.parametrize("storage", STORAGES)
class TestBags:
    def test_lbr_state_comes_back_exactly(self, tmp_path, storage):
        rng = np.random.default_rng(len(storage))
        joint = int(rng.integers(1, 8))
        truth = _draw(rng, 300, 500.0)
        bag = tmp_path / "bag"
        _write_lbr_state(bag, storage, truth, np.full(300, 4))
        ds = import_rosbag(bag, joint=joint, experiment="free")
        j = joint - 1
        assert ds.sample_rate_hz == pytest.approx(500.0, rel=1e-6)
        np.testing.assert_array_equal(ds["q_m"], truth["position"][:, j])
        np.testing.assert_array_equal(ds["tau_j"], truth["torque"][:, j])
        np.testing.assert_array_equal(ds["tau_c"], truth["commanded_torque"][:, j])
        np.testing.assert_array_equal(ds["q_cmd"], truth["commanded_position"][:, j])
        np.testing.assert_array_equal(ds["tau_ext_fri"], truth["external_torque"][:, j])
        np.testing.assert_allclose(ds.t, (truth["ns"] - truth["ns"][0]) * 1e-9, rtol=0, atol=1e-12)  # robot's stamps
        np.testing.assert_allclose(ds.experiment_attrs["pose_rad"], np.median(truth["position"], axis=0))

    def test_joint_state_comes_back_exactly(self, tmp_path, storage):
        truth = _draw(np.random.default_rng(7), 250, 200.0)
        bag = tmp_path / "bag"
        _write_joint_state(bag, storage, truth)
        ds = import_rosbag(bag, joint=4, experiment="free")
        np.testing.assert_array_equal(ds["q_m"], truth["position"][:, 3])
        np.testing.assert_array_equal(ds["tau_j"], truth["torque"][:, 3])
        np.testing.assert_array_equal(ds["dq_m"], truth["velocity"][:, 3])
        assert not ds.has("tau_c")


class TestSessions:
    def test_runs_split_where_the_session_leaves_commanding_active(self, tmp_path):
        truth = _draw(np.random.default_rng(3), 400, 200.0)
        states = np.full(400, 2)
        states[50:180] = 4
        states[250:390] = 4
        bag = tmp_path / "bag"
        _write_lbr_state(bag, "mcap", truth, states, mode=1)  # position mode: no torque command
        runs = import_rosbag(bag, joint=2, experiment="free", split_runs=True)
        assert [r.n_samples for r in runs] == [130, 140]
        np.testing.assert_array_equal(runs[1]["q_m"], truth["position"][250:390, 1])
        assert runs[1].t[0] == 0.0 and not runs[0].has("tau_c")

    def test_older_message_name_and_receive_time(self, tmp_path):
        truth = _draw(np.random.default_rng(4), 200, 100.0)
        bag = tmp_path / "bag"
        _write_joint_state(bag, "sqlite3", truth, stamped=False)  # no stamps: the bag's receive time
        ds = import_rosbag(bag, joint=1, experiment="free")
        np.testing.assert_allclose(ds.t, (truth["ns"] - truth["ns"][0]) * 1e-9, rtol=0, atol=1e-12)
        assert any("below the robot's 1 kHz cycle" in w for w in note_warnings(ds))
        old = tmp_path / "old"
        _write_lbr_state(old, "sqlite3", truth, np.full(200, 4), msgtype="lbr_fri_msgs/msg/LBRState")
        assert import_rosbag(old, joint=1, experiment="free").n_samples == 200


@pytest.mark.parametrize("damage", ["truncated", "garbage", "no_state_topic", "missing", "topic"])
def test_bad_bag_is_refused_in_one_line(tmp_path, damage):
    truth = _draw(np.random.default_rng(1), 200, 200.0)
    bag = tmp_path / "bag"
    topic = None
    if damage == "missing":
        expect = "file not found"
    else:
        _write_lbr_state(bag, "mcap", truth, np.full(200, 4), topic="/lbr/state")
        expect = "not a readable ROS 2 bag"
        if damage == "topic":
            topic, expect = "/other", "no topic '/other' in the bag (topics: /lbr/state (lbr_fri_idl/msg/LBRState))"
        elif damage == "no_state_topic":
            store = ros_typestore()
            other = tmp_path / "other"
            with _writer(other, "sqlite3") as writer:
                conn = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
                writer.write(conn, 1, store.serialize_cdr(store.types["std_msgs/msg/String"](data="hi"),
                                                          "std_msgs/msg/String"))
            bag, expect = other, "no LBRState or JointState topic in the bag (topics: /chatter (std_msgs/msg/String))"
        else:
            data_file = next(p for p in bag.iterdir() if p.suffix == ".mcap")
            raw = data_file.read_bytes()
            data_file.write_bytes(raw[: len(raw) // 2] if damage == "truncated" else os.urandom(len(raw)))
    with pytest.raises(DatasetError) as excinfo:
        import_rosbag(bag, joint=1, experiment="free", topic=topic)
    text = str(excinfo.value)
    assert "\n" not in text and str(bag) in text and expect in text, text


def _simulated_run(rate_hz: float):
    """A constant-velocity run of the simulated joint 1 (ripple on) as a stack would publish it at ``rate_hz``."""
    from iiwa_ident.emulator import DEFAULT_JOINT_POSITIONS
    from iiwa_ident.excite import ConstantVelocity, record
    from iiwa_ident.sim import SimulatedJoint, default_plant

    ds = record(SimulatedJoint(default_plant(), seed=3), ConstantVelocity([0.3, 0.6], range_rad=1.0, mode="position"))
    step = int(round(ds.sample_rate_hz / rate_hz))
    n = len(ds.t[::step])
    position = np.tile(np.asarray(DEFAULT_JOINT_POSITIONS, float), (n, 1))
    position[:, 0] = ds["q_m"][::step]
    torque = np.zeros((n, 7))
    torque[:, 0] = ds["tau_j"][::step]
    return {"ns": 1_764_000_000_000_000_000 + np.round(ds.t[::step] * 1e9).astype(np.int64), "position": position,
            "commanded_position": position.copy(), "torque": torque, "commanded_torque": np.zeros((n, 7)),
            "external_torque": np.zeros((n, 7)), "velocity": np.zeros((n, 7))}


@pytest.mark.parametrize("kind", ["lbr_state", "joint_state"])
def test_a_bag_imports_into_a_dataset_that_ripple_and_diagnose_accept(tmp_path, kind):
    from conftest import import_then_ripple_and_diagnose

    truth = _simulated_run(200.0)
    truth["commanded_position"][:, 0] += 1e-4  # the stack's command is not the measurement
    bag = tmp_path / "bag"
    if kind == "lbr_state":
        _write_lbr_state(bag, "mcap", truth, np.full(len(truth["ns"]), 4), mode=1)
    else:
        _write_joint_state(bag, "sqlite3", truth)
    import_then_ripple_and_diagnose(tmp_path, "--rosbag", str(bag), "--joint", "1")


def test_what_a_stack_log_cannot_give_is_said(tmp_path):
    # Open-loop mode: the stack publishes the commanded positions as the measured ones; 100 Hz publishing.
    truth = _simulated_run(100.0)
    truth["commanded_position"] = truth["position"].copy()
    bag = tmp_path / "bag"
    _write_lbr_state(bag, "sqlite3", truth, np.full(len(truth["ns"]), 4), mode=1)
    warnings = note_warnings(import_rosbag(bag, joint=1, experiment="constant_velocity"))
    assert any("q_m equals q_cmd" in w for w in warnings), warnings
    low = next(w for w in warnings if "below the robot's 1 kHz cycle" in w)
    assert "100 Hz" in low and "fit needs the command of every robot cycle" in low and "cannot be told" in low
