"""Snapshots of a task environment's episode (``TissueEnv.get_state`` / ``set_state``).

A snapshot holds what the episode changes: the env's episode attributes (state, tool, goal, random
generator, counters, the task's bookkeeping), its world's (``TaskWorlds``) per-world arrays and its
solver's per-world state (warm start, divergence history, factor bookkeeping). What the episode
only reads is referenced by name (``Ref``) and looked up on the restoring env: its caches, spaces,
mesh, renderer, the world's stacked model, workspaces and solver; the episode's model is named by
its cache key (rebuilt on a miss, checked against the snapshot's digest of it); the solver's
factors are shared in memory and, pickled, replaced by what they were computed from
(``ImplicitEuler.rebuild_factor``: the same floats, computed again at the first restore). Sizes
and rates per task: benchmarks/snapshots.py.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib

import numpy as np

from sim_core.models.model import Model

#: the model's derived-data entries: its model-cache key (``TissueEnv._model``) and its digest
MODEL_KEY = "env_model_key"
_DIGEST = "env_snapshot_digest"

#: The solver attributes a snapshot does not hold: the stacked model, workspaces, kernel
#: structures and scratch, caches by content, and what is derived from the per-world state
#: (the kernels' factor lists and corrections, rebuilt by the solver's ``world_restored``). The
#: solver of a world of its own topology (a cut world: ``own_solver``) is held the same way, its
#: episode attributes (its factors copied), and made again on the restored world's model.
SOLVER_STRUCTURE = frozenset((
    "stack", "monitors", "workspace", "_workspace", "_own", "_prepared", "factory", "_kept_starts", "_kept_first",
    "_first", "_mass", "_linearised", "_groups", "_packed", "_packed_groups", "_group_work", "_no_corrections",
    "_row_work", "_lu_int", "_lu_float", "_factor_of", "_no_correction", "_correction_of", "_corrections", "_imposed",
    "_patterns", "_structures", "_incidence", "_hg_positions", "_values", "symmetric"))
#: The divergence monitors' attributes that are the block's, not the episode's.
MONITOR_STRUCTURE = frozenset(("count", "threads", "elements", "frames"))
#: The solver's lists of per-world factors (shared, pickled as their sources).
FACTOR_LISTS = ("_factors", "_preconditioners")
_ATOMS = (type(None), bool, int, float, complex, str, bytes, np.generic)


@dataclasses.dataclass(frozen=True, eq=False)
class Ref:
    """Stands in a snapshot for an object the restoring env has its own of: ``("self",)`` the env,
    ``("env", name)`` / ``("worlds", name)`` an attribute of it or of its world, ``("model", key)``
    / ``("model", key, name)`` a model of its model cache or one of its arrays, ``("factor", i)``
    entry i of the snapshot's factors."""

    path: tuple


@dataclasses.dataclass(frozen=True)
class FactorSource:
    """A factor in a pickled snapshot: what it was computed from (``ImplicitEuler.rebuild_factor``)."""

    source: tuple


class _Memo(dict):
    """A ``copy.deepcopy`` memo that records which of its entries were used."""

    def __init__(self, *args):
        super().__init__(*args)
        self.used = set()

    def get(self, key, default=None):
        value = super().get(key, default)
        if isinstance(value, Ref):
            self.used.add(value)
        return value


@dataclasses.dataclass(frozen=True, eq=False)
class EpisodeState:
    """A snapshot of one environment's episode (``TissueEnv.get_state``): restored by ``set_state``
    on an environment of the same class and keywords (this one, another one, or one in another
    process after pickling), the next steps are those the environment took after the snapshot, bit
    for bit. See the module docstring for what it holds."""

    env_class: type
    #: the keywords the snapshot depends on (``TissueEnv._snapshot_settings``)
    settings: tuple
    #: the model-cache key of the episode's model (None: a model not from the cache)
    model_key: object
    #: model-cache key -> digest of every model the snapshot refers to
    models: dict
    #: (the env's, the world's, the solver's, its divergence monitors') episode attributes
    payload: tuple
    #: the ``Ref`` in ``payload``
    references: tuple
    #: the solver's factors (``Ref(("factor", i))``); a pickled snapshot holds their sources instead,
    #: computed again at its first restore
    factors: list

    def __getstate__(self):
        state = dict(self.__dict__)
        state["factors"] = [FactorSource(factor.source) if getattr(factor, "source", None) is not None else factor
                            for factor in self.factors]
        return state


def model_digest(model: Model) -> bytes:
    """A 16-byte digest of a model's arrays (kept in its derived data: computed once per model)."""

    def build():
        digest = hashlib.blake2b(digest_size=16)
        arrays = [model.mesh.nodes, model.mesh.elements]
        arrays += [getattr(model, field.name) for field in dataclasses.fields(model)]
        if model.stress_correction is not None:
            arrays += [value for value in vars(model.stress_correction).values() if isinstance(value, np.ndarray)]
        for array in arrays:
            if isinstance(array, np.ndarray):
                digest.update(np.ascontiguousarray(array).view(np.uint8))
        return digest.digest()

    return model.derived.get(_DIGEST, build)


def _solver_factors(integrator) -> list:
    return [factor for name in FACTOR_LISTS for factor in getattr(integrator, name, ()) if factor is not None]


