"""Finite-strain stress correction of the ``baudet-hyperelastic`` model (docs/physics.md section 11).

Per element e (rest volume V0, mean shape-function gradients b_a = (1/V0) integral of grad N_a,
so that F = sum_a x_a (outer) b_a is the element's mean deformation gradient and
sum_a b_a (outer) X_a = I), the model adds to the element's 16 springs the nodal forces

    f_a = -V0 (P_NH(F) - P_S(F)) b_a,

where P_NH is the compressible neo-Hookean first Piola stress (``sim_core.hyperelastic``) and

    P_S(F) = (1/V0) sum_s k_s (|F D_s| - L_s) (F D_s / |F D_s|) (outer) D_s

the first Piola stress the element's own springs (rest vectors D_s, lengths L_s, the element's
share k_s of their stiffness) produce under the homogeneous deformation F. The correction is the
gradient of the energy V0 (W_NH(F) - W_S(F)), so under any homogeneous deformation the element's
energy is exactly V0 W_NH(F) (the springs' energy is V0 W_S(F) there): the homogeneous response is
neo-Hookean at every strain and every Poisson ratio, whatever the springs, while the springs alone
resist the element's non-affine (hourglass) deformations, which leave F unchanged.

Everything here is numpy, vectorised over elements: the readable reference of the compiled pass
``kernels.stress_correction_add`` and the correction's analytic tangent (``tangent_blocks``).
SI units: m, Pa, N, N/m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .laws import baudet_stiffness, first_piola_stress, material_tangent
from .topology import DIAGONALS, EDGES, FACES, GAUSS_GRADIENTS

#: the two diagonals of each face (FACES order): 12, grouped by the plane they lie in
FACE_DIAGONALS = np.concatenate([FACES[:, [0, 2]], FACES[:, [1, 3]]])
#: the plane of each face diagonal: the two axes (0 x, 1 y, 2 z) it spans
FACE_DIAGONAL_AXES = np.array([[1, 2], [1, 2], [0, 2], [0, 2], [0, 1], [0, 1]] * 2)

#: spring sets of ``build_model(model="baudet-hyperelastic", springs=...)``: "faces" (12 edges and
#: the 12 face diagonals), "isotropic" and "baudet" (12 edges and the 4 inner diagonals)
SPRING_CHOICES = ("faces", "isotropic", "baudet")


def element_spring_pairs(choice: str) -> np.ndarray:
    """(S_e, 2) local corner pairs of an element's springs: the 12 edges (EDGES order) first."""
    if choice not in SPRING_CHOICES:
        raise ValueError(f"springs must be one of {SPRING_CHOICES}, got {choice!r}")
    return np.concatenate([EDGES, FACE_DIAGONALS if choice == "faces" else DIAGONALS])


@dataclass(frozen=True, eq=False)
class StressCorrection:
    """Per-element arrays of the stress correction (M elements).

    Attributes:
        mean_gradient: (M, 8, 3) b_a in 1/m.
        volume: (M,) rest volumes V0 in m^3.
        spring_vector: (M, S_e, 3) rest vectors D_s of the element's springs
            (``element_spring_pairs``; parallel ones merged, ``merge_parallel_springs``), m.
        spring_length: (M, S_e) L_s = |D_s| in m.
        spring_stiffness: (M, S_e) the element's share k_s of each spring's stiffness, N/m.
        shear_modulus, lame: (M,) mu and lambda of the neo-Hookean law, Pa.
        metric_root, metric_root_inverse: (M, 3, 3) R = (sum_a b_a b_a^T)^(1/2) and R^-1 (1/m, m),
            derived from ``mean_gradient`` when not given: B B^T = I_3 (x) R^2 for the map B from the
            element's nodal displacements to F, the metric in which the implicit step takes the
            positive part of the correction's stiffness (``tangent_matrices``).
    """

    mean_gradient: np.ndarray
    volume: np.ndarray
    spring_vector: np.ndarray
    spring_length: np.ndarray
    spring_stiffness: np.ndarray
    shear_modulus: np.ndarray
    lame: np.ndarray
    metric_root: np.ndarray | None = None
    metric_root_inverse: np.ndarray | None = None

    def __post_init__(self):
        if self.metric_root is None:
            values, vectors = np.linalg.eigh(np.einsum("maj,mal->mjl", self.mean_gradient, self.mean_gradient))
            root = np.einsum("mje,me,mle->mjl", vectors, np.sqrt(values), vectors)
            inverse = np.einsum("mje,me,mle->mjl", vectors, 1.0 / np.sqrt(values), vectors)
            object.__setattr__(self, "metric_root", np.ascontiguousarray(root))
            object.__setattr__(self, "metric_root_inverse", np.ascontiguousarray(inverse))


