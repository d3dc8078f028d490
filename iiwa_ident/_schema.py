"""Typed, validated access to a parsed TOML mapping (design files, controller configs).

Every error names the file and the dotted key, as one line, as the file
formats require.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from iiwa_ident.errors import IiwaIdentError

__all__ = ["TableReader", "check_format"]


def check_format(data: dict[str, Any], where: str, name: str, version: int, error: type[IiwaIdentError],
                 required: bool = True) -> None:
    """Refuse a file whose ``format`` is not ``name`` or whose ``format_version`` is not ``version``.

    ``required=False`` accepts a file that states neither (a hand-written plant file, say).
    """
    fmt = data.get("format", None if required else name)
    if fmt != name:
        raise error(f"{where}format: expected {name!r}, got {data.get('format')!r}")
    got = data.get("format_version", None if required else version)
    if got != version:
        raise error(f"{where}format_version: unsupported version {data.get('format_version')!r} "
                    f"(this tool reads {version})")


class TableReader:
    """Read keys like ``"gains.K_fsf"`` from ``data``; subclasses set :attr:`error`.

    Parameters
    ----------
    data : dict
        The parsed file.
    where : str
        Prefix of every message, normally ``"path: "``.
    """

    #: Exception class raised for a bad key.
    error: ClassVar[type[IiwaIdentError]] = IiwaIdentError

    def __init__(self, data: dict[str, Any], where: str) -> None:
        self.data, self.where = data, where

    def fail(self, key: str, msg: str) -> IiwaIdentError:
        return self.error(f"{self.where}{key}: {msg}")

    def check_format(self, name: str, version: int) -> None:
        """:func:`check_format` of the whole mapping."""
        check_format(self.data, self.where, name, version, self.error)

    def get(self, key: str, required: bool = True) -> Any:
        node: Any = self.data
        parts = key.split(".")
        for i, part in enumerate(parts):
            if not isinstance(node, dict):
                raise self.fail(".".join(parts[:i]), "expected a table")
            if part not in node:
                if required:
                    raise self.fail(key, "missing")
                return None
            node = node[part]
        return node

    def table(self, key: str, required: bool = True) -> dict[str, Any] | None:
        t = self.get(key, required)
        if t is None:
            return None
        if not isinstance(t, dict):
            raise self.fail(key, "expected a table")
        return t

    def string(self, key: str) -> str:
        v = self.get(key)
        if not isinstance(v, str):
            raise self.fail(key, f"expected a string, got {v!r}")
        return v

    def integer(self, key: str) -> int:
        v = self.get(key)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(key, f"expected an integer, got {v!r}")
        return v

    def number(self, key: str, positive: bool = False, nonneg: bool = False, allow_inf: bool = False) -> float:
        v = self.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(key, f"expected a number, got {v!r}")
        v = float(v)
        if math.isnan(v) or (math.isinf(v) and not allow_inf):
            raise self.fail(key, f"must be finite, got {v}")
        if positive and not v > 0:
            raise self.fail(key, f"must be positive, got {v:g}")
        if nonneg and v < 0:
            raise self.fail(key, f"must not be negative, got {v:g}")
        return v

    def array(self, key: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
        v = self.get(key)
        if not isinstance(v, list):
            raise self.fail(key, "expected an array of numbers")
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            raise self.fail(key, "expected an array of numbers") from None
        if shape is not None and a.shape != shape:
            want = "x".join(str(n) for n in shape)
            raise self.fail(key, f"expected shape {want}, got {'x'.join(str(n) for n in a.shape) or 'scalar'}")
        if not np.all(np.isfinite(a)):
            raise self.fail(key, "entries must be finite")
        return a

    def square(self, key: str) -> np.ndarray:
        a = self.array(key)
        if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] == 0:
            raise self.fail(key, "expected a non-empty square matrix")
        return a

    def poles(self, key: str, n: int) -> np.ndarray:
        a = self.array(key)
        if a.shape != (n, 2):
            raise self.fail(key, f"expected {n} [re, im] pairs")
        return a[:, 0] + 1j * a[:, 1]

    def sha(self, key: str) -> str:
        s = self.string(key)
        if len(s) != 64 or any(c not in "0123456789abcdef" for c in s):
            raise self.fail(key, "expected 64 lower-case hex digits")
        return s
