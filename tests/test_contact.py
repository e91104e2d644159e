"""sim_core.solvers.contact: frictionless height-field obstacles (floor, sphere and flat probes) and their
active set, on one block and on stacked copies; the static scene's probe converges with the mesh."""

import numpy as np
import pytest

from sim_core.solvers import contact
from sim_core.resolution import Scene, scene_errors, solve_scene


def probe_height(probe, x, z, tip):
    """The probe's lower surface (m) over the horizontal points x, z for a tip (3,) m, +inf outside
    its radius: flat at the tip's height, or the sphere of the probe's radius whose bottom is the tip."""
    r2 = (x - tip[0]) ** 2 + (z - tip[2]) ** 2
    if probe.tip == "flat":
        height = np.full(r2.shape, tip[1])
    else:
        height = tip[1] + probe.radius - np.sqrt(np.maximum(probe.radius**2 - r2, 0.0))
    return np.where(r2 <= probe.radius**2, height, np.inf)


def test_probe_surfaces():
    probe, flat = contact.Probe(0.009), contact.Probe(0.009, "flat")
    tip = np.array([0.03, 0.02, 0.03])
    points = np.array([[0.03, 0.0, 0.03], [0.036, 0.0, 0.03], [0.03, 0.0, 0.0395], [0.04, 0.0, 0.03]])
    r = np.array([0.0, 0.006, 0.0095, 0.01])
    expected = np.where(r <= 0.009, 0.02 + 0.009 - np.sqrt(np.maximum(0.009**2 - r**2, 0)), np.inf)
    np.testing.assert_allclose(probe.surface(points, tip), expected)
    np.testing.assert_array_equal(flat.surface(points, tip), np.where(r <= 0.009, 0.02, np.inf))
    # stacked copies: (N, n, 3) positions with (N, 3) tips give each copy's own surface
    stacked = probe.surface(np.stack([points, points]), np.stack([tip, tip + [0.0, 0.001, 0.0]]))
    inside = np.isfinite(expected)
    np.testing.assert_allclose(stacked[1, inside] - stacked[0, inside], 0.001)
    assert np.all(np.isinf(stacked[:, ~inside]))
    assert np.all(contact.Floor().surface(points) == 0.0)


@pytest.mark.parametrize("kwargs", [dict(radius=0.0), dict(radius=-1e-3), dict(radius=np.nan),
                                    dict(radius=0.009, tip="cone")])
def test_invalid_probe_names_what_is_allowed(kwargs):
    with pytest.raises(ValueError, match="radius|tip"):
        contact.Probe(**kwargs)


def test_active_set_update_release_and_projection():
    probe = contact.Probe(0.01)
    tip = np.array([0.0, 0.0, 0.0])
    positions = np.array([[0.0, 0.001, 0.0],     # through the sphere: joins
                          [0.0, -0.001, 0.0],    # 1 mm under it, in contact: released (gap > tolerance)
                          [0.005, 0.0, 0.0],     # in contact, pushed up into the probe: stays
                          [0.004, 0.0, 0.0],     # in contact, pulled down by the tissue: released
                          [0.02, 0.5, 0.0]])     # outside the radius: never
    candidates = np.ones(5, bool)
    held = np.array([False, True, True, True, False])
    forces = np.array([[0, 0, 0], [0, 1.0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 0]], float)
    positions[2, 1] = probe.surface(positions[2:3], tip)[0] - 1e-4  # slid 0.1 mm under the surface
    new = contact.update(probe, held, positions, forces, candidates, tip)
    np.testing.assert_array_equal(new, [True, False, True, False, False])
    heights = contact.targets(probe, positions, new, tip)
    np.testing.assert_allclose(heights[[0, 2]], probe.surface(positions[[0, 2]], tip))
    velocities = np.tile([0.0, 1.0, 0.0], (5, 1))
    through = contact.project(probe, positions, velocities, candidates, tip)
    np.testing.assert_array_equal(through, [True, False, False, False, False])
    assert positions[0, 1] == probe.surface(positions[:1], tip)[0] and velocities[0, 1] == 0.0
    # the floor: a node below is put back on it with its downward velocity removed
    floor_positions, floor_velocities = np.array([[0.0, -1e-3, 0.0]]), np.array([[0.0, -2.0, 0.0]])
    assert contact.project(contact.Floor(), floor_positions, floor_velocities, np.ones(1, bool))[0]
    assert floor_positions[0, 1] == 0.0 and floor_velocities[0, 1] == 0.0


