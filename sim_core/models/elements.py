"""Element stiffness of linear-elastic finite elements: the formula shared by the FEM references
(``sim_core.solvers.fem``, ``sim_core.solvers.hyperelastic``) and the mass-spring model's hourglass control
(``sim_core.models.model``).

Two element kinds, told apart by the nodes per element (``elements.shape[1]``): trilinear
hexahedra (8 nodes, full 2x2x2 Gauss integration) and linear tetrahedra (4 nodes, one point: their
shape-function gradients are constant, so that point is exact). Isotropic Hooke law per element,
small-displacement theory.
"""

from __future__ import annotations

import numpy as np

from .. import kernels
from ..geometry.mesh import CORNER_NEIGHBOURS, CORNER_SIGN, GAUSS_GRADIENTS

#: the element kinds by nodes per element
ELEMENT_NODES = {8: "hexahedron", 4: "tetrahedron"}


def nodes_per_element(elements) -> int:
    """4 or 8, the nodes per element of an (M, n) connectivity; ``ValueError`` for any other width."""
    width = int(np.shape(elements)[1]) if np.ndim(elements) == 2 else -1
    if width not in ELEMENT_NODES:
        raise ValueError(f"elements must be (M, 8) hexahedra or (M, 4) tetrahedra, got shape {np.shape(elements)}")
    return width


def corner_frames(elements):
    """(neighbours (C, 3), signs (C,)) of the corner frames whose signed volumes the inversion checks
    test (``kernels.any_inverted``): the 8 corner frames of a hexahedron, the single frame of
    node 0 of a tetrahedron."""
    if nodes_per_element(elements) == 8:
        return CORNER_NEIGHBOURS, CORNER_SIGN
    from ..geometry.tetmesh import TET_CORNER_NEIGHBOURS, TET_CORNER_SIGN

    return TET_CORNER_NEIGHBOURS, TET_CORNER_SIGN


def inversion_gradients(model) -> np.ndarray | None:
    """The mean shape-function gradients b_a (M, 8, 3) 1/m on which a model's inversion test is taken,
    or None for the corner test (``corner_frames``).

    A hexahedral model whose elements' energy is a function of their mean deformation gradient
    F = sum_a x_a (outer) b_a and of spring lengths ("baudet-hyperelastic", docs/physics.md section
    11) is defined while det F > 0: that is its test (``kernels.any_collapsed``). Its springs let a
    strongly compressed element fold a corner while its mean volume stays positive, and the
    equilibrium it reaches is the right one (a cantilever hanging 1.14 m under its own weight lands
    on converged neo-Hookean FEM with one corner folded: tests/test_hyperelastic_floors.py), so the
    corner test would reject a valid state. Every other model, and every tetrahedron (whose one
    frame is its F), keeps the corner test: the small-strain corrections of "baudet" assume unfolded elements."""
    correction = model.stress_correction
    if (correction is None or correction.law != "neo-hookean" or model.mesh.elements.shape[1] != 8
            or len(correction.mean_gradient) != len(model.mesh.elements)):
        return None
    return correction.mean_gradient


def inverted(model, positions) -> bool:
    """Whether ``positions`` (N, 3) m invert an element of ``model`` by its inversion test
    (``inversion_gradients``)."""
    elements = model.mesh.elements
    gradients = inversion_gradients(model)
    if gradients is None:
        return bool(kernels.any_inverted(positions, elements, *corner_frames(elements)))
    return bool(kernels.any_collapsed(positions, elements, np.ascontiguousarray(gradients)))


