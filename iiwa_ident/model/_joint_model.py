"""The joint model file's types: the identified model, its parameters, its ripple table and its sources.

The file is TOML, format version 1, read (and validated, effects included) by
:func:`iiwa_ident.ident.read_model` and written by :func:`iiwa_ident.ident.write_model`:

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
    name = "link_friction"       # of iiwa_ident/sim/_effects.py; validated on read
    coulomb_nm = 1.2
    viscous_nms_rad = 0.8

    [[sources]]                  # what the model was identified from
    file = "chirp.h5"
    sha256 = "..."
    role = "fit"
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np

from iiwa_ident import tool_version
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model._parameters import JOINT_PARAMETERS, OBSERVER_GAIN, PARAMETER_UNITS, RIPPLE_PERIOD_RAD

__all__ = [
    "ModelError",
    "Parameter",
    "RippleTable",
    "ripple_period",
    "Source",
    "JointModel",
    "table1_model",
    "PARAMETER_ORIGINS",
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
]

MODEL_FORMAT = "iiwa-ident-model"
MODEL_FORMAT_VERSION = 1

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

    @classmethod
    def from_mapping(cls, raw: Any, where: str = "ripple", error: type[IiwaIdentError] | None = None) -> RippleTable:
        """Read a ripple table as every file stores it: ``period_rad``, ``lut`` and any further keys as
        :attr:`info`.

        Parameters
        ----------
        raw : mapping
            The file's table.
        where : str
            Its place in the file, for the errors (``"model.toml: ripple"``).
        error : type of IiwaIdentError, optional
            The file format's error (default :class:`ModelError`).

        Examples
        --------
        >>> t = RippleTable.from_mapping({"period_rad": 0.0196, "lut": [0.0, 1e-5, 0.0, -1e-5], "method": "fft"})
        >>> t.period_rad, len(t.lut), t.info
        (0.0196, 4, {'method': 'fft'})
        """
        error = error or ModelError
        if not isinstance(raw, dict):
            raise error(f"{where}: expected a table with period_rad and lut")
        info = dict(raw)
        period = _finite(f"{where}.period_rad", info.pop("period_rad", None), error)
        if period <= 0:
            raise error(f"{where}.period_rad: must be positive, got {period:g}")
        lut = info.pop("lut", None)
        if not isinstance(lut, (list, tuple, np.ndarray)) or len(lut) < 4:
            raise error(f"{where}.lut: expected a list of at least 4 deflections [rad]")
        table = np.array([_finite(f"{where}.lut[{i}]", v, error) for i, v in enumerate(lut)])
        return cls(period, table, info)

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


def _finite(where: str, value: Any, error: type[IiwaIdentError]) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise error(f"{where}: must be finite, got {value}")
    return float(value)


def ripple_period(table: RippleTable | None) -> float:
    """The ripple's period [rad]: the table's, or the paper's rho where there is no table (a design or filter
    on a model without an identified ripple).

    Examples
    --------
    >>> ripple_period(None)
    0.01963
    >>> ripple_period(RippleTable(0.0196, np.zeros(8)))
    0.0196
    """
    return table.period_rad if table is not None else RIPPLE_PERIOD_RAD


@dataclass
class Source:
    """A file the model was identified from."""

    file: str
    sha256: str
    role: str = "fit"


@dataclass(kw_only=True)
class JointModel:
    """The identified joint model (see the module docstring for the file layout)."""

    parameters: dict[str, Parameter]
    correlation_names: list[str] = field(default_factory=list)
    correlation: np.ndarray | None = None
    ripple: RippleTable | None = None
    fit: dict[str, Any] = field(default_factory=dict)
    sources: list[Source] = field(default_factory=list)
    #: Extra plant effects as ``{"name": ..., <parameter>: value, ...}`` tables (see ``iiwa_ident.sim._effects``).
    effects: list[dict[str, Any]] = field(default_factory=list)
    joint: int | None = None
    robot_model: str | None = None
    description: str = ""
    #: The 7 joint positions the model holds at [rad] (a starting model from the rigid-body description).
    pose_rad: list[float] | None = None
    tool_version: str = field(default_factory=tool_version)
    created_utc: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))

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


def table1_model() -> JointModel:
    """The paper's Table I with Td = 5 ms and K_I = 25 rad/s (no uncertainties).

    Examples
    --------
    >>> m = table1_model()
    >>> m.robot_model, m.joint, m.value("K"), m.value("Td")
    ('iiwa14', 1, 18500.0, 0.005)
    """
    values = {p.name: p.default for p in (*JOINT_PARAMETERS, OBSERVER_GAIN)}  # Table I's defaults
    return JointModel(
        parameters={k: Parameter(v, None, PARAMETER_UNITS[k]) for k, v in values.items()},
        joint=1, robot_model="iiwa14",
        description="Table I of 'Toward Torque Control of a KUKA LBR IIWA for Physical Human-Robot Interaction' "
                    "(base joint, links arranged for maximum inertia), Td = 5 ms, K_I = 25 rad/s",
        created_utc="2026-11-21T00:00:00+00:00",
    )