def test_sphere_probe_scene_converges_with_the_mesh_where_the_flat_one_did_not():
    """The static Palpation scene (a 9 mm probe pressed 2-8 mm over the stiff inclusion, E 5 kPa,
    nu 0.45): with the sphere the tool force at n = 8 is within 25% of n = 10 (measured 20% against
    n = 12, 4.5% at n = 10), the flat probe moved 34% between n = 10 and n = 12."""
    scene = Scene(size=(0.06, 0.03, 0.06), young_modulus=5e3, poisson_ratio=0.45, gravity=9.81,
                  tool_low=(0.03, 0.03, 0.03), tool_high=(0.03, 0.03, 0.03), tool_radius=0.009, tool_components=(1,),
                  probe="sphere", displacements=[[(0, -d * 1e-3, 0) for d in (2, 4, 6, 8)]],
                  target=(0.03, 0.015, 0.03), inclusion_low=(0.024, 0.01, 0.024), inclusion_high=(0.036, 0.02, 0.036),
                  inclusion_ratio=10.0)
    solutions = [solve_scene(scene, scene.shape(n), hourglass_control=1.0, volume_stiffness=100.0,
                             check_stability=False) for n in (8, 10)]
    assert all(s.converged.all() for s in solutions)
    force = solutions[1].force[:, 1]
    assert np.all(force < 0) and np.all(np.diff(force) < 0)  # pressing harder needs more force
    assert scene_errors(solutions[0], solutions[1])["force"] < 0.25
    with pytest.raises(ValueError, match="tool_radius"):
        Scene(size=0.05, young_modulus=5e3, poisson_ratio=0.45, tool_low=(0.02, 0.05, 0.02),
              tool_high=(0.03, 0.05, 0.03), displacements=[(0, -1e-3, 0)], target=(0.025, 0.025, 0.025), probe="sphere")


@pytest.mark.parametrize("tip, volume, tolerance", [
    ("sphere", lambda d, r: np.pi * d**2 * (3 * r - d) / 3, 0.015),  # the spherical cap under the surface
    ("flat", lambda d, r: np.pi * r**2 * d, 0.06),  # its sharp edge: 1.8% with 8 midpoints
])
@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.00375, 0.00375), (0.0011, 0.0052)])
def test_projected_probe_displaces_the_probe_s_volume_wherever_the_nodes_fall(tip, volume, tolerance, offset):
    """Projected on the top nodes' hat functions (lumped L2, ``curvature_corrected=False``), a probe 4 mm into a flat surface
    imposes nodal indentations whose sum times the nodes' areas is the volume the probe displaces,
    over a node, between four or anywhere (measured with 4 midpoints per element side: the sphere
    within 1.3%, the flat probe 5%), and only on nodes whose faces the probe reaches. Sampled at the
    nodes, the sphere displaces 0.58x its volume over a node and 1.33x between four."""
    from sim_core.geometry.mesh import HexMesh

    mesh = HexMesh.block((8, 4, 8), (0.0075, 0.0075, 0.0075))
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 1], 0.03))
    # the first-order projection (the default adds the sphere's curvature back: the next test)
    probe = contact.Probe(0.009, tip, contact.SurfaceProjection.top_face(mesh, top), curvature_corrected=False)
    tip_position = np.array([0.03 + offset[0], 0.03 - 0.004, 0.03 + offset[1]])
    heights = probe.surface(mesh.nodes, tip_position)
    pushed = np.isfinite(heights)
    assert np.all(np.isin(np.flatnonzero(pushed), top))
    r = np.hypot(mesh.nodes[:, 0] - tip_position[0], mesh.nodes[:, 2] - tip_position[2])
    assert np.all(r[pushed] < 0.009 + np.hypot(0.0075, 0.0075))
    area = 0.0075**2  # an interior node's share of the face
    displaced = (0.03 - heights[pushed]).sum() * area
    assert displaced == pytest.approx(volume(0.004, 0.009), rel=tolerance)
    nodal = contact.Probe(0.009, tip).surface(mesh.nodes[top], tip_position)
    sampled = (0.03 - nodal[nodal < 0.03]).sum() * area
    assert offset == (0.0011, 0.0052) or abs(sampled / volume(0.004, 0.009) - 1) > 0.1


