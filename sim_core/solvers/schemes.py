"""The implicit integrator's time schemes (``ImplicitEuler(scheme=...)``), each made of its linearised
implicit Euler solves (``ImplicitEuler.stage``), so that the Newton/Krylov machinery, the
preconditioners and the N-world batching are the same for every scheme (docs/physics.md section 14):

- "euler": one implicit Euler step of dt (numerical damping ratio about omega dt / 2 for a mode of
  omega rad/s).
- "trapezoidal": the trapezoidal rule (implicit midpoint on the linearisation), one Euler solve of
  dt / 2 extrapolated: y1 = 2 y_half - y0. Second order, no numerical damping on a linear system
  at any dt; stiff modes are not damped either (their amplification tends to -1).
- "tr-bdf2": a trapezoidal stage to t + gamma dt and a BDF2 stage to t + dt, gamma = 2 - sqrt(2),
  whose two solves are Euler solves of the same step (1 - 1/sqrt(2)) dt. Second order and
  L-stable: numerical damping ratio below 1e-3 up to omega dt = 0.4 (measured on the damped
  oscillator), stiff modes damped out within a step. Two solves and two force passes per step.

The material's Rayleigh damping enters each solve (``ImplicitEuler.stage``'s ``rayleigh``): worlds
with different damping laws are solved in groups, one per law. Imposed components end the step at
their targets with the mean velocity over the step, (target - x0) / dt, as with "euler" (the
trapezoidal velocity 2 (target - x0) / dt - v0 alternates under a tool that moves in steps). SI units.
"""

from __future__ import annotations

import numpy as np

#: ``ImplicitEuler``'s time schemes; "euler" is the default.
SCHEMES = ("euler", "trapezoidal", "tr-bdf2")
#: TR-BDF2's trapezoidal fraction of the step, for which both stages solve the same system.
TR_BDF2_GAMMA = 2.0 - np.sqrt(2.0)


def check_scheme(scheme) -> str:
    """``scheme`` if it is one of ``SCHEMES``, else ValueError."""
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {SCHEMES}, got {scheme!r}")
    return scheme


def stage_dt(scheme: str, dt: float) -> float:
    """The time step (s) of each implicit Euler solve that a step of ``dt`` s of ``scheme`` makes (the
    step its system matrix M + h D + h^2 K is built for)."""
    if scheme == "trapezoidal":
        return 0.5 * dt
    if scheme == "tr-bdf2":
        return 0.5 * TR_BDF2_GAMMA * dt
    return dt


def damping_groups(stack, active):
    """[((alpha, beta), mask (N,) bool)]: the ``active`` worlds of ``stack`` grouped by their
    material's Rayleigh coefficients (``Model.rayleigh``), one group per law."""
    laws = [stack.models[index].rayleigh for index in range(stack.count)]
    groups = {}
    for index in np.flatnonzero(active):
        groups.setdefault(laws[index], np.zeros(stack.count, dtype=bool))[index] = True
    return list(groups.items())


def damped_stage(solver, positions, velocities, fixed, target, dt, active, force):
    """``solver.stage`` of the ``active`` worlds, each with its own damping law (one call per law);
    ``solver.last_iterations`` and ``last_residual`` hold every world's."""
    groups = damping_groups(solver.stack, active)
    if len(groups) <= 1:
        rayleigh = groups[0][0] if groups else (0.0, 0.0)
        return solver.stage(positions, velocities, fixed, target, dt, active, force, rayleigh)
    new_positions = np.array(positions, dtype=float)
    new_velocities = np.array(velocities, dtype=float)
    iterations = np.zeros(solver.stack.count, dtype=np.int64)
    residual = np.zeros(solver.stack.count)
    for rayleigh, group in groups:
        x, v = solver.stage(positions, velocities, fixed, target, dt, group, force, rayleigh)
        new_positions[group], new_velocities[group] = x[group], v[group]
        iterations[group], residual[group] = solver.last_iterations[group], solver.last_residual[group]
    solver.last_iterations, solver.last_residual = iterations, residual
    return new_positions, new_velocities


def scheme_advance(solver, positions, velocities, fixed, target, dt, active, force):
    """One step of ``dt`` s of ``solver.scheme`` (``ImplicitEuler.advance``'s arguments and result)."""
    scheme = solver.scheme
    if scheme == "euler":
        return damped_stage(solver, positions, velocities, fixed, target, dt, active, force)
    x0 = np.asarray(positions, dtype=float)
    v0 = np.asarray(velocities, dtype=float)
    target = np.asarray(target, dtype=float)
    fixed = np.asarray(fixed, dtype=bool)
    h = stage_dt(scheme, dt)
    # trapezoidal over a fraction g of the step = an Euler solve of g dt / 2, extrapolated
    fraction = 1.0 if scheme == "trapezoidal" else TR_BDF2_GAMMA
    xe, ve = damped_stage(solver, x0, v0, fixed, x0 + 0.5 * fraction * (target - x0), h, active, force)
    x1, v1 = 2.0 * xe - x0, 2.0 * ve - v0
    if scheme == "tr-bdf2":
        iterations, residual = solver.last_iterations.copy(), solver.last_residual.copy()
        v1[fixed] = ve[fixed]  # the imposed components' mean velocity, not the alternating one
        # BDF2 over (t, t + g dt, t + dt): y1 = y* + h F(y1), y* = (y_g - (1 - g)^2 y0) / (g (2 - g)),
        # an Euler solve of h from y*
        scale = 1.0 / (fraction * (2.0 - fraction))
        start_x = scale * x1 - (scale - 1.0) * x0
        start_v = scale * v1 - (scale - 1.0) * v0
        x1, v1 = damped_stage(solver, start_x, start_v, fixed, target, h, active, force)
        solver.last_iterations = solver.last_iterations + iterations
        solver.last_residual = np.maximum(solver.last_residual, residual)
    moving = fixed & active[:, None, None]
    x1[moving] = target[moving]
    v1[moving] = (target[moving] - x0[moving]) / dt
    keep = ~active
    x1[keep], v1[keep] = x0[keep], v0[keep]
    return x1, v1
