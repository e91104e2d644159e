"""The reference trilinear hexahedron: corner order, edges, faces, corner frames and Gauss points.

Constants only (and the shape-function gradients they are built from), importing nothing of
``sim_core``, so the mesh, the force models and the compiled kernels all read them from here. Node
order is VTK's: 0 (0,0,0), 1 (1,0,0), 2 (1,1,0), 3 (0,1,0), 4 (0,0,1), 5 (1,0,1), 6 (1,1,1),
7 (0,1,1) in local coordinates.
"""

from __future__ import annotations

import numpy as np

#: Local corner coordinates of the VTK hexahedron, in {0, 1}^3.
LOCAL_CORNERS = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    dtype=float,
)
#: The 12 edges, 4 per local axis, each oriented from local coordinate 0 to 1 along its axis.
EDGES = np.array(
    [[0, 1], [3, 2], [4, 5], [7, 6],  # along local x
     [0, 3], [1, 2], [4, 7], [5, 6],  # along local y
     [0, 4], [1, 5], [2, 6], [3, 7]],  # along local z
)
EDGE_AXIS = np.repeat(np.arange(3), 4)
#: The 4 inner diagonals.
DIAGONALS = np.array([[0, 6], [1, 7], [2, 4], [3, 5]])
#: The 6 faces with outward orientation: 0.5 (x[f2] - x[f0]) x (x[f3] - x[f1]) is the outward
#: vector area. Order: x=0, x=1, y=0, y=1, z=0, z=1.
FACES = np.array(
    [[0, 4, 7, 3], [1, 2, 6, 5], [0, 1, 5, 4], [3, 7, 6, 2], [0, 3, 2, 1], [4, 5, 6, 7]]
)
#: For corner c, its three neighbours along local x, y, z (used for corner Jacobians).
CORNER_NEIGHBOURS = np.array(
    [[1, 3, 4], [0, 2, 5], [3, 1, 6], [2, 0, 7], [5, 7, 0], [4, 6, 1], [7, 5, 2], [6, 4, 3]]
)
#: Orientation sign of each corner frame (+1 where the neighbours form a right-handed frame).
CORNER_SIGN = np.array([1, -1, 1, -1, -1, 1, -1, 1], dtype=float)

# -- 2x2x2 Gauss quadrature on the unit cube ---------------------------------------------------
_GAUSS = np.array([0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)])
#: 2x2x2 Gauss points in the unit cube [0, 1]^3 (weights 1/8 each).
GAUSS_POINTS = np.array([[a, b, c] for c in _GAUSS for b in _GAUSS for a in _GAUSS])


def shape_gradients(points: np.ndarray) -> np.ndarray:
    """(P, 8, 3) derivatives of the trilinear shape functions on [0, 1]^3 at ``points``."""
    xi = points[:, None, :]
    corner = LOCAL_CORNERS[None, :, :]
    factors = corner * xi + (1 - corner) * (1 - xi)  # (P, 8, 3)
    signs = 2 * corner - 1
    grads = np.empty(factors.shape)
    grads[..., 0] = signs[..., 0] * factors[..., 1] * factors[..., 2]
    grads[..., 1] = factors[..., 0] * signs[..., 1] * factors[..., 2]
    grads[..., 2] = factors[..., 0] * factors[..., 1] * signs[..., 2]
    return grads


GAUSS_GRADIENTS = shape_gradients(GAUSS_POINTS)
