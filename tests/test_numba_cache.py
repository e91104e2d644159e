"""Results must not depend on which compiled kernels numba loaded from its cache.

numba caches each kernel on its own. A kernel compiled in a process where its callees were loaded from
the cache must give the floats of the same kernel compiled with fresh callees, or the serial and
threaded twins of the vector envs (``kernels.solve_copies_lu_serial`` / ``solve_copies_lu`` ...) drift
apart by rounding depending on what earlier processes cached. With fastmath "reassoc" they did
(``kernels.FAST``): this test failed with it and passes without.
"""

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numba
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: the tasks and models of the test below: baudet's and the hyperelastic model's kernels
TASKS = (("tissue_env/Palpation-v0", "baudet"), ("tissue_env/Retraction-v0", "baudet-hyperelastic"))

#: for each of ``TASKS``: 4 copies, 20 random steps, episodes of 6 (two autoresets each), run by the
#: batched vector env on two numba threads, then on one, then by gymnasium's SyncVectorEnv over
#: single envs; the trajectories are saved to argv[1]. Compiling the kernels is most of the time: a
#: rounding difference shows from the first step that runs a kernel, so longer runs add little.
SCRIPT = f"""
import sys
import gymnasium as gym
import numpy as np
import tissue_env

trace = []
for env_id, model in {TASKS!r}:
    for mode in ("2", "1", "sync"):
        kwargs = dict(max_episode_steps=6, model=model)
        if mode == "sync":
            envs = gym.make_vec(env_id, num_envs=4, vectorization_mode="sync", **kwargs)
        else:
            envs = gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", threads=int(mode),
                                **kwargs)
        rng = np.random.default_rng(5)
        observations, rewards = [envs.reset(seed=5)[0]], []
        for _ in range(20):
            obs, reward, terminated, truncated, _ = envs.step(rng.uniform(-1.2, 1.2, (4, 3)).astype(np.float32))
            observations.append(obs)
            rewards.append(reward)
        envs.close()
        trace += [np.stack(observations), np.stack(rewards)]
np.savez(sys.argv[1], *trace)
"""


#: runs the script of each argument after the first (the script's path) in turn, with argv[1] the
#: output file: the first process compiles every kernel into the empty cache, the second loads them
RUNNER = """
import subprocess
import sys
for out in sys.argv[2:]:
    subprocess.run([sys.executable, sys.argv[1], out], check=True, timeout=900)
"""


def needs_two_threads():
    return numba.config.NUMBA_NUM_THREADS < 2


class Runs:
    """The two processes of the test below, one after the other, in the background: compiling the
    kernels is a single-threaded 3 minutes, so they start when the test session starts
    (``tests/conftest.py``, when this test is selected) and overlap the other tests instead of
    holding up the suite. ``result()`` waits for them and loads their trajectories."""

    def __init__(self):
        self.folder = tempfile.TemporaryDirectory(prefix="numba_cache_test")
        folder = Path(self.folder.name)
        (folder / "script.py").write_text(SCRIPT)
        self.paths = [folder / "compiled.npz", folder / "cached.npz"]
        self.log = folder / "output.txt"
        environment = dict(os.environ, NUMBA_CACHE_DIR=str(folder / "numba_cache"), PYTHONPATH=ROOT)
        with open(self.log, "wb") as log:
            # a session of its own: ``close`` ends the runner and the process it is waiting for
            self.process = subprocess.Popen([sys.executable, "-c", RUNNER, str(folder / "script.py"),
                                             *map(str, self.paths)], env=environment, cwd=ROOT, stdout=log,
                                            stderr=subprocess.STDOUT, start_new_session=True)

    def result(self):
        try:
            code = self.process.wait(timeout=1800)
            assert code == 0, self.log.read_text(errors="replace")[-4000:]
            return [self._load(path) for path in self.paths]
        finally:
            self.close()

    def close(self):
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)  # the runner's process group: it and its child
            self.process.wait()
        self.folder.cleanup()

    @staticmethod
    def _load(path):
        with np.load(path) as data:
            return [data[f"arr_{i}"] for i in range(len(data.files))]


#: the runs started by ``start_in_background`` (tests/conftest.py), or None
background = None


def start_in_background(name):
    """tests/conftest.py, after collection, for each selected test of this module: start the
    processes of the test below now if ``name`` is it; whether they were started."""
    global background
    if name != test_threaded_and_serial_kernels_give_the_same_floats_compiled_or_cached.__name__ or needs_two_threads():
        return False
    if background is None:
        background = Runs()
    return True


def stop_background():
    """The session ended without running the test (-x, a keyboard interrupt): end its processes."""
    global background
    if background is not None:
        background.close()
        background = None


@pytest.mark.skipif(needs_two_threads(), reason="needs two cores for numba's threads")
def test_threaded_and_serial_kernels_give_the_same_floats_compiled_or_cached():
    """A first process (empty cache) compiles every kernel: it runs the vector envs of ``TASKS`` on two
    threads, then on one, then single envs. A second process does the same with every kernel loaded
    from the cache. The six trajectories of each task are equal bit for bit. (With fastmath
    "contract" in the stress correction's kernels, the second process's threaded run differed from
    its single envs by 1e-15 in Retraction's observation: ``kernels.FAST_EXACT``. With "reassoc",
    kernels compiled against cached callees rounded differently: ``kernels.FAST``.)"""
    global background
    runs, background = background or Runs(), None
    compiled, cached = runs.result()
    assert len(compiled) == len(cached) == 2 * 3 * 2
    for task in range(2):
        runs = compiled[6 * task:6 * task + 6] + cached[6 * task:6 * task + 6]
        for run in range(1, 6):
            np.testing.assert_array_equal(runs[2 * run], runs[0])  # observations
            np.testing.assert_array_equal(runs[2 * run + 1], runs[1])  # rewards


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
