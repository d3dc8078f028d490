"""Position correction of eqs (8)-(9) with the identified lookup table.

``theta_j = theta_m - f(theta_m mod rho)``                 (8)
``theta_l = theta_m - f(theta_m mod rho) - tau_j / K``     (9)

Both work on scalars (one sample of a 1 kHz loop) and on arrays.
"""

from __future__ import annotations

import numpy as np

from iiwa_ident.model._joint_model import RippleTable

__all__ = ["joint_position", "link_position"]


def joint_position(q_m: np.ndarray | float, table: RippleTable | None) -> np.ndarray | float:
    """Joint position theta_j [rad] from the motor-side position q_m [rad], eq (8).

    Without a table (no nonlinearity identified) theta_j = q_m.
    """
    if table is None:
        return q_m
    return q_m - table(q_m)


def link_position(q_m: np.ndarray | float, tau_j: np.ndarray | float, K: float,
                  table: RippleTable | None) -> np.ndarray | float:
    """Link position theta_l [rad] from q_m [rad], the joint torque tau_j [Nm] and K [Nm/rad], eq (9)."""
    return joint_position(q_m, table) - tau_j / K
