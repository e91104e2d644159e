"""N worlds of one scene as one model: ``ModelStack`` puts N copies of a block (each its own
material) into one sim_core ``Model`` on a mesh made of N disjoint copies of the block: node ``j`` of
world ``i`` is node ``i * n_nodes + j`` of the stacked model, and every per-spring, per-element and
per-node array is the concatenation of the worlds' arrays. ``StackedForceWorkspace`` is the fused
force pass over the stacked model, world by world on numba's threads.

Topology: every world has ``n_nodes`` node rows, the block's nodes plus ``spare_nodes`` fixed when
the stack is built. A world may hold a model of another topology (elements removed, nodes
duplicated into the spare rows: a cut) on at most ``n_nodes`` nodes; such a world leaves the
stacked arrays (``ModelStack.shared`` is False for it) and the N-world solvers step it on its own
model, with the same method and options. Unused node rows are parked: a node of no element, no
spring and no gravity, which no force moves. SI units."""

from __future__ import annotations


import dataclasses

import numba
import numpy as np
import scipy.sparse as sp

from .. import kernels
from .forces import ForceWorkspace, hourglass_block_map, stress_arguments
from .model import Control, Model, State, extend_topology, share_topology
from ..caches import digest
from .smoothing import SmoothedStrain
from .stress_correction import ARRAY_FIELDS, StressCorrection, write_lanes


#: Model arrays that hold one value per node, spring or element of a copy (its material and rest
#: geometry); the topology arrays (springs, edge_spring) are offset instead.
VALUE_FIELDS = ("mass", "rest_length", "stiffness", "damping", "axis_rest_length", "correction_matrix",
                "rest_volume", "volume_stiffness", "young_modulus", "poisson_ratio", "density")
#: The per-element arrays of "baudet-hyperelastic"'s stress correction (``StressCorrection``), stacked
#: and assigned as the VALUE_FIELDS (each copy its own material: shear_modulus, lame, spring_stiffness).
STRESS_FIELDS = ARRAY_FIELDS

class StackedModel(Model):
    """The model of a ``ModelStack``'s N worlds. Unlike any other ``Model`` its per-world values
    change: ``ModelStack.assign`` rewrites a world's slice of the value arrays (``VALUE_FIELDS``,
    the gravity forces, the masses per dof, the hourglass values, and the rest geometry: the
    nodes' rest positions and the elements' rest edge directions, so that a world may hold a model
    of the same topology on another block geometry, e.g. a domain-randomised size) in place, then calls
    ``values_changed``, which drops the data derived from them (``Model.derived``) and advances
    ``ModelStack.version``, which the N-world solvers' own caches compare with theirs. Its topology
    (mesh, springs, patterns) never changes. For "baudet-hyperelastic" its ``stress_correction`` holds
    the copies' stress-correction arrays one after the other (``STRESS_FIELDS``), rewritten the same way."""

    def values_changed(self):
        """Drop the derived data that depends on the values (``assign`` calls it)."""
        for name in ("hourglass_blocks", "pattern_arrays"):
            self.derived.forget(name)


def with_spare_nodes(model: Model, n_nodes: int) -> Model:
    """``model`` on ``n_nodes`` node rows: its nodes, then parked ones (at its node 0's rest
    position, of the mean node mass, in no element and no spring, without gravity: nothing moves
    them). ``model`` itself when it has ``n_nodes`` nodes."""
    extra = int(n_nodes) - model.n_nodes
    if extra < 0:
        raise ValueError(f"the model has {model.n_nodes} nodes, more than the {n_nodes} node rows of a world")
    if extra == 0:
        return model
    nodes = np.concatenate([model.mesh.nodes, np.repeat(model.mesh.nodes[:1], extra, axis=0)])
    mesh = model.mesh.on_nodes(nodes)
    hourglass = model.hourglass
    if hourglass is not None:
        rows = 3 * int(n_nodes)
        indptr = np.concatenate([hourglass.indptr, np.full(3 * extra, hourglass.indptr[-1])])
        hourglass = sp.csr_matrix((hourglass.data, hourglass.indices, indptr), shape=(rows, rows))
    fields = {field.name: getattr(model, field.name) for field in dataclasses.fields(Model)}
    fields.update(mesh=mesh, hourglass=hourglass,
                  mass=np.concatenate([model.mass, np.full(extra, float(np.mean(model.mass)))]))
    padded = Model(**fields)
    if model.smoothing is None:  # the model's pattern, extended to the parked rows (not built again)
        extend_topology(model, padded)
    return padded


