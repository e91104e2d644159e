"""Forces of the mass-spring model and their Jacobian (vectorised over springs and elements).

Sign conventions: ``forces`` are the forces acting on the nodes (N); ``stiffness`` matrices are
K = -d(forces)/d(positions) (N/m) and damping matrices D = -d(forces)/d(velocities) (N s/m), so
that both are positive semi-definite for plain springs. Equations cite docs/physics.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .. import kernels
from .elements import element_blocks
from ..geometry.mesh import EDGE_AXIS, EDGES, FACES, GAUSS_GRADIENTS, hex_jacobians
from .model import Model
from . import smoothing as _smoothing
from . import stress_correction as _stress


@dataclass
class SpringGeometry:
    """Current spring directions ``unit`` (S, 3), lengths ``length`` (S,) m."""

    unit: np.ndarray
    length: np.ndarray


def spring_geometry(model: Model, positions: np.ndarray) -> SpringGeometry:
    a, b = model.springs[:, 0], model.springs[:, 1]
    vector = positions[b] - positions[a]
    length = np.sqrt(np.einsum("ij,ij->i", vector, vector))
    return SpringGeometry(vector / length[:, None], length)


def element_strains(model: Model, length: np.ndarray) -> np.ndarray:
    """(M, 3) eps_m = mean current length of the element's m-edges / rest - 1 [3]."""
    edges = length[model.edge_spring].reshape(-1, 3, 4).mean(axis=2)
    return edges / model.axis_rest_length - 1.0


def correction_pushes(model: Model, length: np.ndarray) -> np.ndarray:
    """(M, 3) T_j: force (N) pushing apart the two ends of each of the element's j-edges [3]."""
    return np.einsum("mjk,mk->mj", model.correction_matrix, element_strains(model, length))


def volume_terms(model: Model, positions: np.ndarray, gradient: bool = False):
    """Volume-conservation force per element node and, optionally, the volume gradient [4].

    F_S = -kappa sign(dV) (dV / V0)^2 (A_S / A_H) N_S on each face S of hexahedron H, a quarter
    on each of its nodes (restoring: a shrunken element pushes its faces outward).

    Returns (forces (M, 8, 3) N, volume (M,) m^3, dphi (M,) N/m^3, face_force_direction h (M, 8, 3),
    volume gradient (M, 8, 3) m^2 or None).
    """
    corners = positions[model.mesh.elements]  # (M, 8, 3)
    jac = hex_jacobians(positions, model.mesh.elements)
    det = np.linalg.det(jac)
    volume = det.mean(axis=1)
    face = corners[:, FACES]  # (M, 6, 4, 3)
    area_vector = 0.5 * np.cross(face[:, :, 2] - face[:, :, 0], face[:, :, 3] - face[:, :, 1])
    area = np.linalg.norm(area_vector, axis=2)
    total_area = area.sum(axis=1)
    direction = np.zeros_like(corners)  # h: sum over faces of a_S / (4 A_H) on the face's nodes
    share = area_vector / (4.0 * total_area[:, None, None])
    for corner in range(4):
        np.add.at(direction, (slice(None), FACES[:, corner]), share)
    change = volume - model.rest_volume
    relative = change / model.rest_volume
    phi = -model.volume_stiffness * relative * np.abs(relative)  # N
    forces = phi[:, None, None] * direction
    dphi = -2.0 * model.volume_stiffness * np.abs(relative) / model.rest_volume
    grad = None
    if gradient:
        cofactor = det[..., None, None] * np.linalg.inv(jac).transpose(0, 1, 3, 2)  # (M, P, a, b)
        # grad[m, n, a] = sum_{p, b} cofactor[m, p, a, b] G[p, n, b] / P, as one batched matmul
        n_points = len(GAUSS_GRADIENTS)
        flat = cofactor.transpose(0, 2, 1, 3).reshape(-1, 3, n_points * 3)
        grad = (flat @ GAUSS_GRADIENTS.reshape(n_points * 8, 3).reshape(n_points, 8, 3)
                .transpose(0, 2, 1).reshape(n_points * 3, 8)).transpose(0, 2, 1) / n_points
    return forces, volume, dphi, direction, grad


