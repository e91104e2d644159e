"""Train a stable-baselines3 agent on a registered environment.

    python -m training.train --env tissue_env/TumorPositioning-v0 --algo ppo [--timesteps 50000] --seed 0 [--n-envs 4]
        [--config FILE] [--resume RUN_DIR] [--runs-dir runs] [--vec-env dummy|subproc|batched] [--threads 1]
        [--env-threads N]

The run folder runs/<env>/<algo>/seed<S>-<timestamp>/ holds config.json, model.zip,
vecnormalize.pkl, monitor/*.monitor.csv, evaluations.npz (periodic evaluation), checkpoints/
(model, normaliser and an off-policy replay buffer, so an interrupted run resumes without loss with --resume), tb/ (tensorboard)
and result.json. The folder's path is printed as the last line.

Hyperparameters come from training/hyperparams/<algo>.yml (or ``--config``), rl_zoo3's format
(``training.common.load_hyperparams``): the entry's ``n_timesteps`` is the default ``--timesteps``.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import time
import warnings
from datetime import datetime
from pathlib import Path

from .common import (UsageError, action_noise, algorithm_class, check_algo, check_env_id, fail, load_hyperparams,
                     make_env, parse_env_kwargs, run_name, write_json)

PROGRAM = "training.train"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        fail(PROGRAM, message)


def parse_args(argv=None):
    parser = _Parser(prog=f"python -m {PROGRAM}", description="Train an SB3 agent on a tissue_env task.")
    parser.add_argument("--env", help="environment id, e.g. tissue_env/TumorPositioning-v0")
    parser.add_argument("--algo", default="ppo", help="ppo | sac | td3")
    parser.add_argument("--timesteps", type=int,
                        help="total environment steps (default: the hyperparameter file's n_timesteps)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-envs", type=int, default=None, help="parallel environments (default: from config)")
    parser.add_argument("--config", default=None,
                        help="YAML file of hyperparameters keyed by env id, in rl_zoo3's format "
                             "(default training/hyperparams/<algo>.yml)")
    parser.add_argument("--resume", default=None, metavar="RUN_DIR",
                        help="continue an interrupted run from its latest checkpoint (--timesteps: new total)")
    parser.add_argument("--runs-dir", default="runs")
    parser.add_argument("--vec-env", choices=("auto", "dummy", "subproc", "batched"), default="auto",
                        help="auto: SubprocVecEnv when --n-envs > 1 (PPO, 4 envs, 4096 steps on 2 idle "
                             "cores: 9.5 s against 11.4 s with DummyVecEnv), else DummyVecEnv; batched: the "
                             "task's batched vector env in this process (tissue_env.sb3.BatchedVecEnv)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1: PPO ran 20x slower with 2)")
    parser.add_argument("--env-threads", type=int, default=None,
                        help="--vec-env batched: the vector env's threads (its per-copy solves, factorisations, "
                             "force passes and resets; default every core; 1 when several runs share a machine)")
    parser.add_argument("--eval-freq", type=int, default=None, help="env steps between evaluations")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--checkpoint-freq", type=int, default=None, help="env steps between checkpoints")
    parser.add_argument("--env-kwargs", default="{}", help="JSON dict of environment constructor keywords")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser.parse_args(argv)


def numba_threads() -> int:
    """The most threads a batched vector env can use (numba's ``NUMBA_NUM_THREADS``)."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


def _validated(args):
    if args.resume:
        run_dir = Path(args.resume)
        config_path = run_dir / "config.json"
        if not config_path.is_file():
            raise UsageError(f"cannot resume: {config_path} does not exist")
        config = json.loads(config_path.read_text())
        check_env_id(config["env"])
        if args.timesteps is not None:
            if args.timesteps <= 0:
                raise UsageError(f"--timesteps must be a positive integer, got {args.timesteps}")
            config["timesteps"] = args.timesteps  # extend (or finish) the interrupted run
            write_json(config_path, config)
        return run_dir, config
    if not args.env:
        raise UsageError("--env is required (or --resume RUN_DIR)")
    check_env_id(args.env)
    check_algo(args.algo)
    if args.timesteps is not None and args.timesteps <= 0:
        raise UsageError(f"--timesteps must be a positive integer, got {args.timesteps}")
    if args.n_envs is not None and args.n_envs <= 0:
        raise UsageError(f"--n-envs must be positive, got {args.n_envs}")
    if args.threads <= 0:
        raise UsageError(f"--threads must be positive, got {args.threads}")
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    hyperparams = load_hyperparams(args.algo, args.env, args.config)
    budget = hyperparams.pop("n_timesteps", None)
    if args.timesteps is None:
        if budget is None:
            raise UsageError("--timesteps is required: the hyperparameter file has no n_timesteps "
                             f"for {args.env}")
        args.timesteps = int(budget)
    n_envs = args.n_envs or int(hyperparams.pop("n_envs", 1))
    hyperparams.pop("n_envs", None)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = Path(args.runs_dir) / run_name(args.env) / args.algo / f"seed{args.seed}-{stamp}"
    suffix = 1
    while run_dir.exists():
        run_dir = run_dir.with_name(f"seed{args.seed}-{stamp}-{suffix}")
        suffix += 1
    vec_env = args.vec_env if args.vec_env != "auto" else ("subproc" if n_envs > 1 else "dummy")
    if vec_env == "batched":
        import tissue_env

        if args.env not in tissue_env.VECTOR_ENTRY_POINTS:
            raise UsageError(f"--vec-env batched needs a task with a batched vector env, one of "
                             f"{', '.join(sorted(tissue_env.VECTOR_ENTRY_POINTS))}; got {args.env}")
    if args.env_threads is not None:
        if vec_env != "batched":
            raise UsageError(f"--env-threads sets the batched vector env's threads: it needs --vec-env batched "
                             f"(got --vec-env {vec_env})")
        available = numba_threads()
        if not 1 <= args.env_threads <= available:
            raise UsageError(f"--env-threads must be an integer from 1 to {available} (numba's NUMBA_NUM_THREADS), "
                             f"got {args.env_threads}")
    config = dict(env=args.env, algo=args.algo, timesteps=args.timesteps, seed=args.seed, n_envs=n_envs,
                  vec_env=vec_env, threads=args.threads, env_kwargs=env_kwargs, hyperparams=hyperparams,
                  eval_freq=args.eval_freq, eval_episodes=args.eval_episodes, checkpoint_freq=args.checkpoint_freq,
                  env_threads=args.env_threads)
    return run_dir, config


def _make_envs(config, run_dir, seed_offset=0, resume=False):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    monitor_dir = run_dir / "monitor"
    factory = functools.partial(make_env, config["env"])
    eval_env = make_vec_env(factory, n_envs=1, seed=config["seed"] + 10_000, vec_env_cls=DummyVecEnv,
                            env_kwargs=config["env_kwargs"])
    if config["vec_env"] != "batched":
        train_env = make_vec_env(factory, n_envs=config["n_envs"], seed=config["seed"] + seed_offset,
                                 vec_env_cls=SubprocVecEnv if config["vec_env"] == "subproc" else DummyVecEnv,
                                 monitor_dir=str(monitor_dir), env_kwargs=config["env_kwargs"],
                                 monitor_kwargs=dict(info_keywords=("is_success",), override_existing=not resume))
        return train_env, eval_env
    from tissue_env.sb3 import BatchedVecEnv, monitored

    monitor_dir.mkdir(parents=True, exist_ok=True)
    train_env = monitored(BatchedVecEnv(config["env"], config["n_envs"], config["env_kwargs"],
                                        threads=config.get("env_threads")),
                          str(monitor_dir / "batched"), append=resume)
    train_env.seed(config["seed"] + seed_offset)
    # the eval env gets the training env's wrapper layers, which EvalCallback's normaliser
    # synchronisation walks in step; its own Monitor keeps its statistics
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="The environment is already wrapped with a `Monitor`")
        eval_env = VecMonitor(eval_env)
    return train_env, eval_env


