"""benchmarks/dynamic_convergence.py: the env's observations, run dynamically, against a fine mesh's."""

import numpy as np
import pytest

from benchmarks import dynamic_convergence
from benchmarks.env_accuracy import retraction_scenes


def test_a_shape_against_itself_is_exact_and_a_coarser_one_is_not():
    result = dynamic_convergence.run("Retraction", shapes=[(4, 1, 2), (6, 1, 3)], fine=(6, 1, 3))
    coarse, same = result["shapes"]
    assert all(value == 0.0 for value in same["errors"].values())
    assert coarse["errors"]["force"] > 0.05 and coarse["errors"]["volume"] > 0.05
    # the lag is against the shape's own static equilibrium: not zero at full tool speed
    assert same["lag"]["force"] > 0.0
    assert same["damping_ratio"] == 1.0 and result["fine_damping_ratio"] == 1.0


def test_constant_viscosity_scales_the_damping_by_the_element_size():
    scene = retraction_scenes()[0]
    result = dynamic_convergence.run("Retraction", shapes=[(5, 1, 3)], fine=(6, 1, 3), constant_viscosity=True)
    default = dynamic_convergence.env_default_shape("Retraction")
    expected = dynamic_convergence.element_size(scene, default) / dynamic_convergence.element_size(scene, (5, 1, 3))
    assert result["shapes"][0]["damping_ratio"] == pytest.approx(expected)
    assert result["fine_damping_ratio"] == pytest.approx(
        dynamic_convergence.element_size(scene, default) / dynamic_convergence.element_size(scene, (6, 1, 3)))


def test_the_damping_ratio_reaches_the_dynamic_model():
    scenes = retraction_scenes()
    # Retraction's tissue model (its elements are boxes, which "baudet" refuses)
    args = dict(dt=0.02, max_step=0.005, solver_tolerance=1e-4, alpha=0.0, kappa=0.0, model="baudet-hyperelastic")
    plain, _, _ = dynamic_convergence.dynamic(scenes, (4, 1, 2), damping_ratio=1.0, **args)
    damped, _, _ = dynamic_convergence.dynamic(scenes, (4, 1, 2), damping_ratio=3.0, **args)
    assert not np.allclose(plain[0].force, damped[0].force, rtol=1e-3, atol=0.0)
