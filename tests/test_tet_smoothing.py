"""Smoothed-strain tetrahedra (docs/physics.md section 12), the default of ``build_model(TetMesh, ...)``.

References nobody tuned: the locking-free Taylor-Hood cantilever of ``benchmarks.cantilever_reference``
(scikit-fem P2-P1, Richardson-extrapolated; its results file), an affine displacement field (the patch
test), the law's own stress under a homogeneous deformation, finite differences, and the smoothed
stiffness assembled independently in Voigt notation by ``benchmarks.tet_formulations``.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import sim_core
from sim_core import Material, TetMesh, build_model, solve_static
from sim_core.models.forces import internal_forces, stiffness_data
from sim_core.solvers.static import zero_energy_modes

REFERENCE = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "cantilever_reference.json"
E, RHO = 1e4, 1000.0  # Pa, kg/m^3: the reference's
BEAM = (20, 4, 4)  # cubes of 0.05 m: 1 x 0.2 x 0.2 m
MODELS = ("baudet", "baudet-hyperelastic")


def reference(nu):
    rows = json.loads(REFERENCE.read_text())["results"]
    return {key: value["extrapolated"] for key, value in next(
        row["convergence"] for row in rows if row["poisson_ratio"] == nu).items()}


def tip_load(mesh, total):
    """(N, 3) the consistent nodal forces (N) of a uniform traction in -y on the x = max face summing
    to ``total`` N: a third of each boundary triangle's share per corner."""
    faces = mesh.surface_faces()
    x = mesh.nodes[:, 0]
    faces = faces[np.all(np.isclose(x[faces], x.max()), axis=1)]
    corners = mesh.nodes[faces]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    load = np.zeros((mesh.n_nodes, 3))
    np.add.at(load[:, 1], faces.ravel(), -np.repeat(total * area / area.sum() / 3.0, 3))
    return load


def clamped(mesh):
    return np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))


@pytest.mark.parametrize("nu", [0.3, 0.45, 0.49, 0.499])
def test_cantilever_bends_within_5_percent_of_the_locking_free_reference(nu):
    """10 N on the tip of the 1 x 0.2 x 0.2 m cantilever of 20x4x4 cubes (1920 tetrahedra), linear
    elasticity: mean tip deflection within 5% of the converged Taylor-Hood value at every nu up to
    0.499 (measured +1.6%, -1.1%, -3.2%, -4.8% at 0.3, 0.45, 0.49, 0.499), where each tetrahedron's
    own strain (smoothing="none") locks: 21% short at 0.3, 92% at 0.499."""
    mesh = TetMesh.block(BEAM, 0.05)
    material = Material(E, nu, RHO)
    expected = -reference(nu)["tip_mean_uy"]
    load = tip_load(mesh, 10.0)
    tip = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 1.0))
    deflections = {}
    for smoothing in ("edge-node", "none"):
        model = build_model(mesh, material, model="baudet", smoothing=smoothing)
        control = model.new_control().impose(clamped(mesh), mesh.nodes[clamped(mesh)])
        control.force[:] = load
        result = solve_static(model, control, tolerance=1e-10)
        assert result.converged
        deflections[smoothing] = -(result.positions[tip, 1] - mesh.nodes[tip, 1]).mean() / expected
    assert abs(deflections["edge-node"] - 1) < 0.05
    assert deflections["none"] < (0.8 if nu == 0.3 else 0.15 if nu == 0.499 else 0.95)


@pytest.mark.parametrize("nu", [0.3, 0.499])
def test_first_bending_frequency_within_3_percent(nu):
    """The cantilever's first bending frequency (lumped masses) within 3% of the reference's
    (consistent masses, converged): measured -1.4% at 0.3 and +2.7% at 0.499, where each
    tetrahedron's own strain gives +8.6% and +185%."""
    mesh = TetMesh.block(BEAM, 0.05)
    model = build_model(mesh, Material(E, nu, RHO), model="baudet")
    free = np.setdiff1d(np.arange(3 * mesh.n_nodes), (3 * clamped(mesh)[:, None] + np.arange(3)).ravel())
    stiffness = model.pattern.matrix(stiffness_data(model, mesh.nodes)).tocsc()[free][:, free]
    mass = sp.diags(np.repeat(model.mass, 3)[free]).tocsc()
    values = spla.eigsh(stiffness, k=1, M=mass, sigma=0.0, which="LM")[0]
    frequency = np.sqrt(values[0]) / (2 * np.pi)
    assert abs(frequency / reference(nu)["bending_frequency"] - 1) < 0.03


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("nu", [0.0, 0.3, 0.499])
def test_patch_test_is_exact_on_an_irregular_mesh(name, nu):
    """The boundary of an irregular block (interior nodes moved by up to 20% of the spacing) on an
    affine field x -> F x at 10-20% strain: the interior nodes settle on it to 1e-8 of the motion,
    for the small-strain and the neo-Hookean law, and the nodal forces there are those of the
    elements' own law (smoothing="none", each tetrahedron exact) to 1e-9: every domain has F, and
    the law's split between edge and node domains sums to the whole law."""
    mesh = TetMesh.block((4, 3, 3), 0.1)
    rng = np.random.default_rng(3)
    boundary = np.unique(mesh.surface_faces())
    inner = ~np.isin(np.arange(mesh.n_nodes), boundary)
    mesh = TetMesh(mesh.nodes + rng.uniform(-0.02, 0.02, mesh.nodes.shape) * inner[:, None], mesh.elements)
    deformation = np.array([[1.1, 0.15, 0.0], [0.05, 0.9, 0.1], [0.0, -0.1, 1.2]])
    expected = mesh.nodes @ deformation.T
    material = Material(E, nu, RHO)
    model = build_model(mesh, material, model=name)
    control = model.new_control().impose(boundary, expected[boundary])
    result = solve_static(model, control, tolerance=1e-12)
    assert result.converged
    assert np.abs(result.positions - expected).max() < 1e-8 * np.abs(expected - mesh.nodes).max()
    forces = internal_forces(model, expected)
    elements = internal_forces(build_model(mesh, material, model=name, smoothing="none"), expected)
    assert np.abs(forces - elements).max() < 1e-9 * np.abs(elements).max()


