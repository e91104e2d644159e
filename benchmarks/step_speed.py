"""Step speed of the full Baudet model against a bare spring lattice, measured side by side.

    python benchmarks/step_speed.py [--shape 10 10 10] [--repeats 200]

Scene: a block of 0.1 m cubes (E = 1e4 Pa, nu = 0.3, rho = 1500 kg/m^3) with its bottom face fixed,
sagging under gravity (so springs, corrections and volume forces are all active). Reports medians
of repeated steps (ms), CG/BiCGSTAB iterations, a static elongation solve (s), and ratios to the
bare lattice (same springs, no corrections or volume forces). Writes
benchmarks/results/step_speed.json. Timing is never asserted in tests: machines are shared.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_core import HexMesh, Material, build_model  # noqa: E402
from sim_core import kernels  # noqa: E402
from sim_core.experiments import elongation  # noqa: E402
from sim_core.integrators import ImplicitEuler, SymplecticEuler, run  # noqa: E402


def median_ms(function, repeats):
    function()  # warm-up (compilation, caches)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3)


def bare_lattice_numpy_step(model, positions, velocities, dt):
    """Springs only, numpy: the floor a plain implementation reaches."""
    a, b = model.springs[:, 0], model.springs[:, 1]
    vector = positions[b] - positions[a]
    length = np.sqrt(np.einsum("ij,ij->i", vector, vector))
    unit = vector / length[:, None]
    tension = model.stiffness * (length - model.rest_length) + model.damping * np.einsum(
        "ij,ij->i", velocities[b] - velocities[a], unit)
    force = tension[:, None] * unit
    total = np.empty_like(positions)
    for c in range(3):
        total[:, c] = np.bincount(a, force[:, c], len(positions)) - np.bincount(b, force[:, c], len(positions))
    velocities = velocities + dt * (total / model.mass[:, None] + model.gravity)
    return positions + dt * velocities, velocities


def bare_lattice_numba_step(model, positions, velocities, dt, scratch):
    length, unit, tension, forces = scratch
    kernels.spring_pass(positions, model.springs, model.stiffness, model.rest_length, length, unit, tension)
    forces[:] = 0.0
    kernels.scatter_springs(model.springs, unit, tension, model.damping, velocities, True, forces)
    velocities = velocities + dt * (forces / model.mass[:, None] + model.gravity)
    return positions + dt * velocities, velocities


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", type=int, nargs=3, default=[10, 10, 10])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "step_speed.json"))
    args = parser.parse_args(argv)

    mesh = HexMesh.block(args.shape, 0.1)
    material = Material(1e4, 0.3, 1500.0)
    full = build_model(mesh, material, gravity=(0, -9.81, 0))
    bare = build_model(mesh, material, gravity=(0, -9.81, 0), corrections=False, volume_conservation=False)
    control = full.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control.impose(bottom, mesh.nodes[bottom])
    state = full.new_state()
    run(full, state, ImplicitEuler(), 0.01, 5, control)  # a moving, loaded state
    out = state.copy()
    results = {"shape": args.shape, "nodes": mesh.n_nodes, "springs": len(full.springs),
               "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                           "cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__}}

    explicit = SymplecticEuler()
    results["explicit_step_ms"] = median_ms(lambda: explicit.simulate(full, state, out, 1e-3, control), args.repeats)
    results["bare_numpy_explicit_step_ms"] = median_ms(
        lambda: bare_lattice_numpy_step(bare, state.positions, state.velocities, 1e-3), args.repeats)
    n = len(bare.springs)
    scratch = (np.empty(n), np.empty((n, 3)), np.empty(n), np.empty_like(state.positions))
    results["bare_numba_explicit_step_ms"] = median_ms(
        lambda: bare_lattice_numba_step(bare, state.positions, state.velocities, 1e-3, scratch), args.repeats)

    iterations = []

    def implicit_step(integrator, model, states):
        # continuous stepping: each call advances the scene (a warm start may not see the answer)
        report = integrator.simulate(model, states[0], states[1], 0.01, control)
        states.reverse()
        iterations.append(report.iterations)

    for label, integrator, model in [
        ("implicit_step_ms", ImplicitEuler(), full),
        ("implicit_cg_explicit_corrections_step_ms", ImplicitEuler(corrections="explicit"), full),
        ("implicit_15_iterations_step_ms", ImplicitEuler(max_iterations=15), full),
        ("bare_numba_implicit_15_iterations_step_ms", ImplicitEuler(max_iterations=15), bare),
    ]:
        iterations.clear()
        states = [state.copy(), state.copy()]
        results[label] = median_ms(lambda: implicit_step(integrator, model, states), max(args.repeats // 4, 10))
        results[label.replace("_step_ms", "_iterations")] = float(np.median(iterations))
    results["cg_iterations"] = results.pop("implicit_iterations")

    start = time.perf_counter()
    solve = elongation(args.shape, 0.1, 1e4, 0.3, strain=0.01)
    results["static_solve_ms"] = (time.perf_counter() - start) * 1e3
    results["static_solve_converged"] = solve.converged

    results["ratio_explicit_to_bare_numba"] = results["explicit_step_ms"] / results["bare_numba_explicit_step_ms"]
    results["ratio_implicit15_to_bare_numba_implicit15"] = (
        results["implicit_15_iterations_step_ms"] / results["bare_numba_implicit_15_iterations_step_ms"])

    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    temporary = out_path.with_suffix(".tmp")
    temporary.write_text(json.dumps(results, indent=2) + "\n")
    os.replace(temporary, out_path)  # atomic: a reader never sees half a file
    width = max(len(k) for k in results)
    for key, value in results.items():
        if key != "machine":
            print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")
    print(f"written to {out_path}")


if __name__ == "__main__":
    main()
