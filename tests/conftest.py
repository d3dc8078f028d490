"""Shared fixtures: plants with the sensor noise and quantisation switched off for exact checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from iiwa_ident.sim import Plant, default_plant

REPO = Path(__file__).resolve().parents[1]
REAL_LOGS = REPO.parent / "shared" / "data" / "real" / "iiwa14-constant-velocity"


def real_constant_velocity(joint: int, run: str = "vel_p3"):
    """One constant-velocity run of the real iiwa 14 logs as a dataset (skips where the logs are absent)."""
    from iiwa_ident.datasets import import_columns

    d = REAL_LOGS / f"joint{joint}" / run
    if not d.exists():
        pytest.skip(f"real iiwa 14 logs not found at {d}")
    return import_columns({"t": d / "cur_traj_time_s.txt", "q_m": d / "joint_position_measured.txt",
                           "tau_j": d / "joint_torque_measured.txt"}, joint=joint, experiment="constant_velocity")


def quiet(plant: Plant) -> Plant:
    """The plant without sensor noise and encoder quantisation."""
    plant.sensors.update(tau_noise_nm=0.0, ft_noise_nm=0.0, link_encoder_noise_rad=0.0, encoder_tick_rad=0.0)
    return plant


@pytest.fixture
def linear_plant() -> Plant:
    """Table I, no effects, no noise."""
    return quiet(default_plant().without_effects())


@pytest.fixture
def ripple_plant() -> Plant:
    """Table I with the default ripple, no noise."""
    return quiet(default_plant())


def smooth_command(n: int, dt: float = 1e-3, bias: float = 8.0, amp: float = 5.0, f: float = 3.0) -> np.ndarray:
    """A command that starts above the standstill threshold and within the slew-rate limit."""
    t = np.arange(n) * dt
    return 1.5 + bias * np.sin(np.pi * np.minimum(t, 0.5)) ** 2 + amp * np.sin(2 * np.pi * f * t) * np.minimum(t / 0.3, 1)


def assert_not_blank(png) -> None:
    """A rendered page shows something: enough pixels that differ from the background."""
    import matplotlib.image as mpimg

    img = mpimg.imread(png)[..., :3]
    dark = np.mean(img.mean(axis=2) < 0.8)
    assert dark > 0.005, f"{png.name}: blank page ({100 * dark:.2f} % non-white pixels)"


def figures_agree(shown: str, other: str) -> bool:
    """Two printed numbers agree: one value rounds to both (they differ by at most their two half-steps)."""
    def half_step(s: str) -> float:
        return 0.5 * 10.0 ** -(len(s.split(".")[1]) if "." in s else 0)

    return abs(float(shown) - float(other)) <= (half_step(shown) + half_step(other)) * (1 + 1e-9)


def pdf_pages(path) -> int:
    """Page count of a PDF as matplotlib writes it (one ``/Type /Page`` object per page)."""
    import re

    return len(re.findall(rb"/Type\s*/Page\b(?!s)", path.read_bytes()))


def wait_for(predicate, timeout_s: float = 60.0, what: str = "the condition"):
    """Poll ``predicate()`` until it returns a true value and return that value.

    For outcomes of other processes (a file finished by a writer process, a
    message from a child): the test waits for the event itself, and the
    generous ``timeout_s`` only ends a test whose event never comes.
    """
    import threading
    import time

    deadline = time.monotonic() + timeout_s
    pause = threading.Event()
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"{what} did not happen within {timeout_s:g} s")
        pause.wait(0.02)


#: Test files of a quarter of a minute or more of work (shared fixtures that simulate and fit), longest
#: first: ``make test`` hands whole files to its two workers in collection order, and a long file collected
#: last would run alone at the end (measured with ``--durations=0``: 60 s down to 17 s).
_LONG_FILES = ("test_diagnose.py", "test_ident_ripple.py", "test_pipeline.py", "test_ident_joint_fit.py",
               "test_fri_loop.py", "test_diagnose_batch.py", "test_report.py", "test_ident_ripple_subset.py",
               "test_ident_fit.py", "test_ident_bla_subset.py", "test_cli_fit.py")


def pytest_collection_modifyitems(session, config, items):
    def rank(item) -> int:
        name = Path(str(item.fspath)).name
        return _LONG_FILES.index(name) if name in _LONG_FILES else len(_LONG_FILES)

    items.sort(key=rank)  # stable: the order inside each file is kept


def import_then_ripple_and_diagnose(tmp_path, *import_args: str) -> None:
    """``iiwa-ident import IMPORT_ARGS --out run.h5``, then ``ripple`` (a ripple detected) and ``diagnose`` on it."""
    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    run = tmp_path / "run.h5"
    runner = CliRunner()
    result = runner.invoke(app, ["import", *import_args, "--experiment", "constant_velocity", "--out", str(run)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["ripple", str(run), "--json", str(tmp_path / "ripple.json")])
    assert result.exit_code == 0 and "periodic transmission deflection detected" in result.stdout, result.output
    result = runner.invoke(app, ["diagnose", str(run), "--json", str(tmp_path / "diagnose.json")])
    assert result.exit_code == 0, result.output



def assert_diagnosis_shown_alike(pages: list[str], workdir) -> None:
    """The diagnosis's figures agree wherever a report shows them (pages as whitespace-joined text): each named
    effect's held-out gain on page 1, the gain table, its evidence page and the appendix, its RMS before and
    after and confidence on the table and the evidence page, all against ``diagnose.json``; each channel's row
    of the table (RMS, gain, fit, tests before and after) against ``diagnose.json``."""
    import json
    import re

    saved = json.loads((Path(workdir) / "diagnose.json").read_text())
    first, later = pages[0], pages[1:]
    (named,) = [p for p in later if "Named effects and gains" in p]
    appendix = next(p for p in later if p.startswith("Appendix"))
    for e in saved["effects"]:
        name = re.escape(e["name"])
        on_first = re.search(rf"\b{name} \((\d+) %\)", first)
        assert on_first and figures_agree(on_first.group(1), f"{e['gain_pct']:.12g}"), (e["name"], first[:800])
        row = re.search(rf"\b{name}(?: \([^)]*\))? ([\d.]+) ([\d.]+) ([\d.]+) ([-\d.]+)", named)
        assert row, (e["name"], named[:800])
        for shown, value in zip(row.groups(), (e["confidence"], e["rms_before"], e["rms_after"], e["gain_pct"])):
            assert figures_agree(shown, f"{value:.12g}"), (e["name"], row.group(0), e)
        (evidence,) = [p for p in later if p.startswith(f"Evidence for {e['name']} (") or
                       f"Evidence for {e['name']}. " in p]
        held = re.search(r"\(confidence ([\d.]+)\).*?Held-out residual RMS on these channels: ([\d.]+) Nm without "
                         r"the effect, ([\d.]+) Nm with it \(([-\d.]+)% lower\)", evidence)
        assert held, (e["name"], evidence[:800])
        for shown, value in zip(held.groups(), (e["confidence"], e["rms_before"], e["rms_after"], e["gain_pct"])):
            assert figures_agree(shown, f"{value:.12g}"), (e["name"], held.group(0), e)
        again = re.search(rf"diagnosis: {name} named, held-out residual ([-\d.]+) % lower", appendix)
        assert again and figures_agree(again.group(1), f"{e['gain_pct']:.12g}"), (e["name"], appendix[:800])
    datasets = {d["file"]: d for d in saved["datasets"]}
    keys = {"link": "ext_torque_error", "command": "command_error"}
    rows = re.findall(r"(\S+\.h5) / (link|command) ([\d.]+) ([\d.]+) ([-\d.]+) ([-\d.]+) / ([-\d.]+) "
                      r"(pass|FAIL|-)(?: \(at noise\))? / (pass|FAIL|-)", named)
    shown_channels = sum(f"{k}_rms_before" in d for d in datasets.values() for k in keys.values())
    assert rows and len(rows) == shown_channels, (rows, named[:800])
    for file, channel, before, after, gain, fit_b, fit_a, tests_b, tests_a in rows:
        d, key = datasets[file], keys[channel]
        for shown, value in ((before, d[f"{key}_rms_before"]), (after, d[f"{key}_rms_after"]),
                             (gain, d[f"{key}_gain_pct"]), (fit_b, d[f"{key}_fit_pct_before"]),
                             (fit_a, d[f"{key}_fit_pct_after"])):
            assert figures_agree(shown, f"{value:.12g}"), (file, channel, shown, value)
        for shown, passed in ((tests_b, d.get(f"{key}_tests_passed_before")),
                              (tests_a, d.get(f"{key}_tests_passed_after"))):
            assert shown == {True: "pass", False: "FAIL", None: "-"}[passed], (file, channel, shown, passed)
