"""Env steps per second of the batched vector envs against gymnasium's SyncVectorEnv.

Usage: python -m benchmarks.vector_env_speed [--num-envs 16 ...] [--steps 100] [--rounds 3] [--env ID ...]
       [--no-reset] [--async] [--busy-core] [--output benchmarks/results/vector_env_speed.json]

For each task with a ``vector_entry_point`` and each N: ``gym.make_vec(id, num_envs=N,
vectorization_mode="sync")`` (N single envs stepped one after the other, one core) against
``vectorization_mode="vector_entry_point"`` (one batched physics step, ``tissue_env.vector``), once
with ``threads=1`` (one core: what batching alone gives) and once with numba's default threads (every
core: the per-copy factorisations and solves in parallel), same seeds and the same random actions,
one process, registered episode lengths (random actions end almost every episode by truncation, so
resets are included; ``--no-reset`` adds a regime with ``max_episode_steps`` = 10^6). ``--async``
adds ``vectorization_mode="async"`` (one process per copy, wall time only). All modes reset a copy
by the task env's own ``reset`` (the same code and cost), timed separately: the share of resets is
reported.

Two rates per mode: env steps (N x vector steps) per second of wall time, the issue's measure and
what a user waits for, and per second of this process's CPU time (all its threads), which other
jobs on a shared machine disturb less. The modes alternate within every round (sync, vector ...)
and the table gives the medians over ``--rounds`` rounds and the medians of the per-round ratios:
wall ratios against sync for the threaded vector env, CPU ratios for ``threads=1``. Results are
written to ``--output`` (JSON, replaced atomically).

After its rounds, each task is run once more in sync and in the vector env on one thread with
``KernelClock`` on (the same steps, outside the timed rounds: its wrappers cost a little per
call): the share of each mode's CPU time spent inside the compiled kernels and SuperLU's
factorisations (the per-copy arithmetic: solves, factorisations, force passes, goal solves) and
``one_thread_bound``, the one-thread CPU ratio over the one-thread vector env's kernel share: the
ratio it would reach if everything outside its kernels cost nothing. A task whose bound is near 2
cannot be batched to 2x sync on one thread: its per-copy arithmetic is what batching cannot share.

``--busy-core`` measures every mode twice per round, side by side in one run: on the machine as it
is ("idle") and with a CPU burner started by this benchmark (a Python busy loop in its own process,
pinned with ``os.sched_setaffinity`` to the last core this process may use: "busy"), as when a policy
trains in another process on the same machine. The modes are then sync, the vector env on one
thread, on every core (``threads`` = numba's thread count, fixed) and with its default threads
(``threads=None``); the table gives each mode's wall rate against sync under each load (medians of
the per-round ratios; the two loads alternate their order from round to round). Its results go to
``benchmarks/results/vector_env_speed_busy.json`` unless ``--output`` is given.
"""

import argparse
import contextlib
import functools
import os
import platform
import subprocess
import sys
import threading
import time

import gymnasium as gym
import numba
import numpy as np
import scipy.sparse.linalg as spla
from numba.core.registry import CPUDispatcher

import tissue_env
from training.common import write_json
from tissue_env.base import TissueEnv

RESET_SECONDS = [0.0]
_RESET_LOCK = threading.Lock()  # the threaded vector envs reset their copies on several threads
#: (label, vectorization_mode, extra make_vec keywords)
MODES = (("sync", "sync", {}), ("vector 1 thread", "vector_entry_point", dict(threads=1)),
         ("vector", "vector_entry_point", {}))
ASYNC = ("async", "async", {})
#: --busy-core: (label, vectorization_mode, extra make_vec keywords); "vector default" is threads=None
BUSY_MODES = (("sync", "sync", {}), ("vector 1 thread", "vector_entry_point", dict(threads=1)),
              (f"vector {numba.config.NUMBA_NUM_THREADS} threads", "vector_entry_point",
               dict(threads=numba.config.NUMBA_NUM_THREADS)),
              ("vector default", "vector_entry_point", {}))
