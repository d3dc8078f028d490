"""The diagnosis on every real joint, started from the robot's description: one block per joint.

Imports every run of every joint under ``../shared/data/real/iiwa14-constant-velocity`` (200 Hz, constant
speeds back and forth, the arm straight up) and the joint-6 position chirp, in memory, with the pose the
position files give. For each run: the joint's starting model from the rigid-body description
(:func:`iiwa_ident.ident.dataset_model`), the diagnosis of that run alone (what it names, the held-out RMS
before and after), then the joint's other runs predicted by the model the diagnosis extended
(:func:`iiwa_ident.diagnose.residual_rms`), against the starting model's RMS on them. Prints per joint whether
its runs name the same effects, and the named load and inertia against the description's; for joints with
three runs or more, each run predicted by the model the joint's other runs, diagnosed together, extended.

Run: ``.venv/bin/python bench/bench_real_diagnose.py [--root ../shared/data/real] [--joints 1,2,3,4,6]``.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np
from bench_ripple_real import joint_runs, load_run

from iiwa_ident.datasets import Dataset, torque_sign_problem
from iiwa_ident.diagnose import ACROSS_RUNS_WORSE_PCT, diagnose, residual_rms
from iiwa_ident.ident import dataset_model

_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def runs(root: Path, joints: set[int], sign: float = 1.0) -> dict[int, list[Dataset]]:
    """The joints' constant-velocity runs (:func:`bench_ripple_real.joint_runs`) and the joint-6 chirp."""
    out = {j: [ds for _, ds in rs] for j, rs in joint_runs(root, sign).items() if j in joints}
    chirp = root / "iiwa14-position-chirp" / "joint6"
    if 6 in joints and chirp.is_dir():
        ds = load_run(chirp, 6, "chirp", sign)
        ds.path = Path("j6/chirp")
        out.setdefault(6, []).append(ds)
    return out


#: The target of a prediction: at most this share of the starting model's RMS, or, where a published
#: whole-arm identification of a Franka Panda reports one (Gaz et al. 2019, held-out RMS per joint), at most
#: that RMS [Nm].
TARGET_SHARE = 0.20
PANDA_RMS_NM = {2: 1.0, 4: 0.65, 5: 0.42, 7: 0.16}


def _target(joint: int) -> str:
    panda = f" or at most {PANDA_RMS_NM[joint]:.2f} Nm, the Panda's" if joint in PANDA_RMS_NM else ""
    return f"target at most {100 * TARGET_SHARE:.0f} % of the starting RMS{panda}"


