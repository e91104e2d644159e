"""Do an environment's observations, as it produces them, converge with resolution? (issue 4)

``benchmarks/env_accuracy.py`` compares static equilibria across shapes (discretisation) and, on
one shape, the env's observations with the tool at full speed against that shape's own static
equilibrium (the lag). The lag is physics as much as error (the tissue has mass and damping, and
the tool outruns it), and it need not fall with resolution: Retraction's flap lags 34% in force at
(8, 2, 4) and 154% at (20, 3, 10). What an agent sees is the dynamic observation, so this
benchmark measures that one against the same dynamic run on a fine mesh: the scene of
``env_accuracy`` (the env's tissue model, ``env_accuracy.env_setting``; same scenes,
displacements, tool speed ``max_step`` per env step, the env's dt, one substep, its solver
tolerance), the scripted tool reaching each tested displacement at full speed without holding
(``sim_core.resolution.dynamic_scene``), observations taken on arrival: tool force, target
displacement and relative volume change; errors max |q - q_fine| / max |q_fine| over the
displacements, as in env_accuracy. Each shape's lag (its dynamic against its own static
observations) is reported too.

``--integrator static`` steps every run (each shape's and the fine mesh's) by a static
equilibrium per env step (``sim_core.solvers.static.QuasiStatic``, the envs' ``integrator="static"``)
instead of implicit Euler: no lag, so its errors against the fine mesh are the static
discretisation errors, at the cost per env step it reports (``seconds_per_step``).

``--damping-ratio R`` multiplies every spring's critical damping 2 sqrt(m k) by R (the fine run's
too); ``--constant-viscosity`` sets R = h_default / h per shape (h the cube root of an element's
volume), which keeps the viscosity of the env's default mesh: a spring's damping scales like h^2,
the viscous stress it makes like h, so without it a finer mesh is less viscous.

Usage: python -m benchmarks.dynamic_convergence [--task NAME ...] [--shapes NX,NY,NZ ...]
       [--fine NX,NY,NZ] [--damping-ratio R | --constant-viscosity] [--integrator implicit|static]
Writes benchmarks/results/dynamic_convergence.json (``--output``; atomically; --task keeps the
other tasks' results) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from training.common import write_json
from benchmarks.env_accuracy import (
    TASKS, env_default_dt, env_default_shape, env_setting, env_solver_tolerance,
)
from sim_core.resolution import dynamic_scene, scene_errors, solve_scene

ROOT = Path(__file__).resolve().parents[1]

#: shapes compared by default (the env default among them); the fine dynamic reference is
#: env_accuracy's fine model (its resolution n, ``Scene.shape``)
SHAPES = {
    # not (4, 4, 4): there the grasped patch (env_accuracy.tumor_scenes) is the one centre node, a point
    # load whose 12 mm press has no converged static equilibrium
    "TumorPositioning": [(6, 6, 6), (7, 7, 7), (8, 8, 8), (12, 12, 12)],
    "Palpation": [(6, 3, 6), (8, 4, 8), (10, 5, 10)],
    "Retraction": [(8, 2, 4), (10, 2, 5), (12, 2, 6), (20, 3, 10)],
}
PATH = ROOT / "benchmarks" / "results" / "dynamic_convergence.json"


def element_size(scene, shape):
    """The cube root of an element's volume, m."""
    size = np.broadcast_to(np.asarray(scene.size, dtype=float), (3,))
    return float(np.prod(size / np.asarray(shape, dtype=float)) ** (1.0 / 3.0))


def dynamic(scenes, shape, dt, max_step, solver_tolerance, alpha, kappa, damping_ratio=1.0, integrator="implicit",
            model="baudet"):
    """The env-like dynamic observations of every scene at ``shape``: (solutions, env steps, seconds)
    or raises RuntimeError naming the diverging scene."""
    solutions, steps, seconds = [], 0, 0.0
    for scene in scenes:
        solution, count, _, elapsed, reason = dynamic_scene(
            scene, shape, dt=dt, substeps=1, max_step=max_step, hold_steps=0, hourglass_control=alpha,
            volume_stiffness=kappa, solver_tolerance=solver_tolerance,
            solver=dict(preconditioner="auto") if integrator == "implicit" else None,
            damping_ratio=damping_ratio, integrator=integrator, model=model)
        if reason is not None:
            raise RuntimeError(f"{scene.name} at {shape} diverged: {reason}")
        solutions.append(solution)
        steps += count
        seconds += elapsed
    return solutions, steps, seconds


def errors(solutions, references):
    """Worst relative error per quantity over the scenes (each scene normalised by its own largest
    reference value, as ``scene_errors``)."""
    worst = {}
    for solution, reference in zip(solutions, references):
        for quantity, value in scene_errors(solution, reference).items():
            worst[quantity] = max(worst.get(quantity, 0.0), float(value))
    return worst


