"""Learning curves of training runs: mean and spread over seeds, wall-clock on a second axis.

    python -m training.plot RUN_DIR [RUN_DIR ...] --out docs/figures/learning_curve.png

Runs are grouped by (env, algo) from their config.json; each curve is the episode return from the
monitor CSVs, binned over environment steps. A run without a finished episode (killed in its first
seconds) is skipped with a line on stderr.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

from sim_core.files import finish_figure

from .common import CommandParser, UsageError, usage_errors

PROGRAM = "training.plot"


def read_monitor(run_dir: Path):
    """(env steps at episode end, returns, wall-clock seconds) from monitor/*.monitor.csv, or None
    when the run has no finished episode yet.

    The episodes are ordered by their end in environment steps (the cumulative episode length in
    their file: a file per env, whose envs step in lockstep), not by the time column, which starts
    again at each resumed session; a file's times are made cumulative over its sessions. A row cut
    short (a run killed while writing it) is left out."""
    rows = []
    for index, path in enumerate(sorted((run_dir / "monitor").glob("*.monitor.csv"))):
        with open(path) as handle:
            handle.readline()  # JSON header line
            end, offset, previous = 0, 0.0, 0.0
            for row in csv.DictReader(handle):
                try:
                    reward, length, seconds = float(row["r"]), int(row["l"]), float(row["t"])
                except (KeyError, TypeError, ValueError):
                    continue
                if seconds < previous:  # a resumed session: its clock starts again
                    offset += previous
                previous = seconds
                end += length
                rows.append((end, index, reward, length, offset + seconds))
    if not rows:
        return None
    rows.sort(key=lambda row: row[:2])
    returns = np.array([r[2] for r in rows])
    steps = np.cumsum([r[3] for r in rows])
    seconds = np.maximum.accumulate([r[4] for r in rows])
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
        curve = read_monitor(run_dir)
        if curve is None:  # killed before its first episode, or not started: nothing to draw
            print(f"skipping {run_dir}: no finished episode in its monitor logs", file=sys.stderr, flush=True)
            continue
        groups.setdefault(f"{config['env']} {config['algo']}", []).append(curve)
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
    if not groups:
        axis.text(0.5, 0.5, "no finished episodes yet", ha="center", va="center", transform=axis.transAxes)
    axis.set(xlabel="environment steps", ylabel="episode return (mean, min-max over seeds)")
    wall.set_xlabel("wall-clock (s), mean over seeds")
    if groups:
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
