"""The ``difficulty`` keyword: each task's DIFFICULTY table sets its difficulty keywords, a keyword
passed explicitly overrides its level's value, "default" is the task as registered, bad values
raise ValueError naming the keyword, and ``terminate_on_success=False`` lets an episode go on past
a success."""

import warnings

import gymnasium as gym
import numpy as np
import pytest

import tissue_env
from tissue_env.base import DIFFICULTIES

ENV_IDS = sorted(tissue_env.ENV_IDS)
POSITIONING = "tissue_env/TumorPositioning-v0"


def same(env, name, value):
    """Whether the env's keyword ``name`` holds the table value ``value`` (a vector keyword holds a
    number broadcast along the axes)."""
    stored = getattr(env.unwrapped, name)
    if value is None:  # the keyword's own default: TumorPositioning's least goal distance, 2 tolerances
        assert name == "goal_min_distance"
        value = 2.0 * env.unwrapped.success_distance
    if isinstance(value, bool):
        return stored is value
    return np.allclose(np.asarray(stored, dtype=float), np.asarray(value, dtype=float), rtol=0, atol=0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_level_sets_its_keywords_and_explicit_keywords_override_them(env_id):
    table = gym.spec(env_id).entry_point
    module, name = table.split(":")
    cls = getattr(__import__(module, fromlist=[name]), name)
    assert tuple(cls.DIFFICULTY) == DIFFICULTIES
    assert all(set(settings) == set(cls.DIFFICULTY["default"]) for settings in cls.DIFFICULTY.values())
    for level in DIFFICULTIES:
        env = gym.make(env_id, difficulty=level)
        assert env.unwrapped.difficulty == level
        for keyword, value in cls.DIFFICULTY[level].items():
            assert same(env, keyword, value), (level, keyword, getattr(env.unwrapped, keyword), value)
    # each level differs from the default; a keyword given explicitly replaces its level's value only
    assert cls.DIFFICULTY["hard"] != cls.DIFFICULTY["default"] != cls.DIFFICULTY["easy"]
    keyword = next(k for k in cls.DIFFICULTY["hard"] if k != "terminate_on_success")
    override = cls.DIFFICULTY["easy"][keyword]
    env = gym.make(env_id, difficulty="hard", **{keyword: override})
    assert same(env, keyword, override)
    for other, value in cls.DIFFICULTY["hard"].items():
        if other != keyword:
            assert same(env, other, value), other


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_default_level_is_the_registered_task(env_id):
    plain, default = gym.make(env_id), gym.make(env_id, difficulty="default")
    actions = np.random.default_rng(5).uniform(-1, 1, (5,) + plain.action_space.shape).astype(np.float32)
    np.testing.assert_array_equal(plain.reset(seed=3)[0], default.reset(seed=3)[0])
    for action in actions:
        first, second = plain.step(action), default.step(action)
        np.testing.assert_array_equal(first[0], second[0])
        assert first[1:4] == second[1:4]


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("keyword, value", [
    ("difficulty", "expert"), ("difficulty", None), ("difficulty", 2), ("terminate_on_success", "yes"),
    ("terminate_on_success", 1),
])
def test_invalid_difficulty_keywords_name_themselves(env_id, keyword, value):
    with pytest.raises(ValueError, match=keyword):
        gym.make(env_id, **{keyword: value})


@pytest.mark.parametrize("env_id, keyword, value", [
    (POSITIONING, "success_distance", -0.001), (POSITIONING, "goal_displacement", 0.0),
    ("tissue_env/Palpation-v0", "hold_steps", 0), ("tissue_env/Palpation-v0", "inclusion_ratio", -2.0),
    ("tissue_env/Palpation-v0", "inclusion_size", (0.01, 0.0, 0.01)), ("tissue_env/Palpation-v0", "success_radius", 0),
    ("tissue_env/Palpation-v0", "start_distance", -0.01),
    ("tissue_env/Retraction-v0", "success_exposure", 1.5), ("tissue_env/Retraction-v0", "force_limit", 0.0),
])
@pytest.mark.parametrize("level", ["easy", "hard"])
def test_an_invalid_override_is_refused_at_every_level(env_id, keyword, value, level):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match=keyword):
            gym.make(env_id, difficulty=level, **{keyword: value})


def test_without_terminate_on_success_the_episode_goes_on_past_a_success():
    env = gym.make(POSITIONING, terminate_on_success=False)
    env.reset(seed=0)
    successes = []
    for _ in range(15):
        _, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        successes.append(info["is_success"])
        assert not terminated and not truncated
    assert any(successes)
    first = successes.index(True)
    assert successes[first:].count(True) >= 2  # the scripted controller holds the tumour there


def test_hard_tumor_positioning_draws_farther_goals_with_a_tighter_tolerance():
    """What the tumour has to travel to succeed (its start distance from the goal less the
    tolerance) grows from easy to default to hard over the same seeds (hard: its longer goal
    displacement and least goal distance), and the tolerance shrinks."""
    travel, tolerances = {}, []
    for level in DIFFICULTIES:
        env = gym.make(POSITIONING, difficulty=level)
        tolerance = env.unwrapped.success_distance
        distances = np.array([env.reset(seed=seed)[1]["distance"] for seed in range(4)])
        assert np.all(distances >= tolerance)
        travel[level] = np.mean(distances - tolerance)
        tolerances.append(tolerance)
    assert travel["hard"] > 1.2 * travel["default"] > 1.2 * 1.2 * travel["easy"]
    assert tolerances == sorted(tolerances, reverse=True)


def test_goal_min_distance_is_checked():
    with pytest.raises(ValueError, match="goal_min_distance"):
        gym.make(POSITIONING, success_distance=0.002, goal_min_distance=0.001)
    with pytest.raises(ValueError, match="goal_min_distance"):
        gym.make(POSITIONING, goal_min_distance=-1.0)
