"""The controller config: everything an FRI runtime needs to run a design at 1 kHz.

Written by ``iiwa-ident deploy`` after :func:`~iiwa_ident.deploy.check_design`
passed; self-contained (no other file is needed to run it) and protected by
the sha256 of its own content. TOML, format version 2::

    format = "iiwa-ident-controller"
    format_version = 2
    sha256 = "..."                     # of the canonical form of everything else (below)
    tool_version = "0.1.0"
    created_utc = "2026-11-21T07:00:00+00:00"
    robot_model = "iiwa14"
    joint = 1
    sample_time_s = 0.001
    feedforward = "reference"          # reference | paper | none

    [robot]                            # what the robot side must be set to
    control_mode = "JOINT_IMPEDANCE"
    client_command_mode = "TORQUE"
    send_period_ms = 1
    receive_multiplier = 1
    watchdog_timeout_s = 0.005         # stop after this long without a robot message

    [limits]
    torque_nm = 320.0                  # clamp of |tau_c|
    torque_rate_nm_s = 32000.0         # clamp of d tau_c/dt
    velocity_rad_s = 1.4835            # stop above this joint speed
    reference_rate_nm_s = 8000.0       # clamp of d tau_r/dt
    reference_nm = 270.4               # clamp of |tau_r|
    data_sheet_torque_nm = 320.0       # the joint's data sheet, for reference
    data_sheet_velocity_rad_s = 1.4835

    [controller]                       # eqs (16)-(18), x_hat and x_ref on (Ad, Bd, C)
    Ad = [[...], ...]
    Bd = [...]
    C = [0.0, 0.0, 0.0, 1.0]
    Kd = [...]
    Ld = [...]
    Kr_d = 0.0

    [prefilter]                        # F(s) P(s) of eq (22), discrete; absent with feedforward = "none"
    Ad = ...; Bd = ...; Cd = ...; Dd = ...

    [filter]                           # spatial filter, eqs (10)-(12), at ripple.period_rad
    beta = 2.0                         # (the paper's rho without a ripple table)
    v_min_rad_s = 0.2

    [ripple]                           # optional: lookup table of eq (5)
    period_rad = 0.01963               # rho: the lookup table's and the spatial filter's
    lut = [...]                        # [rad]

    [torque_observer]                  # eq (13)
    KI = 25.0                          # [rad/s]
    K = 18500.0                        # [Nm/rad]
    Jl = 5.6                           # [kg m^2]

    [provenance]
    design_file = "design.toml"
    design_sha256 = "..."
    model_file = "model.toml"          # optional, as recorded in the design
    model_sha256 = "..."
    [[provenance.datasets]]            # the model's sources, if recorded
    file = "chirp.h5"
    sha256 = "..."
    role = "fit"

    [[checks]]                         # the deployment checks this config passed
    name = "closed_loop_spectral_radius"
    value = 0.9737
    threshold = 0.999
    comparison = "<="
    unit = "-"

The content hash is the sha256 of ``json.dumps(data_without_sha256,
sort_keys=True, separators=(",", ":"))`` (UTF-8): it depends on the values
only, not on the TOML layout, and floats survive the TOML round trip
exactly. :func:`read_config` recomputes it and refuses a file whose content
was changed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tomllib
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident._json import finite_or_none
from iiwa_ident._schema import TableReader
from iiwa_ident._toml import dumps_toml, load_toml, write_atomic
from iiwa_ident.deploy._checks import (
    Check,
    ControllerLimits,
    DeployError,
    check_design,
    default_rate_limit,
    default_reference_rate,
    failed_checks,
    reference_limit,
)
from iiwa_ident.design import FEEDFORWARD_MODES, SAMPLE_TIME_S, AdditiveController, DesignRecord, FilterSettings
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model import JointModel, RippleTable, Source, StateSpaceMatrices
from iiwa_ident.robot import ROBOT_MODELS, joint_limits

__all__ = [
    "CONFIG_FORMAT",
    "CONFIG_FORMAT_VERSION",
    "ConfigError",
    "RobotSettings",
    "Provenance",
    "ControllerConfig",
    "config_to_dict",
    "config_from_dict",
    "config_json",
    "content_sha256",
    "write_config",
    "read_config",
    "controller_from_config",
    "deploy",
]

CONFIG_FORMAT = "iiwa-ident-controller"
CONFIG_FORMAT_VERSION = 2
_C = (0.0, 0.0, 0.0, 1.0)


class ConfigError(IiwaIdentError):
    """A controller config is missing, unreadable, invalid or tampered with."""


@dataclass(frozen=True)
class RobotSettings:
    """Robot-side FRI settings the controller requires.

    Attributes
    ----------
    control_mode : str
        Sunrise control mode; JOINT_IMPEDANCE (with zero stiffness the
        commanded torque acts as the additive torque of eq (18)).
    client_command_mode : str
        FRI client command mode: TORQUE.
    send_period_ms : int
        FRI send period [ms]: 1 (the design's cycle).
    receive_multiplier : int
        FRI receive multiplier [-]: 1 (a command every cycle).
    watchdog_timeout_s : float
        The runtime stops (brakes) after this long without a robot message [s].
    """

    control_mode: str = "JOINT_IMPEDANCE"
    client_command_mode: str = "TORQUE"
    send_period_ms: int = 1
    receive_multiplier: int = 1
    watchdog_timeout_s: float = 0.005


@dataclass(frozen=True)
class Provenance:
    """Files the config was made from, with their sha256 (hex)."""

    design_file: str = ""
    design_sha256: str = ""
    model_file: str = ""
    model_sha256: str = ""
    datasets: tuple[Source, ...] = ()


@dataclass(kw_only=True)
class ControllerConfig:
    """Content of a controller config (module docstring for units and layout).

    Attributes
    ----------
    robot_model : str
        Key of :data:`iiwa_ident.robot.ROBOT_MODELS`.
    joint : int
        Joint 1-7.
    sample_time_s : float
        Controller cycle [s].
    feedforward : str
        Feed-forward mode of the design.
    Ad, Bd, C, Kd, Ld : ndarray
        Discrete model and gains of eqs (16)-(17).
    Kr_d : float
        Gain on ``tau_r`` in eq (16).
    prefilter : tuple (Ad, Bd, Cd, Dd) or None
        Discrete ``F(s) P(s)`` of eq (22).
    filter : FilterSettings
        Spatial filter.
    ripple : RippleTable or None
        Ripple lookup table (None if no ripple was identified).
    KI, K, Jl : float
        Torque-observer gain [rad/s], joint stiffness [Nm/rad], link inertia [kg m^2].
    limits : ControllerLimits
        Limits the runtime enforces.
    data_sheet_torque_nm, data_sheet_velocity_rad_s : float
        The joint's data-sheet limits [Nm], [rad/s].
    robot : RobotSettings
        Required robot-side settings and the watchdog.
    provenance : Provenance
        Source files and their sha256.
    checks : list of Check
        The deployment checks (all passed).
    sha256 : str
        Content hash (set by :func:`config_to_dict` / verified by :func:`read_config`).
    """

    robot_model: str
    joint: int
    sample_time_s: float
    feedforward: str
    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    Kd: np.ndarray
    Ld: np.ndarray
    Kr_d: float
    prefilter: tuple | None
    filter: FilterSettings
    ripple: RippleTable | None
    KI: float
    K: float
    Jl: float
    limits: ControllerLimits
    data_sheet_torque_nm: float
    data_sheet_velocity_rad_s: float
    robot: RobotSettings = field(default_factory=RobotSettings)
    provenance: Provenance = field(default_factory=Provenance)
    checks: list[Check] = field(default_factory=list)
    tool_version: str = ""
    created_utc: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))
    sha256: str = ""


# ---------------------------------------------------------------------------
# Running the controller from a config
# ---------------------------------------------------------------------------
@dataclass(kw_only=True)
class _DiscreteDesign:
    """The part of a design :class:`AdditiveController` runs on (the config holds no continuous data)."""

    Ad: np.ndarray
    Bd: np.ndarray
    Kd: np.ndarray
    Ld: np.ndarray
    Kr_d: float
    feedforward: str
    ffd: tuple | None
    sample_time_s: float


def controller_from_config(config: ControllerConfig) -> AdditiveController:
    """A fresh per-cycle :class:`AdditiveController` running the config's matrices.

    It produces the same ``step`` outputs as ``design.controller()`` of the
    design the config was deployed from. Limits are not applied here; the
    runtime clamps reference and command with ``config.limits``.
    """
    return AdditiveController(_DiscreteDesign(Ad=config.Ad, Bd=config.Bd, Kd=config.Kd, Ld=config.Ld, Kr_d=config.Kr_d,
                                              feedforward=config.feedforward, ffd=config.prefilter,
                                              sample_time_s=config.sample_time_s))


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------
def _mat(m: Any) -> Any:
    return np.asarray(m, float).tolist()


def content_sha256(data: dict[str, Any]) -> str:
    """sha256 (hex) of the canonical JSON form of ``data`` without its ``sha256`` key."""
    body = {k: v for k, v in data.items() if k != "sha256"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _check_dict(c: Check) -> dict[str, Any]:
    out: dict[str, Any] = {"name": c.name, "value": float(c.value), "threshold": float(c.threshold),
                           "passed": bool(c.passed), "comparison": c.comparison, "unit": c.unit}
    if c.detail:
        out["detail"] = c.detail
    return out


def config_to_dict(config: ControllerConfig) -> dict[str, Any]:
    """The TOML mapping of ``config`` with its content ``sha256`` (module docstring)."""
    out: dict[str, Any] = {
        "format": CONFIG_FORMAT,
        "format_version": CONFIG_FORMAT_VERSION,
        "sha256": "",
        "tool_version": config.tool_version or "0.1.0",
        "created_utc": config.created_utc,
        "robot_model": config.robot_model,
        "joint": int(config.joint),
        "sample_time_s": float(config.sample_time_s),
        "feedforward": config.feedforward,
    }
    r = config.robot
    out["robot"] = {"control_mode": r.control_mode, "client_command_mode": r.client_command_mode,
                    "send_period_ms": int(r.send_period_ms), "receive_multiplier": int(r.receive_multiplier),
                    "watchdog_timeout_s": float(r.watchdog_timeout_s)}
    lim = config.limits
    out["limits"] = {"torque_nm": float(lim.torque_nm), "torque_rate_nm_s": float(lim.torque_rate_nm_s),
                     "velocity_rad_s": float(lim.velocity_rad_s),
                     "reference_rate_nm_s": float(lim.reference_rate_nm_s), "reference_nm": float(lim.reference_nm),
                     "data_sheet_torque_nm": float(config.data_sheet_torque_nm),
                     "data_sheet_velocity_rad_s": float(config.data_sheet_velocity_rad_s)}
    out["controller"] = {"Ad": _mat(config.Ad), "Bd": _mat(config.Bd), "C": _mat(config.C), "Kd": _mat(config.Kd),
                         "Ld": _mat(config.Ld), "Kr_d": float(config.Kr_d)}
    if config.prefilter is not None:
        Af, Bf, Cf, Df = config.prefilter
        out["prefilter"] = {"Ad": _mat(Af), "Bd": _mat(Bf), "Cd": _mat(Cf), "Dd": float(Df)}
    f = config.filter
    out["filter"] = {"beta": float(f.beta), "v_min_rad_s": float(f.v_min_rad_s)}
    if config.ripple is not None:
        out["ripple"] = {"period_rad": float(config.ripple.period_rad), "lut": _mat(config.ripple.lut)}
    out["torque_observer"] = {"KI": float(config.KI), "K": float(config.K), "Jl": float(config.Jl)}
    p = config.provenance
    prov: dict[str, Any] = {k: v for k, v in (("design_file", p.design_file), ("design_sha256", p.design_sha256),
                                              ("model_file", p.model_file), ("model_sha256", p.model_sha256)) if v}
    if p.datasets:
        prov["datasets"] = [{"file": s.file, "sha256": s.sha256, "role": s.role} for s in p.datasets]
    out["provenance"] = prov
    out["checks"] = [_check_dict(c) for c in config.checks]
    out["sha256"] = content_sha256(out)
    return out


def write_config(path: str | os.PathLike, config: ControllerConfig) -> Path:
    """Write ``config`` atomically; what is written is read back and validated first.

    Sets ``config.sha256`` to the content hash written.
    """
    data = config_to_dict(config)
    text = dumps_toml(data)
    config_from_dict(tomllib.loads(text), where=f"{path}: ")
    written = write_atomic(path, text)
    config.sha256 = data["sha256"]
    return written


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------
_TABLES: dict[str, set[str]] = {
    "": {"format", "format_version", "sha256", "tool_version", "created_utc", "robot_model", "joint",
         "sample_time_s", "feedforward", "robot", "limits", "controller", "prefilter", "filter", "ripple",
         "torque_observer", "provenance", "checks"},
    "robot": {"control_mode", "client_command_mode", "send_period_ms", "receive_multiplier", "watchdog_timeout_s"},
    "limits": {"torque_nm", "torque_rate_nm_s", "velocity_rad_s", "reference_rate_nm_s", "reference_nm", "data_sheet_torque_nm",
               "data_sheet_velocity_rad_s"},
    "controller": {"Ad", "Bd", "C", "Kd", "Ld", "Kr_d"},
    "prefilter": {"Ad", "Bd", "Cd", "Dd"},
    "filter": {"beta", "v_min_rad_s"},
    "ripple": {"period_rad", "lut"},
    "torque_observer": {"KI", "K", "Jl"},
    "provenance": {"design_file", "design_sha256", "model_file", "model_sha256", "datasets"},
}
_OPTIONAL_TABLES = {"prefilter", "ripple"}


class _Reader(TableReader):
    """Typed access to the mapping; every error names the file and the dotted key."""

    error = ConfigError


def _check_keys(r: _Reader) -> None:
    for table, allowed in _TABLES.items():
        if table:
            if table not in r.data:
                if table in _OPTIONAL_TABLES:
                    continue
                raise r.fail(table, "missing")
            node = r.data[table]
            if not isinstance(node, dict):
                raise r.fail(table, "expected a table")
        else:
            node = r.data
        for key in node:
            if key not in allowed:
                raise r.fail(f"{table}.{key}" if table else key, "unknown key")


def config_from_dict(data: dict[str, Any], where: str = "") -> ControllerConfig:
    """Validate a config mapping (format, keys, types, shapes, values, content hash) and build it."""
    r = _Reader(data, where)
    r.check_format(CONFIG_FORMAT, CONFIG_FORMAT_VERSION)
    _check_keys(r)
    sha = r.sha("sha256")
    if content_sha256(data) != sha:
        raise r.fail("sha256", "does not match the content: the file was modified after it was written; refused "
                     "(a changed limit is written with its checks by 'iiwa-ident deploy --design DESIGN.toml --out "
                     "controller.toml --torque-limit NM' and the other limit options; see 'iiwa-ident deploy --help')")
    header = _header(r)
    T, mode = header["sample_time_s"], header["feedforward"]
    flt = FilterSettings(r.number("filter.beta", positive=True), r.number("filter.v_min_rad_s", positive=True))
    ripple = None
    if "ripple" in data:
        ripple = RippleTable.from_mapping(r.table("ripple"), f"{r.where}ripple", r.error)
    return ControllerConfig(
        **header, **_controller(r), prefilter=_config_prefilter(r, mode), filter=flt, ripple=ripple,
        KI=r.number("torque_observer.KI", positive=True), K=r.number("torque_observer.K", positive=True),
        Jl=r.number("torque_observer.Jl", positive=True), **_limits(r, header["robot_model"], header["joint"]),
        robot=_robot(r, T), provenance=_provenance(r), checks=_checks(r),
        tool_version=str(data.get("tool_version", "")), created_utc=str(data.get("created_utc", "")), sha256=sha)


def _header(r: _Reader) -> dict[str, Any]:
    """The robot model, the joint, the sample time and the feed-forward mode, by their config field names."""
    robot_model = r.string("robot_model")
    if robot_model not in ROBOT_MODELS:
        raise r.fail("robot_model", f"unknown robot model {robot_model!r} (known: {', '.join(ROBOT_MODELS)})")
    joint = r.integer("joint")
    if not 1 <= joint <= 7:
        raise r.fail("joint", f"expected 1..7, got {joint}")
    T = r.number("sample_time_s", positive=True)
    if abs(T - SAMPLE_TIME_S) > 1e-12:
        raise r.fail("sample_time_s", f"expected {SAMPLE_TIME_S} (the FRI cycle), got {T:g}")
    mode = r.string("feedforward")
    if mode not in FEEDFORWARD_MODES:
        raise r.fail("feedforward", f"expected one of {', '.join(FEEDFORWARD_MODES)}, got {mode!r}")
    return {"robot_model": robot_model, "joint": joint, "sample_time_s": T, "feedforward": mode}


def _robot(r: _Reader, T: float) -> RobotSettings:
    """``[robot]``: the runtime requires exactly these robot-side settings; a watchdog of at least one cycle."""
    want = RobotSettings()
    for key in ("control_mode", "client_command_mode"):
        if r.string(f"robot.{key}") != getattr(want, key):
            raise r.fail(f"robot.{key}", f"expected {getattr(want, key)!r}")
    for key in ("send_period_ms", "receive_multiplier"):
        if r.integer(f"robot.{key}") != getattr(want, key):
            raise r.fail(f"robot.{key}", f"expected {getattr(want, key)}")
    watchdog = r.number("robot.watchdog_timeout_s", positive=True)
    if watchdog < T:
        raise r.fail("robot.watchdog_timeout_s", f"shorter than one cycle ({T:g} s)")
    return RobotSettings(watchdog_timeout_s=watchdog)


def _limits(r: _Reader, robot_model: str, joint: int) -> dict[str, Any]:
    """``[limits]``, within the joint's data sheet, as the config's ``limits`` and data-sheet fields."""
    limits = ControllerLimits(r.number("limits.torque_nm", positive=True),
                              r.number("limits.torque_rate_nm_s", positive=True),
                              r.number("limits.velocity_rad_s", positive=True),
                              r.number("limits.reference_rate_nm_s", positive=True),
                              r.number("limits.reference_nm", positive=True))
    ds_torque = r.number("limits.data_sheet_torque_nm", positive=True)
    ds_velocity = r.number("limits.data_sheet_velocity_rad_s", positive=True)
    sheet = joint_limits(robot_model, joint)
    if abs(ds_torque - sheet.torque_nm) > 1e-9 or abs(ds_velocity - sheet.velocity_rad_s) > 1e-9:
        raise r.fail("limits.data_sheet_torque_nm", f"does not match the data sheet of {robot_model} A{joint}")
    if limits.torque_nm > sheet.torque_nm:
        raise r.fail("limits.torque_nm", f"above the data-sheet limit {sheet.torque_nm:g} Nm")
    if limits.velocity_rad_s > sheet.velocity_rad_s:
        raise r.fail("limits.velocity_rad_s", f"above the data-sheet limit {sheet.velocity_rad_s:g} rad/s")
    for key in ("torque_rate_nm_s", "reference_rate_nm_s"):
        if getattr(limits, key) > default_rate_limit(sheet):
            raise r.fail(f"limits.{key}", f"above the default limit {default_rate_limit(sheet):g} Nm/s")
    if limits.reference_nm > limits.torque_nm:
        raise r.fail("limits.reference_nm", "above limits.torque_nm")
    return {"limits": limits, "data_sheet_torque_nm": ds_torque, "data_sheet_velocity_rad_s": ds_velocity}


def _controller(r: _Reader) -> dict[str, Any]:
    """``[controller]``: the matrices and gains of eqs (16)-(18), by their config field names."""
    C = r.array("controller.C", (4,))
    if not np.array_equal(C, _C):
        raise r.fail("controller.C", "expected [0, 0, 0, 1] (observable canonical form, eq (21))")
    return {"Ad": r.array("controller.Ad", (4, 4)), "Bd": r.array("controller.Bd", (4,)), "C": C,
            "Kd": r.array("controller.Kd", (4,)), "Ld": r.array("controller.Ld", (4,)),
            "Kr_d": r.number("controller.Kr_d")}


def _config_prefilter(r: _Reader, mode: str) -> StateSpaceMatrices | None:
    """``[prefilter]`` as ``(Ad, Bd, Cd, Dd)``; present exactly when there is a feed-forward."""
    if mode == "none":
        if "prefilter" in r.data:
            raise r.fail("prefilter", 'present although feedforward = "none"')
        return None
    if "prefilter" not in r.data:
        raise r.fail("prefilter", f'missing (required with feedforward = "{mode}")')
    Af = r.array("prefilter.Ad")
    if Af.ndim != 2 or Af.shape[0] != Af.shape[1] or Af.shape[0] == 0:
        raise r.fail("prefilter.Ad", "expected a non-empty square matrix")
    n = Af.shape[0]
    return StateSpaceMatrices(Af, r.array("prefilter.Bd", (n,)), r.array("prefilter.Cd", (n,)),
                              r.number("prefilter.Dd"))


def _provenance(r: _Reader) -> Provenance:
    """``[provenance]``: the design's and the model's files with their sha256, the model's datasets."""
    prov = r.get("provenance")
    fields: dict[str, str] = {}
    for key in ("design_file", "model_file"):
        if key in prov:
            fields[key] = r.string(f"provenance.{key}")
    for key in ("design_sha256", "model_sha256"):
        if key in prov:
            fields[key] = r.sha(f"provenance.{key}")
    datasets = []
    raw = prov.get("datasets", [])
    if not isinstance(raw, list):
        raise r.fail("provenance.datasets", "expected an array of tables")
    for i, s in enumerate(raw):
        key = f"provenance.datasets[{i}]"
        if not isinstance(s, dict) or not isinstance(s.get("file"), str) or not isinstance(s.get("sha256"), str):
            raise r.fail(key, "expected file and sha256")
        datasets.append(Source(s["file"], s["sha256"], str(s.get("role", "fit"))))
    return Provenance(datasets=tuple(datasets), **fields)


def _checks(r: _Reader) -> list[Check]:
    """``[[checks]]``: every deployment check, each of which must have passed."""
    checks = []
    raw = r.data.get("checks")
    if not isinstance(raw, list):
        raise r.fail("checks", "expected an array of tables")
    for i, c in enumerate(raw):
        key = f"checks[{i}]"
        try:
            check = Check(name=str(c["name"]), value=float(c["value"]), threshold=float(c["threshold"]),
                          passed=bool(c["passed"]), comparison=str(c["comparison"]), unit=str(c.get("unit", "-")),
                          detail=str(c.get("detail", "")))
        except (KeyError, TypeError, ValueError):
            raise r.fail(key, "expected name, value, threshold, passed and comparison") from None
        if not check.passed:
            raise r.fail(f"{key}.passed", f"check {check.name!r} failed; the config must not be run")
        checks.append(check)
    return checks


def read_config(path: str | os.PathLike) -> ControllerConfig:
    """Read and validate a controller config; errors name the file and the key.

    Raises
    ------
    ConfigError
        Missing or invalid key, a failed check, or content not matching ``sha256``.
    """
    return config_from_dict(load_toml(path, ConfigError), where=f"{path}: ")


# ---------------------------------------------------------------------------
# Deploying a design
# ---------------------------------------------------------------------------
def _option(value: float | None, default: float, name: str) -> float:
    if value is None:
        return default
    if not (math.isfinite(value) and value > 0):
        raise DeployError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def deploy_target(model: JointModel | None, robot_model: str | None = None, joint: int | None = None
                  ) -> tuple[str, int]:
    """The robot model and joint a controller is deployed to: one rule for every caller.

    The model file says which joint it describes; a robot model or joint asked for besides must agree
    with it, and where the model does not say, it must be asked for.

    Parameters
    ----------
    model : JointModel or None
        The model the design came from (None: not found).
    robot_model, joint : optional
        What the user asked for (``--robot-model``, ``--joint``).

    Returns
    -------
    (str, int)
        Robot model and joint.

    Raises
    ------
    DeployError
        When a request contradicts the model, or neither says.

    Examples
    --------
    >>> from iiwa_ident.model import table1_model
    >>> deploy_target(table1_model())
    ('iiwa14', 1)
    >>> deploy_target(table1_model(), joint=2)
    Traceback (most recent call last):
    ...
    iiwa_ident.deploy._checks.DeployError: --joint 2 contradicts the model file (joint 1)
    """
    known_model = model.robot_model if model is not None else None
    known_joint = model.joint if model is not None else None
    if robot_model is not None and known_model is not None and robot_model != known_model:
        raise DeployError(f"--robot-model {robot_model} contradicts the model file ({known_model})")
    if joint is not None and known_joint is not None and joint != known_joint:
        raise DeployError(f"--joint {joint} contradicts the model file (joint {known_joint})")
    robot_model = robot_model or known_model
    joint = joint if joint is not None else known_joint
    if robot_model is None or joint is None:
        raise DeployError("cannot tell the robot model and joint from the design's model file; "
                          "pass --robot-model and --joint")
    return robot_model, int(joint)


def deploy(record: DesignRecord, robot_model: str, joint: int, *, torque_limit: float | None = None,
           rate_limit: float | None = None, velocity_limit: float | None = None,
           reference_rate_limit: float | None = None,
           watchdog_timeout_s: float = RobotSettings.watchdog_timeout_s, design_file: str = "",
           design_sha256: str = "", model: JointModel | None = None) -> ControllerConfig:
    """Check a design and turn it into a controller config.

    Parameters
    ----------
    record : DesignRecord
        The design.
    robot_model : str
        Robot (key of :data:`iiwa_ident.robot.ROBOT_MODELS`).
    joint : int
        Joint 1-7.
    torque_limit : float, optional
        Clamp of the commanded torque [Nm]; default and maximum: the data sheet.
    rate_limit : float, optional
        Clamp of the torque rate [Nm/s]; default and maximum:
        :func:`~iiwa_ident.deploy.default_rate_limit`.
    velocity_limit : float, optional
        Joint speed at which the runtime stops [rad/s]; default and maximum: the data sheet.
    reference_rate_limit : float, optional
        Clamp of the reference rate [Nm/s]; default
        :func:`~iiwa_ident.deploy.default_reference_rate`, maximum the torque-rate default.
    watchdog_timeout_s : float
        Stop after this long without a robot message [s] (default 5 ms).
    design_file, design_sha256 : str
        The design file and its sha256, recorded in the config.
    model : JointModel, optional
        The model the design came from; its dataset sources are recorded.

    Returns
    -------
    ControllerConfig
        With the checks it passed (write it with :func:`write_config`).

    Raises
    ------
    DeployError
        If a check fails (the message lists every failed check) or a setting is invalid.
    """
    sheet = joint_limits(robot_model, joint)
    if not (math.isfinite(watchdog_timeout_s) and SAMPLE_TIME_S <= watchdog_timeout_s):
        raise DeployError(f"watchdog timeout must be at least one cycle, got {watchdog_timeout_s!r} s")
    limits = ControllerLimits(_option(torque_limit, sheet.torque_nm, "--torque-limit"),
                              _option(rate_limit, default_rate_limit(sheet), "--rate-limit"),
                              _option(velocity_limit, sheet.velocity_rad_s, "--velocity-limit"),
                              _option(reference_rate_limit, default_reference_rate(sheet), "--reference-rate"))
    checks = check_design(record, limits, sheet)
    bad = failed_checks(checks)
    if bad:
        raise DeployError("design refused: " + "; ".join(c.describe() for c in bad))
    # The reference clamp keeps the peak command of any rate-limited reference move within the torque limit.
    limits = replace(limits, reference_nm=reference_limit(record, limits.torque_nm, limits.reference_rate_nm_s))
    d = record.design
    datasets = tuple(model.sources) if model is not None else ()
    return ControllerConfig(
        robot_model=robot_model, joint=int(joint), sample_time_s=float(d.sample_time_s), feedforward=d.feedforward,
        Ad=np.array(d.Ad, float), Bd=np.array(d.Bd, float), C=np.array(d.C, float), Kd=np.array(d.Kd, float),
        Ld=np.array(d.Ld, float), Kr_d=float(d.Kr_d),
        prefilter=None if d.ffd is None else tuple(d.ffd),
        filter=record.filter, ripple=record.ripple, KI=float(record.KI), K=float(d.params.K),
        Jl=float(d.params.Jl), limits=limits, data_sheet_torque_nm=float(sheet.torque_nm),
        data_sheet_velocity_rad_s=float(sheet.velocity_rad_s),
        robot=RobotSettings(watchdog_timeout_s=watchdog_timeout_s),
        provenance=Provenance(design_file=design_file, design_sha256=design_sha256,
                              model_file=record.model_file or "", model_sha256=record.model_sha256 or "",
                              datasets=datasets),
        checks=checks, tool_version=record.tool_version)


def config_json(config: ControllerConfig, out: Path) -> dict[str, Any]:
    """The JSON summary of a config written to ``out`` (``iiwa-ident deploy --json``, the pipeline): limits, robot-side settings, sha256 and the checks with their values."""
    lim, r, p = config.limits, config.robot, config.provenance
    return {
        "config": str(out),
        "robot_model": config.robot_model,
        "joint": config.joint,
        "sample_time_s": config.sample_time_s,
        "feedforward": config.feedforward,
        "limits": {"torque_nm": lim.torque_nm, "torque_rate_nm_s": lim.torque_rate_nm_s,
                   "velocity_rad_s": lim.velocity_rad_s, "reference_rate_nm_s": lim.reference_rate_nm_s,
                   "reference_nm": lim.reference_nm,
                   "data_sheet_torque_nm": config.data_sheet_torque_nm,
                   "data_sheet_velocity_rad_s": config.data_sheet_velocity_rad_s},
        "robot": {"control_mode": r.control_mode, "client_command_mode": r.client_command_mode,
                  "send_period_ms": r.send_period_ms, "receive_multiplier": r.receive_multiplier,
                  "watchdog_timeout_s": r.watchdog_timeout_s},
        "sha256": {"config": config.sha256, "design": p.design_sha256 or None, "model": p.model_sha256 or None,
                   "datasets": [{"file": s.file, "sha256": s.sha256, "role": s.role} for s in p.datasets]},
        "checks": [{"name": c.name, "value": finite_or_none(c.value), "threshold": finite_or_none(c.threshold),
                    "comparison": c.comparison, "unit": c.unit, "passed": c.passed} for c in config.checks],
    }
