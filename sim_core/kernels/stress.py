"""The finite-strain stress correction of "baudet-hyperelastic" (docs/physics.md section 11): per
element, f_a = -V0 (P_NH(F) - P_S(F)) b_a with F the element's mean deformation gradient, and its
stiffness, the 9 x 9 matrix T = V0 (A_NH(F) - A_S(F)) on the entries of F (the element block is
K_e = B^T T B, B the map from the element's nodal displacements to F), for the implicit step. The
numpy reference is ``sim_core.models.stress_correction.element_forces`` / ``tangent_matrices``.

The passes take the elements ``LANES`` at a time, one lane per element: every per-element quantity of
a block (F, its cofactor, the stress, the 81 entries of T, ...) is a row of a (., LANES) scratch
array, and the per-element inputs are read in the element-last layout of
``stress_correction.stress_lanes`` (b (n, 3, M), D (S_e, 3, M), L and k (S_e, M); the element
nodes (n, M)), so that each formula is a loop over the lanes that LLVM turns into vector
instructions. Each element's floats come from its own lane's operations alone (no reassociation
across lanes), so they do not depend on the block size. The per-element branches (the negative
part of a compressed element's stress, with its arccos and cosines, and the positive part of an
indefinite tangent) run lane by lane.

One body for every pass: ``_block_deformation`` (F; ``_cell_deformation`` for cells held in compressed
rows, the smoothing domains of tetrahedral models), ``_block_law`` (its cofactor, P_NH - P_S), ``_block_tangent`` and
``_block_clamp`` are inlined into ``stress_correction_range`` (forces, and with ``tangent`` the
stiffness), which the single-model passes (``stress_correction_add``,
``stress_correction_tangent_add``) and their per-copy threaded versions (``*_copies``: a stacked
model's copies, one per numba thread at a time, the same floats) call on their elements.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fastmath import FAST_EXACT

#: elements per block of the passes: the scratch of a tangent block (about 26 KB) stays in L1
LANES = 16


#: row of the symmetric 3 x 3 entry (J, L) in the six-row form 00 01 02 11 12 22
_SYMMETRIC = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def add_outer(g, x0, x1, x2, b0, b1, b2):
    """g + x (x) b for g a 9-tuple of rows 3 i + J: one node's term of a nodal field's gradient
    sum_a x_a (x) b_a (F from the positions, dF from a displacement), summed in the caller's
    registers and under the caller's fastmath flags (numba inlines it in the caller's IR)."""
    return (g[0] + x0 * b0, g[1] + x0 * b1, g[2] + x0 * b2, g[3] + x1 * b0, g[4] + x1 * b1, g[5] + x1 * b2,
            g[6] + x2 * b0, g[7] + x2 * b1, g[8] + x2 * b2)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _spring_image(f, spring_vector, s, m, j):
    """(D, F D) of spring ``s`` of element ``m`` in lane ``j`` (f (9, LANES) rows 3 i + J of F), m."""
    d0, d1, d2 = spring_vector[s, 0, m], spring_vector[s, 1, m], spring_vector[s, 2, m]
    u0 = f[0, j] * d0 + f[1, j] * d1 + f[2, j] * d2
    u1 = f[3, j] * d0 + f[4, j] * d1 + f[5, j] * d2
    u2 = f[6, j] * d0 + f[7, j] * d1 + f[8, j] * d2
    return d0, d1, d2, u0, u1, u2


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _block_deformation(positions, elements, offset, start, n, gradient, f):
    """f (9, LANES): rows 3 i + J of F of the elements start .. start + n - 1 of ``elements``
    (n, M_local) (lane j: local element start + j, row offset + start + j of ``gradient`` (n, 3, M))."""
    for j in range(n):  # F lane by lane in scalars: in the rows of f every term went through memory
        m = offset + start + j
        g = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        for a in range(gradient.shape[0]):
            node = elements[a, start + j]
            g = add_outer(g, positions[node, 0], positions[node, 1], positions[node, 2], gradient[a, 0, m],
                          gradient[a, 1, m], gradient[a, 2, m])
        for r in range(9):
            f[r, j] = g[r]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _cell_deformation(positions, indptr, nodes, entry_gradient, start, n, f):
    """f (9, LANES): rows 3 i + J of F of the cells (smoothing domains) start .. start + n - 1 held
    in compressed rows: cell d's nodes ``nodes[indptr[d]:indptr[d + 1]]`` with gradients
    ``entry_gradient`` (nnz, 3) 1/m (``smoothing.SmoothedStrain``)."""
    for j in range(n):
        d = start + j
        g = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        for e in range(indptr[d], indptr[d + 1]):
            node = nodes[e]
            g = add_outer(g, positions[node, 0], positions[node, 1], positions[node, 2], entry_gradient[e, 0],
                          entry_gradient[e, 1], entry_gradient[e, 2])
        for r in range(9):
            f[r, j] = g[r]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _cell_scatter(indptr, nodes, entry_gradient, offset, start, n, volume, p, forces):
    """forces (N, 3) -= V p b_a on the nodes of the cells start .. start + n - 1 (``_cell_deformation``'s
    compressed rows; their per-cell rows of ``volume`` start at ``offset``)."""
    for j in range(n):
        d = start + j
        v = volume[offset + d]
        p0, p1, p2, p3, p4, p5, p6, p7, p8 = p[0, j], p[1, j], p[2, j], p[3, j], p[4, j], p[5, j], p[6, j], p[7, j], p[8, j]
        for e in range(indptr[d], indptr[d + 1]):
            node = nodes[e]
            b0, b1, b2 = entry_gradient[e, 0], entry_gradient[e, 1], entry_gradient[e, 2]
            forces[node, 0] -= v * (p0 * b0 + p1 * b1 + p2 * b2)
            forces[node, 1] -= v * (p3 * b0 + p4 * b1 + p5 * b2)
            forces[node, 2] -= v * (p6 * b0 + p7 * b1 + p8 * b2)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _block_law(offset, start, n, volume, mu, lam, spring_vector, spring_length, spring_stiffness, linear, f, c, p, det,
               log_j, inverse_volume):
    """The block's stress from its deformation gradients f (9, LANES) (rows 3 i + J; lane j: row
    offset + start + j of the per-element arrays): c, p (9, LANES) rows of cof F = det F F^-T and
    P_NH(F) - P_S(F) in Pa, or with ``linear`` P_lin(F) - P_S(F), P_lin the small-strain Hooke
    stress lam tr(eps) I + 2 mu eps of eps = sym(F) - I; det, log_j (LANES,) det F and ln det F
    (0 if linear); inverse_volume (LANES,) scratch."""
    for j in range(n):
        f00, f01, f02 = f[0, j], f[1, j], f[2, j]
        f10, f11, f12 = f[3, j], f[4, j], f[5, j]
        f20, f21, f22 = f[6, j], f[7, j], f[8, j]
        c00 = f11 * f22 - f12 * f21
        c01 = f12 * f20 - f10 * f22
        c02 = f10 * f21 - f11 * f20
        c[0, j], c[1, j], c[2, j] = c00, c01, c02
        c[3, j] = f02 * f21 - f01 * f22
        c[4, j] = f00 * f22 - f02 * f20
        c[5, j] = f01 * f20 - f00 * f21
        c[6, j] = f01 * f12 - f02 * f11
        c[7, j] = f02 * f10 - f00 * f12
        c[8, j] = f00 * f11 - f01 * f10
        det[j] = f00 * c00 + f01 * c01 + f02 * c02
    if linear:
        for j in range(n):
            m = offset + start + j
            log_j[j] = 0.0
            volumetric = lam[m] * (f[0, j] + f[4, j] + f[8, j] - 3.0)
            for i in range(3):
                for k in range(3):
                    p[3 * i + k, j] = mu[m] * (f[3 * i + k, j] + f[3 * k + i, j])
                p[4 * i, j] += volumetric - 2.0 * mu[m]
    else:
        for j in range(n):  # the logarithm has no vector form here: its own loop, so the others vectorise
            log_j[j] = np.log(det[j])
        for j in range(n):
            m = offset + start + j
            inverse_scale = (lam[m] * log_j[j] - mu[m]) / det[j]  # P = mu F + (lam ln J - mu) F^-T
            for r in range(9):
                p[r, j] = mu[m] * f[r, j] + inverse_scale * c[r, j]
    for j in range(n):
        inverse_volume[j] = 1.0 / volume[offset + start + j]
    for s in range(spring_vector.shape[0]):  # minus the springs' own stress under F
        for j in range(n):
            m = offset + start + j
            d0, d1, d2, u0, u1, u2 = _spring_image(f, spring_vector, s, m, j)
            length = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
            t = spring_stiffness[s, m] * (length - spring_length[s, m]) / length * inverse_volume[j]
            p[0, j] -= t * u0 * d0
            p[1, j] -= t * u0 * d1
            p[2, j] -= t * u0 * d2
            p[3, j] -= t * u1 * d0
            p[4, j] -= t * u1 * d1
            p[5, j] -= t * u1 * d2
            p[6, j] -= t * u2 * d0
            p[7, j] -= t * u2 * d1
            p[8, j] -= t * u2 * d2


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _block_scatter(elements, offset, start, n, gradient, volume, p, forces):
    """forces (N, 3) -= V0 p b_a on the nodes of the block's elements, element by element."""
    for j in range(n):
        m = offset + start + j
        v = volume[m]
        p0, p1, p2, p3, p4, p5, p6, p7, p8 = p[0, j], p[1, j], p[2, j], p[3, j], p[4, j], p[5, j], p[6, j], p[7, j], p[8, j]
        for a in range(gradient.shape[0]):
            node = elements[a, start + j]
            b0, b1, b2 = gradient[a, 0, m], gradient[a, 1, m], gradient[a, 2, m]
            forces[node, 0] -= v * (p0 * b0 + p1 * b1 + p2 * b2)
            forces[node, 1] -= v * (p3 * b0 + p4 * b1 + p5 * b2)
            forces[node, 2] -= v * (p6 * b0 + p7 * b1 + p8 * b2)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _block_tangent(offset, start, n, volume, mu, lam, spring_vector, spring_length, spring_stiffness, linear, f, c,
                   det, log_j, t, products, row, g, scalars):
    """t (81, LANES): row 9 r + q of lane j the entry (r, q) of T = V0 (A_NH(F) - A_S(F)) of the lane's
    element (r = 3 i + J: dP_iJ; q = 3 k + L: dF_kL), with f, c, det, log_j from ``_block_law``:
    A_NH = mu d_ik d_JL + (mu - lam ln J) G_kJ G_iL + lam G_iJ G_kL (G = F^-T = c / det), or with
    ``linear`` the constant A_lin = lam d_iJ d_kL + mu (d_ik d_JL + d_iL d_kJ), and
    A_S = (1/V0) sum_s k_s [(1 - L_s/l_s) d_ik D_J D_L + (L_s / l_s^3) (F D_s)_i D_J (F D_s)_k D_L].
    Both are symmetric, A_NH filled on and above the diagonal and mirrored; the springs' second
    term is a sum of Kronecker products [(F D)(F D)^T]_ik [D D^T]_JL of two symmetric 3 x 3, summed
    as its 6 x 6 distinct products (``_SYMMETRIC`` pairs).
    products (54, LANES): rows 6 a + b the springs' sum over the pairs a = (i, k), b = (J, L), rows
    36 .. 53 the cofactor times the two coefficients of A_NH; row (12, LANES): one spring's
    (F D)(F D)^T L/l^3 k and D D^T; g (6, LANES): sum_s k_s (1 - L_s / l_s) D D^T; scalars
    (3, LANES) scratch: V0 mu and the two coefficients of A_NH (with ``linear``, V0 lam)."""
    _tangent_scalars(offset, start, n, volume, mu, lam, linear, det, log_j, scalars)
    if linear:
        _linear_tangent(n, t, scalars)
    else:
        _neo_hookean_tangent(n, c, t, products, scalars)
    _spring_tangent_sums(offset, start, n, spring_vector, spring_length, spring_stiffness, f, products, row, g)
    _subtract_spring_tangent(n, t, products, g)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _tangent_scalars(offset, start, n, volume, mu, lam, linear, det, log_j, scalars):
    """``_block_tangent``'s per-lane scalars (3, LANES): V0 mu (N m), then the two coefficients of
    A_NH over det^2, V0 (mu - lam ln J) / J^2 and V0 lam / J^2, or with ``linear`` V0 lam."""
    for j in range(n):
        m = offset + start + j
        v = volume[m]
        scalars[0, j] = v * mu[m]
        if not linear:
            inverse_det = 1.0 / det[j]
            scalars[1, j] = v * (mu[m] - lam[m] * log_j[j]) * inverse_det * inverse_det
            scalars[2, j] = v * lam[m] * inverse_det * inverse_det
        else:
            scalars[1, j] = v * lam[m]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _linear_tangent(n, t, scalars):
    """t (81, LANES) = V0 A_lin = V0 (lam d_iJ d_kL + mu (d_ik d_JL + d_iL d_kJ)), from
    ``_tangent_scalars``' V0 mu and V0 lam."""
    for r in range(81):
        for j in range(n):
            t[r, j] = 0.0
    for i in range(3):
        for k in range(3):
            for j in range(n):
                t[9 * (4 * i) + 4 * k, j] = scalars[1, j]  # d_iJ d_kL: rows and columns of the diagonal of F
                t[9 * (3 * i + k) + 3 * k + i, j] += scalars[0, j]  # d_iL d_kJ
        for jj in range(3):
            for j in range(n):
                t[10 * (3 * i + jj), j] += scalars[0, j]  # d_ik d_JL


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _neo_hookean_tangent(n, c, t, products, scalars):
    """t (81, LANES) = V0 A_NH = V0 (mu d_ik d_JL + (mu - lam ln J) G_kJ G_iL + lam G_iJ G_kL), from the
    cofactor c (9, LANES) and ``_tangent_scalars``; filled on and above the diagonal and mirrored.
    Rows 36 .. 53 of products (54, LANES) hold the cofactor times the two coefficients."""
    for r in range(9):
        for j in range(n):
            products[36 + r, j] = scalars[1, j] * c[r, j]
            products[45 + r, j] = scalars[2, j] * c[r, j]
    for i in range(3):
        for jj in range(3):
            r = 3 * i + jj
            for k in range(3):
                for ll in range(3):
                    q = 3 * k + ll
                    if q < r:
                        continue
                    for j in range(n):
                        value = (products[36 + 3 * k + jj, j] * c[3 * i + ll, j]
                                 + products[45 + 3 * i + jj, j] * c[3 * k + ll, j])
                        t[9 * r + q, j] = value
                        t[9 * q + r, j] = value
    for r in range(9):
        for j in range(n):
            t[10 * r, j] += scalars[0, j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _spring_tangent_sums(offset, start, n, spring_vector, spring_length, spring_stiffness, f, products, row, g):
    """The springs' sums of A_S over the block's elements, with F in f (9, LANES): products rows
    6 a + b (36, LANES) = sum_s k_s L_s / l_s^3 [(F D)(F D)^T]_a [D D^T]_b (``_SYMMETRIC`` pairs) and
    g (6, LANES) = sum_s k_s (1 - L_s / l_s) D D^T, in N/m m^2; row (12, LANES) scratch."""
    for a in range(36):
        for j in range(n):
            products[a, j] = 0.0
    for a in range(6):
        for j in range(n):
            g[a, j] = 0.0
    for s in range(spring_vector.shape[0]):
        for j in range(n):
            m = offset + start + j
            d0, d1, d2, u0, u1, u2 = _spring_image(f, spring_vector, s, m, j)
            squared = u0 * u0 + u1 * u1 + u2 * u2
            length = np.sqrt(squared)
            ratio = spring_length[s, m] / length
            k = spring_stiffness[s, m]
            across = k * (1.0 - ratio)
            along = k * ratio / squared
            dd0, dd1, dd2, dd3, dd4, dd5 = d0 * d0, d0 * d1, d0 * d2, d1 * d1, d1 * d2, d2 * d2
            g[0, j] += across * dd0
            g[1, j] += across * dd1
            g[2, j] += across * dd2
            g[3, j] += across * dd3
            g[4, j] += across * dd4
            g[5, j] += across * dd5
            a0, a1, a2 = along * u0, along * u1, along * u2
            row[0, j], row[1, j], row[2, j] = a0 * u0, a0 * u1, a0 * u2
            row[3, j], row[4, j], row[5, j] = a1 * u1, a1 * u2, a2 * u2
            row[6, j], row[7, j], row[8, j] = dd0, dd1, dd2
            row[9, j], row[10, j], row[11, j] = dd3, dd4, dd5
        for a in range(6):
            for b in range(6):
                for j in range(n):
                    products[6 * a + b, j] += row[a, j] * row[6 + b, j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _subtract_spring_tangent(n, t, products, g):
    """t (81, LANES) -= V0 A_S from ``_spring_tangent_sums``' products and g: entry (3 i + J, 3 k + L)
    loses the products of pair (i, k), (J, L), and g's (J, L) where i == k."""
    for i in range(3):
        for jj in range(3):
            for k in range(3):
                for ll in range(3):
                    entry, a, b = 9 * (3 * i + jj) + 3 * k + ll, _SYMMETRIC[i, k], _SYMMETRIC[jj, ll]
                    if i == k:
                        for j in range(n):
                            t[entry, j] -= products[6 * a + b, j] + g[b, j]
                    else:
                        for j in range(n):
                            t[entry, j] -= products[6 * a + b, j]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _symmetric_eigen3(a, values, vectors):
    """Eigenvalues (3,) and eigenvectors (columns of (3, 3)) of the symmetric 3 x 3 ``a`` (overwritten),
    cyclic Jacobi rotations to rounding."""
    for i in range(3):
        for j in range(3):
            vectors[i, j] = 1.0 if i == j else 0.0
    for sweep in range(12):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        scale = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if off <= 1e-30 * scale or off == 0.0:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                if a[p, q] == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
                tangent = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                cosine = 1.0 / np.sqrt(tangent * tangent + 1.0)
                sine = tangent * cosine
                for k in range(3):  # a := J^T a J
                    akp, akq = a[k, p], a[k, q]
                    a[k, p] = cosine * akp - sine * akq
                    a[k, q] = sine * akp + cosine * akq
                for k in range(3):
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k] = cosine * apk - sine * aqk
                    a[q, k] = sine * apk + cosine * aqk
                for k in range(3):
                    vkp, vkq = vectors[k, p], vectors[k, q]
                    vectors[k, p] = cosine * vkp - sine * vkq
                    vectors[k, q] = sine * vkp + cosine * vkq
    for i in range(3):
        values[i] = a[i, i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _negative_part(s00, s01, s02, s11, s12, s22, part, small, values, vectors):
    """part (6,) (rows 00 01 02 11 12 22) = [S]_- = sum over the eigenvalues l_e < 0 of S of
    -l_e v_e v_e^T, S the symmetric 3 x 3 of the six entries; False (part untouched) where S has no
    negative eigenvalue. The eigenvalues in closed form (the trigonometric solution of the
    characteristic cubic), the one eigenvector needed (the smallest's, or with two negative
    eigenvalues the largest's: [S]_- = l_1 v_1 v_1^T - S) as the longest cross product of two rows of
    S - l I. That vector's error is the rounding of S over the gap between l and the nearest other
    eigenvalue, and the gap is at least |l| (l and its neighbour lie on either side of 0), so its
    term l v v^T is off by no more than the rounding of S. ``_symmetric_eigen3`` where those rows
    are parallel (a repeated eigenvalue).
    small, vectors (3, 3), values (3,) scratch."""
    q = (s00 + s11 + s22) / 3.0
    a, b, c = s00 - q, s11 - q, s22 - q
    squared = a * a + b * b + c * c + 2.0 * (s01 * s01 + s02 * s02 + s12 * s12)
    if squared == 0.0:  # S = q I
        if q >= 0.0:
            return False
        part[0], part[1], part[2], part[3], part[4], part[5] = -q, 0.0, 0.0, -q, 0.0, -q
        return True
    radius = np.sqrt(squared / 6.0)
    cosine = (a * (b * c - s12 * s12) - s01 * (s01 * c - s12 * s02) + s02 * (s01 * s12 - b * s02)) / (
        2.0 * radius * radius * radius)
    cosine = min(max(cosine, -1.0), 1.0)
    angle = np.arccos(cosine) / 3.0
    largest = q + 2.0 * radius * np.cos(angle)
    smallest = q + 2.0 * radius * np.cos(angle + 2.0 * np.pi / 3.0)
    if smallest >= 0.0:
        return False
    if largest < 0.0:  # every eigenvalue negative: [S]_- = -S
        part[0], part[1], part[2], part[3], part[4], part[5] = -s00, -s01, -s02, -s11, -s12, -s22
        return True
    middle = 3.0 * q - largest - smallest
    value = largest if middle < 0.0 else smallest
    r00, r11, r22 = s00 - value, s11 - value, s22 - value  # the rows of S - l I: (r00 s01 s02), (s01 r11 s12), (s02 s12 r22)
    x0, x1, x2 = s01 * s12 - s02 * r11, s02 * s01 - r00 * s12, r00 * r11 - s01 * s01  # row 0 x row 1
    y0, y1, y2 = s01 * r22 - s02 * s12, s02 * s02 - r00 * r22, r00 * s12 - s01 * s02  # row 0 x row 2
    z0, z1, z2 = r11 * r22 - s12 * s12, s12 * s02 - s01 * r22, s01 * s12 - r11 * s02  # row 1 x row 2
    nx, ny, nz = x0 * x0 + x1 * x1 + x2 * x2, y0 * y0 + y1 * y1 + y2 * y2, z0 * z0 + z1 * z1 + z2 * z2
    if ny > nx and ny >= nz:
        x0, x1, x2, nx = y0, y1, y2, ny
    elif nz > nx:
        x0, x1, x2, nx = z0, z1, z2, nz
    if nx == 0.0:  # a repeated eigenvalue: the rows are parallel
        small[0, 0], small[0, 1], small[0, 2] = s00, s01, s02
        small[1, 0], small[1, 1], small[1, 2] = s01, s11, s12
        small[2, 0], small[2, 1], small[2, 2] = s02, s12, s22
        _symmetric_eigen3(small, values, vectors)
        if not (values[0] < 0.0 or values[1] < 0.0 or values[2] < 0.0):
            return False
        for row in range(6):
            part[row] = 0.0
        for e in range(3):
            if values[e] < 0.0:
                u0, u1, u2 = vectors[0, e], vectors[1, e], vectors[2, e]
                part[0] -= values[e] * u0 * u0
                part[1] -= values[e] * u0 * u1
                part[2] -= values[e] * u0 * u2
                part[3] -= values[e] * u1 * u1
                part[4] -= values[e] * u1 * u2
                part[5] -= values[e] * u2 * u2
        return True
    weight = value / nx  # l v v^T with v = x / |x|
    if middle < 0.0:  # two negative eigenvalues: l_1 v_1 v_1^T - S
        part[0], part[1], part[2] = weight * x0 * x0 - s00, weight * x0 * x1 - s01, weight * x0 * x2 - s02
        part[3], part[4], part[5] = weight * x1 * x1 - s11, weight * x1 * x2 - s12, weight * x2 * x2 - s22
    else:  # one: -l_3 v_3 v_3^T
        part[0], part[1], part[2] = -weight * x0 * x0, -weight * x0 * x1, -weight * x0 * x2
        part[3], part[4], part[5] = -weight * x1 * x1, -weight * x1 * x2, -weight * x2 * x2
    return True


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _congruence(root, m, source, target):
    """target (9, 9) = S source S with S = I_3 (x) root[m] (root[m] symmetric 3 x 3): the change of
    metric of ``_block_clamp``'s positive part, in both directions."""
    for i in range(3):
        for jj in range(3):
            for k in range(3):
                for ll in range(3):
                    total = 0.0
                    for a in range(3):
                        for b in range(3):
                            total += root[m, jj, a] * source[3 * i + a, 3 * k + b] * root[m, b, ll]
                    target[3 * i + jj, 3 * k + ll] = total


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _block_clamp(offset, start, n, volume, root, root_inverse, linear, det, c, p, t, lower, sym, shift, total, pivot,
                 good, part, small, values, vectors, square, w):
    """The implicit step's SPD treatment of the block's tangents t (81, LANES) (docs/physics.md 11), in
    place, on the lanes with det F > 0; returns the number of lanes whose positive part was taken.

    1. Each element's geometric (initial-stress) term V0 d_ik dS_JL, dS = F^-1 (P_NH - P_S) the
       second Piola-Kirchhoff stress the correction adds, loses its negative part, as the springs'
       geometric term t/l does where a spring is compressed: t += V0 I (x) [dS]_-  (|negative
       eigenvalues| of dS, ``_negative_part``, where dS is not positive definite by its leading
       minors). What remains is the material term F F (C_NH - C_S), positive
       semi-definite at rest for nu >= 0 and at moderate strain.
    2. Where that is still not positive semi-definite (the Cholesky factorisation of
       t + 1e-12 tr(t) I fails; the exact null space of the rotations passes), t := its positive
       part in the metric of the element's nodal displacements (with ``linear``, the small-strain
       law, whose correction has no geometric term, this step only): with S = I_3 (x) R,
       R = (sum_a b_a b_a^T)^(1/2) (``root[m]``; B = S Q with Q's rows orthonormal),
       B^T t B = Q^T (S t S) Q, so the positive part of the 24 x 24 block B^T t B is
       B^T S^-1 (S t S)_+ S^-1 B.
    lower (81, LANES), sym (6, LANES), shift, total, pivot (LANES,) float and good (LANES,) int
    scratch; part (6,), small, vectors (3, 3), values (3,), square, w (9, 9) scratch of the lane-by-lane steps."""
    if not linear:
        for j in range(n):  # dS = F^-1 p = c^T p / det, symmetrised: rows 00 01 02 11 12 22
            inverse_det = 1.0 / det[j]
            row = 0
            for jj in range(3):
                for ll in range(jj, 3):
                    upper = (c[jj, j] * p[ll, j] + c[3 + jj, j] * p[3 + ll, j] + c[6 + jj, j] * p[6 + ll, j]) * inverse_det
                    if ll == jj:
                        sym[row, j] = upper
                    else:
                        lower_entry = (c[ll, j] * p[jj, j] + c[3 + ll, j] * p[3 + jj, j]
                                       + c[6 + ll, j] * p[6 + jj, j]) * inverse_det
                        sym[row, j] = 0.5 * (lower_entry + upper)
                    row += 1
        for j in range(n):
            s00, s01, s02, s11, s12, s22 = sym[0, j], sym[1, j], sym[2, j], sym[3, j], sym[4, j], sym[5, j]
            minor = s00 * s11 - s01 * s01
            determinant = s00 * (s11 * s22 - s12 * s12) - s01 * (s01 * s22 - s12 * s02) + s02 * (s01 * s12 - s11 * s02)
            if not det[j] > 0.0 or (s00 > 0.0 and minor > 0.0 and determinant > 0.0):
                continue  # inverted, or positive definite by its leading minors: no negative part
            if _negative_part(s00, s01, s02, s11, s12, s22, part, small, values, vectors):
                v = volume[offset + start + j]
                for jj in range(3):
                    for ll in range(3):
                        entry = part[_SYMMETRIC[jj, ll]] * v
                        for i in range(3):
                            t[9 * (3 * i + jj) + 3 * i + ll, j] += entry
    for j in range(n):
        trace = 0.0
        for r in range(9):
            trace += t[10 * r, j]
        shift[j] = 1e-12 * abs(trace)
        good[j] = 1
    for col in range(9):  # Cholesky, lane by lane in step
        for j in range(n):
            total[j] = t[10 * col, j] + shift[j]
        for q in range(col):
            for j in range(n):
                total[j] -= lower[9 * col + q, j] * lower[9 * col + q, j]
        for j in range(n):
            if not total[j] > 0.0:
                good[j] = 0
            pivot[j] = np.sqrt(total[j])
            lower[10 * col, j] = pivot[j]
        for i in range(col + 1, 9):
            for j in range(n):
                total[j] = 0.5 * (t[9 * i + col, j] + t[9 * col + i, j])
            for q in range(col):
                for j in range(n):
                    total[j] -= lower[9 * i + q, j] * lower[9 * col + q, j]
            for j in range(n):
                lower[9 * i + col, j] = total[j] / pivot[j]
    clamped = 0
    for j in range(n):
        if det[j] > 0.0 and good[j] == 0:
            m = offset + start + j
            for r in range(9):
                for q in range(9):
                    square[r, q] = t[9 * r + q, j]
            _congruence(root, m, square, w)  # w = S t S
            for r in range(9):  # symmetrise against rounding before the decomposition
                for q in range(r):
                    mean = 0.5 * (w[r, q] + w[q, r])
                    w[r, q] = mean
                    w[q, r] = mean
            eigenvalues, eigenvectors = np.linalg.eigh(w)
            for r in range(9):
                for q in range(9):
                    entry = 0.0
                    for e in range(9):
                        if eigenvalues[e] > 0.0:
                            entry += eigenvalues[e] * eigenvectors[r, e] * eigenvectors[q, e]
                    w[r, q] = entry
            _congruence(root_inverse, m, w, square)  # t = S^-1 w_+ S^-1
            for r in range(9):
                for q in range(9):
                    t[9 * r + q, j] = square[r, q]
            clamped += 1
    return clamped


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT)
def stress_correction_range(positions, elements, offset, gradient, volume, mu, lam, spring_vector, spring_length,
                            spring_stiffness, linear, root, root_inverse, clamp, with_tangent, forces, tangent, indptr,
                            cell_nodes, entry_gradient):
    """The correction of the elements ``elements`` (n, M_local) (node indices into ``positions``),
    or, where ``indptr`` has rows, of the cells (smoothing domains) in compressed rows ``indptr``
    (D_local + 1,), ``cell_nodes`` (nnz,), ``entry_gradient`` (nnz, 3) 1/m (``_cell_deformation``),
    whose per-element (per-cell) rows start at ``offset``: forces (N, 3) N += their nodal forces and, with
    ``with_tangent``, tangent[offset + e] (9, 9) N m = their stiffness on F (``_block_tangent``), with
    ``clamp`` the implicit step's SPD treatment (``_block_clamp``). The per-element arrays are
    element-last (``stress_correction.stress_lanes``): gradient (n, 3, M) b_a in 1/m, volume (M,)
    m^3, mu, lam (M,) Pa, spring_vector (S_e, 3, M) m, spring_length and spring_stiffness (S_e, M)
    m and N/m; root, root_inverse (M, 3, 3) (``StressCorrection.metric_root``). An inverted element
    (det F <= 0) gives NaN forces, which the solvers' inversion checks reject. Returns the number of
    elements whose positive part was taken."""
    f = np.empty((9, LANES))
    c = np.empty((9, LANES))
    p = np.empty((9, LANES))
    det = np.empty(LANES)
    log_j = np.empty(LANES)
    inverse_volume = np.empty(LANES)
    t = np.empty((81, LANES))
    lower = np.empty((81, LANES))
    row = np.empty((12, LANES))
    products = np.empty((54, LANES))
    g = np.empty((6, LANES))
    sym = np.empty((6, LANES))
    scalars = np.empty((3, LANES))
    shift = np.empty(LANES)
    total = np.empty(LANES)
    pivot = np.empty(LANES)
    good = np.empty(LANES, dtype=np.int64)
    part = np.empty(6)
    small = np.empty((3, 3))
    values = np.empty(3)
    vectors = np.empty((3, 3))
    square = np.empty((9, 9))
    w = np.empty((9, 9))
    clamped = 0
    cells = indptr.shape[0] > 0
    n_elements = indptr.shape[0] - 1 if cells else elements.shape[1]
    for start in range(0, n_elements, LANES):
        n = min(LANES, n_elements - start)
        if cells:
            _cell_deformation(positions, indptr, cell_nodes, entry_gradient, start, n, f)
        else:
            _block_deformation(positions, elements, offset, start, n, gradient, f)
        _block_law(offset, start, n, volume, mu, lam, spring_vector, spring_length, spring_stiffness, linear, f, c, p,
                   det, log_j, inverse_volume)
        if cells:
            _cell_scatter(indptr, cell_nodes, entry_gradient, offset, start, n, volume, p, forces)
        else:
            _block_scatter(elements, offset, start, n, gradient, volume, p, forces)
        if with_tangent:
            _block_tangent(offset, start, n, volume, mu, lam, spring_vector, spring_length, spring_stiffness, linear,
                           f, c, det, log_j, t, products, row, g, scalars)
            if clamp:
                clamped += _block_clamp(offset, start, n, volume, root, root_inverse, linear, det, c, p, t, lower, sym,
                                        shift, total, pivot, good, part, small, values, vectors, square, w)
            for j in range(n):
                m = offset + start + j
                for r in range(9):
                    for q in range(9):
                        tangent[m, r, q] = t[9 * r + q, j]
    return clamped


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT)
def stress_correction_add(positions, elements, gradient, volume, mu, lam, spring_vector, spring_length,
                          spring_stiffness, linear, indptr, cell_nodes, entry_gradient, forces):
    """forces (N, 3) N += every element's (cell's) stress correction (``stress_correction_range``'s
    arrays, ``elements`` (n, M) the element nodes, element-last, or the cells' compressed rows
    ``indptr``, ``cell_nodes``, ``entry_gradient``; ``linear`` the law: False neo-Hookean, True
    small-strain Hooke, ``stress_correction.StressCorrection``)."""
    stress_correction_range(positions, elements, np.int64(0), gradient, volume, mu, lam, spring_vector, spring_length,
                            spring_stiffness, linear, np.empty((0, 3, 3)), np.empty((0, 3, 3)), np.bool_(False),
                            np.bool_(False), forces,
                            np.empty((0, 9, 9)), indptr, cell_nodes, entry_gradient)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT)
