"""Train a PPO agent with Ray RLlib on a tissue_env task: several env runners, one machine or a cluster.

    python -m training.rllib --env tissue_env/TumorPositioning-v0 --algo ppo --iterations 20 --num-env-runners 2
        [--seed S] [--address auto|ray://HOST:10001] [--out RUN_DIR] [--checkpoint-every M]
        [--num-envs-per-env-runner N] [--train-batch-size B] [--minibatch-size B] [--num-epochs K]
        [--config FILE] [--env-kwargs JSON] [--ship-code]

Without ``--address`` a local Ray instance is started (no dashboard) and stopped at the end. With
``--address auto`` the script joins the cluster started by ``ray start --head`` on this node; with
``--address ray://HOST:10001`` it drives a remote cluster through Ray Client. The tissue tasks are
registered with ``ray.tune.registry.register_env`` under their gymnasium ids; the env creator
imports ``tissue_env`` itself, so every remote EnvRunner registers the tasks in its own process.
Worker nodes need the package (``pip install tissue-gym``), or ``--ship-code`` uploads the local
``sim_core``, ``tissue_env`` and ``training`` sources with the job (their dependencies must be
installed on the nodes). See docs/rllib.md.

Hyperparameters come from training/hyperparams/ppo.yml (the ones the SB3 script uses) translated to
RLlib: ``n_steps * n_envs`` -> ``train_batch_size_per_learner``, ``batch_size`` -> ``minibatch_size``,
``n_epochs`` -> ``num_epochs``, ``gae_lambda`` -> ``lambda_``, ``ent_coef`` -> ``entropy_coeff``,
``net_arch`` -> separate policy and value networks, ``normalize`` -> a MeanStdFilter on the
observations (RLlib has no reward normalisation). No KL penalty and no value-loss clipping (as SB3).
RLlib's new API stack (RLModule, Learner, EnvRunner) is used: the default of Ray 2.60, tested here.

The run folder (default runs/<env>/ppo-rllib/seed<S>-<timestamp>/, or ``--out``) holds config.json,
result.json (per iteration: env steps sampled, wall time, env steps/s, mean episode return; rewritten
atomically after every iteration), checkpoints/iter_<N>/ (every ``--checkpoint-every`` iterations)
and checkpoint/ (the final algorithm, ``Algorithm.from_checkpoint``). The folder's path is printed
as the last line. Torch uses one thread in the driver (learner) and in every EnvRunner.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import time
from datetime import datetime
from pathlib import Path

from .common import (CommandParser, UsageError, check_env_id, fail, load_hyperparams, parse_env_kwargs, run_name,
                     usage_errors, write_json)

PROGRAM = "training.rllib"
INSTALL_HINT = 'pip install "tissue-gym[rllib]" (install torch==2.13.0 first, see docs/rllib.md)'
ALGORITHMS = ("ppo",)
REPO_ROOT = Path(__file__).resolve().parent.parent


def parse_args(argv=None):
    parser = CommandParser(PROGRAM, description="Train an RLlib agent on a tissue_env task.")
    parser.add_argument("--env", required=True, help="environment id, e.g. tissue_env/TumorPositioning-v0")
    parser.add_argument("--algo", default="ppo", help="ppo (the only one wired up so far)")
    parser.add_argument("--iterations", type=int, required=True, help="training iterations (algo.train() calls)")
    parser.add_argument("--num-env-runners", type=int, default=2,
                        help="remote EnvRunner actors sampling in parallel (0: sample in the driver)")
    parser.add_argument("--num-envs-per-env-runner", type=int, default=1,
                        help="environments per EnvRunner; > 1 uses the task's batched vector env")
    parser.add_argument("--num-cpus-per-env-runner", type=float, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join: 'auto' (ray start on this node) or ray://HOST:PORT; "
                             "default: start a local Ray instance")
    parser.add_argument("--num-cpus", type=int, default=None,
                        help="CPUs of the local Ray instance (default: max(cores, env runners))")
    parser.add_argument("--out", default=None, metavar="RUN_DIR", help="run folder (default: under --runs-dir)")
    parser.add_argument("--runs-dir", default="runs")
    parser.add_argument("--checkpoint-every", type=int, default=0, metavar="M",
                        help="also checkpoint every M iterations (0: only the final checkpoint)")
    parser.add_argument("--config", default=None, help="YAML file of SB3-style PPO hyperparameters keyed by env id")
    parser.add_argument("--train-batch-size", type=int, default=None, help="env steps per iteration")
    parser.add_argument("--minibatch-size", type=int, default=None)
    parser.add_argument("--num-epochs", type=int, default=None)
    parser.add_argument("--env-kwargs", default="{}", help="JSON dict of environment constructor keywords")
    parser.add_argument("--ship-code", action="store_true",
                        help="upload sim_core, tissue_env and training to the cluster (runtime_env py_modules)")
    return parser.parse_args(argv)


def require_ray():
    """Import ray and RLlib, or stop with exit code 2 and the install hint."""
    try:
        import ray  # noqa: F401
        from ray.rllib.algorithms.ppo import PPOConfig  # noqa: F401
    except ImportError as error:
        fail(PROGRAM, f"Ray RLlib is not installed ({error}); install it with {INSTALL_HINT}")
    import ray

    return ray


def _positive(name, value, allow_zero=False):
    if value is None:
        return
    if value < 0 or (value == 0 and not allow_zero):
        raise UsageError(f"--{name} must be a {'non-negative' if allow_zero else 'positive'} integer, got {value}")


def rllib_hyperparams(env_id: str, config: str | None = None) -> dict:
    """training/hyperparams/ppo.yml (SB3 names) translated to PPOConfig.training() keywords."""
    sb3 = load_hyperparams("ppo", env_id, config)
    net_arch = (sb3.get("policy_kwargs") or {}).get("net_arch", [64, 64])
    if isinstance(net_arch, dict):  # SB3's dict(pi=[...], vf=[...])
        net_arch = net_arch.get("pi", [64, 64])
    return dict(
        train_batch_size_per_learner=int(sb3.get("n_steps", 2048)) * int(sb3.get("n_envs", 1)),
        minibatch_size=int(sb3.get("batch_size", 64)),
        num_epochs=int(sb3.get("n_epochs", 10)),
        gamma=float(sb3.get("gamma", 0.99)),
        lambda_=float(sb3.get("gae_lambda", 0.95)),
        lr=float(sb3.get("learning_rate", 3e-4)),
        entropy_coeff=float(sb3.get("ent_coef", 0.0)),
        clip_param=float(sb3.get("clip_range", 0.2)),
        normalize=bool(sb3.get("normalize", False)),
        fcnet_hiddens=[int(n) for n in net_arch],
    )


def _validated(args):
    check_env_id(args.env)
    if args.algo not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {args.algo!r} for {PROGRAM}; choose one of {', '.join(ALGORITHMS)}")
    if args.iterations is None or args.iterations <= 0:
        raise UsageError(f"--iterations must be a positive integer, got {args.iterations}")
    _positive("num-env-runners", args.num_env_runners, allow_zero=True)
    _positive("num-envs-per-env-runner", args.num_envs_per_env_runner)
    _positive("checkpoint-every", args.checkpoint_every, allow_zero=True)
    _positive("train-batch-size", args.train_batch_size)
    _positive("minibatch-size", args.minibatch_size)
    _positive("num-epochs", args.num_epochs)
    _positive("num-cpus", args.num_cpus)
    if args.num_cpus_per_env_runner <= 0:
        raise UsageError(f"--num-cpus-per-env-runner must be positive, got {args.num_cpus_per_env_runner}")
    if args.address is not None and args.num_cpus is not None:
        raise UsageError("--num-cpus sizes the local Ray instance; it cannot be combined with --address")
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    if env_kwargs:  # fail here, not in a remote worker; the runners' vector env takes threads=
        vector = args.num_envs_per_env_runner > 1
        try:
            make_tissue_env(args.env, dict(env_kwargs, num_envs=2) if vector else env_kwargs).close()
        except (TypeError, ValueError) as error:
            raise UsageError(f"--env-kwargs rejected by {args.env}: {error}") from error
    hyperparams = rllib_hyperparams(args.env, args.config)
    for key, value in (("train_batch_size_per_learner", args.train_batch_size),
                       ("minibatch_size", args.minibatch_size), ("num_epochs", args.num_epochs)):
        if value is not None:
            hyperparams[key] = value
    hyperparams["minibatch_size"] = min(hyperparams["minibatch_size"], hyperparams["train_batch_size_per_learner"])
    if args.out:
        run_dir = Path(args.out)
    else:
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        run_dir = Path(args.runs_dir) / run_name(args.env) / f"{args.algo}-rllib" / f"seed{args.seed}-{stamp}"
        suffix = 1
        while run_dir.exists():
            run_dir = run_dir.with_name(f"seed{args.seed}-{stamp}-{suffix}")
            suffix += 1
    if (run_dir / "result.json").exists():
        raise UsageError(f"{run_dir} already holds a run (result.json); choose another --out")
    config = dict(env=args.env, algo=args.algo, iterations=args.iterations, seed=args.seed,
                  num_env_runners=args.num_env_runners, num_envs_per_env_runner=args.num_envs_per_env_runner,
                  num_cpus_per_env_runner=args.num_cpus_per_env_runner, address=args.address,
                  num_cpus=args.num_cpus, checkpoint_every=args.checkpoint_every, env_kwargs=env_kwargs,
                  ship_code=args.ship_code, hyperparams=hyperparams)
    return run_dir, config


# ---------------------------------------------------------------------------------------------
# Environment creator: runs inside every EnvRunner process (local or on another node).

def make_tissue_env(env_id: str, env_config):
    """RLlib env creator. Imports tissue_env here, so that a fresh remote worker registers the
    gymnasium ids before ``gym.make``. RLlib adds ``num_envs`` to the config when it asks for a
    vector env (``gym_env_vectorize_mode=VECTOR_ENTRY_POINT``): then the task's batched vector env
    is built, on one thread unless ``env_config`` asks for more (``threads``): the env runners are
    the parallel processes, as torch is kept to one thread in each."""
    import gymnasium as gym

    import tissue_env  # noqa: F401  (registers the tasks in this process)

    _one_torch_thread()
    kwargs = dict(env_config or {})
    num_envs = kwargs.pop("num_envs", None)
    if num_envs is not None:
        kwargs.setdefault("threads", 1)
        return gym.make_vec(env_id, num_envs=int(num_envs), vectorization_mode="vector_entry_point", **kwargs)
    return gym.make(env_id, **kwargs)


def _one_torch_thread():
    try:
        import torch
    except ImportError:
        return
    if torch.get_num_threads() != 1:
        torch.set_num_threads(1)


def register_tissue_envs() -> list[str]:
    """Register every tissue_env task with Ray Tune's registry under its gymnasium id."""
    from ray.tune.registry import register_env

    import tissue_env

    for env_id in tissue_env.ENV_IDS:
        register_env(env_id, functools.partial(make_tissue_env, env_id))
    return sorted(tissue_env.ENV_IDS)


