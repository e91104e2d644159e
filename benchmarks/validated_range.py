"""The state range in which each mass-spring model is validated, for the validity monitor (issue 42, item 2).

Usage: python -m benchmarks.validated_range [--output benchmarks/results/validated_range.json]

The scene is the hanging cantilever of tests/test_hyperelastic_floors.py: 1 x 0.5 x 0.4 m of 0.1 m
hexahedra (10 x 5 x 4), E = 10 kPa, nu = 0.3, a body force of 3300 N/m^3, clamped at x = 0; its tip
drops about 1.14 m (extreme bending, as a retracted flap hangs). Each model's static equilibrium
(``solve_static``) is compared with converged neo-Hookean FEM on a twice finer 20 x 10 x 8 mesh
(``sim_core.studies.refinement.neo_hookean_chain``, an independent formulation): the tip's drop and
%e_dm (the RMS nodal displacement error over the largest displacement, in %). Where the model is
within 2% at the tip and 2 in %e_dm (tests/test_hyperelastic_floors.py's floor), the state's largest
spring strain |L / L0 - 1| and its elements' volume ratios V / V0 are inside the model's validated
range (``sim_core.models.validity.MODEL_RANGES`` is that range rounded inward); a model that misses
the floor keeps the default range (strain 0.2, volume ratio 0.8-1.2, benchmarks/validation.py).

Written to ``--output`` (JSON, replaced atomically).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.studies.refinement import block_displacement_at, clamped_control, neo_hookean_chain
from training.common import write_json

SHAPE, SPACING, YOUNG, POISSON, BODY_FORCE, GRAVITY = (10, 5, 4), 0.1, 1e4, 0.3, 3300.0, 9.81
MODELS = ("baudet-hyperelastic", "baudet")
#: the accuracy a state must have for its range to count as validated: tip error (relative) and %e_dm
TIP_FLOOR, E_DM_FLOOR = 0.02, 2.0


def state_range(mesh, model, positions):
    """(largest spring strain |L / L0 - 1|, smallest and largest element volume ratio V / V0)."""
    springs = model.springs
    rest = np.linalg.norm(mesh.nodes[springs[:, 1]] - mesh.nodes[springs[:, 0]], axis=1)
    length = np.linalg.norm(positions[springs[:, 1]] - positions[springs[:, 0]], axis=1)
    ratio = mesh.element_volumes(positions) / mesh.element_volumes()
    return float(np.abs(length / rest - 1.0).max()), float(ratio.min()), float(ratio.max())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "validated_range.json"))
    args = parser.parse_args(argv)
    mesh = HexMesh.block(SHAPE, SPACING)
    material = Material(YOUNG, POISSON, BODY_FORCE / GRAVITY)
    control = clamped_control(mesh)
    start = time.perf_counter()
    fine = HexMesh.block(tuple(2 * n for n in SHAPE), SPACING / 2)
    reference = block_displacement_at(fine, neo_hookean_chain([mesh, fine], material, GRAVITY)[-1], mesh.nodes)
    tip = np.isclose(mesh.nodes[:, 0], SHAPE[0] * SPACING)
    rows = {}
    for name in MODELS:
        model = build_model(mesh, material, model=name, gravity=(0.0, -GRAVITY, 0.0))
        result = solve_static(model, control)
        u = result.positions - mesh.nodes
        tip_error = float(u[tip, 1].mean() / reference[tip, 1].mean() - 1.0)
        e_dm = float(100.0 * np.sqrt(np.mean(np.sum((u - reference) ** 2, axis=1)))
                     / np.linalg.norm(reference, axis=1).max())
        strain, low, high = state_range(mesh, model, result.positions)
        validated = bool(result.converged and abs(tip_error) <= TIP_FLOOR and e_dm <= E_DM_FLOOR)
        rows[name] = dict(converged=bool(result.converged), tip_drop_m=float(-u[tip, 1].mean()), tip_error=tip_error,
                          e_dm_percent=e_dm, max_spring_strain=strain, volume_ratio_low=low, volume_ratio_high=high,
                          validated=validated)
        print(f"{name}: converged {result.converged}, tip {tip_error:+.2%}, %e_dm {e_dm:.2f}; largest spring strain "
              f"{strain:.3f}, volume ratio {low:.3f}-{high:.3f}: {'validated' if validated else 'not validated'}",
              flush=True)
    write_json(args.output, dict(
        command="python -m benchmarks.validated_range", scene=dict(
            shape=list(SHAPE), spacing_m=SPACING, young_modulus_pa=YOUNG, poisson_ratio=POISSON,
            body_force_n_m3=BODY_FORCE, clamp="x = 0", reference="fem-neohookean on 20 x 10 x 8 (neo_hookean_chain)",
            reference_tip_drop_m=float(-reference[tip, 1].mean())),
        floors=dict(tip=TIP_FLOOR, e_dm_percent=E_DM_FLOOR), models=rows,
        runtime_seconds=time.perf_counter() - start,
        machine=dict(platform=platform.platform(), cpus=os.cpu_count(), python=platform.python_version())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
