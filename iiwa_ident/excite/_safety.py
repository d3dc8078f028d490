"""Safety supervision of experiments: joint limits, braking, refusal.

Every experiment command passes :meth:`LimitGuard.filter`: torque commands
are clamped to the joint's torque limit, and the run is stopped (then the
joint braked to rest) before the position, the speed or a position command
would leave the data-sheet range. The position check looks ahead by the
braking distance, so the joint stops inside the range, not at its edge.
"""

from __future__ import annotations

import math

from iiwa_ident.robot import Command, JointLimits, RobotInterface

__all__ = ["LimitGuard"]


class LimitGuard:
    """Supervises one joint against its limits.

    Parameters
    ----------
    limits : JointLimits
        Data-sheet limits.
    position_margin_rad : float
        Keep this far inside the range of motion [rad] (default 5 deg).
    velocity_fraction : float
        Stop above this fraction of the speed limit.
    brake_decel_rad_s2 : float
        Deceleration assumed for the braking distance [rad/s^2].
    brake_damping : float
        Damping of the braking torque ``-d v`` [Nm s/rad].
    """

    def __init__(self, limits: JointLimits, position_margin_rad: float = math.radians(5.0),
                 velocity_fraction: float = 0.95, brake_decel_rad_s2: float = 2.0,
                 brake_damping: float = 60.0) -> None:
        self.limits = limits
        self.q_max = limits.position_rad - position_margin_rad
        self.v_max = velocity_fraction * limits.velocity_rad_s
        self.decel = brake_decel_rad_s2
        self.damping = brake_damping
        self.clamped = 0  # cycles whose torque command was clamped

    def filter(self, cmd: Command, state) -> tuple[Command, str]:
        """Return the command to send and, if the run must stop, why."""
        q, v = state.q, state.v
        position_mode = cmd.q_cmd is not None
        if abs(v) > self.v_max:
            return self._hold(state, position_mode), f"speed {abs(v):.3f} rad/s exceeded {self.v_max:.3f} rad/s"
        q_stop = q + v * abs(v) / (2 * self.decel)
        if abs(q_stop) > self.q_max:
            return self._hold(state, position_mode), (f"position {q:.3f} rad would pass the limit "
                                       f"{math.copysign(self.q_max, q_stop):.3f} rad (incl. margin)")
        if cmd.q_cmd is not None:
            if abs(cmd.q_cmd) > self.q_max:
                return self._hold(state, position_mode), f"position command {cmd.q_cmd:.3f} rad is outside +-{self.q_max:.3f} rad"
            return cmd, ""
        tau = cmd.tau_c if cmd.tau_c is not None else math.nan  # a Command holds a torque or a position
        if not math.isfinite(tau):
            return self._hold(state, position_mode), "torque command is not finite"
        lim = self.limits.torque_nm
        if abs(tau) > lim:
            self.clamped += 1
            return Command(tau_c=math.copysign(lim, tau)), ""
        return cmd, ""

    def _hold(self, state, position_mode: bool) -> Command:
        if position_mode:
            return Command(q_cmd=state.q)
        return Command(tau_c=self._brake_torque(state.v))

    def _brake_torque(self, v: float) -> float:
        return max(-self.limits.torque_nm, min(self.limits.torque_nm, -self.damping * v))

    def brake(self, robot: RobotInterface, state, position_mode: bool = False, max_time_s: float = 2.0) -> str:
        """Bring the joint to rest after a stop; returns a note if it did not settle."""
        dt = robot.sample_time_s
        q_prev, v = state.q, state.v
        for _ in range(int(max_time_s / dt)):
            cmd = Command(q_cmd=q_prev) if position_mode else Command(tau_c=self._brake_torque(v))
            meas = robot.step(cmd)
            v = 0.8 * v + 0.2 * (meas.q_m - q_prev) / dt
            q_prev = meas.q_m
            if abs(v) < 0.01:
                return ""
        return f"joint still moving at {v:.3f} rad/s after braking for {max_time_s} s"
