"""The goal-conditioned API (observation_type="goal"): the Dict observation of observation,
achieved_goal and desired_goal, and ``compute_reward(achieved_goal, desired_goal, info)``, which
recomputes the step's reward, single and batched, as stable-baselines3's HerReplayBuffer calls it."""

import copy
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import tissue_env  # noqa: F401  (registers the ids)

POSITIONING = "tissue_env/TumorPositioning-v0"
#: every registered task that takes observation_type="goal"
GOAL_IDS = [env_id for env_id, (entry_point, _) in sorted(tissue_env.ENV_IDS.items())
            if "goal" in gym.envs.registration.load_env_creator(entry_point).observation_types()]


def goal_env(**kwargs):
    return gym.make(POSITIONING, observation_type="goal", **kwargs)


def steps(env, seed, count, rng, scripted_every=0):
    """(observation, reward, info) of up to ``count`` steps of random actions (every
    ``scripted_every``-th the scripted controller's, so that successes occur), resetting at episode ends."""
    out = []
    env.reset(seed=seed)
    for index in range(count):
        scripted = scripted_every and index % scripted_every
        action = env.unwrapped.scripted_action() if scripted else rng.uniform(-1, 1, 3).astype(np.float32)
        observation, reward, terminated, truncated, info = env.step(action)
        out.append((observation, reward, info))
        if terminated or truncated:
            env.reset()
    return out


def test_the_goal_tasks_are_the_ones_with_goal_features():
    assert GOAL_IDS == [POSITIONING]


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_goal_env_from_gym_make_passes_the_gymnasium_and_sb3_checkers_without_warnings(env_id):
    """SB3's checker calls ``env.compute_reward`` on the env it is given: gym.make's env (inside
    PassiveEnvChecker, OrderEnforcing and TimeLimit) passes it as the bare env does (it raised
    "'TimeLimit' object has no attribute 'compute_reward'")."""
    sb3_env_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    wrapped = gym.make(env_id, observation_type="goal")
    assert isinstance(wrapped, gym.wrappers.TimeLimit)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(wrapped.unwrapped, skip_render_check=True)  # gymnasium's asks for the bare env
        for env in (wrapped, wrapped.unwrapped):
            sb3_env_checker.check_env(env, warn=True)


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_gym_make_wrappers_forward_compute_reward_and_only_a_goal_envs(env_id):
    """Every wrapper gym.make puts around a goal env gives the env's own compute_reward; the same
    wrappers around an env without one (the state observation, another package's env) have none,
    so goal-env detection by hasattr stays right; gym.make_vec keeps the vector entry point."""
    env = gym.make(env_id, observation_type="goal")
    layer = env
    while layer is not env.unwrapped:
        assert layer.compute_reward == env.unwrapped.compute_reward
        layer = layer.env
    observation, _ = env.reset(seed=0)
    observation, reward, _, _, info = env.step(env.action_space.sample())
    assert env.compute_reward(observation["achieved_goal"], observation["desired_goal"], info) == reward
    for other in (gym.make(env_id), gym.make("CartPole-v1")):
        assert not hasattr(other, "compute_reward")
    assert not gym.make(env_id).has_wrapper_attr("compute_reward")
    vector = gym.make_vec(env_id, num_envs=2, observation_type="goal")  # default mode: vector_entry_point
    assert isinstance(vector, tissue_env.TissueVectorEnv) and hasattr(vector, "compute_reward")
    vector.close()


def test_compute_reward_equals_the_step_reward_single_and_batched():
    """Over random and scripted steps (successes included), the reward recomputed from the observed
    goals and the info equals the step's reward to 1e-12 (bit for bit, in fact) one step at a time,
    and batched over every step with their infos as a list and as an object array (HER's call)."""
    env = goal_env()
    records = steps(env, 0, 60, np.random.default_rng(0), scripted_every=3)
    rewards = np.array([reward for _, reward, _ in records])
    assert any(info["is_success"] for _, _, info in records) and not all(info["is_success"] for _, _, info in records)
    compute = env.unwrapped.compute_reward
    for observation, reward, info in records:
        value = compute(observation["achieved_goal"], observation["desired_goal"], info)
        assert isinstance(value, float) and abs(value - reward) <= 1e-12
        assert value == reward
    achieved = np.stack([observation["achieved_goal"] for observation, _, _ in records])
    desired = np.stack([observation["desired_goal"] for observation, _, _ in records])
    infos = [info for _, _, info in records]
    for batch_infos in (infos, np.array(infos, dtype=object)):
        batched = compute(achieved, desired, batch_infos)
        assert batched.shape == (len(records),)
        np.testing.assert_allclose(batched, rewards, rtol=0, atol=1e-12)
    # a (B, 1, 3) batch keeps its leading shape
    assert compute(achieved[:, None], desired[:, None], infos).shape == (len(records), 1)


