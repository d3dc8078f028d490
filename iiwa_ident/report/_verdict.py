"""Page 1 of the report: the verdict of each stage, computed from ``pipeline.json`` alone.

Every figure on the page is read from a stage's headline in ``pipeline.json`` (the same numbers the
pipeline prints and the stage pages draw), never typed: :func:`verdict_rows` is a pure function of that
document, so a test can build it on two plants and check that the page follows the data.

Verdicts:

- ``PASS``: the figure meets its reference (stated in the row);
- ``WARN``: it misses it, but not by what makes the result unusable, or the data cannot decide;
- ``FAIL``: the result contradicts the reference;
- ``SKIPPED``: the stage did not run, for the reason shown (the data cannot support it, the user skipped
  it, or a stage it needs did not succeed, whose own row says why): neither a pass nor a warning.

References: the paper's ripple period (0.01963 rad, given to 4 digits: 0.03 %) and its "about 3 times the
gain margin"; a fitted parameter against the simulated plant within 3 standard deviations; an improved
observer, step and sine tracking better than the robot's own loop.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from iiwa_ident.model import RIPPLE_PERIOD_RAD

__all__ = ["VerdictRow", "verdict_rows", "PASS", "WARN", "FAIL", "SKIPPED"]

PASS, WARN, FAIL, SKIPPED = "PASS", "WARN", "FAIL", "SKIPPED"

#: The pipeline stage each row label belongs to (rows are listed in the pipeline's stage order).
_ROW_STAGE = {"fit with table": "ripple", "observer": "design", "step": "validation", "sine": "validation",
              "kappa live": "validation", "held out": "held_out"}

#: Relative tolerance of the ripple period against the paper's value: its printed digits (0.01963).
_PERIOD_DIGITS = 0.5e-5 / RIPPLE_PERIOD_RAD
#: The paper's gain margin ratio of the additive controller over the built-in loop ("about 3x").
_PAPER_KAPPA_RATIO = 3.0


@dataclass(frozen=True)
class VerdictRow:
    """One row of page 1: the stage, its key figure with unit, the reference it is judged by and the verdict."""

    stage: str
    figure: str
    reference: str
    verdict: str


def _stage(doc: dict[str, Any], name: str) -> dict[str, Any] | None:
    return next((s for s in doc.get("stages", []) if s["name"] == name), None)


#: A fit's torque residual beyond this multiple of the simulated sensor noise leaves something unexplained.
_NOISE_FLOOR_FACTOR = 1.5


#: How far the linear prediction of the loop as deployed may be from the live margin [%].
KAPPA_PREDICTION_PCT = 15.0


def _kappa_live_row(source: str, kl: dict) -> VerdictRow:
    """The live kappa sweep of one source: both live margins beside their prediction, and the ratio."""
    def f(x):
        return "-" if x is None else f"{x:.3g}"

    b, a = kl["builtin"], kl["additive"]
    errors = [r.get("linear_error_pct") for r in (b, a)]
    agree = all(e is not None and abs(e) <= KAPPA_PREDICTION_PCT for e in errors)
    ratio = kl.get("ratio_live")
    figure = (f"stable to {f(b['live_limit'])} built-in, {f(a['live_limit'])} additive = {f(ratio)}x live; "
              f"linear {f(b['linear_limit'])} and {f(a['linear_limit'])} = {f(kl.get('ratio_linear'))}x")
    # Where a loop's command sat at the runtime's torque-rate limit the prediction (which has none) does not
    # describe it: say from which kappa, so that a missed prediction carries its cause.
    for name, r in (("built-in", b), ("additive", a)):
        if r.get("rate_limited_from") is not None:
            figure += f"; {name} at the torque-rate limit from {f(r['rate_limited_from'])}"
    name = {"ft": "kappa live, F/T", "estimate": "kappa live, estimate", "fri": "kappa live, KUKA"}.get(source, source)
    ok = ratio is not None and ratio >= 0.8 * _PAPER_KAPPA_RATIO and agree
    return VerdictRow(name, figure, f"paper 15 / 4.6 = 3.3x measured; linear within {KAPPA_PREDICTION_PCT:g} %",
                      PASS if ok else WARN)


def _fit_row(stage: str, h: dict[str, Any]) -> VerdictRow:
    params, rejected = h.get("parameters", {}), h.get("model_rejected")
    z = {k: abs(r["error_std"]) for k, r in params.items() if r.get("error_std") is not None}
    rel = max((abs(r["rel_std_pct"]) for r in params.values() if r.get("rel_std_pct") is not None), default=None)
    whose = "its residual (the ripple's harmonics fitted alongside)" if "ripple" in h.get("method", "") else \
        "residual"
    tests = "" if rejected is None else (f"; {whose} follows the command" if rejected else
                                         f"; {whose} independent of the command")
    level, floor = h.get("residual_tau_j_nm"), h.get("sensor_noise_nm")
    above = level is not None and floor is not None and level > _NOISE_FLOOR_FACTOR * floor
    if level is not None:
        tests += f"; residual {level:.3g} Nm RMS" + (f" (sensor noise {floor:.3g})" if floor is not None else "")
    rejected = bool(rejected) or above
    if z:
        worst = max(z, key=lambda k: z[k])
        fig = f"worst {worst} at {z[worst]:.1f} std of the plant (error {params[worst]['error_pct']:+.3g} %){tests}"
        verdict = PASS if z[worst] <= 3 else (WARN if z[worst] <= 6 else FAIL)
        if rejected:
            verdict = WARN if verdict == PASS else verdict
        return VerdictRow(stage, fig, "every parameter within 3 std of the simulated plant; residual at the "
                          f"sensor noise (within {_NOISE_FLOOR_FACTOR:g}x) and independent of the command", verdict)
    fig = (f"largest relative std {rel:.2g} %" if rel is not None else "parameters fitted") + tests
    return VerdictRow(stage, fig, "residual independent of the command (no truth to compare)",
                      WARN if rejected else PASS)


def _import_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """The runs a logs pipeline imported, and how many of them came with warnings."""
    rows: list[VerdictRow] = []
    runs = h.get("runs", [])
    warned = sum(bool(r.get("warnings")) for r in runs)
    rows.append(VerdictRow("import", f"{len(runs)} run(s), {warned} with warnings (see the runs page)",
                           "logs that say what they can give", WARN if warned else PASS))
    return rows


def _fit_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """The fit's parameters against the simulated plant or their std."""
    return [_fit_row("fit", h)]


