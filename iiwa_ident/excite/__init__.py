"""Experiment programs that drive a robot interface and record datasets.

Public API
----------
record
    Run an experiment on a robot interface under the limit guard.
Experiment, ClientState
    Base class of programs and the client-side state they see.
Chirp
    The exponential chirp (section II.B).
Multisine
    Random-phase odd multisines (:func:`iiwa_ident.references.odd_multisine`), periods times realisations
    (for the best linear approximation).
ConstantVelocity, QuasiStatic, HandGuided, StepTorque, SineTorque
    The other programs (sections III-V).
LimitGuard
    Safety supervision against the joint limits.
EXPERIMENTS
    Program class by dataset experiment name.
"""

from iiwa_ident.excite._chirp import Chirp
from iiwa_ident.excite._multisine import Multisine
from iiwa_ident.excite._programs import (
                                         ConstantVelocity,
                                         HandGuided,
                                         QuasiStatic,
                                         SineTorque,
                                         StepTorque,
)
from iiwa_ident.excite._runner import (
                                         ClientState,
                                         Experiment,
                                         record,
                                         velocity_filter_coefficient,
)
from iiwa_ident.excite._safety import LimitGuard

EXPERIMENTS = {cls.name: cls for cls in (Chirp, Multisine, ConstantVelocity, QuasiStatic, HandGuided, StepTorque,
                                         SineTorque)}

__all__ = ["record", "Experiment", "ClientState", "velocity_filter_coefficient", "Chirp", "Multisine",
           "ConstantVelocity",
           "QuasiStatic", "HandGuided", "StepTorque", "SineTorque", "LimitGuard", "EXPERIMENTS"]
