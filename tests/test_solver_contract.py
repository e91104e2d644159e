"""One solver contract for one world and N (``sim_core.make_solver``): a ``ModelStack``'s worlds step
as the one-world solver steps each of them, external forces included, and a world whose model changed
topology (elements removed, nodes duplicated into the stack's spare rows: a cut) steps as the
one-world solver on that model. The reference is the one-world solver, run to a relative residual of
1e-10; the tolerance proved is 1e-6 of the largest motion."""

import numpy as np
import pytest

from sim_core import HexMesh, Material, ModelStack, State, StepReport, TetMesh, build_model, make_solver

#: method: (dt s, steps, options): a few steps of each, the linear and Newton solves converged tightly
METHODS = {"explicit": (1e-4, 30, {}), "implicit": (0.01, 4, dict(tolerance=1e-10)),
           # 80 Newton iterations per increment: the cut tetrahedral beam's smoothed strain sags 2.7x as far as
           # each tetrahedron's own strain did (a quarter of its length), beyond QuasiStatic's default 20
           "static": (0.01, 2, dict(tolerance=1e-10, max_iterations=80))}
MATERIALS = (Material(20e3, 0.45, 1060), Material(30e3, 0.3, 1000), Material(15e3, 0.4, 1100))


def _cantilever(mesh):
    """Face x = 0 clamped: (nodes, their positions)."""
    left = np.flatnonzero(mesh.nodes[:, 0] == 0)
    return left, mesh.nodes[left]


def _run(solver, state, control, dt, steps):
    for _ in range(steps):
        out = State(state.positions, state.velocities, state.time)
        report = solver.step(state, out, control, dt)
        state = out
    return state, report


def _one_world(method, model, fixed, target, force):
    dt, steps, options = METHODS[method]
    control = model.new_control()
    control.fixed[:], control.target[:], control.force[:] = fixed, target, force
    state, report = _run(make_solver(method, model, **options), model.new_state(), control, dt, steps)
    assert not report.unstable, report.unstable_reason
    return state.positions


@pytest.mark.parametrize("name", ["baudet", "baudet-hyperelastic"])
@pytest.mark.parametrize("method", list(METHODS))
def test_three_worlds_with_a_force_on_one_step_as_one_world_each(method, name):
    mesh = HexMesh.block((4, 2, 2), 0.01)
    models = [build_model(mesh, material, model=name, gravity=(0, -9.81, 0)) for material in MATERIALS]
    stack = ModelStack(models[0], 3)
    for index, model in enumerate(models):
        stack.assign(index, model)
    dt, steps, options = METHODS[method]
    control = stack.new_control()
    left, clamp = _cantilever(mesh)
    control.fixed[:, left], control.target[:, left] = True, clamp
    tip = mesh.nodes[:, 0] == mesh.nodes[:, 0].max()
    control.force[1, tip] = (0.0, -4e-3, 1e-3)  # N per tip node, on world 1 only
    state, report = _run(make_solver(method, stack, **options), stack.new_state(), control, dt, steps)
    assert isinstance(report, StepReport) and report.iterations.shape == (3,) and not report.unstable.any()
    for index, model in enumerate(models):
        reference = _one_world(method, model, control.fixed[index], control.target[index], control.force[index])
        motion = np.abs(reference - mesh.nodes).max()
        assert np.abs(state.positions[index] - reference).max() <= 1e-6 * motion, (method, name, index)
    unforced = _one_world(method, models[1], control.fixed[1], control.target[1], 0.0)
    # the force moves world 1 (a solver that dropped it would fail the comparison above)
    assert np.abs(unforced - state.positions[1]).max() > 0.05 * np.abs(unforced - mesh.nodes).max()


def _cut(mesh, plane_x, removed):
    """``mesh`` cut from its top down to the node row below along the plane x = plane_x (the elements
    beyond the plane get copies, appended, of the top nodes on it) with element ``removed`` taken out."""
    nodes, elements = mesh.nodes, mesh.elements.copy()
    on = np.flatnonzero(np.isclose(nodes[:, 0], plane_x) & np.isclose(nodes[:, 1], nodes[:, 1].max()))
    beyond = nodes[elements].mean(axis=1)[:, 0] > plane_x
    copies = np.full(len(nodes), -1)
    copies[on] = len(nodes) + np.arange(len(on))
    moved = beyond[:, None] & (copies[elements] >= 0)
    elements[moved] = copies[elements][moved]
    keep = np.arange(len(elements)) != removed
    return type(mesh)(np.concatenate([nodes, nodes[on]]), elements[keep]), len(on)


