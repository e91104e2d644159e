"""The checks every cutting task's tests make (tests/test_env_incision.py, tests/test_env_dissection.py):
a vector copy takes the single env's steps through cuts, a reset brings the uncut tissue back,
snapshots, deepcopies and pickles hold the cut, random blades give finite steps and cuts beyond
the spare node rows are refused."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

from same_steps import assert_same_steps


def scripted_steps(env, count):
    """``count`` steps of the scripted controller (fewer if the episode ends); returns the infos."""
    infos = []
    for _ in range(count):
        *_, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        infos.append(info)
        if terminated or truncated:
            break
    return infos


def assert_vector_copy_equals_single(env_id, keywords, steps, other):
    """Copy 0 of a two-copy vector env of ``env_id`` (``keywords``), given the single env's scripted
    actions (at most ``steps``, seed 5) while copy 1 takes ``other`` (3,) each step, takes the single
    env's steps (observations within 1e-9, the same rewards and cuts); copy 1 cuts on its own.
    Returns whether the single env's episode ended."""
    single = gym.make(env_id, **keywords)
    single.reset(seed=5)
    actions, observations, rewards, faces = [], [], [], []
    for _ in range(steps):
        action = single.unwrapped.scripted_action()
        observation, reward, terminated, _, info = single.step(action)
        actions.append(action), observations.append(observation), rewards.append(reward)
        faces.append(info["faces_cut"])
        if terminated:
            break
    assert sum(faces) > 0
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **keywords)
    vector.reset(seed=[5, 9])
    for step, action in enumerate(actions):
        observation, reward, _, _, info = vector.step(np.stack([action, np.asarray(other, np.float32)]))
        assert np.abs(observation[0] - observations[step]).max() < 1e-9
        assert reward[0] == rewards[step] and info["faces_cut"][0] == faces[step]
    assert info["cut_faces"][1] > 0  # the other copy cut on its own
    vector.close()
    return terminated


def assert_reset_restores_the_uncut_tissue(env, env_id, keywords, steps):
    """After cuts, a reset of ``env`` (seed 7) gives the uncut slab back: its world holds the block's
    model again and its next ``steps`` scripted steps are a fresh env's (``env_id``, ``keywords``)
    bit for bit, cuts included."""
    env.reset(seed=7)
    task = env.unwrapped
    assert task.worlds.stack.shared[0] and task.worlds.stack.given[0] is task.model
    again = scripted_steps(env, steps)
    fresh = gym.make(env_id, **keywords)
    fresh.reset(seed=7)
    assert_same_steps([tuple(info.values()) for info in scripted_steps(fresh, steps)],
                      [tuple(info.values()) for info in again])
    assert sum(info["faces_cut"] for info in again) > 0


def assert_snapshots_hold_the_cut(task, env_id, keywords, check=None, max_bytes=None):
    """Taken with ``task``'s world cut, a snapshot (under ``max_bytes`` pickled, if given; restored on
    the env after a reset and on a fresh one, also pickled), a deepcopy and a pickle of the env take the
    original's next 5 scripted steps bit for bit, cuts included; ``check`` (optional): a condition
    those steps must meet."""
    assert not task.worlds.stack.shared[0]
    snapshot = task.get_state()
    assert max_bytes is None or len(pickle.dumps(snapshot, protocol=pickle.HIGHEST_PROTOCOL)) < max_bytes
    duplicate, unpickled = copy.deepcopy(task), pickle.loads(pickle.dumps(task))

    def steps(env):
        return [env.step(env.scripted_action()) for _ in range(5)]

    expected = steps(task)
    assert sum(step[4]["faces_cut"] for step in expected) > 0
    assert check is None or check(expected)
    for other in (duplicate, unpickled):
        assert_same_steps(expected, steps(other))
    task.reset(seed=3)
    task.set_state(snapshot)
    assert not task.worlds.stack.shared[0]
    assert_same_steps(expected, steps(task))
    fresh = gym.make(env_id, **keywords).unwrapped
    fresh.set_state(pickle.loads(pickle.dumps(snapshot)))
    assert_same_steps(expected, steps(fresh))


def assert_random_blades_are_finite(env_id, keywords, spare_nodes, steps, plunge, action):
    """300 random steps of ``env_id``'s default slab (the blade starts above the tissue), then
    ``steps`` steps on the slab of ``keywords`` with ``spare_nodes`` node rows: the actions ``plunge``
    ((P, 3), the blade into the tissue), then ``action(rng)`` (random moves: it cuts most steps,
    until the copies fill the spare rows and the cuts beyond are refused, ``info["cut_refused"]``).
    Every observation and reward finite, no divergence; returns the cutting and the refused steps."""
    env = gym.make(env_id)
    env.action_space.seed(0)
    env.reset(seed=0)
    for _ in range(300):
        observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert np.all(np.isfinite(observation)) and np.isfinite(reward) and not info["unstable"]
        if terminated or truncated:
            env.reset()
    env = gym.make(env_id, spare_nodes=spare_nodes, **keywords)
    env.reset(seed=1)
    rng = np.random.default_rng(2)
    cutting = refused = 0
    for step in range(steps):
        move = plunge[step] if step < len(plunge) else action(rng)
        observation, reward, terminated, truncated, info = env.step(np.asarray(move, dtype=np.float32))
        assert np.all(np.isfinite(observation)) and np.isfinite(reward) and not info["unstable"]
        cutting += info["faces_cut"] > 0
        refused += info["cut_refused"]
        if terminated or truncated:
            break
    assert env.unwrapped.worlds.stack.given[0].n_nodes <= env.unwrapped.mesh.n_nodes + spare_nodes
    return cutting, refused


def assert_approach_is_the_route_shortening(env_id, keywords, seed):
    """On the scripted episode (seed ``seed``) each step's ``reward_approach`` is ``approach_weight``
    times the shortening of the route (``info["route_remaining"]``, m) over 1 cm, the scripted blade
    lengthens the route by less than 0.1 mm in all (Incision's moves back to the line's exact start,
    short of its first face) and ends within an element of its end; a blade lifted straight up
    from the start lengthens it and is penalised by the same rule. Returns the summed approach reward."""
    env = gym.make(env_id, **keywords)
    _, info = env.reset(seed=seed)
    task = env.unwrapped
    weight, element = task.approach_weight, float(np.max(task.spacing))
    remaining, total, lengthened = [info["route_remaining"]], 0.0, 0.0
    for info in scripted_steps(env, 60):
        remaining.append(info["route_remaining"])
        np.testing.assert_allclose(info["reward_approach"], weight * (remaining[-2] - remaining[-1]) / 0.01,
                                   rtol=1e-9, atol=1e-12)
        lengthened += max(remaining[-1] - remaining[-2], 0.0)
        total += info["reward_approach"]
    assert lengthened < 1e-4 and info["is_success"] and remaining[-1] <= element < remaining[0]
    _, info = env.reset(seed=seed)
    before = info["route_remaining"]
    *_, info = env.step(np.array([0.0, 1.0, 0.0], np.float32))
    assert info["route_remaining"] > before
    assert info["reward_approach"] < 0
    assert info["reward_approach"] == pytest.approx(weight * (before - info["route_remaining"]) / 0.01)
    return total
