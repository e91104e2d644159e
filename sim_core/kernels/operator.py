"""The implicit step's system operator A = M + h D + h^2 K: matrix-free products (one model,
``spring_operator``, ``apply_operator``; copy by copy, ``apply_copies``), the assembled matrix's data (``operator_matrix_data``) and the CSR / node-block
(BSR) matrix-vector products they use.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..geometry.topology import EDGES
from .fastmath import FAST, FAST_REDUCE
from .stress import add_outer

_EDGES = np.ascontiguousarray(EDGES)

#: The implicit step's operator data, as every operator kernel takes it (``apply_operator``,
#: ``operator_matrix_data``, the copies' kernels): the springs (S, 2) and their unit vectors (S, 3),
#: stiffness and damping (S,) N/m and N s/m, clamped geometric stiffness (S,) N/m; the node masses
#: (N,) kg; the elements (M, 8 or 4), each element's spring per edge (M, 12), the corrections'
#: matrices (M, 3, 3) and axis rest lengths (M, 3) m; the volume forces' coefficient (M,),
#: direction and gradient (M, 8, 3); the hourglass matrix in CSR (indptr, indices, data N/m);
#: the corrections' elongations and deltas (S,) (scratch); the stress correction's cells in
#: compressed rows (``Model.stress_cells``: indptr (C + 1,), nodes (nnz,), gradients (nnz, 3) 1/m),
#: their tangents (C, 9, 9) and the pattern positions of their node pairs' rows (P, 3)
#: (``Model.stress_pair_rows``), empty without it. Built by ``models.forces.ForceWorkspace`` (one
#: model) and ``copy_data`` (copy c of a stacked model).
OperatorData = namedtuple("OperatorData", (
    "springs", "unit", "stiffness", "damping", "geometric", "mass", "elements", "edge_spring",
    "correction_matrix", "axis_rest_length", "volume_coefficient", "volume_direction", "volume_gradient",
    "hg_indptr", "hg_indices", "hg_data", "elongation", "delta", "stress_indptr", "stress_nodes", "stress_gradient",
    "stress_tangent", "stress_positions"))


@njit(cache=True, nogil=True, error_model="numpy")
def csr_matvec_add(indptr, indices, data, vector, scale, out):
    """out += scale * A @ vector for a CSR matrix (flat dof vectors)."""
    for row in range(indptr.shape[0] - 1):
        total = 0.0
        for k in range(indptr[row], indptr[row + 1]):
            total += data[k] * vector[indices[k]]
        out[row] += scale * total


@njit(cache=True, nogil=True, error_model="numpy")
def _coupling_matvec_add(elements, edge_unit, correction_matrix, axis_rest_length, vector, scale, out):
    """out += scale * K_c vector, K_c = -G W^ G^T the corrections' strain coupling (matrix-free:
    per element 12 edge elongation rates -> 3 axis strains -> 3 pushes -> 12 edge forces)."""
    rate = np.empty(3)
    for m in range(elements.shape[0]):
        rate[:] = 0.0
        for e in range(12):
            p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
            elongation = 0.0
            for c in range(3):
                elongation += edge_unit[m, e, c] * (vector[3 * q + c] - vector[3 * p + c])
            rate[e // 4] += elongation
        for axis in range(3):
            rate[axis] *= 0.25 / axis_rest_length[m, axis]
        for e in range(12):
            j = e // 4
            push = (correction_matrix[m, j, 0] * rate[0] + correction_matrix[m, j, 1] * rate[1]
                    + correction_matrix[m, j, 2] * rate[2])
            p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
            for c in range(3):
                # force +push u on q, -push u on p; K = -df/dx
                out[3 * q + c] -= scale * push * edge_unit[m, e, c]
                out[3 * p + c] += scale * push * edge_unit[m, e, c]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _row_product(tangent, r, d0, d1, d2, d3, d4, d5, d6, d7, d8):
    """Row r of the (9, 9) ``tangent`` times (d0 .. d8), summed left to right."""
    return (tangent[r, 0] * d0 + tangent[r, 1] * d1 + tangent[r, 2] * d2 + tangent[r, 3] * d3 + tangent[r, 4] * d4
            + tangent[r, 5] * d5 + tangent[r, 6] * d6 + tangent[r, 7] * d7 + tangent[r, 8] * d8)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _stress_product(indptr, nodes, stress_gradient, stress_tangent, scale, vector, out):
    """out += scale * K_s vector, K_s the stress correction's stiffness: per cell (an element, or a
    smoothing domain) dF = sum_a v_a (x) b_a (9), dP = T dF with T (9, 9) its stiffness on F
    (``kernels.stress_correction_tangent_add``: V0 (A_NH - A_S), the implicit step's positive part),
    and out_a += dP b_a. Cells in compressed rows (``Model.stress_cells``: indptr (C + 1,), nodes and
    stress_gradient (nnz,), (nnz, 3) b_a), stress_tangent (C, 9, 9); flat dof vectors. dF and dP are
    held in scalars, so that no product's entries go through memory (docs/performance_notes.md,
    "Kernel-level choices")."""
    for m in range(indptr.shape[0] - 1):
        d = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        for e in range(indptr[m], indptr[m + 1]):
            node = nodes[e]
            d = add_outer(d, vector[3 * node], vector[3 * node + 1], vector[3 * node + 2], stress_gradient[e, 0],
                          stress_gradient[e, 1], stress_gradient[e, 2])
        d0, d1, d2, d3, d4, d5, d6, d7, d8 = d
        t = stress_tangent[m]
        p0 = scale * _row_product(t, 0, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p1 = scale * _row_product(t, 1, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p2 = scale * _row_product(t, 2, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p3 = scale * _row_product(t, 3, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p4 = scale * _row_product(t, 4, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p5 = scale * _row_product(t, 5, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p6 = scale * _row_product(t, 6, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p7 = scale * _row_product(t, 7, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        p8 = scale * _row_product(t, 8, d0, d1, d2, d3, d4, d5, d6, d7, d8)
        for e in range(indptr[m], indptr[m + 1]):
            node = nodes[e]
            b0, b1, b2 = stress_gradient[e, 0], stress_gradient[e, 1], stress_gradient[e, 2]
            out[3 * node] += p0 * b0 + p1 * b1 + p2 * b2
            out[3 * node + 1] += p3 * b0 + p4 * b1 + p5 * b2
            out[3 * node + 2] += p6 * b0 + p7 * b1 + p8 * b2


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def stress_diagonal_add(indptr, nodes, stress_gradient, stress_tangent, scale, diagonal):
    """diagonal (3 n,) += scale * the diagonal of K_s (``_stress_product``): entry (a, i) of cell m
    is sum_JL b_aJ T[3 i + J, 3 i + L] b_aL (the Jacobi preconditioners)."""
    for m in range(indptr.shape[0] - 1):
        for e in range(indptr[m], indptr[m + 1]):
            node = nodes[e]
            for i in range(3):
                total = 0.0
                for j in range(3):
                    for ll in range(3):
                        total += stress_gradient[e, j] * stress_tangent[m, 3 * i + j, 3 * i + ll] \
                            * stress_gradient[e, ll]
                diagonal[3 * node + i] += scale * total


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def spring_operator(springs, unit, stiffness, damping, geometric, mass, mass_scale, damping_scale, stiffness_scale,
                    elements, edge_spring, correction_matrix, axis_rest_length, coupling_scale,
                    volume_coefficient, volume_direction, volume_gradient, volume_scale,
                    hg_indptr, hg_indices, hg_data, hg_scale, mask, vector, out, elongation, delta,
                    stress_indptr, stress_nodes, stress_gradient, stress_tangent):
    """out = mask * (mass_scale M + damping_scale D + stiffness_scale (K_springs + K_s) + hg_scale K_hourglass
    + coupling_scale K_c + volume_scale K_v) @ vector, matrix-free from per-spring data.

    A spring's block is c_along u u^T + c_across (I - u u^T) with c_along = stiffness_scale k +
    damping_scale d and c_across = stiffness_scale g (g the clamped geometric stiffness), so the
    product needs the spring's elongation rate e = u . (v_b - v_a). The corrections' coupling K_c =
    -G W^ G^T (``_coupling_matvec_add``) reads the same elongation rates: each element sums them per
    axis into strain rates, turns them into pushes (W), and the pushes change the tension of its 12
    edge springs (``delta``), applied along the springs in the same scatter. K_s, the stress
    correction's stiffness of "baudet-hyperelastic" (``_stress_product``), is there when
    ``stress_tangent`` (M, 9, 9) has rows (empty (0, 9, 9) for the other models). Flat dof vectors;
    ``elongation`` and ``delta`` (S,) are scratch.
    """
    n_nodes = mass.shape[0]
    for node in range(n_nodes):
        w = mass_scale * mass[node]
        out[3 * node] = w * vector[3 * node]
        out[3 * node + 1] = w * vector[3 * node + 1]
        out[3 * node + 2] = w * vector[3 * node + 2]
    coupled = coupling_scale != 0.0
    n_springs = springs.shape[0]
    if coupled:
        for s in range(n_springs):
            a, b = springs[s, 0], springs[s, 1]
            elongation[s] = (unit[s, 0] * (vector[3 * b] - vector[3 * a])
                             + unit[s, 1] * (vector[3 * b + 1] - vector[3 * a + 1])
                             + unit[s, 2] * (vector[3 * b + 2] - vector[3 * a + 2]))
            delta[s] = 0.0
        for m in range(elements.shape[0]):
            r0 = 0.25 * coupling_scale * (elongation[edge_spring[m, 0]] + elongation[edge_spring[m, 1]]
                                          + elongation[edge_spring[m, 2]] + elongation[edge_spring[m, 3]]) \
                / axis_rest_length[m, 0]
            r1 = 0.25 * coupling_scale * (elongation[edge_spring[m, 4]] + elongation[edge_spring[m, 5]]
                                          + elongation[edge_spring[m, 6]] + elongation[edge_spring[m, 7]]) \
                / axis_rest_length[m, 1]
            r2 = 0.25 * coupling_scale * (elongation[edge_spring[m, 8]] + elongation[edge_spring[m, 9]]
                                          + elongation[edge_spring[m, 10]] + elongation[edge_spring[m, 11]]) \
                / axis_rest_length[m, 2]
            for j in range(3):
                p = correction_matrix[m, j, 0] * r0 + correction_matrix[m, j, 1] * r1 + correction_matrix[m, j, 2] * r2
                for q in range(4):
                    delta[edge_spring[m, 4 * j + q]] += p
    if volume_scale != 0.0:
        for m in range(elements.shape[0]):
            if volume_coefficient[m] == 0.0:
                continue
            rate = 0.0
            for n in range(8):
                node = elements[m, n]
                rate += (volume_gradient[m, n, 0] * vector[3 * node] + volume_gradient[m, n, 1] * vector[3 * node + 1]
                         + volume_gradient[m, n, 2] * vector[3 * node + 2])
            rate *= volume_scale * volume_coefficient[m]
            for n in range(8):
                node = elements[m, n]
                out[3 * node] += rate * volume_direction[m, n, 0]
                out[3 * node + 1] += rate * volume_direction[m, n, 1]
                out[3 * node + 2] += rate * volume_direction[m, n, 2]
    if stress_tangent.shape[0] != 0 and stiffness_scale != 0.0:
        _stress_product(stress_indptr, stress_nodes, stress_gradient, stress_tangent, stiffness_scale, vector, out)
    for s in range(n_springs):
        a, b = springs[s, 0], springs[s, 1]
        u0, u1, u2 = unit[s, 0], unit[s, 1], unit[s, 2]
        d0 = vector[3 * b] - vector[3 * a]
        d1 = vector[3 * b + 1] - vector[3 * a + 1]
        d2 = vector[3 * b + 2] - vector[3 * a + 2]
        across = stiffness_scale * geometric[s]
        along = stiffness_scale * stiffness[s] + damping_scale * damping[s] - across
        t = along * (u0 * d0 + u1 * d1 + u2 * d2)
        if coupled:
            t -= delta[s]
        f0 = t * u0 + across * d0
        f1 = t * u1 + across * d1
        f2 = t * u2 + across * d2
        out[3 * a] -= f0
        out[3 * a + 1] -= f1
        out[3 * a + 2] -= f2
        out[3 * b] += f0
        out[3 * b + 1] += f1
        out[3 * b + 2] += f2
    if hg_scale != 0.0:
        for row in range(hg_indptr.shape[0] - 1):
            total = 0.0
            for k in range(hg_indptr[row], hg_indptr[row + 1]):
                total += hg_data[k] * vector[hg_indices[k]]
            out[row] += hg_scale * total
    for i in range(out.shape[0]):
        out[i] *= mask[i]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _packed_spring_operator(data, scales, hg_scale, mask, vector, out):
    """``spring_operator`` on the packed ``data`` (``ForceWorkspace.operator_data``) with the scales
    ``scales[:5]`` and ``hg_scale`` for the hourglass term's CSR arrays in ``data``."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta,
     stress_indptr, stress_nodes, stress_gradient, stress_tangent, _) = data
    spring_operator(springs, unit, stiffness, damping, geometric, mass, scales[0], scales[1], scales[2],
                    elements, edge_spring, correction_matrix, axis_rest_length, scales[3],
                    volume_coefficient, volume_direction, volume_gradient, scales[4],
                    hg_indptr, hg_indices, hg_data, hg_scale, mask, vector, out, elongation, delta,
                    stress_indptr, stress_nodes, stress_gradient, stress_tangent)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def apply_packed(data, scales, mask, vector, out):
    _packed_spring_operator(data, scales, scales[5], mask, vector, out)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_REDUCE)
