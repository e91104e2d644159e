"""The fastmath flag sets of the compiled kernels: which LLVM floating-point liberties each may take.

A kernel's floats depend on these sets, so each kernel keeps the one it was validated with: the
serial and threaded twins of the vector envs must round alike, bit for bit.
"""

from __future__ import annotations

#: fastmath without the no-NaN / no-inf assumptions, so a diverging run still shows NaN to the monitor,
#: and without reassociation, so a kernel's floats do not depend on how LLVM optimised it. With
#: "reassoc", a kernel compiled in a process where its callees were loaded from numba's cache rounded
#: differently (1e-16 to 1e-14 relative) from the same kernel compiled with fresh callees: a serial
#: kernel cached by one process and its threaded twin compiled by the next gave different
#: trajectories (tests/test_env_vector.py's bit-for-bit test failed after
#: ``pytest tests/test_batched_fused.py -k grouped``; it passes without "reassoc"). Without it the
#: envs and the static solve also ran faster, not slower (benchmarks/vector_env_speed.py,
#: ``tissue-sim bench``; the performance page).
FAST = {"nsz", "arcp", "contract"}
#: ``FAST`` with reassociation, for the single-model Jacobi Krylov kernels only (``apply_operator``,
#: ``solve_springs``: no serial / threaded twin whose floats must match; ``spring_operator``, which
#: the copies' kernels call too, has none): their vectorised reductions keep the bare lattice's
#: CG step faster than without.
FAST_REDUCE = FAST | {"reassoc"}
#: ``FAST`` without contraction, for the stress correction's kernels (``kernels.stress``), whose
#: per-element bodies a threaded pass (``stress_correction_tangent_add_copies``) inlines. With
#: "contract", whether LLVM fused a product into an FMA depended on the code it had inlined the body
#: into, and that on which kernels numba had loaded from its cache: in a process whose callees came
#: from the cache, the threaded tangent differed from the serial one by 1e-34 (N/m m^2) and
#: Retraction's vector copies from its single envs by 1e-15 in the observation (both equal in a
#: process that compiled everything; tests/test_numba_cache.py). Without it the passes run as fast
#: (benchmarks/step_speed.py).
FAST_EXACT = FAST - {"contract"}
