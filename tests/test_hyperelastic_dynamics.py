"""baudet-hyperelastic in every solver and environment (docs/physics.md section 11, "Implicit step"):
the stress correction's stiffness in the implicit system (matrix-free and assembled), its SPD
treatment, the stacked N-world model, the explicit time step, and the tasks with
``model="baudet-hyperelastic"``. Each test states its tolerance, through the public API.
"""

import warnings

import gymnasium as gym
import numpy as np
import pytest

import tissue_env
from sim_core import HexMesh, Material, build_model, kernels, solve_static
from sim_core.models.forces import ForceWorkspace, internal_forces, stiffness_data
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, run, stable_time_step
from sim_core.solvers.preconditioners import pattern_arrays
from sim_core.models.stack import ModelStack, StackedForceWorkspace
from sim_core.solvers.static import tangent_stiffness
from sim_core.models.stress_correction import tangent_matrices

MODEL = "baudet-hyperelastic"
TASKS = sorted(tissue_env.ENV_IDS)


def _box(shape=(4, 3, 5), spacing=(0.01, 0.012, 0.009), young_modulus=5e3, nu=0.45, gravity=-9.81):
    mesh = HexMesh.block(shape, np.asarray(spacing))
    return build_model(mesh, Material(young_modulus, nu, 1060.0), model=MODEL, gravity=(0.0, gravity, 0.0))


def _perturbed(model, scale, seed=0):
    rng = np.random.default_rng(seed)
    return model.mesh.nodes + scale * rng.standard_normal(model.mesh.nodes.shape)


def _assembled(workspace, model, scales):
    values = np.empty(model.pattern.nnz)
    kernels.operator_matrix_data(workspace.operator_data, scales, model.spring_positions, model.element_positions,
                                 pattern_arrays(model)[0], model.pattern.diagonal_positions, values)
    return model.pattern.matrix(values).tocsr()


@pytest.mark.parametrize("scale", [1e-4, 1e-3], ids=["1% strain", "10% strain"])
def test_operator_product_equals_the_assembled_matrix_and_the_system_is_spd(scale):
    """The matrix-free system operator (kernels.apply_operator) equals the assembled matrix
    (kernels.operator_matrix_data, the factorised preconditioner's) times a vector to 1e-13 of the
    product, both include the stress correction's clamped blocks (numpy reference
    stiffness_data(clamp=True) to 1e-12), and M + dt D + dt^2 K is positive definite (dt 40 ms) at
    random states of 1% and 10% strain (where the correction's exact block is indefinite)."""
    model = _box()
    positions = _perturbed(model, scale)
    workspace = ForceWorkspace(model)
    workspace.compute(positions, None, geometric=True)
    dt = 0.04
    scales = (1.0, dt, dt * dt, 0.0, 0.0, 0.0)
    vector = np.random.default_rng(1).standard_normal(positions.size)
    product = np.empty_like(vector)
    kernels.apply_operator(workspace.operator_data, scales, np.ones_like(vector), vector, product)
    matrix = _assembled(workspace, model, scales)
    assert np.abs(matrix @ vector - product).max() <= 1e-13 * np.abs(product).max()
    reference = model.pattern.matrix(stiffness_data(model, positions, clamp=True, stiffness_scale=dt * dt,
                                                    damping_scale=dt, mass_scale=1.0)).tocsr()
    assert abs(matrix - reference).max() <= 1e-12 * abs(reference).max()
    assert np.linalg.eigvalsh(matrix.toarray()).min() > 0
    exact = tangent_matrices(model.stress_correction, model.mesh.elements, positions)
    assert np.linalg.eigvalsh(0.5 * (exact + exact.swapaxes(1, 2))).min() < 0  # the clamp has work to do


def test_clamped_correction_stiffness_matches_its_reference_and_is_exact_where_positive():
    """The compiled pass's clamped 9 x 9 stiffness per element equals the numpy reference
    (stress_correction.tangent_matrices(clamp=True)) to 1e-12 of its largest entry, every block is
    positive semi-definite (eigenvalues above -1e-10 of the largest), and at rest (no stress) the
    clamp changes nothing: the exact tangent, to 1e-12."""
    model = _box()
    correction = model.stress_correction
    for positions, at_rest in ((model.mesh.nodes.copy(), True), (_perturbed(model, 1e-3), False)):
        workspace = ForceWorkspace(model)
        workspace.compute(positions, None, geometric=True)
        clamped = workspace.stress_tangent
        reference = tangent_matrices(correction, model.mesh.elements, positions, clamp=True)
        top = np.abs(reference).max()
        assert np.abs(clamped - reference).max() <= 1e-12 * top
        eigen = np.linalg.eigvalsh(0.5 * (clamped + clamped.swapaxes(1, 2)))
        assert eigen.min() >= -1e-10 * eigen.max()
        if at_rest:
            exact = tangent_matrices(correction, model.mesh.elements, positions)
            assert np.abs(clamped - exact).max() <= 1e-12 * top



