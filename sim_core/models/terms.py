"""The force terms a mass-spring model is built from, one builder each (docs/physics.md sections in
brackets): each element's springs (sections 2, 11, 12) and their merge across elements, Baudet's
corrections [3], the finite-strain stress correction (sections 11, 12), the volume forces [4] and the
hourglass control [6]. ``model.build_model`` calls them in turn; a new law is a new builder here.
Every builder works per element, so that a model of a changed mesh (a cut) is these builders on
that mesh. SI units: m, Pa, N/m, N."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validate import finite_array
from .elements import element_block_positions, element_blocks, element_stiffness
from .laws import baudet_shear_ratio, baudet_stiffness, lame_parameters
from ..geometry.mesh import DIAGONALS, EDGE_AXIS, EDGES, HexMesh
from .sparse import BlockPattern, unique_keys
from .stress_correction import (StressCorrection, element_spring_pairs, element_spring_stiffness, mean_gradients,
                                merge_parallel_springs, tetrahedron_spring_stiffness)
from ..geometry.tetmesh import TET_EDGES

#: The models whose shear modulus on a box element is that of Baudet's springs (``max_shear_error``).
SPRING_SHEAR_MODELS = ("baudet", "baudet-original")


def axis_rest_lengths(mesh) -> np.ndarray:
    """(M, 3) mean rest length of each hexahedron's x-, y-, z-edges, m; (M, 0) for tetrahedra."""
    if mesh.elements.shape[1] == 4:
        return np.zeros((mesh.n_elements, 0))
    nodes, elements = mesh.nodes, mesh.elements
    edge_lengths = np.linalg.norm(nodes[elements[:, EDGES[:, 1]]] - nodes[elements[:, EDGES[:, 0]]], axis=2)
    return edge_lengths.reshape(mesh.n_elements, 3, 4).mean(axis=2)


def element_springs(mesh, model: str, young_modulus, poisson_ratio, axis_rest_length, springs: str,
                    max_shear_error) -> tuple[np.ndarray, np.ndarray]:
    """Each element's springs before they are merged: (local node pairs (P, 2), stiffness (M, P) N/m),
    the element's edges first. Tetrahedra: their 6 edges [12]; hexahedra: 12 edges and 4 inner
    diagonals (Baudet [2], or E size / 4 each for "uniform-springs"), or for "baudet-hyperelastic"
    the ``springs`` choice [11]. A non-positive spring is a ValueError (it would not resist its mode)."""
    if mesh.elements.shape[1] == 4:
        return TET_EDGES, tetrahedron_spring_stiffness(mesh.nodes, mesh.elements, young_modulus, poisson_ratio)
    if model == "baudet-hyperelastic":
        values = element_spring_stiffness(axis_rest_length, young_modulus, poisson_ratio, springs)
        _refuse_non_positive(values, lambda bad: (
            f"springs={springs!r} with poisson_ratio {poisson_ratio[bad]:g} and element {bad} of edge lengths "
            f"{np.round(axis_rest_length[bad], 6).tolist()} m gives a non-positive spring stiffness "
            f"{np.round(values[bad], 6).tolist()} N/m: the springs would not resist the hourglass modes. "
            "Use springs='faces' or 'isotropic' (positive for every box and nu)"))
        return element_spring_pairs(springs), values
    if model == "uniform-springs":
        size = axis_rest_length.mean(axis=1)
        edge_k = np.repeat((young_modulus * size / 4.0)[:, None], 3, axis=1)
        diagonal_k = young_modulus * size / 4.0
    else:
        edge_k, diagonal_k = baudet_stiffness(axis_rest_length, young_modulus, poisson_ratio)
        _refuse_non_positive(edge_k, lambda bad: (
            f"poisson_ratio {poisson_ratio[bad]:g} with element {bad} of edge lengths "
            f"{np.round(axis_rest_length[bad], 6).tolist()} m gives a non-positive edge "
            f"stiffness {np.round(edge_k[bad], 6).tolist()} N/m, which makes the element "
            "unstable (negative-energy modes). Baudet's formula needs "
            "6 j^2 k^2 (1+nu) + (nu (j^2+k^2) - i^2) D^2 > 0 for every axis i: use "
            "poisson_ratio > -0.25 and near-cubic elements, or model='baudet-hyperelastic' for box-shaped "
            "elements (its springs are positive on every box)"))
        if model in SPRING_SHEAR_MODELS and max_shear_error is not None:
            check_shear_error(model, axis_rest_length, max_shear_error)
    values = np.concatenate([edge_k[:, EDGE_AXIS], np.repeat(diagonal_k[:, None], 4, axis=1)], axis=1)
    return np.concatenate([EDGES, DIAGONALS]), values


