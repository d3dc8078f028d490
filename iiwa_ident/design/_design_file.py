"""The design file: TOML, format version 2, written by ``iiwa-ident design``.

Everything a 1 kHz controller needs, plus what it was designed from::

    format = "iiwa-ident-design"
    format_version = 2
    tool_version = "0.1.0"
    created_utc = "2026-11-21T06:00:00+00:00"
    sample_time_s = 0.001
    feedforward = "reference"          # reference | paper | none (controller module)

    [model]                            # the joint model the design is based on
    file = "model.toml"                # optional: model file and its sha256
    sha256 = "..."
    [model.parameters]                 # SI units
    Jc = { value = 1.03, unit = "kg m^2" }   # ... bc, K, Jl, Td, KI
    [model.ripple]                     # optional: the model's ripple table, eq (5)
    period_rad = 0.01963               # rho: the lookup table's and the spatial filter's
    lut = [...]

    [filter]                           # spatial filter, eqs (10)-(12), at model.ripple.period_rad
    beta = 2.0                         # (the paper's rho without a ripple table)
    v_min_rad_s = 0.2

    [torque_observer]                  # external-torque observer, eq (13)
    KI = 25.0                          # [rad/s]

    [poles]                            # [re, im] pairs
    controller = [[-180.0, 30.0], ...] # continuous [rad/s]
    observer = [[-620.0, 0.0], ...]    # continuous [rad/s]
    builtin = [[-26.7, 143.4], ...]    # built-in controller, continuous [rad/s]
    additive = [...]                   # additive feedback loop, continuous [rad/s] (8)
    additive_discrete = [...]          # the same at 1 kHz, z-plane [-] (8)

    [gains]
    K_fsf = [...]                      # continuous, [s^3, s^2, s, 1]
    L = [...]                          # continuous, [s^-4, s^-3, s^-2, s^-1]
    Kr = 0.9656                        # unit DC gain of the feedback alone (the paper's Kr)
    Kr_c = 0.0                         # gain on tau_r of the continuous controller in this mode
    Kd = [...]                         # discrete gains of eqs (16)-(17)
    Ld = [...]
    Kr_d = 0.0

    [continuous]                       # Padé-delayed eq (4), eqs (19)-(21)
    c1 = 1200.0                        # [1/s]
    c2 = 480000.0                      # [1/s^2]
    A = [[...], ...]
    B = [...]
    C = [0.0, 0.0, 0.0, 1.0]

    [discrete]                         # zero-order hold at sample_time_s
    Ad = [[...], ...]
    Bd = [...]

    [prefilter]                        # F(s) P(s) of eq (22); absent with feedforward = "none"
    natural_frequency_hz = 50.0
    zeta = 1.0
    A = ...; B = ...; C = ...; D = ... # continuous
    Ad = ...; Bd = ...; Cd = ...; Dd = ...   # Tustin at sample_time_s

    [outer_loop]                       # tau_r = kappa tau_ext with a human arm
    arm_stiffness = 300.0              # [Nm/rad]
    arm_damping = 40.0                 # [Nm s/rad]
    arm_inertia = 0.0                  # [kg m^2]
    kappa_limit = 100.0
    kappa_max_builtin = 7.78           # inf: stable up to kappa_limit
    kappa_max_additive = 23.0

Reading validates every key (errors name the file and the key) and checks
that the stored discrete gains place the stored poles, so a hand-edited or
damaged file is refused rather than run.
"""

from __future__ import annotations

import hashlib
import os
import tomllib
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident import tool_version
from iiwa_ident._json import finite_or_none
from iiwa_ident._schema import TableReader
from iiwa_ident._toml import dumps_toml, load_toml, write_atomic
from iiwa_ident.design._additive import FEEDFORWARD_MODES, AdditiveDesign, DesignError, _scaling, check_poles
from iiwa_ident.design._margins import HumanArm, OuterLoopMargins
from iiwa_ident.design._spatial_filter import FilterSettings
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model import PARAMETER_UNITS, JointModel, JointParameters, ParameterError, RippleTable

__all__ = [
    "DESIGN_FORMAT",
    "DESIGN_FORMAT_VERSION",
    "DesignFileError",
    "DesignRecord",
    "make_record",
    "design_to_dict",
    "design_from_dict",
    "write_design",
    "read_design",
    "design_json",
]

