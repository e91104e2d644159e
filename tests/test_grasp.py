"""The grasper of sim_core.solvers.grasp: its force against solve_static with the same nodes imposed,
one world and N, and its slip at the force limit."""

import numpy as np
import pytest

from benchmarks.grasp import SPACING, grasped_block, net_forces
from sim_core import Control, ModelStack, State, make_solver, solve_static
from sim_core.solvers.grasp import Grasper


@pytest.fixture(scope="module")
def block():
    """(model, base control, start positions, top-face mask, the top face's centre): ``grasped_block``."""
    return grasped_block()


def pull(solver, grasper, base, state, held, offsets, jaw_start, lifts, settle, slip=None):
    """Raise the jaws from ``jaw_start`` ((3,) or (N, 3)) by ``lifts`` (m, one per world) in ramp
    steps, then hold ``settle`` steps; ``slip(state, held) -> held`` after each step. Returns the
    final state, held nodes and control."""
    out = state.copy()
    lifts = np.asarray(lifts, dtype=float)
    ramp = 10
    for step in range(ramp + settle):
        jaw = jaw_start + np.multiply.outer(lifts * min(step + 1, ramp) / ramp, [0.0, 1.0, 0.0])
        fixed, target = grasper.control(base.fixed, base.target, held, offsets, jaw)
        control = Control(fixed, target, np.zeros_like(target))
        solver.step(state, out, control, 0.02)
        state, out = out, state
        if slip is not None:
            held = slip(state, held)
    return state, held, control


def test_a_grasped_patch_pulled_quasi_statically_gives_the_static_reaction(block):
    """One world and two (a ModelStack, pulled by different heights): the grasp force after a slow
    pull and a hold equals the reaction of solve_static with the held nodes imposed at the same
    places, within 1% (the floor; measured: 1e-9)."""
    model, base, start, top, centre = block
    grasper = Grasper(1.01 * SPACING)
    held, offsets = grasper.close(start, centre, top)
    assert held.sum() == 5  # the centre node and its four neighbours on the top face
    state, _, control = pull(make_solver("implicit", model), grasper, base, State(start.copy(), np.zeros_like(start)),
                             held, offsets, centre, 0.002, settle=40)
    force = grasper.force(net_forces(model, state.positions, state.velocities), held)
    reference = solve_static(model, control, initial=start)
    expected = reference.reaction[held].sum(axis=0)
    assert reference.converged and expected[1] > 0.05  # a real pull up
    assert np.linalg.norm(force - expected) <= 0.01 * np.linalg.norm(expected)

    # N worlds: the same grasp closed on stacked positions, each world its own lift
    stack = ModelStack(model, 2)
    positions = np.stack([start, start])
    jaws = np.stack([centre, centre])
    held_n, offsets_n = grasper.close(positions, jaws, top)
    np.testing.assert_array_equal(held_n, [held, held])
    lifts = np.array([0.001, 0.002])
    base_n = Control(np.stack([base.fixed] * 2), np.stack([base.target] * 2), np.zeros_like(positions))
    state_n, _, control_n = pull(make_solver("implicit", stack), grasper, base_n,
                                 State(positions.copy(), np.zeros_like(positions)), held_n, offsets_n, jaws, lifts,
                                 settle=40)
    measured = []
    for world in range(2):
        forces = net_forces(model, state_n.positions[world], state_n.velocities[world])
        measured.append(grasper.force(forces, held_n[world]))
        world_control = Control(control_n.fixed[world], control_n.target[world], np.zeros_like(start))
        expected = solve_static(model, world_control, initial=start).reaction[held].sum(axis=0)
        assert np.linalg.norm(measured[-1] - expected) <= 0.01 * np.linalg.norm(expected)
    assert 0.0 < measured[0][1] < measured[1][1]  # each world its own pull: the higher lift pulls harder


