"""Figures of a transfer-function fit: Bode plot with uncertainty, and harmonic distortion.

The Bode plot compares the non-parametric H1 of ``tau_c -> tau_j`` (with a
band of two standard deviations) with the fitted sampled-data model and the
continuous eq (4), and shows the coherence underneath, like Fig. 3 of the
paper. The distortion figure shows the harmonic responses separated by the
exponential-sweep deconvolution and the nonlinear share per octave band.
"""

from __future__ import annotations

import io
import math

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from iiwa_ident.ident import FitResult
from iiwa_ident.model import discretize, frequency_response

__all__ = ["bode_figure", "harmonics_figure", "fit_figure_pngs"]


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.abs(x))


def bode_figure(result: FitResult, index: int = 0) -> Figure:
    """Bode plot of data (H1 with a 2-sigma band), fitted model and coherence.

    Parameters
    ----------
    result : FitResult
        The fit.
    index : int
        Which dataset of the fit to show.

    Returns
    -------
    matplotlib.figure.Figure
        Three panels: magnitude [dB], phase [deg], coherence.
    """
    est = result.frf[index]
    T = result.sample_times_s[index]
    p = result.parameters
    f = est.f_hz
    fine = np.geomspace(f.min(), f.max(), 600)
    dm = discretize(p, T)
    model_fine = dm.frequency_response(fine)[0]
    eq4_fine = frequency_response(p, fine)

    fig, (ax_m, ax_p, ax_c) = plt.subplots(3, 1, figsize=(8.0, 8.5), sharex=True,
                                            gridspec_kw={"height_ratios": [3, 3, 1.4]})
    mag = np.abs(est.H)
    lo = np.maximum(mag - 2 * est.std_mag, mag * 1e-3)
    hi = mag + 2 * est.std_mag
    # The band is often narrower than the points: its median width is in the legend, so it is read even then.
    width_db = float(np.median(_db(hi) - _db(lo)))
    width_deg = float(np.median(4 * np.degrees(est.std_phase_rad)))
    ax_m.fill_between(f, _db(lo), _db(hi), color="tab:blue", alpha=0.25, lw=0,
                      label=f"H1 $\\pm 2\\sigma$ (median width {width_db:.2g} dB, {width_deg:.2g} deg)")
    ax_m.semilogx(f, _db(est.H), ".", color="tab:blue", ms=4, label="H1 (data)")
    ax_m.semilogx(fine, _db(model_fine), "-", color="tab:red", lw=1.4, label="fitted model (sampled, ZOH)")
    ax_m.semilogx(fine, _db(eq4_fine), "--", color="k", lw=0.9, label="eq (4), continuous")
    ax_m.set_ylabel("magnitude [dB] (Nm/Nm)")
    ax_m.legend(loc="lower left", fontsize=8)
    ax_m.grid(True, which="both", alpha=0.3)

    # Unwrap the data's phase relative to the model so both share one branch.
    model_at_f = dm.frequency_response(f)[0]
    ph_model = np.unwrap(np.angle(model_fine))
    ph_model_f = np.interp(f, fine, ph_model)
    ph_data = ph_model_f + np.angle(est.H / model_at_f)
    dphi = 2 * np.degrees(est.std_phase_rad)
    ax_p.fill_between(f, np.degrees(ph_data) - dphi, np.degrees(ph_data) + dphi, color="tab:blue", alpha=0.25, lw=0)
    ax_p.semilogx(f, np.degrees(ph_data), ".", color="tab:blue", ms=4, label="H1 (data)")
    ax_p.semilogx(fine, np.degrees(ph_model), "-", color="tab:red", lw=1.4, label="fitted model")
    ax_p.semilogx(fine, np.degrees(np.interp(fine, fine, ph_model) + np.angle(eq4_fine / model_fine)), "--",
                  color="k", lw=0.9, label="eq (4)")
    ax_p.set_ylabel("phase [deg]")
    ax_p.grid(True, which="both", alpha=0.3)

    ax_c.semilogx(f, est.coherence, ".-", color="tab:green", ms=3, lw=0.8)
    ax_c.set_ylim(0, 1.05)
    ax_c.set_ylabel("coherence [-]")
    ax_c.set_xlabel("frequency [Hz]")
    ax_c.grid(True, which="both", alpha=0.3)

    title = (f"tau_c -> tau_j: Jc={p['Jc']:.3g} kg m^2, bc={p['bc']:.3g} Nm s/rad, K={p['K']:.0f} Nm/rad, "
             f"Jl={p['Jl']:.3g} kg m^2, Td={p['Td'] * 1e3:.2f} ms")
    ax_m.set_title(title, fontsize=9)
    fig.suptitle(f"Frequency response and fit: {result.labels[index]}", fontsize=10)
    fig.tight_layout()
    return fig


