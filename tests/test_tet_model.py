"""The tetrahedral mesh and mass-spring models (docs/physics.md section 12) against references nobody
tuned: closed-form stresses of homogeneous deformations of one tetrahedron, finite differences,
scikit-fem's independent linear elasticity on the same tetrahedra, finite elements on the same
tetrahedra, and the hexahedral FEM of the same block for the cantilever."""

import contextlib

import numpy as np
import pytest
import skfem
from skfem.models.elasticity import lame_parameters as skfem_lame
from skfem.models.elasticity import linear_elasticity

from sim_core import HexMesh, Material, State, TetMesh, build_model, solve_static
from sim_core.solvers.fem import LinearFEM
from sim_core.models.forces import internal_forces, stiffness_data
from sim_core.solvers.hyperelastic import NeoHookeanFEM
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, stable_time_step
from sim_core.models.model import Control
from sim_core.models.stack import ModelStack
from sim_core.solvers.static import tangent_stiffness, zero_energy_modes
from sim_core.studies import experiments

E, RHO = 1e4, 1000.0
MODELS = ("baudet", "baudet-hyperelastic")


# -- the mesh ----------------------------------------------------------------------------------
def test_block_splits_the_hex_block_on_its_nodes_conformingly():
    tet, hexes = TetMesh.block((3, 2, 4), (0.1, 0.05, 0.02)), HexMesh.block((3, 2, 4), (0.1, 0.05, 0.02))
    assert np.array_equal(tet.nodes, hexes.nodes) and tet.shape == hexes.shape
    assert tet.n_elements == 6 * hexes.n_elements
    volumes = tet.element_volumes()
    assert np.all(volumes > 0) and np.isclose(volumes.sum(), 0.3 * 0.1 * 0.08, rtol=1e-12)
    # conforming: every boundary quad of the hex block is exactly two boundary triangles, no
    # interior face is left unmatched
    faces = tet.surface_faces()
    assert len(faces) == 2 * len(hexes.surface_faces())
    assert np.array_equal(tet.surface_nodes(), hexes.surface_nodes())
    # outward: the divergence theorem, V = 1/3 sum over faces of x . n dA
    x = tet.nodes[faces]
    normal_area = 0.5 * np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    assert np.isclose(np.einsum("fi,fi->", x.mean(axis=1), normal_area) / 3.0, volumes.sum(), rtol=1e-12)
    assert np.array_equal(TetMesh.from_hex(hexes).elements, tet.elements)


def test_bad_tetrahedra_are_refused():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    TetMesh(nodes, [[0, 1, 2, 3]])
    with pytest.raises(ValueError, match="inverted tetrahedron 0.*positive"):
        TetMesh(nodes, [[0, 2, 1, 3]])
    with pytest.raises(ValueError, match="degenerate"):
        TetMesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]), [[0, 1, 2, 3]])
    with pytest.raises(ValueError, match=r"shape \(M, 4\)"):
        TetMesh(nodes, [[0, 1, 2, 3, 0]])
    with pytest.raises(ValueError, match="appears twice"):
        TetMesh(nodes, [[0, 1, 1, 3]])
    with pytest.raises(ValueError, match="must lie in"):
        TetMesh(nodes, [[0, 1, 2, 4]])


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_files_round_trip_and_bad_files_name_themselves(tmp_path, suffix):
    mesh = TetMesh.block((2, 1, 1), 0.1)
    path = tmp_path / f"block{suffix}"
    mesh.write(path)
    back = TetMesh.read(path)
    assert np.array_equal(back.elements, mesh.elements) and np.allclose(back.nodes, mesh.nodes, rtol=0, atol=1e-15)
    hexes = tmp_path / f"hexes{suffix}"
    HexMesh.block((1, 1, 1), 0.1).write(hexes)
    with pytest.raises(ValueError, match=f"{hexes.name}.*no tetrahedra.*1 hexahedron"):
        TetMesh.read(hexes)
    corrupt = tmp_path / f"corrupt{suffix}"
    corrupt.write_bytes(b"not a mesh at all\n" * 4)
    with pytest.raises(ValueError, match=corrupt.name):
        TetMesh.read(corrupt)


