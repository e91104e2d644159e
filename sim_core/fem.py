"""Linear-elastic trilinear hexahedral finite elements on the same nodes: the accuracy reference.

Element matrices from ``sim_core.elements`` (full 2x2x2 Gauss integration, isotropic Hooke law per
element, small-displacement theory). The global matrix reuses the mass-spring model's fixed
sparsity pattern (``BlockPattern``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from .elements import element_stiffness
from .material import Material
from .mesh import HexMesh
from .model import Control
from .sparse import BlockPattern


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
