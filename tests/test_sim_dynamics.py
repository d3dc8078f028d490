"""The simulated joint's dynamics against eq (4) and against an independent solve_ivp model."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest

from conftest import smooth_command
from iiwa_ident.robot import Command
from iiwa_ident.sim import LinkFriction, SimulatedJoint, default_plant
from iiwa_ident.sim._reference import simulate_reference


def eq4(plant, s):
    """Eq (4): tau_j / tau_c with the delay."""
    d = plant.dynamics
    Jc, bc, K, Jl, Td = d["Jc"], d["bc"], d["K"], d["Jl"], d["Td"]
    return np.exp(-Td * s) * Jl * (bc * s + K) / (Jc * Jl * s**2 + Jl * bc * s + (Jc * K + Jl * K))


def steady_sine_response(plant, f_hz, bias=30.0, amp=1.0, seconds=3.0):
    """Complex gain from commanded to measured torque at f_hz, from the last whole periods."""
    T = plant.cycle_s
    n = int(seconds / T)
    t = np.arange(n) * T
    u = bias + amp * np.sin(2 * np.pi * f_hz * t)
    u[:5] = bias  # start clear of the standstill threshold
    meas = SimulatedJoint(plant).run_open_loop(u).measured
    y = meas["tau_j"][:-1]  # the measurement at t_k pairs with the command sent at t_k
    periods = int(np.floor(1.0 * f_hz))  # last ~1 s of whole periods
    m = max(int(round(periods / f_hz / T)), int(round(1 / f_hz / T)))
    seg = slice(n - m, n)
    e = np.exp(-2j * np.pi * f_hz * t[seg])
    return np.sum((y[seg] - y[seg].mean()) * e) / np.sum((u[seg] - u[seg].mean()) * e)


class TestFrequencyResponse:
    """With the nonlinearity off, commanded -> measured torque follows eq (4)."""

    FREQS = [1.0, 5.0, 15.0, 23.0, 40.0, 100.0, 200.0, 350.0]

    @pytest.mark.parametrize("f_hz", FREQS)
    def test_matches_zoh_discretised_eq4(self, linear_plant, f_hz):
        # The sampled joint sees the command through a zero-order hold: compare with the
        # exact ZOH discretisation of eq (4) (its delay is 5 whole cycles).
        d = linear_plant.dynamics
        T = linear_plant.cycle_s
        G = ct.tf([d["Jl"] * d["bc"], d["Jl"] * d["K"]], [d["Jc"] * d["Jl"], d["Jl"] * d["bc"], (d["Jc"] + d["Jl"]) * d["K"]])
        Gd = ct.c2d(G, T, "zoh")
        z = np.exp(2j * np.pi * f_hz * T)
        expected = Gd(z) * z ** -round(d["Td"] / T)
        H = steady_sine_response(linear_plant, f_hz)
        np.testing.assert_allclose(abs(H), abs(expected), rtol=2e-3)
        assert abs(np.angle(H / expected, deg=True)) < 0.2

    @pytest.mark.parametrize("f_hz", [1.0, 5.0, 15.0, 23.0, 40.0])
    def test_matches_continuous_eq4_below_50hz(self, linear_plant, f_hz):
        # Eq (4) itself, with the half-cycle lag and sinc gain of the hold.
        T = linear_plant.cycle_s
        w = 2 * np.pi * f_hz
        expected = eq4(linear_plant, 1j * w) * np.exp(-1j * w * T / 2) * np.sinc(f_hz * T)
        H = steady_sine_response(linear_plant, f_hz)
        np.testing.assert_allclose(abs(H), abs(expected), rtol=1e-2)
        assert abs(np.angle(H / expected, deg=True)) < 1.0

    def test_resonance_of_table1(self, linear_plant):
        # Table I puts the built-in closed-loop poles near -27.5 +- 143i (section V.A): the gain peaks near 23 Hz.
        gains = {f: abs(steady_sine_response(linear_plant, f)) for f in (15.0, 23.0, 35.0)}
        assert gains[23.0] > gains[15.0] and gains[23.0] > gains[35.0]
        assert gains[23.0] > 2.0


class TestAgainstReferenceModel:
    """The compiled simulator against the plain NumPy model integrated by solve_ivp."""

    @pytest.mark.parametrize("with_friction", [False, True])
    def test_ripple_on_agrees(self, ripple_plant, with_friction):
        plant = ripple_plant.with_effects(LinkFriction({"coulomb_nm": 1.0})) if with_friction else ripple_plant
        tau = smooth_command(800)
        ref = simulate_reference(plant, tau)
        hid = SimulatedJoint(plant).run_open_loop(tau).hidden
        assert np.ptp(ref["tau_j"]) > 5.0
        np.testing.assert_allclose(hid["theta_m"], ref["theta_m"], rtol=0, atol=1e-7)
        np.testing.assert_allclose(hid["tau_j"], ref["tau_j"], rtol=0, atol=2e-4)

    def test_ten_substeps_at_least(self):
        from iiwa_ident.errors import PlantError
        from iiwa_ident.sim import plant_from_dict

        with pytest.raises(PlantError, match="simulation.substeps"):
            plant_from_dict({"simulation": {"substeps": 5}})


class TestStepAndBatchAgree:
    """start() + step() per cycle gives the same signals as run_open_loop()."""

    @pytest.mark.parametrize("log_filter", [None, {"cutoff_hz": 12.0, "order": 2.0}, {"order": 0.0, "delay_s": 0.0123}])
    def test_identical_with_noise(self, log_filter):
        from iiwa_ident.sim import make_effect

        plant = default_plant()
        if log_filter is not None:  # a filter between the sensor and the log, after the robot's observer
            plant = plant.with_effects(make_effect("torque_log_filter", log_filter))
        tau = smooth_command(400)
        batch = SimulatedJoint(plant, seed=3).run_open_loop(tau).measured
        joint = SimulatedJoint(plant, seed=3)
        m0 = joint.start()
        rows = [m0] + [joint.step(Command(tau_c=float(x))) for x in tau]
        for name in ("q_m", "tau_j", "tau_ext_fri", "q_l_ref", "tau_ext_ref"):
            stepped = np.array([getattr(m, name) for m in rows])
            np.testing.assert_allclose(stepped, batch[name], rtol=0, atol=1e-9, err_msg=name)

    def test_vm_fallback_matches_compiled(self, ripple_plant):
        tau = smooth_command(200)
        a = SimulatedJoint(ripple_plant, compile=True).run_open_loop(tau).hidden
        b = SimulatedJoint(ripple_plant, compile=False).run_open_loop(tau).hidden
        np.testing.assert_allclose(a["tau_j"], b["tau_j"], rtol=0, atol=1e-9)
