"""Krylov solves of the implicit step for N copies (N = 1: one world): each copy on its own
(``solve_copies_lu``), preconditioned by its sparse factor or by Jacobi (the inverse diagonal,
``jacobi_copies``), or the copies that share a factor in lockstep (``solve_copies_grouped``), on
numba's threads or in this one (the ``_serial`` twins).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fastmath import FAST
from .operator import apply_blocks, apply_copy, copy_data, stress_diagonal_add
from .factor import correct_masked, corrected_lu_apply, lu_columns


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _dot(a, b):
    """a . b of two (n,) vectors."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _dot_and_square(a, b):
    """(a . b, b . b) of two (n,) vectors in one pass."""
    ab = 0.0
    bb = 0.0
    for i in range(a.shape[0]):
        ab += a[i] * b[i]
        bb += b[i] * b[i]
    return ab, bb


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _direction(p, r, v, beta, omega):
    """BiCGSTAB's search direction: p = r + beta (p - omega v)."""
    for i in range(p.shape[0]):
        p[i] = r[i] + beta * (p[i] - omega * v[i])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _half_step(r, v, s, alpha):
    """s = r - alpha v; returns s . s."""
    ss = 0.0
    for i in range(s.shape[0]):
        s[i] = r[i] - alpha * v[i]
        ss += s[i] * s[i]
    return ss


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _stop_at_half(x, r, s, p_hat, alpha):
    """The solve converged at the half step: x += alpha p_hat, r = s."""
    for i in range(x.shape[0]):
        x[i] += alpha * p_hat[i]
        r[i] = s[i]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST, inline="always")
