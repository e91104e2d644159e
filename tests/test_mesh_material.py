"""Geometry, node order, masses, spring counts, mesh files and input validation."""

import numpy as np
import pytest

from sim_core import HexMesh, Material, build_model


def test_block_node_order_and_extent():
    mesh = HexMesh.block((3, 2, 4), (0.1, 0.2, 0.05))
    nx, ny, nz = 3, 2, 4
    for i, j, k in [(0, 0, 0), (3, 2, 4), (1, 2, 3), (2, 0, 1)]:
        index = i + (nx + 1) * (j + (ny + 1) * k)
        assert np.allclose(mesh.nodes[index], [i * 0.1, j * 0.2, k * 0.05])
        assert mesh.node_index(i, j, k) == index
    assert np.allclose(mesh.size, [0.3, 0.4, 0.2])
    # VTK local order of element 0
    expected = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
    assert np.allclose(mesh.nodes[mesh.elements[0]], np.array(expected) * [0.1, 0.2, 0.05])


def test_volumes_masses_and_surface():
    mesh = HexMesh.block((4, 3, 2), 0.05)
    model = build_model(mesh, Material(1e4, 0.3, 1060.0))
    volume = 4 * 3 * 2 * 0.05**3
    assert np.isclose(mesh.element_volumes().sum(), volume, rtol=1e-12)
    assert np.isclose(model.mass.sum(), 1060.0 * volume, rtol=1e-12)
    assert len(mesh.surface_faces()) == 2 * (4 * 3 + 3 * 2 + 4 * 2)
    # outward orientation: divergence theorem gives the volume back
    faces = mesh.nodes[mesh.surface_faces()]
    area = 0.5 * np.cross(faces[:, 2] - faces[:, 0], faces[:, 3] - faces[:, 1])
    assert np.isclose((faces.mean(axis=1) * area).sum() / 3, volume, rtol=1e-12)


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 2, 4), (10, 10, 10)])
def test_spring_count_closed_form(shape):
    nx, ny, nz = shape
    edges = nx * (ny + 1) * (nz + 1) + (nx + 1) * ny * (nz + 1) + (nx + 1) * (ny + 1) * nz
    model = build_model(HexMesh.block(shape, 0.1), Material(1e4, 0.3, 1000))
    assert len(model.springs) == edges + 4 * nx * ny * nz


def test_shared_springs_sum_stiffness():
    """An interior edge belongs to 4 elements, a face edge to 2, a block edge to 1 (docs/physics.md 2)."""
    young, nu, h = 1e4, 0.3, 0.1
    mesh = HexMesh.block((2, 2, 2), h)
    model = build_model(mesh, Material(young, nu, 1000))
    k_edge = young * h * (4 * nu + 1) / (8 * (1 + nu))
    k_diag = 3 * young * h / (8 * (1 + nu))
    lookup = {tuple(s): k for s, k in zip(model.springs.tolist(), model.stiffness)}
    n = mesh.node_index
    assert np.isclose(lookup[(int(n(1, 1, 0)), int(n(1, 1, 1)))], 4 * k_edge)  # interior z-edge
    assert np.isclose(lookup[(int(n(0, 1, 0)), int(n(0, 1, 1)))], 2 * k_edge)  # face z-edge
    assert np.isclose(lookup[(int(n(0, 0, 0)), int(n(1, 0, 0)))], 1 * k_edge)  # block edge
    assert np.isclose(lookup[(int(n(0, 0, 0)), int(n(1, 1, 1)))], k_diag)


def test_damping_is_critical_for_the_reduced_mass():
    model = build_model(HexMesh.block((2, 2, 2), 0.1), Material(1e4, 0.3, 1000), damping_ratio=0.5)
    ma, mb = model.mass[model.springs[:, 0]], model.mass[model.springs[:, 1]]
    assert np.allclose(model.damping, 0.5 * 2 * np.sqrt(ma * mb / (ma + mb) * model.stiffness))


