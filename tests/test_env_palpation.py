"""Palpation-v0: the stiffness sweep finds the inclusion, better than random."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)

ENV_ID = "tissue_env/Palpation-v0"


def episode(env, seed, policy):
    env.reset(seed=seed)
    total = 0.0
    while True:
        _, reward, terminated, truncated, info = env.step(policy(env))
        total += reward
        if terminated or truncated:
            return total, info


def test_scripted_controller_succeeds_and_beats_random():
    env = gym.make(ENV_ID)
    scripted = [episode(env, seed, lambda e: e.unwrapped.scripted_action()) for seed in range(20)]
    success_rate = np.mean([info["is_success"] for _, info in scripted])
    assert success_rate >= 0.8
    env.action_space.seed(0)
    random = [episode(env, seed, lambda e: e.action_space.sample()) for seed in range(3)]
    assert np.mean([r for r, _ in scripted]) > np.mean([r for r, _ in random])


def test_inclusion_is_stiffer_under_the_probe():
    """Pressing 3 mm over the inclusion needs more force than over the opposite side of the slab."""
    env = gym.make(ENV_ID, max_episode_steps=400)
    env.reset(seed=0)
    unwrapped = env.unwrapped
    unwrapped.terminate_on_success = False
    while unwrapped._sweep is None or unwrapped._sweep["index"] < len(unwrapped.inclusion_cells):
        env.step(unwrapped.scripted_action())
    stiffness = unwrapped._sweep["stiffness"]
    cells = unwrapped.inclusion_cells
    inclusion = int(np.flatnonzero((cells == np.array(unwrapped.task_key)).all(axis=1))[0])
    assert np.argmax(stiffness) == inclusion and stiffness[inclusion] > 1.05 * np.median(stiffness)
