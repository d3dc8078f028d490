"""Plant effects: what a plant file can switch on in the simulated joint.

Each effect is a small class that declares its parameters and overrides one
or more hooks of :class:`Effect`. The simulator composes the hooks of all
switched-on effects symbolically (casadi), so a new effect is one new
subclass registered with :func:`register_effect` and nothing else changes.

Hooks (all optional; the default contributes nothing):

``deflection(theta_m, P)``
    Transmission deflection f(theta_m) [rad] of eq (5); returns ``(f, df/dtheta_m)``.
``link_torque(theta_l, omega_l, P)``
    Torque acting on the link [Nm] (friction, loads).
``robot_model_torque(theta_m, P)``
    The part of ``link_torque`` the robot's own model knows (gravity); the
    robot adds its negative to every command and its observer subtracts it.
``sensor(tau, t, P)``
    Transform of the joint torque as the torque sensor reads it [Nm]; the
    internal torque loop regulates this reading.
``extra_delay_s()``
    Extra input delay [s] added to ``Td``.
``log_filter()``
    A filter between the torque sensor and the log (:class:`TorqueLogFilter`), or None: the internal loop,
    the robot's observer and the runtime see the unfiltered reading.

``P`` maps each parameter name to a casadi expression (scalar, or a vector
for list parameters), so one compiled simulator serves every parameter value.

The same class supplies the estimators (the way one feature library both
simulates and fits): the effect written as regressors that are linear in
its coefficients, at its nonlinear parameters (period, frequency, smoothing).

``columns(s)``
    The regressor columns for measured :class:`EffectSignals`; each column
    is a list of ``(point, signal)`` pairs sharing one coefficient, the
    point being where the hooks act (:data:`INJECTIONS`).
``coefficients()``
    This effect's values as the coefficients of its columns.
``values_from(coef)``
    The plant-file values of the effect with these coefficients (not range
    checked: a fit may leave the ranges; :meth:`Effect.clip` brings them in).
``reported(coef)``
    The parameters an estimate reports (JSON), from coefficients;
    ``reported(coefficients())`` is what an exact estimate must report.

Summing ``coef_j * column_j`` at each point gives what the hooks give for
the effect's shape (tested for every effect).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from iiwa_ident.errors import PlantError
from iiwa_ident.model import RIPPLE_PERIOD_RAD, Param

__all__ = [
    "Column",
    "EffectSignals",
    "INJECTIONS",
    "own_dataset_columns",
    "Effect",
    "EFFECTS",
    "register_effect",
    "make_effect",
    "TransmissionRipple",
    "LinkFriction",
    "PositionDependentLoad",
    "LinkSpring",
    "TorqueSensorOffset",
    "TorqueSensorScale",
    "TorqueLogFilter",
    "PeriodicDisturbance",
    "InputDelay",
]

#: Points where an effect's regressors act, one per hook:
#: ``deflection`` the deflection f(theta_m) [rad] (``deflection``), ``link`` a torque on the link [Nm]
#: (``link_torque``), ``command`` a torque added to the internal loop's target [Nm] (the negative of
#: ``robot_model_torque``, which the robot adds to every command), ``sensor`` an additive error of the
#: torque reading the internal loop regulates [Nm], ``reading_scale`` the reading times a relative error
#: (``sensor``) and ``logged`` an additive error of the logged reading only, which the loop does not see [Nm]
#: (``logged_offset``); ``reaction`` the deflection's reaction on the motor side, ``tau_J f'(theta_m)`` [Nm]
#: (the transmission's ratio ``1 - f'``; ``deflection``'s second output times the torque).
INJECTIONS = ("deflection", "link", "command", "sensor", "reading_scale", "logged", "reaction")

#: One regressor column: ``(point, signal)`` pairs, all scaled by the same coefficient.
Column = list[tuple[str, np.ndarray]]


@dataclass(frozen=True, kw_only=True)
class EffectSignals:
    """What an effect's regressors are functions of, per sample of one dataset (SI units).

    Attributes
    ----------
    t : numpy.ndarray
        Time [s].
    q_m : numpy.ndarray
        Motor position [rad].
    theta_l, omega_l : numpy.ndarray
        Link position [rad] and velocity [rad/s].
    tau_j : numpy.ndarray
        Measured joint torque [Nm].
    dataset, n_datasets : int
        This dataset's index among ``n_datasets`` fitted together (time-periodic effects have a phase
        of each: recordings share no time origin).
    """

    t: np.ndarray
    q_m: np.ndarray
    theta_l: np.ndarray
    omega_l: np.ndarray
    tau_j: np.ndarray
    dataset: int = 0
    n_datasets: int = 1


def own_dataset_columns(s: EffectSignals, point: str, signals: list[np.ndarray]) -> list[Column]:
    """Columns with coefficients of each dataset's own: ``signals`` in this dataset's slot, zeros elsewhere."""
    zero = np.zeros_like(s.t)
    return [[(point, x if i == s.dataset else zero)] for i in range(s.n_datasets) for x in signals]


def _check_number(where: str, value: Any, lower: float = -math.inf, upper: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PlantError(f"{where}: expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise PlantError(f"{where}: must be finite, got {value}")
    if not lower <= value <= upper:
        raise PlantError(f"{where}: {value:g} is outside [{lower:g}, {upper:g}]")
    return value


class Effect:
    """Base class of plant effects (see the module docstring for the hooks).

    Subclasses set :attr:`name` and :attr:`params` and override hooks.
    Values are validated on construction; ``where`` prefixes error messages.
    """

    #: Name of the effect's table in the plant file, ``[effects.<name>]``.
    name: ClassVar[str] = ""
    #: Scalar parameters.
    params: ClassVar[tuple[Param, ...]] = ()
    #: One-line description.
    summary: ClassVar[str] = ""

    def __init__(self, values: dict[str, Any] | None = None, where: str = "") -> None:
        values = dict(values or {})
        values.pop("enabled", None)
        where = where or f"effects.{self.name}"
        self.values: dict[str, float] = {}
        known = {p.name for p in self.params} | set(self.extra_keys())
        for key in values:
            if key not in known:
                raise PlantError(f"{where}.{key}: unknown key (known: {', '.join(sorted(known))})")
        for p in self.params:
            self.values[p.name] = _check_number(f"{where}.{p.name}", values.get(p.name, p.default), p.lower, p.upper)
        self._init_extra(values, where)

    # -- structure -----------------------------------------------------
    def extra_keys(self) -> tuple[str, ...]:
        """Non-scalar keys a subclass accepts (validated in :meth:`_init_extra`)."""
        return ()

    def _init_extra(self, values: dict[str, Any], where: str) -> None:
        """Validate and store non-scalar keys."""

    def vector(self) -> np.ndarray:
        """All numeric parameters as one flat vector, in :meth:`layout` order."""
        return np.array([self.values[p.name] for p in self.params], dtype=float)

    def layout(self) -> list[tuple[str, int]]:
        """``(name, size)`` of each parameter in :meth:`vector`."""
        return [(p.name, 1) for p in self.params]

    def structure(self) -> tuple:
        """What the compiled code depends on besides parameter values."""
        return (self.name,)

    def to_dict(self) -> dict[str, Any]:
        """Plant-file table of this effect (round-trips through the constructor)."""
        return dict(self.values)

    # -- hooks ---------------------------------------------------------
    def deflection(self, theta_m: ca.SX, P: dict[str, ca.SX]) -> tuple[Any, Any] | None:
        return None

    def link_torque(self, theta_l: ca.SX, omega_l: ca.SX, P: dict[str, ca.SX]) -> Any:
        return None

    def robot_model_torque(self, theta_m: ca.SX, P: dict[str, ca.SX]) -> Any:
        return None

    def sensor(self, tau: ca.SX, t: ca.SX, P: dict[str, ca.SX]) -> ca.SX:
        return tau

    def logged_offset(self) -> float:
        """A constant error of the logged torque reading that the internal loop does not see [Nm]."""
        return 0.0

    def extra_delay_s(self) -> float:
        return 0.0

    def log_filter(self) -> TorqueLogFilter | None:
        return None

    # -- regressors (module docstring) -----------------------------------
    def columns(self, s: EffectSignals) -> list[Column]:
        """Regressor columns at this effect's nonlinear parameters ([]: not linear in anything)."""
        return []

    def coefficients(self) -> np.ndarray:
        """This effect's values as the coefficients of :meth:`columns`."""
        return np.zeros(0)

    def values_from(self, coef: np.ndarray) -> dict[str, Any]:
        """Plant-file values for coefficients of :meth:`columns` (not range checked)."""
        return dict(self.values)

    def reported(self, coef: np.ndarray) -> dict[str, float]:
        """The parameters an estimate reports, from coefficients of :meth:`columns`."""
        return {k: float(v) for k, v in self.values_from(coef).items() if isinstance(v, (int, float))}

    def clip(self, values: dict[str, Any]) -> dict[str, Any]:
        """``values`` with every scalar parameter brought into its range."""
        out = dict(values)
        for p in self.params:
            if p.name in out:
                out[p.name] = float(min(max(float(out[p.name]), p.lower), p.upper))
        return out


