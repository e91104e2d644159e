"""Train a stable-baselines3 agent on a registered environment.

    python -m training.train --env tissue_env/TumorPositioning-v0 --algo ppo [--timesteps 50000] --seed 0 [--n-envs 4]
        [--config FILE] [--resume RUN_DIR] [--runs-dir runs] [--vec-env dummy|subproc|batched] [--threads 1]
        [--env-threads N]

The run folder runs/<env>/<algo>/seed<S>-<timestamp>/ holds config.json, model.zip,
vecnormalize.pkl, monitor/*.monitor.csv, evaluations.npz (periodic evaluation, every
``--eval-freq`` env steps), checkpoints/ (every ``--checkpoint-freq`` env steps: model,
normaliser and an off-policy replay buffer), tb/ (tensorboard) and result.json. The folder's path
is printed as the last line.

A run may be killed at any moment (SIGKILL included) and continued with ``--resume RUN_DIR``
(``training.checkpoints``): config.json is written first, before the heavy imports and builds
(a run killed in its first seconds resumes from step 0); every file it writes (but SB3's monitor
CSVs and tensorboard events, appended a row at a time) goes to a temporary name and is renamed;
the resume takes the newest checkpoint that loads (printing each one skipped and why), keeps the
evaluations and the monitor episodes up to its step (the monitor CSVs cut atomically) and
continues to the full ``--timesteps``. result.json is kept current while the run
trains: ``wall_clock_s`` sums the run's sessions, ``resumes`` lists each resume's step and the
files it skipped, ``finished`` is true once model.zip is written.

Hyperparameters come from training/hyperparams/<algo>.yml (or ``--config``), rl_zoo3's format
(``training.common.load_hyperparams``): the entry's ``n_timesteps`` is the default ``--timesteps``.
"""

from __future__ import annotations

import functools
import json
import warnings
from datetime import datetime
from pathlib import Path

from .common import (CommandParser, UsageError, action_noise, algorithm_class, check_algo, check_env_id,
                     check_env_kwargs, load_hyperparams, make_env, parse_env_kwargs, replay_buffer_class, run_name,
                     usage_errors, write_json)

PROGRAM = "training.train"


def parse_args(argv=None):
    parser = CommandParser(PROGRAM, description="Train an SB3 agent on a tissue_env task.")
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
                             "force passes and resets; default every core or one, whichever its timed steps find faster; "
                             "1 when several runs share a machine)")
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
    check_env_kwargs(args.env, env_kwargs)  # before the run folder: a bad keyword leaves nothing behind
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
    if resume_stats is not None:  # a checkpoint's VecNormalize (unpickled, without its venv)
        resume_stats.set_venv(train_env)
        train_env = resume_stats
    else:
        train_env = VecNormalize(train_env, **options)
    eval_env = VecNormalize(eval_env, training=False, norm_reward=False, **{k: v for k, v in options.items()
                                                                            if k not in ("norm_reward",)})
    return train_env, eval_env


def round_size(model) -> int:
    """The env steps of one round of ``model.learn``'s loop, which checks its budget only between
    rounds: an on-policy algorithm's rollout (``n_steps`` per env), an off-policy one's
    ``train_freq`` steps per env (its env count when ``train_freq`` counts episodes)."""
    if hasattr(model, "n_steps"):  # OnPolicyAlgorithm
        return int(model.n_steps) * model.n_envs
    frequency = getattr(model, "train_freq", None)
    unit = getattr(getattr(frequency, "unit", None), "value", "step")
    return (int(frequency.frequency) if frequency is not None and unit == "step" else 1) * model.n_envs


