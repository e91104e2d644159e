"""Batched vector envs: registered as vector_entry_point, the same episodes and trajectories as
gymnasium's SyncVectorEnv over single envs (the single env is the one-world case of the same
``TaskWorlds``), next-step autoreset, infos as dicts of arrays, divergence per copy."""

import gymnasium as gym
import numba
import numpy as np
import pytest
import scipy.sparse.linalg as spla
from gymnasium.vector import AutoresetMode

import tissue_env
from sim_core.models.sparse import NodeBlockLU

VECTOR_IDS = sorted(tissue_env.VECTOR_ENTRY_POINTS)


def make_pair(env_id, num_envs, **kwargs):
    vector = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="sync", **kwargs)
    return vector, sync


def assert_infos_match(vector_info, sync_info, atol, rtol=1e-5):
    assert set(vector_info) == set(sync_info)
    for key, expected in sync_info.items():
        actual = vector_info[key]
        assert actual.shape == expected.shape and actual.dtype == expected.dtype, key
        if expected.dtype == object:
            assert [a is None for a in actual] == [e is None for e in expected], key
        else:
            np.testing.assert_allclose(actual, expected, atol=atol, rtol=rtol, err_msg=key)


def run_side_by_side(vector, sync, steps, seed, obs_atol, reward_atol, info_atol, action_scale=1.2, obs_rtol=1e-5,
                     info_rtol=1e-5, also=()):
    """Step ``vector`` (and each vector env of ``also``) and ``sync`` with the same random actions,
    comparing each step's results; returns the number of episode ends of ``vector``."""
    rng = np.random.default_rng(seed)
    sync_obs, sync_info = sync.reset(seed=seed)
    for envs in (vector, *also):
        vector_obs, vector_info = envs.reset(seed=seed)
        np.testing.assert_array_equal(vector_obs, sync_obs)
        assert_infos_match(vector_info, sync_info, 0.0)
    done = 0
    for _ in range(steps):
        actions = rng.uniform(-action_scale, action_scale, vector.action_space.shape).astype(np.float32)
        s = sync.step(actions)
        for envs in (vector, *also):
            v = envs.step(actions)
            np.testing.assert_allclose(v[0], s[0], atol=obs_atol, rtol=obs_rtol)
            np.testing.assert_allclose(v[1], s[1], atol=reward_atol, rtol=0)
            np.testing.assert_array_equal(v[2], s[2])
            np.testing.assert_array_equal(v[3], s[3])
            assert_infos_match(v[4], s[4], info_atol, info_rtol)
        done += int(np.sum(s[2] | s[3]))
    return done


@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_make_vec_uses_the_vector_entry_point(env_id):
    vector, sync = make_pair(env_id, 3)
    assert isinstance(vector.unwrapped, tissue_env.TissueVectorEnv)
    assert vector.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vector.single_observation_space == sync.single_observation_space
    assert vector.observation_space == sync.observation_space and vector.action_space == sync.action_space
    vector.close()
    sync.close()


