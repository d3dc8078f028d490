"""The simulated iiwa joint behind the :class:`~iiwa_ident.robot.RobotInterface`.

Per cycle the robot side does what the real one does between two FRI
messages: the client's command arrives ``Td`` (+ any extra delay) later,
passes the feasibility filter (slew-rate limit, standstill suppression) and
the robot's gravity model into the internal torque loop of eq (1); the
joint of eqs (1)-(5) and the switched-on effects are integrated; and the
robot reports the encoder-quantised motor position, the noisy torque-sensor
reading and its own external-torque estimate of eq (13). The paper's
external references (F/T torque about the joint axis, precision link
position) are reported when the plant fits them.

An external agent (a human arm, an external drive) acts on the link as
``tau_ext = tau + k (pos - theta_l) + d (vel - omega_l)``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from iiwa_ident.model import MomentumObserver
from iiwa_ident.robot import Command, Measurement, RobotInterface
from iiwa_ident.sim._dynamics import INPUTS, OUTPUTS, CycleModel, output_function
from iiwa_ident.sim._plant import Plant, default_plant

__all__ = ["SimulatedJoint", "ExternalAgent", "SimTrace"]

#: An external agent: substep times [s] -> array (n, 5) of
#: (torque [Nm], position [rad], velocity [rad/s], stiffness [Nm/rad], damping [Nm s/rad]).
ExternalAgent = Callable[[np.ndarray], np.ndarray]

_Y = {name: k for k, name in enumerate(OUTPUTS)}


@dataclass
class SimTrace:
    """Signals of a batch run, one entry per cycle (the measurement after each command).

    ``measured`` holds what the robot reports (as in :class:`Measurement`);
    ``hidden`` holds the true internal signals (``theta_l``, ``tau_j`` true,
    ``omega_m``, ...), for evaluation only.
    """

    measured: dict[str, np.ndarray]
    hidden: dict[str, np.ndarray]


class _CommandRow(NamedTuple):
    """One cycle's command as the compiled cycle takes it."""

    tau_cmd: float  #: [Nm]
    q_cmd: float  #: [rad]
    position_mode: float  #: 1.0: the robot's position controller


