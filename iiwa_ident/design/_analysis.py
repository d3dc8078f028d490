"""Closed-loop analysis on the simulated joint: built-in against additive torque control (section V.C).

The same experiment runs with either controller on the client side of the
1 kHz loop (:class:`BuiltinTorqueControl`, :class:`AdditiveTorqueControl`),
on the simulated joint with the transmission ripple of eq (5) switched on.

Experiments
-----------
:func:`step_response`, :func:`sine_tracking` (Figs. 8-9)
    The paper ran the base joint with a free link. A torque reference on a
    free link accelerates it (10 Nm on J_l = 5.6 kg m^2 reaches ~1 rad/s in
    half a second), so, as the programs of :mod:`iiwa_ident.excite` do, a
    weak position hold is added to the reference the torque loop receives::

        tau_r = r(t) - k_hold (q_m - q_0) - d_hold q_m'

    (30 Nm/rad, 10 Nm s/rad by default). This keeps the link within a few
    tenths of a radian while letting it move: the motion is what turns the
    transmission ripple into torque fluctuations at ``|q'| / rho`` Hz
    (eq (6)), the effect the additive controller and its spatial filter are
    meant to handle. Holding the link with a stiff external agent instead
    (``agent_stiffness``) removes that motion and changes the plant (the
    link no longer takes part in eq (4)); it is offered for comparison.

Tracking error
--------------
The FRI delays every command by Td = 5 ms (eq (4)); no client-side
controller can undo that. Errors are therefore taken against the reference
delayed by Td, ``e(t) = tau_J(t) - tau_r(t - Td)``, on the raw joint torque
and on the spatially filtered one of eq (15) (the same filter for both
controllers, applied after the run; for the additive controller it is the
signal its observer sees). Peak and RMS are taken in steady state (after
``settle_s``).

Outer-loop gain margin
----------------------
:func:`kappa_margin` closes ``tau_r = kappa tau_ext`` on the F/T reference
``tau_ext_ref`` while an :class:`~iiwa_ident.sim.ImpedanceAgent`
(hand stiffness and damping of :class:`~iiwa_ident.design.HumanArm`)
moves the link along a slow sine, so that the joint never stands still (the
robot suppresses torque control at standstill below 1 Nm) and the ripple is
excited as in a real interaction. A run is judged unstable (:func:`judge_stability`)
when the oscillatory part of tau_J (above ``highpass_hz``) grows from the
first to the last hand period by more than ``growth_limit`` and is above a
noise floor, when it exceeds an absolute level, or when the limit guard
stops the run. The largest stable ``kappa`` is bracketed around the linear
prediction :func:`~iiwa_ident.design.kappa_max` and bisected.

Measured on the default plant (Table I, ripple on, identified ripple table)
-----------------------------------------------------------------------------
With the design defaults (paper poles, 250 Hz pre-filter, beta = 2),
v_min = 0.2 rad/s, arm 300 Nm/rad and 40 Nm s/rad (seed 0):

* step +-10 Nm: overshoot 38 % built-in (paper ~40 %), 16 % additive (raw tau_J);
* 5 Nm at 0.25 Hz, peak error raw / filtered: built-in 1.7 / 1.0 Nm,
  additive 1.4 / 0.4 Nm;
* 15 Nm at 25 Hz: built-in 35.6 / 36.0 Nm (resonance at 23 Hz), additive
  4.3 / 4.3 Nm (targets: < 10 raw, < 5 filtered);
* kappa_max: built-in 7.6 (linear 7.8), additive 26-28 (linear 32.9); ratio 3.5-3.7
  (the additive margin moves by a few percent with plant details and the seed);
  with the paper's beta = 5 the additive margin is 20.9 (ratio 2.8).

With a 50 Hz pre-filter the additive 25 Hz error is 13 Nm (the pre-filter's
phase lag) and kappa_max drops to ~13 (12.5 with beta = 5): the spatial filter
in the loop, whose notch sweeps 5-16 Hz at the hand's speeds, creates a
~20 Hz limit cycle (without the filter the same loop is stable at 20).
beta = 1 or v_min = 0.5 rad/s push that to ~20. ``bench/bench_control.py``
reproduces the numbers.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.signal import butter, sosfiltfilt

from iiwa_ident.design._additive import (
    DEFAULT_PREFILTER_HZ,
    AdditiveDesign,
    DesignError,
    builtin_poles,
    design_controller,
)
from iiwa_ident.design._controller import AdditiveController
from iiwa_ident.design._cycle import ControlCycle
from iiwa_ident.design._margins import HumanArm, kappa_max
from iiwa_ident.design._spatial_filter import FilterSettings, SpatialFilter
from iiwa_ident.excite import ClientState, Experiment, LimitGuard, record
from iiwa_ident.model import JointModel, JointParameters, RippleTable, joint_position, table1_model
from iiwa_ident.references import square
from iiwa_ident.robot import Command, Measurement
from iiwa_ident.sim import ImpedanceAgent, Plant, SimulatedJoint, default_plant

__all__ = [
    "TorqueControl",
    "BuiltinTorqueControl",
    "AdditiveTorqueControl",
    "ClosedLoopRun",
    "TrackingErrors",
    "StepMetrics",
    "StepResult",
    "SineResult",
    "StabilityVerdict",
    "KappaTrial",
    "KappaMargin",
    "identified_model",
    "make_controller",
    "run_closed_loop",
    "step_response",
    "sine_tracking",
    "tracking_errors",
    "judge_stability",
    "kappa_trial",
    "kappa_margin",
    "compare_controllers",
    "ANALYSIS_PREFILTER_HZ",
    "analysis_design",
]

#: Reference pre-filter of the feed-forward of eq (22) used by the analysis [Hz]: the design default.
ANALYSIS_PREFILTER_HZ = DEFAULT_PREFILTER_HZ


def analysis_design(model: JointModel, prefilter_hz: float = ANALYSIS_PREFILTER_HZ, **kwargs) -> AdditiveDesign:
    """The paper's poles on ``model`` with the analysis pre-filter (``kwargs`` go to ``design_controller``)."""
    return design_controller(JointParameters.from_model(model), prefilter_hz=prefilter_hz, **kwargs)


