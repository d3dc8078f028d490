"""Exponential sine sweep (exponential chirp) and the chirp experiment.

The sweep ``x(t) = sin(2 pi f0 L (exp(t / L) - 1))`` with
``L = T / ln(f1 / f0)`` spends equal time per octave; its instantaneous
frequency is ``f0 exp(t / L)``. Harmonic k of a nonlinear response appears
``L ln k`` earlier than the linear response after deconvolution, which is
what lets the identification separate distortion from the linear part.
"""

from __future__ import annotations

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.excite._runner import ClientState, Experiment
from iiwa_ident.references import exponential_sweep, sweep_rate
from iiwa_ident.robot import Command, RobotInterface

__all__ = ["Chirp"]


class Chirp(Experiment):
    """Torque-commanded exponential chirp with a bias and a weak position hold.

    ``tau_c = bias + A x(t) - k_h (q - q0) - d_h v``: the bias keeps the
    command clear of the standstill threshold (section II.A); the hold is
    far below ``f0`` in bandwidth so it only keeps the link from drifting.

    Parameters
    ----------
    f0_hz, f1_hz : float
        Start and end frequency [Hz].
    duration_s : float
        Sweep duration [s].
    amplitude_nm : float
        Sweep amplitude A [Nm].
    bias_nm : float
        Constant torque added to the sweep [Nm].
    hold_stiffness : float
        Position hold k_h [Nm/rad].
    hold_damping : float
        Velocity damping d_h of the hold [Nm s/rad].
    """

    name = "chirp"

    def __init__(self, f0_hz: float = 0.5, f1_hz: float = 200.0, duration_s: float = 30.0,
                 amplitude_nm: float = 10.0, bias_nm: float = 3.0, hold_stiffness: float = 30.0,
                 hold_damping: float = 10.0) -> None:
        if not 0 < f0_hz < f1_hz:
            raise IiwaIdentError(f"chirp: need 0 < f0 < f1, got f0={f0_hz} Hz, f1={f1_hz} Hz")
        if duration_s <= 0 or amplitude_nm <= 0:
            raise IiwaIdentError("chirp: duration and amplitude must be positive")
        if hold_stiffness < 0 or hold_damping < 0:
            raise IiwaIdentError("chirp: hold stiffness and damping must not be negative")
        self.f0_hz, self.f1_hz, self.duration_s = f0_hz, f1_hz, duration_s
        self.amplitude_nm, self.bias_nm = amplitude_nm, bias_nm
        self.hold_stiffness, self.hold_damping = hold_stiffness, hold_damping
        self._L = sweep_rate(f0_hz, f1_hz, duration_s)

    def check(self, robot: RobotInterface) -> None:
        nyquist = 0.5 / robot.sample_time_s
        if self.f1_hz >= nyquist:
            raise IiwaIdentError(f"chirp: f1 = {self.f1_hz} Hz must be below the Nyquist frequency {nyquist:g} Hz")
        peak = abs(self.bias_nm) + self.amplitude_nm
        if peak > robot.limits.torque_nm:
            raise IiwaIdentError(f"chirp: bias + amplitude = {peak:g} Nm exceeds the joint's torque limit "
                                 f"{robot.limits.torque_nm:g} Nm")

    def command(self, s: ClientState) -> Command:
        tau = (self.bias_nm + self.amplitude_nm * exponential_sweep(s.t, self.f0_hz, self.f1_hz, self.duration_s)
               - self.hold_stiffness * (s.q - s.q0) - self.hold_damping * s.v)
        return Command(tau_c=tau)

    def attrs(self) -> dict:
        return {"sweep": "exponential", "f0_hz": self.f0_hz, "f1_hz": self.f1_hz, "duration_s": self.duration_s,
                "amplitude_nm": self.amplitude_nm, "bias_nm": self.bias_nm, "sweep_rate_s": self._L,
                "hold_stiffness_nm_rad": self.hold_stiffness, "hold_damping_nms_rad": self.hold_damping}
