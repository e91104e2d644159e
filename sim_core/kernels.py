"""Compiled (numba) kernels for the per-step hot path: forces and the implicit Euler solve.

Each kernel is a plain loop over springs or elements compiled once (``cache=True`` keeps the
machine code between runs). The serial kernels release the GIL (``nogil=True``): Python threads
run them at once (the vector envs reset their copies on several threads, whose static solves call
them; a kernel only writes the arrays it is given). The numpy formulation in ``forces.py`` is the
readable reference the tests compare these kernels with; formulas cite shared/physics.md. SI units.
"""

from __future__ import annotations

import os

import numpy as np
from numba import njit, prange

from .topology import EDGES, FACES, GAUSS_GRADIENTS

_EDGES = np.ascontiguousarray(EDGES)
_FACES = np.ascontiguousarray(FACES)
_GRADIENTS = np.ascontiguousarray(GAUSS_GRADIENTS)


@njit(cache=True, nogil=True, error_model="numpy")
def spring_lengths(positions, springs, length):
    """Lengths (m) of every spring into ``length`` (S,)."""
    for s in range(springs.shape[0]):
        a, b = springs[s, 0], springs[s, 1]
        dx = positions[b, 0] - positions[a, 0]
        dy = positions[b, 1] - positions[a, 1]
        dz = positions[b, 2] - positions[a, 2]
        length[s] = np.sqrt(dx * dx + dy * dy + dz * dz)


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


#: VTK corner of each lexicographic corner a + 2 b + 4 c.
_LEXICOGRAPHIC_TO_VTK = np.array([0, 1, 3, 2, 4, 5, 7, 6])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
def element_volumes(positions, elements, out):
    """``out[e]`` = exact volume (m^3) of every trilinear hexahedron (``hex_volume``), no temporaries
    per element: 10x faster than the batched Gauss determinants of ``mesh.hex_volumes``."""
    corner, d = np.empty((8, 3)), np.empty((8, 3))
    for e in range(elements.shape[0]):
        for n in range(8):
            for c in range(3):
                corner[n, c] = positions[elements[e, n], c]
        out[e] = hex_volume(corner, d)
    return out


#: The 15 (a, b, c, sign) of V = 1/12 sum sign d_a . (d_b x d_c), lexicographic corners.
_VOLUME_TRIPLES = np.array([
    [1, 2, 3, 1], [1, 3, 5, 1], [1, 3, 7, 1], [1, 4, 5, -1], [1, 5, 7, -1], [2, 3, 6, -1], [2, 3, 7, -1],
    [2, 4, 6, 1], [2, 6, 7, 1], [3, 5, 7, -1], [3, 6, 7, 1], [4, 5, 6, 1], [4, 5, 7, 1], [4, 6, 7, -1],
    [5, 6, 7, -1]])


@njit(cache=True, nogil=True, error_model="numpy")
def volume_jacobian_terms(positions, elements, rest_volume, kappa, coefficient, direction, gradient):
    """Per element the volume forces' stiffness K_v = c h grad(V)^T (physics.md 4): the coefficient
    c = 2 kappa |dV| / V0^2 (N/m^4... per m^3 of volume change), the force directions h (M, 8, 3),
    a_S / (4 A_H) summed over the node's faces, and the volume gradient (M, 8, 3) in m^2."""
    forces = np.zeros_like(positions)  # (the forces themselves are not returned here)
    volume_forces_jacobian_add(positions, elements, rest_volume, kappa, forces, coefficient, direction, gradient)


@njit(cache=True, nogil=True, error_model="numpy")
def volume_pass(positions, elements, rest_volume, kappa, forces):
    """Volume-conservation forces (physics.md 4) with exact trilinear element volumes."""
    volume_forces_add(positions, elements, rest_volume, kappa, forces)


@njit(cache=True, nogil=True, error_model="numpy")
def csr_matvec_add(indptr, indices, data, vector, scale, out):
    """out += scale * A @ vector for a CSR matrix (flat dof vectors)."""
    for row in range(indptr.shape[0] - 1):
        total = 0.0
        for k in range(indptr[row], indptr[row + 1]):
            total += data[k] * vector[indices[k]]
        out[row] += scale * total


# -- implicit Euler -----------------------------------------------------------------------------
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


@njit(cache=True, nogil=True, error_model="numpy")
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


@njit(cache=True, nogil=True, error_model="numpy")
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


# -- fused hot path (one call per explicit step; per-spring operator data for the implicit step) ------
#: fastmath without the no-NaN / no-inf assumptions, so a diverging run still shows NaN to the monitor,
#: and without reassociation, so a kernel's floats do not depend on how LLVM optimised it. With
#: "reassoc", a kernel compiled in a process where its callees were loaded from numba's cache rounded
#: differently (1e-16 to 1e-14 relative) from the same kernel compiled with fresh callees: a serial
#: kernel cached by one process and its threaded twin compiled by the next gave different
#: trajectories (tests/test_env_vector.py's bit-for-bit test failed after
#: ``pytest tests/test_batched_fused.py -k grouped``; it passes without "reassoc"). Measured without it
#: (benchmarks/vector_env_speed.py, 2 interleaved runs): the envs ran 4-16% faster, sync and vector
#: alike (TumorPositioning's vector env 864/887 -> 1013/1027 steps/s, Palpation's 1404/1371 ->
#: 1566/1636); the static solve 205 -> 187 ms (``tissue-sim bench`` at 10^3).
_FAST = {"nsz", "arcp", "contract"}
#: ``_FAST`` with reassociation, for the single-model Jacobi Krylov kernels only (``apply_operator``,
#: ``solve_springs``: no serial / threaded twin whose floats must match; ``spring_operator``, which
#: the copies' kernels call too, has none): their vectorised reductions kept the bare lattice's
#: 15-iteration CG step at 0.65 ms (0.78 ms without).
_FAST_REDUCE = _FAST | {"reassoc"}


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
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
    for m in range(elements.shape[0] if correction_kind != 0 else 0):  # corrections (physics.md 3)
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


