"""docs/generated/environment_accuracy.md: how each task's simulation defaults are chosen and how
accurate they are (the page, its defaults, resolution, stepping, dynamic convergence, vector env and
rejected alternatives sections; the constitutive sections are in ``constitutive``)."""

from __future__ import annotations

from .common import (HEADER, QUANTITIES, caption, command_for, figure, load, num, pct, shape_label, short_id,
                     table, task_classes, triple)
from .constitutive import (env_constitutive_section, env_contact_section, env_model_choice_section,
                           organ_accuracy_section)


ENV_ACCURACY_SOURCES = ("env_accuracy.json, env_models.json, env_models_reference_x1.5.json, organ_accuracy.json, "
                        "dynamic_convergence*.json, "
                        "env_speed.json, vector_env_speed.json and material_range.json")


def environment_accuracy_page():
    """docs/generated/environment_accuracy.md: how each task's simulation defaults are chosen and how
    accurate they are, the prose here, every number from the results files."""
    accuracy = load("env_accuracy.json")
    out = [HEADER.format(source="benchmarks/results/" + ENV_ACCURACY_SOURCES),
           "# Environment accuracy: how the defaults are chosen\n\n",
           "Every task simulates its tissue with a mesh shape, a time step and a tissue model chosen by "
           "measurement on the task's own scene (the scenes are described in the docstring of "
           "`benchmarks/env_accuracy.py`). Three comparisons, each against an untuned reference:\n\n"
           "* **discretisation**: the same model on a fine mesh, static equilibria at the tested tool "
           "displacements: is the mesh fine enough?\n"
           "* **stepping (the lag)**: the env's own dynamic observations, the tool moving at full speed "
           "(`max_step` per env step) and not held, against the static equilibrium of the same mesh at the "
           "same tool position: does one implicit step per action keep up?\n"
           "* **constitutive**: neo-Hookean FEM (`fem-neohookean`) of the same scene: how far is the "
           "mass-spring law from a continuum law?\n\n"
           "A fourth, `dynamic_convergence`, runs each scene as the env does on each mesh and on the fine "
           "one, and compares what the agent observes. The observed quantities are the tool force, the "
           "target's displacement and the tissue's relative volume change. "
           f"Error definition: {accuracy['error_definition']}.\n\n"]
    out += env_defaults_section(accuracy)
    out += env_resolution_section(accuracy)
    out += env_stepping_section(accuracy)
    out += env_dynamic_section(accuracy)
    out += env_constitutive_section(accuracy)
    out += organ_accuracy_section()
    out += env_model_choice_section()
    out += env_contact_section()
    out += env_vector_section()
    out += env_rejected_section()
    return "".join(out)


