"""Hexahedral meshes: the validation experiments' structured block and general 8-node hex meshes.

Node order of a hexahedron is VTK's: 0 (0,0,0), 1 (1,0,0), 2 (1,1,0), 3 (0,1,0), 4 (0,0,1),
5 (1,0,1), 6 (1,1,1), 7 (0,1,1) in local coordinates. Lengths are in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from .. import kernels
from .._validate import finite_array
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
class MeshGeometry:
    """What ``HexMesh`` and ``TetMesh`` share: their fields and the checks of their nodes and
    elements, counts, extent, boundary nodes, the structured block's node index and file output (a
    subclass names its element kind and has ``surface_faces``)."""

    nodes: np.ndarray
    elements: np.ndarray
    shape: tuple[int, int, int] | None = None
    spacing: np.ndarray | None = field(default=None, repr=False)
    #: None, or (M,) integer label id per element (a segmented volume's tissue classes);
    #: ``Material.from_labels`` turns them into materials
    element_labels: np.ndarray | None = field(default=None, repr=False)

    #: nodes per element, the element's name in messages and its meshio cell type
    nodes_per_element: ClassVar[int]
    element_name: ClassVar[str]
    cell_type: ClassVar[str]

    @staticmethod
    def check_geometry(positions: np.ndarray, elements: np.ndarray) -> None:
        """Raise ``ValueError`` for a degenerate or inverted element (the subclass's test)."""
        raise NotImplementedError

    def __post_init__(self):
        """Check ``nodes`` ((N, 3) finite, m) and ``elements`` ((M, ``nodes_per_element``) integer
        indices into the nodes, no node twice in an element), store them as read-only float and
        int64 arrays, then check the elements' geometry (``check_geometry``)."""
        nodes = finite_array("nodes", self.nodes, shape=(-1, 3))
        corners, name = self.nodes_per_element, self.element_name
        try:
            elements = np.asarray(self.elements)
        except (TypeError, ValueError) as error:
            raise ValueError(f"elements must be an (M, {corners}) integer array ({name} node indices)") from error
        if elements.ndim != 2 or elements.shape[1] != corners or len(elements) == 0:
            raise ValueError(f"elements must have shape (M, {corners}) (one {name} per row) with M >= 1, "
                             f"got {elements.shape}")
        if not np.issubdtype(elements.dtype, np.integer):
            if not np.issubdtype(elements.dtype, np.number) or not np.all(np.equal(np.mod(elements, 1), 0)):
                raise ValueError("elements must hold integer node indices")
        elements = elements.astype(np.int64)
        if elements.min() < 0 or elements.max() >= len(nodes):
            raise ValueError(
                f"element node indices must lie in [0, {len(nodes) - 1}], got [{elements.min()}, {elements.max()}]")
        repeated = np.any(np.diff(np.sort(elements, axis=1), axis=1) == 0, axis=1)
        if np.any(repeated):
            bad = int(np.argmax(repeated))
            raise ValueError(f"degenerate {name} {bad}: a node appears twice in {elements[bad].tolist()}")
        nodes.setflags(write=False)
        elements.setflags(write=False)
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "elements", elements)
        self.check_geometry(nodes, elements)
        if self.element_labels is not None:
            labels = np.asarray(self.element_labels)
            if labels.shape != (len(elements),) or not np.issubdtype(labels.dtype, np.integer):
                raise ValueError(f"element_labels must be an ({len(elements)},) integer array (one label id "
                                 f"per element), got {labels.dtype} of shape {labels.shape}")
            labels = labels.astype(np.int64)
            labels.setflags(write=False)
            object.__setattr__(self, "element_labels", labels)

    def __setstate__(self, state):
        """A copy (``copy.deepcopy``, pickle) is read-only as the original: numpy's copies of the
        arrays are writeable, and a writeable mesh is another numba signature of every kernel that
        reads it (a compilation per kernel after copying an env)."""
        for name in ("nodes", "elements", "element_labels"):
            if isinstance(state.get(name), np.ndarray):
                state[name].setflags(write=False)
        self.__dict__.update(state)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_elements(self) -> int:
        return len(self.elements)

    def on_nodes(self, nodes, elements=None, **fields) -> "MeshGeometry":
        """A mesh of this one's type whose elements are this mesh's on other node rows: ``nodes``
        (N', 3) m and ``elements`` (c M, k) (None: this mesh's), each element ``e`` with the rest
        corners of this mesh's element ``e mod M`` (a cut's copied nodes, a stack's parked rows, N
        worlds side by side); ``fields``: the other fields (default: this mesh's). The elements'
        geometry, checked when this mesh was built, is not checked again (a cut makes many such
        meshes); ValueError where an index is out of range or a corner is not this mesh's."""
        nodes = np.array(nodes, dtype=float)
        elements = self.elements if elements is None else np.array(elements, dtype=np.int64)
        count, corners = self.elements.shape
        if (nodes.ndim != 2 or nodes.shape[1] != 3 or not np.all(np.isfinite(nodes)) or elements.ndim != 2
                or elements.shape[1] != corners
                or len(elements) % count or (elements.size and (elements.min() < 0 or elements.max() >= len(nodes)))):
            raise ValueError(f"on_nodes takes (N, 3) finite nodes and (c {count}, {corners}) element indices into "
                             f"them, got {nodes.shape} and {elements.shape}")
        if not np.array_equal(nodes[elements].reshape(-1, count, corners, 3),
                              np.broadcast_to(self.nodes[self.elements], (len(elements) // count, count, corners, 3))):
            raise ValueError("on_nodes keeps the elements' rest corners: an element's corner is not this mesh's")
        values = {name: getattr(self, name) for name in self.__dataclass_fields__}
        values.update(fields, nodes=nodes, elements=elements)
        labels = values["element_labels"]
        if labels is not None:
            labels = np.array(labels, dtype=np.int64)
            if labels.shape != (len(elements),):
                raise ValueError(f"element_labels must be an ({len(elements)},) integer array, got shape "
                                 f"{labels.shape}")
            values["element_labels"] = labels
        mesh = object.__new__(type(self))
        for name, value in values.items():
            if name in ("nodes", "elements", "element_labels") and value is not None:
                value.setflags(write=False)  # copies made here, read-only as the checked constructor leaves them
            object.__setattr__(mesh, name, value)
        return mesh

    @property
    def size(self) -> np.ndarray:
        """Extent of the bounding box in m."""
        return self.nodes.max(axis=0) - self.nodes.min(axis=0)

    def surface_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes on the boundary surface."""
        return np.unique(self.surface_faces())

    def node_index(self, i, j, k):
        """Index of structured-block node (i, j, k) (only for meshes built by ``block``)."""
        return block_node_index(self.shape, i, j, k, f"{type(self).__name__}.block")

    @classmethod
    def _from_cells(cls, mesh, points, path, plural: str, need: str):
        """The mesh of the ``cell_type`` cells of what meshio read from ``path`` (``read_mesh_file``):
        ``plural`` names them in messages, ``need`` says what is missing when the file has none.
        Raises ``ValueError`` naming the file when they do not form a valid mesh."""
        blocks = cell_blocks(mesh, path, cls.cell_type, plural, need)
        try:
            return cls(points, np.concatenate(blocks))
        except ValueError as error:
            raise ValueError(f"{path}: its {plural} do not form a valid mesh: {error}") from error

    def write(self, path, point_data: dict | None = None, positions=None) -> None:
        """Write the mesh (optionally deformed ``positions`` (N, 3) m and ``point_data``) with meshio.

        The format follows the extension: .vtu, .msh (Gmsh 4.1, binary: meshio's ASCII reader
        cannot read point data back), .vtk, .xdmf, ...
        """
        points = self.nodes if positions is None else finite_array("positions", positions, (self.n_nodes, 3))
        write_mesh_file(path, points, self.cell_type, self.elements, point_data)


@dataclass(frozen=True)
class HexMesh(MeshGeometry):
    """An unstructured mesh of trilinear hexahedra.

    Args:
        nodes: (N, 3) rest positions in m.
        elements: (M, 8) node indices per hexahedron, VTK order.
        shape: (nx, ny, nz) when the mesh is a structured block, else None.
        spacing: (dx, dy, dz) in m when the mesh is a structured block, else None.
        element_labels: None, or (M,) integer label id per element (a segmented volume's
            tissue classes, ``from_mask``); ``Material.from_labels`` turns them into materials.

    Raises ``ValueError`` for wrong shapes, out-of-range indices, repeated nodes in an element, and
    degenerate or inverted elements (a corner Jacobian that is not positive).
    """

    nodes_per_element = 8
    element_name = "element"
    cell_type = "hexahedron"

    @staticmethod
    def check_geometry(positions, elements):
        """``check_elements``: every corner Jacobian positive."""
        check_elements(positions, elements)

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
        elements = block_node_index((nx, ny, nz), corner[..., 0], corner[..., 1], corner[..., 2], "HexMesh.block")
        return cls(nodes, elements, shape=(nx, ny, nz), spacing=spacing)

    @classmethod
    def from_mask(cls, mask, spacing, *, origin=(0.0, 0.0, 0.0), labels=None, components="refuse") -> "HexMesh":
        """One hexahedron per occupied voxel of a segmented volume (a CT/MRI label map, a phantom).

        Args:
            mask: (nx, ny, nz) boolean or integer array; index [i, j, k] is the voxel
                [x0 + i dx, x0 + (i + 1) dx] x [y0 + j dy, ...] x [z0 + k dz, ...] (y up). Non-zero
                (True) voxels are tissue; an integer volume's values are label ids (0 = outside).
            spacing: voxel size (dx, dy, dz) in m, or one number for cubic voxels; > 0.
            origin: (x0, y0, z0) in m, the corner of voxel [0, 0, 0].
            labels: None (mesh every non-zero voxel) or the label ids to mesh (e.g. ``(1, 2)``
                leaves label 3 out); the others count as outside.
            components: what to do when the occupied voxels are not one face-connected piece
                (two voxels sharing only an edge or a corner do not hold together: a loose part
                floats free): "refuse" (ValueError, the default) or "largest" (keep the largest
                face-connected component, with a ``UserWarning`` saying how many voxels were
                dropped).

        Returns:
            A ``HexMesh`` whose nodes are the used grid points, each once (neighbouring voxels share
            them), numbered x fastest, then y, then z as in ``block``; elements in voxel order
            (i fastest), VTK node order, every Jacobian positive. ``element_labels`` holds the
            voxels' label ids (1 for a boolean mask). A full box at the origin is exactly
            ``block(mask.shape, spacing)``, with ``shape`` and ``spacing`` set.

        Raises:
            ValueError: ``mask`` not 3D or not boolean/integer, no occupied voxel, a spacing that
                is not > 0, a bad ``labels`` or ``components``, occupied voxels in several
                face-connected components (with ``components="refuse"``), or a surface that is not
                a manifold: two voxels that touch along an edge or at a corner only, where neither
                shares a face with the other's neighbours (the hexahedra would hinge on one edge or
                node; ``non_manifold_voxels`` locates them). Refine or smooth the segmentation,
                or fill the gap in the mask, and try again.

        Elements are the voxels themselves, never merged: merging uniform k^3 blocks into larger
        hexahedra leaves hanging nodes where a large element meets small ones, a non-conforming
        mesh that neither the mass-spring springs nor the FEM reference handle. Coarsen the whole
        grid instead (``downsample``), to the element size a scene needs (``voxel_factor``).
        """
        volume = _label_volume(mask, labels)
        spacing = _parse_spacing(spacing)
        origin = finite_array("origin", np.broadcast_to(np.asarray(origin, dtype=float), (3,))).copy()
        if components not in ("refuse", "largest"):
            raise ValueError(f'components must be "refuse" or "largest", got {components!r}')
        occupied = volume > 0
        volume = np.where(_single_component(occupied, components), volume, 0)
        occupied = volume > 0
        critical = non_manifold_voxels(occupied)
        if len(critical):
            raise ValueError(
                f"mask is not a manifold solid: {len(critical)} voxels touch others along an edge or at a "
                f"corner only (first at voxel index {critical[0].tolist()}); fill the gaps (fill_non_manifold(mask)) "
                "or refine the mask"
            )
        nx, ny, nz = volume.shape
        voxel = np.flatnonzero(occupied.ravel(order="F"))
        base = np.stack(np.unravel_index(voxel, (nx, ny, nz), order="F"), axis=1)
        corner = base[:, None, :] + LOCAL_CORNERS.astype(int)[None, :, :]
        grid_index = block_node_index((nx, ny, nz), corner[..., 0], corner[..., 1], corner[..., 2], "from_mask")
        used, elements = np.unique(grid_index, return_inverse=True)
        elements = elements.reshape(-1, 8)
        grid = np.stack(np.unravel_index(used, (nx + 1, ny + 1, nz + 1), order="F"), axis=1)
        nodes = origin + grid * spacing
        element_labels = volume.ravel(order="F")[voxel].astype(np.int64)
        full = len(voxel) == volume.size and not np.any(origin)
        return cls(nodes, elements, shape=(nx, ny, nz) if full else None, spacing=spacing if full else None,
                   element_labels=element_labels)

    # -- geometry --------------------------------------------------------------------------
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
        return kernels.element_volumes(kernels.writeable(positions), self.elements, np.empty(self.n_elements))

    def surface_faces(self) -> np.ndarray:
        """(F, 4) node indices of the boundary quads, outward oriented (faces used by one element)."""
        return boundary_faces(self.elements, FACES)

    # -- files -----------------------------------------------------------------------------
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
        path = Path(path)
        mesh, points = read_mesh_file(path, "HexMesh.read", "hexahedra", "e.g. .vtu, .vtk, .msh (Gmsh), .xdmf, .med, .inp",
                                      "HexMesh.write")
        return cls._from_cells(mesh, points, path, "hexahedra", "HexMesh needs 8-node hexahedral cells")

    def write_obj(self, path, positions=None) -> None:
        """Export the boundary surface as a Wavefront .obj of quads (positions in m)."""
        points = self.nodes if positions is None else np.asarray(positions, dtype=float)
        faces = self.surface_faces()
        used, inverse = np.unique(faces, return_inverse=True)
        lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in points[used]]
        lines += ["f " + " ".join(str(i + 1) for i in quad) for quad in inverse.reshape(-1, 4)]
        Path(path).write_text("\n".join(lines) + "\n")


# -- segmented volumes -------------------------------------------------------------------------
def _label_volume(mask, labels) -> np.ndarray:
    """``mask`` as an (nx, ny, nz) int64 label volume (0 outside), keeping only ``labels``."""
    array = np.asarray(mask)
    if array.ndim != 3:
        raise ValueError(f"mask must be a 3D (nx, ny, nz) voxel array, got {array.ndim} dimensions "
                         f"(shape {array.shape})")
    if array.dtype == bool:
        volume = array.astype(np.int64)
    elif np.issubdtype(array.dtype, np.integer):
        if array.size and array.min() < 0:
            raise ValueError(f"mask label ids must be >= 0 (0 = outside), got {int(array.min())}")
        volume = array.astype(np.int64)
    else:
        raise ValueError(f"mask must be a boolean or integer label array, got dtype {array.dtype}")
    if labels is not None:
        try:
            wanted = np.unique(np.asarray(list(labels) if not np.isscalar(labels) else [labels], dtype=np.int64))
        except (TypeError, ValueError) as error:
            raise ValueError(f"labels must be None or a sequence of integer label ids, got {labels!r}") from error
        if len(wanted) == 0 or wanted.min() < 1:
            raise ValueError(f"labels must be non-empty label ids >= 1 (0 is outside), got {labels!r}")
        volume = np.where(np.isin(volume, wanted), volume, 0)
    if not np.any(volume):
        chosen = "" if labels is None else f" with labels {list(map(int, wanted))}"
        raise ValueError(f"mask has no occupied voxel{chosen}: nothing to mesh")
    return volume


def _single_component(occupied: np.ndarray, components: str) -> np.ndarray:
    """The occupied voxels when they form one face-connected component; else the largest
    (``components="largest"``, with a warning) or a ``ValueError``."""
    from scipy import ndimage

    index, count = ndimage.label(occupied)  # the default structure: face neighbours only
    if count == 1:
        return occupied
    sizes = np.bincount(index.ravel())[1:]
    if components == "refuse":
        raise ValueError(
            f"mask has {count} face-connected components (voxels {sorted(sizes.tolist(), reverse=True)[:5]}"
            f"{'...' if count > 5 else ''}); voxels touching only along an edge or at a corner do not hold "
            'together. Pass components="largest" to keep the largest one, or join them in the mask'
        )
    import warnings

    largest = int(np.argmax(sizes)) + 1
    warnings.warn(f"from_mask: kept the largest of {count} face-connected components ({int(sizes.max())} voxels); "
                  f"dropped {int(sizes.sum() - sizes.max())} voxels", UserWarning, stacklevel=3)
    return index == largest


def _critical_windows(occupied: np.ndarray) -> np.ndarray:
    """Every voxel of every critical window of ``occupied`` (padded with one empty voxel per
    side, so that windows on the border are seen): ``non_manifold_voxels``' definition."""
    flagged = np.zeros(occupied.shape, dtype=bool)

    def at(offset, size):  # the voxels at ``offset`` in every window of ``size`` voxels
        return tuple(slice(o, n - s + 1 + o) for o, s, n in zip(offset, size, occupied.shape))

    for normal in range(3):  # 2x2 windows in the plane across ``normal``: a diagonal pair alone
        size = [1 if axis == normal else 2 for axis in range(3)]
        square = [c for c in np.ndindex(2, 2, 2) if c[normal] == 0]
        for pair in ((square[0], square[3]), (square[1], square[2])):
            others = [c for c in square if c not in pair]
            bad = occupied[at(pair[0], size)] & occupied[at(pair[1], size)]
            bad &= ~occupied[at(others[0], size)] & ~occupied[at(others[1], size)]
            for c in square:
                flagged[at(c, size)] |= bad
    cube = list(np.ndindex(2, 2, 2))
    for c in cube[:4]:  # the 4 body diagonals of a 2x2x2 window: an opposite pair alone, or a gap alone
        pair = (c, tuple(1 - v for v in c))
        ends = occupied[at(pair[0], (2, 2, 2))], occupied[at(pair[1], (2, 2, 2))]
        rest = [occupied[at(q, (2, 2, 2))] for q in cube if q not in pair]
        bad = ends[0] & ends[1] & ~np.logical_or.reduce(rest)
        bad |= ~ends[0] & ~ends[1] & np.logical_and.reduce(rest)
        for q in cube:
            flagged[at(q, (2, 2, 2))] |= bad
    return flagged


def non_manifold_voxels(mask) -> np.ndarray:
    """(K, 3) sorted voxel indices [i, j, k] where the solid's boundary is not a 2-manifold.

    The boundary of a union of voxels is a closed manifold surface exactly when no 2x2 window of
    voxels (in any axis plane) holds two diagonal occupied voxels with the other two empty, and no
    2x2x2 window holds two opposite-corner voxels with the other six of the opposite kind (the
    "well-composed" sets of Latecki, 1997, Graphical Models and Image Processing 59(3)). Those
    windows join two voxels by an edge or a node alone (or leave two empty voxels that do); the
    voxels returned are those windows' occupied ones.
    """
    occupied = np.pad(np.asarray(mask, dtype=bool), 1)
    return np.argwhere((_critical_windows(occupied) & occupied)[1:-1, 1:-1, 1:-1])


def fill_non_manifold(mask, *, max_rounds=64):
    """``mask`` with the empty voxels of its critical windows (``non_manifold_voxels``) filled,
    repeated until none is left: edge and corner contacts become face contacts, so that
    ``HexMesh.from_mask`` accepts the result. A filled voxel takes the label of the nearest
    occupied voxel. Adds tissue only where voxels touched diagonally (a voxel-wide seam).

    Returns an array of ``mask``'s shape and dtype. Raises ``ValueError`` for a mask that
    ``from_mask`` would refuse for its type or dimensions, or when ``max_rounds`` do not settle.
    """
    from scipy import ndimage

    array = np.asarray(mask)
    volume = _label_volume(array, None)
    occupied = np.pad(volume > 0, 1)
    for _ in range(int(max_rounds)):
        fill = _critical_windows(occupied) & ~occupied
        if not fill.any():
            break
        occupied |= fill
    else:
        raise ValueError(f"fill_non_manifold: critical windows remain after {max_rounds} rounds")
    occupied = occupied[1:-1, 1:-1, 1:-1]
    added = occupied & (volume == 0)
    if added.any():
        _, nearest = ndimage.distance_transform_edt(volume == 0, return_indices=True)
        volume = volume.copy()
        volume[added] = volume[tuple(index[added] for index in nearest)]
    return volume.astype(bool) if array.dtype == bool else volume.astype(array.dtype)


def downsample(mask, factor, *, vote="majority") -> np.ndarray:
    """A coarser label volume: each block of ``factor``^3 voxels becomes one voxel.

    Args:
        mask: (nx, ny, nz) boolean or integer label volume (0 outside). Blocks at the far ends
            that ``factor`` does not fill are padded with outside voxels.
        factor: integer >= 1 (or (fx, fy, fz)); the new spacing is ``factor`` times the old.
        vote: "majority" (a coarse voxel is tissue when more than half of its block is) or
            "any" (when any voxel of its block is: never loses thin structures, grows the solid).
    Returns:
        (ceil(nx / fx), ceil(ny / fy), ceil(nz / fz)) array of ``mask``'s dtype; a tissue voxel
        takes its block's most frequent non-zero label (the smallest one on a tie).

    Use it to mesh a segmentation at the element size a scene needs rather than the scanner's:
    ``voxel_factor`` gives ``factor`` from an element size such as ``max(scene.size) /
    choose_resolution(scene).resolution`` (``sim_core.resolution``). The whole grid is coarsened
    because a mesh whose uniform regions alone had larger elements would not be conforming.
    """
    from .._validate import integer_at_least

    array = np.asarray(mask)
    volume = _label_volume(array, None)
    factors = np.broadcast_to(np.asarray(factor, dtype=object), (3,))
    factors = [integer_at_least("factor", f, 1) for f in factors]
    if vote not in ("majority", "any"):
        raise ValueError(f'vote must be "majority" or "any", got {vote!r}')
    coarse = [-(-n // f) for n, f in zip(volume.shape, factors)]
    padded = np.zeros([c * f for c, f in zip(coarse, factors)], dtype=np.int64)
    padded[: volume.shape[0], : volume.shape[1], : volume.shape[2]] = volume
    blocks = padded.reshape(coarse[0], factors[0], coarse[1], factors[1], coarse[2], factors[2])
    blocks = blocks.transpose(0, 2, 4, 1, 3, 5).reshape(*coarse, -1)
    tissue = np.count_nonzero(blocks, axis=-1)
    keep = tissue * 2 > blocks.shape[-1] if vote == "majority" else tissue > 0
    out = np.zeros(coarse, dtype=np.int64)
    best = np.zeros(coarse, dtype=np.int64)
    for label in np.unique(volume[volume > 0]):  # a handful of tissue classes
        count = np.count_nonzero(blocks == label, axis=-1)
        better = count > best
        out[better], best[better] = label, count[better]
    out[~keep] = 0
    return out.astype(bool) if array.dtype == bool else out.astype(array.dtype)


def voxel_factor(spacing, element_size) -> int:
    """The largest integer k >= 1 whose coarsened voxels (k x ``spacing``, m) are no larger than
    ``element_size`` (m) along any axis: ``downsample``'s factor for a chosen element size."""
    from .._validate import positive_scalar

    spacing = _parse_spacing(spacing)
    element_size = positive_scalar("element_size", element_size, "m")
    return max(1, int(np.floor(element_size / float(spacing.max()) * (1 + 1e-12))))


# -- element geometry (vectorised over elements) ---------------------------------------------
# -- what every mesh kind shares (HexMesh, TetMesh, surfaces) ---------------------------------
def boundary_faces(elements: np.ndarray, local_faces: np.ndarray) -> np.ndarray:
    """The faces used by one element only, in the elements' (outward) local order: ``local_faces``
    (F_e, n) indexes each element's nodes; returns (F, n) node indices."""
    faces = elements[:, local_faces].reshape(-1, local_faces.shape[1])
    _, index, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    return faces[np.sort(index[counts == 1])]


def block_node_index(shape, i, j, k, builder: str):
    """Index of structured-block node (i, j, k), x fastest; ValueError when the mesh has no ``shape``
    (it was not built by ``builder``)."""
    if shape is None:
        raise ValueError(f"node_index needs a structured block mesh ({builder})")
    nx, ny, _ = shape
    return np.asarray(i) + (nx + 1) * (np.asarray(j) + (ny + 1) * np.asarray(k))


def write_mesh_file(path, points: np.ndarray, cell_type: str, elements: np.ndarray, point_data=None) -> None:
    """Write one block of meshio cells; the format follows the extension (.msh: Gmsh 4.1 binary,
    since meshio's ASCII reader cannot read point data back)."""
    import meshio

    mesh = meshio.Mesh(points, [(cell_type, elements)], point_data=point_data or {})
    path = Path(path)
    if path.suffix == ".msh":
        meshio.write(path, mesh, file_format="gmsh", binary=True)
    else:
        meshio.write(path, mesh)


def read_mesh_file(path: Path, reader: str, content: str, formats: str, writer: str | None = None):
    """``(meshio mesh, points (N, 3) m)`` of ``path``, with the errors every reader here gives.

    Raises ``FileNotFoundError`` when ``path`` does not exist (as ``open`` does) and ``ValueError``,
    naming the file, for everything else: not a file, an extension meshio does not read, an empty
    file, one meshio cannot parse as its format (corrupt, truncated, another format; chained from
    meshio's error, including the ``SystemExit`` some of meshio's readers raise), points that are not
    finite 3D coordinates. ``reader`` (e.g. "HexMesh.read"), ``content`` ("hexahedra") and
    ``formats`` (examples of extensions) word the messages; ``writer`` names what writes such a file.
    """
    import contextlib
    import io

    import meshio
    from meshio._helpers import _filetypes_from_path  # the extension lookup meshio.read uses

    if not path.exists():
        raise FileNotFoundError(2, "mesh file not found", str(path))
    if not path.is_file():
        raise ValueError(f"{path} is not a file: {reader} needs a mesh file ({formats})")
    try:
        found = _filetypes_from_path(path)
    except Exception as error:
        extension = repr("".join(path.suffixes)) if path.suffix else "(none)"
        raise ValueError(f"{path}: unsupported mesh file extension {extension}; {reader} reads meshio's formats "
                         f"that hold {content}, {formats}") from error
    file_format = f"{path.suffix} ({' or '.join(found)})" if len(found) > 1 else f"{path.suffix} ({found[0]})"
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes): not a {file_format} mesh" + (f"; write one with {writer}" if writer else ""))
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
    points = np.asarray(mesh.points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{path}: points must be 3D, (N, 3) coordinates in m; got an array of shape {points.shape}")
    bad = int(np.size(points) - np.count_nonzero(np.isfinite(points)))
    if bad:
        raise ValueError(f"{path}: {bad} point coordinates are not finite (NaN or infinity); they must be numbers in m")
    return mesh, points


def cell_blocks(mesh, path, cell_type: str, content: str, need: str) -> list:
    """The (n_i, k) node-index arrays of ``mesh``'s cells of meshio type ``cell_type``; ValueError
    naming the file and the cell types it holds when there are none (``need`` says what is needed)."""
    blocks = [np.asarray(cells.data) for cells in mesh.cells if cells.type == cell_type]
    if not blocks:
        found = ", ".join(f"{len(cells.data)} {cells.type}" for cells in mesh.cells) or "no cells at all"
        raise ValueError(f"{path} contains no {content} (found {found}); {need} (meshio type {cell_type!r})")
    return blocks


def signed_volumes(positions: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(M,) signed volumes det[x1 - x0, x2 - x0, x3 - x0] / 6 of tetrahedra, m^3 (here, below
    ``sim_core.geometry.tetmesh`` and ``sim_core.geometry.meshing``, which both use it)."""
    corners = positions[elements]
    return np.linalg.det(corners[:, 1:] - corners[:, :1]) / 6.0


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