def observation_filter(env=None, spaces=None, device=None):
    """Env-to-module connector: running mean/std normalisation of observations (SB3's VecNormalize)."""
    from ray.rllib.connectors.env_to_module import MeanStdFilter

    return MeanStdFilter()


def build_config(config: dict):
    """The PPOConfig of a run (``config`` as written to config.json)."""
    import gymnasium as gym
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    hp = dict(config["hyperparams"])
    normalize = hp.pop("normalize", False)
    hiddens = hp.pop("fcnet_hiddens", [64, 64])
    envs_per_runner = int(config["num_envs_per_env_runner"])
    vectorize = gym.VectorizeMode.VECTOR_ENTRY_POINT if envs_per_runner > 1 else gym.VectorizeMode.SYNC
    ppo = (
        PPOConfig()
        .framework("torch")
        .environment(env=config["env"], env_config=dict(config["env_kwargs"]))
        .env_runners(num_env_runners=int(config["num_env_runners"]), num_envs_per_env_runner=envs_per_runner,
                     gym_env_vectorize_mode=vectorize, num_cpus_per_env_runner=config["num_cpus_per_env_runner"],
                     rollout_fragment_length="auto",
                     env_to_module_connector=observation_filter if normalize else None)
        .learners(num_learners=0)  # the learner runs in the driver (CPU); num_learners > 0 for GPUs
        .training(use_kl_loss=False, vf_clip_param=1e6, **hp)
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=hiddens, fcnet_activation="tanh",
                                                   vf_share_layers=False))
        .python_environment(extra_python_environs_for_worker={"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
        .debugging(seed=int(config["seed"]), log_level="WARN")
    )
    return ppo


def init_ray(ray, config: dict):
    """Join the cluster at ``config["address"]``, or start a local instance."""
    runtime_env = {"env_vars": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}}
    if config.get("ship_code"):
        import sim_core
        import tissue_env

        runtime_env["py_modules"] = [str(Path(m.__file__).parent) for m in (sim_core, tissue_env)] + [
            str(Path(__file__).parent)]
    if config.get("address"):
        try:
            ray.init(address=config["address"], runtime_env=runtime_env, logging_level="WARNING")
        except (ConnectionError, RuntimeError, ValueError) as error:
            fail(PROGRAM, f"cannot connect to the Ray cluster at {config['address']!r}: {error}. "
                          "Start one with `ray start --head` (see docs/rllib.md)")
        return
    # Local instance: its workers inherit this environment, so put the repository on their path
    # (the tasks are importable even when tissue-gym is not installed).
    path = os.environ.get("PYTHONPATH", "")
    if str(REPO_ROOT) not in path.split(os.pathsep):
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), path) if p)
    needed = math.ceil(int(config["num_env_runners"]) * float(config["num_cpus_per_env_runner"]))
    num_cpus = config.get("num_cpus") or max(os.cpu_count() or 1, needed, 1)
    ray.init(num_cpus=num_cpus, include_dashboard=False, runtime_env=runtime_env, logging_level="WARNING")


