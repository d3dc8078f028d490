"""Reference tasks of the FRI runtime: what the deployed controller is asked to track.

A task gives the reference torque ``tau_r`` [Nm] of each cycle from the
time since the start and what the runtime knows (:class:`TaskInput`). The
runtime then limits its rate and size (``limits.reference_rate_nm_s``,
``limits.reference_nm`` of the controller config) before the controller
sees it. :func:`make_task` builds one from the ``iiwa-ident run`` options.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from iiwa_ident._defaults import TASKS  # one definition, light for the CLI's help
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.references import exponential_sweep, odd_lines, odd_multisine, sine, square

__all__ = ["TaskInput", "Task", "ZeroTask", "ConstantTask", "StepTask", "SineTask", "ChirpTask", "MultisineTask",
           "KappaTask", "TASKS", "make_task"]


@dataclass(slots=True)
class TaskInput:
    """What a task may use in a cycle.

    The runtime updates one instance in place every cycle (no allocation in
    the 1 kHz loop): read it during :meth:`Task.reference`, do not keep it.

    Attributes
    ----------
    t : float
        Time since the start of the run [s].
    theta_j : float
        Joint position of eq (8) [rad].
    tau_ext : float
        The external torque of the run's source [Nm]: the runtime's estimate of
        eq (14) (improved observer, spatially filtered), KUKA's estimate, or the
        F/T sensor's torque about the joint's axis (``iiwa-ident run --tau-ext``).
    tau_j : float
        The measured joint torque relative to its value at the start [Nm].
    """

    t: float
    theta_j: float
    tau_ext: float
    tau_j: float = 0.0


class Task(ABC):
    """A reference program; subclasses set :attr:`name` and implement :meth:`reference`."""

    #: Name on the command line and in the log.
    name: str = ""
    #: Set by a task that has finished (the reason): the runtime ramps out and ends the run.
    done: str = ""

    @abstractmethod
    def reference(self, s: TaskInput) -> float:
        """Reference torque tau_r [Nm] for this cycle."""

    def attrs(self) -> dict[str, float | str]:
        """Parameters recorded in the log's ``/experiment`` attributes."""
        return {"task": self.name}

    def result_attrs(self) -> dict:
        """What the task found, added to the log's attributes when the run ends."""
        return {}


class ZeroTask(Task):
    """tau_r = 0: the additive controller makes the joint transparent (it cancels residual torque)."""

    name = "zero"

    def reference(self, s: TaskInput) -> float:
        return 0.0


@dataclass
class ConstantTask(Task):
    """tau_r = amplitude [Nm]."""

    amplitude_nm: float
    name = "constant"

    def reference(self, s: TaskInput) -> float:
        return self.amplitude_nm

    def attrs(self) -> dict[str, float | str]:
        return {"task": self.name, "amplitude_nm": self.amplitude_nm}


@dataclass
class StepTask(Task):
    """A square wave between -amplitude and +amplitude [Nm], ``period_s`` [s], starting at +amplitude."""

    amplitude_nm: float
    period_s: float = 2.0
    name = "step"

    def reference(self, s: TaskInput) -> float:
        return square(s.t, self.amplitude_nm, self.period_s)

    def attrs(self) -> dict[str, float | str]:
        return {"task": self.name, "amplitude_nm": self.amplitude_nm, "period_s": self.period_s}


@dataclass
class SineTask(Task):
    """tau_r = amplitude sin(2 pi f t) [Nm] (the paper's tests: 5 Nm at 0.25 Hz, 15 Nm at 25 Hz)."""

    amplitude_nm: float
    frequency_hz: float
    name = "sine"

    def reference(self, s: TaskInput) -> float:
        return sine(s.t, self.amplitude_nm, self.frequency_hz)

    def attrs(self) -> dict[str, float | str]:
        return {"task": self.name, "amplitude_nm": self.amplitude_nm, "frequency_hz": self.frequency_hz}


@dataclass
class ChirpTask(Task):
    """Exponential sweep of tau_r from f0 to f1 [Hz] over ``sweep_s`` [s], then repeated."""

    amplitude_nm: float
    f0_hz: float
    f1_hz: float
    sweep_s: float
    name = "chirp"

    def reference(self, s: TaskInput) -> float:
        return self.amplitude_nm * exponential_sweep(s.t % self.sweep_s, self.f0_hz, self.f1_hz, self.sweep_s)

    def attrs(self) -> dict[str, float | str]:
        return {"task": self.name, "amplitude_nm": self.amplitude_nm, "f0_hz": self.f0_hz, "f1_hz": self.f1_hz,
                "sweep_s": self.sweep_s}


