"""The PDF report of a pipeline run or of one of its stages (``iiwa-ident report``).

Each page is one figure with a caption block below it that says what to
look at. The report is built from the pipeline's in-memory results, or
from the files of a work folder: the fit's and the ripple stage's results as
the pipeline kept them (``fit_result.h5``, ``ripple_result.h5``), the
diagnosis run again on the stored datasets (no experiment is repeated). A stage that failed or was
skipped gets a page saying so, with the message from ``pipeline.json``,
instead of empty axes; a page whose drawing fails says that too; a stage the
pipeline did not have (``pipeline --logs`` runs no validation) gets no page.
Every page carries a banner saying whether its data are simulated or
measured. A report of measured data adds the runs with what their logs say
about themselves (the provenance warnings of ``import``) and each run's
held-out prediction.
"""

from __future__ import annotations

import functools
import hashlib
import json
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.backends.backend_pdf import PdfPages

from iiwa_ident.errors import IiwaIdentError

__all__ = ["REPORT_STAGES", "Page", "banner", "build_report", "load_results", "report_pages"]

#: Characters of a monospace text page's line (7.5 pt on a page 11 inches wide).
_MONO_WIDTH = 140
#: Files of a work folder that hold results (any one makes a folder worth a report).
_RESULT_FILES = ("chirp.h5", "constant_velocity.h5", "model_ripple.toml", "design.toml", "runs")

#: Stages that have pages, in report order.
REPORT_STAGES = ("fit", "ripple", "design", "validation", "diagnose")

# Which in-memory results each stage's pages need, and the stage that made them.
_NEEDS = {"fit": ("chirp",), "ripple": ("constant_velocity", "fit"), "design": ("design",),
          "validation": ("validation",), "diagnose": ("diagnose",)}


@dataclass
class Page:
    """One report page: its stage, title, caption [text] and a function drawing the figure."""

    stage: str
    title: str
    caption: str
    draw: Callable[[], plt.Figure | None]
    captioned: bool = True


# --------------------------------------------------------------------------- layout helpers
def _captioned(fig: plt.Figure, title: str, caption: str) -> plt.Figure:
    """The figure on a page (:func:`_on_page`) above a caption band that spans the page's width."""
    # About 12 characters of 8.5 pt text per inch of page width.
    lines = textwrap.wrap(f"{title}. {caption}", width=int(PAGE_INCHES[0] * 12))
    band = 0.35 + 0.17 * len(lines)
    fig = _on_page(fig, bottom_in=band)
    fig.text(0.03, (band - 0.1) / PAGE_INCHES[1], "\n".join(lines), fontsize=8.5, va="top", ha="left",
             family="sans-serif")
    return fig


#: Every page's size [in]: US letter, landscape.
PAGE_INCHES = (11.0, 8.5)


def _laid_out(fig: plt.Figure) -> None:
    """Fix the figure's layout as its layout engine computes it, so axes can be moved without it."""
    if fig.get_layout_engine() is not None:
        fig.draw_without_rendering()
        fig.set_layout_engine("none")


#: Band kept free at the top of every page for the banner [in].
_BANNER_INCHES = 0.3


def _on_page(fig: plt.Figure, bottom_in: float = 0.2) -> plt.Figure:
    """The figure on a page of :data:`PAGE_INCHES`, scaled to fill it between the banner's band and
    ``bottom_in`` inches at the bottom with its own proportions, centred (fonts keep their size)."""
    w, h = fig.get_size_inches()
    W, H = PAGE_INCHES
    if abs(w - W) < 1e-6 and abs(h - H) < 1e-6 and bottom_in <= 0.2:
        return fig
    _laid_out(fig)
    room = H - _BANNER_INCHES - bottom_in
    scale = min(W / w, room / h)
    fw, fh = w * scale / W, h * scale / H
    x0, y0 = (1 - fw) / 2, (bottom_in + (room - h * scale) / 2) / H
    fig.set_size_inches(W, H)
    for ax in fig.axes:
        p = ax.get_position()
        ax.set_position((x0 + p.x0 * fw, y0 + p.y0 * fh, p.width * fw, p.height * fh))
    for txt in fig.texts:
        if txt.get_transform() == fig.transFigure:
            x, y = txt.get_position()
            txt.set_position((x0 + x * fw, y0 + y * fh))
    return fig


def _rasterize_dense(fig: plt.Figure, points: int = 4000) -> None:
    """Draw long traces as images inside the PDF: the page looks the same and writes many times faster."""
    for ax in fig.axes:
        for artist in (*ax.lines, *ax.collections):
            n = len(artist.get_xdata()) if hasattr(artist, "get_xdata") else len(getattr(artist, "get_offsets",
                                                                                          lambda: [])())
            if n > points:
                artist.set_rasterized(True)


def _text_page(title: str, body: str, mono: bool = False, size: tuple[float, float] = (11.0, 8.5),
               colour: str = "black") -> plt.Figure:
    """A page of text only (the appendix, tables, failure notices): no axes at all."""
    fig = plt.figure(figsize=size)
    fig.text(0.05, 0.95, title, fontsize=15, va="top", weight="bold", color=colour)
    fig.text(0.05, 0.89, body, fontsize=7.5 if mono else 10, va="top", ha="left",
             family="monospace" if mono else "sans-serif")
    return fig


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# --------------------------------------------------------------------------- results from files
def _stage_status(doc: dict[str, Any] | None, name: str) -> tuple[str, str]:
    """(status, message) of a stage from ``pipeline.json`` (``unknown`` without one)."""
    if doc is None:
        return "unknown", ""
    for s in doc.get("stages", []):
        if s["name"] == name:
            return s["status"], s.get("error", "")
    return "absent", "not in pipeline.json"


