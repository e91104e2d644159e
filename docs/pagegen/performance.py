"""docs/generated/performance.md: speeds of the physics, the envs, resets, snapshots, vector envs,
camera observations, cutting and large meshes, the stability limit, speed against accuracy and
other engines, from step_speed.json, env_speed*.json, reset_speed.json, snapshots.json,
vector_env_speed*.json, visual_speed.json, stability*.csv, speed_accuracy*.json, peers.json,
memory_soak.json, cutting*.json and large_mesh.json."""

from __future__ import annotations

from .common import HEADER, RESULTS, caption, command_for, figure, load, load_csv, num, pct, short_id, table


def performance_page():
    out = [HEADER.format(source="benchmarks/results/step_speed.json, env_speed*.json, reset_speed.json, snapshots.json, "
                               "vector_env_speed*.json, visual_speed.json, stability*.csv, speed_accuracy.json, "
                               "cutting*.json and peers.json"),
          "# Performance\n\n",
          "Speeds measured on the project's 2-core machine, shared with other jobs: treat them as orders "
          "of magnitude and compare rows of the same table. Timing is never asserted in the tests.\n\n"]
    sections = (step_section, env_steps_section, resets_section, snapshots_section, vector_section,
                vector_busy_section, visual_speed_section, stability_section, speed_accuracy_section, peers_section,
                memory_section, cutting_section, large_mesh_section)
    for section in sections:
        out += section()
    out += ["## Notes\n\n", '--8<-- "docs/performance_notes.md"\n']
    return "".join(out)


def step_section():
    """One physics step of the block scene (step_speed.json)."""
    step = load("step_speed.json")
    out = ["## One physics step\n\n",
           f"A {'x'.join(map(str, step['shape']))} block ({step['nodes']} nodes, {step['springs']} springs).\n\n",
           caption(command_for("step_speed.py"), "step_speed.json"), "\n"]
    rows = []
    for key, value in step.items():
        if key.endswith("_ms") and "_step" in key:
            name = key[: -len("_ms")].replace("_step", "")
            rows.append([name.replace("_", " "), num(value), num(step.get(f"{name}_iterations"))])
    out += [table(["step", "ms", "solver iterations"], rows), "\n"]
    return out


def env_steps_section():
    """Env steps per second under each integrator (env_speed.json, env_speed_static.json)."""
    out = ["## Environment steps\n\n"]
    for name, script_output in (("env_speed.json", None), ("env_speed_static.json", "env_speed_static.json")):
        data = load(name)
        out += [f"### {data['integrator']} integrator\n\n", caption(command_for("env_speed.py", script_output), name),
                "\n", table(["env", "steps/s", "steps per CPU s", "step only /s", "render fps", "physics ms",
                             "observation ms", "reward ms"],
                            [[short_id(r["env_id"]), num(r["steps_per_s"]), num(r["steps_per_cpu_s"]),
                              num(r["step_only_per_s"]), num(r["render_fps"]), num(r["physics_ms"]),
                              num(r["observation_ms"]), num(r["reward_ms"])] for r in data["results"]]), "\n"]
    return out


def resets_section():
    """The time of a reset per task (reset_speed.json)."""
    reset = load("reset_speed.json")
    load_note = (f"Load average (1 min) {reset['load_average_start'][0]:.2f} at the start, {reset['load_average'][0]:.2f} at "
                 f"the end ({reset['machine']['cpus']} cores). " if "load_average" in reset else "")
    out = ["## Resets\n\n", f"{load_note}Unit: {reset['unit']}.\n\n", caption(command_for("reset_speed.py"), "reset_speed.json"),
           "\n", table(["env", "seeds", "median ms", "mean ms", "p95 ms", "max ms", "factorisations per reset"],
                       [[short_id(r["env_id"]), r["seeds"], num(r["median_ms"]), num(r["mean_ms"]), num(r["p95_ms"]),
                         num(r["max_ms"]), num(r["factorisations_per_reset"])] for r in reset["results"]]), "\n"]
    return out


