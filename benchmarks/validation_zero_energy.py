"""Validation lab, Fig. 6 (``python -m benchmarks.validation --only 6``): the zero-energy modes of
Baudet's model, what hourglass control alpha does to them, and whether a tool pressed, lifted or
dragged on the 6x6x6 indentation block excites them (stability onsets by bisection, settling by
damped dynamics)."""

from __future__ import annotations

import math

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sim_core import HexMesh, Material, build_model  # noqa: E402
from sim_core.experiments import elongation, flexion, indentation, position_errors, shear, tool_patch  # noqa: E402
from sim_core.solvers.static import solve_static, zero_energy_modes  # noqa: E402
from benchmarks.validation_common import (  # noqa: E402
    CANTILEVER, E0, INDENTER, RHO, SUMMARY, save, write_csv)


# -- Fig. 6: zero-energy modes and hourglass control --------------------------------------------
def rigid_modes(nodes):
    """(3N, 6) the 3 translations and 3 infinitesimal rotations of a node set."""
    centred = nodes - nodes.mean(axis=0)
    modes = []
    for axis in range(3):
        translation = np.zeros_like(nodes)
        translation[:, axis] = 1.0
        modes.append(translation.ravel())
        rotation = np.cross(np.eye(3)[axis], centred)
        modes.append(rotation.ravel())
    return np.array(modes).T


def hourglass_shapes(mesh):
    """Count and shapes of the non-rigid zero-energy modes of a free block (baudet, nu = 0.3)."""
    model = build_model(mesh, Material(E0, 0.3, RHO))
    count, values, vectors = zero_energy_modes(model, n_modes=16)
    zero = vectors[:, :count]
    basis, _ = np.linalg.qr(rigid_modes(mesh.nodes))
    non_rigid = zero - basis @ (basis.T @ zero)
    u, s, _ = np.linalg.svd(non_rigid, full_matrices=False)
    n_hourglass = int(np.sum(s > 1e-6 * s[0]))
    return count, n_hourglass, u[:, :n_hourglass]