# -- one tetrahedron: exact stresses, objectivity, balance, tangent -------------------------------
def _one_tet():
    nodes = np.array([[0.0, 0.0, 0.0], [0.03, 0.004, -0.002], [0.006, 0.025, 0.003], [-0.004, 0.005, 0.02]])
    return TetMesh(nodes, [[0, 1, 2, 3]])


def _stress_from_forces(mesh, forces):
    """sigma (small strain) or P (first Piola) = -(1/V0) sum_a f_a (x) X_a: the nodal forces of a
    homogeneous stress on a linear tetrahedron are f_a = -V0 P b_a with sum_a b_a (x) X_a = I."""
    return -np.einsum("ai,aj->ij", forces, mesh.nodes) / mesh.element_volumes()[0]


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.49])
def test_one_tet_small_strain_model_gives_hookes_stress_exactly(nu):
    """baudet on a tetrahedron: any homogeneous strain gives sigma = lambda tr(eps) I + 2 mu eps to
    rounding (1e-9 relative), whatever the springs carry; an infinitesimal rotation gives none."""
    mesh = _one_tet()
    model = build_model(mesh, Material(E, nu, RHO), model="baudet")
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    gradient = np.array([[2e-3, 1e-3, -4e-4], [3e-4, -1e-3, 5e-4], [-2e-4, 7e-4, 1.5e-3]])
    strain = 0.5 * (gradient + gradient.T)
    forces = internal_forces(model, mesh.nodes + mesh.nodes @ gradient.T)
    expected = lam * np.trace(strain) * np.eye(3) + 2 * mu * strain
    assert np.allclose(_stress_from_forces(mesh, forces), expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    skew = 1e-6 * np.array([[0, 1, -2], [-1, 0, 3], [2, -3, 0]])
    spin = internal_forces(model, mesh.nodes + mesh.nodes @ skew.T)
    assert np.abs(spin).max() < 1e-9 * np.abs(forces).max() * 1e-3


def test_one_tet_hyperelastic_model_is_neo_hookean_and_objective():
    """baudet-hyperelastic on a tetrahedron under a large F: P = mu (F - F^-T) + lambda ln J F^-T to
    1e-10; forces and moments balance; rotating the deformed element rotates its forces; a rigid
    rotation gives no force."""
    mesh = _one_tet()
    nu = 0.45
    model = build_model(mesh, Material(E, nu, RHO), model="baudet-hyperelastic")
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    f = np.array([[1.3, 0.25, -0.1], [0.15, 0.8, 0.3], [-0.2, 0.1, 1.1]])
    x = mesh.nodes @ f.T + np.array([0.1, -0.2, 0.05])
    forces = internal_forces(model, x)
    inverse_t = np.linalg.inv(f).T
    expected = mu * (f - inverse_t) + lam * np.log(np.linalg.det(f)) * inverse_t
    assert np.allclose(_stress_from_forces(mesh, forces), expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    assert np.abs(forces.sum(axis=0)).max() < 1e-12 * np.abs(forces).max()
    assert np.abs(np.cross(x, forces).sum(axis=0)).max() < 1e-12 * np.abs(forces).max() * np.abs(x).max()
    angle = 1.1
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1.0]])
    rotation = rotation @ np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
    assert np.allclose(internal_forces(model, x @ rotation.T), forces @ rotation.T, rtol=0,
                       atol=1e-10 * np.abs(forces).max())
    assert np.abs(internal_forces(model, mesh.nodes @ rotation.T)).max() < 1e-10 * np.abs(forces).max()


