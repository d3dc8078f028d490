"""Figures of the ripple identification: spatial spectrum, lookup tables (Fig. 6), eq (6)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from iiwa_ident.ident import RippleResult

__all__ = ["spatial_spectrum_figure", "lookup_table_figure", "velocity_frequency_figure"]


def _notice(fig: plt.Figure, ax: plt.Axes, text: str) -> plt.Figure:
    """Say why there is nothing to draw instead of leaving empty axes."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_axis_off()
    return fig


def _captioned(fig: plt.Figure, caption: str, bottom: float) -> plt.Figure:
    """The figure with what to look for written below its axes (``bottom``: the caption's share of the height)."""
    fig.text(0.01, 0.01, caption, fontsize=8)
    fig.tight_layout(rect=(0, bottom, 1, 1))
    return fig


def spatial_spectrum_figure(result: RippleResult) -> plt.Figure:
    """Consistency (Hotelling T^2) and power of the deflection against the period, with the detected period."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    period = 1.0 / result.spectrum_k
    ax1.semilogx(period, result.spectrum_stat, lw=0.8, label="T² of the passes' coefficients (calibrated)")
    ax2.loglog(period, np.sqrt(np.maximum(result.spectrum_power, 1e-300)), lw=0.8, color="C2",
               label="amplitude of the mean coefficient")
    if result.detected:
        for ax in (ax1, ax2):
            ax.axvline(result.period_rad, color="C3", ls="--", label=f"detected ρ = {result.period_rad:.5f} rad")
    ax1.set_ylabel("T² [-]")
    ax2.set_ylabel("deflection amplitude [rad]")
    ax2.set_xlabel("period ρ [rad]")
    ax1.legend(loc="upper right")
    ax2.legend(loc="upper right")
    verdict = "detected" if result.detected else "none found"
    ax1.set_title(f"Spatial spectrum of the deflection ({verdict}, false-alarm probability {result.false_alarm:.1e})")
    return _captioned(fig, _spectrum_note(result, period), 0.03)


def _spectrum_note(result: RippleResult, period: np.ndarray) -> str:
    """What the spectrum shows, from its own lines: whether the detected period's line is the tallest."""
    if not result.detected or result.period_rad is None or not len(period):
        return ("No line stands out as a position-periodic deflection would (phase-locked in every pass, noise is "
                "not): the runs do not show a ripple this method can find.")
    top = float(period[int(np.argmax(result.spectrum_stat))])
    near = abs(top / result.period_rad - 1.0) < 0.02
    if near:
        return ("The tallest line is at the detected period: a position-periodic deflection is phase-locked in every "
                "pass, noise is not.")
    ratio = result.period_rad / top
    return (f"The tallest line stands at {top:.5f} rad, {ratio:.2f} times shorter than the detected period: a "
            "harmonic of the deflection (its shape is not a pure sine) or another line; the period is the family's "
            "fundamental, which the runs agree on (ripple.json).")


def lookup_table_figure(result: RippleResult) -> plt.Figure:
    """Deflection samples folded modulo rho and the lookup tables of each method (like the paper's Fig. 6)."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    rho, lut = result.period_rad, result.lut
    if not result.detected or rho is None or lut is None:
        return _notice(fig, ax, "no periodic deflection detected")
    colours = {"static": "C0", "dynamic": "C1"}
    # Folded samples averaged in 64 bins per method: the raw samples of a real log are mostly noise.
    edges = np.linspace(0, rho, 65)
    for name in result.methods:
        ps = [p for p in result.passes if p.method == name]
        x = np.concatenate([np.mod(p.theta, rho) for p in ps])
        f = np.concatenate([p.f - p.f.mean() for p in ps])
        idx = np.clip(np.digitize(x, edges) - 1, 0, 63)
        counts = np.bincount(idx, minlength=64)
        means = np.bincount(idx, weights=f, minlength=64) / np.maximum(counts, 1)
        centres = 0.5 * (edges[1:] + edges[:-1])
        ax.plot(centres[counts > 0] * 1e3, means[counts > 0] * 1e6, "o", ms=3, alpha=0.6,
                color=colours.get(name, "C7"), label=f"{name}: folded samples, mean of 64 bins")
    x = np.arange(len(lut)) * rho / len(lut)
    for name, m in result.methods.items():
        ax.plot(x * 1e3, m.lut * 1e6, lw=2, color=colours.get(name, "C7"),
                label=f"{name} method ({m.n_passes} passes, shift {m.shift_rad * 1e6:.1f} µrad)")
    ax.plot(x * 1e3, lut * 1e6, "k--", lw=1.2, label="table written to the model")
    ax.set_xlabel("θm mod ρ [mrad]")
    ax.set_ylabel("θm − θj [µrad]")
    ax.set_title(f"Transmission deflection f(θm mod ρ), ρ = {rho:.5f} rad")
    ax.legend(loc="upper right", fontsize=8)
    return _captioned(fig, "Dots: deflection folded modulo ρ, bin means; lines: lookup tables. "
                      "The methods should agree in shape and phase.", 0.04)


def velocity_frequency_figure(result: RippleResult) -> plt.Figure:
    """Eq (6): ripple frequency against speed, predicted |v| / rho and measured torque peak."""
    fig, ax = plt.subplots(figsize=(6, 4))
    rows = result.velocity_table
    if not rows:
        return _notice(fig, ax, "no periodic deflection detected")
    v = np.array([r["speed_rad_s"] for r in rows])
    vv = np.linspace(0, v.max() * 1.1, 50)
    ax.plot(vv, vv / result.period_rad, "C0-", label="f = |v| / ρ, eq (6)")
    ax.plot(v, [r["measured_hz"] for r in rows], "C3o", label="peak of the joint-torque spectrum")
    ax.set_xlabel("joint speed |v| [rad/s]")
    ax.set_ylabel("ripple frequency [Hz]")
    ax.set_title("Ripple frequency grows with speed")
    ax.legend()
    fig.tight_layout()
    return fig
