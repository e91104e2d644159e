"""The validation experiments' public names; the implementation lives in ``sim_core.studies``."""

from .studies.experiments import (
    FEM_MODELS, MODELS, ExperimentResult, ToolResult, elongation, elongation_control, flexion, hourglass_content,
    indentation,
    position_errors, settle, shear, tool_patch, tool_patch_nodes,
)

__all__ = [
    "ExperimentResult", "FEM_MODELS", "MODELS", "ToolResult", "elongation", "elongation_control", "flexion",
    "hourglass_content",
    "indentation", "position_errors", "settle", "shear", "tool_patch", "tool_patch_nodes",
]
