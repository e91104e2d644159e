"""BimanualExposure-v0: two graspers retract the two flaps of a cleft to expose a target under it."""

from __future__ import annotations

import numpy as np

from sim_core import HexMesh

from .base import TissueEnv, check_range, check_work, difficulty_settings, nonnegative_scalar, positive_scalar
from .retraction import RetractionEnv, RetractionWorlds, flap_constraint, flap_footprint, grasp_setting
from .vector import TissueVectorEnv
from .worlds import TaskWorlds

#: A grasp command opens the jaws below -GRASP_COMMAND_DEAD and closes them above +GRASP_COMMAND_DEAD;
#: in between the jaws stay as they are (a policy holds a grasp without having to hit one value).
GRASP_COMMAND_DEAD = 0.5
#: The target's grid on the floor: points along x (across the cleft) and along z (its middle half).
TARGET_GRID = (6, 3)


def finite_length(name, value) -> float:
    """``value`` as a finite float (a signed length in m); ValueError naming ``name`` otherwise."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if not number or not np.isfinite(value):
        raise ValueError(f"{name} must hold finite numbers in m, got {value!r}")
    return float(value)


class BimanualExposureWorlds(RetractionWorlds):
    """BimanualExposure's step on N worlds (``tissue_env.worlds``): Retraction's floor contact and
    exposure measure, with two graspers, each holding the free edge of its flap."""

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count, tools = self.task, self.num_envs, self.task.tool_count
        n = env.mesh.n_nodes
        #: (T, n) bool the nodes each grasper may close on: the free edge of its flap
        self.candidates = env.edge_nodes
        #: (N, T, n) bool the nodes each world's graspers hold; (N, T, n, 3) m their anchors (position
        #: at closing minus the jaw's offset then: the jaw's offset since is the grasp's translation)
        self.held = np.zeros((count, tools, n), dtype=bool)
        self.grasp_anchors = np.zeros((count, tools, n, 3))
        self.jaw_rest = np.zeros((count, 3 * tools))
        self.held_count = np.zeros((count, tools), dtype=int)
        self.grasp_size = np.zeros((count, tools), dtype=int)
        self.target_points = np.zeros((count, TARGET_GRID[0] * TARGET_GRID[1], 2))
        for name in ("grip_weight", "grip_margin"):
            setattr(self, name, getattr(env, name))

    def _load_task(self, index, env):
        self._base_target[index] = env.base_control.target
        rest = env.episode_mesh.nodes
        self.jaw_rest[index] = env.jaw_rest
        self.held[index] = env.held
        self.grasp_anchors[index] = np.where(env.held[..., None], rest[None], 0.0)
        self.held_count[index] = self.grasp_size[index] = env.held.sum(axis=-1)
        self._load_floor_scene(index, env)
        self._load_grasp_limit(index, env)

    def _write_back_task(self, index, env):
        env.contact = self.contact[index].copy()
        env.held = self.held[index].copy()

    def step(self, actions, active):
        return TaskWorlds.step(self, actions, active)  # no grasp point to choose: the commands close the jaws

    def _grasp_commands(self, commands, active):
        """Close an open grasper whose command is above +GRASP_COMMAND_DEAD on the free-edge nodes of
        its flap within its radius of the jaw (where the jaw is now: ``Grasper.close``), open a
        closed one whose command is below -GRASP_COMMAND_DEAD; the positions are the worlds' current
        ones (the state the jaw meets). Opening is a release, not a slip (``grasp_slipped`` stays 0)."""
        holding = self.held.any(axis=-1)
        offsets = self.tool_offset.reshape(self.num_envs, -1, 3)
        jaws = self.jaw_rest.reshape(offsets.shape) + offsets
        for tool in range(self.held.shape[1]):  # two tools: a loop over tools, each vectorised over worlds
            closing = active & ~holding[:, tool] & (commands[:, tool] > GRASP_COMMAND_DEAD)
            opening = active & holding[:, tool] & (commands[:, tool] < -GRASP_COMMAND_DEAD)
            if closing.any():
                held = self.grasper.close(self.positions[closing], jaws[closing, tool], self.candidates[tool])[0]
                self.held[closing, tool] = held
                self.grasp_anchors[closing, tool] = np.where(
                    held[..., None], self.positions[closing] - offsets[closing, tool, None, :], 0.0)
                self.held_count[closing, tool] = self.grasp_size[closing, tool] = held.sum(axis=-1)
            if opening.any():
                self.held[opening, tool] = False
                self.held_count[opening, tool] = 0

    def _tool_position(self, positions):
        return self.jaw_rest + self.tool_offset  # the jaws, whether they hold tissue or not

    def _floor_nodes(self):
        return self._floor_candidates[None] & ~self.held.any(axis=1)

    def _constrain_tool(self, offset):
        """A tool that holds tissue moves its held patch as Retraction's grasped edge may move
        (``BimanualExposureEnv.constrain_tool`` on the patch's mean displacement from the edge's rest
        middle: the jaw's offset for a grasp closed on the resting edge): a flat push back, or one
        past the lift, buckles the one-element-thick flap into inverted elements. An open tool moves
        anywhere in its workspace."""
        tools = offset.reshape(self.held.shape[:2] + (3,))
        count = self.held.sum(axis=-1)[..., None]
        # the held nodes' mean position at closing, less the jaw's offset then: + the offset, their mean target
        anchor = np.einsum("wtn,wtni->wti", self.held, self.grasp_anchors) / np.maximum(count, 1)
        patch = anchor + tools - self.jaw_rest.reshape(tools.shape)
        moved = self.task.constrain_tool(patch.reshape(offset.shape)).reshape(tools.shape)
        return np.where(count > 0, tools + moved - patch, tools).reshape(offset.shape)

    def _grasp_control(self):
        fixed, target = self._base_fixed, self._base_target
        offsets = self.tool_offset.reshape(self.num_envs, -1, 3)
        for tool in range(self.held.shape[1]):
            fixed, target = self.grasper.control(fixed, target, self.held[:, tool], self.grasp_anchors[:, tool],
                                                 offsets[:, tool])
        return fixed, target, np.repeat(self.held.any(axis=1)[..., None], 3, axis=2)

    def _measure(self, tool_mask):
        """The measurements, and each grasp judged at them (``Grasper.slip``, the graspers side by
        side); each tool's force is its grasp's on the nodes it still holds: (N, 3 T) N."""
        measures = TaskWorlds._measure(self, tool_mask)
        forces = self._node_forces = measures["forces"]
        self.held = self.grasper.slip(forces[:, None], self.held)
        measures["reaction_force"] = self.grasper.force(forces[:, None], self.held).reshape(self.num_envs, -1)
        return measures

    def _tensions(self, measures):
        """(N, T) the magnitude of each tool's force, N."""
        return np.linalg.norm(measures["reaction_force"].reshape(self.num_envs, -1, 3), axis=-1)

    def _task_features(self, measures):
        return dict(
            target_range=(self.target_x - self.centre[0]) / self.length_scale,
            exposed_fraction=measures["exposed_fraction"][:, None],
            tension=self._tensions(measures) / self._force_limits()[:, None],
            grasped=measures["grasped_nodes"] / np.maximum(self.grasp_size, 1),
        )

    def _task_info(self, measures):
        return dict(exposed_fraction=measures["exposed_fraction"].copy(), tension=self._tensions(measures),
                    grasped_nodes=measures["grasped_nodes"].copy(), grasp_lost=measures["grasped_nodes"] == 0,
                    grasp_slipped=measures["grasp_slipped"].copy())

    def _is_success(self, measures):
        return ((measures["exposed_fraction"] >= self.success_exposure)
                & np.all(self._tensions(measures) <= self._force_limits()[:, None], axis=1))

    def _reward_terms(self, measures):
        tension, limit = self._tensions(measures), self._force_limits()[:, None]
        near_slip = np.maximum(0.0, tension / self.grasper.force_limit[:, None] - self.grip_margin) / (1.0 - self.grip_margin)
        terms = dict(
            exposure=measures["exposed_fraction"] - 1.0,
            tension=-self.tension_weight * np.sum(np.maximum(0.0, tension - limit) / limit, axis=1),
            grip=0.0 - self.grip_weight * near_slip.sum(axis=1),
            success=np.where(self._is_success(measures), self.success_bonus, 0.0),
            grasp=0.0 - self.grasp_weight * measures["grasp_slipped"].sum(axis=1),  # 0.0, not -0.0, while held
        )
        terms.update(self._damage_terms(measures))
        return terms


class BimanualExposureEnv(RetractionEnv):
    """
    ## Description

    Two flaps of tissue, the two sides of a cleft (an incision held open, or the two leaves of the
    peritoneum over a structure), lie on a rigid, frictionless floor (y = 0), each attached to the
    body along its outer edge (x = 0 and x = L): a 12.5 x 0.8 x 3 cm sheet of 25 x 2 x 6 hexahedra
    of 5 x 4 x 5 mm whose middle column is missing, so two flaps of 6 cm (Retraction's flap) face each
    other across a 5 mm cleft (the hyperelastic mass-spring model ``baudet-hyperelastic``, as in Retraction, on the same
    elements; gravity on). A target strip on the floor, 2 cm across the cleft and the middle half
    of the width along it, is exposed only where neither flap covers it (at the start only the cleft
    shows: a third of its points). Two graspers, one per flap, hold their flap's free edge
    (``sim_core.solvers.grasp``: the edge's nodes within ``grasp_radius`` of the jaw, held at their
    offsets from it; with ``grasp_commands=True`` they start open and the policy closes them), lift
    it and fold it back over its attached edge, as an assistant's two graspers hold the sides of an
    incision apart. The floor contact is Retraction's active set (a node the tissue pulls up is
    released, a node below the floor is put back on it).

    Each grasp holds up to ``grasp_force_limit``: by default (``"auto"``) Retraction's instruments,
    a 5 N grasper on tissue up to 100 kPa (``GRASP_SLIP_FORCE``: Heijnsdijk et al. 2004) and a
    retractor that does not slip on stiffer tissue (``RETRACTOR_MODULUS``). Past the limit, the
    held nodes slip out of the jaws one after the other, the most loaded first (``Grasper.slip``),
    so a tool never reports more than the limit while it holds. A lost
    grasp does not end the episode; with ``grasp_commands=True`` the grasper may close again where
    its jaw is.

    Physics: one implicit Euler step of ``dt`` = 20 ms per env step, the floor contact in it.
    Measured (1200 random steps, seed 0): no divergence in 16 random episodes at the defaults; with
    ``grasp_commands=True`` random opening and closing regrasps falling flaps in partial bites, and
    about half of the random episodes end ``unstable`` (inverted elements: terminated, never a crash;
    a 3 cm flap diverged in 6 of 20 random episodes even without commands, so the flaps are 6 cm).

    ## Action Space

    ``Box(-1, 1, (6,), float32)`` (``Box(-1, 1, (8,))`` with ``grasp_commands=True``): per tool
    its displacement increment (x, y up, z) scaled by ``max_step`` (default 5 mm), first the left
    tool's (the flap attached at x = 0), then the right one's, then (``grasp_commands=True``) one
    grasp command per tool.

    | Num | Action                                  | Min | Max | Unit         |
    |-----|-----------------------------------------|-----|-----|--------------|
    | 0   | left tool increment along x             | -1  | 1   | max_step (m) |
    | 1   | left tool increment along y (up)        | -1  | 1   | max_step (m) |
    | 2   | left tool increment along z             | -1  | 1   | max_step (m) |
    | 3   | right tool increment along x            | -1  | 1   | max_step (m) |
    | 4   | right tool increment along y (up)       | -1  | 1   | max_step (m) |
    | 5   | right tool increment along z            | -1  | 1   | max_step (m) |
    | 6   | left grasp command (``grasp_commands``) | -1  | 1   | open < -0.5 < keep < 0.5 < close |
    | 7   | right grasp command (``grasp_commands``)| -1  | 1   | open < -0.5 < keep < 0.5 < close |

    A grasp command acts before the move of its step: closing, the jaws take the free-edge nodes of
    their flap within ``grasp_radius`` of the jaw (none if the jaw is away from the edge); opening
    releases them. Each tool's offset stays in its workspace (the left one x from -6 to +0.5 cm,
    the right one mirrored, y from 0 to 6 cm, z +-1 cm) and, while it holds tissue, its held patch
    moves as Retraction's grasped edge may (``retraction.flap_constraint``): back over its attached
    edge only as far as it is lifted, sideways only as far as it is lifted.

    ## Observation Space

    ``observation_type="state"``: ``Box(-100, 100, (27,), float32)`` (the maximum strain within
    +-1000).

    | Index | Observation                                           | Unit (normalised)     |
    |-------|-------------------------------------------------------|-----------------------|
    | 0-5   | jaw positions (left x, y, z, right x, y, z)           | cm from block centre  |
    | 6-11  | tool displacements from their start (same order)      | cm                    |
    | 12-17 | force each grasp exerts on the tissue (same order)    | 0.1 N x E / 5 kPa      |
    | 18    | relative volume change (V - V0) / V0                  | %                     |
    | 19    | maximum spring strain abs(L - L0) / L0                | %                     |
    | 20-21 | target strip x range (start, end)                     | cm from block centre  |
    | 22    | exposed fraction of the target                        | 0-1                   |
    | 23-24 | each tool's tension: force magnitude / force_limit    | 1                     |
    | 25-26 | each grasp: nodes held / nodes its jaws closed on     | 0-1                   |

    ``"deformation"`` appends the surface-node displacements (cm); ``"dict"`` gives the features as
    a ``Dict`` keyed by name; ``"rgb"``, ``"depth"``, ``"rgbd"``, ``"point_cloud"``: the camera of
    Retraction (in front and above; the floor with the target strip coloured). No ``"goal"``
    observation (as Retraction: the desired outcome is the same every episode).

    ## Rewards

    ``r = reward_exposure + reward_tension + reward_grip + reward_success + reward_grasp +
    reward_volume + reward_strain (+ reward_instability)``:

    - ``reward_exposure = exposed fraction - 1`` (the 6 x 3 grid of target points not under either
      flap seen from above; never positive, so finishing is worth more than lingering)
    - ``reward_tension = -tension_weight * sum over tools of max(0, |F| - force_limit) / force_limit``
      (defaults 1 and 0.5 N at E = 5 kPa, scaled with the episode's E: tissue tension)
    - ``reward_grip = -grip_weight * sum over tools of max(0, |F| / grasp_force_limit - grip_margin)
      / (1 - grip_margin)`` (defaults 1 and 0.8: a grasp pulled near its slip limit; 0 with a retractor)
    - ``reward_success = success_bonus`` (default 5) on success
    - ``reward_grasp = -grasp_weight * sum over tools of the share of its nodes that slipped out in
      the step`` (default 5: losing a whole grasp costs what a success gains)
    - ``reward_volume``, ``reward_strain`` (tissue damage) as in every task, ``reward_instability``
      on divergence.

    ## Starting State

    Both flaps flat on the floor at rest, both graspers closed on their flap's free edge, the jaw at
    its middle (``grasp_commands=True``: open there). The target strip is centred
    on the cleft, shifted along x by a draw from ``target_shift_range`` (default +-2.5 mm).

    ## Episode End

    Terminated on success (exposed fraction >= ``success_exposure`` = 0.95, i.e. every target point,
    with each tool's |F| <= ``force_limit``) or on divergence (``info["unstable"]``). Truncated after
    80 steps.

    ## Info

    The entries every task has (``relative_volume_change``, ``unstable``, ``unstable_reason``,
    ``is_success``, ``out_of_range``, ``max_strain``, a ``reward_<term>`` per term, the episode's
    material and ``size``), ``reaction_force`` ((6,) N, the force each grasp exerts on the tissue,
    left then right), ``tool_forces`` ((2, 3) N, the force the tissue exerts on each grasper; 0 when
    it holds nothing), ``grasped`` ((2,) bool), and ``exposed_fraction``, ``tension`` ((2,) N),
    ``grasped_nodes`` ((2,)), ``grasp_slipped`` ((2,), the share of each grasp's nodes that slipped
    out in the step), ``grasp_lost`` ((2,) bool: holds nothing).

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/BimanualExposure-v0", grasp_force_limit=5.0, grasp_commands=False)
    ```

    Vectorised: ``gym.make_vec("tissue_env/BimanualExposure-v0", num_envs=16,
    vectorization_mode="vector_entry_point")`` (``BimanualExposureVectorEnv``).

    Task keywords: ``target_width`` (m, the strip's extent across the cleft, default 2 cm),
    ``target_shift_range`` (m), ``force_limit`` (N at E = 5 kPa, scaled by E / 5 kPa),
    ``tension_weight``, ``grip_weight``, ``grip_margin``, ``success_exposure``, ``success_bonus``,
    ``grasp_force_limit`` (N, not scaled: the instrument's; default "auto", Retraction's choice by
    E; "grasper": 5 N, Heijnsdijk et al., Surg Endosc 18:974-979, 2004; "retractor" or ``np.inf``:
    never slips), ``grasp_weight``, ``grasp_commands`` (default False: both grasps closed on the
    edges from the start; True: they start open and the action ends with a grasp
    command per tool),
    ``difficulty``; shape ``(nx, ny, nz)`` with an odd nx >= 5 (the middle column is the cleft);
    shared keywords in ``tissue_env.base.TissueEnv``. Domain randomisation: ``young_modulus_range``,
    ``poisson_ratio_range``, ``density_range`` (no ``size_range``: the cleft is a fixed mesh).

    ## Version History

    - v0: first version.
    """

    worlds_class = BimanualExposureWorlds
    tool_count = 2
    default_shape = (25, 2, 6)
    default_size = (0.125, 0.008, 0.03)
    min_shape = (5, 1, 1)
    reward_names = ("exposure", "tension", "grip", "success", "grasp", "volume", "strain")
    randomised_parameters = dict(young_modulus="young_modulus_range", poisson_ratio="poisson_ratio_range",
                                 density="density_range")
    episode_keywords = ("target_shift_range",)
    summary = ("two graspers hold the free edges of the two flaps of a cleft lying on a rigid floor and fold "
               "them back to expose a target strip under the cleft, each under a tension limit")
    success_summary = "every target point exposed with each tool's force at most {force_limit:N}"
    DIFFICULTY = dict(
        easy=dict(force_limit=0.8, success_exposure=0.8, terminate_on_success=True),
        default=dict(force_limit=0.5, success_exposure=0.95, terminate_on_success=True),
        hard=dict(force_limit=0.2, success_exposure=0.95, terminate_on_success=False),
    )

    def __init__(self, *, target_width=0.02, target_shift_range=(-0.0025, 0.0025), force_limit=None,
                 tension_weight=1.0, grip_weight=1.0, grip_margin=0.8, success_exposure=None, success_bonus=5.0,
                 grasp_force_limit="auto", grasp_weight=5.0, grasp_commands=False, difficulty="default",
                 **kwargs):
        settings = difficulty_settings(self.DIFFICULTY, difficulty, dict(force_limit=force_limit,
                                                                         success_exposure=success_exposure))
        self.target_width = positive_scalar("target_width", target_width, "m")
        if target_shift_range is None:
            raise ValueError("target_shift_range must be a (low, high) pair in m, got None")
        self.target_shift_range = check_range("target_shift_range", target_shift_range, finite_length)
        self.force_limit = positive_scalar("force_limit", settings["force_limit"], "N")
        self.tension_weight = nonnegative_scalar("tension_weight", tension_weight)
        self.grip_weight = nonnegative_scalar("grip_weight", grip_weight)
        self.grip_margin = nonnegative_scalar("grip_margin", grip_margin)
        if self.grip_margin >= 1:
            raise ValueError(f"grip_margin must lie in [0, 1) (a share of grasp_force_limit), got {grip_margin!r}")
        self.success_exposure = positive_scalar("success_exposure", settings["success_exposure"])
        if self.success_exposure > 1:
            raise ValueError(f"success_exposure must lie in (0, 1], got {success_exposure!r}")
        self.success_bonus = nonnegative_scalar("success_bonus", success_bonus)
        self.grasp_force_limit = grasp_setting(grasp_force_limit)
        self.grasp_weight = nonnegative_scalar("grasp_weight", grasp_weight)
        if not isinstance(grasp_commands, (bool, np.bool_)):
            raise ValueError(f"grasp_commands must be True or False, got {grasp_commands!r}")
        self.grasp_commands = bool(grasp_commands)
        self.grasp_point = "edge"  # Retraction's worlds read it: each grasp is on its flap's free edge
        self.jaw_radius = None
        TissueEnv.__init__(self, difficulty=difficulty, **kwargs)

    # -- scene ---------------------------------------------------------------------------------------
    def _build_mesh(self):
        """The block of ``shape`` without its middle column of hexahedra: two flaps across a cleft one
        element wide, their nodes numbered as the block's (x fastest) with the cleft's gap left out."""
        nx = self.shape[0]
        if nx % 2 == 0:
            raise ValueError(f"shape[0] must be odd (two flaps of equal length and the cleft's column between them), "
                             f"got shape {self.shape}")
        check_work(self.shape, self.max_nodes)
        block = HexMesh.block(self.shape, self.spacing)
        column = np.arange(len(block.elements)) % nx  # elements in block order: i fastest
        elements = block.elements[column != nx // 2]
        used = np.unique(elements)
        index = np.full(block.n_nodes, -1)
        index[used] = np.arange(len(used))
        return HexMesh(block.nodes[used], index[elements])

    @property
    def flap_length(self) -> float:
        """Each flap's length from its attached edge to its free edge, m."""
        return float(self.spacing[0] * (self.shape[0] // 2))

    @property
    def grasp_radius(self) -> float:
        """The reach of a jaw, m: the free edge face's half-diagonal with a margin, so that a jaw at
        the edge's middle closes on the whole edge."""
        return 0.51 * float(np.hypot(self.size[1], self.size[2]))

    def _setup_scene(self):
        nodes = self.mesh.nodes
        x = nodes[:, 0]
        self.fixed_nodes = np.flatnonzero(np.isclose(x, 0.0) | np.isclose(x, self.size[0]))
        #: (T, n) bool each flap's free edge: the left flap's (x = flap length), the right one's
        self.edge_nodes = np.stack([np.isclose(x, self.flap_length), np.isclose(x, self.size[0] - self.flap_length)])
        self.tool_nodes = np.flatnonzero(self.edge_nodes.any(axis=0))
        self._floor_candidates = np.ones(self.mesh.n_nodes, bool)
        self._floor_candidates[self.fixed_nodes] = False
        self.top_candidates = np.zeros(self.mesh.n_nodes, bool)  # no chosen grasp point
        self.contact = self._start_contact()
        self._place_scene(nodes)
        self._footprint = flap_footprint(self.mesh.elements)

    def _start_held(self):
        """(T, n) bool the nodes each grasper holds at the start: its edge without grasp commands."""
        return self.edge_nodes & (not self.grasp_commands)

    def _start_contact(self):
        return self._floor_candidates & np.isclose(self.mesh.nodes[:, 1], 0.0) & ~self._start_held().any(axis=0)

    def _place_scene(self, nodes):
        TissueEnv._place_scene(self, nodes)
        length = self.flap_length
        self.jaw_rest = np.concatenate([nodes[self.edge_nodes[tool]].mean(axis=0) for tool in range(2)])
        self.workspace_low = np.array([-length, 0.0, -0.01, -0.005, 0.0, -0.01])
        self.workspace_high = np.array([0.005, length, 0.01, length, length, 0.01])

    def _start_control(self):
        control = self.base_control.copy()
        held = self._start_held().any(axis=0)
        self.start_tool_mask = np.repeat(held[:, None], 3, axis=1)
        control.impose(np.flatnonzero(held), self.mesh.nodes[held])
        nodes = np.flatnonzero(self.contact)
        control.impose(nodes, np.zeros((len(nodes), 3)), components=(1,))
        return control

    def _task_feature_sizes(self):
        return dict(target_range=2, exposed_fraction=1, tension=2, grasped=2)

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        self.held = self._start_held()
        self.contact = self._start_contact()
        shift = float(self.np_random.uniform(*self.target_shift_range))
        middle = 0.5 * self.size[0] + shift
        self.target_x = np.clip(middle + np.array([-0.5, 0.5]) * self.target_width, 0.0, self.size[0])
        width = self.size[2]
        x = np.linspace(self.target_x[0], self.target_x[1], TARGET_GRID[0])
        z = np.linspace(0.25 * width, 0.75 * width, TARGET_GRID[1])
        self.target_points = np.stack(np.meshgrid(x, z, indexing="ij"), axis=-1).reshape(-1, 2)

    def constrain_tool(self, offset, size=None):
        """Each tool's offset (..., 6) m projected as Retraction's grasped edge (``flap_constraint``),
        the right flap's mirrored (its attached edge is at x = L)."""
        offset = np.asarray(offset, dtype=np.float64)
        mirror = np.array([[1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])  # the right flap's x, as seen from its attached edge
        tools = offset.reshape(offset.shape[:-1] + (2, 3)) * mirror
        return (flap_constraint(tools, self.flap_length) * mirror).reshape(offset.shape)

    def scripted_action(self, lift_height=None, hold=None):
        """Close both graspers, lift each free edge to ``lift_height`` m (default 2/3 of the flap's
        length L), then bring it over its attached edge to (x, y) = ``hold`` m from it (default
        (L / 12, 5 L / 6), Retraction's on its 6 cm flap; mirrored for the right flap); a grasper
        that lost its grasp closes again where it is."""
        self._require_reset("scripted_action()")
        length = self.flap_length
        lift_height = 2.0 * length / 3.0 if lift_height is None else lift_height
        hold = (length / 12.0, 5.0 * length / 6.0) if hold is None else hold
        held = self.held.any(axis=1)
        jaws = (self.jaw_rest + self.tool_offset).reshape(2, 3)
        rest = self.jaw_rest.reshape(2, 3)
        action = np.zeros(8 if self.grasp_commands else 6)
        for tool, side in enumerate((1.0, -1.0)):
            attached = 0.0 if side > 0 else self.size[0]
            if not held[tool]:
                if self.grasp_commands:
                    action[6 + tool] = 1.0
                continue
            jaw = jaws[tool]
            if jaw[1] < lift_height - 1e-6 and side * (jaw[0] - attached) > hold[0] + 0.01:
                goal = np.array([jaw[0], lift_height, rest[tool, 2]])
            else:
                goal = np.array([attached + side * hold[0], hold[1], rest[tool, 2]])
            action[3 * tool:3 * tool + 3] = (goal - jaw) / self.max_step
        return np.clip(action, -1.0, 1.0).astype(np.float32)

    def _markers(self):
        jaws = (self.jaw_rest + self.tool_offset).reshape(2, 3)
        return dict(tool=jaws[0], tool_right=jaws[1],
                    target=np.array([self.target_x.mean(), 0.0, 0.5 * self.size[2]]))


class BimanualExposureVectorEnv(TissueVectorEnv):
    """N copies of BimanualExposure-v0 stepped together (``tissue_env.vector``): built by
    ``gym.make_vec("tissue_env/BimanualExposure-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    Same keywords, spaces, rewards and infos as the single env (see ``BimanualExposureEnv``)."""

    env_class = BimanualExposureEnv