@pytest.mark.parametrize("env_id", VECTOR_IDS)
@pytest.mark.parametrize("tolerance", [None, 1e-9], ids=["default settings", "tight solves"])
@pytest.mark.parametrize("model", ["baudet", "baudet-hyperelastic"])
def test_a_copy_equals_the_single_env_with_the_same_seed_and_actions(env_id, tolerance, model):
    """A vector copy and the single env take the same steps bit for bit (observations, rewards,
    episode ends and infos), over 26 random steps of 4 copies whose short episodes (8 steps) cover
    truncation and the next-step autoreset; at the default solver tolerance as at a tight one, for
    both models: a world's floats do not depend on the other worlds, nor on which pass (stacked,
    per copy on numba's threads) computed them, nor on the number of threads (Baudet's model at the
    default settings: a one-thread vector env too)."""
    kwargs = {} if tolerance is None else dict(solver_tolerance=tolerance)
    if model != "baudet":
        kwargs["model"] = model
    vector, sync = make_pair(env_id, 4, max_episode_steps=8, **kwargs)
    also = []
    if model == "baudet" and tolerance is None and numba.config.NUMBA_NUM_THREADS >= 2:
        # the vector env runs its copies on all of numba's threads (the default); one on a single
        # thread takes the same steps bit for bit too, resets included: 1 and several threads give
        # the same trajectories (``kernels.factor_copies``, ``kernels.solve_copies_lu``: per-copy
        # scratch). This replaced a test that compared 1 and 2 threads over 40 steps of their own.
        assert vector.unwrapped.threads >= 2
        also.append(gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", threads=1,
                                 max_episode_steps=8, **kwargs))
        assert also[0].unwrapped.threads == 1
    # truncations at steps 8, 17 and 26 (steps 9 and 18 autoreset): bitwise equality holds from the
    # first step, so more steps per episode add time, not coverage
    done = run_side_by_side(vector, sync, steps=26, seed=5, obs_atol=0.0, reward_atol=0.0, info_atol=0.0,
                            obs_rtol=0.0, info_rtol=0.0, also=also)
    assert done >= 8  # every copy truncated (and was autoreset) at least twice
    for envs in also:
        envs.close()
    vector.close()
    sync.close()


@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_dict_observations_and_reset_mask(env_id):
    vector, sync = make_pair(env_id, 3, observation_type="dict", solver_tolerance=1e-9)
    vector_obs, _ = vector.reset(seed=[3, 4, 5])
    sync_obs, _ = sync.reset(seed=[3, 4, 5])
    actions = np.full(vector.action_space.shape, 0.5, np.float32)
    v_obs = vector.step(actions)[0]
    s_obs = sync.step(actions)[0]
    for name in s_obs:
        np.testing.assert_allclose(v_obs[name], s_obs[name], atol=2e-4, rtol=0)
    mask = np.array([False, True, False])
    v_obs, v_info = vector.reset(seed=[0, 9, 0], options={"reset_mask": mask})
    s_obs, s_info = sync.reset(seed=[0, 9, 0], options={"reset_mask": mask})
    for name in s_obs:
        np.testing.assert_allclose(v_obs[name], s_obs[name], atol=2e-4, rtol=0)
    assert list(v_info["_is_success"]) == [False, True, False]
    vector.close()
    sync.close()


@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_actions_checked_clipped_and_fresh_arrays(env_id):
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    clipped = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    obs, _ = vector.reset(seed=0)
    clipped.reset(seed=0)
    shape = vector.action_space.shape  # (2, 3 per tool [+ grasp commands])
    bad = np.zeros(shape, np.float32)
    bad[0, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        vector.step(bad)
    with pytest.raises(ValueError, match="shape"):
        vector.step(np.zeros(3 if shape[1] != 3 else 4, np.float32))
    big = np.resize([[5.0, -7.0, 3.0], [0.2, 9.0, -0.3]], shape)
    first = vector.step(big)
    second = clipped.step(np.clip(big, -1, 1))
    np.testing.assert_array_equal(first[0], second[0])
    assert not np.shares_memory(first[0], obs)
    again = vector.step(np.zeros(shape))
    assert not np.shares_memory(again[0], first[0])
    vector.close()
    clipped.close()


@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_divergence_ends_only_that_episode_and_autoresets(env_id):
    # the explicit integrator far past its stability limit (about 1 ms) diverges in every copy,
    # each detected on its own; the next step autoresets it
    vector = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", integrator="explicit",
                          dt=0.05, instability_penalty=7.0)
    vector.reset(seed=0)
    unstable = np.zeros(3, dtype=bool)
    for _ in range(30):
        obs, reward, terminated, truncated, info = vector.step(np.ones(vector.action_space.shape, np.float32))
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward))
        newly = info["unstable"]
        assert np.all(terminated[newly]) and np.all(reward[newly] == -7.0)
        assert all(isinstance(reason, str) for reason in info["unstable_reason"][newly])
        if unstable.any():
            break
        unstable |= newly
    assert unstable.any()
    # the step after: those copies were reset (reward 0, not unstable)
    assert np.all(reward[unstable] == 0.0) and not np.any(info["unstable"][unstable])
    vector.close()


