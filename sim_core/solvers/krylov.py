"""The Krylov solves of the implicit step with a factorised preconditioner: conjugate gradient
(symmetric systems) or right-preconditioned BiCGSTAB, on the compiled matrix-free operator."""

from __future__ import annotations

import numpy as np

from .. import kernels
from .preconditioners import Factor


def apply_system(data, blocks, scales, mask, vector, out):
    """out = mask * A vector (``kernels.apply_operator``; with ``blocks`` (``hourglass_blocks``) the
    hourglass term in node blocks, ``kernels.apply_operator_blocks``)."""
    if blocks is None:
        kernels.apply_operator(data, scales, mask, vector, out)
    else:
        indptr, indices, values, ones = blocks
        kernels.apply_operator_blocks(data, scales, ones, indptr, indices, values, mask, vector, out)


def krylov_solve(data, scales, mask, rhs, guess, factor: Factor, tolerance, max_iterations, symmetric, x, blocks=None):
    """``kernels.solve_springs``'s CG (symmetric) or right-preconditioned BiCGSTAB, same stopping
    test ||r|| <= tolerance ||b||, with ``factor`` as the preconditioner; a numpy loop around the
    compiled operator product (a few iterations: the loop's overhead is small against the products
    and the triangular solves), its hourglass term in node blocks when ``blocks`` is given
    (``hourglass_blocks``). Writes ``x``; returns (iterations, relative residual)."""
    n = rhs.shape[0]
    v = np.empty(n)
    x[:] = guess * mask
    norm_b = float(np.linalg.norm(rhs))
    if norm_b == 0.0:
        x[:] = 0.0
        return 0, 0.0
    apply_system(data, blocks, scales, mask, x, v)
    # the guess scaled by the factor that minimises ||b - a A x0|| (0: no guess), never a worse start
    # than none (the extrapolated dv is a poor guess after a random action: scaling it saves
    # iterations under random actions and costs nothing under smooth ones)
    b = rhs * mask
    vv = float(v @ v)
    scale = float(b @ v) / vv if vv > 0.0 else 0.0
    scale = scale if np.isfinite(scale) else 0.0
    x *= scale
    v *= scale
    r = b - v
    residual = float(np.linalg.norm(r)) / norm_b
    iterations = 0
    z = np.empty(n)
    if symmetric:
        factor.apply(r, z)
        p = z.copy()
        rz = float(r @ z)
        while residual > tolerance and iterations < max_iterations:
            apply_system(data, blocks, scales, mask, p, v)
            curvature = float(p @ v)
            if curvature <= 0.0:
                break
            alpha = rz / curvature
            x += alpha * p
            r -= alpha * v
            factor.apply(r, z)
            rz_new = float(r @ z)
            p *= rz_new / rz
            p += z
            rz = rz_new
            iterations += 1
            residual = float(np.linalg.norm(r)) / norm_b
        return iterations, residual
    r_hat = r.copy()
    p = np.zeros(n)
    v[:] = 0.0
    p_hat, s_hat, t = np.empty(n), np.empty(n), np.empty(n)
    rho_new = float(r @ r)
    rho = alpha = omega = 1.0
    while residual > tolerance and iterations < max_iterations:
        if rho_new == 0.0 or omega == 0.0:
            break
        beta = (rho_new / rho) * (alpha / omega)
        rho = rho_new
        p -= omega * v
        p *= beta
        p += r
        factor.apply(p, p_hat)
        apply_system(data, blocks, scales, mask, p_hat, v)
        denominator = float(r_hat @ v)
        if denominator == 0.0:
            break
        alpha = rho / denominator
        s = r - alpha * v
        iterations += 1
        if float(np.linalg.norm(s)) / norm_b <= tolerance:
            x += alpha * p_hat
            r = s
            residual = float(np.linalg.norm(r)) / norm_b
            break
        factor.apply(s, s_hat)
        apply_system(data, blocks, scales, mask, s_hat, t)
        tt = float(t @ t)
        omega = float(t @ s) / tt if tt > 0 else 0.0
        x += alpha * p_hat
        x += omega * s_hat
        r = s - omega * t
        residual = float(np.linalg.norm(r)) / norm_b
        rho_new = float(r_hat @ r)
    return iterations, residual