def _normalise(train_env, eval_env, run_dir, normalize, resume_stats=None):
    from stable_baselines3.common.vec_env import VecNormalize

    if not normalize:
        return train_env, eval_env
    options = dict(gamma=0.99) if normalize is True else dict(normalize)
    if resume_stats is not None:
        train_env = VecNormalize.load(str(resume_stats), train_env)
    else:
        train_env = VecNormalize(train_env, **options)
    eval_env = VecNormalize(eval_env, training=False, norm_reward=False, **{k: v for k, v in options.items()
                                                                            if k not in ("norm_reward",)})
    return train_env, eval_env


def _steps(path: Path) -> int:
    """The env steps in a checkpoint file's name (model_<steps>_steps.zip, model_replay_buffer_<steps>_steps.pkl)."""
    return int(re.search(r"_(\d+)_steps", path.name).group(1))


def _latest_checkpoint(run_dir: Path):
    best = None
    for path in (run_dir / "checkpoints").glob("model_*_steps.zip"):
        steps = _steps(path)
        if best is None or steps > best[0]:
            best = (steps, path)
    return best


def _checkpoint_callback():
    """SB3's CheckpointCallback that also saves an off-policy model's replay buffer (so that a
    resumed SAC / TD3 run continues with its transitions) and keeps only the latest buffer (one
    is up to buffer_size transitions: tens of MB)."""
    from stable_baselines3.common.callbacks import CheckpointCallback

    class Checkpoints(CheckpointCallback):
        def _on_step(self) -> bool:
            result = super()._on_step()
            if self.n_calls % self.save_freq == 0:  # a checkpoint was written at this call
                buffers = sorted(Path(self.save_path).glob("model_replay_buffer_*_steps.pkl"), key=_steps)
                for old in buffers[:-1]:
                    old.unlink(missing_ok=True)
            return result

    return Checkpoints


