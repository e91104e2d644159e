"""Force Jacobians, time-step estimate, explicit/implicit stability and divergence detection."""

import numpy as np
import pytest

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.models.forces import external_forces, internal_forces, stiffness_data
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, make_integrator, run, stable_time_step
from sim_core.models.model import Control, State


def finite_difference_stiffness(model, positions, step=1e-7):
    n = positions.size
    jacobian = np.zeros((n, n))
    for column in range(n):
        plus, minus = positions.ravel().copy(), positions.ravel().copy()
        plus[column] += step
        minus[column] -= step
        jacobian[:, column] = -(internal_forces(model, plus.reshape(-1, 3)) -
                                internal_forces(model, minus.reshape(-1, 3))).ravel() / (2 * step)
    return jacobian


@pytest.mark.parametrize("name", ["baudet", "baudet-original", "uniform-springs"])
def test_tangent_stiffness_matches_finite_differences(name):
    """Springs + corrections (+ hourglass) tangent is exact: 1e-7 relative to finite differences."""
    mesh = HexMesh.block((2, 2, 1), (0.1, 0.11, 0.12))
    model = build_model(mesh, Material(1e4, 0.4, 1000), model=name, volume_conservation=False,
                        hourglass_control=0.3, max_shear_error=None)  # a box: any element shape
    assert _tangent_error(model, 0.005, seed=1) < 1e-7


def _tangent_error(model, amplitude, seed):
    """max |K - K_fd| / max |K_fd| of the assembled tangent against finite differences at the rest
    nodes moved by ``amplitude`` m times a standard normal."""
    positions = model.mesh.nodes + amplitude * np.random.default_rng(seed).standard_normal(model.mesh.nodes.shape)
    exact = model.pattern.matrix(stiffness_data(model, positions)).toarray()
    numeric = finite_difference_stiffness(model, positions)
    return np.abs(exact - numeric).max() / np.abs(numeric).max()


def test_volume_force_tangent_is_close():
    """Volume forces: the rank-one tangent is exact to O(dV / V0) (here < 1e-3)."""
    mesh = HexMesh.block((2, 2, 1), 0.1)
    model = build_model(mesh, Material(1e4, 0.4, 1000))
    assert _tangent_error(model, 0.003, seed=2) < 1e-3


def test_forces_vanish_at_rest_and_under_rigid_motion():
    mesh = HexMesh.block((3, 2, 2), 0.05)
    model = build_model(mesh, Material(1e4, 0.45, 1000), hourglass_control=0.5)
    assert np.abs(internal_forces(model, mesh.nodes)).max() < 1e-12
    angle = 0.3
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    moved = mesh.nodes @ rotation.T + [0.1, -0.2, 0.3]
    scale = model.stiffness.max() * 0.05
    assert np.abs(internal_forces(model, moved)).max() < 1e-9 * scale


def test_volume_force_is_restoring():
    """A uniformly shrunken element is pushed outward, an expanded one inward (docs/physics.md 4)."""
    mesh = HexMesh.block((1, 1, 1), 0.1)
    model = build_model(mesh, Material(1e4, 0.3, 1000), corrections=False)
    springs_only = build_model(mesh, Material(1e4, 0.3, 1000), corrections=False, volume_conservation=False)
    centre = mesh.nodes.mean(axis=0)
    for factor, sign in ((0.9, 1.0), (1.1, -1.0)):
        positions = centre + factor * (mesh.nodes - centre)
        volume_force = internal_forces(model, positions) - internal_forces(springs_only, positions)
        outward = ((positions - centre) * volume_force).sum(axis=1)
        assert np.all(sign * outward > 0)


