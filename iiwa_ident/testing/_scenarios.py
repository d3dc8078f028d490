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
``hum``            a time-periodic disturbance of the torque reading, 0.05-0.5 Nm at 5-150 Hz, half
                   of them with 2nd and 3rd harmonics (drawn from a stream of its own, so that the
                   other draws of a seed are those without it)

Hidden-effect scenarios (:func:`draw_hidden_effects`, for judging a
diagnosis): 0-2 of the plant effects of :data:`HIDDEN_RANGES` on a Table I
joint, or (``shapes=True``) on a joint within 30 % of Table I with larger
loads and frictions and half of the effects in another shape
(:data:`HIDDEN_OTHER_SHAPES`), recorded on a chirp, constant-velocity runs
and a hand-guided run (:func:`simulate_hidden_effects`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import lfilter

from iiwa_ident.datasets import Dataset
from iiwa_ident.excite import Chirp, ConstantVelocity, HandGuided, Multisine, record
from iiwa_ident.model import resonance_hz
from iiwa_ident.sim import Plant, SimulatedJoint, default_plant, make_effect

__all__ = ["NUISANCES", "RIPPLE_NUISANCES", "Scenario", "RippleScenario", "draw_scenario", "scenario_plant",
           "simulate_scenario", "simulate_scenario_multisine", "draw_ripple_scenario", "simulate_ripple_scenario",
           "HIDDEN_RANGES", "HIDDEN_LARGE_RANGES", "HIDDEN_OTHER_SHAPES", "HiddenEffectScenario",
           "draw_hidden_effects", "hidden_effect_plant", "simulate_hidden_effects"]

#: Nuisance names, in the order pass rates are printed.
NUISANCES: tuple[str, ...] = ("coulomb", "viscous", "gravity", "offset", "ripple", "stribeck", "load_harmonic",
                              "offset_drift", "hum")
#: Table I's eq (4) parameters (the default plant's).
_TABLE1 = dict(default_plant().dynamics)


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


def _checked(nuisances: Sequence[str], known: Sequence[str]) -> list[str]:
    """The chosen nuisances, all of them known."""
    unknown = set(nuisances) - set(known)
    if unknown:
        raise ValueError(f"unknown nuisances {sorted(unknown)} (known: {', '.join(known)})")
    return list(nuisances)


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
        if np.random.default_rng([seed, 1]).uniform() < 0.25:
            on.append("hum")
    else:
        on = _checked(nuisances, NUISANCES)
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
        ripple = default_plant().effect("transmission_ripple")
        assert ripple is not None  # the default plant has the paper's ripple
        effects["transmission_ripple"] = dict(ripple.to_dict())
    if "hum" in on:
        effects["periodic_disturbance"] = _hum(np.random.default_rng([seed, 2]), rate)

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


def _hum(rng: np.random.Generator, rate_hz: float) -> dict[str, float]:
    """A hum's parameters (see the ``hum`` nuisance); its fundamental below 0.4 of the rate."""
    hum = {"amplitude_nm": rng.uniform(0.05, 0.5), "frequency_hz": rng.uniform(5.0, min(150.0, 0.4 * rate_hz)),
           "phase_rad": rng.uniform(-math.pi, math.pi)}
    if rng.uniform() < 0.5:
        for k in (2, 3):
            hum[f"harmonic{k}_nm"] = rng.uniform(0.2, 0.5) * hum["amplitude_nm"]
            hum[f"harmonic{k}_phase_rad"] = rng.uniform(-math.pi, math.pi)
    return hum


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


def simulate_scenario_multisine(sc: Scenario, period_s: float = 2.0, periods: int = 2,
                                realisations: int = 4) -> Dataset:
    """The scenario's joint excited by random-phase odd multisines instead of its chirp.

    Same plant, band (the chirp's ``f0``-``f1``), peak amplitude, bias and hold as the chirp; the dataset
    carries ``/truth``.
    """
    p = sc.protocol
    ms = Multisine(f_lo_hz=p["f0_hz"], f_hi_hz=p["f1_hz"], period_s=period_s, periods=periods,
                   realisations=realisations, amplitude_nm=p["amplitude_nm"], bias_nm=p["bias_nm"],
                   hold_stiffness=30.0 if p["held"] else 0.0, hold_damping=10.0 if p["held"] else 5.0, seed=sc.seed)
    joint = SimulatedJoint(scenario_plant(sc), seed=sc.seed, q0=p["q0_rad"])
    return record(joint, ms)


# --------------------------------------------------------------------------- ripple scenarios

#: Nuisances of the ripple scenarios, in the order pass rates are printed.
RIPPLE_NUISANCES: tuple[str, ...] = ("friction", "gravity", "hum", "coloured_noise", "gaps")


@dataclass(kw_only=True)
class RippleScenario:
    """One draw for the ripple identification: a joint's runs at constant speeds, with or without a ripple.

    Attributes
    ----------
    seed : int
        The seed it was drawn from.
    ripple : dict or None
        The ``transmission_ripple`` table (``period_rad``, ``harmonics``), None for a null draw.
    runs : list of dict
        Per run: ``speed_rad_s``, ``range_rad``, ``mode`` ("torque" or "position").
    rate_hz : float
        The robot's rate (the log's rate).
    effects : dict
        Plant-file tables of the simulator's nuisance effects, by effect name.
    after : dict
        What is done to the recorded logs: ``hum_harmonics`` [(Nm, Hz), ...] added to tau_j,
        ``coloured_noise`` (std [Nm], pole of the AR(1) filter), ``gaps`` (count and length [s]).
    nuisances : list of str
        The names from :data:`RIPPLE_NUISANCES` that are on.
    """

    seed: int
    ripple: dict[str, Any] | None
    runs: list[dict[str, Any]]
    rate_hz: float
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    after: dict[str, Any] = field(default_factory=dict)
    nuisances: list[str] = field(default_factory=list)

    @property
    def cycles_per_rev(self) -> float | None:
        """The true ripple's cycles per revolution (None for a null draw)."""
        return None if self.ripple is None else 2 * math.pi / self.ripple["period_rad"]

    def describe(self) -> str:
        """One line for logs and failure messages."""
        what = "no ripple" if self.ripple is None else (
            f"{self.cycles_per_rev:.1f} cycles/rev, amplitudes "
            + "/".join(f"{a * 1e6:.1f}" for a, _ in self.ripple["harmonics"]) + " urad")
        speeds = ", ".join(f"{r['speed_rad_s']:.3g}" for r in self.runs)
        return (f"seed {self.seed}: {what}; {self.rate_hz:g} Hz, runs at {speeds} rad/s; nuisances: "
                f"{', '.join(self.nuisances) or 'none'}")


def draw_ripple_scenario(seed: int, *, null: bool = False, nuisances: Sequence[str] | None = None) -> RippleScenario:
    """Draw the ripple scenario of ``seed``.

    A ripple of 100-800 cycles per revolution with three harmonics, the second 0.3-4 and the third
    0-2 times the fundamental (amplitude 3-30 urad, log-uniform); two or three runs at speeds
    0.05-1.3 rad/s (log-uniform; the simulated joint's limit is 1.48 rad/s) over 0.4-1.2 rad, in torque
    or position mode, at 200, 500 or 1000 Hz. Nuisances, each on with probability one half: link
    Coulomb and viscous friction (0.2-3 Nm, 0-1 Nm s/rad), a position-dependent load (2-30 Nm, 90-100 %
    compensated), time-periodic hum on the torque sensor (a line of 5-80 Hz and its 2nd and 3rd
    harmonics, 0.005-0.05 Nm each), coloured sensor noise (AR(1), pole 0.9-0.99, 0.005-0.03 Nm), and
    gaps (1-6 dropped stretches of 10-40 ms per run). ``null`` draws everything but the ripple.
    """
    rng = np.random.default_rng(seed)
    ripple = None
    cpr = rng.uniform(100.0, 800.0)
    a1 = _log_uniform(rng, 3e-6, 3e-5)
    harmonics = [[a1, rng.uniform(-math.pi, math.pi)], [a1 * rng.uniform(0.3, 4.0), rng.uniform(-math.pi, math.pi)],
                 [a1 * rng.uniform(0.0, 2.0), rng.uniform(-math.pi, math.pi)]]
    if not null:
        ripple = {"period_rad": 2 * math.pi / cpr, "harmonics": harmonics}
    rate = float(rng.choice([200.0, 500.0, 1000.0]))
    n_runs = int(rng.integers(2, 4))
    runs = [{"speed_rad_s": _log_uniform(rng, 0.05, 1.3), "range_rad": rng.uniform(0.4, 1.2),
             "mode": str(rng.choice(["torque", "position"]))} for _ in range(n_runs)]
    on = [n for n in RIPPLE_NUISANCES if rng.uniform() < 0.5] if nuisances is None else \
        _checked(nuisances, RIPPLE_NUISANCES)
    effects: dict[str, dict[str, Any]] = {}
    after: dict[str, Any] = {}
    if "friction" in on:
        effects["link_friction"] = {"coulomb_nm": rng.uniform(0.2, 3.0), "viscous_nms_rad": rng.uniform(0.0, 1.0)}
    if "gravity" in on:
        effects["position_dependent_load"] = {"amplitude_nm": rng.uniform(2.0, 30.0) * rng.choice([-1.0, 1.0]),
                                              "phase_rad": rng.uniform(-math.pi, math.pi),
                                              "compensated": rng.uniform(0.9, 1.0)}
    if "hum" in on:
        f_hum = rng.uniform(5.0, 80.0)
        after["hum_harmonics"] = [(rng.uniform(0.005, 0.05), m * f_hum, rng.uniform(-math.pi, math.pi))
                                  for m in (1, 2, 3) if m * f_hum < 0.5 * rate]
    if "coloured_noise" in on:
        after["coloured_noise"] = (rng.uniform(0.005, 0.03), rng.uniform(0.9, 0.99))
    if "gaps" in on:
        after["gaps"] = (int(rng.integers(1, 7)), rng.uniform(0.01, 0.04))
    return RippleScenario(seed=seed, ripple=ripple, runs=runs, rate_hz=rate, effects=effects, after=after, nuisances=on)


def simulate_ripple_scenario(sc: RippleScenario) -> list[Dataset]:
    """Record the scenario's runs on its simulated joint, then apply its sensor nuisances and gaps."""
    base = default_plant().without_effects()
    tables = dict(sc.effects)
    if sc.ripple is not None:
        tables["transmission_ripple"] = sc.ripple
    plant = base.with_effects(*(make_effect(name, table) for name, table in tables.items()))
    plant.simulation["cycle_s"] = 1.0 / sc.rate_hz
    rng = np.random.default_rng(sc.seed + 7919)
    out = []
    for i, run in enumerate(sc.runs):
        joint = SimulatedJoint(plant, seed=sc.seed * 10 + i)
        ds = record(joint, ConstantVelocity([run["speed_rad_s"]], range_rad=run["range_rad"], mode=run["mode"]))
        t = ds["t"]
        signals = {k: np.array(v, dtype=float) for k, v in ds.signals.items()}
        tau = signals["tau_j"]
        for amp, f, ph in sc.after.get("hum_harmonics", []):
            tau += amp * np.sin(2 * math.pi * f * t + ph + rng.uniform(-math.pi, math.pi))
        if "coloured_noise" in sc.after:
            std, pole = sc.after["coloured_noise"]
            e = rng.normal(0.0, std * math.sqrt(1 - pole ** 2), len(t))
            tau += _ar1(e, pole)
        keep = np.ones(len(t), bool)
        if "gaps" in sc.after:
            count, length = sc.after["gaps"]
            n_gap = max(1, int(round(length * sc.rate_hz)))
            for start in rng.integers(0, max(1, len(t) - n_gap), size=count):
                keep[start:start + n_gap] = False
        out.append(Dataset(signals={k: v[keep] for k, v in signals.items()}, experiment=ds.experiment,
                           source=ds.source, joint=ds.joint, sample_rate_hz=sc.rate_hz))
    return out


# ----------------------------------------------------------------------------- hidden effects (diagnosis)

#: Ranges the hidden effects of :func:`draw_hidden_effects` are drawn from (plant-effect names; SI units).
HIDDEN_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "transmission_ripple": {"period_rad": (0.008, 0.05), "amplitude_rad": (2.5e-5, 8e-5)},
    "link_friction": {"coulomb_nm": (0.5, 3.0), "viscous_nms_rad": (0.5, 3.0)},
    "position_dependent_load": {"amplitude_nm": (2.0, 10.0), "phase_rad": (-math.pi, math.pi)},
    "torque_sensor_offset": {"offset_nm": (0.3, 2.0)},  # either sign
    "torque_sensor_scale": {"scale": (0.03, 0.10)},  # |scale - 1|, either sign
    "periodic_disturbance": {"frequency_hz": (8.0, 90.0), "amplitude_nm": (0.1, 0.5)},
    "input_delay": {"extra_s": (0.001, 0.003)},  # extra delay on top of the joint's Td
}