def _measured(doc: dict[str, Any] | None) -> bool:
    return doc is not None and doc.get("headline", {}).get("data") == "measured"


def _stage_headline(doc: dict[str, Any] | None, name: str) -> dict[str, Any] | None:
    for s in (doc or {}).get("stages", []):
        if s["name"] == name and s["status"] == "ok":
            return s.get("headline", {})
    return None


def banner(doc: dict[str, Any] | None) -> str:
    """The line every page carries: SIMULATED (the plant file) or MEASURED (the logs or the robot, the robot
    model, the joint); '' without a ``pipeline.json``."""
    if doc is None:
        return ""
    inputs = doc.get("inputs", {})
    if _measured(doc):
        imp = _stage_headline(doc, "import") or {}
        logs = inputs.get("logs", "")
        logs = logs if len(logs) <= 90 else "..." + logs[-87:]
        return (f"MEASURED: {len(doc['headline'].get('runs', []))} run(s) of {inputs.get('robot_model', '?')} joint "
                f"{imp.get('joint', inputs.get('joint', '?'))} from {logs}")
    if "robot" in inputs:
        return f"MEASURED on the robot: {inputs['robot']}"
    if "plant" in inputs:
        return f"SIMULATED: {inputs['plant']}"
    return ""


def load_results(workdir: Path, doc: dict[str, Any] | None, stages: tuple[str, ...] = REPORT_STAGES,
                 ) -> dict[str, Any]:
    """What the report pages need, from the files of a work folder.

    The fit's and the ripple stage's results are read from the files the pipeline kept them in
    (:func:`iiwa_ident.pipeline.load_saved_results`) and computed again only where those no longer stand for
    the folder's data; the diagnosis is computed again.

    Parameters
    ----------
    workdir : Path
        A pipeline work folder.
    doc : dict or None
        Its ``pipeline.json``; stages it marks as failed or skipped are not loaded.
    stages : tuple of str
        Stages whose pages are wanted.

    Returns
    -------
    dict
        The same keys the pipeline keeps in memory (``chirp``, ``fit``,
        ``model``, ``cv``, ``qs``, ``hand``, ``ripple``, ``model_ripple``,
        ``design``, ``validation``, ``diagnosis``) for what could be loaded,
        and ``load_errors`` by stage for what could not.
    """
    ld = _Loader(workdir, doc, stages)
    if ld.p["runs_dir"].is_dir() and ld.usable("import"):
        from iiwa_ident.datasets import read_dataset

        # A folder of `pipeline --logs`: the runs it imported.
        ld.attempt("import", lambda: [read_dataset(f) for f in sorted(ld.p["runs_dir"].glob("*.h5"))], "runs")
    (_load_logs if "runs" in ld.out else _load_experiments)(ld)
    return ld.out


class _Loader:
    """What the report pages draw, loaded stage by stage from a work folder; a stage that cannot be loaded
    leaves its one-line reason in ``out["load_errors"]`` and the others go on."""

    def __init__(self, workdir: Path, doc: dict[str, Any] | None, stages: tuple[str, ...]) -> None:
        from iiwa_ident.pipeline import FILES

        self.workdir, self.doc, self.want = workdir, doc, set(stages)
        self.p = {k: workdir / v for k, v in FILES.items()}
        self.out: dict[str, Any] = {"load_errors": {}}

    def usable(self, stage: str) -> bool:
        return _stage_status(self.doc, stage)[0] in ("ok", "unknown")

    def attempt(self, stage: str, fn: Callable[[], Any], key: str | None = None) -> None:
        """Run ``fn`` for ``stage`` (its value stored under ``key``, if given), its failure kept by stage."""
        try:
            value = fn()
        except IiwaIdentError as err:
            self.out["load_errors"][stage] = str(err)
        except (OSError, KeyError, ValueError) as err:
            self.out["load_errors"][stage] = f"{type(err).__name__}: {err}"
        else:
            if key is not None:
                self.out[key] = value

    def kept(self, file: str, name: str) -> Any:
        """What the stage computed, where its file still stands for the work folder's inputs (else None)."""
        from iiwa_ident.pipeline import load_saved_results

        return (load_saved_results(self.p[file], self.workdir) or {}).get(name)

    def fit(self, chirps: list[Path], base_model: Any = None) -> None:
        """The fit as the pipeline kept it, or fitted again; its model file; the first chirp."""
        from iiwa_ident.datasets import read_dataset
        from iiwa_ident.ident import fit_model, read_model

        result = self.kept("fit_result", "fit")
        if result is None:
            model, result = fit_model(chirps, base_model=base_model)
        else:
            model = read_model(self.p["model"])
        self.out.update(model=model, fit=result)
        if "chirp" not in self.out:
            self.out["chirp"] = read_dataset(chirps[0])

    def ripple(self, data: list[Any], model: Any) -> Any:
        """The ripple stage's result as the pipeline kept it, or identified again with the model's K and Jl."""
        from iiwa_ident.ident import identify_ripple

        return self.kept("ripple_result", "ripple") or identify_ripple(data, K=model.value("K"), Jl=model.value("Jl"))

    def design(self) -> Any:
        from iiwa_ident.design import read_design

        return read_design(self.p["design"])