# ---------------------------------------------------------------------------
# Controllers on the client side of the loop
# ---------------------------------------------------------------------------
class TorqueControl(ABC):
    """A client-side joint-torque controller: reference torque -> commanded torque, once per cycle."""

    #: ``"builtin"`` or ``"additive"``.
    kind: str = ""

    @abstractmethod
    def reset(self) -> None:
        """Forget all state; call before each run."""

    @abstractmethod
    def command(self, tau_r: float, meas: Measurement) -> float:
        """The commanded torque tau_c [Nm] for reference ``tau_r`` [Nm] and this cycle's measurement."""


class BuiltinTorqueControl(TorqueControl):
    """The robot's own torque controller (section V.A): ``tau_c = tau_r``."""

    kind = "builtin"

    def reset(self) -> None:
        """Nothing to reset: the controller has no state."""

    def command(self, tau_r: float, meas: Measurement) -> float:
        return float(tau_r)


class AdditiveTorqueControl(TorqueControl):
    """The additive controller of section V.B: the runtime's :class:`~iiwa_ident.design.ControlCycle`.

    Per cycle: ``theta_j`` from the motor position by eq (8) (if a ripple
    table is given, else ``q_m``), ``tau_J,filt`` by the spatial filter of
    eqs (10)-(12) and (15) relative to the first cycle's torque, then eqs
    (16)-(18) give ``tau_c`` (zero in the first cycle, as on the robot).

    Parameters
    ----------
    design : AdditiveDesign
        The controller design.
    filter : FilterSettings, optional
        The spatial filter (default: the design's beta and v_min at the lookup table's period).
    ripple : RippleTable, optional
        Lookup table of eq (8) for the joint position the filter runs along.
    dt : float
        Cycle [s].
    """

    kind = "additive"

    def __init__(self, design: AdditiveDesign, filter: FilterSettings | None = None, ripple: RippleTable | None = None,
                 dt: float = 1e-3) -> None:
        self.design = design
        self.cycle = ControlCycle(AdditiveController(design), filter=filter, dt=dt, ripple=ripple)

    @property
    def ripple(self) -> RippleTable | None:
        """The lookup table of eq (8) the cycle runs along (None: theta_j = q_m)."""
        return self.cycle.ripple

    @classmethod
    def from_model(cls, model: JointModel, design: AdditiveDesign | None = None, filter: FilterSettings | None = None,
                   **design_kwargs) -> AdditiveTorqueControl:
        """The controller for ``model`` (:func:`analysis_design` unless ``design`` is given)."""
        if design is None:
            design = analysis_design(model, **design_kwargs)
        return cls(design, filter, model.ripple, design.sample_time_s)

    @property
    def tau_j_filt(self) -> float:
        """The filtered joint torque of the last cycle [Nm]."""
        return self.cycle.tau_j_filt

    def reset(self) -> None:
        self.cycle.reset()

    def command(self, tau_r: float, meas: Measurement) -> float:
        return self.cycle.step(meas, tau_r)


def make_controller(kind: str, model: JointModel, design: AdditiveDesign | None = None,
                    filter: FilterSettings | None = None) -> TorqueControl:
    """``"builtin"`` or ``"additive"`` controller for ``model`` (the additive one's spatial filter: ``filter``)."""
    if kind == "builtin":
        return BuiltinTorqueControl()
    if kind == "additive":
        return AdditiveTorqueControl.from_model(model, design, filter=filter)
    raise ValueError(f"controller kind must be 'builtin' or 'additive', got {kind!r}")


