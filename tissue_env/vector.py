"""Vector environments: N copies of a task stepped by one batched physics step.

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` builds the task's
``<Task>VectorEnv``: a ``gymnasium.vector.VectorEnv`` whose N copies share one stacked sim_core
model (``sim_core.batched``). One env step of all copies is one batched implicit Euler step and
one vectorised pass for the measurements, observations, rewards and infos, instead of N Python
step calls. Semantics are those of ``vectorization_mode="sync"``:

- next-step autoreset (``metadata["autoreset_mode"] = AutoresetMode.NEXT_STEP``): the step after
  a copy terminates or truncates resets it (reward 0, not terminated, not truncated, the reset's
  observation and info) and ignores its action;
- ``reset(seed=s)`` seeds copy i with s + i (a list gives one seed per copy);
  ``options={"reset_mask": mask}`` resets only the masked copies;
- infos are dicts of arrays with a boolean ``_key`` mask per key;
- the registered ``max_episode_steps`` truncates, as gymnasium's TimeLimit does.

Every copy is a task environment (``self.envs[i]``): resets run its own ``reset`` (its
``np_random``, goal, inclusion ...), so a vector env and N single envs with the same seeds draw the
same episodes, and their trajectories agree up to the linear solvers' tolerance
(tests/test_env_vector.py). Only the per-step work is batched. A task provides the vectorised
counterparts of its hooks (``_batch_control``, ``_batch_task_measures``, ...).

The vector env does several times the env steps per second of ``vectorization_mode="sync"``, on
one thread (``threads=1``) as on several (benchmarks/vector_env_speed.py measures it; the
performance page). numba's idle threads spin briefly between parallel regions before they sleep
(``kernels.start_threads``).
TumorPositioning's copies are preconditioned by one node-block LDL^T of the start matrix's
symmetric part that they share (solver "reference") and solved in lockstep chunks of 8 on numba's
threads (``kernels.solve_copies_grouped``: one pass over the factor and the hourglass matrix for all
of a chunk's running copies); Palpation's and Retraction's by their own node-block LDL^T factors,
capacitance-corrected for their contacts (solver "factorised"), a copy per thread at a time
(``kernels.solve_copies_lu``), and their factorisations (``kernels.factor_copies``) run on the
threads too. The copies' resets (their task envs' own ``reset``) run on a pool of as many Python
threads (``_reset_rows``; a static solve releases the GIL for most of its time). Every task measures
with the next step's force pass (``share_force_pass``), the force pass reads each distinct hourglass
matrix once for all its copies (``sim_core.stack.StackedForceWorkspace``) and the per-copy solves read it in
node blocks. What batching cannot share is each copy's own sparse algebra (Retraction's floor
re-factorises at about two steps in three) and TumorPositioning's resets (a static solve for the
goal, the same code in both modes: a large share of its vector env's CPU time).
"""

from __future__ import annotations

import os
import weakref
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.vector.vector_env import AutoresetMode

from sim_core import kernels
from sim_core.batched import BatchedImplicitEuler, make_batched_integrator
from sim_core.model import Control, State
from sim_core.stack import ModelStack, StackedForceWorkspace

from .base import observation_arrays


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


