"""Eq (4) of the paper, the joint's torque transfer function, as LTI objects.

With the link free, eqs (1)-(3) give from the commanded torque ``tau_c`` to
the joint torque ``tau_J``::

    tau_J / tau_c = e^{-Td s} Jl (bc s + K) / (Jc Jl s^2 + Jl bc s + (Jc + Jl) K)     (4)

The same denominator carries a torque on the link (``-K Jc``) and a
transmission deflection ``f`` (``-K Jc Jl s^2``). The design model of
section V.B replaces the delay by its second-order Padé approximant.

References
----------
.. [1] "Toward Torque Control of a KUKA LBR IIWA for Physical Human-Robot
   Interaction", eqs (1)-(4) and Table I; the Padé design model of section V.B.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from iiwa_ident.model._parameters import JointParameters, ParameterSource, parameter_values

if TYPE_CHECKING:
    import control as ct  # imported where used: python-control is slow to import

__all__ = ["INPUTS", "pade_coefficients", "resonance_hz", "coefficients", "transfer_function",
           "polynomials", "frequency_response"]

#: Inputs of eq (4)'s family: the FRI command (delayed by ``Td``), a torque added to the motor side's
#: command inside the robot (not delayed), a torque on the link [Nm], the transmission's deflection
#: ``f(theta_m)`` of eq (5) [rad], and the ripple's reaction on the motor side [Nm].
INPUTS: tuple[str, ...] = ("command", "motor", "link", "deflection", "reaction")


def pade_coefficients(Td: float) -> tuple[float, float]:
    """``(c1, c2) = (6/Td, 12/Td^2)`` of the second-order Padé delay [1/s, 1/s^2].

    Examples
    --------
    >>> pade_coefficients(0.005)
    (1200.0, 480000.0)
    """
    return 6.0 / Td, 12.0 / Td ** 2


def resonance_hz(Jc: float, K: float, Jl: float) -> float:
    """Resonance of eq (4) without damping, ``sqrt(K (1/Jc + 1/Jl)) / (2 pi)`` [Hz].

    Examples
    --------
    >>> round(resonance_hz(1.03, 18500.0, 5.6), 2)
    23.21
    """
    return math.sqrt(K * (1.0 / Jc + 1.0 / Jl)) / (2 * math.pi)


def coefficients(p: JointParameters, delay: str = "none") -> tuple[np.ndarray, np.ndarray]:
    """Numerator and monic denominator of eq (4), highest power first.

    Parameters
    ----------
    p : JointParameters
        Model parameters.
    delay : {"none", "pade"}
        Without the delay (2 and 3 coefficients) or with its second-order
        Padé approximant (4 and 5 coefficients, the numerator's leading one
        ``bc / Jc``, zero without damping).
    """
    if delay not in ("pade", "none"):
        raise ValueError("delay must be 'pade' or 'none'")
    num, den = polynomials(p, "command")
    num, den = num / den[0], den / den[0]
    if delay == "pade":
        c1, c2 = pade_coefficients(p.Td)
        num, den = np.polymul([1.0, -c1, c2], num), np.polymul([1.0, c1, c2], den)
        num = np.concatenate([np.zeros(4 - len(num)), num])  # polymul drops a zero leading coefficient
    return num, den


def transfer_function(p: JointParameters, delay: str = "pade") -> ct.TransferFunction:
    """Eq (4) from ``tau_c`` to ``tau_J`` [Nm/Nm] as a python-control transfer function.

    Parameters
    ----------
    p : JointParameters
        Model parameters.
    delay : {"pade", "none"}
        The delay as the second-order Padé approximant (fourth order, the
        design model of section V.B) or left out (second order).

    Examples
    --------
    >>> G = transfer_function(JointParameters(1.03, 55.0, 18500.0, 5.6, 0.005))
    >>> round(float(G.dcgain()), 4)  # Jl / (Jc + Jl): the link keeps its share of a slow torque
    0.8446
    """
    import control as ct  # here, not at import: python-control takes most of a second to import

    return ct.tf(*coefficients(p, delay))


def polynomials(p: ParameterSource, input: str = "command") -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator of ``tau_J`` per input without the delay, highest power first.

    The denominator is eq (4)'s ``Jc Jl s^2 + Jl bc s + (Jc + Jl) K`` for every
    input; the numerators are ``Jl (bc s + K)`` for the command and a torque
    added inside the robot, ``-K Jc`` for a torque on the link [Nm/Nm],
    ``-K Jc Jl s^2`` for a transmission deflection [Nm/rad] and ``K Jl`` for
    the ripple's reaction, a torque on the motor that the loop's damping does
    not see (eq (1) with ``r`` added to ``z'`` of
    :func:`~iiwa_ident.model.state_matrices`) [Nm/Nm].

    Parameters
    ----------
    p : JointParameters, mapping, joint model or sequence
        (:func:`~iiwa_ident.model.parameter_values`).
    input : {"command", "motor", "link", "deflection", "reaction"}
        The input (:data:`INPUTS`).

    Examples
    --------
    >>> num, den = polynomials(JointParameters(1.0, 50.0, 1e4, 4.0, 0.005), "link")
    >>> num.tolist(), den.tolist()
    ([-10000.0], [4.0, 200.0, 50000.0])
    """
    if input not in INPUTS:
        raise ValueError(f"input must be one of {INPUTS}")
    Jc, bc, K, Jl, _ = parameter_values(p)
    den = np.array([Jc * Jl, Jl * bc, (Jc + Jl) * K])
    if input == "link":
        return np.array([-K * Jc]), den
    if input == "deflection":
        # K f pushes the motor side, -K f the link, and the sensor reads -K f directly: the sum leaves
        # only the inertias' share (no torque at low frequency, -K f far above the resonance).
        return np.array([-K * Jc * Jl, 0.0, 0.0]), den
    if input == "reaction":
        return np.array([K * Jl]), den
    return np.array([Jl * bc, Jl * K]), den


def frequency_response(p: ParameterSource, f_hz: np.ndarray | float, input: str = "command") -> np.ndarray:
    """The continuous-time response of ``tau_J`` at ``f_hz`` [Hz], the delay exact.

    Parameters
    ----------
    p : JointParameters, mapping, joint model or sequence
        ``Jc`` [kg m^2], ``bc`` [Nm s/rad], ``K`` [Nm/rad], ``Jl`` [kg m^2],
        ``Td`` [s] (:func:`~iiwa_ident.model.parameter_values`).
    f_hz : array_like
        Frequencies [Hz] (negative ones give the conjugate).
    input : {"command", "motor", "link", "deflection", "reaction"}
        ``tau_J / tau_c`` (delayed by ``Td``), the same for a torque added
        inside the robot (no delay), ``tau_J`` per torque on the link, or per
        transmission deflection [Nm/rad] (:func:`polynomials`).

    Returns
    -------
    numpy.ndarray
        Complex response [Nm/Nm] ([Nm/rad] for the deflection).
    """
    num, den = polynomials(p, input)
    s = 2j * np.pi * np.asarray(f_hz, float)
    out = np.polyval(num, s) / np.polyval(den, s)
    if input == "command":
        out = out * np.exp(-parameter_values(p)[4] * s)
    return out
