"""A training run survives being killed at any moment: SIGKILLed again and again (at random
moments, during start-up and in the middle of checkpoint writes) and resumed with --resume each
time, it reaches its full budget with the evaluation history of an uninterrupted run; the
checkpoint picker skips checkpoints that do not load and says why."""

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from background_jobs import ModuleJobs

ENV = "tissue_env/Retraction-v0"  # the cheapest task (about 4 ms a step)
BUDGET = 2048
N_STEPS = 64  # PPO rollout: a checkpoint every rollout
CHECKPOINT_EVERY = 64
EVAL_EVERY = 128
#: a third at start-up, a third in a checkpoint write, a third at a random moment (seeded): each kind
#: of kill three or four times, two of them before a resume that meets a damaged checkpoint. (22 kills
#: took 2 min of the suite: each session is a process that imports torch and loads the kernels.)
KILLS = 11
HEARTBEAT = 0.2  # training.checkpoints.RunRecord's


def _config(folder: Path) -> Path:
    path = folder / "ppo_tiny.yml"
    path.write_text(f"default:\n  policy: MlpPolicy\n  normalize: true\n  n_steps: {N_STEPS}\n  batch_size: 32\n"
                    "  n_epochs: 1\n  policy_kwargs: {net_arch: [8]}\n")
    return path


def _newest_step(folder: Path) -> int:
    steps = [int(p.name.split("_")[1]) for p in folder.glob("model_*_steps.zip")] if folder.is_dir() else []
    return max(steps, default=0)


def _temporaries(folder: Path):
    try:
        return [entry.name for entry in os.scandir(folder) if entry.name.startswith(".")]
    except FileNotFoundError:
        return []


class Session:
    """One ``python -m training.train`` process, its output in files, its time measured."""

    def __init__(self, args, folder: Path, index: int, background=None):
        """``background``: the ``background_jobs.Jobs`` whose job starts it (a session of its own)."""
        self.out = folder / f"session{index}.out"
        self.err = folder / f"session{index}.err"
        with open(self.out, "w") as out, open(self.err, "w") as err:
            self.start = time.perf_counter()
            self.process = subprocess.Popen([sys.executable, "-m", "training.train", *args], stdout=out,
                                            stderr=err, cwd=Path(__file__).resolve().parents[1],
                                            start_new_session=background is not None)
        if background is not None:
            background.adopt(self.process)
        self.seconds = None

    def running(self):
        return self.process.poll() is None

    def kill(self):
        self.process.send_signal(signal.SIGKILL)
        return self.wait()

    def wait(self, timeout=None):
        code = self.process.wait(timeout)
        self.seconds = time.perf_counter() - self.start
        return code


def _wait_for(condition, session, timeout=60.0, pause=0.002):
    """Poll ``condition`` until true (True) or the session ends / time runs out (False)."""
    end = time.perf_counter() + timeout
    while time.perf_counter() < end:
        if condition():
            return True
        if not session.running():
            return False
        time.sleep(pause)
    return False