@pytest.mark.parametrize("name", MODELS)
def test_tangent_equals_finite_differences(name):
    """static.tangent_stiffness (springs' exact geometric term plus the correction's tangent) is
    -d(forces)/dx: central differences of the compiled forces at a deformed 2x1x1 block agree to 1e-6."""
    mesh = TetMesh.block((2, 1, 1), 0.02)
    model = build_model(mesh, Material(E, 0.4, RHO), model=name)
    rng = np.random.default_rng(3)
    x = mesh.nodes @ np.array([[1.1, 0.1, 0], [0, 0.9, 0.05], [0.02, 0, 1.05]]).T + 1e-3 * rng.standard_normal(
        mesh.nodes.shape)
    stiffness = tangent_stiffness(model, x).toarray()
    h = 1e-7
    numeric = np.empty_like(stiffness)
    for dof in range(x.size):
        step = np.zeros(x.size)
        step[dof] = h
        numeric[:, dof] = -(internal_forces(model, x + step.reshape(-1, 3))
                            - internal_forces(model, x - step.reshape(-1, 3))).ravel() / (2 * h)
    assert np.abs(stiffness - numeric).max() < 1e-6 * np.abs(stiffness).max()


# -- an independent FEM: scikit-fem -------------------------------------------------------------
def test_linear_fem_on_tets_matches_scikit_fem():
    """fem-linear on tetrahedra against scikit-fem's P1 linear elasticity on the same nodes and
    tetrahedra: the stiffness matrices to 1e-12 and the cantilever under gravity (clamped at x = 0) to
    1e-8 of the tip displacement; the tetrahedral mass-spring model "baudet" solves to the same
    equilibrium to 1e-6 (the static solver's force tolerance)."""
    mesh = TetMesh.block((6, 2, 2), 0.02)
    nu = 0.3
    material = Material(E, nu, RHO)
    fem = LinearFEM(mesh, material)
    sk_mesh = skfem.MeshTet(mesh.nodes.T.copy(), mesh.elements.T.copy())
    basis = skfem.Basis(sk_mesh, skfem.ElementVector(skfem.ElementTetP1()))
    order = basis.nodal_dofs.T.ravel()  # ours: node-major x y z
    stiffness = skfem.asm(linear_elasticity(*skfem_lame(E, nu)), basis)[order][:, order].toarray()
    assert np.abs(fem.stiffness.toarray() - stiffness).max() < 1e-12 * np.abs(stiffness).max()

    gravity = (0.0, -9.81, 0.0)

    @skfem.LinearForm
    def weight(v, w):
        return RHO * gravity[1] * v[1]

    clamp = np.flatnonzero(mesh.nodes[:, 0] == 0)
    load = skfem.asm(weight, basis)
    reference = skfem.solve(*skfem.condense(skfem.asm(linear_elasticity(*skfem_lame(E, nu)), basis), load,
                                            D=basis.nodal_dofs[:, clamp].ravel()))[order].reshape(-1, 3)
    control = Control.free(mesh.n_nodes).impose(clamp, mesh.nodes[clamp])
    positions, _ = fem.solve(control, gravity)
    tip = np.abs(reference).max()
    assert tip > 1e-4
    assert np.abs(positions - mesh.nodes - reference).max() < 1e-8 * tip
    model = build_model(mesh, material, model="baudet", gravity=gravity, smoothing="none")
    equilibrium = solve_static(model, control, tolerance=1e-10)
    assert equilibrium.converged
    assert np.abs(equilibrium.positions - mesh.nodes - reference).max() < 1e-6 * tip


# -- the experiments on the tetrahedral block --------------------------------------------------------
@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("nu", [0.1, 0.3, 0.45])
def test_tet_elongation_measures_e_and_nu(name, nu):
    """1% elongation of a 4x2x2 block of tetrahedra: E within 2% and nu within 0.02 of the imposed."""
    result = experiments.elongation((4, 2, 2), 0.1, E, nu, strain=0.01, model=name, element="tet")
    assert result.converged
    assert abs(result.young_modulus / E - 1) < 0.02
    assert abs(result.poisson_ratio - nu) < 0.02


