"""A first run says what it does (``sim_core.compiling``): when numba compiles a kernel that its
cache does not hold, one message on stderr (logger "sim_core.kernels") says so, how long it takes
and how to warm up ahead of time; a process that loads the kernels from the cache says nothing;
the message can be silenced through logging; nothing goes to stdout."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: compiles (or loads) two small kernels; argv[1] "quiet" silences the logger, "progress" reports
#: every compilation (PROGRESS_SECONDS = 0)
SCRIPT = """
import logging
import sys

import numpy as np

import sim_core.compiling
from sim_core import kernels

if sys.argv[1] == "quiet":
    logging.getLogger("sim_core.kernels").setLevel(logging.ERROR)
if sys.argv[1] == "progress":
    sim_core.compiling.PROGRESS_SECONDS = 0.0
positions = np.random.default_rng(0).random((4, 3))
springs = np.array([[0, 1], [2, 3]], dtype=np.int64)
kernels.spring_lengths(positions, springs, np.empty(2))
kernels.hex_volume(np.random.default_rng(0).random((8, 3)))
"""


def _run(cache, mode):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=ROOT)
    return subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, env=env,
                          timeout=600, check=True)


def test_a_compile_says_so_once_and_a_cached_load_says_nothing(tmp_path):
    first = _run(tmp_path / "cache", "default")
    assert first.stdout == ""
    assert first.stderr.count("compiling numba kernels") == 1, first.stderr
    assert "tissue-gym-warmup" in first.stderr and "min of CPU" in first.stderr
    assert "still compiling" not in first.stderr  # progress every 30 s: two small kernels take less
    again = _run(tmp_path / "cache", "default")  # the same cache: loaded, not compiled
    assert again.stdout == "" and again.stderr == ""


def test_the_message_is_silenced_through_logging_and_reports_progress(tmp_path):
    quiet = _run(tmp_path / "quiet", "quiet")
    assert quiet.stdout == "" and quiet.stderr == ""
    progress = _run(tmp_path / "progress", "progress")
    lines = progress.stderr.splitlines()
    assert lines[0].startswith("tissue-gym: compiling numba kernels")
    assert "tissue-gym: compiled 1 kernels in" in lines[1]
    assert all("still compiling" in line for line in lines[1:]) and len(lines) >= 3
