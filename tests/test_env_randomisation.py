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


def _draws(env, seeds, key):
    return [np.array(env.reset(seed=seed)[1][key], dtype=float) for seed in seeds]


@pytest.mark.parametrize("env_id", sorted(tissue_env.ENV_IDS))
def test_density_range_draws_the_mass_of_each_episode(env_id):
    """density_range: a density per episode, inside the range, different across episodes, the same
    for the same seed, reported as info["density"] at reset and at every step, and the episode's
    model carries it: its lumped masses sum to density x the block's volume."""
    env = gym.make(env_id, density_range=(900.0, 1200.0))
    densities = _draws(env, (0, 1, 2), "density")
    assert all(900.0 <= d <= 1200.0 for d in densities) and len({float(d) for d in densities}) == 3
    assert float(_draws(env, (1,), "density")[0]) == float(densities[1])
    info = env.step(np.zeros(env.action_space.shape, np.float32))[4]
    model = env.unwrapped.model
    assert info["density"] == float(densities[1])
    assert model.mass.sum() == pytest.approx(info["density"] * model.rest_volume.sum(), rel=1e-12)
    assert gym.make(env_id, density=1000.0).reset(seed=0)[1]["density"] == 1000.0


def test_palpation_inclusion_size_range_sets_the_stiff_volume():
    """inclusion_size_range: each axis drawn per episode inside its range, info["inclusion_size"];
    the elements stiffened hold exactly the drawn box (shares x volumes = its volume, for a box
    inside the slab), a different one per episode."""
    low, high = (0.008, 0.006, 0.008), (0.016, 0.01, 0.016)
    env = gym.make(PALPATION, inclusion_size_range=(low, high), young_modulus=4e3, inclusion_ratio=10.0)
    sizes = []
    for seed in range(3):
        _, info = env.reset(seed=seed)
        size = np.asarray(info["inclusion_size"])
        assert np.all(size >= low) and np.all(size <= high)
        share = (env.unwrapped.model.young_modulus / 4e3 - 1.0) / 9.0
        assert share @ env.unwrapped.mesh.element_volumes() == pytest.approx(np.prod(size), rel=1e-9)
        sizes.append(tuple(size))
    assert len(set(sizes)) == 3
    assert np.allclose(gym.make(PALPATION).reset(seed=0)[1]["inclusion_size"], (0.012, 0.01, 0.012))


@pytest.mark.parametrize("value", [((0.01, 0.01, 0.01), (0.005, 0.02, 0.02)), (0.01,), ((0.0, 0.01, 0.01), 0.02)])
def test_invalid_inclusion_size_range_names_it(value):
    with pytest.raises(ValueError, match="inclusion_size_range"):
        gym.make(PALPATION, inclusion_size_range=value)


@pytest.mark.parametrize("env_id", sorted(tissue_env.ENV_IDS))
def test_a_vector_copy_equals_the_single_env_under_randomisation(env_id):
    """With every material range on (and Palpation's inclusion ranges), a vector env's copies draw
    the single envs' episodes of the same seeds and take their steps (to 1e-6)."""
    ranges = dict(young_modulus_range=(3e3, 8e3), poisson_ratio_range=(0.4, 0.45), density_range=(950.0, 1150.0))
    if "Palpation" in env_id:
        ranges.update(inclusion_ratio_range=(4.0, 12.0), inclusion_size_range=(0.008, 0.014))
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **ranges)
    singles = [gym.make(env_id, **ranges) for _ in range(2)]
    observations, infos = vector.reset(seed=[10, 11])
    expected = [single.reset(seed=seed) for single, seed in zip(singles, (10, 11))]
    actions = np.random.default_rng(4).uniform(-1, 1, (4, 2) + singles[0].action_space.shape).astype(np.float32)
    for step in range(len(actions) + 1):
        for index in range(2):
            np.testing.assert_allclose(observations[index], expected[index][0], rtol=0, atol=1e-6)
            for key in ("young_modulus", "poisson_ratio", "density") + (("inclusion_size",) if "Palpation" in env_id else ()):
                np.testing.assert_array_equal(infos[key][index], expected[index][-1][key])
        if step == len(actions):
            break
        observations, _, _, _, infos = vector.step(actions[step])
        expected = [single.step(action) for single, action in zip(singles, actions[step])]
    vector.close()
