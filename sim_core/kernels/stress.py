"""The finite-strain stress correction of "baudet-hyperelastic" (docs/physics.md section 11): per
element, f_a = -V0 (P_NH(F) - P_S(F)) b_a with F the element's mean deformation gradient, and its
stiffness, the 9 x 9 matrix T = V0 (A_NH(F) - A_S(F)) on the entries of F (the element block is
K_e = B^T T B, B the map from the element's nodal displacements to F), for the implicit step. The
numpy reference is ``sim_core.stress_correction.element_forces`` / ``tangent_blocks``.

One formula for every pass: ``_element_stress`` (F, its cofactor, P_NH - P_S) and
``_element_tangent`` are inlined into the forces-only pass (``stress_correction_add``), the pass that
also fills the tangent (``stress_correction_tangent_add``) and their per-copy threaded versions
(``*_copies``: a stacked model's copies, one per numba thread at a time, the same floats).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fastmath import FAST_EXACT


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _element_stress(positions, elements, mean_gradient, volume, mu, lam, spring_vector, spring_length,
                    spring_stiffness, linear, m, f, c, p):
    """Element ``m`` (of mean_gradient.shape[1] nodes): f (3, 3) = F, c (3, 3) = cof F = det F F^-T,
    p (3, 3) = P_NH(F) - P_S(F) in Pa, or with ``linear`` P_lin(F) - P_S(F), P_lin the small-strain
    Hooke stress lam tr(eps) I + 2 mu eps of eps = sym(F) - I. Returns (det F, ln det F; 0 if linear)."""
    for i in range(3):
        for j in range(3):
            f[i, j] = 0.0
    for a in range(mean_gradient.shape[1]):
        node = elements[m, a]
        for i in range(3):
            x = positions[node, i]
            for j in range(3):
                f[i, j] += x * mean_gradient[m, a, j]
    c[0, 0] = f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]
    c[0, 1] = f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2]
    c[0, 2] = f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]
    c[1, 0] = f[0, 2] * f[2, 1] - f[0, 1] * f[2, 2]
    c[1, 1] = f[0, 0] * f[2, 2] - f[0, 2] * f[2, 0]
    c[1, 2] = f[0, 1] * f[2, 0] - f[0, 0] * f[2, 1]
    c[2, 0] = f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]
    c[2, 1] = f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]
    c[2, 2] = f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]
    det = f[0, 0] * c[0, 0] + f[0, 1] * c[0, 1] + f[0, 2] * c[0, 2]
    if linear:
        log_j = 0.0
        volumetric = lam[m] * (f[0, 0] + f[1, 1] + f[2, 2] - 3.0)
        for i in range(3):
            for j in range(3):
                p[i, j] = mu[m] * (f[i, j] + f[j, i])
            p[i, i] += volumetric - 2.0 * mu[m]
    else:
        log_j = np.log(det)
        inverse_scale = (lam[m] * log_j - mu[m]) / det  # P = mu F + (lam ln J - mu) F^-T
        for i in range(3):
            for j in range(3):
                p[i, j] = mu[m] * f[i, j] + inverse_scale * c[i, j]
    inverse_volume = 1.0 / volume[m]
    for s in range(spring_vector.shape[1]):  # minus the springs' own stress under F
        d0, d1, d2 = spring_vector[m, s, 0], spring_vector[m, s, 1], spring_vector[m, s, 2]
        u0 = f[0, 0] * d0 + f[0, 1] * d1 + f[0, 2] * d2
        u1 = f[1, 0] * d0 + f[1, 1] * d1 + f[1, 2] * d2
        u2 = f[2, 0] * d0 + f[2, 1] * d1 + f[2, 2] * d2
        length = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        t = spring_stiffness[m, s] * (length - spring_length[m, s]) / length * inverse_volume
        p[0, 0] -= t * u0 * d0
        p[0, 1] -= t * u0 * d1
        p[0, 2] -= t * u0 * d2
        p[1, 0] -= t * u1 * d0
        p[1, 1] -= t * u1 * d1
        p[1, 2] -= t * u1 * d2
        p[2, 0] -= t * u2 * d0
        p[2, 1] -= t * u2 * d1
        p[2, 2] -= t * u2 * d2
    return det, log_j


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _scatter_stress(elements, mean_gradient, volume, m, p, forces):
    """forces (N, 3) -= V0 p b_a on the nodes of element ``m``."""
    v = volume[m]
    for a in range(mean_gradient.shape[1]):
        node = elements[m, a]
        b0, b1, b2 = mean_gradient[m, a, 0], mean_gradient[m, a, 1], mean_gradient[m, a, 2]
        for i in range(3):
            forces[node, i] -= v * (p[i, 0] * b0 + p[i, 1] * b1 + p[i, 2] * b2)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _element_tangent(f, c, det, log_j, volume, mu, lam, spring_vector, spring_length, spring_stiffness, linear, m,
                     t, w):
    """t (9, 9) = V0 (A_NH(F) - A_S(F)) of element ``m`` (row 3 i + J: dP_iJ; column 3 k + L: dF_kL),
    with f, c, det, log_j from ``_element_stress``:
    A_NH = mu d_ik d_JL + (mu - lam ln J) G_kJ G_iL + lam G_iJ G_kL (G = F^-T = c / det), or with
    ``linear`` the constant A_lin = lam d_iJ d_kL + mu (d_ik d_JL + d_iL d_kJ), and
    A_S = (1/V0) sum_s k_s [(1 - L_s/l_s) d_ik D_J D_L + (L_s / l_s^3) (F D_s)_i D_J (F D_s)_k D_L].
    w (9, 9) scratch (its first row: the spring's u (x) D)."""
    v = volume[m]
    vmu = v * mu[m]
    if linear:
        for r in range(9):
            for q in range(9):
                t[r, q] = 0.0
        for i in range(3):
            for k in range(3):
                t[4 * i, 4 * k] = v * lam[m]  # d_iJ d_kL: rows and columns of the diagonal of F
                t[3 * i + k, 3 * k + i] += vmu  # d_iL d_kJ
            for jj in range(3):
                t[3 * i + jj, 3 * i + jj] += vmu  # d_ik d_JL
    else:
        inverse_det = 1.0 / det
        coefficient = v * (mu[m] - lam[m] * log_j) * inverse_det * inverse_det
        vlam = v * lam[m] * inverse_det * inverse_det
        for i in range(3):
            for jj in range(3):
                r = 3 * i + jj
                for k in range(3):
                    for ll in range(3):
                        t[r, 3 * k + ll] = coefficient * c[k, jj] * c[i, ll] + vlam * c[i, jj] * c[k, ll]
                t[r, r] += vmu
    g00 = g01 = g02 = g11 = g12 = g22 = 0.0  # sum_s k_s (1 - L_s / l_s) D D^T
    row = w[0]
    for s in range(spring_vector.shape[1]):
        d0, d1, d2 = spring_vector[m, s, 0], spring_vector[m, s, 1], spring_vector[m, s, 2]
        u0 = f[0, 0] * d0 + f[0, 1] * d1 + f[0, 2] * d2
        u1 = f[1, 0] * d0 + f[1, 1] * d1 + f[1, 2] * d2
        u2 = f[2, 0] * d0 + f[2, 1] * d1 + f[2, 2] * d2
        squared = u0 * u0 + u1 * u1 + u2 * u2
        length = np.sqrt(squared)
        ratio = spring_length[m, s] / length
        k = spring_stiffness[m, s]
        across = k * (1.0 - ratio)
        g00 += across * d0 * d0
        g01 += across * d0 * d1
        g02 += across * d0 * d2
        g11 += across * d1 * d1
        g12 += across * d1 * d2
        g22 += across * d2 * d2
        along = k * ratio / squared
        row[0], row[1], row[2] = u0 * d0, u0 * d1, u0 * d2
        row[3], row[4], row[5] = u1 * d0, u1 * d1, u1 * d2
        row[6], row[7], row[8] = u2 * d0, u2 * d1, u2 * d2
        for r in range(9):
            value = along * row[r]
            for q in range(9):
                t[r, q] -= value * row[q]
    for i in range(3):
        b = 3 * i
        t[b, b] -= g00
        t[b, b + 1] -= g01
        t[b, b + 2] -= g02
        t[b + 1, b] -= g01
        t[b + 1, b + 1] -= g11
        t[b + 1, b + 2] -= g12
        t[b + 2, b] -= g02
        t[b + 2, b + 1] -= g12
        t[b + 2, b + 2] -= g22


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
def _positive_definite(t, lower):
    """Whether the symmetric (9, 9) t is positive semi-definite to rounding: the Cholesky
    factorisation of t + 1e-12 tr(t) I (the exact null space of the rotations passes). lower scratch."""
    trace = 0.0
    for r in range(9):
        trace += t[r, r]
    shift = 1e-12 * abs(trace)
    for j in range(9):
        total = t[j, j] + shift
        for q in range(j):
            total -= lower[j, q] * lower[j, q]
        if not total > 0.0:
            return False
        pivot = np.sqrt(total)
        lower[j, j] = pivot
        for i in range(j + 1, 9):
            total = 0.5 * (t[i, j] + t[j, i])
            for q in range(j):
                total -= lower[i, q] * lower[j, q]
            lower[i, j] = total / pivot
    return True


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _congruence(root, m, source, target):
    """target (9, 9) = S source S with S = I_3 (x) root[m] (root[m] symmetric 3 x 3): the change of
    metric of ``_clamp_tangent``, in both directions."""
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
def _clamp_tangent(t, c, det, p, volume, root, root_inverse, linear, m, w, lower, small, values, vectors):
    """The implicit step's SPD treatment of element ``m``'s tangent t (9, 9) (docs/physics.md 11),
    in place; returns 0 (t kept), 1 (geometric term clamped) or 2 (positive part taken).

    1. Its geometric (initial-stress) term V0 d_ik dS_JL, dS = F^-1 (P_NH - P_S) the second
       Piola-Kirchhoff stress the correction adds, loses its negative part, as the springs'
       geometric term t/l does where a spring is compressed: t += V0 I (x) [dS]_-  (|negative
       eigenvalues| of dS). What remains is the material term F F (C_NH - C_S), positive
       semi-definite at rest for nu >= 0 and at moderate strain.
    2. Where that is still not positive semi-definite (``_positive_definite``; a large strain),
       t := its positive part in the metric of the element's nodal displacements (with ``linear``,
       the small-strain law, whose correction has no geometric term, this step only): with
       S = I_3 (x) R, R = (sum_a b_a b_a^T)^(1/2) (``root[m]``; B = S Q with Q's rows orthonormal),
       B^T t B = Q^T (S t S) Q, so the positive part of the 24 x 24 block B^T t B is
       B^T S^-1 (S t S)_+ S^-1 B.
    w, lower (9, 9), small (3, 3), values (3,), vectors (3, 3) scratch."""
    changed = 0
    if not linear:
        changed = _clamp_geometric(t, c, det, p, volume, m, small, values, vectors)
    if _positive_definite(t, lower):
        return changed
    _congruence(root, m, t, w)  # w = S t S
    for r in range(9):  # symmetrise against rounding before the decomposition
        for q in range(r):
            mean = 0.5 * (w[r, q] + w[q, r])
            w[r, q] = mean
            w[q, r] = mean
    eigenvalues, eigenvectors = np.linalg.eigh(w)
    for r in range(9):
        for q in range(9):
            total = 0.0
            for e in range(9):
                if eigenvalues[e] > 0.0:
                    total += eigenvalues[e] * eigenvectors[r, e] * eigenvectors[q, e]
            w[r, q] = total
    _congruence(root_inverse, m, w, t)  # t = S^-1 w_+ S^-1
    return 2


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT, inline="always")
def _clamp_geometric(t, c, det, p, volume, m, small, values, vectors):
    """Step 1 of ``_clamp_tangent``: t += V0 I (x) [dS]_-; returns 1 where it changed t, else 0."""
    inverse_det = 1.0 / det
    for jj in range(3):  # dS = F^-1 p = c^T p / det, symmetrised
        for ll in range(3):
            small[jj, ll] = (c[0, jj] * p[0, ll] + c[1, jj] * p[1, ll] + c[2, jj] * p[2, ll]) * inverse_det
    for jj in range(3):
        for ll in range(jj):
            mean = 0.5 * (small[jj, ll] + small[ll, jj])
            small[jj, ll] = mean
            small[ll, jj] = mean
    _symmetric_eigen3(small, values, vectors)
    changed = 0
    if values[0] < 0.0 or values[1] < 0.0 or values[2] < 0.0:
        changed = 1
        v = volume[m]
        for jj in range(3):
            for ll in range(3):
                total = 0.0
                for e in range(3):
                    if values[e] < 0.0:
                        total -= values[e] * vectors[jj, e] * vectors[ll, e]
                total *= v
                for i in range(3):
                    t[3 * i + jj, 3 * i + ll] += total
    return changed


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT)
def stress_correction_add(positions, elements, mean_gradient, volume, mu, lam, spring_vector, spring_length,
                          spring_stiffness, linear, forces):
    """forces (N, 3) N += every element's stress correction.

    mean_gradient (M, n, 3) 1/m (n nodes per element: 8 hexahedra, 4 tetrahedra), volume (M,) m^3,
    mu and lam (M,) Pa, spring_vector (M, S_e, 3) m, spring_length and spring_stiffness (M, S_e) m
    and N/m, ``linear`` the law (False: neo-Hookean, True: small-strain Hooke;
    ``stress_correction.StressCorrection``).
    An inverted element (det F <= 0) gives NaN forces, which the solvers' inversion checks reject.
    """
    f = np.empty((3, 3))
    c = np.empty((3, 3))
    p = np.empty((3, 3))
    for m in range(elements.shape[0]):
        _element_stress(positions, elements, mean_gradient, volume, mu, lam, spring_vector, spring_length,
                        spring_stiffness, linear, m, f, c, p)
        _scatter_stress(elements, mean_gradient, volume, m, p, forces)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_EXACT)
