"""Model no more than a scene needs: the coarsest mass-spring resolution, and the cheapest env
stepping, that keep a scene's observed quantities within a tolerance of the fine model (issue 6,
sec. 3). This module chooses the resolution, ``sim_core.studies.stepping`` the stepping; both solve
the scenes of ``sim_core.studies.scenes`` with ``sim_core.studies.solving``.

Two references: the fine model (the default of ``choose_resolution``: ``reference`` = its ``model``,
"baudet" or "baudet-hyperelastic") is the same mass-spring model and setting on a fine mesh, so the
error is the discretisation error alone;
``"fem-neohookean"`` is a finite-element continuum model, so the error adds the constitutive
difference (the mass-spring law departs from neo-Hookean at large strain and that part does not
fall with resolution).

``choose_resolution(scene, tolerance)`` solves the scene with the reference on a
fine mesh, then with the mass-spring model at increasing resolutions (static equilibrium,
``solve_static(..., check_stability=True)``) for each setting in a small grid of
``hourglass_control`` x ``volume_stiffness``, and returns the coarsest resolution, and at it the
setting with the smallest error, whose observed quantities

- ``force``: the (3,) force the tool exerts on the tissue (sum over its imposed components),
- ``target``: the position of the target point (trilinear interpolation in its rest element),
- ``volume``: the relative volume change (V - V0) / V0 of the block,

all stay within ``tolerance`` of the reference at every tested tool displacement, with every
equilibrium converged and stable (a saddle, e.g. hourglass buckling, is not admissible: a dynamic
simulation does not stay there). The error of a quantity is ``scene_errors``' (its definition:
``sim_core.studies.solving``): max_k |q_k - q_k^ref| / max_k |q_k^ref| over the K displacements.

Resolution ``n`` means elements no larger than ``max(size) / n`` along any axis (``Scene.shape``).
Shapes whose elements the mass-spring model rejects ("baudet": boxes, whose shear modulus its
springs get wrong, or too elongated for its stiffness; docs/physics.md section 2) are reported as
inadmissible. The settings do not change the number of
unknowns; their measured solve times are reported next to the errors.
SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .checks import check_scalar, check_shape
from .scenes import Scene, check_scenes
from .solving import QUANTITIES, check_quantities, check_tolerances, scene_errors, solve_scene


@dataclass
class Candidate:
    """One (resolution, setting) tried by ``choose_resolution``.

    Attributes:
        resolution: n (elements no longer than max(size) / n).  shape: elements per axis.
        hourglass_control, volume_stiffness: the mass-spring setting.
        errors: {quantity: relative error} (max over scenes and displacements), None if not solved.
        converged, stable: every equilibrium converged / is a minimum (check_stability).
        admissible: converged, stable and every error within its tolerance.
        solve_time: s of static solves (sum over the scenes' displacements); n_nodes.
        reason: why it is not admissible (None when it is).
    """

    resolution: int
    shape: tuple
    hourglass_control: float
    volume_stiffness: float
    errors: dict | None
    converged: bool
    stable: bool
    admissible: bool
    solve_time: float
    n_nodes: int
    reason: str | None = None
    lowest_eigenvalue: float | None = None
    case_errors: dict | None = None
    case_stable: list | None = None

    def worst_ratio(self, tolerance: dict) -> float:
        """max over quantities of error / tolerance (inf when not solved)."""
        if self.errors is None:
            return math.inf
        return max(self.errors[q] / tolerance[q] for q in tolerance)

    def summary(self) -> dict:
        out = asdict(self)
        out["shape"] = list(self.shape)
        return out


@dataclass
class ResolutionChoice:
    """Outcome of ``choose_resolution``.

    Attributes:
        chosen: the admissible ``Candidate`` of the coarsest resolution (smallest worst error over
            tolerance among that resolution's settings), or None when none is admissible.
        best: the converged, stable candidate with the smallest worst error / tolerance (what
            comes closest when nothing is admissible; the coarsest one among those within 10% of
            that smallest ratio), or None.
        candidates: every candidate tried, in order.  tolerance: {quantity: tolerance}.
        reference_shape: the reference mesh (per scene).  reference_time: s (all references).
        reference_stable: every reference equilibrium is a minimum.  reference: the solutions
            (for a fine mass-spring model, a dict {(hourglass_control, volume_stiffness): solutions}).
        total_time: s.  reference_model: the fine mass-spring model ("baudet",
            "baudet-hyperelastic") or "fem-neohookean".
        reference_convergence: for a fine mass-spring reference, per setting, the errors of the
            finest candidate coarser than the reference against it (how far the reference itself may be from
            convergence), a list of dicts; None for "fem-neohookean".
    """

    chosen: Candidate | None
    best: Candidate | None
    candidates: list
    tolerance: dict
    reference_shape: list
    reference_time: float
    reference_stable: bool
    reference_converged: bool
    total_time: float
    reference: list = field(default_factory=list, repr=False)
    reference_model: str = "fem-neohookean"
    reference_convergence: list | None = None

    @property
    def resolution(self) -> int | None:
        return None if self.chosen is None else self.chosen.resolution

    def summary(self) -> dict:
        return dict(
            chosen=None if self.chosen is None else self.chosen.summary(),
            best=None if self.best is None else self.best.summary(),
            candidates=[c.summary() for c in self.candidates], tolerance=self.tolerance,
            reference_shape=[list(s) for s in self.reference_shape], reference_time=self.reference_time,
            reference_stable=self.reference_stable, reference_converged=self.reference_converged,
            total_time=self.total_time, reference_model=self.reference_model,
            reference_convergence=self.reference_convergence,
        )


def _settings(name, values, low):
    try:
        values = sorted({float(v) for v in values})
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a non-empty sequence of numbers >= {low}, got {values!r}") from error
    if not values or any(not math.isfinite(v) or v < low for v in values):
        raise ValueError(f"{name} must be a non-empty sequence of finite numbers >= {low}, got {values!r}")
    return values


def evaluate(scenes, shape, references, tolerance, *, hourglass_control, volume_stiffness, resolution=None,
             model="baudet"):
    """Solve ``scenes`` (a Scene or a list) with one mass-spring setting on ``shape`` and compare
    with ``references`` (their ``SceneSolution`` s): a ``Candidate``. ``model``: "baudet" (with
    ``hourglass_control`` and ``volume_stiffness``) or "baudet-hyperelastic" (which ignores them)."""
    scenes = [scenes] if isinstance(scenes, Scene) else list(scenes)
    tolerance = check_tolerances(tolerance, QUANTITIES) if not isinstance(tolerance, dict) else tolerance
    shape = tuple(int(s) for s in shape)
    n_nodes = int(np.prod(np.asarray(shape) + 1))
    common = dict(resolution=resolution, shape=shape, hourglass_control=float(hourglass_control),
                  volume_stiffness=float(volume_stiffness), n_nodes=n_nodes)
    errors, converged, stable, elapsed, lowest = {}, True, True, 0.0, np.inf
    case_errors, case_stable = {q: [] for q in QUANTITIES}, []
    for scene, reference in zip(scenes, references):
        try:
            solution = solve_scene(scene, shape, hourglass_control=hourglass_control,
                                   volume_stiffness=volume_stiffness, model=model)
        except ValueError as error:  # e.g. elements too elongated for Baudet's stiffness
            return Candidate(errors=None, converged=False, stable=False, admissible=False, solve_time=0.0,
                             reason=f"model rejected: {str(error).splitlines()[0][:160]}", **common)
        elapsed += solution.solve_time
        converged &= bool(np.all(solution.converged))
        stable &= bool(all(s is True for s in solution.stable))
        finite = solution.lowest_eigenvalue[np.isfinite(solution.lowest_eigenvalue)]
        if len(finite):
            lowest = min(lowest, float(finite.min()))
        for name, value in scene_errors(solution, reference, per_case=True).items():
            errors[name] = max(errors.get(name, 0.0), float(value.max()))
            case_errors[name].extend(float(v) for v in value)
        case_stable.extend(None if v is None else bool(v) for v in solution.stable)
    errors = {q: errors[q] for q in tolerance}
    within = all(errors[q] <= tolerance[q] for q in tolerance)
    reason = None
    if not converged:
        reason = "static solve did not converge"
    elif not stable:
        reason = "unstable equilibrium (saddle)"
    elif not within:
        worst = max(tolerance, key=lambda q: errors[q] / tolerance[q])
        reason = f"{worst} error {errors[worst]:.3g} > {tolerance[worst]:.3g}"
    return Candidate(errors=errors, converged=converged, stable=stable, admissible=reason is None,
                     solve_time=elapsed, reason=reason, lowest_eigenvalue=None if lowest == np.inf else lowest,
                     case_errors=case_errors, case_stable=case_stable, **common)


#: The mass-spring models ``choose_resolution`` tries (its ``model``), each its own fine reference.
MSS_MODELS = ("baudet", "baudet-hyperelastic")
REFERENCE_MODELS = MSS_MODELS + ("fem-neohookean",)


class References(tuple):
    """``(solutions, shapes, seconds)`` from ``reference_solutions`` (a plain 3-tuple when
    unpacked), with the reference ``model`` and, for a mass-spring model, its ``hourglass_control`` and
    ``volume_stiffness`` (0 for "baudet-hyperelastic", which has neither; None for "fem-neohookean")."""

    def __new__(cls, solutions, shapes, seconds, model="fem-neohookean", hourglass_control=None,
                volume_stiffness=None):
        out = super().__new__(cls, (solutions, shapes, seconds))
        out.model, out.hourglass_control, out.volume_stiffness = model, hourglass_control, volume_stiffness
        return out

    @property
    def setting(self):
        return None if self.model not in MSS_MODELS else (self.hourglass_control, self.volume_stiffness)


def _reference_shape_arguments(reference_resolution, reference_shape):
    if reference_shape is None:
        try:
            value = int(reference_resolution)
            exact = float(reference_resolution) == value
        except (TypeError, ValueError) as error:
            raise ValueError(f"reference_resolution must be an integer >= 2, got {reference_resolution!r}") from error
        if value < 2 or not exact:
            raise ValueError(f"reference_resolution must be an integer >= 2, got {reference_resolution!r}")
        return value, None
    return reference_resolution, check_shape("reference_shape", reference_shape)


def reference_solutions(scenes, *, reference_resolution=10, reference_shape=None, model="fem-neohookean",
                        hourglass_control=1.0, volume_stiffness=100.0) -> References:
    """Reference solutions of ``scenes`` on their fine meshes: ``References`` (solutions, shapes, seconds).

    Args:
        reference_resolution: n of the reference mesh (``Scene.shape(n)``), or ``reference_shape``.
        model: "fem-neohookean" (the constitutive reference: a converged continuum model),
            "baudet" (the same mass-spring model, with ``hourglass_control`` and
            ``volume_stiffness``, on the fine mesh: the discretisation reference) or
            "baudet-hyperelastic" (the same, without those settings).
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    scenes = check_scenes(scenes, "scenes")
    if model not in REFERENCE_MODELS:
        raise ValueError(f"model must be one of {REFERENCE_MODELS}, got {model!r}")
    reference_resolution, reference_shape = _reference_shape_arguments(reference_resolution, reference_shape)
    shapes = [reference_shape if reference_shape is not None else s.shape(reference_resolution) for s in scenes]
    start = time.perf_counter()
    if model in MSS_MODELS:
        alpha, kappa = _setting(model, hourglass_control, volume_stiffness)
        solutions = [solve_scene(s, shape, model=model, hourglass_control=alpha, volume_stiffness=kappa)
                     for s, shape in zip(scenes, shapes)]
        return References(solutions, shapes, time.perf_counter() - start, model, alpha, kappa)
    solutions = [solve_scene(s, shape, model="fem-neohookean") for s, shape in zip(scenes, shapes)]
    return References(solutions, shapes, time.perf_counter() - start)


def _setting(model, hourglass_control, volume_stiffness):
    """(alpha, kappa) of a mass-spring ``model``: checked for "baudet", (0, 0) for "baudet-hyperelastic"
    (no hourglass control, no volume forces)."""
    if model == "baudet-hyperelastic":
        return 0.0, 0.0
    return (check_scalar("hourglass_control", hourglass_control, low=0.0, strict=False),
            check_scalar("volume_stiffness", volume_stiffness, low=0.0, strict=False))


def _reference_map(references, model, settings, scenes, reference_resolution, reference_shape):
    """{setting: References} for a mass-spring ``model`` ({None: References} for "fem-neohookean"), computing
    the ones not given."""
    given = {}
    if references is not None:
        items = references.values() if isinstance(references, dict) else [references]
        for item in items:
            try:
                solutions, shapes, seconds = item
            except (TypeError, ValueError) as error:
                raise ValueError("references must be reference_solutions(...) results (or a dict of them)") from error
            if len(solutions) != len(scenes):
                raise ValueError(f"references hold {len(solutions)} solutions for {len(scenes)} scenes")
            item_model = getattr(item, "model", "fem-neohookean")
            if item_model != model:
                raise ValueError(f"references are {item_model!r} solutions but reference is {model!r}")
            given[getattr(item, "setting", None)] = item
    if model == "fem-neohookean":
        if None not in given:
            given[None] = reference_solutions(scenes, reference_resolution=reference_resolution,
                                              reference_shape=reference_shape)
        return given
    out = {}
    for alpha, kappa in settings:
        out[(alpha, kappa)] = given.get((alpha, kappa)) or reference_solutions(
            scenes, reference_resolution=reference_resolution, reference_shape=reference_shape, model=model,
            hourglass_control=alpha, volume_stiffness=kappa)
    return out


def choose_resolution(scene, tolerance=0.05, *, resolutions=range(2, 9), hourglass_controls=(0.0, 0.25, 0.5, 1.0),
                      volume_stiffnesses=(1.0, 100.0), reference=None, reference_resolution=10, reference_shape=None,
                      quantities=QUANTITIES, full_scan=False, references=None, model="baudet") -> ResolutionChoice:
    """The coarsest mass-spring resolution and setting that reproduce ``scene`` within ``tolerance``.

    Args:
        scene: a ``Scene`` or a list of them (same block, e.g. probes at several places): the errors
            are the worst over all of them.
        tolerance: relative error allowed on each observed quantity (e.g. 0.05), or a dict
            {"force": ..., "target": ..., "volume": ...} (``sim_core.studies.solving`` for the definition).
        resolutions: the n to try, coarsest first (integers >= 1; ``Scene.shape(n)``).
        hourglass_controls: alpha values to try (>= 0).  volume_stiffnesses: kappa multipliers (>= 0).
            Both "baudet"'s only.
        reference: ``model`` (the fine model: the same mass-spring model and setting on the
            reference mesh; only resolutions strictly coarser than it can be chosen) or
            "fem-neohookean" (the constitutive reference). Default: the model of ``references``
            when given, else ``model``.
        reference_resolution: n of the reference mesh (or ``reference_shape``).
        quantities: which observed quantities must meet the tolerance (a subset of QUANTITIES).
        full_scan: try every resolution (for charts); otherwise stop at the first one with an
            admissible setting.
        references: precomputed ``reference_solutions(...)`` result to reuse (for the fine model, one per
            setting: a single result or a dict {(alpha, kappa): result}; missing ones are computed).
        model: the mass-spring model of the candidates, "baudet" (with the settings) or
            "baudet-hyperelastic" (one setting: no hourglass control, no volume forces; boxes the
            "baudet" model refuses are admissible to it).
    Returns:
        ``ResolutionChoice``; ``chosen`` is None when no candidate is admissible.
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    clock = time.perf_counter()
    scenes = check_scenes(scene)
    if any(not np.allclose(s.size, scenes[0].size) for s in scenes):
        raise ValueError("scene: every Scene in the list must have the same size")
    if model not in MSS_MODELS:
        raise ValueError(f"model must be one of {MSS_MODELS}, got {model!r}")
    reference = _reference_model(reference, references, model)
    fine = reference != "fem-neohookean"
    quantities = check_quantities(quantities)
    tolerance = check_tolerances(tolerance, quantities)
    resolutions = _check_resolutions(resolutions)
    hourglass_controls = _settings("hourglass_controls", hourglass_controls, 0.0)
    volume_stiffnesses = _settings("volume_stiffnesses", volume_stiffnesses, 0.0)
    reference_resolution, reference_shape = _reference_shape_arguments(reference_resolution, reference_shape)
    settings = ([_setting(model, None, None)] if model == "baudet-hyperelastic" else
                [(alpha, kappa) for alpha in hourglass_controls for kappa in volume_stiffnesses])
    ref_map = _reference_map(references, reference, settings, scenes, reference_resolution, reference_shape)
    ref_of = (lambda setting: ref_map[None]) if reference == "fem-neohookean" else ref_map.__getitem__
    everything = list(ref_map.values())
    ref_converged = all(bool(np.all(s.converged)) for r in everything for s in r[0])
    ref_stable = all(all(v is True for v in s.stable) for r in everything for s in r[0])
    ref_shapes, ref_time = everything[0][1], float(sum(r[2] for r in everything))
    # a fine-model reference admits only candidates strictly coarser than its mesh
    ref_nodes = int(np.prod(np.asarray(ref_shapes[0]) + 1)) if fine else None

    candidates, chosen = _scan_resolutions(scenes, resolutions, settings, ref_of, tolerance, model, ref_nodes,
                                           full_scan)
    best = _best_candidate(candidates, tolerance, ref_nodes)
    convergence = None if not fine else _reference_convergence(candidates, settings, ref_nodes, ref_shapes[0])
    solutions = ref_map[None][0] if reference == "fem-neohookean" else {k: v[0] for k, v in ref_map.items()}
    return ResolutionChoice(chosen=chosen, best=best, candidates=candidates, tolerance=tolerance,
                            reference_shape=[list(s) for s in ref_shapes], reference_time=ref_time,
                            reference_stable=ref_stable, reference_converged=ref_converged,
                            total_time=time.perf_counter() - clock, reference=solutions,
                            reference_model=reference, reference_convergence=convergence)


def _reference_model(reference, references, model):
    """``choose_resolution``'s reference model, checked: the given one, else that of ``references``
    (a single ``reference_solutions`` result), else ``model`` (none, or a dict of them per setting)."""
    if reference is None:
        reference = getattr(references, "model", "fem-neohookean") if isinstance(references, tuple) else (
            model if references is None or isinstance(references, dict) else "fem-neohookean")
    if reference not in (model, "fem-neohookean"):
        raise ValueError(f"reference must be the candidates' model {model!r} (the fine model) or 'fem-neohookean', "
                         f"got {reference!r}")
    return reference


def _check_resolutions(resolutions):
    """The distinct resolutions n, sorted, of a non-empty sequence of integers >= 1; ValueError otherwise."""
    try:
        given = list(resolutions)
        checked = [int(r) for r in given]
        exact = all(float(a) == b for a, b in zip(given, checked))
    except (TypeError, ValueError) as error:
        raise ValueError(f"resolutions must be integers >= 1, got {resolutions!r}") from error
    if not checked or not exact or min(checked) < 1:
        raise ValueError(f"resolutions must be a non-empty sequence of integers >= 1, got {checked!r}")
    return sorted(set(checked))


def _scan_resolutions(scenes, resolutions, settings, ref_of, tolerance, model, ref_nodes, full_scan):
    """(every candidate evaluated, the chosen one or None): each resolution, coarsest first, with every
    setting; the chosen one is the admissible candidate of the coarsest resolution that has one (the
    smallest worst error ratio, then the fastest), and the scan stops there unless ``full_scan``. With
    ``ref_nodes`` (a fine-model reference's node count) a candidate with as many nodes is not admissible."""
    candidates, chosen = [], None
    seen = set()
    for resolution in resolutions:
        shape = scenes[0].shape(resolution)
        if shape in seen:  # min_shape or rounding can map two n to one mesh
            continue
        seen.add(shape)
        here = []
        for alpha, kappa in settings:
            candidate = evaluate(scenes, shape, ref_of((alpha, kappa))[0], tolerance, hourglass_control=alpha,
                                 volume_stiffness=kappa, resolution=resolution, model=model)
            if ref_nodes is not None and candidate.admissible and candidate.n_nodes >= ref_nodes:
                candidate.admissible, candidate.reason = False, "not coarser than the reference"
            here.append(candidate)
        candidates.extend(here)
        admissible = [c for c in here if c.admissible]
        if admissible and chosen is None:
            chosen = min(admissible, key=lambda c: (c.worst_ratio(tolerance), c.solve_time))
            if not full_scan:
                break
    return candidates, chosen


def _best_candidate(candidates, tolerance, ref_nodes):
    """The smallest sound candidate (converged, stable, with errors; coarser than a fine-model reference
    of ``ref_nodes`` nodes) whose worst error ratio is within 10% of the least one; None when none is."""
    sound = [c for c in candidates if c.converged and c.stable and c.errors is not None
             and (ref_nodes is None or c.n_nodes < ref_nodes)]
    if not sound:
        return None
    smallest = min(c.worst_ratio(tolerance) for c in sound)
    return min((c for c in sound if c.worst_ratio(tolerance) <= 1.1 * smallest),
               key=lambda c: (c.n_nodes, c.worst_ratio(tolerance)))


def _reference_convergence(candidates, settings, ref_nodes, ref_shape):
    """Per setting, the errors of the finest candidate coarser than the fine-model reference (shape
    ``ref_shape``, ``ref_nodes`` nodes): how far the model is from its own converged solution."""
    convergence = []
    for alpha, kappa in settings:
        coarser = [c for c in candidates if c.errors is not None and c.n_nodes < ref_nodes
                   and (c.hourglass_control, c.volume_stiffness) == (alpha, kappa)]
        finest = max(coarser, key=lambda c: c.n_nodes, default=None)
        convergence.append(dict(
            hourglass_control=alpha, volume_stiffness=kappa, reference_shape=list(ref_shape),
            resolution=None if finest is None else finest.resolution,
            shape=None if finest is None else list(finest.shape),
            errors=None if finest is None else finest.errors))
    return convergence
