"""Size and speed of episode snapshots (``env.unwrapped.get_state()`` / ``set_state``), per task.

Usage: python -m benchmarks.snapshots [--snapshots 20] [--repeats 50] [--env ID ...]
       [--output benchmarks/results/snapshots.json]

One env per task with its default keywords, reset with seed 0, then stepped with random actions
(seeded); a snapshot is taken after every step, up to ``--snapshots`` of them (the episode is reset
with the next seed when it ends). Per task: the pickled size of each snapshot (MB = 1e6 bytes,
``pickle.HIGHEST_PROTOCOL``), and over ``--repeats`` calls on each snapshot the wall time of
``get_state``, of ``set_state`` with the snapshot in memory (models, factors and caches shared) and
of ``set_state`` of a snapshot just unpickled on a fresh env of the task (whose first restore
computes the solver's factors again from what the snapshot says they were computed from, and finds
or builds the model), all as medians, with snapshots per second = 1 / median time. Results are
written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import os
import pickle
import platform
import time

import gymnasium as gym
import numpy as np

import tissue_env
from training.common import write_json

#: The floor of issue 43: a pickled snapshot of every task is below this size.
MAX_MB = 2.0


def _timed(call, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return times


def measure(env_id, snapshots, repeats, seed=0):
    env = gym.make(env_id).unwrapped
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    taken = []
    while len(taken) < snapshots:
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
        if terminated or truncated:
            seed += 1
            env.reset(seed=seed)
        taken.append(env.get_state())
    sizes = [len(pickle.dumps(snapshot, protocol=pickle.HIGHEST_PROTOCOL)) / 1e6 for snapshot in taken]
    get_times, set_times, unpickled_times = [], [], []
    for snapshot in taken:
        env.set_state(snapshot)
        get_times += _timed(env.get_state, repeats)
        set_times += _timed(lambda: env.set_state(snapshot), repeats)
    fresh = gym.make(env_id).unwrapped
    for snapshot in taken:
        data = pickle.dumps(snapshot, protocol=pickle.HIGHEST_PROTOCOL)
        unpickled_times += _timed(lambda: fresh.set_state(pickle.loads(data)), 1)
    return dict(env_id=env_id, snapshots=len(taken), repeats=repeats,
                pickled_mb_median=float(np.median(sizes)), pickled_mb_max=float(np.max(sizes)),
                get_state_ms_median=1e3 * float(np.median(get_times)),
                get_state_per_s=1.0 / float(np.median(get_times)),
                set_state_ms_median=1e3 * float(np.median(set_times)),
                set_state_per_s=1.0 / float(np.median(set_times)),
                unpickled_set_state_ms_median=1e3 * float(np.median(unpickled_times)),
                below_floor=bool(np.max(sizes) < MAX_MB))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--snapshots", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.ENV_IDS))
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "snapshots.json"))
    args = parser.parse_args(argv)
    if args.snapshots < 1 or args.repeats < 1:
        parser.error(f"--snapshots and --repeats must be >= 1, got {args.snapshots} and {args.repeats}")
    rows = []
    print(f"{'env id':38s} {'MB median':>9s} {'MB max':>7s} {'get/s':>8s} {'set/s':>8s} {'unpickled set ms':>17s}")
    for env_id in args.env:
        row = measure(env_id, args.snapshots, args.repeats)
        rows.append(row)
        print(f"{env_id:38s} {row['pickled_mb_median']:9.3f} {row['pickled_mb_max']:7.3f} {row['get_state_per_s']:8.0f} "
              f"{row['set_state_per_s']:8.0f} {row['unpickled_set_state_ms_median']:17.1f}", flush=True)
    result = dict(benchmark="snapshots",
                  unit="MB (1e6 bytes) per pickled snapshot; snapshots per second; ms (medians)",
                  floor_mb=MAX_MB, machine=dict(cpus=os.cpu_count(), platform=platform.platform()), results=rows)
    write_json(args.output, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
