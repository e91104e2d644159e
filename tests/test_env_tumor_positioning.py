"""TumorPositioning-v0: solvable by the proportional controller, better than random, physics settles."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)
from sim_core import solve_static

ENV_ID = "tissue_env/TumorPositioning-v0"


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
