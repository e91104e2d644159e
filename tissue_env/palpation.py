"""Palpation-v0: find a stiff inclusion hidden in soft tissue by indenting the surface with a probe."""

from __future__ import annotations

import numpy as np

from sim_core import Material
from sim_core import kernels
from sim_core.models.model import Control
from sim_core.solvers import contact
from sim_core.solvers.static import same_contacts

from .base import (TissueEnv, check_range, check_region, check_vector, check_vector_range, difficulty_settings,
                   nonnegative_scalar, positive_scalar)
from .camera import ALBEDO, probe_mesh
from .vector import TissueVectorEnv
from .worlds import TaskWorlds

#: Solves of one implicit step over the probe's contact set (``TaskWorlds._advance``): the
#: step is solved again from its start while the set it ends with differs from the one it was
#: solved with. Pressing 4 mm in one step at nu 0.49 the set settles in 2-3 solves; a step that
#: presses nothing takes one (1.4 solves per env step over random and scripted episodes).
CONTACT_PASSES = 4
#: How far (m) the held heights may move between two solves of a step for its set to count as
#: settled: a held node slides along the sphere (x, z free) and its bound follows. 20 um is 0.5% of
#: a 4 mm press; with 0.1 mm the first held reading at nu 0.49 was 1.5x its equilibrium's (the
#: sliding of a press made in one step is more than that), with 1 um the step cost 10-30% more.
CONTACT_HEIGHT_TOLERANCE = 2e-5


def update_palpation_map(palpation_map, centres, tips, depth, reading, map_depth, radius, rows):
    """Record presses in the palpation maps (N, C) in place and return which rows (N,) probed a
    cell for the first time. A row probes the candidate cell whose centre (``centres`` (C, 2) or,
    one lattice per row, (N, C, 2), x and z in m) is nearest its tip (``tips`` (N, 3), m) when that centre is within ``radius``
    (m), the tip is at least ``map_depth`` (m) deep (``depth`` (N,)) and the probe touches
    (``reading`` (N,) > 0: the apparent modulus, Pa, depth-normalised so that a deeper press
    reads the same tissue alike); the cell keeps the reading of its latest probe, so that a
    press held still replaces the first step's (the first step of a press at full speed reads
    0.91-1.32x the held reading at the same place at the default shape: the damping of the tissue
    it sets moving). Only ``rows`` (N,) bool are updated."""
    centres = np.broadcast_to(centres, palpation_map.shape + (2,))
    distance = np.hypot(centres[..., 0] - tips[:, None, 0], centres[..., 1] - tips[:, None, 2])
    cell = np.argmin(distance, axis=1)
    index = np.arange(len(cell))
    probed = rows & (depth >= map_depth - 1e-9) & (distance[index, cell] <= radius) & (reading > 0)
    new = probed & (palpation_map[index, cell] == 0)
    palpation_map[index, cell] = np.where(probed, reading, palpation_map[index, cell])
    return new


def apparent_modulus(force, indentation, radius, tip):
    """Apparent (Hertz) modulus E* = E / (1 - nu^2), Pa, of a probe's reading on an elastic
    half-space: a sphere of ``radius`` (m) pushed ``indentation`` (m) with ``force`` (N):
    F = 4/3 E* sqrt(R) d^1.5; a flat punch: F = 2 E* R d (Boussinesq). Arrays broadcast; 0 where
    the indentation is below 0.1 mm or the force is not a push. On Palpation's homogeneous slab
    (E* 6.3 kPa, 3 cm thick) it reads 7.0-7.6 kPa held 4-8 mm deep (F / d: 42-75 N/m; the default
    (10, 5, 10), ``benchmarks/palpation_map.py``)."""
    force, indentation = np.asarray(force, dtype=float), np.asarray(indentation, dtype=float)
    touching = (indentation > 1e-4) & (force > 0)
    safe = np.where(touching, indentation, 1.0)
    modulus = force / (4.0 / 3.0 * np.sqrt(radius) * safe**1.5) if tip == "sphere" else force / (2.0 * radius * safe)
    return np.where(touching, modulus, 0.0)


def map_features(palpation_map, centres, tips, length_scale, modulus):
    """Observation features of palpation maps (N, C) in Pa (``centres`` (C, 2) or (N, C, 2) m, as
    ``update_palpation_map`` takes them): the map in units of ``modulus`` (N,) Pa
    (the tissue's apparent modulus E / (1 - nu^2): the surrounding tissue reads about 1 at any
    stiffness; 0 where not probed yet), the horizontal offset (cm) from the tip to the stiffest
    probed cell and to the nearest cell not probed yet (zeros when there is none)."""
    offsets = (np.broadcast_to(centres, palpation_map.shape + (2,)) - tips[:, None][..., [0, 2]]) / length_scale
    index = np.arange(len(palpation_map))
    probed = palpation_map > 0
    stiffest = np.where(probed.any(axis=1)[:, None], offsets[index, np.argmax(palpation_map, axis=1)], 0.0)
    distance = np.where(probed, np.inf, np.hypot(offsets[..., 0], offsets[..., 1]))
    unprobed = np.where((~probed).any(axis=1)[:, None], offsets[index, np.argmin(distance, axis=1)], 0.0)
    return dict(palpation_map=palpation_map / modulus[:, None], stiffest_offset=stiffest, unprobed_offset=unprobed)