def _load_logs(ld: _Loader) -> None:
    """A folder of ``pipeline --logs``: the starting model the diagnosis began from, then the stages."""
    from iiwa_ident.diagnose import diagnose
    from iiwa_ident.ident import read_model

    out, p, want = ld.out, ld.p, ld.want
    if p["model_start"].is_file() and ld.usable("ripple"):
        ld.attempt("ripple", lambda: read_model(p["model_start"]), "model_start")
    if want & {"ripple"} and "model_start" in out and out["runs"]:
        ld.attempt("ripple", lambda: ld.ripple(out["runs"], out["model_start"]), "ripple")
    if want & {"diagnose"} and "model_start" in out and out["runs"] and ld.usable("diagnose"):
        ld.attempt("diagnose", lambda: diagnose(out["runs"], out["model_start"]), "diagnosis")
    chirps = [ds.path for ds in out["runs"] if ds.has("tau_c")]
    if want & {"fit"} and ld.usable("fit") and p["model"].is_file() and chirps:
        ld.attempt("fit", lambda: ld.fit(chirps, base_model=out.get("model_start")))
    if want & {"design"} and p["design"].is_file() and ld.usable("design"):
        ld.attempt("design", ld.design, "design")


def _load_experiments(ld: _Loader) -> None:
    """A folder of ``pipeline --target``: its recorded experiments, then the stages."""
    from iiwa_ident.datasets import read_dataset
    from iiwa_ident.diagnose import diagnose
    from iiwa_ident.ident import read_model

    out, p, want = ld.out, ld.p, ld.want
    for key, stage in (("chirp", "chirp"), ("cv", "constant_velocity"), ("qs", "constant_velocity"),
                       ("hand", "hand_guided")):
        if p[key].is_file() and ld.usable(stage):
            ld.attempt(stage, functools.partial(read_dataset, p[key]), key)
    if want & {"fit"} and "chirp" in out and ld.usable("fit"):
        ld.attempt("fit", lambda: ld.fit([p["chirp"]]))
    if p["model_ripple"].is_file() and ld.usable("ripple"):
        ld.attempt("ripple", lambda: read_model(p["model_ripple"]), "model_ripple")
    if want & {"ripple"} and "cv" in out and "model_ripple" in out:
        data = [out["cv"]] + ([out["qs"]] if "qs" in out else [])
        ld.attempt("ripple", lambda: ld.ripple(data, out["model_ripple"]), "ripple")
    if want & {"design", "validation"} and p["design"].is_file() and ld.usable("design"):
        ld.attempt("design", ld.design, "design")
    if want & {"validation"} and p["validation_json"].is_file() and ld.usable("validation"):
        ld.attempt("validation", lambda: json.loads(p["validation_json"].read_text()), "validation")
    if want & {"diagnose"} and "model_ripple" in out and ld.usable("diagnose"):
        keys = [k for k in ("chirp", "cv", "hand") if k in out]
        ld.attempt("diagnose", lambda: diagnose([out[k] for k in keys], out["model_ripple"]), "diagnosis")


# --------------------------------------------------------------------------- pages
_VERDICT_COLOUR = {"PASS": "#c8e6c9", "WARN": "#ffe0b2", "FAIL": "#ffcdd2", "SKIPPED": "#eeeeee"}


def _warnings(doc: dict[str, Any]) -> list[str]:
    """What the stages warned about, from ``pipeline.json`` (each once, its stage first)."""
    out: list[str] = []
    for s in doc.get("stages", []):
        h = s.get("headline") or {}
        said = list(h.get("warnings", [])) + list((h.get("refit") or {}).get("warnings", []))
        for r in h.get("runs", []) if s["name"] == "import" else []:
            said += [f"{r['run']}: {w}" for w in r.get("warnings", [])]
        for w in said:
            line = f"{s['name']}: {w}"
            if line not in out:
                out.append(line)
    return out


#: Lines of warnings page 1 holds.
_WARNING_LINES = 10

#: Pages shown as thumbnails on page 1, by title (those the report has).
_THUMBNAILS = ("Bode plot of tau_c -> tau_J", "Lookup tables (like Fig. 6)", "Step responses through FRI (like Fig. 8)",
               "kappa margin")


#: Resolution of page 1's thumbnails [dots per inch]: their axis labels readable when printed.
_THUMBNAIL_DPI = 90


def _thumbnail(page: Page) -> Any:
    """The page's figure as a small image (None when it cannot be drawn: its own page says why)."""
    import io

    try:
        fig = page.draw()
        if fig is None:
            return None
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=_THUMBNAIL_DPI)
        plt.close(fig)
        buf.seek(0)
        return plt.imread(buf)
    except Exception:  # noqa: BLE001  (a thumbnail must not cost page 1)
        plt.close("all")
        return None


