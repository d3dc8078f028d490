"""Reading and writing the toolkit's TOML files (plants, models, designs, configs).

Python 3.11 reads TOML (``tomllib``) but does not write it; the files here
hold only tables, numbers, booleans, strings and (nested) lists of numbers,
so a small writer covers them without another dependency.
"""

from __future__ import annotations

import math
import os
import tempfile
import tomllib
from pathlib import Path
from typing import Any

from iiwa_ident.errors import IiwaIdentError

__all__ = ["load_toml", "dumps_toml", "write_atomic"]


def load_toml(path: str | os.PathLike, error: type[IiwaIdentError] = IiwaIdentError) -> dict[str, Any]:
    """Read a TOML file; a missing or malformed file raises ``error`` naming it."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory, not a TOML file") from None
    except tomllib.TOMLDecodeError as err:
        raise error(f"{path}: not valid TOML ({err})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a text file") from None


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if hasattr(v, "tolist"):  # numpy scalars and arrays
        return _value(v.tolist())
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _key(k: str) -> str:
    return k if k and k.replace("_", "").replace("-", "").isalnum() else _value(k)


def _is_scalar(v: Any) -> bool:
    return not isinstance(v, (dict, list, tuple)) and not hasattr(v, "tolist") or hasattr(v, "ndim") and v.ndim == 0


def _inline(d: dict) -> str:
    return "{ " + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in d.items() if v is not None) + " }"


def _is_table_list(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and bool(v) and all(isinstance(x, dict) for x in v)


def _body(data: dict[str, Any], inline: bool = True) -> list[str]:
    """Key-value lines of one table; all-scalar sub-tables are written inline if ``inline``."""
    lines = []
    for k, v in data.items():
        if v is None or _is_table_list(v):
            continue
        if isinstance(v, dict):
            if inline and v and all(_is_scalar(x) for x in v.values()):
                lines.append(f"{_key(k)} = {_inline(v)}")
            continue
        lines.append(f"{_key(k)} = {_value(v)}")
    return lines


def dumps_toml(data: dict[str, Any], _prefix: str = "") -> str:
    """Serialise nested dicts to TOML text.

    Plain keys first, then sub-tables (``[a.b]``), with small all-scalar
    tables inside a table written inline, and lists of dicts as arrays of
    tables (``[[name]]``).
    """
    blocks: list[str] = []
    body = _body(data, inline=bool(_prefix))
    if body:
        blocks.append("\n".join(body))
    for k, v in data.items():
        name = f"{_prefix}.{_key(k)}" if _prefix else _key(k)
        if isinstance(v, dict) and not (v and all(_is_scalar(x) for x in v.values()) and _prefix):
            inner = dumps_toml(v, name).strip()
            has_body = bool(_body(v, inline=True)) or not v
            header = f"[{name}]" if has_body else ""
            blocks.append("\n".join(x for x in (header, inner) if x))
        elif _is_table_list(v):
            for item in v:
                blocks.append(f"[[{name}]]\n" + "\n".join(_body(item)))
    return "\n\n".join(b for b in blocks if b).strip() + "\n"


def _umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_atomic(path: str | os.PathLike, text: str | bytes) -> Path:
    """Write ``text`` to ``path`` through a temporary file and a rename (mode ``0666`` less the umask)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = text.encode() if isinstance(text, str) else text
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        # mkstemp makes the file private (0600); the written file gets the mode any file of this user gets,
        # so that another account on the lab PC can read a controller.toml as it reads the datasets.
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
