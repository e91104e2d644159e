"""docs/generated/validation.md: the mass-spring model against finite elements, from
benchmarks/results/validation_summary.json, validation_*.csv, tet_formulations.json and
cantilever_reference.json."""

from __future__ import annotations

from .common import HEADER, RESULTS, caption, command_for, figure, load, load_csv, num, pct, stability, table


def validation_page():
    summary = load("validation_summary.json")
    validate = command_for("validation.py")
    out = [HEADER.format(source="benchmarks/results/validation_summary.json and validation_*.csv"),
           "# Validation\n\n",
           "The mass-spring model against finite elements on the same nodes (the experiments and metrics "
           "of [physics section 7](../physics.md#7-experiments-and-metrics), the floors of "
           "[section 8](../physics.md#8-acceptance-floors)). "
           "How each experiment is set up and what it shows is discussed in the "
           "[validation lab](../validation.md); the tables here are regenerated from the results files.\n\n",
           "## Headline per figure\n\n", caption(validate, "validation_summary.json"), "\n"]
    rows = []
    for key, value in summary.items():
        if not isinstance(value, dict) or "headline" not in value:
            continue
        number = key.split("_", 1)[0]
        rows.append([f"{number} {key.split('_', 1)[1].replace('_', ' ')}", value["headline"],
                     num(summary["wall_time_s"].get(number))])
    out += [table(["figure", "headline", "run time (s)"], rows), "\n"]

    out += small_deformation_sections(validate, summary)
    out += large_deformation_sections(validate)
    out += tetrahedral_bending_section()
    out += ["## Environments\n\n", "Each task's scene against a fine mesh and against neo-Hookean FEM, and how the "
            "environments' defaults are chosen: [environment accuracy](environment_accuracy.md).\n"]
    return "".join(out)


