"""Identification: the joint model file, the transfer-function fit and the ripple identification."""

from iiwa_ident.ident.model_file import (
    JointModel,
    ModelError,
    Parameter,
    RippleTable,
    Source,
    model_from_dict,
    read_model,
    table1_model,
    write_model,
)

__all__ = ["JointModel", "ModelError", "Parameter", "RippleTable", "Source", "model_from_dict", "read_model",
           "table1_model", "write_model"]
