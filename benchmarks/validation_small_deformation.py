"""Validation lab, small deformation (``python -m benchmarks.validation --only 1 2 3 4 5 7``): the
measured E and nu (Fig. 1), position errors in elongation (Fig. 2), shear (Fig. 3), flexion of the
cantilever (Fig. 4), volume under compression and indentation (Fig. 5) and non-cubic elements
(Fig. 7), each mass-spring variant against FEM."""

from __future__ import annotations

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sim_core import HexMesh  # noqa: E402
from sim_core.experiments import elongation, flexion, indentation, position_errors, shear  # noqa: E402
from sim_core.models.laws import baudet_shear_ratio  # noqa: E402
from sim_core.models.model import MAX_SHEAR_ERROR, baudet_stiffness  # noqa: E402
from benchmarks.validation_common import (  # noqa: E402
    CANTILEVER, E0, FEM, HYPER, INDENTER, MSS, NUS, STYLE, SUMMARY, fem_errors, finish_grid, plot_errors, rows_of,
    run_model, save, write_csv)


# -- Fig. 1: measured E and nu against strain ------------------------------------------------
ELONGATION_STRAINS = (-0.30, -0.25, -0.20, -0.15, -0.10, -0.05, -0.02, -0.01,
                      0.01, 0.02, 0.05, 0.10, 0.15, 0.20, 0.25, 0.30)


def figure_moduli():
    rows = []
    for nu in NUS:
        for label in (*MSS, *FEM):
            for strain in ELONGATION_STRAINS:
                r = run_model(elongation, label, shape=(4, 4, 4), spacing=0.1, young_modulus=E0,
                              poisson_ratio=nu, strain=strain)
                rows.append(dict(nu=nu, model=label, strain=strain, young_modulus=r.young_modulus,
                                 poisson_ratio=r.poisson_ratio, converged=r.converged))
    write_csv("validation_1_moduli", rows)
    # the homogeneous branch does not depend on the block size: check against the report's block
    check = []
    for label in ("baudet", "fem-neohookean"):
        small = run_model(elongation, label, shape=(4, 4, 4), spacing=0.1, young_modulus=E0, poisson_ratio=0.3, strain=0.1)
        large = run_model(elongation, label, shape=(10, 10, 10), spacing=0.1, young_modulus=E0, poisson_ratio=0.3, strain=0.1)
        check.append(max(abs(small.young_modulus / large.young_modulus - 1), abs(small.poisson_ratio - large.poisson_ratio)))

    fig, axes = plt.subplots(2, len(NUS), figsize=(4.0 * len(NUS), 7.5), sharex=True)
    for column, nu in enumerate(NUS):
        for label in (*MSS, *FEM):
            data = [r for r in rows if r["nu"] == nu and r["model"] == label]
            strain = np.array([r["strain"] for r in data]) * 100
            for row, key, scale in ((0, "young_modulus", E0), (1, "poisson_ratio", 1.0)):
                values = np.array([r[key] for r in data]) / scale
                for side in (strain < 0, strain > 0):
                    axes[row, column].plot(strain[side], values[side], markersize=4, **STYLE[label],
                                           label=label if side[-1] else None)
        axes[0, column].axhline(1.0, color="green", linewidth=0.8)
        axes[1, column].axhline(nu, color="green", linewidth=0.8)
        axes[0, column].set_title(f"nu = {nu}")
        axes[1, column].set_xlabel("imposed strain (%)")
    finish_grid(fig, axes, ("measured E / E", "measured nu"),
                "Fig. 1 - elongation/compression of a block (4x4x4; homogeneous branch): measured E and nu "
                "(green: imposed)", "validation_1_moduli")

    def worst(label, limit, key):
        data = [r for r in rows if r["model"] == label and abs(r["strain"]) <= limit + 1e-12]
        if key == "young_modulus":
            return max(abs(r[key] / E0 - 1) for r in data)
        return max(abs(r[key] - r["nu"]) for r in data)

    table = {label: {f"{int(limit * 100)}%": dict(E_rel_err=worst(label, limit, "young_modulus"),
                                                   nu_abs_err=worst(label, limit, "poisson_ratio"))
                     for limit in (0.01, 0.05, 0.10, 0.30)} for label in (*MSS, *FEM)}
    at = {label: next(r["poisson_ratio"] for r in rows if r["model"] == label and r["nu"] == 0.4 and r["strain"] == 0.01)
          for label in MSS}
    SUMMARY["1_moduli"] = dict(
        headline="nu = 0.4 at 1% strain measures " + ", ".join(f"{k}: {v:.3f}" for k, v in at.items()),
        worst_over_nu_and_strain_up_to=table, block_size_check_max_difference=max(check))


