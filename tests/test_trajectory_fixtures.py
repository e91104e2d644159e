"""Every task replays its recorded trajectories (tests/fixtures/trajectories.py) bit for bit: the
single env and the vector env, three seeds, 200 steps of fixed actions each, observations, rewards
and episode ends. A change that is meant to restructure code without changing results keeps them;
one that changes results on purpose re-records them (``python tests/fixtures/trajectories.py``)
and says why in its commit message.

Bitwise equality holds on the kind of machine and library versions the fixtures were recorded
with (BLAS and numba pick their instructions per CPU); elsewhere the test is skipped."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import tissue_env

# tests/fixtures/trajectories.py is a script (it re-records the fixtures), loaded by its path
_spec = importlib.util.spec_from_file_location("trajectories", Path(__file__).parent / "fixtures" / "trajectories.py")
trajectories = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(trajectories)

FIXTURES = np.load(trajectories.PATH)
SAME_MACHINE = str(FIXTURES["machine"]) == trajectories.machine()
pytestmark = pytest.mark.skipif(not SAME_MACHINE, reason=(
    f"fixtures recorded on {FIXTURES['machine']}, this is {trajectories.machine()}: bitwise replay "
    "needs the same CPU and library versions"))


def _recorded(name):
    """Skip a task whose fixtures were not recorded on the fixtures' machine yet (a task added on another
    machine: ``python tests/fixtures/trajectories.py --task ID`` there adds it)."""
    if f"{name}/vector/obs" not in FIXTURES.files:
        pytest.skip(f"no fixtures recorded for {name} yet")


@pytest.mark.parametrize("env_id", sorted(tissue_env.ENV_IDS))
@pytest.mark.parametrize("seed", trajectories.SEEDS)
def test_single_env_replays_its_fixture_bit_for_bit(env_id, seed):
    name = env_id.split("/")[1]
    _recorded(name)
    obs, rewards, done = trajectories.single_run(env_id, seed)
    np.testing.assert_array_equal(obs, FIXTURES[f"{name}/single/{seed}/obs"])
    np.testing.assert_array_equal(rewards, FIXTURES[f"{name}/single/{seed}/reward"])
    np.testing.assert_array_equal(done, FIXTURES[f"{name}/single/{seed}/done"])


@pytest.mark.parametrize("env_id", sorted(tissue_env.ENV_IDS))
def test_vector_env_replays_its_fixture_bit_for_bit(env_id):
    name = env_id.split("/")[1]
    _recorded(name)
    obs, rewards, done = trajectories.vector_run(env_id)
    np.testing.assert_array_equal(obs, FIXTURES[f"{name}/vector/obs"])
    np.testing.assert_array_equal(rewards, FIXTURES[f"{name}/vector/reward"])
    np.testing.assert_array_equal(done, FIXTURES[f"{name}/vector/done"])
