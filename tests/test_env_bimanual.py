"""BimanualExposure-v0: two tools, each with its grasp command; the multi-tool action layout."""

import copy

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the tasks)
from tissue_env.episodes import random_policy, run_episode, scripted_policy

ENV_ID = "tissue_env/BimanualExposure-v0"


def test_action_layout_moves_each_tool_by_its_own_entries():
    """Entries 0-2 move the left jaw, 3-5 the right one (y up), 6-7 close / keep / open the grasps:
    the tool displacement features and the infos follow exactly the entries given."""
    env = gym.make(ENV_ID, grasp_commands=True)
    assert env.action_space.shape == (8,) and gym.make(ENV_ID).action_space.shape == (6,)
    obs, info = env.reset(seed=0)
    assert not info["grasped"].any() and np.all(info["tool_forces"] == 0.0)
    # close only the right grasper, without moving
    obs, _, _, _, info = env.step(np.array([0, 0, 0, 0, 0, 0, 0.2, 0.9], np.float32))
    assert list(info["grasped"]) == [False, True] and info["grasped_nodes"][0] == 0 and info["grasped_nodes"][1] > 0
    # lift the right tool only: its offset is one max_step up, the left one's is unchanged
    obs, _, _, _, info = env.step(np.array([0, 0, 0, 0, 1, 0, 0, 0], np.float32))
    offset = env.unwrapped.tool_offset
    np.testing.assert_array_equal(offset, [0, 0, 0, 0, env.unwrapped.max_step, 0])
    np.testing.assert_allclose(obs[6:12], offset / env.unwrapped.length_scale, rtol=1e-6)
    assert info["tool_forces"][1, 1] < 0 and np.all(info["tool_forces"][0] == 0.0)  # the lifted flap pulls down
    assert info["tool_forces"].shape == (2, 3) and info["grasped"].shape == (2,)
    # opening releases the grasp (not a slip: no grasp penalty)
    obs, _, _, _, info = env.step(np.array([0, 0, 0, 0, 0, 0, 0, -1], np.float32))
    assert not info["grasped"].any() and np.all(info["tool_forces"] == 0.0) and info["reward_grasp"] == 0.0


def test_a_jaw_away_from_its_edge_closes_on_nothing():
    env = gym.make(ENV_ID, grasp_commands=True)
    env.reset(seed=0)
    for _ in range(5):  # the left jaw 5 mm towards the cleft, then up 4 x 5 mm: out of reach of the edge
        env.step(np.array([1, 1, 0, 0, 0, 0, 0, 0], np.float32))
    _, _, _, _, info = env.step(np.array([0, 0, 0, 0, 0, 0, 1, 0], np.float32))
    assert not info["grasped"][0]


def test_tools_mirror_each_other_on_the_symmetric_scene():
    """The two flaps mirror each other about x = L/2: mirrored moves give mirrored tool forces (x
    opposite, y and z equal) and mirrored jaws, a check of which forces go to which tool."""
    env = gym.make(ENV_ID)
    env.reset(seed=0)
    for move in ([0, 1, 0], [0, 1, 0], [-1, 1, 0], [-1, 0, 0]):
        left = np.array(move, float)
        right = left * [-1, 1, 1]
        _, _, _, _, info = env.step(np.concatenate([left, right]).astype(np.float32))
    forces = info["tool_forces"]
    assert np.linalg.norm(forces[0]) > 1e-3
    np.testing.assert_allclose(forces[1] * [-1, 1, 1], forces[0], rtol=1e-6, atol=1e-9)


def test_scripted_controller_succeeds_and_beats_random():
    env = gym.make(ENV_ID)
    scripted = [run_episode(env, scripted_policy, seed) for seed in range(10)]
    assert sum(info["is_success"] for _, _, info in scripted) >= 9
    random = [run_episode(env, random_policy, seed) for seed in range(2)]
    assert np.mean([r for r, _, _ in scripted]) > np.mean([r for r, _, _ in random]) + 10.0