# -- Fig. 2: position errors in elongation ------------------------------------------------------
def figure_elongation_errors():
    strains = (-0.20, -0.10, -0.05, -0.01, 0.01, 0.05, 0.10, 0.20, 0.30)
    nu = 0.3
    rows = []
    for strain in strains:
        runs = {label: run_model(elongation, label, shape=(6, 6, 6), spacing=1 / 6, young_modulus=E0,
                                 poisson_ratio=nu, strain=strain) for label in (*MSS, *FEM)}
        for label in (*MSS, "fem-linear"):
            for reference in FEM:
                if label == reference:
                    continue
                e_dm, e_max = position_errors(runs[label], runs[reference])
                rows.append(dict(strain=strain, model=label, reference=reference, e_dm=e_dm, e_max=e_max))
    write_csv("validation_2_elongation_errors", rows)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for ax, reference in zip(axes, FEM):
        for label in (*MSS, "fem-linear"):
            data = [r for r in rows if r["model"] == label and r["reference"] == reference]
            if not data:
                continue
            x = np.array([r["strain"] for r in data]) * 100
            plot_errors(ax, x, [r["e_dm"] for r in data], [r["e_max"] for r in data], label, markersize=4)
        ax.set_title(f"against {reference}")
        ax.set_xlabel("imposed strain (%)")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("position error (% of largest FEM displacement)")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Fig. 2 - elongation position errors, 6x6x6 block, nu = {nu} (report Fig. 14)")
    save(fig, "validation_2_elongation_errors")
    pick = {(r["model"], r["reference"]): r for r in rows if r["strain"] == 0.10}
    SUMMARY["2_elongation_errors"] = dict(
        headline=(f"10% strain, %e_dm against fem-neohookean: baudet {pick[('baudet', 'fem-neohookean')]['e_dm']:.2f}, "
                  f"baudet-hyperelastic {pick[('baudet-hyperelastic', 'fem-neohookean')]['e_dm']:.2g}, "
                  f"baudet-original {pick[('baudet-original', 'fem-neohookean')]['e_dm']:.2f}, "
                  f"fem-linear {pick[('fem-linear', 'fem-neohookean')]['e_dm']:.2f}"),
        at_10_percent={f"{m} vs {ref}": dict(e_dm=r["e_dm"], e_max=r["e_max"]) for (m, ref), r in pick.items()})


# -- Fig. 3: shear -------------------------------------------------------------------------------
SHEAR_ANGLES = (1.0, 2.0, 5.0, 10.0, 15.0, 20.0)


