"""Validation lab, large deformation (``python -m benchmarks.validation --only 8 9 10 11 12``):
``baudet-hyperelastic`` beside ``baudet`` and the FEM laws in tension/compression to +-30% (Fig. 8),
shear to 30 degrees (Fig. 9), the cantilever to large deflection (Fig. 10), unconfined compression
near incompressibility (Fig. 11) and the zero-energy mode count of each model (Fig. 12)."""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sim_core import HexMesh, Material, build_model  # noqa: E402
from sim_core.experiments import (  # noqa: E402
    elongation, elongation_control, flexion, position_errors, shear, tool_patch_nodes)
from sim_core.solvers.fem import LinearFEM  # noqa: E402
from sim_core.solvers.hyperelastic import NeoHookeanFEM  # noqa: E402
from sim_core.models.model import MSS_MODELS as MSS_NAMES, Control  # noqa: E402
from sim_core.solvers.static import zero_energy_modes  # noqa: E402
from sim_core.studies.refinement import clamped_control  # noqa: E402
from benchmarks.validation_common import (  # noqa: E402
    CANTILEVER, E0, HYPER, LARGE, RHO, SUMMARY, cantilever, finish_grid, model_options, mss_lowest, run_model,
    saddle_rings, save, style, volume_change, write_csv)


# -- Fig. 8: elongation and compression to +-30%: stress-strain and volume ------------------------
LARGE_STRAINS = (-0.30, -0.25, -0.20, -0.15, -0.10, -0.05, 0.05, 0.10, 0.15, 0.20, 0.25, 0.30)
LARGE_NUS = (0.3, 0.45, 0.49)


def block_strain_rows(nus, labels, strains):
    """Elongation of the 4x4x4 block of 0.1 m cubes for each nu, label and strain: nominal stress
    (reaction / rest area, Pa), dV/V0, convergence and the mass-spring tangent's lowest eigenvalue
    (N/m), each row also against fem-neohookean's (one of ``labels``) at its nu and strain."""
    mesh = HexMesh.block((4, 4, 4), 0.1)
    area = 0.4 * 0.4
    rows = []
    for nu in nus:
        for label in labels:
            for strain in strains:
                r = run_model(elongation, label, shape=(4, 4, 4), spacing=0.1, young_modulus=E0, poisson_ratio=nu,
                              strain=strain)
                lowest = (mss_lowest(label, mesh, nu, elongation_control(mesh, strain), r.positions)
                          if model_options(label)["model"] in MSS_NAMES else None)
                rows.append(dict(nu=nu, model=label, strain=strain, nominal_stress=r.reaction / area,
                                 relative_volume_change=volume_change(r), converged=r.converged,
                                 lowest_eigenvalue=lowest))
    neo = {(r["nu"], r["strain"]): r for r in rows if r["model"] == "fem-neohookean"}
    for r in rows:
        ref = neo[(r["nu"], r["strain"])]
        r["stress_ratio_to_neohookean"] = r["nominal_stress"] / ref["nominal_stress"]
        r["volume_change_minus_neohookean"] = r["relative_volume_change"] - ref["relative_volume_change"]
    return rows


def plot_strain_panels(rows, nus, labels, panels, strain_sign, xlabel):
    """Two rows of panels, one column per nu: ``panels`` ((key, scale), (key, scale)) of ``rows``
    (``block_strain_rows``) against strain_sign * strain in %, saddles and failures marked."""
    fig, axes = plt.subplots(2, len(nus), figsize=(5.2 * len(nus), 8.5), sharex=True)
    for column, nu in enumerate(nus):
        for label in labels:
            data = [r for r in rows if r["nu"] == nu and r["model"] == label]
            x = [strain_sign * r["strain"] * 100 for r in data]
            for row, (key, scale) in enumerate(panels):
                y = [r[key] * scale for r in data]
                axes[row, column].plot(x, y, markersize=4, label=label, **style(label))
                saddle_rings(axes[row, column], data, x, y)
        axes[0, column].set_title(f"nu = {nu}")
        axes[1, column].set_xlabel(xlabel)
        for ax in axes[:, column]:
            ax.grid(alpha=0.3)
    return fig, axes


