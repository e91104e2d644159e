"""Dissection-v0: free a flap of tissue from its bed by cutting the thin connective layer between them."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from sim_core.cutting import shared_faces
from sim_core.solvers.grasp import Grasper

from .base import TissueEnv, difficulty_settings, nonnegative_scalar, positive_scalar
from .camera import ALBEDO
from .cut_tasks import BladeTaskEnv, BladeTaskWorlds, difficulty_levels
from .retraction import GRASP_SLIP_FORCE, grasp_limit
from .vector import TissueVectorEnv

#: Element labels of the tissue layers (``DissectionEnv.labels``).
BED, CONNECTIVE, FLAP = 0, 1, 2


def layer_labels(centres, spacing, connective_layer, flap_layers):
    """(M,) the label of each element from its centre (M, 3) m: the label volume of the slab's element
    layers along y (``spacing`` (3,) m): ``BED`` below the connective layer (element layer index
    ``connective_layer``), ``CONNECTIVE`` in it, ``FLAP`` in the ``flap_layers`` above it, ``BED``
    above those (none on the default slab)."""
    layer = np.floor(centres[:, 1] / spacing[1]).astype(np.int64)
    mask = np.full(layer.max() + 1, BED)  # the label of each element layer: a mask along y
    mask[connective_layer] = CONNECTIVE
    mask[connective_layer + 1:connective_layer + 1 + flap_layers] = FLAP
    return mask[layer]


class DissectionWorlds(BladeTaskWorlds):
    """Dissection's step on N worlds (``tissue_env.worlds``, ``tissue_env.blade``, ``tissue_env.cut_tasks``):
    a blade the agent moves, and a grasper on the flap's free edge that peels the freed flap up (scripted)."""

    task_weights = ("height_weight", "damage_allowed")

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count = self.task, self.num_envs
        self._anchor_block = np.repeat(env.mesh.nodes[None], count, axis=0)  # a held node's place at closing
        self.grasper = Grasper(float(np.max(env.size)), env.grasp_force_limit)
        #: (N, rows) bool the node rows each world's grasper holds (a copy of a held node is held too)
        self.held = np.zeros(self.positions.shape[:2], dtype=bool)
        self.held_count = np.zeros(count, dtype=int)
        #: (N, 3) m the jaw's displacement from its rest (the peel, ``_peel``)
        self.jaw_offset = np.zeros((count, 3))
        self.tip_rest = np.zeros((count, 3))
        self.half_edge = np.array([0.0, 0.0, 0.5 * env.blade_length])
        self.labels = env.labels
        self.layer_y = np.array(env.layer_y)
        self.peel = np.array([-(1.0 - np.cos(env.peel_angle_rad)), np.sin(env.peel_angle_rad), 0.0])
        self.column_of = env.column_of  # (M,) the column (x index + nx * z index) of each element
        self.columns = env.columns  # (nx, nz)
        self.spacing_x = env.spacing[0]
        self._pairs = shared_faces(env.mesh)  # (P, 2) the block's element pairs that share a face
        self._pair_keys = self._pairs[:, 0] * self.n_elements_block + self._pairs[:, 1]
        self.freed = np.zeros((count, int(np.prod(self.columns))), dtype=bool)  # columns cut off the bed
        self.flap_damage = np.zeros(count, dtype=int)
        self.bed_damage = np.zeros(count, dtype=int)
        self.free = np.zeros(count, dtype=bool)
        #: (N, 3) m where each world's sweep starts (beside the free edge, at the layer's top at the
        #: episode's start, mid-slab), and the x its sweep ends at
        self.entry, self.sweep_end = np.tile(env.sweep_entry, (count, 1)), env.sweep_end

    def blade_edges(self, offsets):
        centre = self.tip_rest + offsets
        return np.stack([centre - self.half_edge, centre + self.half_edge], axis=1)

    def _load_task(self, index, env):
        super()._load_task(index, env)
        self._controls = None
        self.tip_rest[index] = env.tip_rest
        self.entry[index] = env.sweep_entry
        self.held[index] = False
        self.held[index, env.tool_nodes] = True
        self.held_count[index] = len(env.tool_nodes)
        self.jaw_offset[index] = 0.0
        self.freed[index] = False
        self.flap_damage[index] = self.bed_damage[index] = 0
        self.free[index] = False

    def _write_back_task(self, index, env):
        env.progress = float(self.progress[index])
        env.jaw_offset = self.jaw_offset[index].copy()
        env.free = bool(self.free[index])
        env.freed_length = float(self.freed_length()[index])

    def _tool_moved(self, previous, active):
        super()._tool_moved(previous, active)
        # the jaw peels the freed flap back: towards the place the free edge has when the flap turns
        # by the peel angle about the cut front, at most max_step a step (no jerk when a slice frees)
        goal = self.freed_length()[:, None] * self.peel
        step = np.clip(goal - self.jaw_offset, -self.max_step, self.max_step)
        self.jaw_offset = np.where(active[:, None], self.jaw_offset + step, self.jaw_offset)

    def freed_length(self):
        """(N,) m the length of flap freed from the grasped edge (x = L) in: the whole x slices of
        columns cut off, counted from the edge (column ``x index + nx * z index``)."""
        nx, nz = self.columns
        freed = self.freed.reshape(self.num_envs, nz, nx)[:, :, ::-1]
        return self.spacing_x * np.cumprod(freed, axis=2).sum(axis=2).min(axis=1)

    def cut_front(self):
        """(N,) m the x the sweep must pass to cut the next column still joined (``freed`` False): a
        quarter element past the centre, at rest, of the uncut column nearest the free edge (the blade
        cuts a column's connective face when it crosses the column's centre); the sweep's end once every
        column is cut."""
        nx, nz = self.columns
        uncut = ~self.freed.reshape(self.num_envs, nz, nx).all(axis=1)  # (N, nx): an x slice with a column joined
        slice_x = (np.arange(nx) + 0.5) * self.spacing_x
        front = np.where(uncut, slice_x, -np.inf).max(axis=1) - 0.25 * self.spacing_x
        return np.maximum(front, self.sweep_end)

    def route(self, offsets):
        """Over to beside the free edge at the layer's top (``entry``), then along x through the layer
        to the sweep's end. The route's point nearest the blade lies on the sweep between the entry and
        the cut front (``cut_front``): a blade within that stretch counts as on the sweep, its distance
        from the layer's top and from mid-slab in z added; a blade past the front, the front still
        joined (it strayed from the layer's top or in z), has the way back to the front added, so the
        route pulls it back to what is left to cut. Continuous in the blade's place; a cut moves the
        front only past a blade that cut it. The next point is the cut front's (at the layer's top, mid-slab):
        what is left to cut."""
        centre = self.tip_rest + offsets
        entry, front = self.entry, self.cut_front()
        along = np.clip(centre[:, 0], front, entry[:, 0])
        point = np.column_stack([along, entry[:, 1:]])
        remaining = np.abs(centre - point).sum(axis=1) + along - self.sweep_end
        target = np.column_stack([np.minimum(front, entry[:, 0]), entry[:, 1:]])
        return remaining, np.where((centre[:, 0] > entry[:, 0])[:, None], entry, target)

    def _cut_made(self, index, faces):
        first, second = self.labels[faces[:, 0]], self.labels[faces[:, 1]]
        # a face between the connective layer and the flap or the bed frees its column
        opened = (first == CONNECTIVE) != (second == CONNECTIVE)
        connective = np.where(first[opened] == CONNECTIVE, faces[opened, 0], faces[opened, 1])
        self.freed[index, self.column_of[connective]] = True
        flap = int(np.count_nonzero((first == FLAP) & (second == FLAP)))
        bed = int(np.count_nonzero((first == BED) & (second == BED)))
        self.flap_damage[index] += flap
        self.bed_damage[index] += bed
        super()._cut_made(index, faces, float(self.freed[index].mean()), flap + bed)
        self.free[index] = self._flap_free(index)
        # a copy of a held node is held as its original
        padded = np.concatenate([self.held[index, :self.n_nodes], [False]])
        self.held[index] = padded[self.node_origin[index]]

    def _flap_free(self, index):
        """Whether no path of uncut faces joins a flap element to a bed element in world ``index``."""
        done = np.concatenate(self.cuts[index])
        pairs = self._pairs[~np.isin(self._pair_keys, done[:, 0] * self.n_elements_block + done[:, 1])]
        size = self.n_elements_block
        graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(size, size))
        component = connected_components(graph, directed=False)[1]
        return not np.intersect1d(component[self.labels == FLAP], component[self.labels == BED]).size

    def _control(self, rows=None):
        """The attached bottom, and the grasped free edge at the jaw's displacement from where it
        closed (``Grasper.control``), on each world's node rows; the blade imposes nothing."""
        if self._controls is None:
            self._controls = (self.node_rows(self._block_fixed, False), self.node_rows(self._block_target, 0.0),
                              self.node_rows(self._anchor_block, 0.0))
        fixed, target, anchors = self._controls
        fixed, target = self.grasper.control(fixed, target, self.held, anchors, self.jaw_offset)
        return fixed, target, np.repeat(self.held[..., None], 3, axis=2)

    def _measure(self, tool_mask):
        """The measurements, and the grasp judged at them (``Grasper.slip`` at ``grasp_force_limit``):
        the tool's force is the grasper's on the nodes still held."""
        measures = super()._measure(tool_mask)
        forces = measures["forces"]
        self.held = self.grasper.slip(forces, self.held)
        measures["reaction_force"] = self.grasper.force(forces, self.held)
        return measures

    def _record(self, measures, rows, fresh):
        measures["grasped_nodes"] = self.held.sum(axis=1)

    def _grasped(self, measures):
        return measures["grasped_nodes"][:, None] > 0

    def _task_measures(self, positions):
        measures = super()._task_measures(positions)
        # from the layer's top at the start: midway between the layer's and the flap's centroids, the
        # height that cuts the layer off the flap with the most margin (its middle is on the layer's centroids)
        measures["height_error"] = (self.tip_rest + self.tool_offset)[:, 1] - self.entry[:, 1]
        return measures

    def _blade_task_features(self, measures):
        scale = self.length_scale
        layer = np.broadcast_to((self.layer_y - self.centre[1]) / scale, (self.num_envs, 2))
        return dict(layer=layer, height_error=measures["height_error"][:, None] / scale,
                    freed_length=self.freed_length()[:, None] / scale, jaw_displacement=self.jaw_offset / scale)

    def step(self, actions, active):
        """Every task's step; a world whose flap is free ends its episode, a success or not (with more
        than ``damage_allowed`` flap or bed faces cut): nothing is left to cut, and the flap would
        hang from the grasper alone."""
        observations, rewards, terminated, infos = super().step(actions, active)
        return observations, rewards, terminated | (self.free & np.asarray(active, dtype=bool)), infos

    def _is_success(self, measures):
        return self.free & (self.damage <= self.damage_allowed)

    def _task_reward_terms(self, measures):
        return dict(height=-self.height_weight * np.abs(measures["height_error"]) / self.length_scale)

    def _task_info(self, measures):
        info = super()._task_info(measures)
        info.update(flap_damage=self.flap_damage.copy(),
                    bed_damage=self.bed_damage.copy(), flap_free=self.free.copy(),
                    grasped_nodes=measures["grasped_nodes"].copy(), jaw_displacement=self.jaw_offset.copy(),
                    height_error=np.array(measures["height_error"], dtype=float))
        return info

    def _scene_extras(self):
        """The blade (a thin horizontal quad along z, in the tool's colour): what a surgeon sees."""
        count = self.num_envs
        (start, end) = np.moveaxis(self.blade_edges(self.tool_offset), 1, 0)
        side = np.array([0.0015, 0.0, 0.0])
        vertices = np.stack([start - side, start + side, end + side, end - side], axis=1).reshape(count, 4, 3)
        triangles = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
        return vertices, triangles, np.tile(ALBEDO["tool"], (4, 1))


