"""Linearised implicit Euler (Baraff and Witkin 1998) for one world or N worlds of one scene
stepped together (``ImplicitEuler``), one linear solve per world and step:

    (M + dt D + dt^2 K) dv = dt (f(x0, v0) - dt K v0),   v1 = v0 + dv,   x1 = x0 + dt v1.

K holds the springs (geometric term clamped at zero), the corrections' push along the current
edges and their strain coupling, the volume forces' rank-one stiffness and, for
"baudet-hyperelastic", the stress correction's element blocks clamped to their positive part
(docs/physics.md sections 3 and 11). The coupling and the volume terms are not symmetric: each
world's system is solved by a right-preconditioned BiCGSTAB on the compiled matrix-free operator,
stopped at ||r|| <= tolerance ||b||.

N worlds are one ``ModelStack``: the worlds share one topology (the task's block), so they are one
sim_core ``Model`` on a mesh made of N disjoint copies of the block. A world whose material
changes overwrites its slot; nothing is rebuilt. One world is the stack of one (``WorldsSolver``'s
one-world case): studies, validation and the environments run the same step.

A step is one fused force pass over the stacked model (``kernels.model_forces``: forces, clamped
geometric stiffness, volume terms, through a ``StackedForceWorkspace``; with more than one thread
one copy per thread, ``kernels.model_forces_copies``), the right-hand side's operator product per
copy (``kernels.apply_copies``) and the copies' BiCGSTABs in one compiled call
(``kernels.solve_copies_lu``: the copies one at a time on numba's threads, each with its own
scratch, so any thread count gives the same floats; one thread, and a forked process: the
``_serial`` twins). No Python loop over copies in the step (but for factorisations and
capacitance corrections).

Preconditioners (``PRECONDITIONERS``), each copy its own:
- "jacobi": the inverse diagonal of its system (``kernels.jacobi_copies``), recomputed each step.
  Its iteration count grows with resolution, stiffness and dt.
- "factorised": the sparse factor of its free-dof system matrix (``kernels.operator_matrix_data``,
  the matrix of the matrix-free operator; in node blocks the LDL^T of its symmetric part
  (``SYMMETRIC_FACTOR``: the matrix is symmetric up to about 1e-4 of its entries, and the
  symmetric factor holds, factorises and applies half the values of the LU:
  ``sparse.NodeBlockLU(symmetric=True)``, ``kernels.block_ldl_factor``), through
  ``preconditioners.node_block_factor``, else SuperLU's scalar LU), kept across steps and
  re-factorised at the current state when a solve needs more than max(REFACTOR_MIN, 2 x the
  iterations right after the last factorisation) (the one refactor rule; ``amortise`` adds a
  budget of excess iterations). A contact that imposes more dofs keeps the factor, restricted
  exactly to the free dofs by a capacitance correction; the copies a step re-factorises are
  assembled and factorised in one compiled call (``kernels.factor_copies``). 1-5 iterations.
- "auto" (the default): "jacobi" until a copy's solve has not converged after
  ``auto_switch_iterations(free dofs)`` iterations (the measured crossing of the two step
  times), then "factorised" for the rest of the copy's episode (that step continues from its
  iterate with the factor).
- "reference": the sparse factor of the copy's system matrix at the start of its episode, applied
  by triangular solves (``sparse.NodeBlockLU`` in node blocks, as above). Copies that start alike
  share one factor (one cache entry) and the copies that share one are solved in lockstep chunks
  (``lockstep_chunk``, ``kernels.solve_copies_grouped``), so that a triangular solve reads a shared
  factor once for all the chunk's running copies of it; a copy's floats do not depend on its
  chunk, so any thread count gives the same trajectories. A copy that needed more than
  ``refresh_iterations`` iterations is re-linearised at its new state, and a copy that has not
  converged after ``first_pass`` iterations is re-linearised and solved again; a re-linearised
  copy leaves its group.
The step's force pass at a state is computed once (``ImplicitEuler.linearise``): a vector env that
measures with it (``share_force_pass``) gives the next step its forces and linearisation. The
trajectories of N worlds equal those of N single worlds up to the solvers' tolerance
(tests/test_solver_contract.py, tests/test_env_vector.py). SI units.
"""

from __future__ import annotations

import hashlib

import numpy as np
import scipy.sparse as sp
from numba.typed import List as TypedList

from .. import kernels
from ..caches import BudgetCache
from ..models.model import Model
from .schemes import check_scheme, damping_groups, scheme_advance, stage_dt
from .solver import WorldsSolver
from .factors import SYMMETRIC_FACTOR, CopyFactor, copies_structure, system_factor
from .preconditioners import (AUTO_MAX_DOFS, CAPACITANCE_MAX, REFACTOR_MIN, FreeStructure,
                              auto_switch_iterations, node_block_factor)
from ..models.sparse import edge_incidence
from ..models.stack import ModelStack, StackedForceWorkspace

#: Start-of-episode preconditioners an integrator keeps, keyed by the content of (model, reference
#: positions, dt, imposed dofs): its N copies share them across episodes.
PRECONDITIONER_CACHE_SIZE = 64
#: The implicit step's preconditioners (module docstring); "auto" is the default.
PRECONDITIONERS = ("auto", "factorised", "jacobi", "reference")
#: ``lu_apply``'s packed form of a Jacobi preconditioner (its floats: the copy's inverse diagonal)
JACOBI_INTS = np.array([0, 1], dtype=np.int64)
#: Solver "reference": at most this many copies per lockstep chunk on several threads, and on one
#: (``lockstep_chunk``).
LOCKSTEP_CHUNK = 8
SERIAL_LOCKSTEP_CHUNK = 16


