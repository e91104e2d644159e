"""The hourglass matrix in 3 x 3 node blocks (``forces.hourglass_blocks``): the single envs' operator
products (``kernels.apply_operator_blocks``) and force passes (``kernels.bsr3_matvec_add``)
read it so, and must give the scalar CSR results up to rounding; a model whose hourglass values
change in place (``ModelStack.assign``) must not keep stale blocks."""

import numpy as np

from sim_core import kernels
from sim_core.models.forces import ForceWorkspace, hourglass_blocks
from sim_core.models.material import Material
from sim_core.geometry.mesh import HexMesh
from sim_core.models.model import build_model


def _model(young_modulus=5e3, hourglass_control=1.0):
    return build_model(HexMesh.block((3, 4, 2), 0.02), Material(young_modulus, 0.45, 1060.0), gravity=(0, -9.81, 0),
                       hourglass_control=hourglass_control, volume_stiffness=100.0)


def _state(model, seed=0):
    rng = np.random.default_rng(seed)
    nodes = model.mesh.nodes
    return nodes + 1e-3 * rng.standard_normal(nodes.shape), 1e-2 * rng.standard_normal(nodes.shape)


def _scalar_forces(model, x, v):
    forces = ForceWorkspace(model).compute(x, v, hourglass=False).copy()
    indptr, indices, data = model.hourglass_arrays
    kernels.csr_matvec_add(indptr, indices, data, (x - model.rest_positions).ravel(), -1.0, forces.reshape(-1))
    return forces


def test_blocks_hold_the_hourglass_matrix_and_none_without_it():
    model = _model()
    indptr, indices, values, ones = hourglass_blocks(model)
    dense = np.zeros(model.hourglass.shape)
    for i in range(len(indptr) - 1):
        for q in range(indptr[i], indptr[i + 1]):
            dense[3 * i:3 * i + 3, 3 * indices[q]:3 * indices[q] + 3] = values[9 * q:9 * q + 9].reshape(3, 3)
    assert np.array_equal(dense, model.hourglass.toarray())
    assert np.array_equal(ones, np.ones(model.hourglass.shape[0]))
    assert hourglass_blocks(_model(hourglass_control=0.0)) is None


def test_block_operator_and_forces_equal_the_scalar_csr_ones():
    model = _model()
    x, v = _state(model)
    workspace = ForceWorkspace(model, implicit=True)
    forces = workspace.compute(x, v, geometric=True, volume_jacobian=True).copy()
    reference = _scalar_forces(model, x, v)
    assert np.abs(forces - reference).max() <= 1e-13 * np.abs(reference).max()
    rng = np.random.default_rng(1)
    vector = rng.standard_normal(x.size)
    mask = (rng.random(x.size) > 0.2).astype(float)
    scales = (1.0, 0.02, 4e-4, 4e-4, 4e-4, 4e-4)
    scalar, blocked = np.empty(x.size), np.empty(x.size)
    kernels.apply_operator(workspace.operator_data, scales, mask, vector, scalar)
    indptr, indices, values, ones = hourglass_blocks(model)
    kernels.apply_operator_blocks(workspace.operator_data, scales, ones, indptr, indices, values, mask, vector, blocked)
    assert np.abs(blocked - scalar).max() <= 1e-13 * np.abs(scalar).max()
    assert np.all(blocked[mask == 0.0] == 0.0)


def test_a_stacked_model_drops_its_blocks_when_its_values_change():
    """The stacked model of N worlds is the one model whose values change in place; its node-block
    hourglass form is derived data it must drop then (``StackedModel.values_changed``)."""
    from sim_core.models.stack import ModelStack

    stack = ModelStack(_model(), 1)
    model = stack.model
    x, v = _state(model)
    ForceWorkspace(model).compute(x, v)  # the blocks are built and kept
    model.hourglass.data *= 2.0  # as ModelStack.assign writes another world's values
    stale = ForceWorkspace(model).compute(x, v).copy()
    model.values_changed()
    fresh = ForceWorkspace(model).compute(x, v).copy()
    reference = _scalar_forces(model, x, v)
    assert np.abs(fresh - reference).max() <= 1e-13 * np.abs(reference).max()
    assert np.abs(stale - reference).max() > 1e-6 * np.abs(reference).max()


def test_model_stack_assign_refreshes_the_stacked_blocks():
    from sim_core.models.stack import ModelStack

    soft, stiff = _model(5e3), _model(2e4)
    stack = ModelStack(soft, 2)
    x, v = _state(soft)
    positions, velocities = np.concatenate([x, x]), np.concatenate([v, v])
    ForceWorkspace(stack.model).compute(positions, velocities)  # blocks of two soft copies
    stack.assign(1, stiff)
    forces = ForceWorkspace(stack.model).compute(positions, velocities).reshape(2, -1, 3)
    expected = _scalar_forces(stiff, x, v)
    assert np.abs(forces[1] - expected).max() <= 1e-12 * np.abs(expected).max()
    assert np.abs(forces[0] - _scalar_forces(soft, x, v)).max() <= 1e-12 * np.abs(expected).max()
