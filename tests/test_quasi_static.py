"""Quasi-static stepping (``integrator="static"``): every step is the static (contact) equilibrium."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the tasks)
from sim_core import HexMesh, Material, build_model
from sim_core.solvers import contact
from sim_core.models.forces import external_forces, internal_forces
from sim_core.solvers.integrators import make_integrator
from sim_core.models.model import State
from sim_core.resolution import dynamic_scene, solve_scene
from sim_core.solvers.static import QuasiStatic

from benchmarks.env_accuracy import env_defaults, palpation_scenes


def test_a_step_is_an_equilibrium_with_zero_velocities():
    mesh = HexMesh.block((3, 3, 3), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    control = model.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 1], 0.03))
    control.impose(bottom, mesh.nodes[bottom]).impose(top, mesh.nodes[top] + [0.003, -0.002, 0.0])
    integrator = make_integrator("static", tolerance=1e-8)
    state, out = model.new_state(), model.new_state()
    report = integrator.simulate(model, state, out, 0.04, control)
    assert report.unstable_reason is None and out.time == pytest.approx(0.04)
    assert np.all(out.velocities == 0.0)
    forces = internal_forces(model, out.positions) + external_forces(model, control)
    free = ~control.fixed
    assert np.abs(forces[free]).max() <= 1e-6 * np.abs(forces[control.fixed]).max()


@pytest.mark.parametrize("keyword", [dict(tolerance=0.0), dict(max_iterations=0), dict(max_load_steps=0)])
def test_invalid_arguments(keyword):
    with pytest.raises(ValueError, match=next(iter(keyword))):
        QuasiStatic(**keyword)


def test_env_like_static_stepping_reads_the_static_contact_scene():
    """The probe at full speed, a static solve per step with the active set iterated (sliding
    heights included), reads the static scene's forces; with the set updated once per step (or
    without the heights following the sliding) the deepest press between nodes read 11.5% more at (8, 4, 8)."""
    alpha, kappa = env_defaults()
    for scene in palpation_scenes()[1:]:
        stepped, *_, reason = dynamic_scene(scene, (6, 3, 6), dt=0.04, substeps=1, max_step=0.004, hold_steps=0,
                                            hourglass_control=alpha, volume_stiffness=kappa, solver_tolerance=1e-2,
                                            integrator="static")
        assert reason is None
        static = solve_scene(scene, (6, 3, 6), hourglass_control=alpha, volume_stiffness=kappa, check_stability=False)
        np.testing.assert_allclose(stepped.force, static.force, rtol=0, atol=1e-3 * np.abs(static.force).max())


@pytest.mark.parametrize("task", ["Palpation", "Retraction"])
def test_env_static_steps_end_on_the_contact_equilibrium(task):
    env = gym.make(f"tissue_env/{task}-v0", integrator="static")
    env.reset(seed=1)
    unwrapped = env.unwrapped
    for _ in range(8):
        _, _, terminated, truncated, info = env.step(unwrapped.scripted_action())
        assert not info["unstable"]
        state, control = unwrapped.state, unwrapped.control
        assert np.all(state.velocities == 0.0)
        forces = unwrapped.measures["forces"]
        free = ~control.fixed
        scale = np.abs(forces).max()
        assert np.abs(forces[free]).max() <= 1e-4 * scale  # equilibrium on every free component
        if task == "Palpation":
            gaps = contact.gap(unwrapped.probe, state.positions, unwrapped.probe_start + unwrapped.tool_offset)
            candidates = np.isin(np.arange(unwrapped.mesh.n_nodes), unwrapped.top_nodes)  # the probe's
        else:
            gaps = state.positions[:, 1]
            # the floor's: every node but the attached and the grasped ones
            candidates = ~np.isin(np.arange(unwrapped.mesh.n_nodes), np.union1d(unwrapped.fixed_nodes, unwrapped.tool_nodes))
        assert np.all(gaps[candidates & ~unwrapped.contact] >= -1e-7)  # nothing through the obstacle
        assert np.all(np.abs(gaps[unwrapped.contact]) <= 1e-6)  # the held nodes on its surface
        if terminated or truncated:
            break


@pytest.mark.parametrize("task", ["Palpation", "Retraction"])
def test_vector_env_steps_static_as_the_single_envs(task):
    """The vector env's static worlds (one QuasiStatic per world, the contact's active set iterated
    per world) take the single envs' steps: observations within 1e-6 over 6 steps of a contact."""
    env_id = f"tissue_env/{task}-v0"
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", integrator="static")
    sync = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync", integrator="static")
    observations = [vector.reset(seed=0)[0], sync.reset(seed=0)[0]]
    np.testing.assert_allclose(observations[0], observations[1], rtol=0, atol=1e-6)
    actions = np.tile(np.array([0.5, -1.0, 0.25], np.float32) if task == "Palpation" else
                      np.array([0.0, 1.0, 0.0], np.float32), (2, 1))
    for _ in range(6):
        v, s = vector.step(actions), sync.step(actions)
        np.testing.assert_allclose(v[0], s[0], rtol=0, atol=1e-6)
        np.testing.assert_allclose(v[1], s[1], rtol=0, atol=1e-6)
        assert not v[4]["unstable"].any()
    vector.close()
    sync.close()


