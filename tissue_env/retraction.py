"""Retraction-v0: lift and pull back a flap of tissue to expose a target region under it."""

from __future__ import annotations

import numpy as np

from sim_core import kernels
from sim_core.solvers.grasp import Grasper

from .base import TissueEnv, check_range, difficulty_settings, nonnegative_scalar, positive_scalar
from .camera import ALBEDO, Camera, floor_tiles
from .vector import TissueVectorEnv
from .worlds import TaskWorlds

#: Local corners of the bottom (y = 0) and top (y = 1) faces of a VTK hexahedron, in cyclic order.
_BOTTOM, _TOP = [0, 1, 5, 4], [3, 2, 6, 7]
#: The default grasp force limit, N: the pull a laparoscopic grasper holds bowel against before it slips.
#: Heijnsdijk et al. measured slip of pig bowel pulled at 5 N between laparoscopic grasper jaws (the pinch
#: force that prevents slip at a 5 N pull: 3 N with a profiled jaw, up to 22 N with a smooth one; Surg
#: Endosc 18:974-979, 2004, doi:10.1007/s00464-003-9153-2), and subjects holding pig bowel at a 5 N pull
#: pinched 6.8 N against the 3.0 N that prevented slip (Heijnsdijk et al., Surg Endosc 18:980-985, 2004):
#: 5 N is the pull a grasper is made and used to hold without slipping.
GRASP_SLIP_FORCE = 5.0
#: The instruments ``grasp_force_limit`` may name, with the pull (N) each holds before the tissue
#: slips out: "grasper", the laparoscopic grasper (GRASP_SLIP_FORCE); "retractor", an instrument that
#: holds the edge by its shape, not by friction between jaws (a retractor blade or hook behind the edge,
#: a stay suture through it), so nothing slips out of it: np.inf.
GRASP_INSTRUMENTS = dict(grasper=GRASP_SLIP_FORCE, retractor=np.inf)
#: With ``grasp_force_limit="auto"`` (the default) the scene holds tissue up to this Young's modulus
#: (Pa: soft organs, 1-100 kPa) with the grasper and stiffer tissue (cartilage-like, up to 1 MPa) with
#: the retractor. Measured (``python -m benchmarks.material_range``, ``scripted_peak_tool_force_N``):
#: at 100 kPa the 5 N grasper lets some of the edge's nodes slip but keeps enough for the scripted
#: lift to succeed on every seed and nu; at 1 MPa the retractor holds 66-275 N (nu 0.3-0.49) in the
#: scripted lift's first step, where the grasper loses the whole edge (tests/test_env_material_range.py).
RETRACTOR_MODULUS = 1e5
#: Where the grasper takes the flap (``grasp_point``): "edge", the whole free edge from the start, or
#: "chosen", the nodes of the top face around the point the first action picks.
GRASP_POINTS = ("edge", "chosen")


