"""Figures of the closed-loop analysis (section V): tracking like Figs. 8-9, pole map, kappa margins.

Every function takes the dictionary of
:func:`iiwa_ident.design.compare_controllers` and returns a
matplotlib Figure (Agg backend); saving is left to the caller.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from iiwa_ident.design import ClosedLoopRun, KappaMargin

__all__ = ["tracking_figure", "pole_figure", "kappa_figure"]

_KINDS = ("builtin", "additive")
_TITLES = {"builtin": "built-in (tau_c = tau_r)", "additive": "additive, eqs (16)-(18)"}
_KIND_COLOURS = {"builtin": "C3", "additive": "C0"}


def _trace(ax: plt.Axes, run: ClosedLoopRun, t0: float, t1: float, delay_s: float) -> None:
    """Reference (delayed by Td), raw and filtered tau_J on ``[t0, t1]`` [s]."""
    sel = (run.t >= t0) & (run.t <= t1)
    ax.plot(run.t[sel] + delay_s, run.tau_r[sel], "k--", lw=1.2, label="tau_r (shifted by Td)")
    ax.plot(run.t[sel], run.tau_j[sel], color="C7", lw=0.9, label="tau_J")
    ax.plot(run.t[sel], run.tau_j_filt[sel], color="C2", lw=1.2, label="tau_J,filt, eq (15)")
    ax.set_xlim(t0, t1)
    ax.grid(True, alpha=0.3)


def tracking_figure(result: dict, delay_s: float = 0.005) -> plt.Figure:
    """Step and sine responses of both controllers (Figs. 8 and 9).

    Rows: the first edges of the square wave, the slow sine, the fast sine
    (last 0.2 s of the run); columns: built-in, additive. Each panel states
    the steady-state peak errors on the raw and the filtered torque.

    Parameters
    ----------
    result : dict
        From :func:`~iiwa_ident.design.compare_controllers`.
    delay_s : float
        Shift of the plotted reference [s] (the FRI delay the errors are taken at).
    """
    rows = [("step", None)] + [("sine", i) for i in range(len(result["sine"]["builtin"]))]
    fig, axes = plt.subplots(len(rows), 2, figsize=(12, 3.0 * len(rows)), squeeze=False)
    for r, (what, i) in enumerate(rows):
        for c, kind in enumerate(_KINDS):
            ax = axes[r, c]
            if what == "step":
                res = result["step"][kind]
                t_edge = res.edges_s[1] if len(res.edges_s) > 1 else 0.0
                _trace(ax, res.run, t_edge - 0.05, t_edge + 0.25, delay_s)
                m = res.metrics
                title = (f"{_TITLES[kind]}: step, overshoot {100 * m.overshoot_raw:.0f} % raw / "
                         f"{100 * m.overshoot_filt:.0f} % filtered")
                err = res.errors
            else:
                res = result["sine"][kind][i]
                t_end = res.run.t[-1]
                span = min(t_end - res.start_s, max(0.2, 2.0 / res.frequency_hz))
                _trace(ax, res.run, t_end - span, t_end, delay_s)
                title = f"{_TITLES[kind]}: {res.amplitude_nm:g} Nm at {res.frequency_hz:g} Hz"
                err = res.errors
            ax.set_title(title, fontsize=9)
            ax.text(0.01, 0.02, f"steady-state peak error: raw {err.raw_peak:.1f} Nm, filtered {err.filt_peak:.1f} Nm",
                    transform=ax.transAxes, fontsize=8, va="bottom",
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
            ax.set_ylabel("torque [Nm]")
            if r == len(rows) - 1:
                ax.set_xlabel("time [s]")
            if r == 0 and c == 0:
                ax.legend(fontsize=8, loc="upper right")
    fig.suptitle("Torque tracking on the simulated joint (ripple on): built-in against additive.\n"
                 "Look at the overshoot after a step and at the 25 Hz row, where the built-in loop "
                 "resonates and the additive loop follows the delayed reference.", fontsize=10)
    fig.tight_layout()
    return fig


def pole_figure(result: dict) -> plt.Figure:
    """Continuous closed-loop poles: built-in (eq (4)), additive feedback and observer poles (section V.B).

    Circles of constant natural frequency [Hz] help read the plot; the
    built-in pair sits close to the imaginary axis (zeta ~ 0.19).
    """
    poles = result["poles"]
    fig, ax = plt.subplots(figsize=(7, 5.5))
    groups = (("builtin", "built-in, eq (4)", "C3", "x"), ("additive", "additive feedback K_FSF", "C0", "o"),
              ("observer", "additive observer L", "C2", "s"))
    for key, label, colour, marker in groups:
        p = np.asarray(poles[key], complex)
        ax.scatter(p.real, p.imag, color=colour, marker=marker, s=60, label=label,
                   facecolors="none" if marker != "x" else None)
    for f_hz in (25, 50, 100, 160):
        w = 2 * math.pi * f_hz
        th = np.linspace(math.pi / 2, 3 * math.pi / 2, 100)
        ax.plot(w * np.cos(th), w * np.sin(th), color="0.8", lw=0.7)
        ax.text(-w * math.cos(math.pi / 4), w * math.sin(math.pi / 4), f"{f_hz} Hz", fontsize=7, color="0.5",
                ha="right", va="bottom")
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("real part [rad/s]")
    ax.set_ylabel("imaginary part [rad/s]")
    ax.set_title("Closed-loop poles in the s-plane. The additive design moves the\nlightly damped "
                 "built-in pair (23 Hz, zeta 0.19) to well-damped poles.", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return fig


def kappa_figure(result: dict) -> plt.Figure:
    """Outer-loop trials ``tau_r = kappa tau_ext``: oscillation level against kappa, stable or unstable.

    Each marker is one simulated run (filled: stable, cross: unstable),
    plotted at the RMS of the oscillatory tau_J in its last hand period
    (runs stopped by the limit guard at the top). Vertical lines: the
    largest stable kappa found by simulation (solid) and the linear
    prediction (dashed), per controller.
    """
    margins: dict[str, KappaMargin] = result.get("kappa", {})
    fig, ax = plt.subplots(figsize=(8, 5))
    top = 1.0
    for kind in _KINDS:
        m = margins.get(kind)
        if m is None:
            continue
        for t in m.trials:
            if np.isfinite(t.verdict.rms_last):
                top = max(top, t.verdict.rms_last)
    top *= 3.0
    for kind in _KINDS:
        m = margins.get(kind)
        if m is None:
            continue
        col = _KIND_COLOURS[kind]
        ks = np.array([t.kappa for t in m.trials])
        lev = np.array([t.verdict.rms_last if np.isfinite(t.verdict.rms_last) else top for t in m.trials])
        ok = np.array([t.verdict.stable for t in m.trials])
        ax.scatter(ks[ok], lev[ok], color=col, marker="o", label=f"{kind}: stable run")
        ax.scatter(ks[~ok], lev[~ok], color=col, marker="x", s=60, label=f"{kind}: unstable run")
        ax.axvline(m.kappa_max, color=col, lw=1.5, label=f"{kind}: kappa_max simulated {m.kappa_max:.1f}")
        if math.isfinite(m.linear):
            ax.axvline(m.linear, color=col, lw=1.2, ls="--", label=f"{kind}: linear prediction {m.linear:.1f}")
    ax.set_yscale("log")
    ax.set_xlabel("outer-loop gain kappa [-]")
    ax.set_ylabel("oscillatory tau_J RMS, last hand period [Nm]")
    ratio = result.get("kappa_ratio")
    ttl = "Gain margin of tau_r = kappa tau_ext with a hand holding the link"
    if ratio is not None:
        ttl += f"\nkappa_max additive / built-in = {ratio:.2f} (paper: 15 / 4.6 > 3.3); runs stopped by the guard at the top"
    ax.set_title(ttl, fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig
