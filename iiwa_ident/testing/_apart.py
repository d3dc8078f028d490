"""A second data path for judging ``diagnose``: a joint simulated apart from the project's simulator.

The hidden-effect cases of :mod:`iiwa_ident.testing` are drawn and simulated by the project's own
simulator (:mod:`iiwa_ident.sim`), whose effects are the very ones the candidates fit. An estimator tested
only there is judged on its own assumptions. This module writes the joint once more, from the paper's
equations, with its own integrator, its own effects in other shapes and its own experiments:

* eq (1) realised on the motor position the internal controller moves (``theta_m = w + (b_c / K) v``,
  ``v' = e / J_c``, ``w' = v``, ``e = u - tau_s``), the joint position behind the transmission from eq (5),
  eqs (2)-(3) on the link (the deflection's reaction on the motor is left out); classical Runge-Kutta with
  five steps per cycle and the delay rounded to a step;
* friction ``F_c (2/pi) atan(omega / v_s) + F_v omega`` (and a breakaway term ``F_s exp(-|omega| / v_b)``
  in the other shape), a gravity load ``A cos(theta_l + psi)`` that the robot compensates (with a second
  harmonic it does not know, in the other shape), an offset of the reading the loop regulates or, in half
  the draws, of the logged reading only (drifting linearly in the other shape), a sensor scale, a hum
  (with harmonics in the other shape), a ripple of harmonics 1, 2 (and 4 in the other shape), an extra
  delay; and the causes real logs show (:func:`draw_apart_cause_case`): a spring on the link about a rest
  angle (stiffening with the cube of the stretch in the other shape) and a driver's exponential smoothing
  of the logged reading, noise included (two stages in the other shape);
* a linear-sweep chirp under a weak position hold, trapezoidal constant-velocity runs tracked by a
  client PD with feed-forward, and a hand that guides the link through its own impedance; the torque
  noise coloured (first-order autoregressive), the encoder quantised, a pre-roll under the client's
  control before logging starts (no standstill switch).

The truth is returned in the project's terms (candidate names and the parameters a diagnosis reports:
:func:`~iiwa_ident.testing.expected_findings`' conventions), for scoring; the datasets carry
none of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from iiwa_ident.datasets import Dataset

__all__ = ["ApartCase", "CHIRP_AMPLITUDE_NM", "draw_apart_case", "draw_apart_cause_case", "simulate_apart_case"]

CHIRP_AMPLITUDE_NM = 8.0  # the chirp's torque amplitude [Nm], unless a refused fit asks for a stronger one

_T = 1e-3  # robot cycle [s]
_STEPS = 5  # Runge-Kutta steps per cycle
_TICK = 2 * math.pi / 2 ** 20 / 100  # motor-side encoder tick [rad]
_TABLE1 = {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}
_NAMES = ("transmission_ripple", "link_friction", "position_dependent_load", "torque_sensor_offset",
          "torque_sensor_scale", "periodic_disturbance", "input_delay")


@dataclass
class ApartCase:
    """One joint of the second data path: its dynamics, hidden effects (this module's own parameters) and
    what a diagnosis must report for them.

    Attributes
    ----------
    seed : int
    dynamics : dict
        Jc, bc, K, Jl, Td [SI]; Td on the integrator's step.
    effects : dict
        This module's own effect parameters by candidate name.
    expected : dict
        Per hidden effect, the parameters a diagnosis reports (the candidates' conventions).
    reshaped : list of str
        Effects in another shape than the candidate's (named by family, parameters not scored).
    """

    seed: int
    dynamics: dict[str, float]
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    expected: dict[str, dict[str, float]] = field(default_factory=dict)
    reshaped: list[str] = field(default_factory=list)


def draw_apart_case(seed: int, n_effects: int | None = None) -> ApartCase:
    """Draw a joint within 30 % of Table I and 0-2 hidden effects (weights 1:2:2), half in another shape."""
    rng = np.random.default_rng([seed, 42])
    dyn = {k: v * float(rng.uniform(0.7, 1.3)) for k, v in _TABLE1.items()}
    h = _T / _STEPS
    dyn["Td"] = round(dyn["Td"] / h) * h
    n = int(rng.choice([0, 1, 1, 2, 2])) if n_effects is None else n_effects
    names = [str(x) for x in rng.choice(_NAMES, size=n, replace=False)] if n else []
    case = ApartCase(seed, dyn)
    for name in names:
        other = bool(rng.uniform() < 0.5) and name not in ("torque_sensor_scale", "input_delay")
        if other:
            case.reshaped.append(name)
        e: dict[str, Any]
        if name == "transmission_ripple":
            rho = float(rng.uniform(0.01, 0.04))
            a1 = float(rng.uniform(3e-5, 8e-5))
            amps = [a1, float(rng.uniform(0.1, 0.3)) * a1] + ([0.0, float(rng.uniform(0.2, 0.4)) * a1] if other else [])
            e = {"period_rad": rho, "amplitudes": amps, "phases": [float(x) for x in rng.uniform(0, 2 * np.pi, 4)]}
            x = np.linspace(0, 2 * np.pi, 4096, endpoint=False)
            f = sum(a * np.sin((k + 1) * x + p) for k, (a, p) in enumerate(zip(amps, e["phases"])))
            exp = {"period_rad": rho, "amplitude_rad": float(np.ptp(f) / 2)}
        elif name == "link_friction":
            e = {"coulomb_nm": float(rng.uniform(0.5, 5.0)), "viscous_nms_rad": float(rng.uniform(0.5, 4.0)),
                 "smoothing_rad_s": 0.004,
                 "breakaway_nm": 0.0, "breakaway_rad_s": 0.05}
            if other:
                e["breakaway_nm"] = float(rng.uniform(0.3, 0.6)) * e["coulomb_nm"]
                e["breakaway_rad_s"] = float(rng.uniform(0.02, 0.1))
            exp = {"coulomb_nm": e["coulomb_nm"], "viscous_nms_rad": e["viscous_nms_rad"]}
        elif name == "position_dependent_load":
            e = {"amplitude_nm": float(rng.uniform(3.0, 40.0)), "psi_rad": float(rng.uniform(-np.pi, np.pi)),
                 "harmonic2_nm": 0.0, "harmonic2_rad": 0.0}
            if other:
                e["harmonic2_nm"] = float(rng.uniform(0.05, 0.2)) * e["amplitude_nm"]
                e["harmonic2_rad"] = float(rng.uniform(-np.pi, np.pi))
            # A cos(theta + psi) = A sin(theta + psi + pi/2): the candidates' phase.
            phase = (e["psi_rad"] + math.pi / 2 + math.pi) % (2 * math.pi) - math.pi
            exp = {"amplitude_nm": e["amplitude_nm"], "phase_rad": phase}
        elif name == "torque_sensor_offset":
            e = {"offset_nm": float(rng.uniform(0.3, 2.5)) * float(rng.choice([-1, 1])),
                 "drift_nm_s": float(rng.uniform(0.004, 0.012)) * float(rng.choice([-1, 1])) if other else 0.0,
                 "in_loop": bool(rng.uniform() < 0.5)}
            exp = {"offset_nm": e["offset_nm"]}
        elif name == "torque_sensor_scale":
            e = {"scale": 1.0 + float(rng.uniform(0.03, 0.1)) * float(rng.choice([-1, 1]))}
            exp = {"scale": e["scale"]}
        elif name == "periodic_disturbance":
            a = float(rng.uniform(0.1, 0.5))
            e = {"frequency_hz": float(rng.uniform(8.0, 90.0)), "amplitudes": [a],
                 "phase_rad": float(rng.uniform(0, 6))}
            if other:
                e["amplitudes"] += [float(rng.uniform(0.2, 0.4)) * a, float(rng.uniform(0.2, 0.4)) * a]
            exp = {"frequency_hz": e["frequency_hz"], "amplitude_nm": a}
        else:  # input_delay: the model's Td is off
            extra = round(float(rng.uniform(0.001, 0.003)) / h) * h
            e = {"extra_s": extra}
            name, exp = "model_parameters", {"Td_s": dyn["Td"] + extra, "K_nm_rad": dyn["K"], "Jl_kgm2": dyn["Jl"]}
        case.effects[name] = e
        case.expected[name] = exp
    return case


def draw_apart_cause_case(seed: int) -> ApartCase:
    """A link spring or a filter before the log (alternating by seed; half in another shape), alone on every third
    seed, else beside one effect of :func:`draw_apart_case` (not an extra delay, judged elsewhere)."""
    rng = np.random.default_rng([seed, 64])
    case = draw_apart_case(seed, 0 if seed % 3 == 0 else 1)
    if "model_parameters" in case.effects:
        case.effects.pop("model_parameters")
        case.expected.pop("model_parameters")
    name = ("link_spring", "torque_log_filter")[seed % 2]
    other = bool(rng.uniform() < 0.5)
    if name == "link_spring":
        k, rest = float(rng.uniform(2.0, 6.0)), float(rng.uniform(-0.5, 0.5))
        # The other shape: a hose that stiffens, k (1 + (x / 0.6)^2) x for a stretch x (0.6 rad: a third more at 0.35).
        e: dict[str, Any] = {"stiffness_nm_rad": k, "rest_rad": rest, "cubic": 1.0 / 0.6**2 if other else 0.0}
        exp = {"stiffness_nm_rad": k, "rest_rad": rest}
    else:
        fc = float(rng.uniform(8.0, 15.0))
        e = {"cutoff_hz": fc, "stages": 2 if other else 1}
        exp = {"cutoff_hz": fc}
    if other:
        case.reshaped.append(name)
    case.effects[name] = e
    case.expected[name] = exp
    return case


class _Joint:
    """The joint of one case: right-hand side, torques and the robot's own compensation."""

    def __init__(self, case: ApartCase) -> None:
        d = case.dynamics
        self.Jc, self.bc, self.K, self.Jl = d["Jc"], d["bc"], d["K"], d["Jl"]
        fx = case.effects
        self.delay = d["Td"] + fx.get("model_parameters", {}).get("extra_s", 0.0)
        r = fx.get("transmission_ripple")
        self.ripple = None if r is None else (2 * math.pi / r["period_rad"],
                                              [(k + 1, a, p) for k, (a, p) in enumerate(zip(r["amplitudes"],
                                                                                             r["phases"])) if a])
        self.fr = fx.get("link_friction")
        self.load = fx.get("position_dependent_load")
        off = fx.get("torque_sensor_offset", {})
        # An offset the loop does not see is in the logged reading only.
        in_loop = off.get("in_loop", True)
        self.offset_nm, self.drift_nm_s = off.get("offset_nm", 0.0) * in_loop, off.get("drift_nm_s", 0.0)
        self.logged = 0.0 if in_loop else off["offset_nm"]
        self.scale = fx.get("torque_sensor_scale", {"scale": 1.0})["scale"]
        self.hum = fx.get("periodic_disturbance")
        self.spring = fx.get("link_spring")
        self.smoothing = fx.get("torque_log_filter")

    def theta_j(self, theta_m: float) -> float:
        """Eq (5): the joint position behind the transmission."""
        if self.ripple is None:
            return theta_m
        w, terms = self.ripple
        return theta_m - sum(a * math.sin(k * w * theta_m + p) for k, a, p in terms)

    def link_torque(self, th: float, om: float) -> float:
        out = 0.0
        if self.fr is not None:
            s = (2 / math.pi) * math.atan(om / self.fr["smoothing_rad_s"])
            out -= (self.fr["coulomb_nm"] + self.fr["breakaway_nm"] * math.exp(-abs(om) / self.fr["breakaway_rad_s"])) \
                * s + self.fr["viscous_nms_rad"] * om
        if self.load is not None:
            out += self.load["amplitude_nm"] * math.cos(th + self.load["psi_rad"]) \
                + self.load["harmonic2_nm"] * math.sin(2 * th + self.load["harmonic2_rad"])
        if self.spring is not None:
            x = th - self.spring["rest_rad"]
            out -= self.spring["stiffness_nm_rad"] * x * (1.0 + self.spring["cubic"] * x * x)
        return out

    def log(self, reading: np.ndarray) -> np.ndarray:
        """The log of the reading: a driver's exponential smoothing, ``y += a (x - y)`` per cycle with the pole of
        the cut-off, from the first sample (none without)."""
        if self.smoothing is None:
            return reading
        a = 1.0 - math.exp(-2 * math.pi * self.smoothing["cutoff_hz"] * _T)
        y = np.asarray(reading, float)
        for _ in range(int(self.smoothing["stages"])):
            out = np.empty_like(y)
            acc = y[0]
            for i, x in enumerate(y):
                acc += a * (x - acc)
                out[i] = acc
            y = out
        return y

    def compensation(self, theta_m: float) -> float:
        """What the robot adds to the loop's target: its model of the gravity load (not the harmonic), on the
        motor position it measures."""
        if self.load is None:
            return 0.0
        return -self.load["amplitude_nm"] * math.cos(theta_m + self.load["psi_rad"])

    def reading(self, tau_j: float, t: float) -> float:
        out = self.scale * tau_j + self.offset_nm + self.drift_nm_s * t
        if self.hum is not None:
            w = 2 * math.pi * self.hum["frequency_hz"]
            out += sum(a * math.sin((k + 1) * (w * t + self.hum["phase_rad"]))
                       for k, a in enumerate(self.hum["amplitudes"]))
        return out

    def rhs(self, x: list[float], t: float, tau_cmd: float, ext: tuple[float, float, float, float]
            ) -> list[float]:
        w, v, th, om = x
        theta_m = w + self.bc / self.K * v
        theta_j = self.theta_j(theta_m)
        tau_j = self.K * (theta_j - th)
        e = tau_cmd + self.compensation(theta_m) - self.reading(tau_j, t)
        kh, dh, qh, vh = ext
        tau_ext = kh * (qh - th) + dh * (vh - om)
        return [v, e / self.Jc, om,
                (tau_j + tau_ext + self.link_torque(th, om)) / self.Jl]


def _simulate(case: ApartCase, client, hand, n: int, seed: int, preroll: int = 500) -> dict[str, np.ndarray]:
    """Run ``preroll`` + ``n`` cycles; ``client(k, q, v, q0)`` gives the torque command of cycle k,
    ``hand(t)`` the hand's (stiffness, damping, position, velocity) or None."""
    j = _Joint(case)
    rng = np.random.default_rng([seed, 7])
    h = _T / _STEPS
    lag = int(round(j.delay / h))
    # At rest with the link at 0: the spring holds the load (the pre-roll settles the rest).
    tau0 = -j.link_torque(0.0, 0.0)
    x = [tau0 / j.K, 0.0, 0.0, 0.0]
    total = preroll + n
    cmds = np.zeros(total)
    rows = np.zeros((total, 5))  # theta_m, tau reading, theta_l, tau_ext, time
    q_prev = q0 = None
    pending = [0.0] * (lag + _STEPS)  # substep commands in flight
    for k in range(total):
        t = (k - preroll) * _T
        theta_m = x[0] + j.bc / j.K * x[1]
        tau_j = j.K * (j.theta_j(theta_m) - x[2])
        ext = hand(t) if hand is not None else (0.0, 0.0, 0.0, 0.0)
        rows[k] = (theta_m, j.reading(tau_j, t) + j.logged, x[2], ext[0] * (ext[2] - x[2]) + ext[1] * (ext[3] - x[3]),
                   t)
        q = round(rows[k, 0] / _TICK) * _TICK
        q0 = q if q0 is None else q0
        vel = 0.0 if q_prev is None else (q - q_prev) / _T
        q_prev = q
        cmds[k] = client(k - preroll, q, vel, q0)
        pending.extend([cmds[k]] * _STEPS)
        for s in range(_STEPS):
            u = pending[len(pending) - _STEPS + s - lag]
            ts = t + s * h
            e1 = hand(ts) if hand is not None else ext
            e2 = hand(ts + h / 2) if hand is not None else ext
            e3 = hand(ts + h) if hand is not None else ext
            k1 = j.rhs(x, ts, u, e1)
            k2 = j.rhs([a + h / 2 * b for a, b in zip(x, k1)], ts + h / 2, u, e2)
            k3 = j.rhs([a + h / 2 * b for a, b in zip(x, k2)], ts + h / 2, u, e2)
            k4 = j.rhs([a + h * b for a, b in zip(x, k3)], ts + h, u, e3)
            x = [a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        del pending[:-(lag + _STEPS)]
    rows, cmds = rows[preroll:], cmds[preroll:]
    white = rng.standard_normal((n, 3))
    colored = np.empty(n)
    acc = 0.0
    for i in range(n):  # AR(1) torque noise, 0.025 Nm RMS
        acc = 0.4 * acc + math.sqrt(1 - 0.16) * white[i, 0]
        colored[i] = acc
    return {"t": rows[:, 4] - rows[0, 4], "q_m": np.round(rows[:, 0] / _TICK) * _TICK,
            "tau_j": j.log(rows[:, 1] + 0.025 * colored), "tau_c": cmds, "q_l_ref": rows[:, 2] + 1e-6 * white[:, 1],
            "tau_ext_ref": rows[:, 3] + 0.05 * white[:, 2]}


class _Moves(NamedTuple):
    """Position [rad], velocity [rad/s] and acceleration [rad/s^2] references."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray


def _trapezoids(speeds: tuple[float, ...], travel: float, accel: float) -> _Moves:
    """Position, velocity, acceleration of back-and-forth moves over ``travel`` centred on the start."""
    q, out_q, out_v, out_a = 0.0, [0.0], [0.0], [0.0]
    targets = [(travel / 2, speeds[0])] + [(s * travel / 2, v) for v in speeds for s in (-1, 1)] + [(0.0, speeds[0])]
    for goal, vmax in targets:
        dist = goal - q
        sgn = math.copysign(1.0, dist)
        vpk = min(vmax, math.sqrt(abs(dist) * accel))
        ta = vpk / accel
        tc = (abs(dist) - vpk * ta) / vpk
        for i in range(1, int((2 * ta + tc) / _T) + 1):
            t = i * _T
            if t < ta:
                a, vel, pos = accel, accel * t, accel * t * t / 2
            elif t < ta + tc:
                a, vel, pos = 0.0, vpk, vpk * ta / 2 + vpk * (t - ta)
            else:
                r = max(2 * ta + tc - t, 0.0)
                a, vel, pos = -accel, accel * r, abs(dist) - accel * r * r / 2
            out_q.append(q + sgn * pos)
            out_v.append(sgn * vel)
            out_a.append(sgn * a)
        q = goal
        out_q += [q] * 150
        out_v += [0.0] * 150
        out_a += [0.0] * 150
    return _Moves(np.array(out_q), np.array(out_v), np.array(out_a))


class _Hold(NamedTuple):
    """The hand's impedance and where it holds the link."""

    stiffness: float  #: [Nm/rad]
    damping: float  #: [Nm s/rad]
    position: float  #: [rad]
    velocity: float  #: [rad/s]


def simulate_apart_case(case: ApartCase, chirp_s: float = 10.0, amplitude_nm: float = CHIRP_AMPLITUDE_NM
                        ) -> list[Dataset]:
    """The case's chirp (``amplitude_nm``), constant-velocity run and hand-guided run (see the module
    docstring)."""
    s = case.seed * 10
    f0, f1, amp, bias, kh, dh = 0.5, 120.0, amplitude_nm, 2.0, 40.0, 12.0

    def chirp(k, q, v, q0):
        t = max(k, 0) * _T
        phase = 2 * math.pi * (f0 * t + (f1 - f0) * t * t / (2 * chirp_s))
        return (bias + amp * math.sin(phase) if k >= 0 else bias) - kh * (q - q0) - dh * v

    n = int(round(chirp_s / _T))
    out = [Dataset(signals=_simulate(case, chirp, None, n, s + 1), experiment="chirp", source="simulation", joint=1,
                   sample_rate_hz=1 / _T,
                   experiment_attrs={"sweep": "linear", "f0_hz": f0, "f1_hz": f1, "duration_s": chirp_s,
                                     "amplitude_nm": amp, "bias_nm": bias})]
    speeds, travel = (0.3, 0.8), 0.6
    qr, vr, ar = _trapezoids(speeds, travel, 3.0)

    def cv(k, q, v, q0):
        i = min(max(k, 0), len(qr) - 1)
        return 5.0 * ar[i] + 350.0 * (q0 + qr[i] - q) + 70.0 * (vr[i] - v)

    out.append(Dataset(signals=_simulate(case, cv, None, len(qr), s + 2), experiment="constant_velocity",
                       source="simulation", joint=1, sample_rate_hz=1 / _T,
                       experiment_attrs={"velocity_rad_s": np.array(speeds), "range_rad": travel, "mode": "torque"}))
    rng = np.random.default_rng([case.seed, 3])
    lines = [(2 * math.pi * float(f), float(p), a) for f, p, a in
             zip(np.array([0.2, 0.37, 0.6]) * rng.uniform(0.9, 1.1, 3), rng.uniform(0, 2 * np.pi, 3),
                 (0.2, 0.08, 0.04))]

    def hand(t):
        if t < 0:
            return _Hold(250.0, 35.0, 0.0, 0.0)
        pos = sum(a * (math.sin(w * t + p) - math.sin(p)) for w, p, a in lines)
        vel = sum(a * w * math.cos(w * t + p) for w, p, a in lines)
        return _Hold(250.0, 35.0, pos, vel)

    out.append(Dataset(signals=_simulate(case, lambda k, q, v, q0: 0.0, hand, 6000, s + 3), experiment="hand_guided",
                       source="simulation", joint=1, sample_rate_hz=1 / _T, experiment_attrs={"duration_s": 6.0}))
    return out