def test_time_step_estimate_matches_physics_md():
    """10x10x10 block of 0.1 m cubes, rho 1500, nu 0.3, E 1e4: 0.034 s springs only, 0.032 s
    with corrections (undamped); Gershgorin is a safe lower bound; dt scales as 1/sqrt(E)."""
    mesh = HexMesh.block((10, 10, 10), 0.1)
    springs = build_model(mesh, Material(1e4, 0.3, 1500), corrections=False, volume_conservation=False)
    full = build_model(mesh, Material(1e4, 0.3, 1500), volume_conservation=False)
    assert stable_time_step(springs, damping=False) == pytest.approx(0.034, rel=0.03)
    assert stable_time_step(full, damping=False) == pytest.approx(0.032, rel=0.03)
    assert stable_time_step(full, method="gershgorin", damping=False) < stable_time_step(full, damping=False)
    stiff = build_model(mesh, Material(4e4, 0.3, 1500), volume_conservation=False)
    assert stable_time_step(stiff, damping=False) == pytest.approx(stable_time_step(full, damping=False) / 2, rel=1e-3)
    # damping lowers the limit
    assert stable_time_step(full) < stable_time_step(full, damping=False)


def _loaded_block(damping_ratio=1.0, nu=0.45, hourglass=0.5):
    mesh = HexMesh.block((4, 4, 4), 0.02)
    model = build_model(mesh, Material(5e3, nu, 1060), gravity=(0, -9.81, 0), damping_ratio=damping_ratio,
                        hourglass_control=hourglass)
    control = model.new_control()
    bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
    control.impose(bottom, mesh.nodes[bottom])
    state = model.new_state()
    state.velocities += 1e-3 * np.random.default_rng(0).standard_normal(state.velocities.shape)
    state.velocities[control.fixed] = 0
    return model, control, state


@pytest.mark.parametrize("damping_ratio", [0.0, 1.0])
def test_explicit_stable_below_limit_and_divergence_detected_above(damping_ratio):
    """0.9x the estimated limit: bounded over 2000 steps; 2x: divergence detected with a reason."""
    model, control, state = _loaded_block(damping_ratio)
    limit = stable_time_step(model, control)
    below = state.copy()
    report = run(model, below, SymplecticEuler(), 0.9 * limit, 2000, control)
    assert not report.unstable
    assert np.abs(below.positions - model.rest_positions).max() < 0.01  # sag of a few mm
    above = state.copy()
    report = run(model, above, SymplecticEuler(), 2.0 * limit, 2000, control)
    assert report.unstable and report.unstable_step < 2000
    assert isinstance(report.unstable_reason, str) and report.unstable_reason


@pytest.mark.parametrize("nu, preconditioner", [(0.3, "jacobi"), (0.45, "jacobi"), (0.45, "factorised")])
def test_implicit_bounded_at_ten_times_the_explicit_limit(nu, preconditioner):
    """10x the explicit limit, 300 steps: bounded, the corrections' coupling and the volume forces
    in the implicit system (left explicit, this run diverged at nu 0.45)."""
    model, control, state = _loaded_block(nu=nu)
    limit = stable_time_step(model, control)
    report = run(model, state, ImplicitEuler(preconditioner=preconditioner), 10 * limit, 300, control)
    assert not report.unstable
    assert np.abs(state.positions - model.rest_positions).max() < 0.01


@pytest.mark.parametrize("name, dt_factor, steps", [("explicit", 0.9, 6000), ("implicit", 10.0, 600)])
def test_dynamics_settle_on_the_static_equilibrium(name, dt_factor, steps):
    """Damped dynamics end where solve_static ends: within 2% of the sag."""
    model, control, state = _loaded_block()
    equilibrium = solve_static(model, control)
    limit = stable_time_step(model, control)
    report = run(model, state, make_integrator(name), dt_factor * limit, steps, control)
    assert not report.unstable
    sag = np.abs(equilibrium.positions - model.rest_positions).max()
    assert np.abs(state.positions - equilibrium.positions).max() < 0.02 * sag


def test_imposed_motion_is_followed():
    model, control, state = _loaded_block()
    top = np.flatnonzero(model.rest_positions[:, 1] == model.rest_positions[:, 1].max())
    control.impose(top, model.rest_positions[top] + [0.002, 0, 0])
    integrator = ImplicitEuler()
    out = state.copy()
    report = integrator.simulate(model, state, out, 0.01, control)
    assert not report.unstable and report.iterations > 0
    assert np.allclose(out.positions[top], model.rest_positions[top] + [0.002, 0, 0])
    assert out.time == pytest.approx(0.01)