def compression_with_stability(strain, alpha, shape=(6, 6, 6), nu=0.45):
    """experiments.elongation's boundary conditions on a 1 m block of ``shape`` (4 load steps),
    solved with the stability check. Returns (apparent E in Pa, converged, lowest eigenvalue N/m)."""
    mesh = HexMesh.block(shape, 1.0 / shape[0])
    model = build_model(mesh, Material(E0, nu, RHO), hourglass_control=alpha)
    nodes, control = mesh.nodes, model.new_control()
    left, right = np.flatnonzero(np.isclose(nodes[:, 0], 0)), np.flatnonzero(np.isclose(nodes[:, 0], 1))
    control.impose(left, nodes[left], components=0)
    centre, top = mesh.node_index(0, shape[1] // 2, shape[2] // 2), mesh.node_index(0, shape[1] // 2, shape[2])
    control.impose([centre], nodes[centre], components=[1, 2]).impose([top], nodes[top], components=1)
    control.impose(right, nodes[right] + [strain, 0, 0], components=0)
    result = solve_static(model, control, load_steps=4, check_stability=True)
    return float(result.reaction[right, 0].sum() / strain), result.converged, result.lowest_eigenvalue


# -- Fig. 6 (continued): does a tool excite the zero-energy modes? ------------------------------
TOOL_NU = 0.45
TOOL_DEPTHS = (0.01, 0.02, 0.05, 0.10, 0.15, 0.20, 0.30)
#: glued tool moves as a fraction of the block height: lifted (y) or dragged sideways (x)
TOOL_PULLS = (("lift", 1, 0.05), ("lift", 1, 0.10), ("lift", 1, 0.20),
              ("drag", 0, 0.05), ("drag", 0, 0.10), ("drag", 0, 0.20))


def tool_row(case, load, alpha, mss, fem):
    """One CSV row: the static equilibrium and, for a saddle, where the dynamics settles."""
    row = dict(case=case, load=load, alpha=alpha, converged=mss.converged, lowest_eigenvalue=mss.lowest_eigenvalue,
               hourglass_ratio=mss.hourglass_content / fem.hourglass_content, e_dm=position_errors(mss, fem)[0],
               relative_volume_change=mss.relative_volume_change, tool_force=float(np.linalg.norm(mss.tool_force)),
               fem_tool_force=float(np.linalg.norm(fem.tool_force)), fem_lowest_eigenvalue=fem.lowest_eigenvalue,
               fem_hourglass_content=fem.hourglass_content, settled=None, settled_converged=None,
               settled_lowest_eigenvalue=None, settled_hourglass_ratio=None, settled_e_dm=None,
               settled_tool_force=None, settle_failure=mss.settle_failure)
    if mss.settled is not None:
        s = mss.settled
        row.update(settled=True, settled_converged=s.converged, settled_lowest_eigenvalue=s.lowest_eigenvalue,
                   settled_hourglass_ratio=s.hourglass_content / fem.hourglass_content,
                   settled_e_dm=position_errors(s, fem)[0], settled_tool_force=float(np.linalg.norm(s.tool_force)))
    elif mss.settle_failure is not None:
        row["settled"] = False
    return row


def stability_onset(alpha, nu, glued, limit=0.30, iterations=7):
    """Smallest indentation depth (fraction of the height) whose static equilibrium is a saddle,
    by bisection on [0, limit] (resolution limit / 2^iterations); inf when ``limit`` is stable."""
    def stable(depth):
        r = indentation(**INDENTER, poisson_ratio=nu, depth=depth, glued=glued, hourglass_control=alpha,
                        check_stability=True)
        return r.converged and r.stable

    if stable(limit):
        return math.inf
    low, high = 0.0, limit
    for _ in range(iterations):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if stable(middle) else (low, middle)
    return high


def tool_loading(alphas):
    """Rows for the indentation and pull sweeps, the stability onsets, and the side-view data."""
    rows, views = [], {}
    height = INDENTER["shape"][1] * INDENTER["spacing"]
    for depth in TOOL_DEPTHS:
        fem = indentation(**INDENTER, poisson_ratio=TOOL_NU, depth=depth, model="fem-neohookean", check_stability=True)
        for alpha in alphas:
            mss = indentation(**INDENTER, poisson_ratio=TOOL_NU, depth=depth, hourglass_control=alpha,
                              check_stability=True, settle_if_unstable=True)
            rows.append(tool_row("indentation", depth, alpha, mss, fem))
            if depth == 0.05:
                views[alpha] = mss
        if depth == 0.05:
            views["fem"] = fem
    for kind, axis, fraction in TOOL_PULLS:
        move = np.zeros(3)
        move[axis] = fraction * height
        fem = tool_patch(**INDENTER, poisson_ratio=TOOL_NU, displacement=move, model="fem-neohookean", check_stability=True)
        for alpha in alphas:
            mss = tool_patch(**INDENTER, poisson_ratio=TOOL_NU, displacement=move, hourglass_control=alpha,
                             check_stability=True, settle_if_unstable=True)
            rows.append(tool_row(kind, fraction, alpha, mss, fem))
    onsets = []
    for nu, glued in ((0.3, False), (0.45, False), (0.49, False), (0.45, True)):
        for alpha in alphas:
            onsets.append(dict(nu=nu, contact="glued" if glued else "frictionless", alpha=alpha,
                               unstable_from_depth=stability_onset(alpha, nu, glued)))
    return rows, onsets, views


def plot_tool_loading(fig, grid, rows, onsets, views, alphas):
    colors = dict(zip(alphas, ("tab:blue", "tab:purple", "tab:green")))
    # side view of the mid-plane z = Lz/2 at 5% indentation: FEM, pure model after settling, alpha = 0.5
    ax = fig.add_subplot(grid[2, 0])
    fem = views["fem"]
    rest = fem.rest_positions
    mid = np.isclose(rest[:, 2], rest[:, 2].max() / 2)
    magnify = 3.0
    shown = (("fem-neohookean", fem.positions, "black", "-"),
             ("alpha = 0, settled", (views[0.0].settled or views[0.0]).positions, colors[0.0], "-"),
             ("alpha = 0.5", views[0.5].positions, colors[0.5], "--"))
    nx, ny = INDENTER["shape"][0], INDENTER["shape"][1]
    index = np.flatnonzero(mid).reshape(ny + 1, nx + 1)  # rows: j (y), columns: i (x)
    for label, positions, color, style in shown:
        drawn = rest + magnify * (positions - rest)
        for line in list(index) + list(index.T):
            ax.plot(drawn[line, 0], drawn[line, 1], style, color=color, linewidth=1.0)
        ax.plot([], [], style, color=color, label=label)
    ax.set_aspect("equal")
    ax.set_title(f"5% frictionless indentation, nu = {TOOL_NU}: mid-plane z = Lz/2, displacements x{magnify:g}",
                 fontsize=9)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_axis_off()
    for column, (key, settled_key, ylabel) in enumerate(
            (("e_dm", "settled_e_dm", "%e_dm vs fem-neohookean"),
             ("hourglass_ratio", "settled_hourglass_ratio", "hourglass content / fem-neohookean's"))):
        ax = fig.add_subplot(grid[2, column + 1])
        for alpha in alphas:
            data = [r for r in rows if r["case"] == "indentation" and r["alpha"] == alpha]
            x = [r["load"] * 100 for r in data]
            ax.plot(x, [r[key] for r in data], "o-", color=colors[alpha], label=f"alpha = {alpha}: static solve")
            for r, xi in zip(data, x):
                if r["lowest_eigenvalue"] < 0:
                    ax.plot(xi, r[key], "o", mfc="none", color="red", markersize=12)
            moved = [(xi, r[settled_key]) for r, xi in zip(data, x) if r["settled"]]
            if moved:
                ax.plot(*zip(*moved), "s:", color=colors[alpha], mfc="white", label=f"alpha = {alpha}: after settling")
            for r, xi in zip(data, x):
                if r["settled"] is False:
                    ax.plot(xi, r[key], "kx", markersize=10)
        ax.set_xscale("log")
        ax.set_xticks([1, 2, 5, 10, 20, 30], ["1", "2", "5", "10", "20", "30"])
        ax.set_xlabel("frictionless indentation depth (% of block height)")
        ax.set_ylabel(ylabel)
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    # tool pulls: grouped markers per case
    cases = [(kind, fraction) for kind, _, fraction in TOOL_PULLS]
    for column, (key, settled_key, ylabel) in enumerate(
            (("e_dm", "settled_e_dm", "%e_dm vs fem-neohookean"),
             ("hourglass_ratio", "settled_hourglass_ratio", "hourglass content / fem-neohookean's"))):
        ax = fig.add_subplot(grid[3, column])
        for offset, alpha in zip((-0.2, 0.0, 0.2), alphas):
            for position, (kind, fraction) in enumerate(cases):
                r = next(r for r in rows if r["case"] == kind and r["load"] == fraction and r["alpha"] == alpha)
                ax.plot(position + offset, r[key], "o", color=colors[alpha],
                        label=f"alpha = {alpha}" if position == 0 else None)
                if r["lowest_eigenvalue"] < 0:
                    ax.plot(position + offset, r[key], "o", mfc="none", color="red", markersize=12)
                if r["settled"]:
                    ax.plot(position + offset, r[settled_key], "s", color=colors[alpha], mfc="white")
                    ax.plot([position + offset] * 2, [r[key], r[settled_key]], ":", color=colors[alpha])
        ax.set_xticks(range(len(cases)), [f"{kind} {fraction * 100:g}%" for kind, fraction in cases])
        ax.set_ylabel(ylabel)
        ax.set_title("glued tool lifted (y) or dragged sideways (x) by a % of the block height", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    ax = fig.add_subplot(grid[3, 2])
    groups = [(nu, contact) for nu, contact in dict.fromkeys((o["nu"], o["contact"]) for o in onsets)]
    for offset, alpha in zip((-0.25, 0.0, 0.25), alphas):
        values = [next(o["unstable_from_depth"] for o in onsets if (o["nu"], o["contact"], o["alpha"]) == (nu, contact, alpha))
                  for nu, contact in groups]
        shown_values = [min(v, 0.32) * 100 for v in values]
        ax.bar(np.arange(len(groups)) + offset, shown_values, width=0.25, color=colors[alpha], label=f"alpha = {alpha}")
        for position, value in enumerate(values):
            ax.text(position + offset, min(value, 0.32) * 100 + 0.3, ">30" if math.isinf(value) else f"{value * 100:.1f}",
                    ha="center", fontsize=7)
    ax.set_xticks(range(len(groups)), [f"nu = {nu}\n{contact}" for nu, contact in groups])
    ax.set_ylabel("indentation depth (% of height) from which\nthe static equilibrium is a saddle")
    ax.set_title("stability limit of the indentation (bisection, 6x6x6 block)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, axis="y")


def figure_zero_energy_modes():
    alphas = (0.0, 0.5, 1.0)
    mesh = HexMesh.block((2, 2, 2), 0.1)
    count, n_hourglass, shapes = hourglass_shapes(mesh)
    counts = _zero_energy_mode_counts(count, n_hourglass, alphas)
    rows = _hourglass_control_rows(alphas)
    write_csv("validation_6_zero_energy_modes", rows)
    tool_rows, onsets, views = tool_loading(alphas)
    write_csv("validation_6_tool_loading", tool_rows)
    write_csv("validation_6_stability_onset", onsets)
    fig = plt.figure(figsize=(17, 19))
    grid = fig.add_gridspec(4, 3, hspace=0.3)
    _plot_free_block_modes(fig, grid, mesh, shapes, n_hourglass)
    _plot_hourglass_control(fig, grid, rows, alphas)
    plot_tool_loading(fig, grid, tool_rows, onsets, views, alphas)
    fig.suptitle(f"Fig. 6 - zero-energy modes: {n_hourglass} non-rigid modes per free block; effect of hourglass "
                 "control alpha (x: not converged, or the dynamics inverts an element; red ring: unstable\n"
                 "equilibrium, a saddle; white squares: where damped dynamics settles from it). Rows 3-4: a 3x3-node "
                 f"tool on a 6x6x6 block of 0.1 m cubes, bottom fixed, nu = {TOOL_NU}", y=0.995)
    save(fig, "validation_6_zero_energy_modes")
    SUMMARY["6_zero_energy_modes"] = _zero_energy_summary(rows, tool_rows, onsets, counts, count, n_hourglass, alphas)


def _zero_energy_mode_counts(count, n_hourglass, alphas):
    """The zero-energy modes of the free 2x2x2 block (``count`` with the rigid ones, ``n_hourglass``
    without) and under the elongation, flexion and shear experiments' conditions, per alpha."""
    counts = dict(free_2x2x2=count, free_2x2x2_non_rigid=n_hourglass)
    for alpha in alphas:
        counts[f"elongation_10x10x10_alpha={alpha}"] = elongation(
            (10, 10, 10), 0.1, E0, 0.3, strain=0.01, count_modes=True, hourglass_control=alpha).zero_energy_modes
        counts[f"flexion_10x5x4_alpha={alpha}"] = flexion(
            **CANTILEVER, gravity=0.04, count_modes=True, hourglass_control=alpha).zero_energy_modes
    counts["shear_6x6x6_alpha=0.0"] = shear((6, 6, 6), 0.1, E0, 0.3, angle_deg=5, count_modes=True).zero_energy_modes
    return counts


def _hourglass_control_rows(alphas):
    """The effect of alpha on the curves: per alpha, %e_dm against fem-neohookean under shear (deg)
    and the cantilever's gravity (m/s^2), and the apparent E under compression, with convergence and
    the lowest eigenvalue of the equilibrium (None where not computed)."""
    rows = []
    for alpha in alphas:
        for angle in (2.0, 10.0, 20.0):
            options = dict(hourglass_control=alpha)
            mss = shear((10, 10, 10), 0.1, E0, 0.3, angle_deg=angle, **options)
            fem = shear((10, 10, 10), 0.1, E0, 0.3, angle_deg=angle, model="fem-neohookean")
            rows.append(dict(alpha=alpha, experiment="shear", load=angle, e_dm=position_errors(mss, fem)[0],
                             measured=mss.shear_modulus, converged=mss.converged, lowest_eigenvalue=None))
        for gravity in (0.04, 0.15, 0.25, 0.45):
            # same cantilever as experiments.flexion, solved here to also get the stability check
            beam = HexMesh.block(CANTILEVER["shape"], CANTILEVER["spacing"])
            model = build_model(beam, Material(E0, 0.3, RHO), gravity=(0, -gravity, 0), hourglass_control=alpha)
            control = model.new_control()
            clamp = np.flatnonzero(beam.nodes[:, 0] == 0)
            control.impose(clamp, beam.nodes[clamp])
            mss = solve_static(model, control, check_stability=True)
            fem = flexion(**CANTILEVER, gravity=gravity, model="fem-neohookean")
            rows.append(dict(alpha=alpha, experiment="flexion", load=gravity,
                             e_dm=position_errors(mss.positions, fem.positions, beam.nodes)[0],
                             measured=float((mss.positions - beam.nodes)[beam.nodes[:, 0] == 1.0, 1].mean()),
                             converged=mss.converged, lowest_eigenvalue=mss.lowest_eigenvalue))
        for strain in (-0.10, -0.20, -0.25, -0.30):
            young_modulus, converged, lowest = compression_with_stability(strain, alpha)
            rows.append(dict(alpha=alpha, experiment="compression", load=strain, e_dm=float("nan"),
                             measured=young_modulus, converged=converged, lowest_eigenvalue=lowest))
    return rows


def _plot_free_block_modes(fig, grid, mesh, shapes, n_hourglass):
    """Row 1 of Fig. 6: up to three zero-energy modes of the free 2x2x2 block over its rest edges."""
    edges = np.unique(np.sort(mesh.elements[:, np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7],
                                                         [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])].reshape(-1, 2),
                              axis=1), axis=0)
    for index in range(min(n_hourglass, 3)):
        ax = fig.add_subplot(grid[0, index], projection="3d")
        mode = shapes[:, index].reshape(-1, 3)
        moved = mesh.nodes + 0.04 * mode / np.abs(mode).max()
        for a, b in edges:
            ax.plot(*mesh.nodes[[a, b]].T, color="0.8", linewidth=0.8)
            ax.plot(*moved[[a, b]].T, color="tab:red", linewidth=1.2)
        ax.set_title(f"zero-energy mode {index + 1} of a free 2x2x2 block")
        ax.set_axis_off()


def _plot_hourglass_control(fig, grid, rows, alphas):
    """Row 2 of Fig. 6: the rows of ``_hourglass_control_rows`` per experiment, one curve per alpha
    (x: not converged; red ring: an unstable equilibrium)."""
    panels = (("shear", "shear angle (deg)", "%e_dm vs fem-neohookean"),
              ("flexion", "gravity (m/s^2)", "%e_dm vs fem-neohookean"),
              ("compression", "imposed strain", "apparent E / E, compression of a 6x6x6 block, nu = 0.45"))
    for column, (experiment, xlabel, ylabel) in enumerate(panels):
        ax = fig.add_subplot(grid[1, column])
        for alpha, color in zip(alphas, ("tab:blue", "tab:purple", "tab:green")):
            data = [r for r in rows if r["alpha"] == alpha and r["experiment"] == experiment]
            y = [r["measured"] / E0 if experiment == "compression" else r["e_dm"] for r in data]
            ax.plot([r["load"] for r in data], y, "o-", color=color, label=f"alpha = {alpha}")
            for r, value in zip(data, y):
                if not r["converged"]:
                    ax.plot(r["load"], value, "kx", markersize=10)
                if r["lowest_eigenvalue"] is not None and r["lowest_eigenvalue"] < 0:
                    ax.plot(r["load"], value, "o", mfc="none", color="red", markersize=12)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)