def figure_large_elongation():
    rows = block_strain_rows(LARGE_NUS, LARGE, LARGE_STRAINS)
    write_csv("validation_8_large_elongation", rows)
    fig, axes = plot_strain_panels(rows, LARGE_NUS, LARGE, (("nominal_stress", 1e-3), ("relative_volume_change", 100)),
                                   1, "imposed strain (%)")
    finish_grid(fig, axes, ("nominal axial stress: reaction / rest area (kPa)", "dV/V0 (%)"),
                "Fig. 8 - uniaxial tension and compression to +-30% of a 4x4x4 block, lateral faces free "
                "(red ring: the mass-spring equilibrium is a saddle)", "validation_8_large_elongation")

    def worst(label, key, limit=0.30):
        data = [r for r in rows if r["model"] == label and abs(r["strain"]) <= limit + 1e-12]
        if key == "stress":
            return max(abs(r["stress_ratio_to_neohookean"] - 1) for r in data)
        return max(abs(r["volume_change_minus_neohookean"]) for r in data)

    pick = {(r["model"], r["strain"]): r for r in rows if r["nu"] == 0.45}
    SUMMARY["8_large_elongation"] = dict(
        headline=("nu = 0.45, nominal stress / neo-Hookean at -30% and +30%: "
                  + ", ".join(f"{m} {pick[(m, -0.3)]['stress_ratio_to_neohookean']:.3f} / "
                              f"{pick[(m, 0.3)]['stress_ratio_to_neohookean']:.3f}" for m in ("baudet", HYPER, "fem-linear"))
                  + f"; worst |dV/V0 - neo-Hookean's| over nu in {list(LARGE_NUS)} and +-30%: "
                  + ", ".join(f"{m} {worst(m, 'volume') * 100:.2f} pp" for m in ("baudet", HYPER))),
        worst_stress_error={m: worst(m, "stress") for m in LARGE},
        worst_volume_error_pp={m: worst(m, "volume") * 100 for m in LARGE},
        saddles={m: [(r["nu"], r["strain"]) for r in rows if r["model"] == m and r["lowest_eigenvalue"] is not None
                     and r["lowest_eigenvalue"] < 0] for m in ("baudet", HYPER)},
        rows=rows)


# -- Fig. 9: shear to 30 degrees --------------------------------------------------------------------
LARGE_ANGLES = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)


def figure_large_shear():
    nus = (0.3, 0.45)
    rows = []
    for nu in nus:
        for angle in LARGE_ANGLES:
            runs = {}
            for label in LARGE:
                extra = {} if label == "fem-linear" else dict(load_steps=4)
                runs[label] = run_model(shear, label, shape=(10, 10, 10), spacing=0.1, young_modulus=E0,
                                        poisson_ratio=nu, angle_deg=angle, **extra)
            for label, r in runs.items():
                rows.append(dict(nu=nu, model=label, angle_deg=angle, shear_force=r.reaction,
                                 force_ratio_to_neohookean=r.reaction / runs["fem-neohookean"].reaction,
                                 e_dm_vs_neohookean=position_errors(r, runs["fem-neohookean"])[0] if label != "fem-neohookean" else 0.0,
                                 converged=r.converged))
    write_csv("validation_9_large_shear", rows)
    fig, axes = plt.subplots(3, len(nus), figsize=(6.0 * len(nus), 11.5), sharex=True)
    for column, nu in enumerate(nus):
        for label in LARGE:
            data = [r for r in rows if r["nu"] == nu and r["model"] == label]
            x = [r["angle_deg"] for r in data]
            axes[0, column].plot(x, [r["shear_force"] for r in data], markersize=4, label=label, **style(label))
            axes[1, column].plot(x, [r["force_ratio_to_neohookean"] for r in data], markersize=4, label=label, **style(label))
            if label != "fem-neohookean":
                axes[2, column].plot(x, [r["e_dm_vs_neohookean"] for r in data], markersize=4, label=label, **style(label))
        axes[0, column].set_title(f"nu = {nu}")
        axes[1, column].axhline(1.0, color="green", linewidth=0.8)
        axes[1, column].axhspan(0.9, 1.1, color="green", alpha=0.06)
        axes[2, column].set_yscale("log")
        axes[2, column].set_xlabel("shear angle (deg)")
        for ax in axes[:, column]:
            ax.grid(alpha=0.3)
    finish_grid(fig, axes, ("top-face force along x (N)", "force / fem-neohookean's (green band: +-10%)",
                            "%e_dm against fem-neohookean"),
                "Fig. 9 - simple shear of the 10x10x10 block of 0.1 m cubes to 30 degrees (bottom fixed, top moved, "
                "sides free)", "validation_9_large_shear")
    at30 = {(r["nu"], r["model"]): r for r in rows if r["angle_deg"] == 30.0}
    SUMMARY["9_large_shear"] = dict(
        headline="force / neo-Hookean at 30 deg: " + "; ".join(
            f"nu = {nu}: " + ", ".join(f"{m} {at30[(nu, m)]['force_ratio_to_neohookean']:.3f}" for m in ("baudet", HYPER, "fem-linear"))
            for nu in nus) + "; %e_dm at 30 deg, nu = 0.45: " + ", ".join(
            f"{m} {at30[(0.45, m)]['e_dm_vs_neohookean']:.2f}" for m in ("baudet", HYPER)),
        rows=rows)


