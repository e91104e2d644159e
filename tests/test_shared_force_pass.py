"""One force pass per env step: ``ImplicitEuler.linearise`` is the measurement's pass and the next step's."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the tasks)
from sim_core.forces import ForceWorkspace, external_forces


@pytest.mark.parametrize("task", ["TumorPositioning", "Palpation", "Retraction"])
def test_one_force_pass_per_step_and_same_measures(task, monkeypatch):
    env = gym.make(f"tissue_env/{task}-v0")
    env.reset(seed=3)
    env.action_space.seed(3)
    unwrapped = env.unwrapped
    calls = []
    original = ForceWorkspace.compute

    def counting(self, *args, **kwargs):
        calls.append(1)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(ForceWorkspace, "compute", counting)
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