def apply_operator(data, scales, mask, vector, out):
    """``spring_operator`` with its arguments packed: ``data`` an ``OperatorData``, scales = (mass,
    damping, stiffness, coupling, volume, hourglass); the stress
    correction's stiffness K_s (stress_gradient (M, 8, 3), stress_tangent (M, 9, 9), or empty) goes
    with the stiffness scale."""
    apply_packed(data, scales, mask, vector, out)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _stress_matrix_add(indptr, nodes, gradient, tangent, positions, scale, out):
    """out (pattern data) += scale * B^T T B of every cell (``_stress_product``'s matrix): block (a, b)
    of cell m is sum_JL b_aJ T[3 i + J, 3 k + L] b_bL, added at ``positions`` (P, 3) (the rows of
    each of the cell's node pairs, cell by cell, a-major: ``Model.stress_pair_rows``)."""
    size = 0
    for m in range(indptr.shape[0] - 1):
        size = max(size, indptr[m + 1] - indptr[m])
    h = np.empty((9, size, 3))  # h[r, b, k] = scale sum_L T[r, 3 k + L] b_bL, per cell
    pair = 0
    for m in range(indptr.shape[0] - 1):
        first, count = indptr[m], indptr[m + 1] - indptr[m]
        for r in range(9):
            for n in range(count):
                for k in range(3):
                    total = 0.0
                    for ll in range(3):
                        total += tangent[m, r, 3 * k + ll] * gradient[first + n, ll]
                    h[r, n, k] = scale * total
        for a in range(count):
            b0, b1, b2 = gradient[first + a, 0], gradient[first + a, 1], gradient[first + a, 2]
            for n in range(count):
                for i in range(3):
                    row = positions[pair, i]
                    for k in range(3):
                        out[row + k] += b0 * h[3 * i, n, k] + b1 * h[3 * i + 1, n, k] + b2 * h[3 * i + 2, n, k]
                pair += 1