def snapshots_section():
    """get_state / set_state per task (snapshots.json)."""
    snaps = load("snapshots.json")
    out = ["## Snapshots\n\n",
           "`env.unwrapped.get_state()` and `set_state(snapshot)` ([getting started](../getting-started.md#episode-snapshots)): "
           "a snapshot holds the episode (state, tool, the task's bookkeeping, random generator, the solver's "
           "per-world state) and refers to the models, caches and factors. Medians over "
           f"{snaps['results'][0]['snapshots']} snapshots per task taken along random episodes; a snapshot just "
           "unpickled is restored on a fresh env, whose first restore computes the solver's factors again. "
           f"Unit: {snaps['unit']}.\n\n",
           caption(command_for("snapshots.py"), "snapshots.json"), "\n",
           table(["env", "MB pickled (median)", "MB pickled (max)", "get_state per s", "set_state per s",
                  "set_state of an unpickled snapshot (ms)"],
                 [[short_id(r["env_id"]), num(r["pickled_mb_median"]), num(r["pickled_mb_max"]),
                   num(r["get_state_per_s"]), num(r["set_state_per_s"]), num(r["unpickled_set_state_ms_median"])]
                  for r in snaps["results"]]), "\n"]
    return out


def vector_section():
    """The vector envs' modes side by side (vector_env_speed.json, vector_env_speed_async.json)."""
    out = ["## Vector environments\n\n"]
    for name, output in (("vector_env_speed.json", None), ("vector_env_speed_async.json", "vector_env_speed_async.json")):
        data = load(name)
        modes = list(data["results"][0]["modes"])
        out += [f"Unit: {data['unit']}.\n\n", caption(command_for("vector_env_speed.py", output), name), "\n"]
        out += [table(["env", "copies"] + [f"{mode} (wall)" for mode in modes] + ["vector / sync (wall)"],
                      [[short_id(r["env_id"]), r["num_envs"]]
                       + [num(r["modes"][mode]["wall_steps_per_s"]) for mode in modes] + [num(r["wall_ratio"])]
                       for r in data["results"]]), "\n"]
    out += [figure("vector_env_speed.png", "vector env speed"), "\n"]
    return out


def stability_section():
    """The explicit stability limit and the stability map's outcomes (stability_limits.csv,
    stability.csv)."""
    out = ["## Explicit stability limit\n\n",
           "The computed limit (`stable_time_step`) against the largest step measured stable: a ratio above 1 "
           "means the estimate is optimistic.\n\n", caption(command_for("stability.py"), "stability_limits.csv"), "\n"]
    rows = load_csv("stability_limits.csv")
    out += [table(["variant", "E (Pa)", "nu", "estimated dt (s)", "measured dt (s)", "ratio"],
                  [[r["variant"], num(r["young_modulus"]), r["poisson_ratio"], num(r["estimated_dt"]),
                    num(r["measured_dt"]), num(r["ratio"], 4)] for r in rows]), "\n"]
    runs = load_csv("stability.csv")
    counts = {}
    for r in runs:
        counts[(r["integrator"], r["category"])] = counts.get((r["integrator"], r["category"]), 0) + 1
    out += ["Outcome of every run of the stability map (`stability.csv`):\n\n",
            table(["integrator", "outcome", "runs"], [[i, c, n] for (i, c), n in sorted(counts.items())]), "\n",
            figure("stability_map.png", "stability map"), "\n"]
    return out


def speed_accuracy_section():
    """The Pareto fronts and the cost to reach an error per scene (speed_accuracy.json), MuJoCo flex
    on the same scenes, and the figure."""
    speed = load("speed_accuracy.json")
    out = ["## Speed against accuracy\n\n", f"{speed['error_definition']}\n\n{speed['speed_definition']}\n\n",
           caption(command_for("speed_accuracy.py"), "speed_accuracy.json"), "\n"]
    for scene in speed["scenes"].values():
        out += [f"### {scene['label']}\n\nPareto front (fastest configuration for each accuracy):\n\n",
                table(["configuration", "wall s per simulated s", "error (%)", "max error (%)"],
                      [[p["configuration"], num(p["wall_per_sim_s"]), num(p["error_pct"]), num(p["error_max_pct"])]
                       for p in scene["pareto"]]), "\n"]
        if "cost_to_reach_error" in scene:
            reach = scene["cost_to_reach_error"]
            out += [f"Cheapest configuration of each method within {num(reach['error_pct'])}% error"
                    f" (floor: {scene['floor']['statement']}: **{'holds' if scene['floor']['holds'] else 'does not hold'}**"
                    + (f", cost ratio {num(scene['floor']['cost_ratio'])}" if scene['floor']['cost_ratio'] else "") + "):\n\n",
                    table(["method", "configuration", "wall s per simulated s", "error (%)"],
                          [[method, best["configuration"], num(best["wall_per_sim_s"]), num(best["error_pct"])] if best
                           else [method, "never", "-", "-"] for method, best in reach["by_method"].items()]), "\n"]
    out += speed_accuracy_peers_section()
    out += [figure("speed_accuracy.png", "speed against accuracy"), "\n"]
    return out


