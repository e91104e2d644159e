"""The camera's z-buffer rasteriser (tissue_env.camera) against analytic scenes.

References nobody tuned: the pinhole model's rays through the pixel centres (written here from the
convention, not taken from the module), ray-plane intersections, the projected area of a cube face
(f / distance per unit length) and Lambert's cosine law.
"""

import numpy as np
import pytest

from sim_core import HexMesh
from tissue_env.camera import (AMBIENT, BACKGROUND, LIGHT_DIRECTION, Camera, CameraView, SurfaceSampler, lambert,
                               rasterise, surface_triangles, triangle_normals)


def axis_camera(size=64, fov=60.0, near=0.01, far=100.0):
    """At the origin looking along +z, y up: its right is world -x."""
    return Camera(position=(0, 0, 0), target=(0, 0, 1), up=(0, 1, 0), fov_deg=fov, width=size, height=size,
                  near=near, far=far)


def reference_rays(camera):
    """(H, W, 3) world rays (forward component 1) through the pixel centres of ``axis_camera``."""
    focal = 0.5 * camera.height / np.tan(np.radians(camera.fov_deg) / 2)
    x = (np.arange(camera.width) + 0.5 - camera.width / 2) / focal
    y = (camera.height / 2 - (np.arange(camera.height) + 0.5)) / focal
    x, y = np.meshgrid(x, y)
    return np.stack([-x, y, np.ones_like(x)], axis=-1)  # right = -x, up = +y, forward = +z


def quad(corners):
    return np.asarray(corners, dtype=float), np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("distance", [0.05, 0.3, 7.0])
def test_plane_facing_the_camera_has_its_exact_depth_everywhere(distance):
    camera = axis_camera()
    half = 10 * distance  # far wider than the field of view
    vertices, triangles = quad([[-half, -half, distance], [half, -half, distance], [half, half, distance],
                                [-half, half, distance]])
    rgb, depth = rasterise(camera, vertices, triangles, np.full((2, 3), 200, np.uint8))
    assert np.all(rgb == 200)
    np.testing.assert_allclose(depth, distance, rtol=1e-9, atol=0)


def test_tilted_plane_depth_is_the_ray_intersection():
    """Perspective-correct depth: a plane n . x = c seen obliquely gives depth c / (n . ray) at
    each pixel (the ray's forward component is 1), to 1e-9 relative."""
    camera = axis_camera(size=80)
    normal = np.array([0.3, -0.2, 1.0])
    offset = 0.5
    # a quad in the plane wider than the view: corners at z solving n . x = c for x, y = +-0.6
    corners = [[x, y, (offset - normal[0] * x - normal[1] * y) / normal[2]] for x, y in
               ((-0.6, -0.6), (0.6, -0.6), (0.6, 0.6), (-0.6, 0.6))]
    vertices, triangles = quad(corners)
    _, depth = rasterise(camera, vertices, triangles, np.full((2, 3), 255, np.uint8))
    expected = offset / (reference_rays(camera) @ normal)
    np.testing.assert_allclose(depth, expected, rtol=1e-9, atol=0)


