"""Figures of the closed-loop validation through FRI: step and sine (Figs. 8-9), kappa margin, parameter table.

The tracking figures read the run logs of
:func:`iiwa_ident.pipeline.run_validation`; every function returns
a matplotlib Figure (Agg backend) and leaves saving to the caller.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Rectangle

from iiwa_ident.datasets import read_dataset
from iiwa_ident.pipeline import reference_of

__all__ = ["tracking_run_figure", "kappa_margin_figure", "parameter_table_figure"]

_TITLES = {"builtin": "built-in (tau_c = tau_r)", "additive": "additive, eqs (16)-(18)"}
_COLOURS = {"builtin": "C3", "additive": "C0"}


def _load(folder: Path, row: dict[str, Any]) -> dict[str, np.ndarray]:
    """Time from 0 [s], tau_J [Nm], the reference [Nm] and, for the additive runs, tau_J,filt [Nm]."""
    ds = read_dataset(folder / row["file"])
    t = np.asarray(ds["t"], float)
    t = t - t[0]
    out = {"t": t, "tau_j": np.asarray(ds["tau_j"], float)}
    if ds.has("tau_r"):
        out["tau_r"] = np.asarray(ds["tau_r"], float)
    else:  # the built-in runs command the reference itself (plus a weak hold): rebuild it from the task
        out["tau_r"] = reference_of(row["task"], t, row["amplitude_nm"], row.get("period_s", 1.0),
                                    row.get("frequency_hz", 1.0))
    if ds.has("tau_j_filt"):
        out["tau_j_filt"] = np.asarray(ds["tau_j_filt"], float)
    return out


def tracking_run_figure(validation: dict[str, Any], folder: Path, task: str) -> plt.Figure:
    """Built-in against additive for one task through FRI: the whole run and a zoom (Fig. 8 or 9).

    Parameters
    ----------
    validation : dict
        ``validation.json`` content.
    folder : Path
        Folder of the run logs.
    task : str
        ``"step"`` or ``"sine"``.

    Returns
    -------
    matplotlib.figure.Figure
        Columns: built-in, additive; rows: the whole run, a zoom on one edge
        (step) or on the last periods (sine). The reference is drawn shifted
        by the FRI delay Td, which no client-side controller removes.
    """
    delay = float(validation.get("delay_s", 0.005))
    rows = {r["name"]: r for r in validation["runs"]}
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), squeeze=False)
    for c, kind in enumerate(("builtin", "additive")):
        row = rows.get(f"{kind}_{task}")
        if row is None:
            for ax in axes[:, c]:
                ax.text(0.5, 0.5, f"no {kind} {task} run", ha="center", va="center", transform=ax.transAxes)
                ax.set_axis_off()
            continue
        d = _load(folder, row)
        t = d["t"]
        if task == "step":
            half = 0.5 * row.get("period_s", 1.0)
            zoom = (half - 0.05, min(t[-1], half + 0.3))
        else:
            span = min(4.0 / row.get("frequency_hz", 1.0), 0.5 * t[-1])
            zoom = (t[-1] - span, t[-1])
        for r, (t0, t1) in enumerate(((0.0, t[-1]), zoom)):
            ax = axes[r, c]
            sel = (t >= t0) & (t <= t1)
            ax.plot(t[sel] + delay, d["tau_r"][sel], "k--", lw=1.1, label=f"tau_r shifted by Td = {delay * 1e3:.2f} ms")
            ax.plot(t[sel], d["tau_j"][sel], color=_COLOURS[kind], lw=0.9, label="tau_J measured")
            if "tau_j_filt" in d:
                ax.plot(t[sel], d["tau_j_filt"][sel], color="C2", lw=1.0, label="tau_J,filt, eq (15)")
            ax.set_xlim(t0, t1)
            ax.set_ylabel("joint torque [Nm]")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7, loc="upper right")
            if r == 1:
                ax.set_xlabel("time since the start of the run [s]")
        text = f"peak error {row['peak_error_nm']:.1f} Nm, RMS {row['rms_error_nm']:.2f} Nm"
        if task == "step" and row.get("overshoot_pct") is not None and math.isfinite(row["overshoot_pct"]):
            text += f", overshoot {row['overshoot_pct']:.0f} %"
        axes[0, c].set_title(f"{_TITLES[kind]}: {text}", fontsize=9)
        axes[1, c].set_title("zoom on the first falling edge" if task == "step" else "zoom on the last periods",
                             fontsize=9)
    what = (f"{rows.get('builtin_step', {}).get('amplitude_nm', '')} Nm square wave" if task == "step" else
            f"{rows.get('builtin_sine', {}).get('amplitude_nm', '')} Nm sine at "
            f"{rows.get('builtin_sine', {}).get('frequency_hz', '')} Hz")
    fig.suptitle(f"Torque tracking through FRI ({validation.get('target', 'sim')} target): {what}", fontsize=11)
    fig.tight_layout()
    return fig


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


def kappa_margin_figure(validation: dict[str, Any], folder: Path) -> plt.Figure:
    """Outer loop ``tau_r = kappa tau_ext``: the live sweeps through FRI beside their linear predictions.

    Left: per source and controller, the live margin (a bar from the last stable to the first unstable
    kappa of the sweep) and the prediction of the loop as deployed (a cross); the dotted lines are the
    design's margins of section V.C (the true torque, no filter). Right, like the paper's measurement:
    the joint torque of the first source's sweep against time for both controllers, kappa in force on
    the right axis, the judged onset of instability marked.
    """
    k = validation["kappa"]
    sweeps: dict[str, Any] = k.get("sweeps") or {}
    fig = plt.figure(figsize=(12, 6))
    grid = fig.add_gridspec(2, 2, width_ratios=(0.85, 1.4))
    ax_b = fig.add_subplot(grid[:, 0])
    labels, x = [], 0
    for source, sw in sweeps.items():
        for loop in ("builtin", "additive"):
            r = sw[loop]
            col = _COLOURS[loop]
            lo, hi = r.get("live_limit"), r.get("unstable_at")
            if lo is not None:
                ax_b.bar(x, (hi or lo) - lo, bottom=lo, width=0.6, color=col, alpha=0.55,
                         label="live: last stable to first unstable kappa" if x == 0 else None)
                ax_b.text(x, hi or lo, f"{lo:.1f}-{_fmt(hi)}", ha="center", va="bottom", fontsize=7)
            elif hi is not None:
                ax_b.plot([x], [hi], "v", color=col)
                ax_b.text(x, hi, f"unstable at {hi:.2g}", ha="center", va="bottom", fontsize=7)
            if r.get("linear_limit") is not None:
                ax_b.plot([x], [r["linear_limit"]], "kx", ms=8, label="linear, as deployed" if x == 0 else None)
            labels.append(f"{'built-in' if loop == 'builtin' else 'additive'}\n{source}")
            x += 1
    for loop, key in (("builtin", "linear_builtin"), ("additive", "linear_additive")):
        if k.get(key):
            ax_b.axhline(k[key], color=_COLOURS[loop], ls=":", lw=1,
                         label=f"{'built-in' if loop == 'builtin' else 'additive'} section V.C model {k[key]:.1f}")
    ax_b.set_xticks(range(len(labels)), labels, fontsize=8)
    ax_b.set_yscale("log")
    values = [float(y) for line in ax_b.get_lines() for y in np.asarray(line.get_ydata(), float)] + [
        float(v) for p in ax_b.patches if isinstance(p, Rectangle) for v in (p.get_y(), p.get_y() + p.get_height())]
    shown = [y for y in values if np.isfinite(y) and y > 0]
    if shown:  # room above for the legend
        ax_b.set_ylim(min(shown) / 1.3, max(shown) * 2.5)
    ax_b.set_ylabel("outer-loop gain kappa [-]")
    ratios = ", ".join(f"{s}: live {_fmt(sw.get('ratio_live'))}x, linear {_fmt(sw.get('ratio_linear'))}x"
                       for s, sw in sweeps.items())
    ax_b.set_title("live margins through FRI" + (f"\n{ratios}" if ratios else ""), fontsize=9)
    ax_b.legend(fontsize=7, loc="upper left")
    ax_b.grid(True, which="both", axis="y", alpha=0.3)
    axes = [fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])]
    if not sweeps:
        note = k.get("live_skipped", "no live kappa sweep")
        for ax in axes:
            ax.text(0.5, 0.5, note, ha="center", va="center", wrap=True, transform=ax.transAxes, fontsize=9)
            ax.set_axis_off()
    else:
        source, sw = next(iter(sweeps.items()))
        for ax, loop in zip(axes, ("builtin", "additive")):
            r = sw[loop]
            ds = read_dataset(folder / r["file"])
            t = np.asarray(ds["t"], float)
            t = t - t[0]
            tau_j = np.asarray(ds["tau_j"], float)
            ax.plot(t, tau_j - tau_j[0], color=_COLOURS[loop], lw=0.6, label="tau_J measured")
            ax.set_ylabel("tau_J [Nm]")
            ax2 = ax.twinx()
            steps = r["steps"]
            ts = [st["t_start_s"] for st in steps] + [t[-1]]
            ax2.stairs([st["kappa"] for st in steps], ts, color="k", lw=1.0, label="kappa")
            ax2.set_ylabel("kappa [-]")
            if r.get("unstable_at") is not None:
                t_on = steps[-1]["t_start_s"]
                ax.axvline(t_on, color="C3", ls="--", lw=1)
            ax.set_title(f"{_TITLES[loop]}, tau_ext from {source}: stable to kappa {_fmt(r.get('live_limit'))}, "
                         f"unstable at {_fmt(r.get('unstable_at'))}", fontsize=9)
            ax.text(0.01, 0.04, (r.get("reason") or r.get("stop_reason") or "")[:110], transform=ax.transAxes,
                    fontsize=7, bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
            ax.grid(True, alpha=0.3)
        axes[-1].set_xlabel("time since the start of the sweep [s]")
    fig.suptitle("Gain margin of tau_r = kappa tau_ext measured live: built-in against additive", fontsize=11)
    fig.tight_layout()
    return fig


def parameter_table_figure(headline: dict[str, Any], correlation: dict[str, Any] | None = None,
                           model: str = "model.toml") -> plt.Figure:
    """The fitted parameters of eq (4) with standard deviations (and errors against a simulated truth).

    Parameters
    ----------
    headline : dict
        ``parameters`` of the fit stage's headline: per name ``value``, ``std``,
        ``rel_std_pct`` and optionally ``simulated`` (the simulated plant's value) and ``error_pct``.
    correlation : dict, optional
        ``names`` and ``matrix`` of the fit's correlation, drawn beside the table.
    model : str
        The model file the table is of, named in the title (other pages may run another).
    """
    units = {"Jc": "kg m^2", "bc": "Nm s/rad", "K": "Nm/rad", "Jl": "kg m^2", "Td": "s"}
    params = headline["parameters"]
    has_truth = any("simulated" in v for v in params.values())
    cols = ["parameter", "unit", "value", "std", "rel. std [%]"] + (["simulated", "error [%]", "error [std]"]
                                                                     if has_truth else [])
    rows = []
    for name, v in params.items():
        row = [name, units.get(name, ""), f"{v['value']:.6g}", f"{v['std']:.3g}",
               "-" if v.get("rel_std_pct") is None else f"{v['rel_std_pct']:.3f}"]
        if has_truth:
            row += [f"{v['simulated']:.6g}" if "simulated" in v else "-",
                    f"{v['error_pct']:+.3g}" if "error_pct" in v else "-",
                    f"{v['error_std']:+.1f}" if v.get("error_std") is not None else "-"]
        rows.append(row)
    fig = plt.figure(figsize=(12, 4.5))
    grid = fig.add_gridspec(1, 2, width_ratios=(1.6, 1.0))
    ax = fig.add_subplot(grid[0, 0])
    ax.set_axis_off()
    table = ax.table(cellText=rows, colLabels=cols, loc="center", cellLoc="right")
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.auto_set_column_width(list(range(len(cols))))
    table.scale(1.0, 1.5)
    ax.set_title(f"{model}: parameters of eq (4) fitted to the chirp", fontsize=10)
    if correlation:
        axc = fig.add_subplot(grid[0, 1])
        m = np.asarray(correlation["matrix"], float)
        im = axc.imshow(m, vmin=-1, vmax=1, cmap="RdBu_r")
        names = correlation["names"]
        axc.set_xticks(range(len(names)), names)
        axc.set_yticks(range(len(names)), names)
        for i in range(len(names)):
            for j in range(len(names)):
                # Dark cells (|rho| near 1) get white digits, so every value stays readable.
                axc.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center", fontsize=7,
                         color="white" if abs(m[i, j]) > 0.6 else "black")
        fig.colorbar(im, ax=axc, label="correlation coefficient [-]")
        axc.set_xlabel("parameter")
        axc.set_ylabel("parameter")
        axc.set_title("correlation of the estimates", fontsize=10)
    fig.tight_layout()
    return fig
