"""Palpation-v0: the stiffness sweep finds the inclusion; random probing rarely does."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the ids)
from sim_core.solvers import contact
from tissue_env.episodes import random_policy, run_episode, scripted_policy

ENV_ID = "tissue_env/Palpation-v0"


def tip_of(env):
    """The probe tip (3,) m: its start plus the tool offset (both public attributes)."""
    return env.probe_start + env.tool_offset


@pytest.fixture(scope="module")
def scripted_sweeps():
    """The default env's scripted sweep (``scripted_policy``) over seeds 0-19, played once for the
    two tests below: per episode (return, is_success, summed force penalty ``reward_force``)."""
    env = gym.make(ENV_ID)
    episodes = []
    for seed in range(20):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        total, penalty, done = 0.0, 0.0, False
        while not done:
            _, reward, terminated, truncated, info = env.step(scripted_policy(env))
            total += float(reward)
            penalty += info["reward_force"]
            done = terminated or truncated
        episodes.append((total, bool(info["is_success"]), penalty))
    env.close()
    return episodes


def test_scripted_sweep_succeeds_and_random_probing_rarely_does(scripted_sweeps):
    env = gym.make(ENV_ID)
    random = [run_episode(env, random_policy, seed) for seed in range(20)]
    scripted_rate = np.mean([success for _, success, _ in scripted_sweeps])
    random_rate = np.mean([info["is_success"] for _, _, info in random])
    assert scripted_rate >= 0.8
    assert random_rate <= 0.15  # measured 5 % (6 % over 100 seeds)
    assert np.mean([r for r, _, _ in scripted_sweeps]) > np.mean([r for r, _, _ in random])


def test_the_scripted_sweeps_presses_stay_near_the_force_limit(scripted_sweeps):
    """The default ``force_limit`` (2 N) is set for the default mesh, which resolves the stiff
    inclusion: over seeds 0-19 the scripted sweep (100% success) pays no force penalty (its presses
    peak at 0.51 N; -0.60 per episode when it ploughed to its final press, issue 42); with the 1 N limit set on the coarser (8, 4, 8) it paid
    -1.91 (at worst -4.93), and PPO fell from 85% to 30-35% at its budget (README)."""
    assert gym.make(ENV_ID).unwrapped.force_limit == 2.0
    assert all(success for _, success, _ in scripted_sweeps)
    penalties = [penalty for _, _, penalty in scripted_sweeps]
    assert np.mean(penalties) > -1.0 and min(penalties) > -2.5, np.round(penalties, 2)


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
        action = np.clip((target - tip_of(unwrapped)) / unwrapped.max_step, -1, 1).astype(np.float32)
        _, _, terminated, _, info = env.step(action)
        held.append(info["press_steps"])
        if terminated:
            break
    assert info["is_success"] and held[-3:] == [1, 2, 3]


def test_inclusion_is_stiffer_under_the_probe():
    """Pressing 4 mm over the inclusion (the scripted sweep's press, each cell's reading the
    ``apparent_modulus`` of the last step held there) needs more force than over the other cells."""
    env = gym.make(ENV_ID, max_episode_steps=400)
    env.reset(seed=0)
    unwrapped = env.unwrapped
    unwrapped.terminate_on_success = False
    cells = unwrapped.inclusion_cells
    centres, depth = unwrapped.cell_centres, unwrapped.top_y - 0.004  # the sweep's press depth
    stiffness = np.full(len(cells), np.nan)
    for _ in range(400):
        _, _, _, truncated, info = env.step(unwrapped.scripted_action())
        tip = tip_of(unwrapped)
        over = np.flatnonzero(np.all(np.abs(centres - tip[[0, 2]]) <= 1e-6, axis=1))
        if len(over) and tip[1] <= depth + 1e-6:  # pressed over a cell: the latest reading is what the sweep keeps
            stiffness[over[0]] = info["apparent_modulus"]
        elif np.all(np.isfinite(stiffness)) or truncated:  # every cell pressed and the probe gone on
            break
    assert np.all(np.isfinite(stiffness)), stiffness
    inclusion = int(np.flatnonzero((cells == unwrapped.inclusion_cell).all(axis=1))[0])
    assert np.argmax(stiffness) == inclusion and stiffness[inclusion] > 1.05 * np.median(stiffness)


@pytest.mark.parametrize("shape, drift", [(None, 0.25), ((8, 4, 8), 0.15)])
def test_palpation_map_records_the_latest_press_and_rewards_the_first_once(shape, drift):
    env = gym.make("tissue_env/Palpation-v0", **({} if shape is None else dict(shape=shape)))
    env.reset(seed=3)
    unwrapped = env.unwrapped
    centre = unwrapped.cell_centres[0]
    n_cells = len(unwrapped.cell_centres)

    def go(goal, steps=12):
        infos = []
        for _ in range(steps):
            tip = tip_of(unwrapped)
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
    assert explore == [0, 0.5, 0, 0]  # 6 mm in two steps: once, on the first step 4 mm deep
    assert np.count_nonzero(unwrapped.palpation_map) == 1
    # the cell holds the latest reading: the apparent modulus (Pa) of the press held still
    assert unwrapped.palpation_map[0] == infos[-1]["apparent_modulus"] > 0
    # observed relative to the tissue's apparent modulus E* = E / (1 - nu^2)
    tissue = infos[-1]["young_modulus"] / (1.0 - infos[-1]["poisson_ratio"] ** 2)
    np.testing.assert_allclose(obs[15:15 + n_cells], unwrapped.palpation_map / tissue, rtol=1e-6)
    np.testing.assert_allclose(obs[15 + n_cells:17 + n_cells], 0.0, atol=1e-5)  # stiffest = here
    # pressing deeper on the same cell does not reward again; its depth-normalised reading moves
    # by less than ``drift`` (F / d rises by 1.5x from 4 to 8 mm): measured +19% at the default
    # (10, 5, 10) (bound 25%), +12% at (8, 4, 8) (bound 15%); finer meshes stiffen the 8 mm press
    # (0.9 probe radii, a quarter of the slab: no longer Hertz's half-space) more: +43% at
    # (12, 6, 12), +53% at (14, 7, 14)
    held = unwrapped.palpation_map[0]
    _, infos = go(np.array([centre[0], surface - 0.008, centre[1]]), steps=3)
    assert all(info["reward_explore"] == 0 for info in infos)
    assert unwrapped.palpation_map[0] == infos[-1]["apparent_modulus"]
    assert abs(unwrapped.palpation_map[0] / held - 1) < drift, (unwrapped.palpation_map[0], held)
    # the offset to the nearest unprobed cell points to a neighbour one cell pitch away (cm)
    pitch = unwrapped.cell_size[0] / unwrapped.length_scale
    np.testing.assert_allclose(np.hypot(*obs[17 + n_cells:19 + n_cells]), pitch, rtol=1e-5)


def stiff_box(env):
    """Stiff volume (m^3: the elements' volumes weighted by their share of the inclusion's extra
    stiffness) and its centre (m) of an env's model."""
    unwrapped = env.unwrapped
    model, mesh = unwrapped.model, unwrapped.mesh
    share = (model.young_modulus / unwrapped.young_modulus - 1.0) / (unwrapped.episode_inclusion_ratio - 1.0)
    volume = mesh.element_volumes() * share
    return volume.sum(), volume @ mesh.nodes[mesh.elements].mean(axis=1) / volume.sum()


