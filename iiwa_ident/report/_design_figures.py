"""Figures of the design stage: the spatial filter (like the paper's Fig. 4), the observers (Fig. 7) and the
reproduction of section V's numbers."""

from __future__ import annotations

import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from iiwa_ident.datasets import Dataset
from iiwa_ident.design import (
    PAPER_FILTER,
    REPRODUCTION_COLUMNS,
    REPRODUCTION_POLES,
    FilterSettings,
    ReproductionRow,
    SpatialFilter,
    compare_observers,
    link_speed,
    observer_lag,
    reproduction_cells,
    ripple_line_cut,
    run_observers,
    spatial_filter_response,
)
from iiwa_ident.model import JointModel, RippleTable

__all__ = ["spatial_filter_figure", "observer_figure", "reproduction_figure"]

_COLOURS = {"reference": "k", "builtin": "C3", "improved": "C0", "filtered": "C2", "fri": "C7"}
_LABELS = {"builtin": "built-in (motor velocity)", "improved": "link velocity, eq (9)",
           "filtered": "link velocity + spatial filter, eq (14)", "fri": "reported by FRI"}


def _amplitude_spectrum(x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum [unit of x] with a Hann window (amplitude-corrected)."""
    x = np.asarray(x, float) - np.mean(x)
    w = np.hanning(len(x))
    spec = np.abs(np.fft.rfft(x * w)) * 2.0 / w.sum()
    return np.fft.rfftfreq(len(x), dt), spec


def spatial_filter_figure(dataset: Dataset, filter: FilterSettings = PAPER_FILTER, ripple: RippleTable | None = None,
                          speeds: tuple[float, ...] = (0.3, 0.6, 1.2), periods_shown: float = 8.0) -> plt.Figure:
    """Joint torque before and after the spatial filter at several speeds, and the filter's response.

    Parameters
    ----------
    dataset : Dataset
        A constant-velocity record (``t``, ``q_m``, ``tau_j``).
    filter : FilterSettings
        The spatial filter of eqs (10)-(12) (a design's ``record.filter``; default: the paper's).
    ripple : RippleTable or None
        The lookup table whose period the filter works at (a design's ``record.ripple``; None: the paper's rho).
    speeds : tuple of float
        Speeds to show [rad/s]; each row takes the longest pass within 10 % of it.
    periods_shown : float
        Length of the time traces, in ripple periods.

    Returns
    -------
    matplotlib.figure.Figure
        One row per speed (torque against time; amplitude spectra of the
        whole pass) and a bottom row with the filter's frequency response at
        those speeds.
    """
    t, q, tau = (np.asarray(dataset[k], float) for k in ("t", "q_m", "tau_j"))
    dt = 1.0 / dataset.sample_rate_hz
    spatial = SpatialFilter.from_settings(filter, ripple, dt)
    period_rad, beta, v_min = spatial.period_rad, spatial.beta, spatial.v_min
    filtered = spatial.apply(tau, q)
    passes = ripple_line_cut(t, q, tau, filtered, period_rad)
    fig = plt.figure(figsize=(11, 3.0 * len(speeds) + 3.2))
    grid = fig.add_gridspec(len(speeds) + 1, 2, width_ratios=(1.2, 1.0))
    summary = []
    for row, speed in enumerate(speeds):
        ax_t, ax_f = fig.add_subplot(grid[row, 0]), fig.add_subplot(grid[row, 1])
        near = [p for p in passes if abs(abs(p["speed_rad_s"]) - speed) <= 0.1 * speed]
        if not near:
            for ax in (ax_t, ax_f):
                ax.text(0.5, 0.5, f"no constant-speed pass near {speed} rad/s", ha="center", va="center",
                        transform=ax.transAxes)
                ax.set_axis_off()
            summary.append(f"{speed} rad/s: no pass")
            continue
        p = max(near, key=lambda r: r["stop_s"] - r["start_s"])
        sel = (t >= p["start_s"]) & (t <= p["stop_s"])
        # A few ripple periods from the middle of the pass, where the filter has long settled.
        span = periods_shown * period_rad / abs(p["speed_rad_s"])
        mid = 0.5 * (p["start_s"] + p["stop_s"])
        win = sel & (np.abs(t - mid) <= 0.5 * span)
        ax_t.plot(t[win] - t[win][0], tau[win], color="C3", lw=1.0, label="τJ measured")
        ax_t.plot(t[win] - t[win][0], filtered[win], color="C2", lw=1.4, label="τJ,filt = H_filt τJ")
        ax_t.set_ylabel("joint torque [Nm]")
        ax_t.set_title(f"{p['speed_rad_s']:+.2f} rad/s: ripple at |v|/ρ = {p['freq_hz']:.1f} Hz", fontsize=10)
        ax_t.legend(loc="upper right", fontsize=8)
        f, s_raw = _amplitude_spectrum(tau[sel], dt)
        _, s_filt = _amplitude_spectrum(filtered[sel], dt)
        ax_f.semilogy(f, s_raw, color="C3", lw=0.8, label="measured")
        ax_f.semilogy(f, s_filt, color="C2", lw=0.8, label="filtered")
        for k in (1, 2):
            ax_f.axvline(k * p["freq_hz"], color="k", ls=":", lw=0.8)
        ax_f.set_xlim(0, min(0.5 / dt, 2.6 * p["freq_hz"] + 10))
        ax_f.set_ylabel("amplitude [Nm]")
        ax_f.set_title(f"spectrum of the pass ({p['stop_s'] - p['start_s']:.2f} s): line cut by {p['cut_db']:.0f} dB",
                       fontsize=10)
        ax_f.legend(loc="upper right", fontsize=8)
        summary.append(f"{abs(p['speed_rad_s']):.2f} rad/s: {p['cut_db']:.0f} dB")
        if row == len(speeds) - 1:
            ax_t.set_xlabel("time within the window [s]")
            ax_f.set_xlabel("frequency [Hz]")
    ax_h, ax_p = fig.add_subplot(grid[len(speeds), 0]), fig.add_subplot(grid[len(speeds), 1])
    freq = np.logspace(-1, np.log10(0.5 / dt), 600)
    slow = np.linspace(0.05, 5.0, 300)
    for k, speed in enumerate(speeds):
        gain = 20 * np.log10(np.abs(spatial_filter_response(freq, speed, dt, period_rad, beta, v_min)))
        ax_h.semilogx(freq, gain, color=f"C{k}", label=f"{speed} rad/s (notch at {speed / period_rad:.1f} Hz)")
        gain = 20 * np.log10(np.abs(spatial_filter_response(slow, speed, dt, period_rad, beta, v_min)))
        ax_p.plot(slow, gain, color=f"C{k}", label=f"{speed} rad/s: {gain[np.argmin(np.abs(slow - 2.0))]:+.2f} dB "
                  "at 2 Hz")
    for ax in (ax_h, ax_p):
        ax.axhspan(-0.5, 0.5, color="0.85", zorder=0)
        ax.axvline(2.0, color="k", ls=":", lw=0.8)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("|H_filt| [dB]")
    ax_h.set_ylim(-45, 6)
    ax_h.set_title(f"Response at constant speed (β = {beta:g}, v_min = {v_min:g} rad/s)", fontsize=10)
    ax_h.legend(loc="lower left", fontsize=8)
    ax_p.set_ylim(-1.0, 2.5)
    ax_p.set_title("Passband (grey: ±0.5 dB)", fontsize=10)
    ax_p.legend(loc="upper left", fontsize=8)
    fig.suptitle("Spatial filter of eqs (10)-(12) on constant-velocity motion (cf. Fig. 4)")
    fig.text(0.01, 0.005, "Look for: the ripple line at |v|/ρ (first dotted line) gone from the filtered spectrum at "
             f"every speed [{'; '.join(summary)}];\nthe line at 2|v|/ρ (second harmonic of f) is outside the notch "
             "and stays. Bottom: the notch follows the speed; below it 1 - H² = (1 - H)(1 + H) rises above 0 dB,\n"
             "more at low speed (dotted: 2 Hz).", fontsize=8, va="bottom")
    fig.tight_layout(rect=(0, 0.05, 1, 0.97))
    return fig


def observer_figure(dataset: Dataset, model: JointModel, filter: FilterSettings = PAPER_FILTER,
                    speed_threshold: float = 0.5, zoom_s: float = 1.0) -> plt.Figure:
    """External-torque estimates of the three observers against the F/T reference (like Fig. 7).

    Parameters
    ----------
    dataset : Dataset
        A hand-guided record with ``tau_ext_ref``.
    model : JointModel
        K, Jl, KI and the ripple table.
    filter : FilterSettings
        The spatial filter of the filtered observer (default: the paper's).
    speed_threshold : float
        Link speed marking fast motion in the RMS table [rad/s].
    zoom_s : float
        Length of the zoomed window around the fastest moment [s].

    Returns
    -------
    matplotlib.figure.Figure
        The whole record, a zoom on the fastest second, the link speed, and
        the RMS table in the caption.
    """
    t = np.asarray(dataset["t"], float)
    ref = np.asarray(dataset["tau_ext_ref"], float)
    dt = 1.0 / dataset.sample_rate_hz
    est = run_observers(dataset, model, filter)
    table = compare_observers(dataset, model, speed_threshold, filter, estimates=est)
    speed = link_speed(dataset, model)
    lagged = observer_lag(ref, model.value("KI"), dt)

    fig, (ax_all, ax_zoom, ax_v) = plt.subplots(3, 1, figsize=(11, 10), gridspec_kw={"height_ratios": (1.2, 1.2, 0.6)})
    i_peak = int(np.argmax(np.abs(speed)))
    zoom = np.abs(t - t[i_peak]) <= 0.5 * zoom_s
    for ax, sel in ((ax_all, slice(None)), (ax_zoom, zoom)):
        ax.plot(t[sel], ref[sel], color="k", lw=1.6, label="F/T reference τext")
        if ax is ax_zoom:
            ax.plot(t[sel], lagged[sel], color="k", ls="--", lw=1.0, label="reference through the observer's lag")
        for name in ("builtin", "improved", "filtered"):
            if name in est:
                ax.plot(t[sel], est[name][sel], color=_COLOURS[name], lw=0.9, label=_LABELS[name])
        ax.set_ylabel("external torque [Nm]")
        ax.legend(loc="upper right", fontsize=8, ncol=2)
    ax_all.set_title("External-torque estimates while the link is moved by hand (τc = 0)", fontsize=10)
    ax_zoom.set_title(f"Zoom: {zoom_s:g} s around the fastest moment ({abs(speed[i_peak]):.2f} rad/s)", fontsize=10)
    ax_all.axvspan(t[zoom][0], t[zoom][-1], color="0.9", zorder=0)
    ax_v.plot(t, speed, color="C4", lw=1.0, label="link speed from eq (9)")
    for sgn in (1, -1):
        ax_v.axhline(sgn * speed_threshold, color="k", ls=":", lw=0.8)
    ax_v.fill_between(t, -speed_threshold, speed_threshold, color="0.92", zorder=0,
                      label=f"|v| ≤ {speed_threshold} rad/s (not in the fast RMS)")
    ax_v.set_xlabel("time [s]")
    ax_v.set_ylabel("link speed [rad/s]")
    ax_v.legend(loc="upper right", fontsize=8)

    rows = table["observers"]
    lines = [f"RMS error [Nm]           all    |v|>{speed_threshold:.1f}   vs lagged ref: all   |v|>{speed_threshold:.1f}"]
    for name in ("builtin", "improved", "filtered", "fri"):
        if name in rows:
            r = rows[name]
            lines.append(f"{_LABELS[name]:<40.40s} {r['rms_nm']:6.2f} {r['rms_fast_nm']:7.2f}"
                         f"            {r['rms_lagged_nm']:6.3f} {r['rms_lagged_fast_nm']:7.3f}")
    ratio = ""
    if "ratio_fast" in table:
        ratio = (f"Built-in / filtered at |v| > {speed_threshold} rad/s: {table['ratio_fast']:.2f}x against the "
                 f"reference, {table['ratio_lagged_fast']:.1f}x against the lagged reference "
                 f"({100 * table['fast_fraction']:.0f}% of samples fast, β = {filter.beta:g}).\n")
    fig.text(0.01, 0.005, "\n".join(lines) + "\n" + ratio +
             "Look for: the built-in estimate oscillating at the ripple frequency when the link is fast; the eq (9) "
             "estimates following the\nlagged reference. All three lag the F/T torque by eq (13)'s first-order "
             f"response (1/K_I = {1e3 / model.value('KI'):.0f} ms), an error common to all;\nthe lagged-reference "
             "columns show the error the improvements can remove.", fontsize=7.5, family="monospace", va="bottom")
    fig.tight_layout(rect=(0, 0.13, 1, 1))
    return fig


def reproduction_figure(rows: list[ReproductionRow], source: str) -> plt.Figure:
    """Section V's printed numbers beside the ones computed from ``source`` (Table I), as a table whose
    explanations wrap in their cells; one letter landscape page."""
    cells = reproduction_cells(rows)
    wrapped = [c[:7] + ("\n".join(textwrap.wrap(c[7], 88)) or "",) for c in cells]
    lines = [max(1, c[7].count("\n") + 1) for c in wrapped]
    fig = plt.figure(figsize=(11.0, 8.5))
    ax = fig.add_axes((0.03, 0.03, 0.94, 0.86))
    ax.set_axis_off()
    table = ax.table(cellText=wrapped, colLabels=REPRODUCTION_COLUMNS, loc="upper center", cellLoc="right",
                     colLoc="right", colWidths=[0.1, 0.055, 0.07, 0.07, 0.065, 0.07, 0.065, 0.5])
    table.auto_set_font_size(False)
    table.set_fontsize(7)
    # The height of a line of text, so that every row holds its explanation and the table the page.
    unit = min(0.84 / (sum(lines) + 0.8 * len(lines) + 1.8), 0.03)
    for (row, col), cell in table.get_celld().items():
        cell.set_height(unit * (1.8 if row == 0 else lines[row - 1] + 0.8))
        if col in (0, 1, 7):
            cell.get_text().set_horizontalalignment("left")
            cell.PAD = 0.02
    fig.text(0.03, 0.95, "Paper reproduction (section V)", fontsize=15, va="top", weight="bold")
    fig.text(0.03, 0.91, f"model {source}, {REPRODUCTION_POLES}", fontsize=9, va="top")
    return fig