CUT_CASES = [("hex", "baudet", "explicit"), ("hex", "baudet", "implicit"),
             ("hex", "baudet-hyperelastic", "implicit"), ("tet", "baudet", "implicit"),
             ("tet", "baudet", "static"), ("tet", "baudet-hyperelastic", "static"),
             ("tet", "baudet-hyperelastic", "explicit")]


@pytest.mark.parametrize("element, name, method", CUT_CASES)
def test_a_world_that_changed_topology_steps_as_one_world_on_its_model(element, name, method):
    block = HexMesh.block((4, 2, 2), 0.01)
    mesh = block if element == "hex" else TetMesh.from_hex(block)
    cut, added = _cut(mesh, 0.02, removed=1 if element == "hex" else 6)
    material = Material(20e3, 0.45, 1060)
    whole = build_model(mesh, material, model=name, gravity=(0, -9.81, 0))
    changed = build_model(cut, material, model=name, gravity=(0, -9.81, 0))
    stack = ModelStack(whole, 3, spare_nodes=added + 2)
    stack.assign(1, changed)
    assert stack.shared.tolist() == [True, False, True] and stack.n_nodes == mesh.n_nodes + added + 2
    dt, steps, options = METHODS[method]
    control = stack.new_control()
    left, clamp = _cantilever(mesh)
    control.fixed[:, left], control.target[:, left] = True, clamp
    solver = make_solver(method, stack, **options)
    state, report = _run(solver, stack.new_state(), control, dt, steps)
    assert not report.unstable.any(), report.unstable_reason
    n = changed.n_nodes
    reference = _one_world(method, changed, control.fixed[1, :n], control.target[1, :n], 0.0)
    motion = np.abs(reference - cut.nodes).max()
    assert np.abs(state.positions[1, :n] - reference).max() <= 1e-6 * motion
    # the spare rows the cut did not use stay parked, and the uncut worlds step as the whole model
    np.testing.assert_array_equal(state.positions[1, n:], stack.new_state().positions[1, n:])
    whole_reference = _one_world(method, whole, control.fixed[0, :mesh.n_nodes], control.target[0, :mesh.n_nodes], 0.0)
    assert np.abs(state.positions[0, :mesh.n_nodes] - whole_reference).max() <= 1e-6 * motion
    # the cut changes the motion (a world stepped as the uncut block would fail the first comparison)
    assert np.abs(state.positions[1, :mesh.n_nodes] - state.positions[0, :mesh.n_nodes]).max() > 0.02 * motion

    # back to the block's topology (an episode reset): world 1 rejoins the stacked arrays
    stack.assign(1, whole)
    solver.model_changed(1)
    again, _ = _run(solver, stack.new_state(), control, dt, steps)
    assert stack.shared.all()
    assert np.abs(again.positions[1] - again.positions[0]).max() <= 1e-6 * motion


def test_stack_rejects_a_model_beyond_its_rows_and_bad_solver_input():
    mesh = HexMesh.block((2, 1, 1), 0.01)
    model = build_model(mesh, Material(20e3, 0.45, 1060))
    cut, added = _cut(mesh, 0.01, removed=-1)
    stack = ModelStack(model, 2, spare_nodes=added - 1)
    with pytest.raises(ValueError, match="spare_nodes"):
        stack.assign(0, build_model(cut, Material(20e3, 0.45, 1060)))
    with pytest.raises(ValueError, match="count"):
        ModelStack(model, 0)
    with pytest.raises(ValueError, match="method"):
        make_solver("verlet", stack)
    with pytest.raises(ValueError, match="ModelStack"):
        make_solver("implicit", mesh)
    solver = make_solver("implicit", stack)
    state = model.new_state()  # one world's arrays given to an N-world solver
    with pytest.raises(ValueError, match="shape"):
        solver.step(state, state, model.new_control(), 0.01)
    with pytest.raises(ValueError, match="world mask"):
        solver.reset(np.ones(3, dtype=bool))


