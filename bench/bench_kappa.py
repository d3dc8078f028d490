"""The outer loop's gain margin measured live through FRI against the emulator, beside its linear prediction.

Usage: python bench/bench_kappa.py [--scale 1.25] [--start 1 --factor 1.1 --max 40 --hold-s 2]

For each plant (the default, Table I; and one whose K and Td are ``--scale`` times and Jl ``2 - --scale`` times
the default's: 25 % more and 25 % less at 1.25), the pipeline identifies the joint, designs and deploys the additive controller and sweeps kappa
in lockstep for the Net F/T source and the runtime's estimate (its validation stage); for the estimate
also with the command's rate limits lifted (the robot's slew limit and the runtime's torque-rate limit; the
reference's rate limit stays), which shows what the linear prediction leaves out there.

Prints per plant, source and loop: the live bracket (last stable, first unstable kappa), the linear prediction
of the loop as deployed and how far it lies outside the bracket, and the ratio additive / built-in.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path


def _plant_file(scale: float, folder: Path) -> Path | None:
    """The default plant with K and Td times ``scale`` and Jl times ``2 - scale`` (each 25 % off at 1.25), as a
    plant file (None: the default)."""
    if scale == 1.0:
        return None
    from iiwa_ident.sim import default_plant, save_plant

    p = default_plant()
    d = dict(p.dynamics)
    d.update(K=d["K"] * scale, Jl=d["Jl"] * (2.0 - scale), Td=d["Td"] * scale)
    path = folder / f"plant_{scale:g}.toml"
    save_plant(dataclasses.replace(p, dynamics=d), path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.25)
    ap.add_argument("--start", type=float, default=1.0)
    ap.add_argument("--factor", type=float, default=1.1)
    ap.add_argument("--max", type=float, default=40.0)
    ap.add_argument("--hold-s", type=float, default=2.0)
    args = ap.parse_args()

    from iiwa_ident.deploy import read_config
    from iiwa_ident.design import read_design
    from iiwa_ident.pipeline import PipelineSettings, run_kappa_sweep, run_pipeline
    from iiwa_ident.runtime import SweepSettings
    from iiwa_ident.sim import default_plant, load_plant

    settings = SweepSettings(start=args.start, factor=args.factor, max=args.max, hold_s=args.hold_s)
    fmt = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731  (a one-line helper)
    print(f"{'plant':22} {'source':32} {'loop':9} {'stable to':>9} {'unstable':>9} {'linear':>8} {'outside':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for scale in (1.0, args.scale):
            name = "default" if scale == 1.0 else f"K,Td x{scale:g}, Jl x{2 - scale:g}"
            work = Path(tmp) / f"work_{scale:g}"
            plant_file = _plant_file(scale, Path(tmp))
            # The pipeline identifies, designs and deploys on this plant, then sweeps the F/T and the estimate.
            settings_p = PipelineSettings.full()
            settings_p = dataclasses.replace(settings_p, validation=dataclasses.replace(
                settings_p.validation, kappa=settings))
            t0 = time.perf_counter()
            run_pipeline(work, target="sim", plant=plant_file, progress=lambda _m: None, settings=settings_p,
                         skip=("diagnose",))
            sweeps = json.loads((work / "validation.json").read_text())["kappa"]["sweeps"]
            plant = load_plant(plant_file) if plant_file else default_plant()
            cfg, rec = read_config(work / "controller.toml"), read_design(work / "design.toml")
            lifted_plant = dataclasses.replace(plant, internal={**plant.internal, "slew_rate_nm_s": 1e7})
            lifted_cfg = dataclasses.replace(cfg, limits=dataclasses.replace(cfg.limits, torque_rate_nm_s=1e7))
            sweeps["estimate, no command rate limits"] = run_kappa_sweep(
                lifted_cfg, work / "lifted", record=rec, tau_ext="estimate", plant=lifted_plant, settings=settings)
            for label, out in sweeps.items():
                for loop in ("builtin", "additive"):
                    r = out[loop]
                    err = "-" if r["linear_error_pct"] is None else f"{r['linear_error_pct']:+.0f} %"
                    print(f"{name:22} {label:32} {loop:9} {fmt(r['live_limit']):>9} {fmt(r['unstable_at']):>9} "
                          f"{fmt(r['linear_limit']):>8} {err:>8}")
                print(f"{name:22} {label:32} ratio live {fmt(out['ratio_live'])}, linear {fmt(out['ratio_linear'])}")
            print(f"{name}: {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
