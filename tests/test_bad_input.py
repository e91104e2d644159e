"""Bad input gets a ValueError saying what was wrong and what is allowed (mesh files, solve_static's
arguments and control, the probe, under-constrained static problems)."""

import numpy as np
import pytest

from sim_core import HexMesh, Material, build_model

from sim_core.solvers import contact
from sim_core.models.model import Control
from sim_core.solvers.static import solve_static, unconstrained_motions


@pytest.fixture(scope="module")
def block():
    mesh = HexMesh.block((2, 2, 2), spacing=0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060.0), gravity=(0, -9.81, 0), hourglass_control=1.0)
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    return mesh, model, bottom


def clamped(block):
    mesh, model, bottom = block
    return model.new_control().impose(bottom, mesh.nodes[bottom])


# -- mesh files ---------------------------------------------------------------------------------
@pytest.mark.parametrize("ext", ["vtu", "msh", "vtk"])
def test_empty_file(tmp_path, ext):
    path = tmp_path / f"empty.{ext}"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=rf"empty\.{ext} is empty \(0 bytes\): not a \.{ext}"):
        HexMesh.read(path)


@pytest.mark.parametrize("ext", ["vtu", "msh", "vtk"])
@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_corrupt_file_is_a_value_error_not_an_exit(tmp_path, ext, damage):
    good = tmp_path / f"good.{ext}"
    HexMesh.block((2, 1, 1)).write(good)
    data = good.read_bytes()
    path = tmp_path / f"{damage}.{ext}"
    path.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"\x00\x17not a mesh\xff" * 20)
    with pytest.raises(ValueError, match=rf"{damage}\.{ext} is not a readable \.{ext} .*mesh") as caught:
        HexMesh.read(path)
    assert caught.value.__cause__ is not None  # chained from meshio's error (SystemExit for vtu/vtk)


def test_keyboard_interrupt_still_propagates(tmp_path, monkeypatch):
    import meshio

    path = tmp_path / "good.vtu"
    HexMesh.block((1, 1, 1)).write(path)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(meshio, "read", interrupted)
    with pytest.raises(KeyboardInterrupt):
        HexMesh.read(path)


@pytest.mark.parametrize("cell, connectivity, ext", [("tetra", [[0, 1, 2, 3]], "vtu"), ("quad", [[0, 1, 2, 3]], "msh")])
def test_no_hexahedra(tmp_path, cell, connectivity, ext):
    import meshio

    path = tmp_path / f"{cell}.{ext}"
    points = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 1.0]])
    meshio.write(path, meshio.Mesh(points, [(cell, np.array(connectivity))]), **({"file_format": "gmsh"} if ext == "msh" else {}))
    with pytest.raises(ValueError, match=rf"{cell}\.{ext} contains no hexahedra \(found 1 {cell}\); HexMesh needs 8-node"):
        HexMesh.read(path)


def test_inconsistent_hexahedra(tmp_path):
    import meshio

    mesh = HexMesh.block((1, 1, 1))
    elements = mesh.elements.copy()
    elements[0, 0] = 99
    path = tmp_path / "outside.vtu"
    meshio.write(path, meshio.Mesh(mesh.nodes, [("hexahedron", elements)]))
    with pytest.raises(ValueError, match=r"outside\.vtu: its hexahedra do not form a valid mesh: element node indices "
                                         r"must lie in \[0, 7\]"):
        HexMesh.read(path)
    path = tmp_path / "inverted.vtu"
    meshio.write(path, meshio.Mesh(mesh.nodes, [("hexahedron", mesh.elements[:, [1, 0, 3, 2, 5, 4, 7, 6]])]))
    with pytest.raises(ValueError, match=r"inverted\.vtu: .*inverted element 0"):
        HexMesh.read(path)


def test_missing_file_unsupported_extension_and_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        HexMesh.read(tmp_path / "missing.vtu")
    odd = tmp_path / "mesh.xyz"
    odd.write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"mesh\.xyz: unsupported mesh file extension '\.xyz'; HexMesh.read reads"):
        HexMesh.read(odd)
    with pytest.raises(ValueError, match="is not a file"):
        HexMesh.read(tmp_path)


def test_a_valid_file_reads_back(tmp_path):
    mesh = HexMesh.block((2, 1, 3), spacing=0.01)
    for ext in ("vtu", "msh", "vtk"):
        mesh.write(tmp_path / f"ok.{ext}")
        read = HexMesh.read(tmp_path / f"ok.{ext}")
        assert np.array_equal(read.elements, mesh.elements) and np.allclose(read.nodes, mesh.nodes)


