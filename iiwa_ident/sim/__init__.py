"""The simulated iiwa joint: plant files, effects and the joint behind the robot interface.

Public API
----------
Plant, load_plant, default_plant, save_plant, plant_from_dict, plant_from_model
    The plant description, its TOML file format and the plant of a joint model (:mod:`iiwa_ident.sim._plant`).
Effect, EFFECTS, register_effect, make_effect and the effect classes
    Switchable plant effects, the simulator's hooks and the estimators' regressors in one class each
    (:mod:`iiwa_ident.sim._effects`; EffectSignals, Column, INJECTIONS, own_dataset_columns).
SimulatedJoint, SimTrace, ExternalAgent
    The joint as the robot presents it through FRI (:mod:`iiwa_ident.sim._joint`).
simulate_reference
    The reference model: eqs (1)-(4) integrated apart from the compiled cycle (:mod:`iiwa_ident.sim._reference`).
"""

from iiwa_ident.sim._agents import ImpedanceAgent
from iiwa_ident.sim._effects import (
    EFFECTS,
    INJECTIONS,
    Column,
    Effect,
    EffectSignals,
    InputDelay,
    LinkFriction,
    LinkSpring,
    PeriodicDisturbance,
    PositionDependentLoad,
    TorqueLogFilter,
    TorqueSensorOffset,
    TorqueSensorScale,
    TransmissionRipple,
    make_effect,
    own_dataset_columns,
    register_effect,
)
from iiwa_ident.sim._joint import ExternalAgent, SimTrace, SimulatedJoint
from iiwa_ident.sim._plant import (
    Plant,
    default_plant,
    load_plant,
    plant_from_dict,
    plant_from_model,
    save_plant,
)
from iiwa_ident.sim._reference import simulate_reference

__all__ = [
    "EFFECTS", "Effect", "register_effect", "make_effect", "EffectSignals", "Column", "INJECTIONS",
    "own_dataset_columns",
    "TransmissionRipple", "LinkFriction", "PositionDependentLoad", "LinkSpring", "TorqueSensorOffset",
    "TorqueSensorScale", "TorqueLogFilter", "PeriodicDisturbance", "InputDelay",
    "Plant", "default_plant", "load_plant", "plant_from_dict", "plant_from_model", "save_plant",
    "SimulatedJoint", "SimTrace", "ExternalAgent", "simulate_reference",
    "ImpedanceAgent",
]