@pytest.mark.parametrize("dt", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_time_step_is_rejected(dt):
    model, control, state = _loaded_block()
    with pytest.raises(ValueError, match="dt"):
        SymplecticEuler().simulate(model, state, state.copy(), dt, control)


def test_bad_integrator_options():
    with pytest.raises(ValueError, match="integrator must be one of"):
        make_integrator("rk4")
    with pytest.raises(ValueError, match="preconditioner"):
        ImplicitEuler(preconditioner="maybe")
    with pytest.raises(ValueError, match="max_iterations"):
        ImplicitEuler(max_iterations=0)
    with pytest.raises(ValueError, match="damping_ratio"):
        build_model(HexMesh.block((1, 1, 1), 0.1), Material(), damping_ratio=-1)
    with pytest.raises(ValueError, match="gravity"):
        build_model(HexMesh.block((1, 1, 1), 0.1), Material(), gravity=(0, float("nan"), 0))


def test_external_forces_include_gravity_on_lumped_masses():
    model, control, _ = _loaded_block()
    control.force[0] = [1.0, 2.0, 3.0]
    total = external_forces(model, control).sum(axis=0)
    assert total == pytest.approx([1.0, 2.0 - 9.81 * model.mass.sum(), 3.0])


@pytest.mark.parametrize("options", [dict(), dict(model="baudet-original", nu_factor=True),
                                     dict(hourglass_control=0.5), dict(model="uniform-springs")])
def test_compiled_forces_match_numpy_reference(options):
    """The numba kernels and the numpy formulation agree to 1e-12 relative (with damping)."""
    from sim_core.models.forces import internal_forces_reference

    mesh = HexMesh.block((3, 4, 2), (0.1, 0.11, 0.12))
    if options.get("model", "baudet") in ("baudet", "baudet-original"):
        options = dict(options, max_shear_error=None)  # a box: the kernels for any element shape
    model = build_model(mesh, Material(1e4, 0.45, 1000), **options)
    rng = np.random.default_rng(0)
    positions = mesh.nodes + 0.01 * rng.standard_normal(mesh.nodes.shape)
    velocities = rng.standard_normal(mesh.nodes.shape)
    compiled = internal_forces(model, positions, velocities)
    reference = internal_forces_reference(model, positions, velocities)
    assert np.abs(compiled - reference).max() < 1e-12 * np.abs(reference).max()


def test_divergence_monitor_reasons():
    from sim_core.solvers.solver import DivergenceMonitor
    from sim_core.models.model import State

    model = build_model(HexMesh.block((2, 2, 2), 0.1), Material(1e4, 0.3, 1000))
    monitor = DivergenceMonitor(model)
    rest = model.new_state()
    assert monitor.check(rest, force_inversion_check=True) is None
    inverted = rest.copy()
    inverted.positions[model.mesh.node_index(1, 1, 1)] = [0.05, 0.05, -0.3]  # centre node pushed through
    assert "inverted" in monitor.check(inverted, force_inversion_check=True)
    nan = rest.copy()
    nan.velocities[3, 1] = np.nan
    assert "non-finite" in monitor.check(nan)
    fast = rest.copy()
    fast.velocities[0] = [1e4, 0, 0]
    assert "speed" in monitor.check(fast)
    far = State(rest.positions + [100.0, 0, 0], rest.velocities)
    assert "left the region" in monitor.check(far)


def test_the_copies_monitor_gives_each_copys_own_monitor_reasons():
    """``DivergenceMonitors`` (one compiled pass for N copies, the vector envs') gives, step by step,
    the reasons of N ``DivergenceMonitor``s (its one-copy case) fed the same states, so a copy's
    checks do not depend on the other copies, threaded and serial alike: a quiet
    copy, one whose velocity field flips sign and grows (caught after 20 steps), one that leaves the
    region, one with a NaN, one too fast, one with an element pushed inside out (caught at the 10th
    check), and a copy skipped on some steps (its history untouched). A copy whose check failed is
    assigned again, as the vector env resets it."""
    from sim_core.solvers.solver import DivergenceMonitor, DivergenceMonitors

    model = build_model(HexMesh.block((2, 2, 2), 0.1), Material(1e4, 0.3, 1000))
    count, rest, n = 6, model.rest_positions, model.n_nodes
    rng = np.random.default_rng(2)
    pattern = rng.standard_normal((n, 3))
    batched = [DivergenceMonitors(count, n, model.mesh.elements, threads=threads) for threads in (1, 2)]
    singles = [DivergenceMonitor(model) for _ in range(count)]
    for monitors in batched:
        for index in range(count):
            monitors.assign(index, model)
    seen = set()
    for step in range(45):
        positions = np.repeat(rest[None], count, axis=0) + 1e-4 * rng.standard_normal((count, n, 3))
        velocities = 1e-3 * rng.standard_normal((count, n, 3))
        velocities[1] = 0.05 * (-1.2) ** (step % 30) * pattern  # a growing step-to-step oscillation
        if step == 12:
            positions[2] += [100.0, 0, 0]
        if step == 7:
            velocities[3, 4, 1] = np.nan
        if step == 17:
            velocities[4, 0] = [1e4, 0, 0]
        if step >= 3:
            positions[5, model.mesh.node_index(1, 1, 1)] = [0.05, 0.05, -0.3]
        rows = np.ones(count, dtype=bool)
        rows[0] = step % 3 != 1
        expected = [singles[i].check(State(positions[i], velocities[i])) if rows[i] else None for i in range(count)]
        for monitors in batched:
            assert list(monitors.check(positions, velocities, rows)) == expected, step
        for index, reason in enumerate(expected):
            if reason is not None:
                seen.add(reason.split()[0])
                singles[index] = DivergenceMonitor(model)
                for monitors in batched:
                    monitors.assign(index, model)
    assert seen == {"growing", "a", "non-finite", "node", "inverted"}


def test_closed_form_hexahedron_volume_matches_gauss():
    """The compiled 15-triple-product volume equals 2x2x2 Gauss (exact) for distorted elements."""
    from sim_core import kernels
    from sim_core.geometry.mesh import hex_volumes

    mesh = HexMesh.block((1, 1, 1), (0.03, 0.05, 0.04))
    rng = np.random.default_rng(5)
    for _ in range(20):
        positions = mesh.nodes + 0.008 * rng.standard_normal(mesh.nodes.shape)
        corners = np.ascontiguousarray(positions[mesh.elements[0]])
        assert kernels.hex_volume(corners) == pytest.approx(hex_volumes(positions, mesh.elements)[0], rel=1e-12)
    # HexMesh.element_volumes (the compiled loop over elements) on a distorted 3x2x4 block
    block = HexMesh.block((3, 2, 4), (0.01, 0.012, 0.011))
    positions = block.nodes + 0.0015 * rng.standard_normal(block.nodes.shape)
    np.testing.assert_allclose(block.element_volumes(positions), hex_volumes(positions, block.elements), rtol=1e-12)


def test_stiff_volume_forces_are_stable_only_when_implicit():
    """Volume forces x100 on a 4 cm block squeezed by 30%: with their rank-one stiffness in the
    implicit system the run settles on the static equilibrium (volume within 0.002)."""
    mesh = HexMesh.block((4, 4, 4), 0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060), gravity=(0, -9.81, 0), hourglass_control=1.0,
                        volume_stiffness=100.0)
    control = model.new_control()
    y = mesh.nodes[:, 1]
    bottom, top = np.flatnonzero(y == 0), np.flatnonzero(np.isclose(y, y.max()))
    control.impose(bottom, mesh.nodes[bottom])
    control.impose(top, mesh.nodes[top] - [0, 0.012, 0], components=[1])
    equilibrium = solve_static(model, control)
    assert equilibrium.converged
    rest_volume = mesh.element_volumes().sum()
    state = model.new_state()
    report = run(model, state, ImplicitEuler(), 0.02, 200, control)
    assert not report.unstable
    volume_change = mesh.element_volumes(state.positions).sum() / rest_volume - 1
    static_change = mesh.element_volumes(equilibrium.positions).sum() / rest_volume - 1
    assert volume_change == pytest.approx(static_change, abs=0.002)


