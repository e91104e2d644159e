"""An episode is a value: ``copy.deepcopy(env)``, ``pickle`` and ``get_state`` / ``set_state`` taken
mid-episode reproduce the original's next steps bit for bit (observations, rewards, episode ends,
infos), on every task and with every integrator. A snapshot is the task environment's
(``env.unwrapped``); wrappers keep their own state (TimeLimit its step count), so the snapshot tests
step the unwrapped environment."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

import tissue_env
from same_steps import assert_same_steps

ENV_IDS = sorted(tissue_env.ENV_IDS)


def _steps(env, actions):
    out = []
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, info = env.reset()
            out.append((obs, info))
    return out


def _mid_episode(env_id, integrator="implicit", seed=4):
    env = gym.make(env_id, integrator=integrator)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    shape = env.action_space.shape  # (3,) per tool, then any grasp commands
    for action in rng.uniform(-1, 1, (6,) + shape).astype(np.float32):
        env.step(action)
    return env, rng.uniform(-1, 1, (25,) + shape).astype(np.float32)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("integrator", ["implicit", "static"])
def test_deepcopy_and_pickle_reproduce_the_next_steps(env_id, integrator):
    env, actions = _mid_episode(env_id, integrator)
    duplicate = copy.deepcopy(env)
    unpickled = pickle.loads(pickle.dumps(env))
    expected = _steps(env, actions)
    assert_same_steps(expected, _steps(duplicate, actions))
    assert_same_steps(expected, _steps(unpickled, actions))


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("target", ["same env, twice", "another env"])
def test_get_state_set_state_restores_the_episode(env_id, target):
    """A snapshot restores any number of times, on its own env or on another env of the task."""
    env, actions = _mid_episode(env_id)
    env = env.unwrapped
    snapshot = env.get_state()
    expected = _steps(env, actions)
    targets = [env, env]
    if target == "another env":
        other = gym.make(env_id).unwrapped
        other.reset(seed=123)
        targets = [other]
    for restored in targets:
        restored.set_state(snapshot)
        assert_same_steps(expected, _steps(restored, actions))


def test_set_state_rejects_what_is_not_a_snapshot_of_the_same_task():
    env = gym.make("tissue_env/Palpation-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="get_state"):
        env.unwrapped.set_state({"state": None})
    other = gym.make("tissue_env/Retraction-v0")
    other.reset(seed=0)
    with pytest.raises(ValueError, match="PalpationEnv"):
        env.unwrapped.set_state(other.unwrapped.get_state())
