"""How much of Palpation's map reading is the mesh: press readings by probe position.

Usage: python -m benchmarks.palpation_map [--output benchmarks/results/palpation_map.json]

At the default scene, the probe is placed above a point and pressed straight down at full speed
(action (0, -1, 0), two steps: 6 mm under the undeformed surface) from the episode's start height,
then held still two steps. Two readings of the apparent modulus (``info["apparent_modulus"]``, Pa,
what the palpation map records): the first step at least ``map_depth`` (4 mm) deep, and the press
held two steps (what the map holds once a press is held). For each probe sampling
(``probe_sampling`` "projected", the default, and "node", earlier versions'):

1. a homogeneous slab (``inclusion_ratio=1``) on a 4 x 4 grid over one node period (6 mm at the
   default (10, 5, 10)) around the slab's centre: how the reading varies with where the nodes fall
   under the probe;
2. the same slab at the 9 candidate cell centres;
3. the inclusion at each cell in turn (the default 10x stiffer box): the reading of the
   inclusion's cell over the stiffest other cell. Below 1, the map points to a wrong cell.

and, with the default sampling, how the reading depends on the depth: the homogeneous slab pressed
4 and 8 mm deep (moved there, then held two steps) over three cell centres (``depth``: apparent
modulus and indentation stiffness F / d).

Results are written to ``--output`` (JSON, replaced atomically) and drawn in ``--figure``
(docs/figures/palpation_map.png); ``--plot-only`` redraws the figure from the JSON.
"""

import argparse
import json
import os

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)
from training.common import write_json

ENV_ID = "tissue_env/Palpation-v0"
SAMPLINGS = ("projected", "node")
STAGES = ("first_step", "held")


def move_over(env, x, z):
    """Step the probe over (x, z) m above the surface (it touches nothing: the start equilibrium stays)."""
    for _ in range(50):
        move = (np.array([x, 0.0, z]) - env._tip() * [1, 0, 1]) / env.max_step
        if np.abs(move).max() < 1e-9:
            return
        env.step(np.clip(move, -1, 1).astype(np.float32))
    raise RuntimeError(f"the probe did not reach ({x}, {z}) m")


def press(env, x, z, seed=0):
    """(first step >= map_depth deep, held two steps) apparent moduli (Pa) of a straight-down
    press at (x, z) m at full speed to 6 mm, from a reset with ``seed``."""
    env.reset(seed=seed)
    move_over(env, x, z)
    first = None
    for action in ([0, -1, 0], [0, -1, 0], [0, 0, 0], [0, 0, 0]):
        env.step(np.array(action, np.float32))
        measures = env.measures
        if first is None and measures["depth"] >= env.map_depth - 1e-9:
            first = measures["apparent_modulus"]
    return float(first), float(measures["apparent_modulus"])


def seed_with_inclusion_at(env, cell, limit=1000):
    for seed in range(limit):
        env.reset(seed=seed)
        if env.inclusion_index == cell:
            return seed
    raise RuntimeError(f"no seed below {limit} puts the inclusion in cell {cell}")


def measure(sampling):
    homogeneous = gym.make(ENV_ID, inclusion_ratio=1.0, probe_sampling=sampling, max_episode_steps=400).unwrapped
    homogeneous.reset(seed=0)
    centres = homogeneous.cell_centres
    spacing = float(homogeneous.mesh.spacing[0])
    middle = centres.mean(axis=0)
    offsets = np.linspace(0.0, spacing, 4, endpoint=False)
    grid = np.array([[press(homogeneous, middle[0] + dx, middle[1] + dz) for dz in offsets] for dx in offsets])
    cells = np.array([press(homogeneous, x, z) for x, z in centres])
    env = gym.make(ENV_ID, probe_sampling=sampling, max_episode_steps=400).unwrapped
    env.terminate_on_success = False
    contrast = []
    for cell in range(len(centres)):
        seed = seed_with_inclusion_at(env, cell)
        readings = np.array([press(env, x, z, seed) for x, z in centres])
        contrast.append(readings[cell] / np.delete(readings, cell, axis=0).max(axis=0))
    contrast = np.array(contrast)
    result = dict(shape=[int(n) for n in homogeneous.shape], node_spacing_m=spacing, grid_offsets_m=offsets.tolist(),
                  cell_centres_m=centres.tolist())
    for index, stage in enumerate(STAGES):
        result[stage] = dict(
            homogeneous_grid_pa=grid[..., index].tolist(),
            homogeneous_grid_max_over_min=float(grid[..., index].max() / grid[..., index].min()),
            homogeneous_cells_pa=cells[:, index].tolist(),
            homogeneous_cells_max_over_min=float(cells[:, index].max() / cells[:, index].min()),
            inclusion_over_stiffest_other=contrast[:, index].tolist(),
        )
    return result


