"""A plain reference implementation of the joint, integrated with ``scipy.integrate.solve_ivp``.

It writes eqs (1)-(5) once more in NumPy, independently of the casadi model,
for two uses: the tests check that the fast simulator agrees with it, and
the benchmark measures the fast simulator against it as the straightforward
baseline. It covers open-loop torque commands on a plant whose effects are
the transmission ripple and link friction, with the command clear of the standstill threshold
and within the slew-rate limit (those robot-side switches are not modelled).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from iiwa_ident.sim._effects import TransmissionRipple
from iiwa_ident.sim._plant import Plant

__all__ = ["simulate_reference", "SUPPORTED_EFFECTS"]

SUPPORTED_EFFECTS = ("transmission_ripple", "link_friction")


def _ripple(plant: Plant):
    eff = plant.effect("transmission_ripple")
    if not isinstance(eff, TransmissionRipple):
        return lambda th: (0.0, 0.0)
    w = 2 * math.pi / eff.values["period_rad"]
    a, b = eff.cos_coef, eff.sin_coef
    k = np.arange(1, len(a) + 1)

    def f(th: float) -> tuple[float, float]:
        c, s = np.cos(k * w * th), np.sin(k * w * th)
        return float(a @ c + b @ s), float(w * ((k * b) @ c - (k * a) @ s))

    return f


def simulate_reference(plant: Plant, tau_c: np.ndarray, rtol: float = 1e-9, atol: float = 1e-12,
                       method: str = "RK45") -> dict[str, np.ndarray]:
    """Simulate the open-loop torque command ``tau_c`` (one value per cycle).

    Returns the true ``theta_m``, ``theta_l`` [rad] and ``tau_j`` [Nm] at the
    cycle instants ``t = k * cycle_s``, k = 0..len(tau_c), from rest at
    ``theta_m = 0`` with the spring unloaded.
    """
    for e in plant.effects:
        if e.name not in SUPPORTED_EFFECTS:
            raise ValueError(f"the reference model does not cover the effect {e.name!r}")
    d = plant.dynamics
    Jc, bc, K, Jl, Td = d["Jc"], d["bc"], d["K"], d["Jl"], d["Td"]
    T = plant.cycle_s
    h = T / plant.substeps
    delay = round(Td / h) * h  # the fast simulator realises the delay to the nearest substep
    ripple = _ripple(plant)
    fr = plant.effect("link_friction")
    tau_c = np.asarray(tau_c, float)
    n = len(tau_c)

    def command(t: float) -> float:
        k = math.floor((t - delay) / T + 1e-9)
        return float(tau_c[k]) if 0 <= k < n else 0.0

    def rhs(t: float, s: np.ndarray) -> list[float]:
        theta_m, z, theta_l, omega_l = s
        f, df = ripple(theta_m)
        tau_j = K * (theta_m - f - theta_l)
        tau = command(t)
        link = 0.0
        if fr is not None:
            v = fr.values
            link -= v["coulomb_nm"] * math.tanh(omega_l / v["smoothing_rad_s"]) + v["viscous_nms_rad"] * omega_l
        return [((bc / K) * (tau - tau_j) + z) / Jc, tau - tau_j * (1 - df), omega_l, (tau_j + link) / Jl]

    t_eval = np.arange(n + 1) * T
    # The command switches at the cycle edges shifted by the delay: stop there so no step straddles a jump.
    edges = np.unique(np.clip(np.concatenate([t_eval, t_eval + delay]), 0, t_eval[-1]))
    s = np.array([0.0, 0.0, -ripple(0.0)[0], 0.0])  # at rest with an unloaded spring, as the fast simulator
    out = np.empty((n + 1, 4))
    out[0] = s
    for t0, t1 in zip(edges[:-1], edges[1:]):
        sol = solve_ivp(rhs, (t0, t1), s, method=method, rtol=rtol, atol=atol, max_step=h)
        s = sol.y[:, -1]
        k = int(round(t1 / T))
        if abs(t1 - k * T) < 1e-12:
            out[k] = s
    theta_m, theta_l = out[:, 0], out[:, 2]
    f = np.array([ripple(x)[0] for x in theta_m])
    return {"t": t_eval, "theta_m": theta_m, "theta_l": theta_l, "tau_j": K * (theta_m - f - theta_l)}
