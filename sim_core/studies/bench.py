"""Step-speed measurements of the full model against a bare spring lattice, side by side.

Used by ``tissue-sim bench`` and ``benchmarks/step_speed.py``. Scene: a block of 0.1 m cubes
(E = 1e4 Pa, nu = 0.3, rho = 1500 kg/m^3), bottom face fixed, sagging under a reduced gravity of
0.5 m/s^2 (a few % strain), so springs, corrections and volume forces are all active. Medians of
repeated steps in ms; the static solve is the 5-degree shear experiment. ``stiff_block`` adds
ImplicitEuler's Jacobi and factorised preconditioners side by side on TumorPositioning's stiff
block (``stiff_<n>_*`` keys); the 10^3 block's entries are Jacobi unless named factorised / auto.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from .. import kernels
from ..solvers.integrators import ImplicitEuler, SymplecticEuler, run
from ..models.material import Material
from ..geometry.mesh import HexMesh
from ..models.model import build_model
from .experiments import shear


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


def interleaved_median_ms(functions: dict, repeats: int) -> dict:
    """Median ms of each function, called round-robin (one call of each per round) so that every
    reading sees the same load on a shared machine."""
    for function in functions.values():
        function()  # warm-up (compilation, caches)
    times = {label: [] for label in functions}
    for _ in range(repeats):
        for label, function in functions.items():
            start = time.perf_counter()
            function()
            times[label].append(time.perf_counter() - start)
    return {label: float(np.median(values) * 1e3) for label, values in times.items()}


def copy_bandwidth(n_bytes: int, repeats: int = 20) -> float:
    """Measured memory bandwidth in bytes/s: a numpy copy reads and writes n_bytes (median)."""
    source = np.ones(n_bytes // 8)
    target = np.empty_like(source)
    seconds = median_ms(lambda: np.copyto(target, source), repeats) * 1e-3
    return 2.0 * source.nbytes / seconds


def _nbytes(*arrays) -> int:
    return int(sum(np.asarray(a).nbytes for a in arrays))


def step_bytes(model, iterations: int, symmetric: bool) -> dict:
    """Compulsory memory traffic (bytes) of one step: every array a pass reads or writes counted once per
    pass, indices and vectors included (a floor: caches, gathers and scatters only add to it).

    explicit: the fused force kernel (springs, corrections, volume, scatter) and the update.
    implicit: the force pass with the operator's data, the right-hand side (1-2 operator products),
    and per solver iteration 1 (CG) or 2 (BiCGSTAB) operator products plus the fused vector updates
    (about 13 (CG) or 24 (BiCGSTAB) vector streams of 3N doubles).
    """
    n_nodes, n_springs, n_elements = model.n_nodes, len(model.springs), model.mesh.n_elements
    node_vector = 3 * n_nodes * 8
    spring_data = _nbytes(model.springs, model.stiffness, model.rest_length, model.damping)
    spring_state_bytes = n_springs * 8 * 5  # length, unit (3), tension
    element_data = 0
    if model.correction_mode is not None:
        element_data += _nbytes(model.edge_spring, model.correction_matrix, model.axis_rest_length) + n_elements * 24
    if model.has_volume_forces:
        element_data += _nbytes(model.mesh.elements, model.rest_volume, model.volume_stiffness)
    forces_pass = spring_data + 2 * spring_state_bytes + element_data + 4 * node_vector  # x, v, forces (rw)
    update = 7 * node_vector + _nbytes(model.mass)  # x0, v0, f, gravity, control force, target, fixed; x1, v1
    explicit = forces_pass + update
    coupled = model.correction_mode is not None and not symmetric
    volume = model.has_volume_forces and not symmetric
    operator = _nbytes(model.springs, model.stiffness, model.damping, model.mass) + n_springs * 8 * 4 + 2 * node_vector
    if coupled:  # elongation and push pass
        operator += n_springs * (16 + 8 * 3 + 8 * 3) + _nbytes(model.edge_spring, model.correction_matrix,
                                                                model.axis_rest_length)
    if volume:
        operator += n_elements * (8 * 8 + 8 + 2 * 24 * 8) + node_vector
    products = (1 if symmetric else 2) * iterations + 3  # + K v0, the imposed part, the initial residual
    vectors = (13 if symmetric else 24) * iterations * node_vector
    implicit = forces_pass + n_springs * 8 + (n_elements * 49 * 8 if volume else 0) + products * operator + vectors
    return {"explicit": explicit, "implicit": implicit, "operator_product": operator}


def tumor_block(shape, patch_radius):
    """TumorPositioning's block: a 5 cm cube of ``shape`` hexahedra, E 5 kPa, nu 0.45, rho 1060,
    volume stiffness x100, hourglass control 1, gravity. Returns (model, bottom nodes, top-patch
    nodes within ``patch_radius`` m of the top face's centre)."""
    mesh = HexMesh.block(shape, 0.05 / np.asarray(shape))
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0,
                        volume_stiffness=100.0)
    nodes = mesh.nodes
    bottom = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))
    top = np.flatnonzero(np.isclose(nodes[:, 1], 0.05))
    patch = top[np.linalg.norm(nodes[top][:, [0, 2]] - 0.025, axis=1) <= patch_radius]
    return model, bottom, patch


