"""Training scripts: a smoke run trains, checkpoints, resumes, evaluates and plots; bad input fails
cleanly with exit code 2."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ENV = "tissue_env/TumorPositioning-v0"


def run(*args, cwd=None):
    process = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=cwd)
    return process.returncode, process.stdout, process.stderr


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    code, out, err = run("training.train", "--env", ENV, "--algo", "ppo", "--timesteps", "256", "--seed", "3",
                         "--n-envs", "2", "--runs-dir", str(runs), "--no-progress", "--eval-episodes", "1",
                         "--checkpoint-freq", "128", "--eval-freq", "128", "--config", str(_small_config(runs)))
    assert code == 0, err
    run_dir = Path(out.strip().splitlines()[-1])
    return run_dir


def _small_config(folder):
    path = Path(folder) / "ppo_small.yml"
    path.write_text("default:\n  policy: MlpPolicy\n  normalize: true\n  n_steps: 64\n  batch_size: 32\n"
                    "  n_epochs: 2\n  policy_kwargs: {net_arch: [16, 16]}\n")
    return path


def test_run_folder_contents(trained):
    assert trained.parent.name == "ppo" and trained.name.startswith("seed3-")
    assert trained.parent.parent.name == "tissue_env_TumorPositioning-v0"
    for name in ("config.json", "model.zip", "vecnormalize.pkl", "result.json", "evaluations.npz"):
        assert (trained / name).is_file(), name
    assert list((trained / "monitor").glob("*.monitor.csv"))
    assert list((trained / "checkpoints").glob("model_*_steps.zip"))
    assert list((trained / "checkpoints").glob("model_vecnormalize_*_steps.pkl"))
    assert json.loads((trained / "result.json").read_text())["timesteps"] == 256


def test_resume_continues_from_the_latest_checkpoint(trained):
    (trained / "model.zip").unlink()  # as if the run had been interrupted after its last checkpoint
    code, out, err = run("training.train", "--resume", str(trained), "--timesteps", "384", "--no-progress")
    assert code == 0, err
    assert Path(out.strip().splitlines()[-1]) == trained
    result = json.loads((trained / "result.json").read_text())
    assert result["timesteps"] == 384 and result["resumed_from"] == 256
    assert (trained / "model.zip").is_file()


def test_evaluate_json_and_plot(trained, tmp_path):
    code, out, err = run("training.evaluate", str(trained), "--episodes", "2", "--seed", "7")
    assert code == 0, err
    result = json.loads(out)
    for who in ("agent", "random", "scripted"):
        assert set(result[who]) >= {"mean_return", "std_return", "success_rate", "mean_episode_length"}
        assert result[who]["episodes"] == 2
    figure = tmp_path / "curve.png"
    code, out, err = run("training.plot", str(trained), "--out", str(figure))
    assert code == 0, err
    assert figure.stat().st_size > 1000


@pytest.mark.parametrize("args, word", [
    (("training.train", "--env", "tissue_env/Nope-v0", "--timesteps", "10"), "unknown environment id"),
    (("training.train", "--env", ENV, "--algo", "dqn", "--timesteps", "10"), "unknown algorithm"),
    (("training.train", "--env", ENV, "--timesteps", "0"), "positive"),
    (("training.train", "--env", ENV, "--timesteps", "-5"), "positive"),
    (("training.train", "--resume", "/nonexistent/run"), "cannot resume"),
    (("training.evaluate", "/nonexistent/run"), "does not exist"),
    (("training.evaluate", ".", "--episodes", "0"), "positive"),
    (("training.plot", "/nonexistent/run", "--out", "x.png"), "not a run folder"),
])
def test_bad_arguments_exit_2(args, word):
    code, out, err = run(*args)
    assert code == 2, (out, err)
    assert word in err and "Traceback" not in err


def test_sac_checkpoints_keep_the_latest_replay_buffer_and_resume_with_it(tmp_path):
    import pickle

    config = tmp_path / "sac_small.yml"
    config.write_text("default:\n  policy: MlpPolicy\n  normalize: false\n  buffer_size: 1000\n  learning_starts: 50\n"
                      "  batch_size: 16\n  policy_kwargs: {net_arch: [16, 16]}\n")
    code, out, err = run("training.train", "--env", ENV, "--algo", "sac", "--timesteps", "200", "--seed", "1",
                         "--n-envs", "1", "--runs-dir", str(tmp_path), "--no-progress", "--eval-episodes", "1",
                         "--checkpoint-freq", "100", "--eval-freq", "1000", "--config", str(config))
    assert code == 0, err
    run_dir = Path(out.strip().splitlines()[-1])
    buffers = list((run_dir / "checkpoints").glob("model_replay_buffer_*_steps.pkl"))
    assert [b.name for b in buffers] == ["model_replay_buffer_200_steps.pkl"]  # older ones removed
    (run_dir / "model.zip").unlink()
    code, out, err = run("training.train", "--resume", str(run_dir), "--timesteps", "300", "--no-progress")
    assert code == 0, err
    with open(run_dir / "checkpoints" / "model_replay_buffer_300_steps.pkl", "rb") as handle:
        buffer = pickle.load(handle)
    # the transitions before the interruption were kept (SB3 saves a checkpoint before it stores that
    # step's transition: 199 + 99); without the saved buffer the resumed run would hold 99
    assert buffer.size() == 298


def test_rllib_runners_build_their_vector_envs_on_one_thread():
    """An RLlib env runner's batched vector env keeps to one thread (the runners are the parallel
    processes) unless env_config asks for more; this needs no Ray."""
    from training.rllib import make_tissue_env
    env = make_tissue_env("tissue_env/Palpation-v0", {"num_envs": 2})
    assert env.unwrapped.threads == 1
    env.close()
    if __import__("numba").config.NUMBA_NUM_THREADS >= 2:
        env = make_tissue_env("tissue_env/Palpation-v0", {"num_envs": 2, "threads": 2})
        assert env.unwrapped.threads == 2
        env.close()
