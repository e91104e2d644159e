"""Compiled (numba) kernels for the per-step hot path: forces and the implicit Euler solve.

Each kernel is a plain loop over springs or elements compiled once (``cache=True`` keeps the
machine code between runs). The serial kernels release the GIL (``nogil=True``): Python threads
run them at once (the vector envs reset their copies on several threads, whose static solves call
them; a kernel only writes the arrays it is given). The numpy formulation in ``sim_core.models.forces`` is
the readable reference the tests compare these kernels with. SI units.

The modules, lowest first: ``boundary`` (one numba type per array argument), ``fastmath`` (the
fastmath flag sets), ``vectors`` (3-vectors as tuples,
inlined into the per-element bodies), ``threads`` (the thread policy and ``variant``, the choice
between a kernel and its ``_serial`` twin), ``measure`` (lengths, volumes, health, strain,
reaction), ``update`` (the integrators' per-dof state updates), ``forces`` (the force passes),
``stress`` (the finite-strain stress correction), ``operator`` (the implicit step's matrix-free
operator products and its assembled matrix), ``factor`` (block LU / LDL^T factors and their
solves), ``pattern`` (a mesh's node-pair block pattern),
``krylov_copies`` (the implicit step's Krylov solves, per copy: N = 1 is one world), ``contact`` (the probe's projected
surface), ``geometry`` (points covered by quads seen from above). Every public name is re-exported
here: ``kernels.model_forces(...)``.

numba checks a cached kernel against the file that defines it only: a kernel that calls (or
inlines) a function of another module, or reads a constant of ``sim_core.geometry.topology``, would keep its
cached machine code when only that other file changes. So the package drops its whole cache when
the source of any kernel module or of the topology changed since the cache was written
(``drop_stale_cache``, at import, before any kernel is compiled or loaded), as a single file of
kernels did. A cache elsewhere (``NUMBA_CACHE_DIR``) is the user's to clear.
"""

import hashlib
import os
import tempfile
from pathlib import Path

#: the sources a kernel's machine code depends on
SOURCES = sorted(Path(__file__).parent.glob("*.py")) + [Path(__file__).parent.parent / "geometry" / "topology.py"]
STAMP = "kernel-sources.blake2b"


def drop_stale_cache(cache: Path, sources=SOURCES) -> bool:
    """Delete numba's cached kernels (``*.nbi``, ``*.nbc``) in ``cache`` unless they were written
    from the current ``sources`` (a digest kept in ``cache / STAMP``); returns whether it did. A
    cache that cannot be written is left as it is (an installed package: its sources do not change)."""
    digest = hashlib.blake2b(b"".join(path.read_bytes() for path in sources), digest_size=16).hexdigest()
    stamp = cache / STAMP
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for path in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            path.unlink(missing_ok=True)
        handle, temporary = tempfile.mkstemp(dir=cache, prefix=STAMP)  # written whole, then renamed
        with os.fdopen(handle, "w") as out:
            out.write(digest)
        os.replace(temporary, stamp)
    except OSError:
        return False
    return True


drop_stale_cache(Path(__file__).parent / "__pycache__")

from .boundary import writeable  # noqa: F401
from .fastmath import (  # noqa: F401
    FAST, FAST_REDUCE,
)
from .threads import (  # noqa: F401
    FORKED, SPIN_COUNT, available_threads, running_threads, serial_product, start_threads, thread_count, threaded,
    using_threads, variant,
)
from .measure import (  # noqa: F401
    any_collapsed, any_inverted, element_volumes, element_volumes_copies, health, health_copies, health_copies_serial,
    hex_volume, masked_reaction, spring_lengths, spring_lengths_copies, strain_extremes,
    strain_extremes_serial,
)
from .update import (  # noqa: F401
    implicit_rows_rhs, implicit_rows_rhs_serial, implicit_rows_start, implicit_rows_start_serial,
    implicit_rows_update, implicit_rows_update_serial, symplectic_update,
)
from .forces import (  # noqa: F401
    correction_pass, fixed_direction_corrections, model_forces, model_forces_copies, model_forces_copies_serial,
    scatter_springs,
    scatter_springs_copies, spring_pass, stacked_hourglass_subtract_groups,
    stacked_hourglass_subtract_groups_serial, subtract_pushes,
    volume_forces_add, volume_forces_jacobian_add, volume_jacobian_terms, volume_pass,
)
from .stress import (  # noqa: F401
    stress_correction_add, stress_correction_add_copies, stress_correction_tangent_add,
    stress_correction_tangent_add_copies, stress_correction_tangent_add_copies_serial,
)
from .operator import (  # noqa: F401
    apply_blocks, apply_copies, apply_copies_serial, apply_copy, apply_operator, apply_operator_blocks,
    OperatorData, apply_packed, bsr3_matvec_add, copy_data, csr_matvec_add, operator_matrix_data, operator_matrix_data_blocks,
    spring_operator,
)
from .factor import (  # noqa: F401
    block_ldl_factor, block_ldl_solve, block_ldl_solve_one, block_lu_apply, block_lu_factor, block_lu_solve,
    capacitance_corrections, capacitance_corrections_serial, correct_masked, corrected_lu_apply, entry_blocks,
    entry_positions,
    factor_copies, factor_copies_serial, inverse_columns_copies, inverse_columns_copies_serial, lu_apply,
    lu_columns, node_graph, ordered_fill, set_list_items, symbolic_fill,
)
from .pattern import (  # noqa: F401
    block_data_positions, free_entries, node_pair_blocks,
)
from .krylov_copies import (  # noqa: F401
    bsr3_matvec_add_rows, inverse_diagonal, jacobi_copies, jacobi_copies_serial, solve_copies_grouped,
    solve_copies_grouped_serial, solve_copies_lu, solve_copies_lu_serial,
)
from .contact import (  # noqa: F401
    projected_probe_surfaces, projected_probe_surfaces_rows,
)
from .geometry import (  # noqa: F401
    points_covered_by_quads,
)
