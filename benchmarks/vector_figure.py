"""A figure of the vector envs' and the training's throughput, from the benchmarks' JSON results.

Usage: python -m benchmarks.vector_figure [--results benchmarks/results] [--output docs/figures/vector_env_speed.png]

Left: env steps per wall second at N = 16 of ``vectorization_mode="sync"``, ``"async"`` and the
batched vector env on one thread and on every core (``vector_env_speed.json``, the async rates from
``vector_env_speed_async.json``, each from its own run). Right: PPO's env steps per wall second,
sampling and updates, with SubprocVecEnv and with the batched vector env (``--vec-env batched``),
for 4 and 16 envs (``training_speed.json``). Nothing is measured here: re-run
``benchmarks/vector_env_speed.py`` (``--async``) and ``benchmarks/training_speed.py`` first
(``make bench`` does).
"""

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sim_core.files import finish_figure  # noqa: E402

ENV_MODES = (("sync", "sync"), ("async", "async"), ("vector 1 thread", "vector, 1 thread"),
             ("vector", "vector, all threads"))


def short(env_id):
    return env_id.split("/")[-1].replace("-v0", "")


def env_rates(results: Path, num_envs=16):
    """{task: {mode label: env steps per wall second}} at ``num_envs`` copies."""
    rates = {}
    for name in ("vector_env_speed.json", "vector_env_speed_async.json"):
        path = results / name
        if not path.is_file():
            continue
        for row in json.loads(path.read_text())["results"]:
            if row["num_envs"] != num_envs or row.get("episodes", "registered") != "registered":
                continue
            modes = rates.setdefault(short(row["env_id"]), {})
            for mode, summary in row["modes"].items():
                if name.endswith("async.json") and mode != "async":
                    continue  # the main run's rates for the other modes
                modes[mode] = summary["wall_steps_per_s"]
    return rates


def training_rates(results: Path):
    """{(task, n_envs): {mode: env steps per wall second}}."""
    path = results / "training_speed.json"
    if not path.is_file():
        return {}
    rows = json.loads(path.read_text())["results"]
    return {(short(row["env_id"]), row["n_envs"]): row["steps_per_s"] for row in rows}


def draw(results: Path, output: Path):
    envs, training = env_rates(results), training_rates(results)
    if not envs:
        raise SystemExit(f"no vector_env_speed results at N = 16 in {results}: run python -m benchmarks.vector_env_speed")
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    tasks = sorted(envs)
    width = 0.8 / len(ENV_MODES)
    for k, (mode, label) in enumerate(ENV_MODES):
        values = [envs[task].get(mode, np.nan) for task in tasks]
        bars = left.bar(np.arange(len(tasks)) + (k - 1.5) * width, values, width, label=label)
        left.bar_label(bars, fmt="%.0f", fontsize=7)
    left.set_xticks(np.arange(len(tasks)), tasks)
    left.set_ylabel("env steps per wall second")
    left.set_title("16 copies of a task (2-core VM)")
    left.legend(fontsize=8)
    if training:
        keys = sorted(training)
        modes = sorted({mode for rates in training.values() for mode in rates}, key=["subproc", "batched"].index)
        width = 0.8 / len(modes)
        for k, mode in enumerate(modes):
            bars = right.bar(np.arange(len(keys)) + (k - (len(modes) - 1) / 2) * width,
                             [training[key].get(mode, np.nan) for key in keys], width,
                             label={"subproc": "SubprocVecEnv", "batched": "--vec-env batched"}.get(mode, mode))
            right.bar_label(bars, fmt="%.0f", fontsize=7)
        right.set_xticks(np.arange(len(keys)), [f"{task.replace('Positioning', 'Pos.')}\n{n} envs" for task, n in keys],
                         fontsize=8)
        right.set_ylabel("PPO env steps per wall second")
        right.set_title("PPO training (sampling and updates)")
        right.legend(fontsize=8)
    finish_figure(fig, output, dpi=90)
    return output


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", default=str(Path(__file__).resolve().parent / "results"))
    parser.add_argument("--output", default="docs/figures/vector_env_speed.png")
    args = parser.parse_args(argv)
    print(f"wrote {draw(Path(args.results), Path(args.output))}")


if __name__ == "__main__":
    main()
