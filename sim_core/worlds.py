"""Solvers of N worlds, whichever the method: ``make_worlds_solver`` builds the one a scene of N
worlds (a ``ModelStack``) steps with, and ``PerWorld`` makes an N-world solver of N one-world
solvers (a static equilibrium per step has no batched form: each world's Newton solve is its own).

Every solver returned keeps the contract of ``sim_core.solver``: ``prepare`` a world at the start
of its episode, then ``step(state_in, state_out, control, dt, active)`` on (N, n, 3) states and
controls, which returns a ``WorldsReport``. SI units."""

from __future__ import annotations

from typing import Callable

import numpy as np

from .batched import BatchedImplicitEuler, BatchedSymplecticEuler
from .model import Control, Model, State
from .solver import OneWorldSolver, WorldsReport, check_dt
from .stack import ModelStack
from .static import QuasiStatic

#: The methods ``make_worlds_solver`` knows.
METHODS = ("implicit", "explicit", "static")


class PerWorld:
    """An N-world solver made of one one-world solver per world, each built by ``factory()`` at
    its world's ``prepare`` and bound to the world's model: its world's steps are those of the
    one-world solver alone, whatever the other worlds do.

    Args:
        stack: the worlds (``ModelStack``).
        factory: a callable returning a fresh ``OneWorldSolver`` (e.g. ``QuasiStatic``).
    """

    def __init__(self, stack: ModelStack, factory: Callable[[], OneWorldSolver]):
        self.stack = stack
        self.factory = factory
        self.solvers: list[OneWorldSolver | None] = [None] * stack.count

    def prepare(self, index: int, model: Model, positions: np.ndarray, dt: float, fixed: np.ndarray):
        """World ``index`` starts an episode of ``model``: a fresh solver (its kept factors and
        divergence history start again)."""
        self.solvers[index] = self.factory().bind(model)

    def step(self, state_in: State, state_out: State, control: Control, dt: float, active=None) -> WorldsReport:
        """Advance the ``active`` worlds (None: all) by ``dt`` s, each by its own solver; the other
        worlds keep their state. A world whose solver raises is reported unstable ("physics
        error: ...") and keeps its state."""
        dt = check_dt(dt)
        count = self.stack.count
        active = np.ones(count, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        if active.shape != (count,):
            raise ValueError(f"active must be None or an ({count},) bool world mask, got shape {active.shape}")
        positions = np.array(state_in.positions, dtype=float)
        velocities = np.array(state_in.velocities, dtype=float)
        iterations, residual = np.zeros(count, dtype=int), np.zeros(count)
        reasons = np.full(count, None, dtype=object)
        for index in np.flatnonzero(active):
            solver = self.solvers[index]
            if solver is None:
                raise ValueError(f"world {index} was not prepared (prepare(index, model, ...) starts its episode)")
            world = State(positions[index].copy(), velocities[index].copy(), state_in.time)
            out = State(world.positions, world.velocities, world.time)
            force = np.zeros_like(world.positions) if control.force is None else control.force[index]
            try:
                report = solver.step(world, out, Control(control.fixed[index], control.target[index], force), dt)
            except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as error:
                reasons[index] = f"physics error: {error}"
                continue
            positions[index], velocities[index] = out.positions, out.velocities
            iterations[index], residual[index], reasons[index] = report.iterations, report.residual, report.unstable_reason
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return WorldsReport(iterations, residual, reasons)


def make_worlds_solver(method: str, stack: ModelStack, tolerance: float, solver: str = "factorised",
                       amortise: int | None = None, threads: int | None = None):
    """The N-world solver of ``method`` for ``stack``: "implicit" (``BatchedImplicitEuler`` with
    linear solver ``solver``, relative residual ``tolerance``), "explicit"
    (``BatchedSymplecticEuler``) or "static" (``PerWorld`` of ``QuasiStatic``: an equilibrium per
    step, per world)."""
    if method == "implicit":
        return BatchedImplicitEuler(stack, tolerance=tolerance, solver=solver, amortise=amortise, threads=threads)
    if method == "explicit":
        return BatchedSymplecticEuler(stack, threads=1 if threads is None else threads)
    if method == "static":
        return PerWorld(stack, QuasiStatic)
    raise ValueError(f"method must be one of {METHODS}, got {method!r}")
