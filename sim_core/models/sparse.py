"""A sparse matrix with a pattern built once and values updated in place.

The pattern couples every pair of nodes that share an element (3x3 blocks per node pair), which
contains every spring and every element matrix. Assembly is one ``np.bincount`` over precomputed
positions in the CSR ``data`` array: no COO rebuild, no Python loop.

``NodeBlockLU`` factorises such a matrix, restricted to whole nodes, in dense 3 x 3 node blocks:
the implicit step's preconditioner (``preconditioners.node_block_factor``) and the vector envs'.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import kernels

#: symbolic structures (ordering, fill) kept by ``NodeBlockLU``, one per free set and matrix pattern
ORDER_CACHE_SIZE = 64
#: SuperLU's fill-reducing orderings of the node graph (``block_structure``): MMD on A + A^T, and
#: COLAMD, which a pattern wider than its elements' also tries (``Model.node_orderings``): on the
#: smoothed tetrahedra's (nodes coupled two edges apart) MMD fills most, and neither is the better
#: on every such pattern (benchmarks/tet_cost.py)
NODE_ORDERINGS = ("MMD_AT_PLUS_A", "COLAMD")


def unique_keys(keys, return_inverse: bool = False):
    """``np.unique`` of the integer array ``keys`` (1D; its sorted distinct values, and with
    ``return_inverse`` the index of each key among them) by one sort: several times faster than
    NumPy 2's hash-based ``unique`` on the tens of thousands of node-pair keys a cut renumbers."""
    keys = np.asarray(keys).ravel()
    order = np.argsort(keys, kind="stable") if return_inverse else None
    ordered = keys[order] if return_inverse else np.sort(keys)
    first = np.empty(len(ordered), dtype=bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    values = ordered[first]
    if not return_inverse:
        return values
    inverse = np.empty(len(keys), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return values, inverse


class BlockPattern:
    """Fixed CSR pattern for a (3N, 3N) matrix over node pairs that share an element.

    Args:
        n_nodes: number of nodes N.
        elements: (M, n) node indices (n = 8 hexahedra, 4 tetrahedra); every pair of nodes within an
            element is coupled, and every node with itself (a node of no element too: a stack's
            parked node rows, a node a cut left alone).
        extra_pairs: (P, 2) further coupled node pairs (a tetrahedral model's smoothing domains).
    """

    def __init__(self, n_nodes: int, elements: np.ndarray, extra_pairs: np.ndarray | None = None):
        self.n_nodes = n_nodes
        self.n_dofs = 3 * n_nodes
        as_int = lambda array: kernels.writeable(np.ascontiguousarray(array, dtype=np.int64))  # noqa: E731
        extra = np.zeros((0, 2), np.int64) if extra_pairs is None else np.asarray(extra_pairs).reshape(-1, 2)
        # each node's partners through its elements (a compiled pass, no sort of every element pair)
        self.block_indptr, self.block_columns = kernels.node_pair_blocks(as_int(elements), as_int(extra),
                                                                          int(n_nodes))
        degree = np.diff(self.block_indptr)
        #: the node-pair blocks, sorted (a * n_nodes + b): every entry is found through its block, a
        #: search among 9 times fewer keys than the entries (a cut rebuilds these patterns)
        keys = self.block_keys = np.repeat(np.arange(n_nodes, dtype=np.int64), degree) * n_nodes + self.block_columns
        # CSR of the dofs, block by block: dof row 3 a + i holds, for each block (a, b) in order, the
        # columns 3 b, 3 b + 1, 3 b + 2; it starts at 9 block_indptr[a] + 3 i degree(a)
        index_type = np.int32 if 9 * len(keys) < 2**31 else np.int64  # scipy's choice for a CSR matrix
        self.indptr = np.zeros(self.n_dofs + 1, index_type)
        self.indptr[1:] = np.cumsum(np.repeat(3 * degree, 3))
        # the blocks of dof rows 3 a, 3 a + 1, 3 a + 2: block row a's blocks, three times
        lengths = np.repeat(degree, 3)
        sequence = (np.arange(3 * len(keys)) + np.repeat(np.repeat(self.block_indptr[:-1], 3) - (np.cumsum(lengths)
                                                                                               - lengths), lengths))
        self.indices = ((3 * (keys % n_nodes))[sequence][:, None] + np.arange(3)).ravel().astype(index_type)
        self.nnz = 9 * len(keys)
        self._degree = degree
        self.diagonal_positions = self.positions(np.arange(self.n_dofs), np.arange(self.n_dofs))

    def padded(self, n_nodes: int) -> "BlockPattern":
        """This pattern on ``n_nodes`` nodes: its own, then nodes coupled to themselves only (a stack's
        parked node rows), appended: every entry of its nodes keeps its position in ``data``."""
        extra = int(n_nodes) - self.n_nodes
        if extra < 0:
            raise ValueError(f"a padded pattern has at least the pattern's {self.n_nodes} nodes, got {n_nodes}")
        pattern = BlockPattern.__new__(BlockPattern)
        pattern.n_nodes, pattern.n_dofs = int(n_nodes), 3 * int(n_nodes)
        new = np.arange(self.n_nodes, n_nodes, dtype=np.int64)
        old_rows, old_columns = self.block_keys // self.n_nodes, self.block_keys % self.n_nodes
        pattern.block_keys = np.concatenate([old_rows * n_nodes + old_columns, new * n_nodes + new])
        pattern._degree = np.concatenate([self._degree, np.ones(extra, np.int64)])
        pattern.block_indptr = np.concatenate([self.block_indptr, self.block_indptr[-1] + 1 + np.arange(extra)])
        pattern.block_columns = np.concatenate([self.block_columns, new])
        pattern.nnz = self.nnz + 9 * extra
        index_type = np.int32 if pattern.nnz < 2**31 else np.int64
        pattern.indptr = np.concatenate([self.indptr, self.indptr[-1] + 3 + 3 * np.arange(3 * extra)]
                                        ).astype(index_type)
        pattern.indices = np.concatenate([self.indices, (3 * np.repeat(new, 9) + np.tile(np.arange(3), 3 * extra))]
                                         ).astype(index_type)
        pattern.diagonal_positions = pattern.positions(np.arange(pattern.n_dofs), np.arange(pattern.n_dofs))
        return pattern

    def positions(self, rows, cols) -> np.ndarray:
        """Positions in ``data`` of entries (rows, cols); raises if one is outside the pattern."""
        rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
        a, b = rows // 3, cols // 3
        block = self._blocks(a, b)
        return (9 * self.block_indptr[a] + 3 * (rows - 3 * a) * self._degree[a] + 3 * (block - self.block_indptr[a])
                + cols - 3 * b)

    def _blocks(self, a, b) -> np.ndarray:
        """The index of each node-pair block (a, b) among ``block_keys``; raises if one is outside."""
        keys = a * self.n_nodes + b
        bound = self.n_nodes * self.n_nodes
        table = None
        if bound <= DENSE_LOOKUP:  # the dense table, built once per pattern (a cut model's pattern is asked 5 times)
            table = self.__dict__.get("_table")
            if table is None:
                table = self._table = _lookup_table(self.block_keys, bound)
        found = _sorted_index(self.block_keys, keys, bound, table)
        if not np.array_equal(self.block_keys[found], keys):
            raise ValueError("entry outside the fixed sparsity pattern")
        return found

    def __getstate__(self):  # the lookup table is rebuilt on first use, not copied or pickled
        state = dict(self.__dict__)
        state.pop("_table", None)
        return state

    def csr_positions(self, indptr, indices) -> np.ndarray:
        """(nnz,) the positions in ``data`` of the entries of a CSR matrix (``indptr``, ``indices``) of
        this pattern's size (raises if one is outside): ``arange`` when it holds exactly the
        pattern's first entries (a hexahedral model's hourglass matrix, assembled on its pattern)."""
        indptr, indices = np.asarray(indptr), np.asarray(indices)
        count = len(indices)
        if count == 0:
            return np.zeros(0, np.int64)
        rows = int(np.argmax(indptr == count))  # its rows from this one on are empty
        if (count <= self.nnz and int(self.indptr[rows]) == count
                and np.array_equal(indptr[:rows + 1], self.indptr[:rows + 1])
                and np.array_equal(indices, self.indices[:count])):
            return np.arange(count, dtype=np.int64)
        return self.positions(np.repeat(np.arange(len(indptr) - 1), np.diff(indptr)), indices)

    def block_positions(self, node_rows: np.ndarray, node_cols: np.ndarray) -> np.ndarray:
        """Positions of the 3x3 blocks (node_rows[..., None], node_cols) -> shape (..., 3, 3)
        (``kernels.block_data_positions``); raises if one is outside the pattern."""
        a, b = np.broadcast_arrays(np.asarray(node_rows, dtype=np.int64), np.asarray(node_cols, dtype=np.int64))
        out = np.empty(a.shape + (3, 3), np.int64)
        if a.size and not kernels.block_data_positions(self.block_indptr, self.block_columns,
                                                       np.ascontiguousarray(a.ravel()),
                                                       np.ascontiguousarray(b.ravel()), out.reshape(-1, 3, 3)):
            raise ValueError("entry outside the fixed sparsity pattern")
        return out

    def assemble(self, positions: np.ndarray, values: np.ndarray) -> np.ndarray:
        """``data`` array of the sum of ``values`` at ``positions`` (same shapes)."""
        return np.bincount(positions.ravel(), weights=values.ravel(), minlength=self.nnz)

    def matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """A CSR matrix sharing this pattern (index arrays are not copied)."""
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_dofs, self.n_dofs))


