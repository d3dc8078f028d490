"""The three external-torque observers of section IV (eqs (13)-(14)) and their comparison (Fig. 7)."""

from __future__ import annotations

import numpy as np
import pytest

from iiwa_ident.datasets import Dataset
from iiwa_ident.design import FilterSettings
from iiwa_ident.design._observers import (
    OBSERVERS,
    BuiltinObserver,
    FilteredObserver,
    LinkVelocityObserver,
    compare_observers,
    link_speed,
    make_observer,
    observer_lag,
    run_observers,
)
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import ConstantVelocity, HandGuided, record
from iiwa_ident.ident._ripple import identify_ripple
from iiwa_ident.model import RippleTable, table1_model
from iiwa_ident.sim import SimulatedJoint, default_plant

DT = 1e-3
K, JL, KI = 18500.0, 5.6, 25.0


def _synthetic(n: int = 3000, seed: int = 0):
    """A link driven by known torques, integrated exactly as the discrete eq (13) assumes.

    ``v_{k+1} = v_k + dt (tau_J,k + tau_ext,k) / J_l``, ``theta_k = theta_{k-1} + dt v_k`` and
    ``q_m = theta_l + tau_J / K`` (eqs (3), (5) without a ripple). tau_ext starts at 0.
    """
    rng = np.random.default_rng(seed)
    t = DT * np.arange(n)
    tau_j = 5.0 * np.sin(2 * np.pi * 1.3 * t) + 0.5 * rng.standard_normal(n)
    tau_ext = 8.0 * np.sin(2 * np.pi * 0.4 * t) ** 2 + 3.0 * (t > 1.5)
    v = np.zeros(n)
    theta = np.zeros(n)
    v[0] = 0.3
    for k in range(1, n):
        v[k] = v[k - 1] + DT * (tau_j[k - 1] + tau_ext[k - 1]) / JL
        theta[k] = theta[k - 1] + DT * v[k]
    theta[0] = theta[1] - DT * v[1]
    return t, theta + tau_j / K, tau_j, tau_ext


class TestObserverLag:
    def test_step_response(self):
        y = observer_lag(np.ones(50), KI, DT)
        k = np.arange(50)
        np.testing.assert_allclose(y, 1 - (1 - KI * DT) ** k, rtol=1e-12, atol=1e-15)


class TestLinkVelocityObserver:
    def test_exact_link_motion_gives_the_lagged_external_torque(self):
        t, q_m, tau_j, tau_ext = _synthetic()
        est = LinkVelocityObserver(table1_model(), DT).run((q_m, tau_j))
        # Started at sample 1 with p(0) = J_l v_1: the lag of tau_ext from sample 1 on.
        expect = np.concatenate([[0.0], observer_lag(tau_ext[1:], KI, DT)])
        np.testing.assert_allclose(est, expect, rtol=0, atol=1e-9)

    def test_builtin_sees_the_elastic_deflection_as_external_torque(self):
        t, q_m, tau_j, tau_ext = _synthetic()
        lagged = np.concatenate([[0.0], observer_lag(tau_ext[1:], KI, DT)])
        err_b = BuiltinObserver(table1_model(), DT).run((q_m, tau_j)) - lagged
        # Motor velocity = link velocity + d(tau_J)/dt / K: error K_I J_l / K d(tau_J)/dt, lagged.
        assert np.sqrt(np.mean(err_b ** 2)) > 0.1

    def test_update_equals_run(self):
        t, q_m, tau_j, _ = _synthetic(800)
        for cls in (BuiltinObserver, LinkVelocityObserver):
            obs = cls(table1_model(), DT)
            seq = [obs.update(q, tj) for q, tj in zip(q_m, tau_j)]
            np.testing.assert_allclose(seq, obs.run((q_m, tau_j)), rtol=1e-12, atol=1e-9)

    def test_start_in_motion_has_no_transient(self):
        t, q_m, tau_j, tau_ext = _synthetic()
        est = LinkVelocityObserver(table1_model(), DT).run((q_m, tau_j))
        assert abs(est[1]) < 1e-12 and abs(est[2]) < 0.1  # v(0) = 0.3 rad/s would give K_I J_l v = 42 Nm


class TestFilteredObserver:
    def test_needs_a_ripple_table(self):
        with pytest.raises(IiwaIdentError):
            FilteredObserver(table1_model(), DT)

    def test_update_equals_run_and_reset(self):
        model = table1_model()
        model.ripple = RippleTable(0.01963, 4e-5 * np.sin(2 * np.pi * np.arange(64) / 64))
        t, q_m, tau_j, _ = _synthetic(1200)
        q_m = q_m + 0.6 * t  # moving, so the filter works
        obs = FilteredObserver(model, DT, FilterSettings(beta=3.0))
        seq = [obs.update(q, tj) for q, tj in zip(q_m, tau_j)]
        np.testing.assert_allclose(seq, obs.run((q_m, tau_j)), rtol=1e-12, atol=1e-9)
        obs.reset()
        assert obs.update(q_m[0], tau_j[0]) == 0.0

    def test_registry(self):
        model = table1_model()
        model.ripple = RippleTable(0.01963, np.zeros(16))
        assert list(OBSERVERS) == ["builtin", "improved", "filtered"]
        assert isinstance(make_observer("filtered", model, DT, filter=FilterSettings(beta=2.0)), FilteredObserver)
        with pytest.raises(IiwaIdentError):
            make_observer("kalman", model)