LOADS = ("idle", "busy")


class Burner:
    """A busy loop in its own process pinned to one core (the last this process may use), for the
    block's duration: what a policy update in another process does to the env's cores."""

    def __enter__(self):
        self.core = max(os.sched_getaffinity(0))
        # the loop ends with this process, however it ends (its parent changes)
        loop = "import os\nparent = os.getppid()\nwhile os.getppid() == parent:\n    pass\n"
        self.process = subprocess.Popen([sys.executable, "-c", loop])
        os.sched_setaffinity(self.process.pid, {self.core})
        time.sleep(0.3)  # the loop has started and holds its core
        return self

    def __exit__(self, *exc):
        self.process.kill()
        self.process.wait()


class KernelClock:
    """This process's CPU seconds inside sim_core's compiled kernels and SuperLU's factorisations
    while the block runs (``seconds``): every numba dispatcher that a sim_core or tissue_env module
    holds by name, and ``scipy.sparse.linalg.splu``, is wrapped for the block and restored after it
    (the serial twins too: ``kernels.variant`` finds them by module and name). One thread only."""

    def __enter__(self):
        self.seconds = 0.0
        self._inside = False
        self._patched = []
        wrappers = {}
        for name, module in list(sys.modules.items()):
            if module is None or not name.startswith(("sim_core", "tissue_env")):
                continue
            for attribute, value in list(vars(module).items()):
                if isinstance(value, CPUDispatcher):
                    if id(value) not in wrappers:
                        wrappers[id(value)] = self._timed(value, value.py_func)
                    self._patched.append((module, attribute, value))
                    setattr(module, attribute, wrappers[id(value)])
        self._patched.append((spla, "splu", spla.splu))
        spla.splu = self._timed(spla.splu, spla.splu)
        return self

    def _timed(self, function, source):
        def timed(*args, **kwargs):
            if self._inside:
                return function(*args, **kwargs)
            self._inside = True
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds += time.process_time() - start
                self._inside = False
        timed.__module__, timed.__name__ = source.__module__, source.__name__
        return timed

    def __exit__(self, *exc):
        for module, attribute, value in reversed(self._patched):
            setattr(module, attribute, value)


def kernel_shares(env_id, num_envs, steps, **kwargs):
    """{mode label: the share of its CPU time inside the kernels} of sync and the one-thread vector
    env, one run each of ``steps`` vector steps (``rate``'s actions) under ``KernelClock``."""
    shares = {}
    for label, mode, extra in MODES[:2]:
        clock = KernelClock()
        cpu = num_envs * steps / rate(env_id, mode, num_envs, steps, clock=clock, **extra, **kwargs)[1]
        shares[label] = clock.seconds / cpu
    return shares


def _timed_reset(reset):
    @functools.wraps(reset)
    def wrapper(self, *args, **kwargs):
        start = time.thread_time()  # this thread's CPU time: concurrent resets are not counted twice
        try:
            return reset(self, *args, **kwargs)
        finally:
            spent = time.thread_time() - start
            with _RESET_LOCK:
                RESET_SECONDS[0] += spent
    return wrapper


TissueEnv._reset_episode = _timed_reset(TissueEnv._reset_episode)  # the episode draw, every mode's


def rate(env_id, mode, num_envs, steps, seed=0, clock=None, **kwargs):
    """(env steps per wall second, per CPU second of this process, share of the CPU time spent in
    resets) for ``steps`` vector steps of random actions; ``clock``: None or a ``KernelClock`` that
    runs over those steps."""
    envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=mode, **kwargs)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, (steps, num_envs) + envs.single_action_space.shape).astype(np.float32)
    envs.reset(seed=seed)
    for action in actions[:3]:  # warm up: compiled kernels, caches, threads
        envs.step(action)
    envs.reset(seed=seed)
    RESET_SECONDS[0] = 0.0
    with clock if clock is not None else contextlib.nullcontext():
        start, wall = time.process_time(), time.perf_counter()
        for action in actions:
            envs.step(action)
        elapsed, wall = time.process_time() - start, time.perf_counter() - wall
    resets = RESET_SECONDS[0]
    envs.close()
    return num_envs * steps / wall, num_envs * steps / elapsed, resets / elapsed


