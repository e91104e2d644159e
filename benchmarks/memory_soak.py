"""Resident memory of each task over a long run of random actions: does anything grow without bound?

Usage: python -m benchmarks.memory_soak [--steps 100000] [--env ID ...] [--randomise]
       [--envs-in-turn 0] [--output benchmarks/results/memory_soak.json]

One env per task in its own process (so one task's memory does not count against another's),
random actions from a seeded action space, episodes reset on termination or truncation. The
resident set size (RSS, from /proc/self/status) is read every ``steps / 50`` steps. "After warm-up"
is the RSS once 10% of the steps have run (every kernel compiled, every cache at its working size);
the run passes when the largest RSS after that is within 15% of it. ``--randomise`` draws the
Young's modulus per episode from 3-30 kPa (every episode a new model: the model caches at work).
``--envs-in-turn K`` instead builds K envs of each task one after the other in one process (each
reset and stepped 200 times, then dropped) and reports the RSS after each.
Results are written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import gc
import multiprocessing
import os
import platform
import sys
import time

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the envs)
from training.common import write_json

TASKS = ("tissue_env/TumorPositioning-v0", "tissue_env/Palpation-v0", "tissue_env/Retraction-v0")
WARMUP_SHARE = 0.1
BOUND = 0.15


def rss_mb(field: str = "VmRSS") -> float:
    """This process's resident set size, MB (``field`` of /proc/self/status: VmRSS now, VmHWM its peak)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no {field} in /proc/self/status")


def soak(env_id, steps, randomise, seed=0):
    kwargs = dict(young_modulus_range=(3e3, 3e4)) if randomise else {}
    env = gym.make(env_id, **kwargs)
    env.action_space.seed(seed)
    env.reset(seed=seed)
    every = max(1, steps // 50)
    samples, episodes, unstable = [], 0, 0
    start = time.perf_counter()
    for step in range(1, steps + 1):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        unstable += bool(info.get("unstable", False))
        if terminated or truncated:
            episodes += 1
            env.reset()
        if step % every == 0:
            samples.append((step, rss_mb()))
    seconds = time.perf_counter() - start
    env.close()
    warm = next(rss for step, rss in samples if step >= WARMUP_SHARE * steps)
    after = [rss for step, rss in samples if step >= WARMUP_SHARE * steps]
    growth = max(after) / warm - 1.0
    return dict(env_id=env_id, steps=steps, randomise=randomise, episodes=episodes, unstable_steps=unstable,
                seconds=seconds, rss_start_mb=samples[0][1], rss_after_warmup_mb=warm, rss_max_mb=max(after),
                rss_final_mb=samples[-1][1], growth_after_warmup=growth, within_bound=bool(growth <= BOUND),
                samples=samples)


def in_turn(env_id, count):
    samples = []
    for index in range(count):
        env = gym.make(env_id, young_modulus=5e3 + 1e3 * index)
        env.action_space.seed(index)
        env.reset(seed=index)
        for _ in range(200):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
        env.close()
        del env
        gc.collect()
        samples.append(rss_mb())
    growth = max(samples[1:]) / samples[0] - 1.0 if count > 1 else 0.0
    return dict(env_id=env_id, envs_in_turn=count, rss_after_each_mb=samples, growth_after_first=growth,
                within_bound=bool(growth <= BOUND))


def _child(args, queue):
    function, arguments = args
    queue.put(function(*arguments))


def isolated(function, *arguments):
    """``function(*arguments)`` in a fresh process (its memory is its own)."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_child, args=((function, arguments), queue))
    process.start()
    result = queue.get()
    process.join()
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--env", nargs="*", default=list(TASKS))
    parser.add_argument("--randomise", action="store_true")
    parser.add_argument("--envs-in-turn", type=int, default=0)
    parser.add_argument("--output", default="benchmarks/results/memory_soak.json")
    args = parser.parse_args(argv)
    if args.steps < 100:
        parser.error("--steps must be >= 100")
    results = []
    for env_id in args.env:
        if args.envs_in_turn:
            result = isolated(in_turn, env_id, args.envs_in_turn)
            print(f"{env_id}: RSS after each env (MB) {np.round(result['rss_after_each_mb'], 0).tolist()}, "
                  f"growth after the first {100 * result['growth_after_first']:.1f}%", flush=True)
        else:
            result = isolated(soak, env_id, args.steps, args.randomise)
            print(f"{env_id}: {args.steps} steps in {result['seconds']:.0f} s, RSS {result['rss_start_mb']:.0f} -> "
                  f"{result['rss_after_warmup_mb']:.0f} (warm) -> max {result['rss_max_mb']:.0f}, "
                  f"final {result['rss_final_mb']:.0f} MB: growth after warm-up "
                  f"{100 * result['growth_after_warmup']:.1f}%", flush=True)
        results.append(result)
    write_json(args.output, dict(
        steps=args.steps, randomise=args.randomise, envs_in_turn=args.envs_in_turn, bound=BOUND,
        warmup_share=WARMUP_SHARE,
        machine=dict(platform=platform.platform(), cpus=os.cpu_count(), python=platform.python_version(),
                     numpy=np.__version__),
        results=results))
    return 0 if all(result["within_bound"] for result in results) else 1


if __name__ == "__main__":
    sys.exit(main())
