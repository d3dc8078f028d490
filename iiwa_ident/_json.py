"""JSON output helpers shared by the library's summaries and the CLI."""

from __future__ import annotations

import math

__all__ = ["finite_or_none"]


def finite_or_none(x: float) -> float | None:
    """A number for JSON output: inf and NaN become null."""
    return float(x) if math.isfinite(x) else None