#: these shapes mesh the 6 x 3 x 6 cm block with boxes, which "baudet" refuses (its shear modulus is
#: exact for cubes only: tests/test_box_elements.py); the geometry checked here is the model's input
BOX_MODEL = dict(model="baudet-hyperelastic")


@pytest.mark.parametrize("shape", [(5, 3, 5), (8, 4, 8), (10, 6, 10), (7, 5, 9)])
def test_shape_only_sets_the_resolution_of_the_inclusion(shape):
    """At every shape the inclusion stiffens exactly the 1.2 x 1 x 1.2 cm box (each element by its
    volume share in it), at the same candidate centres (x, z in 1.8, 3.0, 4.2 cm, y = 1.5 cm): one
    element at (5, 3, 5), parts of 8 at (8, 4, 8) wherever the nodes fall."""
    env = gym.make(ENV_ID, shape=shape, **BOX_MODEL)
    unwrapped = env.unwrapped
    expected = [[x, 0.015, z] for x in (0.018, 0.030, 0.042) for z in (0.018, 0.030, 0.042)]
    np.testing.assert_allclose(unwrapped.inclusion_centres, expected, atol=1e-12)
    assert env.observation_space == gym.make(ENV_ID, shape=(5, 3, 5), **BOX_MODEL).observation_space  # same map cells
    volumes = unwrapped.inclusion_shares @ unwrapped.mesh.element_volumes()
    np.testing.assert_allclose(volumes, 0.012 * 0.01 * 0.012, rtol=1e-9)
    centres = (unwrapped.inclusion_shares * unwrapped.mesh.element_volumes()) @ unwrapped.mesh.nodes[
        unwrapped.mesh.elements].mean(axis=1) / volumes[:, None]
    if shape == (5, 3, 5):  # the box is one element
        assert np.all(unwrapped.inclusion_elements.sum(axis=1) == 1)
        np.testing.assert_allclose(centres, expected, atol=1e-12)
    # an episode's inclusion stiffens its candidate box, by the share of each element in it
    for seed in (1, 2):
        env.reset(seed=seed)
        volume, centre = stiff_box(env)
        assert np.isclose(volume, 0.012 * 0.01 * 0.012, rtol=1e-9)
        stiff = unwrapped.model.young_modulus > unwrapped.young_modulus
        assert np.array_equal(stiff, unwrapped.inclusion_elements[unwrapped.inclusion_index])


