"""Experiment programs on the simulated joint: what they record, and the safety guard."""

from __future__ import annotations

import math

import numpy as np
import pytest

from iiwa_ident.datasets import read_dataset, write_dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import (
    Chirp,
    ConstantVelocity,
    Experiment,
    HandGuided,
    LimitGuard,
    QuasiStatic,
    SineTorque,
    StepTorque,
    record,
)
from iiwa_ident.references import exponential_sweep
from iiwa_ident.robot import Command, joint_limits
from iiwa_ident.sim import SimulatedJoint, default_plant


class TestExponentialSweep:
    def test_instantaneous_frequency(self):
        f0, f1, T = 1.0, 100.0, 10.0
        t = np.arange(0, T, 1e-4)
        x = exponential_sweep(t, f0, f1, T)
        # Zero crossings: the local period follows f0 * exp(t / L).
        up = np.where((x[:-1] < 0) & (x[1:] >= 0))[0]
        tc = t[up]
        f_local = 1 / np.diff(tc)
        mid = 0.5 * (tc[:-1] + tc[1:])
        expected = f0 * np.exp(mid / (T / np.log(f1 / f0)))
        np.testing.assert_allclose(f_local[5:], expected[5:], rtol=0.03)


class TestChirp:
    def test_records_torque_commanded_dataset(self, tmp_path):
        ds = record(SimulatedJoint(seed=1), Chirp(duration_s=4.0, f1_hz=100.0))
        assert ds.experiment == "chirp" and ds.source == "simulation"
        assert set(ds.signals) >= {"t", "q_m", "tau_j", "tau_c", "tau_ext_fri"}
        assert ds.sample_rate_hz == pytest.approx(1000.0)
        assert ds.experiment_attrs["f1_hz"] == 100.0
        # The bias keeps the command clear of the 1 Nm standstill threshold on average and the hold keeps the link near.
        assert np.abs(ds["q_m"]).max() < 0.5
        path = write_dataset(tmp_path / "c.h5", ds)
        back = read_dataset(path)
        np.testing.assert_array_equal(back["tau_c"], ds["tau_c"])

    def test_refuses_f1_above_nyquist(self):
        with pytest.raises(IiwaIdentError, match="Nyquist"):
            record(SimulatedJoint(), Chirp(f1_hz=600.0, duration_s=1.0))

    def test_refuses_torque_over_limit(self):
        with pytest.raises(IiwaIdentError, match="torque limit"):
            record(SimulatedJoint(), Chirp(amplitude_nm=400.0, duration_s=1.0))


class TestConstantVelocity:
    @pytest.mark.parametrize("mode", ["torque", "position"])
    def test_cruises_at_each_speed_both_directions(self, mode):
        speeds = [0.3, 1.2]
        ds = record(SimulatedJoint(seed=2), ConstantVelocity(speeds, range_rad=0.8, mode=mode))
        v = np.gradient(ds["q_m"], ds["t"])
        for s in speeds:
            for sign in (1, -1):
                near = np.abs(v - sign * s) < 0.1 * s
                assert near.sum() * 1e-3 > 0.3 * 0.8 / s, (s, sign)
        assert ("tau_c" in ds.signals) == (mode == "torque")
        assert ("q_cmd" in ds.signals) == (mode == "position")

    def test_record_at_200hz(self):
        ds = record(SimulatedJoint(), ConstantVelocity([0.6], range_rad=0.4, mode="position"), record_every=5)
        assert ds.sample_rate_hz == pytest.approx(200.0)
        np.testing.assert_allclose(np.diff(ds["t"]), 0.005, rtol=1e-9)

    def test_refuses_too_fast(self):
        with pytest.raises(IiwaIdentError, match="speed limit"):
            record(SimulatedJoint(), ConstantVelocity([1.45]))


class TestQuasiStatic:
    def test_link_reference_and_slow_motion(self):
        ds = record(SimulatedJoint(seed=3), QuasiStatic(torques_nm=[5.0], velocity_rad_s=0.02, range_rad=0.04))
        assert "q_l_ref" in ds.signals
        assert np.ptp(ds["q_l_ref"]) == pytest.approx(0.04, rel=0.02)
        # The commanded load shows in the joint torque.
        mid = len(ds["t"]) // 4
        assert abs(np.median(ds["tau_j"][mid:2 * mid]) - 5.0) < 0.1


class TestHandGuided:
    def test_moves_fast_with_zero_command(self):
        ds = record(SimulatedJoint(seed=4), HandGuided(duration_s=8.0, peak_speed_rad_s=1.0))
        v = np.gradient(ds["q_m"], ds["t"])
        assert np.abs(v).max() > 0.6
        np.testing.assert_array_equal(ds["tau_c"], 0.0)
        assert np.abs(ds["tau_ext_ref"]).max() > 2.0

    def test_kappa_needs_ft_sensor(self):
        plant = default_plant()
        plant.ft_sensor = False
        with pytest.raises(IiwaIdentError, match="F/T"):
            record(SimulatedJoint(plant), HandGuided(duration_s=1.0, kappa=2.0))


class TestTorqueReferences:
    def test_step_and_sine(self):
        step = record(SimulatedJoint(), StepTorque(amplitude_nm=10.0, period_s=1.0, cycles=2))
        assert step.experiment == "step" and np.ptp(step["tau_c"]) > 19.0
        sine = record(SimulatedJoint(), SineTorque(amplitude_nm=15.0, frequency_hz=25.0, duration_s=1.0))
        spec = np.abs(np.fft.rfft(sine["tau_j"][200:]))
        freqs = np.fft.rfftfreq(len(sine["tau_j"][200:]), 1e-3)
        assert abs(freqs[np.argmax(spec[1:]) + 1] - 25.0) < 1.5


class _Push(Experiment):
    """Steady 0.5 rad/s towards and past the position limit."""

    name = "free"
    duration_s = 30.0

    def command(self, s):
        return Command(tau_c=60.0 * (0.5 - s.v))


class TestLimitGuard:
    def test_stops_before_position_limit(self):
        ds = record(SimulatedJoint(), _Push())
        assert "position" in ds.experiment_attrs["stopped_reason"]
        limit = joint_limits("iiwa14", 1).position_rad
        assert np.abs(ds["q_m"]).max() < limit - math.radians(4.0)
        assert ds.duration_s < 30.0

    def test_clamps_torque(self):
        guard = LimitGuard(joint_limits("iiwa14", 6))

        class S:
            q, v, meas = 0.0, 0.0, None

        cmd, reason = guard.filter(Command(tau_c=100.0), S())
        assert cmd.tau_c == 40.0 and reason == ""

    def test_stops_on_speed(self):
        guard = LimitGuard(joint_limits("iiwa14", 1))

        class S:
            q, v, meas = 0.0, 1.5, None

        cmd, reason = guard.filter(Command(tau_c=0.0), S())
        assert "speed" in reason and cmd.tau_c < 0
