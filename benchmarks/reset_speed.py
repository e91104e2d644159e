"""Wall time of each task's ``reset`` over many seeds: what an episode costs before its first step.

Usage: python -m benchmarks.reset_speed [--seeds 1000] [--env ID ...] [--env-kwargs JSON]
       [--output benchmarks/results/reset_speed.json]

One env per task, reset with seeds 1 .. N in turn after a warm-up reset (seed 0), one process: the
median, mean, 95th percentile and slowest reset (ms), and for TumorPositioning, whose reset solves
the goal's static equilibrium (``TumorPositioningEnv._start_hook``), the static solves and LU
factorisations per reset and the seeds whose goal needed a retry (a larger displacement solved
again) or kept a smaller goal because the retry failed. ``--env-kwargs`` builds the envs with those
keywords (a JSON object, e.g. a domain randomisation range: every reset that draws a new size or
material builds its model and solves its start). Results are written to ``--output`` (JSON,
replaced atomically).
"""

import argparse
import json
import os
import platform
import time

import gymnasium as gym
import numpy as np

import sim_core.solvers.static as static
import tissue_env
import tissue_env.tumor_positioning as tumor_positioning
from training.common import write_json


class _Counter:
    """Counts ``solve_static`` calls from the goal solve and ``static._factorise`` calls."""

    def __init__(self):
        self.solves = self.factorisations = 0
        self._solve, self._factorise = tumor_positioning.solve_static, static._factorise

    def __enter__(self):
        def solve(*args, **kwargs):
            self.solves += 1
            return self._solve(*args, **kwargs)

        def factorise(*args, **kwargs):
            self.factorisations += 1
            return self._factorise(*args, **kwargs)

        tumor_positioning.solve_static, static._factorise = solve, factorise
        return self

    def __exit__(self, *exc):
        tumor_positioning.solve_static, static._factorise = self._solve, self._factorise


def measure(env_id, seeds, env_kwargs=None):
    env = gym.make(env_id, **(env_kwargs or {})).unwrapped
    env.reset(seed=0)
    times, solves, factorisations, retried = [], [], [], []
    with _Counter() as counter:
        for seed in range(1, seeds + 1):
            before = (counter.solves, counter.factorisations)
            start = time.perf_counter()
            env.reset(seed=seed)
            times.append(1e3 * (time.perf_counter() - start))
            solves.append(counter.solves - before[0])
            factorisations.append(counter.factorisations - before[1])
            if solves[-1] > 1:
                retried.append(seed)
    times = np.array(times)
    row = dict(env_id=env_id, env_kwargs=env_kwargs or {}, seeds=seeds, median_ms=float(np.median(times)), mean_ms=float(times.mean()),
               p95_ms=float(np.percentile(times, 95)), max_ms=float(times.max()),
               slowest_seed=int(np.argmax(times)) + 1, factorisations_per_reset=float(np.mean(factorisations)))
    if env_id == "tissue_env/TumorPositioning-v0":
        row.update(goal_solves_per_reset=float(np.mean(solves)), retried_seeds=len(retried))
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1000)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.ENV_IDS))
    parser.add_argument("--env-kwargs", type=json.loads, default=None,
                        help="the envs' keywords as a JSON object, e.g. '{\"size_range\": [0.045, 0.055]}'")
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "reset_speed.json"))
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {args.seeds}")
    rows = []
    start_load = os.getloadavg()  # the machine's load, beside the times (a shared machine)
    print(f"{'env id':34s} {'median':>8s} {'mean':>8s} {'p95':>8s} {'max':>8s}  ms per reset, seeds 1-{args.seeds}")
    for env_id in args.env:
        row = measure(env_id, args.seeds, args.env_kwargs)
        rows.append(row)
        extra = (f"   {row['goal_solves_per_reset']:.2f} goal solves, {row['factorisations_per_reset']:.2f} "
                 f"factorisations per reset, {row['retried_seeds']} seeds retried"
                 if "goal_solves_per_reset" in row else "")
        print(f"{env_id:34s} {row['median_ms']:8.1f} {row['mean_ms']:8.1f} {row['p95_ms']:8.1f} {row['max_ms']:8.1f}"
              f"{extra}", flush=True)
    result = dict(benchmark="reset_speed", unit="ms of wall time per reset",
                  machine=dict(cpus=os.cpu_count(), platform=platform.platform()), load_average_start=start_load,
                  load_average=os.getloadavg(), results=rows)
    write_json(args.output, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