#: Wider ranges of the harder draws (``shapes=True``).
HIDDEN_LARGE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "link_friction": {"coulomb_nm": (0.5, 6.0), "viscous_nms_rad": (0.5, 3.0)},
    "position_dependent_load": {"amplitude_nm": (2.0, 40.0), "phase_rad": (-math.pi, math.pi)},
}

#: The shape each family takes instead of the simple one in a harder draw.
HIDDEN_OTHER_SHAPES: dict[str, str] = {
    "link_friction": "Stribeck breakaway friction (20-50 % above Coulomb below 0.01-0.1 rad/s)",
    "position_dependent_load": "a second harmonic of 5-20 % of the load",
    "torque_sensor_offset": "a drift of up to 0.01 Nm/s",
    "transmission_ripple": "a third harmonic of 20-50 % of the fundamental",
    "periodic_disturbance": "second and third harmonics of 20-50 % of the fundamental each",
}


@dataclass
class HiddenEffectScenario:
    """A joint with 0-2 hidden effects, for judging a diagnosis (see :func:`draw_hidden_effects`).

    Attributes
    ----------
    seed : int
    hidden : dict
        Plant-effect tables by name (:mod:`iiwa_ident.sim._effects`), the truth a diagnosis must not see.
    dynamics : dict
        The joint's Jc, bc, K, Jl, Td [SI] (Table I unless drawn).
    reshaped : list of str
        Hidden effects given a shape other than the simple one of their family.
    """

    seed: int
    hidden: dict[str, dict[str, Any]] = field(default_factory=dict)
    dynamics: dict[str, float] = field(default_factory=lambda: dict(_TABLE1))
    reshaped: list[str] = field(default_factory=list)



