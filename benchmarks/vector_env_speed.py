"""Env steps per second of the batched vector envs against gymnasium's SyncVectorEnv.

Usage: python benchmarks/vector_env_speed.py [--num-envs 16] [--steps 100] [--rounds 3] [--env ID ...]

For each task with a ``vector_entry_point``: ``gym.make_vec(id, num_envs=N, vectorization_mode=
"sync")`` (N single envs stepped one after the other) against ``vectorization_mode=
"vector_entry_point"`` (one batched physics step, ``tissue_env.vector``), same seeds and the same
random actions, one process. Two regimes: the registered episode length (random actions end
almost every episode by truncation, so the copies reset together every 50-100 steps), and
episodes long enough that no reset happens (``max_episode_steps`` = 10^6). Both modes reset a copy
by the task env's own ``reset`` (the same code and cost), timed separately: the table gives the
total rate, the share of resets in it, and the rate of the steps alone.

Rates are env steps (N x vector steps) per second of this process's CPU time, so that other jobs
on a shared machine do not count; the modes run alternately, ``--rounds`` times, best round each.
"""

import argparse
import functools
import time

import gymnasium as gym
import numpy as np

import tissue_env
from tissue_env.base import TissueEnv

RESET_SECONDS = [0.0]


def _timed_reset(reset):
    @functools.wraps(reset)
    def wrapper(self, *args, **kwargs):
        start = time.process_time()
        try:
            return reset(self, *args, **kwargs)
        finally:
            RESET_SECONDS[0] += time.process_time() - start
    return wrapper


TissueEnv.reset = _timed_reset(TissueEnv.reset)


def rate(env_id, mode, num_envs, steps, seed=0, **kwargs):
    """(env steps per CPU second, share of the time spent in resets, env steps per CPU second
    without the resets) for ``steps`` vector steps of random actions."""
    envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=mode, **kwargs)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, (steps, num_envs, 3)).astype(np.float32)
    envs.reset(seed=seed)
    for action in actions[:3]:  # warm up: compiled kernels, caches
        envs.step(action)
    envs.reset(seed=seed)
    RESET_SECONDS[0] = 0.0
    start = time.process_time()
    for action in actions:
        envs.step(action)
    elapsed = time.process_time() - start
    resets = RESET_SECONDS[0]
    envs.close()
    count = num_envs * steps
    return count / elapsed, resets / elapsed, count / max(elapsed - resets, 1e-9)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--steps", type=int, default=100, help="vector steps per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.VECTOR_ENTRY_POINTS))
    args = parser.parse_args()
    print(f"N = {args.num_envs}, {args.steps} vector steps, random actions, best of {args.rounds} rounds; "
          "env steps per CPU second")
    print(f"{'env id':32s} {'episodes':>10s} | {'sync':>6s} {'vector':>6s} {'ratio':>5s} | {'resets':>13s} |"
          f" {'steps only: sync':>16s} {'vector':>6s} {'ratio':>5s}")
    for env_id in args.env:
        for label, kwargs in (("registered", {}), ("no reset", dict(max_episode_steps=10**6))):
            best = {}
            for _ in range(args.rounds):
                for mode in ("sync", "vector_entry_point"):
                    result = rate(env_id, mode, args.num_envs, args.steps, **kwargs)
                    if mode not in best or result[0] > best[mode][0]:
                        best[mode] = result
            sync, sync_share, sync_steps = best["sync"]
            vector, vector_share, vector_steps = best["vector_entry_point"]
            print(f"{env_id:32s} {label:>10s} | {sync:6.0f} {vector:6.0f} {vector / sync:4.1f}x |"
                  f" {sync_share:5.0%} / {vector_share:5.0%} | {sync_steps:16.0f} {vector_steps:6.0f}"
                  f" {vector_steps / sync_steps:4.1f}x", flush=True)


if __name__ == "__main__":
    main()
