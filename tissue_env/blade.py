"""Cutting from a tool: a blade that separates the faces it sweeps through, in every world.

``CuttingWorlds`` is the ``TaskWorlds`` of a task whose tool is a blade: its cutting edge is a
segment (``blade_edges``, placed by the tool's offset), and when the tool moves in a step the edge
sweeps the surface between its old and new places. Before the step's physics, each world whose
blade moved is cut along the shared faces that surface crosses (``sim_core.cutting.blade_faces``
at the world's current positions, ``sim_core.cutting.cut_world``): the cut follows faces (no
slivers, no element lost), stays within about half an element of the swept surface, and carries the
state across (each copied node starts at its original's position and velocity: the cut itself adds
no energy). Each world is cut on its own; the single env is the one-world case of the same code.

A cut world holds a model of its own topology in the ``ModelStack`` (its copied nodes in the spare
node rows, ``TissueEnv.spare_nodes``) and is stepped on it; its measurements (spring strains,
element volumes, nodal forces) are taken on its own model. A reset gives the world the uncut model
back (``TaskWorlds.load``): nothing of the cut stays, and no process restart is needed. A snapshot
(``get_state``) holds the faces cut (the model is cut again along them at a restore: the same floats)
and the cut world's solver state (``tissue_env.snapshots``); a deepcopy or pickle of the env holds
everything as it is.

``info`` (per world): ``faces_cut`` (faces cut this step), ``cut_faces`` (all so far),
``cut_length`` (m, the blade tip's travel in the steps that cut), ``cut_deviation`` (m, the largest
distance of a face cut this step from the surface the blade swept: at most about half an element),
``element_quality`` (the smallest element volume over its rest volume: 1 undeformed, 0 collapsed;
a cut makes no new element) and ``cut_refused`` (a cut that would need more node rows than the
spare ones: nothing is cut that step). SI units.
"""

from __future__ import annotations

import numpy as np

from sim_core import kernels
from sim_core.cutting import blade_faces, cut_world, element_faces, separation
from sim_core.models.forces import ForceWorkspace
from sim_core.models.model import State

from .camera import CameraView
from .worlds import TaskWorlds


def corner_surface(mesh):
    """(faces (F, k) indices of element corners, rest corner positions (M * c, 3) m): the mesh's
    boundary faces (faces of one element) on the element corners (corner ``e * c + local`` of
    element ``e`` with ``c`` corners) instead of the nodes, so that a camera draws each side of a
    cut apart (a cut world's corners are its elements' nodes, ``CuttingWorlds.corner_positions``)."""
    faces = element_faces(mesh)  # (M, f, k)
    count, per, size = faces.shape
    corners = mesh.elements.shape[1]
    keys = np.sort(faces.reshape(count * per, size), axis=1)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    boundary = counts[inverse.ravel()] == 1
    local = np.broadcast_to(element_local_faces(mesh)[None], (count, per, size)).reshape(count * per, size)
    element = np.repeat(np.arange(count), per)
    slots = element[:, None] * corners + local
    return slots[boundary], mesh.nodes[mesh.elements].reshape(-1, 3)


def corner_view(view, mesh):
    """The ``CameraView`` ``view`` (a task's base camera) on the element corners of ``mesh``
    (``corner_surface``), so that each side of a cut is drawn apart."""
    faces, corners = corner_surface(mesh)
    return CameraView(view.camera, faces, corners, [], view.point_count, view.point_normals, view.bounds)


class CornerCamera:
    """Mixin of a cutting task's env (before ``TissueEnv`` in its bases): its camera draws the
    elements' corners (``corner_view``), so that each side of a cut is drawn apart."""

    def _camera_setup(self, image_size, camera, point_count, point_normals):
        return corner_view(super()._camera_setup(image_size, camera, point_count, point_normals), self.mesh)


def spare_node_rows(value, default) -> int:
    """The ``spare_nodes`` keyword (node rows per world for a cut's copies) as an int, ``default`` for
    None; ValueError unless an integer >= 0."""
    value = default if value is None else value
    if isinstance(value, bool) or not float(value).is_integer() or value < 0:
        raise ValueError(f"spare_nodes must be an integer >= 0 (node rows per world), got {value!r}")
    return int(value)


def element_local_faces(mesh):
    """(f, k) the local corners of an element's faces (those ``element_faces`` indexes)."""
    sample = mesh.elements[:1]
    faces = element_faces(type(mesh)(mesh.nodes, sample))[0]
    return np.argmax(faces[:, :, None] == sample[0][None, None, :], axis=2)


def _segment_distance(points, start, end):
    """(P,) the distance of ``points`` (P, 3) from the segment start -> end (3,), m."""
    direction = end - start
    length = float(direction @ direction)
    t = np.clip((points - start) @ direction / length, 0.0, 1.0) if length > 0 else np.zeros(len(points))
    return np.linalg.norm(points - (start + t[:, None] * direction), axis=1)