def _verdict_page(doc: dict[str, Any], index: list[str], thumbs: Sequence[Page] = ()) -> Page:
    """Page 1: the banner, one verdict per stage (:mod:`iiwa_ident.report._verdict`), thumbnails of the key
    figures, the warnings, the pages."""
    def draw() -> plt.Figure:
        from iiwa_ident.report._verdict import verdict_rows

        rows = verdict_rows(doc)
        fig = plt.figure(figsize=(11.0, 8.5))
        head = banner(doc) or "no pipeline.json: no verdict"
        fig.text(0.04, 0.965, "iiwa-ident report", fontsize=16, weight="bold", va="top")
        fig.text(0.04, 0.925, textwrap.fill(head, 125), fontsize=10, weight="bold", va="top",
                 color="C3" if head.startswith("MEASURED") else "C0")
        n_rows = max(len(rows), 1)
        height = min(0.036 * (n_rows + 1), 0.5)
        ax = fig.add_axes((0.04, 0.89 - height, 0.92, height))
        ax.axis("off")
        cells = [[r.stage, textwrap.fill(r.figure, 78), textwrap.fill(r.reference, 42), r.verdict] for r in rows] or \
            [["-", "no stage has results", "-", "-"]]
        table = ax.table(cellText=cells, colLabels=["stage", "key figure", "reference", "verdict"],
                         colWidths=[0.11, 0.52, 0.29, 0.08], loc="upper left", cellLoc="left")
        table.auto_set_font_size(False)
        table.set_fontsize(8)
        row_lines = [1] + [max(c.count("\n") + 1 for c in row) for row in cells]  # per row, the header first
        unit = 1.0 / sum(1 + 0.6 * (n - 1) for n in row_lines)
        for (i, j), cell in table.get_celld().items():
            cell.set_height(unit * (1 + 0.6 * (row_lines[i] - 1)))
            if i == 0:
                cell.set_text_props(weight="bold")
            elif j == 3:
                cell.set_facecolor(_VERDICT_COLOUR.get(cells[i - 1][3], "white"))
                cell.set_text_props(weight="bold")
        y = 0.89 - height - 0.035
        images = [(p.title, im) for p in thumbs if (im := _thumbnail(p)) is not None]
        for k, (title, im) in enumerate(images):
            ax_t = fig.add_axes((0.04 + 0.235 * k, y - 0.21, 0.225, 0.21))
            ax_t.imshow(im)
            ax_t.set_axis_off()
            ax_t.set_title(f"p. {index.index(title) + 1}: {title}", fontsize=7)
        if images:
            y -= 0.24
        warn = _warnings(doc)
        fig.text(0.04, y, f"Warnings ({len(warn)})" if warn else "Warnings: none", fontsize=10, weight="bold",
                 va="top")
        # Whole warnings, wrapped, as many as the page holds; the rest counted.
        lines: list[str] = []
        shown = 0
        for w in warn:
            wrapped = textwrap.wrap(w, 175, subsequent_indent="    ")
            if len(lines) + len(wrapped) > _WARNING_LINES:
                break
            lines += wrapped
            shown += 1
        if shown < len(warn):
            lines.append(f"... and {len(warn) - shown} more (the stages' pages and JSON files)")
        fig.text(0.04, y - 0.025, "\n".join(lines), fontsize=7, va="top", family="sans-serif")
        y_index = y - 0.045 - 0.016 * len(lines)
        fig.text(0.04, y_index, "Pages", fontsize=10, weight="bold", va="top")
        col = (len(index) + 2) // 3
        for c in range(3):
            part = index[c * col:(c + 1) * col]
            fig.text(0.04 + 0.31 * c, y_index - 0.025,
                     "\n".join(f"{c * col + i + 1:3d}  {textwrap.shorten(t, 44, placeholder='...')}"
                                for i, t in enumerate(part)),
                     fontsize=7, va="top", family="monospace")
        return fig

    return Page("verdict", "Verdict", "", draw, captioned=False)


def _title_page(workdir: Path, doc: dict[str, Any] | None, stage: str | None) -> Page:
    def draw() -> plt.Figure:
        from iiwa_ident.pipeline import (
            FILES,
            PipelineResult,
            StageRecord,
            format_summary,
        )

        lines = []
        if doc is not None:
            inputs = doc.get("inputs", {})
            lines.append("Inputs")
            for k, v in inputs.items():
                lines.append(f"  {k}: {v}")
            lines.append("")
            recs = [StageRecord(name=s["name"], title=s.get("title", ""), status=s["status"],
                                duration_s=s.get("duration_s", 0.0), error=s.get("error", ""),
                                outputs=s.get("outputs", []), headline=s.get("headline", {}))
                    for s in doc.get("stages", [])]
            res = PipelineResult(workdir, recs, doc.get("headline", {}), None, doc.get("wall_s", 0.0))
            summary = format_summary(res).strip("\n")
            lines.extend(textwrap.fill(x, 150, subsequent_indent="    ") for x in summary.splitlines())
        else:
            lines.append("no pipeline.json in this folder: pages are built from the files present")
        lines.append("")
        lines.append("Files (sha256)")
        names = sorted(set(FILES.values()) - {FILES["report"], FILES["validation_dir"]})
        vdir = workdir / FILES["validation_dir"]
        files = [workdir / n for n in names if (workdir / n).is_file()]
        if vdir.is_dir():
            files += sorted(vdir.glob("*.h5"))
        if (workdir / FILES["runs_dir"]).is_dir():
            files += sorted((workdir / FILES["runs_dir"]).glob("*.h5"))
        for f in files:
            lines.append(f"  {str(f.relative_to(workdir)):<34} {_sha256(f)}")
        what = "the whole pipeline" if stage is None else f"stage '{stage}'"
        return _text_page(f"Appendix: inputs, stages and files of {what}", "\n".join(lines), mono=True)

    return Page("title", "Appendix: inputs, stages and files (sha256)", "Inputs with their sha256, the stages with status and duration, the "
                "headline figures and every file of the work folder with its sha256. Check the stage table first: "
                "a failed stage has its own page saying why.", draw, captioned=False)


