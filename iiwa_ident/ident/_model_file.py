"""Reading and writing the joint model file (TOML, format version 1), read by every command after ``fit``.

The file's layout and its types are those of :mod:`iiwa_ident.model`
(:class:`~iiwa_ident.model.JointModel`; its docstring shows the file). Here a
file is validated key by key (the ``[[effects]]`` with the simulator's own
effect classes, which is why the reader lives above the simulator) and
written atomically.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident._schema import check_format
from iiwa_ident._toml import dumps_toml, load_toml, write_atomic
from iiwa_ident.model import (
    MODEL_FORMAT,
    MODEL_FORMAT_VERSION,
    PARAMETER_ORIGINS,
    PARAMETER_UNITS,
    JointModel,
    ModelError,
    Parameter,
    RippleTable,
    Source,
)

__all__ = ["read_model", "write_model", "model_from_dict"]

#: Parameters that must be positive.
_POSITIVE = ("Jc", "K", "Jl", "KI")


#: The keys of a parameter's entry.
_PARAMETER_KEYS = ("value", "std", "unit", "origin")


def _known_keys(table: dict[str, Any], known: tuple[str, ...], where: str) -> None:
    """Refuse a key the format does not have (a misspelt ``sdt`` would be dropped without a word)."""
    for key in table:
        if key not in known:
            raise ModelError(f"{where}.{key}: unknown key (known: {', '.join(known)})")


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ModelError(f"{where}: expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ModelError(f"{where}: must be finite, got {value}")
    return value


def model_from_dict(data: dict[str, Any], where: str = "") -> JointModel:
    """Validate a model-file mapping and build the :class:`JointModel`; errors name ``where`` and the key.

    Examples
    --------
    >>> from iiwa_ident.model import table1_model
    >>> data = table1_model().to_dict()
    >>> data["parameters"]["K"]["value"] = -1.0
    >>> model_from_dict(data, "m.toml: ")
    Traceback (most recent call last):
    ...
    iiwa_ident.model._joint_model.ModelError: m.toml: parameters.K.value: must be positive, got -1
    """
    check_format(data, where, MODEL_FORMAT, MODEL_FORMAT_VERSION, ModelError)
    known = {"format", "format_version", "tool_version", "created_utc", "joint", "robot_model", "description",
             "parameters", "correlation", "ripple", "fit", "sources", "effects", "pose_rad"}
    for key in data:
        if key not in known:
            raise ModelError(f"{where}{key}: unknown key")
    raw = data.get("parameters")
    if not isinstance(raw, dict):
        raise ModelError(f"{where}parameters: missing table")
    params: dict[str, Parameter] = {}
    for name in PARAMETER_UNITS:
        if name not in raw:
            raise ModelError(f"{where}parameters.{name}: missing")
    for name, entry in raw.items():
        if not isinstance(entry, dict) or "value" not in entry:
            raise ModelError(f"{where}parameters.{name}: expected {{ value = ..., std = ..., unit = ... }}")
        _known_keys(entry, _PARAMETER_KEYS, f"{where}parameters.{name}")
        value = _number(f"{where}parameters.{name}.value", entry["value"])
        std = entry.get("std")
        if std is not None:
            std = _number(f"{where}parameters.{name}.std", std)
            if std < 0:
                raise ModelError(f"{where}parameters.{name}.std: must not be negative")
        if name in _POSITIVE and value <= 0:
            raise ModelError(f"{where}parameters.{name}.value: must be positive, got {value:g}")
        if name in ("bc", "Td") and value < 0:
            raise ModelError(f"{where}parameters.{name}.value: must not be negative, got {value:g}")
        unit = entry.get("unit", PARAMETER_UNITS.get(name, ""))
        if name in PARAMETER_UNITS and unit != PARAMETER_UNITS[name]:
            raise ModelError(f"{where}parameters.{name}.unit: expected {PARAMETER_UNITS[name]!r}, got {unit!r}")
        origin = entry.get("origin")
        if origin is not None and origin not in PARAMETER_ORIGINS:
            raise ModelError(f"{where}parameters.{name}.origin: expected one of {', '.join(PARAMETER_ORIGINS)}, "
                             f"got {origin!r}")
        params[name] = Parameter(value, std, unit, origin)

    names, corr = [], None
    if "correlation" in data:
        c = data["correlation"]
        if not isinstance(c, dict):
            raise ModelError(f"{where}correlation: expected a table of names and matrix")
        _known_keys(c, ("names", "matrix"), f"{where}correlation")
        names = list(c.get("names", []))
        try:
            corr = np.asarray(c.get("matrix"), dtype=float)
        except (TypeError, ValueError):
            raise ModelError(f"{where}correlation.matrix: expected a square table of numbers") from None
        n = len(names)
        if corr.shape != (n, n) or any(nm not in params for nm in names):
            raise ModelError(f"{where}correlation: names and a {n}x{n} matrix of known parameters expected")
        if not np.all(np.isfinite(corr)) or np.abs(corr).max() > 1 + 1e-9 or not np.allclose(corr, corr.T, atol=1e-9):
            raise ModelError(f"{where}correlation.matrix: must be symmetric with entries in [-1, 1]")

    ripple = RippleTable.from_mapping(data["ripple"], f"{where}ripple") if "ripple" in data else None

    sources = []
    for i, s in enumerate(data.get("sources", [])):
        if not isinstance(s, dict) or "file" not in s or "sha256" not in s:
            raise ModelError(f"{where}sources[{i}]: expected file and sha256")
        _known_keys(s, ("file", "sha256", "role"), f"{where}sources[{i}]")
        sources.append(Source(str(s["file"]), str(s["sha256"]), str(s.get("role", "fit"))))
    effects = _effects(data.get("effects", []), where)
    joint = data.get("joint")
    if joint is not None and (isinstance(joint, bool) or not isinstance(joint, int) or not 1 <= joint <= 7):
        raise ModelError(f"{where}joint: expected an integer 1..7")
    pose = data.get("pose_rad")
    if pose is not None:
        if not isinstance(pose, list) or len(pose) != 7:
            raise ModelError(f"{where}pose_rad: expected the 7 joint positions [rad]")
        pose = [_number(f"{where}pose_rad[{i}]", v) for i, v in enumerate(pose)]
    return JointModel(parameters=params, correlation_names=names, correlation=corr, ripple=ripple,
                      fit=dict(data.get("fit", {})), sources=sources, effects=effects, joint=joint,
                      robot_model=data.get("robot_model"), description=str(data.get("description", "")),
                      pose_rad=pose,
                      tool_version=str(data.get("tool_version", "")), created_utc=str(data.get("created_utc", "")))


def _effects(raw: Any, where: str) -> list[dict[str, Any]]:
    """Validate ``[[effects]]`` tables with the simulator's own effect classes."""
    from iiwa_ident.errors import PlantError
    from iiwa_ident.sim import make_effect

    if not isinstance(raw, list):
        raise ModelError(f"{where}effects: expected a list of [[effects]] tables")
    out, seen = [], set()
    for i, entry in enumerate(raw):
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise ModelError(f"{where}effects[{i}]: expected a table with a name")
        name = entry["name"]
        if name in seen:
            raise ModelError(f"{where}effects[{i}]: effect {name!r} given twice")
        seen.add(name)
        try:
            make_effect(name, {k: v for k, v in entry.items() if k != "name"}, f"{where}effects[{i}].{name}")
        except PlantError as err:  # re-raised as a model-file error, message unchanged
            raise ModelError(str(err)) from None
        out.append(dict(entry))
    return out


def read_model(path: str | os.PathLike) -> JointModel:
    """Read and validate a model file; errors name the file and the key."""
    return model_from_dict(load_toml(path, ModelError), where=f"{path}: ")


def write_model(path: str | os.PathLike, model: JointModel) -> Path:
    """Write ``model`` atomically (validated by reading back what is written).

    Examples
    --------
    >>> import tempfile
    >>> from iiwa_ident.model import table1_model
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = write_model(Path(tmp) / "model.toml", table1_model())
    ...     read_model(path).value("K")
    18500.0
    """
    data = model.to_dict()
    text = dumps_toml(data)
    import tomllib

    model_from_dict(tomllib.loads(text), where=f"{path}: ")
    return write_atomic(path, text)
