"""CLI: ``iiwa-ident design`` through typer's runner."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.cli._design_cmd import parse_poles
from iiwa_ident.design._design_file import read_design
from iiwa_ident.errors import IiwaIdentError

runner = CliRunner()
TABLE1 = Path(__file__).resolve().parents[1] / "datasets" / "paper-table1.toml"


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("design")
    out, js = tmp / "design.toml", tmp / "design.json"
    res = invoke("design", "--model", TABLE1, "--out", out, "--json", js, "--paper")
    return res, out, js


class TestParsePoles:
    def test_complex_literals(self):
        assert parse_poles("-180+30j, -180-30j,-500+1j,-500-1j", "--poles") == [
            -180 + 30j, -180 - 30j, -500 + 1j, -500 - 1j]
        assert parse_poles("-620,-630.5", "--observer-poles") == [-620.0, -630.5]

    def test_unparsable(self):
        with pytest.raises(IiwaIdentError, match="--poles: cannot read 'abc'"):
            parse_poles("-1,abc", "--poles")


class TestDesignCommand:
    def test_default_run_prints_and_writes(self, default_run):
        res, out, _ = default_run
        assert res.exit_code == 0, res.output
        for text in ("built-in controller poles: -26.7 +- 143.4j", "K_FSF = [2.341e-08", "Kr    = 0.9656",
                     "kappa_max built-in 7.78", "DC gain tau_r -> tau_J on the model: 1.0000",
                     "Section V reproduction", "K_FSF,4", f"wrote {out}"):
            assert text in res.output, text
        assert read_design(out).design.feedforward == "reference"

    def test_every_printed_gain_is_its_value(self, default_run):
        # Four decimals printed any gain below 5e-5 as 0.0000; the default form's Kr_d is 0 by design, and says so.
        import re

        res, out, _ = default_run
        design = read_design(out).design
        assert design.Kr_d == 0.0 and "Kr_d = 0 (the reference reaches the feedback through the model's y_ref" \
            in res.output
        assert float(re.search(r"Kr    = (\S+)", res.output).group(1)) == pytest.approx(design.Kr, rel=1e-3)
        assert "0.0000" not in res.output

    def test_json_keys(self, default_run):
        res, _, js = default_run
        data = json.loads(js.read_text())
        for key in ("builtin_poles", "K_fsf", "L", "Kr", "poles", "observer_poles", "kappa_max"):
            assert key in data
        np.testing.assert_allclose(data["builtin_poles"], [[-26.699, 143.359], [-26.699, -143.359]],
                                   rtol=0, atol=1e-3)
        np.testing.assert_allclose(data["L"], [3.843e11, 1.996e9, 3.346e6, 2.005e3], rtol=5e-3, atol=0)
        assert len(data["K_fsf"]) == 4 and data["Kr"] == pytest.approx(0.9656, abs=1e-4)
        assert data["poles"] == [[-180.0, 30.0], [-180.0, -30.0], [-500.0, 1.0], [-500.0, -1.0]]
        assert data["observer_poles"] == [[-620.0, 0.0], [-630.0, 0.0], [-1000.0, 0.0], [-1010.0, 0.0]]
        k = data["kappa_max"]
        assert set(k) == {"builtin", "additive"} and k["additive"] > k["builtin"] > 0

    def test_custom_poles_and_mode(self, tmp_path):
        out, js = tmp_path / "d.toml", tmp_path / "d.json"
        res = invoke("design", "--model", TABLE1, "--poles=-150+20j,-150-20j,-400,-450",
                     "--observer-poles", "-700,-700,-900,-900", "--feedforward", "none",
                     "--arm-damping", "60", "--out", out, "--json", js)
        assert res.exit_code == 0, res.output
        data = json.loads(js.read_text())
        assert data["poles"] == [[-150.0, 20.0], [-150.0, -20.0], [-400.0, 0.0], [-450.0, 0.0]]
        assert data["feedforward"] == "none" and data["arm"]["damping"] == 60.0
        assert "Section V reproduction" not in res.output

    @pytest.mark.parametrize("args, message", [
        (("--poles=-180+30j,-180-30j,-500",), "--poles: expected 4 poles, got 3"),
        (("--poles=-180+30j,-180-30j,-500,20",), "--poles: 20 is not stable"),
        (("--poles=-180+30j,-180-31j,-500,-600",), "--poles: -180+30j has no conjugate partner"),
        (("--poles=-180+30j,-180-30j,-500,x1",), "--poles: cannot read 'x1'"),
        (("--observer-poles=-620,-630,-1000",), "--observer-poles: expected 4 poles"),
        (("--observer-poles=-620,-630,-1000,0",), "--observer-poles: 0 is not stable"),
        (("--feedforward", "twice"), "feedforward must be one of"),
        (("--arm-stiffness", "-5"), "arm stiffness must be positive"),
    ])
    def test_bad_input_is_one_line_error(self, tmp_path, args, message):
        out = tmp_path / "d.toml"
        res = invoke("design", "--model", TABLE1, *args, "--out", out)
        assert res.exit_code == 2
        assert message in res.output
        assert "Traceback" not in res.output
        assert len([ln for ln in res.output.splitlines() if ln.startswith("error:")]) == 1
        assert not out.exists()

    def test_missing_model(self, tmp_path):
        res = invoke("design", "--model", tmp_path / "none.toml", "--out", tmp_path / "d.toml")
        assert res.exit_code == 2
        assert "none.toml: no such file" in res.output

    def test_unstable_with_exact_delay_warns(self, tmp_path):
        res = invoke("design", "--model", TABLE1, "--poles=-300+30j,-300-30j,-800,-900",
                     "--observer-poles=-1500,-1600,-1700,-1800", "--out", tmp_path / "d.toml")
        assert res.exit_code == 0, res.output
        assert "UNSTABLE" in res.output and "warning:" in res.output