def _failure_page(stage: str, status: str, message: str) -> Page:
    def draw() -> plt.Figure:
        body = textwrap.fill(message or "no message", 110)
        head = {"failed": f"Stage '{stage}' failed", "skipped": f"Stage '{stage}' was skipped"}.get(
            status, f"Stage '{stage}': no results ({status})")
        return _text_page(head, body + "\n\nNothing is drawn for this stage: its results do not exist.",
                          colour="C3")

    return Page(stage, f"{stage}: {status}", "This stage produced no results, so its figures are left out. "
                "Fix the cause named above and run the pipeline again.", draw, captioned=False)


def _fit_pages(r: dict[str, Any], doc: dict[str, Any] | None) -> list[Page]:
    from iiwa_ident.report._fit_figures import bode_figure, harmonics_figure
    from iiwa_ident.report._validation_figures import parameter_table_figure

    fit = r["fit"]

    def table() -> plt.Figure:
        headline = None
        if doc is not None:
            headline = next((s["headline"] for s in doc.get("stages", []) if s["name"] == "fit"), None)
        if not headline:
            headline = {"parameters": {k: {"value": fit.parameters[k], "std": fit.std[k],
                                           "rel_std_pct": 100 * fit.std[k] / abs(fit.parameters[k])}
                                       for k in fit.parameters}}
        corr = {"names": list(fit.parameters), "matrix": fit.correlation} if fit.correlation is not None else None
        return parameter_table_figure(headline, corr)

    return [
        Page("fit", "Bode plot of tau_c -> tau_J", "Measured frequency response (H1, with its 2-sigma band) against "
             "the fitted eq (4) with delay, and the coherence. Look for the fit inside the band up to the "
             "resonance and beyond, and for the coherence near 1 wherever the fit is judged.",
             lambda: bode_figure(fit)),
        Page("fit", "Harmonic distortion", "Harmonic impulse responses of the exponential sweep and the share of "
             "output power in harmonics per octave band. Look for small shares: the transmission ripple is the "
             "only nonlinearity and it adds little to a 10 Nm chirp.", lambda: harmonics_figure(fit)),
        Page("fit", "Fitted model against the chirp", f"{_compared_model(r)[1]} run on the chirp it was fitted "
             "to (as 'iiwa-ident compare' does): measured and predicted joint torque with the fit percentage, then "
             "the residual's autocorrelation and its cross-correlation with the torque command with their 99 % "
             "bounds. Look at the independence of the command: a residual that follows the command means the model "
             "misses part of the response; whiteness fails in closed loop even for a complete model.",
             lambda: _comparison(r)),
        Page("fit", "Parameter table", "The five parameters with their standard deviations (and, on the "
             "simulated joint, the error against the plant that was simulated, in % and in std), with the "
             "correlation of the estimates. Look for errors within 3 standard deviations" + _ripple_shift(doc)
             + "." + _log_filter_said(fit), table),
    ]


def _log_filter_said(fit: Any) -> str:
    """The fitted filter before the log, in words (empty without one)."""
    if getattr(fit, "log_filter", None) is None:
        return ""
    from iiwa_ident.ident import LOG_ONLY, log_filter_text

    return (f" The logged tau_J passed a filter, {log_filter_text(fit.log_filter)}, fitted with the parameters "
            f"(the Bode plot's model includes it); it acts on {LOG_ONLY}.")


def _ripple_shift(doc: dict[str, Any] | None) -> str:
    """What the ripple table changes in the fit (from pipeline.json: the fit and its refit with the table)."""
    fit = _stage_headline(doc, "fit")
    refit = ((_stage_headline(doc, "ripple") or {}).get("refit") or {}).get("parameters")
    if not fit or not refit:
        return ""
    first = fit["parameters"]
    moved = {k: 100 * (refit[k]["value"] / first[k]["value"] - 1) for k in ("K", "Jl") if k in refit and k in first}
    said = ", ".join(f"{k} by {v:+.2g} %" for k, v in moved.items())
    return f"; the fit with the ripple's table (ripple stage) moves {said}" if said else ""


def _compared_model(r: dict[str, Any]) -> tuple[Any, str]:
    """The model the fit's comparison page runs, and what it is in words.

    The fit estimates the ripple's harmonics alongside its parameters and leaves them out of its model file
    (the ripple stage identifies the table): run without them, the chirp's ripple stays in the residual, which
    then follows the command although the fit's own residual does not. Where the ripple stage wrote its
    model, that model (the fit's parameters refitted with the table) is the one the fit stands for.
    """
    ripple = r.get("model_ripple")
    if ripple is not None and ripple.ripple is not None:
        return ripple, ("model_ripple.toml (the joint's parameters refitted with the ripple stage's table, the "
                        "model every later stage uses)")
    model = r.get("model")
    if model is None:
        return None, "The fitted model"
    said = "model.toml (the fitted parameters"
    if model.ripple is None:
        said += "; it holds no ripple table, so the ripple the fit estimated alongside stays in this residual"
    return model, said + ")"


def _comparison(r: dict[str, Any]) -> plt.Figure:
    from iiwa_ident.diagnose import compare
    from iiwa_ident.report._diagnose_figures import comparison_figure

    rows = [c for c in compare([r["chirp"]], _compared_model(r)[0]) if c.channel == "command"]
    if not rows:
        raise IiwaIdentError("the chirp has no torque command to compare the model on")
    return comparison_figure(rows[0])


