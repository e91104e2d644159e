"""Topology change: separating elements along the faces they share (a cut).

``separate(model, faces) -> Model`` cuts the faces ``faces`` (pairs of elements that share a face) and gives
a node one copy per group of its elements that stay connected through its uncut faces: the model of
the mesh born with that cut. A mass-spring model changes only what the cut touches, and here it is
built from the cut mesh by ``build_model`` with the model's own material and options, so that it is
exactly the model of that mesh (masses, springs, corrections, volumes, smoothing domains); what
depends on an element alone (its rest volume, its hourglass matrix) is taken from the uncut model
(``build_model(same_elements=...)``), and the cut model's pattern is built only when a solver steps it.

Numbering: the elements keep their order and indices, the original nodes keep theirs (each stays
with the group of its elements that holds its lowest element corner), and the copies are appended in
the order of their original node, then of their group's lowest element corner.
``separation(model, faces)`` also gives ``Separation.origin``, which maps every node of the cut
model to the node it was copied from, and ``Separation.state``, which carries a ``State`` across (a copy starts where its original is, at its
velocity). SI units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry.mesh import HexMesh
from .geometry.tetmesh import TET_FACES, TetMesh
from .geometry.topology import FACES
from .models.material import Material
from .models.model import Model, State, build_model
from .models.sparse import unique_keys


@dataclass(frozen=True)
class Separation:
    """The outcome of ``separation``: the cut model and how its nodes come from the uncut one's.

    Attributes:
        model: the model of the cut mesh.
        origin: (N', ) int64, the node of the uncut model each node of the cut one was copied from
            (``origin[i] == i`` for the original nodes, i < N).
        faces: (F, 2) int64 the cut element pairs, each sorted, in the order given.
    """

    model: Model
    origin: np.ndarray
    faces: np.ndarray

    @property
    def added(self) -> int:
        """Nodes the cut added (copies)."""
        return len(self.origin) - int(self.origin.max(initial=-1)) - 1 if len(self.origin) else 0

    def state(self, state: State) -> State:
        """The uncut model's ``state`` on the cut model's nodes: each copy at its original's
        position and velocity (the cut itself moves nothing)."""
        return State(np.array(state.positions)[self.origin], np.array(state.velocities)[self.origin], state.time)


def element_faces(mesh: HexMesh | TetMesh) -> np.ndarray:
    """(M, f, k) the node indices of every element's faces (hexahedra: 6 quads, tetrahedra: 4 triangles)."""
    return mesh.elements[:, FACES if isinstance(mesh, HexMesh) else TET_FACES]


def shared_faces(mesh: HexMesh | TetMesh) -> np.ndarray:
    """(P, 2) int64 every pair of elements that share a face (each pair sorted, pairs sorted): the
    faces ``separate`` can cut."""
    return _face_pairs(mesh)


def model_shared_faces(model: Model) -> np.ndarray:
    """``shared_faces`` of ``model``'s mesh, kept with the model (a blade asks at every step it moves)."""
    return model.derived.get("shared_faces", lambda: _face_pairs(model.mesh))


def _face_pairs(mesh):
    faces = element_faces(mesh)
    count, per = faces.shape[:2]
    keys = np.sort(faces.reshape(count * per, -1), axis=1)
    order = np.lexsort(keys.T[::-1])
    keys, owner = keys[order], np.repeat(np.arange(count), per)[order]
    same = np.all(keys[1:] == keys[:-1], axis=1)
    return np.stack([owner[:-1][same], owner[1:][same]], axis=1).astype(np.int64)


def separate(model: Model, faces) -> Model:
    """The model of ``model``'s mesh cut along ``faces`` (F, 2): pairs of element indices that share a
    face (either order); ``separation`` gives it with each node's origin and the state mapping. A
    pair that does not share a face, or an index outside the mesh, is a ValueError naming it; cutting
    no face gives ``model`` itself."""
    return separation(model, faces).model


def separation(model: Model, faces) -> Separation:
    """``separate`` with what a simulation needs to go on through the cut: the ``Separation`` (the
    cut model, each node's origin, ``Separation.state`` carrying a state across)."""
    mesh = model.mesh
    pairs = np.asarray(faces)
    if pairs.size == 0:
        pairs = np.zeros((0, 2), dtype=np.int64)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
        raise ValueError(f"faces must be an (F, 2) integer array of element pairs that share a face, got "
                         f"{pairs.dtype} of shape {pairs.shape}")
    pairs = np.sort(pairs.astype(np.int64), axis=1)
    if len(pairs) and (pairs.min() < 0 or pairs.max() >= mesh.n_elements):
        raise ValueError(f"faces' element indices must lie in [0, {mesh.n_elements - 1}], got "
                         f"[{pairs.min()}, {pairs.max()}]")
    shared = model_shared_faces(model)
    keys = shared[:, 0] * mesh.n_elements + shared[:, 1]
    wanted = pairs[:, 0] * mesh.n_elements + pairs[:, 1]
    found = np.isin(wanted, keys)
    if not np.all(found):
        bad = pairs[int(np.argmin(found))]
        raise ValueError(f"elements {bad[0]} and {bad[1]} share no face: a cut separates elements along a face "
                         "they share (sim_core.cutting.shared_faces lists them)")
    if not len(pairs):
        return Separation(model, np.arange(mesh.n_nodes, dtype=np.int64), pairs)
    elements, origin = _split_nodes(mesh, shared, shared[~np.isin(keys, wanted)])
    if len(origin) == mesh.n_nodes:  # no node copied (a crack one element wide): the mesh born with it is this one
        return Separation(model, origin, pairs)
    nodes = mesh.nodes[origin]
    cut_mesh = mesh.on_nodes(nodes, elements, shape=None, spacing=None)  # the same corners: checked once
    return Separation(_rebuild(model, cut_mesh), origin, pairs)


def _corner_edges(elements, pairs):
    """(slots, slots): the element corners (element * n + local node) joined by ``pairs`` (J, 2) of
    elements that share a face: the corners of the common face's nodes in the two elements."""
    n = elements.shape[1]
    a, b = pairs[:, 0], pairs[:, 1]
    rows, i, j = np.nonzero(elements[a][:, :, None] == elements[b][:, None, :])  # corner i of a is corner j of b
    return a[rows] * n + i, b[rows] * n + j


def _lowest_slots(size, edges):
    """(size,) for each of ``size`` slots the lowest slot of its connected component in the graph of
    ``edges`` (two (E,) arrays): the lowest label spread along the edges, each label then replaced by
    its own (pointer jumping) until nothing changes. A cut's edges join the corners of one node (at
    most 8 for hexahedra), so a few passes do it, without building a sparse graph."""
    label = np.arange(size, dtype=np.int64)
    first, second = (np.asarray(side, dtype=np.int64) for side in edges)
    while True:
        low = np.minimum(label[first], label[second])
        spread = label.copy()
        np.minimum.at(spread, first, low)
        np.minimum.at(spread, second, low)
        spread = spread[spread]
        if np.array_equal(spread, label):
            return label
        label = spread


def _split_nodes(mesh, shared, joined):
    """(elements (M, n) renumbered, origin (N',)): every element corner (element * n + local node) is
    a vertex of a graph whose edges join a node's corners in two elements of a ``joined`` (uncut)
    shared face; each connected set of a node's corners is one node. Corners that no shared face
    joined before the cut either (elements touching at a node only) stay joined through the node:
    the cut separates only what it separates."""
    elements = mesh.elements
    count, n = elements.shape
    size = count * n
    node_of_slot = elements.ravel()
    before = _lowest_slots(size, _corner_edges(elements, shared))
    # each node's groups before the cut, joined to its first group (a node-only contact stays one node)
    groups = _unique_pairs(node_of_slot, before, size)  # (node, group's first slot), sorted
    first_of_node = groups[np.searchsorted(groups[:, 0], groups[:, 0]), 1]
    cut_a, cut_b = _corner_edges(elements, joined)
    after = _lowest_slots(size, (np.r_[cut_a, groups[:, 1]], np.r_[cut_b, first_of_node]))
    # one node per (original node, group after the cut): the group with the node's lowest corner
    # keeps the node's index, the others are copies appended in (node, first corner) order
    kept = _unique_pairs(node_of_slot, after, size)
    keeps = np.r_[True, kept[1:, 0] != kept[:-1, 0]]
    new_index = np.empty(len(kept), dtype=np.int64)
    new_index[keeps] = kept[keeps, 0]
    copies = np.flatnonzero(~keeps)
    new_index[copies] = mesh.n_nodes + np.arange(len(copies))
    origin = np.concatenate([np.arange(mesh.n_nodes), kept[copies, 0]]).astype(np.int64)
    lookup = np.searchsorted(kept[:, 0] * size + kept[:, 1], node_of_slot * size + after)
    return new_index[lookup].reshape(count, n), origin


def _unique_pairs(first, second, size):
    """(P, 2) the distinct rows (first, second) sorted, ``second`` < ``size``: np.unique(axis=0) on one
    int64 key per row (several times faster)."""
    keys = unique_keys(first.astype(np.int64) * size + second)
    return np.stack([keys // size, keys % size], axis=1)


def _rebuild(model: Model, mesh):
    """``build_model`` of ``mesh`` (the same elements, nodes copied) with ``model``'s material and options."""
    options = dict(model.options)
    corrections = options.pop("corrections", True)
    if isinstance(mesh, TetMesh):  # the hexahedral options a tetrahedral model records at their defaults
        for name in ("volume_conservation", "volume_stiffness", "nu_factor", "hourglass_control"):
            options.pop(name, None)
    material = Material(model.young_modulus, model.poisson_ratio, model.density, *(model.damping_law or ()))
    return build_model(mesh, material, model=model.name, corrections=corrections, gravity=model.gravity,
                       max_shear_error=None, same_elements=model, **options)


def blade_faces(model: Model, positions, edge_from, edge_to) -> np.ndarray:
    """(F, 2) the shared faces of ``model``'s mesh that a blade crosses: the blade's edge, the
    segment ``edge_from`` (2, 3) m, moves to ``edge_to`` (2, 3) m (its two ends each along a
    straight line) and sweeps the surface between them (split into the triangles (a, b, b') and
    (a, b', a')); a face is crossed when the segment between its two elements' centroids at
    ``positions`` (N, 3) m passes through that surface. Cutting along faces makes no slivers, and the
    cut faces lie within about half an element of the swept surface (each such segment is one
    element across)."""
    edge_from, edge_to = (np.asarray(value, dtype=float) for value in (edge_from, edge_to))
    for name, value in (("edge_from", edge_from), ("edge_to", edge_to)):
        if value.shape != (2, 3) or not np.all(np.isfinite(value)):
            raise ValueError(f"{name} must be the blade edge's two ends, a finite (2, 3) array in m, got shape "
                             f"{value.shape}")
    positions = np.asarray(positions, dtype=float)
    if positions.shape != (model.n_nodes, 3):
        raise ValueError(f"positions must be a ({model.n_nodes}, 3) array in m, got shape {positions.shape}")
    pairs = model_shared_faces(model)
    centres = positions[model.mesh.elements].mean(axis=1)
    start, end = centres[pairs[:, 0]], centres[pairs[:, 1]]
    # only a segment that meets the swept surface's bounding box (widened by a margin far above
    # rounding) can cross it: the test runs on those few, with the same floats per segment
    corners = np.concatenate([edge_from, edge_to])
    low, high = corners.min(axis=0), corners.max(axis=0)
    margin = 1e-6 * (float(np.max(high - low)) + float(np.max(np.abs(corners))))
    near = np.flatnonzero(np.all((np.minimum(start, end) <= high + margin)
                                 & (np.maximum(start, end) >= low - margin), axis=1))
    start, end = start[near], end[near]
    (a, b), (a_to, b_to) = edge_from, edge_to
    crossed = np.zeros(len(near), dtype=bool)
    for triangle in ((a, b, b_to), (a, b_to, a_to)):
        crossed |= _segments_cross_triangle(start, end, *triangle)
    return pairs[near[crossed]]


def _cross(u, v):
    """u x v for (S, 3) or (3,) arrays (broadcast): ``np.cross``'s products and differences, without
    its axis handling (a blade's every step asks it)."""
    u, v = np.asarray(u), np.asarray(v)
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1], u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


def _segments_cross_triangle(start, end, p0, p1, p2, tolerance=1e-12):
    """(S,) whether each segment start -> end (S, 3) crosses the triangle (p0, p1, p2) (Moller-Trumbore,
    the segment's parameter in [0, 1]; a degenerate triangle is crossed by none)."""
    direction = end - start
    e1, e2 = p1 - p0, p2 - p0
    h = _cross(direction, e2)
    det = h @ e1
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.where(np.abs(det) > tolerance * np.linalg.norm(e1) * np.linalg.norm(e2) * np.linalg.norm(
            direction, axis=1), 1.0 / det, 0.0)
        s = start - p0
        u = inverse * np.einsum("ij,ij->i", s, h)
        q = _cross(s, e1)
        v = inverse * np.einsum("ij,ij->i", direction, q)
        t = inverse * (q @ e2)
    return (inverse != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def carried_nodes(before: Model, after: Model) -> np.ndarray:
    """(N',) the node of ``before`` each node of ``after`` comes from, for two models of one mesh's
    elements (the same order) where ``after`` is cut further: a node of ``after`` sits at element
    corners where ``before`` has the node it was copied from (cuts only split nodes)."""
    carried = np.empty(after.n_nodes, dtype=np.int64)
    carried[after.mesh.elements.ravel()] = before.mesh.elements.ravel()
    return carried


def cut_world(stack, state: State, index: int, faces, solver=None, uncut: Model | None = None) -> Separation:
    """Cut world ``index`` of a ``ModelStack`` along ``faces`` (``separation`` of the model it holds)
    in the middle of its episode: the cut model goes into the world (``ModelStack.assign``; a world
    holds at most ``stack.n_nodes`` node rows, so the stack needs ``spare_nodes`` for the copies),
    the world's rows of ``state`` (N, n, 3) are carried across in place (``Separation.state``: the
    cut moves nothing and adds no kinetic energy) and ``solver.model_changed(index)`` is called when
    a solver is given. The other worlds are untouched. Returns the ``Separation``.

    ``uncut``: None, or the world's model before any cut, when ``faces`` are all the faces cut so far
    (the world then holds ``separation(uncut, faces)``). Cutting in steps needs it: a face whose cut
    copies no node yet (a crack one element wide) leaves the model as it was, and only the union of
    the cuts separates the nodes that the cuts together split."""
    index = int(index)
    current = stack.given[index]
    cut = separation(current if uncut is None else uncut, faces)
    if cut.model is current or (uncut is not None and cut.model is uncut and current is uncut):
        return cut
    count = cut.model.n_nodes
    rows = cut.origin if uncut is None else carried_nodes(current, cut.model)
    stack.assign(index, cut.model)
    for array in (state.positions, state.velocities):
        array[index, :count] = array[index, rows]
    if solver is not None:
        solver.model_changed(index)
    return cut