def stress_correction_tangent_add(positions, elements, mean_gradient, volume, mu, lam, spring_vector, spring_length,
                                  spring_stiffness, linear, root, root_inverse, clamp, forces, tangent):
    """``stress_correction_add`` that also writes each element's stiffness on F, tangent (M, 9, 9)
    N/m * m^2 = V0 (A_NH - A_S) (``_element_tangent``), with ``clamp`` the implicit step's SPD
    treatment (``_clamp_tangent``: the negative part of its geometric term dropped, and its positive
    part in the element's displacement metric where that is not enough; root, root_inverse
    (M, 3, 3) the metric's square root and its inverse, ``StressCorrection.metric_root``;
    docs/physics.md section 11). Returns the number of elements whose positive part was taken."""
    f = np.empty((3, 3))
    c = np.empty((3, 3))
    p = np.empty((3, 3))
    w = np.empty((9, 9))
    lower = np.empty((9, 9))
    small = np.empty((3, 3))
    values = np.empty(3)
    vectors = np.empty((3, 3))
    clamped = 0
    for m in range(elements.shape[0]):
        det, log_j = _element_stress(positions, elements, mean_gradient, volume, mu, lam, spring_vector, spring_length,
                                     spring_stiffness, linear, m, f, c, p)
        _scatter_stress(elements, mean_gradient, volume, m, p, forces)
        t = tangent[m]
        _element_tangent(f, c, det, log_j, volume, mu, lam, spring_vector, spring_length, spring_stiffness, linear, m,
                         t, w)
        if clamp and det > 0.0:
            if _clamp_tangent(t, c, det, p, volume, root, root_inverse, linear, m, w, lower, small, values,
                              vectors) == 2:
                clamped += 1
    return clamped