def whole_rounds(model, steps: int) -> int:
    """``steps`` rounded up to whole rounds (``round_size``): the steps ``model.learn(steps)``
    takes, so that its progress bar ends at its total (15,360/15,360, not 15,360/15,000)."""
    size = round_size(model)
    return -(-int(steps) // size) * size


def train(config: dict, run_dir: Path, resume: bool = False, progress: bool = True) -> Path:
    """Train (or, with ``resume``, continue from the newest checkpoint that loads) to
    ``config["timesteps"]`` env steps. Every file is written atomically (``training.checkpoints``)."""
    from . import checkpoints as ckpt

    run_dir.mkdir(parents=True, exist_ok=True)
    if not resume:  # first of all: a run killed from here on (even during the imports) can be resumed
        write_json(run_dir / "config.json", config)
    folder = run_dir / "checkpoints"
    if resume:
        ckpt.remove_stale_temporaries(run_dir, folder, run_dir / "monitor")
        ckpt.repair_monitor_logs(run_dir / "monitor")
    record = ckpt.RunRecord(run_dir / "result.json")
    record.open()  # before the heavy imports: their time is part of the session's

    import torch
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    torch.set_num_threads(int(config["threads"]))
    hyperparams = dict(config["hyperparams"])
    hyperparams.pop("n_timesteps", None)  # the budget is config["timesteps"]
    normalize = hyperparams.pop("normalize", False)
    noise = {key: hyperparams.pop(key) for key in ("noise_type", "noise_std", "action_noise_std") if key in hyperparams}
    policy = hyperparams.pop("policy", "MlpPolicy")
    if hyperparams.get("replay_buffer_class") is not None:  # named in the file (e.g. HerReplayBuffer)
        hyperparams["replay_buffer_class"] = replay_buffer_class(hyperparams["replay_buffer_class"])
    algo_cls = algorithm_class(config["algo"])
    off_policy = issubclass(algo_cls, OffPolicyAlgorithm)
    n_envs = config["n_envs"]

    step, loaded, skipped, cut = None, None, [], {}
    if resume:
        load = ckpt.checkpoint_loader(folder, algo_cls, bool(normalize), off_policy, n_envs, device="cpu",
                                      tensorboard_log=str(run_dir / "tb"))
        step, loaded, skipped = ckpt.pick_checkpoint(folder, load)
        if step is None:
            print(f"no loadable checkpoint in {folder}: training from the start", flush=True)
        else:  # the episodes of the steps trained again after the checkpoint leave the learning curve
            cut = ckpt.truncate_monitor_logs(run_dir / "monitor", step, n_envs, config["vec_env"] == "batched")
    train_env, eval_env = _make_envs(config, run_dir, seed_offset=step or 0, resume=step is not None)
    train_env, eval_env = _normalise(train_env, eval_env, run_dir, normalize, loaded[1] if loaded else None)

    if loaded is not None:
        model = loaded[0]
        model.set_env(train_env)
        buffer = getattr(model, "replay_buffer", None)
        if hasattr(buffer, "set_env") and getattr(buffer, "env", None) is None:
            buffer.set_env(model.get_env())  # a HerReplayBuffer computes relabelled rewards through the env
    else:
        exploration = action_noise(noise, train_env.action_space.shape[0])
        if exploration is not None:
            hyperparams["action_noise"] = exploration
        model = algo_cls(policy, train_env, seed=config["seed"], verbose=0, tensorboard_log=str(run_dir / "tb"),
                         **hyperparams)
    done = int(model.num_timesteps)
    evaluations, dropped = ckpt.load_evaluations(run_dir / "evaluations.npz", up_to=done)
    if dropped:  # evaluations of the steps to be trained again: the resumed run evaluates them anew
        ckpt.save_evaluations(run_dir / "evaluations.npz", evaluations)
    if resume:
        record.begin(done, dict(step=step, skipped=skipped, dropped_evaluations=dropped,
                                dropped_episodes=sum(cut.values()), at=datetime.now().isoformat(timespec="seconds")))
        print(f"resuming {run_dir} at step {step}" if step is not None else f"restarting {run_dir}", flush=True)
    else:
        record.begin(0, None)

    total = int(config["timesteps"])
    eval_freq = config.get("eval_freq") or max(total // 10, 1)
    checkpoint_freq = config.get("checkpoint_freq") or max(total // 10, 1)
    callbacks = ckpt.callbacks(run_dir, checkpoint_freq, eval_env, eval_freq, int(config.get("eval_episodes", 5)),
                               evaluations, record, start_step=done)
    remaining = total - done
    if remaining > 0:
        steps = whole_rounds(model, remaining)
        if steps != remaining:
            print(f"training {steps} env steps, not {remaining}: SB3 trains whole rounds of "
                  f"{round_size(model)} steps", flush=True)
        model.learn(total_timesteps=steps, callback=callbacks, reset_num_timesteps=step is None,
                    progress_bar=progress, tb_log_name="run")
    ckpt.save_model(model, run_dir / "model.zip")
    if normalize:
        ckpt.save_vecnormalize(train_env, run_dir / "vecnormalize.pkl")
    record.finish(int(model.num_timesteps))
    train_env.close()
    eval_env.close()
    return run_dir


def main(argv=None) -> int:
    args = parse_args(argv)
    with usage_errors(PROGRAM):
        run_dir, config = _validated(args)
    run_dir = train(config, run_dir, resume=bool(args.resume), progress=not args.no_progress)
    print(run_dir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