@pytest.mark.parametrize("stretch, shear", [
    ((0.8, 0.8, 0.8), 0.0),  # three equal negative eigenvalues
    ((0.8, 1.0, 1.0), 0.0),  # three negative, two of them equal
    ((0.9, 0.9, 1.24), 0.0),  # two equal negative, one positive
    ((0.85, 0.9, 1.3), 0.1),  # two distinct negative, one positive
    ((0.7, 1.2, 1.2), 0.0),  # one negative, two equal positive
    ((0.8, 1.05, 1.2), 0.1),  # one negative, two distinct positive
    ((1.1, 1.2, 1.15), 0.1),  # none negative
], ids=["3-equal", "3-negative", "2-equal", "2-distinct", "1-equal-rest", "1-distinct", "0"])
def test_clamped_stiffness_matches_its_reference_for_every_sign_pattern(stretch, shear):
    """Under homogeneous deformations of a block of cubes (stretches along the axes, a shear, a
    rotation) whose correction stress dS has three, two, one or no negative eigenvalues, repeated
    or distinct (the ids), the compiled pass's clamped stiffness (its negative part of dS in closed
    form) equals the numpy reference's (LAPACK's eigen-decomposition) to 1e-12 of its largest entry
    in every element, and differs from the unclamped stiffness in every element where dS has a
    negative eigenvalue."""
    model = build_model(HexMesh.block((4, 3, 5), 0.01), Material(5e3, 0.45, 1060.0), model=MODEL)
    angle = 0.3
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    # the shear turns dS's eigenvectors off the axes (every entry of its negative part nonzero)
    gradient = rotation @ np.diag(stretch) @ (np.eye(3) + shear * np.array([[0, 1, 0.6], [0, 0, 0.8], [0, 0, 0]]))
    positions = model.mesh.nodes @ gradient.T
    workspace = ForceWorkspace(model)
    workspace.compute(positions, None, geometric=True)
    correction, elements = model.stress_correction, model.mesh.elements
    reference = tangent_matrices(correction, elements, positions, clamp=True)
    top = np.abs(reference).max(axis=(1, 2))
    assert np.all(np.abs(workspace.stress_tangent - reference).max(axis=(1, 2)) <= 1e-12 * top)
    changed = np.abs(reference - tangent_matrices(correction, elements, positions)).max(axis=(1, 2)) > 1e-6 * top
    assert np.all(changed) or stretch[0] > 1.0

