"""TumorPositioning-v0: solvable by the proportional controller, better than random, physics settles."""

import gymnasium as gym
import numpy as np
import pytest

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


def test_grasped_patch_has_a_physical_size():
    """``tool_size`` is a length: a finer mesh grasps the same 2.5 cm square with more nodes; a square
    smaller than the node spacing that holds no node is a ValueError naming the keyword."""
    for shape, count in (((4, 4, 4), 9), ((8, 8, 8), 25)):
        env = gym.make(ENV_ID, shape=shape).unwrapped
        tool = env.mesh.nodes[env.tool_nodes]
        assert len(env.tool_nodes) == count
        np.testing.assert_allclose(np.ptp(tool[:, [0, 2]], axis=0), [0.025, 0.025], atol=1e-12)
        np.testing.assert_allclose(tool[:, 1], 0.05)
    with pytest.raises(ValueError, match="tool_size"):
        gym.make(ENV_ID, tool_size=0.005, shape=(3, 3, 3))
    with pytest.raises(ValueError, match="tool_size"):
        gym.make(ENV_ID, tool_size=-0.01)
