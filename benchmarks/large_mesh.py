"""Work against mesh size: what a reset and a static solve cost as the block is refined.

Usage: python -m benchmarks.large_mesh [--env-shapes 8 12 14 16] [--static-shapes 10 16 22 30]
       [--direct-max 22] [--output benchmarks/results/large_mesh.json]

Two measurements, each in one process, wall time on this machine:

* env: ``tissue_env/TumorPositioning-v0`` with ``shape=(n, n, n)`` (``max_nodes=None``): construction,
  the first reset (its start equilibrium under gravity and its goal solve) and the median of 5 steps,
  after a warm-up env (4^3) has compiled the kernels.
  ``tissue_env.base.MAX_NODES`` is the mesh size past which the envs refuse a shape by default.
* static: ``solve_static`` of a 7 cm block of n^3 elements (E = 5 kPa, nu = 0.45, volume forces
  x100, hourglass control 1: the envs' model) under gravity, its bottom fixed and a central top patch
  pressed 1 cm and pushed 5 mm sideways, with ``linear_solver="direct"`` (sparse LU, up to
  ``--direct-max``) and ``"iterative"`` (AMG-preconditioned Krylov): wall time, Newton iterations and
  the largest position difference between the two.
Results are written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import os
import platform
import sys
import time
import warnings

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401
from sim_core import HexMesh, Material, build_model, solve_static
from tissue_env.base import MAX_NODES
from training.common import write_json


def env_cost(n):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        env = gym.make("tissue_env/TumorPositioning-v0", shape=(n, n, n), max_nodes=None)
        built = time.perf_counter()
        env.reset(seed=0)
        reset = time.perf_counter()
        env.action_space.seed(0)
        steps = []
        for _ in range(5):
            tick = time.perf_counter()
            env.step(env.action_space.sample())
            steps.append(time.perf_counter() - tick)
        env.close()
    return dict(shape=[n, n, n], nodes=(n + 1) ** 3, construct_s=built - start, first_reset_s=reset - built,
                step_median_ms=1e3 * float(np.median(steps)))


def static_scene(n, size=0.07, patch=0.15, move=(0.005, -0.01, 0.0)):
    """The static scene: a cube of side ``size`` m in n^3 elements (the envs' model) under gravity,
    its bottom fixed and the top nodes within ``patch`` * ``size`` of the top's centre (along x and
    z) moved by ``move`` (m). Returns (model, control)."""
    mesh = HexMesh.block((n, n, n), size / n)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0.0, -9.81, 0.0), hourglass_control=1.0,
                        volume_stiffness=100.0)
    nodes = mesh.nodes
    bottom = np.flatnonzero(nodes[:, 1] == 0.0)
    top = np.flatnonzero(np.isclose(nodes[:, 1], size) & (np.abs(nodes[:, 0] - size / 2) < patch * size)
                         & (np.abs(nodes[:, 2] - size / 2) < patch * size))
    control = model.new_control().impose(bottom, nodes[bottom]).impose(top, nodes[top] + np.asarray(move))
    return model, control


def static_cost(n, direct_max):
    model, control = static_scene(n)
    row = dict(shape=[n, n, n], nodes=model.n_nodes, free_dofs=int(np.count_nonzero(~control.fixed)))
    solutions = {}
    for solver in ("direct", "iterative"):
        if solver == "direct" and n > direct_max:
            continue
        start = time.perf_counter()
        result = solve_static(model, control, tolerance=1e-8, linear_solver=solver)
        row[f"{solver}_s"] = time.perf_counter() - start
        row[f"{solver}_converged"] = bool(result.converged)
        row[f"{solver}_newton_iterations"] = int(result.iterations)
        solutions[solver] = result.positions
    if len(solutions) == 2:
        displacement = np.abs(solutions["direct"] - model.rest_positions).max()
        row["max_difference_over_max_displacement"] = float(
            np.abs(solutions["direct"] - solutions["iterative"]).max() / displacement)
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-shapes", type=int, nargs="*", default=[8, 12, 14, 16])
    parser.add_argument("--static-shapes", type=int, nargs="*", default=[10, 16, 22, 30])
    parser.add_argument("--direct-max", type=int, default=22)
    parser.add_argument("--output", default="benchmarks/results/large_mesh.json")
    args = parser.parse_args(argv)
    env_rows, static_rows = [], []
    env_cost(4)  # compile and load every kernel first: the first row would count it
    for n in args.env_shapes:
        env_rows.append(env_cost(n))
        row = env_rows[-1]
        print(f"env n={n} ({row['nodes']} nodes): construct {row['construct_s']:.1f} s, first reset "
              f"{row['first_reset_s']:.1f} s, step {row['step_median_ms']:.0f} ms", flush=True)
    for n in args.static_shapes:
        static_rows.append(static_cost(n, args.direct_max))
        print("static", {k: (round(v, 3) if isinstance(v, float) else v) for k, v in static_rows[-1].items()},
              flush=True)
    write_json(args.output, dict(
        max_nodes=MAX_NODES, env=env_rows, static=static_rows,
        machine=dict(platform=platform.platform(), cpus=os.cpu_count(), python=platform.python_version(),
                     numpy=np.__version__, load_average=list(os.getloadavg()))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
