"""The batched factorised solver (sim_core.solvers.implicit, solver "factorised") keeps each copy's
node-block LU when a contact imposes more dofs, and restricts it exactly to the free dofs by a
capacitance correction (``factors.CopyFactor.correction``, ``kernels.corrected_lu_apply``)."""

import numpy as np
import pytest

from sim_core.studies.bench import tumor_block
from sim_core.solvers.implicit import ImplicitEuler
from sim_core.models.stack import ModelStack


def test_a_moving_contact_keeps_each_copys_factor_exact_through_its_capacitance_correction():
    """Each copy's probe-like contact imposes the y dof of 4-9 top nodes, another set per copy and
    step (x and z free), on TumorPositioning's 6^3 block at rest. The copies' factors, made at the
    first step without contact, are kept and corrected for the dofs imposed now: every step takes
    the iterations of freshly factorised copies (at most one more) and gives their solution
    (1e-9 m), with one factorisation per copy."""
    model, bottom, _ = tumor_block((6, 6, 6), 0.01)
    nodes = model.mesh.nodes
    top = np.flatnonzero(np.isclose(nodes[:, 1], nodes[:, 1].max()))
    centre = top[np.argsort(np.hypot(nodes[top, 0] - 0.025, nodes[top, 2] - 0.025))]
    count, dt = 3, 0.04
    stack = ModelStack(model, count)
    positions = np.repeat(nodes[None], count, axis=0)
    velocities = np.zeros_like(positions)
    active = np.ones(count, dtype=bool)

    def contact(step):
        fixed = np.zeros(positions.shape, dtype=bool)
        fixed[:, bottom] = True
        target = positions.copy()
        for copy in range(count if step else 0):
            held = centre[(step + copy) % 3:(step + copy) % 3 + 4 + step]
            fixed[copy, held, 1] = True
            target[copy, held, 1] -= 0.0005 * step
        return fixed, target

    kept = ImplicitEuler(stack, tolerance=1e-8, preconditioner="factorised")
    kept.advance(positions, velocities, *contact(0), dt, active)
    assert kept.factorisations == count
    for step in range(1, 6):
        kept.warm[:] = 0.0  # the same start as a fresh integrator's
        out, _ = kept.advance(positions, velocities, *contact(step), dt, active)
        assert all(len(kept.correction_lists[1][copy]) == 4 + step for copy in range(count))  # corrected
        fresh = ImplicitEuler(stack, tolerance=1e-8, preconditioner="factorised")
        fresh_out, _ = fresh.advance(positions, velocities, *contact(step), dt, active)
        assert np.all(kept.last_iterations <= fresh.last_iterations + 1), (step, kept.last_iterations,
                                                                             fresh.last_iterations)
        assert np.abs(out - fresh_out).max() < 1e-9
    assert kept.factorisations == count


def test_the_capacitance_product_runs_in_this_thread_and_equals_numpys():
    """``kernels.serial_product`` (the correction's (dofs, k) x (k, k) product, kept off OpenBLAS's
    spinning thread pool) equals numpy's product to 1e-12, zero columns and a 1 x 1 case included."""
    from sim_core import kernels
    rng = np.random.default_rng(3)
    for m, k in ((819, 1), (819, 7), (1536, 72)):
        a = rng.normal(size=(m, k))
        a[::5] = 0.0
        b = rng.normal(size=(k, k))
        np.testing.assert_allclose(kernels.serial_product(a, b), a @ b, rtol=0, atol=1e-12)


