"""The cost of cutting in the environments (issue 44's floors) and the memory of many cut episodes.

Usage: python -m benchmarks.cutting [--episodes 220] [--repeats 5] [--output benchmarks/results/cutting.json]
       [--env tissue_env/Incision-v0]

On Incision-v0 (or ``--env``, a cutting task with a scripted controller: Dissection-v0 writes
benchmarks/results/cutting_dissection.json; single env, default keywords, one thread):

- an env step before any cut: the median CPU time of steps with the blade held above the tissue;
- a step that cuts: the median of the scripted incision's cutting steps (each separates the faces the
  blade crossed and rebuilds the world's model, ``sim_core.cutting.cut_world``), in env steps;
- a step after a cut: the median of steps with the blade held still in a world that holds a cut
  model with copied nodes (stepped on its own model), against the median of the same steps of an
  uncut twin (the same env and seed, its blade held above the tissue) taken in alternation with them,
  so that a shared machine's load weighs on both alike;
- why a step after a cut costs more: the linear solver's iterations and factorisations per step
  (``solver_iterations``, ``factorisations``) and the largest node speed of the cut world in those
  steps, against the twin's; the median CPU time of one BiCGSTAB iteration and of one numeric
  refactorisation of the cut world's system (``solver_costs``), and from them the linear solver's
  extra work per step after the cut ((iterations - the twin's) x an iteration + factorisations x a
  refactorisation) as a ratio to the twin's step (``solver_work_ratio``: what the solver's work alone
  makes of the ratio); the ratio of the mean step times (``mean_ratio``: the median leaves out the
  steps that refactorise); and the same ratio, iterations and speed after ``SETTLE`` more held steps
  (the cut tissue at rest);
- a cut's parts: each cut of the timed episodes made again outside the env, CPU medians of its
  separation (``sim_core.cutting.separation``: the cut model), its one-world stack on the world's node
  rows (``stack.with_spare_nodes``, ``ModelStack``) and its factor's symbolic structure
  (``solvers.factors.copies_structure`` on every node row);
- memory: the scripted incision (every episode cuts, copies nodes and resets) ``--episodes``
  times in one process; the peak resident set size (VmHWM of /proc/self/status) after 20 episodes
  and at the end, and their ratio (the floor: less than 10% growth from 20 to 220 episodes).

Each timing is the median over ``--repeats`` episodes' steps. Results to ``--output`` (JSON).
"""

import argparse
import copy
import gc
import os
import platform
import time

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the envs)
from sim_core import kernels
from benchmarks.memory_soak import rss_mb
from sim_core.cutting import separation
from sim_core.models.stack import ModelStack, with_spare_nodes
from sim_core.solvers.factors import copies_structure
from training.common import write_json

ENV_ID = "tissue_env/Incision-v0"
MEMORY_FIRST = 20
#: held steps after the timed ones before the settled ones (the cut tissue at rest)
SETTLE = 150


def peak_rss_mb() -> float:
    """This process's peak resident set size, MB (VmHWM)."""
    return rss_mb("VmHWM")


def timed(env, action):
    """(CPU seconds of the step, its result): the process's CPU time, not the wall clock, so that other
    processes on a shared machine do not count (the single env steps on one thread)."""
    start = time.process_time()
    result = env.step(action)
    return time.process_time() - start, result


def solver_iterations(env) -> int:
    """The implicit solver's iterations in ``env``'s last step (a cut world's own solver's)."""
    integrator = env.unwrapped.worlds.integrator
    own = integrator.own_solver(0)
    return int(np.ravel((integrator if own is None else own).last_iterations)[0])


def factorisations(env) -> int:
    """The implicit solver's factorisations so far in ``env``'s world (a cut world's own solver's: since its
    last cut)."""
    integrator = env.unwrapped.worlds.integrator
    own = integrator.own_solver(0)
    return (integrator if own is None else own).factorisations


