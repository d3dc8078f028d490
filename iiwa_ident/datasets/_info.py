"""Summaries of a dataset for people (a table) and for scripts (a JSON-ready dict)."""

from __future__ import annotations

from typing import Any

import numpy as np

from iiwa_ident.datasets._format import ROBOT_NAME_ATTR, SIGNAL_UNITS, Dataset, robot_name
from iiwa_ident.datasets._provenance import IMPORT_WARNINGS_ATTR, dataset_warnings

__all__ = ["dataset_info", "format_info"]


def _jsonable(value: Any) -> Any:
    """Turn numpy scalars and arrays into plain Python values for JSON."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def dataset_info(ds: Dataset) -> dict[str, Any]:
    """Describe a dataset: metadata and per-signal statistics.

    Parameters
    ----------
    ds : Dataset
        A validated dataset (e.g. from :func:`read_dataset`).

    Returns
    -------
    dict
        JSON-serialisable dict with keys ``path`` (str or None),
        ``experiment``, ``source``, ``joint``, ``sample_rate_hz`` [Hz],
        ``n_samples``, ``duration_s`` [s], ``created_utc``,
        ``experiment_attrs``, ``warnings`` (e.g. the joint did not move while another did) and
        ``signals``; the latter maps each signal name
        to ``unit``, ``min``, ``max``, ``mean`` and ``std`` (population
        standard deviation), all in the signal's unit.
    """
    signals: dict[str, dict[str, Any]] = {}
    for name, values in ds.signals.items():
        arr = np.asarray(values, dtype=np.float64)
        signals[name] = {
            "unit": SIGNAL_UNITS.get(name, "?"),
            "min": float(arr.min()),
            "max": float(arr.max()),
            "mean": float(arr.mean()),
            "std": float(arr.std()),
        }
    return {
        "path": None if ds.path is None else str(ds.path),
        "robot": robot_name(ds),
        "experiment": ds.experiment,
        "source": ds.source,
        "joint": int(ds.joint),
        "sample_rate_hz": float(ds.sample_rate_hz),
        "n_samples": ds.n_samples,
        "duration_s": ds.duration_s,
        "created_utc": ds.created_utc,
        "experiment_attrs": {k: _jsonable(v) for k, v in ds.experiment_attrs.items()},
        "signals": signals,
        "warnings": dataset_warnings(ds),
    }


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list):
        shown = ", ".join(_fmt(v) for v in value[:6])
        more = f", ... ({len(value)} values)" if len(value) > 6 else ""
        return f"[{shown}{more}]"
    return str(value)


def format_info(info: dict[str, Any]) -> str:
    """Render the output of :func:`dataset_info` as a readable text table.

    Parameters
    ----------
    info : dict
        As returned by :func:`dataset_info`.

    Returns
    -------
    str
        Several lines, without a trailing newline.
    """
    lines: list[str] = []
    if info.get("path"):
        lines.append(f"file          {info['path']}")
    if info.get("robot"):
        lines.append(f"robot         {info['robot']}")
    lines += [
        f"experiment    {info['experiment']}",
        f"source        {info['source']}",
        f"joint         {info['joint']}",
        f"sample rate   {_fmt(info['sample_rate_hz'])} Hz",
        f"samples       {info['n_samples']}",
        f"duration      {info['duration_s']:.3f} s",
        f"created (UTC) {info['created_utc']}",
    ]
    # What import found is printed with the warnings below.
    attrs = {k: v for k, v in (info.get("experiment_attrs") or {}).items()
             if k not in (IMPORT_WARNINGS_ATTR, ROBOT_NAME_ATTR)}
    if attrs:
        lines.append("experiment attributes:")
        width = max(len(k) for k in attrs)
        lines += [f"  {k:<{width}}  {_fmt(v)}" for k, v in attrs.items()]

    header = ("signal", "unit", "min", "max", "mean", "std")
    rows = [
        (name, s["unit"], *(f"{s[key]:.6g}" for key in ("min", "max", "mean", "std")))
        for name, s in info["signals"].items()
    ]
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    lines.append("")
    for i, row in enumerate([header, *rows]):
        # Names left-aligned, numbers right-aligned so decimal places line up roughly.
        cells = [
            f"{cell:<{w}}" if col < 2 else f"{cell:>{w}}"
            for col, (cell, w) in enumerate(zip(row, widths))
        ]
        lines.append("  ".join(cells).rstrip())
        if i == 0:
            lines.append("  ".join("-" * w for w in widths))
    lines += [f"warning: {w}" for w in info.get("warnings", [])]
    return "\n".join(lines)
