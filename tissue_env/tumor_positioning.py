"""TumorPositioning-v0: bring a tumour inside the tissue to a goal by moving a grasped surface patch."""

from __future__ import annotations

import numpy as np

from sim_core import solve_static
from sim_core.solvers.static import FactorCache
from sim_core.geometry.mesh import LOCAL_CORNERS

from .base import (TISSUE_DENSITY_MAX, TissueEnv, check_range, check_region, check_vector, difficulty_settings,
                   nonnegative_scalar, positive_scalar)
from .camera import VISUAL_TYPES
from .vector import TissueVectorEnv
from .worlds import TaskWorlds


# Goal solves: keep the (cached) start tangent while it contracts the residual by 0.95 per step,
# with Anderson mixing over 5 steps, and give up past 8 load increments (the last converged goal is
# kept), for the reset time: long chord runs, accelerated, reuse one factorisation for most of a
# goal, and the increment cap bounds the time a goal that cannot converge (a deep press on a fine
# mesh) takes to fail; the goals are Newton's (docs/performance_notes.md, "Static solves and resets").
GOAL_SOLVER = dict(chord_contraction=0.95, acceleration=5, max_load_steps=8)
#: A retry (a larger displacement, solved from the previous equilibrium) gives up sooner: the
#: failing ones (large compressions at the workspace corners) are the slowest resets, and giving up
#: sooner leaves the goals the same.
GOAL_RETRY_SOLVER = dict(GOAL_SOLVER, max_load_steps=2, max_iterations=20)
#: Random goal directions a reset tries before it says that no goal is reachable (``_start_hook``).
GOAL_ATTEMPTS = 5
#: The sag under gravity (rho g L^2 / E), in block sizes, up to which the default goals are reached
#: (measured on the default block: 0.52 at E = 1000 Pa and 0.39 at density 4000 kg/m^3 reached them,
#: 0.57 at E = 460 Pa and 0.98 at density 1e4 kg/m^3 did not): the stiffness and density a
#: reset without a reachable goal advises.
GOAL_SAG = 0.4


def square_patch(nodes, candidates, centre, tool_size, tolerance):
    """The ``candidates`` (node indices) whose rest position among ``nodes`` (n, 3) m lies within
    ``tool_size`` / 2 (+ ``tolerance``) m of ``centre`` (3,) m along x and along z: a grasped square
    of physical size, so a finer mesh grasps the same patch with more nodes."""
    offset = np.abs(nodes[candidates][:, [0, 2]] - np.asarray(centre)[[0, 2]])
    return candidates[np.all(offset <= 0.5 * tool_size + tolerance, axis=1)]


def trilinear_weights(local):
    """(8,) weights of the VTK corners of a hexahedron at local coordinates ``local`` in [0, 1]^3."""
    local = np.asarray(local, dtype=float)
    return np.prod(LOCAL_CORNERS * local + (1.0 - LOCAL_CORNERS) * (1.0 - local), axis=1)


