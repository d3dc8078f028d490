"""Fleet ripple over the shared real iiwa 14 logs (one robot, five joints), on a local cluster and on a separately
started scheduler with two workers.

Usage: python bench/bench_fleet.py [--root DATA_ROOT] [--workers 2]

Prints, for each engine, the per-joint table (the fleet table's figures) and the wall time. The scheduler and its
workers are started as processes of their own (``dask scheduler``, ``dask worker``), as on a lab's machines.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from iiwa_ident.datasets import import_columns, set_robot_name, write_dataset
from iiwa_ident.fleet import run_fleet

ROBOT = "iiwa14-harvard"  # the one robot the shared logs are of


def import_real_logs(root: Path, folder: Path) -> list[Path]:
    """Every run of the constant-velocity logs as a dataset named after its robot."""
    out = []
    for run in sorted(root.glob("joint*/vel_*")):
        joint = int(run.parent.name.removeprefix("joint"))
        ds = import_columns({"t": run / "cur_traj_time_s.txt", "q_m": run / "joint_position_measured.txt",
                             "tau_j": run / "joint_torque_measured.txt"}, joint=joint,
                            experiment="constant_velocity", robot_model="iiwa14")
        set_robot_name(ds, ROBOT)
        out.append(write_dataset(folder / f"j{joint}_{run.name}.h5", ds))
    return out


def table(doc: dict) -> str:
    lines = ["| joint | runs | detected | period [rad] | std [rad] | cycles/rev | amplitude [µrad] | std [µrad] "
             "| error |",
             "|---|---|---|---|---|---|---|---|---|"]
    for g in sorted(doc["groups"], key=lambda g: (g["joint"] is None, g["joint"] or 0)):
        r = g.get("ripple") or {}
        det = r.get("detected")

        def num(key: str, fmt: str, scale: float = 1.0, r: dict = r, det: bool | None = det) -> str:
            v = r.get(key)
            return "" if v is None or not det else format(v * scale, fmt)

        lines.append(f"| {g['joint']} | {len(g['datasets'])} | {'yes' if det else 'no' if r else ''} | "
                     f"{num('period_rad', '.5f')} | {num('period_std_rad', '.1e')} | {num('cycles_per_rev', '.1f')} | "
                     f"{num('amplitude_rad', '.1f', 1e6)} | {num('amplitude_std_rad', '.1f', 1e6)} | "
                     f"{g['error'] or ''} |")
    return "\n".join(lines)


def separate_scheduler(workers: int, folder: Path):
    """Start ``dask scheduler`` and ``workers`` ``dask worker`` processes; return (address, processes)."""
    dask = Path(sys.executable).with_name("dask")
    sched_file = folder / "scheduler.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    procs = [subprocess.Popen([str(dask), "scheduler", "--scheduler-file", str(sched_file), "--port", "0",
                               "--dashboard-address", ":0"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    deadline = time.time() + 60
    while not sched_file.exists() and time.time() < deadline:
        time.sleep(0.2)
    for _ in range(workers):
        procs.append(subprocess.Popen([str(dask), "worker", "--scheduler-file", str(sched_file), "--nthreads", "1",
                                       "--nworkers", "1", "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
    from distributed import Client

    address = json.loads(sched_file.read_text())["address"]
    with Client(address) as client:
        client.wait_for_workers(workers, timeout=120)
    return address, procs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data" / "real")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    logs = args.root / "iiwa14-constant-velocity"
    if not logs.is_dir():
        sys.exit(f"{logs}: not found (give --root)")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = import_real_logs(logs, folder)
        print(f"{len(paths)} runs of robot {ROBOT} imported from {logs}")
        doc = run_fleet("ripple", paths, folder / "local", workers=args.workers)
        print(f"\nlocal cluster, {doc['engine']['workers']} worker processes: {doc['wall_s']:.1f} s "
              f"({len(paths) / doc['wall_s']:.2f} joint-runs/s)")
        print(table(doc))
        again = run_fleet("ripple", paths, folder / "local", workers=args.workers)
        print(f"the same again: {again['resumed']} of {len(again['groups'])} groups taken from the first run, "
              f"{again['wall_s']:.2f} s")
        address, procs = separate_scheduler(args.workers, folder)
        try:
            doc2 = run_fleet("ripple", paths, folder / "remote", scheduler=address)
        finally:
            for p in procs[::-1]:
                p.terminate()
            for p in procs:
                p.wait(30)
        print(f"\nseparate scheduler {address}, {doc2['engine']['workers']} workers: {doc2['wall_s']:.1f} s "
              f"({len(paths) / doc2['wall_s']:.2f} joint-runs/s)")
        print(table(doc2))
        # As JSON text: a NaN (a speed whose torque spectrum has no peak) is never equal to itself.
        same = (json.dumps([g.get("ripple") for g in doc["groups"]])
                == json.dumps([g.get("ripple") for g in doc2["groups"]]))
        print(f"same results on both engines: {same}")


if __name__ == "__main__":
    main()
