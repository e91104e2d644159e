"""Visual observations of the tasks (observation_type "rgb", "depth", "rgbd", "point_cloud" and
render_mode "depth_array"): the checkers, the spaces, the vector env's copies equal to the single
env bit for bit, no hidden ground truth in the images, the tool and the task's scene visible."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import tissue_env
from tissue_env.camera import ALBEDO, VISUAL_TYPES, Camera

ENV_IDS = sorted(tissue_env.ENV_IDS)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("observation_type", VISUAL_TYPES)
def test_checkers_pass(env_id, observation_type):
    env = gym.make(env_id, observation_type=observation_type, render_mode="depth_array").unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env)
    sb3_env_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    with warnings.catch_warnings():
        # SB3 warns that a float32 (H, W, C) box is not a uint8 image (depth and rgbd are metric)
        warnings.filterwarnings("ignore", message=".*is an image but.*")
        warnings.filterwarnings("ignore", message=".*unconventional shape.*")
        if observation_type == "rgb":
            warnings.simplefilter("error")
        sb3_env_checker.check_env(gym.make(env_id, observation_type=observation_type), warn=True)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_spaces_and_observations(env_id):
    for observation_type, shape, dtype in (("rgb", (80, 80, 3), np.uint8), ("depth", (80, 80, 1), np.float32),
                                           ("rgbd", (80, 80, 4), np.float32), ("point_cloud", (300, 6), np.float32)):
        env = gym.make(env_id, observation_type=observation_type, image_size=80, point_count=300, point_normals=True)
        space = env.observation_space
        assert space.shape == shape and space.dtype == dtype
        observation, _ = env.reset(seed=1)
        for _ in range(3):
            assert observation.shape == shape and observation.dtype == dtype and space.contains(observation)
            observation, *_ = env.step(env.action_space.sample())
        if observation_type == "depth":
            camera = env.unwrapped.camera
            assert space.low.min() == np.float32(camera.near) and space.high.max() == np.float32(camera.far)
            seen = observation[..., 0] < camera.far
            assert 0.05 < seen.mean() < 0.95  # the scene and the background both in view
        if observation_type == "point_cloud":
            positions = env.unwrapped.state.positions
            low, high = positions.min(axis=0), positions.max(axis=0)
            assert np.all((observation[:, :3] >= low - 1e-6) & (observation[:, :3] <= high + 1e-6))
            np.testing.assert_allclose(np.linalg.norm(observation[:, 3:], axis=1), 1.0, rtol=1e-5)
        env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_a_vector_copy_reproduces_the_single_envs_images(env_id):
    """Bit for bit, over 14 random steps of 3 copies with truncation and autoreset (the copies'
    positions equal the single envs', and the rasteriser is the same per copy)."""
    for observation_type in ("rgb", "depth"):
        kwargs = dict(observation_type=observation_type, max_episode_steps=6)
        vector = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", **kwargs)
        sync = gym.make_vec(env_id, num_envs=3, vectorization_mode="sync", **kwargs)
        assert vector.single_observation_space == sync.single_observation_space
        assert vector.observation_space == sync.observation_space
        rng = np.random.default_rng(3)
        v, s = vector.reset(seed=7)[0], sync.reset(seed=7)[0]
        np.testing.assert_array_equal(v, s)
        for _ in range(14):
            actions = rng.uniform(-1, 1, (3,) + vector.single_action_space.shape).astype(np.float32)
            v, s = vector.step(actions)[0], sync.step(actions)[0]
            assert v.shape == (3,) + vector.single_observation_space.shape
            np.testing.assert_array_equal(v, s)
        vector.close()
        sync.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_depth_array_render_is_the_depth_observation(env_id):
    env = gym.make(env_id, observation_type="depth", render_mode="depth_array")
    observation, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.shape == observation.shape[:2] and frame.dtype == np.float32
    np.testing.assert_array_equal(frame, observation[..., 0])
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", render_mode="depth_array",
                          observation_type="depth")
    observations, _ = vector.reset(seed=0)
    frames = vector.render()
    assert len(frames) == 2
    for frame, observation in zip(frames, observations):
        np.testing.assert_array_equal(frame, observation[..., 0])


def test_hidden_tumour_and_goal_are_not_drawn():
    """Episodes with different tumours and goals start from the same tissue state: their images are
    the same, while the debug render (its markers) differs."""
    env = gym.make("tissue_env/TumorPositioning-v0", observation_type="rgb", render_mode="rgb_array")
    images, frames, tumours = [], [], []
    for seed in (0, 1, 2):
        observation, info = env.reset(seed=seed)
        images.append(observation)
        frames.append(env.render())
        tumours.append(info["tumor_position"])
    assert not np.allclose(tumours[0], tumours[1])
    for image in images[1:]:
        np.testing.assert_array_equal(image, images[0])
    assert not np.array_equal(frames[0], frames[1])


