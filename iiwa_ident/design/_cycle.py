"""The additive controller's work in one sample: the one control cycle of analysis and runtime.

:class:`ControlCycle` is stepped once per 1 kHz sample by the closed-loop
analysis on the simulated joint (:mod:`iiwa_ident.design._analysis`) and by
the FRI runtime on the robot (:mod:`iiwa_ident.runtime`, which adds the
task, the watchdog and the limits around it). Per sample:

1. position correction, eqs (8)-(9): ``theta_j = q_m - f(q_m)``,
   ``theta_l = theta_j - tau_J / K``;
2. spatial filter of the joint torque along ``theta_j``, eqs (10)-(12), (15);
3. the improved external-torque observer, eq (13) on the link velocity of
   eq (9), spatially filtered, eq (14) (when an observer gain is given);
4. the additive controller, eqs (16)-(18).

Torque offset: the controller's model (eqs (19)-(21)) starts at rest with
zero torque, so the cycle regulates ``tau_J`` relative to its value at the
sample it (re)starts from (gravity on a joint whose load does not change
during the run, sensor offset). The first sample after a (re)start only
records that state and commands nothing.
"""

from __future__ import annotations

from iiwa_ident.design._controller import AdditiveController
from iiwa_ident.design._spatial_filter import FilterSettings, SpatialFilter
from iiwa_ident.model import MomentumObserver, RippleTable
from iiwa_ident.robot import Measurement

__all__ = ["ControlCycle"]


class ControlCycle:
    """Eqs (8)-(18) once per sample (module docstring).

    Parameters
    ----------
    controller : AdditiveController
        The discrete additive controller of eqs (16)-(18).
    filter : FilterSettings, optional
        The spatial filters' beta, v_min and period (default: the design's beta and v_min at the
        lookup table's period; a period other than the table's is refused with ValueError).
    dt : float
        Sample time [s].
    ripple : RippleTable, optional
        Lookup table of eq (8) (``theta_j = q_m`` without one).
    K : float, optional
        Joint stiffness of eq (9) [Nm/rad]; with ``KI`` and ``Jl`` it enables the observer.
    KI : float, optional
        Observer gain of eq (13) [1/s].
    Jl : float, optional
        Link inertia of eq (13) [kg m^2].

    Examples
    --------
    >>> from iiwa_ident.design import AdditiveController, design_controller, table1_parameters
    >>> from iiwa_ident.robot import Measurement
    >>> params, _ = table1_parameters()
    >>> cycle = ControlCycle(AdditiveController(design_controller(params)))
    >>> cycle.step(Measurement(0.0, 0.0, 2.0, 0.0), tau_r=5.0)  # (re)start: takes the 2 Nm offset
    0.0
    >>> cycle.step(Measurement(0.001, 0.0, 2.0, 0.0), tau_r=5.0) > 0.0
    True
    >>> cycle.tau_j_filt
    0.0
    """

    def __init__(self, controller: AdditiveController, *, filter: FilterSettings | None = None, dt: float = 1e-3,
                 ripple: RippleTable | None = None, K: float | None = None, KI: float | None = None,
                 Jl: float | None = None) -> None:
        self.controller = controller
        self.ripple = ripple
        self.dt = float(dt)
        #: The spatial filters' settings; they work at the lookup table's period (one rho for both).
        self.filter = filter or FilterSettings()
        self.torque_filter = SpatialFilter.from_settings(self.filter, ripple, dt)
        self._K: float | None = None
        self.observer: MomentumObserver | None = None
        self.observer_filter: SpatialFilter | None = None
        if K is not None and KI is not None and Jl is not None:
            self._K = float(K)
            self.observer = MomentumObserver(KI, Jl, dt)
            self.observer_filter = SpatialFilter.from_settings(self.filter, ripple, dt)
        self.started = False
        self.tau_offset = 0.0  #: tau_J at the (re)start [Nm]
        self.theta_j = 0.0  #: joint position of eq (8) at the last sample [rad]
        self.tau_j_filt = 0.0  #: filtered joint torque of eq (15), offset removed [Nm]
        self.tau_ext = 0.0  #: filtered external-torque estimate of eq (14) [Nm] (0 without observer)
        self._theta_l_prev = 0.0

    @property
    def speed(self) -> float:
        """Smoothed joint speed the spatial filter sees [rad/s]."""
        return self.torque_filter.speed

    def _theta(self, q_m: float, tau_j: float) -> tuple[float, float]:
        """theta_j of eq (8) and theta_l of eq (9) [rad]."""
        theta_j = q_m - self.ripple.at(q_m) if self.ripple is not None else q_m
        return theta_j, (theta_j - tau_j / self._K if self._K else theta_j)

    def reset(self) -> None:
        """Forget everything; the next sample (re)starts the cycle."""
        self.started = False

    def restart(self, meas: Measurement) -> None:
        """Start from rest at this measurement: filters, observer and controller cleared, offset taken."""
        self.tau_offset = meas.tau_j
        self.theta_j, self._theta_l_prev = self._theta(meas.q_m, meas.tau_j)
        self.torque_filter.reset()
        self.torque_filter.step(0.0, self.theta_j)
        if self.observer is not None and self.observer_filter is not None:
            self.observer.reset()
            self.observer_filter.reset()
            self.observer_filter.step(0.0, self.theta_j)
        self.controller.reset()
        self.tau_j_filt = self.tau_ext = 0.0
        self.started = True

    def observe(self, meas: Measurement, gap_cycles: float = 1.0) -> None:
        """Steps 1-3: ``theta_j``, ``tau_j_filt`` and ``tau_ext`` from this sample's measurement.

        ``gap_cycles`` is the number of samples since the previous measurement
        (1 when none was lost or late); the link velocity is taken over it.
        """
        theta_j, theta_l = self._theta(meas.q_m, meas.tau_j)
        self.theta_j = theta_j
        tau = meas.tau_j - self.tau_offset
        self.tau_j_filt = self.torque_filter.step(tau, theta_j)  # eq (15)
        if self.observer is not None and self.observer_filter is not None:
            v_l = (theta_l - self._theta_l_prev) / (self.dt * max(gap_cycles, 1.0))
            self._theta_l_prev = theta_l
            self.tau_ext = self.observer_filter.step(self.observer.update(v_l, tau), theta_j)  # eqs (13)-(14)

    def command(self, tau_r: float) -> float:
        """Step 4: the additive controller's torque [Nm] for reference ``tau_r`` [Nm], eqs (16)-(18)."""
        return self.controller.step(tau_r, self.tau_j_filt)

    def step(self, meas: Measurement, tau_r: float, gap_cycles: float = 1.0) -> float:
        """One sample: measurement and reference [Nm] -> additive torque [Nm] (0 at a (re)start)."""
        if not self.started:
            self.restart(meas)
            return 0.0
        self.observe(meas, gap_cycles)
        return self.command(tau_r)
