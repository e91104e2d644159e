"""Dissection-v0: the scripted dissection frees the flap, the grasper's peel keeps the cut surfaces
apart (without it the freed flap sinks through its bed), cutting the flap or the bed is counted as
damage, success is the flap's separation from the bed in the cut model, a vector copy is the single
env through cuts, reset brings the uncut tissue back, and snapshots, deepcopy and pickle hold the cut."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401
from cut_steps import (assert_approach_is_the_route_shortening, assert_random_blades_are_finite,
                       assert_reset_restores_the_uncut_tissue, assert_snapshots_hold_the_cut,
                       assert_vector_copy_equals_single, scripted_steps)
from tissue_env.dissection import BED, CONNECTIVE, FLAP

ENV_ID = "tissue_env/Dissection-v0"
#: A smaller slab of the same 5 mm elements (a cut rebuilds its model: cheaper tests)
SMALL = dict(shape=(6, 4, 4), size=(0.03, 0.02, 0.02),
             blade_start_range=((0.033, 0.022, 0.008), (0.038, 0.028, 0.012)))


def interface_gaps(env):
    """(G,) m the height of each flap-side node over its connective-side twin, for the nodes of the
    layer's top that the cut has copied: positive where the cut has opened, negative where the flap
    has passed into the layer below it."""
    task = env.unwrapped
    model = task.worlds.stack.given[0]
    elements, labels = model.mesh.elements, task.labels
    on_flap = np.zeros(model.n_nodes, dtype=bool)
    on_flap[elements[labels == FLAP].ravel()] = True
    on_layer = np.zeros(model.n_nodes, dtype=bool)
    on_layer[elements[labels == CONNECTIVE].ravel()] = True
    origin = task.worlds.node_origin[0, :model.n_nodes]
    copies = np.arange(task.mesh.n_nodes, model.n_nodes)
    originals = origin[copies]
    flap_side = np.where(on_flap[copies] & ~on_flap[originals], copies, originals)
    layer_side = np.where(flap_side == copies, originals, copies)
    keep = on_flap[flap_side] & on_layer[layer_side] & ~on_flap[layer_side]
    y = task.state.positions[:, 1]
    return y[flap_side[keep]] - y[layer_side[keep]]


def test_the_scripted_dissection_frees_the_flap_on_nine_of_ten_seeds():
    from tissue_env.episodes import run_episode, scripted_policy

    env = gym.make(ENV_ID, **SMALL)  # the default slab: benchmarks/dissection.py
    scripted = [run_episode(env, scripted_policy, seed) for seed in range(10)]
    assert sum(info["is_success"] for _, _, info in scripted) >= 9
    assert all(info["flap_damage"] == 0 and info["bed_damage"] == 0 and info["cut_progress"] == 1.0
               for _, _, info in scripted)


def test_the_approach_reward_is_the_route_shortening():
    """The approach term (potential-based, ``tissue_env.cut_tasks``) is the route's shortening per cm at
    every step; the scripted dissection only shortens it, in all by 6.0-6.4 cm on seeds 0-2 (the docstring's)."""
    assert 5.9 < assert_approach_is_the_route_shortening(ENV_ID, {}, 0) < 6.5


def test_a_blade_past_a_joined_column_is_pulled_back_to_it():
    """A blade swept along x above the layer (through the flap) leaves the columns joined: past the
    first one the route lengthens (each step along x is penalised) and the observed next point lies
    behind the blade, at that column; back beside the free edge and along the layer's top, the sweep
    frees the column and the route is shorter than it was (a potential of the blade's place and the
    columns still joined)."""
    env = gym.make(ENV_ID, **SMALL, observation_type="dict")
    env.reset(seed=0)
    task = env.unwrapped
    spacing, size_x = task.spacing, task.size[0]
    entry = task.sweep_entry

    def move(goal, steps):
        for _ in range(steps):
            tip = task.tip_rest + task.tool_offset
            step = env.step(np.clip((np.asarray(goal) - tip) / task.max_step, -1, 1).astype(np.float32))
        return step

    above = (entry[0], entry[1] + 0.7 * spacing[1], entry[2])  # between the flap's first and second centroids
    move(above, 8)
    observation, _, _, _, info = move((size_x - 1.5 * spacing[0], above[1], entry[2]), 3)
    approach = info["reward_approach"]
    assert info["cut_progress"] == 0.0 and info["flap_damage"] > 0
    assert approach < 0.0 and observation["route_offset"][0] > 0.0  # lengthened; the next point behind
    before = info["route_remaining"]
    move(above, 4)
    move(entry, 3)
    *_, info = move((size_x - 1.5 * spacing[0], entry[1], entry[2]), 3)
    assert info["cut_progress"] > 0.0 and info["route_remaining"] < before


@pytest.mark.parametrize("poisson_ratio", [0.3, 0.45, 0.49])
def test_the_scripted_dissection_frees_a_soft_flap(poisson_ratio):
    """At E = 1 kPa the slab sags under its weight (the sweep follows the layer's top in the start
    equilibrium, 1.1 mm below its rest height at nu = 0.3) and the lifted flap slides back over the
    blade (it sweeps back over the slice it missed): the flap is freed, no bed face cut and at most
    ``damage_allowed`` flap faces (2 at nu = 0.45, where the freed flap's corners sag into the cut)."""
    env = gym.make(ENV_ID, young_modulus=1e3, poisson_ratio=poisson_ratio)
    env.reset(seed=100)
    infos = scripted_steps(env, 60)
    assert infos[-1]["is_success"] and infos[-1]["bed_damage"] == 0
    assert infos[-1]["flap_damage"] <= env.unwrapped.damage_allowed


@pytest.mark.parametrize("peel_angle", [30.0, 0.0])
def test_the_peel_keeps_the_cut_apart_and_without_it_the_flap_sinks_into_its_bed(peel_angle):
    """Until the flap is free, with the grasper's peel (30 deg) every freed node of the flap's underside
    stays above its twin on the connective layer (the cut open by more than 0.5 mm everywhere, by cm
    at the grasped edge); with the edge held where it was (peel 0) the freed flap sags through the
    layer it was cut from (by more than 0.5 mm): nothing else keeps the cut surfaces apart."""
    env = gym.make(ENV_ID, peel_angle=peel_angle, **SMALL)
    env.reset(seed=0)
    lowest, highest = np.inf, -np.inf
    for _ in range(40):
        *_, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        gaps = interface_gaps(env)
        if len(gaps) and not info["flap_free"]:
            lowest, highest = min(lowest, gaps.min()), max(highest, gaps.max())
        if terminated or truncated:
            break
    assert info["flap_free"] and not info["unstable"]
    if peel_angle:
        assert lowest > 5e-4 and highest > 1e-2
    else:
        assert lowest < -5e-4 and highest < 1e-3


def test_success_is_the_flap_separated_from_the_bed():
    """``flap_free`` turns on at the step that cuts the last column, not before; then no node of the cut
    model is shared by a flap element and a connective or bed element (the flap is a body of its own)."""
    env = gym.make(ENV_ID, **SMALL)
    env.reset(seed=1)
    infos = scripted_steps(env, 40)
    assert [info["flap_free"] for info in infos] == [False] * (len(infos) - 1) + [True]
    assert infos[-1]["is_success"] and infos[-1]["reward_success"] == 5.0
    assert [info["cut_progress"] for info in infos][-2] < 1.0 == infos[-1]["cut_progress"]
    task = env.unwrapped
    elements, labels = task.worlds.stack.given[0].mesh.elements, task.labels
    assert not np.intersect1d(elements[labels == FLAP], elements[labels != FLAP]).size
    assert np.intersect1d(elements[labels == CONNECTIVE], elements[labels == BED]).size  # the layer stays on the bed


def test_cutting_the_flap_or_the_bed_is_damage():
    """A blade swept through the flap (above the layer) cuts flap faces and frees nothing (the flap
    freed after that ends the episode without a success: more than ``damage_allowed`` faces cut);
    plunged through the slab between the last two columns it cuts flap and bed faces: each is penalised."""
    env = gym.make(ENV_ID, **SMALL)
    env.reset(seed=0)
    task = env.unwrapped
    spacing = task.spacing
    for goal, steps in (((task.size[0] + 0.25 * spacing[0], 3.0 * spacing[1], 0.5 * task.size[2]), 12),
                        ((0.5 * task.size[0], 3.0 * spacing[1], 0.5 * task.size[2]), 6)):
        for _ in range(steps):
            tip = task.tip_rest + task.tool_offset
            *_, info = env.step(np.clip((np.array(goal) - tip) / task.max_step, -1, 1).astype(np.float32))
    assert info["flap_damage"] > task.damage_allowed and info["bed_damage"] == 0 and info["cut_progress"] == 0.0
    infos = scripted_steps(env, 40)  # up out of the flap, then the dissection: it ends the episode, not a success
    assert infos[-1]["flap_free"] and not infos[-1]["is_success"] and infos[-1]["reward_success"] == 0.0
    env.reset(seed=0)
    x = task.size[0] - spacing[0]  # between the last two columns' centroids
    damage = []
    for goal in ((x, task.size[1] + 0.002, 0.5 * task.size[2]), (x, 0.002, 0.5 * task.size[2])):
        for _ in range(12):
            tip = task.tip_rest + task.tool_offset
            *_, info = env.step(np.clip((np.array(goal) - tip) / task.max_step, -1, 1).astype(np.float32))
            damage.append(info["reward_damage"])
    assert info["flap_damage"] > 0 and info["bed_damage"] > 0 and min(damage) < 0
    assert sum(damage) == -task.damage_weight * (info["flap_damage"] + info["bed_damage"])


def test_a_vector_copy_equals_the_single_env_through_cuts():
    """Copy 0 of a two-copy vector env, given the single env's scripted actions (a whole dissection)
    while copy 1 cuts elsewhere, takes the single env's steps (observations within 1e-9, the same
    rewards and cuts)."""
    assert assert_vector_copy_equals_single(ENV_ID, SMALL, 30, [-1.0, -0.4, 0.3])


def test_reset_restores_the_uncut_tissue_and_snapshots_copies_and_pickles_hold_the_cut():
    """After cuts, a reset gives the uncut slab back (the block's model; the next episode is a fresh
    env's bit for bit); a snapshot taken with the world cut, a deepcopy and a pickle of the env take
    the original's next steps bit for bit, cuts and the grasper's peel included."""
    env = gym.make(ENV_ID, **SMALL)
    env.reset(seed=2)
    scripted_steps(env, 14)
    assert_snapshots_hold_the_cut(env.unwrapped, ENV_ID, SMALL,
                                  check=lambda steps: steps[-1][4]["jaw_displacement"][1] > 0)  # the peel
    assert_reset_restores_the_uncut_tissue(env, ENV_ID, SMALL, 16)


@pytest.mark.parametrize("keyword, value", [("connective_layer", 0), ("flap_layers", 3), ("peel_angle", 120.0),
                                            ("blade_start_range", ((0.05, 0.02, 0.01),)), ("spare_nodes", -1),
                                            ("grasp_force_limit", 0.0), ("connective_stiffness_ratio", -1.0),
                                            ("damage_allowed", -1), ("damage_allowed", 1.5)])
def test_bad_keywords_name_what_is_wrong(keyword, value):
    with pytest.raises(ValueError, match=keyword):
        gym.make(ENV_ID, **{keyword: value})


def test_random_steps_are_finite_and_cuts_beyond_the_spare_rows_are_refused():
    """300 random steps of the default slab (the blade starts above the tissue), and 40 steps of a blade
    plunged into the small slab and then driven about at random (it cuts most steps, until the copies
    fill the world's spare node rows: the cuts beyond are refused): every observation and reward
    finite, no divergence."""
    cutting, refused = assert_random_blades_are_finite(ENV_ID, SMALL, 6, 40, [[-1.0, -1.0, 0.0]] * 8,
                                                       lambda rng: rng.uniform(-1.0, 1.0, 3))
    assert cutting >= 2 and refused >= 1
