"""Krylov solves of the implicit step on the matrix-free operator: one model (``solve_springs``,
Jacobi-preconditioned CG or BiCGSTAB) and N copies in lockstep, copy index last (``batched_solve``,
preconditioned by the copies' groups' LUs or by Jacobi).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .fastmath import FAST, FAST_REDUCE
from .operator import apply_packed, batched_apply_packed, stress_diagonal_add
from .factor import lu_columns


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST_REDUCE)
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
    if data[19].shape[0] != 0:  # the stress correction's element blocks (baudet-hyperelastic)
        stress_diagonal_add(data[6], data[18], data[19], stiffness_scale, inverse_diagonal)
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
    apply_packed(data, scales, mask, x, v)
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
            apply_packed(data, scales, mask, p, v)
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
        apply_packed(data, scales, mask, p_hat, v)
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
        apply_packed(data, scales, mask, s_hat, t)
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


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def batched_precondition(lu_int, lu_float, group_of, running, inverse_diagonal, mask, vector, out, columns,
                          buffer, accumulator):
    """out = mask * P_c vector[:, c] per ``running`` copy c (0 for the others): P the inverse of the
    packed sparse LU of the copy's group (``group_of[c]`` >= 0: ``lu_int[g]``, ``lu_float[g]``; a
    node-block factor when ``lu_int[g][0]`` < 0, see ``block_lu_solve``, else ``lu_apply``'s scalar
    layout, k = 0: the identity) or the Jacobi diagonal ``inverse_diagonal`` (``group_of[c]`` < 0).
    The running copies of a group are solved together: each entry of L and U is read once and
    updates a row of all their right-hand sides (contiguous, the copy index last in ``buffer`` (k, N)),
    so a group costs about one pass over its factor (the loop overhead per entry dominates, so a
    pass for many copies costs little more than for one).
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
        lu_columns(lu_int[g], lu_float[g], vector, out, columns, used, buffer, accumulator)
    for i in range(out.shape[0]):
        for c in range(n_copies):
            out[i, c] *= mask[i, c]


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def batched_solve(data, scales, mask, rhs, guess, active, tolerance, max_iterations, lu_int, lu_float, group_of, work,
                  solution, iterations, residual):
    """Right-preconditioned BiCGSTAB (``solve_springs``' algorithm) of every ``active`` copy, in lockstep
    with its own scalars and stopping test ||r|| <= tolerance ||b||: a copy that has converged (or broken
    down) stops changing (and is left out of the preconditioner's passes). Preconditioner per copy: the
    packed sparse LU ``lu_int[g]``, ``lu_float[g]`` of its group g = ``group_of[c]``, or the Jacobi
    diagonal of M + springs (+ hourglass) for g < 0 (``batched_precondition``). Vectors (3 n, N);
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
        if data[20].shape[0] != 0:  # the stress correction's element blocks, copy by copy
            elements, stress_gradient, stress_tangent = data[6], data[19], data[20]
            column = np.zeros(dofs)
            for c in range(n_copies):
                column[:] = 0.0
                stress_diagonal_add(elements, stress_gradient[:, :, :, c], stress_tangent[:, :, :, c], stiffness_scale, column)
                for i in range(dofs):
                    inverse_diagonal[i, c] += column[i]
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
    batched_apply_packed(data, scales, mask, x, v)
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
        batched_precondition(lu_int, lu_float, group_of, running, inverse_diagonal, mask, p, p_hat, columns,
                              buffer, accumulator)
        batched_apply_packed(data, scales, mask, p_hat, v)
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
        batched_precondition(lu_int, lu_float, group_of, running, inverse_diagonal, mask, s, s_hat, columns,
                              buffer, accumulator)
        batched_apply_packed(data, scales, mask, s_hat, t)
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
