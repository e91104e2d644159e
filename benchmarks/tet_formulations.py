"""Which linear-tetrahedron formulation bends right at tissue Poisson ratios: a study that chooses
the tetrahedral model's next formulation by measured accuracy.

sim_core's tetrahedral model is, at small strain, exactly the linear tetrahedron (constant strain
per element, "FEM-T4"): it locks as nu -> 0.5 and is stiff in bending at every nu. This study
assembles the small-strain stiffness of candidate formulations on the same nodes (numpy / scipy,
no sim_core kernel) and solves the static cantilever of ``benchmarks.cantilever_reference``
(1 x 0.2 x 0.2 m, clamped at x = 0, 10 N tip load in -y, 20 x 4 x 4 cubes each split into 6
tetrahedra: 1920 tetrahedra):

* ``FEM-T4``: the constant-strain tetrahedron (the model today).
* ``ANP``: its deviatoric part per element, the volumetric part from node-averaged volume
  change (average nodal pressure; the node-based smoothed volumetric strain): one volumetric
  constraint per node instead of per element, which removes volumetric locking.
* ``ES-FEM``: the strain smoothed over edge domains (each edge's domain takes 1/6 of the volume
  of each tetrahedron around it), deviatoric and volumetric.
* ``ES/NS-FEM``: the edge-smoothed deviatoric strain with the node-smoothed volumetric strain
  (the selective smoothed FEM): ES-FEM's bending with ANP's incompressibility.
* ``NSdev+ANP``: the deviatoric strain node-smoothed too (an upper bound on the deflection).

Each smoothed strain is a volume-weighted average of the elements' constant strains, so every
formulation passes the patch test (a linear displacement field gives the exact uniform strain
everywhere) and keeps the element stiffness's rigid modes.

Writes ``benchmarks/results/tet_formulations.json``: per nu, each formulation's mean tip
deflection and its ratio to the locking-free reference when its results file exists, else to
Timoshenko beam theory. Run: ``python -m benchmarks.tet_formulations``. SI units.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sim_core import Material, build_model
from sim_core.geometry.tetmesh import TetMesh
from sim_core.models.elements import quadrature, strain_displacement
from sim_core.models.forces import stiffness_data
from training.common import write_json

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
POISSON_RATIOS = (0.3, 0.45, 0.49, 0.499)
YOUNG = 1.0e4  # Pa
DENSITY = 1000.0  # kg/m^3, the reference's
LOAD = 10.0  # N, total tip load in -y
SHAPE = (20, 4, 4)  # cubes of 0.05 m along x, y, z
#: Voigt form of the identity (the volumetric direction)
TRACE = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


def deviatoric_matrix(mu: float) -> np.ndarray:
    """The (6, 6) Voigt matrix of 2 mu dev(eps) (engineering shear strains), Pa."""
    matrix = np.zeros((6, 6))
    matrix[:3, :3] = 2.0 * mu * (np.eye(3) - 1.0 / 3.0)
    matrix[3:, 3:] = mu * np.eye(3)
    return matrix


def element_strains(nodes: np.ndarray, elements: np.ndarray):
    """(B (M, 6, 12), volumes (M,)): each linear tetrahedron's Voigt strain-displacement matrix
    (1/m) and volume (m^3), from sim_core's element quadrature (one exact point)."""
    gradients, weights = quadrature(nodes, elements)
    return strain_displacement(gradients[:, 0]), weights[:, 0]