class TestRunChecks:
    def test_sample_time_mismatch_refused(self):
        ds = Dataset(signals={"t": np.arange(10) * 2e-3, "q_m": np.zeros(10), "tau_j": np.zeros(10)},
                     experiment="free", source="simulation", joint=1, sample_rate_hz=500.0)
        with pytest.raises(IiwaIdentError, match="sampled every 2 ms"):
            BuiltinObserver(table1_model(), DT).run(ds)
        assert BuiltinObserver(table1_model(), 2e-3).run(ds).shape == (10,)

    def test_compare_needs_the_reference(self):
        ds = Dataset(signals={"t": np.arange(10) * DT, "q_m": np.zeros(10), "tau_j": np.zeros(10)},
                     experiment="free", source="simulation", joint=1, sample_rate_hz=1000.0)
        with pytest.raises(IiwaIdentError, match="tau_ext_ref"):
            compare_observers(ds, table1_model())


# ------------------------------------------------------------------ simulated joint


@pytest.fixture(scope="module")
def model():
    """Table I with the ripple table identified from a constant-velocity run, as a user would."""
    cv = record(SimulatedJoint(default_plant(), seed=1), ConstantVelocity((0.3, 0.6, 1.2), range_rad=1.0))
    res = identify_ripple([cv])
    assert res.detected
    m = table1_model()
    m.ripple = RippleTable(res.period_rad, res.lut)
    return m


@pytest.fixture(scope="module")
def hand_guided():
    """20 s moved by hand at zero commanded torque (Fig. 7), peak hand speed 1 rad/s."""
    return record(SimulatedJoint(default_plant(), seed=10), HandGuided(20.0, seed=0))


@pytest.fixture(scope="module")
def comparison(hand_guided, model):
    return {beta: compare_observers(hand_guided, model, filter=FilterSettings(beta=beta)) for beta in (5.0, 2.0)}


class TestBuiltinOnSimulation:
    def test_reproduces_what_the_robot_reports(self, hand_guided, model):
        est = BuiltinObserver(model, DT).run(hand_guided)
        # Same eq (13) on the same q_m; only the start convention differs, and it decays as exp(-K_I t).
        late = hand_guided["t"] > 0.5
        np.testing.assert_allclose(est[late], hand_guided["tau_ext_fri"][late], rtol=0, atol=1e-4)


class TestCompareObservers:
    def test_table_layout(self, comparison):
        c = comparison[5.0]
        assert set(c["observers"]) == {"builtin", "improved", "filtered", "fri"}
        for row in c["observers"].values():
            assert set(row) == {"rms_nm", "rms_fast_nm", "rms_lagged_nm", "rms_lagged_fast_nm"}
            assert all(np.isfinite(v) and v > 0 for v in row.values())
        assert c["ratio_fast"] == pytest.approx(
            c["observers"]["builtin"]["rms_fast_nm"] / c["observers"]["filtered"]["rms_fast_nm"], rel=1e-12)

    def test_enough_fast_motion(self, comparison, hand_guided, model):
        assert comparison[5.0]["fast_fraction"] > 0.15
        assert np.abs(link_speed(hand_guided, model)).max() < 1.3

    def test_link_velocity_cuts_the_builtin_error_3x_when_fast(self, comparison):
        rows = comparison[5.0]["observers"]
        assert rows["builtin"]["rms_lagged_fast_nm"] >= 3.0 * rows["improved"]["rms_lagged_fast_nm"]

    def test_filtered_with_beta_2_cuts_the_builtin_error_3x_when_fast(self, comparison):
        assert comparison[2.0]["ratio_lagged_fast"] >= 3.0

    def test_paper_beta_cuts_it_3x(self, comparison):
        # beta = 5 widens the notch towards the human's torque band (see spatial_filter), yet stays above 3x.
        assert comparison[5.0]["ratio_lagged_fast"] >= 3.0

    def test_against_the_raw_reference_every_variant_beats_the_builtin(self, comparison):
        # The raw error is dominated by eq (13)'s own 40 ms lag, common to all three.
        for beta in (5.0, 2.0):
            rows = comparison[beta]["observers"]
            assert rows["improved"]["rms_fast_nm"] < rows["builtin"]["rms_fast_nm"]
            assert rows["filtered"]["rms_fast_nm"] < rows["builtin"]["rms_fast_nm"]

    def test_run_observers_names(self, hand_guided, model):
        est = run_observers(hand_guided, model)
        assert list(est) == ["builtin", "improved", "filtered"]
        assert all(e.shape == hand_guided["t"].shape for e in est.values())


class TestObserverFigure:
    def test_draws_the_comparison(self, hand_guided, model, tmp_path):
        from iiwa_ident.report._design_figures import observer_figure

        fig = observer_figure(hand_guided, model)
        labels = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
        assert any("built-in" in s for s in labels) and any("eq (14)" in s for s in labels)
        assert any("RMS error" in t.get_text() for t in fig.texts)
        fig.savefig(tmp_path / "observers.png", dpi=60)
        assert (tmp_path / "observers.png").stat().st_size > 10_000
