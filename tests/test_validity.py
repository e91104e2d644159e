"""The validity monitor (``sim_core.models.validity``): a state outside the model's validated range is
flagged in every info, never silent; a reset that cannot start a meaningful episode raises; an
observation entry beyond its bound is flagged, and none is at the defaults."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env
from sim_core.models.validity import VALIDATED_STRAIN, ValidityRange, out_of_range

ENV_IDS = sorted(tissue_env.ENV_IDS)


def test_out_of_range_names_the_first_limit_a_state_exceeds():
    reasons = out_of_range([0.1, 0.35, 0.1, 0.3], [0.9, 0.9, 0.7, 0.5], [1.1, 1.1, 1.05, 1.6])
    assert reasons[0] is None
    assert "spring strain 0.35 beyond the validated 0.2" in reasons[1]
    assert "element volume ratio 0.7-1.05 outside the validated 0.8-1.2" in reasons[2]
    assert reasons[3].startswith("spring strain 0.3")  # the strain first
    assert out_of_range([0.3], [1.0], [1.0], ValidityRange(max_strain=0.5))[0] is None


@pytest.mark.parametrize("kwargs, words", [(dict(max_strain=0.0), "max_strain"),
                                            (dict(volume_ratio=(1.1, 1.2)), "volume_ratio")])
def test_invalid_range_is_a_value_error(kwargs, words):
    with pytest.raises(ValueError, match=words):
        ValidityRange(**kwargs)


@pytest.mark.parametrize("env_id", ["tissue_env/TumorPositioning-v0", "tissue_env/Palpation-v0"])
@pytest.mark.parametrize("young_modulus", [1.0, 10.0])
def test_tissue_that_cannot_carry_its_weight_is_refused_at_reset(env_id, young_modulus):
    """E = 1 and 10 Pa: the block under gravity has no start equilibrium (measured: Newton stops at
    1-8% of the load); the reset says so instead of starting from the rest shape, where
    TumorPositioning's goal solve also failed and reset returned is_success=True, distance 0."""
    env = gym.make(env_id, young_modulus=young_modulus)
    with pytest.raises(ValueError, match="no start equilibrium under gravity.*young_modulus="):
        env.reset(seed=0)


def test_tissue_too_stiff_to_resolve_is_told_so_not_to_stiffen():
    """E = 1e12 Pa on TumorPositioning's 5 cm block: the sag under gravity (about 2.6e-11 m) is
    2.4e6 rounding steps of the node positions and Newton's residual stalls at 2e-3 of the load;
    the reset names precision and a softer material, and does not advise a stiffer one."""
    env = gym.make("tissue_env/TumorPositioning-v0", young_modulus=1e12)
    with pytest.raises(ValueError, match="too stiff for double precision.*softer material") as error:
        env.reset(seed=0)
    assert "stiffer" not in str(error.value)


@pytest.mark.parametrize("young_modulus", [1.0, 10.0])
def test_soft_flap_steps_are_flagged_out_of_range(young_modulus):
    """Retraction starts flat on its floor (no start solve): at E = 1 and 10 Pa every step that
    leaves the validated range says so (measured: every step, spring strains 1.4-2.6 after 10)."""
    env = gym.make("tissue_env/Retraction-v0", young_modulus=young_modulus)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(10):
        _, _, terminated, _, info = env.step(env.action_space.sample())
        strain_beyond = info["max_strain"] > VALIDATED_STRAIN
        assert info["out_of_range"] == (strain_beyond or info["out_of_range_reason"] is not None)
        if strain_beyond:
            assert info["out_of_range"] and "spring strain" in info["out_of_range_reason"]
        assert not info["is_success"]
        if terminated:
            break
    assert info["out_of_range"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_defaults_flag_exactly_the_steps_beyond_the_validated_strain_and_clip_nothing(env_id):
    """At the defaults, 3 random-action episodes: ``out_of_range`` is set exactly where the largest
    spring strain exceeds VALIDATED_STRAIN (or an element's volume ratio leaves 0.8-1.2), and no
    observation entry is ever beyond its bound (``observation_clipped`` never set; Palpation's
    map, in kPa, reached 102 before it was read relative to the tissue). The vector env reports
    the same keys per copy."""
    env = gym.make(env_id)
    env.action_space.seed(1)
    flagged = steps = 0
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert not info["observation_clipped"]
        while True:
            observation, _, terminated, truncated, info = env.step(env.action_space.sample())
            steps += 1
            assert not info["observation_clipped"] and np.all(np.abs(observation) < 100.0)
            if info["max_strain"] > VALIDATED_STRAIN:
                assert info["out_of_range"] and "spring strain" in info["out_of_range_reason"]
            if info["out_of_range"]:
                flagged += 1
            else:
                assert info["out_of_range_reason"] is None
            if terminated or truncated:
                break
    assert 0 < flagged < steps  # random actions go beyond the validated strain, not always
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    _, infos = vector.reset(seed=0)
    assert infos["out_of_range"].shape == (2,) and infos["observation_clipped"].dtype == bool
    vector.close()
