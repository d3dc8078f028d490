"""A filter between the torque sensor and the log in the joint fit: its phase estimate, the torque it hid, the fit.

Each test draws a cut-off and a joint, simulates a chirp whose logged torque passed the filter (the simulator's
``torque_log_filter``, applied after the robot's own loop), and fits the file without looking at the truth.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.datasets import write_dataset
from iiwa_ident.excite import Chirp, record
from iiwa_ident.ident import read_model
from iiwa_ident.ident._joint_fit import fit_joint
from iiwa_ident.ident._log_filter import estimate_log_filter, unfiltered_torque
from iiwa_ident.ident._records import prepare_records
from iiwa_ident.sim import SimulatedJoint, TorqueLogFilter, default_plant, make_effect

TABLE1 = {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}
runner = CliRunner()


def chirp(seed: int, cutoff_hz: float | None, duration_s: float = 15.0, spread: float = 0.3, rate_hz: float = 1000.0):
    """A chirp of a joint drawn within +-``spread`` of Table I (default ripple and noise) at ``rate_hz``, its torque
    logged through a first-order filter at ``cutoff_hz`` (None: unfiltered); and the truth."""
    rng = np.random.default_rng(seed)
    truth = {k: v * rng.uniform(1 - spread, 1 + spread) for k, v in TABLE1.items()}
    plant = default_plant()
    plant.simulation["cycle_s"] = 1.0 / rate_hz
    if cutoff_hz is not None:
        plant = plant.with_effects(make_effect("torque_log_filter", {"cutoff_hz": cutoff_hz}))
    plant.dynamics.update(truth)
    return record(SimulatedJoint(plant, seed=seed), Chirp(duration_s=duration_s)), truth


class TestPhaseEstimate:
    def test_cutoff_from_the_phase_of_tau_j_against_q_m(self):
        rng = np.random.default_rng(7)
        fc = float(np.exp(rng.uniform(np.log(5.0), np.log(50.0))))
        ds, _ = chirp(7, fc, duration_s=10.0)
        est = estimate_log_filter(prepare_records([ds]))
        assert est.shown and est.order == 1 and est.explained > 0.99
        assert est.cutoff_hz == pytest.approx(fc, rel=0.03)

    def test_nothing_shown_without_a_filter(self):
        ds, _ = chirp(8, None, duration_s=10.0)
        assert not estimate_log_filter(prepare_records([ds])).shown


def test_unfiltered_torque_undoes_the_filter_in_the_band():
    # A torque with content up to 150 Hz through a 12 Hz filter, undone up to 200 Hz: the original back
    # (away from the ends, where the even extension differs from the signal's past).
    rng = np.random.default_rng(3)
    T, n = 1e-3, 8000
    t = np.arange(n) * T
    x = sum(rng.normal() * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in rng.uniform(0.5, 150.0, 20))
    lf = TorqueLogFilter({"cutoff_hz": 12.0})
    back = unfiltered_torque(lf.apply(x, T), T, lf, 200.0)
    np.testing.assert_allclose(back[500:-500], x[500:-500], rtol=0, atol=0.02 * np.std(x))


class TestFitThroughTheFilter:
    def test_chirp_logged_through_a_filter_is_fitted(self, tmp_path):
        # The issue's case: a chirp logged through a 8-15 Hz first-order filter was refused ("Jc ... fitted
        # negative"); now K, Jl within 3 %, Td within 0.5 ms, the cut-off within 4 std of its value.
        rng = np.random.default_rng(12)
        fc = float(rng.uniform(8.0, 15.0))
        ds, truth = chirp(12, fc)
        path = tmp_path / "chirp.h5"
        write_dataset(path, ds)
        out, js = tmp_path / "model.toml", tmp_path / "fit.json"
        res = runner.invoke(app, ["fit", str(path), "--out", str(out), "--json", str(js)])
        assert res.exit_code == 0, res.output
        assert "torque_log_filter (the log of tau_j only): one first-order stage" in res.output
        doc = json.loads(js.read_text())
        got = {k: doc["parameters"][k]["value"] for k in truth}
        for k in ("Jc", "bc", "K", "Jl"):
            assert got[k] == pytest.approx(truth[k], rel=0.03), k
        assert got["Td"] == pytest.approx(truth["Td"], abs=0.5e-3)
        lf = doc["log_filter"]
        assert lf["order"] == 1 and abs(lf["cutoff_hz"] - fc) < 4 * lf["std"] + 1e-3 * fc, (lf, fc)
        # The model file carries it, for compare and diagnose to simulate the log as it was.
        effects = {e["name"]: e for e in read_model(out).effects}
        assert effects["torque_log_filter"]["cutoff_hz"] == pytest.approx(lf["cutoff_hz"], rel=1e-12)

    def test_no_filter_where_the_data_do_not_ask(self):
        ds, truth = chirp(13, None, duration_s=10.0)
        result = fit_joint([ds])
        assert result.log_filter is None
        assert result.parameters["K"] == pytest.approx(truth["K"], rel=0.03)

    def test_a_log_faster_than_the_robots_cycle(self, tmp_path):
        # At 2 kHz the search's top (0.45 of the rate) lies above any filter the effect describes: no traceback,
        # the filter found and fitted.
        ds, truth = chirp(15, 12.0, duration_s=6.0, rate_hz=2000.0)
        path, out = tmp_path / "chirp_2khz.h5", tmp_path / "model.toml"
        write_dataset(path, ds)
        res = runner.invoke(app, ["fit", str(path), "--out", str(out)])
        assert res.exit_code == 0, res.output
        lf = next(e for e in read_model(out).effects if e["name"] == "torque_log_filter")
        assert lf["cutoff_hz"] == pytest.approx(12.0, rel=0.02)


def test_the_reports_fit_page_says_the_filter_acts_on_the_log_only():
    from iiwa_ident.report._pdf import _fit_pages

    ds, _ = chirp(16, 10.0, duration_s=6.0)
    result = fit_joint([ds])
    assert result.log_filter is not None
    caption = _fit_pages({"fit": result}, None)[-1].caption
    assert "The logged tau_J passed a filter, one first-order stage at" in caption
    assert "the log only: the robot's torque loop" in caption