@njit(cache=True, error_model="numpy", fastmath=_FAST, parallel=True)
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def symplectic_update(positions, velocities, forces, gravity_force, control_force, mass, dt, fixed, target,
                      out_positions, out_velocities):
    """v1 = v0 + dt (f + f_gravity + f_control) / m, x1 = x0 + dt v1; imposed components move to their
    target with the velocity that gets them there in dt (``integrators._impose``)."""
    for node in range(positions.shape[0]):
        for c in range(3):
            if fixed[node, c]:
                out_velocities[node, c] = (target[node, c] - positions[node, c]) / dt
                out_positions[node, c] = target[node, c]
            else:
                v = velocities[node, c] + dt * (forces[node, c] + (gravity_force[node, c] + control_force[node, c])) \
                    / mass[node]
                out_velocities[node, c] = v
                out_positions[node, c] = positions[node, c] + dt * v


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def spring_operator(springs, unit, stiffness, damping, geometric, mass, mass_scale, damping_scale, stiffness_scale,
                    elements, edge_spring, correction_matrix, axis_rest_length, coupling_scale,
                    volume_coefficient, volume_direction, volume_gradient, volume_scale,
                    hg_indptr, hg_indices, hg_data, hg_scale, mask, vector, out, elongation, delta):
    """out = mask * (mass_scale M + damping_scale D + stiffness_scale K_springs + hg_scale K_hourglass
    + coupling_scale K_c + volume_scale K_v) @ vector, matrix-free from per-spring data.

    A spring's block is c_along u u^T + c_across (I - u u^T) with c_along = stiffness_scale k +
    damping_scale d and c_across = stiffness_scale g (g the clamped geometric stiffness), so the
    product needs the spring's elongation rate e = u . (v_b - v_a). The corrections' coupling K_c =
    -G W^ G^T (``_coupling_matvec_add``) reads the same elongation rates: each element sums them per
    axis into strain rates, turns them into pushes (W), and the pushes change the tension of its 12
    edge springs (``delta``), applied along the springs in the same scatter. Flat dof vectors;
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
def _apply(data, scales, mask, vector, out):
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta) = data
    spring_operator(springs, unit, stiffness, damping, geometric, mass, scales[0], scales[1], scales[2],
                    elements, edge_spring, correction_matrix, axis_rest_length, scales[3],
                    volume_coefficient, volume_direction, volume_gradient, scales[4],
                    hg_indptr, hg_indices, hg_data, scales[5], mask, vector, out, elongation, delta)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST_REDUCE)
def apply_operator(data, scales, mask, vector, out):
    """``spring_operator`` with its arguments packed: data = (springs, unit, stiffness, damping,
    geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length, volume_coefficient,
    volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta), scales =
    (mass, damping, stiffness, coupling, volume, hourglass)."""
    _apply(data, scales, mask, vector, out)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST_REDUCE)
def solve_springs(data, scales, mask, rhs, guess, tolerance, max_iterations, symmetric, work, solution):
    """The implicit Euler solve on the matrix-free ``spring_operator``: Jacobi-preconditioned CG
    (symmetric) or right-preconditioned BiCGSTAB, with the vector updates fused into single passes
    and no allocation (``work`` (8, n) scratch). Writes ``solution``; returns (iterations,
    relative residual)."""
    springs, unit, stiffness, damping, geometric, mass = data[0], data[1], data[2], data[3], data[4], data[5]
    hg_indptr, hg_indices, hg_data = data[13], data[14], data[15]
    mass_scale, damping_scale, stiffness_scale, hg_scale = scales[0], scales[1], scales[2], scales[5]
    n = rhs.shape[0]
    inverse_diagonal, r, r_hat, p, v, s, t, p_hat = work[0], work[1], work[2], work[3], work[4], work[5], work[6], work[7]
    x = solution
    # Jacobi preconditioner: the diagonal of M + springs (+ hourglass)
    for node in range(mass.shape[0]):
        for c in range(3):
            inverse_diagonal[3 * node + c] = mass_scale * mass[node]
    for k in range(springs.shape[0]):
        a, b = springs[k, 0], springs[k, 1]
        across = stiffness_scale * geometric[k]
        along = stiffness_scale * stiffness[k] + damping_scale * damping[k] - across
        for c in range(3):
            value = along * unit[k, c] * unit[k, c] + across
            inverse_diagonal[3 * a + c] += value
            inverse_diagonal[3 * b + c] += value
    for row in range(n):
        value = inverse_diagonal[row]
        if value > 0.0:
            if hg_scale != 0.0:
                for k in range(hg_indptr[row], hg_indptr[row + 1]):
                    if hg_indices[k] == row:
                        value += hg_scale * hg_data[k]
            inverse_diagonal[row] = mask[row] / value
        else:
            inverse_diagonal[row] = 0.0
    for i in range(n):
        x[i] = guess[i] * mask[i]
    _apply(data, scales, mask, x, v)
    norm_b = 0.0
    rr = 0.0
    for i in range(n):
        norm_b += rhs[i] * rhs[i]
        r[i] = rhs[i] * mask[i] - v[i]
        rr += r[i] * r[i]
    norm_b = np.sqrt(norm_b)
    if norm_b == 0.0:
        x[:] = 0.0
        return 0, 0.0
    residual = np.sqrt(rr) / norm_b
    iterations = 0
    if symmetric:
        z = s
        rz = 0.0
        for i in range(n):
            z[i] = inverse_diagonal[i] * r[i]
            p[i] = z[i]
            rz += r[i] * z[i]
        while residual > tolerance and iterations < max_iterations:
            _apply(data, scales, mask, p, v)
            curvature = 0.0
            for i in range(n):
                curvature += p[i] * v[i]
            if curvature <= 0.0:
                break
            alpha = rz / curvature
            rz_new = 0.0
            rr = 0.0
            for i in range(n):
                x[i] += alpha * p[i]
                r[i] -= alpha * v[i]
                z[i] = inverse_diagonal[i] * r[i]
                rz_new += r[i] * z[i]
                rr += r[i] * r[i]
            beta = rz_new / rz
            for i in range(n):
                p[i] = z[i] + beta * p[i]
            rz = rz_new
            iterations += 1
            residual = np.sqrt(rr) / norm_b
        return iterations, residual
    # right-preconditioned BiCGSTAB
    rho_new = 0.0
    for i in range(n):
        r_hat[i] = r[i]
        v[i] = 0.0
        p[i] = 0.0
        rho_new += r[i] * r[i]
    rho = 1.0
    alpha = 1.0
    omega = 1.0
    while residual > tolerance and iterations < max_iterations:
        if rho_new == 0.0 or omega == 0.0:
            break
        beta = (rho_new / rho) * (alpha / omega)
        rho = rho_new
        for i in range(n):
            p[i] = r[i] + beta * (p[i] - omega * v[i])
            p_hat[i] = inverse_diagonal[i] * p[i]
        _apply(data, scales, mask, p_hat, v)
        denominator = 0.0
        for i in range(n):
            denominator += r_hat[i] * v[i]
        if denominator == 0.0:
            break
        alpha = rho / denominator
        ss = 0.0
        for i in range(n):
            s[i] = r[i] - alpha * v[i]
            ss += s[i] * s[i]
        iterations += 1
        if np.sqrt(ss) / norm_b <= tolerance:
            rr = 0.0
            for i in range(n):
                x[i] += alpha * p_hat[i]
                r[i] = s[i]
                rr += r[i] * r[i]
            residual = np.sqrt(rr) / norm_b
            break
        # s_hat = D^-1 s goes in r (r is rebuilt from s and t below)
        s_hat = r
        for i in range(n):
            s_hat[i] = inverse_diagonal[i] * s[i]
        _apply(data, scales, mask, s_hat, t)
        tt = 0.0
        ts = 0.0
        for i in range(n):
            tt += t[i] * t[i]
            ts += t[i] * s[i]
        omega = ts / tt if tt > 0 else 0.0
        rr = 0.0
        rho_new = 0.0
        for i in range(n):
            x[i] += alpha * p_hat[i] + omega * s_hat[i]
            r[i] = s[i] - omega * t[i]
            rr += r[i] * r[i]
            rho_new += r_hat[i] * r[i]
        residual = np.sqrt(rr) / norm_b
    return iterations, residual


@njit(cache=True, nogil=True, error_model="numpy")
def operator_matrix_data(data, scales, spring_positions, element_positions, hg_positions, diagonal_positions, out):
    """``out`` (the model's ``BlockPattern`` data, zeroed here) = the matrix that ``apply_operator``
    applies with these ``scales`` (no mask): mass, spring blocks (clamped geometric term), the
    corrections' coupling -G W^ G^T along the current spring directions, the volume forces'
    rank-one c h grad(V)^T and the hourglass matrix, the same terms as ``spring_operator`` so that
    the assembled matrix reproduces the matrix-free product to rounding (the factorised
    preconditioner of ``ImplicitEuler``). spring_positions (S, 4, 3, 3) (blocks aa, bb, ab, ba),
    element_positions (M, 8, 8, 3, 3), hg_positions (nnz_hg,), diagonal_positions (3N,): positions
    in ``out`` (``Model``'s derived arrays)."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta) = data
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
    if hg_scale != 0.0:
        for k in range(hg_data.shape[0]):
            out[hg_positions[k]] += hg_scale * hg_data[k]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def volume_forces_add(positions, elements, rest_volume, kappa, forces):
    """Adds every element's volume-conservation force (physics.md 4) to ``forces`` (N, 3): the
    body of ``volume_forces_jacobian_add`` without the stiffness terms."""
    none = np.empty((0, 8, 3))
    _volume_forces(positions, elements, rest_volume, kappa, forces, False, np.empty(0), none, none)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def volume_forces_jacobian_add(positions, elements, rest_volume, kappa, forces, coefficient, direction, gradient):
    """``volume_forces_add`` that also fills the rank-one stiffness terms of
    ``volume_jacobian_terms``: coefficient (M,), direction and gradient (M, 8, 3)."""
    _volume_forces(positions, elements, rest_volume, kappa, forces, True, coefficient, direction, gradient)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _volume_forces(positions, elements, rest_volume, kappa, forces, jacobian, coefficient, direction, gradient):
    """Adds every element's volume-conservation force (physics.md 4) to ``forces`` (N, 3), with
    exact trilinear volumes: the formulas of ``hex_volume`` and ``volume_pass`` written out as one
    straight-line body per element (generated code, no scratch arrays; 2.4x faster than
    the earlier two-pass version). With ``jacobian``, also fills the rank-one stiffness terms of
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


# -- batched copies (tissue_env.batched): N copies of one block, copy index last ------------------------
# Every per-copy array has the copy as its last axis ((S, N), (S, 3, N), (3 n, N) ...), so each loop over
# springs, elements or hourglass entries reads its indices once for all N copies (the inner loop over
# copies is contiguous). Same formulas as ``spring_operator`` / ``solve_springs``.
@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _copies_row_product(hg_indptr, hg_indices, hg_data, hg_group, vector, row, total):
    """total (N,) = row ``row`` of each copy's hourglass matrix (CSR ``hg_indptr``, ``hg_indices`` of
    one copy, values ``hg_data[:, hg_group[c]]`` (nnz, G)) times that copy's column of ``vector``
    (dofs, N); with one matrix for every copy (G = 1) the inner loop is contiguous (vectorised)."""
    for c in range(total.shape[0]):
        total[c] = 0.0
    shared = hg_data.shape[1] == 1
    for k in range(hg_indptr[row], hg_indptr[row + 1]):
        col = hg_indices[k]
        if shared:
            value = hg_data[k, 0]
            for c in range(total.shape[0]):
                total[c] += value * vector[col, c]
        else:
            for c in range(total.shape[0]):
                total[c] += hg_data[k, hg_group[c]] * vector[col, c]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def batched_spring_operator(springs, unit, stiffness, damping, geometric, mass, mass_scale, damping_scale,
                            stiffness_scale, elements, edge_spring, correction_matrix, axis_rest_length,
                            coupling_scale, volume_coefficient, volume_direction, volume_gradient, volume_scale,
                            hg_indptr, hg_indices, hg_data, hg_group, hg_scale, mask, vector, out, elongation,
                            delta):
    """``spring_operator`` of N copies at once: out (3 n, N) = mask * A @ vector (3 n, N), with the
    single block's topology (springs, elements, edge_spring, hg_indptr, hg_indices) and per-copy values
    (unit (S, 3, N), stiffness, damping, geometric (S, N), mass (n, N), correction_matrix (M, 3, 3, N),
    axis_rest_length (M, 3, N), volume_coefficient (M, N), volume_direction, volume_gradient (M, 8, 3, N),
    hg_data (nnz, G): the G distinct hourglass matrices' values, copy c using column hg_group[c]).
    elongation, delta (S, N) are scratch."""
    n_copies = vector.shape[1]
    for node in range(mass.shape[0]):
        for k in range(3):
            row = 3 * node + k
            for c in range(n_copies):
                out[row, c] = mass_scale * mass[node, c] * vector[row, c]
    coupled = coupling_scale != 0.0
    n_springs = springs.shape[0]
    if coupled:
        for s in range(n_springs):
            a, b = springs[s, 0], springs[s, 1]
            for c in range(n_copies):
                elongation[s, c] = (unit[s, 0, c] * (vector[3 * b, c] - vector[3 * a, c])
                                    + unit[s, 1, c] * (vector[3 * b + 1, c] - vector[3 * a + 1, c])
                                    + unit[s, 2, c] * (vector[3 * b + 2, c] - vector[3 * a + 2, c]))
                delta[s, c] = 0.0
        for m in range(elements.shape[0]):
            for c in range(n_copies):
                r0 = 0.25 * coupling_scale * (elongation[edge_spring[m, 0], c] + elongation[edge_spring[m, 1], c]
                                              + elongation[edge_spring[m, 2], c] + elongation[edge_spring[m, 3], c]) \
                    / axis_rest_length[m, 0, c]
                r1 = 0.25 * coupling_scale * (elongation[edge_spring[m, 4], c] + elongation[edge_spring[m, 5], c]
                                              + elongation[edge_spring[m, 6], c] + elongation[edge_spring[m, 7], c]) \
                    / axis_rest_length[m, 1, c]
                r2 = 0.25 * coupling_scale * (elongation[edge_spring[m, 8], c] + elongation[edge_spring[m, 9], c]
                                              + elongation[edge_spring[m, 10], c] + elongation[edge_spring[m, 11], c]) \
                    / axis_rest_length[m, 2, c]
                for j in range(3):
                    p = (correction_matrix[m, j, 0, c] * r0 + correction_matrix[m, j, 1, c] * r1
                         + correction_matrix[m, j, 2, c] * r2)
                    for q in range(4):
                        delta[edge_spring[m, 4 * j + q], c] += p
    if volume_scale != 0.0:
        for m in range(elements.shape[0]):
            for c in range(n_copies):
                if volume_coefficient[m, c] == 0.0:
                    continue
                rate = 0.0
                for n in range(8):
                    node = elements[m, n]
                    rate += (volume_gradient[m, n, 0, c] * vector[3 * node, c]
                             + volume_gradient[m, n, 1, c] * vector[3 * node + 1, c]
                             + volume_gradient[m, n, 2, c] * vector[3 * node + 2, c])
                rate *= volume_scale * volume_coefficient[m, c]
                for n in range(8):
                    node = elements[m, n]
                    out[3 * node, c] += rate * volume_direction[m, n, 0, c]
                    out[3 * node + 1, c] += rate * volume_direction[m, n, 1, c]
                    out[3 * node + 2, c] += rate * volume_direction[m, n, 2, c]
    for s in range(n_springs):
        a, b = springs[s, 0], springs[s, 1]
        for c in range(n_copies):
            u0, u1, u2 = unit[s, 0, c], unit[s, 1, c], unit[s, 2, c]
            d0 = vector[3 * b, c] - vector[3 * a, c]
            d1 = vector[3 * b + 1, c] - vector[3 * a + 1, c]
            d2 = vector[3 * b + 2, c] - vector[3 * a + 2, c]
            across = stiffness_scale * geometric[s, c]
            along = stiffness_scale * stiffness[s, c] + damping_scale * damping[s, c] - across
            t = along * (u0 * d0 + u1 * d1 + u2 * d2)
            if coupled:
                t -= delta[s, c]
            f0 = t * u0 + across * d0
            f1 = t * u1 + across * d1
            f2 = t * u2 + across * d2
            out[3 * a, c] -= f0
            out[3 * a + 1, c] -= f1
            out[3 * a + 2, c] -= f2
            out[3 * b, c] += f0
            out[3 * b + 1, c] += f1
            out[3 * b + 2, c] += f2
    if hg_scale != 0.0:
        total = np.empty(n_copies)
        for row in range(hg_indptr.shape[0] - 1):
            _copies_row_product(hg_indptr, hg_indices, hg_data, hg_group, vector, row, total)
            for c in range(n_copies):
                out[row, c] += hg_scale * total[c]
    for i in range(out.shape[0]):
        for c in range(n_copies):
            out[i, c] *= mask[i, c]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _batched_apply(data, scales, mask, vector, out):
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta,
     hg_group) = data
    batched_spring_operator(springs, unit, stiffness, damping, geometric, mass, scales[0], scales[1], scales[2],
                            elements, edge_spring, correction_matrix, axis_rest_length, scales[3],
                            volume_coefficient, volume_direction, volume_gradient, scales[4],
                            hg_indptr, hg_indices, hg_data, hg_group, scales[5], mask, vector, out, elongation, delta)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def batched_apply_operator(data, scales, mask, vector, out):
    """``batched_spring_operator`` with its arguments packed as ``apply_operator``'s (copies last), plus
    hg_group (N,) last."""
    _batched_apply(data, scales, mask, vector, out)


@njit(cache=True, nogil=True, inline="always")
def _lu_offsets(ints):
    """Offsets in a packed sparse LU's ``ints`` ([k, nnz_L, nnz_U, L indptr (k + 1), L indices,
    U indptr (k + 1), U indices, gather (k), free (k), perm_c (k)], see ``_lu_apply``): (nnz_L,
    L indptr, L indices, U indptr, U indices, gather, free, perm_c)."""
    k = ints[0]
    nnz_l = ints[1]
    lp = 3
    li = lp + k + 1
    up = li + nnz_l
    ui = up + k + 1
    gather = ui + ints[2]
    return nnz_l, lp, li, up, ui, gather, gather + k, gather + 2 * k


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _subtract_block(values, base, buffer, j, a0, a1, a2, used):
    """a -= B x for columns t < ``used``: B the row-major 3x3 block values[base:base + 9], x the
    rows j, j + 1, j + 2 of ``buffer`` (the node-block triangular solves' inner update)."""
    b00, b01, b02 = values[base], values[base + 1], values[base + 2]
    b10, b11, b12 = values[base + 3], values[base + 4], values[base + 5]
    b20, b21, b22 = values[base + 6], values[base + 7], values[base + 8]
    for t in range(used):
        x0 = buffer[j, t]
        x1 = buffer[j + 1, t]
        x2 = buffer[j + 2, t]
        a0[t] -= b00 * x0 + b01 * x1 + b02 * x2
        a1[t] -= b10 * x0 + b11 * x1 + b12 * x2
        a2[t] -= b20 * x0 + b21 * x1 + b22 * x2


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _block_lu_solve(ints, values, vector, out, columns, used, buffer, accumulator):
    """out[:, columns[:used]] = A^-1 vector[:, columns[:used]] through a packed node-block sparse LU
    (``sparse.NodeBlockLU``): P A P^T = L U with P a permutation of whole nodes and L, U
    in block CSR of dense 3 x 3 blocks (L's diagonal block last in its block row, U's first).
    ``ints``: [-k, nb, blocks of L, blocks of U, L indptr (nb + 1), L block columns, U indptr (nb + 1),
    U block columns, order (k): the dof at each position of P], ``values``: [L blocks, U blocks]
    (9 row-major values each). Row-oriented substitutions: a block row accumulates the products
    of its blocks with the solved rows of all right-hand sides (``buffer`` (k, N), the copy index
    last; ``accumulator`` (3, N)), one index per 9 values. A symmetric factor (``ints[2]`` = 0: no
    L) goes through ``_block_ldl_solve``."""
    if ints[2] == 0:
        _block_ldl_solve(ints, values, vector, out, columns, used, buffer, accumulator)
        return
    k = -ints[0]
    nb = ints[1]
    nnz_l = ints[2]
    lp = 4
    li = lp + nb + 1
    up = li + nnz_l
    ui = up + nb + 1
    order = ui + ints[3]
    u_values = 9 * nnz_l
    for j in range(k):
        row = ints[order + j]
        for t in range(used):
            buffer[j, t] = vector[row, columns[t]]
    a0 = accumulator[0]
    a1 = accumulator[1]
    a2 = accumulator[2]
    for block_row in range(nb):  # L y = b
        i = 3 * block_row
        for t in range(used):
            a0[t] = buffer[i, t]
            a1[t] = buffer[i + 1, t]
            a2[t] = buffer[i + 2, t]
        last = ints[lp + block_row + 1] - 1
        for q in range(ints[lp + block_row], last):
            _subtract_block(values, 9 * q, buffer, 3 * ints[li + q], a0, a1, a2, used)
        base = 9 * last
        for t in range(used):
            y0 = a0[t] / values[base]
            y1 = (a1[t] - values[base + 3] * y0) / values[base + 4]
            y2 = (a2[t] - values[base + 6] * y0 - values[base + 7] * y1) / values[base + 8]
            buffer[i, t] = y0
            buffer[i + 1, t] = y1
            buffer[i + 2, t] = y2
    for block_row in range(nb - 1, -1, -1):  # U x = y
        i = 3 * block_row
        for t in range(used):
            a0[t] = buffer[i, t]
            a1[t] = buffer[i + 1, t]
            a2[t] = buffer[i + 2, t]
        first = ints[up + block_row]
        for q in range(first + 1, ints[up + block_row + 1]):
            _subtract_block(values, u_values + 9 * q, buffer, 3 * ints[ui + q], a0, a1, a2, used)
        base = u_values + 9 * first
        for t in range(used):
            y2 = a2[t] / values[base + 8]
            y1 = (a1[t] - values[base + 5] * y2) / values[base + 4]
            y0 = (a0[t] - values[base + 1] * y1 - values[base + 2] * y2) / values[base]
            buffer[i, t] = y0
            buffer[i + 1, t] = y1
            buffer[i + 2, t] = y2
    for j in range(k):
        row = ints[order + j]
        for t in range(used):
            out[row, columns[t]] = buffer[j, t]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def block_lu_factor(a_indptr, a_indices, a_values, l_indptr, l_indices, u_indptr, u_indices, out, work):
    """Numeric LU without pivoting, P A P^T = L U, of a matrix of dense 3 x 3 blocks on a given
    fill pattern (``sparse.NodeBlockLU``). A: block CSR (a_indptr, a_indices, a_values: 9
    row-major values per block, the rows and columns already permuted). L: block CSR whose rows
    hold the strictly lower block columns, sorted, then the diagonal block; U: block CSR whose rows
    hold the diagonal block, then the upper block columns. Row-oriented (row i is scattered into
    ``work`` (9 nb,), eliminated with the earlier rows' U, and gathered). Writes out = [L blocks,
    U blocks] (``block_lu_apply``'s layout; L's diagonal blocks unit lower triangular, U's upper
    triangular). Returns False when a pivot is zero or not finite."""
    nb = a_indptr.shape[0] - 1
    u0 = 9 * l_indptr[nb]
    for i in range(nb):
        for q in range(l_indptr[i], l_indptr[i + 1]):
            w = 9 * l_indices[q]
            for e in range(9):
                work[w + e] = 0.0
        for q in range(u_indptr[i], u_indptr[i + 1]):
            w = 9 * u_indices[q]
            for e in range(9):
                work[w + e] = 0.0
        for q in range(a_indptr[i], a_indptr[i + 1]):
            w = 9 * a_indices[q]
            for e in range(9):
                work[w + e] += a_values[9 * q + e]
        for q in range(l_indptr[i], l_indptr[i + 1] - 1):
            k = l_indices[q]
            d = u0 + 9 * u_indptr[k]  # U_kk
            w = 9 * k
            lq = 9 * q
            for r in range(3):  # L_ik = W_k U_kk^-1
                x0 = work[w + 3 * r] / out[d]
                x1 = (work[w + 3 * r + 1] - x0 * out[d + 1]) / out[d + 4]
                x2 = (work[w + 3 * r + 2] - x0 * out[d + 2] - x1 * out[d + 5]) / out[d + 8]
                out[lq + 3 * r] = x0
                out[lq + 3 * r + 1] = x1
                out[lq + 3 * r + 2] = x2
            for p in range(u_indptr[k] + 1, u_indptr[k + 1]):  # W_j -= L_ik U_kj
                b = u0 + 9 * p
                w = 9 * u_indices[p]
                for r in range(3):
                    l0, l1, l2 = out[lq + 3 * r], out[lq + 3 * r + 1], out[lq + 3 * r + 2]
                    for c in range(3):
                        work[w + 3 * r + c] -= l0 * out[b + c] + l1 * out[b + 3 + c] + l2 * out[b + 6 + c]
        w = 9 * i  # the diagonal block: 3 x 3 LU without pivoting
        d00, d01, d02 = work[w], work[w + 1], work[w + 2]
        l10 = work[w + 3] / d00
        l20 = work[w + 6] / d00
        d11 = work[w + 4] - l10 * d01
        d12 = work[w + 5] - l10 * d02
        l21 = (work[w + 7] - l20 * d01) / d11
        d22 = work[w + 8] - l20 * d02 - l21 * d12
        if not (np.isfinite(l10) and np.isfinite(l20) and np.isfinite(l21) and np.isfinite(d22) and d22 != 0.0):
            return False
        lq = 9 * (l_indptr[i + 1] - 1)
        for e in range(9):
            out[lq + e] = 0.0
        out[lq] = out[lq + 4] = out[lq + 8] = 1.0
        out[lq + 3] = l10
        out[lq + 6] = l20
        out[lq + 7] = l21
        d = u0 + 9 * u_indptr[i]
        for e in range(9):
            out[d + e] = 0.0
        out[d], out[d + 1], out[d + 2] = d00, d01, d02
        out[d + 4], out[d + 5], out[d + 8] = d11, d12, d22
        for p in range(u_indptr[i] + 1, u_indptr[i + 1]):  # U_ij = L_ii^-1 W_j
            b = u0 + 9 * p
            w = 9 * u_indices[p]
            for c in range(3):
                y0 = work[w + c]
                y1 = work[w + 3 + c] - l10 * y0
                out[b + c] = y0
                out[b + 3 + c] = y1
                out[b + 6 + c] = work[w + 6 + c] - l20 * y0 - l21 * y1
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _invert3(values, base, out, target):
    """out[target:target + 9] = the inverse of the row-major 3 x 3 block values[base:base + 9];
    False where its determinant is zero or not finite."""
    a, b, c = values[base], values[base + 1], values[base + 2]
    d, e, f = values[base + 3], values[base + 4], values[base + 5]
    g, h, i = values[base + 6], values[base + 7], values[base + 8]
    c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
    det = a * c00 + d * c01 + g * c02
    if not (np.isfinite(det) and det != 0.0):
        return False
    s = 1.0 / det
    out[target], out[target + 1], out[target + 2] = c00 * s, c01 * s, c02 * s
    out[target + 3], out[target + 4], out[target + 5] = (f * g - d * i) * s, (a * i - c * g) * s, (c * d - a * f) * s
    out[target + 6], out[target + 7], out[target + 8] = (d * h - e * g) * s, (b * g - a * h) * s, (a * e - b * d) * s
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def block_ldl_factor(a_indptr, a_indices, a_values, a_transpose, l_indptr, l_indices, l_to_u, u_indptr, u_indices,
                     out, work):
    """Numeric block LDL^T without pivoting, S = U^T D U, of the symmetric part S = (A + A^T) / 2 of
    a matrix of dense 3 x 3 blocks with a symmetric block pattern, on a given fill pattern
    (``sparse.NodeBlockLU``'s symmetric form): U unit upper block triangular, D block diagonal.
    A as ``block_lu_factor`` takes it, with ``a_transpose`` (nnz blocks,) the position of block
    (j, i) for each block (i, j); U's pattern (u_indptr, u_indices: the diagonal block first in each
    row, then the upper block columns, sorted) and L's = U's transpose (l_indptr, l_indices: the lower
    block columns of each row, sorted, then the diagonal), ``l_to_u`` the position in U of the block
    (k, i) for each L block (i, k). Row-oriented, up-looking, on the upper triangle only: about half
    the block products of ``block_lu_factor``. Writes out (9 nnz_U,) = U's off-diagonal blocks and, in
    each diagonal slot, D_i^-1 (``_block_ldl_solve``'s layout). Returns False when a D_i is
    singular or not finite."""
    nb = a_indptr.shape[0] - 1
    m = np.empty(9)
    for i in range(nb):
        for q in range(u_indptr[i], u_indptr[i + 1]):
            w = 9 * u_indices[q]
            for e in range(9):
                work[w + e] = 0.0
        for q in range(a_indptr[i], a_indptr[i + 1]):  # the upper part of row i of (A + A^T) / 2
            j = a_indices[q]
            if j < i:
                continue
            w, a, t = 9 * j, 9 * q, 9 * a_transpose[q]
            for r in range(3):
                for c in range(3):
                    work[w + 3 * r + c] += 0.5 * (a_values[a + 3 * r + c] + a_values[t + 3 * c + r])
        for q in range(l_indptr[i], l_indptr[i + 1] - 1):
            k = l_indices[q]
            p = l_to_u[q]  # the block (k, i) of D U (not yet scaled)
            d = 9 * u_indptr[k]  # D_k^-1
            b = 9 * p
            for r in range(3):  # m = D_k^-1 (D U)_ki = U_ki
                for c in range(3):
                    m[3 * r + c] = (out[d + 3 * r] * out[b + c] + out[d + 3 * r + 1] * out[b + 3 + c]
                                    + out[d + 3 * r + 2] * out[b + 6 + c])
            for p2 in range(p, u_indptr[k + 1]):  # W_j -= U_ki^T (D U)_kj, j >= i
                g = 9 * p2
                w = 9 * u_indices[p2]
                for r in range(3):
                    m0, m1, m2 = m[r], m[3 + r], m[6 + r]
                    for c in range(3):
                        work[w + 3 * r + c] -= m0 * out[g + c] + m1 * out[g + 3 + c] + m2 * out[g + 6 + c]
            for e in range(9):
                out[b + e] = m[e]
        d = 9 * u_indptr[i]
        if not _invert3(work, 9 * i, out, d):
            return False
        for q in range(u_indptr[i] + 1, u_indptr[i + 1]):  # (D U)_ij, scaled when row j is eliminated
            w = 9 * u_indices[q]
            b = 9 * q
            for e in range(9):
                out[b + e] = work[w + e]
    return True


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _block_ldl_solve(ints, values, vector, out, columns, used, buffer, accumulator):
    """``_block_lu_solve`` through a packed node-block LDL^T (``block_ldl_factor``): P S P^T = U^T D U.
    ``ints``: [-k, nb, 0, blocks of U, U indptr (nb + 1), U block columns, order (k)], ``values``: U's
    blocks with D_i^-1 in each diagonal slot. U^T z = b by a forward sweep that scatters each solved
    block row into the later rows, then x = U^-1 D^-1 z by a backward sweep: U's blocks are read
    twice, half the values of the LU's two sweeps. The forward sweep starts at the first block row
    where b is not zero (columns of the inverse: unit vectors)."""
    if used == 1:
        _block_ldl_solve_one(ints, values, vector[:, columns[0]], out[:, columns[0]], buffer[:, 0])
        return
    k = -ints[0]
    nb = ints[1]
    up = 4
    ui = up + nb + 1
    order = ui + ints[3]
    start = nb  # the first block row with a non-zero right-hand side: z is zero before it
    for j in range(k):
        row = ints[order + j]
        for t in range(used):
            value = vector[row, columns[t]]
            buffer[j, t] = value
            if value != 0.0 and j // 3 < start:
                start = j // 3
    for block_row in range(start, nb):  # U^T z = b: z_i is final, then b_j -= U_ij^T z_i
        i = 3 * block_row
        for q in range(ints[up + block_row] + 1, ints[up + block_row + 1]):
            base = 9 * q
            j = 3 * ints[ui + q]
            b00, b01, b02 = values[base], values[base + 1], values[base + 2]
            b10, b11, b12 = values[base + 3], values[base + 4], values[base + 5]
            b20, b21, b22 = values[base + 6], values[base + 7], values[base + 8]
            for t in range(used):
                z0 = buffer[i, t]
                z1 = buffer[i + 1, t]
                z2 = buffer[i + 2, t]
                buffer[j, t] -= b00 * z0 + b10 * z1 + b20 * z2
                buffer[j + 1, t] -= b01 * z0 + b11 * z1 + b21 * z2
                buffer[j + 2, t] -= b02 * z0 + b12 * z1 + b22 * z2
    a0 = accumulator[0]
    a1 = accumulator[1]
    a2 = accumulator[2]
    for block_row in range(nb - 1, -1, -1):  # U x = D^-1 z
        i = 3 * block_row
        first = ints[up + block_row]
        base = 9 * first
        for t in range(used):
            z0 = buffer[i, t]
            z1 = buffer[i + 1, t]
            z2 = buffer[i + 2, t]
            a0[t] = values[base] * z0 + values[base + 1] * z1 + values[base + 2] * z2
            a1[t] = values[base + 3] * z0 + values[base + 4] * z1 + values[base + 5] * z2
            a2[t] = values[base + 6] * z0 + values[base + 7] * z1 + values[base + 8] * z2
        for q in range(first + 1, ints[up + block_row + 1]):
            _subtract_block(values, 9 * q, buffer, 3 * ints[ui + q], a0, a1, a2, used)
        for t in range(used):
            buffer[i, t] = a0[t]
            buffer[i + 1, t] = a1[t]
            buffer[i + 2, t] = a2[t]
    for j in range(k):
        row = ints[order + j]
        for t in range(used):
            out[row, columns[t]] = buffer[j, t]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _block_ldl_solve_one(ints, values, vector, out, buffer):
    """``_block_ldl_solve`` for one right-hand side (n,) (the Krylov solves' case), its running
    values in registers: 0.25 against 0.36 ms through the loop over columns (a Palpation copy)."""
    k = -ints[0]
    nb = ints[1]
    up = 4
    ui = up + nb + 1
    order = ui + ints[3]
    start = nb  # the first block row with a non-zero right-hand side (a unit vector's: late)
    for j in range(k):
        value = vector[ints[order + j]]
        buffer[j] = value
        if value != 0.0 and start == nb:
            start = j // 3
    for block_row in range(start, nb):  # U^T z = b
        i = 3 * block_row
        z0 = buffer[i]
        z1 = buffer[i + 1]
        z2 = buffer[i + 2]
        for q in range(ints[up + block_row] + 1, ints[up + block_row + 1]):
            base = 9 * q
            j = 3 * ints[ui + q]
            buffer[j] -= values[base] * z0 + values[base + 3] * z1 + values[base + 6] * z2
            buffer[j + 1] -= values[base + 1] * z0 + values[base + 4] * z1 + values[base + 7] * z2
            buffer[j + 2] -= values[base + 2] * z0 + values[base + 5] * z1 + values[base + 8] * z2
    for block_row in range(nb - 1, -1, -1):  # U x = D^-1 z
        i = 3 * block_row
        first = ints[up + block_row]
        base = 9 * first
        z0 = buffer[i]
        z1 = buffer[i + 1]
        z2 = buffer[i + 2]
        a0 = values[base] * z0 + values[base + 1] * z1 + values[base + 2] * z2
        a1 = values[base + 3] * z0 + values[base + 4] * z1 + values[base + 5] * z2
        a2 = values[base + 6] * z0 + values[base + 7] * z1 + values[base + 8] * z2
        for q in range(first + 1, ints[up + block_row + 1]):
            base = 9 * q
            j = 3 * ints[ui + q]
            x0 = buffer[j]
            x1 = buffer[j + 1]
            x2 = buffer[j + 2]
            a0 -= values[base] * x0 + values[base + 1] * x1 + values[base + 2] * x2
            a1 -= values[base + 3] * x0 + values[base + 4] * x1 + values[base + 5] * x2
            a2 -= values[base + 6] * x0 + values[base + 7] * x1 + values[base + 8] * x2
        buffer[i] = a0
        buffer[i + 1] = a1
        buffer[i + 2] = a2
    for j in range(k):
        out[ints[order + j]] = buffer[j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def block_lu_apply(ints, values, mask, vector, out, buffer):
    """out = mask * A^-1 vector (n,) through a packed node-block LU: ``_block_lu_solve`` with one
    column (a copy specialised for one right-hand side was measured only 9-11% faster); the dofs
    the factor does not hold get 0. ``buffer`` (k,) scratch."""
    k = -ints[0]
    columns = np.zeros(1, dtype=np.int64)
    for i in range(out.shape[0]):
        out[i] = 0.0
    _block_lu_solve(ints, values, vector.reshape(-1, 1), out.reshape(-1, 1), columns, 1,
                    buffer[:k].reshape(-1, 1), np.empty((3, 1)))
    for i in range(out.shape[0]):
        out[i] *= mask[i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _lu_columns(ints, values, vector, out, columns, used, buffer, accumulator):
    """out[:, columns[:used]] = A^-1 vector[:, columns[:used]] through one packed sparse LU: a
    node-block factor (``ints[0]`` < 0, ``_block_lu_solve``), SuperLU's scalar layout (``ints[0]`` =
    k > 0, ``_lu_apply``'s; column sweeps with all right-hand sides at once) or none (k = 0: the
    identity). Each entry of L and U is read once for all the columns. The rows of ``out`` that the
    factor does not hold are left as they are. ``buffer`` (>= |k|, >= used) and ``accumulator`` (3, >= used) scratch."""
    k = ints[0]
    if k < 0:
        _block_lu_solve(ints, values, vector, out, columns, used, buffer, accumulator)
        return
    if k == 0:
        for i in range(vector.shape[0]):
            for t in range(used):
                out[i, columns[t]] = vector[i, columns[t]]
        return
    nnz_l, lp, li, up, ui, gather, free, perm_c = _lu_offsets(ints)
    for j in range(k):
        row = ints[gather + j]
        for t in range(used):
            buffer[j, t] = vector[row, columns[t]]
    for j in range(k):  # L (CSC, diagonal first): column sweeps, all right-hand sides at once
        diagonal = values[ints[lp + j]]
        for t in range(used):
            buffer[j, t] /= diagonal
        for q in range(ints[lp + j] + 1, ints[lp + j + 1]):
            row = ints[li + q]
            value = values[q]
            for t in range(used):
                buffer[row, t] -= value * buffer[j, t]
    for j in range(k - 1, -1, -1):  # U (CSC, diagonal last)
        end = ints[up + j + 1] - 1
        diagonal = values[nnz_l + end]
        for t in range(used):
            buffer[j, t] /= diagonal
        for q in range(ints[up + j], end):
            row = ints[ui + q]
            value = values[nnz_l + q]
            for t in range(used):
                buffer[row, t] -= value * buffer[j, t]
    for i in range(k):
        row = ints[free + i]
        source = ints[perm_c + i]
        for t in range(used):
            out[row, columns[t]] = buffer[source, t]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _batched_precondition(lu_int, lu_float, group_of, running, inverse_diagonal, mask, vector, out, columns,
                          buffer, accumulator):
    """out = mask * P_c vector[:, c] per ``running`` copy c (0 for the others): P the inverse of the
    packed sparse LU of the copy's group (``group_of[c]`` >= 0: ``lu_int[g]``, ``lu_float[g]``; a
    node-block factor when ``lu_int[g][0]`` < 0, see ``_block_lu_solve``, else ``_lu_apply``'s scalar
    layout, k = 0: the identity) or the Jacobi diagonal ``inverse_diagonal`` (``group_of[c]`` < 0).
    The running copies of a group are solved together: each entry of L and U is read once and
    updates a row of all their right-hand sides (contiguous, the copy index last in ``buffer`` (k, N)),
    so a group costs about one pass over its factor (the loop overhead per entry dominates: measured
    with 1.7e5 entries, scalar 0.35 ms for one copy and 0.6 ms for 16, node blocks 0.08 and 0.45 ms).
    ``columns`` (N,) int and ``accumulator`` (3, N) scratch."""
    n_copies = vector.shape[1]
    out[:] = 0.0
    for c in range(n_copies):
        if group_of[c] < 0 and running[c]:
            for i in range(vector.shape[0]):
                out[i, c] = inverse_diagonal[i, c] * vector[i, c]
    for g in range(len(lu_int)):
        used = 0
        for c in range(n_copies):
            if group_of[c] == g and running[c]:
                columns[used] = c
                used += 1
        if used == 0:
            continue
        _lu_columns(lu_int[g], lu_float[g], vector, out, columns, used, buffer, accumulator)
    for i in range(out.shape[0]):
        for c in range(n_copies):
            out[i, c] *= mask[i, c]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def batched_solve(data, scales, mask, rhs, guess, active, tolerance, max_iterations, lu_int, lu_float, group_of, work,
                  solution, iterations, residual):
    """Right-preconditioned BiCGSTAB (``solve_springs``' algorithm) of every ``active`` copy, in lockstep
    with its own scalars and stopping test ||r|| <= tolerance ||b||: a copy that has converged (or broken
    down) stops changing (and is left out of the preconditioner's passes). Preconditioner per copy: the
    packed sparse LU ``lu_int[g]``, ``lu_float[g]`` of its group g = ``group_of[c]``, or the Jacobi
    diagonal of M + springs (+ hourglass) for g < 0 (``_batched_precondition``). Vectors (3 n, N);
    ``work`` (8, 3 n, N) scratch. Writes solution (NaN columns for a non-finite right-hand side),
    iterations (N,) and residual (N,) (0 for a zero right-hand side)."""
    dofs, n_copies = rhs.shape
    springs, unit, stiffness, damping, geometric, mass = data[0], data[1], data[2], data[3], data[4], data[5]
    hg_indptr, hg_indices, hg_data, hg_group = data[13], data[14], data[15], data[18]
    mass_scale, damping_scale, stiffness_scale, hg_scale = scales[0], scales[1], scales[2], scales[5]
    r, r_hat, p, v, s, t, p_hat, s_hat = work[0], work[1], work[2], work[3], work[4], work[5], work[6], work[7]
    x = solution
    columns = np.empty(n_copies, dtype=np.int64)
    largest = 1
    for g in range(len(lu_int)):
        largest = max(largest, abs(lu_int[g][0]))
    buffer = np.empty((largest, n_copies))
    accumulator = np.empty((3, n_copies))
    inverse_diagonal = np.zeros((dofs, n_copies))
    jacobi = False
    for c in range(n_copies):
        if group_of[c] < 0:
            jacobi = True
    if jacobi:  # the diagonal of M + springs (+ hourglass), as ``solve_springs``
        for node in range(mass.shape[0]):
            for k in range(3):
                for c in range(n_copies):
                    inverse_diagonal[3 * node + k, c] = mass_scale * mass[node, c]
        for q in range(springs.shape[0]):
            a, b = springs[q, 0], springs[q, 1]
            for k in range(3):
                for c in range(n_copies):
                    across = stiffness_scale * geometric[q, c]
                    along = stiffness_scale * stiffness[q, c] + damping_scale * damping[q, c] - across
                    value = along * unit[q, k, c] * unit[q, k, c] + across
                    inverse_diagonal[3 * a + k, c] += value
                    inverse_diagonal[3 * b + k, c] += value
        for row in range(dofs):
            diagonal_hg = -1
            if hg_scale != 0.0:
                for q in range(hg_indptr[row], hg_indptr[row + 1]):
                    if hg_indices[q] == row:
                        diagonal_hg = q
            for c in range(n_copies):
                value = inverse_diagonal[row, c]
                if value > 0.0:
                    if diagonal_hg >= 0:
                        value += hg_scale * hg_data[diagonal_hg, hg_group[c]]
                    inverse_diagonal[row, c] = mask[row, c] / value
                else:
                    inverse_diagonal[row, c] = 0.0
    norm_b = np.zeros(n_copies)
    finite = np.ones(n_copies, dtype=np.bool_)
    for c in range(n_copies):
        for i in range(dofs):
            value = rhs[i, c] * mask[i, c]
            if not np.isfinite(value):
                finite[c] = False
    for i in range(dofs):
        for c in range(n_copies):
            s[i, c] = rhs[i, c] * mask[i, c] if finite[c] else 0.0  # s holds b
            x[i, c] = guess[i, c] * mask[i, c]
    for i in range(dofs):
        for c in range(n_copies):
            norm_b[c] += s[i, c] * s[i, c]
    for c in range(n_copies):
        norm_b[c] = np.sqrt(norm_b[c])
        if norm_b[c] == 0.0:
            for i in range(dofs):
                x[i, c] = 0.0
    _batched_apply(data, scales, mask, x, v)
    rr = np.zeros(n_copies)
    for i in range(dofs):
        for c in range(n_copies):
            r[i, c] = s[i, c] - v[i, c]
            rr[c] += r[i, c] * r[i, c]
    safe = np.where(norm_b == 0.0, 1.0, norm_b)
    running = np.zeros(n_copies, dtype=np.bool_)
    for c in range(n_copies):
        residual[c] = np.sqrt(rr[c]) / safe[c]
        iterations[c] = 0
        running[c] = active[c] and finite[c] and norm_b[c] > 0.0 and residual[c] > tolerance
    rho = np.ones(n_copies)
    alpha = np.zeros(n_copies)
    omega = np.ones(n_copies)
    rho_new = np.zeros(n_copies)
    dot1 = np.zeros(n_copies)
    dot2 = np.zeros(n_copies)
    for i in range(dofs):
        for c in range(n_copies):
            r_hat[i, c] = r[i, c]
            v[i, c] = 0.0
            p[i, c] = 0.0
    while running.any():
        rho_new[:] = 0.0
        for i in range(dofs):
            for c in range(n_copies):
                rho_new[c] += r_hat[i, c] * r[i, c]
        beta = np.zeros(n_copies)
        for c in range(n_copies):
            if running[c] and (rho_new[c] == 0.0 or omega[c] == 0.0):
                running[c] = False
            if running[c]:
                beta[c] = (rho_new[c] / rho[c]) * (alpha[c] / omega[c])
                rho[c] = rho_new[c]
        for i in range(dofs):
            for c in range(n_copies):
                p[i, c] = r[i, c] + beta[c] * (p[i, c] - omega[c] * v[i, c])
        _batched_precondition(lu_int, lu_float, group_of, running, inverse_diagonal, mask, p, p_hat, columns,
                              buffer, accumulator)
        _batched_apply(data, scales, mask, p_hat, v)
        dot1[:] = 0.0
        for i in range(dofs):
            for c in range(n_copies):
                dot1[c] += r_hat[i, c] * v[i, c]
        for c in range(n_copies):
            if running[c] and not (np.isfinite(dot1[c]) and dot1[c] != 0.0):
                running[c] = False
            alpha[c] = rho[c] / dot1[c] if running[c] else 0.0
        dot2[:] = 0.0
        for i in range(dofs):
            for c in range(n_copies):
                s[i, c] = r[i, c] - alpha[c] * v[i, c]
                dot2[c] += s[i, c] * s[i, c]
        early = np.zeros(n_copies, dtype=np.bool_)
        for c in range(n_copies):
            if running[c]:
                iterations[c] += 1
                s_residual = np.sqrt(dot2[c]) / safe[c]
                if s_residual <= tolerance:
                    early[c] = True
                    residual[c] = s_residual
                    running[c] = False
        if early.any():
            for i in range(dofs):
                for c in range(n_copies):
                    if early[c]:
                        x[i, c] += alpha[c] * p_hat[i, c]
                        r[i, c] = s[i, c]
        if not running.any():
            break
        _batched_precondition(lu_int, lu_float, group_of, running, inverse_diagonal, mask, s, s_hat, columns,
                              buffer, accumulator)
        _batched_apply(data, scales, mask, s_hat, t)
        dot1[:] = 0.0
        dot2[:] = 0.0
        for i in range(dofs):
            for c in range(n_copies):
                dot1[c] += t[i, c] * t[i, c]
                dot2[c] += t[i, c] * s[i, c]
        for c in range(n_copies):
            omega[c] = dot2[c] / dot1[c] if (running[c] and dot1[c] > 0.0) else 0.0
        rr[:] = 0.0
        for i in range(dofs):
            for c in range(n_copies):
                if running[c]:
                    x[i, c] += alpha[c] * p_hat[i, c] + omega[c] * s_hat[i, c]
                    r[i, c] = s[i, c] - omega[c] * t[i, c]
                    rr[c] += r[i, c] * r[i, c]
        for c in range(n_copies):
            if running[c]:
                residual[c] = np.sqrt(rr[c]) / safe[c]
                if not (np.isfinite(residual[c]) and residual[c] > tolerance and iterations[c] < max_iterations):
                    running[c] = False
            if not running[c]:
                omega[c] = 1.0
    for c in range(n_copies):
        if active[c] and not finite[c]:
            for i in range(dofs):
                x[i, c] = np.nan
        if norm_b[c] == 0.0:
            residual[c] = 0.0


# -- per-copy solves with sparse LU preconditioners (tissue_env.batched, solver "factorised") --------
@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _lu_apply(ints, values, mask, vector, out, buffer):
    """out = mask * A^-1 vector through one packed sparse LU: Pr A Pc = L U on the copy's free dofs
    (SuperLU's convention). ``ints``: [k, nnz_L, nnz_U, L indptr (k + 1), L indices, U indptr (k + 1),
    U indices, gather (k), free (k), perm_c (k)] (CSC, sorted indices: L's diagonal first, U's last in
    each column), ``values``: [L data, U data]; gather[j] = the dof that Pr puts in position j. The
    factor's free dofs may include dofs the mask imposes (a factor of a larger free set: an
    approximate inverse). k = 0: no factor (out = mask * vector)."""
    k = ints[0]
    if k == 0:
        for i in range(vector.shape[0]):
            out[i] = mask[i] * vector[i]
        return
    if k < 0:  # a node-block factor (``sparse.NodeBlockLU``)
        block_lu_apply(ints, values, mask, vector, out, buffer)
        return
    nnz_l, lp, li, up, ui, gather, free, perm_c = _lu_offsets(ints)
    for j in range(k):
        buffer[j] = vector[ints[gather + j]]
    for j in range(k):
        value = buffer[j] / values[ints[lp + j]]
        buffer[j] = value
        if value != 0.0:
            for q in range(ints[lp + j] + 1, ints[lp + j + 1]):
                buffer[ints[li + q]] -= values[q] * value
    for j in range(k - 1, -1, -1):
        end = ints[up + j + 1] - 1
        value = buffer[j] / values[nnz_l + end]
        buffer[j] = value
        if value != 0.0:
            for q in range(ints[up + j], end):
                buffer[ints[ui + q]] -= values[nnz_l + q] * value
    for i in range(vector.shape[0]):
        out[i] = 0.0
    for i in range(k):
        row = ints[free + i]
        out[row] = mask[row] * buffer[ints[perm_c + i]]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _corrected_lu_apply(ints, values, mask, ones, correction, imposed, gathered, vector, out, buffer):
    """out = mask * (y - correction @ y[imposed]) with y = A^-1 vector (``_lu_apply`` without mask):
    a factor of a larger free set F restricted exactly to the free dofs ``mask`` (capacitance
    correction, ``correction`` (3 n, k) = B[:, imposed] (B[imposed, imposed])^-1 with B the
    factor's inverse and ``imposed`` (k,) the dofs of F imposed now; exact for a vector zero on
    them). k = 0: ``_lu_apply`` with ``mask``. ``ones`` (3 n,) ones, ``gathered`` (>= k,) scratch."""
    k = imposed.shape[0]
    if k == 0:
        _lu_apply(ints, values, mask, vector, out, buffer)
        return
    _lu_apply(ints, values, ones, vector, out, buffer)
    _correct_masked(out, correction, imposed, gathered, mask)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _correct_masked(out, correction, imposed, gathered, mask):
    """out = mask * (out - correction @ out[imposed]): a capacitance correction (``_corrected_lu_apply``)
    on an unmasked solve ``out`` (3 n,); ``gathered`` (>= k,) scratch."""
    k = imposed.shape[0]
    for j in range(k):
        gathered[j] = out[imposed[j]]
    for i in range(out.shape[0]):
        value = out[i]
        for j in range(k):
            value -= correction[i, j] * gathered[j]
        out[i] = mask[i] * value


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, hg_block_data, mask, vector, out):
    """``_apply`` with the hourglass term read from the node-block (BSR) form of the hourglass matrix
    (``hg_block_indptr`` (n + 1,), ``hg_block_indices`` (nb,) node columns, ``hg_block_data`` (9 nb,)
    row-major 3 x 3 blocks) instead of the CSR arrays in ``data``: one index and three vector loads
    per 9 values (2.3x faster than the scalar CSR loop at Palpation's 8x4x8, where that loop was 80%
    of the operator product). The same sums, in the same column order per row (rounding aside)."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta) = data
    spring_operator(springs, unit, stiffness, damping, geometric, mass, scales[0], scales[1], scales[2],
                    elements, edge_spring, correction_matrix, axis_rest_length, scales[3],
                    volume_coefficient, volume_direction, volume_gradient, scales[4],
                    hg_indptr, hg_indices, hg_data, 0.0, ones, vector, out, elongation, delta)
    if scales[5] != 0.0:
        bsr3_matvec_add(hg_block_indptr, hg_block_indices, hg_block_data, vector, scales[5], out)
    for i in range(out.shape[0]):
        out[i] *= mask[i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def apply_operator_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, hg_block_data, mask, vector, out):
    """``apply_operator`` with the hourglass term read from the node-block (BSR) form of the
    hourglass matrix (``_apply_blocks``; the single envs' implicit step, ``ImplicitEuler``)."""
    _apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, hg_block_data, mask, vector, out)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _inverse_columns_task(lu_int, lu_float, copies, indptr, dofs, out, t):
    """``inverse_columns_copies``' columns of task ``t``."""
    first, count = indptr[t], indptr[t + 1] - indptr[t]
    ints, values = lu_int[copies[t]], lu_float[copies[t]]
    n_dofs = out.shape[1]
    rhs = np.zeros((n_dofs, count))
    solved = np.zeros((n_dofs, count))
    for i in range(count):
        rhs[dofs[first + i], i] = 1.0
    k = -ints[0]
    _block_lu_solve(ints, values, rhs, solved, np.arange(count), count, np.empty((k, count)), np.empty((3, count)))
    for i in range(count):
        for j in range(n_dofs):
            out[first + i, j] = solved[j, i]


@njit(cache=True, error_model="numpy", parallel=True)
def inverse_columns_copies(lu_int, lu_float, copies, indptr, dofs, out):
    """Columns of the inverse of several copies' node-block factors (``integrators.InverseColumns``,
    the capacitance corrections' columns): task t solves the unit vectors of the dofs
    ``dofs[indptr[t]:indptr[t + 1]]`` together through the factor of copy ``copies[t]``
    (``lu_int[c]``, ``lu_float[c]``: ``_block_lu_solve``), into the rows ``out[indptr[t]:indptr[t + 1]]``
    ((total, 3 n), zero where the factor holds no dof). The tasks on numba's threads."""
    for t in prange(copies.shape[0]):
        _inverse_columns_task(lu_int, lu_float, copies, indptr, dofs, out, np.int64(t))


@njit(cache=True, nogil=True, error_model="numpy")
def inverse_columns_copies_serial(lu_int, lu_float, copies, indptr, dofs, out):
    """``inverse_columns_copies`` in this thread only (one thread, a forked process)."""
    for t in range(copies.shape[0]):
        _inverse_columns_task(lu_int, lu_float, copies, indptr, dofs, out, t)


@njit(cache=True, nogil=True, inline="always")
def _copy_data(stacked, hg_rows, hg_group, c):
    """``apply_operator``'s data of copy ``c`` of a stacked model (copies first; ``solve_copies_lu``,
    ``factor_copies``): its slices of the per-spring, per-node and per-element arrays, the shared
    topology, and its group's hourglass values ``hg_rows[hg_group[c]]``."""
    (springs, unit, stiffness, damping, geometric, mass, elements, edge_spring, correction_matrix, axis_rest_length,
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_unused, elongation,
     delta) = stacked
    n_springs, n_elements, n_nodes = springs.shape[0], elements.shape[0], mass.shape[0] // hg_group.shape[0]
    a, b = c * n_springs, (c + 1) * n_springs
    e0, e1 = c * n_elements, (c + 1) * n_elements
    return (springs, unit[a:b], stiffness[a:b], damping[a:b], geometric[a:b], mass[c * n_nodes:(c + 1) * n_nodes],
            elements, edge_spring, correction_matrix[e0:e1], axis_rest_length[e0:e1], volume_coefficient[e0:e1],
            volume_direction[e0:e1], volume_gradient[e0:e1], hg_indptr, hg_indices, hg_rows[hg_group[c]],
            elongation[a:b], delta[a:b])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _dot(a, b):
    """a . b of two (n,) vectors."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _dot_and_square(a, b):
    """(a . b, b . b) of two (n,) vectors in one pass."""
    ab = 0.0
    bb = 0.0
    for i in range(a.shape[0]):
        ab += a[i] * b[i]
        bb += b[i] * b[i]
    return ab, bb


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _masked_start(rhs, guess, mask, b, x):
    """A BiCGSTAB's start: b = mask * rhs and x = mask * guess; returns ||b||, or -1 for a
    non-finite right-hand side (x NaN) (x = 0 for a zero one)."""
    finite = True
    total = 0.0
    for i in range(rhs.shape[0]):
        value = rhs[i] * mask[i]
        if not np.isfinite(value):
            finite = False
        b[i] = value
        total += value * value
    for i in range(rhs.shape[0]):
        x[i] = np.nan if not finite else (guess[i] * mask[i] if total > 0.0 else 0.0)
    return np.sqrt(total) if finite else -1.0


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _scaled_start(x, b, v, r, r_hat, p):
    """The BiCGSTAB start from the guess ``x`` scaled by the factor a that minimises ||b - a A x||
    (``v`` = A x on entry; 0: no guess, never a worse start than none; the previous step's dv is a
    poor guess after a random action): x *= a, r = r_hat = b - a v, p = v = 0; returns ||r||^2."""
    bv, vv = _dot_and_square(b, v)
    scale = bv / vv if vv > 0.0 and np.isfinite(bv / vv) else 0.0
    rr = 0.0
    for i in range(x.shape[0]):
        x[i] *= scale
        r[i] = b[i] - scale * v[i]
        rr += r[i] * r[i]
        r_hat[i] = r[i]
        p[i] = 0.0
        v[i] = 0.0
    return rr


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _solve_copy(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int, lu_float,
                factor_of, corrections, imposed, work, solution, iterations, residual, hg_block_indptr,
                hg_block_indices, hg_block_rows, ones, c):
    """``solve_copies_lu``'s solve of copy ``c``, with ``work`` (8, 3 n) its own scratch."""
    dofs = rhs.shape[1]
    iterations[c] = 0
    residual[c] = 0.0
    if not active[c]:
        return
    r, r_hat, p, v, s, t, p_hat, s_hat = work[0], work[1], work[2], work[3], work[4], work[5], work[6], work[7]
    buffer = np.empty(dofs)
    x = solution[c]
    data = _copy_data(stacked, hg_rows, hg_group, c)
    m = mask[c]
    blocks = hg_block_rows[hg_group[c]]
    ints = lu_int[factor_of[c]]
    values = lu_float[factor_of[c]]
    correction = corrections[c]
    held = imposed[c]
    gathered = np.empty(held.shape[0])
    norm_b = _masked_start(rhs[c], guess[c], m, s, x)
    if norm_b < 0.0:
        residual[c] = np.inf
    if norm_b <= 0.0:
        return
    _apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, blocks, m, x, v)
    res = np.sqrt(_scaled_start(x, s, v, r, r_hat, p)) / norm_b  # the guess scaled to the least residual
    rho = alpha = omega = 1.0
    count = 0
    limit = limits[c]
    while res > tolerance and count < limit:
        rho_new = _dot(r_hat, r)
        if rho_new == 0.0 or omega == 0.0:
            break
        beta = (rho_new / rho) * (alpha / omega)
        rho = rho_new
        for i in range(dofs):
            p[i] = r[i] + beta * (p[i] - omega * v[i])
        _corrected_lu_apply(ints, values, m, ones, correction, held, gathered, p, p_hat, buffer)
        _apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, blocks, m, p_hat, v)
        denominator = _dot(r_hat, v)
        if not (np.isfinite(denominator) and denominator != 0.0):
            break
        alpha = rho / denominator
        ss = 0.0
        for i in range(dofs):
            s[i] = r[i] - alpha * v[i]
            ss += s[i] * s[i]
        count += 1
        if np.sqrt(ss) / norm_b <= tolerance:
            for i in range(dofs):
                x[i] += alpha * p_hat[i]
                r[i] = s[i]
            res = np.sqrt(ss) / norm_b
            break
        _corrected_lu_apply(ints, values, m, ones, correction, held, gathered, s, s_hat, buffer)
        _apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, blocks, m, s_hat, t)
        ts, tt = _dot_and_square(s, t)
        omega = ts / tt if tt > 0.0 else 0.0
        rr = 0.0
        for i in range(dofs):
            x[i] += alpha * p_hat[i] + omega * s_hat[i]
            r[i] = s[i] - omega * t[i]
            rr += r[i] * r[i]
        res = np.sqrt(rr) / norm_b
        if not np.isfinite(res):
            break
    iterations[c] = count
    residual[c] = res