def peers_section():
    """The sagging block in other soft-body engines (peers.json)."""
    peers = load("peers.json")
    scene = peers["scene"]
    out = ["## Other soft-body engines\n\n",
           f"A {'x'.join(map(str, scene['shape']))} block ({scene['nodes']} nodes), E = {num(scene['young_modulus_pa'])} Pa, "
           f"nu = {scene['poisson_ratio']}, sagging under gravity; sag = {peers['method']['sag']}.\n\n",
           caption(command_for("peers.py"), "peers.json"),
           "(`make bench-peers` installs the optional engines first.)\n\n"]
    out += [table(["engine", "status", "physics", "dt (s)", "ms per step", "sim s per wall s", "top sag after 1 s (m)"],
                  [[name, e["status"], e.get("physics", "-"), num(e.get("dt_s")), num(e.get("ms_per_step")),
                    num(e.get("sim_s_per_wall_s")), num(e.get("top_sag_1s_m"))]
                   for name, e in peers["engines"].items()]), "\n"]
    return out


def memory_section():
    """Resident memory over long random runs (memory_soak.json)."""
    soak = load("memory_soak.json")
    out = ["## Memory over long runs\n\n",
           f"Resident memory of one env per task over {soak['steps']} random steps"
           f"{' with the Young modulus drawn per episode (a new model every episode)' if soak['randomise'] else ''}, "
           f"each task in its own process; after warm-up = after {pct(soak['warmup_share'], 2)}% of the steps. "
           "The caches that keep models and factorisations have byte budgets (`sim_core.caches`: "
           "`set_cache_budget`, `cache_usage`).\n\n",
           caption(command_for("memory_soak.py"), "memory_soak.json"), "\n",
           table(["env", "episodes", "RSS at start (MB)", "after warm-up (MB)", "max after warm-up (MB)",
                  "final (MB)", "growth after warm-up (%)"],
                 [[short_id(r["env_id"]), r["episodes"], num(r["rss_start_mb"]), num(r["rss_after_warmup_mb"]),
                   num(r["rss_max_mb"]), num(r["rss_final_mb"]), pct(r["growth_after_warmup"])]
                  for r in soak["results"]]), "\n"]
    return out


def large_mesh_section():
    """Construction, reset and step against mesh size, and the static solver's switch
    (large_mesh.json)."""
    mesh = load("large_mesh.json")
    out = ["## Work against mesh size\n\n",
           f"The envs refuse a shape with more than {mesh['max_nodes']} nodes unless `max_nodes` is raised "
           "(a reset is Newton on the whole mesh), and warn about a slow one. `solve_static` switches to "
           "AMG-preconditioned Krylov solves past `sim_core.solvers.static.DIRECT_DOF_LIMIT` free dofs "
           "(`linear_solver=\"auto\"`).\n\n",
           caption(command_for("large_mesh.py"), "large_mesh.json"), "\n",
           table(["TumorPositioning shape", "nodes", "construct (s)", "first reset (s)", "step (ms)"],
                 [["x".join(map(str, r["shape"])), r["nodes"], num(r["construct_s"]), num(r["first_reset_s"]),
                   num(r["step_median_ms"])] for r in mesh["env"]]), "\n",
           table(["static scene shape", "free dofs", "direct (s)", "iterative (s)", "Newton iterations (direct / iterative)",
                  "max difference / max displacement"],
                 [["x".join(map(str, r["shape"])), r["free_dofs"], num(r.get("direct_s")), num(r.get("iterative_s")),
                   f"{r.get('direct_newton_iterations', '-')} / {r.get('iterative_newton_iterations', '-')}",
                   num(r.get("max_difference_over_max_displacement"))] for r in mesh["static"]]), "\n"]
    return out


