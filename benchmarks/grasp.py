"""The grasper's force against solve_static, and its slip, in sim_core and in Retraction.

Usage: python -m benchmarks.grasp [--output benchmarks/results/grasp.json]

1. A 5-node patch on the top face of a 2 x 1 x 2 cm block (5 kPa, nu 0.45, gravity, the bottom face
   fixed) pulled up by implicit steps (10 ramp steps of 20 ms, then 40 held) by 0.5 to 3 mm, in one
   ``ModelStack`` of one world per lift: the grasp force against the reaction of ``solve_static``
   with the same nodes imposed at the same places (relative error of the vector).
2. The same patch pulled 1 cm up in 10 steps under grasp limits of 0.1 to 1 N: the nodes held and
   the grasp force (N) after each step's slip.
3. Retraction-v0 pulled straight up at full speed (action (0, 1, 0)) with ``grasp_force_limit`` of
   0.02, 0.05 and 0.2 N and the default: the grasped nodes, |tool_forces| (N) and ``reward_grasp``
   per step.

Results are written to ``--output`` (JSON, replaced atomically).
"""

import argparse
import os
import platform
import time

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the ids)
from sim_core import Control, HexMesh, Material, ModelStack, State, build_model, make_solver, solve_static
from sim_core.models.forces import internal_forces
from sim_core.solvers.grasp import Grasper
from training.common import write_json

SPACING = 0.005


def grasped_block():
    """A 2 x 1 x 2 cm block of 5 kPa tissue under gravity on a fixed bottom face, at rest: (model, base
    control, start positions (n, 3) m, top-face mask (n,), the top face's centre (3,) m)."""
    mesh = HexMesh.block((4, 2, 4), SPACING)
    model = build_model(mesh, Material(5e3, 0.45, 1060), gravity=(0, -9.81, 0))
    nodes = mesh.nodes
    bottom = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))
    base = model.new_control().impose(bottom, nodes[bottom])
    start = solve_static(model, base).positions
    top = np.isclose(nodes[:, 1], nodes[:, 1].max())
    return model, base, start, top, nodes[top].mean(axis=0)


def net_forces(model, positions, velocities):
    """The net nodal forces (tissue and gravity, N) of one world."""
    return internal_forces(model, positions, velocities) + model.gravity_force


def quasi_static(lifts=(0.0005, 0.001, 0.002, 0.003), ramp=10, hold=40):
    model, base, start, top, centre = grasped_block()
    count = len(lifts)
    grasper = Grasper(1.01 * SPACING)
    positions = np.repeat(start[None], count, axis=0)
    jaws = np.repeat(centre[None], count, axis=0)
    held, offsets = grasper.close(positions, jaws, top)
    solver = make_solver("implicit", ModelStack(model, count))
    state, out = State(positions.copy(), np.zeros_like(positions)), State(positions.copy(), np.zeros_like(positions))
    fixed0, target0 = np.repeat(base.fixed[None], count, axis=0), np.repeat(base.target[None], count, axis=0)
    for step in range(ramp + hold):
        jaw = jaws + np.multiply.outer(np.asarray(lifts) * min(step + 1, ramp) / ramp, [0.0, 1.0, 0.0])
        fixed, target = grasper.control(fixed0, target0, held, offsets, jaw)
        solver.step(state, out, Control(fixed, target, np.zeros_like(target)), 0.02)
        state, out = out, state
    rows = []
    for world, lift in enumerate(lifts):
        force = grasper.force(net_forces(model, state.positions[world], state.velocities[world]), held[world])
        reference = solve_static(model, Control(fixed[world], target[world], np.zeros_like(start)), initial=start)
        expected = reference.reaction[held[world]].sum(axis=0)
        rows.append(dict(lift_m=lift, held_nodes=int(held[world].sum()), grasp_force_N=force.tolist(),
                         static_reaction_N=expected.tolist(),
                         relative_error=float(np.linalg.norm(force - expected) / np.linalg.norm(expected))))
    return rows


def slip(limits=(0.1, 0.25, 0.5, 1.0), lift=0.01, steps=12):
    model, base, start, top, centre = grasped_block()
    rows = []
    for limit in limits:
        grasper = Grasper(1.01 * SPACING, limit)
        held, offsets = grasper.close(start, centre, top)
        solver = make_solver("implicit", model)
        state, out = State(start.copy(), np.zeros_like(start)), State(start.copy(), np.zeros_like(start))
        counts, forces = [], []
        for step in range(steps):
            jaw = centre + [0.0, lift * min(step + 1, 10) / 10, 0.0]
            fixed, target = grasper.control(base.fixed, base.target, held, offsets, jaw)
            solver.step(state, out, Control(fixed, target, np.zeros_like(start)), 0.02)
            state, out = out, state
            nodal = net_forces(model, state.positions, state.velocities)
            held = grasper.slip(nodal, held)
            counts.append(int(held.sum()))
            forces.append(float(np.linalg.norm(grasper.force(nodal, held))))
        rows.append(dict(force_limit_N=limit, held_nodes=counts, grasp_force_N=forces))
    return rows


def retraction(limits=(0.02, 0.05, 0.2, None), steps=8):
    rows = []
    for limit in limits:
        env = gym.make("tissue_env/Retraction-v0", **({} if limit is None else dict(grasp_force_limit=limit)))
        _, info = env.reset(seed=0)
        infos = [info] + [env.step(np.array([0.0, 1.0, 0.0], np.float32))[4] for _ in range(steps)]
        held = [int(i["grasped_nodes"]) for i in infos]
        force = [float(np.linalg.norm(i["tool_forces"][0])) for i in infos]
        rows.append(dict(grasp_force_limit_N=env.unwrapped.episode_grasp_force_limit, grasped_nodes=held,
                         tool_force_N=force, reward_grasp=[float(i["reward_grasp"]) for i in infos],
                         max_force_while_grasped_N=max(f for f, i in zip(force, infos) if i["grasped"][0]),
                         unstable=any(bool(i["unstable"]) for i in infos)))
        env.close()
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default=os.path.join("benchmarks", "results", "grasp.json"))
    args = parser.parse_args(argv)
    started = time.time()
    result = dict(command="python -m benchmarks.grasp", machine=platform.machine(), quasi_static=quasi_static(),
                  slip=slip(), retraction=retraction())
    result["seconds"] = round(time.time() - started, 1)
    write_json(args.output, result)
    for row in result["quasi_static"]:
        print(f"lift {row['lift_m'] * 1e3:.1f} mm: grasp force vs solve_static, relative error {row['relative_error']:.2e}")
    for row in result["slip"]:
        print(f"limit {row['force_limit_N']} N: held {row['held_nodes']}, max force {max(row['grasp_force_N']):.4f} N")
    for row in result["retraction"]:
        print(f"Retraction limit {row['grasp_force_limit_N']} N: held {row['grasped_nodes']}, max force while grasped "
              f"{row['max_force_while_grasped_N']:.4f} N")


if __name__ == "__main__":
    main()