def test_a_low_grasp_limit_lets_both_edges_slip_and_never_reports_more():
    """Both tools pulled straight up at full speed with grasp_force_limit=0.02 N: each grasp slips
    (nodes leave it, then it is lost), and while it holds its force never passes 0.022 N."""
    env = gym.make(ENV_ID, grasp_force_limit=0.02, grasp_commands=False)
    _, info = env.reset(seed=0)
    held = [info["grasped_nodes"].copy()]
    worst = 0.0
    for _ in range(12):
        _, reward, _, _, info = env.step(np.array([0, 1, 0, 0, 1, 0], np.float32))
        held.append(info["grasped_nodes"].copy())
        worst = max(worst, np.linalg.norm(info["tool_forces"], axis=1)[info["grasped"]].max(initial=0.0))
        assert np.all(info["reward_grasp"] <= 0.0)
    held = np.array(held)
    assert np.all(held[-1] == 0) and np.all(np.diff(held, axis=0) <= 0)
    assert worst <= 0.022
    assert info["grasp_lost"].all()


def test_random_steps_stay_finite_and_observations_types():
    env = gym.make(ENV_ID, max_episode_steps=300)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(3)
    for _ in range(300):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 6).astype(np.float32))
        assert not info["unstable"]  # measured: no divergence of random episodes at the defaults
        assert np.all(np.isfinite(obs)) and np.isfinite(reward) and np.all(np.isfinite(info["tool_forces"]))
        if terminated or truncated:
            obs, _ = env.reset()
    for observation_type in ("dict", "rgb", "point_cloud"):
        env = gym.make(ENV_ID, observation_type=observation_type)
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        obs, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)


def test_snapshot_and_deepcopy_reproduce_the_next_steps():
    env = gym.make(ENV_ID)
    env.reset(seed=1)
    for _ in range(3):
        env.step(env.unwrapped.scripted_action())
    snapshot = env.unwrapped.get_state()
    twin = copy.deepcopy(env)
    actions = np.random.default_rng(0).uniform(-1, 1, (4, 6)).astype(np.float32)
    first = [env.step(a)[0] for a in actions]
    env.unwrapped.set_state(snapshot)
    np.testing.assert_array_equal([env.step(a)[0] for a in actions], first)
    np.testing.assert_array_equal([twin.step(a)[0] for a in actions], first)


@pytest.mark.parametrize("keyword, value", [
    ("shape", (12, 2, 6)), ("grip_margin", 1.0), ("target_shift_range", (0.0, "a")), ("grasp_commands", "yes"),
    ("grasp_force_limit", 0.0), ("target_width", -0.01), ("size_range", (0.05, 0.07)),
])
def test_invalid_keywords_raise(keyword, value):
    with pytest.raises(ValueError, match=keyword):
        gym.make(ENV_ID, **{keyword: value})


def test_grasp_commands_in_a_vector_env_give_the_single_envs_steps():
    """The grasp commands act per world: a vector env's copies, each closing and opening its own
    graspers, take the single envs' steps (same seeds, same actions) to the last bit."""
    vector = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", threads=1, grasp_commands=True)
    singles = [gym.make(ENV_ID, grasp_commands=True) for _ in range(2)]
    vector.reset(seed=[4, 5])
    for index, env in enumerate(singles):
        env.reset(seed=4 + index)
    actions = np.random.default_rng(2).uniform(-1, 1, (6, 2, 8)).astype(np.float32)
    actions[0, :, 6:] = [[1.0, 0.0], [0.0, 1.0]]  # copy 0 closes its left grasper, copy 1 its right one
    held = []
    for step in actions:
        observations, rewards, _, _, infos = vector.step(step)
        held.append(infos["grasped"].copy())
        for index, env in enumerate(singles):
            observation, reward, _, _, info = env.step(step[index])
            np.testing.assert_array_equal(observations[index], observation)
            assert rewards[index] == reward
            np.testing.assert_array_equal(infos["grasped"][index], info["grasped"])
            np.testing.assert_array_equal(infos["tool_forces"][index], info["tool_forces"])
    assert held[0].tolist() == [[True, False], [False, True]]  # each copy's own command closed its own jaw
