"""Palpation-v0: the stiffness sweep finds the inclusion; random probing rarely does."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)
from tissue_env.episodes import random_policy, run_episode, scripted_policy

ENV_ID = "tissue_env/Palpation-v0"


def test_scripted_sweep_succeeds_and_random_probing_rarely_does():
    env = gym.make(ENV_ID)
    scripted = [run_episode(env, scripted_policy, seed) for seed in range(20)]
    random = [run_episode(env, random_policy, seed) for seed in range(20)]
    scripted_rate = np.mean([info["is_success"] for _, _, info in scripted])
    random_rate = np.mean([info["is_success"] for _, _, info in random])
    assert scripted_rate >= 0.8
    assert random_rate <= 0.15  # measured 5 % (6 % over 100 seeds)
    assert np.mean([r for r, _, _ in scripted]) > np.mean([r for r, _, _ in random])


def test_probe_starts_away_from_the_inclusion_at_a_random_place():
    env = gym.make(ENV_ID)
    starts = []
    for seed in range(8):
        _, info = env.reset(seed=seed)
        unwrapped = env.unwrapped
        starts.append(unwrapped.probe_start.copy())
        assert info["horizontal_distance"] >= unwrapped.start_distance
        assert np.all(unwrapped.workspace_low <= 0) and np.all(unwrapped.workspace_high >= 0)
    assert len({tuple(np.round(s, 6)) for s in starts}) == len(starts)


def test_success_needs_the_press_held_for_hold_steps():
    env = gym.make(ENV_ID, hold_steps=3, max_episode_steps=200)
    env.reset(seed=0)
    unwrapped = env.unwrapped
    target = unwrapped.inclusion_centre.copy()
    target[1] = unwrapped.top_y - unwrapped.success_depth - 0.001
    held = []
    for _ in range(40):
        action = np.clip((target - unwrapped._tip()) / unwrapped.max_step, -1, 1).astype(np.float32)
        _, _, terminated, _, info = env.step(action)
        held.append(info["press_steps"])
        if terminated:
            break
    assert info["is_success"] and held[-3:] == [1, 2, 3]


def test_inclusion_is_stiffer_under_the_probe():
    """Pressing 3 mm over the inclusion needs more force than over the other candidate cells."""
    env = gym.make(ENV_ID, max_episode_steps=400)
    env.reset(seed=0)
    unwrapped = env.unwrapped
    unwrapped.terminate_on_success = False
    while unwrapped._sweep is None or unwrapped._sweep["index"] < len(unwrapped.inclusion_cells):
        env.step(unwrapped.scripted_action())
    stiffness = unwrapped._sweep["stiffness"]
    cells = unwrapped.inclusion_cells
    inclusion = int(np.flatnonzero((cells == unwrapped.inclusion_cell).all(axis=1))[0])
    assert np.argmax(stiffness) == inclusion and stiffness[inclusion] > 1.05 * np.median(stiffness)


def test_palpation_map_records_first_probes_and_rewards_them_once():
    env = gym.make("tissue_env/Palpation-v0")
    env.reset(seed=3)
    unwrapped = env.unwrapped
    centre = unwrapped.cell_centres[0]
    n_cells = len(unwrapped.cell_centres)

    def go(goal, steps=12):
        infos = []
        for _ in range(steps):
            tip = unwrapped._tip()
            action = np.clip((goal - tip) / unwrapped.max_step, -1, 1).astype(np.float32)
            obs, _, terminated, _, info = env.step(action)
            infos.append(info)
            if terminated:
                break
        return obs, infos

    surface = unwrapped.top_y
    go(np.array([centre[0], surface + 0.002, centre[1]]))
    assert np.all(unwrapped.palpation_map == 0)
    obs, infos = go(np.array([centre[0], surface - 0.004, centre[1]]), steps=4)
    explore = [info["reward_explore"] for info in infos]
    assert explore.count(0.5) == 1 and sum(explore) == 0.5  # once, on the first probing step
    first = unwrapped.palpation_map[0]
    assert first > 0 and np.count_nonzero(unwrapped.palpation_map) == 1
    np.testing.assert_allclose(obs[15:15 + n_cells], unwrapped.palpation_map / 100.0, rtol=1e-6)
    np.testing.assert_allclose(obs[15 + n_cells:17 + n_cells], 0.0, atol=1e-5)  # stiffest = here
    # pressing deeper on the same cell neither rewards again nor changes its recorded stiffness
    _, infos = go(np.array([centre[0], surface - 0.008, centre[1]]), steps=3)
    assert all(info["reward_explore"] == 0 for info in infos)
    assert unwrapped.palpation_map[0] == first
    # the offset to the nearest unprobed cell points to a neighbour one cell pitch away (cm)
    pitch = unwrapped.spacing[0] / unwrapped.length_scale
    np.testing.assert_allclose(np.hypot(*obs[17 + n_cells:19 + n_cells]), pitch, rtol=1e-5)