@dataclass
class SpringState:
    """Per-spring quantities of one force evaluation: ``length`` (S,) m, ``unit`` (S, 3),
    ``tension`` (S,) N (elastic, corrections included, damping excluded)."""

    length: np.ndarray
    unit: np.ndarray
    tension: np.ndarray


def spring_state(model: Model, positions: np.ndarray) -> tuple[SpringState, np.ndarray | None]:
    """Compiled spring and correction pass. Returns (SpringState, pushes (M, 3) N or None)."""
    n_springs = len(model.springs)
    state = SpringState(np.empty(n_springs), np.empty((n_springs, 3)), np.empty(n_springs))
    kernels.spring_pass(positions, model.springs, model.stiffness, model.rest_length,
                        state.length, state.unit, state.tension)
    push = None
    if model.correction_mode is not None:
        push = np.empty((model.mesh.n_elements, 3))
        kernels.correction_pass(state.length, model.edge_spring, model.correction_matrix,
                                model.axis_rest_length, push)
        if model.correction_mode == "projected":
            kernels.subtract_pushes(model.edge_spring, push, state.tension)
    return state, push


_CORRECTION_KIND = {None: 0, "projected": 1, "fixed": 2}


def hourglass_block_map(matrix, pattern=None):
    """The node-block (BSR, 3 x 3) layout of a CSR matrix with 3 dofs per node: (block indptr
    (N + 1,), block columns (nb,), positions (9 nb,) int64: the index in ``matrix.data`` of each
    row-major block value, -1 for the zeros a block adds). Values of another matrix of the same
    pattern are ``data[positions]`` where positions >= 0 (``sim_core.solvers.implicit``'s per-copy
    hourglass values). ``pattern``: None, or the model's ``sparse.BlockPattern``: a matrix that holds
    its first entries (a hexahedral model's hourglass matrix, assembled on it) takes the layout from
    its blocks, without a BSR conversion (a cut builds two per model)."""
    layout = None if pattern is None else _pattern_block_map(matrix, pattern)
    if layout is not None:
        return layout
    probe = sp.csr_matrix((np.arange(1.0, matrix.nnz + 1.0), matrix.indices, matrix.indptr), shape=matrix.shape)
    blocks = sp.bsr_matrix(probe, blocksize=(3, 3))
    blocks.sort_indices()
    return (blocks.indptr.astype(np.int64), blocks.indices.astype(np.int64),
            blocks.data.reshape(-1).astype(np.int64) - 1)


