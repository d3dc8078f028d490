"""Identification: the joint model file's reader and writer, the joint fit and the ripple identification.

The model's types (:class:`~iiwa_ident.model.JointModel`, :class:`~iiwa_ident.model.RippleTable`) and the
position correction live in :mod:`iiwa_ident.model`. Beside the names below: :func:`best_linear_approximation`
and :func:`fit_bla` (the best linear approximation from multisines), :func:`cramer_rao_std` (the fit's
Cramér-Rao bound), :func:`detection_probability`, :func:`pooled_detection_probability` and
:class:`RunSensitivity` (the ripple search's chance of finding a line of a given amplitude).
"""

from iiwa_ident.ident._bla import BlaFit, best_linear_approximation, fit_bla
from iiwa_ident.ident._joint_fit import METHODS, fit_joint, fit_model
from iiwa_ident.ident._lines import line_ratio
from iiwa_ident.ident._log_filter import LOG_FILTER_MIN_HZ, LOG_ONLY, log_filter_text
from iiwa_ident.ident._model_file import model_from_dict, read_model, write_model
from iiwa_ident.ident._resid import INDEPENDENCE, LEVEL, MAX_LAG, WHITENESS, ResidualTest, ResidualTests, residual_tests
from iiwa_ident.ident._ripple import (
    PERIOD_MAX_RAD,
    PERIOD_MIN_RAD,
    RippleResult,
    identify_ripple,
    ripple_model,
)
from iiwa_ident.ident._ripple_detect import RunSensitivity, detection_probability, pooled_detection_probability
from iiwa_ident.ident._ripple_passes import find_passes
from iiwa_ident.ident._starting_model import (
    DESCRIPTION_FACTOR,
    LOAD_NEGLIGIBLE_NM,
    PAYLOAD_LEVER_MIN_M,
    POSE_TOLERANCE_RAD,
    Payload,
    PhysicalRanges,
    against_description,
    check_model_matches,
    dataset_model,
    model_for,
    payload_of_load,
    physical_ranges,
    starting_model,
)
from iiwa_ident.ident._tf_fit import FitResult, cramer_rao_std

__all__ = ["model_from_dict", "read_model", "write_model", "BlaFit", "METHODS", "fit_joint", "fit_model", "line_ratio", "PERIOD_MAX_RAD", "PERIOD_MIN_RAD", "RippleResult", "find_passes", "identify_ripple", "ripple_model", "FitResult",
           "starting_model", "dataset_model", "check_model_matches", "model_for", "LOAD_NEGLIGIBLE_NM", "POSE_TOLERANCE_RAD",
           "DESCRIPTION_FACTOR", "PhysicalRanges", "physical_ranges", "against_description",
           "Payload", "payload_of_load", "PAYLOAD_LEVER_MIN_M", "ResidualTest",
           "ResidualTests", "residual_tests", "WHITENESS", "INDEPENDENCE", "LEVEL", "MAX_LAG", "LOG_FILTER_MIN_HZ", "LOG_ONLY", "log_filter_text",
           "best_linear_approximation", "fit_bla", "cramer_rao_std", "detection_probability",
           "pooled_detection_probability", "RunSensitivity"]