def test_a_run_at_the_edge_of_the_explicit_limit_is_flagged_before_it_explodes():
    """No corrections, nu 0.45, 0.9x the estimated limit (0.997x the measured one): the highest
    mode grows from rounding noise; after 500 steps the block was 12x its static displacement
    while the speed check had not fired (an undetected divergence in benchmarks/stability.py).
    The growing step-to-step oscillation check flags it (measured: step 415); 0.8x stays clean."""
    from sim_core import HexMesh, Material, build_model
    from sim_core.solvers.integrators import SymplecticEuler, run, stable_time_step

    mesh = HexMesh.block((4, 4, 4), 0.01)
    model = build_model(mesh, Material(1e4, 0.45, 1060.0), hourglass_control=0.5, corrections=False)
    control = model.new_control()
    y = mesh.nodes[:, 1]
    bottom, top = np.flatnonzero(y == 0), np.flatnonzero(np.isclose(y, y.max()))
    control.impose(bottom, mesh.nodes[bottom])
    control.impose(top, mesh.nodes[top] + [0, 0.0004, 0])
    estimate = stable_time_step(model, control)
    edge = run(model, model.new_state(), SymplecticEuler(), 0.9 * estimate, 500, control)
    assert edge.unstable and "oscillation" in edge.unstable_reason
    safe = run(model, model.new_state(), SymplecticEuler(), 0.8 * estimate, 500, control)
    assert not safe.unstable


