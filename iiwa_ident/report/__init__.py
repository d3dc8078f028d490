"""Figures and PDF reports (matplotlib, Agg backend).

Public API
----------
build_report
    The PDF report of a pipeline's work folder, or of one stage (:mod:`iiwa_ident.report._pdf`).
fit_figure_pngs, lookup_table_figure, spatial_spectrum_figure, velocity_frequency_figure, figure_set
    The figures of ``fit --plots``, ``ripple --plots`` and ``diagnose --plots``.
comparison_figure
    A model against one dataset's channel (``compare --figures``).
kappa_figure, pole_figure, tracking_figure
    The closed-loop analysis's figures: the live kappa sweep, the poles, the tracking of a sine.
"""

from iiwa_ident.report._control_figures import kappa_figure, pole_figure, tracking_figure
from iiwa_ident.report._diagnose_figures import comparison_figure, figure_set
from iiwa_ident.report._fit_figures import fit_figure_pngs
from iiwa_ident.report._pdf import build_report
from iiwa_ident.report._ripple_figures import (
           lookup_table_figure,
           spatial_spectrum_figure,
           velocity_frequency_figure,
)

__all__ = ["build_report", "fit_figure_pngs", "lookup_table_figure", "spatial_spectrum_figure",
           "velocity_frequency_figure", "figure_set", "comparison_figure", "kappa_figure", "pole_figure",
           "tracking_figure"]
