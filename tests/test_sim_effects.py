"""Each plant effect changes what it should and nothing else; the ripple is consistent with eq (5)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import smooth_command
from iiwa_ident.sim import (
    InputDelay,
    LinkFriction,
    PeriodicDisturbance,
    PositionDependentLoad,
    SimulatedJoint,
    TorqueSensorOffset,
    TorqueSensorScale,
    TransmissionRipple,
)
from iiwa_ident.sim._agents import ImpedanceAgent


def cruise(plant, speed=0.6, seconds=2.0, stiffness=20000.0):
    """Drive the link at constant speed with a stiff external agent, zero-ish command (torque mode)."""
    joint = SimulatedJoint(plant)
    t = np.arange(0, seconds + 1, 1e-3)
    ramp = np.minimum(t / 0.2, 1.0)
    pos = np.cumsum(speed * ramp) * 1e-3
    joint.set_agent(ImpedanceAgent(t, pos, speed * ramp, stiffness, 2000.0))
    n = int(seconds / 1e-3)
    return joint.run_open_loop(np.full(n, 2.0))


class TestTransmissionRipple:
    def test_deflection_is_f_of_motor_position(self, ripple_plant):
        # theta_m - theta_j = f(theta_m mod rho) with theta_j = theta_l + tau_j / K, eq (5) and (3).
        tr = cruise(ripple_plant)
        h = tr.hidden
        K = ripple_plant.dynamics["K"]
        deflection = h["theta_m"] - (h["theta_l"] + h["tau_j"] / K)
        f = ripple_plant.effect("transmission_ripple").evaluate(h["theta_m"])
        np.testing.assert_allclose(deflection, f, rtol=0, atol=1e-12)
        assert np.ptp(f) > 1e-4

    def test_same_through_measured_channels(self, ripple_plant):
        tr = cruise(ripple_plant)
        m = tr.measured
        K = ripple_plant.dynamics["K"]
        f = ripple_plant.effect("transmission_ripple").evaluate(m["q_m"])
        np.testing.assert_allclose(m["q_m"] - (m["q_l_ref"] + m["tau_j"] / K), f, rtol=0, atol=1e-12)

    def test_torque_ripple_at_velocity_over_period(self, ripple_plant, linear_plant):
        # Eq (6): the ripple appears at f = v / rho; without the effect there is nothing there.
        speed, rho = 0.6, ripple_plant.effect("transmission_ripple").values["period_rad"]
        f_ripple = speed / rho

        def peak(plant):
            tau = cruise(plant, speed=speed).hidden["tau_j"][600:]
            spec = np.abs(np.fft.rfft(tau - tau.mean())) / len(tau)
            freqs = np.fft.rfftfreq(len(tau), 1e-3)
            band = np.abs(freqs - f_ripple) < 1.0
            return freqs[band][np.argmax(spec[band])], spec[band].max()

        f_peak, amp = peak(ripple_plant)
        assert abs(f_peak - f_ripple) < 0.8
        assert amp > 0.05
        assert peak(linear_plant)[1] < 1e-3

    def test_reaction_follows_from_model(self, ripple_plant):
        # The ripple torque is a deterministic function of position: two passes over the
        # same positions give the same torque pattern (it is not injected noise).
        a = cruise(ripple_plant, seconds=1.5).hidden
        ripple_plant.sensors["tau_noise_nm"] = 0.5
        b = cruise(ripple_plant, seconds=1.5).hidden
        np.testing.assert_allclose(a["tau_j"], b["tau_j"], rtol=0, atol=1e-12)

    def test_lut_equals_harmonics(self, ripple_plant):
        eff = ripple_plant.effect("transmission_ripple")
        rho = eff.values["period_rad"]
        table = eff.evaluate(np.arange(64) * rho / 64).tolist()
        lut = TransmissionRipple({"period_rad": rho, "lut": table})
        x = np.linspace(0, 3 * rho, 777)
        np.testing.assert_allclose(lut.evaluate(x), eff.evaluate(x), rtol=0, atol=1e-15)
        tau = smooth_command(300)
        a = SimulatedJoint(ripple_plant).run_open_loop(tau).hidden["tau_j"]
        b = SimulatedJoint(ripple_plant.with_effects(lut)).run_open_loop(tau).hidden["tau_j"]
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


class TestLinkFriction:
    def test_terminal_velocity_and_sensor_untouched(self, linear_plant):
        # 3 Nm against 1 Nm Coulomb + 4 Nm s/rad viscous settles at (3 - 1) / 4 = 0.5 rad/s.
        plant = linear_plant.with_effects(LinkFriction({"coulomb_nm": 1.0, "viscous_nms_rad": 4.0}))
        h = SimulatedJoint(plant).run_open_loop(np.full(10000, 3.0)).hidden
        np.testing.assert_allclose(h["omega_l"][-1], 0.5, rtol=5e-3)
        np.testing.assert_array_equal(h["tau_s"], h["tau_j"])
        free = SimulatedJoint(linear_plant).run_open_loop(np.full(10000, 3.0)).hidden
        assert free["omega_l"][-1] > 4.0


class TestPositionDependentLoad:
    @pytest.mark.parametrize("compensated", [1.0, 0.0])
    def test_gravity_like_load(self, linear_plant, compensated):
        A, q0 = 20.0, 0.5
        plant = linear_plant.with_effects(PositionDependentLoad({"amplitude_nm": A, "compensated": compensated}))
        joint = SimulatedJoint(plant, q0=q0)
        tr = joint.run_open_loop(np.full(1500, 2.0))
        h, m = tr.hidden, tr.measured
        free = SimulatedJoint(linear_plant, q0=q0).run_open_loop(np.full(1500, 2.0)).hidden
        # The torque sensor always sees the load (gravity shows in tau_j at rest)...
        np.testing.assert_allclose(h["tau_j"][0], -A * np.sin(h["theta_l"][0]), rtol=1e-9)
        if compensated:
            # ...the robot's model cancels it in the motion and in its observer.
            np.testing.assert_allclose(h["theta_l"], free["theta_l"], rtol=0, atol=2e-3)
            assert np.abs(m["tau_ext_fri"][500:]).max() < 0.5
        else:
            # ...an unknown payload drives the link and shows as an external torque.
            assert abs(h["theta_l"][-1] - free["theta_l"][-1]) > 0.05
            # The observer of eq (13) is a first-order lag K_I / (s + K_I) on the true disturbance.
            from scipy.signal import lfilter

            KI, T = plant.internal["KI"], plant.cycle_s
            load = A * np.sin(h["theta_l"])
            lagged = lfilter([KI * T], [1.0, KI * T - 1.0], load)
            err = m["tau_ext_fri"][300:] - lagged[300:]
            assert np.sqrt(np.mean(err ** 2)) < 0.05 * np.ptp(load)


class TestTorqueSensorOffset:
    def test_reading_offset_and_loop_regulates_reading(self, linear_plant):
        c = 1.5
        plant = linear_plant.with_effects(TorqueSensorOffset({"offset_nm": c}))
        tau = smooth_command(2000)
        h = SimulatedJoint(plant).run_open_loop(tau).hidden
        np.testing.assert_allclose(h["tau_s"] - h["tau_j"], c, rtol=0, atol=1e-12)
        # The internal loop regulates the reading, so the mechanics see the command less the offset.
        shifted = SimulatedJoint(linear_plant).run_open_loop(tau - c).hidden
        np.testing.assert_allclose(h["tau_j"][1000:], shifted["tau_j"][1000:], rtol=0, atol=1e-6)


class TestTorqueSensorScale:
    def test_reading_is_scaled(self, linear_plant):
        plant = linear_plant.with_effects(TorqueSensorScale({"scale": 1.05}))
        h = SimulatedJoint(plant).run_open_loop(smooth_command(500)).hidden
        np.testing.assert_allclose(h["tau_s"], 1.05 * h["tau_j"], rtol=1e-12, atol=1e-12)


class TestPeriodicDisturbance:
    def test_hum_on_reading_only(self, linear_plant):
        plant = linear_plant.with_effects(PeriodicDisturbance({"amplitude_nm": 0.3, "frequency_hz": 50.0, "phase_rad": 0.4}))
        tr = SimulatedJoint(plant).run_open_loop(smooth_command(500))
        h, t = tr.hidden, tr.measured["t"]
        np.testing.assert_allclose(h["tau_s"] - h["tau_j"], 0.3 * np.sin(2 * np.pi * 50 * t + 0.4), rtol=0, atol=1e-12)


class TestInputDelay:
    def test_shifts_response_and_nothing_else(self, linear_plant):
        tau = smooth_command(600)
        base = SimulatedJoint(linear_plant).run_open_loop(tau).hidden["tau_j"]
        late = SimulatedJoint(linear_plant.with_effects(InputDelay({"extra_s": 0.002}))).run_open_loop(tau).hidden["tau_j"]
        np.testing.assert_allclose(late[2:], base[:-2], rtol=0, atol=1e-12)
        assert np.abs(late[7:] - base[7:]).max() > 1e-3


class TestTorqueLogFilter:
    def test_only_the_logged_torque_is_filtered(self):
        # The loop, the robot's observer and the hidden torque are the same with and without it; the logged
        # torque is the unfiltered one through one first-order stage at the cut-off (checked against the
        # continuous filter's ramp response at the samples, exact for an input linear between them).
        from iiwa_ident.sim import TorqueLogFilter, default_plant, make_effect

        plant = default_plant()
        fc = float(np.random.default_rng(5).uniform(5.0, 50.0))
        tau = smooth_command(3000)
        plain = SimulatedJoint(plant, seed=2).run_open_loop(tau)
        logged = SimulatedJoint(plant.with_effects(make_effect("torque_log_filter", {"cutoff_hz": fc})),
                                seed=2).run_open_loop(tau)
        for name in ("tau_j", "theta_l"):
            np.testing.assert_array_equal(logged.hidden[name], plain.hidden[name])
        np.testing.assert_array_equal(logged.measured["tau_ext_fri"], plain.measured["tau_ext_fri"])
        np.testing.assert_allclose(logged.measured["tau_j"], TorqueLogFilter({"cutoff_hz": fc}).apply(
            plain.measured["tau_j"], 1e-3), rtol=0, atol=1e-9)
        # A ramp from rest: the continuous response t - tau (1 - exp(-t / tau)), at any sample period.
        tau = 1 / (2 * np.pi * fc)
        for dt in (1e-3, 5e-3):
            t = np.arange(400) * dt
            got = TorqueLogFilter({"cutoff_hz": fc}).apply(np.r_[0.0, t[1:]], dt)
            np.testing.assert_allclose(got, t - tau * (1 - np.exp(-t / tau)), rtol=0, atol=1e-12)

    def test_columns_and_response(self):
        # A matrix's columns are each filtered as a vector would be; the response is the sampled filter's
        # steady-state gain and phase for a sine (measured after the transient has died out).
        from iiwa_ident.sim import TorqueLogFilter

        rng = np.random.default_rng(11)
        lf = TorqueLogFilter({"cutoff_hz": float(rng.uniform(5.0, 50.0)), "order": 2.0})
        X = rng.normal(size=(300, 3))
        np.testing.assert_allclose(lf.apply(X, 1e-3), np.column_stack([lf.apply(x, 1e-3) for x in X.T]),
                                   rtol=0, atol=1e-12)
        dt, f = 5e-3, float(rng.uniform(2.0, 60.0))
        t = np.arange(20000) * dt
        y = lf.apply(np.exp(2j * np.pi * f * t).real, dt)
        h = lf.frequency_response(np.array([f]), dt)[0]
        np.testing.assert_allclose(y[-2000:], (h * np.exp(2j * np.pi * f * t[-2000:])).real, rtol=0, atol=1e-9)

    def test_second_order_is_the_continuous_filter_at_the_samples(self):
        # w^2 / (s^2 + 2 zeta w s + w^2) for a random damping (two equal stages at 1, Butterworth at 0.71): the
        # continuous response to an input linear between samples, at any rate; one sample at a time the same.
        from scipy import signal

        from iiwa_ident.errors import PlantError
        from iiwa_ident.sim import TorqueLogFilter

        rng = np.random.default_rng(12)
        for zeta in (1.0, float(rng.uniform(0.3, 1.0))):
            fc = float(rng.uniform(0.5, 20.0))
            lf = TorqueLogFilter({"cutoff_hz": fc, "order": 2.0, "damping": zeta})
            for dt in (1e-3, 5e-3):
                x = rng.normal(size=600).cumsum()
                w, t = 2 * np.pi * fc, np.arange(600) * dt
                _, want, _ = signal.lsim(signal.lti([w * w], [1, 2 * zeta * w, w * w]), x - x[0], t, interp=True)
                got = lf.apply(x, dt)
                np.testing.assert_allclose(got, want + x[0], rtol=0, atol=1e-9 * np.abs(x).max())
                state, one = None, []
                for v in x:
                    state, y = lf.step(state, float(v), dt)
                    one.append(y)
                np.testing.assert_allclose(one, got, rtol=0, atol=1e-9 * np.abs(x).max())
        with pytest.raises(PlantError, match="damping"):
            TorqueLogFilter({"cutoff_hz": 5.0, "order": 1.0, "damping": 0.7})

    def test_a_pure_delay_is_the_input_shifted(self):
        # Order 0: the logged torque is the torque delay_s earlier, linear between samples (a shift by whole
        # samples at a multiple of the sample period), at rest on the first sample; one sample at a time the
        # same; its response exp(-2 pi j f d) where the input is slow against the samples; it keeps only the
        # keys of its order.
        from iiwa_ident.errors import PlantError
        from iiwa_ident.sim import TorqueLogFilter

        rng = np.random.default_rng(13)
        x = rng.normal(size=800).cumsum()
        for dt in (1e-3, 5e-3):
            t = np.arange(len(x)) * dt
            d = float(rng.uniform(0.0, 150.0)) * dt
            lf = TorqueLogFilter({"order": 0.0, "delay_s": d})
            got = lf.apply(x, dt)
            np.testing.assert_allclose(got, np.interp(t - d, t, x), rtol=0, atol=1e-9 * np.abs(x).max())
            state, one = None, []
            for v in x:
                state, y = lf.step(state, float(v), dt)
                one.append(y)
            np.testing.assert_allclose(one, got, rtol=0, atol=1e-9 * np.abs(x).max())
            whole = TorqueLogFilter({"order": 0.0, "delay_s": 7 * dt}).apply(x, dt)
            np.testing.assert_array_equal(whole[7:], x[:-7])
            f = np.array([0.01, 0.05]) / dt
            np.testing.assert_allclose(lf.frequency_response(f, dt), np.exp(-2j * np.pi * f * d), rtol=0, atol=0.02)
            assert lf.lag_s == d and lf.reported(np.ones(1)) == {"order": 0.0, "delay_s": d}
        for bad, word in (({"order": 0.0}, "delay_s"), ({"order": 0.0, "delay_s": 0.1, "cutoff_hz": 3.0}, "cut-off"),
                          ({"order": 1.0, "delay_s": 0.1}, "delay_s"), ({"order": 0.0, "delay_s": 0.1, "damping": 0.7},
                                                                        "damping")):
            with pytest.raises(PlantError, match=word):
                TorqueLogFilter(bad)
