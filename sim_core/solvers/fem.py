"""Linear-elastic finite elements on the same nodes: the accuracy reference ("fem-linear").

Trilinear hexahedra (``HexMesh``) or linear tetrahedra (``TetMesh``); element matrices from
``sim_core.models.elements`` (hexahedra: full 2x2x2 Gauss integration; tetrahedra: exact one-point),
isotropic Hooke law per element, small-displacement theory. The global matrix reuses the mass-spring model's fixed
sparsity pattern (``BlockPattern``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from ..models.elements import element_block_positions, element_blocks, element_stiffness
from ..models.material import Material
from ..geometry.mesh import HexMesh
from ..geometry.tetmesh import TetMesh
from ..models.model import Control
from ..models.sparse import BlockPattern


@dataclass
class LinearFEM:
    """Linear-elastic FEM model of a hexahedral or tetrahedral mesh (K assembled once, factorised per
    constraint set)."""

    mesh: HexMesh | TetMesh
    material: Material

    def __post_init__(self):
        props = self.material.per_element(self.mesh.n_elements)
        self.pattern = BlockPattern(self.mesh.n_nodes, self.mesh.elements)
        elements = self.mesh.elements
        n = elements.shape[1]
        positions = element_block_positions(self.pattern, elements)
        ke = element_stiffness(self.mesh.nodes, elements, props["young_modulus"], props["poisson_ratio"])
        self.stiffness = self.pattern.matrix(self.pattern.assemble(positions, element_blocks(ke, n)))
        volume = self.mesh.element_volumes()
        self.mass = np.bincount(elements.ravel(), weights=np.repeat(props["density"] * volume / n, n),
                                minlength=self.mesh.n_nodes)

    def solve(self, control: Control, gravity=(0.0, 0.0, 0.0)):
        """Static linear solution. Returns (positions (N, 3) m, reaction (N, 3) N).

        Loads: the control's nodal forces plus gravity on the lumped masses rho V / n (for
        trilinear hexahedra and linear tetrahedra this equals the consistent body load of a
        uniform field).
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
