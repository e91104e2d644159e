"""Incision-v0: cut along a line marked on a tissue surface to a set depth, sparing the vessel layer below."""

from __future__ import annotations

import numpy as np

from sim_core.cutting import blade_faces

from .base import TissueEnv, check_range, difficulty_settings, nonnegative_scalar, positive_scalar
from .blade import face_centres
from .camera import ALBEDO
from .cut_tasks import BladeTaskEnv, BladeTaskWorlds, difficulty_levels
from .vector import TissueVectorEnv


class IncisionWorlds(BladeTaskWorlds):
    """Incision's step on N worlds (``tissue_env.worlds``, ``tissue_env.blade``, ``tissue_env.cut_tasks``)."""

    task_weights = ("path_weight", "depth_weight", "success_fraction")
    # the slit settles after a cut (its speed 10x less each step): a factor made before it rests costs
    # one more iteration per step until it does, so the factor is renewed after 2 excess iterations (a
    # refactorisation is worth 8-10 iterations, and 1 renewal per cut either way: the least counted
    # work over the 10 and 50 steps after the cut, benchmarks/cutting.py's solver_costs)
    refactor_amortise = 1

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count = self.task, self.num_envs
        self.tip_rest = np.tile(env.tip_rest, (count, 1))
        self.blade_length = env.blade_length
        self.surface_y = np.full(count, env.size[1])
        self.half_element = 0.5 * env.spacing[0]
        self.line = np.zeros((count, 3))  # x start, x end, z of each world's line, m
        self.target_depth = np.zeros(count)
        self.vessel = env.vessel_elements  # (M,) bool: the elements of the layer to spare
        self.n_elements = env.mesh.n_elements
        self.required = [np.zeros(0, dtype=np.int64)] * count  # each world's faces of the ideal incision (keys)
        self.required_x = [np.zeros(0)] * count  # their centres' x at rest, m
        self.done = [np.zeros(0, dtype=bool)] * count  # which of them are cut
        self.reach = np.zeros(count)  # m, the x of the first face of the ideal incision not yet cut

    def blade_edges(self, offsets):
        tip = self.tip_rest + offsets
        return np.stack([tip, tip + np.array([0.0, self.blade_length, 0.0])], axis=1)

    def _load_task(self, index, env):
        super()._load_task(index, env)
        self.line[index] = env.line
        self.target_depth[index] = env.target_depth
        self.required[index] = env.required_faces[:, 0] * self.n_elements + env.required_faces[:, 1]
        self.required_x[index] = env.required_x
        self.done[index] = np.zeros(len(env.required_faces), dtype=bool)
        self._reach(index)

    def _reach(self, index):
        uncut = self.required_x[index][~self.done[index]]
        self.reach[index] = uncut.min() if len(uncut) else self.line[index, 1] + self.half_element

    def _write_back_task(self, index, env):
        env.progress = float(self.progress[index])
        env.damage = int(self.damage[index])

    def _cut_made(self, index, faces):
        keys = faces[:, 0] * self.n_elements + faces[:, 1]
        self.done[index] = self.done[index] | np.isin(self.required[index], keys)
        self._reach(index)
        progress = float(self.done[index].mean()) if len(self.done[index]) else 1.0
        vessel = int(np.count_nonzero(self.vessel[faces[:, 0]] | self.vessel[faces[:, 1]]))
        super()._cut_made(index, faces, progress, vessel)

    def route(self, offsets):
        """The line's start at the target depth, then along the line to half an element past its end:
        the route's next point is the line's point at depth nearest the tip between its start and
        the first face of the ideal incision still uncut (``reach``)."""
        tip = self.tip_rest + offsets
        start, z = self.line[:, 0], self.line[:, 2]
        along = np.clip(tip[:, 0], start, np.maximum(start, self.reach))
        point = np.column_stack([along, self.surface_y - self.target_depth, z])
        end = self.line[:, 1] + self.half_element
        return np.abs(tip - point).sum(axis=1) + np.maximum(end - along, 0.0), point

    def _control(self, rows=None):
        """The attached bottom and the stretched sides, on each world's node rows (a node a cut copied
        is held as its original); the blade imposes nothing."""
        if self._controls is None:
            fixed = self.node_rows(self._block_fixed, False)
            self._controls = (fixed, self.node_rows(self._block_target, 0.0), np.zeros_like(fixed))
        return self._controls

    def _task_measures(self, positions):
        measures = super()._task_measures(positions)
        tip = self.tip_rest + self.tool_offset
        depth = self.surface_y - tip[:, 1]
        off_line = np.stack([tip[:, 2] - self.line[:, 2], np.maximum.reduce(
            [self.line[:, 0] - tip[:, 0], np.zeros(self.num_envs), tip[:, 0] - self.line[:, 1]])], axis=1)
        measures.update(tip_depth=depth, path_error=off_line, depth_error=depth - self.target_depth)
        return measures

    def _blade_task_features(self, measures):
        scale = self.length_scale
        line = np.column_stack([self.line[:, :2] - self.centre[0], self.line[:, 2:] - self.centre[2],
                                self.target_depth])
        return dict(line=line / scale, tip_depth=measures["tip_depth"][:, None] / scale,
                    path_error=measures["path_error"] / scale, depth_error=measures["depth_error"][:, None] / scale)

    def _is_success(self, measures):
        return (self.progress >= self.success_fraction) & (self.damage == 0)

    def _task_reward_terms(self, measures):
        scale = self.length_scale
        return dict(path=-self.path_weight * np.abs(measures["path_error"]).sum(axis=1) / scale,
                    depth=-self.depth_weight * np.abs(measures["depth_error"]) / scale)

    def _task_info(self, measures):
        info = super()._task_info(measures)
        info.update(vessel_damage=self.damage.copy(),
                    tip_depth=np.array(measures["tip_depth"], dtype=float),
                    path_error=np.linalg.norm(measures["path_error"], axis=1))
        return info

    def _scene_extras(self):
        """The blade (a thin vertical quad from its tip up, in the tool's colour) and the marked line
        (a thin strip just above the rest surface, in the target's colour): what a surgeon sees."""
        count = self.num_envs
        tip = self.tip_rest + self.tool_offset
        up = np.array([0.0, self.blade_length, 0.0])
        side = np.array([0.0015, 0.0, 0.0])
        blade = np.stack([tip - side, tip + side, tip + side + up, tip - side + up], axis=1)
        half = np.array([0.0, 0.0, 0.0008])
        start = np.column_stack([self.line[:, 0], self.surface_y + 2e-4, self.line[:, 2]])
        end = np.column_stack([self.line[:, 1], self.surface_y + 2e-4, self.line[:, 2]])
        strip = np.stack([start - half, end - half, end + half, start + half], axis=1)
        vertices = np.concatenate([blade, strip], axis=1).reshape(count, 8, 3)
        quads = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
        triangles = np.concatenate([quads, quads + 4])
        albedo = np.concatenate([np.tile(ALBEDO["tool"], (4, 1)), np.tile(ALBEDO["target"], (4, 1))])
        return vertices, triangles, albedo


