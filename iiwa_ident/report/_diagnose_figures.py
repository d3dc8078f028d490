"""Figures of the discrepancy diagnosis: residuals before and after, evidence per effect, gain table."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from iiwa_ident.diagnose import Diagnosis

__all__ = ["residuals_figure", "evidence_figure", "gain_table_figure", "figure_set", "comparison_figure"]

_CHANNEL_LABEL = {"link": "link channel (external-torque estimate error)",
                  "command": "command channel (torque response error)"}


def _binned(x: np.ndarray, y: np.ndarray, bins: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``y`` in equal bins of ``x`` (empty bins dropped)."""
    edges = np.linspace(np.min(x), np.max(x), bins + 1)
    idx = np.clip(np.digitize(x, edges) - 1, 0, bins - 1)
    counts = np.bincount(idx, minlength=bins)
    sums = np.bincount(idx, weights=y, minlength=bins)
    keep = counts > 0
    centres = 0.5 * (edges[1:] + edges[:-1])
    return centres[keep], sums[keep] / counts[keep]


def residuals_figure(d: Diagnosis, index: int, channel: str) -> plt.Figure:
    """Residual of one channel of one dataset before and after the named effects.

    Four panels: over time [s]; against the motor position [rad] (folded modulo
    the named ripple period when there is one); against the link velocity
    [rad/s]; amplitude spectrum [Nm] against frequency [Hz].
    """
    ctx = d.contexts[index]
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    m = ctx.masks[channel]
    before = ctx.residual[channel]
    after = d.residual_after(ctx, channel)
    t = ctx.t[m]
    (ax_t, ax_q), (ax_v, ax_f) = axes
    ax_t.plot(t, before[m], lw=0.6, label="before")
    ax_t.plot(t, after[m], lw=0.6, label="after", alpha=0.8)
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("residual [Nm]")
    ripple = d.effect("transmission_ripple")
    if ripple is not None:
        rho = ripple.parameters["period_rad"]
        x, label = np.mod(ctx.q_m[m], rho), f"q_m mod {rho:.5f} rad [rad]"
    else:
        x, label = ctx.q_m[m], "motor position q_m [rad]"
    ax_v_x = ctx.omega_l[m]
    for ax, xx, xl in ((ax_q, x, label), (ax_v, ax_v_x, "link velocity [rad/s]")):
        for y, name, colour in ((before[m], "before", "C0"), (after[m], "after", "C1")):
            ax.plot(xx, y, ".", ms=1, alpha=0.15, color=colour)
            bx, by = _binned(xx, y)
            ax.plot(bx, by, lw=1.5, color=colour, label=f"{name} (bin means)")
        ax.set_xlabel(xl)
        ax.set_ylabel("residual [Nm]")
    dt = ctx.dt
    for y, name in ((before[m], "before"), (after[m], "after")):
        win = np.hanning(len(y))
        amp = 2 * np.abs(np.fft.rfft((y - y.mean()) * win)) / win.sum()
        ax_f.semilogy(np.fft.rfftfreq(len(y), dt), np.maximum(amp, 1e-9), lw=0.6, label=name)
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("amplitude [Nm]")
    for ax in axes.ravel():
        ax.legend(loc="upper right", fontsize=7)
    fig.suptitle(f"{ctx.name} ({ctx.experiment}): {_CHANNEL_LABEL[channel]}")
    fig.text(0.01, 0.01, "Residual = measured minus predicted joint torque. Structure that survives in 'after' is "
             "what the named effects do not explain.", fontsize=8)
    fig.tight_layout(rect=(0, 0.03, 1, 0.96))
    return fig


def evidence_figure(d: Diagnosis, name: str) -> plt.Figure:
    """Partial residual of one named effect against its variable, with the fitted effect.

    The partial residual is the residual after all named effects plus this
    effect's own contribution: what the data say about the effect alone.
    """
    report = d.effect(name)
    if report is None:
        raise ValueError(f"evidence figure: the diagnosis names no {name!r}")
    cand = next(c for c in d.selection.selected if c.name == name)
    blocks = [b for b in d.blocks if np.any(d.contribution(b.ctx, b.channel, only=name)[b.mask])][:4]
    fig, axes = plt.subplots(1, max(len(blocks), 1), figsize=(4.2 * max(len(blocks), 1), 4), squeeze=False)
    for ax, b in zip(axes[0], blocks):
        ctx = b.ctx
        own = d.contribution(ctx, b.channel, only=name)
        partial = d.residual_after(ctx, b.channel) + own
        x, label = cand.evidence_axis(ctx)
        m = b.mask
        ax.plot(x[m], partial[m], ".", ms=1.5, alpha=0.2, color="C0", label="partial residual")
        bx, by = _binned(x[m], partial[m])
        ax.plot(bx, by, lw=1.5, color="C1", label="partial residual (bin means)")
        # The effect reaches a channel through the joint's dynamics, so it is drawn as bin means as well.
        bx, by = _binned(x[m], own[m])
        ax.plot(bx, by, lw=1.2, ls="--", color="C3", label="fitted effect (bin means)")
        ax.set_xlabel(label)
        ax.set_ylabel("torque [Nm]")
        ax.set_title(f"{ctx.name}, {b.channel}", fontsize=9)
        ax.legend(loc="upper right", fontsize=7)
    pars = ", ".join(f"{k} = {v:.4g}" for k, v in report.parameters.items())
    fig.suptitle(f"Evidence for {name} (confidence {report.confidence:.4f}): {pars}", fontsize=10)
    fig.text(0.01, 0.01, f"Held-out residual RMS on these channels: {report.rms_before:.4f} Nm without the effect, "
             f"{report.rms_after:.4f} Nm with it ({report.gain_pct:.1f}% lower).", fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 0.93))
    return fig


