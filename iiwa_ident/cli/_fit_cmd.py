"""Subcommand ``fit``: eqs (1)-(4) with delay, link-side effects and uncertainties from torque-commanded chirps."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NamedTuple, Optional

import typer

from iiwa_ident._toml import write_atomic
from iiwa_ident.cli._app import app, fail, json_text
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    from iiwa_ident.ident import BlaFit, FitResult

__all__ = ["fit_cmd", "format_fit", "format_bla_fit"]

# Units shown where they differ from the model file's SI unit: name -> (unit, factor from SI).
_DISPLAY = {"Td": ("ms", 1e3)}


class _ValueText(NamedTuple):
    """A parameter's value, std and relative std as printed."""

    value: str
    std: str
    rel_std: str


def _value_text(name: str, value: float, std: float) -> _ValueText:
    from iiwa_ident.model import PARAMETER_UNITS

    unit, factor = _DISPLAY.get(name, (PARAMETER_UNITS[name], 1.0))
    rel = f"{100 * std / abs(value):.2f} %" if value else "-"
    return _ValueText(f"{value * factor:.6g} {unit}", f"{std * factor:.3g} {unit}", rel)


def _band(lo: float, hi: float) -> str:
    return f"{lo:.3g}-{hi:.3g} Hz"


def _parameter_lines(values: dict[str, float], std: dict[str, float]) -> list[str]:
    """The parameter table (value, std, relative std; the delay in ms) and the delay line."""
    from iiwa_ident.model import PARAMETER_NAMES

    lines = ["parameter  value                std              rel. std"]
    for name in PARAMETER_NAMES:
        v, s, r = _value_text(name, values[name], std[name])
        lines.append(f"{name:<10} {v:<20} {s:<16} {r}")
    lines.append(f"delay Td = {values['Td'] * 1e3:.4g} +- {std['Td'] * 1e3:.2g} ms")
    return lines


def format_fit(result: FitResult) -> str:
    """The human-readable summary printed by ``iiwa-ident fit``.

    Parameters
    ----------
    result : FitResult
        A fit from :func:`iiwa_ident.ident._tf_fit.fit_transfer_function`.

    Returns
    -------
    str
        Parameter table (value, std, relative std; the delay in ms), residual
        noise levels, fit quality per octave band and the nonlinear share
        per octave band.
    """
    from iiwa_ident.ident import log_filter_text
    from iiwa_ident.model import PARAMETER_NAMES

    lines = _parameter_lines(result.parameters, result.std)
    lines.append(f"method: {result.method}")
    lines.append(f"std: {result.std_method}")
    if result.model_rejected and result.std_robust:
        lines.append("the residual follows the command: the std above assumes a complete model and is not to be "
                     "trusted; model-error aware std:")
        lines.append("  " + ", ".join(f"{k} {_value_text(k, result.parameters[k], result.std_robust[k])[1]}"
                                      for k in PARAMETER_NAMES))
        lines.append(f"  ({result.std_robust_method})")
    if result.effects:
        lines.append("")
        lines.append("link-side effects (simulator names; * = above 3 std)")
        for e in result.effects:
            # A value searched rather than estimated (the ripple's period) has no std to show.
            vals = ", ".join(f"{k} = {v:.4g} +- {e.std[k]:.2g}" if math.isfinite(e.std[k]) else
                             f"{k} = {v:.4g} (searched, no std)" for k, v in e.values.items()
                             if not (math.isfinite(e.std[k]) and e.std[k] == 0.0))
            lines.append(f"  {'*' if e.significant else ' '} {e.name}: {vals}")
            if e.note:
                lines.append(f"      ({e.note})")
        lines.append("")
    if result.log_filter is not None:
        lines.append(f"torque_log_filter (the log of tau_j only): {log_filter_text(result.log_filter)}")
        lines.append("")
    for label, noise in zip(result.labels, result.noise):
        lines.append(f"residual noise ({Path(label).name}): tau_j {noise['tau_j_nm']:.3g} Nm RMS, "
                     f"q_m {noise['q_m_rad']:.3g} rad RMS")
    lines.append("")
    less = " less the effects' response" if result.effects else ""
    lines.append(f"fit quality per octave band (H1 of tau_c -> tau_j{less} against the fitted eq (4))")
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
            for nb in bands:
                share = "     n/a" if not math.isfinite(nb.share) else f"{100 * nb.share:6.2f} %"
                if len(nb.harmonics) > 1:
                    ks = f"harmonics 2-{nb.harmonics[-1]} measurable"
                else:
                    ks = "no harmonic inside the sweep"
                lines.append(f"  {_band(nb.lo_hz, nb.hi_hz):<16}  {share}  ({ks}){tag}")
    return "\n".join(lines)


