"""Force passes of the mass-spring model: springs, the corrections, the volume forces and the
hourglass term, for one model (``model_forces``: one call per explicit step) and for N stacked
copies (``model_forces_copies``, the stacked hourglass subtraction).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..geometry.topology import EDGES
from .fastmath import FAST
from .measure import corner_differences, trilinear_volume
from .vectors import add, cross, norm, row, sub

_EDGES = np.ascontiguousarray(EDGES)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def spring_pass(positions, springs, stiffness, rest_length, length, unit, tension):
    """Lengths (m), unit vectors and elastic tension k (L - L0) (N) of every spring. Inlined into
    ``model_forces``, so there it runs under that kernel's fastmath flags."""
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


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _element_push(length, edge_spring, correction_matrix, axis_rest_length, push, m):
    """T_j of element m (docs/physics.md 3): push[m, j] = sum_k W[m, j, k] eps_k, eps_k the mean
    strain of its four edges along local axis k."""
    e0 = 0.25 * (length[edge_spring[m, 0]] + length[edge_spring[m, 1]] + length[edge_spring[m, 2]]
                 + length[edge_spring[m, 3]]) / axis_rest_length[m, 0] - 1.0
    e1 = 0.25 * (length[edge_spring[m, 4]] + length[edge_spring[m, 5]] + length[edge_spring[m, 6]]
                 + length[edge_spring[m, 7]]) / axis_rest_length[m, 1] - 1.0
    e2 = 0.25 * (length[edge_spring[m, 8]] + length[edge_spring[m, 9]] + length[edge_spring[m, 10]]
                 + length[edge_spring[m, 11]]) / axis_rest_length[m, 2] - 1.0
    for j in range(3):
        push[m, j] = correction_matrix[m, j, 0] * e0 + correction_matrix[m, j, 1] * e1 \
            + correction_matrix[m, j, 2] * e2


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _subtract_element_push(edge_spring, push, tension, m):
    """Projected corrections act along the current edge: element m's push T lowers its edges' tension by T."""
    for e in range(12):
        tension[edge_spring[m, e]] -= push[m, e // 4]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _fixed_direction_element(elements, push, rest_direction, forces, m):
    """Element m's corrections along the rest directions of its edges (the published variant)."""
    for e in range(12):
        t = push[m, e // 4]
        p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
        for c in range(3):
            forces[q, c] += t * rest_direction[m, e, c]
            forces[p, c] -= t * rest_direction[m, e, c]


@njit(cache=True, nogil=True, error_model="numpy")
def correction_pass(length, edge_spring, correction_matrix, axis_rest_length, push):
    """T_j per element (docs/physics.md 3): push[m, j] = sum_k W[m, j, k] eps_k."""
    for m in range(edge_spring.shape[0]):
        _element_push(length, edge_spring, correction_matrix, axis_rest_length, push, m)


@njit(cache=True, nogil=True, error_model="numpy")
def subtract_pushes(edge_spring, push, tension):
    """Projected corrections act along the current edge: a push T lowers the edge's tension by T."""
    for m in range(edge_spring.shape[0]):
        _subtract_element_push(edge_spring, push, tension, m)


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
        _fixed_direction_element(elements, push, rest_direction, forces, m)


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
    spring_pass(positions, springs, stiffness, rest_length, length, unit, tension)
    forces[:] = 0.0
    for m in range(elements.shape[0] if correction_kind != 0 else 0):  # corrections (docs/physics.md 3)
        _element_push(length, edge_spring, correction_matrix, axis_rest_length, push, m)
        if correction_kind == 1:
            _subtract_element_push(edge_spring, push, tension, m)
        else:
            _fixed_direction_element(elements, push, rest_edge_direction, forces, m)
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
        for dof in range(hg_indptr.shape[0] - 1):
            total = 0.0
            for k in range(hg_indptr[dof], hg_indptr[dof + 1]):
                col = hg_indices[k]
                total += hg_data[k] * (x[col] - rest[col])
            flat[dof] -= total


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _model_forces_copy(c, count, arrays):
    """Copy ``c``'s ``model_forces`` (without the hourglass term) of ``model_forces_copies``'
    ``arrays``."""
    (positions, velocities, use_velocity, springs, stiffness, rest_length, damping, elements, edge_spring,
     correction_matrix, axis_rest_length, correction_kind, rest_edge_direction, rest_volume, kappa, has_volume, length,
     unit, tension, push, forces, want_geometric, geometric, want_volume_jacobian, volume_coefficient, volume_direction,
     volume_gradient) = arrays
    n = positions.shape[0] // count
    n_springs, n_elements = springs.shape[0], elements.shape[0]
    g = geometric.shape[0] // count  # 0 for a forces-only workspace
    v = volume_coefficient.shape[0] // count
    no_int = np.zeros(1, dtype=np.int64)
    no_float = np.zeros(1)
    a, b = c * n_springs, (c + 1) * n_springs
    e0, e1 = c * n_elements, (c + 1) * n_elements
    model_forces(positions[c * n:(c + 1) * n], velocities[c * n:(c + 1) * n], use_velocity, springs,
                 stiffness[a:b], rest_length[a:b], damping[a:b], elements, edge_spring, correction_matrix[e0:e1],
                 axis_rest_length[e0:e1], correction_kind, rest_edge_direction[e0:e1], rest_volume[e0:e1],
                 kappa[e0:e1], has_volume, no_int, no_int, no_float, positions[c * n:(c + 1) * n], np.bool_(False),
                 length[a:b], unit[a:b], tension[a:b], push[e0:e1], forces[c * n:(c + 1) * n], want_geometric,
                 geometric[c * g:(c + 1) * g], want_volume_jacobian, volume_coefficient[c * v:(c + 1) * v],
                 volume_direction[c * v:(c + 1) * v], volume_gradient[c * v:(c + 1) * v])


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def model_forces_copies(count, active, arrays):
    """``model_forces`` (without the hourglass term) of the copies ``active`` (count,) bool of a
    stacked model of ``count`` equal copies (copies first: copy c's nodes, springs and elements are
    the c-th equal slices), one copy per numba thread at a time. ``arrays``: the tuple (positions,
    velocities, use_velocity, springs, stiffness, rest_length, damping, elements, edge_spring,
    correction_matrix, axis_rest_length, correction_kind, rest_edge_direction, rest_volume, kappa,
    has_volume, length, unit, tension, push, forces, want_geometric, geometric, want_volume_jacobian,
    volume_coefficient, volume_direction, volume_gradient) of ``model_forces``' arguments, where
    ``springs``, ``elements`` and ``edge_spring`` are ONE copy's topology (local indices) and every
    other array is the stacked model's. The copies are disjoint, so each writes only its own slices,
    in the stacked pass's order: the same floats as ``model_forces`` on the stacked model (the other
    copies' slices are left as they are)."""
    for c in prange(count):
        if active[c]:
            _model_forces_copy(c, count, arrays)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def model_forces_copies_serial(count, active, arrays):
    """``model_forces_copies`` in this thread only (some of the copies on one thread)."""
    for c in range(count):
        if active[c]:
            _model_forces_copy(c, count, arrays)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def volume_forces_add(positions, elements, rest_volume, kappa, forces):
    """Adds every element's volume-conservation force (docs/physics.md 4) to ``forces`` (N, 3): the
    body of ``volume_forces_jacobian_add`` without the stiffness terms."""
    none = np.empty((0, 8, 3))
    # a literal flag (two specialisations, both warmed up): the pruned branch decides which products
    # LLVM contracts into FMAs (FAST), so a run-time flag would change the floats
    _volume_forces(positions, elements, rest_volume, kappa, forces, False, np.empty(0), none, none)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def volume_forces_jacobian_add(positions, elements, rest_volume, kappa, forces, coefficient, direction, gradient):
    """``volume_forces_add`` that also fills the rank-one stiffness terms of
    ``volume_jacobian_terms``: coefficient (M,), direction and gradient (M, 8, 3)."""
    _volume_forces(positions, elements, rest_volume, kappa, forces, True, coefficient, direction, gradient)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _face_vector(a, b, c, d):
    """(x_c - x_a) x (x_d - x_b) of the face (a, b, c, d) (``topology.FACES``): twice its outward
    vector area a_S (m^2)."""
    return cross(sub(c, a), sub(d, b))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_scaled(out, i, scale, v):
    """out[i] += scale v, for an (N, 3) ``out``."""
    out[i, 0] += scale * v[0]
    out[i, 1] += scale * v[1]
    out[i, 2] += scale * v[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _set_scaled(out, m, n, scale, v):
    """out[m, n] = scale v, for an (M, 8, 3) ``out``."""
    out[m, n, 0] = scale * v[0]
    out[m, n, 1] = scale * v[1]
    out[m, n, 2] = scale * v[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _volume_gradient(d, gradient, m):
    """gradient[m] (8, 3) = dV/dx_n (m^2) of the exact trilinear volume V, from the element's
    ``corner_differences`` d: dV/dd_i is 1/12 of the signed crosses d_b x d_c of the triples of
    ``measure._VOLUME_TRIPLES`` that hold d_i (in that table's order), and dV/dx_0 = -sum_i dV/dd_i."""
    d1, d2, d3, d4, d5, d6, d7 = d
    x12, x13, x14, x15, x17 = cross(d1, d2), cross(d1, d3), cross(d1, d4), cross(d1, d5), cross(d1, d7)
    x23, x24, x26, x27 = cross(d2, d3), cross(d2, d4), cross(d2, d6), cross(d2, d7)
    x35, x36, x37 = cross(d3, d5), cross(d3, d6), cross(d3, d7)
    x45, x46, x47 = cross(d4, d5), cross(d4, d6), cross(d4, d7)
    x56, x57, x67 = cross(d5, d6), cross(d5, d7), cross(d6, d7)
    for c in range(3):
        g1 = (+ x23[c] + x35[c] + x37[c] - x45[c] - x57[c]) / 12.0
        g2 = (- x13[c] - x36[c] - x37[c] + x46[c] + x67[c]) / 12.0
        g3 = (+ x12[c] - x15[c] - x17[c] + x26[c] + x27[c] - x57[c] + x67[c]) / 12.0
        g4 = (+ x15[c] - x26[c] + x56[c] + x57[c] - x67[c]) / 12.0
        g5 = (+ x13[c] - x14[c] + x17[c] + x37[c] - x46[c] - x47[c] - x67[c]) / 12.0
        g6 = (- x23[c] + x24[c] - x27[c] - x37[c] + x45[c] + x47[c] + x57[c]) / 12.0
        g7 = (+ x13[c] - x15[c] - x23[c] + x26[c] - x35[c] + x36[c] + x45[c] - x46[c] - x56[c]) / 12.0
        # d_1 .. d_7 are the lexicographic corners 1 .. 7: VTK corners 1 3 2 4 5 7 6
        gradient[m, 0, c] = -(g1 + g2 + g3 + g4 + g5 + g6 + g7)
        gradient[m, 1, c] = g1
        gradient[m, 3, c] = g2
        gradient[m, 2, c] = g3
        gradient[m, 4, c] = g4
        gradient[m, 5, c] = g5
        gradient[m, 7, c] = g6
        gradient[m, 6, c] = g7


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def _volume_forces(positions, elements, rest_volume, kappa, forces, jacobian, coefficient, direction, gradient):
    """Adds every element's volume-conservation force (docs/physics.md 4) to ``forces`` (N, 3), with
    exact trilinear volumes (``measure.trilinear_volume``): one straight-line body per element, in
    registers (no scratch arrays). The force on node n is -kappa r |r| h_n with r = (V - V0) / V0 and
    h_n = sum of a_S / (4 A_H) over the node's three faces S (A_H the element's total face area).
    With ``jacobian``, also fills the rank-one stiffness terms of ``volume_jacobian_terms``:
    coefficient (M,), direction h and gradient (M, 8, 3); without it those arrays are not touched
    (may be empty).
    """
    for m in range(elements.shape[0]):
        if kappa[m] == 0.0:
            if jacobian:
                coefficient[m] = 0.0
            continue
        i0, i1, i2, i3 = elements[m, 0], elements[m, 1], elements[m, 2], elements[m, 3]
        i4, i5, i6, i7 = elements[m, 4], elements[m, 5], elements[m, 6], elements[m, 7]
        x0, x1, x2, x3 = row(positions, i0), row(positions, i1), row(positions, i2), row(positions, i3)
        x4, x5, x6, x7 = row(positions, i4), row(positions, i5), row(positions, i6), row(positions, i7)
        d = corner_differences(x0, x1, x2, x3, x4, x5, x6, x7)
        volume = trilinear_volume(d)
        # twice the face vector areas, faces x=0, x=1, y=0, y=1, z=0, z=1
        f0, f1 = _face_vector(x0, x4, x7, x3), _face_vector(x1, x2, x6, x5)
        f2, f3 = _face_vector(x0, x1, x5, x4), _face_vector(x3, x7, x6, x2)
        f4, f5 = _face_vector(x0, x3, x2, x1), _face_vector(x4, x5, x6, x7)
        area = 0.5 * (norm(f0) + norm(f1) + norm(f2) + norm(f3) + norm(f4) + norm(f5))
        relative = (volume - rest_volume[m]) / rest_volume[m]
        share = 1.0 / (8.0 * area)  # the 1/2 of each a_S, and 1 / (4 A_H)
        scale = -kappa[m] * relative * abs(relative) * share
        # each node's three faces, along local x, y, z
        h0, h1, h2, h3 = add(add(f0, f2), f4), add(add(f1, f2), f4), add(add(f1, f3), f4), add(add(f0, f3), f4)
        h4, h5, h6, h7 = add(add(f0, f2), f5), add(add(f1, f2), f5), add(add(f1, f3), f5), add(add(f0, f3), f5)
        _add_scaled(forces, i0, scale, h0)
        _add_scaled(forces, i1, scale, h1)
        _add_scaled(forces, i2, scale, h2)
        _add_scaled(forces, i3, scale, h3)
        _add_scaled(forces, i4, scale, h4)
        _add_scaled(forces, i5, scale, h5)
        _add_scaled(forces, i6, scale, h6)
        _add_scaled(forces, i7, scale, h7)
        if not jacobian:
            continue
        coefficient[m] = 2.0 * kappa[m] * abs(volume - rest_volume[m]) / rest_volume[m] ** 2
        _set_scaled(direction, m, 0, share, h0)
        _set_scaled(direction, m, 1, share, h1)
        _set_scaled(direction, m, 2, share, h2)
        _set_scaled(direction, m, 3, share, h3)
        _set_scaled(direction, m, 4, share, h4)
        _set_scaled(direction, m, 5, share, h5)
        _set_scaled(direction, m, 6, share, h6)
        _set_scaled(direction, m, 7, share, h7)
        _volume_gradient(d, gradient, m)


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
