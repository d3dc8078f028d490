"""Benchmark of ``diagnose`` on hidden-effect cases: hit rate, false positives, confusion, timing.

Run: ``.venv/bin/python bench/bench_diagnose.py [--cases 30] [--first-seed 1] [--causes] [--apart]``.
Each case hides 0, 1 or 2 random plant effects in the simulated joint
(:mod:`iiwa_ident.testing`), simulates the typical input and
diagnoses it with the Table I model (the case's own eq (4)); ``--causes``: a log filter or a link
spring, alone or beside another effect; ``--apart``: on the joint simulated apart from the project's
simulator.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

from iiwa_ident.diagnose import CANDIDATES
from iiwa_ident.testing import run_case


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--causes", action="store_true", help="a log filter or a link spring, alone or beside "
                        "one effect of the shared generator (draw_cause_case)")
    parser.add_argument("--apart", action="store_true", help="the second data path: a joint simulated apart from "
                        "the project's simulator (iiwa_ident.testing)")
    args = parser.parse_args()
    rows = []
    t0 = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.cases):
        r = run_case(seed, causes=args.causes, apart=args.apart)
        rows.append(r)
        status = "hit " if r["hit"] else "MISS"
        print(f"seed {seed:4d} {status} hidden={','.join(r['hidden']) or '-':<48} named={','.join(r['named']) or '-':<48}"
              f" bad={','.join(r['bad_parameters']) or '-'}  sim {r['simulate_s']:.1f} s, diagnose {r['diagnose_s']:.1f} s")
    n = len(rows)
    hits = sum(r["hit"] for r in rows)
    names_ok = sum(r["names_ok"] for r in rows)
    n_hidden = sum(len(r["hidden"]) for r in rows)
    n_false = sum(len(r["false"]) for r in rows)
    clean = [r for r in rows if not r["hidden"]]
    print()
    print(f"cases {n}: hit rate {hits / n:.0%} (names and parameters), names right {names_ok / n:.0%}")
    print(f"hidden effects {n_hidden}: missed {sum(len(r['missed']) for r in rows)}; "
          f"false positives {n_false} ({n_false / n:.2f} per case); clean cases with a false name "
          f"{sum(bool(r['false']) for r in clean)}/{len(clean)}")
    print("\nconfusion (hidden effect -> named set):")
    conf: dict[str, Counter] = {name: Counter() for name in CANDIDATES}
    for r in rows:
        for h in r["hidden"]:
            conf[h]["found" if h in r["named"] else "missed"] += 1
            for f in r["false"]:
                conf[h][f"+{f}"] += 1
        if not r["hidden"]:
            for f in r["false"]:
                conf.setdefault("(none)", Counter())[f"+{f}"] += 1
    for name, c in conf.items():
        if c:
            print(f"  {name:<26} " + ", ".join(f"{k}: {v}" for k, v in sorted(c.items())))
    sim = sum(r["simulate_s"] for r in rows)
    diag = sum(r["diagnose_s"] for r in rows)
    print(f"\ntiming: simulate {sim / n:.1f} s/case, diagnose {diag / n:.1f} s/case, total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