def _refuse_non_positive(values: np.ndarray, message) -> None:
    """ValueError(``message(element)``) for the first element (row of ``values``) with a stiffness <= 0."""
    if np.any(values <= 0):
        raise ValueError(message(int(np.argmax(np.any(values <= 0, axis=1)))))


def merge_springs(mesh, local_pairs: np.ndarray, values: np.ndarray):
    """The elements' springs merged across elements (a spring shared by several elements gets the sum
    of their stiffness) [2]: springs (S, 2) node pairs, stiffness (S,) N/m, edge_spring (M, E) the
    spring of each element edge (its first E = 12 or 6 local pairs), rest_length (S,) m."""
    nodes, elements = mesh.nodes, mesh.elements
    pairs = np.sort(elements[:, local_pairs].reshape(-1, 2), axis=1).astype(np.int64)
    # one int64 key per pair: the order of unique(axis=0), several times faster (a cut merges again)
    size = max(int(mesh.n_nodes), 1)
    keys, inverse = unique_keys(pairs[:, 0] * size + pairs[:, 1], return_inverse=True)
    springs = np.stack([keys // size, keys % size], axis=1).astype(elements.dtype)
    inverse = inverse.ravel()
    stiffness = np.bincount(inverse, weights=values.ravel(), minlength=len(springs))
    edges = 6 if elements.shape[1] == 4 else 12
    edge_spring = inverse.reshape(len(elements), len(local_pairs))[:, :edges].copy()
    rest_length = np.linalg.norm(nodes[springs[:, 1]] - nodes[springs[:, 0]], axis=1)
    return springs, stiffness, edge_spring, rest_length


def masses_and_damping(mesh, density, rest_volume, springs, stiffness, damping_ratio):
    """Lumped masses (N,) kg, rho V / n to each of an element's n nodes, and spring damping (S,)
    N s/m, ``damping_ratio`` times the critical 2 sqrt(mu k) of each spring's two nodes [5]. A node
    of no element (zero mass) is a ValueError."""
    n = mesh.elements.shape[1]
    mass = np.bincount(
        mesh.elements.ravel(), weights=np.repeat(density * rest_volume / n, n), minlength=mesh.n_nodes
    )
    if not np.all(mass > 0):
        orphans = np.flatnonzero(~(mass > 0))
        raise ValueError(f"nodes {orphans[:10].tolist()}{' ...' if len(orphans) > 10 else ''} belong to no element: "
                         "a node of no element has no mass; remove it from the mesh (every node must be in an element)")
    reduced_mass = mass[springs[:, 0]] * mass[springs[:, 1]] / (mass[springs[:, 0]] + mass[springs[:, 1]])
    damping = damping_ratio * 2.0 * np.sqrt(reduced_mass * np.abs(stiffness))
    return mass, damping


def baudet_corrections(model: str, axis_rest_length, young_modulus, poisson_ratio, nu_factor: bool):
    """Baudet's correction forces [3]: (W (M, 3, 3), mode) with T_j = sum_m W_jm eps_m the push along
    each j-edge. "baudet": stress-based, projected on the deformed edges ("projected"); "baudet-original":
    as published (half size, strain-based, along the rest directions: "fixed", times nu with
    ``nu_factor``); other models: none (zeros, None)."""
    if model == "baudet":
        return correction_matrix(axis_rest_length, young_modulus, poisson_ratio), "projected"
    if model == "baudet-original":
        scale = 0.5 * (poisson_ratio if nu_factor else 1.0)
        w = correction_matrix(axis_rest_length, young_modulus, poisson_ratio, stress_based=False, scale=1.0)
        return w * (scale[:, None, None] if np.ndim(scale) else scale), "fixed"
    return np.zeros((len(axis_rest_length), 3, 3)), None


def stress_correction(mesh, local_pairs, values, young_modulus, poisson_ratio, law: str) -> StressCorrection:
    """The finite-strain stress correction (sections 11, 12): per element, f_a = -V0 (P(F) - P_S(F)) b_a on
    its mean deformation gradient, P the ``law``'s stress ("neo-hookean" or "linear") and P_S the
    stress of its springs (``local_pairs``, ``values`` (M, P) N/m; a hexahedron's parallel springs
    merged into one per direction)."""
    nodes, elements = mesh.nodes, mesh.elements
    gradient, volume = mean_gradients(nodes, elements)
    vectors = nodes[elements[:, local_pairs[:, 1]]] - nodes[elements[:, local_pairs[:, 0]]]
    if elements.shape[1] == 8:
        vectors, values = merge_parallel_springs(vectors, values)
    shear, lame = lame_parameters(young_modulus, poisson_ratio)
    return StressCorrection(
        mean_gradient=np.ascontiguousarray(gradient), volume=volume, spring_vector=np.ascontiguousarray(vectors),
        spring_length=np.linalg.norm(vectors, axis=2), spring_stiffness=np.ascontiguousarray(values),
        shear_modulus=np.asarray(shear, float), lame=np.asarray(lame, float), law=law)


def volume_stiffness(young_modulus, poisson_ratio, rest_volume, scale: float) -> np.ndarray:
    """(M,) the volume forces' kappa = scale K V0^(2/3) in N, K = E / (3 (1 - 2 nu)) the bulk modulus [4]."""
    bulk = young_modulus / (3.0 * (1.0 - 2.0 * poisson_ratio))
    return scale * bulk * rest_volume ** (2.0 / 3.0)


def correction_coefficients(axis_lengths: np.ndarray, poisson_ratio) -> np.ndarray:
    """(M, 3, 3) C[i, j] of docs/physics.md section 3 (zero on the diagonal); cube: -(4 nu - 1) / 2."""
    nu = poisson_ratio
    d2 = (axis_lengths**2).sum(axis=1)
    coefficients = np.zeros((len(axis_lengths), 3, 3))
    for i_axis in range(3):
        for j_axis in range(3):
            if i_axis == j_axis:
                continue
            k_axis = 3 - i_axis - j_axis
            i, j, k = (axis_lengths[:, a] for a in (i_axis, j_axis, k_axis))
            coefficients[:, i_axis, j_axis] = -(
                d2 * (nu * (i**2 + k**2) - i**2) + 6.0 * nu * i**2 * k**2
            ) / (6.0 * i * j * k**2)
    return coefficients


def correction_matrix(axis_lengths, young_modulus, poisson_ratio, *, stress_based=True, scale=1.0):
    """(M, 3, 3) W mapping element strains eps_m to the push T_j on each j-edge (N) [3].

    T_j = 1/4 sum_{i != j} C_ij F_i, F_i = A_i sigma_i (stress-based, A_i = V / i0) or
    F_i = E A_i eps_i (strain-based, the published variant). ``scale`` multiplies everything
    (0.5 reproduces the report's /48 form).
    """
    coefficients = correction_coefficients(axis_lengths, poisson_ratio)
    volume = np.prod(axis_lengths, axis=1)
    area = volume[:, None] / axis_lengths  # A_i, (M, 3)
    nu = poisson_ratio
    if stress_based:
        lame = young_modulus * nu / ((1 + nu) * (1 - 2 * nu))
        shear = young_modulus / (2 * (1 + nu))
        stress = lame[:, None, None] * np.ones((1, 3, 3)) + 2 * shear[:, None, None] * np.eye(3)
    else:
        stress = young_modulus[:, None, None] * np.eye(3)[None]
    # W_jm = 1/4 sum_i C_ij A_i S_im
    return 0.25 * scale * np.einsum("mij,mi,mik->mjk", coefficients, area, stress)


def check_shear_error(model: str, axis_lengths: np.ndarray, max_shear_error: float) -> None:
    """ValueError when the springs of ``model`` ("baudet", "baudet-original") give an element of
    rest edge lengths ``axis_lengths`` (M, 3) m a shear modulus more than ``max_shear_error``
    (relative, >= 0) off in some plane (docs/physics.md section 2)."""
    max_shear_error = float(finite_array("max_shear_error", max_shear_error))
    if max_shear_error < 0:
        raise ValueError(f"max_shear_error must be None or >= 0 (a relative error), got {max_shear_error}")
    error = np.abs(baudet_shear_ratio(axis_lengths) - 1.0)  # (M, 3)
    if np.all(error <= max_shear_error):
        return
    bad = int(np.argmax(error.max(axis=1)))
    plane = int(np.argmax(error[bad]))
    raise ValueError(
        f"model={model!r} gives element {bad} of edge lengths {np.round(axis_lengths[bad], 6).tolist()} m a shear "
        f"modulus {baudet_shear_ratio(axis_lengths[bad])[plane]:.3f} times the material's in the plane normal to "
        f"axis {'xyz'[plane]} (Baudet's springs give D^2 / (3 k^2) G: exact on cubes only, docs/physics.md "
        f"section 2), beyond max_shear_error={max_shear_error:g}. For box-shaped elements use "
        f"model='baudet-hyperelastic' (its stress correction gives the exact shear modulus on every box), or the "
        f"tetrahedral path (a TetMesh, element='tet' in the experiments); or mesh with near-cubic elements "
        f"(1:1:a with a in about [0.96, 1.04] at 5%); max_shear_error=None accepts the error")


def hourglass_projectors(nodes: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(M, 8, 8) orthogonal projectors on each element's hourglass space: the nodal fields
    orthogonal to 1, X, Y, Z of its rest corners (4-dimensional for any valid hexahedron)."""
    if elements.shape[1] != 8:
        raise ValueError(f"hourglass projectors need (M, 8) hexahedra, got elements of shape {elements.shape}: "
                         "a linear tetrahedron's displacements are all affine (it has no hourglass space)")
    corners = nodes[elements]  # (M, 8, 3)
    affine = np.concatenate([np.ones((len(elements), 8, 1)), corners - corners.mean(axis=1, keepdims=True)], axis=2)
    q, _ = np.linalg.qr(affine)  # (M, 8, 4) orthonormal basis of the affine fields
    return np.eye(8)[None] - q @ q.transpose(0, 2, 1)


def hourglass_element_matrices(mesh: HexMesh, young_modulus, poisson_ratio, alpha: float) -> np.ndarray:
    """(M, 24, 24) alpha (P_e x I3) K_e^FEM (P_e x I3) per element (N/m): each depends on its element's
    rest corners and material alone, so a cut mesh's are its uncut mesh's [6]."""
    projector = hourglass_projectors(mesh.nodes, mesh.elements)
    full = np.einsum("mab,ij->maibj", projector, np.eye(3)).reshape(-1, 24, 24)
    stiffness = element_stiffness(mesh.nodes, mesh.elements, young_modulus, poisson_ratio)
    return alpha * full @ stiffness @ full


def hourglass_matrix(mesh: HexMesh, young_modulus, poisson_ratio, alpha: float, matrices=None,
                     pattern: BlockPattern | None = None, positions=None) -> sp.csr_matrix:
    """alpha sum_e (P_e x I3) K_e^FEM (P_e x I3): FEM stiffness restricted to hourglass modes (N/m),
    assembled from ``matrices`` (``hourglass_element_matrices``; None: computed here) on ``pattern``
    (the ``BlockPattern`` of the mesh's elements, its index arrays shared) at the element blocks'
    ``positions`` in it (``element_block_positions``); None: built here."""
    if matrices is None:
        matrices = hourglass_element_matrices(mesh, young_modulus, poisson_ratio, alpha)
    if pattern is None:
        pattern = BlockPattern(mesh.n_nodes, mesh.elements)
    if positions is None:
        positions = element_block_positions(pattern, mesh.elements)
    return pattern.matrix(pattern.assemble(positions, element_blocks(matrices, 8)))