def test_per_element_material():
    """A stiffer middle element (5x E) adds 4x its own spring stiffness to the merged springs."""
    young, nu, h = 1e4, 0.3, 0.1
    mesh = HexMesh.block((3, 1, 1), h)
    soft = build_model(mesh, Material(young, nu, 1000))
    mixed = build_model(mesh, Material(np.array([young, 5 * young, young]), nu, 1000))
    assert np.all(mixed.stiffness >= soft.stiffness - 1e-9)
    one_element = 12 * young * h * (4 * nu + 1) / (8 * (1 + nu)) + 4 * 3 * young * h / (8 * (1 + nu))
    assert np.isclose(mixed.stiffness.sum() - soft.stiffness.sum(), 4 * one_element)
    with pytest.raises(ValueError, match="one value per element"):
        build_model(mesh, Material(np.array([young, young]), nu, 1000))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(young_modulus=0.0), "young_modulus"),
        (dict(young_modulus=-5.0), "young_modulus"),
        (dict(young_modulus=float("nan")), "young_modulus"),
        (dict(poisson_ratio=0.5), "poisson_ratio"),
        (dict(poisson_ratio=-0.25), "poisson_ratio"),
        (dict(poisson_ratio=0.7), "poisson_ratio"),
        (dict(poisson_ratio=float("inf")), "poisson_ratio"),
        (dict(density=0.0), "density"),
        (dict(density=float("nan")), "density"),
    ],
)
def test_material_rejects_bad_values(kwargs, word):
    with pytest.raises(ValueError, match=word):
        Material(**{**dict(young_modulus=1e4, poisson_ratio=0.3, density=1000.0), **kwargs})


def test_material_message_gives_allowed_range():
    with pytest.raises(ValueError, match=r"\(-0.25, 0.5\)"):
        Material(1e4, 0.6, 1000)
    with pytest.raises(ValueError, match="> 0 Pa"):
        Material(-1.0, 0.3, 1000)


@pytest.mark.parametrize("spacing", [0.0, -0.1, (0.1, 0.0, 0.1), float("nan")])
def test_block_rejects_bad_spacing(spacing):
    with pytest.raises(ValueError, match="spacing"):
        HexMesh.block((2, 2, 2), spacing)


@pytest.mark.parametrize("shape", [(0, 2, 2), (2, 2), (2.5, 2, 2), "abc"])
def test_block_rejects_bad_shape(shape):
    with pytest.raises(ValueError, match="shape"):
        HexMesh.block(shape, 0.1)


def test_inverted_and_degenerate_elements_are_rejected():
    mesh = HexMesh.block((2, 1, 1), 0.1)
    flipped = mesh.elements.copy()
    flipped[1] = flipped[1][[4, 5, 6, 7, 0, 1, 2, 3]]
    with pytest.raises(ValueError, match="inverted element 1"):
        HexMesh(mesh.nodes, flipped)
    squashed = mesh.nodes.copy()
    squashed[mesh.elements[0][4:], 2] = 0.0  # top face of element 0 onto its bottom face
    with pytest.raises(ValueError, match="degenerate|inverted"):
        HexMesh(squashed, mesh.elements)
    repeated = mesh.elements.copy()
    repeated[0, 1] = repeated[0, 0]
    with pytest.raises(ValueError, match="degenerate element 0"):
        HexMesh(mesh.nodes, repeated)
    with pytest.raises(ValueError, match="indices"):
        HexMesh(mesh.nodes, mesh.elements + 100)
    with pytest.raises(ValueError, match="shape"):
        HexMesh(mesh.nodes[:, :2], mesh.elements)


def test_general_mesh_with_skewed_elements():
    mesh = HexMesh.block((2, 2, 2), 0.1)
    nodes = mesh.nodes.copy()
    nodes[:, 0] += 0.3 * nodes[:, 1]  # shear the block: still valid hexahedra
    skewed = HexMesh(nodes, mesh.elements)
    assert np.isclose(skewed.element_volumes().sum(), 0.2**3)
    with pytest.raises(ValueError, match="shear modulus"):  # its slanted edges are 1.044 x the others
        build_model(skewed, Material(1e4, 0.3, 1000))
    model = build_model(skewed, Material(1e4, 0.3, 1000), max_shear_error=None)
    assert np.isclose(model.mass.sum(), 1000 * 0.2**3)


@pytest.mark.parametrize("suffix", [".vtu", ".msh"])
def test_mesh_file_round_trip(tmp_path, suffix):
    mesh = HexMesh.block((3, 2, 2), (0.1, 0.05, 0.02))
    path = tmp_path / f"block{suffix}"
    mesh.write(path, point_data={"displacement": np.zeros((mesh.n_nodes, 3))})
    back = HexMesh.read(path)
    assert np.allclose(back.nodes, mesh.nodes)
    assert np.array_equal(back.elements, mesh.elements)


def test_surface_obj_export(tmp_path):
    mesh = HexMesh.block((2, 2, 2), 0.1)
    path = tmp_path / "surface.obj"
    mesh.write_obj(path)
    lines = path.read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == len(mesh.surface_nodes()) == 26
    assert sum(line.startswith("f ") for line in lines) == 24
