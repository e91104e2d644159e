"""HexMesh.from_mask: voxel volumes to hexahedral meshes (geometry exact, nodes shared, labels
carried, bad masks refused) and the same physics as HexMesh.block on a box."""

import numpy as np
import pytest

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.geometry.mesh import corner_jacobians, downsample, fill_non_manifold, non_manifold_voxels, voxel_factor


def ball(n, radius):
    centre = (n - 1) / 2
    i, j, k = np.meshgrid(*[np.arange(n)] * 3, indexing="ij")
    return (i - centre) ** 2 + (j - centre) ** 2 + (k - centre) ** 2 <= radius**2


def test_volume_is_voxel_count_times_voxel_volume():
    """Exact to rounding (1e-12 relative): every element is one axis-aligned voxel."""
    mask = ball(9, 3.6)
    spacing = (0.002, 0.003, 0.0025)
    mesh = HexMesh.from_mask(mask, spacing, origin=(0.1, -0.2, 0.05))
    assert mesh.n_elements == mask.sum()
    assert np.isclose(mesh.element_volumes().sum(), mask.sum() * np.prod(spacing), rtol=1e-12, atol=0)
    assert np.all(corner_jacobians(mesh.nodes, mesh.elements) > 0)
    assert np.allclose(mesh.nodes.min(axis=0), np.array([0.1, -0.2, 0.05]) + np.argwhere(mask).min(axis=0) * spacing)


def test_nodes_are_shared_and_unused_ones_dropped():
    """An L of three voxels in one layer: 8 grid points per node layer, 2 layers, so 16 nodes
    (not 3 x 8 = 24); two voxels in a row: 12. Every node is used and none is repeated."""
    mask = np.zeros((3, 3, 2), dtype=bool)
    mask[0, 0, 0] = mask[1, 0, 0] = mask[0, 1, 0] = True
    mesh = HexMesh.from_mask(mask, 0.01)
    assert mesh.n_nodes == 16 and mesh.n_elements == 3
    assert len(np.unique(mesh.nodes, axis=0)) == mesh.n_nodes
    assert np.array_equal(np.unique(mesh.elements), np.arange(mesh.n_nodes))
    row = np.zeros((4, 1, 1), dtype=bool)
    row[1:3] = True
    assert HexMesh.from_mask(row, 0.01).n_nodes == 12
    # a 3x3x3 cube without its centre voxel (a closed cavity) still uses all 4^3 grid points
    hollow = np.ones((3, 3, 3), dtype=bool)
    hollow[1, 1, 1] = False
    assert HexMesh.from_mask(hollow, 0.01).n_nodes == 64


def test_full_box_is_the_block():
    """A full mask gives HexMesh.block's nodes and elements, in the same order."""
    spacing = (0.01, 0.02, 0.015)
    block = HexMesh.block((3, 2, 4), spacing)
    mesh = HexMesh.from_mask(np.ones((3, 2, 4), dtype=bool), spacing)
    assert np.array_equal(mesh.elements, block.elements)
    assert np.allclose(mesh.nodes, block.nodes, rtol=0, atol=1e-15)
    assert mesh.shape == (3, 2, 4) and np.allclose(mesh.spacing, spacing)
    assert np.array_equal(mesh.element_labels, np.ones(24, dtype=int))


def test_labels_are_carried_to_the_elements():
    rng = np.random.default_rng(3)
    labels = rng.integers(1, 4, size=(4, 3, 5))
    labels[0, 0, 0] = 0  # one outside voxel at a corner keeps the solid manifold
    spacing = 0.005
    mesh = HexMesh.from_mask(labels, spacing)
    centres = mesh.nodes[mesh.elements].mean(axis=1)
    voxel = np.floor(centres / spacing).astype(int)
    assert np.array_equal(mesh.element_labels, labels[voxel[:, 0], voxel[:, 1], voxel[:, 2]])
    assert mesh.n_elements == 59
    # only some labels: label 3's voxels are left out (a mask of labels 1 and 2 touching by faces)
    one_two = np.ones((4, 3, 5), dtype=int)
    one_two[2:, :, :] = 2
    one_two[:, :, 4] = 3
    part = HexMesh.from_mask(one_two, spacing, labels=(1, 2))
    assert part.n_elements == 4 * 3 * 4 and set(part.element_labels.tolist()) == {1, 2}


