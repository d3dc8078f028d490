"""Subcommand ``ripple``: find the transmission nonlinearity's period and lookup table (section III)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from iiwa_ident._defaults import PERIOD_MAX_RAD, PERIOD_MIN_RAD
from iiwa_ident.cli._app import (
    STARTING_MODEL,
    app,
    datasets_argument,
    fail,
    figures_option,
    json_option,
    model_option,
    write_json,
)
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    from iiwa_ident.ident import RippleResult

__all__ = ["ripple_cmd", "format_ripple"]


def format_ripple(r: RippleResult) -> str:
    """A readable summary: verdict, period in three units, methods, eq (6)."""
    import numpy as np

    lines = []
    if not r.detected and r.agreement.get("verdict") == "disagree":
        lines.append("the runs disagree on the period (table below): the data do not decide, nothing is written "
                     "as a ripple table")
    elif not r.detected and r.agreement.get("verdict") == "temporal":
        lines.append("the line found is periodic in time, not in position (warning below): nothing is written as a "
                     "ripple table")
    elif not r.detected:
        lines.append(f"no periodic nonlinearity: the strongest line has false-alarm probability {r.false_alarm:.2g} "
                     f"(T² = {r.statistic:.1f}); nothing is written as a ripple table")
    else:
        amplitude = r.amplitude_rad if r.amplitude_rad is not None else math.nan  # set when detected
        lines += [
            f"periodic transmission deflection detected (false-alarm probability {r.false_alarm:.1e})",
            f"  period rho     {r.period_rad:.6f} rad  (std {r.period_std_rad:.1e} rad)",
            f"                 {r.cycles_per_rev:.2f} cycles per joint revolution",
            f"                 {r.period_ticks:.0f} encoder ticks (5.989e-8 rad a tick)",
            f"  amplitude      {amplitude * 1e6:.2f} µrad (half peak-to-peak of the table; std "
            + (f"{r.amplitude_std_rad * 1e6:.2f} µrad)" if r.amplitude_std_rad is not None
               else "unknown: fewer than three passes)"),
            f"  link motion    {r.link_motion}",
            "",
            f"  {'method':<10}{'passes':>7}{'samples':>9}{'harmonics':>10}{'ampl [µrad]':>13}{'rms [µrad]':>12}"
            f"{'resid [µrad]':>14}{'shift [µrad]':>14}",
        ]
        for name, m in r.methods.items():
            lines.append(f"  {name:<10}{m.n_passes:>7}{m.n_samples:>9}{m.harmonics:>10}{m.amplitude_rad * 1e6:>13.2f}"
                         f"{m.rms_rad * 1e6:>12.2f}{m.residual_rms_rad * 1e6:>14.2f}{m.shift_rad * 1e6:>14.2f}")
        if len(r.methods) == 2:
            diff = r.methods["static"].lut - r.methods["dynamic"].lut
            lines.append(f"  static vs dynamic table: RMS difference {np.sqrt(np.mean(diff ** 2)) * 1e6:.2f} µrad")
        lines += ["", "  eq (6), f = |v| / rho:", f"  {'speed [rad/s]':>15}{'predicted [Hz]':>16}{'measured [Hz]':>15}"]
        for row in r.velocity_table:
            measured = "-" if math.isnan(row["measured_hz"]) else f"{row['measured_hz']:.1f}"
            lines.append(f"  {row['speed_rad_s']:>15.2f}{row['predicted_hz']:>16.1f}{measured:>15}")
    if r.runs:
        lines += ["", f"  {'run':<40}{'speed [rad/s]':>14}{'cycles/rev':>12}{'std':>9}{'harmonic':>10}  verdict"]
        agree = set(r.agreement.get("agree", []))
        alone = _one_speed_runs(r)
        for run in r.runs:
            name = run["run"] if len(run["run"]) <= 38 else "..." + run["run"][-35:]
            if not run["detected"]:
                verdict = ("unusable: " + run["reason"] if not run["usable"] else
                           "beyond its Nyquist limit" if "Nyquist" in run.get("reason", "") else "no detection")
                lines.append(f"  {name:<40}{run['speed_rad_s']:>14.3f}{'-':>12}{'-':>9}{'-':>10}  {verdict}")
                continue
            std_cpr = run["cycles_per_rev"] * run["period_std_rad"] / run["period_rad"]
            std = f"{std_cpr:.2f}" if math.isfinite(std_cpr) else "-"
            lines.append(f"  {name:<40}{run['speed_rad_s']:>14.3f}{run['cycles_per_rev']:>12.2f}{std:>9}"
                         f"{run.get('harmonic', '-'):>10}  {_run_verdict(run, agree, alone)}")
        a = r.agreement
        if a.get("chi2") is not None:
            lines.append(f"  agreement: chi2 {a['chi2']:.2f} on {a['dof']} dof (p = {a['p_value']:.2g}); "
                         f"std widened by the Birge ratio {a['birge_ratio']:.2f}")
        elif a.get("verdict") == "none":
            lines.append("  no run detects a periodic deflection")
    if r.lines is not None and r.lines.shown():
        lines += ["", _lines_table(r.lines)]
    if r.sensitivity:
        lines += ["", f"what each run detects (one run alone, false-alarm probability {r.sensitivity[0].false_alarm:g}):"]
        names = [row["run"] for row in r.runs] if r.runs else []
        for x in r.sensitivity:
            name = names[x.dataset] if x.dataset < len(names) else f"run {x.dataset + 1}"
            lines.append("  " + x.sentence(name))
    for w in r.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def _one_speed_runs(r: RippleResult) -> set[str]:
    """Runs whose own line is significant at their speed only (not reproduced, not temporal)."""
    if r.lines is None:
        return set()
    out = set()
    for c in r.lines.one_speed():
        for run, row in zip(r.lines.runs, r.runs):
            if row.get("detected") and abs(row["cycles_per_rev"] / c.cycles_per_rev - 1) < 3e-3:
                out.add(run.name)
    return out


def _lines_table(x) -> str:
    """Each candidate line worth a row, tested in every run: amplitude [µrad] and p-value (* significant)."""
    head = f"  lines tested in every run: amplitude [µrad] (p-value), * significant at p < {x.alpha:.1g}"
    rows = [head, f"  {'cycles/rev':>11}{'in family':>11}" + "".join(f"{'run ' + str(i + 1):>19}"
                                                                      for i in range(len(x.runs)))]
    h_of = {id(c): h for c, h in x.harmonics}
    for c in x.shown():
        tag = f"h{h_of[id(c)]}" if id(c) in h_of else ("temporal" if c.temporal_hz is not None else "-")
        cells = []
        for i, t in enumerate(c.tests):
            cells.append("not tested" if not t.tested else
                         f"{t.amplitude_rad * 1e6:.2f} ({c.p_value(i):.0e}){'*' if c.significant[i] else ' '}")
        # A family line where the compensated period puts it; another line where the runs that show it do.
        k = h_of[id(c)] * x.k_ref if id(c) in h_of and x.k_ref else x.seen_k(c)
        rows.append(f"  {2 * math.pi * k:>11.2f}{tag:>11}" + "".join(f"{cell:>19}" for cell in cells))
    rows.append("  runs: " + "; ".join(f"{i + 1} = {run.name} ({run.speed:.2f} rad/s)" for i, run in enumerate(x.runs)))
    return "\n".join(rows)


def _run_verdict(run: dict, agree: set, alone: set) -> str:
    """How a run's line stands against the joint's period: it agrees (its fundamental, or a subharmonic seen at
    this speed only whose harmonic is the period's line), it is seen at this speed only, or it disagrees."""
    if run["run"] in agree:
        return "agrees (its own line: this speed only)" if run["run"] in alone else "agrees"
    return "this speed only" if run["run"] in alone else "disagrees"


@app.command("ripple")
def ripple_cmd(
    data: Annotated[list[Path], datasets_argument("Constant-velocity and/or quasi-static datasets of one joint")],
    model: Annotated[Optional[Path], model_option("Model file for K and Jl", STARTING_MODEL + ", else Table I "
                                                  "borrowed")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", help="Model file to write, with the ripple table.")] = None,
    json_out: Annotated[Optional[Path], json_option("the result")] = None,
    figures: Annotated[Optional[Path], figures_option()] = None,
    bins: Annotated[int, typer.Option("--bins", help="Lookup-table size.")] = 256,
    period_min: Annotated[float, typer.Option("--period-min", help="Shortest period searched [rad].",
                                              show_default=f"{PERIOD_MIN_RAD:.4g} rad, "
                                                           f"{2 * math.pi / PERIOD_MIN_RAD:.0f} per revolution")
                          ] = PERIOD_MIN_RAD,
    period_max: Annotated[float, typer.Option("--period-max", help="Longest period searched [rad].",
                                              show_default=f"{PERIOD_MAX_RAD:.4g} rad, "
                                                           f"{2 * math.pi / PERIOD_MAX_RAD:.0f} per revolution")
                          ] = PERIOD_MAX_RAD,
    link_motion: Annotated[str, typer.Option("--link-motion", help="auto | restored | neglected (dynamic method).")] = "auto",
    amplitude_of_interest: Annotated[float, typer.Option(
        "--amplitude-of-interest", min=0.01, help="Deflection amplitude [µrad] for which each run that does not "
        "detect it is told what run would (at its speed or the fastest slower one).")] = 10.0,
) -> None:
    """Find the period and lookup table of the transmission deflection of eq (5).

    Uses every run given together: constant-velocity runs (dynamic method, also
    200 Hz position-controlled logs without a torque command) and quasi-static
    runs with the link reference (static method). With several runs each is
    also analysed alone: a table of the per-run periods, which harmonic of the
    joint's period each one sees, and their agreement; runs that disagree are
    reported and nothing is written as a table.

    Example:
      iiwa-ident simulate constant_velocity --velocity 0.3,0.6,1.2 --out cv.h5
      iiwa-ident ripple cv.h5 --model model.toml --out model_ripple.toml --json ripple.json
    """
    from iiwa_ident.datasets import dataset_files, read_dataset, sha256_file
    from iiwa_ident.ident import model_for, ripple_model, write_model
    from iiwa_ident.model import Source

    try:
        data = dataset_files(data)
        datasets = [read_dataset(p) for p in data]
        base = model_for(datasets, model, borrow=True)
        with progress(f"searching the ripple's period in {len(datasets)} run(s)"):
            model_out, result = ripple_model(base, datasets, [Source(str(p), sha256_file(p), "ripple") for p in data],
                                             period_min=period_min, period_max=period_max, bins=bins,
                                             link_motion=link_motion,
                                             amplitude_of_interest=amplitude_of_interest * 1e-6)
        typer.echo(format_ripple(result))
        if out:
            write_model(out, model_out)
            typer.echo(f"wrote {out}")
        if json_out:
            write_json(json_out, result.to_json())
        if figures:
            from iiwa_ident.report import (
                lookup_table_figure,
                spatial_spectrum_figure,
                velocity_frequency_figure,
            )

            figures.mkdir(parents=True, exist_ok=True)
            for name, fn in (("ripple_spectrum", spatial_spectrum_figure), ("ripple_lut", lookup_table_figure),
                             ("ripple_velocity", velocity_frequency_figure)):
                fig = fn(result)
                fig.savefig(figures / f"{name}.png", dpi=110)
            typer.echo(f"figures in {figures}")
    except IiwaIdentError as err:
        raise fail(str(err)) from None
