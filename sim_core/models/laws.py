"""Pointwise formulas the models share, with no dependence on meshes or solvers: Baudet's spring
stiffnesses from E and nu (docs/physics.md section 2) and the compressible neo-Hookean law (its
energy, first Piola stress and material tangent; section 10), vectorised over any leading axes.
SI units: Pa, m, N/m. ``sim_core.models.model`` and ``sim_core.solvers.hyperelastic`` re-export them.
"""

from __future__ import annotations

import numpy as np


def baudet_stiffness(axis_lengths: np.ndarray, young_modulus, poisson_ratio):
    """Per-element spring stiffnesses (N/m) of Baudet's hexahedron [2].

    Args:
        axis_lengths: (M, 3) rest edge lengths x0, y0, z0 in m.
        young_modulus, poisson_ratio: (M,) material.
    Returns:
        (edge (M, 3) stiffness of the x-, y-, z-edges, diagonal (M,) stiffness of the 4 diagonals).
    """
    x0, y0, z0 = axis_lengths.T
    d2 = x0**2 + y0**2 + z0**2
    nu = poisson_ratio
    denominator = 24.0 * (1.0 + nu) * x0 * y0 * z0
    diagonal = young_modulus * d2**2 / denominator
    edge = np.empty_like(axis_lengths)
    for axis in range(3):
        i = axis_lengths[:, axis]
        j = axis_lengths[:, (axis + 1) % 3]
        k = axis_lengths[:, (axis + 2) % 3]
        edge[:, axis] = young_modulus * (
            6.0 * j**2 * k**2 * (1.0 + nu) + (nu * (j**2 + k**2) - i**2) * d2
        ) / denominator
    return edge, diagonal


def baudet_shear_ratio(axis_lengths: np.ndarray) -> np.ndarray:
    """(M, 3) shear modulus of Baudet's springs over the material's, G_meas / G = D^2 / (3 k^2), in
    the plane normal to each axis k (column k) of an element of rest edge lengths ``axis_lengths``
    (M, 3) m [2]: 1 in every plane for a cube only (one diagonal stiffness serves three planes)."""
    axis_lengths = np.asarray(axis_lengths, float)
    d2 = (axis_lengths**2).sum(axis=-1, keepdims=True)
    return d2 / (3.0 * axis_lengths**2)


# -- constitutive law (pointwise, vectorised over any leading axes) ----------------------------
def lame_parameters(young_modulus, poisson_ratio):
    """(mu, lambda) in Pa from E (Pa) and nu (docs/physics.md notation)."""
    young_modulus, nu = np.asarray(young_modulus, float), np.asarray(poisson_ratio, float)
    return young_modulus / (2 * (1 + nu)), young_modulus * nu / ((1 + nu) * (1 - 2 * nu))


def strain_energy_density(deformation_gradient, mu, lam):
    """W(F) in J/m^3 (Pa) of the compressible neo-Hookean law; F (..., 3, 3), mu and lam broadcast
    against F's leading axes. Returns +inf where det F <= 0."""
    f = np.asarray(deformation_gradient, float)
    det = np.linalg.det(f)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_j = np.log(det)
    energy = 0.5 * mu * (np.einsum("...ab,...ab->...", f, f) - 3.0) - mu * log_j + 0.5 * lam * log_j**2
    return np.where(det > 0, energy, np.inf)


def first_piola_stress(deformation_gradient, mu, lam):
    """P(F) = mu (F - F^-T) + lambda ln J F^-T in Pa; F (..., 3, 3)."""
    f = np.asarray(deformation_gradient, float)
    inverse_t = np.linalg.inv(f).swapaxes(-1, -2)
    log_j = np.log(np.linalg.det(f))
    mu, lam = np.asarray(mu)[..., None, None], np.asarray(lam)[..., None, None]
    return mu * (f - inverse_t) + lam * log_j[..., None, None] * inverse_t


def material_tangent(deformation_gradient, mu, lam):
    """(..., 3, 3, 3, 3) A_aBcD = dP_aB / dF_cD in Pa (the law: ``sim_core.solvers.hyperelastic``'s module docstring)."""
    f = np.asarray(deformation_gradient, float)
    inverse = np.linalg.inv(f)
    log_j = np.log(np.linalg.det(f))
    mu, lam = np.asarray(mu, float), np.asarray(lam, float)
    mu, lam = np.broadcast_to(mu, log_j.shape), np.broadcast_to(lam, log_j.shape)
    eye = np.eye(3)
    identity_part = np.einsum("ac,BD->aBcD", eye, eye)
    tangent = mu[..., None, None, None, None] * identity_part
    tangent = tangent + (mu - lam * log_j)[..., None, None, None, None] * np.einsum("...Bc,...Da->...aBcD", inverse, inverse)
    tangent = tangent + lam[..., None, None, None, None] * np.einsum("...Ba,...Dc->...aBcD", inverse, inverse)
    return tangent