def env_defaults_section(accuracy):
    classes = task_classes()
    out = ["## The defaults and one env step\n\n",
           "One env step is `substeps` linearised implicit Euler steps of `dt` "
           "(`sim_core.solvers.implicit.ImplicitEuler`). Implicit Euler is stable far past the explicit limit, "
           "so one step per action is enough, and with the springs' critical damping the tissue settles on "
           "the static equilibrium within a few steps of a held tool (tested against `solve_static`). A "
           "`solve_static` per step (the opt-in `integrator=\"static\"`) costs a factorisation per Newton "
           "iteration; its speed is on the [performance page](performance.md#environment-steps). Under "
           "`baudet` the envs add hourglass control and stiffened volume forces (physics sections "
           "[4](../physics.md#4-volume-conservation-forces) and [6](../physics.md#6-zero-energy-modes-and-hourglass-control)): "
           "with weaker ones the deepest tool positions were saddle equilibria and random Retraction "
           "episodes inverted elements. `baudet-hyperelastic` needs neither. The linear solves of a step "
           "stop at the task's solver tolerance: an inexact solve keeps the equilibria, but Retraction's "
           "floor contact makes its trajectories chaotic, and a loose tolerance let random episodes diverge, "
           "so it keeps a tight one.\n\n",
           "Every episode of a model starts from the same state, so the first step's factorisation is kept "
           "(by the content of model, start state, dt and imposed set) and taken by later episodes' first "
           "steps; an episode is bitwise the same on a fresh env and after any other episodes "
           "(`tests/test_env_common.py`).\n\n",
           "*The task classes' defaults (`tissue_env`), and the setting env_accuracy measured "
           "(`benchmarks/results/env_accuracy.json`, `env_default`):*\n\n"]
    rows, stale = [], []
    for task, cls in classes.items():
        entry = accuracy["tasks"].get(task)
        default = entry["env_default"] if entry else {}
        measured = (default.get("model", "baudet"), tuple(default.get("shape", ())), default.get("dt"))
        coded = (cls.default_model, tuple(cls.default_shape), cls.default_dt)
        if measured != coded:
            stale.append(task)
        rows.append([task, f"`{cls.default_model}`", shape_label(cls.default_shape), num(cls.default_dt),
                     num(cls.default_solver_tolerance), num(default.get("hourglass_control")),
                     num(default.get("volume_stiffness")),
                     "yes" if measured == coded else f"no: {measured[0]}, {shape_label(measured[1])}, {num(measured[2])}"])
    out += [table(["task", "model", "shape", "dt (s)", "solver tolerance", "hourglass control", "volume stiffness",
                   "env_accuracy.json measured this setting"], rows), "\n"]
    if stale:
        out += [f"The results of {', '.join(stale)} were measured at another setting than the code's: re-run "
                f"`{command_for('env_accuracy.py')} --task NAME`.\n\n"]
    return out


def env_resolution_section(accuracy):
    tasks = accuracy["tasks"]
    first = next(iter(tasks.values()))["budget_choice"]
    floor, issue_floor = first["floor"], first["issue_floor"]
    command = command_for("env_accuracy.py")
    out = ["## How the default shape is chosen\n\n",
           f"**The default is the most accurate shape that keeps {num(issue_floor)} env steps/s with a "
           f"{num(floor / issue_floor)}x margin**, i.e. that measures at least {num(floor)} steps/s "
           "(per CPU second, resets included, random actions, one process; medians of interleaved rounds that "
           "take every candidate shape in turn) in env_accuracy's speed measurement "
           "(`sim_core.resolution.choose_resolution` and `choose_stepping` do the accuracy part). The margin "
           f"is there because the project's shared machine ({load('env_speed.json')['machine']['cpus']} cores) runs at a "
           "different speed from run to run, so a "
           "shape measured just over the floor would fall under it in a slower period (the last table of "
           "this section compares two runs). `choose_resolution` at a tolerance gives the coarsest shape "
           "within it instead; neither tolerance needs to be met by the default.\n\n",
           caption(command, "env_accuracy.json"), "\n"]
    rows = []
    for task, entry in tasks.items():
        disc, budget, default = entry["discretisation"], entry["budget_choice"], entry["env_default"]
        by_tolerance = disc["chosen_by_tolerance"]
        reference = ", ".join(dict.fromkeys(shape_label(s) for s in disc["reference_shape"]))
        convergence = "; ".join(f"{shape_label(c['shape'])}: {triple(c['errors'])}" for c in disc["reference_convergence"])
        rows.append([task, f"`{default.get('model', 'baudet')}`", shape_label(default["shape"]),
                     num(entry["env_speeds"].get(shape_label(default["shape"]))), reference,
                     triple(default["discretisation"]["errors"]),
                     shape_label(budget["shape"]) + (" (= default)" if budget.get("is_env_default") else ""),
                     *[shape_label(by_tolerance[key]["shape"]) if by_tolerance.get(key) else "none"
                       for key in ("5pct", "10pct")], convergence])
    out += [table(["task", "model", "default shape", "steps/s", "fine reference", "default vs fine (force / target / "
                   "volume, %)", "budgeted choice", "coarsest within 5%", "within 10%",
                   "fine reference's own convergence (%)"], rows), "\n"]
    differ = [task for task, entry in tasks.items() if not entry["budget_choice"].get("is_env_default")]
    out += ["Every task's default is its budgeted choice.\n\n" if not differ else
            f"The default is not the budgeted choice for {', '.join(differ)}.\n\n"]
    out += ["Every candidate (errors against the fine reference, static equilibria; a saddle is an equilibrium "
            "with a negative tangent eigenvalue, refused by the rule):\n\n"]
    rows = []
    for task, entry in tasks.items():
        default = shape_label(entry["env_default"]["shape"])
        for c in entry["discretisation"]["candidates"]:
            label = shape_label(c["shape"])
            speed = entry["env_speeds"].get(label)
            rows.append([task, label + (" (default)" if label == default else ""), c["n_nodes"], num(speed),
                         "yes" if speed is not None and speed >= entry["budget_choice"]["floor"] else "no",
                         triple(c["errors"]), "stable" if c["stable"] else "saddle"])
    out += [table(["task", "shape", "nodes", "steps/s", f">= {num(floor)} steps/s", "force / target / volume (%)",
                   "equilibria"], rows), "\n", figure("env_accuracy.png", "environment accuracy"), "\n"]

    speed = {short_id(r["env_id"]).removesuffix("-v0"): r for r in load("env_speed.json")["results"]}
    rows = []
    for task, entry in tasks.items():
        label = shape_label(entry["env_default"]["shape"])
        if task in speed and label in entry["env_speeds"]:
            other = speed[task]["steps_per_cpu_s"]
            rows.append([task, label, num(entry["env_speeds"][label]), num(other), num(other / entry["env_speeds"][label])])
    out += ["The same defaults in two runs on the same machine, steps per CPU second: env_accuracy's measurement "
            "and `env_speed.py`'s (one round of its own):\n\n",
            caption(command, "env_accuracy.json"), caption(command_for("env_speed.py"), "env_speed.json"), "\n",
            table(["task", "default shape", "env_accuracy", "env_speed", "env_speed / env_accuracy"], rows), "\n"]
    return out


