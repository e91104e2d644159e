"""solve_static's FactorCache (reused start tangent) and chord/Anderson options; TumorPositioning's goal solve."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401  (registers the ids)
from sim_core import solve_static
from sim_core.solvers.static import FactorCache
from tissue_env.tumor_positioning import GOAL_SOLVER


def _goal_problem(displacement=(0.006, 0.004, -0.008), **kwargs):
    env = gym.make("tissue_env/TumorPositioning-v0", **kwargs).unwrapped
    env.reset(seed=0)
    control = env.base_control.copy().impose(env.tool_nodes, env.tool_rest + np.asarray(displacement))
    return env, control, env.state.positions.copy()


def test_cache_hit_gives_the_same_result_bitwise():
    env, control, start = _goal_problem()
    plain = solve_static(env.model, control, initial=start, tolerance=1e-8)
    cache = FactorCache()
    first = solve_static(env.model, control, initial=start, tolerance=1e-8, cache=cache)
    second = solve_static(env.model, control, initial=start.copy(), tolerance=1e-8, cache=cache)
    assert cache.misses == 1 and cache.hits == 1
    assert np.array_equal(plain.positions, first.positions)
    assert np.array_equal(plain.positions, second.positions)
    assert plain.iterations == second.iterations


def test_cache_keys_on_model_fixed_pattern_and_positions():
    env, control, start = _goal_problem()
    cache = FactorCache(size=2)
    solve_static(env.model, control, initial=start, cache=cache)
    other = env.base_control.copy().impose(env.tool_nodes[:1], env.tool_rest[:1] + 0.005)  # other fixed dofs
    solve_static(env.model, other, initial=start, cache=cache)
    moved = start.copy()
    moved[0, 0] += 1e-12  # other linearisation state
    solve_static(env.model, control, initial=moved, cache=cache)
    assert cache.hits == 0 and cache.misses == 3
    solve_static(env.model, control, initial=moved, cache=cache)  # the newest entry is kept
    assert cache.hits == 1 and cache.misses == 3
    clone = pickle.loads(pickle.dumps(cache))  # copies start empty
    solve_static(env.model, control, initial=moved, cache=clone)
    assert clone.hits == 0 and clone.misses == 1 and clone.size == 2
    solve_static(env.model, control, initial=start, cache=cache)  # least recently used: dropped
    assert cache.hits == 1 and cache.misses == 4


def test_chord_and_anderson_converge_within_tolerance():
    env, control, start = _goal_problem()
    reference = solve_static(env.model, control, initial=start, tolerance=1e-10)
    for options in ({}, dict(chord_contraction=0.7), GOAL_SOLVER, dict(chord_contraction=0.9, acceleration=5)):
        result = solve_static(env.model, control, initial=start, tolerance=1e-8, cache=FactorCache(), **options)
        assert result.converged and result.residual < 1e-8
        assert np.abs(result.positions - reference.positions).max() < 1e-8


def test_goal_does_not_depend_on_the_cache_state():
    """A warm cache (earlier resets of the same model) gives bitwise the same goals as a cold one,
    and the goals are within 1e-6 m of the plain (no cache, default Newton) solve."""
    warm = gym.make("tissue_env/TumorPositioning-v0").unwrapped
    warm.reset(seed=100)
    for seed in range(1, 6):
        warm.reset(seed=seed)
        cold = gym.make("tissue_env/TumorPositioning-v0").unwrapped
        cold.reset(seed=seed)
        assert np.array_equal(warm.goal, cold.goal)
        control = cold.base_control.copy().impose(cold.tool_nodes, cold.tool_rest + cold.goal_tool_displacement)
        plain = solve_static(cold.model, control, initial=cold.state.positions, tolerance=1e-8)
        goal = cold.tumor_weights @ plain.positions[cold.tumor_nodes]
        assert np.linalg.norm(goal - cold.goal) < 1e-6
    assert warm.goal_factors.hits >= 5
    copy.deepcopy(warm)  # the LU cache does not block copies


def test_goal_tool_displacement_reaches_the_goal_when_a_retry_fails():
    """When the tumour moves less than the minimum goal distance the displacement is scaled up and
    solved again; when that retry does not converge the goal stays the last converged equilibrium,
    and ``goal_tool_displacement`` is that equilibrium's tool displacement. At seed 43 the first
    direction's retry (a larger compression at the workspace corner) fails and leaves its goal
    within success_distance of the tumour (a success at reset): another direction is drawn, whose
    goal is reached, and the reset is no success."""
    env = gym.make("tissue_env/TumorPositioning-v0").unwrapped
    _, info = env.reset(seed=43)
    assert not info["is_success"]
    start = env.state.positions
    control = env.base_control.copy().impose(env.tool_nodes, env.tool_rest + env.goal_tool_displacement)
    plain = solve_static(env.model, control, initial=start, tolerance=1e-8)
    assert plain.converged
    assert np.linalg.norm(env.tumor_weights @ plain.positions[env.tumor_nodes] - env.goal) < 1e-6
    assert np.linalg.norm(env.goal - env.tumor_start) >= env.success_distance


def test_a_failing_goal_retry_gives_up_without_damping_towards_gradient_steps(monkeypatch):
    """A Newton step rejected with a fresh tangent ends the load step (``static._newton``) instead of
    refactorising with the diagonal damping raised x100 at a time: the resets whose goal retry
    fails factorise at most 16 times per goal direction (seed 60: 11, 23 with the escalation).
    Seeds 43 and 72 left their first goals 1.3 and 1.8 mm from the tumour, within success_distance
    (a success at reset): they draw more directions (3 and 2; 27 and 16 factorisations)."""
    from sim_core.solvers import static

    env = gym.make("tissue_env/TumorPositioning-v0").unwrapped
    env.reset(seed=0)
    calls = []
    # the goal solves factorise with scipy's sparse LU (the direct solver, up to
    # static.DIRECT_DOF_LIMIT free dofs; Newton's and the predictor's): count the LU factorisations
    import scipy.sparse.linalg as spla

    assert 3 * env.model.mesh.n_nodes <= static.DIRECT_DOF_LIMIT
    splu = spla.splu
    monkeypatch.setattr(spla, "splu", lambda *args, **kwargs: calls.append(1) or splu(*args, **kwargs))
    counts = {}
    for seed in (43, 60, 72):
        calls.clear()
        _, info = env.reset(seed=seed)
        counts[seed] = len(calls)
        assert not info["is_success"] and np.linalg.norm(env.goal - env.tumor_start) >= env.success_distance
    assert counts[60] <= 16 and counts[72] <= 2 * 16 and counts[43] <= 3 * 16, counts


def test_compiled_tangent_is_the_numpy_tangent():
    """``static.tangent_stiffness`` (the compiled assembly of the implicit step, geometric term not
    clamped) equals ``forces.stiffness_data`` (numpy) to 1e-12 at a deformed state with compressed
    springs, for the full model (projected corrections, volume forces, hourglass control)."""
    from sim_core.models.forces import stiffness_data
    from sim_core.solvers.static import tangent_stiffness

    env, control, start = _goal_problem((0.004, -0.01, 0.006), model="baudet")
    result = solve_static(env.model, control, initial=start, tolerance=1e-6)
    positions = result.positions + np.random.default_rng(0).normal(scale=2e-4, size=start.shape)
    model = env.model
    assert model.correction_mode == "projected" and model.has_volume_forces and model.hourglass is not None
    reference = model.pattern.matrix(stiffness_data(model, positions)).toarray()
    compiled = tangent_stiffness(model, positions).toarray()
    assert np.abs(compiled - reference).max() < 1e-12 * np.abs(reference).max()
    assert (reference < 0).any()  # a tangent with negative entries: the geometric term is not clamped
    with pytest.raises(ValueError, match="positions must be a finite"):
        tangent_stiffness(model, positions[:-1])
    with pytest.raises(ValueError, match="positions must be a finite"):
        tangent_stiffness(model, np.full_like(positions, np.nan))
