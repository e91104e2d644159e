"""Camera observations of the deformed tissue: a z-buffer rasteriser of its surface triangles.

What a camera sees is the block's boundary surface (``HexMesh.surface_faces``: each quad split into
two triangles, ``surface_triangles``) at the current node positions, with the rigid geometry of a
task's scene (Retraction's floor and its target strip, Palpation's probe) and the tool's grasp
shaded in the tool's colour. Nothing hidden is ever drawn: not the tumour, not the inclusion (the
debug frames of ``render_mode="rgb_array"``, ``tissue_env.rendering``, mark them).

Why a numba z-buffer rather than a GL library: pyrender and moderngl render through an OpenGL
context (a display, EGL or OSMesa), which headless training machines, containers and CI runners
often lack, and each env process would need its own. The scenes are small (a few hundred triangles
at 64-128 px), so one compiled loop over triangles with a depth test renders a frame in tens of
microseconds, below the cost of a physics step (``benchmarks/visual_speed.py``), with no GPU, no
context, and the same floats on every machine: a copy of a vector env gives the single env's
images bit for bit.

Conventions (SI units):
    - ``Camera``: a pinhole camera at ``position`` (m) looking at ``target`` (m), ``up`` its
      approximate upward direction, ``fov_deg`` the vertical field of view, ``width`` x ``height``
      pixels, ``near`` / ``far`` the clipping distances (m). Camera frame: x right, y up, z forward.
      Pixel (row i, column j) covers [j, j + 1) x [i, i + 1) of the image plane, its centre at
      (j + 0.5, i + 0.5); rows go downward.
    - Depth is the metric distance along the optical axis (the camera-frame z, what a depth
      camera and MuJoCo's linearised ``depth_array`` report), not the distance along the ray. A
      pixel that sees nothing has depth ``far``. A triangle with a vertex nearer than ``near`` is
      not drawn (no clipping: the task cameras keep the scene well inside); points beyond ``far``
      are not drawn.
    - Colour: Lambert shading of each triangle's albedo by a fixed directional light
      (``LIGHT_DIRECTION``, towards the light, with ``AMBIENT`` light), flat per triangle and
      two-sided (the normal turned towards the camera); background ``BACKGROUND``.
    - Point cloud: ``SurfaceSampler`` places K material points on the surface triangles once,
      deterministically (no random generator: triangles by stratified inverse-CDF sampling of
      their rest areas, barycentric coordinates from the R2 low-discrepancy sequence), so the
      observation has a fixed shape (K, 3), or (K, 6) with the unit outward normals, and each
      point follows the same piece of tissue. It covers the whole surface, as a registered surface
      model would, not only the part the camera sees.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from sim_core.kernels.raster import rasterise_triangles as _rasterise

#: The observation types a camera gives (``TissueEnv``'s ``observation_type``).
VISUAL_TYPES = ("rgb", "depth", "rgbd", "point_cloud")
#: RGB of pixels that see nothing.
BACKGROUND = (0, 0, 0)
#: Direction towards the fixed directional light (world frame, normalised where used): from above,
#: in front (+z) and to the right (+x) of the scenes.
LIGHT_DIRECTION = (0.3, 1.0, 0.6)
#: Share of the albedo lit whatever the normal (a face turned away from the light is not black).
AMBIENT = 0.3
#: Albedos (RGB in [0, 1]) of the scene's materials.
ALBEDO = dict(tissue=(0.85, 0.50, 0.45), tool=(0.25, 0.30, 0.40), floor=(0.70, 0.70, 0.70),
              target=(0.20, 0.65, 0.30), probe=(0.60, 0.62, 0.68))


def _vector(name, value):
    try:
        array = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError) as error:
        raise ValueError(f"camera {name} must be three numbers (m), got {value!r}") from error
    if not np.all(np.isfinite(array)):
        raise ValueError(f"camera {name} must be finite, got {value!r}")
    return tuple(float(v) for v in array)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera (see the module docstring for its conventions). Bad values raise ValueError."""

    position: tuple = (0.0, 0.0, 1.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: float = 45.0
    width: int = 64
    height: int = 64
    near: float = 0.01
    far: float = 1.0
    _frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        position, target, up = (_vector(name, getattr(self, name)) for name in ("position", "target", "up"))
        forward = np.subtract(target, position)
        if np.linalg.norm(forward) == 0:
            raise ValueError(f"camera position and target must differ, both are {position}")
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, up)
        if np.linalg.norm(right) < 1e-9 * np.linalg.norm(up):
            raise ValueError(f"camera up {up} must not be parallel to the viewing direction {tuple(forward)}")
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        try:
            fov = float(self.fov_deg)
            near, far = float(self.near), float(self.far)
        except (TypeError, ValueError) as error:
            raise ValueError(f"camera fov_deg, near and far must be numbers, got {self.fov_deg!r}, {self.near!r}, "
                             f"{self.far!r}") from error
        if not 0.0 < fov < 180.0:
            raise ValueError(f"camera fov_deg must lie in (0, 180) degrees, got {self.fov_deg!r}")
        if not (np.isfinite(near) and np.isfinite(far) and 0.0 < near < far):
            raise ValueError(f"camera near and far must be finite with 0 < near < far (m), got {self.near!r}, "
                             f"{self.far!r}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not float(value).is_integer() or int(value) < 1:
                raise ValueError(f"camera {name} must be an integer >= 1 (pixels), got {value!r}")
        for name, value in (("position", position), ("target", target), ("up", up), ("fov_deg", fov),
                            ("near", near), ("far", far), ("width", int(self.width)), ("height", int(self.height))):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_frame", (np.stack([right, true_up, forward]), np.array(position)))

    def with_size(self, width, height) -> "Camera":
        """The same camera with another image size (pixels)."""
        return replace(self, width=width, height=height)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rows: the camera's right, up and forward unit vectors in the world frame."""
        return self._frame[0].copy()

    @property
    def focal(self) -> float:
        """Focal length in pixels (square pixels): the image's half height over tan(fov / 2)."""
        return 0.5 * self.height / np.tan(np.radians(0.5 * self.fov_deg))

    def to_camera(self, points) -> np.ndarray:
        """Points (..., 3) m in the camera frame (x right, y up, z forward = depth)."""
        rotation, position = self._frame
        return (np.asarray(points, dtype=float) - position) @ rotation.T

    def project(self, points):
        """(u, v, depth) of points (..., 3) m: the image-plane coordinates (pixels, column u and
        row v, continuous) and the depth along the optical axis (m)."""
        local = self.to_camera(points)
        depth = local[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = 0.5 * self.width + self.focal * local[..., 0] / depth
            v = 0.5 * self.height - self.focal * local[..., 1] / depth
        return u, v, depth

    def pixel_rays(self) -> np.ndarray:
        """(height, width, 3) world directions through the pixel centres, scaled so that their
        component along the optical axis is 1: the point a pixel sees at depth z is
        ``position + z * ray``."""
        columns = (np.arange(self.width) + 0.5 - 0.5 * self.width) / self.focal
        rows = (0.5 * self.height - (np.arange(self.height) + 0.5)) / self.focal
        local = np.stack(np.broadcast_arrays(columns[None, :], rows[:, None], np.ones((1, 1))), axis=-1)
        return local @ self._frame[0]


def surface_triangles(faces) -> np.ndarray:
    """(2 F, 3) triangles of the quads ``faces`` (F, 4) (outward oriented, as
    ``HexMesh.surface_faces`` gives them): quad (a, b, c, d) -> (a, b, c), (a, c, d), which keep
    its orientation (the right-hand normal of each triangle points out). Triangle 2 f and 2 f + 1
    are quad f's. Triangles (F, 3) (``TetMesh.surface_faces``) are returned as they are."""
    faces = np.asarray(faces)
    if faces.shape[1] == 3:
        return faces.astype(np.int64)
    return np.stack([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]], axis=1).reshape(-1, 3).astype(np.int64)


def triangle_normals(vertices, triangles) -> np.ndarray:
    """(..., T, 3) unit right-hand normals of ``triangles`` (T, 3) at ``vertices`` (..., V, 3); zero for
    a degenerate triangle."""
    a, b, c = (vertices[..., triangles[:, k], :] for k in range(3))
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)


