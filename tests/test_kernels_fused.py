"""The fused hot-path kernels (``kernels.model_forces``, ``spring_operator``, the implicit step)
against the numpy reference and the assembled sparse matrices: same physics within round-off."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from sim_core import kernels
from sim_core.models.forces import ForceWorkspace, internal_forces, internal_forces_reference, spring_state, stiffness_data
from sim_core.solvers.integrators import ImplicitEuler, run
from sim_core.models.material import Material
from sim_core.geometry.mesh import HexMesh
from sim_core.models.model import build_model

VARIANTS = [dict(), dict(hourglass_control=0.5), dict(model="baudet-original"), dict(corrections=False),
            dict(volume_stiffness=100.0)]


def _scene(**options):
    mesh = HexMesh.block((3, 4, 2), 0.02)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), **options)
    rng = np.random.default_rng(0)
    positions = mesh.nodes + 1e-3 * rng.standard_normal(mesh.nodes.shape)
    velocities = 1e-2 * rng.standard_normal(mesh.nodes.shape)
    return model, positions, velocities


@pytest.mark.parametrize("options", VARIANTS)
def test_fused_forces_match_reference_and_separate_kernels(options):
    model, x, v = _scene(**options)
    fused = internal_forces(model, x, v)
    scale = np.abs(fused).max()
    assert np.abs(fused - internal_forces_reference(model, x, v)).max() <= 1e-12 * scale
    springs, push = spring_state(model, x)
    assert np.abs(fused - internal_forces(model, x, v, springs=springs, push=push)).max() <= 1e-12 * scale
    workspace = ForceWorkspace(model)
    workspace.compute(x, v, geometric=True, volume_jacobian=True)
    assert np.allclose(workspace.tension, springs.tension, rtol=1e-12, atol=1e-12 * np.abs(springs.tension).max())
    assert np.allclose(workspace.geometric, np.maximum(springs.tension / springs.length, 0.0), rtol=1e-12, atol=1e-9)


def test_volume_kernels_match_the_generic_formulas():
    model, x, _ = _scene()
    elements, n_elements = model.mesh.elements, model.mesh.n_elements
    coefficient, direction, gradient = np.zeros(n_elements), np.zeros((n_elements, 8, 3)), np.zeros((n_elements, 8, 3))
    kernels.volume_jacobian_terms(x, elements, model.rest_volume, model.volume_stiffness, coefficient, direction,
                                  gradient)
    # gradient: finite differences of the exact volume; direction: sum of a_S / (4 A_H)
    corner = x[elements[0]].copy()
    step = 1e-7
    for n in range(8):
        for c in range(3):
            plus, minus = corner.copy(), corner.copy()
            plus[n, c] += step
            minus[n, c] -= step
            fd = (kernels.hex_volume(plus) - kernels.hex_volume(minus)) / (2 * step)
            assert fd == pytest.approx(gradient[0, n, c], rel=1e-6, abs=1e-12)
    volume = kernels.hex_volume(corner)
    assert coefficient[0] == pytest.approx(2 * model.volume_stiffness[0] * abs(volume - model.rest_volume[0])
                                           / model.rest_volume[0] ** 2, rel=1e-12)


@pytest.mark.parametrize("options", VARIANTS)
def test_matrix_free_operator_matches_assembled_matrix(options):
    model, x, v = _scene(**options)
    dt = 0.01
    workspace = ForceWorkspace(model)
    workspace.compute(x, v, geometric=True, volume_jacobian=True)
    coupled = model.correction_mode is not None
    volume = model.has_volume_forces
    hourglass = model.hourglass is not None
    scales = (1.0, dt, dt * dt, dt * dt if coupled else 0.0, dt * dt if volume else 0.0, dt * dt if hourglass else 0.0)
    vector = np.random.default_rng(1).standard_normal(x.size)
    mask = np.ones(x.size)
    mask[:9] = 0.0
    out = np.empty(x.size)
    kernels.apply_operator(workspace.operator_data, scales, mask, vector, out)
    if model.correction_mode == "fixed":
        return  # the integrator applies the fixed-direction coupling along current edges (approximation)
    data = stiffness_data(model, x, corrections="full" if coupled else "none", volume=volume, clamp=True,
                          stiffness_scale=dt * dt, damping_scale=dt, mass_scale=1.0)
    expected = mask * (model.pattern.matrix(data).tocsr() @ vector)
    assert np.abs(out - expected).max() <= 1e-12 * np.abs(expected).max()


@pytest.mark.parametrize("preconditioner", ["jacobi", "factorised"])
def test_implicit_step_solves_the_assembled_system(preconditioner):
    model, _, _ = _scene(hourglass_control=0.5)
    control = model.new_control()
    bottom = np.flatnonzero(model.mesh.nodes[:, 1] == 0)
    control.impose(bottom, model.mesh.nodes[bottom])
    state = model.new_state()
    run(model, state, ImplicitEuler(), 0.01, 3, control)
    integrator = ImplicitEuler(preconditioner=preconditioner, tolerance=1e-12)
    out = state.copy()
    report = integrator.simulate(model, state, out, 0.01, control)
    assert report.residual <= 1e-12
    # the same linearised step with the assembled matrix and a direct solve
    dt, x0, v0 = 0.01, state.positions, state.velocities
    forces = internal_forces(model, x0, v0) + model.gravity_force + control.force
    stiffness = model.pattern.matrix(stiffness_data(model, x0, corrections="full", volume=True, clamp=True)).tocsr()
    system = model.pattern.matrix(stiffness_data(model, x0, corrections="full", volume=True, clamp=True,
                                                 stiffness_scale=dt * dt,
                                                 damping_scale=dt, mass_scale=1.0)).tocsr()
    rhs = dt * (forces.ravel() - dt * (stiffness @ v0.ravel()))
    free = np.flatnonzero(~control.fixed.ravel())
    known = np.zeros(x0.size)
    fixed = ~np.isin(np.arange(x0.size), free)
    known[fixed] = (((control.target - x0) / dt) - v0).ravel()[fixed]
    rhs -= system @ known
    dv = known.copy()
    dv[free] = spla.spsolve(system[free][:, free].tocsc(), rhs[free])
    expected = v0 + dv.reshape(-1, 3)
    assert np.abs(out.velocities - expected).max() <= 1e-8 * np.abs(expected).max()
