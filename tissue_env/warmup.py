"""``tissue-gym-warmup``: compile every numba kernel the environments call, once, into numba's cache,
so that a first env step after an install takes a fraction of a second instead of minutes.

    tissue-gym-warmup [--steps 3] [--num-envs 2]      # or: python -m tissue_env.warmup

It builds every registered task and its batched vector env, resets and steps them (and the other
integrators and elements of ``VARIANTS`` and ``VECTOR_VARIANTS``, and Incision's scripted cuts), and
prints what it did and how long it took. Bad arguments end with exit code 2 and a one-line message."""

from __future__ import annotations

import argparse
import sys
import time


#: Keywords whose kernels the defaults do not reach: the explicit and static integrators, and the
#: tetrahedral organ (its smoothed strain and element volumes), each on one task.
VARIANTS = (("tissue_env/TumorPositioning-v0", dict(integrator="explicit")),
            ("tissue_env/TumorPositioning-v0", dict(integrator="static")),
            ("tissue_env/LiverNeedleAlignment-v0", dict(element="tet")))
#: Vector envs past the defaults: the explicit integrator's stacked force pass on two numba threads
#: (the stress correction copy by copy), where the machine has two.
VECTOR_VARIANTS = (("tissue_env/TumorPositioning-v0", dict(integrator="explicit", threads=2)),)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tissue-gym-warmup", description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3, help="steps per env (default 3)")
    parser.add_argument("--num-envs", type=int, default=2, help="copies of each vector env (default 2)")
    return parser


def _step(make, steps, label):
    """Build an env with ``make()``, reset it, step it ``steps`` times with random actions, close it,
    and print ``label`` and the time all that took."""
    start = time.perf_counter()
    env = make()
    env.reset(seed=0)
    for _ in range(steps):
        env.step(env.action_space.sample())
    env.close()
    print(f"{label}: built, reset and stepped {steps} times in {time.perf_counter() - start:.1f} s", flush=True)


#: Steps of Incision's scripted controller that warm-up takes: past the first cuts that copy nodes,
#: so that a cut world's own solver and measurements (internal forces on its model) are compiled.
CUT_STEPS = 18


def _cut(label):
    """Step Incision's scripted incision ``CUT_STEPS`` times (a cut world) and print the time."""
    import gymnasium as gym

    start = time.perf_counter()
    env = gym.make("tissue_env/Incision-v0")
    env.reset(seed=0)
    for _ in range(CUT_STEPS):
        env.step(env.unwrapped.scripted_action())
    env.close()
    print(f"{label}: {CUT_STEPS} scripted steps through cuts in {time.perf_counter() - start:.1f} s", flush=True)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.steps < 1 or args.num_envs < 1:
        sys.stderr.write("tissue-gym-warmup: error: --steps and --num-envs must be >= 1\n")
        return 2
    import gymnasium as gym

    import tissue_env
    from sim_core.kernels import available_threads

    total = time.perf_counter()
    for env_id in tissue_env.ENV_IDS:
        _step(lambda: gym.make(env_id), args.steps, env_id)
        if env_id in tissue_env.VECTOR_ENTRY_POINTS:
            _step(lambda: gym.make_vec(env_id, num_envs=args.num_envs, vectorization_mode="vector_entry_point"),
                  args.steps, f"{env_id} vector env (N = {args.num_envs})")
    for env_id, keywords in VARIANTS:
        _step(lambda: gym.make(env_id, **keywords), args.steps, f"{env_id} {keywords}")
    for env_id, keywords in VECTOR_VARIANTS if available_threads() > 1 else ():
        _step(lambda: gym.make_vec(env_id, num_envs=args.num_envs, vectorization_mode="vector_entry_point",
                                   **keywords), args.steps, f"{env_id} vector env {keywords}")
    _cut("tissue_env/Incision-v0 cutting")
    print(f"warmup done in {time.perf_counter() - total:.1f} s: the kernels are compiled and cached", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