@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_render_rgb_array(env_id):
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", render_mode="rgb_array")
    vector.reset(seed=0)
    vector.step(np.ones(vector.action_space.shape, np.float32))
    frames = vector.render()
    assert len(frames) == 2 and frames[0].dtype == np.uint8 and frames[0].shape == frames[1].shape
    vector.close()


def test_invalid_num_envs():
    with pytest.raises(ValueError, match="num_envs"):
        tissue_env.TumorPositioningVectorEnv(num_envs=0)


@pytest.mark.parametrize("solver", ["factorised", "reference"])
def test_every_per_copy_solver_gives_the_single_env_trajectories(solver):
    """Each of the implicit step's per-copy linear solvers (``preconditioner`` keyword;
    sim_core.solvers.implicit) gives a copy the single env's steps, on Palpation, whose probe contact changes
    the imposed dofs during an episode (the factorised solver keeps or re-factorises a copy's factor
    when its free set changes): observations within 1e-6. (Solver "jacobi" runs the copies in
    lockstep with the copy index innermost, where the compiler vectorises across copies: a copy's
    floats depend on the copy count, and Palpation's contact decisions amplify the rounding.)"""
    vector, sync = make_pair("tissue_env/Palpation-v0", 3, preconditioner=solver, max_episode_steps=15)
    assert vector.unwrapped.worlds.integrator.preconditioner == solver
    run_side_by_side(vector, sync, steps=25, seed=3, obs_atol=1e-6, reward_atol=1e-6, info_atol=1e-7, obs_rtol=0.0,
                     info_rtol=1e-4)
    vector.close()
    sync.close()


def test_scalar_fallback_factor_solves_the_system(monkeypatch):
    """Where the node-block LU fails (forced here), a copy gets SuperLU's scalar factor of its
    free-dof matrix, packed for the compiled solves: applied by kernels.lu_apply it equals
    spsolve's solution (to 1e-8), and the steps stay finite."""
    from sim_core import kernels
    import sim_core.solvers.implicit as implicit

    monkeypatch.setattr(implicit, "node_block_factor", lambda model, values, free, **kwargs: None)
    # the fused factorisations (kernels.factor_copies) fail too: every copy takes _factorise's path
    monkeypatch.setattr(implicit.ImplicitEuler, "_block_structure", lambda self, key, nodes: None)
    vector = gym.make_vec("tissue_env/Palpation-v0", num_envs=2, vectorization_mode="vector_entry_point")
    vector.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(10):
        observations, *_ = vector.step(rng.uniform(-1, 1, (2, 3)))
        assert np.all(np.isfinite(observations))
    integrator = vector.unwrapped.worlds.integrator
    factor = integrator._factors[0]
    assert integrator.preconditioner == "factorised" and factor.ints[0] > 0  # a scalar factor
    k = int(factor.ints[0])  # packed: ..., gather (k), free (k), perm_c (k)
    free = factor.ints[len(factor.ints) - 2 * k:len(factor.ints) - k]
    values = integrator._values.copy()  # the last factorisation's matrix, in the model's pattern
    factor = integrator._scalar_factor(values, np.isin(np.arange(3 * vector.unwrapped.worlds.n_nodes), free))
    pattern = implicit.FreeStructure(vector.unwrapped.worlds.stack.reference, free)
    matrix = implicit.sp.csc_matrix((values[pattern.take], pattern.indices, pattern.indptr), shape=pattern.shape)
    vector_in = rng.normal(size=3 * vector.unwrapped.worlds.n_nodes)
    mask = np.zeros(3 * vector.unwrapped.worlds.n_nodes)
    mask[free] = 1.0
    out = np.empty_like(vector_in)
    kernels.lu_apply(factor.ints, factor.floats, mask, vector_in * mask, out, np.empty(k))
    expected = spla.spsolve(matrix.tocsc(), vector_in[free])
    np.testing.assert_allclose(out[free], expected, rtol=1e-8, atol=1e-12 * np.abs(expected).max())
    vector.close()


