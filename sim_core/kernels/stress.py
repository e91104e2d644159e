"""The finite-strain stress correction of "baudet-hyperelastic" (docs/physics.md section 11): per
element, f_a = -V0 (P_NH(F) - P_S(F)) b_a with F the element's mean deformation gradient. The numpy
reference is ``sim_core.stress_correction.element_forces``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .fastmath import FAST


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def stress_correction_add(positions, elements, mean_gradient, volume, mu, lam, spring_vector, spring_length,
                          spring_stiffness, forces):
    """forces (N, 3) N += every element's stress correction.

    mean_gradient (M, 8, 3) 1/m, volume (M,) m^3, mu and lam (M,) Pa, spring_vector (M, 16, 3) m,
    spring_length and spring_stiffness (M, 16) m and N/m (``stress_correction.StressCorrection``).
    An inverted element (det F <= 0) gives NaN forces, which the solvers' inversion checks reject.
    """
    f = np.empty((3, 3))
    p = np.empty((3, 3))
    for m in range(elements.shape[0]):
        for i in range(3):
            for j in range(3):
                f[i, j] = 0.0
        for a in range(8):
            node = elements[m, a]
            for i in range(3):
                x = positions[node, i]
                for j in range(3):
                    f[i, j] += x * mean_gradient[m, a, j]
        # cofactor matrix of F: det F F^-T
        c00 = f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]
        c01 = f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2]
        c02 = f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]
        c10 = f[0, 2] * f[2, 1] - f[0, 1] * f[2, 2]
        c11 = f[0, 0] * f[2, 2] - f[0, 2] * f[2, 0]
        c12 = f[0, 1] * f[2, 0] - f[0, 0] * f[2, 1]
        c20 = f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]
        c21 = f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]
        c22 = f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]
        det = f[0, 0] * c00 + f[0, 1] * c01 + f[0, 2] * c02
        log_j = np.log(det)
        inverse_scale = (lam[m] * log_j - mu[m]) / det  # P = mu F + (lam ln J - mu) F^-T
        p[0, 0] = mu[m] * f[0, 0] + inverse_scale * c00
        p[0, 1] = mu[m] * f[0, 1] + inverse_scale * c01
        p[0, 2] = mu[m] * f[0, 2] + inverse_scale * c02
        p[1, 0] = mu[m] * f[1, 0] + inverse_scale * c10
        p[1, 1] = mu[m] * f[1, 1] + inverse_scale * c11
        p[1, 2] = mu[m] * f[1, 2] + inverse_scale * c12
        p[2, 0] = mu[m] * f[2, 0] + inverse_scale * c20
        p[2, 1] = mu[m] * f[2, 1] + inverse_scale * c21
        p[2, 2] = mu[m] * f[2, 2] + inverse_scale * c22
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
        v = volume[m]
        for a in range(8):
            node = elements[m, a]
            b0, b1, b2 = mean_gradient[m, a, 0], mean_gradient[m, a, 1], mean_gradient[m, a, 2]
            for i in range(3):
                forces[node, i] -= v * (p[i, 0] * b0 + p[i, 1] * b1 + p[i, 2] * b2)