def rest_contact(unwrapped, offset):
    """(held top nodes, their imposed heights (n,) m) of the env's probe pressed at ``offset`` (m)
    from its start on the rest mesh: the contact set and heights its control forms
    (``sim_core.solvers.contact.update`` and ``targets``, from no contact and no force)."""
    nodes = unwrapped.mesh.nodes
    tip = unwrapped.probe_start + offset
    candidates = np.zeros(unwrapped.mesh.n_nodes, bool)
    candidates[unwrapped.top_nodes] = True
    held = contact.update(unwrapped.probe, np.zeros(unwrapped.mesh.n_nodes, bool), nodes, np.zeros_like(nodes),
                          candidates, tip)
    return np.flatnonzero(held), contact.targets(unwrapped.probe, nodes, held, tip)


@pytest.mark.parametrize("shape, count", [((5, 3, 5), 4), ((10, 6, 10), 9)])
def test_flat_probe_radius_is_9_mm_whatever_the_shape(shape, count):
    """The flat probe pressing 2 mm at the slab centre holds the top nodes within 9 mm of its axis:
    4 on the 12 mm grid of (5, 3, 5), 9 on the 6 mm grid of (10, 6, 10) (a radius of 0.75 element,
    4.5 mm, would hold only the centre node there). Sampled at the nodes; projected, the nodes whose
    faces meet the probe hold too."""
    unwrapped = gym.make(ENV_ID, shape=shape, probe_tip="flat", probe_sampling="node", **BOX_MODEL).unwrapped
    assert unwrapped.probe_radius == 0.009
    held, target = rest_contact(unwrapped, np.array([0.0, -unwrapped.clearance - 0.002, 0.0]))
    contact = unwrapped.mesh.nodes[held]
    distance = np.hypot(contact[:, 0] - 0.03, contact[:, 2] - 0.03)
    assert len(contact) == count and np.all(distance <= 0.009) and np.all(contact[:, 1] == unwrapped.top_y)
    top = unwrapped.mesh.nodes[unwrapped.top_nodes]
    assert np.count_nonzero(np.hypot(top[:, 0] - 0.03, top[:, 2] - 0.03) <= 0.009) == count
    assert np.allclose(target[held], unwrapped.top_y - 0.002)


@pytest.mark.parametrize("shape, count", [((5, 3, 5), 4), ((10, 6, 10), 5), ((12, 6, 12), 9)])
def test_sphere_probe_holds_the_nodes_under_its_surface_at_its_height(shape, count):
    """The default sphere-ended probe (radius 9 mm) pressed 5 mm at the slab centre holds exactly the
    top nodes its surface reaches, r <= sqrt(R^2 - (R - 5 mm)^2) = 8.06 mm from its axis, each at
    the sphere's height over it (4 nodes at 8.49 mm are out of reach at (5, 3, 5) until 6 mm deep).
    Sampled at the nodes (the default projects the probe: test_contact.py)."""
    unwrapped = gym.make(ENV_ID, shape=shape, probe_sampling="node", **BOX_MODEL).unwrapped
    assert unwrapped.probe_tip == "sphere"
    depth = 0.005 if shape != (5, 3, 5) else 0.0065
    held, target = rest_contact(unwrapped, np.array([0.0, -unwrapped.clearance - depth, 0.0]))
    top = unwrapped.mesh.nodes[unwrapped.top_nodes]
    r = np.hypot(top[:, 0] - 0.03, top[:, 2] - 0.03)
    reached = 0.009 - np.sqrt(np.maximum(0.009**2 - r**2, 0.0)) <= depth
    assert np.array_equal(np.sort(held), np.sort(unwrapped.top_nodes[reached & (r <= 0.009)]))
    assert len(held) == count
    nodes = unwrapped.mesh.nodes[held]
    height = unwrapped.top_y - depth + 0.009 - np.sqrt(0.009**2 - np.hypot(nodes[:, 0] - 0.03, nodes[:, 2] - 0.03)**2)
    np.testing.assert_allclose(target[held], height, atol=1e-12)


