"""Solving a scene (``sim_core.studies.scenes.Scene``) on one mesh: its observed quantities at
every tested tool displacement (``solve_scene``: static mass-spring equilibrium, or the neo-Hookean
FEM reference; the floor's or probe's frictionless contact by an active set) and their errors
against a reference solution (``scene_errors``).

Observed quantities (``QUANTITIES``): ``force``, the (3,) force the tool exerts on the tissue (sum
over its imposed components); ``target``, the position of the target point (trilinear interpolation
in its rest element); ``volume``, the relative volume change (V - V0) / V0 of the block.

Error of a quantity q over the K tested displacements (the position-error convention of
docs/physics.md section 7, normalised by the largest reference value rather than case by case, so a
nearly zero value at a small displacement does not dominate):

    error_q = max_k |q_k - q_k^ref| / max_k |q_k^ref|,    target: q = x - X (its displacement).

SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from ..solvers import contact as contact_
from ..solvers.hyperelastic import NeoHookeanFEM
from ..models.model import Control, build_model
from ..solvers.static import lowest_eigenvalue, solve_static
from .scenes import Scene

QUANTITIES = ("force", "target", "volume")


@dataclass
class SceneSolution:
    """Observed quantities of one discretised scene at each tested displacement (path order).

    Attributes:
        shape: elements per axis.  force: (K, 3) N.  target: (K, 3) m.  volume: (K,) (V - V0)/V0.
        target_rest: (3,) m.  converged, stable: (K,) bool (stable None when not checked).
        lowest_eigenvalue: (K,) N/m.  solve_time: s, the static solves only (no stability checks).
        check_time: s spent in the stability checks.
    """

    shape: tuple
    force: np.ndarray
    target: np.ndarray
    volume: np.ndarray
    target_rest: np.ndarray
    converged: np.ndarray
    stable: np.ndarray
    lowest_eigenvalue: np.ndarray
    solve_time: float
    check_time: float = 0.0


#: The mass-spring models a scene is solved with (``mss_model``).
SCENE_MODELS = ("baudet", "baudet-hyperelastic")


def mss_model(mesh, material, gravity, hourglass_control, volume_stiffness, model="baudet", damping_ratio=1.0):
    """The scene's mass-spring ``Model``: "baudet" with the given hourglass control and volume
    stiffness, or "baudet-hyperelastic", which has neither (they are ignored); gravity in m/s^2 along -y."""
    if model not in SCENE_MODELS:
        raise ValueError(f"model must be one of {SCENE_MODELS}, got {model!r}")
    if model == "baudet-hyperelastic":
        return build_model(mesh, material, model=model, gravity=(0.0, -gravity, 0.0), damping_ratio=damping_ratio)
    return build_model(mesh, material, gravity=(0.0, -gravity, 0.0), hourglass_control=hourglass_control,
                       volume_stiffness=volume_stiffness, damping_ratio=damping_ratio)


def mss_solver(mesh, material, gravity, hourglass_control, volume_stiffness, check_stability, model="baudet"):
    """``model_solver`` of a mass-spring ``model`` (``mss_model``)."""
    return model_solver(mss_model(mesh, material, gravity, hourglass_control, volume_stiffness, model),
                        check_stability)


def model_solver(model, check_stability=False):
    """(solve, timer): ``solve(control, initial)`` -> (positions, reaction, converged, lowest
    eigenvalue or None), ``solve_static`` of ``model`` to 1e-8 (two load steps from rest); a
    degenerate configuration is reported as not converged. ``timer["check"]``: seconds spent in the
    stability checks."""
    mesh = model.mesh
    timer = {"check": 0.0}

    def solve(control, initial):
        try:
            return _solve(control, initial)
        except (ArithmeticError, ValueError, RuntimeError):  # degenerate configuration
            return (initial if initial is not None else mesh.nodes).copy(), np.zeros((mesh.n_nodes, 3)), False, None

    def _solve(control, initial):
        result = solve_static(model, control, initial=initial, load_steps=2 if initial is None else 1,
                              tolerance=1e-8)
        lowest = None
        if check_stability and result.converged:
            start = time.perf_counter()
            lowest = lowest_eigenvalue(model, control, result.positions)
            timer["check"] += time.perf_counter() - start
        return result.positions, result.reaction, result.converged, lowest

    return solve, timer


def _fem_solver(mesh, material, gravity, check_stability):
    fem = NeoHookeanFEM(mesh, material)
    timer = {"check": 0.0}

    def solve(control, initial):
        try:
            return _solve(control, initial)
        except (ArithmeticError, ValueError, RuntimeError):  # e.g. an inverted start
            return (initial if initial is not None else mesh.nodes).copy(), np.zeros((mesh.n_nodes, 3)), False, None

    def _solve(control, initial):
        result = fem.solve(control, (0.0, -gravity, 0.0), initial=initial, load_steps=2, tolerance=1e-8)
        lowest = None
        if check_stability and result.converged:
            start = time.perf_counter()
            free = np.flatnonzero(~control.fixed.ravel())
            stiffness = fem.tangent_stiffness(result.positions).tocsr()[free][:, free]
            lowest = float(spla.eigsh(stiffness, k=1, which="SA", tol=1e-6, maxiter=50 * len(free))[0][0])
            timer["check"] += time.perf_counter() - start
        return result.positions, result.reaction, result.converged, lowest

    return solve, timer


def contact_candidates(scene, n_nodes, fixed, tool):
    """(n,) bool: the nodes the scene's obstacle may hold (the floor: every node neither attached nor
    grasped; a probe: its candidates, the tool nodes)."""
    candidates = np.zeros(n_nodes, bool)
    if scene.floor:
        candidates[:] = True
        candidates[np.union1d(fixed, tool)] = False
    elif scene.probe is not None:
        candidates[tool] = True
    return candidates


def tool_control(scene, base, nodes, tool, displacement):
    """``base`` with the tool's nodes imposed at ``displacement`` (m) from rest (a probe imposes
    through its contact instead)."""
    control = base.copy()
    if scene.probe is None:
        control.impose(tool, nodes[tool] + displacement, components=scene.tool_components)
    return control


def tool_force(scene, tool, contact, reaction):
    """(3,) the force (N) the tool exerts on the tissue: the constraint forces ``reaction`` (n, 3)
    on the tool's imposed components, or on the probe's contact nodes (along y)."""
    imposed = np.zeros(reaction.shape, bool)
    if scene.probe is None:
        imposed[np.ix_(tool, scene.tool_components)] = True
    else:
        imposed[contact, 1] = True
    return np.where(imposed, reaction, 0.0).sum(axis=0)


def from_surface(obstacle, heights):
    """``obstacle`` with a projected probe's indentation measured from the node heights ``heights``
    (n,) m (its projection kept: ``SurfaceProjection.with_reference``); other obstacles as they are."""
    projection = getattr(obstacle, "projection", None)
    if projection is None:
        return obstacle
    return contact_.Probe(obstacle.radius, obstacle.tip, projection.with_reference(heights))


def solve_with_contact(solve, control, initial, obstacle, candidates, tip=None, rest=None, max_rounds=25,
                        tolerance=1e-9, slide_tolerance=1e-7):
    """Static solve with a frictionless obstacle (``sim_core.solvers.contact``: the floor y >= 0 or a probe
    from above) by an active set: the candidate nodes (n,) bool on or through its surface get
    their height imposed on it at their (x, z), the nodes it would pull are released, and the
    heights follow the nodes' horizontal sliding (read at ``contact.relaxed_positions``); repeated
    until no node goes through the surface by more than ``tolerance`` (m) and the held heights are
    within ``slide_tolerance`` (m) of the surface under the nodes. Returns (positions, reaction, converged, lowest eigenvalue, control, contact (n,) bool)."""
    if obstacle is None:
        positions, reaction, converged, lowest = solve(control, initial)
        return positions, reaction, converged, lowest, control, np.zeros(len(control.fixed), bool)
    start = rest if initial is None else initial
    contact = contact_.touching(obstacle, start, candidates, tip, tolerance=1e-12)
    sampled = start  # where the held heights are read (``contact.relaxed_positions`` after the first round)
    for _ in range(max_rounds):
        trial = control.copy()
        active = np.flatnonzero(contact)
        if len(active):
            target = start[active].copy()
            target[:, 1] = contact_.targets(obstacle, sampled, contact, tip)[active]
            trial.impose(active, target, components=(1,))
        positions, reaction, converged, lowest = solve(trial, initial if initial is None else start)
        if not converged:
            return positions, reaction, False, lowest, trial, contact
        through = contact_.touching(obstacle, positions, candidates & ~contact, tip, tolerance=-tolerance)
        pulled = contact & ~contact_.release(obstacle, contact, -reaction, tolerance=1e-12)
        drift = contact & (np.abs(contact_.gap(obstacle, positions, tip)) > slide_tolerance)
        if not through.any() and not pulled.any() and not drift.any():
            return positions, reaction, True, lowest, trial, contact
        sampled = contact_.relaxed_positions(sampled, positions, contact)
        contact = (contact | through) & ~pulled
        start = initial = positions  # the solver ramps the newly imposed heights from here
    return positions, reaction, False, lowest, trial, contact


def solve_scene(scene: Scene, shape, *, model="baudet", hourglass_control=0.0, volume_stiffness=1.0,
                check_stability=True) -> SceneSolution:
    """Solve every tested displacement of ``scene`` on a ``shape`` mesh with ``model`` "baudet" or
    "baudet-hyperelastic" (static mass-spring equilibrium; hourglass_control and volume_stiffness
    are baudet's) or "fem-neohookean" (the reference)."""
    mesh, material, fixed, tool, target_nodes, weights = scene.discretise(shape)
    nodes = mesh.nodes
    if model == "fem-neohookean":
        solve, timer = _fem_solver(mesh, material, scene.gravity, check_stability)
    elif model in ("baudet", "baudet-hyperelastic"):
        solve, timer = mss_solver(mesh, material, scene.gravity, hourglass_control, volume_stiffness,
                                  check_stability, model)
    else:
        raise ValueError(f"model must be 'baudet', 'baudet-hyperelastic' or 'fem-neohookean', got {model!r}")
    base = Control.free(mesh.n_nodes).impose(fixed, nodes[fixed])
    candidates = contact_candidates(scene, mesh.n_nodes, fixed, tool)
    obstacle = scene.obstacle(mesh, candidates)
    rest_volume = float(mesh.element_volumes().sum())
    results = dict(force=[], target=[], volume=[], converged=[], lowest=[])
    elapsed = 0.0
    start_clock = time.perf_counter()
    # equilibrium under gravity with the tool at rest (the environments' start state)
    rest_positions = nodes.copy()
    if scene.gravity > 0:
        rest_positions, _, ok, _, _, _ = solve_with_contact(
            solve, tool_control(scene, base, nodes, tool, np.zeros(3)), None, obstacle, candidates,
            scene.probe_tip(np.zeros(3)), rest=nodes)
        rest_positions = rest_positions if ok else nodes.copy()
        # the indentation is measured from the start surface, as in Palpation
        obstacle = from_surface(obstacle, rest_positions[:, 1])
    for path in scene.displacements:
        positions = rest_positions
        for displacement in path:
            control = tool_control(scene, base, nodes, tool, displacement)
            positions, reaction, converged, lowest, _, contact = solve_with_contact(
                solve, control, positions, obstacle, candidates, scene.probe_tip(displacement))
            results["force"].append(tool_force(scene, tool, contact, reaction))
            results["target"].append(weights @ positions[target_nodes])
            results["volume"].append(float(mesh.element_volumes(positions).sum()) / rest_volume - 1.0)
            results["converged"].append(bool(converged))
            results["lowest"].append(np.nan if lowest is None else float(lowest))
            if not converged:
                positions = rest_positions
    elapsed = time.perf_counter() - start_clock - timer["check"]
    lowest = np.asarray(results["lowest"])
    stable = np.where(np.isnan(lowest), None, lowest >= 0.0) if check_stability else np.full(len(lowest), None)
    return SceneSolution(
        shape=tuple(int(s) for s in shape), force=np.asarray(results["force"]), target=np.asarray(results["target"]),
        volume=np.asarray(results["volume"]), target_rest=weights @ nodes[target_nodes],
        converged=np.asarray(results["converged"]), stable=np.asarray(stable, dtype=object),
        lowest_eigenvalue=lowest, solve_time=float(elapsed), check_time=float(timer["check"]),
    )


def scene_errors(solution: SceneSolution, reference: SceneSolution, per_case: bool = False) -> dict:
    """{"force", "target", "volume"}: max over the cases of |q - q_ref| / max |q_ref| (module doc);
    with ``per_case``, the (K,) array |q_k - q_k^ref| / max |q_ref| instead of its maximum."""
    errors = {}
    for name in QUANTITIES:
        value, ref = getattr(solution, name), getattr(reference, name)
        if name == "target":
            value, ref = value - solution.target_rest, ref - reference.target_rest
        difference = np.linalg.norm(np.reshape(value - ref, (len(ref), -1)), axis=1)
        scale = float(np.linalg.norm(np.reshape(ref, (len(ref), -1)), axis=1).max())
        case = difference / scale if scale > 0 else difference
        errors[name] = case if per_case else float(case.max())
    return errors


def check_quantities(quantities) -> tuple:
    """A non-empty subset of QUANTITIES as a tuple, else ValueError naming ``quantities``."""
    try:
        quantities = tuple(quantities)
    except TypeError as error:
        raise ValueError(f"quantities must be a subset of {QUANTITIES}, got {quantities!r}") from error
    if not quantities or any(q not in QUANTITIES for q in quantities):
        raise ValueError(f"quantities must be a non-empty subset of {QUANTITIES}, got {quantities!r}")
    return quantities


def check_tolerances(tolerance, quantities):
    if isinstance(tolerance, dict):
        unknown = set(tolerance) - set(QUANTITIES)
        if unknown:
            raise ValueError(f"tolerance has unknown quantities {sorted(unknown)}; use {QUANTITIES}")
        values = {q: tolerance[q] for q in quantities if q in tolerance}
        missing = [q for q in quantities if q not in values]
        if missing:
            raise ValueError(f"tolerance is missing the quantities {missing}")
    else:
        values = {q: tolerance for q in quantities}
    out = {}
    for name, value in values.items():
        try:
            value = float(value)
        except (TypeError, ValueError) as error:
            raise ValueError(f"tolerance must be a number or a dict of numbers, got {tolerance!r}") from error
        if not math.isfinite(value) or value <= 0:
            raise ValueError(f"tolerance must be > 0 (a relative error, e.g. 0.05), got {tolerance!r}")
        out[name] = value
    return out