DESIGN_FORMAT = "iiwa-ident-design"
DESIGN_FORMAT_VERSION = 2


class DesignFileError(IiwaIdentError):
    """A design file is missing, unreadable or invalid."""


@dataclass(kw_only=True)
class DesignRecord:
    """A design file's content.

    Attributes
    ----------
    design : AdditiveDesign
        The controller (run it with ``record.design.controller()``).
    margins : OuterLoopMargins
        Outer-loop ``kappa_max`` of the built-in and the additive controller.
    KI : float
        External-torque observer gain of eq (13) [rad/s].
    filter : FilterSettings
        Spatial-filter settings.
    ripple : RippleTable or None
        The model's ripple table.
    model_file, model_sha256 : str or None
        The model file the design came from.
    """

    design: AdditiveDesign
    margins: OuterLoopMargins
    KI: float
    filter: FilterSettings = field(default_factory=FilterSettings)
    ripple: RippleTable | None = None
    model_file: str | None = None
    model_sha256: str | None = None
    description: str = ""
    tool_version: str = ""
    created_utc: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))


def make_record(design: AdditiveDesign, margins: OuterLoopMargins, model: JointModel,
                model_path: str | os.PathLike | None = None, filter: FilterSettings | None = None,
                description: str = "") -> DesignRecord:
    """Bundle a design with its model reference and filter settings.

    Parameters
    ----------
    design, margins
        From :func:`~iiwa_ident.design.design_controller` and
        :func:`~iiwa_ident.design.outer_loop_margins`.
    model : JointModel
        The model the design is based on (KI and the ripple table are taken from it).
    model_path : path, optional
        Its file; recorded with its sha256.
    filter : FilterSettings, optional
        The spatial filter's beta and v_min (default: the design's); it works at the ripple table's
        period (:func:`~iiwa_ident.design.filter_period`).
    """
    sha = None
    if model_path is not None:
        sha = hashlib.sha256(Path(model_path).read_bytes()).hexdigest()
    return DesignRecord(design=design, margins=margins, KI=float(model.value("KI")), filter=filter or FilterSettings(),
                        ripple=model.ripple, model_file=None if model_path is None else str(model_path),
                        model_sha256=sha, description=description, tool_version=tool_version())


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------
def _pairs(z: np.ndarray) -> list[list[float]]:
    return [[float(np.real(x)), float(np.imag(x))] for x in np.asarray(z, complex)]


def _mat(m: np.ndarray) -> list:
    return np.asarray(m, float).tolist()


def design_to_dict(record: DesignRecord) -> dict[str, Any]:
    """The TOML mapping of a :class:`DesignRecord` (module docstring)."""
    d = record.design
    out: dict[str, Any] = {
        "format": DESIGN_FORMAT,
        "format_version": DESIGN_FORMAT_VERSION,
        "tool_version": record.tool_version or tool_version(),
        "created_utc": record.created_utc,
    }
    if record.description:
        out["description"] = record.description
    out["sample_time_s"] = float(d.sample_time_s)
    out["feedforward"] = d.feedforward
    model: dict[str, Any] = {}
    if record.model_file:
        model["file"] = record.model_file
    if record.model_sha256:
        model["sha256"] = record.model_sha256
    params = {**d.params.as_dict(), "KI": record.KI}
    model["parameters"] = {k: {"value": float(v), "unit": PARAMETER_UNITS[k]} for k, v in params.items()}
    if record.ripple is not None:
        model["ripple"] = {"period_rad": float(record.ripple.period_rad), "lut": _mat(record.ripple.lut)}
    out["model"] = model
    out["filter"] = {"beta": record.filter.beta, "v_min_rad_s": record.filter.v_min_rad_s}
    out["torque_observer"] = {"KI": record.KI}
    out["poles"] = {
        "controller": _pairs(d.poles), "observer": _pairs(d.observer_poles), "builtin": _pairs(d.builtin_poles),
        "additive": _pairs(d.additive_poles), "additive_discrete": _pairs(d.additive_poles_discrete),
    }
    out["gains"] = {"K_fsf": _mat(d.K_fsf), "L": _mat(d.L), "Kr": float(d.Kr), "Kr_c": float(d.Kr_c),
                    "Kd": _mat(d.Kd), "Ld": _mat(d.Ld), "Kr_d": float(d.Kr_d)}
    out["continuous"] = {"c1": float(d.c1), "c2": float(d.c2), "A": _mat(d.A), "B": _mat(d.B), "C": _mat(d.C)}
    out["discrete"] = {"Ad": _mat(d.Ad), "Bd": _mat(d.Bd)}
    if d.ff is not None and d.ffd is not None:
        out["prefilter"] = {
            "natural_frequency_hz": float(d.prefilter_hz), "zeta": float(d.prefilter_zeta),
            "A": _mat(d.ff[0]), "B": _mat(d.ff[1]), "C": _mat(d.ff[2]), "D": float(d.ff[3]),
            "Ad": _mat(d.ffd[0]), "Bd": _mat(d.ffd[1]), "Cd": _mat(d.ffd[2]), "Dd": float(d.ffd[3]),
        }
    m = record.margins
    out["outer_loop"] = {
        "arm_stiffness": m.arm.stiffness, "arm_damping": m.arm.damping, "arm_inertia": m.arm.inertia,
        "kappa_limit": float(m.kappa_limit), "kappa_max_builtin": float(m.builtin),
        "kappa_max_additive": float(m.additive),
    }
    return out


