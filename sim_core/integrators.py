"""Time integration: symplectic (semi-implicit) Euler, implicit Euler (Baraff and Witkin), the
stable explicit time step, and divergence detection.

Every integrator has one verb, ``simulate(model, state_in, state_out, dt, control) -> StepReport``
(Warp's convention, shared/STYLE.md). A diverging run is reported (``StepReport.unstable_reason``),
never left to produce an unexplained NaN. SI units: s, m, m/s, N.
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import kernels
from .forces import ForceWorkspace, hourglass_blocks, stiffness_data
from .mesh import CORNER_NEIGHBOURS, CORNER_SIGN
from .model import Control, Model, State
from .sparse import NodeBlockLU


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


def _check_dt(dt) -> float:
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a finite time step > 0 s, got {dt}")
    return dt


def _impose(control: Control, state_in: State, positions: np.ndarray, velocities: np.ndarray, dt: float):
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
               self.oscillation_steps, self.previous, self.has_previous, self.growing, due, CORNER_NEIGHBOURS,
               CORNER_SIGN, self.elements, status, speed)
        reasons = np.full(self.count, None, dtype=object)
        for index in np.flatnonzero(status):
            kind = status[index]
            reasons[index] = ("non-finite positions or velocities" if kind == 1
                              else _too_fast(speed[index], self.max_speed[index]) if kind == 2
                              else _LEFT_REGION if kind == 3
                              else _INVERTED if kind == 4
                              else _oscillation(self.oscillation_steps[index]))
        return reasons


class SymplecticEuler:
    """Semi-implicit (symplectic) Euler: v += dt M^-1 f(x, v); x += dt v.

    Stable for dt below ``stable_time_step(model)`` (about 2 / omega_max, less with damping).
    """

    name = "explicit"

    def __init__(self, monitor: bool = True):
        self.monitor = monitor
        self._monitors: dict[int, DivergenceMonitor] = {}
        self._workspaces: dict[int, ForceWorkspace] = {}

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float, control: Control | None = None) -> StepReport:
        dt = _check_dt(dt)
        control = model.new_control() if control is None else control
        x0 = np.ascontiguousarray(state_in.positions, dtype=float)
        v0 = np.ascontiguousarray(state_in.velocities, dtype=float)
        forces = self._workspace(model, implicit=False).compute(x0, v0)  # one fused kernel call
        positions, velocities = np.empty_like(x0), np.empty_like(v0)
        kernels.symplectic_update(x0, v0, forces, model.gravity_force, control.force, model.mass, dt, control.fixed,
                                  control.target, positions, velocities)
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return StepReport(unstable_reason=self._check(model, state_out))

    def _workspace(self, model, implicit):
        """The preallocated arrays of the fused kernels for this model (kept between steps)."""
        workspace = self._workspaces.get(id(model))
        if workspace is None or workspace.model is not model:
            workspace = self._workspaces[id(model)] = ForceWorkspace(model, implicit=implicit)
        return workspace

    def _check(self, model, state):
        if not self.monitor:
            return None
        monitor = self._monitors.get(id(model))
        if monitor is None or monitor.model is not model:
            monitor = self._monitors[id(model)] = DivergenceMonitor(model)
        return monitor.check(state)


class ImplicitEuler(SymplecticEuler):
    """Linearised implicit Euler (Baraff and Witkin 1998), one linear solve per step:

        (M + dt D + dt^2 K) dv = dt (f(x0, v0) - dt K v0),   v1 = v0 + dv,   x1 = x0 + dt v1.

    K holds the springs (geometric term clamped at zero so the matrix is SPD) and the corrections'
    push along the current edges. The corrections' strain coupling is not symmetric (physics.md 3):
    ``corrections="explicit"`` leaves it in f only and solves with Jacobi-preconditioned conjugate
    gradient; ``corrections="implicit"`` adds it, and the volume forces' rank-one stiffness
    (matrix-free), to the system and solves with BiCGSTAB. Measured
    (tests/test_integrators.py): at 10x the explicit limit with nu = 0.45 the explicit-correction
    variant diverges while the implicit one stays bounded at a similar iteration count, so
    "implicit" is the default (with "explicit", volume forces stay explicit too). The matrix keeps
    the model's fixed sparsity pattern; only values change.

    Preconditioner: Jacobi's iteration count grows with resolution, stiffness and dt (TumorPositioning,
    5 cm cube, nu 0.45, volume stiffness x100: 22 iterations at 4^3 elements and dt 20 ms, about 50
    at 7^3 and 40 ms). "factorised" assembles the exact system matrix of the matrix-free operator
    (``kernels.operator_matrix_data``) on the free dofs and factorises it (SuperLU), keeps the factor
    across steps for the same (model, dt, imposed dofs), and re-factorises at the current state when
    a solve needs more than max(8, 2x the iterations right after the last factorisation) or the key
    changes: 1-4 iterations, each two operator products and two triangular solves (measured in
    tests/test_preconditioner.py and benchmarks/results/step_speed.json). "auto" starts
    with Jacobi and switches a key to "factorised" when a Jacobi solve has not converged after
    ``auto_switch_iterations(free dofs)`` iterations (the measured crossing of the two step times;
    that step is solved again with the factor from the same guess, so "auto" steps are exactly
    those of the preconditioner it picked), up to AUTO_MAX_DOFS free dofs. Both stop at the same
    relative residual, so they agree to the solver tolerance.

    Args:
        corrections: "implicit" (default, BiCGSTAB) or "explicit" (CG on the SPD part).
        tolerance: relative residual of the linear solve.
        max_iterations: cap on solver iterations (the report used 15).
        preconditioner: "jacobi" (default), "factorised" or "auto". Not "auto" by default yet: with it
            the envs' single-env trajectories change within the tolerance and get closer to the
            exact ones, which fails tests/test_env_vector.py's Retraction bound (vector env error
            <= 2x the single env's: 15.2 against 2x 1.76).
    """

    name = "implicit"

    def __init__(self, corrections: str = "implicit", tolerance: float = 1e-6, max_iterations: int = 200,
                 monitor: bool = True, preconditioner: str = "jacobi"):
        if corrections not in ("explicit", "implicit"):
            raise ValueError(f"corrections must be 'explicit' or 'implicit', got {corrections!r}")
        if not tolerance > 0:
            raise ValueError(f"tolerance must be > 0, got {tolerance}")
        if int(max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
        if preconditioner not in PRECONDITIONERS:
            raise ValueError(f"preconditioner must be one of {PRECONDITIONERS}, got {preconditioner!r}")
        super().__init__(monitor=monitor)
        self.corrections = corrections
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.preconditioner = preconditioner
        self._warm: np.ndarray | None = None
        self._warm_old: np.ndarray | None = None
        self._warm_converged = False  # the last solve reached the tolerance
        self._factor: _Factor | None = None
        self._auto_factorised: set = set()  # keys "auto" switched to the factorised preconditioner
        #: factorisations done so far (a diagnostic; the tests read it)
        self.factorisations = 0
        #: factorisations taken from ``factor_store`` instead of made (a diagnostic)
        self.factor_reuses = 0
        self.factor_store: FactorStore | None = None
        self._threshold = REFACTOR_MIN  # re-factorise when a solve needs more iterations (_set_baseline)
        self._step_positions = None  # the current step's linearisation positions (for factor_store)
        self._linearised = None  # (model, positions) of the workspace's force pass made by ``linearise``

    def _implicit_volume(self, model: Model) -> bool:
        """Whether the step treats the volume forces implicitly (their rank-one stiffness in the system)."""
        return self.corrections == "implicit" and model.has_volume_forces

    def linearise(self, model: Model, positions: np.ndarray) -> ForceWorkspace:
        """The step's force pass at ``positions`` (N, 3) m: the workspace whose ``forces`` (N, 3) N
        are the internal forces without damping (no gravity, no control force) and whose spring
        lengths, unit vectors, clamped geometric stiffness and volume terms are the implicit
        system's there. The next ``simulate`` of ``model`` from the same positions reuses this pass
        instead of computing it again (an environment measures its state with it: one force pass
        per step instead of two). The arrays are the workspace's: read them before the next step."""
        x0 = np.ascontiguousarray(positions, dtype=float)
        workspace = self._workspace(model, implicit=True)
        if not self._reuses(model, x0):
            workspace.compute(x0, None, geometric=True, volume_jacobian=self._implicit_volume(model))
            self._linearised = (model, x0.copy())
        return workspace

    def _reuses(self, model, x0) -> bool:
        cached = self._linearised
        return cached is not None and cached[0] is model and np.array_equal(cached[1], x0)

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float, control: Control | None = None) -> StepReport:
        dt = _check_dt(dt)
        control = model.new_control() if control is None else control
        x0 = np.ascontiguousarray(state_in.positions, dtype=float)
        v0 = np.ascontiguousarray(state_in.velocities, dtype=float)
        coupled = self.corrections == "implicit" and model.correction_mode is not None
        # Volume forces' rank-one stiffness, with the other non-symmetric terms (BiCGSTAB only).
        implicit_volume = self._implicit_volume(model)
        # one fused pass: the forces without damping, the springs' clamped geometric stiffness, the
        # volume terms (``linearise``'s, when it was made at these positions)
        workspace = self.linearise(model, x0)
        self._step_positions = x0
        forces = workspace.forces
        self._linearised = None  # its forces are changed in place below
        forces += model.gravity_force + control.force
        has_hourglass = model.hourglass is not None
        data = workspace.operator_data
        n = x0.size

        def scales(mass, damping, stiffness):  # (mass, damping, stiffness, coupling, volume, hourglass)
            return (float(mass), float(damping), float(stiffness), stiffness if coupled else 0.0,
                    stiffness if implicit_volume else 0.0, stiffness if has_hourglass else 0.0)

        system = scales(1.0, dt, dt * dt)  # A = M + dt D + dt^2 K
        free = ~control.fixed.ravel()
        known = np.zeros(n)  # dv on the imposed dofs
        moved = v0.reshape(-1).copy()  # v0 + known: v0, and the target velocities on the imposed dofs
        if not free.all():
            target_velocity = ((control.target - x0) / dt).reshape(-1)
            known[~free] = target_velocity[~free] - moved[~free]
            moved[~free] = target_velocity[~free]
        # rhs = dt f(x0, v0) - dt^2 K v0 - A known, with f(x0, v0) = f_0 - D v0 (f_0 without damping),
        # is dt f_0 + M v0 - A (v0 + known): one operator product instead of two.
        product = np.empty(n)
        blocks = hourglass_blocks(model)
        _operator(data, blocks, system, np.ones(n), moved, product)
        rhs = dt * forces.reshape(-1) + _pattern_arrays(model)[4] * v0.reshape(-1) - product
        mask = free.astype(float)
        # Warm start: the last two steps' dv extrapolated linearly (measured on sim_core.bench's sagging
        # block: 6 -> 4 BiCGSTAB iterations, 18% faster; neutral under the envs' random actions), which
        # the factorised solve (_krylov) scales to the least residual before iterating.
        guess = self._warm if self._warm is not None and self._warm.shape == rhs.shape else np.zeros_like(rhs)
        if self._warm_old is not None and self._warm_old.shape == rhs.shape:
            guess = 2.0 * guess - self._warm_old
        dv = np.empty(n)
        symmetric = not (coupled or implicit_volume)
        key = (id(model), dt, _digest(control.fixed), system)
        # "auto" decides per (model, dt, scales): a contact that changes the imposed set from step to
        # step (Palpation's probe, Retraction's floor) leaves the system as stiff as it was
        use_factor = self.preconditioner == "factorised" or (
            self.preconditioner == "auto" and _system_key(key) in self._auto_factorised)
        if not use_factor:
            cap = self.max_iterations
            n_free = int(np.count_nonzero(free))
            if self.preconditioner == "auto" and n_free <= AUTO_MAX_DOFS:
                cap = min(cap, auto_switch_iterations(n_free))
            iterations, residual = kernels.solve_springs(
                data, system, mask, rhs * mask, guess, self.tolerance, cap, symmetric, workspace.work, dv)
            if residual > self.tolerance and cap < self.max_iterations:
                # "auto": Jacobi did not converge within auto_switch_iterations: this system is stiff
                # enough for the factorised preconditioner; solve again with it from the same guess,
                # so that the step is exactly the "factorised" one.
                self._auto_factorised.add(_system_key(key))
                more, residual = self._solve_factorised(model, key, data, system, mask, rhs, guess,
                                                        self.max_iterations - iterations, symmetric, dv, blocks)
                iterations += more
        else:
            iterations, residual = self._solve_factorised(model, key, data, system, mask, rhs, guess,
                                                          self.max_iterations, symmetric, dv, blocks)
        # Extrapolate only from converged solves: a capped solve's (max_iterations below what the
        # system needs) error is amplified by 2 dv_k - dv_(k-1) from step to step (speed_accuracy's
        # 15-iteration BiCGSTAB at 16^3: a 2 mm press read 5.6 mm at dt 50 ms, inverted elements at
        # 20 ms; 2.0 mm with the last dv alone).
        converged = residual <= self.tolerance
        self._warm_old = self._warm if converged and self._warm_converged else None
        self._warm, self._warm_converged = dv, converged
        dv = np.where(free, dv, known)
        velocities = v0 + dv.reshape(-1, 3)
        positions = x0 + dt * velocities
        _impose(control, state_in, positions, velocities, dt)
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return StepReport(int(iterations), float(residual), self._check(model, state_out))

    # -- factorised preconditioner ------------------------------------------------------------------
    def share_factors(self, store: "FactorStore | None"):
        """Look up and keep the factorisations made at ``store.positions`` in ``store`` (None: stop).
        A caller whose steps often start from the same state (an environment's reset) skips those
        factorisations; the steps stay exactly those of a fresh integrator: a kept factor is the
        one this step would make (same model, dt, scales, imposed set and linearisation), and the
        iteration threshold is this integrator's own (tests/test_env_common.py)."""
        self.factor_store = store

    def _solve_factorised(self, model, key, data, system, mask, rhs, guess, max_iterations, symmetric, out,
                          blocks=None):
        """Krylov solve preconditioned by the sparse LU of the system matrix on the free dofs,
        assembled at the state of its last (re-)factorisation; re-factorises (and continues from the
        current iterate) when the solve needs more than ``max(REFACTOR_MIN, 2 x`` the iterations
        right after the last factorisation``)`` or the model, dt or scales changed. When only the
        imposed set changed (a contact that holds other nodes), the factorisation is kept and applied
        restricted to the new free dofs (``_Factor.restricted``: exact on the nodes it holds, Jacobi
        on free dofs it lacks, at most RESTRICTED_MAX_CHANGED of its dofs), under the same iteration
        test."""
        factor = self._factor
        fresh = factor is None or factor.model is not model or _system_key(factor.key) != _system_key(key)
        preconditioner = factor
        if not fresh and factor.key != key:
            preconditioner = factor.restricted(mask)
            fresh = preconditioner.changed > RESTRICTED_MAX_CHANGED * len(factor.structure.free)
        if fresh:
            preconditioner = factor = self._factorise(model, key, data, system, mask)
        limit = max_iterations if fresh else min(max_iterations, self._threshold)
        iterations, residual = _krylov(data, system, mask, rhs * mask, guess, preconditioner, self.tolerance, limit,
                                       symmetric, out, blocks)
        if not fresh and residual > self.tolerance and iterations < max_iterations:
            factor = self._factorise(model, key, data, system, mask)  # at this step's linearisation
            more, residual = _krylov(data, system, mask, rhs * mask, out.copy(), factor, self.tolerance,
                                     max_iterations - iterations, symmetric, out, blocks)
            self._set_baseline(more)
            return iterations + more, residual
        if fresh:
            self._set_baseline(iterations)
        return iterations, residual

    def _set_baseline(self, iterations: int):
        """Re-factorise when a solve needs more than max(REFACTOR_MIN, 2 x ``iterations``), the
        iterations of the solve right after the factorisation."""
        self._threshold = max(REFACTOR_MIN, 2 * int(iterations))

    def _factorise(self, model, key, data, system, mask):
        """The factorisation of the system matrix at the current step's linearisation on the free
        dofs ``mask``; from ``factor_store`` when the step starts at its positions (the same matrix)."""
        store = self.factor_store
        kept = store is not None and store.model is model and np.array_equal(self._step_positions, store.positions)
        factor = store.get(key) if kept else None
        if factor is not None:
            self.factor_reuses += 1
        else:
            structure = free_structure(model, np.flatnonzero(mask))
            values = np.empty(model.pattern.nnz)
            kernels.operator_matrix_data(data, system, model.spring_positions, model.element_positions,
                                         structure.hg_positions, model.pattern.diagonal_positions, values)
            factor = _Factor(model, key, structure, values)
            self.factorisations += 1
            if kept:
                store.put(key, factor)
        self._factor = factor
        return factor