def merge_parallel_springs(vectors: np.ndarray, stiffness: np.ndarray, tolerance: float = 1e-10):
    """(vectors (M, G, 3), stiffness (M, G)): the element's springs with equal rest vectors up to sign
    merged into one of summed stiffness (P_S and A_S depend on a spring only through k_s, D_s and
    |D_s|, and D_s and -D_s give the same terms), when every element has the same groups (a box
    mesh: 24 springs -> 3 edge directions + 6 face-diagonal directions, 9); else the input. The
    stress correction's pass then costs a third of its spring loop (``kernels.stress_correction_add``)."""
    first = vectors[0]
    scale = np.linalg.norm(first, axis=1)
    groups, signs = [], []
    assigned = np.full(len(first), -1)
    for s in range(len(first)):
        if assigned[s] >= 0:
            continue
        members = [s]
        member_signs = [1.0]
        for q in range(s + 1, len(first)):
            if assigned[q] >= 0:
                continue
            for sign in (1.0, -1.0):
                if np.linalg.norm(first[q] - sign * first[s]) <= tolerance * scale[s]:
                    members.append(q)
                    member_signs.append(sign)
                    break
        assigned[members] = len(groups)
        groups.append(np.array(members))
        signs.append(np.array(member_signs))
    if len(groups) == len(first):
        return vectors, stiffness
    lengths = np.linalg.norm(vectors, axis=2)
    for members, member_signs in zip(groups, signs):
        reference = vectors[:, members[0]]
        difference = vectors[:, members] - member_signs[None, :, None] * reference[:, None, :]
        if np.any(np.linalg.norm(difference, axis=2) > tolerance * lengths[:, members]):
            return vectors, stiffness
    merged_vectors = np.stack([vectors[:, members[0]] for members in groups], axis=1)
    merged_stiffness = np.stack([stiffness[:, members].sum(axis=1) for members in groups], axis=1)
    return np.ascontiguousarray(merged_vectors), np.ascontiguousarray(merged_stiffness)


