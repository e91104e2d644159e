"""Vector environments: N copies of a task stepped by one batched physics step.

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` builds the task's
``<Task>VectorEnv``: a ``gymnasium.vector.VectorEnv`` on the task's N worlds
(``tissue_env.worlds.TaskWorlds``: one stacked sim_core model, one N-world solver, one vectorised
pass for the measurements, observations, rewards and infos). The single env is the one-world case
of the same worlds, so a copy and a single env with the same seed and actions take the same steps.
Semantics are those of ``vectorization_mode="sync"``:

- next-step autoreset (``metadata["autoreset_mode"] = AutoresetMode.NEXT_STEP``): the step after
  a copy terminates or truncates resets it (reward 0, not terminated, not truncated, the reset's
  observation and info) and ignores its action;
- ``reset(seed=s)`` seeds copy i with s + i (a list gives one seed per copy);
  ``options={"reset_mask": mask}`` resets only the masked copies;
- infos are dicts of arrays with a boolean ``_key`` mask per key;
- the registered ``max_episode_steps`` truncates, as gymnasium's TimeLimit does.

Every copy has a task environment (``self.envs[i]``) that draws its episodes (its own
``np_random``, goal, inclusion ...), so a vector env and N single envs with the same seeds draw the
same episodes (tests/test_env_vector.py).

The vector env does several times the env steps per second of ``vectorization_mode="sync"``, on
one thread (``threads=1``) as on several (benchmarks/vector_env_speed.py measures it; the
performance page). With its default threads it times its own steps and runs each on every core or on
one, whichever is faster at the moment (``TissueVectorEnv``: the threads help on idle cores and slow
every step down when another process holds a core). numba's idle threads spin briefly between
parallel regions before they sleep (``kernels.start_threads``). How each task's worlds solve their linear systems (``linear_solver``
of its ``TaskWorlds``) is documented in ``sim_core.solvers.implicit``. The copies' resets (their task
envs' episode draws) run on a pool of as many Python threads (``_reset_rows``; a static solve
releases the GIL for most of its time).
"""

from __future__ import annotations

import contextlib
import os
import time
import weakref
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.vector.vector_env import AutoresetMode

from sim_core import kernels


#: the vector envs whose reset pool has threads: stopped before a fork (CPython's threading failed in
#: a child forked with the pool's idle threads alive, "Exception ignored in ... _after_fork ...
#: SystemError"); a pool restarts at the next threaded reset
_POOLED: "weakref.WeakSet" = weakref.WeakSet()


def _stop_reset_pools():
    for env in list(_POOLED):
        env._stop_pool()


os.register_at_fork(before=_stop_reset_pools)


def _thread_count(threads) -> int:
    """The vector env's thread count (see ``TissueVectorEnv``), checked; starts numba's pool with
    briefly spinning idle threads (``kernels.start_threads``) when it uses more than one (one
    thread, and a forked process, use the serial kernels and never start it)."""
    available = kernels.available_threads()
    if threads is None:
        threads = available
    elif isinstance(threads, bool) or not float(threads).is_integer() or not 1 <= int(threads) <= available:
        raise ValueError(f"threads must be None or an integer from 1 to {available} (numba's NUMBA_NUM_THREADS, "
                         f"the cores it found), got {threads!r}")
    if kernels.threaded(int(threads)):
        kernels.start_threads()
    return int(threads)


#: Default threads (``threads=None``): steps timed per thread count before the two are compared (the
#: median of each; the first step after a change is not timed: threads that slept wake in it)
TRIAL_STEPS = 4
#: Default threads: steps between two comparisons, first and at most (the interval doubles each time
#: the comparison keeps the count, and returns to the first after a change)
CHECK_INTERVAL = 50
MAX_CHECK_INTERVAL = 400
#: Default threads: a comparison also starts early when the median of the last ``TRIAL_STEPS`` steps
#: is this many times that of the steps which chose the count (another process took a core)
SLOWDOWN = 1.5


