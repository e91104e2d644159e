"""sim_core.geometry.meshing: isosurfaces, closed-surface checks, surface files and tetrahedralisation."""

import numpy as np
import pytest

from sim_core.geometry.meshing import (
    check_closed, enclosed_volume, isosurface, read_surface, tet_quality, tet_volumes, tetrahedralise,
)


def icosphere(level, radius=0.01):
    """A closed, outward triangle sphere: the icosahedron's faces split ``level`` times, the new
    vertices pushed onto the sphere. Its enclosed volume is a polyhedron's, a little below
    4/3 pi r^3."""
    t = (1 + 5**0.5) / 2
    vertices = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                         [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float)
    faces = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                      [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                      [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    vertices /= np.linalg.norm(vertices, axis=1)[:, None]
    for _ in range(level):
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        keys, index = np.unique(edges, axis=0, return_inverse=True)
        middle = vertices[keys].mean(axis=1)
        middle /= np.linalg.norm(middle, axis=1)[:, None]
        ab, bc, ca = (index.ravel().reshape(3, -1) + len(vertices))
        vertices = np.vstack([vertices, middle])
        a, b, c = faces.T
        faces = np.concatenate([np.stack(f, axis=1) for f in ([a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca])])
    return vertices * radius, faces


def sphere_grid(n, radius=0.01):
    h = 2.4 * radius / n
    x = (np.arange(n + 1) - n / 2) * h
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return np.sqrt(X**2 + Y**2 + Z**2) - radius, h, (x[0],) * 3


def test_isosurface_of_a_sphere_is_closed_outward_and_converges():
    """Marching tetrahedra on the sphere's signed distance: watertight and outward at every grid,
    the enclosed volume's error falls as h^2 (2.0%, 0.51%, 0.13% measured)."""
    errors = []
    for n in (12, 24, 48):
        vertices, faces = isosurface(*sphere_grid(n))
        check_closed(vertices, faces)
        errors.append(abs(enclosed_volume(vertices, faces) / (4 / 3 * np.pi * 0.01**3) - 1))
        assert np.allclose(np.linalg.norm(vertices, axis=1), 0.01, atol=0.05 * 2.4 * 0.01 / n * 3)
    assert errors[-1] < 0.002
    assert errors[0] / errors[1] > 3 and errors[1] / errors[2] > 3


def test_isosurface_refuses_open_or_empty_level_sets():
    values, h, origin = sphere_grid(12)
    with pytest.raises(ValueError, match="boundary"):
        isosurface(values - 0.008, h, origin)  # a sphere of 1.8 cm on a grid of half-width 1.2 cm
    with pytest.raises(ValueError, match="no sign change"):
        isosurface(values + 1.0, h, origin)
    with pytest.raises(ValueError, match="spacing"):
        isosurface(values, 0.0, origin)
    with pytest.raises(ValueError, match="grid"):
        isosurface(values[:, :, :1], h, origin)


def test_closed_surface_checks_and_volume():
    """A unit cube of 12 triangles encloses exactly 1 m^3; removing a face opens it, flipping one
    breaks its orientation, reversing all gives -1."""
    vertices = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    faces = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    check_closed(vertices, faces)
    assert enclosed_volume(vertices, faces) == pytest.approx(1.0, rel=1e-15)
    assert enclosed_volume(vertices, faces[:, ::-1]) == pytest.approx(-1.0, rel=1e-15)
    with pytest.raises(ValueError, match="not closed: 3 edges"):
        check_closed(vertices, faces[1:])
    flipped = faces.copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(ValueError, match="not consistently oriented"):
        check_closed(vertices, flipped)
    with pytest.raises(ValueError, match="integer array"):
        check_closed(vertices, faces.astype(float))


@pytest.mark.parametrize("suffix", [".stl", ".obj"])
def test_read_surface_round_trip(tmp_path, suffix):
    """An icosphere written by meshio and read back is the same closed surface (STL's repeated
    facet corners merged)."""
    import meshio

    vertices, faces = icosphere(2)
    path = tmp_path / f"sphere{suffix}"
    meshio.write(path, meshio.Mesh(vertices, [("triangle", faces)]), **({"binary": True} if suffix == ".stl" else {}))
    read_vertices, read_faces = read_surface(path)
    assert len(read_vertices) == len(vertices) and len(read_faces) == len(faces)
    check_closed(read_vertices, read_faces)
    assert enclosed_volume(read_vertices, read_faces) == pytest.approx(enclosed_volume(vertices, faces), rel=1e-6)


def test_read_surface_names_the_bad_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_surface(tmp_path / "missing.stl")
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"\x00\x01 not a mesh" * 3)
    with pytest.raises(ValueError, match="garbage.stl"):
        read_surface(garbage)
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    with pytest.raises(ValueError, match="empty.obj is empty"):
        read_surface(empty)
    unknown = tmp_path / "sphere.xyz123"
    unknown.write_text("1 2 3\n")
    with pytest.raises(ValueError, match="sphere.xyz123"):
        read_surface(unknown)


def test_a_non_closed_surface_is_refused():
    vertices, faces = icosphere(1)
    with pytest.raises(ValueError, match="not closed"):
        tetrahedralise(vertices, faces[:-1])


def check_tetrahedra(nodes, tets, surface_volume, tolerance):
    volumes = tet_volumes(nodes, tets)
    assert np.all(volumes > 0)
    assert np.array_equal(np.unique(tets), np.arange(len(nodes)))  # every node used
    assert abs(volumes.sum() / surface_volume - 1) < tolerance
    quality = tet_quality(nodes, tets)
    assert quality["radius_edge"].max() <= 5.0 and quality["mean_ratio"].min() >= 0.02  # the default limits
    return volumes


def test_icosphere_tetrahedralises_with_positive_tetrahedra():
    """fTetWild on a 1280-face icosphere of radius 1 cm: every tetrahedron positive, the total
    volume within 2% of the surface's enclosed volume (0.07% measured), and with max_volume every
    tetrahedron below it."""
    pytest.importorskip("pytetwild", reason="the mesh extra (pytetwild) is not installed")
    vertices, faces = icosphere(3)
    surface_volume = enclosed_volume(vertices, faces)
    nodes, tets = tetrahedralise(vertices, faces)
    check_tetrahedra(nodes, tets, surface_volume, 0.02)
    radius = np.linalg.norm(nodes, axis=1)
    assert radius.max() <= 0.01 * (1 + 2e-3)  # inside the envelope (1e-3 of the diagonal)
    limit = 2e-8  # m^3: a 3 mm-edge regular tetrahedron is 3.2e-9
    nodes, tets = tetrahedralise(vertices, faces, max_volume=limit)
    volumes = check_tetrahedra(nodes, tets, surface_volume, 0.02)
    assert volumes.max() <= limit
    with pytest.raises(ValueError, match="max_radius_edge"):
        tetrahedralise(vertices, faces, max_radius_edge=0.5)


def test_phantom_lobe_surface_tetrahedralises():
    """The liver phantom's outer surface (marching tetrahedra at 4 mm, thin rims included)."""
    pytest.importorskip("pytetwild", reason="the mesh extra (pytetwild) is not installed")
    from sim_core.models.phantoms import liver_lobe

    phantom = liver_lobe(0.004)
    vertices, faces = phantom.surface()
    nodes, tets = tetrahedralise(vertices, faces, edge_length=0.004)
    check_tetrahedra(nodes, tets, enclosed_volume(vertices, faces), 0.02)
    assert abs(tet_volumes(nodes, tets).sum() / phantom.volume() - 1) < 0.03


def test_missing_extra_names_it(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pytetwild", None)  # as if not installed
    vertices, faces = icosphere(1)
    with pytest.raises(ImportError, match=r"tissue-gym\[mesh\]"):
        tetrahedralise(vertices, faces)


@pytest.mark.parametrize("model", ["baudet", "baudet-hyperelastic"])
def test_tet_mesh_from_a_surface_file_passes_the_patch_test(tmp_path, model):
    """``TetMesh.read`` of an STL sphere (1 cm radius) tetrahedralises it (``TetMesh.from_surface``):
    every tetrahedron positive, volume within 2% of the surface's. On those unstructured tetrahedra
    the patch test: with the surface nodes moved by a homogeneous stretch (1% along x, -0.45% across),
    the static interior nodes follow the same affine field to 1e-8 of the stretch (a linear
    tetrahedron's springs and stress correction are exact for an affine field whatever its shape,
    and a homogeneous deformation is an equilibrium of any homogeneous law, the hyperelastic one included)."""
    pytest.importorskip("pytetwild", reason="the mesh extra (pytetwild) is not installed")
    import meshio

    from sim_core import Material, TetMesh, build_model, solve_static
    from sim_core.models.model import Control

    vertices, faces = icosphere(2)
    path = tmp_path / "sphere.stl"
    meshio.write_points_cells(path, vertices, [("triangle", faces)], binary=True)
    mesh = TetMesh.read(path, edge_length=0.004)
    assert np.all(mesh.element_volumes() > 0)
    assert abs(mesh.element_volumes().sum() / enclosed_volume(vertices, faces) - 1) < 0.02
    mesh.write(tmp_path / "sphere.vtu")
    with pytest.raises(ValueError, match="only to a surface file"):
        TetMesh.read(tmp_path / "sphere.vtu", edge_length=0.004)

    stretch = np.diag([1.01, 0.9955, 0.9955])
    surface = mesh.surface_nodes()
    interior = np.setdiff1d(np.arange(mesh.n_nodes), surface)
    assert len(interior) > 0
    built = build_model(mesh, Material(1e4, 0.45, 1000.0), model=model, gravity=(0.0, 0.0, 0.0))
    control = Control.free(mesh.n_nodes).impose(surface, mesh.nodes[surface] @ stretch.T)
    result = solve_static(built, control, tolerance=1e-12)
    assert result.converged
    error = np.abs(result.positions[interior] - mesh.nodes[interior] @ stretch.T).max()
    assert error < 1e-8 * 0.01 * 0.01  # of the 1e-4 m stretch of a 1 cm radius


def test_from_surface_refuses_an_open_surface():
    pytest.importorskip("pytetwild", reason="the mesh extra (pytetwild) is not installed")
    from sim_core import TetMesh

    vertices, faces = icosphere(1)
    with pytest.raises(ValueError, match="closed|edge"):
        TetMesh.from_surface(vertices, faces[1:])