def write_design(path: str | os.PathLike, record: DesignRecord) -> Path:
    """Write ``record`` atomically (validated by reading back what is written)."""
    text = dumps_toml(design_to_dict(record))
    design_from_dict(tomllib.loads(text), where=f"{path}: ")
    return write_atomic(path, text)


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------
_TOP = {"format", "format_version", "tool_version", "created_utc", "description", "sample_time_s", "feedforward",
        "model", "filter", "torque_observer", "poles", "gains", "continuous", "discrete", "prefilter", "outer_loop"}
_TABLE_KEYS = {
    "model": {"file", "sha256", "parameters", "ripple"},
    "filter": {"beta", "v_min_rad_s"},
    "torque_observer": {"KI"},
    "poles": {"controller", "observer", "builtin", "additive", "additive_discrete"},
    "gains": {"K_fsf", "L", "Kr", "Kr_c", "Kd", "Ld", "Kr_d"},
    "continuous": {"c1", "c2", "A", "B", "C"},
    "discrete": {"Ad", "Bd"},
    "prefilter": {"natural_frequency_hz", "zeta", "A", "B", "C", "D", "Ad", "Bd", "Cd", "Dd"},
    "outer_loop": {"arm_stiffness", "arm_damping", "arm_inertia", "kappa_limit", "kappa_max_builtin",
                   "kappa_max_additive"},
}


class _Reader(TableReader):
    """Typed access to the mapping; every error names the file and the dotted key."""

    error = DesignFileError


def _check_tables(r: _Reader) -> None:
    for key in r.data:
        if key not in _TOP:
            raise r.fail(key, "unknown key")
    for name, allowed in _TABLE_KEYS.items():
        t = r.table(name, required=name != "prefilter")
        for key in t or {}:
            if key not in allowed:
                raise r.fail(f"{name}.{key}", "unknown key")


def _char_poly_close(M: np.ndarray, roots: np.ndarray, rtol: float) -> bool:
    got, want = np.real(np.poly(M)), np.real(np.poly(roots))
    return bool(np.all(np.abs(got - want) <= rtol * np.maximum(1.0, np.abs(want))))


