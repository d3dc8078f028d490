"""The whole pipeline from the first chirp to the report (``iiwa-ident pipeline``).

Public API
----------
run_pipeline, PipelineResult, PipelineSettings
    Run every stage into a work folder; the outcome; the experiment lengths.
Stage, StageRecord, STAGES, FILES
    The stage abstraction, its outcome, the stages in order, the file names.
format_summary, read_pipeline_json
    The closing summary; ``pipeline.json`` of a work folder.
run_log_pipeline, find_log_runs, LOG_STAGES, LOG_FILES
    The pipeline on a robot's own logs (``--logs``): the runs it finds, its stages, the column files it reads.
save_results, load_saved_results, RESULT_PACKAGES
    A stage's results kept in the work folder for the report, with the sha256 of the files they came from.
run_kappa_sweep, HoldingHand
    The outer loop's gain margin measured live through FRI for both controllers, beside its linear
    prediction (:mod:`iiwa_ident.pipeline._kappa`).
run_validation, ValidationSettings, reference_of
    The closed-loop validation stage on its own: both controllers through FRI; its reference.
"""

from iiwa_ident.pipeline._core import (
    FILES,
    STAGES,
    PipelineContext,
    PipelineResult,
    PipelineSettings,
    Stage,
    StageRecord,
    StageSkipped,
    format_summary,
    read_pipeline_json,
    run_pipeline,
)
from iiwa_ident.pipeline._kappa import HoldingHand, run_kappa_sweep
from iiwa_ident.pipeline._logs import LOG_FILES, LOG_STAGES, find_log_runs, run_log_pipeline
from iiwa_ident.pipeline._saved import RESULT_PACKAGES, load_saved_results, save_results
from iiwa_ident.pipeline._validation import (
    ValidationSettings,
    reference_of,
    run_validation,
)

__all__ = ["run_kappa_sweep", "HoldingHand", "FILES", "STAGES", "PipelineContext", "PipelineResult", "PipelineSettings", "Stage", "StageRecord",
           "StageSkipped", "LOG_FILES", "LOG_STAGES", "find_log_runs", "run_log_pipeline",
           "ValidationSettings", "format_summary", "read_pipeline_json", "run_pipeline", "run_validation",
           "reference_of", "RESULT_PACKAGES", "load_saved_results", "save_results"]
