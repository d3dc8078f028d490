"""The joint fit on chirps whose logged torque passed a driver's filter.

Draws ``--draws`` scenarios of the shared generator (:func:`iiwa_ident.testing.draw_scenario`: random
truths from wrist to base joints, chirp protocols, held or free links, 0-3 nuisances), half logged at 200 Hz and
half at 1 kHz, 20 s each. Each is simulated twice: with a first-order ``torque_log_filter`` of cut-off
log-uniform in 5-50 Hz (the simulator's effect: after the robot's loop, on the logged ``tau_j`` only), and
without it. :func:`iiwa_ident.ident.fit_joint` fits each, never told which. Printed per rate:

- filtered: the share fitted with ``K`` and ``Jl`` within 3 % and ``Td`` within 0.5 ms (the target), the
  same with ``Jc`` and ``bc`` too, the share with the filter in the model, the cut-off's median relative error
  and the share of cut-offs within 2 of their std of the truth (and of their model-error aware std, the
  phase's and the fit's estimates compared where the model misses part of the response), refusals;
- unfiltered: the same accuracy, and the share given a filter they do not have (false).

Run: ``.venv/bin/python bench/bench_fit_log_filter.py [--draws 24] [--first 0] [--jobs 2]``.
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite import Chirp, record
from iiwa_ident.sim import SimulatedJoint, make_effect
from iiwa_ident.testing import draw_scenario, scenario_plant

_REL, _TD_S = 0.03, 0.5e-3
RATES = (200.0, 1000.0)
CUTOFF_HZ = (5.0, 50.0)


def run_draw(seed: int) -> dict:
    """The scenario of ``seed`` with and without a drawn log filter, each fitted: the outcomes."""
    from iiwa_ident.ident import fit_joint

    rate = RATES[seed % 2]
    sc = draw_scenario(seed, duration_s=20.0, rate_hz=rate)
    rng = np.random.default_rng(seed + 104729)
    fc = float(math.exp(rng.uniform(*np.log(CUTOFF_HZ))))
    p = sc.protocol
    chirp = Chirp(f0_hz=p["f0_hz"], f1_hz=p["f1_hz"], duration_s=p["duration_s"], amplitude_nm=p["amplitude_nm"],
                  bias_nm=p["bias_nm"], hold_stiffness=30.0 if p["held"] else 0.0,
                  hold_damping=10.0 if p["held"] else 5.0)
    out = {"seed": seed, "rate": rate, "cutoff_hz": fc, "describe": sc.describe()}
    for kind in ("filtered", "plain"):
        plant = scenario_plant(sc)
        if kind == "filtered":
            plant = plant.with_effects(make_effect("torque_log_filter", {"cutoff_hz": fc}))
        ds = record(SimulatedJoint(plant, seed=sc.seed, q0=p["q0_rad"]), chirp)
        t0 = time.perf_counter()
        try:
            res = fit_joint([ds])
        except IiwaIdentError as err:
            out[kind] = {"refused": str(err)}
            continue
        err = {k: (res.parameters[k] - sc.truth[k]) if k == "Td" else res.parameters[k] / sc.truth[k] - 1.0
               for k in sc.truth}
        o = {"error": err, "fit_s": time.perf_counter() - t0, "log_filter": res.log_filter, "rejected": res.model_rejected,
             "target": abs(err["K"]) <= _REL and abs(err["Jl"]) <= _REL and abs(err["Td"]) <= _TD_S,
             "all": all(abs(err[k]) <= _REL for k in ("Jc", "bc", "K", "Jl")) and abs(err["Td"]) <= _TD_S}
        out[kind] = o
    return out


def _share(xs: list[bool]) -> str:
    return f"{sum(xs)}/{len(xs)}" if xs else "-"


def report(outcomes: list[dict]) -> None:
    for rate in RATES:
        rows = [o for o in outcomes if o["rate"] == rate]
        print(f"\n{rate:g} Hz logs ({len(rows)} draws, cut-offs {CUTOFF_HZ[0]:g}-{CUTOFF_HZ[1]:g} Hz):")
        for kind in ("filtered", "plain"):
            fitted = [o[kind] for o in rows if "refused" not in o[kind]]
            refused = [o for o in rows if "refused" in o[kind]]
            line = (f"  {kind:<9} K, Jl within 3 % and Td 0.5 ms: {_share([f['target'] for f in fitted])} of fitted; "
                    f"all five: {_share([f['all'] for f in fitted])}; refused {len(refused)}")
            print(line)
            if kind == "filtered":
                named = [(o["cutoff_hz"], o[kind]["log_filter"]) for o in rows
                         if "refused" not in o[kind] and o[kind]["log_filter"] is not None]
                rel = [abs(lf["cutoff_hz"] / fc - 1) for fc, lf in named]
                within = [abs(lf["cutoff_hz"] - fc) <= 2 * lf["std"] for fc, lf in named]
                robust = [abs(lf["cutoff_hz"] - fc) <= 2 * lf["std_robust"] for fc, lf in named]
                print(f"            filter in the model: {len(named)}/{len(fitted)}; cut-off median |error| "
                      f"{100 * float(np.median(rel)) if rel else float('nan'):.2f} % (worst "
                      f"{100 * max(rel) if rel else float('nan'):.2f} %), within 2 std: {_share(within)}, "
                      f"within 2 model-error aware std: {_share(robust)} (median "
                      f"{100 * float(np.median([lf['std_robust'] / fc for fc, lf in named])) if named else 0:.2f} %)")
            else:
                false = [f for f in fitted if f["log_filter"] is not None]
                print(f"            given a filter they do not have: {len(false)}/{len(fitted)}")
            for o in rows:
                f = o[kind]
                if "refused" in f:
                    print(f"    refused: {o['describe']}: {f['refused']}")
                elif not f["target"]:
                    e = f["error"]
                    print(f"    miss: {o['describe']}; cut-off {o['cutoff_hz']:.3g} Hz; K {100 * e['K']:+.2f} %, "
                          f"Jl {100 * e['Jl']:+.2f} %, Td {1e3 * e['Td']:+.3f} ms; filter {f['log_filter']}")
        times = [o[k]["fit_s"] for o in rows for k in ("filtered", "plain") if "fit_s" in o[k]]
        print(f"  fit time: median {float(np.median(times)):.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--draws", type=int, default=24)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    seeds = range(args.first, args.first + args.draws)
    with ProcessPoolExecutor(args.jobs) as pool:
        outcomes = list(pool.map(run_draw, seeds))
    report(outcomes)


if __name__ == "__main__":
    main()
