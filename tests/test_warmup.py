"""``tissue-gym-warmup`` (tissue_env.warmup): it builds, resets and steps every task and its vector env."""

import subprocess
import sys

import tissue_env
from tissue_env.warmup import main


def test_warmup_steps_every_task_and_vector_env(capsys):
    assert main(["--steps", "1"]) == 0
    out = capsys.readouterr().out
    for env_id in tissue_env.ENV_IDS:
        assert f"{env_id}: built, reset and stepped 1 times in" in out
        if env_id in tissue_env.VECTOR_ENTRY_POINTS:
            assert f"{env_id} vector env (N = 2)" in out
    assert out.strip().splitlines()[-1].startswith("warmup done in")
    bad = subprocess.run([sys.executable, "-m", "tissue_env.warmup", "--steps", "0"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--steps" in bad.stderr