def test_relabelled_goals_get_the_reward_of_their_distance():
    """HER's relabelling: with the achieved goal as the desired one the step is a success (distance
    0: the success bonus plus the goal-independent terms of the info); with a goal 1 cm further the
    distance term is -1 and there is no bonus."""
    env = goal_env()
    observation, _, info = steps(env, 1, 3, np.random.default_rng(1))[-1]
    achieved = observation["achieved_goal"]
    damage = info["reward_volume"] + info["reward_strain"]
    assert not info["is_success"]
    assert env.unwrapped.compute_reward(achieved, achieved, info) == pytest.approx(5.0 + damage, abs=1e-12)
    shifted = achieved + np.array([0.0, 1.0, 0.0])
    assert env.unwrapped.compute_reward(achieved, shifted, info) == pytest.approx(-1.0 + damage, abs=1e-12)


def test_a_diverging_step_is_recomputed_as_the_instability_penalty():
    env = goal_env(integrator="explicit", dt=0.05, instability_penalty=7.0)
    env.reset(seed=0)
    for _ in range(30):
        observation, reward, terminated, _, info = env.step(env.unwrapped.scripted_action())
        if terminated:
            break
    assert info["unstable"] and reward == -7.0
    assert env.unwrapped.compute_reward(observation["achieved_goal"], observation["desired_goal"], info) == -7.0


def test_goal_observation_is_the_state_observation_and_its_goals():
    """``observation`` is the "state" vector of the same seed and actions (float32; the goal env
    measures the distance on the observed goals, 1e-17 m from the state env's), ``achieved_goal``
    and ``desired_goal`` its tumour and goal positions (cm from the block centre)."""
    goal, state = goal_env(), gym.make(POSITIONING)
    actions = np.random.default_rng(2).uniform(-1, 1, (8, 3)).astype(np.float32)
    observation, _ = goal.reset(seed=4)
    expected, _ = state.reset(seed=4)
    for action in actions:
        assert goal.observation_space.contains(observation)
        np.testing.assert_allclose(observation["observation"], expected, rtol=0, atol=1e-6)
        np.testing.assert_allclose(observation["achieved_goal"], expected[11:14], rtol=0, atol=1e-5)
        np.testing.assert_allclose(observation["desired_goal"], expected[14:17], rtol=0, atol=1e-5)
        assert observation["achieved_goal"].dtype == observation["desired_goal"].dtype == np.float64
        observation, reward, _, _, _ = goal.step(action)
        expected, expected_reward, _, _, _ = state.step(action)
        assert reward == pytest.approx(expected_reward, abs=1e-12)


def test_vector_env_goal_observations_and_compute_reward():
    """The vector env has the single env's goal observation space; a copy reproduces the single env
    of the same seed and actions (to 1e-6) and its compute_reward, on the vector env's infos (a
    dict of (N,) arrays), recomputes every copy's reward."""
    vector = gym.make_vec(POSITIONING, num_envs=2, vectorization_mode="vector_entry_point", observation_type="goal")
    single = goal_env()
    assert vector.single_observation_space == single.observation_space
    observations, _ = vector.reset(seed=7)
    single_observation, _ = single.reset(seed=7)
    rng = np.random.default_rng(3)
    for _ in range(6):
        for key in ("observation", "achieved_goal", "desired_goal"):
            np.testing.assert_allclose(observations[key][0], single_observation[key], rtol=0, atol=1e-6)
        actions = rng.uniform(-1, 1, (2, 3)).astype(np.float32)
        observations, rewards, terminated, truncated, infos = vector.step(actions)
        single_observation, reward, _, _, _ = single.step(actions[0])
        assert rewards[0] == pytest.approx(reward, abs=1e-6)
        recomputed = vector.unwrapped.compute_reward(observations["achieved_goal"], observations["desired_goal"], infos)
        np.testing.assert_allclose(recomputed, rewards, rtol=0, atol=1e-12)
        assert not (terminated.any() or truncated.any())
    vector.close()


