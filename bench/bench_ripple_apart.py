"""The ripple's period on runs written apart from the search: how often within 1e-4, and nothing invented.

A generator of its own (not the simulated joint, not the scenario generator): per draw a period of 150-450
cycles per revolution, three runs at three speeds (0.15-1.0 rad/s, at least 1.3 apart, either sign), 3-5 s
each at 200, 500 or 1000 Hz; the motor at constant speed, its position quantised like the iiwa's encoder; the
joint torque a load, the deflection's sine (30-100 µrad, one phase for the transmission) times 185 Nm/rad,
white or coloured noise (AR(1), 0.02 Nm), and in half of the draws a hum at 15-80 Hz and a first-order filter
(8-40 Hz) before logging. Null draws are the same without the sine. Prints, over the draws, how many periods
lie within 1e-4 and 1e-3 of the truth, how many errors the reported std covers (2 std), how many of the
periods off by more than 1e-4 report a std that says so, the median relative error, and how many null draws
report a period, and each draw's Cramér-Rao bound (from its truth) with the count an efficient estimator
would place within 1e-4.

Run: ``.venv/bin/python bench/bench_ripple_apart.py [--draws 100] [--workers 2]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import scipy.signal as sg

from iiwa_ident.datasets import Dataset
from iiwa_ident.ident import identify_ripple

__all__ = ["draw", "main"]

_TICK = 5.989e-8


def _run(rng: np.random.Generator, speed: float, duration: float, rate: float, cpr: float, amp: float,
         phase: float, coloured: bool, hum_hz: float | None, filter_hz: float | None) -> Dataset:
    t = np.arange(int(duration * rate)) / rate
    q = rng.uniform(-1.0, 1.0) + speed * t
    e = rng.standard_normal(len(t))
    if coloured:
        e = sg.lfilter([math.sqrt(1 - 0.9 ** 2)], [1.0, -0.9], e)
    tau = 4.0 + 185.0 * amp * np.sin(cpr * q + phase) + 0.02 * e
    if hum_hz is not None:
        tau += 0.01 * np.sin(2 * math.pi * hum_hz * t + rng.uniform(0, 2 * math.pi))
    if filter_hz is not None:
        b, a = sg.butter(1, filter_hz / (rate / 2))
        tau = sg.lfilter(b, a, tau - tau[0]) + tau[0]
    return Dataset(signals={"t": t, "q_m": np.round(q / _TICK) * _TICK, "tau_j": tau},
                   experiment="constant_velocity", source="import", joint=1, sample_rate_hz=rate)


def _crb_rel(cpr: float, amp: float, runs: list[Dataset], coloured: bool) -> float:
    """Cramér-Rao bound on the relative std of the cycles per revolution, from this draw's truth.

    Each run's amplitude and phase are free (the filter before logging shifts each run's phase by its own
    temporal frequency); per run the information is ``B**2 N L**2 / (24 S)``, with ``B`` the torque
    amplitude, ``N`` samples over ``L`` rad of travel and ``S`` the noise's variance at the line's temporal
    frequency (the AR(1) colour raises it; the filter scales line and noise alike, the hum is left out).
    """
    b = 185.0 * amp
    info = 0.0
    for ds in runs:
        t, q = ds.signals["t"], ds.signals["q_m"]
        rate = ds.sample_rate_hz
        speed = abs(q[-1] - q[0]) / (t[-1] - t[0])
        s = 0.02 ** 2
        if coloured:
            w = cpr * speed / rate
            s *= (1 - 0.9 ** 2) / abs(1 - 0.9 * np.exp(-1j * w)) ** 2
        info += b ** 2 * len(t) * (q[-1] - q[0]) ** 2 / (24.0 * s)
    return math.inf if info == 0 else 1.0 / (math.sqrt(info) * cpr)


def draw(seed: int, null: bool = False) -> tuple[float, list[Dataset], str, float]:
    """One draw: the true cycles per revolution, its three runs, a description and its Cramér-Rao bound."""
    rng = np.random.default_rng(seed)
    cpr = rng.uniform(150.0, 450.0)
    amp = 0.0 if null else rng.uniform(30e-6, 100e-6)
    rate = float(rng.choice([200.0, 500.0, 1000.0]))
    while True:
        speeds = np.sort(rng.uniform(0.15, 1.0, 3))
        if speeds[1] > 1.3 * speeds[0] and speeds[2] > 1.3 * speeds[1]:
            break
    nuisance = rng.random() < 0.5
    hum = float(rng.uniform(15.0, 80.0)) if nuisance else None
    filt = float(rng.uniform(8.0, 40.0)) if nuisance else None
    coloured = bool(rng.random() < 0.5)
    phase = rng.uniform(0, 2 * math.pi)
    runs = [_run(rng, v * rng.choice([-1.0, 1.0]), rng.uniform(3.0, 5.0), rate, cpr, amp, phase, coloured,
                 hum if hum is not None and hum < 0.45 * rate else None, filt) for v in speeds]
    what = (f"{cpr:.1f} cpr, {amp * 1e6:.0f} µrad, {rate:.0f} Hz, {', '.join(f'{v:.2f}' for v in speeds)} rad/s"
            + (", coloured" if coloured else "") + (f", hum {hum:.0f} Hz, filter {filt:.0f} Hz" if nuisance else ""))
    return cpr, runs, what, _crb_rel(cpr, amp, runs, coloured)


def _one(args: tuple[int, bool]) -> tuple[int, bool, float, bool, float | None, float | None, str, float, float]:
    seed, null = args
    cpr, runs, what, crb = draw(seed, null)
    t0 = time.perf_counter()
    r = identify_ripple(runs)
    sec = time.perf_counter() - t0
    if not r.detected:
        return seed, null, cpr, False, None, None, what, sec, crb
    err = (r.cycles_per_rev - cpr) / cpr
    std = r.period_std_rad / r.period_rad
    return seed, null, cpr, True, err, std, what, sec, crb


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=20000)
    args = parser.parse_args(argv)
    jobs = [(args.seed + i, False) for i in range(args.draws)] + [(args.seed + i, True) for i in range(args.draws)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(_one, jobs))
    ripple = [r for r in rows if not r[1]]
    null = [r for r in rows if r[1]]
    found = [r for r in ripple if r[3]]
    errs = np.array([abs(r[4]) for r in found])
    within4 = int(np.sum(errs <= 1e-4))
    within3 = int(np.sum(errs <= 1e-3))
    covered = sum(abs(r[4]) <= 2 * r[5] for r in found)
    print(f"ripple draws: {len(ripple)}; detected {len(found)}; period within 1e-4: {within4}, within 1e-3: "
          f"{within3}; covered by 2 std: {covered} of {len(found)}; median |error| "
          f"{np.median(errs) if len(errs) else float('nan'):.2g}; median time {np.median([r[7] for r in rows]):.1f} s")
    crb = np.array([r[8] for r in ripple])
    reach = [r for r in ripple if 2 * r[8] <= 1e-4]
    best = float(np.sum([math.erf(1e-4 / (math.sqrt(2) * c)) for c in crb]))
    print(f"Cramér-Rao bound (relative std, per draw): median {np.median(crb):.2g}, range {crb.min():.2g}-"
          f"{crb.max():.2g}; an efficient estimator would place {best:.1f} of {len(ripple)} within 1e-4; "
          f"{len(reach)} draws have 2 bounds within 1e-4, of which {sum(r[3] and abs(r[4]) <= 1e-4 for r in reach)} "
          "are within 1e-4")
    if found:
        print(f"error / bound: median {np.median([abs(r[4]) / r[8] for r in found]):.2g}; reported std / bound: "
              f"median {np.median([r[5] / r[8] for r in found]):.2g}")
    off = [r for r in found if abs(r[4]) > 1e-4]
    print(f"of the {len(off)} detections off by more than 1e-4, {sum(2 * r[5] > 1e-4 for r in off)} say so: their "
          "own 2 std reach past 1e-4 (the data place the line no closer)")
    print(f"null draws: {len(null)}; a period reported on {sum(r[3] for r in null)}")
    for r in ripple:
        if not r[3] or abs(r[4]) > 1e-4:
            print(f"  seed {r[0]}: {r[6]}: " + ("not detected" if not r[3] else f"error {r[4]:+.2g}, std {r[5]:.2g}")
                  + f", bound {r[8]:.2g}")
    for r in null:
        if r[3]:
            print(f"  null seed {r[0]}: {r[6]}: reported")
    return 0


if __name__ == "__main__":
    sys.exit(main())
