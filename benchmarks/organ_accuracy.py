"""How fine must LiverNeedleAlignment's organ mesh be, and how fast is it? (issue 28 item 4)

The organ task's mesh is the liver phantom's voxel grid (``shape``: voxels per axis over the
lobe's 8 x 4 x 6.4 cm box, ``HexMesh.from_mask``), not a block, so ``benchmarks/env_accuracy.py``'s
block scenes do not apply; this benchmark measures the task's own scene on each candidate grid:
the env's mesh, materials (parenchyma, tumour, vessel), attachment, grasped patch, gravity and
mass-spring setting (hourglass control 1, volume stiffness x100), read from the env built at that
shape. At each tested tool displacement (``CASES``, from rest, inside the workspace) it solves the
static equilibrium (``sim_core.studies.solving.model_solver``: ``solve_static`` to 1e-8, from the
start equilibrium under gravity) and records the force the tool exerts (3,) N, the tumour's
displacement from its rest position (the material point at the phantom's tumour centre: the same
point on every grid) and the relative volume change. Errors against the finest grid
(``REFERENCE``) as ``sim_core.studies.solving.scene_errors``: max over the cases of
|q - q_ref| / max |q_ref|, over the cases both grids solve (a case without a static equilibrium on
a grid is listed in the results, not compared). The reference's own convergence is the next finest
grid's error.

Elements: every grid is run with the voxels as hexahedra (``element="hex"``, the default) and
split into 6 tetrahedra each on the same nodes (``element="tet"``: smoothed-strain tetrahedra, no
hourglass control or volume forces); each candidate is compared with the reference grid of both,
so that the table shows whether the two converge to the same scene.

Speed: env steps per CPU second at every candidate shape (``benchmarks.env_accuracy.env_speeds``:
random actions, resets included, median of interleaved rounds), and the budgeted choice, as for the
other tasks: the most accurate candidate that keeps 300 steps/s with the 1.25x margin (375).

Writes benchmarks/results/organ_accuracy.json (atomically) and prints a table.
Run: python -m benchmarks.organ_accuracy [--rounds 3] [--no-speed]
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from benchmarks.env_accuracy import SPEED_FLOOR, SPEED_MARGIN, env_speeds
from sim_core.studies.solving import QUANTITIES, SceneSolution, model_solver, scene_errors
from tissue_env import LiverNeedleAlignmentEnv
from training.common import write_json

ROOT = Path(__file__).resolve().parents[1]

ENV_ID = "tissue_env/LiverNeedleAlignment-v0"
#: Tool displacements from rest (m) inside the env's workspace (+-20 mm, down 5 mm at most): pull,
#: the deepest press, drags along x and z, and two diagonal moves like the paths' goals.
CASES = {"pull 12 mm": (0.0, 0.012, 0.0), "press 5 mm": (0.0, -0.005, 0.0), "drag x 12 mm": (0.012, 0.0, 0.0),
         "drag z 12 mm": (0.0, 0.0, 0.012), "diagonal (8, 8, -8) mm": (0.008, 0.008, -0.008),
         "diagonal (-10, -4, 6) mm": (-0.010, -0.004, 0.006)}
#: Candidate voxel grids over the env's 8 x 4 x 6.4 cm box: cubic voxels only (the env's ``baudet``
#: refuses boxes, and the box's sides 8, 4, 6.4 cm share 8 mm and its divisors): 8 mm; the reference is the 4 mm grid (a 2.67 mm grid, (30, 15, 24), has
#: about 10^4 nodes: not yet run).
CANDIDATES = ((10, 5, 8),)
FINER = ()
REFERENCE = (20, 10, 16)


#: the lobe's voxels as hexahedra or as 6 tetrahedra each (LiverNeedleAlignment's ``element``)
ELEMENTS = ("hex", "tet")


def make_env(shape, element="hex") -> LiverNeedleAlignmentEnv:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the reference grid is past the env's slow-reset warning
        return LiverNeedleAlignmentEnv(shape=shape, max_nodes=None, element=element)


def solve_shape(shape, element="hex") -> SceneSolution:
    """The task's scene on the ``shape`` voxel grid solved at every case (module docstring)."""
    env = make_env(shape, element)
    env.reset(seed=0)
    start = env.state.positions.copy()
    solve, _ = model_solver(env.model)
    forces, tumours, volumes, converged = [], [], [], []
    clock = time.perf_counter()
    rest_volume = float(env.model.rest_volume.sum())
    for displacement in CASES.values():
        control = env.base_control.copy().impose(env.tool_nodes, env.tool_rest + np.asarray(displacement))
        positions, reaction, ok, _ = solve(control, start)
        forces.append(reaction[env.tool_nodes].sum(axis=0))
        tumours.append(env.tumor_weights @ positions[env.tumor_nodes])
        volumes.append((env.mesh.element_volumes(positions).sum() - rest_volume) / rest_volume)
        converged.append(ok)
    rest = env.tumor_weights @ env.mesh.nodes[env.tumor_nodes]
    return SceneSolution(shape=tuple(shape), force=np.array(forces), target=np.array(tumours), volume=np.array(volumes),
                         target_rest=rest, converged=np.array(converged), stable=np.full(len(CASES), None),
                         lowest_eigenvalue=np.full(len(CASES), np.nan), solve_time=time.perf_counter() - clock)


