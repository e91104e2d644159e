"""The implicit step's per-copy preconditioner factors (``sim_core.solvers.implicit``) and the
structures they are made on: ``CopyFactor`` (a copy's packed sparse factor, as the solve kernels
take it, with its capacitance corrections), ``system_factor`` (the factor of a model's implicit
system matrix at a state: solver "reference" and snapshots) and ``copies_structure`` (the node-block
symbolic structure ``kernels.factor_copies`` assembles and factorises on). SI units."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..models.forces import stiffness_data
from ..models.model import Model
from ..models.sparse import NodeBlockLU, block_structure, symmetric_structure
from .preconditioners import InverseColumns, free_structure

#: Solver "factorised": each copy's preconditioner is the node-block LDL^T of its system matrix's
#: symmetric part (the matrix is symmetric up to about 1e-4 of its entries, from the corrections'
#: coupling and the volume terms) rather than its LU: half the values to store, factorise and read
#: at every application (``kernels.block_ldl_factor``, ``kernels.block_ldl_solve_one``).
SYMMETRIC_FACTOR = True


def system_factor(model, positions, dt, fixed):
    """The packed sparse LU (``CopyFactor``) of the implicit system matrix M + dt D + dt^2 K (K at
    ``positions`` (n, 3) m, geometric terms clamped as the integrator does) on the dofs not in
    ``fixed`` (n, 3); the identity (no factor) when the matrix is singular (a diverging state)."""
    factor = _system_factor_of(model, positions, dt, fixed)
    # what it was computed from: a pickled snapshot of a world carries this, not the factor
    factor.source = ("system", np.array(positions, dtype=float), float(dt), np.array(fixed, dtype=bool))
    return factor


def _system_factor_of(model, positions, dt, fixed):
    free = np.flatnonzero(~np.asarray(fixed, dtype=bool).ravel())
    alpha, beta = model.rayleigh  # the material's damping enters as the step's mass and stiffness do
    data = stiffness_data(model, positions, volume=False, clamp=True, stiffness_scale=dt * dt + dt * beta,
                          damping_scale=dt, mass_scale=1.0 + dt * alpha)
    matrix = model.pattern.matrix(data).tocsr()[free][:, free].tocsc()
    if NodeBlockLU.applies(free):
        try:
            with np.errstate(all="ignore"):
                factor = NodeBlockLU(matrix, free, symmetric=SYMMETRIC_FACTOR, orderings=model.node_orderings)
            if np.all(np.isfinite(factor.floats)):
                return factor
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            pass
    try:
        with np.errstate(all="ignore"):
            factor = CopyFactor(matrix, free)
    except (RuntimeError, ValueError, np.linalg.LinAlgError):
        return CopyFactor()
    if not np.all(np.isfinite(factor.floats)):
        return CopyFactor()
    factor.lu = factor.lower = factor.upper = None  # only the packed arrays are used
    return factor


class CopyFactor:
    """A sparse LU (SuperLU, as ``ImplicitEuler``'s factorised preconditioner, or a node-block LU
    with ``refactored``) of one copy's free-dof system matrix, packed for
    ``kernels.solve_copies_lu`` (``ints``, ``floats``). Shared by the copies and episodes that start
    alike (``ImplicitEuler._kept_first``): what decides its renewal (the iterations right after the factorisation)
    is each copy's own (``ImplicitEuler._set_baseline``)."""

    #: what it was computed from (``ImplicitEuler.rebuild_factor``), None if unknown
    source = None

    def __init__(self, matrix=None, free=None):
        self._inverse, self._corrections = None, {}
        if matrix is None:
            self.ints, self.floats = np.zeros(1, dtype=np.int64), np.zeros(1)
            self.lu = self.lower = self.upper = None
            return
        lu = spla.splu(matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        lower, upper = lu.L.tocsc(), lu.U.tocsc()
        lower.sort_indices()
        upper.sort_indices()
        k = matrix.shape[0]
        columns = np.arange(k)
        if not (np.array_equal(lower.indices[lower.indptr[:-1]], columns)
                and np.array_equal(upper.indices[upper.indptr[1:] - 1], columns)):
            raise np.linalg.LinAlgError("LU factor without its diagonal")
        gather = np.empty(k, dtype=np.int64)
        gather[lu.perm_r] = free  # (Pr b)[perm_r[j]] = b[j]
        self.ints = np.concatenate([[k, lower.nnz, upper.nnz], lower.indptr, lower.indices, upper.indptr,
                                    upper.indices, gather, free, lu.perm_c]).astype(np.int64)
        self.floats = np.concatenate([lower.data, upper.data])
        self.lu, self.lower, self.upper = lu, lower, upper

    @classmethod
    def refactored(cls, ints, floats):
        """A node-block LU's packed ``ints`` and ``floats`` as a factor."""
        factor = cls.__new__(cls)
        factor._inverse, factor._corrections = None, {}
        factor.ints, factor.floats = ints, floats
        return factor

    def inverse(self, n_dofs: int) -> InverseColumns:
        """The columns of its inverse kept so far (``preconditioners.InverseColumns``)."""
        if self._inverse is None:
            self._inverse = InverseColumns(self.ints, self.floats, n_dofs)
        return self._inverse

    def has_correction(self, imposed: np.ndarray) -> bool:
        """Whether the correction for ``imposed`` is kept (``correction`` solves nothing)."""
        return imposed.tobytes() in self._corrections

    def correction(self, imposed: np.ndarray, n_dofs: int):
        """A node-block LU's capacitance correction for the dofs ``imposed`` (k,) sorted, free in the
        factor but imposed now: (W, imposed) for ``kernels.corrected_lu_apply``, W from
        ``preconditioners.InverseColumns.correction`` (its columns kept per dof); None where it is
        singular. Kept per imposed set (8 per factor)."""
        key = imposed.tobytes()
        if key not in self._corrections:
            self.keep_correction(imposed, self.inverse(n_dofs).correction(imposed))
        return self._corrections[key]

    def keep_correction(self, imposed: np.ndarray, correction):
        """Keep W (or None: singular) as the correction for ``imposed`` (8 per factor)."""
        if len(self._corrections) >= 8:
            self._corrections.clear()
        self._corrections[imposed.tobytes()] = None if correction is None else (correction, imposed)


def copies_structure(model: Model, nodes: np.ndarray, symmetric: bool = SYMMETRIC_FACTOR):
    """``kernels.factor_copies``' structure of ``model``'s system matrix on the whole nodes ``nodes``
    (n,) bool: (node dofs, the free structure's take, indices and columns (``free_structure``), the
    node-block symbolic factor (``sparse.block_structure``; ``symmetric``: its LDL^T form,
    ``sparse.symmetric_structure``), and its scratch arrays), int64 arrays; None where it has no node
    or its symbolic factor fails."""
    node_dofs = np.flatnonzero(np.repeat(nodes, 3))
    if not len(node_dofs):
        return None
    whole = free_structure(model, node_dofs)
    matrix = sp.csc_matrix((np.ones(len(whole.take)), whole.indices, whole.indptr), shape=whole.shape)
    try:
        symbolic = block_structure(matrix, node_dofs, model.node_orderings)
        a_indptr, a_indices, a_map, l_indptr, l_indices, u_indptr, u_indices, ints = symbolic
        a_transpose, l_to_u = np.zeros(0, np.int64), np.zeros(0, np.int64)
        if symmetric:
            a_transpose, l_to_u, ints = symmetric_structure(symbolic)
    except (RuntimeError, ValueError, np.linalg.LinAlgError):
        return None
    as_int = lambda array: np.ascontiguousarray(array, dtype=np.int64)  # noqa: E731
    return (as_int(node_dofs), as_int(whole.take), as_int(whole.indices), as_int(whole.columns), as_int(a_map),
            as_int(a_indptr), as_int(a_indices), as_int(l_indptr), as_int(l_indices), as_int(u_indptr),
            as_int(u_indices), as_int(a_transpose), as_int(l_to_u), as_int(ints), np.empty(9 * len(a_indices)),
            np.empty(9 * (len(a_indptr) - 1)))