def test_every_solver_keeps_one_step_contract():
    """Explicit, implicit and quasi-static solvers of one world and the implicit and explicit solvers
    of N worlds step with one verb, ``step(state_in, state_out, control, dt, active=None)``; a world
    left out by ``active`` keeps its state; an unbound solver says what is missing."""
    from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler
    from sim_core.solvers.solver import StepReport
    from sim_core.models.stack import ModelStack

    mesh = HexMesh.block((3, 2, 2), 0.01)
    model = build_model(mesh, Material(5e3, 0.45, 1060), gravity=(0, -9.81, 0), hourglass_control=1.0)
    control = model.new_control().impose(np.flatnonzero(mesh.nodes[:, 0] == 0), mesh.nodes[mesh.nodes[:, 0] == 0])
    for name, dt in (("explicit", 1e-4), ("implicit", 0.01), ("static", 0.01)):
        solver = make_integrator(name, model=model)
        state, out = model.new_state(), model.new_state()
        report = solver.step(state, out, control, dt)
        assert isinstance(report, StepReport) and not report.unstable
        reference = model.new_state()
        make_integrator(name).simulate(model, model.new_state(), reference, dt, control)
        np.testing.assert_array_equal(out.positions, reference.positions)  # the same step as simulate
        skipped = model.new_state()
        solver.step(out, skipped, control, dt, active=False)
        np.testing.assert_array_equal(skipped.positions, out.positions)
        assert skipped.time == pytest.approx(out.time + dt)
    with pytest.raises(ValueError, match="bind"):
        make_integrator("implicit").step(model.new_state(), model.new_state(), control, 0.01)

    stack = ModelStack(model, 3)
    fixed = np.broadcast_to(control.fixed, (3,) + control.fixed.shape).copy()
    target = np.broadcast_to(control.target, fixed.shape).copy()
    for solver, dt in ((ImplicitEuler(stack, preconditioner="factorised", threads=1), 0.01),
                       (SymplecticEuler(stack), 1e-4)):
        for index in range(3):
            solver.prepare(index, model, mesh.nodes, dt, control.fixed)
        rest = np.broadcast_to(mesh.nodes, fixed.shape).copy()
        state = State(rest, np.zeros_like(rest))
        out = State(rest.copy(), np.zeros_like(rest))
        active = np.array([True, False, True])
        report = solver.step(state, out, Control(fixed, target, np.zeros_like(rest)), dt, active)
        assert isinstance(report, StepReport) and not report.unstable.any()
        np.testing.assert_array_equal(out.positions[1], rest[1])
        assert np.abs(out.positions[0] - rest[0]).max() > 0  # gravity moved the stepped worlds
        np.testing.assert_array_equal(out.positions[0], out.positions[2])