def test_tet_elongation_under_force_spreads_the_load_consistently():
    """A force-controlled pull (the face load spread over the triangles, 1/3 of each triangle's area
    per node) stretches the block homogeneously: E within 0.5% at 0.5% strain."""
    force = 0.005 * E * 0.2 * 0.2
    result = experiments.elongation((4, 2, 2), 0.1, E, 0.3, force=force, model="baudet", element="tet")
    assert abs(result.young_modulus / E - 1) < 0.005
    spread = result.positions[:, 0][np.isclose(result.rest_positions[:, 0], 0.4)]
    assert np.ptp(spread) < 1e-9 * 0.4


@pytest.mark.parametrize("name", MODELS)
def test_tet_cantilever_against_hexahedral_fem(name):
    """A 1 x 0.5 x 0.4 m cantilever under its own weight (tip deflection 1.4% of its length), nu = 0.3,
    20x10x8 cubes: the tetrahedral models' tip deflection within 10% of fem-linear on the hexahedra of
    the same nodes (measured +1.2% with the default smoothed strain; 3.4% low with smoothing="none",
    each linear tetrahedron's own strain, stiffer in bending). The hexahedral
    reference is converged to about 1%: it moves 2.5% from 10x5x4 to 20x10x8 cubes, so its
    second-order extrapolation is 0.8% beyond it."""
    reference = experiments.flexion((20, 10, 8), 0.05, 5e6, 0.3, density=RHO, model="fem-linear")
    result = experiments.flexion((20, 10, 8), 0.05, 5e6, 0.3, density=RHO, model=name, element="tet")
    assert result.converged
    assert abs(result.tip_deflection / reference.tip_deflection - 1) < 0.10


@pytest.mark.parametrize("name, reference, angle", [("baudet", "fem-linear", 5.0),
                                                     ("baudet-hyperelastic", "fem-neohookean", 5.0),
                                                     ("baudet-hyperelastic", "fem-neohookean", 30.0)])
def test_tet_shear_against_fem_on_the_same_tetrahedra(name, reference, angle):
    """Simple shear of a 3x3x3 block of tetrahedra, up to 30 degrees, each tetrahedron on its own
    strain (smoothing="none"): %e_dm below 5% against FEM of the same law on the same tetrahedra (the
    element energies are the same, so it is at the solvers' tolerance: below 1e-4 %)."""
    fem = experiments.shear((3, 3, 3), 0.1, E, 0.4, angle_deg=angle, model=reference, element="tet")
    with pytest.warns(UserWarning) if angle > experiments.VALIDATED_SHEAR_DEG else contextlib.nullcontext():
        mss = experiments.shear((3, 3, 3), 0.1, E, 0.4, angle_deg=angle, model=name, element="tet",
                                smoothing="none")
    e_dm, e_max = experiments.position_errors(mss, fem)
    assert mss.converged and fem.converged
    assert e_dm < 5.0 and e_dm < 1e-4
    assert abs(mss.shear_modulus / fem.shear_modulus - 1) < 1e-6


def test_experiments_refuse_unknown_elements_and_hexahedral_only_models():
    with pytest.raises(ValueError, match=r"element must be one of \('hex', 'tet'\)"):
        experiments.elongation((2, 2, 2), 0.1, E, 0.3, strain=0.01, element="quad")
    with pytest.raises(ValueError, match="needs hexahedra"):
        experiments.shear((2, 2, 2), 0.1, E, 0.3, angle_deg=2, model="baudet-original", element="tet")


# -- build_model's refusals --------------------------------------------------------------------
@pytest.mark.parametrize("options, message", [
    (dict(model="uniform-springs"), "needs hexahedra"),
    (dict(hourglass_control=1.0), "hourglass_control=1.0.*does not apply to a TetMesh"),
    (dict(volume_conservation=True), "volume_conservation=True.*does not apply to a TetMesh"),
    (dict(model="baudet-hyperelastic", springs="isotropic"), "springs='isotropic'.*6 edges"),
])
def test_build_model_refuses_hexahedral_options_on_tets(options, message):
    with pytest.raises(ValueError, match=message):
        build_model(TetMesh.block((1, 1, 1), 0.1), Material(E, 0.3, RHO), **options)