def smoothing(elements: np.ndarray, volumes: np.ndarray, kind: str):
    """(domain of each (element, share) pair, the pair's element, its weight, domain volumes) for
    smoothing domains ``kind``: "element" (the elements themselves), "edge" (1/6 of each element
    per edge) or "node" (1/4 of each element per corner). A domain's smoothed strain is the
    weighted sum of its elements' strains (weights sum to 1)."""
    count = len(elements)
    if kind == "element":
        return np.arange(count), np.arange(count), np.ones(count), volumes
    if kind == "edge":
        pairs = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
        keys = np.sort(elements[:, pairs], axis=2).reshape(-1, 2)
        share = 6
    elif kind == "node":
        keys = elements.reshape(-1, 1)
        share = 4
    else:
        raise ValueError(f"kind must be 'element', 'edge' or 'node', got {kind!r}")
    _, domain = np.unique(keys, axis=0, return_inverse=True)
    domain = domain.ravel()
    owner = np.repeat(np.arange(count), share)
    part = np.repeat(volumes / share, share)
    domain_volume = np.bincount(domain, weights=part)
    return domain, owner, part / domain_volume[domain], domain_volume


def smoothed_stiffness(n_nodes, elements, strain, volumes, kind: str, material: np.ndarray) -> sp.csr_matrix:
    """K = sum over smoothing domains d of V_d B_d^T D B_d with B_d the weighted sum of its
    elements' B (``smoothing``), D the (6, 6) ``material`` matrix: (3 n, 3 n) N/m."""
    domain, owner, weight, domain_volume = smoothing(elements, volumes, kind)
    dofs = (3 * elements[:, :, None] + np.arange(3)).reshape(len(elements), 12)
    values = strain[owner] * weight[:, None, None]
    rows = np.broadcast_to((6 * domain)[:, None, None] + np.arange(6)[None, :, None], values.shape)
    columns = np.broadcast_to(dofs[owner][:, None, :], values.shape)
    smoothed = sp.csr_matrix((values.ravel(), (rows.ravel(), columns.ravel())),
                             shape=(6 * len(domain_volume), 3 * n_nodes))
    return (smoothed.T @ sp.kron(sp.diags(domain_volume), sp.csr_matrix(material)) @ smoothed).tocsr()


def formulations(mesh: TetMesh, young: float, nu: float) -> dict:
    """Each formulation's stiffness (3 n, 3 n) N/m (module docstring)."""
    mu, bulk = young / (2.0 * (1.0 + nu)), young / (3.0 * (1.0 - 2.0 * nu))
    strain, volumes = element_strains(mesh.nodes, mesh.elements)
    deviatoric, volumetric = deviatoric_matrix(mu), bulk * np.outer(TRACE, TRACE)

    def part(kind, material):
        return smoothed_stiffness(mesh.n_nodes, mesh.elements, strain, volumes, kind, material)

    element_dev, edge_dev, node_dev = part("element", deviatoric), part("edge", deviatoric), part("node", deviatoric)
    element_vol, edge_vol, node_vol = part("element", volumetric), part("edge", volumetric), part("node", volumetric)
    return {"FEM-T4": element_dev + element_vol, "ANP": element_dev + node_vol, "ES-FEM": edge_dev + edge_vol,
            "ES/NS-FEM": edge_dev + node_vol, "NSdev+ANP": node_dev + node_vol}


def tip_deflection(mesh: TetMesh, stiffness: sp.csr_matrix, load: float = LOAD) -> float:
    """Mean -u_y (m) of the tip face (x = max) under ``load`` N spread equally over its nodes,
    the x = 0 face clamped."""
    nodes = mesh.nodes
    tip = np.flatnonzero(np.isclose(nodes[:, 0], nodes[:, 0].max()))
    clamped = np.flatnonzero(np.isclose(nodes[:, 0], 0.0))
    force = np.zeros(3 * mesh.n_nodes)
    force[3 * tip + 1] = -load / len(tip)
    free = np.setdiff1d(np.arange(3 * mesh.n_nodes), (3 * clamped[:, None] + np.arange(3)).ravel())
    displacement = np.zeros(3 * mesh.n_nodes)
    displacement[free] = spla.spsolve(stiffness[free][:, free].tocsc(), force[free])
    return float(-displacement[3 * tip + 1].mean())


