"""Design of the spatial filter, external-torque observers and additive torque controller.

Public API
----------
SpatialFilter, FilterSettings, filter_period, spatial_filter_response, ripple_bandpass_coefficients, gamma_weight, ripple_line_cut
    The spatial filter and its settings of eqs (10)-(12) (:mod:`iiwa_ident.design._spatial_filter`).
ExternalTorqueObserver, BuiltinObserver, LinkVelocityObserver, FilteredObserver, OBSERVERS, make_observer,
run_observers, compare_observers, observer_lag
    The three observer variants of eqs (13)-(14) (:mod:`iiwa_ident.design._observers`).
HumanArm, AdditiveDesign, AdditiveController (runs a DiscreteDesign), OuterLoopMargins, DesignError, PAPER_POLES,
PAPER_OBSERVER_POLES, design_controller, kappa_max, outer_loop_margins, exact_delay_spectral_radius,
DeployedLoop, DeployedMargin, deployed_loop_matrix, deployed_kappa_max, deployed_margin
    The additive torque controller of section V.B: its design (:mod:`iiwa_ident.design._additive`), the
    controller one sample at a time (:mod:`iiwa_ident.design._controller`) and the outer-loop margin
    (:mod:`iiwa_ident.design._margins`; the loop as deployed: source, F/T filter, spatial filter).
ClosedLoopRun, KappaMargin, AdditiveTorqueControl, analysis_design, identified_model, compare_controllers,
kappa_margin, sine_tracking
    The closed-loop analysis on the simulated joint: both controllers compared, the outer loop's live
    margin and the tracking of a sine (:mod:`iiwa_ident.design._analysis`).
ControlCycle
    Eqs (8)-(18) once per sample, for the analysis and the FRI runtime (:mod:`iiwa_ident.design._cycle`).
DesignRecord, DesignFileError, make_record, read_design, write_design
    The design file (:mod:`iiwa_ident.design._design_file`).
paper_reproduction, format_reproduction, reproduction_cells, ReproductionRow
    The paper's numbers beside the computed ones (:mod:`iiwa_ident.design._paper`).
"""

from iiwa_ident.design._additive import (
    DEFAULT_PREFILTER_HZ,
    FEEDFORWARD_MODES,
    PAPER_OBSERVER_POLES,
    PAPER_POLES,
    SAMPLE_TIME_S,
    AdditiveDesign,
    DesignError,
    builtin_poles,
    check_poles,
    design_controller,
    natural_frequency_damping,
)
from iiwa_ident.design._analysis import (
    AdditiveTorqueControl,
    ClosedLoopRun,
    KappaMargin,
    analysis_design,
    compare_controllers,
    identified_model,
    kappa_margin,
    sine_tracking,
)
from iiwa_ident.design._controller import AdditiveController, DiscreteDesign
from iiwa_ident.design._cycle import ControlCycle
from iiwa_ident.design._design_file import (
    DesignFileError,
    DesignRecord,
    design_json,
    make_record,
    read_design,
    write_design,
)
from iiwa_ident.design._margins import (
    DeployedLoop,
    DeployedMargin,
    HumanArm,
    OuterLoopMargins,
    deployed_kappa_max,
    deployed_loop_matrix,
    deployed_margin,
    exact_delay_spectral_radius,
    kappa_max,
    outer_loop_margins,
)
from iiwa_ident.design._observers import (
    OBSERVERS,
    BuiltinObserver,
    ExternalTorqueObserver,
    FilteredObserver,
    LinkVelocityObserver,
    compare_observers,
    link_speed,
    make_observer,
    observer_lag,
    run_observers,
)
from iiwa_ident.design._paper import (
    REPRODUCTION_COLUMNS,
    REPRODUCTION_POLES,
    ReproductionRow,
    format_reproduction,
    paper_reproduction,
    reproduction_cells,
    table1_parameters,
)
from iiwa_ident.design._spatial_filter import (
    DESIGN_BETA,
    PAPER_BETA,
    PAPER_FILTER,
    RIPPLE_PERIOD_RAD,
    V_MIN_RAD_S,
    FilterSettings,
    SpatialFilter,
    filter_period,
    gamma_weight,
    ripple_bandpass_coefficients,
    ripple_line_cut,
    spatial_filter_response,
)

__all__ = [
    "AdditiveTorqueControl", "analysis_design", "compare_controllers", "identified_model", "kappa_margin",
    "sine_tracking",
    "SpatialFilter", "spatial_filter_response", "ripple_bandpass_coefficients", "gamma_weight",
    "ripple_line_cut", "ExternalTorqueObserver", "BuiltinObserver", "LinkVelocityObserver", "FilteredObserver",
    "OBSERVERS", "make_observer", "run_observers", "compare_observers", "observer_lag",
    "HumanArm", "AdditiveDesign", "AdditiveController", "DiscreteDesign", "OuterLoopMargins", "DesignError",
    "PAPER_POLES", "PAPER_OBSERVER_POLES", "design_controller", "kappa_max", "outer_loop_margins",
    "DeployedLoop", "DeployedMargin", "deployed_kappa_max", "deployed_loop_matrix", "deployed_margin",
    "exact_delay_spectral_radius", "DesignRecord", "FilterSettings", "filter_period", "PAPER_FILTER", "DesignFileError", "make_record", "read_design",
    "write_design", "paper_reproduction", "format_reproduction",
    "reproduction_cells", "REPRODUCTION_COLUMNS", "REPRODUCTION_POLES", "ReproductionRow",
    "ClosedLoopRun", "KappaMargin", "ControlCycle",
    "DEFAULT_PREFILTER_HZ", "FEEDFORWARD_MODES", "SAMPLE_TIME_S", "builtin_poles", "check_poles", "natural_frequency_damping",
    "design_json",
    "link_speed",
    "table1_parameters",
    "DESIGN_BETA", "PAPER_BETA", "V_MIN_RAD_S", "RIPPLE_PERIOD_RAD",
]