class NodeBlockLU:
    """A sparse LU of a system matrix whose free dofs are whole nodes, in dense 3 x 3 node blocks,
    packed for ``kernels.block_lu_apply`` (one right-hand side) and ``kernels.block_lu_solve``
    (several) as (``ints``, ``floats``): P A P^T = L U with P a symmetric permutation of whole
    nodes (SuperLU's MMD on A + A^T or COLAMD of the node graph, ``NODE_ORDERINGS``) and no pivoting
    (the implicit system matrix M + dt D + dt^2 K is dominated by its diagonal), so that L and U
    keep the node blocks. The fill is that of SuperLU's scalar ordering (1.65e5 entries at
    TumorPositioning's 6^3 block, in 1.9e4 blocks), and the substitutions read one index per 9
    values: faster than SuperLU's scalar solve for one right-hand side.

    The ordering and the block fill pattern (a symbolic SuperLU factor of the node graph) are
    computed once per matrix pattern and free set; each factorisation is then numeric only
    (``kernels.block_lu_factor``), faster than SuperLU's scalar factorisation (see the performance
    page).

    With ``symmetric``, the factor is instead the block LDL^T of the matrix's symmetric part
    (A + A^T) / 2, P S P^T = U^T D U (``kernels.block_ldl_factor``), stored as U alone with D^-1 in
    its diagonal blocks: half the values, so it factorises and applies in less time than the LU; a
    preconditioner for a matrix that is symmetric up to small terms (the implicit system's
    corrections' coupling and volume terms: about 1e-4 of its entries).

    Args:
        matrix: (k, k) CSC system matrix on the free dofs (the same pattern gives the same
            structure; explicit zeros are kept as structural entries).
        free: (k,) the free dofs, whole nodes in order (``applies``).
        symmetric: factorise the symmetric part (LDL^T) instead of the matrix (LU).
        orderings: the node orderings to try (``block_structure``; ``Model.node_orderings``).
    Raises np.linalg.LinAlgError on a zero or non-finite pivot."""

    #: symbolic structures per (free set, matrix pattern), shared by all threads (``_lock``)
    _structures: OrderedDict = OrderedDict()
    _lock = threading.Lock()

    @staticmethod
    def applies(free) -> bool:
        """Whether the free dofs ``free`` (sorted) are whole nodes."""
        free = np.asarray(free)
        if free.size == 0 or free.size % 3:
            return False
        triples = free.reshape(-1, 3)
        return bool(np.all(triples[:, 0] % 3 == 0) and np.all(triples == triples[:, :1] + np.arange(3)))

    def __init__(self, matrix, free, symmetric: bool = False, orderings=NODE_ORDERINGS[:1]):
        matrix = sp.csc_matrix(matrix)
        orderings = tuple(orderings)
        key = (np.asarray(free).tobytes(), matrix.indptr.tobytes(), matrix.indices.tobytes(), bool(symmetric),
               orderings)
        with self._lock:
            structure = self._structures.get(key)
            if structure is not None:
                self._structures.move_to_end(key)
        if structure is None:
            structure = block_structure(matrix, np.asarray(free), orderings)
            if symmetric:
                structure = structure + symmetric_structure(structure)
            with self._lock:
                self._structures[key] = structure
                if len(self._structures) > ORDER_CACHE_SIZE:
                    self._structures.popitem(last=False)
        a_indptr, a_indices, a_map, l_indptr, l_indices, u_indptr, u_indices, self.ints = structure[:8]
        a_values = np.zeros(9 * len(a_indices))
        a_values[a_map] = matrix.data
        work = np.empty(9 * (len(a_indptr) - 1))
        if symmetric:
            a_transpose, l_to_u, self.ints = structure[8:]
            self.floats = np.empty(9 * len(u_indices))
            done = kernels.block_ldl_factor(a_indptr, a_indices, a_values, a_transpose, l_indptr, l_indices, l_to_u,
                                            u_indptr, u_indices, self.floats, work)
        else:
            self.floats = np.empty(9 * (len(l_indices) + len(u_indices)))
            done = kernels.block_lu_factor(a_indptr, a_indices, a_values, l_indptr, l_indices, u_indptr, u_indices,
                                           self.floats, work)
        if not done:
            raise np.linalg.LinAlgError("node-block factor: zero or non-finite pivot")


