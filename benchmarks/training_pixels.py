"""PPO from pixels alone (the camera's 64 x 64 RGB image, SB3's CnnPolicy) against random actions.

Usage: python -m benchmarks.training_pixels [--env tissue_env/Retraction-v0] [--seeds 0]
       [--timesteps N] [--episodes 20] [--output benchmarks/results/training_pixels.json]

Each seed trains with ``training.train`` (hyperparameters: training/hyperparams/ppo_pixels.yml,
env keywords ``observation_type="rgb", image_size=64``, the batched vector env on one thread) into
runs/pixels/<env>/ppo/seed<S>/ (a finished run is reused, an interrupted one resumed), then
``training.evaluate`` runs the agent, uniform random actions and the scripted controller on the
same episode seeds (1000, 1001, ...). The entry records both commands, so a run can also be
repeated by hand. Results are written to ``--output`` (JSON, replaced atomically), one entry per
(env, algo, observation), with the train wall-clock time of each seed.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from training.common import load_hyperparams, run_name, write_json
from training.evaluate import evaluate
from training.train import train

ROOT = Path(__file__).resolve().parents[1]

CONFIG = ROOT / "training" / "hyperparams" / "ppo_pixels.yml"
ENV_KWARGS = dict(observation_type="rgb", image_size=64)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="tissue_env/Retraction-v0")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--timesteps", type=int, default=None, help="default: the config's n_timesteps")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--runs-dir", default=str(ROOT / "runs" / "pixels"))
    parser.add_argument("--output", default=str(ROOT / "benchmarks" / "results" / "training_pixels.json"))
    args = parser.parse_args(argv)
    hyperparams = load_hyperparams("ppo", args.env, str(CONFIG))
    n_envs = int(hyperparams.pop("n_envs", 1))
    budget = int(hyperparams.pop("n_timesteps"))
    timesteps = args.timesteps or budget
    relative_config = CONFIG.relative_to(ROOT)
    train_command = (f"python -m training.train --env {args.env} --algo ppo --config {relative_config} "
                     f"--env-kwargs '{json.dumps(ENV_KWARGS)}' --vec-env batched --env-threads 1 "
                     f"--eval-freq {max(timesteps // 10, 1)} --eval-episodes 5 --checkpoint-freq {max(timesteps // 5, 1)}"
                     + ("" if timesteps == budget else f" --timesteps {timesteps}") + " --seed <S>")
    evaluations, walls, dirs = [], [], []
    for seed in args.seeds:
        run_dir = Path(args.runs_dir) / run_name(args.env) / "ppo" / f"seed{seed}"
        if not ((run_dir / "result.json").is_file() and (run_dir / "model.zip").is_file()):
            config = dict(env=args.env, algo="ppo", timesteps=timesteps, seed=seed, n_envs=n_envs, vec_env="batched",
                          threads=1, env_kwargs=dict(ENV_KWARGS), hyperparams=dict(hyperparams),
                          eval_freq=max(timesteps // 10, 1), eval_episodes=5, checkpoint_freq=max(timesteps // 5, 1),
                          env_threads=1)
            resume = (run_dir / "config.json").is_file()
            print(f"{'resuming' if resume else 'training'} {args.env} ppo pixels seed {seed} ({timesteps} steps)",
                  flush=True)
            train(config, run_dir, resume=resume, progress=False)
        start = time.perf_counter()
        evaluations.append(evaluate(run_dir, args.episodes, seed=1000))
        walls.append(json.loads((run_dir / "result.json").read_text())["wall_clock_s"])
        dirs.append(str(run_dir.relative_to(ROOT)) if run_dir.is_relative_to(ROOT) else str(run_dir))
        agent, random = evaluations[-1]["agent"], evaluations[-1]["random"]
        print(f"  seed {seed}: agent success {agent['success_rate']:.0%} return {agent['mean_return']:.2f}; random "
              f"{random['success_rate']:.0%} {random['mean_return']:.2f} (evaluated in {time.perf_counter() - start:.0f} s)",
              flush=True)
    out = Path(args.output)
    summary = json.loads(out.read_text()) if out.is_file() else {}
    command = f"python -m benchmarks.training_pixels --env {args.env} --seeds {' '.join(map(str, args.seeds))}" + (
        "" if timesteps == budget else f" --timesteps {timesteps}") + (
        "" if args.episodes == 20 else f" --episodes {args.episodes}")
    summary[f"{args.env} ppo rgb"] = dict(
        env=args.env, algo="ppo", policy=hyperparams.get("policy"), env_kwargs=ENV_KWARGS, vec_env="batched",
        seeds=args.seeds, timesteps=timesteps, episodes=args.episodes, train_wall_clock_s=walls,
        agent_success=[e["agent"]["success_rate"] for e in evaluations],
        agent_return=[e["agent"]["mean_return"] for e in evaluations],
        agent_episode_length=[e["agent"]["mean_episode_length"] for e in evaluations],
        random=evaluations[0]["random"], scripted=evaluations[0]["scripted"],
        beats_random=[e["agent"]["mean_return"] > e["random"]["mean_return"]
                      and e["agent"]["success_rate"] > e["random"]["success_rate"] for e in evaluations],
        command=command, train_command=train_command,
        evaluate_command=f"python -m training.evaluate <RUN_DIR> --episodes {args.episodes} --seed 1000",
        run_dirs=dirs)
    write_json(out, summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
