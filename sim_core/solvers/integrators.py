"""Time integration: symplectic (semi-implicit) Euler, implicit Euler (Baraff and Witkin), the
quasi-static solver by name (``make_integrator``), the stable explicit time step and ``run``.

Every integrator keeps the solver contract of ``sim_core.solvers.solver``: bound to a model (``bind``,
``make_integrator(name, model=model)``), ``step(state_in, state_out, control, dt) -> StepReport``;
``simulate(model, state_in, state_out, dt, control)`` is the same step with the model named at the
call. A diverging run is reported
(``StepReport.unstable_reason``), never left to produce an unexplained NaN. The implicit step's
factorised preconditioners are in ``sim_core.solvers.preconditioners``, its Krylov solves in
``sim_core.solvers.krylov``. SI units: s, m, m/s, N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import kernels
from ..caches import digest
from ..models.forces import ForceWorkspace, hourglass_blocks, stiffness_data
from .krylov import apply_system, krylov_solve
from ..models.model import Control, Model, State
from .preconditioners import (AUTO_MAX_DOFS, PRECONDITIONERS, REFACTOR_MIN, RESTRICTED_MAX_CHANGED, Factor,
                              FactorStore, auto_switch_iterations, free_structure, pattern_arrays)
from .solver import DivergenceMonitor, OneWorldSolver, StepReport, check_dt, impose_control
from .static import QuasiStatic


class SymplecticEuler(OneWorldSolver):
    """Semi-implicit (symplectic) Euler: v += dt M^-1 f(x, v); x += dt v.

    Stable for dt below ``stable_time_step(model)`` (about 2 / omega_max, less with damping).
    """

    name = "explicit"

    def __init__(self, monitor: bool = True):
        self.monitor = monitor
        # per model (keyed by the model itself, so that a copy of the integrator and its models
        # finds its own entries)
        self._monitors: dict[Model, DivergenceMonitor] = {}
        self._workspaces: dict[Model, ForceWorkspace] = {}

    def _options(self):
        return dict(monitor=self.monitor)

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float, control: Control | None = None) -> StepReport:
        dt = check_dt(dt)
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
        workspace = self._workspaces.get(model)
        if workspace is None:
            workspace = self._workspaces[model] = ForceWorkspace(model, implicit=implicit)
        return workspace

    def _check(self, model, state):
        if not self.monitor:
            return None
        monitor = self._monitors.get(model)
        if monitor is None:
            monitor = self._monitors[model] = DivergenceMonitor(model)
        return monitor.check(state)


class ImplicitEuler(SymplecticEuler):
    """Linearised implicit Euler (Baraff and Witkin 1998), one linear solve per step:

        (M + dt D + dt^2 K) dv = dt (f(x0, v0) - dt K v0),   v1 = v0 + dv,   x1 = x0 + dt v1.

    K holds the springs (geometric term clamped at zero so the matrix is SPD), the corrections'
    push along the current edges and, for "baudet-hyperelastic", the stress correction's element
    blocks, each clamped to its positive part (docs/physics.md section 11; symmetric, so CG). The corrections' strain coupling is not symmetric (docs/physics.md 3):
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
        preconditioner: "jacobi" (default), "factorised" or "auto". Jacobi is the default because
            its cost per step is the most predictable on small meshes; "auto" picks per system.
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
        self._factor: Factor | None = None
        self._auto_factorised: set = set()  # keys "auto" switched to the factorised preconditioner
        #: factorisations done so far (a diagnostic; the tests read it)
        self.factorisations = 0
        #: factorisations taken from ``factor_store`` instead of made (a diagnostic)
        self.factor_reuses = 0
        self.factor_store: FactorStore | None = None
        self._threshold = REFACTOR_MIN  # re-factorise when a solve needs more iterations (_set_baseline)
        self._step_positions = None  # the current step's linearisation positions (for factor_store)
        self._linearised = None  # (model, positions) of the workspace's force pass made by ``linearise``

    def _options(self):
        return dict(corrections=self.corrections, tolerance=self.tolerance, max_iterations=self.max_iterations,
                    monitor=self.monitor, preconditioner=self.preconditioner)

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
        dt = check_dt(dt)
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
        apply_system(data, blocks, system, np.ones(n), moved, product)
        rhs = dt * forces.reshape(-1) + pattern_arrays(model)[4] * v0.reshape(-1) - product
        mask = free.astype(float)
        # Warm start: the last two steps' dv extrapolated linearly (fewer BiCGSTAB iterations on
        # sim_core.studies.bench's sagging block; neutral under the envs' random actions), which
        # the factorised solve (krylov_solve) scales to the least residual before iterating.
        guess = self._warm if self._warm is not None and self._warm.shape == rhs.shape else np.zeros_like(rhs)
        if self._warm_old is not None and self._warm_old.shape == rhs.shape:
            guess = 2.0 * guess - self._warm_old
        dv = np.empty(n)
        symmetric = not (coupled or implicit_volume)
        key = (model, dt, digest(control.fixed), system)
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
        impose_control(control, state_in, positions, velocities, dt)
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
        restricted to the new free dofs (``Factor.restricted``: exact on the nodes it holds, Jacobi
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
        iterations, residual = krylov_solve(data, system, mask, rhs * mask, guess, preconditioner, self.tolerance, limit,
                                       symmetric, out, blocks)
        if not fresh and residual > self.tolerance and iterations < max_iterations:
            factor = self._factorise(model, key, data, system, mask)  # at this step's linearisation
            more, residual = krylov_solve(data, system, mask, rhs * mask, out.copy(), factor, self.tolerance,
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
            factor = Factor(model, key, structure, values)
            self.factorisations += 1
            if kept:
                store.put(key, factor)
        self._factor = factor
        return factor


def _system_key(key):
    """(model, dt, scales) of a solve key (model, dt, imposed-set digest, scales)."""
    return key[0], key[1], key[3]


INTEGRATORS = {"explicit": SymplecticEuler, "implicit": ImplicitEuler}


def make_integrator(name: str, model: Model | None = None, **options):
    """Integrator by name: "explicit" (symplectic Euler), "implicit" (Baraff-Witkin Euler) or "static"
    (``sim_core.solvers.static.QuasiStatic``: a static equilibrium per step), bound to ``model`` when given
    (its ``step`` verb, ``sim_core.solvers.solver``)."""
    if name == "static":
        solver = QuasiStatic(**options)
    elif name in INTEGRATORS:
        solver = INTEGRATORS[name](**options)
    else:
        raise ValueError(f"integrator must be one of {tuple(INTEGRATORS) + ('static',)}, got {name!r}")
    return solver if model is None else solver.bind(model)


# -- stable time step --------------------------------------------------------------------------
def _damped_limit(omega: float, zeta: float) -> float:
    """Symplectic Euler on x'' + 2 zeta omega x' + omega^2 x = 0 is stable for
    omega dt < 2 (sqrt(1 + zeta^2) - zeta) (Jury criterion on its 2x2 amplification matrix)."""
    return 2.0 * (np.sqrt(1.0 + zeta**2) - zeta) / omega


def stable_time_step(model: Model, control: Control | None = None, *, method: str = "eigen",
                     positions: np.ndarray | None = None, damping: bool = True) -> float:
    """Largest stable symplectic-Euler time step in s (docs/physics.md section 5).

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