#: Registry of effect classes by plant-file name.
EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an :class:`Effect` subclass to :data:`EFFECTS`."""
    if not cls.name:
        raise ValueError("an effect needs a name")
    EFFECTS[cls.name] = cls
    return cls


def make_effect(name: str, values: dict[str, Any] | None = None, where: str = "") -> Effect:
    """Build the effect ``name`` from its plant-file table."""
    if name not in EFFECTS:
        raise PlantError(f"{where or 'effects'}.{name}: unknown effect (known: {', '.join(sorted(EFFECTS))})")
    return EFFECTS[name](values, where or f"effects.{name}")


@register_effect
class TransmissionRipple(Effect):
    """Spatially periodic transmission deflection, eq (5).

    ``theta_j = theta_m - f(theta_m mod rho)`` with f a Fourier series
    ``f(x) = sum_k A_k sin(2 pi k x / rho + phi_k)``, given either as
    ``harmonics = [[A_1, phi_1], [A_2, phi_2], ...]`` [rad, rad] or as a
    lookup table ``lut`` of f sampled at ``x_i = i rho / N`` [rad]. A table is
    turned into its trigonometric interpolant (mean removed: a constant
    deflection is only a torque-sensor offset), truncated at
    ``max_harmonics``. The motor-side reaction uses df/dtheta_m of the same
    series, so it is consistent with the deflection by construction.
    """

    name = "transmission_ripple"
    summary = "position-periodic transmission deflection f(theta_m mod rho), eq (5)"
    params = (Param("period_rad", RIPPLE_PERIOD_RAD, "rad", 1e-4, 1.0, "period rho of the deflection"),)

    def extra_keys(self) -> tuple[str, ...]:
        return ("harmonics", "lut", "max_harmonics")

    def _init_extra(self, values: dict[str, Any], where: str) -> None:
        if ("harmonics" in values) == ("lut" in values):
            raise PlantError(f"{where}: give exactly one of 'harmonics' and 'lut'")
        max_h = int(_check_number(f"{where}.max_harmonics", values.get("max_harmonics", 32), 1, 256))
        if "harmonics" in values:
            rows = values["harmonics"]
            if not isinstance(rows, list) or not rows:
                raise PlantError(f"{where}.harmonics: expected a non-empty list of [amplitude, phase] pairs")
            amp_phase = []
            for i, row in enumerate(rows):
                if not isinstance(row, list) or len(row) != 2:
                    raise PlantError(f"{where}.harmonics[{i}]: expected [amplitude_rad, phase_rad]")
                amp_phase.append((
                    _check_number(f"{where}.harmonics[{i}][0]", row[0], 0.0, 1e-2),
                    _check_number(f"{where}.harmonics[{i}][1]", row[1]),
                ))
            a = np.array([A * math.sin(ph) for A, ph in amp_phase])  # cos coefficients
            b = np.array([A * math.cos(ph) for A, ph in amp_phase])  # sin coefficients
            self.source: dict[str, Any] = {"harmonics": [list(r) for r in amp_phase]}
        else:
            lut = values["lut"]
            if not isinstance(lut, list) or len(lut) < 4:
                raise PlantError(f"{where}.lut: expected a list of at least 4 deflections [rad]")
            table = np.array([_check_number(f"{where}.lut[{i}]", v, -1e-2, 1e-2) for i, v in enumerate(lut)])
            a, b = lut_to_fourier(table, max_h)
            self.source = {"lut": table.tolist(), "max_harmonics": max_h}
        self.cos_coef, self.sin_coef = a, b

    @property
    def n_harmonics(self) -> int:
        return len(self.cos_coef)

    def vector(self) -> np.ndarray:
        return np.concatenate([[self.values["period_rad"]], self.cos_coef, self.sin_coef])

    def layout(self) -> list[tuple[str, int]]:
        n = self.n_harmonics
        return [("period_rad", 1), ("cos_coef", n), ("sin_coef", n)]

    def structure(self) -> tuple:
        return (self.name, self.n_harmonics)

    def to_dict(self) -> dict[str, Any]:
        return {"period_rad": self.values["period_rad"], **self.source}

    def evaluate(self, theta_m: np.ndarray) -> np.ndarray:
        """Numeric f(theta_m) [rad], for tests and plots."""
        x = 2 * np.pi * np.asarray(theta_m, float)[..., None] / self.values["period_rad"]
        k = np.arange(1, self.n_harmonics + 1)
        return np.cos(k * x) @ self.cos_coef + np.sin(k * x) @ self.sin_coef

    @classmethod
    def shape(cls, period_rad: float, n_harmonics: int = 3) -> TransmissionRipple:
        """A zero deflection of ``n_harmonics`` harmonics at ``period_rad`` [rad]: the shape an estimate fits.

        The period is not range checked (an estimate's search may leave the plant file's range).
        """
        effect = cls({"harmonics": [[0.0, 0.0]] * n_harmonics})
        effect.values["period_rad"] = float(period_rad)
        return effect

    def columns(self, s):
        w = 2 * np.pi / self.values["period_rad"]
        x = w * s.q_m
        out = []
        for k in range(1, self.n_harmonics + 1):
            c, sn = np.cos(k * x), np.sin(k * x)
            out.append([("deflection", c), ("reaction", -k * w * sn * s.tau_j)])
            out.append([("deflection", sn), ("reaction", k * w * c * s.tau_j)])
        return out

    def coefficients(self):
        return np.column_stack([self.cos_coef, self.sin_coef]).ravel()

    def values_from(self, coef):
        c = np.asarray(coef, float).reshape(-1, 2)  # A sin(k x + phi) = A sin(phi) cos(k x) + A cos(phi) sin(k x)
        return {"period_rad": self.values["period_rad"],
                "harmonics": [[float(math.hypot(a, b)), float(math.atan2(a, b))] for a, b in c]}

    @staticmethod
    def table(coef: np.ndarray, bins: int) -> np.ndarray:
        """The deflection [rad] of coefficients ``coef`` (cos, sin of each harmonic) at ``bins`` points of a period."""
        c = np.asarray(coef, float).reshape(-1, 2)
        x = 2 * np.pi * np.arange(bins) / bins
        k = np.arange(1, len(c) + 1)
        return np.cos(np.outer(x, k)) @ c[:, 0] + np.sin(np.outer(x, k)) @ c[:, 1]

    def reported(self, coef):
        """``period_rad`` and ``amplitude_rad``, half the peak-to-peak of the deflection."""
        f = self.table(coef, 1024)
        return {"period_rad": float(self.values["period_rad"]), "amplitude_rad": float(np.ptp(f) / 2)}

    def deflection(self, theta_m, P):
        omega = 2 * math.pi / P["period_rad"]
        c1, s1 = ca.cos(omega * theta_m), ca.sin(omega * theta_m)
        ck, sk = c1, s1
        f = 0
        df = 0
        # cos/sin of k*x by the angle-addition recurrence: two trig calls for all harmonics.
        for k in range(self.n_harmonics):
            a, b = P["cos_coef"][k], P["sin_coef"][k]
            f += a * ck + b * sk
            df += (k + 1) * (b * ck - a * sk)
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
        return f, omega * df


def lut_to_fourier(table: np.ndarray, max_harmonics: int) -> tuple[np.ndarray, np.ndarray]:
    """Fourier coefficients of a periodic table sampled at ``x_i = i rho / N``.

    Returns ``(a, b)`` with ``f(x) = sum_k a_k cos(k w x) + b_k sin(k w x)``,
    ``w = 2 pi / rho``; the mean and, for even N, the Nyquist term are dropped.
    """
    n = len(table)
    spec = np.fft.rfft(table) / n
    kmax = min(max_harmonics, (n - 1) // 2)
    a = 2 * spec.real[1:kmax + 1]
    b = -2 * spec.imag[1:kmax + 1]
    return a, b


@register_effect
class LinkFriction(Effect):
    """Coulomb, Stribeck and viscous friction on the link [Nm].

    ``tau = -(F_c + F_s exp(-(omega_l / v_st)^2)) tanh(omega_l / v_s) - F_v omega_l``;
    the tanh with a small ``v_s`` keeps the integrator smooth where
    sign(omega_l) would jump. The Stribeck term (``F_s``, default 0) is the
    extra breakaway friction near standstill; the identification models
    ``F_c`` and ``F_v`` only, so a Stribeck term tests it on a shape it
    does not assume.
    """

    name = "link_friction"
    summary = "link Coulomb + viscous friction"
    params = (
        Param("coulomb_nm", 2.0, "Nm", 0.0, 200.0, "Coulomb friction level"),
        Param("viscous_nms_rad", 1.0, "Nm s/rad", 0.0, 500.0, "viscous coefficient"),
        Param("smoothing_rad_s", 0.005, "rad/s", 1e-5, 1.0, "velocity scale of the Coulomb tanh"),
        Param("stribeck_nm", 0.0, "Nm", 0.0, 200.0, "extra breakaway friction at standstill F_s"),
        Param("stribeck_velocity_rad_s", 0.05, "rad/s", 1e-4, 10.0, "velocity scale v_st of the Stribeck term"),
    )

    def link_torque(self, theta_l, omega_l, P):
        level = P["coulomb_nm"] + P["stribeck_nm"] * ca.exp(-(omega_l / P["stribeck_velocity_rad_s"]) ** 2)
        return -level * ca.tanh(omega_l / P["smoothing_rad_s"]) - P["viscous_nms_rad"] * omega_l

    def columns(self, s):
        # Coulomb and viscous only: the Stribeck term's velocity scale makes it nonlinear.
        w = s.omega_l
        return [[("link", -np.tanh(w / self.values["smoothing_rad_s"]))], [("link", -w)]]

    def coefficients(self):
        return np.array([self.values["coulomb_nm"], self.values["viscous_nms_rad"]])

    def values_from(self, coef):
        return {"coulomb_nm": float(coef[0]), "viscous_nms_rad": float(coef[1]),
                "smoothing_rad_s": self.values["smoothing_rad_s"]}

    def reported(self, coef):
        return {"coulomb_nm": float(coef[0]), "viscous_nms_rad": float(coef[1])}


@register_effect
class PositionDependentLoad(Effect):
    """Position-dependent load ``A sin(theta_l + phi) + c`` on the link (gravity on joints 2, 4, 6).

    ``compensated`` is the fraction the robot's own model knows (1: gravity
    of a correctly configured robot, which the robot compensates and its
    observer removes; 0: an unknown payload). A second harmonic
    ``A2 sin(2 theta_l + phi2)`` (default 0) stands for a load that is not
    exactly a sinusoid (an offset centre of mass on a tilted axis, a cable);
    the robot's model does not know it and the identification does not fit
    it.
    """

    name = "position_dependent_load"
    summary = "gravity-like load A sin(theta_l + phi) + c"
    params = (
        Param("amplitude_nm", 10.0, "Nm", -1000.0, 1000.0, "load amplitude A"),
        Param("phase_rad", 0.0, "rad", -10.0, 10.0, "phase phi"),
        Param("constant_nm", 0.0, "Nm", -1000.0, 1000.0, "constant load c"),
        Param("compensated", 1.0, "1", 0.0, 1.0, "fraction known to the robot's model"),
        Param("harmonic2_nm", 0.0, "Nm", -1000.0, 1000.0, "amplitude A2 of the second harmonic"),
        Param("harmonic2_phase_rad", 0.0, "rad", -10.0, 10.0, "phase phi2 of the second harmonic"),
    )

    def link_torque(self, theta_l, omega_l, P):
        return (P["amplitude_nm"] * ca.sin(theta_l + P["phase_rad"]) + P["constant_nm"]
                + P["harmonic2_nm"] * ca.sin(2 * theta_l + P["harmonic2_phase_rad"]))

    def robot_model_torque(self, theta_m, P):
        return P["compensated"] * (P["amplitude_nm"] * ca.sin(theta_m + P["phase_rad"]) + P["constant_nm"])

    def columns(self, s):
        # A sin(theta + phi) = A cos(phi) sin(theta) + A sin(phi) cos(theta) on the link; the robot's
        # compensation of the known fraction c enters the loop's target with the opposite sign.
        th, tm = s.theta_l, s.q_m
        return [[("link", np.sin(th))], [("link", np.cos(th))], [("command", np.sin(tm))], [("command", np.cos(tm))]]

    def coefficients(self):
        A, ph, c = self.values["amplitude_nm"], self.values["phase_rad"], self.values["compensated"]
        a, b = A * math.cos(ph), A * math.sin(ph)
        return np.array([a, b, -c * a, -c * b])

    def values_from(self, coef):
        """Amplitude >= 0, phase in (-pi, pi], compensated fraction in [0, 1] (1 when the data do not show it)."""
        a, b = float(coef[0]), float(coef[1])
        norm = a * a + b * b
        comp = 1.0 if norm == 0 or (coef[2] == 0 and coef[3] == 0) else -(a * coef[2] + b * coef[3]) / norm
        return {"amplitude_nm": math.hypot(a, b), "phase_rad": math.atan2(b, a),
                "compensated": float(np.clip(comp, 0.0, 1.0))}

    def reported(self, coef):
        v = self.values_from(coef)
        return {"amplitude_nm": v["amplitude_nm"], "phase_rad": v["phase_rad"]}


@register_effect
class LinkSpring(Effect):
    """A torque of the link position: ``-k (theta_l - theta_0) - kappa theta_l^2`` [Nm].

    Cables and hoses along the arm act as a spring on the joints they cross, on any axis (gravity loads only
    those whose axis is not vertical); the robot's model does not know it. Its curvature ``kappa`` (about the
    joint's zero, default 0) is the next term of a cable's torque over a wide travel; ``theta_0`` is where the
    straight part is zero. Over a travel of a radian or more the straight line is told from gravity's sine by
    its shape; over a short one the two look alike, and a curvature looks like gravity's cosine on any travel.
    """

    name = "link_spring"
    summary = "spring torque -k (theta_l - theta_0) - kappa theta_l^2 on the link (cables, hoses)"
    params = (
        Param("stiffness_nm_rad", 4.0, "Nm/rad", -1000.0, 1000.0, "stiffness k"),
        Param("rest_rad", 0.0, "rad", -10.0, 10.0, "rest angle theta_0 of the link (of the straight part)"),
        Param("curvature_nm_rad2", 0.0, "Nm/rad^2", -1000.0, 1000.0, "curvature kappa about the joint's zero"),
    )

    def link_torque(self, theta_l, omega_l, P):
        return -P["stiffness_nm_rad"] * (theta_l - P["rest_rad"]) - P["curvature_nm_rad2"] * theta_l * theta_l

    def columns(self, s):
        # -k theta_l + k theta_0 - kappa theta_l^2: the slope and the torque at theta_l = 0, and the curvature.
        return [[("link", -s.theta_l)], [("link", np.ones_like(s.theta_l))], [("link", -s.theta_l ** 2)]]

    def coefficients(self):
        k = self.values["stiffness_nm_rad"]
        return np.array([k, k * self.values["rest_rad"], self.values["curvature_nm_rad2"]])

    def values_from(self, coef):
        """The rest angle is the torque at zero over the stiffness (0 without a stiffness)."""
        k, c = float(coef[0]), float(coef[1])
        return {"stiffness_nm_rad": k, "rest_rad": c / k if k != 0 else 0.0,
                "curvature_nm_rad2": float(coef[2]) if len(coef) > 2 else 0.0}


@register_effect
class TorqueSensorOffset(Effect):
    """Offset of the joint torque sensor [Nm]: ``offset + drift t`` in the reading the internal torque loop
    regulates, and ``logged`` in the logged reading only.

    Where a robot's loop takes its feedback is not published: an offset the loop sees shows in the torque
    response to a command as ``(1 - G_c)`` of itself (the loop drives the true torque away by it); one on
    the logged reading only shows whole. The drift (default 0; thermal, over minutes) is a shape the
    identification does not fit: it assumes a constant offset.
    """

    name = "torque_sensor_offset"
    summary = "torque-sensor offset"
    params = (
        Param("offset_nm", 0.5, "Nm", -50.0, 50.0, "added to the reading the internal loop regulates"),
        Param("drift_nm_s", 0.0, "Nm/s", -1.0, 1.0, "slow drift of the offset"),
        Param("logged_nm", 0.0, "Nm", -50.0, 50.0, "added to the logged reading only"),
    )

    def sensor(self, tau, t, P):
        return tau + P["offset_nm"] + P["drift_nm_s"] * t

    def logged_offset(self):
        return float(self.values["logged_nm"])

    def columns(self, s):
        # The constant offset where the loop sees it and where it does not; a drift is another shape.
        return [[("sensor", np.ones_like(s.t))], [("logged", np.ones_like(s.t))]]

    def coefficients(self):
        return np.array([self.values["offset_nm"], self.values["logged_nm"]])

    def values_from(self, coef):
        return {"offset_nm": float(coef[0]), "logged_nm": float(coef[1])}

    def reported(self, coef):
        """``offset_nm``: the whole offset of the logged reading; ``logged_nm``: the part the loop does not see."""
        return {"offset_nm": float(coef[0] + coef[1]), "logged_nm": float(coef[1])}


@register_effect
class TorqueSensorScale(Effect):
    """Scale error of the joint torque sensor: reading = scale * torque."""

    name = "torque_sensor_scale"
    summary = "torque-sensor scale error"
    params = (Param("scale", 1.02, "1", 0.5, 2.0, "reading per true torque"),)

    def sensor(self, tau, t, P):
        return P["scale"] * tau

    def columns(self, s):
        # reading - tau = (s - 1) tau = ((s - 1) / s) reading: the column is the reading itself.
        return [[("reading_scale", s.tau_j)]]

    def coefficients(self):
        return np.array([(self.values["scale"] - 1.0) / self.values["scale"]])

    def values_from(self, coef):
        return {"scale": 1.0 / (1.0 - float(coef[0]))}


def _delay_taps(delay_s: float, dt: float) -> tuple[int, float]:
    """A delay [s] as whole samples and the fraction of one more (a whole number up to rounding has none)."""
    n, frac = divmod(delay_s / dt, 1.0)
    if frac > 1.0 - 1e-9:
        return int(n) + 1, 0.0
    return int(n), 0.0 if frac < 1e-9 else float(frac)


@functools.lru_cache(maxsize=256)
def _log_filter_coefficients(cutoff_hz: float, order: float, damping: float, delay_s: float, dt: float
                             ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(b, a)`` of :class:`TorqueLogFilter`, ``a`` as long as ``b`` (cached: a simulation asks for them every
    sample)."""
    from scipy import signal as _signal

    if order == 0.0:  # the delayed samples of an input linear between them: two taps round the delay
        n, frac = _delay_taps(delay_s, dt)
        b = [0.0] * n + [1.0 - frac, frac]
        return tuple(b), (1.0,) + (0.0,) * (len(b) - 1)
    w = 2.0 * math.pi * cutoff_hz
    if order == 1.0:  # the first-order hold's closed form (a fit asks for a new cut-off at every step)
        p = math.exp(-w * dt)
        g = (1.0 - p) / (w * dt)
        return (1.0 - g, g - p), (1.0, -p)
    den = [1.0, 2.0 * damping * w, w * w]
    num, den_d, _ = _signal.cont2discrete(([den[-1]], den), dt, method="foh")
    num, den_d = np.ravel(num), np.ravel(den_d)
    return tuple(float(x) for x in num / den_d[0]), tuple(float(x) for x in den_d / den_d[0])


