"""docs/figures/incision.png: Incision-v0's scripted incision, seen from above and by the env's camera.

Usage: python -m benchmarks.incision_figure [--seed 0] [--output docs/figures/incision.png]

Left: the top surface of the stretched slab after the scripted incision (each element's top face at
its deformed corners, so the two lips of the cut are drawn apart), the marked line, the blade tip and
the faces of the ideal incision the blade cut; the gap is shaded by its width. Right: the same state
as the agent's ``observation_type="rgb"`` sees it (64 x 64 pixels).
"""

import argparse

import numpy as np

from benchmarks.cut_figure import element_corners, save, scripted_state


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default="docs/figures/incision.png")
    args = parser.parse_args(argv)
    from matplotlib.collections import PolyCollection

    # the blade held still for 10 steps after the incision: it settles open under the tension
    env, image, info = scripted_state("tissue_env/Incision-v0", args.seed, 60, settle=10)
    corners = element_corners(env)
    top = np.isclose(env.mesh.nodes[env.mesh.elements].mean(axis=1)[:, 1], env.size[1] - 0.5 * env.spacing[1])
    quads = corners[top][:, [3, 2, 6, 7]][..., [0, 2]] * 1e3  # each top element's top face, x-z in mm

    def draw(left):
        left.add_collection(PolyCollection(quads, facecolor="#e8b4a0", edgecolor="#8a4b3a", linewidths=0.5))
        start, end, z = env.line * 1e3
        left.plot([start, end], [z, z], "b--", lw=1.2, label="marked line")
        tip = (env.tip_rest + env.tool_offset) * 1e3
        left.plot(tip[0], tip[2], "k^", ms=8, label="blade tip")
        left.legend(loc="lower right", fontsize=8)
        left.set_title(f"top surface after the cut: {info['cut_faces']} faces, progress {info['cut_progress']:.0%}, "
                       f"{1e3 * info['cut_length']:.1f} mm", fontsize=9)

    save(draw, image, args.output, 4.2, xlim=(-2, env.size[0] * 1e3 + 2), ylim=(-2, env.size[2] * 1.06e3 + 2),
         xlabel="x (mm)", ylabel="z (mm)")


if __name__ == "__main__":
    main()
