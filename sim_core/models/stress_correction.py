"""Finite-strain stress correction of the ``baudet-hyperelastic`` model (docs/physics.md section 11).

Per element e (rest volume V0, mean shape-function gradients b_a = (1/V0) integral of grad N_a,
so that F = sum_a x_a (outer) b_a is the element's mean deformation gradient and
sum_a b_a (outer) X_a = I), the model adds to the element's 16 springs the nodal forces

    f_a = -V0 (P_NH(F) - P_S(F)) b_a,

where P_NH is the compressible neo-Hookean first Piola stress (``sim_core.solvers.hyperelastic``) and

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

from .elements import nodes_per_element, quadrature
from .laws import baudet_stiffness, first_piola_stress, lame_parameters, material_tangent
from ..geometry.mesh import signed_volumes
from ..geometry.topology import DIAGONALS, EDGES, FACES, GAUSS_GRADIENTS

#: the two diagonals of each face (FACES order): 12, grouped by the plane they lie in
FACE_DIAGONALS = np.concatenate([FACES[:, [0, 2]], FACES[:, [1, 3]]])
#: the plane of each face diagonal: the two axes (0 x, 1 y, 2 z) it spans
FACE_DIAGONAL_AXES = np.array([[1, 2], [1, 2], [0, 2], [0, 2], [0, 1], [0, 1]] * 2)

#: the stress laws of ``StressCorrection.law``
LAWS = ("neo-hookean", "linear")

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
        mean_gradient: (M, n, 3) b_a in 1/m (n = 8 hexahedra, 4 tetrahedra).
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
        law: the stress P(F) the correction completes the springs' to, one of ``LAWS``:
            "neo-hookean" (``laws.first_piola_stress``, "baudet-hyperelastic") or "linear" (the
            small-strain Hooke stress of eps = sym(F) - I, ``linear_stress``: "baudet" on tetrahedra).
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
    law: str = "neo-hookean"

    def __post_init__(self):
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {LAWS}, got {self.law!r}")
        if self.metric_root is None:
            values, vectors = np.linalg.eigh(np.einsum("maj,mal->mjl", self.mean_gradient, self.mean_gradient))
            root = np.einsum("mje,me,mle->mjl", vectors, np.sqrt(values), vectors)
            inverse = np.einsum("mje,me,mle->mjl", vectors, 1.0 / np.sqrt(values), vectors)
            object.__setattr__(self, "metric_root", np.ascontiguousarray(root))
            object.__setattr__(self, "metric_root_inverse", np.ascontiguousarray(inverse))

    @property
    def linear(self) -> bool:
        """Whether the law is the small-strain one (the compiled kernels' ``linear`` flag)."""
        return self.law == "linear"

    def arrays(self) -> dict:
        """The per-element arrays by field name (every field but ``law``), e.g. to stack copies."""
        return {name: getattr(self, name) for name in ARRAY_FIELDS}


#: the per-element array fields of ``StressCorrection`` (all but ``law``)
ARRAY_FIELDS = ("mean_gradient", "volume", "spring_vector", "spring_length", "spring_stiffness", "shear_modulus",
                "lame", "metric_root", "metric_root_inverse")


#: the per-element arrays the compiled passes read element-last (``stress_lanes``)
LANE_FIELDS = ("mean_gradient", "spring_vector", "spring_length", "spring_stiffness")


def stress_lanes(correction: StressCorrection) -> dict:
    """The correction's ``LANE_FIELDS`` in the compiled passes' element-last layout (``kernels.stress``
    runs a block of elements in the lanes of vector instructions): mean_gradient (n, 3, M) 1/m,
    spring_vector (S_e, 3, M) m, spring_length (S_e, M) m, spring_stiffness (S_e, M) N/m."""
    return {name: np.ascontiguousarray(np.moveaxis(getattr(correction, name), 0, -1)) for name in LANE_FIELDS}


def write_lanes(lanes: dict, correction: StressCorrection, elements: slice) -> None:
    """Write ``correction``'s arrays into the rows ``elements`` of ``stress_lanes`` arrays (a stacked
    model's copy, ``ModelStack.assign``)."""
    for name in LANE_FIELDS:
        lanes[name][..., elements] = np.moveaxis(getattr(correction, name), 0, -1)


def linear_stress(deformation_gradient, mu, lam):
    """P_lin(F) = lam tr(eps) I + 2 mu eps in Pa, eps = sym(F) - I: the small-strain Hooke stress
    (the tensor form of ``elements.elasticity_matrices``' law), F (..., 3, 3)."""
    f = np.asarray(deformation_gradient, float)
    strain = 0.5 * (f + f.swapaxes(-1, -2)) - np.eye(3)
    mu, lam = np.asarray(mu)[..., None, None], np.asarray(lam)[..., None, None]
    return lam * np.trace(strain, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) + 2.0 * mu * strain


def linear_tangent(mu, lam):
    """(..., 3, 3, 3, 3) A_iJkL = dP_lin / dF = lam d_iJ d_kL + mu (d_ik d_JL + d_iL d_kJ), Pa."""
    eye = np.eye(3)
    mu, lam = np.asarray(mu, float)[..., None, None, None, None], np.asarray(lam, float)[..., None, None, None, None]
    return (lam * np.einsum("ij,kl->ijkl", eye, eye)
            + mu * (np.einsum("ik,jl->ijkl", eye, eye) + np.einsum("il,jk->ijkl", eye, eye)))


def law_stress(correction: "StressCorrection", deformation_gradient):
    """(M, 3, 3) the correction's law's first Piola stress at F (M, 3, 3), Pa."""
    if correction.linear:
        return linear_stress(deformation_gradient, correction.shear_modulus, correction.lame)
    return first_piola_stress(deformation_gradient, correction.shear_modulus, correction.lame)


def law_tangent(correction: "StressCorrection", deformation_gradient):
    """(M, 3, 3, 3, 3) dP / dF of the correction's law at F (M, 3, 3), Pa."""
    if correction.linear:
        return np.broadcast_to(linear_tangent(correction.shear_modulus, correction.lame),
                               deformation_gradient.shape[:1] + (3, 3, 3, 3))
    return material_tangent(deformation_gradient, correction.shear_modulus, correction.lame)


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
    """(b (M, n, 3) in 1/m, V0 (M,) in m^3): b_a = (1/V0) int grad N_a dV of trilinear hexahedra
    (n = 8) or linear tetrahedra (n = 4, whose gradients are constant: b_a = grad N_a exactly).

    Hexahedra: 2x2x2 Gauss quadrature is exact here, det J grad_X N_a = cof(J) grad_xi N_a being a
    polynomial of degree at most 3 in each local coordinate."""
    if nodes_per_element(elements) == 4:
        gradients, weights = quadrature(nodes, elements)
        return np.ascontiguousarray(gradients[:, 0]), weights[:, 0]
    corners = nodes[elements]  # (M, 8, 3)
    jacobian = np.einsum("mna,pnb->mpab", corners, GAUSS_GRADIENTS)  # dX/dxi (M, P, 3, 3)
    det = np.linalg.det(jacobian)
    # det J J^-T: the cofactor matrix, so grad_X N det J = cof(J) grad_xi N
    cofactor = det[..., None, None] * np.linalg.inv(jacobian).swapaxes(-1, -2)
    weight = 1.0 / GAUSS_GRADIENTS.shape[0]
    integral = weight * np.einsum("mpab,pnb->mna", cofactor, GAUSS_GRADIENTS)
    volume = weight * det.sum(axis=1)
    return integral / volume[:, None, None], volume


def tetrahedron_spring_stiffness(nodes: np.ndarray, elements: np.ndarray, young_modulus, poisson_ratio) -> np.ndarray:
    """(M, 6) per-element stiffness (N/m) of each tetrahedron's 6 edge springs (``tetmesh.TET_EDGES``
    order): the largest multiple of a least-squares fit of the springs' small-strain stiffness to
    the isotropic shear stiffness that the element's Hooke tensor C still bounds from above
    (docs/physics.md section 12).

    Under a small strain eps the element's springs (rest vectors D_s, lengths L_s, unit n_s) store
    V0/2 eps : C_S : eps with C_S = sum_s kappa_s N_s (x) N_s, N_s = n_s n_s^T, kappa_s = k_s L_s^2 / V0.
    In the orthonormal (Mandel) basis of symmetric tensors, N_s is a unit 6-vector v_s and C_S =
    sum_s kappa_s v_s v_s^T. (1) w = argmin ||sum_s w_s v_s v_s^T - I_6||_F: H w = 1 with H_st =
    (v_s . v_t)^2 = (n_s . n_t)^4 (the springs' best approximation of a multiple of the identity,
    i.e. of an isotropic shear stiffness), negative entries set to 0. (2) kappa = alpha w with
    alpha = 1 / lambda_max(C^-1/2 C_S(w) C^-1/2), C^-1/2 = P_dev / sqrt(2 mu) + P_vol / sqrt(3 K):
    the largest alpha with C - C_S positive semi-definite, so the stress correction's small-strain
    stiffness V0 (C - C_S) only adds stiffness (no clamping at rest). Positive or zero for every
    tetrahedron and nu in (-1, 0.5); bounded by the shear modulus as nu -> 0.5 (the volumetric
    stiffness is the correction's alone)."""
    from ..geometry.tetmesh import TET_EDGES

    nu = np.asarray(poisson_ratio, dtype=float)
    young_modulus = np.asarray(young_modulus, dtype=float)
    shear, _ = lame_parameters(young_modulus, nu)
    bulk = young_modulus / (3.0 * (1.0 - 2.0 * nu))
    vectors = nodes[elements[:, TET_EDGES[:, 1]]] - nodes[elements[:, TET_EDGES[:, 0]]]  # (M, 6, 3)
    length = np.linalg.norm(vectors, axis=2)
    unit = vectors / length[..., None]
    volume = signed_volumes(nodes, elements)
    cosine = np.einsum("msi,mti->mst", unit, unit)
    weights = np.maximum(np.linalg.solve(cosine**4, np.ones(cosine.shape[:2])[..., None])[..., 0], 0.0)  # (M, 6)
    mandel = _mandel(np.einsum("msi,msj->msij", unit, unit))  # (M, 6, 6): v_s as rows
    springs = np.einsum("ms,msa,msb->mab", weights, mandel, mandel)
    volumetric = np.outer(_mandel(np.eye(3)), _mandel(np.eye(3))) / 3.0
    inverse_root = ((np.eye(6) - volumetric)[None] / np.sqrt(2.0 * shear)[:, None, None]
                    + volumetric[None] / np.sqrt(3.0 * bulk)[:, None, None])
    largest = np.linalg.eigvalsh(inverse_root @ springs @ inverse_root)[:, -1]
    kappa = weights / largest[:, None]
    return kappa * volume[:, None] / length**2


def _mandel(tensors: np.ndarray) -> np.ndarray:
    """(..., 6) Mandel vectors (xx, yy, zz, sqrt2 yz, sqrt2 zx, sqrt2 xy) of symmetric (..., 3, 3)
    tensors: A : B = mandel(A) . mandel(B)."""
    root = np.sqrt(2.0)
    return np.stack([tensors[..., 0, 0], tensors[..., 1, 1], tensors[..., 2, 2], root * tensors[..., 1, 2],
                     root * tensors[..., 0, 2], root * tensors[..., 0, 1]], axis=-1)


def element_spring_stiffness(axis_lengths: np.ndarray, young_modulus, poisson_ratio, choice: str = "faces"):
    """(M, S_e) per-element stiffness share (N/m) of each spring of ``element_spring_pairs(choice)``.

    "faces": the springs resist exactly the element's hourglass modes, so each is matched to the
    strain energy of the modes it sees (box of edges i, j, k, volume V). The face diagonals of the
    i-j faces take the shear modes u_i = c s_j s_k and u_j = c s_i s_k (shears linear across the
    element) with the shear modulus, k_f,ij = G V (i^2 + j^2) / (12 i^2 j^2). The bending mode
    u_i = c s_i s_j (a strain eps_ii = 2 c s_j / i linear across the element) must carry Young's
    modulus, E V c^2 (2/3) / i^2 as in a beam; the diagonals of the i-k faces stretch with it and
    already carry G V c^2 (2/3) / k^2 of it, so the edges along i take the rest,
    k_e,i = V (E / i^2 - G (1 / j^2 + 1 / k^2) / 2) / 12 (the mean over the two bending modes of
    axis i: exact for both when j = k), kept at least E V / (48 i^2) so that the twist mode
    u_i = c s_i s_j s_k, which only the edges resist, stays stiff (the bound acts on boxes
    elongated along i by about 1.4 and more). Positive for every box and every nu, and free of
    lambda: nu -> 0.5 stiffens only the correction's volumetric response, never the hourglass modes.
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
    beam = young_modulus[:, None] / squares
    across = 0.5 * shear[:, None] * (1.0 / squares[:, [1, 0, 0]] + 1.0 / squares[:, [2, 2, 1]])
    edge = volume[:, None] * np.maximum(beam - across, 0.25 * beam) / 12.0
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
    """(M, n, 3) correction forces f_a = -V0 (P(F) - P_S(F)) b_a on the element nodes, N (P the law's
    stress, ``law_stress``)."""

    f = deformation_gradients(correction, elements, positions)
    stress = law_stress(correction, f) - spring_stress(correction, f)
    return -correction.volume[:, None, None] * np.einsum("mij,maj->mai", stress, correction.mean_gradient)


def tangent_matrices(correction: StressCorrection, elements: np.ndarray, positions: np.ndarray,
                     clamp: bool = False) -> np.ndarray:
    """``tangent_matrices_at`` the elements' mean deformation gradients at ``positions`` (N, 3) m."""
    return tangent_matrices_at(correction, deformation_gradients(correction, elements, positions), clamp)


def tangent_matrices_at(correction: StressCorrection, f: np.ndarray, clamp: bool = False) -> np.ndarray:
    """(M, 9, 9) T = V0 (A_NH(F) - A_S(F)) in N m (row 3 i + J, column 3 k + L: dP_iJ / dF_kL times
    V0), the correction's stiffness on its element's F (M, 3, 3): K_e = B^T T B. ``clamp``: the implicit
    step's SPD treatment (docs/physics.md section 11, ``kernels.stress_correction_tangent_add``):
    (1) its geometric term V0 d_ik dS_JL (dS = F^-1 (P_NH - P_S)) loses its negative part, as the
    springs' geometric term does where they are compressed; (2) where the result is still not
    positive semi-definite (beyond -1e-12 of its trace), its positive part as a 24 x 24 block: with
    S = I_3 (x) R (``StressCorrection.metric_root``), B = S Q with orthonormal rows Q, so
    (B^T T B)_+ = B^T S^-1 (S T S)_+ S^-1 B. The numpy reference of the compiled pass."""
    tangent = law_tangent(correction, f) - spring_tangent(correction, f)
    tangent = correction.volume[:, None, None] * tangent.reshape(-1, 9, 9)
    if clamp and not correction.linear:  # the small-strain law has no geometric term
        stress = law_stress(correction, f) - spring_stress(correction, f)
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
    """(M, 3n, 3n) K_e = -d f_e / d x_e = V0 b (x) (A(F) - A_S(F)) (x) b in N/m (node-major dofs, n
    nodes per element); ``clamp``: its positive part (``tangent_matrices``)."""
    tangent = tangent_matrices(correction, elements, positions, clamp).reshape(-1, 3, 3, 3, 3)
    b = correction.mean_gradient
    n = 3 * b.shape[1]
    return np.einsum("maJ,miJkL,mbL->maibk", b, tangent, b, optimize=True).reshape(-1, n, n)
