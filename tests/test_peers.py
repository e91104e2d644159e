"""benchmarks/peers.py: the shared geometry (hex-to-tet split, MJCF and VTK writers) and, when the
peer packages are installed, one tiny run of each engine. Timing is never asserted."""

import re

import numpy as np
import pytest

from benchmarks import peers
from sim_core.geometry.mesh import HexMesh


def tiny_scene():
    return peers.Scene(shape=(2, 2, 2), spacing=0.05, young_modulus=1e4, poisson_ratio=0.3, density=1500.0,
                       gravity=0.5)


def test_hex_to_tets_conserves_volume_with_positive_tets():
    mesh = HexMesh.block((3, 2, 4), spacing=(0.1, 0.07, 0.05))
    # a sheared, non-uniform mesh too: the split must not assume cubes
    sheared = mesh.nodes + 0.2 * mesh.nodes[:, [1]] * np.array([1.0, 0.0, 0.0]) + 0.01 * np.sin(mesh.nodes)
    for nodes in (mesh.nodes, sheared):
        tets = peers.hex_to_tets(nodes, mesh.elements)
        assert tets.shape == (6 * mesh.n_elements, 4)
        volumes = peers.tet_volumes(nodes, tets)
        assert np.all(volumes > 0)
    tets = peers.hex_to_tets(mesh.nodes, mesh.elements)
    # exact for the block's (affine) hexahedra
    assert peers.tet_volumes(mesh.nodes, tets).sum() == pytest.approx(mesh.element_volumes().sum(), rel=1e-12)
    assert peers.tet_volumes(mesh.nodes, tets).sum() == pytest.approx(0.3 * 0.14 * 0.2, rel=1e-12)


def test_hex_to_tets_is_conforming():
    # every interior triangle is shared by exactly two tets, boundary triangles tile the surface
    mesh = HexMesh.block((2, 2, 2), 0.1)
    tets = peers.hex_to_tets(mesh.nodes, mesh.elements)
    faces = np.sort(tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2}
    assert np.sum(counts == 1) == 6 * 4 * 2  # 6 faces x 4 quads x 2 triangles


def test_writers_have_the_scene_nodes(tmp_path):
    scene = tiny_scene()
    vtk = peers.write_vtk(tmp_path / "block.vtk", scene.nodes, scene.tets).read_text()
    assert f"POINTS {len(scene.nodes)} double" in vtk and len(scene.nodes) == 27
    assert f"CELLS {len(scene.tets)} {5 * len(scene.tets)}" in vtk
    lines = vtk.splitlines()
    start = lines.index(f"POINTS {len(scene.nodes)} double") + 1
    points = np.array([[float(v) for v in line.split()] for line in lines[start:start + len(scene.nodes)]])
    np.testing.assert_allclose(points, scene.nodes)
    xml = peers.mjcf(scene.nodes, scene.tets, scene.bottom, young_modulus=1e4, poisson_ratio=0.3, mass=scene.mass,
                     gravity=0.5, dt=1e-3, damping=scene.rayleigh_beta)
    point = re.search(r'point="([^"]*)"', xml).group(1).split()
    element = re.search(r'element="([^"]*)"', xml).group(1).split()
    pin = re.search(r'pin id="([^"]*)"', xml).group(1).split()
    assert len(point) == 3 * 27 and len(element) == 4 * len(scene.tets) and len(pin) == 9
    assert scene.mass == pytest.approx(1500.0 * 0.1**3)


def _run_engine(engine, scene):
    run = peers.simulate_from_rest(engine, scene, 1e-3, 0.05)
    assert run["finite"] and run["unstable_reason"] is None
    assert run["top_sag_m"] < 0  # sags under gravity
    assert abs(run["top_sag_m"]) < 0.01
    np.testing.assert_allclose(np.asarray(engine.positions())[scene.bottom], scene.nodes[scene.bottom], atol=1e-9)


def test_ours_tiny_block():
    scene = tiny_scene()
    for kind in ("explicit", "implicit"):
        _run_engine(peers.Ours(scene, kind), scene)


def test_mujoco_tiny_block():
    pytest.importorskip("mujoco")
    scene = tiny_scene()
    engine = peers.MuJoCoFlex(scene)
    try:
        assert engine.model.nflexvert == 27 and engine.model.nflexelem == len(scene.tets)
        _run_engine(engine, scene)
        # a divergence is reported even though MuJoCo resets the state to finite values
        peers.simulate_from_rest(engine, scene, 0.2, 2.0)
        assert engine.unstable_reason is not None
    finally:
        engine.close()


def test_pybullet_tiny_block(tmp_path):
    pytest.importorskip("pybullet")
    scene = tiny_scene()
    engine = peers.PyBulletNeoHookean(scene, workdir=tmp_path)
    try:
        assert len(engine.positions()) == 27
        _run_engine(engine, scene)
    finally:
        engine.close()


def test_missing_package_is_skipped(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_peers(name, *args, **kwargs):
        if name in ("mujoco", "pybullet"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_peers)
    engines, records = peers.build_engines(tiny_scene())
    assert set(engines) == {"ours-explicit", "ours-implicit"}
    assert {name: r["status"] for name, r in records.items()} == {"mujoco-flex": "skipped",
                                                                  "pybullet-neohookean": "skipped"}
