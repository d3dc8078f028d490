"""Monte Carlo benchmark of the multisine fit: bias, spread, reported std, coverage and the Cramer-Rao bound.

For a fixed truth (``bench_fit.TRUTH``) it simulates ``--seeds`` multisine experiments (1-100 Hz odd lines,
2 s period, 2 steady-state periods x 4 realisations, 10 Nm peak, 3 Nm bias, 6 s lead-in: 30 s, as long as
``bench_fit``'s chirp), fits each through its best linear approximation
(:func:`iiwa_ident.ident.fit_bla`) and prints per parameter the bias, the std over seeds, the mean
reported std, their ratio (calibration), the share of 95 % intervals covering the truth and the
Cramer-Rao bound of the same data for white noise at the sensor levels
(:func:`iiwa_ident.ident.cramer_rao_std`, the time-domain model on each seed's command; for any
unbiased estimator from these samples). Cases: the default plant (the paper's ripple), the plant without
effects, and the model exact (no effects, no slew limit, no standstill suppression).

Run: ``.venv/bin/python bench/bench_bla.py [--seeds 20]``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fit import TRUTH  # noqa: E402  (the same truth as the chirp benchmark)

from iiwa_ident.excite import Multisine, record  # noqa: E402  (after bench/ is on the path, as above)
from iiwa_ident.ident import best_linear_approximation, cramer_rao_std, fit_bla  # noqa: E402  (as above)
from iiwa_ident.model import PARAMETER_NAMES
from iiwa_ident.sim import SimulatedJoint, default_plant  # noqa: E402  (as above)


def run_case(plant, seeds: int) -> dict:
    tau_noise = plant.sensors["tau_noise_nm"]
    q_noise = plant.sensors["encoder_tick_rad"] / math.sqrt(12.0)
    est, rep, crb, chi2 = [], [], [], []
    for seed in range(seeds):
        exp = Multisine(1.0, 100.0, period_s=2.0, periods=2, realisations=4, amplitude_nm=10.0, bias_nm=3.0,
                        seed=seed)
        ds = record(SimulatedJoint(plant, seed=seed), exp)
        fit = fit_bla(best_linear_approximation(ds), 1.0 / ds.sample_rate_hz)
        est.append([fit.parameters[k] for k in PARAMETER_NAMES])
        rep.append([fit.std[k] for k in PARAMETER_NAMES])
        chi2.append(fit.chi2_dof)
        b = cramer_rao_std(TRUTH, [ds], tau_noise, q_noise)
        crb.append([b[k] for k in PARAMETER_NAMES])
    return {"est": np.array(est), "rep": np.array(rep), "crb": np.array(crb), "chi2": np.array(chi2)}


def report(title: str, r: dict) -> None:
    truth = np.array([TRUTH[k] for k in PARAMETER_NAMES])
    est, rep, crb = r["est"], r["rep"], r["crb"]
    bias = est.mean(axis=0) - truth
    spread = est.std(axis=0, ddof=1)
    cover = np.mean(np.abs(est - truth) <= 1.96 * rep, axis=0)
    print(f"\n{title}: {len(est)} seeds, chi2/dof median {np.median(r['chi2']):.2f}")
    print("  param   bias [%]   spread [%]  reported [%]  reported/spread  95 % cover  spread/CRB  reported/CRB")
    for i, k in enumerate(PARAMETER_NAMES):
        print(f"  {k:<5s} {100 * bias[i] / truth[i]:10.3f} {100 * spread[i] / truth[i]:11.4f} "
              f"{100 * rep[:, i].mean() / truth[i]:12.4f} {rep[:, i].mean() / spread[i]:15.2f} "
              f"{100 * cover[i]:10.0f} % {spread[i] / crb[:, i].mean():10.2f} {rep[:, i].mean() / crb[:, i].mean():12.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    plant = default_plant()
    plant.dynamics.update(TRUTH)
    exact = plant.without_effects()
    exact.internal["slew_rate_nm_s"] = 1e7
    exact.internal["standstill_torque_nm"] = 0.0
    for title, p in (("ripple on (default plant)", plant), ("ripple off (plant.without_effects())",
                                                            plant.without_effects()),
                     ("model exact (no effects, no slew limit, no standstill suppression)", exact)):
        report(title, run_case(p, args.seeds))


if __name__ == "__main__":
    main()