def figure_shear():
    nu = 0.3
    g0 = E0 / (2 * (1 + nu))
    rows = []
    for angle in SHEAR_ANGLES:
        runs = {label: run_model(shear, label, shape=(10, 10, 10), spacing=0.1, young_modulus=E0,
                                 poisson_ratio=nu, angle_deg=angle) for label in (*MSS, *FEM)}
        for label, result in runs.items():
            rows.append(dict(angle_deg=angle, model=label, shear_modulus=result.shear_modulus,
                             converged=result.converged, **fem_errors(label, runs)))
    write_csv("validation_3_shear", rows)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    for label in (*MSS, *FEM):
        data = [r for r in rows if r["model"] == label]
        angle = [r["angle_deg"] for r in data]
        axes[0].plot(angle, [r["shear_modulus"] / g0 for r in data], markersize=4, **STYLE[label], label=label)
        for ax, reference in zip(axes[1:], FEM):
            if label == reference:
                continue
            plot_errors(ax, angle, [r[f"e_dm_vs_{reference}"] for r in data], [r[f"e_max_vs_{reference}"] for r in data],
                        label)
    axes[0].axhline(1.0, color="green", linewidth=0.8)
    axes[0].set_ylabel("measured G / G")
    axes[0].legend(fontsize=7)
    for ax, reference in zip(axes[1:], FEM):
        ax.set_title(f"position error against {reference}")
        ax.axhspan(0, 2, color="green", alpha=0.06)
        ax.set_yscale("log")
    axes[1].legend(fontsize=6)
    for ax in axes:
        ax.set_xlabel("shear angle (deg)")
        ax.grid(alpha=0.3)
    fig.suptitle(f"Fig. 3 - simple shear of the 10x10x10 block, nu = {nu} (report Fig. 15); green band: floor 2%")
    save(fig, "validation_3_shear")
    baudet, hyper = rows_of(rows, "baudet", "baudet-hyperelastic")
    within = [r for r in baudet if 2 <= r["angle_deg"] <= 10]
    SUMMARY["3_shear"] = dict(
        headline=(f"baudet, 2-10 deg: worst %e_dm {max(r['e_dm_vs_fem-linear'] for r in within):.2f} "
                  f"(fem-linear), {max(r['e_dm_vs_fem-neohookean'] for r in within):.2f} (fem-neohookean); "
                  f"G/G0 at 20 deg {baudet[-1]['shear_modulus'] / g0:.3f} vs neo-Hookean "
                  f"{[r for r in rows if r['model'] == 'fem-neohookean'][-1]['shear_modulus'] / g0:.3f}; baudet-hyperelastic: "
                  f"worst %e_dm {max(r['e_dm_vs_fem-neohookean'] for r in hyper if 2 <= r['angle_deg'] <= 10):.2f} "
                  f"(fem-neohookean), G/G0 at 20 deg {hyper[-1]['shear_modulus'] / g0:.3f}"),
        rows=[{k: r[k] for k in ("angle_deg", "model", "shear_modulus", "e_dm_vs_fem-linear", "e_dm_vs_fem-neohookean",
                                 "e_max_vs_fem-neohookean")} for r in rows])


# -- Fig. 4: flexion -----------------------------------------------------------------------------
GRAVITIES = (0.01, 0.02, 0.04, 0.08, 0.15, 0.25, 0.35, 0.45, 0.55)


