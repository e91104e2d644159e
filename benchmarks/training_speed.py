"""Training throughput of stable-baselines3 PPO on each vector-env mode of ``training.train``.

Usage: python -m benchmarks.training_speed [--timesteps 16384] [--n-envs 4 16] [--rounds 1] [--env ID ...]
       [--modes subproc batched] [--output benchmarks/results/training_speed.json]

For each task, each N and each ``--vec-env`` mode: ``python -m training.train --algo ppo`` with the
task's PPO hyperparameters (``training/hyperparams/ppo.yml``) but ``n_steps`` = 1024 / N, so that
every N collects the same 1024 env steps per update; no evaluation and one checkpoint, in a
temporary folder. The rate is env steps per wall second of ``model.learn`` (``result.json``'s
``wall_clock_s``: sampling and the PPO updates; torch on one thread), the modes alternating within
every round; medians over rounds. Results are written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from training.common import write_json

REPO = Path(__file__).resolve().parent.parent

TASKS = ("tissue_env/TumorPositioning-v0", "tissue_env/Palpation-v0", "tissue_env/Retraction-v0")


def rate(env_id, mode, n_envs, timesteps, seed=0):
    """Env steps per wall second of one PPO run."""
    with tempfile.TemporaryDirectory() as folder:
        config = Path(folder) / "ppo.yml"
        config.write_text(f"default:\n  n_envs: {n_envs}\n  n_steps: {1024 // n_envs}\n")
        command = [sys.executable, "-m", "training.train", "--env", env_id, "--algo", "ppo", "--timesteps",
                   str(timesteps), "--seed", str(seed), "--n-envs", str(n_envs), "--vec-env", mode, "--runs-dir",
                   folder, "--no-progress", "--eval-freq", str(10 * timesteps), "--checkpoint-freq",
                   str(timesteps), "--config", str(config)]
        process = subprocess.run(command, capture_output=True, text=True, cwd=REPO)
        if process.returncode != 0:
            raise RuntimeError(f"{' '.join(command)} failed:\n{process.stderr[-2000:]}")
        run_dir = Path(process.stdout.strip().splitlines()[-1])
        result = json.loads((run_dir / "result.json").read_text())
        return result["timesteps"] / result["wall_clock_s"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=16384)
    parser.add_argument("--n-envs", type=int, nargs="+", default=[4, 16])
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--env", nargs="+", default=list(TASKS))
    parser.add_argument("--modes", nargs="+", default=["subproc", "batched"])
    parser.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "training_speed.json"))
    args = parser.parse_args()
    print(f"PPO, {args.timesteps} env steps, 1024 per update; env steps per wall second, median of {args.rounds}")
    print(f"{'env id':32s} {'N':>3s} | " + " | ".join(f"{mode:>8s}" for mode in args.modes))
    rows = []
    for env_id in args.env:
        for n_envs in args.n_envs:
            runs = {mode: [] for mode in args.modes}
            for _ in range(args.rounds):
                for mode in args.modes:
                    runs[mode].append(rate(env_id, mode, n_envs, args.timesteps))
            row = dict(env_id=env_id, n_envs=n_envs, timesteps=args.timesteps, rounds=args.rounds,
                       steps_per_s={mode: float(np.median(values)) for mode, values in runs.items()},
                       rounds_steps_per_s=runs)
            rows.append(row)
            cells = " | ".join(f"{row['steps_per_s'][mode]:8.0f}" for mode in args.modes)
            print(f"{env_id:32s} {n_envs:3d} | {cells}", flush=True)
            write_json(args.output, dict(benchmark="training_speed", unit="env steps per wall second of model.learn",
                                         machine=dict(cpus=os.cpu_count(), platform=platform.platform()),
                                         load_average=os.getloadavg(), results=rows))


if __name__ == "__main__":
    main()
