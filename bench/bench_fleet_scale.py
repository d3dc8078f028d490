"""Fleet scale: a simulated fleet identified with ``fleet ripple`` on a local cluster of 1 and 2 workers.

Usage: python bench/bench_fleet_scale.py [--robots 50] [--runs 2] [--worn 3] [--seed 0]

The fleet: ``--robots`` robots x 7 joints x ``--runs`` constant-velocity runs (0.3 and 0.6 rad/s over 0.6 rad,
200 Hz, position mode) of the simulated joint, whose dynamics are Table I's for every joint; the fleet spreads
in the ripple: per joint size (A1-A2, A3-A4, A5-A7) its period (assumed, not data-sheet facts: 320 / 256 / 200
cycles per revolution), per robot and joint its amplitude (log-normal, 30 %, around 20 urad), and ``--worn``
joints of the fleet carry 3x their ripple.
A joint is flagged worn when its detected ripple's amplitude is more than twice the fleet's median for that
joint (an undetected group's amplitude is no estimate).

Prints: wall time, joint-runs per second per worker, the peak memory of a worker process over the run (max RSS),
and which joints were flagged against the worn ones.
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
WORN_FACTOR = 3.0
FLAG_FACTOR = 2.0


def _cycles_per_rev(joint: int) -> float:
    return next(cpr for joints, cpr in SIZES if joint in joints)


def simulate_joint(robot: int, joint: int, amplitude_rad: float, runs: int, folder: str, seed: int) -> list[str]:
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
                    ConstantVelocity([0.3, 0.6], range_rad=0.6, mode="position"))
        set_robot_name(ds, f"robot{robot:02d}")
        # The joint number is the fleet's: the simulated joint stands in for each of the arm's seven.
        ds.joint = joint
        out.append(str(write_dataset(Path(folder) / f"r{robot:02d}_j{joint}_{r}.h5", ds)))
    return out


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=50)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--worn", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from distributed import Client, LocalCluster

    from iiwa_ident.fleet import run_fleet

    rng = np.random.default_rng(args.seed)
    joints = [(r, j) for r in range(args.robots) for j in range(1, 8)]
    worn = {joints[i] for i in rng.choice(len(joints), size=min(args.worn, len(joints)), replace=False)}
    amplitude = {key: 20e-6 * math.exp(rng.normal(0.0, 0.3)) * (WORN_FACTOR if key in worn else 1.0)
                 for key in joints}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            futures = [client.submit(simulate_joint, r, j, amplitude[(r, j)], args.runs, tmp, args.seed, pure=False)
                       for r, j in joints]
            paths = [p for f in futures for p in f.result()]
        print(f"fleet of {args.robots} robots x 7 joints x {args.runs} runs = {len(paths)} joint-runs simulated in "
              f"{time.perf_counter() - t0:.0f} s; worn: {sorted(worn)}")
        for workers in (1, 2):
            # The cluster started here, so that its workers' peak memory can be read after the whole run.
            with LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None,
                              env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
                              ) as cluster, Client(cluster) as client:
                doc = run_fleet("ripple", paths, Path(tmp) / f"fleet{workers}", scheduler=cluster.scheduler_address)
                rss = max(client.run(_peak_rss_mb).values())
            wall = doc["wall_s"]
            failed = [g for g in doc["groups"] if g["error"]]
            # Only a detected ripple's amplitude is an estimate; an undetected group's is the noise's best line.
            amp = {(int(g["robot"].removeprefix("robot")), g["joint"]): g["ripple"]["amplitude_rad"]
                   for g in doc["groups"] if not g["error"] and g["ripple"].get("detected")}
            detected = {size: sum(1 for (_, j) in amp if j in joints_) for joints_, _ in SIZES for size in [joints_]}
            flagged = set()
            for j in range(1, 8):
                values = [a for (r, jj), a in amp.items() if jj == j and a]
                median = float(np.median(values)) if values else math.nan
                flagged |= {(r, jj) for (r, jj), a in amp.items() if jj == j and a and a > FLAG_FACTOR * median}
            print(f"{workers} worker(s): {wall:.0f} s, {len(paths) / wall / workers:.2f} joint-runs per second per "
                  f"worker, {len(failed)} groups failed; ripple detected per joint size "
                  + ", ".join(f"A{'-A'.join(map(str, js))}: {n} of {args.robots * len(js)}" for js, n in detected.items())
                  + f"; peak memory of a worker {rss:.0f} MB; flagged {sorted(flagged)}; every worn joint and "
                  f"no other: {flagged == worn}")


if __name__ == "__main__":
    sys.exit(main())