def identified_model(plant: Plant | None = None, seed: int = 1, base: JointModel | None = None,
                     speeds: tuple[float, ...] = (0.3, 0.6, 1.2), range_rad: float = 1.0) -> JointModel:
    """``base`` (Table I) with the ripple table identified from a simulated constant-velocity run.

    The table is what a user would get from :func:`~iiwa_ident.ident.identify_ripple`
    on the plant, never the plant's own truth.
    """
    from iiwa_ident.excite import ConstantVelocity
    from iiwa_ident.ident import identify_ripple

    ds = record(SimulatedJoint(plant or default_plant(), seed=seed), ConstantVelocity(speeds, range_rad=range_rad))
    res = identify_ripple([ds])
    model = base or table1_model()
    if res.detected:
        model.ripple = res.table()
    return model


# ---------------------------------------------------------------------------
# Running a closed loop
# ---------------------------------------------------------------------------
@dataclass(kw_only=True)
class ClosedLoopRun:
    """Signals of one closed-loop run, one sample per cycle.

    Attributes
    ----------
    kind : str
        Controller kind.
    t : ndarray
        Time [s].
    r : ndarray
        The experiment's reference without the position hold [Nm].
    tau_r : ndarray
        Reference given to the torque controller (with the hold) [Nm].
    tau_c : ndarray
        Commanded torque [Nm].
    tau_j : ndarray
        Measured joint torque, the measurement the command was computed from [Nm].
    q_m : ndarray
        Motor position [rad].
    tau_ext_ref : ndarray
        F/T reference torque [Nm] (NaN if not fitted).
    stopped : str
        Why the limit guard stopped the run ("" if it ran to the end).
    """

    kind: str
    t: np.ndarray
    r: np.ndarray
    tau_r: np.ndarray
    tau_c: np.ndarray
    tau_j: np.ndarray
    q_m: np.ndarray
    tau_ext_ref: np.ndarray
    stopped: str = ""
    tau_j_filt: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 1e-3


class _ClosedLoop(Experiment):
    """A torque controller under the analysis' reference and position hold, as an experiment program."""

    name = "free"

    def __init__(self, controller: TorqueControl, reference: Callable[[float], float], duration_s: float,
                 hold_stiffness: float, hold_damping: float, kappa: float, agent: ImpedanceAgent | None) -> None:
        self.controller, self.reference, self.duration_s = controller, reference, float(duration_s)
        self.hold_stiffness, self.hold_damping, self.kappa, self._agent = hold_stiffness, hold_damping, kappa, agent
        self.r: list[float] = []  # per cycle, beside the recorded signals
        self.tau_r: list[float] = []

    def agent(self, q0: float) -> ImpedanceAgent | None:
        return self._agent

    def command(self, s: ClientState) -> Command:
        r = self.reference(s.t)
        tau_r = r - self.hold_stiffness * (s.q - s.q0) - self.hold_damping * s.v
        if self.kappa != 0.0:
            if s.meas.tau_ext_ref is None:
                raise DesignError("the outer loop of section V.C needs the external-torque reference")
            tau_r += self.kappa * s.meas.tau_ext_ref
        self.r.append(r)
        self.tau_r.append(tau_r)
        return Command(tau_c=self.controller.command(tau_r, s.meas))


def run_closed_loop(controller: TorqueControl, plant: Plant | None, reference: Callable[[float], float],
                    duration_s: float, *, seed: int = 0, hold_stiffness: float = 30.0, hold_damping: float = 10.0,
                    kappa: float = 0.0, agent: ImpedanceAgent | None = None, model: JointModel | None = None,
                    filter: FilterSettings | None = None) -> ClosedLoopRun:
    """Run ``controller`` on a simulated joint for ``duration_s``.

    ``tau_r = r(t) - hold_stiffness (q - q0) - hold_damping v + kappa tau_ext_ref``
    each cycle, commands pass the :class:`~iiwa_ident.excite.LimitGuard`; the loop is
    :func:`~iiwa_ident.excite.record`'s, as for every experiment (after a stop it brakes the joint).

    Parameters
    ----------
    controller : TorqueControl
        Built-in or additive; reset before the run.
    plant : Plant, optional
        The simulated plant (default: the default plant, ripple on).
    reference : callable
        ``r(t)`` [Nm].
    duration_s : float
        Duration [s].
    seed : int
        Sensor-noise seed.
    hold_stiffness, hold_damping : float
        Client position hold added to the reference [Nm/rad], [Nm s/rad].
    kappa : float
        Outer-loop gain on the F/T reference [-] (section V.C).
    agent : ImpedanceAgent, optional
        External agent acting on the link.
    model : JointModel, optional
        Model whose ripple table gives theta_j (eq (8)) for the offline filtered torque.
    filter : FilterSettings, optional
        The spatial filter's settings (default: the design's beta and v_min).

    Returns
    -------
    ClosedLoopRun
        ``tau_j_filt`` holds the spatially filtered tau_J (eq (15)).
    """
    robot = SimulatedJoint(plant or default_plant(), seed=seed)
    controller.reset()
    loop = _ClosedLoop(controller, reference, duration_s, hold_stiffness, hold_damping, kappa, agent)
    ds = record(robot, loop, guard=LimitGuard(robot.limits))  # the one loop driver of every experiment
    sig = ds.signals
    n = len(sig["t"])
    tau_ext_ref = sig.get("tau_ext_ref", np.full(n, np.nan))
    run = ClosedLoopRun(kind=controller.kind, t=sig["t"], r=np.array(loop.r[:n]), tau_r=np.array(loop.tau_r[:n]),
                        tau_c=sig["tau_c"], tau_j=sig["tau_j"], q_m=sig["q_m"], tau_ext_ref=tau_ext_ref,
                        stopped=ds.experiment_attrs.get("stopped_reason", ""))
    dt = robot.sample_time_s
    ripple = model.ripple if model is not None else getattr(controller, "ripple", None)
    theta = np.asarray(joint_position(run.q_m, ripple), float)
    run.tau_j_filt = SpatialFilter.from_settings(filter or FilterSettings(), ripple, dt).apply(run.tau_j, theta)
    return run


