"""The solvers' shared contract.

Every solver has one verb, ``solver.step(state_in, state_out, control, dt, active=None)``: it
advances the worlds of its model by ``dt`` seconds under ``control`` (imposed positions, external
forces) from ``state_in`` into ``state_out`` and returns a ``StepReport`` of what it did and whether
a world diverged; ``reset(world_mask)`` starts worlds again and ``model_changed(index)`` follows a
changed model. A solver of one world (``OneWorldSolver``: ``sim_core.solvers.static.QuasiStatic``, and
the integrators' one-world case; ``bind`` gives it its model) steps (n, 3) states; a solver of N worlds
(``WorldsSolver``: ``sim_core.solvers.implicit.ImplicitEuler``, ``sim_core.solvers.integrators.SymplecticEuler``;
``sim_core.solvers.worlds.PerWorld``) steps the (N, n, 3) states of a ``ModelStack`` with ``active`` an
(N,) world mask, and reports per world. Both
run the same divergence checks (``DivergenceMonitors``, of which ``DivergenceMonitor`` is the
one-world case). ``sim_core.make_solver`` builds either. Here also: the time step check and the
imposed components of a control. SI units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import kernels
from ..models.elements import corner_frames, inversion_gradients
from ..models.model import Control, Model, State
from ..models.stack import ModelStack


@dataclass
class StepReport:
    """What one ``step`` did. One world: ``iterations`` of the linear solver (0 for explicit), its
    relative ``residual`` and ``unstable_reason`` (None while the run is healthy). N worlds: the same
    fields per world, ``iterations`` (N,) int, ``residual`` (N,) float and ``unstable_reason`` (N,)
    object (None where the world is healthy, and for the worlds the step left alone); ``unstable``
    is then an (N,) bool array."""

    iterations: int | np.ndarray = 0
    residual: float | np.ndarray = 0.0
    unstable_reason: str | None | np.ndarray = None

    @property
    def unstable(self):
        """bool (one world) or (N,) bool: the worlds that diverged in this step."""
        if isinstance(self.unstable_reason, np.ndarray):
            return np.array([reason is not None for reason in self.unstable_reason], dtype=bool)
        return self.unstable_reason is not None


class OneWorldSolver:
    """The ``step`` verb of a solver of one world, on top of its ``simulate(model, state_in,
    state_out, dt, control)``: ``bind(model)`` (or ``make_integrator(name, model=model)``) gives the
    solver the model it steps."""

    model: Model | None = None

    def bind(self, model: Model):
        """Step ``model`` from now on (returns the solver)."""
        if not isinstance(model, Model):
            raise ValueError(f"bind takes a sim_core Model (build_model), got {type(model).__name__}")
        self.model = model
        return self

    def reset(self, world_mask=None):
        """Start a new episode (``world_mask`` None or True; False leaves it as it is): the
        divergence history, warm starts and kept factors start again, as with a fresh solver."""
        if world_mask is None or bool(np.all(world_mask)):
            model = self.model
            self.__dict__.update(type(self)(**self._options()).__dict__)
            self.model = model  # what the user set

    def model_changed(self, index: int = 0, model: Model | None = None):
        """The world's model changed: step ``model`` from now on (None: the bound one), from a fresh
        history (``reset``). ``index`` must be 0 (one world)."""
        if int(index) != 0:
            raise ValueError(f"a solver of one world has world 0 only, got index {index}")
        self.reset()
        if model is not None:
            self.bind(model)

    def step(self, state_in: State, state_out: State, control: Control | None, dt: float, active=None) -> StepReport:
        """Advance the bound model's world by ``dt`` s from ``state_in`` into ``state_out`` under
        ``control`` (None: nothing imposed). ``active``: None or True steps it; False copies
        ``state_in`` into ``state_out`` and advances the clock (the one-world case of a world mask)."""
        if self.model is None:
            raise ValueError("this solver has no model: bind one first (solver.bind(model), or "
                             "make_solver(method, model))")
        if active is not None and not bool(np.all(active)):
            dt = check_dt(dt)
            state_out.positions, state_out.velocities = state_in.positions.copy(), state_in.velocities.copy()
            state_out.time = state_in.time + dt
            return StepReport()
        return self.simulate(self.model, state_in, state_out, dt, control)


def check_world_mask(mask, count: int) -> np.ndarray:
    """``mask`` as an (count,) bool world mask (None: every world), or ValueError."""
    mask = np.ones(count, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if mask.shape != (count,):
        raise ValueError(f"a world mask must be None or an ({count},) bool array, got shape {mask.shape}")
    return mask


def check_shapes(state: State, control: Control, shape: tuple, meaning: str):
    """ValueError unless the state's positions and velocities and the control's fixed and target
    arrays all have ``shape`` (``meaning`` names its axes in the message)."""
    for name, array in (("positions", state.positions), ("velocities", state.velocities),
                        ("control.fixed", control.fixed), ("control.target", control.target)):
        if np.shape(array) != shape:
            raise ValueError(f"{name} must have shape {shape} {meaning}, got {np.shape(array)}")


def check_dt(dt) -> float:
    """``dt`` as a float, or ValueError unless it is a finite time step > 0 s."""
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a finite time step > 0 s, got {dt}")
    return dt


def impose_control(control: Control, state_in: State, positions: np.ndarray, velocities: np.ndarray, dt: float):
    """Move imposed components to their targets, with the velocity that gets them there in dt."""
    fixed = control.fixed
    if np.any(fixed):
        velocities[fixed] = (control.target[fixed] - state_in.positions[fixed]) / dt
        positions[fixed] = control.target[fixed]


_LEFT_REGION = "a node left the region of 10 block sizes around the rest mesh"
_INVERTED = "inverted element (non-positive corner Jacobian)"
_COLLAPSED = "inverted element (non-positive determinant of its mean deformation gradient)"


def _too_fast(speed: float, max_speed: float) -> str:
    return f"node speed {speed:.3g} m/s exceeds {max_speed:.3g} m/s (100x the elastic wave speed)"


def _oscillation(steps: int) -> str:
    return f"growing step-to-step oscillation for {steps} steps (the time step is beyond the stability limit)"


class DivergenceMonitor:
    """Detects a diverging simulation and says why.

    Checks (cheap ones every step, element inversion every ``inversion_every`` steps):
    non-finite positions or velocities; a node faster than ``speed_factor`` times the fastest
    elastic wave speed sqrt(E / rho) (no tissue motion a tool imposes comes near it); a node
    farther than ``extent_factor`` block sizes from the rest mesh; an inverted element (a corner
    Jacobian <= 0, or for a model whose elements' energy is a function of their mean deformation
    gradient, that gradient's determinant <= 0: ``models.elements.inversion_gradients``); a
    growing step-to-step oscillation: the velocity field reverses (cosine with the previous
    step's below -0.5) and grows, for ``oscillation_steps`` consecutive checks, with
    an RMS node speed above ``oscillation_floor`` times the wave speed. That is the signature of
    a time step beyond the explicit stability limit (the highest mode flips sign every step); it
    catches a run at the very edge of the limit while its amplitude is still small, long before the
    speed check would (docs/performance_notes.md, "Divergence checks").
    The checks assume consecutive states of one trajectory (one monitor per trajectory).
    """

    def __init__(self, model: Model, speed_factor: float = 100.0, extent_factor: float = 10.0,
                 inversion_every: int = 10, oscillation_steps: int = 20, oscillation_floor: float = 1e-4):
        self.model = model
        #: one copy of the batched monitor: the checks are written once, for both
        self._copies = DivergenceMonitors(1, model.n_nodes, model.mesh.elements)
        self._copies.assign(0, model, speed_factor=speed_factor, extent_factor=extent_factor,
                            inversion_every=inversion_every, oscillation_steps=oscillation_steps,
                            oscillation_floor=oscillation_floor)

    @property
    def count(self) -> int:
        """The checks made so far."""
        return int(self._copies.checks[0])

    def check(self, state: State, force_inversion_check: bool = False) -> str | None:
        """The reason the state ``state`` (the next of this trajectory's) diverges, or None."""
        positions, velocities = np.asarray(state.positions), np.asarray(state.velocities)
        return self._copies.check(positions[None], velocities[None], _ONE, force_inversion_check)[0]


#: the rows argument of a one-copy ``DivergenceMonitors.check``
_ONE = np.ones(1, dtype=bool)


class DivergenceMonitors:
    """``DivergenceMonitor``'s checks for the N copies of a batched simulation (``tissue_env.vector``;
    ``DivergenceMonitor`` is its one-copy case): the same thresholds and messages per copy, one
    compiled pass over all copies per check (``kernels.health_copies``). ``assign`` a copy's model
    (with its reset: the copy's history starts again), then ``check`` consecutive states."""

    def __init__(self, count: int, n_nodes: int, elements: np.ndarray, threads: int = 1):
        self.count = int(count)
        #: the copies on numba's threads when ``kernels.threaded(threads)``
        self.threads = int(threads)
        self.elements = np.ascontiguousarray(elements, dtype=np.int64)
        self.frames = corner_frames(self.elements)  # the inversion check's corner frames
        #: per copy, whether its inversion test is on the mean deformation gradients ``gradients[c]``
        #: (M, n, 3) 1/m rather than the corners (an (N, 0, n, 3) array while no copy needs them)
        self.mean_test = np.zeros(count, dtype=bool)
        self.gradients = np.zeros((count, 0) + self.elements.shape[1:] + (3,))
        self.max_speed = np.zeros(count)
        #: an oscillation counts above this RMS node speed, m/s (oscillation_floor x the wave speed)
        self.floor_speed = np.zeros(count)
        self.low = np.zeros((count, 3))
        self.high = np.zeros((count, 3))
        self.checks = np.zeros(count, dtype=np.int64)
        self.growing = np.zeros(count, dtype=np.int64)
        self.previous = np.zeros((count, n_nodes, 3))
        self.has_previous = np.zeros(count, dtype=bool)
        self.inversion_every = np.ones(count, dtype=np.int64)
        self.oscillation_steps = np.zeros(count, dtype=np.int64)

    def assign(self, index: int, model: Model, speed_factor: float = 100.0, extent_factor: float = 10.0,
               inversion_every: int = 10, oscillation_steps: int = 20, oscillation_floor: float = 1e-4):
        """Copy ``index`` now simulates ``model``, from a fresh history (``DivergenceMonitor``'s
        keywords)."""
        if model.mesh.elements.shape != self.elements.shape or model.n_nodes != self.previous.shape[1]:
            raise ValueError(f"copy {index}'s model has {model.n_nodes} nodes and {len(model.mesh.elements)} "
                             f"elements; the copies share {self.previous.shape[1]} and {len(self.elements)}")
        wave_speed = float(np.sqrt(np.max(model.young_modulus / model.density)))
        self.max_speed[index] = speed_factor * wave_speed
        self.floor_speed[index] = float(oscillation_floor) * wave_speed
        rest = model.rest_positions
        size = float(np.max(rest.max(axis=0) - rest.min(axis=0)))
        self.low[index] = rest.min(axis=0) - extent_factor * size
        self.high[index] = rest.max(axis=0) + extent_factor * size
        self.inversion_every[index] = max(int(inversion_every), 1)
        gradients = inversion_gradients(model)
        self.mean_test[index] = gradients is not None
        if gradients is not None:
            if self.gradients.shape[1] != len(self.elements):
                self.gradients = np.zeros((self.count,) + self.elements.shape + (3,))
            self.gradients[index] = gradients
        self.oscillation_steps[index] = int(oscillation_steps)
        self.checks[index] = self.growing[index] = 0
        self.has_previous[index] = False

    def check(self, positions: np.ndarray, velocities: np.ndarray, rows: np.ndarray,
              force_inversion_check: bool = False) -> np.ndarray:
        """``DivergenceMonitor.check`` of every copy in ``rows`` (N,) bool for the new positions (m) and
        velocities (m/s) (N, n, 3): (N,) object array of reasons, None where healthy (and for the
        other copies, whose history is left as it is)."""
        rows = np.asarray(rows, dtype=bool)
        positions = np.ascontiguousarray(positions, dtype=float)
        velocities = np.ascontiguousarray(velocities, dtype=float)
        if positions.shape != self.previous.shape or velocities.shape != self.previous.shape:
            raise ValueError(f"positions and velocities must have shape {self.previous.shape}, got "
                             f"{positions.shape} and {velocities.shape}")
        self.checks += rows
        due = rows & ((self.checks % self.inversion_every == 0) | force_inversion_check)
        status = np.empty(self.count, dtype=np.int64)
        speed = np.zeros(self.count)
        kernel = kernels.variant(kernels.health_copies, self.threads)
        kernel(positions, velocities, rows, self.low, self.high, self.max_speed, self.floor_speed,
               self.oscillation_steps, self.previous, self.has_previous, self.growing, due, *self.frames,
               self.elements, self.gradients, self.mean_test, status, speed)
        reasons = np.full(self.count, None, dtype=object)
        for index in np.flatnonzero(status):
            kind = status[index]
            reasons[index] = ("non-finite positions or velocities" if kind == 1
                              else _too_fast(speed[index], self.max_speed[index]) if kind == 2
                              else _LEFT_REGION if kind == 3
                              else _INVERTED if kind == 4
                              else _COLLAPSED if kind == 6
                              else _oscillation(self.oscillation_steps[index]))
        return reasons


class WorldsSolver(OneWorldSolver):
    """The solver contract (``sim_core.solvers.solver``) for the N worlds of a ``ModelStack``:
    ``step(state_in, state_out, control, dt, active)`` with states and controls of shape (N, n, 3)
    and ``active`` an (N,) world mask, which returns a ``StepReport`` of per-world arrays whose
    divergence reasons come from the worlds' ``DivergenceMonitors``. A world starts an episode
    (``prepare``, or ``reset(world_mask)``: then at its next step, from the state and control it
    gets) and is told when its model changed (``model_changed(index)``; a changed model is also
    noticed at the next step). A world whose model has another topology than the stack's block
    (``ModelStack.shared`` False: a cut) is stepped on its own model by a solver of the same class
    and options on a stack of that one world. A subclass provides ``advance(positions, velocities,
    fixed, target, dt, active, force)`` -> (positions, velocities), new (N, n, 3) arrays in which
    the inactive worlds keep their state, and ``_options`` (the keywords that rebuild it).

    One world is the case N = 1: built on a ``Model`` (or on nothing, then ``bind(model)``) instead
    of a ``ModelStack``, the solver steps (n, 3) states and controls and reports scalars
    (``step``, and ``simulate(model, state_in, state_out, dt, control)`` with the model named at
    the call), each model through a solver of its class and options on a one-world stack of it."""

    stack: ModelStack | None = None

    def _one_world(self, target) -> bool:
        """Whether ``target`` (a ``ModelStack``, a ``Model`` or None) makes this a solver of one
        world; if so, set it up (bound to ``target`` when it is a model)."""
        if isinstance(target, ModelStack):
            return False
        if target is not None and not isinstance(target, Model):
            raise ValueError(f"a solver steps a sim_core Model (one world) or a ModelStack (N worlds), "
                             f"got {type(target).__name__}")
        self.model = target
        #: one world: the solver of each model stepped so far, on a one-world stack of it
        self._worlds = {}
        return True

    @property
    def one_world(self) -> bool:
        """Whether this solver steps one world ((n, 3) states) rather than a ``ModelStack``."""
        return self.stack is None

    def bind(self, model: Model):
        """One world: step ``model`` from now on (returns the solver)."""
        if not self.one_world:
            raise ValueError("bind is for a solver of one world; this one steps a ModelStack")
        return super().bind(model)

    def _single_options(self):
        """The options of a solver of one world's stack: one thread (the threads share copies, and
        there is one)."""
        options = self._options()
        if "threads" in options:
            options["threads"] = 1
        return options

    def world(self, model: Model):
        """One world: the N = 1 solver that steps ``model`` (made at its first step, kept: its
        warm start, factors and divergence history are the episode's)."""
        solver = self._worlds.get(model)
        if solver is None:
            if len(self._worlds) >= 8:  # a study that steps many models keeps the last few
                self._worlds.pop(next(iter(self._worlds)))
            solver = self._worlds[model] = type(self)(ModelStack(model, 1), **self._single_options())
        return solver

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float,
                 control: Control | None = None) -> StepReport:
        """One world: advance ``model``'s world by ``dt`` s from ``state_in`` into ``state_out``
        ((n, 3) arrays, m and m/s) under ``control`` (None: nothing imposed); a ``StepReport`` of
        scalars."""
        if not self.one_world:
            raise ValueError("simulate(model, ...) is for a solver of one world; step the ModelStack instead")
        control = model.new_control() if control is None else control
        check_shapes(state_in, control, (model.n_nodes, 3), "(nodes, 3)")
        force = None if control.force is None else np.asarray(control.force, dtype=float)[None]
        out = State(None, None)
        report = self.world(model).step(
            State(np.asarray(state_in.positions, dtype=float)[None], np.asarray(state_in.velocities, dtype=float)[None],
                  state_in.time),
            out, Control(np.asarray(control.fixed, dtype=bool)[None], np.asarray(control.target, dtype=float)[None],
                         force), dt)
        state_out.positions, state_out.velocities, state_out.time = out.positions[0], out.velocities[0], out.time
        return StepReport(int(report.iterations[0]), float(report.residual[0]), report.unstable_reason[0])

    def _start_worlds(self, stack, threads: int):
        self.stack = stack
        self.monitors = DivergenceMonitors(stack.count, stack.n_nodes, stack.reference.mesh.elements,
                                           threads=threads)
        self.last_iterations = np.zeros(stack.count, dtype=int)
        self.last_residual = np.zeros(stack.count)
        #: the model each world's episode was prepared with (None: prepare at its next step)
        self._prepared = [None] * stack.count
        #: the one-world solvers of the worlds that hold a model of their own topology
        self._own = {}

    def prepare(self, index: int, model: Model, positions: np.ndarray, dt: float, fixed: np.ndarray):
        """World ``index`` starts an episode of ``model`` (the one ``stack.assign`` gave it) at
        ``positions`` (n, 3) m with the imposed components ``fixed`` (n, 3) bool and time step
        ``dt`` s: its divergence history (and the warm start and factors of the implicit solver)
        start again."""
        padded = self.stack.models[index]
        self._prepared[index] = padded
        if not self.stack.shared[index]:
            self.own_solver(index).prepare(0, padded, positions, dt, fixed)
            return
        self._own.pop(index, None)
        self._prepare_shared(index, padded, positions, dt, fixed)

    def own_solver(self, index: int):
        """The one-world solver of world ``index`` when it holds a model of its own topology
        (``ModelStack.shared`` False: a cut world), made for that model if it has none yet (what
        ``prepare`` makes and steps); None for a world of the stack's block."""
        index = int(index)
        if self.stack.shared[index]:
            return None
        padded = self.stack.models[index]
        own = self._own.get(index)
        if own is None or own.stack.models[0] is not padded:
            own = self._own[index] = type(self)(ModelStack(padded, 1), **self._single_options())
        return own

    def own_worlds(self) -> list:
        """The worlds stepped on a model of their own topology now (a snapshot holds their solvers' state)."""
        return [index for index in self._own if not self.stack.shared[index]]

    def _prepare_shared(self, index, model, positions, dt, fixed):
        self.monitors.assign(index, model)

    def reset(self, world_mask=None):
        """The worlds in ``world_mask`` ((N,) bool; None: all) start a new episode at their next
        step, from the state and control it gets. One world: None or True starts it again (its
        divergence history, warm start and factors), as with a fresh solver; False leaves it."""
        if self.one_world:
            return super().reset(world_mask)
        mask = check_world_mask(world_mask, self.stack.count)
        for index in np.flatnonzero(mask):
            self._prepared[index] = None

    def model_changed(self, index: int = 0, model: Model | None = None):
        """World ``index``'s model changed (``stack.assign``: material or topology): it starts again
        at its next step on its new model. One world: ``index`` 0, and ``model`` (None: the bound
        one) is stepped from now on, from a fresh history."""
        if self.one_world:
            return super().model_changed(index, model)
        self._prepared[int(index)] = None

    def world_restored(self, index: int):
        """World ``index``'s per-world state was put back as it was at an earlier step (an env's
        ``set_state``): it goes on from there on its current model, not from a fresh start. Solvers
        with state derived from the per-world state rebuild it here."""
        self._prepared[int(index)] = self.stack.models[int(index)]

    def step(self, state_in: State, state_out: State, control: Control, dt: float, active=None) -> StepReport:
        """Advance the ``active`` worlds (None: all) by ``dt`` s from ``state_in`` into ``state_out``
        under ``control`` (``fixed``, ``target``, ``force`` (N, n, 3): imposed components, their
        positions in m, external nodal forces in N added to gravity). The other worlds keep their
        state. One world: (n, 3) arrays of the bound model, ``control`` None for nothing imposed,
        ``active`` None or True (False copies the state and advances the clock)."""
        if self.one_world:
            return super().step(state_in, state_out, control, dt, active)
        dt = check_dt(dt)
        stack, count = self.stack, self.stack.count
        active = check_world_mask(active, stack.count)
        shape = (count, stack.n_nodes, 3)
        check_shapes(state_in, control, shape, "(worlds, node rows, 3)")
        force = control.force
        if force is not None and np.shape(force) != shape:
            raise ValueError(f"control.force must be None or of shape {shape} in N, got {np.shape(force)}")
        return self._step_checked(state_in, state_out, control, dt, active)

    def _step_checked(self, state_in: State, state_out: State, control: Control, dt: float, active) -> StepReport:
        """``step`` of arguments it checked (``dt`` a float, ``active`` an (N,) bool mask, the shapes): a
        cut world's own solver is stepped through here by the solver that checked them."""
        stack, count, force = self.stack, self.stack.count, control.force
        for index in np.flatnonzero(active):
            if self._prepared[index] is not stack.models[index]:
                self.prepare(index, stack.models[index], np.asarray(state_in.positions[index], dtype=float), dt,
                             np.asarray(control.fixed[index], dtype=bool))
        shared = active & stack.shared
        if shared.any():
            positions, velocities = self.advance(state_in.positions, state_in.velocities, control.fixed,
                                                 control.target, dt, shared, force)
        else:
            positions = np.array(state_in.positions, dtype=float)
            velocities = np.array(state_in.velocities, dtype=float)
            self.last_iterations, self.last_residual = np.zeros(count, dtype=int), np.zeros(count)
        reasons = np.full(count, None, dtype=object)
        if shared.any():  # (a cut world's own solver checks it; no stacked world stepped: nothing to check)
            reasons[shared] = self.monitors.check(positions, velocities, shared)[shared]
        iterations, residual = self.last_iterations.copy(), self.last_residual.copy()
        for index in np.flatnonzero(active & ~stack.shared):
            one = slice(index, index + 1)
            out = State(positions[one], velocities[one])
            report = self._own[index]._step_checked(
                State(state_in.positions[one], state_in.velocities[one], state_in.time), out,
                Control(control.fixed[one], control.target[one], None if force is None else force[one]), dt, _ONE)
            positions[index], velocities[index] = out.positions[0], out.velocities[0]
            iterations[index], residual[index] = report.iterations[0], report.residual[0]
            reasons[index] = report.unstable_reason[0]
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return StepReport(iterations, residual, reasons)
