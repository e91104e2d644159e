"""The integrators' per-dof state updates: the symplectic Euler step, and the batched implicit
step's per-dof glue.

The ``implicit_rows_*`` passes run over (N, 3 n) rows that numpy made one temporary array each: the
same IEEE operations in the same order per element (no fastmath), so the same floats, in one pass,
the rows on numba's threads (the ``_serial`` twins: one thread, a forked process).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fastmath import FAST


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def symplectic_update(positions, velocities, forces, gravity_force, control_force, mass, dt, fixed, target,
                      out_positions, out_velocities):
    """v1 = v0 + dt (f + f_gravity + f_control) / m, x1 = x0 + dt v1; imposed components move to their
    target with the velocity that gets them there in dt (``solver.impose_control``)."""
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
