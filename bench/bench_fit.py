"""Monte Carlo benchmark of ``iiwa-ident fit``: bias, spread and the Cramer-Rao bound.

For a fixed truth (Table I, Td = 5 ms) it simulates ``--seeds`` 30 s chirps
(default ``Chirp()``: 0.5-200 Hz, 10 Nm, 3 Nm bias) with the default sensor
noise, each seed starting at a random position within one encoder tick (the
quantisation error of a given trajectory is otherwise the same in every
seed and would show as bias, not spread), fits each with :func:`iiwa_ident.ident.fit_joint`
(``--method``, default ``eq4``: the output-error fit of eq (4) from start values of the data), and prints
per parameter:

- truth, mean of the estimates, bias (absolute and relative),
- std over seeds, the mean std the fit reported, and the RMS error,
- the Cramer-Rao bound (CRB): inverse Fisher information of the output-error
  model at the true parameters for white noise of the data's sensor levels
  (``tau_j``: 0.02 Nm; ``q_m``: encoder tick / sqrt(12)), computed from the
  model Jacobian on each seed's command and averaged. ``CRB`` includes the
  fit's nuisance terms (torque offset, position drift spline) as unknowns;
  ``CRB0`` is the plain model without them. ``CRBr`` is the bound for white
  noise at the levels the fit's residuals show (with the ripple these are
  far above the sensor noise: the ripple acts as a large disturbance),
- the ratios std / CRB (goal: at most 1.5), RMS error / CRB, std / CRBr,
  and the mean reported std over the std across seeds (calibration).

It runs three cases and says which goals are met: with the transmission
ripple (the default plant); without any effect (``plant.without_effects()``,
which keeps the robot's own feasibility filter: the slew-rate limit and the
standstill suppression); and, as checks of the estimator itself, a plant
the model describes exactly (no effects, no slew limit, no standstill
suppression), once with the encoder's quantisation and once with white
Gaussian position noise of the same RMS instead (the textbook setting of
the bound: quantisation error is a deterministic function of the position,
not independent noise). Not part of ``make test`` (about five minutes).

Run: ``.venv/bin/python bench/bench_fit.py [--seeds 20] [--method auto] [--cases 1 2]``.
"""

from __future__ import annotations

import argparse
import copy
import math
import time

import numpy as np

from iiwa_ident.excite import Chirp, record
from iiwa_ident.ident import METHODS, cramer_rao_std, fit_joint
from iiwa_ident.model import PARAMETER_NAMES
from iiwa_ident.sim import SimulatedJoint, default_plant

__all__ = ["TRUTH", "run_case", "main"]

TRUTH = {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}
_SCALE = {"Td": (1e3, "ms")}  # display Td in ms


def run_case(plant, seeds: int, duration_s: float, white_q: bool = False, method: str = "eq4") -> dict:
    """Fit ``seeds`` simulated chirps of ``plant``; return estimates, reported std and bounds.

    With ``white_q`` the encoder does not quantise; white noise of the
    quantisation's RMS is added to ``q_m`` instead.
    """
    tau_noise = plant.sensors["tau_noise_nm"]
    tick = plant.sensors["encoder_tick_rad"]
    q_noise = tick / math.sqrt(12.0)
    if white_q:
        plant = copy.deepcopy(plant)
        plant.sensors["encoder_tick_rad"] = 0.0
    est, rep, crb, crb0, crbr, noise, seconds = [], [], [], [], [], [], []
    for seed in range(seeds):
        rng = np.random.default_rng(10_000 + seed)
        q0 = rng.uniform(0.0, tick)
        ds = record(SimulatedJoint(plant, seed=seed, q0=q0), Chirp(duration_s=duration_s))
        if white_q:
            ds.signals["q_m"] = ds.signals["q_m"] + q_noise * rng.standard_normal(ds.n_samples)
        t0 = time.perf_counter()
        res = fit_joint([ds], method=method)
        seconds.append(time.perf_counter() - t0)
        est.append([res.parameters[k] for k in PARAMETER_NAMES])
        rep.append([res.std[k] for k in PARAMETER_NAMES])
        noise.append([res.noise[0]["tau_j_nm"], res.noise[0]["q_m_rad"]])
        b = cramer_rao_std(TRUTH, [ds], tau_noise, q_noise)
        b0 = cramer_rao_std(TRUTH, [ds], tau_noise, q_noise, nuisance=False)
        br = cramer_rao_std(TRUTH, [ds], res.noise[0]["tau_j_nm"], res.noise[0]["q_m_rad"])
        crb.append([b[k] for k in PARAMETER_NAMES])
        crb0.append([b0[k] for k in PARAMETER_NAMES])
        crbr.append([br[k] for k in PARAMETER_NAMES])
    return {"est": np.array(est), "rep": np.array(rep), "crb": np.array(crb), "crb0": np.array(crb0),
            "crbr": np.array(crbr),
            "noise": np.array(noise), "seconds": np.array(seconds), "tau_noise": tau_noise, "q_noise": q_noise,
            "q_kind": "white" if white_q else "quantisation"}


def _fmt(name: str, value: float) -> str:
    factor, _ = _SCALE.get(name, (1.0, ""))
    return f"{value * factor:.4g}"


