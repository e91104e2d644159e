"""training/rllib.py on a local Ray instance: a tiny PPO run with one env runner writes result.json
and a checkpoint; bad input fails with exit code 2. Skipped when Ray RLlib is not installed
(``pip install -e ".[rllib]"``, docs/rllib.md)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ray")
pytest.importorskip("ray.rllib")
pytest.importorskip("torch")

ENV = "tissue_env/TumorPositioning-v0"
REPO = Path(__file__).resolve().parent.parent
ITERATION_KEYS = {"iteration", "env_steps_sampled", "env_steps_sampled_lifetime", "wall_time_s", "env_steps_per_s",
                  "episode_return_mean", "episode_len_mean", "num_episodes"}


def run(*args, timeout=180):
    process = subprocess.run([sys.executable, "-m", "training.rllib", *args], capture_output=True, text=True,
                             cwd=REPO, timeout=timeout)
    return process.returncode, process.stdout, process.stderr


def test_tiny_run_writes_result_and_checkpoint(tmp_path):
    out = tmp_path / "run"
    code, stdout, stderr = run("--env", ENV, "--algo", "ppo", "--iterations", "2", "--num-env-runners", "1",
                               "--seed", "3", "--out", str(out), "--checkpoint-every", "1", "--num-cpus", "1",
                               "--train-batch-size", "100", "--minibatch-size", "50", "--num-epochs", "1")
    assert code == 0, stderr[-3000:]
    assert Path(stdout.strip().splitlines()[-1]) == out
    result = json.loads((out / "result.json").read_text())
    assert result["env"] == ENV and result["num_env_runners"] == 1 and result["seed"] == 3
    assert len(result["iterations"]) == 2
    for record in result["iterations"]:
        assert ITERATION_KEYS <= set(record)
        assert record["env_steps_sampled"] >= 100 and record["env_steps_per_s"] > 0
    assert result["iterations"][-1]["env_steps_sampled_lifetime"] == result["total_env_steps"]
    assert result["iterations"][-1]["episode_return_mean"] is not None  # 200 steps = 4 episodes of 50
    config = json.loads((out / "config.json").read_text())
    assert config["hyperparams"]["train_batch_size_per_learner"] == 100
    # the final checkpoint and the periodic one (every iteration but the last) restore with RLlib
    assert (out / "checkpoint" / "rllib_checkpoint.json").is_file()
    assert (out / "checkpoints" / "iter_000001" / "rllib_checkpoint.json").is_file()
    assert result["final_checkpoint"] == str(out / "checkpoint")


@pytest.mark.parametrize("args, message", [
    (["--env", "tissue_env/Nope-v0", "--iterations", "1"], "unknown environment id"),
    (["--env", ENV, "--iterations", "0"], "--iterations must be a positive integer"),
    (["--env", ENV, "--iterations", "-3"], "--iterations must be a positive integer"),
    (["--env", ENV, "--iterations", "1", "--algo", "dqn"], "unknown algorithm"),
    (["--env", ENV, "--iterations", "1", "--num-env-runners", "-1"], "--num-env-runners"),
    (["--env", ENV, "--iterations", "1", "--env-kwargs", '{"poisson_ratio": 0.7}'], "--env-kwargs rejected"),
    (["--env", ENV], "--iterations"),
])
def test_bad_arguments_exit_with_code_2(args, message, capsys):
    from training.rllib import main

    with pytest.raises(SystemExit) as exit_info:  # validation comes before Ray starts
        main(args)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_bad_arguments_exit_code_from_the_shell():
    code, stdout, stderr = run("--env", "tissue_env/Nope-v0", "--iterations", "1")
    assert code == 2 and "unknown environment id" in stderr and "Traceback" not in stderr


def test_missing_ray_names_the_extra(tmp_path):
    script = ("import sys; sys.modules['ray'] = None\n"  # makes `import ray` raise ImportError
              "from training.rllib import main\n"
              f"main(['--env', {ENV!r}, '--iterations', '1', '--out', {str(tmp_path / 'run')!r}])\n")
    process = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert process.returncode == 2
    assert "pip install \"tissue-gym[rllib]\"" in process.stderr
    assert not (tmp_path / "run").exists()