# -- solve_static's arguments and control -------------------------------------------------------
@pytest.mark.parametrize("keyword, message", [
    (dict(tolerance=-1), "tolerance must be a finite number > 0"),
    (dict(tolerance=0), "tolerance must be a finite number > 0"),
    (dict(tolerance=float("nan")), "tolerance must be a finite number > 0"),
    (dict(tolerance="1e-8"), "tolerance must be a finite number > 0 .*got str"),
    (dict(max_iterations=0), "max_iterations must be an integer >= 1, got 0"),
    (dict(max_iterations=2.5), "max_iterations must be an integer >= 1, got 2.5"),
    (dict(max_iterations=True), "max_iterations must be an integer >= 1, got bool"),
    (dict(load_steps=0), "load_steps must be an integer >= 1, got 0"),
    (dict(max_load_steps=0), "max_load_steps must be an integer >= 1, got 0"),
    (dict(chord_contraction=1.5), r"chord_contraction must be a number in \(0, 1\)"),
    (dict(acceleration=-1), "acceleration must be an integer >= 0"),
])
def test_solver_arguments(block, keyword, message):
    with pytest.raises(ValueError, match=message):
        solve_static(block[1], clamped(block), **keyword)


def test_integral_floats_are_accepted(block):
    a = solve_static(block[1], clamped(block), max_iterations=40.0, load_steps=1.0)
    b = solve_static(block[1], clamped(block))
    assert np.array_equal(a.positions, b.positions)


def test_non_finite_control(block):
    model = block[1]
    control = clamped(block)
    control.force[[3, 5], 0] = [np.nan, np.inf]
    with pytest.raises(ValueError, match=r"control.force has 2 non-finite entries \(NaN or infinity\); nodal forces "
                                         "must all be finite numbers in N"):
        solve_static(model, control)
    control = clamped(block)
    control.target[0, 1] = np.nan
    with pytest.raises(ValueError, match="control.target has 1 non-finite entries .* where control.fixed is True"):
        solve_static(model, control)
    control = clamped(block)
    control.target[~control.fixed] = np.nan  # not read where free
    assert solve_static(model, control).converged


def test_control_shapes(block):
    mesh, model, _ = block
    with pytest.raises(ValueError, match=rf"control.force must be a \({mesh.n_nodes}, 3\) array .* got shape \(4, 3\)"):
        solve_static(model, Control(np.zeros((mesh.n_nodes, 3), bool), np.zeros((mesh.n_nodes, 3)), np.zeros((4, 3))))
    with pytest.raises(ValueError, match="control.fixed must be a boolean"):
        solve_static(model, Control(np.zeros((mesh.n_nodes, 3), int), np.zeros((mesh.n_nodes, 3)),
                                    np.zeros((mesh.n_nodes, 3))))
    with pytest.raises(ValueError, match=rf"initial must be a \({mesh.n_nodes}, 3\) array of positions in m .* got shape"):
        solve_static(model, clamped(block), initial=np.zeros((3, 3)))
    start = mesh.nodes.copy()
    start[2] = np.nan
    with pytest.raises(ValueError, match="initial has 3 non-finite entries"):
        solve_static(model, clamped(block), initial=start)


def test_impose_checks(block):
    mesh, model, _ = block
    control = model.new_control()
    with pytest.raises(ValueError, match=rf"node indices must lie in \[0, {mesh.n_nodes - 1}\]"):
        control.impose([mesh.n_nodes], [0, 0, 0])
    with pytest.raises(ValueError, match="components must be among 0, 1, 2"):
        control.impose([0], [0, 0, 0], components=3)
    with pytest.raises(ValueError, match="nodes must be a 1D sequence of integer node indices"):
        control.impose([0.5], [0, 0, 0])
    with pytest.raises(ValueError, match=r"positions must broadcast to \(2, 3\)"):
        control.impose([0, 1], np.zeros((3, 3)))


# -- probe ------------------------------------------------------------------------------------
@pytest.mark.parametrize("radius, got", [("0.01", "str '0.01'"), (np.array([[0.01, 0.02]]), r"an array of shape \(1, 2\)"),
                                         (0.0, "0.0"), (-0.01, "-0.01"), (float("nan"), "nan"), (True, "bool True")])
