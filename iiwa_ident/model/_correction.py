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

    Examples
    --------
    >>> import numpy as np
    >>> from iiwa_ident.model import RippleTable
    >>> table = RippleTable(0.02, np.array([0.0, 1e-5, 0.0, -1e-5]))  # f = 10 urad a quarter period in
    >>> round(float(joint_position(0.005, table)), 9), joint_position(0.005, None)
    (0.00499, 0.005)
    """
    if table is None:
        return q_m
    return q_m - table(q_m)


def link_position(q_m: np.ndarray | float, tau_j: np.ndarray | float, K: float,
                  table: RippleTable | None) -> np.ndarray | float:
    """Link position theta_l [rad] from q_m [rad], the joint torque tau_j [Nm] and K [Nm/rad], eq (9).

    Examples
    --------
    >>> round(link_position(0.1, 18.5, 18500.0, None), 6)  # 18.5 Nm twist the spring by 1 mrad
    0.099
    """
    return joint_position(q_m, table) - tau_j / K
