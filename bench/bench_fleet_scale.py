"""Fleet scale: a simulated fleet identified with ``fleet ripple`` on a local cluster of 1 and 2 workers.

Usage: python bench/bench_fleet_scale.py [--robots 50] [--runs 2] [--travel 1.3] [--amplitude 20] [--worn 3]
[--worn-factor 5] [--seed 0] [--workers 1,2]

The fleet: ``--robots`` robots x 7 joints x ``--runs`` constant-velocity runs (0.3 and 0.6 rad/s over ``--travel``
rad, 200 Hz, position mode) of the simulated joint, whose dynamics are Table I's for every joint; the fleet spreads
in the ripple: per joint size (A1-A2, A3-A4, A5-A7) its period (assumed, not data-sheet facts: 320 / 256 / 200
cycles per revolution), per robot and joint its amplitude (log-normal, 30 %, around ``--amplitude`` urad), and
``--worn``
joints of the fleet carry ``--worn-factor`` times their ripple.

Prints: wall time, joint-runs per second per worker, the peak memory of a worker process over the run (max RSS);
per joint size the ripples detected against the detection curve's prediction at each group's true amplitude
and period, from each run's noise level as ``ripple`` measured it: for the search over all the group's passes
pooled (:func:`iiwa_ident.ident.pooled_detection_probability`) and, as a lower bound, the groups
where at least one run's longest pass alone detects (:func:`~iiwa_ident.ident.detection_probability`);
and the joints the library flags as worn
(:func:`iiwa_ident.fleet.flag_worn`) against the worn ones, with each worn joint's ratio to the fleet's median and
its p-value.
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: Per joint size: (joints, ripple cycles per revolution) -- assumed.
SIZES = (((1, 2), 320.0), ((3, 4), 256.0), ((5, 6, 7), 200.0))


def _cycles_per_rev(joint: int) -> float:
    return next(cpr for joints, cpr in SIZES if joint in joints)


def simulate_joint(robot: int, joint: int, amplitude_rad: float, runs: int, travel_rad: float, folder: str,
                   seed: int) -> list[str]:
    """Record one robot's joint (its runs) and write the datasets; returns their paths (a Dask task)."""
    from iiwa_ident.datasets import set_robot_name, write_dataset
    from iiwa_ident.excite import ConstantVelocity, record
    from iiwa_ident.sim import SimulatedJoint, TransmissionRipple, default_plant

    cpr = _cycles_per_rev(joint)
    plant = default_plant().without_effects("transmission_ripple")
    plant = plant.with_effects(TransmissionRipple({"period_rad": 2 * math.pi / cpr,
                                                   "harmonics": [[amplitude_rad, 0.3 * joint]]}))
    plant.simulation["cycle_s"] = 1.0 / 200.0
    out = []
    for r in range(runs):
        ds = record(SimulatedJoint(plant, seed=seed + 1000 * robot + 10 * joint + r),
                    ConstantVelocity([0.3, 0.6], range_rad=travel_rad, mode="position"))
        set_robot_name(ds, f"robot{robot:02d}")
        # The joint number is the fleet's: the simulated joint stands in for each of the arm's seven.
        ds.joint = joint
        out.append(str(write_dataset(Path(folder) / f"r{robot:02d}_j{joint}_{r}.h5", ds)))
    return out


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def predicted_detection(group: dict, amplitude_rad: float, cycles_per_rev: float) -> float:
    """Probability that at least one of the group's runs alone detects its ripple, by the detection curve."""
    from iiwa_ident.ident import detection_probability

    miss = 1.0
    for run in (group["ripple"] or {}).get("sensitivity") or []:
        if run.get("psd_rad2_hz") is None:
            continue
        miss *= 1.0 - detection_probability(amplitude_rad, run["travel_rad"], run["speed_rad_s"], run["psd_rad2_hz"],
                                            run["rate_hz"], cycles_per_rev, run["false_alarm"])
    return 1.0 - miss


