"""BimanualExposure-v0's figure: the scripted controller's episode (frames at its start, middle and
end) and, per step, the exposed fraction of the target and each grasper's force (N).

Usage: python -m benchmarks.bimanual_figure [--seed 0] [--output docs/figures/bimanual_exposure.png]
"""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.task_gallery import draw_frames, episode_frames, figure_arguments  # noqa: E402
from sim_core.files import finish_figure  # noqa: E402

TASK = "BimanualExposure"


def episode(seed=0):
    """(frames [(step, frame, info)] (``task_gallery.episode_frames``), exposed (S,), tool force
    magnitudes (S, 2) N, last info) of the scripted controller's episode."""
    frames = episode_frames(TASK, seed)
    exposed = np.array([info["exposed_fraction"] for *_, info in frames])
    forces = np.array([np.linalg.norm(info["tool_forces"], axis=1) for *_, info in frames])
    return frames, exposed, forces, frames[-1][2]


def figure(frames, exposed, forces, info, path):
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.2), gridspec_kw=dict(width_ratios=[1, 1, 1, 1.3]))
    draw_frames(axes[:3], frames, "(success)")
    ax = axes[3]
    steps = np.arange(len(exposed))
    ax.plot(steps, exposed, "k-o", ms=3, label="exposed fraction")
    ax.set_xlabel("env step")
    ax.set_ylabel("exposed fraction of the target")
    ax.set_ylim(0, 1.05)
    right = ax.twinx()
    right.plot(steps, forces[:, 0], "C0--", label="left grasper |F| (N)")
    right.plot(steps, forces[:, 1], "C1:", label="right grasper |F| (N)")
    right.set_ylabel("tool force (N)")
    lines = ax.get_legend_handles_labels()
    more = right.get_legend_handles_labels()
    ax.legend(lines[0] + more[0], lines[1] + more[1], fontsize=7, loc="center right")
    fig.suptitle("BimanualExposure-v0: two graspers fold back the flaps of a cleft (scripted controller)", fontsize=10)
    finish_figure(fig, path, dpi=90)


def main(argv=None):
    args = figure_arguments(__doc__, "docs/figures/bimanual_exposure.png", argv)
    frames, exposed, forces, info = episode(args.seed)
    figure(frames, exposed, forces, info, args.output)
    print(f"{len(frames) - 1} steps, success {bool(info['is_success'])}, largest tool force {forces.max():.3f} N")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