class TumorPositioningWorlds(TaskWorlds):
    """TumorPositioning's step on N worlds (``tissue_env.worlds``)."""

    # Solver "reference": the start-of-episode node-block factor, shared by the worlds that start
    # alike as every world's preconditioner, costs no more iterations per world than per-world
    # factors kept up to date (solver "factorised") and saves their factorisations: the tool moves
    # the tissue only a few millimetres from the start. Solved in lockstep chunks, each pass over
    # the shared factor and hourglass matrix serves all of a chunk's running worlds
    # (``sim_core.solvers.implicit``'s "reference"; benchmarks/vector_env_speed.py and the performance page).
    # The measurement's force pass is the next step's (the reaction force only reads it).
    linear_solver = "reference"
    share_force_pass = True

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count = self.task, self.num_envs
        # the imposed dofs (attached bottom, grasped patch) do not change during an episode; each
        # world's grasped patch (``tool_size_range``) and the targets of its attached face (its block,
        # ``size_range``), set at its reset
        self._base_fixed = env.base_control.fixed
        self._fixed = np.zeros((count,) + self._base_fixed.shape, bool)
        self._tool_mask = np.zeros_like(self._fixed)
        self._base_target = np.zeros((count,) + self._base_fixed.shape)
        #: the distinct grasped patches (node indices), by content, and each world's
        self._patches, self._patch_of, self._groups = {}, [None] * count, None
        for index in range(count):
            self._set_patch(index, env.tool_nodes, env.base_control.target)
        corners = env.mesh.elements.shape[1]  # the nodes of the element holding the tumour: 8, or 4 (tetrahedra)
        self.tumor_nodes = np.zeros((count, corners), dtype=int)
        self.tumor_weights = np.zeros((count, corners))
        self.tumor_start = np.zeros((count, 3))
        self.tool_size_of = np.zeros(count)  # each world's grasped square's side this episode, m
        self.goal = np.zeros((count, 3))
        self.success_distance, self.success_bonus = env.success_distance, env.success_bonus

    def _set_patch(self, index, nodes, base_target):
        key = np.asarray(nodes).tobytes()
        self._patches.setdefault(key, np.asarray(nodes))
        if self._patch_of[index] != key:
            self._patch_of[index], self._groups = key, None
        self._tool_mask[index] = False
        self._tool_mask[index, nodes] = True
        self._fixed[index] = self._base_fixed | self._tool_mask[index]
        self._base_target[index] = base_target

    def _patch_groups(self):
        """[(grasped nodes, worlds holding that patch)]: one pass per distinct patch (one by default)."""
        if self._groups is None:
            keys = self._patch_of
            self._groups = [(self._patches[key], np.array([i for i, k in enumerate(keys) if k == key]))
                            for key in dict.fromkeys(keys)]
            self._patches = {key: self._patches[key] for key in dict.fromkeys(keys)}
        return self._groups

    def _load_task(self, index, env):
        self._set_patch(index, env.tool_nodes, env.base_control.target)
        self.tumor_nodes[index] = env.tumor_nodes
        self.tumor_weights[index] = env.tumor_weights
        self.tumor_start[index] = env.tumor_start
        self.tool_size_of[index] = env.episode_tool_size
        self.goal[index] = env.goal

    def _control(self, rows=None):
        target = self._base_target.copy()
        for nodes, rows in self._patch_groups():  # the patch at its rest (each world's block) + the tool's offset
            target[rows[:, None], nodes] = self.rest_positions[rows][:, nodes] + self.tool_offset[rows, None, :]
        return self._fixed, target, self._tool_mask

    def _tool_position(self, positions):
        position = np.empty((self.num_envs, 3))
        for nodes, rows in self._patch_groups():
            position[rows] = positions[rows][:, nodes].mean(axis=1)
        return position

    def _tumor(self, positions):
        """(N, 3) the tumour's positions, m: trilinear in its element's nodes of ``positions`` (N, n, 3)."""
        corners = positions[np.arange(self.num_envs)[:, None], self.tumor_nodes]  # (N, 8 or 4, 3)
        return (self.tumor_weights[:, None, :] @ corners)[:, 0]

    def _task_measures(self, positions):
        tumor = self._tumor(positions)
        if self.goal_observed:  # the distance of the observed goals, the one compute_reward recomputes
            achieved, desired = self._goal_vectors(tumor)
            return dict(tumor=tumor, achieved_goal=achieved, desired_goal=desired,
                        distance=self.goal_distance(achieved, desired))
        return dict(tumor=tumor, distance=np.linalg.norm(self.goal - tumor, axis=1))

    def _goal_vectors(self, tumor):
        """(tumour position, goal position) (N, 3) in the observation's units (cm from the block
        centre): the state observation's ``tumor_position`` and ``goal_position``, and the goal
        observation's achieved and desired goals."""
        return (tumor - self.centre) / self.length_scale, (self.goal - self.centre) / self.length_scale

    def goal_distance(self, achieved, desired):
        """Tumour-goal distance, m, of achieved and desired goals (..., 3) in the observation's units."""
        return np.linalg.norm(desired - achieved, axis=-1) * self.length_scale

    def _task_features(self, measures):
        tumor, scale = measures["tumor"], self.length_scale
        tumor_position, goal_position = self._goal_vectors(tumor)
        return dict(
            tumor_position=tumor_position, goal_position=goal_position,
            goal_error=(self.goal - tumor) / scale, goal_distance=measures["distance"][:, None] / scale,
            tumor_displacement=(tumor - self.tumor_start) / scale,
        )

    def _task_info(self, measures):
        return dict(distance=measures["distance"].copy(), tumor_position=measures["tumor"].copy(),
                    goal=self.goal.copy(), tool_size=self.tool_size_of.copy())

    def _is_success(self, measures):
        return measures["distance"] < self.success_distance

    def _distance_terms(self, distance):
        """The reward terms of the tumour-goal distances (B,) m: distance and success."""
        return dict(distance=-distance / self.length_scale,
                    success=np.where(distance < self.success_distance, self.success_bonus, 0.0))

    def _reward_terms(self, measures):
        terms = self._distance_terms(measures["distance"])
        terms.update(self._damage_terms(measures))
        return terms

    def _goal_reward_terms(self, achieved, desired):
        return self._distance_terms(self.goal_distance(achieved, desired))


