"""Palpation's probe force at the env's resolution against converged indentation references (issue 42, item 6).

Usage: python -m benchmarks.indentation_reference [--resolutions 10 16 20] [--poisson-ratio 0.45]
       [--output benchmarks/results/indentation_reference.json]
       (nu 0.49: --poisson-ratio 0.49 --resolutions 10 --output benchmarks/results/indentation_reference_nu049.json)

The scene is Palpation's at its defaults without gravity and without the inclusion: a 6 x 3 x 6 cm
slab of E = 5 kPa attached by its bottom face, the 9 mm sphere-ended probe pressed frictionlessly
into its top face (``sim_core.studies.solving.solve_scene``: static equilibrium, the active set
solved to convergence), depths 0.5-8 mm by continuation, with the env's model
(``PalpationEnv.default_model``) and probe sampling ("projected"), on meshes of n x n/2 x n cubes
(n = 10 is the env's 6 mm). The probe force at each depth:

- **axisymmetric**: an independent reference, none of sim_core (``axisymmetric_forces``: scikit-fem,
  quadratic triangles, linear elasticity, frictionless active set) on the cylinder of the slab's
  thickness and top area (its equal-area radius; the inscribed cylinder beside it), base bonded;
- **extrapolated** (with three or more resolutions): the model's two finest meshes, the probe over the
  centre node, extrapolated at second order, F(h) = F0 + C h^2 per depth (h the cube's side), bracketed
  by the first-order extrapolation (F0 + C h) and reported beside the Richardson extrapolation of the
  three finest (p fitted per depth), which contact's uneven convergence (the nodes the rim reaches
  change with h) can throw off;
- **Hertz** for a sphere on an elastic half-space, F = 4/3 E* sqrt(R) d^1.5, and Hertz on a layer of
  thickness t bonded to a rigid base (Dimitriadis et al., Biophys. J. 82 (2002) 2798, their eq. 12
  with their nu-dependent alpha0, beta0): the same times a polynomial in chi = sqrt(R d) / t; closed
  forms valid while the contact radius stays small against R and t;
- the env's force at its 6 mm cubes, the probe over a node (the centre), over the middle of a cell's
  side (3 mm off in x) and over a cell's centre (3 mm off in x and z), and its errors against the
  references.

Written to ``--output`` (JSON, replaced atomically). ``--summarise`` recomputes the summary from the
forces already in ``--output`` (no solve).
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
DEPTHS_MM = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)


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


def axisymmetric_forces(depths, radius, thickness, cylinder_radius, young_modulus, poisson_ratio, spacing=5e-4):
    """An independent reference (scikit-fem, none of sim_core): the force (N) of a rigid sphere of
    ``radius`` (m) pressed frictionlessly ``depths`` (m) into the axis of a linear-elastic cylinder of
    ``cylinder_radius`` and ``thickness`` (m), its base bonded, its side free. Axisymmetric quadratic
    triangles (2 pi r dr dz; strains u_r,r, u_z,z, u_r / r, (u_r,z + u_z,r) / 2) of side ``spacing``
    (m) within 12 mm of the axis and 6 mm of the top, graded outside; contact by an active set on the
    top's vertical degrees of freedom: those in contact follow the sphere, u_z = -(d - R + sqrt(R^2 -
    r^2)), until none pulls on it and no other goes through it. Small strains and the undeformed r:
    valid while the indentation is small against the layer (the finite-strain model stiffens past it)."""
    from skfem import Basis, BilinearForm, ElementTriP2, ElementVector, MeshTri, asm, condense, solve
    from skfem.helpers import grad

    def graded(length, fine, count):
        return np.concatenate([np.arange(0.0, fine + 1e-12, spacing), np.geomspace(fine, length, count + 1)[1:]])

    mesh = MeshTri.init_tensor(graded(cylinder_radius, 0.012, 20), np.unique(thickness - graded(thickness, 0.006, 25)))
    basis = Basis(mesh, ElementVector(ElementTriP2()), intorder=4)
    lame = young_modulus * poisson_ratio / ((1 + poisson_ratio) * (1 - 2 * poisson_ratio))
    shear = young_modulus / (2 * (1 + poisson_ratio))

    def strains(u, r):
        g = grad(u)
        return g[0][0], g[1][1], u[0] / r, g[0][1] + g[1][0]  # rr, zz, theta theta, engineering rz

    @BilinearForm
    def stiffness(u, v, w):
        e, f = strains(u, w.x[0]), strains(v, w.x[0])
        trace = e[0] + e[1] + e[2]
        return 2 * np.pi * w.x[0] * (sum((lame * trace + 2 * shear * e[i]) * f[i] for i in range(3))
                                     + shear * e[3] * f[3])

    matrix = asm(stiffness, basis)
    axis = basis.get_dofs(lambda x: np.isclose(x[0], 0.0))
    top = basis.get_dofs(lambda x: np.isclose(x[1], thickness))
    fixed = np.concatenate([basis.get_dofs(lambda x: np.isclose(x[1], 0.0)).all(), axis.nodal["u^1"], axis.facet["u^1"]])
    vertical = np.concatenate([top.nodal["u^2"], top.facet["u^2"]])
    r = basis.doflocs[0, vertical]
    forces = []
    for depth in np.atleast_1d(depths):
        bound = np.where(r < radius, -(depth - radius + np.sqrt(np.maximum(radius**2 - r**2, 0.0))), np.inf)
        active = r < np.sqrt(radius * depth)  # Hertz's contact radius to start
        for _ in range(200):
            x = np.zeros(matrix.shape[0])
            x[vertical[active]] = bound[active]
            x = solve(*condense(matrix, x=x, D=np.concatenate([fixed, vertical[active]])))
            reaction = (matrix @ x)[vertical]
            pulls, through = active & (reaction > 0), ~active & (x[vertical] > bound + 1e-12)
            if not pulls.any() and not through.any():
                break
            active = (active & ~pulls) | through
        else:
            raise RuntimeError(f"the axisymmetric contact at {depth} m did not settle")
        forces.append(-reaction[active].sum())
    return np.array(forces)


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


def indentation_forces(resolution, poisson_ratio, model, sampling="projected", offset=(0.0, 0.0), young_modulus=YOUNG):
    """(forces (D,) N at DEPTHS_MM, seconds) of the probe ``offset`` (m, in x and z) off the centre
    of an n x n/2 x n slab's top face."""
    x, z = 0.03 + offset[0], 0.03 + offset[1]
    scene = Scene(size=SIZE, young_modulus=young_modulus, poisson_ratio=poisson_ratio, density=DENSITY, gravity=0.0,
                  fixed_face="y-", tool_low=(x, 0.03, z), tool_high=(x, 0.03, z), tool_radius=RADIUS,
                  tool_components=(1,), probe="sphere", probe_sampling=sampling,
                  displacements=[[(0.0, -d * MM, 0.0) for d in DEPTHS_MM]], target=(0.03, 0.015, 0.03))
    start = time.perf_counter()
    solution = solve_scene(scene, (resolution, resolution // 2, resolution), model=model, check_stability=False)
    if not np.all(solution.converged):
        raise RuntimeError(f"the indentation on the n = {resolution} mesh did not converge: {solution.converged}")
    return -solution.force[:, 1], time.perf_counter() - start


#: Where the env's probe is pressed, in cells off a node: over a node, over the middle of a cell's
#: side (an edge), over a cell's centre
POSITIONS = {"node": (0.0, 0.0), "edge": (0.5, 0.0), "cell_centre": (0.5, 0.5)}
#: The cylinder of the slab's top area (its equal-area radius) and the one inscribed in it (m)
CYLINDERS = {"equal_area": float(np.sqrt(SIZE[0] * SIZE[2] / np.pi)), "inscribed": 0.5 * SIZE[0]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="*", default=[10, 16, 20],
                        help="meshes (cubes across) for the extrapolated reference: three or more, or only the env's")
    parser.add_argument("--poisson-ratio", type=float, default=0.45)
    parser.add_argument("--output", default=os.path.join(os.path.dirname(__file__), "results",
                                                         "indentation_reference.json"))
    parser.add_argument("--summarise", action="store_true", help="recompute the summary from --output's forces")
    args = parser.parse_args(argv)
    model, env_resolution = PalpationEnv.default_model, PalpationEnv.default_shape[0]
    nu = args.poisson_ratio
    depths = np.array(DEPTHS_MM) * MM
    if args.summarise:
        with open(args.output) as stream:
            stored = json.load(stream)
        model, nu, resolutions = stored["model"], stored["poisson_ratio"], stored["resolutions"]
        meshes = {n: np.array([row["meshes_n"][str(n)] for row in stored["rows"]]) for n in resolutions}
        env = {name: np.array([row["env_n"][name] for row in stored["rows"]]) for name in POSITIONS}
        cylinders = {name: np.array([row["axisymmetric_n"][name] for row in stored["rows"]]) for name in CYLINDERS}
    else:
        resolutions = sorted(set(args.resolutions) | {env_resolution})
        if len(resolutions) == 2:
            raise SystemExit("the extrapolated reference needs three resolutions (or give only the env's)")
        meshes = {}
        for n in resolutions:
            forces, seconds = indentation_forces(n, nu, model)
            meshes[n] = forces
            print(f"n = {n} ({1e3 * SIZE[0] / n:g} mm cubes): F = {np.round(forces, 4).tolist()} N ({seconds:.0f} s)",
                  flush=True)
        cell = SIZE[0] / env_resolution
        env = {name: meshes[env_resolution] if offset == (0.0, 0.0) else
               indentation_forces(env_resolution, nu, model, offset=(offset[0] * cell, offset[1] * cell))[0]
               for name, offset in POSITIONS.items()}
        cylinders = {name: axisymmetric_forces(depths, RADIUS, SIZE[1], radius, YOUNG, nu)
                     for name, radius in CYLINDERS.items()}
    axisymmetric = cylinders["equal_area"]
    extrapolated = len(resolutions) >= 3
    if extrapolated:
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
    rows = []
    for i, depth in enumerate(DEPTHS_MM):
        row = dict(depth_mm=depth, axisymmetric_n={name: float(f[i]) for name, f in cylinders.items()},
                   hertz_n=float(closed[i]), hertz_bonded_layer_n=float(layer[i]),
                   meshes_n={str(n): float(meshes[n][i]) for n in resolutions},
                   env_n={name: float(f[i]) for name, f in env.items()},
                   env_error_axisymmetric={name: float(f[i] / axisymmetric[i] - 1.0) for name, f in env.items()})
        if extrapolated:
            row.update(reference_n=float(reference[i]), first_order_extrapolation_n=float(first_order[i]),
                       richardson_n=float(richardson_force[i]), richardson_order=float(orders[i]),
                       env_error={name: float(f[i] / reference[i] - 1.0) for name, f in env.items()},
                       reference_over_axisymmetric=float(reference[i] / axisymmetric[i]))
        rows.append(row)
        against = "".join(f", {name} {100 * row['env_error_axisymmetric'][name]:+.1f}%" for name in env)
        print(f"{depth:4g} mm: axisymmetric {axisymmetric[i]:.4f} N (inscribed {cylinders['inscribed'][i]:.4f})"
              + (f", extrapolated {reference[i]:.4f} (first order {first_order[i]:.4f})" if extrapolated else "")
              + f", Hertz {closed[i]:.4f}, bonded layer {layer[i]:.4f}; env against the axisymmetric{against}"
              + ("; against the extrapolated" + "".join(f", {name} {100 * row['env_error'][name]:+.1f}%" for name in env)
                 if extrapolated else ""), flush=True)
    write_json(args.output, dict(
        command="python -m benchmarks.indentation_reference" + ("" if args.output.endswith("indentation_reference.json")
                                                                 else f" --poisson-ratio {nu} --resolutions "
                                                                 + " ".join(map(str, resolutions))
                                                                 + f" --output {os.path.relpath(args.output)}"),
        model=model, poisson_ratio=nu, young_modulus=YOUNG, size_m=list(SIZE), probe_radius_m=RADIUS,
        env_resolution=env_resolution, resolutions=resolutions, positions_cells=POSITIONS, cylinders_m=CYLINDERS,
        rows=rows, machine=dict(platform=platform.platform(), cpus=os.cpu_count(), python=platform.python_version())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