def test_goal_env_snapshots_pickle_and_copy():
    env = goal_env().unwrapped
    env.reset(seed=2)
    env.step(np.array([1.0, 0.0, -1.0], np.float32))
    snapshot = env.get_state()
    restored = pickle.loads(pickle.dumps(env))
    copied = copy.deepcopy(env)
    action = np.array([0.5, 0.5, 0.5], np.float32)
    expected = env.step(action)
    env.set_state(snapshot)
    for other in (restored, copied, env):
        observation, reward = other.step(action)[:2]
        assert reward == expected[1]
        for key in expected[0]:
            np.testing.assert_array_equal(observation[key], expected[0][key])
        assert other.compute_reward(observation["achieved_goal"], observation["desired_goal"], expected[4]) == reward


@pytest.mark.parametrize("env_id", ["tissue_env/Palpation-v0", "tissue_env/Retraction-v0"])
def test_tasks_without_a_goal_refuse_the_goal_observation(env_id):
    with pytest.raises(ValueError, match="observation_type='goal'"):
        gym.make(env_id, observation_type="goal")


def test_compute_reward_exists_only_for_goal_observations_and_checks_its_input():
    state = gym.make(POSITIONING).unwrapped
    assert not hasattr(state, "compute_reward")  # SB3 and gymnasium-robotics detect a goal env by it
    env = goal_env()
    observation, _, info = steps(env, 0, 1, np.random.default_rng(0))[0]
    achieved, desired = observation["achieved_goal"], observation["desired_goal"]
    compute = env.unwrapped.compute_reward
    with pytest.raises(ValueError, match="copy_info_dict"):
        compute(np.stack([achieved] * 2), np.stack([desired] * 2), [{}, {}])  # HerReplayBuffer's default
    with pytest.raises(ValueError, match="one info dict or 3"):
        compute(np.stack([achieved] * 3), np.stack([desired] * 3), [info, info])
    with pytest.raises(ValueError, match="one shape"):
        compute(achieved[:2], desired[:2], info)


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_her_replay_buffer_trains_on_the_gym_make_env(env_id):
    """SAC with stable-baselines3's HerReplayBuffer, given gym.make's env itself (SB3 wraps it in
    Monitor and DummyVecEnv), over 200 steps (4 episodes): it samples relabelled transitions, whose
    rewards it asks of compute_reward with an array of infos (copy_info_dict=True)."""
    sb3 = pytest.importorskip("stable_baselines3")

    env = gym.make(env_id, observation_type="goal")
    model = sb3.SAC("MultiInputPolicy", env, learning_starts=150, batch_size=32, buffer_size=1000, seed=0,
                    replay_buffer_class=sb3.HerReplayBuffer, policy_kwargs=dict(net_arch=[16, 16]),
                    replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future", copy_info_dict=True))
    model.learn(total_timesteps=200)
    assert model.num_timesteps == 200 and model.replay_buffer.size() == 200
    samples = model.replay_buffer.sample(64)
    assert np.all(np.isfinite(samples.rewards.numpy()))
    # relabelled goals reach the success bonus: some virtual transitions are successes
    assert samples.rewards.numpy().max() > 4.0
    model.get_env().close()


def test_the_her_hyperparameter_file_builds_a_her_run(tmp_path):
    """``training.benchmark --variant her``'s setting: the goal observation and hyperparams/her/sac.yml,
    whose HerReplayBuffer (named in the file) copies the infos that compute_reward needs."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import HerReplayBuffer

    from training.benchmark import VARIANTS
    from training.common import load_hyperparams, replay_buffer_class

    setting = VARIANTS["her"]
    assert setting["env_kwargs"] == {"observation_type": "goal"}
    hyperparams = load_hyperparams("sac", POSITIONING, setting["config"].format(algo="sac"))
    assert hyperparams["policy"] == "MultiInputPolicy"
    assert replay_buffer_class(hyperparams["replay_buffer_class"]) is HerReplayBuffer
    assert hyperparams["replay_buffer_kwargs"]["copy_info_dict"] is True