def lockstep_chunk(count: int, threads: int = 2) -> int:
    """Copies per lockstep chunk of solver "reference" (``kernels.solve_copies_grouped``) for
    ``count`` copies solved on ``threads`` threads. Several: half of them (two chunks, one for each
    of two threads: a single chunk on two threads is slower than solving per copy), at most
    ``LOCKSTEP_CHUNK`` (more copies give more chunks for more threads). One: all of them, at most
    ``SERIAL_LOCKSTEP_CHUNK`` (a pass over a shared factor for 16 copies costs less than two for 8:
    benchmarks/vector_env_speed.py). A copy's floats do not depend on its chunk (the substitutions
    of every right-hand side are the same arithmetic: tests/test_batched_fused.py), so the thread
    count does not change the trajectories."""
    if threads <= 1:
        return max(1, min(SERIAL_LOCKSTEP_CHUNK, count))
    return max(1, min(LOCKSTEP_CHUNK, (count + 1) // 2))


class _TypedItems(list):
    """A numba typed List's items in a plain list: how a solver's typed lists pickle and copy."""


def _mapped(value, memo, kind, make):
    """``value`` with its items of type ``kind`` (also inside tuples) replaced by ``make(item)``, each
    item once: numba typed Lists to ``_TypedItems`` for pickling, and back."""
    if isinstance(value, kind):
        if id(value) not in memo:
            memo[id(value)] = make(value)
        return memo[id(value)]
    if isinstance(value, tuple):  # a named tuple (kernels.OperatorData) stays one: numba types it by its class
        items = [_mapped(item, memo, kind, make) for item in value]
        return type(value)(*items) if hasattr(value, "_fields") else tuple(items)
    return value


class ImplicitEuler(WorldsSolver):
    """Linearised implicit Euler on one world (a ``Model``, or None and ``bind`` later) or on the
    N worlds of a ``ModelStack``: one preconditioned BiCGSTAB per world and step; see the module
    docstring.

    Args:
        stack: the ``ModelStack`` of N worlds, or a ``Model`` (one world), or None (one world,
            ``bind`` it or name the model at ``simulate``).
        tolerance: relative residual ||r|| / ||b|| each world's linear solve reaches.
        max_iterations: cap on each world's solver iterations.
        preconditioner: "auto" (default), "factorised", "jacobi" or "reference"
            (``PRECONDITIONERS``).
        refresh_iterations: preconditioner "reference": a world whose step needs more iterations
            has its preconditioner re-linearised (0: never).
        amortise: preconditioner "factorised": see ``self.amortise``.
        threads: more than one runs the per-world kernels on numba's threads
            (``kernels.threaded``; the count they use is ``numba.get_num_threads()``), one their
            ``_serial`` versions; None: numba's ``NUMBA_NUM_THREADS``. One world runs on one.
        scheme: the time scheme (``schemes.SCHEMES``): "euler" (default: this linearised implicit
            Euler, numerical damping ratio about omega dt / 2), "trapezoidal" (no numerical damping,
            one solve) or "tr-bdf2" (numerical damping below 1e-3 up to omega dt = 0.4, stiff modes
            damped out; two solves) (docs/physics.md section 14).
    """

    name = "implicit"

    def __init__(self, stack: ModelStack | Model | None = None, tolerance: float = 1e-6, max_iterations: int = 200,
                 preconditioner: str = "auto", refresh_iterations: int = 8, amortise: int | None = None,
                 threads: int | None = None, scheme: str = "euler"):
        self.scheme = check_scheme(scheme)
        if preconditioner not in PRECONDITIONERS:
            raise ValueError(f"preconditioner must be one of {PRECONDITIONERS}, got {preconditioner!r}")
        if not float(tolerance) > 0:
            raise ValueError(f"tolerance must be > 0, got {tolerance}")
        if int(max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
        self.threads = kernels.available_threads() if threads is None else int(threads)
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1 or None, got {threads}")
        self.preconditioner = preconditioner
        #: preconditioner "factorised": None re-factorises a copy when a solve needs more than max(8, 2 x
        #: the iterations right after its last factorisation); an integer R also re-factorises it (at
        #: its next step) once its iterations beyond that baseline add up to more than R, and at once
        #: when a solve needs more than the baseline + 2 R
        self.amortise = None if amortise is None else int(amortise)
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.refresh_iterations = int(refresh_iterations)
        if self._one_world(stack):
            return
        self._start_worlds(stack, self.threads)
        #: iterations before a stalled copy is re-linearised and solved again ("reference")
        self.first_pass = min(30, self.max_iterations // 2)
        self.refreshes = 0
        self._factorisations = 0
        count, dofs = stack.count, 3 * stack.n_nodes
        self.warm = np.zeros((count, dofs))
        self._preconditioners = [None] * count
        # the preconditioners ("reference") and first-step factors ("factorised") kept for episodes
        # that start alike, by content (PRECONDITIONER_CACHE_SIZE each, within the "start_factors"
        # byte budget: sim_core.caches)
        self._kept_starts = BudgetCache("start_factors", PRECONDITIONER_CACHE_SIZE)
        self._kept_first = BudgetCache("start_factors", PRECONDITIONER_CACHE_SIZE)
        self._groups = None
        self.workspace = StackedForceWorkspace(stack, implicit=True, threads=self.threads)
        self._packed = None
        self._packed_groups = None
        self._linearised = None  # (stack version, positions) of the workspace's last force pass
        self._mass = None  # _dof_mass: (stack version, the copies' masses per dof (N, 3 n))
        self._first = None  # _copies_first: (stack version, arrays)
        if preconditioner == "reference":  # solve_copies_grouped's scratch; capacitance corrections: none
            self._group_work = np.empty((8, count, dofs))
            self._no_corrections = (TypedList([np.zeros((0, 0))] * count),
                                    TypedList([np.zeros(0, dtype=np.int64)] * count))
            return
        self._row_work = np.empty((8, dofs))  # solve_copies_lu's scratch
        identity = CopyFactor()
        self._factors = [None] * count
        self._pending = [None] * count  # (cache key, free dofs) of a copy's episode start
        self._factor_free = np.zeros((count, dofs), dtype=bool)  # the free set of each factor
        self._stale = np.zeros(count, dtype=bool)  # re-factorise at the next step
        self._factor_dt = np.full(count, np.nan)  # the time step of each factor's system (s)
        #: the copies preconditioned by Jacobi ("jacobi"; "auto" until a solve stalls), their inverse
        #: diagonals (N, 3 n) (``kernels.jacobi_copies``; their rows are their entries of _lu_float)
        self._jacobi = np.full(count, preconditioner in ("jacobi", "auto"))
        self._diagonal = np.zeros((count, dofs))
        # per copy (a factor may be shared): the iterations right after its factor was made, those
        # spent beyond them since (``amortise``), the iterations after which it is renewed, and
        # whether its factor came from the cache at its episode's start (its first solve then
        # counts as right after a factorisation, as it would have been without the cache)
        self._baseline = np.zeros(count, dtype=np.int64)
        self._excess = np.zeros(count, dtype=np.int64)
        self._threshold = np.full(count, REFACTOR_MIN, dtype=np.int64)
        self._adopted = np.zeros(count, dtype=bool)
        self._lu_int = TypedList([identity.ints] * count)
        self._lu_float = TypedList([identity.floats] * count)
        self._factor_of = np.arange(count, dtype=np.int64)
        #: each copy's capacitance correction (``CopyFactor.correction``) as the kernel takes it
        self._no_correction = (np.zeros((0, 0)), np.zeros(0, dtype=np.int64))
        self._correction_of = [self._no_correction] * count
        self._corrections = TypedList([self._no_correction[0]] * count)
        self._imposed = TypedList([self._no_correction[1]] * count)
        self._patterns = {}
        self._structures = {}  # kernels.factor_copies' structure per node set (``sparse.block_structure``)
        self._incidence = edge_incidence(stack.reference)
        #: factorise the LDL^T of the system matrix's symmetric part (``kernels.block_ldl_factor``)
        #: instead of its LU: half the values for every preconditioner application
        self.symmetric = SYMMETRIC_FACTOR
        reference = stack.reference
        self._hg_positions = reference.pattern.csr_positions(*reference.hourglass_arrays[:2])
        self._values = np.empty(reference.pattern.nnz)

    @property
    def factorisations(self) -> int:
        """The factorisations made so far (a diagnostic; one world: since its last ``reset``)."""
        if self.one_world:
            return sum(solver.factorisations for solver in self._worlds.values())
        return self._factorisations

    def __getstate__(self):  # numba's typed Lists do not pickle: their items do
        memo = {}
        return {name: _mapped(value, memo, TypedList, _TypedItems) for name, value in self.__dict__.items()}

    def __setstate__(self, state):
        memo = {}
        self.__dict__.update({name: _mapped(value, memo, _TypedItems, TypedList) for name, value in state.items()})
        # a Jacobi copy's list entry is a view of its row of _diagonal, which jacobi_copies rewrites
        # each step; pickling copied the two apart
        for index in np.flatnonzero(self.__dict__.get("_jacobi", ())):
            kernels.set_list_items(self._lu_int, self._lu_float, index, JACOBI_INTS, self._diagonal[index])

    # -- preconditioner ------------------------------------------------------------------------------
    def _options(self):
        return dict(tolerance=self.tolerance, max_iterations=self.max_iterations, preconditioner=self.preconditioner,
                    refresh_iterations=self.refresh_iterations, amortise=self.amortise, threads=self.threads,
                    scheme=self.scheme)

    def _prepare_shared(self, index: int, model: Model, positions: np.ndarray, dt: float, fixed: np.ndarray):
        """Start an episode of copy ``index``: clear its warm start and (solver "reference") set its
        preconditioner, the sparse LU of its system matrix M + dt D + dt^2 K (K at ``positions``
        (n, 3) m, the episode's start; geometric terms clamped as the integrator does) on the dofs
        not in ``fixed`` (n, 3) (``factors.system_factor``). Shared (cached) between copies and episodes that
        start alike: the copies holding the same factor form one group, solved together."""
        super()._prepare_shared(index, model, positions, dt, fixed)
        dt = stage_dt(self.scheme, dt)  # the scheme's solves are implicit Euler solves of this step
        self.warm[index] = 0.0
        if self.preconditioner in ("jacobi", "auto"):  # Jacobi from the episode's start
            self._use_jacobi(index)
            return
        digest = hashlib.blake2b(digest_size=16)
        for array in (model.stiffness, model.damping, model.mass, model.correction_matrix, model.volume_stiffness,
                      model.young_modulus, model.poisson_ratio, np.ascontiguousarray(positions), fixed,
                      np.array([dt, model.n_nodes, len(model.springs), *model.rayleigh])):
            digest.update(np.ascontiguousarray(array).tobytes())
        key = digest.digest()
        if self.preconditioner == "factorised":
            free = ~np.asarray(fixed, dtype=bool).ravel()
            kind = (key, "ldl" if self.symmetric else "lu")
            entry = self._kept_first.get(kind)
            if entry is None:  # factorised by the copy's first step, at this linearisation
                self._set_factor(index, None, free)
                self._pending[index] = (kind, free)
            else:  # the factor the copy's first step would make (if its imposed set is still ``fixed``)
                self._set_factor(index, entry, free)
                self._factor_dt[index] = dt
                self._pending[index] = None
            self._adopted[index] = entry is not None
            self._stale[index] = False  # a renewal the last episode asked for
            return
        entry = self._kept_starts.get(key)
        if entry is None:
            entry = self._kept_starts.put(key, system_factor(model, positions, dt, fixed))
        self._use(index, entry)

    def _use(self, index, entry):
        if self._preconditioners[index] is not entry:
            self._preconditioners[index] = entry
            self._groups = None

    def _refresh(self, index, positions, dt, fixed):
        """Re-linearise copy ``index``'s preconditioner at its current ``positions``: after large
        tool motions the start matrix is a poorer approximation and its solver needs more
        iterations, which all copies wait for (without refreshes the iteration count of random
        steps grows several-fold). The copy gets a factor of its own (it leaves its group)."""
        self._use(index, system_factor(self.stack.models[index], positions, dt, fixed))
        self.refreshes += 1

    def _group(self):
        if self._groups is None:
            groups = {}
            for index, entry in enumerate(self._preconditioners):
                if entry is not None:  # None: a world not stepped on the stacked arrays (its own topology)
                    groups.setdefault(id(entry), (entry, []))[1].append(index)
            self._groups = [(entry, np.array(indices)) for entry, indices in groups.values()]
        return self._groups

    # -- factorised preconditioner (solver "factorised") ---------------------------------------------
    def _set_factor(self, index, factor, free):
        self._jacobi[index] = False
        self._factors[index] = factor
        self._factor_free[index] = free
        if factor is not None:
            kernels.set_list_items(self._lu_int, self._lu_float, index, factor.ints, factor.floats)

    def _use_jacobi(self, index):
        """Copy ``index`` is preconditioned by its inverse diagonal (a row of ``_diagonal``, its
        entry of the factor lists) until ``_set_factor`` gives it a factor."""
        self._jacobi[index] = True
        self._factors[index] = None
        self._factor_free[index] = False
        self._stale[index] = False
        self._pending[index] = None
        kernels.set_list_items(self._lu_int, self._lu_float, index, JACOBI_INTS, self._diagonal[index])
        if self._correction_of[index] is not self._no_correction:
            self._correction_of[index] = self._no_correction
            kernels.set_list_items(self._corrections, self._imposed, index, *self._no_correction)

    def _set_baseline(self, copies, iterations):
        """The copies ``copies`` (N,) bool got their factor (made, or taken from the cache) and their
        first solve took ``iterations`` (N,): each is renewed once a solve needs more than
        max(REFACTOR_MIN, 2 x that) (``amortise``: that + 2 amortise, or once the excess iterations
        add up to amortise)."""
        baseline = iterations[copies].astype(np.int64)
        self._baseline[copies], self._excess[copies] = baseline, 0
        self._threshold[copies] = (np.maximum(REFACTOR_MIN, 2 * baseline) if self.amortise is None
                                   else baseline + 2 * self.amortise)

    def _factorise(self, index, system, free):
        """Factorise copy ``index``'s system matrix (``system``: the operator's scales) at the step's
        linearisation (the workspace's last force pass) on its ``free`` dofs (3 n,) bool."""
        reference = self.stack.reference
        single = kernels.copy_data(*self._copies_first(), np.int64(index))
        values = self._values
        kernels.operator_matrix_data(single, system, reference.spring_positions, reference.element_positions,
                                     self._hg_positions, reference.pattern.diagonal_positions, values)
        block = node_block_factor(self.stack.models[index], values, free, symmetric=self.symmetric)
        if block is not None:  # the node-block LU, its structure kept per node set
            factor = CopyFactor.refactored(block.ints, block.floats)
        else:
            factor = self._scalar_factor(values, free)
        self._factorisations += 1
        self._set_factor(index, factor, free)
        return factor

    def _factorise_copies(self, indices, system, covers):
        """``_factorise`` of the copies ``indices`` (T,) on their ``covers`` (T, 3 n) bool, the node-block
        LUs of the copies with one node set in one compiled call (``kernels.factor_copies``: the same
        assembly and numeric factorisation, the same floats, without a Python round trip per copy);
        a copy whose node-block LU fails (a zero or non-finite pivot) goes through ``_factorise``
        (SuperLU's scalar factor). Returns the copies' new factors (T,)."""
        factors = [None] * len(indices)
        if len(indices) == 0:
            return factors
        nodes = covers.reshape(len(indices), -1, 3).any(axis=2)
        groups = {}
        for t in range(len(indices)):
            groups.setdefault(nodes[t].tobytes(), []).append(t)
        stacked, hg_rows, hg_group = self._copies_first()
        reference = self.stack.reference
        for key, members in groups.items():
            members = np.array(members)
            structure = self._block_structure(key, nodes[members[0]])
            ok = np.zeros(len(members), dtype=bool)
            if structure is not None:
                (node_dofs, take, rows, columns, a_map, a_indptr, a_indices, l_indptr, l_indices, u_indptr, u_indices,
                 a_transpose, l_to_u, ints, a_values, work) = structure
                factorise = kernels.variant(kernels.factor_copies, self.threads)
                factorise(stacked, system, hg_rows, hg_group, reference.spring_positions, reference.element_positions,
                          self._hg_positions, reference.pattern.diagonal_positions, indices[members],
                          covers[members], node_dofs, take, rows, columns, a_map, a_indptr, a_indices, l_indptr,
                          l_indices, u_indptr, u_indices, a_transpose, l_to_u, ints, self._values, a_values, work,
                          self._lu_int, self._lu_float, ok, *self._incidence)
            for t, done in zip(members, ok):
                index = int(indices[t])
                if done:  # the kernel set the copy's entries of _lu_int and _lu_float
                    factor = CopyFactor.refactored(ints, self._lu_float[index])
                    self._jacobi[index] = False
                    self._factors[index] = factor
                    self._factor_free[index] = covers[t]
                    self._factorisations += 1
                else:
                    factor = self._factorise(index, system, covers[t])
                factors[t] = factor
        self._factor_dt[indices] = system[1]
        # what each was computed from (``rebuild_factor``): the copy's linearised positions, the
        # operator's scales and the dofs it covers
        linearised = self._linearised[1].reshape(self.stack.count, -1, 3)
        for t, factor in enumerate(factors):
            factor.source = ("linearised", linearised[indices[t]].copy(), tuple(system), covers[t].copy())
        return factors

    def rebuild_factor(self, index: int, source):
        """The preconditioner factor a factor's ``source`` describes, computed again (the same
        floats) on world ``index``'s model: a pickled snapshot of a world's solver state carries the
        sources of its factors, not the factors (megabytes each). Solver "factorised" also makes it
        copy ``index``'s factor, as ``_factorise_copies`` does (the caller then restores the copy's
        state)."""
        if source[0] == "system":
            return system_factor(self.stack.models[index], *source[1:])
        _, positions, system, covers = source
        flat = np.array(self.stack.model.rest_positions, dtype=float)
        flat.reshape(self.stack.count, -1, 3)[index] = positions
        self.linearise(flat)
        factor = self._factorise_copies(np.array([index], dtype=np.int64), system, np.asarray(covers)[None])[0]
        self._linearised = None  # the other copies were linearised at rest positions
        return factor

    def _block_structure(self, key, nodes):
        """``kernels.factor_copies``' structure for the whole nodes ``nodes`` (n,) bool (``key`` their
        bytes; ``factors.copies_structure``), kept per node set; None where it has no node or its
        symbolic factor fails."""
        if key in self._structures:
            return self._structures[key]
        structure = copies_structure(self.stack.reference, nodes, self.symmetric)
        if len(self._structures) >= 4 * self.stack.count:
            self._structures.clear()
        self._structures[key] = structure
        return structure

    def _correct(self, indices, free_rows):
        """Set the capacitance correction of the copies ``indices`` whose node-block factor's free set
        holds dofs imposed now (``free_rows`` (N, 3 n) bool), at most CAPACITANCE_MAX (more: the
        factor masked, as before); the others get none."""
        dofs = free_rows.shape[1]
        held = self._factor_free[indices] & ~free_rows[indices]
        counts = np.count_nonzero(held, axis=1)
        wanted = []  # (copy, its factor, the dofs to correct for)
        for row, index in enumerate(indices):
            factor = self._factors[index]
            if 0 < counts[row] <= CAPACITANCE_MAX and factor.ints[0] < 0:
                wanted.append((index, factor, np.flatnonzero(held[row])))
            elif self._correction_of[index] is not self._no_correction:
                self._correction_of[index] = self._no_correction
                kernels.set_list_items(self._corrections, self._imposed, index, *self._no_correction)
        self._inverse_columns(wanted, dofs)
        self._form_corrections(wanted, dofs)
        for index, factor, imposed in wanted:
            entry = factor.correction(imposed, dofs) or self._no_correction
            if self._correction_of[index] is not entry:
                self._correction_of[index] = entry
                kernels.set_list_items(self._corrections, self._imposed, index, *entry)

    def _inverse_columns(self, wanted, dofs):
        """Solve the columns of the inverse that the corrections ``wanted`` ([(copy, factor, imposed
        dofs)]) need and their factors do not keep yet, all copies in one compiled call on numba's
        threads (``kernels.inverse_columns_copies``: each copy's columns together, as
        ``InverseColumns.columns`` solves them), and keep them. Copies that share a factor ask its
        inverse once, for the union of their dofs (asked one after the other, a later request that
        overflows the kept columns would forget those an earlier one counted on)."""
        needed = {}  # id(inverse) -> (a copy with that factor, the inverse, its copies' imposed dofs)
        for index, factor, imposed in wanted:
            if not factor.has_correction(imposed):
                inverse = factor.inverse(dofs)
                needed.setdefault(id(inverse), (index, inverse, []))[2].append(imposed)
        tasks = []
        for index, inverse, imposed in needed.values():
            missing = inverse.missing(imposed[0] if len(imposed) == 1 else np.unique(np.concatenate(imposed)))
            if missing.size:
                tasks.append((index, inverse, missing))
        if not tasks:
            return
        copies = np.array([index for index, _, _ in tasks], dtype=np.int64)
        indptr = np.zeros(len(tasks) + 1, dtype=np.int64)
        np.cumsum([len(missing) for _, _, missing in tasks], out=indptr[1:])
        flat = np.concatenate([missing for _, _, missing in tasks])
        out = np.zeros((len(flat), dofs))
        kernels.variant(kernels.inverse_columns_copies, self.threads)(self._lu_int, self._lu_float, copies, indptr,
                                                                      flat, out)
        for t, (_, inverse, missing) in enumerate(tasks):
            inverse.store(missing, out[indptr[t]:indptr[t + 1]])

    def _form_corrections(self, wanted, dofs):
        """Form the corrections W that ``wanted`` ([(copy, factor, imposed dofs)], their columns of the
        inverse kept) need and their factors do not keep yet, all in one compiled call on numba's
        threads (``kernels.capacitance_corrections``), and keep them in their factors."""
        tasks = {}
        for _, factor, imposed in wanted:
            if not factor.has_correction(imposed):
                tasks.setdefault((id(factor), imposed.tobytes()), (factor, imposed))
        if not tasks:
            return
        tasks = list(tasks.values())
        indptr = np.zeros(len(tasks) + 1, dtype=np.int64)
        np.cumsum([len(imposed) for _, imposed in tasks], out=indptr[1:])
        columns = np.concatenate([factor.inverse(dofs).rows(imposed) for factor, imposed in tasks])
        flat = np.concatenate([imposed for _, imposed in tasks]).astype(np.int64)
        out = np.empty(dofs * indptr[-1])
        ok = np.zeros(len(tasks), dtype=bool)
        kernels.variant(kernels.capacitance_corrections, self.threads)(columns, indptr, flat, out, ok)
        for t, (factor, imposed) in enumerate(tasks):
            correction = out[dofs * indptr[t]:dofs * indptr[t + 1]].reshape(dofs, -1) if ok[t] else None
            factor.keep_correction(imposed, correction)

    def _scalar_factor(self, values, free):
        """SuperLU's scalar factor of the system matrix (pattern ``values``) on the ``free`` dofs, for
        where the node-block LU fails (a zero or non-finite pivot: only diverging states were seen
        to); the identity where SuperLU fails too."""
        key = free.tobytes()
        pattern = self._patterns.get(key)
        if pattern is None:
            if len(self._patterns) >= 4 * self.stack.count:
                self._patterns.clear()
            pattern = self._patterns[key] = FreeStructure(self.stack.reference, np.flatnonzero(free))
        matrix = sp.csc_matrix((values[pattern.take], pattern.indices, pattern.indptr), shape=pattern.shape)
        try:
            with np.errstate(all="ignore"):
                factor = CopyFactor(matrix, pattern.free)
            factor.lu = factor.lower = factor.upper = None
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            factor = CopyFactor()  # singular (a diverging state): no preconditioner
        return factor

    def world_restored(self, index: int):
        """``WorldsSolver.world_restored``: world ``index``'s preconditioner (its factor or its Jacobi
        diagonal, restored with its per-world state) is packed again for the solve kernels, its
        capacitance correction formed again at its next step, and the caches of the last force pass
        and of the lockstep groups dropped."""
        super().world_restored(index)
        self._linearised = None
        self._groups = self._packed = self._packed_groups = None
        if self.preconditioner == "reference":
            return
        if self._jacobi[index]:
            kernels.set_list_items(self._lu_int, self._lu_float, index, JACOBI_INTS, self._diagonal[index])
        else:
            factor = self._factors[index] if self._factors[index] is not None else CopyFactor()
            kernels.set_list_items(self._lu_int, self._lu_float, index, factor.ints, factor.floats)
        self._correction_of[index] = self._no_correction
        kernels.set_list_items(self._corrections, self._imposed, index, *self._no_correction)

    def _copies_first(self):
        """``kernels.solve_copies_lu``'s view of the stacked model: (data, hourglass rows (G, nnz),
        hourglass group (N,))."""
        stack = self.stack
        if self._first is None or self._first[0] != stack.version:
            reference, model, workspace = stack.reference, stack.model, self.workspace
            values = stack.copies_last()
            hg_rows = np.ascontiguousarray(values["hourglass"].T)
            hg_indptr, hg_indices, _ = reference.hourglass_arrays
            stressed = len(workspace.stress_tangent) > 0  # one copy's cells and pair rows, every copy's values
            cells = reference.stress_cells if stressed else (workspace.stress_indptr, workspace.stress_nodes)
            pair_rows = reference.stress_pair_rows if stressed else workspace.stress_positions
            stacked = kernels.OperatorData(
                reference.springs, workspace.unit, model.stiffness, model.damping, workspace.geometric, model.mass,
                reference.mesh.elements, reference.edge_spring, model.correction_matrix, model.axis_rest_length,
                workspace.volume_coefficient, workspace.volume_direction, workspace.volume_gradient, hg_indptr,
                hg_indices, hg_rows[0], workspace.elongation, workspace.delta, *cells[:2], workspace.stress_gradient,
                workspace.stress_tangent, pair_rows)
            self._first = (stack.version, (stacked, hg_rows, values["hourglass_group"]))
        return self._first[1]

    def copies_first(self):
        """The per-copy kernels' (``kernels.apply_copies``, ``kernels.solve_copies_lu``) view of the
        stacked model at the workspace's last linearisation: (data, hourglass rows (G, nnz),
        hourglass group (N,)), SI units; with ``self.workspace.hourglass_blocks()`` their operator."""
        return self._copies_first()

    @property
    def factor_lists(self):
        """Solver "factorised": (ints, floats), each copy's packed preconditioner factor as
        ``kernels.solve_copies_lu`` takes it (node-block LU: ints[0] < 0; SuperLU's: ints[0] = k free
        dofs; identity: 0). Read-only views of the integrator's lists."""
        return self._lu_int, self._lu_float

    @property
    def correction_lists(self):
        """Solver "factorised": (W, imposed dofs), each copy's capacitance correction of its factor
        as ``kernels.solve_copies_lu`` takes it ((3 n, k) and (k,) dof indices; k = 0: none)."""
        return self._corrections, self._imposed

    def _hourglass_blocks(self):
        """``kernels.solve_copies_lu``'s node-block (BSR) form of the copies' hourglass matrices:
        (block indptr (n + 1,), block columns (nb,), values (G, 9 nb) per group of ``_copies_first``'s
        hg_rows), rebuilt after ``ModelStack.assign``."""
        return self.workspace.hourglass_blocks()

    def _solve_copies(self, system, mask_rows, rhs_rows, guess_rows, active, free_rows, iterations, residual):
        """Every active copy's BiCGSTAB preconditioned by its own preconditioner, one compiled call
        solving the copies one after the other (``kernels.solve_copies_lu``: a copy costs its own
        iterations, no lockstep). A copy on Jacobi gets this step's inverse diagonal
        (``kernels.jacobi_copies``); under "auto", one that has not converged after
        ``auto_switch_iterations`` gets a factor and continues from its iterate. A copy with a
        factor: without one, or whose free dofs are not all in its factor's (a probe contact
        released), it is factorised at this step's linearisation, on the union of its free sets; a
        contact that imposes more dofs keeps the factor, restricted exactly to the free dofs by a
        capacitance correction (``_correct``; a SuperLU factor, or more than CAPACITANCE_MAX dofs:
        its masked inverse, a close preconditioner). One that needs more than its factor's threshold
        is re-factorised here and continues from its iterate. The copies' vectors are rows (N, 3 n):
        mask_rows (float), rhs_rows, guess_rows, free_rows (bool); returns the solutions (N, 3 n) and
        writes iterations and residual (N,)."""
        stacked, hg_rows, hg_group = self._copies_first()
        jacobi = active & self._jacobi
        if jacobi.any():
            kernels.variant(kernels.jacobi_copies, self.threads)(stacked, system, hg_rows, hg_group, mask_rows, jacobi,
                                                                 self._diagonal)
        factored = active & ~self._jacobi
        fresh = self._factor_where_needed(system, factored, free_rows)
        limits = np.where(fresh, self.max_iterations, np.minimum(self._threshold, self.max_iterations))
        if self.preconditioner == "auto":  # Jacobi until auto_switch_iterations, up to AUTO_MAX_DOFS free dofs
            free = np.count_nonzero(free_rows, axis=1)
            switch = np.where(free <= AUTO_MAX_DOFS, auto_switch_iterations(free, self.stack.reference.pattern_density),
                              self.max_iterations)
            limits = np.where(jacobi, np.minimum(switch, self.max_iterations), limits)
        else:
            limits = np.where(jacobi, self.max_iterations, limits)
        self._correct(np.flatnonzero(factored), free_rows)
        blocks = self._hourglass_blocks()
        rows = np.zeros_like(rhs_rows)
        work = self._row_work
        solve = kernels.variant(kernels.solve_copies_lu, self.threads)
        solve(stacked, system, hg_rows, hg_group, mask_rows, rhs_rows, guess_rows, active, self.tolerance,
              limits.astype(np.int64), self._lu_int, self._lu_float, self._factor_of, self._corrections,
              self._imposed, work, rows, iterations, residual, *blocks)
        going = (active & (residual > self.tolerance) & (iterations < self.max_iterations)
                 & np.all(np.isfinite(rows), axis=1))
        # a factor that no longer fits, and (auto) a Jacobi solve that stalled: a factor at this step
        stalled = going & ((factored & ~fresh) | (jacobi & (self.preconditioner == "auto")))
        self._set_baseline(fresh, iterations)
        if self.amortise is not None:
            # amortised: re-factorise (at the next step) once the iterations spent beyond those right
            # after the last factorisation add up to about a factorisation's cost
            kept = factored & ~fresh & ~stalled
            self._excess[kept] += np.maximum(0, iterations[kept] - self._baseline[kept])
            self._stale |= kept & (self._excess > self.amortise)
        if stalled.any():
            again_rows = np.flatnonzero(stalled)
            covers = free_rows[again_rows] | (self._factor_free[again_rows] & ~jacobi[again_rows, None])
            self._factorise_copies(again_rows, system, covers)
            self._correct(again_rows, free_rows)
            again = np.zeros_like(rows)
            more = np.zeros(self.stack.count, dtype=np.int64)
            more_residual = np.zeros(self.stack.count)
            limits = (self.max_iterations - iterations).astype(np.int64)
            solve(stacked, system, hg_rows, hg_group, mask_rows, rhs_rows, rows, stalled, self.tolerance, limits,
                  self._lu_int, self._lu_float, self._factor_of, self._corrections, self._imposed, work, again, more,
                  more_residual, *blocks)
            self._set_baseline(stalled, more)
            rows[stalled] = again[stalled]
            residual[stalled] = more_residual[stalled]
            iterations += np.where(stalled, more, 0)
        return rows

    def _factor_where_needed(self, system, factored, free_rows):
        """Factorise the copies ``factored`` (N,) bool that have no factor, a stale one, or one whose
        free set misses free dofs (``free_rows`` (N, 3 n)); returns the copies whose factor is fresh
        at this step (made now, or taken from the cache at the episode's start for these free dofs:
        the one this first step would make)."""
        adopted = self._adopted & factored
        fresh = adopted & np.all(free_rows == self._factor_free, axis=1)
        self._adopted[factored] = False
        # a factor of another time step's system (a run whose dt changed) is not this one's
        missing = (np.array([factor is None for factor in self._factors]) | self._stale | (adopted & ~fresh)
                   | (self._factor_dt != system[1]))
        uncovered = np.any(free_rows & ~self._factor_free, axis=1)
        todo = np.flatnonzero(factored & (missing | uncovered))
        covers = free_rows[todo] | (self._factor_free[todo] & ~missing[todo, None])
        for index, factor in zip(todo, self._factorise_copies(todo, system, covers)):
            pending = self._pending[index]
            if pending is not None and np.array_equal(pending[1], free_rows[index]) and factor.ints[0] > 0:
                self._kept_first.put(pending[0], factor)
            self._pending[index] = None
            self._stale[index] = False
            fresh[index] = True
        return fresh

    def _solve_shared(self, system, mask, rhs, guess_rows, active, limit, solution, iterations, residual):
        """Solver "reference": every ``active`` copy's BiCGSTAB preconditioned by its group's factor
        (``_pack_preconditioners``), at most ``limit`` iterations (``kernels.solve_copies_grouped``:
        the copies in chunks of ``lockstep_chunk`` on numba's threads, each chunk in lockstep with one
        pass over a shared factor for all its running copies; a copy costs its own iterations). mask, rhs, solution
        (3 n, N); guess_rows (N, 3 n); iterations, residual (N,) written."""
        lu_int, lu_float, group_of = self._pack_preconditioners()
        stacked, hg_rows, hg_group = self._copies_first()
        rows = np.zeros((self.stack.count, rhs.shape[0]))
        limits = np.full(self.stack.count, limit, dtype=np.int64)
        kernels.variant(kernels.solve_copies_grouped, self.threads)(
            stacked, system, hg_rows, hg_group, np.ascontiguousarray(mask.T), np.ascontiguousarray(rhs.T),
            np.ascontiguousarray(guess_rows), active, self.tolerance, limits, lu_int, lu_float, group_of,
            *self._no_corrections, self._group_work, rows, iterations, residual, *self._hourglass_blocks(),
            lockstep_chunk(self.stack.count, kernels.running_threads(self.threads)))
        solution[:] = rows.T

    # -- step ------------------------------------------------------------------------------------------
    def _pack_preconditioners(self):
        """Preconditioner "reference": the kernel's view of the copies' preconditioners: (lu_int,
        lu_float, group_of), the packed LUs of the groups of copies that share one
        (``kernels.solve_copies_grouped``)."""
        count = self.stack.count
        groups = self._group()
        if self._packed is None or self._packed_groups is not groups:
            group_of = np.full(count, -1, dtype=np.int64)
            for g, (_, rows) in enumerate(groups):
                group_of[rows] = g
            self._packed = (TypedList([factor.ints for factor, _ in groups]),
                            TypedList([factor.floats for factor, _ in groups]), group_of)
            self._packed_groups = groups
        return self._packed

    def linearise(self, positions, rows=None):
        """The step's force pass over the stacked model at ``positions`` (N n, 3) m: internal forces
        without damping (N n, 3) N, with the clamped geometric stiffness and volume terms of the
        implicit system in ``self.workspace``. ``rows``: None (every copy) or the copies (N,) bool
        whose entries are wanted (the others' may be another state's). Once per state and copy:
        a copy whose positions were linearised last (by the vector env's measurement of the
        previous step) is reused, the others alone computed (a contact pass that solves some
        copies again)."""
        count, version = self.stack.count, self.stack.version
        wanted = np.ones(count, dtype=bool) if rows is None else np.asarray(rows, dtype=bool)
        if self._linearised is None or self._linearised[0] != version:
            self._linearised = (version, positions.copy(), np.zeros(count, dtype=bool))
        _, kept, done = self._linearised
        needed = wanted & ~(done & np.all(kept.reshape(count, -1) == positions.reshape(count, -1), axis=1))
        if needed.any():
            self.workspace.compute(positions, None, geometric=True, volume_jacobian=self.stack.model.has_volume_forces,
                                   rows=needed)
            if not self.workspace.partial_pass(geometric=True):
                needed[:] = True  # (every copy was computed)
            kept.reshape(count, -1)[needed] = positions.reshape(count, -1)[needed]
            done |= needed
        return self.workspace.forces

    def advance(self, positions, velocities, fixed, target, dt, active, force=None):
        """One step of the scheme (``self.scheme``) of every copy in ``active`` (N,) bool; the others
        keep their state (``schemes.scheme_advance``: one or two ``stage`` solves).

        Args:
            positions, velocities: (N, n, 3) m, m/s.  fixed: (N, n, 3) bool imposed components.
            target: (N, n, 3) imposed positions, m (read where fixed).  dt: s.
            force: None or (N, n, 3) external nodal forces, N.
        Returns: (positions, velocities) (N, n, 3), new arrays.
        """
        return scheme_advance(self, positions, velocities, fixed, target, dt, active, force)

    def stage(self, positions, velocities, fixed, target, dt, active, force=None, rayleigh=(0.0, 0.0)):
        """One linearised implicit Euler step of ``dt`` s of every copy in ``active`` (``advance``'s
        arguments), with Rayleigh damping ``rayleigh`` = (alpha 1/s, beta s), forces -(alpha M +
        beta K) v at the step's end velocity: the system M + dt D + dt^2 K gains dt (alpha M + beta
        K) (docs/physics.md section 14)."""
        stack = self.stack
        model = stack.model
        count, n_nodes = positions.shape[:2]
        dofs = 3 * n_nodes
        x0 = np.ascontiguousarray(positions.reshape(-1, 3), dtype=float)
        v0 = np.ascontiguousarray(velocities.reshape(-1, 3), dtype=float)
        # one fused pass over the stacked model: forces without damping, clamped geometric stiffness,
        # volume terms
        forces = self.linearise(x0, active) + model.gravity_force
        if force is not None and np.any(force):  # (zero forces add nothing: the floats stay the same)
            forces += np.asarray(force, dtype=float).reshape(-1, 3)
        alpha, beta = rayleigh
        stiffness = dt * dt + dt * beta
        # A = (1 + dt alpha) M + dt D + (dt^2 + dt beta) K: (mass, damping, stiffness, coupling, volume,
        # hourglass) scales; the right-hand side's M v0 - A v0 then holds the damping forces at v0
        system = self.scales(1.0 + dt * alpha, float(dt), stiffness)
        # every vector a row per copy (N, 3 n), as the per-copy kernels take them; the lockstep
        # solver ("reference") takes the copy index last (transposed for it)
        x_rows, v_rows = x0.reshape(count, dofs), v0.reshape(count, dofs)
        target_rows = target.reshape(count, dofs)
        imposed = fixed.reshape(count, dofs)
        free = ~imposed
        # rhs = dt f(x0, v0) - dt^2 K v0 - A known = dt f_0 + M v0 - A (v0 + known), known = dv on the
        # imposed dofs, f_0 without damping: one operator product
        target_velocity, moved = np.empty((count, dofs)), np.empty((count, dofs))
        kernels.variant(kernels.implicit_rows_start, self.threads)(x_rows, v_rows, target_rows, imposed, dt,
                                                                   target_velocity, moved)
        product = np.zeros((count, dofs))  # (the inactive copies' rows stay 0)
        stacked, hg_rows, hg_group = self._copies_first()
        kernels.variant(kernels.apply_copies, self.threads)(stacked, system, hg_rows, hg_group, moved,
                                                            np.ascontiguousarray(active, dtype=bool), product,
                                                            *self._hourglass_blocks())
        rhs = np.empty((count, dofs))
        kernels.variant(kernels.implicit_rows_rhs, self.threads)(forces.reshape(count, dofs), self._dof_mass(), v_rows,
                                                                 product, dt, rhs)
        iterations = np.zeros(count, dtype=np.int64)
        residual = np.zeros(count)
        stalled = np.zeros(count, dtype=bool)
        if self.preconditioner != "reference":
            solution = self._solve_copies(system, free.astype(float), rhs, self.warm, active, free, iterations,
                                          residual)
        else:
            solution, stalled = self._solve_reference(system, free, rhs, active, x0, fixed, dt, iterations, residual)
        self.warm = np.where(active[:, None], solution, self.warm)
        self.last_iterations, self.last_residual = iterations, residual
        # v' = v0 + dv (the solution on free dofs), x' = x0 + dt v'; the imposed dofs at their targets
        new_positions, new_velocities = np.empty((count, n_nodes, 3)), np.empty((count, n_nodes, 3))
        update = kernels.variant(kernels.implicit_rows_update, self.threads)
        update(x_rows, v_rows, solution, imposed, target_rows, target_velocity, dt, active,
               positions.reshape(count, dofs), velocities.reshape(count, dofs), new_positions.reshape(count, dofs),
               new_velocities.reshape(count, dofs))
        if self.preconditioner == "reference" and self.refresh_iterations:
            # per copy, so that a copy's steps do not depend on the other copies
            slow = active & ~stalled & (iterations > self.refresh_iterations)
            for index in np.flatnonzero(slow):
                if np.all(np.isfinite(new_positions[index])):
                    self._refresh(index, new_positions[index], dt, fixed[index])
        return new_positions, new_velocities

    def _solve_reference(self, system, free, rhs, active, x0, fixed, dt, iterations, residual):
        """Preconditioner "reference": the copies' lockstep solves (``_solve_shared``); a copy whose
        start-of-episode preconditioner no longer fits (large deformation, a contact change) stalls
        after ``first_pass`` iterations: it is re-linearised here, exactly, and solved again from
        there. Returns the solutions (N, 3 n) and the stalled copies (N,) bool."""
        count = self.stack.count
        mask = np.ascontiguousarray(free.T, dtype=float)
        rhs = np.ascontiguousarray(rhs.T)
        solution = np.empty((rhs.shape[0], count))
        self._solve_shared(system, mask, rhs, self.warm, active, self.first_pass, solution, iterations, residual)
        stalled = active & (residual > self.tolerance) & np.all(np.isfinite(solution), axis=0)
        if stalled.any():
            for index in np.flatnonzero(stalled):
                self._refresh(index, x0.reshape(count, -1, 3)[index], dt, fixed[index])
            again = np.empty_like(solution)
            more = np.zeros(count, dtype=np.int64)
            self._solve_shared(system, mask, rhs, solution.T, stalled, self.max_iterations - self.first_pass,
                               again, more, residual)
            solution = np.where(stalled[None, :], again, solution)
            iterations += more
        return solution.T, stalled

    def scales(self, mass, damping, stiffness):
        """The operator's (mass, damping, stiffness, coupling, volume, hourglass) scales of mass M +
        damping D + stiffness K, K with every term the stacked model has."""
        model = self.stack.model
        return (mass, damping, stiffness, stiffness if model.correction_mode is not None else 0.0,
                stiffness if model.has_volume_forces else 0.0, stiffness if model.hourglass is not None else 0.0)

    def damping_forces(self, positions, velocities):
        """The material laws' damping forces -(alpha M + beta K) v (N n, 3) N at ``positions`` and
        ``velocities`` (N n, 3) m, m/s of the stacked worlds (K the implicit step's, linearised
        there: the next step's force pass), 0 for the worlds without a law [14]."""
        count = self.stack.count
        forces = np.zeros((count, 3 * self.stack.n_nodes))
        laws = [(law, group) for law, group in damping_groups(self.stack, self.stack.shared) if any(law)]
        if laws:
            self.linearise(positions)
            stacked, hg_rows, hg_group = self._copies_first()
            rows = np.ascontiguousarray(velocities, dtype=float).reshape(count, -1)
            product = np.empty_like(rows)
            for (alpha, beta), group in laws:
                kernels.variant(kernels.apply_copies, self.threads)(stacked, self.scales(alpha, 0.0, beta), hg_rows,
                                                                    hg_group, rows, group, product,
                                                                    *self._hourglass_blocks())
                forces[group] = -product[group]
        return forces.reshape(-1, 3)

    def _dof_mass(self):
        """(N, 3 n) each copy's mass per dof, kg, kept per stack version (rebuilt after ``assign``)."""
        stack = self.stack
        if self._mass is None or self._mass[0] != stack.version:
            self._mass = (stack.version, np.repeat(stack.model.mass, 3).reshape(stack.count, -1))
        return self._mass[1]