def same_topology(model: Model, reference: Model) -> bool:
    """Whether ``model`` has the nodes, springs, elements and force terms of ``reference`` (its
    values, material and rest geometry may differ): a model the stacked arrays can hold."""
    return (model.n_nodes == reference.n_nodes and len(model.springs) == len(reference.springs)
            and model.mesh.elements.shape == reference.mesh.elements.shape
            and model.correction_mode == reference.correction_mode
            and (model.hourglass is None) == (reference.hourglass is None)
            and (model.hourglass is None or model.hourglass.nnz == reference.hourglass.nnz)
            and (model.stress_correction is None) == (reference.stress_correction is None)
            and (model.stress_correction is None or (model.stress_correction.spring_vector.shape
                 == reference.stress_correction.spring_vector.shape
                 and model.stress_correction.law == reference.stress_correction.law))
            and (model.smoothing is None) == (reference.smoothing is None)
            and (model.smoothing is None or (np.array_equal(model.smoothing.indptr, reference.smoothing.indptr)
                                             and np.array_equal(model.smoothing.nodes, reference.smoothing.nodes)))
            and np.array_equal(model.springs, reference.springs)
            and np.array_equal(model.edge_spring, reference.edge_spring)
            and np.array_equal(model.mesh.elements, reference.mesh.elements))