def _episode_of(integrator):
    """(the solver's episode attributes, its divergence monitors'): what a snapshot holds of it."""
    solver = {name: value for name, value in vars(integrator).items() if name not in SOLVER_STRUCTURE}
    monitors = {}
    if hasattr(integrator, "monitors"):
        monitors = {name: value for name, value in vars(integrator.monitors).items() if name not in MONITOR_STRUCTURE}
    return solver, monitors


def _restore_episode(integrator, solver, monitors):
    integrator.__dict__.update(solver)
    if monitors:
        integrator.monitors.__dict__.update(monitors)


def capture(env) -> EpisodeState:
    """The snapshot of ``env``'s episode (``TissueEnv.get_state``)."""
    worlds = env._worlds
    memo = _Memo({id(env): Ref(("self",))})
    shared = env.shared_names()
    for name in shared:
        value = getattr(env, name, None)
        if not isinstance(value, _ATOMS):
            memo[id(value)] = Ref(("env", name))
    models = {model.derived.peek(MODEL_KEY): model for model in env.model_cache.values() + [env.model]}
    models.pop(None, None)
    for key, model in models.items():
        for name, value in vars(model).items():
            if not isinstance(value, _ATOMS):
                memo[id(value)] = Ref(("model", key, name))
        memo[id(model)] = Ref(("model", key))
    attributes = {name: value for name, value in env.__dict__.items() if name not in shared and name != "_worlds"}
    world, solver, monitors, own, factors = {}, {}, {}, {}, []
    if worlds is not None:
        memo[id(worlds)] = Ref(("worlds",))
        for name in worlds.structure:
            value = getattr(worlds, name, None)
            if not isinstance(value, _ATOMS):
                memo[id(value)] = Ref(("worlds", name))
        world = {name: value for name, value in vars(worlds).items() if name not in worlds.structure}
        integrator = worlds.integrator
        for factor in _solver_factors(integrator):
            if id(factor) not in memo:
                memo[id(factor)] = Ref(("factor", len(factors)))
                factors.append(factor)
        solver, monitors = _episode_of(integrator)
        for index in getattr(integrator, "own_worlds", list)():
            own[index] = _episode_of(integrator.own_solver(index))
    payload = copy.deepcopy((attributes, world, solver, monitors, own), memo)
    model_key = env.model.derived.peek(MODEL_KEY)
    digests = {key: model_digest(models[key]) for key in
               {reference.path[1] for reference in memo.used if reference.path[0] == "model"} | {model_key}}
    return EpisodeState(type(env), env._snapshot_settings(), model_key, digests, payload, tuple(memo.used), factors)


def restore(env, state: EpisodeState):
    """Return ``env`` to the snapshot ``state`` (``TissueEnv.set_state``)."""
    if not isinstance(state, EpisodeState) or state.env_class is not type(env):
        raise ValueError(f"set_state takes a snapshot from get_state() of a {type(env).__name__}, got "
                         f"{type(state).__name__ if not isinstance(state, EpisodeState) else state.env_class.__name__}")
    settings = env._snapshot_settings()
    if state.settings != settings:
        different = [f"{name}={theirs!r} (this env: {ours!r})" for (name, theirs), (_, ours)
                     in zip(state.settings, settings) if theirs != ours]
        raise ValueError(f"the snapshot is of a {type(env).__name__} with other keywords: {', '.join(different)}; "
                         "set_state restores a snapshot on an env of the same task and keywords")
    models = {}
    for key, digest in state.models.items():
        model = env._model_of_key(key)
        if model_digest(model) != digest:
            raise ValueError(f"the snapshot's model of material key {key} differs from the one this "
                             f"{type(env).__name__} builds for it (an env with other material keywords?); set_state "
                             "restores a snapshot on an env of the same task and keywords")
        models[key] = model
    world = state.payload[1]
    if world and env._worlds is None:
        env._worlds = env.worlds_class([env], threads=1)
    worlds = env._worlds
    if world:
        worlds.stack.assign(0, models[state.model_key])
    factors = state.factors
    for index, factor in enumerate(factors):
        if isinstance(factor, FactorSource):
            # computed once per unpickled snapshot: later restores share it
            factors[index] = worlds.integrator.rebuild_factor(0, factor.source)
    memo = {}
    for reference in state.references:
        kind, *path = reference.path
        if kind == "self":
            value = env
        elif kind == "env":
            value = getattr(env, path[0])
        elif kind == "worlds":
            value = worlds if not path else getattr(worlds, path[0])
        elif kind == "model":
            value = models[path[0]] if len(path) == 1 else getattr(models[path[0]], path[1])
        else:
            value = factors[path[0]]
        memo[id(reference)] = value
    attributes, world, solver, monitors, own = copy.deepcopy(state.payload, memo)
    env.__dict__.update(attributes)
    if not world:
        return
    worlds.__dict__.update(world)
    worlds.restored(0)  # a cut world's model back (its own topology)
    integrator = worlds.integrator
    _restore_episode(integrator, solver, monitors)
    for index, (own_solver, own_monitors) in own.items():  # a cut world's solver, made again on its model
        one = integrator.own_solver(index)
        _restore_episode(one, own_solver, own_monitors)
        one.world_restored(0)
    if hasattr(integrator, "world_restored"):  # its derived state (the packed preconditioner), as at the snapshot
        integrator.world_restored(0)


