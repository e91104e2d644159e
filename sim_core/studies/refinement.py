"""Refinement and objectivity checks of the block experiments: a structured block's displacement at
material points (to compare solutions on different meshes of one block), a neo-Hookean reference
carried from a coarse mesh to finer ones by Newton, and the rigid rotations of the objectivity
checks. Used by benchmarks/validation.py (figures 13 and 14) and tests/test_hyperelastic_floors.py.
SI units: m, m/s^2, N.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla
from scipy.interpolate import RegularGridInterpolator

from ..geometry.mesh import HexMesh
from ..models.material import Material
from ..models.model import Control
from ..solvers.hyperelastic import NeoHookeanFEM


def clamped_control(mesh) -> Control:
    """The cantilever's control: the nodes of the face x = 0 held at rest, every other node free."""
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    return Control.free(mesh.n_nodes).impose(clamp, mesh.nodes[clamp])


def block_displacement_at(mesh: HexMesh, positions, points) -> np.ndarray:
    """Displacement (P, 3) m of a structured block solution ``positions`` (N, 3) at material
    ``points`` (P, 3) (rest coordinates, m; clipped to the block), trilinear in the block's cells
    (node (i, j, k) at index i + (nx + 1) (j + (ny + 1) k))."""
    nx, ny, nz = mesh.shape
    u = (positions - mesh.nodes).reshape(nz + 1, ny + 1, nx + 1, 3).transpose(2, 1, 0, 3)
    axes = [np.linspace(0.0, mesh.size[a], mesh.shape[a] + 1) for a in range(3)]
    return RegularGridInterpolator(axes, u)(np.clip(points, 0.0, mesh.size))


def displacement_errors(mesh: HexMesh, positions, reference, points) -> tuple[float, float]:
    """(%e_dm, %e_max) at material ``points``: the rms and the largest |u - u_ref| over the largest
    |u_ref|, in %, with u the block solution's displacement there (``block_displacement_at``) and
    ``reference`` (P, 3) u_ref in m."""
    distance = np.linalg.norm(block_displacement_at(mesh, positions, points) - reference, axis=1)
    scale = np.linalg.norm(reference, axis=1).max()
    return float(np.sqrt(np.mean(distance**2)) / scale * 100), float(distance.max() / scale * 100)


def neo_hookean_newton(fem: NeoHookeanFEM, control: Control, gravity: float, start, tolerance: float = 1e-9,
                       max_iterations: int = 30) -> tuple[np.ndarray, int]:
    """Static equilibrium of ``fem`` under gravity (0, -gravity, 0) m/s^2 and ``control``'s forces by
    Newton from ``start`` (N, 3) m: the consistent tangent, and a step halved (up to 30 times) until
    every element keeps det F > 0 and the residual norm falls. Stops when the free dofs' residual is
    below ``tolerance`` times the load's norm. Returns (positions, iterations); raises RuntimeError
    when ``max_iterations`` are not enough."""
    x = np.array(start, float)
    x[control.fixed] = control.target[control.fixed]
    load = (fem.mass[:, None] * np.array([0.0, -gravity, 0.0])[None, :] + control.force).ravel()
    free = np.flatnonzero(~control.fixed.ravel())
    scale = np.linalg.norm(load)
    for iteration in range(max_iterations):
        residual = fem.internal_forces(x).ravel() - load
        norm = np.linalg.norm(residual[free])
        if norm < tolerance * scale:
            return x, iteration
        stiffness = fem.tangent_stiffness(x).tocsr()[free][:, free].tocsc()
        step = spla.splu(stiffness, permc_spec="MMD_AT_PLUS_A").solve(-residual[free])
        length = 1.0
        for _ in range(30):
            trial = x.copy()
            trial.ravel()[free] += length * step
            if (fem.min_jacobian(trial) > 0
                    and np.linalg.norm((fem.internal_forces(trial).ravel() - load)[free]) < (1 - 1e-4 * length) * norm):
                break
            length *= 0.5
        x = trial
    raise RuntimeError("the neo-Hookean reference did not converge")


def neo_hookean_chain(meshes, material: Material, gravity: float, control=clamped_control) -> list:
    """fem-neohookean's equilibria under gravity (0, -gravity, 0) m/s^2 on the structured blocks
    ``meshes`` (one block, coarse to fine), each held by ``control(mesh)``: the first solved from rest
    (``NeoHookeanFEM.solve``, 4 load steps), each next one by ``neo_hookean_newton`` from the previous
    one's displacement interpolated onto it (a fine mesh's Newton from rest may not converge).
    Returns the positions (N, 3) m of each mesh."""
    out, previous = [], None
    for mesh in meshes:
        fem = NeoHookeanFEM(mesh, material)
        if previous is None:
            positions = fem.solve(control(mesh), (0.0, -gravity, 0.0), load_steps=4).positions
        else:
            start = mesh.nodes + block_displacement_at(previous, out[-1], mesh.nodes)
            positions = neo_hookean_newton(fem, control(mesh), gravity, start)[0]
        out.append(positions)
        previous = mesh
    return out


def moved_cantilever(turn, offset) -> tuple[HexMesh, np.ndarray, Control, np.ndarray]:
    """The objectivity checks' cantilever moved by the rigid motion x -> Q x + c (``turn`` Q (3, 3),
    ``offset`` c m): a 6x2x2 block of 0.1 m cubes, its face x = 0 clamped at Q X + c. Returns (mesh,
    the moved rest positions Q X + c, the control, the tip load (N, 3) N before rotation: 1 N along
    -y on each node of the face x = 0.6 m)."""
    mesh = HexMesh.block((6, 2, 2), 0.1)
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    tip = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.6))
    start = mesh.nodes @ np.asarray(turn).T + offset
    control = Control.free(mesh.n_nodes).impose(clamp, start[clamp])
    load = np.zeros((mesh.n_nodes, 3))
    load[tip, 1] = -1.0
    return mesh, start, control, load


def rotation_matrix(axis, angle_deg: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_deg`` degrees about ``axis`` (any length): Rodrigues' formula."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.radians(angle_deg)
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