def test_slip_lets_the_most_loaded_nodes_go_first_until_the_force_is_within_the_limit():
    """Random nodal forces on two worlds with their own limits: the nodes left hold at most the
    limit, only held nodes slip, every node that slipped pulled at least as much along the grasp
    force as every node kept, and one node fewer slipped would leave the force above the limit."""
    rng = np.random.default_rng(0)
    forces = rng.normal(size=(2, 12, 3)) + [0.0, -1.0, 0.0]  # the tissue pulls the grasped nodes down
    held = rng.random((2, 12)) < 0.7
    limits = np.array([1.5, 4.0])
    grasper = Grasper(0.01, limits)
    total = grasper.force(forces, held)
    assert np.all(np.linalg.norm(total, axis=1) > limits)  # both worlds must slip
    kept = grasper.slip(forces, held)
    slipped = held & ~kept
    assert not np.any(kept & ~held) and np.all(slipped.sum(axis=1) >= 1)
    for world in range(2):
        node_forces = grasper.node_forces(forces[world], held[world])
        assert np.linalg.norm(node_forces[kept[world]].sum(axis=0)) <= limits[world]
        pulls = node_forces @ (total[world] / np.linalg.norm(total[world]))
        if kept[world].any():
            assert pulls[slipped[world]].min() >= pulls[kept[world]].max()
        last = np.flatnonzero(slipped[world])[np.argmin(pulls[slipped[world]])]  # the last to slip
        one_fewer = kept[world].copy()
        one_fewer[last] = True
        assert np.linalg.norm(node_forces[one_fewer].sum(axis=0)) > limits[world]
    # within the limit nothing slips
    np.testing.assert_array_equal(Grasper(0.01, 1e3).slip(forces, held), held)


def test_one_limit_per_world_applies_to_every_grasp_of_that_world():
    """Three worlds with two graspers each ((N, T, n) held nodes, the worlds' forces (N, 1, n, 3)) and
    one limit per world, one of them np.inf (a grasp that never slips): each grasp slips as a
    grasper with its world's scalar limit does, the unlimited world's not at all."""
    rng = np.random.default_rng(1)
    forces = rng.normal(size=(3, 1, 12, 3)) + [0.0, -1.0, 0.0]
    held = np.stack([rng.random((3, 12)) < 0.5 for _ in range(2)], axis=1)
    limits = np.array([1.0, np.inf, 2.5])
    kept = Grasper(0.01, limits).slip(forces, held)
    for world, limit in enumerate(limits):
        for tool in range(2):
            expected = Grasper(0.01, limit).slip(forces[world, 0], held[world, tool])
            np.testing.assert_array_equal(kept[world, tool], expected)
    np.testing.assert_array_equal(kept[1], held[1])
    assert np.any(kept[0] != held[0])


def test_pulling_past_the_limit_slips_node_by_node_and_never_holds_more_than_the_limit(block):
    """The patch pulled 1 cm up under a grasp limit of 0.25 N: nodes slip one or a few at a time over
    several steps (not all at once), the force on the nodes still held never passes the limit, and
    the grasp is lost; without a limit the same pull holds every node and passes 0.25 N."""
    model, base, start, top, centre = block
    records = {}
    for limit in (np.inf, 0.25):
        grasper = Grasper(1.01 * SPACING, limit)
        held, offsets = grasper.close(start, centre, top)
        history = []

        def slip(state, held):
            forces = net_forces(model, state.positions, state.velocities)
            held = grasper.slip(forces, held)
            history.append((held.sum(), np.linalg.norm(grasper.force(forces, held))))
            return held

        pull(make_solver("implicit", model), grasper, base, State(start.copy(), np.zeros_like(start)), held, offsets,
             centre, 0.01, settle=2, slip=slip)
        records[limit] = np.array(history)
    free, limited = records[np.inf], records[0.25]
    assert np.all(free[:, 0] == 5) and free[:, 1].max() > 0.25
    counts = limited[:, 0]
    assert np.all(np.diff(counts) <= 0) and counts[-1] == 0
    assert len(set(counts.tolist()) - {0, 5}) >= 2  # partly held over several steps: node by node
    assert np.all(limited[:, 1] <= 0.25)


@pytest.mark.parametrize("kwargs, message", [
    (dict(radius=0.0), "grasp radius"), (dict(radius=np.nan), "grasp radius"), (dict(radius="1"), "grasp radius"),
    (dict(radius=0.01, force_limit=-1.0), "force_limit"), (dict(radius=0.01, force_limit=np.nan), "force_limit"),
    (dict(radius=0.01, force_limit=[1.0, 0.0]), "force_limit"),
])
def test_bad_grasper_raises_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Grasper(**kwargs)


def test_bad_close_arguments_raise_value_error():
    grasper = Grasper(0.01)
    with pytest.raises(ValueError, match="jaw"):
        grasper.close(np.zeros((4, 3)), np.zeros(2))
    with pytest.raises(ValueError, match="positions"):
        grasper.close(np.zeros((4, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="candidates"):
        grasper.close(np.zeros((4, 3)), np.zeros(3), np.ones(3, bool))