def env_stepping_section(accuracy):
    out = ["## Stepping: the lag behind the static equilibrium\n\n",
           "With the tool at full speed the tissue lags behind the tool (it has mass and damping), so the "
           "observations on arrival differ from the static equilibrium at the same tool position. This lag is "
           "physics as much as error, and it need not fall with resolution; a held tool reads the static "
           "values. `choose_stepping` tries dt and substeps on the default (and on the 5% shape) and keeps the "
           "cheapest stepping within a tolerance; the envs keep one step of their dt, for speed, and report "
           "the lag they have:\n\n", caption(command_for("env_accuracy.py"), "env_accuracy.json"), "\n"]
    rows = []
    for task, entry in accuracy["tasks"].items():
        stepping = entry["env_default"]["stepping"]
        rows.append([task, shape_label(entry["env_default"]["shape"]), num(stepping["dt"]), stepping["substeps"],
                     num(entry["max_step"] * 1e3), triple(stepping["errors"]), num(stepping["iterations"])])
    out += [table(["task", "shape", "dt (s)", "substeps", "tool max_step (mm)", "lag: force / target / volume (%)",
                   "solver iterations per step"], rows), "\n", "Every stepping tried:\n\n"]
    rows = []
    for task, entry in accuracy["tasks"].items():
        for label, study in entry["stepping"].items():
            for c in study["candidates"]:
                rows.append([task, label, num(c["dt"]), c["substeps"], triple(c["errors"]),
                             "yes" if c["admissible"] else "no"])
    out += [table(["task", "shape", "dt (s)", "substeps", "lag: force / target / volume (%)", "within 5%"], rows), "\n"]
    return out


DYNAMIC_FILES = ("dynamic_convergence.json", "dynamic_convergence_constant_viscosity.json",
                 "dynamic_convergence_damping3.json", "dynamic_convergence_static.json")


def default_shape_row(entry):
    return next((s for s in entry["shapes"] if s.get("is_env_default")), None)


