"""The probe force as the agent reads it, stepped by implicit Euler and by static equilibria.

Usage: python -m benchmarks.lag_figure [--output docs/figures/static_vs_implicit.png]

Palpation (its defaults: ``baudet-hyperelastic``), the probe over the middle of the slab (over the inclusion), pressed
at full speed (``max_step`` = 4 mm per env step) to 8 mm, held for 6 steps and lifted at full
speed, once with ``integrator="implicit"`` (the default) and once with ``integrator="static"``
(``sim_core.solvers.static.QuasiStatic``): the vertical force the probe exerts (N) at every env step. The
implicit tissue lags behind the probe (mass and damping) and settles on the static reading when
the probe is held. The success press does not end the episode here. Writes the figure atomically
and prints the readings.
"""

import argparse

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import tissue_env  # noqa: E402,F401  (registers the tasks)
from sim_core.files import finish_figure  # noqa: E402

DEPTH_STEPS, HOLD_STEPS = 3, 6  # 2 mm above the surface + 2 steps of 4 mm, then held


def press(integrator, seed=0, inspect=None, **kwargs):
    """(tip depth (m, positive below the surface), probe force (N, downward positive)) per env step
    of the press (``kwargs``: Palpation's keywords, e.g. ``model``; ``inspect(env)``, when given, is
    called with the unwrapped env after each of them)."""
    env = gym.make("tissue_env/Palpation-v0", integrator=integrator, **kwargs)
    env.reset(seed=seed)
    unwrapped = env.unwrapped
    unwrapped.terminate_on_success = False  # keep pressing after the success press
    centre = unwrapped.inclusion_centre
    depths, forces = [], []
    # move over the inclusion at the surface, then down, hold, up
    while np.hypot(*(unwrapped._tip() - centre)[[0, 2]]) > 1e-9:
        offset = np.array([centre[0], unwrapped._tip()[1], centre[2]]) - unwrapped._tip()
        env.step(np.clip(offset / unwrapped.max_step, -1, 1).astype(np.float32))
    actions = [(0, -1, 0)] * DEPTH_STEPS + [(0, 0, 0)] * HOLD_STEPS + [(0, 1, 0)] * DEPTH_STEPS
    for action in actions:
        _, _, terminated, truncated, info = env.step(np.array(action, np.float32))
        depths.append(info["depth"])
        forces.append(-float(unwrapped.measures["reaction_force"][1]))
        if inspect is not None:
            inspect(unwrapped)
        if terminated or truncated:
            break
    env.close()
    return np.array(depths), np.array(forces)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default="docs/figures/static_vs_implicit.png")
    args = parser.parse_args(argv)
    runs = {name: press(name) for name in ("implicit", "static")}
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    for name, (depth, force) in runs.items():
        steps = np.arange(1, len(force) + 1)
        top.plot(steps, 1e3 * depth, "o-" if name == "static" else "s--", label=name)
        bottom.plot(steps, force, "o-" if name == "static" else "s--", label=name)
        print(name, "depth mm", np.round(1e3 * depth, 2).tolist(), "force N", np.round(force, 3).tolist())
    top.set_ylabel("probe depth (mm)")
    bottom.set_ylabel("probe force (N)")
    bottom.set_xlabel("env step (40 ms)")
    bottom.legend()
    top.set_title("Palpation: a press at full speed, held, lifted (over the inclusion)")
    finish_figure(fig, args.output, dpi=90)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
