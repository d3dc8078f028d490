"""Subcommand ``fit``: eq (4) with delay and uncertainties from torque-commanded chirps."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Optional

import typer

from iiwa_ident._toml import write_atomic
from iiwa_ident.cli._app import app, fail, json_text
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident.model_file import PARAMETER_UNITS, write_model
from iiwa_ident.ident.tf_fit import PARAMETER_NAMES, FitResult, fit_model

__all__ = ["fit_cmd", "format_fit"]

# Units shown where they differ from the model file's SI unit: name -> (unit, factor from SI).
_DISPLAY = {"Td": ("ms", 1e3)}


def _value_text(name: str, value: float, std: float) -> tuple[str, str, str]:
    unit, factor = _DISPLAY.get(name, (PARAMETER_UNITS[name], 1.0))
    rel = f"{100 * std / abs(value):.2f} %" if value else "-"
    return f"{value * factor:.6g} {unit}", f"{std * factor:.3g} {unit}", rel


def _band(lo: float, hi: float) -> str:
    return f"{lo:.3g}-{hi:.3g} Hz"


def format_fit(result: FitResult) -> str:
    """The human-readable summary printed by ``iiwa-ident fit``.

    Parameters
    ----------
    result : FitResult
        A fit from :func:`iiwa_ident.ident.tf_fit.fit_transfer_function`.

    Returns
    -------
    str
        Parameter table (value, std, relative std; the delay in ms), residual
        noise levels, fit quality per octave band and the nonlinear share
        per octave band.
    """
    lines = ["parameter  value                std              rel. std"]
    for name in PARAMETER_NAMES:
        v, s, r = _value_text(name, result.parameters[name], result.std[name])
        lines.append(f"{name:<10} {v:<20} {s:<16} {r}")
    lines.append(f"delay Td = {result.parameters['Td'] * 1e3:.3f} +- {result.std['Td'] * 1e3:.3f} ms")
    for label, noise in zip(result.labels, result.noise):
        lines.append(f"residual noise ({Path(label).name}): tau_j {noise['tau_j_nm']:.3g} Nm RMS, "
                     f"q_m {noise['q_m_rad']:.3g} rad RMS")
    lines.append("")
    lines.append("fit quality per octave band (H1 of tau_c -> tau_j against the fitted model)")
    lines.append("  band              coherence  rel. error  error / uncertainty")
    multi = len(result.labels) > 1
    for b in result.bands:
        tag = f"  [{Path(b.dataset).name}]" if multi else ""
        lines.append(f"  {_band(b.lo_hz, b.hi_hz):<16}  {b.coherence:9.3f}  {100 * b.rel_error:8.2f} %"
                     f"  {b.z_rms:19.2f}{tag}")
    if any(result.nonlinear):
        lines.append("")
        lines.append("nonlinear share per octave band (output power in harmonics 2.. of the sweep)")
        for label, bands in zip(result.labels, result.nonlinear):
            tag = f"  [{Path(label).name}]" if multi else ""
            for b in bands:
                share = "     n/a" if not math.isfinite(b.share) else f"{100 * b.share:6.2f} %"
                if len(b.harmonics) > 1:
                    ks = f"harmonics 2-{b.harmonics[-1]} measurable"
                else:
                    ks = "no harmonic inside the sweep"
                lines.append(f"  {_band(b.lo_hz, b.hi_hz):<16}  {share}  ({ks}){tag}")
    return "\n".join(lines)


@app.command("fit")
def fit_cmd(
    chirps: Annotated[list[Path], typer.Argument(help="Chirp dataset files (.h5) of one joint, fitted together.")],
    out: Annotated[Path, typer.Option("--out", help="Model file to write (TOML).")],
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Also write the result as JSON (SI units, "
                                                                   "Td in s).")] = None,
    model: Annotated[Optional[Path], typer.Option("--model", help="Base model whose K_I and ripple table are "
                                                                  "kept (default: K_I = 25 rad/s, Table I).")] = None,
    figures: Annotated[Optional[Path], typer.Option("--figures", help="Folder for the Bode and harmonic "
                                                                      "distortion plots (PNG).")] = None,
) -> None:
    """Fit eq (4) with its delay to torque-commanded chirps, with uncertainties.

    Both the joint torque and the motor position are fitted from the torque
    command (time-domain maximum likelihood), so all four parameters and the
    delay are identified, not only their ratios. Prints the parameters with
    their standard deviations, the fit quality and the nonlinear share per
    octave band, and warnings.

    Example: iiwa-ident fit chirp.h5 --out joint1.toml --json joint1.json --figures figs/
    """
    try:
        for target in (out, json_out):
            if target is not None and target.is_dir():
                raise IiwaIdentError(f"{target}: is a directory, not a file")
        if figures is not None and figures.exists() and not figures.is_dir():
            raise IiwaIdentError(f"{figures}: exists and is not a folder")
        joint_model, result = fit_model(chirps, base_model=model)
        # Prepare every output before writing any, so a failure leaves no partial results.
        json_doc = json_text(result.to_json()) if json_out else None
        pngs: dict[str, bytes] = {}
        if figures is not None:
            from iiwa_ident.report.fit_figures import fit_figure_pngs

            pngs = fit_figure_pngs(result)
        written = [write_model(out, joint_model)]
        if json_doc is not None:
            written.append(write_atomic(json_out, json_doc))
        for name, data in pngs.items():
            written.append(write_atomic(figures / name, data))
    except IiwaIdentError as err:
        raise fail(str(err))
    except OSError as err:
        raise fail(f"{err.filename or 'output'}: cannot write ({err.strerror or err})")
    typer.echo(format_fit(result))
    for w in result.warnings:
        typer.echo(f"warning: {w}", err=True)
    for path in written:
        typer.echo(f"wrote {path}")
