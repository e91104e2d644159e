"""Contact geometry: the upper bound a rigid probe (spherical or flat tip) sets on the nodes under it,
projected over each node's support (``contact.Probe.surface``), for M probe / node-set pairs.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _projected_bound(x, z, tip_x, tip_y, tip_z, weights, offsets, level, radius, flat):
    """``contact.Probe``'s projected bound of one node at (x, z) m: the average over the node's
    support, weighted by its hat function (``weights`` (Q,), summing to 1), of min(probe surface,
    ``level``) at the points (x, z) + ``offsets`` (Q, 2) m, the probe's lowest point at (tip_x,
    tip_y, tip_z) m, its surface tip_y + R - sqrt(R^2 - r^2) within ``radius`` R of its axis (tip_y
    with ``flat``); +inf where it reaches below ``level`` at no point."""
    r2_max = radius * radius
    total = 0.0
    below = False
    for q in range(offsets.shape[0]):
        w = weights[q]
        if w == 0.0:
            continue
        dx = x + offsets[q, 0] - tip_x
        dz = z + offsets[q, 1] - tip_z
        r2 = dx * dx + dz * dz
        height = level
        if r2 <= r2_max:
            surface = tip_y if flat else tip_y + radius - np.sqrt(r2_max - r2)
            if surface < level:
                height = surface
                below = True
        total += w * height
    return total if below else np.inf


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _projected_probe_row(x, z, tips, weights, offsets, reference, radii, reach, flat, out, m):
    """Row ``m`` of ``projected_probe_surfaces``."""
    radius = radii[0] if radii.shape[0] == 1 else radii[m]
    row_offsets = offsets[0] if offsets.shape[0] == 1 else offsets[m]
    near2 = (radius + (reach[0] if reach.shape[0] == 1 else reach[m])) ** 2
    tip_x, tip_y, tip_z = tips[m, 0], tips[m, 1], tips[m, 2]
    levels = reference[0] if reference.shape[0] == 1 else reference[m]
    for k in range(x.shape[1]):
        dx = x[m, k] - tip_x
        dz = z[m, k] - tip_z
        if dx * dx + dz * dz <= near2:
            out[m, k] = _projected_bound(x[m, k], z[m, k], tip_x, tip_y, tip_z, weights[k], row_offsets, levels[k],
                                         radius, flat)
        else:
            out[m, k] = np.inf


@njit(cache=True, error_model="numpy", parallel=True)
def projected_probe_surfaces_rows(x, z, tips, weights, offsets, reference, radii, reach, flat, out):
    """``projected_probe_surfaces`` with its rows (the vector envs' copies) on numba's threads (the
    same floats)."""
    for m in prange(x.shape[0]):
        _projected_probe_row(x, z, tips, weights, offsets, reference, radii, reach, flat, out, np.int64(m))


@njit(cache=True, nogil=True, error_model="numpy")
def projected_probe_surfaces(x, z, tips, weights, offsets, reference, radii, reach, flat, out):
    """``contact.Probe.surface``'s projected bound of every node of M probe / node-set pairs in one
    pass: ``x``, ``z`` (M, n) the nodes' horizontal coordinates, m, ``tips`` (M, 3) m, ``weights``
    (n, Q), ``offsets`` (M, Q, 2) or (1, Q, 2) m the quadrature points relative to their node,
    ``reference`` (M, n) or (1, n) m, ``radii`` (M,) or (1,) the probes' radii, m, ``reach`` (M,) or
    (1,) m (a (1, ...) array is the same for every row); a node farther than its radius + reach
    from its row's probe axis gets +inf (no quadrature point can be under the probe), the others
    ``_projected_bound``. Writes ``out`` (M, n) m."""
    for m in range(x.shape[0]):
        _projected_probe_row(x, z, tips, weights, offsets, reference, radii, reach, flat, out, m)