@pytest.mark.parametrize("name", MODELS)
def test_free_block_has_only_rigid_modes_and_the_clamp_is_idle_at_rest(name):
    """A free 3x2x2 block of smoothed tetrahedra has exactly its 6 rigid zero-energy modes at
    nu = 0.3 and 0.499 (no spurious mode from the smoothing), and at rest the implicit step's positive
    part changes nothing (the stiffness is positive semi-definite)."""
    mesh = TetMesh.block((3, 2, 2), 0.01)
    for nu in (0.3, 0.499):
        model = build_model(mesh, Material(E, nu, RHO), model=name)
        count, _, _ = zero_energy_modes(model)
        assert count == 6
        full = stiffness_data(model, mesh.nodes)
        assert np.abs(stiffness_data(model, mesh.nodes, clamp=True) - full).max() < 1e-12 * np.abs(full).max()


def test_stiffness_equals_the_independent_voigt_assembly():
    """At rest the linear model's stiffness equals the edge-smoothed deviatoric plus node-smoothed
    volumetric stiffness that benchmarks/tet_formulations assembles in Voigt notation with scipy
    (another code: engineering strains, 6 x 6 material matrices) to 1e-10 of its largest entry."""
    formulations = pytest.importorskip("benchmarks.tet_formulations")
    mesh = TetMesh.block((3, 2, 2), 0.1)
    for nu in (0.3, 0.49):
        model = build_model(mesh, Material(E, nu, RHO), model="baudet")
        ours = model.pattern.matrix(stiffness_data(model, mesh.nodes)).toarray()
        theirs = formulations.formulations(mesh, E, nu)["ES/NS-FEM"].toarray()
        assert np.abs(ours - theirs).max() < 1e-10 * np.abs(theirs).max()


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("method", ["implicit", "explicit"])
def test_n_worlds_step_as_each_world_alone(name, method):
    """Three worlds of different materials (one with a tip force) in a ModelStack step bit for bit as
    each world alone, explicit and implicit."""
    mesh = TetMesh.block((6, 2, 2), 0.05)
    materials = [Material(1e4, 0.3, RHO), Material(3e4, 0.49, RHO), Material(5e3, 0.45, RHO)]
    models = [build_model(mesh, m, model=name, gravity=(0, -9.81, 0)) for m in materials]
    stack = sim_core.ModelStack(models[0], 3)
    for index, model in enumerate(models):
        stack.assign(index, model)
    fixed = clamped(mesh)
    control = stack.new_control()
    control.fixed[:, fixed] = True
    control.target[:, fixed] = mesh.nodes[fixed]
    control.force[1, -1, 1] = -0.5
    dt, steps = (0.01, 10) if method == "implicit" else (2e-4, 50)
    solver = sim_core.make_solver(method, stack)
    state, scratch = stack.new_state(), stack.new_state()
    for _ in range(steps):
        solver.step(state, scratch, control, dt)
        state, scratch = scratch, state
    for index, model in enumerate(models):
        alone = sim_core.make_solver(method, model)
        one, other = model.new_state(), model.new_state()
        single = model.new_control()
        single.fixed[:], single.target[:], single.force[:] = control.fixed[index], control.target[index], \
            control.force[index]
        for _ in range(steps):
            alone.step(one, other, single, dt)
            one, other = other, one
        assert np.array_equal(one.positions, state.positions[index])
    assert np.all(state.positions[:, -1, 1] < mesh.nodes[-1, 1])


def test_smoothing_option_is_checked():
    mesh = TetMesh.block((1, 1, 1), 0.1)
    with pytest.raises(ValueError, match=r"smoothing must be one of \('edge-node', 'none'\)"):
        build_model(mesh, Material(E, 0.3, RHO), smoothing="nodes")
    with pytest.raises(ValueError, match="applies to a TetMesh only"):
        build_model(sim_core.HexMesh.block((1, 1, 1), 0.1), Material(E, 0.3, RHO), smoothing="edge-node")
