"""Frictionless unilateral contact with rigid height-field obstacles, by an active set.

An obstacle bounds the height y of the block's nodes by a surface over the horizontal plane:
the floor ``y >= 0`` (``Floor``) or a probe pressed from above, ``y <= h(x, z)`` (``Probe``:
a sphere-ended probe, whose lower surface is h = y_tip + R - sqrt(R^2 - r^2) within its radius R
of the axis, r the horizontal distance to it; or a flat-ended cylinder, h = y_tip). A node in
contact has its height imposed on the surface at its current (x, z), its x and z stay free: the
contact force is along y and no shear is transmitted. For the floor that is exact frictionless
contact; for the sphere it is Hertz's boundary condition (normal displacement prescribed, zero
shear traction on the contact area), whose small-slope approximation it shares.

The active set is updated as in a static contact solve (and ``sim_core.resolution``'s scenes,
``tissue_env``'s Palpation and Retraction use the same functions):

- ``release``: a node the obstacle would have to pull (the net force on it, tissue plus loads,
  points away from the obstacle) leaves the set;
- ``touching``: a node on or through the surface (within ``tolerance``) is in the set (``update``
  forms a step's set from the last one: kept unless released, joined when touched);
- ``project``: after a step, a free node that went through the surface is put back on it, its
  velocity into the obstacle removed, and it joins the set.

All functions work on one block ((n, 3) positions) or a stack of copies ((N, n, 3) positions with
per-copy probe tips (N, 3)). SI units: m, N, m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TIPS = ("sphere", "flat")
#: Gap (m) under which a held node stays in contact (``update``). A node held on a curved surface
#: slides along it during a step (x and z are free), so the surface above it is no longer exactly
#: at its height; releasing it for that made a held press oscillate with period 2 (Palpation at
#: 8x4x8, a corner cell 5 mm deep: 0.93 / 2.22 N forever with 1e-6 m). With 1e-4 m it settles to
#: 0.278 N in 4 steps, with 5e-4 m in 2 steps. A probe lifted further than this in a step lets go.
SLIDE_TOLERANCE = 5e-4


@dataclass(frozen=True)
class Floor:
    """The rigid floor y >= ``height`` (m) under the block."""

    height: float = 0.0
    #: +1: the obstacle bounds y from below (the admissible side is y >= surface)
    side = 1.0

    def surface(self, positions, tip=None):
        """Surface height (m) under each node: (..., n) of ``height``."""
        return np.full(np.shape(positions)[:-1], float(self.height))


@dataclass(frozen=True)
class Probe:
    """A rigid probe of ``radius`` (m) pressed from above, its axis vertical: ``tip="sphere"``
    (a hemispherical end, the lowest point at the tip) or ``"flat"`` (a flat-ended cylinder). The
    tip position (m) is passed to ``surface``: it moves with the tool."""

    radius: float
    tip: str = "sphere"
    #: -1: the obstacle bounds y from above (the admissible side is y <= surface)
    side = -1.0

    def __post_init__(self):
        if not np.isfinite(self.radius) or self.radius <= 0:
            raise ValueError(f"probe radius must be a finite length > 0 in m, got {self.radius!r}")
        if self.tip not in TIPS:
            raise ValueError(f"probe tip must be one of {TIPS}, got {self.tip!r}")

    def surface(self, positions, tip):
        """Height (m) of the probe's lower surface over each node's (x, z), +inf where the node is
        outside the probe's radius: positions (n, 3) with tip (3,), or (N, n, 3) with tips (N, 3)."""
        positions, tip = np.asarray(positions), np.asarray(tip)
        tip = tip[..., None, :]
        r2 = (positions[..., 0] - tip[..., 0]) ** 2 + (positions[..., 2] - tip[..., 2]) ** 2
        inside = r2 <= self.radius**2
        if self.tip == "flat":
            height = np.broadcast_to(tip[..., 1], r2.shape)
        else:
            height = tip[..., 1] + self.radius - np.sqrt(np.maximum(self.radius**2 - r2, 0.0))
        return np.where(inside, height, np.inf)


def gap(obstacle, positions, tip=None):
    """Signed distance (m, along y) from each node to the obstacle's surface, >= 0 on the
    admissible side (+inf for a probe's nodes outside its radius)."""
    with np.errstate(invalid="ignore"):  # inf - inf cannot occur: positions are finite
        return obstacle.side * (positions[..., 1] - obstacle.surface(positions, tip))


def touching(obstacle, positions, candidates, tip=None, tolerance=0.0):
    """Candidate nodes on or through the surface (gap <= ``tolerance``, m): (..., n) bool."""
    return candidates & (gap(obstacle, positions, tip) <= tolerance)


def release(obstacle, contact, forces, tolerance=0.0):
    """The contact set without the nodes the obstacle would have to pull: ``forces`` (..., n, 3)
    are the net nodal forces (N) with the contact's constraint forces left out (tissue, gravity,
    loads); a node stays when they push it into the obstacle (or pull it away by no more than
    ``tolerance``, N)."""
    return contact & (obstacle.side * forces[..., 1] <= tolerance)


def update(obstacle, contact, positions, forces, candidates, tip=None, tolerance=SLIDE_TOLERANCE):
    """The contact set for the next step (..., n) bool, before the step, the obstacle (a probe's
    ``tip``) already at its new place: a node in contact stays unless the obstacle would pull it
    (``release`` with the net ``forces``, N) or its surface moved away from it by more than
    ``tolerance`` (m); a candidate not in contact joins when it is on or through the surface (the
    tool moved into it)."""
    distance = gap(obstacle, positions, tip)
    kept = release(obstacle, contact, forces) & (distance <= tolerance)
    return kept | (candidates & ~contact & (distance <= 0.0))


def targets(obstacle, positions, contact, tip=None):
    """Imposed heights (m) of the contact nodes: the surface at their current (x, z); the other
    nodes keep their y. (..., n) float."""
    surface = obstacle.surface(positions, tip)
    return np.where(contact & np.isfinite(surface), surface, positions[..., 1])


def project(obstacle, positions, velocities, candidates, tip=None):
    """Put the candidate nodes that went through the surface back on it (in place: y on the
    surface, the velocity component into the obstacle removed) and return them (..., n) bool."""
    through = candidates & (gap(obstacle, positions, tip) < 0.0)
    if np.any(through):
        surface = obstacle.surface(positions, tip)
        positions[..., 1] = np.where(through, surface, positions[..., 1])
        if obstacle.side > 0:
            velocities[..., 1] = np.where(through, np.maximum(velocities[..., 1], 0.0), velocities[..., 1])
        else:
            velocities[..., 1] = np.where(through, np.minimum(velocities[..., 1], 0.0), velocities[..., 1])
    return through