def test_unclamped_operator_equals_finite_differences_of_the_forces():
    """Unclamped (Newton's tangent, ForceWorkspace.compute(exact=True)), the operator's stiffness
    product K v equals central finite differences of the internal forces (step 1e-7 m) to 1e-6 of
    |K v|, and the assembled tangent (static.tangent_stiffness) equals the numpy stiffness_data to
    1e-12, at a random state of 5% strain."""
    model = _box()
    positions = _perturbed(model, 5e-4)
    workspace = ForceWorkspace(model)
    workspace.compute(positions, None, geometric=True, exact=True)
    scales = (0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    vector = np.random.default_rng(2).standard_normal(positions.size)
    product = np.empty_like(vector)
    kernels.apply_operator(workspace.operator_data, scales, np.ones_like(vector), vector, product)
    h = 1e-7
    step = h * vector.reshape(-1, 3)
    difference = -(internal_forces(model, positions + step) - internal_forces(model, positions - step)).ravel() / (2 * h)
    assert np.abs(product - difference).max() <= 1e-6 * np.abs(product).max()
    tangent = tangent_stiffness(model, positions)
    reference = model.pattern.matrix(stiffness_data(model, positions)).tocsr()
    assert abs(tangent - reference).max() <= 1e-12 * abs(reference).max()
    assert np.abs(tangent @ vector - product).max() <= 1e-12 * np.abs(product).max()


@pytest.mark.parametrize("nu", [0.3, 0.45, 0.49, 0.499])
@pytest.mark.parametrize("young_modulus", [1e3, 1e4, 1e5])
def test_implicit_euler_is_stable_at_the_env_steps_and_settles_on_the_static_equilibrium(nu, young_modulus):
    """ImplicitEuler (factorised preconditioner, tolerance 1e-8) at the environments' steps (20 and
    40 ms) on a 6 x 4 x 6 block of 1 cm cubes, bottom held, top centre pressed 2 mm and released
    (a moving, loaded state), then held: no instability, and after 3 s held it is at rest
    (|v| < 1e-9 m/s) on solve_static's equilibrium (tolerance 1e-10) to 1e-7 of the sag."""
    mesh = HexMesh.block((6, 4, 6), 0.01)
    model = build_model(mesh, Material(young_modulus, nu, 1060.0), model=MODEL, gravity=(0.0, -9.81, 0.0))
    nodes = mesh.nodes
    bottom = np.flatnonzero(nodes[:, 1] == 0)
    top = np.flatnonzero(np.isclose(nodes[:, 1], nodes[:, 1].max()))
    patch = top[np.linalg.norm(nodes[top][:, [0, 2]] - 0.03, axis=1) <= 0.011]
    for dt in (0.02, 0.04):
        integrator = ImplicitEuler(tolerance=1e-8, preconditioner="factorised")
        state = model.new_state()
        for depth in list(np.linspace(0.0, 0.002, 6)) + list(np.linspace(0.002, 0.0, 6)):
            control = model.new_control().impose(bottom, nodes[bottom]).impose(patch, nodes[patch] - [0, depth, 0],
                                                                                components=1)
            report = run(model, state, integrator, dt, 1, control)
            assert not report.unstable, (dt, report.unstable_reason)
        control = model.new_control().impose(bottom, nodes[bottom]).impose(patch, nodes[patch], components=1)
        report = run(model, state, integrator, dt, int(round(3.0 / dt)), control)
        assert not report.unstable, (dt, report.unstable_reason)
        static = solve_static(model, control, tolerance=1e-10)
        assert static.converged
        sag = np.abs(static.positions - nodes).max()
        assert np.abs(state.positions - static.positions).max() <= 1e-7 * sag
        assert np.abs(state.velocities).max() < 1e-9


def test_explicit_time_step_accounts_for_the_correction():
    """stable_time_step includes the correction's stiffness (at nu = 0.49 its limit is under half the
    springs' alone); SymplecticEuler runs 0.3 s stably at 0.8x the limit and diverges at 1.5x."""
    mesh = HexMesh.block((4, 3, 4), 0.01)
    material = Material(1e4, 0.49, 1060.0)
    model = build_model(mesh, material, model=MODEL, gravity=(0.0, -9.81, 0.0))
    springs = build_model(mesh, material, model=MODEL, corrections=False)
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control = model.new_control().impose(bottom, mesh.nodes[bottom])
    dt = stable_time_step(model, control)
    assert dt < 0.5 * stable_time_step(springs, control)
    assert not run(model, model.new_state(), SymplecticEuler(), 0.8 * dt, int(0.3 / (0.8 * dt)), control).unstable
    assert run(model, model.new_state(), SymplecticEuler(), 1.5 * dt, int(0.3 / (1.5 * dt)), control).unstable


def test_stacked_copies_each_their_material_equal_the_single_models():
    """A ModelStack of three copies with their own E and nu: its stacked correction arrays are the
    copies' (assign), the stacked force pass and tangent equal each single model's bit for bit, on
    one thread and on two (kernels.stress_correction_*_copies), and ImplicitEuler (every
    solver) settles each copy on its own static equilibrium to 1e-6 of the sag."""
    from sim_core.solvers.implicit import PRECONDITIONERS, ImplicitEuler
    from sim_core.models.model import Control, State

    mesh = HexMesh.block((3, 2, 3), 0.01)
    models = [build_model(mesh, Material(e, nu, 1060.0), model=MODEL, gravity=(0.0, -9.81, 0.0))
              for e, nu in ((2e3, 0.3), (5e3, 0.49), (1e4, 0.45))]
    stack = ModelStack(models[0], 3)
    # a first pass builds the passes' element-last arrays of the stack: assign must rewrite them too
    StackedForceWorkspace(stack, implicit=True, threads=1).compute(stack.model.mesh.nodes, None, geometric=True)
    for index, model in enumerate(models):
        stack.assign(index, model)
    positions = [_perturbed(model, 3e-4, seed=i) for i, model in enumerate(models)]
    flat = np.concatenate(positions)
    for threads in (1, 2):
        workspace = StackedForceWorkspace(stack, implicit=True, threads=threads)
        workspace.compute(flat, None, geometric=True)
        for index, model in enumerate(models):
            single = ForceWorkspace(model)
            single.compute(positions[index], None, geometric=True)
            nodes = slice(index * mesh.n_nodes, (index + 1) * mesh.n_nodes)
            elements = slice(index * mesh.n_elements, (index + 1) * mesh.n_elements)
            np.testing.assert_array_equal(workspace.forces[nodes], single.forces)
            np.testing.assert_array_equal(workspace.stress_tangent[elements], single.stress_tangent)
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control = models[0].new_control().impose(bottom, mesh.nodes[bottom])
    statics = [solve_static(model, control, tolerance=1e-10).positions for model in models]
    fixed = np.repeat(control.fixed[None], 3, axis=0)
    target = np.repeat(control.target[None], 3, axis=0)
    for solver in PRECONDITIONERS:
        integrator = ImplicitEuler(stack, tolerance=1e-10, preconditioner=solver, threads=1)
        state = State(np.repeat(mesh.nodes[None], 3, axis=0), np.zeros((3, mesh.n_nodes, 3)))
        for index, model in enumerate(models):
            integrator.prepare(index, model, mesh.nodes, 0.04, control.fixed)
        for _ in range(60):
            report = integrator.step(state, state, Control(fixed, target, np.zeros_like(target)), 0.04)
            assert not any(reason is not None for reason in report.unstable_reason), solver
        for index in range(3):
            sag = np.abs(statics[index] - mesh.nodes).max()
            assert np.abs(state.positions[index] - statics[index]).max() <= 1e-6 * sag, (solver, index)


# -- environments -------------------------------------------------------------------------------------
def test_env_model_keyword_is_validated():
    """model must be one of tissue_env.base.MODELS; hourglass_control > 0 and any volume_stiffness are
    refused with "baudet-hyperelastic" (they do not apply), and its defaults are 0 (not applied)."""
    from tissue_env.tumor_positioning import TumorPositioningEnv

    with pytest.raises(ValueError, match="model must be one of"):
        TumorPositioningEnv(model="fem")
    with pytest.raises(ValueError, match="hourglass_control does not apply"):
        TumorPositioningEnv(model=MODEL, hourglass_control=1.0)
    with pytest.raises(ValueError, match="volume_stiffness does not apply"):
        TumorPositioningEnv(model=MODEL, volume_stiffness=100.0)
    env = TumorPositioningEnv(model=MODEL, shape=(3, 3, 3), hourglass_control=0)
    assert env.model.name == MODEL and env.model.hourglass is None and not env.model.has_volume_forces
    baudet = TumorPositioningEnv(model="baudet", shape=(3, 3, 3))
    assert (baudet.hourglass_control, baudet.volume_stiffness) == (1.0, 100.0) and baudet.model.name == "baudet"


@pytest.mark.parametrize("env_id", TASKS)
def test_env_checker_and_1000_random_steps(env_id):
    """gymnasium's check_env passes with model="baudet-hyperelastic"; 1000 random steps (episodes
    reset as they end) raise nothing, and every observation and reward is finite; a step whose
    physics fails is flagged (info["unstable"] with its reason), never a silent non-finite value."""
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id, model=MODEL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped, skip_render_check=True)
    random_steps(env, 1000, seed=0)
    env.close()


