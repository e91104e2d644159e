"""The environment accuracy page's sections on the tissue models: each task's scene against
neo-Hookean FEM (env_accuracy.json, env_models*.json), the organ task's voxel grids
(organ_accuracy.json), which model each task uses and why, and contact (material_range.json)."""

from __future__ import annotations

from .common import (QUANTITIES, RESULTS, caption, command_for, load, num, pct, shape_label, short_id, stability,
                     table, task_classes, triple)


def env_models_rows(data):
    rows = []
    for task, entry in data["tasks"].items():
        reference = ", ".join(dict.fromkeys(shape_label(s) for s in entry["reference_shapes"]))
        for model, row in entry["models"].items():
            rows.append([task, f"`{model}`", shape_label(entry["shape"]), reference, triple(row.get("errors")),
                         stability(row.get("lowest_eigenvalue")) if row.get("errors") else "-",
                         num(row.get("lowest_eigenvalue")), row.get("reason") or "-"])
    return rows


def env_constitutive_section(accuracy):
    out = ["## Against neo-Hookean FEM\n\n",
           "The same static scenes, the env's mesh and model against `fem-neohookean` on the mesh env_accuracy "
           "uses for it (the largest absolute errors are per case: the tool force in N, the target in mm, the "
           "volume change in percentage points). `baudet`'s law departs from neo-Hookean at the tasks' "
           "strains, so its error does not fall with resolution; `baudet-hyperelastic` is neo-Hookean under "
           "every homogeneous deformation ([physics section 11](../physics.md#11-the-hyperelastic-model-baudet-hyperelastic)), "
           "so what remains of its error is the discretisation's.\n\n",
           caption(command_for("env_accuracy.py"), "env_accuracy.json"), "\n"]
    rows = []
    for task, entry in accuracy["tasks"].items():
        default = entry["env_default"]
        constitutive = default["constitutive"]
        absolute = {q: max((v for v in constitutive.get("case_errors_absolute", {}).get(q, []) if v is not None),
                           default=None) for q in QUANTITIES}
        reference = ", ".join(dict.fromkeys(shape_label(s) for s in entry["constitutive"]["reference_shape"]))
        rows.append([task, f"`{default.get('model', 'baudet')}`", shape_label(default["shape"]), reference,
                     triple(constitutive["errors"]), num(absolute["force"]), num(absolute["target"]),
                     num(absolute["volume"])])
    out += [table(["task", "model", "shape", "FEM mesh", "force / target / volume (%)", "largest force error (N)",
                   "largest target error (mm)", "largest volume error (pp)"], rows), "\n"]
    models = load("env_models.json")["tasks"]
    stale = [f"{task} ({', '.join(shape_label(s) for s in models[task]['reference_shapes'])} against "
             f"{', '.join(shape_label(s) for s in entry['constitutive']['reference_shape'])})"
             for task, entry in accuracy["tasks"].items()
             if task in models and models[task]["reference_shapes"] != entry["constitutive"]["reference_shape"]]
    if stale:
        out += ["**`env_models.json` was measured against another FEM mesh than env_accuracy's** for "
                + ", ".join(stale) + f": re-run `{command_for('env_models.py')}`.\n\n"]
    for name, scale in (("env_models.json", None), ("env_models_reference_x1.5.json", "1.5")):
        data = load(name)
        command = command_for("env_models.py", None if scale is None else name)
        out += ["Both models on each task's default mesh" + (f", the FEM mesh {scale}x finer" if scale else "")
                + " (a model that refuses a mesh is given with its reason):\n\n", caption(command, name), "\n",
                table(["task", "model", "shape", "FEM mesh", "force / target / volume (%)", "equilibria",
                       "lowest tangent eigenvalue (N/m)", "refused"], env_models_rows(data)), "\n"]
    return out


def organ_accuracy_section():
    """The organ task's voxel grids against a fine grid (organ_accuracy.json), when it exists."""
    out = []
    if (RESULTS / "organ_accuracy.json").is_file():
        organ = load("organ_accuracy.json")
        out += ["## The organ task: voxel grid of LiverNeedleAlignment\n\n",
                f"Error definition: {organ['error_definition']}. Reference: the "
                f"{'x'.join(map(str, organ['reference_shape']))} grid ({organ['reference_nodes']} nodes). Speed: env "
                f"steps per CPU second with resets (floor {organ['speed_floor']:.0f}: {organ['issue_floor']:.0f} with "
                "the 1.25x margin).\n\n", caption(organ["command"], "organ_accuracy.json"), "\n"]
        import tissue_env

        default = list(tissue_env.LiverNeedleAlignmentEnv.default_shape)
        marks = lambda shape: "".join(  # noqa: E731
            mark for mark, on in ((" (default)", shape == default), (" (budgeted choice)", shape == organ["budget_choice"]))
            if on)
        rows = [["x".join(map(str, r["shape"])) + (marks(r["shape"]) if r.get("element", "hex") == "hex" else ""),
                 r.get("element", "hex"), r["nodes"], r["tumour_elements"], r["tool_nodes"], pct(r["errors"]["force"]),
                 pct(r["errors"]["target"]), pct(r["errors"]["volume"]), num(r["steps_per_cpu_s"])]
                for r in organ["results"]]
        out += [table(["voxel grid", "elements", "nodes", "tumour elements", "tool nodes", "force (%)", "tumour (%)",
                       "volume (%)", "steps per CPU s"], rows), "\n"]
        if "reference_gap_tet_vs_hex" in organ:
            gap = organ["reference_gap_tet_vs_hex"]
            crossed = [r for r in organ["results"] if any(key.startswith("errors_against_") for key in r)]
            out += ["Each grid against the reference of the other elements, and the two references apart (the "
                    "tetrahedral reference against the hexahedral one). They are two models, not two meshes of "
                    "one: the hexahedral scene carries the task's hourglass control and volume forces x100 (stiffer "
                    "and nearly incompressible, chosen to keep its elements valid), the tetrahedra the material's "
                    "own Poisson ratio with none of either, so the gap is the model difference; each element kind "
                    "converges to its own reference as the first table shows.\n\n",
                    table(["voxel grid", "elements", "against", "force (%)", "tumour (%)", "volume (%)"],
                          [["x".join(map(str, r["shape"])), r["element"], key[len("errors_against_"):],
                            pct(r[key]["force"]), pct(r[key]["target"]), pct(r[key]["volume"])]
                           for r in crossed for key in r if key.startswith("errors_against_")]
                          + [["x".join(map(str, organ["reference_shape"])), "tet", "hex (reference)", pct(gap["force"]),
                              pct(gap["target"]), pct(gap["volume"])]]), "\n"]

    return out


