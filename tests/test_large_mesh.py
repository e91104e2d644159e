"""Bounded work on large meshes: the iterative static solver, and envs that refuse (or warn about)
a mesh whose resets would take minutes. The costs themselves are measured by
``benchmarks/large_mesh.py``."""

import gymnasium as gym
import numpy as np
import pytest

import tissue_env  # noqa: F401
from sim_core import solve_static
from benchmarks.large_mesh import static_scene
from tissue_env.base import MAX_NODES, SLOW_NODES


def _scene(n=5):
    """The benchmark's static scene on a 5 cm cube, a 2.2 cm patch moved 8 mm down and 4 mm sideways."""
    return static_scene(n, size=0.05, patch=0.22, move=(0.004, -0.008, 0.0))


def test_iterative_static_solve_equals_the_direct_one():
    """The AMG-preconditioned Krylov path reaches the same equilibrium as the sparse LU: positions
    within 1e-6 of the largest displacement (both solved to a 1e-9 force residual)."""
    model, control = _scene()
    direct = solve_static(model, control, tolerance=1e-9, linear_solver="direct")
    iterative = solve_static(model, control, tolerance=1e-9, linear_solver="iterative")
    assert direct.converged and iterative.converged
    displacement = np.abs(direct.positions - model.rest_positions).max()
    assert np.abs(direct.positions - iterative.positions).max() <= 1e-6 * displacement


def test_solve_static_rejects_an_unknown_linear_solver():
    model, control = _scene(2)
    with pytest.raises(ValueError, match="linear_solver must be one of"):
        solve_static(model, control, linear_solver="lu")


def test_an_env_refuses_a_mesh_past_its_node_limit_and_names_the_alternatives():
    n = int(round(MAX_NODES ** (1 / 3)))  # (n + 1)^3 > MAX_NODES
    with pytest.raises(ValueError, match=r"max_nodes=.*coarser shape.*choose_resolution.*max_nodes=None"):
        gym.make("tissue_env/Palpation-v0", shape=(n, n, n))
    with pytest.raises(ValueError, match="max_nodes must be"):
        gym.make("tissue_env/Palpation-v0", max_nodes=-1)


def test_an_env_past_the_slow_size_warns_why_its_resets_take_long():
    n = int(np.ceil(SLOW_NODES ** (1 / 3)))  # n^3 >= SLOW_NODES, so (n + 1)^3 nodes are past it
    assert SLOW_NODES < (n + 1) ** 3 <= MAX_NODES
    with pytest.warns(UserWarning, match="a reset solves a .*-dof static equilibrium"):
        env = gym.make("tissue_env/TumorPositioning-v0", shape=(n, n, n))
    env.close()
