"""The camera's z-buffer kernel (``tissue_env.camera``): triangles already projected to pixel
coordinates are filled with the nearest one's colour and depth. Compiled here with the other kernels so
the environment layer holds no compiled code."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def rasterise_triangles(u, v, inverse_depth, triangles, colours, near, far, background, depth, image):
    """Z-buffer of N worlds: u, v, inverse_depth (N, V) of the projected vertices; triangles (T, 3);
    colours (N, T, 3) uint8; depth (N, H, W) float64 and image (N, H, W, 3) uint8 are filled.
    A pixel is covered when its centre is inside the triangle or on its edge; the depth is the
    perspective-correct one (1 / depth interpolated linearly in the image plane), the nearer
    triangle wins (ties: the first drawn)."""
    count, height, width = depth.shape
    inverse_near = 1.0 / near
    for world in range(count):
        for i in range(height):
            for j in range(width):
                depth[world, i, j] = far
                for k in range(3):
                    image[world, i, j, k] = background[k]
        for t in range(triangles.shape[0]):
            a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            za, zb, zc = inverse_depth[world, a], inverse_depth[world, b], inverse_depth[world, c]
            # behind the camera, or nearer than the near plane (or not finite): not drawn
            if not (0.0 < za <= inverse_near and 0.0 < zb <= inverse_near and 0.0 < zc <= inverse_near):
                continue
            ua, va = u[world, a], v[world, a]
            ub, vb = u[world, b], v[world, b]
            uc, vc = u[world, c], v[world, c]
            area = (ub - ua) * (vc - va) - (vb - va) * (uc - ua)
            if area == 0.0 or not np.isfinite(area):
                continue
            j0 = max(int(np.floor(min(ua, ub, uc) - 0.5)), 0)
            j1 = min(int(np.ceil(max(ua, ub, uc) - 0.5)), width - 1)
            i0 = max(int(np.floor(min(va, vb, vc) - 0.5)), 0)
            i1 = min(int(np.ceil(max(va, vb, vc) - 0.5)), height - 1)
            for i in range(i0, i1 + 1):
                y = i + 0.5
                for j in range(j0, j1 + 1):
                    x = j + 0.5
                    wa = ((ub - x) * (vc - y) - (vb - y) * (uc - x)) / area
                    wb = ((uc - x) * (va - y) - (vc - y) * (ua - x)) / area
                    wc = ((ua - x) * (vb - y) - (va - y) * (ub - x)) / area
                    if wa < 0.0 or wb < 0.0 or wc < 0.0:
                        continue
                    z = 1.0 / (wa * za + wb * zb + wc * zc)
                    if z < depth[world, i, j] and z >= near:
                        depth[world, i, j] = z
                        for k in range(3):
                            image[world, i, j, k] = colours[world, t, k]


