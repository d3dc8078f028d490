"""The three external-torque observers of section IV, behind one interface.

All three are the momentum observer of eq (13),
``tau_ext_hat = KI [ Jl v - int (tau_J + tau_ext_hat) dt - Jl v(0) ]``,
and differ in the velocity ``v`` they use and in what follows:

``builtin`` (:class:`BuiltinObserver`)
    ``v`` from finite differences of the motor position q_m, as the robot's
    own observer does (it ignores the series elasticity and the ripple).
``improved`` (:class:`LinkVelocityObserver`)
    ``v`` from finite differences of the link position of eq (9),
    ``theta_l = q_m - f(q_m mod rho) - tau_J / K``.
``filtered`` (:class:`FilteredObserver`)
    The improved estimate passed through the spatial filter of eqs (10)-(12),
    along the joint position of eq (8): eq (14).

Each offers :meth:`~ExternalTorqueObserver.update` (one sample, for a 1 kHz
loop) and :meth:`~ExternalTorqueObserver.run` (a whole record, same numbers).
The velocity needs two positions, so the first sample only stores the
position and returns 0 (``tau_ext_hat(0) = 0``); the momentum observer
starts at the second sample with ``p(0) = Jl v_1``, so a record that
starts in motion gives no start transient.

:func:`compare_observers` scores the three against the F/T reference of a
hand-guided record (Fig. 7). Eq (13) reaches the external torque only
through its first-order lag ``KI / (s + KI)`` (time constant 1 / KI =
40 ms at KI = 25 rad/s), an error common to the three variants and large while
a hand pushes against the controlled damping; so besides the error against
the raw reference the table gives the error against the reference passed
through that lag, which is what the improvements of section IV can reduce.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from iiwa_ident.datasets import Dataset
from iiwa_ident.design._spatial_filter import PAPER_FILTER, FilterSettings, SpatialFilter
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model import JointModel, MomentumObserver, joint_position, link_position

__all__ = [
    "ExternalTorqueObserver",
    "BuiltinObserver",
    "LinkVelocityObserver",
    "FilteredObserver",
    "OBSERVERS",
    "make_observer",
    "run_observers",
    "observer_lag",
    "link_speed",
    "compare_observers",
]

#: Records whose sample time differs from the observer's by more than this (relative) are refused.
_DT_TOLERANCE = 1e-6


class _Signals(NamedTuple):
    """q_m [rad], tau_j [Nm] and the sample time [s] where the data tells it."""

    q_m: np.ndarray
    tau_j: np.ndarray
    dt: float | None


def _signals(data: Any) -> _Signals:
    """q_m [rad], tau_j [Nm] and the sample time [s] if the data tells it."""
    if isinstance(data, tuple):
        q_m, tau_j = data
        return _Signals(np.asarray(q_m, float), np.asarray(tau_j, float), None)
    q_m, tau_j = np.asarray(data["q_m"], float), np.asarray(data["tau_j"], float)
    if isinstance(data, Dataset):
        return _Signals(q_m, tau_j, 1.0 / data.sample_rate_hz)
    if isinstance(data, Mapping) and "t" in data and len(data["t"]) > 1:
        return _Signals(q_m, tau_j, float(np.median(np.diff(np.asarray(data["t"], float)))))
    return _Signals(q_m, tau_j, None)


class ExternalTorqueObserver:
    """Eq (13) on a velocity obtained by differencing a position; subclasses choose the position.

    Parameters
    ----------
    model : JointModel
        Supplies K [Nm/rad], Jl [kg m^2], KI [rad/s] and the ripple table.
    dt : float
        Sample time [s].
    """

    #: Short name used in tables and figures.
    name = "base"
    #: One-line description for legends.
    label = ""

    def __init__(self, model: JointModel, dt: float = 1e-3) -> None:
        if dt <= 0:
            raise ValueError("observer: dt must be positive")
        self.model, self.dt = model, float(dt)
        self.K, self.Jl, self.KI = model.value("K"), model.value("Jl"), model.value("KI")
        self.table = model.ripple
        self._momentum = MomentumObserver(self.KI, self.Jl, self.dt)
        self.reset()

    # -- what a subclass decides ---------------------------------------------
    def position(self, q_m: np.ndarray | float, tau_j: np.ndarray | float) -> np.ndarray | float:
        """The position [rad] whose difference is the observer's velocity (scalar or array)."""
        raise NotImplementedError

    def _post(self, estimate: float, q_m: float) -> float:
        return estimate

    def _post_batch(self, estimate: np.ndarray, q_m: np.ndarray) -> np.ndarray:
        return estimate

    # -- interface -------------------------------------------------------------
    def reset(self) -> None:
        """Forget the past: the next :meth:`update` is the first sample."""
        self._momentum.reset()
        self._x_prev: float | None = None

    def update(self, q_m: float, tau_j: float, tau_model: float = 0.0) -> float:
        """One sample: motor position [rad], joint torque [Nm], model torque [Nm] -> estimate [Nm].

        ``tau_model`` is the torque the robot's model assigns to the link
        (gravity), zero for the base joint.
        """
        x = float(self.position(q_m, tau_j))
        if self._x_prev is None:
            self._x_prev = x
            return self._post(0.0, q_m)
        v = (x - self._x_prev) / self.dt
        self._x_prev = x
        return self._post(self._momentum.update(v, tau_j, tau_model), q_m)

    def run(self, data: Dataset | Mapping[str, np.ndarray] | tuple[np.ndarray, np.ndarray],
            tau_model: np.ndarray | float = 0.0) -> np.ndarray:
        """The estimate for a whole record, from a fresh state (the running state is untouched).

        Parameters
        ----------
        data : Dataset, mapping or (q_m, tau_j)
            Signals ``q_m`` [rad] and ``tau_j`` [Nm] sampled at this observer's ``dt``
            (a dataset or a mapping with ``t`` is checked against it).
        tau_model : float or array
            Model torque on the link [Nm] (gravity; 0 for the base joint).

        Returns
        -------
        numpy.ndarray
            External-torque estimate [Nm], one per sample, 0 at the first.
        """
        q_m, tau_j, dt = _signals(data)
        if q_m.shape != tau_j.shape or q_m.ndim != 1 or len(q_m) < 2:
            raise IiwaIdentError("observer: q_m and tau_j must be 1-D, of one length, at least 2 samples")
        if dt is not None and abs(dt - self.dt) > _DT_TOLERANCE * self.dt:
            raise IiwaIdentError(f"observer: the record is sampled every {dt * 1e3:.4g} ms, the observer "
                                 f"every {self.dt * 1e3:.4g} ms; build it with dt={dt:g}")
        x = np.asarray(self.position(q_m, tau_j), float)
        v = np.diff(x) / self.dt
        tm = np.broadcast_to(np.asarray(tau_model, float), q_m.shape)[1:]
        est = MomentumObserver(self.KI, self.Jl, self.dt).filter(v, tau_j[1:], tm)
        return self._post_batch(np.concatenate([[0.0], est]), q_m)