def lambert(vertices, triangles, albedo, camera: Camera, light=LIGHT_DIRECTION, ambient=AMBIENT) -> np.ndarray:
    """(..., T, 3) uint8 colours of ``triangles`` (T, 3) at ``vertices`` (..., V, 3): albedo (T, 3)
    in [0, 1] times ambient + (1 - ambient) max(0, n . l), n the normal turned towards the camera,
    l the unit direction towards the light."""
    normal = triangle_normals(vertices, triangles)
    centroid = vertices[..., triangles, :].mean(axis=-2)
    facing = np.sum(normal * (np.asarray(camera.position) - centroid), axis=-1, keepdims=True)
    normal = np.where(facing < 0, -normal, normal)
    light = np.asarray(light, dtype=float)
    light = light / np.linalg.norm(light)
    intensity = ambient + (1.0 - ambient) * np.maximum(normal @ light, 0.0)
    return np.rint(255.0 * np.clip(np.asarray(albedo) * intensity[..., None], 0.0, 1.0)).astype(np.uint8)


def rasterise(camera: Camera, vertices, triangles, colours, background=BACKGROUND):
    """Draw ``triangles`` (T, 3) at ``vertices`` (N, V, 3) m (or (V, 3): one world) with ``colours``
    (T, 3) or (N, T, 3) uint8. Returns (rgb (N, H, W, 3) uint8, depth (N, H, W) float64 m along the
    optical axis, ``camera.far`` where nothing is seen); without the world axis for (V, 3) vertices."""
    vertices = np.asarray(vertices, dtype=float)
    single = vertices.ndim == 2
    if single:
        vertices = vertices[None]
    count = len(vertices)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    colours = np.ascontiguousarray(np.broadcast_to(np.asarray(colours, dtype=np.uint8),
                                                   (count, len(triangles), 3)))
    u, v, depth_of = camera.project(vertices)
    with np.errstate(divide="ignore"):
        inverse = np.where(depth_of > 0, 1.0 / depth_of, -1.0)
    depth = np.empty((count, camera.height, camera.width))
    image = np.empty((count, camera.height, camera.width, 3), dtype=np.uint8)
    _rasterise(np.ascontiguousarray(u), np.ascontiguousarray(v), np.ascontiguousarray(inverse), triangles, colours,
               camera.near, camera.far, np.asarray(background, dtype=np.uint8), depth, image)
    return (image[0], depth[0]) if single else (image, depth)