def test_copies_share_models_and_caches():
    """The batched env's copies are built from the same keywords: one model (and start state, first
    goal factor cache) serves them all instead of one per copy."""
    vector = gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=3, vectorization_mode="vector_entry_point")
    first, *others = vector.unwrapped.envs
    assert others
    for copy in others:
        assert copy.model is first.model
        assert copy.model_cache is first.model_cache
        assert copy.goal_factors is first.goal_factors
    vector.close()


@pytest.mark.parametrize("layout", ["node blocks", "scalar"])
def test_reference_preconditioner_solves_each_group_with_its_factor(layout, monkeypatch):
    """Solver "reference": the copies that start alike share one sparse LU (one group), and the
    lockstep solves (kernels.solve_copies_grouped) apply each group's factor to all its copies:
    the exact inverse of the group's system matrix on the free dofs, zero on the imposed ones; a
    re-linearised copy gets a factor of its own. Both factor layouts: node blocks (free dofs are
    whole nodes, TumorPositioning) and the scalar fallback."""
    from sim_core import kernels
    from sim_core.models.forces import stiffness_data
    import sim_core.solvers.implicit as implicit

    if layout == "scalar":
        monkeypatch.setattr(NodeBlockLU, "applies", staticmethod(lambda free: False))
    vector = gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=4, vectorization_mode="vector_entry_point")
    env = vector.unwrapped.worlds
    vector.reset(seed=0)
    integrator = env.integrator
    assert integrator.preconditioner == "reference"
    assert len(integrator._group()) == 1  # the four copies start alike: one factor
    assert (integrator._group()[0][0].ints[0] < 0) == (layout == "node blocks")
    rng = np.random.default_rng(1)
    for _ in range(3):
        vector.step(rng.uniform(-1, 1, (4, 3)))
    fixed, _, _ = env._control()
    copy = env.envs[2]
    integrator._refresh(2, env.positions[2], env.dt, fixed[2])
    groups = integrator._group()
    assert sorted(len(rows) for _, rows in groups) == [1, 3]
    lu_int, lu_float, group_of = integrator._pack_preconditioners()
    dofs = 3 * env.n_nodes
    vectors = rng.normal(size=(dofs, 4))
    mask = np.ascontiguousarray(~fixed.reshape(4, dofs).T, dtype=float)
    free = np.flatnonzero(mask[:, 0])
    assert group_of[0] != group_of[2]
    for index, positions in ((0, copy.state.positions), (2, env.positions[2])):
        # copy 0 still has the start-of-episode factor, copy 2 the one at its current state
        out = np.empty(dofs)
        group = group_of[index]
        kernels.lu_apply(lu_int[group], lu_float[group], np.ascontiguousarray(mask[:, index]),
                         np.ascontiguousarray(vectors[:, index]), out, np.empty(dofs))
        data = stiffness_data(copy.model, positions, volume=False, clamp=True, stiffness_scale=env.dt ** 2,
                              damping_scale=env.dt, mass_scale=1.0)
        matrix = copy.model.pattern.matrix(data).tocsr()[free][:, free].tocsc()
        expected = spla.spsolve(matrix, vectors[free, index])
        np.testing.assert_allclose(out[free], expected, rtol=1e-8, atol=1e-12 * np.abs(expected).max())
        assert np.all(out[mask[:, index] == 0] == 0.0)
    vector.close()