@njit(cache=True, error_model="numpy", fastmath=FAST_EXACT, parallel=True)
def stress_correction_add_copies(count, positions, elements, mean_gradient, volume, mu, lam, spring_vector,
                                 spring_length, spring_stiffness, linear, forces):
    """``stress_correction_add`` of a stacked model of ``count`` copies (copies first), one copy per numba
    thread at a time: ``elements`` is ONE copy's (local node indices), every other array the stacked
    model's. The copies are disjoint, so each writes only its own nodes, in the stacked pass's
    order: the same floats as ``stress_correction_add`` on the stacked model."""
    n = positions.shape[0] // count
    n_elements = elements.shape[0]
    for c in prange(count):
        e0, e1 = c * n_elements, (c + 1) * n_elements
        stress_correction_add(positions[c * n:(c + 1) * n], elements, mean_gradient[e0:e1], volume[e0:e1], mu[e0:e1],
                              lam[e0:e1], spring_vector[e0:e1], spring_length[e0:e1], spring_stiffness[e0:e1],
                              linear, forces[c * n:(c + 1) * n])


@njit(cache=True, error_model="numpy", fastmath=FAST_EXACT, parallel=True)
def stress_correction_tangent_add_copies(count, positions, elements, mean_gradient, volume, mu, lam, spring_vector,
                                         spring_length, spring_stiffness, linear, root, root_inverse, clamp, forces,
                                         tangent):
    """``stress_correction_tangent_add`` per copy on numba's threads (``stress_correction_add_copies``'
    layout; the same floats as the stacked pass)."""
    n = positions.shape[0] // count
    n_elements = elements.shape[0]
    clamped = np.zeros(count, dtype=np.int64)
    for c in prange(count):
        e0, e1 = c * n_elements, (c + 1) * n_elements
        clamped[c] = stress_correction_tangent_add(
            positions[c * n:(c + 1) * n], elements, mean_gradient[e0:e1], volume[e0:e1], mu[e0:e1], lam[e0:e1],
            spring_vector[e0:e1], spring_length[e0:e1], spring_stiffness[e0:e1], linear, root[e0:e1],
            root_inverse[e0:e1], clamp, forces[c * n:(c + 1) * n], tangent[e0:e1])
    return clamped.sum()
