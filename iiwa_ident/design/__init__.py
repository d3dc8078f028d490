"""Design of the spatial filter, external-torque observers and additive torque controller.

Public API
----------
MomentumObserver
    Eq (13) as the robot runs it (used by the simulated joint).
SpatialFilter, spatial_filter_response, ripple_bandpass_coefficients, gamma_weight, ripple_line_cut
    The spatial filter of eqs (10)-(12) (:mod:`iiwa_ident.design.spatial_filter`).
ExternalTorqueObserver, BuiltinObserver, LinkVelocityObserver, FilteredObserver, OBSERVERS, make_observer,
run_observers, compare_observers, observer_lag
    The three observer variants of eqs (13)-(14) (:mod:`iiwa_ident.design.observers`).
"""

from iiwa_ident.design.observer import MomentumObserver
from iiwa_ident.design.observers import (
    OBSERVERS,
    BuiltinObserver,
    ExternalTorqueObserver,
    FilteredObserver,
    LinkVelocityObserver,
    compare_observers,
    make_observer,
    observer_lag,
    run_observers,
)
from iiwa_ident.design.spatial_filter import (
    SpatialFilter,
    gamma_weight,
    ripple_bandpass_coefficients,
    ripple_line_cut,
    spatial_filter_response,
)

__all__ = [
    "MomentumObserver", "SpatialFilter", "spatial_filter_response", "ripple_bandpass_coefficients", "gamma_weight",
    "ripple_line_cut", "ExternalTorqueObserver", "BuiltinObserver", "LinkVelocityObserver", "FilteredObserver",
    "OBSERVERS", "make_observer", "run_observers", "compare_observers", "observer_lag",
]