def stress_correction_tangent_add(positions, elements, gradient, volume, mu, lam, spring_vector, spring_length,
                                  spring_stiffness, linear, indptr, cell_nodes, entry_gradient, root, root_inverse,
                                  clamp, forces, tangent):
    """``stress_correction_add`` that also writes each element's (cell's) stiffness on F, tangent
    (M, 9, 9) N/m * m^2 = V0 (A_NH - A_S), with ``clamp`` the implicit step's SPD treatment (the
    negative part of its geometric term dropped, and its positive part in the element's displacement
    metric where that is not enough; docs/physics.md section 11). Returns the number of elements
    whose positive part was taken."""
    return stress_correction_range(positions, elements, np.int64(0), gradient, volume, mu, lam, spring_vector,
                                   spring_length, spring_stiffness, linear, root, root_inverse, clamp, np.bool_(True),
                                   forces, tangent, indptr,
                                   cell_nodes, entry_gradient)


@njit(cache=True, error_model="numpy", fastmath=FAST_EXACT, parallel=True)
def stress_correction_add_copies(count, positions, elements, gradient, volume, mu, lam, spring_vector, spring_length,
                                 spring_stiffness, linear, indptr, cell_nodes, entry_gradient, forces):
    """``stress_correction_add`` of a stacked model of ``count`` copies (copies first), one copy per numba
    thread at a time: ``elements`` (n, M_copy) (or the cells' ``indptr`` and ``cell_nodes``) are ONE
    copy's (local node indices), every other array the stacked model's (``entry_gradient`` too:
    each copy's nnz rows in turn). The copies are disjoint, so each writes only its own nodes, in
    the stacked pass's order: the same floats as ``stress_correction_add`` on the stacked model."""
    n = positions.shape[0] // count
    n_elements = indptr.shape[0] - 1 if indptr.shape[0] > 0 else elements.shape[1]
    nnz = indptr[-1] if indptr.shape[0] > 0 else 0
    empty_root = np.empty((0, 3, 3))
    empty_tangent = np.empty((0, 9, 9))
    for copy in prange(count):
        stress_correction_range(positions[copy * n:(copy + 1) * n], elements, copy * n_elements, gradient, volume, mu,
                                lam, spring_vector, spring_length, spring_stiffness, linear, empty_root, empty_root,
                                np.bool_(False), np.bool_(False), forces[copy * n:(copy + 1) * n], empty_tangent,
                                indptr, cell_nodes,
                                entry_gradient[copy * nnz:(copy + 1) * nnz])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _stress_tangent_copy(copy, count, positions, elements, gradient, volume, mu, lam, spring_vector, spring_length,
                         spring_stiffness, linear, indptr, cell_nodes, entry_gradient, root, root_inverse, clamp,
                         forces, tangent):
    """Copy ``copy``'s pass of ``stress_correction_tangent_add_copies``; returns its clamped
    elements."""
    n = positions.shape[0] // count
    n_elements = indptr.shape[0] - 1 if indptr.shape[0] > 0 else elements.shape[1]
    nnz = indptr[-1] if indptr.shape[0] > 0 else 0
    return stress_correction_range(
        positions[copy * n:(copy + 1) * n], elements, copy * n_elements, gradient, volume, mu, lam, spring_vector,
        spring_length, spring_stiffness, linear, root, root_inverse, clamp, np.bool_(True),
        forces[copy * n:(copy + 1) * n],
        tangent, indptr, cell_nodes, entry_gradient[copy * nnz:(copy + 1) * nnz])


