"""Static equilibrium of the mass-spring model: damped Newton with line search and load stepping.

Zero-energy modes (docs/physics.md section 6): the 16-spring hexahedron has 3 non-rigid hourglass
modes per block, so the tangent stiffness can be singular even when rigid motion is removed.
The solver handles them with a Levenberg-Marquardt term ``mu diag(K)`` in the Newton system: the
step is the regularised (near minimum-norm) one, so a mode that no force excites keeps its initial
amplitude (zero from rest) instead of making the linear solve fail; mu grows only when a step does
not reduce the residual. ``zero_energy_modes`` counts them (shift-invert Lanczos on the
constrained tangent) so that experiments can report them.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import kernels
from ..caches import BudgetCache
from ..models.forces import ForceWorkspace, external_forces, internal_forces, stiffness_data
from .preconditioners import free_structure, pattern_arrays
from .solver import DivergenceMonitor, OneWorldSolver, StepReport, check_dt
from ..models.elements import inverted
from .._validate import count_not_finite, integer_at_least, positive_scalar, real_scalar
from ..models.model import Control, Model, State


@dataclass
class StaticResult:
    """Outcome of ``solve_static``.

    Attributes:
        state: equilibrium state (positions m, zero velocities).
        converged: relative force residual below the tolerance.
        residual: ||free-dof force residual|| / ||applied + reaction forces|| (dimensionless).
        iterations: total Newton iterations over all load steps.
        load_steps: number of load increments that were needed.
        reaction: (N, 3) forces (N) the imposed displacements exert on the nodes (0 where free).
        message: why it stopped.
        lowest_eigenvalue: smallest eigenvalue (N/m) of the symmetric part of the constrained
            tangent stiffness at the solution, when asked for (``check_stability=True``); negative
            means an unstable equilibrium (a saddle: the structure buckles under that load).
    """

    state: State
    converged: bool
    residual: float
    iterations: int
    load_steps: int
    reaction: np.ndarray
    message: str = ""
    lowest_eigenvalue: float | None = None

    @property
    def stable(self) -> bool | None:
        """True/False when the stability was checked, None otherwise."""
        if self.lowest_eigenvalue is None:
            return None
        return self.lowest_eigenvalue >= 0.0

    @property
    def positions(self) -> np.ndarray:
        return self.state.positions


class FactorCache:
    """Reusable LU factors of the constrained tangent stiffness, for repeated ``solve_static`` calls
    on the same model (e.g. an env's goal solve at every reset, from the same start).

    An entry is keyed by the model's identity, the free-dof pattern, the linearisation positions
    (bitwise) and the damping: it holds exactly the factor ``solve_static`` would compute there, so a
    hit changes no result, only skips the factorisation. Least recently used entries are dropped past
    ``size`` entries or past the "static_factors" byte budget (``sim_core.caches``; an entry holds
    its model, which that budget does not count).
    Thread-safe (the vector envs reset their copies, which share one cache, on several threads): the
    factorisations run outside the lock, so two threads missing the same entry at once both compute
    it (the same floats).
    """

    def __init__(self, size: int = 8):
        self.size = integer_at_least("size", size, 1)
        self._entries = BudgetCache("static_factors", self.size)
        self.hits = self.misses = 0
        self._lock = threading.Lock()

    def factorise(self, model, positions, free, damping, solver="auto"):
        """(stiffness, LU of the damped K_ff) at ``positions``: cached or computed (and stored)."""
        key = (model, free.tobytes(), np.ascontiguousarray(positions, dtype=float).tobytes(), float(damping),
               _use_direct(solver, len(free)))
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self.hits += 1
                return entry
            self.misses += 1
        value = _factorise(model, positions, free, damping, solver)  # outside the lock: threads factorise at once
        return self._entries.put(key, value)

    @property
    def nbytes(self) -> int:
        """Bytes the kept factors hold (``sim_core.caches.nbytes``)."""
        return self._entries.nbytes

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self):
        self._entries.clear()

    def __getstate__(self):  # LU objects do not pickle: copies start empty
        return dict(size=self.size)

    def __setstate__(self, state):
        self.__init__(state["size"])


def _free_dofs(control: Control) -> np.ndarray:
    return np.flatnonzero(~control.fixed.ravel())


def _initial_positions(model, initial) -> np.ndarray:
    try:
        start = np.array(initial, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"initial must be a ({model.n_nodes}, 3) array of positions in m, got {type(initial).__name__}") \
            from error
    if start.shape != (model.n_nodes, 3):
        raise ValueError(f"initial must be a ({model.n_nodes}, 3) array of positions in m (one row per node), "
                         f"got shape {start.shape}")
    bad = count_not_finite(start)
    if bad:
        raise ValueError(f"initial has {bad} non-finite entries (NaN or infinity); start positions must all be finite (m)")
    return start


def check_control(model: Model, control: Control) -> Control:
    """Raise ``ValueError`` unless ``control`` fits ``model``: ``fixed`` an (N, 3) bool array,
    ``target`` and ``force`` (N, 3) numeric arrays, ``force`` finite everywhere and ``target``
    finite where ``fixed``. Returns ``control`` itself (its arrays are not copied)."""
    shape = (model.n_nodes, 3)
    for name in ("fixed", "target", "force"):
        array = getattr(control, name, None)
        if not isinstance(array, np.ndarray) or array.shape != shape:
            got = f"shape {array.shape}" if isinstance(array, np.ndarray) else f"{type(array).__name__}"
            raise ValueError(f"control.{name} must be a {shape} array (one row per node of the model, x y z), "
                             f"got {got}; build controls with model.new_control()")
    if control.fixed.dtype != bool:
        raise ValueError(f"control.fixed must be a boolean (N, 3) mask (True where a component is imposed), "
                         f"got dtype {control.fixed.dtype}")
    for name in ("target", "force"):
        dtype = getattr(control, name).dtype
        if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
            raise ValueError(f"control.{name} must hold real numbers, got dtype {dtype}")
    bad = count_not_finite(control.force)
    if bad:
        raise ValueError(f"control.force has {bad} non-finite entries (NaN or infinity); nodal forces must all be "
                         "finite numbers in N")
    bad = count_not_finite(control.target[control.fixed])
    if bad:
        raise ValueError(f"control.target has {bad} non-finite entries (NaN or infinity) where control.fixed is True; "
                         "imposed positions must be finite numbers in m")
    return control


#: Share of a rigid motion's squared norm on the imposed components below which the supports do
#: not hold it, and share of the load's norm along unheld motions above which the load is not
#: balanced by anything (a load meant to be balanced is, to rounding: 1e-15)
_HELD = 1e-10
_UNBALANCED = 1e-6


def _axis_name(vector) -> str:
    vector = np.asarray(vector, dtype=float) / np.linalg.norm(vector)
    axis = int(np.argmax(np.abs(vector)))
    if abs(vector[axis]) > 1.0 - 1e-9:
        return "xyz"[axis]
    return "(" + ", ".join(f"{v:.3g}" for v in np.where(np.abs(vector) < 1e-9, 0.0, vector)) + ")"


def rigid_fields(positions):
    """(fields (6, N, 3), centre (3,) m, size m): a basis of the linearised rigid motions about
    ``positions`` (N, 3) m, rotations about x, y, z through the centroid ``centre`` (scaled by
    1 / ``size``, the rms distance from it), then translations along x, y, z."""
    centre = positions.mean(axis=0)
    relative = positions - centre
    size = float(np.sqrt(np.mean(np.sum(relative**2, axis=1)))) or 1.0
    fields = np.zeros((6,) + positions.shape)
    for axis in range(3):
        fields[axis] = np.cross(np.eye(3)[axis], relative) / size
        fields[3 + axis][:, axis] = 1.0
    return fields, centre, size


def unconstrained_motions(positions, fixed) -> list[tuple[str, np.ndarray]]:
    """The rigid-body motions that no imposed component holds: [(name, (N, 3) field)], a basis of
    the linearised rigid motions about ``positions`` (N, 3) m that vanish on every component where
    ``fixed`` (N, 3) bool is True ("translation along y", "rotation about z (axis through ...)")."""
    positions = np.asarray(positions, dtype=float)
    fields, centre, size = rigid_fields(positions)
    basis = fields.reshape(6, -1).T
    held = basis[np.asarray(fixed, dtype=bool).ravel()]
    values, vectors = scipy.linalg.eigh(held.T @ held, basis.T @ basis)
    null = vectors[:, values < _HELD]
    if null.shape[1] == 0:
        return []
    rows = null.T / np.abs(null.T).max(axis=1, keepdims=True)
    pivot_row = 0  # reduced row echelon form, rotations first: one named motion per row
    for column in range(6):
        if pivot_row == len(rows):
            break
        best = pivot_row + int(np.argmax(np.abs(rows[pivot_row:, column])))
        if abs(rows[best, column]) < 1e-8:
            continue
        rows[[pivot_row, best]] = rows[[best, pivot_row]]
        rows[pivot_row] /= rows[pivot_row, column]
        for other in range(len(rows)):
            if other != pivot_row:
                rows[other] -= rows[other, column] * rows[pivot_row]
        pivot_row += 1
    motions = []
    for row in rows:
        rotation, translation = row[:3], row[3:]
        field = (row @ fields.reshape(6, -1)).reshape(positions.shape)
        if np.linalg.norm(rotation) > 1e-8:
            point = centre + size * np.cross(rotation, translation) / float(rotation @ rotation)
            point = np.where(np.abs(point) < 1e-9 * size, 0.0, point)  # rounding of an axis through 0
            name = _axis_name(rotation)
            if len(name) == 1:  # an axis along x, y or z: where it crosses the other two
                where = "at " + ", ".join(f"{'xyz'[a]} = {point[a]:.4g}" for a in range(3) if "xyz"[a] != name)
            else:
                where = "through (" + ", ".join(f"{v:.4g}" for v in point) + ")"
            motions.append((f"rotation about {name} (axis {where} m)", field))
        else:
            motions.append((f"translation along {_axis_name(translation)}", field))
    return motions


def check_supports(model: Model, control: Control, positions, load) -> None:
    """Raise ``ValueError`` when the load (gravity plus ``control.force``, N) pushes along a
    rigid-body motion that no imposed component holds: no static equilibrium exists (Newton would
    only report a failed load step). Rigid motions left free by the supports are allowed when the
    load does no work along them, a zero load included (a free block at rest, a block on a
    frictionless floor under vertical gravity): the solver's regularised steps leave them at rest."""
    load_norm = float(np.linalg.norm(load))
    if load_norm == 0.0:
        return
    held = np.asarray(positions, dtype=float)[np.asarray(control.fixed).all(axis=1)]
    if len(held) >= 3:  # three fully held points not on one line hold every rigid motion
        spread = held - held.mean(axis=0)
        singular = np.linalg.svd(spread, compute_uv=False)
        if singular[1] > 1e-9 * max(singular[0], 1e-300):
            return
    motions = unconstrained_motions(positions, control.fixed)
    if not motions:
        return
    fields = np.stack([field.ravel() for _, field in motions], axis=1)
    orthonormal = np.linalg.qr(fields)[0]
    if np.linalg.norm(orthonormal.T @ load.ravel()) <= _UNBALANCED * load_norm:
        return
    pushed = [name for name, field in motions
              if abs(float(field.ravel() @ load.ravel())) > _UNBALANCED * load_norm * np.linalg.norm(field)]
    names = ", ".join(name for name, _ in motions)
    raise ValueError(
        f"under-constrained static problem: the imposed components (control.fixed, {int(control.fixed.sum())} of "
        f"{control.fixed.size}) leave {len(motions)} rigid-body motion(s) free: {names}; the load (gravity + "
        f"control.force) pushes along {', '.join(pushed) or names}, so no static equilibrium exists. Impose those "
        "components on some nodes (control.impose(nodes, positions, components)): a translation along an axis needs "
        "that component imposed on at least one node, a rotation about an axis needs the components perpendicular to "
        "it imposed on nodes off the axis (two distinct points, or one point's two components); or remove the load "
        "along the free motions")


def _residual(model, positions, applied):
    return internal_forces(model, positions) + applied


def _relative(force, free, applied):
    scale = max(np.linalg.norm(force - applied), np.linalg.norm(applied), 1e-300)
    return np.linalg.norm(force.ravel()[free]) / scale


def solve_static(
    model: Model,
    control: Control | None = None,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = 1e-8,
    max_iterations: int = 40,
    load_steps: int = 1,
    max_load_steps: int = 256,
    check_stability: bool = False,
    cache: FactorCache | None = None,
    chord_contraction: float = 0.25,
    acceleration: int = 0,
    linear_solver: str = "auto",
) -> StaticResult:
    """Find positions where internal + external forces vanish on every free component.

    Args:
        model: the mass-spring model (gravity from ``model.gravity``).
        control: imposed positions (``fixed``, ``target`` m) and nodal forces (``force`` N).
        initial: (N, 3) starting positions in m (default: rest). Imposed components are ramped
            linearly from there in load steps (halved when Newton fails), each step starting from a
            linear predictor that moves the free nodes with the imposed ones. Loads (gravity, nodal
            forces) are ramped from zero when starting from rest, and applied in full from
            ``initial`` (typically a previous equilibrium under the same loads).
        tolerance: relative force residual to reach.
        max_iterations: Newton iterations per load step before the step is subdivided.
        load_steps: initial number of load increments.
        max_load_steps: give up (converged=False) past this many increments.
        check_stability: compute the lowest eigenvalue of the tangent at the solution (a saddle
            point, e.g. hourglass buckling under compression, is an equilibrium too).
        cache: a ``FactorCache`` for the predictor's factorisations (at the start of a load step):
            repeated solves from the same positions (same model, same imposed dofs) then reuse the
            LU. The result does not depend on whether the cache hits.
        chord_contraction: a factorised tangent is reused (chord steps) while every step reduces
            the residual norm at least by this factor, refactorised otherwise. Larger values (up to
            ~0.7) trade cheap chord iterations for factorisations, e.g. with a cached start tangent
            and moderate displacements; the converged result stays within ``tolerance``.
        acceleration: Anderson mixing depth for the chord steps (0: plain chord steps), which
            speeds up a chord iteration with an old tangent.
        linear_solver: how each Newton step solves the tangent system: "direct" (sparse LU),
            "iterative" (``IterativeTangent``: AMG-preconditioned conjugate gradients, memory and
            time about linear in the mesh size) or "auto" (direct up to DIRECT_DOF_LIMIT free dofs,
            iterative above).

    Raises ``ValueError`` before solving, saying what was wrong and what is allowed, for: a
    tolerance that is not a finite number > 0; max_iterations, load_steps or max_load_steps
    that are not integers >= 1 (acceleration >= 0; chord_contraction in (0, 1)); ``initial``
    or ``control`` arrays not of the model's (N, 3) shape; NaN or infinity in ``initial``,
    ``control.force`` or ``control.target`` where ``control.fixed``; and an under-constrained
    problem whose load has no equilibrium (``check_supports``): the load pushes along a
    rigid-body motion that no imposed component holds. Free rigid motions the load does not push
    along (a zero load, a block on a frictionless floor under vertical gravity) are allowed: the
    regularised Newton steps leave them at rest.
    """
    tolerance = positive_scalar("tolerance", tolerance, "a relative force residual, e.g. 1e-8")
    max_iterations = integer_at_least("max_iterations", max_iterations, 1)
    load_steps = integer_at_least("load_steps", load_steps, 1)
    max_load_steps = integer_at_least("max_load_steps", max_load_steps, 1)
    chord_contraction = real_scalar("chord_contraction", chord_contraction, "a number in (0, 1)")
    if not 0.0 < chord_contraction < 1.0:
        raise ValueError(f"chord_contraction must be a number in (0, 1) (default 0.25), got {chord_contraction!r}")
    acceleration = integer_at_least("acceleration", acceleration, 0)
    if linear_solver not in LINEAR_SOLVERS:
        raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {linear_solver!r}")
    control = model.new_control() if control is None else check_control(model, control)
    start = model.rest_positions.copy() if initial is None else _initial_positions(model, initial)
    free = _free_dofs(control)
    fixed = control.fixed
    full_load = external_forces(model, control)
    check_supports(model, control, start, full_load)
    ramp_loads = initial is None
    state = {"positions": start.copy()}

    def advance(level):
        applied = level * full_load if ramp_loads else full_load
        target = start[fixed] + level * (control.target[fixed] - start[fixed])
        trial, factor = _predict(model, state["positions"], free, fixed, target, applied, cache, linear_solver)
        ok, trial, residual, used = _newton(model, trial, free, applied, tolerance, max_iterations, factor,
                                            chord_contraction, acceleration, linear_solver)
        if ok:
            state["positions"] = trial
        return ok, residual, used

    converged, iterations, increments, residual, message = ramp_load(advance, load_steps, max_load_steps,
                                                                     fast_iterations=6)
    positions = state["positions"]
    force = _residual(model, positions, full_load)
    if converged:
        residual = _relative(force, free, full_load)
        message = "converged"
    reaction = np.where(fixed, -force, 0.0)
    lowest = None
    if check_stability:
        lowest = lowest_eigenvalue(model, control, positions)
    return StaticResult(State(positions, np.zeros_like(positions)), converged, float(residual),
                        iterations, increments, reaction, message, lowest)


#: most static solves per step while a contact's active set changes (``tissue_env.base.TissueEnv._advance``,
#: ``sim_core.resolution.dynamic_scene``), and how far (m) the imposed heights may still move for
#: the set to count as settled (the static scenes' ``slide_tolerance``: a held node slides along
#: the obstacle, and its height follows)
STATIC_CONTACT_PASSES = 25
STATIC_SLIDE_TOLERANCE = 1e-7


def same_contacts(previous_fixed, previous_target, fixed, target,
                  tolerance: float = STATIC_SLIDE_TOLERANCE) -> np.ndarray:
    """Per world, whether two controls (``fixed`` (..., n, 3) bool, ``target`` (..., n, 3) m, the
    worlds first) impose the same components at positions within ``tolerance`` m: a contact's
    active set has settled (no node joined or left, the held heights stopped moving). (...) bool."""
    fixed = np.asarray(fixed, dtype=bool)
    moved = np.where(fixed, np.abs(np.asarray(target) - np.asarray(previous_target)), 0.0)
    return np.all(np.asarray(previous_fixed, dtype=bool) == fixed, axis=(-2, -1)) & np.all(moved <= tolerance, axis=(-2, -1))


def same_contact(previous: Control, control: Control, tolerance: float = STATIC_SLIDE_TOLERANCE) -> bool:
    """``same_contacts`` of one world's controls."""
    return bool(same_contacts(previous.fixed, previous.target, control.fixed, control.target, tolerance))


#: QuasiStatic keeps a step's predictor tangent for the next steps while they converge in at most
#: this many Newton iterations
REUSE_ITERATIONS = 6


class _KeptTangent:
    """``FactorCache``'s interface for ``QuasiStatic``: the predictor's tangent LU of the last
    factorisation, returned for any positions while the model and the free dofs are the same (a
    tangent of a nearby state: the predictor and the first chord steps, which Newton refreshes
    when they stop contracting)."""

    def __init__(self):
        self._key, self._value = None, None
        self._source = None  # (positions, free, damping, solver) the kept tangent was factorised at

    def factorise(self, model, positions, free, damping, solver="auto"):
        key = (model, free.tobytes(), float(damping), _use_direct(solver, len(free)))
        if self._value is None and self._source is not None and self._key[1:] == key[1:]:
            # an unpickled copy: the tangent it kept, factorised again where it was (the same floats)
            self._key, self._value = key, _factorise(model, *self._source)
        if self._key is None or self._key[0] is not model or self._key[1:] != key[1:]:
            self._key, self._value = key, _factorise(model, positions, free, damping, solver)
            self._source = (np.array(positions, dtype=float), np.array(free), float(damping), solver)
        return self._value

    def clear(self):
        self._key, self._value, self._source = None, None, None

    def __getstate__(self):  # LU objects do not pickle: what the kept one was factorised from does
        return dict(key=None if self._key is None else (None,) + self._key[1:], source=self._source)

    def __setstate__(self, state):
        self._key, self._value, self._source = state["key"], None, state["source"]

    def __deepcopy__(self, memo):  # the kept factor is never modified (only replaced): shared
        kept = _KeptTangent()
        kept._key, kept._source = copy.deepcopy((self._key, self._source), memo)
        kept._value = self._value
        return kept


class QuasiStatic(OneWorldSolver):
    """Quasi-static stepping: each step is the static equilibrium (``solve_static``) under the
    step's control, solved from the previous positions, so the state has no inertia, damping or
    lag behind the tool: the observations at every tool position are those of the static scene.
    The same ``simulate`` interface as the integrators (``sim_core.solvers.integrators``); ``dt`` (s) only
    advances the clock, and the velocities are zero (a sequence of equilibria).

    Args:
        tolerance: relative force residual of each equilibrium (``solve_static``).
        max_iterations: Newton iterations per load increment before it is halved. 40: a probe pressed
            8 mm deep at a slab's edge (frictionless contact nodes free to slide) gives a nearly
            singular tangent whose line-searched steps shrink the residual by about 10% each, and
            halving the increment does not help (tests/test_quasi_static.py); a converging step
            stops at its tolerance, so the budget costs only the steps that need it.
        max_load_steps: a step whose imposed displacement needs more increments than this is
            reported as a failure (``StepReport.unstable_reason``): no equilibrium was found
            near the previous one (past a buckling load, or an inverted element).
    A step costs a few Newton iterations, each a chord step with a kept tangent LU or a tangent
    assembly and sparse factorisation: slower than one implicit Euler step (measured in
    benchmarks/dynamic_convergence.py --integrator static), for observations without lag. The
    predictor's tangent is kept from step to step (same model and free dofs) while steps
    converge within REUSE_ITERATIONS: fewer factorisations, so more steps per CPU second for every
    task's static env (random actions; observations within the solve tolerance).
    """

    name = "static"

    def __init__(self, tolerance: float = 1e-6, max_iterations: int = 40, max_load_steps: int = 8, monitor: bool = True):
        self.tolerance = positive_scalar("tolerance", tolerance, "a relative force residual, e.g. 1e-6")
        self.max_iterations = integer_at_least("max_iterations", max_iterations, 1)
        self.max_load_steps = integer_at_least("max_load_steps", max_load_steps, 1)
        self.monitor = monitor
        self._factors = _KeptTangent()
        self._monitor = None  # the integrators' DivergenceMonitor of the last model stepped

    def _options(self):
        return dict(tolerance=self.tolerance, max_iterations=self.max_iterations, max_load_steps=self.max_load_steps,
                    monitor=self.monitor)

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float, control: Control | None = None):
        dt = check_dt(dt)
        control = model.new_control() if control is None else control
        result = solve_static(model, control, initial=state_in.positions, tolerance=self.tolerance,
                              max_iterations=self.max_iterations, max_load_steps=self.max_load_steps,
                              chord_contraction=0.5, cache=self._factors)
        if result.iterations > REUSE_ITERATIONS:
            self._factors.clear()  # the state moved away from the kept tangent: a fresh one next step
        positions = result.positions
        state_out.positions, state_out.velocities, state_out.time = positions, np.zeros_like(positions), state_in.time + dt
        reason = None
        if not result.converged:
            reason = f"static solve did not converge ({result.message})"
        elif self.monitor:  # the integrators' checks, element inversion at every step (an equilibrium can jump)
            if self._monitor is None or self._monitor.model is not model:
                self._monitor = DivergenceMonitor(model)
            reason = self._monitor.check(state_out, force_inversion_check=True)
        return StepReport(int(result.iterations), float(result.residual), reason)


