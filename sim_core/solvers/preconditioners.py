"""The implicit step's factorised preconditioners: the sparse factor of the system matrix on the
free dofs (``Factor``, a node-block LU or LDL^T, else SuperLU's), its restriction to another imposed
set (exact through a capacitance correction, ``InverseColumns``), the structures a factorisation
gathers its values through (``FreeStructure``, ``pattern_arrays``), and the factorisations kept at
one state for many episodes (``FactorStore``)."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import kernels
from ..caches import digest
from ..models.model import Model
from ..models.sparse import NodeBlockLU


#: ImplicitEuler's preconditioners. "jacobi": the diagonal of the mass, spring and hourglass terms
#: (compiled BiCGSTAB / CG, ``kernels.solve_springs``); "factorised": the sparse LU of the whole system
#: matrix at the state of its last factorisation, kept across steps; "auto": Jacobi, switching a
#: (model, dt, fixed set) to "factorised" once a Jacobi solve needs more than
#: ``auto_switch_iterations(free dofs)``.
PRECONDITIONERS = ("auto", "jacobi", "factorised")


def auto_switch_iterations(n_free: int) -> int:
    """Jacobi iterations above which "auto" switches to the factorised preconditioner: where the
    two step times cross, which moves to more iterations as the mesh grows (an LU solve costs more,
    relative to an operator product, as the fill grows): 5 sqrt(n_free / 400), at least 6, fitted
    to where they crossed in interleaved timings (docs/performance_notes.md)."""
    return max(6, int(round(5.0 * np.sqrt(n_free / 400.0))))


#: "auto" stays with Jacobi above this many free dofs (LU fill and memory grow like dofs^(4/3)).
AUTO_MAX_DOFS = 30000
#: A factorisation serves another imposed set (``Factor.restricted``) when at most this share of its
#: free dofs gets Jacobi: dofs free now on nodes it does not hold (the SuperLU fallback,
#: ``_Restricted``: every dof whose status changed). More, and factorising again is cheaper than the
#: extra iterations. Chosen for the contact tasks (Palpation's probe, Retraction's floor): 1% gave
#: more env steps per CPU second than no reuse and than reuse without a limit (random actions; see
#: the performance page). Imposed dofs on the nodes it holds (a contact's) are corrected exactly
#: (``_Capacitance``).
RESTRICTED_MAX_CHANGED = 0.01
#: Re-factorise when a solve needs more than max(REFACTOR_MIN, 2 x the count right after factorising).
REFACTOR_MIN = 8


class FreeStructure:
    """The CSC structure of the system matrix restricted to the free dofs (``free``), with the
    positions of its entries in the model's ``BlockPattern`` data: a factorisation only gathers
    values, nothing is re-sliced. Built from ``pattern_arrays`` by masks (O(nnz) numpy, once per
    imposed set: a contact makes many)."""

    def __init__(self, model: Model, free: np.ndarray):
        # no reference to the model: this structure lives in the model's derived data, and a cycle
        # would keep every evicted model (and its arrays) alive until a full garbage collection
        column, rows, transpose, self.hg_positions, _ = pattern_arrays(model)
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


def pattern_arrays(model: Model):
    """The model's symmetric block pattern read as CSC, column by column (column of each entry, its
    row, the position in the CSR data of the entry (row, column)), the pattern positions of the
    hourglass matrix's entries, and the mass per dof (kg); computed once, kept in ``model.derived``."""
    return model.derived.get("pattern_arrays", lambda: _build_pattern_arrays(model))


def _build_pattern_arrays(model: Model):
    pattern = model.pattern
    column = np.repeat(np.arange(pattern.n_dofs), np.diff(pattern.indptr))  # CSR row c = CSC column c
    rows = pattern.indices.astype(np.int64)
    transpose = pattern.positions(rows, column)  # data position of (row, column): the pattern is symmetric
    hg_indptr, hg_indices, _ = model.hourglass_arrays
    hg_rows = np.repeat(np.arange(len(hg_indptr) - 1), np.diff(hg_indptr))
    hg_positions = pattern.positions(hg_rows, hg_indices) if len(hg_indices) else np.zeros(0, np.int64)
    return column, rows, transpose, hg_positions, np.repeat(model.mass, 3)


class Factor:
    """Sparse LU of the system matrix, for the Krylov solves' preconditioner on the free dofs
    (``restricted``: any imposed set). A node-block LU (``sparse.NodeBlockLU``) of the matrix on
    the whole nodes that hold a free dof, the imposed dofs among them decoupled (rows and columns
    zero, diagonal kept: a contact imposes single dofs, Palpation's probe and Retraction's floor
    impose y, x and z stay free), so its inverse on the free dofs is that of the free-dof matrix.
    Restricted to another imposed set it stays exact for the free dofs imposed now, through a
    capacitance correction (``_Capacitance``) whose columns of the inverse are solved at first use per
    factorisation and kept, so a contact that moves onto other nodes keeps the factor and its
    iteration count; dofs free now but imposed at the factorisation get Jacobi. The
    node-block LU's substitutions read one index per 3 x 3 block, faster than SuperLU's scalar
    solve, and so is its numeric factorisation (compiled, on a structure kept per node set; see
    ``sparse.NodeBlockLU``). Where it fails, SuperLU's scalar LU of the free-dof matrix (minimum-degree
    ordering on A + A^T, symmetric mode: the matrix is symmetric up to the corrections' coupling),
    restricted to another imposed set by ``_Restricted``."""

    def __init__(self, model, key, structure: FreeStructure, values: np.ndarray):
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
        key = digest(mask)
        preconditioner = self._restricted.get(key)
        if preconditioner is None:
            if len(self._restricted) >= 8:
                self._restricted.clear()
            preconditioner = self._restricted[key] = _Capacitance(self, mask)
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

    def __init__(self, factor: Factor, mask: np.ndarray):
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


def free_structure(model: Model, dofs: np.ndarray) -> FreeStructure:
    """``FreeStructure`` of the dofs ``dofs`` (sorted), with each entry's column (``columns``),
    cached per model (a few dof sets each)."""
    cache = model.derived.get("free_structures", dict)
    key = dofs.tobytes()
    structure = cache.get(key)
    if structure is None:
        if len(cache) >= 8:
            cache.clear()
        structure = cache[key] = FreeStructure(model, dofs)
        structure.columns = np.repeat(np.arange(len(dofs)), np.diff(structure.indptr))
    return structure


class _Restricted:
    """A factorisation made for another imposed set, used as the preconditioner on this one: its LU
    solve, zeroed on the dofs imposed now, and Jacobi (the diagonal at the factorisation) on the
    dofs free now but imposed then. It differs from the inverse of this set's matrix by a low-rank
    term (rank: the dofs whose status changed), which the Krylov solve absorbs in a few more
    iterations than a re-factorisation would need; a re-factorisation costs more (measured on
    Palpation's probe contact)."""

    def __init__(self, factor: Factor, mask: np.ndarray):
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
