"""Subcommand ``design``: the additive torque controller of section V.B from a model file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from iiwa_ident._defaults import DEFAULT_PREFILTER_HZ, DESIGN_BETA, FEEDFORWARD_MODES
from iiwa_ident.cli._app import app, fail, json_option, write_json
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    import numpy as np

    from iiwa_ident.design import AdditiveDesign, OuterLoopMargins

__all__ = ["design_cmd", "parse_poles", "format_design"]


def parse_poles(text: str, option: str) -> list[complex]:
    """Comma-separated Python complex literals (``-180+30j,-180-30j,...``) -> list of complex [rad/s]."""
    poles = []
    for token in text.split(","):
        token = token.strip().replace(" ", "")
        if not token:
            continue
        try:
            poles.append(complex(token))
        except ValueError:
            raise IiwaIdentError(f"{option}: cannot read {token!r} as a complex number (e.g. -180+30j)") from None
    return poles


def _pole_text(poles: np.ndarray) -> str:
    """Poles as ``-180 +- 30j, -620`` (one entry per conjugate pair)."""
    out: list[str] = []
    seen: list[complex] = []
    for z in poles:
        if z.imag < 0 and any(abs(w - z.conjugate()) < 1e-9 * max(1.0, abs(z)) for w in seen):
            continue
        seen.append(z)
        out.append(f"{z.real:.4g} +- {abs(z.imag):.4g}j" if z.imag else f"{z.real:.4g}")
    return ", ".join(out)


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


def _kappa(k: float) -> str:
    return f"> {k:g}" if math.isinf(k) else f"{k:.2f}"


def format_design(design: AdditiveDesign, margins: OuterLoopMargins) -> str:
    """The summary printed by ``iiwa-ident design``: poles, gains, DC gain and outer-loop margins."""
    from iiwa_ident.design import exact_delay_spectral_radius, natural_frequency_damping

    p = design.params
    T = design.sample_time_s
    bp = design.builtin_poles[0]
    fn, zeta = natural_frequency_damping(bp)
    lines = [
        f"model: Jc = {p.Jc:g} kg m^2, bc = {p.bc:g} Nm s/rad, K = {p.K:g} Nm/rad, Jl = {p.Jl:g} kg m^2, "
        f"Td = {p.Td * 1e3:g} ms (Pade c1 = {design.c1:g} 1/s, c2 = {design.c2:g} 1/s^2)",
        f"built-in controller poles: {bp.real:.4g} +- {abs(bp.imag):.4g}j rad/s ({fn:.2f} Hz, zeta {zeta:.3f})",
        f"controller poles: {_pole_text(design.poles)} rad/s",
        f"observer poles:   {_pole_text(design.observer_poles)} rad/s",
        f"K_FSF = {_vec(design.K_fsf)}  [s^3, s^2, s, 1]",
        f"L     = {_vec(design.L)}  [s^-4, s^-3, s^-2, s^-1]",
        f"Kr    = {design.Kr:.4g}  (unit DC gain of the feedback alone)",
        f"discrete at {1 / T:g} Hz: Kd = {_vec(design.Kd)}, Ld = {_vec(design.Ld)}, Kr_d = {design.Kr_d:.4g}"
        + (" (the reference reaches the feedback through the model's y_ref, not through Kr_d)"
           if design.Kr_d == 0.0 and design.feedforward == "reference" else ""),
    ]
    if design.feedforward == "none":
        lines.append("feed-forward: none")
    else:
        lines.append(f"feed-forward: '{design.feedforward}', eq (22) behind a {design.prefilter_hz:g} Hz "
                     f"pre-filter (zeta {design.prefilter_zeta:g})")
    lines.append(f"DC gain tau_r -> tau_J on the model: {design.dc_gain(True):.4f}")
    rho = exact_delay_spectral_radius(design)
    lines.append(f"with the exact {p.Td * 1e3:g} ms delay instead of Pade: spectral radius {rho:.4f} "
                 f"({'stable' if rho < 1 else 'UNSTABLE'})")
    a = margins.arm
    lines.append(f"outer loop tau_r = kappa tau_ext, arm K_h = {a.stiffness:g} Nm/rad, D_h = {a.damping:g} Nm s/rad, "
                 f"J_h = {a.inertia:g} kg m^2 (exact {p.Td * 1e3:g} ms delay, tau_J,filt = tau_J):")
    ratio = "" if math.isinf(margins.additive) or margins.builtin == 0 else f", ratio {margins.ratio:.2f}"
    lines.append(f"  kappa_max built-in {_kappa(margins.builtin)}, additive {_kappa(margins.additive)}{ratio}"
                 f"  (paper, measured: 4.6 and stable at 15)")
    return "\n".join(lines)


@app.command("design")
def design_cmd(
    model: Annotated[Path, typer.Option("--model", help="Model TOML file (from 'fit', or datasets/paper-table1.toml).")],
    out: Annotated[Path, typer.Option("--out", help="Design TOML file to write.")],
    poles: Annotated[str, typer.Option("--poles", help="4 controller poles [rad/s], Python complex literals; "
                                       "use the = form: --poles=-180+30j,-180-30j,-500+1j,-500-1j")] = "",
    observer_poles: Annotated[str, typer.Option("--observer-poles", help="4 observer poles [rad/s] "
                                                "(default -620,-630,-1000,-1010).")] = "",
    json_out: Annotated[Optional[Path], json_option("the key numbers")] = None,
    paper: Annotated[bool, typer.Option("--paper", help="Also print the reproduction of the paper's section V "
                                        "numbers (Table I model, paper's poles).")] = False,
    feedforward: Annotated[str, typer.Option("--feedforward", help="How Kr and eq (22) combine: "
                                             + " | ".join(FEEDFORWARD_MODES))] = "reference",
    prefilter_hz: Annotated[float, typer.Option("--prefilter-hz", help="Pre-filter of the feed-forward [Hz].")]
    = DEFAULT_PREFILTER_HZ,
    arm_stiffness: Annotated[float, typer.Option("--arm-stiffness", help="Human arm stiffness K_h [Nm/rad].")] = 300.0,
    arm_damping: Annotated[float, typer.Option("--arm-damping", help="Human arm damping D_h [Nm s/rad].")] = 40.0,
    arm_inertia: Annotated[float, typer.Option("--arm-inertia", help="Hand inertia J_h [kg m^2].")] = 0.0,
    beta: Annotated[float, typer.Option("--beta", help="Spatial filter sharpness, eq (10) (paper: 5; "
                                        "2 keeps more outer-loop margin).")] = DESIGN_BETA,
    v_min: Annotated[float, typer.Option("--v-min", help="Spatial filter fade-out speed, eq (12) [rad/s].")] = 0.2,
) -> None:
    """Design the additive torque controller, report poles, gains and kappa margins, write the design file.

    Examples:
      iiwa-ident design --model datasets/paper-table1.toml --out design.toml --paper
      iiwa-ident design --model model.toml --poles=-150+20j,-150-20j,-400,-450 --out d.toml --json d.json
    """
    from iiwa_ident.design import (
        PAPER_OBSERVER_POLES,
        PAPER_POLES,
        FilterSettings,
        HumanArm,
        check_poles,
        design_controller,
        design_json,
        exact_delay_spectral_radius,
        format_reproduction,
        make_record,
        outer_loop_margins,
        paper_reproduction,
        table1_parameters,
        write_design,
    )
    from iiwa_ident.ident import read_model
    from iiwa_ident.model import JointParameters

    try:
        if not (math.isfinite(beta) and beta > 0 and math.isfinite(v_min) and v_min > 0):
            raise IiwaIdentError("--beta and --v-min must be positive")
        p = check_poles(parse_poles(poles, "--poles") if poles else PAPER_POLES, "--poles")
        o = check_poles(parse_poles(observer_poles, "--observer-poles") if observer_poles else PAPER_OBSERVER_POLES,
                        "--observer-poles")
        the_model = read_model(model)
        params = JointParameters.from_model(the_model)
        arm = HumanArm(arm_stiffness, arm_damping, arm_inertia)
        design = design_controller(params, p, o, feedforward=feedforward, prefilter_hz=prefilter_hz)
        margins = outer_loop_margins(design, arm)
        typer.echo(format_design(design, margins))
        if exact_delay_spectral_radius(design) >= 1:
            typer.echo("warning: the additive loop is unstable on the plant with the exact delay; "
                       "the Pade model is too coarse for these poles (choose slower ones)", err=True)
        if paper:
            t1, source = table1_parameters()
            typer.echo("")
            typer.echo(format_reproduction(paper_reproduction(t1), source))
        write_design(out, make_record(design, margins, the_model, model, FilterSettings(beta, v_min)))
        typer.echo(f"wrote {out}")
        if json_out is not None:
            write_json(json_out, design_json(design, margins))
    except IiwaIdentError as err:
        raise fail(str(err)) from None