def _ripple_pages(r: dict[str, Any]) -> list[Page]:
    from iiwa_ident.report._ripple_figures import (
        lookup_table_figure,
        spatial_spectrum_figure,
        velocity_frequency_figure,
    )

    res = r["ripple"]
    methods = " and ".join(sorted(res.methods)) if res.detected else "none"
    return [
        Page("ripple", "Spatial spectrum", f"Consistency of the deflection's Fourier coefficients across passes "
             f"against the period. Look for one line at rho = {res.period_rad:.5f} rad (paper 0.01963 rad) "
             "standing far above a flat floor. Lines at rho/2, rho/3, ... are the deflection's higher harmonics "
             "(its shape is not a pure sine) and may stand taller than rho's own: they belong to the same family, "
             "whose fundamental is the period.", lambda: spatial_spectrum_figure(res)),
        Page("ripple", "Lookup tables (like Fig. 6)", f"The deflection folded modulo rho with the table of each "
             f"method ({methods}). Look for the methods agreeing: the table is what the position correction of "
             "eqs (8)-(9) subtracts.", lambda: lookup_table_figure(res)),
        Page("ripple", "Ripple frequency against speed, eq (6)", "Predicted |v|/rho against the measured peak of "
             "the torque spectrum per speed. Look for the points on the line: the ripple is periodic in "
             "position, not in time.", lambda: velocity_frequency_figure(res)),
    ]


def _design_pages(r: dict[str, Any]) -> list[Page]:
    import numpy as np

    from iiwa_ident.design import (
        builtin_poles,
        paper_reproduction,
        table1_parameters,
    )
    from iiwa_ident.report._control_figures import pole_figure
    from iiwa_ident.report._design_figures import observer_figure, reproduction_figure, spatial_filter_figure

    rec = r["design"]
    pages = []
    cv, model = r.get("cv"), r.get("model_ripple")
    if cv is not None:
        speeds = tuple(sorted({round(abs(float(v)), 3) for v in
                               np.atleast_1d(cv.experiment_attrs.get("velocity_rad_s", (0.3, 0.6, 1.2)))}))
        pages.append(Page("design", "Spatial filter at several speeds (like Fig. 4)", f"Joint torque before and "
                          f"after the spatial filter (beta = {rec.filter.beta:g}) at each speed, the spectra and the "
                          "filter's response. Look for the ripple line cut by tens of dB while slower torque "
                          "passes unchanged.",
                          lambda: spatial_filter_figure(cv, rec.filter, rec.ripple, speeds=speeds or (0.3, 0.6, 1.2))))
    hand = r.get("hand")
    if hand is not None and model is not None and hand.has("tau_ext_ref"):
        pages.append(Page("design", "External-torque observers (like Fig. 7)", "The built-in observer of eq (13), "
                          "the improved one on the link velocity of eq (9) and the spatially filtered one, against "
                          "the F/T reference during hand guiding. Look at the zoom on fast motion: the built-in "
                          "estimate carries the ripple, the improved ones do not.",
                          lambda: observer_figure(hand, model, rec.filter)))
    d = rec.design
    poles = {"poles": {"builtin": builtin_poles(d.params), "additive": np.asarray(d.poles),
                       "observer": np.asarray(d.observer_poles)}}
    pages.append(Page("design", "Pole map", "Continuous closed-loop poles of the built-in loop (eq (4)), the "
                      "additive feedback and its observer. Look for the lightly damped built-in pair near 23 Hz "
                      "moved to well-damped poles.", lambda: pole_figure(poles)))

    def reproduction() -> plt.Figure:
        t1, source = table1_parameters()
        return reproduction_figure(paper_reproduction(t1), source)

    pages.append(Page("design", "Paper reproduction table", "The paper's printed gains and matrices beside the "
                      "ones computed on Table I with the paper's poles, and with bc/Jc = 55 1/s. Look at the diff "
                      "columns: the explanations name every difference above rounding.", reproduction))
    return pages


def _validation_pages(r: dict[str, Any], workdir: Path) -> list[Page]:
    from iiwa_ident.pipeline import FILES
    from iiwa_ident.report._validation_figures import (
        kappa_margin_figure,
        tracking_run_figure,
    )

    v = r["validation"]
    folder = workdir / FILES["validation_dir"]
    return [
        Page("validation", "Step responses through FRI (like Fig. 8)", "Square-wave reference with the robot's "
             "own loop (left) and the deployed additive controller (right), run through the FRI runtime. Look "
             "at the overshoot after each edge: the built-in loop rings at its 23 Hz resonance.",
             lambda: tracking_run_figure(v, folder, "step")),
        Page("validation", "Sine responses through FRI (like Fig. 9)", "The fast sine with both controllers. "
             "Look at the zoom: the built-in loop amplifies near its resonance, the additive loop follows the "
             "reference delayed by Td.", lambda: tracking_run_figure(v, folder, "sine")),
        Page("validation", "kappa margin", "tau_r = kappa tau_ext with kappa raised stepwise through FRI until the "
             "run itself shows an instability, built-in loop and additive controller, a hand holding the arm. "
             "Left: each live margin (bar: last stable to first unstable kappa) beside the linear prediction of "
             "the loop as deployed (cross). Right: the joint torque through the kappa steps; the dashed line is "
             "the judged onset. Look at the ratio of the additive to the built-in margin (paper: 15 / 4.6).",
             lambda: kappa_margin_figure(v, folder)),
    ]