def _probe_imports():
    import tissue_env  # noqa: F401
    import training.rllib  # noqa: F401

    return True


def _check_worker_imports(ray):
    """On a cluster, fail early (instead of a dead EnvRunner) when a Ray worker cannot import the code."""
    try:
        ray.get(ray.remote(num_cpus=0)(_probe_imports).remote(), timeout=300)
    except Exception as error:  # RayTaskError wrapping ModuleNotFoundError, timeouts
        cause = getattr(error, "cause", None) or error
        reason = f"{type(cause).__name__}: {cause}".strip().splitlines()[-1]
        sys.stderr.write(f"{PROGRAM}: error: a Ray worker cannot import the tissue-gym code ({reason}). Install "
                         "tissue-gym on every node, submit with `ray job submit --working-dir .`, or pass "
                         "--ship-code (docs/rllib.md)\n")
        raise SystemExit(1) from None


def _check_resources(ray, config):
    needed = int(config["num_env_runners"]) * float(config["num_cpus_per_env_runner"])
    available = ray.cluster_resources().get("CPU", 0)
    if needed > available:
        sys.stderr.write(f"{PROGRAM}: warning: {config['num_env_runners']} env runners need {needed:g} CPUs but "
                         f"the cluster has {available:g}; they start when nodes join (autoscaler)\n")