def test_projected_probe_on_stacked_copies_and_its_reference():
    """Stacked copies ((N, n, 3) positions, (N, 3) tips, an (N, n) reference) give each copy's own
    projected surface, the same as one block; a surface 1 mm lower (a sagging start) is indented
    less: its bounds are lower where the probe reaches above it; bad inputs name what is allowed."""
    from sim_core.geometry.mesh import HexMesh

    mesh = HexMesh.block((6, 2, 6), (0.01, 0.01, 0.01))
    projection = contact.SurfaceProjection.top_face(mesh)
    probe = contact.Probe(0.009, "sphere", projection, curvature_corrected=False)  # the reference's plumbing
    tips = np.array([[0.03, 0.016, 0.03], [0.025, 0.017, 0.031]])
    single = np.stack([probe.surface(mesh.nodes, tip) for tip in tips])
    stacked = probe.surface(np.stack([mesh.nodes, mesh.nodes]), tips)
    np.testing.assert_array_equal(stacked, single)
    lower = contact.Probe(0.009, "sphere", projection.with_reference(np.stack([mesh.nodes[:, 1] - 0.001] * 2)),
                          curvature_corrected=False)
    lowered = lower.surface(np.stack([mesh.nodes, mesh.nodes]), tips)
    centre = np.argmin(np.hypot(mesh.nodes[:, 0] - 0.03, mesh.nodes[:, 2] - 0.03) + 10 * (mesh.nodes[:, 1] < 0.02))
    finite = np.isfinite(lowered)
    assert np.all(np.isfinite(single[finite])) and np.all(lowered[finite] <= single[finite])
    assert lowered[0, centre] < single[0, centre] - 1e-4
    with pytest.raises(ValueError, match="heights"):
        projection.with_reference(np.zeros(3))
    with pytest.raises(ValueError, match="top face"):
        contact.SurfaceProjection.top_face(mesh, [0])
    with pytest.raises(ValueError, match="points"):
        contact.SurfaceProjection.top_face(mesh, points=0)
    with pytest.raises(ValueError, match="projection"):
        contact.Probe(0.009, "sphere", projection="yes")
    with pytest.raises(ValueError, match="probe_sampling"):
        Scene(size=0.03, young_modulus=5e3, poisson_ratio=0.45, tool_low=(0.015, 0.03, 0.015),
              tool_high=(0.015, 0.03, 0.015), tool_radius=0.009, tool_components=(1,), probe="sphere",
              probe_sampling="mortar", displacements=[(0, -0.002, 0)], target=(0.015, 0.015, 0.015))


@pytest.mark.parametrize("tip", ["sphere", "flat"])
def test_projected_surface_kernel_equals_its_definition(tip):
    """The compiled bound (``kernels.projected_probe_surfaces``) equals its definition evaluated with
    numpy, the hat-weighted average of min(probe surface, reference) over each node's support
    (+inf where the probe is above the reference everywhere on it), on perturbed positions and
    random tips (measured: 3e-17 m)."""
    from sim_core.geometry.mesh import HexMesh

    mesh = HexMesh.block((8, 4, 8), (0.0075, 0.0075, 0.0075))
    projection = contact.SurfaceProjection.top_face(mesh)
    probe = contact.Probe(0.009, tip, projection, curvature_corrected=False)  # the kernel's average alone
    rng = np.random.default_rng(1)
    for _ in range(20):
        positions = mesh.nodes + rng.normal(0.0, 5e-4, mesh.nodes.shape)
        tip_position = np.array([rng.uniform(0.01, 0.05), 0.03 - rng.uniform(0.0, 0.008), rng.uniform(0.01, 0.05)])
        heights = probe_height(probe, positions[:, 0, None] + projection.offsets[:, 0],
                               positions[:, 2, None] + projection.offsets[:, 1], tip_position)
        reference = projection.reference[:, None]
        below = heights < reference
        average = (projection.weights * np.where(below, heights, reference)).sum(axis=1)
        expected = np.where((projection.weights * below).sum(axis=1) > 0, average, np.inf)
        np.testing.assert_allclose(probe.surface(positions, tip_position), expected, rtol=0, atol=1e-15)