def _rms(rows: list[tuple[str, str, float]]) -> float:
    return float(np.sqrt(np.mean([r[2] ** 2 for r in rows]))) if rows else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=_ROOT)
    parser.add_argument("--joints", default="1,2,3,4,6")
    args = parser.parse_args(argv)
    if not (args.root / "iiwa14-constant-velocity").is_dir():
        print(f"error: no real logs under {args.root}", file=sys.stderr)
        return 2
    # The recording's torque sign, as `import` tells it (the runs whose gravity decides it), for all its runs:
    # one driver logged every joint.
    verdicts = {str(ds.path): torque_sign_problem(ds) for dss in runs(args.root, {1, 2, 3, 4, 5, 6, 7}).values()
                for ds in dss}
    decided = [p for p, w in verdicts.items() if w]
    sign = -1.0 if decided else 1.0
    print(f"the recording's torque sign: {'the other way round' if decided else 'as the convention'} "
          f"(import's check on {', '.join(decided) or 'no run'}); all runs imported with tau_j x {sign:+.0f}")
    by_joint = runs(args.root, {int(x) for x in args.joints.split(",")}, sign)
    for j, dss in by_joint.items():
        print(f"joint {j}: {len(dss)} run(s)")
        named_sets = []
        for ds in dss:
            t0 = time.perf_counter()
            start = dataset_model([ds])
            d = diagnose([ds], start)
            wall = time.perf_counter() - t0
            before = float(np.sqrt(np.mean([c.rms_before ** 2 for c in d.channels])))
            after = float(np.sqrt(np.mean([c.rms_after ** 2 for c in d.channels])))
            named = sorted(e.name for e in d.effects)
            named_sets.append(tuple(named))
            desc = {e["name"]: e for e in start.effects}
            params = []
            for e in d.effects:
                p = ", ".join(f"{k} {v:.4g}" for k, v in e.parameters.items())
                params.append(f"{e.name} ({p})")
            load0 = desc.get("position_dependent_load", {}).get("amplitude_nm", 0.0)
            # The extended model, simulated again on the run: what a user gets (the diagnosis's fit is of
            # linearised columns).
            carried = _rms(residual_rms([ds], d.extended))
            print(f"  {ds.path}: held-out RMS {before:.3f} -> {after:.3f} Nm ({100 * (1 - after / before):.1f} % "
                  f"lower; the extended model predicts the run at {carried:.3f} Nm), {wall:.0f} s; "
                  f"named: {'; '.join(params) or 'nothing'}")
            against = "; ".join(e.detail["against_description"] for e in d.effects if e.detail.get("against_description"))
            print(f"      description: Jl {start.value('Jl'):.4g} kg m^2, gravity amplitude {load0:.4g} Nm"
                  + (f" ({against})" if against else "") + "; "
                  f"suspects: {', '.join(s['name'] + ' (' + s['failed'] + ')' for s in d.suspects) or 'none'}")
            others = [o for o in dss if o is not ds]
            if others:
                rows_start = residual_rms(others, start)
                rows_ext = residual_rms(others, d.extended)
                per = "; ".join(f"{a[0]} {a[2]:.3f} -> {b[2]:.3f}" for a, b in zip(rows_start, rows_ext))
                ratio = _rms(rows_ext) / _rms(rows_start)
                print(f"      other runs predicted (starting -> extended model, Nm): {per}; "
                      f"{100 * ratio:.1f} % of the starting RMS ({_target(j)})")
        if len(dss) == 1:
            # No other run to predict: the run's own held-out (blocked cross-validation) RMS is what there is.
            print(f"  joint {j}, one run: held-out within the run {after:.3f} Nm, {100 * after / before:.0f} % of the "
                  f"starting RMS; the extended model predicts the run (in-sample) at {carried:.3f} Nm, "
                  f"{100 * carried / before:.0f} % ({_target(j)})")
        same = len(set(named_sets)) == 1
        print(f"  joint {j}: the runs name {'the same effects' if same else 'different effects'}: "
              + " | ".join(", ".join(s) or "nothing" for s in named_sets))
        # The runs logged one way (a filter before the log belongs to the recording path) diagnosed together:
        # each named effect judged on every run predicted from the others.
        rates = [round(ds.sample_rate_hz) for ds in dss]
        rate = max(set(rates), key=rates.count)
        together = [ds for ds, r in zip(dss, rates) if r == rate]
        if len(together) > 1:
            d = diagnose(together, dataset_model(together))
            worse = {e.name: [r for r, g in e.detail["across_runs_pct"].items() if g < -ACROSS_RUNS_WORSE_PCT]
                     for e in d.effects}
            per = "; ".join(f"{e.name} ({', '.join(f'{r} {g:.0f} %' for r, g in e.detail['across_runs_pct'].items())})"
                            for e in d.effects)
            print(f"  joint {j}, its {len(together)} runs at {rate:.0f} Hz together name: {per or 'nothing'} "
                  f"(each run's RMS lower with the effect, predicted from the others); "
                  + ("every effect lowers every run's" if not any(worse.values()) else
                     "worse with it: " + "; ".join(f"{n} on {', '.join(w)}" for n, w in worse.items() if w)))
            # What the library's effects leave on runs they were fitted to: no prediction from other runs does
            # better than this floor.
            floor = "; ".join(f"{a[0]} {a[2]:.3f} -> {b[2]:.3f} ({100 * b[2] / a[2]:.1f} %)" for a, b in
                              zip(residual_rms(together, dataset_model(together)), residual_rms(together, d.extended)))
            print(f"      in-sample, the runs by the model they extended (starting -> extended, Nm): {floor}")
        if len(dss) >= 3:
            # Leave one run out: the joint's other runs diagnosed together (their speeds differ), the run left
            # out predicted.
            ratios, left = [], []
            for k, ds in enumerate(dss):
                rest = dss[:k] + dss[k + 1:]
                start = dataset_model(rest)
                d = diagnose(rest, start)
                a, b = _rms(residual_rms([ds], start)), _rms(residual_rms([ds], d.extended))
                ratios.append(b / a)
                left.append(b)
                print(f"    {ds.path} left out: the other runs name {', '.join(sorted(e.name for e in d.effects))}; "
                      f"it is predicted {a:.3f} -> {b:.3f} Nm ({100 * b / a:.1f} % of the starting RMS)")
                alike = [o for o in rest if round(o.sample_rate_hz) == round(ds.sample_rate_hz)]
                if len(alike) not in (0, len(rest)):
                    # A filter before the log belongs to the recording path: from the runs logged as it was only.
                    start_alike = dataset_model(alike)
                    d_alike = diagnose(alike, start_alike)
                    a2, b2 = _rms(residual_rms([ds], start_alike)), _rms(residual_rms([ds], d_alike.extended))
                    gains = "; ".join(f"{e.name} ({', '.join(f'{r} {g:.0f} %' for r, g in e.detail.get('across_runs_pct', {}).items())})"
                                      for e in d_alike.effects)
                    print(f"      from the runs logged as it was only ({', '.join(str(o.path) for o in alike)}): they "
                          f"name {gains} (each of them predicted from the others, RMS lower with the effect); it is "
                          f"predicted {a2:.3f} -> {b2:.3f} Nm ({100 * b2 / a2:.1f} % of the starting RMS)")
                if all(abs(o.sample_rate_hz - ds.sample_rate_hz) > 1e-6 * ds.sample_rate_hz for o in rest):
                    # Logged another way: a filter before the log belongs to the recording path, which the other
                    # runs did not see. The joint's effects from them, the path's filter from the run alone.
                    joint_only = copy.deepcopy(d.extended)
                    joint_only.effects = [e for e in joint_only.effects if e.get("name") != "torque_log_filter"]
                    own = diagnose([ds], joint_only, candidates=["torque_log_filter"])
                    c = _rms(residual_rms([ds], own.extended))
                    f = own.effect("torque_log_filter")
                    print(f"      logged at {ds.sample_rate_hz:.0f} Hz, the others at "
                          f"{', '.join(sorted({f'{o.sample_rate_hz:.0f}' for o in rest}))} Hz: with its own path's "
                          f"filter ({'none named' if f is None else ', '.join(f'{k} {v:.3g}' for k, v in f.parameters.items())}"
                          f", identified on it alone) {c:.3f} Nm ({100 * c / a:.1f} %)")
            print(f"  joint {j}, leave one run out: {min(ratios) * 100:.0f}-{max(ratios) * 100:.0f} % of the "
                  f"starting RMS, {min(left):.3f}-{max(left):.3f} Nm ({_target(j)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