def _number(value):
    """JSON-friendly float: None for missing or NaN."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(value) else value


def iteration_record(result: dict, wall: float) -> dict:
    """The per-iteration entry of result.json from ``algo.train()``'s result dict."""
    runners = result.get("env_runners", {})
    steps = int(runners.get("num_env_steps_sampled", 0) or 0)
    return dict(
        iteration=int(result.get("training_iteration", 0)),
        env_steps_sampled=steps,
        env_steps_sampled_lifetime=int(_number(result.get("num_env_steps_sampled_lifetime")) or 0),
        wall_time_s=wall,
        env_steps_per_s=steps / wall if wall > 0 else None,
        episode_return_mean=_number(runners.get("episode_return_mean")),
        episode_len_mean=_number(runners.get("episode_len_mean")),
        num_episodes=int(runners.get("num_episodes", 0) or 0),
    )


def train(config: dict, run_dir: Path, log=print) -> dict:
    """Run the training loop on an initialised Ray; returns the result dict written to result.json."""
    import gymnasium as gym
    import ray

    _one_torch_thread()
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "config.json", config)
    register_tissue_envs()
    start = time.perf_counter()
    algo = build_config(config).build_algo()
    setup = time.perf_counter() - start
    result = dict(env=config["env"], algo=config["algo"], seed=config["seed"],
                  num_env_runners=config["num_env_runners"],
                  num_envs_per_env_runner=config["num_envs_per_env_runner"],
                  address=config["address"], ray_version=ray.__version__, gymnasium_version=gym.__version__,
                  cluster_cpus=ray.cluster_resources().get("CPU"), setup_time_s=setup, iterations=[],
                  checkpoints=[], final_checkpoint=None)
    try:
        for index in range(1, int(config["iterations"]) + 1):
            tick = time.perf_counter()
            metrics = algo.train()
            record = iteration_record(metrics, time.perf_counter() - tick)
            result["iterations"].append(record)
            ret = record["episode_return_mean"]
            log(f"iter {index:4d}  env steps {record['env_steps_sampled']:6d}  {record['wall_time_s']:7.2f} s  "
                f"{record['env_steps_per_s']:7.1f} steps/s  return {'n/a' if ret is None else f'{ret:.2f}'}")
            every = int(config.get("checkpoint_every") or 0)
            if every and index % every == 0 and index < int(config["iterations"]):
                path = run_dir / "checkpoints" / f"iter_{index:06d}"
                algo.save_to_path(str(path.resolve()))
                result["checkpoints"].append(str(path))
            _summarise(result)
            write_json(run_dir / "result.json", result)
        final = run_dir / "checkpoint"
        algo.save_to_path(str(final.resolve()))
        result["final_checkpoint"] = str(final)
        _summarise(result)
        write_json(run_dir / "result.json", result)
    finally:
        algo.stop()
    return result


def _summarise(result):
    iterations = result["iterations"]
    steps = sum(r["env_steps_sampled"] for r in iterations)
    wall = sum(r["wall_time_s"] for r in iterations)
    result.update(total_env_steps=steps, total_wall_time_s=wall, env_steps_per_s=steps / wall if wall else None)


def main(argv=None) -> int:
    args = parse_args(argv)
    with usage_errors(PROGRAM):
        run_dir, config = _validated(args)
    ray = require_ray()
    init_ray(ray, config)
    try:
        if config.get("address"):
            _check_worker_imports(ray)
        _check_resources(ray, config)
        train(config, run_dir)
    finally:
        ray.shutdown()
    sys.stdout.flush()
    print(run_dir)
    return 0


if __name__ == "__main__":
    # Run the module's own copy (training.rllib, not __main__) so that the env creator and the
    # connector are pickled by reference for the Ray workers.
    from training.rllib import main as _main

    raise SystemExit(_main())
