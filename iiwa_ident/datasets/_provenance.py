"""What a log says about itself: checks of an imported run against the robot's description.

Each check returns one line for the user, or None; :func:`dataset_warnings` gathers them for ``import`` and
``info``.
"""

from __future__ import annotations

import numpy as np

from iiwa_ident.datasets._format import Dataset, dataset_pose
from iiwa_ident.datasets._import import moving_joint_problem

__all__ = ["torque_sign_problem", "dataset_warnings", "SIGN_MIN_GRAVITY_NM"]

#: The gravity torque must change by at least this much over the run to tell the reading's sign [Nm].
SIGN_MIN_GRAVITY_NM = 0.5
#: ... and its coefficient be this many standard errors from zero.
_SIGN_MIN_T = 10.0
_MOVING_RAD_S = 0.02  # samples slower than this are left out (stiction, reversal)


def torque_sign_problem(dataset: Dataset) -> str | None:
    """A warning when the torque reading's sign is opposite to the toolkit's convention, or None.

    The convention: ``tau_j`` is the torque the joint exerts on its link, so holding the link against
    gravity reads as the description's gravity torque ``g(q)``. Over the run, ``tau_j`` is regressed on
    ``g(q_j)`` at the dataset's pose (:mod:`iiwa_ident.description`) with a friction ``tanh(omega / 0.01)``,
    a viscous term and a constant, on the samples where the joint moves. A coefficient of ``g`` near -1 (below
    -0.5, at least 10 standard errors from zero) is a reading of the other sign (the real iiwa 14 logs of
    Drake's driver read -0.94 to -1.29 on joints 2, 4 and 6). Joints without a gravity torque that changes by
    :data:`SIGN_MIN_GRAVITY_NM` over the run (a vertical axis) do not decide it, nor datasets without robot
    and pose: None.
    """
    robot, pose = dataset_pose(dataset)
    if pose is None or not dataset.has("q_m") or not dataset.has("tau_j"):
        return None
    from iiwa_ident.description import ROBOTS, gravity_sinusoid

    if (robot or "iiwa14") not in ROBOTS:
        return None
    amp, phase = gravity_sinusoid(robot or "iiwa14", dataset.joint, pose)
    q = np.asarray(dataset["q_m"], float)
    t = np.asarray(dataset.t, float)
    g = amp * np.sin(q + phase)
    if len(q) < 10 or np.ptp(g) < SIGN_MIN_GRAVITY_NM:
        return None
    # Central differences over about 20 ms: the encoder's steps average out.
    k = max(1, int(round(0.02 * dataset.sample_rate_hz)))
    w = np.zeros_like(q)
    w[k:-k] = (q[2 * k:] - q[:-2 * k]) / (t[2 * k:] - t[:-2 * k])
    moving = np.abs(w) > _MOVING_RAD_S
    if moving.sum() < 10:
        return None
    X = np.column_stack([g, np.tanh(w / 0.01), w, np.ones_like(q)])[moving]
    y = np.asarray(dataset["tau_j"], float)[moving]
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    try:
        cov = float(r @ r) / max(len(y) - X.shape[1], 1) * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return None
    a, se = float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0)))
    if a < -0.5 and abs(a) >= _SIGN_MIN_T * se:
        return (f"tau_j reads the other way round: it follows the description's gravity torque with the factor "
                f"{a:.2f} (the convention: the torque the joint exerts on its link, +1); import the log with "
                "--scale tau_j=-1")
    return None


def dataset_warnings(dataset: Dataset) -> list[str]:
    """Every check's warning for ``dataset`` (the joint given did not move; the torque's sign)."""
    return [w for w in (moving_joint_problem(dataset), torque_sign_problem(dataset)) if w]
