"""A copied environment (``copy.deepcopy``, a pickle round trip) steps with the kernels its original
compiled: numba compiles one machine code per signature, and a copy whose arrays or operator data
changed type (a writeable mesh, a plain tuple for ``kernels.OperatorData``) would compile every
kernel it calls again (minutes of CPU). Counted through each kernel's ``signatures``."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the tasks)
from sim_core import kernels


def _signatures() -> dict:
    """Compiled signatures of every kernel ``sim_core.kernels`` exports, by name."""
    return {name: len(kernel.signatures) for name, kernel in vars(kernels).items()
            if hasattr(kernel, "py_func") and hasattr(kernel, "signatures")}


@pytest.mark.parametrize("env_id", ["tissue_env/TumorPositioning-v0", "tissue_env/BimanualExposure-v0"])
def test_a_copied_env_compiles_no_kernel_its_original_did_not(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(env.action_space.low, env.action_space.high,
                                               (3,) + env.action_space.shape).astype(env.action_space.dtype)
    env.step(actions[0])
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    # the original first: every kernel and signature these steps call
    last = [env.step(action) for action in actions][-1][0]
    compiled = _signatures()
    assert sum(compiled.values()) > 0
    for twin in copies:
        twin_last = [twin.step(action) for action in actions][-1][0]
        np.testing.assert_array_equal(twin_last, last)  # the same steps, so the same code paths
    grown = {name: (count, len(getattr(kernels, name).signatures)) for name, count in compiled.items()
             if len(getattr(kernels, name).signatures) != count}
    assert not grown, f"kernels compiled again for a copy (signatures before, after): {grown}"