def test_training_survives_repeated_sigkills(tmp_path):
    """11 SIGKILLs (seeded): three during start-up or the resume's loading, four timed to hit a
    checkpoint write (the test polls for its temporary file and kills then), four at a random
    moment after some progress; twice the newest checkpoint is damaged (cut to 0 bytes, truncated)
    before a resume. The run ends at its budget, its model loads, evaluations.npz holds every
    scheduled evaluation once and in order, and wall_clock_s sums the sessions."""
    rng = random.Random(30)
    runs = tmp_path / "runs"
    first = ["--env", ENV, "--algo", "ppo", "--timesteps", str(BUDGET), "--seed", "0", "--n-envs", "1",
             "--runs-dir", str(runs), "--no-progress", "--eval-episodes", "1", "--eval-freq", str(EVAL_EVERY),
             "--checkpoint-freq", str(CHECKPOINT_EVERY), "--config", str(_config(tmp_path)),
             "--env-kwargs", '{"max_episode_steps": 8}']
    plan = ["progress"] + [rng.choice(["startup", "write", "progress"]) for _ in range(KILLS - 1)]
    damage = {5: "empty", 9: "truncated"}  # after these kills the newest checkpoint is damaged
    for index in damage:
        plan[index + 1] = "write"  # the resume that meets the damage gets past its loading
    run_dir, folder = None, None
    sessions, modes, write_hits, damaged = [], [], 0, {}
    began = time.perf_counter()
    for index, mode in enumerate(plan):
        session = Session(first if run_dir is None else ["--resume", str(run_dir), "--no-progress"], tmp_path,
                          len(sessions))
        sessions.append(session)
        if run_dir is None:
            assert _wait_for(lambda: list(runs.glob("*/ppo/*/config.json")), session), session.err.read_text()
            run_dir = next(runs.glob("*/ppo/*/config.json")).parent
            folder = run_dir / "checkpoints"
        start_step = _newest_step(folder)
        if BUDGET - start_step <= 6 * CHECKPOINT_EVERY and index - 1 not in damage:
            mode = "startup"  # keep budget for the kills still to come
        if mode == "startup":
            time.sleep(rng.uniform(0.2, 2.5))
        else:
            assert _wait_for(lambda: _newest_step(folder) > start_step, session), session.err.read_text()
            seen = set(_temporaries(folder))
            if mode == "write":
                _wait_for(lambda: set(_temporaries(folder)) - seen, session, pause=0.0005)
            else:
                time.sleep(rng.uniform(0.0, 0.4))
        assert session.running(), f"session {index} ended before its kill: {session.err.read_text()[-2000:]}"
        assert session.kill() == -signal.SIGKILL
        if mode != "startup":  # the kill cut a checkpoint write short: its temporary is left behind
            write_hits += bool(set(_temporaries(folder)) - seen)
        modes.append(mode)
        if index in damage:
            newest = max(folder.glob("model_*_steps.zip"), key=lambda p: int(p.name.split("_")[1]))
            size = newest.stat().st_size
            with open(newest, "r+b") as stream:
                stream.truncate(0 if damage[index] == "empty" else size // 2)
            damaged[index] = newest.name
    final = Session(["--resume", str(run_dir), "--no-progress"], tmp_path, len(sessions))
    assert final.wait(timeout=180) == 0, final.err.read_text()
    sessions.append(final)
    print(f"{len(plan)} kills ({', '.join(f'{m}: {modes.count(m)}' for m in set(modes))}, {write_hits} during a "
          f"checkpoint write, leaving its temporary) in {time.perf_counter() - began:.1f} s")

    assert len(modes) == KILLS and modes.count("startup") >= 2 and modes.count("write") >= 3 and write_hits >= 2
    # the damaged checkpoints were skipped on the next resume, with the file and the reason
    for index, name in damaged.items():
        said = sessions[index + 1].out.read_text()
        assert f"skipping checkpoint {name}" in said, said
    assert "0 bytes" in sessions[min(damaged) + 1].out.read_text()

    result = json.loads((run_dir / "result.json").read_text())
    assert result["finished"] and result["timesteps"] == BUDGET
    from stable_baselines3 import PPO

    assert PPO.load(run_dir / "model.zip", device="cpu").num_timesteps == BUDGET
    # checkpoints fall on rollout boundaries after the update: every counted step trained on (one
    # epoch: one update a rollout)
    for path in sorted(folder.glob("model_*_steps.zip")):
        model = PPO.load(path, device="cpu")
        assert model.num_timesteps % N_STEPS == 0 and model._n_updates == model.num_timesteps // N_STEPS, path.name
    evaluations = np.load(run_dir / "evaluations.npz")
    expected = list(range(EVAL_EVERY, BUDGET + 1, EVAL_EVERY))  # an uninterrupted run's schedule
    assert evaluations["timesteps"].tolist() == expected
    assert evaluations["results"].shape == evaluations["ep_lengths"].shape == (len(expected), 1)

    # resume events: one a resume, the damaged files among the skipped
    skipped = {entry["file"] for resume in result["resumes"] for entry in resume["skipped"]}
    assert set(damaged.values()) <= skipped
    assert len(result["resumes"]) >= len(modes) - modes.count("startup")
    # wall clock: every session that got past its imports is counted (a killed one to within a
    # heartbeat); sessions killed during their imports may be missing
    trained = [s.seconds for s, mode in zip(sessions, modes + ["final"]) if mode != "startup"]
    print(f"wall_clock_s {result['wall_clock_s']:.1f}; sessions measured {sum(s.seconds for s in sessions):.1f} s, "
          f"those past start-up {sum(trained):.1f} s")
    assert result["wall_clock_s"] > sessions[-1].seconds - 0.5
    assert result["wall_clock_s"] >= sum(trained) - (HEARTBEAT + 0.3) * len(trained)
    assert result["wall_clock_s"] <= sum(s.seconds for s in sessions) + 1.0
    assert not _temporaries(folder), "a resume removes the temporaries the killed sessions left"


def _sac_killed_run(background, tmp_path):
    """The SAC run of the test below, killed three times (twice in a checkpoint write, once at a random
    moment) and resumed: (run folder, the transitions in each checkpoint's replay buffer after each
    kill: [(file name, step, transitions)])."""
    import pickle

    rng = random.Random(31)
    config = tmp_path / "sac_tiny.yml"
    config.write_text("default:\n  policy: MlpPolicy\n  normalize: true\n  buffer_size: 1000\n  learning_starts: 40\n"
                      "  batch_size: 16\n  policy_kwargs: {net_arch: [8]}\n")
    runs = tmp_path / "runs"
    first = ["--env", ENV, "--algo", "sac", "--timesteps", "400", "--seed", "0", "--n-envs", "1", "--runs-dir",
             str(runs), "--no-progress", "--eval-episodes", "1", "--eval-freq", "100", "--checkpoint-freq", "25",
             "--config", str(config), "--env-kwargs", '{"max_episode_steps": 8}']
    run_dir, buffers = None, []
    for index, mode in enumerate(["write", "progress", "write"]):
        session = Session(first if run_dir is None else ["--resume", str(run_dir), "--no-progress"], tmp_path, index,
                          background)
        if run_dir is None:
            assert _wait_for(lambda: list(runs.glob("*/sac/*/config.json")), session), session.err.read_text()
            run_dir = next(runs.glob("*/sac/*/config.json")).parent
        folder = run_dir / "checkpoints"
        start_step = _newest_step(folder)
        assert _wait_for(lambda: _newest_step(folder) > start_step, session), session.err.read_text()
        if mode == "write":
            seen = set(_temporaries(folder))
            _wait_for(lambda: set(_temporaries(folder)) - seen, session, pause=0.0005)
        else:
            time.sleep(rng.uniform(0.0, 0.3))
        assert session.running(), session.err.read_text()[-2000:]
        session.kill()
        for buffer in folder.glob("model_replay_buffer_*_steps.pkl"):
            with open(buffer, "rb") as stream:
                buffers.append((buffer.name, int(buffer.name.split("_")[3]), pickle.load(stream).size()))
    final = Session(["--resume", str(run_dir), "--no-progress"], tmp_path, 3, background)
    assert final.wait(timeout=180) == 0, final.err.read_text()
    return run_dir, buffers


#: the self-contained runs of the tests below that have no timing to keep (``background_jobs``):
#: they start when the session starts (``start_in_background``) and overlap the other tests
JOBS = {"sac": _sac_killed_run}
TESTS_OF_JOBS = {"test_sac_killed_resumes_with_every_transition": "sac"}

MODULE_JOBS = ModuleJobs(JOBS, "resume_test", TESTS_OF_JOBS)
start_in_background, stop_background = MODULE_JOBS.start, MODULE_JOBS.stop  # tests/conftest.py's hooks


@pytest.fixture(scope="module")
def jobs():
    yield from MODULE_JOBS.fixture()


def test_sac_killed_resumes_with_every_transition(jobs):
    """Off-policy: killed three times (twice in a checkpoint write, once at a random moment), SAC ends
    at its budget and each checkpoint's replay buffer holds as many transitions as its step (none
    lost, none twice)."""
    import pickle

    run_dir, buffers = jobs.result("sac")
    assert buffers  # checked after each kill
    for name, step, transitions in buffers:
        assert transitions == step, name
    with open(run_dir / "checkpoints" / "model_replay_buffer_400_steps.pkl", "rb") as stream:
        assert pickle.load(stream).size() == 400
    assert np.load(run_dir / "evaluations.npz")["timesteps"].tolist() == [100, 200, 300, 400]
    result = json.loads((run_dir / "result.json").read_text())
    assert result["finished"] and result["timesteps"] == 400 and len(result["resumes"]) == 3


def _monitor_steps(run_dir: Path) -> dict:
    """{monitor file: the summed lengths of its episodes} of a run (whole rows only)."""
    steps = {}
    for path in (run_dir / "monitor").glob("*.monitor.csv"):
        rows = path.read_text().splitlines()[2:]
        steps[path.name] = sum(int(row.split(",")[1]) for row in rows if row.count(",") >= 3)
    return steps


def _plot(run_dir: Path, out: Path):
    process = subprocess.run([sys.executable, "-m", "training.plot", str(run_dir), "--out", str(out)],
                             capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    return process.returncode, process.stderr


def test_a_run_killed_early_and_late_resumes_with_the_episodes_of_the_run_once(tmp_path):
    """A run of two envs, SIGKILLed twice. First 3 s after its start (the imports, the env and model
    builds): config.json is there, so the run folder plots (no episode yet: skipped, exit 0) and
    --resume trains it on. Then with episodes logged past its newest checkpoint: it
    resumes from the checkpoint, and the monitor logs drop the episodes of the steps trained again,
    so that at the end their episodes cover at most the run's steps (plus one episode); the run
    reaches its budget with every scheduled evaluation, and plots. (Two tests once, each starting
    and resuming a run of its own.)"""
    budget, episode = 384, 8
    runs = tmp_path / "runs"
    session = Session(["--env", ENV, "--algo", "ppo", "--timesteps", str(budget), "--seed", "0", "--n-envs", "2",
                       "--vec-env", "dummy", "--runs-dir", str(runs), "--no-progress", "--eval-episodes", "1",
                       "--eval-freq", "128", "--checkpoint-freq", "128", "--config", str(_config(tmp_path)),
                       "--env-kwargs", f'{{"max_episode_steps": {episode}}}'], tmp_path, 0)
    time.sleep(max(0.0, 3.0 - (time.perf_counter() - session.start)))
    # on a loaded machine (a busy core, the other test worker) the imports can outlast 3 s: the kill
    # then waits for the run's first file (config.json, written before the env and the model are built)
    assert _wait_for(lambda: list(runs.glob("*/ppo/*/config.json")), session), session.err.read_text()
    assert session.running(), session.err.read_text()[-2000:]
    assert session.kill() == -signal.SIGKILL
    folders = list(runs.glob("*/ppo/*"))
    assert len(folders) == 1 and (folders[0] / "config.json").is_file(), folders
    run_dir = folders[0]
    folder = run_dir / "checkpoints"
    from training import plot

    assert plot.main([str(run_dir), "--out", str(tmp_path / "early.png")]) == 0  # as python -m training.plot

    session = Session(["--resume", str(run_dir), "--no-progress"], tmp_path, 1)

    def ahead():  # episodes logged well past the newest checkpoint
        newest = _newest_step(folder)
        return newest >= 128 and sum(_monitor_steps(run_dir).values()) > newest + 4 * episode
    assert _wait_for(ahead, session, pause=0.01), session.err.read_text()
    assert session.kill() == -signal.SIGKILL
    final = Session(["--resume", str(run_dir), "--no-progress"], tmp_path, 2)
    assert final.wait(timeout=180) == 0, final.err.read_text()
    result = json.loads((run_dir / "result.json").read_text())
    assert result["finished"] and result["timesteps"] == budget and len(result["resumes"]) == 2
    assert result["resumes"][1]["dropped_episodes"] > 0
    assert np.load(run_dir / "evaluations.npz")["timesteps"].tolist() == [128, 256, 384]
    steps = _monitor_steps(run_dir)
    assert len(steps) == 2 and sum(steps.values()) <= budget + episode, steps
    assert all(total <= budget // 2 + episode for total in steps.values()), steps
    code, err = _plot(run_dir, tmp_path / "curve.png")
    assert code == 0 and (tmp_path / "curve.png").stat().st_size > 1000, err


def test_monitor_logs_are_cut_to_the_episodes_of_the_checkpoint(tmp_path):
    """One file per env: the episodes ending within step / n_envs steps each; one file of every env's
    episodes (batched): those whose lengths sum to at most step. Rewritten whole (no temporary left)."""
    from training.checkpoints import truncate_monitor_logs

    header = '#{"t_start": 1}\nr,l,t,is_success\n'
    rows = "".join(f"{i}.0,8,{i}.5,False\n" for i in range(6))  # episodes ending at 8, 16, ..., 48 steps
    for name in ("0", "1"):
        (tmp_path / f"{name}.monitor.csv").write_text(header + rows)
    assert truncate_monitor_logs(tmp_path, 48, n_envs=2) == {"0.monitor.csv": 3, "1.monitor.csv": 3}
    assert (tmp_path / "0.monitor.csv").read_text() == header + rows[:rows.index("3.0")]
    assert truncate_monitor_logs(tmp_path, 48, n_envs=2) == {}
    batched = tmp_path / "batched"
    batched.mkdir()
    (batched / "batched.monitor.csv").write_text(header + rows)
    assert truncate_monitor_logs(batched, 40, n_envs=2, batched=True) == {"batched.monitor.csv": 1}
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["0.monitor.csv", "1.monitor.csv", "batched",
                                                           "batched.monitor.csv"]


def _ppo_checkpoints(folder: Path, steps):
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from training import checkpoints as ckpt

    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = PPO("MlpPolicy", env, n_steps=16, batch_size=16, policy_kwargs=dict(net_arch=[4]), device="cpu")
    for step in steps:
        model.num_timesteps = step
        ckpt.save_vecnormalize(env, ckpt.vecnormalize_path(folder, step))
        ckpt.save_model(model, ckpt.model_path(folder, step))
    env.close()
    return PPO


def test_checkpoint_picker_takes_the_newest_that_loads(tmp_path):
    """Newest first; a 0-byte zip, a truncated zip, a zip without its (or with an unpicklable)
    VecNormalize are skipped, each with a line naming the file and why; none: (None, None, ...)."""
    from training import checkpoints as ckpt

    algo = _ppo_checkpoints(tmp_path, [100, 200, 300, 400, 500, 600])
    (tmp_path / "model_600_steps.zip").write_bytes(b"")
    data = (tmp_path / "model_500_steps.zip").read_bytes()
    (tmp_path / "model_500_steps.zip").write_bytes(data[: len(data) // 2])
    (tmp_path / "model_vecnormalize_400_steps.pkl").write_bytes(b"not a pickle")
    (tmp_path / "model_vecnormalize_300_steps.pkl").unlink()
    (tmp_path / ".model_700_steps.zip.abc.tmp.zip").write_bytes(b"half")  # a killed write's temporary
    lines = []
    load = ckpt.checkpoint_loader(tmp_path, algo, normalize=True, off_policy=False, n_envs=1, device="cpu")
    step, (model, stats), skipped = ckpt.pick_checkpoint(tmp_path, load, log=lines.append)
    assert step == 200 and model.num_timesteps == 200 and stats.obs_rms.mean.shape == (3,)
    assert [entry["step"] for entry in skipped] == [600, 500, 400, 300]
    assert lines[0] == "skipping checkpoint model_600_steps.zip (step 600): empty file (0 bytes)"
    assert lines[1].startswith("skipping checkpoint model_500_steps.zip (step 500): ") and "zip" in lines[1]
    assert lines[2].startswith("skipping checkpoint model_vecnormalize_400_steps.pkl (step 400): cannot be unpickled")
    assert lines[3] == "skipping checkpoint model_vecnormalize_300_steps.pkl (step 300): missing"

    for path in tmp_path.glob("model_*_steps.zip"):
        path.write_bytes(b"")
    assert ckpt.pick_checkpoint(tmp_path, load, log=lines.append)[:2] == (None, None)
    assert ckpt.pick_checkpoint(tmp_path / "nothing", load, log=lines.append) == (None, None, [])
    assert ckpt.remove_stale_temporaries(tmp_path) == [tmp_path / ".model_700_steps.zip.abc.tmp.zip"]


def test_off_policy_checkpoint_needs_its_buffer_with_as_many_transitions(tmp_path):
    """SAC: a checkpoint is usable only with a replay buffer of as many transitions as its step."""
    from stable_baselines3 import SAC

    from training import checkpoints as ckpt

    model = SAC("MlpPolicy", "Pendulum-v1", buffer_size=100, learning_starts=1000, policy_kwargs=dict(net_arch=[4]),
                device="cpu")
    model.learn(30)
    for step in (20, 30):
        model.num_timesteps = step
        ckpt.save_replay_buffer(model, ckpt.buffer_path(tmp_path, step))
        ckpt.save_model(model, ckpt.model_path(tmp_path, step))
    lines = []
    load = ckpt.checkpoint_loader(tmp_path, SAC, normalize=False, off_policy=True, n_envs=1, device="cpu")
    # the buffer holds 30 transitions: step 30's; step 20 (buffer of 30) is refused
    assert ckpt.pick_checkpoint(tmp_path, load, log=lines.append)[0] == 30
    ckpt.buffer_path(tmp_path, 30).unlink()
    step, loaded, skipped = ckpt.pick_checkpoint(tmp_path, load, log=lines.append)
    assert step is None and [entry["reason"] for entry in skipped] == [
        "missing", "holds 30 transitions, the checkpoint step is 20"]


@pytest.fixture(autouse=True)
def _one_thread(monkeypatch):
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_evaluate_takes_the_newest_loadable_checkpoint_with_its_normaliser(tmp_path, capsys):
    """Without model.zip, training.evaluate's agent is the newest checkpoint that loads, its
    observations normalised with that checkpoint's VecNormalize."""
    from training.evaluate import agent_policy

    _ppo_checkpoints(tmp_path / "checkpoints", [64, 128])
    (tmp_path / "checkpoints" / "model_128_steps.zip").write_bytes(b"")
    policy = agent_policy(tmp_path, dict(algo="ppo", hyperparams=dict(normalize=True)))
    assert policy(np.zeros(3, dtype=np.float32), None).shape == (1,)
    assert "skipping checkpoint model_128_steps.zip (step 128): empty file (0 bytes)" in capsys.readouterr().err


def test_a_monitor_row_cut_by_a_kill_is_removed_before_the_resume_appends(tmp_path):
    from training.checkpoints import repair_monitor_logs

    whole, cut = tmp_path / "0.monitor.csv", tmp_path / "1.monitor.csv"
    whole.write_text('#{"t_start": 1}\nr,l,t\n1.0,8,0.1\n')
    cut.write_text('#{"t_start": 1}\nr,l,t\n1.0,8,0.1\n-0.5,8,0.')
    assert repair_monitor_logs(tmp_path) == [cut]
    assert cut.read_text() == whole.read_text()
    assert repair_monitor_logs(tmp_path / "absent") == []


def test_a_later_run_in_the_same_process_counts_only_its_own_time(tmp_path):
    """training.benchmark trains its runs one after the other in one process: a run's wall clock
    starts at its own start, not at the process's (which would add the earlier runs' time)."""
    import time

    from training.checkpoints import RunRecord

    first = RunRecord(tmp_path / "first.json")
    first.open()
    time.sleep(1.0)
    first.finish(10)
    second = RunRecord(tmp_path / "second.json")
    second.open()
    second.finish(10)
    assert json.loads((tmp_path / "first.json").read_text())["wall_clock_s"] >= 1.0
    assert json.loads((tmp_path / "second.json").read_text())["wall_clock_s"] < 0.5