def design_from_dict(data: dict[str, Any], where: str = "") -> DesignRecord:
    """Validate a design-file mapping and build the :class:`DesignRecord`."""
    r = _Reader(data, where)
    r.check_format(DESIGN_FORMAT, DESIGN_FORMAT_VERSION)
    _check_tables(r)
    T = r.number("sample_time_s", positive=True)
    mode = r.string("feedforward")
    if mode not in FEEDFORWARD_MODES:
        raise r.fail("feedforward", f"expected one of {', '.join(FEEDFORWARD_MODES)}, got {mode!r}")
    values, params = _parameters(r)
    model_file, sha = _model_source(r)
    raw_ripple = r.table("model.ripple", required=False)
    ripple = None if raw_ripple is None else RippleTable.from_mapping(raw_ripple, f"{r.where}model.ripple", r.error)
    flt = FilterSettings(r.number("filter.beta", positive=True), r.number("filter.v_min_rad_s", positive=True))
    KI = r.number("torque_observer.KI", positive=True)
    if abs(KI - values["KI"]) > 1e-12 * max(1.0, KI):
        raise r.fail("torque_observer.KI", f"differs from model.parameters.KI ({values['KI']:g})")
    poles = _poles(r, T)
    matrices = _matrices(r)
    _check_placement(r, matrices, poles, T)
    design = AdditiveDesign(
        params=params, sample_time_s=T, feedforward=mode, poles=poles["controller"],
        observer_poles=poles["observer"], builtin_poles=poles["builtin"], additive_poles=poles["additive"],
        additive_poles_discrete=poles["additive_discrete"], **matrices, **_prefilter(r, mode))
    description = data.get("description", "")
    return DesignRecord(design=design, margins=_margins(r), KI=KI, filter=flt, ripple=ripple, model_file=model_file,
                        model_sha256=sha, description=str(description),
                        tool_version=str(data.get("tool_version", "")), created_utc=str(data.get("created_utc", "")))


def _parameters(r: _Reader) -> tuple[dict[str, float], JointParameters]:
    """``model.parameters``: the values by name (KI among them) and the joint's parameters."""
    values: dict[str, float] = {}
    for name, unit in PARAMETER_UNITS.items():
        key = f"model.parameters.{name}"
        entry = r.table(key) or {}
        values[name] = r.number(f"{key}.value", positive=name != "bc", nonneg=True)
        if entry.get("unit", unit) != unit:
            raise r.fail(f"{key}.unit", f"expected {unit!r}, got {entry.get('unit')!r}")
    try:
        return values, JointParameters.from_mapping(values)
    except ParameterError as err:
        raise r.fail("model.parameters", str(err)) from None


def _model_source(r: _Reader) -> tuple[str | None, str | None]:
    """The model's file and its sha256, each None where the design does not record it."""
    model_file = r.get("model.file", required=False)
    sha = r.get("model.sha256", required=False)
    if model_file is not None:
        model_file = r.string("model.file")
    if sha is not None:
        sha = r.string("model.sha256")
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise r.fail("model.sha256", "expected 64 lower-case hex digits")
    return model_file, sha


def _poles(r: _Reader, T: float) -> dict[str, np.ndarray]:
    """``[poles]`` by key; the controller's and the observer's checked as a design's (:func:`check_poles`)."""
    poles = {}
    for key, what in (("controller", "poles"), ("observer", "observer poles")):
        p = r.poles(f"poles.{key}", 4)
        try:
            poles[key] = check_poles(p, what, T)
        except DesignError as err:
            raise r.fail(f"poles.{key}", str(err)) from None
    poles["builtin"] = r.poles("poles.builtin", 2)
    poles["additive"] = r.poles("poles.additive", 8)
    poles["additive_discrete"] = r.poles("poles.additive_discrete", 8)
    return poles


def _matrices(r: _Reader) -> dict[str, Any]:
    """``[continuous]``, ``[discrete]`` and ``[gains]`` as :class:`AdditiveDesign`'s keyword arguments."""
    C = r.array("continuous.C", (4,))
    if not np.array_equal(C, [0.0, 0.0, 0.0, 1.0]):
        raise r.fail("continuous.C", "expected [0, 0, 0, 1] (observable canonical form, eq (21))")
    out: dict[str, Any] = {"A": r.array("continuous.A", (4, 4)), "B": r.array("continuous.B", (4,)), "C": C,
                           "c1": r.number("continuous.c1", positive=True),
                           "c2": r.number("continuous.c2", positive=True),
                           "Ad": r.array("discrete.Ad", (4, 4)), "Bd": r.array("discrete.Bd", (4,))}
    out.update({k: r.array(f"gains.{k}", (4,)) for k in ("K_fsf", "L", "Kd", "Ld")})
    out.update({k: r.number(f"gains.{k}") for k in ("Kr", "Kr_c", "Kr_d")})
    return out


