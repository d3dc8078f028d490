"""The joint model file: TOML, format version 1, read by every command after ``fit``.

::

    format = "iiwa-ident-model"
    format_version = 1
    tool_version = "0.1.0"
    created_utc = "2026-11-21T05:00:00+00:00"
    joint = 1
    robot_model = "iiwa14"
    description = "..."

    pose_rad = [0.0, ...]        # optional: the 7 joint positions the model holds at (the others')

    [parameters]                 # SI units; std absent = not estimated; origin optional:
                                 # "measured", "description" (the rigid-body description) or "borrowed"
    Jc = { value = 1.03, std = 0.004, unit = "kg m^2" }
    bc = { value = 55.0, std = 0.3, unit = "Nm s/rad" }
    K  = { value = 18500.0, std = 40.0, unit = "Nm/rad" }
    Jl = { value = 5.6, std = 0.01, unit = "kg m^2" }
    Td = { value = 0.005, std = 1e-5, unit = "s" }
    KI = { value = 25.0, unit = "rad/s" }

    [correlation]                # of the estimated parameters
    names = ["Jc", "bc", "K", "Jl", "Td"]
    matrix = [[1.0, ...], ...]

    [ripple]                     # transmission nonlinearity, eq (5)
    period_rad = 0.01963
    lut = [...]                  # f(x_i) [rad] at x_i = i * period_rad / len(lut)
    ...

    [fit]                        # diagnostics of the fit (free-form numbers and strings)

    [[effects]]                  # optional extra plant effects (``diagnose``), plant-effect vocabulary
    name = "link_friction"       # of iiwa_ident/sim/effects.py; validated on read
    coulomb_nm = 1.2
    viscous_nms_rad = 0.8

    [[sources]]                  # what the model was identified from
    file = "chirp.h5"
    sha256 = "..."
    role = "fit"
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident import tool_version
from iiwa_ident._toml import dumps_toml, load_toml, write_atomic
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model import JOINT_PARAMETERS, OBSERVER_GAIN, PARAMETER_UNITS, RIPPLE_PERIOD_RAD

__all__ = [
    "ModelError",
    "Parameter",
    "RippleTable",
    "ripple_period",
    "Source",
    "JointModel",
    "read_model",
    "write_model",
    "model_from_dict",
    "table1_model",
    "PARAMETER_ORIGINS",
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
]

MODEL_FORMAT = "iiwa-ident-model"
MODEL_FORMAT_VERSION = 1

#: Parameters every model has, with their SI units.
_POSITIVE = ("Jc", "K", "Jl", "KI")


class ModelError(IiwaIdentError):
    """A model file is missing, unreadable or invalid."""


#: Where a parameter's value comes from, when a model file says so.
PARAMETER_ORIGINS = ("measured", "description", "borrowed")


@dataclass
class Parameter:
    """A model parameter: value, standard deviation (None: not estimated), unit, and where the value comes
    from (:data:`PARAMETER_ORIGINS`; None: not stated)."""

    value: float
    std: float | None = None
    unit: str = ""
    origin: str | None = None


@dataclass
class RippleTable:
    """Transmission deflection f(theta_m mod rho) of eq (5) as a lookup table.

    Attributes
    ----------
    period_rad : float
        Period rho [rad].
    lut : numpy.ndarray
        f at ``x_i = i * period_rad / len(lut)`` [rad], mean zero.
    info : dict
        Identification details (method, amplitude, uncertainty, ...).
    """

    period_rad: float
    lut: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)

    def __call__(self, theta_m: np.ndarray | float) -> np.ndarray:
        """f(theta_m mod rho) [rad] by periodic linear interpolation of the table."""
        n = len(self.lut)
        x = np.mod(np.asarray(theta_m, float), self.period_rad) / self.period_rad * n
        i0 = np.floor(x).astype(int) % n
        frac = x - np.floor(x)
        return (1 - frac) * self.lut[i0] + frac * self.lut[(i0 + 1) % n]

    def slope(self, theta_m: np.ndarray | float) -> np.ndarray:
        """df/dtheta_m [rad/rad] of the interpolated table (constant between its entries)."""
        n = len(self.lut)
        x = np.mod(np.asarray(theta_m, float), self.period_rad) / self.period_rad * n
        i0 = np.floor(x).astype(int) % n
        return (self.lut[(i0 + 1) % n] - self.lut[i0]) * (n / self.period_rad)

    def at(self, theta_m: float) -> float:
        """``self(theta_m)`` for one float [rad], without numpy (a few hundred ns in a 1 kHz loop)."""
        lut = self.__dict__.get("_lut_list")
        if lut is None:  # cached plain-float copy; the table is not modified after construction
            lut = self.__dict__["_lut_list"] = [float(v) for v in self.lut]
        n = len(lut)
        x = (theta_m % self.period_rad) / self.period_rad * n
        i0 = math.floor(x)
        frac = x - i0
        i0 %= n
        return (1.0 - frac) * lut[i0] + frac * lut[(i0 + 1) % n]


def ripple_period(table: RippleTable | None) -> float:
    """The ripple's period [rad]: the table's, or the paper's rho where there is no table (a design or filter
    on a model without an identified ripple)."""
    return table.period_rad if table is not None else RIPPLE_PERIOD_RAD


@dataclass
class Source:
    """A file the model was identified from."""

    file: str
    sha256: str
    role: str = "fit"


@dataclass
class JointModel:
    """The identified joint model (see the module docstring for the file layout)."""

    parameters: dict[str, Parameter]
    correlation_names: list[str] = field(default_factory=list)
    correlation: np.ndarray | None = None
    ripple: RippleTable | None = None
    fit: dict[str, Any] = field(default_factory=dict)
    sources: list[Source] = field(default_factory=list)
    #: Extra plant effects as ``{"name": ..., <parameter>: value, ...}`` tables (see ``iiwa_ident.sim.effects``).
    effects: list[dict[str, Any]] = field(default_factory=list)
    joint: int | None = None
    robot_model: str | None = None
    description: str = ""
    #: The 7 joint positions the model holds at [rad] (a starting model from the rigid-body description).
    pose_rad: list[float] | None = None
    tool_version: str = field(default_factory=tool_version)
    created_utc: str = field(default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="seconds"))

    def value(self, name: str) -> float:
        """The value of parameter ``name`` in SI units."""
        return self.parameters[name].value

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "tool_version": self.tool_version,
            "created_utc": self.created_utc,
        }
        if self.joint is not None:
            out["joint"] = self.joint
        if self.robot_model:
            out["robot_model"] = self.robot_model
        if self.description:
            out["description"] = self.description
        if self.pose_rad is not None:
            out["pose_rad"] = [float(x) for x in self.pose_rad]
        out["parameters"] = {
            name: {k: v for k, v in (("value", p.value), ("std", p.std), ("unit", p.unit), ("origin", p.origin))
                   if v is not None}
            for name, p in self.parameters.items()
        }
        if self.correlation is not None:
            out["correlation"] = {"names": list(self.correlation_names), "matrix": np.asarray(self.correlation).tolist()}
        if self.ripple is not None:
            out["ripple"] = {"period_rad": self.ripple.period_rad, "lut": np.asarray(self.ripple.lut).tolist(),
                             **self.ripple.info}
        if self.fit:
            out["fit"] = self.fit
        if self.sources:
            out["sources"] = [{"file": s.file, "sha256": s.sha256, "role": s.role} for s in self.sources]
        if self.effects:
            out["effects"] = [dict(e) for e in self.effects]
        return out

    def to_plant(self, base=None):
        """A simulation plant with these dynamics and, if present, this ripple table."""
        from iiwa_ident.sim import TransmissionRipple, default_plant

        plant = (base or default_plant()).without_effects("transmission_ripple")
        for name in ("Jc", "bc", "K", "Jl", "Td"):
            plant.dynamics[name] = self.value(name)
        plant.internal["KI"] = self.value("KI")
        if self.ripple is not None:
            plant = plant.with_effects(TransmissionRipple({"period_rad": self.ripple.period_rad,
                                                          "lut": np.asarray(self.ripple.lut).tolist()}))
        if self.effects:
            from iiwa_ident.sim import make_effect

            plant = plant.with_effects(*[make_effect(e["name"], {k: v for k, v in e.items() if k != "name"})
                                         for e in self.effects])
        return plant


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ModelError(f"{where}: expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ModelError(f"{where}: must be finite, got {value}")
    return value


def model_from_dict(data: dict[str, Any], where: str = "") -> JointModel:
    """Validate a model-file mapping and build the :class:`JointModel`."""
    if data.get("format") != MODEL_FORMAT:
        raise ModelError(f"{where}format: expected {MODEL_FORMAT!r}, got {data.get('format')!r}")
    if data.get("format_version") != MODEL_FORMAT_VERSION:
        raise ModelError(f"{where}format_version: unsupported version {data.get('format_version')!r} (this tool reads 1)")
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

    ripple = None
    if "ripple" in data:
        r = dict(data["ripple"])
        period = _number(f"{where}ripple.period_rad", r.pop("period_rad", None))
        if period <= 0:
            raise ModelError(f"{where}ripple.period_rad: must be positive")
        lut = r.pop("lut", None)
        if not isinstance(lut, list) or len(lut) < 4:
            raise ModelError(f"{where}ripple.lut: expected a list of at least 4 deflections [rad]")
        table = np.array([_number(f"{where}ripple.lut[{i}]", v) for i, v in enumerate(lut)])
        ripple = RippleTable(period, table, r)

    sources = []
    for i, s in enumerate(data.get("sources", [])):
        if not isinstance(s, dict) or "file" not in s or "sha256" not in s:
            raise ModelError(f"{where}sources[{i}]: expected file and sha256")
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
    """Write ``model`` atomically (validated by reading back what is written)."""
    data = model.to_dict()
    text = dumps_toml(data)
    import tomllib

    model_from_dict(tomllib.loads(text), where=f"{path}: ")
    return write_atomic(path, text)


def table1_model() -> JointModel:
    """The paper's Table I with Td = 5 ms and K_I = 25 rad/s (no uncertainties)."""
    values = {p.name: p.default for p in (*JOINT_PARAMETERS, OBSERVER_GAIN)}  # Table I's defaults
    return JointModel(
        parameters={k: Parameter(v, None, PARAMETER_UNITS[k]) for k, v in values.items()},
        joint=1, robot_model="iiwa14",
        description="Table I of 'Toward Torque Control of a KUKA LBR IIWA for Physical Human-Robot Interaction' "
                    "(base joint, links arranged for maximum inertia), Td = 5 ms, K_I = 25 rad/s",
        created_utc="2026-11-21T00:00:00+00:00",
    )
