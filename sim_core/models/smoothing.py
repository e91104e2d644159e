"""Smoothed strain on tetrahedra (docs/physics.md section 12): the law evaluated on deformation
gradients averaged over domains around the mesh's edges and nodes instead of on each linear
tetrahedron's own, so that a tetrahedral model neither locks near nu = 0.5 nor stiffens in bending.

A domain d takes a share of each tetrahedron t around it, a sixth of its volume per edge and a quarter
per node, and its deformation gradient is the volume-weighted mean of theirs,

    F_d = sum_t w_dt F_t = sum_a x_a (outer) b_da,   b_da = sum_t w_dt b_ta,   w_dt = (V_t / k) / V_d,

with k = 6 (edge domains) or 4 (node domains) and V_d = sum_t V_t / k: a domain is a generalised
element whose "mean gradients" b_da run over the nodes of its tetrahedra. The energy is
sum_d V_d W_d(F_d) and the nodal forces f_a = -sum_d V_d P_d(F_d) b_da, so every domain is the
stress correction of section 11 on its own F (without springs): the same law code, the same
tangent and positive part in the implicit step. The law is split between the two kinds of domains:
on edge domains the law with its volumetric stiffness removed (mu, lambda = -2 mu / 3), on node
domains the pure volume term (mu = 0, lambda + 2 mu / 3). The two sum to the law (mu, lambda) under
every homogeneous deformation (each domain sees the same F then), at every strain: edge domains
carry the deviatoric (shape) stiffness, which they soften in bending by coupling neighbouring
elements across every face; node domains carry the bulk stiffness with one volume constraint per
node against three displacement components, which cannot lock. With material varying per element,
a domain takes the volume-weighted mean of its tetrahedra's mu and lambda (each tetrahedron's share
of the domain's energy at the domain's F).

The domains are stored as compressed rows (``indptr``, ``nodes``, ``gradient``): domain d couples the
nodes ``nodes[indptr[d]:indptr[d + 1]]`` (sorted) with gradients ``gradient[...]`` (1/m); its
per-domain law arrays (volume, mu, lambda, metric roots, no springs) are a ``StressCorrection``
(``law``). Edge domains come first, in the model's spring order (a tetrahedral model's springs are
its edges), then the node domains of the nodes of some tetrahedron, in node order. SI units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .stress_correction import StressCorrection, law_stress, tangent_matrices_at

#: ``build_model(TetMesh, ..., smoothing=...)``: "edge-node" (this module, the default on
#: tetrahedra) or "none" (each tetrahedron's own F: exactly linear-tetrahedron FEM, which locks)
SMOOTHING = ("edge-node", "none")

#: the domains' share of each tetrahedron's volume: a sixth per edge, a quarter per node
EDGE_SHARE, NODE_SHARE = 6, 4


@dataclass(frozen=True, eq=False)
class SmoothedStrain:
    """The smoothing domains of a tetrahedral model (D domains, nnz domain-node entries).

    Attributes:
        indptr: (D + 1,) int64, domain d's entries are ``indptr[d]:indptr[d + 1]``.
        nodes: (nnz,) int64 node of each entry (sorted within a domain).
        gradient: (nnz, 3) b_da in 1/m: F_d = sum over d's entries of x_a (outer) b_da.
        law: the per-domain law arrays (``StressCorrection`` with no springs and no element
            gradients: volume V_d m^3, shear_modulus and lame Pa, metric roots of the domain's
            gradients, the law "linear" or "neo-hookean").
    """

    indptr: np.ndarray
    nodes: np.ndarray
    gradient: np.ndarray
    law: StressCorrection

    @property
    def n_domains(self) -> int:
        return len(self.indptr) - 1

    def pairs(self) -> np.ndarray:
        """(P, 2) node pairs of every domain (``cell_pairs``): the entries its stiffness fills."""
        return cell_pairs(self.indptr, self.nodes)


def cell_pairs(indptr: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """(P, 2) the node pairs (a, b) of every cell held in compressed rows (cell c's nodes
    ``nodes[indptr[c]:indptr[c + 1]]``), cell by cell, a-major within a cell: sum over cells of n_c^2."""
    counts = np.diff(indptr)
    per_entry = np.repeat(counts, counts)  # n_c of each entry's cell
    rows = np.repeat(np.arange(len(nodes)), per_entry)  # entry a, once per entry b of its cell
    block_start = np.repeat(np.cumsum(per_entry) - per_entry, per_entry)
    columns = np.repeat(np.repeat(indptr[:-1], counts), per_entry) + np.arange(len(rows)) - block_start
    return np.stack([nodes[rows], nodes[columns]], axis=1)


def smoothed_strain(nodes: np.ndarray, elements: np.ndarray, edge_spring: np.ndarray, n_springs: int,
                    gradient: np.ndarray, volume: np.ndarray, shear_modulus, lame, law: str) -> SmoothedStrain:
    """The edge and node domains of the tetrahedra ``elements`` (M, 4) on ``nodes`` (N, 3) m, their
    edges' springs ``edge_spring`` (M, 6) (``n_springs`` in all), element gradients ``gradient``
    (M, 4, 3) 1/m and volumes (M,) m^3, the per-element mu and lambda (M,) Pa and the ``law``."""
    n_elements, n_nodes = len(elements), len(nodes)
    shear_modulus = np.broadcast_to(np.asarray(shear_modulus, float), (n_elements,))
    lame = np.broadcast_to(np.asarray(lame, float), (n_elements,))
    # (domain, element, share of the element's volume) pairs: edges first, then nodes
    domain = np.concatenate([edge_spring.ravel(), n_springs + elements.ravel()])
    element = np.concatenate([np.repeat(np.arange(n_elements), EDGE_SHARE), np.repeat(np.arange(n_elements), NODE_SHARE)])
    share = np.concatenate([np.repeat(volume / EDGE_SHARE, EDGE_SHARE), np.repeat(volume / NODE_SHARE, NODE_SHARE)])
    # compact numbering: every spring is an edge of some tetrahedron; a node of no tetrahedron has no domain
    used, domain = np.unique(domain, return_inverse=True)
    domain = domain.ravel()
    if not np.array_equal(used[:n_springs], np.arange(n_springs)):
        raise ValueError("every spring of a smoothed tetrahedral model must be an edge of a tetrahedron")
    n_domains = len(used)
    domain_volume = np.bincount(domain, weights=share, minlength=n_domains)
    weight = share / domain_volume[domain]
    mu = np.bincount(domain, weights=weight * shear_modulus[element], minlength=n_domains)
    lam = np.bincount(domain, weights=weight * lame[element], minlength=n_domains)
    edge = np.arange(n_domains) < n_springs
    # the law split: edges the law without its bulk stiffness, nodes the bulk stiffness alone
    domain_mu = np.where(edge, mu, 0.0)
    domain_lame = np.where(edge, -2.0 * mu / 3.0, lam + 2.0 * mu / 3.0)
    # b_da = sum_t w_dt b_ta, summed over the (domain, node) keys of every (pair, corner)
    corner_domain = np.repeat(domain, 4)
    corner_node = elements[element].ravel()
    corner_gradient = (weight[:, None, None] * gradient[element]).reshape(-1, 3)
    keys = corner_domain.astype(np.int64) * n_nodes + corner_node
    unique_keys, entry = np.unique(keys, return_inverse=True)
    entry = entry.ravel()
    entries = np.stack([np.bincount(entry, weights=corner_gradient[:, j], minlength=len(unique_keys))
                        for j in range(3)], axis=1)
    entry_domain = unique_keys // n_nodes
    indptr = np.searchsorted(entry_domain, np.arange(n_domains + 1)).astype(np.int64)
    metric = np.zeros((n_domains, 3, 3))
    np.add.at(metric, entry_domain, np.einsum("ej,el->ejl", entries, entries))
    values, vectors = np.linalg.eigh(metric)
    root = np.einsum("mje,me,mle->mjl", vectors, np.sqrt(values), vectors)
    root_inverse = np.einsum("mje,me,mle->mjl", vectors, 1.0 / np.sqrt(values), vectors)
    law_arrays = StressCorrection(
        mean_gradient=np.zeros((n_domains, 0, 3)), volume=domain_volume, spring_vector=np.zeros((n_domains, 0, 3)),
        spring_length=np.zeros((n_domains, 0)), spring_stiffness=np.zeros((n_domains, 0)),
        shear_modulus=np.ascontiguousarray(domain_mu), lame=np.ascontiguousarray(domain_lame),
        metric_root=np.ascontiguousarray(root), metric_root_inverse=np.ascontiguousarray(root_inverse), law=law)
    return SmoothedStrain(indptr=indptr, nodes=(unique_keys % n_nodes).astype(np.int64),
                          gradient=np.ascontiguousarray(entries), law=law_arrays)


def strain_operator(smoothed: SmoothedStrain, n_nodes: int) -> sp.csr_matrix:
    """(9 D, 3 N) sparse B with vec(F_d) = B x (row 9 d + 3 i + J, column 3 a + i: b_daJ), constant."""
    counts = np.diff(smoothed.indptr)
    domain = np.repeat(np.arange(smoothed.n_domains), counts)
    i, j = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    rows = 9 * domain[:, None, None] + 3 * i[None] + j[None]
    columns = np.broadcast_to(3 * smoothed.nodes[:, None, None] + i[None], rows.shape)
    data = np.broadcast_to(smoothed.gradient[:, None, :], rows.shape)
    return sp.csr_matrix((data.ravel(), (rows.ravel(), columns.ravel())), shape=(9 * smoothed.n_domains, 3 * n_nodes))


def deformation_gradients(smoothed: SmoothedStrain, positions: np.ndarray) -> np.ndarray:
    """(D, 3, 3) the domains' deformation gradients F_d = sum_a x_a (outer) b_da at positions (N, 3) m."""
    terms = np.einsum("ei,ej->eij", np.asarray(positions, float)[smoothed.nodes], smoothed.gradient)
    return np.add.reduceat(terms, smoothed.indptr[:-1], axis=0)


