"""Domain randomisation of the block's size (``size_range``), of TumorPositioning's grasped patch
(``tool_size_range``) and the observation of the drawn parameters (``observe_parameters``): bad
input is a ValueError naming the keyword, the draws stay in their ranges and are in ``info``, a
drawn block is the same physics as a block built at that size, the copies of a vector env draw
their own, and the observation passes gymnasium's and stable-baselines3's checkers."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tissue_env  # noqa: F401  (registers the ids)

PALPATION, POSITIONING, RETRACTION, LIVER = ("tissue_env/Palpation-v0", "tissue_env/TumorPositioning-v0",
                                             "tissue_env/Retraction-v0", "tissue_env/LiverNeedleAlignment-v0")
#: TumorPositioning's default block is 5 cm cubed, Retraction's flap 6 x 0.8 x 3 cm
TUMOR_SIZES = ((0.045, 0.045, 0.045), (0.055, 0.055, 0.055))
FLAP_SIZES = ((0.055, 0.007, 0.027), (0.065, 0.009, 0.033))
#: Palpation's slab is 6 x 3 x 6 cm; model="baudet" takes near-cubic elements only (its default, baudet-hyperelastic, any box)
SLAB_SIZES = ((0.05, 0.026, 0.055), (0.07, 0.034, 0.065))


@pytest.mark.parametrize("env_id, kwargs, message", [
    (POSITIONING, dict(size_range=0.05), "size_range must be None or a (low, high) pair"),
    (POSITIONING, dict(size_range=((0.05, 0.05, 0.05), (0.04, 0.06, 0.06))), "low <= high along every axis"),
    (POSITIONING, dict(size_range=(-0.01, 0.05)), "size_range must be finite and > 0"),
    # Baudet's springs refuse the 1:10:1 elements of that corner (baudet-hyperelastic takes any box)
    (POSITIONING, dict(model="baudet", size_range=((0.05, 0.05, 0.05), (0.05, 0.5, 0.05))), "size_range corner"),
    (LIVER, dict(size_range=(0.05, 0.06)), "LiverNeedleAlignmentEnv takes no size_range"),
    (PALPATION, dict(size_range=SLAB_SIZES, model="baudet"), "size_range corner"),
    (PALPATION, dict(cell_size=(0.012, 0.0, 0.012)), "cell_size must be finite and > 0"),
    (PALPATION, dict(cell_size=0.025), "too small for the palpation scene"),
    (POSITIONING, dict(tool_size_range=(0.03, 0.02)), "tool_size_range must have low <= high"),
    (POSITIONING, dict(tool_size_range=(0.001, 0.02)), "tool_size_range's low end = 0.001 m grasps no top node"),
    (POSITIONING, dict(tool_size_range=(0.02, 0.03), observation_type="rgb"), "tool_size_range draws the grasped"),
    (PALPATION, dict(probe_radius_range=(0.0, 0.01)), "probe_radius_range must be a finite number > 0"),
    (POSITIONING, dict(observe_parameters=1), "observe_parameters must be True or False"),
    (POSITIONING, dict(observe_parameters=True), "none is: give one of"),
    (RETRACTION, dict(observe_parameters=True, density_range=(1000, 1100), observation_type="depth"),
     "observe_parameters appends values to a vector observation"),
])
def test_bad_randomisation_keywords_are_value_errors(env_id, kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        gym.make(env_id, **kwargs)


def _steps(env, actions):
    """(reaction forces, relative volume changes, max strains) over ``actions`` from a reset."""
    records = []
    for action in actions:
        info = env.step(action)[-1]
        records.append(np.concatenate([info["reaction_force"], [info["relative_volume_change"], info["max_strain"]]]))
    return np.array(records)


@pytest.mark.parametrize("env_id, name, value", [
    (POSITIONING, "size", (0.047, 0.052, 0.054)), (RETRACTION, "size", (0.058, 0.0085, 0.031)),
    (POSITIONING, "tool_size", 0.04), (PALPATION, "probe_radius", 0.0065)])
def test_a_drawn_value_is_the_physics_of_an_env_built_with_it(env_id, name, value):
    # a range of one value draws that value: the episode must be the env built with it (the tool,
    # the attached face, the masses, the springs on the scaled block; the grasped nodes; the probe's
    # contact), bit for bit
    drawn = gym.make(env_id, **{f"{name}_range": (value, value)})
    built = gym.make(env_id, **{name: value})
    _, info = drawn.reset(seed=3)
    built.reset(seed=3)
    np.testing.assert_array_equal(info[name], value)
    actions = np.random.default_rng(0).uniform(-1, 1, (8, 3)).astype(np.float32)
    actions[:, 1] = -np.abs(actions[:, 1])  # down: the probe presses
    measured = _steps(drawn, actions)
    np.testing.assert_array_equal(measured, _steps(built, actions))
    default = gym.make(env_id)  # and the default block's is another
    default.reset(seed=3)
    assert not np.allclose(_steps(default, actions), measured, rtol=1e-3)


def test_sizes_and_tool_sizes_are_drawn_per_episode_into_info_and_the_start_state():
    env = gym.make(POSITIONING, size_range=TUMOR_SIZES, tool_size_range=(0.015, 0.035))
    sizes, tool_sizes = [], []
    for seed in range(3):
        _, info = env.reset(seed=seed)
        low, high = np.asarray(TUMOR_SIZES)
        assert np.all((info["size"] >= low) & (info["size"] <= high))
        assert 0.015 <= info["tool_size"] <= 0.035
        # the attached bottom face spans the drawn block (held at its rest positions)
        bottom = env.unwrapped.state.positions[env.unwrapped.fixed_nodes]
        np.testing.assert_allclose(np.ptp(bottom[:, [0, 2]], axis=0), info["size"][[0, 2]], rtol=1e-12)
        # the grasped patch: the top nodes within tool_size / 2 of the top's centre, on the drawn block
        patch = env.unwrapped.start_control.target[env.unwrapped.tool_nodes]
        assert np.all(np.abs(patch[:, [0, 2]] - 0.5 * info["size"][[0, 2]]) <= 0.5 * info["tool_size"] + 1e-9)
        sizes.append(tuple(info["size"]))
        tool_sizes.append(info["tool_size"])
    assert len(set(sizes)) == 3 and len(set(tool_sizes)) == 3


@pytest.mark.parametrize("env_id, kwargs, name", [
    (POSITIONING, dict(size_range=TUMOR_SIZES, tool_size_range=(0.015, 0.035)), "size"),
    (RETRACTION, dict(size_range=FLAP_SIZES), "size"),
    (PALPATION, dict(probe_radius_range=(0.006, 0.012)), "probe_radius"),
    (PALPATION, dict(size_range=SLAB_SIZES, model="baudet-hyperelastic"), "size"),
])
def test_vector_copies_draw_their_own_values_and_equal_single_envs(env_id, kwargs, name):
    vector = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", **kwargs)
    observations, infos = vector.reset(seed=5)
    assert len({tuple(np.atleast_1d(value)) for value in infos[name]}) == 3
    singles = [gym.make(env_id, **kwargs) for _ in range(3)]
    starts = [env.reset(seed=5 + i) for i, env in enumerate(singles)]
    np.testing.assert_array_equal(infos[name], [info[name] for _, info in starts])
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 3, 3)).astype(np.float32)
    actions[..., 1] = -np.abs(actions[..., 1])
    for action in actions:
        observations = vector.step(action)[0]
        single = [env.step(action[i])[0] for i, env in enumerate(singles)]
    np.testing.assert_array_equal(observations, np.stack(single))


def test_observed_parameters_are_the_drawn_values_normalised_over_their_ranges():
    kwargs = dict(size_range=FLAP_SIZES, young_modulus_range=(3e3, 8e3))
    plain = gym.make(RETRACTION, **kwargs)
    env = gym.make(RETRACTION, observe_parameters=True, **kwargs)
    observation, info = env.reset(seed=2)
    base, _ = plain.reset(seed=2)
    assert observation.shape == (base.shape[0] + 4,)  # E, then the size's three axes
    np.testing.assert_array_equal(observation[:-4], base)  # the same episode, the parameters appended
    low, high = np.asarray(FLAP_SIZES)
    expected = np.concatenate([[2 * (info["young_modulus"] - 3e3) / 5e3 - 1], 2 * (info["size"] - low) / (high - low) - 1])
    np.testing.assert_allclose(observation[-4:], expected, atol=1e-6)
    assert np.all(np.abs(observation[-4:]) <= 1)
    dict_env = gym.make(RETRACTION, observe_parameters=True, observation_type="dict", **kwargs)
    np.testing.assert_allclose(dict_env.reset(seed=2)[0]["parameters"], expected, atol=1e-6)


@pytest.mark.parametrize("observation_type", ["state", "dict", "goal"])
def test_observed_parameters_pass_the_gymnasium_and_sb3_checkers(observation_type):
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    env = gym.make(POSITIONING, observe_parameters=True, observation_type=observation_type,
                   size_range=TUMOR_SIZES, tool_size_range=(0.015, 0.035), density_range=(1000.0, 1100.0))
    observation, _ = env.reset(seed=0)
    parameters = observation["observation"][-5:] if observation_type == "goal" else (
        observation["parameters"] if observation_type == "dict" else observation[-5:])
    assert parameters.shape == (5,) and np.all(np.abs(parameters) <= 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the checkers' advice (e.g. on unbounded spaces), not failures
        check_env(env.unwrapped, skip_render_check=True)
        sb3_checker.check_env(env.unwrapped, warn=False)


def test_a_stacked_copy_on_another_block_geometry_has_that_blocks_forces():
    # sim_core.models.stack: a copy assigned a model of the same topology on a scaled block takes its rest
    # geometry with it (the hourglass term's rest positions, the rest edge directions): its forces are
    # the single model's, bit for bit, beside copies of the other geometry
    from sim_core import HexMesh, Material, build_model
    from sim_core.models.forces import ForceWorkspace
    from sim_core.models.stack import ModelStack, StackedForceWorkspace

    def model(spacing, young):
        # baudet, for its hourglass term's rest positions; the bound on its boxes' shear error is
        # about accuracy, not the stacking checked here
        return build_model(HexMesh.block((3, 2, 3), spacing), Material(young, 0.45, 1060.0), gravity=(0, -9.81, 0),
                           hourglass_control=1.0, volume_stiffness=100.0, max_shear_error=None)

    models = [model(0.01, 5e3), model(np.array([0.012, 0.009, 0.011]), 7e3), model(0.01, 5e3)]
    stack = ModelStack(models[0], 3)
    stack.assign(1, models[1])
    rng = np.random.default_rng(0)
    positions = np.stack([m.mesh.nodes for m in models]) + 1e-3 * rng.normal(size=(3, models[0].n_nodes, 3))
    velocities = 1e-2 * rng.normal(size=positions.shape)
    forces = StackedForceWorkspace(stack, implicit=False).compute(positions.reshape(-1, 3), velocities.reshape(-1, 3))
    for index, single in enumerate(models):
        expected = ForceWorkspace(single, implicit=False).compute(positions[index], velocities[index])
        np.testing.assert_array_equal(forces.reshape(3, -1, 3)[index], expected)


def test_a_drawn_slab_is_the_palpation_scene_built_at_that_size():
    # Palpation keeps its candidate lattice on a drawn slab, each cell scaled with the slab (the
    # palpation map keeps its length): the drawn episode is the env built at that size with the
    # cells scaled so. A size draw takes random numbers the built env does not, so the probe starts
    # elsewhere: both probes are moved over the inclusion (no contact), then press it; the press
    # is the same physics to the rounding of the probe's path (measured: 5e-11 relative).
    from tissue_env.palpation import PalpationEnv

    size, default = np.array([0.057, 0.0285, 0.057]), np.array(PalpationEnv.default_size)
    region = ((0.5, 0.5), (0.5, 0.5))  # the centre cell only: the same inclusion in both
    drawn = gym.make(PALPATION, size_range=(size, size), inclusion_region=region)
    built = gym.make(PALPATION, size=size, inclusion_region=region,
                     cell_size=np.array(PalpationEnv.default_cell_size) * size / default)
    _, info = drawn.reset(seed=3)
    _, expected = built.reset(seed=3)
    np.testing.assert_array_equal(info["size"], size)
    np.testing.assert_array_equal(info["inclusion_centre"], expected["inclusion_centre"])
    np.testing.assert_array_equal(drawn.unwrapped.state.positions, built.unwrapped.state.positions)

    def press(env):
        unwrapped, records = env.unwrapped, []
        goal, moves = unwrapped.inclusion_centre, 8
        for k in range(moves):  # above the surface, in as many steps in both envs
            tip = unwrapped.probe_start + unwrapped.tool_offset
            env.step(((np.array([goal[0], tip[1], goal[2]]) - tip) / (unwrapped.max_step * (moves - k))).astype(np.float32))
        for k in range(5):
            _, reward, terminated, _, info = env.step(np.array([0.0, -0.6 if k < 4 else 0.0, 0.0], np.float32))
            records.append([*info["reaction_force"], info["apparent_modulus"], info["depth"], info["press_steps"],
                            info["max_strain"], reward, terminated])
        return np.array(records)

    measured = press(drawn)
    assert measured[-1, 5] == 3 and measured[-1, -1]  # the press held over the inclusion: success
    np.testing.assert_allclose(measured, press(built), rtol=1e-9, atol=1e-12)


def test_palpation_on_drawn_slabs_keeps_its_map_and_its_scripted_sweep_finds_the_inclusion():
    # the candidate lattice scales with the drawn slab: the same C cells at the same fractions of
    # the slab, the inclusion centre at the same fraction of its depth; the scripted sweep (the
    # map's presses, then the stiffest cell) finds the inclusion on every drawn slab (measured: 20
    # of 20 seeds over SLAB_SIZES, median 64 steps)
    env = gym.make(PALPATION, size_range=SLAB_SIZES, model="baudet-hyperelastic")
    fixed = gym.make(PALPATION, model="baudet-hyperelastic").unwrapped
    fractions = fixed.cell_centres / fixed.size[[0, 2]]
    for seed in range(3):
        observation, info = env.reset(seed=seed)
        unwrapped = env.unwrapped
        assert observation.shape == env.observation_space.shape
        np.testing.assert_allclose(unwrapped.cell_centres / info["size"][[0, 2]], fractions, rtol=1e-12)
        assert unwrapped.top_y == info["size"][1]
        np.testing.assert_allclose((info["size"][1] - info["inclusion_centre"][1]) / info["size"][1], 0.5, rtol=1e-12)
        for _ in range(100):
            _, _, terminated, truncated, info = env.step(unwrapped.scripted_action())
            if terminated or truncated:
                break
        assert info["is_success"] and not info["unstable"]
