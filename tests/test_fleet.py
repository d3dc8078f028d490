"""The fleet: groups by robot and joint, one Dask task each, failures as rows, finished groups kept for a re-run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from iiwa_ident.datasets import Dataset, set_robot_name, write_dataset
from iiwa_ident.fleet import UNNAMED, fleet_table, group_datasets, group_key, run_fleet, run_group

pytest.importorskip("distributed")


def _synthetic(path, robot: str | None, joint: int, seed: int):
    rng = np.random.default_rng(seed)
    n = 200
    ds = Dataset(signals={"t": np.arange(n) * 1e-3, "q_m": rng.normal(size=n), "tau_j": rng.normal(size=n)},
                 experiment="free", source="import", joint=joint, sample_rate_hz=1000.0)
    set_robot_name(ds, robot)
    return write_dataset(path, ds)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Short constant-velocity runs of two robots' joint 1 (the simulated joint, ripple on)."""
    from iiwa_ident.excite import ConstantVelocity, record
    from iiwa_ident.sim import SimulatedJoint, default_plant

    folder = tmp_path_factory.mktemp("fleet_runs")
    out = []
    for k, robot in enumerate(("cell-a", "cell-b")):
        ds = record(SimulatedJoint(default_plant(), seed=k), ConstantVelocity([0.3, 0.6], range_rad=0.6))
        set_robot_name(ds, robot)
        out.append(write_dataset(folder / f"{robot}.h5", ds))
    return out


def test_grouping_by_robot_and_joint(tmp_path):
    paths = [_synthetic(tmp_path / f"{i}.h5", robot, joint, i)
             for i, (robot, joint) in enumerate([("r1", 2), ("r2", 2), ("r1", 2), ("r1", 5), (None, 2)])]
    (tmp_path / "bad.h5").write_bytes(b"not hdf5")
    groups = group_datasets(paths + [tmp_path / "bad.h5"])
    assert [(g.robot, g.joint, len(g.datasets)) for g in groups] == [
        ("r1", 2, 2), ("r2", 2, 1), ("r1", 5, 1), (UNNAMED, 2, 1), (UNNAMED, None, 1)]
    assert groups[-1].error is not None and "bad.h5" in groups[-1].error and "\n" not in groups[-1].error
    # The key follows the inputs' contents and the stage.
    assert group_key("ripple", groups[0]) != group_key("diagnose", groups[0])
    assert group_key("ripple", groups[0]) == group_key("ripple", group_datasets(paths[:3:2])[0])


def test_a_group_that_fails_is_a_row(tmp_path):
    out = run_group("ripple", [tmp_path / "none.h5"])
    assert set(out) == {"error"} and "none.h5" in out["error"]
    with pytest.raises(ValueError):
        run_group("dance", [])


def test_local_cluster_runs_isolates_failures_and_resumes(runs, tmp_path):
    bad = tmp_path / "broken.h5"
    bad.write_bytes(b"\x89HDF\r\n garbage")
    seen = []
    doc = run_fleet("ripple", [*runs, bad], tmp_path / "fleet", workers=1,
                    progress=lambda done, total, label: seen.append((done, total)))
    rows = {(g["robot"], g["joint"]): g for g in doc["groups"]}
    assert set(rows) == {("cell-a", 1), ("cell-b", 1), (UNNAMED, None)}
    for robot in ("cell-a", "cell-b"):
        assert rows[(robot, 1)]["error"] is None and "period_rad" in rows[(robot, 1)]["ripple"]
    assert "broken.h5" in rows[(UNNAMED, None)]["error"]
    assert doc["engine"]["workers"] == 1 and doc["resumed"] == 0 and seen[-1] == (3, 3)
    table = fleet_table(doc).splitlines()
    assert table[0].startswith("robot,joint,datasets,detected,period_rad") and len(table) == 4
    assert table[0].endswith("amplitude_std_rad,cycles_per_rev,fleet_median_rad,ratio_to_fleet,worn_p,worn,error")
    # Two robots are no fleet median: nothing judged, and each row says why.
    assert doc["wear"]["compared"] == 0 and doc["wear"]["flagged"] == []
    assert all(g["wear"]["worn"] is None and g["wear"]["why"] for g in doc["groups"])
    json.dumps(doc)  # the --json document is plain JSON
    again = run_fleet("ripple", [*runs, bad], tmp_path / "fleet", workers=1)
    assert again["resumed"] == 2
    assert [g["ripple"] for g in again["groups"]] == [g["ripple"] for g in doc["groups"]]


def test_command_writes_the_table_and_fails_when_a_group_failed(runs, tmp_path):
    from typer.testing import CliRunner

    from iiwa_ident.cli import app

    result = CliRunner().invoke(app, ["fleet", "ripple", str(runs[0]), "--workers", "1", "--out",
                                      str(tmp_path / "f"), "--json", str(tmp_path / "f.json")])
    assert result.exit_code == 0, result.output
    assert "worn joints: none judged" in result.output
    assert (tmp_path / "f.csv").read_text().splitlines()[1].startswith("cell-a,1,1,")  # beside the JSON
    assert json.loads((tmp_path / "f.json").read_text())["groups"][0]["robot"] == "cell-a"
    result = CliRunner().invoke(app, ["fleet", "ripple", str(tmp_path / "nope.h5"), "--workers", "1", "--out",
                                      str(tmp_path / "g")])
    assert result.exit_code == 1 and "nope.h5" in result.output
    assert (tmp_path / "g" / "fleet.csv").exists()  # without --json the table is in OUT


def test_workers_started_elsewhere_reach_relative_paths(runs, tmp_path, monkeypatch):
    # A worker started in another working folder than the client's: relative paths given here must reach it.
    from distributed import LocalCluster

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        monkeypatch.chdir(runs[0].parent)
        doc = run_fleet("ripple", [runs[0].name], tmp_path / "rel", scheduler=cluster.scheduler_address)
    assert doc["groups"][0]["error"] is None, doc["groups"][0]["error"]
