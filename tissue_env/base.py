"""The shared scene of every task: a block of soft tissue built with sim_core, a tool, observations,
reward plumbing, divergence handling and rendering.

A task subclasses ``TissueEnv`` and fills in a few hooks (which nodes are fixed, how the tool
imposes positions, the task features, the reward terms, the reset distribution); see
``tumor_positioning.py`` for the smallest example. SI units throughout (m, kg, s, Pa, N).

Physics per env step (its cost: ``benchmarks/env_speed.py``): ``substeps`` linearised implicit
Euler steps of ``dt`` s (``sim_core.integrators.ImplicitEuler``). It is stable far past the explicit
limit (about 1 ms for 1 cm elements of a 5 kPa tissue), so one step of ``default_dt`` (20 ms, 40 ms
for TumorPositioning and Palpation) per env step is enough, and with the springs' critical damping the block
settles to the quasi-static equilibrium within a few steps of a slow tool (checked against
``solve_static`` in tests/test_env_tumor_positioning.py). Each task's ``default_shape`` is the
most accurate shape that keeps a speed budget of 300 env steps/s (``benchmarks/env_accuracy.py``;
the environment accuracy page of the documentation).
A full ``solve_static`` per env step costs several implicit steps (a sparse LU factorisation per
Newton iteration), so it is used only at reset (initial sag under gravity, goal generation) and by
the opt-in "static" integrator.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.forces import ForceWorkspace, external_forces
from sim_core.integrators import ImplicitEuler, make_integrator
from sim_core.preconditioners import PRECONDITIONERS, FactorStore
from sim_core.model import State
from sim_core.static import STATIC_CONTACT_PASSES, same_contact

from .rendering import Renderer

#: Observation values are clipped to +-OBS_LIMIT (normalised units): a safety net, never reached
#: by a healthy simulation, that keeps every observation inside the observation space.
OBS_LIMIT = 100.0
OBSERVATION_TYPES = ("state", "deformation", "dict")
INTEGRATORS = ("implicit", "explicit", "static")
MODEL_CACHE_SIZE = 16


# -- argument checks (ValueError naming the keyword) -------------------------------------------
def _number(name, value, unit=""):
    try:
        return float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number{unit and ' in ' + unit}, got {value!r}") from error


def positive_scalar(name, value, unit=""):
    value = _number(name, value, unit)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0{unit and ' ' + unit}, got {value!r}")
    return value


def nonnegative_scalar(name, value):
    value = _number(name, value)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return value


def check_poisson_ratio(name, value):
    value = _number(name, value)
    if not (-0.25 < value < 0.5):
        raise ValueError(f"{name} must lie in (-0.25, 0.5) for the mass-spring model, got {value!r}")
    return value


def check_region(name, value, axes):
    """((a0, b0, ...), (a1, b1, ...)) fractions in [0, 1] of the block along ``axes`` (e.g. "xz"),
    low <= high, as a (2, len(axes)) array; else ValueError naming ``name``."""
    form = "(" + ", ".join("(" + ", ".join(f"{axis}{i}" for axis in axes) + ")" for i in (0, 1)) + ")"
    try:
        region = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be {form} fractions, got {value!r}") from error
    if region.shape != (2, len(axes)) or not np.all(np.isfinite(region)) or np.any(region < 0) or np.any(region > 1) \
            or np.any(region[0] > region[1]):
        raise ValueError(f"{name} must be {form} fractions in [0, 1] with low <= high, got {value!r}")
    return region


def check_range(name, value, check):
    """None or a (low, high) pair whose ends pass ``check`` and low <= high."""
    if value is None:
        return None
    try:
        low, high = value
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be None or a (low, high) pair, got {value!r}") from error
    low, high = check(name, low), check(name, high)
    if low > high:
        raise ValueError(f"{name} must have low <= high, got {value!r}")
    return (low, high)


def check_vector(name, value, unit="m"):
    """A positive scalar (broadcast) or three positive numbers."""
    try:
        array = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number or three numbers in {unit}, got {value!r}") from error
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{name} must be finite and > 0 {unit} along every axis, got {value!r}")
    return array


def check_shape(name, value, minimum):
    try:
        shape = tuple(int(s) for s in value)
        exact = all(float(s) == v for s, v in zip(value, shape))
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be three integers (nx, ny, nz), got {value!r}") from error
    if len(shape) != 3 or not exact or any(s < m for s, m in zip(shape, minimum)):
        raise ValueError(f"{name} must be three integers (nx, ny, nz) >= {tuple(minimum)}, got {value!r}")
    return shape


# -- the base environment --------------------------------------------------------------------
def observation_arrays(parts, names, as_dict: bool):
    """The observation from its features ``parts`` (float64 arrays, the feature index last): one
    float32 array (their concatenation) or a dict ``names`` -> array, with NaN set to 0 and every
    value clipped to +-OBS_LIMIT in one pass over the concatenation (a pass per feature was a
    noticeable share of a step)."""
    flat = np.concatenate(parts, axis=-1)
    np.nan_to_num(flat, copy=False, nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
    np.clip(flat, -OBS_LIMIT, OBS_LIMIT, out=flat)
    flat = flat.astype(np.float32)
    if not as_dict:
        return flat
    ends = np.cumsum([part.shape[-1] for part in parts])
    return {name: np.ascontiguousarray(flat[..., end - part.shape[-1]:end])
            for name, part, end in zip(names, parts, ends)}


@dataclass(frozen=True, eq=False)
class EpisodeState:
    """A snapshot of one environment's episode (``TissueEnv.get_state``): restored by
    ``set_state`` on an environment of the same class and keywords, the next steps are those the
    environment took after the snapshot, bit for bit."""

    env_class: type
    attributes: dict


#: Attributes of a task environment that a snapshot shares instead of copying: caches of models and
#: of their factorisations (a cached result is the one that would be computed), the renderer and
#: the spaces. A task's own caches are added by its ``shared_attributes``.
SHARED_ATTRIBUTES = ("_cache_lock", "_model_cache", "_start_cache", "_factor_stores", "_renderer", "mesh",
                     "action_space", "observation_space", "spec")


class TissueEnv(gym.Env):
    """Base class: a sim_core tissue block, a tool moved by displacement increments, observations,
    rewards and divergence handling. Not registered itself; see the task classes.

    Constructor keywords shared by every task (SI units):
        young_modulus: E in Pa (default 5e3, liver-like).
        poisson_ratio: nu in (-0.25, 0.5) (default 0.45).
        density: kg/m^3 (default 1060).
        shape: (nx, ny, nz) hexahedra of the block.
        size: (Lx, Ly, Lz) block extent in m (a float gives a cube).
        integrator: "implicit" (default, linearised implicit Euler), "static" (a static equilibrium
            per env step, ``sim_core.static.QuasiStatic``, with a contact's active set iterated
            to convergence within the step: observations without the dynamic lag, those of the
            static scene at every tool position, at several times the cost of an implicit step; single
            envs and ``vectorization_mode="sync"``/``"async"``) or "explicit" (symplectic Euler,
            needs dt below about 1 ms; for experiments on stability).
        dt: physics time step in s (the task's ``default_dt``: 0.02, TumorPositioning and Palpation 0.04);
            substeps: physics steps per env step (default 1).
        max_step: tool displacement in m per env step for an action component of 1.
        hourglass_control: sim_core's hourglass stabilisation alpha (default 1).
        volume_stiffness: multiplier of sim_core's volume-force stiffness kappa = K V0^(2/3)
            (default 100). The defaults are measured in benchmarks/env_accuracy.py: with
            alpha = 1 and x100 every tested tool position of every task has a stable equilibrium
            (with 0.5 and x1, TumorPositioning and Palpation had saddles at their deepest
            positions) and the volume-change error against neo-Hookean FEM is about halved;
            the implicit integrator treats the volume forces implicitly, so dynamics stay stable.
        gravity: m/s^2 along -y (default 9.81).
        observation_type: "state" (default), "deformation" (adds the displacement of the surface
            nodes) or "dict" (the "deformation" features as a Dict space).
        young_modulus_range, poisson_ratio_range: None or (low, high): domain randomisation, a new
            value drawn uniformly at every reset and reported in every ``info`` of the episode under
            ``young_modulus`` / ``poisson_ratio`` (the fixed values without a range) (the model is rebuilt: a slower reset).
        volume_weight: weight of the |relative volume change| penalty.
        strain_threshold, strain_weight: penalty strain_weight * max(0, max spring strain - threshold)
            (a damage proxy).
        instability_penalty: reward (negated) of the step where the simulation diverges.
        solver_tolerance: relative residual of the implicit integrator's linear solve (the task's
            ``default_solver_tolerance``: 1e-4, fewer iterations than 1e-6 with positions within
            0.01 mm of the 1e-6 run; TumorPositioning and Palpation 1e-2, see their docstrings).
        preconditioner: the implicit integrator's ("auto" default, "jacobi" or "factorised";
            ``sim_core.integrators.ImplicitEuler``): "auto" starts with Jacobi and switches to a
            sparse LU of the system matrix, kept across steps, when Jacobi needs more than about
            5 sqrt(free dofs / 400) iterations: more env steps/s than "jacobi", the more so the
            finer the mesh and the longer dt (``benchmarks/env_speed.py``).
        render_mode: None, "rgb_array" or "human".
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    #: Defaults a task may override.
    default_shape = (6, 4, 6)
    default_dt = 0.02
    default_solver_tolerance = 1e-4
    default_size = (0.06, 0.04, 0.06)
    default_max_step = 0.002
    min_shape = (2, 2, 2)
    #: Observation units: lengths in cm, forces in units of 0.1 N, strains and volume change in %.
    length_scale = 0.01
    force_scale = 0.1
    #: End the episode when the task succeeds.
    terminate_on_success = True
    #: Names of the reward terms (each also in info as ``reward_<name>``).
    reward_names: tuple = ()

    def __init__(self, *, young_modulus=5.0e3, poisson_ratio=0.45, density=1060.0, shape=None, size=None,
                 integrator="implicit", dt=None, substeps=1, max_step=None, hourglass_control=1.0,
                 volume_stiffness=100.0, gravity=9.81, observation_type="state", young_modulus_range=None,
                 poisson_ratio_range=None, volume_weight=1.0, strain_threshold=0.3, strain_weight=1.0,
                 instability_penalty=10.0, solver_tolerance=None, preconditioner="auto", render_mode=None):
        self.young_modulus = positive_scalar("young_modulus", young_modulus, "Pa")
        self.poisson_ratio = check_poisson_ratio("poisson_ratio", poisson_ratio)
        self.density = positive_scalar("density", density, "kg/m^3")
        self.shape = check_shape("shape", self.default_shape if shape is None else shape, self.min_shape)
        self.size = check_vector("size", self.default_size if size is None else size)
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        self.integrator_name = integrator
        self.dt = positive_scalar("dt", self.default_dt if dt is None else dt, "s")
        if isinstance(substeps, bool) or not float(substeps).is_integer() or int(substeps) < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
        self.substeps = int(substeps)
        self.max_step = positive_scalar("max_step", self.default_max_step if max_step is None else max_step, "m")
        self.hourglass_control = nonnegative_scalar("hourglass_control", hourglass_control)
        self.volume_stiffness = nonnegative_scalar("volume_stiffness", volume_stiffness)
        self.gravity = nonnegative_scalar("gravity", gravity)
        if observation_type not in OBSERVATION_TYPES:
            raise ValueError(f"observation_type must be one of {OBSERVATION_TYPES}, got {observation_type!r}")
        self.observation_type = observation_type
        self.young_modulus_range = check_range(
            "young_modulus_range", young_modulus_range, lambda n, v: positive_scalar(n, v, "Pa"))
        self.poisson_ratio_range = check_range("poisson_ratio_range", poisson_ratio_range, check_poisson_ratio)
        self.volume_weight = nonnegative_scalar("volume_weight", volume_weight)
        self.strain_threshold = nonnegative_scalar("strain_threshold", strain_threshold)
        self.strain_weight = nonnegative_scalar("strain_weight", strain_weight)
        self.instability_penalty = nonnegative_scalar("instability_penalty", instability_penalty)
        self.solver_tolerance = positive_scalar(
            "solver_tolerance", self.default_solver_tolerance if solver_tolerance is None else solver_tolerance)
        if preconditioner not in PRECONDITIONERS:
            raise ValueError(f"preconditioner must be one of {PRECONDITIONERS}, got {preconditioner!r}")
        self.preconditioner = preconditioner
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode

        self.spacing = self.size / np.asarray(self.shape)
        self.mesh = HexMesh.block(self.shape, self.spacing)
        nodes = self.mesh.nodes
        self.centre = 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))
        self.surface_nodes = self.mesh.surface_nodes()
        self._surface_faces = self.mesh.surface_faces()
        # the caches below are shared by a vector env's copies (``share_caches``), which may reset on
        # several threads: one lock guards them
        self._cache_lock = threading.RLock()
        self._model_cache: OrderedDict = OrderedDict()
        self._start_cache: OrderedDict = OrderedDict()  # model -> start positions (as many as models)
        # model -> FactorStore: the implicit integrator's factorisations at the model's start state
        # (every episode's first step), per imposed set; as many as the model cache
        self._factor_stores: OrderedDict = OrderedDict()
        self._setup_scene()
        # Build the default model now: it validates material and geometry together (Baudet's edge
        # stiffness must stay positive) and raises ValueError at construction, not at reset.
        try:
            self.model = self._model(self.young_modulus, self.poisson_ratio, self._default_task_key())
        except ValueError as error:
            raise ValueError(f"shape/size/poisson_ratio give an invalid model: {error}") from error

        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self._feature_sizes = OrderedDict(
            tool_position=3, tool_displacement=3, reaction_force=3, relative_volume_change=1, max_strain=1)
        self._feature_sizes.update(self._task_feature_sizes())
        if observation_type != "state":
            self._feature_sizes["surface_displacement"] = 3 * len(self.surface_nodes)
        if observation_type == "dict":
            self.observation_space = spaces.Dict({
                name: spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(n,), dtype=np.float32)
                for name, n in self._feature_sizes.items()})
        else:
            total = sum(self._feature_sizes.values())
            self.observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(total,), dtype=np.float32)
        self._renderer = None
        self._measure_workspace = None
        self.state = None

    # -- hooks a task implements -------------------------------------------------------------
    def _setup_scene(self):
        """Set ``self.fixed_nodes`` (nodes attached to the body) and ``self.tool_nodes``."""
        raise NotImplementedError

    def _task_feature_sizes(self) -> dict:
        return {}

    def _task_features(self, positions) -> dict:
        return {}

    def _default_task_key(self):
        """Key of the task's material layout (e.g. the inclusion cell), None when homogeneous."""
        return None

    def _material(self, young_modulus, poisson_ratio, task_key) -> Material:
        return Material(young_modulus, poisson_ratio, self.density)

    def _reset_task(self, options):
        """Draw the episode (goal, target, ...) from ``self.np_random``; set ``self.task_key``."""

    def _control(self):
        """The sim_core Control for the current tool position; also sets ``self.tool_mask``
        ((N, 3) bool, the dofs the tool imposes)."""
        control = self.base_control.copy()
        positions = self.tool_rest + self.tool_offset
        control.impose(self.tool_nodes, positions)
        self.tool_mask = np.zeros((self.mesh.n_nodes, 3), bool)
        self.tool_mask[self.tool_nodes] = True
        return control

    def _after_substep(self, state):
        """Contact projection and the like, applied to the state after each physics step."""

    def _initial_positions(self, model, control):
        """Start positions: the static equilibrium under gravity with the tool at rest."""
        result = solve_static(model, control, tolerance=1e-6)
        return result.positions if result.converged else model.rest_positions.copy()

    def _reward_terms(self, measures) -> dict:
        raise NotImplementedError

    def _is_success(self, measures) -> bool:
        raise NotImplementedError

    def scripted_action(self) -> np.ndarray:
        """A hand-written controller's action for the current state (a baseline)."""
        raise NotImplementedError

    def _require_reset(self, call):
        """Raise RuntimeError for ``call`` (e.g. "render()") when no episode has started yet: the
        state, the tool and the task's goal are drawn by ``reset``."""
        if self.state is None:
            raise RuntimeError(f"call reset() before {call}")

    # -- model building --------------------------------------------------------------------------
    def _model(self, young_modulus, poisson_ratio, task_key):
        key = (float(young_modulus), float(poisson_ratio), task_key)
        with self._cache_lock:
            model = self._model_cache.get(key)
            if model is None:
                model = build_model(
                    self.mesh, self._material(young_modulus, poisson_ratio, task_key),
                    gravity=(0.0, -self.gravity, 0.0), hourglass_control=self.hourglass_control,
                    volume_stiffness=self.volume_stiffness)
                self._model_cache[key] = model
                if len(self._model_cache) > MODEL_CACHE_SIZE:
                    self._model_cache.popitem(last=False)
            else:
                self._model_cache.move_to_end(key)
            return model

    def _start_positions(self, model):
        # The start depends only on the model (the tool starts at rest): computed once per model.
        with self._cache_lock:  # held while a missing start is solved: once per model
            cache = self._start_cache.get(model)
            if cache is None:
                cache = self._start_cache[model] = self._initial_positions(model, self._control())
                if len(self._start_cache) > MODEL_CACHE_SIZE:
                    self._start_cache.popitem(last=False)
            else:
                self._start_cache.move_to_end(model)
            return cache.copy()

    # -- Gymnasium API -----------------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state = None
        young_modulus, poisson_ratio = self.young_modulus, self.poisson_ratio
        if self.young_modulus_range is not None:
            young_modulus = float(self.np_random.uniform(*self.young_modulus_range))
        if self.poisson_ratio_range is not None:
            poisson_ratio = float(self.np_random.uniform(*self.poisson_ratio_range))
        self.episode_young_modulus, self.episode_poisson_ratio = young_modulus, poisson_ratio
        self.tool_offset = np.zeros(3)
        self.task_key = self._default_task_key()
        self._reset_task(options)
        self.model = self._model(young_modulus, poisson_ratio, self.task_key)
        self.rest_volume = float(self.model.rest_volume.sum())
        options = (dict(tolerance=self.solver_tolerance, preconditioner=self.preconditioner)
                   if self.integrator_name == "implicit" else {})
        self.integrator = make_integrator(self.integrator_name, model=self.model, **options)
        positions = self._start_positions(self.model)
        if self.integrator_name == "implicit":
            # Every episode of a model starts from the same state: its first step's factorisation is
            # kept (per imposed set) and the next episodes take it instead of factorising. The steps
            # are those of a fresh integrator (ImplicitEuler.share_factors): an episode does not
            # depend on the episodes before it.
            self.integrator.share_factors(self._factor_store(self.model, positions))
        self.state = State(positions, np.zeros_like(positions))
        self._scratch = self.state.copy()
        self.control = self._control()
        self._start_hook()
        self.elapsed_steps = 0
        self.measures = self._measure(self.state)
        self._record(self.measures)
        info = self._info(self.measures, self._zero_rewards(), unstable_reason=None)
        if self.render_mode == "human":
            self.render()
        return self._observation(self.measures), info

    def _factor_store(self, model, positions):
        with self._cache_lock:
            store = self._factor_stores.get(model)
            if store is None or not np.array_equal(store.positions, positions):
                store = self._factor_stores[model] = FactorStore(model, positions)
                if len(self._factor_stores) > MODEL_CACHE_SIZE:
                    self._factor_stores.popitem(last=False)
            else:
                self._factor_stores.move_to_end(model)
            return store

    def _start_hook(self):
        """Called at the end of reset, after the state exists (task bookkeeping)."""

    def __getstate__(self):  # a lock does not pickle: a copy gets its own (and its own caches)
        state = self.__dict__.copy()
        state.pop("_cache_lock", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._cache_lock = threading.RLock()

    #: a task's caches that snapshots share (see SHARED_ATTRIBUTES)
    shared_attributes: tuple = ()

    def _shared_memo(self) -> dict:
        """A ``copy.deepcopy`` memo that maps the objects a snapshot shares to themselves: the
        caches (SHARED_ATTRIBUTES, ``shared_attributes``), every cached model and its arrays (a
        model never changes), and the factor stores (the factorisations at a model's start state)."""
        shared = [getattr(self, name) for name in SHARED_ATTRIBUTES + self.shared_attributes if hasattr(self, name)]
        models = list(self._model_cache.values()) + [getattr(self, "model", None)]
        shared += list(self._factor_stores.values())
        for model in models:
            if model is not None:
                shared.append(model)
                shared.extend(vars(model).values())
        return {id(item): item for item in shared if item is not None}

    def get_state(self) -> EpisodeState:
        """A snapshot of the current episode (state, tool, goal, random generator, solver state):
        ``set_state(snapshot)`` returns this environment, or another one of the same class and
        keywords, to it, and its next steps are then those taken after the snapshot, bit for bit
        (planning, tree search, replays). Caches and models are shared, not copied."""
        shared = SHARED_ATTRIBUTES + self.shared_attributes
        attributes = {name: value for name, value in self.__dict__.items() if name not in shared}
        return EpisodeState(type(self), copy.deepcopy(attributes, self._shared_memo()))

    def set_state(self, state: EpisodeState):
        """Restore a snapshot of ``get_state`` (it can be restored any number of times)."""
        if not isinstance(state, EpisodeState) or state.env_class is not type(self):
            raise ValueError(f"set_state takes a snapshot from get_state() of a {type(self).__name__}, got "
                             f"{type(state).__name__ if not isinstance(state, EpisodeState) else state.env_class.__name__}")
        self.__dict__.update(copy.deepcopy(state.attributes, self._shared_memo()))

    def share_caches(self, other):
        """Use ``other``'s models, start states, first-step factorisations and task caches (an env
        built with the same keywords; the vector envs call it for their copies). Tasks with caches
        of their own extend it."""
        self._cache_lock = other._cache_lock
        self._model_cache, self._start_cache = other._model_cache, other._start_cache
        self._factor_stores = other._factor_stores
        self.model = other.model

    def constrain_tool(self, offset):
        """Tool offsets (..., 3) in m, already clipped to the workspace box, projected on the
        task's admissible set (default: the box itself). Vectorised: the vector envs call it on
        their (N, 3) offsets (their copies share size and workspace)."""
        return offset

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (3,):
            raise ValueError(f"action must have shape (3,), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action must be finite (no NaN or infinity), got {action.tolist()}")
        self._require_reset("step()")
        action = np.clip(action, -1.0, 1.0)
        self.tool_offset = self.constrain_tool(
            np.clip(self.tool_offset + self.max_step * action, self.workspace_low, self.workspace_high))
        self.control = self._control()
        reason = self._advance(self.control)
        self.elapsed_steps += 1
        self.measures = self._measure(self.state)
        self._record(self.measures)
        if reason is None:
            rewards = self._reward_terms(self.measures)
            success = bool(self._is_success(self.measures))
        else:
            rewards = self._zero_rewards()
            rewards["instability"] = -self.instability_penalty
            success = False
        reward = float(sum(rewards.values()))
        terminated = reason is not None or (success and self.terminate_on_success)
        info = self._info(self.measures, rewards, reason, success)
        if self.render_mode == "human":
            self.render()
        return self._observation(self.measures), reward, bool(terminated), False, info

    def _advance(self, control):
        """Run the substeps; on divergence keep the last healthy state and return the reason.

        With ``integrator="static"`` a substep is a static equilibrium, and a contact's active set
        (Palpation's probe, Retraction's floor) is iterated within it: after each solve the task
        projects the nodes that went through the obstacle (``_after_substep``) and re-forms its
        control at the new state (``_control``: nodes the tissue pulls away are released, held
        heights follow the nodes' sliding), and the equilibrium is solved again until the imposed
        set and heights settle (``sim_core.static.same_contact``; at most STATIC_CONTACT_PASSES
        solves), so the state is the equilibrium of the contact problem at the tool's position.
        The implicit integrator updates the set once per step: the dynamics carry it along."""
        passes = STATIC_CONTACT_PASSES if self.integrator_name == "static" else 1
        for _ in range(self.substeps):
            for attempt in range(passes):
                reason = self._substep(control)
                if reason is not None:
                    return reason
                if attempt + 1 == passes:
                    break
                self.measures = self._measure(self.state)  # the forces that release contact nodes
                previous, control = control, self._control()
                self.control = control
                if same_contact(previous, control):
                    break
        return None

    def _substep(self, control):
        """One integrator step from ``self.state``; returns the reason of a divergence (the state kept)."""
        state, scratch = self.state, self._scratch
        try:
            with np.errstate(all="ignore"):
                report = self.integrator.step(state, scratch, control, self.dt)
            reason = report.unstable_reason
        except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as error:
            reason = f"physics error: {error}"
        if reason is None and not (np.all(np.isfinite(scratch.positions)) and np.all(np.isfinite(scratch.velocities))):
            reason = "non-finite positions or velocities"
        if reason is None:
            self._after_substep(scratch)
            # A zero-length spring (two nodes on top of each other, e.g. a diverging explicit run
            # projected on the floor) has no direction: the state is no longer usable.
            a, b = self.model.springs[:, 0], self.model.springs[:, 1]
            length = np.linalg.norm(scratch.positions[b] - scratch.positions[a], axis=1)
            if not np.all(length > 1e-6 * self.model.rest_length):
                reason = "collapsed spring (zero length)"
        if reason is not None:
            self._scratch = state.copy()
            return reason
        self.state, self._scratch = scratch, state
        return None

    # -- measurements, observation, info -----------------------------------------------------------
    def _measure(self, state) -> dict:
        positions = state.positions
        model = self.model
        try:
            with np.errstate(all="ignore"):
                x = np.ascontiguousarray(positions, dtype=float)
                velocities = np.ascontiguousarray(state.velocities, dtype=float)
                if isinstance(self.integrator, ImplicitEuler):
                    # the next step's force pass (``ImplicitEuler.linearise``), plus the damping
                    workspace = self.integrator.linearise(model, x)
                    forces = workspace.add_damping(velocities, workspace.forces + external_forces(model, self.control))
                else:
                    workspace = self._measure_workspace
                    if workspace is None or workspace.model is not model:  # one per model
                        workspace = self._measure_workspace = ForceWorkspace(model, implicit=False)
                    forces = workspace.compute(x, velocities) + external_forces(model, self.control)
            length = workspace.length  # the spring lengths of this fused pass
        except ArithmeticError:  # a degenerate (last healthy) state: report no force rather than crash
            forces = np.zeros_like(positions)
            a, b = model.springs[:, 0], model.springs[:, 1]
            length = np.linalg.norm(positions[b] - positions[a], axis=1)
        reaction = np.where(self.tool_mask, -forces, 0.0).sum(axis=0)
        strain = float(np.max(np.abs(length / model.rest_length - 1.0)))
        volume = float(self.mesh.element_volumes(positions).sum())
        measures = dict(
            positions=positions, reaction_force=reaction, max_strain=strain, forces=forces,
            relative_volume_change=(volume - self.rest_volume) / self.rest_volume,
        )
        measures.update(self._task_measures(positions))
        return measures

    def _task_measures(self, positions) -> dict:
        return {}

    def _record(self, measures):
        """Episode bookkeeping once per reset and per step, after the measurements (e.g. how long
        a condition has held); may add entries to ``measures``. ``_measure`` itself has no side
        effects, so it can be called again (rendering, vector envs)."""

    def _tool_position(self, positions):
        """Tool position in m (default: mean of the grasped nodes)."""
        return positions[self.tool_nodes].mean(axis=0)

    def _features(self, measures) -> dict:
        positions = measures["positions"]
        tool = self._tool_position(positions)
        features = dict(
            tool_position=(tool - self.centre) / self.length_scale,
            tool_displacement=self.tool_offset / self.length_scale,
            reaction_force=measures["reaction_force"] / self.force_scale,
            relative_volume_change=[100.0 * measures["relative_volume_change"]],
            max_strain=[100.0 * measures["max_strain"]],
        )
        features.update(self._task_features(measures))
        if self.observation_type != "state":
            displacement = positions[self.surface_nodes] - self.mesh.nodes[self.surface_nodes]
            features["surface_displacement"] = displacement.ravel() / self.length_scale
        return features

    def _observation(self, measures):
        features = self._features(measures)
        parts = [np.asarray(features[name], dtype=np.float64).ravel() for name in self._feature_sizes]
        return observation_arrays(parts, list(self._feature_sizes), self.observation_type == "dict")

    def _zero_rewards(self) -> dict:
        return {name: 0.0 for name in self.reward_names + ("instability",)}

    def _info(self, measures, rewards, unstable_reason, success=None) -> dict:
        if success is None:
            success = bool(self._is_success(measures)) if unstable_reason is None else False
        info = dict(
            relative_volume_change=float(measures["relative_volume_change"]),
            max_strain=float(measures["max_strain"]),
            reaction_force=np.array(measures["reaction_force"], dtype=float),
            unstable=unstable_reason is not None,
            unstable_reason=unstable_reason,
            is_success=bool(success),
            # the episode's material, as drawn from the *_range keywords (or the fixed values)
            young_modulus=float(self.episode_young_modulus),
            poisson_ratio=float(self.episode_poisson_ratio),
        )
        for name in self.reward_names + ("instability",):
            info[f"reward_{name}"] = float(rewards.get(name, 0.0))
        info.update(self._task_info(measures))
        return info

    def _task_info(self, measures) -> dict:
        return {}

    # -- shared reward terms -------------------------------------------------------------------
    def _damage_terms(self, measures) -> dict:
        return dict(
            volume=-self.volume_weight * abs(measures["relative_volume_change"]),
            strain=-self.strain_weight * max(0.0, measures["max_strain"] - self.strain_threshold),
        )

    # -- rendering -----------------------------------------------------------------------------------
    def _markers(self) -> dict:
        """Named points (m) to draw: tool, target, goal ..."""
        return {}

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make")
            return None
        self._require_reset("render()")
        if self._renderer is None:
            self._renderer = Renderer(self._surface_faces, self.mesh.size, self.centre,
                                      human=self.render_mode == "human", fps=self.metadata["render_fps"])
        positions = self.state.positions
        displacement = np.linalg.norm(positions - self.mesh.nodes, axis=1)
        frame = self._renderer.draw(positions, displacement, self._markers(), self._extra_drawing())
        return frame if self.render_mode == "rgb_array" else None

    def _extra_drawing(self):
        """Optional (kind, data) items the renderer draws (floor, target region ...)."""
        return []

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