def small_deformation_sections(validate, summary):
    """Figures 1-7: the models at small strain against linear and neo-Hookean FEM (``summary``:
    validation_summary.json)."""
    out = ["## 1. Measured E and nu against strain\n\n",
           "Worst error over nu in {0.1, 0.2, 0.3, 0.4, 0.45}, up to each strain: relative error of E, "
           "absolute error of nu.\n\n", caption(validate, "validation_summary.json"), "\n"]
    worst = summary["1_moduli"]["worst_over_nu_and_strain_up_to"]
    strains = list(next(iter(worst.values())).keys())
    out += [table(["model"] + [f"up to {s}" for s in strains],
                  [[model] + [f"{pct(v[s]['E_rel_err'], 2)}%, {num(v[s]['nu_abs_err'], 2)}" for s in strains]
                   for model, v in worst.items()]), "\n", figure("validation_1_moduli.png", "moduli"), "\n"]

    out += ["## 2. Position errors in elongation\n\n", caption(validate, "validation_2_elongation_errors.csv"), "\n"]
    rows = [r for r in load_csv("validation_2_elongation_errors.csv") if abs(float(r["strain"])) in (0.01, 0.1)]
    out += [table(["strain", "model", "reference", "%e_dm", "%e_max"],
                  [[num(r["strain"]), r["model"], r["reference"], num(r["e_dm"]), num(r["e_max"])] for r in rows]),
            "\n", figure("validation_2_elongation_errors.png", "elongation errors"), "\n"]

    out += ["## 3. Shear\n\n", caption(validate, "validation_3_shear.csv"), "\n"]
    rows = [r for r in load_csv("validation_3_shear.csv") if float(r["angle_deg"]) in (2.0, 10.0)]
    out += [table(["angle (deg)", "model", "G (Pa)", "%e_dm vs fem-linear", "%e_max vs fem-linear",
                   "%e_dm vs fem-neohookean"],
                  [[num(r["angle_deg"]), r["model"], num(r["shear_modulus"], 4), num(r["e_dm_vs_fem-linear"]),
                    num(r["e_max_vs_fem-linear"]), num(r["e_dm_vs_fem-neohookean"])] for r in rows]),
            "\n", figure("validation_3_shear.png", "shear"), "\n"]

    out += ["## 4. Flexion of the cantilever\n\n", caption(validate, "validation_4_flexion.csv"), "\n"]
    rows = load_csv("validation_4_flexion.csv")
    out += [table(["gravity (m/s^2)", "model", "tip deflection (m)", "neo-Hookean tip / length",
                   "%e_dm vs fem-linear", "%e_dm vs fem-neohookean", "%e_max vs fem-neohookean"],
                  [[num(r["gravity"]), r["model"], num(r["tip_deflection"]), num(r["neo_tip_over_length"]),
                    num(r["e_dm_vs_fem-linear"]), num(r["e_dm_vs_fem-neohookean"]),
                    num(r["e_max_vs_fem-neohookean"])] for r in rows if r["model"] == "baudet"]),
            "\n", figure("validation_4_flexion.png", "flexion"), "\n"]

    out += ["## 5. Volume\n\n", "Relative volume change at the largest load of each case, nu = 0.45.\n\n",
            caption(validate, "validation_5_volume.csv"), "\n"]
    rows = load_csv("validation_5_volume.csv")
    largest = {}
    for r in rows:
        if r["nu"] != "0.45" or r["converged"] != "True":
            continue
        key = (r["case"], r["model"])
        if key not in largest or abs(float(r["load"])) > abs(float(largest[key]["load"])):
            largest[key] = r
    out += [table(["case", "model", "load", "dV/V0 (%)"],
                  [[case, model, num(r["load"]), pct(float(r["relative_volume_change"]))]
                   for (case, model), r in largest.items()]),
            "\n", figure("validation_5_volume.png", "volume"), "\n"]

    out += ["## 6. Zero-energy modes and hourglass control\n\n",
            "Depth (fraction of the block height) from which frictionless or glued tool loading makes the "
            "static equilibrium unstable, per hourglass control alpha.\n\n",
            caption(validate, "validation_6_stability_onset.csv"), "\n"]
    rows = load_csv("validation_6_stability_onset.csv")
    out += [table(["nu", "contact", "alpha", "unstable from depth"],
                  [[r["nu"], r["contact"], r["alpha"], num(r["unstable_from_depth"])] for r in rows]), "\n",
            caption(validate, "validation_6_tool_loading.csv"), "\n"]
    rows = load_csv("validation_6_tool_loading.csv")
    out += [table(["case", "load", "alpha", "%e_dm", "hourglass ratio", "tool force (N)", "FEM tool force (N)"],
                  [[r["case"], num(r["load"]), r["alpha"], num(r["e_dm"]), num(r["hourglass_ratio"]),
                    num(r["tool_force"]), num(r["fem_tool_force"])] for r in rows]),
            "\n", figure("validation_6_zero_energy_modes.png", "zero-energy modes"), "\n"]

    out += ["## 7. Non-cubic elements\n\n", "Admissible aspect ratio (all edge stiffnesses positive) per nu:\n\n",
            caption(validate, "validation_7_admissible_aspect.csv"), "\n"]
    out += [table(["nu", "smallest aspect", "largest aspect"],
                  [[r["nu"], num(r["min_aspect"], 4), num(r["max_aspect"], 4)]
                   for r in load_csv("validation_7_admissible_aspect.csv")]), "\n",
            caption(validate, "validation_7_non_cubic.csv"), "\n"]
    out += [table(["model", "aspect", "orientation", "G / G_FEM", "predicted element G / G0", "shear %e_dm",
                   "E / E0 (elongation)", "nu (elongation)"],
                  [[r["model"], num(r["aspect"]), r["orientation"], num(r["shear_ratio_to_fem"]),
                    num(r["predicted_shear_ratio"]),
                    num(r["shear_e_dm"]), num(r["elongation_E_ratio"], 4), num(r["elongation_nu"], 4)]
                   for r in load_csv("validation_7_non_cubic.csv")]),
            "\n", figure("validation_7_non_cubic.png", "non-cubic elements"), "\n"]
    return out