#: ``_sorted_index`` looks keys below this up in a dense table instead of searching them
DENSE_LOOKUP = 1 << 20


def _sorted_index(keys, wanted, bound, table=None):
    """(W,) for each of ``wanted`` the index of the same value in ``keys`` (sorted, distinct, all in
    [0, ``bound``)), clipped to the last key where it is missing (the caller checks): a dense table
    when ``bound`` is small (a cut's small systems: a binary search per entry was a noticeable part
    of a cut's factorisation; ``table``: that table, ``_lookup_table``, if the caller keeps one),
    else ``np.searchsorted``."""
    if bound > DENSE_LOOKUP:
        return np.minimum(np.searchsorted(keys, wanted), max(len(keys) - 1, 0))
    return (_lookup_table(keys, bound) if table is None else table)[np.clip(wanted, 0, bound)]


def _lookup_table(keys, bound):
    """(bound + 1,) ``_sorted_index``'s dense table: the index of each value in ``keys`` (sorted,
    distinct, in [0, ``bound``)), the last key's elsewhere."""
    table = np.full(bound + 1, max(len(keys) - 1, 0), dtype=np.int32 if len(keys) < 2**31 else np.int64)
    table[keys] = np.arange(len(keys))
    return table


def block_structure(matrix, free, orderings=NODE_ORDERINGS[:1]):
    """``NodeBlockLU``'s symbolic part: the node ordering (of ``orderings``, names of
    ``NODE_ORDERINGS``, the one whose numeric factorisation does the fewest 3 x 3 block products;
    the first on a tie), the permuted block pattern of A with the position of each stored entry in
    its blocks, the block fill patterns of L and U, and the packed integer header."""
    k = matrix.shape[0]
    nb = k // 3
    indptr, indices = (kernels.writeable(np.ascontiguousarray(array, dtype=np.int64))
                       for array in (matrix.indptr, matrix.indices))
    block_row, block_col, entry_block = kernels.entry_blocks(indptr, indices, nb)  # its node blocks
    graph = sp.csc_matrix(kernels.node_graph(block_row, block_col, nb)[::-1], shape=(nb, nb))  # G + G^T + nb I
    best = None
    for spec in orderings:
        ordering = spla.splu(graph, permc_spec=spec, diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        candidate = _ordered_fill(block_row, block_col, nb, np.argsort(ordering.perm_c))
        if best is None or candidate[-1] < best[-1]:
            best = candidate
    node_order, a_indptr, a_indices, rank, l_indptr, l_indices, u_indptr, u_indices, _ = best
    a_map = kernels.entry_positions(indptr, indices, entry_block, rank)
    order = (3 * node_order[:, None] + np.arange(3)).ravel()
    ints = np.concatenate([[-k, nb, len(l_indices), len(u_indices)], l_indptr, l_indices, u_indptr, u_indices,
                           np.asarray(free)[order]]).astype(np.int64)
    return a_indptr, a_indices, a_map.astype(np.int64), l_indptr, l_indices, u_indptr, u_indices, ints


def _ordered_fill(block_row, block_col, nb, node_order):
    """The node blocks (``block_row``, ``block_col``) of a matrix of ``nb`` block rows under the node
    ordering ``node_order`` (the node at each position): (node_order, the permuted block pattern
    (CSR indptr, indices), each block's rank in it, the block fill patterns of L and U (CSR
    indptr, indices), the 3 x 3 block products of the numeric factorisation: for each block (i, k)
    of L off the diagonal, the blocks of U's row k, ``kernels.block_lu_factor``'s work). The block
    fill is the symbolic factor of the permuted node graph made symmetric (``kernels.ordered_fill``,
    ``kernels.symbolic_fill``: the elimination tree's row unions, the pattern a numeric LU without
    pivoting fills), L its transpose."""
    as_int = lambda array: kernels.writeable(np.ascontiguousarray(array, dtype=np.int64))  # noqa: E731
    node_order = as_int(node_order)
    return (node_order,) + tuple(kernels.ordered_fill(as_int(block_row), as_int(block_col), int(nb), node_order))


def symmetric_structure(structure):
    """The symmetric form of a ``block_structure``: (a_transpose, l_to_u, ints) for
    ``kernels.block_ldl_factor`` and ``kernels.block_ldl_solve``: the position of block (j, i) for
    each block (i, j) of A, the position in U of block (k, i) for each block (i, k) of L, and the
    packed header [-k, nb, 0, blocks of U, U indptr, U block columns, order]. Raises
    np.linalg.LinAlgError where A's or the fill's block pattern is not symmetric."""
    a_indptr, a_indices, _, l_indptr, l_indices, u_indptr, u_indices, ints = structure
    nb = len(a_indptr) - 1

    def transpose_positions(indptr, indices, other_indptr, other_indices):
        rows = np.repeat(np.arange(nb, dtype=np.int64), np.diff(indptr))
        keys = np.repeat(np.arange(nb, dtype=np.int64), np.diff(other_indptr)) * nb + other_indices
        wanted = indices * nb + rows
        found = _sorted_index(keys, wanted, nb * nb)
        if len(indices) != len(other_indices) or not np.array_equal(keys[found], wanted):
            raise np.linalg.LinAlgError("the node-block pattern is not symmetric")
        return found.astype(np.int64)

    a_transpose = transpose_positions(a_indptr, a_indices, a_indptr, a_indices)
    l_to_u = transpose_positions(l_indptr, l_indices, u_indptr, u_indices)
    k = -int(ints[0])
    packed = np.concatenate([[-k, nb, 0, len(u_indices)], u_indptr, u_indices, ints[len(ints) - k:]]).astype(np.int64)
    return a_transpose, l_to_u, packed


def edge_incidence(model):
    """(node_edge, node_sign) (M, 8, 3) for ``kernels.operator_matrix_data_blocks``: the spring of each
    element's axis group g (edges 4 g .. 4 g + 3 of ``edge_spring``) through its local node k, and
    +1 where k is the spring's first node, -1 where it is its second; empty (0, 8, 3) arrays where
    a node is not on exactly one edge of each group (then ``operator_matrix_data`` assembles), and for
    tetrahedra (no axis groups, no corrections' coupling)."""
    elements, springs, edge_spring = model.mesh.elements, model.springs, model.edge_spring
    count = len(elements)
    none = np.zeros((0, 8, 3), np.int64), np.zeros((0, 8, 3))
    if elements.shape[1] != 8:
        return none
    ends = springs[edge_spring]  # (M, 12, 2) the two nodes of each element edge's spring
    local = elements[:, None, None, :] == ends[..., None]  # (M, 12, 2, 8): the local node of each end
    if not np.all(local.sum(axis=3) == 1):
        return none
    k = np.argmax(local, axis=3)
    group = np.broadcast_to((np.arange(12) // 4)[None, :, None], k.shape)
    slots = (3 * k + group).reshape(count, 24)  # each (local node, axis group) once: all 24 of them
    if not np.all(np.sort(slots, axis=1) == np.arange(24)):
        return none
    node_edge = np.empty((count, 8, 3), dtype=np.int64)
    node_sign = np.empty((count, 8, 3))
    rows = np.broadcast_to(np.arange(count)[:, None, None], k.shape)
    node_edge[rows, k, group] = np.broadcast_to(edge_spring[:, :, None], k.shape)
    node_sign[rows, k, group] = np.broadcast_to(np.array([1.0, -1.0]), k.shape)
    return node_edge, node_sign
