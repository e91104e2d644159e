"""Hexahedral meshes: the validation experiments' structured block and general 8-node hex meshes.

Node order of a hexahedron is VTK's: 0 (0,0,0), 1 (1,0,0), 2 (1,1,0), 3 (0,1,0), 4 (0,0,1),
5 (1,0,1), 6 (1,1,1), 7 (0,1,1) in local coordinates. Lengths are in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import kernels
from ._validate import finite_array
from .topology import (  # noqa: F401  (re-exported: the names mesh users import)
    CORNER_NEIGHBOURS, CORNER_SIGN, DIAGONALS, EDGE_AXIS, EDGES, FACES, GAUSS_GRADIENTS, GAUSS_POINTS,
    LOCAL_CORNERS, shape_gradients,
)


def _parse_spacing(spacing) -> np.ndarray:
    spacing = finite_array("spacing", np.broadcast_to(np.asarray(spacing, dtype=float), (3,)))
    if np.any(spacing <= 0):
        raise ValueError(f"spacing must be > 0 m along every axis, got {spacing.tolist()}")
    return spacing.copy()


def _parse_shape(shape) -> tuple[int, int, int]:
    try:
        values = tuple(int(s) for s in shape)
    except (TypeError, ValueError) as error:
        raise ValueError(f"shape must be three positive integers (nx, ny, nz), got {shape!r}") from error
    if len(values) != 3 or any(v < 1 for v in values) or any(float(s) != v for s, v in zip(shape, values)):
        raise ValueError(f"shape must be three positive integers (nx, ny, nz), got {shape!r}")
    return values


@dataclass(frozen=True)
class HexMesh:
    """An unstructured mesh of trilinear hexahedra.

    Args:
        nodes: (N, 3) rest positions in m.
        elements: (M, 8) node indices per hexahedron, VTK order.
        shape: (nx, ny, nz) when the mesh is a structured block, else None.
        spacing: (dx, dy, dz) in m when the mesh is a structured block, else None.

    Raises ``ValueError`` for wrong shapes, out-of-range indices, repeated nodes in an element, and
    degenerate or inverted elements (a corner Jacobian that is not positive).
    """

    nodes: np.ndarray
    elements: np.ndarray
    shape: tuple[int, int, int] | None = None
    spacing: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        nodes = finite_array("nodes", self.nodes, shape=(-1, 3))
        try:
            elements = np.asarray(self.elements)
        except (TypeError, ValueError) as error:
            raise ValueError("elements must be an (M, 8) integer array") from error
        if elements.ndim != 2 or elements.shape[1] != 8 or len(elements) == 0:
            raise ValueError(f"elements must have shape (M, 8) with M >= 1, got {elements.shape}")
        if not np.issubdtype(elements.dtype, np.integer):
            if not np.all(np.equal(np.mod(elements, 1), 0)):
                raise ValueError("elements must hold integer node indices")
        elements = elements.astype(np.int64)
        if elements.min() < 0 or elements.max() >= len(nodes):
            raise ValueError(
                f"element node indices must lie in [0, {len(nodes) - 1}], got "
                f"[{elements.min()}, {elements.max()}]"
            )
        if np.any(np.diff(np.sort(elements, axis=1), axis=1) == 0):
            bad = int(np.nonzero(np.any(np.diff(np.sort(elements, axis=1), axis=1) == 0, axis=1))[0][0])
            raise ValueError(f"degenerate element {bad}: a node appears twice in {elements[bad].tolist()}")
        nodes.setflags(write=False)
        elements.setflags(write=False)
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "elements", elements)
        check_elements(nodes, elements)

    # -- construction ----------------------------------------------------------------------
    @classmethod
    def block(cls, shape, spacing=0.1) -> "HexMesh":
        """Structured block of ``shape = (nx, ny, nz)`` hexahedra with ``spacing`` metres.

        Occupies [0, nx dx] x [0, ny dy] x [0, nz dz]; node (i, j, k) sits at (i dx, j dy, k dz)
        and has index i + (nx + 1) (j + (ny + 1) k): the node order of the experiments' contract,
        x fastest, then y, then z.
        """
        nx, ny, nz = _parse_shape(shape)
        spacing = _parse_spacing(spacing)
        i, j, k = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij")
        grid = np.stack([i.ravel(order="F"), j.ravel(order="F"), k.ravel(order="F")], axis=1)
        nodes = grid * spacing
        ei, ej, ek = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
        base = np.stack([ei.ravel(order="F"), ej.ravel(order="F"), ek.ravel(order="F")], axis=1)
        corner = base[:, None, :] + LOCAL_CORNERS.astype(int)[None, :, :]
        elements = corner[..., 0] + (nx + 1) * (corner[..., 1] + (ny + 1) * corner[..., 2])
        return cls(nodes, elements, shape=(nx, ny, nz), spacing=spacing)

    # -- geometry --------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_elements(self) -> int:
        return len(self.elements)

    @property
    def size(self) -> np.ndarray:
        """Extent of the bounding box in m."""
        return self.nodes.max(axis=0) - self.nodes.min(axis=0)

    def box_shares(self, low, high) -> np.ndarray:
        """(M,) share of each element's volume inside the axis-aligned box [low, high] (m): exact
        for axis-aligned hexahedra (a block's), computed on the elements' bounding boxes otherwise.
        A material region given as a box then does not depend on where the mesh's nodes fall."""
        corners = self.nodes[self.elements]
        lo, hi = corners.min(axis=1), corners.max(axis=1)
        overlap = np.clip(np.minimum(hi, np.asarray(high, float)) - np.maximum(lo, np.asarray(low, float)), 0.0, None)
        share = np.prod(overlap, axis=1) / np.prod(hi - lo, axis=1)
        return np.where(share > 1e-9, share, 0.0)  # a box face on an element face: rounding, not overlap

    def element_volumes(self, positions=None) -> np.ndarray:
        """(M,) volumes in m^3, exact for trilinear hexahedra (the compiled closed form
        ``kernels.element_volumes``, equal to 2x2x2 Gauss on det J, ``hex_volumes``)."""
        positions = self.nodes if positions is None else positions
        positions = np.ascontiguousarray(positions, dtype=float)
        if positions.shape != self.nodes.shape:
            raise ValueError(f"positions must have shape {self.nodes.shape}, got {positions.shape}")
        return kernels.element_volumes(positions, self.elements, np.empty(self.n_elements))

    def surface_faces(self) -> np.ndarray:
        """(F, 4) node indices of the boundary quads, outward oriented (faces used by one element)."""
        faces = self.elements[:, FACES].reshape(-1, 4)
        key = np.sort(faces, axis=1)
        _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
        return faces[np.sort(index[counts == 1])]

    def surface_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes on the boundary surface."""
        return np.unique(self.surface_faces())

    def node_index(self, i, j, k):
        """Index of structured-block node (i, j, k) (only for meshes built by ``block``)."""
        if self.shape is None:
            raise ValueError("node_index needs a structured block mesh (HexMesh.block)")
        nx, ny, _ = self.shape
        return np.asarray(i) + (nx + 1) * (np.asarray(j) + (ny + 1) * np.asarray(k))

    # -- files -----------------------------------------------------------------------------
    def write(self, path, point_data: dict | None = None, positions=None) -> None:
        """Write the mesh (optionally deformed ``positions`` and ``point_data``) with meshio.

        The format follows the extension: .vtu, .msh (Gmsh 4.1, binary: meshio's ASCII reader
        cannot read point data back), .vtk, .xdmf, ...
        """
        import meshio

        points = self.nodes if positions is None else finite_array("positions", positions, (self.n_nodes, 3))
        mesh = meshio.Mesh(points, [("hexahedron", self.elements)], point_data=point_data or {})
        path = Path(path)
        if path.suffix == ".msh":
            meshio.write(path, mesh, file_format="gmsh", binary=True)
        else:
            meshio.write(path, mesh)

    @classmethod
    def read(cls, path) -> "HexMesh":
        """Read the hexahedra of a mesh file with meshio (.msh, .vtu, .vtk, ...).

        Raises ``FileNotFoundError`` when ``path`` does not exist (as ``open`` does) and
        ``ValueError``, naming the file, for everything else that is wrong with it: not a file, an
        extension meshio does not read, an empty file, one meshio cannot parse as its format
        (corrupt, truncated, another format; chained from meshio's error, including the
        ``SystemExit`` some of meshio's readers raise), no hexahedra in it (the cell types found
        are listed), or hexahedra that do not form a valid mesh (``HexMesh``'s checks).
        """
        import contextlib
        import io

        import meshio
        from meshio._helpers import _filetypes_from_path  # the extension lookup meshio.read uses

        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(2, "mesh file not found", str(path))
        if not path.is_file():
            raise ValueError(f"{path} is not a file: HexMesh.read needs a mesh file (.vtu, .vtk, .msh, ...)")
        try:
            formats = _filetypes_from_path(path)
        except Exception as error:
            extension = repr("".join(path.suffixes)) if path.suffix else "(none)"
            raise ValueError(
                f"{path}: unsupported mesh file extension {extension}; HexMesh.read "
                "reads meshio's formats that hold hexahedra, e.g. .vtu, .vtk, .msh (Gmsh), .xdmf, .med, .inp"
            ) from error
        file_format = f"{path.suffix} ({' or '.join(formats)})" if len(formats) > 1 else f"{path.suffix} ({formats[0]})"
        if path.stat().st_size == 0:
            raise ValueError(f"{path} is empty (0 bytes): not a {file_format} mesh; write one with HexMesh.write")
        log = io.StringIO()
        try:
            with contextlib.redirect_stderr(log), contextlib.redirect_stdout(log):
                mesh = meshio.read(path)
        except (Exception, SystemExit) as error:  # meshio's vtu/vtk readers exit on a bad file
            detail = " ".join((log.getvalue() + " " + (str(error) if not isinstance(error, SystemExit) else "")).split())
            raise ValueError(
                f"{path} is not a readable {file_format} mesh (corrupt, truncated or another format): "
                f"{type(error).__name__}{': ' + detail if detail else ''}"
            ) from error
        blocks = [np.asarray(cells.data) for cells in mesh.cells if cells.type == "hexahedron"]
        if not blocks:
            found = ", ".join(f"{len(cells.data)} {cells.type}" for cells in mesh.cells) or "no cells at all"
            raise ValueError(f"{path} contains no hexahedra (found {found}); HexMesh needs 8-node hexahedral "
                             "cells (meshio type 'hexahedron')")
        points = np.asarray(mesh.points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"{path}: points must be 3D, (N, 3) coordinates in m; got an array of shape {points.shape}")
        bad = int(np.size(points) - np.count_nonzero(np.isfinite(points)))
        if bad:
            raise ValueError(f"{path}: {bad} point coordinates are not finite (NaN or infinity); they must be numbers in m")
        try:
            return cls(points, np.concatenate(blocks))
        except ValueError as error:
            raise ValueError(f"{path}: its hexahedra do not form a valid mesh: {error}") from error

    def write_obj(self, path, positions=None) -> None:
        """Export the boundary surface as a Wavefront .obj of quads (positions in m)."""
        points = self.nodes if positions is None else np.asarray(positions, dtype=float)
        faces = self.surface_faces()
        used, inverse = np.unique(faces, return_inverse=True)
        lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in points[used]]
        lines += ["f " + " ".join(str(i + 1) for i in quad) for quad in inverse.reshape(-1, 4)]
        Path(path).write_text("\n".join(lines) + "\n")


# -- element geometry (vectorised over elements) ---------------------------------------------
def hex_jacobians(positions: np.ndarray, elements: np.ndarray, gradients=GAUSS_GRADIENTS) -> np.ndarray:
    """(M, P, 3, 3) Jacobians dx/dxi at the given reference points (rows: x, columns: xi)."""
    corners = positions[elements]  # (M, 8, 3)
    n_points = gradients.shape[0]
    # J[m, p, a, b] = sum_n corners[m, n, a] gradients[p, n, b], as one batched matmul
    flat = gradients.transpose(1, 0, 2).reshape(8, n_points * 3)
    return (corners.transpose(0, 2, 1) @ flat).reshape(-1, 3, n_points, 3).transpose(0, 2, 1, 3)


def hex_volumes(positions: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(M,) exact volumes of trilinear hexahedra in m^3."""
    return np.linalg.det(hex_jacobians(positions, elements)).mean(axis=1)


def corner_jacobians(positions: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(M, 8) signed volumes of the 8 corner tetrahedra frames (m^3); positive when valid."""
    corners = positions[elements]
    edges = corners[:, CORNER_NEIGHBOURS, :] - corners[:, :, None, :]  # (M, 8, 3, 3)
    return CORNER_SIGN * np.linalg.det(edges)


def check_elements(positions: np.ndarray, elements: np.ndarray, name: str = "element") -> None:
    """Raise ``ValueError`` when an element is degenerate or inverted (corner Jacobian <= 0)."""
    det = corner_jacobians(positions, elements)
    scale = np.abs(det).max(axis=1)
    if np.any(scale == 0):
        bad = int(np.argmax(scale == 0))
        raise ValueError(f"degenerate {name} {bad}: zero volume")
    relative = det / scale[:, None]
    tolerance = 1e-10
    if np.any(relative <= tolerance):
        bad = int(np.argmax(np.any(relative <= tolerance, axis=1)))
        kind = "inverted" if np.any(relative[bad] < -tolerance) else "degenerate"
        raise ValueError(
            f"{kind} {name} {bad}: corner Jacobians {np.round(det[bad], 12).tolist()} must all be > 0 "
            "(VTK node order: 0-1-2-3 counter-clockwise seen from 4-5-6-7)"
        )
