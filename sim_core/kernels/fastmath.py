"""The fastmath flag sets of the compiled kernels: which LLVM floating-point liberties each may take.

A kernel's floats depend on these sets, so each kernel keeps the one it was validated with: the
serial and threaded twins of the vector envs must round alike, bit for bit.
"""

from __future__ import annotations

#: fastmath without the no-NaN / no-inf assumptions, so a diverging run still shows NaN to the monitor,
#: and without reassociation, so a kernel's floats do not depend on how LLVM optimised it (with it,
#: they depended on which callees numba had loaded from its cache, and a serial kernel and its
#: threaded twin could round apart: docs/performance_notes.md, "Fastmath flags").
FAST = {"nsz", "arcp", "contract"}
#: ``FAST`` with reassociation, for the single-model operator product only (``apply_operator``: no
#: serial / threaded twin whose floats must match; ``spring_operator``, which the copies' kernels
#: call too, has none), so that LLVM vectorises its reductions.
FAST_REDUCE = FAST | {"reassoc"}
#: ``FAST`` without contraction, for the stress correction's kernels (``kernels.stress``), whose
#: per-element bodies a threaded pass (``stress_correction_tangent_add_copies``) inlines: with
#: "contract", whether LLVM fuses a product into an FMA depends on the code it inlined the body into,
#: so the threaded and serial passes could round apart (tests/test_numba_cache.py).
FAST_EXACT = FAST - {"contract"}
