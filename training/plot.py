"""Learning curves of training runs: mean and spread over seeds, wall-clock on a second axis.

    python -m training.plot RUN_DIR [RUN_DIR ...] --out docs/figures/learning_curve.png

Runs are grouped by (env, algo) from their config.json; each curve is the episode return from the
monitor CSVs, binned over environment steps.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from sim_core.files import finish_figure

from .common import CommandParser, UsageError, usage_errors

PROGRAM = "training.plot"


def read_monitor(run_dir: Path):
    """(env steps at episode end, returns, wall-clock seconds) from monitor/*.monitor.csv."""
    rows = []
    for path in sorted((run_dir / "monitor").glob("*.monitor.csv")):
        with open(path) as handle:
            handle.readline()  # JSON header line
            rows.extend((float(r["r"]), int(r["l"]), float(r["t"])) for r in csv.DictReader(handle))
    if not rows:
        raise UsageError(f"{run_dir} has no monitor data")
    rows.sort(key=lambda row: row[2])
    returns = np.array([r[0] for r in rows])
    steps = np.cumsum([r[1] for r in rows])
    seconds = np.array([r[2] for r in rows])
    return steps, returns, seconds


def plot(run_dirs, out: Path, bins: int = 30) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list] = {}
    for run_dir in run_dirs:
        run_dir = Path(run_dir)
        config_path = run_dir / "config.json"
        if not config_path.is_file():
            raise UsageError(f"{run_dir} is not a run folder (no config.json)")
        config = json.loads(config_path.read_text())
        groups.setdefault(f"{config['env']} {config['algo']}", []).append(read_monitor(run_dir))
    figure, axis = plt.subplots(figsize=(7, 4))
    wall = axis.twiny()
    for label, runs in groups.items():
        horizon = min(steps[-1] for steps, _, _ in runs)
        edges = np.linspace(0, horizon, bins + 1)
        centres = 0.5 * (edges[1:] + edges[:-1])
        curves = []
        for steps, returns, _ in runs:
            index = np.clip(np.searchsorted(edges, steps, side="right") - 1, 0, bins - 1)
            sums = np.bincount(index, returns, bins)
            counts = np.bincount(index, minlength=bins)
            curve = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
            # carry values over empty bins (forward, then backward for the first episodes)
            valid = np.flatnonzero(~np.isnan(curve))
            curve = curve[valid[np.clip(np.searchsorted(valid, np.arange(bins), side="right") - 1, 0, None)]]
            curves.append(curve)
        curves = np.array(curves)
        mean, low, high = np.nanmean(curves, 0), np.nanmin(curves, 0), np.nanmax(curves, 0)
        line, = axis.plot(centres, mean, label=f"{label} ({len(runs)} seeds)")
        axis.fill_between(centres, low, high, color=line.get_color(), alpha=0.2)
        seconds = np.mean([np.interp(horizon, s, t) for s, _, t in runs])
        wall.set_xlim(0, seconds)
    axis.set(xlabel="environment steps", ylabel="episode return (mean, min-max over seeds)")
    wall.set_xlabel("wall-clock (s), mean over seeds")
    axis.legend(fontsize=8)
    finish_figure(figure, out, dpi=110)
    return out


def main(argv=None) -> int:
    parser = CommandParser(PROGRAM, description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    with usage_errors(PROGRAM):
        path = plot(args.runs, Path(args.out))
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
