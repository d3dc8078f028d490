"""Wall time of ``iiwa-ident pipeline`` on the default simulated joint (target: at most 60 s, full length).

Run: ``.venv/bin/python bench/bench_pipeline.py [--short] [--runs 1] [--workdir DIR]``.
Each run starts in a fresh process, as ``iiwa-ident pipeline`` does (the
import time counts), and prints the per-stage times and the total. The
machine is shared: the load average is printed beside each run.
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

CLI = str(Path(sys.executable).with_name("iiwa-ident"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--short", action="store_true", help="the short configuration of the tests")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--workdir", type=Path, default=None,
                        help="keep the outputs here (default: a temporary folder)")
    args = parser.parse_args()
    walls = []
    for i in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            workdir = args.workdir or Path(tmp) / "pipeline"
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            proc = subprocess.run([CLI, "pipeline", "--target", "sim", "--workdir", str(workdir)]
                                  + (["--short"] if args.short else []), capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if proc.returncode not in (0, 1):
                sys.exit(f"pipeline failed: {proc.stderr.strip()}")
            doc = json.loads((workdir / "pipeline.json").read_text())
        walls.append(wall)
        stages = ", ".join(f"{s['name']} {s['duration_s']:.1f}" for s in doc["stages"])
        print(f"run {i + 1}: {wall:.1f} s wall (load average {load:.2f} before) -- {stages}")
    config = "short" if args.short else "full"
    best = min(walls)
    verdict = "" if args.short else (" (target 60 s: met)" if best <= 60 else " (target 60 s: NOT met)")
    print(f"{config} pipeline on the default plant: best {best:.1f} s, median {sorted(walls)[len(walls) // 2]:.1f} s "
          f"of {len(walls)} run(s){verdict}")


if __name__ == "__main__":
    main()
