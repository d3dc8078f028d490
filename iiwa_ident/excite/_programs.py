"""Experiment programs besides the chirp.

constant_velocity
    Client-side velocity tracking (torque mode) or a position reference
    (position mode), back and forth at several speeds: the dynamic ripple
    identification of section III.B.
quasi_static
    Constant commanded torque while an external agent moves the link slowly;
    records the external link-position reference (static method, Fig. 6).
hand_guided
    A human arm (impedance to a hand trajectory) moves the link; the command
    is zero or ``kappa * tau_ext`` from the F/T reference (Fig. 7, section V.C).
step, sine
    Torque references for tracking tests (Figs. 8-9).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite._runner import ClientState, Experiment
from iiwa_ident.references import sine, square
from iiwa_ident.robot import Command, RobotInterface
from iiwa_ident.sim import ImpedanceAgent

__all__ = ["ConstantVelocity", "QuasiStatic", "HandGuided", "StepTorque", "SineTorque", "trapezoid_profile"]


class TrapezoidProfile(NamedTuple):
    """Position [rad], velocity [rad/s] and acceleration [rad/s^2] references of :func:`trapezoid_profile`."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray


def trapezoid_profile(q_start: float, moves: list[tuple[float, float]], accel: float, dt: float,
                      pause_s: float = 0.2) -> TrapezoidProfile:
    """Position, velocity and acceleration references of point-to-point moves.

    Parameters
    ----------
    q_start : float
        Start position [rad].
    moves : list of (target [rad], speed [rad/s])
        Each move accelerates at ``accel`` [rad/s^2] to ``speed``, cruises and
        decelerates to rest at the target (triangular if too short to cruise).
    dt : float
        Sample time [s].
    pause_s : float
        Rest between moves [s].
    """
    q_parts, v_parts, a_parts = [np.array([q_start])], [np.zeros(1)], [np.zeros(1)]
    q = q_start
    for target, speed in moves:
        dist = abs(target - q)
        sgn = 1.0 if target >= q else -1.0
        vpk = min(speed, math.sqrt(dist * accel))
        t_acc = vpk / accel
        t_cruise = max(0.0, (dist - vpk * t_acc) / vpk) if vpk > 0 else 0.0
        total = 2 * t_acc + t_cruise
        t = np.arange(1, int(math.ceil(total / dt)) + 1) * dt
        t = np.minimum(t, total)
        a = np.where(t < t_acc, accel, np.where(t < t_acc + t_cruise, 0.0, -accel))
        v = np.where(t < t_acc, accel * t, np.where(t < t_acc + t_cruise, vpk, np.maximum(0.0, accel * (total - t))))
        s = np.where(t < t_acc, 0.5 * accel * t ** 2,
                     np.where(t < t_acc + t_cruise, 0.5 * vpk * t_acc + vpk * (t - t_acc),
                              dist - 0.5 * accel * (total - t) ** 2))
        q_parts += [q + sgn * s, np.full(int(pause_s / dt), target)]
        v_parts += [sgn * v, np.zeros(int(pause_s / dt))]
        a_parts += [sgn * a, np.zeros(int(pause_s / dt))]
        q = target
    return TrapezoidProfile(np.concatenate(q_parts), np.concatenate(v_parts), np.concatenate(a_parts))


class _Profiled(Experiment):
    """An experiment following precomputed references sampled at the robot's cycle."""

    _dt: float  #: the robot's cycle [s], set by _setup
    _q: np.ndarray  #: the position reference [rad], one sample per cycle

    def _setup(self, dt: float) -> None:
        raise NotImplementedError

    def _ref(self, t: float) -> int:
        return min(int(round(t / self._dt)), len(self._q) - 1)


