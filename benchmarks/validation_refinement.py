"""Validation lab, Fig. 13 and 14 (``python -m benchmarks.validation --only 13 14``): objectivity
(a cantilever solved again with its clamp and loads rotated) and refinement of a 1 x 0.2 x 0.2 m
cantilever at 30% tip deflection against a 60x12x12 neo-Hookean reference."""

from __future__ import annotations

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sim_core import HexMesh, Material, build_model  # noqa: E402
from sim_core.solvers.hyperelastic import NeoHookeanFEM  # noqa: E402
from sim_core.solvers.static import solve_static  # noqa: E402
from sim_core.studies.refinement import (  # noqa: E402
    block_displacement_at, clamped_control, displacement_errors, moved_cantilever, neo_hookean_chain, rotation_matrix)
from benchmarks.validation_common import (  # noqa: E402
    E0, HYPER, RHO, SUMMARY, cantilever, model_options, saddle_rings, save, style, write_csv)


# -- Fig. 13: objectivity ---------------------------------------------------------------------------
OBJECTIVITY_ANGLES = (10.0, 30.0, 60.0, 90.0, 120.0, 180.0)
OBJECTIVITY_MODELS = ("baudet", "baudet, alpha = 1", HYPER, "fem-neohookean")
OBJECTIVITY_AXIS = (1.0, 2.0, -0.5)


def loaded_block(label, turn, offset, nu=0.45, increments=8):
    """A 6x2x2 cantilever of 0.1 m cubes, clamped at x = 0, 1 N down on each of its 9 tip nodes,
    with the whole problem moved by the rigid motion x -> Q x + c: clamp at Q X + c, loads rotated
    by Q, solved from the moved rest state Q X + c (force-free for every model here: an affine
    motion) with the load ramped in the same ``increments`` either way. An objective model lands on
    Q x + c of the unmoved answer x. Returns (mesh, positions)."""
    mesh, start, control, load = moved_cantilever(turn, offset)
    load = load @ turn.T
    if label == "fem-neohookean":
        control.force[:] = load
        result = NeoHookeanFEM(mesh, Material(E0, nu, RHO)).solve(control, initial=start, load_steps=increments)
        assert result.converged, result.message
        return mesh, result.positions
    model = build_model(mesh, Material(E0, nu, RHO), **model_options(label))
    positions = start
    for step in range(1, increments + 1):
        control.force[:] = load * step / increments
        # from the exact rest state the chord iterations of baudet-hyperelastic need more than the
        # default 40 for the first increment
        result = solve_static(model, control, initial=positions, max_iterations=100)
        assert result.converged, result.message
        positions = result.positions
    return mesh, positions


def figure_objectivity():
    offset = np.array([0.1, -0.2, 0.3])
    rows = []
    for label in OBJECTIVITY_MODELS:
        mesh, plain = loaded_block(label, np.eye(3), np.zeros(3))
        largest = float(np.linalg.norm(plain - mesh.nodes, axis=1).max())
        for angle in OBJECTIVITY_ANGLES:
            turn = rotation_matrix(OBJECTIVITY_AXIS, angle)
            _, turned = loaded_block(label, turn, offset)
            deviation = float(np.linalg.norm(turned - (plain @ turn.T + offset), axis=1).max())
            rows.append(dict(model=label, angle_deg=angle, largest_displacement=largest,
                             deviation_over_largest=deviation / largest))
    write_csv("validation_13_objectivity", rows)
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for label in OBJECTIVITY_MODELS:
        data = [r for r in rows if r["model"] == label]
        ax.plot([r["angle_deg"] for r in data], [max(r["deviation_over_largest"], 1e-16) * 100 for r in data],
                markersize=5, label=label, **style(label))
    ax.axhline(0.1, color="green", linewidth=0.8, label="floor 0.1%")
    ax.set_yscale("log")
    ax.set_xlabel(f"rotation of the boundary conditions about {OBJECTIVITY_AXIS} (deg)")
    ax.set_ylabel("max |x_rotated - (Q x + c)| / largest displacement (%)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.suptitle("Fig. 13 - objectivity: a 6x2x2 cantilever (nu = 0.45, 9 N on its tip) solved again with its clamp\n"
                 "and loads rotated (from the rotated rest state, same load increments)", fontsize=10)
    save(fig, "validation_13_objectivity")
    worst = {m: max(r["deviation_over_largest"] for r in rows if r["model"] == m) for m in OBJECTIVITY_MODELS}
    SUMMARY["13_objectivity"] = dict(
        headline="worst deviation from the rotated answer over 10-180 deg (% of the largest displacement): "
                 + ", ".join(f"{m} {v * 100:.2g}" for m, v in worst.items()),
        worst=worst, rows=rows)


# -- Fig. 14: refinement of a cantilever at 30% tip deflection ---------------------------------------
#: 1 m x 0.2 m x 0.2 m cantilever, m elements through the 0.2 m side (5m x m x m cubes), nu = 0.3
REFINE_NU, REFINE_GRAVITY = 0.3, 0.055
REFINE_LEVELS = (1, 2, 3, 4)
REFINE_REFERENCE = (2, 4, 6, 8, 12)  # the fem-neohookean chain; the last is the reference
REFINE_MSS = ("baudet", "baudet, alpha = 0.5", HYPER)


def refine_mesh(m):
    return HexMesh.block((5 * m, m, m), 0.2 / m)