class FactorStore:
    """Factorisations of ``ImplicitEuler``'s factorised preconditioner made at one state
    (``positions`` (N, 3) m) of one ``model``, kept per (dt, scales, imposed set): at most ``size``
    (least recently used dropped). Integrators that share it (``ImplicitEuler.share_factors``; an
    environment's episodes, which all start from the model's start state) factorise that state's
    matrix once per imposed set. Thread-safe; a factor is used by one integrator at a time (its
    preconditioner keeps scratch arrays)."""

    def __init__(self, model: Model, positions: np.ndarray, size: int = 4):
        self.model = model
        self.positions = np.array(positions, dtype=float)
        self.size = int(size)
        self._entries: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            factor = self._entries.get(key)
            if factor is not None:
                self._entries.move_to_end(key)
            return factor

    def put(self, key, factor):
        with self._lock:
            self._entries[key] = factor
            while len(self._entries) > self.size:
                self._entries.popitem(last=False)

    def __len__(self):
        return len(self._entries)

    def __getstate__(self):  # a copy (pickle, deepcopy) starts empty: the factors are a cache
        return dict(model=self.model, positions=self.positions, size=self.size)

    def __setstate__(self, state):
        self.__init__(state["model"], state["positions"], state["size"])


#: ImplicitEuler's preconditioners. "jacobi": the diagonal of the mass, spring and hourglass terms
#: (compiled BiCGSTAB / CG, ``kernels.solve_springs``); "factorised": the sparse LU of the whole system
#: matrix at the state of its last factorisation, kept across steps; "auto": Jacobi, switching a
#: (model, dt, fixed set) to "factorised" once a Jacobi solve needs more than
#: ``auto_switch_iterations(free dofs)``.
PRECONDITIONERS = ("auto", "jacobi", "factorised")


