"""The ripple search's data: runs cut into passes and the transmission deflection estimated along each.

A pass is a stretch of one run at constant speed in one direction without
gaps (:func:`find_passes`). Along it :func:`deflection` estimates
``f = theta_m - theta_j`` by either method of :mod:`iiwa_ident.ident._ripple`
(static with the link reference, dynamic with the link's own motion restored
from the torque), high-passed for the periods searched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.interpolate import BSpline

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError

__all__ = ['Pass', 'deflection', 'find_passes', 'smooth_velocity', 'spread_repeated_stamps']


@dataclass(kw_only=True)
class Pass:
    """One stretch of constant-speed motion in one direction, without gaps.

    Attributes
    ----------
    dataset : int
        Index of the dataset it comes from.
    method : str
        ``"static"`` or ``"dynamic"``.
    speed : float
        Median signed speed [rad/s].
    theta : numpy.ndarray
        Motor position q_m of the kept samples [rad].
    f : numpy.ndarray
        Deflection estimate at those samples [rad].
    t : numpy.ndarray
        Sample times [s].
    tau_hp : numpy.ndarray
        High-passed joint torque [Nm] (for eq (6) checks).
    nuisance : numpy.ndarray
        Orthonormal basis of what is slow in time (projected out of ``f``);
        fits project it out of their regressors too, so the estimate is the
        joint least-squares one.
    period_max : float
        Longest period this pass resolves: half its travel, at most the search limit [rad].
    weight : float
        Inverse noise standard deviation of the pass [1/rad], set by the fit.
    """

    dataset: int
    method: str
    speed: float
    theta: np.ndarray
    f: np.ndarray
    t: np.ndarray
    tau_hp: np.ndarray
    nuisance: np.ndarray
    period_max: float
    weight: float = 1.0



def smooth_velocity(t: np.ndarray, q: np.ndarray, window_s: float = 0.05) -> np.ndarray:
    dt = np.median(np.diff(t))
    v = np.gradient(q, t)
    n = max(1, int(round(window_s / dt)))
    if n > 1:
        kernel = np.ones(n) / n
        v = np.convolve(np.pad(v, (n // 2, n - 1 - n // 2), mode="edge"), kernel, mode="valid")
    return v


def find_passes(t: np.ndarray, q: np.ndarray, min_speed: float, min_travel: float,
                tolerance: float = 0.15) -> list[tuple[int, int]]:
    """Index ranges ``[i0, i1)`` of constant-speed motion in one direction without time gaps.

    A sample belongs to a pass when the smoothed speed is above ``min_speed``
    [rad/s] and within ``tolerance`` of the move's plateau speed; a pass
    must travel at least ``min_travel`` [rad].
    """
    dt = np.median(np.diff(t))
    v = smooth_velocity(t, q)
    gap = np.r_[False, np.diff(t) > 1.5 * dt]
    moving = np.abs(v) >= min_speed
    out = []
    i = 0
    n = len(t)
    while i < n:
        if not moving[i]:
            i += 1
            continue
        j = i + 1
        sgn = np.sign(v[i])
        while j < n and moving[j] and np.sign(v[j]) == sgn and not gap[j]:
            j += 1
        # Keep the constant-speed core: samples within tolerance of the plateau speed (the
        # median would be pulled down by the acceleration ramps of a short move).
        seg = v[i:j]
        plateau = sgn * np.percentile(np.abs(seg), 90)
        ok = np.abs(seg - plateau) <= tolerance * abs(plateau)
        k = 0
        while k < len(seg):
            if not ok[k]:
                k += 1
                continue
            m = k
            while m < len(seg) and ok[m]:
                m += 1
            if abs(q[i + m - 1] - q[i + k]) >= min_travel:
                out.append((i + k, i + m))
            k = m
        i = j
    return out


def _smooth_basis(t: np.ndarray, knot_spacing: float) -> np.ndarray:
    """Cubic B-spline basis over ``t`` with knots about ``knot_spacing`` apart (plus a constant)."""
    t0, t1 = float(t[0]), float(t[-1])
    n_int = max(1, int(math.ceil((t1 - t0) / knot_spacing)))
    inner = np.linspace(t0, t1, n_int + 1)
    knots = np.r_[[t0] * 3, inner, [t1] * 3]
    return BSpline.design_matrix(np.clip(t, t0, t1), knots, 3).toarray()


class _PassDeflection(NamedTuple):
    """One pass's deflection estimate, high-passed torque and nuisance basis."""

    deflection: np.ndarray
    tau_hp: np.ndarray
    basis: np.ndarray


