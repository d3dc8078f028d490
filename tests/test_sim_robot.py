"""The robot's own behaviour in the simulated joint (section II.A, eq (13), sensors)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import smooth_command
from iiwa_ident.robot import Command
from iiwa_ident.sim import SimulatedJoint, default_plant
from iiwa_ident.sim._agents import ImpedanceAgent


def constant_push(torque: float, seconds: float = 10.0) -> ImpedanceAgent:
    t = np.array([0.0, seconds])
    return ImpedanceAgent(t, [0, 0], [0, 0], 0.0, 0.0, torque=[torque, torque])


class TestFeasibilityFilter:
    def test_slew_rate_limit(self, linear_plant):
        slew = linear_plant.internal["slew_rate_nm_s"]
        h = SimulatedJoint(linear_plant).run_open_loop(np.full(50, 60.0)).hidden
        applied = h["tau_applied"]
        assert np.diff(applied).max() <= slew * linear_plant.cycle_s * (1 + 1e-12)
        assert applied[-1] == pytest.approx(60.0)
        # 20000 Nm/s is 20 Nm a cycle: 20, 40, 60 Nm at the ends of the first three cycles.
        first = np.argmax(applied > 0)
        np.testing.assert_allclose(applied[first:first + 4], [20.0, 40.0, 60.0, 60.0], rtol=1e-12)

    def test_delay_of_td(self, linear_plant):
        h = SimulatedJoint(linear_plant).run_open_loop(np.full(20, 5.0)).hidden
        # The command sent at t = 0 acts from Td = 5 ms: the first measurement showing it is at 6 ms.
        assert np.argmax(h["tau_applied"] != 0) == round(linear_plant.dynamics["Td"] / linear_plant.cycle_s) + 1


class TestStandstillSuppression:
    def test_below_threshold_nothing_moves(self, linear_plant):
        h = SimulatedJoint(linear_plant).run_open_loop(np.full(1000, 0.8)).hidden
        assert h["held"].min() == 1.0
        assert np.ptp(h["theta_m"]) == 0.0

    def test_above_threshold_moves(self, linear_plant):
        h = SimulatedJoint(linear_plant).run_open_loop(np.full(1000, 1.2)).hidden
        assert h["held"][-1] == 0.0
        assert h["theta_l"][-1] > 0.05

    def test_external_push_releases(self, linear_plant):
        joint = SimulatedJoint(linear_plant)
        joint.set_agent(constant_push(3.0))
        h = joint.run_open_loop(np.zeros(1000)).hidden
        assert h["held"][-1] == 0.0 and h["theta_l"][-1] > 0.1

    def test_stops_again_when_still_and_small(self, linear_plant):
        # Moving, then a command of zero: once the joint stands still it stays held.
        tau = np.r_[np.full(300, 3.0), np.full(300, -3.0), np.zeros(2000)]
        plant = linear_plant
        from iiwa_ident.sim import LinkFriction

        plant = plant.with_effects(LinkFriction({"coulomb_nm": 0.5, "viscous_nms_rad": 5.0}))
        h = SimulatedJoint(plant).run_open_loop(tau).hidden
        assert h["held"][400] == 0.0 and h["held"][-1] == 1.0


class TestBuiltinObserver:
    def test_converges_to_external_torque(self, linear_plant):
        joint = SimulatedJoint(linear_plant)
        joint.set_agent(constant_push(4.0))
        m = joint.run_open_loop(np.full(1000, 2.0)).measured
        # First order with K_I = 25 rad/s: after 0.4 s (10 time constants) it has converged.
        np.testing.assert_allclose(m["tau_ext_fri"][400:], 4.0, rtol=0, atol=0.05)
        np.testing.assert_allclose(m["tau_ext_ref"][400:], 4.0, rtol=0, atol=1e-9)

    def test_lags_by_one_over_ki(self, linear_plant):
        joint = SimulatedJoint(linear_plant)
        joint.set_agent(constant_push(4.0))
        m = joint.run_open_loop(np.full(200, 2.0)).measured
        t = m["t"]
        k = np.searchsorted(t, 0.04 + 0.006)  # one time constant after the push starts being seen
        assert 0.5 * 4.0 < m["tau_ext_fri"][k] < 0.75 * 4.0


class TestSensors:
    def test_encoder_quantisation(self):
        plant = default_plant()
        m = SimulatedJoint(plant).run_open_loop(smooth_command(500)).measured
        ticks = m["q_m"] / plant.sensors["encoder_tick_rad"]
        np.testing.assert_allclose(ticks, np.round(ticks), rtol=0, atol=1e-6)

    def test_torque_noise_level(self):
        plant = default_plant()
        tr = SimulatedJoint(plant, seed=5).run_open_loop(smooth_command(20000))
        noise = tr.measured["tau_j"] - tr.hidden["tau_s"]
        np.testing.assert_allclose(noise.std(), plant.sensors["tau_noise_nm"], rtol=0.05)
        assert abs(noise.mean()) < 4 * plant.sensors["tau_noise_nm"] / np.sqrt(len(noise))

    def test_seed_reproducible_and_distinct(self):
        a = SimulatedJoint(seed=1).run_open_loop(smooth_command(100)).measured["tau_j"]
        b = SimulatedJoint(seed=1).run_open_loop(smooth_command(100)).measured["tau_j"]
        c = SimulatedJoint(seed=2).run_open_loop(smooth_command(100)).measured["tau_j"]
        np.testing.assert_array_equal(a, b)
        assert np.abs(a - c).max() > 0

    def test_references_optional(self, linear_plant):
        linear_plant.ft_sensor = False
        linear_plant.link_encoder = False
        joint = SimulatedJoint(linear_plant)
        m0 = joint.start()
        assert m0.tau_ext_ref is None and m0.q_l_ref is None
        m = joint.run_open_loop(np.ones(10)).measured
        assert "tau_ext_ref" not in m and "q_l_ref" not in m


class TestPositionMode:
    def test_tracks_position_command(self, linear_plant):
        joint = SimulatedJoint(linear_plant)
        joint.start()
        for _ in range(3000):
            m = joint.step(Command(q_cmd=0.1))
        assert m.q_m == pytest.approx(0.1, abs=1e-4)