class SimulatedJoint(RobotInterface):
    """One simulated iiwa joint, commanded once per cycle.

    Parameters
    ----------
    plant : Plant, optional
        The plant (default: :func:`~iiwa_ident.sim.default_plant`).
    seed : int, optional
        Seed of the sensor noise.
    q0 : float
        Initial joint position [rad].
    compile : bool
        Use the C-compiled dynamics (default) or casadi's virtual machine.
    """

    source = "simulation"

    def __init__(self, plant: Plant | None = None, seed: int | None = None, q0: float = 0.0,
                 compile: bool = True) -> None:
        self.plant = plant or default_plant()
        self.joint = self.plant.joint
        self.limits = self.plant.limits
        self.sample_time_s = self.plant.cycle_s
        self.model = CycleModel(self.plant, compile=compile)
        self._outputs = output_function(self.plant)
        M = self.plant.substeps
        h = self.sample_time_s / M
        delay = self.plant.dynamics["Td"] + sum(e.extra_delay_s() for e in self.plant.effects)
        # The delay is realised to the nearest substep (0.1 ms at the defaults).
        self.delay_substeps = int(round(delay / h))
        self.seed = seed
        self.q0 = float(q0)
        # A constant error of the logged reading that the internal loop does not see [Nm].
        self._logged_nm = sum(e.logged_offset() for e in self.plant.effects)
        # A filter between the sensor and the log: after the robot's observer, on the logged torque only.
        self._log_filter = next((f for f in (e.log_filter() for e in self.plant.effects) if f is not None), None)
        self.agent: ExternalAgent | None = None
        self._started = False
        self._tau_prev = 0.0  #: the last torque command, through the feasibility filter [Nm]

    # -- set-up ----------------------------------------------------------
    def set_agent(self, agent: ExternalAgent | None) -> None:
        """Attach (or detach with None) an external agent acting on the link."""
        self.agent = agent

    def describe(self) -> dict:
        return {"robot_model": self.plant.robot_model, "joint": self.joint, "compiled": self.model.compiled}

    def truth(self) -> dict:
        """The plant parameters and switched-on effects (for a dataset's ``/truth``)."""
        return self.plant.to_dict()

    def _initial_state(self) -> np.ndarray:
        """Standstill in static equilibrium at ``q0`` (torque control suppressed)."""
        d = self.plant.dynamics
        theta_m = self.q0
        f = float(self._outputs(theta_m, theta_m, 0.0, self.model.p)[0])
        # The joint carries the static link torque of the effects; the robot holds the motor (held = 1).
        theta_l = theta_m - f
        for _ in range(20):  # fixed point of K (theta_m - f - theta_l) = -tau_link(theta_l)
            load = float(self._outputs(theta_m, theta_l, 0.0, self.model.p)[4])
            theta_l = theta_m - f + load / d["K"]
        return np.array([theta_m, 0.0, theta_l, 0.0, 1.0, 1.0, theta_m])

    # -- inputs of one cycle ------------------------------------------------
    def _cycle_inputs(self, k0: int, n: int, commands: np.ndarray, first: int = 0) -> np.ndarray:
        """Input rows of cycles ``k0 .. k0+n-1``.

        ``commands`` is (m, 3) rows ``(tau_cmd, q_cmd, position_mode)`` of the
        client's cycles ``first .. first+m-1``; before the first command the
        robot holds still (zero torque command, torque control suppressed).
        """
        M = self.plant.substeps
        T = self.sample_time_s
        nin = len(INPUTS)
        sub = k0 * M + np.arange(n * M)  # global substep numbers
        idx = (sub - self.delay_substeps) // M  # which client command acts at each substep
        rows = np.zeros((n * M, nin))
        valid = idx >= 0
        rows[valid, 0:3] = commands[idx[valid] - first]
        rows[~valid, 1] = self.q0
        if self.agent is not None:
            rows[:, 3:8] = self.agent(sub * (T / M))
        U = np.empty((n, 1 + nin * M))
        U[:, 0] = (k0 + np.arange(n)) * T
        U[:, 1:] = rows.reshape(n, nin * M)
        return U

    def _feasible(self, tau: float, previous: float) -> float:
        """The feasibility filter's slew limit on a torque command, one cycle after ``previous`` [Nm]."""
        step = self.plant.internal["slew_rate_nm_s"] * self.sample_time_s
        return previous + min(max(tau - previous, -step), step)

    def _command_row(self, command: Command) -> _CommandRow:
        if command.tau_c is not None:
            self._tau_prev = self._feasible(float(command.tau_c), self._tau_prev)
            return _CommandRow(self._tau_prev, 0.0, 0.0)
        self._tau_prev = 0.0
        assert command.q_cmd is not None  # a Command holds a torque or a position
        return _CommandRow(0.0, float(command.q_cmd), 1.0)

    # -- measurement model ------------------------------------------------
    def _noise(self, n: int) -> np.ndarray:
        return self._rng.standard_normal((n, 3))

    def _measure(self, y: np.ndarray, noise: np.ndarray) -> dict[str, np.ndarray]:
        """Robot-side sensors for output rows ``y`` (n, ny) and noise rows (n, 3)."""
        s = self.plant.sensors
        tick = s["encoder_tick_rad"]
        theta_m = y[:, _Y["theta_m"]]
        q_m = np.round(theta_m / tick) * tick if tick > 0 else theta_m.copy()
        out = {
            "q_m": q_m,
            "tau_j": y[:, _Y["tau_s"]] + self._logged_nm + s["tau_noise_nm"] * noise[:, 0],
        }
        if self.plant.link_encoder:
            out["q_l_ref"] = y[:, _Y["theta_l"]] + s["link_encoder_noise_rad"] * noise[:, 1]
        if self.plant.ft_sensor:
            out["tau_ext_ref"] = y[:, _Y["tau_ext"]] + s["ft_noise_nm"] * noise[:, 2]
        return out

    # -- RobotInterface -----------------------------------------------------
    def start(self) -> Measurement:
        self._rng = np.random.default_rng(self.seed)
        self._x = self._initial_state()
        self._k = 0
        self._tau_prev = 0.0
        self._history: deque = deque(maxlen=self.delay_substeps // self.plant.substeps + 2)
        self._observer = MomentumObserver(self.plant.internal["KI"], self.plant.dynamics["Jl"], self.sample_time_s)
        y0 = self._y0()
        meas = self._measure(y0[None, :], self._noise(1))
        self._q_prev = float(meas["q_m"][0])
        tau_ext = self._observer.update(0.0, float(meas["tau_j"][0]), float(y0[_Y["tau_model"]]))
        self._log_state: list[float] | None = None
        self._log_through_filter(meas)
        self._started = True
        return self._measurement(0.0, meas, tau_ext)

    def _y0(self) -> np.ndarray:
        """Outputs at the initial state, before any command."""
        x = self._x
        f, tau_j, tau_s, tau_model, _ = (float(v) for v in self._outputs(x[0], x[2], 0.0, self.model.p))
        y = np.zeros(len(OUTPUTS))
        y[_Y["theta_m"]], y[_Y["theta_l"]], y[_Y["held"]] = x[0], x[2], x[5]
        y[_Y["tau_j"]], y[_Y["tau_s"]], y[_Y["tau_model"]] = tau_j, tau_s, tau_model
        return y

    def _log_through_filter(self, meas: dict[str, np.ndarray]) -> None:
        """The logged torque of one step through the log filter (in place; nothing without one)."""
        if self._log_filter is not None:
            self._log_state, y = self._log_filter.step(self._log_state, float(meas["tau_j"][0]), self.sample_time_s)
            meas["tau_j"] = np.array([y])

    def _measurement(self, t: float, meas: dict[str, np.ndarray], tau_ext_fri: float) -> Measurement:
        return Measurement(
            t=t,
            q_m=float(meas["q_m"][0]),
            tau_j=float(meas["tau_j"][0]),
            tau_ext_fri=float(tau_ext_fri),
            q_l_ref=float(meas["q_l_ref"][0]) if "q_l_ref" in meas else None,
            tau_ext_ref=float(meas["tau_ext_ref"][0]) if "tau_ext_ref" in meas else None,
        )

    def step(self, command: Command) -> Measurement:
        if not self._started:
            raise RuntimeError("call start() before step()")
        self._history.append(self._command_row(command))
        k = self._k
        # The deque holds the client's commands k-len+1 .. k, all the delay can reach.
        first = k - len(self._history) + 1
        U = self._cycle_inputs(k, 1, np.array(self._history), first)
        self._x, y = self.model.step(self._x, U[0])
        self._k += 1
        meas = self._measure(y[None, :], self._noise(1))
        q = float(meas["q_m"][0])
        velocity = (q - self._q_prev) / self.sample_time_s
        self._q_prev = q
        tau_ext = self._observer.update(velocity, float(meas["tau_j"][0]), float(y[_Y["tau_model"]]))
        self._log_through_filter(meas)
        self._last_y = y
        return self._measurement(self._k * self.sample_time_s, meas, tau_ext)

    @property
    def hidden_state(self) -> dict[str, float]:
        """True internal signals after the last step (for evaluation and tests only)."""
        return {name: float(self._last_y[i]) for i, name in enumerate(OUTPUTS)}

    # -- batch ------------------------------------------------------------
    def run_open_loop(self, tau_c: np.ndarray | None = None, q_cmd: np.ndarray | None = None) -> SimTrace:
        """Run a whole command sequence at once (same result as start + step per command).

        Parameters
        ----------
        tau_c : array, optional
            Torque command per cycle [Nm] (torque mode).
        q_cmd : array, optional
            Position command per cycle [rad] (position mode); give exactly one.

        Returns
        -------
        SimTrace
            ``measured`` has ``t``, ``q_m``, ``tau_j``, ``tau_ext_fri`` and the
            fitted references, including the initial measurement at t = 0, so
            each array is one longer than the command.
        """
        if (tau_c is None) == (q_cmd is None):
            raise ValueError("give exactly one of tau_c and q_cmd")
        cmd = np.asarray(tau_c if tau_c is not None else q_cmd, float)
        n = len(cmd)
        commands = np.zeros((n, 3))
        if tau_c is not None:
            self._tau_prev = 0.0
            for k, tau in enumerate(cmd.tolist()):
                commands[k, 0] = self._tau_prev = self._feasible(tau, self._tau_prev)
        else:
            commands[:, 1] = cmd
            commands[:, 2] = 1.0
        self._rng = np.random.default_rng(self.seed)
        self._x = x0 = self._initial_state()
        y0 = self._y0()
        noise0 = self._noise(1)
        U = self._cycle_inputs(0, n, commands)
        X, Y = self.model.run(x0, U)
        Yall = np.vstack([y0[None, :], Y])
        noise = np.vstack([noise0, self._noise(n)])
        meas = self._measure(Yall, noise)
        T = self.sample_time_s
        velocity = np.concatenate([[0.0], np.diff(meas["q_m"]) / T])
        obs = MomentumObserver(self.plant.internal["KI"], self.plant.dynamics["Jl"], T)
        meas["tau_ext_fri"] = obs.filter(velocity, meas["tau_j"], Yall[:, _Y["tau_model"]])
        if self._log_filter is not None:
            meas["tau_j"] = self._log_filter.apply(meas["tau_j"], T)
        meas["t"] = np.arange(n + 1) * T
        self._x = X[-1]
        hidden = {name: Yall[:, i] for i, name in enumerate(OUTPUTS)}
        return SimTrace(measured=meas, hidden=hidden)
