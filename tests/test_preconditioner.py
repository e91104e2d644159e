"""ImplicitEuler's preconditioners on one world: "jacobi", "factorised" (sparse factor of the system
matrix, kept across steps) and "auto" agree to the solver tolerance; the factorised one needs far
fewer iterations on a stiff block, keeps its factor through a contact (capacitance correction) and
re-factorises when a dof is released, dt changes or its solves slow down; bad names are rejected."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sim_core import HexMesh, Material, build_model, kernels
from sim_core.studies.bench import tumor_block
from sim_core.models.forces import ForceWorkspace
from sim_core.solvers.integrators import ImplicitEuler, make_integrator, run
from sim_core.solvers.preconditioners import FreeStructure


def stiff_scene(shape=(6, 6, 6)):
    """TumorPositioning's material on a 5 cm cube: E 5 kPa, nu 0.45, volume stiffness x100,
    hourglass control 1; bottom fixed, a top patch pressed down 1 mm per step (dt 40 ms)."""
    model, bottom, patch = tumor_block(shape, 0.01)
    nodes = model.mesh.nodes

    def control(step):
        c = model.new_control()
        c.impose(bottom, nodes[bottom])
        c.impose(patch, nodes[patch] + [0.0, -0.001 * step, 0.0005 * step])
        return c
    return model, control, patch


def trajectory(model, control, integrator, steps, dt=0.04):
    state = model.new_state()
    out = state.copy()
    positions, iterations = [], []
    for step in range(1, steps + 1):
        report = integrator.simulate(model, state, out, dt, control(step))
        assert not report.unstable
        state, out = out, state
        positions.append(state.positions.copy())
        iterations.append(report.iterations)
    return np.array(positions), np.array(iterations)


def test_assembled_matrix_is_the_matrix_free_operator():
    model, control, _ = stiff_scene((3, 3, 3))
    state = model.new_state()
    run(model, state, ImplicitEuler(), 0.04, 3, control(3))
    workspace = ForceWorkspace(model)
    workspace.compute(state.positions, state.velocities, geometric=True, volume_jacobian=True)
    vector = np.random.default_rng(0).standard_normal(3 * model.n_nodes)
    structure = FreeStructure(model, np.arange(3 * model.n_nodes))
    for scales in [(1.0, 0.04, 0.0016, 0.0016, 0.0016, 0.0016), (0.0, 0.0, 1.0, 1.0, 1.0, 1.0), (1.0, 0.1, 0.01, 0, 0, 0)]:
        data = np.empty(model.pattern.nnz)
        kernels.operator_matrix_data(workspace.operator_data, scales, model.spring_positions, model.element_positions,
                                     structure.hg_positions, model.pattern.diagonal_positions, data)
        product = np.empty_like(vector)
        kernels.apply_operator(workspace.operator_data, scales, np.ones_like(vector), vector, product)
        assert np.abs(model.pattern.matrix(data) @ vector - product).max() < 1e-12 * np.abs(product).max()


def test_factorised_agrees_with_jacobi_in_far_fewer_iterations():
    """Stiff block (nu 0.45, volume stiffness x100), 6^3 elements, tolerance 1e-8, dt 40 ms, 8
    steps pressing 8 mm: the Jacobi solves take more than 50 iterations (median), the factorised
    ones at most 8 and 8x fewer; positions agree within 1e-9 m (each solve's tolerance)."""
    model, control, _ = stiff_scene()
    options = dict(tolerance=1e-8, max_iterations=400)
    jacobi, jacobi_iterations = trajectory(model, control, ImplicitEuler(preconditioner="jacobi", **options), 8)
    integrator = ImplicitEuler(preconditioner="factorised", **options)
    factorised, factorised_iterations = trajectory(model, control, integrator, 8)
    assert np.abs(factorised - jacobi).max() < 1e-9
    assert np.median(jacobi_iterations) > 50
    assert np.median(factorised_iterations) <= 8
    assert np.median(jacobi_iterations) > 8 * np.median(factorised_iterations)
    assert factorised_iterations[0] <= 2  # the factor is exact at its own linearisation
    assert 1 <= integrator.factorisations <= 3


def test_auto_switches_on_stiff_blocks_only():
    model, control, _ = stiff_scene((4, 4, 4))
    jacobi, _ = trajectory(model, control, ImplicitEuler(preconditioner="jacobi", tolerance=1e-8), 4)
    auto = ImplicitEuler(tolerance=1e-8, preconditioner="auto")
    positions, iterations = trajectory(model, control, auto, 4)
    assert auto.factorisations == 1 and iterations[-1] <= 6
    assert np.abs(positions - jacobi).max() < 1e-8
    assert ImplicitEuler().preconditioner == "auto"  # the default
    # a soft block (1 m, E 10 kPa, nu 0.3, dt 10 ms: 5 Jacobi iterations) stays with Jacobi
    soft = build_model(HexMesh.block((4, 4, 4), 0.1), Material(1e4, 0.3, 1500.0), gravity=(0, -0.5, 0))
    fixed = soft.new_control()
    bottom = np.flatnonzero(soft.mesh.nodes[:, 1] == 0)
    fixed.impose(bottom, soft.mesh.nodes[bottom])
    auto = ImplicitEuler(preconditioner="auto")
    run(soft, soft.new_state(), auto, 0.01, 5, fixed)
    assert auto.factorisations == 0


def test_keeps_the_factor_for_more_imposed_dofs_and_refactorises_for_a_release_or_another_dt():
    """A contact that holds one more node keeps the factorisation (restricted exactly to the free
    dofs by a capacitance correction) and the step is solved to the tolerance in at most 8
    iterations; a dof released (free now, imposed at the factorisation) or another dt (another
    matrix) factorises again. Every step equals a tight Jacobi solve within 1e-7 m."""
    model, control, patch = stiff_scene((6, 6, 6))
    integrator = ImplicitEuler(preconditioner="factorised", tolerance=1e-6)
    state = model.new_state()
    for step in range(1, 4):  # same imposed dofs: one factorisation
        integrator.simulate(model, state, state.copy(), 0.04, control(step))
    assert integrator.factorisations == 1
    node = np.flatnonzero(~control(3).fixed.any(axis=1))[-1]
    held = control(3).impose([node], model.mesh.nodes[[node]])  # another set holds one more node
    released = control(3)
    released.fixed[patch[0]] = False  # the tool lets go of one node
    for changed, dt, factorisations in ((held, 0.04, 1), (released, 0.04, 2), (released, 0.02, 3)):
        out = state.copy()
        report = integrator.simulate(model, state, out, dt, changed)
        assert integrator.factorisations == factorisations and report.residual <= 1e-6 and report.iterations <= 8
        reference = state.copy()
        ImplicitEuler(preconditioner="jacobi", tolerance=1e-10, max_iterations=1000).simulate(
            model, state, reference, dt, changed)
        assert np.abs(out.positions - reference.positions).max() < 1e-7


def test_a_moving_contact_keeps_the_factor_exact_through_its_capacitance_correction():
    """A probe-like contact imposes the y dof of a few top nodes, a different set each step (x and
    z free). The factor holds those nodes whole and corrects its inverse for the imposed dofs
    (``InverseColumns.correction``), which is exact: every step takes the iterations of a factor made for its
    own imposed set, from the same state (at most one more) and the same solution (1e-9 m), with
    one factorisation."""
    model, control, _ = stiff_scene((6, 6, 6))
    nodes = model.mesh.nodes
    top = np.flatnonzero(np.isclose(nodes[:, 1], nodes[:, 1].max()))
    centre = top[np.argsort(np.hypot(nodes[top, 0] - 0.025, nodes[top, 2] - 0.025))]
    bottom = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))

    def contact(step):
        c = model.new_control()
        c.impose(bottom, nodes[bottom])
        held = centre[step % 3: step % 3 + 4 + step]  # 4-9 nodes, another set each step
        c.impose(held, nodes[held] - [0.0, 0.0005 * step, 0.0], components=(1,))
        return c

    kept = ImplicitEuler(preconditioner="factorised", tolerance=1e-8)
    state = model.new_state()
    kept.simulate(model, state, state.copy(), 0.04, model.new_control().impose(bottom, nodes[bottom]))
    for step in range(1, 6):
        out, fresh_out = state.copy(), state.copy()
        kept.world(model).warm[:] = 0.0  # the same start as a fresh integrator's
        report = kept.simulate(model, state, out, 0.04, contact(step))
        fresh = ImplicitEuler(preconditioner="factorised", tolerance=1e-8)
        fresh_report = fresh.simulate(model, state, fresh_out, 0.04, contact(step))
        assert report.iterations <= fresh_report.iterations + 1, (step, report.iterations, fresh_report.iterations)
        assert np.abs(out.positions - fresh_out.positions).max() < 1e-9
    assert kept.factorisations == 1