def env_dynamic_section(accuracy):
    classes = task_classes()
    out = ["## What the agent observes: dynamic convergence\n\n",
           "env_accuracy's static comparison says how well a shape's equilibria converge, its lag how far the "
           "observations with the tool at full speed are from the shape's own equilibrium. `dynamic_convergence` "
           "runs each scene as the env does (the scripted tool at `max_step` per env step, the env's dt and "
           "solver tolerance, no hold) on each shape and on a fine mesh run the same way, and compares the "
           "observations on arrival (`errors`); each shape's lag against its own static equilibrium is reported "
           "too. The agents act on these dynamic observations, so at full tool speed these are the honest "
           "accuracy of the defaults. Three variants test the cause of the differences: 3x the springs' "
           "critical damping (`--damping-ratio 3`), the default mesh's viscosity kept on every mesh "
           "(`--constant-viscosity`, the damping scaled by h_default / h), and a static equilibrium per env "
           "step (`--integrator static`: no lag, so its errors are the static discretisation errors).\n\n"]
    data = {name: load(name) for name in DYNAMIC_FILES}
    stale = sorted({task for entries in data.values() for task, entry in entries.items()
                    if task in classes and entry.get("model", "baudet") != classes[task].default_model})
    if stale:
        out += [f"**Not yet re-run at the current model:** {', '.join(stale)} (the model column differs from the "
                "task's default model in the table at the top); the commands below regenerate the files.\n\n"]
    base = data["dynamic_convergence.json"]
    moved = []
    for name in ("dynamic_convergence_constant_viscosity.json", "dynamic_convergence_damping3.json"):
        for task, entry in data[name].items():
            row, ref = default_shape_row(entry), default_shape_row(base.get(task, {"shapes": []}))
            if row and ref:
                for q in QUANTITIES:
                    moved.append((abs(row["errors"][q] - ref["errors"][q]), task, q, name))
    if moved:
        worst = max(moved)
        out += ["The springs' damping is not what makes the dynamic errors: with 3x the damping or with a constant "
                f"viscosity the defaults' errors move by at most {pct(worst[0], 2)} percentage points "
                f"({worst[1]}'s {worst[2]}, `{worst[3]}`).\n\n"]
    for name in DYNAMIC_FILES:
        entries = data[name]
        command = command_for("dynamic_convergence.py", None if name == "dynamic_convergence.json" else name)
        first = next(iter(entries.values()))
        out += [f"### {first['integrator']} integrator, damping: {num(first['damping'])}\n\n", caption(command, name), "\n"]
        rows = []
        for task, entry in entries.items():
            for shape in entry["shapes"]:
                label = shape_label(shape["shape"]) + (" (default)" if shape.get("is_env_default") else "")
                rows.append([task, f"`{entry.get('model', 'baudet')}`", label, shape_label(entry["fine_shape"]),
                             triple(shape["errors"]), triple(shape["lag"])])
        out += [table(["task", "model", "shape", "fine mesh", "errors: force / target / volume (%)",
                       "lag: force / target / volume (%)"], rows), "\n"]
    out += [figure("static_vs_implicit.png", "static against implicit"), "\n"]
    return out


