"""Run one episode with a policy: the loop that tests, benchmarks and evaluation share."""

from __future__ import annotations


def run_episode(env, policy, seed: int, frames: list | None = None):
    """Reset ``env`` with ``seed`` (the action space too) and act with ``policy(env)`` until the
    episode ends. Returns (total reward, number of steps, last info); appends rendered frames to
    ``frames`` when given."""
    env.reset(seed=int(seed))
    env.action_space.seed(int(seed))
    total, steps = 0.0, 0
    while True:
        _, reward, terminated, truncated, info = env.step(policy(env))
        total += float(reward)
        steps += 1
        if frames is not None:
            frames.append(env.render())
        if terminated or truncated:
            return total, steps, info


def scripted_policy(env):
    """The task's hand-written controller (``env.unwrapped.scripted_action()``)."""
    return env.unwrapped.scripted_action()


def random_policy(env):
    """Uniform random actions from the (seeded) action space."""
    return env.action_space.sample()