def _diagnose_pages(r: dict[str, Any]) -> list[Page]:
    from iiwa_ident.report import _diagnose_figures as df

    d = r["diagnosis"]
    changed = bool(d.effects or d.replaced)
    pages = [Page("diagnose", "Named effects and gains", "Held-out residual RMS before and after each named "
                  "effect, per effect and per dataset channel, with each channel's fit and residual tests (as "
                  "'compare' gives them, in-sample) before and after. Look at the gain column: an effect is named "
                  "only when it lowers the held-out residual by at least 3 % with 0.999 confidence"
                  + ("." if changed else "; nothing was named, so the residual pages are left out (before and "
                     "after would be the same)."), lambda: df.gain_table_figure(d))]
    for ctx in d.contexts if changed else ():
        for ch in ctx.channels:
            what = "link-side external-torque error" if ch == "link" else "joint-torque response to the command"
            pages.append(Page("diagnose", f"Residuals before and after: {ctx.name}"
                              f" / {ch}", f"Residual of the {what} with the model before and after the named effects. "
                              "Look for structure that disappears after: what is left should look like noise.",
                              functools.partial(df.residuals_figure, d, ctx.index, ch)))
    for e in d.effects:
        # What the effect means beyond its curve, as the summary says it: a filter acts on the log only, a load
        # against the description is a payload.
        said = [e.detail[k] for k in ("log_only", "against_description", "payload") if e.detail.get(k)]
        pages.append(Page("diagnose", f"Evidence for {e.name}", "Partial residual against the effect's variable "
                          "with the fitted effect. Look for the curve following the binned points."
                          + "".join(f" {x[0].upper()}{x[1:]}." for x in said),
                          functools.partial(df.evidence_figure, d, e.name)))
    return pages


def _runs_page(doc: dict[str, Any]) -> Page | None:
    imp = _stage_headline(doc, "import")
    if not imp:
        return None

    def draw() -> plt.Figure:
        lines = textwrap.wrap(f"robot {imp.get('robot_model')}, joint {imp.get('joint')}; torque sign "
                              f"{imp.get('torque_sign')}", _MONO_WIDTH) + [""]
        for r in imp["runs"]:
            speed = "-" if r.get("speed_rad_s") is None else f"{r['speed_rad_s']:.2f} rad/s"
            lines += textwrap.wrap(f"{r['run']}: {r['experiment']}, {r['samples']} samples at {r['rate_hz']:.4g} "
                                   f"Hz, speed {speed} ({r['source']})", _MONO_WIDTH, subsequent_indent="  ")
            for w in r.get("warnings", []):
                lines += textwrap.wrap(f"warning: {w}", _MONO_WIDTH, initial_indent="    ",
                                       subsequent_indent="      ")
            if not r.get("warnings"):
                lines.append("    no warning")
        return _text_page("Runs and what their logs say", "\n".join(lines), mono=True)

    return Page("import", "Runs and what their logs say", "Each imported run with its experiment, rate and "
                "speed, and what the checks of import found in it (samples lost, a torque filtered before it was "
                "logged, the torque's sign, a joint that did not move). Read the warnings first: they say what "
                "the data cannot give.", draw, captioned=False)


def _held_out_page(doc: dict[str, Any]) -> Page | None:
    held = _stage_headline(doc, "held_out")
    if not held or not held.get("runs"):
        return None
    rows = held["runs"]

    def draw() -> plt.Figure:
        import numpy as np

        from iiwa_ident.diagnose import verdict_text

        fig, ax = plt.subplots(figsize=(11, 6))
        x = np.arange(len(rows))
        before = [r["before_nm"] for r in rows]
        after = [r["after_nm"] for r in rows]
        ax.bar(x - 0.2, before, 0.4, label="starting model (the description at the logged pose)", color="0.6")
        ax.bar(x + 0.2, after, 0.4, label="extended by the diagnosis of the other runs", color="C0")
        for i, r in enumerate(rows):
            if r.get("ratio") is not None:
                fit = r.get("fit_pct", {}).get("link")
                tests = r.get("residual_tests_passed", {}).get("link")
                # A prediction worse than the run's mean does not model the run, whatever its residual's tests say.
                said = "not modelled (below 0 %)" if fit is not None and fit < 0 else f"tests {verdict_text(tests)}"
                extra = "" if fit is None else f"\nfit {fit:.0f} %, {said}"
                ax.annotate(f"{100 * r['ratio']:.0f} %{extra}", (i + 0.2, r["after_nm"]), ha="center", va="bottom",
                            fontsize=8)
        ax.set_xticks(x, [r["run"] for r in rows], rotation=15, ha="right", fontsize=8)
        ax.set_ylabel("held-out residual RMS [Nm]")
        ax.legend(loc="upper right", fontsize=9)
        fig.tight_layout()
        return fig

    return Page("held_out", "Each run predicted from the other runs", "Residual RMS of each run with the joint's "
                "starting model and with the model the diagnosis extended on the other runs only (above each bar: "
                "after as a share of before, the link channel's fit and whether its residual passes the tests of "
                "'compare'). Look for every run lower after: an effect named on some "
                "runs that does not predict another is a property of those runs, not of the joint.", draw)


