"""The node-pair block pattern of a mesh (``sim_core.models.sparse.BlockPattern``): which node pairs
share an element, and where a node pair's 3 x 3 block lies in the pattern's CSR data. A pass over
each node's elements instead of a sort of every element's node pairs (a cut builds its model's
pattern at every cut)."""

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def node_pair_blocks(elements, extra, n_nodes):
    """(indptr (n_nodes + 1,), columns) int64: for each node a, the nodes b (sorted, distinct) with
    a and b in one element of ``elements`` (M, n), or (a, b) a row of ``extra`` (P, 2), and b = a."""
    count, n = elements.shape
    start = np.zeros(n_nodes + 1, np.int64)  # node -> its elements (CSR), then its extra pairs
    for e in range(count):
        for i in range(n):
            start[elements[e, i] + 1] += 1
    for a in range(n_nodes):
        start[a + 1] += start[a]
    incident = np.empty(start[n_nodes], np.int64)
    fill = start[:n_nodes].copy()
    for e in range(count):
        for i in range(n):
            a = elements[e, i]
            incident[fill[a]] = e
            fill[a] += 1
    extra_start = np.zeros(n_nodes + 1, np.int64)
    for p in range(len(extra)):
        extra_start[extra[p, 0] + 1] += 1
    for a in range(n_nodes):
        extra_start[a + 1] += extra_start[a]
    extra_column = np.empty(len(extra), np.int64)
    fill = extra_start[:n_nodes].copy()
    for p in range(len(extra)):
        a = extra[p, 0]
        extra_column[fill[a]] = extra[p, 1]
        fill[a] += 1
    mark = np.full(n_nodes, -1, np.int64)
    row = np.empty(n_nodes, np.int64)
    indptr = np.zeros(n_nodes + 1, np.int64)
    columns = np.empty(n * len(incident) + len(extra) + n_nodes, np.int64)  # room for every candidate
    for a in range(n_nodes):
        mark[a] = a
        row[0] = a
        size = 1
        for q in range(start[a], start[a + 1]):
            e = incident[q]
            for j in range(n):
                b = elements[e, j]
                if mark[b] != a:
                    mark[b] = a
                    row[size] = b
                    size += 1
        for q in range(extra_start[a], extra_start[a + 1]):
            b = extra_column[q]
            if mark[b] != a:
                mark[b] = a
                row[size] = b
                size += 1
        first = indptr[a]
        columns[first:first + size] = np.sort(row[:size])
        indptr[a + 1] = first + size
    return indptr, columns[:indptr[n_nodes]].copy()


@njit(cache=True, nogil=True)
def block_data_positions(block_indptr, block_columns, rows, cols, out):
    """``out`` (K, 3, 3) int64: the positions in a ``BlockPattern``'s CSR data of the 3 x 3 blocks
    (rows[k], cols[k]) of its node-pair blocks (``block_indptr``, ``block_columns``, each row sorted):
    entry (3 a + r, 3 b + c) lies at 9 indptr[a] + 3 r degree(a) + 3 (rank of b in row a) + c.
    Returns False (``out`` partly written) where a block is outside the pattern."""
    for k in range(len(rows)):
        a, b = rows[k], cols[k]
        low, high = block_indptr[a], block_indptr[a + 1]
        left, right = low, high
        while left < right:  # the first column >= b
            middle = (left + right) // 2
            if block_columns[middle] < b:
                left = middle + 1
            else:
                right = middle
        if left == high or block_columns[left] != b:
            return False
        first = 9 * low + 3 * (left - low)
        stride = 3 * (high - low)
        for r in range(3):
            for c in range(3):
                out[k, r, c] = first + stride * r + c
    return True


@njit(cache=True, nogil=True)
def free_entries(block_indptr, block_columns, free):
    """The CSC structure of a ``BlockPattern``'s matrix (node-pair blocks ``block_indptr``,
    ``block_columns``: symmetric, rows sorted) restricted to the dofs ``free`` (3 n,) bool, column
    by column, rows ascending: (take (E,) int64, the position in the pattern's CSR data of each
    entry (row, column); indices (E,) int32, its row among the free dofs; indptr (k + 1,) int32;
    columns (E,) int64, its column among the free dofs)."""
    n_dofs = len(free)
    number = np.empty(n_dofs, np.int64)
    count = 0
    for d in range(n_dofs):
        number[d] = count
        if free[d]:
            count += 1
    size = 0  # entries: a free column c of node b meets the free rows of every block (a, b)
    for c in range(n_dofs):
        if free[c]:
            b = c // 3
            for q in range(block_indptr[b], block_indptr[b + 1]):
                a = block_columns[q]
                for i in range(3):
                    if free[3 * a + i]:
                        size += 1
    take = np.empty(size, np.int64)
    indices = np.empty(size, np.int32)
    columns = np.empty(size, np.int64)
    indptr = np.zeros(count + 1, np.int32)
    e = 0
    for c in range(n_dofs):
        if not free[c]:
            continue
        b, j = c // 3, c % 3
        for q in range(block_indptr[b], block_indptr[b + 1]):
            a = block_columns[q]
            low, high = block_indptr[a], block_indptr[a + 1]
            left, right = low, high
            while left < right:  # block (a, b) in row a
                middle = (left + right) // 2
                if block_columns[middle] < b:
                    left = middle + 1
                else:
                    right = middle
            first = 9 * low + 3 * (left - low) + j
            for i in range(3):
                r = 3 * a + i
                if free[r]:
                    take[e] = first + 3 * (high - low) * i
                    indices[e] = number[r]
                    columns[e] = number[c]
                    e += 1
        indptr[number[c] + 1] = e
    return take, indices, indptr, columns