def _ripple_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """The ripple's period against the paper's, and the fit with its table."""
    rows: list[VerdictRow] = []
    if h.get("detected"):
        rho, sd = h["period_rad"], h.get("period_std_rad")
        dev = rho / RIPPLE_PERIOD_RAD - 1.0
        fig = f"rho = {rho:.6f} rad" + (f" +- {sd:.2g}" if sd else "") + f" ({100 * dev:+.3f} % from the paper)"
        m = int(round(rho / RIPPLE_PERIOD_RAD))
        if 2 <= m <= 4 and abs(rho / (m * RIPPLE_PERIOD_RAD) - 1.0) <= 5e-3:
            # A longer period whose family holds the paper's line (once per motor revolution, for m = 2).
            fig = (f"rho = {rho:.6f} rad" + (f" +- {sd:.2g}" if sd else "") + f", {m} x the paper's "
                   f"({100 * (rho / (m * RIPPLE_PERIOD_RAD) - 1):+.2f} %): its harmonic {m} is the paper's line")
        rows.append(VerdictRow("ripple", fig, f"paper {RIPPLE_PERIOD_RAD} rad (+-{100 * _PERIOD_DIGITS:.2f} %, "
                               "its digits)", PASS if abs(dev) <= _PERIOD_DIGITS else WARN))
    else:
        rows.append(VerdictRow("ripple", "no period found", f"paper {RIPPLE_PERIOD_RAD} rad", WARN))
    refit = h.get("refit")
    if refit:
        rows.append(_fit_row("fit with table", refit))
    return rows


def _design_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """The linear kappa margins' ratio and the observers' errors."""
    rows: list[VerdictRow] = []
    ratio = h.get("kappa_ratio")
    if ratio is not None:
        rows.append(VerdictRow("design", f"kappa margin (linear, section V.C's model) "
                               f"{h['kappa_max_additive']:.3g} additive / "
                               f"{h['kappa_max_builtin']:.3g} built-in = {ratio:.2f}x",
                               f"paper about {_PAPER_KAPPA_RATIO:g}x",
                               PASS if ratio >= 0.8 * _PAPER_KAPPA_RATIO else (WARN if ratio > 1 else FAIL)))
    obs = h.get("observer")
    if obs:
        better = obs["improved_rms_nm"] < obs["builtin_rms_nm"]
        raw = ""
        if obs.get("improved_rms_raw_nm") is not None:
            raw = (f"; against the F/T itself {obs['improved_rms_raw_nm']:.3g} and {obs['builtin_rms_raw_nm']:.3g}"
                   " Nm (their common lag dominates)")
        rows.append(VerdictRow("observer", f"improved {obs['improved_rms_nm']:.3g} Nm against built-in "
                               f"{obs['builtin_rms_nm']:.3g} Nm RMS ({obs['improvement']:.2f}x), |v| > "
                               f"{obs.get('speed_threshold_rad_s', 0.5):g} rad/s{raw}",
                               "F/T reference through the observers' own lag (K_I)", PASS if better else FAIL))
    return rows


def _deploy_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """The deployed config's safety checks."""
    rows: list[VerdictRow] = []
    ok = h.get("checks_passed") == h.get("checks")
    rows.append(VerdictRow("deploy", f"{h.get('checks_passed')}/{h.get('checks')} checks, torque limit "
                           f"{h.get('torque_limit_nm')} Nm", "every check passes", PASS if ok else FAIL))
    return rows


