"""Geometric queries on deformed meshes seen from above (projected on the horizontal plane x, z)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def points_covered_by_quads(points, positions, quads, out):
    """Which points of the horizontal plane a deformed mesh's quads cover, seen from above:
    out[c, p] = whether the 2D point ``points[c, p]`` (N, P, 2), (x, z) m, lies inside or on the
    boundary of at least one of the quads of copy c, each taken as convex, of either orientation;
    quad q's corners are the nodes ``quads[q]`` (Q, 4) of ``positions[c]`` (N, n, 3) projected on
    (x, z). Point p is inside quad q when the cross products of its 4 edges with p all have one sign
    (zero counts as either; a NaN corner covers nothing): the decisions of those cross products
    evaluated with numpy over (N, P, Q, 4, 2) arrays, without the temporaries."""
    n_copies, n_points = points.shape[0], points.shape[1]
    corners = np.empty((quads.shape[0], 4, 2))
    for c in range(n_copies):
        for q in range(quads.shape[0]):
            for k in range(4):
                corners[q, k, 0] = positions[c, quads[q, k], 0]
                corners[q, k, 1] = positions[c, quads[q, k], 2]
        for p in range(n_points):
            px, pz = points[c, p, 0], points[c, p, 1]
            inside = False
            for q in range(quads.shape[0]):
                positive = True
                negative = True
                for k in range(4):
                    k1 = (k + 1) % 4
                    ex = corners[q, k1, 0] - corners[q, k, 0]
                    ez = corners[q, k1, 1] - corners[q, k, 1]
                    cross = ex * (pz - corners[q, k, 1]) - ez * (px - corners[q, k, 0])
                    if not cross >= 0:
                        positive = False
                    if not cross <= 0:
                        negative = False
                if positive or negative:
                    inside = True
                    break
            out[c, p] = inside