def test_the_copies_inverse_columns_equal_each_factors_own():
    """``kernels.inverse_columns_copies`` (the corrections' columns of every copy's inverse in one call
    on numba's threads) gives the floats of its serial version and of ``InverseColumns.columns`` (one
    copy's columns solved together), zero on the imposed dofs."""
    from sim_core import kernels
    from sim_core.solvers.preconditioners import InverseColumns
    model, bottom, _ = tumor_block((5, 5, 5), 0.01)
    count, dt = 3, 0.04
    stack = ModelStack(model, count)
    positions = np.repeat(model.mesh.nodes[None], count, axis=0)
    fixed = np.zeros(positions.shape, dtype=bool)
    fixed[:, bottom] = True
    integrator = ImplicitEuler(stack, tolerance=1e-8, preconditioner="factorised")
    integrator.advance(positions, np.zeros_like(positions), fixed, positions, dt, np.ones(count, dtype=bool))
    free = np.flatnonzero(~fixed[0].ravel())
    picks = [free[[3, 40, 41]], free[[len(free) - 1]], free[[0, len(free) // 2]]]
    copies = np.array([0, 1, 2], dtype=np.int64)
    indptr = np.array([0, 3, 4, 6], dtype=np.int64)
    dofs = np.concatenate(picks).astype(np.int64)
    n_dofs = 3 * model.n_nodes
    threaded, serial = np.zeros((6, n_dofs)), np.zeros((6, n_dofs))
    kernels.inverse_columns_copies(*integrator.factor_lists, copies, indptr, dofs, threaded)
    kernels.inverse_columns_copies_serial(*integrator.factor_lists, copies, indptr, dofs, serial)
    np.testing.assert_array_equal(threaded, serial)
    ints, floats = integrator.factor_lists
    for t, picked in enumerate(picks):
        own = InverseColumns(ints[t], floats[t], n_dofs).columns(picked)
        np.testing.assert_array_equal(threaded[indptr[t]:indptr[t + 1]], own.T)
        assert np.all(threaded[indptr[t]:indptr[t + 1]][:, ~np.isin(np.arange(n_dofs), free)] == 0.0)


def _factorised_copies(count=3):
    """A factorised ImplicitEuler after one step of TumorPositioning's 5^3 block (bottom
    fixed), with its free dofs."""
    model, bottom, _ = tumor_block((5, 5, 5), 0.01)
    stack = ModelStack(model, count)
    positions = np.repeat(model.mesh.nodes[None], count, axis=0)
    fixed = np.zeros(positions.shape, dtype=bool)
    fixed[:, bottom] = True
    integrator = ImplicitEuler(stack, tolerance=1e-8, preconditioner="factorised")
    integrator.advance(positions, np.zeros_like(positions), fixed, positions, 0.04, np.ones(count, dtype=bool))
    return integrator, np.flatnonzero(~fixed[0].ravel()), 3 * model.n_nodes


def test_the_batched_corrections_equal_each_factors_own():
    """``kernels.capacitance_corrections`` (all copies' W = Z (Z[c])^-1 in one call, Gauss-Jordan with
    partial pivoting) equals ``InverseColumns.correction`` (numpy's inverse) to 1e-10 of |W|, threaded
    and serial alike (bitwise), for 1 to 40 imposed dofs; a singular Z[c] (a dof twice) is reported
    (ok False), not returned as NaN or huge values."""
    from sim_core import kernels
    from sim_core.solvers.preconditioners import InverseColumns
    integrator, free, n_dofs = _factorised_copies()
    rng = np.random.default_rng(5)
    picks = [np.sort(rng.choice(free, size, replace=False)) for size in (1, 7, 40)]
    picks.append(np.array([free[2], free[2], free[9]]))  # singular: two equal columns
    ints, floats = integrator.factor_lists
    inverses = [InverseColumns(ints[t % 3], floats[t % 3], n_dofs) for t in range(4)]
    columns = np.concatenate([inverse.columns(picked).T for inverse, picked in zip(inverses, picks)])
    columns = np.ascontiguousarray(columns)  # the integrator's layout: the kernel's compiled signature
    indptr = np.cumsum([0] + [len(picked) for picked in picks]).astype(np.int64)
    flat = np.concatenate(picks).astype(np.int64)
    threaded, serial = np.full(n_dofs * indptr[-1], np.nan), np.full(n_dofs * indptr[-1], np.nan)
    ok_threaded, ok_serial = np.zeros(4, dtype=bool), np.zeros(4, dtype=bool)
    kernels.capacitance_corrections(columns, indptr, flat, threaded, ok_threaded)
    kernels.capacitance_corrections_serial(columns, indptr, flat, serial, ok_serial)
    assert ok_threaded.tolist() == ok_serial.tolist() == [True, True, True, False]
    np.testing.assert_array_equal(threaded[:n_dofs * indptr[3]], serial[:n_dofs * indptr[3]])
    for t in range(3):
        w = threaded[n_dofs * indptr[t]:n_dofs * indptr[t + 1]].reshape(n_dofs, -1)
        reference = inverses[t].correction(picks[t])
        np.testing.assert_allclose(w, reference, rtol=0, atol=1e-10 * np.abs(reference).max())
        np.testing.assert_allclose(w[picks[t]], np.eye(len(picks[t])), rtol=0, atol=1e-10)  # W[c] = I


def test_the_kept_columns_of_the_inverse_are_the_solved_ones_and_forgotten_past_the_cache():
    """``InverseColumns`` keeps solved columns in one array: asked again (in another order, mixed with
    new ones) it returns the floats a fresh solve gives, and it forgets them all when keeping the
    new ones would pass CAPACITANCE_CACHE."""
    from sim_core.solvers import preconditioners
    from sim_core.solvers.preconditioners import InverseColumns
    integrator, free, n_dofs = _factorised_copies(1)
    ints, floats = (factors[0] for factors in integrator.factor_lists)
    kept = InverseColumns(ints, floats, n_dofs)
    first, second = free[[5, 1, 30]], free[[30, 2, 5, 77]]
    kept.columns(first)
    assert kept.missing(second).tolist() == free[[2, 77]].tolist()
    np.testing.assert_array_equal(kept.columns(second), InverseColumns(ints, floats, n_dofs).columns(second))
    limit = preconditioners.CAPACITANCE_CACHE
    many = free[100:100 + limit - 4]
    assert kept.missing(many).tolist() == many.tolist()  # 5 kept + 508 > 512: everything again
    np.testing.assert_array_equal(kept.columns(many)[:, :3], InverseColumns(ints, floats, n_dofs).columns(many[:3]))


def test_copies_sharing_a_factor_ask_its_inverse_once_for_all_their_dofs(monkeypatch):
    """Two copies with one factor (episodes that start alike share it) need columns of its inverse
    that together overflow the kept columns: their union is solved at once, and both corrections
    equal a fresh ``InverseColumns.correction`` (asked one after the other, the second request
    forgot the columns the first counted on). Asking ``rows`` for columns not kept is an error,
    not another dof's column."""
    from sim_core.solvers import preconditioners
    from sim_core.solvers.preconditioners import InverseColumns
    monkeypatch.setattr(preconditioners, "CAPACITANCE_CACHE", 8)
    integrator, free, n_dofs = _factorised_copies(1)
    factor = integrator._factors[0]
    first, second = free[:6], free[10:15]
    factor.inverse(n_dofs).columns(first)  # kept from an earlier step
    wanted = [(0, factor, first), (0, factor, second)]
    integrator._inverse_columns(wanted, n_dofs)
    integrator._form_corrections(wanted, n_dofs)
    for imposed in (first, second):
        w, _ = factor.correction(imposed, n_dofs)
        reference = InverseColumns(factor.ints, factor.floats, n_dofs).correction(imposed)
        np.testing.assert_allclose(w, reference, rtol=0, atol=1e-10 * np.abs(reference).max())
    with pytest.raises(KeyError, match="not kept"):
        InverseColumns(factor.ints, factor.floats, n_dofs).rows(first)
