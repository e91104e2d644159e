"""Step-speed measurements of the full model against a bare spring lattice, side by side.

Used by ``tissue-sim bench`` and ``benchmarks/step_speed.py``. Scene: a block of 0.1 m cubes
(E = 1e4 Pa, nu = 0.3, rho = 1500 kg/m^3), bottom face fixed, sagging under a reduced gravity of
0.5 m/s^2 (a few % strain), so springs, corrections and volume forces are all active. Medians of
repeated steps in ms; the static solve is the 5-degree shear experiment.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from . import kernels
from .experiments import shear
from .integrators import ImplicitEuler, SymplecticEuler, run
from .material import Material
from .mesh import HexMesh
from .model import build_model


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


def measure(shape=(10, 10, 10), repeats: int = 200) -> dict:
    """Run every measurement; returns a JSON-ready dict (times in ms)."""
    mesh = HexMesh.block(shape, 0.1)
    material = Material(1e4, 0.3, 1500.0)
    full = build_model(mesh, material, gravity=(0, -0.5, 0))
    bare = build_model(mesh, material, gravity=(0, -0.5, 0), corrections=False, volume_conservation=False)
    control = full.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control.impose(bottom, mesh.nodes[bottom])
    state = full.new_state()
    run(full, state, ImplicitEuler(), 0.01, 5, control)  # a moving, loaded state
    out = state.copy()
    shape = [int(n) for n in shape]
    results = {"shape": shape, "nodes": mesh.n_nodes, "springs": len(full.springs),
               "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                           "cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__}}

    explicit = SymplecticEuler()
    results["explicit_step_ms"] = median_ms(lambda: explicit.simulate(full, state, out, 1e-3, control), repeats)
    results["bare_numpy_explicit_step_ms"] = median_ms(
        lambda: bare_lattice_numpy_step(bare, state.positions, state.velocities, 1e-3), repeats)
    n = len(bare.springs)
    scratch = (np.empty(n), np.empty((n, 3)), np.empty(n), np.empty_like(state.positions))
    results["bare_numba_explicit_step_ms"] = median_ms(
        lambda: bare_lattice_numba_step(bare, state.positions, state.velocities, 1e-3, scratch), repeats)

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
        results[label] = median_ms(lambda: implicit_step(integrator, model, states), max(repeats // 4, 10))
        results[label.replace("_step_ms", "_iterations")] = float(np.median(iterations))
    results["cg_iterations"] = results.pop("implicit_iterations")

    start = time.perf_counter()
    solve = shear(shape, 0.1, 1e4, 0.3, angle_deg=5.0)  # a static solve that any shape admits
    results["static_solve_ms"] = (time.perf_counter() - start) * 1e3
    results["static_solve_converged"] = solve.converged

    results["ratio_explicit_to_bare_numba"] = results["explicit_step_ms"] / results["bare_numba_explicit_step_ms"]
    results["ratio_implicit15_to_bare_numba_implicit15"] = (
        results["implicit_15_iterations_step_ms"] / results["bare_numba_implicit_15_iterations_step_ms"])

    return results