class IncisionEnv(BladeTaskEnv, TissueEnv):
    """
    ## Description

    A slab of skin-like tissue (5 x 2 x 3 cm, 10 x 4 x 6 hexahedra of 5 mm, Baudet's mass-spring
    model of ``sim_core`` with hourglass control and volume forces; gravity on) lies on the body,
    attached along its bottom face (y = 0), and is held stretched across the line by ``tension``
    (default 5%: its faces z = 0 and z = 3 cm held 5% further apart than at rest, as skin is under tension). Its
    bottom layer of elements (y < 5 mm) is a vessel / organ layer (``vessel_stiffness_ratio`` times
    stiffer) that must not be cut. A line is marked on the top surface along x; the agent moves a
    scalpel blade (a straight cutting edge ``blade_length`` long, vertical, its tip the tool) and must
    cut along the line to ``target_depth`` (default 1 cm) without reaching the vessel layer.

    The blade cuts (``tissue_env.blade``, ``sim_core.cutting``): when it moves in a step, its edge
    sweeps a surface, and every pair of elements whose centroid-to-centroid segment crosses that
    surface is separated along the face it shares (nodes copied, the model rebuilt: the model of the
    tissue born with that cut), before the step's physics. The cut follows faces (no slivers, within
    half an element of the blade's path), adds no energy (each copy starts at its original's place
    and velocity), and the incision gapes under the tension. A blade plunged straight along its edge
    sweeps no surface and cuts nothing; it cuts when it moves sideways. The blade exerts no force on
    the tissue (a sharp blade; cutting forces are not modelled). ``docs/figures/incision.png``
    (``python -m benchmarks.incision_figure``) shows the slab after the scripted incision, its lips
    apart, and the agent's rgb view.

    Physics: one implicit Euler step of ``dt`` = 20 ms per env step; a cut world is stepped on its
    own cut model. Each world has ``spare_nodes`` node rows for the copies (by default two
    full-depth cuts across the slab's length); a cut that would need more is refused
    (``info["cut_refused"]``, nothing cut that step).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: displacement increment of the blade tip, scaled by ``max_step``
    (default 2.5 mm, half an element), clipped to the workspace (the slab's extent in x and z, from
    y = 0 to 1 cm above the surface).

    | Num | Action                     | Min | Max | Unit         |
    |-----|----------------------------|-----|-----|--------------|
    | 0   | blade tip's increment in x | -1  | 1   | max_step (m) |
    | 1   | blade tip's increment in y | -1  | 1   | max_step (m) |
    | 2   | blade tip's increment in z | -1  | 1   | max_step (m) |

    ## Observation Space

    ``observation_type="state"``: ``Box(-100, 100, (24,), float32)``, the maximum spring strain within
    +-1000, every other entry within +-100.

    | Index | Observation                                          | Unit (normalised)    |
    |-------|------------------------------------------------------|----------------------|
    | 0-2   | blade tip position                                   | cm from block centre |
    | 3-5   | blade tip displacement from its start                | cm                   |
    | 6-8   | force the blade exerts on the tissue (zero)          | 0.1 N x E / 5 kPa    |
    | 9     | relative volume change (V - V0) / V0                 | %                    |
    | 10    | maximum spring strain abs(L - L0) / L0               | %                    |
    | 11-14 | the line: x start, x end, z, and the target depth     | cm (from centre)     |
    | 15    | blade tip depth below the rest surface               | cm                   |
    | 16-17 | tip off the line: along z, along x beyond its ends   | cm                   |
    | 18    | depth error: tip depth - target depth                | cm                   |
    | 19    | cut progress: the share of the line's faces cut      | 0-1                  |
    | 20    | vessel-layer faces cut so far                        | faces                |
    | 21-23 | the route's next point from the tip (Rewards)        | cm                   |

    ``"deformation"`` appends the surface-node displacements (cm); ``"dict"`` gives the features as
    a ``Dict`` keyed by name; the visual observations show the tissue (each side of a cut apart,
    so the incision is seen gaping), the blade and the marked line. There is no ``"goal"``
    observation: the outcome is the set of faces cut so far, not a state a transition reaches, so
    there is no achieved goal to relabel with.

    ## Rewards

    ``r = reward_progress + reward_approach + reward_path + reward_depth + reward_damage +
    reward_success + reward_volume + reward_strain (+ reward_instability)``:

    - ``reward_progress = progress_weight * (gain in cut progress this step)`` (default 10: a whole
      incision earns 10); the progress is the share of the faces of the ideal incision (the line
      swept to ``target_depth`` at the episode's start) that are cut;
    - ``reward_approach = approach_weight * (R_before - R_after) / 1 cm`` (default 1), R the length
      (L1, m) of what remains of the route: from the tip to the line's start at the target depth, or
      to the nearest point of the line at depth up to its first face not yet cut, and from there
      along the line to half an element past its end (``info["route_remaining"]``): potential-based
      shaping (``tissue_env.cut_tasks``; it sums to the route's net shortening, 5.1-5.4 on the
      scripted incision), which lets an agent learn the approach and the plunge before its first cut;
    - ``reward_path = -path_weight * (|tip z - line z| + distance along x beyond the line's ends) / 1 cm``
      (default 0.2), the path deviation;
    - ``reward_depth = -depth_weight * |tip depth - target depth| / 1 cm`` (default 0.2);
    - ``reward_damage = -damage_weight * (vessel-layer faces cut this step)`` (default 2);
    - ``reward_success = success_bonus`` (default 5) on success;
    - ``reward_volume``, ``reward_strain`` as in every task, ``reward_instability`` on divergence.

    ``info`` also has the cut's report: ``faces_cut`` (this step), ``cut_faces`` (all), ``cut_length``
    (m), ``cut_deviation`` (m, this step's faces from the swept surface), ``element_quality``,
    ``cut_refused``, and ``cut_progress``, ``vessel_damage``, ``tip_depth`` (m), ``path_error`` (m),
    ``route_remaining`` (m).

    ## Starting State

    The stretched slab at its static equilibrium under gravity; the blade tip 5 mm above the middle
    of the top surface. The line starts at x drawn in ``line_start_range`` (default 0.8-1.5 cm) and is
    ``line_length`` (default 2.5 cm) long, at z drawn in ``line_z_range`` (default 1.2-1.8 cm).

    ## Episode End

    Terminated on success (cut progress >= ``success_fraction`` = 0.9 with no vessel face cut) or on
    divergence (``info["unstable"]``). Truncated after 60 steps.

    ## Difficulty

    ``difficulty="easy" | "default" | "hard"`` sets ``success_fraction`` from ``IncisionEnv.DIFFICULTY``
    (75%, 90%, the whole ideal incision; a keyword passed explicitly overrides its level's value).

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/Incision-v0", target_depth=0.01, tension=0.05)
    ```

    Vectorised: ``gym.make_vec("tissue_env/Incision-v0", num_envs=16, vectorization_mode="vector_entry_point")``
    steps the copies together, each cut on its own (``IncisionVectorEnv``, same keywords, spaces,
    rewards and infos; ``tissue_env.vector``).

    Task keywords: ``target_depth`` (m), ``line_start_range`` (m), ``line_z_range`` (m), ``line_length`` (m),
    ``tension`` (the sides' stretch, -), ``vessel_stiffness_ratio``, ``blade_length`` (m),
    ``progress_weight``, ``approach_weight``, ``path_weight``, ``depth_weight``, ``damage_weight``, ``success_fraction``,
    ``success_bonus``, ``difficulty``, ``spare_nodes`` (node rows per world for the cut's copies); shared keywords in
    ``tissue_env.base.TissueEnv``. Domain randomisation (per episode, ``randomised_parameters``):
    ``young_modulus_range``, ``poisson_ratio_range``, ``density_range``; ``line_start_range`` and
    ``line_z_range`` place the line. The slab's size is fixed per env (no ``size_range``).

    ## Version History

    - v0: the first version.
    """

    worlds_class = IncisionWorlds
    min_shape = (4, 3, 2)
    reward_names = ("progress", "approach", "path", "depth", "damage", "success", "volume", "strain")
    episode_keywords = ("line_start_range", "line_z_range")
    task_features = dict(line=4, tip_depth=1, path_error=2, depth_error=1)
    layer_ratio_keyword = "vessel_stiffness_ratio"
    #: The difficulty levels' keywords (``difficulty``; keywords passed explicitly override them): the
    #: share of the ideal incision's faces that counts as a success.
    DIFFICULTY = difficulty_levels("success_fraction", 0.75, 0.9, 1.0)
    summary = "cut along a line marked on a stretched slab to a set depth without cutting the vessel layer below"
    success_summary = "{success_fraction:%} of the line cut to {target_depth:m} with no vessel face cut"

    def __init__(self, *, target_depth=0.01, line_start_range=(0.008, 0.015), line_z_range=(0.012, 0.018),
                 line_length=0.025, tension=0.05, vessel_stiffness_ratio=3.0, blade_length=0.03,
                 progress_weight=None, approach_weight=None, path_weight=0.2, depth_weight=0.2, damage_weight=None,
                 success_fraction=None, success_bonus=None, spare_nodes=None, difficulty="default", **kwargs):
        success_fraction = difficulty_settings(self.DIFFICULTY, difficulty,
                                               dict(success_fraction=success_fraction))["success_fraction"]
        self.target_depth = positive_scalar("target_depth", target_depth, "m")
        self.line_start_range = check_range("line_start_range", line_start_range,
                                            lambda name, value: nonnegative_scalar(name, value))
        self.line_z_range = check_range("line_z_range", line_z_range, lambda name, value: positive_scalar(name, value))
        if self.line_start_range is None or self.line_z_range is None:
            raise ValueError("line_start_range and line_z_range must be (low, high) pairs in m, got None")
        self.line_length = positive_scalar("line_length", line_length, "m")
        self.tension = nonnegative_scalar("tension", tension)
        if self.tension >= 0.5:
            raise ValueError(f"tension must lie in [0, 0.5) (the sides' stretch), got {tension!r}")
        self.vessel_stiffness_ratio = positive_scalar("vessel_stiffness_ratio", vessel_stiffness_ratio)
        self.blade_length = positive_scalar("blade_length", blade_length, "m")
        self._blade_keywords(dict(progress_weight=progress_weight, approach_weight=approach_weight,
                                  path_weight=path_weight, depth_weight=depth_weight, damage_weight=damage_weight,
                                  success_bonus=success_bonus), spare_nodes)
        self.success_fraction = positive_scalar("success_fraction", success_fraction)
        if self.success_fraction > 1:
            raise ValueError(f"success_fraction must lie in (0, 1], got {success_fraction!r}")
        super().__init__(difficulty=difficulty, **kwargs)
        size = self.size
        if self.target_depth >= size[1]:
            raise ValueError(f"target_depth must be less than the slab's thickness {size[1]:g} m, got {target_depth!r}")
        if self.line_start_range[1] + self.line_length > size[0] or self.line_z_range[1] >= size[2]:
            raise ValueError(f"the line (line_start_range {list(self.line_start_range)} m + line_length "
                             f"{self.line_length:g} m, line_z_range {list(self.line_z_range)} m) must lie on the slab "
                             f"of {size.tolist()} m")

    # -- scene ---------------------------------------------------------------------------------------
    def _setup_scene(self):
        nodes = self.mesh.nodes
        size = self.size
        count = self.shape[0] + 1
        self._spare_rows(2 * count * (self.shape[1] + 1))  # two full-depth cuts
        bottom = np.isclose(nodes[:, 1], 0.0)
        sides = np.isclose(nodes[:, 2], 0.0) | np.isclose(nodes[:, 2], size[2])
        self.fixed_nodes = np.flatnonzero(bottom | sides)
        self.tool_nodes = np.zeros(0, dtype=np.int64)
        centres = nodes[self.mesh.elements].mean(axis=1)
        #: (M,) bool: the vessel layer's elements (the bottom layer)
        self.vessel_elements = self.layer_elements = centres[:, 1] < self.spacing[1]
        self.tip_rest = np.array([0.5 * size[0], size[1] + 0.005, 0.5 * size[2]])
        self._place_scene(nodes)

    def _place_scene(self, nodes):
        super()._place_scene(nodes)
        stretched = nodes[self.fixed_nodes].copy()
        middle = 0.5 * self.size[2]
        stretched[:, 2] = middle + (1.0 + self.tension) * (stretched[:, 2] - middle)
        self.base_control.target[self.fixed_nodes] = stretched
        self.tool_rest = np.zeros((0, 3))
        self.workspace_low = np.array([0.0, 0.0, 0.0]) - self.tip_rest
        self.workspace_high = np.array([self.size[0], self.size[1] + 0.01, self.size[2]]) - self.tip_rest

    camera_target = (0.5, 0.6, 0.5)
    camera_direction = (0.0, 1.0, 0.45)
    camera_distance = 1.7

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        start = float(self.np_random.uniform(*self.line_start_range))
        z = float(self.np_random.uniform(*self.line_z_range))
        self.line = np.array([start, start + self.line_length, z])
        self.progress, self.damage = 0.0, 0

    def _start_hook(self):
        """The faces of the ideal incision: the line swept at ``target_depth`` through the start state."""
        edges = [self._edge(np.array([x, self.size[1] - self.target_depth, self.line[2]])) for x in self.line[:2]]
        #: (R, 2) the element pairs of the ideal incision (the cut progress is the share of them cut)
        self.required_faces = blade_faces(self.model, self.state.positions, *edges)
        #: (R,) m the x of their shared faces' centres at rest (the route, ``IncisionWorlds.route``)
        self.required_x = face_centres(self.mesh.elements, self.mesh.nodes, self.required_faces)[:, 0]

    def _edge(self, tip):
        return np.stack([tip, tip + np.array([0.0, self.blade_length, 0.0])])

    def scripted_action(self) -> np.ndarray:
        """Above the line's start, plunge to the target depth (a plunge along the edge cuts nothing),
        then cut along the line to its end."""
        self._require_reset("scripted_action()")
        tip = self.tip_rest + self.tool_offset
        (start, end, z), depth_y = self.line, self.size[1] - self.target_depth
        at_start = abs(tip[0] - start) < 1e-6 and abs(tip[2] - z) < 1e-6
        if tip[1] <= depth_y + 1e-6 and (at_start or tip[0] > start):  # at depth: cut along the line
            goal = np.array([end + 0.5 * self.spacing[0], depth_y, z])
        elif at_start:  # plunge
            goal = np.array([start, depth_y, z])
        elif tip[1] < self.size[1] + 0.002:  # in the tissue off the line: up first
            goal = np.array([tip[0], self.size[1] + 0.002, tip[2]])
        else:  # above the surface, to the line's start
            goal = np.array([start, tip[1], z])
        return self._towards(goal, tip)

    def _extra_drawing(self):
        y = self.size[1]
        return [("segment", (np.array([self.line[0], y, self.line[2]]), np.array([self.line[1], y, self.line[2]])))]


class IncisionVectorEnv(TissueVectorEnv):
    """N copies of Incision-v0 stepped together (``tissue_env.vector``): built by
    ``gym.make_vec("tissue_env/Incision-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    Same keywords, spaces, rewards and infos as the single env (see ``IncisionEnv``); each copy is cut
    on its own."""

    env_class = IncisionEnv
