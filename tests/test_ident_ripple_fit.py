"""The output-error fit with the transmission ripple of eq (5): its sampled inputs and the fit through them."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from scipy.signal import lsim

from conftest import quiet, smooth_command
from iiwa_ident.datasets import Dataset
from iiwa_ident.excite import Chirp, record
from iiwa_ident.ident._records import prepare_record
from iiwa_ident.ident._tf_fit import RippleTerms, fit_transfer_function
from iiwa_ident.model import PARAMETER_NAMES, RippleTable, discretize, frequency_response
from iiwa_ident.sim import SimulatedJoint, default_plant
from iiwa_ident.sim._effects import TransmissionRipple

TABLE1 = {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}


def _continuous(params: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B_deflection, B_reaction) of eqs (1)-(3) with tau_j = K (theta_m - f - theta_l), written from the
    equations: Jc theta_m' = (bc/K)(tau - tau_j) + z, z' = tau - tau_j (1 - f'), Jl omega_l' = tau_j."""
    Jc, bc, K, Jl = (params[k] for k in ("Jc", "bc", "K", "Jl"))
    A = np.array([[-bc / Jc, 1 / Jc, bc / Jc, 0], [-K, 0, K, 0], [0, 0, 0, 1], [K / Jl, 0, -K / Jl, 0]])
    # d/df of the right-hand side at fixed state: tau_j drops by K f.
    B_f = np.array([bc / Jc, K, 0, -K / Jl])
    B_r = np.array([0, 1.0, 0, 0])  # the reaction tau_j f' adds to z' only
    return A, B_f, B_r


def test_deflection_response_has_no_static_torque_and_the_spring_far_above():
    f = np.array([1e-3, 5.0, 23.0, 400.0])
    A, B_f, _ = _continuous(TABLE1)
    C = np.array([[TABLE1["K"], 0, -TABLE1["K"], 0]])
    G = ct.ss(A, B_f[:, None], C, [[-TABLE1["K"]]])
    np.testing.assert_allclose(frequency_response(TABLE1, f, "deflection"), G(2j * np.pi * f).ravel(),
                               rtol=1e-9, atol=1e-9)
    assert abs(frequency_response(TABLE1, np.array([1e-4]), "deflection")[0]) < 1e-6
    assert frequency_response(TABLE1, np.array([1e4]), "deflection")[0].real == pytest.approx(
        -TABLE1["K"], rel=1e-3)


@pytest.mark.parametrize("kind", ["deflection", "reaction"])
def test_sampled_motion_inputs_match_a_fine_continuous_simulation(kind):
    # A smooth input known only at the samples: a 1 kHz model of it against lsim on a 50 kHz grid.
    T, n, sub = 1e-3, 1500, 50
    t_fine = np.arange(n * sub) * T / sub
    def sig(t):
        return (1e-4 * np.sin(2 * np.pi * 31.0 * t) * np.sin(np.pi * np.minimum(t, 0.5)) ** 2
                + 4e-5 * np.sin(2 * np.pi * 67.0 * t + 0.3) * np.minimum(t / 0.5, 1.0) ** 3)

    scale = 1.0 if kind == "deflection" else 2e3  # a reaction [Nm] of the size tau_j f' reaches
    A, B_f, B_r = _continuous(TABLE1)
    B = B_f if kind == "deflection" else B_r
    K = TABLE1["K"]
    C = np.array([[K, 0, -K, 0], [1, 0, 0, 0]])
    D = np.array([[-K if kind == "deflection" else 0.0], [0.0]])
    _, y, _ = lsim((A, B[:, None], C, D), scale * sig(t_fine), t_fine)
    want = y[::sub].T
    dm = discretize(TABLE1, T, kind)
    assert dm.sampled_motion
    got = dm.simulate(scale * sig(np.arange(n) * T))
    for i in range(2):
        np.testing.assert_allclose(got[i], want[i], rtol=0, atol=5e-3 * np.max(np.abs(want[i])))
    # Held like a command, the same samples lag by half a sample: ten times the error.
    dm.sampled_motion = False
    held = dm.simulate(scale * sig(np.arange(n) * T))
    assert np.max(np.abs(held[0] - want[0])) > 3e-2 * np.max(np.abs(want[0]))


