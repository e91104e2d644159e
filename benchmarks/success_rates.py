"""Success rate and mean return of the scripted controller and of random actions, per task.

Usage: python benchmarks/success_rates.py [--seeds 20] [--env ID ...]. Episode k uses reset
seed k for both policies; the random policy samples the action space seeded with k. Each task
must be solvable (scripted >= 80 %) and not solvable by chance (random well below it).
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.ENV_IDS))
    args = parser.parse_args()
    print(f"{'env id':34s} {'policy':9s} {'success':>8s} {'return':>8s} {'time':>6s}")
    for env_id in args.env:
        for name, row in measure(env_id, args.seeds).items():
            print(f"{env_id:34s} {name:9s} {row['success']:8.0%} {row['mean_return']:8.2f} {row['seconds']:5.1f}s")


if __name__ == "__main__":
    main()
