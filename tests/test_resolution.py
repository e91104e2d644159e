"""choose_resolution (sim_core.resolution): a tiny indentation scene, fast (< 30 s)."""

import numpy as np
import pytest

from sim_core.resolution import (
    Scene, choose_resolution, choose_stepping, reference_solutions, scene_errors, solve_scene, stepping_error,
)

MM = 1e-3


def tiny_scene(**changes):
    """A 2 cm cube, bottom fixed, the central quarter of the top pressed 0.5 and 1 mm (glued)."""
    values = dict(size=0.02, young_modulus=5e3, poisson_ratio=0.3, density=1000.0, gravity=0.0,
                  tool_low=(0.005, 0.02, 0.005), tool_high=(0.015, 0.02, 0.015),
                  displacements=[[(0, -0.5 * MM, 0), (0, -1.0 * MM, 0)]], target=(0.01, 0.01, 0.01), name="tiny")
    values.update(changes)
    return Scene(**values)


@pytest.fixture(scope="module")
def setup():
    scene = tiny_scene()
    references = reference_solutions(scene, reference_resolution=4)
    return scene, references


def test_chosen_resolution_meets_the_tolerance(setup):
    scene, references = setup
    choice = choose_resolution(scene, 0.2, resolutions=(2, 3, 4), hourglass_controls=(0.5,), volume_stiffnesses=(1.0,),
                               references=references)
    assert references[0][0].converged.all() and choice.reference_stable
    assert choice.chosen is not None and choice.chosen.admissible and choice.chosen.stable
    # recompute independently: the errors are really below the tolerance
    solution = solve_scene(scene, choice.chosen.shape, hourglass_control=0.5, volume_stiffness=1.0)
    errors = scene_errors(solution, references[0][0])
    assert choice.chosen.resolution == 3  # n = 2 misses the force by 47%
    assert all(errors[q] <= 0.2 for q in errors)
    assert errors == pytest.approx(choice.chosen.errors)
    assert all(s is True for s in solution.stable)


def test_finer_tolerance_never_gives_a_coarser_answer(setup):
    scene, references = setup
    previous = 0
    for tolerance in (0.5, 0.15, 0.05, 0.01, 1e-4):
        choice = choose_resolution(scene, tolerance, resolutions=(2, 3, 4), hourglass_controls=(0.5,),
                                   volume_stiffnesses=(1.0,), references=references)
        resolution = np.inf if choice.chosen is None else choice.chosen.resolution
        assert resolution >= previous
        previous = resolution
    assert choice.chosen is None and choice.best is not None  # 1e-4: out of reach, the closest is reported


def test_reference_mesh_scores_its_own_solution_as_exact(setup):
    scene, references = setup
    errors = scene_errors(references[0][0], references[0][0])
    assert all(v == 0.0 for v in errors.values())


def test_shape_rule():
    scene = tiny_scene(size=(0.06, 0.03, 0.06))
    assert scene.shape(5) == (5, 3, 5) and scene.shape(2) == (2, 1, 2)
    flap = tiny_scene(size=(0.06, 0.008, 0.03), tool_low=(0.06, 0, 0), tool_high=(0.06, 0.008, 0.03),
                      target=(0.03, 0.004, 0.015), fixed_face="x-")
    assert flap.shape(6) == (6, 1, 3)


@pytest.mark.parametrize("keyword, value", [
    ("size", -1.0), ("poisson_ratio", 0.6), ("young_modulus", 0.0), ("fixed_face", "bottom"),
    ("displacements", [(0, 0, 0)]), ("displacements", "abc"), ("target", (0.5, 0.01, 0.01)),
    ("tool_components", (3,)), ("tool_low", (0.02, 0.02, 0.02)),
])
def test_invalid_scene_raises_value_error_naming_the_argument(keyword, value):
    with pytest.raises(ValueError, match=keyword):
        tiny_scene(**{keyword: value})


@pytest.mark.parametrize("keyword, value", [
    ("tolerance", -0.1), ("tolerance", float("nan")), ("resolutions", (0, 2)), ("resolutions", (2.5,)),
    ("hourglass_controls", (-1.0,)), ("volume_stiffnesses", ()), ("reference_resolution", 1),
    ("quantities", ("pressure",)),
])
def test_invalid_choice_arguments_raise_value_error_naming_the_argument(setup, keyword, value):
    scene, references = setup
    with pytest.raises(ValueError, match=keyword):
        choose_resolution(scene, **{keyword: value, **({} if keyword == "reference_resolution" else {"references": references})})


def test_scene_argument_must_be_a_scene():
    with pytest.raises(ValueError, match="scene"):
        choose_resolution("a block", 0.05)


def test_tool_selecting_no_node_is_rejected():
    scene = tiny_scene(tool_low=(0.001, 0.02, 0.001), tool_high=(0.002, 0.02, 0.002))
    with pytest.raises(ValueError, match="tool"):
        scene.discretise((2, 2, 2))


# -- the fine mass-spring model as the reference (discretisation error) -------------------------------
@pytest.fixture(scope="module")
def fine():
    # the whole top glued and dragged: no tool quantisation, so the errors fall cleanly with n
    scene = tiny_scene(tool_low=(0, 0.02, 0), tool_high=(0.02, 0.02, 0.02),
                       displacements=[[(0.5 * MM, 0, 0), (1.0 * MM, -0.5 * MM, 0)]])
    return scene, reference_solutions(scene, reference_resolution=6, model="baudet", hourglass_control=1.0,
                                      volume_stiffness=100.0)


