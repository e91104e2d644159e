"""One force pass per env step: the implicit step's linearisation (``BatchedImplicitEuler.linearise``,
``ImplicitEuler.linearise``) is the measurement's pass and the next step's."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the tasks)
from sim_core.models.forces import ForceWorkspace, external_forces
from sim_core.models.stack import StackedForceWorkspace


@pytest.mark.parametrize("task", ["TumorPositioning", "Palpation", "Retraction"])
def test_one_force_pass_per_step_and_same_measures(task, monkeypatch):
    env = gym.make(f"tissue_env/{task}-v0")
    env.reset(seed=3)
    env.action_space.seed(3)
    unwrapped = env.unwrapped
    calls = []
    original, stacked = ForceWorkspace.compute, StackedForceWorkspace.compute

    def counting(self, *args, **kwargs):
        calls.append(1)
        return stacked(self, *args, **kwargs)

    monkeypatch.setattr(StackedForceWorkspace, "compute", counting)
    steps = 12
    for _ in range(steps):
        env.step(env.action_space.sample())
        # the measured forces are those of a separate pass with the damping in the fused kernel
        state = unwrapped.state
        reference = ForceWorkspace(unwrapped.model, implicit=False)
        expected = (original(reference, state.positions.copy(), state.velocities.copy())
                    + external_forces(unwrapped.model, unwrapped.control))
        scale = np.abs(expected).max()
        np.testing.assert_allclose(unwrapped.measures["forces"], expected, rtol=0, atol=1e-12 * scale)
    # without the shared pass a step computes the forces twice (step and measurement)
    assert len(calls) == steps


def test_linearise_is_reused_only_at_the_same_positions_and_model():
    from sim_core import HexMesh, Material, build_model
    from sim_core.solvers.integrators import ImplicitEuler
    from sim_core.models.model import State

    mesh = HexMesh.block((3, 3, 3), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    other = build_model(mesh, Material(8e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    control = model.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control.impose(bottom, mesh.nodes[bottom])
    rng = np.random.default_rng(0)
    a = mesh.nodes + 1e-4 * rng.standard_normal(mesh.nodes.shape)
    b = mesh.nodes + 1e-4 * rng.standard_normal(mesh.nodes.shape)

    def step(integrator, positions, which=model):
        state, out = State(positions.copy(), np.zeros_like(positions)), State(positions.copy(), np.zeros_like(positions))
        integrator.simulate(which, state, out, 0.01, control)
        return out.positions

    for prepared, positions, which in ((a, b, model), (a, a, model), (a, a, other)):
        integrator = ImplicitEuler(tolerance=1e-10)
        integrator.linearise(model, prepared)
        np.testing.assert_array_equal(step(integrator, positions, which), step(ImplicitEuler(tolerance=1e-10), positions, which))
    # positions changed in place after the pass are not taken for the old ones
    integrator = ImplicitEuler(tolerance=1e-10)
    moved = a.copy()
    integrator.linearise(model, moved)
    moved += 1e-4
    np.testing.assert_array_equal(step(integrator, moved), step(ImplicitEuler(tolerance=1e-10), moved))
