"""The one control cycle: analytic checks of offset, observer and restart."""

from __future__ import annotations

import doctest

import numpy as np
import pytest

import iiwa_ident.design._cycle as cycle_module
from iiwa_ident.design import (
    DESIGN_BETA,
    RIPPLE_PERIOD_RAD,
    AdditiveController,
    ControlCycle,
    FilterSettings,
    design_controller,
    table1_parameters,
)
from iiwa_ident.model import RippleTable
from iiwa_ident.robot import Measurement

PARAMS, _ = table1_parameters()
DESIGN = design_controller(PARAMS)


def _cycle(**kwargs) -> ControlCycle:
    return ControlCycle(AdditiveController(DESIGN), **kwargs)


def _run(cycle: ControlCycle, q_m: np.ndarray, tau_j: np.ndarray, tau_r: np.ndarray) -> np.ndarray:
    return np.array([cycle.step(Measurement(k * 1e-3, q, t, 0.0), r)
                     for k, (q, t, r) in enumerate(zip(q_m, tau_j, tau_r))])


def test_doctests():
    assert doctest.testmod(cycle_module).failed == 0


def test_a_constant_torque_offset_changes_nothing():
    rng = np.random.default_rng(3)
    n = 600
    q_m = 0.4 * np.sin(np.linspace(0, 6, n))
    tau_j = rng.normal(0, 0.5, n) + 3 * np.sin(np.linspace(0, 20, n))
    tau_r = 4 * np.sign(np.sin(np.linspace(0, 9, n)))
    table = RippleTable(0.2, 1e-4 * np.sin(np.linspace(0, 2 * np.pi, 16, endpoint=False)))
    a = _run(_cycle(ripple=table), q_m, tau_j, tau_r)
    b = _run(_cycle(ripple=table), q_m, tau_j + 17.5, tau_r)
    assert a[0] == 0.0 and b[0] == 0.0
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


def test_the_controller_sees_the_filtered_torque_at_rest():
    # At rest the spatial filter passes tau_J through (gamma = 0), so the controller gets tau_J - offset.
    c = _cycle()
    ref = AdditiveController(DESIGN)
    c.step(Measurement(0.0, 0.1, 1.0, 0.0), 0.0)
    for k, tau in enumerate([1.0, 1.5, 2.0, 2.5], start=1):
        out = c.step(Measurement(k * 1e-3, 0.1, tau, 0.0), 2.0)
        assert c.tau_j_filt == pytest.approx(tau - 1.0, abs=1e-12)
        assert out == pytest.approx(ref.step(2.0, tau - 1.0), rel=1e-12, abs=1e-12)


def test_the_observer_finds_a_static_external_torque():
    # Link at rest: eq (13) settles at tau_ext = -(tau_J - offset), with time constant 1/KI.
    KI = 25.0
    c = _cycle(K=PARAMS.K, KI=KI, Jl=PARAMS.Jl)
    c.step(Measurement(0.0, 0.0, 0.5, 0.0), 0.0)
    n = 400
    for k in range(1, n):
        c.observe(Measurement(k * 1e-3, 0.0, 3.5, 0.0))
    assert c.tau_ext == pytest.approx(-3.0, abs=3.0 * np.exp(-KI * 0.3))
    assert _cycle().tau_ext == 0.0  # no observer without K, KI and Jl


def test_restart_forgets_the_past():
    c = _cycle()
    q = np.linspace(0, 0.5, 300)
    _run(c, q, np.sin(q * 40), np.ones(300))
    c.reset()
    fresh = _cycle()
    m = [Measurement(k * 1e-3, 0.2, 0.3 * k, 0.0) for k in range(5)]
    assert [c.step(x, 1.0) for x in m] == [fresh.step(x, 1.0) for x in m]


def test_one_period_for_the_filter_and_the_lookup_table():
    table = RippleTable(0.2, 1e-4 * np.sin(np.linspace(0, 2 * np.pi, 16, endpoint=False)))
    assert _cycle(ripple=table).torque_filter.period_rad == 0.2  # the filter takes the table's period
    assert _cycle(ripple=table, filter=FilterSettings(beta=5.0)).torque_filter.beta == 5.0
    assert _cycle().torque_filter.period_rad == RIPPLE_PERIOD_RAD  # no table: the paper's rho
    assert _cycle().filter.beta == DESIGN_BETA  # the design's beta by default, as the runtime deploys it