def draw_hidden_effects(seed: int, n_effects: int | None = None, *, shapes: bool = False) -> HiddenEffectScenario:
    """Draw 0, 1 or 2 hidden effects (weights 1:2:2 unless ``n_effects`` is given) with random parameters.

    ``shapes``: the harder draw: the joint's dynamics within 30 % of Table I (Td on the simulator's 0.1 ms
    substep), the wider ranges of :data:`HIDDEN_LARGE_RANGES`, and half of the effects in the shape of
    :data:`HIDDEN_OTHER_SHAPES`.
    """
    rng = np.random.default_rng(seed)
    n = int(rng.choice([0, 1, 1, 2, 2])) if n_effects is None else n_effects
    names = [str(x) for x in rng.choice(list(HIDDEN_RANGES), size=n, replace=False)] if n else []
    sc = HiddenEffectScenario(seed)
    extra = np.random.default_rng([seed, 1])  # the harder draw's own numbers leave the plain draw's unchanged
    if shapes:
        sc.dynamics = {k: v * float(extra.uniform(0.7, 1.3)) for k, v in _TABLE1.items()}
        # The simulator realises the delay to its 0.1 ms substep: the truth is the delay the data have.
        sc.dynamics["Td"] = round(sc.dynamics["Td"] / 1e-4) * 1e-4
    for name in names:
        ranges = HIDDEN_LARGE_RANGES.get(name, HIDDEN_RANGES[name]) if shapes else HIDDEN_RANGES[name]
        r = {k: float(rng.uniform(*v)) for k, v in ranges.items()}
        other = shapes and name in HIDDEN_OTHER_SHAPES and extra.uniform() < 0.5
        if other:
            sc.reshaped.append(name)
        if name == "transmission_ripple":
            ph = rng.uniform(0, 2 * np.pi, 2)
            A = r["amplitude_rad"]
            harmonics = [[A, float(ph[0])], [0.25 * A, float(ph[1])]]
            if other:
                harmonics.append([float(extra.uniform(0.2, 0.5)) * A, float(extra.uniform(0, 2 * np.pi))])
            sc.hidden[name] = {"period_rad": r["period_rad"], "harmonics": harmonics}
        elif name == "link_friction":
            sc.hidden[name] = {"coulomb_nm": r["coulomb_nm"], "viscous_nms_rad": r["viscous_nms_rad"]}
            if other:
                sc.hidden[name].update(stribeck_nm=float(extra.uniform(0.2, 0.5)) * r["coulomb_nm"],
                                       stribeck_velocity_rad_s=float(extra.uniform(0.01, 0.1)))
        elif name == "position_dependent_load":
            sc.hidden[name] = {**r, "compensated": 1.0}
            if other:
                sc.hidden[name].update(harmonic2_nm=float(extra.uniform(0.05, 0.2)) * r["amplitude_nm"],
                                       harmonic2_phase_rad=float(extra.uniform(-np.pi, np.pi)))
        elif name == "torque_sensor_offset":
            sc.hidden[name] = {"offset_nm": r["offset_nm"] * float(rng.choice([-1, 1]))}
            if other:
                sc.hidden[name]["drift_nm_s"] = float(extra.uniform(-0.01, 0.01))
        elif name == "torque_sensor_scale":
            sc.hidden[name] = {"scale": 1 + r["scale"] * float(rng.choice([-1, 1]))}
        elif name == "periodic_disturbance":
            sc.hidden[name] = {**r, "phase_rad": float(rng.uniform(-np.pi, np.pi))}
            if other:
                for k in (2, 3):
                    sc.hidden[name].update({f"harmonic{k}_nm": float(extra.uniform(0.2, 0.5)) * r["amplitude_nm"],
                                            f"harmonic{k}_phase_rad": float(extra.uniform(-np.pi, np.pi))})
        elif name == "input_delay":
            sc.hidden[name] = {"extra_s": r["extra_s"]}
    return sc