def ramp_load(advance, load_steps: int, max_load_steps: int, fast_iterations: int):
    """Adaptive load stepping from level 0 to 1: ``advance(level) -> (ok, residual, iterations)``
    solves one level (keeping its state on success). A failed increment is halved, one that took at
    most ``fast_iterations`` doubles the next; below 1 / ``max_load_steps`` it gives up.

    Returns (reached level 1, total iterations, increments, last residual, message).
    """
    done, step = 0.0, 1.0 / max(int(load_steps), 1)
    iterations, increments, residual, message = 0, 0, np.inf, ""
    while done < 1.0 - 1e-12:
        level = min(done + step, 1.0)
        ok, residual, used = advance(level)
        iterations += used
        if ok:
            done = level
            increments += 1
            step = min(step * 2.0 if used <= fast_iterations else step, 1.0 - done) if done < 1.0 else step
        else:
            step /= 2.0
            if step < 1.0 / max_load_steps:
                message = f"Newton did not converge at load level {level:.4f} (residual {residual:.2e})"
                break
    return done >= 1.0 - 1e-12, iterations, increments, residual, message


def tangent_stiffness(model: Model, positions: np.ndarray) -> sp.csr_matrix:
    """(3 N, 3 N) CSR tangent stiffness K (N/m) at ``positions`` (N, 3) m: ``stiffness_data(model,
    positions)`` (springs with their unclamped geometric term, the corrections' full coupling, the
    volume forces' rank-one term, hourglass), assembled by the compiled kernels
    (``kernels.operator_matrix_data``, the implicit step's assembly): equal to rounding (2e-15
    relative, tests/test_static_cache.py) and several times faster. Models whose corrections push along
    the rest directions (``correction_mode="fixed"``) use ``stiffness_data``."""
    positions = np.asarray(positions, dtype=float)
    if positions.shape != (model.n_nodes, 3) or not np.all(np.isfinite(positions)):
        raise ValueError(f"positions must be a finite ({model.n_nodes}, 3) array in m, got shape {positions.shape}")
    return model.pattern.matrix(_tangent_data(model, positions)).tocsr()


