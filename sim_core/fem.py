"""Linear-elastic trilinear hexahedral finite elements on the same nodes: the accuracy reference.

Full 2x2x2 Gauss integration, isotropic Hooke law per element, small-displacement theory. The
global matrix reuses the mass-spring model's fixed sparsity pattern (``BlockPattern``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from .material import Material
from .mesh import GAUSS_GRADIENTS, HexMesh
from .model import Control
from .sparse import BlockPattern


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
    # sum_p w_p B_p^T D B_p as batched matrix products (BLAS; a 4-operand einsum took 10x longer)
    stress = np.matmul(d[:, None], b)  # (M, P, 6, 24)
    return np.matmul(b.transpose(0, 1, 3, 2) * weight[:, :, None, None], stress).sum(axis=1)


@dataclass
class LinearFEM:
    """Linear-elastic FEM model of a hex mesh (K assembled once, factorised per constraint set)."""

    mesh: HexMesh
    material: Material

    def __post_init__(self):
        props = self.material.per_element(self.mesh.n_elements)
        self.pattern = BlockPattern(self.mesh.n_nodes, self.mesh.elements)
        elements = self.mesh.elements
        positions = self.pattern.block_positions(
            np.repeat(elements[:, :, None], 8, axis=2), np.repeat(elements[:, None, :], 8, axis=1)
        )
        ke = element_stiffness(self.mesh.nodes, elements, props["young_modulus"], props["poisson_ratio"])
        blocks = ke.reshape(-1, 8, 3, 8, 3).transpose(0, 1, 3, 2, 4)
        self.stiffness = self.pattern.matrix(self.pattern.assemble(positions, blocks))
        volume = self.mesh.element_volumes()
        self.mass = np.bincount(elements.ravel(), weights=np.repeat(props["density"] * volume / 8, 8),
                                minlength=self.mesh.n_nodes)

    def solve(self, control: Control, gravity=(0.0, 0.0, 0.0)):
        """Static linear solution. Returns (positions (N, 3) m, reaction (N, 3) N).

        Loads: the control's nodal forces plus gravity on the lumped masses (for trilinear
        elements this equals the consistent body load of a uniform field).
        """
        nodes = self.mesh.nodes
        load = (control.force + self.mass[:, None] * np.asarray(gravity, dtype=float)[None, :]).ravel()
        fixed = control.fixed.ravel()
        free = np.flatnonzero(~fixed)
        imposed = np.zeros(nodes.size)
        imposed[fixed] = (control.target - nodes).ravel()[fixed]
        k = self.stiffness.tocsr()
        rhs = load[free] - k[free][:, fixed] @ imposed[fixed]
        displacement = imposed.copy()
        displacement[free] = spla.splu(k[free][:, free].tocsc()).solve(rhs)
        internal = k @ displacement
        reaction = np.where(fixed, internal - load, 0.0).reshape(-1, 3)
        return nodes + displacement.reshape(-1, 3), reaction