# ---------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackingErrors:
    """Steady-state tracking errors ``tau_J(t) - tau_r(t - Td)`` [Nm].

    Attributes
    ----------
    raw_peak, raw_rms : float
        On the measured joint torque.
    filt_peak, filt_rms : float
        On the spatially filtered joint torque, eq (15).
    mean : float
        Mean error of the raw torque (the offset the paper sees at 0.25 Hz) [Nm].
    """

    raw_peak: float
    raw_rms: float
    filt_peak: float
    filt_rms: float
    mean: float

    def as_dict(self) -> dict[str, float]:
        return {"raw_peak": self.raw_peak, "raw_rms": self.raw_rms, "filt_peak": self.filt_peak,
                "filt_rms": self.filt_rms, "mean": self.mean}


def _delayed(x: np.ndarray, samples: int) -> np.ndarray:
    """``x`` delayed by ``samples`` (first value held)."""
    if samples <= 0:
        return x.copy()
    return np.concatenate([np.full(samples, x[0]), x[:-samples]])


def tracking_errors(run: ClosedLoopRun, start_s: float, delay_s: float = 0.005,
                    stop_s: float | None = None) -> TrackingErrors:
    """Peak and RMS of ``tau_J(t) - tau_r(t - delay_s)`` between ``start_s`` and ``stop_s`` [s]."""
    d = int(round(delay_s / run.dt))
    ref = _delayed(run.tau_r, d)
    sel = (run.t >= start_s) & (run.t <= (stop_s if stop_s is not None else np.inf))
    if not np.any(sel):
        raise ValueError("tracking_errors: empty evaluation window")
    e_raw = (run.tau_j - ref)[sel]
    e_f = (run.tau_j_filt - ref)[sel]
    return TrackingErrors(float(np.abs(e_raw).max()), float(np.sqrt(np.mean(e_raw ** 2))),
                          float(np.abs(e_f).max()), float(np.sqrt(np.mean(e_f ** 2))), float(np.mean(e_raw)))


@dataclass(frozen=True)
class StepMetrics:
    """Averages over the edges of a square-wave reference.

    Attributes
    ----------
    overshoot_raw, overshoot_filt : float
        Largest excursion beyond the new reference, relative to the step height [-],
        on the raw and on the filtered torque (the paper: ~40 % built-in).
    rise_time_s : float
        10 %-90 % rise of the filtered torque [s] (after the input delay).
    settling_time_s : float
        Time from the edge until the filtered torque stays within ``band`` of
        the step height around the reference [s] (NaN if it never does).
    band : float
        Settling band [-].
    """

    overshoot_raw: float
    overshoot_filt: float
    rise_time_s: float
    settling_time_s: float
    band: float

    def as_dict(self) -> dict[str, float]:
        return {"overshoot_raw": self.overshoot_raw, "overshoot_filt": self.overshoot_filt,
                "rise_time_s": self.rise_time_s, "settling_time_s": self.settling_time_s, "band": self.band}


class _EdgeMetrics(NamedTuple):
    """One step edge's overshoots [%] (raw and filtered torque), rise and settling time [s]."""

    overshoot_raw: float
    overshoot_filtered: float
    rise_s: float
    settle_s: float


def _edge_metrics(run: ClosedLoopRun, i0: int, i1: int, height: float, band: float, delay: int) -> _EdgeMetrics:
    """Overshoot (raw, filt), rise and settling time of one edge at sample ``i0`` (window up to ``i1``)."""
    sgn = math.copysign(1.0, height)
    ref = _delayed(run.tau_r, delay)[i0:i1]
    e_raw = sgn * (run.tau_j[i0:i1] - ref) / abs(height)
    e_f = sgn * (run.tau_j_filt[i0:i1] - ref) / abs(height)
    over_raw, over_f = max(0.0, float(e_raw.max())), max(0.0, float(e_f.max()))
    # Progress from the old to the new level, on the filtered torque.
    progress = 1.0 + e_f
    above10 = np.nonzero(progress >= 0.1)[0]
    above90 = np.nonzero(progress >= 0.9)[0]
    rise = (above90[0] - above10[0]) * run.dt if len(above10) and len(above90) else math.nan
    outside = np.nonzero(np.abs(e_f) > band)[0]
    if len(outside) == 0:
        settle = 0.0
    elif outside[-1] >= len(e_f) - 1:
        settle = math.nan  # still outside the band at the end of the half period
    else:
        settle = (outside[-1] + 1) * run.dt
    return _EdgeMetrics(over_raw, over_f, rise, settle)


