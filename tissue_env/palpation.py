"""Palpation-v0: find a stiff inclusion hidden in soft tissue by indenting the surface with a probe."""

from __future__ import annotations

import numpy as np

from sim_core import Material
from sim_core.model import Control

from .base import TissueEnv, nonnegative_scalar, positive_scalar


class PalpationEnv(TissueEnv):
    """
    ## Description

    A slab of liver-like tissue (6 x 3 x 6 cm, 5 x 3 x 5 hexahedra of 1.2 x 1 x 1.2 cm, Baudet
    mass-spring model of ``sim_core``, gravity on) is attached to the body by its bottom face. One
    element of the middle layer (1 cm under the surface) is a tumour ``inclusion_ratio`` (default 10)
    times stiffer than the tissue (per-element Young's modulus). A flat-ended cylindrical probe of
    radius ``probe_radius`` (default 0.75 element) indents the top surface: every top-surface node
    under the probe that would lie above its tip is held at the tip height (frictionless projection
    contact, only the vertical component is imposed). The agent sees the probe position and the
    reaction force and must press at least 5 mm deep within 1 cm (horizontally) of the inclusion:
    what a surgeon does when palpating a liver for a tumour.

    Physics: one implicit Euler step of ``dt`` = 20 ms per env step (see ``tissue_env.base``).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: probe displacement increment, scaled by ``max_step`` (default
    4 mm) and clipped to the workspace (the probe axis stays over the central 80 % of the top face;
    the tip between 10 mm above and ``max_depth`` (default 8 mm) below the undeformed surface).

    | Num | Action                     | Min | Max | Unit         |
    |-----|----------------------------|-----|-----|--------------|
    | 0   | probe increment along x    | -1  | 1   | max_step (m) |
    | 1   | probe increment along y    | -1  | 1   | max_step (m) |
    | 2   | probe increment along z    | -1  | 1   | max_step (m) |

    ## Observation Space

    ``observation_type="state"``: ``Box(-100, 100, (14,), float32)``.

    | Index | Observation                                        | Unit (normalised)     |
    |-------|----------------------------------------------------|-----------------------|
    | 0-2   | probe tip position                                 | cm from block centre  |
    | 3-5   | probe displacement from its start                  | cm                    |
    | 6-8   | force the probe exerts on the tissue               | 0.1 N                 |
    | 9     | relative volume change (V - V0) / V0               | %                     |
    | 10    | maximum spring strain abs(L - L0) / L0             | %                     |
    | 11    | indentation depth below the undeformed surface     | cm (negative above)   |
    | 12    | number of surface nodes in contact                 | count                 |
    | 13    | indentation stiffness, vertical force / depth      | N/m / 100 (0 if none) |

    ``"deformation"`` appends the surface-node displacements (cm); ``"dict"`` gives the features
    as a ``Dict`` keyed by name. The inclusion position is not observed.

    ## Rewards

    ``r = reward_success + reward_time + reward_force + reward_volume + reward_strain
    (+ reward_instability)``:

    - ``reward_success = success_bonus`` (default 10) on success, else 0
    - ``reward_time = -time_penalty`` (default 0.05) per step
    - ``reward_force = -force_weight * max(0, |F| - force_limit) / force_limit`` (defaults 1, 1 N)
    - ``reward_volume``, ``reward_strain`` as in every task (``tissue_env.base``), and
      ``reward_instability = -instability_penalty`` on a diverging step.

    ## Starting State

    The slab at static equilibrium under gravity; the probe tip 2 mm above the undeformed surface
    over the centre of the top face. The inclusion is one of the interior elements of the layer
    under the top layer, drawn uniformly (9 positions at the defaults).

    ## Episode End

    Terminated on success (tip at least ``success_depth`` = 5 mm below the undeformed surface with
    its axis within ``success_radius`` = 1 cm of the inclusion centre) or on divergence
    (``info["unstable"]``). Truncated after 100 steps.

    ## Arguments

    ```python
    import gymnasium as gym
    import tissue_env
    env = gym.make("tissue_env/Palpation-v0", inclusion_ratio=10.0, max_step=0.004)
    ```

    Task keywords: ``inclusion_ratio``, ``probe_radius`` (m, default 0.75 element width),
    ``max_depth`` (m), ``success_depth`` (m), ``success_radius`` (m), ``success_bonus``,
    ``time_penalty``, ``force_limit`` (N), ``force_weight``; shared keywords in
    ``tissue_env.base.TissueEnv``.

    ## Version History

    - v0: initial version.
    """

    default_shape = (5, 3, 5)
    default_size = (0.06, 0.03, 0.06)
    default_max_step = 0.004
    min_shape = (3, 2, 3)
    reward_names = ("success", "time", "force", "volume", "strain")
    #: Start height of the probe tip above the undeformed surface, m.
    clearance = 0.002

    def __init__(self, *, inclusion_ratio=10.0, probe_radius=None, max_depth=0.008, success_depth=0.005,
                 success_radius=0.01, success_bonus=10.0, time_penalty=0.05, force_limit=1.0, force_weight=1.0,
                 **kwargs):
        self.inclusion_ratio = positive_scalar("inclusion_ratio", inclusion_ratio)
        self.probe_radius = None if probe_radius is None else positive_scalar("probe_radius", probe_radius, "m")
        self.max_depth = positive_scalar("max_depth", max_depth, "m")
        self.success_depth = positive_scalar("success_depth", success_depth, "m")
        self.success_radius = positive_scalar("success_radius", success_radius, "m")
        self.success_bonus = nonnegative_scalar("success_bonus", success_bonus)
        self.time_penalty = nonnegative_scalar("time_penalty", time_penalty)
        self.force_limit = positive_scalar("force_limit", force_limit, "N")
        self.force_weight = nonnegative_scalar("force_weight", force_weight)
        super().__init__(**kwargs)

    # -- scene ---------------------------------------------------------------------------------------
    def _setup_scene(self):
        nodes = self.mesh.nodes
        nx, ny, nz = self.shape
        self.fixed_nodes = np.flatnonzero(np.isclose(nodes[:, 1], 0.0))
        self.top_nodes = np.flatnonzero(np.isclose(nodes[:, 1], self.size[1]))
        self.top_y = float(self.size[1])
        if self.probe_radius is None:
            self.probe_radius = 0.75 * float(min(self.spacing[0], self.spacing[2]))
        self.tool_nodes = np.zeros(0, dtype=int)
        self.probe_start = np.array([self.centre[0], self.top_y + self.clearance, self.centre[2]])
        self.base_control = Control.free(self.mesh.n_nodes).impose(self.fixed_nodes, nodes[self.fixed_nodes])
        half = 0.4 * self.size
        self.workspace_low = np.array([-half[0], -self.clearance - self.max_depth, -half[2]])
        self.workspace_high = np.array([half[0], 0.01 - self.clearance, half[2]])
        # Candidate inclusion cells: interior elements (i, k) of the layer under the top layer.
        i, k = np.meshgrid(np.arange(1, nx - 1), np.arange(1, nz - 1), indexing="ij")
        self.inclusion_cells = np.stack([i.ravel(), np.full(i.size, ny - 2), k.ravel()], axis=1)

    def _default_task_key(self):
        return tuple(int(c) for c in self.inclusion_cells[len(self.inclusion_cells) // 2])

    def _material(self, young_modulus, poisson_ratio, task_key):
        nx, ny, _ = self.shape
        i, j, k = task_key
        young = np.full(self.mesh.n_elements, float(young_modulus))
        young[i + nx * (j + ny * k)] *= self.inclusion_ratio
        return Material(young, poisson_ratio, self.density)

    def _task_feature_sizes(self):
        return dict(depth=1, contact_nodes=1, indentation_stiffness=1)

    # -- episode -------------------------------------------------------------------------------------
    def _reset_task(self, options):
        cell = self.inclusion_cells[self.np_random.integers(len(self.inclusion_cells))]
        self.task_key = tuple(int(c) for c in cell)
        self.inclusion_centre = (np.asarray(cell) + 0.5) * self.spacing
        self.contact_nodes = np.zeros(0, dtype=int)

    def _start_hook(self):
        self._sweep = None

    def _tip(self):
        return self.probe_start + self.tool_offset

    def _control(self):
        tip = self._tip()
        current = self.mesh.nodes if self.state is None else self.state.positions
        top = current[self.top_nodes]
        horizontal = np.hypot(top[:, 0] - tip[0], top[:, 2] - tip[2])
        touching = (horizontal <= self.probe_radius) & (top[:, 1] >= tip[1])
        self.contact_nodes = self.top_nodes[touching]
        control = self.base_control.copy()
        if len(self.contact_nodes):
            target = current[self.contact_nodes].copy()
            target[:, 1] = tip[1]
            control.impose(self.contact_nodes, target, components=(1,))
        self.tool_mask = np.zeros((self.mesh.n_nodes, 3), bool)
        self.tool_mask[self.contact_nodes, 1] = True
        return control

    def _tool_position(self, positions):
        return self._tip()

    def _task_measures(self, positions):
        tip = self._tip()
        depth = self.top_y - tip[1]
        return dict(depth=depth, horizontal_distance=float(np.hypot(*(tip - self.inclusion_centre)[[0, 2]])))

    def _measure(self, state):
        measures = super()._measure(state)
        pushing = -measures["reaction_force"][1]  # downward force of the probe, N
        depth = measures["depth"]
        measures["indentation_stiffness"] = pushing / depth if depth > 1e-4 and len(self.contact_nodes) else 0.0
        return measures

    def _task_features(self, measures):
        return dict(depth=[measures["depth"] / self.length_scale], contact_nodes=[len(self.contact_nodes)],
                    indentation_stiffness=[measures["indentation_stiffness"] / 100.0])

    def _task_info(self, measures):
        return dict(depth=measures["depth"], horizontal_distance=measures["horizontal_distance"],
                    inclusion_centre=self.inclusion_centre.copy(), indentation_stiffness=measures["indentation_stiffness"])

    def _is_success(self, measures):
        return measures["depth"] >= self.success_depth - 1e-9 and measures["horizontal_distance"] <= self.success_radius

    def _reward_terms(self, measures):
        force = float(np.linalg.norm(measures["reaction_force"]))
        terms = dict(
            success=self.success_bonus if self._is_success(measures) else 0.0,
            time=-self.time_penalty,
            force=-self.force_weight * max(0.0, force - self.force_limit) / self.force_limit,
        )
        terms.update(self._damage_terms(measures))
        return terms

    # -- scripted sweep ------------------------------------------------------------------------------
    def scripted_action(self, probe_depth=0.003):
        """A sweep: press ``probe_depth`` over each candidate cell centre, record the indentation
        stiffness, then press ``success_depth`` + 1 mm over the stiffest one."""
        if self._sweep is None:
            centres = (self.inclusion_cells[:, [0, 2]] + 0.5) * self.spacing[[0, 2]]
            self._sweep = dict(centres=centres, index=0, phase="move", stiffness=np.zeros(len(centres)))
        sweep = self._sweep
        tip = self._tip()
        surface = self.top_y
        if sweep["index"] < len(sweep["centres"]):
            goal_xz = sweep["centres"][sweep["index"]]
            if sweep["phase"] == "move":
                goal = np.array([goal_xz[0], surface, goal_xz[1]])
                if np.allclose(tip[[0, 2]], goal_xz, atol=1e-6) and tip[1] >= surface - 1e-6:
                    sweep["phase"] = "press"
                    goal = np.array([goal_xz[0], surface - probe_depth, goal_xz[1]])
            else:  # pressed: record and go on
                sweep["stiffness"][sweep["index"]] = self.measures["indentation_stiffness"]
                sweep["index"] += 1
                sweep["phase"] = "move"
                goal = np.array([tip[0], surface, tip[2]])
        else:
            best = sweep["centres"][int(np.argmax(sweep["stiffness"]))]
            goal = np.array([best[0], surface - self.success_depth - 0.001, best[1]])
        return np.clip((goal - tip) / self.max_step, -1.0, 1.0).astype(np.float32)

    def _markers(self):
        return dict(tool=self._tip(), inclusion=np.array([self.inclusion_centre[0], self.top_y, self.inclusion_centre[2]]))