def solver_costs(env, repeats=200):
    """(s per BiCGSTAB iteration, s per numeric refactorisation): median CPU times on the cut world's own
    implicit solver at its current state (the same compiled calls as a step: ``kernels.solve_copies_lu``
    on one thread with its factor; ``ImplicitEuler.rebuild_factor`` less its force pass), on a deep copy
    of ``env`` (``env`` is left as it is)."""
    env = copy.deepcopy(env)
    worlds = env.unwrapped.worlds
    solver = worlds.integrator.own_solver(0)
    dt, rows = worlds.dt, solver.stack.n_nodes
    system = solver.scales(1.0, dt, dt * dt)
    free = ~worlds.fixed[0, :rows].reshape(1, -1)
    stacked, hg_rows, hg_group = solver.copies_first()
    rhs = np.where(free, np.random.default_rng(0).normal(size=free.shape), 0.0)
    solution, iterations, residual = np.zeros_like(rhs), np.zeros(1, dtype=np.int64), np.zeros(1)
    arguments = (stacked, system, hg_rows, hg_group, free.astype(float), rhs, np.zeros_like(rhs), np.ones(1, dtype=bool),
                 0.0)  # tolerance 0: every allowed iteration runs
    after = (*solver.factor_lists, np.zeros(1, dtype=np.int64), *solver.correction_lists, np.empty((8, rhs.shape[1])),
             solution, iterations, residual, *solver.workspace.hourglass_blocks())

    def solve(limit):
        start = time.process_time()
        kernels.solve_copies_lu_serial(*arguments, np.array([limit], dtype=np.int64), *after)
        return time.process_time() - start, int(iterations[0])

    short, long = ([solve(limit) for _ in range(repeats)] for limit in (1, 4))
    more = long[0][1] - short[0][1]
    iteration = (np.median([t for t, _ in long]) - np.median([t for t, _ in short])) / max(more, 1)
    positions = np.array(worlds.positions[0, :rows], dtype=float)
    source = ("linearised", positions, tuple(system), free[0])
    rebuilds, passes = [], []
    for _ in range(max(repeats // 10, 5)):
        start = time.process_time()
        solver.rebuild_factor(0, source)  # its force pass at these positions, then the factorisation
        rebuilds.append(time.process_time() - start)
        start = time.process_time()
        solver.linearise(positions)  # the force pass alone (rebuild_factor dropped the kept one)
        passes.append(time.process_time() - start)
    return float(iteration), float(np.median(rebuilds) - np.median(passes))


def held_steps(env, twin, held, still):
    """(CPU times, s, iterations, largest node speeds, m/s, factorisations) of ``held`` steps of ``env`` with
    the blade held still, and of ``twin``'s (None: none) in alternation with them: lists (env's, twin's),
    the factorisations the two made in those steps."""
    times, iterations, speeds = ([], []), ([], []), ([], [])
    made = [factorisations(stepped) if stepped is not None else 0 for stepped in (env, twin)]
    for _ in range(held):
        for side, stepped in enumerate((env, twin)):
            if stepped is None:
                continue
            times[side].append(timed(stepped, still)[0])
            iterations[side].append(solver_iterations(stepped))
            speeds[side].append(float(np.abs(stepped.unwrapped.worlds.velocities[0]).max()))
    made = [factorisations(stepped) - count if stepped is not None else 0 for stepped, count in zip((env, twin), made)]
    return times, iterations, speeds, made


def episode_times(env, seed, held=10, twin=None, details=None):
    """(before, cutting, after, uncut) lists of step CPU times, s, of one scripted incision: ``uncut``
    the steps of ``twin`` (an env of the same id, reset with the same seed, never cut; None: none)
    timed in alternation with the ``after`` steps. ``details``: None, or a dict of lists that gets
    the after steps' and the twin's iterations and node speeds, and those of ``held`` steps timed the
    same way after ``SETTLE`` more (keys ``after_*``, ``uncut_*``, ``settled_*``, ``settled_uncut_*``)."""
    env.reset(seed=seed)
    still = np.zeros(3, np.float32)
    before = [timed(env, still)[0] for _ in range(held)]  # the blade 5 mm above the tissue: no cut
    cutting = []
    for _ in range(60):
        seconds, (_, _, terminated, truncated, info) = timed(env, env.unwrapped.scripted_action())
        if info["faces_cut"]:
            cutting.append(seconds)
            if details is not None:  # the union of the cuts so far (the world holds the uncut model cut along it)
                details.setdefault("cuts", []).append(np.concatenate(env.unwrapped.worlds.cuts[0]))
        if terminated or truncated:
            break
    if env.unwrapped.worlds.stack.shared[0]:
        raise RuntimeError("the scripted incision left no cut world with copied nodes")
    after, uncut = [], []
    if twin is not None:  # past its first step (its factorisation), as the cut env's world is
        twin.reset(seed=seed)
        for _ in range(3):
            twin.step(still)
    (after, uncut), iterations, speeds, made = held_steps(env, twin, held, still)
    if details is not None and twin is not None:
        keep(details, "", iterations, speeds, made=made)
        for _ in range(SETTLE):
            env.step(still)
            twin.step(still)
        times, iterations, speeds, made = held_steps(env, twin, held, still)
        keep(details, "settled_", iterations, speeds, times, made)
        iteration, refactorisation = solver_costs(env)  # last, and its deep copy's garbage collected now:
        gc.collect()  # not in the next timed steps
        details.setdefault("iteration_s", []).append(iteration)
        details.setdefault("refactorisation_s", []).append(refactorisation)
    return before, cutting, after, uncut


def keep(details, prefix, iterations, speeds, times=None, made=(0, 0)):
    """Add ``held_steps``' lists (env's, twin's) and factorisation counts to ``details`` under ``prefix``."""
    for side, name in enumerate(("after", "uncut")):
        details.setdefault(f"{prefix}{name}_factorisations", []).append(made[side])
        details.setdefault(f"{prefix}{name}_iterations", []).extend(iterations[side])
        details.setdefault(f"{prefix}{name}_speed", []).extend(speeds[side])
        if times is not None:
            details.setdefault(f"{prefix}{name}_s", []).extend(times[side])


def cut_parts(env, cuts) -> dict:
    """The median CPU time, s, of each part of a cut (module docstring), made again on ``env``'s uncut
    model along each of ``cuts`` (the unions of faces of the timed cutting steps)."""
    uncut, rows = env.unwrapped.model, env.unwrapped.worlds.stack.n_nodes
    times = {"separation_s": [], "one_world_stack_s": [], "factor_structure_s": []}
    for faces in cuts:
        start = time.process_time()
        model = separation(uncut, faces).model
        separated = time.process_time()
        padded = with_spare_nodes(model, rows)
        ModelStack(padded, 1)
        stacked = time.process_time()
        copies_structure(padded, np.ones(rows, dtype=bool))
        done = time.process_time()
        for name, seconds in zip(times, (separated - start, stacked - separated, done - stacked)):
            times[name].append(seconds)
    return {name: float(np.median(values)) for name, values in times.items()}


def memory(env, episodes):
    """(peak RSS after MEMORY_FIRST episodes, peak RSS at the end, MB; successes)."""
    first, successes = None, 0
    for episode in range(episodes):
        env.reset(seed=episode)
        for _ in range(60):
            _, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
            if terminated or truncated:
                break
        successes += bool(info["is_success"])
        if episode + 1 == MEMORY_FIRST:
            first = peak_rss_mb()
    return first, peak_rss_mb(), successes


def details_line(after_cut) -> str:
    """The after-cut diagnosis in one line."""
    return (f"{after_cut['iterations']:.1f} vs {after_cut['uncut_twin_iterations']:.1f} iterations and "
            f"{after_cut['factorisations_per_step']:.2f} vs {after_cut['uncut_twin_factorisations_per_step']:.2f} "
            f"factorisations per step, an iteration {after_cut['iteration_s'] * 1e3:.3f} ms and a refactorisation "
            f"{after_cut['refactorisation_s'] * 1e3:.2f} ms: the solver's extra work alone "
            f"{after_cut['solver_work_ratio']:.2f}x, mean ratio {after_cut['mean_ratio']:.2f}x; node speed "
            f"{after_cut['max_node_speed']:.2g} m/s; after {after_cut['settled_after_steps']} more steps "
            f"{after_cut['settled_ratio']:.2f}x, {after_cut['settled_iterations']:.1f} vs "
            f"{after_cut['settled_uncut_twin_iterations']:.1f} iterations, {after_cut['settled_max_node_speed']:.2g} m/s")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=220)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--output", default="benchmarks/results/cutting.json")
    parser.add_argument("--env", default=ENV_ID)
    args = parser.parse_args(argv)
    env_id = args.env
    if args.episodes <= MEMORY_FIRST or args.repeats < 1:
        parser.error(f"--episodes must be > {MEMORY_FIRST} and --repeats >= 1")
    env, twin = gym.make(env_id), gym.make(env_id)
    episode_times(env, 0, twin=twin)  # warm: kernels loaded, the start state solved
    before, cutting, after, uncut, details = [], [], [], [], {}
    for seed in range(1, args.repeats + 1):
        b, c, a, u = episode_times(env, seed, twin=twin, details=details)
        before += b
        cutting += c
        after += a
        uncut += u
    step, cut, later, twin_step = (float(np.median(values)) for values in (before, cutting, after, uncut))
    extra_iterations = float(np.mean(details["after_iterations"]) - np.mean(details["uncut_iterations"]))
    made = float(np.sum(details["after_factorisations"]) / len(after))
    iteration, refactorisation = (float(np.median(details[name])) for name in ("iteration_s", "refactorisation_s"))
    parts = cut_parts(env, details["cuts"])
    start = time.perf_counter()
    first, last, successes = memory(gym.make(env_id), args.episodes)
    result = dict(
        env_id=env_id, machine=platform.processor() or platform.machine(),
        step_s=step, cutting_step_s=cut, step_after_cut_s=later, uncut_twin_step_s=twin_step,
        cutting_step_in_env_steps=cut / step, step_after_cut_ratio=later / twin_step,
        steps_timed=dict(before=len(before), cutting=len(cutting), after=len(after), uncut_twin=len(uncut)),
        cut_parts=parts,
        after_cut=dict(
            iterations=float(np.mean(details["after_iterations"])),
            uncut_twin_iterations=float(np.mean(details["uncut_iterations"])),
            factorisations_per_step=made,
            uncut_twin_factorisations_per_step=float(np.sum(details["uncut_factorisations"]) / len(uncut)),
            iteration_s=iteration, refactorisation_s=refactorisation,
            refactorisation_in_iterations=refactorisation / iteration,
            solver_work_ratio=(twin_step + extra_iterations * iteration + made * refactorisation) / twin_step,
            mean_ratio=float(np.mean(after) / np.mean(uncut)),
            max_node_speed=float(np.median(details["after_speed"])),
            uncut_twin_max_node_speed=float(np.median(details["uncut_speed"])),
            settled_after_steps=SETTLE,
            settled_ratio=float(np.median(details["settled_after_s"]) / np.median(details["settled_uncut_s"])),
            settled_iterations=float(np.mean(details["settled_after_iterations"])),
            settled_uncut_twin_iterations=float(np.mean(details["settled_uncut_iterations"])),
            settled_max_node_speed=float(np.median(details["settled_after_speed"])),
            load_average=list(os.getloadavg())),
        memory=dict(episodes=args.episodes, peak_rss_mb_after_20=first, peak_rss_mb_at_end=last,
                    growth=last / first - 1.0, scripted_successes=successes,
                    wall_time_s=time.perf_counter() - start),
        floors=dict(cutting_step_in_env_steps=5.0, step_after_cut_ratio=1.2, memory_growth=0.10),
    )
    write_json(args.output, result)
    print(f"env step {step * 1e3:.2f} ms; cutting step {cut * 1e3:.1f} ms = {cut / step:.1f} env steps; "
          f"after a cut {later * 1e3:.2f} ms = {later / twin_step:.2f}x the uncut twin's {twin_step * 1e3:.2f} ms; "
          f"({details_line(result['after_cut'])}); a cut's separation, one-world stack, factor structure "
          f"{', '.join(f'{seconds * 1e3:.2f}' for seconds in parts.values())} ms; peak RSS {first:.0f} MB after "
          f"{MEMORY_FIRST} episodes, {last:.0f} MB after {args.episodes} ({100 * (last / first - 1):+.1f}%)")
    return result


if __name__ == "__main__":
    main()
