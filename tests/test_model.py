"""The joint model, eqs (1)-(4): analytic references for the one implementation every part uses."""

from __future__ import annotations

import doctest

import numpy as np
import pytest

import iiwa_ident.model as model
from iiwa_ident.model import (
    JOINT_PARAMETERS,
    PARAMETER_NAMES,
    JointParameters,
    ParameterError,
    _eq4,
    _parameters,
    coefficients,
    frequency_response,
    pade_coefficients,
    parameter_values,
    resonance_hz,
    transfer_function,
)

TABLE1 = JointParameters(1.03, 55.0, 18500.0, 5.6, 0.005)


def state_space_response(p: JointParameters, f_hz: np.ndarray) -> np.ndarray:
    """tau_J / tau_c from eqs (1)-(3) in their integrated form, solved as a linear system at each frequency.

    Jc theta_m'' = (bc/K + 1/s)(tau_c - tau_J) s, Jl theta_l'' = tau_J, tau_J = K (theta_m - theta_l);
    the command is delayed by Td.
    """
    out = []
    for f in f_hz:
        s = 2j * np.pi * f
        g = p.bc * s / p.K + 1.0  # the internal loop's PD on the torque error
        # unknowns theta_m, theta_l; tau_J = K (theta_m - theta_l)
        M = np.array([[p.Jc * s**2 + g * p.K, -g * p.K],
                      [-p.K, p.Jl * s**2 + p.K]])
        theta = np.linalg.solve(M, np.array([g, 0.0]))
        out.append(p.K * (theta[0] - theta[1]) * np.exp(-p.Td * s))
    return np.array(out)


def test_doctests():
    for module in (_eq4, _parameters):
        assert doctest.testmod(module).failed == 0


def test_frequency_response_is_eq4():
    f = np.geomspace(0.1, 400.0, 50)
    Jc, bc, K, Jl, Td = parameter_values(TABLE1)
    s = 2j * np.pi * f
    want = np.exp(-Td * s) * Jl * (bc * s + K) / (Jc * Jl * s**2 + Jl * bc * s + (Jc + Jl) * K)
    np.testing.assert_allclose(frequency_response(TABLE1, f), want, rtol=1e-13, atol=0)
    np.testing.assert_allclose(frequency_response(TABLE1, f), state_space_response(TABLE1, f), rtol=1e-9, atol=0)


def test_dc_and_high_frequency_limits():
    assert frequency_response(TABLE1, 1e-6) == pytest.approx(TABLE1.Jl / (TABLE1.Jc + TABLE1.Jl), rel=1e-6)
    assert frequency_response(TABLE1, 1e-6, "link") == pytest.approx(-TABLE1.Jc / (TABLE1.Jc + TABLE1.Jl), rel=1e-6)
    assert abs(frequency_response(TABLE1, 1e-6, "deflection")) < 1e-6
    assert frequency_response(TABLE1, 1e5, "deflection").real == pytest.approx(-TABLE1.K, rel=1e-3)


def test_pade_model_matches_the_exact_delay_at_low_frequency():
    G = transfer_function(TABLE1)
    for f in (0.5, 5.0, 20.0):
        exact = frequency_response(TABLE1, f)
        pade = complex(G(2j * np.pi * f))
        # |e^{-jx} - R22(jx)| = x^5 / 720 to leading order (x = w Td): the 2nd-order Padé error, analytic.
        x = 2 * np.pi * f * TABLE1.Td
        assert abs(pade - exact) / abs(exact) == pytest.approx(x**5 / 720, rel=0.05)


def test_transfer_functions_agree():
    G2 = transfer_function(TABLE1, delay="none")
    f = np.geomspace(0.1, 200.0, 20)
    np.testing.assert_allclose([complex(G2(2j * np.pi * x)) for x in f], frequency_response(TABLE1, f, "motor"),
                               rtol=1e-12, atol=0)
    num, den = coefficients(TABLE1, "pade")
    assert len(num) == 4 and len(den) == 5 and den[0] == 1.0
    num0, _ = coefficients(JointParameters(1.0, 0.0, 1e4, 2.0, 0.004), "pade")
    assert len(num0) == 4 and num0[0] == 0.0  # no damping: the leading coefficient is kept, zero
    assert num[-1] == pytest.approx(pade_coefficients(TABLE1.Td)[1] * TABLE1.K / TABLE1.Jc, rel=1e-12)


def test_resonance_is_the_undamped_pole():
    p = JointParameters(1.03, 0.0, 18500.0, 5.6, 0.005)
    poles = transfer_function(p, delay="none").poles()
    assert np.abs(poles.imag).max() / (2 * np.pi) == pytest.approx(resonance_hz(p.Jc, p.K, p.Jl), rel=1e-12)


