"""Batched physics for the vector environments: N copies of one scene stepped together.

The N copies share one topology (the task's block), so they are one sim_core ``Model`` on a mesh
made of N disjoint copies of the block (``ModelStack``): node ``j`` of copy ``i`` is node
``i * n_nodes + j`` of the stacked model, and every per-spring, per-element and per-node array is
the concatenation of the copies' arrays. A copy whose material changes (a new episode with
another inclusion or Young's modulus) overwrites its slot; nothing is rebuilt.

``BatchedImplicitEuler`` advances all copies by the discrete equation of sim_core's
``ImplicitEuler`` (corrections="implicit"), built from the same ``sim_core.kernels`` calls on the
stacked arrays:

    (M + dt D + dt^2 K) dv = dt (f(x0, v0) - dt K v0),   v1 = v0 + dv,   x1 = x0 + dt v1.

Only the linear solver differs. sim_core solves one copy with Jacobi-preconditioned BiCGSTAB
(about 20 iterations per env step of TumorPositioning); one call on the stacked model would keep
that cost per copy (measured: no faster than N single steps) and couple the copies through shared
scalars and one stopping test. Here every copy runs its own BiCGSTAB (its own scalars and
stopping test ||r|| <= tolerance ||b||, as sim_core's), all in lockstep, preconditioned by the
exact inverse of the copy's system matrix at the start of its episode. Copies that start alike
share that inverse, so the preconditioner is one dense matrix product for the whole batch, and
it stays close to the current matrix while the tissue moves a few millimetres: 4-5 iterations on
average. When it no longer fits (large deformation, a probe contact that changes the imposed
dofs), the copy that needed the most iterations (more than ``refresh_iterations``) is
re-linearised at its current state, one per step, and a copy that has not converged after
``first_pass`` iterations is re-linearised and solved again. The trajectories equal those of N
single environments up to the solvers' tolerance (tests/test_env_vector.py). ``solver="jacobi"``
instead runs sim_core's own compiled solve on each copy's slice of the stacked system (for scenes
whose deformation is too large for a start-of-episode preconditioner, e.g. Retraction). SI units.

Uses sim_core's public API and its compiled kernels, including ``kernels._operator`` (the matrix-
free product of the implicit system, the one ``ImplicitEuler`` applies).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sim_core import HexMesh
from sim_core import kernels
from sim_core.forces import internal_forces, spring_state, stiffness_data
from sim_core.integrators import DivergenceMonitor, SymplecticEuler
from sim_core.model import Control, Model, State

#: Model arrays that hold one value per node, spring or element of a copy (its material and rest
#: geometry); the topology arrays (springs, edge_spring) are offset instead.
VALUE_FIELDS = ("mass", "rest_length", "stiffness", "damping", "axis_rest_length", "correction_matrix",
                "rest_volume", "volume_stiffness", "young_modulus", "poisson_ratio", "density")
#: Preconditioners kept per process, keyed by the content of (model, reference positions, dt,
#: imposed dofs): the N copies of a vector env (and several vector envs) share them.
PRECONDITIONER_CACHE_SIZE = 64
_preconditioners: OrderedDict = OrderedDict()
#: Rows per dense product in the preconditioner: OpenBLAS runs products this small on one thread,
#: larger ones on all cores, which was measured 10-50x slower on a loaded 2-core machine.
BLAS_ROWS = 4


class ModelStack:
    """N copies of one block as one sim_core ``Model`` (``self.model``); ``assign(i, model)``
    puts a model of the same block (any material) into copy ``i``.

    Args:
        model: a model of the block (copied into every slot).
        count: number of copies N.
    """

    def __init__(self, model: Model, count: int):
        self.count = int(count)
        self.n_nodes = model.n_nodes
        self.n_springs = len(model.springs)
        self.n_elements = model.mesh.n_elements
        self.reference = model
        nodes = np.tile(model.mesh.nodes, (count, 1))
        offsets = np.arange(count)[:, None, None]
        elements = (model.mesh.elements[None] + self.n_nodes * offsets).reshape(-1, 8)
        springs = (model.springs[None] + self.n_nodes * offsets).reshape(-1, 2)
        edge_spring = (model.edge_spring[None] + self.n_springs * offsets).reshape(-1, 12)
        hourglass = None
        if model.hourglass is not None:
            single = model.hourglass
            self.hourglass_nnz = single.nnz
            rows = 3 * self.n_nodes
            indptr = np.concatenate([[0], (single.indptr[1:][None] + single.nnz * np.arange(count)[:, None]).ravel()])
            indices = (single.indices[None] + rows * np.arange(count)[:, None]).ravel()
            hourglass = sp.csr_matrix((np.tile(single.data, count), indices, indptr),
                                      shape=(rows * count, rows * count))
        values = {name: np.concatenate([getattr(model, name)] * count) for name in VALUE_FIELDS}
        self.model = Model(
            mesh=HexMesh(nodes, elements), name=model.name, springs=springs, edge_spring=edge_spring,
            correction_mode=model.correction_mode, gravity=model.gravity.copy(), hourglass=hourglass,
            options=dict(model.options), **values,
        )
        # slots of each copy in the per-dof arrays the Model derived at construction
        self._mass_positions = self.model.pattern.diagonal_positions.reshape(count, -1)
        self.models = [model] * count
        self._hourglass_keys = [_digest(model.hourglass.data) if model.hourglass is not None else None] * count
        self._hourglass_by_key = {self._hourglass_keys[0]: model.hourglass}
        self._hourglass_groups = None

    def _check(self, model: Model):
        same = (model.n_nodes == self.n_nodes and len(model.springs) == self.n_springs
                and model.mesh.n_elements == self.n_elements and model.correction_mode == self.reference.correction_mode
                and (model.hourglass is None) == (self.reference.hourglass is None)
                and np.array_equal(model.springs, self.reference.springs)
                and np.array_equal(model.mesh.elements, self.reference.mesh.elements))
        if not same:
            raise ValueError("ModelStack.assign needs a model of the same block (mesh, springs, options)")

    def assign(self, index: int, model: Model):
        """Copy ``model``'s values into copy ``index`` (a no-op when it is already there)."""
        if self.models[index] is model:
            return
        self._check(model)
        stacked = self.model
        for name in VALUE_FIELDS:
            single = getattr(model, name)
            getattr(stacked, name)[index * len(single):(index + 1) * len(single)] = single
        nodes = slice(index * self.n_nodes, (index + 1) * self.n_nodes)
        stacked.gravity_force[nodes] = model.gravity_force
        stacked.mass_data[self._mass_positions[index]] = np.repeat(model.mass, 3)
        if model.hourglass is not None:
            data = slice(index * self.hourglass_nnz, (index + 1) * self.hourglass_nnz)
            stacked.hourglass.data[data] = model.hourglass.data
            if stacked.hourglass_arrays[2] is not stacked.hourglass.data:
                stacked.hourglass_arrays[2][data] = model.hourglass.data
            key = _digest(model.hourglass.data)
            self._hourglass_by_key.setdefault(key, model.hourglass)
            self._hourglass_keys[index] = key
            self._hourglass_groups = None
        self.models[index] = model

    def hourglass_groups(self):
        """[(single-copy hourglass matrix, copy indices)] grouping the copies with equal matrices."""
        if self._hourglass_groups is None:
            keys = self._hourglass_keys
            self._hourglass_groups = [] if keys[0] is None else [
                (self._hourglass_by_key[key], np.array([i for i, k in enumerate(keys) if k == key]))
                for key in dict.fromkeys(keys)]
            used = set(keys)
            self._hourglass_by_key = {k: m for k, m in self._hourglass_by_key.items() if k in used}
        return self._hourglass_groups


