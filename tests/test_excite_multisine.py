"""Random-phase odd multisines and the multisine experiment."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.datasets import read_dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import Multisine, record
from iiwa_ident.references import crest_factor, odd_lines, odd_multisine
from iiwa_ident.sim import SimulatedJoint, default_plant


class TestOddMultisine:
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_power_only_on_the_excited_odd_lines_flat(self, seed):
        n = 2000
        lines = odd_lines(n, 1000.0, 1.0, 100.0)
        assert np.all(lines % 2 == 1) and lines[0] == 3 and lines[-1] == 199  # 1.5 ... 99.5 Hz at 0.5 Hz
        x = odd_multisine(n, lines, np.random.default_rng(seed))
        X = np.abs(np.fft.rfft(x))
        np.testing.assert_allclose(X[lines], X[lines].mean(), rtol=1e-9)
        others = np.setdiff1d(np.arange(len(X)), lines)
        assert X[others].max() <= 1e-9 * X[lines].max()
        assert np.max(np.abs(x)) == pytest.approx(1.0, abs=1e-12)

    def test_crest_factor_reduced(self):
        n = 2000
        lines = odd_lines(n, 1000.0, 1.0, 100.0)
        plain = [crest_factor(odd_multisine(n, lines, np.random.default_rng(s), crest_iterations=0))
                 for s in range(5)]
        clipped = [crest_factor(odd_multisine(n, lines, np.random.default_rng(s))) for s in range(5)]
        assert max(clipped) < 2.0 < min(plain)

    def test_no_line_in_the_band_refused(self):
        with pytest.raises(IiwaIdentError, match="no line in the band"):
            odd_multisine(100, np.array([], int), np.random.default_rng(0))


class TestMultisineExperiment:
    def test_runs_periods_times_realisations_and_records_the_design(self):
        # Without the hold the command is exactly bias + A x_m(t) (no bias either: a free link would drift).
        exp = Multisine(2.0, 50.0, period_s=0.5, periods=2, realisations=3, amplitude_nm=8.0, bias_nm=0.0,
                        hold_stiffness=0.0, hold_damping=0.0, seed=4, lead_in_s=0.25, transient_periods=1)
        ds = record(SimulatedJoint(default_plant(), seed=1), exp)
        a = ds.experiment_attrs
        assert ds.experiment == "multisine" and ds.n_samples == 250 + 3 * 3 * 500 and a["lead_in_s"] == 0.25
        assert (a["period_s"], a["periods"], a["realisations"], a["transient_periods"]) == (0.5, 2, 3, 1)
        lines, x = exp.design(1e-3)
        np.testing.assert_array_equal(a["excited_lines"], lines)
        assert a["crest_factor"] == pytest.approx(max(crest_factor(s) for s in x))
        assert np.all(ds["tau_c"][:250] == 0.0)  # the lead-in: no bias to ramp in, no hold
        u = ds["tau_c"][250:].reshape(3, 3, 500)  # realisation, period (the first is the transient one), sample
        for m in range(3):
            for p in range(3):
                np.testing.assert_allclose(u[m, p], 8.0 * x[m], rtol=0, atol=1e-12)
        # New phases in each realisation.
        assert abs(np.corrcoef(x[0], x[1])[0, 1]) < 0.2

    def test_lead_in_ramps_the_bias_in_smoothly(self):
        exp = Multisine(2.0, 50.0, period_s=0.5, amplitude_nm=8.0, bias_nm=4.0, hold_stiffness=0.0,
                        hold_damping=0.0, lead_in_s=1.0)
        u = record(SimulatedJoint(default_plant(), seed=1), exp)["tau_c"][:1000]
        assert u[0] == 0.0 and np.all(np.diff(u) >= 0) and np.all(u[600:] == 4.0)
        assert np.abs(np.diff(u)).max() < 4.0 * np.pi / 2 / 600 * 1.001  # raised cosine over 0.6 s

    @pytest.mark.parametrize("kw, message", [
        ({"periods": 1}, "at least 2 periods and 2 realisations"),
        ({"realisations": 1}, "at least 2 periods and 2 realisations"),
        ({"f_lo_hz": 50.0, "f_hi_hz": 10.0}, "need 0 < f_lo < f_hi"),
        ({"amplitude_nm": 0.0}, "amplitude must be positive"),
        ({"lead_in_s": -1.0}, "lead-in must be a non-negative time"),
        ({"transient_periods": 0}, "at least 1 transient period"),
    ])
    def test_bad_settings(self, kw, message):
        with pytest.raises(IiwaIdentError, match=message):
            Multisine(**kw)

    @pytest.mark.parametrize("kw, message", [
        ({"period_s": 0.004}, "fewer than 2 odd lines"),
        ({"period_s": 0.0125}, "not a whole number of 1 ms cycles"),
        ({"f_hi_hz": 600.0}, "below the Nyquist frequency"),
        ({"amplitude_nm": 400.0}, "exceeds the joint's torque limit"),
    ])
    def test_refused_before_commanding(self, kw, message):
        with pytest.raises(IiwaIdentError, match=message):
            record(SimulatedJoint(default_plant()), Multisine(**kw))


runner = CliRunner()


def test_cli_simulate_multisine(tmp_path):
    out = tmp_path / "ms.h5"
    res = runner.invoke(app, ["simulate", "multisine", "--band", "2,40", "--period", "0.5", "--periods", "2",
                              "--realisations", "2", "--amplitude", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    ds = read_dataset(out)
    # The default 6 s lead-in, and 4 s of transient periods in each realisation.
    assert ds.experiment == "multisine" and ds.n_samples == 6000 + 2 * (8 + 2) * 500
    assert ds.experiment_attrs["transient_periods"] == 8
    assert ds.experiment_attrs["amplitude_nm"] == 5.0
    res = runner.invoke(app, ["simulate", "multisine", "--band", "2,40", "--period", "0.5", "--periods", "2",
                              "--realisations", "2", "--transient-periods", "3", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert read_dataset(out).n_samples == 6000 + 2 * (3 + 2) * 500


@pytest.mark.parametrize("args, message", [
    (["--band", "2"], "--band expects F_LO,F_HI"),
    (["--periods", "1"], "at least 2 periods"),
    (["--transient-periods", "0"], "at least 1 transient period"),
])
def test_cli_bad_multisine_options(tmp_path, args, message):
    res = runner.invoke(app, ["simulate", "multisine", "--out", str(tmp_path / "x.h5"), *args])
    assert res.exit_code == 2 and message in res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "x.h5").exists()