def env_model_choice_section():
    classes = task_classes()
    models = load("env_models.json")["tasks"]

    def errors(task, model):
        return triple(models.get(task, {}).get("models", {}).get(model, {}).get("errors"))

    palpation = models.get("Palpation", {}).get("models", {}).get("baudet-hyperelastic", {})
    out = ["## Which model each task uses, and why\n\n",
           table(["task", "default model (`default_model`)"], [[task, f"`{cls.default_model}`"]
                                                                for task, cls in classes.items()]), "\n",
           "* **TumorPositioning** and **Retraction** take `baudet-hyperelastic`. Against neo-Hookean FEM on "
           f"their scenes its force / target / volume errors are {errors('TumorPositioning', 'baudet-hyperelastic')}% "
           f"(TumorPositioning; `baudet` {errors('TumorPositioning', 'baudet')}%) and "
           f"{errors('Retraction', 'baudet-hyperelastic')}% (Retraction; `baudet` {errors('Retraction', 'baudet')}%), "
           "from `env_models.json` above. Retraction's elements are boxes, on which Baudet's springs get the "
           "shear modulus wrong; `build_model` refuses them under `baudet` "
           "([physics section 2](../physics.md#2-spring-stiffnesses)), and a cubic mesh of the same flap would "
           "be far too slow for the speed floor.\n",
           "* **Palpation** keeps `baudet`: with `baudet-hyperelastic` the probe's contact equilibrium at the "
           "deepest press is a saddle "
           + (f"(`env_models.json`: lowest tangent eigenvalue {num(palpation.get('lowest_eigenvalue'))} N/m, "
              "`stable` false), so a held press would not settle on it.\n\n" if palpation.get("stable") is False else
              "in the runs that chose it, but `env_models.json` now finds every equilibrium stable: the reason no "
              "longer holds and the default should be revisited.\n\n")]
    return out


def env_contact_section():
    return ["## Contact\n\n",
            "Palpation's probe is sphere-ended, in a frictionless active-set contact (`sim_core.solvers.contact`, shared "
            "with Retraction's floor and with the scenes of `sim_core.resolution`): the top nodes on or over "
            "their bound have their height imposed on it, x and z free (Hertz's boundary condition); a node the "
            "tissue pulls away is released, and one that went through its bound during a step is projected back "
            "and joins. The bound is the probe's indentation of the start surface projected on the top nodes' "
            "basis functions (the hat-weighted average of the probe's surface over the faces around each node), "
            "so the displaced volume is the probe's wherever the nodes fall. Sampled at the nodes instead "
            "(`probe_sampling=\"node\"`), a press over a node moves one node and one between nodes four, and the "
            "readings carry the mesh's pattern; a flat probe imposes whichever nodes lie under it, so even the "
            "fine model did not converge. The inclusion stiffens each element by its volume share in the "
            "inclusion's box, so its stiff volume is the same at every shape.\n\n",
            "Retraction's floor is the same active-set contact inside the implicit step (the frictionless "
            "contact of the static scene), so a held flap settles on the static equilibrium (tested); a clamp "
            "after the step settled far from it in volume change. A contact that moves keeps the implicit "
            "integrator's factorisation, corrected exactly for the dofs it imposes (a capacitance correction, "
            "`sim_core.solvers.implicit`). At the soft end of the material range Retraction's flap, lifted by its "
            "clamped edge, stretches its springs beyond 100%, as neo-Hookean FEM on its mesh does: the "
            "maximum-strain entry (%) is bounded at 1000% (`tissue_env.worlds.FEATURE_LIMITS`), every other "
            "entry at 100, and `info[\"observation_clipped\"]` reports any entry at its bound. Retraction and "
            "BimanualExposure hold tissue stiffer than 100 kPa with a retractor, which does not slip, instead of "
            "the 5 N laparoscopic grasper (`grasp_force_limit=\"auto\"`, the default): the largest force on a "
            "tool in the scripted episodes says why (with the grasper, at most its 5 N):\n\n",
            caption(command_for("material_range.py"), "material_range.json"), "\n",
            table(["env", "E (Pa)", "nu", "entries at their bound (%)", "largest max spring strain (%)",
                   "unreported clipped steps", "largest abs(reward)", "scripted successes",
                   "scripted peak tool force (N)"],
                  [[short_id(r["env_id"]), num(r["young_modulus"]), num(r.get("poisson_ratio", 0.45))]
                   + (["refused at reset: " + r["refused"], "", "", "", "", ""] if "refused" in r else
                      [pct(r["share_at_bound"]), f"{r['max_strain_percent']:.0f}", r["unreported_clipped_steps"],
                       num(r["max_abs_reward"]), f"{r['scripted_successes']} / {r['seeds']}",
                       num(r.get("scripted_peak_tool_force_N"))])
                   for r in load("material_range.json")["results"]]), "\n"]