class DissectionEnv(BladeTaskEnv, TissueEnv):
    """
    ## Description

    A flap of tissue (the top 1 cm of a 5 x 2 x 3 cm slab, 10 x 4 x 6 hexahedra of 5 mm, Baudet's
    mass-spring model of ``sim_core`` with hourglass control and volume forces; gravity on) is joined
    to its bed (the bottom 5 mm, attached to the body along y = 0) by a thin connective layer (one
    element layer, 5 to 10 mm up, ``connective_stiffness_ratio`` times as stiff: loose areolar
    tissue). The elements carry labels (``labels``: bed, connective, flap; a label mask along y, as
    the other tasks label a vessel layer or a tumour). The agent moves a scalpel blade (a straight
    horizontal cutting edge ``blade_length`` long along z, centred on the tool) and must free the
    flap by cutting through the connective layer, without cutting the flap or the bed.

    A grasper (``sim_core.solvers.grasp.Grasper``, as in Retraction-v0) holds the flap's free edge
    (the nodes of its end face x = 5 cm above the connective layer) and peels it (a scripted
    assistant): as whole slices of the flap are freed from the free edge in, the jaw moves the edge to
    where it would be had the freed length turned by ``peel_angle`` (default 30 deg) about the cut
    front, at most ``max_step`` a step. So the layer opens as it is cut and the freed flap is held
    clear of its bed: the cut surfaces carry no contact (nothing stops one from passing through the
    other), and the peel keeps them apart. A flap cut free far from the grasped edge first rests on
    its cut surface until the cut reaches the grasped edge (it sags into it by the flap's own
    deflection; a contact between the cut sides is not modelled). Measured on the scripted dissection
    (tests/test_env_dissection.py): with the peel the cut stays open by more than 0.5 mm at every freed
    node until the flap is free; with the edge held at rest (``peel_angle=0``) the freed flap sinks
    into the layer it was cut from by over 1 mm. The episode ends at the step that frees the flap: in
    that step the flap's far end, no longer held, starts to fall (by about 4 mm on the default slab);
    what would follow, the flap hanging from the grasper alone, is not part of the task. ``docs/figures/dissection.png``
    (``python -m benchmarks.dissection_figure``) shows the cut open behind the blade as the grasper
    peels the flap, and the agent's rgb view. The grasp holds up to
    ``grasp_force_limit`` (default 5 N, Retraction's); past it the edge slips out of the jaws.

    The blade cuts as Incision-v0's (``tissue_env.blade``, ``sim_core.cutting``): when it moves in a
    step, its edge sweeps a surface, and each pair of elements whose centroid-to-centroid segment
    crosses it is separated along their shared face (nodes copied, the model rebuilt), before the
    step's physics. Moved horizontally at the connective layer's height, it separates the layer from
    the flap above (between the centroids of the two, 7.5 to 12.5 mm up) or from the bed below (2.5
    to 7.5 mm up); higher it cuts the flap (12.5 to 17.5 mm), and moved vertically through the tissue
    it cuts the elements beside each other. The blade exerts no force.

    Physics: one implicit Euler step of ``dt`` = 20 ms per env step; a cut world is stepped on its
    own cut model, with ``spare_nodes`` node rows for the copies (by default two whole layers of
    nodes); a cut that would need more is refused (``info["cut_refused"]``).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: the blade centre's displacement increment along x, y and z (entries
    0, 1, 2, each in [-1, 1]), scaled by ``max_step`` (default 2.5 mm, half an element), clipped to
    the workspace (x from -5 mm to 1 cm past the free edge, y from 0 to 1 cm above the slab, z across
    the slab). The grasper is not commanded.

    ## Observation Space

    ``observation_type="state"``: ``Box(-100, 100, (23,), float32)``, the maximum spring strain within
    +-1000, every other entry within +-100.

    | Index | Observation                                              | Unit (normalised)    |
    |-------|----------------------------------------------------------|----------------------|
    | 0-2   | blade centre position                                    | cm from slab centre  |
    | 3-5   | blade displacement from its start                        | cm                   |
    | 6-8   | force the grasper exerts on the flap                     | 0.1 N x E / 5 kPa    |
    | 9     | relative volume change (V - V0) / V0                     | %                    |
    | 10    | maximum spring strain abs(L - L0) / L0                   | %                    |
    | 11-12 | the connective layer's bottom and top (y) at rest        | cm from slab centre  |
    | 13    | blade height above the layer's top at the start          | cm                   |
    | 14    | flap length freed from the grasped edge                  | cm                   |
    | 15-17 | the jaw's displacement (the peel)                        | cm                   |
    | 18    | cut progress: the share of the layer's columns cut off   | 0-1                  |
    | 19    | flap and bed faces cut so far                            | faces                |
    | 20-22 | the next point to cut at (the entry, then the cut front) | cm from the blade   |

    ``"deformation"`` appends the surface-node
    displacements (cm); ``"dict"`` gives the features as a ``Dict`` keyed by name; the visual
    observations show the tissue (each side of a cut apart) and the blade. No ``"goal"`` observation
    (the outcome is the set of faces cut, not a state to relabel).

    ## Rewards

    ``r = reward_progress + reward_approach + reward_height + reward_damage + reward_success +
    reward_volume + reward_strain (+ reward_instability)``:

    - ``reward_progress = progress_weight * (gain in cut progress this step)`` (default 10); the
      progress is the share of the connective layer's columns (its elements) separated from the flap
      or from the bed;
    - ``reward_approach = approach_weight * (R_before - R_after) / 1 cm`` (default 1), R the length
      (L1, m) of what remains of the route: over to beside the free edge at the layer's top, mid-slab
      in z (``sweep_entry``), then along x through the layer to a quarter element past the far end,
      with the blade's distance from the layer's top and from mid-slab in z, and, for a blade past the
      cut front (a quarter element past the centre of the uncut column nearest the free edge: it
      strayed and left a column joined), the way back to it (``info["route_remaining"]``; continuous
      in the blade's place): potential-based shaping
      (``tissue_env.cut_tasks``; it sums to the route's net shortening, 6.0-6.4 on the scripted
      dissection), which lets an agent learn the approach before its first cut;
    - ``reward_height = -height_weight * |blade height - the layer's top| / 1 cm`` (default 1): the
      layer's top is midway between the mean heights of the layer's and the flap's centroids in the
      start equilibrium (a soft slab sags under its weight), where a horizontal sweep cuts the layer
      off the flap with the most margin;
    - ``reward_damage = -damage_weight * (flap or bed faces cut this step)`` (default 2): a face
      between two flap elements or two bed elements;
    - ``reward_success = success_bonus`` (default 5) on success: the flap free with at most
      ``damage_allowed`` flap or bed faces cut;
    - ``reward_volume``, ``reward_strain`` as in every task, ``reward_instability`` on divergence.

    ## Info

    Every task's keys; ``tool_forces`` (1, 3) N is the tissue's force on the grasper (the tool that
    exerts force: the blade exerts none) and ``grasped`` (1,) whether it holds any node. The blade's
    cut report: ``faces_cut`` (this step), ``cut_faces`` (all), ``cut_length`` (m), ``cut_deviation``
    (m), ``element_quality``, ``cut_refused``; and ``cut_progress``, ``flap_damage``, ``bed_damage``
    (faces), ``flap_free`` (no uncut face joins a flap element to a bed element, through any chain of
    elements), ``grasped_nodes``, ``jaw_displacement`` (m), ``height_error`` (m), ``route_remaining`` (m).

    ## Starting State

    The slab at its static equilibrium under gravity, the free edge held at rest; the blade's centre
    beside the free edge, drawn in ``blade_start_range`` (default x 5.3-5.8 cm, y 1.2-1.6 cm, z
    1-2 cm: beside the flap, 2 to 6 mm above the layer's top).

    ## Episode End

    Terminated when the flap is free (a success with at most ``damage_allowed`` flap or bed faces
    cut, default 2; a freed flap ends the episode either way, also with ``terminate_on_success=False``:
    nothing is left to cut) or on divergence (``info["unstable"]``). Truncated after 60 steps.

    ## Difficulty

    ``difficulty="easy" | "default" | "hard"`` sets ``damage_allowed`` from ``DissectionEnv.DIFFICULTY``
    (6, 2, 0 flap or bed faces; a keyword passed explicitly overrides its level's value).

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/Dissection-v0", connective_stiffness_ratio=0.5, peel_angle=30.0)
    ```

    Vectorised: ``gym.make_vec("tissue_env/Dissection-v0", num_envs=16, vectorization_mode="vector_entry_point")``
    (``DissectionVectorEnv``, same keywords, spaces, rewards and infos; each copy cut on its own).

    Task keywords: ``connective_layer`` (the element layer index, from the bottom, of the connective
    layer; default 1), ``flap_layers`` (element layers of the flap above it; default 2),
    ``connective_stiffness_ratio``, ``blade_length`` (m), ``blade_start_range`` ((low, high) corners
    in m), ``peel_angle`` (deg, in [0, 90]), ``grasp_force_limit`` (N), ``progress_weight``,
    ``approach_weight``, ``height_weight``, ``damage_weight``, ``success_bonus``, ``damage_allowed`` (faces), ``difficulty``,
    ``spare_nodes``; shared keywords in
    ``tissue_env.base.TissueEnv``. Domain randomisation: ``young_modulus_range``,
    ``poisson_ratio_range``, ``density_range``; ``blade_start_range`` places the blade. No
    ``size_range``.

    ## Version History

    - v0: the first version.
    """

    worlds_class = DissectionWorlds
    min_shape = (2, 3, 1)
    reward_names = ("progress", "approach", "height", "damage", "success", "volume", "strain")
    episode_keywords = ("blade_start_range",)
    task_features = dict(layer=2, height_error=1, freed_length=1, jaw_displacement=3)
    layer_ratio_keyword = "connective_stiffness_ratio"
    #: The difficulty levels' keywords (``difficulty``; keywords passed explicitly override them): the
    #: flap or bed faces a success may have cut.
    DIFFICULTY = difficulty_levels("damage_allowed", 6, 2, 0)
    summary = "free a flap from its bed by cutting the connective layer between them, a grasper peeling it"
    success_summary = "no uncut face joins the flap to the bed, at most {damage_allowed} flap or bed faces cut"

    def __init__(self, *, connective_layer=1, flap_layers=2, connective_stiffness_ratio=0.5, blade_length=0.04,
                 blade_start_range=((0.053, 0.012, 0.01), (0.058, 0.016, 0.02)), peel_angle=30.0,
                 grasp_force_limit=GRASP_SLIP_FORCE, progress_weight=None, approach_weight=None, height_weight=1.0,
                 damage_weight=None, success_bonus=None, damage_allowed=None, spare_nodes=None, difficulty="default",
                 **kwargs):
        damage_allowed = difficulty_settings(self.DIFFICULTY, difficulty,
                                             dict(damage_allowed=damage_allowed))["damage_allowed"]
        if isinstance(damage_allowed, bool) or not isinstance(damage_allowed, (int, np.integer)) or damage_allowed < 0:
            raise ValueError(f"damage_allowed must be an integer >= 0 (flap or bed faces), got {damage_allowed!r}")
        self.damage_allowed = int(damage_allowed)
        for name, value in (("connective_layer", connective_layer), ("flap_layers", flap_layers)):
            number = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
            if not number or value < 1:  # connective_layer >= 1: a bed layer under it
                raise ValueError(f"{name} must be an integer >= 1 (element layers), got {value!r}")
        self.connective_layer, self.flap_layers = int(connective_layer), int(flap_layers)
        self.connective_stiffness_ratio = positive_scalar("connective_stiffness_ratio", connective_stiffness_ratio)
        self.blade_length = positive_scalar("blade_length", blade_length, "m")
        try:
            low, high = (np.asarray(corner, dtype=float) for corner in blade_start_range)
        except (TypeError, ValueError) as error:
            raise ValueError(f"blade_start_range must be two (x, y, z) corners in m, got {blade_start_range!r}") \
                from error
        if low.shape != (3,) or high.shape != (3,) or not (np.all(np.isfinite(low)) and np.all(low <= high)):
            raise ValueError(f"blade_start_range must be two finite (x, y, z) corners in m with low <= high, got "
                             f"{blade_start_range!r}")
        self.blade_start_range = (low, high)
        self.peel_angle = nonnegative_scalar("peel_angle", peel_angle)
        if self.peel_angle > 90:
            raise ValueError(f"peel_angle must lie in [0, 90] deg, got {peel_angle!r}")
        self.peel_angle_rad = np.deg2rad(self.peel_angle)
        self.grasp_force_limit = grasp_limit(grasp_force_limit)
        self._blade_keywords(dict(progress_weight=progress_weight, approach_weight=approach_weight,
                                  height_weight=height_weight, damage_weight=damage_weight,
                                  success_bonus=success_bonus), spare_nodes)
        super().__init__(difficulty=difficulty, **kwargs)

    # -- scene ---------------------------------------------------------------------------------------
    def _setup_scene(self):
        nodes, size, spacing = self.mesh.nodes, self.size, self.spacing
        layers = self.shape[1]
        if self.connective_layer + self.flap_layers >= layers:
            raise ValueError(f"connective_layer ({self.connective_layer}) + flap_layers ({self.flap_layers}) must "
                             f"leave a bed layer under them and fit in the slab's {layers} element layers along y")
        # two whole layers of nodes
        self._spare_rows(2 * (self.shape[0] + 1) * (self.shape[2] + 1))
        centres = nodes[self.mesh.elements].mean(axis=1)
        #: (M,) the label of each element: BED, CONNECTIVE or FLAP
        self.labels = layer_labels(centres, spacing, self.connective_layer, self.flap_layers)
        self.layer_elements = self.labels == CONNECTIVE
        #: (2,) m the connective layer's bottom and top at rest
        self.layer_y = (self.connective_layer * spacing[1], (self.connective_layer + 1) * spacing[1])
        self.columns = (self.shape[0], self.shape[2])
        index = np.floor(centres / spacing).astype(np.int64)
        self.column_of = index[:, 0] + self.shape[0] * index[:, 2]
        self.fixed_nodes = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))
        # the grasper holds the free edge's end face above the connective layer (never on the cut)
        self.tool_nodes = np.flatnonzero(np.isclose(nodes[:, 0], size[0]) & (nodes[:, 1] > self.layer_y[1] + 1e-9)
                                         & (nodes[:, 1] <= (self.layer_y[1] + self.flap_layers * spacing[1]) + 1e-9))
        self.tip_rest = self.blade_start_range[0].copy()
        self._layer_of = index[:, 1]  # (M,) each element's layer along y
        self.sweep_entry = np.array([size[0] + 0.25 * spacing[0], self.layer_y[1], 0.5 * size[2]])
        self.sweep_end = -0.25 * spacing[0]  # m, the x the sweep goes to: past the slab's far end
        self._place_scene(nodes)

    def _place_scene(self, nodes):
        super()._place_scene(nodes)
        self._workspace()

    def _workspace(self):
        size = self.size
        self.workspace_low = np.array([-0.005, 0.0, 0.0]) - self.tip_rest
        self.workspace_high = np.array([size[0] + 0.01, size[1] + 0.01, size[2]]) - self.tip_rest

    camera_target = (0.5, 0.5, 0.5)
    camera_direction = (0.35, 0.6, 1.0)
    camera_distance = 1.9

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        low, high = self.blade_start_range
        self.tip_rest = self.np_random.uniform(low, high)
        self._workspace()
        self.progress, self.free, self.freed_length = 0.0, False, 0.0
        self.jaw_offset = np.zeros(3)

    def _start_hook(self):
        """Where the sweep starts (``sweep_entry``, (3,) m): beside the free edge, mid-slab in z, at the
        layer's top at the episode's start (midway between the mean heights of the layer's and the flap's
        first layer's centroids in the start equilibrium: it separates the layer from the flap with the
        most margin; a soft slab sags under its weight: by 1.1 mm at E = 1 kPa and nu = 0.3, 0.2 mm at
        the defaults)."""
        centres = self.state.positions[self.mesh.elements].mean(axis=1)[:, 1]
        layer = self.connective_layer
        top = 0.5 * (centres[self._layer_of == layer].mean() + centres[self._layer_of == layer + 1].mean())
        self.sweep_entry = np.array([self.size[0] + 0.25 * self.spacing[0], top, 0.5 * self.size[2]])

    def scripted_action(self) -> np.ndarray:
        """Beside the free edge, down to the connective layer's top (midway between the layer's and the
        flap's centroids: it separates the layer from the flap), at the slab's middle in z; then along
        x through the whole layer, from the grasped edge in (the grasper peels what is cut). If the
        flap still holds at the sweep's end (a soft flap the peel lifts slides over the blade: at
        E = 1 kPa the last slice's segment from the layer's centroid to the flap's crossed the blade's
        height at x = 3.3 mm and two steps later at 4.0 mm, so the move from 3.75 to 1.25 mm missed
        it), the blade steps aside by ``max_step`` in z (along its edge: it cuts nothing), sweeps back
        to 0.2 elements past the cut front (at nu = 0.3 the held slice's segment crossed 0.1 element
        past it; no further: the freed flap's corners sag into the cut behind it, and sweeps back to
        0.4 or 1 element past the front cut 4 of its faces at nu = 0.45) and forth again.
        From elsewhere in the slab: up above it, then over to beside the free edge."""
        self._require_reset("scripted_action()")
        tip = self.tip_rest + self.tool_offset
        entry, clear = self.sweep_entry, self.size[1] + 0.002
        at_height = abs(tip[1] - entry[1]) < 1e-6
        if at_height and tip[0] < entry[0] + 1e-6:  # the sweep; the blade's z says which way
            aside = entry[2] + self.max_step
            if abs(tip[2] - aside) < 1e-6:  # back along the cut, to 0.2 elements past the cut front
                back = min(self.size[0] - self.freed_length + 0.2 * self.spacing[0], entry[0])
                goal = np.array([back, entry[1], aside if tip[0] < back - 1e-6 else entry[2]])
            elif tip[0] > self.sweep_end + 1e-6 or abs(tip[2] - entry[2]) > 1e-6:  # forth (or back to mid-slab)
                goal = np.array([self.sweep_end, entry[1], entry[2]])
            else:  # at the sweep's end with the flap held: aside, to sweep back
                goal = np.array([tip[0], entry[1], aside])
        elif tip[0] < entry[0] - 1e-6 and tip[1] < clear - 1e-6:  # in the slab off the sweep: up first
            goal = np.array([tip[0], clear, tip[2]])
        elif tip[0] < entry[0] - 1e-6:  # above the slab: over to beside the free edge
            goal = np.array([entry[0], tip[1], entry[2]])
        else:  # beside the free edge: down to the layer
            goal = entry
        return self._towards(goal, tip)


class DissectionVectorEnv(TissueVectorEnv):
    """N copies of Dissection-v0 stepped together (``tissue_env.vector``): built by
    ``gym.make_vec("tissue_env/Dissection-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    Same keywords, spaces, rewards and infos as the single env (see ``DissectionEnv``); each copy is cut
    on its own."""

    env_class = DissectionEnv
