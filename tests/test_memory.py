"""Bounded memory: caches with byte budgets, and models freed as soon as nothing uses them.

The long soak (10^5 steps per task, RSS after warm-up within 15%) is a benchmark
(``benchmarks/memory_soak.py``); these tests check the mechanisms it relies on.
"""

import gc
import pickle
import weakref

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401
from sim_core import caches
from sim_core.caches import BudgetCache, cache_budget, cache_usage, nbytes, set_cache_budget
from tissue_env.base import MODEL_CACHE_SIZE


@pytest.fixture
def budget():
    """Restore the "static_factors" budget after a test changes it."""
    before = cache_budget("static_factors")
    yield
    set_cache_budget("static_factors", before)


def test_nbytes_counts_each_buffer_once():
    array = np.zeros(1000)
    assert nbytes(array) == 8000
    assert nbytes((array, array, [array])) == 8000  # one buffer, referred to three times
    assert nbytes({"a": np.zeros(10), "b": array[:10]}) == 80 + 8000  # a view of array counts array


def test_budget_cache_drops_least_recently_used_past_its_bytes(budget):
    set_cache_budget("static_factors", 10_000)
    cache = BudgetCache("static_factors")
    for key in range(5):
        cache.put(key, np.zeros(500))  # 4000 bytes each: two fit
    assert len(cache) == 2 and 3 in cache and 4 in cache
    assert cache.nbytes == 8000 <= cache.budget
    cache.get(3)  # 3 is now the most recently used: 4 goes first
    cache.put(5, np.zeros(500))
    assert 3 in cache and 5 in cache and 4 not in cache


def test_budget_cache_keeps_the_newest_entry_even_past_its_budget(budget):
    set_cache_budget("static_factors", 100)
    cache = BudgetCache("static_factors")
    cache.put("big", np.zeros(1000))
    assert "big" in cache and cache.get("big").size == 1000
    cache.put("bigger", np.zeros(2000))
    assert len(cache) == 1 and "bigger" in cache


def test_budget_cache_entry_limit_and_empty_copies():
    cache = BudgetCache("models", max_entries=3)
    for key in range(6):
        cache.put(key, key)
    assert len(cache) == 3 and [cache.get(k) for k in (3, 4, 5)] == [3, 4, 5]
    copy = pickle.loads(pickle.dumps(cache))
    assert len(copy) == 0 and copy.kind == "models" and copy.max_entries == 3


def test_set_cache_budget_trims_live_caches_and_is_reported(budget):
    cache = BudgetCache("static_factors")
    for key in range(4):
        cache.put(key, np.zeros(1000))
    set_cache_budget("static_factors", 16_000)
    assert len(cache) == 2
    usage = cache_usage()["static_factors"]
    assert usage["budget"] == 16_000 and usage["entries"] >= 2 and usage["bytes"] >= 16_000


@pytest.mark.parametrize("kind, value", [("nothing", 1), ("models", -1), ("models", 1.5), ("models", True)])
def test_set_cache_budget_rejects_bad_input(kind, value):
    with pytest.raises(ValueError, match="kind must be one of|budget_bytes must be"):
        set_cache_budget(kind, value)


def test_default_budgets_are_documented():
    for kind, value in caches.DEFAULT_BUDGETS.items():
        assert f'``"{kind}"``' in caches.__doc__ and f"{value >> 20} MiB" in caches.__doc__


def test_evicted_models_are_freed_without_a_garbage_collection():
    """Domain randomisation draws a new model every episode. Past the model cache's size each
    evicted model must be freed by reference counting alone: a reference cycle through a model
    (its derived data referring back to it) kept every one alive, with its factorisations, until a
    full collection, which numpy's memory does not trigger (RSS grew by GBs per hour)."""
    env = gym.make("tissue_env/TumorPositioning-v0", young_modulus_range=(3e3, 3e4))
    env.reset(seed=0)
    refs = []
    gc.collect()
    gc.disable()
    try:
        for _ in range(MODEL_CACHE_SIZE + 6):
            env.reset()
            env.step(env.action_space.sample())
            refs.append(weakref.ref(env.unwrapped.model))
        alive = sum(ref() is not None for ref in refs)
    finally:
        gc.enable()
    # the cache's MODEL_CACHE_SIZE models, plus the default model built at construction if drawn again
    assert alive <= MODEL_CACHE_SIZE
    assert refs[0]() is None
    env.close()


def test_a_model_is_measured_with_its_derived_data(budget):
    """A model's bytes include the data the solvers derive from it (here a static solve's); a
    factor cache's bytes are its factors'."""
    from sim_core import HexMesh, Material, build_model, solve_static
    from sim_core.solvers.static import FactorCache

    mesh = HexMesh.block((4, 4, 4), 0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1000.0), gravity=(0, -9.81, 0))
    bare = nbytes(model)
    assert bare >= model.stiffness.nbytes + model.mesh.nodes.nbytes + model.mass.nbytes
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control = model.new_control().impose(bottom, mesh.nodes[bottom])
    factors = FactorCache()
    solve_static(model, control.impose([int(np.argmax(mesh.nodes[:, 1]))], [[0.02, 0.045, 0.02]]), cache=factors)
    assert nbytes(model) > bare  # free-dof structures, pattern arrays
    # the entry: the tangent (CSR) and its LU, at least the LU's L and U entries
    assert factors.nbytes > 12 * 3 * mesh.n_nodes
    set_cache_budget("static_factors", 0)
    assert len(factors) == 1  # the newest entry stays