def _pass_deflection(t: np.ndarray, q: np.ndarray, tau: np.ndarray, q_l: np.ndarray | None, K: float,
                     Jl: float | None, f_cut: float) -> _PassDeflection:
    """Deflection estimate, high-passed torque and nuisance basis of one pass.

    ``q - tau/K - theta_l`` with theta_l the measured link position (static)
    or the double integral of tau/J_l (dynamic: the link's own motion under
    the joint torque, eq (2); zero when ``Jl`` is None, the link's motion
    neglected); whatever is slow in time (integration
    constants, friction, gravity, the tracking controller) lies in the span
    of a cubic spline with knots 1/f_cut apart, which is projected out. It
    passes every period shorter than the search limit essentially untouched.
    """
    Q, _ = np.linalg.qr(_smooth_basis(t, 1.0 / f_cut))
    if q_l is None and Jl is None:
        theta_l = np.zeros_like(q)
    elif q_l is None:
        tc = t - t[0]
        acc = (tau - tau.mean()) / Jl
        vel = np.r_[0.0, np.cumsum(0.5 * (acc[1:] + acc[:-1]) * np.diff(tc))]
        theta_l = np.r_[0.0, np.cumsum(0.5 * (vel[1:] + vel[:-1]) * np.diff(tc))]
    else:
        theta_l = q_l
    raw = q - tau / K - theta_l
    return _PassDeflection(raw - Q @ (Q.T @ raw), tau - Q @ (Q.T @ tau), Q)


def spread_repeated_stamps(t: np.ndarray) -> np.ndarray:
    """Time stamps with each run of repeated stamps spread evenly towards the next distinct one.

    Real 200 Hz logs stamp a few consecutive samples alike (the logger, not the robot, repeats a
    stamp); the samples were taken a period apart, and a velocity or an integral over a zero time
    step would be infinite.
    """
    t = np.asarray(t, dtype=float)
    same = np.r_[False, np.diff(t) <= 0.0]
    if not same.any():
        return t
    out = t.copy()
    i, n = 1, len(t)
    while i < n:
        if not same[i]:
            i += 1
            continue
        j = i
        while j < n and same[j]:
            j += 1
        # Samples i-1 .. j-1 share a stamp; spread them up to the next distinct one (or one period on).
        t0 = out[i - 1]
        t1 = t[j] if j < n else t0 + (j - i + 1) * float(np.median(np.diff(t[~same])))
        out[i - 1:j] = t0 + (t1 - t0) * np.arange(j - i + 1) / (j - i + 1)
        i = j
    return out


def deflection(dataset: Dataset, index: int, K: float, Jl: float, period_max: float, min_speed: float,
               min_travel: float, method: str | None = None, link_motion: str = "restored") -> list[Pass]:
    """The passes of one dataset with their deflection estimates.

    Parameters
    ----------
    dataset : Dataset
        Constant-velocity run (dynamic method) or quasi-static run with
        ``q_l_ref`` (static method).
    K, Jl : float
        Stiffness [Nm/rad] and link inertia [kg m^2] of the model.
    period_max : float
        Longest period searched [rad]; a pass resolves periods up to half
        its travel, and its high-pass keeps every period it resolves.
    min_speed : float
        Slowest motion used [rad/s].
    min_travel : float
        Shortest pass kept [rad].
    method : str, optional
        Force ``"static"`` or ``"dynamic"`` (default: static for quasi_static runs).
    link_motion : str
        Dynamic method: ``"restored"`` (the link's own motion from the torque and ``Jl``, eq (2))
        or ``"neglected"`` (theta_l taken as constant over the pass).
    """
    if link_motion not in ("restored", "neglected"):
        raise IiwaIdentError(f"ripple: link_motion must be restored or neglected, got {link_motion!r}")
    t, q, tau = spread_repeated_stamps(dataset["t"]), dataset["q_m"], dataset["tau_j"]
    if method is None:
        method = "static" if dataset.experiment == "quasi_static" else "dynamic"
    if method == "static" and not dataset.has("q_l_ref"):
        raise IiwaIdentError(f"{dataset.path or 'dataset'}: the static method needs the link reference q_l_ref")
    q_l = dataset["q_l_ref"] if method == "static" else None
    out = []
    for i0, i1 in find_passes(t, q, min_speed, min_travel=min_travel):
        if i1 - i0 < 16:
            continue
        speed = float(np.median(np.diff(q[i0:i1]) / np.diff(t[i0:i1])))
        longest = min(period_max, abs(q[i1 - 1] - q[i0]) / 2)
        f_cut = 0.5 * abs(speed) / longest
        f, th, Q = _pass_deflection(t[i0:i1], q[i0:i1], tau[i0:i1], None if q_l is None else q_l[i0:i1], K,
                                    Jl if link_motion == "restored" else None, f_cut)
        out.append(Pass(dataset=index, method=method, speed=speed, theta=q[i0:i1], f=f, t=t[i0:i1], tau_hp=th,
                        nuisance=Q, period_max=longest))
    return out