@dataclass
class StepResult:
    """Outcome of :func:`step_response`: the run, its metrics and the steady-state errors."""

    run: ClosedLoopRun
    metrics: StepMetrics
    errors: TrackingErrors
    edges_s: np.ndarray


def step_response(controller: TorqueControl, plant: Plant | None = None, amplitude_nm: float = 10.0,
                  period_s: float = 1.0, cycles: int = 2, *, band: float = 0.05, settle_s: float = 0.3,
                  seed: int = 0, model: JointModel | None = None, filter: FilterSettings | None = None,
                  hold_stiffness: float = 30.0, hold_damping: float = 10.0,
                  agent_stiffness: float | None = None, delay_s: float = 0.005) -> StepResult:
    """Square-wave steps between ``+amplitude`` and ``-amplitude`` (Fig. 8).

    The first half period steps up from rest (a step of ``amplitude``); each
    later edge is a step of ``2 amplitude``. Metrics are averaged over the
    edges; steady-state errors use the part of every half period later than
    ``settle_s`` after its edge.

    Parameters
    ----------
    controller : TorqueControl
        Built-in or additive.
    plant : Plant, optional
        Simulated plant (default plant, ripple on).
    amplitude_nm, period_s : float
        Square-wave amplitude [Nm] and period [s].
    cycles : int
        Number of periods.
    band : float
        Settling band, relative to the step height [-].
    settle_s : float
        Start of the steady state after each edge [s].
    seed : int
        Noise seed.
    model : JointModel, optional
        Model with the ripple table for the offline filtered torque.
    filter : FilterSettings, optional
        The spatial filter's settings (default: the design's beta and v_min).
    hold_stiffness, hold_damping : float
        Client position hold [Nm/rad], [Nm s/rad] (module docstring).
    agent_stiffness : float, optional
        If given, a stiff external agent holds the link at its start
        position instead (damping 2 sqrt(k J_l) / 10) [Nm/rad].
    delay_s : float
        Delay the reference is compared at [s] (the FRI's Td).
    """
    def ref(t: float) -> float:
        return square(t, amplitude_nm, period_s)

    half = period_s / 2
    duration = period_s * cycles
    agent = _holding_agent(plant, agent_stiffness, duration)
    if agent is not None:
        hold_stiffness = hold_damping = 0.0
    run = run_closed_loop(controller, plant, ref, duration, seed=seed, hold_stiffness=hold_stiffness,
                          hold_damping=hold_damping, agent=agent, model=model, filter=filter)
    dly = int(round(delay_s / run.dt))
    n_half = int(round(half / run.dt))
    edges = np.arange(0, len(run.t), n_half)
    rows = []
    for j, i0 in enumerate(edges.tolist()):
        i1 = min(i0 + n_half, len(run.t))
        if i1 - i0 < n_half // 2:
            break
        height = amplitude_nm if j == 0 else (2 * amplitude_nm if j % 2 == 0 else -2 * amplitude_nm)
        rows.append(_edge_metrics(run, i0, i1, height, band, dly))
    arr = np.array(rows, float)
    metrics = StepMetrics(float(np.nanmean(arr[:, 0])), float(np.nanmean(arr[:, 1])),
                          float(np.nanmean(arr[:, 2])),
                          float(np.nanmean(arr[:, 3])) if np.all(np.isfinite(arr[:, 3])) else math.nan, band)
    # Steady state: the end of every half period.
    sel = np.zeros(len(run.t), bool)
    for start in edges:
        sel[start + int(round(settle_s / run.dt)):start + n_half] = True
    errors = _errors_on(run, sel, dly)
    return StepResult(run, metrics, errors, edges * run.dt)


def _errors_on(run: ClosedLoopRun, sel: np.ndarray, delay: int) -> TrackingErrors:
    ref = _delayed(run.tau_r, delay)
    e_raw, e_f = (run.tau_j - ref)[sel], (run.tau_j_filt - ref)[sel]
    return TrackingErrors(float(np.abs(e_raw).max()), float(np.sqrt(np.mean(e_raw ** 2))),
                          float(np.abs(e_f).max()), float(np.sqrt(np.mean(e_f ** 2))), float(np.mean(e_raw)))


def _holding_agent(plant: Plant | None, stiffness: float | None, duration_s: float,
                   q0: float = 0.0) -> ImpedanceAgent | None:
    """A stiff agent holding the link at ``q0`` (None without a stiffness)."""
    if stiffness is None:
        return None
    Jl = (plant or default_plant()).dynamics["Jl"]
    damping = 0.2 * math.sqrt(stiffness * Jl)  # zeta = 0.1 on the held link
    t = np.array([0.0, duration_s + 1.0])
    return ImpedanceAgent(t, np.full(2, q0), np.zeros(2), stiffness, damping)


