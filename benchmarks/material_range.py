"""Every task across the stiffness range of real tissue: observations inside their bounds, rewards
of the same size, the scripted controller still succeeding.

Usage: python -m benchmarks.material_range [--moduli 1e3 1e4 1e5 1e6] [--poisson-ratios 0.3 0.45 0.49]
       [--steps 100] [--seeds 3] [--output benchmarks/results/material_range.json]

For each task, Young's modulus E (Pa) and Poisson's ratio nu (a material the env refuses at reset
is recorded with its message): ``--steps`` random actions (action space seeded 0, episodes
reset as they end) give the share of observation entries at their bound (|x| >= 0.999 of the
observation space's bound: OBS_LIMIT, or FEATURE_LIMITS for the maximum spring strain in %, which a
soft tissue stretched to more than twice its length passes 100% of), the largest maximum spring
strain, the steps with an entry at its bound that ``info`` does not report as clipped
(``observation_clipped``), and the largest |reward|; then the task's scripted controller runs one episode on each of
``--seeds`` seeds (100, 101, ...): its successes are counted, and the largest force on a tool in them (N,
``info["tool_forces"]``; what a grasp held, for the tasks whose instrument may slip) recorded. Written to ``--output`` (JSON,
replaced atomically); with ``--env`` naming some tasks, the other tasks' rows already in
``--output`` are kept.
"""

import argparse
import json
import os
import platform
import sys
import warnings

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401
from tissue_env.worlds import FEATURE_LIMITS, OBS_LIMIT
from training.common import write_json

#: every registered task
TASKS = tuple(tissue_env.ENV_IDS)


def measure(env_id, young_modulus, steps, seeds, poisson_ratio=None):
    """One row of the table (module docstring); ``poisson_ratio`` None: the task's default."""
    env = gym.make(env_id, young_modulus=young_modulus,
                   **({} if poisson_ratio is None else dict(poisson_ratio=poisson_ratio)))
    row = dict(env_id=env_id, young_modulus=young_modulus, poisson_ratio=float(env.unwrapped.poisson_ratio),
               seeds=seeds)
    env.action_space.seed(0)
    try:
        env.reset(seed=0)
    except ValueError as error:  # a material the task refuses (e.g. too soft for its weight): say so
        return dict(row, refused=str(error).splitlines()[0])
    at_bound = entries = unreported = 0
    largest = largest_strain = 0.0
    limits = env.observation_space.high
    # the maximum spring strain (%) is the entry bounded by its own limit: its index differs by task
    strain_entries = np.flatnonzero(limits == np.float32(FEATURE_LIMITS["max_strain"]))
    for _ in range(steps):
        observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
        bound = np.abs(observation) >= 0.999 * limits
        at_bound += int(np.count_nonzero(bound))
        largest_strain = max(largest_strain, float(observation[strain_entries].max()))
        unreported += int(bound.any() and not info["observation_clipped"])
        entries += observation.size
        largest = max(largest, abs(float(reward)))
        if terminated or truncated:
            env.reset()
    successes, peak = 0, 0.0
    for seed in range(100, 100 + seeds):
        env.reset(seed=seed)
        terminated = truncated = False
        while not (terminated or truncated):
            _, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
            peak = max(peak, float(np.max(np.linalg.norm(info["tool_forces"], axis=-1), initial=0.0)))
        successes += bool(info["is_success"])
    env.close()
    return dict(row, share_at_bound=at_bound / entries, max_strain_percent=largest_strain,
                unreported_clipped_steps=unreported, max_abs_reward=largest, scripted_successes=successes,
                scripted_peak_tool_force_N=peak)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moduli", type=float, nargs="*", default=[1e3, 1e4, 1e5, 1e6])
    parser.add_argument("--poisson-ratios", type=float, nargs="*", default=[0.3, 0.45, 0.49])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--env", nargs="*", default=list(TASKS))
    parser.add_argument("--output", default="benchmarks/results/material_range.json")
    args = parser.parse_args(argv)
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for env_id in args.env:
            for modulus in args.moduli:
                for ratio in args.poisson_ratios:
                    rows.append(measure(env_id, modulus, args.steps, args.seeds, poisson_ratio=ratio))
                    r = rows[-1]
                    if "refused" in r:
                        print(f"{env_id} E={modulus:g} Pa nu={ratio:g}: refused: {r['refused']}", flush=True)
                        continue
                    print(f"{env_id} E={modulus:g} Pa nu={ratio:g}: {100 * r['share_at_bound']:.2f}% of entries at "
                          f"bound (max spring strain {r['max_strain_percent']:.0f}%), max |reward| "
                          f"{r['max_abs_reward']:.2f}, scripted {r['scripted_successes']}/{args.seeds}", flush=True)
    if os.path.exists(args.output):  # the tasks not measured this time keep their rows
        with open(args.output) as stream:
            kept = [row for row in json.load(stream)["results"] if row["env_id"] not in args.env]
        rows = sorted(kept + rows, key=lambda row: TASKS.index(row["env_id"]) if row["env_id"] in TASKS else len(TASKS))
    write_json(args.output, dict(command="python -m benchmarks.material_range", steps=args.steps, obs_limit=OBS_LIMIT, feature_limits=FEATURE_LIMITS, results=rows,
                                 machine=dict(platform=platform.platform(), cpus=os.cpu_count(),
                                              python=platform.python_version())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