def stiff_block(repeats: int = 200, shapes=((4, 4, 4), (7, 7, 7))) -> dict:
    """Jacobi against factorised preconditioning of the implicit step on TumorPositioning's block:
    a 5 cm cube, E 5 kPa, nu 0.45, rho 1060, volume stiffness x100, hourglass control 1, bottom
    fixed, a top patch pressed 0.2 mm per step (dt 20 ms at 4^3, 40 ms at 7^3, the env settings);
    interleaved medians (ms) and median iterations, keys ``stiff_<n>_...``."""
    results = {}
    for shape, dt in zip(shapes, (0.02, 0.04)):
        model, bottom, patch = tumor_block(shape, 1.5 * 0.05 / shape[0])
        nodes = model.mesh.nodes
        integrators = {name: ImplicitEuler(tolerance=1e-4, preconditioner=name) for name in ("jacobi", "factorised")}
        counts = {name: [] for name in integrators}

        def stepper(name):
            states, step = [model.new_state(), model.new_state()], [0]

            def advance():  # the patch goes down and back (5 mm), so the state keeps changing
                step[0] += 1
                depth = 0.0002 * (25 - abs(step[0] % 50 - 25))
                control = model.new_control()
                control.impose(bottom, nodes[bottom])
                control.impose(patch, nodes[patch] - [0.0, depth, 0.0])
                report = integrators[name].simulate(model, states[0], states[1], dt, control)
                states.reverse()
                counts[name].append(report.iterations)
            return advance

        label = f"stiff_{shape[0]}"
        times = interleaved_median_ms({name: stepper(name) for name in integrators}, max(repeats // 2, 20))
        results[f"{label}_dt_s"] = dt
        for name in integrators:
            results[f"{label}_implicit_{name}_ms"] = times[name]
            results[f"{label}_implicit_{name}_iterations"] = float(np.median(counts[name]))
        results[f"{label}_factorisations"] = integrators["factorised"].factorisations
        results[f"{label}_ratio_jacobi_to_factorised"] = times["jacobi"] / times["factorised"]
    return results


def measure(shape=(10, 10, 10), repeats: int = 200) -> dict:
    """Run every measurement; returns a JSON-ready dict (times in ms).

    Full model and bare lattice (same springs, no corrections, no volume forces) are timed side by
    side, interleaved call by call. The implicit comparisons:
      (a) ``ratio_implicit_fixed15``: both solvers run exactly 15 iterations (tolerance ~0): the
          full model's BiCGSTAB (two operator products per iteration) against the bare lattice's CG.
      (b) ``ratio_implicit_converged``: both to the same relative residual (1e-6).
      (c) ``ratio_implicit_to_bare_fixed15``: the issue's reading, the full model's real step
          (converged, 1e-6) against the bare lattice's fixed 15-iteration CG step.
    """
    full, bare, state, control = _sagging_block(shape)
    shape = [int(n) for n in shape]
    results = {"shape": shape, "nodes": full.mesh.n_nodes, "springs": len(full.springs),
               "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                           "cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__}}
    results.update(_explicit_times(full, bare, state, control, repeats))
    results.update(_implicit_times(full, bare, state, control, repeats))
    results.update(stiff_block(repeats))
    results["implicit_solver"] = "BiCGSTAB (full model, corrections and volume implicit); CG (bare lattice)"

    start = time.perf_counter()
    solve = shear(shape, 0.1, 1e4, 0.3, angle_deg=5.0)  # a static solve that any shape admits
    results["static_solve_ms"] = (time.perf_counter() - start) * 1e3
    results["static_solve_converged"] = solve.converged

    results["ratio_explicit_to_bare_numba"] = results["explicit_step_ms"] / results["bare_numba_explicit_step_ms"]
    results["ratio_explicit_to_bare_same_integrator"] = (
        results["explicit_step_ms"] / results["bare_same_integrator_explicit_step_ms"])
    results["ratio_implicit_fixed15"] = (
        results["implicit_fixed15_step_ms"] / results["bare_numba_implicit_fixed15_step_ms"])
    results["ratio_implicit_converged"] = results["implicit_step_ms"] / results["bare_converged_implicit_step_ms"]
    results["ratio_implicit_to_bare_fixed15"] = (
        results["implicit_step_ms"] / results["bare_numba_implicit_fixed15_step_ms"])
    results["ratio_implicit15_to_bare_numba_implicit15"] = (  # both capped at 15 iterations, tolerance 1e-6
        results["implicit_15_iterations_step_ms"] / results["bare_numba_implicit_15_iterations_step_ms"])
    results.update(_bandwidth_floors(full, results))
    return results


def _sagging_block(shape):
    """``measure``'s scene: (full model, bare lattice, a moving loaded state after 5 implicit steps of
    10 ms, the control fixing the bottom face)."""
    mesh = HexMesh.block(shape, 0.1)
    material = Material(1e4, 0.3, 1500.0)
    full = build_model(mesh, material, gravity=(0, -0.5, 0))
    bare = build_model(mesh, material, gravity=(0, -0.5, 0), corrections=False, volume_conservation=False)
    control = full.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control.impose(bottom, mesh.nodes[bottom])
    state = full.new_state()
    run(full, state, ImplicitEuler(), 0.01, 5, control)  # a moving, loaded state
    return full, bare, state, control


def _explicit_times(full, bare, state, control, repeats):
    """Explicit steps of 1 ms from ``state`` (ms): the full model, the bare lattice's numba springs and
    the same integrator on the bare lattice interleaved, then the numpy lattice."""
    explicit = SymplecticEuler()
    out = state.copy()
    n = len(bare.springs)
    scratch = (np.empty(n), np.empty((n, 3)), np.empty(n), np.empty_like(state.positions))
    results = interleaved_median_ms({
        "explicit_step_ms": lambda: explicit.simulate(full, state, out, 1e-3, control),
        "bare_numba_explicit_step_ms": lambda: bare_lattice_numba_step(
            bare, state.positions, state.velocities, 1e-3, scratch),
        "bare_same_integrator_explicit_step_ms": lambda: explicit.simulate(bare, state, out, 1e-3, control),
    }, repeats)
    results["bare_numpy_explicit_step_ms"] = median_ms(
        lambda: bare_lattice_numpy_step(bare, state.positions, state.velocities, 1e-3), max(repeats // 4, 10))
    return results


def _implicit_times(full, bare, state, control, repeats):
    """Implicit steps of 10 ms continued from ``state``, every configuration interleaved: medians (ms),
    median iterations (``*_iterations``; ``cg_iterations`` the full model's BiCGSTAB) and the
    factorised and auto preconditioners' factorisation counts."""
    never = 1e-30  # a tolerance no solve reaches: exactly max_iterations iterations
    jacobi = dict(preconditioner="jacobi")  # the entries without a preconditioner in their name: Jacobi
    configurations = {
        "implicit_step_ms": (ImplicitEuler(**jacobi), full),
        "implicit_step_factorised_ms": (ImplicitEuler(preconditioner="factorised"), full),
        "implicit_step_auto_ms": (ImplicitEuler(preconditioner="auto"), full),
        "bare_converged_implicit_step_ms": (ImplicitEuler(**jacobi), bare),
        "implicit_fixed15_step_ms": (ImplicitEuler(tolerance=never, max_iterations=15, **jacobi), full),
        "bare_numba_implicit_fixed15_step_ms": (ImplicitEuler(tolerance=never, max_iterations=15, **jacobi), bare),
        "implicit_15_iterations_step_ms": (ImplicitEuler(max_iterations=15, **jacobi), full),
        "bare_numba_implicit_15_iterations_step_ms": (ImplicitEuler(max_iterations=15, **jacobi), bare),
    }
    iterations = {label: [] for label in configurations}

    def stepper(label):
        integrator, model = configurations[label]
        states = [state.copy(), state.copy()]

        def step():  # continuous stepping: each call advances the scene (a warm start may not see the answer)
            report = integrator.simulate(model, states[0], states[1], 0.01, control)
            states.reverse()
            iterations[label].append(report.iterations)
        return step

    results = interleaved_median_ms({label: stepper(label) for label in configurations}, max(repeats // 4, 10))
    for label, counts in iterations.items():
        results[label[:-len("_ms")].replace("_step", "") + "_iterations"] = float(np.median(counts))
    results["cg_iterations"] = results.pop("implicit_iterations")  # BiCGSTAB (corrections implicit)
    results["implicit_factorisations"] = configurations["implicit_step_factorised_ms"][0].factorisations
    results["implicit_auto_factorisations"] = configurations["implicit_step_auto_ms"][0].factorisations
    return results


def _bandwidth_floors(full, results):
    """The memory-bandwidth floor of the measured steps: compulsory bytes per step / copy bandwidth
    measured now, from main memory (a 256 MB copy) and from cache (a 1 MB copy: the step's arrays
    fit in L2), and the measured steps' multiples of it."""
    bandwidth = copy_bandwidth(256 * 2**20, 10)
    cache_bandwidth = copy_bandwidth(2**20, 200)
    traffic = step_bytes(full, int(round(results["cg_iterations"])), symmetric=False)
    floors = {"memory_bandwidth_GBps": bandwidth / 1e9, "cache_bandwidth_GBps": cache_bandwidth / 1e9,
              "explicit_bytes_per_step": traffic["explicit"], "implicit_bytes_per_step": traffic["implicit"],
              "explicit_bandwidth_floor_ms": traffic["explicit"] / bandwidth * 1e3,
              "implicit_bandwidth_floor_ms": traffic["implicit"] / bandwidth * 1e3,
              "explicit_cache_floor_ms": traffic["explicit"] / cache_bandwidth * 1e3,
              "implicit_cache_floor_ms": traffic["implicit"] / cache_bandwidth * 1e3}
    floors["explicit_times_bandwidth_floor"] = results["explicit_step_ms"] / floors["explicit_bandwidth_floor_ms"]
    floors["implicit_times_bandwidth_floor"] = results["implicit_step_ms"] / floors["implicit_bandwidth_floor_ms"]
    return floors
