"""One effect library: each effect's regressors reproduce its simulator hooks, and round-trip its values."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from iiwa_ident.sim import EFFECTS, INJECTIONS, EffectSignals, make_effect


def _draw(name: str, rng: np.random.Generator) -> dict:
    """Random values in the shape the regressors describe (no Stribeck term, drift or higher harmonics)."""
    u = rng.uniform
    if name == "transmission_ripple":
        return {"period_rad": u(0.01, 0.05), "harmonics": [[u(1e-5, 1e-4), u(-3, 3)] for _ in range(3)]}
    if name == "link_friction":
        return {"coulomb_nm": u(0.1, 5), "viscous_nms_rad": u(0.1, 3), "smoothing_rad_s": u(0.002, 0.02)}
    if name == "position_dependent_load":
        return {"amplitude_nm": u(1, 30), "phase_rad": u(-3, 3), "compensated": u(0, 1)}
    if name == "link_spring":
        return {"stiffness_nm_rad": u(0.5, 10), "rest_rad": u(-1, 1), "curvature_nm_rad2": u(-2, 2)}
    if name == "torque_sensor_offset":
        return {"offset_nm": u(-2, 2)}
    if name == "torque_sensor_scale":
        return {"scale": u(0.9, 1.1)}
    if name == "periodic_disturbance":
        return {"amplitude_nm": u(0.1, 1), "frequency_hz": u(5, 90), "phase_rad": u(-3, 3)}
    return {}


def _hooks(effect, t, q_m, theta_l, omega_l, tau) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """What the simulator's hooks give at each point, evaluated numerically; and the torque reading."""
    P, i, vector = {}, 0, effect.vector()
    for name, size in effect.layout():
        v = vector[i:i + size]
        P[name] = float(v[0]) if size == 1 else [float(x) for x in v]
        i += size
    num = lambda x: np.array(ca.DM(x)).ravel() if x is not None else np.zeros_like(t)  # noqa: E731  (a one-line helper)
    d = effect.deflection(ca.DM(q_m), P)
    out = {"deflection": num(d[0] if d is not None else None),
           "reaction": num(d[1]) * tau if d is not None else np.zeros_like(t),
           "link": num(effect.link_torque(ca.DM(theta_l), ca.DM(omega_l), P)),
           "command": -num(effect.robot_model_torque(ca.DM(q_m), P))}
    reading = num(effect.sensor(ca.DM(tau), ca.DM(t), P))
    out["sensor"] = reading - tau  # additive and relative errors together
    return out, reading


# A delay and the log's filter are dynamics, not a hook at a point (the filter: tests/test_sim_effects.py).
@pytest.mark.parametrize("name", [n for n in EFFECTS if n not in ("input_delay", "torque_log_filter")])
def test_columns_times_coefficients_are_the_hooks(name):
    rng = np.random.default_rng(sorted(EFFECTS).index(name))  # str hashes change from run to run
    effect = make_effect(name, _draw(name, rng))
    n = 2000
    t = np.arange(n) * 1e-3
    q_m = np.cumsum(rng.normal(0, 2e-3, n))
    theta_l = q_m + rng.normal(0, 1e-3, n)
    omega_l = rng.normal(0, 0.3, n)
    tau = rng.normal(0, 10, n)
    hooks, reading = _hooks(effect, t, q_m, theta_l, omega_l, tau)
    cols = effect.columns(EffectSignals(t=t, q_m=q_m, theta_l=theta_l, omega_l=omega_l, tau_j=reading))
    coef = effect.coefficients()
    assert len(cols) == len(coef) > 0
    got = {p: np.zeros(n) for p in INJECTIONS}
    for c, column in zip(coef, cols):
        for point, x in column:
            got[point] += c * x
    got["sensor"] += got.pop("reading_scale")
    for point in hooks:
        scale = max(np.max(np.abs(hooks[point])), 1e-12)
        np.testing.assert_allclose(got[point], hooks[point], rtol=0, atol=1e-9 * scale, err_msg=point)


@pytest.mark.parametrize("name", [n for n in EFFECTS if n != "input_delay"])
def test_values_round_trip_through_coefficients(name):
    rng = np.random.default_rng(7)
    values = _draw(name, rng)
    effect = make_effect(name, values)
    back = make_effect(name, effect.values_from(effect.coefficients()))
    np.testing.assert_allclose(back.coefficients(), effect.coefficients(), rtol=1e-12, atol=1e-15)
    for key, v in effect.reported(effect.coefficients()).items():
        if key in values:
            assert v == pytest.approx(values[key], rel=1e-9), key


def test_ripple_reports_half_the_peak_to_peak():
    e = make_effect("transmission_ripple", {"period_rad": 0.02, "harmonics": [[4e-5, 0.3], [1e-5, 1.0]]})
    x = np.linspace(0, 0.02, 20001)
    want = np.ptp(e.evaluate(x)) / 2
    assert e.reported(e.coefficients())["amplitude_rad"] == pytest.approx(want, rel=1e-4)


def test_clip_brings_fits_into_the_ranges():
    e = make_effect("link_friction", {})
    assert e.clip({"coulomb_nm": -0.3, "viscous_nms_rad": 900.0}) == {"coulomb_nm": 0.0, "viscous_nms_rad": 500.0}
    assert math.isclose(make_effect("torque_sensor_scale", {}).values_from(np.array([0.5]))["scale"], 2.0)
