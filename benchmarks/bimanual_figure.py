"""BimanualExposure-v0's figure: the scripted controller's episode (frames at its start, middle and
end) and, per step, the exposed fraction of the target and each grasper's force (N).

Usage: python -m benchmarks.bimanual_figure [--seed 0] [--output docs/figures/bimanual_exposure.png]
"""

import argparse

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import tissue_env  # noqa: E402,F401  (registers the tasks)
from sim_core.files import finish_figure  # noqa: E402

ENV_ID = "tissue_env/BimanualExposure-v0"


def episode(seed=0):
    """(frames [(step, frame)], exposed (S,), tool force magnitudes (S, 2) N, last info) of the
    scripted controller's episode."""
    env = gym.make(ENV_ID, render_mode="rgb_array")
    _, info = env.reset(seed=seed)
    frames, exposed, forces = [(0, env.render())], [info["exposed_fraction"]], [np.linalg.norm(info["tool_forces"], axis=1)]
    done, step = False, 0
    while not done:
        _, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        step += 1
        frames.append((step, env.render()))
        exposed.append(info["exposed_fraction"])
        forces.append(np.linalg.norm(info["tool_forces"], axis=1))
        done = terminated or truncated
    env.close()
    return frames, np.array(exposed), np.array(forces), info


def figure(frames, exposed, forces, info, path):
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.2), gridspec_kw=dict(width_ratios=[1, 1, 1, 1.3]))
    for ax, (step, frame) in zip(axes, (frames[0], frames[len(frames) // 2], frames[-1])):
        ax.imshow(frame)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"step {step}" + (" (success)" if step == frames[-1][0] and info["is_success"] else ""),
                     fontsize=9)
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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default="docs/figures/bimanual_exposure.png")
    args = parser.parse_args(argv)
    frames, exposed, forces, info = episode(args.seed)
    figure(frames, exposed, forces, info, args.output)
    print(f"{len(frames) - 1} steps, success {bool(info['is_success'])}, largest tool force {forces.max():.3f} N")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
