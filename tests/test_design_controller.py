"""Additive torque controller of section V.B, its discretisation, the outer-loop margin and the paper's numbers."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

from iiwa_ident.design._additive import (
    FEEDFORWARD_MODES,
    PAPER_OBSERVER_POLES,
    PAPER_POLES,
    DesignError,
    _close_on_model,
    _dc,
    builtin_poles,
    check_poles,
    design_controller,
    feedforward_transfer_function,
    natural_frequency_damping,
    realisation,
)
from iiwa_ident.design._controller import AdditiveController
from iiwa_ident.design._margins import (
    HumanArm,
    arm_plant,
    exact_delay_spectral_radius,
    kappa_max,
    outer_loop_margins,
    outer_loop_matrix,
)
from iiwa_ident.design._paper import (
    PAPER_VALUES,
    format_reproduction,
    paper_reproduction,
    table1_parameters,
)
from iiwa_ident.model import JointParameters, pade_coefficients, table1_model, transfer_function

TABLE1 = JointParameters(1.03, 55.0, 18500.0, 5.6, 0.005)
T = 1e-3


@pytest.fixture(scope="module")
def designs():
    return {mode: design_controller(TABLE1, feedforward=mode) for mode in FEEDFORWARD_MODES}


def sorted_roots(z):
    return np.array(sorted(np.asarray(z, complex), key=lambda x: (round(x.real, 6), x.imag)))


class TestPadeCoefficients:
    def test_paper_values(self):
        c1, c2 = pade_coefficients(0.005)
        assert c1 == pytest.approx(1200.0, rel=1e-12)
        assert c2 == pytest.approx(480000.0, rel=1e-12)

    def test_approximates_delay_phase(self):
        c1, c2 = pade_coefficients(0.005)
        w = 2 * np.pi * 20.0
        pade = ((1j * w) ** 2 - c1 * 1j * w + c2) / ((1j * w) ** 2 + c1 * 1j * w + c2)
        np.testing.assert_allclose(np.angle(pade), -w * 0.005, rtol=1e-3, atol=0)


class TestModelTransferFunction:
    def test_orders_and_dc_gain(self):
        g4 = transfer_function(TABLE1)
        g2 = transfer_function(TABLE1, delay="none")
        assert len(g4.den[0][0]) == 5 and len(g2.den[0][0]) == 3
        for g in (g4, g2):
            np.testing.assert_allclose(float(np.real(ct.dcgain(g))), 5.6 / 6.63, rtol=1e-12, atol=0)

    def test_equals_eq4_with_pade(self):
        p = TABLE1
        c1, c2 = pade_coefficients(p.Td)
        g = transfer_function(p)
        for f in (0.5, 5.0, 23.0, 80.0, 300.0):
            s = 2j * np.pi * f
            want = ((s * s - c1 * s + c2) / (s * s + c1 * s + c2) * p.Jl * (p.bc * s + p.K)
                    / (p.Jc * p.Jl * s * s + p.Jl * p.bc * s + (p.Jc + p.Jl) * p.K))
            np.testing.assert_allclose(g(s), want, rtol=1e-10, atol=0)


class TestRealisation:
    def test_structure(self):
        A, B, C = realisation(TABLE1)
        np.testing.assert_array_equal(C, [0, 0, 0, 1])
        np.testing.assert_array_equal(A[:, :3], [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])

    def test_transfer_function_equals_pade_model(self):
        A, B, C = realisation(TABLE1)
        tf = ct.ss2tf(A, B.reshape(-1, 1), C.reshape(1, -1), 0)
        model = transfer_function(TABLE1)
        np.testing.assert_allclose(np.trim_zeros(tf.num[0][0], "f"), model.num[0][0], rtol=1e-6, atol=0)
        np.testing.assert_allclose(tf.den[0][0], model.den[0][0], rtol=1e-9, atol=0)
        for f in (0.1, 2.0, 23.2, 100.0, 400.0):
            s = 2j * np.pi * f
            H = C @ np.linalg.solve(s * np.eye(4) - A, B)
            np.testing.assert_allclose(H, model(s), rtol=1e-8, atol=0)

    def test_eq19_printed_A_is_consistent(self):
        p = TABLE1
        c1, c2 = pade_coefficients(p.Td)
        kw = p.K * (1 / p.Jl + 1 / p.Jc)
        A, _, _ = realisation(p)
        printed = [-c2 * kw, -c1 * kw - c2 * p.bc / p.Jc, -kw - c1 * p.bc / p.Jc - c2, -p.bc / p.Jc - c1]
        np.testing.assert_allclose(A[:, 3], printed, rtol=1e-12, atol=0)

    def test_eq20_printed_B1_lacks_c2(self):
        p = TABLE1
        c1, c2 = pade_coefficients(p.Td)
        _, B, _ = realisation(p)
        np.testing.assert_allclose(B[0], c2 * p.K / p.Jc, rtol=1e-12, atol=0)
        np.testing.assert_allclose(B[1:], [c2 * p.bc / p.Jc - c1 * p.K / p.Jc, p.K / p.Jc - c1 * p.bc / p.Jc,
                                           p.bc / p.Jc], rtol=1e-12, atol=0)


class TestBuiltinPoles:
    def test_table1(self):
        bp = builtin_poles(TABLE1)
        np.testing.assert_allclose(bp[0], -26.699 + 143.359j, rtol=0, atol=1e-3)
        assert bp[1] == pytest.approx(bp[0].conjugate(), rel=1e-12)

    def test_are_poles_of_eq4(self):
        np.testing.assert_allclose(sorted_roots(builtin_poles(TABLE1)),
                                   sorted_roots(transfer_function(TABLE1, delay="none").poles()),
                                   rtol=1e-10, atol=0)


class TestNaturalFrequencyDamping:
    def test_builtin(self):
        fn, zeta = natural_frequency_damping(builtin_poles(TABLE1)[0])
        assert fn == pytest.approx(23.21, abs=0.01)
        assert zeta == pytest.approx(0.183, abs=1e-3)

    def test_paper_annotation(self):
        fn, zeta = natural_frequency_damping(-500 + 1j)
        assert fn == pytest.approx(79.58, abs=0.01)
        assert zeta == pytest.approx(1.0, abs=1e-5)


class TestCheckPoles:
    def test_accepts_paper_poles(self):
        p = check_poles(PAPER_POLES)
        np.testing.assert_array_equal(p, np.array(PAPER_POLES))

    @pytest.mark.parametrize("poles, message", [
        ([-1, -2, -3], "expected 4 poles, got 3"),
        ([-1, -2, -3, 0.5], "not stable"),
        ([-1, -2, -3, 0], "not stable"),
        ([-180 + 30j, -180 - 31j, -500, -600], "no conjugate partner"),
        ([-100 + 4000j, -100 - 4000j, -500, -600], "Nyquist"),
        ([-1, -2, -3, complex("nan")], "finite"),
    ])
    def test_rejects(self, poles, message):
        with pytest.raises(DesignError, match=message):
            check_poles(poles)


class TestFeedforwardTransferFunction:
    def test_dc_inverts_plant(self):
        ff = feedforward_transfer_function(TABLE1)
        np.testing.assert_allclose(float(np.real(ct.dcgain(ff))), 6.63 / 5.6, rtol=1e-12, atol=0)

    def test_ff_times_plant_is_prefilter(self):
        ff = feedforward_transfer_function(TABLE1, 50.0, 1.0)
        g = transfer_function(TABLE1, delay="none")
        wf = 2 * np.pi * 50.0
        for f in (1.0, 10.0, 40.0, 200.0):
            s = 2j * np.pi * f
            np.testing.assert_allclose(ff(s) * g(s), wf ** 2 / (s * s + 2 * wf * s + wf ** 2), rtol=1e-10, atol=0)

    def test_strictly_proper(self):
        ff = feedforward_transfer_function(TABLE1)
        assert len(ff.den[0][0]) - len(np.trim_zeros(ff.num[0][0], "f")) == 1


class TestDesignController:
    def test_places_exactly_the_requested_poles(self, designs):
        d = designs["reference"]
        np.testing.assert_allclose(sorted_roots(np.linalg.eigvals(d.A - np.outer(d.B, d.K_fsf))),
                                   sorted_roots(PAPER_POLES), rtol=1e-7, atol=0)
        np.testing.assert_allclose(sorted_roots(np.linalg.eigvals(d.A - np.outer(d.L, d.C))),
                                   sorted_roots(PAPER_OBSERVER_POLES), rtol=1e-7, atol=0)

    def test_discrete_gains_place_mapped_poles(self, designs):
        d = designs["reference"]
        np.testing.assert_allclose(sorted_roots(np.linalg.eigvals(d.Ad - np.outer(d.Bd, d.Kd))),
                                   sorted_roots(np.exp(np.array(PAPER_POLES) * T)), rtol=0, atol=1e-7)
        np.testing.assert_allclose(sorted_roots(np.linalg.eigvals(d.Ad - np.outer(d.Ld, d.C))),
                                   sorted_roots(np.exp(np.array(PAPER_OBSERVER_POLES) * T)), rtol=0, atol=1e-7)

    def test_other_poles_and_repeated_observer_poles(self):
        poles = [-150 + 20j, -150 - 20j, -400, -450]
        obs = [-800, -800, -900, -900]
        d = design_controller(TABLE1, poles, obs, feedforward="none")
        np.testing.assert_allclose(np.poly(d.A - np.outer(d.B, d.K_fsf)), np.real(np.poly(poles)), rtol=1e-8, atol=0)
        np.testing.assert_allclose(np.poly(d.A - np.outer(d.L, d.C)), np.poly(obs), rtol=1e-8, atol=0)

    def test_separation_gives_the_additive_poles(self, designs):
        d = designs["reference"]
        want = sorted_roots(list(PAPER_POLES) + list(PAPER_OBSERVER_POLES))
        np.testing.assert_allclose(sorted_roots(d.additive_poles), want, rtol=1e-7, atol=0)
        np.testing.assert_allclose(sorted_roots(np.log(d.additive_poles_discrete) / T), want, rtol=1e-6, atol=0)

    def test_kr_gives_feedback_unit_dc_gain(self, designs):
        d = designs["none"]
        closed = d.C @ np.linalg.solve(np.outer(d.B, d.K_fsf) - d.A, d.B) * d.Kr
        assert closed == pytest.approx(1.0, rel=1e-9)
        assert d.Kr == pytest.approx(0.96563, abs=1e-5)
        assert d.Kr_c == pytest.approx(d.Kr, rel=1e-9)

    @pytest.mark.parametrize("mode", FEEDFORWARD_MODES)
    def test_overall_dc_gain_is_one(self, designs, mode):
        d = designs[mode]
        assert d.dc_gain(discrete=True) == pytest.approx(1.0, abs=1e-9)
        assert d.dc_gain(discrete=False) == pytest.approx(1.0, abs=1e-9)

    def test_paper_kr_with_feedforward_double_counts(self, designs):
        # Eqs (16)-(18) as printed (paper's Kr plus tau_ff): tau_ff already inverts G(0).
        d = designs["paper"]
        dc = _dc(_close_on_model(d.controller_matrices(False, d.Kr), d.model_matrices(False)), False)
        assert dc == pytest.approx(2.684, abs=1e-3)
        assert d.Kr_d < 0 and designs["reference"].Kr_d == 0.0

    def test_reference_mode_follows_prefiltered_model(self, designs):
        # On its own (Pade) model the feedback stays at rest: tau_J = Pade * P * tau_r.
        d = designs["reference"]
        cl = d.closed_loop(discrete=False)
        c1, c2 = d.c1, d.c2
        wf = 2 * np.pi * d.prefilter_hz
        for f in (1.0, 10.0, 50.0):
            s = 2j * np.pi * f
            want = (s * s - c1 * s + c2) / (s * s + c1 * s + c2) * wf ** 2 / (s * s + 2 * wf * s + wf ** 2)
            np.testing.assert_allclose(cl(s)[0, 0], want, rtol=1e-6, atol=0)

    @pytest.mark.parametrize("kwargs, message", [
        ({"feedforward": "both"}, "feedforward"),
        ({"prefilter_hz": 600.0}, "pre-filter"),
        ({"sample_time_s": 0.0}, "sample time"),
        ({"poles": [-1, -2, -3, 4]}, "not stable"),
    ])
    def test_rejects_bad_settings(self, kwargs, message):
        with pytest.raises(DesignError, match=message):
            design_controller(TABLE1, **kwargs)


class TestDiscretisation:
    @pytest.mark.parametrize("mode", ["reference", "none"])
    def test_keeps_continuous_response_below_50hz(self, designs, mode):
        d = designs[mode]
        cc, cd = d.closed_loop(discrete=False), d.closed_loop(discrete=True)
        for f in np.linspace(0.2, 50.0, 40):
            w = 2 * np.pi * f
            # The zero-order hold of tau_c delays by half a cycle; everything else must match.
            hc = cc(1j * w)[0, 0] * np.exp(-1j * w * T / 2)
            hd = cd(np.exp(1j * w * T))[0, 0]
            assert abs(hd - hc) < 0.01, f
            assert abs(abs(hd) - abs(hc)) < 0.01, f


class TestAdditiveController:
    @pytest.mark.parametrize("mode", FEEDFORWARD_MODES)
    def test_step_equals_compact_realisation(self, designs, mode):
        d = designs[mode]
        Ac, Bc, Cc, Dc = d.controller_matrices(discrete=True, scaled=False)
        rng = np.random.default_rng(1)
        r, y = rng.normal(size=200), rng.normal(size=200)
        x = np.zeros(Ac.shape[0])
        want = []
        for k in range(200):
            u = np.array([r[k], y[k]])
            want.append(Cc @ x + Dc @ u)
            x = Ac @ x + Bc @ u
        ctrl = AdditiveController(d)
        got = [ctrl.step(r[k], y[k]) for k in range(200)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)

    def test_reset(self, designs):
        ctrl = designs["reference"].controller()
        first = [ctrl.step(1.0, 0.0) for _ in range(5)]
        ctrl.reset()
        assert [ctrl.step(1.0, 0.0) for _ in range(5)] == first

    def test_step_settles_on_simulated_joint(self, designs, linear_plant):
        from iiwa_ident.robot import Command
        from iiwa_ident.sim import SimulatedJoint

        # 5 Nm rather than 1 Nm: the robot suppresses torque control below 1 Nm from standstill.
        def run(design):
            robot = SimulatedJoint(linear_plant, seed=0)
            m = robot.start()
            ctrl = design.controller()
            tau = []
            for _ in range(300):
                m = robot.step(Command(tau_c=ctrl.step(5.0, m.tau_j)))
                tau.append(m.tau_j)
            return np.array(tau)

        # The built-in loop alone overshoots by ~60 %. The default 250 Hz pre-filter lets eq (22)
        # through almost unfiltered (~15 % on an ideal step); a 50 Hz one gives a slower, flat edge.
        tau = run(designs["reference"])
        np.testing.assert_allclose(tau[100:], 5.0, rtol=0, atol=0.01)
        assert tau.max() < 5.0 * 1.2
        tau = run(design_controller(TABLE1, prefilter_hz=50.0))
        np.testing.assert_allclose(tau[100:], 5.0, rtol=0, atol=0.01)
        assert tau.max() < 5.0 * 1.03
        assert tau[25] > 4.5


class TestArmPlant:
    def test_soft_arm_gives_eq4(self):
        A, B, C = arm_plant(TABLE1, HumanArm(stiffness=1e-9, damping=0.0))
        g = transfer_function(TABLE1, delay="none")
        for f in (2.0, 23.0, 100.0):
            s = 2j * np.pi * f
            np.testing.assert_allclose(C[0] @ np.linalg.solve(s * np.eye(4) - A, B), g(s), rtol=1e-6, atol=0)

    def test_ft_torque_is_arm_force(self):
        arm = HumanArm(300.0, 40.0, 0.5)
        A, B, C = arm_plant(TABLE1, arm)
        x = np.array([0.01, 0.2, 0.02, -0.3])
        accel = (A @ x)[3]
        assert C[1] @ x == pytest.approx(-(300.0 * 0.02 + 40.0 * -0.3 + 0.5 * accel), rel=1e-12)

    def test_rejects_bad_arm(self):
        with pytest.raises(DesignError, match="stiffness"):
            HumanArm(stiffness=0.0)
        with pytest.raises(DesignError, match="damping"):
            HumanArm(damping=-1.0)


class TestOuterLoopMatrix:
    def test_size_and_stability_at_zero(self, designs):
        M = outer_loop_matrix(TABLE1, 0.0)
        assert M.shape == (4 + 5, 4 + 5)  # plant + five delayed commands
        assert np.abs(np.linalg.eigvals(M)).max() < 1.0
        Ma = outer_loop_matrix(TABLE1, 0.0, designs["reference"])
        assert Ma.shape == (9 + 4 + 4 + 3, 9 + 4 + 4 + 3)

    def test_fractional_delay_adds_one_state(self):
        p = JointParameters(1.03, 55.0, 18500.0, 5.6, 0.0045)
        assert outer_loop_matrix(p, 1.0).shape == (4 + 5, 4 + 5)
        p = JointParameters(1.03, 55.0, 18500.0, 5.6, 0.004)
        assert outer_loop_matrix(p, 1.0).shape == (4 + 4, 4 + 4)


class TestKappaMax:
    def test_finite_and_additive_larger(self, designs):
        kb = kappa_max(TABLE1)
        ka = kappa_max(TABLE1, designs["reference"])
        assert math.isfinite(kb) and math.isfinite(ka)
        assert ka > 2 * kb
        # 23.0 with a 50 Hz pre-filter, 32.9 with the default 250 Hz (faster feed-forward, less phase lag).
        np.testing.assert_allclose([kb, ka], [7.78, 32.9], rtol=0.01, atol=0)
        assert kappa_max(TABLE1, design_controller(TABLE1, prefilter_hz=50.0)) == pytest.approx(23.0, rel=0.01)

    def test_boundary(self):
        k = kappa_max(TABLE1, tol=1e-5)
        rho = [np.abs(np.linalg.eigvals(outer_loop_matrix(TABLE1, x))).max() for x in (k - 1e-3, k + 1e-3)]
        assert rho[0] < 1.0 < rho[1]

    def test_stiffer_damping_lowers_margin(self):
        assert kappa_max(TABLE1, arm=HumanArm(300.0, 100.0)) < kappa_max(TABLE1, arm=HumanArm(300.0, 40.0))

    def test_limit_gives_inf(self):
        assert kappa_max(TABLE1, kappa_limit=2.0) == math.inf


class TestOuterLoopMargins:
    def test_ratio(self, designs):
        m = outer_loop_margins(designs["none"], HumanArm())
        assert m.additive > m.builtin > 0
        assert m.ratio == pytest.approx(m.additive / m.builtin, rel=1e-12)


class TestExactDelaySpectralRadius:
    def test_paper_design_survives_exact_delay(self, designs):
        assert exact_delay_spectral_radius(designs["none"]) < 0.9
        # The reference generator carries the model's built-in pair |exp(p T)| = exp(-26.7 ms/s).
        assert exact_delay_spectral_radius(designs["reference"]) == pytest.approx(math.exp(-0.0267), abs=1e-4)

    def test_too_fast_poles_fail(self):
        d = design_controller(TABLE1, [-300 + 30j, -300 - 30j, -800, -900], [-1500, -1600, -1700, -1800])
        assert exact_delay_spectral_radius(d) > 1.0


@pytest.fixture(scope="module")
def rows():
    return {r.quantity: r for r in paper_reproduction()}


class TestPaperReproduction:
    def test_table1_source_matches_builtin_model(self):
        params, source = table1_parameters()
        assert params == JointParameters.from_model(table1_model())
        assert source.endswith("paper-table1.toml")

    def test_L_within_half_percent(self, rows):
        for i in range(1, 5):
            assert abs(rows[f"L_{i}"].rel_diff) < 0.005
            assert abs(rows[f"L_{i}"].rel_diff_bc) < 0.005

    def test_builtin_poles(self, rows):
        assert rows["built-in Re"].computed == pytest.approx(-26.70, abs=0.01)
        assert rows["built-in Re"].computed_bc == pytest.approx(PAPER_VALUES["builtin_re"], abs=1e-9)
        assert abs(rows["built-in fn"].rel_diff) < 0.002
        assert abs(rows["built-in zeta"].rel_diff_bc) < 0.005

    def test_kfsf_matches_with_paper_damping(self, rows):
        for i in range(1, 5):
            assert abs(rows[f"K_FSF,{i}"].rel_diff_bc) < 0.02
        assert abs(rows["K_FSF,4"].rel_diff) > 0.2  # Table I's bc = 55 as listed

    def test_kr_and_printed_b1(self, rows):
        assert abs(rows["Kr"].rel_diff) < 0.003
        assert rows["B_1 of eq (20)"].computed / rows["B_1 of eq (20)"].paper == pytest.approx(480000.0, rel=1e-12)
        assert "signs flipped" in rows["B_1 of eq (20)"].explanation

    def test_every_row_explained(self, rows):
        assert all(r.explanation for r in rows.values())


class TestFormatReproduction:
    def test_table(self):
        text = format_reproduction(paper_reproduction(), "datasets/paper-table1.toml")
        assert "datasets/paper-table1.toml" in text
        for name in ("K_FSF,4", "L_1", "Kr", "built-in Re", "fn(-1010)"):
            assert name in text
        assert "3.8430e+11" in text and "0.9636" in text
