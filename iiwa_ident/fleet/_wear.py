"""Worn joints of a fleet: a detected ripple larger than the fleet's for that joint by more than its uncertainty.

The comparison is in the logarithm of the amplitude, where a joint's ripple is
a factor away from the fleet's: for joint ``j`` of robot ``r``,
``d = ln(A_rj / median_r' A_r'j)``, whose uncertainty combines

- the amplitude's own standard error (:attr:`~iiwa_ident.ident.RippleResult.amplitude_std_rad`,
  ``std / A`` in the logarithm),
- the spread of healthy joints around the median, ``sigma_fleet``: of the groups whose ``d`` lies within 3.5
  robust (median absolute deviation) spreads, pooled over the joint numbers, the spread beyond each one's own
  measurement variance (Paule-Mandel: the weighted squares of ``d`` match their degrees of freedom), and
- the median's own standard error, ``sqrt(pi / 2 / n)`` times that spread.

A group is flagged when the one-sided probability of a ``d`` this large under
those uncertainties (Student's t, the spread being estimated) is below the fleet's false-alarm probability divided by
the number of groups compared (Bonferroni: the chance of flagging any healthy
joint of the fleet stays below ``false_alarm``). An undetected ripple has no
amplitude estimate, and a joint number with fewer than three detections no
fleet median: neither is judged, and the row says why.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["WEAR_FALSE_ALARM", "MIN_GROUPS", "flag_worn"]

#: Probability that any healthy joint of the fleet is flagged.
WEAR_FALSE_ALARM = 0.01
#: Detections of one joint number needed for a fleet median.
MIN_GROUPS = 3


def _estimate(row: dict[str, Any]) -> tuple[float, float] | None:
    """(amplitude, its std) [rad] of a group with a detected ripple and a finite std, else None."""
    r = row.get("ripple") or {}
    a, s = r.get("amplitude_rad"), r.get("amplitude_std_rad")
    if row.get("error") or not r.get("detected") or a is None or s is None:
        return None
    a, s = float(a), float(s)
    # A zero or non-finite std is no uncertainty to judge by (and would make z infinite in the JSON).
    return (a, s) if math.isfinite(a) and a > 0 and math.isfinite(s) and s > 0 else None


def _healthy_spread(d: np.ndarray, own: np.ndarray, dof: int) -> float:
    """The spread sigma of ``d`` beyond each group's own measurement variance ``own`` (Paule-Mandel: the
    sigma at which the weighted squares of ``d`` match their ``dof``), 0 where the measurements explain it all.

    Subtracting the mean measurement variance from the total instead fails where a few measurements are far
    noisier than the rest: at 0.25 µrad a fleet drawn with a 30 % spread read 4 %, and four healthy joints at
    1.3-1.9x the median were flagged.
    """
    def excess(s2: float) -> float:
        return float(np.sum(d ** 2 / (s2 + own))) - dof

    if len(d) < 2 or excess(0.0) <= 0.0:
        return 0.0
    from scipy import optimize  # here: the fleet's command line starts without it

    hi = max(float(np.max(d ** 2)), 1e-12)
    while excess(hi) > 0.0:
        hi *= 4.0
    return math.sqrt(optimize.brentq(excess, 0.0, hi, xtol=1e-14))


def flag_worn(groups: list[dict[str, Any]], false_alarm: float = WEAR_FALSE_ALARM) -> dict[str, Any]:
    """Judge every group of a fleet ripple run against the fleet's median for its joint number.

    Parameters
    ----------
    groups : list of dict
        The rows of :func:`~iiwa_ident.fleet.run_fleet` for the ripple stage (``robot``, ``joint``,
        ``ripple``: the :meth:`~iiwa_ident.ident.RippleResult.to_json` document, ``error``).
    false_alarm : float
        Probability that any healthy joint of the fleet is flagged (0-1).

    Returns
    -------
    dict
        ``false_alarm``, ``sigma_fleet`` (the healthy spread, in the logarithm of the amplitude [-], None when
        no joint number has enough detections), ``compared`` (groups judged), ``threshold_p``, ``flagged``
        (``[robot, joint]`` pairs) and ``rows``: per group, in the order given, ``fleet_median_rad``, ``ratio``
        (amplitude / median), ``z``, ``p`` and ``worn`` (True, False, or None with ``why`` when not judged).

    Examples
    --------
    >>> rows = [{"robot": f"r{i}", "joint": 1, "error": None,
    ...          "ripple": {"detected": True, "amplitude_rad": a * 1e-6, "amplitude_std_rad": 0.5e-6}}
    ...         for i, a in enumerate([20, 22, 18, 21, 19, 80])]
    >>> out = flag_worn(rows)
    >>> out["flagged"]
    [['r5', 1]]
    """
    from scipy import stats  # here: the fleet's command line starts without it

    if not 0.0 < false_alarm < 1.0:
        raise ValueError(f"false_alarm must lie in (0, 1), got {false_alarm!r}")
    est = [_estimate(g) for g in groups]
    known = {i: e for i, e in enumerate(est) if e is not None}
    by_joint: dict[Any, list[int]] = {}
    for i in known:
        by_joint.setdefault(groups[i].get("joint"), []).append(i)
    medians = {j: float(np.median([math.log(known[i][0]) for i in idx]))
               for j, idx in by_joint.items() if len(idx) >= MIN_GROUPS}
    judged = [i for j in medians for i in by_joint[j]]
    sigma_fleet: float | None = None
    dof = 1
    if judged:
        d = np.array([math.log(known[i][0]) - medians[groups[i]["joint"]] for i in judged])
        own = np.array([(known[i][1] / known[i][0]) ** 2 for i in judged])
        # The spread of d from the groups within 3.5 robust (MAD) spreads of the median: as robust to the worn
        # ones as the MAD, and as efficient as a standard deviation (the MAD's own error flagged healthy joints
        # of a 210-joint fleet).
        mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
        keep = np.abs(d - np.median(d)) <= 3.5 * mad if mad > 0 else np.ones(len(d), bool)
        dof = max(int(keep.sum()) - len(medians), 1)
        sigma_fleet = _healthy_spread(d[keep], own[keep], dof)
    threshold = false_alarm / max(len(judged), 1)
    rows, flagged = [], []
    for g, e in zip(groups, est):
        row: dict[str, Any] = {"fleet_median_rad": None, "ratio": None, "z": None, "p": None, "worn": None}
        j = g.get("joint")
        if g.get("error"):
            row["why"] = "the group failed"
        elif not (g.get("ripple") or {}).get("detected"):
            row["why"] = "no ripple detected: no amplitude to compare"
        elif e is None:
            row["why"] = "amplitude std unknown (fewer than three passes) or zero"
        elif j not in medians:
            row["why"] = f"fewer than {MIN_GROUPS} detections of joint {j} in the fleet: no median to compare with"
        else:
            assert sigma_fleet is not None  # a joint with a median is judged, so the spread is known
            a, s = e
            n = len(by_joint[j])
            var = (s / a) ** 2 + sigma_fleet ** 2 + math.pi / 2.0 / n * (sigma_fleet ** 2 + (s / a) ** 2)
            z = (math.log(a) - medians[j]) / math.sqrt(var) if var > 0 else math.inf
            # Student's t: the spread is itself estimated from the fleet.
            p = float(stats.t.sf(z, dof))
            row.update(fleet_median_rad=math.exp(medians[j]), ratio=a / math.exp(medians[j]), z=z, p=p,
                       worn=bool(p < threshold))
            if row["worn"]:
                flagged.append([g.get("robot"), j])
        rows.append(row)
    return {"false_alarm": false_alarm, "sigma_fleet": sigma_fleet, "compared": len(judged),
            "threshold_p": threshold, "flagged": flagged, "rows": rows}