def figure_flexion():
    rows, kept = [], {}
    for gravity in GRAVITIES:
        runs = {label: run_model(flexion, label, gravity=gravity, **CANTILEVER) for label in (*MSS, *FEM)}
        kept[gravity] = runs
        for label, result in runs.items():
            rows.append(dict(gravity=gravity, model=label, tip_deflection=result.tip_deflection,
                             converged=result.converged, neo_tip_over_length=-runs["fem-neohookean"].tip_deflection / 1.0,
                             **fem_errors(label, runs)))
    write_csv("validation_4_flexion", rows)
    fig = plt.figure(figsize=(16, 9))
    grid = fig.add_gridspec(2, 2)
    for column, gravity in enumerate((0.04, 0.45)):
        ax = fig.add_subplot(grid[0, column])
        runs = kept[gravity]
        rest = runs["baudet"].rest_positions
        front = np.isclose(rest[:, 2], 0.0)  # the z = 0 side face, seen along z
        ax.plot(rest[front, 0], rest[front, 1], ".", color="0.8", label="rest")
        ax.plot(*runs["fem-neohookean"].positions[front, :2].T, "o", color="gold", markersize=7, label="fem-neohookean")
        ax.plot(*runs["fem-linear"].positions[front, :2].T, "s", mfc="none", color="0.5", markersize=5, label="fem-linear")
        ax.plot(*runs["baudet"].positions[front, :2].T, ".", color="red", markersize=5, label="baudet")
        ax.plot(*runs["baudet-hyperelastic"].positions[front, :2].T, "x", color="tab:green", markersize=5,
                label="baudet-hyperelastic")
        e_dm = position_errors(runs["baudet"], runs["fem-neohookean"])[0]
        ax.set_title(f"g = {gravity} m/s^2: neo-Hookean tip {-runs['fem-neohookean'].tip_deflection * 100:.1f}% of L, "
                     f"baudet %e_dm {e_dm:.2f}")
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(fontsize=7, loc="lower left")
    for column, reference in enumerate(FEM):
        ax = fig.add_subplot(grid[1, column])
        for label in (*MSS, "fem-linear"):
            if label == reference:
                continue
            data = [r for r in rows if r["model"] == label]
            x = [r["neo_tip_over_length"] * 100 for r in data]
            plot_errors(ax, x, [r[f"e_dm_vs_{reference}"] for r in data], [r[f"e_max_vs_{reference}"] for r in data],
                        label)
        ax.axvline(5, color="green", linewidth=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("neo-Hookean tip deflection (% of the 1 m length)")
        ax.set_ylabel(f"position error against {reference} (%)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6)
    fig.suptitle("Fig. 4 - 10x5x4 cantilever of 0.1 m cubes under gravity (E = 10 kPa, nu = 0.3, rho = 1500) "
                 "(report Fig. 16-17); green: 5% of L")
    save(fig, "validation_4_flexion")
    baudet, hyper = rows_of(rows, "baudet", "baudet-hyperelastic")
    linear_regime = [r for r in baudet if r["neo_tip_over_length"] < 0.05]
    SUMMARY["4_flexion"] = dict(
        headline=(f"baudet against fem-neohookean: %e_dm <= {max(r['e_dm_vs_fem-neohookean'] for r in linear_regime):.2f} "
                  f"below 5% tip deflection, {baudet[-2]['e_dm_vs_fem-neohookean']:.2f} at "
                  f"{baudet[-2]['neo_tip_over_length'] * 100:.0f}% (g = {baudet[-2]['gravity']}), "
                  f"{baudet[-1]['e_dm_vs_fem-neohookean']:.2f} at {baudet[-1]['neo_tip_over_length'] * 100:.0f}%; "
                  f"baudet-hyperelastic <= {max(r['e_dm_vs_fem-neohookean'] for r in hyper if r['neo_tip_over_length'] < 0.05):.2f}, "
                  f"{hyper[-2]['e_dm_vs_fem-neohookean']:.2f}, {hyper[-1]['e_dm_vs_fem-neohookean']:.2f}"),
        rows=[{k: r[k] for k in ("gravity", "model", "tip_deflection", "neo_tip_over_length", "e_dm_vs_fem-neohookean",
                                 "e_max_vs_fem-neohookean", "e_dm_vs_fem-linear", "converged")} for r in rows])


# -- Fig. 5: volume under compression and indentation ------------------------------------------
INDENT_DEPTHS = (0.05, 0.10, 0.15, 0.20, 0.25, 0.30)
#: hourglass control of every mass-spring curve of the indentation panels (the environments' default)
INDENT_ALPHA = 0.5


def figure_volume():
    strains = (-0.05, -0.10, -0.15, -0.20, -0.25, -0.30)
    nus = (0.3, 0.45, 0.49)
    mesh = HexMesh.block((4, 4, 4), 0.1)
    rest = mesh.element_volumes().sum()
    variants = {"baudet, no volume forces": dict(model="baudet", volume_conservation=False),
                "baudet (volume forces)": dict(model="baudet"),
                "baudet, volume_stiffness = 10": dict(model="baudet", volume_stiffness=10.0),
                "baudet, volume_stiffness = 100": dict(model="baudet", volume_stiffness=100.0),
                "baudet-original": dict(model="baudet-original"),
                "baudet-hyperelastic": dict(model="baudet-hyperelastic"),
                "fem-neohookean": dict(model="fem-neohookean")}
    rows = []
    for nu in nus:
        for label, options in variants.items():
            for strain in strains:
                r = elongation((4, 4, 4), 0.1, E0, nu, strain=strain, load_steps=4, **options)
                rows.append(dict(case="compression", nu=nu, model=label, load=strain, converged=r.converged,
                                 young_modulus=r.young_modulus, lowest_eigenvalue=None,
                                 relative_volume_change=mesh.element_volumes(r.positions).sum() / rest - 1))
    small = {v: elongation((4, 4, 4), 0.1, E0, 0.45, strain=0.01, volume_conservation=v).young_modulus for v in (False, True)}
    small[100] = elongation((4, 4, 4), 0.1, E0, 0.45, strain=0.01, volume_stiffness=100.0).young_modulus
    # indentation by a frictionless flat tool (only the vertical component of the patch imposed)
    indent_variants = {label: options for label, options in variants.items() if label != "baudet, volume_stiffness = 10"}
    for nu in nus:
        for label, options in indent_variants.items():
            # the new model refuses hourglass control (its springs resist the hourglass modes)
            extra = {} if label in ("fem-neohookean", "baudet-hyperelastic") else dict(hourglass_control=INDENT_ALPHA)
            for depth in INDENT_DEPTHS:
                r = indentation(**INDENTER, poisson_ratio=nu, depth=depth, check_stability=True, **options, **extra)
                rows.append(dict(case="indentation", nu=nu, model=label, load=depth, converged=r.converged,
                                 young_modulus=None, lowest_eigenvalue=r.lowest_eigenvalue,
                                 relative_volume_change=r.relative_volume_change))
    write_csv("validation_5_volume", rows)
    fig, axes = plt.subplots(2, 3, figsize=(15, 9.5), sharey="row")
    colors = {"baudet, no volume forces": "tab:cyan", "baudet (volume forces)": "tab:blue", "baudet-original": "tab:orange",
              "baudet, volume_stiffness = 10": "tab:purple", "baudet, volume_stiffness = 100": "tab:green",
              "baudet-hyperelastic": "tab:olive", "fem-neohookean": "black"}
    for row, case in enumerate(("compression", "indentation")):
        for ax, nu in zip(axes[row], nus):
            for label in variants:
                data = [r for r in rows if r["case"] == case and r["nu"] == nu and r["model"] == label]
                if not data:
                    continue
                x = [abs(r["load"]) * 100 for r in data]
                y = [r["relative_volume_change"] * 100 for r in data]
                ax.plot(x, y, "o-", color=colors[label], markersize=4, label=label)
                for r, xi, yi in zip(data, x, y):
                    if r["lowest_eigenvalue"] is not None and r["lowest_eigenvalue"] < 0:
                        ax.plot(xi, yi, "o", mfc="none", color="red", markersize=10)
                    if not r["converged"]:
                        ax.plot(xi, yi, "kx", markersize=10)
            ax.set_title(f"{case}, nu = {nu}")
            ax.set_xlabel("compression (%)" if case == "compression" else "indentation depth (% of block height)")
            ax.grid(alpha=0.3)
        axes[row, 0].set_ylabel("relative volume change dV/V0 (%)")
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].plot([], [], "o", mfc="none", color="red", label="unstable equilibrium (saddle)")
    axes[1, 0].legend(fontsize=8)
    fig.suptitle("Fig. 5 - volume change. Top: uniaxial compression (4x4x4 block, lateral faces free). Bottom: "
                 f"frictionless 3x3-node tool pressed into a 6x6x6 block, bottom fixed; mass-spring curves with "
                 f"hourglass_control = {INDENT_ALPHA} (baudet-hyperelastic: none, it refuses it)")
    save(fig, "validation_5_volume")
    pick = {r["model"]: r["relative_volume_change"] for r in rows
            if r["case"] == "compression" and r["nu"] == 0.45 and r["load"] == -0.2}
    dent = {r["model"]: r for r in rows if r["case"] == "indentation" and r["nu"] == 0.45 and r["load"] == 0.2}
    stable_to = {nu: max([0.0] + [r["load"] for r in rows if r["case"] == "indentation" and r["nu"] == nu
                                  and r["model"] == "baudet (volume forces)" and r["lowest_eigenvalue"] >= 0])
                 for nu in nus}
    stable_to_100 = {nu: max([0.0] + [r["load"] for r in rows if r["case"] == "indentation" and r["nu"] == nu
                                      and r["model"] == "baudet, volume_stiffness = 100" and r["lowest_eigenvalue"] >= 0])
                     for nu in nus}
    SUMMARY["5_volume"] = dict(
        headline=(f"nu = 0.45, 20% compression: dV/V0 = {pick['baudet, no volume forces'] * 100:.2f}% without volume "
                  f"forces, {pick['baudet (volume forces)'] * 100:.2f}% with (x100 stiffness: "
                  f"{pick['baudet, volume_stiffness = 100'] * 100:.2f}%), neo-Hookean {pick['fem-neohookean'] * 100:.2f}%; "
                  f"20% indentation (alpha = {INDENT_ALPHA}): "
                  f"{dent['baudet, no volume forces']['relative_volume_change'] * 100:.2f}% without, "
                  f"{dent['baudet (volume forces)']['relative_volume_change'] * 100:.2f}% with, "
                  f"{dent['baudet, volume_stiffness = 100']['relative_volume_change'] * 100:.2f}% at x100, neo-Hookean "
                  f"{dent['fem-neohookean']['relative_volume_change'] * 100:.2f}%, baudet-hyperelastic (no alpha) "
                  f"{dent['baudet-hyperelastic']['relative_volume_change'] * 100:.2f}%; "
                  f"E at 1% changes by {abs(small[True] / small[False] - 1) * 100:.3f}% with them, "
                  f"{abs(small[100] / small[False] - 1) * 100:.3f}% at x100"),
        at_20_percent={f"nu={r['nu']} {r['model']}": r["relative_volume_change"] for r in rows
                       if r["case"] == "compression" and r["load"] == -0.2},
        indentation_at_20_percent={f"nu={r['nu']} {r['model']}": dict(relative_volume_change=r["relative_volume_change"],
                                                                     lowest_eigenvalue=r["lowest_eigenvalue"])
                                   for r in rows if r["case"] == "indentation" and r["load"] == 0.2},
        indentation_stable_up_to_depth={"default kappa": stable_to, "kappa x100": stable_to_100},
        small_strain_E_change={"default kappa": abs(small[True] / small[False] - 1), "kappa x100": abs(small[100] / small[False] - 1)})


# -- Fig. 7: non-cubic elements ----------------------------------------------------------------
def admissible(aspect, nu):
    """True when every Baudet edge stiffness of an element (1, 1, aspect) is positive (docs/physics.md 2)."""
    edge, _ = baudet_stiffness(np.array([[1.0, 1.0, aspect]]), np.array([1.0]), np.array([nu]))
    return bool(np.all(edge > 0))


def figure_non_cubic():
    aspects = np.geomspace(0.25, 4.0, 161)
    nus = np.linspace(-0.24, 0.499, 149)
    ok = np.array([[admissible(a, nu) for a in aspects] for nu in nus])
    limits = []
    for nu in (0.0, 0.1, 0.2, 0.3, 0.4, 0.45, 0.49, 0.499):
        fine = np.geomspace(0.2, 5.0, 4001)
        good = np.array([admissible(a, nu) for a in fine])
        limits.append(dict(nu=nu, min_aspect=float(fine[good].min()), max_aspect=float(fine[good].max())))
    nu = 0.45
    g0 = E0 / (2 * (1 + nu))
    rows = []
    for label in ("baudet", HYPER):
        # baudet runs with build_model's shear bound off (max_shear_error=None): the figure shows
        # the error the bound refuses
        options = dict(max_shear_error=None) if label == "baudet" else {}
        for aspect in (0.5, 0.75, 1.0, 1.25, 1.5, 1.6, 2.0):
            for orientation, spacing in (("short/long axis along z", (0.1, 0.1, 0.1 * aspect)),
                                         ("along x", (0.1 * aspect, 0.1, 0.1))):
                if label == "baudet" and not admissible(aspect, nu):
                    continue
                mss = run_model(shear, label, shape=(6, 6, 6), spacing=spacing, young_modulus=E0, poisson_ratio=nu,
                                angle_deg=5, **options)
                fem = shear((6, 6, 6), spacing, E0, nu, angle_deg=5, model="fem-linear")
                pull = run_model(elongation, label, shape=(6, 6, 6), spacing=spacing, young_modulus=E0,
                                 poisson_ratio=nu, strain=0.001, **options)
                # docs/physics.md 2: Baudet's springs in the plane normal to z (the hyperelastic model: exact)
                predicted = baudet_shear_ratio(np.array([spacing]))[0, 2] if label == "baudet" else 1.0
                rows.append(dict(model=label, aspect=aspect, orientation=orientation,
                                 shear_ratio=mss.shear_modulus / g0,
                                 shear_ratio_to_fem=mss.shear_modulus / fem.shear_modulus,
                                 fem_shear_ratio=fem.shear_modulus / g0, predicted_shear_ratio=predicted,
                                 shear_e_dm=position_errors(mss, fem)[0], shear_e_max=position_errors(mss, fem)[1],
                                 elongation_E_ratio=pull.young_modulus / E0, elongation_nu=pull.poisson_ratio))
    write_csv("validation_7_non_cubic", rows)
    write_csv("validation_7_admissible_aspect", limits)
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    axes[0].contourf(aspects, nus, ok.astype(float), levels=[-0.5, 0.5, 1.5], colors=["#f4cccc", "#d9ead3"])
    for aspect, name in ((2.0, "1:1:2"), (4.0, "1:1:4"), (0.5, "2:2:1"), (0.25, "4:4:1")):
        axes[0].axvline(aspect, color="0.4", linewidth=0.8, linestyle=":")
        axes[0].text(aspect, 0.47, name, rotation=90, fontsize=8, ha="right", va="top")
    axes[0].set_xscale("log")
    axes[0].set_xticks([0.25, 0.5, 1, 2, 4], ["1/4", "1/2", "1", "2", "4"])
    axes[0].minorticks_off()
    axes[0].set_xlabel("aspect a of an element (1, 1, a)")
    axes[0].set_ylabel("Poisson's ratio")
    for edge in bounded_aspects():
        axes[0].axvline(edge, color="tab:blue", linewidth=1.0)
    axes[0].text(1.0, -0.2, f"baudet's default\nbound: G within\n{MAX_SHEAR_ERROR:.0%}", fontsize=7, ha="center",
                 color="tab:blue")
    axes[0].set_title("Baudet edge k > 0 (green) / <= 0 (red); blue: accepted by max_shear_error")
    for label, line in (("baudet", "-"), (HYPER, ":")):
        for orientation, marker in (("short/long axis along z", "o"), ("along x", "s")):
            data = [r for r in rows if r["orientation"] == orientation and r["model"] == label]
            a = [r["aspect"] for r in data]
            axes[1].plot(a, [r["shear_ratio_to_fem"] for r in data], marker + line,
                         label=f"{label} / fem-linear, odd axis {orientation}")
            axes[2].plot(a, [r["shear_e_dm"] for r in data], marker + line, label=f"{label} shear %e_dm, {orientation}")
            if label == "baudet":
                axes[1].plot(a, [r["predicted_shear_ratio"] for r in data], "k" + marker, mfc="none", markersize=9,
                             label=f"baudet element G_xy / G = D^2 / (3 z^2) (docs/physics.md 2), {orientation}")
                axes[2].plot(a, [abs(r["elongation_E_ratio"] - 1) * 100 for r in data], marker + "--",
                             label=f"baudet elongation at 0.1%: |E/E0 - 1| (%), {orientation}")
    axes[1].axhline(1.0, color="green", linewidth=0.8)
    axes[1].set_xlabel("aspect a")
    axes[1].set_ylabel("G_xy measured by the MSS / by fem-linear (6x6x6, 5 deg)")
    axes[1].legend(fontsize=6, loc="upper right")
    axes[2].set_xlabel("aspect a")
    axes[2].set_ylabel("error (%) against fem-linear / imposed E")
    axes[2].set_yscale("log")
    axes[2].legend(fontsize=7)
    for ax in axes[1:]:
        ax.grid(alpha=0.3)
    fig.suptitle(f"Fig. 7 - non-cubic elements (1, 1, a), nu = {nu}: where Baudet's stiffness is admissible, "
                 "and the shear/elongation errors of baudet (where it is) and baudet-hyperelastic")
    save(fig, "validation_7_non_cubic")
    baudet_rows = [r for r in rows if r["model"] == "baudet"]
    hyper_rows = [r for r in rows if r["model"] == HYPER]
    worst = max((r for r in baudet_rows if r["aspect"] != 1.0), key=lambda r: r["shear_e_dm"])
    low, high = bounded_aspects()
    SUMMARY["7_non_cubic"] = dict(
        headline=(f"1:1:2 and 1:1:4 are rejected by baudet's edge stiffness for every nu (aspect limit a < "
                  f"{limits[-1]['max_aspect']:.3f} even at nu = 0.499); accepted elements keep E, nu exact at small "
                  f"strain (worst |E/E0 - 1| at 0.1% {max(abs(r['elongation_E_ratio'] - 1) for r in baudet_rows) * 100:.3f}%) "
                  f"but shear is off: G_MSS/G_FEM = {worst['shear_ratio_to_fem']:.2f} and %e_dm {worst['shear_e_dm']:.1f} "
                  f"at a = {worst['aspect']} ({worst['orientation']}), so build_model refuses baudet elements beyond "
                  f"a in [{low:.3f}, {high:.3f}] (max_shear_error {MAX_SHEAR_ERROR:.0%}); baudet-hyperelastic on "
                  f"a = 0.5-2: G/G_FEM {min(r['shear_ratio_to_fem'] for r in hyper_rows):.3f}-"
                  f"{max(r['shear_ratio_to_fem'] for r in hyper_rows):.3f}, %e_dm at most "
                  f"{max(r['shear_e_dm'] for r in hyper_rows):.2f}"),
        limits=limits, bounded_aspects=[low, high], rows=rows)


def bounded_aspects():
    """(low, high): the aspects a of an element (1, 1, a) whose Baudet shear modulus is within
    MAX_SHEAR_ERROR in every plane (``build_model``'s default bound)."""
    fine = np.geomspace(0.5, 2.0, 200001)
    error = np.abs(baudet_shear_ratio(np.stack([np.ones_like(fine), np.ones_like(fine), fine], axis=1)) - 1).max(axis=1)
    inside = fine[error <= MAX_SHEAR_ERROR]
    return float(inside.min()), float(inside.max())