def auto_switch_iterations(n_free: int) -> int:
    """Jacobi iterations above which "auto" switches to the factorised preconditioner: where the
    two step times cross, measured (2 cores, interleaved medians) at about 5 Jacobi iterations for
    ~400 free dofs, 8-13 for ~1200 and 15 for ~3600 (an LU solve costs more, relative to an operator
    product, as the fill grows with the mesh): 5 sqrt(n_free / 400), at least 6."""
    return max(6, int(round(5.0 * np.sqrt(n_free / 400.0))))


#: "auto" stays with Jacobi above this many free dofs (LU fill and memory grow like dofs^(4/3)).
AUTO_MAX_DOFS = 30000
#: A factorisation serves another imposed set (``_Factor.restricted``) when at most this share of its
#: free dofs gets Jacobi: dofs free now on nodes it does not hold (the SuperLU fallback,
#: ``_Restricted``: every dof whose status changed). More, and factorising again is cheaper than the
#: extra iterations. Measured with ``_Restricted`` (env steps per CPU second, random actions):
#: Palpation at 8x4x8 (a probe contact, ~1000 dofs) 174 without reuse, 393 at 1%, 369 without a
#: limit; Retraction at 8x2x4 (the floor, ~360 dofs) 367-382 without reuse, 400 at 1%, 319 without
#: a limit. Imposed dofs on the nodes it holds (a contact's) are corrected exactly (``_Capacitance``).
RESTRICTED_MAX_CHANGED = 0.01
#: Re-factorise when a solve needs more than max(REFACTOR_MIN, 2 x the count right after factorising).
REFACTOR_MIN = 8


