"""Slower closed-loop studies: the comparison with figures, and the pre-filter / filter-beta sweep.

Run: ``.venv/bin/python bench/bench_control.py [outdir]`` (PNGs go to ``outdir``, default /tmp).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from iiwa_ident.design import (
    AdditiveTorqueControl,
    FilterSettings,
    analysis_design,
    compare_controllers,
    identified_model,
    kappa_margin,
    sine_tracking,
)
from iiwa_ident.report import kappa_figure, pole_figure, tracking_figure


def main(outdir: str = "/tmp") -> None:
    out = Path(outdir)
    t0 = time.perf_counter()
    model = identified_model(seed=1)
    res = compare_controllers(model)
    print(f"comparison in {time.perf_counter() - t0:.1f} s")
    for kind in ("builtin", "additive"):
        m = res["step"][kind].metrics
        print(f"{kind:9s} step: overshoot raw {m.overshoot_raw:.2f} filt {m.overshoot_filt:.2f}, "
              f"settling {m.settling_time_s:.3f} s")
        for s in res["sine"][kind]:
            e = s.errors
            print(f"{kind:9s} {s.amplitude_nm:g} Nm @ {s.frequency_hz:g} Hz: raw peak {e.raw_peak:.2f} rms {e.raw_rms:.2f}"
                  f" | filt peak {e.filt_peak:.2f} rms {e.filt_rms:.2f} Nm")
        k = res["kappa"][kind]
        print(f"{kind:9s} kappa_max sim {k.kappa_max:.2f} (unstable at {k.kappa_unstable:.2f}), linear {k.linear:.2f}")
    print(f"ratio sim {res['kappa_ratio']:.2f}, linear {res['kappa_linear_ratio']:.2f}")
    for name, fn in (("tracking", tracking_figure), ("poles", pole_figure), ("kappa", kappa_figure)):
        fn(res).savefig(out / f"control_{name}.png", dpi=100)

    # Pre-filter of eq (22) and filter beta: 25 Hz error and simulated kappa_max.
    print("prefilter_hz beta  25Hz filt peak  kappa_max(additive)")
    for pf in (50.0, 250.0):
        design = analysis_design(model, prefilter_hz=pf)
        for beta in (5.0, 2.0):
            flt = FilterSettings(beta=beta)
            ctrl = AdditiveTorqueControl.from_model(model, design, filter=flt)
            e = sine_tracking(ctrl, None, 15.0, 25.0, model=model, filter=flt).errors
            k = kappa_margin("additive", None, model=model, design=design, filter=flt, rel_tol=0.08)
            print(f"{pf:12g} {beta:4g}  {e.filt_peak:14.2f}  {k.kappa_max:10.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
