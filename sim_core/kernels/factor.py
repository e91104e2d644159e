"""Sparse factors of the implicit step's matrix: node-block LU and LDL^T factorisations, their solves
(one or several right-hand sides, packed SuperLU factors, capacitance-corrected), the factors of
several copies in one call (``factor_copies``), columns of their inverses and the capacitance
corrections built from them.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fastmath import FAST
from .operator import copy_data, operator_matrix_data, operator_matrix_data_blocks


@njit(cache=True, nogil=True, inline="always")
def _triangle_offsets(header, rows, nnz_l, nnz_u):
    """Offsets of the two triangles packed in a factor's ``ints`` after its ``header`` entries:
    L indptr (rows + 1), L indices (nnz_l), U indptr (rows + 1), U indices (nnz_u). Returns
    (L indptr, L indices, U indptr, U indices, the entry after U's indices)."""
    lp = header
    li = lp + rows + 1
    up = li + nnz_l
    ui = up + rows + 1
    return lp, li, up, ui, ui + nnz_u


@njit(cache=True, nogil=True, inline="always")
def _lu_offsets(ints):
    """Offsets in a packed sparse LU's ``ints`` ([k, nnz_L, nnz_U, L indptr (k + 1), L indices,
    U indptr (k + 1), U indices, gather (k), free (k), perm_c (k)], see ``lu_apply``): (nnz_L,
    L indptr, L indices, U indptr, U indices, gather, free, perm_c)."""
    k = ints[0]
    nnz_l = ints[1]
    lp, li, up, ui, gather = _triangle_offsets(3, k, nnz_l, ints[2])
    return nnz_l, lp, li, up, ui, gather, gather + k, gather + 2 * k


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def block_lu_solve(ints, values, vector, out, columns, used, buffer, accumulator):
    """out[:, columns[:used]] = A^-1 vector[:, columns[:used]] through a packed node-block sparse LU
    (``sparse.NodeBlockLU``): P A P^T = L U with P a permutation of whole nodes and L, U
    in block CSR of dense 3 x 3 blocks (L's diagonal block last in its block row, U's first).
    ``ints``: [-k, nb, blocks of L, blocks of U, L indptr (nb + 1), L block columns, U indptr (nb + 1),
    U block columns, order (k): the dof at each position of P], ``values``: [L blocks, U blocks]
    (9 row-major values each). Row-oriented substitutions: a block row accumulates the products
    of its blocks with the solved rows of all right-hand sides (``buffer`` (k, N), the copy index
    last; ``accumulator`` (3, N)), one index per 9 values. A symmetric factor (``ints[2]`` = 0: no
    L) goes through ``block_ldl_solve``."""
    if ints[2] == 0:
        block_ldl_solve(ints, values, vector, out, columns, used, buffer, accumulator)
        return
    k = -ints[0]
    nb = ints[1]
    nnz_l = ints[2]
    lp, li, up, ui, order = _triangle_offsets(4, nb, nnz_l, ints[3])
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
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
    each diagonal slot, D_i^-1 (``block_ldl_solve``'s layout). Returns False when a D_i is
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def block_ldl_solve(ints, values, vector, out, columns, used, buffer, accumulator):
    """``block_lu_solve`` through a packed node-block LDL^T (``block_ldl_factor``): P S P^T = U^T D U.
    ``ints``: [-k, nb, 0, blocks of U, U indptr (nb + 1), U block columns, order (k)], ``values``: U's
    blocks with D_i^-1 in each diagonal slot. U^T z = b by a forward sweep that scatters each solved
    block row into the later rows, then x = U^-1 D^-1 z by a backward sweep: U's blocks are read
    twice, half the values of the LU's two sweeps. The forward sweep starts at the first block row
    where b is not zero (columns of the inverse: unit vectors)."""
    if used == 1:
        block_ldl_solve_one(ints, values, vector[:, columns[0]], out[:, columns[0]], buffer[:, 0])
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def block_ldl_solve_one(ints, values, vector, out, buffer):
    """``block_ldl_solve`` for one right-hand side (n,) (the Krylov solves' case), its running
    values in registers: faster than the loop over columns."""
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def block_lu_apply(ints, values, mask, vector, out, buffer):
    """out = mask * A^-1 vector (n,) through a packed node-block LU: ``block_lu_solve`` with one
    column (a copy specialised for one right-hand side gained too little to keep); the dofs
    the factor does not hold get 0. ``buffer`` (k,) scratch."""
    k = -ints[0]
    columns = np.zeros(1, dtype=np.int64)
    for i in range(out.shape[0]):
        out[i] = 0.0
    block_lu_solve(ints, values, vector.reshape(-1, 1), out.reshape(-1, 1), columns, np.int64(1),
                    buffer[:k].reshape(-1, 1), np.empty((3, 1)))
    for i in range(out.shape[0]):
        out[i] *= mask[i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def lu_columns(ints, values, vector, out, columns, used, buffer, accumulator):
    """out[:, columns[:used]] = A^-1 vector[:, columns[:used]] through one packed sparse LU: a
    node-block factor (``ints[0]`` < 0, ``block_lu_solve``), SuperLU's scalar layout (``ints[0]`` =
    k > 0, ``lu_apply``'s; column sweeps with all right-hand sides at once) or none (k = 0: the
    identity). Each entry of L and U is read once for all the columns. The rows of ``out`` that the
    factor does not hold are left as they are. ``buffer`` (>= |k|, >= used) and ``accumulator`` (3, >= used) scratch."""
    k = ints[0]
    if k < 0:
        block_lu_solve(ints, values, vector, out, columns, used, buffer, accumulator)
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def lu_apply(ints, values, mask, vector, out, buffer):
    """out = mask * A^-1 vector through one packed sparse LU: Pr A Pc = L U on the copy's free dofs
    (SuperLU's convention). ``ints``: [k, nnz_L, nnz_U, L indptr (k + 1), L indices, U indptr (k + 1),
    U indices, gather (k), free (k), perm_c (k)] (CSC, sorted indices: L's diagonal first, U's last in
    each column), ``values``: [L data, U data]; gather[j] = the dof that Pr puts in position j. The
    factor's free dofs may include dofs the mask imposes (a factor of a larger free set: an
    approximate inverse). k = 0: no factor: ``ints`` [0] the identity (out = mask * vector), [0, 1]
    Jacobi with ``values`` the masked inverse diagonal (out = values * vector, ``inverse_diagonal``)."""
    k = ints[0]
    if k == 0:
        if ints.shape[0] > 1:
            for i in range(vector.shape[0]):
                out[i] = values[i] * vector[i]
        else:
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def corrected_lu_apply(ints, values, mask, ones, correction, imposed, gathered, vector, out, buffer):
    """out = mask * (y - correction @ y[imposed]) with y = A^-1 vector (``lu_apply`` without mask):
    a factor of a larger free set F restricted exactly to the free dofs ``mask`` (capacitance
    correction, ``correction`` (3 n, k) = B[:, imposed] (B[imposed, imposed])^-1 with B the
    factor's inverse and ``imposed`` (k,) the dofs of F imposed now; exact for a vector zero on
    them). k = 0: ``lu_apply`` with ``mask``. ``ones`` (3 n,) ones, ``gathered`` (>= k,) scratch."""
    k = imposed.shape[0]
    if k == 0:
        lu_apply(ints, values, mask, vector, out, buffer)
        return
    lu_apply(ints, values, ones, vector, out, buffer)
    correct_masked(out, correction, imposed, gathered, mask)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def correct_masked(out, correction, imposed, gathered, mask):
    """out = mask * (out - correction @ out[imposed]): a capacitance correction (``corrected_lu_apply``)
    on an unmasked solve ``out`` (3 n,); ``gathered`` (>= k,) scratch."""
    k = imposed.shape[0]
    for j in range(k):
        gathered[j] = out[imposed[j]]
    for i in range(out.shape[0]):
        value = out[i]
        for j in range(k):
            value -= correction[i, j] * gathered[j]
        out[i] = mask[i] * value


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
    block_lu_solve(ints, values, rhs, solved, np.arange(count), count, np.empty((k, count)), np.empty((3, count)))
    for i in range(count):
        for j in range(n_dofs):
            out[first + i, j] = solved[j, i]


@njit(cache=True, error_model="numpy", parallel=True)
def inverse_columns_copies(lu_int, lu_float, copies, indptr, dofs, out):
    """Columns of the inverse of several copies' node-block factors (``preconditioners.InverseColumns``,
    the capacitance corrections' columns): task t solves the unit vectors of the dofs
    ``dofs[indptr[t]:indptr[t + 1]]`` together through the factor of copy ``copies[t]``
    (``lu_int[c]``, ``lu_float[c]``: ``block_lu_solve``), into the rows ``out[indptr[t]:indptr[t + 1]]``
    ((total, 3 n), zero where the factor holds no dof). The tasks on numba's threads."""
    for t in prange(copies.shape[0]):
        _inverse_columns_task(lu_int, lu_float, copies, indptr, dofs, out, np.int64(t))


@njit(cache=True, nogil=True, error_model="numpy")
def inverse_columns_copies_serial(lu_int, lu_float, copies, indptr, dofs, out):
    """``inverse_columns_copies`` in this thread only (one thread, a forked process)."""
    for t in range(copies.shape[0]):
        _inverse_columns_task(lu_int, lu_float, copies, indptr, dofs, out, t)


@njit(cache=True, nogil=True, error_model="numpy")
def _factor_copy(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                 diagonal_positions, c, cover, node_dofs, take, rows, columns, a_map, a_indptr, a_indices, l_indptr,
                 l_indices, u_indptr, u_indices, a_transpose, l_to_u, values, a_values, work, out, node_edge,
                 node_sign):
    """``factor_copies``' factorisation of copy ``c`` on its cover ``cover`` (3 n,) into ``out``, with
    ``values``, ``a_values`` and ``work`` its own scratch; False where a pivot is zero or not finite."""
    data = copy_data(stacked, hg_rows, hg_group, c)
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


@njit(cache=True, error_model="numpy", parallel=True)
def factor_copies(stacked, scales, hg_rows, hg_group, spring_positions, element_positions, hg_positions,
                  diagonal_positions, copies, covers, node_dofs, take, rows, columns, a_map, a_indptr, a_indices,
                  l_indptr, l_indices, u_indptr, u_indices, a_transpose, l_to_u, ints, values, a_values, work, lu_int,
                  lu_float, ok, node_edge, node_sign):
    """The node-block LUs of several copies' system matrices in one call, each exactly as
    ``operator_matrix_data`` followed by ``preconditioners.node_block_factor`` (``sparse.NodeBlockLU``,
    ``block_lu_factor``) computes it: for copy c = ``copies[t]`` of the stacked model (``stacked``,
    ``hg_rows``, ``hg_group`` as ``solve_copies_lu`` takes them), the matrix of the operator with
    ``scales`` is assembled on the model's pattern (``values`` (nnz,) scratch), restricted to the
    whole nodes ``node_dofs`` (k,) (``preconditioners.FreeStructure``: ``take``, ``rows``, ``columns``
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
    """Several capacitance corrections W = Z (Z[c])^-1 at once (``preconditioners.InverseColumns.correction``,
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


@njit(cache=True, nogil=True)
def set_list_items(first, second, index, first_value, second_value):
    """``first[index] = first_value`` and ``second[index] = second_value`` on two numba typed Lists,
    compiled once and cached: a typed List's own ``__setitem__`` called from Python is compiled again
    in every process (about 0.4 s at the first factorisation of an env's life)."""
    first[index] = first_value
    second[index] = second_value


@njit(cache=True, nogil=True)
def _add_right_of(k, columns, start, stop, mark, row, count):
    """``symbolic_fill``'s union: append to ``row[:count]`` the ``columns[start:stop]`` right of ``k``
    not yet in it (``mark[j] == k``); returns the new count."""
    for p in range(start, stop):
        j = columns[p]
        if j > k and mark[j] != k:
            mark[j] = k
            row[count] = j
            count += 1
    return count


@njit(cache=True, nogil=True)
def symbolic_fill(indptr, indices, nb):
    """The block fill pattern of a symbolic LU (or Cholesky) factor without pivoting of a structurally
    symmetric matrix of ``nb`` block rows (CSR ``indptr``, ``indices``; the diagonal is taken as
    present): (U indptr (nb + 1,), U indices, each row sorted). U's row k holds A's entries right of
    the diagonal in row k and those of the rows of k's children in the elimination tree (the rows
    whose first off-diagonal entry is k) right of k; L's pattern is its transpose."""
    head = np.full(nb, -1, np.int64)  # each row's first child in the elimination tree, then their siblings
    sibling = np.full(nb, -1, np.int64)
    mark = np.full(nb, -1, np.int64)
    row = np.empty(nb, np.int64)
    u_indptr = np.zeros(nb + 1, np.int64)
    u_indices = np.empty(max(2 * len(indices), nb), np.int64)
    for k in range(nb):
        row[0] = k
        mark[k] = k
        count = _add_right_of(k, indices, indptr[k], indptr[k + 1], mark, row, 1)
        child = head[k]
        while child != -1:
            count = _add_right_of(k, u_indices, u_indptr[child], u_indptr[child + 1], mark, row, count)
            child = sibling[child]
        ordered = np.sort(row[:count])
        start = u_indptr[k]
        if start + count > len(u_indices):
            grown = np.empty(2 * (start + count), np.int64)
            grown[:start] = u_indices[:start]
            u_indices = grown
        u_indices[start:start + count] = ordered
        u_indptr[k + 1] = start + count
        if count > 1:
            parent = ordered[1]
            sibling[k] = head[parent]
            head[parent] = k
    return u_indptr, u_indices[:u_indptr[nb]].copy()


@njit(cache=True, nogil=True)
def _count_entry(c, r, amount, mark, value, columns, size):
    """Row ``r`` of a symmetric union (``ordered_fill``, ``node_graph``): add ``amount`` to its entry
    ``c`` (a new entry joins ``columns[:size]``, marked ``mark[c] == r``); returns the new count."""
    if mark[c] != r:
        mark[c] = r
        value[c] = 0.0
        columns[size] = c
        size += 1
    value[c] += amount
    return size


@njit(cache=True, nogil=True)
def _bucket(keys, items, nb):
    """(indptr (nb + 1,), ``items`` grouped by their ``keys`` in [0, nb), each group in the items'
    order): a stable counting sort, the CSR rows of (key, item) pairs."""
    indptr = np.zeros(nb + 1, np.int64)
    for q in range(len(keys)):
        indptr[keys[q] + 1] += 1
    for r in range(nb):
        indptr[r + 1] += indptr[r]
    grouped = np.empty(len(keys), np.int64)
    fill = indptr[:nb].copy()
    for q in range(len(keys)):
        grouped[fill[keys[q]]] = items[q]
        fill[keys[q]] += 1
    return indptr, grouped


@njit(cache=True, nogil=True)
def ordered_fill(block_row, block_col, nb, node_order):
    """``sparse.block_structure``'s symbolic factor under a node ordering, in one compiled pass: the
    node blocks (``block_row``, ``block_col``) (B,) of a matrix of ``nb`` block rows (distinct),
    permuted by ``node_order`` (the node at each position): (the permuted block pattern's CSR indptr
    and indices (each row sorted), each block's rank in it (B,), the block fill patterns of L (CSC
    by rows ascending: U's transpose) and U (``symbolic_fill`` of the pattern made symmetric), the
    3 x 3 block products of the numeric factorisation: for each block of L off the diagonal, the
    blocks of U's row it multiplies)."""
    count = len(block_row)
    position = np.empty(nb, np.int64)
    for p in range(nb):
        position[node_order[p]] = p
    rows, cols = np.empty(count, np.int64), np.empty(count, np.int64)
    for q in range(count):
        rows[q], cols[q] = position[block_row[q]], position[block_col[q]]
    a_indptr, slot = _bucket(rows, np.arange(count), nb)  # the blocks by permuted row
    t_indptr, t_indices = _bucket(cols, rows, nb)  # the transpose's rows (the permuted columns)
    a_indices = np.empty(count, np.int64)
    rank = np.empty(count, np.int64)
    columns = np.empty(nb, np.int64)
    for r in range(nb):
        low, size = a_indptr[r], a_indptr[r + 1] - a_indptr[r]
        for p in range(size):
            columns[p] = position[block_col[slot[low + p]]]
        order = np.argsort(columns[:size])
        for p in range(size):
            a_indices[low + p] = columns[order[p]]
            rank[slot[low + order[p]]] = low + p
    # the pattern made symmetric: row r holds A's row r and A's column r
    mark = np.full(nb, -1, np.int64)
    value = np.zeros(nb)  # (counts, unused here)
    indptr = np.zeros(nb + 1, np.int64)
    indices = np.empty(2 * count, np.int64)
    for r in range(nb):
        size = 0
        for p in range(a_indptr[r], a_indptr[r + 1]):
            size = _count_entry(a_indices[p], r, 1.0, mark, value, columns, size)
        for p in range(t_indptr[r], t_indptr[r + 1]):
            size = _count_entry(t_indices[p], r, 1.0, mark, value, columns, size)
        indices[indptr[r]:indptr[r] + size] = np.sort(columns[:size])
        indptr[r + 1] = indptr[r] + size
    u_indptr, u_indices = symbolic_fill(indptr, indices[:indptr[nb]], nb)
    u_rows = np.empty(len(u_indices), np.int64)
    for i in range(nb):
        u_rows[u_indptr[i]:u_indptr[i + 1]] = i
    l_indptr, l_indices = _bucket(u_indices, u_rows, nb)  # U's transpose: rows ascending in each column
    products = 0
    for j in range(nb):  # each column's last entry is its diagonal
        for p in range(l_indptr[j], l_indptr[j + 1] - 1):
            i = l_indices[p]
            products += u_indptr[i + 1] - u_indptr[i]
    return a_indptr, a_indices, rank, l_indptr, l_indices, u_indptr, u_indices, products


@njit(cache=True, nogil=True)
def entry_blocks(indptr, indices, nb):
    """The 3 x 3 node blocks of a CSC matrix's stored entries (``indptr``, ``indices``; 3 nb rows and
    columns): (block rows, block columns) (B,) of its distinct blocks sorted by (row, column), and
    the block of each stored entry (nnz,), in storage order."""
    mark = np.full(nb, -1, np.int64)
    local = np.empty(nb, np.int64)
    found_row = np.empty(len(indices), np.int64)  # the blocks as found, column by column
    found_col = np.empty(len(indices), np.int64)
    entry = np.empty(len(indices), np.int64)
    count = 0
    for b in range(nb):
        for column in range(3 * b, 3 * b + 3):
            for p in range(indptr[column], indptr[column + 1]):
                a = indices[p] // 3
                if mark[a] != b:
                    mark[a] = b
                    local[a] = count
                    found_row[count] = a
                    found_col[count] = b
                    count += 1
                entry[p] = local[a]
    order = _bucket(found_row[:count], np.arange(count), nb)[1]  # by row, columns ascending (found so)
    final = np.empty(count, np.int64)
    final[order] = np.arange(count)
    block_row, block_col = found_row[order], found_col[order]
    for p in range(len(indices)):
        entry[p] = final[entry[p]]
    return block_row, block_col, entry


@njit(cache=True, nogil=True)
def entry_positions(indptr, indices, entry_block, rank):
    """(nnz,) the position of each stored entry of a CSC matrix (``indptr``, ``indices``) in its
    node-block factor's block values: 9 rank[block] + 3 (row % 3) + column % 3 (``entry_blocks``'
    block of each entry, ``rank`` each block's place in the permuted pattern)."""
    out = np.empty(len(indices), np.int64)
    for column in range(len(indptr) - 1):
        for p in range(indptr[column], indptr[column + 1]):
            out[p] = 9 * rank[entry_block[p]] + 3 * (indices[p] % 3) + column % 3
    return out


@njit(cache=True, nogil=True)
def node_graph(block_row, block_col, nb):
    """The node graph SuperLU orders (``sparse.block_structure``): G + G^T + nb I of the blocks'
    pattern G (``block_row``, ``block_col`` (B,), distinct, sorted by row then column), in CSC form
    (indptr, indices, data; symmetric, each column sorted): an entry counts its block and its
    transpose, the diagonal adds nb."""
    start, t_indices = _bucket(block_col, block_row, nb)  # the transpose's rows
    indptr = np.zeros(nb + 1, np.int64)
    indices = np.empty(2 * len(block_row) + nb, np.int64)
    data = np.empty(2 * len(block_row) + nb)
    value = np.zeros(nb)
    mark = np.full(nb, -1, np.int64)
    columns = np.empty(nb, np.int64)
    q = 0
    for r in range(nb):
        size = 0
        while q < len(block_row) and block_row[q] == r:
            size = _count_entry(block_col[q], r, 1.0, mark, value, columns, size)
            q += 1
        for p in range(start[r], start[r + 1]):
            size = _count_entry(t_indices[p], r, 1.0, mark, value, columns, size)
        size = _count_entry(r, r, float(nb), mark, value, columns, size)
        ordered = np.sort(columns[:size])
        first = indptr[r]
        for p in range(size):
            indices[first + p] = ordered[p]
            data[first + p] = value[ordered[p]]
        indptr[r + 1] = first + size
    return indptr, indices[:indptr[nb]].copy(), data[:indptr[nb]].copy()
