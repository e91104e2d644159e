"""TumorPositioning-v0: solvable by the proportional controller, better than random, physics settles."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)
from tissue_env.episodes import random_policy, run_episode, scripted_policy
from sim_core import solve_static

ENV_ID = "tissue_env/TumorPositioning-v0"


def test_scripted_controller_succeeds_and_beats_random():
    env = gym.make(ENV_ID)
    scripted = [run_episode(env, scripted_policy, seed) for seed in range(20)]
    assert np.mean([info["is_success"] for _, _, info in scripted]) >= 0.8
    random = [run_episode(env, random_policy, seed) for seed in range(3)]
    assert np.mean([r for r, _, _ in scripted]) > np.mean([r for r, _, _ in random])


def test_dynamics_settle_to_static_equilibrium():
    """Holding the tool still, the implicit steps reach solve_static's equilibrium (tumour within 0.05 mm)."""
    env = gym.make(ENV_ID, max_episode_steps=200)
    env.reset(seed=2)
    unwrapped = env.unwrapped
    unwrapped.terminate_on_success = False
    for _ in range(4):
        env.step(np.array([1.0, 0.5, -1.0], np.float32))
    for _ in range(25):
        env.step(np.zeros(3, np.float32))
    result = solve_static(unwrapped.model, unwrapped.control, initial=unwrapped.state.positions)
    tumor = unwrapped.tumor_weights @ result.positions[unwrapped.tumor_nodes]
    assert result.converged
    assert np.linalg.norm(tumor - unwrapped.measures["tumor"]) < 5e-5
