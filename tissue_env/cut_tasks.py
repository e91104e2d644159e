"""The shape the blade tasks share (Incision-v0, Dissection-v0): their env and their worlds.

``BladeTaskWorlds`` is the ``CuttingWorlds`` (``tissue_env.blade``) of a task scored by the share of
a set of faces cut (``progress``), the faces it must spare (``damage``) and a route: the path of the
blade, from its start over to where the cut begins and then along the cut, that the task's
surgeon follows. A task gives ``route`` (the length, m, of what remains of that path from a blade
place, given the faces cut so far, and the point it heads to) and its own bookkeeping of a cut
(``_cut_made``); this class gives the rewards every blade task has:

- ``reward_progress = progress_weight * (gain in progress this step)``;
- ``reward_approach = approach_weight * (R_before - R_after) / 1 cm``, R the route's remaining
  length before the step's move and cut and after them: shaping by the route as a potential
  (its sum over an episode is the route's net shortening; undiscounted, so it leaves the ranking
  of policies unchanged only for a discount of 1, with a small pull towards short routes below
  it), the term that lets an agent learn to follow the route before the first face is cut;
- ``reward_damage = -damage_weight * (faces of the spared tissue cut this step)``;
- ``reward_success = success_bonus`` on success;

and the features ``cut_progress``, ``damage`` and ``route_offset`` (the route's next point from
the blade, cm). ``BladeTaskEnv`` is the env's share: the reward weights' keywords, the features, the
stiffness of the task's layer, the spare node rows, the tool marker, the scripted
controller's step towards a goal. SI units.
"""

from __future__ import annotations

import numpy as np

from sim_core import Material

from .base import nonnegative_scalar
from .blade import CornerCamera, CuttingWorlds, spare_node_rows

#: The reward weights every blade task takes (keyword: default): the progress earned by the whole
#: cut, the approach per cm of route, the penalty per face of spared tissue cut, the success bonus.
BLADE_WEIGHTS = dict(progress_weight=10.0, approach_weight=1.0, damage_weight=2.0, success_bonus=5.0)
#: The features every blade task appends to its own (name: size).
BLADE_FEATURES = dict(cut_progress=1, damage=1, route_offset=3)


def difficulty_levels(keyword, easy, default, hard) -> dict:
    """A blade task's ``DIFFICULTY`` table: one keyword's value per level (episodes end on success)."""
    return {level: {keyword: value, "terminate_on_success": True}
            for level, value in (("easy", easy), ("default", default), ("hard", hard))}