def _summary(run, own_cpu):
    """Medians of one mode's rounds (wall, CPU, reset share); the CPU rates only where the work is
    this process's (not async's worker processes)."""
    summary = dict(wall_steps_per_s=float(np.median(run[:, 0])), wall_rounds=run[:, 0].tolist())
    if own_cpu:
        summary.update(cpu_steps_per_s=float(np.median(run[:, 1])), cpu_rounds=run[:, 1].tolist(),
                       reset_share=float(np.median(run[:, 2])))
    return summary


def _cell(summary):
    cpu = summary.get("cpu_steps_per_s")
    return f"{summary['wall_steps_per_s']:6.0f} " + (f"({cpu:5.0f})" if cpu is not None else "( wall)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[16])
    parser.add_argument("--steps", type=int, default=100, help="vector steps per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--env", nargs="*", default=sorted(tissue_env.VECTOR_ENTRY_POINTS))
    parser.add_argument("--no-reset", action="store_true", help="also measure episodes that never end")
    parser.add_argument("--async", dest="with_async", action="store_true",
                        help="also measure vectorization_mode='async' (one process per copy; slow to start)")
    parser.add_argument("--busy-core", action="store_true",
                        help="measure with and without a CPU burner on one core, side by side (see the docstring)")
    parser.add_argument("--output", default=None,
                        help="default benchmarks/results/vector_env_speed.json (--busy-core: vector_env_speed_busy.json)")
    args = parser.parse_args()
    if args.output is None:
        args.output = os.path.join(os.path.dirname(__file__), "results",
                                   "vector_env_speed_busy.json" if args.busy_core else "vector_env_speed.json")
    if args.busy_core:
        return busy_core(args)
    regimes = [("registered", {})] + ([("no reset", dict(max_episode_steps=10**6))] if args.no_reset else [])
    modes = MODES + ((ASYNC,) if args.with_async else ())
    print(f"{args.steps} vector steps, random actions, median of {args.rounds} interleaved rounds, "
          f"{numba.config.NUMBA_NUM_THREADS} threads; env steps per wall second (per CPU second)")
    print(f"{'env id':32s} {'N':>3s} {'episodes':>10s} | " + " | ".join(f"{label:>15s}" for label, _, _ in modes)
          + " | vector / sync wall, 1 thread / sync CPU")
    rows = []
    for env_id in args.env:
        for num_envs in args.num_envs:
            for regime, regime_kwargs in regimes:
                results = {label: [] for label, _, _ in modes}
                for _ in range(args.rounds):
                    for label, mode, kwargs in modes:
                        results[label].append(rate(env_id, mode, num_envs, args.steps, **kwargs, **regime_kwargs))
                runs = {label: np.array(values) for label, values in results.items()}
                sync, single, vector = runs["sync"], runs["vector 1 thread"], runs["vector"]
                row = dict(env_id=env_id, num_envs=num_envs, episodes=regime, steps=args.steps, rounds=args.rounds,
                           threads=numba.config.NUMBA_NUM_THREADS,
                           modes={label: _summary(run, label != "async") for label, run in runs.items()},
                           wall_ratio=float(np.median(vector[:, 0] / sync[:, 0])),
                           cpu_ratio_one_thread=float(np.median(single[:, 1] / sync[:, 1])))
                if args.with_async:
                    row["async_wall_ratio"] = float(np.median(vector[:, 0] / runs["async"][:, 0]))
                shares = kernel_shares(env_id, num_envs, args.steps, **regime_kwargs)
                row.update(kernel_share=shares, one_thread_bound=row["cpu_ratio_one_thread"] / shares["vector 1 thread"])
                rows.append(row)
                cells = " | ".join(_cell(row["modes"][label]) for label, _, _ in modes)
                print(f"{env_id:32s} {num_envs:3d} {regime:>10s} | {cells} | {row['wall_ratio']:4.1f}x,"
                      f" {row['cpu_ratio_one_thread']:4.2f}x (kernels {100 * shares['sync']:.0f}% of sync's CPU, "
                      f"{100 * shares['vector 1 thread']:.0f}% of 1 thread's: bound {row['one_thread_bound']:.2f}x)",
                      flush=True)
                write_json(args.output, dict(
                    benchmark="vector_env_speed",
                    unit="env steps per wall second and per CPU second of the process (medians of interleaved rounds)",
                    kernel_share="share of a mode's CPU time inside sim_core's compiled kernels and SuperLU's "
                                 "factorisations (KernelClock, one more run of each mode after the rounds)",
                    one_thread_bound="cpu_ratio_one_thread over the one-thread vector env's kernel share: its "
                                     "one-thread ratio if nothing outside its kernels cost time",
                    machine=dict(cpus=os.cpu_count(), platform=platform.platform()),
                    load_average=os.getloadavg(), results=rows))


def busy_core(args):
    """``--busy-core``: every mode on the machine as it is and beside a pinned CPU burner, interleaved."""
    threads = numba.config.NUMBA_NUM_THREADS
    start_load = os.getloadavg()
    labels = [label for label, _, _ in BUSY_MODES]
    print(f"{args.steps} vector steps, random actions, median of {args.rounds} interleaved rounds, {threads} threads, "
          f"load average {start_load[0]:.2f} {start_load[1]:.2f} {start_load[2]:.2f}; env steps per wall second "
          f"(per CPU second); busy: a busy loop pinned to core {max(os.sched_getaffinity(0))}")
    print(f"{'env id':32s} {'N':>3s} {'load':>5s} | " + " | ".join(f"{label:>16s}" for label in labels)
          + " | wall / sync: " + ", ".join(labels[1:]))
    rows = []
    for env_id in args.env:
        for num_envs in args.num_envs:
            results = {(load, label): [] for load in LOADS for label in labels}
            for index in range(args.rounds):
                for load in (LOADS if index % 2 == 0 else LOADS[::-1]):
                    with (Burner() if load == "busy" else contextlib.nullcontext()):
                        for label, mode, kwargs in BUSY_MODES:
                            results[load, label].append(rate(env_id, mode, num_envs, args.steps, **kwargs))
            for load in LOADS:
                runs = {label: np.array(results[load, label]) for label in labels}
                sync = runs["sync"]
                ratios = {label: float(np.median(runs[label][:, 0] / sync[:, 0])) for label in labels[1:]}
                row = dict(env_id=env_id, num_envs=num_envs, load=load, steps=args.steps, rounds=args.rounds,
                           threads=threads, modes={label: _summary(run, True) for label, run in runs.items()},
                           wall_ratio=ratios)
                rows.append(row)
                cells = " | ".join(f"{_cell(row['modes'][label]):>16s}" for label in labels)
                print(f"{env_id:32s} {num_envs:3d} {load:>5s} | {cells} | "
                      + ", ".join(f"{ratios[label]:4.2f}x" for label in labels[1:]), flush=True)
            write_json(args.output, dict(
                benchmark="vector_env_speed --busy-core",
                unit="env steps per wall second and per CPU second of the process (medians of interleaved rounds); "
                     "wall_ratio: each vector mode's wall rate over sync's, median of the per-round ratios",
                busy="a Python busy loop in its own process pinned to one core (os.sched_setaffinity)",
                machine=dict(cpus=os.cpu_count(), platform=platform.platform()),
                load_average_start=start_load, load_average=os.getloadavg(), results=rows))


if __name__ == "__main__":
    main()