class _ThreadChooser:
    """The default thread count's run-time choice (see ``TissueVectorEnv``): every core (``most``)
    or one, whichever ran the last comparison's steps faster (wall time of the physics step, the
    resets excluded), compared again every ``interval`` steps or when the steps slow down."""

    def __init__(self, most: int):
        self.most = most
        self.active = most  # the count the steps run on
        self.trial = None  # during a comparison: the count on trial
        self.skip = 1  # untimed steps left (the first after a change)
        self.times = []  # this count's timed steps since its last change
        self.reference = None  # the median step time of the count in use when it was chosen
        self.incumbent = None  # during a comparison: the median of the count the comparison started on
        self.interval = CHECK_INTERVAL
        self.until_check = TRIAL_STEPS + 1  # the first comparison: once every count has been timed

    def record(self, seconds: float):
        """Take one physics step's wall time on ``active`` threads; maybe change ``active``."""
        if self.skip:
            self.skip -= 1
            return
        self.times.append(seconds)
        del self.times[:-TRIAL_STEPS]
        if self.trial is None:
            self.until_check -= 1
            slowed = (self.reference is not None and len(self.times) == TRIAL_STEPS
                      and float(np.median(self.times)) > SLOWDOWN * self.reference)
            if (self.until_check <= 0 or slowed) and len(self.times) == TRIAL_STEPS:
                self.incumbent = float(np.median(self.times))
                self.trial = 1 if self.active != 1 else self.most
                self._switch(self.trial)
        elif len(self.times) == TRIAL_STEPS:
            candidate = float(np.median(self.times))
            incumbent_count = self.most if self.trial == 1 else 1
            if candidate < self.incumbent:  # the trial's count wins: keep it
                self.reference = candidate
                self.interval = CHECK_INTERVAL
                self.trial = None
                self.until_check = self.interval
                self.times = []
            else:
                self.reference = self.incumbent
                self.interval = min(2 * self.interval, MAX_CHECK_INTERVAL)
                self.trial = None
                self._switch(incumbent_count)
                self.until_check = self.interval

    def _switch(self, count: int):
        self.active = count
        self.skip = 1
        self.times = []