class PalpationWorlds(TaskWorlds):
    """Palpation's step on N worlds (``tissue_env.worlds``)."""

    # The measurement's force pass is the next step's (the same observations, bitwise): one force
    # pass per step instead of two (benchmarks/vector_env_speed.py, the performance page).
    share_force_pass = True

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count = self.task, self.num_envs
        self._probe_candidates = env._probe_candidates
        #: (N,) each copy's top face height, m, and (N, C, 2) its candidate cells' centres (x, z), m:
        #: its episode's slab (``size_range``)
        self.top_y = np.full(count, env.top_y)
        self.cell_centres = np.repeat(env.cell_centres[None], count, axis=0)
        #: (N, n) each copy's start heights (``PalpationEnv.start_heights``), m, updated in place at
        #: its reset: the projected probe's reference
        self.start_heights = np.repeat(env.mesh.nodes[None, :, 1], count, axis=0)
        #: (N,) each copy's probe radius this episode, m (``probe_radius_range``), and (N, V, 3) its
        #: probe's vertices (the camera's), m from the tip
        self.probe_radius = np.full(count, env.probe_radius)
        # one row of quadrature offsets per copy: its slab's spacing (size_range)
        self._projection = None if env.probe.projection is None else env.probe.projection.with_reference(
            self.start_heights).stacked(count)
        if self._projection is not None:
            self.start_heights = self._projection.reference
        self.probe = contact.Probe(self.probe_radius.copy(), env.probe_tip, self._projection)
        template, self._probe_triangles = probe_mesh(env.probe_radius, env.probe_tip)
        self._probe_vertices = np.repeat(template[None], count, axis=0)
        self._base_fixed = env.base_control.fixed
        self._base_target = np.repeat(env.base_control.target[None], count, axis=0)  # each copy's slab
        self.probe_start = np.zeros((count, 3))
        self.inclusion_ratio_of = np.zeros(count)  # each copy's inclusion stiffness ratio this episode
        self.inclusion_size_of = np.zeros((count, 3))  # and its inclusion's size, m
        self.inclusion_centre = np.zeros((count, 3))
        self.press_steps = np.zeros(count, dtype=int)
        self.contact = np.zeros((count, env.mesh.n_nodes), dtype=bool)  # nodes each copy's probe holds
        self._node_forces = None  # (N, n, 3) net forces of the last measurement
        self._sampled = None  # (N, n, 3) m: within a step, where its last contact pass read the held heights
        self._tool_mask = None  # (N, n, 3) the step's contact dofs (projected nodes join after the step)
        self._formed = None  # within a step: the last (fixed, target, tool mask) formed by ``_control``
        self.palpation_map = np.zeros((count, len(env.cell_centres)))
        self.distance = np.zeros(count)
        for name in ("success_depth", "success_radius", "hold_steps", "success_bonus", "time_penalty", "force_limit",
                     "force_weight", "map_depth", "explore_bonus", "approach_weight"):
            setattr(self, name, getattr(env, name))

    def _load_task(self, index, env):
        if self.probe_radius[index] != env.episode_probe_radius:
            self.probe_radius[index] = env.episode_probe_radius
            self.probe = contact.Probe(self.probe_radius.copy(), env.probe_tip, self._projection)
            self._probe_vertices[index] = probe_mesh(env.episode_probe_radius, env.probe_tip)[0]
        if self._projection is not None:
            self._projection.set_row(index, env.probe.projection)
        self.top_y[index] = env.top_y
        self.cell_centres[index] = env.cell_centres
        self._base_target[index] = env.base_control.target
        self.inclusion_ratio_of[index] = env.episode_inclusion_ratio
        self.inclusion_size_of[index] = env.episode_inclusion_size
        self.probe_start[index] = env.probe_start
        self.start_heights[index] = env.start_heights
        self.inclusion_centre[index] = env.inclusion_centre
        self.press_steps[index] = env.press_steps
        self.palpation_map[index] = env.palpation_map
        self.distance[index] = 0.0  # (set by the reset's measurement)
        self.contact[index] = env.contact

    def _tips(self):
        return self.probe_start + self.tool_offset

    def _control(self, rows=None):
        """The attached bottom face and the probe contact (``sim_core.solvers.contact``): the top nodes on
        or under the probe's surface have their height imposed on it (frictionless: x and z stay
        free), so the implicit step solves with the contact in place; a node the tissue pulls away
        from the probe (net force on it downward, measured at the current state) is released.
        ``rows``: None (every world), or the worlds (N,) bool still solving a step's contact passes,
        whose contact alone is formed again (the others keep the control they were solved with)."""
        count, tips, positions = self.num_envs, self._tips(), self.positions  # the state before the step
        forces = np.zeros_like(positions) if self._node_forces is None else self._node_forces
        if rows is None or rows.all():
            index, probe = slice(None), self.probe
            fixed = np.repeat(self._base_fixed[None], count, axis=0)
            target = self._base_target.copy()
            tool_mask = np.zeros_like(fixed)
        else:  # only the solving worlds' geometry: a world's floats do not depend on the others
            index, probe = np.flatnonzero(rows), self._probe_rows(rows)
            fixed, target, tool_mask = (array.copy() for array in self._formed)
            fixed[index], target[index], tool_mask[index] = self._base_fixed, self._base_target[index], False
        positions, tips, sampled = positions[index], tips[index], self._sampled
        if sampled is not None:  # a step's next contact pass: the held heights read nearer where they were
            positions = sampled[index] = contact.relaxed_positions(sampled[index], positions, self.contact[index])
        # once for the contact update and its targets, the copies on the kernels' threads when threaded
        surface = probe.surface(positions, tips, parallel=kernels.threaded(self.threads))
        held = self.contact[index] = contact.update(probe, self.contact[index], positions, forces[index],
                                                    self._probe_candidates, tips, surface=surface)
        fixed[index, :, 1] |= held
        target[index, :, 1] = np.where(held, contact.targets(probe, positions, held, tips, surface=surface),
                                       target[index, :, 1])
        tool_mask[index, :, 1] = held
        self._tool_mask = tool_mask
        self._formed = (fixed, target, tool_mask)
        return fixed, target, tool_mask

    def _probe_rows(self, rows):
        """The probe of the worlds ``rows`` (N,) bool alone: their radii and projection rows."""
        projection = self._projection
        if projection is not None:
            projection = contact.SurfaceProjection(projection.offsets[rows], projection.weights,
                                                   projection.reference[rows], projection.reach[rows])
        return contact.Probe(self.probe.radius[rows], self.probe.tip, projection)

    def _advance(self, fixed, target, tool_mask, active):
        """The implicit step with the probe's contact set solved within the step (``TaskWorlds._advance``,
        at most CONTACT_PASSES solves): after a solve the set is re-formed at the step's end
        (``_control``: the nodes the tissue pulls are released, those that went through the probe
        joined, held heights at the nodes' new (x, z)) and, where it differs from the set the step was
        solved with, the step is solved again from its start. A set formed once per step lags a step
        behind: a probe pushed 4 mm into the slab holds every top node its bound passed (21 at the
        default shape, where the equilibrium holds 9) for that whole step, the tissue pulls on the
        outer ones, and the next step releases them all at once; at nu 0.49 the first held reading
        was then 1.7x (``baudet-hyperelastic``) to 4x (``baudet``) the equilibrium's, which the
        scripted sweep (one held step per press) read as stiffness (tests/test_env_palpation.py).
        ``integrator="static"`` iterates the set as every task does. Either way a pass reads the
        held heights at ``contact.relaxed_positions`` (from where the step's first control read
        them: the nodes at its start)."""
        self._sampled = self.positions.copy()
        try:
            return super()._advance(fixed, target, tool_mask, active)
        finally:
            self._sampled = self._formed = None

    def _contact_passes(self):
        return super()._contact_passes() if self.static else (CONTACT_PASSES, CONTACT_HEIGHT_TOLERANCE)

    def _contact_forces(self, tool_mask, rows):
        self._node_forces = self.net_forces(rows)  # at the solve's end: the nodes the tissue pulls

    def _after_substep(self, positions, velocities, rows):
        # a free top node that went into the probe is put back on its surface and joins the contact (a
        # held one is where its imposed height put it: the next pass reads its height again); the
        # surface of the worlds ``rows`` alone
        if not rows.any():
            return
        index, probe = (slice(None), self.probe) if rows.all() else (np.flatnonzero(rows), self._probe_rows(rows))
        tips, moved, moving = self._tips()[index], positions[index], velocities[index]
        through = contact.project(probe, moved, moving, self._probe_candidates & ~self.contact[index], tips,
                                  surface=probe.surface(moved, tips, parallel=kernels.threaded(self.threads)))
        positions[index], velocities[index] = moved, moving
        self.contact[index] |= through
        self._tool_mask[index, :, 1] |= through

    def _tool_position(self, positions):
        return self._tips()

    def _scene_extras(self):
        """The probe (its end and a shaft) at each world's tip; never the inclusion."""
        triangles = self._probe_triangles
        albedo = np.broadcast_to(ALBEDO["probe"], (len(triangles), 3))
        return self._tips()[:, None, :] + self._probe_vertices, triangles, albedo

    def _task_measures(self, positions):
        tip = self._tips()
        depth = self.top_y - tip[:, 1]
        horizontal = np.hypot(tip[:, 0] - self.inclusion_centre[:, 0], tip[:, 2] - self.inclusion_centre[:, 2])
        pressing = (depth >= self.success_depth - 1e-9) & (horizontal <= self.success_radius)
        return dict(depth=depth, horizontal_distance=horizontal, pressing=pressing)

    def _measure(self, tool_mask):
        measures = super()._measure(tool_mask)
        self._node_forces = measures["forces"]
        pushing, depth = -measures["reaction_force"][:, 1], measures["depth"]
        touching = (depth > 1e-4) & self.contact.any(axis=1)
        measures["indentation_stiffness"] = np.where(touching, pushing / np.where(touching, depth, 1.0), 0.0)
        tips = self._tips()
        env = self.task
        indentation = env.start_surface(tips, self.start_heights, self.block_size / np.asarray(env.mesh.shape)) - tips[:, 1]
        measures["apparent_modulus"] = apparent_modulus(np.where(self.contact.any(axis=1), pushing, 0.0), indentation,
                                                        self.probe_radius, env.probe_tip)
        return measures

    def _record(self, measures, rows, fresh):
        # consecutive steps of a success press, the palpation map, the approach to the inclusion
        self.press_steps = np.where(rows, np.where(measures["pressing"], self.press_steps + 1, 0), self.press_steps)
        measures["press_steps"] = self.press_steps.copy()
        measures["new_cell"] = update_palpation_map(self.palpation_map, self.cell_centres, self._tips(), measures["depth"],
                                                    measures["apparent_modulus"], self.map_depth,
                                                    self.success_radius, rows)
        distance = measures["horizontal_distance"]
        measures["approach"] = np.where(rows & ~fresh, self.distance - distance, 0.0)
        self.distance = np.where(rows, distance, self.distance)

    def _task_features(self, measures):
        # moduli and stiffnesses relative to the episode's tissue: the same range at any stiffness
        modulus = self.episode_young_modulus / (1.0 - self.episode_poisson_ratio ** 2)  # E*, Pa
        return dict(depth=measures["depth"][:, None] / self.length_scale,
                    contact_nodes=self.contact.sum(axis=1)[:, None],
                    # F / d of a flat punch of the probe's radius on the tissue: 2 E* R
                    indentation_stiffness=(measures["indentation_stiffness"] / (2.0 * modulus * self.probe_radius))[:, None],
                    hold_progress=np.minimum(measures["press_steps"], self.hold_steps)[:, None] / self.hold_steps,
                    **map_features(self.palpation_map, self.cell_centres, self._tips(), self.length_scale, modulus))

    def _task_info(self, measures):
        return dict(depth=measures["depth"].copy(), horizontal_distance=measures["horizontal_distance"].copy(),
                    press_steps=measures["press_steps"].copy(), inclusion_centre=self.inclusion_centre.copy(),
                    indentation_stiffness=measures["indentation_stiffness"].copy(),
                    apparent_modulus=measures["apparent_modulus"].copy(),
                    inclusion_ratio=self.inclusion_ratio_of.copy(), inclusion_size=self.inclusion_size_of.copy(),
                    probe_radius=self.probe_radius.copy())

    def _grasped(self, measures):
        # a probe presses, it holds nothing: its force is the contact's (``tool_forces``)
        return np.zeros((self.num_envs, 1), dtype=bool)

    def _is_success(self, measures):
        return measures["press_steps"] >= self.hold_steps

    def _reward_terms(self, measures):
        force = np.linalg.norm(measures["reaction_force"], axis=1)
        limit = self.scaled_force(self.force_limit)  # N, in the episode's tissue
        terms = dict(
            success=np.where(self._is_success(measures), self.success_bonus, 0.0),
            explore=np.where(measures["new_cell"], self.explore_bonus, 0.0),
            approach=self.approach_weight * measures["approach"] / 0.01,
            time=np.full(self.num_envs, -self.time_penalty),
            force=-self.force_weight * np.maximum(0.0, force - limit) / limit,
        )
        terms.update(self._damage_terms(measures))
        return terms

    def _write_back_task(self, index, env):
        env.contact = self.contact[index].copy()
        env.press_steps = int(self.press_steps[index])
        env.palpation_map = self.palpation_map[index].copy()
        env.distance = float(self.distance[index])


