"""Closed-loop analysis on the simulated joint: built-in against additive (section V.C)."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
import pytest

from iiwa_ident.design._analysis import (
    AdditiveTorqueControl,
    BuiltinTorqueControl,
    ClosedLoopRun,
    compare_controllers,
    identified_model,
    judge_stability,
    make_controller,
    sine_tracking,
    step_response,
    tracking_errors,
)
from iiwa_ident.model import table1_model
from iiwa_ident.report._control_figures import kappa_figure, pole_figure, tracking_figure
from iiwa_ident.robot import Measurement


@pytest.fixture(scope="module")
def model():
    """Table I with the ripple table identified on a simulated constant-velocity run."""
    return identified_model(seed=1)


@pytest.fixture(scope="module")
def result(model):
    """The whole comparison with the kappa margins (the slow part, ~30 s)."""
    return compare_controllers(model, rel_tol=0.08)


def _fake_run(tau_r, tau_j, dt=1e-3, stopped=""):
    n = len(tau_r)
    t = np.arange(n) * dt
    run = ClosedLoopRun(kind="builtin", t=t, r=np.asarray(tau_r), tau_r=np.asarray(tau_r), tau_c=np.asarray(tau_r),
                        tau_j=np.asarray(tau_j), q_m=np.zeros(n), tau_ext_ref=np.zeros(n), stopped=stopped)
    run.tau_j_filt = np.asarray(tau_j)
    return run


class TestControllers:
    def test_builtin_passes_reference(self):
        c = BuiltinTorqueControl()
        c.reset()
        assert c.command(3.5, Measurement(0.0, 0.0, 1.0, 0.0)) == 3.5

    def test_additive_reset_repeats(self, model):
        c = make_controller("additive", model)
        meas = [Measurement(k * 1e-3, 1e-3 * k, 2.0 + 0.1 * k, 0.0) for k in range(50)]
        first = [c.command(5.0, m) for m in meas]
        c.reset()
        second = [c.command(5.0, m) for m in meas]
        assert np.allclose(first, second)
        assert isinstance(c, AdditiveTorqueControl)

    def test_unknown_kind(self):
        with pytest.raises(ValueError, match="builtin"):
            make_controller("pid", table1_model())


class TestMetrics:
    def test_errors_use_delayed_reference(self):
        t = np.arange(2000) * 1e-3
        r = 10 * np.sin(2 * np.pi * 5 * t)
        j = np.concatenate([np.zeros(5), r[:-5]])  # exactly the 5 ms FRI delay
        e = tracking_errors(_fake_run(r, j), 0.5)
        assert e.raw_peak < 1e-9 and e.filt_rms < 1e-9
        e0 = tracking_errors(_fake_run(r, j), 0.5, delay_s=0.0)
        assert e0.raw_peak == pytest.approx(2 * 10 * math.sin(math.pi * 5 * 0.005), rel=1e-2)

    def test_growing_oscillation_is_unstable(self):
        t = np.arange(7000) * 1e-3
        grow = 0.5 * np.exp(0.5 * t) * np.sin(2 * np.pi * 20 * t)
        steady = 2.0 * np.sin(2 * np.pi * 20 * t)
        assert not judge_stability(_fake_run(np.zeros_like(t), grow), 2.0).stable
        assert judge_stability(_fake_run(np.zeros_like(t), steady), 2.0).stable
        assert not judge_stability(_fake_run(np.zeros_like(t), steady, stopped="speed"), 2.0).stable


class TestOnSimulatedJoint:
    def test_step_builtin_overshoots_like_paper(self, model):
        res = step_response(BuiltinTorqueControl(), None, 10.0, cycles=1, model=model)
        # Paper: ~40 % overshoot (zeta = 0.19).
        assert 0.25 < res.metrics.overshoot_raw < 0.55
        assert not res.run.stopped

    def test_agent_held_link(self, model):
        res = sine_tracking(BuiltinTorqueControl(), None, 5.0, 2.0, duration_s=1.0, model=model,
                            agent_stiffness=2e4)
        # Link held: no motion, hence no ripple and the raw and filtered torques agree.
        assert np.ptp(res.run.q_m) < 5e-3
        assert res.errors.raw_peak == pytest.approx(res.errors.filt_peak, abs=0.2)


class TestComparison:
    def test_poles(self, result):
        b = result["poles"]["builtin"]
        assert b[0].real == pytest.approx(-26.7, abs=0.5) and abs(b[0].imag) == pytest.approx(143.4, abs=1)
        assert len(result["poles"]["additive_closed_loop"]) == 8

    def test_additive_tracks_25hz(self, result):
        add = result["sine"]["additive"][1]
        assert add.frequency_hz == 25.0
        # Targets of section V.C.
        assert add.errors.filt_peak < 5.0
        assert add.errors.raw_peak < 10.0
        assert result["sine"]["builtin"][1].errors.raw_peak > 3 * add.errors.raw_peak

    def test_additive_better_at_low_frequency(self, result):
        b, a = result["sine"]["builtin"][0].errors, result["sine"]["additive"][0].errors
        assert a.filt_rms < b.filt_rms

    def test_step_less_overshoot(self, result):
        assert result["step"]["additive"].metrics.overshoot_raw < result["step"]["builtin"].metrics.overshoot_raw

    def test_kappa_margins(self, result):
        kb, ka = result["kappa"]["builtin"], result["kappa"]["additive"]
        # Built-in: simulation near the linear prediction (no filter in the loop).
        assert kb.kappa_max == pytest.approx(kb.linear, rel=0.15)
        assert kb.kappa_max < kb.kappa_unstable
        assert result["kappa_ratio"] >= 3.0
        assert any(not t.verdict.stable for t in ka.trials)

    def test_figures(self, result, tmp_path):
        for name, fn in (("tracking", tracking_figure), ("poles", pole_figure), ("kappa", kappa_figure)):
            fig = fn(result)
            path = tmp_path / f"{name}.png"
            fig.savefig(path, dpi=50)
            plt.close(fig)
            assert path.stat().st_size > 1000