def stacked_internal_forces(stack: ModelStack, positions, velocities=None, springs=None, push=None):
    """(N * n, 3) ``sim_core.forces.internal_forces`` of the stacked model, with the hourglass term
    as one sparse product per group of equal copies (the stacked CSR product was measured 4x
    slower); the other terms are sim_core's."""
    model = stack.model
    forces = internal_forces(model, positions, velocities, springs=springs, push=push, hourglass=False)
    groups = stack.hourglass_groups()
    if groups:
        displacement = (positions - model.rest_positions).reshape(stack.count, -1)
        rows = forces.reshape(stack.count, -1)
        for matrix, copies in groups:
            rows[copies] -= (matrix @ displacement[copies].T).T
    return forces


def _digest(array) -> bytes:
    return hashlib.blake2b(np.ascontiguousarray(array).tobytes(), digest_size=16).digest()


def _inverse_system(model, positions, dt, fixed):
    """(free dofs, transposed dense inverse) of the implicit system matrix on the free dofs."""
    free = np.flatnonzero(~fixed.ravel())
    data = stiffness_data(model, positions, volume=False, clamp=True, stiffness_scale=dt * dt,
                          damping_scale=dt, mass_scale=1.0)
    factor = spla.splu(model.pattern.matrix(data).tocsr()[free][:, free].tocsc())
    # column by column: SuperLU's one-vector solves stay on one thread (np.linalg.inv and
    # many-column solves use threaded BLAS, measured 10-50x slower on a loaded 2-core machine)
    identity = np.eye(len(free))
    inverse = np.stack([factor.solve(identity[:, j]) for j in range(len(free))], axis=1)
    return free, np.ascontiguousarray(inverse.T)