def _tangent_data(model, positions):
    if model.correction_mode not in (None, "projected"):
        return stiffness_data(model, positions)
    workspace = ForceWorkspace(model, implicit=True)  # scratch of this call: callers may run on threads
    workspace.compute(np.ascontiguousarray(positions, dtype=float), None, geometric=True,
                      volume_jacobian=model.has_volume_forces, exact=True)  # Newton's tangent: not clamped
    scales = (0.0, 0.0, 1.0, 1.0 if model.correction_mode else 0.0, 1.0 if model.has_volume_forces else 0.0,
              1.0 if model.hourglass is not None else 0.0)
    values = np.empty(model.pattern.nnz)
    kernels.operator_matrix_data(workspace.operator_data, scales, model.spring_positions, model.element_positions,
                                 pattern_arrays(model)[0], model.pattern.diagonal_positions, values)
    return values


def _free_tangent(model, positions, free):
    """(K, K_ff): the tangent (CSR, all dofs) and its free-dof block (CSC, ``free`` (k,) dofs)."""
    values = _tangent_data(model, positions)
    structure = free_structure(model, free)
    reduced = sp.csc_matrix((values[structure.take], structure.indices, structure.indptr), shape=structure.shape)
    return model.pattern.matrix(values).tocsr(), reduced