def _digest(array) -> bytes:
    return hashlib.blake2b(np.ascontiguousarray(array).view(np.uint8), digest_size=16).digest()


class _FreeStructure:
    """The CSC structure of the system matrix restricted to the free dofs (``free``), with the
    positions of its entries in the model's ``BlockPattern`` data: a factorisation only gathers
    values, nothing is re-sliced. Built from ``_pattern_arrays`` by masks (O(nnz) numpy, once per
    imposed set: a contact makes many)."""

    def __init__(self, model: Model, free: np.ndarray):
        column, rows, transpose, self.hg_positions, _ = _pattern_arrays(model)
        self.model = model
        self.free = free
        mask = np.zeros(model.pattern.n_dofs, bool)
        mask[free] = True
        keep = mask[column] & mask[rows]
        number = np.cumsum(mask) - 1
        self.take = transpose[keep]
        self.indices = number[rows[keep]].astype(np.int32)
        self.indptr = np.zeros(len(free) + 1, np.int32)
        np.cumsum(np.bincount(number[column[keep]], minlength=len(free)), out=self.indptr[1:])
        self.shape = (len(free), len(free))


def _pattern_arrays(model: Model):
    """Per model (cached while it lives): the model's symmetric block pattern read as CSC, column by
    column (column of each entry, its row, the position in the CSR data of the entry (row,
    column)), the pattern positions of the hourglass matrix's entries, and the mass per dof (kg)."""
    cached = _PATTERN_ARRAYS.get(model)
    if cached is None:
        pattern = model.pattern
        column = np.repeat(np.arange(pattern.n_dofs), np.diff(pattern.indptr))  # CSR row c = CSC column c
        rows = pattern.indices.astype(np.int64)
        transpose = pattern.positions(rows, column)  # data position of (row, column): the pattern is symmetric
        hg_indptr, hg_indices, _ = model.hourglass_arrays
        hg_rows = np.repeat(np.arange(len(hg_indptr) - 1), np.diff(hg_indptr))
        hg_positions = pattern.positions(hg_rows, hg_indices) if len(hg_indices) else np.zeros(0, np.int64)
        cached = _PATTERN_ARRAYS[model] = (column, rows, transpose, hg_positions, np.repeat(model.mass, 3))
    return cached


