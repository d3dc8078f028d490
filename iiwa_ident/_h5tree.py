"""Trees of the package's result dataclasses in an HDF5 file: what a stage computed, read back without running it.

A tree is a dict of str keys whose values are numbers, strings, None, lists, tuples, sets, dicts, numpy arrays
and dataclass instances of these. Its shape is stored as JSON (``/structure``), each array as its own HDF5
dataset (``/arrays/aN``), so arrays keep their dtype and the file holds no code: reading constructs only
dataclasses defined in the packages the caller names, through their fields.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident.errors import IiwaIdentError

__all__ = ["write_tree", "read_tree"]

_FORMAT = "iiwa-ident result tree 1"


class _Encoder:
    def __init__(self) -> None:
        self.arrays: list[np.ndarray] = []

    def __call__(self, x: Any) -> Any:
        if x is None or isinstance(x, (bool, str)):
            return x
        if isinstance(x, (int, np.integer)) and not isinstance(x, np.bool_):
            return int(x)
        if isinstance(x, np.bool_):
            return bool(x)
        if isinstance(x, (float, np.floating)):
            # JSON has no inf or NaN: spelled out.
            return float(x) if math.isfinite(x) else {"$float": repr(float(x))}
        if isinstance(x, (complex, np.complexfloating)):
            return {"$complex": [self(x.real), self(x.imag)]}
        if isinstance(x, np.ndarray):
            if x.dtype.kind not in "biufc":
                raise TypeError(f"an array of {x.dtype} cannot be stored (numbers only)")
            self.arrays.append(x)
            return {"$array": len(self.arrays) - 1}
        if isinstance(x, list):
            return [self(v) for v in x]
        if isinstance(x, tuple):
            return {"$tuple": [self(v) for v in x]}
        if isinstance(x, (set, frozenset)):
            return {"$set": [self(v) for v in x], "frozen": isinstance(x, frozenset)}
        if isinstance(x, dict):
            return {"$dict": [[self(k), self(v)] for k, v in x.items()]}
        if dataclasses.is_dataclass(x) and not isinstance(x, type):
            cls = type(x)
            return {"$dataclass": f"{cls.__module__}:{cls.__qualname__}",
                    "fields": {f.name: self(getattr(x, f.name)) for f in dataclasses.fields(x)}}
        raise TypeError(f"a {type(x).__name__} cannot be stored")


def write_tree(path: str | Path, tree: dict[str, Any]) -> None:
    """Write ``tree`` to the HDF5 file ``path`` (atomically: a temporary file, then a rename).

    Raises
    ------
    TypeError
        If the tree holds something other than numbers, strings, None, lists, tuples, sets, dicts, numeric arrays
        and dataclasses of these.
    """
    import h5py

    encode = _Encoder()
    structure = json.dumps(encode(tree))
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = _FORMAT
            f.create_dataset("structure", data=np.frombuffer(structure.encode(), dtype=np.uint8))
            arrays = f.create_group("arrays")
            for i, a in enumerate(encode.arrays):
                arrays.create_dataset(f"a{i}", data=a, **({"compression": "gzip", "shuffle": True} if a.size > 4096 else {}))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _dataclass(name: str, packages: tuple[str, ...]) -> type:
    module, _, qualname = name.partition(":")
    if not any(module == p or module.startswith(p + ".") for p in packages):
        raise ValueError(f"{name}: not a result of {', '.join(packages)}")
    try:
        obj: Any = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        # Written by another version of the package, whose modules or classes were named otherwise.
        raise ValueError(f"{name}: no such class in this version of {module.partition('.')[0]}") from None
    if not (isinstance(obj, type) and dataclasses.is_dataclass(obj)):
        raise ValueError(f"{name}: not a dataclass")
    return obj


def read_tree(path: str | Path, packages: Iterable[str]) -> dict[str, Any]:
    """Read a tree written by :func:`write_tree`.

    Parameters
    ----------
    path : path
        The HDF5 file.
    packages : iterable of str
        Packages (``"iiwa_ident.ident"``) whose dataclasses the tree may hold; any other is refused.

    Raises
    ------
    IiwaIdentError
        If the file is missing, not such a tree, or names a class outside ``packages``.
    """
    import h5py

    path = Path(path)
    packages = tuple(packages)
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != _FORMAT:
                raise ValueError(f"not a result tree (format {f.attrs.get('format')!r})")
            structure = json.loads(bytes(f["structure"][()]).decode())
            arrays = [f["arrays"][f"a{i}"][()] for i in range(len(f["arrays"]))]
    except (OSError, KeyError, ValueError) as err:
        raise IiwaIdentError(f"{path}: {err}") from None

    def decode(x: Any) -> Any:
        if isinstance(x, list):
            return [decode(v) for v in x]
        if not isinstance(x, dict):
            return x
        if "$float" in x:
            return float(x["$float"])
        if "$complex" in x:
            return complex(decode(x["$complex"][0]), decode(x["$complex"][1]))
        if "$array" in x:
            return np.asarray(arrays[x["$array"]])
        if "$tuple" in x:
            return tuple(decode(v) for v in x["$tuple"])
        if "$set" in x:
            items = (_hashable(decode(v)) for v in x["$set"])
            return frozenset(items) if x["frozen"] else set(items)
        if "$dict" in x:
            return {_hashable(decode(k)): decode(v) for k, v in x["$dict"]}
        cls = _dataclass(x["$dataclass"], packages)
        values = {k: decode(v) for k, v in x["fields"].items()}
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = set(values) - set(fields)
        if unknown:
            raise ValueError(f"{x['$dataclass']}: no field {', '.join(sorted(unknown))}")
        obj = cls(**{k: v for k, v in values.items() if fields[k].init})
        for k, v in values.items():
            if not fields[k].init:
                object.__setattr__(obj, k, v)
        return obj

    try:
        tree = decode(structure)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError, ImportError) as err:
        raise IiwaIdentError(f"{path}: {err}") from None
    if not isinstance(tree, dict):
        raise IiwaIdentError(f"{path}: not a result tree")
    return tree


def _hashable(key: Any) -> Any:
    return tuple(_hashable(k) for k in key) if isinstance(key, list) else key
