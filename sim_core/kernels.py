"""Compiled (numba) kernels for the per-step hot path: forces and the implicit Euler solve.

Each kernel is a plain loop over springs or elements compiled once (``cache=True`` keeps the
machine code between runs). The numpy formulation in ``forces.py`` is the readable reference the
tests compare these kernels with; formulas cite shared/physics.md. SI units.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .mesh import EDGES, FACES, GAUSS_GRADIENTS, GAUSS_POINTS

_EDGES = np.ascontiguousarray(EDGES)
_FACES = np.ascontiguousarray(FACES)
_GRADIENTS = np.ascontiguousarray(GAUSS_GRADIENTS)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def correction_pass(length, edge_spring, correction_matrix, axis_rest_length, push):
    """T_j per element (physics.md 3): push[m, j] = sum_k W[m, j, k] eps_k."""
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


@njit(cache=True, error_model="numpy")
def subtract_pushes(edge_spring, push, tension):
    """Projected corrections act along the current edge: a push T lowers the edge's tension by T."""
    for m in range(edge_spring.shape[0]):
        for e in range(12):
            tension[edge_spring[m, e]] -= push[m, e // 4]


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def fixed_direction_corrections(elements, push, rest_direction, forces):
    """The published variant: corrections along the rest directions of the element edges."""
    for m in range(elements.shape[0]):
        for e in range(12):
            t = push[m, e // 4]
            p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
            for c in range(3):
                forces[q, c] += t * rest_direction[m, e, c]
                forces[p, c] -= t * rest_direction[m, e, c]


#: VTK corner of each lexicographic corner a + 2 b + 4 c.
_LEXICOGRAPHIC_TO_VTK = np.array([0, 1, 3, 2, 4, 5, 7, 6])


@njit(cache=True, error_model="numpy", inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, error_model="numpy")
def hex_volume(corner, d=None):
    """Exact volume (m^3) of a trilinear hexahedron from its (8, 3) corners, VTK order.

    The integral of det J is a cubic form in the corners; written with d_i = x_i - x_0 for the
    corners in lexicographic order (i = a + 2 b + 4 c at local (a, b, c)) it is (1/12) sum of 15
    triple products, grouped here into 9 cross products (coefficients fitted to, and tested
    against, 2x2x2 Gauss quadrature, which is exact for this integrand).
    """
    if d is None:
        d = np.empty((8, 3))  # scratch (pass one in hot loops: no allocation per element)
    for n in range(8):
        vtk = _LEXICOGRAPHIC_TO_VTK[n]
        for c in range(3):
            d[n, c] = corner[vtk, c] - corner[0, c]
    a = _cross(d[2, 0], d[2, 1], d[2, 2], d[3, 0], d[3, 1], d[3, 2])
    b = _cross(d[3, 0], d[3, 1], d[3, 2], d[5, 0] + d[7, 0], d[5, 1] + d[7, 1], d[5, 2] + d[7, 2])
    e = _cross(d[5, 0], d[5, 1], d[5, 2], d[4, 0] - d[7, 0], d[4, 1] - d[7, 1], d[4, 2] - d[7, 2])
    volume = d[1, 0] * (a[0] + b[0] + e[0]) + d[1, 1] * (a[1] + b[1] + e[1]) + d[1, 2] * (a[2] + b[2] + e[2])
    a = _cross(d[3, 0], d[3, 1], d[3, 2], d[6, 0] + d[7, 0], d[6, 1] + d[7, 1], d[6, 2] + d[7, 2])
    b = _cross(d[6, 0], d[6, 1], d[6, 2], d[7, 0] - d[4, 0], d[7, 1] - d[4, 1], d[7, 2] - d[4, 2])
    volume += d[2, 0] * (b[0] - a[0]) + d[2, 1] * (b[1] - a[1]) + d[2, 2] * (b[2] - a[2])
    a = _cross(d[6, 0] - d[5, 0], d[6, 1] - d[5, 1], d[6, 2] - d[5, 2], d[7, 0], d[7, 1], d[7, 2])
    volume += d[3, 0] * a[0] + d[3, 1] * a[1] + d[3, 2] * a[2]
    six_seven = _cross(d[6, 0], d[6, 1], d[6, 2], d[7, 0], d[7, 1], d[7, 2])
    a = _cross(d[5, 0], d[5, 1], d[5, 2], d[6, 0] + d[7, 0], d[6, 1] + d[7, 1], d[6, 2] + d[7, 2])
    volume += d[4, 0] * (a[0] - six_seven[0]) + d[4, 1] * (a[1] - six_seven[1]) + d[4, 2] * (a[2] - six_seven[2])
    volume -= d[5, 0] * six_seven[0] + d[5, 1] * six_seven[1] + d[5, 2] * six_seven[2]
    return volume / 12.0


#: The 15 (a, b, c, sign) of V = 1/12 sum sign d_a . (d_b x d_c), lexicographic corners.
_VOLUME_TRIPLES = np.array([
    [1, 2, 3, 1], [1, 3, 5, 1], [1, 3, 7, 1], [1, 4, 5, -1], [1, 5, 7, -1], [2, 3, 6, -1], [2, 3, 7, -1],
    [2, 4, 6, 1], [2, 6, 7, 1], [3, 5, 7, -1], [3, 6, 7, 1], [4, 5, 6, 1], [4, 5, 7, 1], [4, 6, 7, -1],
    [5, 6, 7, -1]])


@njit(cache=True, error_model="numpy")
def volume_jacobian_terms(positions, elements, rest_volume, kappa, coefficient, direction, gradient):
    """Per element the volume forces' stiffness K_v = c h grad(V)^T (physics.md 4): the coefficient
    c = 2 kappa |dV| / V0^2 (N/m^4... per m^3 of volume change), the force directions h (M, 8, 3),
    a_S / (4 A_H) summed over the node's faces, and the volume gradient (M, 8, 3) in m^2."""
    corner = np.empty((8, 3))
    d = np.empty((8, 3))
    grad_lex = np.empty((8, 3))
    area = np.empty((6, 3))
    for m in range(elements.shape[0]):
        coefficient[m] = 0.0
        if kappa[m] == 0.0:
            continue
        for n in range(8):
            for c in range(3):
                corner[n, c] = positions[elements[m, n], c]
        volume = hex_volume(corner, d)  # also fills d (lexicographic differences)
        coefficient[m] = 2.0 * kappa[m] * abs(volume - rest_volume[m]) / rest_volume[m] ** 2
        grad_lex[:] = 0.0
        for t in range(15):
            a, b, cc, sign = _VOLUME_TRIPLES[t, 0], _VOLUME_TRIPLES[t, 1], _VOLUME_TRIPLES[t, 2], _VOLUME_TRIPLES[t, 3]
            w = sign / 12.0
            x = _cross(d[b, 0], d[b, 1], d[b, 2], d[cc, 0], d[cc, 1], d[cc, 2])
            y = _cross(d[cc, 0], d[cc, 1], d[cc, 2], d[a, 0], d[a, 1], d[a, 2])
            z = _cross(d[a, 0], d[a, 1], d[a, 2], d[b, 0], d[b, 1], d[b, 2])
            for c in range(3):
                grad_lex[a, c] += w * x[c]
                grad_lex[b, c] += w * y[c]
                grad_lex[cc, c] += w * z[c]
        for c in range(3):
            total = 0.0
            for n in range(1, 8):
                total += grad_lex[n, c]
            grad_lex[0, c] = -total
        for n in range(8):
            vtk = _LEXICOGRAPHIC_TO_VTK[n]
            for c in range(3):
                gradient[m, vtk, c] = grad_lex[n, c]
        total_area = 0.0
        for f in range(6):
            n0, n1, n2, n3 = _FACES[f, 0], _FACES[f, 1], _FACES[f, 2], _FACES[f, 3]
            a0, a1, a2 = _cross(corner[n2, 0] - corner[n0, 0], corner[n2, 1] - corner[n0, 1],
                                corner[n2, 2] - corner[n0, 2], corner[n3, 0] - corner[n1, 0],
                                corner[n3, 1] - corner[n1, 1], corner[n3, 2] - corner[n1, 2])
            area[f, 0], area[f, 1], area[f, 2] = 0.5 * a0, 0.5 * a1, 0.5 * a2
            total_area += np.sqrt(area[f, 0] ** 2 + area[f, 1] ** 2 + area[f, 2] ** 2)
        direction[m] = 0.0
        for f in range(6):
            for k in range(4):
                for c in range(3):
                    direction[m, _FACES[f, k], c] += area[f, c] / (4.0 * total_area)


@njit(cache=True, error_model="numpy")
def volume_pass(positions, elements, rest_volume, kappa, forces):
    """Volume-conservation forces (physics.md 4) with exact trilinear element volumes."""
    corner = np.empty((8, 3))
    scratch = np.empty((8, 3))
    area = np.empty((6, 3))
    for m in range(elements.shape[0]):
        if kappa[m] == 0.0:
            continue
        for n in range(8):
            for c in range(3):
                corner[n, c] = positions[elements[m, n], c]
        volume = hex_volume(corner, scratch)
        relative = (volume - rest_volume[m]) / rest_volume[m]
        phi = -kappa[m] * relative * abs(relative)
        total_area = 0.0
        for f in range(6):
            n0, n1, n2, n3 = _FACES[f, 0], _FACES[f, 1], _FACES[f, 2], _FACES[f, 3]
            d1x = corner[n2, 0] - corner[n0, 0]
            d1y = corner[n2, 1] - corner[n0, 1]
            d1z = corner[n2, 2] - corner[n0, 2]
            d2x = corner[n3, 0] - corner[n1, 0]
            d2y = corner[n3, 1] - corner[n1, 1]
            d2z = corner[n3, 2] - corner[n1, 2]
            area[f, 0] = 0.5 * (d1y * d2z - d1z * d2y)
            area[f, 1] = 0.5 * (d1z * d2x - d1x * d2z)
            area[f, 2] = 0.5 * (d1x * d2y - d1y * d2x)
            total_area += np.sqrt(area[f, 0] ** 2 + area[f, 1] ** 2 + area[f, 2] ** 2)
        scale = phi / (4.0 * total_area)
        for f in range(6):
            for k in range(4):
                node = elements[m, _FACES[f, k]]
                for c in range(3):
                    forces[node, c] += scale * area[f, c]


@njit(cache=True, error_model="numpy")
def csr_matvec_add(indptr, indices, data, vector, scale, out):
    """out += scale * A @ vector for a CSR matrix (flat dof vectors)."""
    for row in range(indptr.shape[0] - 1):
        total = 0.0
        for k in range(indptr[row], indptr[row + 1]):
            total += data[k] * vector[indices[k]]
        out[row] += scale * total


# -- implicit Euler -----------------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def assemble_implicit(block_of_spring, n_blocks, diagonal_block, unit, length, tension, stiffness,
                      damping, mass, dt, clamp, blocks):
    """Blocks (3x3 per node pair) of M + dt D + dt^2 K for the springs (geometric term clamped)."""
    blocks[:] = 0.0
    for node in range(mass.shape[0]):
        for c in range(3):
            blocks[diagonal_block[node], c, c] = mass[node]
    for s in range(unit.shape[0]):
        geometric = tension[s] / length[s]
        if clamp and geometric < 0.0:
            geometric = 0.0
        along = dt * dt * stiffness[s] + dt * damping[s]
        across = dt * dt * geometric
        for r in range(3):
            for c in range(3):
                value = (along - across) * unit[s, r] * unit[s, c]
                if r == c:
                    value += across
                blocks[block_of_spring[s, 0], r, c] += value
                blocks[block_of_spring[s, 1], r, c] += value
                blocks[block_of_spring[s, 2], r, c] -= value
                blocks[block_of_spring[s, 3], r, c] -= value


@njit(cache=True, error_model="numpy")
def _block_matvec(node_indptr, node_indices, blocks, vector, out):
    for node in range(node_indptr.shape[0] - 1):
        x0 = 0.0
        x1 = 0.0
        x2 = 0.0
        for k in range(node_indptr[node], node_indptr[node + 1]):
            col = node_indices[k]
            v0, v1, v2 = vector[3 * col], vector[3 * col + 1], vector[3 * col + 2]
            x0 += blocks[k, 0, 0] * v0 + blocks[k, 0, 1] * v1 + blocks[k, 0, 2] * v2
            x1 += blocks[k, 1, 0] * v0 + blocks[k, 1, 1] * v1 + blocks[k, 1, 2] * v2
            x2 += blocks[k, 2, 0] * v0 + blocks[k, 2, 1] * v1 + blocks[k, 2, 2] * v2
        out[3 * node] = x0
        out[3 * node + 1] = x1
        out[3 * node + 2] = x2


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _volume_matvec_add(elements, coefficient, direction, gradient, vector, scale, out):
    """out += scale * K_v vector with K_v = sum_e c_e h_e grad(V_e)^T, the volume forces' rank-one
    stiffness per element (physics.md 4; see forces.volume_terms)."""
    for m in range(elements.shape[0]):
        if coefficient[m] == 0.0:
            continue
        rate = 0.0
        for n in range(8):
            node = elements[m, n]
            for c in range(3):
                rate += gradient[m, n, c] * vector[3 * node + c]
        rate *= scale * coefficient[m]
        for n in range(8):
            node = elements[m, n]
            for c in range(3):
                out[3 * node + c] += rate * direction[m, n, c]


@njit(cache=True, error_model="numpy")
def _operator(node_indptr, node_indices, blocks, hg_indptr, hg_indices, hg_data, hg_scale,
              elements, edge_unit, correction_matrix, axis_rest_length, coupling_scale, mask, vector, out,
              volume_coefficient=None, volume_direction=None, volume_gradient=None, volume_scale=0.0):
    _block_matvec(node_indptr, node_indices, blocks, vector, out)
    if hg_scale != 0.0:
        csr_matvec_add(hg_indptr, hg_indices, hg_data, vector, hg_scale, out)
    if coupling_scale != 0.0:
        _coupling_matvec_add(elements, edge_unit, correction_matrix, axis_rest_length, vector, coupling_scale, out)
    if volume_coefficient is not None:
        if volume_scale != 0.0:
            _volume_matvec_add(elements, volume_coefficient, volume_direction, volume_gradient, vector,
                               volume_scale, out)
    for i in range(out.shape[0]):
        out[i] *= mask[i]


@njit(cache=True, error_model="numpy")
def solve_implicit(node_indptr, node_indices, blocks, diagonal_block, hg_indptr, hg_indices, hg_data, hg_scale,
                   elements, edge_unit, correction_matrix, axis_rest_length, coupling_scale,
                   mask, rhs, guess, tolerance, max_iterations, symmetric,
                   volume_coefficient=None, volume_direction=None, volume_gradient=None, volume_scale=0.0):
    """Jacobi-preconditioned CG (symmetric) or BiCGSTAB on the masked system. Returns
    (solution, iterations, relative residual)."""
    n = rhs.shape[0]
    inverse_diagonal = np.empty(n)
    for node in range(diagonal_block.shape[0]):
        for c in range(3):
            value = blocks[diagonal_block[node], c, c]
            inverse_diagonal[3 * node + c] = mask[3 * node + c] / value if value > 0 else 0.0
    if hg_scale != 0.0:  # include the hourglass diagonal in the preconditioner
        for row in range(n):
            for k in range(hg_indptr[row], hg_indptr[row + 1]):
                if hg_indices[k] == row and inverse_diagonal[row] > 0:
                    inverse_diagonal[row] = 1.0 / (1.0 / inverse_diagonal[row] + hg_scale * hg_data[k])
    x = guess * mask
    work = np.empty(n)
    _operator(node_indptr, node_indices, blocks, hg_indptr, hg_indices, hg_data, hg_scale, elements, edge_unit,
              correction_matrix, axis_rest_length, coupling_scale, mask, x, work,
              volume_coefficient, volume_direction, volume_gradient, volume_scale)
    r = rhs * mask - work
    norm_b = np.sqrt(np.dot(rhs, rhs))
    if norm_b == 0.0:
        return np.zeros(n), 0, 0.0
    residual = np.sqrt(np.dot(r, r)) / norm_b
    iterations = 0
    if symmetric:
        z = inverse_diagonal * r
        p = z.copy()
        rz = np.dot(r, z)
        while residual > tolerance and iterations < max_iterations:
            _operator(node_indptr, node_indices, blocks, hg_indptr, hg_indices, hg_data, hg_scale, elements,
                      edge_unit, correction_matrix, axis_rest_length, coupling_scale, mask, p, work,
                      volume_coefficient, volume_direction, volume_gradient, volume_scale)
            curvature = np.dot(p, work)
            if curvature <= 0.0:
                break
            alpha = rz / curvature
            x += alpha * p
            r -= alpha * work
            z = inverse_diagonal * r
            rz_new = np.dot(r, z)
            p = z + (rz_new / rz) * p
            rz = rz_new
            iterations += 1
            residual = np.sqrt(np.dot(r, r)) / norm_b
        return x, iterations, residual
    # right-preconditioned BiCGSTAB
    r_hat = r.copy()
    rho = 1.0
    alpha = 1.0
    omega = 1.0
    v = np.zeros(n)
    p = np.zeros(n)
    t = np.empty(n)
    while residual > tolerance and iterations < max_iterations:
        rho_new = np.dot(r_hat, r)
        if rho_new == 0.0 or omega == 0.0:
            break
        beta = (rho_new / rho) * (alpha / omega)
        rho = rho_new
        p = r + beta * (p - omega * v)
        p_hat = inverse_diagonal * p
        _operator(node_indptr, node_indices, blocks, hg_indptr, hg_indices, hg_data, hg_scale, elements,
                  edge_unit, correction_matrix, axis_rest_length, coupling_scale, mask, p_hat, v,
                  volume_coefficient, volume_direction, volume_gradient, volume_scale)
        denominator = np.dot(r_hat, v)
        if denominator == 0.0:
            break
        alpha = rho / denominator
        s = r - alpha * v
        iterations += 1
        if np.sqrt(np.dot(s, s)) / norm_b <= tolerance:
            x += alpha * p_hat
            r = s
            residual = np.sqrt(np.dot(r, r)) / norm_b
            break
        s_hat = inverse_diagonal * s
        _operator(node_indptr, node_indices, blocks, hg_indptr, hg_indices, hg_data, hg_scale, elements,
                  edge_unit, correction_matrix, axis_rest_length, coupling_scale, mask, s_hat, t,
                  volume_coefficient, volume_direction, volume_gradient, volume_scale)
        tt = np.dot(t, t)
        omega = np.dot(t, s) / tt if tt > 0 else 0.0
        x += alpha * p_hat + omega * s_hat
        r = s - omega * t
        residual = np.sqrt(np.dot(r, r)) / norm_b
    return x, iterations, residual


@njit(cache=True, error_model="numpy")
def edge_units(positions, elements, out):
    """(M, 12, 3) current unit vectors of every element edge (local orientation)."""
    for m in range(elements.shape[0]):
        for e in range(12):
            p, q = elements[m, _EDGES[e, 0]], elements[m, _EDGES[e, 1]]
            dx = positions[q, 0] - positions[p, 0]
            dy = positions[q, 1] - positions[p, 1]
            dz = positions[q, 2] - positions[p, 2]
            norm = np.sqrt(dx * dx + dy * dy + dz * dz)
            out[m, e, 0] = dx / norm
            out[m, e, 1] = dy / norm
            out[m, e, 2] = dz / norm


@njit(cache=True, error_model="numpy")
def health(positions, velocities, low, high):
    """(all finite, max speed in m/s, all nodes inside [low, high]) in one pass."""
    finite = True
    inside = True
    max_speed_squared = 0.0
    for node in range(positions.shape[0]):
        speed_squared = 0.0
        for c in range(3):
            x = positions[node, c]
            v = velocities[node, c]
            if not (np.isfinite(x) and np.isfinite(v)):
                finite = False
            if x < low[c] or x > high[c]:
                inside = False
            speed_squared += v * v
        if speed_squared > max_speed_squared:
            max_speed_squared = speed_squared
    return finite, np.sqrt(max_speed_squared), inside


@njit(cache=True, error_model="numpy")
def any_inverted(positions, elements, neighbours, signs):
    """True when a corner Jacobian (signed corner frame volume) of any element is <= 0."""
    for m in range(elements.shape[0]):
        for corner in range(8):
            o = elements[m, corner]
            a, b, c = elements[m, neighbours[corner, 0]], elements[m, neighbours[corner, 1]], elements[m, neighbours[corner, 2]]
            ax, ay, az = positions[a, 0] - positions[o, 0], positions[a, 1] - positions[o, 1], positions[a, 2] - positions[o, 2]
            bx, by, bz = positions[b, 0] - positions[o, 0], positions[b, 1] - positions[o, 1], positions[b, 2] - positions[o, 2]
            cx, cy, cz = positions[c, 0] - positions[o, 0], positions[c, 1] - positions[o, 1], positions[c, 2] - positions[o, 2]
            det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
            if signs[corner] * det <= 0.0:
                return True
    return False