def depth_readings(depths=(0.004, 0.008), cells=(0, 4, 8)):
    """{depth (mm): (apparent moduli (Pa), F / d (N/m))} of held presses on the homogeneous slab
    over the cell centres ``cells``: the probe moved to ``depth`` under the undeformed surface
    (full speed, 8 steps), then held two steps."""
    env = gym.make(ENV_ID, inclusion_ratio=1.0, max_episode_steps=400).unwrapped
    readings = {}
    for depth in depths:
        moduli, stiffnesses = [], []
        for x, z in env.cell_centres[list(cells)]:
            env.reset(seed=0)
            move_over(env, x, z)
            goal = np.array([x, env.top_y - depth, z])
            for _ in range(8):
                env.step(np.clip((goal - env._tip()) / env.max_step, -1, 1).astype(np.float32))
            for _ in range(2):
                env.step(np.zeros(3, np.float32))
            moduli.append(float(env.measures["apparent_modulus"]))
            stiffnesses.append(float(env.measures["indentation_stiffness"]))
        readings[f"{1e3 * depth:g}"] = dict(apparent_modulus_pa=moduli, force_over_depth_n_per_m=stiffnesses)
    return readings


def plot(results, path):
    """Held readings on the homogeneous slab over one node period (both samplings, one colour
    scale) and the inclusion's cell over the stiffest other cell in each placement."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(12, 3.6), gridspec_kw=dict(width_ratios=[1, 1, 1.4]))
    grids = {sampling: np.array(results[sampling]["held"]["homogeneous_grid_pa"]) / 1e3 for sampling in SAMPLINGS}
    low, high = min(g.min() for g in grids.values()), max(g.max() for g in grids.values())
    offsets = np.array(results[SAMPLINGS[0]]["grid_offsets_m"]) * 1e3
    step = offsets[1] - offsets[0]
    extent = (offsets[0] - step / 2, offsets[-1] + step / 2, offsets[0] - step / 2, offsets[-1] + step / 2)
    for axis, sampling in zip(axes[:2], ("node", "projected")):
        grid = grids[sampling]
        image = axis.imshow(grid.T, origin="lower", extent=extent, vmin=low, vmax=high, cmap="viridis")
        axis.set_title(f"{sampling}: max/min {grid.max() / grid.min():.2f}")
        axis.set_xlabel("probe x from a node (mm)")
        axis.set_ylabel("probe z from a node (mm)")
    figure.colorbar(image, ax=axes[:2], label="held reading, apparent modulus (kPa)", shrink=0.85)
    placements = np.arange(len(results["node"]["held"]["inclusion_over_stiffest_other"]))
    for shift, sampling in ((-0.2, "node"), (0.2, "projected")):
        axes[2].bar(placements + shift, results[sampling]["held"]["inclusion_over_stiffest_other"], width=0.4,
                    label=sampling)
    axes[2].axhline(1.0, color="k", lw=1)
    axes[2].set_xlabel("inclusion placement (candidate cell)")
    axes[2].set_ylabel("inclusion cell / stiffest other")
    axes[2].set_title("held press over each cell centre")
    axes[2].set_ylim(0.0, 2.2)
    axes[2].legend(loc="upper center", ncol=2)
    shape = tuple(results["projected"]["shape"])
    figure.suptitle(f"Palpation {shape}: a 9 mm sphere pressed 6 mm, held two steps "
                    "(benchmarks/palpation_map.py)", fontsize=10)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "palpation_map.json"))
    parser.add_argument("--figure", default=os.path.join(os.path.dirname(__file__), "..", "docs", "figures",
                                                         "palpation_map.png"))
    parser.add_argument("--plot-only", action="store_true", help="redraw the figure from --output")
    args = parser.parse_args(argv)
    if args.plot_only:
        with open(args.output) as stream:
            plot(json.load(stream), args.figure)
        return 0
    results = {}
    for sampling in SAMPLINGS:
        results[sampling] = result = measure(sampling)
        for stage in STAGES:
            row = result[stage]
            contrast = np.array(row["inclusion_over_stiffest_other"])
            print(f"{sampling:9s} {stage:10s}: homogeneous max/min {row['homogeneous_grid_max_over_min']:.2f} over the "
                  f"node period, {row['homogeneous_cells_max_over_min']:.2f} over the cells "
                  f"({min(row['homogeneous_cells_pa']) / 1e3:.2f}-{max(row['homogeneous_cells_pa']) / 1e3:.2f} kPa); "
                  f"inclusion / stiffest other {contrast.min():.2f}-{contrast.max():.2f}, below 1 in "
                  f"{int((contrast < 1).sum())} of {len(contrast)}", flush=True)
    results["depth"] = depth_readings()
    for depth, row in results["depth"].items():
        moduli, stiffnesses = np.array(row["apparent_modulus_pa"]) / 1e3, row["force_over_depth_n_per_m"]
        print(f"held {depth} mm deep over cells 0, 4, 8: apparent modulus {moduli.min():.2f}-{moduli.max():.2f} kPa, "
              f"F / d {min(stiffnesses):.0f}-{max(stiffnesses):.0f} N/m", flush=True)
    write_json(args.output, results)
    plot(results, args.figure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
