"""Measurements of the current state: spring lengths, exact hexahedron volumes, the health checks
(finite, speed, bounds, inverted corners), strain extremes and the reaction on masked nodes, for one
model and for N stacked copies.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .vectors import add, cross, dot, row, sub


@njit(cache=True, nogil=True, error_model="numpy")
def spring_lengths(positions, springs, length):
    """Lengths (m) of every spring into ``length`` (S,)."""
    for s in range(springs.shape[0]):
        a, b = springs[s, 0], springs[s, 1]
        dx = positions[b, 0] - positions[a, 0]
        dy = positions[b, 1] - positions[a, 1]
        dz = positions[b, 2] - positions[a, 2]
        length[s] = np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def corner_differences(x0, x1, x2, x3, x4, x5, x6, x7):
    """(d_1, ..., d_7), d_i = x_i - x_0 (m) for the corners in lexicographic order (i = a + 2 b + 4 c
    at local (a, b, c)), from the corners x0 .. x7 (3-tuples) of a hexahedron in VTK order."""
    return (sub(x1, x0), sub(x3, x0), sub(x2, x0), sub(x4, x0),
            sub(x5, x0), sub(x7, x0), sub(x6, x0))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def trilinear_volume(d):
    """Exact volume (m^3) of a trilinear hexahedron from its ``corner_differences`` d.

    The integral of det J is a cubic form in the corners; written with the d_i it is (1/12) sum of
    15 triple products (``_VOLUME_TRIPLES``), grouped here into 9 cross products (coefficients
    fitted to, and tested against, 2x2x2 Gauss quadrature, which is exact for this integrand).
    """
    d1, d2, d3, d4, d5, d6, d7 = d
    volume = dot(d1, add(add(cross(d2, d3), cross(d3, add(d5, d7))), cross(d5, sub(d4, d7))))
    volume += dot(d2, sub(cross(d6, sub(d7, d4)), cross(d3, add(d6, d7))))
    volume += dot(d3, cross(sub(d6, d5), d7))
    six_seven = cross(d6, d7)
    volume += dot(d4, sub(cross(d5, add(d6, d7)), six_seven))
    volume -= dot(d5, six_seven)
    return volume / 12.0


@njit(cache=True, nogil=True, error_model="numpy")
def hex_volume(corner):
    """Exact volume (m^3) of a trilinear hexahedron from its (8, 3) corners, VTK order
    (``trilinear_volume``)."""
    return trilinear_volume(corner_differences(row(corner, 0), row(corner, 1), row(corner, 2), row(corner, 3),
                                               row(corner, 4), row(corner, 5), row(corner, 6), row(corner, 7)))


@njit(cache=True, nogil=True, error_model="numpy")
def element_volumes(positions, elements, out):
    """``out[e]`` = exact volume (m^3) of every trilinear hexahedron (``hex_volume``), no temporaries
    per element: much faster than the batched Gauss determinants of ``mesh.hex_volumes``; of every
    tetrahedron, det[x1 - x0, x2 - x0, x3 - x0] / 6, when ``elements`` has 4 columns."""
    if elements.shape[1] == 4:
        for e in range(elements.shape[0]):
            a, b, c, d = elements[e, 0], elements[e, 1], elements[e, 2], elements[e, 3]
            u0, u1, u2 = positions[b, 0] - positions[a, 0], positions[b, 1] - positions[a, 1], positions[b, 2] - positions[a, 2]
            v0, v1, v2 = positions[c, 0] - positions[a, 0], positions[c, 1] - positions[a, 1], positions[c, 2] - positions[a, 2]
            w0, w1, w2 = positions[d, 0] - positions[a, 0], positions[d, 1] - positions[a, 1], positions[d, 2] - positions[a, 2]
            out[e] = (u0 * (v1 * w2 - v2 * w1) - u1 * (v0 * w2 - v2 * w0) + u2 * (v0 * w1 - v1 * w0)) / 6.0
        return out
    corner = np.empty((8, 3))
    for e in range(elements.shape[0]):
        for n in range(8):
            for c in range(3):
                corner[n, c] = positions[elements[e, n], c]
        out[e] = hex_volume(corner)
    return out


#: The 15 (a, b, c, sign) of V = 1/12 sum sign d_a . (d_b x d_c), lexicographic corners.
_VOLUME_TRIPLES = np.array([
    [1, 2, 3, 1], [1, 3, 5, 1], [1, 3, 7, 1], [1, 4, 5, -1], [1, 5, 7, -1], [2, 3, 6, -1], [2, 3, 7, -1],
    [2, 4, 6, 1], [2, 6, 7, 1], [3, 5, 7, -1], [3, 6, 7, 1], [4, 5, 6, 1], [4, 5, 7, 1], [4, 6, 7, -1],
    [5, 6, 7, -1]])


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
    """True when a corner Jacobian (signed corner frame volume) of any element is <= 0: the frames of
    corner ``neighbours`` (C, 3) with orientation ``signs`` (C,) (``elements.corner_frames``: the 8 of
    a hexahedron, the one of a tetrahedron)."""
    for m in range(elements.shape[0]):
        for corner in range(neighbours.shape[0]):
            o = elements[m, corner]
            a, b, c = elements[m, neighbours[corner, 0]], elements[m, neighbours[corner, 1]], elements[m, neighbours[corner, 2]]
            ax, ay, az = positions[a, 0] - positions[o, 0], positions[a, 1] - positions[o, 1], positions[a, 2] - positions[o, 2]
            bx, by, bz = positions[b, 0] - positions[o, 0], positions[b, 1] - positions[o, 1], positions[b, 2] - positions[o, 2]
            cx, cy, cz = positions[c, 0] - positions[o, 0], positions[c, 1] - positions[o, 1], positions[c, 2] - positions[o, 2]
            det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
            if signs[corner] * det <= 0.0:
                return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def any_collapsed(positions, elements, gradients):
    """True when any element's mean deformation gradient F = sum_a x_a (outer) b_a (``gradients``
    (M, n, 3) the b_a in 1/m) has det F <= 0: the inversion test of a model whose elements' energy
    is a function of that F (``models.elements.inversion_gradients``)."""
    for m in range(elements.shape[0]):
        f00 = f01 = f02 = f10 = f11 = f12 = f20 = f21 = f22 = 0.0
        for a in range(elements.shape[1]):
            node = elements[m, a]
            x, y, z = positions[node, 0], positions[node, 1], positions[node, 2]
            b0, b1, b2 = gradients[m, a, 0], gradients[m, a, 1], gradients[m, a, 2]
            f00 += x * b0
            f01 += x * b1
            f02 += x * b2
            f10 += y * b0
            f11 += y * b1
            f12 += y * b2
            f20 += z * b0
            f21 += z * b1
            f22 += z * b2
        det = f00 * (f11 * f22 - f12 * f21) - f01 * (f10 * f22 - f12 * f20) + f02 * (f10 * f21 - f11 * f20)
        if not det > 0.0:
            return True
    return False


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
                 has_previous, growing, due, neighbours, signs, elements, gradients, mean_test, status, speed, c):
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
    elif due[c] and mean_test[c]:
        if any_collapsed(positions[c], elements, gradients[c]):
            status[c] = 6
    elif due[c] and any_inverted(positions[c], elements, neighbours, signs):
        status[c] = 4


@njit(cache=True, error_model="numpy", parallel=True)
def health_copies(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                  has_previous, growing, due, neighbours, signs, elements, gradients, mean_test, status, speed):
    """``solver.DivergenceMonitors.check``'s tests for the copies ``rows`` (N,) bool of positions
    and velocities (N, n, 3), in this order: status[c] = 1 non-finite, 2 a node faster than
    ``max_speed[c]`` m/s (speed[c] its speed), 3 a node outside [low[c], high[c]] (N, 3) m; else the
    oscillation test against ``previous[c]`` (the copy's last checked velocities, where
    ``has_previous[c]``; then set to these): ``growing[c]`` counts the consecutive checks whose
    velocity field reverses (cosine below -0.5) and grows with v.v > n ``floor_speed[c]``^2, and
    reaching ``oscillation_steps[c]`` gives 5; else, where ``due[c]``, the inversion test: where
    ``mean_test[c]``, 6 for an element whose mean deformation gradient has det <= 0 (``any_collapsed``
    with the copy's ``gradients[c]`` (M, n, 3) 1/m), elsewhere 4 for an inverted corner
    (``any_inverted`` on ``elements``); 0 healthy."""
    for c in prange(positions.shape[0]):
        _health_copy(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                     has_previous, growing, due, neighbours, signs, elements, gradients, mean_test, status, speed,
                     np.int64(c))


@njit(cache=True, nogil=True, error_model="numpy")
def health_copies_serial(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                         has_previous, growing, due, neighbours, signs, elements, gradients, mean_test, status,
                         speed):
    """``health_copies`` in this thread only."""
    for c in range(positions.shape[0]):
        _health_copy(positions, velocities, rows, low, high, max_speed, floor_speed, oscillation_steps, previous,
                     has_previous, growing, due, neighbours, signs, elements, gradients, mean_test, status, speed, c)
