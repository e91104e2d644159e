"""Surface meshes of implicit shapes, closed-surface checks, surface files and tetrahedralisation.

A surface is ``(vertices, faces)``: (V, 3) float positions in m and (F, 3) int vertex indices per
triangle, counter-clockwise seen from outside (the right-hand normal points out), so that the
divergence theorem gives a positive enclosed volume.

- ``isosurface``: the zero level set of a function sampled on a grid, by marching tetrahedra,
- ``check_closed`` / ``enclosed_volume``: watertightness and the signed volume of a surface,
- ``read_surface``: STL / OBJ / PLY / OFF / VTK files through meshio,
- ``tetrahedralise``: a closed surface to positively oriented tetrahedra.
"""

from __future__ import annotations

from itertools import permutations
from pathlib import Path

import numpy as np

from .._validate import finite_array
from .mesh import read_mesh_file, signed_volumes

#: The 6 tetrahedra of a grid cell around its diagonal (0,0,0)-(1,1,1) (Kuhn's subdivision):
#: one per order of the axes. Neighbouring cells cut their shared face along the same diagonal,
#: so the tetrahedra of the whole grid are conforming and the isosurface has no cracks.
_KUHN = np.array([
    [(0, 0, 0), tuple(int(a == p[0]) for a in range(3)),
     tuple(int(a in p[:2]) for a in range(3)), (1, 1, 1)]
    for p in permutations(range(3))
])  # (6, 4, 3) local corner offsets


def isosurface(values, spacing, origin=(0.0, 0.0, 0.0), *, snap=0.01):
    """The closed triangle surface where ``values`` changes sign (inside: values < 0).

    Args:
        values: (nx, ny, nz) samples of a signed function (e.g. a signed distance in m) at the
            grid points ``origin + (i, j, k) * spacing``; finite. Zero counts as outside.
        spacing: grid step (dx, dy, dz) in m (or one number), > 0.
        origin: position of sample [0, 0, 0] in m.
        snap: where the linear zero of an edge falls within ``snap`` (a fraction of the edge) of
            a grid point it is moved to that distance, so that no triangle is degenerate.
    Returns:
        ``(vertices, faces)``: a watertight, consistently outward-oriented surface when every
        sample on the grid's boundary is outside (>= 0): each cell is cut into 6 tetrahedra
        (``_KUHN``) and each tetrahedron's zero set, linear in it, is one triangle or two;
        vertices on the grid's edges are shared between the cells that meet there.
    Raises:
        ValueError: values not 3D with at least 2 samples per axis, not finite, a bad spacing,
            no sign change, or an inside sample on the grid's boundary (the surface would be open).
    """
    values = finite_array("values", values)
    if values.ndim != 3 or min(values.shape) < 2:
        raise ValueError(f"values must be an (nx, ny, nz) grid with nx, ny, nz >= 2, got shape {values.shape}")
    spacing = finite_array("spacing", np.broadcast_to(np.asarray(spacing, dtype=float), (3,))).copy()
    if np.any(spacing <= 0):
        raise ValueError(f"spacing must be > 0 m along every axis, got {spacing.tolist()}")
    origin = finite_array("origin", np.broadcast_to(np.asarray(origin, dtype=float), (3,))).copy()
    inside = values < 0
    if not inside.any() or inside.all():
        raise ValueError("values has no sign change: there is no surface (inside is values < 0)")
    border = inside.copy()
    border[1:-1, 1:-1, 1:-1] = False
    if border.any():
        raise ValueError("values is negative (inside) on the grid's boundary: pad the grid so that the "
                         "shape lies strictly inside it, or the surface is not closed")
    shape = np.array(values.shape)
    # cells that the surface crosses: some but not all of their 8 corners inside
    corner_inside = [inside[i:shape[0] - 1 + i, j:shape[1] - 1 + j, k:shape[2] - 1 + k]
                     for i, j, k in np.ndindex(2, 2, 2)]
    count = np.sum(corner_inside, axis=0)
    cells = np.argwhere((count > 0) & (count < 8))  # (C, 3)
    corners = cells[:, None, None, :] + _KUHN[None]  # (C, 6, 4, 3)
    tets = np.ravel_multi_index(corners.reshape(-1, 3).T, values.shape).reshape(-1, 4)  # flat grid ids
    flat_values = values.ravel()
    tet_inside = flat_values[tets] < 0
    n_inside = tet_inside.sum(axis=1)
    grid_points = lambda ids: origin + np.stack(np.unravel_index(ids, values.shape), axis=-1) * spacing  # noqa: E731

    triangles = []  # (T, 3, 2) edge (inside id, outside id) per triangle corner
    for k in (1, 2, 3):
        chosen = tets[n_inside == k]
        if not len(chosen):
            continue
        flags = tet_inside[n_inside == k]
        order = np.argsort(~flags, axis=1, kind="stable")  # inside corners first
        ordered = np.take_along_axis(chosen, order, axis=1)
        ins, outs = ordered[:, :k], ordered[:, k:]
        if k == 1:
            tri = [np.stack([ins[:, 0], outs[:, m]], axis=1) for m in range(3)]
            triangles.append(np.stack(tri, axis=1))
        elif k == 3:
            tri = [np.stack([ins[:, m], outs[:, 0]], axis=1) for m in range(3)]
            triangles.append(np.stack(tri, axis=1))
        else:  # a quad: (i0, o0), (i0, o1), (i1, o1), (i1, o0), cut along its first diagonal
            quad = [np.stack(pair, axis=1) for pair in ((ins[:, 0], outs[:, 0]), (ins[:, 0], outs[:, 1]),
                                                       (ins[:, 1], outs[:, 1]), (ins[:, 1], outs[:, 0]))]
            triangles.append(np.stack([quad[0], quad[1], quad[2]], axis=1))
            triangles.append(np.stack([quad[0], quad[2], quad[3]], axis=1))
    edges = np.concatenate(triangles)  # (T, 3, 2)
    # orient each triangle from the inside corners to the outside ones: decided on the edge
    # midpoints, where no triangle is degenerate; sliding the points along their edges to the
    # zero crossings keeps that orientation
    mid = 0.5 * (grid_points(edges[..., 0]) + grid_points(edges[..., 1]))  # (T, 3, 3)
    normal = np.cross(mid[:, 1] - mid[:, 0], mid[:, 2] - mid[:, 0])
    outward = grid_points(edges[:, 0, 1]) - grid_points(edges[:, 0, 0])  # inside -> outside along an edge
    flip = np.einsum("ij,ij->i", normal, outward) < 0
    edges[flip] = edges[flip][:, ::-1]
    keys, faces = np.unique(np.sort(edges, axis=2).reshape(-1, 2), axis=0, return_inverse=True)
    f0, f1 = flat_values[keys[:, 0]], flat_values[keys[:, 1]]
    t = np.clip(f0 / (f0 - f1), snap, 1.0 - snap)
    p0, p1 = grid_points(keys[:, 0]), grid_points(keys[:, 1])
    vertices = p0 + t[:, None] * (p1 - p0)
    return vertices, faces.reshape(-1, 3).astype(np.int64)


