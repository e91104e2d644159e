"""A grasper that holds surface nodes by imposed displacements and lets them slip at a force limit.

Beside ``contact`` (a rigid obstacle's unilateral contact): a grasper's jaws close on the candidate
nodes (surface nodes, typically) within ``radius`` of its jaw point and hold them rigidly, each at
its offset from the jaw at closing (``Grasper.close``). While held, a node's position is imposed:
its target is the jaw's position plus its offset (``Grasper.control``), so every solver (explicit,
implicit, static, one world or N) steps the grasp as it steps any imposed displacement, and the
force the grasper exerts on the tissue is the reaction on the held nodes, minus the net nodal force
(tissue and gravity) on them (``Grasper.force``): at a static equilibrium exactly the reaction that
``solve_static`` returns for the same nodes imposed at the same positions (tests/test_grasp.py).

**Slip.** A grasp holds by friction between the jaws and the tissue, up to a pull it can carry
(``force_limit``, N). When the magnitude of the grasp force passes it, nodes slip out of the jaws one
after the other (``Grasper.slip``): the held node whose reaction pulls most along the total goes
first (the most loaded contact slides first), then the next, until the force on the nodes still held
is within the limit, or none is held (the grasp is lost). The slip acts at the state where the force
was measured: the nodes that slipped are free from the next step on, and the force on those still
held at that state is within the limit by construction, so a grasp never reports more than its
limit. Tearing the tissue out (the grasped elements cut from the rest) is not modelled here.

All functions take one world ((n, 3) positions, a (3,) jaw) or N worlds ((N, n, 3), jaws (N, 3)),
vectorised over nodes and worlds. SI units: m, N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import real_scalar


@dataclass(frozen=True, eq=False)
class Grasper:
    """A grasper closing on the nodes within ``radius`` (m) of its jaw point and holding them up to
    a grasp force of ``force_limit`` (N; ``np.inf``: never slips). ``force_limit`` may be an (N,)
    array for N worlds (one limit per world)."""

    radius: float
    force_limit: float | np.ndarray = np.inf

    def __post_init__(self):
        radius = real_scalar("grasp radius", self.radius, "one finite number > 0 (a length in m, e.g. 0.005)")
        if not np.isfinite(radius) or radius <= 0:
            raise ValueError(f"grasp radius must be one finite number > 0 (a length in m, e.g. 0.005), got "
                             f"{self.radius!r}")
        limit = np.array(self.force_limit, dtype=float) if np.ndim(self.force_limit) else None
        if limit is None:
            value = real_scalar("grasp force_limit", self.force_limit, "a number > 0 in N (np.inf: never slips)")
            if np.isnan(value) or value <= 0:
                raise ValueError(f"grasp force_limit must be a number > 0 in N (np.inf: never slips), got "
                                 f"{self.force_limit!r}")
        elif limit.ndim != 1 or limit.size == 0 or np.any(np.isnan(limit)) or np.any(limit <= 0):
            raise ValueError(f"grasp force_limit must be a number > 0 in N or an (N,) array of them (one per "
                             f"world), got {self.force_limit!r}")
        else:
            limit.setflags(write=False)
            object.__setattr__(self, "force_limit", limit)

    def close(self, positions, jaw, candidates=None):
        """The jaws close at ``jaw`` (m; (3,) or (N, 3)): the candidate nodes (``candidates`` (n,) or
        (N, n) bool; None: every node) within ``radius`` of it are held. Returns (held (..., n) bool,
        offsets (..., n, 3) m: each node's position from the jaw, what ``control`` keeps)."""
        positions, jaw = _world_arrays(positions, jaw)
        offsets = positions - jaw[..., None, :]
        held = np.einsum("...i,...i->...", offsets, offsets) <= float(self.radius) ** 2
        if candidates is not None:
            candidates = np.asarray(candidates, dtype=bool)
            if candidates.shape[-1] != positions.shape[-2]:
                raise ValueError(f"candidates must be a bool mask over the {positions.shape[-2]} nodes, got shape "
                                 f"{candidates.shape}")
            held &= candidates
        return held, np.where(held[..., None], offsets, 0.0)

    @staticmethod
    def control(fixed, target, held, offsets, jaw):
        """(fixed, target): copies of the control's ``fixed`` (..., n, 3) bool and ``target``
        (..., n, 3) m with every held node imposed at the jaw's position (``jaw`` (3,) or (N, 3) m)
        plus its offset. Equivalently, with the held nodes' positions at closing as ``offsets`` and
        the jaw's displacement since as ``jaw``: the same translation of the grasp."""
        held = np.asarray(held, dtype=bool)[..., None]
        jaw = np.asarray(jaw, dtype=float)
        return (np.asarray(fixed, dtype=bool) | held,
                np.where(held, jaw[..., None, :] + np.asarray(offsets, dtype=float), target))

    @staticmethod
    def node_forces(forces, held):
        """(..., n, 3) N the force the grasper exerts on each held node (0 on the others): minus the
        net nodal ``forces`` (tissue and gravity, N) on it, the reaction of its imposed position."""
        return np.where(np.asarray(held, dtype=bool)[..., None], -np.asarray(forces, dtype=float), 0.0)

    @classmethod
    def force(cls, forces, held):
        """(..., 3) N the force the grasper exerts on the tissue: the sum of ``node_forces``. The force
        the tissue exerts on the grasper is its opposite."""
        return cls.node_forces(forces, held).sum(axis=-2)

    def slip(self, forces, held):
        """The held nodes (..., n) bool left once nodes have slipped out, node after node, until the
        grasp force on those left is at most ``force_limit`` (see the module docstring); ``forces``
        (..., n, 3) N the net nodal forces at the state the grasp is judged at."""
        held = np.asarray(held, dtype=bool)
        reaction = self.node_forces(forces, held)
        total = reaction.sum(axis=-2)
        magnitude = np.linalg.norm(total, axis=-1)
        limit = np.asarray(self.force_limit, dtype=float)  # one per world: the leading axis of the rest
        limit = limit.reshape(limit.shape + (1,) * (magnitude.ndim - limit.ndim))
        if not np.any(magnitude > limit):
            return held.copy()
        direction = total / np.maximum(magnitude, np.finfo(float).tiny)[..., None]
        pull = np.einsum("...ni,...i->...n", reaction, direction)
        order = np.argsort(np.where(held, -pull, np.inf), axis=-1, kind="stable")  # most pulling first
        ranked = np.take_along_axis(reaction, order[..., None], axis=-2)
        # remaining[k]: the grasp force once the first k ranked nodes have slipped (k = 0 ... n)
        remaining = total[..., None, :] - np.concatenate([np.zeros_like(ranked[..., :1, :]),
                                                          np.cumsum(ranked, axis=-2)], axis=-2)
        within = np.linalg.norm(remaining, axis=-1) <= limit[..., None]
        within[..., -1] = True  # every node gone: no force (rounding of the cumulative sum aside)
        count = np.argmax(within, axis=-1)  # the fewest slips that bring the force within the limit
        rank = np.empty_like(order)
        np.put_along_axis(rank, order, np.broadcast_to(np.arange(order.shape[-1]), order.shape), axis=-1)
        return held & (rank >= count[..., None])


def _world_arrays(positions, jaw):
    """``positions`` (n, 3) or (N, n, 3) m and ``jaw`` (3,) or (N, 3) m as float arrays; ValueError
    for other shapes or non-finite values."""
    positions = np.asarray(positions, dtype=float)
    jaw = np.asarray(jaw, dtype=float)
    if positions.ndim not in (2, 3) or positions.shape[-1] != 3:
        raise ValueError(f"positions must be (n, 3) or (N, n, 3) in m, got shape {positions.shape}")
    if jaw.shape != (3,) and jaw.shape != positions.shape[:-2] + (3,):
        raise ValueError(f"the jaw must be an (x, y, z) point in m: shape (3,), or (N, 3) for positions (N, n, 3); "
                         f"got shape {jaw.shape} for positions {positions.shape}")
    if not (np.all(np.isfinite(jaw)) and np.all(np.isfinite(positions))):
        raise ValueError("positions and the jaw must be finite (m)")
    return positions, jaw