def mean_gradients(nodes: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(b (M, 8, 3) in 1/m, V0 (M,) in m^3) of trilinear hexahedra: b_a = (1/V0) int grad N_a dV.

    2x2x2 Gauss quadrature is exact here: det J grad_X N_a = cof(J) grad_xi N_a is a polynomial of
    degree at most 3 in each local coordinate."""
    corners = nodes[elements]  # (M, 8, 3)
    jacobian = np.einsum("mna,pnb->mpab", corners, GAUSS_GRADIENTS)  # dX/dxi (M, P, 3, 3)
    det = np.linalg.det(jacobian)
    # det J J^-T: the cofactor matrix, so grad_X N det J = cof(J) grad_xi N
    cofactor = det[..., None, None] * np.linalg.inv(jacobian).swapaxes(-1, -2)
    weight = 1.0 / GAUSS_GRADIENTS.shape[0]
    integral = weight * np.einsum("mpab,pnb->mna", cofactor, GAUSS_GRADIENTS)
    volume = weight * det.sum(axis=1)
    return integral / volume[:, None, None], volume


def element_spring_stiffness(axis_lengths: np.ndarray, young_modulus, poisson_ratio, choice: str = "faces"):
    """(M, S_e) per-element stiffness share (N/m) of each spring of ``element_spring_pairs(choice)``.

    "faces": the springs resist exactly the element's hourglass modes, so each is matched to the
    strain energy of the modes it sees (box of edges i, j, k, volume V): the edges along i take the
    bending modes (u_i = c s_i s_j, a strain eps_ii = 2 c s_j / i linear across the element) with
    Young's modulus, k_e,i = E V / (12 i^2); the face diagonals of the i-j faces take the modes
    u_i = c s_j s_k and u_j = c s_i s_k (shears linear across the element) with the shear modulus,
    k_f,ij = G V (i^2 + j^2) / (12 i^2 j^2). Positive for every box and every nu, and free of lambda:
    nu -> 0.5 stiffens only the correction's volumetric response, never the hourglass modes.
    Others: 12 edges then the 4 inner diagonals with ``spring_stiffness``'s (edge, diagonal) values.
    """
    if choice != "faces":
        edge, diagonal = spring_stiffness(axis_lengths, young_modulus, poisson_ratio, choice)
        return np.concatenate([edge[:, np.repeat(np.arange(3), 4)], np.repeat(diagonal[:, None], 4, axis=1)], axis=1)
    nu = np.asarray(poisson_ratio, dtype=float)
    young_modulus = np.asarray(young_modulus, dtype=float)
    shear = young_modulus / (2.0 * (1.0 + nu))
    volume = np.prod(axis_lengths, axis=1)
    squares = axis_lengths**2
    edge = young_modulus[:, None] * volume[:, None] / (12.0 * squares)
    i, j = squares[:, FACE_DIAGONAL_AXES[:, 0]], squares[:, FACE_DIAGONAL_AXES[:, 1]]
    face = shear[:, None] * volume[:, None] * (i + j) / (12.0 * i * j)
    return np.concatenate([edge[:, np.repeat(np.arange(3), 4)], face], axis=1)


def spring_stiffness(axis_lengths: np.ndarray, young_modulus, poisson_ratio, choice: str = "isotropic"):
    """Per-element stiffnesses (edge (M, 3) of the x-, y-, z-edges, inner diagonal (M,)) in N/m.

    "isotropic": the springs of a nu = 1/4 (Cauchy) solid of shear modulus mu_S, with
    mu_S = min(mu, 3 K / 5) (K the bulk modulus): on a cube, edges k_e = mu_S l / 2 and diagonals
    k_d = 3 mu_S l / 4, whose small-strain stress is mu_S (tr(eps) I + 2 eps). Then
    C_NH - C_S = (lambda - mu_S) I (x) I + 2 (mu - mu_S) I_sym is positive semi-definite: the
    correction adds stiffness, never removes it. Boxes: k_e,i = mu_S V / (2 i^2) and
    k_d = mu_S V D^2 / (4 max(i^2 j^2)) (no plane sheared stiffer than mu_S), positive for every
    box, every nu in (-1, 0.5); the stiffness never grows with lambda, so nu -> 0.5 stiffens only
    the correction's volumetric part.
    "baudet": Baudet's formula (``model.baudet_stiffness``), non-positive on elongated boxes.
    """
    if choice == "baudet":

        return baudet_stiffness(axis_lengths, young_modulus, poisson_ratio)
    if choice != "isotropic":
        raise ValueError(f"springs must be one of {SPRING_CHOICES}, got {choice!r}")
    nu = np.asarray(poisson_ratio, dtype=float)
    mu = young_modulus / (2.0 * (1.0 + nu))
    bulk = young_modulus / (3.0 * (1.0 - 2.0 * nu))
    spring_shear = np.minimum(mu, 0.6 * bulk)
    volume = np.prod(axis_lengths, axis=1)
    squares = axis_lengths**2
    d2 = squares.sum(axis=1)
    plane = np.stack([squares[:, 0] * squares[:, 1], squares[:, 1] * squares[:, 2],
                      squares[:, 0] * squares[:, 2]], axis=1).max(axis=1)
    edge = spring_shear[:, None] * volume[:, None] / (2.0 * squares)
    diagonal = spring_shear * volume * d2 / (4.0 * plane)
    return edge, diagonal


def spring_stress(correction: StressCorrection, deformation_gradient: np.ndarray) -> np.ndarray:
    """(M, 3, 3) P_S(F) in Pa: the springs' first Piola stress under the homogeneous F (M, 3, 3)."""
    current = np.einsum("mij,msj->msi", deformation_gradient, correction.spring_vector)
    length = np.linalg.norm(current, axis=2)
    scale = correction.spring_stiffness * (length - correction.spring_length) / length
    return np.einsum("ms,msi,msj->mij", scale, current, correction.spring_vector) / correction.volume[:, None, None]


def spring_tangent(correction: StressCorrection, deformation_gradient: np.ndarray) -> np.ndarray:
    """(M, 3, 3, 3, 3) A_S = dP_S / dF in Pa:
    (1/V0) sum_s k_s [(1 - L_s/l_s) d_ik + (L_s/l_s) n_i n_k] D_J D_L, n = F D_s / l_s."""
    current = np.einsum("mij,msj->msi", deformation_gradient, correction.spring_vector)
    length = np.linalg.norm(current, axis=2)
    unit = current / length[..., None]
    ratio = correction.spring_length / length
    k = correction.spring_stiffness / correction.volume[:, None]
    axial = np.einsum("ms,msi,msk->msik", k * ratio, unit, unit) + (k * (1.0 - ratio))[..., None, None] * np.eye(3)
    return np.einsum("msik,msJ,msL->miJkL", axial, correction.spring_vector, correction.spring_vector)


def deformation_gradients(correction: StressCorrection, elements: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(M, 3, 3) mean deformation gradients F = sum_a x_a (outer) b_a of positions (N, 3) m."""
    return np.einsum("mai,maj->mij", positions[elements], correction.mean_gradient)


def element_forces(correction: StressCorrection, elements: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(M, 8, 3) correction forces f_a = -V0 (P_NH(F) - P_S(F)) b_a on the element nodes, N."""

    f = deformation_gradients(correction, elements, positions)
    stress = first_piola_stress(f, correction.shear_modulus, correction.lame) - spring_stress(correction, f)
    return -correction.volume[:, None, None] * np.einsum("mij,maj->mai", stress, correction.mean_gradient)


def tangent_matrices(correction: StressCorrection, elements: np.ndarray, positions: np.ndarray,
                     clamp: bool = False) -> np.ndarray:
    """(M, 9, 9) T = V0 (A_NH(F) - A_S(F)) in N m (row 3 i + J, column 3 k + L: dP_iJ / dF_kL times
    V0), the correction's stiffness on its element's F: K_e = B^T T B. ``clamp``: the implicit
    step's SPD treatment (docs/physics.md section 11, ``kernels.stress_correction_tangent_add``):
    (1) its geometric term V0 d_ik dS_JL (dS = F^-1 (P_NH - P_S)) loses its negative part, as the
    springs' geometric term does where they are compressed; (2) where the result is still not
    positive semi-definite (beyond -1e-12 of its trace), its positive part as a 24 x 24 block: with
    S = I_3 (x) R (``StressCorrection.metric_root``), B = S Q with orthonormal rows Q, so
    (B^T T B)_+ = B^T S^-1 (S T S)_+ S^-1 B. The numpy reference of the compiled pass."""

    f = deformation_gradients(correction, elements, positions)
    tangent = material_tangent(f, correction.shear_modulus, correction.lame) - spring_tangent(correction, f)
    tangent = correction.volume[:, None, None] * tangent.reshape(-1, 9, 9)
    if clamp:
        stress = first_piola_stress(f, correction.shear_modulus, correction.lame) - spring_stress(correction, f)
        second = np.linalg.solve(f, stress)  # F^-1 dP
        values, vectors = np.linalg.eigh(0.5 * (second + second.swapaxes(1, 2)))
        negative = np.einsum("mje,me,mle->mjl", vectors, np.maximum(-values, 0.0), vectors)
        tangent = tangent + correction.volume[:, None, None] * np.einsum("ik,mJL->miJkL", np.eye(3), negative).reshape(
            -1, 9, 9)
        symmetric = 0.5 * (tangent + tangent.swapaxes(1, 2))
        trace = np.abs(np.trace(tangent, axis1=1, axis2=2))
        indefinite = np.linalg.eigvalsh(symmetric)[:, 0] < -1e-12 * trace
        if np.any(indefinite):
            eye = np.eye(3)
            root = np.einsum("ik,mJL->miJkL", eye, correction.metric_root[indefinite]).reshape(-1, 9, 9)
            root_inverse = np.einsum("ik,mJL->miJkL", eye, correction.metric_root_inverse[indefinite]).reshape(-1, 9, 9)
            weighted = root @ tangent[indefinite] @ root
            values, vectors = np.linalg.eigh(0.5 * (weighted + weighted.swapaxes(1, 2)))
            positive = np.einsum("mre,me,mqe->mrq", vectors, np.maximum(values, 0.0), vectors)
            tangent[indefinite] = root_inverse @ positive @ root_inverse
    return tangent


def tangent_blocks(correction: StressCorrection, elements: np.ndarray, positions: np.ndarray,
                   clamp: bool = False) -> np.ndarray:
    """(M, 24, 24) K_e = -d f_e / d x_e = V0 b (x) (A_NH(F) - A_S(F)) (x) b in N/m (node-major dofs);
    ``clamp``: its positive part (``tangent_matrices``)."""
    tangent = tangent_matrices(correction, elements, positions, clamp).reshape(-1, 3, 3, 3, 3)
    b = correction.mean_gradient
    return np.einsum("maJ,miJkL,mbL->maibk", b, tangent, b, optimize=True).reshape(-1, 24, 24)