_PATTERN_ARRAYS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


class _Factor:
    """Sparse LU of the system matrix, for the Krylov solves' preconditioner on the free dofs
    (``restricted``: any imposed set). A node-block LU (``sparse.NodeBlockLU``) of the matrix on
    the whole nodes that hold a free dof, the imposed dofs among them decoupled (rows and columns
    zero, diagonal kept: a contact imposes single dofs, Palpation's probe and Retraction's floor
    impose y, x and z stay free), so its inverse on the free dofs is that of the free-dof matrix.
    Restricted to another imposed set it stays exact for the free dofs imposed now, through a
    capacitance correction (``_Capacitance``) whose columns of the inverse are solved at first use per
    factorisation and kept, so a contact that moves onto other nodes keeps the factor and its
    iteration count; dofs free now but imposed at the factorisation get Jacobi. The
    node-block LU's substitutions read one index per 3 x 3 block, 1.9x faster than SuperLU's
    scalar solve at TumorPositioning's 6^3 (0.22 against 0.42 ms), and its numeric factorisation
    (compiled, on a structure kept per node set) 1.4x faster (5.8 against 8.1 ms; 2.6x at
    Retraction's 8x2x4). Where it fails, SuperLU's scalar LU of the free-dof matrix (minimum-degree
    ordering on A + A^T, symmetric mode: the matrix is symmetric up to the corrections' coupling),
    restricted to another imposed set by ``_Restricted``."""

    def __init__(self, model, key, structure: _FreeStructure, values: np.ndarray):
        self.model, self.key, self.structure = model, key, structure
        #: (n_dofs,) the system matrix's diagonal (for the Jacobi part on dofs the factor lacks)
        self.diagonal = values[model.pattern.diagonal_positions]
        self.lu = None
        free = np.zeros(model.pattern.n_dofs, bool)
        free[structure.free] = True
        self._mask = free.astype(float)
        #: (n_dofs,) bool: the dofs the factor holds (its free dofs; the imposed dofs of the whole
        #: nodes it covers are decoupled)
        self.covered = free
        self.block = node_block_factor(model, values, free)
        #: a factorisation's cost in Krylov iterations (``_factorisation_cost``; see CHEAP_FACTOR)
        self.cost = REFACTOR_MIN
        if self.block is not None:
            self.cost = _factorisation_cost(self.block.ints)
            self._buffer = np.empty(-int(self.block.ints[0]))
            #: its inverse's columns and capacitance corrections (``InverseColumns``)
            self.inverse = InverseColumns(self.block.ints, self.block.floats, len(free))
            self._restricted: dict = {}  # imposed-set digest -> _Capacitance
            self._own = self.restricted(self._mask)
            return
        matrix = sp.csc_matrix((values[structure.take], structure.indices, structure.indptr), shape=structure.shape)
        self.lu = spla.splu(matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                            options=dict(SymmetricMode=True))

    def apply(self, vector: np.ndarray, out: np.ndarray):
        """out = P^-1 vector (zero on the imposed dofs) for the factorisation's own imposed set."""
        if self.block is not None:
            return self._own.apply(vector, out)
        free = self.structure.free
        out[:] = 0.0
        out[free] = self.lu.solve(vector[free])
        return out

    def restricted(self, mask: np.ndarray):
        """The preconditioner for the free dofs ``mask`` (n_dofs,) float: exact (capacitance) on
        the covered dofs, Jacobi on the free dofs the factor does not cover. Kept per imposed set."""
        if self.block is None:
            return _Restricted(self, mask)
        digest = _digest(mask)
        preconditioner = self._restricted.get(digest)
        if preconditioner is None:
            if len(self._restricted) >= 8:
                self._restricted.clear()
            preconditioner = self._restricted[digest] = _Capacitance(self, mask)
        return preconditioner