def report_pages(workdir: Path, doc: dict[str, Any] | None, results: dict[str, Any],
                 stage: str | None = None) -> list[Page]:
    """The pages of the report, in order: the verdict (page 1, with a ``pipeline.json``), the runs and held-out
    pages of measured data, per stage its figures or a failure notice, and the appendix of inputs and files.

    Parameters
    ----------
    workdir : Path
        The work folder (run logs, files for the appendix).
    doc : dict or None
        ``pipeline.json`` content (stage status and messages).
    results : dict
        In-memory results (from the pipeline or :func:`load_results`).
    stage : str, optional
        Only this stage's pages (between the verdict and the appendix).
    """
    if stage is not None and stage not in REPORT_STAGES:
        raise IiwaIdentError(f"--stage {stage}: expected one of {', '.join(REPORT_STAGES)}")
    pages: list[Page] = []
    if stage is None and doc is not None and _measured(doc):
        pages += [p for p in (_runs_page(doc), _held_out_page(doc)) if p is not None]
    makers = {"fit": (("fit",), lambda: _fit_pages(results, doc)),
              "ripple": (("ripple",), lambda: _ripple_pages(results)),
              "design": (("design",), lambda: _design_pages(results)),
              "validation": (("validation",), lambda: _validation_pages(results, workdir)),
              "diagnose": (("diagnosis",), lambda: _diagnose_pages(results))}
    for name in REPORT_STAGES if stage is None else (stage,):
        keys, make = makers[name]
        status, message = _stage_status(doc, name)
        if status == "absent":
            continue  # a stage this pipeline does not have (--logs runs no validation)
        if status in ("failed", "skipped"):
            pages.append(_failure_page(name, status, message))
            continue
        missing = [k for k in keys if k not in results]
        if missing:
            why = results.get("load_errors", {}).get(name) or message or (
                f"its results ({', '.join(missing)}) are not in the work folder")
            pages.append(_failure_page(name, status if status not in ("ok", "unknown") else "missing", why))
            continue
        pages.extend(make())
    pages.append(_title_page(workdir, doc, stage))
    if doc is not None:
        # Page 1 indexes every page, itself included.
        pages.insert(0, _verdict_page(doc, ["Verdict"] + [p.title for p in pages],
                                      [p for p in pages if p.title in _THUMBNAILS]))
    return pages


def build_report(out: str | Path, workdir: str | Path, doc: dict[str, Any] | None = None,
                 results: dict[str, Any] | None = None, stage: str | None = None, dpi: int = 100,
                 png_dir: str | Path | None = None, png_dpi: int = 40) -> list[str]:
    """Write the PDF report; return the page titles.

    Parameters
    ----------
    out : path
        PDF file to write (atomically: a temporary file, then a rename).
    workdir : path
        The pipeline's work folder.
    doc : dict, optional
        ``pipeline.json`` content (read from ``workdir`` when None).
    results : dict, optional
        In-memory results; read from the work folder's files (:func:`load_results`) when None.
    stage : str, optional
        Only this stage (see :data:`REPORT_STAGES`).
    dpi : int
        Resolution of raster elements in the PDF [dots per inch].
    png_dir : path, optional
        Also save every page as ``page_NN.png`` here (for checking the pages).
    png_dpi : int
        Resolution of those PNGs [dots per inch].

    Raises
    ------
    IiwaIdentError
        If the folder does not exist or the PDF cannot be written.
    """
    from iiwa_ident.pipeline import read_pipeline_json

    workdir = Path(workdir)
    out = Path(out)
    if not workdir.is_dir():
        raise IiwaIdentError(f"{workdir}: no such folder")
    if stage is not None and stage not in REPORT_STAGES:
        raise IiwaIdentError(f"--stage {stage}: expected one of {', '.join(REPORT_STAGES)}")
    if doc is None:
        doc = read_pipeline_json(workdir)
    if doc is None and not any((workdir / name).exists() for name in _RESULT_FILES):
        raise IiwaIdentError(f"{workdir}: no pipeline results (no pipeline.json and none of "
                             f"{', '.join(_RESULT_FILES)}): run 'iiwa-ident pipeline' into it first")
    head = banner(doc)
    if results is None:
        from iiwa_ident._blas import single_threaded_blas

        with single_threaded_blas():
            results = load_results(workdir, doc, REPORT_STAGES if stage is None else (stage,))
    pages = report_pages(workdir, doc, results, stage)
    if png_dir is not None:
        Path(png_dir).mkdir(parents=True, exist_ok=True)
    titles: list[str] = []
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with PdfPages(tmp) as pdf:
            for i, page in enumerate(pages, 1):
                try:
                    fig = page.draw()
                    if fig is None:
                        raise IiwaIdentError("nothing to draw for this page")
                    fig = _captioned(fig, page.title, page.caption) if page.captioned else _on_page(fig)
                    title = page.title
                    _rasterize_dense(fig)
                    if head:
                        fig.text(0.5, 0.998, textwrap.fill(head, 160), ha="center", va="top", fontsize=8, weight="bold",
                                 color="C3" if head.startswith("MEASURED") else "C0")
                    fig.text(0.99, 0.003, f"page {i} of {len(pages)}", ha="right", va="bottom", fontsize=7)
                except Exception as err:  # noqa: BLE001  (one bad page must not cost the others)
                    plt.close("all")
                    fig = _text_page(f"{page.title}: this page could not be drawn",
                                     textwrap.fill(f"{type(err).__name__}: {err}", 110), colour="C3")
                    title = f"{page.title} (not drawn: {err})"
                pdf.savefig(fig, dpi=dpi)
                if png_dir is not None:
                    fig.savefig(Path(png_dir) / f"page_{i:02d}.png", dpi=png_dpi)
                plt.close(fig)
                titles.append(title)
            info = pdf.infodict()
            info["Title"] = "iiwa-ident report"
        tmp.replace(out)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise IiwaIdentError(f"{out}: cannot write ({err.strerror or err})") from None
    return titles
