"""The PDF report: every page renders, failed stages get a page saying what failed, the CLI.

The work folder comes from a short pipeline run without the closed-loop
validation (``tests/test_pipeline.py`` renders those pages); the report is
then rebuilt from the files alone, as ``iiwa-ident report`` does.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_diagnosis_shown_alike, assert_not_blank, figures_agree, pdf_pages
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.pipeline import run_pipeline
from iiwa_ident.report._pdf import REPORT_STAGES, build_report, load_results, report_pages

CLI = [str(Path(sys.executable).with_name("iiwa-ident"))]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report")
    result = run_pipeline(folder, short=True, progress=lambda _m: None, skip=("validation",), report=None)
    assert result.ok, [(s.name, s.error) for s in result.stages if s.status == "failed"]
    return folder


class TestEveryPageRenders:
    def test_from_the_files_of_a_work_folder(self, workdir, tmp_path):
        out = tmp_path / "report.pdf"
        titles = build_report(out, workdir, png_dir=tmp_path / "png", png_dpi=30)
        assert not any("not drawn" in t for t in titles), titles
        assert pdf_pages(out) == len(titles)
        pngs = sorted((tmp_path / "png").glob("page_*.png"))
        assert len(pngs) == len(titles)
        for png in pngs:
            assert_not_blank(png)
        expected = ["Verdict", "Appendix: inputs, stages and files (sha256)", "Bode plot of tau_c -> tau_J", "Harmonic distortion", "Fitted model against the chirp",
                    "Parameter table",
                    "Spatial spectrum", "Lookup tables (like Fig. 6)", "Spatial filter at several speeds (like Fig. 4)",
                    "External-torque observers (like Fig. 7)", "Pole map", "Paper reproduction table",
                    "validation: skipped", "Named effects and gains"]
        for title in expected:
            assert title in titles, title
        # Residual pages (before and after) only where the diagnosis changed the model.
        diag = next(s for s in json.loads((workdir / "pipeline.json").read_text())["stages"]
                    if s["name"] == "diagnose")["headline"]
        changed = bool(diag["effects"] or diag["replaced"])
        assert any(t.startswith("Residuals before and after") for t in titles) == changed

    def test_every_figure_has_a_caption_and_labelled_axes(self, workdir):
        doc = json.loads((workdir / "pipeline.json").read_text())
        results = load_results(workdir, doc, ("fit", "ripple"))
        import matplotlib.pyplot as plt

        for page in report_pages(workdir, doc, results):
            if page.stage not in ("fit", "ripple") or not page.captioned:
                continue
            assert len(page.caption) > 60 and "Look" in page.caption, page.title
            fig = page.draw()
            plotted = [ax for ax in fig.axes if ax.has_data() and ax.axison and ax.get_label() != "<colorbar>"]
            for ax in plotted:
                assert ax.get_xlabel() or ax.get_ylabel(), (page.title, ax.get_title())
            plt.close(fig)

    def test_one_stage(self, workdir, tmp_path):
        titles = build_report(tmp_path / "ripple.pdf", workdir, stage="ripple")
        assert titles[0] == "Verdict" and titles[-1].startswith("Appendix") and len(titles) == 5
        assert all(("ripple" in t.lower() or "spectrum" in t.lower() or "lookup" in t.lower() or "eq (6)" in t)
                   for t in titles[1:-1]), titles


class TestFailedStages:
    def test_a_failed_stage_page_says_what_failed(self, workdir, tmp_path):
        broken = tmp_path / "broken"
        shutil.copytree(workdir, broken)
        doc = json.loads((broken / "pipeline.json").read_text())
        message = "no periodic nonlinearity: the strongest line has false-alarm probability 0.31"
        for s in doc["stages"]:
            if s["name"] == "ripple":
                s["status"], s["error"] = "failed", message
            elif s["name"] in ("design", "deploy", "diagnose"):
                s["status"], s["error"] = "skipped", "skipped: needs ripple, which did not succeed"
        (broken / "pipeline.json").write_text(json.dumps(doc))
        pages = report_pages(broken, doc, load_results(broken, doc))
        by_stage = {p.stage: p for p in pages if p.title.endswith(("failed", "skipped"))}
        assert set(by_stage) == {"ripple", "design", "validation", "diagnose"}
        fig = by_stage["ripple"].draw()
        texts = " ".join(t.get_text() for t in fig.texts)
        assert "Stage 'ripple' failed" in texts and "false-alarm probability 0.31" in texts
        assert fig.axes == [], "a failed stage must not draw empty axes"
        titles = build_report(broken / "report.pdf", broken, png_dir=tmp_path / "png", png_dpi=30)
        assert "ripple: failed" in titles and "design: skipped" in titles
        for png in sorted((tmp_path / "png").glob("*.png")):
            assert_not_blank(png)

    def test_a_folder_without_results_is_refused(self, tmp_path):
        (tmp_path / "empty").mkdir()
        with pytest.raises(IiwaIdentError, match="empty: no pipeline results"):
            build_report(tmp_path / "r.pdf", tmp_path / "empty")
        assert not (tmp_path / "r.pdf").exists()

    def test_missing_files_are_named(self, workdir, tmp_path):
        # A folder whose pipeline.json names stages whose files are gone: each such stage says so.
        gone = tmp_path / "gone"
        gone.mkdir()
        shutil.copy(workdir / "pipeline.json", gone / "pipeline.json")
        titles = build_report(tmp_path / "r.pdf", gone)
        assert titles[0] == "Verdict" and titles[-1].startswith("Appendix")
        assert len(titles) == 2 + len(REPORT_STAGES)
        assert all(t.endswith(("missing", "skipped")) for t in titles[1:-1]), titles


class TestCli:
    def test_report_command(self, workdir, tmp_path):
        out = tmp_path / "fit.pdf"
        proc = subprocess.run(CLI + ["report", "--workdir", str(workdir), "--stage", "fit", "--out", str(out)],
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        assert "page  1: Verdict" in proc.stdout and f"wrote {out}" in proc.stdout
        assert pdf_pages(out) == 6  # verdict, Bode, harmonics, the model against the chirp, parameters, appendix

    def test_errors_are_one_line(self, tmp_path):
        proc = subprocess.run(CLI + ["report", "--workdir", str(tmp_path / "nowhere")], capture_output=True, text=True)
        assert proc.returncode == 2
        assert proc.stderr == f"error: {tmp_path / 'nowhere'}: no such folder\n", proc.stderr
        with pytest.raises(IiwaIdentError, match="--stage nope: expected one of fit, ripple"):
            build_report(tmp_path / "r.pdf", tmp_path, stage="nope")


class TestVerdictPage:
    def test_page_one_holds_the_verdict_of_every_stage(self, workdir, tmp_path):
        # Extracted from the PDF as a reader sees it: the banner, one row per stage with its figure from
        # pipeline.json and its verdict, the page index, page numbers; the sha256 in the appendix.
        import pypdf

        from iiwa_ident.report._verdict import verdict_rows

        out = tmp_path / "report.pdf"
        titles = build_report(out, workdir)
        pages = pypdf.PdfReader(out).pages
        assert len(pages) == len(titles)
        first = pages[0].extract_text()
        doc = json.loads((workdir / "pipeline.json").read_text())
        assert "iiwa-ident report" in first and "SIMULATED: " in first and f"page 1 of {len(pages)}" in first
        rows = verdict_rows(doc)
        assert {r.stage for r in rows} >= {"fit", "ripple", "design", "deploy", "diagnose", "validation"}
        flat = " ".join(first.split())
        for r in rows:
            assert " ".join(f"{r.stage} {r.figure.split()[0]}".split()) in flat, r
            assert r.verdict in ("PASS", "WARN", "FAIL", "SKIPPED")
        ripple = next(s for s in doc["stages"] if s["name"] == "ripple")["headline"]
        assert f"rho = {ripple['period_rad']:.6f} rad" in flat
        import textwrap

        for i, title in enumerate(titles, 1):  # the index (long titles shortened)
            assert f"{i} {textwrap.shorten(title, 44, placeholder='...')}" in flat, title
        assert f"page {len(pages)} of {len(pages)}" in pages[-1].extract_text()
        import re

        digest = re.compile(r"\b[0-9a-f]{64}\b")  # the hashes live in the appendix, not on page 1
        assert digest.search(pages[-1].extract_text()) and not digest.search(first)

    def test_the_verdicts_follow_the_data(self, workdir):
        # The same run as if another plant had made it: every row is computed from pipeline.json, none typed.
        from iiwa_ident.report._verdict import verdict_rows

        doc = json.loads((workdir / "pipeline.json").read_text())
        by = {s["name"]: s for s in doc["stages"]}
        by["ripple"]["headline"]["period_rad"] = 0.025
        design = by["design"]["headline"]
        design.update(kappa_max_builtin=10.0, kappa_max_additive=15.0, kappa_ratio=1.5)
        design["observer"].update(improved_rms_nm=2.0 * design["observer"]["builtin_rms_nm"], improvement=0.5)
        by["fit"]["headline"]["parameters"]["K"].update(error_std=-9.0, error_pct=-1.0)
        rows = {r.stage: r for r in verdict_rows(doc)}
        assert rows["ripple"].verdict == "WARN" and f"{100 * (0.025 / 0.01963 - 1):+.3f} % from the paper" in rows["ripple"].figure
        by["ripple"]["headline"]["period_rad"] = 2 * 0.01963 * 1.001   # the once-per-motor-revolution family
        row = next(r for r in verdict_rows(doc) if r.stage == "ripple")
        assert row.verdict == "WARN" and "2 x the paper's (+0.10 %): its harmonic 2 is the paper's line" in row.figure
        by["ripple"]["headline"]["period_rad"] = 0.025
        assert rows["design"].verdict == "WARN" and "= 1.50x" in rows["design"].figure
        assert rows["observer"].verdict == "FAIL" and "(0.50x)" in rows["observer"].figure
        assert rows["fit"].verdict == "FAIL" and "worst K at 9.0 std" in rows["fit"].figure
        by["fit"]["status"], by["fit"]["error"] = "failed", "no coherent band"
        rows = verdict_rows(doc)
        assert any(r.stage == "fit" and r.verdict == "FAIL" and "no coherent band" in r.figure for r in rows)

    def test_the_captions_follow_the_data(self, workdir):
        # The parameter table's caption says what the ripple's table moves, from pipeline.json; the spatial
        # filter's says the design's beta, from the design file: change the data and the captions follow.
        doc = json.loads((workdir / "pipeline.json").read_text())
        results = load_results(workdir, doc, ("fit", "ripple", "design"))

        def captions(d):
            return {p.title: p.caption for p in report_pages(workdir, d, results)}

        fit = next(s for s in doc["stages"] if s["name"] == "fit")["headline"]["parameters"]
        refit = next(s for s in doc["stages"] if s["name"] == "ripple")["headline"]["refit"]["parameters"]
        shift = 100 * (refit["K"]["value"] / fit["K"]["value"] - 1)
        assert f"moves K by {shift:+.2g} %" in captions(doc)["Parameter table"]
        refit["K"]["value"] = fit["K"]["value"] * 0.98
        assert "moves K by -2 %" in captions(doc)["Parameter table"]
        beta = results["design"].filter.beta
        assert f"(beta = {beta:g})" in captions(doc)["Spatial filter at several speeds (like Fig. 4)"]
        import dataclasses

        rec = results["design"]
        results["design"] = dataclasses.replace(rec, filter=dataclasses.replace(rec.filter, beta=beta + 3.0))
        assert f"(beta = {beta + 3.0:g})" in captions(doc)["Spatial filter at several speeds (like Fig. 4)"]


def test_the_spatial_spectrum_says_which_line_is_the_tallest():
    # The note read "look for one sharp line" on pages whose detected period was not the tallest line.
    from types import SimpleNamespace

    from iiwa_ident.report._ripple_figures import _spectrum_note

    period = np.array([0.0049, 0.0098, 0.0196, 0.04])
    tallest_there = SimpleNamespace(detected=True, period_rad=0.0196, spectrum_stat=np.array([1.0, 2.0, 9.0, 1.0]))
    assert _spectrum_note(tallest_there, period).startswith("The tallest line is at the detected period")
    harmonic = SimpleNamespace(detected=True, period_rad=0.0196, spectrum_stat=np.array([1.0, 9.0, 4.0, 1.0]))
    assert _spectrum_note(harmonic, period).startswith("The tallest line stands at 0.00980 rad, 2.00 times shorter")
    assert _spectrum_note(SimpleNamespace(detected=False), period).startswith("No line stands out")


def test_page_one_and_the_fit_page_say_one_thing_of_the_residual(workdir):
    # Page 1 read "residual independent of the command" from the fit's own residual (the ripple's harmonics
    # fitted alongside) while the fit page ran model.toml, which holds no table: 93.6 %, independence FAILED.
    from iiwa_ident.diagnose import compare
    from iiwa_ident.diagnose._channels import INDEPENDENCE
    from iiwa_ident.report._pdf import _compared_model
    from iiwa_ident.report._verdict import verdict_rows

    doc = json.loads((workdir / "pipeline.json").read_text())
    results = load_results(workdir, doc, ("fit", "ripple"))
    model, said = _compared_model(results)
    assert said.startswith("model_ripple.toml") and model.ripple is not None
    (row,) = [c for c in compare([results["chirp"]], model) if c.channel == "command"]
    independent = next(t for t in row.tests.tests if t.name == INDEPENDENCE).passed
    rows = {r.stage: r for r in verdict_rows(doc)}
    for stage in ("fit", "fit with table"):
        claims = "independent of the command" in rows[stage].figure
        assert claims == independent, (stage, rows[stage].figure, row.tests.summary())
    assert "(the ripple's harmonics fitted alongside)" in rows["fit"].figure
    titles = [p.title for p in report_pages(workdir, doc, results, "fit")]
    page = next(p for p in report_pages(workdir, doc, results, "fit") if p.title == "Fitted model against the chirp")
    assert page.caption.startswith("model_ripple.toml (the joint's parameters refitted"), titles


def test_a_channel_said_explained_is_not_shown_failing_alone(workdir):
    # The diagnosis page's title said "model explains the data" above a channel "FAIL / FAIL": a channel
    # explained at the sensor's noise now says so beside its verdict.
    from iiwa_ident.report._diagnose_figures import gain_table_figure

    doc = json.loads((workdir / "pipeline.json").read_text())
    d = load_results(workdir, doc, ("diagnose",))["diagnosis"]
    at_noise = [c for c in d.channels if c.after is not None and c.after.passed is False and c.after.at_noise]
    assert at_noise, "the short pipeline's chirp link channel fails its whiteness at the sensor's noise"
    table = gain_table_figure(d).axes[0].tables[0].get_celld()
    rows = {table[i, 0].get_text().get_text(): table[i, 6].get_text().get_text()
            for i in range(1, max(r for r, _ in table) + 1)}
    for c in at_noise:
        assert rows[f"{c.dataset} / {c.channel}"].endswith("FAIL (at noise)"), rows


def test_a_figure_shown_twice_is_the_same_figure(workdir, tmp_path):
    # Page 1 against the pages that show the same quantity again, read from the PDF as a reader sees it:
    # the fit's worst parameter (error in % and in std) in the parameter table and in the appendix, the
    # ripple's period on the spectrum and table pages; the diagnosis page against diagnose.json.
    import re

    import pypdf

    out = tmp_path / "report.pdf"
    build_report(out, workdir)
    pages = [" ".join(p.extract_text().split()) for p in pypdf.PdfReader(out).pages]
    first, later = pages[0], pages[1:]
    m = re.search(r"fit worst (\w+) at ([\d.]+) std of the plant \(error ([-+\d.e]+) %\)", first)
    assert m, first[:400]
    name, z, err = m.groups()
    (table,) = [p for p in later if "model.toml: parameters of eq (4) fitted to the chirp" in p]
    row = re.search(rf"\b{name} \S+(?: \S+)? ([-\d.e+]+) ([\d.e+-]+) ([\d.]+) ([\d.e+-]+) ([-+\d.e]+) ([-+\d.]+)", table)
    assert row, table[:600]
    assert figures_agree(err, row.group(5)) and figures_agree(z, row.group(6).lstrip("+-")), (m.group(0), row.group(0))
    # The Bode page's title shows the same fit's parameters as the table.
    (bode,) = [p for p in later if "Bode plot of tau_c -> tau_J" in p]
    title = re.search(r"tau_c -> tau_j: Jc=(\S+) kg m\^2, bc=(\S+) Nm s/rad, K=(\S+) Nm/rad, Jl=(\S+) kg m\^2, "
                      r"Td=(\S+) ms", bode)
    assert title, bode[:400]
    for shown, (param, unit, scale) in zip(title.groups(), (("Jc", "kg m\\^2", 1.0), ("bc", "Nm s/rad", 1.0),
                                                              ("K", "Nm/rad", 1.0), ("Jl", "kg m\\^2", 1.0),
                                                              ("Td", "s", 1e3))):
        value = re.search(rf"\b{param} {unit} ([-\d.e+]+)", table).group(1)
        assert figures_agree(shown, f"{float(value) * scale:.12g}"), (param, shown, value)
    (appendix,) = [p for p in later if p.startswith("Appendix")]
    shown = re.search(rf"fit: .*?\b{name} ([-+\d.]+) %", appendix)
    assert shown and figures_agree(shown.group(1), err), (shown and shown.group(0), err)
    # The design's kappa margins and the observer's gain: page 1 against the appendix's lines.
    kappa = re.search(r"kappa margin \(linear, section V\.C's model\) ([\d.]+) additive / ([\d.]+) built-in = "
                      r"([\d.]+)x", first)
    again = re.search(r"kappa_max \(linear, exact delay\): built-in ([\d.]+), additive ([\d.]+), ratio ([\d.]+)",
                      appendix)
    assert kappa and again, (first[:600], appendix[:600])
    for shown, other in zip(kappa.groups(), (again.group(2), again.group(1), again.group(3))):
        assert figures_agree(shown, other), (kappa.group(0), again.group(0))
    gain = re.search(r"observer improved .*?\(([\d.]+)x\)", first)
    said = re.search(r"observer: built-in over filtered RMS error .*?= ([\d.]+)x", appendix)
    assert gain and said and figures_agree(gain.group(1), said.group(1)), (gain and gain.group(0), said)
    rho = re.search(r"ripple rho = ([\d.]+) rad", first).group(1)
    again = [v for p in later for v in re.findall(r"ρ = ([\d.]+) rad", p)]
    assert again and all(figures_agree(rho, v) for v in again), (rho, again)
    # The diagnosis's figures against diagnose.json, wherever they are shown.
    assert_diagnosis_shown_alike(pages, workdir)


def test_the_report_draws_what_the_pipeline_kept(workdir, tmp_path, monkeypatch):
    # `report --workdir` reads the fit's and the ripple stage's results from the files the pipeline kept them
    # in; it runs them again only where the data changed since.
    import iiwa_ident.ident as ident

    def ran_again(*_a, **_k):
        raise IiwaIdentError("ran again")

    monkeypatch.setattr(ident, "fit_model", ran_again)
    monkeypatch.setattr(ident, "identify_ripple", ran_again)
    doc = json.loads((workdir / "pipeline.json").read_text())
    results = load_results(workdir, doc, ("fit", "ripple"))
    assert not results["load_errors"], results["load_errors"]
    saved = json.loads((workdir / "fit.json").read_text())["parameters"]
    assert {k: v["value"] for k, v in saved.items()} == results["fit"].parameters
    assert json.loads((workdir / "ripple.json").read_text())["period_rad"] == results["ripple"].period_rad
    titles = build_report(tmp_path / "r.pdf", workdir, stage="fit") + build_report(tmp_path / "r2.pdf", workdir,
                                                                                    stage="ripple")
    assert "Bode plot of tau_c -> tau_J" in titles and "Spatial spectrum" in titles, titles
    assert not any("not drawn" in t or ": failed" in t or ": missing" in t for t in titles), titles
    # The chirp changed since the fit (another recording under its name): the kept fit no longer stands for it.
    changed = tmp_path / "changed"
    shutil.copytree(workdir, changed)
    with open(changed / "chirp.h5", "ab") as fh:
        fh.write(b"\0")
    again = load_results(changed, doc, ("fit", "ripple"))
    assert again["load_errors"] == {"fit": "ran again"} and "ripple" in again, again["load_errors"]
    # A kept file that cannot be read (cut short, or not a result tree) is not trusted either: computed again.
    (changed / "ripple_result.h5").write_bytes((workdir / "ripple_result.h5").read_bytes()[:5000])
    again = load_results(changed, doc, ("ripple",))
    assert again["load_errors"] == {"ripple": "ran again"}, again["load_errors"]


def test_the_paper_reproduction_page_is_a_table_of_the_printed_cells():
    # It was the text table in a monospace font; now a table whose cells are the ones `design` prints.
    from iiwa_ident.design import REPRODUCTION_COLUMNS, paper_reproduction, reproduction_cells, table1_parameters
    from iiwa_ident.report._design_figures import reproduction_figure

    t1, source = table1_parameters()
    rows = paper_reproduction(t1)
    fig = reproduction_figure(rows, source)
    (table,) = fig.axes[0].tables
    cells = table.get_celld()
    assert tuple(cells[0, c].get_text().get_text() for c in range(8)) == REPRODUCTION_COLUMNS
    for i, want in enumerate(reproduction_cells(rows), 1):
        shown = tuple(cells[i, c].get_text().get_text() for c in range(8))
        assert shown[:7] == want[:7] and " ".join(shown[7].split()) == " ".join(want[7].split()), (shown, want)
    assert not any(t.get_fontfamily() == ["monospace"] for t in fig.texts)
    assert tuple(fig.get_size_inches()) == (11.0, 8.5)