def _check_placement(r: _Reader, m: dict[str, Any], poles: dict[str, np.ndarray], T: float) -> None:
    """The stored gains must place the stored poles (on the well-conditioned scaled state)."""
    S = _scaling(m["A"])
    Si = np.linalg.inv(S)
    A, B, C, Ad, Bd = m["A"], m["B"], m["C"], m["Ad"], m["Bd"]
    checks = [
        ("gains.K_fsf", Si @ (A - np.outer(B, m["K_fsf"])) @ S, poles["controller"]),
        ("gains.L", Si @ (A - np.outer(m["L"], C)) @ S, poles["observer"]),
        ("gains.Kd", Si @ (Ad - np.outer(Bd, m["Kd"])) @ S, np.exp(poles["controller"] * T)),
        ("gains.Ld", Si @ (Ad - np.outer(m["Ld"], C)) @ S, np.exp(poles["observer"] * T)),
    ]
    for key, M, roots in checks:
        if not _char_poly_close(M, roots, 1e-6):
            raise r.fail(key, "does not place the poles stored in [poles] (file edited or damaged?)")


def _prefilter(r: _Reader, mode: str) -> dict[str, Any]:
    """``[prefilter]`` as :class:`AdditiveDesign`'s keyword arguments (none with ``feedforward = "none"``)."""
    if mode == "none":
        if r.table("prefilter", required=False) is not None:
            raise r.fail("prefilter", 'present although feedforward = "none"')
        return {"ff": None, "ffd": None, "prefilter_hz": 0.0, "prefilter_zeta": 0.0}
    if r.table("prefilter", required=False) is None:
        raise r.fail("prefilter", f'missing (required with feedforward = "{mode}")')
    Af = r.square("prefilter.A")
    n = Af.shape[0]
    ff = (Af, r.array("prefilter.B", (n,)), r.array("prefilter.C", (n,)), r.number("prefilter.D"))
    ffd = (r.array("prefilter.Ad", (n, n)), r.array("prefilter.Bd", (n,)), r.array("prefilter.Cd", (n,)),
           r.number("prefilter.Dd"))
    if np.abs(np.linalg.eigvals(ffd[0])).max() >= 1.0:
        raise r.fail("prefilter.Ad", "is not stable")
    return {"ff": ff, "ffd": ffd, "prefilter_hz": r.number("prefilter.natural_frequency_hz", positive=True),
            "prefilter_zeta": r.number("prefilter.zeta", positive=True)}


def _margins(r: _Reader) -> OuterLoopMargins:
    """``[outer_loop]``: the human arm and the design's outer-loop margins."""
    arm = HumanArm(r.number("outer_loop.arm_stiffness", positive=True),
                   r.number("outer_loop.arm_damping", nonneg=True), r.number("outer_loop.arm_inertia", nonneg=True))
    return OuterLoopMargins(
        builtin=r.number("outer_loop.kappa_max_builtin", nonneg=True, allow_inf=True),
        additive=r.number("outer_loop.kappa_max_additive", nonneg=True, allow_inf=True),
        arm=arm, kappa_limit=r.number("outer_loop.kappa_limit", positive=True))


def read_design(path: str | os.PathLike) -> DesignRecord:
    """Read and validate a design file; errors name the file and the key."""
    return design_from_dict(load_toml(path, DesignFileError), where=f"{path}: ")


def design_json(design: AdditiveDesign, margins: OuterLoopMargins) -> dict[str, Any]:
    """The JSON summary of a design (``iiwa-ident design --json``, the pipeline's ``design.json``). Complex numbers as ``[re, im]``; an unbounded ``kappa_max`` is null."""
    def pairs(z):
        return [[float(np.real(x)), float(np.imag(x))] for x in z]

    return {
        "builtin_poles": pairs(design.builtin_poles),
        "poles": pairs(design.poles),
        "observer_poles": pairs(design.observer_poles),
        "K_fsf": [float(x) for x in design.K_fsf],
        "L": [float(x) for x in design.L],
        "Kr": float(design.Kr),
        "Kd": [float(x) for x in design.Kd],
        "Ld": [float(x) for x in design.Ld],
        "Kr_d": float(design.Kr_d),
        "feedforward": design.feedforward,
        "prefilter_hz": design.prefilter_hz if design.ff is not None else None,
        "dc_gain": design.dc_gain(True),
        "additive_poles": pairs(design.additive_poles),
        "sample_time_s": design.sample_time_s,
        "kappa_max": {"builtin": finite_or_none(margins.builtin), "additive": finite_or_none(margins.additive)},
        "arm": {"stiffness": margins.arm.stiffness, "damping": margins.arm.damping, "inertia": margins.arm.inertia},
    }
