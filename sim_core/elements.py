"""Element stiffness of linear-elastic trilinear hexahedra: the formula shared by the FEM reference
(``sim_core.fem``) and the mass-spring model's hourglass control (``sim_core.model``).

Full 2x2x2 Gauss integration, isotropic Hooke law per element, small-displacement theory.
"""

from __future__ import annotations

import numpy as np

from .mesh import GAUSS_GRADIENTS


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


def element_stiffness(nodes: np.ndarray, elements: np.ndarray, young_modulus, poisson_ratio) -> np.ndarray:
    """(M, 24, 24) element stiffness matrices in N/m (node-major dofs: x0 y0 z0 x1 ...)."""
    corners = nodes[elements]
    jac = np.einsum("mna,pnb->mpab", corners, GAUSS_GRADIENTS)  # dx/dxi
    det = np.linalg.det(jac)
    if np.any(det <= 0):
        raise ValueError("inverted or degenerate element: non-positive Jacobian at a Gauss point")
    # dN/dx = dN/dxi J^-1
    grad = np.einsum("pnb,mpba->mpna", GAUSS_GRADIENTS, np.linalg.inv(jac))
    n_elements, n_points = det.shape
    b = np.zeros((n_elements, n_points, 6, 8, 3))
    for axis in range(3):
        b[:, :, axis, :, axis] = grad[..., axis]
    for row, (p, q) in zip((3, 4, 5), ((0, 1), (1, 2), (2, 0))):
        b[:, :, row, :, p] = grad[..., q]
        b[:, :, row, :, q] = grad[..., p]
    b = b.reshape(n_elements, n_points, 6, 24)
    d = elasticity_matrices(young_modulus, poisson_ratio)
    weight = det / n_points  # Gauss weights on [0, 1]^3 are 1/8
    # sum_p w_p B_p^T D B_p as batched matrix products (BLAS; a 4-operand einsum is much slower)
    stress = np.matmul(d[:, None], b)  # (M, P, 6, 24)
    return np.matmul(b.transpose(0, 1, 3, 2) * weight[:, :, None, None], stress).sum(axis=1)
