"""Figures and PDF reports (matplotlib, Agg backend)."""
