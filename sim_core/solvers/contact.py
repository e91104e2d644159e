"""Frictionless unilateral contact with rigid height-field obstacles, by an active set.

An obstacle bounds the height y of the block's nodes by a surface over the horizontal plane:
the floor ``y >= 0`` (``Floor``) or a probe pressed from above, ``y <= h(x, z)`` (``Probe``:
a sphere-ended probe, whose lower surface is h = y_tip + R - sqrt(R^2 - r^2) within its radius R
of the axis, r the horizontal distance to it; or a flat-ended cylinder, h = y_tip). A node in
contact has its height imposed on the surface at its current (x, z), its x and z stay free: the
contact force is along y and no shear is transmitted. For the floor that is exact frictionless
contact; for the sphere it is Hertz's boundary condition (normal displacement prescribed, zero
shear traction on the contact area), whose small-slope approximation it shares.

The active set is updated as in a static contact solve (and ``sim_core.studies.solving``'s scenes,
``tissue_env``'s Palpation and Retraction use the same functions):

- ``release``: a node the obstacle would have to pull (the net force on it, tissue plus loads,
  points away from the obstacle) leaves the set;
- ``touching``: a node on or through the surface (within ``tolerance``) is in the set (``update``
  forms a step's set from the last one: kept unless released, joined when touched);
- ``project``: after a step, a free node that went through the surface is put back on it, its
  velocity into the obstacle removed, and it joins the set.

Where a probe is sampled: at the nodes (``Probe(radius, tip)``: a node's height is bounded by the
probe's surface over the node itself) or, with a ``SurfaceProjection`` (``Probe(radius, tip,
projection)``), by the probe's indentation of the rest surface projected on the nodes' bilinear
basis functions: a node's bound is the average, weighted by its hat function over the faces
around it, of min(probe surface, the node's rest height). Sampled at the nodes, a coarse mesh
feels a probe pressed over a node on that node alone and one pressed between nodes on four of
them: at a 7.5 mm spacing (Palpation's earlier (8, 4, 8)) a 9 mm sphere 4 mm deep displaces
0.58x its volume over a node and 1.33x between four (tests/test_contact.py), and held presses
read a homogeneous slab 1.47 max/min over one node period. Projected, it displaces its own
volume within 1.3% wherever the nodes fall, held presses read the slab within 1.05
at Palpation's default (10, 5, 10) (benchmarks/palpation_map.py), and Palpation's fine
model converges to 5.7 / 9.9 / 7.6% (force / target / volume, 10 against 12 elements across;
benchmarks/env_accuracy.py). This is a lumped L2 (mortar-like) projection of the indentation: it
bounds each node by the weighted indentation over its support instead of pointwise.

That average takes the sphere's curvature off: the hat average of the paraboloid d - r^2 / (2R) is
its value at the node less the hat's second moment over 2R, (hx^2 + hz^2) / (12 R), so the
first-order projection imposes the sphere as if it were that much shallower (0.67 mm at Palpation's
6 mm cells with the 9 mm sphere: a 2 mm press imposed as 1.33 mm, its force 41% under a converged
reference). A projected sphere adds it back over the quadrature points it covers (``Probe``'s
``curvature_corrected``, default; ``curvature_offsets``), and with it the cells' interpolation
deficit: the bilinear surface through nodes on the sphere lies above it inside each cell by the
same amount on average, so over Hertz's contact area (a^2 = R d) each cell's nodes are lowered by
it, the consistent (mortar) L2 projection: the surface then has the sphere's mean indentation over
each contact cell, its nodes (hx^2 + hz^2) / (12 R) below the sphere; the rim stays the
projection's, smooth wherever the nodes fall (docs/physics.md section 16). Its force against an
independent axisymmetric reference and the extrapolated meshes, per depth and probe position:
docs/physics.md section 16 (``python -m benchmarks.indentation_reference``).

All functions work on one block ((n, 3) positions) or a stack of copies ((N, n, 3) positions with
per-copy probe tips (N, 3)). SI units: m, N, m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import kernels
from .._validate import real_scalar

TIPS = ("sphere", "flat")
#: Where a probe is sampled: "projected" (its indentation projected on the surface nodes' basis
#: functions, ``SurfaceProjection``) or "node" (at the nodes)
SAMPLINGS = ("projected", "node")
#: Gap (m) under which a held node stays in contact (``update``). A node held on a curved surface
#: slides along it during a step (x and z are free), so the surface above it is no longer exactly
#: at its height; releasing it for that made a held press oscillate with period 2 (Palpation at
#: 8x4x8, a corner cell 5 mm deep: 0.93 / 2.22 N forever with 1e-6 m). With 1e-4 m it settles to
#: 0.278 N in 4 steps, with 5e-4 m in 2 steps. A probe lifted further than this in a step lets go.
SLIDE_TOLERANCE = 5e-4
#: How far (share of the way) a held node's reading point follows the node in one contact pass of
#: a step (``relaxed_positions``)
HELD_RELAXATION = 0.5


@dataclass(frozen=True)
class Floor:
    """The rigid floor y >= ``height`` (m) under the block."""

    height: float = 0.0
    #: +1: the obstacle bounds y from below (the admissible side is y >= surface)
    side = 1.0

    def __post_init__(self):
        height = real_scalar("floor height", self.height, "one finite number (m)")
        if not np.isfinite(height):
            raise ValueError(f"floor height must be one finite number (m), got {self.height!r}")

    def surface(self, positions, tip=None):
        """Surface height (m) under each node: (..., n) of ``height``."""
        return np.full(np.shape(positions)[:-1], float(self.height))


@dataclass(frozen=True, eq=False)
class SurfaceProjection:
    """Quadrature of each surface node's bilinear hat function over the faces around it, on a
    structured block's top face (``top_face``), for ``Probe``'s projected sampling.

    Attributes:
        offsets: (Q, 2) quadrature points (x, z) relative to the node, m (rest spacing); for
            stacked copies on blocks of different spacings (a vector env's drawn sizes), (N, Q, 2),
            one set per copy (``stacked``).
        weights: (n, Q) the hat function's weights, zero outside the face, each face node's row
            summing to 1; zero rows for the nodes the probe does not touch.
        reference: (n,) heights of the nodes, m, from which the probe's indentation is measured
            (the surface's height where the probe is above it): the rest heights, or those of
            ``with_reference`` ((N, n) for stacked copies).
        reach: the farthest quadrature point from its node, m ((N,) with (N, Q, 2) offsets).
    """

    offsets: np.ndarray
    weights: np.ndarray
    reference: np.ndarray
    reach: float | np.ndarray

    @classmethod
    def top_face(cls, mesh, nodes=None, points: int = 4) -> "SurfaceProjection":
        """The projection on the top face (y maximal) of a structured block ``mesh``
        (``HexMesh.block``): ``nodes`` (default: the top face's) are those the probe may touch,
        ``points`` midpoints per element side (a 9 mm sphere 4 mm into a 7.5 mm mesh displaces its
        volume within 4.3% with 2, 1.3% with 4, 0.1% with 8; tests/test_contact.py's measure)."""
        if mesh.spacing is None:
            raise ValueError("a surface projection needs a structured block (HexMesh.block): its mesh has no spacing")
        if isinstance(points, bool) or not float(points).is_integer() or int(points) < 1:
            raise ValueError(f"points must be an integer >= 1, got {points!r}")
        rest = mesh.nodes
        top = np.isclose(rest[:, 1], rest[:, 1].max())
        chosen = np.zeros(len(rest), bool)
        chosen[np.flatnonzero(top) if nodes is None else np.asarray(nodes, dtype=int)] = True
        if np.any(chosen & ~top):
            raise ValueError("the projected nodes must lie on the block's top face")
        t = (np.arange(2 * int(points)) + 0.5) / int(points) - 1.0  # midpoints over (-1, 1)
        tx, tz = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
        offsets = np.stack([tx * mesh.spacing[0], tz * mesh.spacing[2]], axis=1)
        hat = (1.0 - np.abs(tx)) * (1.0 - np.abs(tz))
        low, high = rest[:, [0, 2]].min(axis=0) - 1e-12, rest[:, [0, 2]].max(axis=0) + 1e-12
        points_xz = rest[:, None, [0, 2]] + offsets[None]
        inside = np.all((points_xz >= low) & (points_xz <= high), axis=2)
        weights = np.where(chosen[:, None] & inside, hat[None], 0.0)
        total = weights.sum(axis=1, keepdims=True)
        weights = np.divide(weights, total, out=np.zeros_like(weights), where=total > 0)
        reach = float(np.hypot(*mesh.spacing[[0, 2]]))
        return cls(offsets, weights, rest[:, 1].copy(), reach)

    def with_reference(self, heights) -> "SurfaceProjection":
        """The same projection measuring the indentation from ``heights`` (m): (n,) or, for
        stacked copies, (N, n) (the surface at the start of an episode, at equilibrium under
        gravity: measured from the rest heights, a probe pressed into a sagging slab (Palpation's:
        0.67 mm at its centre) pushes only once its averaged indentation exceeds the sag)."""
        heights = np.asarray(heights, dtype=float)
        if heights.shape[-1:] != self.reference.shape[-1:] or not np.all(np.isfinite(heights)):
            raise ValueError(f"heights must be finite with a last axis of {self.reference.shape[-1]} nodes, "
                             f"got shape {heights.shape}")
        return SurfaceProjection(self.offsets, self.weights, heights, self.reach)

    def stacked(self, count: int) -> "SurfaceProjection":
        """The projection for ``count`` stacked copies, each with its own quadrature offsets
        ((count, Q, 2), m), reach ((count,), m) and reference heights ((count, n), m), all
        starting as this one's: a copy on a block of other spacings (the same structured block
        scaled along its axes, whose weights are the same) sets its rows in place (``set_row``)."""
        offsets = np.array(np.broadcast_to(self.offsets, (count,) + self.offsets.shape[-2:]), dtype=float)
        reference = np.array(np.broadcast_to(self.reference, (count,) + self.reference.shape[-1:]), dtype=float)
        return SurfaceProjection(offsets, self.weights, reference, np.array(np.broadcast_to(self.reach, (count,)),
                                                                            dtype=float))

    def set_row(self, index: int, projection: "SurfaceProjection") -> None:
        """Copy ``projection``'s offsets, reach and reference heights (a block of the same topology,
        of its own spacings) into row ``index`` of this ``stacked`` projection, in place."""
        if np.ndim(self.reach) != 1 or projection.weights.shape != self.weights.shape:
            raise ValueError(f"set_row takes a projection of the same nodes and quadrature ({self.weights.shape}) into a "
                             f"stacked projection; got {projection.weights.shape} into reach of shape "
                             f"{np.shape(self.reach)}")
        self.offsets[index] = projection.offsets
        self.reach[index] = projection.reach
        self.reference[index] = projection.reference


@dataclass(frozen=True, eq=False)
class Probe:
    """A rigid probe of ``radius`` (m) pressed from above, its axis vertical: ``tip="sphere"``
    (a hemispherical end, the lowest point at the tip) or ``"flat"`` (a flat-ended cylinder). The
    tip position (m) is passed to ``surface``: it moves with the tool. ``projection``: None (the
    probe is sampled at the nodes) or a ``SurfaceProjection`` (its indentation is projected on the
    nodes' basis functions; see the module's docstring). For stacked copies ``radius`` may be an
    (N,) array, one radius per copy (a domain-randomised probe)."""

    radius: float | np.ndarray
    tip: str = "sphere"
    projection: SurfaceProjection | None = None
    #: Projected sphere: add back the curvature the hat average takes off and the cells' interpolation
    #: deficit over the contact (``curvature_offsets``: the consistent projection)
    curvature_corrected: bool = True
    #: -1: the obstacle bounds y from above (the admissible side is y <= surface)
    side = -1.0

    def __post_init__(self):
        if np.ndim(self.radius) == 1:  # one per copy
            radius = np.array(self.radius, dtype=float)
            if radius.size == 0 or not np.all(np.isfinite(radius)) or np.any(radius <= 0):
                raise ValueError(f"probe radii must be finite numbers > 0 (lengths in m), got {self.radius!r}")
            radius.setflags(write=False)
            object.__setattr__(self, "radius", radius)
        else:
            radius = real_scalar("probe radius", self.radius, "one finite number > 0 (a length in m, e.g. 0.005)")
            if not np.isfinite(radius) or radius <= 0:
                raise ValueError(f"probe radius must be one finite number > 0 (a length in m, e.g. 0.005), got "
                                 f"{self.radius!r}")
        if not isinstance(self.tip, str) or self.tip not in TIPS:
            raise ValueError(f"probe tip must be one of {TIPS}, got {self.tip!r}")
        if self.projection is not None and not isinstance(self.projection, SurfaceProjection):
            raise ValueError(f"projection must be None or a SurfaceProjection, got {type(self.projection).__name__}")

    def _height(self, x, z, tip):
        """The probe's lower surface (m) at horizontal points x, z (tip broadcast against them),
        +inf outside its radius."""
        r2 = (x - tip[..., 0]) ** 2 + (z - tip[..., 2]) ** 2
        radius = self.radius if np.ndim(self.radius) == 0 else self.radius[:, None]  # (N,): a copy's per row
        inside = r2 <= radius**2
        if self.tip == "flat":
            height = np.broadcast_to(tip[..., 1], r2.shape)
        else:
            height = tip[..., 1] + radius - np.sqrt(np.maximum(radius**2 - r2, 0.0))
        return np.where(inside, height, np.inf)

    def surface(self, positions, tip, parallel: bool = False):
        """Height (m) that bounds each node from above, +inf where the probe is not over it:
        positions (n, 3) with tip (3,), or (N, n, 3) with tips (N, 3). Sampled at the nodes, the
        probe's lower surface over the node's (x, z); projected, the hat-weighted average over
        the node's support (around its current (x, z)) of min(probe surface, rest height), +inf
        where the probe reaches below the rest height nowhere on the support. ``parallel``: the
        N rows on numba's threads (the vector envs; the same floats)."""
        positions, tip = np.asarray(positions), np.asarray(tip)
        if (tip.shape != (3,) and tip.shape != positions.shape[:-2] + (3,)) or not np.issubdtype(tip.dtype, np.number):
            raise ValueError(f"probe tip position must be an (x, y, z) point in m: shape (3,) for positions (n, 3), "
                             f"(3,) or (N, 3) for stacked positions (N, n, 3); got shape {tip.shape} for positions "
                             f"{positions.shape}")
        if not np.all(np.isfinite(tip)):
            raise ValueError(f"probe tip position must be finite (m), got {tip.tolist()}")
        projection = self.projection
        if projection is None:
            return self._height(positions[..., 0], positions[..., 2], tip[..., None, :])
        n = positions.shape[-2]
        rows = np.ascontiguousarray(positions, dtype=float).reshape(-1, n, 3)
        reference = np.ascontiguousarray(projection.reference, dtype=float).reshape(-1, n)
        tips = np.ascontiguousarray(np.broadcast_to(tip, rows.shape[:1] + (3,)), dtype=float)
        out = np.empty(rows.shape[:2])
        kernel = kernels.projected_probe_surfaces_rows if parallel else kernels.projected_probe_surfaces
        radii = np.ascontiguousarray(np.atleast_1d(self.radius), dtype=float)  # (1,) or one per row
        offsets = np.ascontiguousarray(projection.offsets, dtype=float).reshape((-1,) + projection.offsets.shape[-2:])
        reach = np.ascontiguousarray(np.atleast_1d(projection.reach), dtype=float)  # (1,) or one per row
        kernel(np.ascontiguousarray(rows[:, :, 0]), np.ascontiguousarray(rows[:, :, 2]), tips, projection.weights,
               offsets, reference, radii, reach, self.tip == "flat", out)
        if self.tip == "sphere" and self.curvature_corrected:
            touched = np.flatnonzero(np.isfinite(out).any(axis=0))  # the nodes the probe bounds (any copy)
            bounds = out[:, touched]
            out[:, touched] = np.where(np.isfinite(bounds), bounds - curvature_offsets(
                rows[:, touched], tips, projection.weights[touched], offsets, reference[:, touched], radii), bounds)
        return out.reshape(positions.shape[:-1])


def curvature_offsets(positions, tips, weights, offsets, reference, radii):
    """(N, A) m: how much deeper than the hat-weighted average of its indentation a node's bound
    must be for the projection to impose a sphere's indentation consistently, for A nodes'
    ``positions`` (N, A, 3) m with their quadrature ``weights`` (A, Q), ``offsets`` (1 or N, Q, 2) m
    and ``reference`` heights (N, A) m, the spheres' ``tips`` (N, 3) m and ``radii`` (1 or N,) m.

    Derivation (docs/physics.md section 16): near the tip the indentation is the paraboloid
    w(x) = d - |x - x_tip|^2 / (2R). Two terms, each a second moment over 2R:

    - nodal: over a node's support the hat average of w is w(x_a) + sum_q w_q (o_q . grad w) +
      1/2 sum_q w_q o_q^T (Hess w) o_q = w(x_a) - sum_q w_q |o_q|^2 / (2R) (the symmetric hat's first
      moment is zero, Hess w = -I / R). Added back over the quadrature points the sphere's footprint
      covers (Hess w = 0 outside it) it bounds the nodes under the sphere by the sphere itself;
    - cell: the bilinear surface through nodes on the sphere lies above it inside each cell by the
      interpolation bubble (xi (hx - xi) + zeta (hz - zeta)) / (2R) (xi, zeta from a corner), whose
      cell mean is (hx^2 + hz^2) / (12 R). The consistent (mortar) L2 projection, whose nodal values
      give each cell the sphere's mean indentation, lowers a cell's nodes by that mean. It is taken
      over the part of the cell in contact, Hertz's a^2 = R d (half the area of the geometric
      footprint: around the contact the tissue sinks away from the sphere): the midpoint mean of
      the bubble over the cell's quadrature points, each counted by the share of its square inside
      that circle (so the bound moves continuously as a node slides), and each node gets its cells'
      means weighted by its hat.

    A node whose support lies in the contact is then bounded (hx^2 + hz^2) / (12 R) below the sphere
    (0.67 mm at Palpation's 6 mm cells and 9 mm sphere), exact for a quadratic indentation; the rim
    keeps the projection's smooth spread. Both terms vanish as h^2."""
    radius = radii[:, None]  # (1 or N, 1)
    x = positions[:, :, None, 0] + offsets[:, None, :, 0]  # (N, A, Q)
    z = positions[:, :, None, 2] + offsets[:, None, :, 1]
    r2 = (x - tips[:, None, None, 0]) ** 2 + (z - tips[:, None, None, 2]) ** 2
    depth = np.minimum(reference - tips[:, None, 1], radius)  # the sphere's depth under each node's reference
    covered = (depth[:, :, None] > 0) & (r2 <= (depth * (2.0 * radius - depth))[:, :, None])
    moment = weights[None] * (offsets[:, None, :, 0] ** 2 + offsets[:, None, :, 1] ** 2)  # (1 or N, A, Q)
    nodal = np.sum(np.where(covered, moment, 0.0), axis=2)
    across, along = np.abs(offsets[..., 0]), np.abs(offsets[..., 1])  # (1 or N, Q): from the node, the cell's corner
    sides = [a.max(axis=1, keepdims=True) + a.min(axis=1, keepdims=True) for a in (across, along)]  # hx, hz (midpoints)
    bubble = across * (sides[0] - across) + along * (sides[1] - along)  # (1 or N, Q) m^2
    cells = (2 * (offsets[..., 0] > 0) + (offsets[..., 1] > 0))[..., None] == np.arange(4)  # (1 or N, Q, 4)
    # the share of each quadrature point's square (side: the points' spacing) inside Hertz's contact,
    # a^2 = R d, to first order in the spacing: continuous as the nodes slide (held heights settle)
    spacing = np.sqrt(4.0 * across.min(axis=1) * along.min(axis=1))[:, None, None]  # (1 or N, 1, 1)
    contact_radius = np.sqrt(np.maximum(depth * radius, 0.0))[:, :, None]
    inside = np.clip((contact_radius - np.sqrt(r2)) / spacing + 0.5, 0.0, 1.0) * (depth[:, :, None] > 0)
    means = (inside * bubble[:, None, :]) @ (cells / cells.sum(axis=1, keepdims=True))  # (N, A, 4)
    shares = weights[None] @ cells  # (1 or N, A, 4): each node's hat weight on its four cells
    return (nodal + np.sum(means * shares, axis=2)) / (2.0 * radius)


def gap(obstacle, positions, tip=None, surface=None):
    """Signed distance (m, along y) from each node to the obstacle's surface, >= 0 on the
    admissible side (+inf for a probe's nodes outside its radius). ``surface``: the obstacle's
    ``surface(positions, tip)`` when the caller has it already (the same floats, computed once)."""
    if surface is None:
        surface = obstacle.surface(positions, tip)
    with np.errstate(invalid="ignore"):  # inf - inf cannot occur: positions are finite
        return obstacle.side * (positions[..., 1] - surface)


def touching(obstacle, positions, candidates, tip=None, tolerance=0.0):
    """Candidate nodes on or through the surface (gap <= ``tolerance``, m): (..., n) bool."""
    return candidates & (gap(obstacle, positions, tip) <= tolerance)


def release(obstacle, contact, forces, tolerance=0.0):
    """The contact set without the nodes the obstacle would have to pull: ``forces`` (..., n, 3)
    are the net nodal forces (N) with the contact's constraint forces left out (tissue, gravity,
    loads); a node stays when they push it into the obstacle (or pull it away by no more than
    ``tolerance``, N)."""
    return contact & (obstacle.side * forces[..., 1] <= tolerance)


def update(obstacle, contact, positions, forces, candidates, tip=None, tolerance=SLIDE_TOLERANCE, surface=None):
    """The contact set for the next step (..., n) bool, before the step, the obstacle (a probe's
    ``tip``) already at its new place: a node in contact stays unless the obstacle would pull it
    (``release`` with the net ``forces``, N) or its surface moved away from it by more than
    ``tolerance`` (m); a candidate not in contact joins when it is on or through the surface (the
    tool moved into it). ``surface``: as ``gap`` takes it."""
    distance = gap(obstacle, positions, tip, surface)
    kept = release(obstacle, contact, forces) & (distance <= tolerance)
    return kept | (candidates & ~contact & (distance <= 0.0))


def relaxed_positions(sampled, positions, contact, relaxation=HELD_RELAXATION):
    """Where the held heights are read in the next contact pass of a step: (..., n, 3) m, the
    ``positions`` with the x and z of the nodes in ``contact`` moved from where they were read last
    (``sampled``, m) by ``relaxation`` of the way to the nodes (the others at the nodes).

    Why: a held node's height is imposed on the obstacle's surface h over its (x, z), which stay
    free, so a pass moves them and the height is read again: the fixed-point map T -> h(x(T)), of
    gain g = (dh/dx) (dx/dT), the surface's slope times the node's horizontal slide per unit of
    imposed height. Under a sphere's flank the slope is about 1 (r ~ 0.7 R) and nearly
    incompressible tissue pressed deeper slides outward by about as much (g about -1.1: Palpation at
    nu 0.45, the sphere 8 mm deep, ``integrator="static"``), so reading at the nodes (x_{k+1} read
    where pass k left them) alternates with period 2 and does not settle: held heights 0.46 mm apart
    after 25 passes, the reading taken at the iterate whose nodes were snapped into the probe,
    12.6% above the equilibrium (0.912 against 0.810 N; tests/test_lag_figure.py). Read at
    x~_{k+1} = x~_k + w (x_k - x~_k), the error changes by 1 + w (g - 1) per pass: w = 1/2 removes it
    at g = -1 and converges for -3 < g < 1 (halving it per pass where the surface is flat, g = 0)."""
    relaxed = np.array(positions, dtype=float)
    moved = np.asarray(sampled) + relaxation * (relaxed - np.asarray(sampled))
    for axis in (0, 2):
        relaxed[..., axis] = np.where(contact, moved[..., axis], relaxed[..., axis])
    return relaxed


def targets(obstacle, positions, contact, tip=None, surface=None):
    """Imposed heights (m) of the contact nodes: the surface at their current (x, z); the other
    nodes keep their y. (..., n) float. ``surface``: as ``gap`` takes it."""
    if surface is None:
        surface = obstacle.surface(positions, tip)
    return np.where(contact & np.isfinite(surface), surface, positions[..., 1])


def project(obstacle, positions, velocities, candidates, tip=None, surface=None):
    """Put the candidate nodes that went through the surface back on it (in place: y on the
    surface, the velocity component into the obstacle removed) and return them (..., n) bool.
    ``surface``: as ``gap`` takes it."""
    if surface is None:
        surface = obstacle.surface(positions, tip)  # once, for the test and the projection
    through = candidates & (gap(obstacle, positions, tip, surface) < 0.0)
    if np.any(through):
        positions[..., 1] = np.where(through, surface, positions[..., 1])
        if obstacle.side > 0:
            velocities[..., 1] = np.where(through, np.maximum(velocities[..., 1], 0.0), velocities[..., 1])
        else:
            velocities[..., 1] = np.where(through, np.minimum(velocities[..., 1], 0.0), velocities[..., 1])
    return through