def _pattern_block_map(matrix, pattern):
    """``hourglass_block_map`` of ``matrix`` when it holds exactly ``pattern``'s entries of its first
    node rows (the rows after them empty), else None."""
    indptr, indices, count = matrix.indptr, matrix.indices, matrix.nnz
    rows = int(np.argmax(indptr == count))
    if (matrix.shape != (pattern.n_dofs, pattern.n_dofs) or rows % 3 or count > pattern.nnz
            or int(pattern.indptr[rows]) != count or not np.array_equal(indptr[:rows + 1], pattern.indptr[:rows + 1])
            or not np.array_equal(indices, pattern.indices[:count])):
        return None
    blocks = int(pattern.block_indptr[rows // 3])
    block_indptr = np.minimum(pattern.block_indptr, blocks).astype(np.int64)
    node = np.repeat(np.arange(rows // 3), np.diff(block_indptr[:rows // 3 + 1]))
    positions = pattern.block_positions(node, pattern.block_keys[:blocks] % pattern.n_nodes)
    return block_indptr, (pattern.block_keys[:blocks] % pattern.n_nodes).astype(np.int64), positions.reshape(-1)


def hourglass_blocks(model: Model):
    """The node-block (BSR, 3 x 3) form of ``model.hourglass`` for ``kernels.apply_operator_blocks``:
    (block indptr (N + 1,), block columns (nb,), row-major block values (9 nb,), ones (3 N,)), or
    None without hourglass control. Built once per model and kept in ``model.derived``: a model's
    matrix is constant (the one model whose values change, ``sim_core.models.stack.StackedModel``, drops
    it when they do). Read in
    blocks, an operator product or a force pass loads one index and three vector entries per 9
    values, where the scalar CSR loops were about half of their time."""
    return model.derived.get("hourglass_blocks", lambda: _hourglass_blocks(model))


def _hourglass_blocks(model: Model):
    if model.hourglass is None:
        return None
    indptr, indices, positions = hourglass_block_map(model.hourglass, model.__dict__.get("pattern"))
    values = np.zeros(len(positions))
    stored = positions >= 0
    values[stored] = model.hourglass.data[positions[stored]]
    return indptr, indices, values, np.ones(model.hourglass.shape[0])


class ForceWorkspace:
    """Preallocated per-model arrays for the fused force kernel (``kernels.model_forces``) and the
    implicit step's matrix-free operator (``kernels.spring_operator``): nothing is allocated per
    step. Owned by one integrator (or one call); the arrays are overwritten by every ``compute``.
    """

    def __init__(self, model: Model, implicit: bool = True, pair_rows: bool = True):
        n_springs, n_elements, n_nodes = len(model.springs), model.mesh.n_elements, model.n_nodes
        self.model = model
        self.length = np.empty(n_springs)
        self.unit = np.empty((n_springs, 3))
        self.tension = np.empty(n_springs)
        self.push = np.zeros((n_elements, 3))
        self.forces = np.empty((n_nodes, 3))
        self._zero_tension = np.zeros(n_springs)  # add_damping's elastic part
        # the implicit step's arrays (empty placeholders for a forces-only workspace)
        n_springs, n_elements, n_nodes = (n_springs, n_elements, n_nodes) if implicit else (0, 0, 0)
        self.geometric = np.zeros(n_springs)
        self.volume_coefficient = np.zeros(n_elements)
        self.volume_direction = np.zeros((n_elements, 8, 3))
        self.volume_gradient = np.zeros((n_elements, 8, 3))
        self.elongation = np.empty(n_springs)
        self.delta = np.empty(n_springs)
        self.correction_kind = _CORRECTION_KIND[model.correction_mode]
        self.has_volume = model.has_volume_forces
        self.has_hourglass = model.hourglass is not None
        self.hourglass_arrays = model.hourglass_arrays
        self.rest_positions = np.ascontiguousarray(model.rest_positions, dtype=float)
        self.work = np.empty((8, 3 * n_nodes))
        # the stress correction's stiffness on each element's F (baudet-hyperelastic, implicit: (M, 9, 9)),
        # filled by a ``compute`` with ``geometric``; empty for the other models
        correction = model.stress_correction
        stressed = correction is not None and implicit
        self.stress_indptr, self.stress_nodes, self.stress_gradient = model.stress_cells if stressed else _NO_CELLS
        self.stress_tangent = np.zeros((len(correction.volume) if stressed else 0, 9, 9))
        # the assembly's positions (a stacked model's copies are assembled on one copy's: ``pair_rows`` False)
        self.stress_positions = (model.stress_pair_rows if stressed and pair_rows
                                 else np.zeros((0, 3), dtype=np.int64))
        #: elements whose correction stiffness the last ``compute`` clamped to its positive part
        self.clamped_elements = 0
        hg_indptr, hg_indices, hg_data = self.hourglass_arrays
        #: the implicit operator's data at the last ``compute`` (``kernels.OperatorData``)
        self.operator_data = kernels.OperatorData(
            model.springs, self.unit, model.stiffness, model.damping, self.geometric, model.mass, model.mesh.elements,
            model.edge_spring, model.correction_matrix, model.axis_rest_length, self.volume_coefficient,
            self.volume_direction, self.volume_gradient, hg_indptr, hg_indices, hg_data, self.elongation, self.delta,
            self.stress_indptr, self.stress_nodes, self.stress_gradient, self.stress_tangent, self.stress_positions)

    def compute(self, positions: np.ndarray, velocities: np.ndarray | None, hourglass: bool = True,
                geometric: bool = False, volume_jacobian: bool = False, exact: bool = False) -> np.ndarray:
        """Internal forces (N, 3) into ``self.forces`` (and length, unit, tension, push as
        ``spring_state``); ``geometric`` / ``volume_jacobian`` also fill the implicit step's data:
        the springs' geometric stiffness clamped at zero and the stress correction's stiffness
        (baudet-hyperelastic) clamped to its positive part, the SPD system of the implicit step
        [11], or with ``exact`` both unclamped (Newton's tangent, ``static.tangent_stiffness``)."""
        model = self.model
        positions = kernels.writeable(positions)
        use_velocity = velocities is not None
        velocities = kernels.writeable(velocities) if use_velocity else positions
        hg_indptr, hg_indices, hg_data = self.hourglass_arrays
        # the hourglass term is added below, its matrix read in node blocks (hourglass_blocks); the
        # kernel's rest positions (read by its own hourglass pass only) are the positions, as the copies'
        kernels.model_forces(
            positions, velocities, use_velocity, model.springs, model.stiffness,
            model.rest_length, model.damping, model.mesh.elements, model.edge_spring, model.correction_matrix,
            model.axis_rest_length, self.correction_kind, model.rest_edge_direction, model.rest_volume,
            model.volume_stiffness, self.has_volume, hg_indptr, hg_indices, hg_data, positions,
            False, self.length, self.unit, self.tension, self.push, self.forces, geometric, self.geometric,
            volume_jacobian and self.has_volume, self.volume_coefficient, self.volume_direction, self.volume_gradient)
        if geometric and exact:
            np.divide(self.tension, self.length, out=self.geometric)
        self._add_stress(positions, geometric, exact)
        if hourglass and self.has_hourglass:  # f -= K_hg (x - X)
            indptr, indices, values, _ = hourglass_blocks(model)
            kernels.bsr3_matvec_add(indptr, indices, values, (positions - self.rest_positions).reshape(-1), -1.0,
                                    self.forces.reshape(-1))
        return self.forces

    def _add_stress(self, positions, geometric, exact):
        """The stress correction's forces into ``self.forces`` and, with ``geometric`` (an implicit
        workspace), its stiffness into ``self.stress_tangent`` (clamped unless ``exact``)."""
        if geometric and len(self.stress_tangent):
            correction = self.model.stress_correction
            self.clamped_elements = kernels.stress_correction_tangent_add(
                positions, *stress_arguments(self.model), correction.metric_root, correction.metric_root_inverse,
                not exact, self.forces, self.stress_tangent)
        else:
            add_stress_correction(self.model, positions, self.forces)

    def add_damping(self, velocities: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """forces (N, 3) N += the springs' damping forces at ``velocities`` (N, 3) m/s along the unit
        vectors of the last ``compute``: a pass without damping (an implicit step's, reused by
        a measurement) completed to the damped forces without a second pass."""
        kernels.scatter_springs(self.model.springs, self.unit, self._zero_tension, self.model.damping, velocities, True,
                                forces)
        return forces


def add_stress_correction(model: Model, positions: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """forces (N, 3) N += the finite-strain stress correction of "baudet-hyperelastic" [11] at
    ``positions`` (N, 3) m (compiled, ``kernels.stress_correction_add``); a no-op for other models."""
    if model.stress_correction is not None:
        kernels.stress_correction_add(positions, *stress_arguments(model), forces)
    return forces


def stress_arguments(model: Model, elements_of: Model | None = None) -> tuple:
    """The arguments of the compiled stress-correction passes after the positions: the element
    nodes (n, M) of ``elements_of`` (default ``model``; a stacked model's reference copy for the
    per-copy passes), then ``model``'s correction arrays, element-last
    (``stress_correction.stress_lanes``, kept in ``model.derived``; its per-element volume, mu and
    lambda as they are), its law, and the cells of a smoothed model (``Model.stress_cells``: the
    compressed rows of ``elements_of``, the gradients of ``model``), empty for the others."""
    correction = model.stress_correction
    lanes = model.derived.get("stress_lanes", lambda: _stress.stress_lanes(correction))
    owner = model if elements_of is None else elements_of
    if model.smoothing is not None:
        indptr, nodes, _ = owner.stress_cells
        elements, gradient = _NO_ELEMENTS, model.smoothing.gradient
    else:
        # a copy (writeable) even where the transpose is contiguous already (one element): one kernel signature
        elements = owner.derived.get("element_lanes", lambda: np.array(owner.mesh.elements.T, order="C"))
        indptr, nodes, gradient = _NO_CELLS
    return (elements, lanes["mean_gradient"], correction.volume, correction.shear_modulus, correction.lame,
            lanes["spring_vector"], lanes["spring_length"], lanes["spring_stiffness"], correction.linear, indptr, nodes,
            gradient)


#: the compiled passes' placeholders: no element lanes (a smoothed model), no cells (the others)
_NO_ELEMENTS = np.zeros((0, 0), dtype=np.int64)
_NO_CELLS = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3)))


def internal_forces(model: Model, positions: np.ndarray, velocities: np.ndarray | None = None,
                    springs: SpringState | None = None, push: np.ndarray | None = None,
                    hourglass: bool = True) -> np.ndarray:
    """(N, 3) elastic + viscous spring forces, corrections, volume and hourglass forces in N
    (no gravity). Compiled kernels; ``internal_forces_reference`` is the numpy formulation.

    Args:
        positions: (N, 3) m.  velocities: (N, 3) m/s, or None for no damping.
        springs, push: a ``spring_state`` of these positions, to avoid recomputing it.
        hourglass: include the hourglass-control force (a caller may apply it its own way).
    """
    positions = np.ascontiguousarray(positions, dtype=float)
    use_velocity = velocities is not None
    velocity_array = np.ascontiguousarray(velocities, dtype=float) if use_velocity else None
    if springs is None:  # one fused pass (kernels.model_forces)
        return ForceWorkspace(model, implicit=False).compute(positions, velocity_array, hourglass=hourglass)
    forces = np.zeros_like(positions)
    kernels.scatter_springs(model.springs, springs.unit, springs.tension, model.damping,
                            velocity_array if use_velocity else positions, use_velocity, forces)
    if model.correction_mode == "fixed":
        kernels.fixed_direction_corrections(model.mesh.elements, push, model.rest_edge_direction, forces)
    if model.has_volume_forces:
        kernels.volume_pass(positions, model.mesh.elements, model.rest_volume, model.volume_stiffness, forces)
    add_stress_correction(model, positions, forces)
    if hourglass and model.hourglass is not None:
        indptr, indices, data = model.hourglass_arrays
        kernels.csr_matvec_add(indptr, indices, data, (positions - model.rest_positions).ravel(), -1.0,
                               forces.reshape(-1))
    return forces


def internal_forces_reference(model: Model, positions: np.ndarray, velocities: np.ndarray | None = None) -> np.ndarray:
    """Numpy formulation of ``internal_forces`` (reference for the compiled kernels)."""
    geometry = spring_geometry(model, positions)
    tension = model.stiffness * (geometry.length - model.rest_length)
    if velocities is not None:
        a, b = model.springs[:, 0], model.springs[:, 1]
        relative_velocity = velocities[b] - velocities[a]
        tension += model.damping * np.einsum("ij,ij->i", relative_velocity, geometry.unit)
    forces = None
    if model.correction_mode is not None:
        push = correction_pushes(model, geometry.length)
        if model.correction_mode == "projected":
            edge_push = np.repeat(push, 4, axis=1)
            tension -= np.bincount(model.edge_spring.ravel(), weights=edge_push.ravel(),
                                   minlength=len(tension))
        else:  # along the rest directions of the element edges
            edge_force = np.repeat(push, 4, axis=1)[..., None] * model.rest_edge_direction
            nodal = np.zeros((len(push), 8, 3))
            np.add.at(nodal, (slice(None), EDGES[:, 1]), edge_force)
            np.add.at(nodal, (slice(None), EDGES[:, 0]), -edge_force)
            forces = model.element_scatter @ nodal.reshape(-1, 3)
    total = model.incidence @ (tension[:, None] * geometry.unit)
    if forces is not None:
        total += forces
    if model.has_volume_forces:
        volume_force = volume_terms(model, positions)[0]
        total += model.element_scatter @ volume_force.reshape(-1, 3)
    if model.smoothing is not None:
        total += _smoothing.domain_forces(model.smoothing, positions)
    elif model.stress_correction is not None:
        nodal = _stress.element_forces(model.stress_correction, model.mesh.elements, positions)
        total += model.element_scatter @ nodal.reshape(-1, 3)
    if model.hourglass is not None:
        total -= (model.hourglass @ (positions - model.rest_positions).ravel()).reshape(-1, 3)
    return total


def external_forces(model: Model, control=None) -> np.ndarray:
    """(N, 3) gravity on the lumped masses plus the control's nodal forces, N."""
    if control is None:
        return model.gravity_force.copy()
    return model.gravity_force + control.force


def _axial_blocks(coefficient_uu, coefficient_perp, unit):
    """(S, 3, 3) blocks c_uu u u^T + c_perp (I - u u^T)."""
    outer = unit[:, :, None] * unit[:, None, :]
    return (coefficient_uu - coefficient_perp)[:, None, None] * outer + coefficient_perp[:, None, None] * np.eye(3)


def spring_block_data(model: Model, blocks: np.ndarray) -> np.ndarray:
    """Assemble per-spring 3x3 blocks B into the pattern: +B on (a,a), (b,b); -B on (a,b), (b,a)."""
    values = np.stack([blocks, blocks, -blocks, -blocks], axis=1)
    return model.pattern.assemble(model.spring_positions, values)


def element_block_data(model: Model, matrices: np.ndarray) -> np.ndarray:
    """Assemble (M, 3n, 3n) element matrices (node-major dofs, n nodes per element) into the pattern."""
    return model.pattern.assemble(model.element_positions, element_blocks(matrices, model.mesh.elements.shape[1]))


def stress_tangent_blocks(model: Model, positions: np.ndarray, clamp: bool = False) -> np.ndarray:
    """(M, 3n, 3n) V0 b (x) (A(F) - A_S(F)) (x) b in N/m: the stress correction's exact
    stiffness [11] (symmetric: the correction is the gradient of an energy); ``clamp``: each
    block's positive part, the implicit step's treatment (``stress_correction.tangent_matrices``)."""
    return _stress.tangent_blocks(model.stress_correction, model.mesh.elements, np.asarray(positions, dtype=float),
                                  clamp)


def correction_coupling(model: Model, positions: np.ndarray) -> np.ndarray:
    """(M, 24, 24) -G W^ G^T: the non-symmetric stiffness of the corrections' strain coupling [3]."""
    elements = model.mesh.elements
    corners = positions[elements]
    vector = corners[:, EDGES[:, 1]] - corners[:, EDGES[:, 0]]  # (M, 12, 3)
    unit = vector / np.linalg.norm(vector, axis=2, keepdims=True)
    n_elements = len(elements)

    def pattern_matrix(directions):
        g = np.zeros((n_elements, 8, 3, 12))
        edges = np.arange(12)
        g[:, EDGES[:, 1], :, edges] = directions.transpose(1, 0, 2)
        g[:, EDGES[:, 0], :, edges] = -directions.transpose(1, 0, 2)
        return g.reshape(n_elements, 24, 12)

    g_right = pattern_matrix(unit)
    g_left = g_right if model.correction_mode == "projected" else pattern_matrix(model.rest_edge_direction)
    # W^[e, r] = W[axis(e), axis(r)] / (4 rest length of axis(r))
    w_hat = model.correction_matrix[:, EDGE_AXIS][:, :, EDGE_AXIS] / (
        4.0 * model.axis_rest_length[:, EDGE_AXIS][:, None, :]
    )
    return -(g_left @ w_hat) @ g_right.transpose(0, 2, 1)


def stiffness_data(
    model: Model,
    positions: np.ndarray,
    *,
    corrections: str = "full",
    volume: bool = True,
    clamp: bool = False,
    stiffness_scale: float = 1.0,
    damping_scale: float = 0.0,
    mass_scale: float = 0.0,
) -> np.ndarray:
    """Values (pattern ``data``) of  mass_scale M + damping_scale D + stiffness_scale K.

    Args:
        positions: (N, 3) current positions in m.
        corrections: "full" (exact, non-symmetric), "geometric" (only the corrections' push along
            the current edges, symmetric) or "none".
        volume: include the volume forces' dominant rank-one term 2 kappa |dV| / V0^2 h grad(V)^T.
            The stress correction of "baudet-hyperelastic" (its exact tangent, ``stress_tangent_blocks``)
            is included unless ``corrections="none"``.
        clamp: drop negative geometric stiffness (compressed springs) and take the positive part
            of each element's stress-correction block (baudet-hyperelastic) so the matrix stays SPD,
            as Baraff and Witkin's implicit Euler needs for conjugate gradient [11].
    """
    geometry = spring_geometry(model, positions)
    tension = model.stiffness * (geometry.length - model.rest_length)
    push = None
    if model.correction_mode == "projected" and corrections != "none":
        push = correction_pushes(model, geometry.length)
        tension = tension - np.bincount(
            model.edge_spring.ravel(), weights=np.repeat(push, 4, axis=1).ravel(), minlength=len(tension)
        )
    geometric = tension / geometry.length
    if clamp:
        geometric = np.maximum(geometric, 0.0)
    blocks = _axial_blocks(
        stiffness_scale * model.stiffness + damping_scale * model.damping,
        stiffness_scale * geometric, geometry.unit,
    )
    data = spring_block_data(model, blocks)
    element_matrices = None
    if model.correction_mode is not None and corrections == "full":
        element_matrices = stiffness_scale * correction_coupling(model, positions)
    if volume and model.has_volume_forces:
        _, _, dphi, direction, grad = volume_terms(model, positions, gradient=True)
        rank_one = -dphi[:, None, None] * direction.reshape(-1, 24, 1) * grad.reshape(-1, 1, 24)
        rank_one *= stiffness_scale
        element_matrices = rank_one if element_matrices is None else element_matrices + rank_one
    if model.smoothing is not None and corrections != "none" and stiffness_scale:
        matrix = _smoothing.stiffness_matrix(model.smoothing, positions, clamp).tocoo()
        data += model.pattern.assemble(model.pattern.positions(matrix.row, matrix.col), stiffness_scale * matrix.data)
    elif model.stress_correction is not None and corrections != "none" and stiffness_scale:
        blocks = stiffness_scale * stress_tangent_blocks(model, positions, clamp)
        element_matrices = blocks if element_matrices is None else element_matrices + blocks
    if element_matrices is not None:
        data += element_block_data(model, element_matrices)
    if model.hourglass is not None and stiffness_scale:
        data += stiffness_scale * model.hourglass.data
    if mass_scale:
        data += mass_scale * model.mass_data
    return data
