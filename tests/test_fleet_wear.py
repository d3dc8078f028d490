"""The fleet's worn-joint flag: a ripple above the fleet's median for its joint beyond the uncertainties."""

from __future__ import annotations

import math

import numpy as np
import pytest

from iiwa_ident.fleet import MIN_GROUPS, flag_worn


def _fleet(rng, robots: int, spread: float, rel_std: float, worn: dict | None = None) -> list[dict]:
    """Rows of a fleet ripple run: each joint's amplitude log-normal around its joint number's level."""
    worn = worn or {}
    level = {j: 20e-6 * math.exp(rng.normal(0.0, 0.5)) for j in range(1, 8)}
    rows = []
    for r in range(robots):
        for j in range(1, 8):
            true = level[j] * math.exp(rng.normal(0.0, spread)) * worn.get((f"r{r}", j), 1.0)
            measured = true * (1.0 + rel_std * rng.normal())
            rows.append({"robot": f"r{r}", "joint": j, "error": None,
                         "ripple": {"detected": True, "amplitude_rad": measured,
                                    "amplitude_std_rad": rel_std * measured}})
    return rows


def test_a_healthy_fleet_is_flagged_rarely():
    # Monte Carlo over fleets without a worn joint, spreads and measurement errors drawn: the chance of any
    # flag in a fleet is the stated false-alarm probability (1 %); the median's and spread's own estimation
    # errors allow it up to about 4 % here.
    rng = np.random.default_rng(7)
    any_flag = 0
    fleets = 300
    for _ in range(fleets):
        rows = _fleet(rng, int(rng.integers(5, 40)), rng.uniform(0.05, 0.4), rng.uniform(0.01, 0.3))
        any_flag += bool(flag_worn(rows)["flagged"])
    assert any_flag <= 0.04 * fleets, any_flag


def test_worn_joints_well_above_the_spread_are_flagged():
    rng = np.random.default_rng(11)
    for _ in range(20):
        spread = rng.uniform(0.05, 0.3)
        # Far above what the spread allows: 8 spreads in the logarithm plus the measurement's share.
        factor = math.exp(8 * math.hypot(spread, 0.05))
        worn = {(f"r{int(rng.integers(0, 30))}", int(rng.integers(1, 8))): factor}
        out = flag_worn(_fleet(rng, 30, spread, 0.05, worn))
        assert [tuple(f) for f in out["flagged"]] == list(worn), (spread, out["flagged"])
        assert out["sigma_fleet"] == pytest.approx(spread, rel=0.35)


def test_rows_not_judged_say_why():
    good = [{"robot": f"r{i}", "joint": 1, "error": None,
             "ripple": {"detected": True, "amplitude_rad": 20e-6, "amplitude_std_rad": 1e-6}} for i in range(3)]
    rows = good + [
        {"robot": "a", "joint": 1, "error": "a.h5: not an HDF5 file", "ripple": None},
        {"robot": "b", "joint": 1, "error": None, "ripple": {"detected": False, "amplitude_rad": None}},
        {"robot": "c", "joint": 1, "error": None,
         "ripple": {"detected": True, "amplitude_rad": 90e-6, "amplitude_std_rad": None}},
        {"robot": "e", "joint": 1, "error": None,
         "ripple": {"detected": True, "amplitude_rad": 90e-6, "amplitude_std_rad": 0.0}},
        {"robot": "d", "joint": 2, "error": None,
         "ripple": {"detected": True, "amplitude_rad": 90e-6, "amplitude_std_rad": 1e-6}},
    ]
    out = flag_worn(rows)
    whys = [r.get("why", "") for r in out["rows"]]
    assert whys[3] == "the group failed"
    assert whys[4].startswith("no ripple detected")
    assert whys[5].startswith("amplitude std unknown")
    assert whys[6].startswith("amplitude std unknown")
    assert whys[7].startswith(f"fewer than {MIN_GROUPS} detections of joint 2")
    assert out["compared"] == 3 and out["flagged"] == []
    assert all(r["worn"] is False for r in out["rows"][:3]) and all(r["worn"] is None for r in out["rows"][3:])
    with pytest.raises(ValueError):
        flag_worn(rows, false_alarm=0.0)


def test_the_command_line_names_the_worn_joints():
    from iiwa_ident.cli._fleet_cmd import _wear_line

    rng = np.random.default_rng(3)
    rows = _fleet(rng, 12, 0.1, 0.05, {("r4", 6): 4.0})
    wear = flag_worn(rows)
    for row, judged in zip(rows, wear.pop("rows")):
        row["wear"] = judged
    line = _wear_line({"groups": rows, "wear": wear})
    head, flagged = line.split("): ", 1)
    assert head.startswith("worn joints (") and "over 84 joints" in head, line
    assert flagged.startswith("r4 joint 6 (") and flagged.count("x the median, p = ") == 1, line


def test_a_few_noisy_amplitudes_do_not_hide_the_healthy_spread():
    # A tenth of the joints measured with a std twice their amplitude (a line barely detected): the spread
    # beyond the measurements is still the one drawn, and no healthy joint is flagged for lying in it.
    rng = np.random.default_rng(5)
    flags = 0
    for _ in range(10):
        spread = rng.uniform(0.2, 0.4)
        rows = _fleet(rng, 20, spread, 0.05)
        for row in rows:
            if rng.random() < 0.1:
                row["ripple"]["amplitude_std_rad"] = 2.0 * row["ripple"]["amplitude_rad"]
        out = flag_worn(rows)
        assert out["sigma_fleet"] == pytest.approx(spread, rel=0.35)
        flags += len(out["flagged"])
    assert flags <= 1, flags