class InverseColumns:
    """Columns of the inverse B of a packed node-block LU (``sparse.NodeBlockLU``'s ``ints``,
    ``floats``) over ``n_dofs`` dofs, kept per dof (at most CAPACITANCE_CACHE) and solved together
    for those not kept yet (``kernels.block_lu_solve``), and the capacitance correction of an
    imposed set built from them. Shared by ``ImplicitEuler``'s factors (``_Capacitance``) and the
    batched vector envs' per-copy factors."""

    def __init__(self, ints, floats, n_dofs: int):
        self.ints, self.floats, self.n_dofs = ints, floats, int(n_dofs)
        self._slot = np.full(self.n_dofs, -1, dtype=np.int64)  # dof -> its row of _rows, -1: not kept
        self._rows = np.empty((0, self.n_dofs))  # the kept columns of B as rows, grown as needed
        self._kept = 0

    def missing(self, dofs) -> np.ndarray:
        """The dofs of ``dofs`` (int64 array) whose columns are not kept (all of them, the kept ones
        forgotten, when keeping them would pass CAPACITANCE_CACHE): what ``columns`` solves, for a
        caller that solves them itself (``store``)."""
        dofs = np.asarray(dofs, dtype=np.int64)
        missing = dofs[self._slot[dofs] < 0]
        if missing.size and self._kept + missing.size > CAPACITANCE_CACHE:
            self._slot[:] = -1
            self._kept = 0
            missing = dofs
        return missing

    def store(self, dofs, columns: np.ndarray):
        """Keep the columns (len(dofs), n_dofs) of B for ``dofs`` (not kept yet), solved by the
        caller."""
        dofs = np.asarray(dofs, dtype=np.int64)
        end = self._kept + len(dofs)
        if end > len(self._rows):
            rows = np.empty((max(end, min(2 * len(self._rows), CAPACITANCE_CACHE), 16), self.n_dofs))
            rows[:self._kept] = self._rows[:self._kept]
            self._rows = rows
        self._rows[self._kept:end] = columns
        self._slot[dofs] = np.arange(self._kept, end)
        self._kept = end

    def columns(self, dofs) -> np.ndarray:
        """(n_dofs, len(dofs)) the columns ``dofs`` of B (zero on the dofs the factor does not
        hold, and on those it decouples), C-contiguous."""
        missing = self.missing(dofs)
        if missing.size:
            count = len(missing)
            rhs = np.zeros((self.n_dofs, count))
            rhs[missing, np.arange(count)] = 1.0
            out = np.zeros((self.n_dofs, count))
            k = -int(self.ints[0])
            kernels.block_lu_solve(self.ints, self.floats, rhs, out, np.arange(count, dtype=np.int64), count,
                                   np.empty((k, count)), np.empty((3, count)))
            self.store(missing, out.T)
        return np.ascontiguousarray(self.rows(dofs).T)

    def rows(self, dofs) -> np.ndarray:
        """(len(dofs), n_dofs) the kept columns ``dofs`` of B as rows (all must be kept: ``missing``)."""
        slots = self._slot[np.asarray(dofs, dtype=np.int64)]
        if np.any(slots < 0):
            raise KeyError(f"columns of dofs {np.asarray(dofs)[slots < 0].tolist()} are not kept: solve them first")
        return self._rows[slots]

    def correction(self, imposed: np.ndarray):
        """W = B[:, c] (B[c, c])^-1 (n_dofs, k) C-contiguous for the dofs c = ``imposed`` (k,), free
        in the factor but imposed now: (B r - W (B r)[c]) restricted to the other free dofs is the
        inverse of the matrix on them applied to r, exactly for r zero on c
        (``kernels.corrected_lu_apply``). None where B[c, c] is singular."""
        z = self.columns(imposed)
        try:
            return kernels.serial_product(z, np.linalg.inv(z[imposed]))
        except np.linalg.LinAlgError:
            return None


def _factorisation_cost(ints) -> float:
    """A node-block LU's factorisation cost in BiCGSTAB iterations (two triangular solves and two
    operator products each), from its structure: the block products of the factorisation,
    sum over block rows of (L blocks x U blocks), against the blocks an iteration's solves read,
    times 0.75. Measured (factorisation with its assembly against an iteration): Retraction 8x2x4
    5, TumorPositioning 6^3 8, Palpation 8x4x8 13.5; this gives 6.0, 12.7, 14.0."""
    nb, n_l, n_u = int(ints[1]), int(ints[2]), int(ints[3])
    l_counts = np.diff(ints[4:5 + nb])
    u_counts = np.diff(ints[5 + nb + n_l:6 + 2 * nb + n_l])
    return 0.75 * float(l_counts @ u_counts) / max(n_l + n_u, 1)


#: A factorisation that costs fewer iterations than this (``_factorisation_cost``) is renewed on a
#: contact change of more than RESTRICTED_MAX_CHANGED of its dofs (Retraction's 8x2x4: 6.0;
#: TumorPositioning's 6^3 12.7 and Palpation's 8x4x8 14.0 keep theirs, corrected exactly)
CHEAP_FACTOR = 10.0
#: Columns of the inverse a factor keeps for its capacitance corrections (``InverseColumns``), and
#: the most dofs one correction handles (more: ``_Capacitance.changed`` asks for a new factor).
CAPACITANCE_CACHE = 512
CAPACITANCE_MAX = 96