@njit(cache=True, nogil=True, error_model="numpy")
def operator_matrix_data(data, scales, spring_positions, element_positions, hg_positions, diagonal_positions, out):
    """``out`` (the model's ``BlockPattern`` data, zeroed here) = the matrix that ``apply_operator``
    applies with these ``scales`` (no mask): mass, spring blocks (clamped geometric term), the
    corrections' coupling -G W^ G^T along the current spring directions, the volume forces'
    rank-one c h grad(V)^T, the stress correction's element blocks B^T T B and the hourglass matrix, the same terms as ``spring_operator`` so that
    the assembled matrix reproduces the matrix-free product to rounding (the factorised
    preconditioner of ``ImplicitEuler``). spring_positions (S, 4, 3, 3) (blocks aa, bb, ab, ba),
    element_positions (M, n, n, 3, 3), hg_positions (nnz_hg,), diagonal_positions (3N,): positions
    in ``out`` (``Model``'s derived arrays)."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta,
     stress_indptr, stress_nodes, stress_gradient, stress_tangent, stress_positions) = data
    mass_scale, damping_scale, stiffness_scale = scales[0], scales[1], scales[2]
    coupling_scale, volume_scale, hg_scale = scales[3], scales[4], scales[5]
    out[:] = 0.0
    for node in range(mass.shape[0]):
        for c in range(3):
            out[diagonal_positions[3 * node + c]] += mass_scale * mass[node]
    for s in range(springs.shape[0]):
        across = stiffness_scale * geometric[s]
        along = stiffness_scale * stiffness[s] + damping_scale * damping[s] - across
        for i in range(3):
            for j in range(3):
                value = along * unit[s, i] * unit[s, j]
                if i == j:
                    value += across
                out[spring_positions[s, 0, i, j]] += value
                out[spring_positions[s, 1, i, j]] += value
                out[spring_positions[s, 2, i, j]] -= value
                out[spring_positions[s, 3, i, j]] -= value
    if coupling_scale != 0.0:
        local = np.empty((12, 2), dtype=np.int64)  # element-local end nodes of the 12 edge springs
        for m in range(elements.shape[0]):
            for e in range(12):
                s = edge_spring[m, e]
                for end in range(2):
                    node = springs[s, end]
                    for k in range(8):
                        if elements[m, k] == node:
                            local[e, end] = k
            for e in range(12):  # row edge (its delta), column edge r (its elongation rate)
                se = edge_spring[m, e]
                ae, be = local[e, 0], local[e, 1]
                for r in range(12):
                    sr = edge_spring[m, r]
                    ar, br = local[r, 0], local[r, 1]
                    coefficient = correction_matrix[m, e // 4, r // 4] * 0.25 * coupling_scale \
                        / axis_rest_length[m, r // 4]
                    for i in range(3):
                        for j in range(3):
                            value = coefficient * unit[se, i] * unit[sr, j]
                            out[element_positions[m, ae, br, i, j]] += value
                            out[element_positions[m, ae, ar, i, j]] -= value
                            out[element_positions[m, be, br, i, j]] -= value
                            out[element_positions[m, be, ar, i, j]] += value
    if volume_scale != 0.0:
        for m in range(elements.shape[0]):
            coefficient = volume_scale * volume_coefficient[m]
            if coefficient == 0.0:
                continue
            for k in range(8):
                for n in range(8):
                    for i in range(3):
                        for j in range(3):
                            out[element_positions[m, k, n, i, j]] += \
                                coefficient * volume_direction[m, k, i] * volume_gradient[m, n, j]
    if stress_tangent.shape[0] != 0 and stiffness_scale != 0.0:  # B^T T B per cell
        _stress_matrix_add(stress_indptr, stress_nodes, stress_gradient, stress_tangent, stress_positions,
                           stiffness_scale, out)
    if hg_scale != 0.0:
        for k in range(hg_data.shape[0]):
            out[hg_positions[k]] += hg_scale * hg_data[k]


@njit(cache=True, nogil=True, error_model="numpy")
def operator_matrix_data_blocks(data, scales, spring_positions, element_positions, hg_positions, diagonal_positions,
                                node_edge, node_sign, out):
    """``operator_matrix_data`` (the same matrix, up to rounding) with the corrections' coupling
    assembled per node pair: at element m, node k lies on exactly one edge of each axis group g
    (``node_edge[m, k, g]``, the spring; ``node_sign`` +1 where k is its first node, else -1), so
    the coupling block of nodes (k, n) is sum_g R[k, g] Q[n, g]^T with R[k, g] = sign u_edge and
    Q[n, g] = -sum_h W[g, h] sign 0.25 c u_edge(n, h) / L_h: 64 blocks of 27 products per
    element instead of 144 edge pairs of 36 scattered entries (4x fewer operations)."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta,
     stress_indptr, stress_nodes, stress_gradient, stress_tangent, stress_positions) = data
    coupling_scale = scales[3]
    no_coupling = (scales[0], scales[1], scales[2], 0.0, scales[4], scales[5])
    operator_matrix_data(data, no_coupling, spring_positions, element_positions, hg_positions, diagonal_positions,
                         out)
    if coupling_scale == 0.0:
        return
    r = np.empty((8, 3, 3))
    q = np.empty((8, 3, 3))
    p = np.empty((8, 3, 3))
    for m in range(elements.shape[0]):
        for k in range(8):
            for g in range(3):
                s = node_edge[m, k, g]
                sign = node_sign[m, k, g]
                w = -sign * 0.25 * coupling_scale / axis_rest_length[m, g]
                for i in range(3):
                    r[k, g, i] = sign * unit[s, i]
                    p[k, g, i] = w * unit[s, i]
        for n in range(8):
            for g in range(3):
                for j in range(3):
                    q[n, g, j] = (correction_matrix[m, g, 0] * p[n, 0, j] + correction_matrix[m, g, 1] * p[n, 1, j]
                                  + correction_matrix[m, g, 2] * p[n, 2, j])
        for k in range(8):
            for n in range(8):
                for i in range(3):
                    r0, r1, r2 = r[k, 0, i], r[k, 1, i], r[k, 2, i]
                    for j in range(3):
                        out[element_positions[m, k, n, i, j]] += r0 * q[n, 0, j] + r1 * q[n, 1, j] + r2 * q[n, 2, j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def bsr3_matvec_add(indptr, indices, data, vector, scale, out):
    """out += scale * A @ vector for a matrix of 3 x 3 node blocks (``forces.hourglass_blocks``:
    block indptr (n + 1,), node columns (nb,), row-major block values (9 nb,); flat dof vectors):
    one index and three vector loads per 9 values (``csr_matvec_add`` reads one per value)."""
    for i in range(indptr.shape[0] - 1):
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[q]
            b = 9 * q
            x0, x1, x2 = vector[j], vector[j + 1], vector[j + 2]
            t0 += data[b] * x0 + data[b + 1] * x1 + data[b + 2] * x2
            t1 += data[b + 3] * x0 + data[b + 4] * x1 + data[b + 5] * x2
            t2 += data[b + 6] * x0 + data[b + 7] * x1 + data[b + 8] * x2
        out[3 * i] += scale * t0
        out[3 * i + 1] += scale * t1
        out[3 * i + 2] += scale * t2


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, hg_block_data, mask, vector, out):
    """``apply_packed`` with the hourglass term read from the node-block (BSR) form of the hourglass matrix
    (``hg_block_indptr`` (n + 1,), ``hg_block_indices`` (nb,) node columns, ``hg_block_data`` (9 nb,)
    row-major 3 x 3 blocks) instead of the CSR arrays in ``data``: one index and three vector loads
    per 9 values (faster than the scalar CSR loop, which dominated the operator product). The same
    sums, in the same column order per row (rounding aside)."""
    _packed_spring_operator(data, scales, 0.0, ones, vector, out)
    if scales[5] != 0.0:
        bsr3_matvec_add(hg_block_indptr, hg_block_indices, hg_block_data, vector, scales[5], out)
    for i in range(out.shape[0]):
        out[i] *= mask[i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def apply_operator_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, hg_block_data, mask, vector, out):
    """``apply_operator`` with the hourglass term read from the node-block (BSR) form of the
    hourglass matrix (``apply_blocks``; the single envs' implicit step, ``ImplicitEuler``)."""
    apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, hg_block_data, mask, vector, out)


