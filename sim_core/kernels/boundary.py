"""One numba type for each array a kernel reads, whatever the caller holds.

numba compiles (and caches) one machine code per signature, and an array's type includes its
writeability: a kernel called once with a mesh's read-only nodes and once with a writeable state
array compiles twice (seconds to minutes for the large kernels), and ``tissue-gym-warmup`` compiles
the environments' signatures only. The kernels' own calls (a copy's slice of a stacked array) are
writeable, so the Python callers pass what they read through ``writeable``."""

import numpy as np


def writeable(array: np.ndarray) -> np.ndarray:
    """``array`` if it is writeable, else a copy of it (a mesh's nodes, a frozen input). The
    kernels only read it: the copy is never written back."""
    return array if array.flags.writeable else array.copy()