def gain_table_figure(d: Diagnosis) -> plt.Figure:
    """Table of held-out residual RMS before and after, per effect and per dataset channel."""
    # An undecided effect is named, but the other shape of a named effect would predict as well.
    undecided = {u["name"]: f" (or {u['or_shape_of']}'s shape: undecided)" for u in d.undecided}
    rows = [[e.name + undecided.get(e.name, ""), f"{e.confidence:.4f}", f"{e.rms_before:.4f}", f"{e.rms_after:.4f}",
             f"{e.gain_pct:.1f}", "", ""] for e in d.effects]
    # Not named: the data do not decide between it and another shape of a named effect (its gain as named).
    rows += [[f"({a['name']} or {a['or_shape_of']}'s shape)", "ambiguous", "", "", f"{a['gain_pct']:.1f}", "", ""]
             for a in d.ambiguous]
    # The model's own effects the data contradicted (left out of the extended model), with their gain.
    rows += [[f"(replaced: {r['old']} -> {' + '.join(r['new']) or 'nothing'})", "replaced", "", "",
              f"{r['gain_pct']:.1f}", "", ""] for r in d.replaced]
    for c in d.channels:
        fits = tests = ""
        if c.before is not None and c.after is not None:
            fits = f"{c.before.fit_pct:.1f} / {c.after.fit_pct:.1f}"
            # A channel whose tests fail at the sensor's noise is explained (ChannelComparison.explained): said.
            tests = " / ".join(x.verdict + (" (at noise)" if x.passed is False and x.at_noise else "")
                               for x in (c.before, c.after))
        rows.append([f"{c.dataset} / {c.channel}", "", f"{c.rms_before:.4f}", f"{c.rms_after:.4f}",
                     f"{c.gain_pct:.1f}", fits, tests])
    fig, ax = plt.subplots(figsize=(11, 0.6 + 0.3 * (len(rows) + 1)))
    ax.set_axis_off()
    table = ax.table(cellText=rows, colLabels=["effect / dataset channel", "confidence", "RMS before [Nm]",
                                              "RMS after [Nm]", "gain [%]", "fit % before/after",
                                              "tests before/after"],
                     colWidths=[0.3, 0.09, 0.11, 0.11, 0.08, 0.14, 0.17], loc="center", cellLoc="left")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    verdict = "model explains the data: nothing named" if d.explained else f"{len(d.effects)} effect(s) named"
    if d.sign_reversed:
        verdict = f"torque sign reversed in {len(d.sign_reversed)} run(s), then " + verdict
    if d.ambiguous:
        verdict += f", {len(d.ambiguous)} ambiguous"
    if d.undecided:
        verdict += f", {len(d.undecided)} undecided"
    if d.replaced:
        verdict += f", {len(d.replaced)} of the model's replaced"
    if d.unexplained_channels:
        verdict += f"; residual tests fail on {len(d.unexplained_channels)} channel(s)"
    ax.set_title(f"Held-out gain of the named effects ({verdict})", fontsize=10)
    return fig


def figure_set(d: Diagnosis) -> dict[str, plt.Figure]:
    """All figures by file stem: residuals per dataset channel, evidence per effect, the gain table."""
    figs = {"diagnose_gain_table": gain_table_figure(d)}
    for ctx in d.contexts:
        for ch in ctx.channels:
            figs[f"diagnose_residuals_{ctx.index}_{ch}"] = residuals_figure(d, ctx.index, ch)
    for e in d.effects:
        figs[f"diagnose_evidence_{e.name}"] = evidence_figure(d, e.name)
    return figs


def comparison_figure(c) -> plt.Figure:
    """A model against one dataset's channel (:class:`~iiwa_ident.diagnose.ChannelComparison`): measured and
    predicted over time with the fit, then the residual's autocorrelation and its cross-correlation with the
    input, each with its per-lag bounds (as ``resid`` draws them) and the test's verdict."""
    fig = plt.figure(figsize=(11, 7))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.3, 1])
    ax = fig.add_subplot(grid[0, :])
    ax.plot(c.t - c.t[0], c.predicted, lw=1.2, color="C0", label=f"predicted (fit {c.fit_pct:.1f} %)")
    ax.plot(c.t - c.t[0], c.measured, lw=0.6, color="0.2", label="measured")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("torque [Nm]")
    ax.set_title(f"{c.dataset}: {_CHANNEL_LABEL.get(c.channel, c.channel).split(' (')[0]}, RMS error "
                 f"{c.rms_nm:.3g} Nm", fontsize=10)
    ax.legend(loc="upper right", fontsize=8)
    for i, t in enumerate(c.tests.tests):
        a = fig.add_subplot(grid[1, i])
        a.vlines(t.lags, 0, t.correlation, color=["C3" if k in t.failing else "C0" for k in t.lags], lw=1.5)
        a.plot(t.lags, t.bound, "k--", lw=0.8)
        a.plot(t.lags, -t.bound, "k--", lw=0.8)
        a.axhline(0, color="0.5", lw=0.5)
        a.set_xlabel(f"lag [samples of {1e3 * c.lag_s:.3g} ms]")
        a.set_ylabel("normalised correlation")
        a.set_title(f"{t.name}: {'passed' if t.passed else 'FAILED'} (p = {t.p_value:.2g})", fontsize=9)
    fig.tight_layout()
    return fig
