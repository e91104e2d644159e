"""Physics.md sections 1-3 on a single element: the formulas give E and nu back to round-off.

The response is linearised exactly (the tangent stiffness at rest, checked against finite
differences in test_forces.py), so a measured modulus off by more than 1e-9 relative means a
formula is wrong.
"""

import numpy as np
import pytest

from sim_core import HexMesh, Material, build_model
from sim_core.models.forces import stiffness_data


def linear_uniaxial(model, axis):
    """Pull one element along ``axis`` with symmetry conditions on the three faces at 0.

    Returns (E_measured / E, nu_measured for the two other axes).
    """
    mesh = model.mesh
    nodes = mesh.nodes
    length = mesh.size
    strain = 1e-3
    fixed = np.zeros((mesh.n_nodes, 3), bool)
    imposed = np.zeros((mesh.n_nodes, 3))
    for a in range(3):
        fixed[np.isclose(nodes[:, a], 0), a] = True  # symmetry planes
    far = np.isclose(nodes[:, axis], length[axis])
    fixed[far, axis] = True
    imposed[far, axis] = strain * length[axis]
    k = model.pattern.matrix(stiffness_data(model, nodes)).toarray()
    free = ~fixed.ravel()
    u = imposed.ravel().copy()
    u[free] = np.linalg.lstsq(k[np.ix_(free, free)], -k[np.ix_(free, ~free)] @ u[~free], rcond=None)[0]
    reaction = (k @ u).reshape(-1, 3)[far, axis].sum()
    area = np.prod(length) / length[axis]
    displacement = u.reshape(-1, 3)
    young = reaction / area / strain
    ratios = []
    for other in range(3):
        if other != axis:
            high = np.isclose(nodes[:, other], length[other])
            ratios.append(-displacement[high, other].mean() / length[other] / strain)
    return young / model.young_modulus[0], ratios


CASES = [((0.1, 0.1, 0.1), nu) for nu in (-0.2, 0.0, 0.1, 0.25, 0.3, 0.4, 0.45, 0.49)] + [
    (spacing, nu) for spacing in [(0.1, 0.11, 0.12), (0.12, 0.1, 0.11)] for nu in (0.0, 0.1, 0.3, 0.45, 0.49)
]


@pytest.mark.parametrize("spacing, nu", CASES)
def test_single_element_recovers_e_and_nu(spacing, nu):
    # the boxes' shear error is beyond build_model's default bound (tests/test_box_elements.py): off here,
    # where only the elongation formulas are checked
    model = build_model(HexMesh.block((1, 1, 1), spacing), Material(1e4, nu, 1000), max_shear_error=None)
    for axis in range(3):
        young_ratio, ratios = linear_uniaxial(model, axis)
        assert young_ratio == pytest.approx(1.0, abs=1e-9)
        assert ratios == pytest.approx([nu, nu], abs=1e-9)


@pytest.mark.parametrize("nu", [0.1, 0.3, 0.45])
def test_without_corrections_springs_obey_cauchy(nu):
    """Physics.md 1: central springs alone measure nu = 1/(4 nu + 3), E ratio 2(4nu+1)/(4nu+3)."""
    model = build_model(HexMesh.block((1, 1, 1), 0.1), Material(1e4, nu, 1000), corrections=False)
    young_ratio, ratios = linear_uniaxial(model, 0)
    assert young_ratio == pytest.approx(2 * (4 * nu + 1) / (4 * nu + 3), rel=1e-9)
    assert ratios == pytest.approx([1 / (4 * nu + 3)] * 2, rel=1e-9)


def test_cube_closed_forms():
    """k_edge = E l (4nu+1) / (8(1+nu)), k_d = 3 E l / (8(1+nu)), C = -(4nu-1)/2 (docs/physics.md 2-3)."""
    from sim_core.models.model import baudet_stiffness, correction_coefficients

    young, nu, length = 2e4, 0.35, 0.05
    edge, diagonal = baudet_stiffness(np.full((1, 3), length), np.array([young]), np.array([nu]))
    assert np.allclose(edge, young * length * (4 * nu + 1) / (8 * (1 + nu)))
    assert np.allclose(diagonal, 3 * young * length / (8 * (1 + nu)))
    c = correction_coefficients(np.full((1, 3), length), np.array([nu]))[0]
    assert np.allclose(c[~np.eye(3, dtype=bool)], -(4 * nu - 1) / 2)
    assert np.allclose(np.diag(c), 0)


@pytest.mark.parametrize("spacing, nu", [((0.1, 0.1, 0.2), 0.3), ((0.1, 0.1, 0.15), 0.0), ((0.1, 0.1, 0.1), -0.3)])
def test_elements_with_negative_edge_stiffness_are_rejected(spacing, nu):
    """Where Baudet's edge stiffness is <= 0 the element has negative-energy modes: refuse it."""
    if nu <= -0.25:
        with pytest.raises(ValueError, match="poisson_ratio"):
            Material(1e4, nu, 1000)
        return
    with pytest.raises(ValueError, match="non-positive edge stiffness"):
        build_model(HexMesh.block((1, 1, 1), spacing), Material(1e4, nu, 1000))
