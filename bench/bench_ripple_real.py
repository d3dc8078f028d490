"""The ripple on every real joint: one row per joint of the real iiwa 14 logs.

Imports every run of every joint under ``../shared/data/real/iiwa14-constant-velocity`` (200 Hz, constant
speeds back and forth) and the joint-6 position chirp under ``../shared/data/real/iiwa14-position-chirp``
(1 kHz with gaps, speeds up to 3.3 rad/s), in memory, and runs :func:`iiwa_ident.ident.identify_ripple`
on each joint's runs together (every run is also analysed alone). Prints, per joint, the per-run periods
(cycles per revolution, with the harmonic of the joint's period each run sees), the joint's answer with its
std, the runs' agreement (chi2 p-value), the table's amplitude in rad and as a torque at Table I's K, and the
false-alarm probability; then the joint-6 chirp alone and with the constant-velocity runs. Where the runs
disagree the row says so.

Run: ``.venv/bin/python bench/bench_ripple_real.py [--root ../shared/data/real] [--no-chirp]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from iiwa_ident.datasets import Dataset, import_columns
from iiwa_ident.ident import RippleResult, identify_ripple

__all__ = ["load_run", "joint_runs", "main"]

_K = 18500.0  # Table I [Nm/rad]: the amplitude as a torque, f K
_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def load_run(folder: Path, joint: int, experiment: str = "constant_velocity", sign: float = 1.0) -> Dataset:
    """One run of the real logs (time, position, torque files; an iiwa 14), imported in memory with the
    torque times ``sign``."""
    return import_columns({"t": folder / "cur_traj_time_s.txt", "q_m": folder / "joint_position_measured.txt",
                           "tau_j": folder / "joint_torque_measured.txt"}, joint=joint, experiment=experiment,
                          robot_model="iiwa14", scale={"tau_j": sign})


def joint_runs(root: Path, sign: float = 1.0) -> dict[int, list[tuple[str, Dataset]]]:
    """Every constant-velocity run of every joint, by joint."""
    out: dict[int, list[tuple[str, Dataset]]] = {}
    for jd in sorted((root / "iiwa14-constant-velocity").glob("joint*")):
        j = int(jd.name.removeprefix("joint"))
        for rd in sorted(p for p in jd.iterdir() if p.is_dir()):
            ds = load_run(rd, j, sign=sign)
            ds.path = Path(f"j{j}/{rd.name}")
            out.setdefault(j, []).append((rd.name, ds))
    return out


def _row(label: str, r: RippleResult, seconds: float) -> str:
    """One Markdown row: the runs, the joint's answer, agreement, amplitude, false alarm, time."""
    alone = {r.lines.runs[i].name for c in r.lines.one_speed() for i, s in enumerate(c.significant) if s} \
        if r.lines is not None else set()

    def seen(x: dict) -> str:
        if not x["detected"]:
            return "beyond Nyquist" if "Nyquist" in x.get("reason", "") else "none"
        how = f"h{x['harmonic']}" if "harmonic" in x else "this speed only" if x["run"] in alone else "not in the family"
        return f"{x['cycles_per_rev']:.1f} ({how})"

    runs = "; ".join(f"{Path(x['run']).name} {x['speed_rad_s']:.2f} rad/s: {seen(x)}" for x in r.runs) or "one run"
    if r.detected:
        std_cpr = r.cycles_per_rev * r.period_std_rad / r.period_rad
        # The table's strongest harmonic: a period of two motor-side cycles shows as harmonic 2.
        h_dom = int(np.argmax(np.abs(np.fft.rfft(r.lut))[1:9])) + 1
        answer = (f"{r.cycles_per_rev:.2f} ± {std_cpr:.2f} ({r.period_rad:.5f} rad)"
                  + (f", strongest harmonic {h_dom} ({h_dom * r.cycles_per_rev:.1f})" if h_dom > 1 else ""))
        amp = f"{r.amplitude_rad * 1e6:.1f} µrad, {r.amplitude_rad * _K:.3f} Nm"
    else:
        answer, amp = "not decided" if r.agreement.get("verdict") == "disagree" else "none", "-"
    p = r.agreement.get("p_value")
    verdict = r.agreement.get("verdict", "-")
    agree = (f"{verdict}, p = {p:.2g}" if verdict == "reproduced" else f"p = {p:.2g}") if p is not None else verdict
    notes = "; ".join(w for w in r.warnings if any(x in w for x in ("weaker lines", "disagree", "edge", "rad/s only",
                                                                    "compensated", "periodic in time", "Nyquist",
                                                                    "eq (6): ", "the deflection about the table")))
    return (f"| {label} | {runs} | {answer} | {agree} | {amp} | {r.false_alarm:.1g} | {seconds:.0f} s |"
            + (f" {notes}" if notes else ""))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=_ROOT, help="folder of the real logs")
    parser.add_argument("--no-chirp", action="store_true", help="skip the joint-6 chirp (about a minute)")
    args = parser.parse_args(argv)
    if not (args.root / "iiwa14-constant-velocity").is_dir():
        print(f"{args.root}: no iiwa14-constant-velocity folder; give --root")
        return 2
    runs = joint_runs(args.root)
    print("| joint | runs: speed, cycles/rev (harmonic seen) | joint: cycles/rev ± std (period) | agreement "
          "| amplitude | false alarm | time |")
    print("|---|---|---|---|---|---|---|")
    for j, items in runs.items():
        t0 = time.perf_counter()
        r = identify_ripple([ds for _, ds in items])
        print(_row(str(j), r, time.perf_counter() - t0), flush=True)
    chirp_dir = args.root / "iiwa14-position-chirp" / "joint6"
    if not args.no_chirp and chirp_dir.is_dir():
        chirp = load_run(chirp_dir, 6, experiment="free")
        chirp.path = Path("j6/chirp")
        t0 = time.perf_counter()
        print(_row("6, chirp alone", identify_ripple([chirp]), time.perf_counter() - t0), flush=True)
        t0 = time.perf_counter()
        r = identify_ripple([ds for _, ds in runs.get(6, [])] + [chirp])
        print(_row("6, runs and chirp", r, time.perf_counter() - t0), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
