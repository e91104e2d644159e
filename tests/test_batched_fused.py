"""The batched vector envs' fused factorisations (``ImplicitEuler._factorise_copies``,
``kernels.factor_copies``) give the same factors as the per-copy path (``_factorise``)."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401


def _stepped(env_id, count=4, steps=12, seed=3, **kwargs):
    envs = gym.make_vec(env_id, num_envs=count, vectorization_mode="vector_entry_point", **kwargs)
    rng = np.random.default_rng(seed)
    envs.reset(seed=seed)
    for _ in range(steps):
        envs.step(rng.uniform(-1, 1, (count, 3)).astype(np.float32))
    return envs.unwrapped


def covered(points, quads):
    """(..., P) True where a 2D point (..., P, 2) lies inside at least one convex quad (..., Q, 4, 2)
    of either orientation (leading dimensions: a batch of scenes)."""
    edge = np.roll(quads, -1, axis=-2) - quads  # (..., Q, 4, 2)
    relative = points[..., :, None, None, :] - quads[..., None, :, :, :]  # (..., P, Q, 4, 2)
    cross = edge[..., None, :, :, 0] * relative[..., 1] - edge[..., None, :, :, 1] * relative[..., 0]
    inside = np.all(cross >= 0, axis=-1) | np.all(cross <= 0, axis=-1)
    return inside.any(axis=-1)


def _system(integrator, dt):
    return (1.0, dt, dt * dt, dt * dt, dt * dt, dt * dt)


def test_fused_factorisations_equal_the_per_copy_factors():
    envs = _stepped("tissue_env/Retraction-v0")
    integrator = envs.worlds.integrator
    count, dofs = envs.num_envs, 3 * envs.worlds.n_nodes
    fixed, _, tool_mask = envs.worlds._control()
    free = ~fixed.reshape(count, dofs)
    rng = np.random.default_rng(0)
    covers = free.copy()
    held = envs.worlds.envs[1].base_control.fixed | np.asarray(tool_mask[1])  # attached and grasped
    covers[1] |= ~held.reshape(-1)  # the floor contact released
    covers[2] &= rng.uniform(size=dofs) > 0.1  # single dofs imposed inside free nodes (decoupled)
    assert np.any(covers[2] != free[2])
    system = _system(integrator, envs.worlds.dt)
    assert integrator._incidence[0].shape == (envs.worlds.stack.n_elements, 8, 3)  # the per-node-pair coupling assembly
    expected = []
    for index in range(count):
        factor = integrator._factorise(index, system, covers[index])
        expected.append((factor.ints, factor.floats.copy()))
    before = integrator.factorisations
    factors = integrator._factorise_copies(np.arange(count), system, covers)
    assert integrator.factorisations == before + count
    for index, factor in enumerate(factors):
        ints, floats = expected[index]
        assert factor.ints[0] < 0  # node-block factors
        assert factor.ints[2] == 0  # the LDL^T of the symmetric part (batched.SYMMETRIC_FACTOR): no L stored
        assert np.array_equal(factor.ints, ints)
        # the same assembly and elimination (the compiler may contract or reorder the compiled
        # elimination's floating-point operations differently inside the fused kernel: rounding)
        np.testing.assert_allclose(factor.floats, floats, rtol=1e-12, atol=1e-12 * np.abs(floats).max())
        assert np.shares_memory(integrator.factor_lists[1][index], factor.floats)
        assert np.array_equal(integrator.factor_lists[0][index], ints)
        assert np.array_equal(integrator._factor_free[index], covers[index])
    # the copies' factors differ (their states do): a kernel that mixed copies up would fail above
    assert not np.allclose(factors[0].floats, factors[3].floats)


def test_a_failed_block_factor_falls_back_to_the_scalar_factor(monkeypatch):
    envs = _stepped("tissue_env/Retraction-v0", count=2, steps=3)
    integrator = envs.worlds.integrator
    dofs = 3 * envs.worlds.n_nodes
    fixed, _, _ = envs.worlds._control()
    covers = ~fixed.reshape(2, dofs)
    system = _system(integrator, envs.worlds.dt)
    integrator._structures.clear()
    monkeypatch.setattr(integrator, "_block_structure", lambda key, nodes: None)
    import sim_core.solvers.implicit as batched
    monkeypatch.setattr(batched, "node_block_factor", lambda model, values, free, **kwargs: None)
    factors = integrator._factorise_copies(np.arange(2), system, covers)
    for index, factor in enumerate(factors):
        assert factor.ints[0] == np.count_nonzero(covers[index])  # SuperLU's scalar factor
        assert integrator.factor_lists[0][index] is factor.ints


def test_points_covered_by_quads_kernel_matches_covered():
    from sim_core import kernels
    rng = np.random.default_rng(1)
    count, n_nodes = 3, 40
    quads = rng.integers(0, n_nodes, (30, 4)).astype(np.int64)
    positions = rng.uniform(-1.0, 1.0, (count, n_nodes, 3))
    positions[1, 5] = positions[1, 6]  # degenerate quads (repeated corners)
    positions[2, 7, 0] = np.nan  # a non-finite corner covers nothing
    points = rng.uniform(-1.0, 1.0, (count, 50, 2))
    points[0, :4] = positions[0, quads[0], :][:, [0, 2]]  # on corners: on the boundary counts as inside
    expected = covered(points, positions[:, quads][..., [0, 2]])
    out = np.empty((count, 50), dtype=bool)
    kernels.points_covered_by_quads(points, positions, quads, out)
    assert np.array_equal(out, expected)
    assert 0 < expected.sum() < expected.size


def test_vector_retraction_exposure_equals_the_single_envs():
    envs = _stepped("tissue_env/Retraction-v0", count=3, steps=20, seed=5)
    worlds = envs.worlds
    measures = worlds.measures  # the last step's, at the current positions
    for index in range(3):  # the compiled pass against the numpy test of the points under the flap
        quads = worlds.positions[index][worlds.footprint_quads][..., [0, 2]]
        expected = 1.0 - float(np.mean(covered(worlds.target_points[index], quads)))
        assert measures["exposed_fraction"][index] == expected


@pytest.mark.parametrize("env_id, groups", [("tissue_env/Palpation-v0", "several"),
                                             ("tissue_env/TumorPositioning-v0", "one")])
def test_stacked_force_workspace_equals_the_stacked_models_force_pass(env_id, groups):
    """StackedForceWorkspace's hourglass term (one copy's matrix read once for all copies where they
    share it; each copy's own in node blocks where they differ) gives the stacked model's forces
    (ForceWorkspace) to rounding."""
    from sim_core.models.forces import ForceWorkspace
    from sim_core.models.stack import StackedForceWorkspace
    envs = _stepped(env_id, count=4, steps=6, seed=0, model="baudet")  # the model with hourglass control
    stack = envs.worlds.stack
    # Palpation's copies draw different inclusions (hourglass matrices), TumorPositioning's share one
    assert (len(stack.hourglass_groups()) > 1) == (groups == "several")
    positions = np.ascontiguousarray(envs.worlds.positions.reshape(-1, 3))
    velocities = np.ascontiguousarray(envs.worlds.velocities.reshape(-1, 3))
    rest = stack.model.rest_positions.reshape(envs.num_envs, -1, 3)
    assert np.abs(envs.worlds.positions - rest).max() > 1e-4  # deformed: the hourglass term is not zero
    for implicit, args in ((True, dict(velocities=None, geometric=True, volume_jacobian=True)),
                           (False, dict(velocities=velocities))):
        expected = ForceWorkspace(stack.model, implicit=implicit)
        workspace = StackedForceWorkspace(stack, implicit=implicit)
        want = expected.compute(positions, **args).copy()
        got = workspace.compute(positions, **args)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
        without = expected.compute(positions, args["velocities"], hourglass=False).copy()
        assert np.abs(want - without).max() > 1e-3 * np.abs(want).max()  # the term this checks matters
        if implicit:
            np.testing.assert_array_equal(workspace.geometric, expected.geometric)
            np.testing.assert_array_equal(workspace.volume_coefficient, expected.volume_coefficient)


def test_per_copy_solves_read_the_hourglass_matrices_in_node_blocks():
    """kernels.apply_blocks with StackedForceWorkspace.hourglass_blocks (the node-block form of each
    copy's hourglass matrix, solve_copies_lu's operator) equals apply_operator with the copy's CSR
    matrix (to rounding), for copies with different hourglass matrices."""
    from sim_core import kernels
    envs = _stepped("tissue_env/Palpation-v0", count=4, steps=4, seed=0, model="baudet")
    integrator, stack = envs.worlds.integrator, envs.worlds.stack
    assert len(stack.hourglass_groups()) > 1
    stacked, hg_rows, hg_group = integrator.copies_first()
    indptr, indices, values = integrator.workspace.hourglass_blocks()
    assert values.shape == (len(hg_rows), 9 * len(indices))
    nodes = stack.n_nodes
    dt = envs.worlds.dt
    system = (1.0, dt, dt * dt, dt * dt, dt * dt, dt * dt)
    rng = np.random.default_rng(0)
    for c in range(envs.num_envs):
        data = kernels.copy_data(stacked, hg_rows, hg_group, np.int64(c))  # copy c's slices, its hourglass values
        vector = rng.normal(size=3 * nodes)
        mask = (rng.uniform(size=3 * nodes) > 0.2).astype(float)
        expected, out = np.empty_like(vector), np.empty_like(vector)
        kernels.apply_operator(data, system, mask, vector, expected)
        kernels.apply_blocks(data, system, np.ones(3 * nodes), indptr, indices, values[hg_group[c]], mask, vector,
                             out)
        np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        hourglass = dt * dt * (stack.models[c].hourglass @ vector)  # the term this checks matters
        assert np.abs(hourglass).max() > 1e-3 * np.abs(expected).max()


def test_threaded_force_pass_and_products_give_the_serial_floats():
    """With more than one thread the stacked force pass runs one copy per thread
    (``kernels.model_forces_copies``), the hourglass term one block of rows per thread and the
    right-hand side's operator products one copy per thread (``kernels.apply_copies``): the same
    floats as the serial pass over the stacked model, bit for bit (the vector envs' results do not
    depend on the thread count)."""
    from sim_core import kernels
    from sim_core.models.stack import StackedForceWorkspace
    for env_id in ("tissue_env/Palpation-v0", "tissue_env/TumorPositioning-v0"):
        envs = _stepped(env_id, count=4, steps=6, seed=0)
        stack = envs.worlds.stack
        positions = np.ascontiguousarray(envs.worlds.positions.reshape(-1, 3))
        velocities = np.ascontiguousarray(envs.worlds.velocities.reshape(-1, 3))
        for implicit, args in ((True, dict(velocities=None, geometric=True, volume_jacobian=True)),
                               (False, dict(velocities=velocities))):
            serial, threaded = (StackedForceWorkspace(stack, implicit=implicit, threads=t) for t in (1, 2))
            for workspace in (serial, threaded):
                workspace.compute(positions, **args)
            assert np.abs(serial.forces).max() > 0
            for name in ("forces", "length", "unit", "tension", "push", "geometric", "volume_coefficient",
                         "volume_direction", "volume_gradient"):
                np.testing.assert_array_equal(getattr(threaded, name), getattr(serial, name), err_msg=name)
        integrator = envs.worlds.integrator
        integrator.linearise(positions + 1e-7)  # a fresh linearisation for the products
        stacked, hg_rows, hg_group = integrator.copies_first()
        blocks = integrator.workspace.hourglass_blocks()
        system = _system(integrator, envs.worlds.dt)
        vector = np.random.default_rng(1).normal(size=(envs.num_envs, 3 * envs.worlds.n_nodes))
        out = {}
        for name in ("apply_copies", "apply_copies_serial"):
            out[name] = np.empty_like(vector)
            getattr(kernels, name)(stacked, system, hg_rows, hg_group, vector, np.ones(len(vector), dtype=bool),
                                   out[name], *blocks)
        np.testing.assert_array_equal(out["apply_copies"], out["apply_copies_serial"])


def test_a_force_pass_of_some_copies_gives_their_floats_and_leaves_the_others():
    """``StackedForceWorkspace.compute(rows=...)`` (a contact pass that solves some copies again)
    computes the asked copies alone, copy by copy, on one thread or two: their forces and implicit
    data are those of the pass over every copy, bit for bit, and the other copies' entries are left
    as they were."""
    from sim_core.models.stack import StackedForceWorkspace
    for env_id in ("tissue_env/Palpation-v0", "tissue_env/TumorPositioning-v0"):
        envs = _stepped(env_id, count=4, steps=6, seed=0)
        stack = envs.worlds.stack
        positions = np.ascontiguousarray(envs.worlds.positions.reshape(-1, 3))
        args = dict(velocities=None, geometric=True, volume_jacobian=stack.model.has_volume_forces)
        every = StackedForceWorkspace(stack, implicit=True, threads=1)
        every.compute(positions, **args)
        rows = np.array([True, False, False, True])
        node_rows = np.repeat(rows, stack.n_nodes)
        for threads in (1, 2):
            some = StackedForceWorkspace(stack, implicit=True, threads=threads)
            some.forces[:] = 7.0
            some.stress_tangent[:] = 7.0
            some.compute(positions, rows=rows, **args)
            np.testing.assert_array_equal(some.forces[node_rows], every.forces[node_rows])
            assert np.all(some.forces[~node_rows] == 7.0)
            if len(every.stress_tangent):  # a hyperelastic stress correction's tangent
                cells = np.repeat(rows, len(every.stress_tangent) // len(rows))
                np.testing.assert_array_equal(some.stress_tangent[cells], every.stress_tangent[cells])
                assert np.all(some.stress_tangent[~cells] == 7.0)
            springs = np.repeat(rows, len(every.geometric) // len(rows))
            np.testing.assert_array_equal(some.geometric[springs], every.geometric[springs])


def test_per_copy_solves_scale_their_guess_to_the_least_residual():
    """``kernels.solve_copies_lu`` starts from the guess scaled by the factor that minimises the
    residual ||b - a A x0||: a guess that is a multiple of the solution (3 x, -2 x) starts converged
    (0 iterations, the solution to rounding; unscaled, they need hundreds without a preconditioner). Over 150 random
    TumorPositioning steps this took 2.95 -> 2.54 iterations per copy (smooth actions 3.91 -> 3.69)."""
    from numba.typed import List as TypedList

    from sim_core import kernels
    # (8, 4, 8): unpreconditioned, the default (10, 5, 10) needs about 3000 iterations from zero
    envs = _stepped("tissue_env/Palpation-v0", count=3, steps=4, seed=1, shape=(8, 4, 8), model="baudet")
    integrator = envs.worlds.integrator
    stacked, hg_rows, hg_group = integrator.copies_first()
    blocks = integrator.workspace.hourglass_blocks()
    count, dofs = envs.num_envs, 3 * envs.worlds.n_nodes
    system = _system(integrator, envs.worlds.dt)
    exact = np.random.default_rng(2).normal(size=(count, dofs))
    rhs = np.empty_like(exact)
    kernels.apply_copies_serial(stacked, system, hg_rows, hg_group, exact, np.ones(count, dtype=bool), rhs, *blocks)
    identity = np.zeros(1, dtype=np.int64)  # k = 0: no preconditioner
    lists = (TypedList([identity]), TypedList([np.zeros(1)]), np.zeros(count, dtype=np.int64),
             TypedList([np.zeros((0, 0))] * count), TypedList([np.zeros(0, dtype=np.int64)] * count))
    for guess, converged in ((3.0 * exact, True), (-2.0 * exact, True), (np.zeros_like(exact), False)):
        solution, iterations, residual = np.zeros_like(exact), np.zeros(count, np.int64), np.zeros(count)
        kernels.solve_copies_lu_serial(stacked, system, hg_rows, hg_group, np.ones_like(exact), rhs, guess,
                                       np.ones(count, bool), 1e-10, np.full(count, 500, np.int64), *lists,
                                       np.empty((8, dofs)), solution, iterations, residual, *blocks)
        assert np.all(residual <= 1e-10)
        if converged:  # the scaled guess is the solution (to rounding)
            assert np.all(iterations == 0)
            np.testing.assert_allclose(solution, exact, rtol=0, atol=1e-12 * np.abs(exact).max())
        else:  # no preconditioner: hundreds of iterations to the same solution
            assert np.all(iterations > 0)
            np.testing.assert_allclose(solution, exact, rtol=0, atol=1e-5 * np.abs(exact).max())


def _solve_inputs(envs, factor_of, seed=4):
    """The Palpation copies' own factors (node-block LUs with their capacitance corrections for the
    probe's imposed dofs), free masks and random right-hand sides and guesses, as the per-copy
    kernels take them, with ``factor_of`` mapping copies to those factors."""
    integrator = envs.worlds.integrator
    count, dofs = envs.num_envs, 3 * envs.worlds.n_nodes
    fixed, _, _ = envs.worlds._control()
    free = ~fixed.reshape(count, dofs)
    integrator._correct(np.arange(count), free)
    rng = np.random.default_rng(seed)
    rhs = rng.normal(size=(count, dofs)) * free
    guess = rng.normal(size=(count, dofs))
    return (integrator.copies_first(), integrator.workspace.hourglass_blocks(), free.astype(float), rhs, guess,
            (*integrator.factor_lists, np.asarray(factor_of, dtype=np.int64), *integrator.correction_lists))


def test_grouped_lockstep_solves_equal_the_per_copy_solves():
    """``kernels.solve_copies_grouped`` (chunks of copies in lockstep, one pass over a shared factor
    for all the chunk's copies of it) gives each copy ``solve_copies_lu``'s iterations and solution
    (to rounding), with shared and own factors, capacitance corrections, a copy stopped by its
    cap, an inactive copy, a zero and a non-finite right-hand side; every chunk size gives the same
    floats, and the threaded kernel the serial one's exactly."""
    from sim_core import kernels
    envs = _stepped("tissue_env/Palpation-v0", count=6, steps=10, seed=2, model="baudet")
    assert any(len(imposed) for imposed in envs.worlds.integrator.correction_lists[1])  # corrections are exercised
    count, dofs = envs.num_envs, 3 * envs.worlds.n_nodes
    system = _system(envs.worlds.integrator, 2.0 * envs.worlds.dt)  # the factors are approximate: several iterations
    for factor_of in (np.arange(count), [0, 0, 3, 3, 0, 5]):
        (stacked, hg_rows, hg_group), blocks, mask, rhs, guess, lists = _solve_inputs(envs, factor_of)
        rhs[2] = 0.0
        rhs[4, 7] = np.nan
        active = np.ones(count, bool)
        active[5] = False
        limits = np.array([200, 200, 200, 1, 200, 200])  # copy 3 stops at its cap

        def solve(name, *chunk):
            solution, iterations, residual = np.zeros((count, dofs)), np.zeros(count, np.int64), np.zeros(count)
            work = np.empty((8, count, dofs) if chunk else (8, dofs))
            getattr(kernels, name)(stacked, system, hg_rows, hg_group, mask, rhs, guess, active, 1e-12, limits, *lists,
                                   work, solution, iterations, residual, *blocks, *chunk)
            return solution, iterations, residual

        expected, iterations, residual = solve("solve_copies_lu_serial")
        assert iterations[3] == 1 and residual[3] > 1e-12 and np.all(iterations[[0, 1]] > 1)
        assert np.isinf(residual[4]) and np.all(np.isnan(expected[4]))
        assert np.all(expected[2] == 0.0) and iterations[5] == 0 and np.all(expected[5] == 0.0)
        scale = np.abs(expected[np.isfinite(expected)]).max()
        first = solve("solve_copies_grouped_serial", 1)
        for chunk in (1, 2, 6, 8):
            serial = solve("solve_copies_grouped_serial", chunk)
            for one, two in zip(serial, first):  # a copy's floats do not depend on its chunk
                np.testing.assert_array_equal(one, two)
            np.testing.assert_array_equal(serial[1], iterations)
            np.testing.assert_allclose(serial[2], residual, rtol=1e-6)
            np.testing.assert_allclose(serial[0], expected, rtol=0, atol=1e-10 * scale)
            for one, two in zip(solve("solve_copies_grouped", chunk), serial):
                np.testing.assert_array_equal(one, two)  # NaN rows equal too


def test_lockstep_chunks_give_two_threads_work_and_one_thread_one_pass():
    """Solver "reference" splits the copies into lockstep chunks of ``lockstep_chunk``: on several
    threads at least two chunks from two copies on (one chunk of 4 copies left the second core idle:
    7% slower than per copy on 2 threads) and at most ``LOCKSTEP_CHUNK`` copies each (16 copies: 2
    chunks of 8); on one thread one chunk, up to ``SERIAL_LOCKSTEP_CHUNK`` copies (16 copies: one
    pass over a shared factor instead of two). The floats do not depend on the chunks
    (``test_grouped_lockstep_solves_equal_the_per_copy_solves``)."""
    from sim_core.solvers.implicit import LOCKSTEP_CHUNK, SERIAL_LOCKSTEP_CHUNK, lockstep_chunk
    assert lockstep_chunk(1, 2) == 1 and lockstep_chunk(16, 2) == 8 == LOCKSTEP_CHUNK
    assert lockstep_chunk(16, 1) == 16 == SERIAL_LOCKSTEP_CHUNK and lockstep_chunk(5, 1) == 5
    for count in range(1, 65):
        chunk = lockstep_chunk(count, 2)
        chunks = -(-count // chunk)
        assert 1 <= chunk <= LOCKSTEP_CHUNK
        assert chunks >= min(count, 2)
        assert lockstep_chunk(count, 1) == min(count, SERIAL_LOCKSTEP_CHUNK)


def test_threaded_measurement_kernels_give_the_serial_floats():
    """The vector envs' measurement passes over the stacked model (spring lengths, element volumes,
    the springs' damping forces) run one copy per thread when threaded: the same floats as the
    serial pass, bit for bit."""
    from sim_core import kernels
    from sim_core.models.stack import StackedForceWorkspace
    envs = _stepped("tissue_env/Palpation-v0", count=4, steps=6, seed=0, model="baudet")
    stack, count = envs.worlds.stack, envs.num_envs
    model = stack.model
    positions = np.ascontiguousarray(envs.worlds.positions.reshape(-1, 3))
    velocities = np.ascontiguousarray(envs.worlds.velocities.reshape(-1, 3))
    assert np.abs(velocities).max() > 0
    serial, threaded = np.empty(len(model.springs)), np.empty(len(model.springs))
    kernels.spring_lengths(positions, model.springs, serial)
    kernels.spring_lengths_copies(count, positions, model.springs, threaded)
    np.testing.assert_array_equal(threaded, serial)
    elements = model.mesh.elements
    serial = kernels.element_volumes(positions, elements, np.empty(len(elements)))
    threaded = kernels.element_volumes_copies(count, positions, elements, np.empty(len(elements)))
    np.testing.assert_array_equal(threaded, serial)
    damped = []
    for threads in (1, 2):
        workspace = StackedForceWorkspace(stack, implicit=True, threads=threads)
        forces = workspace.compute(positions, None, geometric=True).copy()
        damped.append(workspace.add_damping(velocities, forces.copy()))
        assert np.abs(damped[-1] - forces).max() > 0  # the damping forces are not zero
    np.testing.assert_array_equal(damped[1], damped[0])


def test_the_probe_surface_of_all_copies_on_threads_gives_the_serial_floats():
    """Palpation's vector env computes its copies' projected probe surfaces with the copies on
    numba's threads (``Probe.surface(parallel=True)``): the same floats as the serial pass, with the
    probe over the tissue in some copies and away from it in others."""
    envs = _stepped("tissue_env/Palpation-v0", count=4, steps=6, seed=0, model="baudet")
    tips = envs.worlds.probe_start + envs.worlds.tool_offset  # (N, 3) m, each copy's probe tip
    serial = envs.worlds.probe.surface(envs.worlds.positions, tips)
    threaded = envs.worlds.probe.surface(envs.worlds.positions, tips, parallel=True)
    np.testing.assert_array_equal(threaded, serial)
    assert np.isfinite(serial).any() and np.isinf(serial).any()


def test_the_step_glue_kernels_give_numpys_floats():
    """The batched implicit step's per-dof passes (``kernels.implicit_rows_start``, ``_rhs``,
    ``_update``) and the vector envs' strain / collapse and tool reaction passes give the floats of
    the numpy expressions they replaced, bit for bit, threaded and serial; NaN lengths give NaN
    strain and count as collapsed, as numpy's max and comparison do; inactive rows keep their state."""
    from sim_core import kernels
    rng = np.random.default_rng(11)
    count, dofs, dt = 5, 27, 0.04
    x, v, target, forces, mass, product, solution, old_x, old_v = rng.normal(size=(9, count, dofs))
    imposed = rng.random((count, dofs)) < 0.3
    active = np.array([True, True, False, True, True])
    target_velocity = (target - x) / dt
    moved = np.where(imposed, target_velocity, v)
    rhs = dt * forces + mass * v - product
    known = np.where(imposed, target_velocity - v, 0.0)
    new_v = v + np.where(~imposed, solution, known)
    new_x = x + dt * new_v
    new_v[imposed], new_x[imposed] = target_velocity[imposed], target[imposed]
    new_x[~active], new_v[~active] = old_x[~active], old_v[~active]
    for suffix in ("", "_serial"):
        got = np.empty((4, count, dofs))
        getattr(kernels, "implicit_rows_start" + suffix)(x, v, target, imposed, dt, got[0], got[1])
        getattr(kernels, "implicit_rows_rhs" + suffix)(forces, mass, v, product, dt, got[2])
        np.testing.assert_array_equal(got[0], target_velocity)
        np.testing.assert_array_equal(got[1], moved)
        np.testing.assert_array_equal(got[2], rhs)
        out_x, out_v = np.empty((count, dofs)), np.empty((count, dofs))
        getattr(kernels, "implicit_rows_update" + suffix)(x, v, solution, imposed, target, target_velocity, dt, active,
                                                          old_x, old_v, out_x, out_v)
        np.testing.assert_array_equal(out_x, new_x)
        np.testing.assert_array_equal(out_v, new_v)
    length, rest = rng.uniform(0.5, 1.5, (2, count, 40))
    length[1, 3], length[2, 7], length[4, 0] = np.nan, 0.0, 1e-9 * rest[4, 0]
    for suffix in ("", "_serial"):
        strain, collapsed = np.empty(count), np.empty(count, dtype=bool)
        getattr(kernels, "strain_extremes" + suffix)(length, rest, strain, collapsed)
        np.testing.assert_array_equal(strain, np.max(np.abs(length / rest - 1.0), axis=1))
        np.testing.assert_array_equal(collapsed, ~np.all(length > 1e-6 * rest, axis=1))
    assert collapsed.tolist() == [False, True, True, False, True]
    node_forces = rng.normal(size=(count, 30, 3)) * np.exp(3 * rng.normal(size=(count, 30, 3)))
    mask = rng.random((count, 30, 3)) < 0.4
    reaction = np.empty((count, 3))
    kernels.masked_reaction(node_forces, mask, reaction)
    np.testing.assert_array_equal(reaction, np.where(mask, -node_forces, 0.0).sum(axis=1))