def format_bla_fit(result: BlaFit) -> str:
    """The summary printed by ``iiwa-ident fit`` for multisines: parameters, chi2/dof, the BLA's variances."""
    lines = _parameter_lines(result.parameters, result.std)
    lines.append("method: best linear approximation of the multisines (robust method), eq (4) fitted to it")
    lines.append(f"std: {result.std_method}")
    lines.append(f"chi2/dof {result.chi2_dof:.2f} (about 1 when eq (4) explains the BLA within its variance)")
    lines.append("")
    lines.append("BLA variance per octave band, relative to |G|^2 (noise: from the periods; nonlinear: the")
    lines.append("realisations' spread beyond it)")
    lines.append("  output  band              lines   noise        nonlinear")
    multi = len(result.labels) > 1
    for row in result.variance_bands():
        tag = f"  [{Path(str(row['dataset'])).name}]" if multi else ""
        lines.append(f"  {row['output']:<6}  {_band(float(row['lo_hz']), float(row['hi_hz'])):<16}  {row['lines']:5d}   "
                     f"{row['noise_rel']:<11.3g}  {row['nonlinear_rel']:.3g}{tag}")
    return "\n".join(lines)


@app.command("fit")
def fit_cmd(
    chirps: Annotated[list[Path], typer.Argument(help="Chirp dataset files (.h5) of one joint, fitted together; "
                                                     "or multisine files (fitted through their best linear "
                                                     "approximation).")],
    out: Annotated[Path, typer.Option("--out", help="Model file to write (TOML).")],
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Also write the result as JSON (SI units, "
                                                                   "Td in s).")] = None,
    model: Annotated[Optional[Path], typer.Option("--model", help="Base model whose K_I and ripple table are "
                                                                  "kept; the fit takes the ripple's period from "
                                                                  "it instead of searching (default: K_I = 25 "
                                                                  "rad/s, Table I).")] = None,
    figures: Annotated[Optional[Path], typer.Option("--figures", help="Folder for the Bode and harmonic "
                                                                      "distortion plots (PNG).")] = None,
    method: Annotated[str, typer.Option("--method", help="Estimator: auto (idim when the link shows Coulomb "
                                                         "friction, else joint), joint (inverse dynamics, then "
                                                         "output error with the effects and the transmission "
                                                         "ripple's deflection; reported as joint+ripple when it "
                                                         "shows), idim (inverse dynamics only) or eq4 (output "
                                                         "error of eq (4) without link-side effects or "
                                                         "ripple).")] = "auto",
) -> None:
    """Fit eqs (1)-(4) with the delay and the link-side effects to torque-commanded chirps.

    Every channel is used (commanded torque, joint torque, motor position,
    link angle from eq (9)): the inverse dynamics give link friction, a
    position-dependent load, the torque-sensor offset and the transmission
    ripple (its period searched, or taken from --model) with the joint's
    parameters; the sampled-data output-error fit then refines the joint's
    parameters with those effects as known torques. Prints the parameters
    with their standard deviations, the effects, the fit quality and the
    nonlinear share per octave band, and warnings. A parameter the data
    cannot identify is refused with the reason. A joint torque low-pass
    filtered before it was logged (a driver's filter) is fitted through:
    its cut-off with the parameters, kept where the likelihood asks for it;
    it acts on the log only.

    Examples:

      iiwa-ident fit chirp.h5 --out joint1.toml --json joint1.json --figures figs/

      iiwa-ident fit chirp_a.h5 chirp_b.h5 --method idim --out joint2.toml

      iiwa-ident fit chirp.h5 --model joint1_ripple.toml --out joint1.toml

      iiwa-ident fit ms.h5 --out joint1.toml --json joint1.json   (a multisine: the BLA's noise and nonlinear
      variance per band, the std from both)
    """
    from iiwa_ident.ident import METHODS, BlaFit, fit_model, write_model

    try:
        if method not in METHODS:
            raise IiwaIdentError(f"--method: unknown estimator {method!r} (known: {', '.join(METHODS)})")
        for target in (out, json_out):
            if target is not None and target.is_dir():
                raise IiwaIdentError(f"{target}: is a directory, not a file")
        if figures is not None and figures.exists() and not figures.is_dir():
            raise IiwaIdentError(f"{figures}: exists and is not a folder")
        pngs: dict[str, bytes] = {}
        with progress(f"fitting {', '.join(p.name for p in chirps)}") as shown:
            joint_model, result = fit_model(chirps, base_model=model, method=method)
            if figures is not None and not isinstance(result, BlaFit):
                shown.say("drawing the figures")
                from iiwa_ident.report import fit_figure_pngs

                pngs = fit_figure_pngs(result)
        if isinstance(result, BlaFit):
            if figures is not None:
                raise IiwaIdentError("--figures: the plots are of chirp fits; not made for multisines")
            text, warnings = format_bla_fit(result), result.warnings()
        else:
            text, warnings = format_fit(result), list(result.warnings)
        # Prepare every output before writing any, so a failure leaves no partial results.
        json_doc = json_text(result.to_json()) if json_out else None
        written = [write_model(out, joint_model)]
        if json_doc is not None and json_out is not None:
            written.append(write_atomic(json_out, json_doc))
        for name, data in pngs.items():
            written.append(write_atomic(figures / name, data))  # type: ignore[operator]  # pngs only with --figures
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    except OSError as err:
        raise fail(f"{err.filename or 'output'}: cannot write ({err.strerror or err})") from None
    typer.echo(text)
    for w in warnings:
        typer.echo(f"warning: {w}", err=True)
    for path in written:
        typer.echo(f"wrote {path}")
