"""Clear errors and warnings for calls out of order or beyond the validated physics.

- ``render()`` and ``scripted_action()`` before ``reset()`` raise RuntimeError, as ``step()`` does,
  on every task: on the env itself, through gym.make's wrappers and on the batched vector env.
- ``elongation`` / ``shear`` of a mass-spring model beyond the validated strain / angle warn
  (UserWarning) and still return the same result; inside the range (and for the FEM references)
  they do not warn.
"""

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest

import tissue_env
from sim_core.experiments import elongation, shear
from sim_core.studies.experiments import VALIDATED_SHEAR_DEG, VALIDATED_STRAIN

ENV_IDS = list(tissue_env.ENV_IDS)
BLOCK = dict(shape=(2, 2, 2), spacing=0.1, young_modulus=1e4, poisson_ratio=0.3)


# -- calls before reset() ------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_before_reset_raises(env_id):
    env = gym.make(env_id, render_mode="rgb_array").unwrapped
    with pytest.raises(RuntimeError, match=r"^call reset\(\) before render\(\)$"):
        env.render()
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_before_reset_through_the_wrappers(env_id):
    # gym.make's order enforcing refuses first; without it (TimeLimit, the env checker) the env's error comes through
    env = gym.make(env_id, render_mode="rgb_array")
    with pytest.raises(gym.error.ResetNeeded):
        env.render()
    env.close()
    env = gym.make(dataclasses.replace(gym.spec(env_id), order_enforce=False), render_mode="rgb_array")
    with pytest.raises(RuntimeError, match=r"^call reset\(\) before render\(\)$"):
        env.render()
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_scripted_action_before_reset_raises(env_id):
    env = gym.make(env_id)
    for target in (env.unwrapped, env):
        scripted_action = (target.scripted_action if target is env.unwrapped
                           else target.get_wrapper_attr("scripted_action"))
        with pytest.raises(RuntimeError, match=r"^call reset\(\) before scripted_action\(\)$"):
            scripted_action()
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_step_before_reset_still_raises(env_id):
    env = gym.make(env_id).unwrapped
    with pytest.raises(RuntimeError, match=r"^call reset\(\) before step\(\)$"):
        env.step(np.zeros(env.action_space.shape))
    env.close()


def test_calls_after_reset_work():
    env = gym.make(ENV_IDS[0], render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render().dtype == np.uint8
    assert env.unwrapped.scripted_action().shape == (3,)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_vector_render_before_reset_raises(env_id):
    vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", render_mode="rgb_array")
    with pytest.raises(RuntimeError, match=r"^call reset\(\) before render\(\)$"):
        vector.render()
    vector.close()


# -- beyond the validated range --------------------------------------------------------------------
def _warnings_of(run):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run()
    return result, [w for w in caught if issubclass(w.category, UserWarning)]


def test_bounds_are_those_of_the_validation():
    assert VALIDATED_STRAIN == 0.2 and VALIDATED_SHEAR_DEG == 10.0


@pytest.mark.parametrize("strain", [5.0, 0.25, -0.5])
def test_elongation_beyond_the_validated_strain_warns(strain):
    with pytest.warns(UserWarning, match=rf"^strain {strain:g} is beyond the range the mass-spring model is "
                                         r"validated for \(\|strain\| <= 0.2 in tension and compression") as record:
        result = elongation(**BLOCK, strain=strain)
    assert len(record) == 1 and "model extrapolation" in str(record[0].message)
    assert record[0].filename == __file__  # points at the caller
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = elongation(**BLOCK, strain=strain)
    assert again.young_modulus == result.young_modulus  # the warning changes no result


@pytest.mark.parametrize("strain", [0.01, -0.2, 0.2])
def test_elongation_inside_the_validated_strain_does_not_warn(strain):
    _, caught = _warnings_of(lambda: elongation(**BLOCK, strain=strain))
    assert caught == []


def test_elongation_under_force_warns_on_the_measured_strain():
    # E = 1e4 Pa over a 0.04 m^2 face: 20 N is about 5% strain, 3000 N several times the length
    _, caught = _warnings_of(lambda: elongation(**BLOCK, force=20.0))
    assert caught == []
    with pytest.warns(UserWarning, match=r"^measured strain [0-9.]+ \(under force 3000 N\) is beyond"):
        elongation(**BLOCK, force=3000.0)


def test_fem_references_do_not_warn():
    _, caught = _warnings_of(lambda: elongation(**BLOCK, strain=0.5, model="fem-linear"))
    assert caught == []


@pytest.mark.parametrize("angle", [20.0, -30.0])
def test_shear_beyond_the_validated_angle_warns(angle):
    with pytest.warns(UserWarning, match=rf"^angle_deg {angle:g} is beyond the range the mass-spring model is "
                                         r"validated for \(\|angle_deg\| <= 10 in shear"):
        shear(**BLOCK, angle_deg=angle)


@pytest.mark.parametrize("angle", [2.0, 10.0, -5.0])
def test_shear_inside_the_validated_angle_does_not_warn(angle):
    _, caught = _warnings_of(lambda: shear(**BLOCK, angle_deg=angle))
    assert caught == []