class SurfaceSampler:
    """K material points on triangles (T, 3) of a surface, placed once (see the module docstring):
    triangle index k of quantile (k + 0.5) / K of the rest areas' cumulative distribution, and
    barycentric coordinates of the R2 sequence's k-th point (folded into the triangle). Its
    ``sample(vertices)`` gives the points (and normals) at deformed vertices."""

    def __init__(self, triangles, rest_vertices, count: int):
        triangles = np.asarray(triangles, dtype=np.int64)
        rest = np.asarray(rest_vertices, dtype=float)
        a, b, c = (rest[triangles[:, k]] for k in range(3))
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        cumulative = np.cumsum(area) / area.sum()
        quantiles = (np.arange(count) + 0.5) / count
        self.triangle = np.minimum(np.searchsorted(cumulative, quantiles), len(triangles) - 1)
        golden = 1.32471795724474602596  # the plastic number: the R2 sequence's generator
        r = np.outer(np.arange(1, count + 1), [1.0 / golden, 1.0 / golden**2]) % 1.0
        fold = r.sum(axis=1) > 1.0
        r[fold] = 1.0 - r[fold]
        self.weights = np.column_stack([1.0 - r.sum(axis=1), r])  # (K, 3) barycentric
        self.triangles = triangles

    def sample(self, vertices, normals: bool = False) -> np.ndarray:
        """(N, K, 3) points, m, at ``vertices`` (N, V, 3); (N, K, 6) with the unit outward normals
        of their triangles after them when ``normals``."""
        corners = vertices[:, self.triangles[self.triangle]]  # (N, K, 3, 3)
        points = np.einsum("kc,nkcd->nkd", self.weights, corners)
        if not normals:
            return points
        return np.concatenate([points, triangle_normals(vertices, self.triangles[self.triangle])], axis=-1)