class BuiltinObserver(ExternalTorqueObserver):
    """The robot's own observer: eq (13) on the motor-side velocity (differences of q_m)."""

    name = "builtin"
    label = "built-in (motor velocity)"

    def position(self, q_m: np.ndarray | float, tau_j: np.ndarray | float) -> np.ndarray | float:
        """The motor position q_m [rad] itself."""
        return q_m


class LinkVelocityObserver(ExternalTorqueObserver):
    """Eq (13) on the link velocity: differences of theta_l from eq (9)."""

    name = "improved"
    label = "link velocity, eq (9)"

    def position(self, q_m: np.ndarray | float, tau_j: np.ndarray | float) -> np.ndarray | float:
        """The link position theta_l [rad] of eq (9)."""
        return link_position(q_m, tau_j, self.K, self.table)


class FilteredObserver(LinkVelocityObserver):
    """Eq (14): the link-velocity estimate through the spatial filter H_filt of eqs (10)-(12).

    The filter runs along the joint position of eq (8) at the period of
    the model's ripple table.

    Parameters
    ----------
    model : JointModel
        Must have a ripple table (its period sets the filter).
    dt : float
        Sample time [s].
    filter : FilterSettings
        The spatial filter (default: the paper's beta and v_min); its period is the table's.
    """

    name = "filtered"
    label = "link velocity + spatial filter, eq (14)"

    def __init__(self, model: JointModel, dt: float = 1e-3, filter: FilterSettings = PAPER_FILTER) -> None:
        if model.ripple is None:
            raise IiwaIdentError("observer: the spatially filtered observer needs the model's ripple table "
                                 "(run the ripple identification first)")
        self.filter = SpatialFilter.from_settings(filter, model.ripple, dt)
        super().__init__(model, dt)

    def reset(self) -> None:
        super().reset()
        self.filter.reset()

    def _post(self, estimate: float, q_m: float) -> float:
        return self.filter.step(estimate, float(joint_position(q_m, self.table)))

    def _post_batch(self, estimate: np.ndarray, q_m: np.ndarray) -> np.ndarray:
        return self.filter.apply(estimate, np.asarray(joint_position(q_m, self.table), float), self.dt)


#: The observers by name, in the order of Fig. 7.
OBSERVERS: dict[str, type[ExternalTorqueObserver]] = {
    cls.name: cls for cls in (BuiltinObserver, LinkVelocityObserver, FilteredObserver)
}


def make_observer(name: str, model: JointModel, dt: float = 1e-3, **options: float) -> ExternalTorqueObserver:
    """The observer called ``name`` (``builtin``, ``improved`` or ``filtered``); options go to its constructor."""
    try:
        cls = OBSERVERS[name]
    except KeyError:
        raise IiwaIdentError(f"observer: unknown {name!r} (known: {', '.join(OBSERVERS)})") from None
    return cls(model, dt, **options)


def _dt(dataset: Dataset) -> float:
    return 1.0 / dataset.sample_rate_hz


