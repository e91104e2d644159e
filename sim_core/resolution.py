"""The resolution and stepping choice's public names; the implementation lives in ``sim_core.studies``."""

from .studies.resolution import (
    FACES, QUANTITIES, REFERENCE_MODELS, Candidate, References, ResolutionChoice, Scene, SceneSolution,
    SteppingCandidate, SteppingChoice, choose_resolution, choose_stepping, dynamic_scene, evaluate,
    reference_solutions, scene_errors, solve_scene, stepping_error,
)

__all__ = [
    "Candidate", "FACES", "QUANTITIES", "REFERENCE_MODELS", "References", "ResolutionChoice", "Scene",
    "SceneSolution", "SteppingCandidate", "SteppingChoice", "choose_resolution", "choose_stepping",
    "dynamic_scene", "evaluate", "reference_solutions", "scene_errors", "solve_scene", "stepping_error",
]