# -- rigid scene geometry ---------------------------------------------------------------------------
def floor_tiles(x_breaks, z_breaks, height=0.0):
    """(vertices (..., X Z, 3), triangles (2 (X - 1) (Z - 1), 3)) of a horizontal grid of quads at
    ``height`` (m) with corner coordinates ``x_breaks`` (..., X) and ``z_breaks`` (Z,) or (..., Z) m, facing up;
    tile (p, q) (x between breaks p and p + 1, z between q and q + 1) is triangles 2 (p (Z - 1) + q) and
    the next."""
    x_breaks = np.asarray(x_breaks, dtype=float)
    z_breaks = np.asarray(z_breaks, dtype=float)
    nx, nz = x_breaks.shape[-1], z_breaks.shape[-1]
    x = np.repeat(x_breaks[..., :, None], nz, axis=-1)
    z = np.broadcast_to(z_breaks[..., None, :], x.shape)
    vertices = np.stack([x, np.full(x.shape, float(height)), z], axis=-1).reshape(x_breaks.shape[:-1] + (nx * nz, 3))
    p, q = np.meshgrid(np.arange(nx - 1), np.arange(nz - 1), indexing="ij")
    corner = (p * nz + q).ravel()
    quads = np.stack([corner, corner + 1, corner + nz + 1, corner + nz], axis=1)  # counter-clockwise from above
    return vertices, surface_triangles(quads)


def probe_mesh(radius, tip="sphere", shaft_length=0.03, segments=12, rings=4):
    """(vertices (V, 3), triangles (T, 3)) of a vertical probe whose lowest point is at the origin
    (m): a hemispherical end of ``radius`` (``tip="sphere"``) or a flat end (``"flat"``) under a
    cylindrical shaft of the same radius, ``shaft_length`` m above the end."""
    angle = 2.0 * np.pi * np.arange(segments) / segments
    circle = np.stack([np.cos(angle), np.zeros(segments), np.sin(angle)], axis=1) * radius
    if tip == "sphere":
        polar = np.linspace(0.0, 0.5 * np.pi, rings + 1)[1:]  # from the bottom pole up to the equator
        levels = [circle * np.sin(p) + [0.0, radius * (1.0 - np.cos(p)), 0.0] for p in polar]
        top = radius
    else:
        levels = [circle.copy()]
        top = 0.0
    levels.append(circle + [0.0, top + shaft_length, 0.0])
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], *levels, [[0.0, top + shaft_length, 0.0]]])
    triangles = []
    ring = lambda r: 1 + r * segments + np.arange(segments)  # noqa: E731
    nxt = lambda r: 1 + r * segments + (np.arange(segments) + 1) % segments  # noqa: E731
    triangles.append(np.stack([np.zeros(segments, int), nxt(0), ring(0)], axis=1))  # the end (fan from the tip)
    for r in range(len(levels) - 1):
        triangles.append(np.stack([ring(r), nxt(r), nxt(r + 1)], axis=1))
        triangles.append(np.stack([ring(r), nxt(r + 1), ring(r + 1)], axis=1))
    last = len(levels) - 1
    triangles.append(np.stack([np.full(segments, len(vertices) - 1), ring(last), nxt(last)], axis=1))
    return vertices, np.concatenate(triangles).astype(np.int64)