#: ``_tangent_data``'s force workspace per model, one set per thread (a workspace's arrays are
#: overwritten by every pass: the vector envs' copies share a model and reset on several threads)


#: free dofs above which ``solve_static``'s "auto" linear solver is iterative: a sparse LU's fill
#: and time grow as about n^(4/3) and n^2 on a 3D block (22^3 elements, 35k dofs: 55M entries, 10 s
#: per factorisation on 2 busy cores), while AMG-preconditioned conjugate gradients take about 25
#: iterations whatever the size (benchmarks/large_mesh.py)
DIRECT_DOF_LIMIT = 30_000
LINEAR_SOLVERS = ("auto", "direct", "iterative")
#: relative residual of an iterative linear solve, and its iteration cap (Newton's line search
#: judges the step either way)
ITERATIVE_TOLERANCE = 1e-10
ITERATIVE_MAX_ITERATIONS = 400


def _use_direct(solver, n_free):
    return solver == "direct" or (solver == "auto" and n_free <= DIRECT_DOF_LIMIT)


def _factorise(model, positions, free, damping, solver="auto"):
    """(K, solver of K_ff + damping |diag(K_ff)|) at ``positions``: a sparse LU (``solver``
    "direct", or "auto" up to DIRECT_DOF_LIMIT free dofs) or an ``IterativeTangent``. SuperLU with
    the minimum degree ordering on K + K^T in symmetric mode, pivoting only below a tenth of the
    column's largest entry: where SuperLU's default threshold pivots (a block with perturbed
    positions) this is faster, with less fill and the same residual; near rest the same factor and
    time."""
    stiffness, reduced = _free_tangent(model, positions, free)
    matrix = (reduced + sp.diags(damping * np.abs(reduced.diagonal()))).tocsc()
    if not _use_direct(solver, len(free)):
        return stiffness, IterativeTangent(matrix, positions, free)
    return stiffness, spla.splu(matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1,
                                options=dict(SymmetricMode=True))


