"""Scenes: a tool task on a block of tissue, described the way an environment sets it up, and its
discretisation on a mesh of a given resolution.

A ``Scene`` holds the block (size in m, material, optionally a stiffer box-shaped inclusion), the
face attached to the body, gravity, an optional rigid floor y >= 0 (frictionless unilateral
contact), the tool (the surface nodes inside a box, optionally a vertical cylinder, and which
components it imposes), the tool displacements to test (paths solved by continuation) and a target
point inside the block.

Resolution ``n`` means elements no larger than ``h = max(size) / n`` along any axis:
``shape_i = max(min_shape_i, ceil(size_i / h))`` (so n = 4 on a cube is 4x4x4, on a 6 x 3 x 6 cm
slab n = 5 is 5x3x5). SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..solvers import contact as contact_
from ..models.material import Material
from ..geometry.mesh import LOCAL_CORNERS, HexMesh
from .checks import check_scalar, check_shape, check_vector

FACES = ("x-", "x+", "y-", "y+", "z-", "z+")


@dataclass(frozen=True, eq=False)
class Scene:
    """A tool task on a block of tissue (SI units).

    Attributes:
        size: (Lx, Ly, Lz) block extent in m (a float gives a cube); the block is
            [0, Lx] x [0, Ly] x [0, Lz], y up.
        young_modulus, poisson_ratio, density: the tissue (Pa, -, kg/m^3).
        fixed_face: the face attached to the body (all components fixed): "x-", "x+", "y-", "y+",
            "z-" or "z+" ("y-" is the bottom y = 0).
        tool_low, tool_high: (3,) corners of the box (m) that selects the tool's nodes among the
            block's surface nodes at rest (a degenerate box selects a face or a line of nodes).
        tool_radius: None, or a radius (m): the tool is then the vertical cylinder of this radius
            around the box centre (x and z bounded by the radius, y by the box): a round probe.
        tool_components: the components the tool imposes: (0, 1, 2) glued, (1,) a frictionless probe.
        probe: None (the tool's nodes are imposed throughout, as ``tool_components`` says), or a
            contact probe of radius ``tool_radius`` pressed from above (``sim_core.solvers.contact.Probe``):
            "sphere" (hemispherical end) or "flat" (flat-ended cylinder), its lowest point at the
            top centre of the tool box plus the displacement; the tool box's surface nodes, at any
            x and z, are the contact candidates (frictionless active set, only u_y imposed).
        probe_sampling: "projected" (default: the probe's indentation of the start surface projected
            on the top nodes' basis functions, ``sim_core.solvers.contact.SurfaceProjection``; the tool box
            must then lie on the top face) or "node" (the probe sampled at the nodes).
        displacements: tool displacements from rest (m): an (K, 3) array of independent cases, or a
            sequence of paths (each an (K_p, 3) array) solved in order by continuation, each path
            starting from the equilibrium under gravity with the tool at rest.
        target: (3,) a material point inside the block (m, rest coordinates).
        gravity: m/s^2 along -y.
        floor: a rigid frictionless floor at y = 0 (unilateral contact on every free node).
        inclusion_low, inclusion_high, inclusion_ratio: an optional box (m) of tissue
            ``inclusion_ratio`` times stiffer; each element gets E (1 + (ratio - 1) f), f the share
            of its volume inside the box.
        min_shape: the smallest number of elements per axis.
        name: a label.
    """

    size: tuple
    young_modulus: float
    poisson_ratio: float
    tool_low: tuple
    tool_high: tuple
    displacements: object
    target: tuple
    density: float = 1060.0
    fixed_face: str = "y-"
    tool_radius: float | None = None
    tool_components: tuple = (0, 1, 2)
    probe: str | None = None
    probe_sampling: str = "projected"
    gravity: float = 9.81
    floor: bool = False
    inclusion_low: tuple | None = None
    inclusion_high: tuple | None = None
    inclusion_ratio: float = 1.0
    min_shape: tuple = (1, 1, 1)
    name: str = "scene"

    def __post_init__(self):
        size = check_vector("size", self.size, positive=True)
        set_ = lambda key, value: object.__setattr__(self, key, value)  # noqa: E731 (frozen dataclass)
        set_("size", size)
        set_("young_modulus", check_scalar("young_modulus", self.young_modulus, low=0.0))
        nu = check_scalar("poisson_ratio", self.poisson_ratio)
        if not -0.25 < nu < 0.5:
            raise ValueError(f"poisson_ratio must lie in (-0.25, 0.5), got {self.poisson_ratio!r}")
        set_("poisson_ratio", nu)
        set_("density", check_scalar("density", self.density, low=0.0))
        if self.fixed_face not in FACES:
            raise ValueError(f"fixed_face must be one of {FACES}, got {self.fixed_face!r}")
        low, high = check_vector("tool_low", self.tool_low), check_vector("tool_high", self.tool_high)
        if np.any(low > high):
            raise ValueError(f"tool_low must be <= tool_high on every axis, got {low.tolist()} and {high.tolist()}")
        set_("tool_low", low)
        set_("tool_high", high)
        if self.tool_radius is not None:
            set_("tool_radius", check_scalar("tool_radius", self.tool_radius, low=0.0))
        components = tuple(sorted({int(c) for c in np.atleast_1d(self.tool_components)}))
        if not components or any(c not in (0, 1, 2) for c in components):
            raise ValueError(f"tool_components must be a non-empty subset of (0, 1, 2), got {self.tool_components!r}")
        set_("tool_components", components)
        set_("displacements", _paths(self.displacements))
        target = check_vector("target", self.target)
        if np.any(target < 0) or np.any(target > size):
            raise ValueError(f"target must lie inside the block [0, size], got {target.tolist()}")
        set_("target", target)
        set_("gravity", check_scalar("gravity", self.gravity, low=0.0, strict=False))
        set_("floor", bool(self.floor))
        if self.probe is not None:
            if self.probe not in contact_.TIPS:
                raise ValueError(f"probe must be None or one of {contact_.TIPS}, got {self.probe!r}")
            if self.tool_radius is None:
                raise ValueError("a probe needs tool_radius (m), its radius")
            if self.floor:
                raise ValueError("a scene has one contact obstacle: a probe or a floor, not both")
        if self.probe_sampling not in contact_.SAMPLINGS:
            raise ValueError(f"probe_sampling must be one of {contact_.SAMPLINGS}, got {self.probe_sampling!r}")
        if (self.inclusion_low is None) != (self.inclusion_high is None):
            raise ValueError("inclusion_low and inclusion_high must be given together")
        if self.inclusion_low is not None:
            set_("inclusion_low", check_vector("inclusion_low", self.inclusion_low))
            set_("inclusion_high", check_vector("inclusion_high", self.inclusion_high))
        set_("inclusion_ratio", check_scalar("inclusion_ratio", self.inclusion_ratio, low=0.0))
        set_("min_shape", check_shape("min_shape", self.min_shape))

    # -- contact ----------------------------------------------------------------------------
    def obstacle(self, mesh=None, candidates=None):
        """The scene's contact obstacle (``sim_core.solvers.contact``): the floor, the probe, or None. A
        probe with ``probe_sampling="projected"`` is projected on the top face of ``mesh`` at its
        ``candidates`` (n,) bool, its indentation measured from the rest heights (``from_surface``
        measures it from another surface)."""
        if self.floor:
            return contact_.Floor()
        if self.probe is None:
            return None
        if self.probe_sampling == "node":
            return contact_.Probe(self.tool_radius, self.probe)
        if mesh is None:
            raise ValueError("a projected probe needs the scene's mesh and contact candidates")
        return contact_.Probe(self.tool_radius, self.probe,
                              contact_.SurfaceProjection.top_face(mesh, np.flatnonzero(candidates)))

    def probe_tip(self, displacement):
        """(3,) the probe's lowest point (m) at a tool displacement (m); None without a probe."""
        if self.probe is None:
            return None
        centre = 0.5 * (self.tool_low + self.tool_high)
        return np.array([centre[0], self.tool_high[1], centre[2]]) + np.asarray(displacement, dtype=float)

    # -- discretisation ----------------------------------------------------------------------
    def shape(self, resolution: int) -> tuple:
        """Elements per axis at ``resolution`` n: no element longer than max(size) / n."""
        h = float(self.size.max()) / int(resolution)
        return tuple(max(m, math.ceil(length / h - 1e-9)) for m, length in zip(self.min_shape, self.size))

    def discretise(self, shape):
        """(mesh, material, fixed nodes, tool nodes (a probe's: its contact candidates), target
        element, target weights) for ``shape``."""
        shape = tuple(int(s) for s in shape)
        spacing = self.size / np.asarray(shape)
        mesh = HexMesh.block(shape, spacing)
        nodes = mesh.nodes
        tol = 1e-6 * float(spacing.min())
        axis, end = "xyz".index(self.fixed_face[0]), self.fixed_face[1] == "+"
        fixed = np.flatnonzero(np.abs(nodes[:, axis] - (self.size[axis] if end else 0.0)) <= tol)
        surface = mesh.surface_nodes()
        low, high = self.tool_low.copy(), self.tool_high.copy()
        if self.tool_radius is not None:  # the cylinder bounds x and z (a probe's contact: nothing)
            low[[0, 2]], high[[0, 2]] = -np.inf, np.inf
        inside = np.all((nodes[surface] >= low - tol) & (nodes[surface] <= high + tol), axis=1)
        if self.tool_radius is not None and self.probe is None:
            centre = 0.5 * (self.tool_low + self.tool_high)
            inside &= np.hypot(*(nodes[surface][:, [0, 2]] - centre[[0, 2]]).T) <= self.tool_radius + tol
        tool = np.setdiff1d(surface[inside], fixed)
        if len(tool) == 0:
            raise ValueError(f"the tool selects no surface node of the {shape} mesh of scene {self.name!r}")
        young = np.full(mesh.n_elements, self.young_modulus)
        if self.inclusion_low is not None:
            share = mesh.box_shares(self.inclusion_low, self.inclusion_high)
            young = young * (1.0 + (self.inclusion_ratio - 1.0) * share)
        material = Material(young, self.poisson_ratio, self.density)
        cell = np.minimum((self.target // spacing).astype(int), np.asarray(shape) - 1)
        element = int(cell[0] + shape[0] * (cell[1] + shape[1] * cell[2]))
        local = self.target / spacing - cell
        weights = np.prod(LOCAL_CORNERS * local + (1.0 - LOCAL_CORNERS) * (1.0 - local), axis=1)
        return mesh, material, fixed, tool, mesh.elements[element], weights


def _paths(value):
    """Tool displacements as a tuple of (K_p, 3) float arrays (paths)."""
    try:
        if isinstance(value, np.ndarray) or (len(value) and np.ndim(value[0]) == 1):
            array = np.asarray(value, dtype=float)
            if array.ndim != 2 or array.shape[1] != 3:
                raise ValueError
            paths = tuple(array[i:i + 1] for i in range(len(array)))
        else:
            paths = tuple(np.asarray(p, dtype=float).reshape(-1, 3) for p in value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"displacements must be a (K, 3) array or a sequence of (K_p, 3) paths in m, got {value!r}") from error
    if not paths or any(len(p) == 0 or not np.all(np.isfinite(p)) for p in paths):
        raise ValueError("displacements must hold at least one finite (3,) displacement per path")
    if not any(np.any(p != 0) for p in paths):
        raise ValueError("displacements must contain a non-zero displacement")
    return paths


def check_scenes(scene, name="scene") -> list:
    """A Scene or a non-empty list/tuple of Scenes as a list, else ValueError naming ``name``."""
    scenes = [scene] if isinstance(scene, Scene) else list(scene) if isinstance(scene, (list, tuple)) else None
    if not scenes or not all(isinstance(s, Scene) for s in scenes):
        raise ValueError(f"{name} must be a Scene or a non-empty list of Scenes, got {scene!r}")
    return scenes
