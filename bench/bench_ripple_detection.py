"""The ripple search's detection curve: measured on runs written apart from it, against its prediction.

A generator of its own (not the simulated joint, not the scenario generator): per draw one constant-speed run
in one direction, a line of a random period (250-450 cycles per revolution) and phase as a deflection of the
stated amplitude times K = 18500 Nm/rad in the joint torque, 0.1 Nm of noise (a third of the draws white, a
third AR(1) with pole 0.9, a third white noise through a first-order 12 Hz low-pass before logging, scaled to
the same level), the position quantised like the iiwa's encoder. A draw counts as detected when the search
reports the line's period within 0.5 %; detections at another period are counted apart.

The prediction (:func:`iiwa_ident.ident.detection_probability`) is given the noise's spectral
density at the line's frequency in each draw (the generator's own, divided by K^2), as ``ripple`` reads it off
a run. Prints per cell (rate, speed, travel, amplitude) the detected share, the share at a wrong period and the
predicted probability, and the cells where the detected share falls more than two binomial std below the
prediction; with ``--figure`` draws the curve.

Run: ``.venv/bin/python bench/bench_ripple_detection.py [--draws 10] [--workers 2] [--figure docs/ripple_detection.png]``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import scipy.signal as sg

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident import detection_probability, identify_ripple

__all__ = ["main"]

_K, _SIGMA_NM, _TICK, _FILTER_HZ = 18500.0, 0.1, 5.989e-8, 12.0
AMPLITUDES_URAD = (2.0, 5.0, 10.0, 20.0, 50.0)
TRAVELS_RAD = (0.3, 0.6, 1.0, 1.4, 2.0)
SPEEDS = (0.1, 0.3, 1.0)
RATES = (200.0, 1000.0)


def _noise(rng: np.random.Generator, n: int, rate: float, colour: str) -> tuple[np.ndarray, callable]:
    """Torque noise of std _SIGMA_NM and its one-sided PSD [Nm^2/Hz] as a function of frequency."""
    e = rng.standard_normal(n)
    if colour == "white":
        b, a = [1.0], [1.0]
    elif colour == "ar1":
        b, a = [math.sqrt(1 - 0.9 ** 2)], [1.0, -0.9]
    else:
        b, a = sg.butter(1, _FILTER_HZ / (rate / 2))
    impulse = np.zeros(4000)
    impulse[0] = 1.0
    gain = math.sqrt(float(np.sum(sg.lfilter(b, a, impulse) ** 2)))
    x = sg.lfilter(b, a, e) / gain * _SIGMA_NM

    def psd(f_hz: float) -> float:
        h = sg.freqz(b, a, worN=[f_hz], fs=rate)[1][0]
        return 2.0 * _SIGMA_NM ** 2 / rate * abs(h) ** 2 / gain ** 2

    return x, psd


def _one(args: tuple) -> tuple:
    rate, speed, travel, amp_urad, seed = args
    rng = np.random.default_rng(seed)
    cpr = rng.uniform(250.0, 450.0)
    colour = ("white", "ar1", "filtered")[seed % 3]
    t = np.arange(int(travel / speed * rate)) / rate
    q = rng.uniform(-1.0, 1.0) + speed * t
    noise, psd = _noise(rng, t.size, rate, colour)
    tau = 4.0 + _K * amp_urad * 1e-6 * np.sin(cpr * q + rng.uniform(0, 2 * math.pi)) + noise
    ds = Dataset(signals={"t": t, "q_m": np.round(q / _TICK) * _TICK, "tau_j": tau}, experiment="constant_velocity",
                 source="import", joint=1, sample_rate_hz=rate)
    f_hz = speed * cpr / (2 * math.pi)
    predicted = detection_probability(amp_urad * 1e-6, travel, speed, psd(min(f_hz, 0.499 * rate)) / _K ** 2, rate,
                                      cpr)
    try:
        r = identify_ripple([ds])
    except IiwaIdentError:
        return args, False, False, predicted
    right = bool(r.detected and abs(r.cycles_per_rev / cpr - 1) < 5e-3)
    return args, right, bool(r.detected and not right), predicted


def _figure(cells: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(RATES), len(SPEEDS), figsize=(11, 6.5), sharex=True, sharey=True)
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(TRAVELS_RAD)))
    for (i, rate), (j, speed) in itertools.product(enumerate(RATES), enumerate(SPEEDS)):
        ax = axes[i, j]
        for travel, c in zip(TRAVELS_RAD, colours):
            rows = [cells[(rate, speed, travel, a)] for a in AMPLITUDES_URAD]
            ax.plot(AMPLITUDES_URAD, [r["predicted"] for r in rows], "-", color=c, lw=1.2)
            ax.plot(AMPLITUDES_URAD, [r["detected"] for r in rows], "o", color=c, ms=4,
                    label=f"{travel:g} rad" if (i, j) == (0, 0) else None)
        ax.set_xscale("log")
        ax.set_xticks(AMPLITUDES_URAD, [f"{a:g}" for a in AMPLITUDES_URAD])
        ax.minorticks_off()
        ax.set_title(f"{rate:.0f} Hz, {speed:g} rad/s", fontsize=9)
        ax.grid(True, alpha=0.3)
        if i == len(RATES) - 1:
            ax.set_xlabel("deflection amplitude [µrad]")
        if j == 0:
            ax.set_ylabel("detection probability")
    axes[0, 0].legend(title="travel", fontsize=7, title_fontsize=7, loc="lower right")
    n = next(iter(cells.values()))["draws"]
    fig.suptitle(f"Ripple search, one run, {_SIGMA_NM:g} Nm torque noise through {_K:.0f} Nm/rad: measured "
                 f"(dots, {n} draws a cell) and predicted (lines)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=30000)
    parser.add_argument("--figure", default=None)
    args = parser.parse_args(argv)
    jobs = [(rate, speed, travel, amp, args.seed + d)
            for rate, speed, travel, amp in itertools.product(RATES, SPEEDS, TRAVELS_RAD, AMPLITUDES_URAD)
            for d in range(args.draws)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(_one, jobs, chunksize=8))
    cells: dict = {}
    for (rate, speed, travel, amp, _), right, wrong, predicted in rows:
        c = cells.setdefault((rate, speed, travel, amp), {"right": 0, "wrong": 0, "predicted": [], "draws": 0})
        c["right"] += right
        c["wrong"] += wrong
        c["predicted"].append(predicted)
        c["draws"] += 1
    low, wrong_total = [], 0
    print("rate_hz speed travel amplitude_urad detected wrong_period predicted")
    for key in sorted(cells):
        c = cells[key]
        c["detected"] = c["right"] / c["draws"]
        c["predicted"] = float(np.mean(c["predicted"]))
        wrong_total += c["wrong"]
        std = math.sqrt(max(c["predicted"] * (1 - c["predicted"]), 0.25 / c["draws"]) / c["draws"])
        if c["detected"] < c["predicted"] - 2 * std:
            low.append(key)
        print(f"{key[0]:7.0f} {key[1]:5.1f} {key[2]:6.1f} {key[3]:14.0f} {c['detected']:8.2f} "
              f"{c['wrong'] / c['draws']:12.2f} {c['predicted']:9.2f}")
    gap = np.array([cells[k]["detected"] - cells[k]["predicted"] for k in cells])
    print(f"cells: {len(cells)}, {args.draws} draws each; measured - predicted: median {np.median(gap):+.2f}, "
          f"mean {np.mean(gap):+.2f}; cells more than 2 binomial std below the prediction: {len(low)}; "
          f"detections at a wrong period: {wrong_total} of {len(rows)} draws")
    for key in low:
        print(f"  below: {key[0]:.0f} Hz, {key[1]:g} rad/s, {key[2]:g} rad, {key[3]:g} µrad: measured "
              f"{cells[key]['detected']:.2f}, predicted {cells[key]['predicted']:.2f}")
    if args.figure:
        _figure(cells, args.figure)
        print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
