"""Results must not depend on which compiled kernels numba loaded from its cache.

numba caches each kernel on its own. A kernel compiled in a process where its callees were loaded from
the cache must give the floats of the same kernel compiled with fresh callees, or the serial and
threaded twins of the vector envs (``kernels.solve_copies_lu_serial`` / ``solve_copies_lu`` ...) drift
apart by rounding depending on what earlier processes cached. With fastmath "reassoc" they did
(``kernels.FAST``): this test failed with it and passes without.
"""

import os
import subprocess
import sys

import numba
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: 4 copies of Palpation, 40 random steps, episodes of 12 (resets included); ``threads`` from argv,
#: the trajectory saved to argv[2]
SCRIPT = """
import sys
import gymnasium as gym
import numpy as np
import tissue_env

threads, path = int(sys.argv[1]), sys.argv[2]
envs = gym.make_vec("tissue_env/Palpation-v0", num_envs=4, vectorization_mode="vector_entry_point",
                    threads=threads, max_episode_steps=12)
rng = np.random.default_rng(5)
obs, _ = envs.reset(seed=11)
trace = [obs]
for _ in range(40):
    obs, reward, terminated, truncated, _ = envs.step(rng.uniform(-1, 1, (4, 3)).astype(np.float32))
    trace += [obs, reward]
envs.close()
np.savez(path, *trace)
"""


def _run(threads, path, cache):
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=ROOT)
    subprocess.run([sys.executable, "-c", SCRIPT, str(threads), str(path)], check=True, env=environment,
                   cwd=ROOT, timeout=900)
    with np.load(path) as data:
        return [data[f"arr_{i}"] for i in range(len(data.files))]


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two cores for numba's threads")
def test_threaded_kernels_compiled_against_cached_callees_give_the_serial_floats(tmp_path):
    """A first process (empty cache) runs the vector env on one thread: the serial kernels and their
    callees are compiled and cached. A second one runs it on two threads: the threaded kernels are
    compiled there, linked with the callees loaded from the cache. Both trajectories are equal bit
    for bit."""
    cache = tmp_path / "numba_cache"
    serial = _run(1, tmp_path / "serial.npz", cache)
    threaded = _run(2, tmp_path / "threaded.npz", cache)
    assert len(serial) == len(threaded) == 81
    for one, two in zip(serial, threaded):
        np.testing.assert_array_equal(one, two)


def test_a_kernel_cache_written_from_other_sources_is_dropped(tmp_path):
    """numba checks a cached kernel against its own file only; the kernels package drops its cache
    when any kernel module (or the topology constants they compile in) changed since it was written."""
    from sim_core.kernels import STAMP, drop_stale_cache

    source = tmp_path / "kernel.py"
    source.write_text("x = 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "kernel.f-1.py311.nbi").write_bytes(b"index")
    (cache / "kernel.f-1.py311.1.nbc").write_bytes(b"code")
    assert drop_stale_cache(cache, [source])  # no stamp yet: the cache's sources are unknown
    assert not list(cache.glob("*.nb?")) and (cache / STAMP).is_file()
    (cache / "kernel.f-1.py311.nbi").write_bytes(b"index")
    assert not drop_stale_cache(cache, [source])  # same sources: kept
    assert (cache / "kernel.f-1.py311.nbi").is_file()
    source.write_text("x = 2\n")
    assert drop_stale_cache(cache, [source])  # a source changed: dropped
    assert not (cache / "kernel.f-1.py311.nbi").exists()
