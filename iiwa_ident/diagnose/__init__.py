"""Discrepancy diagnosis: what the model gets wrong, which effect causes it, and the gain of adding it.

Public API
----------
diagnose, Diagnosis, EffectReport, ChannelReport, ACROSS_RUNS_WORSE_PCT
    Run the diagnosis on datasets with a model; the result, per effect and per channel; how much worse a run
    predicted from the others must be with an effect to be said worse.
residual_rms
    How well a model predicts datasets, per residual channel (nothing fitted).
compare, ChannelComparison, fit_percent
    A model against data per dataset and channel: signals, fit percentage, RMS and residual tests.
CandidateEffect, CANDIDATES, register_candidate, EvidenceChannel
    The pluggable library of candidate effects (one subclass per effect), and an effect's own evidence.
build_context, Context
    The model's prediction of a dataset and its residual channels.
"""

from iiwa_ident.diagnose._candidates import CANDIDATES, CandidateEffect, EvidenceChannel, register_candidate
from iiwa_ident.diagnose._channels import verdict_text
from iiwa_ident.diagnose._compare import ChannelComparison, compare, fit_percent
from iiwa_ident.diagnose._diagnosis import (
                                          ACROSS_RUNS_WORSE_PCT,
                                          ChannelReport,
                                          ChannelRms,
                                          Diagnosis,
                                          EffectReport,
                                          diagnose,
                                          residual_rms,
                                          undecided_sentence,
)
from iiwa_ident.diagnose._predict import Context, build_context

__all__ = ["diagnose", "residual_rms", "ChannelRms", "Diagnosis", "EffectReport", "ChannelReport", "CandidateEffect", "CANDIDATES",
           "EvidenceChannel", "register_candidate", "build_context", "Context", "compare", "ChannelComparison",
           "fit_percent", "verdict_text", "undecided_sentence", "ACROSS_RUNS_WORSE_PCT"]
