"""Deployment: check a design and export it as a self-contained controller config.

:func:`deploy` runs :func:`check_design` (stability, margins, finiteness,
limits) and builds a :class:`ControllerConfig`, the file an FRI runtime
executes at 1 kHz; :func:`write_config` / :func:`read_config` store it with
the sha256 of its own content, and :func:`controller_from_config` rebuilds
the per-cycle controller from it.
"""

from iiwa_ident.deploy._checks import (
    DEFAULT_RATE_RISE_TIME_S,
    DEFAULT_REFERENCE_RISE_TIME_S,
    MAX_SPECTRAL_RADIUS,
    MIN_KAPPA_MARGIN,
    MIN_REFERENCE_FRACTION,
    Check,
    ControllerLimits,
    DeployError,
    check_design,
    default_rate_limit,
    default_reference_rate,
    failed_checks,
    reference_limit,
    step_peak_gain,
)
from iiwa_ident.deploy._config_file import (
    CONFIG_FORMAT,
    CONFIG_FORMAT_VERSION,
    ConfigError,
    ControllerConfig,
    Provenance,
    RobotSettings,
    config_from_dict,
    config_json,
    config_to_dict,
    content_sha256,
    controller_from_config,
    deploy,
    deploy_target,
    read_config,
    write_config,
)

__all__ = [
    "DEFAULT_RATE_RISE_TIME_S",
    "MAX_SPECTRAL_RADIUS",
    "MIN_KAPPA_MARGIN",
    "MIN_REFERENCE_FRACTION",
    "Check",
    "ControllerLimits",
    "DeployError",
    "check_design",
    "default_rate_limit",
    "failed_checks",
    "step_peak_gain",
    "reference_limit",
    "default_reference_rate",
    "DEFAULT_REFERENCE_RISE_TIME_S",
    "CONFIG_FORMAT",
    "CONFIG_FORMAT_VERSION",
    "ConfigError",
    "ControllerConfig",
    "Provenance",
    "RobotSettings",
    "config_from_dict",
    "config_to_dict",
    "content_sha256",
    "controller_from_config",
    "deploy",
    "deploy_target",
    "read_config",
    "write_config",
    "config_json",
]