@dataclass
class SineResult:
    """Outcome of :func:`sine_tracking`."""

    run: ClosedLoopRun
    errors: TrackingErrors
    amplitude_nm: float
    frequency_hz: float
    start_s: float


def sine_tracking(controller: TorqueControl, plant: Plant | None = None, amplitude_nm: float = 5.0,
                  frequency_hz: float = 0.25, duration_s: float | None = None, *, settle_s: float | None = None,
                  seed: int = 0, model: JointModel | None = None, filter: FilterSettings | None = None,
                  hold_stiffness: float = 30.0, hold_damping: float = 10.0,
                  agent_stiffness: float | None = None, delay_s: float = 0.005) -> SineResult:
    """Track ``r(t) = A sin(2 pi f t)`` (Fig. 9) and report the steady-state errors.

    Parameters
    ----------
    controller, plant
        As for :func:`step_response`.
    amplitude_nm, frequency_hz : float
        Amplitude [Nm] and frequency [Hz] (paper: 5 Nm at 0.25 Hz, 15 Nm at 25 Hz).
    duration_s : float, optional
        Duration [s] (default: two periods, at least 2 s).
    settle_s : float, optional
        Start of the steady-state window [s] (default: half the duration).
    seed, model, filter, hold_stiffness, hold_damping, agent_stiffness, delay_s
        As in :func:`step_response`.
    """
    if duration_s is None:
        duration_s = max(2.0, 2.0 / frequency_hz)
    if settle_s is None:
        settle_s = duration_s / 2
    w = 2 * math.pi * frequency_hz

    def ref(t: float) -> float:
        return amplitude_nm * math.sin(w * t)

    agent = _holding_agent(plant, agent_stiffness, duration_s)
    if agent is not None:
        hold_stiffness = hold_damping = 0.0
    run = run_closed_loop(controller, plant, ref, duration_s, seed=seed, hold_stiffness=hold_stiffness,
                          hold_damping=hold_damping, agent=agent, model=model, filter=filter)
    errors = tracking_errors(run, settle_s, delay_s)
    return SineResult(run, errors, amplitude_nm, frequency_hz, settle_s)


# ---------------------------------------------------------------------------
# Outer-loop gain margin
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class StabilityVerdict:
    """How a run of the outer loop was judged.

    Attributes
    ----------
    stable : bool
        The verdict.
    growth : float
        RMS of the oscillatory tau_J in the last window over the first [-].
    rms_first, rms_last : float
        Those RMS values [Nm].
    peak : float
        Largest |tau_J| [Nm].
    reason : str
        Why it is unstable ("" if stable).
    """

    stable: bool
    growth: float
    rms_first: float
    rms_last: float
    peak: float
    reason: str = ""


def judge_stability(run: ClosedLoopRun, window_s: float, start_s: float = 1.0, highpass_hz: float = 3.0,
                    growth_limit: float = 1.5, floor_nm: float = 0.5, absolute_nm: float = 25.0) -> StabilityVerdict:
    """Decide whether an outer-loop run grew unstable.

    The oscillatory part of tau_J (above ``highpass_hz``, zero-phase
    Butterworth) is cut into windows of ``window_s`` (a whole hand period,
    so a stable loop repeats itself from window to window) from ``start_s``.
    Unstable if: the guard stopped the run; the last window's RMS exceeds
    ``growth_limit`` times the first's and ``floor_nm``; or any window's RMS
    exceeds ``absolute_nm`` (a limit cycle large enough to feel).
    """
    peak = float(np.nanmax(np.abs(run.tau_j))) if len(run.tau_j) else math.inf
    if run.stopped:
        return StabilityVerdict(False, math.inf, math.nan, math.nan, peak, f"stopped: {run.stopped}")
    if not np.all(np.isfinite(run.tau_j)):
        return StabilityVerdict(False, math.inf, math.nan, math.nan, peak, "non-finite torque")
    sos = butter(4, highpass_hz, "highpass", fs=1.0 / run.dt, output="sos")
    osc = sosfiltfilt(sos, run.tau_j)
    n_w = int(round(window_s / run.dt))
    i0 = int(round(start_s / run.dt))
    rms = [float(np.sqrt(np.mean(osc[i:i + n_w] ** 2))) for i in range(i0, len(osc) - n_w + 1, n_w)]
    if len(rms) < 2:
        raise ValueError("judge_stability: the run is shorter than two windows after start_s")
    growth = rms[-1] / max(rms[0], 1e-12)
    if max(rms) > absolute_nm:
        return StabilityVerdict(False, growth, rms[0], rms[-1], peak, f"oscillation RMS {max(rms):.1f} Nm")
    if growth > growth_limit and rms[-1] > floor_nm:
        return StabilityVerdict(False, growth, rms[0], rms[-1], peak, f"oscillation grew x{growth:.2f}")
    return StabilityVerdict(True, growth, rms[0], rms[-1], peak)


