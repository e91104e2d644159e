"""The batched factorised solver (tissue_env.batched, solver "factorised") keeps each copy's
node-block LU when a contact imposes more dofs, and restricts it exactly to the free dofs by a
capacitance correction (``_CopyFactor.correction``, ``kernels._corrected_lu_apply``)."""

import numpy as np

from sim_core.bench import tumor_block
from tissue_env.batched import BatchedImplicitEuler, ModelStack


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

    kept = BatchedImplicitEuler(stack, tolerance=1e-8, solver="factorised")
    kept.simulate(positions, velocities, *contact(0), dt, active)
    assert kept.factorisations == count
    for step in range(1, 6):
        kept.warm[:] = 0.0  # the same start as a fresh integrator's
        out, _ = kept.simulate(positions, velocities, *contact(step), dt, active)
        assert all(len(kept._imposed[copy]) == 4 + step for copy in range(count))  # corrected
        fresh = BatchedImplicitEuler(stack, tolerance=1e-8, solver="factorised")
        fresh_out, _ = fresh.simulate(positions, velocities, *contact(step), dt, active)
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
