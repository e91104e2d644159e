"""The liver-lobe phantom: voxel volumes converge to the implicit shape's, the tumour lies inside
the lobe, the surfaces are closed and outward, and the hexahedral mesh carries the labels into a
model that holds its own weight."""

import numpy as np
import pytest

from sim_core import Material, build_model, solve_static
from sim_core.geometry.meshing import check_closed, enclosed_volume
from sim_core.models.phantoms import LIVER_MATERIALS, PARENCHYMA, TUMOUR, VESSEL, LiverLobe, liver_lobe

SPHERE = 4 / 3 * np.pi * 0.0075**3  # the default tumour's volume, m^3


@pytest.fixture(scope="module")
def monte_carlo_volume():
    """The implicit lobe's volume by Monte Carlo: 2e6 uniform points in its box (standard error
    0.07%), independent of any grid."""
    geometry = LiverLobe()
    points = np.random.default_rng(1).random((2_000_000, 3)) * np.asarray(geometry.size)
    share = np.mean(geometry.labels(points) > 0)
    return share * np.prod(geometry.size)


def test_mask_volume_converges_to_the_implicit_volume(monte_carlo_volume):
    """Voxel-centre sampling at 4, 2, 1 mm: the relative error falls (0.8%, 0.3%, 0.04% measured)
    below 0.3% at 1 mm, within four Monte Carlo standard errors."""
    errors = [abs(liver_lobe(h).volume() / monte_carlo_volume - 1) for h in (0.004, 0.002, 0.001)]
    assert errors[0] < 0.02 and errors[1] < errors[0] and errors[2] < errors[0]
    assert errors[2] < 0.003


def test_lobe_fills_its_box_and_holds_all_labels():
    phantom = liver_lobe(0.002)
    occupied = np.argwhere(phantom.mask > 0)
    low, high = occupied.min(axis=0) * 0.002, (occupied.max(axis=0) + 1) * 0.002
    assert np.allclose(low, 0.0, atol=0.002) and np.allclose(high, LiverLobe().size, atol=0.002)
    assert set(np.unique(phantom.mask).tolist()) == {0, PARENCHYMA, TUMOUR, VESSEL}
    # the vessel: every vessel voxel centre lies within the tube's radius of its axis
    geometry = phantom.geometry
    centres = (np.argwhere(phantom.mask == VESSEL) + 0.5) * 0.002
    assert np.all(geometry.vessel(centres) < 0)


def test_tumour_is_inside_the_lobe_and_has_the_sphere_volume():
    """No tumour voxel is lost to the outside (every voxel centre in the sphere is tissue), and
    its voxel volume is within 2% of 4/3 pi r^3 at 1 mm (7.5 voxels per radius)."""
    phantom = liver_lobe(0.001)
    centres = (np.argwhere(np.ones(phantom.mask.shape, dtype=bool)) + 0.5) * 0.001
    in_sphere = (phantom.geometry.tumour(centres) < 0).reshape(phantom.mask.shape)
    assert np.all(phantom.mask[in_sphere] > 0)
    assert np.all(in_sphere[phantom.mask == TUMOUR])
    assert abs(phantom.volume(TUMOUR) / SPHERE - 1) < 0.02
    with pytest.raises(ValueError, match="does not lie inside the lobe"):
        LiverLobe(tumour_centre=(0.04, 0.038, 0.03))  # near the top surface
    with pytest.raises(ValueError, match="does not lie inside the lobe"):
        LiverLobe(tumour_radius=0.03)


def test_surfaces_are_closed_outward_and_enclose_the_mask_volume():
    phantom = liver_lobe(0.002)
    vertices, faces = phantom.surface()
    check_closed(vertices, faces)  # every edge in two faces, once each way
    volume = enclosed_volume(vertices, faces)
    assert volume > 0  # outward
    assert abs(volume / phantom.volume() - 1) < 0.02  # -0.5% measured
    # the tumour's surface converges to the sphere (14%, 3.6%, 0.9% low at 4, 2, 1 mm)
    errors = [abs(enclosed_volume(*phantom.surface("tumour", spacing=h)) / SPHERE - 1) for h in (0.004, 0.002, 0.001)]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 0.02
    check_closed(*phantom.surface("tumour"))
    with pytest.raises(ValueError, match="part"):
        phantom.surface("liver")


def test_hex_mesh_carries_labels_and_holds_its_weight():
    """The 4 mm phantom meshed (from_mask after fill_non_manifold), with the labels' materials,
    resting on its lowest layer of nodes under gravity: the equilibrium converges and the support
    carries the weight rho g V of the mesh (to 1e-8)."""
    phantom = liver_lobe(0.004)
    mesh = phantom.hex_mesh()
    assert set(np.unique(mesh.element_labels).tolist()) == {PARENCHYMA, TUMOUR, VESSEL}
    assert mesh.element_volumes().sum() >= phantom.volume() * (1 - 1e-12)  # filling only adds voxels
    assert mesh.element_volumes().sum() <= phantom.volume() * 1.02
    material = phantom.material(mesh)
    stiff = mesh.element_labels == TUMOUR
    assert np.all(material.young_modulus[stiff] == LIVER_MATERIALS[TUMOUR].young_modulus)
    model = build_model(mesh, material, gravity=(0.0, -9.81, 0.0), hourglass_control=1.0)
    y = mesh.nodes[:, 1]
    bottom = np.flatnonzero(y <= y.min() + 0.004 + 1e-9)
    result = solve_static(model, model.new_control().impose(bottom, mesh.nodes[bottom]), tolerance=1e-10)
    assert result.converged
    weight = 9.81 * np.sum(material.density * mesh.element_volumes())
    assert np.allclose(result.reaction.sum(axis=0), [0.0, weight, 0.0], rtol=0, atol=1e-8 * weight)


def test_materials_follow_the_cited_ranges():
    """The defaults lie in the ranges the module docstring cites: parenchyma 3.3-7.8 kPa, a tumour
    several times stiffer, a vessel stiffer still, nu 0.45-0.5, rho 1050-1070 kg/m^3."""
    parenchyma, tumour, vessel = (LIVER_MATERIALS[k] for k in (PARENCHYMA, TUMOUR, VESSEL))
    assert 3.3e3 <= parenchyma.young_modulus <= 7.8e3
    assert tumour.young_modulus >= 3 * parenchyma.young_modulus
    assert 1e5 <= vessel.young_modulus <= 1e6 and vessel.young_modulus > tumour.young_modulus
    for material in LIVER_MATERIALS.values():
        assert 0.45 <= material.poisson_ratio < 0.5 and 1050 <= material.density <= 1070
    custom = liver_lobe(0.004, materials={TUMOUR: Material(4e4, 0.45, 1060.0)})
    assert custom.materials[TUMOUR].young_modulus == 4e4
    assert custom.materials[PARENCHYMA] is LIVER_MATERIALS[PARENCHYMA]


def test_bad_phantom_arguments_are_refused():
    with pytest.raises(ValueError, match="voxel_size"):
        liver_lobe(0.0)
    with pytest.raises(ValueError, match="size"):
        liver_lobe(0.004, size=(0.08, -0.04, 0.06))
    with pytest.raises(ValueError, match="taper"):
        liver_lobe(0.004, taper=1.0)
    with pytest.raises(ValueError, match="materials"):
        liver_lobe(0.004, materials={7: Material()})
    with pytest.raises(ValueError, match="no tumour"):
        liver_lobe(0.004, tumour_radius=0).surface("tumour")
    assert TUMOUR not in np.unique(liver_lobe(0.004, tumour_radius=0).mask)