class _Capacitance:
    """The node-block factor ``factor`` (the inverse B of the matrix on its free dofs) restricted to
    the free dofs ``mask``: with c its free dofs imposed now, (A_ff)^-1 r = (B r)_f - B_fc
    (B_cc)^-1 (B r)_c exactly for r zero on c (the Krylov vectors are); Jacobi (the factorisation's
    diagonal) on free dofs it does not hold."""

    def __init__(self, factor: _Factor, mask: np.ndarray):
        self.factor, self.mask = factor, mask
        free = mask > 0
        self.imposed = np.flatnonzero(factor.covered & ~free)
        self.extra = np.flatnonzero(free & ~factor.covered)
        self.inverse_diagonal = 1.0 / factor.diagonal[self.extra]
        #: free dofs the factor lacks (Jacobi), and a correction too large to keep: ask for a new
        #: factor. A factorisation cheaper than CHEAP_FACTOR iterations counts every dof whose status
        #: changed, as ``_Restricted`` does: there a fresh factor at the state of a large contact
        #: change beats a kept one the state moved away from (Retraction's flap, 800 random steps:
        #: 5794 operator products with this rule, 10928 keeping its factors)
        self.changed = len(self.extra) + (len(factor.covered) if len(self.imposed) > CAPACITANCE_MAX else 0)
        if factor.cost < CHEAP_FACTOR:
            self.changed = max(self.changed, int(np.count_nonzero(free != factor.covered)))
        # W = B[:, c] (B_cc)^-1, solved at the first application (a set that asks for a new factor
        # never needs it); none (the factor masked, a close preconditioner) where B_cc is singular
        self._pending = 0 < len(self.imposed) <= CAPACITANCE_MAX
        self._correction, self._held = np.zeros((len(mask), 0)), np.zeros(0, dtype=np.int64)
        self._ones, self._gathered = np.ones(len(mask)), np.empty(len(self.imposed))

    def apply(self, vector: np.ndarray, out: np.ndarray):
        factor = self.factor
        if self._pending:
            self._pending = False
            correction = factor.inverse.correction(self.imposed)
            if correction is not None:
                self._correction, self._held = correction, self.imposed
        kernels.corrected_lu_apply(factor.block.ints, factor.block.floats, self.mask, self._ones, self._correction,
                                   self._held, self._gathered, vector, out, factor._buffer)
        if len(self.extra):
            out[self.extra] = vector[self.extra] * self.inverse_diagonal
        return out


def node_block_factor(model: Model, values: np.ndarray, free: np.ndarray, symmetric: bool = False):
    """``NodeBlockLU`` of the system matrix with the model's pattern ``values`` on the whole nodes
    that hold a dof of ``free`` ((3 N,) bool), the imposed dofs among them decoupled (rows and
    columns zero, diagonal kept): its inverse on the free dofs is that of the free-dof matrix,
    and its structure depends only on the node set, so a contact that imposes single dofs keeps
    it (``symmetric``: the LDL^T of the matrix's symmetric part). None where the factorisation
    fails (a zero or non-finite pivot)."""
    node_dofs = np.flatnonzero(np.repeat(free.reshape(-1, 3).any(axis=1), 3))
    if len(node_dofs) == 0:
        return None
    whole = free_structure(model, node_dofs)
    local = free[node_dofs]
    data = values[whole.take]
    data[~((local[whole.indices] & local[whole.columns]) | (whole.indices == whole.columns))] = 0.0
    matrix = sp.csc_matrix((data, whole.indices, whole.indptr), shape=whole.shape)
    try:
        with np.errstate(all="ignore"):
            return NodeBlockLU(matrix, node_dofs, symmetric=symmetric)
    except (RuntimeError, ValueError, np.linalg.LinAlgError):
        return None


def free_structure(model: Model, dofs: np.ndarray) -> _FreeStructure:
    """``_FreeStructure`` of the dofs ``dofs`` (sorted), with each entry's column (``columns``),
    cached per model (a few dof sets each)."""
    cache = _STRUCTURES.setdefault(model, {})
    key = dofs.tobytes()
    structure = cache.get(key)
    if structure is None:
        if len(cache) >= 8:
            cache.clear()
        structure = cache[key] = _FreeStructure(model, dofs)
        structure.columns = np.repeat(np.arange(len(dofs)), np.diff(structure.indptr))
    return structure


_STRUCTURES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


class _Restricted:
    """A factorisation made for another imposed set, used as the preconditioner on this one: its LU
    solve, zeroed on the dofs imposed now, and Jacobi (the diagonal at the factorisation) on the
    dofs free now but imposed then. It differs from the inverse of this set's matrix by a low-rank
    term (rank: the dofs whose status changed), which the Krylov solve absorbs in a few more
    iterations than a re-factorisation would need; a re-factorisation costs more (measured on
    Palpation's probe contact)."""

    def __init__(self, factor: _Factor, mask: np.ndarray):
        self.factor, self.mask = factor, mask
        known = np.zeros(len(mask), bool)
        known[factor.structure.free] = True
        self.extra = np.flatnonzero((mask > 0) & ~known)
        #: dofs whose status (free or imposed) differs from the factorisation's
        self.changed = len(self.extra) + int(np.count_nonzero(known & (mask == 0)))
        self.inverse_diagonal = 1.0 / factor.diagonal[self.extra]

    def apply(self, vector: np.ndarray, out: np.ndarray):
        self.factor.apply(vector, out)
        out *= self.mask
        out[self.extra] = vector[self.extra] * self.inverse_diagonal
        return out


def _system_key(key):
    """(model, dt, scales) of a solve key (model, dt, imposed-set digest, scales)."""
    return key[0], key[1], key[3]


def _operator(data, blocks, scales, mask, vector, out):
    """out = mask * A vector (``kernels.apply_operator``; with ``blocks`` (``hourglass_blocks``) the
    hourglass term in node blocks, ``kernels.apply_operator_blocks``)."""
    if blocks is None:
        kernels.apply_operator(data, scales, mask, vector, out)
    else:
        indptr, indices, values, ones = blocks
        kernels.apply_operator_blocks(data, scales, ones, indptr, indices, values, mask, vector, out)


