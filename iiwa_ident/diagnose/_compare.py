"""A model against data, as ``compare`` and ``resid`` do it: the predicted and measured signals, the fit
percentage, the RMS and the residual tests, per dataset and channel (``iiwa-ident compare``).

The model predicts with everything it holds: its parameters, its ripple table and its extra effects (from
``diagnose``); nothing is fitted. One channel's figures: :mod:`iiwa_ident.diagnose._channels`.
"""

from __future__ import annotations

from collections.abc import Sequence

from iiwa_ident.datasets import Dataset
from iiwa_ident.diagnose._channels import ChannelComparison, channel_comparison, fit_percent
from iiwa_ident.diagnose._diagnosis import _residuals
from iiwa_ident.model import JointModel

__all__ = ["ChannelComparison", "compare", "fit_percent"]


def compare(datasets: Sequence[Dataset], model: JointModel) -> list[ChannelComparison]:
    """How well ``model`` predicts each channel of each dataset (nothing fitted).

    Raises
    ------
    IiwaIdentError
        A model of another joint or robot than the datasets' (one line).
    """
    _, contexts, _ = _residuals(datasets, model)
    return [channel_comparison(ctx, ch, ctx.residual[ch]) for ctx in contexts for ch in ctx.channels]
