"""``make demo``: train a short PPO run on TumorPositioning-v0, evaluate it against random actions
and the scripted controller, and write a learning curve and a strip of frames of one episode.

    python -m training.demo [--timesteps 12000] [--seed 0] [--episodes 20] [--output-dir DIR | --publish]

About 100 s of CPU once the kernels are compiled (``make`` compiles them first): training 12,288
steps (whole rollouts), evaluations and figures; it shows SB3's progress bar (tqdm and rich, the
``train`` extra) and the wall clock of each phase, 5.5 minutes on 2 cores that other jobs kept busy.
Prints where the outputs are. The run and the two figures go under
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


def strip_steps(steps: int, reached, frames_wanted: int = 8) -> np.ndarray:
    """The steps (0 = the reset) an episode strip of ``steps`` steps shows, at most
    ``frames_wanted``: every step up to the first success ``reached`` (None: none) when that comes
    early, then frames spread evenly to the last step; otherwise frames spread over the whole
    episode with the first success among them."""
    if reached is not None and reached <= frames_wanted // 2:
        return np.unique(np.concatenate([np.arange(reached + 1),
                                         np.linspace(reached, steps, frames_wanted - reached).round().astype(int)]))
    picks = np.unique(np.linspace(0, steps, min(frames_wanted, steps + 1)).round().astype(int))
    if reached is not None and reached not in picks and len(picks) > 2:
        inner = 1 + int(np.argmin(np.abs(picks[1:-1] - reached)))  # the first and the last stay
        picks[inner] = reached
    return np.unique(picks)


def frame_strip(run_dir: Path, out: Path, seed: int, frames_wanted: int = 8) -> Path:
    """Render the agent's episode on ``seed`` to the time limit (the episode the evaluation ends at
    the first success goes on, to show whether the agent holds the tumour there) and save
    ``frames_wanted`` frames of it: every step up to the first success, then frames spread over
    the rest to the last step. Each frame is titled with its step and the tumour's distance to the
    goal; a legend names the markers and a colour bar gives the displacement
    (``tissue_env.rendering``)."""
    import gymnasium as gym
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tissue_env.rendering import colour_bar

    from .evaluate import agent_policy

    config = json.loads((run_dir / "config.json").read_text())
    env = gym.make(ENV, render_mode="rgb_array", **{**config.get("env_kwargs", {}), "terminate_on_success": False})
    policy = agent_policy(run_dir, config)
    observation, info = env.reset(seed=seed)
    frames = [(env.render(), info.get("distance"), False)]
    done = False
    while not done:
        observation, _, terminated, truncated, info = env.step(policy(observation, env))
        frames.append((env.render(), info.get("distance"), bool(info.get("is_success"))))
        done = terminated or truncated
    handles, labels = env.unwrapped.render_legend()
    scale = env.unwrapped.render_scale
    env.close()
    steps = len(frames) - 1
    reached = next((step for step, (_, _, success) in enumerate(frames) if success), None)
    picks = strip_steps(steps, reached, frames_wanted)
    figure, axes = plt.subplots(1, len(picks), figsize=(1.9 * len(picks) + 1.0, 2.9), squeeze=False)
    for ax, step in zip(axes[0], picks):
        frame, distance, success = frames[step]
        ax.imshow(frame[28:-28, 28:-28])  # the renderer's margin around the block
        ax.set_axis_off()
        title = f"step {step}" if step else "start (reset)"
        if distance is not None:
            title += f"\n{1e3 * float(np.ravel(distance)[0]):.1f} mm to goal"
        ax.set_title(title, fontsize=9, color="green" if success else "black")
    outcome = (f"goal reached at step {reached} (where evaluation ends the episode), "
               f"{'held' if frames[-1][2] else 'not held'} to step {steps}" if reached is not None
               else f"goal not reached in {steps} steps")
    figure.suptitle(f"PPO agent on {ENV.split('/')[-1]}, episode seed {seed}: {outcome}\n"
                    f"(green: within the success distance)", fontsize=9)
    figure.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
    figure.subplots_adjust(left=0.005, right=0.94, top=0.76, bottom=0.12, wspace=0.02)
    colour_bar(figure, scale, cax=figure.add_axes((0.95, 0.18, 0.008, 0.52)))
    with atomic_path(out) as temporary:
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)
    return out


def progress_bar_available() -> bool:
    """SB3's progress bar needs tqdm and rich (the ``train`` extra installs both)."""
    import importlib.util

    return all(importlib.util.find_spec(name) is not None for name in ("tqdm", "rich"))


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
    train(config, run_dir, progress=progress_bar_available())
    trained = time.perf_counter() - start
    print(f"evaluating the agent, random actions and the scripted controller on {args.episodes} episodes each...",
          flush=True)
    result = evaluate(run_dir, args.episodes, seed=1000)
    evaluated = time.perf_counter() - start - trained
    figures = figures_dir(args)
    figures.mkdir(parents=True, exist_ok=True)
    curve = plot([run_dir], figures / "demo_learning_curve.png")
    strip = frame_strip(run_dir, figures / "demo_episode.png", seed=1000)
    drawn = time.perf_counter() - start - trained - evaluated
    print()
    print(f"{'policy':<10}{'success':>9}{'mean return':>13}{'episode length':>16}   ({args.episodes} episodes, seeds 1000+)")
    for who in ("agent", "random", "scripted"):
        stats = result[who]
        print(f"{who:<10}{stats['success_rate']:>9.0%}{stats['mean_return']:>13.2f}{stats['mean_episode_length']:>16.1f}")
    print(f"\nwall-clock: training {trained:.0f} s, evaluation {evaluated:.0f} s, figures {drawn:.0f} s")
    print(f"run folder:      {run_dir}")
    print(f"learning curve:  {curve}")
    print(f"episode frames:  {strip}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