def predicted_pooled(group: dict, amplitude_rad: float, cycles_per_rev: float) -> float:
    """Probability that the search over all the group's passes together detects its ripple, by the pooled curve."""
    from iiwa_ident.ident import RunSensitivity, pooled_detection_probability

    runs = [RunSensitivity.from_json(dict(run, cycles_per_rev=cycles_per_rev))
            for run in (group["ripple"] or {}).get("sensitivity") or []]
    return pooled_detection_probability(amplitude_rad, runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=50)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--travel", type=float, default=1.3, help="travel of each run [rad]")
    ap.add_argument("--amplitude", type=float, default=20.0, help="the fleet's median ripple amplitude [urad]")
    ap.add_argument("--worn", type=int, default=3)
    ap.add_argument("--worn-factor", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", default="1,2", help="worker counts to time, comma separated")
    args = ap.parse_args()
    from distributed import Client, LocalCluster

    from iiwa_ident.fleet import run_fleet

    rng = np.random.default_rng(args.seed)
    joints = [(r, j) for r in range(args.robots) for j in range(1, 8)]
    worn = {joints[i] for i in rng.choice(len(joints), size=min(args.worn, len(joints)), replace=False)}
    amplitude = {key: args.amplitude * 1e-6 * math.exp(rng.normal(0.0, 0.3))
                 * (args.worn_factor if key in worn else 1.0) for key in joints}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            futures = [client.submit(simulate_joint, r, j, amplitude[(r, j)], args.runs, args.travel, tmp, args.seed,
                                     pure=False) for r, j in joints]
            paths = [p for f in futures for p in f.result()]
        print(f"fleet of {args.robots} robots x 7 joints x {args.runs} runs of {args.travel:g} rad = {len(paths)} "
              f"joint-runs simulated in {time.perf_counter() - t0:.0f} s; worn ({args.worn_factor:g}x): {sorted(worn)}")
        for workers in (int(w) for w in args.workers.split(",")):
            # The cluster started here, so that its workers' peak memory can be read after the whole run.
            with LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None,
                              env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
                              ) as cluster, Client(cluster) as client:
                doc = run_fleet("ripple", paths, Path(tmp) / f"fleet{workers}", scheduler=cluster.scheduler_address)
                rss = max(client.run(_peak_rss_mb).values())
            wall = doc["wall_s"]
            failed = [g for g in doc["groups"] if g["error"]]
            print(f"{workers} worker(s): {wall:.0f} s, {len(paths) / wall / workers:.2f} joint-runs per second per "
                  f"worker, {len(failed)} groups failed; peak memory of a worker {rss:.0f} MB")
        # The last run's table: detection against the curve, flags against the worn joints.
        key = {(int(g["robot"].removeprefix("robot")), g["joint"]): g for g in doc["groups"] if not g["error"]}
        for joints_, cpr in SIZES:
            rows = [(k, g) for k, g in key.items() if k[1] in joints_]
            # The curve predicts detection; where the search pools the runs it may detect more. How close the
            # detected periods are: within 0.5 % (the bound for real joints) and within 2 of their std.
            found = [g["ripple"] for _, g in rows if g["ripple"]["detected"]]
            near = sum(1 for r in found if abs(r["cycles_per_rev"] / cpr - 1) <= 5e-3)
            covered = sum(1 for r in found if abs(2 * math.pi / cpr - r["period_rad"]) <= 2 * r["period_std_rad"])
            expected = [predicted_detection(g, amplitude[k], cpr) for k, g in rows]
            pooled = [predicted_pooled(g, amplitude[k], cpr) for k, g in rows]
            std = math.sqrt(sum(p * (1 - p) for p in expected))
            std_pooled = math.sqrt(sum(p * (1 - p) for p in pooled))
            print(f"  A{'-A'.join(map(str, joints_))} ({cpr:.0f} cycles/rev): detected {len(found)} of {len(rows)}, "
                  f"the curve predicts {sum(pooled):.1f} +- {std_pooled:.1f} for the runs' passes pooled "
                  f"({sum(expected):.1f} +- {std:.1f} from any run alone); of those detected "
                  f"{near} within 0.5 % of the period, {covered} within 2 std")
        wear = doc["wear"]
        flagged = {(int(r.removeprefix("robot")), j) for r, j in wear["flagged"]}
        print(f"  worn flags (false-alarm probability {wear['false_alarm']:g} over {wear['compared']} joints "
              f"compared, healthy spread x{math.exp(wear['sigma_fleet'] or 0.0):.2f}): flagged {sorted(flagged)}; "
              f"worn and flagged {len(flagged & worn)} of {len(worn)}, flagged and not worn {len(flagged - worn)}")
        for k in sorted(worn):
            g = key.get(k)
            w = (g or {}).get("wear") or {}
            state = (f"ratio to the fleet's median {w['ratio']:.2f}, p = {w['p']:.1e}" if w.get("p") is not None
                     else w.get("why", "failed"))
            print(f"    worn {k}: amplitude {amplitude[k] * 1e6:.1f} urad; {state}; flagged {k in flagged}")
        for k in sorted(flagged - worn):
            g = key[k]
            r, w = g["ripple"], g.get("wear") or {}
            print(f"    flagged, not worn {k}: drawn {amplitude[k] * 1e6:.2f} urad, found {r['amplitude_rad'] * 1e6:.2f} "
                  f"+- {(r.get('amplitude_std_rad') or math.nan) * 1e6:.2f} urad at {r['cycles_per_rev']:.1f} cycles/rev "
                  f"(true {_cycles_per_rev(k[1]):.0f}); ratio {w.get('ratio', math.nan):.2f}, p = {w.get('p', math.nan):.1e}")


if __name__ == "__main__":
    sys.exit(main())
