"""The solvers' shared contract.

Every solver has one verb, ``solver.step(state_in, state_out, control, dt, active=None)``: it
advances the worlds of its model by ``dt`` seconds under ``control`` (imposed positions, forces)
from ``state_in`` into ``state_out`` and reports what it did and whether a world diverged. A solver
of one world (``sim_core.integrators``' explicit and implicit Euler, ``sim_core.static.QuasiStatic``;
``bind`` gives it its model) returns a ``StepReport``; a solver of N worlds (``sim_core.batched``:
states and controls of shape (N, n, 3), ``active`` an (N,) world mask) a ``WorldsReport``, the same
fields per world. Both run the same divergence checks (``DivergenceMonitors``, of which
``DivergenceMonitor`` is the one-world case). Here also: the time step check and the imposed
components of a control. SI units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .elements import corner_frames
from .model import Control, Model, State


@dataclass
class StepReport:
    """What one ``simulate`` call did: ``iterations`` of the linear solver (0 for explicit),
    its relative ``residual``, and ``unstable_reason`` (None while the run is healthy)."""

    iterations: int = 0
    residual: float = 0.0
    unstable_reason: str | None = None

    @property
    def unstable(self) -> bool:
        return self.unstable_reason is not None


@dataclass
class WorldsReport:
    """What one step of N worlds did, per world: ``iterations`` (N,) of the linear solver,
    ``residual`` (N,) its relative residual and ``unstable_reason`` (N,) object (None where the
    world is healthy, and for the worlds the step left alone)."""

    iterations: np.ndarray
    residual: np.ndarray
    unstable_reason: np.ndarray

    @property
    def unstable(self) -> np.ndarray:
        """(N,) bool: the worlds that diverged in this step."""
        return np.array([reason is not None for reason in self.unstable_reason], dtype=bool)


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

    def step(self, state_in: State, state_out: State, control: Control | None, dt: float, active=None) -> StepReport:
        """Advance the bound model's world by ``dt`` s from ``state_in`` into ``state_out`` under
        ``control`` (None: nothing imposed). ``active``: None or True steps it; False copies
        ``state_in`` into ``state_out`` and advances the clock (the one-world case of a world mask)."""
        if self.model is None:
            raise ValueError("this solver has no model: bind one first (solver.bind(model), or "
                             "make_integrator(name, model=model))")
        if active is not None and not bool(np.all(active)):
            dt = check_dt(dt)
            state_out.positions, state_out.velocities = state_in.positions.copy(), state_in.velocities.copy()
            state_out.time = state_in.time + dt
            return StepReport()
        return self.simulate(self.model, state_in, state_out, dt, control)


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
    Jacobian <= 0); a growing step-to-step oscillation: the velocity field reverses (cosine with
    the previous step's below -0.5) and grows, for ``oscillation_steps`` consecutive checks, with
    an RMS node speed above ``oscillation_floor`` times the wave speed. That is the signature of
    a time step beyond the explicit stability limit (the highest mode flips sign every step); it
    catches a run at the very edge of the limit while its amplitude is still small (measured:
    a 4x4x4 block at 0.9x the estimated limit, 0.997x the measured one, was 12x its static
    displacement after 500 steps before the speed check fired; this check fires at about step 415).
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
               self.elements, status, speed)
        reasons = np.full(self.count, None, dtype=object)
        for index in np.flatnonzero(status):
            kind = status[index]
            reasons[index] = ("non-finite positions or velocities" if kind == 1
                              else _too_fast(speed[index], self.max_speed[index]) if kind == 2
                              else _LEFT_REGION if kind == 3
                              else _INVERTED if kind == 4
                              else _oscillation(self.oscillation_steps[index]))
        return reasons
