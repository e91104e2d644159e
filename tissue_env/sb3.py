"""stable-baselines3 on the tasks' batched vector envs (``tissue_env.vector``).

Needs stable-baselines3 (``pip install "tissue-gym[train]"``); ``import tissue_env`` does not
import this module::

    from stable_baselines3 import PPO
    from tissue_env.sb3 import BatchedVecEnv
    model = PPO("MlpPolicy", BatchedVecEnv("tissue_env/TumorPositioning-v0", n_envs=8)).learn(10_000)

``BatchedVecEnv`` is a stable-baselines3 ``VecEnv`` over ``gym.make_vec(id, num_envs=N,
vectorization_mode="vector_entry_point")``: the N copies are stepped by one batched physics step
in this process, on numba's threads (``threads``), instead of N single envs in this process
(``DummyVecEnv``) or in N worker processes (``SubprocVecEnv``). The clone's ``python -m
training.train --vec-env batched`` uses it; ``monitored`` adds stable-baselines3's ``VecMonitor`` (one monitor CSV for the
N copies, appended to when a run resumes).

Semantics are stable-baselines3's: a copy that terminates or truncates is reset in the same
``step_wait`` (its info holds ``terminal_observation`` and ``TimeLimit.truncated``, and the
returned observation is the new episode's first), where the gymnasium vector env resets it at the
next step; infos are one dict per copy; ``seed(s)`` seeds copy i with s + i at the next reset, as
``make_vec_env`` seeds its envs. So the copies draw the episodes that ``make_vec_env``'s envs draw
with the same seed, and step them with the same physics (tests/test_training.py).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

try:
    from stable_baselines3.common.vec_env import VecEnv, VecMonitor
except ImportError as error:  # a clear hint instead of a bare ModuleNotFoundError
    raise ImportError("tissue_env.sb3 needs stable-baselines3: pip install \"tissue-gym[train]\" "
                      "(or pip install stable-baselines3)") from error


class BatchedVecEnv(VecEnv):
    """A stable-baselines3 ``VecEnv`` of ``n_envs`` copies of the task ``env_id`` stepped by its
    batched vector env (see the module docstring).

    Args:
        env_id: a registered task id with a ``vector_entry_point`` (``tissue_env/<Task>-v0``).
        n_envs: number of copies N.
        env_kwargs: the task's constructor keywords, the same for every copy.
        threads: the vector env's threads (numba's, for the per-copy solves, factorisations and
            force passes, and the reset pool's): None every core or one, whichever its timed steps
            find faster (``TissueVectorEnv``), 1 serial (the same floats).
    """

    def __init__(self, env_id: str, n_envs: int, env_kwargs: dict | None = None, threads: int | None = None):
        import tissue_env  # noqa: F401  (registers the tasks)

        if env_kwargs and "threads" in env_kwargs:
            raise ValueError("BatchedVecEnv takes the vector env's threads as its own threads= argument "
                             "(training.train: --env-threads), not in env_kwargs")
        if env_id not in tissue_env.VECTOR_ENTRY_POINTS:
            raise ValueError(f"{env_id!r} has no batched vector env; those with one: "
                             f"{', '.join(sorted(tissue_env.VECTOR_ENTRY_POINTS))}")
        self.vector_env = gym.make_vec(env_id, num_envs=int(n_envs), vectorization_mode="vector_entry_point",
                                       threads=threads, **(env_kwargs or {}))
        self.spec = gym.spec(env_id)
        self._actions = None
        super().__init__(int(n_envs), self.vector_env.single_observation_space,
                         self.vector_env.single_action_space)

    # -- stepping -------------------------------------------------------------------------------------
    def reset(self):
        seed = self._seeds[0]
        options = self._options[0]
        if any(other != options for other in self._options):
            raise ValueError("BatchedVecEnv resets every copy with the same options (set_options with one "
                             f"dict); got {self._options}")
        observations, infos = self.vector_env.reset(seed=seed, options=options or None)
        self.reset_infos = self._split(infos)
        self._reset_seeds()
        self._reset_options()
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        observations, rewards, terminated, truncated, infos = self.vector_env.step(self._actions)
        dones = terminated | truncated
        infos = self._split(infos)
        if dones.any():
            for index in np.flatnonzero(dones):
                infos[index]["terminal_observation"] = observations[index].copy()
                infos[index]["TimeLimit.truncated"] = bool(truncated[index] and not terminated[index])
            fresh, reset_infos = self.vector_env.reset(options={"reset_mask": dones})
            observations = observations.copy()
            observations[dones] = fresh[dones]
            for index, info in enumerate(self._split(reset_infos)):
                if dones[index]:
                    self.reset_infos[index] = info
        return observations, rewards.astype(np.float32), dones, infos

    def _split(self, infos: dict) -> list[dict]:
        """The gymnasium vector env's infos (dicts of arrays, each with a ``_key`` mask) as one dict per
        copy."""
        out = [{} for _ in range(self.num_envs)]
        for key, values in infos.items():
            if key.startswith("_"):
                continue
            mask = infos.get("_" + key, np.ones(self.num_envs, dtype=bool))
            rows = self._split(values) if isinstance(values, dict) else values
            for index in np.flatnonzero(mask):
                out[index][key] = rows[index]
        return out

    def close(self) -> None:
        self.vector_env.close()

    # -- the copies -----------------------------------------------------------------------------------
    def _copies(self, indices):
        return [self.vector_env.unwrapped.envs[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices=None) -> list:
        if attr_name == "render_mode":
            return [self.vector_env.render_mode] * len(list(self._get_indices(indices)))
        return [getattr(env, attr_name) for env in self._copies(indices)]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        raise AttributeError("BatchedVecEnv copies share one batched state; set attributes through "
                             "the task's keywords instead")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        return [getattr(env, method_name)(*method_args, **method_kwargs) for env in self._copies(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(list(self._get_indices(indices)))

    def get_images(self):
        frames = self.vector_env.render()
        return list(frames) if frames is not None else [None] * self.num_envs


def monitored(venv: BatchedVecEnv, filename: str | None, append: bool = False,
              info_keywords: tuple[str, ...] = ("is_success",)) -> VecMonitor:
    """``venv`` in stable-baselines3's ``VecMonitor`` writing ``filename`` (``.monitor.csv`` is
    added), appended to when ``append`` (a resumed run keeps its episodes)."""
    from stable_baselines3.common.monitor import ResultsWriter

    monitor = VecMonitor(venv, None, info_keywords=info_keywords)
    if filename is not None:
        monitor.results_writer = ResultsWriter(filename, header={"t_start": monitor.t_start, "env_id": venv.spec.id},
                                               extra_keys=info_keywords, override_existing=not append)
    return monitor