@pytest.mark.parametrize("distance", [2.0, 3.5, 6.0])
def test_unit_cube_along_an_axis_covers_its_projected_square(distance):
    mesh = HexMesh.block((2, 2, 2), spacing=0.5)
    nodes = mesh.nodes - 0.5  # the unit cube centred at the origin
    camera = Camera(position=(0, 0, -distance), target=(0, 0, 0), up=(0, 1, 0), fov_deg=40.0, width=96, height=96,
                    near=0.1, far=50.0)
    triangles = surface_triangles(mesh.surface_faces())
    rgb, depth = rasterise(camera, nodes, triangles, np.full((len(triangles), 3), 255, np.uint8))
    focal = 0.5 * camera.height / np.tan(np.radians(20.0))
    side = focal * 1.0 / (distance - 0.5)  # pixels: the front face at distance - 0.5
    covered = depth < camera.far
    centre = np.arange(96) + 0.5 - 48.0
    x, y = np.meshgrid(centre, centre)
    inside = np.maximum(np.abs(x), np.abs(y)) < side / 2 - 1.0
    outside = np.maximum(np.abs(x), np.abs(y)) > side / 2 + 1.0
    assert covered[inside].all() and not covered[outside].any()
    assert abs(covered.sum() - side**2) <= 4 * side + 4  # a one-pixel border around the square
    np.testing.assert_allclose(depth[covered], distance - 0.5, rtol=1e-9)  # only the front face is seen
    assert np.all(rgb[~covered] == BACKGROUND)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_nearer_triangle_wins_whatever_the_drawing_order(order):
    camera = axis_camera()
    near_vertices = [[-1, -1, 1.0], [1, -1, 1.0], [0, 1, 1.0]]
    far_vertices = [[-3, -3, 2.0], [3, -3, 2.0], [0, 3, 2.0]]  # larger in the image
    vertices = np.array(near_vertices + far_vertices, dtype=float)
    triangles = np.array([[0, 1, 2], [3, 4, 5]])[list(order)]
    colours = np.array([[255, 0, 0], [0, 0, 255]], np.uint8)[list(order)]
    rgb, depth = rasterise(camera, vertices, triangles, colours)
    # the ray through the image centre meets both: the near (red) one wins
    centre = rgb[32, 32]
    assert tuple(centre) == (255, 0, 0) and depth[32, 32] == pytest.approx(1.0, rel=1e-12)
    near_only = np.isclose(depth, 1.0, rtol=1e-9)
    far_seen = np.isclose(depth, 2.0, rtol=1e-9)
    assert near_only.sum() > 0 and far_seen.sum() > 0
    assert np.all(rgb[near_only] == [255, 0, 0]) and np.all(rgb[far_seen] == [0, 0, 255])


def test_near_and_far_planes():
    camera = axis_camera(near=0.5, far=3.0)
    colours = np.full((2, 3), 255, np.uint8)
    crossing, triangles = quad([[-1, -1, 0.2], [1, -1, 1.0], [1, 1, 1.0], [-1, 1, 0.2]])  # a vertex nearer than near
    assert np.all(rasterise(camera, crossing, triangles, colours)[1] == 3.0)
    beyond, triangles = quad([[-9, -9, 4.0], [9, -9, 4.0], [9, 9, 4.0], [-9, 9, 4.0]])
    rgb, depth = rasterise(camera, beyond, triangles, colours)
    assert np.all(depth == 3.0) and np.all(rgb == BACKGROUND)
    behind, triangles = quad([[-1, -1, -1.0], [1, -1, -1.0], [1, 1, -1.0], [-1, 1, -1.0]])
    assert np.all(rasterise(camera, behind, triangles, colours)[1] == 3.0)


@pytest.mark.parametrize("tilt", [0.0, 0.4, 1.1])
def test_lambert_shading_follows_the_cosine_law(tilt):
    camera = axis_camera()
    normal = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])  # towards the camera (at -z of the plane)
    tangent = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
    centre = np.array([0, 0, 2.0])
    vertices = np.array([centre - tangent - [0, 1, 0], centre + tangent - [0, 1, 0], centre + [0, 1, 0]])
    albedo = np.array([[0.9, 0.5, 0.2]])
    colour = lambert(vertices, np.array([[0, 1, 2]]), albedo, camera)[0]
    light = np.asarray(LIGHT_DIRECTION) / np.linalg.norm(LIGHT_DIRECTION)
    expected = 255 * albedo[0] * (AMBIENT + (1 - AMBIENT) * max(normal @ light, 0.0))
    np.testing.assert_allclose(colour, expected, atol=0.5)
    # two-sided: the same triangle wound the other way is shaded alike
    np.testing.assert_array_equal(lambert(vertices, np.array([[0, 2, 1]]), albedo, camera)[0], colour)


