"""Accuracy floors of baudet-hyperelastic at large deformation (issue 27), through the public API.

The compression floor (20% and 30% at nu = 0.45 and 0.49, here also 0.499: dV/V0 within 1
percentage point of fem-neohookean and axial stress within 10%, stable equilibrium) is asserted by
``tests/test_hyperelastic_mss.py::test_unconfined_compression_follows_neo_hookean``; this file adds
refinement and objectivity under the protocols of benchmarks/validation.py figures 13 and 14.
Each test states its tolerance and what was measured.
"""

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from scipy.interpolate import RegularGridInterpolator

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.solvers.hyperelastic import NeoHookeanFEM
from sim_core.models.model import Control

MODEL = "baudet-hyperelastic"
E, RHO = 1e4, 1500.0
#: Fig. 14's cantilever: 1 m x 0.2 m x 0.2 m of 5m x m x m cubes, clamped at x = 0, under gravity
#: that sags its tip 30% of its length; nu = 0.3, where the fully integrated reference does not lock
NU, GRAVITY = 0.3, 0.055


def beam(m):
    return HexMesh.block((5 * m, m, m), 0.2 / m)


def clamped(mesh):
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    return Control.free(mesh.n_nodes).impose(clamp, mesh.nodes[clamp])


def displacement_at(mesh, positions, points):
    """Trilinear displacement (P, 3) of a block solution at rest-coordinate ``points``."""
    nx, ny, nz = mesh.shape
    u = (positions - mesh.nodes).reshape(nz + 1, ny + 1, nx + 1, 3).transpose(2, 1, 0, 3)
    axes = [np.linspace(0.0, mesh.size[a], mesh.shape[a] + 1) for a in range(3)]
    return RegularGridInterpolator(axes, u)(np.clip(points, 0.0, mesh.size))


def neo_hookean_reference(levels=(2, 4, 8)):
    """fem-neohookean on the finest of ``levels``: NeoHookeanFEM.solve on the first mesh, then Newton
    (its tangent, backtracking, det F > 0) from each solution interpolated to the next mesh."""
    positions = None
    for coarse, m in zip((None, *levels), levels):
        mesh = beam(m)
        fem = NeoHookeanFEM(mesh, Material(E, NU, RHO))
        control = clamped(mesh)
        if coarse is None:
            positions = fem.solve(control, (0.0, -GRAVITY, 0.0), load_steps=4).positions
            continue
        x = mesh.nodes + displacement_at(beam(coarse), positions, mesh.nodes)
        load = (fem.mass[:, None] * np.array([0.0, -GRAVITY, 0.0])).ravel()
        free = np.flatnonzero(~control.fixed.ravel())
        for _ in range(30):
            residual = fem.internal_forces(x).ravel() - load
            norm = np.linalg.norm(residual[free])
            if norm < 1e-9 * np.linalg.norm(load):
                break
            step = spla.splu(fem.tangent_stiffness(x).tocsr()[free][:, free].tocsc()).solve(-residual[free])
            length = 1.0
            while True:
                trial = x.copy()
                trial.ravel()[free] += length * step
                if fem.min_jacobian(trial) > 0 and np.linalg.norm(
                        (fem.internal_forces(trial).ravel() - load)[free]) < (1 - 1e-4 * length) * norm:
                    break
                length *= 0.5
                assert length > 1e-6, "line search failed"
            x = trial
        else:
            raise AssertionError(f"the {mesh.shape} reference did not converge")
        positions = x
    return beam(levels[-1]), positions


def test_refinement_error_falls_and_every_equilibrium_is_stable():
    """Refining the 30%-deflection cantilever from 5x1x1 to 20x4x4 elements: %e_dm at the 54 nodes
    of the coarsest mesh (rms |u - u_ref| / max |u_ref|) against fem-neohookean on 40x8x8 falls with
    every refinement, is below 2% on 20x4x4, and every equilibrium has a positive lowest tangent
    eigenvalue. Measured against this reference 11.3, 3.7, 1.6, 0.70 (lowest eigenvalues 0.73 to
    0.031 N/m; figure 14, against 60x12x12: 11.58, 4.02, 1.89, 1.03, the 40x8x8 FEM 0.34 from
    it); baudet 31.4 to 5.1, a saddle on three of the four meshes."""
    fine, reference = neo_hookean_reference()
    points = beam(1).nodes
    u_ref = displacement_at(fine, reference, points)
    assert -u_ref[np.isclose(points[:, 0], 1.0), 1].mean() == pytest.approx(0.3, abs=0.02)  # 30% of the length
    errors = []
    for m in (1, 2, 3, 4):
        mesh = beam(m)
        model = build_model(mesh, Material(E, NU, RHO), model=MODEL, gravity=(0.0, -GRAVITY, 0.0))
        result = solve_static(model, clamped(mesh), load_steps=4, check_stability=True)
        assert result.converged
        assert result.lowest_eigenvalue > 0, (m, result.lowest_eigenvalue)
        distance = np.linalg.norm(displacement_at(mesh, result.positions, points) - u_ref, axis=1)
        errors.append(np.sqrt(np.mean(distance**2)) / np.linalg.norm(u_ref, axis=1).max() * 100)
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 2.0, errors


def rotation(axis, angle_deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.radians(angle_deg)
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def moved_cantilever(turn, offset, gravity, increments=8):
    """6x2x2 cantilever (nu = 0.45) clamped at Q X + c, 1 N on each tip node plus its weight under
    ``gravity`` (m/s^2, as nodal forces m_a g on the model's lumped masses, so that both loads ramp),
    both rotated by Q, solved from the moved rest state Q X + c with the loads ramped in ``increments``."""
    mesh = HexMesh.block((6, 2, 2), 0.1)
    model = build_model(mesh, Material(E, 0.45, RHO), model=MODEL)
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    tip = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.6))
    positions = mesh.nodes @ turn.T + offset
    control = Control.free(mesh.n_nodes).impose(clamp, positions[clamp])
    load = np.zeros((mesh.n_nodes, 3))
    load[tip, 1] = -1.0
    load[:, 1] -= model.mass * gravity
    for step in range(1, increments + 1):
        control.force[:] = (load @ turn.T) * step / increments
        # max_iterations: from the exact rest state the chord iterations need 41 for the first increment
        result = solve_static(model, control, initial=positions, max_iterations=100)
        assert result.converged, result.message
        positions = result.positions
    return mesh, positions


@pytest.mark.parametrize("angle", [30.0, 90.0, 180.0])
def test_objectivity_of_a_loaded_block_rotated_through_its_boundary_conditions(angle):
    """Figure 13's protocol, with gravity added: the same loaded cantilever with its clamp, tip loads
    and gravity moved by x -> Q x + c (angle about the oblique axis (1, 2, -0.5)) lands on Q x + c of
    the unmoved answer to 0.1% of its largest displacement, 0.45 m (measured 5e-13 to 9e-13 %; in
    figure 13, baudet with hourglass_control=1: up to 18%)."""
    offset = np.array([0.1, -0.2, 0.3])
    mesh, plain = moved_cantilever(np.eye(3), np.zeros(3), gravity=0.2)
    largest = np.linalg.norm(plain - mesh.nodes, axis=1).max()
    assert largest > 0.1
    turn = rotation([1.0, 2.0, -0.5], angle)
    _, turned = moved_cantilever(turn, offset, gravity=0.2)
    assert np.linalg.norm(turned - (plain @ turn.T + offset), axis=1).max() < 1e-3 * largest
