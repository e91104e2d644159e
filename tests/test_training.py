"""Training scripts: a smoke run trains, checkpoints, resumes, evaluates and plots; bad input fails
cleanly with exit code 2."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from background_jobs import ModuleJobs

ENV = "tissue_env/TumorPositioning-v0"


def run(*args, cwd=None, background=None):
    """(exit code, stdout, stderr) of ``python -m *args``; with ``background`` (``background_jobs.Jobs``),
    a process of that job's, in a session of its own."""
    process = subprocess.Popen([sys.executable, "-m", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, cwd=cwd, start_new_session=background is not None)
    if background is not None:
        background.adopt(process)
    out, err = process.communicate()
    return process.returncode, out, err


def _snapshot(runs: Path, run_dir: Path, snapshots: Path) -> Path:
    """A copy of the runs folder ``runs`` (the run folder ``run_dir``'s path under it kept): the run as
    it was, for the checks of a test before the job changes it (a resume)."""
    shutil.copytree(runs, snapshots)
    return snapshots / run_dir.relative_to(runs)


def _trained(background, folder, *arguments):
    """A job's first training run: ``training.train`` on ENV with ``arguments`` into ``folder``/runs;
    {"train": (code, stdout, stderr)}, with the run folder ("run_dir") and a copy of the runs as they
    are ("snapshot", ``_snapshot``) when it succeeded."""
    runs = folder / "runs"
    code, out, err = run("training.train", "--env", ENV, "--runs-dir", str(runs), *arguments, background=background)
    job = dict(train=(code, out, err))
    if code == 0:
        job["run_dir"] = run_dir = Path(out.strip().splitlines()[-1])
        job["snapshot"] = _snapshot(runs, run_dir, folder / "snapshot")
    return job


def _train_ppo(background, folder):
    """The PPO smoke run (``trained``): trained, copied as it is (``snapshot``), then resumed from its
    newest checkpoint as if interrupted after it, evaluated and plotted (the tests' order)."""
    job = _trained(background, folder, "--algo", "ppo", "--timesteps", "256", "--seed", "3", "--n-envs", "2",
                   "--no-progress", "--eval-episodes", "1", "--checkpoint-freq", "128", "--eval-freq", "128",
                   "--config", str(_small_config(folder)))
    if "run_dir" not in job:
        return job
    run_dir = job["run_dir"]
    (run_dir / "model.zip").unlink()  # as if the run had been interrupted after its last checkpoint
    job["resume"] = run("training.train", "--resume", str(run_dir), "--timesteps", "384", "--no-progress",
                        background=background)
    job["evaluate"] = run("training.evaluate", str(run_dir), "--episodes", "2", "--seed", "7", background=background)
    job["figure"] = folder / "curve.png"
    job["plot"] = run("training.plot", str(run_dir), "--out", str(job["figure"]), background=background)
    return job


def _train_sac(background, folder):
    """SAC with a checkpoint every 50 steps, copied as it is (``snapshot``), then resumed (model.zip
    removed) to 300 steps."""
    config = folder / "sac_small.yml"
    config.write_text("default:\n  policy: MlpPolicy\n  normalize: false\n  buffer_size: 1000\n  learning_starts: 50\n"
                      "  batch_size: 16\n  policy_kwargs: {net_arch: [16, 16]}\n")
    job = _trained(background, folder, "--algo", "sac", "--timesteps", "200", "--seed", "1", "--n-envs", "1",
                   "--no-progress", "--eval-episodes", "1", "--checkpoint-freq", "50", "--eval-freq", "1000",
                   "--config", str(config))
    if "run_dir" not in job:
        return job
    run_dir = job["run_dir"]
    (run_dir / "model.zip").unlink()
    job["resume"] = run("training.train", "--resume", str(run_dir), "--timesteps", "300", "--no-progress",
                        background=background)
    return job


def _train_batched(background, folder):
    """PPO on the batched vector env, copied as it is (``snapshot``), then resumed to 384 steps."""
    common = ("--no-progress", "--eval-episodes", "1", "--eval-freq", "128", "--checkpoint-freq", "128")
    job = _trained(background, folder, "--algo", "ppo", "--timesteps", "256", "--seed", "2", "--n-envs", "2",
                   "--vec-env", "batched", "--config", str(_small_config(folder)), "--env-kwargs",
                   '{"max_episode_steps": 16}', "--env-threads", "1", *common)
    if "run_dir" not in job:
        return job
    run_dir = job["run_dir"]
    job["resume"] = run("training.train", "--resume", str(run_dir), "--timesteps", "384", *common,
                        background=background)
    return job


#: the training runs of the tests below, by name, and the tests that read them: each is a few
#: processes that import torch and train for 5-15 s, self-contained, so they start when the session
#: starts (``start_in_background``) and overlap the other tests instead of holding up the suite (about
#: a minute). They run 10 below the session's priority: on the cores the other tests leave idle.
JOBS = {"ppo": _train_ppo, "sac": _train_sac, "batched": _train_batched}
TESTS_OF_JOBS = {"test_run_folder_contents": "ppo", "test_resume_continues_from_the_latest_checkpoint": "ppo",
                 "test_evaluate_json_and_plot": "ppo",
                 "test_sac_checkpoints_keep_the_latest_replay_buffers_and_resume_with_them": "sac",
                 "test_training_on_the_batched_vec_env_keeps_its_monitor_through_a_resume": "batched"}

MODULE_JOBS = ModuleJobs(JOBS, "training_test", TESTS_OF_JOBS, niceness=10)
start_in_background, stop_background = MODULE_JOBS.start, MODULE_JOBS.stop  # tests/conftest.py's hooks


@pytest.fixture(scope="module")
def jobs():
    yield from MODULE_JOBS.fixture()


def _job(jobs, name):
    job = jobs.result(name)
    code, out, err = job["train"]
    assert code == 0, err
    return job


def run_main(capsys, module, *argv):
    """(exit code, stderr) of ``module``'s main(argv), as ``python -m module`` runs it, in this
    process: an exception other than SystemExit (a traceback) propagates and fails the test."""
    import importlib

    with pytest.raises(SystemExit) as ended:
        importlib.import_module(module).main(list(argv))
    return ended.value.code, capsys.readouterr().err


@pytest.fixture(scope="module")
def trained(jobs):
    return _job(jobs, "ppo")


def _small_config(folder):
    path = Path(folder) / "ppo_small.yml"
    path.write_text("default:\n  policy: MlpPolicy\n  normalize: true\n  n_steps: 64\n  batch_size: 32\n"
                    "  n_epochs: 2\n  policy_kwargs: {net_arch: [16, 16]}\n")
    return path


def test_run_folder_contents(trained):
    snapshot = trained["snapshot"]  # the run folder as training left it
    assert snapshot.parent.name == "ppo" and snapshot.name.startswith("seed3-")
    assert snapshot.parent.parent.name == "tissue_env_TumorPositioning-v0"
    for name in ("config.json", "model.zip", "vecnormalize.pkl", "result.json", "evaluations.npz"):
        assert (snapshot / name).is_file(), name
    assert list((snapshot / "monitor").glob("*.monitor.csv"))
    assert list((snapshot / "checkpoints").glob("model_*_steps.zip"))
    assert list((snapshot / "checkpoints").glob("model_vecnormalize_*_steps.pkl"))
    assert json.loads((snapshot / "result.json").read_text())["timesteps"] == 256


def test_resume_continues_from_the_latest_checkpoint(trained):
    """model.zip removed (as if the run had been interrupted after its last checkpoint), --resume
    continues from the newest checkpoint to the new budget."""
    run_dir = trained["run_dir"]
    code, out, err = trained["resume"]
    assert code == 0, err
    assert Path(out.strip().splitlines()[-1]) == run_dir
    result = json.loads((run_dir / "result.json").read_text())
    assert result["timesteps"] == 384 and result["resumed_from"] == 256
    assert (run_dir / "model.zip").is_file()


def test_evaluate_json_and_plot(trained):
    code, out, err = trained["evaluate"]
    assert code == 0, err
    result = json.loads(out)
    for who in ("agent", "random", "scripted"):
        assert set(result[who]) >= {"mean_return", "std_return", "success_rate", "mean_episode_length"}
        assert result[who]["episodes"] == 2
    code, out, err = trained["plot"]
    assert code == 0, err
    assert trained["figure"].stat().st_size > 1000


@pytest.mark.parametrize("args, word", [
    (("training.train", "--env", "tissue_env/Nope-v0", "--timesteps", "10"), "unknown environment id"),
    (("training.train", "--env", ENV, "--algo", "dqn", "--timesteps", "10"), "unknown algorithm"),
    (("training.train", "--env", ENV, "--timesteps", "0"), "positive"),
    (("training.train", "--env", ENV, "--timesteps", "-5"), "positive"),
    (("training.train", "--resume", "/nonexistent/run"), "cannot resume"),
    (("training.evaluate", "/nonexistent/run"), "does not exist"),
    (("training.evaluate", ".", "--episodes", "0"), "positive"),
    (("training.plot", "/nonexistent/run", "--out", "x.png"), "not a run folder"),
    (("training.train", "--env", ENV, "--timesteps", "10", "--env-threads", "1"), "it needs --vec-env batched"),
    (("training.train", "--env", ENV, "--timesteps", "10", "--vec-env", "batched", "--env-threads", "0"),
     "--env-threads must be an integer from 1 to"),
])
def test_bad_arguments_exit_2(args, word, capsys):
    code, err = run_main(capsys, *args)
    assert code == 2, err
    assert word in err and "Traceback" not in err


@pytest.mark.parametrize("env_kwargs, word", [('{"bogus": 1}', "unexpected keyword argument 'bogus'"),
                                              ('[1, 2]', "must be a JSON object")])
def test_bad_env_kwargs_exit_2_before_a_run_folder_is_made(env_kwargs, word, tmp_path, capsys):
    """--env-kwargs the environment refuses are reported on one line (exit code 2) before the run
    folder is made: no folder without its config.json is left behind."""
    code, err = run_main(capsys, "training.train", "--env", ENV, "--timesteps", "10", "--runs-dir", str(tmp_path),
                         "--env-kwargs", env_kwargs)
    assert code == 2 and word in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.iterdir())