def test_held_press_settles_on_the_static_contact_equilibrium():
    """Pressed 5 mm over a corner cell and held, the probe's force and the tissue settle on the
    frictionless-contact equilibrium that the static active set (sim_core.studies.solving) finds for
    the same probe (measured: within 1e-6 N after 40 steps; the contact set held within one step)."""
    from sim_core.studies.solving import model_solver, solve_with_contact

    env = gym.make(ENV_ID, max_episode_steps=400).unwrapped
    env.terminate_on_success = False
    env.reset(seed=3)
    goal = np.array([0.018, env.top_y - 0.005, 0.018])
    forces = []
    for step in range(60):
        target = goal if step >= 10 else np.array([goal[0], env.top_y, goal[2]])
        env.step(np.clip((target - tip_of(env)) / env.max_step, -1, 1).astype(np.float32))
        forces.append(env.measures["reaction_force"][1])
    assert abs(forces[-1] - forces[-2]) < 1e-6  # settled, no oscillation
    solve, _ = model_solver(env.model)
    candidates = np.zeros(env.mesh.n_nodes, bool)
    candidates[env.top_nodes] = True
    positions, reaction, converged, _, _, contact = solve_with_contact(
        solve, env.base_control.copy(), env.state.positions, env.probe, candidates, tip_of(env))
    assert converged and np.array_equal(contact, env.contact)
    assert abs(reaction[contact, 1].sum() - forces[-1]) < 1e-4 * abs(forces[-1])
    assert np.abs(positions - env.state.positions).max() < 1e-6


@pytest.mark.parametrize("kwargs, words", [
    (dict(probe_tip="cone"), ("probe_tip", "sphere", "flat")),
    (dict(probe_sampling="mortar"), ("probe_sampling", "projected", "node")),
    (dict(inclusion_size=-0.01), ("inclusion_size",)),
    (dict(inclusion_size=(0.012, 0.012)), ("inclusion_size",)),
    (dict(inclusion_size=(0.012, 0.0, 0.012)), ("inclusion_size",)),
    (dict(inclusion_size="big"), ("inclusion_size",)),
    (dict(probe_radius=0.0), ("probe_radius",)),
    (dict(probe_radius=-0.009), ("probe_radius",)),
])
def test_invalid_inclusion_size_or_probe_radius_names_the_keyword(kwargs, words):
    with pytest.raises(ValueError) as error:
        gym.make(ENV_ID, **kwargs)
    assert all(word in str(error.value) for word in words), str(error.value)


def held_reading(env, x, z, seed):
    """Apparent modulus (Pa) of a press at (x, z) m straight down at full speed to 6 mm, held 2
    steps (what the palpation map then holds), from a reset with ``seed``."""
    env.reset(seed=seed)
    for _ in range(20):  # over (x, z), above the surface (no contact: the start equilibrium stays)
        move = (np.array([x, 0.0, z]) - tip_of(env) * [1, 0, 1]) / env.max_step
        if np.abs(move).max() < 1e-9:
            break
        env.step(np.clip(move, -1, 1).astype(np.float32))
    for action in ([0, -1, 0], [0, -1, 0], [0, 0, 0], [0, 0, 0]):
        _, _, _, _, info = env.step(np.array(action, np.float32))
    return info["apparent_modulus"]


@pytest.mark.parametrize("sampling, shape, low, high", [("projected", None, 1.0, 1.2), ("projected", (8, 4, 8), 1.0, 1.2),
                                                        ("node", (8, 4, 8), 1.3, np.inf)])