def hidden_effect_plant(sc: HiddenEffectScenario, base: Plant | None = None) -> Plant:
    """The joint of a hidden-effect scenario: ``base`` (default: the default plant with the scenario's
    dynamics) without its own effects, with the hidden ones."""
    if base is None:
        base = default_plant()
        base.dynamics.update(sc.dynamics)
    return base.without_effects().with_effects(*[make_effect(n, v) for n, v in sc.hidden.items()])


def simulate_hidden_effects(sc: HiddenEffectScenario, base: Plant | None = None, chirp_s: float = 4.0
                            ) -> list[Dataset]:
    """The typical input of a diagnosis on the scenario's joint (about 20 s of data in all).

    A ``chirp_s`` chirp (0.5-150 Hz), constant-velocity runs at 0.4 and 1.0 rad/s over 0.5 rad (torque mode)
    and a 5 s hand-guided run, with the default noise.
    """
    plant = hidden_effect_plant(sc, base)
    s = sc.seed * 10
    return [
        record(SimulatedJoint(plant, seed=s + 1), Chirp(f0_hz=0.5, f1_hz=150.0, duration_s=chirp_s)),
        record(SimulatedJoint(plant, seed=s + 2), ConstantVelocity([0.4, 1.0], range_rad=0.5)),
        record(SimulatedJoint(plant, seed=s + 3), HandGuided(duration_s=5.0, seed=sc.seed)),
    ]


def _ar1(e: np.ndarray, pole: float) -> np.ndarray:
    """x[n] = pole x[n-1] + e[n] (stationary start)."""
    x0 = e[0] / math.sqrt(1 - pole ** 2)
    y, _ = lfilter([1.0], [1.0, -pole], e[1:], zi=[pole * x0])
    return np.r_[x0, y]