def _surface_arrays(vertices, faces, name="surface"):
    vertices = finite_array(f"{name} vertices", vertices, shape=(-1, 3))
    try:
        faces = np.asarray(faces)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} faces must be an (F, 3) integer array") from error
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"{name} faces must be a non-empty (F, 3) integer array of vertex indices, got "
                         f"{faces.dtype} of shape {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"{name} faces index vertices outside [0, {len(vertices) - 1}]")
    return vertices, faces.astype(np.int64)


def check_closed(vertices, faces, name="surface") -> None:
    """Raise ``ValueError`` unless the triangle surface is closed and consistently oriented: every
    edge is used by exactly two faces, once in each direction (a watertight, orientable
    2-manifold without boundary), and no face repeats a vertex."""
    vertices, faces = _surface_arrays(vertices, faces, name)
    if np.any((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])):
        raise ValueError(f"{name} has degenerate faces (a vertex repeated in a triangle)")
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    undirected, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    if np.any(counts != 2):
        open_edges, shared = int(np.sum(counts == 1)), int(np.sum(counts > 2))
        raise ValueError(f"{name} is not closed: {open_edges} edges belong to one face only (holes) and "
                         f"{shared} to more than two (non-manifold); a closed surface uses each edge twice")
    _, once = np.unique(directed, axis=0, return_counts=True)
    if np.any(once != 1):
        raise ValueError(f"{name} is not consistently oriented: neighbouring faces run along a shared edge "
                         "in the same direction (orient every face counter-clockwise seen from outside)")


