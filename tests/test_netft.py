"""ATI Net F/T over RDT: the datagrams against the published layout, the projection against MuJoCo's
Jacobian, and a sensor read over loopback (lost, stale, foreign, bad status, silence)."""

from __future__ import annotations

import math
import select
import socket
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.netft import (
    Calibration,
    EmulatedNetFt,
    JointAxisProjection,
    NetFtSensor,
    NetFtSettings,
    RdtCommand,
    RdtError,
    RdtRecord,
    RdtServer,
    decode_record,
    decode_request,
    encode_record,
    encode_request,
)

U32 = st.integers(0, 2**32 - 1)
I32 = st.integers(-(2**31), 2**31 - 1)


class TestDatagrams:
    def test_request_layout(self):
        # uint16 0x1234, uint16 command, uint32 sample count, network byte order.
        assert encode_request(RdtCommand.START_REALTIME, 0) == bytes.fromhex("1234 0002 00000000")
        assert encode_request(RdtCommand.SET_SOFTWARE_BIAS) == bytes.fromhex("1234 0042 00000000")
        assert encode_request(RdtCommand.START_BUFFERED, 1000) == bytes.fromhex("1234 0003 000003e8")
        assert decode_request(bytes.fromhex("1234 0000 00000005")) == (0, 5)

    def test_record_layout(self):
        data = bytes.fromhex("00000007 0000002a 00000000 000f4240 fff0bdc0 00000000 00000001 ffffffff 7fffffff")
        rec = decode_record(data)
        assert (rec.rdt_sequence, rec.ft_sequence, rec.status) == (7, 42, 0)
        assert rec.counts == (1_000_000, -1_000_000, 0, 1, -1, 2**31 - 1)
        assert encode_record(rec) == data

    @pytest.mark.parametrize("data, what", [(b"\x12\x34\x00\x02\x00\x00\x00", "7 bytes"),
                                            (bytes.fromhex("4321 0002 00000000"), "header 0x4321")])
    def test_bad_requests(self, data, what):
        with pytest.raises(RdtError, match=what):
            decode_request(data)

    def test_bad_record_length(self):
        with pytest.raises(RdtError, match="35 bytes"):
            decode_record(bytes(35))

    @settings(max_examples=200, deadline=None)
    @given(U32, U32, U32, st.tuples(I32, I32, I32, I32, I32, I32))
    def test_records_round_trip(self, rdt, ft, status, counts):
        rec = RdtRecord(rdt, ft, status, counts)
        assert decode_record(encode_record(rec)) == rec
        assert struct.unpack("!III6i", encode_record(rec)) == (rdt, ft, status, *counts)


class TestCalibration:
    def test_counts_per_unit(self):
        cal = Calibration(counts_per_force=1000.0, counts_per_torque=50_000.0)
        w = cal.wrench((2500, -1000, 0, 50_000, 0, -25_000))
        np.testing.assert_allclose(w, [2.5, -1.0, 0.0, 1.0, 0.0, -0.5], rtol=0, atol=1e-12)
        assert cal.counts(w) == (2500, -1000, 0, 50_000, 0, -25_000)

    def test_saturates_at_int32(self):
        assert Calibration(1e6, 1e6).counts([1e5, -1e5, 0, 0, 0, 0])[:2] == (2**31 - 1, -(2**31))

    @pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
    def test_refused(self, bad):
        with pytest.raises(IiwaIdentError, match="counts_per_force must be a positive number"):
            Calibration(counts_per_force=bad)