def _validation_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """Step and sine through FRI, and the live kappa margins."""
    rows: list[VerdictRow] = []
    step = h.get("tracking", {}).get("step")
    if step:
        rows.append(VerdictRow("step", f"overshoot {step['additive_overshoot_pct']:.0f} % additive, "
                               f"{step['builtin_overshoot_pct']:.0f} % built-in", "below the built-in loop's",
                               PASS if step["additive_overshoot_pct"] < step["builtin_overshoot_pct"] else FAIL))
    sine = h.get("tracking", {}).get("sine")
    if sine:
        hz = h.get("sine_hz")
        rows.append(VerdictRow("sine", f"{'' if hz is None else f'{hz:g} Hz '}peak error "
                               f"{sine['additive_peak_error_nm']:.3g} Nm additive, "
                               f"{sine['builtin_peak_error_nm']:.3g} Nm built-in", "below the built-in loop's",
                               PASS if sine["additive_peak_error_nm"] < sine["builtin_peak_error_nm"] else FAIL))
    for source, kl in (h.get("kappa_live") or {}).items():
        rows.append(_kappa_live_row(source, kl))
    if h.get("kappa_live_skipped"):
        rows.append(VerdictRow("kappa live", "not measured", h["kappa_live_skipped"], WARN))
    return rows


def _diagnose_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """What the diagnosis named, or that the model explains the data."""
    rows: list[VerdictRow] = []
    if h.get("explained"):
        rows.append(VerdictRow("diagnose", "the model explains the data: nothing named",
                               "no effect lowers the held-out residual; residual tests pass", PASS))
    else:
        named = ", ".join(f"{e['name']} ({e['gain_pct']:.0f} %)" for e in h.get("effects", [])) or "none"
        left = h.get("unexplained_channels", [])
        turned = h.get("sign_reversed", [])
        rows.append(VerdictRow("diagnose", (f"torque sign reversed in {len(turned)} run(s) (--scale tau_j=-1); "
                                            if turned else "") + f"named: {named}"
                               + (f"; residual tests fail on {len(left)} channel(s)" if left else ""),
                               "the model explains the data", WARN))
    return rows


def _held_out_rows(h: dict[str, Any]) -> list[VerdictRow]:
    """Each run predicted from the others."""
    rows: list[VerdictRow] = []
    runs = h.get("runs", [])
    ratios = [r["ratio"] for r in runs if r.get("ratio") is not None]
    if ratios:
        # Lower is not enough: a prediction worse than a run's mean (negative fit) does not model that run.
        fits = [f for r in runs for f in r.get("fit_pct", {}).values() if f is not None]
        worse = [f for f in fits if f < 0]
        rows.append(VerdictRow("held out", f"each run predicted from the others at {100 * min(ratios):.0f}-"
                               f"{100 * max(ratios):.0f} % of the starting model's RMS"
                               + (f"; {len(worse)} channel(s) with a fit below 0 % (worst {min(worse):.0f} %)"
                                  if worse else ""),
                               "every run lower, every fit above 0 %",
                               PASS if max(ratios) < 1 and not worse else WARN))
    return rows


#: Each stage's rows from its headline in ``pipeline.json``, in the order they are made.
_STAGE_ROWS: dict[str, Callable[[dict[str, Any]], list[VerdictRow]]] = {
    "import": _import_rows,
    "fit": _fit_rows,
    "ripple": _ripple_rows,
    "design": _design_rows,
    "deploy": _deploy_rows,
    "validation": _validation_rows,
    "diagnose": _diagnose_rows,
    "held_out": _held_out_rows,
}


def verdict_rows(doc: dict[str, Any]) -> list[VerdictRow]:
    """The verdict table of a pipeline run (module docstring), one row per stage that has results.

    Parameters
    ----------
    doc : dict
        The content of ``pipeline.json``.

    Returns
    -------
    list of VerdictRow
        In the pipeline's stage order; a failed stage is a ``FAIL`` row with its message, a skipped one a
        ``SKIPPED`` row with its reason.
    """
    rows: list[VerdictRow] = []
    for s in doc.get("stages", []):
        if s["status"] == "failed":
            rows.append(VerdictRow(s["name"], f"failed: {s.get('error', '')}", "the stage runs", FAIL))
        elif s["status"] == "skipped" and s["name"] != "report":
            why = s.get("error", "").removeprefix("skipped: ")
            rows.append(VerdictRow(s["name"], why, "the stage runs", SKIPPED))
    by = {s["name"]: s.get("headline", {}) for s in doc.get("stages", []) if s["status"] == "ok"}
    for name, rows_of in _STAGE_ROWS.items():
        if name in by:
            rows += rows_of(by[name])
    order = [s["name"] for s in doc.get("stages", [])]
    where = {r: order.index(_ROW_STAGE.get(r.stage, r.stage)) if _ROW_STAGE.get(r.stage, r.stage) in order
             else len(order) for r in rows}
    return sorted(rows, key=lambda r: where[r])