def run(task, shapes=None, fine=None, damping_ratio=1.0, constant_viscosity=False, integrator="implicit"):
    make, max_step, _, fine_resolution, _ = TASKS[task]
    scenes = make()
    shapes = [tuple(s) for s in (shapes or SHAPES[task])]
    fine = tuple(fine or scenes[0].shape(fine_resolution))
    model, alpha, kappa = env_setting(task)
    dt, tolerance = env_default_dt(task), env_solver_tolerance(task)
    default_size = element_size(scenes[0], env_default_shape(task))

    def ratio(shape):
        return default_size / element_size(scenes[0], shape) if constant_viscosity else float(damping_ratio)

    clock = time.perf_counter()
    references, fine_steps, fine_seconds = dynamic(scenes, fine, dt, max_step, tolerance, alpha, kappa, ratio(fine),
                                                   integrator, model)
    rows = []
    for shape in shapes:
        solutions, steps, seconds = dynamic(scenes, shape, dt, max_step, tolerance, alpha, kappa, ratio(shape),
                                            integrator, model)
        static = [solve_scene(scene, shape, model=model, hourglass_control=alpha, volume_stiffness=kappa,
                              check_stability=False) for scene in scenes]
        rows.append(dict(shape=list(shape), errors=errors(solutions, references), lag=errors(solutions, static),
                         damping_ratio=ratio(shape), env_steps=steps, seconds=seconds,
                         seconds_per_step=seconds / max(steps, 1),
                         is_env_default=shape == env_default_shape(task),
                         volume=[s.volume.tolist() for s in solutions],
                         force_norm=[np.linalg.norm(s.force, axis=1).tolist() for s in solutions]))
    return dict(task=task, integrator=integrator, dt=dt, substeps=1, max_step=max_step, solver_tolerance=tolerance,
                model=model, hourglass_control=alpha,
                volume_stiffness=kappa, damping="constant viscosity" if constant_viscosity else float(damping_ratio),
                fine_damping_ratio=ratio(fine), fine_shape=list(fine), fine_seconds=fine_seconds, fine_env_steps=fine_steps,
                fine_volume=[r.volume.tolist() for r in references],
                fine_force_norm=[np.linalg.norm(r.force, axis=1).tolist() for r in references],
                shapes=rows, wall_time=time.perf_counter() - clock)


def table(results):
    print("dynamic observations (tool at full speed, no hold) against the fine mesh's, and the lag (against the "
          "shape's own static equilibrium); errors in % (force / target / volume)")
    for name, result in results.items():
        print(f"{name} ({result.get('model', 'baudet')}): fine {tuple(result['fine_shape'])}, "
              f"{result.get('integrator', 'implicit')}, "
              f"dt {result['dt'] * 1e3:.0f} ms, max_step {result['max_step'] * 1e3:.0f} mm, damping {result['damping']}")
        for row in result["shapes"]:
            e, lag = row["errors"], row["lag"]
            print(f"  {str(tuple(row['shape'])):14s} vs fine {100 * e['force']:6.1f} {100 * e['target']:6.1f} "
                  f"{100 * e['volume']:6.1f}   lag {100 * lag['force']:6.1f} {100 * lag['target']:6.1f} "
                  f"{100 * lag['volume']:6.1f}   damping x{row['damping_ratio']:.2f}"
                  f"   {1e3 * row['seconds'] / max(row['env_steps'], 1):6.2f} ms/step"
                  f"{'   env default' if row['is_env_default'] else ''}")


def _shape(text):
    values = tuple(int(v) for v in text.split(","))
    if len(values) != 3 or min(values) < 1:
        raise argparse.ArgumentTypeError(f"a shape is NX,NY,NZ with positive integers, got {text!r}")
    return values


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", action="append", choices=list(TASKS), help="only this task (repeatable)")
    parser.add_argument("--shapes", nargs="+", type=_shape, help="shapes to compare (one task only)")
    parser.add_argument("--fine", type=_shape, help="the fine reference shape (one task only)")
    damping = parser.add_mutually_exclusive_group()
    damping.add_argument("--damping-ratio", type=float, default=1.0,
                         help="multiplier of the critical spring damping, every shape (default 1)")
    damping.add_argument("--constant-viscosity", action="store_true",
                         help="damping ratio h_default / h per shape: the default mesh's viscosity")
    parser.add_argument("--integrator", choices=("implicit", "static"), default="implicit",
                        help="env-step physics of every run (default implicit: the envs' default)")
    parser.add_argument("--output", default=str(PATH), help="JSON file to write")
    args = parser.parse_args(argv)
    if not args.damping_ratio >= 0.0:
        parser.error(f"--damping-ratio must be >= 0, got {args.damping_ratio}")
    path = Path(args.output)
    tasks = args.task or list(TASKS)
    if (args.shapes or args.fine) and len(tasks) != 1:
        parser.error("--shapes and --fine need exactly one --task")
    results = json.loads(path.read_text()) if path.is_file() and args.task else {}
    for name in tasks:
        results[name] = run(name, args.shapes, args.fine, args.damping_ratio, args.constant_viscosity, args.integrator)
        print(f"{name}: {results[name]['wall_time']:.0f} s", flush=True)
    results = {name: results[name] for name in TASKS if name in results}
    write_json(path, results, indent=1)
    table(results)
    return results


if __name__ == "__main__":
    main()