def test_sac_checkpoints_keep_the_latest_replay_buffers_and_resume_with_them(jobs):
    import pickle

    job = _job(jobs, "sac")
    buffers = sorted((job["snapshot"] / "checkpoints").glob("model_replay_buffer_*_steps.pkl"))
    # older ones removed; two kept, so that a damaged newest checkpoint leaves one to resume from
    assert [b.name for b in buffers] == ["model_replay_buffer_150_steps.pkl", "model_replay_buffer_200_steps.pkl"]
    code, out, err = job["resume"]  # model.zip removed first
    assert code == 0, err
    with open(job["run_dir"] / "checkpoints" / "model_replay_buffer_300_steps.pkl", "rb") as handle:
        buffer = pickle.load(handle)
    # the checkpoint step is the number of transitions in its buffer: the transitions before the
    # interruption were kept (without the saved buffer the resumed run would hold 100)
    assert buffer.size() == 300


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


@pytest.mark.parametrize("env_id", ["tissue_env/Retraction-v0", "tissue_env/Palpation-v0"])
def test_batched_vec_env_steps_the_episodes_of_make_vec_env(env_id):
    """``tissue_env.sb3.BatchedVecEnv`` (stable-baselines3 on the batched vector env) with seed s
    draws the episodes of ``make_vec_env``'s DummyVecEnv with seed s and follows them (at the
    default settings: observations and rewards within 1e-6), with SB3's same-step reset: the same dones, the
    terminal observation and TimeLimit.truncated in the info, the next episode's first observation
    returned, is_success reported (3 copies, episodes of 12 steps, 30 steps)."""
    import functools

    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    from training.common import make_env
    from tissue_env.sb3 import BatchedVecEnv

    kwargs = dict(max_episode_steps=12)
    batched = BatchedVecEnv(env_id, 3, kwargs)
    reference = make_vec_env(functools.partial(make_env, env_id), n_envs=3, seed=7, vec_env_cls=DummyVecEnv,
                             env_kwargs=kwargs)
    batched.seed(7)
    np.testing.assert_array_equal(batched.reset(), reference.reset())
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(30):
        actions = rng.uniform(-1, 1, (3, 3)).astype(np.float32)
        obs, rewards, dones, infos = batched.step(actions)
        ref_obs, ref_rewards, ref_dones, ref_infos = reference.step(actions)
        np.testing.assert_array_equal(dones, ref_dones)
        np.testing.assert_allclose(obs, ref_obs, atol=1e-6, rtol=0)
        np.testing.assert_allclose(rewards, ref_rewards, atol=1e-6, rtol=0)
        for info, ref_info, done in zip(infos, ref_infos, dones):
            assert info["is_success"] == ref_info["is_success"]
            if done:
                ends += 1
                assert info["TimeLimit.truncated"] == ref_info["TimeLimit.truncated"]
                np.testing.assert_allclose(info["terminal_observation"], ref_info["terminal_observation"], atol=1e-6)
    assert ends >= 6
    batched.close()
    reference.close()


