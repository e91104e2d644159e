"""Palpation's probe force at the env's resolution against a converged indentation reference (issue 42, item 6).

Usage: python -m benchmarks.indentation_reference [--resolutions 10 16 20] [--poisson-ratio 0.45]
       [--output benchmarks/results/indentation_reference.json]

The scene is Palpation's at its defaults without gravity and without the inclusion: a 6 x 3 x 6 cm
slab of E = 5 kPa attached by its bottom face, the 9 mm sphere-ended probe pressed frictionlessly
into the centre of its top face (``sim_core.studies.solving.solve_scene``: static equilibrium, the
active set solved to convergence), depths 0.5-8 mm by continuation, with the env's model
(``PalpationEnv.default_model``) and probe sampling ("projected"), on meshes of n x n/2 x n cubes
(n = 10 is the env's 6 mm). The probe force at each depth:

- **reference**: the two finest meshes extrapolated at second order, F(h) = F0 + C h^2 per depth (h
  the cube's side), bracketed by the first-order extrapolation (F0 + C h) and reported beside the
  Richardson extrapolation of the three finest (p fitted per depth), which contact's uneven
  convergence (the nodes the rim reaches change with h) can throw off;
- **Hertz** for a sphere on an elastic half-space, F = 4/3 E* sqrt(R) d^1.5, and Hertz on a layer of
  thickness t bonded to a rigid base (Dimitriadis et al., Biophys. J. 82 (2002) 2798, their eq. 12
  with their nu-dependent alpha0, beta0): the same times a polynomial in chi = sqrt(R d) / t; an
  independent closed form, valid while the contact radius stays small against R and t (d = 0.5-2 mm
  here, where chi is 0.07-0.14);
- the env's force at its 6 mm cubes, the probe over a node (the centre) and over the middle of a
  cell (3 mm off in x and z), and its error against the reference.

The projected sphere is curvature-corrected (``contact.curvature_offsets``, the env's default); the
first-order projection it replaced read 41 / 32 / 29 / 21% under this reference at 2 / 4 / 6 / 8 mm
(n = 10, over a node, measured with ``curvature_corrected=False`` before it became the default).

Written to ``--output`` (JSON, replaced atomically). ``--summarise`` recomputes the reference, the
closed forms and the env's corrected force from the meshes' forces already in ``--output`` (no solve).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

from sim_core.studies.scenes import Scene
from sim_core.studies.solving import solve_scene
from tissue_env.palpation import PalpationEnv
from training.common import write_json

MM = 1e-3
#: Palpation's defaults (``PalpationEnv``): slab, probe radius, tissue
SIZE, RADIUS, YOUNG, DENSITY = (0.06, 0.03, 0.06), 0.009, 5e3, 1060.0
DEPTHS_MM = (0.5, 1.0, 2.0, 4.0, 6.0, 8.0)


def hertz(depth, radius, young_modulus, poisson_ratio):
    """Hertz's force (N) of a rigid sphere of ``radius`` (m) pushed ``depth`` (m) into an elastic
    half-space: 4/3 E / (1 - nu^2) sqrt(R) d^1.5."""
    return 4.0 / 3.0 * young_modulus / (1.0 - poisson_ratio**2) * np.sqrt(radius) * np.asarray(depth) ** 1.5


def bonded_layer_factor(depth, radius, thickness, poisson_ratio):
    """Dimitriadis et al. (2002), eq. 12: the force of a sphere on a layer of ``thickness`` (m)
    bonded to a rigid base over Hertz's, a series in chi = sqrt(R d) / t (small chi)."""
    nu = poisson_ratio
    chi = np.sqrt(radius * np.asarray(depth)) / thickness
    alpha = -(1.2876 - 1.4678 * nu + 1.3442 * nu**2) / (1.0 - nu)
    beta = (0.6387 - 1.0277 * nu + 1.5164 * nu**2) / (1.0 - nu)
    pi = np.pi
    return (1.0 - 2.0 * alpha / pi * chi + 4.0 * alpha**2 / pi**2 * chi**2
            - 8.0 / pi**3 * (alpha**3 + 4.0 * pi**2 / 15.0 * beta) * chi**3
            + 16.0 * alpha / pi**4 * (alpha**3 + 3.0 * pi**2 / 5.0 * beta) * chi**4)


def richardson(spacings, forces):
    """(F0, p) per depth from three meshes: F(h) = F0 + C h^p through the three (h, F) of each
    column of ``forces`` (3, D), spacings (3,) m, finest last; p solved by bisection on the ratio of
    the differences (for any refinement ratios)."""
    h1, h2, h3 = spacings
    extrapolated, orders = [], []
    for f1, f2, f3 in np.asarray(forces).T:
        ratio = (f1 - f2) / (f2 - f3)

        def mismatch(p):
            return (h1**p - h2**p) / (h2**p - h3**p) - ratio

        low, high = 0.1, 4.0
        if mismatch(low) * mismatch(high) > 0:  # no order in range: take the finest mesh's trend at p = 1
            p = 1.0
        else:
            for _ in range(80):
                middle = 0.5 * (low + high)
                low, high = (middle, high) if mismatch(low) * mismatch(middle) > 0 else (low, middle)
            p = 0.5 * (low + high)
        c = (f2 - f3) / (h2**p - h3**p)
        extrapolated.append(f3 - c * h3**p)
        orders.append(p)
    return np.array(extrapolated), np.array(orders)