def triangle_distance(points, a, b, c):
    """(P,) the distance of ``points`` (P, 3) from the triangle (a, b, c) (each (3,)), m."""
    edges = np.minimum.reduce([_segment_distance(points, a, b), _segment_distance(points, b, c),
                               _segment_distance(points, c, a)])
    normal = np.cross(b - a, c - a)
    area = np.linalg.norm(normal)
    if area == 0.0:  # a degenerate triangle: its edges
        return edges
    normal = normal / area
    height = (points - a) @ normal
    foot = points - height[:, None] * normal
    inside = np.ones(len(points), dtype=bool)
    for p, q in ((a, b), (b, c), (c, a)):
        inside &= np.cross(q - p, foot - p) @ normal >= 0.0
    return np.where(inside, np.abs(height), edges)


def face_centres(elements, positions, faces):
    """(F, 3) the centroid, m, of the face each pair of ``faces`` (F, 2) shares: the mean of its
    nodes (the corners the two elements of ``elements`` (M, k) have in common) at ``positions``."""
    first, second = elements[faces[:, 0]], elements[faces[:, 1]]
    shared = np.any(first[:, :, None] == second[:, None, :], axis=2)  # (F, k): a's corners on the face
    return (positions[first] * shared[..., None]).sum(axis=1) / shared.sum(axis=1)[:, None]