def random_steps(env, count, seed, stable=False):
    """``count`` random steps from ``env.reset(seed=seed)``, resetting as episodes end: every
    observation and reward finite, ``info["unstable"]`` set exactly when a reason is given (and
    never, if ``stable``)."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(count):
        observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert np.all(np.isfinite(observation)) and np.isfinite(reward)
        assert info["unstable"] == (info["unstable_reason"] is not None)
        assert not (stable and info["unstable"]), info["unstable_reason"]
        if terminated or truncated:
            env.reset()


@pytest.mark.parametrize("env_id", TASKS)
def test_env_static_and_explicit_integrators(env_id):
    """integrator="static" (an equilibrium per step) and "explicit" (at a quarter of the stable time
    step of the task's model) step the tasks with model="baudet-hyperelastic": 10 random steps,
    finite observations; the static steps are stable, and an explicit step that diverges is
    flagged (the explicit integrator takes the tool's whole move in one physics step: measured,
    "baudet" diverges on Retraction's 10th step at half its limit too)."""
    probe = gym.make(env_id, model=MODEL).unwrapped
    probe.reset(seed=0)
    dt = 0.25 * stable_time_step(probe.model, probe.start_control)
    for options in (dict(integrator="static"), dict(integrator="explicit", dt=dt)):
        env = gym.make(env_id, model=MODEL, **options)
        random_steps(env, 10, seed=1, stable=options["integrator"] == "static")
        env.close()
