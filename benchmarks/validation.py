"""Validation lab (issue 3): the report's Fig. 12-17 reproduced, our model beside them, FEM as truth.

    python -m benchmarks.validation            # every figure (about 10-15 minutes on 2 cores)
    python -m benchmarks.validation --only 1 4 # a subset (--only 8 9 10 11 12 13 14: the large-deformation set)

Writes docs/figures/validation_*.png (matplotlib, Agg), one CSV per figure in benchmarks/results/
and benchmarks/results/validation_summary.json (the number that sums up each figure, quoted in
docs/validation.md). Material everywhere: E = 1e4 Pa, rho = 1500 kg/m^3 (docs/physics.md section 7).

Grids chosen to keep the run short (each is said in the figure's title and in docs/validation.md):
- Elongation (Fig. 1, 5): a 4x4x4 block. With these boundary conditions the exact solution of every
  model is a homogeneous deformation, so any block size measures the same E, nu and volume change
  on that branch (the script checks 4x4x4 against 10x10x10 at 10% strain); whether a large block
  leaves that branch under compression is Fig. 6's subject.
- Position errors in elongation (Fig. 2): 6x6x6 block (the node set changes the rms slightly).
- Shear (Fig. 3): the report's 10x10x10 block; flexion (Fig. 4): the report's 10x5x4 cantilever.
- Tool loading (Fig. 5 bottom, Fig. 6 rows 3-4): a 6x6x6 block of 0.1 m cubes, bottom face fixed, the
  3x3 central nodes of the top face (a 0.2 m square tool) pressed (frictionless: only u_y imposed),
  lifted or dragged (glued: all components imposed), by a fraction of the 0.6 m height.

Figures 8-14 (issue 27) put ``baudet-hyperelastic`` (docs/physics.md section 11) beside ``baudet``
and the FEM laws at large deformation: tension/compression to +-30% (Fig. 8, 4x4x4), shear to 30
degrees (Fig. 9, 10x10x10), the 10x5x4 cantilever to large deflection (Fig. 10), unconfined
compression at nu 0.45-0.499 (Fig. 11), zero-energy mode counts (Fig. 12), objectivity (Fig. 13) and
refinement of a 1 x 0.2 x 0.2 m cantilever at 30% tip deflection against a 60x12x12 neo-Hookean
reference at nu = 0.3 (Fig. 14).

The figures live in sibling modules, this file runs them: benchmarks/validation_common.py (material,
labels, styles, shared set-ups, writers), validation_small_deformation.py (Fig. 1-5, 7),
validation_zero_energy.py (Fig. 6), validation_large_deformation.py (Fig. 8-12) and
validation_refinement.py (Fig. 13-14).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

from sim_core.files import atomic_write
from benchmarks.validation_common import RESULTS, SUMMARY
from benchmarks.validation_large_deformation import (
    figure_compression, figure_large_elongation, figure_large_flexion, figure_large_shear, figure_mode_counts)
from benchmarks.validation_refinement import figure_objectivity, figure_refinement
from benchmarks.validation_small_deformation import (
    figure_elongation_errors, figure_flexion, figure_moduli, figure_non_cubic, figure_shear, figure_volume)
from benchmarks.validation_zero_energy import figure_zero_energy_modes

FIGURE_FUNCTIONS = {1: figure_moduli, 2: figure_elongation_errors, 3: figure_shear, 4: figure_flexion,
                    5: figure_volume, 6: figure_zero_energy_modes, 7: figure_non_cubic,
                    8: figure_large_elongation, 9: figure_large_shear, 10: figure_large_flexion,
                    11: figure_compression, 12: figure_mode_counts, 13: figure_objectivity, 14: figure_refinement}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", type=int, nargs="+", choices=sorted(FIGURE_FUNCTIONS), help="figures to make")
    args = parser.parse_args(argv)
    # the figures load the mass-spring models beyond their validated range on purpose
    warnings.filterwarnings("ignore", message=".*beyond the range the mass-spring model is validated for.*")
    summary_path = RESULTS / "validation_summary.json"
    if args.only and summary_path.exists():
        SUMMARY.update(json.loads(summary_path.read_text()))
    timings = SUMMARY.setdefault("wall_time_s", {})
    for number in args.only or sorted(FIGURE_FUNCTIONS):
        start = time.perf_counter()
        FIGURE_FUNCTIONS[number]()
        timings[str(number)] = round(time.perf_counter() - start, 1)
        key = next(k for k in SUMMARY if k.startswith(f"{number}_"))
        print(f"Fig. {number} ({timings[str(number)]} s): {SUMMARY[key]['headline']}", flush=True)
        # after every figure, atomically: a run stopped part way keeps the figures it made
        RESULTS.mkdir(parents=True, exist_ok=True)
        atomic_write(summary_path, json.dumps(SUMMARY, indent=1,
                                              default=lambda v: v.item() if hasattr(v, "item") else str(v)))


if __name__ == "__main__":
    main()