# -- Fig. 10: flexion to large deflection -----------------------------------------------------------
LARGE_GRAVITIES = (0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0)
FLEXION_MSS = ("baudet", "baudet, alpha = 0.5", HYPER)


def figure_large_flexion():
    mesh = HexMesh.block(CANTILEVER["shape"], CANTILEVER["spacing"])
    tip = np.isclose(mesh.nodes[:, 0], mesh.size[0])
    length = float(mesh.size[0])
    rows, kept = [], {}
    for gravity in LARGE_GRAVITIES:
        solved = {}
        for label in ("fem-neohookean", "fem-linear"):
            r = flexion(**CANTILEVER, gravity=gravity, model=label, **({} if label == "fem-linear" else dict(load_steps=4)))
            solved[label] = (r.positions, r.converged, None)
        for label in FLEXION_MSS:
            solved[label] = cantilever(label, gravity)
        kept[gravity] = solved
        neo = solved["fem-neohookean"][0]
        for label, (positions, converged, lowest) in solved.items():
            e_dm, e_max = position_errors(positions, neo, mesh.nodes) if label != "fem-neohookean" else (0.0, 0.0)
            rows.append(dict(gravity=gravity, model=label, tip_drop=float(-(positions[tip, 1] - mesh.nodes[tip, 1]).mean()),
                             tip_drop_over_length=float(-(positions[tip, 1] - mesh.nodes[tip, 1]).mean()) / length,
                             e_dm_vs_neohookean=e_dm, e_max_vs_neohookean=e_max, converged=converged,
                             lowest_eigenvalue=lowest))
    write_csv("validation_10_large_flexion", rows)
    order = ("fem-neohookean", "fem-linear", *FLEXION_MSS)
    fig, axes = plt.subplots(1, 3, figsize=(18, 5.2))
    for label in order:
        data = [r for r in rows if r["model"] == label]
        x = [r["gravity"] for r in data]
        y = [r["tip_drop_over_length"] * 100 for r in data]
        axes[0].plot(x, y, markersize=4, label=label, **style(label))
        saddle_rings(axes[0], data, x, y)
        if label != "fem-neohookean":
            e = [r["e_dm_vs_neohookean"] for r in data]
            axes[1].plot(x, e, markersize=4, label=label, **style(label))
            saddle_rings(axes[1], data, x, e)
    axes[0].set_ylabel("tip drop (% of the 1 m length)")
    axes[1].set_ylabel("%e_dm against fem-neohookean (same nodes)")
    axes[1].set_yscale("log")
    axes[1].axhline(10, color="green", linewidth=0.8)
    for ax in axes[:2]:
        ax.set_xlabel("gravity (m/s^2)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    shown = 0.75
    ax = axes[2]
    front = np.isclose(mesh.nodes[:, 2], 0.0)
    ax.plot(mesh.nodes[front, 0], mesh.nodes[front, 1], ".", color="0.8", label="rest")
    for label, marker, color, size in (("fem-neohookean", "o", "gold", 7), (HYPER, ".", "tab:green", 6),
                                       ("baudet", "x", "tab:blue", 5)):
        positions = kept[shown][label][0]
        ax.plot(*positions[front, :2].T, marker, color=color, markersize=size, linestyle="none", label=label)
    ax.set_aspect("equal")
    ax.set_title(f"side view (face z = 0) at g = {shown} m/s^2", fontsize=9)
    ax.legend(fontsize=7, loc="lower left")
    fig.suptitle("Fig. 10 - the 10x5x4 cantilever of 0.1 m cubes (nu = 0.3) to large deflection; red ring: saddle "
                 "(lowest tangent eigenvalue < 0), x: not converged")
    save(fig, "validation_10_large_flexion")
    pick = {(r["model"], r["gravity"]): r for r in rows}
    SUMMARY["10_large_flexion"] = dict(
        headline=(f"%e_dm against fem-neohookean at g = 0.5 (tip {pick[('fem-neohookean', 0.5)]['tip_drop_over_length'] * 100:.0f}% "
                  f"of L) and g = 1.0 ({pick[('fem-neohookean', 1.0)]['tip_drop_over_length'] * 100:.0f}%): "
                  + ", ".join(f"{m} {pick[(m, 0.5)]['e_dm_vs_neohookean']:.2f} / "
                              + (f"{pick[(m, 1.0)]['e_dm_vs_neohookean']:.2f}" if pick[(m, 1.0)]["converged"] else "not converged")
                              for m in (*FLEXION_MSS, "fem-linear"))
                  + "; saddles at g = " + ", ".join(
                      f"{m}: {[r['gravity'] for r in rows if r['model'] == m and (r['lowest_eigenvalue'] or 0) < 0]}"
                      for m in FLEXION_MSS)),
        rows=rows)


# -- Fig. 11: unconfined compression near incompressibility -----------------------------------------
COMPRESSION_NUS = (0.45, 0.49, 0.499)
COMPRESSION_STRAINS = (-0.05, -0.10, -0.15, -0.20, -0.25, -0.30)
COMPRESSION_MODELS = ("baudet", "baudet, volume_stiffness = 100", HYPER, "fem-neohookean", "fem-linear")


def figure_compression():
    rows = block_strain_rows(COMPRESSION_NUS, COMPRESSION_MODELS, COMPRESSION_STRAINS)
    write_csv("validation_11_compression", rows)
    fig, axes = plot_strain_panels(rows, COMPRESSION_NUS, COMPRESSION_MODELS,
                                   (("relative_volume_change", 100), ("stress_ratio_to_neohookean", 1)), -1,
                                   "compression (%)")
    for column in range(len(COMPRESSION_NUS)):
        axes[1, column].axhspan(0.9, 1.1, color="green", alpha=0.06)
    finish_grid(fig, axes, ("dV/V0 (%)", "axial stress / fem-neohookean's (green band: +-10%)"),
                "Fig. 11 - unconfined compression of a 4x4x4 block near incompressibility (red ring: saddle)",
                "validation_11_compression")
    pick = {(r["nu"], r["model"], r["strain"]): r for r in rows}
    hyper = [r for r in rows if r["model"] == HYPER]
    SUMMARY["11_compression"] = dict(
        headline=("30% compression, dV/V0 (%): " + "; ".join(
            f"nu = {nu}: " + ", ".join(f"{m} {pick[(nu, m, -0.3)]['relative_volume_change'] * 100:.2f}"
                                       for m in ("baudet", HYPER, "fem-neohookean")) for nu in COMPRESSION_NUS)
                  + f"; {HYPER} worst |dV/V0 - neo-Hookean's| {max(abs(r['volume_change_minus_neohookean']) for r in hyper) * 100:.2g} pp, "
                  f"worst stress error {max(abs(r['stress_ratio_to_neohookean'] - 1) for r in hyper) * 100:.2g}%, "
                  f"{sum(r['lowest_eigenvalue'] < 0 for r in hyper)} saddles; baudet saddles: "
                  f"{sum(r['lowest_eigenvalue'] < 0 for r in rows if r['model'] == 'baudet')} of "
                  f"{sum(r['model'] == 'baudet' for r in rows)}"),
        rows=rows)


# -- Fig. 12: zero-energy modes of each model ------------------------------------------------------
MODE_MODELS = ("baudet", "baudet, alpha = 0.5", HYPER, "fem-linear", "fem-neohookean")


def fem_zero_modes(label, mesh, nu, control, n_modes):
    """``static.zero_energy_modes``'s count for an FEM law: the tangent at rest on the free dofs."""
    material = Material(E0, nu, RHO)
    stiffness = (LinearFEM(mesh, material).stiffness if label == "fem-linear"
                 else NeoHookeanFEM(mesh, material).tangent_stiffness(mesh.nodes))
    free = np.flatnonzero(~control.fixed.ravel())
    symmetric = stiffness.tocsr()[free][:, free]
    symmetric = 0.5 * (symmetric + symmetric.T)
    scale = float(np.mean(np.abs(symmetric.diagonal())))
    values = spla.eigsh(symmetric.tocsc(), k=min(n_modes, len(free) - 2), sigma=-1e-3 * scale, which="LM")[0]
    return int(np.sum(np.abs(values) < 1e-8 * scale))


def mode_setups():
    """(name, mesh, control, rigid motions left free) of each constraint set counted in Fig. 12."""
    setups = []
    for shape in ((2, 2, 2), (4, 4, 4)):
        mesh = HexMesh.block(shape, 0.1)
        setups.append((f"free {'x'.join(map(str, shape))}", mesh, Control.free(mesh.n_nodes), 6))
    mesh = HexMesh.block((6, 6, 6), 0.1)
    setups.append(("elongation 6x6x6", mesh, elongation_control(mesh, 0.01), 0))
    bottom, top = np.flatnonzero(np.isclose(mesh.nodes[:, 1], 0.0)), np.flatnonzero(np.isclose(mesh.nodes[:, 1], 0.6))
    setups.append(("shear 6x6x6", mesh, Control.free(mesh.n_nodes).impose(bottom, mesh.nodes[bottom])
                   .impose(top, mesh.nodes[top]), 0))
    tool = tool_patch_nodes(mesh, 3)
    setups.append(("indentation 6x6x6", mesh, Control.free(mesh.n_nodes).impose(bottom, mesh.nodes[bottom])
                   .impose(tool, mesh.nodes[tool], components=1), 0))
    beam = HexMesh.block(CANTILEVER["shape"], CANTILEVER["spacing"])
    setups.append(("flexion 10x5x4", beam, clamped_control(beam), 0))
    return setups


def figure_mode_counts():
    nu, n_modes = 0.3, 24
    rows = []
    for name, mesh, control, rigid in mode_setups():
        for label in MODE_MODELS:
            if label.startswith("fem"):
                count = fem_zero_modes(label, mesh, nu, control, n_modes)
            else:
                model = build_model(mesh, Material(E0, nu, RHO), **model_options(label))
                count = zero_energy_modes(model, control, n_modes=n_modes)[0]
            rows.append(dict(setup=name, model=label, zero_energy_modes=count, rigid_motions_free=rigid,
                             non_rigid=count - rigid, at_least=count >= n_modes - 2))
    write_csv("validation_12_mode_counts", rows)
    setups = list(dict.fromkeys(r["setup"] for r in rows))
    fig, ax = plt.subplots(figsize=(13, 4.8))
    width = 0.8 / len(MODE_MODELS)
    for index, label in enumerate(MODE_MODELS):
        counts = [next(r["non_rigid"] for r in rows if r["setup"] == s and r["model"] == label) for s in setups]
        positions = np.arange(len(setups)) + (index - (len(MODE_MODELS) - 1) / 2) * width
        ax.bar(positions, counts, width=width, color=style(label)["color"], label=label,
               hatch="//" if label == "fem-neohookean" else None, edgecolor="white")
        for position, count in zip(positions, counts):
            ax.text(position, count + 0.1, str(count), ha="center", fontsize=8)
    ax.set_xticks(range(len(setups)), setups)
    ax.set_ylabel("non-rigid zero-energy modes at rest")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.suptitle(f"Fig. 12 - zero-energy modes of the constrained tangent at rest (nu = {nu}; eigenvalues below 1e-8 of "
                 "the mean diagonal; the rigid motions a free block keeps are subtracted)")
    save(fig, "validation_12_mode_counts")
    table = {s: {r["model"]: r["non_rigid"] for r in rows if r["setup"] == s} for s in setups}
    SUMMARY["12_mode_counts"] = dict(
        headline="non-rigid zero-energy modes: " + "; ".join(
            f"{s}: " + ", ".join(f"{m} {table[s][m]}" for m in ("baudet", HYPER, "fem-linear")) for s in setups),
        counts=table)