def test_refactorises_when_iterations_grow():
    """A factor from the rest state serves a block pressed 12 mm down poorly (8 iterations without
    converging to 1e-8): re-factorised at that state, then 1 more iteration (measured)."""
    model, control, _ = stiff_scene((4, 4, 4))
    integrator = ImplicitEuler(preconditioner="factorised", tolerance=1e-8)
    state = model.new_state()
    integrator.simulate(model, state, state.copy(), 0.04, control(0))
    assert integrator.factorisations == 1
    pressed = state.copy()
    run(model, pressed, ImplicitEuler(preconditioner="jacobi"), 0.04, 12, control(12))
    report = integrator.simulate(model, pressed, pressed.copy(), 0.04, control(12))
    assert integrator.factorisations == 2 and report.residual <= 1e-8
    assert report.iterations <= 8 + 2


@pytest.mark.parametrize("bad", ["cholesky", "", None, 3])
def test_bad_preconditioner_names_are_rejected(bad):
    with pytest.raises(ValueError, match="preconditioner"):
        ImplicitEuler(preconditioner=bad)
    with pytest.raises(ValueError, match="preconditioner"):
        make_integrator("implicit", preconditioner=bad)


@pytest.mark.parametrize("symmetric", [False, True])
@pytest.mark.parametrize("shape, imposed_y", [((3, 3, 3), False), ((4, 4, 4), True)])
def test_node_block_lu_solves_the_free_dof_system(shape, imposed_y, symmetric):
    """The node-block LU (``sparse.NodeBlockLU``, compiled numeric factorisation on a symbolic fill
    pattern) inverts a non-symmetric diagonally dominant matrix on the block's pattern to 1e-12,
    also with single dofs decoupled (a contact imposing only y, as ``Factor`` builds it), and a
    second factorisation of the same pattern reuses the structure and gives the same factor. Its
    symmetric form (LDL^T, half the values) inverts the matrix's symmetric part (A + A^T) / 2 to
    1e-12, through the one- and the several-right-hand-side substitutions."""
    from sim_core.models.sparse import NodeBlockLU

    model, _, patch = stiff_scene(shape)
    n_dofs = 3 * model.n_nodes
    bottom = np.flatnonzero(model.mesh.nodes[:, 1] == 0.0)
    nodes = np.setdiff1d(np.arange(model.n_nodes), bottom)
    node_dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
    whole = FreeStructure(model, node_dofs)
    rng = np.random.default_rng(3)
    values = rng.standard_normal(model.pattern.nnz)
    values[model.pattern.diagonal_positions] += 80.0
    data = values[whole.take]
    free = np.ones(len(node_dofs), bool)
    if imposed_y:
        free[3 * np.searchsorted(nodes, patch) + 1] = False
        columns = np.repeat(np.arange(len(node_dofs)), np.diff(whole.indptr))
        data[~((free[whole.indices] & free[columns]) | (whole.indices == columns))] = 0.0
    matrix = sp.csc_matrix((data, whole.indices, whole.indptr), shape=whole.shape)
    factor = NodeBlockLU(matrix, node_dofs, symmetric=symmetric)
    again = NodeBlockLU(matrix, node_dofs, symmetric=symmetric)
    assert np.array_equal(factor.floats, again.floats)
    lu_size = len(NodeBlockLU(matrix, node_dofs).floats)
    assert len(factor.floats) == (lu_size // 2 if symmetric else lu_size)
    rhs = rng.standard_normal(n_dofs)
    out = np.empty(n_dofs)
    mask = np.zeros(n_dofs)
    mask[node_dofs[free]] = 1.0
    kernels.block_lu_apply(factor.ints, factor.floats, mask, rhs, out, np.empty(len(node_dofs)))
    reduced = matrix[free][:, free]
    if symmetric:
        reduced = (reduced + reduced.T) / 2
        assert abs(reduced - matrix[free][:, free]).max() > 0.1  # the matrix itself is not symmetric
    expected = spla.spsolve(reduced.tocsc(), rhs[node_dofs[free]])
    assert np.abs(out[node_dofs[free]] - expected).max() < 1e-12 * np.abs(expected).max()
    assert np.all(out[mask == 0.0] == 0.0)
    # several right-hand sides at once (the capacitance corrections' columns of the inverse)
    columns = np.array([0, 2], dtype=np.int64)
    several = np.stack([rhs, np.zeros(n_dofs), 2.0 * rhs], axis=1)
    solved = np.zeros_like(several)
    kernels.block_lu_solve(factor.ints, factor.floats, several, solved, columns, 2,
                           np.empty((len(node_dofs), 2)), np.empty((3, 2)))
    for column, scale in ((0, 1.0), (2, 2.0)):
        assert np.abs(solved[node_dofs[free], column] - scale * expected).max() < 1e-12 * np.abs(expected).max()
    # unit right-hand sides (the capacitance corrections' columns of the inverse, whose substitution
    # starts at the first non-zero row): the inverse's columns
    held = node_dofs[free]
    dense = np.linalg.inv(reduced.toarray())
    for picked in ([len(held) - 1], [len(held) - 1, len(held) // 2], [len(held) // 3, 0, len(held) - 2]):
        count = len(picked)
        units = np.zeros((n_dofs, count))
        units[held[picked], np.arange(count)] = 1.0
        inverse = np.zeros_like(units)
        kernels.block_lu_solve(factor.ints, factor.floats, units, inverse, np.arange(count, dtype=np.int64), count,
                               np.empty((len(node_dofs), count)), np.empty((3, count)))
        np.testing.assert_allclose(inverse[held], dense[:, picked], rtol=0, atol=1e-12 * np.abs(dense).max())
    singular = matrix.copy()
    singular.data[:] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        NodeBlockLU(singular, node_dofs, symmetric=symmetric)


def test_smoothed_tet_factor_tries_a_second_ordering_and_keeps_the_cheaper():
    """On the smoothed tetrahedra's wider pattern (nodes coupled two edges apart), where SuperLU's
    MMD fills most, the node-block factor also tries COLAMD (``Model.node_orderings``) and keeps the
    ordering with the fewest block products: on benchmarks.tet_cost's block it holds fewer values
    than MMD's alone and inverts the same matrix to 1e-12. Element patterns (hexahedra, unsmoothed
    tetrahedra) keep MMD alone."""
    from sim_core import TetMesh
    from sim_core.models.sparse import NODE_ORDERINGS, NodeBlockLU

    material = Material(1e4, 0.45, 1000.0)
    assert build_model(HexMesh.block((4, 2, 2), 0.01), material).node_orderings == NODE_ORDERINGS[:1]
    assert build_model(TetMesh.block((4, 2, 2), 0.01), material, smoothing="none").node_orderings == NODE_ORDERINGS[:1]
    model = build_model(TetMesh.block((16, 8, 8), 0.01), material, smoothing="edge-node")
    assert model.node_orderings == NODE_ORDERINGS
    clamp = np.isclose(model.rest_positions[:, 0], 0.0)
    node_dofs = (3 * np.flatnonzero(~clamp)[:, None] + np.arange(3)).ravel()
    whole = FreeStructure(model, node_dofs)
    values = np.random.default_rng(5).standard_normal(model.pattern.nnz)
    values[model.pattern.diagonal_positions] += 200.0
    matrix = sp.csc_matrix((values[whole.take], whole.indices, whole.indptr), shape=whole.shape)
    mmd = NodeBlockLU(matrix, node_dofs, orderings=NODE_ORDERINGS[:1])
    chosen = NodeBlockLU(matrix, node_dofs, orderings=model.node_orderings)
    assert len(chosen.floats) < 0.9 * len(mmd.floats)
    rhs = np.random.default_rng(6).standard_normal(3 * model.n_nodes)
    mask = np.zeros(3 * model.n_nodes)
    mask[node_dofs] = 1.0
    expected = spla.spsolve(matrix, rhs[node_dofs])
    for factor in (mmd, chosen):
        out = np.empty(3 * model.n_nodes)
        kernels.block_lu_apply(factor.ints, factor.floats, mask, rhs, out, np.empty(len(node_dofs)))
        assert np.abs(out[node_dofs] - expected).max() < 1e-12 * np.abs(expected).max()