class CuttingWorlds(TaskWorlds):
    """The worlds of a task whose tool is a blade (see the module docstring). A task implements
    ``blade_edges``; its ``_load_task``, ``_task_info`` and ``_control`` extend this class's
    (``node_origin`` maps a cut world's node rows to the block's nodes, for the controls)."""

    # A world's factor is renewed once its iterations beyond those right after its last
    # factorisation add up to more than 3 (``ImplicitEuler``'s ``amortise``): a cut frees tissue that
    # moves (Incision's slit settling, Dissection's flap), a factor made during that motion keeps
    # costing iterations (it does not recover as the tissue rests), and the excess persists step
    # after step, so renewing early costs the least: iterations x an iteration's time + renewals x a
    # refactorisation's, counted over the steps after the cut (benchmarks/cutting.py's solver_costs)
    refactor_amortise = 3

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        count, env = self.num_envs, self.task
        #: (N, M, k) each world's elements (its nodes: a cut world's own numbering)
        self.elements = np.repeat(env.mesh.elements[None], count, axis=0)
        self.n_elements_block = env.mesh.n_elements
        #: (N, rows) the block node each node row comes from (a parked row: the block's node count,
        #: a row past the block's arrays that ``node_rows`` fills)
        self.node_origin = np.tile(self._parked_origin(), (count, 1))
        #: each world's cuts this episode: a list of (F, 2) element pairs per cutting step
        self.cuts = [[] for _ in range(count)]
        self.faces_cut = np.zeros(count, dtype=int)
        self.cut_faces = np.zeros(count, dtype=int)
        self.cut_length = np.zeros(count)
        self.cut_deviation = np.zeros(count)
        self.cut_refused = np.zeros(count, dtype=bool)
        self._force_workspaces = {}  # world -> the force workspace of its cut model (``_force_workspace``)

    def _parked_origin(self):
        origin = np.full(self.stack.n_nodes, self.n_nodes, dtype=np.int64)
        origin[:self.n_nodes] = np.arange(self.n_nodes)
        return origin

    def blade_edges(self, offsets) -> np.ndarray:
        """(N, 2, 3) the blade's cutting edge (its two ends, m) of each world at tool offsets (N, 3) m."""
        raise NotImplementedError

    def node_rows(self, values, fill):
        """(N, rows, ...) the block's per-node ``values`` (N, n, ...) on each world's node rows: a copied
        node takes its original's value, a parked row ``fill``."""
        values = np.asarray(values)
        padded = np.concatenate([values, np.broadcast_to(np.asarray(fill, dtype=values.dtype),
                                                         (len(values), 1) + values.shape[2:])], axis=1)
        return padded[np.arange(len(values))[:, None], self.node_origin]

    def _load_task(self, index, env):
        self.elements[index] = env.model.mesh.elements
        self.node_origin[index] = self._parked_origin()
        self.cuts[index] = []
        self.faces_cut[index] = self.cut_faces[index] = 0
        self.cut_length[index] = self.cut_deviation[index] = 0.0
        self.cut_refused[index] = False
        self._force_workspaces.pop(index, None)

    def restored(self, index):
        if self.cuts[index]:  # the snapshot's cut model: its uncut model cut along the same faces (the same floats)
            self.stack.assign(index, separation(self.envs[index].model, np.concatenate(self.cuts[index])).model)

    # -- the cut -------------------------------------------------------------------------------------
    def _tool_moved(self, previous, active):
        self.faces_cut[active] = 0
        self.cut_deviation[active] = 0.0
        self.cut_refused[active] = False
        start, end = self.blade_edges(previous), self.blade_edges(self.tool_offset)
        moved = active & np.any(start != end, axis=(1, 2))
        for index in np.flatnonzero(moved):  # each world's cut is its own (a few faces)
            self._cut(index, start[index], end[index])

    def _cut(self, index, edge_from, edge_to):
        model = self.stack.given[index]
        positions = self.positions[index, :model.n_nodes]
        faces = blade_faces(model, positions, edge_from, edge_to)
        if len(faces) and self.cuts[index]:  # a face cut before that copied no node is still shared: not again
            done = np.concatenate(self.cuts[index])
            size = self.n_elements_block
            faces = faces[~np.isin(faces[:, 0] * size + faces[:, 1], done[:, 0] * size + done[:, 1])]
        if not len(faces):
            return
        centres = face_centres(model.mesh.elements, positions, faces)
        every = np.concatenate(self.cuts[index] + [faces])  # the union: a crack one element wide copies no node
        try:
            cut = cut_world(self.stack, State(self.positions, self.velocities), index, every, self.integrator,
                            uncut=self.envs[index].model)
        except ValueError as error:
            if "spare_nodes" not in str(error):
                raise
            self.cut_refused[index] = True  # out of node rows: the world stays as it was
            return
        if cut.model is not self.envs[index].model:
            self.elements[index] = cut.model.mesh.elements
            self.node_origin[index, :cut.model.n_nodes] = cut.origin  # the uncut model's nodes are the block's
        self.cuts[index].append(faces)
        self.faces_cut[index] = len(faces)
        self.cut_faces[index] += len(faces)
        self.cut_length[index] += float(np.linalg.norm(edge_to[0] - edge_from[0]))
        (a, b), (a_to, b_to) = edge_from, edge_to
        self.cut_deviation[index] = float(np.minimum(triangle_distance(centres, a, b, b_to),
                                                     triangle_distance(centres, a, b_to, a_to)).max())
        self._cut_made(index, faces)

    def _cut_made(self, index, faces):
        """World ``index`` was cut along ``faces`` (F, 2) this step (task bookkeeping)."""

    # -- measurements on a cut world's own model ------------------------------------------------------
    def _measure(self, tool_mask):
        measures = super()._measure(tool_mask)
        forces, reaction = measures["forces"], measures["reaction_force"]
        for index in np.flatnonzero(~self.stack.shared):
            model = self.stack.given[index]
            rows, one = model.n_nodes, slice(index, index + 1)
            positions = np.ascontiguousarray(self.positions[index, :rows])
            with np.errstate(all="ignore"):
                forces[index, rows:] = 0.0
                np.add(self._force_workspace(index, model).compute(
                    positions, np.ascontiguousarray(self.velocities[index, :rows])),
                    model.gravity_force.reshape(-1, 3), out=forces[index, :rows])
                kernels.masked_reaction(forces[one], tool_mask[one], reaction[one])  # as the stacked worlds'
                length = np.empty(len(model.springs))
                kernels.spring_lengths(positions, model.springs, length)
                measures["max_strain"][index] = np.max(np.abs(length / model.rest_length - 1.0))
                ratio = model.mesh.element_volumes(positions) / model.rest_volume
                volume = float((ratio * model.rest_volume).sum())
            measures["relative_volume_change"][index] = (volume - self.rest_volume[index]) / self.rest_volume[index]
            measures["volume_ratio_low"][index], measures["volume_ratio_high"][index] = ratio.min(), ratio.max()
        return measures

    def _force_workspace(self, index, model):
        """World ``index``'s force workspace on its cut ``model``, kept while it holds that model (here,
        not in the model's derived data: a workspace refers to its model, and the cycle would keep every
        cut model of an episode alive until a full garbage collection)."""
        workspace = self._force_workspaces.get(index)
        if workspace is None or workspace.model is not model:
            workspace = self._force_workspaces[index] = ForceWorkspace(model, implicit=False)
        return workspace

    def corner_positions(self, positions):
        """(N, M * k, 3) the positions, m, of every world's element corners (``corner_surface``)."""
        count = self.num_envs
        return positions[np.arange(count)[:, None, None], self.elements].reshape(count, -1, 3)

    def camera_images(self):
        return self.task._camera_view.images(self.corner_positions(self.positions), self._scene_extras())

    def _visual_observation(self, measures):
        observation, self.clipped = self.task._camera_view.observe(
            self.task.observation_type, self.corner_positions(measures["positions"]), self._scene_extras())
        return observation

    def _task_info(self, measures):
        return dict(faces_cut=self.faces_cut.copy(), cut_faces=self.cut_faces.copy(),
                    cut_length=self.cut_length.copy(), cut_deviation=self.cut_deviation.copy(),
                    element_quality=np.asarray(measures["volume_ratio_low"], dtype=float).copy(),
                    cut_refused=self.cut_refused.copy())
