"""RLlib PPO throughput on a local Ray instance for 1 and 2 env runners (training/rllib.py's config).

Usage: python -m benchmarks.rllib_throughput [--envs tissue_env/TumorPositioning-v0 ...] [--runners 1 2]
    [--iterations 4] [--warmup 1] [--num-cpus 2] [--out benchmarks/results/rllib_throughput.json]

For every task and runner count the PPO config of ``python -m training.rllib`` (hyperparameters of
training/hyperparams/ppo.yml: 1024 env steps per iteration, 10 epochs of minibatches of 64) is built
on one local Ray instance (``ray.init(num_cpus=2, include_dashboard=False)``) and measured:

* train: env steps sampled / wall time of one ``algo.train()`` (sampling on the runners, then the
  PPO update in the driver), median over ``--iterations`` after ``--warmup`` iterations;
* sample: sampling alone, every runner asked for ``--sample-steps`` env steps at once
  (``env_runner_group.foreach_env_runner``), total env steps / wall time, median of 3;
* sample per runner CPU second: the same env steps / the CPU time the runners' processes used
  (``time.process_time`` inside each runner). It does not depend on how many cores other jobs leave
  free: if it stays put from 1 to 2 runners, the runners add no per-step cost and K runners on K
  free cores sample K times as fast;
* for reference, one plain ``gym.make`` env in this process with random actions (no Ray, no policy).

The result goes to benchmarks/results/rllib_throughput.json (temporary file + os.replace) and a
table is printed. The 1-minute load average before and after each measurement is recorded: on a
small machine shared with other jobs the numbers are noisy, compare them only within one run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

from training.common import write_json

REPO = Path(__file__).resolve().parent.parent

DEFAULT_OUT = REPO / "benchmarks" / "results" / "rllib_throughput.json"
ALL_ENVS = ("tissue_env/TumorPositioning-v0", "tissue_env/Palpation-v0", "tissue_env/Retraction-v0")


def plain_env_speed(env_id: str, steps: int = 300, seed: int = 0) -> float:
    """Env steps/s of one env in this process, random actions, resets included."""
    import gymnasium as gym

    import tissue_env  # noqa: F401

    from benchmarks.env_speed import random_steps_per_s

    return random_steps_per_s(gym.make(env_id), steps, seed)


def _sample_with_cpu_time(runner, num_timesteps):
    """In the EnvRunner: sample, return (env steps, CPU seconds of this process)."""
    import time

    start = time.process_time()
    steps = sum(len(episode) for episode in runner.sample(num_timesteps=num_timesteps))
    return steps, time.process_time() - start


def measure(env_id: str, runners: int, envs_per_runner: int, args) -> dict:
    import ray

    from training import rllib

    config = dict(env=env_id, algo="ppo", iterations=args.iterations + args.warmup, seed=0,
                  num_env_runners=runners, num_envs_per_env_runner=envs_per_runner, num_cpus_per_env_runner=1,
                  address=None, num_cpus=args.num_cpus, checkpoint_every=0, env_kwargs={}, ship_code=False,
                  hyperparams=rllib.rllib_hyperparams(env_id))
    load_before = os.getloadavg()[0]
    tick = time.perf_counter()
    algo = rllib.build_config(config).build_algo()
    setup = time.perf_counter() - tick
    try:
        records = []
        for index in range(args.warmup + args.iterations):
            tick = time.perf_counter()
            result = algo.train()
            record = rllib.iteration_record(result, time.perf_counter() - tick)
            if index >= args.warmup:
                records.append(record)
        sample_rates, cpu_rates = [], []
        for _ in range(3):
            tick = time.perf_counter()
            outcomes = algo.env_runner_group.foreach_env_runner(
                lambda runner, n=args.sample_steps: _sample_with_cpu_time(runner, n), local_env_runner=runners == 0)
            wall = time.perf_counter() - tick
            steps = sum(count for count, _ in outcomes)
            sample_rates.append(steps / wall)
            cpu_rates.append(steps / sum(cpu for _, cpu in outcomes))
    finally:
        algo.stop()
    return dict(
        env=env_id, num_env_runners=runners, num_envs_per_env_runner=envs_per_runner,
        cluster_cpus=ray.cluster_resources().get("CPU"),
        train_batch_size=config["hyperparams"]["train_batch_size_per_learner"],
        num_epochs=config["hyperparams"]["num_epochs"], minibatch_size=config["hyperparams"]["minibatch_size"],
        setup_time_s=setup,
        train_env_steps_per_s=statistics.median(r["env_steps_per_s"] for r in records),
        train_env_steps_per_s_all=[r["env_steps_per_s"] for r in records],
        iteration_wall_time_s=statistics.median(r["wall_time_s"] for r in records),
        sample_env_steps_per_s=statistics.median(sample_rates), sample_env_steps_per_s_all=sample_rates,
        sample_env_steps_per_runner_cpu_s=statistics.median(cpu_rates),
        load_average_before=load_before, load_average_after=os.getloadavg()[0],
    )


def _ratio(value) -> str:
    return "     n/a" if value is None else f"{value:7.2f}x"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(ALL_ENVS))
    parser.add_argument("--runners", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--envs-per-runner", nargs="+", type=int, default=[1],
                        help="environments per runner (> 1: the task's batched vector env)")
    parser.add_argument("--iterations", type=int, default=4, help="measured training iterations")
    parser.add_argument("--warmup", type=int, default=1, help="training iterations before measuring")
    parser.add_argument("--sample-steps", type=int, default=512, help="env steps per runner in the sampling test")
    parser.add_argument("--num-cpus", type=int, default=2, help="CPUs of the local Ray instance")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)

    from training import rllib

    ray = rllib.require_ray()
    import gymnasium as gym

    baseline = {env_id: plain_env_speed(env_id) for env_id in args.envs}
    rllib.init_ray(ray, dict(num_env_runners=max(args.runners), num_cpus_per_env_runner=1, address=None,
                             num_cpus=args.num_cpus))
    rows = []
    try:
        rllib._one_torch_thread()
        rllib.register_tissue_envs()
        for env_id in args.envs:
            for envs_per_runner in args.envs_per_runner:
                for runners in args.runners:
                    row = measure(env_id, runners, envs_per_runner, args)
                    row["plain_env_steps_per_s"] = baseline[env_id]
                    rows.append(row)
                    print(f"{env_id} runners={runners} x {envs_per_runner} envs: "
                          f"train {row['train_env_steps_per_s']:.0f} steps/s, "
                          f"sample {row['sample_env_steps_per_s']:.0f} steps/s "
                          f"(load {row['load_average_before']:.1f})",
                          file=sys.stderr, flush=True)
    finally:
        ray.shutdown()
    for row in rows:
        one = next((r for r in rows if r["env"] == row["env"] and r["num_env_runners"] == 1
                    and r["num_envs_per_env_runner"] == row["num_envs_per_env_runner"]), None)
        row["train_speedup_vs_1_runner"] = row["train_env_steps_per_s"] / one["train_env_steps_per_s"] if one else None
        row["sample_speedup_vs_1_runner"] = (row["sample_env_steps_per_s"] / one["sample_env_steps_per_s"]
                                             if one else None)
    import torch

    write_json(args.out, dict(
        description="RLlib PPO env steps per second on a local Ray instance (benchmarks/rllib_throughput.py)",
        note="shared machine: other jobs ran on the same cores, numbers are noisy (see load_average_*)",
        ray_version=ray.__version__, gymnasium_version=gym.__version__, torch_version=torch.__version__,
        python=sys.version.split()[0], cpu_count=os.cpu_count(), num_cpus=args.num_cpus,
        iterations=args.iterations, warmup=args.warmup, sample_steps=args.sample_steps, results=rows))
    print(f"{'env id':32s} {'runners':>7s} {'envs':>4s} {'train steps/s':>13s} {'speed-up':>8s} "
          f"{'sample steps/s':>14s} {'speed-up':>8s} {'per CPU s':>9s} {'iter s':>6s} {'1 env, no Ray':>13s} "
          f"{'load':>5s}")
    for row in rows:
        print(f"{row['env']:32s} {row['num_env_runners']:7d} {row['num_envs_per_env_runner']:4d} "
              f"{row['train_env_steps_per_s']:13.0f} {_ratio(row['train_speedup_vs_1_runner'])} "
              f"{row['sample_env_steps_per_s']:14.0f} "
              f"{_ratio(row['sample_speedup_vs_1_runner'])} {row['sample_env_steps_per_runner_cpu_s']:9.0f} "
              f"{row['iteration_wall_time_s']:6.2f} "
              f"{row['plain_env_steps_per_s']:13.0f} {row['load_average_before']:5.1f}")
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
