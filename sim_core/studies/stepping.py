"""The cheapest environment stepping for a scene: ``choose_stepping(scene, shape, tolerance)``
compares an environment's stepping (``substeps`` implicit Euler steps of ``dt`` per env step, the
tool moving ``max_step`` per env step) with the static equilibrium at the same tool position on that
mesh (``sim_core.studies.solving.solve_scene``), the errors as ``scene_errors`` defines them.
SI units: m, Pa, N, kg/m^3, m/s^2, s.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from ..solvers import contact as contact_
from ..models.forces import external_forces, internal_forces
from ..solvers.integrators import make_integrator
from ..models.model import Control, State
from ..solvers.static import STATIC_CONTACT_PASSES, same_contact
from .checks import check_integer, check_scalar, check_shape
from .scenes import check_scenes
from .solving import (
    QUANTITIES, SceneSolution, check_quantities, check_tolerances, contact_candidates, from_surface, mss_model,
    mss_solver, scene_errors, solve_scene, solve_with_contact, tool_control, tool_force,
)


@dataclass
class SteppingCandidate:
    """One (dt, substeps) tried by ``choose_stepping`` on one mesh.

    Attributes:
        dt: s per implicit Euler step.  substeps: implicit steps per env step (the cost).
        errors: {quantity: lag error}: max over the tested displacements of |q_dyn - q_static| /
            max |q_static| (the ``scene_errors`` convention), q_dyn observed after the env steps
            that bring the tool there (plus ``hold_steps``), q_static the static equilibrium of the
            same mesh and setting at the same tool position.  None when the run diverged.
        case_errors: {quantity: [per displacement]}.  env_steps: env steps simulated.
        iterations: mean linear-solver iterations per env step.  step_time: s per env step.
        admissible: no divergence and every error within the tolerance.  reason: why not.
    """

    dt: float
    substeps: int
    errors: dict | None
    case_errors: dict | None
    env_steps: int
    iterations: float
    step_time: float
    admissible: bool
    reason: str | None = None

    def summary(self) -> dict:
        return asdict(self)


@dataclass
class SteppingChoice:
    """Outcome of ``choose_stepping``: ``chosen`` (the admissible candidate with the fewest
    implicit steps per env step, then the fewest solver iterations per env step, then the
    smallest error), every candidate, the tolerance and the mesh."""

    chosen: SteppingCandidate | None
    candidates: list
    tolerance: dict
    shape: tuple
    max_step: float
    hold_steps: int
    total_time: float

    def summary(self) -> dict:
        return dict(chosen=None if self.chosen is None else self.chosen.summary(),
                    candidates=[c.summary() for c in self.candidates], tolerance=self.tolerance,
                    shape=list(self.shape), max_step=self.max_step, hold_steps=self.hold_steps,
                    total_time=self.total_time)


def dynamic_scene(scene, shape, *, dt, substeps, max_step, hold_steps, hourglass_control, volume_stiffness,
                  solver_tolerance, solver=None, damping_ratio=1.0, integrator="implicit", model="baudet"):
    """Observed quantities of ``scene`` as an environment produces them: from the static rest state
    (gravity, tool at rest) the tool moves towards each tested displacement by at most ``max_step``
    per component per env step (a scripted controller at full speed; the displacements of a path
    in order), each env step being ``substeps`` implicit Euler steps of ``dt`` (floor: y projected
    after each step, the floor nodes held at y = 0 in the step, as Retraction does), then is held
    ``hold_steps`` env steps; the observation
    is taken then. ``damping_ratio``: ``build_model``'s multiplier of the critical spring damping.
    ``integrator``: "implicit" (``ImplicitEuler`` with ``solver_tolerance`` and the ``solver``
    keywords) or "static" (``sim_core.solvers.static.QuasiStatic``, the ``solver`` keywords: an equilibrium
    per step, as the envs' ``integrator="static"``). ``model``: "baudet" or "baudet-hyperelastic"
    (``solving.mss_model``; hourglass_control and volume_stiffness are baudet's).
    Returns (SceneSolution, env steps, iterations, seconds, divergence reason)."""
    if integrator not in ("implicit", "static"):
        raise ValueError(f"integrator must be 'implicit' or 'static', got {integrator!r}")
    setup = _scene_setup(scene, shape, hourglass_control, volume_stiffness, model, damping_ratio)
    options = dict(solver or {}) if integrator == "static" else dict(tolerance=solver_tolerance, **(solver or {}))
    stepper = make_integrator(integrator, **options)
    passes = STATIC_CONTACT_PASSES if integrator == "static" else 1
    observed = dict(force=[], target=[], volume=[])
    env_steps, iterations = 0, 0
    clock = time.perf_counter()
    for path in scene.displacements:
        state = State(setup.rest.copy(), np.zeros_like(setup.rest))
        scratch = state.copy()
        offset = np.zeros(3)
        # contact as the environments (RetractionEnv's floor, PalpationEnv's probe): the nodes on
        # the obstacle have their height imposed in the step; a node it would pull is released; one
        # that goes through it joins (after a projection)
        contact = (np.zeros(setup.mesh.n_nodes, bool) if setup.obstacle is None else
                   contact_.touching(setup.obstacle, state.positions, setup.candidates, scene.probe_tip(offset), 1e-12))
        for displacement in path:
            moves = int(math.ceil(float(np.max(np.abs(displacement - offset))) / max_step - 1e-9))
            for k in range(moves + hold_steps):
                if k < moves:
                    offset = offset + np.clip(displacement - offset, -max_step, max_step)
                control, contact = _formed_control(setup, state, offset, contact)
                state, scratch, control, contact, count, reason = _env_step(
                    setup, stepper, state, scratch, control, contact, offset, dt, substeps, passes)
                iterations += count
                if reason is not None:
                    return None, env_steps, iterations, time.perf_counter() - clock, reason
                env_steps += 1
            _observe(setup, state, control, contact, observed)
    elapsed = time.perf_counter() - clock
    count = len(observed["volume"])
    solution = SceneSolution(
        shape=tuple(shape), force=np.asarray(observed["force"]), target=np.asarray(observed["target"]),
        volume=np.asarray(observed["volume"]), target_rest=setup.weights @ setup.mesh.nodes[setup.target_nodes],
        converged=np.ones(count, bool), stable=np.full(count, None, dtype=object),
        lowest_eigenvalue=np.full(count, np.nan), solve_time=elapsed)
    return solution, env_steps, iterations, elapsed, None


@dataclass
class _SceneSetup:
    """What ``dynamic_scene`` steps: the scene on its mesh, the model, the fixed nodes' control
    (``base``), the tool's nodes, the contact's candidates and obstacle (None without one), the
    rest state (m) and its volume (m^3), the observed target's nodes and weights."""

    scene: object
    mesh: object
    model: object
    base: Control
    tool: np.ndarray
    candidates: np.ndarray
    obstacle: object
    rest: np.ndarray
    rest_volume: float
    target_nodes: np.ndarray
    weights: np.ndarray


def _scene_setup(scene, shape, hourglass_control, volume_stiffness, model_name, damping_ratio):
    """``dynamic_scene``'s ``_SceneSetup``: the rest state is the static equilibrium under gravity with
    the tool at rest (the mesh's nodes without gravity, or where that solve fails), and the obstacle
    follows the rest state's heights."""
    mesh, material, fixed, tool, target_nodes, weights = scene.discretise(shape)
    nodes = mesh.nodes
    model = mss_model(mesh, material, scene.gravity, hourglass_control, volume_stiffness, model_name, damping_ratio)
    solve, _ = mss_solver(mesh, material, scene.gravity, hourglass_control, volume_stiffness, False, model_name)
    base = Control.free(mesh.n_nodes).impose(fixed, nodes[fixed])
    candidates = contact_candidates(scene, mesh.n_nodes, fixed, tool)
    obstacle = scene.obstacle(mesh, candidates)
    rest = nodes.copy()
    if scene.gravity > 0:
        rest, _, ok, _, _, _ = solve_with_contact(solve, tool_control(scene, base, nodes, tool, np.zeros(3)), None,
                                                   obstacle, candidates, scene.probe_tip(np.zeros(3)), rest=nodes)
        rest = rest if ok else nodes.copy()
        obstacle = from_surface(obstacle, rest[:, 1])
    return _SceneSetup(scene, mesh, model, base, tool, candidates, obstacle, rest, float(mesh.element_volumes().sum()),
                       target_nodes, weights)


def _formed_control(setup, state, offset, contact):
    """The step's control at ``state``: the tool at ``offset`` (m), and the contact's active set
    updated (nodes touching join, nodes the tissue pulls away leave) with their heights imposed."""
    scene, obstacle = setup.scene, setup.obstacle
    control = tool_control(scene, setup.base, setup.mesh.nodes, setup.tool, offset)
    if obstacle is None:
        return control, contact
    tip = scene.probe_tip(offset)
    net = internal_forces(setup.model, state.positions, state.velocities) + external_forces(setup.model, control)
    contact = contact_.update(obstacle, contact, state.positions, net, setup.candidates, tip)
    held = np.flatnonzero(contact)
    if len(held):
        target = state.positions[held].copy()
        target[:, 1] = contact_.targets(obstacle, state.positions, contact, tip)[held]
        control.impose(held, target, components=(1,))
    return control, contact


def _env_step(setup, stepper, state, scratch, control, contact, offset, dt, substeps, passes):
    """One env step: ``substeps`` steps of ``dt`` s under ``control``, each with up to ``passes``
    contact passes (the active set iterated within the step, as TissueEnv._advance). Returns (state,
    scratch, control, contact, solver iterations, divergence reason or None); after a divergence the
    states are those of the failed step."""
    obstacle, model = setup.obstacle, setup.model
    tip = setup.scene.probe_tip(offset)
    iterations = 0
    for _ in range(substeps):
        for attempt in range(passes):
            with np.errstate(all="ignore"):
                report = stepper.simulate(model, state, scratch, dt, control)
            iterations += report.iterations
            reason = report.unstable_reason
            if reason is None and not np.all(np.isfinite(scratch.positions)):
                reason = "non-finite positions"
            if reason is not None:
                return state, scratch, control, contact, iterations, reason
            if obstacle is not None:
                contact |= contact_.project(obstacle, scratch.positions, scratch.velocities, setup.candidates, tip)
            state, scratch = scratch, state
            if obstacle is None or attempt + 1 == passes:
                break
            previous = control
            control, contact = _formed_control(setup, state, offset, contact)
            if same_contact(previous, control):
                break
    return state, scratch, control, contact, iterations, None


def _observe(setup, state, control, contact, observed):
    """Appends the observed quantities at ``state`` to ``observed``: the tool's force (N, as
    TissueEnv._measure), the target's position (m) and the relative volume change."""
    positions = state.positions
    forces = internal_forces(setup.model, positions, state.velocities) + external_forces(setup.model, control)
    observed["force"].append(tool_force(setup.scene, setup.tool, contact, -forces))
    observed["target"].append(setup.weights @ positions[setup.target_nodes])
    observed["volume"].append(float(setup.mesh.element_volumes(positions).sum()) / setup.rest_volume - 1.0)


def stepping_error(scene, shape, *, dt=0.02, substeps=1, max_step=0.002, hold_steps=0, hourglass_control=1.0,
                   volume_stiffness=100.0, static=None, tolerance=0.05, solver_tolerance=1e-4,
                   solver=None, model="baudet") -> SteppingCandidate:
    """How far an environment's stepping (``substeps`` implicit Euler steps of ``dt`` per env step,
    the tool moving ``max_step`` per env step, then held ``hold_steps`` env steps) leaves the
    observed quantities from the static equilibrium at the same tool position, on ``shape``.

    Args:
        scene: a ``Scene`` or a list of them.  shape: elements per axis.
        static: the scenes' static ``SceneSolution`` s on ``shape`` with the same setting
            (computed when None).
        tolerance: relative error allowed (a number or a dict per quantity) for ``admissible``.
        solver_tolerance: relative residual of the linear solves (the envs' default, 1e-4).
        solver: further ``ImplicitEuler`` keywords (e.g. ``preconditioner``, ``max_iterations``);
            None: its defaults.
        model: "baudet" or "baudet-hyperelastic" (which ignores hourglass_control and volume_stiffness).
    Returns:
        ``SteppingCandidate`` (errors in the ``scene_errors`` convention against ``static``).
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    scenes = check_scenes(scene)
    shape = check_shape("shape", shape)
    dt = check_scalar("dt", dt, low=0.0)
    substeps = check_integer("substeps", substeps, 1)
    max_step = check_scalar("max_step", max_step, low=0.0)
    hold_steps = check_integer("hold_steps", hold_steps, 0)
    alpha = check_scalar("hourglass_control", hourglass_control, low=0.0, strict=False)
    kappa = check_scalar("volume_stiffness", volume_stiffness, low=0.0, strict=False)
    tolerance = tolerance if isinstance(tolerance, dict) and set(tolerance) <= set(QUANTITIES) and all(
        isinstance(v, float) for v in tolerance.values()) else check_tolerances(tolerance, QUANTITIES)
    if static is None:
        static = [solve_scene(s, shape, model=model, hourglass_control=alpha, volume_stiffness=kappa,
                              check_stability=False) for s in scenes]
    errors, case_errors, steps, iterations, elapsed = {}, {q: [] for q in QUANTITIES}, 0, 0, 0.0
    for scene_, reference in zip(scenes, static):
        solution, n, its, seconds, reason = dynamic_scene(
            scene_, shape, dt=dt, substeps=substeps, max_step=max_step, hold_steps=hold_steps,
            hourglass_control=alpha, volume_stiffness=kappa, solver_tolerance=solver_tolerance, solver=solver,
            model=model)
        steps, iterations, elapsed = steps + n, iterations + its, elapsed + seconds
        if solution is None:
            return SteppingCandidate(dt, substeps, None, None, steps, iterations / max(steps, 1),
                                     elapsed / max(steps, 1), False, f"diverged: {reason}")
        for name, value in scene_errors(solution, reference, per_case=True).items():
            errors[name] = max(errors.get(name, 0.0), float(value.max()))
            case_errors[name].extend(float(v) for v in value)
    errors = {q: errors[q] for q in tolerance}
    reason = None
    if not all(errors[q] <= tolerance[q] for q in tolerance):
        worst = max(tolerance, key=lambda q: errors[q] / tolerance[q])
        reason = f"{worst} lag {errors[worst]:.3g} > {tolerance[worst]:.3g}"
    return SteppingCandidate(dt, substeps, errors, case_errors, steps, iterations / max(steps, 1),
                             elapsed / max(steps, 1), reason is None, reason)


def choose_stepping(scene, shape, tolerance=0.05, *, dts=(0.01, 0.02, 0.04), substeps=(1, 2), max_step=0.002,
                    hold_steps=0, hourglass_control=1.0, volume_stiffness=100.0, quantities=QUANTITIES,
                    static=None, solver_tolerance=1e-4, solver=None, model="baudet") -> SteppingChoice:
    """The cheapest env stepping (``dt``, ``substeps``) whose observations stay within ``tolerance``
    of the static equilibrium at the same tool position (``stepping_error``) on ``shape``.

    Cheapest: fewest implicit steps per env step (``substeps``), then fewest linear-solver
    iterations per env step, then the smallest worst error / tolerance. ``solver_tolerance``,
    ``solver`` (``ImplicitEuler`` keywords) and ``model`` as in ``stepping_error``.
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    clock = time.perf_counter()
    scenes = check_scenes(scene)
    quantities = check_quantities(quantities)
    tolerance = check_tolerances(tolerance, quantities)
    try:
        dts = sorted({check_scalar("dts", d, low=0.0) for d in dts})
        substeps = sorted({check_integer("substeps", s, 1) for s in substeps})
    except TypeError as error:
        raise ValueError(f"dts and substeps must be sequences, got {dts!r} and {substeps!r}") from error
    if not dts:
        raise ValueError("dts must hold at least one time step > 0 s")
    if not substeps:
        raise ValueError("substeps must hold at least one integer >= 1")
    shape = tuple(int(s) for s in shape)
    if static is None:
        static = [solve_scene(s, shape, model=model, hourglass_control=hourglass_control,
                              volume_stiffness=volume_stiffness, check_stability=False) for s in scenes]
    candidates = [stepping_error(scenes, shape, dt=dt, substeps=n, max_step=max_step, hold_steps=hold_steps,
                                 hourglass_control=hourglass_control, volume_stiffness=volume_stiffness,
                                 static=static, tolerance=tolerance, solver_tolerance=solver_tolerance, solver=solver,
                                 model=model)
                  for n in substeps for dt in dts]
    admissible = [c for c in candidates if c.admissible]
    chosen = None
    if admissible:
        chosen = min(admissible, key=lambda c: (c.substeps, round(c.iterations, 1),
                                                max(c.errors[q] / tolerance[q] for q in tolerance)))
    return SteppingChoice(chosen, candidates, tolerance, shape, float(max_step), int(hold_steps),
                          time.perf_counter() - clock)