def timoshenko(young: float, nu: float, length=1.0, side=0.2, load=LOAD) -> float:
    """Timoshenko cantilever tip deflection (m) of a square section: P L^3 / (3 E I) + P L / (k G A),
    k = 10 (1 + nu) / (12 + 11 nu)."""
    inertia, area, shear = side**4 / 12.0, side**2, young / (2.0 * (1.0 + nu))
    return load * length**3 / (3.0 * young * inertia) + load * length / (10.0 * (1 + nu) / (12 + 11 * nu) * shear * area)


def reference_deflections(young: float) -> dict | None:
    """{nu: converged locking-free tip deflection (m)} from ``benchmarks.cantilever_reference``'s
    results, scaled to ``young``; None where that file is missing."""
    path = RESULTS / "cantilever_reference.json"
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    scale = data["problem"]["young_modulus_pa"] / young
    return {float(row["poisson_ratio"]): -scale * float(row["convergence"]["tip_mean_uy"]["extrapolated"])
            for row in data["results"]}


def bending_frequency(mesh: TetMesh, stiffness: sp.csr_matrix, masses: np.ndarray) -> float:
    """The lowest eigenfrequency (Hz) of the clamped (x = 0) cantilever with lumped node masses (kg)."""
    clamped = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    free = np.setdiff1d(np.arange(3 * mesh.n_nodes), (3 * clamped[:, None] + np.arange(3)).ravel())
    mass = sp.diags(np.repeat(masses, 3)[free]).tocsc()
    value = spla.eigsh(stiffness[free][:, free].tocsc(), k=1, M=mass, sigma=0.0, which="LM")[0][0]
    return float(np.sqrt(value) / (2 * np.pi))


def reference_frequencies() -> dict | None:
    """{nu: converged first bending frequency (Hz)} from ``benchmarks.cantilever_reference``'s results
    (E and rho as here), or None where that file is missing."""
    path = RESULTS / "cantilever_reference.json"
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    return {float(row["poisson_ratio"]): float(row["convergence"]["bending_frequency"]["extrapolated"])
            for row in data["results"]}


def main():
    start = time.perf_counter()
    mesh = TetMesh.block(SHAPE, 1.0 / SHAPE[0])
    references, frequencies = reference_deflections(YOUNG), reference_frequencies()
    rows = []
    for nu in POISSON_RATIOS:
        reference = references.get(nu) if references else None
        against = reference if reference is not None else timoshenko(YOUNG, nu)
        # sim_core's tetrahedral model (its default smoothing) on the same mesh, assembled by sim_core
        model = build_model(mesh, Material(YOUNG, nu, DENSITY), model="baudet")
        candidates = dict(formulations(mesh, YOUNG, nu))
        candidates["sim_core baudet"] = model.pattern.matrix(stiffness_data(model, mesh.nodes)).tocsr()
        for name, stiffness in candidates.items():
            deflection = tip_deflection(mesh, stiffness)
            frequency = bending_frequency(mesh, stiffness, model.mass)
            row = dict(poisson_ratio=nu, formulation=name, tip_deflection=deflection, ratio=deflection / against,
                       against="reference" if reference is not None else "timoshenko", bending_frequency=frequency)
            if frequencies:
                row["frequency_ratio"] = frequency / frequencies[nu]
            rows.append(row)
            print(f"nu {nu:<5} {name:<16} tip {deflection:.4e} m  ratio {deflection / against:.3f}  "
                  f"f {frequency:.4f} Hz")
    write_json(RESULTS / "tet_formulations.json", dict(
        command="python -m benchmarks.tet_formulations", mesh=f"{SHAPE} cubes split into 6 tetrahedra each",
        young_modulus=YOUNG, density=DENSITY, masses="lumped, rho V / 4 per node of each tetrahedron (sim_core's)",
        load=LOAD, rows=rows, seconds=time.perf_counter() - start))


if __name__ == "__main__":
    main()
