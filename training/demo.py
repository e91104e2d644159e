"""``make demo``: train a short PPO run on TumorPositioning-v0, evaluate it against random actions
and the scripted controller, and write a learning curve and a strip of frames of one episode.

    python -m training.demo [--timesteps 12000] [--seed 0] [--episodes 20] [--output-dir DIR | --publish]

About 2-3 minutes on 2 cores. Prints where the outputs are. The run and the two figures go under
runs/demo/ of the clone (or ``--output-dir``); ``--publish`` writes the figures into docs/figures/
instead, replacing the committed ones that the README shows.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sim_core.files import atomic_path

from .common import check_env_id, load_hyperparams
from .evaluate import evaluate
from .plot import plot
from .train import train

ROOT = Path(__file__).resolve().parents[1]
ENV = "tissue_env/TumorPositioning-v0"
#: where --publish writes the figures (committed, shown by the README)
PUBLISHED = ROOT / "docs" / "figures"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=12000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--runs-dir", default=str(ROOT / "runs" / "demo"))
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--output-dir", default=None, help="folder of the figures (default: --runs-dir)")
    where.add_argument("--publish", action="store_true",
                       help=f"write the figures into {PUBLISHED.relative_to(ROOT)}/ (the committed ones)")
    return parser.parse_args(argv)


def figures_dir(args) -> Path:
    """Where the figures go: docs/figures/ with --publish, else --output-dir, else --runs-dir."""
    if args.publish:
        return PUBLISHED
    return Path(args.output_dir or args.runs_dir)


def frame_strip(run_dir: Path, out: Path, seed: int, frames_wanted: int = 6) -> Path:
    """Render the agent's episode on ``seed`` and save evenly spaced frames side by side."""
    import gymnasium as gym
    from PIL import Image

    from .evaluate import agent_policy

    config = json.loads((run_dir / "config.json").read_text())
    env = gym.make(ENV, render_mode="rgb_array", **config.get("env_kwargs", {}))
    policy = agent_policy(run_dir, config)
    observation, _ = env.reset(seed=seed)
    frames = [env.render()]
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(policy(observation, env))
        frames.append(env.render())
        done = terminated or truncated
    env.close()
    picks = np.unique(np.linspace(0, len(frames) - 1, min(frames_wanted, len(frames))).round().astype(int))
    strip = np.concatenate([frames[i] for i in picks], axis=1)
    with atomic_path(out) as temporary:
        Image.fromarray(strip).save(temporary)
    return out


def main(argv=None) -> int:
    args = parse_args(argv)
    check_env_id(ENV)
    hyperparams = load_hyperparams("ppo", ENV)
    n_envs = int(hyperparams.pop("n_envs", 4))
    hyperparams.pop("n_timesteps", None)  # the demo's budget is --timesteps
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run_dir = Path(args.runs_dir) / "tissue_env_TumorPositioning-v0" / "ppo" / f"seed{args.seed}-{stamp}"
    config = dict(env=ENV, algo="ppo", timesteps=args.timesteps, seed=args.seed, n_envs=n_envs, vec_env="dummy",
                  threads=1, env_kwargs={}, hyperparams=hyperparams, eval_freq=max(args.timesteps // 6, 1),
                  eval_episodes=10, checkpoint_freq=max(args.timesteps // 4, 1))
    start = time.perf_counter()
    print(f"training PPO on {ENV} for {args.timesteps} steps ({n_envs} envs)...", flush=True)
    train(config, run_dir, progress=False)
    trained = time.perf_counter() - start
    result = evaluate(run_dir, args.episodes, seed=1000)
    figures = figures_dir(args)
    figures.mkdir(parents=True, exist_ok=True)
    curve = plot([run_dir], figures / "demo_learning_curve.png")
    strip = frame_strip(run_dir, figures / "demo_episode.png", seed=1000)
    print()
    print(f"{'policy':<10}{'success':>9}{'mean return':>13}{'episode length':>16}   ({args.episodes} episodes, seeds 1000+)")
    for who in ("agent", "random", "scripted"):
        stats = result[who]
        print(f"{who:<10}{stats['success_rate']:>9.0%}{stats['mean_return']:>13.2f}{stats['mean_episode_length']:>16.1f}")
    print(f"\ntraining wall-clock: {trained:.0f} s")
    print(f"run folder:      {run_dir}")
    print(f"learning curve:  {curve}")
    print(f"episode frames:  {strip}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