def tetrahedral_bending_section():
    """Candidate tetrahedral formulations against the locking-free cantilever reference
    (tet_formulations.json, cantilever_reference.json), when both exist."""
    if not ((RESULTS / "tet_formulations.json").is_file() and (RESULTS / "cantilever_reference.json").is_file()):
        return []
    study, reference = load("tet_formulations.json"), load("cantilever_reference.json")
    ratios = sorted({row["poisson_ratio"] for row in study["rows"]})
    names = list(dict.fromkeys(row["formulation"] for row in study["rows"]))
    value = {(row["formulation"], row["poisson_ratio"]): row["ratio"] for row in study["rows"]}
    frequency = {(row["formulation"], row["poisson_ratio"]): row.get("frequency_ratio") for row in study["rows"]}
    converged = {row["poisson_ratio"]: row["convergence"]["tip_mean_uy"] for row in reference["results"]}
    return ["## Tetrahedra in bending at tissue Poisson ratios\n\n",
            "The cantilever 1 x 0.2 x 0.2 m (clamped at x = 0, 10 N at the tip, E = 10 kPa) on 20 x 4 x 4 cubes "
            "each split into 6 tetrahedra: the mean tip deflection of each small-strain formulation on those "
            "nodes over the converged locking-free reference (Taylor-Hood P2-P1, Richardson-extrapolated; "
            "1 is exact). FEM-T4 is each tetrahedron on its own strain (sim_core's smoothing=\"none\"); the others "
            "smooth the elements' strains over node (ANP: the volumetric part only; NS), edge (ES) or both (ES/NS: "
            "edge-smoothed deviatoric with node-smoothed volumetric strain) domains, assembled by the study; "
            "\"sim_core baudet\" is sim_core's default tetrahedral model (ES/NS) as sim_core assembles it.\n\n",
            caption(study["command"], "tet_formulations.json"), "\n",
            table(["formulation"] + [f"nu {nu:g}" for nu in ratios],
                  [[name] + [num(value[(name, nu)], 3) for nu in ratios] for name in names]), "\n",
            *([] if "frequency_ratio" not in study["rows"][0] else [
                "The first bending frequency with lumped masses over the reference's (consistent masses, "
                "converged):\n\n",
                table(["formulation"] + [f"nu {nu:g}" for nu in ratios],
                      [[name] + [num(frequency[(name, nu)], 3) for nu in ratios] for name in names]), "\n"]),
            caption(reference["command"], "cantilever_reference.json"), "\n",
            table(["nu", "reference tip deflection (m)", "estimated error (GCI, finest mesh)"],
                  [[f"{nu:g}", num(-converged[nu]["extrapolated"], 5), pct(converged[nu]["gci_fine"], 2) + "%"]
                   for nu in ratios]), "\n"]


def pivot(rows, row_key, column_key, value):
    """The ``value`` of CSV ``rows`` as a grid: (row names, column names, one list of values per row
    name), names in order of first appearance, a cell the first row of its pair."""
    row_names = list(dict.fromkeys(r[row_key] for r in rows))
    column_names = list(dict.fromkeys(r[column_key] for r in rows))
    cells = {}
    for r in rows:
        cells.setdefault((r[row_key], r[column_key]), r[value])
    return row_names, column_names, [[cells[(a, b)] for b in column_names] for a in row_names]


