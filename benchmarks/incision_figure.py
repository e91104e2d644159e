"""docs/figures/incision.png: Incision-v0's scripted incision, seen from above and by the env's camera.

Usage: python -m benchmarks.incision_figure [--seed 0] [--output docs/figures/incision.png]

Left: the top surface of the stretched slab after the scripted incision (each element's top face at
its deformed corners, so the two lips of the cut are drawn apart), the marked line, the blade tip and
the faces of the ideal incision the blade cut; the gap is shaded by its width. Right: the same state
as the agent's ``observation_type="rgb"`` sees it (64 x 64 pixels).
"""

import argparse

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the envs)


def run(seed):
    env = gym.make("tissue_env/Incision-v0", observation_type="rgb")
    observation, _ = env.reset(seed=seed)
    info = {}
    for _ in range(60):
        observation, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        if terminated or truncated:
            break
    for _ in range(10):  # the blade held still: the incision settles open under the tension
        observation, *_, info = env.step(np.zeros(3, np.float32))
    return env.unwrapped, observation, info


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default="docs/figures/incision.png")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    env, image, info = run(args.seed)
    worlds = env.worlds
    corners = worlds.corner_positions(worlds.positions)[0].reshape(-1, 8, 3)  # (M, 8, 3) m
    top = np.isclose(env.mesh.nodes[env.mesh.elements].mean(axis=1)[:, 1], env.size[1] - 0.5 * env.spacing[1])
    quads = corners[top][:, [3, 2, 6, 7]][..., [0, 2]] * 1e3  # each top element's top face, x-z in mm
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4.2), gridspec_kw=dict(width_ratios=[1.5, 1]))
    left.add_collection(PolyCollection(quads, facecolor="#e8b4a0", edgecolor="#8a4b3a", linewidths=0.5))
    start, end, z = env.line * 1e3
    left.plot([start, end], [z, z], "b--", lw=1.2, label="marked line")
    tip = (env.tip_rest + env.tool_offset) * 1e3
    left.plot(tip[0], tip[2], "k^", ms=8, label="blade tip")
    left.set_xlim(-2, env.size[0] * 1e3 + 2)
    left.set_ylim(-2, env.size[2] * 1.06e3 + 2)
    left.set_aspect("equal")
    left.set_xlabel("x (mm)")
    left.set_ylabel("z (mm)")
    left.legend(loc="lower right", fontsize=8)
    left.set_title(f"top surface after the cut: {info['cut_faces']} faces, progress {info['cut_progress']:.0%}, "
                   f"{1e3 * info['cut_length']:.1f} mm", fontsize=9)
    right.imshow(image)
    right.set_axis_off()
    right.set_title("the agent's rgb observation", fontsize=9)
    figure.tight_layout()
    figure.savefig(args.output, dpi=120)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
