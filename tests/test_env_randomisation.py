"""Domain randomisation keywords of the tasks (issue 4): ranges are drawn from np_random at each
reset, stay inside their ranges, and invalid ranges raise ValueError naming the keyword."""

import warnings

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the ids)

PALPATION, POSITIONING, RETRACTION = ("tissue_env/Palpation-v0", "tissue_env/TumorPositioning-v0",
                                      "tissue_env/Retraction-v0")


def test_palpation_inclusion_ratio_range_sets_the_inclusion_stiffness():
    env = gym.make(PALPATION, inclusion_ratio_range=(3.0, 12.0), young_modulus=4e3)
    ratios = []
    for seed in range(3):
        env.reset(seed=seed)
        unwrapped = env.unwrapped
        ratio = unwrapped.episode_inclusion_ratio
        young = unwrapped.model.young_modulus
        assert 3.0 <= ratio <= 12.0
        # the inclusion box's stiff volume: elements stiffened by their share in it (tissue_env.palpation)
        share = (young / 4e3 - 1.0) / (ratio - 1.0)
        assert np.all((share >= -1e-12) & (share <= 1 + 1e-12)) and share.max() > 0.1
        assert np.isclose(share @ unwrapped.mesh.element_volumes(), 0.012 * 0.01 * 0.012)
        ratios.append(ratio)
    assert len(set(ratios)) == 3


def test_palpation_inclusion_region_restricts_the_candidate_cells():
    # 5 x 5 layer: element centres at fractions 0.1, 0.3, 0.5, 0.7, 0.9
    env = gym.make(PALPATION, inclusion_region=((0.0, 0.6), (0.4, 1.0)))
    cells = env.unwrapped.inclusion_cells
    assert sorted(map(tuple, cells[:, [0, 2]])) == [(0, 3), (0, 4), (1, 3), (1, 4)]
    seen = set()
    for seed in range(8):
        _, info = env.reset(seed=seed)
        seen.add(tuple(env.unwrapped.inclusion_cell[[0, 2]]))
        assert info["horizontal_distance"] >= env.unwrapped.start_distance - 1e-12
    assert seen <= {(0, 3), (0, 4), (1, 3), (1, 4)} and len(seen) > 1


def test_tumor_positioning_goal_scale_range_sets_the_goal_tool_displacement():
    env = gym.make(POSITIONING, goal_scale_range=(0.9, 1.0))
    for seed in range(3):
        env.reset(seed=seed)
        unwrapped = env.unwrapped
        largest = np.abs(unwrapped.goal_tool_displacement).max()
        # the draw (0.9-1 x 12 mm), or more when the scale-up for the minimum goal distance kicked in
        assert largest >= 0.9 * 0.012 - 1e-12
        assert np.all(np.abs(unwrapped.goal_tool_displacement) <= unwrapped.workspace + 1e-12)


def test_tumor_positioning_tumor_region_holds_the_tumour():
    env = gym.make(POSITIONING, tumor_region=((0.3, 0.6, 0.3), (0.4, 0.7, 0.4)))
    for seed in range(3):
        env.reset(seed=seed)
        unwrapped = env.unwrapped
        rest = unwrapped.tumor_weights @ unwrapped.mesh.nodes[unwrapped.tumor_nodes]
        assert np.all(rest >= np.array([0.3, 0.6, 0.3]) * 0.05 - 1e-12)
        assert np.all(rest <= np.array([0.4, 0.7, 0.4]) * 0.05 + 1e-12)


def test_retraction_target_start_range():
    env = gym.make(RETRACTION, target_start_range=(0.035, 0.036))
    for seed in range(3):
        env.reset(seed=seed)
        assert 0.035 <= env.unwrapped.target_x[0] <= 0.036


@pytest.mark.parametrize("env_id, keyword, value", [
    (PALPATION, "inclusion_ratio_range", (12.0, 3.0)),
    (PALPATION, "inclusion_ratio_range", (0.0, 3.0)),
    (PALPATION, "inclusion_ratio_range", 5.0),
    (PALPATION, "inclusion_ratio_range", (3.0, float("nan"))),
    (PALPATION, "inclusion_region", ((0.5, 0.5), (0.2, 0.9))),
    (PALPATION, "inclusion_region", ((0.0, 0.0), (1.5, 1.0))),
    (PALPATION, "inclusion_region", (0.2, 0.8)),
    (PALPATION, "inclusion_region", ((0.41, 0.41), (0.49, 0.49))),  # no element centre inside
    (PALPATION, "hold_steps", 0),
    (PALPATION, "hold_steps", 2.5),
    (PALPATION, "start_distance", -0.01),
    (POSITIONING, "goal_scale_range", (1.0, 0.5)),
    (POSITIONING, "goal_scale_range", (0.0, 1.0)),
    (POSITIONING, "goal_scale_range", None),
    (POSITIONING, "goal_scale_range", "wide"),
    (POSITIONING, "tumor_region", ((0.7, 0.2, 0.2), (0.3, 0.8, 0.8))),
    (POSITIONING, "tumor_region", ((0.2, 0.2), (0.8, 0.8))),
    (RETRACTION, "target_start_range", (0.04, 0.03)),
    (RETRACTION, "target_start_range", (0.03,)),
    (RETRACTION, "target_start_range", (-0.01, 0.03)),
    (RETRACTION, "target_start_range", None),
])
def test_invalid_randomisation_keyword_names_it(env_id, keyword, value):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match=keyword):
            gym.make(env_id, **{keyword: value})


@pytest.mark.parametrize("env_id", sorted(tissue_env.ENV_IDS))
def test_the_sampled_material_is_in_every_info(env_id):
    """Domain randomisation reports what it drew: every info of an episode (reset and steps) has the
    episode's ``young_modulus`` and ``poisson_ratio`` (Palpation also its ``inclusion_ratio``), the
    fixed values without a range, and a vector env reports each copy's own draw."""
    ranges = dict(young_modulus_range=(2e3, 8e3), poisson_ratio_range=(0.3, 0.45))
    env = gym.make(env_id, **ranges)
    drawn = set()
    for seed in (0, 1):
        _, info = env.reset(seed=seed)
        young, poisson = info["young_modulus"], info["poisson_ratio"]
        assert 2e3 <= young <= 8e3 and 0.3 <= poisson <= 0.45
        assert young == env.unwrapped.episode_young_modulus
        step_info = env.step(env.action_space.sample())[4]
        assert (step_info["young_modulus"], step_info["poisson_ratio"]) == (young, poisson)
        drawn.add(young)
    assert len(drawn) == 2  # a new draw per reset
    fixed = gym.make(env_id, young_modulus=4e3)
    assert fixed.reset(seed=0)[1]["young_modulus"] == 4e3
    if "Palpation" in env_id:
        ratio = gym.make(env_id, inclusion_ratio_range=(3.0, 12.0)).reset(seed=0)[1]["inclusion_ratio"]
        assert 3.0 <= ratio <= 12.0
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **ranges)
    _, infos = vector.reset(seed=[0, 1])
    singles = [gym.make(env_id, **ranges).reset(seed=seed)[1]["young_modulus"] for seed in (0, 1)]
    np.testing.assert_array_equal(infos["young_modulus"], singles)
    infos = vector.step(vector.action_space.sample())[4]
    np.testing.assert_array_equal(infos["young_modulus"], singles)
    vector.close()
