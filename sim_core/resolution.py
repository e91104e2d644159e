"""The resolution and stepping choice's public names; the implementation lives in ``sim_core.studies``."""

from .studies.resolution import (
    REFERENCE_MODELS, Candidate, References, ResolutionChoice, choose_resolution, evaluate, reference_solutions,
)
from .studies.scenes import FACES, Scene
from .studies.solving import QUANTITIES, SceneSolution, scene_errors, solve_scene
from .studies.stepping import SteppingCandidate, SteppingChoice, choose_stepping, dynamic_scene, stepping_error

__all__ = [
    "Candidate", "FACES", "QUANTITIES", "REFERENCE_MODELS", "References", "ResolutionChoice", "Scene",
    "SceneSolution", "SteppingCandidate", "SteppingChoice", "choose_resolution", "choose_stepping",
    "dynamic_scene", "evaluate", "reference_solutions", "scene_errors", "solve_scene", "stepping_error",
]