@njit(cache=True, error_model="numpy", fastmath=_FAST, parallel=True)
def solve_copies_lu(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                    lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                    hg_block_indptr, hg_block_indices, hg_block_rows):
    """Each ``active`` copy's right-preconditioned BiCGSTAB (``solve_springs``' algorithm and stopping
    test ||r|| <= tolerance ||b||), the copies shared among numba's threads, each with its own
    scratch (no lockstep: a copy costs its own iterations; ``work`` (8, 3 n) serves a single copy),
    preconditioned by its sparse LU ``factor_of[c]`` restricted to its free dofs
    ``mask[c]``, with the capacitance correction ``corrections[c]`` (3 n, k) for the dofs
    ``imposed[c]`` (k,) that are free in the factor but imposed now (``_corrected_lu_apply``; k = 0:
    the factor masked, ``_lu_apply``), and stopped after ``limits[c]`` iterations. ``stacked``:
    ``apply_operator``'s data of the N-copy stacked model (copies first: copy c's springs, elements
    and nodes are the c-th equal slices; topology arrays springs, elements, edge_spring, hg_indptr,
    hg_indices of ONE copy), its hourglass values per copy group ``hg_rows`` (G, nnz) and
    ``hg_group`` (N,). Vectors (N, 3 n). Writes solution (NaN rows for a
    non-finite right-hand side), iterations and residual (N,). The operator products read the
    hourglass matrix in node blocks (``_apply_blocks``): ``hg_block_indptr``, ``hg_block_indices``
    and each group's block values ``hg_block_rows`` (G, 9 nb) (``hg_rows`` is the CSR form of the
    same matrices)."""
    n_copies, dofs = rhs.shape
    ones = np.ones(dofs)
    for copy in prange(n_copies):  # the copies on all of numba's threads, each with its own scratch
        own = work if n_copies == 1 else np.empty((8, dofs))
        _solve_copy(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int, lu_float,
                    factor_of, corrections, imposed, own, solution, iterations, residual, hg_block_indptr,
                    hg_block_indices, hg_block_rows, ones, np.int64(copy))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def solve_copies_lu_serial(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                           lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                           hg_block_indptr, hg_block_indices, hg_block_rows):
    """``solve_copies_lu`` in this thread only, the copies one after the other with the scratch
    ``work`` (8, 3 n): for one thread, and in a forked process, where GNU OpenMP's pool must not be
    used (``FORKED``)."""
    ones = np.ones(rhs.shape[1])
    for c in range(rhs.shape[0]):
        _solve_copy(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int, lu_float,
                    factor_of, corrections, imposed, work, solution, iterations, residual, hg_block_indptr,
                    hg_block_indices, hg_block_rows, ones, c)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _apply_copy(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones, mask,
                vector, out, c):
    """out = mask * A_c vector: ``_apply_blocks`` on copy ``c``'s data (``_copy_data``); (3 n,) vectors."""
    _apply_blocks(_copy_data(stacked, hg_rows, hg_group, c), scales, ones, hg_block_indptr, hg_block_indices,
                  hg_block_rows[hg_group[c]], mask, vector, out)