def test_a_stacked_projection_gives_each_row_its_own_blocks_surface():
    """``SurfaceProjection.stacked`` / ``set_row``: copies on blocks of other spacings (the same
    structured block scaled along its axes: the same weights) in one pass, threaded or not, give
    each row the bound of its own block's projection, bit for bit."""
    from sim_core.geometry.mesh import HexMesh

    spacings = [(0.0075, 0.0075, 0.0075), (0.0068, 0.008, 0.0083), (0.0082, 0.007, 0.0071)]
    meshes = [HexMesh.block((8, 4, 8), spacing) for spacing in spacings]
    singles = [contact.SurfaceProjection.top_face(mesh) for mesh in meshes]
    stacked = singles[0].stacked(len(meshes))
    for index, single in enumerate(singles):
        stacked.set_row(index, single)
    rng = np.random.default_rng(2)
    positions = np.stack([mesh.nodes + rng.normal(0.0, 3e-4, mesh.nodes.shape) for mesh in meshes])
    tips = np.array([[0.031, 0.027, 0.029], [0.02, 0.029, 0.035], [0.04, 0.026, 0.022]])
    for tip in ("sphere", "flat"):
        for parallel in (False, True):
            rows = contact.Probe(0.009, tip, stacked).surface(positions, tips, parallel=parallel)
            for index, single in enumerate(singles):
                expected = contact.Probe(0.009, tip, single).surface(positions[index], tips[index])
                assert np.isfinite(expected).sum() > 4  # the probe is over some nodes
                np.testing.assert_array_equal(rows[index], expected)
    with pytest.raises(ValueError, match="same nodes and quadrature"):
        stacked.set_row(0, contact.SurfaceProjection.top_face(HexMesh.block((6, 4, 6), 0.01)))


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.00375, 0.00375), (0.0011, 0.0052)])
def test_curvature_corrected_projection_gives_each_contact_cell_the_sphere_s_mean_indentation(offset):
    """The hat average of a sphere's indentation is its value at the node minus the hat's second
    moment over 2R, and the bilinear surface through nodes on the sphere lies above it by the
    interpolation bubble (contact.curvature_offsets): with both added back, the bilinear surface
    through the bounds of a 9 mm sphere 4 mm into a 1.5 mm mesh has the sphere's mean height over
    each cell inside Hertz's contact (a^2 = R d: the consistent L2 projection), wherever the nodes
    fall, its nodes (hx^2 + hz^2) / (12 R) = 42 um below the sphere (both within 12 um: the sphere
    is not quite its paraboloid; measured 6 um), where the first-order projection leaves each such
    cell's mean twice that, 83 um, above it."""
    from sim_core.geometry.mesh import HexMesh

    h, radius, depth = 0.0015, 0.009, 0.004
    mesh = HexMesh.block((40, 2, 40), (h, h, h))
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 1], 2 * h))
    projection = contact.SurfaceProjection.top_face(mesh, top)
    tip = np.array([0.03 + offset[0], 2 * h - depth, 0.03 + offset[1]])
    corrected = contact.Probe(radius, "sphere", projection).surface(mesh.nodes, tip)
    first_order = contact.Probe(radius, "sphere", projection, curvature_corrected=False).surface(mesh.nodes, tip)
    sphere = contact.Probe(radius, "sphere")
    # nodes whose support (+-h) lies inside the contact, less the quadrature's spacing; the cells between them
    grid = {tuple(np.round(node[[0, 2]] / h).astype(int)): index for index, node in zip(top, mesh.nodes[top])}
    inner = np.sqrt(radius * depth) - h / 4
    interior = {(i, k) for (i, k) in grid if all(np.hypot((i + a) * h - tip[0], (k + b) * h - tip[2]) < inner
                                                 for a in (-1, 1) for b in (-1, 1))}
    cells = [(i, k) for (i, k) in interior if {(i + 1, k), (i, k + 1), (i + 1, k + 1)} <= interior]
    assert len(cells) >= 1
    t = (np.arange(40) + 0.5) / 40
    u, v = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
    for i, k in cells:
        corners = [grid[i, k], grid[i + 1, k], grid[i, k + 1], grid[i + 1, k + 1]]
        shape = np.stack([(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v])
        points = np.stack([(i + u) * h, np.full_like(u, 2 * h), (k + v) * h], axis=1)
        target = sphere.surface(points, tip).mean()
        assert abs(corrected[corners] @ shape.mean(axis=1) - target) < 1.2e-5
        assert first_order[corners] @ shape.mean(axis=1) - target > 7.5e-5
        np.testing.assert_allclose(corrected[corners], sphere.surface(mesh.nodes[corners], tip) - 2 * h**2 / (12 * radius),
                                   atol=1.2e-5)
    # the rim stays smooth: the correction touches the nodes the projection touches, no others
    assert np.array_equal(np.isfinite(corrected), np.isfinite(first_order))


def test_axisymmetric_reference_reads_hertz_on_a_wide_bonded_layer():
    """The independent reference (scikit-fem, benchmarks.indentation_reference.axisymmetric_forces) on a
    cylinder 50 cm wide, 3 cm thick, its base bonded, E 5 kPa, nu 0.45: a 9 mm sphere 0.5 and 1 mm deep
    against Hertz on a layer bonded to a rigid base (Dimitriadis et al. 2002, chi = sqrt(R d) / t of
    0.07-0.1, where their series holds): measured -0.6 / -1.0%; 25% above Hertz on a half-space."""
    from benchmarks.indentation_reference import axisymmetric_forces, bonded_layer_factor, hertz

    depths = np.array([0.0005, 0.001])
    forces = axisymmetric_forces(depths, 0.009, 0.03, 0.5, 5e3, 0.45)
    layer = hertz(depths, 0.009, 5e3, 0.45) * bonded_layer_factor(depths, 0.009, 0.03, 0.45)
    np.testing.assert_allclose(forces, layer, rtol=0.015)
    assert np.all(forces > 1.05 * hertz(depths, 0.009, 5e3, 0.45))


@pytest.mark.parametrize("position", ["node", "edge", "cell_centre"])
@pytest.mark.parametrize("poisson_ratio, young_modulus", [(0.45, 5e3), (0.49, 40e3)])
def test_indentation_at_palpation_resolution_against_the_axisymmetric_reference(position, poisson_ratio,
                                                                                young_modulus):
    """Palpation's slab (6 x 3 x 6 cm, bottom attached, no gravity) on its 6 mm cubes, its 9 mm sphere
    pressed 2 to 8 mm over a node, over a cell's side and over a cell's centre (static, active set
    converged), against the independent axisymmetric reference on the cylinder of the slab's top area:
    within 11% at 2 mm, where the contact (4.2 mm across its radius) is smaller than a cell, 9% at 3 and
    5 mm (the cell centre's low side) and 8% at 4 and 8 mm (benchmarks/indentation_reference.py: +3.6 to
    +10.4% at 2 mm; the cell centre at nu 0.49 -8.2 / -7.5 / -8.5% at 3 / 4 / 5 mm, the worst deeper; the
    first-order projection read 25-42% under at 2-8 mm, the nodes on the sphere alone 6-19%)."""
    from benchmarks.indentation_reference import CYLINDERS, POSITIONS, axisymmetric_forces
    from sim_core.studies.scenes import Scene
    from sim_core.studies.solving import solve_scene

    depths, cell = np.array([0.002, 0.003, 0.004, 0.005, 0.008]), 0.006
    x, z = (0.03 + cell * offset for offset in POSITIONS[position])
    scene = Scene(size=(0.06, 0.03, 0.06), young_modulus=young_modulus, poisson_ratio=poisson_ratio, gravity=0.0,
                  tool_low=(x, 0.03, z), tool_high=(x, 0.03, z), tool_radius=0.009, tool_components=(1,),
                  probe="sphere", displacements=[[(0, -d, 0) for d in depths]], target=(0.03, 0.015, 0.03))
    solution = solve_scene(scene, (10, 5, 10), model="baudet-hyperelastic", check_stability=False)
    assert solution.converged.all()
    error = -solution.force[:, 1] / axisymmetric_forces(depths, 0.009, 0.03, CYLINDERS["equal_area"], young_modulus,
                                                        poisson_ratio) - 1.0
    assert np.all(np.abs(error) < [0.11, 0.09, 0.08, 0.09, 0.08]), error