# -- an env's camera view ---------------------------------------------------------------------------
class CameraView:
    """What an env's camera observes (``TissueEnv``'s visual ``observation_type``): the surface
    triangles of its mesh, the tool's faces in the tool's colour, and a task's rigid geometry
    passed per call.

    Args:
        camera: the ``Camera``.
        faces: (F, 4) the mesh's outward surface quads (``HexMesh.surface_faces``), or (F, 3)
            triangles (``TetMesh.surface_faces``).
        rest_positions: (n, 3) m, the mesh's nodes (the point cloud's sampling).
        tool_nodes: nodes the tool holds: a face all of whose nodes it holds has the tool's albedo.
        point_count: K points of the "point_cloud" observation; point_normals: append normals.
        bounds: (low (3,), high (3,)) m, the point cloud's world box (points outside are clipped
            to it and reported).
    """

    def __init__(self, camera: Camera, faces, rest_positions, tool_nodes, point_count=512, point_normals=False,
                 bounds=None):
        self.camera = camera
        self.triangles = surface_triangles(faces)
        held = np.zeros(len(rest_positions), dtype=bool)
        held[np.asarray(tool_nodes, dtype=int)] = True
        faces = np.asarray(faces)  # each quad is two triangles (surface_triangles), a triangle one
        tool_face = np.repeat(held[faces].all(axis=1), 2 if faces.shape[1] == 4 else 1)
        self.albedo = np.where(tool_face[:, None], ALBEDO["tool"], ALBEDO["tissue"])
        self.n_nodes = len(rest_positions)
        self.point_count, self.point_normals = int(point_count), bool(point_normals)
        self.sampler = SurfaceSampler(self.triangles, rest_positions, self.point_count)
        self.bounds = bounds

    def images(self, positions, extras=None):
        """(rgb (N, H, W, 3) uint8, depth (N, H, W) float64 m) of the tissue at ``positions`` (N, n, 3)
        m with ``extras``: None or (vertices (N, V, 3) m, triangles (T, 3), albedo (T, 3))."""
        vertices, triangles, albedo = positions, self.triangles, self.albedo
        if extras is not None:
            extra_vertices, extra_triangles, extra_albedo = extras
            vertices = np.concatenate([positions, extra_vertices], axis=1)
            triangles = np.concatenate([triangles, np.asarray(extra_triangles) + self.n_nodes])
            albedo = np.concatenate([albedo, np.broadcast_to(extra_albedo, (len(extra_triangles), 3))])
        colours = lambert(vertices, triangles, albedo, self.camera)
        return rasterise(self.camera, vertices, triangles, colours)

    def space(self, kind):
        """The single env's observation space of ``kind`` (one of VISUAL_TYPES)."""
        from gymnasium import spaces

        camera = self.camera
        shape = (camera.height, camera.width)
        if kind == "rgb":
            return spaces.Box(0, 255, shape + (3,), dtype=np.uint8)
        if kind == "depth":
            return spaces.Box(np.float32(camera.near), np.float32(camera.far), shape + (1,), dtype=np.float32)
        if kind == "rgbd":
            low = np.broadcast_to(np.array([0, 0, 0, camera.near], dtype=np.float32), shape + (4,))
            high = np.broadcast_to(np.array([1, 1, 1, camera.far], dtype=np.float32), shape + (4,))
            return spaces.Box(low.copy(), high.copy(), dtype=np.float32)
        low, high = (np.asarray(b, dtype=np.float32) for b in self.bounds)
        if self.point_normals:
            low, high = np.concatenate([low, -np.ones(3, np.float32)]), np.concatenate([high, np.ones(3, np.float32)])
        size = len(low)
        return spaces.Box(np.broadcast_to(low, (self.point_count, size)).copy(),
                          np.broadcast_to(high, (self.point_count, size)).copy(), dtype=np.float32)

    def observe(self, kind, positions, extras=None):
        """(observations (N, ...) of ``kind``, clipped (N,) bool: a point-cloud point outside the
        bounds, clipped to them) at ``positions`` (N, n, 3) m."""
        count = len(positions)
        clipped = np.zeros(count, dtype=bool)
        if kind == "point_cloud":
            points = self.sampler.sample(positions, self.point_normals)
            low, high = (np.asarray(b, dtype=float) for b in self.bounds)
            xyz = points[..., :3]
            clipped = ~np.all((xyz >= low) & (xyz <= high), axis=(1, 2))
            points[..., :3] = np.clip(np.nan_to_num(xyz, nan=0.0), low, high)
            return points.astype(np.float32), clipped
        rgb, depth = self.images(positions, extras)
        if kind == "rgb":
            return rgb, clipped
        depth = depth.astype(np.float32)[..., None]
        if kind == "depth":
            return depth, clipped
        return np.concatenate([rgb.astype(np.float32) / np.float32(255.0), depth], axis=-1), clipped