class TissueVectorEnv(VectorEnv):
    """Base class of the tasks' vector environments (see the module docstring).

    Args:
        num_envs: number of copies N.
        max_episode_steps: truncation length (the registered one when built by ``make_vec``),
            None for none.
        threads: threads of the batched step's per-copy force passes, products, factorisations and
            solves (numba's pool) and of the copies' resets (a Python thread pool); the copies are
            independent, so the results are the same for any count: None for
            numba's default (every core, or ``NUMBA_NUM_THREADS``), 1 to keep to one core (several
            env processes on one machine, e.g. RLlib env runners). In a process forked from one
            that may have started the pool, the env uses one thread: GNU OpenMP's pool is not
            fork-safe (``kernels.FORKED``).
        **kwargs: the task's constructor keywords, the same for every copy.
    """

    #: The task class; set by each task's vector env.
    env_class = None
    #: How the batched implicit step solves each copy's linear system (``sim_core.batched``):
    #: "factorised" (each copy's sparse LU kept across steps), "reference" (the sparse LU of the
    #: start-of-episode system matrix, shared by the copies that start alike), both solved per copy
    #: on numba's threads, or "jacobi" (the Jacobi diagonal, all copies in lockstep).
    linear_solver = "factorised"
    #: The measurement's force pass is also the next implicit step's (``BatchedImplicitEuler.linearise``
    #: at the new state, plus the springs' damping forces): one pass over the stacked model per step
    #: instead of two. The reaction force then differs from the single env's by rounding only; off for
    #: tasks whose contact decisions read the sign of nodal forces.
    share_force_pass = False
    #: solver "factorised": None, or the iterations beyond the fresh count after which a copy's
    #: factor is refreshed (``BatchedImplicitEuler``'s ``amortise``; for scenes whose matrix changes
    #: fast and factorises cheaply, e.g. Retraction)
    refactor_amortise = None
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = None, threads: int | None = None,
                 **kwargs):
        if isinstance(num_envs, bool) or not float(num_envs).is_integer() or int(num_envs) < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.threads = _thread_count(threads)
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

        self.stack = ModelStack(env.model, count)
        self._forces = StackedForceWorkspace(self.stack, implicit=False, threads=self.threads)  # measurements
        self.integrator = make_batched_integrator(env.integrator_name, self.stack, env.solver_tolerance,
                                                  self.linear_solver, self.refactor_amortise, self.threads)
        self.mesh = env.mesh
        self.n_nodes = env.mesh.n_nodes
        self.springs = env.model.springs
        self.rest_length = self.stack.model.rest_length.reshape(count, -1)
        self.positions = np.tile(env.mesh.nodes, (count, 1, 1))
        self.velocities = np.zeros_like(self.positions)
        self._lengths = self.rest_length.copy()  # spring lengths (N, S) m of the current state
        self.tool_offset = np.zeros((count, 3))
        self.workspace_low = np.zeros((count, 3))
        self.workspace_high = np.zeros((count, 3))
        self.rest_volume = np.ones(count)
        self.episode_young_modulus = np.zeros(count)  # each copy's material this episode (Pa, -)
        self.episode_poisson_ratio = np.zeros(count)
        self.elapsed = np.zeros(count, dtype=int)
        self._no_force = np.zeros_like(self.positions)  # the worlds' loads are their models' gravity
        self._autoreset = np.zeros(count, dtype=bool)
        self._pool = None  # the reset threads (``_reset_rows``), started at the first threaded reset
        self._started = False
        self._observations = None
        self._feature_sizes = env._feature_sizes
        self.reward_names = env.reward_names + ("instability",)
        # constants shared by every copy (the same keywords built them)
        for name in ("max_step", "dt", "substeps", "instability_penalty", "terminate_on_success", "volume_weight",
                     "strain_weight", "strain_threshold"):
            setattr(self, name, getattr(env, name))

    # -- hooks a task implements (vectorised counterparts of TissueEnv's) -----------------------------
    def _load_task(self, index: int, env):
        """Copy the episode's task data (goal, tumour ...) of ``env`` after its reset into row ``index``."""

    def _batch_control(self):
        """(fixed (N, n, 3) bool, target (N, n, 3) m, tool_mask (N, n, 3) bool) for the current
        tool offsets and state (the stacked ``TissueEnv._control``)."""
        raise NotImplementedError

    def _batch_after_substep(self, positions, velocities, rows):
        """Contact projection and the like on ``rows`` of the new state (in place)."""

    def _batch_tool_position(self, positions):
        raise NotImplementedError

    def _batch_task_measures(self, positions) -> dict:
        return {}

    def _batch_record(self, measures, rows):
        """Episode bookkeeping for ``rows`` after a step (``TissueEnv._record``)."""

    def _batch_task_features(self, measures) -> dict:
        return {}

    def _batch_reward_terms(self, measures) -> dict:
        raise NotImplementedError

    def _batch_success(self, measures) -> np.ndarray:
        raise NotImplementedError

    def _batch_task_info(self, measures) -> dict:
        return {}

    def _write_back_task(self, index: int, env):
        """Put row ``index``'s task state back into ``env`` (for rendering)."""

    def _write_back_measures(self, index: int, measures: dict):
        """Add what ``TissueEnv._record`` would have added to a re-measured ``measures``."""

    # -- loading episodes ---------------------------------------------------------------------------
    def _load(self, index: int):
        env = self.envs[index]
        self.stack.assign(index, env.model)
        self.positions[index] = env.state.positions
        self.velocities[index] = env.state.velocities
        self._lengths[index] = self._spring_lengths(self.positions)[index]
        self.integrator.prepare(index, env.model, env.state.positions, env.dt, env.control.fixed)
        self.tool_offset[index] = env.tool_offset
        self.workspace_low[index] = env.workspace_low
        self.workspace_high[index] = env.workspace_high
        self.rest_volume[index] = env.rest_volume
        self.episode_young_modulus[index] = env.episode_young_modulus
        self.episode_poisson_ratio[index] = env.episode_poisson_ratio
        self.elapsed[index] = 0
        self._load_task(index, env)

    def _stop_pool(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        _POOLED.discard(self)

    def _reset_rows(self, rows, seeds, options):
        """Reset the copies ``rows`` by their task envs' own ``reset``, on ``threads`` Python threads
        when the vector env has more than one (``kernels.threaded``): most of a reset's time (a goal
        or start solve: SuperLU, the nogil compiled kernels) runs without the GIL, and each copy's
        reset reads only its own env and the lock-guarded shared caches, so the results are those of
        the serial loop, faster on 2 threads. Then each
        copy's state is loaded into the batch, in row order."""
        envs = self.envs

        def reset(index):
            return envs[index].reset(seed=seeds[index], options=options)

        if len(rows) > 1 and kernels.threaded(self.threads):
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="tissue-reset")
                _POOLED.add(self)
            results = list(self._pool.map(reset, rows))
        else:
            results = [reset(index) for index in rows]
        observations, infos = {}, {}
        for index, (observation, info) in zip(rows, results):
            observations[index], infos[index] = observation, info
            self._load(index)
        return observations, infos

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
        observations, reset_infos = self._reset_rows(rows, seeds, options)
        self._autoreset[rows] = False
        self._started = True
        self._observations = self._stack_observations(observations, self._observations)
        infos = {}
        for index in rows:
            infos = self._add_info(infos, reset_infos[index], index)
        return self._copy(self._observations), infos

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        with kernels.using_threads(self.threads):  # serial kernels for one thread: the pool is not touched
            return self._step(actions)

    def _step(self, actions):
        count = self.num_envs
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (count, 3):
            raise ValueError(f"actions must have shape ({count}, 3), got {actions.shape}")
        resetting = self._autoreset.copy()
        active = ~resetting
        if not np.all(np.isfinite(actions[active])):
            raise ValueError(f"actions must be finite (no NaN or infinity), got {actions.tolist()}")

        reset_rows = np.flatnonzero(resetting)
        reset_observations, reset_infos = self._reset_rows(reset_rows, [None] * count, None)

        clipped = np.clip(np.where(active[:, None], actions, 0.0), -1.0, 1.0)
        step = self.max_step * clipped
        self.tool_offset = np.where(
            active[:, None],
            self.envs[0].constrain_tool(np.clip(self.tool_offset + step, self.workspace_low, self.workspace_high)),
            self.tool_offset)
        fixed, target, tool_mask = self._batch_control()
        reasons = self._advance(fixed, target, active)
        self.elapsed[active] += 1
        measures = self._measure(tool_mask)
        self._batch_record(measures, active)
        unstable = np.array([reason is not None for reason in reasons])
        terms = self._batch_reward_terms(measures)
        rewards = OrderedDict()
        for name in self.reward_names:
            if name == "instability":
                # single envs add this term only on a diverging step (sum order matters for floats)
                continue
            rewards[name] = np.where(unstable, 0.0, terms[name])
        success = self._batch_success(measures) & ~unstable
        total = np.zeros(count)
        for name, value in rewards.items():
            total = total + value
        instability = np.where(unstable, -self.instability_penalty, 0.0)
        total = np.where(unstable, instability, total)  # the single env's diverging step: only this term
        rewards["instability"] = instability
        terminated = unstable | (success & self.terminate_on_success)
        truncated = np.zeros(count, dtype=bool)
        if self.max_episode_steps is not None:
            truncated = self.elapsed >= self.max_episode_steps
        observations = self._observation(measures)
        infos = self._info(measures, rewards, reasons, success)

        # rows that were reset in this call
        total[resetting] = 0.0
        terminated[resetting] = False
        truncated[resetting] = False
        self._put_observations(observations, reset_observations)
        for index in reset_rows:
            infos = self._add_info(infos, reset_infos[index], index)
        self._autoreset = (terminated | truncated) & active
        self._observations = observations
        return self._copy(observations), total, terminated, truncated, infos

    # -- physics --------------------------------------------------------------------------------------
    def _advance(self, fixed, target, active):
        """``TissueEnv._advance`` for every row in ``active``: (N,) reasons (None when healthy)."""
        count = self.num_envs
        reasons = np.full(count, None, dtype=object)
        running = active.copy()
        positions, velocities = self.positions, self.velocities
        control = Control(fixed, target, self._no_force)
        for _ in range(self.substeps):
            new = State(positions, velocities)
            try:
                with np.errstate(all="ignore"):
                    # each world's divergence checks (non-finite positions or velocities first) included
                    report = self.integrator.step(State(positions, velocities), new, control, self.dt, running)
            except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as error:
                for index in np.flatnonzero(running):
                    reasons[index] = f"physics error: {error}"
                break
            new_positions, new_velocities = new.positions, new.velocities
            reasons[running] = report.unstable_reason[running]
            healthy = running & np.array([reason is None for reason in reasons])
            self._batch_after_substep(new_positions, new_velocities, healthy)
            with np.errstate(all="ignore"):
                length = self._spring_lengths(new_positions)
                collapsed = self._strain(length)[1]
            length[~running] = self._lengths[~running]
            for index in np.flatnonzero(healthy & collapsed):
                reasons[index] = "collapsed spring (zero length)"
            failed = running & np.array([reason is not None for reason in reasons])
            keep = ~running | failed
            new_positions[keep] = positions[keep]
            new_velocities[keep] = velocities[keep]
            length[failed] = self._lengths[failed]
            positions, velocities, self._lengths = new_positions, new_velocities, length
            running &= ~failed
        self.positions, self.velocities = positions, velocities
        return reasons

    def _spring_lengths(self, positions):
        """(N, S) spring lengths, m, of the stacked positions (N, n, 3) (one compiled pass)."""
        springs = self.stack.model.springs
        length = np.empty(len(springs))
        flat = np.ascontiguousarray(positions.reshape(-1, 3), dtype=float)
        if kernels.threaded(self.threads):  # the copies on numba's threads
            kernels.spring_lengths_copies(self.num_envs, flat, springs, length)
        else:
            kernels.spring_lengths(flat, springs, length)
        return length.reshape(self.num_envs, -1)

    def _strain(self, length):
        """(max |L / L0 - 1| (N,), whether a spring collapsed, L <= 1e-6 L0 (N,) bool) of the spring
        lengths (N, S) m, in one compiled pass."""
        strain, collapsed = np.empty(self.num_envs), np.empty(self.num_envs, dtype=bool)
        kernels.variant(kernels.strain_extremes, self.threads)(length, self.rest_length, strain, collapsed)
        return strain, collapsed

    # -- measurements, observation, info -------------------------------------------------------------
    def _measure(self, tool_mask):
        """``TissueEnv._measure`` of every row."""
        count = self.num_envs
        positions, velocities = self.positions, self.velocities
        flat = positions.reshape(-1, 3)
        model = self.stack.model
        with np.errstate(all="ignore"):
            flat = np.ascontiguousarray(flat, dtype=float)
            flat_velocities = np.ascontiguousarray(velocities.reshape(-1, 3), dtype=float)
            if self.share_force_pass and isinstance(self.integrator, BatchedImplicitEuler):
                forces = self.integrator.linearise(flat).copy()  # elastic, corrections, volume, hourglass
                self.integrator.workspace.add_damping(flat_velocities, forces)
            else:
                forces = self._forces.compute(flat, flat_velocities)
            forces = forces + model.gravity_force
            forces = forces.reshape(count, -1, 3)
            reaction = np.empty((count, 3))
            kernels.masked_reaction(forces, tool_mask, reaction)
            strain = self._strain(self._lengths)[0]
            # exact trilinear volumes of the stacked model's elements (HexMesh.element_volumes)
            elements = model.mesh.elements
            arguments = (flat, elements, np.empty(len(elements)))
            volume = (kernels.element_volumes_copies(count, *arguments) if kernels.threaded(self.threads)
                      else kernels.element_volumes(*arguments)).reshape(count, -1).sum(axis=1)
        measures = dict(positions=positions, reaction_force=reaction, max_strain=strain, forces=forces,
                        relative_volume_change=(volume - self.rest_volume) / self.rest_volume)
        measures.update(self._batch_task_measures(positions))
        return measures

    def _features(self, measures):
        env = self.envs[0]
        positions = measures["positions"]
        features = dict(
            tool_position=(self._batch_tool_position(positions) - env.centre) / env.length_scale,
            tool_displacement=self.tool_offset / env.length_scale,
            reaction_force=measures["reaction_force"] / env.force_scale,
            relative_volume_change=100.0 * measures["relative_volume_change"][:, None],
            max_strain=100.0 * measures["max_strain"][:, None],
        )
        features.update(self._batch_task_features(measures))
        if env.observation_type != "state":
            surface = env.surface_nodes
            displacement = positions[:, surface] - env.mesh.nodes[surface]
            features["surface_displacement"] = displacement.reshape(self.num_envs, -1) / env.length_scale
        return features

    def _observation(self, measures):
        features = self._features(measures)
        parts = [np.asarray(features[name], dtype=np.float64).reshape(self.num_envs, -1) for name in self._feature_sizes]
        return observation_arrays(parts, list(self._feature_sizes), self.envs[0].observation_type == "dict")

    def _stack_observations(self, observations, previous):
        """Batch the reset observations {row: obs} over ``previous`` (None: all rows given)."""
        if self.envs[0].observation_type == "dict":
            if previous is None:
                previous = {name: np.zeros((self.num_envs,) + space.shape, space.dtype)
                            for name, space in self.single_observation_space.spaces.items()}
            out = {name: array.copy() for name, array in previous.items()}
        else:
            space = self.single_observation_space
            out = np.zeros((self.num_envs,) + space.shape, space.dtype) if previous is None else previous.copy()
        self._put_observations(out, observations)
        return out

    def _put_observations(self, out, observations):
        for index, observation in observations.items():
            if isinstance(out, dict):
                for name in out:
                    out[name][index] = observation[name]
            else:
                out[index] = observation

    @staticmethod
    def _copy(observations):
        if isinstance(observations, dict):
            return {name: array.copy() for name, array in observations.items()}
        return observations.copy()

    def _info(self, measures, rewards, reasons, success):
        """The single envs' infos as arrays (what SyncVectorEnv builds from them)."""
        count = self.num_envs
        present = np.ones(count, dtype=bool)
        info = dict(
            relative_volume_change=np.asarray(measures["relative_volume_change"], dtype=float),
            max_strain=np.asarray(measures["max_strain"], dtype=float),
            reaction_force=np.array(measures["reaction_force"], dtype=float),
            unstable=np.array([reason is not None for reason in reasons]),
            unstable_reason=reasons.copy(),
            is_success=np.asarray(success, dtype=bool),
            young_modulus=self.episode_young_modulus.copy(),
            poisson_ratio=self.episode_poisson_ratio.copy(),
        )
        for name in self.reward_names:
            info[f"reward_{name}"] = np.asarray(rewards[name], dtype=float)
        info.update(self._batch_task_info(measures))
        out = {}
        for key, value in info.items():
            out[key] = value
            out[f"_{key}"] = present.copy()
        return out

    # -- rendering and closing -------------------------------------------------------------------------
    def _write_back(self, index: int):
        """Put row ``index``'s state into ``self.envs[index]`` (what its render draws)."""
        env = self.envs[index]
        env.state = State(self.positions[index].copy(), self.velocities[index].copy())
        env.tool_offset = self.tool_offset[index].copy()
        self._write_back_task(index, env)
        env.control = env._control()
        env.measures = env._measure(env.state)
        self._write_back_measures(index, env.measures)

    def render(self):
        if self.render_mode is None:
            return None
        if not self._started:
            raise RuntimeError("call reset() before render()")
        frames = []
        for index, env in enumerate(self.envs):
            if env.state is not None:
                self._write_back(index)
            frames.append(env.render())
        return tuple(frames)

    def close_extras(self, **kwargs):
        self._stop_pool()
        for env in self.envs:
            env.close()

    def _damage_terms(self, measures):
        """``TissueEnv._damage_terms`` of every row."""
        return dict(
            volume=-self.volume_weight * np.abs(measures["relative_volume_change"]),
            strain=-self.strain_weight * np.maximum(0.0, measures["max_strain"] - self.strain_threshold),
        )