def indentation_forces(resolution, poisson_ratio, model, sampling="projected", offset=0.0):
    """(forces (D,) N at DEPTHS_MM, seconds) of the probe ``offset`` (m) off the centre of an
    n x n/2 x n slab's top face in x and z."""
    at = 0.03 + offset
    scene = Scene(size=SIZE, young_modulus=YOUNG, poisson_ratio=poisson_ratio, density=DENSITY, gravity=0.0,
                  fixed_face="y-", tool_low=(at, 0.03, at), tool_high=(at, 0.03, at), tool_radius=RADIUS,
                  tool_components=(1,), probe="sphere", probe_sampling=sampling,
                  displacements=[[(0.0, -d * MM, 0.0) for d in DEPTHS_MM]], target=(0.03, 0.015, 0.03))
    start = time.perf_counter()
    solution = solve_scene(scene, (resolution, resolution // 2, resolution), model=model, check_stability=False)
    if not np.all(solution.converged):
        raise RuntimeError(f"the indentation on the n = {resolution} mesh did not converge: {solution.converged}")
    return -solution.force[:, 1], time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="*", default=[10, 16, 20])
    parser.add_argument("--poisson-ratio", type=float, default=0.45)
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results",
                                                         "indentation_reference.json"))
    parser.add_argument("--summarise", action="store_true", help="recompute the summary from --output's forces")
    args = parser.parse_args(argv)
    model, env_resolution = PalpationEnv.default_model, PalpationEnv.default_shape[0]
    nu = args.poisson_ratio
    if args.summarise:
        with open(args.output) as stream:
            stored = json.load(stream)
        model, nu = stored["model"], stored["poisson_ratio"]
        resolutions = stored["resolutions"]
        meshes = {n: np.array([row["meshes_n"][str(n)] for row in stored["rows"]]) for n in resolutions}
        between = np.array([row["env_mid_cell_n"] for row in stored["rows"]])
    else:
        resolutions = sorted(set(args.resolutions) | {env_resolution})
        if len(resolutions) < 3:
            raise SystemExit("Richardson extrapolation needs three resolutions")
        meshes = {}
        for n in resolutions:
            forces, seconds = indentation_forces(n, nu, model)
            meshes[n] = forces
            print(f"n = {n} ({1e3 * SIZE[0] / n:g} mm cubes): F = {np.round(forces, 4).tolist()} N ({seconds:.0f} s)",
                  flush=True)
        between = indentation_forces(env_resolution, nu, model, offset=0.5 * SIZE[0] / env_resolution)[0]
    depths = np.array(DEPTHS_MM) * MM
    finest = resolutions[-3:]
    spacings = np.array([SIZE[0] / n for n in finest])
    richardson_force, orders = richardson(spacings, np.array([meshes[n] for n in finest]))
    # contact converges unevenly (which nodes the rim reaches changes with h): the reference is the
    # second-order extrapolation of the two finest meshes, bracketed by the first-order one
    (h2, h3), (f2, f3) = spacings[-2:], (meshes[finest[-2]], meshes[finest[-1]])
    reference = f3 + (f3 - f2) * h3**2 / (h2**2 - h3**2)
    first_order = f3 + (f3 - f2) * h3 / (h2 - h3)
    closed = hertz(depths, RADIUS, YOUNG, nu)
    layer = closed * bonded_layer_factor(depths, RADIUS, SIZE[1], nu)
    on_node = meshes[env_resolution]
    rows = []
    for i, depth in enumerate(DEPTHS_MM):
        rows.append(dict(depth_mm=depth, reference_n=float(reference[i]), first_order_extrapolation_n=float(first_order[i]),
                         richardson_n=float(richardson_force[i]), richardson_order=float(orders[i]),
                         hertz_n=float(closed[i]), hertz_bonded_layer_n=float(layer[i]),
                         meshes_n={str(n): float(meshes[n][i]) for n in resolutions},
                         env_on_node_n=float(on_node[i]), env_mid_cell_n=float(between[i]),
                         env_on_node_error=float(on_node[i] / reference[i] - 1.0),
                         env_on_node_error_first_order=float(on_node[i] / first_order[i] - 1.0),
                         env_mid_cell_error_first_order=float(between[i] / first_order[i] - 1.0),
                         env_mid_cell_error=float(between[i] / reference[i] - 1.0),
                         reference_over_bonded_hertz=float(reference[i] / layer[i])))
        print(f"{depth:4g} mm: reference {reference[i]:.4f} N (first order {first_order[i]:.4f}, Richardson "
              f"{richardson_force[i]:.4f} at order {orders[i]:.2f}), Hertz {closed[i]:.4f}, bonded "
              f"layer {layer[i]:.4f}; env over a node {100 * rows[-1]['env_on_node_error']:+.1f}%, mid-cell "
              f"{100 * rows[-1]['env_mid_cell_error']:+.1f}%", flush=True)
    write_json(args.output, dict(
        command="python -m benchmarks.indentation_reference", model=model, poisson_ratio=nu, young_modulus=YOUNG,
        size_m=list(SIZE), probe_radius_m=RADIUS, env_resolution=env_resolution, resolutions=resolutions,
        richardson_resolutions=finest, rows=rows,
        machine=dict(platform=platform.platform(), cpus=os.cpu_count(), python=platform.python_version())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
