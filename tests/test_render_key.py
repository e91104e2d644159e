"""Pictures a user reads: rendered frames with an optional key (legend and colour bar), a colour
range taken from the scene that an episode does not saturate, the demo's episode strip over the
whole episode, and a training progress bar whose total is what SB3 trains."""

import gymnasium as gym
import numpy as np
import pytest

from tissue_env.rendering import FRAME_SIZE, KEY_FRAME_WIDTH


def test_frames_with_and_without_their_key():
    plain = gym.make("tissue_env/TumorPositioning-v0", render_mode="rgb_array")
    keyed = gym.make("tissue_env/TumorPositioning-v0", render_mode="rgb_array", render_key=True)
    plain.reset(seed=3)
    keyed.reset(seed=3)
    frame, key_frame = plain.render(), keyed.render()
    assert frame.shape == (FRAME_SIZE, FRAME_SIZE, 3) and key_frame.shape == (FRAME_SIZE, KEY_FRAME_WIDTH, 3)
    assert np.array_equal(frame[:, FRAME_SIZE // 4:3 * FRAME_SIZE // 4], key_frame[:, FRAME_SIZE // 4:3 * FRAME_SIZE // 4])
    assert (key_frame[:, FRAME_SIZE:] < 200).any()  # the key drew something in its panel
    _, labels = keyed.unwrapped.render_legend()
    assert labels == ["tool", "tumour (hidden)", "goal"]
    with pytest.raises(ValueError, match="render_key"):
        gym.make("tissue_env/TumorPositioning-v0", render_key="yes")


@pytest.mark.parametrize("env_id", ["tissue_env/TumorPositioning-v0", "tissue_env/LiverNeedleAlignment-v0"])
def test_the_colour_range_holds_an_episode(env_id):
    """The colours span the workspace's largest tool offset (TumorPositioning: 2 cm; a fixed fifth
    of the block, 1 cm, saturated); the scripted episode held to its time limit stays within it."""
    env = gym.make(env_id, terminate_on_success=False, max_episode_steps=25)
    env.reset(seed=1)
    unwrapped = env.unwrapped
    largest = 0.0
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(unwrapped.scripted_action())
        done = terminated or truncated
        largest = max(largest, np.linalg.norm(unwrapped.state.positions - unwrapped.episode_mesh.nodes, axis=1).max())
    assert unwrapped.render_scale == pytest.approx(0.02)
    assert 0.1 * unwrapped.render_scale < largest < unwrapped.render_scale


def test_palpation_colours_span_the_probe_depth():
    env = gym.make("tissue_env/Palpation-v0", max_depth=0.006)
    assert env.unwrapped.render_scale == pytest.approx(0.006)


def test_the_strip_shows_the_whole_episode():
    from training.demo import strip_steps

    assert list(strip_steps(50, 2)) == [0, 1, 2, 12, 21, 31, 40, 50]  # every step of the approach, then the hold
    assert list(strip_steps(2, 2)) == [0, 1, 2]
    for steps, reached in ((50, None), (50, 0), (50, 6), (50, 30), (7, None), (100, 99)):
        picks = strip_steps(steps, reached)
        assert picks[0] == 0 and picks[-1] == steps and len(picks) <= 8 and (np.diff(picks) > 0).all()
        assert reached is None or reached in picks
        assert len(picks) == min(8, steps + 1)


def test_the_progress_bar_total_is_what_is_trained():
    """PPO trains whole rollouts: 15,000 steps of 4 envs x 256 are 15,360 (the bar ended at
    "15,360/15,000"); SAC steps its envs together."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.env_util import make_vec_env

    from training.train import whole_rounds

    ppo = PPO("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=4), n_steps=256, batch_size=64, device="cpu")
    assert whole_rounds(ppo, 15000) == 15360 and whole_rounds(ppo, 1024) == 1024
    ppo.learn(whole_rounds(ppo, 1500))
    assert ppo.num_timesteps == whole_rounds(ppo, 1500) == 2048
    sac = SAC("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=3), buffer_size=100, device="cpu")
    assert whole_rounds(sac, 100) == 102