@dataclass
class KappaTrial:
    """One simulated outer-loop run: gain, verdict and (optionally) the run."""

    kappa: float
    verdict: StabilityVerdict
    run: ClosedLoopRun | None = None


def _hand_agent(arm: HumanArm, amplitude_rad: float, frequency_hz: float, duration_s: float,
                ease_s: float = 0.5) -> ImpedanceAgent:
    """The hand: stiffness/damping of ``arm`` to a sine trajectory that eases in over ``ease_s``."""
    t = np.arange(0.0, duration_s + 1.0, 1e-3)
    w = 2 * math.pi * frequency_hz
    x = np.clip(t / ease_s, 0.0, 1.0)
    ease, dease = x * x * (3 - 2 * x), np.where(t < ease_s, 6 * x * (1 - x) / ease_s, 0.0)
    pos = amplitude_rad * np.sin(w * t)
    vel = amplitude_rad * w * np.cos(w * t)
    return ImpedanceAgent(t, ease * pos, ease * vel + dease * pos, arm.stiffness, arm.damping)


def kappa_trial(controller: TorqueControl, kappa: float, plant: Plant | None = None, arm: HumanArm = HumanArm(),
                *, hand_amplitude_rad: float = 0.1, hand_frequency_hz: float = 0.5, periods: int = 3,
                seed: int = 0, keep_run: bool = False, **judge_kwargs) -> KappaTrial:
    """One run of ``tau_r = kappa tau_ext_ref`` with the hand moving the link; judged by :func:`judge_stability`.

    Parameters
    ----------
    controller : TorqueControl
        Built-in or additive.
    kappa : float
        Outer-loop gain [-].
    plant : Plant, optional
        Simulated plant (default plant, ripple on).
    arm : HumanArm
        Hand stiffness [Nm/rad] and damping [Nm s/rad] (the inertia is not simulated).
    hand_amplitude_rad, hand_frequency_hz : float
        The hand's sine trajectory [rad], [Hz] (peak speed ``2 pi f A``).
    periods : int
        Hand periods judged (the run is one second longer: the first is the ease-in).
    seed : int
        Noise seed.
    keep_run : bool
        Keep the signals in the result.
    """
    window = 1.0 / hand_frequency_hz
    duration = 1.0 + periods * window
    agent = _hand_agent(arm, hand_amplitude_rad, hand_frequency_hz, duration)
    run = run_closed_loop(controller, plant, lambda t: 0.0, duration, seed=seed, hold_stiffness=0.0,
                          hold_damping=0.0, kappa=kappa, agent=agent)
    verdict = judge_stability(run, window, start_s=1.0, **judge_kwargs)
    return KappaTrial(float(kappa), verdict, run if keep_run else None)


@dataclass
class KappaMargin:
    """Outcome of :func:`kappa_margin`.

    Attributes
    ----------
    kind : str
        Controller kind.
    kappa_max : float
        Largest gain judged stable in simulation [-] (``kappa_limit`` if never unstable).
    kappa_unstable : float
        Smallest gain judged unstable [-] (inf if none).
    linear : float
        Linear prediction of :func:`~iiwa_ident.design.kappa_max` (no ripple, no filter) [-].
    trials : list of KappaTrial
        Every run, in the order made.
    """

    kind: str
    kappa_max: float
    kappa_unstable: float
    linear: float
    trials: list[KappaTrial]


