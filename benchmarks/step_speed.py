"""Step speed of the full Baudet model against a bare spring lattice, measured side by side.

    python -m benchmarks.step_speed [--shape 10 10 10] [--repeats 200] [--models-only]

Scene and measurements: ``sim_core.studies.bench`` (a block of 0.1 m cubes sagging under a reduced
gravity). Reports medians of repeated steps (ms), full model and bare lattice (same springs, no
corrections or volume forces) interleaved call by call, CG/BiCGSTAB iterations, a static shear solve
(ms), the ratios to the bare lattice (explicit; implicit at a fixed 15 iterations, converged to the
same tolerance, and the full model's converged step against the bare fixed-15 CG step), and the
memory-bandwidth floor (compulsory bytes per step / numpy-copy bandwidth measured in the same run),
and the implicit step with ImplicitEuler's factorised preconditioner against Jacobi, on this block
(``implicit_step_factorised_ms``, ``implicit_step_auto_ms``) and on TumorPositioning's stiff 5 cm
block at 4^3 / dt 20 ms and 7^3 / dt 40 ms (``stiff_4_*``, ``stiff_7_*``).
``models_*``: "baudet" (as ``build_model`` makes it, and as the environments make it: hourglass
control 1, volume stiffness x100) and "baudet-hyperelastic" on the same mesh and scene, explicit
(1 ms) and implicit (ImplicitEuler, 10 ms, Jacobi and factorised preconditioners), interleaved call by
call, with the ratios hyperelastic / baudet (``models_ratio_*``; ``--models-only`` runs these alone).
Writes benchmarks/results/step_speed.json. Timing is never asserted in tests: machines are shared.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from training.common import write_json
from sim_core import HexMesh, Material, build_model
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, run
from sim_core.studies.bench import interleaved_median_ms, measure

#: the models ``model_comparison`` times side by side: label -> build_model keywords
MODELS = {
    "baudet": dict(model="baudet"),
    "baudet_env": dict(model="baudet", hourglass_control=1.0, volume_stiffness=100.0),
    "hyperelastic": dict(model="baudet-hyperelastic"),
}


def model_comparison(shape=(10, 10, 10), repeats: int = 200, poisson_ratio: float = 0.3) -> dict:
    """Step times (ms, medians) of ``MODELS`` on one mesh: sim_core.studies.bench's scene (0.1 m
    cubes, E 1e4 Pa, rho 1500, bottom fixed, gravity 0.5 m/s^2, a moving loaded state), explicit
    (SymplecticEuler, 1 ms) and implicit (ImplicitEuler, 10 ms, tolerance 1e-6, Jacobi and
    factorised), every model's step interleaved with the others' call by call; ratios to "baudet"
    and to "baudet_env"."""
    mesh = HexMesh.block(shape, 0.1)
    material = Material(1e4, poisson_ratio, 1500.0)
    models = {label: build_model(mesh, material, gravity=(0, -0.5, 0), **options) for label, options in MODELS.items()}
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    results = {"models_shape": [int(n) for n in shape], "models_poisson_ratio": poisson_ratio}
    states = {}
    for label, model in models.items():
        control = model.new_control().impose(bottom, mesh.nodes[bottom])
        state = model.new_state()
        run(model, state, ImplicitEuler(), 0.01, 5, control)  # a moving, loaded state
        states[label] = (state, control)
    for kind in ("explicit", "implicit_jacobi", "implicit_factorised"):
        functions, iterations = {}, {label: [] for label in models}
        for label, model in models.items():
            state, control = states[label]
            if kind == "explicit":
                integrator, dt = SymplecticEuler(), 1e-3
            else:
                integrator, dt = ImplicitEuler(preconditioner=kind.split("_")[1]), 0.01
            pair = [state.copy(), state.copy()]

            def step(model=model, integrator=integrator, dt=dt, pair=pair, control=control, label=label):
                report = integrator.simulate(model, pair[0], pair[1], dt, control)
                pair.reverse()
                iterations[label].append(report.iterations)
            functions[label] = step
        times = interleaved_median_ms(functions, repeats if kind == "explicit" else max(repeats // 4, 10))
        for label in models:
            results[f"models_{kind}_{label}_ms"] = times[label]
            if kind != "explicit":
                results[f"models_{kind}_{label}_iterations"] = float(np.median(iterations[label]))
        results[f"models_ratio_{kind}"] = times["hyperelastic"] / times["baudet"]
        results[f"models_ratio_{kind}_to_env_baudet"] = times["hyperelastic"] / times["baudet_env"]
    return results


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", type=int, nargs=3, default=[10, 10, 10])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--models-only", action="store_true", help="only baudet against baudet-hyperelastic")
    parser.add_argument("--out", default=None,
                        help="default benchmarks/results/step_speed.json (step_speed_models.json with --models-only)")
    args = parser.parse_args(argv)
    name = "step_speed_models.json" if args.models_only else "step_speed.json"
    out = args.out or str(Path(__file__).parent / "results" / name)
    results = {} if args.models_only else measure(args.shape, args.repeats)
    results.update(model_comparison(args.shape, args.repeats))
    write_json(out, results)
    args.out = out
    width = max(len(k) for k in results)
    for key, value in results.items():
        if key != "machine":
            print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