def subset(solution: SceneSolution, keep) -> SceneSolution:
    """``solution`` restricted to the cases ``keep`` (K,) bool."""
    return SceneSolution(shape=solution.shape, force=solution.force[keep], target=solution.target[keep],
                         volume=solution.volume[keep], target_rest=solution.target_rest,
                         converged=solution.converged[keep], stable=solution.stable[keep],
                         lowest_eigenvalue=solution.lowest_eigenvalue[keep], solve_time=solution.solve_time)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="interleaved speed rounds (median)")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed measurement")
    parser.add_argument("--output", default=str(ROOT / "benchmarks" / "results" / "organ_accuracy.json"))
    args = parser.parse_args(argv)
    references = {element: solve_shape(REFERENCE, element) for element in ELEMENTS}
    reference = references["hex"]
    rows = []
    for shape in CANDIDATES + FINER:
        for element in ELEMENTS:
            solution = solve_shape(shape, element)
            env = make_env(shape, element)
            row = dict(shape=list(shape), element=element, nodes=env.mesh.n_nodes, elements=env.mesh.n_elements,
                       tumour_elements=int(np.count_nonzero(env.mesh.element_labels == 2)),
                       tool_nodes=len(env.tool_nodes), converged=bool(solution.converged.all()),
                       converged_cases=[name for name, ok in zip(CASES, solution.converged) if ok],
                       solve_seconds=solution.solve_time, candidate=shape in CANDIDATES)
            # the errors over the cases solved on both grids (a case without a static equilibrium on
            # one of them, the press on a fine grid's thin rims, is listed, not compared)
            for against, fine in references.items():
                both = solution.converged & fine.converged
                errors = scene_errors(subset(solution, both), subset(fine, both))
                suffix = "" if against == element else f"_against_{against}"
                row.update({f"errors{suffix}": errors, f"worst_error{suffix}": max(errors.values()),
                            f"compared_cases{suffix}": [name for name, ok in zip(CASES, both) if ok]})
            rows.append(row)
            print(f"{'x'.join(map(str, shape)):>9s} {element} {env.mesh.n_nodes:5d} nodes: "
                  + " ".join(f"{q} {100 * row['errors'][q]:5.1f}%" for q in QUANTITIES), flush=True)
    # each reference against the other: how far the two element types' converged scenes are apart
    both = references["hex"].converged & references["tet"].converged
    reference_gap = scene_errors(subset(references["tet"], both), subset(references["hex"], both))
    speeds = {} if args.no_speed else {element: env_speeds(ENV_ID, CANDIDATES, rounds=args.rounds, element=element)
                                       for element in ELEMENTS}
    floor = SPEED_FLOOR * SPEED_MARGIN
    for row in rows:
        row["steps_per_cpu_s"] = speeds.get(row["element"], {}).get("x".join(map(str, row["shape"])))
    fast = [row for row in rows if row["candidate"] and row["element"] == "hex" and row["converged"]
            and (row["steps_per_cpu_s"] or 0.0) >= floor]
    choice = min(fast, key=lambda row: row["worst_error"]) if fast else None
    default = list(LiverNeedleAlignmentEnv.default_shape)
    for row in rows:
        speed = row["steps_per_cpu_s"]
        print(f"{'x'.join(map(str, row['shape'])):>9s} {row['element']} worst {100 * row['worst_error']:5.1f}%  "
              f"{'' if speed is None else f'{speed:5.0f} steps/CPU s'}"
              f"{'  <- default' if row['shape'] == default and row['element'] == 'hex' else ''}")
    if choice is not None:
        print(f"budgeted choice (most accurate >= {floor:.0f} steps/CPU s): {tuple(choice['shape'])}")
    reference_nodes = make_env(REFERENCE).mesh.n_nodes
    write_json(Path(args.output), dict(
        env_id=ENV_ID, cases={name: list(value) for name, value in CASES.items()}, reference_shape=list(REFERENCE),
        reference_nodes=reference_nodes, reference_converged=bool(reference.converged.all()),
        reference_tet_converged=bool(references["tet"].converged.all()), reference_gap_tet_vs_hex=reference_gap,
        reference_converged_cases=[name for name, ok in zip(CASES, reference.converged) if ok],
        reference_values=dict(force=reference.force.tolist(), tumour_displacement=(reference.target - reference.target_rest).tolist(),
                              volume=reference.volume.tolist()),
        error_definition=("max over the cases of |q - q_ref| / max |q_ref|; q = tool force (3,) N, tumour displacement "
                          "from rest (3,) m, relative volume change; reference = the same mass-spring model and scene on "
                          "the finest voxel grid, of the same elements (errors_against_*: of the other elements)"),
        speed_floor=floor, issue_floor=SPEED_FLOOR, speed_rounds=0 if args.no_speed else args.rounds,
        budget_choice=None if choice is None else choice["shape"], env_default=default,
        command="python -m benchmarks.organ_accuracy" + (f" --rounds {args.rounds}" if args.rounds != 3 else "")
                + (" --no-speed" if args.no_speed else ""),
        results=rows))


if __name__ == "__main__":
    main()
