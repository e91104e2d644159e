"""The solvers by method for one world or N: ``make_solver(method, target)`` with ``target`` a
``Model`` or a ``ModelStack``, and ``PerWorld``, an N-world solver of N one-world solvers (a static
equilibrium per step has no batched form: each world's Newton solve is its own).

Every solver returned keeps the contract of ``sim_core.solvers.solver``: ``step(state_in, state_out,
control, dt, active)`` on (n, 3) or (N, n, 3) states and controls, which returns a ``StepReport``;
``reset(world_mask)`` starts worlds' episodes again, ``model_changed(index)`` after
``ModelStack.assign``. SI units."""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from ..models.model import Control, Model, State
from .integrators import INTEGRATORS, make_integrator
from .solver import OneWorldSolver, StepReport, check_dt, check_world_mask
from ..models.stack import ModelStack
from .static import QuasiStatic

#: The methods ``make_worlds_solver`` knows.
METHODS = ("implicit", "explicit", "static")


class PerWorld:
    """An N-world solver made of one one-world solver per world, each built by ``factory()`` at
    its world's episode start and bound to the world's model: its world's steps are those of the
    one-world solver alone, whatever the other worlds do (a world of its own topology included).

    Args:
        stack: the worlds (``ModelStack``).
        factory: a callable returning a fresh ``OneWorldSolver`` (e.g. ``QuasiStatic``).
    """

    def __init__(self, stack: ModelStack, factory: Callable[[], OneWorldSolver]):
        self.stack = stack
        self.factory = factory
        self.solvers: list[OneWorldSolver | None] = [None] * stack.count

    def prepare(self, index: int, model: Model, positions: np.ndarray, dt: float, fixed: np.ndarray):
        """World ``index`` starts an episode of its model (``stack.assign``'s): a fresh solver (its
        kept factors and divergence history start again)."""
        self.solvers[index] = self.factory().bind(self.stack.given[index])

    def reset(self, world_mask=None):
        """The worlds in ``world_mask`` ((N,) bool; None: all) start a new episode at their next step."""
        for index in np.flatnonzero(check_world_mask(world_mask, self.stack.count)):
            self.solvers[index] = None

    def model_changed(self, index: int):
        """World ``index``'s model changed (``stack.assign``): a fresh solver at its next step."""
        self.solvers[int(index)] = None

    def step(self, state_in: State, state_out: State, control: Control, dt: float, active=None) -> StepReport:
        """Advance the ``active`` worlds (None: all) by ``dt`` s, each by its own solver; the other
        worlds keep their state. A world whose solver raises is reported unstable ("physics
        error: ...") and keeps its state."""
        dt = check_dt(dt)
        count = self.stack.count
        active = check_world_mask(active, count)
        positions = np.array(state_in.positions, dtype=float)
        velocities = np.array(state_in.velocities, dtype=float)
        iterations, residual = np.zeros(count, dtype=int), np.zeros(count)
        reasons = np.full(count, None, dtype=object)
        for index in np.flatnonzero(active):
            solver = self.solvers[index]
            if solver is None or solver.model is not self.stack.given[index]:
                self.prepare(index, self.stack.given[index], positions[index], dt, control.fixed[index])
                solver = self.solvers[index]
            # the world's own nodes: its parked rows (ModelStack.spare_nodes) stay where they are
            nodes = slice(0, solver.model.n_nodes)
            world = State(positions[index, nodes].copy(), velocities[index, nodes].copy(), state_in.time)
            out = State(world.positions, world.velocities, world.time)
            force = np.zeros_like(world.positions) if control.force is None else control.force[index, nodes]
            try:
                report = solver.step(world, out, Control(control.fixed[index, nodes], control.target[index, nodes], force),
                                     dt)
            except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as error:
                reasons[index] = f"physics error: {error}"
                continue
            positions[index, nodes], velocities[index, nodes] = out.positions, out.velocities
            iterations[index], residual[index], reasons[index] = report.iterations, report.residual, report.unstable_reason
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return StepReport(iterations, residual, reasons)


def make_solver(method: str, target: Model | ModelStack, **options):
    """The solver of ``method`` for ``target``, with one verb, ``step(state_in, state_out, control,
    dt, active=None) -> StepReport``, ``reset(world_mask)`` and ``model_changed(index)``.

    Args:
        method: "explicit" (symplectic Euler), "implicit" (linearised implicit Euler) or "static"
            (a static equilibrium per step).
        target: a ``Model`` (one world: states and controls (n, 3)) or a ``ModelStack`` (N worlds:
            (N, n, 3), ``active`` an (N,) world mask; reports per world).
        options: the method's keywords, the same for one world and N. "implicit": those of
            ``ImplicitEuler`` (``tolerance``, ``max_iterations``, ``preconditioner``,
            ``refresh_iterations``, ``amortise``, ``threads``, ``scheme``); "explicit": ``threads``; "static":
            those of ``QuasiStatic`` (``tolerance``, ``max_iterations``, ``max_load_steps``).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if isinstance(target, Model):
        return make_integrator(method, model=target, **options)
    if not isinstance(target, ModelStack):
        raise ValueError(f"target must be a sim_core Model (one world) or a ModelStack (N worlds), "
                         f"got {type(target).__name__}")
    if method in INTEGRATORS:
        return INTEGRATORS[method](target, **options)
    QuasiStatic(**options)  # its keywords checked now, not at the first step
    return PerWorld(target, functools.partial(QuasiStatic, **options))  # a partial pickles, a lambda does not


def make_worlds_solver(method: str, stack: ModelStack, tolerance: float, solver: str = "factorised",
                       amortise: int | None = None, threads: int | None = None, scheme: str = "euler"):
    """The N-world solver of ``method`` for ``stack`` as the vector environments build it
    (``make_solver`` with their keywords): "implicit" with linear solver ``solver``, relative
    residual ``tolerance`` and time scheme ``scheme``, "explicit" or "static"."""
    if method == "implicit":
        return make_solver(method, stack, tolerance=tolerance, preconditioner=solver, amortise=amortise,
                           threads=threads, scheme=scheme)
    if method == "explicit":
        return make_solver(method, stack, threads=1 if threads is None else threads)
    if method == "static":
        return make_solver(method, stack)
    raise ValueError(f"method must be one of {METHODS}, got {method!r}")