def grasp_limit(value) -> float:
    """``grasp_force_limit`` as a float: a number > 0 in N, ``np.inf`` for a grasp that never slips."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    limit = float(value) if number else np.nan
    if np.isnan(limit) or limit <= 0:
        raise ValueError(f"grasp_force_limit must be a number > 0 in N (np.inf: a grasp that never slips; default "
                         f"{GRASP_SLIP_FORCE} N), got {value!r}")
    return limit


def grasp_setting(value):
    """``grasp_force_limit`` as a task keeps it: "auto" (the instrument chosen by the tissue's
    stiffness, ``grasp_limits``), or a limit in N: a number > 0, ``np.inf`` or an instrument's name
    (``GRASP_INSTRUMENTS``)."""
    if isinstance(value, str):
        if value != "auto" and value not in GRASP_INSTRUMENTS:
            raise ValueError(f"grasp_force_limit must be a number > 0 in N, np.inf, 'auto' or an instrument of "
                             f"{sorted(GRASP_INSTRUMENTS)}, got {value!r}")
        return GRASP_INSTRUMENTS.get(value, value)
    return grasp_limit(value)


def grasp_limits(setting, young_modulus):
    """The grasp force limits, N (shape of ``young_modulus``, Pa), of a ``grasp_setting``: with
    "auto", the grasper's GRASP_SLIP_FORCE on tissue up to RETRACTOR_MODULUS and a retractor's
    np.inf (no slip) on stiffer tissue."""
    modulus = np.asarray(young_modulus, dtype=float)
    if isinstance(setting, str):  # "auto"
        return np.where(modulus > RETRACTOR_MODULUS, GRASP_INSTRUMENTS["retractor"], GRASP_INSTRUMENTS["grasper"])
    return np.full(modulus.shape, float(setting))


def flap_footprint(elements):
    """(2M, 4) node indices of the bottom and top face of each of the M hexahedra ``elements``: a
    target point on the floor under one of these quads, seen from above (x-z), is hidden."""
    return np.concatenate([elements[:, _BOTTOM], elements[:, _TOP]])


def flap_constraint(offset, length):
    """The offsets (..., 3) m of a grasped free edge of a flap of ``length`` (...) m, projected where
    the one-element-thick flap deforms without inverting elements (``RetractionEnv.constrain_tool``):
    back towards the attached edge (-x) only as far as lifted, max(dy, 2 dy - L/3), sideways only
    as far as lifted, min(1 cm, dy / 2)."""
    offset = np.array(offset, dtype=np.float64, copy=True)
    lift = np.maximum(offset[..., 1], 0.0)
    back = np.maximum(lift, 2.0 * lift - length / 3.0)
    offset[..., 0] = np.maximum(offset[..., 0], -back)
    side = np.minimum(0.01, 0.5 * lift)
    offset[..., 2] = np.clip(offset[..., 2], -side, side)
    return offset


class RetractionWorlds(TaskWorlds):
    """Retraction's step on N worlds (``tissue_env.worlds``)."""

    # The flap swings through large rotations: its matrix changes fast and factorises cheaply
    # (a few hundred free dofs), so a copy's factor is refreshed once its extra iterations add up.
    # The Jacobi lockstep was faster, but its trajectories strayed much further from the exact ones
    # than the single env's (this chaotic flap, random actions), where the factors' stay close:
    # the factors are kept. The measurement's force
    # pass is the next step's (observations equal to 5e-17 with and without): one force pass per
    # step instead of two (benchmarks/vector_env_speed.py, the performance page).
    refactor_amortise = 6
    share_force_pass = True

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count = self.task, self.num_envs
        self.tool_nodes = env.tool_nodes
        self._footprint = np.ascontiguousarray(env._footprint, dtype=np.int64)
        self._base_fixed = env.base_control.fixed
        self._base_target = np.repeat(env.base_control.target[None], count, axis=0)  # each world's (size_range)
        #: the grasper on the free edge: its jaws span the edge (``RetractionEnv.grasp_radius``), each
        #: world's holding up to its episode's limit (N, ``grasp_limits``: the instrument its tissue gets)
        self.grasper = Grasper(env.grasp_radius, np.full(count, GRASP_SLIP_FORCE))
        #: (N, n) bool the nodes each world's grasper holds; (N, n, 3) m the positions of the nodes it
        #: closed on, when it closed (they follow the jaw's displacement, ``tool_offset``, from there);
        #: (N, 3) m the jaw's rest position; (N,) the nodes held after the last measurement
        self.held = np.zeros((count, env.mesh.n_nodes), dtype=bool)
        self.grasp_anchors = np.zeros((count, env.mesh.n_nodes, 3))
        self.jaw_rest = np.zeros((count, 3))
        self.held_count = np.zeros(count, dtype=int)
        #: (N,) bool whether each world's grasp point is chosen (always with grasp_point="edge"), (N,) the
        #: nodes its grasper closed on, (N,) m the jaw's distance from the attached edge (``constrain_tool``)
        self.grasp_chosen = np.zeros(count, dtype=bool)
        self.grasp_size = np.zeros(count, dtype=int)
        self.grasp_reach = np.zeros(count)
        self._top_candidates = env.top_candidates
        self._chosen_mode = env.grasp_point == "chosen"
        self.target_x = np.zeros((count, 2))
        self.target_points = np.zeros((count, 12, 2))  # the 4 x 3 grid of each copy's target
        self._floor_candidates = env._floor_candidates
        self.contact = np.zeros((count, env.mesh.n_nodes), dtype=bool)  # nodes each copy's floor holds
        self._node_forces = None  # (N, n, 3) net forces of the last measurement
        for name in ("force_limit", "tension_weight", "success_exposure", "success_bonus", "grasp_weight"):
            setattr(self, name, getattr(env, name))

    def _load_task(self, index, env):
        self._base_target[index] = env.base_control.target
        # the jaws close on the free edge at rest (the grasp of the episode's start, ``env.held``)
        rest = env.episode_mesh.nodes
        self.jaw_rest[index] = env.jaw_rest
        self.held[index] = self.grasper.close(rest, self.jaw_rest[index], env.held)[0]
        self.grasp_anchors[index] = np.where(self.held[index, :, None], rest, 0.0)
        self.grasp_chosen[index] = env.grasp_chosen
        self.grasp_size[index] = self.held[index].sum()
        self.grasp_reach[index] = env.episode_size[0]
        self._load_floor_scene(index, env)
        self._load_grasp_limit(index, env)

    def _load_grasp_limit(self, index, env):
        """World ``index``'s grasp force limit, N: its episode's instrument (``grasp_limits``)."""
        limits = self.grasper.force_limit.copy()  # (N,) N; a Grasper is immutable: a new one holds them
        limits[index] = env.episode_grasp_force_limit
        self.grasper = Grasper(self.grasper.radius, limits)

    def _load_floor_scene(self, index, env):
        """World ``index``'s target on the floor (its x range and grid points) and the nodes its floor holds."""
        self.target_x[index] = env.target_x
        self.target_points[index] = env.target_points
        self.contact[index] = env.contact

    def _write_back_task(self, index, env):
        env.contact = self.contact[index].copy()
        env.held = self.held[index].copy()
        env.grasp_chosen = bool(self.grasp_chosen[index])
        env.jaw_rest = self.jaw_rest[index].copy()

    def step(self, actions, active):
        """With grasp_point="chosen", a world's first action picks the grasp point (``choose_grasp``)
        and its jaws close there, without moving, in that step; then the steps of every task."""
        choosing = np.asarray(active, dtype=bool) & ~self.grasp_chosen
        if choosing.any():
            actions = np.array(actions, dtype=float)
            self.choose_grasp(choosing, np.clip(actions, -1.0, 1.0))
            actions[choosing] = 0.0
        return super().step(actions, active)

    def choose_grasp(self, rows, actions):
        """Close the graspers of the worlds ``rows`` (N,) bool on the top-face nodes within the jaw's
        radius of the points their ``actions`` (N, 3) in [-1, 1] pick: x from the middle of the flap
        (-1) to its free edge (+1), z across its width (-1 to +1); action 1 is not read. The jaw's
        workspace then reaches back to the attached edge from the point."""
        size = self.block_size[rows]
        jaw = np.column_stack([size[:, 0] * (0.75 + 0.25 * actions[rows, 0]), size[:, 1],
                               size[:, 2] * 0.5 * (1.0 + actions[rows, 2])])
        held = self.grasper.close(self.positions[rows], jaw, self._top_candidates)[0]
        self.held[rows], self.jaw_rest[rows] = held, jaw
        self.grasp_anchors[rows] = np.where(held[..., None], self.positions[rows], 0.0)
        self.grasp_chosen[rows] = True
        self.held_count[rows] = self.grasp_size[rows] = held.sum(axis=1)
        self.grasp_reach[rows] = jaw[:, 0]
        self.workspace_low[rows, 0] = -jaw[:, 0]
        self.tool_offset[rows] = 0.0

    def _tool_position(self, positions):
        # the jaw, which moves on whether it holds tissue or not; holding the whole edge, the mean of
        # the places it imposes on the edge's nodes
        if self._chosen_mode:
            return self.jaw_rest + self.tool_offset
        return (self.tool_offset[:, None, :] + self.grasp_anchors[:, self.tool_nodes]).mean(axis=1)

    def _floor_nodes(self):
        """(N, n) bool the nodes each world's floor may hold: neither attached nor grasped (an edge
        node that slipped out of the grasp falls back under the floor's contact)."""
        return self._floor_candidates[None] & ~self.held

    #: the floor a camera sees, m beyond the flap on every side
    floor_margin = 0.02

    def _scene_extras(self):
        """The floor (y = 0) in tiles whose middle one is each world's target rectangle, in its own
        colour: the task's instruction (the state observation has its x range), not hidden."""
        length, width = self.block_size[:, 0], self.block_size[:, 2]
        margin = self.floor_margin
        x = np.column_stack([np.full(self.num_envs, -margin), self.target_x, length + margin])
        z = np.column_stack([np.full(self.num_envs, -margin), 0.25 * width, 0.75 * width, width + margin])
        vertices, triangles = floor_tiles(x, z)
        albedo = np.tile(ALBEDO["floor"], (len(triangles), 1))
        albedo[8:10] = ALBEDO["target"]  # tile (1, 1): floor_tiles' triangles 2 (1 * 3 + 1) and the next
        return vertices, triangles, albedo

    def _constrain_tool(self, offset):
        # each world's flap length from its attached edge to the jaw
        size = self.block_size.copy()
        size[:, 0] = self.grasp_reach
        return self.task.constrain_tool(offset, size)

    def _control(self, rows=None):
        """The tool, and the floor contact: the height of every node on the floor is imposed (y = 0,
        frictionless: x and z stay free), so the implicit step solves with the contact in place; a
        node that the tissue pulls up (net force on it upward, measured at the current state) is
        released first, as in the static scene's active set (``sim_core.studies.solving``)."""
        if self._node_forces is not None:
            held = self.contact & (self._node_forces[..., 1] <= 0.0)
            self.contact = held if rows is None else np.where(rows[:, None], held, self.contact)
        fixed, target, tool_mask = self._grasp_control()
        target[..., 1] = np.where(self.contact, 0.0, target[..., 1])
        fixed[..., 1] |= self.contact
        return fixed, target, tool_mask

    def _grasp_control(self):
        """(fixed (N, n, 3), target (N, n, 3) m, tool_mask (N, n, 3)): the attached nodes and the
        grasped ones, which follow the jaw's displacement from where it closed on them
        (``sim_core.solvers.grasp``)."""
        fixed, target = self.grasper.control(self._base_fixed, self._base_target, self.held, self.grasp_anchors,
                                             self.tool_offset)
        return fixed, target, np.repeat(self.held[..., None], 3, axis=2)

    def _after_substep(self, positions, velocities, rows):
        # a free node that went below the floor is put back on it and joins the contact set
        below = (positions[..., 1] < 0.0) & rows[:, None] & self._floor_nodes()
        positions[..., 1][below] = 0.0
        velocities[..., 1][below] = np.maximum(velocities[..., 1][below], 0.0)
        self.contact |= below

    def _measure(self, tool_mask):
        """The measurements, and the grasp judged at them: held nodes slip out where the grasp force
        passes ``grasp_force_limit`` (``Grasper.slip``), and the tool's force is the grasp's on the
        nodes still held (within the limit)."""
        measures = super()._measure(tool_mask)
        forces = self._node_forces = measures["forces"]
        self.held = self.grasper.slip(forces, self.held)
        measures["reaction_force"] = self.grasper.force(forces, self.held)
        return measures

    def _record(self, measures, rows, fresh):
        # the share of the nodes the grasper closed on that slipped out of it in this step (per
        # grasper where ``held`` is (N, T, n): a task with T tools)
        count = self.held.sum(axis=-1)
        per_world = (-1,) + (1,) * (count.ndim - 1)
        rows, fresh = rows.reshape(per_world), fresh.reshape(per_world)
        before = np.where(fresh, count, self.held_count)
        measures["grasp_slipped"] = np.where(rows, (before - count) / np.maximum(self.grasp_size, 1), 0.0)
        measures["grasped_nodes"] = count
        self.held_count = np.where(rows, count, self.held_count)

    def _grasped(self, measures):
        return (measures["grasped_nodes"] > 0).reshape(self.num_envs, -1)

    @property
    def footprint_quads(self) -> np.ndarray:
        """(2M, 4) node indices of the bottom and top face of each of the flap's M elements: a
        target point under one of these quads, seen from above (x-z), is hidden
        (``exposed_fraction``)."""
        return self._footprint

    def _task_measures(self, positions):
        # the target points under a footprint quad of the flap (seen from above), in one compiled pass
        hidden = np.empty(self.target_points.shape[:2], dtype=bool)
        kernels.points_covered_by_quads(self.target_points, np.ascontiguousarray(positions, dtype=float),
                                        self._footprint, hidden)
        exposed = 1.0 - np.mean(hidden, axis=1)
        footprint = np.stack([positions[..., 0].min(axis=1), positions[..., 0].max(axis=1)], axis=1)
        return dict(exposed_fraction=exposed, footprint=footprint)

    def _task_features(self, measures):
        scale, centre_x = self.length_scale, self.centre[0]
        return dict(
            target_range=(self.target_x - centre_x) / scale, exposed_fraction=measures["exposed_fraction"][:, None],
            tension=np.linalg.norm(measures["reaction_force"], axis=1)[:, None] / self._force_limits()[:, None],
            footprint_range=(measures["footprint"] - centre_x) / scale,
            **(dict(grasp_chosen=self.grasp_chosen[:, None].astype(float)) if self._chosen_mode else {}),
        )

    def _task_info(self, measures):
        return dict(exposed_fraction=measures["exposed_fraction"].copy(),
                    tension=np.linalg.norm(measures["reaction_force"], axis=1),
                    grasped_nodes=measures["grasped_nodes"].copy(), grasp_lost=measures["grasped_nodes"] == 0,
                    grasp_slipped=measures["grasp_slipped"].copy(), grasp_point=self.jaw_rest.copy())

    def _force_limits(self):
        """(N,) each world's force limit, N (``scaled_force`` of ``force_limit``)."""
        return self.scaled_force(self.force_limit)

    def _is_success(self, measures):
        return ((measures["exposed_fraction"] >= self.success_exposure)
                & (np.linalg.norm(measures["reaction_force"], axis=1) <= self._force_limits()))

    def _reward_terms(self, measures):
        tension = np.linalg.norm(measures["reaction_force"], axis=1)
        terms = dict(
            exposure=measures["exposed_fraction"] - 1.0,
            tension=-self.tension_weight * np.maximum(0.0, tension - self._force_limits()) / self._force_limits(),
            success=np.where(self._is_success(measures), self.success_bonus, 0.0),
            grasp=0.0 - self.grasp_weight * measures["grasp_slipped"],  # 0.0, not -0.0, while the grasp holds
        )
        terms.update(self._damage_terms(measures))
        return terms