@njit(cache=True, error_model="numpy", fastmath=FAST_EXACT, parallel=True)
def stress_correction_tangent_add_copies(count, active, positions, elements, gradient, volume, mu, lam, spring_vector,
                                         spring_length, spring_stiffness, linear, indptr, cell_nodes, entry_gradient,
                                         root, root_inverse, clamp, forces, tangent):
    """``stress_correction_tangent_add`` of the copies ``active`` (count,) bool, one per numba
    thread at a time (``stress_correction_add_copies``' layout; the same floats as the stacked
    pass; the other copies' forces and tangents are left as they are)."""
    clamped = np.zeros(count, dtype=np.int64)
    for copy in prange(count):
        if active[copy]:
            clamped[copy] = _stress_tangent_copy(copy, count, positions, elements, gradient, volume, mu, lam,
                                                 spring_vector, spring_length, spring_stiffness, linear, indptr,
                                                 cell_nodes, entry_gradient, root, root_inverse, clamp, forces, tangent)
    return clamped.sum()


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT)
def stress_correction_tangent_add_copies_serial(count, active, positions, elements, gradient, volume, mu, lam,
                                                spring_vector, spring_length, spring_stiffness, linear, indptr,
                                                cell_nodes, entry_gradient, root, root_inverse, clamp, forces,
                                                tangent):
    """``stress_correction_tangent_add_copies`` in this thread only."""
    clamped = 0
    for copy in range(count):
        if active[copy]:
            clamped += _stress_tangent_copy(copy, count, positions, elements, gradient, volume, mu, lam, spring_vector,
                                            spring_length, spring_stiffness, linear, indptr, cell_nodes,
                                            entry_gradient, root, root_inverse, clamp, forces, tangent)
    return clamped