class ConstantVelocity(_Profiled):
    """Back-and-forth moves at constant speeds.

    Parameters
    ----------
    velocities_rad_s : list of float
        Cruise speeds, each run in both directions [rad/s].
    range_rad : float
        Travel, centred on the start position [rad].
    repeats : int
        Back-and-forth passes per speed.
    mode : "torque" or "position"
        Torque mode: the client tracks the profile with a PD and inertia
        feed-forward; position mode: the robot's position controller does.
    accel_rad_s2 : float
        Acceleration of the profile [rad/s^2].
    inertia : float
        Link inertia for the feed-forward [kg m^2] (Table I by default).
    kp, kd : float
        Client tracking gains [Nm/rad], [Nm s/rad].
    """

    name = "constant_velocity"

    def __init__(self, velocities_rad_s=(0.3, 0.6, 1.2), range_rad: float = 1.0, repeats: int = 1,
                 mode: str = "torque", accel_rad_s2: float = 4.0, inertia: float = 5.6,
                 kp: float = 400.0, kd: float = 80.0) -> None:
        self.velocities = [float(v) for v in velocities_rad_s]
        if not self.velocities or any(v <= 0 for v in self.velocities):
            raise IiwaIdentError("constant_velocity: speeds must be positive")
        if range_rad <= 0 or repeats < 1 or accel_rad_s2 <= 0:
            raise IiwaIdentError("constant_velocity: range, repeats and acceleration must be positive")
        if mode not in ("torque", "position"):
            raise IiwaIdentError(f"constant_velocity: mode must be 'torque' or 'position', got {mode!r}")
        self.range_rad, self.repeats, self.mode = range_rad, repeats, mode
        self.accel, self.inertia, self.kp, self.kd = accel_rad_s2, inertia, kp, kd
        self._setup(1e-3)

    def _setup(self, dt: float) -> None:
        self._dt = dt
        half = self.range_rad / 2
        moves = [(half, self.velocities[0])]
        for v in self.velocities:
            moves += [(-half, v), (half, v)] * self.repeats
        moves.append((0.0, self.velocities[0]))
        self._q, self._v, self._a = trapezoid_profile(0.0, moves, self.accel, dt)
        self.duration_s = len(self._q) * dt

    def check(self, robot: RobotInterface) -> None:
        self._setup(robot.sample_time_s)
        vmax = max(self.velocities)
        if vmax > 0.9 * robot.limits.velocity_rad_s:
            raise IiwaIdentError(f"constant_velocity: {vmax} rad/s exceeds 90% of the joint's speed limit "
                                 f"{robot.limits.velocity_rad_s:.3f} rad/s")
        if self.range_rad / 2 > robot.limits.position_rad - math.radians(10):
            raise IiwaIdentError(f"constant_velocity: range {self.range_rad} rad is too large for this joint")

    def command(self, s: ClientState) -> Command:
        i = self._ref(s.t)
        q_ref = s.q0 + self._q[i]
        if self.mode == "position":
            return Command(q_cmd=q_ref)
        tau = self.inertia * self._a[i] + self.kd * (self._v[i] - s.v) + self.kp * (q_ref - s.q)
        return Command(tau_c=tau)

    def attrs(self) -> dict:
        return {"velocity_rad_s": np.array(self.velocities), "range_rad": self.range_rad, "repeats": self.repeats,
                "mode": self.mode, "accel_rad_s2": self.accel, "duration_s": self.duration_s}


class QuasiStatic(_Profiled):
    """Constant commanded torques while an external agent moves the link slowly.

    Parameters
    ----------
    torques_nm : list of float
        Commanded loads, one back-and-forth pass each [Nm].
    velocity_rad_s : float
        Speed of the external agent [rad/s].
    range_rad : float
        Travel of each pass [rad].
    agent_stiffness, agent_damping : float
        Impedance of the simulated external drive [Nm/rad], [Nm s/rad].
    """

    name = "quasi_static"

    def __init__(self, torques_nm=(2.0, 5.0, 10.0), velocity_rad_s: float = 0.01, range_rad: float = 0.06,
                 agent_stiffness: float = 20000.0, agent_damping: float = 2000.0) -> None:
        self.torques = [float(x) for x in torques_nm]
        if not self.torques:
            raise IiwaIdentError("quasi_static: give at least one torque")
        if velocity_rad_s <= 0 or range_rad <= 0:
            raise IiwaIdentError("quasi_static: speed and range must be positive")
        self.velocity, self.range_rad = velocity_rad_s, range_rad
        self.agent_stiffness, self.agent_damping = agent_stiffness, agent_damping
        self._setup(1e-3)

    def _setup(self, dt: float) -> None:
        self._dt = dt
        moves = []
        for _ in self.torques:
            moves += [(self.range_rad, self.velocity), (0.0, self.velocity)]
        self._q, self._v, _ = trapezoid_profile(0.0, moves, 10 * self.velocity, dt, pause_s=0.5)
        # Which load is commanded when: each load owns one back-and-forth pass.
        n = len(self._q)
        self._load = np.repeat(self.torques, int(math.ceil(n / len(self.torques))))[:n]
        self.duration_s = n * dt

    def check(self, robot: RobotInterface) -> None:
        self._setup(robot.sample_time_s)
        if max(abs(t) for t in self.torques) > robot.limits.torque_nm:
            raise IiwaIdentError("quasi_static: a commanded torque exceeds the joint's torque limit")

    def command(self, s: ClientState) -> Command:
        return Command(tau_c=float(self._load[self._ref(s.t)]))

    def agent(self, q0: float):
        t_grid = np.arange(len(self._q)) * self._dt
        return ImpedanceAgent(t_grid, q0 + self._q, self._v, self.agent_stiffness, self.agent_damping)

    def attrs(self) -> dict:
        return {"torque_nm": np.array(self.torques), "velocity_rad_s": self.velocity, "range_rad": self.range_rad,
                "duration_s": self.duration_s}