def test_vocabulary():
    assert PARAMETER_NAMES == ("Jc", "bc", "K", "Jl", "Td")
    for spec in JOINT_PARAMETERS:
        assert spec.lower <= spec.default <= spec.upper and spec.unit and spec.doc
    table1 = JointParameters(*(spec.default for spec in JOINT_PARAMETERS))
    assert table1 == TABLE1
    assert JointParameters.from_mapping(TABLE1.as_dict()) == TABLE1
    assert parameter_values(TABLE1.as_dict()) == parameter_values(list(parameter_values(TABLE1)))
    assert set(model.__all__) <= set(dir(model))


def test_every_parameter_source_gives_the_same_values():
    """JointParameters, a mapping, a model file's joint model, a sequence and an array name one parameter set."""
    from types import MappingProxyType

    from iiwa_ident.model import ParameterSource, table1_model

    want = parameter_values(TABLE1)
    sources: list[ParameterSource] = [TABLE1, TABLE1.as_dict(), MappingProxyType(TABLE1.as_dict()), table1_model(),
                                      list(want), tuple(want), np.array(want)]
    for source in sources:
        assert parameter_values(source) == want, type(source)
    with pytest.raises(ValueError, match="five parameters"):
        parameter_values(np.array(want)[:4])


@pytest.mark.parametrize("field, value, message", [
    ("Jc", 0.0, "Jc must be positive"), ("K", float("nan"), "K must be positive"),
    ("bc", -1.0, "bc must be non-negative"), ("Td", float("inf"), "Td must be positive"),
])
def test_invalid_parameters(field, value, message):
    values = TABLE1.as_dict() | {field: value}
    with pytest.raises(ParameterError, match=message):
        JointParameters.from_mapping(values)


def test_zero_order_hold_references():
    from iiwa_ident.model import delayed_hold, zoh

    a, b, h = -30.0, 2.0, 1e-3
    Phi, G = zoh(np.array([[a]]), np.array([b]), h)
    np.testing.assert_allclose(Phi, [[np.exp(a * h)]], rtol=1e-14, atol=0)
    np.testing.assert_allclose(G, [(np.exp(a * h) - 1.0) / a * b], rtol=1e-12, atol=0)
    # A pure integrator with a delay of 2.3 samples: u[k-2] acts for 0.7 T, u[k-3] for 0.3 T.
    Phi, G0, G1, d = delayed_hold(np.zeros((1, 1)), np.array([1.0]), 1e-3, 2.3e-3)
    assert d == 2
    np.testing.assert_allclose([Phi[0, 0], G0[0], G1[0]], [1.0, 0.7e-3, 0.3e-3], rtol=1e-9, atol=0)
    # A whole number of samples has no fractional part.
    _, G0, G1, d = delayed_hold(np.zeros((1, 1)), np.array([1.0]), 1e-3, 5e-3)
    assert d == 5 and G1[0] == 0.0 and G0[0] == pytest.approx(1e-3, rel=1e-12)


def test_sampled_model_approaches_eq4_at_low_frequency():
    from iiwa_ident.model import discretize

    f = np.array([0.5, 2.0, 8.0])
    sampled = discretize(TABLE1, 1e-4).frequency_response(f)[0]
    # The hold adds half a sample of delay: T/2 = 50 us, 2.5 mrad at 8 Hz.
    exact = frequency_response(TABLE1, f) * np.exp(-1j * np.pi * f * 1e-4)
    np.testing.assert_allclose(sampled, exact, rtol=1e-5, atol=0)


@pytest.mark.parametrize("kind", ["motor", "link", "deflection", "reaction"])
def test_polynomials_are_the_state_space_model(kind):
    # Each input's numerator over eq (4)'s denominator is C (sI - A)^-1 B of the state-space model, for a
    # random joint (the deflection's direct path -K added; the reaction: a torque on the motor that the loop's
    # damping does not see).
    rng = np.random.default_rng(7)
    p = {"Jc": rng.uniform(0.3, 2.0), "bc": rng.uniform(20, 90), "K": rng.uniform(3e3, 4e4),
         "Jl": rng.uniform(0.3, 20.0), "Td": 0.005}
    A, B, C = model.state_matrices(p, kind)
    num, den = model.polynomials(p, kind)
    for f in rng.uniform(0.1, 300.0, size=5):
        s = 2j * np.pi * f
        ss = C[0] @ np.linalg.solve(s * np.eye(4) - A, B) - (p["K"] if kind == "deflection" else 0.0)  # direct path
        np.testing.assert_allclose(np.polyval(num, s) / np.polyval(den, s), ss, rtol=1e-9, atol=0)
