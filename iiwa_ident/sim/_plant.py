"""Plant description of the simulated joint and its TOML file format.

A plant file holds the joint model of eqs (1)-(4) (Table I by default), the
robot's own behaviour (internal torque loop, feasibility filter, observer,
sensors), the integration settings and the switched-on effects::

    format = "iiwa-ident-plant"
    format_version = 1

    [robot]
    model = "iiwa14"
    joint = 1

    [dynamics]          # eqs (1)-(4), Table I
    Jc = 1.03
    ...

    [effects.transmission_ripple]
    period_rad = 0.01963
    harmonics = [[2.0e-5, 0.0]]

Every key is validated; an unknown key, a wrong type, a NaN or a value out
of range raises :class:`~iiwa_ident.errors.PlantError` naming the key.
The documented default plant is ``iiwa_ident/data/default_plant.toml``.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from iiwa_ident._schema import check_format
from iiwa_ident._toml import dumps_toml, load_toml, write_atomic
from iiwa_ident.errors import PlantError
from iiwa_ident.model import JOINT_PARAMETERS, OBSERVER_GAIN, JointModel, Param
from iiwa_ident.robot import ROBOT_MODELS, JointLimits, joint_limits
from iiwa_ident.sim._effects import Effect, _check_number, make_effect

__all__ = ["Plant", "load_plant", "default_plant", "plant_from_dict", "plant_from_model", "save_plant", "PLANT_FORMAT", "SECTIONS"]

PLANT_FORMAT = "iiwa-ident-plant"
PLANT_FORMAT_VERSION = 1


# Scalar sections of the plant file: name -> parameters (default, unit, range).
SECTIONS: dict[str, tuple[Param, ...]] = {
    "dynamics": JOINT_PARAMETERS,
    "internal": (
        OBSERVER_GAIN,
        Param("slew_rate_nm_s", 20000.0, "Nm/s", 1.0, 1e7, "feasibility filter: command slew-rate limit, per cycle"),
        Param("standstill_torque_nm", 1.0, "Nm", 0.0, 100.0, "torque control suppressed below this from standstill"),
        Param("standstill_velocity_rad_s", 0.002, "rad/s", 0.0, 1.0, "speed below which the joint counts as standing"),
        Param("standstill_time_s", 0.01, "s", 0.0, 10.0, "how long the joint must stand to count as at standstill"),
        Param("position_kp", 3000.0, "Nm/rad", 0.0, 1e6, "stiffness of the robot's position controller"),
        Param("position_kd", 150.0, "Nm s/rad", 0.0, 1e5, "damping of the robot's position controller"),
    ),
    "sensors": (
        Param("encoder_tick_rad", 5.989e-8, "rad", 0.0, 1e-2, "motor encoder quantisation (0: none)"),
        Param("tau_noise_nm", 0.02, "Nm", 0.0, 100.0, "std of joint-torque sensor noise"),
        Param("ft_noise_nm", 0.05, "Nm", 0.0, 100.0, "std of the external F/T torque reference"),
        Param("link_encoder_noise_rad", 1e-6, "rad", 0.0, 1e-2, "std of the external link-position reference"),
    ),
    "simulation": (
        Param("cycle_s", 0.001, "s", 1e-4, 0.1, "robot cycle (FRI send period)"),
        Param("substeps", 10, "1", 10, 1000, "integration steps per cycle (at least 10)"),
    ),
}
_FLAGS = {"sensors": ("ft_sensor", "link_encoder")}


@dataclass(kw_only=True)
class Plant:
    """Everything the simulated joint needs.

    Attributes
    ----------
    robot_model : str
        ``"iiwa7"`` or ``"iiwa14"`` (selects the joint limits).
    joint : int
        Joint number 1-7.
    dynamics, internal, sensors, simulation : dict of str to float
        The scalar sections (see :data:`SECTIONS` for keys, units and ranges).
    ft_sensor, link_encoder : bool
        Whether the external references of the paper's set-up are fitted.
    effects : list of Effect
        Switched-on effects, in file order.
    """

    robot_model: str = "iiwa14"
    joint: int = 1
    dynamics: dict[str, float] = field(default_factory=dict)
    internal: dict[str, float] = field(default_factory=dict)
    sensors: dict[str, float] = field(default_factory=dict)
    simulation: dict[str, float] = field(default_factory=dict)
    ft_sensor: bool = True
    link_encoder: bool = True
    effects: list[Effect] = field(default_factory=list)

    def __post_init__(self) -> None:
        for section, params in SECTIONS.items():
            values = getattr(self, section)
            for p in params:
                values.setdefault(p.name, p.default)

    @property
    def limits(self) -> JointLimits:
        """Data-sheet limits of the joint."""
        return joint_limits(self.robot_model, self.joint)

    @property
    def cycle_s(self) -> float:
        return self.simulation["cycle_s"]

    @property
    def substeps(self) -> int:
        return int(self.simulation["substeps"])

    def effect(self, name: str) -> Effect | None:
        """The switched-on effect ``name``, or None."""
        return next((e for e in self.effects if e.name == name), None)

    def with_effects(self, *effects: Effect) -> Plant:
        """A copy with ``effects`` switched on (replacing ones of the same name)."""
        new = copy.deepcopy(self)
        names = {e.name for e in effects}
        new.effects = [e for e in new.effects if e.name not in names] + list(effects)
        return new

    def without_effects(self, *names: str) -> Plant:
        """A copy with the named effects (all if none named) switched off."""
        new = copy.deepcopy(self)
        new.effects = [e for e in new.effects if names and e.name not in names]
        return new

    def to_dict(self) -> dict[str, Any]:
        """The plant-file content (round-trips through :func:`plant_from_dict`)."""
        out: dict[str, Any] = {
            "format": PLANT_FORMAT,
            "format_version": PLANT_FORMAT_VERSION,
            "robot": {"model": self.robot_model, "joint": self.joint},
        }
        for section in SECTIONS:
            out[section] = dict(getattr(self, section))
        out["simulation"]["substeps"] = int(out["simulation"]["substeps"])
        out["sensors"].update(ft_sensor=self.ft_sensor, link_encoder=self.link_encoder)
        out["effects"] = {e.name: e.to_dict() for e in self.effects}
        return out


def _section(data: dict[str, Any], section: str, where: str) -> tuple[dict[str, float], dict[str, bool]]:
    raw = data.get(section, {})
    if not isinstance(raw, dict):
        raise PlantError(f"{where}{section}: expected a table")
    params = {p.name: p for p in SECTIONS[section]}
    flags = _FLAGS.get(section, ())
    values: dict[str, float] = {}
    flag_values: dict[str, bool] = {}
    for key, value in raw.items():
        if key in flags:
            if not isinstance(value, bool):
                raise PlantError(f"{where}{section}.{key}: expected true or false, got {value!r}")
            flag_values[key] = value
        elif key in params:
            p = params[key]
            values[key] = _check_number(f"{where}{section}.{key}", value, p.lower, p.upper)
        else:
            known = ", ".join(sorted([*params, *flags]))
            raise PlantError(f"{where}{section}.{key}: unknown key (known: {known})")
    return values, flag_values


def plant_from_dict(data: dict[str, Any], where: str = "") -> Plant:
    """Validate a plant-file mapping and build the :class:`Plant`.

    ``where`` (for example ``"plant.toml: "``) prefixes every error message.
    """
    top = {"format", "format_version", "robot", "effects", *SECTIONS}
    for key in data:
        if key not in top:
            raise PlantError(f"{where}{key}: unknown key (known: {', '.join(sorted(top))})")
    check_format(data, where, PLANT_FORMAT, PLANT_FORMAT_VERSION, PlantError, required=False)
    robot = data.get("robot", {})
    if not isinstance(robot, dict):
        raise PlantError(f"{where}robot: expected a table")
    for key in robot:
        if key not in ("model", "joint"):
            raise PlantError(f"{where}robot.{key}: unknown key (known: joint, model)")
    model = robot.get("model", "iiwa14")
    if model not in ROBOT_MODELS:
        raise PlantError(f"{where}robot.model: unknown robot {model!r} (known: {', '.join(ROBOT_MODELS)})")
    joint = robot.get("joint", 1)
    if isinstance(joint, bool) or not isinstance(joint, int) or not 1 <= joint <= 7:
        raise PlantError(f"{where}robot.joint: expected an integer 1..7, got {joint!r}")

    kwargs: dict[str, Any] = {"robot_model": model, "joint": joint}
    for section in SECTIONS:
        values, flags = _section(data, section, where)
        kwargs[section] = values
        kwargs.update(flags)
    effects_raw = data.get("effects", {})
    if not isinstance(effects_raw, dict):
        raise PlantError(f"{where}effects: expected a table of effect tables")
    effects = []
    for name, table in effects_raw.items():
        if not isinstance(table, dict):
            raise PlantError(f"{where}effects.{name}: expected a table")
        if table.get("enabled", True) is False:
            continue
        effects.append(make_effect(name, table, f"{where}effects.{name}"))
    sub = kwargs["simulation"].get("substeps")
    if sub is not None and sub != int(sub):
        raise PlantError(f"{where}simulation.substeps: expected an integer, got {sub}")
    return Plant(effects=effects, **kwargs)


def load_plant(path: str | os.PathLike) -> Plant:
    """Read and validate a plant TOML file."""
    return plant_from_dict(load_toml(path, PlantError), where=f"{path}: ")


def default_plant() -> Plant:
    """The documented default plant shipped with the package (Table I, ripple on)."""
    text = resources.files("iiwa_ident").joinpath("data/default_plant.toml").read_text()
    import tomllib

    return plant_from_dict(tomllib.loads(text), where="default_plant.toml: ")


def save_plant(plant: Plant, path: str | os.PathLike) -> Path:
    """Write ``plant`` as a plant TOML file (atomically)."""
    return write_atomic(path, dumps_toml(plant.to_dict()))


def plant_from_model(model: JointModel, base: Plant | None = None) -> Plant:
    """A plant with a joint model's dynamics, its ripple table (if any) and its extra effects.

    Parameters
    ----------
    model : JointModel
        The identified (or starting) model.
    base : Plant, optional
        The plant whose other settings (cycle, noise, limits, effects other
        than the ripple) are kept (default: :func:`default_plant`).

    Returns
    -------
    Plant
        A new plant; ``base`` is not changed.

    Examples
    --------
    >>> from iiwa_ident.model import table1_model
    >>> plant_from_model(table1_model()).dynamics["K"]
    18500.0
    """
    from iiwa_ident.sim._effects import TransmissionRipple

    plant = (base or default_plant()).without_effects("transmission_ripple")
    for name in ("Jc", "bc", "K", "Jl", "Td"):
        plant.dynamics[name] = model.value(name)
    plant.internal["KI"] = model.value("KI")
    if model.ripple is not None:
        plant = plant.with_effects(TransmissionRipple({"period_rad": model.ripple.period_rad,
                                                      "lut": [float(v) for v in model.ripple.lut]}))
    if model.effects:
        plant = plant.with_effects(*[make_effect(e["name"], {k: v for k, v in e.items() if k != "name"})
                                     for e in model.effects])
    return plant
