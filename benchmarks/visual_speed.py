"""Env steps per second with camera observations against the state observation, every task.

Usage: python -m benchmarks.visual_speed [--steps 300] [--rounds 3] [--sizes 64 128]
       [--output benchmarks/results/visual_speed.json]

For each task, observation_type "state", then "rgb" and "depth" at each image size (the task's
default camera), measured side by side in one process, interleaved within each round: env steps
per wall second with random actions, resets included (``env_speed.random_steps_per_s``, the
measurement of benchmarks/env_speed.py). Each figure is the median over rounds; each ratio
(visual / state) is the median of the rounds' ratios, so that the load of a shared machine, which
drifts between rounds, cancels. The frame cost alone (``TaskWorlds.camera_images``: projection,
shading and the z-buffer of one world) is timed too. The speed floor the camera keeps: visual
observations at >= 0.5x the state observation's steps/s. One process, one core. Results are written
to ``--output`` (JSON, replaced atomically) with the machine's description and the command.
"""

import argparse
import os
import platform
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import tissue_env
from benchmarks.env_speed import random_steps_per_s
from training.common import write_json

ROOT = Path(__file__).resolve().parents[1]

#: the speed floor: a visual observation's steps/s over the state observation's
FLOOR = 0.5


def frame_us(env_id, size, repeats=200):
    """Median microseconds of one frame (rgb and depth together) of the env after a reset."""
    env = gym.make(env_id, observation_type="rgb", image_size=size)
    env.reset(seed=0)
    worlds = env.unwrapped.worlds
    worlds.camera_images()
    times = []
    for _ in range(repeats):
        tick = time.perf_counter()
        worlds.camera_images()
        times.append(time.perf_counter() - tick)
    env.close()
    return 1e6 * float(np.median(times))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--output", default=str(ROOT / "benchmarks" / "results" / "visual_speed.json"))
    args = parser.parse_args(argv)
    configurations = [("state", None)] + [(kind, size) for size in args.sizes for kind in ("rgb", "depth")]
    names = [kind if size is None else f"{kind}_{size}" for kind, size in configurations]
    env_ids = sorted(tissue_env.ENV_IDS)
    rates = {env_id: {name: [] for name in names} for env_id in env_ids}
    for _ in range(max(args.rounds, 1)):
        for env_id in env_ids:
            for name, (kind, size) in zip(names, configurations):
                kwargs = dict(observation_type=kind) if size is None else dict(observation_type=kind, image_size=size)
                rates[env_id][name].append(random_steps_per_s(gym.make(env_id, **kwargs), args.steps))
    results = []
    for env_id in env_ids:
        state = np.asarray(rates[env_id]["state"])
        ratios = {name: float(np.median(np.asarray(rates[env_id][name]) / state)) for name in names[1:]}
        results.append(dict(
            env_id=env_id,
            steps_per_s={name: float(np.median(values)) for name, values in rates[env_id].items()},
            ratio_to_state=ratios,
            frame_us={str(size): frame_us(env_id, size) for size in args.sizes},
            floor_holds=bool(min(ratios.values()) >= FLOOR)))
    print(f"{'env id':34s} " + " ".join(f"{name:>10s}" for name in names) + "   (steps/s; ratio to state)")
    for r in results:
        print(f"{r['env_id']:34s} " + " ".join(f"{r['steps_per_s'][name]:10.0f}" for name in names))
        print(f"{'':34s} {'':>10s} " + " ".join(f"{r['ratio_to_state'][name]:10.2f}" for name in names[1:])
              + f"   frame us: {r['frame_us']}")
    machine = dict(platform=platform.platform(), processor=platform.processor(), cpus=os.cpu_count(),
                   python=platform.python_version(), numpy=np.__version__, load_average=list(os.getloadavg()))
    command = "python -m benchmarks.visual_speed" + (
        "" if (args.steps, args.rounds, args.sizes) == (300, 3, [64, 128])
        else f" --steps {args.steps} --rounds {args.rounds} --sizes {' '.join(map(str, args.sizes))}")
    payload = dict(command=command, steps=args.steps, rounds=args.rounds, sizes=args.sizes, floor=FLOOR,
                   unit="env steps per wall second, random actions, resets included (median over rounds); "
                        "ratio: the median over rounds of visual / state",
                   machine=machine, results=results)
    write_json(args.output, payload)


if __name__ == "__main__":
    main()
