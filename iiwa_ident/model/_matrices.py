"""A state-space system's matrices as one named result (continuous or discrete, the caller says which)."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

__all__ = ["StateSpaceMatrices", "StrictlyProperMatrices"]


class StateSpaceMatrices(NamedTuple):
    """``x' = A x + B u``, ``y = C x + D u`` (or ``x[k+1] = A x[k] + B u[k]``): a system's matrices.

    A tuple, so ``A, B, C, D = system`` unpacks it. ``D`` is a float for a single-input single-output system.

    Examples
    --------
    >>> A, B, C, D = StateSpaceMatrices(np.zeros((1, 1)), np.ones(1), np.ones(1), 0.0)
    >>> D
    0.0
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: Any


class StrictlyProperMatrices(NamedTuple):
    """``x' = A x + B u``, ``y = C x``: a system without feed-through."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
