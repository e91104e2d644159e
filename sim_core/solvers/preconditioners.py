"""The implicit step's factorised preconditioners (``sim_core.solvers.implicit``): the node-block
factor of the system matrix on the free dofs (``node_block_factor``), its restriction to another
imposed set (exact through a capacitance correction, ``InverseColumns``), the structures a
factorisation gathers its values through (``FreeStructure``, ``pattern_arrays``), and the rules
that choose and renew them (``auto_switch_iterations``, ``REFACTOR_MIN``, ``CAPACITANCE_MAX``)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import kernels
from ..models.model import Model
from ..models.sparse import NodeBlockLU


def auto_switch_iterations(n_free, density=1.0):
    """Jacobi iterations above which "auto" switches to the factorised preconditioner: where the
    two step times cross, which moves to more iterations as the mesh grows (an LU solve costs more,
    relative to an operator product, as the fill grows): 5 sqrt(n_free / 400), at least 6, fitted
    to where they crossed in interleaved timings (docs/performance_notes.md), times ``density``,
    the model's node-pair blocks per row over those of its elements alone (``Model.pattern_density``:
    smoothed tetrahedra couple nodes two edges apart, and their LU fills and costs that much more).
    ``n_free``: an int or an array (one per world)."""
    return np.maximum(6, np.rint(5.0 * density * np.sqrt(np.asarray(n_free) / 400.0)).astype(np.int64))


#: "auto" stays with Jacobi above this many free dofs (LU fill and memory grow like dofs^(4/3)).
AUTO_MAX_DOFS = 30000
#: Re-factorise when a solve needs more than max(REFACTOR_MIN, 2 x the count right after factorising).
REFACTOR_MIN = 8


class FreeStructure:
    """The CSC structure of the system matrix restricted to the free dofs (``free``), with the
    positions of its entries in the model's ``BlockPattern`` data: a factorisation only gathers
    values, nothing is re-sliced. Built from the pattern's node-pair blocks in one compiled pass
    (``kernels.free_entries``, once per imposed set: a contact makes many); ``columns`` is each
    entry's column."""

    def __init__(self, model: Model, free: np.ndarray):
        # no reference to the model: this structure lives in the model's derived data, and a cycle
        # would keep every evicted model (and its arrays) alive until a full garbage collection
        pattern = model.pattern
        self.hg_positions = pattern_arrays(model)[0]
        self.free = free
        mask = np.zeros(pattern.n_dofs, bool)
        mask[free] = True
        self.take, self.indices, self.indptr, self.columns = kernels.free_entries(pattern.block_indptr,
                                                                                 pattern.block_columns, mask)
        self.shape = (len(free), len(free))


def pattern_arrays(model: Model):
    """(the pattern positions of the hourglass matrix's entries, the mass per dof (kg)) of the
    model, computed once, kept in ``model.derived``."""
    return model.derived.get("pattern_arrays", lambda: _build_pattern_arrays(model))


def _build_pattern_arrays(model: Model):
    hg_indptr, hg_indices, _ = model.hourglass_arrays
    return model.pattern.csr_positions(hg_indptr, hg_indices), np.repeat(model.mass, 3)


class InverseColumns:
    """Columns of the inverse B of a packed node-block LU (``sparse.NodeBlockLU``'s ``ints``,
    ``floats``) over ``n_dofs`` dofs, kept per dof (at most CAPACITANCE_CACHE) and solved together
    for those not kept yet (``kernels.block_lu_solve``), and the capacitance correction of an
    imposed set built from them. Held by ``ImplicitEuler``'s per-world factors."""

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


#: Columns of the inverse a factor keeps for its capacitance corrections (``InverseColumns``), and
#: the most dofs one correction handles (more: the factor masked, a close preconditioner).
CAPACITANCE_CACHE = 512
CAPACITANCE_MAX = 96


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
            return NodeBlockLU(matrix, node_dofs, symmetric=symmetric, orderings=model.node_orderings)
    except (RuntimeError, ValueError, np.linalg.LinAlgError):
        return None


def free_structure(model: Model, dofs: np.ndarray) -> FreeStructure:
    """``FreeStructure`` of the dofs ``dofs`` (sorted), cached per model (a few dof sets each)."""
    cache = model.derived.get("free_structures", dict)
    key = dofs.tobytes()
    structure = cache.get(key)
    if structure is None:
        if len(cache) >= 8:
            cache.clear()
        structure = cache[key] = FreeStructure(model, dofs)
    return structure