def _pixels_of(image, albedo, tolerance=0.08):
    """Pixels whose colour is a shade of ``albedo`` (the same chromaticity)."""
    rgb = image.astype(float) / 255.0
    brightness = rgb.sum(axis=-1, keepdims=True)
    reference = np.asarray(albedo) / np.sum(albedo)
    return (brightness[..., 0] > 0.05) & np.all(np.abs(rgb / np.maximum(brightness, 1e-9) - reference) < tolerance,
                                                axis=-1)


def test_retraction_shows_the_target_strip_only_once_exposed():
    env = gym.make("tissue_env/Retraction-v0", observation_type="rgb")
    observation, info = env.reset(seed=0)
    assert _pixels_of(observation, ALBEDO["target"]).sum() == 0  # under the flap
    assert _pixels_of(observation, ALBEDO["floor"]).sum() > 100
    terminated = truncated = False
    while not (terminated or truncated):
        observation, _, terminated, truncated, info = env.step(env.unwrapped.scripted_action())
    assert info["is_success"]
    assert _pixels_of(observation, ALBEDO["target"]).sum() > 10


def test_palpation_probe_is_visible_before_it_touches():
    env = gym.make("tissue_env/Palpation-v0", observation_type="rgb")
    first, _ = env.reset(seed=0)
    probe = _pixels_of(first, ALBEDO["probe"], tolerance=0.03)
    assert probe.sum() > 20
    moved, *_ = env.step(np.array([1.0, 0.5, 0.0], np.float32))  # sideways and up: no contact
    assert not np.array_equal(_pixels_of(moved, ALBEDO["probe"], tolerance=0.03), probe)


def test_tumour_positioning_shows_the_grasped_patch_moving_with_the_tool():
    env = gym.make("tissue_env/TumorPositioning-v0", observation_type="rgb")
    first, _ = env.reset(seed=0)
    tool = _pixels_of(first, ALBEDO["tool"], tolerance=0.03)
    assert tool.sum() > 20
    observation = first
    for _ in range(5):
        observation, *_ = env.step(np.array([1.0, 1.0, 0.0], np.float32))
    rows, columns = np.nonzero(_pixels_of(observation, ALBEDO["tool"], tolerance=0.03))
    start_rows, start_columns = np.nonzero(tool)
    assert rows.mean() < start_rows.mean() - 1  # lifted 1 cm: higher in the image


def test_snapshots_restore_the_images():
    env = gym.make("tissue_env/Retraction-v0", observation_type="rgbd").unwrapped
    env.reset(seed=4)
    env.step(np.array([0.0, 1.0, 0.0], np.float32))
    snapshot = env.get_state()
    actions = [np.array([-0.5, 1.0, 0.2], np.float32)] * 3
    first = [env.step(action)[0] for action in actions]
    env.set_state(snapshot)
    again = [env.step(action)[0] for action in actions]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)


def test_camera_keywords():
    env_id = "tissue_env/TumorPositioning-v0"
    camera = dict(position=(0.025, 0.15, 0.025 + 1e-3), target=(0.025, 0.025, 0.025), width=96, height=72)
    env = gym.make(env_id, observation_type="rgb", camera=camera)
    assert env.observation_space.shape == (72, 96, 3)
    assert env.unwrapped.camera == Camera(**camera)
    env = gym.make(env_id, observation_type="depth", camera=Camera(**camera), image_size=64)
    assert env.observation_space.shape == (64, 64, 1)
    default = gym.make(env_id, observation_type="depth", image_size=128)
    assert default.observation_space.shape == (128, 128, 1)
    for keyword, value, message in (("image_size", 32, "image_size must be an integer from 64 to 128"),
                                    ("image_size", 200, "image_size"), ("image_size", 64.5, "image_size"),
                                    ("camera", "front", "camera must be None"),
                                    ("camera", dict(camera, width=16), "64 to 128 pixels"),
                                    ("camera", dict(camera, fov_deg=-3), "fov_deg"),
                                    ("point_count", 0, "point_count"), ("point_normals", "yes", "point_normals"),
                                    ("observation_type", "image", "observation_type must be one of")):
        with pytest.raises(ValueError, match=message):
            gym.make(env_id, **{keyword: value})


def test_a_camera_dict_with_an_unknown_key_is_refused_with_the_keys_allowed():
    with pytest.raises(ValueError, match=r"unknown keys \['zoom'\].*fov_deg"):
        gym.make("tissue_env/Retraction-v0", observation_type="rgb", camera=dict(zoom=2.0))