def vector_busy_section():
    """The vector env beside a process that holds a core (vector_env_speed_busy.json, --busy-core)."""
    if not (RESULTS / "vector_env_speed_busy.json").exists():
        return []
    data = load("vector_env_speed_busy.json")
    modes = list(data["results"][0]["modes"])
    start, end = data["load_average_start"][0], data["load_average"][0]
    out = ["### With another process on a core\n\n",
          "The same modes side by side in one run, on the machine as it was (\"idle\") and beside a busy loop "
          "pinned to one core (\"busy\", as when a policy trains in another process). On a busy core every "
          "parallel region waits for the thread that lost its core, so a vector env fixed on every core can fall "
          "below sync; the default threads (`threads=None`) time the steps on every core and on one and keep the "
          "faster (`TissueVectorEnv`). "
          f"Load average (1 min) {start:.2f} at the start, {end:.2f} at the end ({data['machine']['cpus']} cores). "
          f"Unit: {data['unit']}.\n\n",
          caption(command_for("vector_env_speed.py", "vector_env_speed_busy.json"), "vector_env_speed_busy.json"), "\n"]
    out += [table(["env", "copies", "load"] + [f"{mode} (wall)" for mode in modes]
                  + [f"{mode} / sync (wall)" for mode in modes[1:]],
                  [[short_id(r["env_id"]), r["num_envs"], r["load"]]
                   + [num(r["modes"][mode]["wall_steps_per_s"]) for mode in modes]
                   + [num(r["wall_ratio"][mode]) for mode in modes[1:]] for r in data["results"]]), "\n"]
    return out


def visual_speed_section():
    """The camera observations' env steps/s against the state observation's (visual_speed.json)."""
    data = load("visual_speed.json")
    names = list(data["results"][0]["steps_per_s"])
    sizes = data["sizes"]
    return ["## Camera observations\n\n",
            f"Observation types \"rgb\" and \"depth\" (`tissue_env.camera`, the task's default camera) against "
            f"\"state\", side by side in one process. Unit: {data['unit']}. The floor: every visual observation at "
            f">= {num(data['floor'])}x the state observation's steps/s. Frame: one world's projection, shading "
            "and z-buffer (rgb and depth together), median microseconds.\n\n",
            caption(data["command"], "visual_speed.json"), "\n",
            table(["env"] + [f"{name} steps/s" for name in names] + [f"{name} / state" for name in names[1:]]
                  + [f"frame us ({size} px)" for size in sizes] + ["floor holds"],
                  [[short_id(r["env_id"])] + [num(r["steps_per_s"][name]) for name in names]
                   + [num(r["ratio_to_state"][name]) for name in names[1:]]
                   + [num(r["frame_us"][str(size)]) for size in sizes] + [str(r["floor_holds"])]
                   for r in data["results"]]), "\n"]


def speed_accuracy_peers_section():
    """MuJoCo flex on the speed-accuracy scenes (speed_accuracy_peers.json, the optional bench extra)."""
    if not (RESULTS / "speed_accuracy_peers.json").exists():
        return []
    peers = load("speed_accuracy_peers.json")
    out = [f"### MuJoCo flex on the same scenes\n\nMuJoCo {peers['mujoco_version']}'s 3-D flex, the triangles of the "
          "figure. " + peers["scene_match"][:1].upper() + peers["scene_match"][1:].rstrip(".") + ".\n\nWhere it differs from the chart's runs: "
          + "; ".join(peers["deviations"]) + ".\n\n",
          caption(command_for("speed_accuracy_peers.py"), "speed_accuracy_peers.json"),
          "(`make bench-peers` installs MuJoCo first.)\n\n"]
    rows = [[row["scene"], row["damping"], row["resolution"], num(row.get("dt_s")), num(row.get("wall_per_sim_s")),
             num(row.get("error_pct")), num(row.get("error_max_pct")), row["status"]] for row in peers["rows"]]
    out += [table(["scene", "damping", "n", "dt (s)", "wall s per simulated s", "error (%)", "max error (%)", "status"],
                  rows), "\n"]
    return out


