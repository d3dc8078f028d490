"""The joint fit: inverse dynamics for the link-side effects, then the sampled-data output-error fit.

Two estimators of eqs (1)-(4) exist, each strong where the other is weak:

- :func:`iiwa_ident.ident.idim.fit_idim` (IDIM-IV) uses every channel, is
  linear in the parameters, fits link friction, a position-dependent load and
  a sensor offset, and needs no start values; but its continuous-time
  equations on sampled data are approximate near the Nyquist frequency.
- :func:`iiwa_ident.ident.tf_fit.fit_transfer_function` is exact for the
  sampled, delayed data and reaches the Cramer-Rao bound on clean data; but
  it needs start values and has no link friction or load.

:func:`fit_joint` runs the first, then the second from its values with the
estimated friction, load and gravity-model torques as known inputs. What
each step gives is measured by ``bench/bench_robustness.py fit``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident.idim import STICK_COULOMB_NM, IdimResult, fit_idim
from iiwa_ident.ident.tf_fit import PARAMETER_NAMES, FitResult, fit_transfer_function

__all__ = ["METHODS", "fit_joint"]

#: ``auto``: ``idim`` when the link shows Coulomb friction, else ``joint``; ``joint``: IDIM-IV, then the
#: output-error fit with its effects as known inputs; ``idim``: IDIM-IV alone; ``eq4``: the output-error
#: fit of eq (4) alone (no link-side effects).
METHODS: tuple[str, ...] = ("auto", "joint", "idim", "eq4")


def _from_idim(idim: IdimResult) -> FitResult:
    """An :class:`IdimResult` in the shape of a :class:`FitResult` (no frequency-domain diagnostics)."""
    n = len(PARAMETER_NAMES)
    cov = np.diag([idim.std[k] ** 2 for k in PARAMETER_NAMES])
    return FitResult(parameters=dict(idim.parameters), std=dict(idim.std), std_sandwich=dict(idim.std),
                     correlation=np.eye(n), covariance=cov, noise=[], frf=[], model_frf=[], bands=[], harmonics=[],
                     nonlinear=[], warnings=list(idim.warnings), initial=[dict(idim.parameters)],
                     labels=list(idim.labels), cost=float("nan"), n_evaluations=0, sample_times_s=[])


#: Largest factor by which the output-error fit may move Jc, bc, K or Jl away from IDIM-IV's values.
MAX_DEPARTURE_FACTOR = 1.5
#: Largest shift of the delay between the two [s].
MAX_DEPARTURE_TD_S = 2e-3


def _departure(fitted: dict[str, float], start: dict[str, float]) -> str:
    """What moved too far between the two estimates ('' when nothing did)."""
    for k in PARAMETER_NAMES[:4]:
        ratio = fitted[k] / start[k]
        if not 1.0 / MAX_DEPARTURE_FACTOR <= ratio <= MAX_DEPARTURE_FACTOR:
            return f"{k} by a factor {ratio:.3g}"
    if abs(fitted["Td"] - start["Td"]) > MAX_DEPARTURE_TD_S:
        return f"Td by {1e3 * (fitted['Td'] - start['Td']):.2g} ms"
    return ""


def fit_joint(datasets: Sequence[Dataset], *, method: str = "auto") -> FitResult:
    """Fit a joint's chirps: eqs (1)-(4) with delay, link friction, load and sensor offset.

    Parameters
    ----------
    datasets : sequence of Dataset
        Torque-commanded chirps of one joint.
    method : {"auto", "joint", "idim", "eq4"}
        See :data:`METHODS`.

    Returns
    -------
    FitResult
        With ``method`` and ``effects`` (the link-side effects, from IDIM-IV).

    Raises
    ------
    IiwaIdentError
        The data cannot identify a parameter (the message names it and
        why) or a file cannot be fitted.
    """
    if method not in METHODS:
        raise IiwaIdentError(f"unknown fit method {method!r} (known: {', '.join(METHODS)})")
    if method == "eq4":
        result = fit_transfer_function(datasets)
        result.method = "eq4"
        return result
    idim = fit_idim(datasets)
    if method == "auto":
        # A sticking link makes the friction torque unknown while it sticks; the output-error
        # fit would have to simulate through it, the inverse dynamics leave those samples out.
        friction = idim.effect("link_friction")
        method = "idim" if friction is not None and friction.values["coulomb_nm"] > STICK_COULOMB_NM else "joint"
    if method == "idim":
        result = _from_idim(idim)
    else:
        start = dict(idim.parameters)
        result = fit_transfer_function(datasets, initial=start, known=idim.known_inputs)
        moved = _departure(result.parameters, idim.parameters)
        if moved:
            # Both estimate the same parameters; a large disagreement means the output-error search
            # went astray (it is local and simulates through the effects), not that IDIM is wrong.
            fallback = _from_idim(idim)
            fallback.warnings.append(f"the output-error fit moved {moved} from the inverse-dynamics estimate; "
                                     "the inverse-dynamics values are kept")
            result, method = fallback, "idim"
    result.method = method
    result.effects = idim.effects
    return result