class IterativeTangent:
    """The free-dof tangent K_ff (N/m) solved by Krylov iterations preconditioned with smoothed
    aggregation algebraic multigrid (pyamg), the rigid-body motions of the free nodes at
    ``positions`` (N, 3) m as its near-null space: the large-mesh stand-in for a sparse LU, with
    the same ``solve`` (conjugate gradients where K_ff is symmetric, GMRES otherwise) and memory
    linear in the mesh size. Raises RuntimeError where the hierarchy cannot be built (as SuperLU
    does on a singular matrix: Newton then regularises)."""

    def __init__(self, matrix, positions, free):
        import pyamg  # only large meshes need it

        matrix = sp.csr_matrix(matrix)
        scale = abs(matrix).max()
        self.symmetric = bool(abs(matrix - matrix.T).max() <= 1e-10 * scale)
        modes = rigid_fields(np.asarray(positions, dtype=float))[0].reshape(6, -1).T
        try:
            with np.errstate(all="ignore"):
                self.hierarchy = pyamg.smoothed_aggregation_solver(
                    matrix, B=modes[free], symmetry="symmetric" if self.symmetric else "nonsymmetric", max_coarse=500)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as error:
            raise RuntimeError(f"algebraic multigrid set-up failed: {error}") from error
        self.matrix, self.shape = matrix, matrix.shape
        self.preconditioner = self.hierarchy.aspreconditioner(cycle="V")
        self.iterations = 0

    def solve(self, rhs):
        # scipy's Krylov loops with the hierarchy's V-cycle as the preconditioner: a few times faster
        # than pyamg's own accelerators, whose GMRES is written in Python
        count = [0]

        def counted(_):
            count[0] += 1

        rhs = np.asarray(rhs, dtype=float)
        with np.errstate(all="ignore"):
            if self.symmetric:
                solution, _ = spla.cg(self.matrix, rhs, rtol=ITERATIVE_TOLERANCE, maxiter=ITERATIVE_MAX_ITERATIONS,
                                      M=self.preconditioner, callback=counted)
            else:
                solution, _ = spla.gmres(self.matrix, rhs, rtol=ITERATIVE_TOLERANCE, restart=60,
                                         maxiter=max(1, ITERATIVE_MAX_ITERATIONS // 60), M=self.preconditioner,
                                         callback=counted, callback_type="pr_norm")
        self.iterations += count[0]
        return solution


def _predict(model, positions, free, fixed, target, applied, cache=None, solver="auto"):
    """Linear predictor for a new load level: imposed components jump to ``target`` and the free
    ones follow by K_ff dx_f = r_f - K_fc dx_c. Returns (trial positions, LU of K_ff or None)."""
    trial = positions.copy()
    delta = np.zeros(positions.size)
    delta[fixed.ravel()] = target - positions[fixed]
    trial[fixed] = target
    if not np.any(delta):
        return trial, None
    try:
        factorise = _factorise if cache is None else cache.factorise
        stiffness, factor = factorise(model, positions, free, 1e-10, solver)
    except RuntimeError:
        return trial, None
    force = _residual(model, positions, applied).ravel()
    predicted = trial.copy()
    predicted.ravel()[free] += factor.solve(force[free] - stiffness[free] @ delta)
    if np.all(np.isfinite(predicted)) and not inverted(model, predicted):
        return predicted, factor
    return trial, None


def _newton(model, positions, free, applied, tolerance, max_iterations, factor=None, chord_contraction=0.25,
            acceleration=0, solver="auto"):
    """Newton with line search. The factorised tangent is reused (chord steps) while it keeps
    contracting the residual by 1 / ``chord_contraction`` (4x) per step, and rebuilt otherwise: one
    LU often serves a whole nearly linear solve (``factor``: an LU to start with, e.g. the
    predictor's). ``acceleration`` > 0: Anderson mixing of the chord steps over that many previous
    steps with the same LU (the plain step is tried when the mixed one is rejected).

    A step rejected with a fresh tangent ends the load step unconverged (``solve_static`` then
    halves it); the diagonal damping only grows while the tangent is singular: escalating it after a
    rejected step as well only delays a failure (docs/performance_notes.md, "Static solves")."""
    force = _residual(model, positions, applied)
    residual = _relative(force, free, applied)
    norm = np.linalg.norm(force.ravel()[free])
    damping = 1e-10
    fresh = False
    history = []  # (free positions, chord step) with the current factor
    for iteration in range(1, max_iterations + 1):
        if residual < tolerance:
            return True, positions, residual, iteration - 1
        accepted = False
        while not accepted and damping < 1.0:
            if factor is None:
                history = []
                try:
                    factor = _factorise(model, positions, free, damping, solver)[1]
                except RuntimeError:  # exactly singular: regularise more
                    damping *= 100.0
                    continue
                fresh = True
            step = factor.solve(force.ravel()[free])
            if acceleration and history:
                mixed = _anderson(history, positions.ravel()[free], step)
                accepted, trial, trial_force, trial_norm = _line_search(model, positions, free, applied, mixed, norm)
                if not accepted:
                    history = []
            if not accepted:
                accepted, trial, trial_force, trial_norm = _line_search(model, positions, free, applied, step, norm)
            if not accepted:
                if fresh:
                    # A fresh tangent's Newton step descends the residual norm wherever the residual
                    # is smooth, so a line search that fails with one has met the inversion guard or
                    # a kink: give up the load step (the ramp halves it) rather than regularise
                    # towards gradient steps.
                    return False, positions, residual, iteration
                factor = None
        if not accepted:
            return False, positions, residual, iteration
        if trial_norm > chord_contraction * norm:
            factor = None  # slow contraction: refresh the tangent next time
        elif acceleration:
            history = (history + [(positions.ravel()[free].copy(), step)])[-acceleration:]
        fresh = False
        positions, force, norm = trial, trial_force, trial_norm
        residual = _relative(force, free, applied)
        damping = max(damping / 100.0, 1e-10)
    return residual < tolerance, positions, residual, max_iterations


def _anderson(history, x, step):
    """Anderson-mixed step from ``x`` for the fixed-point map x -> x + step(x), given previous
    (x, step) pairs of the same map."""
    xs = np.stack([h[0] for h in history] + [x], axis=1)
    fs = np.stack([h[1] for h in history] + [step], axis=1)
    dx, df = np.diff(xs, axis=1), np.diff(fs, axis=1)
    gamma = np.linalg.lstsq(df, step, rcond=1e-10)[0]
    mixed = step - (dx + df) @ gamma
    return mixed if np.all(np.isfinite(mixed)) else step


def _line_search(model, positions, free, applied, step, norm):
    """Backtracking on the residual norm; rejects non-finite or inverted configurations."""
    scale = 1.0
    for _ in range(12):
        trial = positions.copy()
        trial.ravel()[free] += scale * step
        if np.all(np.isfinite(trial)) and not inverted(model, trial):
            trial_force = _residual(model, trial, applied)
            trial_norm = np.linalg.norm(trial_force.ravel()[free])
            if trial_norm < (1.0 - 1e-4 * scale) * norm or trial_norm == 0:
                return True, trial, trial_force, trial_norm
        scale *= 0.5
    return False, positions, None, norm


def zero_energy_modes(model: Model, control: Control | None = None, positions=None, relative_tolerance=1e-8,
                      n_modes: int = 16):
    """Count the zero-energy modes of the constrained tangent stiffness (docs/physics.md section 6).

    Args:
        control: which components are imposed (rigid motions left free count as modes too).
        positions: (N, 3) where to linearise, m (default: rest).
        relative_tolerance: eigenvalues below this times the mean diagonal count as zero.
        n_modes: how many of the lowest eigenpairs to compute.
    Returns:
        (count, eigenvalues (N/m) of the smallest modes, mode shapes (n_free, k)).
    """
    control = model.new_control() if control is None else control
    positions = model.rest_positions if positions is None else positions
    free = _free_dofs(control)
    stiffness = tangent_stiffness(model, positions)[free][:, free]
    symmetric = 0.5 * (stiffness + stiffness.T)
    scale = float(np.mean(np.abs(symmetric.diagonal())))
    n_modes = min(n_modes, len(free) - 2)
    values, vectors = spla.eigsh(symmetric.tocsc(), k=n_modes, sigma=-1e-3 * scale, which="LM")
    order = np.argsort(values)
    values, vectors = values[order], vectors[:, order]
    count = int(np.sum(np.abs(values) < relative_tolerance * scale))
    return count, values, vectors


def lowest_eigenvalue(model: Model, control: Control, positions: np.ndarray) -> float:
    """Smallest eigenvalue (N/m) of the symmetric part of the constrained tangent stiffness
    (Lanczos, smallest algebraic); values within 1e-8 of the largest diagonal entry count as 0."""
    free = _free_dofs(control)
    stiffness = tangent_stiffness(model, positions)[free][:, free]
    symmetric = 0.5 * (stiffness + stiffness.T)
    value = float(spla.eigsh(symmetric, k=1, which="SA", tol=1e-6, maxiter=50 * len(free))[0][0])
    return 0.0 if abs(value) < 1e-8 * float(np.abs(symmetric.diagonal()).max()) else value