def test_state_velocities_zero_make_damping_vanish():
    mesh = HexMesh.block((2, 2, 2), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0))
    state = State(mesh.nodes.copy(), np.zeros_like(mesh.nodes))
    out = state.copy()
    QuasiStatic().simulate(model, state, out, 0.01, model.new_control())
    np.testing.assert_allclose(out.positions, mesh.nodes, atol=1e-12)


def test_kept_tangent_saves_factorisations_not_accuracy(monkeypatch):
    from sim_core.solvers import static

    mesh = HexMesh.block((4, 4, 4), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 1], 0.04))
    calls = []
    # the static solves factorise with scipy's sparse LU (the direct solver, up to
    # static.DIRECT_DOF_LIMIT free dofs): count the LU factorisations
    import scipy.sparse.linalg as spla

    assert 3 * mesh.n_nodes <= static.DIRECT_DOF_LIMIT
    splu = spla.splu
    monkeypatch.setattr(spla, "splu", lambda *args, **kwargs: calls.append(1) or splu(*args, **kwargs))
    integrator = QuasiStatic(tolerance=1e-8)
    state, out = model.new_state(), model.new_state()
    steps = 10
    for k in range(1, steps + 1):
        control = model.new_control().impose(bottom, mesh.nodes[bottom]).impose(top, mesh.nodes[top] + [0.0005 * k, 0, 0])
        assert integrator.simulate(model, state, out, 0.04, control).unstable_reason is None
        state, out = out, state
    assert len(calls) < steps  # a factorisation per step (or more) without the kept tangent
    fresh = static.solve_static(model, control, initial=model.rest_positions, tolerance=1e-10)
    np.testing.assert_allclose(state.positions, fresh.positions, rtol=0, atol=1e-6 * 0.005)


def test_an_inverted_equilibrium_is_reported_not_returned_silently():
    mesh = HexMesh.block((1, 1, 1), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0))
    target = mesh.nodes.copy()
    target[mesh.nodes[:, 1] > 0.005, 1] = -0.01  # the top face imposed below the bottom one
    control = model.new_control().impose(np.arange(mesh.n_nodes), target)
    state, out = model.new_state(), model.new_state()
    report = QuasiStatic().simulate(model, state, out, 0.01, control)
    assert report.unstable and "inverted element" in report.unstable_reason
    assert QuasiStatic(monitor=False).simulate(model, state, out, 0.01, control).unstable_reason is None


def test_dynamic_scene_names_its_integrators():
    alpha, kappa = env_defaults()
    with pytest.raises(ValueError, match="integrator must be 'implicit' or 'static', got 'explicit'"):
        dynamic_scene(palpation_scenes()[0], (4, 2, 4), dt=0.04, substeps=1, max_step=0.004, hold_steps=0,
                      hourglass_control=alpha, volume_stiffness=kappa, solver_tolerance=1e-2, integrator="explicit")
    with pytest.raises(ValueError, match="integrator must be one of"):
        make_integrator("quasistatic")
