"""Retraction-v0: lift-and-pull exposes the target under the force limit, better than random."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)

ENV_ID = "tissue_env/Retraction-v0"


def test_flap_stays_on_the_floor_and_starts_covering_the_target():
    env = gym.make(ENV_ID)
    _, info = env.reset(seed=0)
    assert info["exposed_fraction"] == 0.0
    for _ in range(5):
        env.step(np.zeros(3, np.float32))
    assert env.unwrapped.state.positions[:, 1].min() >= 0.0
