"""How much of Palpation's map reading is the mesh: first-press stiffness by probe position.

Usage: python benchmarks/palpation_map.py [--output benchmarks/results/palpation_map.json]

At the default scene, the probe is placed above a point and pressed straight down at full speed
(action (0, -1, 0) per step) from the episode's start height; the reading is the indentation
stiffness (N/m) of the first step at least ``map_depth`` (4 mm) deep, the value the palpation map
records. Three measurements:

1. a homogeneous slab (``inclusion_ratio=1``) on a 4 x 4 grid over one node period (7.5 mm)
   around the slab's centre: how the reading varies with where the nodes fall under the probe;
2. the same slab at the 9 candidate cell centres, and on a grid of half the node spacing over
   the cells' centres +- 1 cm (where the map records presses);
3. the inclusion at each cell in turn (the default 10x stiffer box): the reading of the
   inclusion's cell over the stiffest other cell, raw and divided by the homogeneous reading at
   each cell (a calibration on healthy tissue). Below 1, the map points to a wrong cell.

Results are written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import json
import os
import tempfile

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)

ENV_ID = "tissue_env/Palpation-v0"


def first_press(env, x, z, seed=0, max_steps=40):
    """Indentation stiffness (N/m) and depth (m) of the first step at least ``map_depth`` deep of a
    straight-down press at (x, z) m, from a reset with ``seed``."""
    env.reset(seed=seed)
    tip = env._tip()
    env.tool_offset = env.tool_offset + np.array([x - tip[0], 0.0, z - tip[2]])
    for _ in range(max_steps):
        env.step(np.array([0.0, -1.0, 0.0], np.float32))
        measures = env.measures
        if measures["depth"] >= env.map_depth - 1e-9 and measures["indentation_stiffness"] > 0:
            return float(measures["indentation_stiffness"]), float(measures["depth"])
    return float("nan"), float("nan")


def seed_with_inclusion_at(env, cell, limit=1000):
    for seed in range(limit):
        env.reset(seed=seed)
        if env.inclusion_index == cell:
            return seed
    raise RuntimeError(f"no seed below {limit} puts the inclusion in cell {cell}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results", "palpation_map.json"))
    args = parser.parse_args(argv)
    homogeneous = gym.make(ENV_ID, inclusion_ratio=1.0).unwrapped
    homogeneous.reset(seed=0)
    centres = homogeneous.cell_centres
    spacing = float(homogeneous.mesh.spacing[0])
    middle = centres.mean(axis=0)
    offsets = np.linspace(0.0, spacing, 4, endpoint=False)
    grid = np.array([[first_press(homogeneous, middle[0] + dx, middle[1] + dz)[0] for dz in offsets] for dx in offsets])
    cells = np.array([first_press(homogeneous, x, z)[0] for x, z in centres])
    step = spacing / 2.0
    xs = np.arange(centres[:, 0].min() - 0.01, centres[:, 0].max() + 0.01 + 1e-9, step)
    zs = np.arange(centres[:, 1].min() - 0.01, centres[:, 1].max() + 0.01 + 1e-9, step)
    area = np.array([[first_press(homogeneous, x, z)[0] for z in zs] for x in xs])
    env = gym.make(ENV_ID).unwrapped
    raw, calibrated = [], []
    for cell in range(len(centres)):
        seed = seed_with_inclusion_at(env, cell)
        readings = np.array([first_press(env, x, z, seed)[0] for x, z in centres])
        others = np.delete(np.arange(len(centres)), cell)
        raw.append(float(readings[cell] / readings[others].max()))
        normalised = readings / cells
        calibrated.append(float(normalised[cell] / normalised[others].max()))
    results = dict(
        node_spacing_m=spacing, grid_offsets_m=offsets.tolist(), homogeneous_grid_n_per_m=grid.tolist(),
        homogeneous_grid_max_over_min=float(grid.max() / grid.min()), cell_centres_m=centres.tolist(),
        homogeneous_cells_n_per_m=cells.tolist(), homogeneous_cells_max_over_min=float(cells.max() / cells.min()),
        area_step_m=step, area_x_m=xs.tolist(), area_z_m=zs.tolist(), homogeneous_area_n_per_m=area.tolist(),
        homogeneous_area_range_n_per_m=[float(area.min()), float(area.max())],
        inclusion_over_stiffest_other_raw=raw, inclusion_over_stiffest_other_calibrated=calibrated,
    )
    print(f"homogeneous slab, one node period ({spacing * 1e3:.1f} mm) around the centre, N/m:")
    print(np.round(grid, 1))
    print(f"  max/min {results['homogeneous_grid_max_over_min']:.2f}")
    print(f"homogeneous slab at the 9 cell centres, N/m: {np.round(cells, 1).tolist()} "
          f"(max/min {results['homogeneous_cells_max_over_min']:.2f})")
    print(f"homogeneous slab on a {step * 1e3:.2f} mm grid over the cells +- 1 cm: {area.min():.0f}-{area.max():.0f} N/m")
    print(f"inclusion cell / stiffest other cell, raw:        {np.round(raw, 2).tolist()}")
    print(f"  divided by the homogeneous reading of each cell: {np.round(calibrated, 2).tolist()}")
    directory = os.path.dirname(os.path.abspath(args.output))
    os.makedirs(directory, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=directory, suffix=".tmp")
    with os.fdopen(handle, "w") as stream:
        json.dump(results, stream, indent=2)
    os.replace(temporary, args.output)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
