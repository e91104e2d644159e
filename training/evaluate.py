"""Evaluate a trained run against uniform random actions and the task's scripted controller.

    python -m training.evaluate RUN_DIR --episodes K [--seed S] [--render FILE.gif]

Prints one JSON object: for "agent", "random" and "scripted" (the environment's
``scripted_action()``; null when the task has none), on the same episode seeds: mean_return,
std_return, success_rate, mean_episode_length, episodes.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from tissue_env.episodes import run_episode

from .common import CommandParser, UsageError, algorithm_class, check_env_id, load_model, usage_errors

PROGRAM = "training.evaluate"


def _episodes(env, policy, seeds, frames=None):
    """Run one episode per seed with ``policy(observation, env) -> action``; returns statistics.
    The observation is the one the policy's last step produced (tracked by a small wrapper)."""
    returns, lengths, successes = [], [], []
    tracked = _ObservationTracker(env)
    for index, seed in enumerate(seeds):
        total, length, info = run_episode(tracked, lambda e: policy(tracked.observation, e), seed,
                                          frames if index == 0 else None)
        returns.append(total)
        lengths.append(length)
        successes.append(bool(info.get("is_success", False)))
    return dict(mean_return=float(np.mean(returns)), std_return=float(np.std(returns)),
                success_rate=float(np.mean(successes)), mean_episode_length=float(np.mean(lengths)),
                episodes=len(seeds))


class _ObservationTracker:
    """Forwards reset/step/render to ``env`` and remembers the latest observation."""

    def __init__(self, env):
        self.env, self.observation = env, None
        self.unwrapped, self.action_space = env.unwrapped, env.action_space

    def reset(self, **kwargs):
        self.observation, info = self.env.reset(**kwargs)
        return self.observation, info

    def step(self, action):
        result = self.env.step(action)
        self.observation = result[0]
        return result

    def render(self):
        return self.env.render()


def agent_policy(run_dir: Path, config: dict):
    """The trained agent of ``run_dir`` (its final model, else its newest checkpoint that loads,
    with that checkpoint's normaliser) as a policy ``(observation, env) -> action`` (deterministic)."""
    algo_cls = algorithm_class(config["algo"])
    model_path = run_dir / "model.zip"
    normaliser = None
    if model_path.is_file():
        model = load_model(algo_cls, str(model_path), device="cpu")
        stats = run_dir / "vecnormalize.pkl"
        if stats.is_file():
            import pickle

            with open(stats, "rb") as handle:
                normaliser = pickle.load(handle)  # VecNormalize without its venv: normalize_obs works alone
    else:
        from .checkpoints import checkpoint_loader, pick_checkpoint

        normalize = bool(config.get("hyperparams", {}).get("normalize", False))
        load = checkpoint_loader(run_dir / "checkpoints", algo_cls, normalize, off_policy=False,
                                 n_envs=int(config.get("n_envs", 1)), device="cpu")
        step, loaded, _ = pick_checkpoint(run_dir / "checkpoints", load, log=lambda line: print(line, file=sys.stderr))
        if step is None:
            raise UsageError(f"{run_dir} holds no model.zip and no checkpoint that loads")
        model, normaliser = loaded

    def policy(observation, env):
        if normaliser is not None:
            observation = normaliser.normalize_obs(observation)
        action, _ = model.predict(observation, deterministic=True)
        return action

    return policy


def _save_animation(frames, path: Path):
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames if frame is not None]
    if not images:
        raise UsageError("the environment returned no frames to render")
    if path.suffix.lower() != ".gif":
        raise UsageError(f"--render supports .gif, got {path.suffix}")
    images[0].save(path, save_all=True, append_images=images[1:], duration=100, loop=0)


def evaluate(run_dir: Path, episodes: int, seed: int, render: str | None = None) -> dict:
    import gymnasium as gym
    import torch

    torch.set_num_threads(1)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise UsageError(f"{run_dir} is not a run folder (no config.json)")
    config = json.loads(config_path.read_text())
    check_env_id(config["env"])
    seeds = seed + np.arange(episodes)
    kwargs = dict(config.get("env_kwargs", {}))
    env = gym.make(config["env"], render_mode="rgb_array" if render else None, **kwargs)
    frames = [] if render else None
    result = dict(env=config["env"], algo=config["algo"], run_dir=str(run_dir), episodes=episodes, seed=seed)
    result["agent"] = _episodes(env, agent_policy(run_dir, config), seeds, frames)
    rng = np.random.default_rng(seed)
    space = env.action_space
    result["random"] = _episodes(
        env, lambda observation, e: rng.uniform(space.low, space.high).astype(space.dtype), seeds)
    scripted = getattr(env.unwrapped, "scripted_action", None)
    result["scripted"] = _episodes(env, lambda observation, e: e.unwrapped.scripted_action(), seeds) if scripted else None
    env.close()
    if render:
        _save_animation(frames, Path(render))
        result["render"] = render
    return result


def main(argv=None) -> int:
    parser = CommandParser(PROGRAM, description="Evaluate a training run (JSON on stdout).")
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1000, help="first episode seed (episodes use seed, seed+1, ...)")
    parser.add_argument("--render", default=None, metavar="FILE.gif", help="animate the agent's first episode")
    args = parser.parse_args(argv)
    with usage_errors(PROGRAM):
        if args.episodes <= 0:
            raise UsageError(f"--episodes must be positive, got {args.episodes}")
        run_dir = Path(args.run_dir)
        if not run_dir.is_dir():
            raise UsageError(f"run folder {run_dir} does not exist")
        result = evaluate(run_dir, args.episodes, args.seed, args.render)
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