def figure_refinement():
    points = refine_mesh(1).nodes  # the 6x2x2 coarsest nodes: nodes of every mesh here
    # fem-neohookean on the chain's meshes, each from the previous one: the last is the reference
    reference = dict(zip(REFINE_REFERENCE, neo_hookean_chain([refine_mesh(m) for m in REFINE_REFERENCE],
                                                            Material(E0, REFINE_NU, RHO), REFINE_GRAVITY)))
    finest = REFINE_REFERENCE[-1]
    u_ref = block_displacement_at(refine_mesh(finest), reference[finest], points)
    tip_ref = float(-u_ref[np.isclose(points[:, 0], 1.0), 1].mean())
    rows = []
    for m in REFINE_LEVELS:
        mesh = refine_mesh(m)
        runs = {}
        fem = reference.get(m)
        if fem is None:
            fem = NeoHookeanFEM(mesh, Material(E0, REFINE_NU, RHO)).solve(
                clamped_control(mesh), (0.0, -REFINE_GRAVITY, 0.0), load_steps=4).positions
        runs["fem-neohookean"] = (fem, True, None)
        for label in REFINE_MSS:
            runs[label] = cantilever(label, REFINE_GRAVITY, shape=mesh.shape, spacing=mesh.spacing.tolist(), nu=REFINE_NU)
        for label, (positions, converged, lowest) in runs.items():
            e_dm, e_max = displacement_errors(mesh, positions, u_ref, points)
            tip = np.isclose(mesh.nodes[:, 0], 1.0)
            rows.append(dict(model=label, elements_through_side=m, shape="x".join(map(str, mesh.shape)), e_dm=e_dm,
                             e_max=e_max, tip_drop=float(-(positions[tip, 1] - mesh.nodes[tip, 1]).mean()),
                             converged=converged, lowest_eigenvalue=lowest))
    chain = []
    for m in REFINE_REFERENCE:
        mesh = refine_mesh(m)
        e_dm, e_max = displacement_errors(mesh, reference[m], u_ref, points)
        tip = np.isclose(mesh.nodes[:, 0], 1.0)
        chain.append(dict(elements_through_side=m, e_dm=e_dm, e_max=e_max,
                          tip_drop=float(-(reference[m][tip, 1] - mesh.nodes[tip, 1]).mean())))
    write_csv("validation_14_refinement", rows)
    write_csv("validation_14_reference_chain", chain)
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    for label in ("fem-neohookean", *REFINE_MSS):
        data = [r for r in rows if r["model"] == label]
        x = [r["elements_through_side"] for r in data]
        axes[0].plot(x, [r["e_dm"] for r in data], markersize=5, label=label, **style(label))
        saddle_rings(axes[0], data, x, [r["e_dm"] for r in data])
        axes[1].plot(x, [r["tip_drop"] * 100 for r in data], markersize=5, label=label, **style(label))
        if label != "fem-neohookean":
            axes[2].plot(x, [r["lowest_eigenvalue"] for r in data], markersize=5, label=label, **style(label))
    axes[1].axhline(tip_ref * 100, color="green", linewidth=0.8, label=f"reference ({tip_ref * 100:.1f} cm)")
    axes[0].set_yscale("log")
    axes[0].set_ylabel(f"%e_dm against fem-neohookean 5{finest}x{finest}x{finest}".replace(f"5{finest}", f"{5 * finest}"))
    axes[1].set_ylabel("tip drop (cm)")
    axes[2].set_ylabel("lowest tangent eigenvalue at the equilibrium (N/m)")
    axes[2].axhline(0.0, color="red", linewidth=0.8)
    axes[2].set_yscale("symlog", linthresh=1e-2)
    for ax in axes:
        ax.set_xlabel("elements through the 0.2 m side (mesh 5m x m x m)")
        ax.set_xticks(list(REFINE_LEVELS))
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle(f"Fig. 14 - refinement: 1 x 0.2 x 0.2 m cantilever, nu = {REFINE_NU}, g = {REFINE_GRAVITY} m/s^2 "
                 f"(tip drop {tip_ref * 100:.0f}% of L); error at the 54 nodes of the coarsest mesh; red ring: saddle")
    save(fig, "validation_14_refinement")
    check = next(c for c in chain if c["elements_through_side"] == REFINE_REFERENCE[-2])
    by = {label: [r for r in rows if r["model"] == label] for label in ("fem-neohookean", *REFINE_MSS)}
    SUMMARY["14_refinement"] = dict(
        headline=(f"%e_dm against fem-neohookean {5 * finest}x{finest}x{finest} at m = {list(REFINE_LEVELS)}: "
                  + "; ".join(f"{m} " + ", ".join(f"{r['e_dm']:.2f}" for r in data)
                              + (f" (saddle at m = {[r['elements_through_side'] for r in data if (r['lowest_eigenvalue'] or 0) < 0]})"
                                 if any((r["lowest_eigenvalue"] or 0) < 0 for r in data) else "")
                              for m, data in by.items())
                  + f"; reference check: the {5 * check['elements_through_side']}x{check['elements_through_side']}x"
                  f"{check['elements_through_side']} FEM differs by {check['e_dm']:.2f}"),
        reference=dict(mesh=f"{5 * finest}x{finest}x{finest}", tip_drop=tip_ref, nu=REFINE_NU, gravity=REFINE_GRAVITY),
        reference_chain=chain,
        monotonic={label: all(b["e_dm"] < a["e_dm"] for a, b in zip(data, data[1:])) for label, data in by.items()},
        stable={label: all((r["lowest_eigenvalue"] or 0) > 0 for r in data) for label, data in by.items() if label != "fem-neohookean"},
        rows=rows)
