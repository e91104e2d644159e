"""tissue_env: Gymnasium environments for surgical soft-tissue tasks on the sim_core physics.

Importing the package registers the tasks (gymnasium >= 1.0 has no plugin entry points)::

    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/TumorPositioning-v0")

Each task's class docstring documents its action and observation spaces, rewards, starting state,
episode end and keywords. Every task has a hand-written baseline controller,
``env.unwrapped.scripted_action()``.
"""

import gymnasium

from .base import TissueEnv
from .palpation import PalpationEnv
from .retraction import RetractionEnv
from .tumor_positioning import TumorPositioningEnv

#: Registered ids and their episode lengths (env steps).
ENV_IDS = {
    "tissue_env/TumorPositioning-v0": ("tissue_env.tumor_positioning:TumorPositioningEnv", 50),
    "tissue_env/Palpation-v0": ("tissue_env.palpation:PalpationEnv", 100),
    "tissue_env/Retraction-v0": ("tissue_env.retraction:RetractionEnv", 60),
}

for _env_id, (_entry_point, _max_steps) in ENV_IDS.items():
    if _env_id not in gymnasium.registry:
        gymnasium.register(id=_env_id, entry_point=_entry_point, max_episode_steps=_max_steps)

__all__ = ["ENV_IDS", "PalpationEnv", "RetractionEnv", "TissueEnv", "TumorPositioningEnv"]