def large_deformation_sections(validate):
    """Figures 8-14: baudet-hyperelastic beside baudet and the FEM laws at large deformation."""
    out = ["## 8. Tension and compression to +-30%\n\n",
           "4x4x4 block, lateral faces free; nominal stress = reaction / rest area.\n\n",
           caption(validate, "validation_8_large_elongation.csv"), "\n"]
    rows = [r for r in load_csv("validation_8_large_elongation.csv") if abs(float(r["strain"])) in (0.2, 0.3)]
    out += [table(["nu", "strain", "model", "nominal stress (Pa)", "stress / neo-Hookean", "dV/V0 (%)", "equilibrium"],
                  [[r["nu"], num(r["strain"]), r["model"], num(r["nominal_stress"], 4), num(r["stress_ratio_to_neohookean"], 4),
                    pct(float(r["relative_volume_change"])), stability(r["lowest_eigenvalue"])] for r in rows]),
            "\n", figure("validation_8_large_elongation.png", "large elongation"), "\n"]

    out += ["## 9. Shear to 30 degrees\n\n", caption(validate, "validation_9_large_shear.csv"), "\n"]
    rows = [r for r in load_csv("validation_9_large_shear.csv") if float(r["angle_deg"]) in (20.0, 30.0)]
    out += [table(["nu", "angle (deg)", "model", "top force (N)", "force / neo-Hookean", "%e_dm vs fem-neohookean"],
                  [[r["nu"], num(r["angle_deg"]), r["model"], num(r["shear_force"], 4),
                    num(r["force_ratio_to_neohookean"], 4), num(r["e_dm_vs_neohookean"])] for r in rows]),
            "\n", figure("validation_9_large_shear.png", "large shear"), "\n"]

    out += ["## 10. Flexion to large deflection\n\n", caption(validate, "validation_10_large_flexion.csv"), "\n"]
    rows = load_csv("validation_10_large_flexion.csv")
    out += [table(["gravity (m/s^2)", "model", "tip drop / length", "%e_dm vs fem-neohookean", "converged", "equilibrium"],
                  [[num(r["gravity"]), r["model"], num(r["tip_drop_over_length"]), num(r["e_dm_vs_neohookean"]),
                    r["converged"], stability(r["lowest_eigenvalue"])] for r in rows if r["model"] != "fem-neohookean"]),
            "\n", figure("validation_10_large_flexion.png", "large flexion"), "\n"]

    out += ["## 11. Unconfined compression near incompressibility\n\n",
            caption(validate, "validation_11_compression.csv"), "\n"]
    rows = [r for r in load_csv("validation_11_compression.csv") if float(r["strain"]) in (-0.2, -0.3)]
    out += [table(["nu", "strain", "model", "dV/V0 (%)", "dV/V0 - neo-Hookean's (pp)", "stress / neo-Hookean",
                   "equilibrium"],
                  [[r["nu"], num(r["strain"]), r["model"], pct(float(r["relative_volume_change"])),
                    pct(float(r["volume_change_minus_neohookean"])), num(r["stress_ratio_to_neohookean"], 4),
                    stability(r["lowest_eigenvalue"])] for r in rows]),
            "\n", figure("validation_11_compression.png", "compression"), "\n"]

    out += ["## 12. Zero-energy modes of each model\n\n",
            "Non-rigid zero-energy modes of the constrained tangent at rest (nu = 0.3).\n\n",
            caption(validate, "validation_12_mode_counts.csv"), "\n"]
    setups, models, counts = pivot(load_csv("validation_12_mode_counts.csv"), "setup", "model", "non_rigid")
    out += [table(["set-up"] + models, [[s] + row for s, row in zip(setups, counts)]),
            "\n", figure("validation_12_mode_counts.png", "mode counts"), "\n"]

    out += ["## 13. Objectivity\n\n",
            "Deviation of the rotated problem's equilibrium from the rotated answer, over the largest displacement.\n\n",
            caption(validate, "validation_13_objectivity.csv"), "\n"]
    models, angles, deviations = pivot(load_csv("validation_13_objectivity.csv"), "model", "angle_deg",
                                       "deviation_over_largest")
    out += [table(["model"] + [f"{num(a)} deg (%)" for a in angles],
                  [[m] + [pct(float(d), 2) for d in row] for m, row in zip(models, deviations)]),
            "\n", figure("validation_13_objectivity.png", "objectivity"), "\n"]

    summary = load("validation_summary.json")["14_refinement"]
    reference = summary["reference"]
    out += ["## 14. Refinement of a cantilever at 30% deflection\n\n",
            f"Reference: fem-neohookean on {reference['mesh']} (nu = {reference['nu']}, g = {num(reference['gravity'])} "
            f"m/s^2, tip drop {num(reference['tip_drop'])} m).\n\n", caption(validate, "validation_14_refinement.csv"), "\n"]
    rows = load_csv("validation_14_refinement.csv")
    out += [table(["model", "mesh", "%e_dm", "%e_max", "tip drop (m)", "lowest eigenvalue (N/m)", "equilibrium"],
                  [[r["model"], r["shape"], num(r["e_dm"]), num(r["e_max"]), num(r["tip_drop"]), num(r["lowest_eigenvalue"]),
                    stability(r["lowest_eigenvalue"])] for r in rows]), "\n",
            "The reference chain (each mesh against the finest):\n\n",
            caption(validate, "validation_14_reference_chain.csv"), "\n",
            table(["elements through the side", "%e_dm", "%e_max", "tip drop (m)"],
                  [[r["elements_through_side"], num(r["e_dm"]), num(r["e_max"]), num(r["tip_drop"])]
                   for r in load_csv("validation_14_reference_chain.csv")]),
            "\n", figure("validation_14_refinement.png", "refinement"), "\n"]
    return out