def kappa_margin(controller_kind: str, plant: Plant | None = None, arm: HumanArm = HumanArm(), *,
                 model: JointModel | None = None, design: AdditiveDesign | None = None,
                 filter: FilterSettings | None = None, rel_tol: float = 0.05, kappa_limit: float = 60.0,
                 seed: int = 0, **trial_kwargs) -> KappaMargin:
    """Largest stable outer-loop gain ``kappa`` of ``tau_r = kappa tau_ext`` found by simulation.

    The bracket starts at the linear prediction (:func:`~iiwa_ident.design.kappa_max`
    on the model, with the same arm), widens by factors of 1.5 until it holds
    a stable and an unstable gain, then bisects (geometrically) until their
    ratio is below ``1 + rel_tol``.

    Parameters
    ----------
    controller_kind : {"builtin", "additive"}
        Which controller.
    plant : Plant, optional
        Simulated plant (default plant, ripple on).
    arm : HumanArm
        The hand holding the link.
    model : JointModel, optional
        Model for the design and the filter (default: Table I with an identified ripple table).
    design : AdditiveDesign, optional
        Additive design (default: :func:`analysis_design` on ``model``).
    filter : FilterSettings, optional
        The spatial filter's settings (default: the design's beta and v_min).
    rel_tol : float
        Relative width of the final bracket [-].
    kappa_limit : float
        Largest gain tried [-].
    seed : int
        Noise seed.
    **trial_kwargs
        Passed to :func:`kappa_trial` (hand trajectory, judging thresholds).
    """
    plant = plant or default_plant()  # one plant for every trial
    model = model or identified_model(plant)
    params = JointParameters.from_model(model)
    if controller_kind == "additive" and design is None:
        design = analysis_design(model)
    controller = make_controller(controller_kind, model, design, filter)
    linear = kappa_max(params, design if controller_kind == "additive" else None, arm, kappa_limit=kappa_limit)
    trials: list[KappaTrial] = []

    def stable(k: float) -> bool:
        trial = kappa_trial(controller, k, plant, arm, seed=seed, **trial_kwargs)
        trials.append(trial)
        return trial.verdict.stable

    k = min(linear, kappa_limit) if math.isfinite(linear) and linear > 0 else 1.0
    if stable(k):
        lo, hi = k, math.inf
        while hi == math.inf:
            if lo >= kappa_limit:
                return KappaMargin(controller_kind, kappa_limit, math.inf, linear, trials)
            k = min(lo * 1.5, kappa_limit)
            if stable(k):
                lo = k
            else:
                hi = k
    else:
        lo, hi = 0.0, k
        while lo == 0.0:
            k = hi / 1.5
            if k < 0.05:
                return KappaMargin(controller_kind, 0.0, hi, linear, trials)
            if stable(k):
                lo = k
            else:
                hi = k
    while hi / lo > 1.0 + rel_tol:
        mid = math.sqrt(lo * hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return KappaMargin(controller_kind, lo, hi, linear, trials)


# ---------------------------------------------------------------------------
# The whole comparison
# ---------------------------------------------------------------------------
def compare_controllers(model: JointModel | None = None, plant: Plant | None = None, *,
                        design: AdditiveDesign | None = None, arm: HumanArm = HumanArm(),
                        filter: FilterSettings | None = None, step_amplitude_nm: float = 10.0,
                        sines: tuple[tuple[float, float], ...] = ((5.0, 0.25), (15.0, 25.0)),
                        margins: bool = True, seed: int = 0, rel_tol: float = 0.05) -> dict:
    """Built-in against additive on the simulated joint: poles, steps, sines and kappa margins.

    Parameters
    ----------
    model : JointModel, optional
        Model the additive controller is designed on and whose ripple table
        the filter uses (default: Table I with a ripple table identified on ``plant``).
    plant : Plant, optional
        Simulated plant (default plant, ripple on).
    design : AdditiveDesign, optional
        Additive design (default: :func:`analysis_design`, the paper's poles on ``model``).
    arm : HumanArm
        Hand for the kappa margins.
    filter : FilterSettings, optional
        The spatial filter's settings (default: the design's beta and v_min).
    step_amplitude_nm : float
        Square-wave amplitude [Nm].
    sines : tuple of (amplitude [Nm], frequency [Hz])
        Sine references (paper: 5 Nm at 0.25 Hz, 15 Nm at 25 Hz).
    margins : bool
        Also find the kappa margins by simulation (the slow part).
    seed : int
        Noise seed.
    rel_tol : float
        Relative accuracy of the kappa margins [-].

    Returns
    -------
    dict
        ``poles`` (``builtin``: the two of eq (4) [rad/s]; ``additive``: the
        feedback and observer poles of the design [rad/s]), ``step``
        (per kind: :class:`StepResult`), ``sine`` (per kind: list of
        :class:`SineResult`), ``kappa`` (per kind: :class:`KappaMargin`, if
        ``margins``), ``kappa_ratio``, ``kappa_linear`` (per kind),
        ``kappa_linear_ratio``, ``beta``, ``model``, ``design``.
    """
    plant = plant or default_plant()
    model = model or identified_model(plant)
    params = JointParameters.from_model(model)
    design = design or analysis_design(model)
    kinds = ("builtin", "additive")
    ctrls = {k: make_controller(k, model, design, filter) for k in kinds}
    out: dict = {
        "beta": (filter or FilterSettings()).beta, "model": model, "design": design,
        "poles": {"builtin": builtin_poles(params), "additive": np.asarray(design.poles),
                  "observer": np.asarray(design.observer_poles),
                  "additive_closed_loop": np.asarray(design.additive_poles)},
        "step": {}, "sine": {}, "kappa": {}, "kappa_linear": {},
    }
    for k in kinds:
        out["step"][k] = step_response(ctrls[k], plant, step_amplitude_nm, seed=seed, model=model, filter=filter)
        out["sine"][k] = [sine_tracking(ctrls[k], plant, a, f, seed=seed, model=model, filter=filter) for a, f in sines]
        out["kappa_linear"][k] = kappa_max(params, design if k == "additive" else None, arm)
    lb, la = out["kappa_linear"]["builtin"], out["kappa_linear"]["additive"]
    out["kappa_linear_ratio"] = la / lb if lb > 0 else math.inf
    if margins:
        for k in kinds:
            out["kappa"][k] = kappa_margin(k, plant, arm, model=model, design=design, filter=filter, seed=seed,
                                           rel_tol=rel_tol)
        kb, ka = out["kappa"]["builtin"].kappa_max, out["kappa"]["additive"].kappa_max
        out["kappa_ratio"] = ka / kb if kb > 0 else math.inf
    return out
