"""The environments' scenes with each mass-spring model against neo-Hookean FEM: which physics should
the environments use?

Usage: python -m benchmarks.env_models [--task NAME ...] [--models baudet baudet-hyperelastic]
       [--reference-scale 1] [--output benchmarks/results/env_models.json]

For each task the static scenes of ``benchmarks/env_accuracy.py`` (tool force, target displacement
and volume change at every tested tool displacement, with gravity and contact) are solved on the
env's default mesh with each model (``baudet`` in the envs' setting: hourglass control and volume
stiffness from ``tissue_env.base.MODEL_DEFAULTS``) and compared with ``fem-neohookean`` on the finer
mesh env_accuracy uses (``--reference-scale`` refines it; for Palpation that reference is the
env's own mesh): the largest relative error of each quantity over the cases, whether every
equilibrium is stable (no saddle), and the solve time; a model that refuses the mesh (``baudet`` on
Retraction's box elements, ``sim_core.models.model.MAX_SHEAR_ERROR``) is reported with its reason. Written to ``--output`` (JSON, atomically; ``--task NAME`` re-runs
those tasks and keeps the others' results).
"""

import argparse
import json
import sys
import time
from pathlib import Path

from benchmarks import env_accuracy as ea
from sim_core.studies.resolution import evaluate, reference_solutions
from training.common import write_json

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="*", default=["baudet", "baudet-hyperelastic"])
    parser.add_argument("--task", nargs="*", default=list(ea.TASKS))
    parser.add_argument("--reference-scale", type=float, default=1.0,
                        help="multiply env_accuracy's fem-neohookean resolution by this (a finer reference)")
    parser.add_argument("--output", default=None,
                        help="default benchmarks/results/env_models.json (env_models_reference_x<scale>.json "
                             "with --reference-scale)")
    args = parser.parse_args(argv)
    if args.reference_scale < 1.0:
        parser.error("--reference-scale must be >= 1")
    if args.output is None:
        args.output = ("benchmarks/results/env_models.json" if args.reference_scale == 1.0
                       else f"benchmarks/results/env_models_reference_x{args.reference_scale:g}.json")
    alpha, kappa = ea.env_defaults()
    out = dict(reference="fem-neohookean", reference_scale=args.reference_scale, tasks={})
    previous = Path(args.output)
    if previous.exists():  # --task re-runs those tasks and keeps the others' results
        out["tasks"].update(json.loads(previous.read_text()).get("tasks", {}))
    for name in args.task:
        make, _, fem_resolution, _, _ = ea.TASKS[name]
        scenes, shape = make(), ea.env_default_shape(name)
        start = time.perf_counter()
        fem = reference_solutions(scenes, reference_resolution=int(round(args.reference_scale * fem_resolution)))
        rows = {}
        for model in args.models:
            candidate = evaluate(scenes, shape, fem[0], ea.TOLERANCE, hourglass_control=alpha, volume_stiffness=kappa,
                                 model=model)
            rows[model] = dict(errors=candidate.errors, stable=bool(candidate.stable),
                               converged=bool(candidate.converged), solve_time=candidate.solve_time,
                               lowest_eigenvalue=candidate.lowest_eigenvalue, reason=candidate.reason)
            print(f"{name} {model} {shape}: " + ", ".join(f"{q} {100 * v:.1f}%" for q, v in (candidate.errors or {}).items())
                  + f", stable {candidate.stable}" + (f" ({candidate.reason})" if candidate.reason else ""), flush=True)
        out["tasks"][name] = dict(shape=list(shape), reference_shapes=[list(s) for s in fem[1]], models=rows,
                                  wall_time=time.perf_counter() - start)
    write_json(args.output, out, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