def _full_step(x, r, s, t, p_hat, s_hat, alpha, omega):
    """x += alpha p_hat + omega s_hat, r = s - omega t; returns r . r."""
    rr = 0.0
    for i in range(x.shape[0]):
        x[i] += alpha * p_hat[i] + omega * s_hat[i]
        r[i] = s[i] - omega * t[i]
        rr += r[i] * r[i]
    return rr


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
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
    data = copy_data(stacked, hg_rows, hg_group, c)
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
    apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, blocks, m, x, v)
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
        _direction(p, r, v, beta, omega)
        corrected_lu_apply(ints, values, m, ones, correction, held, gathered, p, p_hat, buffer)
        apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, blocks, m, p_hat, v)
        denominator = _dot(r_hat, v)
        if not (np.isfinite(denominator) and denominator != 0.0):
            break
        alpha = rho / denominator
        ss = _half_step(r, v, s, alpha)
        count += 1
        if np.sqrt(ss) / norm_b <= tolerance:
            _stop_at_half(x, r, s, p_hat, alpha)
            res = np.sqrt(ss) / norm_b
            break
        corrected_lu_apply(ints, values, m, ones, correction, held, gathered, s, s_hat, buffer)
        apply_blocks(data, scales, ones, hg_block_indptr, hg_block_indices, blocks, m, s_hat, t)
        ts, tt = _dot_and_square(s, t)
        omega = ts / tt if tt > 0.0 else 0.0
        rr = _full_step(x, r, s, t, p_hat, s_hat, alpha, omega)
        res = np.sqrt(rr) / norm_b
        if not np.isfinite(res):
            break
    iterations[c] = count
    residual[c] = res


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def solve_copies_lu(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                    lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                    hg_block_indptr, hg_block_indices, hg_block_rows):
    """Each ``active`` copy's right-preconditioned BiCGSTAB (stopping
    test ||r|| <= tolerance ||b||), the copies shared among numba's threads, each with its own
    scratch (no lockstep: a copy costs its own iterations; ``work`` (8, 3 n) serves a single copy),
    preconditioned by its sparse LU ``factor_of[c]`` restricted to its free dofs
    ``mask[c]``, with the capacitance correction ``corrections[c]`` (3 n, k) for the dofs
    ``imposed[c]`` (k,) that are free in the factor but imposed now (``corrected_lu_apply``; k = 0:
    the factor masked, ``lu_apply``), and stopped after ``limits[c]`` iterations. ``stacked``:
    ``apply_operator``'s data of the N-copy stacked model (copies first: copy c's springs, elements
    and nodes are the c-th equal slices; topology arrays springs, elements, edge_spring, hg_indptr,
    hg_indices of ONE copy), its hourglass values per copy group ``hg_rows`` (G, nnz) and
    ``hg_group`` (N,). Vectors (N, 3 n). Writes solution (NaN rows for a
    non-finite right-hand side), iterations and residual (N,). The operator products read the
    hourglass matrix in node blocks (``apply_blocks``): ``hg_block_indptr``, ``hg_block_indices``
    and each group's block values ``hg_block_rows`` (G, 9 nb) (``hg_rows`` is the CSR form of the
    same matrices)."""
    n_copies, dofs = rhs.shape
    ones = np.ones(dofs)
    for copy in prange(n_copies):  # the copies on all of numba's threads, each with its own scratch
        own = work if n_copies == 1 else np.empty((8, dofs))
        _solve_copy(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int, lu_float,
                    factor_of, corrections, imposed, own, solution, iterations, residual, hg_block_indptr,
                    hg_block_indices, hg_block_rows, ones, np.int64(copy))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def inverse_diagonal(data, scales, mask, out):
    """out (3 n,) = mask / diag(A), the Jacobi preconditioner of the implicit system A = M + dt D +
    dt^2 K of the ``OperatorData`` ``data`` with ``scales``: the diagonal of the mass, the springs'
    (axial stiffness and damping, clamped geometric term), the stress correction's element blocks
    and the hourglass matrix; 0 where it is not positive (an imposed or degenerate dof)."""
    (springs, unit, stiffness, damping, geometric, mass, elements, _, _, _, _, _, _, hg_indptr, hg_indices, hg_data,
     _, _, stress_indptr, stress_nodes, stress_gradient, stress_tangent, _) = data
    mass_scale, damping_scale, stiffness_scale, hg_scale = scales[0], scales[1], scales[2], scales[5]
    for node in range(mass.shape[0]):
        for c in range(3):
            out[3 * node + c] = mass_scale * mass[node]
    for k in range(springs.shape[0]):
        a, b = springs[k, 0], springs[k, 1]
        across = stiffness_scale * geometric[k]
        along = stiffness_scale * stiffness[k] + damping_scale * damping[k] - across
        for c in range(3):
            value = along * unit[k, c] * unit[k, c] + across
            out[3 * a + c] += value
            out[3 * b + c] += value
    if stress_tangent.shape[0] != 0:  # the stress correction's element blocks (baudet-hyperelastic)
        stress_diagonal_add(stress_indptr, stress_nodes, stress_gradient, stress_tangent, stiffness_scale, out)
    for row in range(out.shape[0]):
        value = out[row]
        if value > 0.0:
            if hg_scale != 0.0:
                for k in range(hg_indptr[row], hg_indptr[row + 1]):
                    if hg_indices[k] == row:
                        value += hg_scale * hg_data[k]
            out[row] = mask[row] / value
        else:
            out[row] = 0.0


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def jacobi_copies(stacked, scales, hg_rows, hg_group, mask, active, out):
    """out[c] (N, 3 n) = ``inverse_diagonal`` of each ``active`` copy c's system (its data from
    ``copy_data``; ``solve_copies_lu``'s arguments), the copies shared among numba's threads."""
    for c in prange(out.shape[0]):
        if active[c]:
            inverse_diagonal(copy_data(stacked, hg_rows, hg_group, c), scales, mask[c], out[c])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def jacobi_copies_serial(stacked, scales, hg_rows, hg_group, mask, active, out):
    """``jacobi_copies`` in this thread only."""
    for c in range(out.shape[0]):
        if active[c]:
            inverse_diagonal(copy_data(stacked, hg_rows, hg_group, c), scales, mask[c], out[c])


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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def _precondition_rows(vector, out, running, first, lu_int, lu_float, factor_of, corrections, imposed, mask,
                       columns, buffer, accumulator, gathered, pending):
    """out[c] = mask[c] * (y - corrections[c] @ y[imposed[c]]) with y = A_g^-1 vector[c] for every
    copy c = first + i with ``running[i]`` (``corrected_lu_apply``'s result, other rows untouched):
    the copies of a factor g = ``factor_of[c]`` are solved together (``lu_columns``: one pass over
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
            lu_columns(lu_int[g], lu_float[g], vector.T, out.T, columns, np.int64(used), buffer, accumulator)
    for i in range(size):
        if running[i]:
            c = first + i
            correct_masked(out[c], corrections[c], imposed[c], gathered, mask[c])


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def _apply_rows(stacked, scales, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows, ones, mask,
                vector, out, running, first, columns, accumulator, pending):
    """out[c] = mask[c] * A_c vector[c] (``apply_copy``) for every copy c = first + i with
    ``running[i]``: the spring, coupling and volume terms per copy (``scales`` without the hourglass
    term), the hourglass term for all the running copies of a group at once
    (``bsr3_matvec_add_rows``: one pass over the group's node-block matrix, the larger part of an
    operator product's time per copy)."""
    size = running.shape[0]
    springs_only = (scales[0], scales[1], scales[2], scales[3], scales[4], 0.0 * scales[5])
    for i in range(size):
        pending[i] = running[i]
        if running[i]:
            c = first + i
            apply_copy(stacked, springs_only, hg_rows, hg_group, hg_block_indptr, hg_block_indices, hg_block_rows,
                        ones, ones, vector[c], out[c], c)
    if scales[5] != 0.0:
        for i in range(size):
            if pending[i]:
                g = hg_group[first + i]
                used = _take_group(hg_group, pending, first, i, columns)
                bsr3_matvec_add_rows(hg_block_indptr, hg_block_indices, hg_block_rows[g], vector, scales[5], out,
                                     columns, np.int64(used), accumulator)
    for i in range(size):
        if running[i]:
            c = first + i
            row = out[c]
            m = mask[c]
            for j in range(row.shape[0]):
                row[j] *= m[j]


@njit(cache=True, nogil=True, inline="always")
def _scratch_sizes(lu_int, factor_of, imposed, first, last):
    """(the largest factor's dofs, the most dofs a correction holds) of the copies first ... last - 1:
    the sizes of a lockstep chunk's substitution and correction scratch."""
    largest = 1
    held = 0
    for c in range(first, last):
        largest = max(largest, abs(lu_int[factor_of[c]][0]))
        held = max(held, imposed[c].shape[0])
    return largest, held


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def _solve_lockstep(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int, lu_float,
                    factor_of, corrections, imposed, work, solution, iterations, residual, hg_block_indptr,
                    hg_block_indices, hg_block_rows, ones, first, last):
    """``solve_copies_grouped``'s solve of the copies first ... last - 1: ``_solve_copy``'s BiCGSTAB
    (the same scaled guess, updates and stopping tests) in lockstep, each copy with its own scalars
    and iteration count (a copy that stops is left out of every later pass, so it costs its own
    iterations), the preconditioner applied to all the running copies of a factor at once
    (``_precondition_rows``). ``work`` (8, N, 3 n): rows first ... last - 1 used."""
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
    largest, held = _scratch_sizes(lu_int, factor_of, imposed, first, last)
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
            _direction(p[c], r[c], v[c], beta, omega[i])
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
            ss = _half_step(r[c], v[c], s[c], alpha[i])
            iterations[c] += 1
            if np.sqrt(ss) / norm_b[i] <= tolerance:
                _stop_at_half(solution[c], r[c], s[c], p_hat[c], alpha[i])
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
            rr = _full_step(solution[c], r[c], s[c], t[c], p_hat[c], s_hat[c], alpha[i], omega[i])
            res[i] = np.sqrt(rr) / norm_b[i]
            if not (np.isfinite(res[i]) and res[i] > tolerance and iterations[c] < limits[c]):
                running[i] = False
    for i in range(size):
        c = first + i
        if active[c] and norm_b[i] > 0.0:
            residual[c] = res[i]


@njit(cache=True, error_model="numpy", fastmath=FAST, parallel=True)
def solve_copies_grouped(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                         lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                         hg_block_indptr, hg_block_indices, hg_block_rows, chunk):
    """``solve_copies_lu`` (its arguments, results and stopping rule) for copies that share their
    factors (``factor_of``): the copies in contiguous chunks of ``chunk``, shared among numba's
    threads, each chunk solved in lockstep (``_solve_lockstep``): every step of the substitutions
    reads a shared factor once for all the chunk's running copies of it instead of once per copy
    (many copies' substitutions cost little more than one copy's). The chunks
    depend on the copy count only, so any thread count gives the same floats. ``work`` (8, N, 3 n)."""
    n_copies, dofs = rhs.shape
    ones = np.ones(dofs)
    chunk = max(1, chunk)
    for first in prange((n_copies + chunk - 1) // chunk):
        _solve_lockstep(stacked, scales, hg_rows, hg_group, mask, rhs, guess, active, tolerance, limits, lu_int,
                        lu_float, factor_of, corrections, imposed, work, solution, iterations, residual,
                        hg_block_indptr, hg_block_indices, hg_block_rows, ones, np.int64(first * chunk),
                        np.int64(min(n_copies, (first + 1) * chunk)))  # int64 as in the serial version


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
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