def test_measurement_shares_the_next_steps_force_pass():
    """TumorPositioning's vector env measures with the next implicit step's force pass
    (``ImplicitEuler.linearise`` plus the damping forces): the same nodal forces as a full
    pass with velocities up to rounding, and the step from that state does not compute it again."""
    from sim_core.models.forces import ForceWorkspace

    vector = gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=3, vectorization_mode="vector_entry_point")
    env = vector.unwrapped.worlds
    assert env.share_force_pass
    vector.reset(seed=2)
    rng = np.random.default_rng(2)
    for _ in range(4):
        vector.step(rng.uniform(-1, 1, (3, 3)))
    flat = np.ascontiguousarray(env.positions.reshape(-1, 3))
    measured = env.measures["forces"].reshape(-1, 3)  # the last step's measurement
    full = ForceWorkspace(env.stack.model, implicit=False).compute(
        flat, np.ascontiguousarray(env.velocities.reshape(-1, 3))) + env.stack.model.gravity_force
    np.testing.assert_allclose(measured, full, rtol=0, atol=1e-12 * np.abs(full).max())
    integrator = env.integrator
    forces = integrator.workspace.forces  # the pass's output: a sentinel shows whether a pass runs
    forces[0, 0] = np.inf
    assert integrator.linearise(flat)[0, 0] == np.inf  # the measured state: cached, no second pass
    assert np.isfinite(integrator.linearise(flat + 1e-6)[0, 0])  # another state: a new pass
    vector.close()


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two cores for numba's threads")
def test_threaded_resets_give_the_serial_resets():
    """With more than one thread the copies reset on a thread pool (``TissueVectorEnv._reset_rows``):
    TumorPositioning's copies share one model, its caches and its goal solver's factors, and each
    reset solves a goal. 6 rounds of 16 copies give the serial loop's observations and infos exactly
    (fails when the copies' static solves share one force workspace: 6 runs of 6 caught it)."""
    envs = {threads: gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=16, vectorization_mode="vector_entry_point",
                                  threads=threads) for threads in (1, 2)}
    for seed in range(0, 60, 10):
        (serial, serial_info), (threaded, threaded_info) = (envs[t].reset(seed=seed) for t in (1, 2))
        np.testing.assert_array_equal(serial, threaded)
        np.testing.assert_array_equal(serial_info["goal"], threaded_info["goal"])
    assert envs[2].unwrapped.reset_pool_running and not envs[1].unwrapped.reset_pool_running
    for vector in envs.values():
        vector.close()
    assert not envs[2].unwrapped.reset_pool_running