# -- the solvers ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", MODELS)
def test_dynamics_settle_on_the_static_equilibrium(name):
    """A 4x1x1 cantilever of tetrahedra released under gravity: damped implicit Euler at 20x the
    explicit limit (``stable_time_step``) settles on solve_static's equilibrium to 1e-8 of the sag;
    symplectic Euler stays bounded at 0.8x the limit and its divergence at 2x is reported (not a
    crash or NaN); the ModelStack's batched implicit Euler steps each copy as the single solver does
    (1e-9 of the sag)."""
    mesh = TetMesh.block((4, 1, 1), 0.025)
    model = build_model(mesh, Material(1e5, 0.3, RHO), model=name, gravity=(0, -9.81, 0), damping_ratio=2.0)
    clamp = np.flatnonzero(mesh.nodes[:, 0] == 0)
    control = model.new_control().impose(clamp, mesh.nodes[clamp])
    static = solve_static(model, control, tolerance=1e-10).positions
    sag = np.abs(static - mesh.nodes).max()
    limit = stable_time_step(model, control)

    def run(integrator, dt, steps):
        state, scratch = model.new_state(), model.new_state()
        for _ in range(steps):
            report = integrator.simulate(model, state, scratch, dt, control)
            state, scratch = scratch, state
            if report.unstable:
                return state, report
        return state, report

    state, report = run(ImplicitEuler(tolerance=1e-12), 20 * limit, 300)
    assert not report.unstable and np.abs(state.positions - static).max() < 1e-8 * sag
    state, report = run(SymplecticEuler(), 0.8 * limit, 1000)
    assert not report.unstable and np.abs(state.positions - mesh.nodes).max() < 2 * sag
    _, report = run(SymplecticEuler(), 2.0 * limit, 1000)
    assert report.unstable
    stack = ModelStack(model, 2)
    batched = ImplicitEuler(stack, preconditioner="factorised", tolerance=1e-12)
    single = ImplicitEuler(tolerance=1e-12)
    dt = 20 * limit
    positions = np.stack([mesh.nodes] * 2)
    for world in range(2):
        batched.prepare(world, model, positions[world], dt, control.fixed)
    states = [model.new_state(), model.new_state()]
    stacked = Control(np.stack([control.fixed] * 2), np.stack([control.target] * 2), np.zeros_like(positions))
    state, scratch = State(positions.copy(), np.zeros_like(positions)), State(positions.copy(), np.zeros_like(positions))
    for _ in range(10):
        batched.step(state, scratch, stacked, dt)
        state, scratch = scratch, state
        single.simulate(model, states[0], states[1], dt, control)
        states = states[::-1]
    assert np.abs(state.positions - states[0].positions[None]).max() < 1e-9 * sag


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("nu", [0.0, 0.3, 0.49])
def test_springs_never_exceed_the_element_and_a_free_block_has_only_rigid_modes(name, nu):
    """Each tetrahedron on its own strain (smoothing="none"): at rest the springs' stiffness is
    bounded by the element's (K - K_springs positive
    semi-definite, to 1e-9 of the largest eigenvalue), so the implicit step's positive part leaves
    the correction's stiffness as it is (to 1e-12); a free 2x2x2 block of tetrahedra has exactly its 6 rigid
    zero-energy modes."""
    mesh = TetMesh.block((2, 1, 1), 0.01)
    material = Material(E, nu, RHO)
    model = build_model(mesh, material, model=name, smoothing="none")
    full = stiffness_data(model, mesh.nodes)
    assert np.abs(stiffness_data(model, mesh.nodes, clamp=True) - full).max() < 1e-12 * np.abs(full).max()
    springs = model.pattern.matrix(stiffness_data(build_model(mesh, material, model=name, corrections=False,
                                                              smoothing="none"), mesh.nodes)).toarray()
    difference = np.linalg.eigvalsh(model.pattern.matrix(full).toarray() - springs)
    assert difference.min() > -1e-9 * difference.max()
    count, _, _ = zero_energy_modes(build_model(TetMesh.block((2, 2, 2), 0.01), material, model=name,
                                                smoothing="none"))
    assert count == 6