class HandGuided(Experiment):
    """A human arm moves the link; the command is ``kappa * tau_ext_ref``.

    The arm is an impedance (stiffness, damping) to a smooth random hand
    trajectory, a sum of sines between 0.15 and 0.8 Hz scaled to the peak
    speed and kept within ``range_rad``.

    Parameters
    ----------
    duration_s : float
        Duration [s].
    kappa : float
        Outer-loop gain on the F/T reference (0: zero commanded torque).
    peak_speed_rad_s : float
        Peak speed of the hand trajectory [rad/s].
    range_rad : float
        Largest excursion of the hand from the start [rad].
    arm_stiffness, arm_damping : float
        Human arm impedance [Nm/rad], [Nm s/rad].
    seed : int
        Seed of the hand trajectory.
    """

    name = "hand_guided"

    def __init__(self, duration_s: float = 20.0, kappa: float = 0.0, peak_speed_rad_s: float = 1.0,
                 range_rad: float = 0.8, arm_stiffness: float = 300.0, arm_damping: float = 40.0,
                 seed: int = 0) -> None:
        if duration_s <= 0 or peak_speed_rad_s <= 0 or range_rad <= 0:
            raise IiwaIdentError("hand_guided: duration, speed and range must be positive")
        self.duration_s, self.kappa = duration_s, kappa
        self.peak_speed, self.range_rad = peak_speed_rad_s, range_rad
        self.arm_stiffness, self.arm_damping, self.seed = arm_stiffness, arm_damping, seed
        rng = np.random.default_rng(seed)
        self._f = np.array([0.15, 0.33, 0.55, 0.8]) * rng.uniform(0.9, 1.1, 4)
        self._ph = rng.uniform(0, 2 * np.pi, 4)
        w = 2 * np.pi * self._f
        t = np.linspace(0, duration_s, 20001)
        base = np.sin(np.outer(t, w) + self._ph) @ (1 / w)
        dbase = np.cos(np.outer(t, w) + self._ph) @ np.ones(4)
        centred = base - base[0]
        self._scale = min(peak_speed_rad_s / np.abs(dbase).max(), range_rad / np.abs(centred).max())
        self._offset = base[0]

    def hand(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hand position offset from the start [rad] and velocity [rad/s] at times ``t``."""
        w = 2 * np.pi * self._f
        arg = np.outer(t, w) + self._ph
        # A smooth start: the hand eases in over the first second.
        ramp = np.clip(t, 0, 1.0)
        ease, dease = ramp ** 2 * (3 - 2 * ramp), np.where(t < 1.0, 6 * ramp * (1 - ramp), 0.0)
        pos = self._scale * (np.sin(arg) @ (1 / w) - self._offset)
        vel = self._scale * (np.cos(arg) @ np.ones(len(w)))
        return ease * pos, ease * vel + dease * pos

    def check(self, robot: RobotInterface) -> None:
        if self.peak_speed > 0.9 * robot.limits.velocity_rad_s:
            raise IiwaIdentError("hand_guided: peak speed exceeds 90% of the joint's speed limit")

    def command(self, s: ClientState) -> Command:
        if self.kappa == 0.0:
            return Command(tau_c=0.0)
        if s.meas.tau_ext_ref is None:
            raise IiwaIdentError("hand_guided: kappa != 0 needs the F/T reference (tau_ext_ref)")
        return Command(tau_c=self.kappa * s.meas.tau_ext_ref)

    def agent(self, q0: float):
        t_grid = np.arange(0, self.duration_s + 5.0, 1e-3)
        pos, vel = self.hand(t_grid)
        return ImpedanceAgent(t_grid, q0 + pos, vel, self.arm_stiffness, self.arm_damping)

    def attrs(self) -> dict:
        return {"duration_s": self.duration_s, "kappa": self.kappa, "peak_speed_rad_s": self.peak_speed,
                "range_rad": self.range_rad, "arm_stiffness_nm_rad": self.arm_stiffness,
                "arm_damping_nms_rad": self.arm_damping, "seed": self.seed}


class _TorqueReference(Experiment):
    """Torque reference ``tau_r(t)`` sent as the command, with a weak position hold."""

    hold_stiffness = 30.0
    hold_damping = 10.0
    peak_nm: float  #: the reference's largest magnitude [Nm]

    def reference(self, t: float) -> float:
        raise NotImplementedError

    def command(self, s: ClientState) -> Command:
        return Command(tau_c=self.reference(s.t) - self.hold_stiffness * (s.q - s.q0) - self.hold_damping * s.v)

    def check(self, robot: RobotInterface) -> None:
        if self.peak_nm > robot.limits.torque_nm:
            raise IiwaIdentError(f"{self.name}: reference {self.peak_nm} Nm exceeds the joint's torque limit")


class StepTorque(_TorqueReference):
    """Square-wave torque steps between ``+amplitude`` and ``-amplitude`` (Fig. 8).

    Parameters
    ----------
    amplitude_nm : float
        Step height [Nm].
    period_s : float
        Period of the square wave [s].
    cycles : int
        Number of periods.
    """

    name = "step"

    def __init__(self, amplitude_nm: float = 10.0, period_s: float = 1.0, cycles: int = 3,
                 hold_stiffness: float = 30.0, hold_damping: float = 10.0) -> None:
        if period_s <= 0 or cycles < 1:
            raise IiwaIdentError("step: period and cycles must be positive")
        self.amplitude_nm, self.period_s, self.cycles = amplitude_nm, period_s, cycles
        self.hold_stiffness, self.hold_damping = hold_stiffness, hold_damping
        self.duration_s = period_s * cycles
        self.peak_nm = abs(amplitude_nm)

    def reference(self, t: float) -> float:
        return square(t, self.amplitude_nm, self.period_s)

    def attrs(self) -> dict:
        return {"amplitude_nm": self.amplitude_nm, "period_s": self.period_s, "cycles": self.cycles,
                "duration_s": self.duration_s, "hold_stiffness_nm_rad": self.hold_stiffness}


class SineTorque(_TorqueReference):
    """Sinusoidal torque reference ``A sin(2 pi f t) + bias`` (Fig. 9).

    Parameters
    ----------
    amplitude_nm, frequency_hz, duration_s, bias_nm : float
        Amplitude [Nm], frequency [Hz], duration [s], constant offset [Nm].
    """

    name = "sine"

    def __init__(self, amplitude_nm: float = 5.0, frequency_hz: float = 0.25, duration_s: float = 8.0,
                 bias_nm: float = 0.0, hold_stiffness: float = 30.0, hold_damping: float = 10.0) -> None:
        if frequency_hz <= 0 or duration_s <= 0:
            raise IiwaIdentError("sine: frequency and duration must be positive")
        self.amplitude_nm, self.frequency_hz, self.duration_s = amplitude_nm, frequency_hz, duration_s
        self.bias_nm = bias_nm
        self.hold_stiffness, self.hold_damping = hold_stiffness, hold_damping
        self.peak_nm = abs(amplitude_nm) + abs(bias_nm)

    def reference(self, t: float) -> float:
        return sine(t, self.amplitude_nm, self.frequency_hz, self.bias_nm)

    def attrs(self) -> dict:
        return {"amplitude_nm": self.amplitude_nm, "frequency_hz": self.frequency_hz, "duration_s": self.duration_s,
                "bias_nm": self.bias_nm, "hold_stiffness_nm_rad": self.hold_stiffness}