def _rows_dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class BatchedImplicitEuler:
    """sim_core's linearised implicit Euler on a ``ModelStack``, one preconditioned BiCGSTAB per
    copy run in lockstep (see the module docstring).

    Args:
        stack: the ``ModelStack``.
        tolerance: relative residual ||r|| / ||b|| each copy's linear solve reaches.
        max_iterations: cap on each copy's solver iterations.
    """

    def __init__(self, stack: ModelStack, tolerance: float = 1e-4, max_iterations: int = 200,
                 refresh_iterations: int = 8, solver: str = "reference"):
        if solver not in ("reference", "jacobi"):
            raise ValueError(f"solver must be 'reference' or 'jacobi', got {solver!r}")
        self.stack = stack
        self.solver = solver
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.refresh_iterations = int(refresh_iterations)
        #: iterations before a stalled copy is re-linearised and solved again
        self.first_pass = min(30, self.max_iterations // 2)
        self.refreshes = 0
        count, dofs = stack.count, 3 * stack.n_nodes
        self.warm = np.zeros((count, dofs))
        self._preconditioners = [None] * count
        self._groups = None
        model = stack.model
        self._zero_mass = np.zeros_like(model.mass)
        self._zero_damping = np.zeros_like(model.damping)
        self.last_iterations = np.zeros(count, dtype=int)

    # -- preconditioner ------------------------------------------------------------------------------
    def prepare(self, index: int, model: Model, positions: np.ndarray, dt: float, fixed: np.ndarray):
        """Start an episode of copy ``index``: clear its warm start and (solver "reference") set its
        preconditioner, the inverse of its system matrix M + dt D + dt^2 K (K at ``positions``
        (n, 3) m, the episode's start; geometric terms clamped as the integrator does) on the dofs
        not in ``fixed`` (n, 3). Shared (cached) between copies and episodes that start alike."""
        self.warm[index] = 0.0
        if self.solver != "reference":
            return
        digest = hashlib.blake2b(digest_size=16)
        for array in (model.stiffness, model.damping, model.mass, model.correction_matrix, model.volume_stiffness,
                      model.young_modulus, model.poisson_ratio, np.ascontiguousarray(positions), fixed,
                      np.array([dt, model.n_nodes, len(model.springs)])):
            digest.update(np.ascontiguousarray(array).tobytes())
        key = digest.digest()
        entry = _preconditioners.get(key)
        if entry is None:
            entry = _preconditioners[key] = _inverse_system(model, positions, dt, fixed)
            if len(_preconditioners) > PRECONDITIONER_CACHE_SIZE:
                _preconditioners.popitem(last=False)
        else:
            _preconditioners.move_to_end(key)
        self._use(index, entry)

    def _use(self, index, entry):
        if self._preconditioners[index] is not entry:
            self._preconditioners[index] = entry
            self._groups = None

    def _refresh(self, index, positions, dt, fixed):
        """Re-linearise copy ``index``'s preconditioner at its current ``positions``: after large
        tool motions the start matrix is a poorer approximation and its solver needs more
        iterations, which all copies wait for (measured: 6 -> 20 iterations over 150 random steps
        without refresh, about 7 with it)."""
        self._use(index, _inverse_system(self.stack.models[index], positions, dt, fixed))
        self.refreshes += 1

    def _group(self):
        if self._groups is None:
            groups = {}
            for index, entry in enumerate(self._preconditioners):
                groups.setdefault(id(entry), (entry, []))[1].append(index)
            self._groups = [(entry, np.array(indices)) for entry, indices in groups.values()]
        return self._groups

    def _precondition(self, vectors, mask):
        out = np.zeros_like(vectors)
        for (free, inverse_t), rows in self._group():
            every = len(rows) == len(vectors)
            reduced = vectors[:, free] if every else vectors[rows][:, free]
            product = np.concatenate([reduced[k:k + BLAS_ROWS] @ inverse_t
                                      for k in range(0, len(rows), BLAS_ROWS)])
            if every:
                out[:, free] = product
            else:
                out[rows[:, None], free] = product
        out *= mask
        return out

    # -- step ------------------------------------------------------------------------------------------
    def simulate(self, positions, velocities, fixed, target, dt, active):
        """One step of every copy in ``active`` (N,) bool; the others keep their state.

        Args:
            positions, velocities: (N, n, 3) m, m/s.  fixed: (N, n, 3) bool imposed components.
            target: (N, n, 3) imposed positions, m (read where fixed).  dt: s.
        Returns: (positions, velocities) (N, n, 3), new arrays.
        """
        model = self.stack.model
        count, n_nodes = positions.shape[:2]
        x0 = np.ascontiguousarray(positions.reshape(-1, 3), dtype=float)
        v0 = np.ascontiguousarray(velocities.reshape(-1, 3), dtype=float)
        springs, push = spring_state(model, x0)
        forces = stacked_internal_forces(self.stack, x0, v0, springs=springs, push=push) + model.gravity_force
        n_blocks = len(model.node_indices)
        system = np.empty((n_blocks, 3, 3))
        stiffness = np.empty((n_blocks, 3, 3))
        kernels.assemble_implicit(model.block_of_spring, n_blocks, model.diagonal_block, springs.unit,
                                  springs.length, springs.tension, model.stiffness, model.damping, model.mass,
                                  dt, True, system)
        kernels.assemble_implicit(model.block_of_spring, n_blocks, model.diagonal_block, springs.unit,
                                  springs.length, springs.tension, model.stiffness, self._zero_damping,
                                  self._zero_mass, 1.0, True, stiffness)
        coupled = model.correction_mode is not None
        edge_unit = np.zeros((model.mesh.n_elements, 12, 3))
        if coupled:
            kernels.edge_units(x0, model.mesh.elements, edge_unit)
        # the volume forces' rank-one stiffness, implicit as in sim_core's ImplicitEuler
        implicit_volume = model.has_volume_forces
        n_elements = model.mesh.n_elements
        volume_terms = (np.zeros(n_elements), np.zeros((n_elements, 8, 3)), np.zeros((n_elements, 8, 3)))
        if implicit_volume:
            kernels.volume_jacobian_terms(x0, model.mesh.elements, model.rest_volume, model.volume_stiffness,
                                          *volume_terms)
        hg_indptr, hg_indices, hg_data = model.hourglass_arrays
        hourglass_groups = self.stack.hourglass_groups()
        dofs = x0.size

        def apply(blocks, scale, vector, mask):
            """mask * (blocks + scale (K_hourglass + K_coupling + K_volume)) @ vector (flat dof arrays). The
            hourglass term (a constant matrix) is one sparse product per group of copies with equal
            matrices, over all their vectors at once: 4x faster than the stacked matrix."""
            vector = np.ascontiguousarray(vector).reshape(-1)
            out = np.empty(dofs)
            kernels._operator(model.node_indptr, model.node_indices, blocks, hg_indptr, hg_indices, hg_data, 0.0,
                              model.mesh.elements, edge_unit, model.correction_matrix, model.axis_rest_length,
                              scale if coupled else 0.0, mask, vector, out, *volume_terms,
                              scale if implicit_volume else 0.0)
            vectors, rows, row_mask = vector.reshape(count, -1), out.reshape(count, -1), mask.reshape(count, -1)
            for matrix, copies in hourglass_groups:
                if len(copies) == count:
                    rows += scale * (matrix @ vectors.T).T * row_mask
                else:
                    rows[copies] += scale * (matrix @ vectors[copies].T).T * row_mask[copies]
            return out

        ones = np.ones(dofs)
        rhs = dt * (forces.ravel() - dt * apply(stiffness, 1.0, v0.ravel(), ones))
        free = ~fixed.reshape(-1)
        known = np.zeros(dofs)
        if not free.all():
            target_velocity = (target.reshape(-1, 3) - x0) / dt
            known[~free] = (target_velocity - v0).ravel()[~free]
            rhs = rhs - apply(system, dt * dt, known, ones)
        mask = free.astype(float)
        flat_mask = mask
        mask = mask.reshape(count, -1)

        def operator(vectors):
            return apply(system, dt * dt, vectors, flat_mask).reshape(count, -1)

        rhs = rhs.reshape(count, -1)
        if self.solver == "jacobi":
            solution, iterations = self._solve_each(system, edge_unit, rhs, mask, active, dt, coupled,
                                                    volume_terms if implicit_volume else None)
            stalled = np.zeros(count, dtype=bool)
        else:
            solution, iterations, converged = self._solve(operator, rhs, mask, active, self.warm, self.first_pass)
            # A copy whose start-of-episode preconditioner no longer fits (large deformation, a
            # contact change) stalls: re-linearise it here, exactly, and solve it again from there.
            stalled = active & ~converged & np.all(np.isfinite(solution), axis=1)
        if stalled.any():
            for index in np.flatnonzero(stalled):
                self._refresh(index, x0.reshape(count, n_nodes, 3)[index], dt, fixed[index])
            again, more, _ = self._solve(operator, rhs, mask, stalled, solution,
                                         self.max_iterations - self.first_pass)
            solution = np.where(stalled[:, None], again, solution)
            iterations = iterations + more
        self.warm = np.where(active[:, None], solution, self.warm)
        self.last_iterations = iterations
        dv = np.where(free, solution.ravel(), known)
        new_velocities = v0 + dv.reshape(-1, 3)
        new_positions = x0 + dt * new_velocities
        imposed = fixed.reshape(-1, 3)
        new_velocities[imposed] = ((target.reshape(-1, 3) - x0) / dt)[imposed]
        new_positions[imposed] = target.reshape(-1, 3)[imposed]
        new_positions = new_positions.reshape(count, n_nodes, 3)
        new_velocities = new_velocities.reshape(count, n_nodes, 3)
        keep = ~active
        new_positions[keep] = positions[keep]
        new_velocities[keep] = velocities[keep]
        if (self.solver == "reference" and self.refresh_iterations and not stalled.any()
                and iterations.max() > self.refresh_iterations):
            worst = int(np.argmax(iterations))  # one per step: a refresh costs about one batched step
            if np.all(np.isfinite(new_positions[worst])):
                self._refresh(worst, new_positions[worst], dt, fixed[worst])
        return new_positions, new_velocities

    def _solve_each(self, system, edge_unit, rhs, mask, active, dt, coupled, volume_terms=None):
        """sim_core's own compiled solve (Jacobi-preconditioned BiCGSTAB, ``kernels.solve_implicit``)
        on each copy's slice of the stacked system: what its ``ImplicitEuler`` does, minus the
        per-step Python work, which the batch shares."""
        stack = self.stack
        blocks_per_copy = len(system) // stack.count
        solution = np.zeros_like(rhs)
        iterations = np.zeros(stack.count, dtype=int)
        for index in np.flatnonzero(active):
            model = stack.models[index]
            hg_indptr, hg_indices, hg_data = model.hourglass_arrays
            blocks = system[index * blocks_per_copy:(index + 1) * blocks_per_copy]
            elements = slice(index * stack.n_elements, (index + 1) * stack.n_elements)
            solution[index], iterations[index], _ = kernels.solve_implicit(
                model.node_indptr, model.node_indices, blocks, model.diagonal_block, hg_indptr, hg_indices, hg_data,
                dt * dt if model.hourglass is not None else 0.0, model.mesh.elements, edge_unit[elements],
                model.correction_matrix, model.axis_rest_length, dt * dt if coupled else 0.0, mask[index],
                rhs[index] * mask[index], self.warm[index], self.tolerance, self.max_iterations,
                not (coupled or volume_terms is not None),
                *((term[elements] for term in volume_terms) if volume_terms is not None
                  else (np.zeros(stack.n_elements), np.zeros((stack.n_elements, 8, 3)),
                        np.zeros((stack.n_elements, 8, 3)))),
                dt * dt if volume_terms is not None else 0.0)
        return solution, iterations

    def _solve(self, operator, rhs, mask, active, guess, max_iterations):
        """Right-preconditioned BiCGSTAB per row (the algorithm of sim_core's solve_implicit) for
        the ``active`` rows, all in lockstep from ``guess``. A row that has converged (or broken
        down) gets zero step lengths, so the shared vector operations leave it unchanged.
        Returns (solutions, iterations, converged) per row."""
        tolerance = self.tolerance
        count = len(rhs)
        b = rhs * mask
        x = guess * mask
        finite = np.all(np.isfinite(b), axis=1)
        b[~finite] = 0.0  # a diverged copy: reported as NaN below, never mixed into the others
        r = b - operator(x)
        norm_b = np.sqrt(_rows_dot(b, b))
        safe_norm = np.where(norm_b == 0.0, 1.0, norm_b)
        x[norm_b == 0.0] = 0.0
        residual = np.sqrt(_rows_dot(r, r)) / safe_norm
        running = active & finite & (norm_b > 0.0) & (residual > tolerance)
        iterations = np.zeros(count, dtype=int)
        r_hat = r.copy()
        rho = np.ones(count)
        alpha = np.zeros(count)
        omega = np.ones(count)
        v = np.zeros_like(r)
        p = np.zeros_like(r)
        with np.errstate(all="ignore"):
            while running.any():
                rho_new = _rows_dot(r_hat, r)
                running &= (rho_new != 0.0) & (omega != 0.0)
                beta = np.where(running, (rho_new / rho) * (alpha / omega), 0.0)
                rho = np.where(running, rho_new, rho)
                p = r + beta[:, None] * (p - omega[:, None] * v)
                p_hat = self._precondition(p, mask)
                v = operator(p_hat)
                denominator = _rows_dot(r_hat, v)
                running &= np.isfinite(denominator) & (denominator != 0.0)
                alpha = np.where(running, rho / denominator, 0.0)
                s = r - alpha[:, None] * v
                iterations += running
                s_residual = np.sqrt(_rows_dot(s, s)) / safe_norm
                early = running & (s_residual <= tolerance)
                x += np.where(early, alpha, 0.0)[:, None] * p_hat
                r = np.where(early[:, None], s, r)
                residual = np.where(early, s_residual, residual)
                running &= ~early
                if not running.any():
                    break
                s_hat = self._precondition(s, mask)
                t = operator(s_hat)
                tt = _rows_dot(t, t)
                omega = np.where(running & (tt > 0), _rows_dot(t, s) / np.where(tt > 0, tt, 1.0), 0.0)
                step = np.where(running, alpha, 0.0)
                x += step[:, None] * p_hat + omega[:, None] * s_hat
                r = np.where(running[:, None], s - omega[:, None] * t, r)
                residual = np.where(running, np.sqrt(_rows_dot(r, r)) / safe_norm, residual)
                running &= np.isfinite(residual) & (residual > tolerance) & (iterations < max_iterations)
                omega = np.where(running, omega, 1.0)
        x[active & ~finite] = np.nan
        converged = (norm_b == 0.0) | (residual <= tolerance)
        return x, iterations, converged


class BatchedSymplecticEuler:
    """sim_core's symplectic Euler on a ``ModelStack`` (every operation is per node, so the
    stacked step is exactly N single steps)."""

    def __init__(self, stack: ModelStack):
        self.stack = stack
        self._integrator = SymplecticEuler(monitor=False)
        self.last_iterations = np.zeros(stack.count, dtype=int)

    def prepare(self, index, model, positions, dt, fixed):
        pass

    def simulate(self, positions, velocities, fixed, target, dt, active):
        count, n_nodes = positions.shape[:2]
        state = State(np.ascontiguousarray(positions.reshape(-1, 3), dtype=float),
                      np.ascontiguousarray(velocities.reshape(-1, 3), dtype=float))
        out = state.copy()
        control = Control(fixed.reshape(-1, 3), target.reshape(-1, 3), np.zeros((count * n_nodes, 3)))
        self._integrator.simulate(self.stack.model, state, out, dt, control)
        new_positions = out.positions.reshape(count, n_nodes, 3)
        new_velocities = out.velocities.reshape(count, n_nodes, 3)
        keep = ~active
        new_positions[keep] = positions[keep]
        new_velocities[keep] = velocities[keep]
        return new_positions, new_velocities


def make_batched_integrator(name: str, stack: ModelStack, tolerance: float, solver: str = "reference"):
    if name == "implicit":
        return BatchedImplicitEuler(stack, tolerance=tolerance, solver=solver)
    if name == "explicit":
        return BatchedSymplecticEuler(stack)
    raise ValueError(f"integrator must be 'implicit' or 'explicit', got {name!r}")


def new_monitor(model: Model) -> DivergenceMonitor:
    """The divergence monitor sim_core's integrators use, for one copy."""
    return DivergenceMonitor(model)
