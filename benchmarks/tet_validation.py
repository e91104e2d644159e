"""The tetrahedral models (docs/physics.md section 12) measured on the block's cubes split into tetrahedra.

    python -m benchmarks.tet_validation        # about 3 minutes on 2 cores (2 of them the hexahedral
                                               # baudet-hyperelastic cantilever at nu = 0.499)

Writes benchmarks/results/tet_validation.json:
- ``elongation``: E and nu measured at 1% strain on a 4x2x2 block of tetrahedra (both models,
  nu 0.1 to 0.49), as tests/test_tet_model.py checks.
- ``spring_share``: the share of the small-strain energy the springs carry on the block's
  tetrahedra (``build_model(..., corrections=False)`` against the full model, both on each
  tetrahedron's own strain: smoothing="none") under a simple shear, a uniaxial strain and a
  dilatation, per nu.
- ``cantilever``: the tip deflection of a 1 x 0.5 x 0.4 m cantilever under its own weight
  (E = 5 MPa, rho = 1000 kg/m^3: 1.4% of its length at nu = 0.3) on 20x10x8 cubes for nu 0.3 to 0.499:
  the tetrahedral models (smoothed strain, the default, and "baudet" on each tetrahedron's own
  strain, ``tet_baudet_element_strain``), fem-linear on the tetrahedra and on the hexahedra of the same nodes (and on 10x5x4 cubes, its
  convergence) and the hexahedral baudet-hyperelastic (one deformation gradient per hexahedron, which
  does not lock), to show the volumetric locking of linear tetrahedra as nu -> 0.5.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from sim_core import Material, TetMesh, build_model
from sim_core.files import atomic_write
from sim_core.models.forces import internal_forces
from sim_core.studies import experiments

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results" / "tet_validation.json"
MODELS = ("baudet", "baudet-hyperelastic")


def elongation_rows():
    rows = []
    for model in MODELS:
        for nu in (0.1, 0.3, 0.45, 0.49):
            result = experiments.elongation((4, 2, 2), 0.1, 1e4, nu, strain=0.01, model=model, element="tet")
            rows.append(dict(model=model, poisson_ratio=nu, young_modulus_ratio=result.young_modulus / 1e4,
                             measured_poisson_ratio=result.poisson_ratio))
    return rows


def spring_share_rows():
    """W_springs / W_model under small homogeneous strains (1e-6) of a 2x2x2 block of tetrahedra."""
    mesh = TetMesh.block((2, 2, 2), 0.01)
    strains = {"shear_xy": np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0.0]]) * 0.5e-6,
               "uniaxial_xx": np.diag([1e-6, 0, 0]), "dilatation": np.eye(3) * 1e-6}
    rows = []
    for nu in (0.0, 0.3, 0.45, 0.49):
        material = Material(1e4, nu, 1000.0)
        springs = build_model(mesh, material, model="baudet", corrections=False, smoothing="none")
        full = build_model(mesh, material, model="baudet", smoothing="none")
        row = dict(poisson_ratio=nu)
        for name, strain in strains.items():
            displacement = mesh.nodes @ strain.T
            energy = [-0.5 * float(np.sum(displacement * internal_forces(m, mesh.nodes + displacement)))
                      for m in (springs, full)]
            row[name] = energy[0] / energy[1]
        rows.append(row)
    return rows


def cantilever_rows():
    rows = []
    for nu in (0.3, 0.45, 0.49, 0.499):
        row = dict(poisson_ratio=nu)
        for key, model, element, shape, spacing, options in (
                ("tet_baudet", "baudet", "tet", (20, 10, 8), 0.05, {}),
                ("tet_baudet_hyperelastic", "baudet-hyperelastic", "tet", (20, 10, 8), 0.05, {}),
                ("tet_baudet_element_strain", "baudet", "tet", (20, 10, 8), 0.05, dict(smoothing="none")),
                ("tet_fem_linear", "fem-linear", "tet", (20, 10, 8), 0.05, {}),
                ("hex_fem_linear", "fem-linear", "hex", (20, 10, 8), 0.05, {}),
                ("hex_fem_linear_coarse", "fem-linear", "hex", (10, 5, 4), 0.1, {}),
                ("hex_baudet_hyperelastic", "baudet-hyperelastic", "hex", (20, 10, 8), 0.05, {})):
            start = time.perf_counter()
            result = experiments.flexion(shape, spacing, 5e6, nu, density=1000.0, model=model, element=element,
                                         **options)
            row[key] = result.tip_deflection
            row[key + "_seconds"] = time.perf_counter() - start
            row[key + "_converged"] = bool(result.converged)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main():
    results = dict(command="python -m benchmarks.tet_validation", elongation=elongation_rows(),
                   spring_share=spring_share_rows(), cantilever=cantilever_rows())
    atomic_write(RESULTS, json.dumps(results, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
