"""The kernels' thread policy: when the parallel kernels run, and numba's thread pool.

A parallel kernel ``name`` has a twin ``name_serial`` that computes the same floats in the calling
thread only; ``variant`` is the one place that picks between them (``threaded``: more than one
thread, and not in a forked process, where GNU OpenMP's pool is unusable).
"""

from __future__ import annotations

import contextlib
import os
import sys

import numba
import numpy as np
from numba import njit, prange

from .fastmath import FAST


@njit(cache=True, nogil=True, error_model="numpy", fastmath=FAST)
def serial_product(a, b):
    """a @ b (m, k) x (k, p) in this thread: a product of a few-column matrix by a small one
    (``preconditioners.InverseColumns.correction``: m the dofs, k = p the imposed dofs, at most
    ``CAPACITANCE_MAX``). Through numpy, OpenBLAS runs such a product on its thread pool, whose
    threads then spin on the other cores after every call: CPU time spent for no wall time gained
    (a vector env's steps make many such calls)."""
    m, k = a.shape
    p = b.shape[1]
    out = np.zeros((m, p))
    for i in range(m):
        for q in range(k):
            value = a[i, q]
            if value != 0.0:
                for j in range(p):
                    out[i, j] += value * b[q, j]
    return out


@njit(cache=True, parallel=True)
def _touch_threads(out):
    """A parallel loop: its first call starts numba's thread pool (``start_threads``)."""
    for i in prange(out.shape[0]):
        out[i] = i


#: [True] in a process forked from this one (``os.register_at_fork``): GNU OpenMP's thread pool is
#: not fork-safe (numba terminates a forked child that enters a parallel region of a pool its parent
#: started), so the batched vector envs use the serial kernels there (``solve_copies_lu_serial``,
#: ``factor_copies_serial``).
FORKED = [False]
os.register_at_fork(after_in_child=lambda: FORKED.__setitem__(0, True))


def threaded(threads: int) -> bool:
    """Whether the parallel kernels (not their ``_serial`` versions) run for ``threads`` threads:
    more than one, and not in a forked process (``FORKED``)."""
    return threads > 1 and not FORKED[0]


def variant(kernel, threads: int):
    """``kernel``, a parallel kernel, when the parallel kernels run for ``threads`` threads
    (``threaded``), else its twin ``<name>_serial`` of the same module: the same arguments, the same
    floats, in the calling thread. The one place that chooses between the two."""
    if threaded(threads):
        return kernel
    return getattr(sys.modules[kernel.__module__], kernel.__name__ + "_serial")


def running_threads(threads: int) -> int:
    """The threads a kernel chosen by ``variant`` for ``threads`` runs on now: numba's current
    count (``thread_count`` may have lowered it for a step) when the parallel kernels run, else 1."""
    return numba.get_num_threads() if threaded(threads) else 1


def available_threads() -> int:
    """The threads the parallel kernels can use: numba's ``NUMBA_NUM_THREADS`` (the cores it found,
    unless the user set it)."""
    return int(numba.config.NUMBA_NUM_THREADS)


@contextlib.contextmanager
def using_threads(threads: int):
    """Run the parallel kernels on ``threads`` threads inside the block, then restore the count the
    caller had (nothing is changed when ``threaded(threads)`` is false: the serial twins run)."""
    if not threaded(threads):
        yield
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


@contextlib.contextmanager
def thread_count(count: int):
    """numba's thread count set to ``count`` (>= 1) inside the block, restored after: the parallel
    kernels run on that many threads (their floats do not depend on the count). Unlike
    ``using_threads``, one thread keeps the parallel kernels (a caller that chose them for several
    threads and runs a step on one)."""
    previous = numba.get_num_threads()
    numba.set_num_threads(int(count))
    try:
        yield
    finally:
        numba.set_num_threads(previous)


#: GNU OpenMP's spin count for numba's idle threads (``start_threads``): a tenth of libgomp's
#: default of 300000, so that they spin long enough to bridge the Python between a step's parallel
#: kernels and short enough that a pause (a policy update) finds them asleep instead of holding a
#: core (see benchmarks/vector_env_speed.py and the performance page)
SPIN_COUNT = 30000


def start_threads():
    """Start numba's thread pool (the parallel kernels: ``factor_copies``, ``solve_copies_lu``) with
    idle threads that spin briefly, then sleep. With numba's OpenMP layer, GNU OpenMP reads
    ``OMP_WAIT_POLICY`` and ``GOMP_SPINCOUNT`` once, when it loads. Waking a sleeping thread costs
    far more than an empty parallel region with spinning threads, and a vector env step runs a dozen
    regions: a short spin makes the vector envs faster than sleeping threads (OMP_WAIT_POLICY=PASSIVE)
    at a little more CPU time per step, and nearly as fast as libgomp's default spin count without
    keeping a core busy after every region. ``GOMP_SPINCOUNT`` is set for the load
    only, and only when the user has set neither variable; a pool already started is left as it is."""
    unset = "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ
    if unset:
        os.environ["GOMP_SPINCOUNT"] = str(SPIN_COUNT)
    try:
        _touch_threads(np.empty(4))
    finally:
        if unset:
            os.environ.pop("GOMP_SPINCOUNT", None)
