"""The cutting tasks' figures (benchmarks/incision_figure.py, benchmarks/dissection_figure.py): a
view of the cut tissue drawn by the task's module beside the agent's rgb observation of the same state."""

import gymnasium as gym
import numpy as np

import tissue_env  # noqa: F401  (registers the envs)


def scripted_state(env_id, seed, steps, settle=0):
    """(the env, its rgb observation (64 x 64 px), the last info) after ``steps`` steps of the task's
    scripted controller (fewer if the episode ends) and ``settle`` steps of the blade held still."""
    env = gym.make(env_id, observation_type="rgb")
    observation, info = env.reset(seed=seed)
    for _ in range(steps):
        observation, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
        if terminated or truncated:
            break
    for _ in range(settle):
        observation, *_, info = env.step(np.zeros(env.action_space.shape, np.float32))
    return env.unwrapped, observation, info


def element_corners(env):
    """(M, 8, 3) m each element's corners at its world's positions (each side of a cut apart)."""
    worlds = env.worlds
    return worlds.corner_positions(worlds.positions)[0].reshape(-1, 8, 3)


def save(draw, image, output, height, **axes):
    """Draw the left panel (``draw(axes)``, then ``axes.set(**axes)``, equal aspect, a legend) beside
    ``image``, the agent's rgb observation, into ``output``; the figure is 10 x ``height`` inches."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (left, right) = plt.subplots(1, 2, figsize=(10, height), gridspec_kw=dict(width_ratios=[1.5, 1]))
    draw(left)
    left.set(aspect="equal", **axes)
    right.imshow(image)
    right.set_axis_off()
    right.set_title("the agent's rgb observation", fontsize=9)
    figure.tight_layout()
    figure.savefig(output, dpi=120)
    print(f"wrote {output}")
