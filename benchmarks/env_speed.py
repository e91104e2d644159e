"""Env steps per second of every tissue_env task at its defaults, and the time split.

Usage: python -m benchmarks.env_speed [--steps 300] [--rounds 1] [--integrator static]
       [--output benchmarks/results/env_speed.json].
Random actions, resets included in the total rate (per wall-clock second and per CPU second of
this process, which counts other jobs on a shared machine less); the split (physics = integrator
substeps and contact, observation = measurements and features, reward = reward terms and
success) is from the step calls alone. With several rounds the tasks alternate within each round
and every figure is the median over rounds. One process, one core. Results are written to
``--output`` (JSON, replaced atomically) with the machine's description.
"""

import argparse
import os
import platform
import time

import gymnasium as gym
import numpy as np

import tissue_env
from training.common import write_json


def timed(function, bucket, key):
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            bucket[key] += time.perf_counter() - start
    return wrapper


def random_steps_per_s(env, steps=300, seed=0, clock=None):
    """Env steps/s of ``env`` with random actions, resets included, after 5 warm-up steps (compiled
    kernels, caches), by ``clock`` (default ``time.perf_counter``: wall time); closes the env."""
    clock = time.perf_counter if clock is None else clock
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(5):
        env.step(env.action_space.sample())
    env.reset(seed=seed)
    start = clock()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    rate = steps / (clock() - start)
    env.close()
    return rate


def measure(env_id, steps, seed=0, **kwargs):
    env = gym.make(env_id, **kwargs)
    unwrapped = env.unwrapped
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(5):  # warm up (compiled kernels, caches)
        env.step(env.action_space.sample())
    split = dict(physics=0.0, observation=0.0, reward=0.0)
    worlds = unwrapped.worlds  # the env's one world: its step's stages
    worlds._advance = timed(worlds._advance, split, "physics")
    worlds._measure = timed(worlds._measure, split, "observation")
    worlds._observation = timed(worlds._observation, split, "observation")
    worlds._reward_terms = timed(worlds._reward_terms, split, "reward")
    worlds._is_success = timed(worlds._is_success, split, "reward")
    env.reset(seed=seed)
    step_time, start, cpu_start = 0.0, time.perf_counter(), time.process_time()
    for _ in range(steps):
        tick = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        step_time += time.perf_counter() - tick
        if terminated or truncated:
            env.reset()
    total = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    env.close()
    render_env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    render_env.reset(seed=seed)
    render_env.render()
    tick = time.perf_counter()
    for _ in range(10):
        render_env.render()
    fps = 10 / (time.perf_counter() - tick)
    render_env.close()
    return dict(env_id=env_id, steps_per_s=steps / total, steps_per_cpu_s=steps / cpu, step_only_per_s=steps / step_time,
                render_fps=fps, **{f"{k}_ms": 1e3 * v / steps for k, v in split.items()})


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--integrator", choices=("implicit", "static", "explicit"), default=None,
                        help="the envs' integrator keyword (default: theirs, implicit)")
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "env_speed.json"))
    args = parser.parse_args()
    kwargs = {} if args.integrator is None else dict(integrator=args.integrator)
    env_ids = sorted(tissue_env.ENV_IDS)
    rounds = {env_id: [] for env_id in env_ids}
    for _ in range(max(args.rounds, 1)):
        for env_id in env_ids:
            rounds[env_id].append(measure(env_id, args.steps, **kwargs))
    results = [{key: (env_id if key == "env_id" else float(np.median([r[key] for r in rounds[env_id]])))
                for key in rounds[env_id][0]} for env_id in env_ids]
    print(f"{'env id':34s} {'steps/s':>8s} {'per CPU s':>9s} {'(no reset)':>10s} {'physics':>8s} {'obs':>6s} "
          f"{'reward':>6s} {'render':>7s}")
    for r in results:
        print(f"{r['env_id']:34s} {r['steps_per_s']:8.0f} {r['steps_per_cpu_s']:9.0f} {r['step_only_per_s']:10.0f} "
              f"{r['physics_ms']:6.2f}ms {r['observation_ms']:4.2f}ms {r['reward_ms']:4.2f}ms {r['render_fps']:5.1f}fps")
    machine = dict(platform=platform.platform(), processor=platform.processor(), cpus=os.cpu_count(),
                   python=platform.python_version(), numpy=np.__version__, load_average=list(os.getloadavg()))
    payload = dict(steps=args.steps, rounds=args.rounds, integrator=args.integrator or "implicit", machine=machine,
                   results=results)
    write_json(args.output, payload)


if __name__ == "__main__":
    main()