class ModelStack:
    """N copies of one block as one ``StackedModel`` (``self.model``); ``assign(i, model)``
    puts a model into world ``i``: of the same block (any material, any rest geometry), written
    into the stacked arrays, or of another topology on at most ``n_nodes`` nodes (a cut world),
    held on its own (``shared[i]`` False).

    Args:
        model: a model of the block (copied into every slot).
        count: number of copies N.
        spare_nodes: node rows per world beyond the block's, for nodes a topology change adds
            (a cut duplicates the nodes along it); fixed for the stack's life.
    """

    def __init__(self, model: Model, count: int, spare_nodes: int = 0):
        if int(count) < 1:
            raise ValueError(f"count must be >= 1 world, got {count}")
        if int(spare_nodes) < 0:
            raise ValueError(f"spare_nodes must be >= 0, got {spare_nodes}")
        #: the node rows a world's model may add (a cut's duplicated nodes)
        self.spare_nodes = int(spare_nodes)
        #: the models the worlds were given (``assign``), before their parked rows
        self.given = [model] * int(count)
        model = with_spare_nodes(model, model.n_nodes + self.spare_nodes)
        self.count = int(count)
        self.n_nodes = model.n_nodes
        self.n_springs = len(model.springs)
        self.n_elements = model.mesh.n_elements
        self.reference = model
        nodes = np.tile(model.mesh.nodes, (count, 1))
        offsets = np.arange(count)[:, None, None]
        elements = (model.mesh.elements[None] + self.n_nodes * offsets).reshape(-1, model.mesh.elements.shape[1])
        springs = (model.springs[None] + self.n_nodes * offsets).reshape(-1, 2)
        edge_spring = (model.edge_spring[None] + self.n_springs * offsets).reshape(-1, model.edge_spring.shape[1])
        hourglass = None
        if model.hourglass is not None:
            single = model.hourglass
            self.hourglass_nnz = single.nnz
            rows = 3 * self.n_nodes
            indptr = np.concatenate([[0], (single.indptr[1:][None] + single.nnz * np.arange(count)[:, None]).ravel()])
            indices = (single.indices[None] + rows * np.arange(count)[:, None]).ravel()
            hourglass = sp.csr_matrix((np.tile(single.data, count), indices, indptr),
                                      shape=(rows * count, rows * count))
        values = {name: np.concatenate([getattr(model, name)] * count) for name in VALUE_FIELDS}
        stress = None
        if model.stress_correction is not None:
            stress = StressCorrection(**{name: np.ascontiguousarray(np.concatenate(
                [getattr(model.stress_correction, name)] * count)) for name in STRESS_FIELDS},
                law=model.stress_correction.law)
        #: stress-correction rows per world (its elements, or its smoothing domains)
        self.n_cells = 0 if stress is None else len(model.stress_correction.volume)
        smoothing = None
        if model.smoothing is not None:  # the worlds' domains side by side, as the elements
            single = model.smoothing
            nnz = len(single.nodes)
            self.n_entries = nnz
            smoothing = SmoothedStrain(
                indptr=np.concatenate([[0], (single.indptr[1:][None] + nnz * np.arange(count)[:, None]).ravel()]),
                nodes=(single.nodes[None] + self.n_nodes * np.arange(count)[:, None]).ravel(),
                gradient=np.ascontiguousarray(np.tile(single.gradient, (count, 1))), law=stress)
        self.model = StackedModel(
            mesh=model.mesh.on_nodes(nodes, elements, shape=None, spacing=None, element_labels=None), name=model.name,
            springs=springs, edge_spring=edge_spring,
            correction_mode=model.correction_mode, gravity=model.gravity.copy(), hourglass=hourglass,
            options=dict(model.options), stress_correction=stress, smoothing=smoothing, **values,
        )
        if count == 1:  # one world (a cut world's own solver): its model's pattern, not a second one
            share_topology(model, self.model)
        # slots of each copy in the per-dof arrays the Model derived at construction
        self._mass_positions = self.model.pattern.diagonal_positions.reshape(count, -1)
        # built now, not at first use: ``assign`` rewrites its slices in place, from any thread
        self.model.mass_data  # noqa: B018
        #: each world's model on the stack's ``n_nodes`` rows (the given one, its unused rows parked)
        self.models = [model] * count
        #: (N,) bool: the worlds whose model the stacked arrays hold (the block's topology); the
        #: others hold a model of their own (``models[i]``) and are stepped on it
        self.shared = np.ones(count, dtype=bool)
        # the copies' hourglass matrices by content (``hourglass_groups``); one world is one group
        # whatever its matrix (a cut world's own solver: no megabyte to hash)
        self._hourglass_keys = [None if model.hourglass is None else digest(model.hourglass.data) if count > 1
                                else "one world"] * count
        self._hourglass_by_key = {self._hourglass_keys[0]: model.hourglass}
        self._hourglass_groups = None
        self.version = 0
        self._copies_last = None

    def new_state(self) -> State:
        """The worlds at rest: positions (N, n, 3) m each world's rest positions (parked rows at
        their parking place), velocities zero, time 0."""
        rest = np.stack([model.rest_positions for model in self.models])
        return State(rest, np.zeros_like(rest))

    def new_control(self) -> Control:
        """A control of the N worlds with nothing imposed and no external force: fixed (N, n, 3)
        bool, target (N, n, 3) m, force (N, n, 3) N."""
        shape = (self.count, self.n_nodes, 3)
        return Control(np.zeros(shape, bool), np.zeros(shape), np.zeros(shape))

    def assign(self, index: int, model: Model):
        """World ``index`` holds ``model`` from now on (a no-op when it already does): its values
        are written into the stacked arrays when it has the block's topology, else the world holds
        it on its own (``shared[index]`` False). A model of more than ``n_nodes`` nodes is a
        ValueError (build the stack with more ``spare_nodes``). Tell the solvers
        (``solver.model_changed(index)``) unless they step this world next with a fresh episode
        (they notice a changed model at their next step)."""
        index = int(index)
        if not 0 <= index < self.count:
            raise ValueError(f"world index must lie in [0, {self.count - 1}], got {index}")
        if self.given[index] is model:
            return
        if not isinstance(model, Model):
            raise ValueError(f"assign takes a sim_core Model (build_model), got {type(model).__name__}")
        if model.n_nodes > self.n_nodes:
            raise ValueError(f"world {index}'s model has {model.n_nodes} nodes; a world of this stack holds at most "
                             f"{self.n_nodes} ({self.n_nodes - self.spare_nodes} block nodes + {self.spare_nodes} "
                             "spare_nodes): build the ModelStack with more spare_nodes")
        padded = with_spare_nodes(model, self.n_nodes)
        self.given[index] = model
        if not same_topology(padded, self.reference):
            self.models[index] = padded  # the stacked arrays (and ``version``) are left as they are
            self.shared[index] = False
            return
        self.shared[index] = True
        self._write(index, padded)

    def _write(self, index: int, model: Model):
        """Write ``model`` (of the block's topology) into world ``index``'s slice of the stacked arrays."""
        stacked = self.model
        for name in VALUE_FIELDS:
            single = getattr(model, name)
            getattr(stacked, name)[index * len(single):(index + 1) * len(single)] = single
        elements = slice(index * self.n_elements, (index + 1) * self.n_elements)
        if model.stress_correction is not None:
            cells = slice(index * self.n_cells, (index + 1) * self.n_cells)
            for name in STRESS_FIELDS:
                getattr(stacked.stress_correction, name)[cells] = getattr(model.stress_correction, name)
            lanes = stacked.derived.peek("stress_lanes")
            if lanes is not None:  # the compiled passes' element-last copy of the same arrays
                write_lanes(lanes, model.stress_correction, cells)
        if model.smoothing is not None:
            stacked.smoothing.gradient[index * self.n_entries:(index + 1) * self.n_entries] = model.smoothing.gradient
        nodes = slice(index * self.n_nodes, (index + 1) * self.n_nodes)
        # the rest geometry (the reference's for a model of the same block; the force passes read it
        # in place: the hourglass term's rest positions, the fixed corrections' rest directions). The
        # stacked mesh is the one mesh whose nodes change, as its model is the one whose values do.
        rest = stacked.mesh.nodes
        if not np.array_equal(rest[nodes], model.mesh.nodes):  # a model of another block (a size draw)
            rest.setflags(write=True)
            rest[nodes] = model.mesh.nodes
            rest.setflags(write=False)
        stacked.rest_edge_direction[elements] = model.rest_edge_direction
        stacked.gravity_force[nodes] = model.gravity_force
        stacked.mass_data[self._mass_positions[index]] = np.repeat(model.mass, 3)
        if model.hourglass is not None:
            data = slice(index * self.hourglass_nnz, (index + 1) * self.hourglass_nnz)
            stacked.hourglass.data[data] = model.hourglass.data
            if stacked.hourglass_arrays[2] is not stacked.hourglass.data:
                stacked.hourglass_arrays[2][data] = model.hourglass.data
            key = digest(model.hourglass.data)
            self._hourglass_by_key.setdefault(key, model.hourglass)
            self._hourglass_keys[index] = key
            self._hourglass_groups = None
        stacked.values_changed()
        self.models[index] = model
        self.version += 1

    def copies_last(self):
        """The copies' material arrays with the copy index last (``kernels.batched_spring_operator``'s
        layout): dict of stiffness, damping (S, N), mass (n, N), correction_matrix (M, 3, 3, N),
        axis_rest_length (M, 3, N), hourglass data (nnz, G) of the G distinct hourglass matrices and
        hourglass_group (N,) the column of each copy; rebuilt after ``assign``."""
        if self._copies_last is None or self._copies_last[0] != self.version:
            model, count = self.model, self.count

            def last(array):
                array = np.asarray(array, dtype=float)
                return np.ascontiguousarray(np.moveaxis(array.reshape((count, len(array) // count) + array.shape[1:]),
                                                        0, -1))

            arrays = {name: last(getattr(model, name)) for name in
                      ("stiffness", "damping", "mass", "correction_matrix", "axis_rest_length")}
            groups = self.hourglass_groups()  # copies with equal hourglass matrices share a column
            arrays["hourglass"] = np.zeros((self.hourglass_nnz if groups else 0, max(len(groups), 1)))
            arrays["hourglass_group"] = np.zeros(count, dtype=np.int64)
            for g, (matrix, copies) in enumerate(groups):
                arrays["hourglass"][:, g] = matrix.data
                arrays["hourglass_group"][copies] = g
            self._copies_last = (self.version, arrays)
        return self._copies_last[1]

    def hourglass_groups(self):
        """[(single-copy hourglass matrix, copy indices)] grouping the copies with equal matrices."""
        if self._hourglass_groups is None:
            keys = self._hourglass_keys
            self._hourglass_groups = [] if keys[0] is None else [
                (self._hourglass_by_key[key], np.array([i for i, k in enumerate(keys) if k == key]))
                for key in dict.fromkeys(keys)]
            used = set(keys)
            self._hourglass_by_key = {k: m for k, m in self._hourglass_by_key.items() if k in used}
        return self._hourglass_groups


class StackedForceWorkspace(ForceWorkspace):
    """``sim_core.models.forces.ForceWorkspace`` of a ``ModelStack``'s stacked model whose hourglass term
    reads each distinct copy's hourglass matrix once for all the copies that hold it, in node blocks
    (``kernels.stacked_hourglass_subtract_groups``): the stacked CSR matrix is N times a copy's
    (14 MB at Palpation's 8x4x8 and N = 16), out of cache, and made the stacked force pass slower
    per copy than a single env's. The same pass serves one world and N, whatever the other copies
    hold, so a copy's forces are bitwise those of the same world alone."""

    def __init__(self, stack: ModelStack, implicit: bool = True, threads: int = 1):
        super().__init__(stack.model, implicit=implicit, pair_rows=False)
        self.stack = stack
        #: the hourglass pass runs on numba's threads when ``kernels.threaded(threads)``
        self.threads = int(threads)
        self._blocks = None  # hourglass_blocks: (stack version, arrays)
        self._block_map = None

    def hourglass_blocks(self):
        """The node-block (BSR) form of the copies' hourglass matrices: (block indptr (n + 1,), block
        columns (nb,), values (G, 9 nb) per column of ``ModelStack.copies_last``'s hourglass data),
        rebuilt after ``ModelStack.assign``."""
        stack = self.stack
        if self._blocks is None or self._blocks[0] != stack.version:
            if self._block_map is None:  # the position in the CSR data of each block entry (-1: none)
                single = stack.reference.hourglass
                self._block_map = ((np.zeros(stack.n_nodes + 1, np.int64), np.zeros(0, np.int64),
                                    np.zeros(0, np.int64)) if single is None
                                   else hourglass_block_map(single, stack.reference.__dict__.get("pattern")))
            indptr, indices, positions = self._block_map
            hg_rows = stack.copies_last()["hourglass"].T
            values = np.zeros((len(hg_rows), len(positions)))
            if len(positions):
                stored = positions >= 0
                values[:, stored] = hg_rows[:, positions[stored]]
            self._blocks = (stack.version, (indptr, indices, values))
        return self._blocks[1]

    def compute(self, positions, velocities, hourglass=True, geometric=False, volume_jacobian=False, rows=None):
        """``ForceWorkspace.compute``; ``rows``: None (every copy), or the copies (N,) bool whose
        forces (and implicit data) are computed, one copy after the other, the others' entries
        left as they are (a contact pass that solves some worlds again: the same floats per
        copy). Only an implicit pass (``geometric``) takes some of the copies; any other computes
        them all."""
        if rows is not None and (rows.all() or not self.partial_pass(geometric)):
            rows = None
        if kernels.threaded(self.threads) or rows is not None:  # copy by copy: the same floats
            forces = self._compute_copies(positions, velocities, geometric, volume_jacobian, rows)
        else:
            forces = super().compute(positions, velocities, hourglass=False, geometric=geometric,
                                     volume_jacobian=volume_jacobian)
        if hourglass and self.has_hourglass:
            stack = self.stack
            values = stack.copies_last()
            threaded = kernels.threaded(self.threads)
            positions = np.ascontiguousarray(positions, dtype=float)
            # each distinct matrix read once for all its copies, in node blocks: the same floats per
            # copy whatever the other copies hold (one world equals its copy in N worlds)
            group = values["hourglass_group"]
            order = np.argsort(group, kind="stable").astype(np.int64)
            if rows is not None:
                order = order[rows[order]]
            group_start = np.searchsorted(group[order], np.arange(values["hourglass"].shape[1] + 1))
            indptr, indices, block_rows = self.hourglass_blocks()
            args = (indptr, indices, block_rows, order, group_start.astype(np.int64), positions,
                    self.rest_positions, forces)
            if threaded:  # a block of rows per thread
                kernels.stacked_hourglass_subtract_groups(*args, numba.get_num_threads())
            else:
                kernels.stacked_hourglass_subtract_groups_serial(*args)
        return forces

    def partial_pass(self, geometric):
        """Whether ``compute`` with ``geometric`` computes only the copies its ``rows`` asks for (an
        implicit pass), rather than all of them."""
        return geometric and (self.model.stress_correction is None or len(self.stress_tangent) > 0)

    def add_damping(self, velocities, forces):
        """``ForceWorkspace.add_damping``, one copy per thread when threaded (the same floats)."""
        if not kernels.threaded(self.threads):
            return super().add_damping(velocities, forces)
        kernels.scatter_springs_copies(self.stack.count, self.model.springs, self.unit, self._zero_tension,
                                       self.model.damping, velocities, True, forces)
        return forces

    def _compute_copies(self, positions, velocities, geometric, volume_jacobian, rows):
        """``ForceWorkspace.compute`` without the hourglass term of the copies ``rows`` (None:
        all), by ``kernels.model_forces_copies`` (its serial twin on one thread)."""
        model, reference = self.model, self.stack.reference
        use_velocity = velocities is not None
        rows = np.ones(self.stack.count, dtype=bool) if rows is None else np.ascontiguousarray(rows, dtype=bool)
        kernels.variant(kernels.model_forces_copies, self.threads)(self.stack.count, rows, (
            positions, velocities if use_velocity else positions, use_velocity, reference.springs,
            model.stiffness, model.rest_length, model.damping, reference.mesh.elements, reference.edge_spring,
            model.correction_matrix, model.axis_rest_length, self.correction_kind, model.rest_edge_direction,
            model.rest_volume, model.volume_stiffness, self.has_volume, self.length, self.unit, self.tension,
            self.push, self.forces, geometric, self.geometric, volume_jacobian and self.has_volume,
            self.volume_coefficient, self.volume_direction, self.volume_gradient))
        correction = model.stress_correction
        if correction is not None:  # the stress correction, copy by copy (kernels.stress_correction_add's floats)
            arguments = (self.stack.count, positions, *stress_arguments(model, elements_of=reference))
            if geometric and len(self.stress_tangent):
                self.clamped_elements = kernels.variant(kernels.stress_correction_tangent_add_copies, self.threads)(
                    arguments[0], rows, *arguments[1:], correction.metric_root, correction.metric_root_inverse, True,
                    self.forces, self.stress_tangent)
            else:  # every copy (``compute``)
                kernels.stress_correction_add_copies(*arguments, self.forces)
        return self.forces