class TissueVectorEnv(VectorEnv):
    """Base class of the tasks' vector environments (see the module docstring).

    Args:
        num_envs: number of copies N.
        max_episode_steps: truncation length (the registered one when built by ``make_vec``),
            None for none.
        threads: threads of the batched step's per-copy force passes, products, factorisations and
            solves (numba's pool) and of the copies' resets (a Python thread pool); the copies are
            independent, so the results are the same for any count (bit for bit; also when the
            count changes between steps). An integer fixes the count: 1 keeps to one core (several
            env processes on one machine, e.g. RLlib env runners), ``NUMBA_NUM_THREADS`` (numba's
            default: every core) uses them all. None, the default, builds the env for every core
            and chooses at run time between every core and one (``active_threads``): it times the
            physics part of its steps (wall clock, resets excluded) on each, keeps the faster, and
            compares again every ``CHECK_INTERVAL`` steps (the interval doubles, up to
            ``MAX_CHECK_INTERVAL``, while the choice holds) or as soon as its steps run
            ``SLOWDOWN`` times slower than when it chose. On idle cores that keeps the threads' gain
            but for the few steps on trial; when another process holds a core (a policy training in
            another process), every parallel region would wait for the thread that lost its core,
            and the env runs on one (the one-thread speed, several times sync, instead of slower
            than sync; benchmarks/vector_env_speed.py ``--busy-core``). In a process forked from one
            that may have started the pool, the env uses one thread: GNU OpenMP's pool is not
            fork-safe (``kernels.FORKED``).
        **kwargs: the task's constructor keywords, the same for every copy.
    """

    #: The task class; set by each task's vector env.
    env_class = None
    metadata = {"render_modes": ["rgb_array", "depth_array"], "render_fps": 10,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = None, threads: int | None = None,
                 **kwargs):
        if isinstance(num_envs, bool) or not float(num_envs).is_integer() or int(num_envs) < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.threads = _thread_count(threads)
        #: the run-time choice of the default threads (None: a fixed count)
        self._chooser = _ThreadChooser(self.threads) if threads is None and kernels.threaded(self.threads) else None
        if max_episode_steps is not None and int(max_episode_steps) < 1:
            raise ValueError(f"max_episode_steps must be None or an integer >= 1, got {max_episode_steps!r}")
        if kwargs.get("render_mode") == "human":
            raise ValueError("render_mode='human' is not supported by the vector env; use 'rgb_array'")
        self.num_envs = count = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.envs = [self.env_class(**kwargs) for _ in range(count)]
        env = self.envs[0]
        # The copies were built from the same keywords: they share the models (a Palpation model per
        # inclusion cell, a new one per domain-randomised draw), their start states and the
        # task's caches, built once instead of once per copy.
        for copy in self.envs[1:]:
            copy.share_caches(env)
        self.render_mode = env.render_mode
        self.metadata = dict(self.metadata, render_fps=env.metadata["render_fps"])
        self.single_observation_space = env.observation_space
        self.single_action_space = env.action_space
        self.observation_space = batch_space(env.observation_space, count)
        self.action_space = batch_space(env.action_space, count)
        #: the copies' worlds: the env step, written once for one or many worlds
        self.worlds = env.worlds_class(self.envs, threads=self.threads)
        self._autoreset = np.zeros(count, dtype=bool)
        self._pool = None  # the reset threads (``_reset_rows``), started at the first threaded reset
        self._started = False
        self._observations = None

    @property
    def active_threads(self) -> int:
        """The threads the next step runs on: ``threads``, or with the default threads the count the
        run-time choice holds (``threads`` or 1)."""
        return self.threads if self._chooser is None else self._chooser.active

    @contextlib.contextmanager
    def _on_active_threads(self):
        """numba's thread count set to ``active_threads`` inside the block when the env is built for
        several (its parallel kernels; their floats do not depend on the count), restored after."""
        if not kernels.threaded(self.threads):
            yield
            return
        with kernels.thread_count(self.active_threads):
            yield

    @property
    def reset_pool_running(self) -> bool:
        """Whether the thread pool that resets the copies (``threads`` > 1) is running: started at
        the first threaded reset, stopped by ``close`` and before a fork."""
        return self._pool is not None

    def _stop_pool(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        _POOLED.discard(self)

    def _reset_rows(self, rows, seeds, options):
        """Reset the copies ``rows`` (indices): each task env draws its episode
        (``TissueEnv._reset_episode``), on ``threads`` Python threads when the vector env has more
        than one (``kernels.threaded``): most of a reset's time (a goal or start solve: SuperLU,
        the nogil compiled kernels) runs without the GIL, and each copy's reset reads only its own
        env and the lock-guarded shared caches, so the results are those of the serial loop. Then
        each copy is loaded into the worlds, in row order, and measured. Returns the worlds'
        (observations, infos) of that measurement."""
        envs = self.envs

        def reset(index):
            envs[index]._reset_episode(seed=seeds[index], options=options)

        if len(rows) > 1 and kernels.threaded(self.active_threads):
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="tissue-reset")
                _POOLED.add(self)
            list(self._pool.map(reset, rows))
        else:
            for index in rows:
                reset(index)
        for index in rows:
            self.worlds.load(index)
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[rows] = True
        return self.worlds.observe(mask)

    # -- Gymnasium vector API -----------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        count = self.num_envs
        if seed is None:
            seeds = [None] * count
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(count)]
        else:
            seeds = list(seed)
            if len(seeds) != count:
                raise ValueError(f"If seeds are passed as a list the length must match num_envs={count} "
                                 f"but got length={len(seeds)}.")
        options = dict(options) if options is not None else None
        mask = np.ones(count, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = options.pop("reset_mask")
            if not isinstance(mask, np.ndarray) or mask.shape != (count,) or mask.dtype != np.bool_:
                raise ValueError(f"options['reset_mask'] must be a bool numpy array of shape ({count},)")
            if not mask.any():
                raise ValueError("options['reset_mask'] must contain at least one True value")
            if not self._started and not mask.all():
                raise ValueError("the first reset must reset every copy")
        rows = np.flatnonzero(mask)
        with self._on_active_threads():
            observations, infos = self._reset_rows(rows, seeds, options)
        self._autoreset[rows] = False
        self._started = True
        if self._observations is None:
            self._observations = observations
        else:
            _put_rows(self._observations, observations, mask)
        return _copy(self._observations), _masked(infos, mask)

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        with self._on_active_threads():  # serial kernels when built for one thread: the pool is not touched
            return self._step(actions)

    def _step(self, actions):
        count = self.num_envs
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (count,) + self.single_action_space.shape:
            raise ValueError(f"actions must have shape {(count,) + self.single_action_space.shape}, got {actions.shape}")
        resetting = self._autoreset.copy()
        active = ~resetting
        if not np.all(np.isfinite(actions[active])):
            raise ValueError(f"actions must be finite (no NaN or infinity), got {actions.tolist()}")
        reset_rows = np.flatnonzero(resetting)
        if len(reset_rows):
            reset_observations, reset_infos = self._reset_rows(reset_rows, [None] * count, None)
        start = time.perf_counter()
        observations, total, terminated, infos = self.worlds.step(actions, active)
        if self._chooser is not None:  # the default threads: time the physics, maybe change the count
            self._chooser.record(time.perf_counter() - start)
        truncated = np.zeros(count, dtype=bool)
        if self.max_episode_steps is not None:
            truncated = self.worlds.elapsed >= self.max_episode_steps
        if len(reset_rows):  # rows reset in this call: their reset's observation and info
            total[resetting] = 0.0
            terminated[resetting] = False
            truncated[resetting] = False
            _put_rows(observations, reset_observations, resetting)
            for key, value in reset_infos.items():
                infos[key][resetting] = value[resetting]
        self._autoreset = (terminated | truncated) & active
        self._observations = observations
        return _copy(observations), total, terminated, truncated, _masked(infos, np.ones(count, dtype=bool))

    # -- goal-conditioned API (observation_type="goal") -----------------------------------------------
    @property
    def compute_reward(self):
        """The task's ``compute_reward(achieved_goal, desired_goal, info)`` (``TissueEnv.compute_reward``;
        a step's infos as the vector env gives them, a dict of (N,) arrays, are one info per copy).
        Present only with ``observation_type="goal"``."""
        if self.envs[0].observation_type != "goal":
            raise AttributeError(f"compute_reward exists only with observation_type='goal' (this env has "
                                 f"observation_type={self.envs[0].observation_type!r})")
        return self.worlds.compute_reward

    # -- rendering and closing -------------------------------------------------------------------------
    def render(self):
        if self.render_mode is None:
            return None
        if not self._started:
            raise RuntimeError("call reset() before render()")
        if self.render_mode == "depth_array":  # every copy's camera depth (H, W) float32 m
            return tuple(self.worlds.camera_images()[1].astype(np.float32))
        frames = []
        for index, env in enumerate(self.envs):
            self.worlds.write_back(index)
            frames.append(env.render())
        return tuple(frames)

    def close_extras(self, **kwargs):
        self._stop_pool()
        for env in self.envs:
            env.close()


def _put_rows(out, observations, rows):
    """Copy the ``rows`` (N,) bool of the batched ``observations`` into ``out`` (in place)."""
    if isinstance(out, dict):
        for name in out:
            out[name][rows] = observations[name][rows]
    else:
        out[rows] = observations[rows]


def _copy(observations):
    if isinstance(observations, dict):
        return {name: array.copy() for name, array in observations.items()}
    return observations.copy()


def _masked(infos, present):
    """Gymnasium's vector info layout: each key's (N, ...) values and a ``_key`` (N,) bool mask of
    the copies that have it."""
    out = {}
    for key, value in infos.items():
        out[key] = value
        out[f"_{key}"] = present.copy()
    return out
