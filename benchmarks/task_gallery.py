"""A picture of every task: frames of the scripted controller's episode (start, middle, end).

Usage: python -m benchmarks.task_gallery [--seed 0] [--output docs/figures/tasks.png]

Each row is one task at its defaults (``render_mode="rgb_array"``: the deformed block coloured by
displacement, with the tool, target and goal marked), stepped by the task's ``scripted_action``
until the episode ends; the columns are the first frame, the middle one and the last, titled with
the step, whether the episode succeeded and the tool's reaction force (N).
"""

import argparse

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import tissue_env  # noqa: E402,F401  (registers the tasks)
from sim_core.files import finish_figure  # noqa: E402

TASKS = ("TumorPositioning", "Palpation", "Retraction", "LiverNeedleAlignment")


def episode_frames(task, seed=0):
    """[(step, frame (H, W, 3) uint8, info)] of the scripted controller's episode on ``task``."""
    env = gym.make(f"tissue_env/{task}-v0", render_mode="rgb_array")
    _, info = env.reset(seed=seed)
    frames = [(0, env.render(), info)]
    step, done = 0, False
    while not done:
        _, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        step += 1
        frames.append((step, env.render(), info))
        done = terminated or truncated
    env.close()
    return frames


def draw_frames(axes, frames, success_label="success"):
    """Draw the first, the middle and the last of ``frames`` (``episode_frames``) on three ``axes``,
    each titled with its step (and ``success_label`` where the episode succeeded)."""
    for ax, (step, frame, info) in zip(axes, (frames[0], frames[len(frames) // 2], frames[-1])):
        ax.imshow(frame)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"step {step} {success_label if info.get('is_success') else ''}".rstrip(), fontsize=9)


def figure(rows, path):
    fig, axes = plt.subplots(len(rows), 3, figsize=(9, 3.1 * len(rows)))
    for row, (task, frames) in zip(np.atleast_2d(axes), rows):
        draw_frames(row, frames)
        row[0].set_ylabel(task, fontsize=11)
    fig.suptitle("Scripted controller, one episode per task (start, middle, end)", fontsize=11)
    finish_figure(fig, path, dpi=90)


def figure_arguments(doc, output, argv=None):
    """The ``--seed`` (default 0) and ``--output`` (default ``output``) of a figure script whose
    docstring is ``doc``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default=output)
    return parser.parse_args(argv)


def main(argv=None):
    args = figure_arguments(__doc__, "docs/figures/tasks.png", argv)
    rows = [(task, episode_frames(task, args.seed)) for task in TASKS]
    figure(rows, args.output)
    for task, frames in rows:
        print(f"{task}: {len(frames) - 1} steps, success {bool(frames[-1][2].get('is_success'))}")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