class TestProjection:
    @pytest.mark.parametrize("robot", ["iiwa14", "iiwa7"])
    @pytest.mark.parametrize("joint", range(1, 8))
    def test_agrees_with_the_jacobian(self, robot, joint):
        """axis . (lever x F + M) is the joint's entry of J^T [F; M] (MuJoCo's site Jacobian)."""
        import mujoco

        from iiwa_ident.description import check_pose
        rng = np.random.default_rng(joint)
        q = rng.uniform(-1.5, 1.5, 7)
        proj = JointAxisProjection.from_description(robot, joint, q)
        wrench = rng.normal(size=6) * [20, 20, 20, 2, 2, 2]
        # An independent path: the world-frame Jacobian of the flange site.
        xml_model = mujoco.MjModel.from_xml_string(_description_xml(robot))
        data = mujoco.MjData(xml_model)
        data.qpos[:] = check_pose(q)
        mujoco.mj_forward(xml_model, data)
        jacp, jacr = np.zeros((3, 7)), np.zeros((3, 7))
        mujoco.mj_jacSite(xml_model, data, jacp, jacr, 0)
        R = data.site_xmat[0].reshape(3, 3)  # flange -> world
        f_w, m_w = R @ wrench[:3], R @ wrench[3:]
        expected = jacp[:, joint - 1] @ f_w + jacr[:, joint - 1] @ m_w
        assert proj.torque(wrench) == pytest.approx(expected, rel=1e-9, abs=1e-9)

    @settings(max_examples=50, deadline=None)
    @given(st.integers(1, 7), st.floats(-50, 50), st.lists(st.floats(-1.5, 1.5), min_size=7, max_size=7))
    def test_wrench_loads_the_joint_with_its_torque(self, joint, tau, q):
        proj = JointAxisProjection.from_description("iiwa14", joint, q)
        assert proj.torque(proj.wrench(tau)) == pytest.approx(tau, abs=1e-9)

    def test_lever_arm(self):
        p = JointAxisProjection.from_lever_arm(0.25)
        assert p.torque([0, 4.0, 0, 0, 0, 0]) == pytest.approx(1.0)
        assert p.torque([4.0, 0, 0, 0, 0, 0]) == 0.0
        with pytest.raises(IiwaIdentError, match="lever arm"):
            JointAxisProjection.from_lever_arm(-0.1)


def _description_xml(robot):
    # The description writes its model once; the test reads the same MJCF through MuJoCo's own Jacobian.
    from iiwa_ident.description import _dynamics  # the test's independent path needs the model text
    return _dynamics._mjcf(robot)


@pytest.fixture
def server():
    srv = RdtServer(("127.0.0.1", 0))
    yield srv
    srv.close()


def _sensor(server, **kw):
    s = NetFtSensor("127.0.0.1", JointAxisProjection.from_lever_arm(0.5), port=server.address[1], **kw)
    s.start()
    return s


#: Waits for a datagram end once it is there; the time-out only ends a test whose datagram never comes.
_WAIT_S = 30.0


def _settle(server):
    """Take the sensor's requests once they have arrived (bias, then the stream)."""
    while server.client is None:
        assert select.select([server._sock], [], [], _WAIT_S)[0], "no request reached the server"
        server.poll_requests()


def _wait_poll(sensor):
    """One cycle's poll once a record is there."""
    assert select.select([sensor._sock], [], [], _WAIT_S)[0], "no record reached the sensor"
    return sensor.poll()


