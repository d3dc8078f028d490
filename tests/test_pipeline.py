"""The whole pipeline end to end on a short configuration, and its failure handling.

The 60 s budget of the full run on the default plant is measured by
``bench/bench_pipeline.py``, not asserted here: this machine is shared.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import assert_not_blank, figures_agree, pdf_pages
from iiwa_ident.deploy import read_config
from iiwa_ident.design import read_design
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.pipeline import FILES, STAGES, ValidationSettings, run_pipeline, run_validation
from iiwa_ident.report._pdf import build_report
from iiwa_ident.runtime import SweepSettings

CLI = [str(Path(sys.executable).with_name("iiwa-ident"))]


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("pipeline")
    lines: list[str] = []
    result = run_pipeline(workdir, target="sim", short=True, progress=lines.append, report=build_report)
    return workdir, result, lines


class TestShortPipeline:
    def test_every_stage_ran(self, short_run):
        _, result, lines = short_run
        assert [s.name for s in result.stages] == [s.name for s in STAGES] + ["report"]
        failed = {s.name: s.error for s in result.stages if s.status != "ok"}
        assert not failed, failed
        assert result.ok
        # One progress line when a stage starts and one when it ends.
        for stage in STAGES:
            assert any(line.startswith("[") and f"] {stage.name}: ok in" in line for line in lines), stage.name

    def test_every_intermediate_file_is_in_the_folder(self, short_run):
        workdir, _, _ = short_run
        for key in ("chirp", "model", "fit_json", "cv", "hand", "model_ripple", "ripple_json", "design",
                    "design_json", "observers_json", "controller", "controller_json", "validation_json",
                    "diagnose_json", "model_ext", "pipeline_json", "report"):
            assert (workdir / FILES[key]).is_file(), FILES[key]
        logs = sorted(p.name for p in (workdir / "validation").glob("*.h5"))
        assert logs == ["additive_sine.h5", "additive_step.h5", "builtin_sine.h5", "builtin_step.h5",
                        "kappa_additive_ft.h5", "kappa_builtin_ft.h5"]

    def test_the_diagnosis_of_the_simulated_joint_names_nothing(self, short_run):
        # The default plant's only effect is the ripple, which the ripple stage put into the model.
        workdir, _, _ = short_run
        doc = json.loads((workdir / FILES["diagnose_json"]).read_text())
        assert doc["effects"] == [] and doc["replaced"] == [] and doc["ambiguous"] == [] and doc["undecided"] == []

    def test_summary_says_what_the_diagnosis_replaced(self, tmp_path):
        from iiwa_ident.pipeline._core import PipelineResult, format_summary

        h = {"named_effects": [{"name": "position_dependent_load", "gain_pct": 98.0, "confidence": 1.0}],
             "model_explained": False, "ambiguous_effects": [],
             "replaced_effects": [{"old": "torque_sensor_offset", "new": ["position_dependent_load"]}],
             "undecided_effects": [{"name": "torque_sensor_offset", "or_shape_of": "position_dependent_load"}]}
        text = format_summary(PipelineResult(tmp_path, [], h, None, 1.0))
        assert ("diagnosis: the model's torque_sensor_offset contradicted by the data, replaced by "
                "position_dependent_load") in text
        assert "position_dependent_load named, held-out residual 98.0 % lower" in text
        assert ("diagnosis: torque_sensor_offset kept, but another shape of position_dependent_load predicts the "
                "data as well") in text

    def test_pipeline_json_has_the_stages_and_headline(self, short_run):
        workdir, result, _ = short_run
        doc = json.loads((workdir / "pipeline.json").read_text())
        assert doc["format"] == "iiwa-ident-pipeline" and doc["ok"]
        assert {s["name"]: s["status"] for s in doc["stages"]} == {s.name: "ok" for s in result.stages}
        assert all(s["duration_s"] > 0 for s in doc["stages"])
        h = doc["headline"]
        for key in ("fit", "ripple_period_rad", "kappa_linear", "observer_improvement", "tracking", "kappa_live",
                    "named_effects", "replaced_effects", "undecided_effects"):
            assert key in h, key
        # Short experiments still identify the default plant closely.
        assert abs(h["ripple_period_rad"] - 0.01963) < 1e-4
        assert all(abs(v["error_pct"]) < 5 for v in h["fit"].values()), h["fit"]
        assert h["kappa_linear"]["ratio"] > 2
        # The live margins through FRI (F/T source): the paper's ratio, each predicted by the loop as deployed.
        live = h["kappa_live"]["ft"]
        assert live["ratio_live"] >= 3.0, live
        for loop in ("builtin", "additive"):
            assert abs(live[loop]["linear_error_pct"]) <= 15.0, live
        assert h["observer_improvement"] > 1.5
        assert set(h["tracking"]) == {"step", "sine"}

    def test_validation_figures_repeat_exactly(self, short_run, tmp_path):
        """In lockstep the closed-loop figures do not depend on the machine: a second run gives the same."""
        workdir, _, _ = short_run
        first = json.loads((workdir / "validation.json").read_text())
        assert first["clock"] == "lockstep"
        settings = dict(first["settings"])
        settings["kappa"] = SweepSettings(**{k: tuple(v) if isinstance(v, list) else v
                                             for k, v in settings["kappa"].items()})
        # The sweeps' repeatability is test_kappa's; here the four tracking runs.
        settings["kappa_sources"] = ()
        again = run_validation(read_config(workdir / "controller.toml"), tmp_path,
                               kappa_margins=(first["kappa"]["linear_builtin"], first["kappa"]["linear_additive"]),
                               delay_s=first["delay_s"], settings=ValidationSettings(**settings),
                               record=read_design(workdir / "design.toml"))
        again = json.loads(json.dumps(again))  # as written: tuples become lists
        for key in ("runs", "tracking"):
            assert again[key] == first[key], key
        assert again["emulator"] == first["emulator"][:len(again["emulator"])]

    def test_report_has_every_page(self, short_run):
        workdir, result, _ = short_run
        pages = next(s for s in result.stages if s.name == "report").headline["pages"]
        assert pdf_pages(workdir / "report.pdf") == pages
        # The count the README states, plus the pages a diagnosis that names effects adds.
        import re

        readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
        stated = int(re.search(r"`make demo`'s report has (\d+) pages when the diagnosis names nothing", readme)[1])
        diag = next(s for s in result.stages if s.name == "diagnose").headline
        extra = len(diag["channels"]) + len(diag["effects"]) if diag["effects"] or diag["replaced"] else 0
        assert pages == stated + extra

    def test_validation_pages_render(self, short_run, tmp_path):
        from iiwa_ident.report._pdf import build_report

        workdir, _, _ = short_run
        titles = build_report(tmp_path / "v.pdf", workdir, stage="validation", png_dir=tmp_path / "png")
        assert len(titles) == 5 and not any("not drawn" in t for t in titles), titles
        for png in sorted((tmp_path / "png").glob("*.png")):
            assert_not_blank(png)


class TestFailures:
    def test_a_failed_stage_skips_its_dependents_and_the_report_says_so(self, tmp_path, monkeypatch):
        ripple = next(s for s in STAGES if s.name == "ripple")

        def broken(ctx):
            raise IiwaIdentError("no periodic nonlinearity found in constant_velocity.h5")

        monkeypatch.setattr(ripple, "run", broken)
        # Skip what would run long anyway; the point is the bookkeeping.
        result = run_pipeline(tmp_path, short=True, progress=lambda _m: None, skip=("hand_guided",),
                              report=build_report)
        status = {s.name: s.status for s in result.stages}
        assert status["ripple"] == "failed" and status["hand_guided"] == "skipped"
        assert status["chirp"] == status["fit"] == status["constant_velocity"] == "ok"
        for name in ("design", "deploy", "validation", "diagnose"):
            assert status[name] == "skipped", name
        assert "ripple" in next(s for s in result.stages if s.name == "design").error
        assert status["report"] == "ok" and (tmp_path / "report.pdf").is_file()
        doc = json.loads((tmp_path / "pipeline.json").read_text())
        assert not doc["ok"]
        assert next(s for s in doc["stages"] if s["name"] == "ripple")["error"].startswith("no periodic")

    def test_arguments_are_checked_before_anything_runs(self, tmp_path):
        with pytest.raises(IiwaIdentError, match="--target"):
            run_pipeline(tmp_path / "a", target="moon")
        with pytest.raises(IiwaIdentError, match="--robot"):
            run_pipeline(tmp_path / "b", target="robot")
        with pytest.raises(IiwaIdentError, match="unknown stage"):
            run_pipeline(tmp_path / "c", skip=("nothing",))
        with pytest.raises(IiwaIdentError, match="--realtime only applies to --target sim"):
            run_pipeline(tmp_path / "d", target="robot", robot="192.170.10.2", realtime=True)
        assert not (tmp_path / "a").exists()

    def test_cli_errors_are_one_line(self, tmp_path):
        bad = tmp_path / "plant.toml"
        bad.write_text("[dynamics]\nJc = -1\n")
        proc = subprocess.run(CLI + ["pipeline", "--workdir", str(tmp_path / "w"), "--plant", str(bad)],
                              capture_output=True, text=True)
        assert proc.returncode == 2
        assert proc.stderr.startswith("error: ") and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert "Traceback" not in proc.stderr



def test_a_validation_figure_shown_twice_is_the_same_figure(short_run):
    # Page 1's rows of the closed-loop runs against the pages that draw them: the step's overshoots, the
    # sine's peak errors, the live kappa margins, the design's section V.C margins, the observer's RMS.
    import re

    import pypdf

    workdir = short_run[0]
    pages = [" ".join(p.extract_text().split()) for p in pypdf.PdfReader(workdir / "report.pdf").pages]
    first, later = pages[0], " ".join(pages[1:])

    def pair(pattern: str, text: str = first) -> tuple[str, str]:
        m = re.search(pattern, text)
        assert m, (pattern, text[:300])
        return m.groups()

    add, builtin = pair(r"step overshoot ([\d.]+) % additive, ([\d.]+) % built-in")
    assert (builtin, add) == pair(r"built-in \(tau_c = tau_r\): .*? overshoot ([\d.]+) % .*?additive, eqs "
                                  r"\(16\)-\(18\): .*? overshoot ([\d.]+) %", later)
    add, builtin = pair(r"sine [\d.]+ Hz peak error ([\d.]+) Nm additive, ([\d.]+) Nm built-in")
    b2, a2 = pair(r"built-in \(tau_c = tau_r\): peak error ([\d.]+) Nm, RMS [\d.]+ Nm tau_r.*?additive, eqs "
                  r"\(16\)-\(18\): peak error ([\d.]+) Nm, RMS [\d.]+ Nm tau_r shifted by Td = [\d.]+ ms tau_J "
                  r"measured tau_J,filt, eq \(15\) [\d. −]+ time since the start of the run \[s\] [−\d. ]+joint "
                  r"torque \[Nm\] zoom on the last", later)
    assert figures_agree(add, a2) and figures_agree(builtin, b2), (add, a2, builtin, b2)
    builtin, add = pair(r"kappa live, F/T stable to ([\d.]+) built-in, ([\d.]+) additive")
    b2, a2 = pair(r"built-in \(tau_c = tau_r\), tau_ext from ft: stable to kappa ([\d.]+).*?additive, eqs "
                  r"\(16\)-\(18\), tau_ext from ft: stable to kappa ([\d.]+)", later)
    assert figures_agree(add, a2) and figures_agree(builtin, b2), (add, a2, builtin, b2)
    add, builtin = pair(r"design kappa margin \(linear, section V.C's model\) ([\d.]+) additive / ([\d.]+) built-in")
    b2, a2 = pair(r"built-in section V.C model ([\d.]+) additive section V.C model ([\d.]+)", later)
    assert figures_agree(add, a2) and figures_agree(builtin, b2), (add, a2, builtin, b2)
    improved, builtin = pair(r"observer improved ([\d.]+) Nm against built-in ([\d.]+) Nm RMS")
    b2, i2 = pair(r"lagged ref: all \|v\|>0.5 built-in \(motor velocity\) [\d.]+ [\d.]+ [\d.]+ ([\d.]+) link "
                  r"velocity, eq \(9\) [\d.]+ [\d.]+ [\d.]+ ([\d.]+)", later)
    assert figures_agree(improved, i2) and figures_agree(builtin, b2), (improved, i2, builtin, b2)