def run_observers(dataset: Dataset, model: JointModel, filter: FilterSettings = PAPER_FILTER) -> dict[str, np.ndarray]:
    """The three estimates [Nm] for a record, by observer name (``filtered``, with the spatial filter ``filter``,
    only with a ripple table)."""
    dt = _dt(dataset)
    out = {"builtin": BuiltinObserver(model, dt).run(dataset),
           "improved": LinkVelocityObserver(model, dt).run(dataset)}
    if model.ripple is not None:
        out["filtered"] = FilteredObserver(model, dt, filter).run(dataset)
    return out


def observer_lag(tau: np.ndarray, KI: float, dt: float) -> np.ndarray:
    """What eq (13) would report with a perfect velocity: ``tau`` [Nm] through its own lag.

    With the exact link momentum, the discrete eq (13) of
    :class:`~iiwa_ident.model.MomentumObserver` reduces to
    ``tau_hat_{k+1} = tau_hat_k + KI dt (tau_k - tau_hat_k)``, ``tau_hat_0 = 0``:
    a first-order lag of time constant ``1 / KI`` [s].

    Examples
    --------
    >>> [round(float(x), 4) for x in observer_lag(np.ones(4), KI=25.0, dt=1e-3)]  # a 1 Nm step
    [0.0, 0.025, 0.0494, 0.0731]
    """
    a = KI * dt
    return lfilter([0.0, a], [1.0, -(1.0 - a)], np.asarray(tau, float))


def link_speed(dataset: Dataset, model: JointModel, window_s: float = 0.02) -> np.ndarray:
    """Link speed [rad/s] from eq (9), differenced and averaged over ``window_s`` [s]."""
    dt = _dt(dataset)
    theta_l = link_position(np.asarray(dataset["q_m"], float), np.asarray(dataset["tau_j"], float),
                            model.value("K"), model.ripple)
    v = np.gradient(theta_l, dt)
    # Averaging over several ripple periods keeps its velocity fluctuation and the sensor noise out of the mask.
    return uniform_filter1d(v, max(1, int(round(window_s / dt))), mode="nearest")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


def compare_observers(dataset: Dataset, model: JointModel, speed_threshold: float = 0.5,
                      filter: FilterSettings = PAPER_FILTER,
                      estimates: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """RMS errors of the three observers against the F/T reference of a hand-guided record (Fig. 7).

    Parameters
    ----------
    dataset : Dataset
        A record with ``q_m``, ``tau_j`` and ``tau_ext_ref`` (the external
        F/T torque about the joint axis); ``tau_ext_fri`` is scored too when present.
    model : JointModel
        K, Jl, KI and the ripple table (its period sets the spatial filter).
    speed_threshold : float
        Link speed [rad/s] above which samples count as fast.
    filter : FilterSettings
        The spatial filter of eqs (10)-(12) (default: the paper's; a design's ``record.filter`` as deployed).
    estimates : dict, optional
        Estimates already computed by :func:`run_observers`.

    Returns
    -------
    dict
        ``observers``: per name (``builtin``, ``improved``, ``filtered``, and
        ``fri`` for the robot's reported estimate) a dict of RMS errors [Nm]:
        ``rms_nm`` (all samples), ``rms_fast_nm`` (link speed above the
        threshold), and ``rms_lagged_nm`` / ``rms_lagged_fast_nm`` against the
        reference through the observer's own lag (:func:`observer_lag`).
        ``ratio_fast`` and ``ratio_lagged_fast``: built-in over filtered fast
        errors. ``fast_fraction``, ``n_samples``, ``speed_threshold_rad_s``,
        ``observer_gain_rad_s``, ``beta``, ``v_min_rad_s``.

    Notes
    -----
    The link speed that selects the fast samples is that of eq (9)
    (:func:`link_speed`): only measured signals are used.
    """
    if not dataset.has("tau_ext_ref"):
        raise IiwaIdentError("compare observers: the record has no external torque reference (tau_ext_ref)")
    dt = _dt(dataset)
    est = dict(estimates) if estimates is not None else run_observers(dataset, model, filter)
    if dataset.has("tau_ext_fri"):
        est["fri"] = np.asarray(dataset["tau_ext_fri"], float)
    ref = np.asarray(dataset["tau_ext_ref"], float)
    lagged = observer_lag(ref, model.value("KI"), dt)
    fast = np.abs(link_speed(dataset, model)) > speed_threshold
    rows = {}
    for name, e in est.items():
        err, err_lag = e - ref, e - lagged
        rows[name] = {"rms_nm": _rms(err), "rms_fast_nm": _rms(err[fast]),
                      "rms_lagged_nm": _rms(err_lag), "rms_lagged_fast_nm": _rms(err_lag[fast])}
    out: dict[str, Any] = {
        "observers": rows,
        "speed_threshold_rad_s": float(speed_threshold),
        "fast_fraction": float(fast.mean()),
        "n_samples": int(len(ref)),
        "observer_gain_rad_s": model.value("KI"),
        "beta": float(filter.beta),
        "v_min_rad_s": float(filter.v_min_rad_s),
    }
    if "filtered" in rows:
        b, f = rows["builtin"], rows["filtered"]
        out["ratio_fast"] = b["rms_fast_nm"] / f["rms_fast_nm"]
        out["ratio_lagged_fast"] = b["rms_lagged_fast_nm"] / f["rms_lagged_fast_nm"]
    return out
