"""Design of the spatial filter, external-torque observers and additive torque controller."""

from iiwa_ident.design.observer import MomentumObserver

__all__ = ["MomentumObserver"]
