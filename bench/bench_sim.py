"""Benchmark: the simulated joint against a straightforward solve_ivp integration of the same model.

Simulates a 60 s exponential chirp on the default plant (Table I, ripple on)
at 1 kHz with 10 RK4 substeps a cycle, and prints medians of repeated runs:

- the compiled cycle function (batch, ``SimulatedJoint.run_open_loop``),
- the same function on casadi's virtual machine (the fallback without a C compiler),
- the closed-loop path through the robot interface (``start`` + ``step`` per cycle),
- the baseline: the plain NumPy model of :mod:`iiwa_ident.sim._reference`
  integrated by ``scipy.integrate.solve_ivp`` (RK45, rtol 1e-9), run on the
  first ``--baseline-seconds`` of the chirp because it is slow; its speed is
  given per simulated second, like the others.

Target (issue: foundation): 60 s simulated in at most 0.6 s (100x real time).
Run: ``.venv/bin/python bench/bench_sim.py``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np

from iiwa_ident.references import exponential_sweep
from iiwa_ident.robot import Command
from iiwa_ident.sim import SimulatedJoint, default_plant, simulate_reference


def chirp(seconds: float, dt: float = 1e-3) -> np.ndarray:
    t = np.arange(int(seconds / dt)) * dt
    # Start above the 1 Nm standstill threshold and ramp in within the slew limit: the baseline
    # models neither robot-side switch.
    ramp = np.minimum(t / 0.05, 1.0)
    return 1.5 + 1.5 * ramp + 10.0 * exponential_sweep(t, 0.5, 200.0, seconds) * ramp


def timed(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline-seconds", type=float, default=3.0)
    args = ap.parse_args()

    plant = default_plant()
    tau = chirp(args.seconds)

    with tempfile.TemporaryDirectory() as cache:
        os.environ["IIWA_IDENT_CACHE"] = cache  # cold compile, not a leftover
        t0 = time.perf_counter()
        joint = SimulatedJoint(plant, seed=1)
        build = time.perf_counter() - t0
        assert joint.model.compiled, "no C compiler: the compiled path could not be measured"
        fast = timed(lambda: joint.run_open_loop(tau), args.repeats)
        vm_joint = SimulatedJoint(plant, seed=1, compile=False)
        vm = timed(lambda: vm_joint.run_open_loop(tau), max(1, args.repeats // 2))

        n_step = 5000
        step_joint = SimulatedJoint(plant, seed=1)

        def stepped():
            step_joint.start()
            for x in tau[:n_step]:
                step_joint.step(Command(tau_c=float(x)))

        step = timed(stepped, 3)

    nb = int(args.baseline_seconds / plant.cycle_s)
    t0 = time.perf_counter()
    ref = simulate_reference(plant, tau[:nb])
    base = time.perf_counter() - t0
    hid = SimulatedJoint(plant).run_open_loop(tau[:nb]).hidden
    agree = np.abs(hid["tau_j"] - ref["tau_j"]).max()

    sim_s = args.seconds
    med_fast, med_vm, med_step = statistics.median(fast), statistics.median(vm), statistics.median(step)
    per_s_fast = med_fast / sim_s
    per_s_base = base / args.baseline_seconds
    print(f"plant: default (Table I, ripple on, {len(plant.effect('transmission_ripple').cos_coef)} harmonics), "
          f"1 kHz, {plant.substeps} RK4 substeps/cycle")
    print(f"build + compile (cold cache): {build:.2f} s")
    print(f"{'path':<34}{'wall for 60 s':>14}{'x real time':>13}")
    print(f"{f'compiled batch (median of {len(fast)})':<34}{med_fast:>13.3f}s{sim_s / med_fast:>13.0f}")
    print(f"{f'casadi VM batch (median of {len(vm)})':<34}{med_vm:>13.3f}s{sim_s / med_vm:>13.0f}")
    print(f"{'robot interface, per step':<34}{med_step / n_step * 60000:>13.3f}s{sim_s / (med_step / n_step * 60000):>13.1f}"
          f"   ({med_step / n_step * 1e6:.0f} us/cycle)")
    print(f"{f'solve_ivp baseline ({args.baseline_seconds:g} s run)':<34}{per_s_base * sim_s:>13.1f}s"
          f"{1 / per_s_base:>13.2f}")
    print(f"speed-up of compiled batch over solve_ivp: {per_s_base / per_s_fast:.0f}x")
    print(f"agreement with the baseline over {args.baseline_seconds:g} s: max |tau_j difference| = {agree:.2e} Nm "
          f"(tau_j range {np.ptp(ref['tau_j']):.1f} Nm)")
    target = med_fast <= 0.6 * sim_s / 60.0
    print(f"target 60 s in <= 0.6 s: {'met' if target else 'NOT met'}")


if __name__ == "__main__":
    main()