@pytest.mark.parametrize("delay_s", [0.005, 0.0053])
def test_ripple_inputs_reproduce_the_simulated_joint(delay_s):
    # The simulator (casadi, RK4) against the sampled model with the plant's own deflection as known inputs.
    # From the samples alone the ripple's effect on tau_j is reproduced to within 0.2 % of its size (0.09 %
    # measured); through the motion between samples (the command's speed jumps, each sample's mean and slope)
    # to within 0.01 % (0.001 %), a delay on the sample grid (every jump on a sample) as well as between.
    plant = quiet(default_plant())
    plant.internal["standstill_torque_nm"] = 0.0
    plant.dynamics["Td"] = delay_s
    params = dict(TABLE1, Td=delay_s)
    u = smooth_command(3000, amp=6.0, f=4.0)
    meas = SimulatedJoint(plant, seed=0).run_open_loop(u).measured
    tau, q = meas["tau_j"][:-1], meas["q_m"][:-1]
    ripple = next(e for e in plant.effects if isinstance(e, TransmissionRipple))
    lut = ripple.evaluate(np.arange(4096) * ripple.values["period_rad"] / 4096)
    terms = RippleTerms(ripple.values["period_rad"], 0, RippleTable(ripple.values["period_rad"], lut))
    plain = discretize(params, 1e-3).simulate(u)
    effect = tau - plain[0]
    assert np.sqrt(np.mean(effect**2)) > 0.05  # the ripple shows

    D, RX = terms.table_signals(q, tau)
    at_samples = plain + discretize(params, 1e-3, "deflection").simulate(D[:, 0] - D[0, 0]) \
        + discretize(params, 1e-3, "reaction").simulate(RX[:, 0])
    assert np.sqrt(np.mean((tau - at_samples[0]) ** 2)) < 2e-3 * np.sqrt(np.mean(effect**2))

    ds = Dataset(signals={"t": np.arange(len(u)) * 1e-3, "tau_c": u, "tau_j": tau, "q_m": q}, experiment="chirp",
                 source="simulation", joint=1, sample_rate_hz=1000.0)
    rec = prepare_record(ds, 0)
    rec.set_ripple(None, terms.table_signals)
    rec.set_motion(params)
    table = rec.table_inputs()
    between = plain + discretize(params, 1e-3, "deflection").simulate(table.D[:, 0], table.D_means[:, 0],
                                                                      table.D_slopes[:, 0]) \
        + discretize(params, 1e-3, "reaction").simulate(table.RX[:, 0], table.RX_means[:, 0], table.RX_slopes[:, 0])
    assert np.sqrt(np.mean((tau - between[0]) ** 2)) < 1e-4 * np.sqrt(np.mean(effect**2))


@pytest.mark.parametrize("seed", [3, 11])
def test_fit_through_the_ripple_is_unbiased(seed):
    # A random joint with a random three-harmonic ripple; the period as the ripple command gives it.
    rng = np.random.default_rng(seed)
    truth = {k: v * rng.uniform(0.7, 1.3) for k, v in TABLE1.items()}
    period = 2 * math.pi / rng.uniform(200, 400)
    amps = [rng.uniform(3e-5, 8e-5), rng.uniform(0.5e-5, 2e-5), rng.uniform(0.2e-5, 1e-5)]
    plant = default_plant().without_effects()
    plant.dynamics.update(truth)
    plant.effects = [TransmissionRipple(
        {"period_rad": period, "harmonics": [[a, rng.uniform(-math.pi, math.pi)] for a in amps]})]
    ds = record(SimulatedJoint(plant, seed=seed), Chirp(duration_s=12.0, f0_hz=0.5, f1_hz=150.0, amplitude_nm=10.0))
    plain = fit_transfer_function([ds])
    aware = fit_transfer_function([ds], initial=plain.parameters, ripple=RippleTerms(period, 3))
    worst_plain = max(abs(plain.parameters[k] / truth[k] - 1) for k in PARAMETER_NAMES[:4])
    assert worst_plain > 2e-3  # the ripple biases eq (4) alone
    for k in PARAMETER_NAMES[:4]:
        assert aware.parameters[k] == pytest.approx(truth[k], rel=5e-4), k
    # The simulator realises the delay to the nearest substep (0.1 ms).
    realised_td = round(truth["Td"] / 1e-4) * 1e-4
    assert aware.parameters["Td"] == pytest.approx(realised_td, abs=1e-6)
    for k in PARAMETER_NAMES:  # the std covers the remaining error
        value = realised_td if k == "Td" else truth[k]
        assert abs(aware.parameters[k] - value) < 4 * aware.std[k], k
    assert aware.noise[0]["tau_j_nm"] < 1.5 * plant.sensors["tau_noise_nm"]
