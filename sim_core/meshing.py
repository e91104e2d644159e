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

from ._validate import finite_array

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
