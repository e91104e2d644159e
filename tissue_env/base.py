"""The shared scene of every task: a block of soft tissue built with sim_core, a tool, the episode's
draw, rendering, snapshots.

A task subclasses ``TissueEnv`` for its scene and reset distribution (which nodes are fixed, where
the tool grasps, the goal or target an episode draws) and ``tissue_env.worlds.TaskWorlds`` for its
step (control, measurements, observation, rewards), written once on arrays over worlds: the
single env is the one-world case (``reset`` loads the episode into its one world, ``step`` is
``TaskWorlds.step`` of it), the vector env (``tissue_env.vector``) the N-world case. See
``tumor_positioning.py`` for the smallest example. SI units throughout (m, kg, s, Pa, N).

Physics per env step (its cost: ``benchmarks/env_speed.py``): ``substeps`` linearised implicit
Euler steps of ``dt`` s (``sim_core.solvers.implicit.ImplicitEuler``, the same step as for one world). It is stable far past the explicit limit (about 1 ms for
1 cm elements of a 5 kPa tissue), so one step of ``default_dt`` (20 ms, 40 ms for
TumorPositioning and Palpation) per env step is enough, and with the springs' critical damping the
block settles to the quasi-static equilibrium within a few steps of a slow tool (checked against
``solve_static`` in tests/test_env_tumor_positioning.py). Each task's ``default_shape`` is the
most accurate shape that keeps a speed budget of 300 env steps/s (``benchmarks/env_accuracy.py``;
docs/generated/environment_accuracy.md, written by docs/gen_pages.py).
A full ``solve_static`` per env step costs several implicit steps (a sparse LU factorisation per
Newton iteration), so it is used only at reset (initial sag under gravity, goal generation) and by
the opt-in "static" integrator.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import re
import threading
import warnings
from collections import OrderedDict
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.solvers.implicit import PRECONDITIONERS
from sim_core.solvers.schemes import SCHEMES
from sim_core.caches import BudgetCache
from sim_core.models.model import Control, State

from .checks import (  # noqa: F401  (re-exported: the tasks import them from here)
    DIFFICULTIES, MAX_NODES, MODELS, MODEL_DEFAULTS, SLOW_NODES, check_damping, check_flag, check_model, check_poisson_ratio, check_range, check_region, check_shape, check_vector, check_vector_range, check_work, difficulty_settings, nonnegative_scalar, positive_scalar,
)
from .camera import VISUAL_TYPES, Camera, CameraView
from . import snapshots
from .rendering import FrameRendering
from .snapshots import MODEL_KEY, EpisodeState
from .worlds import OBS_LIMIT, TaskWorlds, feature_limit, observation_limits

OBSERVATION_TYPES = ("state", "deformation", "dict", "goal") + VISUAL_TYPES
#: The image sizes (pixels per side) a visual observation accepts: the range its speed is measured in
#: (benchmarks/visual_speed.py), from what SB3's NatureCNN needs (36) with a margin.
IMAGE_SIZE_RANGE = (64, 128)
#: Default image size of the visual observations and of ``render_mode="depth_array"``, pixels.
DEFAULT_IMAGE_SIZE = 64
INTEGRATORS = ("implicit", "explicit", "static")
#: The implicit step's preconditioners (``sim_core.solvers.implicit.PRECONDITIONERS``), where an
#: env's "auto" is its task's (``TaskWorlds.linear_solver``).
MODEL_CACHE_SIZE = 16
#: A start equilibrium that fails to converge with a gravity sag (rho g L^2 / E) under this many
#: rounding steps of the node positions failed for precision, not strength (E = 1e12 Pa on a 5 cm
#: block: 2.4e6 steps, Newton's residual stalls at 2e-3; E = 1e10 Pa: 2.4e8, it converges)
SAG_RESOLUTION = 1e8
#: Soft tissue is about 1000-1100 kg/m^3: a start equilibrium that fails for a denser material is
#: told it is too heavy for its stiffness, for a lighter one that it is too soft for its weight.
TISSUE_DENSITY_MAX = 2000.0
#: The suggested stiffness (density) when the start equilibrium fails: this factor above (below)
#: the value over the fraction of its weight Newton carried (the sag scales as density / E;
#: measured: TumorPositioning carried 26% at E = 100 Pa and 79% at 300 Pa, both pointing at about
#: 380 Pa; Palpation's density = 29300 kg/m^3 carried 99% of its weight and still failed).
WEIGHT_SAFETY = 2.0
#: the model's derived-data entry holding an env's start positions (its equilibrium under gravity)
_START = "env_start_positions"


def load_level(message):
    """The load level (the fraction of the load) at which ``solve_static``'s Newton stopped, read
    from its ``message`` ("Newton did not converge at load level 0.2617 ..."); None if it says none."""
    match = re.search(r"load level ([0-9.eE+-]+)", message or "")
    return float(match.group(1)) if match else None


#: Attributes of a task environment that a snapshot refers to instead of holding: caches of models and
#: of their factorisations (a cached result is the one that would be computed), the renderer, the
#: camera, the block and the spaces. A task's own caches are added by its ``shared_attributes``.
SHARED_ATTRIBUTES = ("_cache_lock", "_model_cache", "_renderer", "_camera_view", "mesh",
                     "action_space", "observation_space", "spec")
#: The keywords a snapshot depends on beyond the model (``_snapshot_settings``): restored on an env
#: whose values differ, it is refused (ValueError naming them).
SNAPSHOT_SETTINGS = ("shape", "size", "element", "model_name", "hourglass_control", "volume_stiffness", "gravity",
                     "integrator_name", "preconditioner", "observation_type", "integrator_scheme", "damping_ratio",
                     "damping_frequency")
#: The one world of a single env (``TaskWorlds.step``'s ``active``).
_ONE = np.ones(1, dtype=bool)


def _row(values, index=0):
    """Entry ``index`` of the worlds' (N, ...) arrays ``values`` (a dict of them, or one array) as a
    single env gives it: numpy scalars as Python numbers, arrays as copies."""
    if isinstance(values, dict):
        return {name: _row(value, index) for name, value in values.items()}
    value = values[index]
    if isinstance(value, np.generic):
        return value.item()
    return value.copy() if isinstance(value, np.ndarray) else value


class TissueEnv(FrameRendering, gym.Env):
    """Base class: a sim_core tissue block, a tool moved by displacement increments, observations,
    rewards and divergence handling. Not registered itself; see the task classes.

    Constructor keywords shared by every task (SI units):
        young_modulus: E in Pa (default 5e3, liver-like).
        poisson_ratio: nu in (-0.25, 0.5) (default 0.45).
        density: kg/m^3 (default 1060).
        shape: (nx, ny, nz) hexahedra of the block.
        size: (Lx, Ly, Lz) block extent in m (a float gives a cube).
        integrator: "implicit" (default, linearised implicit Euler), "static" (a static equilibrium
            per env step, ``sim_core.solvers.static.QuasiStatic``, with a contact's active set iterated
            to convergence within the step: observations without the dynamic lag, those of the
            static scene at every tool position, at several times the cost of an implicit step) or
            "explicit" (symplectic Euler, needs dt below about 1 ms; for experiments on stability).
        dt: physics time step in s (the task's ``default_dt``: 0.02, TumorPositioning and Palpation 0.04);
            substeps: physics steps per env step (default 1).
        integrator_scheme: the implicit integrator's time scheme, "euler" (default: numerical damping
            ratio about omega dt / 2), "tr-bdf2" (second order, little numerical damping, two solves
            per step) or "trapezoidal" (one solve, but its stiff modes ring: a random Retraction
            episode with a damping law diverged) (sim_core's ``ImplicitEuler``, docs/physics.md
            section 14).
        damping_ratio, damping_frequency: the tissue's damping law (sim_core's ``Material``): None
            (default: the springs' dashpots) or the ratio of critical damping of a mode at
            ``damping_frequency`` Hz (default 1; a pair (f1, f2): Rayleigh damping with that ratio
            at both), docs/physics.md section 14. Not with ``integrator="explicit"``.
        max_step: tool displacement in m per env step for an action component of 1.
        model: the tissue model, "baudet" or "baudet-hyperelastic" (``MODELS``; sim_core's
            ``build_model``: docs/physics.md section 11, compressible neo-Hookean at every strain,
            objective, no hourglass control or volume forces); None (default): the task's
            ``default_model``. "baudet" refuses box-shaped elements (its shear modulus is exact
            for cubes only: ``sim_core.models.model.MAX_SHEAR_ERROR``); "baudet-hyperelastic" takes any box.
        hourglass_control: sim_core's hourglass stabilisation alpha (default 1 for "baudet"; does
            not apply to "baudet-hyperelastic": None or 0 only).
        volume_stiffness: multiplier of sim_core's volume-force stiffness kappa = K V0^(2/3)
            (default 100 for "baudet"; does not apply to "baudet-hyperelastic": None only).
            The "baudet" defaults are measured in benchmarks/env_accuracy.py: with
            alpha = 1 and x100 every tested tool position of every task has a stable equilibrium
            (with 0.5 and x1, TumorPositioning and Palpation had saddles at their deepest
            positions) and the volume-change error against neo-Hookean FEM is about halved;
            the implicit integrator treats the volume forces implicitly, so dynamics stay stable.
        gravity: m/s^2 along -y (default 9.81).
        observation_type: "state" (default), "deformation" (adds the displacement of the surface
            nodes), "dict" (the "deformation" features as a Dict space) or, for a goal-conditioned
            task (``goal_features``: TumorPositioning), "goal": a Dict of ``observation`` (the
            "state" vector), ``achieved_goal`` and ``desired_goal``, with ``compute_reward``
            (``_goal_space``; SB3's HerReplayBuffer).
        young_modulus_range, poisson_ratio_range, density_range: None or (low, high) (Pa, -,
            kg/m^3): domain randomisation, a new value drawn uniformly from ``np_random`` at every
            reset (in this order, each only with a range) and reported in every ``info`` of the
            episode under ``young_modulus`` / ``poisson_ratio`` / ``density`` (the fixed values
            without a range). A new material is a new model (built on a cache miss: a slower
            reset; ``MODEL_CACHE_SIZE`` models are kept, within the "models" byte budget). The
            tasks add their own ranges (``randomised_parameters``; see their docstrings and the
            documentation's "Domain randomisation" section).
        size_range: None or (low, high), each a size in m (a number or (Lx, Ly, Lz)): the block's
            extent drawn per episode, each axis uniformly in its range (after the material), for
            the tasks that list ``size`` in ``randomised_parameters`` (ValueError for the others).
            The episode's block is the ``size`` block scaled along each axis about the origin
            (the attached corner): the same ``shape`` of hexahedra, the same nodes in the same
            roles (attached face, grasped patch, contact candidates), at scaled rest positions,
            with a model built for it (a new size is a new model, cached as a material). Observed
            positions stay relative to the centre of the ``size`` block (a frame fixed in space).
            ``info["size"]`` is the episode's (Lx, Ly, Lz) m.
        observe_parameters: append the episode's randomised parameters (the
            ``randomised_parameters`` whose range is given, each axis of a size separately) to the
            state observation, each normalised to [-1, 1] over its range (``parameters``: a key
            of the "dict" observation, part of the "goal" observation's ``observation``); for the
            vector observations only (ValueError with a visual ``observation_type``).
        volume_weight: weight of the |relative volume change| penalty.
        strain_threshold, strain_weight: penalty strain_weight * max(0, max spring strain - threshold)
            (a damage proxy).
        instability_penalty: reward (negated) of the step where the simulation diverges.
        solver_tolerance: relative residual of the implicit integrator's linear solve (the task's
            ``default_solver_tolerance``: 1e-4, fewer iterations than 1e-6 with positions within
            0.01 mm of the 1e-6 run; TumorPositioning and Palpation 1e-2, see their docstrings).
        preconditioner: the implicit step's linear solver (``sim_core.solvers.implicit.ImplicitEuler``):
            "auto" (default: the task's, ``linear_solver`` of its ``TaskWorlds``), "factorised"
            (each world's sparse factor of its system matrix, kept across steps and refreshed when
            its solves slow down), "reference" (the factor of the episode's start matrix) or
            "jacobi" (the inverse diagonal). Here "auto" is the task's choice, not
            ``ImplicitEuler``'s "auto" (Jacobi switching to "factorised" where it stalls).
        render_mode: None, "rgb_array" (the debug frames of ``tissue_env.rendering``, with the hidden
            tumour or inclusion marked), "human", or "depth_array" (the camera's depth image, (H, W)
            float32 m, as ``observation_type="depth"`` sees it).
        render_key: the ``"rgb_array"`` and ``"human"`` frames with a legend of their markers and a
            colour bar of the displacement (mm) on the right: 256 x 384 pixels instead of 256 x 256.
            Either way the colours span ``render_scale`` (the largest tool offset of the workspace).
        max_nodes: the largest mesh (nodes) accepted, MAX_NODES by default (``check_work``: a larger
            ``shape`` raises ValueError); None accepts any size, with a warning past SLOW_NODES.

    Visual observations (``tissue_env.camera``: a z-buffer rasteriser of the deformed surface; they
    never show hidden ground truth such as the tumour or the inclusion, only the tissue, the tool
    and the task's visible scene):
        observation_type "rgb": ``Box(0, 255, (H, W, 3), uint8)``, channel last (SB3's CnnPolicy
            transposes it); "depth": ``Box(near, far, (H, W, 1), float32)``, metric depth along the
            optical axis in m, ``far`` where nothing is seen; "rgbd": ``(H, W, 4)`` float32, the
            colour in [0, 1] then the depth in m (for SB3's CnnPolicy pass
            ``policy_kwargs=dict(normalize_images=False)``); "point_cloud": ``(point_count, 3)``
            float32 world positions in m of material points fixed on the surface (``(point_count, 6)``
            with the unit outward normals when ``point_normals``), bounded to 1 m around the block's
            centre (``info["observation_clipped"]`` says when a point was clipped).
        image_size: pixels per side, an integer in IMAGE_SIZE_RANGE (default 64; None: the
            camera's own size when ``camera`` is given, else 64).
        camera: None (the task's ``default_camera``), a ``tissue_env.camera.Camera`` or a dict of
            its keywords (position, target, up in m, fov_deg, width, height, near, far).
        point_count: K points of the "point_cloud" observation (default 512); point_normals: bool.
        difficulty: "easy", "default" or "hard" (``DIFFICULTIES``): sets the task's difficulty
            keywords from its ``DIFFICULTY`` table (goal distance, tolerances, contrast ...: each
            task's docstring lists them); a difficulty keyword passed explicitly overrides its
            level's value. "default" is the task as registered.
        terminate_on_success: end the episode at a success (True at every level but where the
            task's hard setting asks the agent to hold the success to the end of the episode).
    """

    metadata = {"render_modes": ["rgb_array", "human", "depth_array"], "render_fps": 10}

    #: Defaults a task may override.
    default_shape = (6, 4, 6)
    default_dt = 0.02
    default_solver_tolerance = 1e-4
    default_size = (0.06, 0.04, 0.06)
    default_max_step = 0.002
    min_shape = (2, 2, 2)
    #: The tissue model of ``model=None``: per task, the model closer to neo-Hookean FEM on its scene
    #: (``benchmarks/env_models.py``); a task meshed with boxes needs "baudet-hyperelastic" (Baudet's
    #: springs get the shear modulus right on cubes only).
    default_model = "baudet"
    #: the tissue's elements: "hex" (hexahedra, every task), or "tet" where a task takes ``element``
    element = "hex"
    #: node rows per world beyond the block's, for the nodes a cut adds (``ModelStack.spare_nodes``;
    #: a cutting task sets it)
    spare_nodes = 0
    #: The tools a task moves (T): the action is each tool's (dx, dy, dz) increment in turn, y up, then
    #: the grasp commands (``grasp_commands``: one per tool); the tool features and ``tool_offset``
    #: hold 3 entries per tool in the same order.
    tool_count = 1
    #: Whether the action ends with one grasp command per tool (open / keep / close, ``TaskWorlds._grasp_commands``).
    grasp_commands = False
    #: Observation units: lengths in cm, forces in units of 0.1 N x E / 5 kPa (``worlds.REFERENCE_YOUNG_MODULUS``:
    #: the same strains read the same at any stiffness), strains and volume change in %.
    length_scale = 0.01
    force_scale = 0.1
    #: End the episode when the task succeeds (the ``terminate_on_success`` keyword; its default is
    #: the difficulty's).
    terminate_on_success = True
    #: The keywords each ``difficulty`` sets (``difficulty_settings``; a keyword passed explicitly
    #: overrides its level's value). A task's table names its own keywords too.
    DIFFICULTY = {level: dict(terminate_on_success=True) for level in DIFFICULTIES}
    #: Names of the reward terms (each also in info as ``reward_<name>``).
    reward_names: tuple = ()
    #: A goal-conditioned task's (achieved goal, desired goal) features of the state observation
    #: (``observation_type="goal"``, ``compute_reward``); None for a task without one.
    goal_features: tuple | None = None
    #: Domain randomisation: the physical parameters an episode may draw, each name -> the keyword of
    #: its (low, high) range. The episode's value of each is in every ``info`` under its name, and with
    #: ``observe_parameters`` those drawn are observed. A task lists its own (the README's task table
    #: is generated from it, docs/gen_pages.py).
    randomised_parameters = dict(young_modulus="young_modulus_range", poisson_ratio="poisson_ratio_range",
                                 density="density_range", size="size_range")
    #: The task's other keywords of its episode distribution (goal, target, inclusion place ...).
    episode_keywords: tuple = ()
    #: A one-line description of the task and of its success (README's task table; ``{keyword}`` and
    #: ``{keyword:unit}`` are replaced by the keyword's default, ``readme_summary``).
    summary = ""
    success_summary = ""

    @classmethod
    def observation_types(cls) -> tuple:
        """The ``observation_type`` values the task takes: every one of OBSERVATION_TYPES, "goal" only
        for a goal-conditioned task (``goal_features``)."""
        return tuple(kind for kind in OBSERVATION_TYPES if kind != "goal" or cls.goal_features is not None)

    def __init__(self, *, young_modulus=5.0e3, poisson_ratio=0.45, density=1060.0, shape=None, size=None,
                 integrator="implicit", dt=None, substeps=1, max_step=None, model=None,
                 hourglass_control=None, volume_stiffness=None, gravity=9.81, observation_type="state", young_modulus_range=None,
                 poisson_ratio_range=None, density_range=None, volume_weight=1.0, strain_threshold=0.3, strain_weight=1.0,
                 instability_penalty=10.0, solver_tolerance=None, preconditioner="auto", render_mode=None,
                 max_nodes=MAX_NODES, image_size=None, camera=None, point_count=512, point_normals=False,
                 difficulty="default", terminate_on_success=None, size_range=None, observe_parameters=False,
                 render_key=False, integrator_scheme="euler", damping_ratio=None, damping_frequency=1.0):
        settings = difficulty_settings(self.DIFFICULTY, difficulty, dict(terminate_on_success=terminate_on_success))
        self.difficulty = difficulty
        self.terminate_on_success = check_flag("terminate_on_success", settings["terminate_on_success"])
        self._check_material_and_block(young_modulus, poisson_ratio, density, shape, size, max_nodes)
        self._check_stepping(integrator, dt, substeps, max_step, model, hourglass_control, volume_stiffness, gravity)
        self.damping_ratio, self.damping_frequency, self.integrator_scheme = check_damping(
            damping_ratio, damping_frequency, integrator, integrator_scheme, SCHEMES)
        self._check_observation_type(observation_type)
        self._check_randomisation(young_modulus_range, poisson_ratio_range, density_range, size_range,
                                  observe_parameters)
        self._check_reward_and_solver(volume_weight, strain_threshold, strain_weight, instability_penalty,
                                      solver_tolerance, preconditioner, render_mode)
        self.render_key = check_flag("render_key", render_key)
        self._build_block()
        self._camera_view = self._camera_setup(image_size, camera, point_count, point_normals)
        self._build_spaces()
        self._renderer = None
        self._worlds = None  # this env's one world (``TaskWorlds``), built at its first reset
        self.state = None

    def _check_material_and_block(self, young_modulus, poisson_ratio, density, shape, size, max_nodes):
        """``__init__``'s material (Pa, kg/m^3) and block (hexahedra per axis, extent in m), checked."""
        self.young_modulus = positive_scalar("young_modulus", young_modulus, "Pa")
        self.poisson_ratio = check_poisson_ratio("poisson_ratio", poisson_ratio)
        self.density = positive_scalar("density", density, "kg/m^3")
        self.shape = check_shape("shape", self.default_shape if shape is None else shape, self.min_shape)
        self.max_nodes = max_nodes
        self.size = check_vector("size", self.default_size if size is None else size)

    def _check_stepping(self, integrator, dt, substeps, max_step, model, hourglass_control, volume_stiffness,
                        gravity):
        """``__init__``'s stepping (integrator, dt in s, substeps, the tool's max_step in m), model and
        gravity (m/s^2), checked; the task's defaults where None."""
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        self.integrator_name = integrator
        self.dt = positive_scalar("dt", self.default_dt if dt is None else dt, "s")
        if isinstance(substeps, bool) or not float(substeps).is_integer() or int(substeps) < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
        self.substeps = int(substeps)
        self.max_step = positive_scalar("max_step", self.default_max_step if max_step is None else max_step, "m")
        self.model_name, self.hourglass_control, self.volume_stiffness = check_model(
            self.default_model if model is None else model, hourglass_control, volume_stiffness)
        self.gravity = nonnegative_scalar("gravity", gravity)

    def _check_observation_type(self, observation_type):
        """``__init__``'s observation_type, checked against the task's ``observation_types``."""
        if observation_type not in OBSERVATION_TYPES:
            raise ValueError(f"observation_type must be one of {OBSERVATION_TYPES}, got {observation_type!r}")
        if observation_type not in self.observation_types():
            raise ValueError(f"observation_type='goal' needs a goal-conditioned task (TumorPositioning); "
                             f"{type(self).__name__} has no goal that an achieved state can be relabelled with "
                             f"(see its docstring); use one of {self.observation_types()}")
        self.observation_type = observation_type

    def _check_randomisation(self, young_modulus_range, poisson_ratio_range, density_range, size_range,
                             observe_parameters):
        """``__init__``'s domain randomisation (the ranges drawn from at each reset) and
        observe_parameters, checked against the task's ``randomised_parameters`` and observation type."""
        self.young_modulus_range = check_range(
            "young_modulus_range", young_modulus_range, lambda n, v: positive_scalar(n, v, "Pa"))
        self.poisson_ratio_range = check_range("poisson_ratio_range", poisson_ratio_range, check_poisson_ratio)
        self.density_range = check_range("density_range", density_range,
                                         lambda n, v: positive_scalar(n, v, "kg/m^3"))
        self.episode_density = self.density  # the episode's (drawn from density_range at each reset)
        self.size_range = check_vector_range("size_range", size_range)
        self.observe_parameters = check_flag("observe_parameters", observe_parameters)
        if self.size_range is not None and "size" not in self.randomised_parameters:
            raise ValueError(f"{type(self).__name__} takes no size_range: its block size is fixed per env (see its "
                             f"docstring); it randomises {tuple(self.randomised_parameters.values())}")
        if self.observe_parameters and self.observation_type in VISUAL_TYPES:
            raise ValueError(f"observe_parameters appends values to a vector observation; observation_type="
                             f"{self.observation_type!r} is an image or point cloud: use one of "
                             f"{tuple(t for t in self.observation_types() if t not in VISUAL_TYPES)}")

    def _check_reward_and_solver(self, volume_weight, strain_threshold, strain_weight, instability_penalty,
                                 solver_tolerance, preconditioner, render_mode):
        """``__init__``'s reward weights, the linear solver's tolerance and preconditioner and the
        render mode, checked."""
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

    def _build_block(self):
        """The block's mesh, surface and caches, the task's scene, and the default model (built now:
        it validates material and geometry together, and every ``size_range`` corner's too)."""
        self.spacing = self.size / np.asarray(self.shape)
        self.mesh = self._build_mesh()
        #: the episode's block (``size_range``): its extent (3,) m and mesh; the ``size`` block's
        #: until a reset draws another
        self.episode_size, self.episode_mesh = self.size, self.mesh
        nodes = self.mesh.nodes
        self.centre = 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))
        self.surface_nodes = self.mesh.surface_nodes()
        self._surface_faces = self.mesh.surface_faces()
        # the caches below are shared by a vector env's copies (``share_caches``), which may reset on
        # several threads: one lock guards them
        self._cache_lock = threading.RLock()
        # models by material (MODEL_CACHE_SIZE, within the "models" byte budget: sim_core.caches);
        # each model keeps its start positions in its derived data, so they go with it
        self._model_cache = BudgetCache("models", MODEL_CACHE_SIZE)
        self._setup_scene()
        # Build the default model now: it validates material and geometry together (Baudet's edge
        # stiffness must stay positive) and raises ValueError at construction, not at reset.
        try:
            self.model = self._model(self.young_modulus, self.poisson_ratio, self._default_task_key())
        except ValueError as error:
            raise ValueError(f"shape/size/poisson_ratio give an invalid model: {error}") from error
        if self.size_range is not None:  # the extreme aspect ratios are at the range's corners
            for corner in itertools.product(*zip(*self.size_range)):
                try:
                    self._build_model(np.array(corner), self.young_modulus, self.poisson_ratio,
                                      self._default_task_key(), self.density)
                except ValueError as error:
                    raise ValueError(f"size_range corner {list(corner)} m gives an invalid model with shape "
                                     f"{self.shape}: {error}") from error

    def _build_spaces(self):
        """The action space (the tool's move, in units of max_step) and the observation space of the
        observation type: the features' sizes (the task's, the surface's, the randomised parameters')."""
        observation_type = self.observation_type
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.action_size,), dtype=np.float32)
        tools = 3 * self.tool_count
        self._feature_sizes = OrderedDict(
            tool_position=tools, tool_displacement=tools, reaction_force=tools, relative_volume_change=1, max_strain=1)
        self._feature_sizes.update(self._task_feature_sizes())
        if observation_type not in ("state", "goal"):
            self._feature_sizes["surface_displacement"] = 3 * len(self.surface_nodes)
        if self.observe_parameters:
            count = sum(np.size(low) for _, (low, _) in self._randomised())
            if not count:
                raise ValueError(f"observe_parameters observes the randomised parameters, and none is: give one of "
                                 f"{tuple(self.randomised_parameters.values())}")
            self._feature_sizes["parameters"] = count
        if observation_type in VISUAL_TYPES:
            self.observation_space = self._visual_space()
        elif observation_type == "dict":
            self.observation_space = spaces.Dict({
                name: spaces.Box(-feature_limit(name), feature_limit(name), shape=(n,), dtype=np.float32)
                for name, n in self._feature_sizes.items()})
        else:
            self.observation_space = self._state_space()
        if observation_type == "goal":
            self.observation_space = self._goal_space()

    @property
    def action_size(self) -> int:
        """Entries of an action: 3 per tool (its displacement increment, x, y up, z), then one grasp
        command per tool where the task has them (``grasp_commands``)."""
        return (4 if self.grasp_commands else 3) * self.tool_count

    #: The task's worlds (``tissue_env.worlds.TaskWorlds`` subclass): its env step on arrays over
    #: worlds, the single env's (one world) and the vector env's (N).
    worlds_class = TaskWorlds

    # -- visual observations (tissue_env.camera) -----------------------------------------------------
    #: The default camera: the point it looks at (fractions of the block along x, y, z), its
    #: direction from that point (normalised), its distance in units of the block's largest side,
    #: and its vertical field of view (degrees).
    camera_target = (0.5, 0.5, 0.5)
    camera_direction = (0.45, 1.0, 1.1)
    camera_distance = 2.4
    camera_fov = 45.0

    def default_camera(self, width=DEFAULT_IMAGE_SIZE, height=DEFAULT_IMAGE_SIZE) -> Camera:
        """The task's camera (m): at ``camera_distance`` block sizes from ``camera_target`` along
        ``camera_direction``, looking at it, y up; near 1 cm, far beyond the whole scene."""
        direction = np.asarray(self.camera_direction, dtype=float)
        extent = float(np.max(self.size))
        distance = self.camera_distance * extent
        target = np.asarray(self.camera_target, dtype=float) * self.size
        position = target + distance * direction / np.linalg.norm(direction)
        return Camera(position=position, target=target, up=(0.0, 1.0, 0.0), fov_deg=self.camera_fov,
                      width=width, height=height, near=0.01, far=distance + 4.0 * extent)

    def _camera_setup(self, image_size, camera, point_count, point_normals) -> CameraView:
        """The env's ``CameraView`` from its visual keywords (see the class docstring), checked."""
        if image_size is not None:
            low, high = IMAGE_SIZE_RANGE
            if isinstance(image_size, bool) or not float(image_size).is_integer() or not low <= image_size <= high:
                raise ValueError(f"image_size must be an integer from {low} to {high} (pixels per side), "
                                 f"got {image_size!r}")
            image_size = int(image_size)
        if camera is None:
            size = DEFAULT_IMAGE_SIZE if image_size is None else image_size
            camera = self.default_camera(size, size)
        else:
            if isinstance(camera, dict):
                allowed = tuple(f.name for f in dataclasses.fields(Camera) if f.init)
                unknown = sorted(set(camera) - set(allowed))
                if unknown:
                    raise ValueError(f"camera dict has unknown keys {unknown}; a Camera takes {allowed}")
                camera = Camera(**camera)
            elif not isinstance(camera, Camera):
                raise ValueError(f"camera must be None, a tissue_env.camera.Camera or a dict of its keywords, "
                                 f"got {type(camera).__name__}")
            if image_size is not None:
                camera = camera.with_size(image_size, image_size)
        low, high = IMAGE_SIZE_RANGE
        if not (low <= camera.width <= high and low <= camera.height <= high):
            raise ValueError(f"the camera's image must be {low} to {high} pixels per side, got "
                             f"{camera.width} x {camera.height}")
        if isinstance(point_count, bool) or not float(point_count).is_integer() or not 1 <= point_count <= 100_000:
            raise ValueError(f"point_count must be an integer from 1 to 100000, got {point_count!r}")
        point_normals = check_flag("point_normals", point_normals)
        reach = OBS_LIMIT * self.length_scale  # the state observation's range of positions
        return CameraView(camera, self._surface_faces, self.mesh.nodes, self.tool_nodes, int(point_count),
                          bool(point_normals), bounds=(self.centre - reach, self.centre + reach))

    @property
    def camera(self) -> Camera:
        """The camera of the visual observations and of ``render_mode="depth_array"``."""
        return self._camera_view.camera

    def _visual_space(self):
        """The observation space of a visual ``observation_type`` (``tissue_env.camera.CameraView.space``)."""
        return self._camera_view.space(self.observation_type)

    # -- hooks a task implements -------------------------------------------------------------
    def _build_mesh(self) -> HexMesh:
        """The undeformed mesh (m) of the tissue, from the checked ``shape``, ``size`` and
        ``spacing`` (= size / shape), after ``check_work`` with ``max_nodes``. Default: the
        structured block ``HexMesh.block(shape, spacing)`` over [0, Lx] x [0, Ly] x [0, Lz]. A task
        on another mesh (an organ from a mask: ``LiverNeedleAlignmentEnv``) returns it here; the
        rest of the base class reads only the mesh (its nodes, surface, bounding box)."""
        check_work(self.shape, self.max_nodes)
        return HexMesh.block(self.shape, self.spacing)

    def _setup_scene(self):
        """Set ``self.fixed_nodes`` (nodes attached to the body) and ``self.tool_nodes``."""
        raise NotImplementedError

    def _task_feature_sizes(self) -> dict:
        return {}

    def _default_task_key(self):
        """Key of the task's material layout (e.g. the inclusion cell), None when homogeneous."""
        return None

    def _material(self, young_modulus, poisson_ratio, task_key, density, mesh, size) -> Material:
        """The material (E Pa, nu, density kg/m^3, per element where the task's layout ``task_key``
        varies it) of ``mesh``, the block of extent ``size`` (3,) m (``size``, or a ``size_range``
        draw; ``_block_mesh``)."""
        return Material(young_modulus, poisson_ratio, density)

    def _reset_task(self, options):
        """Draw the episode (goal, target, ...) from ``self.np_random``; set ``self.task_key``."""

    def _start_control(self) -> Control:
        """The sim_core Control at the episode's start, the tool at rest: what the start state is
        the equilibrium of (``_initial_positions``). Sets ``self.start_tool_mask`` ((n, 3) bool,
        the dofs the tool imposes then)."""
        control = self.base_control.copy()
        control.impose(self.tool_nodes, self.tool_rest)
        self.start_tool_mask = np.zeros((self.mesh.n_nodes, 3), bool)
        self.start_tool_mask[self.tool_nodes] = True
        return control

    def _initial_positions(self, model, control):
        """Start positions: the static equilibrium under gravity with the tool at rest. A material
        that cannot carry its own weight in this shape has none: ValueError (an episode from the
        rest shape would be meaningless)."""
        result = solve_static(model, control, tolerance=1e-6)
        if result.converged:
            return result.positions
        material = (f"young_modulus={self.episode_young_modulus:g} Pa, density={self.episode_density:g} kg/m^3, "
                    f"gravity={self.gravity:g} m/s^2 and size {self.episode_size.tolist()} m")
        # the order of the sag under gravity, rho g L^2 / E (m), against the rounding of the node
        # positions: far below it, Newton's residual is rounding and cannot reach the tolerance
        sag = self.episode_density * self.gravity * float(np.max(self.episode_size)) ** 2 / self.episode_young_modulus
        rounding = np.finfo(float).eps * float(np.abs(model.rest_positions).max())
        if sag < SAG_RESOLUTION * rounding:
            raise ValueError(
                f"the block's start equilibrium under gravity cannot be resolved ({result.message}) with {material}: "
                f"the tissue is too stiff for double precision, its sag (about {sag:.1e} m) is within "
                f"{SAG_RESOLUTION:.0e} rounding steps ({rounding:.1e} m) of its node positions; use a softer "
                "material (soft tissue is 1e2 to 1e6 Pa) or more gravity")
        raise ValueError(f"the block has no start equilibrium under gravity ({result.message}) with {material}: "
                         + self._weight_advice(sag, load_level(result.message)))

    def _weight_advice(self, sag, carried=None):
        """The cause and the knobs of a tissue that cannot carry its own weight: too soft for it, or
        (denser than TISSUE_DENSITY_MAX) too heavy for its stiffness, its sag ``sag`` (m, rho g
        L^2 / E) against the block's size, and the stiffness or density that would carry it
        (WEIGHT_SAFETY over the ``carried`` fraction of the weight, when known)."""
        length = float(np.max(self.episode_size))
        modulus, density = self.episode_young_modulus, self.episode_density
        heavy = density > TISSUE_DENSITY_MAX
        cause = (f"the tissue is too heavy for its stiffness (density {density:g} kg/m^3; soft tissue is about "
                 f"1000-1100)" if heavy else f"the tissue is too soft for its weight (young_modulus {modulus:g} Pa)")
        text = (f"{cause}: it cannot carry its own weight, its sag under gravity (rho g L^2 / E) is about "
                f"{sag:.2g} m, {sag / length:.2g} times the block's largest side ({length:g} m)")
        if carried is not None and 0.0 < carried < 1.0:
            factor = WEIGHT_SAFETY / carried
            text += (f", and the static solve carried {carried:.0%} of it. Use a stiffer material (young_modulus "
                     f"{modulus * factor:.2g} Pa or more) or a lighter one (density {density / factor:.2g} kg/m^3 "
                     f"or less)")
        else:
            text += ". Use a stiffer or lighter material"
        ranges = [name for name in ("young_modulus_range", "density_range") if getattr(self, name, None) is not None]
        if ranges:
            text += f" (with {' and '.join(ranges)}: the range's soft or heavy end)"
        return text + ", a smaller block or less gravity; a finer mesh does not help (the load is the same)"

    def scripted_action(self) -> np.ndarray:
        """A hand-written controller's action for the current state (a baseline)."""
        raise NotImplementedError

    def _require_reset(self, call):
        """Raise RuntimeError for ``call`` (e.g. "render()") when no episode has started yet: the
        state, the tool and the task's goal are drawn by ``reset``."""
        if self.state is None:
            raise RuntimeError(f"call reset() before {call}")

    # -- domain randomisation ------------------------------------------------------------------------
    def _randomised(self) -> list:
        """[(parameter, (low, high))] of the ``randomised_parameters`` whose range is given."""
        return [(name, getattr(self, keyword)) for name, keyword in self.randomised_parameters.items()
                if getattr(self, keyword) is not None]

    def observed_parameters(self) -> np.ndarray:
        """The episode's randomised parameters (``_randomised``, in ``randomised_parameters`` order, a
        size's axes one by one), each normalised to [-1, 1] over its range (0 for a range of one
        value): the ``parameters`` feature of ``observe_parameters``."""
        parts = []
        for name, (low, high) in self._randomised():
            value = np.atleast_1d(np.asarray(getattr(self, "episode_" + name), dtype=float))
            low, high = np.atleast_1d(low), np.atleast_1d(high)
            span = np.asarray(high, dtype=float) - low
            parts.append(np.where(span > 0, 2.0 * (value - low) / np.where(span > 0, span, 1.0) - 1.0, 0.0))
        return np.concatenate(parts)

    # -- model building --------------------------------------------------------------------------
    def _model(self, young_modulus, poisson_ratio, task_key, density=None, size=None):
        """The cached model of a material (E Pa, nu, the task's layout key, density kg/m^3, default
        ``density``) on a block of ``size`` (3,) m (default ``size``), built on a miss."""
        density = self.density if density is None else float(density)
        size = self.size if size is None else np.asarray(size, dtype=float)
        key = (float(young_modulus), float(poisson_ratio), density, task_key) + (
            () if np.array_equal(size, self.size) else (tuple(size.tolist()),))
        return self._model_of_key(key)

    def _model_of_key(self, key):
        """The cached model of a ``_model`` cache key (E Pa, nu, density kg/m^3, task key[, size m]),
        built on a miss; the model keeps its key (``snapshots.MODEL_KEY``: a snapshot names its
        model by it)."""
        with self._cache_lock:
            model = self._model_cache.get(key)
            if model is None:
                young_modulus, poisson_ratio, density, task_key = key[:4]
                size = np.array(key[4]) if len(key) > 4 else self.size
                model = self._build_model(size, young_modulus, poisson_ratio, task_key, density)
                model.derived.put(MODEL_KEY, key)
                self._model_cache.put(key, model)
            return model

    def _build_model(self, size, young_modulus, poisson_ratio, task_key, density):
        """The model of a material on the block of extent ``size`` (3,) m (``_block_mesh``)."""
        mesh = self._block_mesh(size)
        # hourglass control and volume forces are hexahedral terms (a tetrahedral "baudet" has neither)
        options = (dict(hourglass_control=self.hourglass_control, volume_stiffness=self.volume_stiffness)
                   if self.model_name == "baudet" and isinstance(mesh, HexMesh) else {})
        material = self._material(young_modulus, poisson_ratio, task_key, density, mesh, size)
        if self.damping_ratio is not None:  # the task's material with the tissue's damping law
            material = dataclasses.replace(material, damping_ratio=self.damping_ratio,
                                           damping_frequency=self.damping_frequency)
        return build_model(mesh, material, model=self.model_name,
                           gravity=(0.0, -self.gravity, 0.0), **options)

    def _block_mesh(self, size):
        """The block of ``shape`` with extent ``size`` (3,) m: ``mesh`` itself at ``size``, else the
        same hexahedra scaled along each axis about the origin (a ``size_range`` draw)."""
        if np.array_equal(size, self.size):
            return self.mesh
        return HexMesh.block(self.shape, np.asarray(size, dtype=float) / np.asarray(self.shape))

    def _place_scene(self, nodes):
        """The scene's rest geometry on the episode's block of rest ``nodes`` (n, 3) m (``_setup_scene``
        on the ``size`` block, each reset on the drawn one): the attached nodes held at their rest
        positions (``base_control``) and the tool's rest (``tool_rest``). Tasks extend it."""
        self.base_control = Control.free(self.mesh.n_nodes).impose(self.fixed_nodes, nodes[self.fixed_nodes])
        self.tool_rest = nodes[self.tool_nodes]

    def _start_positions(self, model):
        # The start depends only on the model (the tool starts at rest): computed once per model.
        with self._cache_lock:  # held while a missing start is solved: once per model
            start = model.derived.peek(_START)
            if start is None:
                start = model.derived.put(_START, self._initial_positions(model, self._start_control()))
            return start.copy()

    # -- Gymnasium API -----------------------------------------------------------------------------
    def _reset_episode(self, *, seed=None, options=None):
        """Draw the next episode (material, the task's goal ..., from ``self.np_random``) and its
        start state: everything a reset does but the measurement (``reset``, and a vector env's
        copies, which the vector env then loads into its worlds)."""
        gym.Env.reset(self, seed=seed)
        self.state = None
        young_modulus, poisson_ratio = self.young_modulus, self.poisson_ratio
        if self.young_modulus_range is not None:
            young_modulus = float(self.np_random.uniform(*self.young_modulus_range))
        if self.poisson_ratio_range is not None:
            poisson_ratio = float(self.np_random.uniform(*self.poisson_ratio_range))
        self.episode_density = self.density
        if self.density_range is not None:
            self.episode_density = float(self.np_random.uniform(*self.density_range))
        self.episode_young_modulus, self.episode_poisson_ratio = young_modulus, poisson_ratio
        if self.size_range is not None:
            self.episode_size = self.np_random.uniform(*self.size_range)
            self.episode_mesh = self._block_mesh(self.episode_size)
            self._place_scene(self.episode_mesh.nodes)
        self.tool_offset = np.zeros(3 * self.tool_count)
        self.task_key = self._default_task_key()
        self._reset_task(options)
        self.model = self._model(young_modulus, poisson_ratio, self.task_key, self.episode_density, self.episode_size)
        self.episode_mesh = self.model.mesh  # the cached model's (shared by snapshots)
        self.rest_volume = float(self.model.rest_volume.sum())
        positions = self._start_positions(self.model)
        self.start_control = self._start_control()
        self.state = State(positions, np.zeros_like(positions))
        self._start_hook()
        self.elapsed_steps = 0

    def reset(self, *, seed=None, options=None):
        self._reset_episode(seed=seed, options=options)
        if self._worlds is None:
            self._worlds = self.worlds_class([self], threads=1)
        worlds = self._worlds
        worlds.load(0)
        observations, infos = worlds.observe(_ONE)
        worlds.write_back(0)
        if self.render_mode == "human":
            self.render()
        return _row(observations), _row(infos)

    @property
    def model_cache(self) -> BudgetCache:
        """The models this env built, keyed by material, block size and task layout (``MODEL_CACHE_SIZE``
        entries within the "models" byte budget of ``sim_core.caches``): one object shared by
        the envs that ``share_caches`` with it, such as a vector env's copies."""
        return self._model_cache

    @property
    def worlds(self) -> TaskWorlds | None:
        """This env's one world (``tissue_env.worlds.TaskWorlds``: its solver, stacked model and
        step stages), built at the first ``reset``; None before."""
        return self._worlds

    def _start_hook(self):
        """Called at the end of an episode's draw, after the start state exists (task bookkeeping)."""

    def __getstate__(self):  # a lock does not pickle: a copy gets its own (and its own caches)
        state = self.__dict__.copy()
        state.pop("_cache_lock", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._cache_lock = threading.RLock()

    #: a task's caches that snapshots share (see SHARED_ATTRIBUTES)
    shared_attributes: tuple = ()

    def shared_names(self) -> tuple:
        """The attributes a snapshot refers to instead of holding (``SHARED_ATTRIBUTES`` and the
        task's ``shared_attributes``)."""
        return SHARED_ATTRIBUTES + self.shared_attributes

    def _snapshot_settings(self) -> tuple:
        """((keyword, value), ...) of ``SNAPSHOT_SETTINGS``: what a snapshot's env and the restoring
        env must share (the rest of an env's keywords are attributes the snapshot restores)."""
        values = ((name, getattr(self, name)) for name in SNAPSHOT_SETTINGS)
        return tuple((name, tuple(value.tolist()) if isinstance(value, np.ndarray) else value)
                     for name, value in values) + (("nodes", self.mesh.n_nodes),)

    def get_state(self) -> EpisodeState:
        """A snapshot of the current episode (state, tool, goal, random generator, counters, the
        solver's per-world state): ``set_state(snapshot)`` returns this environment, or another one
        of the same class and keywords (also in another process, the snapshot pickled), to it, and
        its next steps are then those taken after the snapshot, bit for bit (planning, tree search,
        replays). It holds the episode, not the scene: models, caches and the solver's factors are
        referred to, not copied (``tissue_env.snapshots``; sizes and rates: benchmarks/snapshots.py)."""
        return snapshots.capture(self)

    def set_state(self, state: EpisodeState):
        """Restore a snapshot of ``get_state`` (any number of times). Its model is looked up in the
        model cache by its material, or built again; ValueError for what is not a snapshot of this
        task, or one of an env with other keywords (``SNAPSHOT_SETTINGS``, or a model that differs)."""
        snapshots.restore(self, state)

    def share_caches(self, other):
        """Use ``other``'s models, start states, first-step factorisations and task caches (an env
        built with the same keywords; the vector envs call it for their copies). Tasks with caches
        of their own extend it."""
        self._cache_lock = other._cache_lock
        self._model_cache = other._model_cache
        self.model = other.model

    def constrain_tool(self, offset):
        """Tool offsets (..., 3) in m, already clipped to the workspace box, projected on the
        task's admissible set (default: the box itself). Vectorised: the worlds call it on their
        (N, 3) offsets (their copies share size and workspace)."""
        return offset

    def _state_space(self) -> spaces.Box:
        """The ``"state"`` observation space: every feature's entries within their bounds
        (``worlds.observation_limits``), float32."""
        limits = observation_limits(self._feature_sizes).astype(np.float32)
        return spaces.Box(-limits, limits, dtype=np.float32)

    # -- goal-conditioned API (observation_type="goal") --------------------------------------------
    def _goal_space(self) -> spaces.Dict:
        """The ``"goal"`` observation space: ``observation`` (the ``"state"`` vector, float32),
        ``achieved_goal`` and ``desired_goal`` (the task's ``goal_features`` in the state
        observation's normalised units, float64: ``compute_reward`` recomputes the step's reward
        from them to the last bit)."""
        achieved, _ = self.goal_features
        size = self._feature_sizes[achieved]
        goal = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(size,), dtype=np.float64)
        return spaces.Dict(dict(
            observation=self._state_space(),
            achieved_goal=goal, desired_goal=copy.deepcopy(goal)))

    @property
    def compute_reward(self):
        """``compute_reward(achieved_goal, desired_goal, info)``: the reward of a step whose
        outcome was ``achieved_goal`` had the goal been ``desired_goal``, vectorised over a batch
        of goals (..., k) with ``info`` one step's info or a list / array of them, one per goal
        (SB3's ``HerReplayBuffer`` passes an array; give it ``copy_info_dict=True``, since the
        goal-independent terms come from the info). Equal to the step's reward, bit for bit, for
        the step's own goals (``TaskWorlds.compute_reward``). Present only with
        ``observation_type="goal"`` (goal-env checkers detect a goal env by this method)."""
        if self.observation_type != "goal":
            raise AttributeError(f"compute_reward exists only with observation_type='goal' (this env has "
                                 f"observation_type={self.observation_type!r})")
        return self._compute_reward

    def _compute_reward(self, achieved_goal, desired_goal, info):
        if self._worlds is None:  # the reward's constants only: the worlds reset will load
            self._worlds = self.worlds_class([self], threads=1)
        return self._worlds.compute_reward(achieved_goal, desired_goal, info)

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape} (each tool's dx, dy, dz"
                             f"{', then a grasp command per tool' if self.grasp_commands else ''}), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action must be finite (no NaN or infinity), got {action.tolist()}")
        self._require_reset("step()")
        worlds = self._worlds
        observations, rewards, terminated, infos = worlds.step(action[None], _ONE)
        worlds.write_back(0)
        if self.render_mode == "human":
            self.render()
        return _row(observations), float(rewards[0]), bool(terminated[0]), False, _row(infos)
