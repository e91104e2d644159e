"""A sparse matrix with a pattern built once and values updated in place.

The pattern couples every pair of nodes that share an element (3x3 blocks per node pair), which
contains every spring and every element matrix. Assembly is one ``np.bincount`` over precomputed
positions in the CSR ``data`` array: no COO rebuild, no Python loop.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class BlockPattern:
    """Fixed CSR pattern for a (3N, 3N) matrix over node pairs that share an element.

    Args:
        n_nodes: number of nodes N.
        elements: (M, 8) node indices; every pair of nodes within an element is coupled.
    """

    def __init__(self, n_nodes: int, elements: np.ndarray):
        self.n_nodes = n_nodes
        self.n_dofs = 3 * n_nodes
        pairs = np.stack(
            [np.repeat(elements, 8, axis=1).ravel(), np.tile(elements, (1, 8)).ravel()], axis=1
        )
        pairs = np.unique(pairs, axis=0)
        rows = (3 * pairs[:, 0, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
        cols = (3 * pairs[:, 1, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
        matrix = sp.csr_matrix(
            (np.ones(rows.size), (rows.ravel(), cols.ravel())), shape=(self.n_dofs, self.n_dofs)
        )
        matrix.sort_indices()
        self.indptr = matrix.indptr
        self.indices = matrix.indices
        self.nnz = matrix.nnz
        row_of_entry = np.repeat(np.arange(self.n_dofs), np.diff(self.indptr))
        self._keys = row_of_entry.astype(np.int64) * self.n_dofs + self.indices
        self.diagonal_positions = self.positions(np.arange(self.n_dofs), np.arange(self.n_dofs))

    def positions(self, rows, cols) -> np.ndarray:
        """Positions in ``data`` of entries (rows, cols); raises if one is outside the pattern."""
        keys = np.asarray(rows, dtype=np.int64) * self.n_dofs + np.asarray(cols, dtype=np.int64)
        found = np.searchsorted(self._keys, keys)
        found = np.minimum(found, self.nnz - 1)
        if not np.array_equal(self._keys[found], keys):
            raise ValueError("entry outside the fixed sparsity pattern")
        return found

    def block_positions(self, node_rows: np.ndarray, node_cols: np.ndarray) -> np.ndarray:
        """Positions of the 3x3 blocks (node_rows[..., None], node_cols) -> shape (..., 3, 3)."""
        rows = 3 * np.asarray(node_rows)[..., None, None] + np.arange(3)[:, None]
        cols = 3 * np.asarray(node_cols)[..., None, None] + np.arange(3)[None, :]
        rows, cols = np.broadcast_arrays(rows, cols)
        return self.positions(rows.ravel(), cols.ravel()).reshape(rows.shape)

    def assemble(self, positions: np.ndarray, values: np.ndarray) -> np.ndarray:
        """``data`` array of the sum of ``values`` at ``positions`` (same shapes)."""
        return np.bincount(positions.ravel(), weights=values.ravel(), minlength=self.nnz)

    def matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """A CSR matrix sharing this pattern (index arrays are not copied)."""
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_dofs, self.n_dofs))
