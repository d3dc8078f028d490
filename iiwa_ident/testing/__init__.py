"""The harness of the tests and the benchmarks: seeded draws of joints, hidden effects and runs, and their scoring.

Not part of the library's layers: no part of :mod:`iiwa_ident` imports it; it imports the library through
the packages' public APIs only, as a user would. Every draw is seeded, so a failure can be replayed.

Public API
----------
Scenario, RippleScenario, draw_scenario, draw_ripple_scenario, scenario_plant, simulate_scenario, simulate_scenario_multisine, simulate_ripple_scenario, NUISANCES, RIPPLE_NUISANCES
    Real-looking joints with random truths, protocols and nuisances, for the fit and the ripple search
    (:mod:`iiwa_ident.testing._scenarios`).
HiddenEffectScenario, draw_hidden_effects, hidden_effect_plant, simulate_hidden_effects, HIDDEN_RANGES, HIDDEN_LARGE_RANGES, HIDDEN_OTHER_SHAPES
    0-2 hidden plant effects on a joint and the experiments that record them.
Case, draw_case, draw_cause_case, case_model, simulate_case, score_case, run_case, expected_findings, final_effects, described_runs, user_protocol, run_user_case, TOLERANCES, ABSORBED_BY_FIT, CAUSE_RANGES
    Hidden-effect cases for ``diagnose``: drawn, simulated, diagnosed and scored against the hidden truth
    (:mod:`iiwa_ident.testing._cases`).
ApartCase, draw_apart_case, draw_apart_cause_case, simulate_apart_case, CHIRP_AMPLITUDE_NM
    A second data path: the joint written again from the paper's equations, apart from :mod:`iiwa_ident.sim`
    (:mod:`iiwa_ident.testing._apart`).
"""

from iiwa_ident.testing._apart import (
    CHIRP_AMPLITUDE_NM,
    ApartCase,
    draw_apart_case,
    draw_apart_cause_case,
    simulate_apart_case,
)
from iiwa_ident.testing._cases import (
    ABSORBED_BY_FIT,
    CAUSE_RANGES,
    TOLERANCES,
    Case,
    case_model,
    described_runs,
    draw_case,
    draw_cause_case,
    expected_findings,
    final_effects,
    run_case,
    run_user_case,
    score_case,
    simulate_case,
    user_protocol,
)
from iiwa_ident.testing._scenarios import (
    HIDDEN_LARGE_RANGES,
    HIDDEN_OTHER_SHAPES,
    HIDDEN_RANGES,
    NUISANCES,
    RIPPLE_NUISANCES,
    HiddenEffectScenario,
    RippleScenario,
    Scenario,
    draw_hidden_effects,
    draw_ripple_scenario,
    draw_scenario,
    hidden_effect_plant,
    scenario_plant,
    simulate_hidden_effects,
    simulate_ripple_scenario,
    simulate_scenario,
    simulate_scenario_multisine,
)

__all__ = [
    "Scenario", "RippleScenario", "draw_scenario", "draw_ripple_scenario", "scenario_plant", "simulate_scenario",
    "simulate_scenario_multisine", "simulate_ripple_scenario", "NUISANCES", "RIPPLE_NUISANCES",
    "HiddenEffectScenario", "draw_hidden_effects", "hidden_effect_plant", "simulate_hidden_effects",
    "HIDDEN_RANGES", "HIDDEN_LARGE_RANGES", "HIDDEN_OTHER_SHAPES",
    "Case", "draw_case", "draw_cause_case", "case_model", "simulate_case", "score_case", "run_case",
    "expected_findings", "final_effects", "described_runs", "user_protocol", "run_user_case", "TOLERANCES",
    "ABSORBED_BY_FIT", "CAUSE_RANGES",
    "ApartCase", "draw_apart_case", "draw_apart_cause_case", "simulate_apart_case", "CHIRP_AMPLITUDE_NM",
]