def report(title: str, r: dict) -> dict[str, bool]:
    """Print one case's table; return which goals are met."""
    est, rep = r["est"], r["rep"]
    crb, crb0, crbr = r["crb"].mean(axis=0), r["crb0"].mean(axis=0), r["crbr"].mean(axis=0)
    truth = np.array([TRUTH[k] for k in PARAMETER_NAMES])
    mean = est.mean(axis=0)
    std = est.std(axis=0, ddof=1)
    bias = mean - truth
    rmse = np.sqrt(np.mean((est - truth) ** 2, axis=0))
    print(f"\n== {title}: {len(est)} seeds, fit {np.median(r['seconds']):.2f} s (median) ==")
    print(f"sensor noise: tau_j {r['tau_noise']:.3g} Nm, q_m {r['q_noise']:.3g} rad ({r['q_kind']}); "
          f"fit residual RMS (mean over seeds): tau_j {r['noise'][:, 0].mean():.3g} Nm, "
          f"q_m {r['noise'][:, 1].mean():.3g} rad")
    header = (f"{'param':<6}{'truth':>9}{'mean':>11}{'bias':>11}{'bias %':>9}{'std':>10}{'rep. std':>10}"
              f"{'RMSE':>10}{'CRB':>10}{'CRB0':>10}{'CRBr':>10}{'std/CRB':>8}{'RMSE/CRB':>9}{'std/CRBr':>9}"
              f"{'rep/std':>8}")
    print("units: SI, Td in ms")
    print(header)
    for i, k in enumerate(PARAMETER_NAMES):
        print(f"{k:<6}{_fmt(k, truth[i]):>9}{_fmt(k, mean[i]):>11}{_fmt(k, bias[i]):>11}"
              f"{100 * bias[i] / truth[i]:>8.3f}%{_fmt(k, std[i]):>10}{_fmt(k, rep[:, i].mean()):>10}"
              f"{_fmt(k, rmse[i]):>10}{_fmt(k, crb[i]):>10}{_fmt(k, crb0[i]):>10}{_fmt(k, crbr[i]):>10}"
              f"{std[i] / crb[i]:>8.2f}{rmse[i] / crb[i]:>9.2f}{std[i] / crbr[i]:>9.2f}"
              f"{rep[:, i].mean() / std[i]:>8.2f}")
    z = np.abs(est - truth) / rep
    print(f"estimates within 3 reported std: {int(np.sum(z <= 3))} of {z.size} ("
          + ", ".join(f"{k} {int(np.sum(z[:, i] <= 3))}/{len(est)}" for i, k in enumerate(PARAMETER_NAMES))
          + f"); worst {z.max():.1f} std")
    worst_rel = max(abs(bias[i]) / truth[i] + 2 * std[i] / truth[i] for i in range(4))
    goals = {
        "efficiency (std/CRB <= 1.5 for all, sensor noise)": bool(np.all(std / crb <= 1.5)),
        "efficiency of the RMS error (RMSE/CRB <= 1.5 for all)": bool(np.all(rmse / crb <= 1.5)),
        "efficiency at the residual levels (std/CRBr <= 1.5 for all)": bool(np.all(std / crbr <= 1.5)),
        "accuracy (|bias| + 2 std within 3 %, Td within 0.5 ms)":
            worst_rel <= 0.03 and abs(bias[4]) + 2 * std[4] <= 0.5e-3,
        "calibration (0.5 <= reported std / std <= 2 for all)":
            bool(np.all((rep.mean(axis=0) / std >= 0.5) & (rep.mean(axis=0) / std <= 2.0))),
        "no bias beyond noise (|bias| <= 3 std / sqrt(seeds) + 2 CRB)":
            bool(np.all(np.abs(bias) <= 3 * std / math.sqrt(len(est)) + 2 * crb)),
    }
    for goal, ok in goals.items():
        print(f"  {'met    ' if ok else 'NOT met'}  {goal}")
    return goals


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=30.0, help="chirp duration [s]")
    ap.add_argument("--method", default="eq4", choices=METHODS,
                    help="estimator (iiwa_ident.ident.METHODS; the fit command's default is auto)")
    ap.add_argument("--cases", type=int, nargs="*", default=None,
                    help="which cases to run, by number from 1 (default all)")
    args = ap.parse_args()
    print(f"method: {args.method}")
    print("truth (Table I): " + ", ".join(f"{k}={v:g}" for k, v in TRUTH.items()))
    plant = default_plant()
    for name, value in TRUTH.items():
        plant.dynamics[name] = value
    exact = plant.without_effects()
    exact.internal["slew_rate_nm_s"] = 1e7  # the plant format's maximum: never limits here
    exact.internal["standstill_torque_nm"] = 0.0  # torque control never suppressed
    cases = [("ripple on (default plant)", plant, False),
             ("ripple off (plant.without_effects())", plant.without_effects(), False),
             ("model exact (no effects, no slew limit, no standstill suppression)", exact, False),
             ("model exact, white position noise instead of quantisation", exact, True)]
    results = {}
    for title, p, white in [c for i, c in enumerate(cases, 1) if args.cases is None or i in args.cases]:
        results[title] = report(title, run_case(p, args.seeds, args.duration, white, args.method))
    print("\nsummary:")
    for title, goals in results.items():
        met = [g.split(" (")[0] for g, ok in goals.items() if ok]
        missed = [g.split(" (")[0] for g, ok in goals.items() if not ok]
        print(f"  {title}: met: {', '.join(met) or 'none'}; not met: {', '.join(missed) or 'none'}")


if __name__ == "__main__":
    main()