class RetractionEnv(TissueEnv):
    """
    ## Description

    A flap of tissue (6 x 0.8 x 3 cm, 12 x 2 x 6 hexahedra of 5 x 4 x 5 mm, the hyperelastic
    mass-spring model ``baudet-hyperelastic`` of ``sim_core``, whose stress correction gets these box
    elements' shear modulus right where Baudet's springs alone are 0.76-1.375x off; gravity on) lies
    on a rigid, frictionless floor (y = 0) and stays attached to the body along its edge x = 0. Contact is an active set, as in the static scene of ``sim_core.studies.solving``: the
    height of every node on the floor is imposed in the implicit step (x and z stay free), a node
    the tissue pulls up is released, and a free node that goes below the floor is put back on it
    (losing its downward velocity) and joins the set. Held still, the flap settles exactly on the
    frictionless static equilibrium (``benchmarks/env_accuracy.py``; a post-step clamp alone
    settled up to 121% away in volume change). A
    target region on the floor, under the flap near its free end, must be exposed: the tool grasps
    the free edge (every node of the face x = 6 cm, all components imposed, ``sim_core.solvers.grasp``),
    lifts it and pulls it back, as a surgeon retracts a liver lobe or a peritoneal flap to expose
    what lies under it, while keeping the tension (the force on the tool) under ``force_limit``.

    The instrument is the scene's, chosen for the tissue it is given (``grasp_force_limit="auto"``,
    the default): on soft tissue (E up to 100 kPa, ``RETRACTOR_MODULUS``) a laparoscopic grasper,
    which holds up to 5 N (what it holds bowel against without slipping: ``GRASP_SLIP_FORCE``); on
    stiffer tissue (cartilage-like, up to 1 MPa), whose lifted edge pulls far harder than 5 N, a
    retractor, which holds the edge by its shape and does not slip (``episode_grasp_force_limit``:
    ``np.inf``). A number (N), ``"grasper"`` or ``"retractor"`` sets the instrument at every E.
    Where the force on the grasped nodes passes the grasp's limit, they slip out of the jaws one
    after the other, the most loaded first, until the force on those left is within the limit
    (``Grasper.slip``): the tool never reports more than the
    limit while it holds, and the edge falls back where the grasp is lost. A lost grasp does not end
    the episode (the tool moves on, holding nothing); it costs ``reward_grasp``.

    Physics: one implicit Euler step of ``dt`` = 20 ms per env step with the floor contact in it,
    then the projection of new contacts. Measured: no divergence in 100 random-action episodes (1
    to 4 with the clamp alone); the scripted lift-and-pull succeeds on 20 of 20 seeds.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: displacement increment of the grasped edge, scaled by ``max_step``
    (default 5 mm), clipped to the workspace (x from -6 to +1 cm, y from 0 to 6 cm, z +-1 cm around
    the rest position of the edge).

    | Num | Action                     | Min | Max | Unit         |
    |-----|----------------------------|-----|-----|--------------|
    | 0   | tool increment along x     | -1  | 1   | max_step (m) |
    | 1   | tool increment along y     | -1  | 1   | max_step (m) |
    | 2   | tool increment along z     | -1  | 1   | max_step (m) |

    With ``grasp_point="chosen"`` the grasper holds nothing at the start, and the first action picks
    where it grasps (its jaws close there in that step, without moving): the top-face nodes within
    ``jaw_radius`` (default 6 mm: on these 5 mm elements the 4 or 5 top nodes nearest the point, fewer
    at the flap's border) of the point x = L (0.75 + 0.25 a0), z = W (1 + a2) / 2 on the top
    face (a0 = -1: the middle of the flap, +1: its free edge; a2 across its width W; a1 is not read).
    The following actions move the jaw as above, its workspace reaching back to the attached edge.

    ## Observation Space

    ``observation_type="state"``: ``Box(-100, 100, (17,), float32)``, the maximum spring
    strain within +-1000 (a soft flap stretches past 100%: 127% at 1 kPa), every other entry within
    +-100.

    | Index | Observation                                         | Unit (normalised)     |
    |-------|-----------------------------------------------------|-----------------------|
    | 0-2   | tool position (the grasper's jaw)                   | cm from block centre  |
    | 3-5   | tool displacement from its start                    | cm                    |
    | 6-8   | force the tool exerts on the tissue                 | 0.1 N x E / 5 kPa      |
    | 9     | relative volume change (V - V0) / V0                | %                     |
    | 10    | maximum spring strain abs(L - L0) / L0              | %                     |
    | 11-12 | target region x range (start, end)                  | cm from block centre  |
    | 13    | exposed fraction of the target                      | 0-1                   |
    | 14    | tension: magnitude of the tool force / force_limit  | 1                     |
    | 15-16 | flap footprint x range (min, max over its nodes)    | cm from block centre  |
    | 17    | grasp chosen (``grasp_point="chosen"`` only)        | 0 or 1                |

    ``"deformation"`` appends the surface-node displacements (cm); ``"dict"`` gives the features
    as a ``Dict`` keyed by name. There is no ``"goal"`` observation: the reward is the covering of
    the target by the whole deformed flap (every element's footprint against the target grid) and
    the tension, not a function of a low-dimensional achieved state, and the desired outcome (the
    target exposed under the tension limit) is the same in every episode, so relabelling a
    transition with the state it reached would give no other goal to learn from.

    ## Rewards

    ``r = reward_exposure + reward_tension + reward_success + reward_grasp + reward_volume + reward_strain
    (+ reward_instability)``:

    - ``reward_exposure = exposed fraction - 1`` of the target (points of a 4 x 3 grid on the target
      rectangle not under the flap seen from above): a penalty for the part still covered. It is
      never positive, so ending the episode by succeeding is always worth more than lingering
      (with a positive exposure reward, PPO learned to hover at 80-90% exposure and never finish).
    - ``reward_tension = -tension_weight * max(0, |F| - force_limit) / force_limit`` (defaults 1,
      0.5 N at E = 5 kPa; the limit scales with the episode's E, so the same strains are allowed at
      any stiffness)
    - ``reward_success = success_bonus`` (default 5) on success
    - ``reward_grasp = -grasp_weight * (share of the edge's nodes that slipped out of the grasp in
      the step)`` (default 5: losing the whole grasp costs what a success gains; 0 while it holds)
    - ``reward_volume``, ``reward_strain`` as in every task, ``reward_instability`` on divergence.

    ## Starting State

    The flap flat on the floor at rest; the target rectangle spans 1.5 cm in x starting at a
    distance drawn uniformly in ``target_start_range`` (default 3-4 cm) from the attached edge, and
    the middle half of the flap's width in z.

    ## Episode End

    Terminated on success (exposed fraction >= ``success_exposure`` = 0.95 with |F| <=
    ``force_limit``; unless ``terminate_on_success=False``, the hard level's) or on divergence
    (``info["unstable"]``). Truncated after 60 steps. A lost grasp does not end it.

    ## Info

    Every step's and reset's ``info`` has the entries every task has (``relative_volume_change``,
    ``unstable``, ``unstable_reason``, ``is_success``, ``out_of_range``, ``max_strain``, one
    ``reward_<term>`` per reward term, the episode's material and ``size``), the tool's forces:
    ``reaction_force`` ((3,) N, the force the grasper exerts on the tissue, the sum over the nodes it
    holds) and ``tool_forces`` ((1, 3) float, N: the force the tissue exerts on the grasper, its
    opposite; 0 once the grasp is lost), ``grasped`` ((1,) bool: the grasper holds at least one
    node), and the task's own: ``exposed_fraction``, ``tension`` (N, the magnitude of the tool's
    force), ``grasped_nodes`` (the nodes still held), ``grasp_slipped`` (the share of the nodes the
    grasper closed on that slipped out in this step), ``grasp_lost`` (bool: none is held) and
    ``grasp_point`` ((3,) m, the jaw's rest position: the free edge's middle, or the chosen point).

    ## Difficulty

    ``difficulty="easy" | "default" | "hard"`` sets ``force_limit``, ``success_exposure`` and
    ``terminate_on_success`` from ``RetractionEnv.DIFFICULTY`` (a keyword passed explicitly
    overrides its level's value): easy, a looser tension limit and 85% exposure; hard, a tension
    limit near what holding the lifted flap takes, the whole target exposed, and no termination at
    a success, so the flap must be held back under the limit until the episode ends. Measured
    success rates and steps to success per level: the training page of the documentation
    (``benchmarks/success_rates.py --difficulty``), and SAC's training result at the hard level
    (``python -m training.benchmark --variant hard``).

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/Retraction-v0", force_limit=0.5, max_step=0.005)
    ```

    Vectorised: ``gym.make_vec("tissue_env/Retraction-v0", num_envs=16,
    vectorization_mode="vector_entry_point")`` steps the copies together in one batched physics
    step (``RetractionVectorEnv``, same keywords, spaces, rewards and infos; ``tissue_env.vector``).

    Task keywords: ``target_start_range`` (m), ``target_length`` (m), ``force_limit`` (N at E = 5 kPa, scaled by E / 5 kPa),
    ``tension_weight``, ``success_exposure``, ``success_bonus``, ``difficulty``, ``grasp_force_limit``
    (N, not scaled by E, a property of the instrument: the pull it holds before the edge slips out
    node by node, so a stiff flap pulled far loses it; default "auto": the grasper up to 100 kPa, the
    retractor above, see the Description; "grasper": 5 N at every E, from Heijnsdijk et al., "Slip
    and damage properties of jaws of laparoscopic graspers", Surg Endosc 18:974-979, 2004, whose
    graspers were tested on pig bowel pulled at 5 N, and Heijnsdijk et
    al., Surg Endosc 18:980-985, 2004: 3.0 N of pinch prevented slip at that pull (at 1 MPa the scripted
    lift loses the whole edge with it: tests/test_env_material_range.py); "retractor" or ``np.inf``: a
    grasp that never slips), ``grasp_weight`` (the penalty of losing the whole grasp), ``grasp_point``
    ("edge", the default: the whole free edge held from the start; "chosen": the first action picks
    the grasp point, see the Action Space) and ``jaw_radius`` (m, the chosen grasp's reach); shared keywords in
    ``tissue_env.base.TissueEnv``. Domain randomisation (per episode, ``randomised_parameters``):
    ``young_modulus_range``, ``poisson_ratio_range``, ``density_range`` (the material, in ``info``),
    ``size_range`` (the flap's extent, each axis in m: the flap scaled about its attached edge's
    corner, the grasp the whole free edge of the drawn flap, the workspace reaching back over its
    length; ``info["size"]``) and ``target_start_range`` (the target's place, m from the attached
    edge, clipped to the flap); ``observe_parameters=True`` appends the drawn parameters, each
    normalised to [-1, 1] over its range, to the observation.

    ## Version History

    - v0: the version of the first release (its changes before it: CHANGELOG.md).
    """

    #: The most accurate shape that keeps 300 env steps/s with a 1.25x margin
    #: (benchmarks/env_accuracy.py, with the default model): static tool force / flap centre /
    #: volume change within 1.7 / 3.0 / 9.6% of the (24, 4, 12) model, against 2.8 / 3.5 / 12.4% at
    #: (10, 2, 5), 4.6 / 3.8 / 18% at (8, 2, 4) and 8.3 / 8.4 / 46% at (6, 1, 3); 5.9 / 6.8 / 10.3%
    #: from neo-Hookean FEM on a (15, 2, 8) mesh.
    worlds_class = RetractionWorlds
    #: The default elements are 5 x 4 x 5 mm boxes, whose shear modulus Baudet's springs get 0.76-1.375x
    #: wrong (``build_model`` refuses them): the hyperelastic stress correction gets it exact.
    default_model = "baudet-hyperelastic"
    default_shape = (12, 2, 6)
    default_size = (0.06, 0.008, 0.03)
    default_max_step = 0.005
    min_shape = (2, 1, 1)
    reward_names = ("exposure", "tension", "success", "grasp", "volume", "strain")
    episode_keywords = ("target_start_range",)
    summary = "lift the free edge of a flap lying on a rigid floor to expose a target strip, under a tension limit"
    success_summary = "at least {success_exposure:%} exposed with tool force at most {force_limit:N}"

    #: The difficulty levels' keywords (``difficulty``; keywords passed explicitly override them):
    #: the tension limit (N at E = 5 kPa), the exposed share that counts as a success and whether a
    #: success ends the episode (hard: the target must be kept exposed under the limit to the end).
    DIFFICULTY = dict(
        easy=dict(force_limit=0.8, success_exposure=0.85, terminate_on_success=True),
        default=dict(force_limit=0.5, success_exposure=0.95, terminate_on_success=True),
        hard=dict(force_limit=0.15, success_exposure=1.0, terminate_on_success=False),
    )

    def __init__(self, *, target_start_range=(0.03, 0.04), target_length=0.015, force_limit=None,
                 tension_weight=1.0, success_exposure=None, success_bonus=5.0, grasp_force_limit="auto",
                 grasp_weight=5.0, grasp_point="edge", jaw_radius=0.006, difficulty="default", **kwargs):
        settings = difficulty_settings(self.DIFFICULTY, difficulty, dict(force_limit=force_limit,
                                                                         success_exposure=success_exposure))
        force_limit, success_exposure = settings["force_limit"], settings["success_exposure"]
        if target_start_range is None:
            raise ValueError("target_start_range must be a (low, high) pair in m, got None")
        self.target_start_range = check_range(
            "target_start_range", target_start_range, lambda name, value: positive_scalar(name, value, "m"))
        self.target_length = positive_scalar("target_length", target_length, "m")
        self.force_limit = positive_scalar("force_limit", force_limit, "N")
        self.tension_weight = nonnegative_scalar("tension_weight", tension_weight)
        self.success_exposure = positive_scalar("success_exposure", success_exposure)
        if self.success_exposure > 1:
            raise ValueError(f"success_exposure must lie in (0, 1], got {success_exposure!r}")
        self.success_bonus = nonnegative_scalar("success_bonus", success_bonus)
        self.grasp_force_limit = grasp_setting(grasp_force_limit)
        self.grasp_weight = nonnegative_scalar("grasp_weight", grasp_weight)
        if not isinstance(grasp_point, str) or grasp_point not in GRASP_POINTS:
            raise ValueError(f"grasp_point must be one of {GRASP_POINTS}, got {grasp_point!r}")
        self.grasp_point = grasp_point
        self.jaw_radius = positive_scalar("jaw_radius", jaw_radius, "m")
        super().__init__(difficulty=difficulty, **kwargs)

    @property
    def episode_grasp_force_limit(self) -> float:
        """The grasp force limit of this episode's instrument, N (``np.inf``: a retractor, which does
        not slip): ``grasp_force_limit``, or with "auto" the instrument the episode's tissue gets
        (``grasp_limits``)."""
        self._require_reset("episode_grasp_force_limit")
        return float(grasp_limits(self.grasp_force_limit, self.episode_young_modulus))

    @property
    def grasp_radius(self) -> float:
        """The reach of the grasper's jaws from the middle of the free edge, m: the edge face's
        half-diagonal on the largest block the env may draw (``size_range``), with a margin; with
        grasp_point="chosen", ``jaw_radius`` around the chosen point."""
        if self.grasp_point == "chosen":
            return self.jaw_radius
        largest = np.max(np.vstack([self.size] + ([] if self.size_range is None else list(self.size_range))), axis=0)
        return 0.51 * float(np.hypot(largest[1], largest[2]))

    # -- scene ---------------------------------------------------------------------------------------
    def _setup_scene(self):
        nodes = self.mesh.nodes
        self.fixed_nodes = np.flatnonzero(np.isclose(nodes[:, 0], 0.0))
        self.tool_nodes = np.flatnonzero(np.isclose(nodes[:, 0], self.size[0]))
        #: nodes the floor may hold (neither attached nor grasped), and those it holds now
        self._floor_candidates = np.ones(self.mesh.n_nodes, bool)
        # a chosen grasp holds nothing at the start: the free edge lies on the floor like the rest
        self._floor_candidates[self.fixed_nodes if self.grasp_point == "chosen"
                               else np.union1d(self.fixed_nodes, self.tool_nodes)] = False
        #: the nodes a chosen grasp may close on: the top face's, but the attached ones
        self.top_candidates = np.isclose(nodes[:, 1], self.size[1]) & self._floor_candidates
        self.contact = self._floor_candidates & np.isclose(nodes[:, 1], 0.0)
        self._place_scene(nodes)
        self._footprint = flap_footprint(self.mesh.elements)

    def _place_scene(self, nodes):
        # the grasped edge may come back to the attached one: the workspace spans the flap's length
        super()._place_scene(nodes)
        self.workspace_low = np.array([-self.episode_size[0], 0.0, -0.01])
        self.workspace_high = np.array([0.01, 0.06, 0.01])

    def default_camera(self, width=64, height=64):
        """In front of the flap (+z) and above it, looking at its middle, high enough to see the
        free edge lifted to the top of the workspace and the target strip on the floor (m)."""
        length, width_z = self.size[0], self.size[2]
        return Camera(position=(0.5 * length, 0.075, width_z + 0.07), target=(0.5 * length, 0.02, 0.5 * width_z),
                      up=(0.0, 1.0, 0.0), fov_deg=48.0, width=width, height=height, near=0.01, far=0.4)

    def _initial_positions(self, model, control):
        return model.rest_positions.copy()  # flat on the floor; the contact holds it there

    def _start_control(self):
        """The tool at rest and the floor contact: the height of every node on the floor is imposed
        (y = 0, frictionless: x and z stay free)."""
        control = super()._start_control()
        if self.grasp_point == "chosen":  # nothing held before the first action picks the point
            control.fixed[self.tool_nodes] = False
            self.start_tool_mask[:] = False
        nodes = np.flatnonzero(self.contact)
        if len(nodes):
            control.impose(nodes, np.zeros((len(nodes), 3)), components=(1,))
        return control

    def _task_feature_sizes(self):
        sizes = dict(target_range=2, exposed_fraction=1, tension=1, footprint_range=2)
        if self.grasp_point == "chosen":
            sizes["grasp_chosen"] = 1
        return sizes

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        self.held = np.zeros(self.mesh.n_nodes, dtype=bool)  # the grasper closes on the whole free edge
        self.grasp_chosen = self.grasp_point == "edge"
        self.held[self.tool_nodes] = self.grasp_chosen  # a chosen grasp holds nothing until its first action
        self.jaw_rest = self.tool_rest.mean(axis=0)
        self.contact = self._floor_candidates & np.isclose(self.mesh.nodes[:, 1], 0.0)  # flat on the floor
        start = float(self.np_random.uniform(*self.target_start_range))
        self.target_x = np.array([start, min(start + self.target_length, self.episode_size[0])])
        width = self.episode_size[2]
        x = np.linspace(self.target_x[0], self.target_x[1], 4)
        z = np.linspace(0.25 * width, 0.75 * width, 3)
        self.target_points = np.stack(np.meshgrid(x, z, indexing="ij"), axis=-1).reshape(-1, 2)

    def constrain_tool(self, offset, size=None):
        """Keep the grasped edge where the coarse flap deforms without inverting elements: it
        may come back towards the attached edge only as far as it is lifted (x offset >=
        -max(dy, 2 dy - L/3), L the flap length) and move sideways only as far as it is lifted
        (|dz| <= min(1 cm, dy / 2)). Measured (scripted straight moves to a grid of offsets, 40
        steps each): flat pushes back of 1 cm or more and sideways moves at floor level buckle the
        one-element-thick flap into inverted elements (an ``unstable`` episode end); every offset
        inside this set stayed valid. Offsets in m, shape (..., 3); ``size``: the flaps' extents
        (..., 3) m (None: this episode's)."""
        length = (self.episode_size if size is None else np.asarray(size, dtype=float))[..., 0]
        return flap_constraint(offset, length)

    def scripted_action(self, lift_height=0.04, hold=(0.005, 0.05)):
        """Lift and pull: raise the free edge to ``lift_height`` m, then bring it over the attached
        edge to (x, y) = ``hold`` m, keeping z."""
        self._require_reset("scripted_action()")
        if not self.grasp_chosen:  # grasp the middle of the free edge
            return np.array([1.0, 0.0, 0.0], np.float32)
        tool = self.jaw_rest + self.tool_offset
        if tool[1] < lift_height - 1e-6 and tool[0] > hold[0] + 0.02:
            goal = np.array([tool[0], lift_height, tool[2]])
        else:
            goal = np.array([hold[0], hold[1], self.jaw_rest[2]])
        return np.clip((goal - tool) / self.max_step, -1.0, 1.0).astype(np.float32)

    def _markers(self):
        return dict(tool=self.jaw_rest + self.tool_offset,
                    target=np.array([self.target_x.mean(), 0.0, 0.5 * self.episode_size[2]]))

    def _extra_drawing(self):
        width = self.episode_size[2]
        return [("rectangle", (self.target_x[0], self.target_x[1], 0.25 * width, 0.75 * width, 0.0))]


class RetractionVectorEnv(TissueVectorEnv):
    """N copies of Retraction-v0 stepped together (``tissue_env.vector``): built by
    ``gym.make_vec("tissue_env/Retraction-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    Same keywords, spaces, rewards and infos as the single env (see ``RetractionEnv``)."""

    env_class = RetractionEnv