class PalpationEnv(TissueEnv):
    """
    ## Description

    A slab of liver-like tissue (6 x 3 x 6 cm, 10 x 5 x 10 hexahedra of 6 mm, the hyperelastic
    mass-spring model of ``sim_core``, ``model="baudet-hyperelastic"``, gravity on) is attached to the body by its bottom face. A tumour, a box
    of ``inclusion_size`` (default 1.2 x 1 x 1.2 cm) centred 1.5 cm under the surface, is
    ``inclusion_ratio`` (default 10) times stiffer than the tissue: each element's Young's modulus
    is E (1 + (ratio - 1) f), f the share of its volume inside the box (the inclusion's stiff volume
    is the box's at every shape, wherever the nodes fall). A probe with a hemispherical end of radius
    ``probe_radius`` (default 9 mm; ``probe_tip="flat"``: a flat-ended cylinder) indents the top
    surface with a frictionless contact (``sim_core.solvers.contact``, an active set inside the implicit
    step): the probe's indentation of the start surface (the slab at equilibrium under gravity)
    is projected on the top nodes' bilinear basis functions (``probe_sampling="projected"``: each
    node is bounded by the hat-weighted average of the probe's surface over the faces around it,
    so the displaced volume is the probe's wherever the nodes fall; ``"node"``: by the probe's
    surface over the node itself); the top nodes on or over their bound have their height imposed
    on it (x and z free: Hertz's boundary condition), a node the tissue pulls away from the probe
    is released, and a node that went through its bound during a step is put back on it and joins.
    The probe radius, the inclusion and its candidate positions are physical sizes: ``shape`` only
    sets the resolution (a finer mesh models the same scene with more elements and contact nodes).
    The projected sphere is what makes the observations converge with the mesh (README, "How the
    default resolution is chosen"). The agent sees the probe position and the
    reaction force and must press at least 5 mm deep within 1 cm (horizontally) of the inclusion
    and hold that press for ``hold_steps`` (default 3) consecutive steps: what a surgeon does when
    palpating a liver for a tumour. The probe starts at a random place at least ``start_distance``
    (default 2 cm) away from the inclusion, so the agent has to search; holding the press is what
    tells a deliberate press apart from one a random walk passes through (measured over 20 seeds:
    random actions succeed in about 5% of episodes, the scripted sweep in 100%; see
    tests/test_env_palpation.py).

    Physics: one implicit Euler step of ``dt`` = 40 ms per env step, linear solves to a relative
    residual of 1e-2 (see ``tissue_env.base``); the default shape, dt and tolerance are the
    budgeted choice of ``benchmarks/env_accuracy.py``.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: probe displacement increment, scaled by ``max_step`` (default
    4 mm) and clipped to the workspace (the probe axis stays over the central 80 % of the top face;
    the tip between 10 mm above and ``max_depth`` (default 8 mm) below the undeformed surface; the
    workspace is fixed in space, whatever the start).

    | Num | Action                     | Min | Max | Unit         |
    |-----|----------------------------|-----|-----|--------------|
    | 0   | probe increment along x    | -1  | 1   | max_step (m) |
    | 1   | probe increment along y    | -1  | 1   | max_step (m) |
    | 2   | probe increment along z    | -1  | 1   | max_step (m) |

    ## Observation Space

    ``observation_type="state"``: ``Box(-100, 100, (15 + C + 4,), float32)`` (the maximum
    spring strain within +-1000, every other entry within +-100), C the number of
    candidate inclusion cells (9 at the defaults: 28 values; it depends on ``size`` and
    ``inclusion_region``, not on ``shape``).

    | Index | Observation                                        | Unit (normalised)     |
    |-------|----------------------------------------------------|-----------------------|
    | 0-2   | probe tip position                                 | cm from block centre  |
    | 3-5   | probe displacement from its (random) start         | cm                    |
    | 6-8   | force the probe exerts on the tissue               | 0.1 N x E / 5 kPa      |
    | 9     | relative volume change (V - V0) / V0               | %                     |
    | 10    | maximum spring strain abs(L - L0) / L0             | %                     |
    | 11    | indentation depth below the undeformed surface     | cm (negative above)   |
    | 12    | number of top nodes in contact with the probe      | count                 |
    | 13    | indentation stiffness, vertical force / depth      | 2 E* R (0 if none)    |
    | 14    | steps the success press has been held / hold_steps | 1 (0 when not pressing) |
    | 15 .. 15+C-1 | palpation map: apparent modulus of the latest press on each candidate cell | E* (0 = not probed yet) |
    | 15+C, 16+C   | offset (x, z) from the tip to the stiffest probed cell | cm (0 if none) |
    | 17+C, 18+C   | offset (x, z) from the tip to the nearest cell not probed yet | cm (0 if none) |

    The palpation map is the agent's own memory of where it pressed and what it felt (a cell is
    probed when the tip is ``map_depth`` = 4 mm deep or more with its axis within 1 cm of the
    cell's centre, nearest centre first); it never reveals the inclusion. Without it a memoryless
    policy cannot tell which places it has already pressed: PPO and SAC stayed at the random
    policy's success rate (benchmarks/results/training.json before the map). A cell holds the
    reading of its latest press: the apparent (Hertz) modulus E* = 3 F / (4 sqrt(R) d^1.5)
    (``apparent_modulus``; F the probe's vertical force, d its depth under the start surface),
    which reads the same tissue nearly alike at any depth (held 4 and 8 mm deep over three cells of
    the homogeneous slab: 7.01-7.54 and 6.96-7.56 kPa, where F / d rises from 42-46 to 69-75 N/m;
    E* = E / (1 - nu^2) = 6.3 kPa for a half-space, the 3 cm slab on its attached base is stiffer;
    ``benchmarks/palpation_map.py``, which also
    shows finer meshes reading the 8 mm press higher), so a press 8 mm deep reads the same tissue
    19% above one 4 mm deep (tests/test_env_palpation.py's cell), less than the inclusion's
    1.24-1.33x; and a press held still replaces the first step of a press at full speed, which
    reads 0.91-1.32x the held reading at the same place (the map's grid over one node period: the
    damping of the tissue it sets moving; 0.96-3.87x before the contact set was solved within
    each step, issue 42).
    The observation gives the map, and the indentation stiffness, relative to the episode's
    tissue (E* of its young_modulus and poisson_ratio; 2 E* R, R the probe radius): the
    surrounding tissue reads about 0.9-1.15 at any stiffness and the inclusion its ratio, inside
    the observation bounds from 1 kPa to 1 MPa (in kPa, an inclusion's first press read up to 102
    at the defaults, beyond the bound of 100).

    How well the map locates the inclusion (``benchmarks/palpation_map.py``; the tests in
    tests/test_env_palpation.py): presses 6 mm deep held two steps read a homogeneous slab within
    1.05 (max/min) over one node period, and the inclusion's cell reads 1.24-1.33 times the
    stiffest other cell in all 9 placements (1.11 and 1.15-1.26 at (8, 4, 8) with the first-order
    projection). With the probe
    sampled at the nodes (``"node"``) the coarser (8, 4, 8) felt a press over a node on that node
    and one between nodes on four: 1.39 over the node period, and the inclusion's cell 0.75-1.80
    times the stiffest other (below 1 in 5 of the 9 placements); the default's 6 mm nodes under
    the 9 mm probe read 1.10 and 1.20-1.22 that way.

    ``"deformation"`` appends the surface-node displacements (cm); ``"dict"`` gives the features
    as a ``Dict`` keyed by name. The inclusion position is not observed.

    ## Rewards

    ``r = reward_success + reward_time + reward_force + reward_volume + reward_strain
    (+ reward_instability)``:

    - ``reward_success = success_bonus`` (default 10) on success, else 0
    - ``reward_explore = explore_bonus`` (default 0.5) when a candidate cell is probed for the
      first time (at most C x 0.5 = 4.5 per episode at the defaults, less than the success bonus)
    - ``reward_approach = approach_weight * (d_prev - d) / 1 cm`` (default weight 1), d the
      horizontal distance from the probe axis to the inclusion: potential-based shaping (it sums
      to the net approach over an episode; undiscounted, so it leaves the optimal policies unchanged
      for a discount of 1 only, with a small pull towards short approaches below it). It
      uses the inclusion's position, which the observation never contains. Pilot, PPO 30k steps,
      one seed, 20 evaluation episodes: 65% success with it, 50% without (random: 10%).
    - ``reward_time = -time_penalty`` (default 0.05) per step
    - ``reward_force = -force_weight * max(0, |F| - force_limit) / force_limit`` (defaults 1, 2 N
      at E = 5 kPa, the limit scaled with the episode's E:
      the default mesh resolves the stiff inclusion; the scripted sweep's presses peak at 0.5 N
      since it moves over the chosen cell before its final press (5.6 N when it ploughed there
      pressed, issue 42); with the 1 N limit set on the (8, 4, 8) mesh, whose presses peaked at 1.35 N, PPO
      fell from 85% to 30-35% success at the benchmark's budget, see README)
    - ``reward_volume``, ``reward_strain`` as in every task (``tissue_env.base``), and
      ``reward_instability = -instability_penalty`` on a diverging step.

    ## Starting State

    The slab at static equilibrium under gravity. The inclusion is centred on one of the candidate
    cells, drawn uniformly. The candidate cells are physical: the slab is tiled by cells of
    ``cell_size`` (default 1.2 x 1 x 1.2 cm) (whole cells, centred on the top face, layers counted from the
    surface; at the default size, the elements of a 5 x 3 x 5 mesh) and the candidates are
    the cells of the second layer (centres 1.5 cm under the surface): the interior ones by default (9
    positions at the default size: x, z in {0.018, 0.030, 0.042} m, y = 0.015 m), or, with
    ``inclusion_region``, all those (the outer ring included) whose centre lies in that region of
    the top face. Its stiffness ratio is ``inclusion_ratio`` or,
    with ``inclusion_ratio_range``, drawn uniformly in that range. The probe tip
    starts 2 mm above the undeformed surface, over a point drawn uniformly in the workspace among
    those at least ``start_distance`` (default 2 cm) horizontally from the inclusion centre (the
    farthest of 32 draws when none is that far, which only happens for a custom geometry).

    ## Episode End

    Terminated on success or on divergence (``info["unstable"]``); truncated after 100 steps.
    Success: for ``hold_steps`` (default 3) consecutive steps, the tip at least ``success_depth``
    = 5 mm below the undeformed surface with its axis within ``success_radius`` = 1 cm of the
    inclusion centre (horizontally); ``info["press_steps"]`` counts the steps held so far.

    ## Difficulty

    ``difficulty="easy" | "default" | "hard"`` sets ``inclusion_ratio`` (the contrast),
    ``inclusion_size``, ``success_radius``, ``hold_steps``, ``start_distance`` and
    ``terminate_on_success`` from ``PalpationEnv.DIFFICULTY`` (a keyword passed explicitly
    overrides its level's value): easy, a stiffer inclusion, a wider success radius, a shorter
    hold and a nearer start; hard, a 4x inclusion of 8 mm, a narrower radius, a longer hold and a
    start farther from it. Measured success rates and steps to success per level: the training
    page of the documentation (``benchmarks/success_rates.py --difficulty``).

    ## Domain randomisation

    ``inclusion_ratio_range`` (the contrast), ``inclusion_size_range`` (None or (low, high), each a
    size in m or three: each axis of the inclusion box drawn uniformly per episode;
    ``info["inclusion_size"]``) and ``inclusion_region`` (the candidate places, one drawn per
    episode; ``info["inclusion_centre"]``) vary the inclusion; ``young_modulus_range``,
    ``poisson_ratio_range`` and ``density_range`` the tissue (``tissue_env.base.TissueEnv``). Each
    inclusion or material drawn is a model of its own (cached, ``MODEL_CACHE_SIZE`` of them).
    ``probe_radius_range`` (None or (low, high) m) draws the probe's radius per episode (the
    contact, the apparent modulus of the map and the indentation stiffness's unit 2 E* R follow it;
    ``info["probe_radius"]``). ``size_range`` draws the slab's extent per episode (``info["size"]``;
    ``tissue_env.base.TissueEnv``): the candidate cells are the ``size`` slab's lattice scaled with
    the drawn slab (cells of ``cell_size`` x drawn / ``size``: the palpation map keeps its C cells),
    the inclusion box, probe, depths and radii keep their sizes in m, and the probe's surface
    projection is the drawn slab's. The default ``baudet-hyperelastic`` takes any box; with
    ``model="baudet"`` the elements must stay near-cubic (a ValueError at construction names the
    range's corner that is not): draw the axes together. ``observe_parameters=True`` appends the drawn
    parameters (``randomised_parameters``), each normalised to [-1, 1] over its range, to the
    observation.

    ## Info

    Every step's and reset's ``info`` has the entries every task has (``relative_volume_change``, ``unstable``,
    ``unstable_reason``, ``is_success``, ``out_of_range``, ``max_strain``, one ``reward_<term>`` per reward
    term, the episode's material and ``size``), the tool's forces: ``reaction_force`` ((3,) N, the force the
    tool exerts on the tissue) and ``tool_forces`` ((1, 3) float, N: the force the tissue exerts on the one
    tool, its opposite), and ``grasped`` ((1,) bool: always False: a probe presses and holds nothing; its force
    is the contact's, the tissue pushing it up), and the task's own: ``depth`` and ``horizontal_distance`` (m),
    ``press_steps``, ``inclusion_centre`` and ``inclusion_size`` (m), ``indentation_stiffness`` (N/m),
    ``apparent_modulus`` (Pa), ``inclusion_ratio``, ``probe_radius`` (m).

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/Palpation-v0", inclusion_ratio=10.0, max_step=0.004)
    ```

    Vectorised: ``gym.make_vec("tissue_env/Palpation-v0", num_envs=16,
    vectorization_mode="vector_entry_point")`` steps the copies together in one batched physics
    step (``PalpationVectorEnv``, same keywords, spaces, rewards and infos; ``tissue_env.vector``).

    Task keywords: ``inclusion_ratio``, ``probe_radius`` (m, default 0.009), ``probe_tip``
    ("sphere", default, or "flat"), ``probe_sampling`` ("projected", default, or "node"),
    ``inclusion_size`` (m, a number or (x, y, z), default (0.012, 0.01, 0.012): the inclusion box),
    ``cell_size`` (m, a number or (x, y, z), default (0.012, 0.01, 0.012): the candidate lattice's
    cells),
    ``inclusion_ratio_range`` (None or (low, high): a ratio drawn per reset, the model is rebuilt;
    the episode's ratio is ``info["inclusion_ratio"]``), ``inclusion_size_range`` (see Domain
    randomisation), ``difficulty``,
    ``inclusion_region`` (None or ((x0, z0), (x1, z1)): fractions of the top face that hold the
    candidate inclusion centres; the candidates are the 1.2 cm cells of the top face whose centre
    lies in it, whatever the ``shape``: at the default size, centres at fractions 0.1, 0.3, 0.5, 0.7,
    0.9 in x and z),
    ``max_depth`` (m), ``success_depth`` (m), ``success_radius`` (m), ``hold_steps``,
    ``start_distance`` (m), ``success_bonus``,
    ``time_penalty``, ``force_limit`` (N at E = 5 kPa, scaled by E / 5 kPa), ``force_weight``, ``map_depth`` (m), ``explore_bonus``,
    ``approach_weight``; shared
    keywords in
    ``tissue_env.base.TissueEnv``.

    ## Version History

    - v0: the version of the first release (its changes before it: CHANGELOG.md).
    """

    worlds_class = PalpationWorlds
    #: Chosen by measurement (benchmarks/material_range.py, issue 42): with the contact set solved
    #: within each step, the scripted sweep succeeds on at least 2 of 3 seeds at every E in
    #: 1 kPa-1 MPa and nu in 0.3-0.49 with it, and on none at nu 0.49 from 5 kPa up with "baudet",
    #: whose volume force (sign(r) r^2 times 100 K, physics.md section 4) has no stiffness at rest: a
    #: step's linearisation misses it, and the first held press read 1.9x its equilibrium at 100 kPa.
    default_model = "baudet-hyperelastic"
    default_shape = (10, 5, 10)
    default_size = (0.06, 0.03, 0.06)
    default_dt = 0.04
    default_solver_tolerance = 1e-2
    default_max_step = 0.004
    min_shape = (3, 2, 3)
    #: The default cells (x, y, z) of the candidate lattice, m (keyword ``cell_size``): the elements
    #: of a 5 x 3 x 5 mesh, as physical boxes, so that ``shape`` does not move the candidates (see
    #: ``_setup_scene``).
    default_cell_size = (0.012, 0.01, 0.012)
    reward_names = ("success", "explore", "approach", "time", "force", "volume", "strain")
    #: A drawn slab (``size_range``) keeps the ``size`` slab's candidate lattice, scaled with it
    #: (``_candidate_centres``), and gets its own surface projection (``_place_scene``).
    randomised_parameters = dict(young_modulus="young_modulus_range", poisson_ratio="poisson_ratio_range",
                                 density="density_range", size="size_range", inclusion_ratio="inclusion_ratio_range",
                                 inclusion_size="inclusion_size_range", probe_radius="probe_radius_range")
    episode_keywords = ("inclusion_region",)
    summary = ("indent a {default_size:cm} slab with a probe (random start, at least {start_distance:cm} from the "
               "inclusion) and find a {inclusion_ratio:x} stiffer inclusion; the observation carries the agent's own "
               "palpation map (apparent modulus of the latest press on each candidate cell)")
    success_summary = ("probe at least {success_depth:mm} deep, within {success_radius:cm} of the inclusion "
                       "horizontally, held for {hold_steps} steps")
    #: Start height of the probe tip above the undeformed surface, m.
    clearance = 0.002
    #: The default camera (``TissueEnv.default_camera``): above the slab and in front, the probe's side.
    camera_target = (0.5, 0.9, 0.5)
    camera_direction = (0.3, 1.0, 0.9)
    camera_distance = 2.0

    #: The difficulty levels' keywords (``difficulty``; keywords passed explicitly override them):
    #: the inclusion's contrast (stiffness ratio) and size (m), how near its centre a press counts
    #: (m), how long it is held (steps), how far from it the probe starts (m).
    DIFFICULTY = dict(
        easy=dict(inclusion_ratio=20.0, inclusion_size=(0.012, 0.01, 0.012), success_radius=0.015, hold_steps=2,
                  start_distance=0.01, terminate_on_success=True),
        default=dict(inclusion_ratio=10.0, inclusion_size=(0.012, 0.01, 0.012), success_radius=0.01, hold_steps=3,
                     start_distance=0.02, terminate_on_success=True),
        hard=dict(inclusion_ratio=4.0, inclusion_size=(0.008, 0.008, 0.008), success_radius=0.007, hold_steps=5,
                  start_distance=0.03, terminate_on_success=True),
    )

    def __init__(self, *, inclusion_ratio=None, inclusion_ratio_range=None, inclusion_size_range=None,
                 inclusion_region=None, probe_radius=0.009,
                 probe_tip="sphere", probe_sampling="projected", inclusion_size=None, max_depth=0.008, success_depth=0.005, success_radius=None,
                 hold_steps=None, start_distance=None, success_bonus=10.0, time_penalty=0.05, force_limit=2.0, force_weight=1.0, map_depth=0.004,
                 explore_bonus=0.5, approach_weight=1.0, difficulty="default", probe_radius_range=None, cell_size=None,
                 **kwargs):
        settings = difficulty_settings(self.DIFFICULTY, difficulty, dict(
            inclusion_ratio=inclusion_ratio, inclusion_size=inclusion_size, success_radius=success_radius,
            hold_steps=hold_steps, start_distance=start_distance))
        inclusion_ratio, inclusion_size, success_radius, hold_steps, start_distance = (
            settings[name] for name in ("inclusion_ratio", "inclusion_size", "success_radius", "hold_steps",
                                        "start_distance"))
        self.inclusion_ratio = positive_scalar("inclusion_ratio", inclusion_ratio)
        self.inclusion_ratio_range = check_range("inclusion_ratio_range", inclusion_ratio_range, positive_scalar)
        self.inclusion_region = None if inclusion_region is None else check_region("inclusion_region", inclusion_region, "xz")
        self.probe_radius = positive_scalar("probe_radius", probe_radius, "m")
        self.probe_radius_range = check_range("probe_radius_range", probe_radius_range,
                                              lambda name, value: positive_scalar(name, value, "m"))
        self.episode_probe_radius = self.probe_radius
        if probe_tip not in contact.TIPS:
            raise ValueError(f"probe_tip must be one of {contact.TIPS}, got {probe_tip!r}")
        self.probe_tip = probe_tip
        if probe_sampling not in contact.SAMPLINGS:
            raise ValueError(f"probe_sampling must be one of {contact.SAMPLINGS}, got {probe_sampling!r}")
        self.probe_sampling = probe_sampling
        #: the probe as a contact obstacle (``sim_core.solvers.contact.Probe``; projected on the mesh's top
        #: face in ``_setup_scene``)
        self.probe = contact.Probe(self.probe_radius, probe_tip)
        self.inclusion_size = check_vector("inclusion_size", inclusion_size)
        #: (3,) the candidate lattice's cells, m
        self.cell_size = check_vector("cell_size", self.default_cell_size if cell_size is None else cell_size)
        self.inclusion_size_range = check_vector_range("inclusion_size_range", inclusion_size_range)
        self.episode_inclusion_size = self.inclusion_size.copy()
        self.max_depth = positive_scalar("max_depth", max_depth, "m")
        self.success_depth = positive_scalar("success_depth", success_depth, "m")
        self.success_radius = positive_scalar("success_radius", success_radius, "m")
        if isinstance(hold_steps, bool) or not float(hold_steps).is_integer() or int(hold_steps) < 1:
            raise ValueError(f"hold_steps must be an integer >= 1, got {hold_steps!r}")
        self.hold_steps = int(hold_steps)
        self.start_distance = nonnegative_scalar("start_distance", start_distance)
        self.success_bonus = nonnegative_scalar("success_bonus", success_bonus)
        self.time_penalty = nonnegative_scalar("time_penalty", time_penalty)
        self.force_limit = positive_scalar("force_limit", force_limit, "N")
        self.force_weight = nonnegative_scalar("force_weight", force_weight)
        self.map_depth = positive_scalar("map_depth", map_depth, "m")
        self.explore_bonus = nonnegative_scalar("explore_bonus", explore_bonus)
        self.approach_weight = nonnegative_scalar("approach_weight", approach_weight)
        super().__init__(difficulty=difficulty, **kwargs)

    # -- scene ---------------------------------------------------------------------------------------
    def _setup_scene(self):
        nodes = self.mesh.nodes
        self.fixed_nodes = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))
        self.top_nodes = np.flatnonzero(np.isclose(nodes[:, 1], self.size[1]))
        self.top_y = float(self.size[1])
        self.tool_nodes = np.zeros(0, dtype=int)
        #: (n,) bool: the nodes the probe may touch (the top face) and those it holds now
        self._probe_candidates = np.zeros(self.mesh.n_nodes, bool)
        self._probe_candidates[self.top_nodes] = True
        self.contact = np.zeros(self.mesh.n_nodes, bool)
        #: (n,) node heights at the episode's start (equilibrium under gravity; the rest heights
        #: until the first reset), m: the surface the indentation is measured from
        self.start_heights = nodes[:, 1].copy()
        # Candidate inclusion cells: a lattice of cell_size cells over the slab (whole cells, centred
        # on the top face, layers counted down from the surface; at the default size, the elements of
        # a 5 x 3 x 5 mesh), the cells of its second layer under the surface: the interior ones by
        # default, else those whose centre lies in inclusion_region. Physical, whatever the shape.
        nx, ny, nz = self._lattice_count = np.floor(self.size / self.cell_size + 1e-9).astype(int)
        if nx < 3 or ny < 2 or nz < 3:
            raise ValueError(f"size {self.size.tolist()} m is too small for the palpation scene: it needs at least "
                             f"3 x 2 x 3 candidate cells of {self.cell_size.tolist()} m")
        first = 0 if self.inclusion_region is not None else 1
        i, k = np.meshgrid(np.arange(first, nx - first), np.arange(first, nz - first), indexing="ij")
        #: (C, 3) int lattice indices (i, j, k) of the candidate cells (the element indices of a
        #: 5 x 3 x 5 mesh at the default size)
        self.inclusion_cells = np.stack([i.ravel(), np.full(i.size, ny - 2), k.ravel()], axis=1)
        if self.inclusion_region is not None:
            centres = self._candidate_centres(self.size)
            fraction = centres[:, [0, 2]] / self.size[[0, 2]]
            low, high = self.inclusion_region
            inside = np.all((fraction >= low - 1e-9) & (fraction <= high + 1e-9), axis=1)
            if not inside.any():
                raise ValueError(f"inclusion_region {self.inclusion_region.tolist()} holds no candidate centre (the "
                                 f"{nx} x {nz} cells of {self.cell_size[0]} x {self.cell_size[2]} m across the top "
                                 f"face, centres at fractions {np.unique(fraction[:, 0]).round(3).tolist()} in x and "
                                 f"{np.unique(fraction[:, 1]).round(3).tolist()} in z)")
            self.inclusion_cells = self.inclusion_cells[inside]
        self._place_scene(nodes)
        self._place_probe(np.array([self.centre[0], self.top_y + self.clearance, self.centre[2]]))
        # The inclusion: each element stiffened by the share of its volume inside the inclusion_size
        # box around the candidate centre (C, n_elements), so that the inclusion's size and place
        # do not depend on where the mesh's nodes fall.
        #: (C, n_elements) each candidate inclusion's share of each element's volume on the ``size``
        #: slab (a drawn slab's are computed with its model)
        self.inclusion_shares = np.stack([self._inclusion_shares(self.mesh, centre, self.inclusion_size)
                                          for centre in self.inclusion_centres])
        #: (C, n_elements) bool: the elements each candidate inclusion stiffens (wholly or partly)
        self.inclusion_elements = self.inclusion_shares > 0

    def _place_scene(self, nodes):
        """The episode slab's geometry (``size``'s at construction, a ``size_range`` draw's at each
        reset): the top face's height, the probe's surface projection on its mesh, the workspace
        and the candidate cells' centres (the ``size`` slab's lattice scaled with the slab: the
        palpation map keeps its cells)."""
        super()._place_scene(nodes)
        size = np.asarray(self.episode_size, dtype=float)
        self.top_y = float(size[1])
        if self.probe_sampling == "projected":
            self.probe = contact.Probe(self.episode_probe_radius, self.probe_tip,
                                       contact.SurfaceProjection.top_face(self.episode_mesh, self.top_nodes))
        # The workspace is fixed in space: the tip between 10 mm above and max_depth below the
        # surface, the axis over the central 80 % of the top face. ``workspace_low/high`` (what
        # the base class clips ``tool_offset`` to) are relative to the episode's probe start.
        half, centre = 0.4 * size, 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))
        self.workspace_box = (
            np.array([centre[0] - half[0], self.top_y - self.max_depth, centre[2] - half[2]]),
            np.array([centre[0] + half[0], self.top_y + 0.01, centre[2] + half[2]]),
        )
        #: (C, 3) the candidate cells' centres on the episode's slab, m: the candidate inclusion
        #: centres, and (C, 2) their horizontal (x, z): the palpation map's cells
        self.inclusion_centres = self._candidate_centres(size)
        self.cell_centres = self.inclusion_centres[:, [0, 2]]

    def _candidate_centres(self, size):
        """(C, 3) centres (m) of the candidate cells on a slab of extent ``size`` (3,) m: the lattice
        of ``cell_size`` cells on the ``size`` slab, each cell scaled with the slab (cells of
        cell_size x size / ``size``): whole cells centred on the top face in x and z, layers counted
        from the surface."""
        size = np.asarray(size, dtype=float)
        cell = self.cell_size if np.array_equal(size, self.size) else self.cell_size * size / self.size
        offset = 0.5 * (size - self._lattice_count * cell)  # centred in x and z
        offset[1] = size[1] - self._lattice_count[1] * cell[1]  # layers counted from the surface
        return (self.inclusion_cells + 0.5) * cell + offset

    @staticmethod
    def _inclusion_shares(mesh, centre, size):
        """(n_elements,) the share of each element's volume inside the inclusion box of ``size``
        (3,) m around ``centre`` (3,) m."""
        return mesh.box_shares(centre - 0.5 * np.asarray(size), centre + 0.5 * np.asarray(size))

    def _place_probe(self, start):
        self.probe_start = start
        self.workspace_low = self.workspace_box[0] - start
        self.workspace_high = self.workspace_box[1] - start

    def _default_task_key(self):
        # (candidate index, stiffness ratio, size (m) or None for inclusion_size) of the inclusion:
        # the element stiffnesses follow from its box's shares, what the model depends on
        return (len(self.inclusion_cells) // 2, self.inclusion_ratio, None)

    def _material(self, young_modulus, poisson_ratio, task_key, density, mesh, size):
        index, ratio, box = task_key
        if box is None and np.array_equal(size, self.size):  # the inclusion_size box on the size slab
            shares = self.inclusion_shares[index]
        else:  # a drawn box (inclusion_size_range) or slab (size_range): the box around its candidate centre
            shares = self._inclusion_shares(mesh, self._candidate_centres(size)[index],
                                            self.inclusion_size if box is None else box)
        young = float(young_modulus) * (1.0 + (ratio - 1.0) * shares)
        return Material(young, poisson_ratio, density)

    def _task_feature_sizes(self):
        return dict(depth=1, contact_nodes=1, indentation_stiffness=1, hold_progress=1,
                    palpation_map=len(self.cell_centres), stiffest_offset=2, unprobed_offset=2)

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        index = int(self.np_random.integers(len(self.inclusion_cells)))
        ratio = self.inclusion_ratio
        if self.inclusion_ratio_range is not None:
            ratio = float(self.np_random.uniform(*self.inclusion_ratio_range))
        size = None
        if self.inclusion_size_range is not None:
            size = tuple(float(v) for v in self.np_random.uniform(*self.inclusion_size_range))
        self.inclusion_index, self.episode_inclusion_ratio = index, ratio
        self.episode_inclusion_size = self.inclusion_size.copy() if size is None else np.array(size)
        self.inclusion_cell = self.inclusion_cells[index].copy()
        self.task_key = (index, ratio, size)
        self.inclusion_centre = self.inclusion_centres[index].copy()
        # Probe start: uniform over the workspace among the points at least start_distance from
        # the inclusion (32 draws at once: a fixed number of random numbers per reset).
        low, high = self.workspace_box[0][[0, 2]], self.workspace_box[1][[0, 2]]
        draws = self.np_random.uniform(low, high, size=(32, 2))
        distance = np.hypot(*(draws - self.inclusion_centre[[0, 2]]).T)
        far = np.flatnonzero(distance >= self.start_distance)
        x, z = draws[far[0] if len(far) else int(np.argmax(distance))]
        self._place_probe(np.array([x, self.top_y + self.clearance, z]))
        self.contact = np.zeros(self.mesh.n_nodes, bool)
        self.press_steps = 0
        self.palpation_map = np.zeros(len(self.cell_centres))
        if self.probe_radius_range is not None:  # drawn last: the other draws are those without it
            self.episode_probe_radius = float(self.np_random.uniform(*self.probe_radius_range))
            self.probe = contact.Probe(self.episode_probe_radius, self.probe_tip, self.probe.projection)

    def _start_hook(self):
        self._sweep = None
        self.start_heights = self.state.positions[:, 1].copy()
        if self.probe.projection is not None:
            # (the reset's control, made before, holds no contact either way: the probe starts
            # ``clearance`` above the rest surface, where every bound is +inf)
            self.probe = contact.Probe(self.episode_probe_radius, self.probe_tip,
                                       self.probe.projection.with_reference(self.start_heights))

    def start_surface(self, tips, heights, spacing=None):
        """Height (m) of the start surface under each tip: bilinear in the top nodes' start
        ``heights`` ((n,) or (N, n) m) at the tips' rest (x, z) ((N, 3) m), on a slab of element
        ``spacing`` ((3,) or (N, 3) m; default the episode slab's)."""
        nx, ny, nz = self.mesh.shape
        spacing = np.broadcast_to(self.episode_mesh.spacing if spacing is None else spacing, (len(tips), 3))
        u = np.clip(tips[:, 0] / spacing[:, 0], 0.0, nx)
        w = np.clip(tips[:, 2] / spacing[:, 2], 0.0, nz)
        i, k = np.minimum(u.astype(int), nx - 1), np.minimum(w.astype(int), nz - 1)
        fu, fw = u - i, w - k
        rows = np.arange(len(tips))
        heights = np.broadcast_to(heights, (len(tips), self.mesh.n_nodes))
        corner = lambda a, b: heights[rows, self.mesh.node_index(i + a, ny, k + b)]  # noqa: E731
        return ((1 - fu) * (1 - fw) * corner(0, 0) + fu * (1 - fw) * corner(1, 0) + (1 - fu) * fw * corner(0, 1)
                + fu * fw * corner(1, 1))

    def _tip(self):
        return self.probe_start + self.tool_offset

    def _start_control(self):
        """The attached bottom face: the probe starts ``clearance`` above the surface, touching nothing."""
        self.start_tool_mask = np.zeros((self.mesh.n_nodes, 3), bool)
        return self.base_control.copy()

    @property
    def contact_nodes(self):
        """Indices of the top nodes the probe holds."""
        return np.flatnonzero(self.contact)

    # -- scripted sweep ------------------------------------------------------------------------------
    def scripted_action(self, probe_depth=0.004, settle_steps=1):
        """A sweep: press ``probe_depth`` into the tissue (below the start surface, which a soft
        slab's weight sags: 3.4 mm at its centre at 1 kPa, nu 0.3, where a press 4 mm under the
        undeformed surface went 0.6 mm into it and read nothing of the inclusion) over each candidate
        cell centre (a serpentine from the end nearest the start), hold it ``settle_steps`` and until
        its reading moves less than 5% in a step (at most 3 steps more), record the apparent modulus (what the
        palpation map records), then move over the stiffest one at the surface, press
        ``success_depth`` + 1 mm there and hold it."""
        self._require_reset("scripted_action()")
        if self._sweep is None:
            centres = self.cell_centres.copy()
            rows = np.unique(centres[:, 0], return_inverse=True)[1]
            order = np.concatenate([
                np.flatnonzero(rows == r)[np.argsort(centres[rows == r, 1])[::-1 if r % 2 else 1]]
                for r in range(rows.max() + 1)])
            start = self._tip()[[0, 2]]
            if np.hypot(*(centres[order[-1]] - start)) < np.hypot(*(centres[order[0]] - start)):
                order = order[::-1]
            # stiffness is kept in the order of inclusion_cells; ``order`` is the visiting order
            self._sweep = dict(centres=centres, order=order, index=0, phase="move", stiffness=np.zeros(len(centres)))
        sweep = self._sweep
        tip = self._tip()
        surface = self.top_y
        if sweep["index"] < len(sweep["order"]):
            cell = sweep["order"][sweep["index"]]
            goal_xz = sweep["centres"][cell]
            # the press's height: probe_depth under the start surface there, inside the workspace
            pressed = max(float(self.start_surface(np.array([[goal_xz[0], surface, goal_xz[1]]]),
                                                   self.start_heights)[0]) - probe_depth, surface - self.max_depth)
            # settled: the reading moved less than 5% in the last step (or held settle_steps + 3)
            reading = float(self.measures["apparent_modulus"])
            settled = (abs(reading - sweep.get("last", np.inf)) <= 0.05 * reading
                       or sweep.get("held", 0) >= settle_steps + 3)
            if sweep["phase"] == "move":
                sweep["last"] = np.inf
                goal = np.array([goal_xz[0], surface, goal_xz[1]])
                if np.allclose(tip[[0, 2]], goal_xz, atol=1e-6) and tip[1] >= surface - 1e-6:
                    sweep["phase"] = "press"
                    goal = np.array([goal_xz[0], pressed, goal_xz[1]])
            elif tip[1] > pressed + 1e-6 or sweep.setdefault("held", 0) < settle_steps or not settled:
                # pressing, then held ``settle_steps`` and until the reading settles: the tissue
                # catches up with the probe (soft tissue is slow: at 1 kPa a press held one 40 ms
                # step after the inclusion's read the next cell 1.25x its equilibrium)
                sweep["held"] = sweep.get("held", 0) + (tip[1] <= pressed + 1e-6)
                sweep["last"] = reading
                goal = np.array([goal_xz[0], pressed, goal_xz[1]])
            else:  # pressed: record and go on
                sweep["held"] = 0
                sweep["stiffness"][cell] = self.measures["apparent_modulus"]
                sweep["index"] += 1
                sweep["phase"] = "move"
                goal = np.array([tip[0], surface, tip[2]])
        else:
            best = sweep["centres"][int(np.argmax(sweep["stiffness"]))]
            goal = np.array([best[0], surface - self.success_depth - 0.001, best[1]])
            if not np.allclose(tip[[0, 2]], best, atol=1e-6):
                # over it at the surface first, as the sweep moves: pressed on the way, the probe
                # ploughed through the tissue (111 N at E = 100 kPa, nu 0.49, 14x a held press)
                goal[1] = surface
        return np.clip((goal - tip) / self.max_step, -1.0, 1.0).astype(np.float32)

    @property
    def render_scale(self) -> float:
        """The probe pushes the tissue down by at most ``max_depth`` (it slides over the rest of its
        workspace): the displacement of full colour in the frames (m)."""
        return float(self.max_depth)

    def _markers(self):
        return dict(tool=self._tip(), inclusion=np.array([self.inclusion_centre[0], self.top_y, self.inclusion_centre[2]]))


class PalpationVectorEnv(TissueVectorEnv):
    """N copies of Palpation-v0 stepped together (``tissue_env.vector``): built by
    ``gym.make_vec("tissue_env/Palpation-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    Same keywords, spaces, rewards and infos as the single env (see ``PalpationEnv``)."""

    env_class = PalpationEnv
