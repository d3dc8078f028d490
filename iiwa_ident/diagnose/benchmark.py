"""Hidden-effect cases for testing ``diagnose``: draw, simulate, score.

A case hides 0, 1 or 2 plant effects with random parameters in realistic
ranges (:data:`RANGES`) in the simulated joint, simulates the typical input
of the experiments (a short chirp, constant-velocity runs, a hand-guided
run) and scores a diagnosis against the hidden truth: every hidden effect
must be named with its parameters within :data:`TOLERANCES`, and nothing
else may be named. The truth stays in the :class:`Case`; the diagnosis only
sees the datasets.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from iiwa_ident.datasets import Dataset
from iiwa_ident.excite import Chirp, ConstantVelocity, HandGuided, record
from iiwa_ident.ident.model_file import JointModel, table1_model

__all__ = ["RANGES", "TOLERANCES", "Case", "draw_case", "simulate_case", "score_case", "run_case"]

#: Ranges the hidden parameters are drawn from (JSON parameter names, SI units).
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "transmission_ripple": {"period_rad": (0.008, 0.05), "amplitude_rad": (2.5e-5, 8e-5)},
    "link_friction": {"coulomb_nm": (0.5, 3.0), "viscous_nms": (0.5, 3.0)},
    "position_dependent_load": {"amplitude_nm": (2.0, 10.0), "phase_rad": (-math.pi, math.pi)},
    "torque_sensor_offset": {"offset_nm": (0.3, 2.0)},  # either sign
    "torque_sensor_scale": {"scale": (0.03, 0.10)},  # |scale - 1|, either sign
    "periodic_disturbance": {"frequency_hz": (8.0, 90.0), "amplitude_nm": (0.1, 0.5)},
    "input_delay": {"delay_s": (0.001, 0.003)},  # extra delay on top of the model's 5 ms
}

#: Tolerances per parameter: ``(relative, absolute)``; a value passes within either.
TOLERANCES: dict[str, dict[str, tuple[float, float]]] = {
    "transmission_ripple": {"period_rad": (2e-3, 0.0), "amplitude_rad": (0.25, 0.0)},
    "link_friction": {"coulomb_nm": (0.2, 0.1), "viscous_nms": (0.25, 0.2)},
    "position_dependent_load": {"amplitude_nm": (0.15, 0.3), "phase_rad": (0.0, 0.15)},
    "torque_sensor_offset": {"offset_nm": (0.1, 0.05)},
    "torque_sensor_scale": {"scale": (0.0, 0.01)},
    "periodic_disturbance": {"frequency_hz": (0.005, 0.0), "amplitude_nm": (0.2, 0.02)},
    "input_delay": {"delay_s": (0.0, 3e-4)},
}


@dataclass
class Case:
    """One hidden-effect case: the seed, the hidden effects (plant tables) and their expected parameters."""

    seed: int
    hidden: dict[str, dict[str, Any]] = field(default_factory=dict)
    expected: dict[str, dict[str, float]] = field(default_factory=dict)


def draw_case(seed: int, n_effects: int | None = None) -> Case:
    """Draw a case: 0, 1 or 2 effects (weights 1:2:2 unless ``n_effects`` is given) with random parameters."""
    rng = np.random.default_rng(seed)
    n = int(rng.choice([0, 1, 1, 2, 2])) if n_effects is None else n_effects
    names = list(rng.choice(list(RANGES), size=n, replace=False)) if n else []
    case = Case(seed)
    for name in names:
        r = {k: float(rng.uniform(*v)) for k, v in RANGES[name].items()}
        if name == "transmission_ripple":
            ph = rng.uniform(0, 2 * np.pi, 2)
            A = r["amplitude_rad"]
            case.hidden[name] = {"period_rad": r["period_rad"], "harmonics": [[A, ph[0]], [0.25 * A, ph[1]]]}
            x = np.arange(4096) * 2 * np.pi / 4096
            f = A * np.sin(x + ph[0]) + 0.25 * A * np.sin(2 * x + ph[1])
            case.expected[name] = {"period_rad": r["period_rad"], "amplitude_rad": float(np.ptp(f) / 2)}
        elif name == "link_friction":
            case.hidden[name] = {"coulomb_nm": r["coulomb_nm"], "viscous_nms_rad": r["viscous_nms"]}
            case.expected[name] = r
        elif name == "position_dependent_load":
            case.hidden[name] = {**r, "compensated": 1.0}
            case.expected[name] = r
        elif name == "torque_sensor_offset":
            r["offset_nm"] *= rng.choice([-1, 1])
            case.hidden[name] = case.expected[name] = r
        elif name == "torque_sensor_scale":
            s = 1 + r["scale"] * rng.choice([-1, 1])
            case.hidden[name] = case.expected[name] = {"scale": s}
        elif name == "periodic_disturbance":
            case.hidden[name] = {**r, "phase_rad": float(rng.uniform(-np.pi, np.pi))}
            case.expected[name] = r
        elif name == "input_delay":
            case.hidden[name] = {"extra_s": r["delay_s"]}
            case.expected[name] = {"delay_s": 0.005 + r["delay_s"]}
    return case


def simulate_case(case: Case, model: JointModel | None = None) -> list[Dataset]:
    """The typical input on a joint with the case's hidden effects (about 20 s of data in all).

    A 4 s chirp (0.5-150 Hz), constant-velocity runs at 0.4 and 1.0 rad/s
    over 0.5 rad (torque mode) and a 5 s hand-guided run, on the model's
    dynamics (Table I by default) with the case's effects and default noise.
    """
    from iiwa_ident.sim import SimulatedJoint
    from iiwa_ident.sim.effects import make_effect

    plant = (model or table1_model()).to_plant()
    plant = plant.without_effects().with_effects(*[make_effect(n, v) for n, v in case.hidden.items()])
    s = case.seed * 10
    return [
        record(SimulatedJoint(plant, seed=s + 1), Chirp(f0_hz=0.5, f1_hz=150.0, duration_s=4.0)),
        record(SimulatedJoint(plant, seed=s + 2), ConstantVelocity([0.4, 1.0], range_rad=0.5)),
        record(SimulatedJoint(plant, seed=s + 3), HandGuided(duration_s=5.0, seed=case.seed)),
    ]


def _within(value: float, truth: float, tol: tuple[float, float], angle: bool = False) -> bool:
    err = abs(value - truth)
    if angle:
        err = abs((value - truth + math.pi) % (2 * math.pi) - math.pi)
    return err <= max(tol[0] * abs(truth), tol[1])


def score_case(case: Case, named: dict[str, dict[str, float]]) -> dict[str, Any]:
    """Score named effects against the case.

    Returns
    -------
    dict
        ``hit`` (exactly the hidden effects named, all parameters within
        tolerance), ``names_ok``, ``missed``, ``false`` (named but not hidden)
        and ``bad_parameters`` (``effect.parameter`` outside tolerance).
    """
    hidden, found = set(case.expected), set(named)
    bad = []
    for name in hidden & found:
        for key, truth in case.expected[name].items():
            value = named[name].get(key)
            if value is None or not _within(value, truth, TOLERANCES[name][key], angle=key == "phase_rad"):
                bad.append(f"{name}.{key}")
    return {"hit": hidden == found and not bad, "names_ok": hidden == found, "missed": sorted(hidden - found),
            "false": sorted(found - hidden), "bad_parameters": bad}


def run_case(seed: int, n_effects: int | None = None) -> dict[str, Any]:
    """Draw, simulate, diagnose (Table I model) and score one case; adds timing [s]."""
    from iiwa_ident.diagnose.diagnosis import diagnose

    case = draw_case(seed, n_effects)
    t0 = time.perf_counter()
    data = simulate_case(case)
    t1 = time.perf_counter()
    d = diagnose(data, table1_model())
    t2 = time.perf_counter()
    named = {e.name: e.parameters for e in d.effects}
    out = score_case(case, named)
    out.update(seed=seed, hidden=sorted(case.expected), expected=case.expected, named=named,
               simulate_s=t1 - t0, diagnose_s=t2 - t1)
    return out