def test_material_from_labels_gives_each_element_its_tissue():
    mask = np.ones((2, 1, 1), dtype=int)
    mask[1] = 2
    mesh = HexMesh.from_mask(mask, 0.01)
    soft, stiff = Material(3e3, 0.45, 1060.0), Material(1.5e4, 0.48, 1100.0)
    material = Material.from_labels(mesh.element_labels, {1: soft, 2: stiff})
    assert np.array_equal(material.young_modulus, [3e3, 1.5e4])
    assert np.array_equal(material.poisson_ratio, [0.45, 0.48])
    assert np.array_equal(material.density, [1060.0, 1100.0])
    model = build_model(mesh, material)
    assert np.isclose(model.mass.sum(), (1060.0 + 1100.0) * 1e-6, rtol=1e-12)
    with pytest.raises(ValueError, match=r"labels \[2\] have no material"):
        Material.from_labels(mesh.element_labels, {1: soft})
    with pytest.raises(ValueError, match="scalar parameters"):
        Material.from_labels(mesh.element_labels, {1: soft, 2: Material(np.array([1e3, 2e3]))})
    with pytest.raises(ValueError, match="integer array"):
        Material.from_labels(np.array([1.0, 2.0]), {1: soft, 2: stiff})


@pytest.mark.parametrize("embedded", [False, True])
def test_gravity_equilibrium_equals_the_block(embedded):
    """The same box as HexMesh.block (alone, or inside empty voxels and shifted, so that nodes are
    renumbered and unused grid points dropped) sags under gravity to the same equilibrium, to 1e-10
    of the sag: the same geometry gives the same model."""
    shape, h = (3, 4, 2), 0.01
    material = Material(5e3, 0.45, 1060.0)
    block = HexMesh.block(shape, h)
    mask = np.ones(shape, dtype=bool)
    origin = np.zeros(3)
    if embedded:
        mask = np.pad(mask, ((2, 1), (1, 3), (0, 2)))
        origin = np.array([-0.02, -0.01, 0.0])
    mesh = HexMesh.from_mask(mask, h, origin=origin)
    # the block's node n is the mask mesh's node order[n] (matched by position)
    rounded = lambda x: [tuple(p) for p in np.round(x / h).astype(int)]  # noqa: E731
    where = {p: n for n, p in enumerate(rounded(mesh.nodes))}
    order = np.array([where[p] for p in rounded(block.nodes)])
    assert mesh.n_nodes == block.n_nodes

    def sag(m, nodes):
        model = build_model(m, material, gravity=(0.0, -9.81, 0.0))
        bottom = np.flatnonzero(np.isclose(m.nodes[:, 1], m.nodes[:, 1].min()))
        result = solve_static(model, model.new_control().impose(bottom, m.nodes[bottom]), tolerance=1e-12)
        assert result.converged
        return result.positions[nodes] - m.nodes[nodes]

    reference = sag(block, np.arange(block.n_nodes))
    displacement = sag(mesh, order)
    assert np.abs(reference).max() > 1e-5  # the sag is real (tens of micrometres)
    assert np.abs(displacement - reference).max() <= 1e-10 * np.abs(reference).max()


def test_bad_masks_are_refused():
    with pytest.raises(ValueError, match="3D"):
        HexMesh.from_mask(np.ones((3, 3), dtype=bool), 0.01)
    with pytest.raises(ValueError, match="no occupied voxel"):
        HexMesh.from_mask(np.zeros((3, 3, 3), dtype=bool), 0.01)
    with pytest.raises(ValueError, match="no occupied voxel with labels"):
        HexMesh.from_mask(np.ones((3, 3, 3), dtype=int), 0.01, labels=[2])
    for spacing in (0.0, -0.01, (0.01, 0.0, 0.01)):
        with pytest.raises(ValueError, match="spacing"):
            HexMesh.from_mask(np.ones((2, 2, 2), dtype=bool), spacing)
    with pytest.raises(ValueError, match="boolean or integer"):
        HexMesh.from_mask(np.ones((2, 2, 2)), 0.01)
    with pytest.raises(ValueError, match=">= 0"):
        HexMesh.from_mask(-np.ones((2, 2, 2), dtype=int), 0.01)
    with pytest.raises(ValueError, match="components"):
        HexMesh.from_mask(np.ones((2, 2, 2), dtype=bool), 0.01, components="all")


def test_disconnected_pieces_refused_or_the_largest_kept():
    mask = np.zeros((6, 2, 2), dtype=bool)
    mask[:3] = True  # 12 voxels
    mask[5, 0, 0] = True  # a loose voxel, not touching
    with pytest.raises(ValueError, match="2 face-connected components"):
        HexMesh.from_mask(mask, 0.01)
    with pytest.warns(UserWarning, match="dropped 1 voxels"):
        mesh = HexMesh.from_mask(mask, 0.01, components="largest")
    assert mesh.n_elements == 12 and mesh.n_nodes == 4 * 3 * 3


