"""Retraction-v0: lift-and-pull exposes the target under the force limit, better than random."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)

ENV_ID = "tissue_env/Retraction-v0"


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


def test_flap_stays_on_the_floor_and_starts_covering_the_target():
    env = gym.make(ENV_ID)
    _, info = env.reset(seed=0)
    assert info["exposed_fraction"] == 0.0
    for _ in range(5):
        env.step(np.zeros(3, np.float32))
    assert env.unwrapped.state.positions[:, 1].min() >= 0.0