def test_training_on_the_batched_vec_env_keeps_its_monitor_through_a_resume(jobs):
    """--vec-env batched trains PPO on the batched vector env with periodic evaluations (the eval env's
    normaliser synchronised with the training env's); its VecMonitor CSV gets the episodes, and a
    resumed run appends to it."""
    job = _job(jobs, "batched")
    snapshot, run_dir = job["snapshot"], job["run_dir"]  # the run after its first session; the resumed run
    first = (snapshot / "monitor" / "batched.monitor.csv").read_text().splitlines()
    assert len(first) - 2 >= 256 // 16 - 2  # header lines, then about one episode per 16 steps
    config = json.loads((snapshot / "config.json").read_text())
    assert config["vec_env"] == "batched" and config["env_threads"] == 1
    assert len(np.load(snapshot / "evaluations.npz")["timesteps"]) >= 2
    code, out, err = job["resume"]
    assert code == 0, err
    again = (run_dir / "monitor" / "batched.monitor.csv").read_text().splitlines()
    assert again[:len(first)] == first and len(again) > len(first)


def test_batched_vec_env_input_errors():
    """A task without a batched vector env, and per-copy reset options, are refused with what is allowed."""
    from tissue_env.sb3 import BatchedVecEnv
    with pytest.raises(ValueError, match="has no batched vector env; those with one"):
        BatchedVecEnv("CartPole-v1", 2)
    with pytest.raises(ValueError, match="threads as its own threads= argument"):
        BatchedVecEnv(ENV, 2, {"threads": 1})
    single = BatchedVecEnv(ENV, 2, threads=1)
    assert single.vector_env.unwrapped.threads == 1
    single.close()
    envs = BatchedVecEnv(ENV, 2)
    envs.set_options([{"x": 1}, {}])
    with pytest.raises(ValueError, match="same options"):
        envs.reset()
    envs.close()


