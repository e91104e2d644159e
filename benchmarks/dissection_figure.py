"""docs/figures/dissection.png: Dissection-v0's scripted dissection, seen from the side and by the env's camera.

Usage: python -m benchmarks.dissection_figure [--seed 0] [--steps 17] [--output docs/figures/dissection.png]

Left: a cross-section of the slab (the elements of its middle row in z, at their deformed corners:
bed, connective layer and flap in their own colours) after ``--steps`` steps of the scripted
dissection, the grasper peeling the freed flap up from the free edge while the blade (its edge along
z, drawn as a point) cuts the connective layer: the cut is open behind the blade. Right: the same
state as the agent's ``observation_type="rgb"`` sees it (64 x 64 pixels). Also prints how often the
scripted controller frees the flap on the default slab (10 seeds) and its episode length.
"""

import argparse

import gymnasium as gym
import numpy as np

from benchmarks.cut_figure import element_corners, save, scripted_state
from tissue_env.dissection import BED, CONNECTIVE, FLAP

COLOURS = {BED: "#c98f80", CONNECTIVE: "#f2e3a0", FLAP: "#e8b4a0"}


def success_rate(seeds=10):
    """(freed flaps, mean episode length) of the scripted controller on the default slab."""
    from tissue_env.episodes import run_episode, scripted_policy

    env = gym.make("tissue_env/Dissection-v0")
    results = [run_episode(env, scripted_policy, seed) for seed in range(seeds)]
    return sum(bool(info["is_success"]) for *_, info in results), np.mean([length for _, length, _ in results])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=17)
    parser.add_argument("--output", default="docs/figures/dissection.png")
    args = parser.parse_args(argv)
    from matplotlib.collections import PolyCollection

    env, image, info = scripted_state("tissue_env/Dissection-v0", args.seed, args.steps)
    corners = element_corners(env)
    centres = env.mesh.nodes[env.mesh.elements].mean(axis=1)
    row = np.isclose(centres[:, 2], 0.5 * env.size[2] - 0.5 * env.spacing[2])  # the row just short of the middle
    faces = corners[row][:, [4, 5, 6, 7]][..., :2] * 1e3  # each element's face z = its far side, x-y in mm

    def draw(left):
        left.add_collection(PolyCollection(faces, facecolor=[COLOURS[label] for label in env.labels[row]],
                                           edgecolor="#6a3b2a", linewidths=0.5))
        blade = (env.tip_rest + env.tool_offset) * 1e3
        left.plot(blade[0], blade[1], "k>", ms=8, label="blade (edge along z)")
        jaw = (env.mesh.nodes[env.tool_nodes].mean(axis=0) + env.jaw_offset) * 1e3
        left.plot(jaw[0], jaw[1], "bs", ms=7, label="grasper (scripted peel)")
        for label, name in ((FLAP, "flap"), (CONNECTIVE, "connective layer"), (BED, "bed")):
            left.fill([], [], color=COLOURS[label], label=name)
        left.legend(loc="upper left", fontsize=7, ncol=2)
        left.set_title(f"after {info['cut_faces']} faces cut: progress {info['cut_progress']:.0%}, "
                       f"flap/bed faces cut {info['flap_damage']}/{info['bed_damage']}", fontsize=9)

    save(draw, image, args.output, 4.0, xlim=(-3, env.size[0] * 1e3 + 8), ylim=(-2, env.size[1] * 1e3 + 22),
         xlabel="x (mm)", ylabel="y (mm)")
    freed, length = success_rate()
    print(f"scripted dissection, default slab: the flap freed on {freed}/10 seeds, {length:.1f} steps per episode")


if __name__ == "__main__":
    main()