def quadrature(nodes: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gradients (M, P, n, 3) dN/dX in 1/m, weights (M, P) in m^3) at the integration points of
    each element: 2x2x2 Gauss points for hexahedra (weight det J / 8 on the unit cube), the single
    exact point of a linear tetrahedron (weight its volume, gradients (Dm^-T) of its barycentric
    coordinates, Dm = [x1 - x0, x2 - x0, x3 - x0]). Raises ``ValueError`` for a non-positive
    Jacobian (an inverted or degenerate element)."""
    corners = nodes[elements]
    if nodes_per_element(elements) == 4:
        frame = (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)  # Dm, columns x_a - x_0
        det = np.linalg.det(frame)
        if np.any(det <= 0):
            raise ValueError("inverted or degenerate tetrahedron: non-positive volume")
        inverse = np.linalg.inv(frame)  # row a - 1: grad N_a, a = 1, 2, 3
        gradients = np.concatenate([-inverse.sum(axis=1, keepdims=True), inverse], axis=1)
        return gradients[:, None], (det / 6.0)[:, None]
    jac = np.einsum("mna,pnb->mpab", corners, GAUSS_GRADIENTS)  # dx/dxi
    det = np.linalg.det(jac)
    if np.any(det <= 0):
        raise ValueError("inverted or degenerate element: non-positive Jacobian at a Gauss point")
    # dN/dx = dN/dxi J^-1
    gradients = np.einsum("pnb,mpba->mpna", GAUSS_GRADIENTS, np.linalg.inv(jac))
    return gradients, det / GAUSS_GRADIENTS.shape[0]  # Gauss weights on [0, 1]^3 are 1/8


def elasticity_matrices(young_modulus, poisson_ratio) -> np.ndarray:
    """(M, 6, 6) isotropic Hooke matrices (Pa) in Voigt order xx, yy, zz, xy, yz, zx (engineering shear)."""
    nu = np.asarray(poisson_ratio, dtype=float)
    lame = young_modulus * nu / ((1 + nu) * (1 - 2 * nu))
    shear = young_modulus / (2 * (1 + nu))
    d = np.zeros((len(nu), 6, 6))
    d[:, :3, :3] = lame[:, None, None]
    d[:, np.arange(3), np.arange(3)] += 2 * shear[:, None]
    d[:, np.arange(3, 6), np.arange(3, 6)] = shear[:, None]
    return d


def strain_displacement(gradients: np.ndarray) -> np.ndarray:
    """(..., 6, 3n) Voigt strain-displacement matrices B (1/m; rows xx, yy, zz, xy, yz, zx with
    engineering shear, node-major dofs x0 y0 z0 x1 ...) of shape-function gradients (..., n, 3)."""
    shape, n_nodes = gradients.shape[:-2], gradients.shape[-2]
    b = np.zeros(shape + (6, n_nodes, 3))
    for axis in range(3):
        b[..., axis, :, axis] = gradients[..., axis]
    for row, (p, q) in zip((3, 4, 5), ((0, 1), (1, 2), (2, 0))):
        b[..., row, :, p] = gradients[..., q]
        b[..., row, :, q] = gradients[..., p]
    return b.reshape(shape + (6, 3 * n_nodes))


def element_stiffness(nodes: np.ndarray, elements: np.ndarray, young_modulus, poisson_ratio) -> np.ndarray:
    """(M, 3n, 3n) element stiffness matrices in N/m (node-major dofs: x0 y0 z0 x1 ...), n = 8
    (hexahedra) or 4 (tetrahedra)."""
    grad, weight = quadrature(nodes, elements)
    b = strain_displacement(grad)
    d = elasticity_matrices(young_modulus, poisson_ratio)
    # sum_p w_p B_p^T D B_p as batched matrix products (BLAS; a 4-operand einsum is much slower)
    stress = np.matmul(d[:, None], b)  # (M, P, 6, 3n)
    return np.matmul(b.transpose(0, 1, 3, 2) * weight[:, :, None, None], stress).sum(axis=1)


def element_block_positions(pattern, elements: np.ndarray) -> np.ndarray:
    """(M, n, n, 3, 3) positions in ``pattern``'s (``sparse.BlockPattern``) data of every element's
    node-pair blocks."""
    n = elements.shape[1]
    return pattern.block_positions(np.repeat(elements[:, :, None], n, axis=2),
                                   np.repeat(elements[:, None, :], n, axis=1))


def element_blocks(matrices: np.ndarray, n: int) -> np.ndarray:
    """(M, n, n, 3, 3) node-pair blocks of (M, 3n, 3n) element matrices (node-major dofs)."""
    return matrices.reshape(-1, n, 3, n, 3).transpose(0, 1, 3, 2, 4)
