"""Train PPO and SAC with several seeds on every task and tabulate them against random and scripted.

    python -m training.benchmark [--envs ID ...] [--algos ppo sac] [--seeds 0 1 2] [--episodes 20]
        [--variant her|hard] [--output-dir DIR | --publish] [--out FILE.json]

``--variant`` trains a named setting (``VARIANTS``: its env keywords and hyperparameter file)
instead of the defaults, e.g. ``her``: SAC with a HerReplayBuffer on TumorPositioning's goal
observation; ``hard``: the task's ``difficulty="hard"``. Its runs, learning curves and summary
entries carry the variant's name.

Each (env, algo, seed) run goes to runs/benchmark/...; a finished run (result.json present) is not
trained again, an interrupted one resumes from its checkpoint, so the script can be stopped and
restarted without losing work. Writes training.json (atomically) and learning_<task>_<algo>.png
into runs/benchmark/ (or ``--output-dir``), and prints a markdown table for the README;
``--publish`` writes them into benchmarks/results/ and docs/figures/ instead, replacing the
committed results the README quotes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from .common import HYPERPARAMS, check_env_id, load_hyperparams, run_name, write_json
from .evaluate import evaluate
from .plot import plot
from .train import train

ROOT = Path(__file__).resolve().parents[1]
#: The tasks benchmarked by default. The training budget (env steps) per task and algorithm, chosen
#: from pilot runs, is the n_timesteps of the task's entry in hyperparams/<algo>.yml.
ENVS = ("tissue_env/TumorPositioning-v0", "tissue_env/Palpation-v0", "tissue_env/Retraction-v0",
        "tissue_env/LiverNeedleAlignment-v0")
#: where --publish writes the summary and the learning curves (committed)
PUBLISHED_RESULTS = ROOT / "benchmarks" / "results"
PUBLISHED_FIGURES = ROOT / "docs" / "figures"


#: Named training settings (``--variant``): the env keywords and the hyperparameter file per
#: algorithm ("{algo}" is replaced; None: hyperparams/<algo>.yml).
VARIANTS = {
    # hindsight experience replay on the goal observation (TumorPositioning, the goal-conditioned task)
    "her": dict(env_kwargs={"observation_type": "goal"}, config=str(HYPERPARAMS / "her" / "{algo}.yml")),
    # the task's hard setting (its DIFFICULTY table), the default hyperparameters and budget
    "hard": dict(env_kwargs={"difficulty": "hard"}, config=None),
}


def run_one(env_id: str, algo: str, seed: int, runs: Path, vec_env: str = "dummy", variant: str | None = None) -> Path:
    name = f"seed{seed}" + ("" if vec_env == "dummy" else f"-{vec_env}") + (f"-{variant}" if variant else "")
    run_dir = runs / run_name(env_id) / algo / name
    if (run_dir / "result.json").is_file() and (run_dir / "model.zip").is_file():
        return run_dir
    setting = VARIANTS[variant] if variant else dict(env_kwargs={}, config=None)
    config_file = setting["config"].format(algo=algo) if setting["config"] else None
    hyperparams = load_hyperparams(algo, env_id, config_file)
    n_envs = int(hyperparams.pop("n_envs", 1))
    timesteps = int(hyperparams.pop("n_timesteps", 20000))
    config = dict(env=env_id, algo=algo, timesteps=timesteps, seed=seed, n_envs=n_envs, vec_env=vec_env,
                  threads=1, env_kwargs=dict(setting["env_kwargs"]), hyperparams=hyperparams,
                  eval_freq=max(timesteps // 10, 1), eval_episodes=10, checkpoint_freq=max(timesteps // 5, 1))
    resume = (run_dir / "config.json").is_file()
    print(f"{'resuming' if resume else 'training'} {env_id} {algo} seed {seed} ({timesteps} steps)", flush=True)
    return train(config, run_dir, resume=resume, progress=False)


def outputs(args) -> tuple[Path, Path]:
    """The summary JSON and the folder of the learning curves: benchmarks/results/ and docs/figures/
    with --publish, else --output-dir (default runs/benchmark/); --out names the JSON."""
    suffix = "" if args.vec_env == "dummy" else f"_{args.vec_env}"
    if args.publish:
        results, figures = PUBLISHED_RESULTS, PUBLISHED_FIGURES
    else:
        results = figures = Path(args.output_dir or ROOT / "runs" / "benchmark")
    out = Path(args.out) if args.out else results / f"training{suffix}.json"
    return out, figures


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--algos", nargs="+", default=["ppo", "sac"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--vec-env", choices=("dummy", "batched"), default="dummy",
                        help="the training envs (batched: tissue_env.sb3.BatchedVecEnv; its runs, figures and "
                             "--out default carry the suffix _batched)")
    parser.add_argument("--variant", choices=sorted(VARIANTS), default=None,
                        help="a named setting instead of the defaults (VARIANTS: her, SAC + HerReplayBuffer on the "
                             "goal observation; hard, the task's difficulty='hard')")
    parser.add_argument("--runs-dir", default=str(ROOT / "runs" / "benchmark"))
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--output-dir", default=None,
                       help="folder of training[_batched].json and the learning curves (default runs/benchmark)")
    where.add_argument("--publish", action="store_true",
                       help="write them into benchmarks/results/ and docs/figures/ (the committed ones)")
    parser.add_argument("--out", default=None, help="the summary JSON (default <output folder>/training[_batched].json)")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    suffix = "" if args.vec_env == "dummy" else f"_{args.vec_env}"
    runs = Path(args.runs_dir)
    out, figures = outputs(args)
    summary = json.loads(out.read_text()) if out.is_file() else {}
    for env_id in args.envs:
        check_env_id(env_id)
        for algo in args.algos:
            dirs, evaluations, walls = [], [], []
            for seed in args.seeds:
                start = time.perf_counter()
                run_dir = run_one(env_id, algo, seed, runs, args.vec_env, args.variant)
                dirs.append(run_dir)
                evaluations.append(evaluate(run_dir, args.episodes, seed=1000))
                walls.append(json.loads((run_dir / "result.json").read_text())["wall_clock_s"])
                print(f"  seed {seed}: success {evaluations[-1]['agent']['success_rate']:.0%} "
                      f"({time.perf_counter() - start:.0f} s)", flush=True)
            task = env_id.split("/")[-1]
            variant = f"_{args.variant}" if args.variant else ""
            plot(dirs, figures / f"learning_{task}_{algo}{suffix}{variant}.png")
            key = f"{env_id} {algo}" + (f" {args.variant}" if args.variant else "")
            # read again: another benchmark process may have written its entries since the start
            summary = json.loads(out.read_text()) if out.is_file() else {}
            summary[key] = dict(
                env=env_id, algo=algo, seeds=args.seeds, timesteps=json.loads((dirs[0] / "config.json").read_text())["timesteps"],
                train_wall_clock_s=float(np.mean(walls)),
                agent_success=[e["agent"]["success_rate"] for e in evaluations],
                agent_return=[e["agent"]["mean_return"] for e in evaluations],
                random=evaluations[0]["random"], scripted=evaluations[0]["scripted"],
                vec_env=args.vec_env,
                variant=args.variant,
                env_kwargs=json.loads((dirs[0] / "config.json").read_text())["env_kwargs"],
                command=f"python -m training.benchmark --envs {env_id} --algos {algo} --seeds "
                        + " ".join(map(str, args.seeds)) + (f" --vec-env {args.vec_env}" if suffix else "")
                        + (f" --variant {args.variant}" if args.variant else "")
                        + (" --publish" if args.publish else ""),
            )
            write_json(out, summary)
    print("\n| task | algo | success (mean over seeds) | return | random success / return | scripted success / return | train wall-clock |")
    print("|---|---|---|---|---|---|---|")
    for entry in summary.values():
        print(f"| {entry['env'].split('/')[-1]} | {entry['algo'].upper()} | {np.mean(entry['agent_success']):.0%} "
              f"({', '.join(f'{s:.0%}' for s in entry['agent_success'])}) | {np.mean(entry['agent_return']):.2f} | "
              f"{entry['random']['success_rate']:.0%} / {entry['random']['mean_return']:.2f} | "
              f"{entry['scripted']['success_rate']:.0%} / {entry['scripted']['mean_return']:.2f} | "
              f"{entry['train_wall_clock_s']:.0f} s |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