class BladeTaskWorlds(CuttingWorlds):
    """The worlds of a blade task (see the module docstring). A task implements ``route``,
    ``_cut_made`` (calling this class's), ``_task_reward_terms`` and ``_blade_task_features``;
    ``task_weights`` names its env's further reward weights, copied onto the worlds."""

    task_weights = ()

    def __init__(self, envs, threads=1):
        super().__init__(envs, threads)
        env, count = self.task, self.num_envs
        self._block_fixed = np.repeat(env.base_control.fixed[None], count, axis=0)
        self._block_target = np.repeat(env.base_control.target[None], count, axis=0)
        self._controls = None  # the controls on the worlds' node rows, until a cut or a reset
        self.progress = np.zeros(count)
        self.progress_gain = np.zeros(count)  # this step's
        self.damage = np.zeros(count, dtype=int)  # faces of the spared tissue cut so far
        self.damage_step = np.zeros(count, dtype=int)
        self.route_before = np.zeros(count)  # m, the route's remaining length before this step's move
        for name in (*BLADE_WEIGHTS, *self.task_weights):
            setattr(self, name, getattr(env, name))

    def route(self, offsets):
        """(remaining (N,) m, next point (N, 3) m) of the route of each world's blade at tool offsets
        (N, 3) m, given the faces cut so far."""
        raise NotImplementedError

    def _load_task(self, index, env):
        super()._load_task(index, env)
        self._controls = None
        self.progress[index] = self.progress_gain[index] = 0.0
        self.damage[index] = self.damage_step[index] = 0

    def _tool_moved(self, previous, active):
        self.progress_gain[active] = 0.0
        self.damage_step[active] = 0
        self.route_before = self.route(previous)[0]  # before the cut (a world that did not move: no change)
        super()._tool_moved(previous, active)

    def _cut_made(self, index, faces, progress, damage):
        """World ``index`` was cut along ``faces`` this step, reaching ``progress`` and cutting ``damage``
        faces of the spared tissue (a task's ``_cut_made`` computes them and calls this)."""
        self._controls = None
        self.progress_gain[index] = progress - self.progress[index]
        self.progress[index] = progress
        self.damage_step[index] = damage
        self.damage[index] += damage

    def _tool_position(self, positions):
        return self.tip_rest + self.tool_offset

    def _task_measures(self, positions):
        remaining, point = self.route(self.tool_offset)
        return dict(route_remaining=remaining, route_offset=point - (self.tip_rest + self.tool_offset))

    def _task_features(self, measures):
        features = self._blade_task_features(measures)
        features.update(cut_progress=self.progress[:, None], damage=self.damage[:, None].astype(float),
                        route_offset=measures["route_offset"] / self.length_scale)
        return features

    def _blade_task_features(self, measures) -> dict:
        """The task's own features (name -> (N, size)), before ``BLADE_FEATURES``."""
        raise NotImplementedError

    def _reward_terms(self, measures):
        terms = dict(
            progress=self.progress_weight * self.progress_gain,
            approach=self.approach_weight * (self.route_before - measures["route_remaining"]) / 0.01,
            damage=-self.damage_weight * self.damage_step,
            success=np.where(self._is_success(measures), self.success_bonus, 0.0),
        )
        terms.update(self._task_reward_terms(measures))
        terms.update(self._damage_terms(measures))
        return terms

    def _task_reward_terms(self, measures) -> dict:
        """The task's own reward terms (name -> (N,))."""
        raise NotImplementedError

    def _task_info(self, measures):
        info = super()._task_info(measures)
        info.update(cut_progress=self.progress.copy(), route_remaining=np.array(measures["route_remaining"]))
        return info


class BladeTaskEnv(CornerCamera):
    """The env's share of a blade task (before ``TissueEnv`` in its bases): the reward weights of
    ``BLADE_WEIGHTS`` as keywords (``_blade_keywords``), the features (``task_features``, then
    ``BLADE_FEATURES``), the material (the episode's Young's modulus, times ``layer_ratio_keyword``'s
    value on the task's layer), the spare node rows and the scripted step."""

    #: the slab of both tasks: 5 x 2 x 3 cm of 5 mm hexahedra
    default_shape = (10, 4, 6)
    default_size = (0.05, 0.02, 0.03)
    default_max_step = 0.0025
    randomised_parameters = dict(young_modulus="young_modulus_range", poisson_ratio="poisson_ratio_range",
                                 density="density_range")

    def _blade_keywords(self, weights, spare_nodes):
        """Check and keep the reward weights (name -> value, None: the default) and ``spare_nodes``."""
        for name, value in weights.items():
            setattr(self, name, nonnegative_scalar(name, BLADE_WEIGHTS.get(name) if value is None else value))
        self._spare_nodes = spare_nodes

    def _spare_rows(self, default):
        """Set ``spare_nodes`` from the keyword (``default`` node rows when None)."""
        self.spare_nodes = spare_node_rows(self._spare_nodes, default)

    #: the task's own features (name: size), before ``BLADE_FEATURES``
    task_features = {}
    #: the keyword of the stiffness ratio of the task's layer (``layer_elements``, (M,) bool, set by
    #: its scene): that layer's Young's modulus over the rest's
    layer_ratio_keyword = None

    def _task_feature_sizes(self):
        return {**self.task_features, **BLADE_FEATURES}

    def _material(self, young_modulus, poisson_ratio, task_key, density, mesh, size):
        ratio = getattr(self, self.layer_ratio_keyword)
        return Material(float(young_modulus) * np.where(self.layer_elements, ratio, 1.0), poisson_ratio, density)

    def _towards(self, goal, tip):
        """The action that moves the blade from ``tip`` towards ``goal`` (3,) m, at most ``max_step`` per axis."""
        return np.clip((goal - tip) / self.max_step, -1.0, 1.0).astype(np.float32)

    def _markers(self):
        return dict(tool=self.tip_rest + self.tool_offset)
