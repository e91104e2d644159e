"""Env steps per second of the batched vector envs against gymnasium's SyncVectorEnv.

Usage: python benchmarks/vector_env_speed.py [--num-envs 16 ...] [--steps 100] [--rounds 3] [--env ID ...]
       [--no-reset] [--output benchmarks/results/vector_env_speed.json]

For each task with a ``vector_entry_point`` and each N: ``gym.make_vec(id, num_envs=N,
vectorization_mode="sync")`` (N single envs stepped one after the other) against
``vectorization_mode="vector_entry_point"`` (one batched physics step, ``tissue_env.vector``),
same seeds and the same random actions, one process, registered episode lengths (random actions
end almost every episode by truncation, so resets are included; ``--no-reset`` adds a regime with
``max_episode_steps`` = 10^6). Both modes reset a copy by the task env's own ``reset`` (the same
code and cost), timed separately: the share of resets is reported.

Rates are env steps (N x vector steps) per second of this process's CPU time, so that other jobs
on a shared machine count less; the two modes alternate within every round (sync, vector, sync,
vector ...) and the table gives the medians over ``--rounds`` rounds and the median of the
per-round ratios. Results are written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import functools
import json
import os
import platform
import tempfile
import time

import gymnasium as gym
import numpy as np

import tissue_env
from tissue_env.base import TissueEnv

RESET_SECONDS = [0.0]
MODES = ("sync", "vector_entry_point")


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
    """(env steps per CPU second, share of the time spent in resets) for ``steps`` vector steps of
    random actions."""
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
    return num_envs * steps / elapsed, resets / elapsed


def write_json(path, payload):
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=directory, suffix=".tmp")
    with os.fdopen(handle, "w") as stream:
        json.dump(payload, stream, indent=2)
        stream.write("\n")
    os.chmod(temporary, 0o644)
    os.replace(temporary, path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[16])
    parser.add_argument("--steps", type=int, default=100, help="vector steps per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.VECTOR_ENTRY_POINTS))
    parser.add_argument("--no-reset", action="store_true", help="also measure episodes that never end")
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "vector_env_speed.json"))
    args = parser.parse_args()
    regimes = [("registered", {})] + ([("no reset", dict(max_episode_steps=10**6))] if args.no_reset else [])
    print(f"{args.steps} vector steps, random actions, median of {args.rounds} interleaved rounds; "
          "env steps per CPU second")
    print(f"{'env id':32s} {'N':>3s} {'episodes':>10s} | {'sync':>6s} {'vector':>6s} {'ratio':>5s} | resets sync / vector")
    rows = []
    for env_id in args.env:
        for num_envs in args.num_envs:
            for label, kwargs in regimes:
                results = {mode: [] for mode in MODES}
                for _ in range(args.rounds):
                    for mode in MODES:
                        results[mode].append(rate(env_id, mode, num_envs, args.steps, **kwargs))
                sync = np.array(results["sync"])
                vector = np.array(results["vector_entry_point"])
                row = dict(env_id=env_id, num_envs=num_envs, episodes=label, steps=args.steps, rounds=args.rounds,
                           sync_steps_per_s=float(np.median(sync[:, 0])),
                           vector_steps_per_s=float(np.median(vector[:, 0])),
                           ratio=float(np.median(vector[:, 0] / sync[:, 0])),
                           sync_reset_share=float(np.median(sync[:, 1])),
                           vector_reset_share=float(np.median(vector[:, 1])),
                           sync_rounds=sync[:, 0].tolist(), vector_rounds=vector[:, 0].tolist())
                rows.append(row)
                print(f"{env_id:32s} {num_envs:3d} {label:>10s} | {row['sync_steps_per_s']:6.0f}"
                      f" {row['vector_steps_per_s']:6.0f} {row['ratio']:4.1f}x |"
                      f" {row['sync_reset_share']:5.0%} / {row['vector_reset_share']:5.0%}", flush=True)
                write_json(args.output, dict(
                    benchmark="vector_env_speed", unit="env steps per CPU second (median of interleaved rounds)",
                    machine=dict(cpus=os.cpu_count(), platform=platform.platform()),
                    load_average=os.getloadavg(), results=rows))


if __name__ == "__main__":
    main()
