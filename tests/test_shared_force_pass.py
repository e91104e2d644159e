"""One force pass per env step: the implicit step's linearisation (``ImplicitEuler.linearise``,
``ImplicitEuler.linearise``) is the measurement's pass and the next step's."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the tasks)
from sim_core.models.forces import ForceWorkspace, external_forces
from sim_core.models.stack import StackedForceWorkspace


# Palpation solves a step again while its probe's contact set changes (1.4 solves an env step), so its
# force passes per step are not one: the shared pass is checked on the one-solve tasks
@pytest.mark.parametrize("task", ["TumorPositioning", "Retraction"])
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
    """A step from linearised positions reuses that force pass; from other positions, after the
    world's model changed, or after the positions changed in place, it makes its own: the steps
    equal those of a fresh solver bit for bit."""
    from sim_core import HexMesh, Material, ModelStack, build_model
    from sim_core.solvers.integrators import ImplicitEuler
    from sim_core.models.model import Control, State

    mesh = HexMesh.block((3, 3, 3), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    other = build_model(mesh, Material(8e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    control = model.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control.impose(bottom, mesh.nodes[bottom])
    rng = np.random.default_rng(0)
    a = mesh.nodes + 1e-4 * rng.standard_normal(mesh.nodes.shape)
    b = mesh.nodes + 1e-4 * rng.standard_normal(mesh.nodes.shape)

    def step(integrator, positions):
        state = State(positions[None].copy(), np.zeros((1,) + positions.shape))
        out = State(None, None)
        integrator.step(state, out, Control(control.fixed[None], control.target[None], None), 0.01)
        return out.positions[0]

    def fresh(which=model):
        return ImplicitEuler(ModelStack(which, 1), tolerance=1e-10)

    for prepared, positions in ((a, b), (a, a)):
        integrator = fresh()
        integrator.linearise(prepared.copy())
        np.testing.assert_array_equal(step(integrator, positions), step(fresh(), positions))
    # the world's model changed after the pass
    integrator = fresh()
    integrator.linearise(a.copy())
    integrator.stack.assign(0, other)
    integrator.model_changed(0)
    np.testing.assert_array_equal(step(integrator, a), step(fresh(other), a))
    # positions changed in place after the pass are not taken for the old ones
    integrator = fresh()
    moved = a.copy()
    integrator.linearise(moved)
    moved += 1e-4
    np.testing.assert_array_equal(step(integrator, moved), step(fresh(), moved))
