"""The joint model of the paper, eqs (1)-(4) and the robot's observer, eq (13), at the bottom of the package.

One parameter vocabulary (:data:`JOINT_PARAMETERS`: paper names, SI units,
valid ranges) used by plant files, model files, designs and every JSON
output, and eq (4) as python-control objects and frequency responses.

Public API
----------
Param, ParameterError, JOINT_PARAMETERS, PARAMETER_NAMES, PARAMETER_UNITS, JointParameters, parameter_values,
RIPPLE_PERIOD_RAD, OBSERVER_GAIN
    The vocabulary (:mod:`iiwa_ident.model._parameters`).
INPUTS, pade_coefficients, resonance_hz, coefficients, transfer_function, polynomials,
frequency_response
    Eq (4) (:mod:`iiwa_ident.model._eq4`).
zoh, delayed_hold, DelayedHold, state_matrices, DiscreteModel, discretize, simulate_outputs
    Eqs (1)-(4) as a state-space model, sampled exactly with the delay (:mod:`iiwa_ident.model._sampled`).
StateSpaceMatrices, StrictlyProperMatrices, ParameterValues
    Named results: a system's matrices (:mod:`iiwa_ident.model._matrices`), eq (4)'s parameters as numbers.
MomentumObserver
    The robot's external-torque observer, eq (13), as the robot and the runtime run it
    (:mod:`iiwa_ident.model._observer`).
JointModel, Parameter, RippleTable, Source, ModelError, ripple_period, table1_model, PARAMETER_ORIGINS,
MODEL_FORMAT, MODEL_FORMAT_VERSION
    The model file's types: what ``fit`` identifies and every later stage reads
    (:mod:`iiwa_ident.model._joint_model`; read and written by :mod:`iiwa_ident.ident`).
joint_position, link_position
    The position correction of eqs (8)-(9) with the ripple table (:mod:`iiwa_ident.model._correction`).
"""

from iiwa_ident.model._correction import joint_position, link_position
from iiwa_ident.model._eq4 import (
    INPUTS,
    coefficients,
    frequency_response,
    pade_coefficients,
    polynomials,
    resonance_hz,
    transfer_function,
)
from iiwa_ident.model._joint_model import (
    MODEL_FORMAT,
    MODEL_FORMAT_VERSION,
    PARAMETER_ORIGINS,
    JointModel,
    ModelError,
    Parameter,
    RippleTable,
    Source,
    ripple_period,
    table1_model,
)
from iiwa_ident.model._matrices import StateSpaceMatrices, StrictlyProperMatrices
from iiwa_ident.model._observer import MomentumObserver
from iiwa_ident.model._parameters import (
    JOINT_PARAMETERS,
    OBSERVER_GAIN,
    PARAMETER_NAMES,
    PARAMETER_UNITS,
    RIPPLE_PERIOD_RAD,
    HasParameterValues,
    JointParameters,
    Param,
    ParameterError,
    ParameterSource,
    ParameterValues,
    parameter_values,
)
from iiwa_ident.model._sampled import (
    DelayedHold,
    DiscreteModel,
    delayed_hold,
    discretize,
    sample_means,
    sample_slopes,
    simulate_outputs,
    state_matrices,
    zoh,
)

__all__ = [
    "Param",
    "ParameterError",
    "JOINT_PARAMETERS",
    "PARAMETER_NAMES",
    "PARAMETER_UNITS",
    "JointParameters",
    "parameter_values",
    "ParameterValues",
    "ParameterSource",
    "HasParameterValues",
    "StateSpaceMatrices",
    "StrictlyProperMatrices",
    "DelayedHold",
    "RIPPLE_PERIOD_RAD",
    "OBSERVER_GAIN",
    "INPUTS",
    "pade_coefficients",
    "resonance_hz",
    "coefficients",
    "transfer_function",
    "sample_means",
    "sample_slopes",
    "polynomials",
    "frequency_response",
    "zoh",
    "delayed_hold",
    "state_matrices",
    "DiscreteModel",
    "discretize",
    "simulate_outputs",
    "MomentumObserver",
    "JointModel",
    "Parameter",
    "RippleTable",
    "Source",
    "ModelError",
    "ripple_period",
    "table1_model",
    "PARAMETER_ORIGINS",
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
    "joint_position",
    "link_position",
]
