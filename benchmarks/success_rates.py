"""Success rate and mean return of the scripted controller and of random actions, per task.

Usage: python benchmarks/success_rates.py [--seeds 20] [--env ID ...] [--stability 100]. Episode k
uses reset seed k for both policies; the random policy samples the action space seeded with k. Each
task must be solvable (scripted >= 80 %) and not solvable by chance (random well below it).
``--stability N`` also runs N random-action episodes per task (seeds 1000 ...) and counts those
that ended unstable (``info["unstable"]``), the steps with a non-finite observation, and the
successes: the stability check of the README.
"""

import argparse
import time

import gymnasium as gym
import numpy as np

import tissue_env
from tissue_env.episodes import random_policy, run_episode, scripted_policy


POLICIES = {"scripted": scripted_policy, "random": random_policy}


def measure(env_id, seeds):
    env = gym.make(env_id)
    rows = {}
    for name, policy in POLICIES.items():
        start = time.perf_counter()
        results = [run_episode(env, policy, seed) for seed in range(seeds)]
        rows[name] = dict(success=np.mean([info["is_success"] for _, _, info in results]),
                          mean_return=np.mean([r for r, _, _ in results]),
                          seconds=time.perf_counter() - start)
    env.close()
    return rows


def stability(env_id, episodes, first_seed=1000):
    """(unstable episodes, steps with a non-finite observation, successes, steps) over ``episodes``
    random-action episodes of ``env_id`` at its defaults."""
    env = gym.make(env_id)
    unstable = nonfinite = successes = steps = 0
    for seed in range(first_seed, first_seed + episodes):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        while True:
            observation, _, terminated, truncated, info = env.step(env.action_space.sample())
            steps += 1
            nonfinite += int(not np.all(np.isfinite(observation)))
            if terminated or truncated:
                unstable += int(bool(info["unstable"]))
                successes += int(bool(info["is_success"]))
                break
    env.close()
    return unstable, nonfinite, successes, steps


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.ENV_IDS))
    parser.add_argument("--stability", type=int, default=0, metavar="N",
                        help="also run N random-action episodes per task and count unstable ones")
    args = parser.parse_args()
    print(f"{'env id':34s} {'policy':9s} {'success':>8s} {'return':>8s} {'time':>6s}")
    for env_id in args.env:
        for name, row in measure(env_id, args.seeds).items():
            print(f"{env_id:34s} {name:9s} {row['success']:8.0%} {row['mean_return']:8.2f} {row['seconds']:5.1f}s")
    if args.stability:
        print(f"\n{args.stability} random-action episodes per task (seeds 1000 ...)")
        print(f"{'env id':34s} {'unstable':>8s} {'non-finite steps':>16s} {'successes':>9s} {'steps':>6s}")
        for env_id in args.env:
            unstable, nonfinite, successes, steps = stability(env_id, args.stability)
            print(f"{env_id:34s} {unstable:8d} {nonfinite:16d} {successes:9d} {steps:6d}")


if __name__ == "__main__":
    main()