def test_fine_model_reference_scores_itself_zero_and_coarser_meshes_worse(fine):
    scene, references = fine
    assert references.model == "baudet" and references.setting == (1.0, 100.0)
    choice = choose_resolution(scene, 0.05, resolutions=(2, 4, 6), hourglass_controls=(1.0,),
                               volume_stiffnesses=(100.0,), references=references, full_scan=True)
    assert choice.reference_model == "baudet" and choice.reference_stable
    errors = {c.resolution: c.errors for c in choice.candidates}
    assert all(v == 0.0 for v in errors[6].values())  # the reference mesh against itself
    worst = {n: max(e.values()) for n, e in errors.items()}
    assert worst[2] > 2 * worst[4] > 0.0  # measured 29% and 6%
    # the reference itself is never chosen; the convergence report is the finest coarser mesh
    assert choice.chosen is None or choice.chosen.resolution < 6
    assert choice.reference_convergence[0]["resolution"] == 4
    assert choice.reference_convergence[0]["errors"] == pytest.approx(errors[4])


def test_fem_reference_is_kept_when_given(setup):
    scene, references = setup
    choice = choose_resolution(scene, 0.2, resolutions=(3,), hourglass_controls=(0.5,), volume_stiffnesses=(1.0,),
                               references=references)
    assert choice.reference_model == "fem-neohookean" and choice.reference_convergence is None
    with pytest.raises(ValueError, match="references"):
        choose_resolution(scene, 0.2, resolutions=(3,), reference="baudet", references=references)


# -- the stepping lag ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def static():
    scene = tiny_scene()
    return scene, [solve_scene(scene, (3, 3, 3), hourglass_control=1.0, volume_stiffness=100.0, check_stability=False)]


def test_held_tool_settles_on_the_static_equilibrium(static):
    scene, solutions = static
    lag = stepping_error(scene, (3, 3, 3), dt=0.02, max_step=1e-3, hold_steps=60, static=solutions)
    assert lag.admissible and max(lag.errors.values()) < 1e-4


def test_held_tool_settles_with_a_loose_factorised_solve(static):
    # inexact linear solves (relative residual 1e-2, factorised preconditioner) keep the equilibria:
    # the held tool still settles on the static solution
    scene, solutions = static
    lag = stepping_error(scene, (3, 3, 3), dt=0.02, max_step=1e-3, hold_steps=60, static=solutions,
                         solver_tolerance=1e-2, solver=dict(preconditioner="factorised"))
    assert lag.admissible and max(lag.errors.values()) < 1e-4


def test_lag_after_a_fixed_time_grows_with_dt(static):
    # the tool jumps to each displacement in one env step, then is held; observed 20 ms later
    scene, solutions = static
    worst = [max(stepping_error(scene, (3, 3, 3), dt=dt, max_step=1e-3, hold_steps=round(0.02 / dt) - 1,
                                static=solutions).errors.values()) for dt in (0.0025, 0.005, 0.01, 0.02)]
    assert worst == sorted(worst) and worst[-1] > 5 * worst[0]


def test_cheapest_stepping_is_chosen(static):
    # a tool at max_step per env step: a longer dt is a slower tool, a smaller lag
    scene, solutions = static
    choice = choose_stepping(scene, (3, 3, 3), 0.1, dts=(0.01, 0.04), substeps=(1, 2), max_step=0.25e-3,
                             static=solutions)
    lags = {(c.dt, c.substeps): max(c.errors.values()) for c in choice.candidates}
    assert lags[(0.04, 1)] < lags[(0.01, 1)]
    assert choice.chosen is not None and choice.chosen.substeps == 1 and choice.chosen.admissible


@pytest.mark.parametrize("keyword, value", [
    ("dt", 0.0), ("dt", "fast"), ("substeps", 0), ("substeps", 1.5), ("max_step", -1e-3), ("hold_steps", -1),
    ("shape", (3, 3)), ("hourglass_control", -1.0),
])
def test_invalid_stepping_arguments_raise_value_error_naming_the_argument(static, keyword, value):
    scene, solutions = static
    arguments = dict(shape=(3, 3, 3), static=solutions)
    arguments[keyword] = value
    with pytest.raises(ValueError, match=keyword):
        stepping_error(scene, **arguments)


@pytest.mark.parametrize("keyword, value", [("dts", (0.0,)), ("dts", ()), ("substeps", (0,)), ("tolerance", 0.0)])
def test_invalid_choose_stepping_arguments_raise_value_error(static, keyword, value):
    scene, solutions = static
    with pytest.raises(ValueError, match=keyword):
        choose_stepping(scene, (3, 3, 3), **{keyword: value}, static=solutions)


@pytest.mark.parametrize("keyword, value", [("reference", "fem"), ("reference_resolution", 2.5)])
def test_invalid_reference_arguments(keyword, value):
    with pytest.raises(ValueError, match=keyword):
        choose_resolution(tiny_scene(), 0.05, **{keyword: value})


def test_reference_solutions_rejects_an_unknown_model():
    with pytest.raises(ValueError, match="model"):
        reference_solutions(tiny_scene(), reference_resolution=2, model="springs")
