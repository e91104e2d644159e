"""Tetrahedral meshes: linear (4-node) tetrahedra, and the structured block split into them.

Node order of a tetrahedron is positive: det[x1 - x0, x2 - x0, x3 - x0] > 0 (VTK's and Gmsh's
convention for a valid tetrahedron). ``TetMesh.block`` splits the cubes of ``HexMesh.block`` into six
tetrahedra each on the same nodes (the Kuhn, or Freudenthal, triangulation: every tetrahedron runs
along the cube's main diagonal from local (0, 0, 0) to (1, 1, 1)), so a tetrahedral and a
hexahedral model of one block can be compared node by node. Lengths are in metres.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .mesh import (
    LOCAL_CORNERS, HexMesh, MeshGeometry, boundary_faces, read_mesh_file, signed_volumes,
)

#: The 6 edges of a tetrahedron (local node pairs).
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
#: The 4 faces of a positively oriented tetrahedron, each outward (counter-clockwise seen from
#: outside); face f is the one opposite node 3 - f.
TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
#: The corner frame used for the inversion check: node 0's three neighbours, sign +1 (a tetrahedron
#: has a single signed volume).
TET_CORNER_NEIGHBOURS = np.array([[1, 2, 3]])
TET_CORNER_SIGN = np.array([1.0])


def _kuhn_tetrahedra() -> np.ndarray:
    """(6, 4) VTK corner indices (``mesh.LOCAL_CORNERS``) of the Kuhn split of the unit cube,
    positively oriented: for each permutation (p, q, r) of the axes, the path (0,0,0) -> +e_p ->
    +e_q -> +e_r = (1,1,1). Every cube of a block is split alike, so the split of a shared face is
    the same seen from both cubes (its diagonal through the corner of smallest coordinate sum and
    the one of largest): the tetrahedra conform across cubes."""
    index = {tuple(corner.astype(int)): n for n, corner in enumerate(LOCAL_CORNERS)}
    tets = []
    for order in itertools.permutations(range(3)):
        point = np.zeros(3, dtype=int)
        path = [index[tuple(point)]]
        for axis in order:
            point[axis] = 1
            path.append(index[tuple(point)])
        corners = LOCAL_CORNERS[path]
        if np.linalg.det(corners[1:] - corners[0]) < 0:
            path[1], path[2] = path[2], path[1]
        tets.append(path)
    return np.array(tets)


#: The Kuhn split of a hexahedron's 8 VTK corners into 6 positively oriented tetrahedra.
KUHN_TETRAHEDRA = _kuhn_tetrahedra()


def check_tetrahedra(positions: np.ndarray, elements: np.ndarray, name: str = "tetrahedron") -> None:
    """Raise ``ValueError`` when a tetrahedron is degenerate (zero volume to rounding) or inverted
    (negative orientation)."""
    volume = signed_volumes(positions, elements)
    corners = positions[elements]
    edges = corners[:, TET_EDGES[:, 1]] - corners[:, TET_EDGES[:, 0]]
    scale = np.linalg.norm(edges, axis=2).max(axis=1) ** 3  # volume of the longest edge's cube
    relative = volume / np.where(scale > 0, scale, 1.0)
    tolerance = 1e-10
    if np.any(relative <= tolerance):
        bad = int(np.argmax(relative <= tolerance))
        kind = "inverted" if relative[bad] < -tolerance else "degenerate"
        raise ValueError(
            f"{kind} {name} {bad} (nodes {elements[bad].tolist()}): signed volume {volume[bad]:.6g} m^3 must be > 0; "
            "the node order must be positive, det[x1 - x0, x2 - x0, x3 - x0] > 0 (swap two nodes to flip it)")


@dataclass(frozen=True)
class TetMesh(MeshGeometry):
    """An unstructured mesh of linear (4-node) tetrahedra.

    Args:
        nodes: (N, 3) rest positions in m.
        elements: (M, 4) node indices per tetrahedron, positively oriented
            (det[x1 - x0, x2 - x0, x3 - x0] > 0).
        shape: (nx, ny, nz) cubes when the mesh is a structured block split into tetrahedra, else None.
        spacing: (dx, dy, dz) in m when the mesh is a structured block, else None.
        element_labels: None, or (M,) integer label id per tetrahedron (``from_hex`` of a mesh
            from a voxel mask keeps its hexahedra's).

    Raises ``ValueError`` for wrong shapes, out-of-range indices, repeated nodes in an element, and
    degenerate or inverted tetrahedra.
    """

    nodes_per_element = 4
    element_name = "tetrahedron"
    cell_type = "tetra"

    check_geometry = staticmethod(check_tetrahedra)

    # -- construction ----------------------------------------------------------------------
    @classmethod
    def block(cls, shape, spacing=0.1) -> "TetMesh":
        """Structured block of ``shape = (nx, ny, nz)`` cubes of ``spacing`` m, each split into 6
        tetrahedra (``KUHN_TETRAHEDRA``) on the nodes of ``HexMesh.block(shape, spacing)``: node
        (i, j, k) at (i dx, j dy, k dz) has index i + (nx + 1) (j + (ny + 1) k). Cube c's
        tetrahedra are elements 6 c .. 6 c + 5."""
        return cls.from_hex(HexMesh.block(shape, spacing))

    @classmethod
    def from_hex(cls, mesh: HexMesh) -> "TetMesh":
        """The hexahedra of ``mesh`` each split into 6 tetrahedra on the same nodes (Kuhn split in
        each hexahedron's local axes). Conforming when neighbouring hexahedra share local axis
        directions (a structured block or a mesh from a voxel mask); keeps ``shape``, ``spacing``
        and ``element_labels`` (each tetrahedron its hexahedron's)."""
        if not isinstance(mesh, HexMesh):
            raise ValueError(f"from_hex needs a HexMesh, got {type(mesh).__name__}")
        elements = mesh.elements[:, KUHN_TETRAHEDRA].reshape(-1, 4)
        labels = None if mesh.element_labels is None else np.repeat(mesh.element_labels, len(KUHN_TETRAHEDRA))
        return cls(mesh.nodes.copy(), elements, shape=mesh.shape,
                   spacing=None if mesh.spacing is None else np.array(mesh.spacing), element_labels=labels)

    @classmethod
    def from_surface(cls, vertices, faces, **options) -> "TetMesh":
        """Fill a closed triangle surface (vertices (V, 3) m, faces (F, 3), outward
        counter-clockwise) with tetrahedra: ``sim_core.geometry.meshing.tetrahedralise`` (fTetWild, the
        ``[mesh]`` extra), whose keywords ``options`` passes on (``edge_length`` m,
        ``max_volume`` m^3, the quality limits ``max_radius_edge`` and ``min_mean_ratio``, ...).

        Raises ``ValueError`` for a surface that is not closed or tetrahedra outside the quality
        limits, ``ImportError`` naming the extra when pytetwild is missing."""
        from .meshing import tetrahedralise  # meshing builds on this module

        nodes, tets = tetrahedralise(vertices, faces, **options)
        return cls(nodes, tets)

    # -- geometry --------------------------------------------------------------------------
    def element_volumes(self, positions=None) -> np.ndarray:
        """(M,) signed volumes in m^3 (exact for linear tetrahedra; negative where inverted)."""
        positions = self.nodes if positions is None else np.asarray(positions, dtype=float)
        if positions.shape != self.nodes.shape:
            raise ValueError(f"positions must have shape {self.nodes.shape}, got {positions.shape}")
        return signed_volumes(positions, self.elements)

    def surface_faces(self) -> np.ndarray:
        """(F, 3) node indices of the boundary triangles (faces used by one tetrahedron), outward
        oriented: (x1 - x0) x (x2 - x0) points out of the mesh."""
        return boundary_faces(self.elements, TET_FACES)

    # -- files -----------------------------------------------------------------------------
    @classmethod
    def read(cls, path, **options) -> "TetMesh":
        """Read a mesh file with meshio: its tetrahedra (.vtu, .msh, .vtk, ...), or, when it holds
        a closed triangle surface and no tetrahedra (.stl, .obj, .ply, .off, ...), that surface
        filled with tetrahedra by ``from_surface`` (``options`` are its keywords; coordinates are
        taken as metres).

        Raises ``FileNotFoundError`` when ``path`` does not exist and ``ValueError``, naming the
        file, when meshio cannot read it (unsupported extension, empty, corrupt or another format),
        when it holds neither tetrahedra nor a surface (the cell types found are listed), when its
        tetrahedra do not form a valid mesh (``TetMesh``'s checks: e.g. an inverted tetrahedron) or
        when its surface is not closed."""
        path = Path(path)
        mesh, points = read_mesh_file(path, "TetMesh.read", "tetrahedra or a closed surface",
                                      "e.g. .vtu, .vtk, .msh (Gmsh), or a surface: .stl, .obj, .ply, .off",
                                      "TetMesh.write")
        if not any(cells.type == "tetra" for cells in mesh.cells) and any(
                cells.type in ("triangle", "quad") for cells in mesh.cells):
            from .meshing import surface_of  # meshing builds on this module

            try:
                return cls.from_surface(*surface_of(mesh, points, path), **options)
            except ValueError as error:
                raise ValueError(f"{path}: its surface cannot be filled with tetrahedra: {error}") from error
        if options:
            raise ValueError(f"{path} holds tetrahedra: the tetrahedralisation keywords {sorted(options)} apply only "
                             "to a surface file")
        return cls._from_cells(mesh, points, path, "tetrahedra", "TetMesh needs 4-node tetrahedral cells")