@njit(cache=True, error_model="numpy", fastmath=_FAST, parallel=True)
def apply_copies(stacked, scales, hg_rows, hg_group, vector, out, hg_block_indptr, hg_block_indices, hg_block_rows):
    """out (N, 3 n) = each copy's operator A_c (``apply_operator``'s, the hourglass term in node blocks)
    times its row of ``vector`` (N, 3 n), the copies shared among numba's threads (``solve_copies_lu``'s
    arguments: copy c's per-spring and per-element scratch are its own slices)."""
    ones = np.ones(vector.shape[1])
    for c in prange(vector.shape[0]):
        _apply_copy(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones, ones,
                    vector[c], out[c], np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def apply_copies_serial(stacked, scales, hg_rows, hg_group, vector, out, hg_block_indptr, hg_block_indices,
                        hg_block_rows):
    """``apply_copies`` in this thread only (one thread, a forked process): the same floats."""
    ones = np.ones(vector.shape[1])
    for c in range(vector.shape[0]):
        _apply_copy(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones, ones,
                    vector[c], out[c], c)


# -- lockstep solves of copies that share preconditioners (solver "reference") -----------------------
@njit(cache=True, nogil=True, inline="always")
def _take_group(key, pending, first, start, columns):
    """Gather the ``pending`` copies first + j (j >= start) whose ``key`` is copy first + start's:
    their indices into ``columns``, their ``pending`` cleared; returns how many."""
    used = 0
    for j in range(start, pending.shape[0]):
        if pending[j] and key[first + j] == key[first + start]:
            columns[used] = first + j
            used += 1
            pending[j] = False
    return used


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _precondition_rows(vector, out, running, first, lu_int, lu_float, factor_of, corrections, imposed, mask,
                       columns, buffer, accumulator, gathered, pending):
    """out[c] = mask[c] * (y - corrections[c] @ y[imposed[c]]) with y = A_g^-1 vector[c] for every
    copy c = first + i with ``running[i]`` (``_corrected_lu_apply``'s result, other rows untouched):
    the copies of a factor g = ``factor_of[c]`` are solved together (``_lu_columns``: one pass over
    the factor for all of them). Vectors (N, 3 n); ``pending`` (>= len(running),) bool scratch."""
    size = running.shape[0]
    dofs = vector.shape[1]
    for i in range(size):
        pending[i] = running[i]
        if running[i]:
            for j in range(dofs):
                out[first + i, j] = 0.0
    for i in range(size):
        if pending[i]:
            g = factor_of[first + i]
            used = _take_group(factor_of, pending, first, i, columns)
            _lu_columns(lu_int[g], lu_float[g], vector.T, out.T, columns, used, buffer, accumulator)
    for i in range(size):
        if running[i]:
            c = first + i
            _correct_masked(out[c], corrections[c], imposed[c], gathered, mask[c])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def bsr3_matvec_add_rows(indptr, indices, data, vector, scale, out, columns, used, accumulator):
    """out[c] += scale * A @ vector[c] for the rows c = ``columns[:used]`` of (N, 3 n) ``vector`` and
    ``out``, A in 3 x 3 node blocks (``bsr3_matvec_add``'s layout): each block is read once for all
    the vectors (``accumulator`` (3, >= used) scratch)."""
    for i in range(indptr.shape[0] - 1):
        for t in range(used):
            accumulator[0, t] = 0.0
            accumulator[1, t] = 0.0
            accumulator[2, t] = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[q]
            b = 9 * q
            d0, d1, d2, d3, d4, d5, d6, d7, d8 = (data[b], data[b + 1], data[b + 2], data[b + 3], data[b + 4],
                                                  data[b + 5], data[b + 6], data[b + 7], data[b + 8])
            for t in range(used):
                row = vector[columns[t]]
                x0, x1, x2 = row[j], row[j + 1], row[j + 2]
                accumulator[0, t] += d0 * x0 + d1 * x1 + d2 * x2
                accumulator[1, t] += d3 * x0 + d4 * x1 + d5 * x2
                accumulator[2, t] += d6 * x0 + d7 * x1 + d8 * x2
        for t in range(used):
            row = out[columns[t]]
            row[3 * i] += scale * accumulator[0, t]
            row[3 * i + 1] += scale * accumulator[1, t]
            row[3 * i + 2] += scale * accumulator[2, t]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _apply_rows(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones, mask,
                vector, out, running, first, columns, accumulator, pending):
    """out[c] = mask[c] * A_c vector[c] (``_apply_copy``) for every copy c = first + i with
    ``running[i]``: the spring, coupling and volume terms per copy (``scales`` without the hourglass
    term), the hourglass term for all the running copies of a group at once
    (``bsr3_matvec_add_rows``: one pass over the group's node-block matrix, 2/3 of a product at
    TumorPositioning's 7^3: 43 of 67 us per copy)."""
    size = running.shape[0]
    springs_only = (scales[0], scales[1], scales[2], scales[3], scales[4], 0.0 * scales[5])
    for i in range(size):
        pending[i] = running[i]
        if running[i]:
            c = first + i
            _apply_copy(stacked, springs_only, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows,
                        ones, ones, vector[c], out[c], c)
    if scales[5] != 0.0:
        for i in range(size):
            if pending[i]:
                g = hg_group[first + i]
                used = _take_group(hg_group, pending, first, i, columns)
                bsr3_matvec_add_rows(hg_block_indptr, hg_block_indices, hg_block_rows[g], vector, scales[5], out,
                                     columns, used, accumulator)
    for i in range(size):
        if running[i]:
            c = first + i
            row = out[c]
            m = mask[c]
            for j in range(row.shape[0]):
                row[j] *= m[j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _solve_lockstep(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int, lu_float,
                    factor_of, corrections, imposed, work, solution, iterations, residual, hg_block_indptr,
                    hg_block_indices, hg_block_rows, ones, first, last):
    """``solve_copies_grouped``'s solve of the copies first ... last - 1: ``_solve_copy``'s BiCGSTAB
    (the same scaled guess, updates and stopping tests) in lockstep, each copy with its own scalars
    and iteration count (a copy that stops is left out of every later pass, so it costs its own
    iterations), the preconditioner applied to all the running copies of a factor at once
    (``_precondition_rows``). ``work`` (8, N, 3 n): rows first ... last - 1 used."""
    dofs = rhs.shape[1]
    size = last - first
    r, r_hat, p, v, s, t, p_hat, s_hat = work[0], work[1], work[2], work[3], work[4], work[5], work[6], work[7]
    running = np.zeros(size, dtype=np.bool_)
    started = np.zeros(size, dtype=np.bool_)
    pending = np.zeros(size, dtype=np.bool_)
    norm_b = np.zeros(size)
    res = np.zeros(size)
    rho = np.ones(size)
    alpha = np.ones(size)
    omega = np.ones(size)
    largest = 1
    held = 0
    for c in range(first, last):
        largest = max(largest, abs(lu_int[factor_of[c]][0]))
        held = max(held, imposed[c].shape[0])
    columns = np.empty(size, dtype=np.int64)
    buffer = np.empty((largest, size))
    accumulator = np.empty((3, size))
    gathered = np.empty(held)
    for i in range(size):  # start: the guess scaled to the least residual (``_solve_copy``)
        c = first + i
        iterations[c] = 0
        residual[c] = 0.0
        if not active[c]:
            continue
        x = solution[c]
        m = mask[c]
        norm_b[i] = _masked_start(rhs[c], guess[c], m, s[c], x)
        if norm_b[i] < 0.0:
            residual[c] = np.inf
        started[i] = norm_b[i] > 0.0
    _apply_rows(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows,
                ones, mask, solution, v, started, first, columns, accumulator, pending)
    for i in range(size):
        if not started[i]:
            continue
        c = first + i
        x = solution[c]
        res[i] = np.sqrt(_scaled_start(x, s[c], v[c], r[c], r_hat[c], p[c])) / norm_b[i]
        running[i] = res[i] > tolerance and limits[c] > 0
    while True:
        more = False
        for i in range(size):  # p = r + beta (p - omega v)
            if not running[i]:
                continue
            c = first + i
            rho_new = _dot(r_hat[c], r[c])
            if rho_new == 0.0 or omega[i] == 0.0:
                running[i] = False
                continue
            beta = (rho_new / rho[i]) * (alpha[i] / omega[i])
            rho[i] = rho_new
            for j in range(dofs):
                p[c, j] = r[c, j] + beta * (p[c, j] - omega[i] * v[c, j])
            more = True
        if not more:
            break
        _precondition_rows(p, p_hat, running, first, lu_int, lu_float, factor_of, corrections, imposed, mask, columns,
                           buffer, accumulator, gathered, pending)
        _apply_rows(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices,
                    hg_block_rows, ones, mask, p_hat, v, running, first, columns, accumulator, pending)
        for i in range(size):  # v = A p_hat, s = r - alpha v: done when s is small enough
            if not running[i]:
                continue
            c = first + i
            denominator = _dot(r_hat[c], v[c])
            if not (np.isfinite(denominator) and denominator != 0.0):
                running[i] = False
                continue
            alpha[i] = rho[i] / denominator
            ss = 0.0
            for j in range(dofs):
                s[c, j] = r[c, j] - alpha[i] * v[c, j]
                ss += s[c, j] * s[c, j]
            iterations[c] += 1
            if np.sqrt(ss) / norm_b[i] <= tolerance:
                x = solution[c]
                for j in range(dofs):
                    x[j] += alpha[i] * p_hat[c, j]
                    r[c, j] = s[c, j]
                res[i] = np.sqrt(ss) / norm_b[i]
                running[i] = False
        _precondition_rows(s, s_hat, running, first, lu_int, lu_float, factor_of, corrections, imposed, mask, columns,
                           buffer, accumulator, gathered, pending)
        _apply_rows(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices,
                    hg_block_rows, ones, mask, s_hat, t, running, first, columns, accumulator, pending)
        for i in range(size):  # t = A s_hat, omega, x and r
            if not running[i]:
                continue
            c = first + i
            ts, tt = _dot_and_square(s[c], t[c])
            omega[i] = ts / tt if tt > 0.0 else 0.0
            x = solution[c]
            rr = 0.0
            for j in range(dofs):
                x[j] += alpha[i] * p_hat[c, j] + omega[i] * s_hat[c, j]
                r[c, j] = s[c, j] - omega[i] * t[c, j]
                rr += r[c, j] * r[c, j]
            res[i] = np.sqrt(rr) / norm_b[i]
            if not (np.isfinite(res[i]) and res[i] > tolerance and iterations[c] < limits[c]):
                running[i] = False
    for i in range(size):
        c = first + i
        if active[c] and norm_b[i] > 0.0:
            residual[c] = res[i]


@njit(cache=True, error_model="numpy", fastmath=_FAST, parallel=True)
def solve_copies_grouped(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                         lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                         hg_block_indptr, hg_block_indices, hg_block_rows, chunk):
    """``solve_copies_lu`` (its arguments, results and stopping rule) for copies that share their
    factors (``factor_of``): the copies in contiguous chunks of ``chunk``, shared among numba's
    threads, each chunk solved in lockstep (``_solve_lockstep``): every step of the substitutions
    reads a shared factor once for all the chunk's running copies of it instead of once per copy (at
    TumorPositioning's 7^3, one copy's node-block solve 0.12 ms, 16 together 0.41 ms). The chunks
    depend on the copy count only, so any thread count gives the same floats. ``work`` (8, N, 3 n)."""
    n_copies, dofs = rhs.shape
    ones = np.ones(dofs)
    chunk = max(1, chunk)
    for first in prange((n_copies + chunk - 1) // chunk):
        _solve_lockstep(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                        lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                        hg_block_indptr, hg_block_indices, hg_block_rows, ones, np.int64(first * chunk),
                        np.int64(min(n_copies, (first + 1) * chunk)))  # int64 as in the serial version


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def solve_copies_grouped_serial(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits,
                                lu_int, lu_float, factor_of, corrections, imposed, work, solution, iterations,
                                residual, hg_block_indptr, hg_block_indices, hg_block_rows, chunk):
    """``solve_copies_grouped`` in this thread only, the chunks one after the other: the same floats."""
    n_copies = rhs.shape[0]
    ones = np.ones(rhs.shape[1])
    chunk = max(1, chunk)
    for first in range(0, n_copies, chunk):
        _solve_lockstep(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                        lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                        hg_block_indptr, hg_block_indices, hg_block_rows, ones, np.int64(first),
                        np.int64(min(n_copies, first + chunk)))


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
def _projected_probe_row(x, z, tips, weights, offsets, reference, radius, reach, flat, out, m):
    """Row ``m`` of ``projected_probe_surfaces``."""
    near2 = (radius + reach) ** 2
    tip_x, tip_y, tip_z = tips[m, 0], tips[m, 1], tips[m, 2]
    levels = reference[0] if reference.shape[0] == 1 else reference[m]
    for k in range(x.shape[1]):
        dx = x[m, k] - tip_x
        dz = z[m, k] - tip_z
        if dx * dx + dz * dz <= near2:
            out[m, k] = _projected_bound(x[m, k], z[m, k], tip_x, tip_y, tip_z, weights[k], offsets, levels[k],
                                         radius, flat)
        else:
            out[m, k] = np.inf


@njit(cache=True, error_model="numpy", parallel=True)
def projected_probe_surfaces_rows(x, z, tips, weights, offsets, reference, radius, reach, flat, out):
    """``projected_probe_surfaces`` with its rows (the vector envs' copies) on numba's threads (the
    same floats)."""
    for m in prange(x.shape[0]):
        _projected_probe_row(x, z, tips, weights, offsets, reference, radius, reach, flat, out, np.int64(m))


@njit(cache=True, nogil=True, error_model="numpy")
def projected_probe_surfaces(x, z, tips, weights, offsets, reference, radius, reach, flat, out):
    """``contact.Probe.surface``'s projected bound of every node of M probe / node-set pairs in one
    pass: ``x``, ``z`` (M, n) the nodes' horizontal coordinates, m, ``tips`` (M, 3) m, ``weights``
    (n, Q), ``reference`` (M, n) or (1, n) m (the same for every row); a node farther than
    ``radius`` + ``reach`` m from its row's probe axis gets +inf (no quadrature point can be under
    the probe), the others ``_projected_bound``. Writes ``out`` (M, n) m."""
    for m in range(x.shape[0]):
        _projected_probe_row(x, z, tips, weights, offsets, reference, radius, reach, flat, out, m)


# -- batched factorisations (tissue_env.batched, solver "factorised") ----------------------------------
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
     volume_coefficient, volume_direction, volume_gradient, hg_indptr, hg_indices, hg_data, elongation, delta) = data
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


@njit(cache=True, error_model="numpy", parallel=True)
def factor_copies(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                  diagonal_positions, copies, covers, node_dofs, take, rows, columns, a_map, a_indptr, a_indices,
                  l_indptr, l_indices, u_indptr, u_indices, a_transpose, l_to_u, ints, values, a_values, work, lu_int,
                  lu_float, ok, node_edge, node_sign):
    """The node-block LUs of several copies' system matrices in one call, each exactly as
    ``operator_matrix_data`` followed by ``integrators.node_block_factor`` (``sparse.NodeBlockLU``,
    ``block_lu_factor``) computes it: for copy c = ``copies[t]`` of the stacked model (``stacked``,
    ``hg_rows``, ``hg_group`` as ``solve_copies_lu`` takes them), the matrix of the operator with
    ``scales`` is assembled on the model's pattern (``values`` (nnz,) scratch), restricted to the
    whole nodes ``node_dofs`` (k,) (``integrators._FreeStructure``: ``take``, ``rows``, ``columns``
    of its CSC entries) with the dofs not in ``covers[t]`` (3 n,) decoupled (rows and columns zero,
    diagonal kept), scattered into the permuted block matrix (``a_map``, ``a_values`` scratch) and
    factorised on the fill pattern (l_*, u_*): an LU (``block_lu_factor``), or with ``l_to_u`` not
    empty the LDL^T of its symmetric part (``block_ldl_factor``, ``ints`` its header; the symmetric
    form of ``sparse.NodeBlockLU``). With ``node_edge`` and ``node_sign`` (M, 8, 3), the
    assembly is ``operator_matrix_data_blocks`` (the same matrix up to rounding, faster); empty
    (0, 8, 3): ``operator_matrix_data``. A factor that succeeds is a new array
    ``lu_float[c]``, with ``lu_int[c] = ints`` (the structure's packed header); ``ok[t]`` False (and
    ``lu_int``/``lu_float`` untouched) where a pivot is zero or not finite. The copies are shared
    among numba's threads, each with its own scratch (``values``, ``a_values``, ``work`` serve a
    single copy); the factors are stored after the parallel loop."""
    count = copies.shape[0]
    size = 9 * (u_indices.shape[0] + (0 if l_to_u.shape[0] else l_indices.shape[0]))
    outs = [np.empty(size) for _ in range(count)]
    for entry in prange(count):  # the copies on all of numba's threads, each with its own scratch
        t = np.int64(entry)
        own = count == 1
        ok[t] = _factor_copy(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                             diagonal_positions, copies[t], covers[t], node_dofs, take, rows, columns, a_map,
                             a_indptr, a_indices, l_indptr, l_indices, u_indptr, u_indices, a_transpose, l_to_u,
                             values if own else np.empty(values.shape[0]),
                             a_values if own else np.empty(a_values.shape[0]),
                             work if own else np.empty(work.shape[0]), outs[t], node_edge, node_sign)
    for t in range(count):
        if ok[t]:
            lu_int[copies[t]] = ints
            lu_float[copies[t]] = outs[t]


@njit(cache=True, nogil=True, error_model="numpy")
def factor_copies_serial(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                         diagonal_positions, copies, covers, node_dofs, take, rows, columns, a_map, a_indptr,
                         a_indices, l_indptr, l_indices, u_indptr, u_indices, a_transpose, l_to_u, ints, values,
                         a_values, work, lu_int, lu_float, ok, node_edge, node_sign):
    """``factor_copies`` in this thread only, the copies one after the other with the scratch
    ``values``, ``a_values``, ``work``: for one thread, and in a forked process, where GNU OpenMP's
    pool must not be used (``FORKED``)."""
    size = 9 * (u_indices.shape[0] + (0 if l_to_u.shape[0] else l_indices.shape[0]))
    for t in range(copies.shape[0]):
        out = np.empty(size)
        ok[t] = _factor_copy(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                             diagonal_positions, copies[t], covers[t], node_dofs, take, rows, columns, a_map,
                             a_indptr, a_indices, l_indptr, l_indices, u_indptr, u_indices, a_transpose, l_to_u,
                             values, a_values, work, out, node_edge, node_sign)
        if ok[t]:
            lu_int[copies[t]] = ints
            lu_float[copies[t]] = out


@njit(cache=True, nogil=True, error_model="numpy")
def _factor_copy(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                 diagonal_positions, c, cover, node_dofs, take, rows, columns, a_map, a_indptr, a_indices, l_indptr,
                 l_indices, u_indptr, u_indices, a_transpose, l_to_u, values, a_values, work, out, node_edge,
                 node_sign):
    """``factor_copies``' factorisation of copy ``c`` on its cover ``cover`` (3 n,) into ``out``, with
    ``values``, ``a_values`` and ``work`` its own scratch; False where a pivot is zero or not finite."""
    data = _copy_data(stacked, hg_rows, hg_group, c)
    if node_edge.shape[0] == stacked[6].shape[0]:  # one row per element: the node-pair assembly
        operator_matrix_data_blocks(data, scales, spring_positions, element_positions, hg_positions,
                                    diagonal_positions, node_edge, node_sign, values)
    else:
        operator_matrix_data(data, scales, spring_positions, element_positions, hg_positions, diagonal_positions,
                             values)
    a_values[:] = 0.0
    for q in range(take.shape[0]):
        r = rows[q]
        col = columns[q]
        if r == col or (cover[node_dofs[r]] and cover[node_dofs[col]]):
            a_values[a_map[q]] = values[take[q]]
    if l_to_u.shape[0]:
        return block_ldl_factor(a_indptr, a_indices, a_values, a_transpose, l_indptr, l_indices, l_to_u, u_indptr,
                                u_indices, out, work)
    return block_lu_factor(a_indptr, a_indices, a_values, l_indptr, l_indices, u_indptr, u_indices, out, work)


@njit(cache=True, nogil=True, error_model="numpy")
def covered_points(points, positions, quads, out):
    """out[c, p] = whether the 2D point ``points[c, p]`` (N, P, 2) lies inside at least one convex quad
    of copy c, of either orientation; quad q's corners are the nodes ``quads[q]`` (Q, 4) of
    ``positions[c]`` (N, n, 3) seen from above (x, z). The arithmetic of
    ``tissue_env.retraction.covered`` (the same cross products, so the same decisions), without
    its (N, P, Q, 4, 2) temporaries."""
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _hourglass_block(hg_indptr, hg_indices, hg_data, hg_group, x, rest, flat, displacement, block, blocks, fill):
    """Rows [block dofs / blocks, (block + 1) dofs / blocks) of ``stacked_hourglass_subtract``: the
    copies' displacements there (``fill``), else their forces."""
    n_copies = hg_group.shape[0]
    dofs = hg_indptr.shape[0] - 1
    first, last = block * dofs // blocks, (block + 1) * dofs // blocks
    if fill:
        for c in range(n_copies):
            for i in range(first, last):
                displacement[i, c] = x[c * dofs + i] - rest[c * dofs + i]
        return
    total = np.empty(n_copies)
    for row in range(first, last):
        _copies_row_product(hg_indptr, hg_indices, hg_data, hg_group, displacement, row, total)
        for c in range(n_copies):
            flat[c * dofs + row] -= total[c]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def stacked_hourglass_subtract_serial(hg_indptr, hg_indices, hg_data, hg_group, positions, rest_positions, forces,
                                      displacement):
    """forces (N n, 3) -= K_c (x_c - X_c) for every copy c of a stacked model (copies first: copy c's
    nodes are the c-th n rows), K_c the hourglass matrix of ONE copy (CSR ``hg_indptr``,
    ``hg_indices``) with the values ``hg_data[:, hg_group[c]]`` ((nnz, G): the G distinct matrices).
    ``model_forces``' hourglass term of the stacked model, reading the single copy's matrix once for
    all copies instead of a stacked matrix N times its size (out of cache at N = 16).
    ``displacement`` (3 n, N) scratch."""
    x, rest, flat = positions.reshape(-1), rest_positions.reshape(-1), forces.reshape(-1)
    _hourglass_block(hg_indptr, hg_indices, hg_data, hg_group, x, rest, flat, displacement, 0, 1, True)
    _hourglass_block(hg_indptr, hg_indices, hg_data, hg_group, x, rest, flat, displacement, 0, 1, False)


@njit(cache=True, error_model="numpy", fastmath=_FAST, parallel=True)
def stacked_hourglass_subtract(hg_indptr, hg_indices, hg_data, hg_group, positions, rest_positions, forces,
                               displacement, blocks):
    """``stacked_hourglass_subtract_serial`` with its rows in ``blocks`` blocks (one per numba
    thread) on numba's threads (a row's sum is the same for any split: the same floats)."""
    x, rest, flat = positions.reshape(-1), rest_positions.reshape(-1), forces.reshape(-1)
    for block in prange(blocks):
        _hourglass_block(hg_indptr, hg_indices, hg_data, hg_group, x, rest, flat, displacement, block, blocks, True)
    for block in prange(blocks):
        _hourglass_block(hg_indptr, hg_indices, hg_data, hg_group, x, rest, flat, displacement, block, blocks, False)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, inline="always")
def _hourglass_group_rows(indptr, indices, block_rows, order, group_start, displacement, flat, block, blocks, total):
    """Node rows [block n / blocks, (block + 1) n / blocks) of ``stacked_hourglass_subtract_groups``."""
    n_nodes = indptr.shape[0] - 1
    dofs = 3 * n_nodes
    first, last = block * n_nodes // blocks, (block + 1) * n_nodes // blocks
    for i in range(first, last):
        for g in range(group_start.shape[0] - 1):
            start, end = group_start[g], group_start[g + 1]
            values = block_rows[g]
            for t in range(start, end):
                total[t, 0] = 0.0
                total[t, 1] = 0.0
                total[t, 2] = 0.0
            for q in range(indptr[i], indptr[i + 1]):
                j = 3 * indices[q]
                b = 9 * q
                b00, b01, b02 = values[b], values[b + 1], values[b + 2]
                b10, b11, b12 = values[b + 3], values[b + 4], values[b + 5]
                b20, b21, b22 = values[b + 6], values[b + 7], values[b + 8]
                for t in range(start, end):
                    d0, d1, d2 = displacement[t, j], displacement[t, j + 1], displacement[t, j + 2]
                    total[t, 0] += b00 * d0 + b01 * d1 + b02 * d2
                    total[t, 1] += b10 * d0 + b11 * d1 + b12 * d2
                    total[t, 2] += b20 * d0 + b21 * d1 + b22 * d2
            for t in range(start, end):
                row = order[t] * dofs + 3 * i
                flat[row] -= total[t, 0]
                flat[row + 1] -= total[t, 1]
                flat[row + 2] -= total[t, 2]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
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
    displacement = np.empty((n_copies, dofs))
    for t in range(n_copies):
        c = order[t]
        for j in range(dofs):
            displacement[t, j] = x[c * dofs + j] - rest[c * dofs + j]
    _hourglass_group_rows(indptr, indices, block_rows, order, group_start, displacement, flat, 0, 1,
                          np.empty((n_copies, 3)))


@njit(cache=True, error_model="numpy", fastmath=_FAST, parallel=True)
def stacked_hourglass_subtract_groups(indptr, indices, block_rows, order, group_start, positions, rest_positions,
                                      forces, blocks):
    """``stacked_hourglass_subtract_groups_serial`` with the node rows in ``blocks`` blocks on numba's
    threads (a row's sums do not depend on the split: the same floats)."""
    n_copies = order.shape[0]
    dofs = 3 * (indptr.shape[0] - 1)
    x, rest, flat = positions.reshape(-1), rest_positions.reshape(-1), forces.reshape(-1)
    displacement = np.empty((n_copies, dofs))  # the copies' displacements in group order
    for t in prange(n_copies):
        c = order[t]
        for j in range(dofs):
            displacement[t, j] = x[c * dofs + j] - rest[c * dofs + j]
    for block in prange(blocks):
        _hourglass_group_rows(indptr, indices, block_rows, order, group_start, displacement, flat, block, blocks,
                              np.empty((n_copies, 3)))


@njit(cache=True, error_model="numpy", parallel=True)
def spring_lengths_copies(count, positions, springs, length):
    """``spring_lengths`` of a stacked model of ``count`` copies (copies first: copy c's springs are
    the c-th equal slice), the copies on numba's threads (the same floats)."""
    per = springs.shape[0] // count
    for c in prange(count):
        spring_lengths(positions, springs[c * per:(c + 1) * per], length[c * per:(c + 1) * per])


@njit(cache=True, error_model="numpy", parallel=True)
def element_volumes_copies(count, positions, elements, out):
    """``element_volumes`` of a stacked model of ``count`` copies (copy c's elements the c-th equal
    slice), the copies on numba's threads (the same floats)."""
    per = elements.shape[0] // count
    for c in prange(count):
        element_volumes(positions, elements[c * per:(c + 1) * per], out[c * per:(c + 1) * per])
    return out


@njit(cache=True, error_model="numpy", parallel=True)
def scatter_springs_copies(count, springs, unit, tension, damping, velocities, use_velocity, forces):
    """``scatter_springs`` of a stacked model of ``count`` copies (copy c's springs the c-th equal
    slice, on its own nodes), the copies on numba's threads (the same floats)."""
    per = springs.shape[0] // count
    for c in prange(count):
        a, b = c * per, (c + 1) * per
        scatter_springs(springs[a:b], unit[a:b], tension[a:b], damping[a:b], velocities, use_velocity, forces)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def serial_product(a, b):
    """a @ b (m, k) x (k, p) in this thread: a product of a few-column matrix by a small one
    (``integrators.InverseColumns.correction``: m the dofs, k = p the imposed dofs, at most
    ``CAPACITANCE_MAX``). Through numpy, OpenBLAS runs such a product on its thread pool, whose
    threads then spin on the other cores after every call: Retraction's vector env at N = 16 used
    1.9 CPU seconds per wall second that way, at the same wall time."""
    m, k = a.shape
    p = b.shape[1]
    out = np.zeros((m, p))
    for i in range(m):
        for q in range(k):
            value = a[i, q]
            if value != 0.0:
                for j in range(p):
                    out[i, j] += value * b[q, j]
    return out


@njit(cache=True, parallel=True)
def _touch_threads(out):
    """A parallel loop: its first call starts numba's thread pool (``start_threads``)."""
    for i in prange(out.shape[0]):
        out[i] = i


#: [True] in a process forked from this one (``os.register_at_fork``): GNU OpenMP's thread pool is
#: not fork-safe (numba terminates a forked child that enters a parallel region of a pool its parent
#: started), so the batched vector envs use the serial kernels there (``solve_copies_lu_serial``,
#: ``factor_copies_serial``).
FORKED = [False]
os.register_at_fork(after_in_child=lambda: FORKED.__setitem__(0, True))


def threaded(threads: int) -> bool:
    """Whether the parallel kernels (not their ``_serial`` versions) run for ``threads`` threads:
    more than one, and not in a forked process (``FORKED``)."""
    return threads > 1 and not FORKED[0]


#: GNU OpenMP's spin count for numba's idle threads (``start_threads``): they spin about 0.8 ms
#: after a parallel region (measured: 0.84-0.96 ms of CPU per pause of 20-200 ms; 0.15-0.21 ms
#: sleeping at once, OMP_WAIT_POLICY=PASSIVE; 6-7 ms with libgomp's default of 300000), long enough
#: to bridge the Python between a step's parallel kernels, short enough that a pause (a policy
#: update) finds them asleep
SPIN_COUNT = 30000


def start_threads():
    """Start numba's thread pool (the parallel kernels: ``factor_copies``, ``solve_copies_lu``) with
    idle threads that spin briefly, then sleep. With numba's OpenMP layer, GNU OpenMP reads
    ``OMP_WAIT_POLICY`` and ``GOMP_SPINCOUNT`` once, when it loads. A thread woken from sleep costs
    about 70-80 us per parallel region here (an empty region: 2.5 us with spinning threads), and a
    vector env step runs a dozen regions: Palpation's vector env at N = 16 ran 674-704 env steps/s
    with sleeping threads (PASSIVE), 754-765 with SPIN_COUNT (TumorPositioning 813 -> 857,
    Retraction 1033 -> 1145), at 2-8% less work per CPU second; libgomp's default spin count gave
    771-778 and kept a core busy for 7 ms after every region. ``GOMP_SPINCOUNT`` is set for the load
    only, and only when the user has set neither variable; a pool already started is left as it is."""
    unset = "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ
    if unset:
        os.environ["GOMP_SPINCOUNT"] = str(SPIN_COUNT)
    try:
        _touch_threads(np.empty(4))
    finally:
        if unset:
            os.environ.pop("GOMP_SPINCOUNT", None)


# -- the batched implicit step's per-dof glue (tissue_env.batched / tissue_env.vector) ------------------
# Elementwise passes over (N, 3 n) rows that numpy made one temporary array each: the same IEEE
# operations in the same order per element (no fastmath), so the same floats, in one pass, the rows
# on numba's threads (the ``_serial`` twins: one thread, a forked process).

@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rows_start(x, v, target, imposed, dt, target_velocity, moved, c):
    for i in range(x.shape[1]):
        velocity = (target[c, i] - x[c, i]) / dt
        target_velocity[c, i] = velocity
        moved[c, i] = velocity if imposed[c, i] else v[c, i]


@njit(cache=True, error_model="numpy", parallel=True)
def implicit_rows_start(x, v, target, imposed, dt, target_velocity, moved):
    """The implicit step's start per dof of the rows (N, 3 n): target_velocity = (target - x) / dt
    m/s, and moved = v + the imposed velocity change: the target velocity on the ``imposed`` dofs,
    v elsewhere."""
    for c in prange(x.shape[0]):
        _rows_start(x, v, target, imposed, dt, target_velocity, moved, np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy")
def implicit_rows_start_serial(x, v, target, imposed, dt, target_velocity, moved):
    """``implicit_rows_start`` in this thread only."""
    for c in range(x.shape[0]):
        _rows_start(x, v, target, imposed, dt, target_velocity, moved, c)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rows_rhs(forces, mass, v, product, dt, rhs, c):
    for i in range(v.shape[1]):
        rhs[c, i] = dt * forces[c, i] + mass[c, i] * v[c, i] - product[c, i]


@njit(cache=True, error_model="numpy", parallel=True)
def implicit_rows_rhs(forces, mass, v, product, dt, rhs):
    """rhs = dt f + M v - product per dof of the rows (N, 3 n) (N s, kg m/s)."""
    for c in prange(v.shape[0]):
        _rows_rhs(forces, mass, v, product, dt, rhs, np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy")
def implicit_rows_rhs_serial(forces, mass, v, product, dt, rhs):
    """``implicit_rows_rhs`` in this thread only."""
    for c in range(v.shape[0]):
        _rows_rhs(forces, mass, v, product, dt, rhs, c)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rows_update(x, v, solution, imposed, target, target_velocity, dt, active, positions, velocities, new_x,
                 new_v, c):
    if not active[c]:
        for i in range(x.shape[1]):
            new_x[c, i] = positions[c, i]
            new_v[c, i] = velocities[c, i]
        return
    for i in range(x.shape[1]):
        if imposed[c, i]:
            new_x[c, i] = target[c, i]
            new_v[c, i] = target_velocity[c, i]
        else:
            velocity = v[c, i] + solution[c, i]
            new_v[c, i] = velocity
            new_x[c, i] = x[c, i] + dt * velocity


@njit(cache=True, error_model="numpy", parallel=True)
def implicit_rows_update(x, v, solution, imposed, target, target_velocity, dt, active, positions, velocities,
                         new_x, new_v):
    """The implicit step's end per dof of the rows (N, 3 n): v' = v + dv (dv the ``solution``) and
    x' = x + dt v' on the free dofs, ``target`` and ``target_velocity`` on the ``imposed`` ones; an
    inactive row keeps ``positions`` and ``velocities`` (N, 3 n)."""
    for c in prange(x.shape[0]):
        _rows_update(x, v, solution, imposed, target, target_velocity, dt, active, positions, velocities, new_x,
                     new_v, np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy")
def implicit_rows_update_serial(x, v, solution, imposed, target, target_velocity, dt, active, positions, velocities,
                                new_x, new_v):
    """``implicit_rows_update`` in this thread only."""
    for c in range(x.shape[0]):
        _rows_update(x, v, solution, imposed, target, target_velocity, dt, active, positions, velocities, new_x,
                     new_v, c)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _strain_row(length, rest_length, strain, collapsed, c):
    largest = 0.0
    undefined = False
    short = False
    for s in range(length.shape[1]):
        ratio = abs(length[c, s] / rest_length[c, s] - 1.0)
        if ratio != ratio:
            undefined = True
        elif ratio > largest:
            largest = ratio
        if not length[c, s] > 1e-6 * rest_length[c, s]:
            short = True
    strain[c] = np.nan if undefined else largest
    collapsed[c] = short


@njit(cache=True, error_model="numpy", parallel=True)
def strain_extremes(length, rest_length, strain, collapsed):
    """Per row of spring lengths (N, S) m against ``rest_length`` (N, S): strain[c] = max |L / L0 - 1|
    (NaN where a ratio is NaN, as numpy's max) and collapsed[c] = not all L > 1e-6 L0 (a NaN length
    counts as collapsed, as numpy's comparison)."""
    for c in prange(length.shape[0]):
        _strain_row(length, rest_length, strain, collapsed, np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy")
def strain_extremes_serial(length, rest_length, strain, collapsed):
    """``strain_extremes`` in this thread only."""
    for c in range(length.shape[0]):
        _strain_row(length, rest_length, strain, collapsed, c)


@njit(cache=True, nogil=True, error_model="numpy")
def masked_reaction(forces, mask, out):
    """out[c] = -sum over nodes of ``forces[c]`` (N, n, 3) N where ``mask`` (N, n, 3) holds: the tool's
    reaction per copy, summed node after node as numpy's sum over axis 1."""
    for c in range(forces.shape[0]):
        for k in range(3):
            out[c, k] = -forces[c, 0, k] if mask[c, 0, k] else 0.0
        for node in range(1, forces.shape[1]):
            for k in range(3):
                out[c, k] += -forces[c, node, k] if mask[c, node, k] else 0.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _health_copy(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                 has_previous, growing, due, neighbours, signs, elements, status, speed, c):
    status[c] = 0
    if not rows[c]:
        return
    finite, fastest, inside = health(positions[c], velocities[c], low[c], high[c])
    speed[c] = fastest
    if not finite:
        status[c] = 1
        return
    if fastest > max_speed[c]:
        status[c] = 2
        return
    if not inside:
        status[c] = 3
        return
    if has_previous[c]:  # the oscillation test against the last checked velocities
        new = 0.0
        old = 0.0
        cross = 0.0
        for node in range(velocities.shape[1]):
            for k in range(3):
                v = velocities[c, node, k]
                p = previous[c, node, k]
                new += v * v
                old += p * p
                cross += v * p
        reversing = cross < -0.5 * np.sqrt(new * old)
        fast = new > velocities.shape[1] * floor_speed[c] ** 2
        growing[c] = growing[c] + 1 if reversing and new > old and fast else 0
    has_previous[c] = True
    for node in range(velocities.shape[1]):
        for k in range(3):
            previous[c, node, k] = velocities[c, node, k]
    if growing[c] >= oscillation_steps[c]:
        status[c] = 5
    elif due[c] and any_inverted(positions[c], elements, neighbours, signs):
        status[c] = 4


@njit(cache=True, error_model="numpy", parallel=True)
def health_copies(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                  has_previous, growing, due, neighbours, signs, elements, status, speed):
    """``integrators.DivergenceMonitors.check``'s tests for the copies ``rows`` (N,) bool of positions
    and velocities (N, n, 3), in this order: status[c] = 1 non-finite, 2 a node faster than
    ``max_speed[c]`` m/s (speed[c] its speed), 3 a node outside [low[c], high[c]] (N, 3) m; else the
    oscillation test against ``previous[c]`` (the copy's last checked velocities, where
    ``has_previous[c]``; then set to these): ``growing[c]`` counts the consecutive checks whose
    velocity field reverses (cosine below -0.5) and grows with v.v > n ``floor_speed[c]``^2, and
    reaching ``oscillation_steps[c]`` gives 5; else, where ``due[c]``, 4 for an inverted element
    (``any_inverted`` on ``elements``); 0 healthy."""
    for c in prange(positions.shape[0]):
        _health_copy(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                     has_previous, growing, due, neighbours, signs, elements, status, speed, np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy")
def health_copies_serial(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                         has_previous, growing, due, neighbours, signs, elements, status, speed):
    """``health_copies`` in this thread only."""
    for c in range(positions.shape[0]):
        _health_copy(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                     has_previous, growing, due, neighbours, signs, elements, status, speed, c)


@njit(cache=True, nogil=True, error_model="numpy")
def _capacitance_task(columns, indptr, imposed, out, ok, t):
    """``capacitance_corrections``' task ``t``: Gauss-Jordan inverse of C with partial pivoting, then
    W = Z C^-1 into its slice of ``out``."""
    first, last = indptr[t], indptr[t + 1]
    k = last - first
    n = columns.shape[1]
    system = np.empty((k, k))
    inverse = np.zeros((k, k))
    for a in range(k):
        for b in range(k):
            system[a, b] = columns[first + b, imposed[first + a]]
        inverse[a, a] = 1.0
    scale = 0.0
    for a in range(k):
        for b in range(k):
            scale = max(scale, abs(system[a, b]))
    for col in range(k):
        pivot = col
        for a in range(col + 1, k):
            if abs(system[a, col]) > abs(system[pivot, col]):
                pivot = a
        if not abs(system[pivot, col]) > 1e-14 * scale:  # singular to working precision (or NaN)
            ok[t] = False
            return
        if pivot != col:
            for b in range(k):
                system[col, b], system[pivot, b] = system[pivot, b], system[col, b]
                inverse[col, b], inverse[pivot, b] = inverse[pivot, b], inverse[col, b]
        factor = 1.0 / system[col, col]
        for b in range(k):
            system[col, b] *= factor
            inverse[col, b] *= factor
        for a in range(k):
            if a != col:
                multiple = system[a, col]
                if multiple != 0.0:
                    for b in range(k):
                        system[a, b] -= multiple * system[col, b]
                        inverse[a, b] -= multiple * inverse[col, b]
    base = n * first
    for i in range(n):
        for j in range(k):
            out[base + i * k + j] = 0.0
    for q in range(k):
        for i in range(n):
            value = columns[first + q, i]
            if value != 0.0:
                for j in range(k):
                    out[base + i * k + j] += value * inverse[q, j]
    ok[t] = True


@njit(cache=True, error_model="numpy", parallel=True)
def capacitance_corrections(columns, indptr, imposed, out, ok):
    """Several capacitance corrections W = Z (Z[c])^-1 at once (``integrators.InverseColumns.correction``,
    the batched vector envs' ``_correct``): task t's columns of the inverse are the rows
    ``columns[indptr[t]:indptr[t + 1]]`` (k_t, 3 n) (Z^T), for its imposed dofs
    ``imposed[indptr[t]:indptr[t + 1]]`` (c); its W (3 n, k_t) C-order goes to
    ``out[3 n indptr[t]:3 n indptr[t + 1]]``. ok[t] False where Z[c] is singular to working
    precision (pivot below 1e-14 of its largest entry). The tasks on numba's threads."""
    for t in prange(indptr.shape[0] - 1):
        _capacitance_task(columns, indptr, imposed, out, ok, np.int64(t))


@njit(cache=True, nogil=True, error_model="numpy")
def capacitance_corrections_serial(columns, indptr, imposed, out, ok):
    """``capacitance_corrections`` in this thread only (one thread, a forked process)."""
    for t in range(indptr.shape[0] - 1):
        _capacitance_task(columns, indptr, imposed, out, ok, t)
