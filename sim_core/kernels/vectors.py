"""3-vectors as tuples (x, y, z) for the straight-line per-element bodies of the kernels.

Each helper is inlined into its caller's numba IR (``inline="always"``), so its arithmetic is
compiled under the caller's fastmath flags and stays in registers: a body written with them
computes the same operations, in the same order, as the same body written out component by
component.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def row(array, i):
    """Row ``i`` of an (N, 3) array as a 3-tuple."""
    return array[i, 0], array[i, 1], array[i, 2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def add(a, b):
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def sub(a, b):
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def cross(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def norm(a):
    return np.sqrt(dot(a, a))