_FORK_AFTER_RESETS = """
import multiprocessing, numpy as np, gymnasium as gym, tissue_env
envs = gym.make_vec("tissue_env/TumorPositioning-v0", num_envs=3, vectorization_mode="vector_entry_point",
                    threads=2, max_episode_steps=3)
envs.reset(seed=1)
assert envs.unwrapped.reset_pool_running
def child():
    for _ in range(4):
        envs.step(np.zeros((3, 3), np.float32))
    envs.close()
process = multiprocessing.get_context("fork").Process(target=child)
process.start()
process.join(120)
assert process.exitcode == 0, process.exitcode
envs.reset(seed=2)  # the parent's pool restarts
assert envs.unwrapped.reset_pool_running
envs.close()
"""


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two cores for numba's threads")
def test_a_fork_after_threaded_resets_is_clean():
    """The reset pool is stopped before a fork (``os.register_at_fork``): with its idle threads alive,
    CPython's threading failed in the child ("Exception ignored in ... _after_fork ... SystemError",
    the child going on). The child steps its inherited env and closes it; the parent's pool restarts."""
    import subprocess
    import sys
    done = subprocess.run([sys.executable, "-c", _FORK_AFTER_RESETS], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Exception ignored" not in done.stderr and "Error" not in done.stderr, done.stderr


@pytest.mark.parametrize("threads", [0, -1, 1.5, True, 10 ** 6])
def test_invalid_threads(threads):
    with pytest.raises(ValueError, match="threads must be None or an integer from 1 to"):
        gym.make_vec(VECTOR_IDS[0], num_envs=2, vectorization_mode="vector_entry_point", threads=threads)


def test_starting_the_threads_leaves_the_environment_as_it_was(monkeypatch):
    """``kernels.start_threads`` sets GOMP_SPINCOUNT only while numba's pool loads: the variable is
    absent afterwards when it was absent, and a user's own wait policy or spin count is kept."""
    import os

    from sim_core import kernels
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    kernels.start_threads()
    assert "GOMP_SPINCOUNT" not in os.environ and "OMP_WAIT_POLICY" not in os.environ
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    kernels.start_threads()
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE" and "GOMP_SPINCOUNT" not in os.environ
    monkeypatch.delenv("OMP_WAIT_POLICY")
    monkeypatch.setenv("GOMP_SPINCOUNT", "5")
    kernels.start_threads()
    assert os.environ["GOMP_SPINCOUNT"] == "5" and "OMP_WAIT_POLICY" not in os.environ


def _forked_run(queue):
    envs = gym.make_vec("tissue_env/Retraction-v0", num_envs=3, vectorization_mode="vector_entry_point")
    obs, _ = envs.reset(seed=4)
    for _ in range(8):
        obs, *_ = envs.step(np.full((3, 3), 0.5, dtype=np.float32))
    queue.put(obs)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two cores for numba's threads")
def test_a_process_forked_after_the_threads_started_steps_a_vector_env():
    """GNU OpenMP's pool is not fork-safe: numba terminates a forked child that enters a parallel
    region of its parent's pool. A vector env in a forked process uses the serial kernels, and
    steps as the parent's does on one thread (Retraction: factorisations and capacitance-corrected
    solves every step)."""
    import multiprocessing

    envs = gym.make_vec("tissue_env/Retraction-v0", num_envs=3, vectorization_mode="vector_entry_point")
    envs.reset(seed=4)
    envs.step(np.zeros((3, 3), dtype=np.float32))  # the parent's pool runs
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_forked_run, args=(queue,))
    child.start()
    child.join(120)
    assert child.exitcode == 0, f"the forked process ended with {child.exitcode}"
    expected = gym.make_vec("tissue_env/Retraction-v0", num_envs=3, vectorization_mode="vector_entry_point",
                            threads=1)
    obs, _ = expected.reset(seed=4)
    for _ in range(8):
        obs, *_ = expected.step(np.full((3, 3), 0.5, dtype=np.float32))
    np.testing.assert_array_equal(queue.get(timeout=10), obs)


def _copy_zero(env_id, other_seed, steps=150):
    """Copy 0's observations under fixed actions, the other copies' seeds and actions from ``other_seed``."""
    envs = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point")
    mine, others = np.random.default_rng(0), np.random.default_rng(other_seed)
    observations, _ = envs.reset(seed=[7, 8 + other_seed, 9 + other_seed])
    trajectory = [observations[0]]
    for _ in range(steps):
        actions = others.uniform(-1, 1, envs.action_space.shape).astype(np.float32)
        actions[0] = mine.uniform(-1, 1, envs.action_space.shape[1])
        trajectory.append(envs.step(actions)[0][0])
    envs.close()
    return np.array(trajectory)


@pytest.mark.parametrize("env_id", sorted(tissue_env.ENV_IDS))
def test_a_copy_does_not_depend_on_the_other_copies(env_id):
    # A vector env's copies share the factors kept for episodes that start alike; what decides a
    # factor's renewal is each copy's own, and a kept factor counts as the one the first step would
    # make. So a copy's trajectory is bitwise the same whatever the other copies do, and two vector
    # envs (each with its own kept factors) agree.
    # Each run covers copy 0's first episode (registered length) and the start of its second, where
    # it takes a kept factor or makes one: TumorPositioning (50-step episodes, solver "reference")
    # 60 steps, every copy's episode starting from the one kept start factor; Palpation (100) 105
    # steps, a factorisation at each episode's first step; Retraction (60) 70 steps, re-factorised
    # at most steps; LiverNeedleAlignment (50) 60 steps, a refresh at step 42 (150 steps each took
    # 80 s of the suite, and added no other kind of event for copy 0: counted once in the solver).
    # The two runs (two vector envs) differ only in the other copies' seeds and actions: equal
    # trajectories show that copy 0 depends on its own seed and actions alone, and repeats.
    steps = {"tissue_env/TumorPositioning-v0": 60, "tissue_env/Palpation-v0": 105, "tissue_env/Retraction-v0": 70,
             "tissue_env/LiverNeedleAlignment-v0": 60, "tissue_env/Incision-v0": 65,
             "tissue_env/BimanualExposure-v0": 90,
             "tissue_env/Dissection-v0": 65}[env_id]
    cold = _copy_zero(env_id, 1, steps)
    other = _copy_zero(env_id, 2, steps)
    np.testing.assert_array_equal(cold, other)