@register_effect
class TorqueLogFilter(Effect):
    """A low-pass or a delay between the joint-torque sensor and the log (a driver's filter, e.g. a ROS state
    topic's, or a late time stamp).

    ``order`` 1: one first-order stage at ``cutoff_hz``. ``order`` 2: the second order
    ``w^2 / (s^2 + 2 damping w s + w^2)`` with ``w = 2 pi cutoff_hz``: ``damping`` 1 is two equal first-order
    stages, 0.71 a Butterworth filter (whose gain is 1/sqrt(2) at the cut-off). ``order`` 0: a pure delay of
    ``delay_s`` (no cut-off; ``exp(-s delay_s)``). The continuous filter is discretised at the logging rate for
    an input linear between samples (:meth:`coefficients_at`; the delay interpolates linearly between the two
    samples round it), started at rest on the first sample. Only the logged ``tau_j`` passes it: the internal
    torque loop, the robot's external-torque observer and a controller the runtime runs use the unfiltered
    reading.
    """

    name = "torque_log_filter"
    summary = "low-pass or delay of the logged torque (a driver's filter; the robot's loop does not see it)"
    params = (
        Param("cutoff_hz", 12.0, "Hz", 0.1, 500.0, "cut-off of each first-order stage (order 2: the pair's "
              "natural frequency; order 0: none)"),
        Param("order", 1.0, "1", 0.0, 2.0, "order of the filter (1 or 2; 0: a pure delay)"),
        Param("damping", 1.0, "1", 0.3, 1.0, "damping ratio of the second order (1: two equal first-order "
              "stages; 0.71: Butterworth)"),
        Param("delay_s", 0.0, "s", 0.0, 1.0, "the pure delay of order 0"),
    )

    def _init_extra(self, values: dict[str, Any], where: str) -> None:
        order = self.values["order"]
        if order not in (0.0, 1.0, 2.0):
            raise PlantError(f"{where}.order: 0 (a pure delay), 1 or 2, got {order:g}")
        if order != 2.0 and self.values["damping"] != 1.0:
            raise PlantError(f"{where}.damping: only a second-order filter has a damping ratio, got "
                             f"{self.values['damping']:g} with order {order:g}")
        if order == 0.0 and "cutoff_hz" in values:
            raise PlantError(f"{where}.cutoff_hz: a pure delay (order 0) has no cut-off")
        if (order == 0.0) != (self.values["delay_s"] > 0.0):
            raise PlantError(f"{where}.delay_s: " + ("a pure delay (order 0) needs a delay above 0" if order == 0.0
                                                      else f"only a pure delay (order 0) has one, got order {order:g}"))

    def log_filter(self) -> TorqueLogFilter:
        return self

    def reported(self, coef):
        """``order`` with what the order has: ``cutoff_hz`` (orders 1, 2), ``damping`` (2), ``delay_s`` (0)."""
        return self.to_dict()

    def to_dict(self) -> dict[str, Any]:
        """The plant-file table with the keys of its order only (it round-trips through the constructor)."""
        keys = {0.0: ("order", "delay_s"), 1.0: ("cutoff_hz", "order"), 2.0: ("cutoff_hz", "order", "damping")}
        return {k: self.values[k] for k in keys[self.values["order"]]}

    @property
    def lag_s(self) -> float:
        """The low-frequency lag [s]: ``1/w`` (first order), ``2 damping / w`` (second), the delay (order 0)."""
        if self.values["order"] == 0.0:
            return float(self.values["delay_s"])
        w = 2.0 * math.pi * float(self.values["cutoff_hz"])
        return (2.0 * float(self.values["damping"]) if self.values["order"] == 2.0 else 1.0) / w

    def coefficients_at(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(b, a)`` of the whole filter at the sample period ``dt`` [s]: the continuous filter, exact for an
        input linear between samples (first-order hold), so that it lags as the continuous filter does at any
        rate."""
        b, a = self._coefficients(dt)
        return np.array(b), np.array(a)

    def _coefficients(self, dt: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        return _log_filter_coefficients(float(self.values["cutoff_hz"]), float(self.values["order"]),
                                        float(self.values["damping"]), float(self.values["delay_s"]), float(dt))

    def apply(self, x: np.ndarray, dt: float) -> np.ndarray:
        """The filtered signal of ``x`` sampled every ``dt`` [s] along its first axis (at rest on ``x[0]``; a
        matrix's columns each filtered)."""
        from scipy import signal as _signal

        y = np.asarray(x, float)
        if not len(y):
            return y
        if self.values["order"] == 0.0:  # the two taps by index (a long delay is many taps of a filter)
            n, frac = _delay_taps(float(self.values["delay_s"]), dt)
            k = np.arange(len(y))
            return (1.0 - frac) * y[np.maximum(k - n, 0)] + frac * y[np.maximum(k - n - 1, 0)]
        b, a = self.coefficients_at(dt)
        return _signal.lfilter(b, a, y, axis=0, zi=np.multiply.outer(_signal.lfilter_zi(b, a), y[0]))[0]

    def frequency_response(self, f_hz: np.ndarray, dt: float) -> np.ndarray:
        """The sampled filter's response at ``f_hz`` [Hz] for the sample period ``dt`` [s]."""
        b, a = self.coefficients_at(dt)
        z1 = np.exp(-2j * np.pi * np.asarray(f_hz, float) * dt)
        return np.polyval(b[::-1], z1) / np.polyval(a[::-1], z1)

    def step(self, state: list[float] | None, x: float, dt: float) -> tuple[list[float], float]:
        """One sample of :meth:`apply`: the new state (the transposed direct form's) and the output."""
        b, a = self._coefficients(dt)
        if state is None:  # at rest on x (the filter's gain at zero frequency is 1)
            state = [0.0] * (len(a) - 1)
            for i in range(len(state) - 1, -1, -1):
                state[i] = (b[i + 1] - a[i + 1]) * x + (state[i + 1] if i + 1 < len(state) else 0.0)
        y = b[0] * x + state[0]
        new = [b[i + 1] * x - a[i + 1] * y + (state[i + 1] if i + 1 < len(state) else 0.0)
               for i in range(len(state))]
        return new, y


@register_effect
class PeriodicDisturbance(Effect):
    """Time-periodic disturbance on the torque sensor (mains hum).

    Second and third harmonics (default 0) stand for a hum that is not a pure
    sinusoid (a rectifier's or a PWM's); the diagnosis fits the fundamental.
    """

    name = "periodic_disturbance"
    summary = "time-periodic torque-sensor disturbance"
    params = (
        Param("amplitude_nm", 0.2, "Nm", 0.0, 50.0, "amplitude"),
        Param("frequency_hz", 50.0, "Hz", 0.01, 499.0, "frequency"),
        Param("phase_rad", 0.0, "rad", -10.0, 10.0, "phase at t = 0"),
        Param("harmonic2_nm", 0.0, "Nm", 0.0, 50.0, "amplitude of the second harmonic"),
        Param("harmonic2_phase_rad", 0.0, "rad", -10.0, 10.0, "phase of the second harmonic at t = 0"),
        Param("harmonic3_nm", 0.0, "Nm", 0.0, 50.0, "amplitude of the third harmonic"),
        Param("harmonic3_phase_rad", 0.0, "rad", -10.0, 10.0, "phase of the third harmonic at t = 0"),
    )

    def columns(self, s):
        """The fundamental, with an amplitude and phase of each dataset's own (recordings share no time origin)."""
        return self.harmonic_columns(s, 1)

    def harmonic_columns(self, s: EffectSignals, k: int) -> list[Column]:
        """Columns of the k-th harmonic at the effect's frequency, per dataset."""
        w = 2 * np.pi * k * self.values["frequency_hz"] * (s.t - s.t[0])
        return own_dataset_columns(s, "sensor", [np.sin(w), np.cos(w)])

    def coefficients(self):
        A, ph = self.values["amplitude_nm"], self.values["phase_rad"]
        return np.array([A * math.cos(ph), A * math.sin(ph)])

    def values_from(self, coef):
        """Amplitude: the median over datasets; phase: the first dataset's."""
        c = np.asarray(coef, float).reshape(-1, 2)
        amp, phase = np.hypot(c[:, 0], c[:, 1]), np.arctan2(c[:, 1], c[:, 0])
        amp = amp[amp > 0]
        return {"amplitude_nm": float(np.median(amp)) if len(amp) else 0.0,
                "frequency_hz": self.values["frequency_hz"], "phase_rad": float(phase[0])}

    def reported(self, coef):
        v = self.values_from(coef)
        return {"frequency_hz": v["frequency_hz"], "amplitude_nm": v["amplitude_nm"]}

    def sensor(self, tau, t, P):
        w = 2 * math.pi * P["frequency_hz"] * t
        return (tau + P["amplitude_nm"] * ca.sin(w + P["phase_rad"])
                + P["harmonic2_nm"] * ca.sin(2 * w + P["harmonic2_phase_rad"])
                + P["harmonic3_nm"] * ca.sin(3 * w + P["harmonic3_phase_rad"]))


@register_effect
class InputDelay(Effect):
    """Extra input delay on top of the model's ``Td`` [s]."""

    name = "input_delay"
    summary = "extra input delay"
    params = (Param("extra_s", 0.001, "s", 0.0, 0.05, "added to Td"),)

    def extra_delay_s(self) -> float:
        return self.values["extra_s"]
