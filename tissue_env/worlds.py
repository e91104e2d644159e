"""A task's N worlds: the one implementation of an env step, on arrays over worlds.

A ``TaskWorlds`` holds N worlds of one task (a tissue block, a tool and the task's episode data
per world) as one stacked sim_core model (``sim_core.models.stack.ModelStack``) stepped by one N-world
solver (``sim_core.solvers.worlds.make_worlds_solver``). Its ``step`` is the whole env step of every world:
the tool's move, the task's control, the physics with its divergence checks, the measurements, the
task's bookkeeping, rewards, success, observations and infos, each written once, on arrays whose
first axis is the world. The single environment (``TissueEnv``) is its one-world case and the
vector environment (``TissueVectorEnv``) its N-world case: a copy of a vector env and a single env
with the same seed and actions take the same steps (tests/test_env_vector.py).

Each task writes its hooks on a subclass (``TumorPositioningWorlds``, ...): ``_load_task`` (the
episode data a world's reset drew, from its task env), ``_control``, ``_after_substep``,
``_tool_position``, ``_task_measures``, ``_record``, ``_task_features``, ``_reward_terms``,
``_is_success``, ``_task_info`` and ``_write_back_task``. Episodes are drawn by the task envs
themselves (``TissueEnv._reset_episode``: their own random generators), one env per world.
SI units.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from sim_core import HexMesh, kernels
from sim_core.solvers.implicit import ImplicitEuler
from sim_core.solvers.integrators import stable_time_step
from sim_core.models.model import Control, State
from sim_core.models.stack import ModelStack, StackedForceWorkspace
from sim_core.solvers.static import STATIC_CONTACT_PASSES, STATIC_SLIDE_TOLERANCE, same_contacts
from sim_core.models.validity import ValidityRange, model_range, out_of_range
from sim_core.solvers.worlds import make_worlds_solver

from .camera import VISUAL_TYPES

#: Observation values are clipped to +-OBS_LIMIT (normalised units): a safety net, never reached
#: by a healthy simulation, that keeps every observation inside the observation space.
OBS_LIMIT = 100.0
#: The bounds of the features whose physical range passes +-OBS_LIMIT: ``max_strain`` (%), a spring's
#: abs(L - L0) / L0, passes 100% when soft tissue is stretched to more than twice its length
#: (Retraction's flap at E = 1 kPa reaches 127%, as neo-Hookean FEM on its mesh does:
#: benchmarks/material_range.py); beyond 1000% an element has folded.
FEATURE_LIMITS = {"max_strain": 1000.0}
#: The tissue stiffness (Pa) at which the tasks' force units and force limits are stated: an episode's
#: forces are observed, and its force limits applied, in units scaled by E / REFERENCE_YOUNG_MODULUS,
#: so the same strains read the same from a 1 kPa to a 1 MPa tissue (the default young_modulus).
REFERENCE_YOUNG_MODULUS = 5.0e3
#: The divergence reason of a world whose positions are finite and whose forces are not
NON_FINITE_FORCES = "non-finite forces (an element turned inside out)"


def feature_limit(name: str) -> float:
    """The bound of every entry of the observation feature ``name``: ``FEATURE_LIMITS``, else
    ``OBS_LIMIT``."""
    return FEATURE_LIMITS.get(name, OBS_LIMIT)


def observation_limits(feature_sizes) -> np.ndarray:
    """(total,) float64: the bound (``feature_limit``) of every entry of the state observation
    whose features have the sizes ``feature_sizes`` (name -> entries, in order)."""
    return np.concatenate([np.full(size, feature_limit(name)) for name, size in feature_sizes.items()]
                          or [np.zeros(0)])


def observation_arrays(parts, names, as_dict: bool, clipped=None, limits=OBS_LIMIT):
    """The observation from its features ``parts`` (float64 arrays, the feature index last): one
    float32 array (their concatenation) or a dict ``names`` -> array, with NaN set to 0 and every
    value clipped to +-``limits`` (a number, or one per entry: ``observation_limits``) in one pass
    over the concatenation (a pass per feature was a noticeable share of a step). ``clipped``: None,
    or a bool array of the leading shape that receives where an entry was NaN or beyond its bound
    (what the infos report: never silent)."""
    flat = np.concatenate(parts, axis=-1)
    if clipped is not None:
        clipped[...] = ~np.all(np.abs(flat) <= limits, axis=-1)
    np.nan_to_num(flat, copy=False, nan=0.0)
    np.clip(flat, -limits, limits, out=flat)
    flat = flat.astype(np.float32)
    if not as_dict:
        return flat
    ends = np.cumsum([part.shape[-1] for part in parts])
    return {name: np.ascontiguousarray(flat[..., end - part.shape[-1]:end])
            for name, part, end in zip(names, parts, ends)}


def _info_values(info, count, names):
    """{name: (count,) array} of the entries ``names`` of ``info``: one info (a dict of values, or of
    (count,) arrays, a vector env's) for every goal, or a sequence / array of ``count`` infos; else
    ValueError naming what is missing."""
    if isinstance(info, dict):
        infos = None
    else:
        infos = list(np.asarray(info, dtype=object).ravel())
        if len(infos) != count or not all(isinstance(item, dict) for item in infos):
            raise ValueError(f"compute_reward's info must be one info dict or {count} of them (one per goal), got "
                             f"{len(infos)} item(s) of type(s) {sorted({type(i).__name__ for i in infos})}")
    missing = sorted({name for item in ([info] if infos is None else infos) for name in names if name not in item})
    if missing:
        raise ValueError(f"compute_reward needs the step's info entries {names} (the goal-independent reward terms), "
                         f"missing {missing}; with stable-baselines3's HerReplayBuffer pass "
                         "replay_buffer_kwargs=dict(copy_info_dict=True)")
    if infos is None:
        return {name: np.broadcast_to(np.asarray(info[name]), (count,)) for name in names}
    return {name: np.array([item[name] for item in infos]) for name in names}


def _writeable(array):
    """``array``, or a copy of it where it is a read-only view (a task's control may return one)."""
    return array if array.flags.writeable else array.copy()


class TaskWorlds:
    """N worlds of a task (see the module docstring).

    Args:
        envs: the N task envs whose episodes the worlds play (built with the same keywords:
            they share the block, the tool and the task's constants).
        threads: threads of the per-world kernels (numba's pool; 1: the serial kernels). The
            worlds are independent: any count gives the same floats.
    """

    #: How the implicit step solves each world's linear system (``sim_core.solvers.implicit``):
    #: "factorised" (each world's sparse factor kept across steps), "reference" (the factor of the
    #: start-of-episode system matrix, shared by the worlds that start alike) or "jacobi". A task
    #: env's ``preconditioner="auto"`` takes this one.
    linear_solver = "factorised"
    #: The measurement's force pass is also the next implicit step's (``ImplicitEuler.linearise``
    #: at the new state, plus the springs' damping forces): one pass over the stacked model per step
    #: instead of two; off for tasks whose contact decisions read the sign of nodal forces.
    share_force_pass = False
    #: solver "factorised": None, or the iterations beyond the fresh count after which a world's
    #: factor is refreshed (``ImplicitEuler``'s ``amortise``; for scenes whose matrix changes
    #: fast and factorises cheaply, e.g. Retraction)
    refactor_amortise = None

    #: The state range in which the model's accuracy is validated (``sim_core.models.validity``): a step
    #: whose state leaves it has ``info["out_of_range"]`` True and the reason in
    #: ``info["out_of_range_reason"]``. Each instance has its model's (``model_range``).
    validity = ValidityRange()
    #: The attributes that are the block's, not the episode's: a snapshot (``tissue_env.snapshots``)
    #: refers to the restoring env's own (the stacked model, its workspace, the solver, whose
    #: per-world state it holds, and views of the stacked arrays). A task adds its own.
    structure = ("stack", "_forces", "integrator", "rest_length", "_no_force", "_feature_sizes", "_limits",
                 "reward_names")

    def __init__(self, envs, threads: int = 1):
        self.envs = list(envs)
        self.threads = int(threads)
        self.num_envs = count = len(self.envs)
        env = self.envs[0]
        self.task = env
        # a task that changes topology (a cut) gives each world spare node rows for the nodes it adds
        self.stack = ModelStack(env.model, count, spare_nodes=env.spare_nodes)
        self._forces = StackedForceWorkspace(self.stack, implicit=False, threads=self.threads)  # measurements
        solver = self.linear_solver if env.preconditioner == "auto" else env.preconditioner
        self.integrator = make_worlds_solver(env.integrator_name, self.stack, env.solver_tolerance, solver,
                                             self.refactor_amortise, self.threads, env.integrator_scheme)
        self.static = env.integrator_name == "static"
        self.validity = model_range(env.model_name, isinstance(env.mesh, HexMesh))
        self.n_nodes = env.mesh.n_nodes
        self.rest_length = self.stack.model.rest_length.reshape(count, -1)
        #: (N, rows, 3) the worlds' node positions, m: the block's nodes, then the spare rows
        #: (``ModelStack.spare_nodes``: parked until a cut puts a copied node there)
        self.positions = self.stack.new_state().positions
        self.velocities = np.zeros_like(self.positions)
        self._lengths = self.rest_length.copy()  # spring lengths (N, S) m of the current state
        #: (N, 3 T) each world's tools' offsets from rest and workspace bounds, m: (x, y, z) per tool in turn
        self.tool_offset = np.zeros((count, 3 * env.tool_count))
        self.workspace_low = np.zeros_like(self.tool_offset)
        self.workspace_high = np.zeros_like(self.tool_offset)
        self.rest_volume = np.ones(count)
        #: (N, 3) each world's block extent, m, and (N, n, 3) its rest positions (``size_range``)
        self.block_size = np.tile(env.size, (count, 1))
        self.rest_positions = self.positions.copy()
        #: (N, P) each world's observed parameters (``observe_parameters``; P = 0 without)
        self.parameters = np.zeros((count, env._feature_sizes.get("parameters", 0)))
        self.episode_young_modulus = np.zeros(count)  # each world's material this episode (Pa, -)
        self.episode_poisson_ratio = np.zeros(count)
        self.episode_density = np.zeros(count)  # kg/m^3
        #: (N,) each world's E / REFERENCE_YOUNG_MODULUS: its force unit and force limits scale by it
        self.stiffness_ratio = np.ones(count)
        self.elapsed = np.zeros(count, dtype=int)
        self._no_force = np.zeros_like(self.positions)  # the worlds' loads are their models' gravity
        #: (N, n, 3) bool: the dofs each world's tool imposed at its last measurement
        self.tool_mask = np.zeros(self.positions.shape, dtype=bool)
        #: (N, n, 3) the imposed components (bool) and their targets (m) of each world's last step
        self.fixed = np.zeros(self.positions.shape, dtype=bool)
        self.target = self.positions.copy()
        self.measures = None
        self._feature_sizes = env._feature_sizes
        self._limits = observation_limits(self._feature_sizes)  # each state-observation entry's bound
        #: observation_type "goal": the task measures its goal distance on the observed goals
        #: (``measures["achieved_goal"]``, ``["desired_goal"]``), what ``compute_reward`` reads
        self.goal_observed = env.observation_type == "goal"
        self.reward_names = env.reward_names + ("instability",)
        # constants shared by every world (the same keywords built them)
        for name in ("max_step", "dt", "substeps", "instability_penalty", "volume_weight",
                     "strain_weight", "strain_threshold", "length_scale", "force_scale", "centre"):
            setattr(self, name, getattr(env, name))

    @property
    def terminate_on_success(self) -> bool:
        """Whether a success ends the episode: the task env's (an attribute a study may switch off)."""
        return self.task.terminate_on_success

    # -- hooks a task implements -------------------------------------------------------------------
    def _load_task(self, index: int, env):
        """Copy the episode's task data (goal, tumour ...) of ``env`` after its reset into world ``index``."""

    def _control(self, rows=None):
        """(fixed (N, n, 3) bool, target (N, n, 3) m, tool_mask (N, n, 3) bool: the dofs the tool
        imposes) for the current tool offsets and state. A contact's active set is updated for the
        worlds ``rows`` (N,) bool only (None: all); the others keep theirs."""
        raise NotImplementedError

    def _tool_moved(self, previous, active):
        """The tool of the worlds ``active`` (N,) bool moved from the offsets ``previous`` (N, 3) m to
        ``self.tool_offset``, before the physics: a blade cuts here (``tissue_env.blade``)."""

    def _tool_moves(self, actions, active):
        """The tools' displacement increments (N, 3 T) of the clipped actions (N, A) (each tool's
        x, y, z in turn: the actions themselves for one tool without grasp commands); the grasp
        commands after them (one per tool) go to ``_grasp_commands`` first."""
        moves = self.tool_offset.shape[1]
        if actions.shape[1] == moves:
            return actions
        self._grasp_commands(actions[:, moves:], active)
        return actions[:, :moves]

    def _grasp_commands(self, commands, active):
        """Act on the grasp commands (N, T) in [-1, 1] of the worlds ``active`` (N,) bool, before
        the tools move (a task with ``grasp_commands`` implements it)."""
        raise NotImplementedError

    def _after_substep(self, positions, velocities, rows):
        """Contact projection and the like on the worlds ``rows`` (N,) bool of the new state (in place)."""

    def _constrain_tool(self, offset):
        """The worlds' tool offsets (N, 3) m, clipped to their workspaces, projected on the task's
        admissible set (``TissueEnv.constrain_tool``)."""
        return self.task.constrain_tool(offset)

    def _tool_position(self, positions):
        """(N, 3) tool positions, m (default: the mean of the grasped nodes)."""
        return positions[:, self.task.tool_nodes].mean(axis=1)

    def _task_measures(self, positions) -> dict:
        return {}

    def _record(self, measures, rows, fresh):
        """Episode bookkeeping of the worlds ``rows`` (N,) bool after a measurement (how long a
        condition has held ...); ``fresh`` (N,) bool: the worlds whose episode starts at this
        measurement (their reset). May add entries to ``measures``."""

    def _task_features(self, measures) -> dict:
        return {}

    def _reward_terms(self, measures) -> dict:
        raise NotImplementedError

    def _is_success(self, measures) -> np.ndarray:
        raise NotImplementedError

    def _task_info(self, measures) -> dict:
        return {}

    def _grasped(self, measures) -> np.ndarray:
        """(N, T) bool: whether each world's T tools hold tissue (default: one tool, its patch held by
        imposed displacements all episode)."""
        return np.ones((self.num_envs, 1), dtype=bool)

    def _write_back_task(self, index: int, env):
        """Put world ``index``'s task state back into ``env`` (what its render and scripted
        controller read)."""

    # -- loading episodes ----------------------------------------------------------------------------
    def _rows(self, index: int, values, fill=None):
        """World ``index``'s (rows, ...) array of the block's per-node ``values`` (n, ...): the values,
        then its parked spare rows' (``fill``; None: their rest positions, m)."""
        values = np.asarray(values)
        if len(values) == self.stack.n_nodes:
            return values
        rows = np.empty((self.stack.n_nodes,) + values.shape[1:], dtype=values.dtype)
        rows[len(values):] = self.stack.models[index].rest_positions[len(values):] if fill is None else fill
        rows[:len(values)] = values
        return rows

    def restored(self, index: int):
        """World ``index``'s episode attributes were put back from a snapshot (``tissue_env.snapshots``):
        a task whose worlds change topology puts the world's model back here."""

    def load(self, index: int):
        """World ``index`` plays the episode its task env has just drawn (``TissueEnv._reset_episode``)."""
        env = self.envs[index]
        self.stack.assign(index, env.model)
        if not self.stack.shared[index]:  # the measurements read the stacked arrays of the block's topology
            raise ValueError(f"world {index}'s model does not have the task's block topology (a changed mesh); "
                             "the vector env steps worlds of the block's topology only")
        self.positions[index] = self._rows(index, env.state.positions)
        self.velocities[index] = self._rows(index, env.state.velocities, 0.0)
        kernels.spring_lengths(np.ascontiguousarray(self.positions[index], dtype=float), self.stack.reference.springs,
                               self._lengths[index])  # this world's springs only (the same floats per spring)
        self.fixed, self.target = _writeable(self.fixed), _writeable(self.target)
        self.fixed[index] = self._rows(index, env.start_control.fixed, False)
        self.target[index] = self._rows(index, env.start_control.target)
        self.integrator.prepare(index, env.model, self.positions[index].copy(), env.dt, self.fixed[index].copy())
        self.tool_offset[index] = env.tool_offset
        self.workspace_low[index] = env.workspace_low
        self.workspace_high[index] = env.workspace_high
        self.rest_volume[index] = env.rest_volume
        self.block_size[index] = env.episode_size
        self.rest_positions[index] = self._rows(index, env.episode_mesh.nodes)
        if self.parameters.shape[1]:
            self.parameters[index] = env.observed_parameters()
        self.episode_young_modulus[index] = env.episode_young_modulus
        self.episode_poisson_ratio[index] = env.episode_poisson_ratio
        self.episode_density[index] = env.episode_density
        self.stiffness_ratio[index] = env.episode_young_modulus / REFERENCE_YOUNG_MODULUS
        self.elapsed[index] = 0
        self._load_task(index, env)

    def observe(self, rows):
        """The observations and infos (what ``reset`` returns) of the worlds ``rows`` (N,) bool,
        just loaded: their episodes start at this measurement. Returns (observations, infos) of
        every world (only the rows' are those of a reset)."""
        rows = np.asarray(rows, dtype=bool)
        self.tool_mask = np.array(self.tool_mask)  # a copy: a task may hold the array its control returned
        for index in np.flatnonzero(rows):
            self.tool_mask[index] = self._rows(index, self.envs[index].start_tool_mask, False)
        measures = self._measure(self.tool_mask)
        self._record(measures, rows, rows)
        success = self._is_success(measures)
        rewards = OrderedDict((name, np.zeros(self.num_envs)) for name in self.reward_names)
        reasons = np.full(self.num_envs, None, dtype=object)
        self.measures = measures
        return self._observation(measures), self._info(measures, rewards, reasons, success)

    # -- the step ------------------------------------------------------------------------------------
    def step(self, actions, active):
        """One env step of the worlds ``active`` (N,) bool, the others left as they are.

        Args:
            actions: (N, 3) finite actions in [-1, 1] (clipped) of the active worlds.
        Returns: (observations, rewards (N,), terminated (N,) bool, infos: dict of (N, ...) arrays).
        """
        count = self.num_envs
        active = np.asarray(active, dtype=bool)
        clipped = np.clip(np.where(active[:, None], actions, 0.0), -1.0, 1.0)
        clipped = self._tool_moves(clipped, active)
        previous = self.tool_offset
        self.tool_offset = np.where(
            active[:, None],
            self._constrain_tool(np.clip(self.tool_offset + self.max_step * clipped, self.workspace_low,
                                         self.workspace_high)),
            self.tool_offset)
        self._tool_moved(previous, active)
        fixed, target, tool_mask = self._control()
        reasons, tool_mask, self.fixed, self.target = self._advance(fixed, target, tool_mask, active)
        self.tool_mask = tool_mask
        self.elapsed[active] += 1
        measures = self._measure(tool_mask)
        self._unmeasurable(measures, reasons, active)
        self._record(measures, active, np.zeros(count, dtype=bool))
        unstable = np.array([reason is not None for reason in reasons])
        rewards, total = self._combine_rewards(self._reward_terms(measures), unstable)
        success = self._is_success(measures) & ~unstable
        terminated = unstable | (success & self.terminate_on_success)
        self.measures = measures
        return self._observation(measures), total, terminated, self._info(measures, rewards, reasons, success)

    def _unmeasurable(self, measures, reasons, rows):
        """Give ``reasons`` (N,) object (None: healthy) a reason where a world of ``rows`` (N,) bool has
        finite positions but non-finite nodal forces: an element turned inside out between two of the
        monitor's inversion checks (which run every few steps) has no energy, and its forces and the
        rewards read from them are NaN. Such a step diverges: terminated with the penalty alone."""
        bad = np.asarray(rows, dtype=bool) & ~np.all(np.isfinite(measures["forces"]), axis=(1, 2))
        for index in np.flatnonzero(bad):
            if reasons[index] is None:
                reasons[index] = NON_FINITE_FORCES
                if self.task.integrator_name == "explicit":
                    reasons[index] += self._explicit_step_cause(index)

    def _combine_rewards(self, terms, unstable):
        """(rewards: name -> (N,) each reward term, total (N,)) of the task's reward ``terms`` and
        the worlds' divergence ``unstable`` (N,) bool: a diverging step gets only the instability
        penalty. The step's and ``compute_reward``'s."""
        rewards = OrderedDict()
        for name in self.reward_names:
            if name == "instability":
                continue  # added last, alone on a diverging step
            rewards[name] = np.where(unstable, 0.0, terms[name])
        total = np.zeros(len(unstable))
        for value in rewards.values():
            total = total + value
        instability = np.where(unstable, -self.instability_penalty, 0.0)
        total = np.where(unstable, instability, total)  # a diverging step: only this term
        rewards["instability"] = instability
        return rewards, total

    # -- goal-conditioned API (observation_type="goal") ----------------------------------------------
    #: The info entries ``compute_reward`` reads: the goal-independent reward terms follow from them.
    GOAL_INFO_KEYS = ("relative_volume_change", "max_strain", "unstable")

    def _goal_reward_terms(self, achieved, desired) -> dict:
        """The reward terms that depend on the goal, of (B, k) normalised achieved and desired
        goals (B,) each (a goal-conditioned task implements it)."""
        raise NotImplementedError

    def _goal_observation(self, measures):
        """The ``"goal"`` observation of every world: ``observation`` (the ``"state"`` vector),
        ``achieved_goal`` and ``desired_goal`` (the task's ``measures["achieved_goal"]`` and
        ``["desired_goal"]``, float64, as its reward read them)."""
        observation = self._feature_observation(measures, as_dict=False)
        goals = {}
        for name in ("achieved_goal", "desired_goal"):
            value = np.array(measures[name], dtype=np.float64)
            self.clipped |= ~np.all(np.abs(value) <= OBS_LIMIT, axis=-1)
            np.nan_to_num(value, copy=False, nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
            goals[name] = np.clip(value, -OBS_LIMIT, OBS_LIMIT, out=value)
        return dict(observation=observation, **goals)

    def compute_reward(self, achieved_goal, desired_goal, info):
        """The reward of steps whose outcome was ``achieved_goal`` (..., k) had the goal been
        ``desired_goal`` (..., k), both in the observation's normalised units; ``info``: the step's
        info (a dict of values, or of (B,) arrays as a vector env gives), or a sequence / array of
        B infos, one per goal. The goal terms are the task's (``_goal_reward_terms``), the others
        follow from the info (``GOAL_INFO_KEYS``: ``_damage_terms``, and a diverging step's
        penalty alone), combined as in the step (``_combine_rewards``): for a step's own goals it
        is the step's reward, bit for bit. Returns a float for one pair of goals, else an array of
        the goals' leading shape."""
        achieved = np.asarray(achieved_goal, dtype=np.float64)
        desired = np.asarray(desired_goal, dtype=np.float64)
        size = self.task.observation_space["achieved_goal"].shape[0]
        if achieved.shape != desired.shape or achieved.ndim < 1 or achieved.shape[-1] != size:
            raise ValueError(f"compute_reward takes achieved_goal and desired_goal of one shape (..., {size}), got "
                             f"{achieved.shape} and {desired.shape}")
        batch = achieved.shape[:-1]
        count = int(np.prod(batch))
        values = _info_values(info, count, self.GOAL_INFO_KEYS)
        terms = self._goal_reward_terms(achieved.reshape(count, size), desired.reshape(count, size))
        terms.update(self._damage_terms(values))
        total = self._combine_rewards(terms, values["unstable"].astype(bool))[1]
        return float(total[0]) if not batch else total.reshape(batch)

    # -- physics -------------------------------------------------------------------------------------
    def _advance(self, fixed, target, tool_mask, active):
        """``substeps`` solver steps of the worlds in ``active``; a world that diverges keeps its
        last healthy state. Returns ((N,) reasons, None where healthy; the step's tool mask, imposed
        components and targets).

        A contact's active set (Palpation's probe, Retraction's floor) may be iterated within a
        substep, up to ``_contact_passes()`` solves: after each solve the task projects the nodes
        that went through the obstacle (``_after_substep``), measures the forces its control reads
        (``_contact_forces``) and re-forms its control at the new state (``_control``: nodes the
        tissue pulls away are released, held heights follow the nodes' sliding), and the worlds
        whose imposed set or heights changed (``sim_core.solvers.static.same_contacts``) are solved
        again. With ``integrator="static"`` (STATIC_CONTACT_PASSES) a substep is then the
        equilibrium of the contact problem at the tool's position, each solve from the last one's
        state; a dynamic step solved again starts over from the substep's start. By default the
        implicit integrator updates the set once per step: the dynamics carry it along."""
        count = self.num_envs
        reasons = np.full(count, None, dtype=object)
        running = active.copy()
        passes, tolerance = self._contact_passes()
        for _ in range(self.substeps):
            restart = None if self.static or passes == 1 else (
                self.positions.copy(), self.velocities.copy(), self._lengths.copy())
            solving = running.copy()
            for attempt in range(passes):
                failed = self._substep(Control(fixed, target, self._no_force), solving, reasons)
                running &= ~failed
                solving &= ~failed
                if attempt + 1 == passes or not solving.any():
                    break
                self._contact_forces(tool_mask, solving)
                previous_fixed, previous_target = fixed, target
                fixed, target, tool_mask = self._control(solving)
                solving &= ~same_contacts(previous_fixed, previous_target, fixed, target, tolerance=tolerance)
                if not solving.any():
                    break
                if restart is not None:  # the worlds whose set changed start their step again
                    self.positions = np.where(solving[:, None, None], restart[0], self.positions)
                    self.velocities = np.where(solving[:, None, None], restart[1], self.velocities)
                    self._lengths = np.where(solving[:, None], restart[2], self._lengths)
        return reasons, tool_mask, fixed, target

    def _contact_passes(self):
        """(solves per substep at most, tolerance m): how often ``_advance`` may solve a substep
        while its contact set changes, and how far the held heights may move between two solves for
        the set to count as settled (``same_contacts``)."""
        return (STATIC_CONTACT_PASSES if self.static else 1), STATIC_SLIDE_TOLERANCE

    def _contact_forces(self, tool_mask, rows):
        """Between two contact passes of ``_advance``: the measurement the next ``_control`` reads
        (the forces that release contact nodes; a grasp judged at them, ``Grasper.slip``), of the
        worlds ``rows`` (N,) bool still solving at least."""
        self._measure(tool_mask)

    def _explicit_step_cause(self, index):
        """For a world that diverged under the explicit integrator: the cause, when ``dt`` is above
        its tissue's stable step (``stable_time_step``'s conservative row-sum bound on its model:
        a stiffer, lighter or finer tissue needs a smaller step), and the knobs; else ""."""
        model = self.envs[index].model
        try:
            limit = stable_time_step(model, method="gershgorin")
        except (ArithmeticError, ValueError, RuntimeError):
            return ""
        if not self.dt > limit:
            return ""
        return (f"; the explicit step dt = {self.dt:g} s is above the bound on this tissue's stable step ({limit:.2g} s, "
                f"the conservative row-sum estimate of sim_core.solvers.integrators.stable_time_step): the tissue is "
                f"too stiff or too light for the time step on this mesh (a finer mesh needs a smaller one); use dt "
                f"{0.8 * limit:.2g} s or less, or integrator='implicit' (stable at any dt)")

    def _substep(self, control, running, reasons):
        """One solver step of the worlds ``running`` into ``self.positions``/``velocities``; the
        ones that diverge keep their state and get their reason in ``reasons``. Returns (N,) bool,
        the worlds that diverged."""
        positions, velocities = self.positions, self.velocities
        new = State(positions, velocities)
        try:
            with np.errstate(all="ignore"):
                # each world's divergence checks (non-finite positions or velocities first) included
                report = self.integrator.step(State(positions, velocities), new, control, self.dt, running)
        except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as error:
            for index in np.flatnonzero(running):
                reasons[index] = f"physics error: {error}"
            return running.copy()
        new_positions, new_velocities = new.positions, new.velocities
        reasons[running] = report.unstable_reason[running]
        if self.task.integrator_name == "explicit":
            for index in np.flatnonzero(running):
                if reasons[index] is not None:
                    reasons[index] += self._explicit_step_cause(index)
        healthy = running & np.array([reason is None for reason in reasons])
        self._after_substep(new_positions, new_velocities, healthy)
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
        self.positions, self.velocities, self._lengths = new_positions, new_velocities, length
        return failed

    def _spring_lengths(self, positions):
        """(N, S) spring lengths, m, of the stacked positions (N, n, 3) (one compiled pass)."""
        springs = self.stack.model.springs
        length = np.empty(len(springs))
        flat = np.ascontiguousarray(positions.reshape(-1, 3), dtype=float)
        if kernels.threaded(self.threads):  # the worlds on numba's threads
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
        """The measurements of every world: positions (N, n, 3) m, the net nodal forces (N, n, 3) N,
        the force the tool exerts (the reaction on its dofs ``tool_mask``) (N, 3) N, the largest
        spring strain (N,) and the relative volume change (N,), and the task's."""
        count = self.num_envs
        positions = self.positions
        model = self.stack.model
        with np.errstate(all="ignore"):
            flat = np.ascontiguousarray(positions.reshape(-1, 3), dtype=float)
            forces = self.net_forces()
            reaction = np.empty((count, 3))
            kernels.masked_reaction(forces, tool_mask, reaction)
            strain = self._strain(self._lengths)[0]
            # exact volumes of the stacked model's elements (HexMesh.element_volumes, TetMesh.element_volumes)
            elements = model.mesh.elements
            arguments = (flat, elements, np.empty(len(elements)))
            volumes = (kernels.element_volumes_copies(count, *arguments) if kernels.threaded(self.threads)
                       else kernels.element_volumes(*arguments)).reshape(count, -1)
            ratio = volumes / model.rest_volume.reshape(count, -1)
            volume = volumes.sum(axis=1)
        measures = dict(positions=positions, reaction_force=reaction, max_strain=strain, forces=forces,
                        relative_volume_change=(volume - self.rest_volume) / self.rest_volume,
                        volume_ratio_low=ratio.min(axis=1), volume_ratio_high=ratio.max(axis=1))
        measures.update(self._task_measures(positions))
        return measures

    def net_forces(self, rows=None):
        """(N, n, 3) N: the net nodal forces at the worlds' state (elastic, corrections, volume,
        hourglass, damping and the tissue's damping law, gravity), the imposed components' constraint
        forces left out. ``rows``: None (every world), or the worlds (N,) bool wanted: a task that
        shares the implicit step's force pass (``share_force_pass``) computes only theirs, and the
        others' hold gravity alone."""
        flat = np.ascontiguousarray(self.positions.reshape(-1, 3), dtype=float)
        flat_velocities = np.ascontiguousarray(self.velocities.reshape(-1, 3), dtype=float)
        with np.errstate(all="ignore"):
            if not self.stack.shared.any():  # every world cut: each is measured on its own model (tissue_env.blade)
                forces = np.zeros_like(flat)
            elif self.share_force_pass and isinstance(self.integrator, ImplicitEuler):
                forces = self.integrator.linearise(flat, rows).copy()  # elastic, corrections, volume, hourglass
                self.integrator.workspace.add_damping(flat_velocities, forces)
                if rows is not None:
                    forces.reshape(self.num_envs, -1)[~rows] = 0.0
            else:
                forces = self._forces.compute(flat, flat_velocities)
            if self.task.damping_ratio is not None and isinstance(self.integrator, ImplicitEuler):
                forces += self.integrator.damping_forces(flat, flat_velocities)  # the tissue's damping law
            return (forces + self.stack.model.gravity_force).reshape(self.num_envs, -1, 3)

    def _features(self, measures):
        env = self.task
        positions = measures["positions"]
        features = dict(
            tool_position=((self._tool_position(positions).reshape(self.num_envs, -1, 3) - self.centre)
                           / self.length_scale).reshape(self.num_envs, -1),
            tool_displacement=self.tool_offset / self.length_scale,
            reaction_force=measures["reaction_force"] / self.scaled_force(self.force_scale)[:, None],
            relative_volume_change=100.0 * measures["relative_volume_change"][:, None],
            max_strain=100.0 * measures["max_strain"][:, None],
        )
        features.update(self._task_features(measures))
        if env.observation_type not in ("state", "goal"):
            surface = env.surface_nodes
            displacement = positions[:, surface] - self.rest_positions[:, surface]
            features["surface_displacement"] = displacement.reshape(self.num_envs, -1) / self.length_scale
        if self.parameters.shape[1]:
            features["parameters"] = self.parameters
        return features

    def scaled_force(self, force):
        """(N,) a force in N stated at the reference tissue (REFERENCE_YOUNG_MODULUS: the force unit,
        a task's force limit) in each world's tissue: the same strains at any stiffness."""
        return force * self.stiffness_ratio

    def _observation(self, measures):
        if self.task.observation_type in VISUAL_TYPES:
            return self._visual_observation(measures)
        if self.goal_observed:
            return self._goal_observation(measures)
        return self._feature_observation(measures, as_dict=self.task.observation_type == "dict")

    def _feature_observation(self, measures, as_dict):
        """The worlds' feature vectors (or dicts of them), clipped to their bounds (``observation_limits``);
        resets ``self.clipped``."""
        features = self._features(measures)
        parts = [np.asarray(features[name], dtype=np.float64).reshape(self.num_envs, -1) for name in self._feature_sizes]
        self.clipped = np.zeros(self.num_envs, dtype=bool)
        return observation_arrays(parts, list(self._feature_sizes), as_dict, self.clipped, self._limits)

    # -- visual observations (tissue_env.camera) -----------------------------------------------------
    def _scene_extras(self):
        """The rigid geometry the camera sees besides the tissue: None, or (vertices (N, V, 3) m,
        triangles (T, 3), albedo (T, 3) in [0, 1]) of every world (Retraction's floor and target
        strip, Palpation's probe). Never hidden ground truth (the tumour, the inclusion)."""
        return None

    def camera_images(self):
        """(rgb (N, H, W, 3) uint8, depth (N, H, W) float64 m) of every world through the task's camera."""
        return self.task._camera_view.images(self.positions, self._scene_extras())

    def _visual_observation(self, measures):
        """The visual observations (N, ...) of ``observation_type`` (``tissue_env.camera.CameraView.observe``)."""
        observation, self.clipped = self.task._camera_view.observe(
            self.task.observation_type, measures["positions"], self._scene_extras())
        return observation

    def _info(self, measures, rewards, reasons, success):
        """Every world's info, as (N, ...) arrays (after ``_observation``: its clipping is reported)."""
        outside = out_of_range(measures["max_strain"], measures["volume_ratio_low"], measures["volume_ratio_high"],
                               self.validity)
        info = dict(
            relative_volume_change=np.asarray(measures["relative_volume_change"], dtype=float),
            max_strain=np.asarray(measures["max_strain"], dtype=float),
            reaction_force=np.array(measures["reaction_force"], dtype=float),
            unstable=np.array([reason is not None for reason in reasons]),
            unstable_reason=reasons.copy(),
            is_success=np.asarray(success, dtype=bool),
            # the episode's material, as drawn from the *_range keywords (or the fixed values)
            young_modulus=self.episode_young_modulus.copy(),
            poisson_ratio=self.episode_poisson_ratio.copy(),
            density=self.episode_density.copy(),
            size=self.block_size.copy(),
            out_of_range=np.array([reason is not None for reason in outside]),
            out_of_range_reason=outside,
            observation_clipped=self.clipped.copy(),
            # (N, T, 3) N the force the tissue exerts on each tool: the opposite of the tool's on the
            # tissue (0.0 - r, not -r: a tool that holds nothing reads 0.0, not -0.0)
            tool_forces=0.0 - np.array(measures["reaction_force"], dtype=float).reshape(self.num_envs, -1, 3),
            grasped=np.array(self._grasped(measures), dtype=bool),
        )
        for name in self.reward_names:
            info[f"reward_{name}"] = np.asarray(rewards[name], dtype=float)
        info.update(self._task_info(measures))
        return info

    def _damage_terms(self, measures):
        """The damage penalties of every world: the |relative volume change| and the spring strain
        beyond ``strain_threshold``."""
        return dict(
            volume=-self.volume_weight * np.abs(measures["relative_volume_change"]),
            strain=-self.strain_weight * np.maximum(0.0, measures["max_strain"] - self.strain_threshold),
        )

    # -- back into the task envs ---------------------------------------------------------------------
    def write_back(self, index: int):
        """Put world ``index``'s state, tool, last measurements and task state into its task env
        (what its ``render``, ``scripted_action`` and ``get_state`` read)."""
        env = self.envs[index]
        rows = self.stack.given[index].n_nodes  # the world's model's nodes (a cut adds some), not its parked rows
        env.state = State(self.positions[index, :rows].copy(), self.velocities[index, :rows].copy())
        env.tool_offset = self.tool_offset[index].copy()
        env.elapsed_steps = int(self.elapsed[index])
        env.control = Control(self.fixed[index, :rows].copy(), self.target[index, :rows].copy(), np.zeros((rows, 3)))
        measures = self.measures
        if measures is not None:
            env.measures = {name: (value[index] if isinstance(value, np.ndarray) else value)
                            for name, value in measures.items()}
        self._write_back_task(index, env)