class TumorPositioningEnv(TissueEnv):
    """
    ## Description

    A block of liver-like tissue (5 x 5 x 5 cm, 7 x 7 x 7 hexahedra of 7.1 mm, the
    ``baudet-hyperelastic`` mass-spring model of ``sim_core``: compressible neo-Hookean at every
    strain) rests with its bottom face (y = 0) attached to the body. A tool grasps the
    top-surface nodes in the ``tool_size`` = 2.5 cm square at the centre of the top face (all
    components imposed: 4 x 4 nodes spanning 2.14 cm at the default shape, 3 x 3 spanning 1.67 cm
    at (6, 6, 6), 5 x 5 spanning the full 2.5 cm at (8, 8, 8)). A tumour is a material point inside the block (followed by trilinear
    interpolation of its element's nodes). The agent moves the grasped patch so that the tumour
    reaches a goal position: indirect positioning, as when an organ is pushed or pulled to bring a
    lesion into a radiation field or onto a needle path. Goals are reachable by construction: a
    goal is the tumour's equilibrium position (``solve_static``) for a random tool displacement in
    the workspace.

    Physics: one implicit Euler step of ``dt`` = 40 ms per env step (``substeps`` keyword), linear
    solves to a relative residual of 1e-2 (``solver_tolerance``), gravity on (``tissue_env.base``;
    ``model="baudet"`` takes Baudet's small-strain model with hourglass control 1 and volume
    stiffness x100). The defaults are measured (``benchmarks/env_accuracy.py``,
    ``benchmarks/env_models.py``, ``benchmarks/dynamic_convergence.py``; the documentation's
    environment accuracy page has the numbers): the default shape is the most accurate one that
    keeps 300 env steps/s on one core with a 1.25x margin, and the model is the one closer to
    neo-Hookean FEM on this scene (the patch the tool grasps, on a 14^3 mesh): within 10% in
    static tool force, tumour displacement and volume change, where ``baudet`` is off by tens of
    percent. The loose solver tolerance keeps the equilibria (an inexact solve converges to the
    same state) and runs faster. Random actions (``benchmarks/success_rates.py --stability 100``)
    end 2 of 100 episodes ``unstable``: an element inverts where the tool has pressed about 1.5 cm
    and dragged about 2 cm sideways (40-50% strain at the patch's edge), a state that neo-Hookean
    FEM on the same mesh still resolves (the hyperelastic model has no hourglass control, and its
    springs alone do not keep such corners from folding); ``model="baudet"``, stiffened by its
    volume forces, keeps them valid but is much further from neo-Hookean everywhere else. After a
    tool move the tumour settles to the static equilibrium within a few steps (tested).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: the tool displacement increment, scaled by ``max_step``
    (default 2 mm) and clipped to the workspace (``workspace`` m around the grasp point, default
    +-20 mm per axis). Out-of-range actions are clipped; NaN or infinite actions raise ValueError.

    | Num | Action                    | Min | Max | Unit          |
    |-----|---------------------------|-----|-----|---------------|
    | 0   | tool increment along x    | -1  | 1   | max_step (m)  |
    | 1   | tool increment along y    | -1  | 1   | max_step (m)  |
    | 2   | tool increment along z    | -1  | 1   | max_step (m)  |

    ## Observation Space

    ``observation_type="state"`` (default): ``Box(-100, 100, (24,), float32)``, every entry within
    +-100 but the maximum spring strain's, within +-1000 (the tissue can stretch past 100%). Positions
    are relative to the centre of the undeformed block. Values are clipped to their bounds (never
    reached; ``info["observation_clipped"]`` says when).

    | Index | Observation                                   | Unit (normalised)        |
    |-------|-----------------------------------------------|--------------------------|
    | 0-2   | tool position (mean of grasped nodes)         | cm from block centre     |
    | 3-5   | tool displacement from its start              | cm                       |
    | 6-8   | force the tool exerts on the tissue           | 0.1 N x E / 5 kPa         |
    | 9     | relative volume change (V - V0) / V0          | %                        |
    | 10    | maximum spring strain abs(L - L0) / L0        | %                        |
    | 11-13 | tumour position                               | cm from block centre     |
    | 14-16 | goal position                                 | cm from block centre     |
    | 17-19 | goal - tumour                                 | cm                       |
    | 20    | distance tumour-goal                          | cm                       |
    | 21-23 | tumour displacement from its start            | cm                       |

    ``"deformation"`` appends the displacement of every surface node (cm, node order of
    ``mesh.surface_nodes()``); ``"dict"`` gives the same features as a ``Dict`` of ``Box`` es keyed
    by name (``tool_position``, ..., ``surface_displacement``).

    ``"goal"`` (goal-conditioned, for hindsight experience replay): a ``Dict`` of ``observation``
    (the 24 values above, float32), ``achieved_goal`` (the tumour position, indices 11-13) and
    ``desired_goal`` (the goal position, indices 14-16), both ``Box(-100, 100, (3,), float64)`` in
    cm from the block centre. ``env.compute_reward(achieved_goal, desired_goal, info)`` (on
    ``gym.make``'s env too: its ``TimeLimit``, ``OrderEnforcing`` and ``PassiveEnvChecker`` forward
    it, ``tissue_env.goal``, so SB3's ``check_env`` and ``HerReplayBuffer`` take that env as it is;
    a wrapper of your own does not: use ``env.get_wrapper_attr("compute_reward")`` there)
    recomputes the reward of a step for any goals, vectorised over a batch of goals (..., 3) with
    one info or one per goal (a list or an object array, as SB3's ``HerReplayBuffer`` passes them
    with ``copy_info_dict=True``): the distance and success terms from the goals, the volume,
    strain and instability terms from the info's ``relative_volume_change``, ``max_strain`` and
    ``unstable``. For a step's own goals it equals the step's reward bit for bit (the goal env
    measures the tumour-goal distance on the observed goals, within 1e-17 m of the other
    observation types'). The vector env has the same observation space and ``compute_reward``.

    ## Rewards

    ``r = reward_distance + reward_success + reward_volume + reward_strain (+ reward_instability)``:

    - ``reward_distance = -||tumour - goal|| / 1 cm``
    - ``reward_success = success_bonus`` (default 5) on the step the tumour is within
      ``success_distance`` (default 2 mm) of the goal, else 0
    - ``reward_volume = -volume_weight * |(V - V0) / V0|`` (default weight 1)
    - ``reward_strain = -strain_weight * max(0, max spring strain - strain_threshold)``
      (defaults 1 and 0.3: a damage proxy)
    - ``reward_instability = -instability_penalty`` (default 10) on a diverging step, else 0.

    Every term is also in ``info`` as ``reward_<name>``.

    ## Starting State

    The block at static equilibrium under gravity with the tool holding the patch at rest. The
    tumour's rest position is uniform in ``tumor_region`` (fractions of the block, default the
    central half along every axis); the goal is the tumour's static equilibrium for a tool
    displacement in a random direction, of ``goal_scale_range`` (default 0.5-1) times
    ``goal_displacement`` (default 12 mm) along its largest axis (clipped to the workspace),
    scaled up (within the workspace) until the goal is at least ``goal_min_distance`` (default
    2 ``success_distance``, 4 mm) away.

    ## Difficulty

    ``difficulty="easy" | "default" | "hard"`` sets ``goal_displacement``, ``goal_min_distance``,
    ``success_distance`` and ``terminate_on_success`` from the table ``TumorPositioningEnv.DIFFICULTY``
    (a keyword passed explicitly overrides its level's value): easy, nearer goals and a looser
    tolerance; hard, goals farther away (a longer tool displacement, and scaled up to a longer least
    distance), a tolerance of 1 mm and no termination at a success, so the tumour must be brought
    to the goal and held there until the episode ends (``info["is_success"]`` at its last step). The
    scripted controller's and random actions' success rates and steps to success at each level
    are on the training page of the documentation (``benchmarks/success_rates.py --difficulty``), as
    is SAC's training result at the hard level (``python -m training.benchmark --variant hard``).

    ## Episode End

    Terminated when the tumour is within ``success_distance`` of the goal (``info["is_success"]``;
    unless ``terminate_on_success=False``, the hard level's) or when the simulation diverges (``info["unstable"] = True`` with ``info["unstable_reason"]``).
    Truncated after 50 steps (registered ``max_episode_steps``).

    ## Info

    Every step's and reset's ``info`` has the entries every task has (``relative_volume_change``, ``unstable``,
    ``unstable_reason``, ``is_success``, ``out_of_range``, ``max_strain``, one ``reward_<term>`` per reward
    term, the episode's material and ``size``), the tool's forces: ``reaction_force`` ((3,) N, the force the
    tool exerts on the tissue) and ``tool_forces`` ((1, 3) float, N: the force the tissue exerts on the one
    tool, its opposite), and ``grasped`` ((1,) bool: always True, the patch is held by imposed displacements
    without a force limit), and the task's own: ``distance`` (m, tumour to goal), ``tumor_position`` and
    ``goal`` (m), ``tool_size`` (m).

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/TumorPositioning-v0", young_modulus=5e3, poisson_ratio=0.45,
                   max_step=0.002, observation_type="state", render_mode="rgb_array")
    ```

    Vectorised: ``gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=16,
    vectorization_mode="vector_entry_point")`` steps the copies together in one batched physics
    step (``TumorPositioningVectorEnv``, same keywords, spaces, rewards and infos; ``tissue_env.vector``).

    Task keywords: ``tool_size`` (m, the side of the grasped square), ``workspace`` (m, per axis), ``goal_displacement`` (m), ``goal_scale_range``
    ((low, high) > 0: the range of the goal's tool displacement, in units of
    ``goal_displacement``), ``tumor_region`` (``((x0, y0, z0), (x1, y1, z1))`` fractions of the
    block: the range of the tumour position), ``success_distance`` (m), ``goal_min_distance`` (m),
    ``success_bonus``, ``difficulty``; shared keywords are listed in ``tissue_env.base.TissueEnv``
    (``young_modulus``, ``poisson_ratio``, ``density``, ``shape``, ``size``, ``integrator``, ``dt``,
    ``substeps``, ``young_modulus_range``, ``poisson_ratio_range``, ``density_range``,
    ``terminate_on_success``, ``render_mode``, ...).

    Domain randomisation (per episode, ``randomised_parameters``): ``young_modulus_range``,
    ``poisson_ratio_range``, ``density_range`` (the material; ``info["young_modulus"]``,
    ``["poisson_ratio"]``, ``["density"]``), ``size_range`` (the block's extent, each axis in m: the
    block scaled about its attached corner, the tumour at the same fraction of it; ``info["size"]``)
    and ``tool_size_range`` (the grasped square's side, m: the grasped nodes chosen anew on the
    episode's block; ``info["tool_size"]``; vector observations only, since the camera colours the
    patch of ``tool_size``), besides ``tumor_region`` (the tumour's rest position) and
    ``goal_scale_range`` (the goal's tool displacement). ``observe_parameters=True`` appends the drawn
    parameters, each normalised to [-1, 1] over its range, to the observation (see the
    documentation's "Domain randomisation" section).

    ## Version History

    - v0: the version of the first release (its changes before it: CHANGELOG.md).
    """

    worlds_class = TumorPositioningWorlds
    #: The model closer to neo-Hookean FEM on this scene (``benchmarks/env_models.py``: tool force,
    #: tumour displacement and volume change against a 14^3 FEM of the grasped patch).
    default_model = "baudet-hyperelastic"
    default_shape = (7, 7, 7)
    default_size = (0.05, 0.05, 0.05)
    default_dt = 0.04
    default_solver_tolerance = 1e-2
    reward_names = ("distance", "success", "volume", "strain")
    #: The default camera (``TissueEnv.default_camera``): above the grasped top, in front.
    camera_target = (0.5, 0.6, 0.5)
    goal_features = ("tumor_position", "goal_position")
    randomised_parameters = dict(TissueEnv.randomised_parameters, tool_size="tool_size_range")
    episode_keywords = ("tumor_region", "goal_scale_range")
    summary = "move a grasped top patch so that a tumour inside a {default_size:cm} block reaches a reachable goal"
    success_summary = "tumour within {success_distance:mm} of the goal"

    #: The difficulty levels' keywords (``difficulty``; keywords passed explicitly override them):
    #: the goal's tool displacement (m) and the least tumour-goal distance a goal is scaled up to
    #: (m; None: 2 success_distance), which set the goal distance, the success tolerance (m) and
    #: whether a success ends the episode (hard: the tumour must be held at the goal to the end).
    DIFFICULTY = dict(
        easy=dict(goal_displacement=0.008, goal_min_distance=0.004, success_distance=0.003, terminate_on_success=True),
        default=dict(goal_displacement=0.012, goal_min_distance=None, success_distance=0.002,
                     terminate_on_success=True),
        hard=dict(goal_displacement=0.016, goal_min_distance=0.008, success_distance=0.001,
                  terminate_on_success=False),
    )

    def __init__(self, *, tool_size=0.025, workspace=0.02, goal_displacement=None, goal_scale_range=(0.5, 1.0),
                 tumor_region=((0.25, 0.25, 0.25), (0.75, 0.75, 0.75)),
                 success_distance=None, success_bonus=5.0, goal_min_distance=None, difficulty="default",
                 tool_size_range=None, **kwargs):
        settings = difficulty_settings(self.DIFFICULTY, difficulty, dict(
            goal_displacement=goal_displacement, success_distance=success_distance, goal_min_distance=goal_min_distance))
        goal_displacement, success_distance = settings["goal_displacement"], settings["success_distance"]
        self.tool_size = positive_scalar("tool_size", tool_size, "m")
        self.tool_size_range = check_range("tool_size_range", tool_size_range, lambda n, v: positive_scalar(n, v, "m"))
        self.episode_tool_size = self.tool_size
        self.workspace = check_vector("workspace", workspace)
        self.goal_displacement = check_vector("goal_displacement", goal_displacement)
        if goal_scale_range is None:
            raise ValueError("goal_scale_range must be a (low, high) pair of positive numbers, got None")
        self.goal_scale_range = check_range("goal_scale_range", goal_scale_range, positive_scalar)
        self.tumor_region = check_region("tumor_region", tumor_region, "xyz")
        self.success_distance = positive_scalar("success_distance", success_distance, "m")
        goal_min_distance = settings["goal_min_distance"]
        self.goal_min_distance = (2.0 * self.success_distance if goal_min_distance is None
                                  else positive_scalar("goal_min_distance", goal_min_distance, "m"))
        if self.goal_min_distance < self.success_distance:
            raise ValueError(f"goal_min_distance must be at least success_distance ({self.success_distance:g} m): a "
                             f"nearer goal would be a success at reset, got {goal_min_distance!r}")
        self.success_bonus = nonnegative_scalar("success_bonus", success_bonus)
        self._goal_factors = FactorCache(size=2)  # start tangent LUs of the goal solves, per model
        if self.tool_size_range is not None and kwargs.get("observation_type") in VISUAL_TYPES:
            raise ValueError(f"tool_size_range draws the grasped patch per episode, and the camera's images colour "
                             f"the patch of tool_size (shared by the worlds): observation_type="
                             f"{kwargs['observation_type']!r} is not supported with it; use a vector observation")
        super().__init__(difficulty=difficulty, **kwargs)

    # -- scene ---------------------------------------------------------------------------------------
    def _setup_scene(self):
        nodes = self.mesh.nodes
        self.fixed_nodes = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))
        self.tool_nodes = self._grasped_patch(nodes, self.size, self.tool_size, "tool_size")
        if self.tool_size_range is not None:  # its smallest patch grasps a node too
            self._grasped_patch(nodes, self.size, self.tool_size_range[0], "tool_size_range's low end")
        self._place_scene(nodes)
        self.workspace_low, self.workspace_high = -self.workspace, self.workspace

    def _grasped_patch(self, nodes, size, tool_size, name):
        """The grasped square on the block of rest ``nodes`` (n, 3) and extent ``size`` (3,) m: the top
        nodes within ``tool_size`` / 2 m of the top face's centre along x and z (a physical size, so a
        finer mesh grasps the same patch with more nodes); ValueError naming ``name`` when it grasps
        none."""
        top = np.flatnonzero(np.isclose(nodes[:, 1], size[1]))
        centre = 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))
        patch = square_patch(nodes, top, centre, tool_size, 1e-9 * size[[0, 2]])
        if len(patch) < 1:
            spacing = size / np.asarray(self.shape)
            raise ValueError(f"{name} = {tool_size} m grasps no top node of the {self.shape} mesh; "
                             f"use at least the element width {min(spacing[0], spacing[2]):.4g} m")
        return patch

    shared_attributes = ("_goal_factors",)
    #: Whether a goal's tool displacement is scaled up before its solve by the linear response
    #: (``_draw_goal``): most draws that fell short of the minimum goal distance (44% of seeds 1-100)
    #: were solved twice, the second time from a new factorisation; with it 8% are
    #: (``benchmarks/reset_speed.py``).
    linear_goal_scaling = True

    @property
    def goal_factors(self) -> FactorCache:
        """The ``FactorCache`` of the goal solves' start tangent LUs (shared by the copies of a vector
        env); its ``hits`` and ``misses`` count the factorisations it saved and made."""
        return self._goal_factors

    def share_caches(self, other):
        super().share_caches(other)
        self._goal_factors = other._goal_factors

    def _task_feature_sizes(self):
        return dict(tumor_position=3, goal_position=3, goal_error=3, goal_distance=1, tumor_displacement=3)

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        if self.tool_size_range is not None:  # the grasped patch of this episode, on its block
            self.episode_tool_size = float(self.np_random.uniform(*self.tool_size_range))
            self.tool_nodes = self._grasped_patch(self.episode_mesh.nodes, self.episode_size, self.episode_tool_size,
                                                  "the drawn tool size")
            self._place_scene(self.episode_mesh.nodes)
        # the tumour: a material point at a fraction of the block (the same at any size_range draw)
        low, high = self.tumor_region * self.size
        rest = self.np_random.uniform(low, high)
        cell = np.minimum((rest // self.spacing).astype(int), np.asarray(self.shape) - 1)
        element = int(cell[0] + self.shape[0] * (cell[1] + self.shape[1] * cell[2]))
        self.tumor_nodes = self.mesh.elements[element]
        self.tumor_weights = trilinear_weights(rest / self.spacing - cell)
        self._pending_goal = True

    def _start_hook(self):
        start = self.state.positions
        self.tumor_start = self.tumor_weights @ start[self.tumor_nodes]
        # Reachable goal: the tumour's equilibrium for a random admissible tool displacement.
        # A random direction and a length of 0.5-1 goal_displacement (along its largest axis); when
        # the tumour would move less than the minimum goal distance, the displacement is scaled up
        # (the response is nearly linear): before the solve by the linear response at the start
        # (``_tumor_response``), and where the equilibrium still falls short, solved again from it. A draw
        # whose goal stays within success_distance of the start (no solve converged) would be a
        # success at reset: another direction is drawn, GOAL_ATTEMPTS in all, then ValueError.
        for _ in range(GOAL_ATTEMPTS):
            goal, displacement = self._draw_goal(start)
            if self._start_distance(goal) >= self.success_distance:
                break
        else:
            raise ValueError(self._no_goal_message())
        self.goal = goal
        self.goal_tool_displacement = displacement
        self.measures = None

    def _no_goal_message(self):
        """The reset's ValueError when no goal draw converged: a tissue too soft for its weight (or
        too heavy for its stiffness) to be moved by the tool, with the stiffness, density and goal
        displacement that would (GOAL_SAG: the sag under gravity, rho g L^2 / E, up to which goals
        are reached)."""
        modulus, density = self.episode_young_modulus, self.episode_density
        length = float(np.max(self.episode_size))
        ratio = density * self.gravity * length / modulus  # sag / L
        heavy = density > TISSUE_DENSITY_MAX
        cause = (f"too heavy for its stiffness (density {density:g} kg/m^3; soft tissue is about 1000-1100)" if heavy
                 else f"too soft for its weight (young_modulus {modulus:g} Pa)")
        text = (f"no reachable goal: {GOAL_ATTEMPTS} tool displacements found no static equilibrium that moves the "
                f"tumour {self.success_distance:g} m (young_modulus={modulus:g} Pa, poisson_ratio="
                f"{self.episode_poisson_ratio:g}, density={density:g} kg/m^3, goal_displacement="
                f"{np.round(self.goal_displacement, 6).tolist()} m): ")
        if ratio <= GOAL_SAG:  # not the weight: the tool's displacement itself
            return text + (f"the tool's displacement has no static equilibrium though the tissue carries its weight "
                           f"(its sag is {ratio:.2g} of the block's side); use a smaller goal_displacement or workspace")
        return text + (f"the tissue is {cause} to be moved by the tool, its sag under gravity (rho g L^2 / E) is "
                       f"{ratio:.2g} times the block's largest side, and goals are reached up to about {GOAL_SAG:g}. "
                       f"Use a stiffer material (young_modulus {density * self.gravity * length / GOAL_SAG:.2g} Pa "
                       f"or more), a lighter one (density {GOAL_SAG * modulus / (self.gravity * length):.2g} kg/m^3 "
                       "or less) or a smaller goal_displacement")

    def _start_distance(self, goal):
        """The task's error (m) at the episode's start for the drawn ``goal``: the tumour-goal
        distance (a goal nearer than ``success_distance`` would be a success at reset)."""
        return np.linalg.norm(goal - self.tumor_start)

    def _draw_goal(self, start, minimum=None):
        """(goal (3,) m, tool displacement (3,) m) of one random direction from ``start`` (n, 3) m:
        the tumour at the last converged equilibrium (the start where none converged), scaled up
        to at least ``minimum`` m from the tumour's start (None: ``goal_min_distance``)."""
        direction = self.np_random.normal(size=3)
        direction /= max(np.abs(direction).max(), 1e-12)
        displacement = self.np_random.uniform(*self.goal_scale_range) * direction * self.goal_displacement
        displacement = np.clip(displacement, self.workspace_low, self.workspace_high)
        positions = start
        minimum = self.goal_min_distance if minimum is None else minimum
        # scaled up before the solve where the linear response says the tumour would move too little
        # (the same rule as the retry below, which stays for the nonlinear response)
        linear = np.linalg.norm(displacement @ self._tumor_response(start)) if self.linear_goal_scaling else np.inf
        if linear < minimum:
            displacement = np.clip(displacement * 1.2 * minimum / max(linear, 1e-6), self.workspace_low,
                                   self.workspace_high)
        reached = np.zeros(3)  # the tool displacement of the last converged solve
        for _ in range(3):
            control = self.base_control.copy().impose(self.tool_nodes, self.tool_rest + displacement)
            result = solve_static(self.model, control, initial=positions, tolerance=1e-5,
                                  **(GOAL_SOLVER if positions is start else GOAL_RETRY_SOLVER),
                                  cache=self._goal_factors if positions is start else None)
            if not result.converged:
                break
            positions, reached = result.positions, displacement
            goal = self.tumor_weights @ positions[self.tumor_nodes]
            moved = np.linalg.norm(goal - self.tumor_start)
            if moved >= minimum:
                break
            bigger = np.clip(displacement * 1.2 * minimum / max(moved, 1e-6), self.workspace_low, self.workspace_high)
            if np.allclose(bigger, displacement):
                break
            displacement = bigger
        if not result.converged:  # keep the last converged goal (or the start) rather than a bad one
            goal = self.tumor_weights @ positions[self.tumor_nodes]
            displacement = reached
        return goal, displacement

    def _tumor_response(self, start):
        """(3, 3) the tumour's displacement (rows: per m of tool displacement along x, y, z; m/m) by
        the linear response at ``start`` (n, 3) m, the episode's start: the first goal solve's
        predictor, from the same cached factorisation. The response of every node to the tool's
        three unit translations is computed once per model and grasped patch (``Model.derived``)."""
        model, nodes = self.model, self.tool_nodes

        def build():
            control = self.base_control.copy().impose(nodes, self.tool_rest)
            free = np.flatnonzero(~control.fixed.ravel())
            stiffness, factor = self._goal_factors.factorise(model, start, free, 1e-10)
            translations = np.zeros((3, model.n_nodes * 3))  # each unit translation of the grasped patch
            for axis in range(3):
                translations[axis, 3 * nodes + axis] = 1.0
            rhs = -(stiffness[free] @ translations.T)
            response = translations.copy()  # imposed on the patch; the free dofs' equilibrium solved below
            response[:, free] = [factor.solve(np.ascontiguousarray(column)) for column in rhs.T]
            return response.reshape(3, model.n_nodes, 3)

        key = ("tumor_goal_response", nodes.tobytes(), start.tobytes())
        fields = model.derived.peek(key)
        if fields is None:  # built outside the cache's lock (the factorisation reads the model's cache)
            fields = model.derived.put(key, build())
        return fields[:, self.tumor_nodes].transpose(0, 2, 1) @ self.tumor_weights

    def scripted_action(self, gain=1.5):
        """Proportional control on the observed error: tool increment = gain * (goal - tumour).

        The tool position integrates the error, so it converges to the tool displacement that
        produced the goal (the tumour moves less than the tool: gain > 1 speeds this up).
        """
        self._require_reset("scripted_action()")
        error = self.goal - self.measures["tumor"]
        return np.clip(gain * error / self.max_step, -1.0, 1.0).astype(np.float32)

    def _markers(self):
        positions = self.state.positions
        return dict(tool=positions[self.tool_nodes].mean(axis=0), tumor=self.measures["tumor"], goal=self.goal)


class TumorPositioningVectorEnv(TissueVectorEnv):
    """N copies of TumorPositioning-v0 stepped together (``tissue_env.vector``): built by
    ``gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    Same keywords, spaces, rewards and infos as the single env (see ``TumorPositioningEnv``)."""

    env_class = TumorPositioningEnv

