"""The outer loop's gain margin measured live: ``tau_r = kappa tau_ext`` with kappa raised stepwise.

Section V.C closes ``tau_r = kappa tau_ext`` around the joint's torque controller while a person holds
the arm, and raises kappa until the loop shows instabilities (the built-in controller at 4.6, the
additive one stable through 15). :class:`KappaSweep` is that experiment as a runtime task: kappa
``start, start*factor, ...`` up to ``max``, each held ``hold_s``, and after every cycle a judgement
of the joint torque the run measures (:class:`InstabilityDetector`):

* the joint torque is band-passed (``band_hz``: above the hand's own motion, below the sensor noise's
  bulk) and its RMS taken over windows of ``window_s``;
* **growing oscillation**: the RMS rose over ``rise_windows`` successive windows at one kappa, by
  ``rise_factor`` in all, to at least ``floor_nm``;
* **limit cycle**: a window's RMS at or above ``limit_nm`` (an oscillation a person holding the arm
  feels plainly, whether or not it still grows).

At the first unstable window the sweep ramps kappa to zero over ``ramp_down_s`` and finishes; the
runtime then ramps its output out and ends the run. The live margin is the largest kappa held for its
whole step without a judgement of instability; the kappa in force at the judgement is the first
unstable one. A sweep that reaches ``max`` stable finishes there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import butter

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.runtime._tasks import Task, TaskInput

__all__ = ["SweepSettings", "InstabilityDetector", "KappaSweep"]


@dataclass(frozen=True, kw_only=True)
class SweepSettings:
    """Kappa steps and the judgement of instability (module docstring).

    Attributes
    ----------
    start, factor, max : float
        First kappa, ratio of successive ones (> 1), last one allowed [-].
    hold_s : float
        Time each kappa is held [s].
    band_hz : (float, float)
        Band of the joint torque judged [Hz].
    window_s : float
        RMS window [s].
    rise_windows : int
        Successive rising windows that make a growing oscillation.
    rise_factor : float
        Growth over those windows [-].
    floor_nm : float
        Least RMS of a growing oscillation [Nm].
    limit_nm : float
        RMS of a limit cycle [Nm].
    ramp_down_s : float
        Time to ramp kappa to zero after the judgement [s].
    """

    start: float = 1.0
    factor: float = 1.1
    max: float = 40.0
    hold_s: float = 2.0
    band_hz: tuple[float, float] = (5.0, 150.0)
    window_s: float = 0.25
    rise_windows: int = 4
    rise_factor: float = 3.0
    floor_nm: float = 2.0
    limit_nm: float = 5.0
    ramp_down_s: float = 0.1

    def __post_init__(self) -> None:
        def positive(name: str, v: float) -> None:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise IiwaIdentError(f"kappa sweep: {name} must be a positive number, got {v!r}")

        for name in ("start", "max", "hold_s", "window_s", "floor_nm", "limit_nm", "ramp_down_s"):
            positive(name, getattr(self, name))
        if not (math.isfinite(self.factor) and self.factor > 1.0):
            raise IiwaIdentError(f"kappa sweep: the factor must exceed 1, got {self.factor!r}")
        if self.max < self.start:
            raise IiwaIdentError(f"kappa sweep: max {self.max:g} is below start {self.start:g}")
        if self.steps() > 500:
            raise IiwaIdentError(f"kappa sweep: {self.steps()} steps from {self.start:g} to {self.max:g}; "
                                 "take a larger factor")
        lo, hi = self.band_hz
        positive("band's lower edge", lo)
        if not hi > lo:
            raise IiwaIdentError(f"kappa sweep: the band {lo:g}-{hi:g} Hz is empty")
        if not (isinstance(self.rise_windows, int) and self.rise_windows >= 2):
            raise IiwaIdentError(f"kappa sweep: rise windows must be an integer >= 2, got {self.rise_windows!r}")
        if self.hold_s < self.window_s * (self.rise_windows + 1):
            raise IiwaIdentError(f"kappa sweep: a {self.hold_s:g} s hold is shorter than the {self.rise_windows + 1} "
                                 f"windows of {self.window_s:g} s that judge it")

    def steps(self) -> int:
        """Number of kappa steps from ``start`` up to ``max``."""
        return int(math.floor(math.log(self.max / self.start) / math.log(self.factor) + 1e-9)) + 1

    def kappas(self) -> list[float]:
        """The kappa of each step."""
        return [self.start * self.factor ** i for i in range(self.steps())]


class InstabilityDetector:
    """The judgement of :class:`KappaSweep`, one joint-torque sample at a time.

    Parameters
    ----------
    settings : SweepSettings
        Band, windows and thresholds.
    dt : float
        Sample time [s].
    """

    def __init__(self, settings: SweepSettings, dt: float) -> None:
        lo, hi = settings.band_hz
        hi = min(hi, 0.45 / dt)
        sos = butter(2, [lo, hi], btype="bandpass", fs=1.0 / dt, output="sos")
        self._sos = [tuple(float(c) for c in row) for row in sos]  # plain floats for the cycle
        self._z = [[0.0, 0.0] for _ in self._sos]
        self.settings = settings
        self._n = max(1, int(round(settings.window_s / dt)))
        self._acc = 0.0
        self._k = 0
        self.windows: list[float] = []  #: RMS of each finished window [Nm]
        self._rises = 0
        self._base = 0.0  # RMS before the current run of rising windows

    def restart_segment(self) -> None:
        """A new kappa: growth is judged from here on."""
        self._rises = 0
        self._base = math.inf

    def update(self, x: float) -> str:
        """One sample [Nm]; a finished window may be judged: the reason it is unstable, or ""."""
        for (b0, b1, b2, _a0, a1, a2), z in zip(self._sos, self._z):  # a0 is 1 in scipy's sos
            y = b0 * x + z[0]
            z[0] = b1 * x - a1 * y + z[1]
            z[1] = b2 * x - a2 * y
            x = y
        self._acc += x * x
        self._k += 1
        if self._k < self._n:
            return ""
        rms = math.sqrt(self._acc / self._k)
        self._acc, self._k = 0.0, 0
        prev = self.windows[-1] if self.windows else math.inf
        self.windows.append(rms)
        s = self.settings
        if rms >= s.limit_nm:
            return f"limit cycle: {rms:.1f} Nm RMS in {s.band_hz[0]:g}-{s.band_hz[1]:g} Hz"
        if math.isinf(self._base) or rms <= prev:
            self._rises = 0
            self._base = rms
            return ""
        self._rises += 1
        if self._rises >= s.rise_windows and rms >= s.floor_nm and rms >= s.rise_factor * self._base:
            return (f"growing oscillation: {self._base:.2f} -> {rms:.2f} Nm RMS over {self._rises} windows "
                    f"of {s.window_s:g} s")
        return ""


@dataclass
class KappaSweep(Task):
    """``tau_r = kappa tau_ext`` with kappa raised stepwise until the run shows an instability.

    Parameters
    ----------
    settings : SweepSettings
        Steps and judgement.
    sample_time_s : float
        The loop's cycle [s].

    Attributes
    ----------
    steps : list of dict
        Per kappa step: ``kappa``, ``t_start_s``, ``stable`` (True when held to its end, False for the
        one judged unstable), ``rms_nm`` (the RMS of its windows).
    unstable_at, live_limit : float or None
        The first unstable kappa and the largest one held stable (None: none).
    reason : str
        What the judgement saw ("" when none).
    """

    settings: SweepSettings = field(default_factory=SweepSettings)
    sample_time_s: float = 1e-3
    name = "kappa_sweep"

    def __post_init__(self) -> None:
        self._kappas = self.settings.kappas()
        self._hold = max(1, int(round(self.settings.hold_s / self.sample_time_s)))
        self._detector = InstabilityDetector(self.settings, self.sample_time_s)
        self._k = 0
        self._i = 0
        self._scale = 1.0
        self._ramp = self.sample_time_s / self.settings.ramp_down_s
        self.kappa = self._kappas[0]  #: kappa in force [-]
        self.steps: list[dict[str, Any]] = [self._step(0, 0.0)]
        self.unstable_at: float | None = None
        self.live_limit: float | None = None
        self.reason = ""
        self._detector.restart_segment()

    def _step(self, i: int, t: float) -> dict[str, Any]:
        return {"kappa": self._kappas[i], "t_start_s": t, "stable": None, "rms_nm": []}

    def reference(self, s: TaskInput) -> float:
        if self.reason:  # judged unstable: ramp kappa out, then finish
            self._scale = max(0.0, self._scale - self._ramp)
            if self._scale == 0.0 and not self.done:
                self.done = "kappa sweep: " + self.reason
            return self._scale * self.kappa * s.tau_ext
        n_windows = len(self._detector.windows)
        verdict = self._detector.update(s.tau_j)
        step = self.steps[-1]
        if len(self._detector.windows) > n_windows:
            step["rms_nm"].append(self._detector.windows[-1])
        if verdict:
            self.reason = verdict
            step["stable"] = False
            self.unstable_at = self.kappa
            return self.kappa * s.tau_ext
        self._k += 1
        if self._k >= self._hold:
            step["stable"] = True
            self.live_limit = self.kappa
            self._k = 0
            self._i += 1
            if self._i >= len(self._kappas):
                self.done = f"kappa sweep: stable up to the maximum {self.kappa:.3g}"
                return self.kappa * s.tau_ext
            self.kappa = self._kappas[self._i]
            self.steps.append(self._step(self._i, s.t))
            self._detector.restart_segment()
        return self.kappa * s.tau_ext

    def attrs(self) -> dict[str, float | str]:
        st = self.settings
        return {"task": self.name, "kappa_start": st.start, "kappa_factor": st.factor, "kappa_max": st.max,
                "hold_s": st.hold_s}

    def result_attrs(self) -> dict:
        return {"live_limit": np.nan if self.live_limit is None else self.live_limit,
                "unstable_at": np.nan if self.unstable_at is None else self.unstable_at,
                "instability": self.reason,
                "step_kappa": np.array([s["kappa"] for s in self.steps], float),
                "step_t_start_s": np.array([s["t_start_s"] for s in self.steps], float)}
