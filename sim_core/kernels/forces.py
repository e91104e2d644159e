"""Force passes of the mass-spring model: springs, the corrections, the volume forces and the
hourglass term, for one model (``model_forces``: one call per explicit step) and for N stacked
copies (``model_forces_copies``, the stacked hourglass subtraction).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..topology import EDGES
from .fastmath import FAST

_EDGES = np.ascontiguousarray(EDGES)


@njit(cache=True, nogil=True, error_model="numpy")
def spring_pass(positions, springs, stiffness, rest_length, length, unit, tension):
    """Lengths (m), unit vectors and elastic tension k (L - L0) (N) of every spring."""
    for s in range(springs.shape[0]):
        a, b = springs[s, 0], springs[s, 1]
        dx = positions[b, 0] - positions[a, 0]
        dy = positions[b, 1] - positions[a, 1]
        dz = positions[b, 2] - positions[a, 2]
        current = np.sqrt(dx * dx + dy * dy + dz * dz)
        length[s] = current
        unit[s, 0] = dx / current
        unit[s, 1] = dy / current
        unit[s, 2] = dz / current
        tension[s] = stiffness[s] * (current - rest_length[s])


@njit(cache=True, nogil=True, error_model="numpy")
def correction_pass(length, edge_spring, correction_matrix, axis_rest_length, push):
    """T_j per element (docs/physics.md 3): push[m, j] = sum_k W[m, j, k] eps_k."""
    eps = np.empty(3)
    for m in range(edge_spring.shape[0]):
        for axis in range(3):
            total = 0.0
            for q in range(4):
                total += length[edge_spring[m, 4 * axis + q]]
            eps[axis] = 0.25 * total / axis_rest_length[m, axis] - 1.0
        for j in range(3):
            push[m, j] = (correction_matrix[m, j, 0] * eps[0] + correction_matrix[m, j, 1] * eps[1]
                          + correction_matrix[m, j, 2] * eps[2])


@njit(cache=True, nogil=True, error_model="numpy")
def subtract_pushes(edge_spring, push, tension):
    """Projected corrections act along the current edge: a push T lowers the edge's tension by T."""
    for m in range(edge_spring.shape[0]):
        for e in range(12):
            tension[edge_spring[m, e]] -= push[m, e // 4]


@njit(cache=True, nogil=True, error_model="numpy")
def scatter_springs(springs, unit, tension, damping, velocities, use_velocity, forces):
    """forces += t u on node a and -t u on node b, with t = tension + damping * (dv . u)."""
    for s in range(springs.shape[0]):
        a, b = springs[s, 0], springs[s, 1]
        t = tension[s]
        if use_velocity:
            t += damping[s] * ((velocities[b, 0] - velocities[a, 0]) * unit[s, 0]
                               + (velocities[b, 1] - velocities[a, 1]) * unit[s, 1]
                               + (velocities[b, 2] - velocities[a, 2]) * unit[s, 2])
        for c in range(3):
            forces[a, c] += t * unit[s, c]
            forces[b, c] -= t * unit[s, c]


@njit(cache=True, nogil=True, error_model="numpy")
def fixed_direction_corrections(elements, push, rest_direction, forces):
    """The published variant: corrections along the rest directions of the element edges."""
    for m in range(elements.shape[0]):
        for e in range(12):
            t = push[m, e // 4]
            p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
            for c in range(3):
                forces[q, c] += t * rest_direction[m, e, c]
                forces[p, c] -= t * rest_direction[m, e, c]


@njit(cache=True, nogil=True, error_model="numpy")
def volume_jacobian_terms(positions, elements, rest_volume, kappa, coefficient, direction, gradient):
    """Per element the volume forces' stiffness K_v = c h grad(V)^T (docs/physics.md 4): the coefficient
    c = 2 kappa |dV| / V0^2 (N/m^4... per m^3 of volume change), the force directions h (M, 8, 3),
    a_S / (4 A_H) summed over the node's faces, and the volume gradient (M, 8, 3) in m^2."""
    forces = np.zeros_like(positions)  # (the forces themselves are not returned here)
    volume_forces_jacobian_add(positions, elements, rest_volume, kappa, forces, coefficient, direction, gradient)


@njit(cache=True, nogil=True, error_model="numpy")
def volume_pass(positions, elements, rest_volume, kappa, forces):
    """Volume-conservation forces (docs/physics.md 4) with exact trilinear element volumes."""
    volume_forces_add(positions, elements, rest_volume, kappa, forces)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def model_forces(positions, velocities, use_velocity, springs, stiffness, rest_length, damping,
                 elements, edge_spring, correction_matrix, axis_rest_length, correction_kind, rest_edge_direction,
                 rest_volume, kappa, has_volume, hg_indptr, hg_indices, hg_data, rest_positions, has_hourglass,
                 length, unit, tension, push, forces,
                 want_geometric, geometric, want_volume_jacobian, volume_coefficient, volume_direction,
                 volume_gradient):
    """Every internal force in three passes (springs, elements, springs), into ``forces`` (zeroed here).

    correction_kind: 0 none, 1 projected (a push lowers the edge's tension), 2 fixed directions.
    Fills length, unit, tension (elastic and projected corrections; damping excluded) and push, as
    ``forces.spring_state`` does. For the implicit step, want_geometric fills the per-spring clamped
    geometric stiffness max(tension / length, 0) and want_volume_jacobian the volume forces'
    rank-one terms (coefficient, direction, gradient; see ``volume_jacobian_terms``).
    """
    n_springs = springs.shape[0]
    for s in range(n_springs):
        a, b = springs[s, 0], springs[s, 1]
        dx = positions[b, 0] - positions[a, 0]
        dy = positions[b, 1] - positions[a, 1]
        dz = positions[b, 2] - positions[a, 2]
        current = np.sqrt(dx * dx + dy * dy + dz * dz)
        length[s] = current
        unit[s, 0] = dx / current
        unit[s, 1] = dy / current
        unit[s, 2] = dz / current
        tension[s] = stiffness[s] * (current - rest_length[s])
    forces[:] = 0.0
    for m in range(elements.shape[0] if correction_kind != 0 else 0):  # corrections (docs/physics.md 3)
        e0 = 0.25 * (length[edge_spring[m, 0]] + length[edge_spring[m, 1]] + length[edge_spring[m, 2]]
                     + length[edge_spring[m, 3]]) / axis_rest_length[m, 0] - 1.0
        e1 = 0.25 * (length[edge_spring[m, 4]] + length[edge_spring[m, 5]] + length[edge_spring[m, 6]]
                     + length[edge_spring[m, 7]]) / axis_rest_length[m, 1] - 1.0
        e2 = 0.25 * (length[edge_spring[m, 8]] + length[edge_spring[m, 9]] + length[edge_spring[m, 10]]
                     + length[edge_spring[m, 11]]) / axis_rest_length[m, 2] - 1.0
        for j in range(3):
            push[m, j] = correction_matrix[m, j, 0] * e0 + correction_matrix[m, j, 1] * e1 \
                + correction_matrix[m, j, 2] * e2
        if correction_kind == 1:
            for e in range(12):
                tension[edge_spring[m, e]] -= push[m, e // 4]
        else:
            for e in range(12):
                t = push[m, e // 4]
                p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
                for c in range(3):
                    forces[q, c] += t * rest_edge_direction[m, e, c]
                    forces[p, c] -= t * rest_edge_direction[m, e, c]
    if has_volume:
        if want_volume_jacobian:
            volume_forces_jacobian_add(positions, elements, rest_volume, kappa, forces, volume_coefficient,
                                       volume_direction, volume_gradient)
        else:
            volume_forces_add(positions, elements, rest_volume, kappa, forces)
    for s in range(n_springs):
        a, b = springs[s, 0], springs[s, 1]
        t = tension[s]
        if want_geometric:
            g = t / length[s]
            geometric[s] = g if g > 0.0 else 0.0
        if use_velocity:
            t += damping[s] * ((velocities[b, 0] - velocities[a, 0]) * unit[s, 0]
                               + (velocities[b, 1] - velocities[a, 1]) * unit[s, 1]
                               + (velocities[b, 2] - velocities[a, 2]) * unit[s, 2])
        fx, fy, fz = t * unit[s, 0], t * unit[s, 1], t * unit[s, 2]
        forces[a, 0] += fx
        forces[a, 1] += fy
        forces[a, 2] += fz
        forces[b, 0] -= fx
        forces[b, 1] -= fy
        forces[b, 2] -= fz
    if has_hourglass:  # f -= K_hg (x - X)
        flat = forces.reshape(-1)
        x = positions.reshape(-1)
        rest = rest_positions.reshape(-1)
        for row in range(hg_indptr.shape[0] - 1):
            total = 0.0
            for k in range(hg_indptr[row], hg_indptr[row + 1]):
                col = hg_indices[k]
                total += hg_data[k] * (x[col] - rest[col])
            flat[row] -= total


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def model_forces_copies(count, positions, velocities, use_velocity, springs, stiffness, rest_length, damping,
                        elements, edge_spring, correction_matrix, axis_rest_length, correction_kind,
                        rest_edge_direction, rest_volume, kappa, has_volume, length, unit, tension, push, forces,
                        want_geometric, geometric, want_volume_jacobian, volume_coefficient, volume_direction,
                        volume_gradient):
    """``model_forces`` (without the hourglass term) of a stacked model of ``count`` equal copies
    (copies first: copy c's nodes, springs and elements are the c-th equal slices), one copy per
    numba thread at a time: ``springs``, ``elements`` and ``edge_spring`` are ONE copy's topology
    (local indices); every other array is the stacked model's. The copies are disjoint, so each
    writes only its own slices, in the stacked pass's order: the same floats as ``model_forces`` on
    the stacked model."""
    n = positions.shape[0] // count
    n_springs, n_elements = springs.shape[0], elements.shape[0]
    g = geometric.shape[0] // count  # 0 for a forces-only workspace
    v = volume_coefficient.shape[0] // count
    no_int = np.zeros(1, dtype=np.int64)
    no_float = np.zeros(1)
    for c in prange(count):
        a, b = c * n_springs, (c + 1) * n_springs
        e0, e1 = c * n_elements, (c + 1) * n_elements
        model_forces(positions[c * n:(c + 1) * n], velocities[c * n:(c + 1) * n], use_velocity, springs,
                     stiffness[a:b], rest_length[a:b], damping[a:b], elements, edge_spring, correction_matrix[e0:e1],
                     axis_rest_length[e0:e1], correction_kind, rest_edge_direction[e0:e1], rest_volume[e0:e1],
                     kappa[e0:e1], has_volume, no_int, no_int, no_float, positions[c * n:(c + 1) * n], False,
                     length[a:b], unit[a:b], tension[a:b], push[e0:e1], forces[c * n:(c + 1) * n], want_geometric,
                     geometric[c * g:(c + 1) * g], want_volume_jacobian, volume_coefficient[c * v:(c + 1) * v],
                     volume_direction[c * v:(c + 1) * v], volume_gradient[c * v:(c + 1) * v])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def volume_forces_add(positions, elements, rest_volume, kappa, forces):
    """Adds every element's volume-conservation force (docs/physics.md 4) to ``forces`` (N, 3): the
    body of ``volume_forces_jacobian_add`` without the stiffness terms."""
    none = np.empty((0, 8, 3))
    _volume_forces(positions, elements, rest_volume, kappa, forces, False, np.empty(0), none, none)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def volume_forces_jacobian_add(positions, elements, rest_volume, kappa, forces, coefficient, direction, gradient):
    """``volume_forces_add`` that also fills the rank-one stiffness terms of
    ``volume_jacobian_terms``: coefficient (M,), direction and gradient (M, 8, 3)."""
    _volume_forces(positions, elements, rest_volume, kappa, forces, True, coefficient, direction, gradient)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def _volume_forces(positions, elements, rest_volume, kappa, forces, jacobian, coefficient, direction, gradient):
    """Adds every element's volume-conservation force (docs/physics.md 4) to ``forces`` (N, 3), with
    exact trilinear volumes: the formulas of ``hex_volume`` and ``volume_pass`` written out as one
    straight-line body per element (generated code, no scratch arrays: faster than two passes
    through them). With ``jacobian``, also fills the rank-one stiffness terms of
    ``volume_jacobian_terms``: coefficient (M,), direction and gradient (M, 8, 3); without it those
    arrays are not touched (may be empty).
    """
    for m in range(elements.shape[0]):
        if kappa[m] == 0.0:
            if jacobian:
                coefficient[m] = 0.0
            continue
        i0 = elements[m, 0]
        i1 = elements[m, 1]
        i2 = elements[m, 2]
        i3 = elements[m, 3]
        i4 = elements[m, 4]
        i5 = elements[m, 5]
        i6 = elements[m, 6]
        i7 = elements[m, 7]
        p0x = positions[i0, 0]
        p0y = positions[i0, 1]
        p0z = positions[i0, 2]
        p1x = positions[i1, 0]
        p1y = positions[i1, 1]
        p1z = positions[i1, 2]
        p2x = positions[i2, 0]
        p2y = positions[i2, 1]
        p2z = positions[i2, 2]
        p3x = positions[i3, 0]
        p3y = positions[i3, 1]
        p3z = positions[i3, 2]
        p4x = positions[i4, 0]
        p4y = positions[i4, 1]
        p4z = positions[i4, 2]
        p5x = positions[i5, 0]
        p5y = positions[i5, 1]
        p5z = positions[i5, 2]
        p6x = positions[i6, 0]
        p6y = positions[i6, 1]
        p6z = positions[i6, 2]
        p7x = positions[i7, 0]
        p7y = positions[i7, 1]
        p7z = positions[i7, 2]
        d1x = p1x - p0x
        d1y = p1y - p0y
        d1z = p1z - p0z
        d2x = p3x - p0x
        d2y = p3y - p0y
        d2z = p3z - p0z
        d3x = p2x - p0x
        d3y = p2y - p0y
        d3z = p2z - p0z
        d4x = p4x - p0x
        d4y = p4y - p0y
        d4z = p4z - p0z
        d5x = p5x - p0x
        d5y = p5y - p0y
        d5z = p5z - p0z
        d6x = p7x - p0x
        d6y = p7y - p0y
        d6z = p7z - p0z
        d7x = p6x - p0x
        d7y = p6y - p0y
        d7z = p6z - p0z
        # exact trilinear volume (hex_volume's grouping)
        vax = d2y * d3z - d2z * d3y
        vay = d2z * d3x - d2x * d3z
        vaz = d2x * d3y - d2y * d3x
        vbx = d3y * (d5z + d7z) - d3z * (d5y + d7y)
        vby = d3z * (d5x + d7x) - d3x * (d5z + d7z)
        vbz = d3x * (d5y + d7y) - d3y * (d5x + d7x)
        vex = d5y * (d4z - d7z) - d5z * (d4y - d7y)
        vey = d5z * (d4x - d7x) - d5x * (d4z - d7z)
        vez = d5x * (d4y - d7y) - d5y * (d4x - d7x)
        volume = (d1x * (vax + vbx + vex) + d1y * (vay + vby + vey) + d1z * (vaz + vbz + vez))
        vfx = d3y * (d6z + d7z) - d3z * (d6y + d7y)
        vfy = d3z * (d6x + d7x) - d3x * (d6z + d7z)
        vfz = d3x * (d6y + d7y) - d3y * (d6x + d7x)
        vgx = d6y * (d7z - d4z) - d6z * (d7y - d4y)
        vgy = d6z * (d7x - d4x) - d6x * (d7z - d4z)
        vgz = d6x * (d7y - d4y) - d6y * (d7x - d4x)
        volume += d2x * (vgx - vfx) + d2y * (vgy - vfy) + d2z * (vgz - vfz)
        vhx = (d6y - d5y) * d7z - (d6z - d5z) * d7y
        vhy = (d6z - d5z) * d7x - (d6x - d5x) * d7z
        vhz = (d6x - d5x) * d7y - (d6y - d5y) * d7x
        volume += d3x * vhx + d3y * vhy + d3z * vhz
        vsx = d6y * d7z - d6z * d7y
        vsy = d6z * d7x - d6x * d7z
        vsz = d6x * d7y - d6y * d7x
        vkx = d5y * (d6z + d7z) - d5z * (d6y + d7y)
        vky = d5z * (d6x + d7x) - d5x * (d6z + d7z)
        vkz = d5x * (d6y + d7y) - d5y * (d6x + d7x)
        volume += d4x * (vkx - vsx) + d4y * (vky - vsy) + d4z * (vkz - vsz)
        volume -= d5x * vsx + d5y * vsy + d5z * vsz
        volume = volume / 12.0
        # face area vectors a_S = (x2 - x0) x (x3 - x1) / 2 and the total area A_H
        f0x = (p7y - p0y) * (p3z - p4z) - (p7z - p0z) * (p3y - p4y)
        f0y = (p7z - p0z) * (p3x - p4x) - (p7x - p0x) * (p3z - p4z)
        f0z = (p7x - p0x) * (p3y - p4y) - (p7y - p0y) * (p3x - p4x)
        f1x = (p6y - p1y) * (p5z - p2z) - (p6z - p1z) * (p5y - p2y)
        f1y = (p6z - p1z) * (p5x - p2x) - (p6x - p1x) * (p5z - p2z)
        f1z = (p6x - p1x) * (p5y - p2y) - (p6y - p1y) * (p5x - p2x)
        f2x = (p5y - p0y) * (p4z - p1z) - (p5z - p0z) * (p4y - p1y)
        f2y = (p5z - p0z) * (p4x - p1x) - (p5x - p0x) * (p4z - p1z)
        f2z = (p5x - p0x) * (p4y - p1y) - (p5y - p0y) * (p4x - p1x)
        f3x = (p6y - p3y) * (p2z - p7z) - (p6z - p3z) * (p2y - p7y)
        f3y = (p6z - p3z) * (p2x - p7x) - (p6x - p3x) * (p2z - p7z)
        f3z = (p6x - p3x) * (p2y - p7y) - (p6y - p3y) * (p2x - p7x)
        f4x = (p2y - p0y) * (p1z - p3z) - (p2z - p0z) * (p1y - p3y)
        f4y = (p2z - p0z) * (p1x - p3x) - (p2x - p0x) * (p1z - p3z)
        f4z = (p2x - p0x) * (p1y - p3y) - (p2y - p0y) * (p1x - p3x)
        f5x = (p6y - p4y) * (p7z - p5z) - (p6z - p4z) * (p7y - p5y)
        f5y = (p6z - p4z) * (p7x - p5x) - (p6x - p4x) * (p7z - p5z)
        f5z = (p6x - p4x) * (p7y - p5y) - (p6y - p4y) * (p7x - p5x)
        area = 0.5 * (np.sqrt(f0x * f0x + f0y * f0y + f0z * f0z) + np.sqrt(f1x * f1x + f1y * f1y + f1z * f1z) + np.sqrt(f2x * f2x + f2y * f2y + f2z * f2z) + np.sqrt(f3x * f3x + f3y * f3y + f3z * f3z) + np.sqrt(f4x * f4x + f4y * f4y + f4z * f4z) + np.sqrt(f5x * f5x + f5y * f5y + f5z * f5z))
        relative = (volume - rest_volume[m]) / rest_volume[m]
        share = 1.0 / (8.0 * area)  # the 1/2 of each a_S, and 1 / (4 A_H)
        scale = -kappa[m] * relative * abs(relative) * share
        h0x = f0x + f2x + f4x
        forces[i0, 0] += scale * h0x
        h0y = f0y + f2y + f4y
        forces[i0, 1] += scale * h0y
        h0z = f0z + f2z + f4z
        forces[i0, 2] += scale * h0z
        h1x = f1x + f2x + f4x
        forces[i1, 0] += scale * h1x
        h1y = f1y + f2y + f4y
        forces[i1, 1] += scale * h1y
        h1z = f1z + f2z + f4z
        forces[i1, 2] += scale * h1z
        h2x = f1x + f3x + f4x
        forces[i2, 0] += scale * h2x
        h2y = f1y + f3y + f4y
        forces[i2, 1] += scale * h2y
        h2z = f1z + f3z + f4z
        forces[i2, 2] += scale * h2z
        h3x = f0x + f3x + f4x
        forces[i3, 0] += scale * h3x
        h3y = f0y + f3y + f4y
        forces[i3, 1] += scale * h3y
        h3z = f0z + f3z + f4z
        forces[i3, 2] += scale * h3z
        h4x = f0x + f2x + f5x
        forces[i4, 0] += scale * h4x
        h4y = f0y + f2y + f5y
        forces[i4, 1] += scale * h4y
        h4z = f0z + f2z + f5z
        forces[i4, 2] += scale * h4z
        h5x = f1x + f2x + f5x
        forces[i5, 0] += scale * h5x
        h5y = f1y + f2y + f5y
        forces[i5, 1] += scale * h5y
        h5z = f1z + f2z + f5z
        forces[i5, 2] += scale * h5z
        h6x = f1x + f3x + f5x
        forces[i6, 0] += scale * h6x
        h6y = f1y + f3y + f5y
        forces[i6, 1] += scale * h6y
        h6z = f1z + f3z + f5z
        forces[i6, 2] += scale * h6z
        h7x = f0x + f3x + f5x
        forces[i7, 0] += scale * h7x
        h7y = f0y + f3y + f5y
        forces[i7, 1] += scale * h7y
        h7z = f0z + f3z + f5z
        forces[i7, 2] += scale * h7z
        if not jacobian:
            continue
        coefficient[m] = 2.0 * kappa[m] * abs(volume - rest_volume[m]) / rest_volume[m] ** 2
        direction[m, 0, 0] = share * h0x
        direction[m, 0, 1] = share * h0y
        direction[m, 0, 2] = share * h0z
        direction[m, 1, 0] = share * h1x
        direction[m, 1, 1] = share * h1y
        direction[m, 1, 2] = share * h1z
        direction[m, 2, 0] = share * h2x
        direction[m, 2, 1] = share * h2y
        direction[m, 2, 2] = share * h2z
        direction[m, 3, 0] = share * h3x
        direction[m, 3, 1] = share * h3y
        direction[m, 3, 2] = share * h3z
        direction[m, 4, 0] = share * h4x
        direction[m, 4, 1] = share * h4y
        direction[m, 4, 2] = share * h4z
        direction[m, 5, 0] = share * h5x
        direction[m, 5, 1] = share * h5y
        direction[m, 5, 2] = share * h5z
        direction[m, 6, 0] = share * h6x
        direction[m, 6, 1] = share * h6y
        direction[m, 6, 2] = share * h6z
        direction[m, 7, 0] = share * h7x
        direction[m, 7, 1] = share * h7y
        direction[m, 7, 2] = share * h7z
        x12x = d1y * d2z - d1z * d2y
        x12y = d1z * d2x - d1x * d2z
        x12z = d1x * d2y - d1y * d2x
        x13x = d1y * d3z - d1z * d3y
        x13y = d1z * d3x - d1x * d3z
        x13z = d1x * d3y - d1y * d3x
        x14x = d1y * d4z - d1z * d4y
        x14y = d1z * d4x - d1x * d4z
        x14z = d1x * d4y - d1y * d4x
        x15x = d1y * d5z - d1z * d5y
        x15y = d1z * d5x - d1x * d5z
        x15z = d1x * d5y - d1y * d5x
        x17x = d1y * d7z - d1z * d7y
        x17y = d1z * d7x - d1x * d7z
        x17z = d1x * d7y - d1y * d7x
        x23x = d2y * d3z - d2z * d3y
        x23y = d2z * d3x - d2x * d3z
        x23z = d2x * d3y - d2y * d3x
        x24x = d2y * d4z - d2z * d4y
        x24y = d2z * d4x - d2x * d4z
        x24z = d2x * d4y - d2y * d4x
        x26x = d2y * d6z - d2z * d6y
        x26y = d2z * d6x - d2x * d6z
        x26z = d2x * d6y - d2y * d6x
        x27x = d2y * d7z - d2z * d7y
        x27y = d2z * d7x - d2x * d7z
        x27z = d2x * d7y - d2y * d7x
        x35x = d3y * d5z - d3z * d5y
        x35y = d3z * d5x - d3x * d5z
        x35z = d3x * d5y - d3y * d5x
        x36x = d3y * d6z - d3z * d6y
        x36y = d3z * d6x - d3x * d6z
        x36z = d3x * d6y - d3y * d6x
        x37x = d3y * d7z - d3z * d7y
        x37y = d3z * d7x - d3x * d7z
        x37z = d3x * d7y - d3y * d7x
        x45x = d4y * d5z - d4z * d5y
        x45y = d4z * d5x - d4x * d5z
        x45z = d4x * d5y - d4y * d5x
        x46x = d4y * d6z - d4z * d6y
        x46y = d4z * d6x - d4x * d6z
        x46z = d4x * d6y - d4y * d6x
        x47x = d4y * d7z - d4z * d7y
        x47y = d4z * d7x - d4x * d7z
        x47z = d4x * d7y - d4y * d7x
        x56x = d5y * d6z - d5z * d6y
        x56y = d5z * d6x - d5x * d6z
        x56z = d5x * d6y - d5y * d6x
        x57x = d5y * d7z - d5z * d7y
        x57y = d5z * d7x - d5x * d7z
        x57z = d5x * d7y - d5y * d7x
        x67x = d6y * d7z - d6z * d7y
        x67y = d6z * d7x - d6x * d7z
        x67z = d6x * d7y - d6y * d7x
        g1x = (+ x23x + x35x + x37x - x45x - x57x) / 12.0
        g1y = (+ x23y + x35y + x37y - x45y - x57y) / 12.0
        g1z = (+ x23z + x35z + x37z - x45z - x57z) / 12.0
        g2x = (- x13x - x36x - x37x + x46x + x67x) / 12.0
        g2y = (- x13y - x36y - x37y + x46y + x67y) / 12.0
        g2z = (- x13z - x36z - x37z + x46z + x67z) / 12.0
        g3x = (+ x12x - x15x - x17x + x26x + x27x - x57x + x67x) / 12.0
        g3y = (+ x12y - x15y - x17y + x26y + x27y - x57y + x67y) / 12.0
        g3z = (+ x12z - x15z - x17z + x26z + x27z - x57z + x67z) / 12.0
        g4x = (+ x15x - x26x + x56x + x57x - x67x) / 12.0
        g4y = (+ x15y - x26y + x56y + x57y - x67y) / 12.0
        g4z = (+ x15z - x26z + x56z + x57z - x67z) / 12.0
        g5x = (+ x13x - x14x + x17x + x37x - x46x - x47x - x67x) / 12.0
        g5y = (+ x13y - x14y + x17y + x37y - x46y - x47y - x67y) / 12.0
        g5z = (+ x13z - x14z + x17z + x37z - x46z - x47z - x67z) / 12.0
        g6x = (- x23x + x24x - x27x - x37x + x45x + x47x + x57x) / 12.0
        g6y = (- x23y + x24y - x27y - x37y + x45y + x47y + x57y) / 12.0
        g6z = (- x23z + x24z - x27z - x37z + x45z + x47z + x57z) / 12.0
        g7x = (+ x13x - x15x - x23x + x26x - x35x + x36x + x45x - x46x - x56x) / 12.0
        g7y = (+ x13y - x15y - x23y + x26y - x35y + x36y + x45y - x46y - x56y) / 12.0
        g7z = (+ x13z - x15z - x23z + x26z - x35z + x36z + x45z - x46z - x56z) / 12.0
        g0x = -(g1x + g2x + g3x + g4x + g5x + g6x + g7x)
        g0y = -(g1y + g2y + g3y + g4y + g5y + g6y + g7y)
        g0z = -(g1z + g2z + g3z + g4z + g5z + g6z + g7z)
        gradient[m, 0, 0] = g0x
        gradient[m, 0, 1] = g0y
        gradient[m, 0, 2] = g0z
        gradient[m, 1, 0] = g1x
        gradient[m, 1, 1] = g1y
        gradient[m, 1, 2] = g1z
        gradient[m, 3, 0] = g2x
        gradient[m, 3, 1] = g2y
        gradient[m, 3, 2] = g2z
        gradient[m, 2, 0] = g3x
        gradient[m, 2, 1] = g3y
        gradient[m, 2, 2] = g3z
        gradient[m, 4, 0] = g4x
        gradient[m, 4, 1] = g4y
        gradient[m, 4, 2] = g4z
        gradient[m, 5, 0] = g5x
        gradient[m, 5, 1] = g5y
        gradient[m, 5, 2] = g5z
        gradient[m, 7, 0] = g6x
        gradient[m, 7, 1] = g6y
        gradient[m, 7, 2] = g6z
        gradient[m, 6, 0] = g7x
        gradient[m, 6, 1] = g7y
        gradient[m, 6, 2] = g7z


@njit(cache=True, error_model="numpy", parallel=True)
def scatter_springs_copies(count, springs, unit, tension, damping, velocities, use_velocity, forces):
    """``scatter_springs`` of a stacked model of ``count`` copies (copy c's springs the c-th equal
    slice, on its own nodes), the copies on numba's threads (the same floats)."""
    per = springs.shape[0] // count
    for c in prange(count):
        a, b = c * per, (c + 1) * per
        scatter_springs(springs[a:b], unit[a:b], tension[a:b], damping[a:b], velocities, use_velocity, forces)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _hourglass_group_rows(indptr, indices, block_rows, order, group_start, displacement, flat, block, blocks, total):
    """Node rows [block n / blocks, (block + 1) n / blocks) of ``stacked_hourglass_subtract_groups``;
    ``displacement`` (3 n, N) and ``total`` (3, N) hold the copies last (in group order), so a
    block's three rows of displacements are contiguous for all its copies."""
    n_nodes = indptr.shape[0] - 1
    dofs = 3 * n_nodes
    first, last = block * n_nodes // blocks, (block + 1) * n_nodes // blocks
    for i in range(first, last):
        for g in range(group_start.shape[0] - 1):
            start, end = group_start[g], group_start[g + 1]
            values = block_rows[g]
            for t in range(start, end):
                total[0, t] = 0.0
                total[1, t] = 0.0
                total[2, t] = 0.0
            for q in range(indptr[i], indptr[i + 1]):
                j = 3 * indices[q]
                b = 9 * q
                b00, b01, b02 = values[b], values[b + 1], values[b + 2]
                b10, b11, b12 = values[b + 3], values[b + 4], values[b + 5]
                b20, b21, b22 = values[b + 6], values[b + 7], values[b + 8]
                for t in range(start, end):
                    d0, d1, d2 = displacement[j, t], displacement[j + 1, t], displacement[j + 2, t]
                    total[0, t] += b00 * d0 + b01 * d1 + b02 * d2
                    total[1, t] += b10 * d0 + b11 * d1 + b12 * d2
                    total[2, t] += b20 * d0 + b21 * d1 + b22 * d2
            for t in range(start, end):
                row = order[t] * dofs + 3 * i
                flat[row] -= total[0, t]
                flat[row + 1] -= total[1, t]
                flat[row + 2] -= total[2, t]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def stacked_hourglass_subtract_groups_serial(indptr, indices, block_rows, order, group_start, positions,
                                             rest_positions, forces):
    """forces (N n, 3) -= K_c (x_c - X_c) for every copy c of a stacked model (copies first), K_c the
    hourglass matrix of copy c in node blocks: BSR ``indptr`` (n + 1,), ``indices`` (nb,) of ONE copy
    and the values ``block_rows[g]`` ((G, 9 nb): the G distinct matrices), ``order`` (N,) the copies
    sorted by their matrix and ``group_start`` (G + 1,) where each matrix's copies begin. Each block
    is read once for all the copies of its matrix (Palpation's 16 copies of 7 inclusions: 7 matrices
    of 1.1 MB per pass, not 16), with one index and three vector loads per 9 values."""
    n_copies = order.shape[0]
    dofs = 3 * (indptr.shape[0] - 1)
    x, rest, flat = positions.reshape(-1), rest_positions.reshape(-1), forces.reshape(-1)
    displacement = np.empty((dofs, n_copies))
    for t in range(n_copies):
        c = order[t]
        for j in range(dofs):
            displacement[j, t] = x[c * dofs + j] - rest[c * dofs + j]
    _hourglass_group_rows(indptr, indices, block_rows, order, group_start, displacement, flat, 0, 1,
                          np.empty((3, n_copies)))


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def stacked_hourglass_subtract_groups(indptr, indices, block_rows, order, group_start, positions, rest_positions,
                                      forces, blocks):
    """``stacked_hourglass_subtract_groups_serial`` with the node rows in ``blocks`` blocks on numba's
    threads (a row's sums do not depend on the split: the same floats)."""
    n_copies = order.shape[0]
    dofs = 3 * (indptr.shape[0] - 1)
    x, rest, flat = positions.reshape(-1), rest_positions.reshape(-1), forces.reshape(-1)
    displacement = np.empty((dofs, n_copies))  # the copies' displacements in group order, copies last
    for t in prange(n_copies):
        c = order[t]
        for j in range(dofs):
            displacement[j, t] = x[c * dofs + j] - rest[c * dofs + j]
    for block in prange(blocks):
        _hourglass_group_rows(indptr, indices, block_rows, order, group_start, displacement, flat, block, blocks,
                              np.empty((3, n_copies)))