def train(config: dict, run_dir: Path, resume: bool = False, progress: bool = True) -> Path:
    import torch
    from stable_baselines3.common.callbacks import CallbackList, EvalCallback

    _Checkpoints = _checkpoint_callback()

    torch.set_num_threads(int(config["threads"]))
    run_dir.mkdir(parents=True, exist_ok=True)
    hyperparams = dict(config["hyperparams"])
    hyperparams.pop("n_timesteps", None)  # the budget is config["timesteps"]
    normalize = hyperparams.pop("normalize", False)
    noise = {key: hyperparams.pop(key) for key in ("noise_type", "noise_std", "action_noise_std") if key in hyperparams}
    policy = hyperparams.pop("policy", "MlpPolicy")
    algo_cls = algorithm_class(config["algo"])

    checkpoint = _latest_checkpoint(run_dir) if resume else None
    stats = None
    if checkpoint is not None:
        candidate = run_dir / "checkpoints" / f"model_vecnormalize_{checkpoint[0]}_steps.pkl"
        stats = candidate if candidate.is_file() else None
    train_env, eval_env = _make_envs(config, run_dir, seed_offset=checkpoint[0] if checkpoint else 0,
                                     resume=checkpoint is not None)
    train_env, eval_env = _normalise(train_env, eval_env, run_dir, normalize, stats)

    if checkpoint is not None:
        model = algo_cls.load(str(checkpoint[1]), env=train_env, tensorboard_log=str(run_dir / "tb"))
        done = model.num_timesteps
        buffer = run_dir / "checkpoints" / f"model_replay_buffer_{checkpoint[0]}_steps.pkl"
        if buffer.is_file():  # off-policy: continue with the transitions collected so far
            model.load_replay_buffer(str(buffer))
    else:
        exploration = action_noise(noise, train_env.action_space.shape[0])
        if exploration is not None:
            hyperparams["action_noise"] = exploration
        model = algo_cls(policy, train_env, seed=config["seed"], verbose=0, tensorboard_log=str(run_dir / "tb"),
                         **hyperparams)
        done = 0
        write_json(run_dir / "config.json", config)

    n_envs = config["n_envs"]
    total = int(config["timesteps"])
    eval_freq = config.get("eval_freq") or max(total // 10, 1)
    checkpoint_freq = config.get("checkpoint_freq") or max(total // 10, 1)
    callbacks = CallbackList([
        _Checkpoints(save_freq=max(checkpoint_freq // n_envs, 1), save_path=str(run_dir / "checkpoints"),
                     name_prefix="model", save_vecnormalize=True, save_replay_buffer=True),
        EvalCallback(eval_env, n_eval_episodes=int(config.get("eval_episodes", 5)),
                     eval_freq=max(eval_freq // n_envs, 1), log_path=str(run_dir), best_model_save_path=None,
                     deterministic=True, verbose=0),
    ])
    start = time.perf_counter()
    remaining = total - done
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=callbacks, reset_num_timesteps=checkpoint is None,
                    progress_bar=progress, tb_log_name="run")
    wall = time.perf_counter() - start
    model.save(str(run_dir / "model.zip"))
    if normalize:
        train_env.save(str(run_dir / "vecnormalize.pkl"))
    previous = {}
    if (run_dir / "result.json").is_file():
        previous = json.loads((run_dir / "result.json").read_text())
    write_json(run_dir / "result.json", dict(
        timesteps=int(model.num_timesteps), wall_clock_s=wall + previous.get("wall_clock_s", 0.0),
        resumed_from=checkpoint[0] if checkpoint else None))
    train_env.close()
    eval_env.close()
    return run_dir


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        run_dir, config = _validated(args)
    except UsageError as error:
        fail(PROGRAM, str(error))
    run_dir = train(config, run_dir, resume=bool(args.resume), progress=not args.no_progress)
    print(run_dir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
