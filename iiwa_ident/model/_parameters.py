"""The joint model's parameter vocabulary: paper names, units, valid ranges, meaning."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol, Union, runtime_checkable

import numpy as np

from iiwa_ident.errors import IiwaIdentError

__all__ = ["Param", "ParameterError", "JOINT_PARAMETERS", "PARAMETER_NAMES", "PARAMETER_UNITS", "JointParameters",
           "parameter_values", "ParameterSource", "HasParameterValues", "RIPPLE_PERIOD_RAD", "OBSERVER_GAIN"]


class ParameterError(IiwaIdentError):
    """A joint-model parameter is invalid (the message names it)."""


@dataclass(frozen=True)
class Param:
    """A scalar parameter: of the joint model, of the robot, or of an effect.

    Attributes
    ----------
    name : str
        Key in plant, model and JSON files.
    default : float
        Value when the key is absent.
    unit : str
        Unit, for documentation and error messages.
    lower, upper : float
        Inclusive valid range.
    doc : str
        One line of meaning.
    """

    name: str
    default: float
    unit: str
    lower: float = -math.inf
    upper: float = math.inf
    doc: str = ""


#: Eqs (1)-(4): the defaults are Table I of the paper; the ranges what any iiwa joint may have.
JOINT_PARAMETERS: tuple[Param, ...] = (
    Param("Jc", 1.03, "kg m^2", 1e-4, 1e4, "controlled motor inertia, eq (1)"),
    Param("bc", 55.0, "Nm s/rad", 0.0, 1e5, "controlled motor damping, eq (1)"),
    Param("K", 18500.0, "Nm/rad", 1.0, 1e7, "series-elastic stiffness, eq (3)"),
    Param("Jl", 5.6, "kg m^2", 1e-4, 1e4, "link inertia, eq (2)"),
    Param("Td", 0.005, "s", 0.0, 0.05, "FRI input delay, eq (4)"),
)
#: The joint model's parameters, in this order everywhere.
PARAMETER_NAMES: tuple[str, ...] = tuple(p.name for p in JOINT_PARAMETERS)
#: The paper's period rho of the transmission deflection, eq (5) [rad] (section III.A): the default where
#: none was identified.
RIPPLE_PERIOD_RAD = 0.01963
#: The gain of the robot's external-torque observer, eq (13): a model file's and a plant's parameter beside
#: eqs (1)-(4) (the paper's iiwa: 25 rad/s).
OBSERVER_GAIN = Param("KI", 25.0, "rad/s", 0.0, 1e4, "gain of the built-in external-torque observer, eq (13)")
#: Unit of each parameter a model file may hold.
PARAMETER_UNITS: dict[str, str] = {p.name: p.unit for p in (*JOINT_PARAMETERS, OBSERVER_GAIN)}


@dataclass(frozen=True)
class JointParameters:
    """Parameters of eqs (1)-(4) in SI units.

    Attributes
    ----------
    Jc : float
        Controlled motor inertia [kg m^2].
    bc : float
        Controlled motor damping [Nm s/rad].
    K : float
        Series-elastic stiffness [Nm/rad].
    Jl : float
        Link inertia [kg m^2].
    Td : float
        FRI input delay [s].

    Examples
    --------
    >>> JointParameters(1.03, 55.0, 18500.0, 5.6, 0.005).as_dict()["K"]
    18500.0
    """

    Jc: float
    bc: float
    K: float
    Jl: float
    Td: float

    def __post_init__(self) -> None:
        for name in ("Jc", "K", "Jl", "Td"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ParameterError(f"{name} must be positive and finite, got {v!r}")
        if not (math.isfinite(self.bc) and self.bc >= 0):
            raise ParameterError(f"bc must be non-negative and finite, got {self.bc!r}")

    @classmethod
    def from_model(cls, model: HasParameterValues) -> JointParameters:
        """The parameters of anything with ``value(name)`` (a model file's joint model)."""
        return cls(*parameter_values(model))

    @classmethod
    def from_mapping(cls, values: Mapping[str, float]) -> JointParameters:
        """The parameters of a mapping ``{"Jc": .., ...}`` [SI]."""
        return cls(*parameter_values(values))

    def as_dict(self) -> dict[str, float]:
        """``{"Jc": .., "bc": .., "K": .., "Jl": .., "Td": ..}`` in SI units."""
        return {n: getattr(self, n) for n in PARAMETER_NAMES}


class ParameterValues(NamedTuple):
    """Eq (4)'s parameters as plain numbers [SI], in the order of :data:`PARAMETER_NAMES`."""

    Jc: float
    bc: float
    K: float
    Jl: float
    Td: float


@runtime_checkable
class HasParameterValues(Protocol):
    """Anything that gives a parameter's value by name (a model file's joint model)."""

    def value(self, name: str) -> float: ...


#: Where eqs (1)-(4) take the joint's parameters from (:func:`parameter_values`): :class:`JointParameters`,
#: a mapping ``{"Jc": .., ...}``, a model file's joint model, or the five numbers in the order of
#: :data:`PARAMETER_NAMES` (a sequence or an array: the estimators' vectors) [SI].
ParameterSource = Union[JointParameters, Mapping[str, float], HasParameterValues, Sequence[float], np.ndarray]


def parameter_values(params: ParameterSource) -> ParameterValues:
    """``(Jc, bc, K, Jl, Td)`` [SI] of a :data:`ParameterSource`; not validated."""
    if isinstance(params, JointParameters):
        return ParameterValues(params.Jc, params.bc, params.K, params.Jl, params.Td)
    if isinstance(params, Mapping):
        return ParameterValues(*(float(params[n]) for n in PARAMETER_NAMES))
    if isinstance(params, HasParameterValues):
        return ParameterValues(*(float(params.value(n)) for n in PARAMETER_NAMES))
    vals = [float(v) for v in params]
    if len(vals) != len(PARAMETER_NAMES):
        raise ValueError("expected the five parameters Jc, bc, K, Jl, Td")
    return ParameterValues(*vals)