def test_surface_triangles_point_outward_and_cover_the_surface():
    mesh = HexMesh.block((2, 3, 4), spacing=(0.1, 0.2, 0.05))
    triangles = surface_triangles(mesh.surface_faces())
    nodes = mesh.nodes
    centre = nodes.mean(axis=0)
    normals = triangle_normals(nodes, triangles)
    assert np.all(np.sum(normals * (nodes[triangles].mean(axis=1) - centre), axis=1) > 0)
    a, b, c = (nodes[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    lx, ly, lz = nodes.max(axis=0) - nodes.min(axis=0)
    assert area == pytest.approx(2 * (lx * ly + ly * lz + lx * lz), rel=1e-12)


def test_point_cloud_points_lie_on_the_surface_in_proportion_to_area():
    mesh = HexMesh.block((2, 1, 3), spacing=(0.03, 0.01, 0.02))  # faces of different areas
    nodes = mesh.nodes
    triangles = surface_triangles(mesh.surface_faces())
    count = 2000
    sampler = SurfaceSampler(triangles, nodes, count)
    points = sampler.sample(nodes[None], normals=True)[0]
    assert points.shape == (count, 6)
    low, high = nodes.min(axis=0), nodes.max(axis=0)
    on_face = np.isclose(points[:, :3], low, atol=1e-12) | np.isclose(points[:, :3], high, atol=1e-12)
    assert on_face.any(axis=1).all()
    assert np.all((points[:, :3] >= low - 1e-12) & (points[:, :3] <= high + 1e-12))
    np.testing.assert_allclose(np.linalg.norm(points[:, 3:], axis=1), 1.0, rtol=1e-12)
    # each of the 6 box faces gets its share of the area, stratified: within a point per triangle
    size = high - low
    areas = {0: size[1] * size[2], 1: size[0] * size[2], 2: size[0] * size[1]}
    total = 2 * sum(areas.values())
    for axis in range(3):
        share = np.isclose(points[:, axis], high[axis], atol=1e-12).sum()
        assert abs(share - count * areas[axis] / total) <= len(triangles) / 2
    # deterministic: a second sampler places the same points
    np.testing.assert_array_equal(SurfaceSampler(triangles, nodes, count).sample(nodes[None]), points[None, :, :3])


def test_point_cloud_follows_the_deformed_surface():
    mesh = HexMesh.block((2, 2, 2), spacing=0.01)
    triangles = surface_triangles(mesh.surface_faces())
    sampler = SurfaceSampler(triangles, mesh.nodes, 300)
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = mesh.nodes @ rotation.T + [0.1, 0.2, 0.3]  # a rigid motion moves every point with it
    np.testing.assert_allclose(sampler.sample(moved[None])[0], sampler.sample(mesh.nodes[None])[0] @ rotation.T
                               + [0.1, 0.2, 0.3], atol=1e-15)


def test_camera_view_shapes_and_dtypes():
    mesh = HexMesh.block((3, 3, 3), spacing=0.01)
    camera = Camera(position=(0.08, 0.08, 0.1), target=(0.015, 0.015, 0.015), width=64, height=48, near=0.01, far=0.5)
    view = CameraView(camera, mesh.surface_faces(), mesh.nodes, tool_nodes=[], point_count=100,
                      bounds=(-np.ones(3), np.ones(3)))
    positions = np.stack([mesh.nodes, mesh.nodes + [0.002, 0, 0]])
    for kind, shape, dtype in (("rgb", (48, 64, 3), np.uint8), ("depth", (48, 64, 1), np.float32),
                               ("rgbd", (48, 64, 4), np.float32), ("point_cloud", (100, 3), np.float32)):
        observation, clipped = view.observe(kind, positions)
        space = view.space(kind)
        assert observation.shape == (2,) + shape == (2,) + space.shape
        assert observation.dtype == dtype == space.dtype
        assert all(space.contains(row) for row in observation) and not clipped.any()
    rgb = view.observe("rgb", positions)[0]
    assert rgb.min() >= 0 and rgb.max() <= 255 and (rgb > 0).any()


@pytest.mark.parametrize("keywords, message", [
    (dict(position=(0, 0, 0), target=(0, 0, 0)), "must differ"),
    (dict(up=(0, 0, 1)), "parallel"),
    (dict(fov_deg=180), "fov_deg"),
    (dict(near=1.0, far=0.5), "near and far"),
    (dict(width=0), "width"),
    (dict(height=12.5), "height"),
    (dict(position=(0, np.nan, 1)), "finite"),
])
def test_camera_refuses_bad_values(keywords, message):
    arguments = dict(position=(0, 0, 1), target=(0, 0, 0), up=(0, 1, 0))
    arguments.update(keywords)
    with pytest.raises(ValueError, match=message):
        Camera(**arguments)
