"""Hidden-effect cases for testing ``diagnose``: draw, simulate, score.

A case hides 0, 1 or 2 plant effects with random parameters in realistic
ranges (:data:`RANGES`) in the simulated joint, simulates the typical input
of the experiments (a short chirp, constant-velocity runs, a hand-guided
run) and scores a diagnosis against the hidden truth: every hidden effect
must be named with its parameters within :data:`TOLERANCES`, and nothing
else may be named. The truth stays in the :class:`Case`; the diagnosis only
sees the datasets.

Harder cases (``draw_case(..., shapes=True)``): the joint's own parameters
drawn within 30 % of Table I, larger loads (up to 40 Nm) and frictions (up
to 6 Nm), and half of the effects in a shape the candidates do not have
(:data:`OTHER_SHAPES`: Stribeck friction, a load with a second harmonic, a
drifting offset, a ripple with a third harmonic, a hum with harmonics); such an effect must be
named by its family, its parameters are not scored. ``run_case(...,
fit=True)`` diagnoses against the chirp's fit (its eq (4) parameters) instead
of the true eq (4).
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

__all__ = ["RANGES", "LARGE_RANGES", "OTHER_SHAPES", "TOLERANCES", "ABSORBED_BY_FIT", "Case", "draw_case",
           "case_model", "simulate_case", "score_case", "run_case"]

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

#: Wider ranges of the harder cases (``shapes=True``).
LARGE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "link_friction": {"coulomb_nm": (0.5, 6.0), "viscous_nms": (0.5, 3.0)},
    "position_dependent_load": {"amplitude_nm": (2.0, 40.0), "phase_rad": (-math.pi, math.pi)},
}

#: The shape each family takes instead of the candidate's in a harder case.
OTHER_SHAPES: dict[str, str] = {
    "link_friction": "Stribeck breakaway friction (20-50 % above Coulomb below 0.01-0.1 rad/s)",
    "position_dependent_load": "a second harmonic of 5-20 % of the load",
    "torque_sensor_offset": "a drift of up to 0.01 Nm/s",
    "transmission_ripple": "a third harmonic of 20-50 % of the fundamental",
    "periodic_disturbance": "second and third harmonics of 20-50 % of the fundamental each",
}

#: Tolerances per parameter: ``(relative, absolute)``; a value passes within either.
TOLERANCES: dict[str, dict[str, tuple[float, float]]] = {
    "transmission_ripple": {"period_rad": (2e-3, 0.0), "amplitude_rad": (0.25, 0.0)},
    "link_friction": {"coulomb_nm": (0.2, 0.1), "viscous_nms": (0.25, 0.2)},
    "position_dependent_load": {"amplitude_nm": (0.15, 0.3), "phase_rad": (0.0, 0.15)},
    "torque_sensor_offset": {"offset_nm": (0.1, 0.05)},
    "torque_sensor_scale": {"scale": (0.0, 0.01)},
    "periodic_disturbance": {"frequency_hz": (0.005, 0.0), "amplitude_nm": (0.2, 0.02)},
    # A hidden extra input delay is the model's Td being off: named as model_parameters with the total delay.
    "model_parameters": {"Td_s": (0.0, 3e-4), "K_nm_rad": (0.03, 0.0), "Jl_kgm2": (0.05, 0.0)},
}


@dataclass
class Case:
    """One hidden-effect case: the seed, the hidden effects (plant tables) and their expected parameters."""

    seed: int
    hidden: dict[str, dict[str, Any]] = field(default_factory=dict)
    expected: dict[str, dict[str, float]] = field(default_factory=dict)
    #: The joint's eq (4) parameters (Table I unless drawn).
    dynamics: dict[str, float] = field(default_factory=lambda: dict(_TABLE1))
    #: The hidden effects given a shape other than the candidate's (named by family, parameters not scored).
    reshaped: list[str] = field(default_factory=list)


_TABLE1 = {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}


def draw_case(seed: int, n_effects: int | None = None, *, shapes: bool = False) -> Case:
    """Draw a case: 0, 1 or 2 effects (weights 1:2:2 unless ``n_effects`` is given) with random parameters.

    ``shapes``: the harder case of the module docstring (drawn dynamics, larger loads and frictions, half the
    effects in another shape).
    """
    rng = np.random.default_rng(seed)
    n = int(rng.choice([0, 1, 1, 2, 2])) if n_effects is None else n_effects
    names = list(rng.choice(list(RANGES), size=n, replace=False)) if n else []
    case = Case(seed)
    extra = np.random.default_rng([seed, 1])  # the harder case's own draws leave the plain case's unchanged
    if shapes:
        case.dynamics = {k: v * float(extra.uniform(0.7, 1.3)) for k, v in _TABLE1.items()}
        # The simulator realises the delay to its 0.1 ms substep: the truth is the delay the data have.
        case.dynamics["Td"] = round(case.dynamics["Td"] / 1e-4) * 1e-4
    for name in names:
        ranges = LARGE_RANGES.get(name, RANGES[name]) if shapes else RANGES[name]
        r = {k: float(rng.uniform(*v)) for k, v in ranges.items()}
        other = shapes and name in OTHER_SHAPES and extra.uniform() < 0.5
        if other:
            case.reshaped.append(name)
        if name == "transmission_ripple":
            ph = rng.uniform(0, 2 * np.pi, 2)
            A = r["amplitude_rad"]
            harmonics = [[A, ph[0]], [0.25 * A, ph[1]]]
            if other:
                harmonics.append([float(extra.uniform(0.2, 0.5)) * A, float(extra.uniform(0, 2 * np.pi))])
            case.hidden[name] = {"period_rad": r["period_rad"], "harmonics": harmonics}
            x = np.arange(4096) * 2 * np.pi / 4096
            f = sum(a * np.sin((k + 1) * x + p) for k, (a, p) in enumerate(harmonics))
            case.expected[name] = {"period_rad": r["period_rad"], "amplitude_rad": float(np.ptp(f) / 2)}
        elif name == "link_friction":
            case.hidden[name] = {"coulomb_nm": r["coulomb_nm"], "viscous_nms_rad": r["viscous_nms"]}
            if other:
                case.hidden[name].update(stribeck_nm=float(extra.uniform(0.2, 0.5)) * r["coulomb_nm"],
                                         stribeck_velocity_rad_s=float(extra.uniform(0.01, 0.1)))
            case.expected[name] = r
        elif name == "position_dependent_load":
            case.hidden[name] = {**r, "compensated": 1.0}
            if other:
                case.hidden[name].update(harmonic2_nm=float(extra.uniform(0.05, 0.2)) * r["amplitude_nm"],
                                         harmonic2_phase_rad=float(extra.uniform(-np.pi, np.pi)))
            case.expected[name] = r
        elif name == "torque_sensor_offset":
            r["offset_nm"] *= rng.choice([-1, 1])
            case.hidden[name] = dict(r)
            if other:
                case.hidden[name]["drift_nm_s"] = float(extra.uniform(-0.01, 0.01))
            case.expected[name] = r
        elif name == "torque_sensor_scale":
            s = 1 + r["scale"] * rng.choice([-1, 1])
            case.hidden[name] = case.expected[name] = {"scale": s}
        elif name == "periodic_disturbance":
            case.hidden[name] = {**r, "phase_rad": float(rng.uniform(-np.pi, np.pi))}
            if other:
                for k in (2, 3):
                    case.hidden[name].update({f"harmonic{k}_nm": float(extra.uniform(0.2, 0.5)) * r["amplitude_nm"],
                                              f"harmonic{k}_phase_rad": float(extra.uniform(-np.pi, np.pi))})
            case.expected[name] = r
        elif name == "input_delay":
            case.hidden[name] = {"extra_s": r["delay_s"]}
            case.expected["model_parameters"] = {"Td_s": case.dynamics["Td"] + r["delay_s"],
                                                 "K_nm_rad": case.dynamics["K"], "Jl_kgm2": case.dynamics["Jl"]}
    return case


def case_model(case: Case) -> JointModel:
    """The case's true eq (4) as a model (Table I with the case's dynamics), without effects."""
    model = table1_model()
    for k, v in case.dynamics.items():
        model.parameters[k].value = v
    return model


def simulate_case(case: Case, model: JointModel | None = None, chirp_s: float = 4.0) -> list[Dataset]:
    """The typical input on a joint with the case's hidden effects (about 20 s of data in all).

    A ``chirp_s`` chirp (0.5-150 Hz), constant-velocity runs at 0.4 and 1.0
    rad/s over 0.5 rad (torque mode) and a 5 s hand-guided run, on the model's
    dynamics (the case's by default) with the case's effects and default noise.
    """
    from iiwa_ident.sim import SimulatedJoint
    from iiwa_ident.sim.effects import make_effect

    plant = (model or case_model(case)).to_plant()
    plant = plant.without_effects().with_effects(*[make_effect(n, v) for n, v in case.hidden.items()])
    s = case.seed * 10
    return [
        record(SimulatedJoint(plant, seed=s + 1), Chirp(f0_hz=0.5, f1_hz=150.0, duration_s=chirp_s)),
        record(SimulatedJoint(plant, seed=s + 2), ConstantVelocity([0.4, 1.0], range_rad=0.5)),
        record(SimulatedJoint(plant, seed=s + 3), HandGuided(duration_s=5.0, seed=case.seed)),
    ]


def _within(value: float, truth: float, tol: tuple[float, float], angle: bool = False) -> bool:
    err = abs(value - truth)
    if angle:
        err = abs((value - truth + math.pi) % (2 * math.pi) - math.pi)
    return err <= max(tol[0] * abs(truth), tol[1])


#: Hidden effects a chirp's fit takes into its eq (4) parameters: the extra delay is part of the fitted Td
#: (named, it is ``model_parameters``), a torque sensor's scale scales the fitted bc, K and Jl alike (the
#: motor position fixes Jc). After a fit the diagnosis need not name them (naming them is no error either).
ABSORBED_BY_FIT = ("model_parameters", "torque_sensor_scale")

#: ``model_parameters`` after a fit is right when it leaves none of these farther from the truth than the fit
#: did, beyond its tolerance in :data:`TOLERANCES` (relative; Td absolute).
_REFIT_KEYS = {"K": "K_nm_rad", "Jl": "Jl_kgm2", "Td": "Td_s"}


def score_case(case: Case, named: dict[str, dict[str, float]], fit_error: dict[str, float] | None = None
               ) -> dict[str, Any]:
    """Score named effects against the case.

    ``fit_error``: with a fitted model, its parameters' relative errors; then the effects of
    :data:`ABSORBED_BY_FIT` need not be named, and ``model_parameters`` (a correction of the fit's
    own values) is right unless it moves K, Jl or Td away from the truth beyond its tolerance.

    Returns
    -------
    dict
        ``hit`` (exactly the hidden effects named, all parameters within
        tolerance), ``names_ok``, ``missed``, ``false`` (named but not hidden)
        and ``bad_parameters`` (``effect.parameter`` outside tolerance).
    """
    hidden, found = set(case.expected), set(named)
    bad = []
    if fit_error:
        if "model_parameters" in found:
            tol = TOLERANCES["model_parameters"]
            for k, key in _REFIT_KEYS.items():
                truth = case.dynamics[k]
                fitted = truth * (1.0 + fit_error.get(k, 0.0))
                value = named["model_parameters"].get(key, fitted)
                allowed = max(abs(fitted - truth), tol[key][0] * truth + tol[key][1])
                if abs(value - truth) > allowed:
                    bad.append(f"model_parameters.{key}")
        absorbed = set(ABSORBED_BY_FIT)
        hidden -= absorbed
        found -= absorbed
    for name in (hidden & found & set(case.expected)) - set(case.reshaped):
        for key, truth in case.expected[name].items():
            value = named[name].get(key)
            if value is None or not _within(value, truth, TOLERANCES[name][key], angle=key == "phase_rad"):
                bad.append(f"{name}.{key}")
    return {"hit": hidden == found and not bad, "names_ok": hidden == found, "missed": sorted(hidden - found),
            "false": sorted(found - hidden), "bad_parameters": bad}


def run_case(seed: int, n_effects: int | None = None, *, shapes: bool = False, fit: bool = False) -> dict[str, Any]:
    """Draw, simulate, diagnose and score one case; adds timing [s].

    The model is the case's true eq (4), or with ``fit`` the eq (4) parameters of
    :func:`~iiwa_ident.ident.joint_fit.fit_model` on the case's chirp (10 s then; the
    fitted effects are left out: the diagnosis must find them).
    """
    from iiwa_ident.diagnose.diagnosis import diagnose

    case = draw_case(seed, n_effects, shapes=shapes)
    t0 = time.perf_counter()
    data = simulate_case(case, chirp_s=10.0 if fit else 4.0)
    t1 = time.perf_counter()
    model = case_model(case)
    fit_error: dict[str, float] = {}
    if fit:
        from iiwa_ident.ident.joint_fit import fit_joint

        result = fit_joint(data[:1])
        fit_error = {k: v / case.dynamics[k] - 1.0 for k, v in result.parameters.items()}
        for k, v in result.parameters.items():
            model.parameters[k].value = v
    t2 = time.perf_counter()
    d = diagnose(data, model)
    t3 = time.perf_counter()
    named = {e.name: e.parameters for e in d.effects}
    out = score_case(case, named, fit_error if fit else None)
    out.update(seed=seed, hidden=sorted(case.expected), expected=case.expected, named=named,
               reshaped=list(case.reshaped), simulate_s=t1 - t0, fit_s=t2 - t1, diagnose_s=t3 - t2,
               explained=d.explained, suspects=[x["name"] for x in d.suspects], fit_error=fit_error,
               gains={e.name: e.gain_pct for e in d.effects})
    return out
