"""Incision-v0 and cutting from a blade in the environments (tissue_env.blade): the scripted incision
succeeds, the cut follows the blade within half an element, opens under the tissue's tension and adds
no energy, a vector copy is the single env through cuts, reset brings the uncut tissue back, and
snapshots, deepcopy and pickle hold the cut topology."""

import copy

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401
from cut_steps import (assert_approach_is_the_route_shortening, assert_random_blades_are_finite,
                       assert_reset_restores_the_uncut_tissue, assert_snapshots_hold_the_cut,
                       assert_vector_copy_equals_single, scripted_steps)
from sim_core import cutting
from sim_core.models.forces import internal_forces

ENV_ID = "tissue_env/Incision-v0"
ELEMENT = 0.005  # the slabs' element, m
#: A smaller slab of the same 5 mm elements (a cut rebuilds its model: cheaper tests)
SMALL = dict(shape=(6, 3, 4), size=(0.03, 0.015, 0.02), line_start_range=(0.006, 0.008), line_length=0.015,
             line_z_range=(0.008, 0.012))


def open_cut(seed=0, steps=17):
    """A small slab whose scripted incision has cut a few columns (its world holds a cut model with copies)."""
    env = gym.make(ENV_ID, **SMALL)
    env.reset(seed=seed)
    infos = scripted_steps(env, steps)
    assert not env.unwrapped.worlds.stack.shared[0], "the cut should have copied nodes by now"
    return env, infos


def test_the_scripted_incision_succeeds_on_nine_of_ten_seeds():
    from tissue_env.episodes import run_episode, scripted_policy

    env = gym.make(ENV_ID)
    scripted = [run_episode(env, scripted_policy, seed) for seed in range(10)]
    assert sum(info["is_success"] for _, _, info in scripted) >= 9
    assert all(info["vessel_damage"] == 0 and info["cut_progress"] >= 0.9 for _, _, info in scripted)


def test_the_approach_reward_is_the_route_shortening():
    """The approach term (potential-based, ``tissue_env.cut_tasks``) is the route's shortening per cm at
    every step; the scripted incision only shortens it, in all by 5.1-5.4 cm on seeds 0-2 (the docstring's)."""
    assert 5.0 < assert_approach_is_the_route_shortening(ENV_ID, {}, 0) < 5.5


def test_the_cut_follows_the_blade_and_opens_under_tension():
    """Every face the scripted blade cuts lies within half an element of the surface it swept, the
    cut length is the blade's travel through the tissue, and the two lips of the incision move apart
    (the slab is stretched across the line) while no element degenerates."""
    env, infos = open_cut()
    cutting_steps = [info for info in infos if info["faces_cut"] > 0]
    assert len(cutting_steps) >= 3
    assert max(info["cut_deviation"] for info in cutting_steps) <= 0.5 * ELEMENT
    assert infos[-1]["cut_length"] == pytest.approx(env.unwrapped.max_step * len(cutting_steps))
    worlds = env.unwrapped.worlds
    model = worlds.stack.given[0]
    block = env.unwrapped.mesh.n_nodes
    copies = np.arange(block, model.n_nodes)
    origin = worlds.node_origin[0, copies]
    positions = env.unwrapped.state.positions
    for _ in range(5):
        env.step(np.zeros(3, np.float32))  # the blade held still: the incision settles open
    opened = env.unwrapped.state.positions
    gap = np.abs(opened[copies, 2] - opened[origin, 2])
    assert gap.max() > 1e-4 and np.abs(positions[copies, 2] - positions[origin, 2]).max() < gap.max()
    assert 0.5 < infos[-1]["element_quality"] <= 1.5


def test_a_cut_adds_no_energy():
    """At a cut each copied node starts at its original's position and velocity: the kinetic energy
    is the same to rounding; over the cutting step the kinetic energy grows by at most the work the
    forces did (trapezoid rule on the cut model's internal forces and gravity)."""
    env, _ = open_cut(steps=15)
    worlds = env.unwrapped.worlds
    for _ in range(4):
        before = worlds.stack.given[0]
        state = copy.deepcopy(env.unwrapped.state)
        cuts = len(worlds.cuts[0])
        env.step(env.unwrapped.scripted_action())
        if len(worlds.cuts[0]) > cuts:
            break
    model = worlds.stack.given[0]
    rows = cutting.carried_nodes(before, model)  # the node of the model before the cut each node comes from
    assert model.n_nodes > before.n_nodes
    carried = copy.deepcopy(state)
    carried.positions, carried.velocities = state.positions[rows], state.velocities[rows]
    kinetic = 0.5 * np.sum(before.mass[:, None] * state.velocities ** 2)
    assert 0.5 * np.sum(model.mass[:, None] * carried.velocities ** 2) == pytest.approx(kinetic, rel=1e-12, abs=1e-18)
    after = env.unwrapped.state
    work = 0.0
    for positions, velocities in ((carried.positions, carried.velocities), (after.positions, after.velocities)):
        forces = internal_forces(model, positions, velocities) + model.gravity_force.reshape(-1, 3)
        work += 0.5 * np.sum(forces * (after.positions - carried.positions))
    kinetic_after = 0.5 * np.sum(model.mass[:, None] * after.velocities ** 2)
    assert kinetic_after <= kinetic + work + 1e-9 * abs(work) + 1e-15


def test_a_vector_copy_equals_the_single_env_through_cuts():
    """Copy 0 of a two-copy vector env, given the single env's scripted actions while copy 1 cuts
    elsewhere, takes the single env's steps (observations within 1e-9, the same rewards and cuts)."""
    assert_vector_copy_equals_single(ENV_ID, SMALL, 22, [0.6, -1.0, 0.3])


def test_reset_restores_the_uncut_tissue():
    """After an episode of cuts, a reset gives the uncut slab back: the world holds the block's model
    again and the next episode is, bit for bit, a fresh env's."""
    env, _ = open_cut(seed=2)
    assert_reset_restores_the_uncut_tissue(env, ENV_ID, SMALL, 25)


def test_snapshots_copies_and_pickles_hold_the_cut():
    """Taken with the world cut, a snapshot (under 2 MB pickled: it holds the faces cut and the cut
    world's solver state, not its model; restored on the env and on a fresh one, also pickled), a
    deepcopy and a pickle of the env take the original's next steps bit for bit, cuts included."""
    env, _ = open_cut(seed=1, steps=16)
    assert_snapshots_hold_the_cut(env.unwrapped, ENV_ID, SMALL, max_bytes=2_000_000)  # issue 43's floor


@pytest.mark.parametrize("keyword, value", [("target_depth", 0.03), ("tension", 0.7), ("line_length", 0.06),
                                            ("spare_nodes", -1), ("success_fraction", 1.5)])
def test_bad_keywords_name_what_is_wrong(keyword, value):
    with pytest.raises(ValueError, match=keyword):
        gym.make(ENV_ID, **{keyword: value})


def test_random_blades_give_finite_steps_and_refuse_cuts_beyond_the_spare_rows():
    """300 random steps (a few cuts: the blade starts above the tissue) and 60 steps of a blade plunged
    and then driven about at random on the small slab (it cuts most steps, until the copies fill the world's
    spare node rows: the cuts beyond are refused, ``info["cut_refused"]``): every observation and
    reward finite, no divergence."""
    cutting, refused = assert_random_blades_are_finite(
        ENV_ID, SMALL, 3, 60, [[0.0, -1.0, 0.0]] * 6, lambda rng: rng.choice([-1.0, 1.0], 3) * [1.0, 0.0, 1.0])
    assert cutting >= 3 and refused >= 1