def test_the_default_threads_keep_the_faster_count():
    """With the default threads the vector env chooses at run time between every core and one
    (``vector._ThreadChooser``): the count whose timed steps were faster, compared again when the steps
    slow down and at the periodic check (step times given here: no timing in the test)."""
    from tissue_env.vector import CHECK_INTERVAL, TRIAL_STEPS, _ThreadChooser

    chooser = _ThreadChooser(2)
    speed = {2: 1.0, 1: 3.0}  # idle cores: the threads are faster

    def run(steps):
        for _ in range(steps):
            chooser.record(speed[chooser.active])

    run(2 * TRIAL_STEPS + 3)  # every core timed, then one on trial (the first step after a change untimed)
    assert chooser.active == 2 and chooser.trial is None
    speed = {2: 3.0, 1: 1.3}  # another process took a core: the slowdown starts a comparison at once
    run(2 * (TRIAL_STEPS + 1))
    assert chooser.active == 1 and chooser.trial is None
    speed = {2: 0.9, 1: 1.2}  # the core is free again: found at the periodic check
    run(CHECK_INTERVAL - 1)
    assert chooser.active == 1
    run(TRIAL_STEPS + 2)
    assert chooser.active == 2 and chooser.trial is None


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two cores for numba's threads")
@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_the_default_threads_changing_between_steps_give_the_one_thread_floats(env_id):
    """The default threads' count may change from one step to the next (``active_threads``): a vector
    env whose count changes at every step takes the steps of a one-thread vector env bit for bit,
    resets and autoresets included; a fixed count never changes."""
    default = gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", max_episode_steps=8)
    single = gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", max_episode_steps=8, threads=1)
    chooser = default.unwrapped._chooser
    assert chooser is not None and default.unwrapped.threads >= 2 and default.unwrapped.active_threads >= 2
    assert single.unwrapped._chooser is None and single.unwrapped.active_threads == 1
    counts = []

    def flip(seconds):
        counts.append(chooser.active)
        chooser.active = 1 if chooser.active != 1 else chooser.most

    chooser.record = flip
    rng = np.random.default_rng(3)
    for envs in (default, single):
        envs.reset(seed=11)
    for step in range(20):
        actions = rng.uniform(-1.0, 1.0, default.action_space.shape).astype(np.float32)
        if step == 10:  # a masked reset on one thread
            mask = np.array([True, False, True, False])
            outs = [envs.reset(seed=[1, 2, 3, 4], options={"reset_mask": mask}) for envs in (default, single)]
            np.testing.assert_array_equal(outs[0][0], outs[1][0])
        (obs, reward, terminated, truncated, info), expected = (envs.step(actions) for envs in (default, single))
        for actual, wanted in zip((obs, reward, terminated, truncated), expected[:4]):
            np.testing.assert_array_equal(actual, wanted)
        assert_infos_match(info, expected[4], atol=0.0, rtol=0.0)
    assert set(counts) == {1, default.unwrapped.threads}
    fixed = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", threads=2)
    assert fixed.unwrapped._chooser is None and fixed.unwrapped.active_threads == 2
    for envs in (default, single, fixed):
        envs.close()
