"""Seeded scenarios of real-looking joints for the tests and the benchmarks.

A scenario is a random truth (eqs (1)-(4) over the range of iiwa joints,
wrist to base), a random chirp protocol (band, amplitude, bias, length,
robot cycle, held or free link) and random nuisance effects, some with
shapes the identification does not assume (Stribeck friction, a load with
a second harmonic, an offset that drifts). The same seed always gives the
same scenario and the same data, so an estimator is judged on draws it was
not written against, and a failure can be replayed.

Ranges (uniform in the logarithm for ``Jl`` and ``K``):

=============  ===================================================
``Jl``         0.3-20 kg m^2
``K``          3000-40000 Nm/rad
``Jc, bc, Td`` Table I x 0.4-1.6 (``Td`` on the simulator's substep grid)
robot cycle    1, 2 or 5 ms (1000, 500, 200 Hz)
duration       10-60 s
chirp          from ``f0`` 0.5-2 Hz (raised so the link moves at most
               about 0.3 rad) to 2-4 times the resonance (below 0.4 fs)
bias           0 or 1-5 Nm
link           held (weak position hold in the command) or free (only a
               velocity damping in the command, so it cannot drift away)
=============  ===================================================

Nuisances (each switched on with its own probability):

``coulomb``        link Coulomb friction 0-5 Nm
``viscous``        link viscous friction 0-2 Nm s/rad
``gravity``        position-dependent load 0-40 Nm, 90-100 % compensated
``offset``         torque-sensor offset -2..2 Nm
``ripple``         the paper's transmission ripple
``stribeck``       Stribeck breakaway friction (with Coulomb friction)
``load_harmonic``  a second harmonic of the load (with the load)
``offset_drift``   the offset drifts by up to 0.01 Nm/s (with the offset)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from iiwa_ident.datasets import Dataset
from iiwa_ident.excite._runner import record
from iiwa_ident.excite.chirp import Chirp
from iiwa_ident.sim.effects import make_effect
from iiwa_ident.sim.joint import SimulatedJoint
from iiwa_ident.sim.plant import Plant, default_plant, resonance_hz

__all__ = ["NUISANCES", "Scenario", "draw_scenario", "scenario_plant", "simulate_scenario"]

#: Nuisance names, in the order pass rates are printed.
NUISANCES: tuple[str, ...] = ("coulomb", "viscous", "gravity", "offset", "ripple", "stribeck", "load_harmonic",
                              "offset_drift")
_TABLE1 = {"Jc": 1.03, "bc": 55.0, "Td": 0.005}


@dataclass
class Scenario:
    """One draw: truth, protocol and nuisances.

    Attributes
    ----------
    seed : int
        The seed it was drawn from (also seeds the sensor noise).
    truth : dict
        ``Jc`` [kg m^2], ``bc`` [Nm s/rad], ``K`` [Nm/rad], ``Jl`` [kg m^2], ``Td`` [s].
    protocol : dict
        ``rate_hz``, ``duration_s``, ``f0_hz``, ``f1_hz``, ``amplitude_nm``,
        ``bias_nm``, ``held`` (bool), ``q0_rad``.
    effects : dict
        Plant-file tables of the switched-on effects, by effect name.
    nuisances : list of str
        The names from :data:`NUISANCES` that are on.
    """

    seed: int
    truth: dict[str, float]
    protocol: dict[str, Any]
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    nuisances: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """One line for logs and failure messages."""
        t, p = self.truth, self.protocol
        return (f"seed {self.seed}: Jc={t['Jc']:.3g} bc={t['bc']:.3g} K={t['K']:.4g} Jl={t['Jl']:.3g} "
                f"Td={t['Td'] * 1e3:.2f} ms; {p['rate_hz']:g} Hz {p['duration_s']:g} s "
                f"{p['f0_hz']:.2g}-{p['f1_hz']:.3g} Hz {p['amplitude_nm']:.3g} Nm bias {p['bias_nm']:.2g} Nm "
                f"{'held' if p['held'] else 'free'}; nuisances: {', '.join(self.nuisances) or 'none'}")


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw_scenario(seed: int, *, nuisances: Sequence[str] | None = None, duration_s: float | None = None,
                  rate_hz: float | None = None) -> Scenario:
    """Draw the scenario of ``seed``.

    Parameters
    ----------
    seed : int
        Seed; the same seed gives the same scenario.
    nuisances : sequence of str, optional
        Switch on exactly these (names from :data:`NUISANCES`); default a
        random selection (each about one draw in three).
    duration_s, rate_hz : float, optional
        Fix the chirp's length [s] or the robot's rate [Hz] instead of drawing them.
    """
    rng = np.random.default_rng(seed)
    truth = {
        "Jc": _TABLE1["Jc"] * rng.uniform(0.4, 1.6),
        "bc": _TABLE1["bc"] * rng.uniform(0.4, 1.6),
        "K": _log_uniform(rng, 3000.0, 40000.0),
        "Jl": _log_uniform(rng, 0.3, 20.0),
        "Td": _TABLE1["Td"] * rng.uniform(0.4, 1.6),
    }
    rate = float(rate_hz if rate_hz is not None else rng.choice([200.0, 500.0, 1000.0]))
    # The simulator realises the delay to its substep (a tenth of a cycle): draw it on that grid,
    # so that the truth is the delay the data have.
    step = 0.1 / rate
    truth["Td"] = round(truth["Td"] / step) * step
    duration = float(duration_s if duration_s is not None else rng.uniform(10.0, 60.0))
    if nuisances is None:
        on = [n for n in NUISANCES[:5] if rng.uniform() < 0.35]
        for extra, base in (("stribeck", "coulomb"), ("load_harmonic", "gravity"), ("offset_drift", "offset")):
            if base in on and rng.uniform() < 0.4:
                on.append(extra)
    else:
        unknown = set(nuisances) - set(NUISANCES)
        if unknown:
            raise ValueError(f"unknown nuisances {sorted(unknown)} (known: {', '.join(NUISANCES)})")
        on = list(nuisances)
    effects: dict[str, dict[str, Any]] = {}
    friction = 0.0
    if {"coulomb", "viscous", "stribeck"} & set(on):
        fr = {"coulomb_nm": 0.0, "viscous_nms_rad": 0.0}
        if "coulomb" in on or "stribeck" in on:
            fr["coulomb_nm"] = rng.uniform(0.1, 5.0)
        if "viscous" in on:
            fr["viscous_nms_rad"] = rng.uniform(0.05, 2.0)
        if "stribeck" in on:
            fr["stribeck_nm"] = rng.uniform(0.2, 0.5) * fr["coulomb_nm"]
            fr["stribeck_velocity_rad_s"] = rng.uniform(0.01, 0.1)
        effects["link_friction"] = fr
        friction = fr["coulomb_nm"] + fr.get("stribeck_nm", 0.0)
    if "gravity" in on or "load_harmonic" in on:
        ld = {"amplitude_nm": rng.uniform(2.0, 40.0) * rng.choice([-1.0, 1.0]),
              "phase_rad": rng.uniform(-math.pi, math.pi),
              "compensated": rng.uniform(0.9, 1.0)}
        if "load_harmonic" in on:
            ld["harmonic2_nm"] = rng.uniform(0.05, 0.2) * abs(ld["amplitude_nm"])
            ld["harmonic2_phase_rad"] = rng.uniform(-math.pi, math.pi)
        effects["position_dependent_load"] = ld
    if "offset" in on or "offset_drift" in on:
        off = {"offset_nm": rng.uniform(-2.0, 2.0)}
        if "offset_drift" in on:
            off["drift_nm_s"] = rng.uniform(-0.01, 0.01)
        effects["torque_sensor_offset"] = off
    if "ripple" in on:
        effects["transmission_ripple"] = dict(default_plant().effect("transmission_ripple").to_dict())

    # Protocol: a chirp that moves the link well beyond friction and stays within about 0.3 rad.
    fs = rate
    f_res = resonance_hz(truth["Jc"], truth["K"], truth["Jl"])
    amplitude = max(rng.uniform(3.0, 15.0), 3.0 * friction + 1.0)
    f0 = max(rng.uniform(0.5, 2.0), math.sqrt(amplitude / (0.3 * truth["Jl"])) / (2 * math.pi))
    f1 = min(rng.uniform(2.0, 4.0) * f_res, 0.4 * fs)
    if f1 < 2.0 * f0:
        f1 = min(0.45 * fs, 2.0 * f0)
    # A free link under a load or a sensor offset (a constant torque to the robot) would run away.
    held = bool(rng.uniform() < 0.5) or bool({"gravity", "load_harmonic", "offset", "offset_drift"} & set(on))
    bias = 0.0 if rng.uniform() < 0.3 else rng.uniform(1.0, 5.0)
    if not held:
        bias = 0.0  # a free link under a bias would run into its limits
    protocol = {"rate_hz": rate, "duration_s": duration, "f0_hz": f0, "f1_hz": f1, "amplitude_nm": amplitude,
                "bias_nm": bias, "held": held, "q0_rad": rng.uniform(-1.0, 1.0)}
    return Scenario(seed=seed, truth=truth, protocol=protocol, effects=effects, nuisances=on)


def scenario_plant(sc: Scenario) -> Plant:
    """The plant of a scenario: default robot behaviour, the drawn truth, cycle and effects."""
    base = default_plant().without_effects()
    plant = base.with_effects(*(make_effect(name, table) for name, table in sc.effects.items()))
    plant.dynamics.update(sc.truth)
    plant.simulation["cycle_s"] = 1.0 / sc.protocol["rate_hz"]
    return plant


def simulate_scenario(sc: Scenario) -> Dataset:
    """Record the scenario's chirp on its simulated joint (the dataset carries ``/truth``)."""
    p = sc.protocol
    chirp = Chirp(f0_hz=p["f0_hz"], f1_hz=p["f1_hz"], duration_s=p["duration_s"], amplitude_nm=p["amplitude_nm"],
                  bias_nm=p["bias_nm"], hold_stiffness=30.0 if p["held"] else 0.0,
                  hold_damping=10.0 if p["held"] else 5.0)
    joint = SimulatedJoint(scenario_plant(sc), seed=sc.seed, q0=p["q0_rad"])
    return record(joint, chirp)