def domain_forces(smoothed: SmoothedStrain, positions: np.ndarray) -> np.ndarray:
    """(N, 3) nodal forces f_a = -sum_d V_d P_d(F_d) b_da in N (the numpy reference of
    ``kernels.domain_stress_add``)."""
    law = smoothed.law
    stress = law_stress(law, deformation_gradients(smoothed, positions)) * law.volume[:, None, None]
    domain = np.repeat(np.arange(smoothed.n_domains), np.diff(smoothed.indptr))
    entry_forces = -np.einsum("eij,ej->ei", stress[domain], smoothed.gradient)
    forces = np.zeros((len(positions), 3))
    np.add.at(forces, smoothed.nodes, entry_forces)
    return forces


def stiffness_matrix(smoothed: SmoothedStrain, positions: np.ndarray, clamp: bool = False) -> sp.csr_matrix:
    """(3 N, 3 N) K = sum_d B_d^T T_d B_d in N/m, T_d = V_d A(F_d) (``stress_correction.tangent_matrices_at``;
    ``clamp``: the implicit step's positive part): the numpy reference of the compiled assembly."""
    positions = np.asarray(positions, float)
    tangent = tangent_matrices_at(smoothed.law, deformation_gradients(smoothed, positions), clamp)
    operator = strain_operator(smoothed, len(positions))
    return (operator.T @ sp.block_diag(list(tangent), format="csr") @ operator).tocsr()