def _zero_energy_summary(rows, tool_rows, onsets, counts, count, n_hourglass, alphas):
    """Fig. 6's SUMMARY entry: the headlines (the tool's 5% indentation, the mode counts, the
    apparent E at -30% and the unstable cantilever loads) and the rows behind them."""
    compression = {r["alpha"]: (round(r["measured"] / E0, 3), "stable" if r["lowest_eigenvalue"] >= 0 else "unstable")
                   for r in rows if r["experiment"] == "compression" and r["load"] == -0.30}
    unstable = {alpha: [r["load"] for r in rows if r["alpha"] == alpha and r["experiment"] == "flexion"
                        and r["lowest_eigenvalue"] < 0] for alpha in alphas}
    at5 = {r["alpha"]: r for r in tool_rows if r["case"] == "indentation" and r["load"] == 0.05}
    pure = at5[0.0]
    onset = {o["alpha"]: o["unstable_from_depth"] for o in onsets if o["nu"] == TOOL_NU and o["contact"] == "frictionless"}
    tool_headline = (
        f"5% indentation, nu = {TOOL_NU}: pure model {'unstable' if pure['lowest_eigenvalue'] < 0 else 'stable'}, "
        + (f"settles with {pure['settled_hourglass_ratio']:.1f}x the FEM's hourglass content and %e_dm "
           f"{pure['settled_e_dm']:.1f} (static saddle {pure['e_dm']:.1f}); " if pure["settled"] else "")
        + f"alpha = 0.5: {'stable' if at5[0.5]['lowest_eigenvalue'] >= 0 else 'unstable'}, hourglass ratio "
        f"{at5[0.5]['hourglass_ratio']:.2f}, %e_dm {at5[0.5]['e_dm']:.1f}; frictionless indentation is a saddle from "
        + ", ".join(f"alpha {a}: {'>30' if math.isinf(v) else f'{v * 100:.1f}'}%" for a, v in onset.items()))
    return dict(
        tool_headline=tool_headline, tool_rows=tool_rows, stability_onset=onsets,
        headline=(tool_headline + "; "
                  f"{n_hourglass} non-rigid zero-energy modes per free 2x2x2 block ({count} with the rigid ones), "
                  f"{counts['elongation_10x10x10_alpha=0.0']} under the elongation conditions, 0 with alpha > 0; "
                  "apparent E/E0 at -30% (6x6x6, nu = 0.45): "
                  + ", ".join(f"alpha {a}: {v[0]} ({v[1]})" for a, v in compression.items())
                  + "; cantilever loads (m/s^2) with an unstable equilibrium: "
                  + ", ".join(f"alpha {a}: {v}" for a, v in unstable.items())),
        counts=counts, rows=rows)