def cutting_section():
    """The cost of a cut (issue 44's floors) per cutting task, from cutting*.json."""
    runs = [("cutting.json", None), ("cutting_dissection.json", "cutting_dissection.json")]
    data = [(load(name), command_for("cutting.py", output), name) for name, output in runs]
    floors = data[0][0]["floors"]
    out = ["## Cutting\n\n",
          "CPU time of the single env on one core (`benchmarks/cutting.py`'s docstring: an env step with the blade "
          "held above the tissue; a step that cuts, the median of the scripted cut's cutting steps; a step after a "
          "cut against the same step of an uncut twin env timed in alternation with it), and the peak memory of "
          f"the scripted cut repeated in one process. Floors (issue 44): a cutting step at most "
          f"{num(floors['cutting_step_in_env_steps'])} env steps, a step after a cut at most "
          f"{num(floors['step_after_cut_ratio'])}x, memory growth below {pct(floors['memory_growth'])}% "
          "from 20 episodes to the last.\n\n"]
    out += [caption(command, name) + "\n" for _, command, name in data]
    out += [table(["env", "env step (ms)", "cutting step (ms)", "cutting step (env steps)", "step after a cut (ms)",
                        "uncut twin step (ms)", "after / twin", "episodes", "peak RSS after 20 (MB)",
                        "peak RSS at the end (MB)", "growth (%)"],
                       [[short_id(d["env_id"]), num(1e3 * d["step_s"]), num(1e3 * d["cutting_step_s"]),
                         num(d["cutting_step_in_env_steps"]), num(1e3 * d["step_after_cut_s"]),
                         num(1e3 * d["uncut_twin_step_s"]) if "uncut_twin_step_s" in d else "-",
                         num(d["step_after_cut_ratio"]), d["memory"]["episodes"], num(d["memory"]["peak_rss_mb_after_20"]),
                         num(d["memory"]["peak_rss_mb_at_end"]), pct(d["memory"]["growth"])] for d, _, _ in data]), "\n"]
    diagnosed = [d for d, _, _ in data if "after_cut" in d]
    if diagnosed:  # why a step after a cut costs more: the solver's work and the tissue's motion
        out += ["Why a step after a cut costs more (the same runs): the implicit solver's iterations and "
                "factorisations per step after the cut and the cut world's largest node speed, against the uncut "
                "twin's; the CPU time of one BiCGSTAB iteration and of one numeric refactorisation of the cut "
                "world's system, and from them the ratio the solver's extra work alone makes ((iterations - the "
                "twin's) x an iteration + factorisations x a refactorisation, over the twin's step); the ratio of "
                "the mean step times (the median leaves out the steps that refactorise); and the ratio again after "
                "more held steps (the cut tissue at rest).\n\n",
                table(["env", "iterations after / twin", "factorisations per step after / twin", "iteration (ms)",
                       "refactorisation (ms)", "solver's extra work alone", "mean after / twin",
                       "node speed after (m/s)", "held steps more", "then after / twin",
                       "then iterations after / twin", "then node speed (m/s)"],
                      [[short_id(d["env_id"]), f"{num(a['iterations'])} / {num(a['uncut_twin_iterations'])}",
                        f"{num(a['factorisations_per_step'])} / {num(a['uncut_twin_factorisations_per_step'])}",
                        num(1e3 * a["iteration_s"]), num(1e3 * a["refactorisation_s"]),
                        f"{num(a['solver_work_ratio'])}x", f"{num(a['mean_ratio'])}x",
                        f"{a['max_node_speed']:.2g}", a["settled_after_steps"], num(a["settled_ratio"]),
                        f"{num(a['settled_iterations'])} / {num(a['settled_uncut_twin_iterations'])}",
                        f"{a['settled_max_node_speed']:.2g}"] for d in diagnosed for a in [d["after_cut"]]]), "\n"]
    parted = [d for d, _, _ in data if "cut_parts" in d]
    if parted:  # where a cutting step's time goes (the same runs)
        out += ["Where a cutting step's time goes (the same runs): each cut made again outside the env, CPU "
                "medians of its parts: the cut model (`sim_core.cutting.separation`), its world's one-world stack "
                "on the node rows, and the symbolic structure of its factor (`solvers.factors.copies_structure`); "
                "the rest of a cutting step is its numeric factorisation and the step itself.\n\n",
                table(["env", "separation (ms)", "one-world stack (ms)", "factor structure (ms)"],
                      [[short_id(d["env_id"])] + [num(1e3 * d["cut_parts"][name]) for name in
                                                  ("separation_s", "one_world_stack_s", "factor_structure_s")]
                       for d in parted]), "\n"]
    return out
