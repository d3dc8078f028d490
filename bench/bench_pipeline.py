"""Wall time of ``iiwa-ident pipeline`` on the default simulated joint, whole and per stage, against the targets.

Run: ``.venv/bin/python bench/bench_pipeline.py [--short] [--runs 1] [--workdir DIR] [--profile N]``.
Each run starts in a fresh process, as ``iiwa-ident pipeline`` does (the
import time counts), and prints the per-stage times, the total and the wall time of ``iiwa-ident report
--workdir`` on the folder it left. The
machine is shared: the load average is printed beside each run. With
``--profile N`` one run goes in this process under :mod:`cProfile` instead,
and each stage's N functions of most own time are printed (the profiler
slows pure-Python code more than compiled code: the shares, not the times,
are the finding).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
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
    parser.add_argument("--profile", type=int, default=0, metavar="N",
                        help="profile one run in this process: each stage's N functions of most own time")
    args = parser.parse_args()
    if args.profile:
        profile(args.short, args.profile)
        return
    walls, per_stage = [], {}
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
            # The report again from the folder's files, as a user asks for it (wall, with start-up).
            t0 = time.perf_counter()
            again = subprocess.run([CLI, "report", "--workdir", str(workdir), "--out", str(workdir / "again.pdf")],
                                   capture_output=True, text=True)
            report_again = time.perf_counter() - t0
            if again.returncode != 0:
                sys.exit(f"report --workdir failed: {again.stderr.strip()}")
        walls.append(wall)
        for st in doc["stages"]:
            per_stage.setdefault(st["name"], []).append(st["duration_s"])
        per_stage.setdefault("report --workdir", []).append(report_again)
        stages = ", ".join(f"{s['name']} {s['duration_s']:.1f}" for s in doc["stages"])
        print(f"run {i + 1}: {wall:.1f} s wall (load average {load:.2f} before) -- {stages}; "
              f"report --workdir {report_again:.1f} s wall")
    config = "short" if args.short else "full"
    print(f"{config} pipeline on the default plant, {len(walls)} run(s): median (best) per stage [s]")
    rows = [(name, times) for name, times in per_stage.items()] + [("total (wall)", walls)]
    for name, times in rows:
        target = None if args.short else TARGETS_S.get("total" if name.startswith("total") else name)
        med = sorted(times)[len(times) // 2]
        verdict = "" if target is None else f"  target {target:g} s: {'met' if med <= target else 'NOT met'}"
        print(f"  {name:18s} {med:6.1f} ({min(times):.1f}){verdict}")


#: Per-stage targets of the full pipeline on 2 idle cores [s] (the fit's is that of a 30 s chirp). The
#: validation's includes the live kappa sweeps: about 75 s of simulated time for the additive controller
#: with the F/T (kappa from 1 by 1.1 to its onset near 30, 2 s a step), run in lockstep beside the others.
TARGETS_S = {"fit": 2.0, "ripple": 6.0, "validation": 75.0, "report": 6.0, "total": 100.0}


def profile(short: bool, top: int) -> None:
    """One pipeline run in this process, a profiler per stage (started and stopped by its progress lines)."""
    from iiwa_ident.pipeline import run_pipeline
    from iiwa_ident.report import build_report

    current: dict[str, object] = {}

    def progress(line: str) -> None:
        # "[i/n] NAME: TITLE ..." starts a stage; "[i/n] NAME: <status> in ..." ends it.
        name = line.split("] ", 1)[-1].split(":", 1)[0]
        if line.endswith("..."):
            current["name"], current["prof"] = name, cProfile.Profile()
            current["prof"].enable()
        elif current.get("name") == name:
            current["prof"].disable()
            out = io.StringIO()
            stats = pstats.Stats(current["prof"], stream=out)
            total = stats.total_tt
            print(f"{line}  (profiled: {total:.1f} s)")
            stats.sort_stats("tottime").print_stats(top)
            rows = [r for r in out.getvalue().splitlines()
                    if r.strip()[:1].isdigit() and "function calls" not in r]
            for row in rows[:top]:
                print("    " + row.strip())
            current.clear()

    with tempfile.TemporaryDirectory() as tmp:
        run_pipeline(Path(tmp) / "pipeline", target="sim", short=short, progress=progress, report=build_report)


if __name__ == "__main__":
    main()
