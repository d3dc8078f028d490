"""The pipeline on a robot's own logs (``pipeline --logs``): logs written in a driver's column layout, with
what drivers do to them, and the real iiwa 14 logs when ``../shared`` is beside the checkout."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import assert_diagnosis_shown_alike, figures_agree
from iiwa_ident.cli import app
from iiwa_ident.datasets import read_dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import ConstantVelocity, record
from iiwa_ident.pipeline import FILES, LOG_STAGES, find_log_runs, run_log_pipeline
from iiwa_ident.sim import SimulatedJoint, default_plant

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def write_log(folder: Path, speed: float, seed: int, joint: int = 1, drop: int = 0) -> None:
    """A simulated constant-velocity run of ``joint`` (the others at 0) in the column layout of Drake's iiwa
    driver at 200 Hz: time, 7 positions, 7 torques; ``drop`` samples lost in one gap."""
    ds = record(SimulatedJoint(default_plant(), seed=seed), ConstantVelocity([speed], range_rad=0.8),
                record_every=5)
    keep = np.ones(ds.n_samples, bool)
    if drop:
        keep[ds.n_samples // 2:ds.n_samples // 2 + drop] = False
    folder.mkdir(parents=True)
    n = int(keep.sum())
    q, tau = np.zeros((n, 7)), np.zeros((n, 7))
    q[:, joint - 1], tau[:, joint - 1] = ds["q_m"][keep], ds["tau_j"][keep]
    np.savetxt(folder / "cur_traj_time_s.txt", ds["t"][keep])
    np.savetxt(folder / "joint_position_measured.txt", q)
    np.savetxt(folder / "joint_torque_measured.txt", tau)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs") / "joint1"
    write_log(root / "vel_p3", 0.3, 1)
    write_log(root / "vel_p6", 0.6, 2, drop=7)
    return root


@pytest.fixture(scope="module")
def logs_run(logs, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("logs_run")
    lines: list[str] = []
    result = run_log_pipeline(workdir, [logs], progress=lines.append)
    return workdir, result, lines


def test_runs_are_found_in_folders_of_folders(logs, tmp_path):
    runs = find_log_runs([logs])
    assert [(r.name, r.kind) for r in runs] == [("joint1_vel_p3", "columns"), ("joint1_vel_p6", "columns")]
    assert [r.name for r in find_log_runs([logs / "vel_p3"])] == ["joint1_vel_p3"]
    with pytest.raises(IiwaIdentError, match="no run found"):
        find_log_runs([tmp_path])


def test_every_stage_on_logs(logs_run):
    workdir, result, lines = logs_run
    status = {s.name: s.status for s in result.stages}
    assert status == {"import": "ok", "ripple": "ok", "diagnose": "ok", "held_out": "ok", "fit": "skipped",
                      "design": "skipped", "deploy": "skipped"}, [(s.name, s.error) for s in result.stages]
    assert result.ok  # nothing failed: the logs hold no torque command, so fit says why it did not run
    fit = next(s for s in result.stages if s.name == "fit")
    assert "no torque-commanded record" in fit.error and "chirp --target robot" in fit.error
    assert any("fit: skipped: no torque-commanded record" in x for x in lines)
    for name in ("model_ripple", "ripple_json", "diagnose_json", "model_ext", "pipeline_json"):
        assert (workdir / FILES[name]).is_file(), name
    doc = json.loads((workdir / FILES["pipeline_json"]).read_text())
    h = doc["headline"]
    assert h["data"] == "measured" and h["runs"] == ["joint1_vel_p3", "joint1_vel_p6"]
    assert h["ripple_decided"] is True
    # The default plant's ripple, found from the runs alone (0.01963 rad).
    assert h["ripple_period_rad"] == pytest.approx(0.01963, rel=0.01)
    assert [r["run"] for r in h["held_out"]] == h["runs"]
    assert all(r["after_nm"] > 0 and r["before_nm"] > 0 for r in h["held_out"])
    held = next(s for s in result.stages if s.name == "held_out").headline["runs"]
    assert all(set(r["fit_pct"]) == {"link"} and r["fit_pct"]["link"] < 100 for r in held), held
    assert all(r["residual_tests_passed"]["link"] in (True, False) for r in held)


def test_the_imported_runs_keep_what_the_checks_found(logs_run):
    workdir, result, lines = logs_run
    imp = next(s for s in result.stages if s.name == "import").headline
    by = {r["run"]: r for r in imp["runs"]}
    assert by["joint1_vel_p3"]["warnings"] == []
    assert any("1 gap" in w for w in by["joint1_vel_p6"]["warnings"]), by["joint1_vel_p6"]
    ds = read_dataset(workdir / by["joint1_vel_p6"]["file"])
    assert ds.joint == 1 and ds.experiment == "constant_velocity"
    assert "1 gap" in ds.experiment_attrs["import_warnings"]
    assert any("warning: joint1_vel_p6: time has 1 gap" in x for x in lines)


def test_runs_of_different_joints_are_refused(logs, tmp_path):
    write_log(tmp_path / "other" / "j2", 0.4, 3, joint=2)
    lines: list[str] = []
    result = run_log_pipeline(tmp_path / "w", [logs, tmp_path / "other"], progress=lines.append)
    imp = next(s for s in result.stages if s.name == "import")
    assert imp.status == "failed" and "the runs move different joints" in imp.error
    assert "joint1_vel_p3 (joint 1)" in imp.error and "other_j2 (joint 2)" in imp.error
    assert not result.ok


def test_cli_bad_input_is_one_line(tmp_path):
    res = CliRunner().invoke(app, ["pipeline", "--logs", str(tmp_path / "nothing"), "--workdir", str(tmp_path / "w")])
    assert res.exit_code == 2 and res.stderr.strip().count("\n") == 0, res.output
    assert "nothing: no such file or folder" in res.stderr and "Traceback" not in res.output
    res = CliRunner().invoke(app, ["pipeline", "--logs", str(tmp_path), "--plant", "p.toml", "--workdir",
                                   str(tmp_path / "w")])
    assert res.exit_code == 2 and "drop --plant" in res.stderr
    assert [s.name for s in LOG_STAGES][:4] == ["import", "ripple", "diagnose", "held_out"]


def test_real_joint2_through_the_cli(tmp_path):
    folder = REAL / "iiwa14-constant-velocity" / "joint2"
    if not folder.is_dir():
        pytest.skip(f"real iiwa 14 logs not found at {folder} (expected ../shared beside the checkout)")
    res = CliRunner().invoke(app, ["pipeline", "--logs", str(folder), "--workdir", str(tmp_path / "w")])
    assert res.exit_code == 0, res.output
    assert "torque sign flipped: the gravity of joint2_vel_p3 reads the other way round" in res.stdout
    assert "low-pass filtered before it was logged" in res.stdout
    doc = json.loads((tmp_path / "w" / FILES["pipeline_json"]).read_text())
    assert doc["headline"]["data"] == "measured"
    named = {e["name"] for e in doc["headline"]["named_effects"]}
    assert "position_dependent_load" in named  # the arm's gravity, against the description's
    # What the table leaves unexplained, on the console and in the ripple stage's headline (page 1 lists it).
    ripple = next(s for s in doc["stages"] if s["name"] == "ripple")["headline"]
    said = [w for w in ripple["warnings"] if w.startswith("the deflection about the table is ")]
    assert said and f"warning: {said[0]}" in res.stdout
    # Every figure of the diagnosis the same wherever the report shows it (it names several effects here).
    import pypdf

    pages = [" ".join(p.extract_text().split()) for p in pypdf.PdfReader(tmp_path / "w" / "report.pdf").pages]
    assert_diagnosis_shown_alike(pages, tmp_path / "w")


def test_the_report_of_measured_data(logs_run, tmp_path):
    from iiwa_ident.report import build_report
    from iiwa_ident.report._pdf import banner

    workdir, result, _ = logs_run
    doc = json.loads((workdir / FILES["pipeline_json"]).read_text())
    head = banner(doc)
    assert head.startswith("MEASURED: 2 run(s) of iiwa14 joint 1 from ")
    # Rebuilt from the work folder's files alone, as `report --workdir` does.
    titles = build_report(tmp_path / "r.pdf", workdir, png_dir=tmp_path / "png", png_dpi=30)
    assert titles[:3] == ["Verdict", "Runs and what their logs say", "Each run predicted from the other runs"]
    assert not any(t.endswith("missing") or t.startswith("validation") for t in titles), titles
    assert "fit: skipped" in titles and "Named effects and gains" in titles
    diag = next(s for s in doc["stages"] if s["name"] == "diagnose")["headline"]
    changed = bool(diag["effects"] or diag["replaced"])  # residual pages only where the model changed
    assert any(t.startswith("Residuals before and after: joint1_vel_p6.h5") for t in titles) == changed, titles
    assert not any("dataset 0" in t or "not drawn" in t for t in titles), titles
    # Every page one size; page 1's rows in the pipeline's stage order, a stage the logs cannot support
    # neither passed nor warned (no torque command: fit, design and deploy), its reason said once.
    import pypdf

    from iiwa_ident.report._verdict import verdict_rows

    pages = pypdf.PdfReader(tmp_path / "r.pdf").pages
    assert {(round(float(p.mediabox.width)), round(float(p.mediabox.height))) for p in pages} == {(792, 612)}
    first = " ".join(pages[0].extract_text().split())
    assert "skipped: skipped" not in first and "SKIPPED" in first
    rows = verdict_rows(doc)
    assert [r.stage for r in rows if r.stage in ("import", "ripple", "diagnose", "held out", "fit")] == \
        ["import", "ripple", "diagnose", "held out", "fit"]
    assert {r.stage: r.verdict for r in rows if r.stage in ("fit", "design", "deploy")} == \
        {"fit": "SKIPPED", "design": "SKIPPED", "deploy": "SKIPPED"}
    fit_row = next(r for r in rows if r.stage == "fit")
    assert fit_row.figure.startswith("no torque-commanded record")


def test_the_simulated_report_says_so():
    from iiwa_ident.report._pdf import banner

    assert banner({"inputs": {"plant": "default plant"}, "headline": {}}) == "SIMULATED: default plant"
    assert banner(None) == ""


def test_datasets_without_a_pose_need_a_model(tmp_path):
    from iiwa_ident.datasets import write_dataset
    from iiwa_ident.ident import write_model
    from iiwa_ident.model import table1_model

    paths = []
    for k, speed in enumerate((0.4, 0.8)):
        ds = record(SimulatedJoint(default_plant(), seed=10 + k), ConstantVelocity([speed], range_rad=0.8),
                    record_every=5)
        paths.append(write_dataset(tmp_path / f"cv{k}.h5", ds))
    result = run_log_pipeline(tmp_path / "w1", paths, progress=lambda _m: None)
    status = {s.name: (s.status, s.error) for s in result.stages}
    assert status["ripple"][0] == "ok"
    assert status["diagnose"][0] == "failed" and "does not say the other joints' positions" in status["diagnose"][1]
    model = tmp_path / "table1.toml"
    write_model(model, table1_model())
    result = run_log_pipeline(tmp_path / "w2", paths, model=model, progress=lambda _m: None)
    status = {s.name: s.status for s in result.stages}
    assert status["diagnose"] == "ok" and status["held_out"] == "ok", [(s.name, s.error) for s in result.stages]


def test_a_driver_that_logs_the_command_as_the_position_is_named(tmp_path):
    # A run folder whose commanded-position file is the measured one, sample for sample (a driver in open loop).
    run = tmp_path / "logs" / "joint1" / "vel_p4"
    write_log(run, 0.4, 21)
    (run / "joint_position_commanded.txt").write_bytes((run / "joint_position_measured.txt").read_bytes())
    lines: list[str] = []
    result = run_log_pipeline(tmp_path / "w", [run], progress=lines.append, skip=("held_out",))
    imp = next(s for s in result.stages if s.name == "import")
    assert imp.status == "ok", imp.error
    assert any("q_m equals q_cmd" in w for w in imp.headline["runs"][0]["warnings"]), imp.headline
    assert any("warning: joint1_vel_p4: q_m equals q_cmd" in x for x in lines)


def _concatenated(folder: Path, *parts: Path) -> None:
    """One column log holding the runs ``parts`` one after the other: its time restarts at each."""
    folder.mkdir(parents=True)
    for name in ("cur_traj_time_s.txt", "joint_position_measured.txt", "joint_torque_measured.txt"):
        np.savetxt(folder / name, np.concatenate([np.loadtxt(p / name, ndmin=1) for p in parts]))


@pytest.fixture(scope="module")
def two_in_one(tmp_path_factory):
    """A joint-1 folder with a good run and a log that holds two runs."""
    tmp = tmp_path_factory.mktemp("two_in_one")
    write_log(tmp / "parts" / "a", 0.3, 4)
    write_log(tmp / "parts" / "b", 0.5, 5)
    root = tmp / "joint1"
    write_log(root / "vel_p4", 0.4, 6)
    _concatenated(root / "twice", tmp / "parts" / "a", tmp / "parts" / "b")
    return root


_ONLY_IMPORT = tuple(s.name for s in LOG_STAGES if s.name != "import")


def test_a_run_that_cannot_be_read_is_dropped_and_the_others_go_on(two_in_one, tmp_path):
    lines: list[str] = []
    result = run_log_pipeline(tmp_path / "w", [two_in_one], progress=lines.append, report=None, skip=_ONLY_IMPORT)
    imp = next(s for s in result.stages if s.name == "import")
    assert imp.status == "ok", imp.error
    assert [r["run"] for r in imp.headline["runs"]] == ["joint1_vel_p4"]
    (dropped,) = imp.headline["dropped"]
    assert dropped["run"] == "joint1_twice" and "time goes back" in dropped["reason"]
    assert "--split-runs" in dropped["reason"]
    assert any(x.startswith("  dropped joint1_twice: ") for x in lines)


def test_split_runs_imports_each_run_of_a_log(two_in_one, tmp_path):
    result = run_log_pipeline(tmp_path / "w", [two_in_one], progress=lambda m: None, report=None,
                              skip=_ONLY_IMPORT, split_runs=True)
    imp = next(s for s in result.stages if s.name == "import").headline
    assert [r["run"] for r in imp["runs"]] == ["joint1_twice_run1", "joint1_twice_run2", "joint1_vel_p4"]
    assert imp["dropped"] == []
    first, second = (read_dataset(tmp_path / "w" / r["file"]) for r in imp["runs"][:2])
    assert first.joint == second.joint == 1
    assert first["t"][-1] > second["t"][0]  # each run's own time, restarted


def test_cli_logs_takes_several_paths_and_split_runs(two_in_one, tmp_path):
    res = CliRunner().invoke(app, ["pipeline", "--logs", str(two_in_one / "vel_p4"), str(two_in_one / "twice"),
                                   "--split-runs", "--skip", "ripple", "--no-report", "--workdir", str(tmp_path / "w")])
    assert res.exit_code == 0, res.output
    assert "3 run(s) of joint 1" in res.stdout
    res = CliRunner().invoke(app, ["pipeline", "--workdir", str(tmp_path / "w"), str(two_in_one)])
    assert res.exit_code == 2 and "paths are log runs of --logs" in res.stderr


@pytest.mark.parametrize("args", [["chirp", "--joint", "9", "--out", "x.h5"],
                                  ["simulate", "step", "--joint", "0", "--out", "x.h5"],
                                  ["model", "--joint", "8", "--out", "x.toml"],
                                  ["import", "--joint", "9", "--experiment", "free", "--columns", "t=t.txt",
                                   "--out", "x.h5"],
                                  ["deploy", "--design", "d.toml", "--joint", "9", "--out", "c.toml"],
                                  ["pipeline", "--joint", "9", "--workdir", "w"]])
def test_every_command_checks_its_joint(args, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2 and res.stderr.strip().endswith(f"--joint {args[args.index('--joint') + 1]}: an iiwa "
                                                              "joint is 1-7"), res.output
    assert list(tmp_path.iterdir()) == []


def test_the_simulated_joint_is_the_plant_s(tmp_path):
    res = CliRunner().invoke(app, ["chirp", "--joint", "3", "--duration", "1", "--out", str(tmp_path / "x.h5")])
    assert res.exit_code == 2 and "--joint 3: the simulated plant is joint 1" in res.stderr
    assert not (tmp_path / "x.h5").exists()


def test_split_runs_through_the_cli_on_any_log(tmp_path_factory):
    # Fuzzed over its input space: 1-4 runs of any joint, lengths and rates in one column log, some of them
    # too short to be a run; the import stage through the CLI never ends in a traceback, splits each
    # readable stretch into its own run and drops the rest with their reason.
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    @settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(joint=st.integers(1, 7), lengths=st.lists(st.integers(1, 600), min_size=1, max_size=4),
           rate=st.sampled_from([100.0, 200.0, 1000.0]), split=st.booleans(), seed=st.integers(0, 2**16))
    def check(joint, lengths, rate, split, seed):
        rng = np.random.default_rng(seed)
        folder = tmp_path_factory.mktemp("fuzz") / f"joint{joint}" / "log"
        folder.mkdir(parents=True)
        t = np.concatenate([np.arange(n) / rate for n in lengths])
        q = np.zeros((len(t), 7))
        q[:, joint - 1] = 0.5 * np.sin(2 * np.pi * 0.2 * t) + rng.normal(0, 1e-5, len(t))
        tau = rng.normal(0, 0.05, (len(t), 7))
        np.savetxt(folder / "cur_traj_time_s.txt", t)
        np.savetxt(folder / "joint_position_measured.txt", q)
        np.savetxt(folder / "joint_torque_measured.txt", tau)
        work = folder.parent.parent / "w"
        args = ["pipeline", "--logs", str(folder), "--skip", "ripple", "--no-report", "--workdir", str(work)]
        res = CliRunner().invoke(app, args + (["--split-runs"] if split else []))
        assert "Traceback" not in res.output and res.exception is None or isinstance(res.exception, SystemExit), \
            res.output
        doc = json.loads((work / FILES["pipeline_json"]).read_text())
        imp = next(s for s in doc["stages"] if s["name"] == "import")
        if imp["status"] == "ok":
            got = [r["run"] for r in imp["headline"]["runs"]]
            if split and len(lengths) > 1:
                assert all(r.startswith("joint" + str(joint) + "_log_run") for r in got), got
            assert len(got) + len(imp["headline"]["dropped"]) >= 1
        else:
            assert imp["status"] == "failed" and imp["error"] and res.exit_code == 1, res.output

    check()


def test_a_stray_sample_where_the_time_restarts_is_left_out_and_said(two_in_one, tmp_path):
    # One row after the last restart made the whole log fail with --split-runs ("only 1 sample").
    folder = tmp_path / "joint1" / "stray"
    folder.mkdir(parents=True)
    for name in ("cur_traj_time_s.txt", "joint_position_measured.txt", "joint_torque_measured.txt"):
        rows = np.loadtxt(two_in_one / "twice" / name, ndmin=1)
        np.savetxt(folder / name, np.concatenate([rows, rows[:1]]))
    lines: list[str] = []
    result = run_log_pipeline(tmp_path / "w", [folder], progress=lines.append, report=None, skip=_ONLY_IMPORT,
                              split_runs=True)
    imp = next(s for s in result.stages if s.name == "import").headline
    assert [r["run"] for r in imp["runs"]] == ["joint1_stray_run1", "joint1_stray_run2"]
    (said,) = imp["dropped"]
    assert said["reason"].startswith("one sample, not a run: run 3 (sample ")
    assert any("one sample, not a run" in x for x in lines)



def test_a_figure_shown_twice_in_a_logs_report_is_the_same_figure(logs_run, tmp_path):
    # Page 1 against the pages that show the same quantity again: the ripple's period (its pages and the
    # appendix), each held-out run's share of the starting model's RMS (its bar and the appendix's RMS).
    import re

    import pypdf

    from iiwa_ident.report import build_report

    workdir, _, _ = logs_run
    build_report(tmp_path / "r.pdf", workdir, png_dpi=30)
    pages = [" ".join(p.extract_text().split()) for p in pypdf.PdfReader(tmp_path / "r.pdf").pages]
    first, later = pages[0], pages[1:]
    rho = re.search(r"ripple rho = ([\d.]+) rad", first).group(1)
    again = [v for p in later for v in re.findall(r"(?:ρ|rho) = ([\d.]+) rad", p)]
    assert len(again) >= 3 and all(figures_agree(rho, v) for v in again), (rho, again)
    lo, hi = re.search(r"held out each run predicted from the others at (\d+)-(\d+) %", first).groups()
    (bars,) = [p for p in later if "Each run predicted from the other runs" in p]
    shares = re.findall(r"(\d+) % fit", bars)
    appendix = next(p for p in later if p.startswith("Appendix"))
    rms = re.findall(r"predicted from the other runs, RMS ([\d.]+) -> ([\d.]+) Nm", appendix)
    assert len(shares) == len(rms) == 2, (shares, rms)
    assert min(map(int, shares)) == int(lo) and max(map(int, shares)) == int(hi), (lo, hi, shares)
    assert all(abs(100 * float(b) / float(a) - int(s)) <= 0.5 + 100 * 0.005 / float(a) for (a, b), s in zip(rms, shares))
    assert_diagnosis_shown_alike(pages, workdir)


def test_the_report_of_logs_draws_the_ripple_the_pipeline_kept(logs_run, monkeypatch):
    import iiwa_ident.ident as ident
    from iiwa_ident.report._pdf import load_results

    def ran_again(*_a, **_k):
        raise IiwaIdentError("ran again")

    monkeypatch.setattr(ident, "identify_ripple", ran_again)
    workdir, _, _ = logs_run
    doc = json.loads((workdir / FILES["pipeline_json"]).read_text())
    results = load_results(workdir, doc, ("ripple",))
    assert "ripple" in results and not results["load_errors"], results["load_errors"]
    assert json.loads((workdir / FILES["ripple_json"]).read_text())["period_rad"] == results["ripple"].period_rad