def test_a_node_of_no_element_is_a_clear_error():
    mesh = HexMesh.block((2, 1, 1), 0.01)
    lonely = HexMesh(np.concatenate([mesh.nodes, [[0.5, 0.5, 0.5]]]), mesh.elements)
    with pytest.raises(ValueError, match="belong to no element"):
        build_model(lonely, Material(20e3, 0.45, 1060))


def test_reset_starts_worlds_again_as_fresh_solvers():
    """After ``reset`` a solver steps as a fresh one (warm starts, kept factors and divergence history
    start again), for one world and for a world mask of N."""
    mesh = HexMesh.block((3, 2, 2), 0.01)
    model = build_model(mesh, Material(20e3, 0.45, 1060), gravity=(0, -9.81, 0))
    left, clamp = _cantilever(mesh)
    one_control = model.new_control().impose(left, clamp)
    stack = ModelStack(model, 2)
    control = stack.new_control()
    control.fixed[:, left], control.target[:, left] = True, clamp
    for target, start, ctrl in ((model, model.new_state(), one_control), (stack, stack.new_state(), control)):
        solver = make_solver("implicit", target, tolerance=1e-4)
        first, _ = _run(solver, start, ctrl, 0.02, 3)
        solver.reset()
        again, _ = _run(solver, start, ctrl, 0.02, 3)
        np.testing.assert_array_equal(again.positions, first.positions)


@pytest.mark.parametrize("preconditioner", ["jacobi", "auto", "factorised", "reference"])
def test_a_pickled_or_copied_solver_steps_as_the_original(preconditioner):
    """A pickled and a deep-copied N-world implicit solver, mid-run, continue bit for bit as the
    original (the Jacobi worlds' preconditioners are rows of an array the step rewrites: a copy must
    read its own)."""
    import copy
    import pickle

    mesh = HexMesh.block((3, 2, 2), 0.01)
    model = build_model(mesh, Material(20e3, 0.45, 1060), gravity=(0, -9.81, 0))
    left, clamp = _cantilever(mesh)
    stack = ModelStack(model, 2)
    control = stack.new_control()
    control.fixed[:, left], control.target[:, left] = True, clamp
    solver = make_solver("implicit", stack, tolerance=1e-10, preconditioner=preconditioner, threads=1)
    state, _ = _run(solver, stack.new_state(), control, 0.02, 3)
    twins = [pickle.loads(pickle.dumps(solver)), copy.deepcopy(solver)]
    expected, report = _run(solver, state, control, 0.02, 3)
    assert np.all(report.iterations > 0)
    for twin in twins:
        again, _ = _run(twin, State(state.positions.copy(), state.velocities.copy(), state.time), control, 0.02, 3)
        np.testing.assert_array_equal(again.positions, expected.positions)


@pytest.mark.parametrize("element, name, options", [
    ("hex", "baudet", dict(hourglass_control=0.5, damping_ratio=0.3)), ("hex", "baudet-original", dict(nu_factor=True)),
    ("hex", "baudet-hyperelastic", dict(springs="isotropic")), ("hex", "uniform-springs", {}),
    ("tet", "baudet", {}), ("tet", "baudet-hyperelastic", dict(corrections=False))])
def test_a_model_rebuilds_from_its_options(element, name, options):
    """``Model.options`` are the keywords that build it again: what a changed mesh (a cut) is rebuilt
    with. Every array of the rebuilt model equals the original's."""
    mesh = HexMesh.block((2, 2, 1), 0.01)
    mesh = mesh if element == "hex" else TetMesh.from_hex(mesh)
    material = Material(np.linspace(5e3, 2e4, mesh.n_elements), 0.45, 1060)
    model = build_model(mesh, material, model=name, gravity=(0, -9.81, 0), **options)
    again = build_model(mesh, material, model=model.name, gravity=model.gravity, **model.options)
    for field in ("mass", "springs", "stiffness", "damping", "rest_length", "edge_spring", "correction_matrix",
                  "volume_stiffness", "gravity_force"):
        np.testing.assert_array_equal(getattr(again, field), getattr(model, field), err_msg=field)
    assert again.options == model.options and again.correction_mode == model.correction_mode