def enclosed_volume(vertices, faces) -> float:
    """Signed volume (m^3) enclosed by a closed triangle surface (divergence theorem): positive
    when the faces are oriented outward."""
    vertices, faces = _surface_arrays(vertices, faces)
    a, b, c = (vertices[faces[:, m]] for m in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


# -- surface files -----------------------------------------------------------------------------
def read_surface(path):
    """Read a triangle surface (.stl, .obj, .ply, .off, .vtk, .vtu, ...) with meshio.

    Returns ``(vertices (V, 3) m, faces (F, 3) int)``: the file's triangles (quads are cut in
    two), coincident points merged (STL stores every facet's corners separately) and unused ones
    dropped. Coordinates are taken as metres: scale a file drawn in mm by 1e-3.

    Raises ``FileNotFoundError`` when ``path`` does not exist (as ``open`` and ``HexMesh.read``
    do) and ``ValueError``, naming the file, when meshio cannot read it (unknown extension, empty,
    corrupt or truncated) or it holds no triangles or non-finite points.
    """
    path = Path(path)
    mesh, points = read_mesh_file(path, "read_surface", "triangles or quads", "e.g. .stl, .obj, .ply, .off, .vtk")
    return surface_of(mesh, points, path)


def surface_of(mesh, points, path):
    """``(vertices, faces)`` of a meshio ``mesh`` read from ``path`` (``read_surface``'s result:
    triangles and cut quads, coincident points merged, unused ones dropped); ValueError naming the
    file when it holds neither triangles nor quads."""
    blocks = [np.asarray(c.data) for c in mesh.cells if c.type == "triangle"]
    blocks += [np.asarray(c.data)[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3) for c in mesh.cells if c.type == "quad"]
    if not blocks:
        found = ", ".join(f"{len(c.data)} {c.type}" for c in mesh.cells) or "no cells at all"
        raise ValueError(f"{path} contains no triangles or quads (found {found}); read_surface needs a surface")
    faces = np.concatenate(blocks).astype(np.int64)
    merged, index = np.unique(points, axis=0, return_inverse=True)
    faces = index.ravel()[faces]
    used, faces = np.unique(faces, return_inverse=True)
    return merged[used], faces.reshape(-1, 3)


# -- tetrahedralisation ------------------------------------------------------------------------
#: The optional dependency of ``tetrahedralise`` and the extra that installs it.
MESH_EXTRA = "pip install 'tissue-gym[mesh]'  (pytetwild: fTetWild, MPL-2.0)"


def tet_volumes(nodes, tets) -> np.ndarray:
    """(T,) signed volumes (m^3) of tetrahedra (positive when (1-0, 2-0, 3-0) is right-handed):
    ``mesh.signed_volumes`` of the arrays."""
    return signed_volumes(np.asarray(nodes, dtype=float), np.asarray(tets))


def tet_quality(nodes, tets) -> dict:
    """Shape measures of tetrahedra, each (T,): ``radius_edge``, circumradius over shortest edge
    (sqrt(6)/4 = 0.612 for the regular tetrahedron, large for needles and caps, but not for
    slivers), and ``mean_ratio``, 6 sqrt(2) V / l_rms^3 (1 regular, -> 0 for every degenerate
    shape, slivers included)."""
    a, b, c, d = (nodes[tets[:, m]] for m in range(4))
    u, v, w = b - a, c - a, d - a
    volume = tet_volumes(nodes, tets)
    square = lambda x: np.einsum("ij,ij->i", x, x)  # noqa: E731
    lengths = np.stack([square(x) for x in (u, v, w, c - b, d - b, d - c)], axis=1)
    circum = square(u)[:, None] * np.cross(v, w) + square(v)[:, None] * np.cross(w, u) + square(w)[:, None] * np.cross(u, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        radius = np.linalg.norm(circum, axis=1) / (12.0 * np.abs(volume))
        return {"radius_edge": radius / np.sqrt(lengths.min(axis=1)),
                "mean_ratio": 6.0 * np.sqrt(2.0) * volume / lengths.mean(axis=1) ** 1.5}


def _ftetwild():
    try:
        import pytetwild
    except ModuleNotFoundError as error:
        if error.name == "pyvista":
            raise ImportError(
                "pytetwild >= 0.3 imports pyvista (and VTK) when imported; tetrahedralise needs only its "
                f"array interface: install pytetwild 0.2.x ({MESH_EXTRA}) or pyvista") from error
        raise ImportError(f"tetrahedralise needs the optional mesh extra: {MESH_EXTRA}") from error
    return pytetwild


def tetrahedralise(vertices, faces, *, max_volume=None, edge_length=None, max_radius_edge=5.0,
                   min_mean_ratio=0.02, envelope=1e-3, stop_energy=10.0, threads=0):
    """Fill a closed triangle surface with tetrahedra (fTetWild, through ``pytetwild``).

    Args:
        vertices, faces: the surface (m; ``check_closed`` must pass: every edge in two faces).
        max_volume: largest tetrahedron volume allowed, m^3 (None: set by ``edge_length``). The
            target edge length is that of a regular tetrahedron of a third of it (fTetWild's
            tetrahedra reach about twice the regular volume of their target); if some still
            exceed it the mesh is made again with 0.75 times the edge length, up to twice.
        edge_length: target edge length in m (None: 1/20 of the bounding-box diagonal).
        max_radius_edge: largest circumradius / shortest edge accepted (regular: 0.61).
        min_mean_ratio: smallest mean ratio 6 sqrt(2) V / l_rms^3 accepted (regular: 1); catches
            slivers, which radius/edge does not.
        envelope: how far the volume's boundary may depart from the surface, as a fraction of the
            bounding-box diagonal (fTetWild's epsilon).
        stop_energy: fTetWild optimises the tetrahedra's AMIPS energy (3 for a regular one) down
            to this; lower is better shaped and slower.
        threads: CPU threads (0: all).
    Returns:
        ``(nodes (N, 3) m, tets (T, 4) int)``, every tetrahedron positively oriented (``tet_volumes``
        > 0), all nodes used; tests/test_meshing.py checks the volume against the surface's on an
        icosphere and on the liver phantom.
    Raises:
        ValueError: a surface that is not closed, a bad argument, or a result outside the quality
            limits (the message gives the worst values: lower ``stop_energy``).
        ImportError: pytetwild missing (``MESH_EXTRA`` names the extra).

    Why fTetWild: it meshes the volume inside an envelope of the surface, so marching-tetrahedra
    or scanned surfaces with tiny or nearly degenerate triangles mesh without repair; its wheel
    (3 MB, numpy only) is MPL-2.0, which an MIT project can depend on. TetGen (``tetgen``,
    ``meshpy``) is AGPL (meshpy also ships Triangle, free for non-commercial use only), gmsh is
    GPL and a 39 MB wheel, and ``wildmeshing`` (fTetWild too) installs a top-level package named
    ``test`` that shadows the standard library's. fTetWild writes a file
    ``__tracked_surface.stl`` into the working directory; the call runs in a temporary directory
    so that it does not litter the caller's (the process's working directory changes meanwhile).
    """
    import os
    import tempfile

    vertices, faces = _surface_arrays(vertices, faces)
    check_closed(vertices, faces)
    for name, value, low in (("max_radius_edge", max_radius_edge, 0.6), ("stop_energy", stop_energy, 3.0)):
        if not np.isfinite(value) or value <= low:
            raise ValueError(f"{name} must be a finite number > {low}, got {value!r}")
    if not 0 <= min_mean_ratio < 1:
        raise ValueError(f"min_mean_ratio must lie in [0, 1), got {min_mean_ratio!r}")
    if not 0 < envelope < 0.1:
        raise ValueError(f"envelope must lie in (0, 0.1) (a fraction of the bounding-box diagonal), got {envelope!r}")
    for name, value in (("max_volume", max_volume), ("edge_length", edge_length)):
        if value is not None and (not np.isfinite(value) or value <= 0):
            raise ValueError(f"{name} must be None or a number > 0 ({'m^3' if name == 'max_volume' else 'm'}), "
                             f"got {value!r}")
    if max_volume is not None:
        regular = (6.0 * np.sqrt(2.0) * max_volume / 3.0) ** (1.0 / 3.0)
        edge_length = regular if edge_length is None else min(edge_length, regular)
    pytetwild = _ftetwild()
    for attempt in range(3):
        here = os.getcwd()
        with tempfile.TemporaryDirectory() as scratch:
            os.chdir(scratch)
            try:
                nodes, tets = pytetwild.tetrahedralize(
                    vertices, faces.astype(np.int32), edge_length_abs=edge_length, epsilon=envelope,
                    stop_energy=stop_energy, num_threads=threads, quiet=True)
            finally:
                os.chdir(here)
        nodes, tets = np.asarray(nodes, dtype=float), np.asarray(tets, dtype=np.int64)
        if tets.ndim != 2 or len(tets) == 0:
            raise ValueError("fTetWild returned no tetrahedra for this surface")
        volumes = tet_volumes(nodes, tets)
        tets[volumes < 0] = tets[volumes < 0][:, [0, 2, 1, 3]]  # orient positively
        volumes = np.abs(volumes)
        if max_volume is None or volumes.max() <= max_volume:
            break
        edge_length *= 0.75
    else:
        raise ValueError(f"tetrahedra of up to {volumes.max():.3g} m^3 remain above max_volume = {max_volume:.3g} m^3 "
                         "after refining twice")
    used, tets = np.unique(tets, return_inverse=True)
    nodes, tets = nodes[used], tets.reshape(-1, 4)
    quality = tet_quality(nodes, tets)
    scale = float(np.linalg.norm(np.ptp(vertices, axis=0))) ** 3
    if volumes.min() <= 1e-15 * scale:
        raise ValueError(f"fTetWild returned a degenerate tetrahedron (volume {volumes.min():.3g} m^3)")
    worst_re, worst_q = float(quality["radius_edge"].max()), float(quality["mean_ratio"].min())
    if worst_re > max_radius_edge or worst_q < min_mean_ratio:
        raise ValueError(
            f"tetrahedra outside the quality limits: radius/edge up to {worst_re:.3g} (limit {max_radius_edge}), "
            f"mean ratio down to {worst_q:.3g} (limit {min_mean_ratio}); lower stop_energy (now {stop_energy}) "
            "or the limits")
    return nodes, tets