def test_probe_radius(radius, got):
    with pytest.raises(ValueError, match=rf"probe radius must be one finite number > 0 \(a length in m, e.g. 0.005\), "
                                         rf"got {got}"):
        contact.Probe(radius)


@pytest.mark.parametrize("radii", [np.array([0.01, 0.0]), np.array([0.01, np.nan]), np.array([])])
def test_per_copy_probe_radii(radii):
    # stacked copies may hold one radius each (a domain-randomised probe): each finite and > 0
    with pytest.raises(ValueError, match=r"probe radii must be finite numbers > 0 \(lengths in m\)"):
        contact.Probe(radii)


def test_probe_arguments():
    assert contact.Probe(np.float64(0.01)).radius == 0.01 and contact.Probe(np.array(0.01)).radius == 0.01
    with pytest.raises(ValueError, match="probe tip must be one of"):
        contact.Probe(0.01, tip="cone")
    with pytest.raises(ValueError, match="projection must be None or a SurfaceProjection"):
        contact.Probe(0.01, "sphere", 3)
    with pytest.raises(ValueError, match="floor height must be one finite number"):
        contact.Floor(float("inf"))
    probe = contact.Probe(0.01)
    with pytest.raises(ValueError, match=r"probe tip position must be an \(x, y, z\) point in m"):
        probe.surface(np.zeros((4, 3)), [0.0, 1.0])
    with pytest.raises(ValueError, match="probe tip position must be finite"):
        probe.surface(np.zeros((4, 3)), [0.0, np.nan, 0.0])
    assert probe.surface(np.zeros((2, 4, 3)), [0.0, 1.0, 0.0]).shape == (2, 4)  # one tip for stacked copies


# -- under-constrained static problems ---------------------------------------------------------
def test_no_support_under_gravity(block):
    model = block[1]
    with pytest.raises(ValueError, match=r"under-constrained static problem: .* leave 6 rigid-body motion\(s\) free: "
                                         r".*the load \(gravity \+ control.force\) pushes along translation along y, so "
                                         r"no static equilibrium exists. Impose those components on some nodes"):
        solve_static(model, model.new_control())


def test_named_motions(block):
    mesh = block[0]
    fixed = np.zeros((mesh.n_nodes, 3), bool)
    fixed[0] = True
    assert [name for name, _ in unconstrained_motions(mesh.nodes, fixed)] == [
        "rotation about x (axis at y = 0, z = 0 m)", "rotation about y (axis at x = 0, z = 0 m)",
        "rotation about z (axis at x = 0, y = 0 m)"]
    fixed[:] = False
    fixed[:, 0] = True
    assert [name for name, _ in unconstrained_motions(mesh.nodes, fixed)] == [
        "rotation about x (axis at y = 0.01, z = 0.01 m)", "translation along y", "translation along z"]
    fixed[:] = True
    assert unconstrained_motions(mesh.nodes, fixed) == []


def test_free_motions_the_load_does_not_push_along_are_allowed(block):
    mesh, model, bottom = block
    floor = model.new_control().impose(bottom, mesh.nodes[bottom], components=1)  # x, z, rotation about y free
    assert solve_static(model, floor).converged  # gravity is vertical: nothing pushes along them
    floor.force[bottom[0], 0] = 0.01
    with pytest.raises(ValueError, match="pushes along rotation about y .*translation along x"):
        solve_static(model, floor)
    rest = build_model(mesh, Material(5e3, 0.45, 1060.0))  # no gravity, no supports: nothing pushes
    result = solve_static(rest, rest.new_control())
    assert np.array_equal(result.positions, mesh.nodes)


def test_one_node_held_under_gravity(block):
    mesh, model, _ = block
    control = model.new_control().impose([0], mesh.nodes[0])
    with pytest.raises(ValueError, match="pushes along rotation about x .*rotation about z"):
        solve_static(model, control)


@pytest.mark.parametrize("keyword, message", [
    (dict(tolerance=float("inf")), r"tolerance must be a finite number > 0 \(a relative force residual, e.g. 1e-6\), got inf"),
    (dict(max_iterations=2.5), "max_iterations must be an integer >= 1, got 2.5"),
    (dict(max_load_steps="8"), "max_load_steps must be an integer >= 1, got str '8'"),
])
def test_quasi_static_arguments(keyword, message):
    from sim_core.solvers.static import QuasiStatic

    with pytest.raises(ValueError, match=message):
        QuasiStatic(**keyword)