def env_vector_section():
    data = load("vector_env_speed.json")
    out = ["## Vector environments: what batching shares and what it cannot\n\n",
           "A vector env steps its copies by one batched implicit step and one vectorised pass for the "
           "measurements, observations and rewards. What it shares that single envs cannot:\n\n"
           "* the force pass reads each copy's hourglass matrix in 3x3 node blocks, so copies of one model do "
           "not stack N copies of the matrix (which fell out of cache);\n"
           "* the copies a step re-factorises are assembled and factorised in one compiled call "
           "(`kernels.factor_copies`), and each copy's factorisation is the block LDL^T of its system "
           "matrix's symmetric part (half the values of an LU to read in the substitutions that dominate a "
           "copy's step; the single envs keep the LU);\n"
           "* TumorPositioning's copies share their start preconditioner and run in lockstep chunks, so one "
           "pass over the shared factor serves all of a chunk's running copies, each with its own iteration "
           "count (`kernels.solve_copies_grouped`);\n"
           "* the per-copy solves, factorisations and resets run on threads (numba's for the kernels, a pool "
           "of Python threads for the resets, whose solves release the GIL), and numba's idle threads spin "
           "briefly before they sleep, since a vector step runs a dozen parallel regions;\n"
           "* every env measures with the next step's force pass (`share_force_pass`): one force pass per env "
           "step instead of two;\n"
           "* a step's contact passes (Palpation's probe) force-pass, assemble and solve again only the copies "
           "whose contact set changed (`ImplicitEuler.linearise(positions, rows)`), as a single env solves "
           "again only itself.\n\n"
           "What it cannot share is each copy's own arithmetic: its sparse solves and factorisations "
           "(BimanualExposure's and Retraction's grasps re-factorise a copy most steps), its force passes and "
           "its resets (TumorPositioning's and LiverNeedleAlignment's are static solves for the goal, SuperLU "
           "factorisations, the same code in every mode). The table gives the share of each mode's CPU time "
           "inside the compiled kernels and SuperLU's factorisations (that arithmetic) and the one-thread "
           "bound: the one-thread CPU ratio over the one-thread vector env's kernel share, the ratio it would "
           "reach if nothing outside its kernels cost time. Where the bound is near 2, 2x sync on one thread "
           "is out of reach by batching. The [performance page]"
           "(performance.md#vector-environments) has the speeds of every mode.\n\n",
           f"Unit: {data['unit']}.\n\n", caption(command_for("vector_env_speed.py"), "vector_env_speed.json"), "\n"]
    modes = list(data["results"][0]["modes"])
    shares = list(data["results"][0].get("kernel_share", {}))
    out += [table(["env", "copies"] + [f"{mode}: resets' share of the time (%)" for mode in modes]
                  + [f"{mode}: kernels' share of the CPU (%)" for mode in shares]
                  + ["vector / sync (wall)", "vector 1 thread / sync (CPU)", "one-thread bound"],
                  [[short_id(r["env_id"]), r["num_envs"]] + [pct(r["modes"][m]["reset_share"], 2) for m in modes]
                   + [pct(r["kernel_share"][m], 2) for m in shares]
                   + [num(r["wall_ratio"]), num(r.get("cpu_ratio_one_thread")), num(r.get("one_thread_bound"))]
                   for r in data["results"]]), "\n"]
    return out


def env_rejected_section():
    return ["## Rejected alternatives\n\n",
            "Tried, measured and not kept (the measurements are in CHANGELOG.md):\n\n",
            "* **A static solve per env step** by default: several times slower than an implicit step, and the "
            "implicit step settles on the same equilibrium when the tool is held.\n"
            "* **Palpation's finer default with the coarse mesh's force limit**: the finer mesh resolves the "
            "stiff inclusion, so a press over it passed the reward's force limit set on the coarse mesh and "
            "the trained agents fell behind; the default took the finer mesh only with the limit raised "
            "(`force_limit`, see the [Palpation page](../tasks/palpation.md)).\n"
            "* **Probe bounds sampled at the nodes** and **a flat probe**: the readings carried the mesh's "
            "pattern (see Contact).\n"
            "* **A floor clamp after the step** (Retraction): settled far from the static equilibrium.\n"
            "* **Sharding a vector env over two processes**: each step waits for the slower half, so it gave "
            "no more than the threaded vector env on two cores.\n"
            "* **Preparing TumorPositioning's next episodes in the background** (a thread or a low-priority "
            "process): the resets became cheap, but every other step slowed, since the parallel regions' second "
            "thread lost its core.\n"
            "* **GNU OpenMP's dynamic schedule** for the per-copy kernels, **capacitance corrections on the reset "
            "threads**, **no warm guess** and other `refactor_amortise` values: within noise.\n"
            "* **Scaling TumorPositioning's goal on the linear response** before its first solve, and **retrying "
            "it from the cached start factorisation**: fewer retries or a faster median reset, but no measurable "
            "gain in the vector env, a worse tail and more factorisations.\n\n"]