@dataclass
class MultisineTask(Task):
    """A periodic random-phase odd multisine of tau_r: flat on the odd lines of ``period_s`` [s] within
    ``[f_lo_hz, f_hi_hz]``, peak ``amplitude_nm`` [Nm] (crest factor reduced), phases drawn from ``seed``.

    The closed loop's frequency response on the robot: every period repeats exactly, so its spectrum
    averages over periods (:mod:`iiwa_ident.excite._multisine` for the open-loop experiment). The period is
    tabulated once at the loop's ``sample_time_s``; the cycle only looks it up.
    """

    amplitude_nm: float
    f_lo_hz: float
    f_hi_hz: float
    period_s: float
    sample_time_s: float = 1e-3
    seed: int = 0
    name = "multisine"
    _table: list[float] = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        n = int(round(self.period_s / self.sample_time_s))
        lines = odd_lines(n, 1.0 / self.sample_time_s, self.f_lo_hz, self.f_hi_hz)
        if len(lines) == 0:
            raise IiwaIdentError(f"task: no odd line of a {self.period_s:g} s period between {self.f_lo_hz:g} and "
                                 f"{self.f_hi_hz:g} Hz below the Nyquist frequency")
        x = odd_multisine(n, lines, np.random.default_rng(self.seed))
        self._table = [float(v) for v in self.amplitude_nm * x]  # plain floats for the cycle

    def reference(self, s: TaskInput) -> float:
        table = self._table
        return table[int(round(s.t / self.sample_time_s)) % len(table)]

    def attrs(self) -> dict[str, float | str]:
        return {"task": self.name, "amplitude_nm": self.amplitude_nm, "f_lo_hz": self.f_lo_hz,
                "f_hi_hz": self.f_hi_hz, "period_s": self.period_s, "seed": self.seed}


@dataclass
class KappaTask(Task):
    """tau_r = kappa tau_ext (section V.C): the joint amplifies the torque a human applies.

    ``tau_ext`` is the run's source (``iiwa-ident run --tau-ext``: the runtime's
    estimate of eq (14), KUKA's, or an F/T sensor); ``kappa`` = 0 is the
    transparent joint.
    """

    kappa: float
    name = "kappa"

    def reference(self, s: TaskInput) -> float:
        return self.kappa * s.tau_ext

    def attrs(self) -> dict[str, float | str]:
        return {"task": self.name, "kappa": self.kappa}




def _finite(name: str, value: float, positive: bool = False) -> float:
    if not math.isfinite(value) or (positive and value <= 0):
        raise IiwaIdentError(f"task: {name} must be {'positive' if positive else 'finite'}, got {value!r}")
    return float(value)


def make_task(name: str, amplitude_nm: float = 5.0, frequency_hz: float = 0.25, period_s: float = 2.0,
              f1_hz: float = 50.0, sweep_s: float = 20.0, kappa: float = 1.0, sample_time_s: float = 1e-3) -> Task:
    """The task called ``name`` with its parameters (units as in the classes); one-line errors.

    The multisine's band is ``frequency_hz`` to ``f1_hz`` and its period ``period_s``, tabulated at the
    loop's ``sample_time_s`` [s].
    """
    amplitude_nm = _finite("amplitude", amplitude_nm)
    if name == "zero":
        return ZeroTask()
    if name == "constant":
        return ConstantTask(amplitude_nm)
    if name == "step":
        return StepTask(amplitude_nm, _finite("period", period_s, True))
    if name == "sine":
        return SineTask(amplitude_nm, _finite("frequency", frequency_hz, True))
    if name == "chirp":
        f0 = _finite("frequency", frequency_hz, True)
        f1 = _finite("f1", f1_hz, True)
        if f1 <= f0:
            raise IiwaIdentError("task: the chirp's end frequency must exceed its start frequency")
        return ChirpTask(amplitude_nm, f0, f1, _finite("sweep duration", sweep_s, True))
    if name == "multisine":
        f_lo, f_hi = _finite("frequency", frequency_hz, True), _finite("f1", f1_hz, True)
        if f_hi <= f_lo:
            raise IiwaIdentError("task: the multisine's upper frequency (f1) must exceed its lower one")
        return MultisineTask(amplitude_nm, f_lo, f_hi, _finite("period", period_s, True),
                             _finite("sample time", sample_time_s, True))
    if name == "kappa":
        kappa = _finite("kappa", kappa)
        if kappa < 0:
            raise IiwaIdentError("task: kappa must not be negative")
        return KappaTask(kappa)
    raise IiwaIdentError(f"unknown task {name!r} (known: {', '.join(TASKS)})")