HYPERPARAMS = sorted((Path(__file__).resolve().parents[1] / "training" / "hyperparams").glob("*.yml"))


def _env_ids(path):
    import yaml

    return [key for key in yaml.safe_load(path.read_text()) if key != "default"]


def test_training_loader_reads_every_entry_of_every_hyperparameter_file():
    """training.common.load_hyperparams reads every env id of every file: a registered task, an
    n_timesteps budget, a policy, and keywords the algorithm's constructor accepts (the keys the
    training script handles itself removed)."""
    import inspect

    import gymnasium as gym

    import tissue_env  # noqa: F401
    from training.common import algorithm_class, load_hyperparams

    assert {path.stem for path in HYPERPARAMS} == {"ppo", "ppo_pixels", "sac", "td3"}
    # the per-algorithm files; a variant's file (ppo_pixels.yml: pixel observations, CnnPolicy, one task)
    # is read by benchmarks/training_pixels.py and tested with it
    for path in (p for p in HYPERPARAMS if "_" not in p.stem):
        algo = path.stem
        accepted = set(inspect.signature(algorithm_class(algo).__init__).parameters)
        ids = _env_ids(path)
        assert set(ids) == set(tissue_env.ENV_IDS), path.name
        for env_id in ids:
            assert env_id in gym.registry
            hyperparams = load_hyperparams(algo, env_id)
            assert int(hyperparams.pop("n_timesteps")) > 0 and hyperparams.pop("policy") == "MlpPolicy"
            for key in ("n_envs", "normalize", "noise_type", "noise_std"):
                hyperparams.pop(key, None)
            assert set(hyperparams) <= accepted, (path.name, env_id, set(hyperparams) - accepted)


@pytest.mark.parametrize("path", HYPERPARAMS, ids=lambda path: path.name)
def test_hyperparameter_files_pass_rl_zoo3s_checks(path, tmp_path):
    """rl_zoo3 sets up an experiment from every entry of the file with its own code: it reads the
    entry, preprocesses it (n_timesteps, schedules, normalize, policy_kwargs, the keys it removes),
    builds the envs and the action noise, and constructs the model (eval_freq -1: no evaluation)."""
    pytest.importorskip("rl_zoo3")
    import argparse

    import tissue_env  # noqa: F401  (registers the tasks, as rl_zoo3's --gym-packages tissue_env does)
    from rl_zoo3.exp_manager import ExperimentManager
    from training.common import algorithm_class

    for env_id in _env_ids(path):
        manager = ExperimentManager(argparse.Namespace(), path.stem, env_id, str(tmp_path / "zoo"), config=str(path),
                                    eval_freq=-1, verbose=0)
        model, saved = manager.setup_experiment()
        assert isinstance(model, algorithm_class(path.stem)), env_id
        assert manager.n_timesteps == int(saved["n_timesteps"]) > 0
        assert manager.n_envs == model.n_envs == int(saved.get("n_envs", 1))
        model.env.close()


