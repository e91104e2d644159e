"""tissue_env: Gymnasium environments for surgical soft-tissue tasks on the sim_core physics.

Importing the package registers the tasks (gymnasium >= 1.0 has no plugin entry points)::

    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/TumorPositioning-v0")

Each task's class docstring documents its action and observation spaces, rewards, starting state,
episode end and keywords. Every task has a hand-written baseline controller,
``env.unwrapped.scripted_action()``.

Every task also has a batched vector env (``tissue_env.vector``), registered as its
``vector_entry_point``: ``gym.make_vec(id, num_envs=16, vectorization_mode="vector_entry_point")``
steps all copies in one batched physics step (benchmarks/vector_env_speed.py).
``tissue_env.sb3.BatchedVecEnv`` is the same as a stable-baselines3 ``VecEnv``; that module needs
stable-baselines3 (``pip install "tissue-gym[train]"``) and is not imported here, so
``import tissue_env`` needs only the base dependencies.
"""

import gymnasium

from .base import TissueEnv
from .bimanual import BimanualExposureEnv, BimanualExposureVectorEnv
from .goal import forward_compute_reward
from .dissection import DissectionEnv, DissectionVectorEnv
from .incision import IncisionEnv, IncisionVectorEnv
from .liver_needle import LiverNeedleAlignmentEnv, LiverNeedleAlignmentVectorEnv
from .palpation import PalpationEnv, PalpationVectorEnv
from .retraction import RetractionEnv, RetractionVectorEnv
from .tumor_positioning import TumorPositioningEnv, TumorPositioningVectorEnv
from .vector import TissueVectorEnv

#: Registered ids and their episode lengths (env steps).
ENV_IDS = {
    "tissue_env/TumorPositioning-v0": ("tissue_env.tumor_positioning:TumorPositioningEnv", 50),
    "tissue_env/Palpation-v0": ("tissue_env.palpation:PalpationEnv", 100),
    "tissue_env/Retraction-v0": ("tissue_env.retraction:RetractionEnv", 60),
    "tissue_env/LiverNeedleAlignment-v0": ("tissue_env.liver_needle:LiverNeedleAlignmentEnv", 50),
    "tissue_env/Incision-v0": ("tissue_env.incision:IncisionEnv", 60),
    "tissue_env/BimanualExposure-v0": ("tissue_env.bimanual:BimanualExposureEnv", 80),
    "tissue_env/Dissection-v0": ("tissue_env.dissection:DissectionEnv", 60),
}
#: Batched vector environments (``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``).
VECTOR_ENTRY_POINTS = {
    "tissue_env/TumorPositioning-v0": "tissue_env.tumor_positioning:TumorPositioningVectorEnv",
    "tissue_env/Palpation-v0": "tissue_env.palpation:PalpationVectorEnv",
    "tissue_env/Retraction-v0": "tissue_env.retraction:RetractionVectorEnv",
    "tissue_env/LiverNeedleAlignment-v0": "tissue_env.liver_needle:LiverNeedleAlignmentVectorEnv",
    "tissue_env/Incision-v0": "tissue_env.incision:IncisionVectorEnv",
    "tissue_env/BimanualExposure-v0": "tissue_env.bimanual:BimanualExposureVectorEnv",
    "tissue_env/Dissection-v0": "tissue_env.dissection:DissectionVectorEnv",
}

# gym.make's wrappers forward a goal env's compute_reward (tissue_env.goal: SB3's check_env and HER)
forward_compute_reward()

for _env_id, (_entry_point, _max_steps) in ENV_IDS.items():
    if _env_id not in gymnasium.registry:
        gymnasium.register(id=_env_id, entry_point=_entry_point, max_episode_steps=_max_steps,
                           vector_entry_point=VECTOR_ENTRY_POINTS.get(_env_id))

__all__ = ["ENV_IDS", "VECTOR_ENTRY_POINTS", "BimanualExposureEnv", "BimanualExposureVectorEnv", "DissectionEnv",
           "DissectionVectorEnv", "IncisionEnv",
           "IncisionVectorEnv", "LiverNeedleAlignmentEnv", "LiverNeedleAlignmentVectorEnv", "PalpationEnv",
           "PalpationVectorEnv", "RetractionEnv", "RetractionVectorEnv", "TissueEnv", "TissueVectorEnv",
           "TumorPositioningEnv", "TumorPositioningVectorEnv"]
