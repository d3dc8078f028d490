"""Coverage of the payload the diagnosis says for a gravity load beyond the description's.

Run: ``.venv/bin/python bench/bench_payload.py [--draws 24]``. Each draw puts a random point mass (0.5-8 kg) at the
flange of the described iiwa 14 standing straight up, on joint 2, 4 or 6 in turn, records a 200 Hz
constant-velocity run over 1.2 rad and a hand-guided run of the simulated joint, diagnoses them from the joint's
starting model and compares the named payload with the mass, in units of its reported std.
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from iiwa_ident.description import gravity_sinusoid
from iiwa_ident.diagnose import diagnose
from iiwa_ident.ident import starting_model
from iiwa_ident.testing import described_runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=24)
    args = parser.parse_args()
    z, t0 = [], time.perf_counter()
    for k in range(args.draws):
        joint = (2, 4, 6)[k % 3]
        m = float(np.random.default_rng([k, 7]).uniform(0.5, 8.0))
        start = starting_model("iiwa14", joint)
        truth = copy.deepcopy(start)
        a, p = gravity_sinusoid("iiwa14", joint, [0.0] * 7, m)
        truth.effects[0].update(amplitude_nm=a, phase_rad=p + np.pi)
        e = diagnose(described_runs(truth, joint, 100 + 2 * k), start).effect("position_dependent_load")
        if e is None or "payload_kg" not in e.detail:
            print(f"draw {k:3d} joint {joint}: {m:.3f} kg, no load named")
            continue
        err, std = e.detail["payload_kg"] - m, e.detail["payload_std_kg"]
        z.append(err / std)
        print(f"draw {k:3d} joint {joint}: {m:.3f} kg, said {e.detail['payload_kg']:.4f} +- {std:.2g} "
              f"({err / std:+.2f} std)")
    z = np.abs(np.array(z))
    print(f"\n{len(z)} of {args.draws} draws named a load; |error| / std: median {np.median(z):.2f}, "
          f"within 2 std {np.mean(z <= 2):.0%} (stated 95 %), within 3 std {np.mean(z <= 3):.0%} (stated 99.7 %); "
          f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