@njit(cache=True, nogil=True, inline="always")
def copy_data(stacked, hg_rows, hg_group, c):
    """``OperatorData`` of copy ``c`` of a stacked model (copies first; ``solve_copies_lu``,
    ``factor_copies``): its slices of the per-spring, per-node and per-element arrays, the shared
    topology, and its group's hourglass values ``hg_rows[hg_group[c]]``. A plain tuple of the
    ``OperatorData`` fields in their order: numba's parallel analysis fails on a named tuple built
    inside a ``prange`` body."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_unused, elongation,
     delta, stress_indptr, stress_nodes, stress_gradient, stress_tangent, stress_positions) = stacked
    n_springs, n_elements, n_nodes = springs.shape[0], elements.shape[0], mass.shape[0] // hg_group.shape[0]
    a, b = c * n_springs, (c + 1) * n_springs
    e0, e1 = c * n_elements, (c + 1) * n_elements
    n_cells, nnz = max(stress_indptr.shape[0] - 1, 0), stress_nodes.shape[0]
    return (springs, unit[a:b], stiffness[a:b], damping[a:b], geometric[a:b], mass[c * n_nodes:(c + 1) * n_nodes],
            elements, edge_spring, correction_matrix[e0:e1], axis_rest_length[e0:e1], volume_coefficient[e0:e1],
            volume_direction[e0:e1], volume_gradient[e0:e1], hg_indptr, hg_indices, hg_rows[hg_group[c]],
            elongation[a:b], delta[a:b], stress_indptr, stress_nodes, stress_gradient[c * nnz:(c + 1) * nnz],
            stress_tangent[c * n_cells:(c + 1) * n_cells], stress_positions)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def apply_copy(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones, mask,
                vector, out, c):
    """out = mask * A_c vector: ``apply_blocks`` on copy ``c``'s data (``copy_data``); (3 n,) vectors."""
    apply_blocks(copy_data(stacked, hg_rows, hg_group, c), scales, ones, hg_block_indptr, hg_block_indices,
                  hg_block_rows[hg_group[c]], mask, vector, out)


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def apply_copies(stacked, scales, hg_rows, hg_group, vector, active, out, hg_block_indptr, hg_block_indices,
                 hg_block_rows):
    """out (N, 3 n) = each ``active`` (N,) bool copy's operator A_c (``apply_operator``'s, the
    hourglass term in node blocks) times its row of ``vector`` (N, 3 n), the copies shared among
    numba's threads (``solve_copies_lu``'s arguments: copy c's per-spring and per-element scratch
    are its own slices); the other rows of ``out`` are left as they are."""
    ones = np.ones(vector.shape[1])
    for c in prange(vector.shape[0]):
        if active[c]:
            apply_copy(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones,
                        ones, vector[c], out[c], np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def apply_copies_serial(stacked, scales, hg_rows, hg_group, vector, active, out, hg_block_indptr, hg_block_indices,
                        hg_block_rows):
    """``apply_copies`` in this thread only (one thread, a forked process): the same floats."""
    ones = np.ones(vector.shape[1])
    for c in range(vector.shape[0]):
        if active[c]:
            apply_copy(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones,
                        ones, vector[c], out[c], c)