def test_voxels_touching_along_an_edge_or_a_corner_are_refused():
    """Alone, two voxels meeting at an edge or a corner are two components; joined by a face path
    elsewhere, they are one component that hinges on the edge (node): not a manifold, refused."""
    for other in ((1, 1, 0), (1, 1, 1)):
        mask = np.zeros((2, 2, 2), dtype=bool)
        mask[0, 0, 0] = mask[other] = True
        with pytest.raises(ValueError, match="2 face-connected components"):
            HexMesh.from_mask(mask, 0.01)
    # a ring in one layer without its centre, closed by the diagonal contact of (2, 1) and (1, 2)
    ring = np.zeros((3, 3, 1), dtype=bool)
    for i, j in [(0, 0), (1, 0), (2, 0), (2, 1), (0, 1), (0, 2), (1, 2)]:
        ring[i, j, 0] = True
    assert non_manifold_voxels(ring).tolist() == [[1, 2, 0], [2, 1, 0]]
    with pytest.raises(ValueError, match="not a manifold solid: 2 voxels"):
        HexMesh.from_mask(ring, 0.01)
    # (1, 1, 1) and (2, 2, 2) share one node; a face path around their 2x2x2 window joins them
    corner = np.zeros((4, 4, 4), dtype=bool)
    for voxel in [(1, 1, 1), (1, 1, 0), (1, 2, 0), (2, 2, 0), (3, 2, 0), (3, 2, 1), (3, 2, 2), (2, 2, 2)]:
        corner[voxel] = True
    assert non_manifold_voxels(corner).tolist() == [[1, 1, 1], [2, 2, 2]]
    with pytest.raises(ValueError, match="not a manifold solid"):
        HexMesh.from_mask(corner, 0.01)


def test_non_manifold_voxels_finds_exactly_the_critical_windows():
    assert len(non_manifold_voxels(ball(9, 3.6))) == 0
    diagonal = np.zeros((2, 2, 1), dtype=bool)
    diagonal[0, 0, 0] = diagonal[1, 1, 0] = True
    assert non_manifold_voxels(diagonal).tolist() == [[0, 0, 0], [1, 1, 0]]
    gap = np.ones((2, 2, 2), dtype=bool)
    gap[0, 0, 0] = gap[1, 1, 1] = False  # two empty voxels meeting at the centre node
    assert len(non_manifold_voxels(gap)) == 6


def test_downsample_votes_and_labels():
    mask = np.zeros((4, 4, 4), dtype=int)
    mask[:2, :2, :2] = 1  # one full coarse voxel of label 1
    mask[2:, :2, :2] = 2
    mask[2, 0, 0] = 3  # a minority label in the second block
    mask[0, 2, 0] = 1  # one voxel of eight in a third block
    coarse = downsample(mask, 2)
    assert coarse.shape == (2, 2, 2)
    assert coarse[0, 0, 0] == 1 and coarse[1, 0, 0] == 2 and coarse[0, 1, 0] == 0
    assert downsample(mask, 2, vote="any")[0, 1, 0] == 1
    # padding: 5 voxels along x in blocks of 2 gives 3 coarse voxels
    assert downsample(np.ones((5, 2, 2), dtype=bool), 2).shape == (3, 1, 1)
    assert downsample(np.ones((5, 2, 2), dtype=bool), 2).dtype == bool
    # a coarsened ball keeps its volume roughly (majority vote), the mesh is built from it
    fine = ball(24, 10.5)
    coarse = downsample(fine, 3)
    assert abs(coarse.sum() * 27 / fine.sum() - 1) < 0.1
    with pytest.raises(ValueError, match="factor"):
        downsample(fine, 0)
    with pytest.raises(ValueError, match="vote"):
        downsample(fine, 2, vote="all")


def test_voxel_factor_fits_the_element_size():
    assert voxel_factor(0.001, 0.0035) == 3
    assert voxel_factor(0.001, 0.003) == 3  # 3 x 1 mm is 3 mm (rounding does not lose it)
    assert voxel_factor((0.001, 0.002, 0.001), 0.003) == 1  # the largest axis decides
    assert voxel_factor(0.002, 0.001) == 1
    with pytest.raises(ValueError, match="element_size"):
        voxel_factor(0.001, 0.0)


def test_fill_non_manifold_turns_diagonal_contacts_into_face_contacts():
    """The hinged ring and a random sparse volume: after filling, no critical window is left,
    from_mask accepts the volume, only empty voxels were filled and they carry a neighbour's label."""
    ring = np.zeros((3, 3, 1), dtype=int)
    for i, j in [(0, 0), (1, 0), (2, 0), (2, 1), (0, 1), (0, 2), (1, 2)]:
        ring[i, j, 0] = 2
    filled = fill_non_manifold(ring)
    assert filled.dtype == ring.dtype and filled[1, 1, 0] == 2 and filled[2, 2, 0] == 2
    assert np.count_nonzero(filled) == 9
    rng = np.random.default_rng(7)
    sparse = (rng.random((8, 7, 6)) < 0.55).astype(np.int16) * rng.integers(1, 3, size=(8, 7, 6)).astype(np.int16)
    filled = fill_non_manifold(sparse)
    assert len(non_manifold_voxels(filled)) == 0
    assert np.all(filled[sparse > 0] == sparse[sparse > 0])  # nothing occupied changed
    assert set(np.unique(filled[(sparse == 0) & (filled > 0)])) <= {1, 2}
    HexMesh.from_mask(filled, 0.01, components="largest")