def test_demo_and_benchmark_write_under_runs_unless_published(tmp_path):
    """make demo and python -m training.benchmark leave the committed figures and results alone:
    by default they write under runs/ (or --output-dir); only --publish targets docs/figures/ and
    benchmarks/results/."""
    from training import benchmark, demo

    root = Path(__file__).resolve().parents[1]
    assert demo.figures_dir(demo.parse_args([])) == root / "runs" / "demo"
    assert demo.figures_dir(demo.parse_args(["--output-dir", str(tmp_path)])) == tmp_path
    assert demo.figures_dir(demo.parse_args(["--publish"])) == root / "docs" / "figures"

    out, figures = benchmark.outputs(benchmark.parse_args([]))
    assert (out, figures) == (root / "runs" / "benchmark" / "training.json", root / "runs" / "benchmark")
    out, figures = benchmark.outputs(benchmark.parse_args(["--vec-env", "batched", "--output-dir", str(tmp_path)]))
    assert (out, figures) == (tmp_path / "training_batched.json", tmp_path)
    out, figures = benchmark.outputs(benchmark.parse_args(["--publish"]))
    assert (out, figures) == (root / "benchmarks" / "results" / "training.json", root / "docs" / "figures")
    for module in (demo, benchmark):
        with pytest.raises(SystemExit):
            module.parse_args(["--publish", "--output-dir", str(tmp_path)])


def test_train_takes_the_budget_and_the_noise_from_the_hyperparameter_file(tmp_path, capsys):
    """Without --timesteps a run trains for the entry's n_timesteps; rl_zoo3's noise_type /
    noise_std become the off-policy algorithm's action noise; rl_zoo3 keys the scripts do not
    implement, or Python strings where a mapping is needed, are refused with exit code 2."""
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    from training.common import action_noise
    from training.train import _validated, parse_args

    config = tmp_path / "td3.yml"
    config.write_text("default: &default\n  n_timesteps: 1234\n  policy: MlpPolicy\n  noise_type: normal\n"
                      "  noise_std: 0.2\n")
    _, settings = _validated(parse_args(["--env", ENV, "--algo", "td3", "--config", str(config),
                                         "--runs-dir", str(tmp_path)]))
    assert settings["timesteps"] == 1234 and "n_timesteps" not in settings["hyperparams"]
    noise = action_noise(dict(settings["hyperparams"]), 3)
    assert isinstance(noise, NormalActionNoise)
    # its draws are those of a zero-mean normal of standard deviation 0.2 per action dimension
    saved = np.random.get_state()
    np.random.seed(11)
    drawn = noise()
    np.random.seed(11)
    expected = np.random.normal(0.0, 0.2, size=3)
    np.random.set_state(saved)
    np.testing.assert_allclose(drawn, expected, rtol=1e-6)  # float32 draws
    assert isinstance(action_noise({"noise_type": "ornstein-uhlenbeck", "noise_std": 0.1}, 2),
                      OrnsteinUhlenbeckActionNoise)
    assert isinstance(action_noise({"action_noise_std": 0.1}, 2), NormalActionNoise)  # runs saved before
    assert action_noise({"learning_rate": 1e-3}, 2) is None
    for text, word in (("default:\n  frame_stack: 4\n", "frame_stack"),
                       ("default:\n  policy_kwargs: 'dict(net_arch=[8])'\n", "YAML mapping"),
                       ("default:\n  noise_type: pink\n", "noise_type must be one of"),
                       ("other/Env-v0:\n  gamma: 0.9\n", "has no entry for"),
                       ("default:\n  policy: MlpPolicy\n", "--timesteps is required")):
        config.write_text(text)
        code, err = run_main(capsys, "training.train", "--env", ENV, "--algo", "td3", "--config", str(config))
        assert code == 2 and word in err and "Traceback" not in err, (text, err)
