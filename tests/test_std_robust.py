"""The fit's model-error aware std: equal to the std where the residual is independent of the command, wider by
the two estimators' disagreement where it is not (its coverage is measured by ``bench_robustness.py coverage``)."""

from __future__ import annotations

import math

from iiwa_ident.ident._joint_fit import fit_joint
from iiwa_ident.model import PARAMETER_NAMES
from iiwa_ident.testing import draw_scenario, simulate_scenario

Z95 = 1.959964


def _fit(seed: int, nuisances=None):
    sc = draw_scenario(seed, nuisances=nuisances)
    return sc, fit_joint([simulate_scenario(sc)])


def test_equal_to_std_where_the_model_holds():
    # A joint with none of the effects the model lacks: the residual is independent of the command.
    sc, res = _fit(5, nuisances=[])
    assert not res.model_rejected, [t.summary() for t in res.residual_tests]
    assert res.std_robust == res.std
    doc = res.to_json()
    assert doc["model_rejected"] is False and "equal to std" in doc["std_robust_method"]
    assert all(doc["parameters"][k]["std_robust"] == doc["parameters"][k]["std"] for k in PARAMETER_NAMES)


def test_wider_where_the_residual_follows_the_command():
    # Gravity and a load harmonic on a held link (draw 1 of the robustness benchmark): the residual follows
    # the command; the model-error aware std is the wider and covers every parameter, and the fit says which
    # std to trust.
    sc, res = _fit(1)
    assert res.model_rejected
    for k in PARAMETER_NAMES:
        assert res.std_robust[k] >= res.std[k] > 0
        assert abs(res.parameters[k] - sc.truth[k]) <= Z95 * res.std_robust[k], k
    assert any(res.std_robust[k] > 1.5 * res.std[k] for k in PARAMETER_NAMES)
    doc = res.to_json()
    assert doc["model_rejected"] is True and "difference" in doc["std_robust_method"]
    assert all(math.isfinite(doc["parameters"][k]["std_robust"]) for k in PARAMETER_NAMES)


def test_every_method_gives_it():
    # Eq (4) alone compares with IDIM-IV, IDIM-IV with the output-error fit: each widened where rejected.
    sc = draw_scenario(1)
    ds = simulate_scenario(sc)
    for method, other in (("eq4", "inverse-dynamics"), ("idim", "output-error")):
        res = fit_joint([ds], method=method)
        assert res.model_rejected, method
        assert other in res.std_robust_method, (method, res.std_robust_method)
        assert all(res.std_robust[k] >= res.std[k] > 0 for k in PARAMETER_NAMES), method