def test_the_same_tissue_reads_alike_wherever_the_nodes_fall_under_the_probe(sampling, shape, low, high):
    """Homogeneous slab, held presses on a 3 x 3 grid over one node period p at the centre (offsets
    0, p / 3, 2 p / 3 along x and 0, p / 2, 0.73 p along z): with the projected probe the readings'
    max/min is below 1.2 at the default (10, 5, 10) (measured 1.13, p = 6 mm) and at (8, 4, 8)
    (1.10, p = 7.5 mm; 1.11 on the map's 4 x 4 grid); sampled at the nodes, (8, 4, 8) reads 1.3 or
    more (1.34, and 2.05 for the first step of a press, which is why the map keeps the latest
    reading). At (10, 5, 10) the node sampling reads 1.09: 6 mm elements under a 9 mm probe
    average the nodes well enough."""
    kwargs = {} if shape is None else dict(shape=shape)
    env = gym.make(ENV_ID, inclusion_ratio=1.0, probe_sampling=sampling, max_episode_steps=400, **kwargs).unwrapped
    centre, period = env.centre, env.spacing[0]
    readings = [held_reading(env, centre[0] + a, centre[2] + b, 0) for a in (0.0, period / 3, 2 * period / 3)
                for b in (0.0, period / 2, 0.73 * period)]
    assert min(readings) > 0
    assert low <= max(readings) / min(readings) < high, readings


def test_a_held_press_over_the_inclusion_reads_stiffest_in_every_placement():
    """The inclusion in each of the 9 candidate cells in turn, a held press over every cell centre:
    the inclusion's cell reads at least 1.1x the stiffest other cell in all 9 placements (measured
    at the default (10, 5, 10): 1.24-1.29, and 1.27-1.35 sampled at the nodes,
    benchmarks/palpation_map.py; at (8, 4, 8) 1.15-1.26, and 0.75-1.80 sampled at the nodes, below
    1 in 5 placements)."""
    env = gym.make(ENV_ID, max_episode_steps=400).unwrapped
    env.terminate_on_success = False
    centres = env.cell_centres
    ratios = []
    for cell in range(len(centres)):
        seed = next(s for s in range(1000) if env.reset(seed=s) and env.inclusion_index == cell)
        readings = np.array([held_reading(env, x, z, seed) for x, z in centres])
        ratios.append(readings[cell] / np.delete(readings, cell).max())
    assert min(ratios) >= 1.1, np.round(ratios, 3)


def test_a_press_at_nu_049_reads_its_equilibrium_after_one_held_step(young_modulus=1e5):
    """Pressed 4 mm in one step at full speed over the slab's centre and held one step, as the
    scripted sweep records, the homogeneous slab at nu 0.49 reads what the static contact
    equilibrium reads there (integrator="static"), and the press step holds the equilibrium's
    contact set. With the set formed once per step the press held all 21 top nodes the probe's
    bound passed (9 at equilibrium) and the held step read 1.7x the equilibrium at 100 kPa. The
    press rings (inertia; implicit Euler damps it over a few 40 ms steps): the first held step reads
    within 10% of the equilibrium and the fifth within 1% (measured +6.9% and +0.3% at 100 kPa,
    +3.9% and +0.3% at 10 kPa; before the cubes' bending took off the face diagonals' share, +1.4%
    and +0.3%: the first held step falls at another phase of the ringing)."""
    readings, sets, settled = {}, {}, {}
    for integrator in ("implicit", "static"):
        env = gym.make(ENV_ID, young_modulus=young_modulus, poisson_ratio=0.49, inclusion_ratio=1.0,
                       integrator=integrator, max_episode_steps=400).unwrapped
        env.reset(seed=0)
        centre = np.array([0.03, env.top_y, 0.03])
        for _ in range(20):  # over the centre, the tip on the undeformed surface
            move = (centre - tip_of(env)) / env.max_step
            if np.abs(move).max() < 1e-9:
                break
            env.step(np.clip(move, -1, 1).astype(np.float32))
        env.step(np.array([0, -1, 0], np.float32))  # 4 mm down in one step
        sets[integrator] = env.contact_nodes
        env.step(np.zeros(3, np.float32))
        readings[integrator] = env.measures["apparent_modulus"]
        for _ in range(4):
            env.step(np.zeros(3, np.float32))
        settled[integrator] = env.measures["apparent_modulus"]
        env.close()
    assert np.array_equal(sets["implicit"], sets["static"])
    assert readings["implicit"] == pytest.approx(readings["static"], rel=0.1)
    assert settled["implicit"] == pytest.approx(settled["static"], rel=0.01)


def test_scripted_sweep_succeeds_in_stiff_near_incompressible_tissue():
    """E = 100 kPa, nu 0.49: the scripted sweep finds the inclusion (0 of 3 seeds with one solve per
    step, whose first held readings put the centre cell above the inclusion's)."""
    env = gym.make(ENV_ID, young_modulus=1e5, poisson_ratio=0.49)
    env.reset(seed=100)
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
    assert info["is_success"]
