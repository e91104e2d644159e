"""Success rate and mean return of the scripted controller and of random actions, per task.

Usage: python -m benchmarks.success_rates [--seeds 20] [--env ID ...] [--stability 100]
[--difficulty easy default hard --out benchmarks/results/difficulty.json]. Episode k
uses reset seed k for both policies; the random policy samples the action space seeded with k. Each
task must be solvable (scripted >= 80 %) and not solvable by chance (random well below it).
``--stability N`` also runs N random-action episodes per task (seeds 1000 ...) and counts those
that ended unstable (``info["unstable"]``), the steps with a non-finite observation, and the
successes: the stability check of the README.

``--difficulty LEVEL ...`` measures each task at each ``difficulty`` (its ``DIFFICULTY`` table) and
writes, per task and level, the keywords the level sets and for both policies the success rate
(the last step's ``is_success``: with ``terminate_on_success=False`` the success held at the end),
the share of episodes that reached a success at some step, the mean number of steps to the first
success (of the episodes that reached one), the mean return, the largest spring strain and, for
TumorPositioning, the mean start distance of the tumour from its goal, into ``--out`` (JSON).
"""

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import tissue_env
from tissue_env.episodes import random_policy, run_episode, scripted_policy
from training.common import write_json


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


def difficulty_episode(env, policy, seed):
    """(return, steps, first success step or None, last info, largest spring strain, start info) of one
    episode of ``policy`` with reset seed ``seed`` (the action space seeded with it too)."""
    _, start = env.reset(seed=int(seed))
    env.action_space.seed(int(seed))
    total, steps, first, strain = 0.0, 0, None, 0.0
    while True:
        _, reward, terminated, truncated, info = env.step(policy(env))
        total += float(reward)
        steps += 1
        strain = max(strain, float(info["max_strain"]))
        if first is None and info["is_success"]:
            first = steps
        if terminated or truncated:
            return total, steps, first, info, strain, start


def measure_difficulty(env_id, level, seeds):
    """The row of ``env_id`` at ``difficulty=level`` (see the module docstring)."""
    env = gym.make(env_id, difficulty=level)
    table = type(env.unwrapped).DIFFICULTY[level]
    row = dict(env_id=env_id, difficulty=level, seeds=seeds,
               keywords={name: (list(value) if isinstance(value, tuple) else value) for name, value in table.items()})
    for name, policy in POLICIES.items():
        start = time.perf_counter()
        episodes = [difficulty_episode(env, policy, seed) for seed in range(seeds)]
        firsts = [first for _, _, first, _, _, _ in episodes if first is not None]
        result = dict(success_rate=float(np.mean([info["is_success"] for _, _, _, info, _, _ in episodes])),
                      reached_rate=len(firsts) / seeds,
                      mean_steps_to_success=float(np.mean(firsts)) if firsts else None,
                      mean_return=float(np.mean([total for total, *_ in episodes])),
                      mean_episode_length=float(np.mean([steps for _, steps, *_ in episodes])),
                      max_strain=float(max(strain for *_, strain, _ in episodes)),
                      seconds=time.perf_counter() - start)
        if "distance" in episodes[0][5]:
            result["mean_start_distance_m"] = float(np.mean([start["distance"] for *_, start in episodes]))
        row[name] = result
    env.close()
    return row


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
    parser.add_argument("--difficulty", nargs="*", default=None, metavar="LEVEL",
                        help="measure every task at these difficulty levels into --out instead")
    parser.add_argument("--out", default="benchmarks/results/difficulty.json")
    args = parser.parse_args()
    if args.difficulty:
        rows = []
        for env_id in args.env:
            for level in args.difficulty:
                row = measure_difficulty(env_id, level, args.seeds)
                rows.append(row)
                for name in POLICIES:
                    result = row[name]
                    steps = result["mean_steps_to_success"]
                    print(f"{env_id:34s} {level:8s} {name:9s} success {result['success_rate']:5.0%} reached "
                          f"{result['reached_rate']:5.0%} steps {steps if steps is None else round(steps, 1)} "
                          f"return {result['mean_return']:8.2f} ({result['seconds']:.0f} s)", flush=True)
        command = ("python -m benchmarks.success_rates --difficulty " + " ".join(args.difficulty)
                   + f" --seeds {args.seeds}" + ("" if sorted(args.env) == sorted(tissue_env.ENV_IDS)
                                                 else " --env " + " ".join(args.env)) + f" --out {args.out}")
        write_json(Path(args.out), dict(command=command, unit="success rates 0-1, steps, m", results=rows))
        return
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