class TestSensorOverLoopback:
    def test_torque_from_the_stream_with_bias(self, server):
        ft = EmulatedNetFt(server, JointAxisProjection.from_lever_arm(0.5), NetFtSettings(cutoff_hz=None))
        sensor = _sensor(server)
        _settle(server)
        server.bias_requested = True  # the request may have been taken by _settle: bias at 1.5 Nm
        ft.cycle(1.5)
        assert _wait_poll(sensor) == pytest.approx(0.0, abs=1e-6)
        ft.cycle(4.0)
        assert _wait_poll(sensor) == pytest.approx(2.5, abs=1e-6)
        assert sensor.stats.lost == 0 and sensor.stats.received == 2
        sensor.stop()

    def test_rate_and_filter(self, server):
        """At 7 kHz seven records per 1 ms cycle; a first-order filter of the stated cut-off."""
        s = NetFtSettings(rate_hz=7000.0, cutoff_hz=100.0)
        ft = EmulatedNetFt(server, JointAxisProjection.from_lever_arm(0.5), s)
        sensor = _sensor(server, bias=False)
        _settle(server)
        ft.cycle(0.0)
        _wait_poll(sensor)
        ft.cycle(10.0)
        got = _wait_poll(sensor)
        assert sensor.stats.received == 14
        a = np.exp(-2 * np.pi * 100.0 / 7000.0)
        assert got == pytest.approx(10.0 * (1 - a ** 7), abs=1e-5)

    def test_lost_stale_foreign_and_bad_status(self, server):
        sensor = _sensor(server, fault_cycles=3)
        _settle(server)
        cal = Calibration()
        send = lambda rec: server._sock.sendto(encode_record(rec), server.client)  # noqa: E731  (a one-line helper)
        counts = cal.counts([0, 2.0, 0, 0, 0, 0])
        send(RdtRecord(10, 1, 0, counts))
        assert _wait_poll(sensor) == pytest.approx(1.0)
        send(RdtRecord(13, 2, 0, counts))  # 11 and 12 lost
        send(RdtRecord(13, 2, 0, counts))  # duplicate
        send(RdtRecord(12, 2, 0, counts))  # reordered
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(encode_record(RdtRecord(14, 3, 0, counts)), server.client)
        while not sensor.stats.foreign:
            _wait_poll(sensor)
        assert (sensor.stats.lost, sensor.stats.stale, sensor.stats.foreign) == (2, 2, 1)
        # A faulted sensor: records keep coming, their status word says the data are bad.
        for k in range(3):
            send(RdtRecord(20 + k, 10 + k, 0x80020000, counts))
            assert _wait_poll(sensor) is None
        assert sensor.stats.bad_status == 3
        assert sensor.fault == "F/T sensor: status 0x80020000 for 3 cycles"

    def test_a_sensor_that_stops_answering(self, server):
        ft = EmulatedNetFt(server, JointAxisProjection.from_lever_arm(0.5))
        sensor = _sensor(server, fault_cycles=5, bias=False)
        _settle(server)
        ft.cycle(1.0)
        assert _wait_poll(sensor) is not None
        for _ in range(4):
            assert sensor.poll() is None
            assert sensor.fault == ""
        assert sensor.poll() is None
        assert sensor.fault == "F/T sensor: no record for 5 cycles"
        assert sensor.tau != 0.0  # the last good value is held, the loop ramps down on the fault

    def test_stop_ends_the_stream(self, server):
        ft = EmulatedNetFt(server, JointAxisProjection.from_lever_arm(0.5))
        sensor = _sensor(server)
        _settle(server)
        sensor.stop()
        assert select.select([server._sock], [], [], _WAIT_S)[0]
        ft.cycle(1.0)
        assert server.remaining == 0


def test_the_emulated_sensors_own_noise(server):
    """Per channel, seeded: about the axis 0.5 m x Fy + Mz has the std the channels' stds give."""
    ft = EmulatedNetFt(server, JointAxisProjection.from_lever_arm(0.5),
                       NetFtSettings(cutoff_hz=None, force_noise_n=0.5, torque_noise_nm=0.05, seed=3))
    sensor = _sensor(server, bias=False)
    _settle(server)
    got = []
    for _ in range(2000):
        ft.cycle(0.0)
        got.append(_wait_poll(sensor))
    assert sensor.stats.lost == 0
    assert np.std(got) == pytest.approx(math.hypot(0.5 * 0.5, 0.05), rel=0.1)
    with pytest.raises(IiwaIdentError, match="force_noise_n must be a std"):
        NetFtSettings(force_noise_n=-1.0)


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 7), st.lists(st.floats(-1.5, 1.5), min_size=7, max_size=7),
       st.tuples(I32, I32, I32, I32, I32, I32), st.floats(1e3, 1e7), st.floats(1e3, 1e7))
def test_the_loops_weights_are_the_projection_of_the_calibrated_wrench(joint, q, counts, cpf, cpt):
    proj = JointAxisProjection.from_description("iiwa14", joint, q)
    cal = Calibration(cpf, cpt)
    w = proj.coefficients((cpf,) * 3 + (cpt,) * 3)
    want = proj.torque(cal.wrench(counts))
    assert sum(a * b for a, b in zip(w, counts)) == pytest.approx(want, rel=1e-9, abs=1e-9 * (1 + abs(want)))