def harmonics_figure(result: FitResult, index: int = 0) -> Figure | None:
    """Harmonic responses of the sweep and the nonlinear share per octave band (arguments as :func:`bode_figure`).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when the dataset is not an exponential sweep. Top: output
        amplitude of harmonic k per unit input amplitude against the input
        frequency [dB]; bottom: share of the output power in harmonics 2..K
        per octave band [%].
    """
    harm = result.harmonics[index]
    if harm is None:
        return None
    bands = result.nonlinear[index]
    fig, (ax_h, ax_s) = plt.subplots(2, 1, figsize=(8.0, 7.0), gridspec_kw={"height_ratios": [3, 2]})
    f_in = np.geomspace(harm.f0_hz, harm.f1_hz, 400)
    for k in range(1, harm.n_harmonics + 1):
        h = harm.at_input(k, f_in)
        ok = np.isfinite(h)
        if ok.sum() < 2:
            continue
        ax_h.semilogx(f_in[ok], _db(h[ok]), lw=1.6 if k == 1 else 1.0, label="linear (k=1)" if k == 1 else f"k={k}")
    noise = np.sqrt(np.interp(f_in, harm.f_hz, harm.noise[0]))
    ax_h.semilogx(f_in, _db(noise), ":", color="gray", lw=1.0, label="noise floor")
    ax_h.set_xlabel("input frequency [Hz]")
    ax_h.set_ylabel("|harmonic k| per input amplitude [dB]")
    ax_h.set_title("Harmonic responses of tau_j (exponential-sweep deconvolution)", fontsize=10)
    ax_h.grid(True, which="both", alpha=0.3)
    ax_h.legend(fontsize=8, ncol=3, loc="lower left")

    labels = [f"{b.lo_hz:.3g}-{b.hi_hz:.3g}" for b in bands]
    shares = [100 * b.share if math.isfinite(b.share) else 0.0 for b in bands]
    colors = ["tab:red" if math.isfinite(b.share) and b.share > 0.05 else "tab:blue" for b in bands]
    x = np.arange(len(bands))
    ax_s.bar(x, shares, color=colors)
    for xi, b in zip(x, bands):
        if not math.isfinite(b.share):
            ax_s.text(xi, 0, "n/a", ha="center", va="bottom", fontsize=8)
    top = max(shares, default=0.0)
    if top > 2.5:
        ax_s.axhline(5.0, color="tab:red", ls="--", lw=0.8, label="5 % warning level")
        ax_s.set_ylim(0, max(6.0, 1.2 * top))
    else:
        # Far below the warning level: scaled to the data, so the bars show (the level is named in the title).
        ax_s.set_ylim(0, max(1.25 * top, 1e-3))
    if top > 2.5:
        ax_s.legend(fontsize=8, loc="upper right")
    ax_s.set_xticks(x)
    ax_s.set_xticklabels(labels, rotation=30, fontsize=8)
    ax_s.set_xlabel("octave band of the input frequency [Hz]")
    ax_s.set_ylabel("nonlinear share [%]")
    ax_s.set_title("Output power in harmonics 2.. (red: above the 5 % warning level; largest here "
                   f"{top:.2g} %)", fontsize=10)
    ax_s.grid(True, axis="y", alpha=0.3)
    fig.suptitle(f"Harmonic distortion: {result.labels[index]}", fontsize=10)
    fig.tight_layout()
    return fig


def fit_figure_pngs(result: FitResult, dpi: int = 110) -> dict[str, bytes]:
    """All figures of a fit rendered as PNG, by file name (nothing is written).

    Returns
    -------
    dict of str to bytes
        ``bode.png`` and ``harmonics.png`` for a single dataset; with several
        datasets the names carry the dataset number (``bode_2.png``, ...).
    """
    out: dict[str, bytes] = {}
    n = len(result.labels)
    for i in range(n):
        suffix = "" if n == 1 else f"_{i + 1}"
        for name, make in (("bode", bode_figure), ("harmonics", harmonics_figure)):
            fig = make(result, i)
            if fig is None:
                continue
            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=dpi)
            plt.close(fig)
            out[f"{name}{suffix}.png"] = buf.getvalue()
    return out