def _krylov(data, scales, mask, rhs, guess, factor: _Factor, tolerance, max_iterations, symmetric, x, blocks=None):
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
    _operator(data, blocks, scales, mask, x, v)
    # the guess scaled by the factor that minimises ||b - a A x0|| (0: no guess), never a worse start
    # than none (the extrapolated dv is a poor guess after a random action: TumorPositioning's mean
    # iterations 3.57 -> 2.84 over 400 random steps, 19% more steps/s; smooth actions 3.56 -> 3.50)
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
            _operator(data, blocks, scales, mask, p, v)
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
        _operator(data, blocks, scales, mask, p_hat, v)
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
        _operator(data, blocks, scales, mask, s_hat, t)
        tt = float(t @ t)
        omega = float(t @ s) / tt if tt > 0 else 0.0
        x += alpha * p_hat
        x += omega * s_hat
        r = s - omega * t
        residual = float(np.linalg.norm(r)) / norm_b
        rho_new = float(r_hat @ r)
    return iterations, residual


INTEGRATORS = {"explicit": SymplecticEuler, "implicit": ImplicitEuler}


def make_integrator(name: str, **options):
    """Integrator by name: "explicit" (symplectic Euler), "implicit" (Baraff-Witkin Euler) or "static"
    (``sim_core.static.QuasiStatic``: a static equilibrium per step)."""
    if name == "static":
        from .static import QuasiStatic

        return QuasiStatic(**options)
    if name not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {tuple(INTEGRATORS) + ('static',)}, got {name!r}")
    return INTEGRATORS[name](**options)


# -- stable time step --------------------------------------------------------------------------
def _damped_limit(omega: float, zeta: float) -> float:
    """Symplectic Euler on x'' + 2 zeta omega x' + omega^2 x = 0 is stable for
    omega dt < 2 (sqrt(1 + zeta^2) - zeta) (Jury criterion on its 2x2 amplification matrix)."""
    return 2.0 * (np.sqrt(1.0 + zeta**2) - zeta) / omega


def stable_time_step(model: Model, control: Control | None = None, *, method: str = "eigen",
                     positions: np.ndarray | None = None, damping: bool = True) -> float:
    """Largest stable symplectic-Euler time step in s (physics.md section 5).

    Args:
        method: "eigen" (Arnoldi on M^-1 K for omega_max, the damping ratio of that mode from its
            Rayleigh quotient) or "gershgorin" (row-sum bounds, cheap and conservative).
        positions: where to linearise (default rest), m.
        damping: account for the spring damping, which lowers the limit.
    Not the report's 2 sqrt(m_max / k_min), which is about 5x too large. Measured against the
    largest stable dt (benchmarks/stability.py): up to 10.8% optimistic, so step at 0.8x or less.
    A 10x10x10 block sagging under its own weight diverged at 0.9x (after 1.9 s) and ran 10 s
    stably at 0.8x; the limit at the loaded state was within 2% of the one at rest.
    """
    control = model.new_control() if control is None else control
    positions = model.rest_positions if positions is None else positions
    free = np.flatnonzero(~control.fixed.ravel())
    stiffness = model.pattern.matrix(stiffness_data(model, positions)).tocsr()[free][:, free]
    damping_matrix = model.pattern.matrix(stiffness_data(model, positions, stiffness_scale=0.0, damping_scale=1.0,
                                                         corrections="none", volume=False)).tocsr()[free][:, free]
    inverse_mass = 1.0 / np.repeat(model.mass, 3)[free]
    if method == "gershgorin":
        omega = np.sqrt(np.max(inverse_mass * np.asarray(abs(stiffness).sum(axis=1)).ravel()))
        zeta = np.max(inverse_mass * np.asarray(abs(damping_matrix).sum(axis=1)).ravel()) / (2 * omega) if damping else 0.0
        return float(_damped_limit(omega, zeta))
    if method != "eigen":
        raise ValueError(f"method must be 'eigen' or 'gershgorin', got {method!r}")
    operator = sp.diags(inverse_mass) @ stiffness
    # The most restrictive mode is not always the stiffest one when damping ratios differ, so take
    # the smallest damped limit over the highest few modes.
    n_modes = min(8, len(free) - 2)
    values, vectors = spla.eigs(operator, k=n_modes, which="LM", tol=1e-6)
    limits = []
    for value, vector in zip(values, vectors.T):
        omega = float(np.sqrt(abs(value.real)))
        mode = vector.real if np.linalg.norm(vector.real) >= np.linalg.norm(vector.imag) else vector.imag
        mass_norm = mode @ (mode / inverse_mass)
        zeta = float(mode @ (damping_matrix @ mode) / (2.0 * omega * mass_norm)) if damping else 0.0
        limits.append(_damped_limit(omega, max(zeta, 0.0)))
    return float(min(limits))


@dataclass
class RunReport:
    """Outcome of ``run``: steps done, whether the run became unstable, at which step and why."""

    steps: int
    unstable: bool
    unstable_reason: str | None
    unstable_step: int | None
    iterations: list


def run(model: Model, state: State, integrator, dt: float, steps: int, control: Control | None = None) -> RunReport:
    """Advance ``state`` in place by ``steps`` steps of ``dt`` s; stops at the first instability."""
    iterations = []
    scratch = state.copy()
    for step in range(1, int(steps) + 1):
        report = integrator.simulate(model, state, scratch, dt, control)
        iterations.append(report.iterations)
        state.positions, state.velocities, state.time = scratch.positions, scratch.velocities, scratch.time
        if report.unstable:
            return RunReport(step, True, report.unstable_reason, step, iterations)
    return RunReport(int(steps), False, None, None, iterations)
