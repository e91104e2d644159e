"""What the smoothed strain costs on tetrahedra: the same block stepped with smoothing="edge-node"
(the default) and "none" (each tetrahedron's own strain), side by side in one run.

    python -m benchmarks.tet_cost        # about a minute on 2 cores

Writes benchmarks/results/tet_cost.json: per model and smoothing, the median wall time of a force
pass and of an implicit Euler step (20 ms, under gravity, clamped at x = 0, after warm-up) of a
16 x 8 x 8-cube block (6144 tetrahedra), per tetrahedron, and the ratios edge-node / none, and
the 3 x 3 blocks of L in the step's node-block factor (its orderings, and MMD's alone). Medians
of alternating repeats (the machine is shared; the 1-minute load average at the end is recorded).
SI units: seconds.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from sim_core import Material, TetMesh, build_model, make_solver
from sim_core.files import atomic_write
from sim_core.models.forces import internal_forces
from sim_core.models.sparse import NODE_ORDERINGS, block_structure
from sim_core.solvers.preconditioners import free_structure

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "tet_cost.json"
SHAPE, SPACING = (16, 8, 8), 0.01  # m
DT, REPEATS, STEPS = 0.02, 7, 10


def setup(model_name, smoothing):
    mesh = TetMesh.block(SHAPE, SPACING)
    model = build_model(mesh, Material(1e4, 0.45, 1000.0), model=model_name, gravity=(0, -9.81, 0),
                        smoothing=smoothing)
    control = model.new_control()
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    control.impose(clamp, mesh.nodes[clamp])
    solver = make_solver("implicit", model)
    return model, control, solver


def time_steps(model, control, solver):
    state, scratch = model.new_state(), model.new_state()
    start = time.perf_counter()
    for _ in range(STEPS):
        solver.step(state, scratch, control, DT)
        state, scratch = scratch, state
    return (time.perf_counter() - start) / STEPS


def time_forces(model):
    positions = model.rest_positions + 1e-4
    start = time.perf_counter()
    for _ in range(20):
        internal_forces(model, positions)
    return (time.perf_counter() - start) / 20


def factor_blocks(model, orderings):
    """The 3 x 3 blocks of L in the node-block factor of the block's free nodes (all but x = 0)
    under the node orderings ``orderings`` (``sparse.block_structure`` keeps the cheapest)."""
    free = np.repeat(~np.isclose(model.rest_positions[:, 0], 0.0), 3)
    node_dofs = np.flatnonzero(free)
    whole = free_structure(model, node_dofs)
    pattern = sp.csc_matrix((np.ones(len(whole.take)), whole.indices, whole.indptr), shape=whole.shape)
    return len(block_structure(pattern, node_dofs, orderings)[4])


def main():
    rows = []
    for model_name in ("baudet", "baudet-hyperelastic"):
        setups = {smoothing: setup(model_name, smoothing) for smoothing in ("edge-node", "none")}
        for model, control, solver in setups.values():  # compile and warm every cache first
            time_steps(model, control, solver), time_forces(model)
        samples = {smoothing: {"step": [], "forces": []} for smoothing in setups}
        for _ in range(REPEATS):  # alternate, so that both see the same load
            for smoothing, (model, control, solver) in setups.items():
                samples[smoothing]["step"].append(time_steps(*setups[smoothing]))
                samples[smoothing]["forces"].append(time_forces(model))
        n_elements = setups["none"][0].mesh.n_elements
        row = dict(model=model_name, elements=n_elements, nodes=setups["none"][0].n_nodes)
        for smoothing, times in samples.items():
            for what, values in times.items():
                row[f"{what}_seconds_{smoothing}"] = float(np.median(values))
                row[f"{what}_seconds_per_element_{smoothing}"] = float(np.median(values)) / n_elements
        for smoothing, (model, _, _) in setups.items():
            row[f"factor_l_blocks_{smoothing}"] = factor_blocks(model, model.node_orderings)
            row[f"factor_l_blocks_mmd_{smoothing}"] = factor_blocks(model, NODE_ORDERINGS[:1])
        for what in ("step", "forces"):
            row[f"{what}_ratio"] = row[f"{what}_seconds_edge-node"] / row[f"{what}_seconds_none"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    atomic_write(RESULTS, json.dumps(dict(command="python -m benchmarks.tet_cost", shape=SHAPE, spacing=SPACING,
                                          dt=DT, repeats=REPEATS, steps=STEPS, rows=rows,
                                          load_average=os.getloadavg()[0], cores=os.cpu_count()), indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
