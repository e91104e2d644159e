"""Model no more than a scene needs: the coarsest mass-spring resolution, and the cheapest env
stepping, that keep a scene's observed quantities within a tolerance of the fine model (issue 6,
sec. 3).

Two references: ``reference="baudet"`` (the default of ``choose_resolution``) is the same
mass-spring model and setting on a fine mesh, so the error is the discretisation error alone;
``"fem-neohookean"`` is a finite-element continuum model, so the error adds the constitutive
difference (the mass-spring law departs from neo-Hookean at large strain and that part does not
fall with resolution). ``choose_stepping(scene, shape, tolerance)`` then compares an
environment's stepping (``substeps`` implicit Euler steps of ``dt`` per env step, the tool moving
``max_step`` per env step) with the static equilibrium at the same tool position on that mesh.

A ``Scene`` describes a tool task on a block of tissue the way an environment sets it up: the
block (size in m, material, optionally a stiffer box-shaped inclusion), the face attached to the
body, gravity, an optional rigid floor y >= 0 (frictionless unilateral contact), the tool (the
surface nodes inside a box, optionally a vertical cylinder, and which components it imposes),
the tool displacements to test (paths solved by continuation) and a target point inside the block.

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
simulation does not stay there).

Error of a quantity q over the K tested displacements (the position-error convention of
physics.md section 7, normalised by the largest reference value rather than case by case, so a
nearly zero value at a small displacement does not dominate):

    error_q = max_k |q_k - q_k^ref| / max_k |q_k^ref|,    target: q = x - X (its displacement).

Resolution ``n`` means elements no larger than ``h = max(size) / n`` along any axis:
``shape_i = max(min_shape_i, ceil(size_i / h))`` (so n = 4 on a cube is 4x4x4, on a 6 x 3 x 6 cm
slab n = 5 is 5x3x5). Shapes whose elements the mass-spring model rejects (too elongated for
Baudet's stiffness, physics.md section 2) are reported as inadmissible. The settings do not
change the number of unknowns; their measured solve times are reported next to the errors.
SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import contact as contact_
from ..hyperelastic import NeoHookeanFEM
from ..material import Material
from ..mesh import LOCAL_CORNERS, HexMesh
from ..model import Control, build_model
from ..static import solve_static

QUANTITIES = ("force", "target", "volume")
FACES = ("x-", "x+", "y-", "y+", "z-", "z+")


# -- input checks (ValueError naming the argument) ------------------------------------------------
def _vector(name, value, *, positive=False):
    try:
        array = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number or three numbers, got {value!r}") from error
    if not np.all(np.isfinite(array)) or (positive and np.any(array <= 0)):
        raise ValueError(f"{name} must be three finite numbers{' > 0' if positive else ''}, got {value!r}")
    return array


def _scalar(name, value, *, low=None, strict=True):
    try:
        value = float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number, got {value!r}") from error
    if not math.isfinite(value) or (low is not None and (value <= low if strict else value < low)):
        raise ValueError(f"{name} must be a finite number {'>' if strict else '>='} {low}, got {value!r}")
    return value


@dataclass(frozen=True, eq=False)
class Scene:
    """A tool task on a block of tissue (SI units).

    Attributes:
        size: (Lx, Ly, Lz) block extent in m (a float gives a cube); the block is
            [0, Lx] x [0, Ly] x [0, Lz], y up.
        young_modulus, poisson_ratio, density: the tissue (Pa, -, kg/m^3).
        fixed_face: the face attached to the body (all components fixed): "x-", "x+", "y-", "y+",
            "z-" or "z+" ("y-" is the bottom y = 0).
        tool_low, tool_high: (3,) corners of the box (m) that selects the tool's nodes among the
            block's surface nodes at rest (a degenerate box selects a face or a line of nodes).
        tool_radius: None, or a radius (m): the tool is then the vertical cylinder of this radius
            around the box centre (x and z bounded by the radius, y by the box): a round probe.
        tool_components: the components the tool imposes: (0, 1, 2) glued, (1,) a frictionless probe.
        probe: None (the tool's nodes are imposed throughout, as ``tool_components`` says), or a
            contact probe of radius ``tool_radius`` pressed from above (``sim_core.contact.Probe``):
            "sphere" (hemispherical end) or "flat" (flat-ended cylinder), its lowest point at the
            top centre of the tool box plus the displacement; the tool box's surface nodes, at any
            x and z, are the contact candidates (frictionless active set, only u_y imposed).
        probe_sampling: "projected" (default: the probe's indentation of the start surface projected
            on the top nodes' basis functions, ``sim_core.contact.SurfaceProjection``; the tool box
            must then lie on the top face) or "node" (the probe sampled at the nodes).
        displacements: tool displacements from rest (m): an (K, 3) array of independent cases, or a
            sequence of paths (each an (K_p, 3) array) solved in order by continuation, each path
            starting from the equilibrium under gravity with the tool at rest.
        target: (3,) a material point inside the block (m, rest coordinates).
        gravity: m/s^2 along -y.
        floor: a rigid frictionless floor at y = 0 (unilateral contact on every free node).
        inclusion_low, inclusion_high, inclusion_ratio: an optional box (m) of tissue
            ``inclusion_ratio`` times stiffer; each element gets E (1 + (ratio - 1) f), f the share
            of its volume inside the box.
        min_shape: the smallest number of elements per axis.
        name: a label.
    """

    size: tuple
    young_modulus: float
    poisson_ratio: float
    tool_low: tuple
    tool_high: tuple
    displacements: object
    target: tuple
    density: float = 1060.0
    fixed_face: str = "y-"
    tool_radius: float | None = None
    tool_components: tuple = (0, 1, 2)
    probe: str | None = None
    probe_sampling: str = "projected"
    gravity: float = 9.81
    floor: bool = False
    inclusion_low: tuple | None = None
    inclusion_high: tuple | None = None
    inclusion_ratio: float = 1.0
    min_shape: tuple = (1, 1, 1)
    name: str = "scene"

    def __post_init__(self):
        size = _vector("size", self.size, positive=True)
        set_ = lambda key, value: object.__setattr__(self, key, value)  # noqa: E731 (frozen dataclass)
        set_("size", size)
        set_("young_modulus", _scalar("young_modulus", self.young_modulus, low=0.0))
        nu = _scalar("poisson_ratio", self.poisson_ratio)
        if not -0.25 < nu < 0.5:
            raise ValueError(f"poisson_ratio must lie in (-0.25, 0.5), got {self.poisson_ratio!r}")
        set_("poisson_ratio", nu)
        set_("density", _scalar("density", self.density, low=0.0))
        if self.fixed_face not in FACES:
            raise ValueError(f"fixed_face must be one of {FACES}, got {self.fixed_face!r}")
        low, high = _vector("tool_low", self.tool_low), _vector("tool_high", self.tool_high)
        if np.any(low > high):
            raise ValueError(f"tool_low must be <= tool_high on every axis, got {low.tolist()} and {high.tolist()}")
        set_("tool_low", low)
        set_("tool_high", high)
        if self.tool_radius is not None:
            set_("tool_radius", _scalar("tool_radius", self.tool_radius, low=0.0))
        components = tuple(sorted({int(c) for c in np.atleast_1d(self.tool_components)}))
        if not components or any(c not in (0, 1, 2) for c in components):
            raise ValueError(f"tool_components must be a non-empty subset of (0, 1, 2), got {self.tool_components!r}")
        set_("tool_components", components)
        set_("displacements", _paths(self.displacements))
        target = _vector("target", self.target)
        if np.any(target < 0) or np.any(target > size):
            raise ValueError(f"target must lie inside the block [0, size], got {target.tolist()}")
        set_("target", target)
        set_("gravity", _scalar("gravity", self.gravity, low=0.0, strict=False))
        set_("floor", bool(self.floor))
        if self.probe is not None:
            if self.probe not in contact_.TIPS:
                raise ValueError(f"probe must be None or one of {contact_.TIPS}, got {self.probe!r}")
            if self.tool_radius is None:
                raise ValueError("a probe needs tool_radius (m), its radius")
            if self.floor:
                raise ValueError("a scene has one contact obstacle: a probe or a floor, not both")
        if self.probe_sampling not in contact_.SAMPLINGS:
            raise ValueError(f"probe_sampling must be one of {contact_.SAMPLINGS}, got {self.probe_sampling!r}")
        if (self.inclusion_low is None) != (self.inclusion_high is None):
            raise ValueError("inclusion_low and inclusion_high must be given together")
        if self.inclusion_low is not None:
            set_("inclusion_low", _vector("inclusion_low", self.inclusion_low))
            set_("inclusion_high", _vector("inclusion_high", self.inclusion_high))
        set_("inclusion_ratio", _scalar("inclusion_ratio", self.inclusion_ratio, low=0.0))
        try:
            min_shape = tuple(int(s) for s in self.min_shape)
        except (TypeError, ValueError) as error:
            raise ValueError(f"min_shape must be three integers >= 1, got {self.min_shape!r}") from error
        if len(min_shape) != 3 or min(min_shape) < 1:
            raise ValueError(f"min_shape must be three integers >= 1, got {self.min_shape!r}")
        set_("min_shape", min_shape)

    # -- contact ----------------------------------------------------------------------------
    def obstacle(self, mesh=None, candidates=None):
        """The scene's contact obstacle (``sim_core.contact``): the floor, the probe, or None. A
        probe with ``probe_sampling="projected"`` is projected on the top face of ``mesh`` at its
        ``candidates`` (n,) bool, its indentation measured from the rest heights (``_from_surface``
        measures it from another surface)."""
        if self.floor:
            return contact_.Floor()
        if self.probe is None:
            return None
        if self.probe_sampling == "node":
            return contact_.Probe(self.tool_radius, self.probe)
        if mesh is None:
            raise ValueError("a projected probe needs the scene's mesh and contact candidates")
        return contact_.Probe(self.tool_radius, self.probe,
                              contact_.SurfaceProjection.top_face(mesh, np.flatnonzero(candidates)))

    def probe_tip(self, displacement):
        """(3,) the probe's lowest point (m) at a tool displacement (m); None without a probe."""
        if self.probe is None:
            return None
        centre = 0.5 * (self.tool_low + self.tool_high)
        return np.array([centre[0], self.tool_high[1], centre[2]]) + np.asarray(displacement, dtype=float)

    # -- discretisation ----------------------------------------------------------------------
    def shape(self, resolution: int) -> tuple:
        """Elements per axis at ``resolution`` n: no element longer than max(size) / n."""
        h = float(self.size.max()) / int(resolution)
        return tuple(max(m, math.ceil(length / h - 1e-9)) for m, length in zip(self.min_shape, self.size))

    def discretise(self, shape):
        """(mesh, material, fixed nodes, tool nodes (a probe's: its contact candidates), target
        element, target weights) for ``shape``."""
        shape = tuple(int(s) for s in shape)
        spacing = self.size / np.asarray(shape)
        mesh = HexMesh.block(shape, spacing)
        nodes = mesh.nodes
        tol = 1e-6 * float(spacing.min())
        axis, end = "xyz".index(self.fixed_face[0]), self.fixed_face[1] == "+"
        fixed = np.flatnonzero(np.abs(nodes[:, axis] - (self.size[axis] if end else 0.0)) <= tol)
        surface = mesh.surface_nodes()
        low, high = self.tool_low.copy(), self.tool_high.copy()
        if self.tool_radius is not None:  # the cylinder bounds x and z (a probe's contact: nothing)
            low[[0, 2]], high[[0, 2]] = -np.inf, np.inf
        inside = np.all((nodes[surface] >= low - tol) & (nodes[surface] <= high + tol), axis=1)
        if self.tool_radius is not None and self.probe is None:
            centre = 0.5 * (self.tool_low + self.tool_high)
            inside &= np.hypot(*(nodes[surface][:, [0, 2]] - centre[[0, 2]]).T) <= self.tool_radius + tol
        tool = np.setdiff1d(surface[inside], fixed)
        if len(tool) == 0:
            raise ValueError(f"the tool selects no surface node of the {shape} mesh of scene {self.name!r}")
        young = np.full(mesh.n_elements, self.young_modulus)
        if self.inclusion_low is not None:
            share = mesh.box_shares(self.inclusion_low, self.inclusion_high)
            young = young * (1.0 + (self.inclusion_ratio - 1.0) * share)
        material = Material(young, self.poisson_ratio, self.density)
        cell = np.minimum((self.target // spacing).astype(int), np.asarray(shape) - 1)
        element = int(cell[0] + shape[0] * (cell[1] + shape[1] * cell[2]))
        local = self.target / spacing - cell
        weights = np.prod(LOCAL_CORNERS * local + (1.0 - LOCAL_CORNERS) * (1.0 - local), axis=1)
        return mesh, material, fixed, tool, mesh.elements[element], weights


def _paths(value):
    """Tool displacements as a tuple of (K_p, 3) float arrays (paths)."""
    try:
        if isinstance(value, np.ndarray) or (len(value) and np.ndim(value[0]) == 1):
            array = np.asarray(value, dtype=float)
            if array.ndim != 2 or array.shape[1] != 3:
                raise ValueError
            paths = tuple(array[i:i + 1] for i in range(len(array)))
        else:
            paths = tuple(np.asarray(p, dtype=float).reshape(-1, 3) for p in value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"displacements must be a (K, 3) array or a sequence of (K_p, 3) paths in m, got {value!r}") from error
    if not paths or any(len(p) == 0 or not np.all(np.isfinite(p)) for p in paths):
        raise ValueError("displacements must hold at least one finite (3,) displacement per path")
    if not any(np.any(p != 0) for p in paths):
        raise ValueError("displacements must contain a non-zero displacement")
    return paths


# -- solving a scene ------------------------------------------------------------------------------------
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


def _mss_solver(mesh, material, gravity, hourglass_control, volume_stiffness, check_stability):
    model = build_model(mesh, material, gravity=(0.0, -gravity, 0.0), hourglass_control=hourglass_control,
                        volume_stiffness=volume_stiffness)
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
            from ..static import lowest_eigenvalue
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
            import scipy.sparse.linalg as spla

            start = time.perf_counter()
            free = np.flatnonzero(~control.fixed.ravel())
            stiffness = fem.tangent_stiffness(result.positions).tocsr()[free][:, free]
            lowest = float(spla.eigsh(stiffness, k=1, which="SA", tol=1e-6, maxiter=50 * len(free))[0][0])
            timer["check"] += time.perf_counter() - start
        return result.positions, result.reaction, result.converged, lowest

    return solve, timer


def _contact_candidates(scene, n_nodes, fixed, tool):
    """(n,) bool: the nodes the scene's obstacle may hold (the floor: every node neither attached nor
    grasped; a probe: its candidates, the tool nodes)."""
    candidates = np.zeros(n_nodes, bool)
    if scene.floor:
        candidates[:] = True
        candidates[np.union1d(fixed, tool)] = False
    elif scene.probe is not None:
        candidates[tool] = True
    return candidates


def _tool_control(scene, base, nodes, tool, displacement):
    """``base`` with the tool's nodes imposed at ``displacement`` (m) from rest (a probe imposes
    through its contact instead)."""
    control = base.copy()
    if scene.probe is None:
        control.impose(tool, nodes[tool] + displacement, components=scene.tool_components)
    return control


def _tool_force(scene, tool, contact, reaction):
    """(3,) the force (N) the tool exerts on the tissue: the constraint forces ``reaction`` (n, 3)
    on the tool's imposed components, or on the probe's contact nodes (along y)."""
    imposed = np.zeros(reaction.shape, bool)
    if scene.probe is None:
        imposed[np.ix_(tool, scene.tool_components)] = True
    else:
        imposed[contact, 1] = True
    return np.where(imposed, reaction, 0.0).sum(axis=0)


def _from_surface(obstacle, heights):
    """``obstacle`` with a projected probe's indentation measured from the node heights ``heights``
    (n,) m (its projection kept: ``SurfaceProjection.with_reference``); other obstacles as they are."""
    projection = getattr(obstacle, "projection", None)
    if projection is None:
        return obstacle
    return contact_.Probe(obstacle.radius, obstacle.tip, projection.with_reference(heights))


def _solve_with_contact(solve, control, initial, obstacle, candidates, tip=None, rest=None, max_rounds=25,
                        tolerance=1e-9, slide_tolerance=1e-7):
    """Static solve with a frictionless obstacle (``sim_core.contact``: the floor y >= 0 or a probe
    from above) by an active set: the candidate nodes (n,) bool on or through its surface get
    their height imposed on it at their (x, z), the nodes it would pull are released, and the
    heights follow the nodes' horizontal sliding; repeated until no node goes through the surface
    by more than ``tolerance`` (m) and the held heights are within ``slide_tolerance`` (m) of the
    surface under the nodes. Returns (positions, reaction, converged, lowest eigenvalue, control, contact (n,) bool)."""
    if obstacle is None:
        positions, reaction, converged, lowest = solve(control, initial)
        return positions, reaction, converged, lowest, control, np.zeros(len(control.fixed), bool)
    start = rest if initial is None else initial
    contact = contact_.touching(obstacle, start, candidates, tip, tolerance=1e-12)
    for _ in range(max_rounds):
        trial = control.copy()
        active = np.flatnonzero(contact)
        if len(active):
            target = start[active].copy()
            target[:, 1] = contact_.targets(obstacle, start, contact, tip)[active]
            trial.impose(active, target, components=(1,))
        positions, reaction, converged, lowest = solve(trial, initial if initial is None else start)
        if not converged:
            return positions, reaction, False, lowest, trial, contact
        through = contact_.touching(obstacle, positions, candidates & ~contact, tip, tolerance=-tolerance)
        pulled = contact & ~contact_.release(obstacle, contact, -reaction, tolerance=1e-12)
        drift = contact & (np.abs(contact_.gap(obstacle, positions, tip)) > slide_tolerance)
        if not through.any() and not pulled.any() and not drift.any():
            return positions, reaction, True, lowest, trial, contact
        contact = (contact | through) & ~pulled
        start = initial = positions  # the solver ramps the newly imposed heights from here
    return positions, reaction, False, lowest, trial, contact


def solve_scene(scene: Scene, shape, *, model="baudet", hourglass_control=0.0, volume_stiffness=1.0,
                check_stability=True) -> SceneSolution:
    """Solve every tested displacement of ``scene`` on a ``shape`` mesh with ``model`` "baudet"
    (static mass-spring equilibrium) or "fem-neohookean" (the reference)."""
    mesh, material, fixed, tool, target_nodes, weights = scene.discretise(shape)
    nodes = mesh.nodes
    if model == "fem-neohookean":
        solve, timer = _fem_solver(mesh, material, scene.gravity, check_stability)
    elif model in ("baudet", "baudet-original", "uniform-springs"):
        if model != "baudet":
            raise ValueError("solve_scene: only 'baudet' and 'fem-neohookean' are supported, got {model!r}")
        solve, timer = _mss_solver(mesh, material, scene.gravity, hourglass_control, volume_stiffness,
                                   check_stability)
    else:
        raise ValueError(f"model must be 'baudet' or 'fem-neohookean', got {model!r}")
    base = Control.free(mesh.n_nodes).impose(fixed, nodes[fixed])
    candidates = _contact_candidates(scene, mesh.n_nodes, fixed, tool)
    obstacle = scene.obstacle(mesh, candidates)
    rest_volume = float(mesh.element_volumes().sum())
    results = dict(force=[], target=[], volume=[], converged=[], lowest=[])
    elapsed = 0.0
    start_clock = time.perf_counter()
    # equilibrium under gravity with the tool at rest (the environments' start state)
    rest_positions = nodes.copy()
    if scene.gravity > 0:
        rest_positions, _, ok, _, _, _ = _solve_with_contact(
            solve, _tool_control(scene, base, nodes, tool, np.zeros(3)), None, obstacle, candidates,
            scene.probe_tip(np.zeros(3)), rest=nodes)
        rest_positions = rest_positions if ok else nodes.copy()
        # the indentation is measured from the start surface, as in Palpation
        obstacle = _from_surface(obstacle, rest_positions[:, 1])
    for path in scene.displacements:
        positions = rest_positions
        for displacement in path:
            control = _tool_control(scene, base, nodes, tool, displacement)
            positions, reaction, converged, lowest, _, contact = _solve_with_contact(
                solve, control, positions, obstacle, candidates, scene.probe_tip(displacement))
            results["force"].append(_tool_force(scene, tool, contact, reaction))
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


# -- the choice ------------------------------------------------------------------------------------------
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
            (for "baudet", a dict {(hourglass_control, volume_stiffness): solutions}).
        total_time: s.  reference_model: "baudet" (fine mass-spring) or "fem-neohookean".
        reference_convergence: for "baudet", per setting, the errors of the finest candidate
            coarser than the reference against it (how far the reference itself may be from
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


def _scenes(scene, name="scene") -> list:
    """A Scene or a non-empty list/tuple of Scenes as a list, else ValueError naming ``name``."""
    scenes = [scene] if isinstance(scene, Scene) else list(scene) if isinstance(scene, (list, tuple)) else None
    if not scenes or not all(isinstance(s, Scene) for s in scenes):
        raise ValueError(f"{name} must be a Scene or a non-empty list of Scenes, got {scene!r}")
    return scenes


def _quantities(quantities) -> tuple:
    """A non-empty subset of QUANTITIES as a tuple, else ValueError naming ``quantities``."""
    try:
        quantities = tuple(quantities)
    except TypeError as error:
        raise ValueError(f"quantities must be a subset of {QUANTITIES}, got {quantities!r}") from error
    if not quantities or any(q not in QUANTITIES for q in quantities):
        raise ValueError(f"quantities must be a non-empty subset of {QUANTITIES}, got {quantities!r}")
    return quantities


def _tolerances(tolerance, quantities):
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


def _settings(name, values, low):
    try:
        values = sorted({float(v) for v in values})
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a non-empty sequence of numbers >= {low}, got {values!r}") from error
    if not values or any(not math.isfinite(v) or v < low for v in values):
        raise ValueError(f"{name} must be a non-empty sequence of finite numbers >= {low}, got {values!r}")
    return values


def evaluate(scenes, shape, references, tolerance, *, hourglass_control, volume_stiffness, resolution=None):
    """Solve ``scenes`` (a Scene or a list) with one mass-spring setting on ``shape`` and compare
    with ``references`` (their ``SceneSolution`` s): a ``Candidate``."""
    scenes = [scenes] if isinstance(scenes, Scene) else list(scenes)
    tolerance = _tolerances(tolerance, QUANTITIES) if not isinstance(tolerance, dict) else tolerance
    shape = tuple(int(s) for s in shape)
    n_nodes = int(np.prod(np.asarray(shape) + 1))
    common = dict(resolution=resolution, shape=shape, hourglass_control=float(hourglass_control),
                  volume_stiffness=float(volume_stiffness), n_nodes=n_nodes)
    errors, converged, stable, elapsed, lowest = {}, True, True, 0.0, np.inf
    case_errors, case_stable = {q: [] for q in QUANTITIES}, []
    for scene, reference in zip(scenes, references):
        try:
            solution = solve_scene(scene, shape, hourglass_control=hourglass_control,
                                   volume_stiffness=volume_stiffness)
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


REFERENCE_MODELS = ("baudet", "fem-neohookean")


class References(tuple):
    """``(solutions, shapes, seconds)`` from ``reference_solutions`` (a plain 3-tuple when
    unpacked), with the reference ``model`` and, for "baudet", its ``hourglass_control`` and
    ``volume_stiffness`` (None for "fem-neohookean")."""

    def __new__(cls, solutions, shapes, seconds, model="fem-neohookean", hourglass_control=None,
                volume_stiffness=None):
        out = super().__new__(cls, (solutions, shapes, seconds))
        out.model, out.hourglass_control, out.volume_stiffness = model, hourglass_control, volume_stiffness
        return out

    @property
    def setting(self):
        return None if self.model != "baudet" else (self.hourglass_control, self.volume_stiffness)


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
    try:
        shape = tuple(int(s) for s in reference_shape)
    except (TypeError, ValueError) as error:
        raise ValueError(f"reference_shape must be three integers >= 1, got {reference_shape!r}") from error
    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"reference_shape must be three integers >= 1, got {reference_shape!r}")
    return reference_resolution, shape


def reference_solutions(scenes, *, reference_resolution=10, reference_shape=None, model="fem-neohookean",
                        hourglass_control=1.0, volume_stiffness=100.0) -> References:
    """Reference solutions of ``scenes`` on their fine meshes: ``References`` (solutions, shapes, seconds).

    Args:
        reference_resolution: n of the reference mesh (``Scene.shape(n)``), or ``reference_shape``.
        model: "fem-neohookean" (the constitutive reference: a converged continuum model) or
            "baudet" (the same mass-spring model, with ``hourglass_control`` and
            ``volume_stiffness``, on the fine mesh: the discretisation reference).
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    scenes = _scenes(scenes, "scenes")
    if model not in REFERENCE_MODELS:
        raise ValueError(f"model must be one of {REFERENCE_MODELS}, got {model!r}")
    reference_resolution, reference_shape = _reference_shape_arguments(reference_resolution, reference_shape)
    shapes = [reference_shape if reference_shape is not None else s.shape(reference_resolution) for s in scenes]
    start = time.perf_counter()
    if model == "baudet":
        alpha = _scalar("hourglass_control", hourglass_control, low=0.0, strict=False)
        kappa = _scalar("volume_stiffness", volume_stiffness, low=0.0, strict=False)
        solutions = [solve_scene(s, shape, hourglass_control=alpha, volume_stiffness=kappa)
                     for s, shape in zip(scenes, shapes)]
        return References(solutions, shapes, time.perf_counter() - start, model, alpha, kappa)
    solutions = [solve_scene(s, shape, model="fem-neohookean") for s, shape in zip(scenes, shapes)]
    return References(solutions, shapes, time.perf_counter() - start)


def _reference_map(references, model, settings, scenes, reference_resolution, reference_shape):
    """{setting: References} for "baudet" ({None: References} for "fem-neohookean"), computing
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
            scenes, reference_resolution=reference_resolution, reference_shape=reference_shape, model="baudet",
            hourglass_control=alpha, volume_stiffness=kappa)
    return out


def choose_resolution(scene, tolerance=0.05, *, resolutions=range(2, 9), hourglass_controls=(0.0, 0.25, 0.5, 1.0),
                      volume_stiffnesses=(1.0, 100.0), reference=None, reference_resolution=10, reference_shape=None,
                      quantities=QUANTITIES, full_scan=False, references=None) -> ResolutionChoice:
    """The coarsest mass-spring resolution and setting that reproduce ``scene`` within ``tolerance``.

    Args:
        scene: a ``Scene`` or a list of them (same block, e.g. probes at several places): the errors
            are the worst over all of them.
        tolerance: relative error allowed on each observed quantity (e.g. 0.05), or a dict
            {"force": ..., "target": ..., "volume": ...} (module docstring for the definition).
        resolutions: the n to try, coarsest first (integers >= 1; ``Scene.shape(n)``).
        hourglass_controls: alpha values to try (>= 0).  volume_stiffnesses: kappa multipliers (>= 0).
        reference: "baudet" (the fine model: the same mass-spring model and setting on the
            reference mesh; only resolutions strictly coarser than it can be chosen) or
            "fem-neohookean" (the constitutive reference). Default: the model of ``references``
            when given, else "baudet".
        reference_resolution: n of the reference mesh (or ``reference_shape``).
        quantities: which observed quantities must meet the tolerance (a subset of QUANTITIES).
        full_scan: try every resolution (for charts); otherwise stop at the first one with an
            admissible setting.
        references: precomputed ``reference_solutions(...)`` result to reuse (for "baudet", one per
            setting: a single result or a dict {(alpha, kappa): result}; missing ones are computed).
    Returns:
        ``ResolutionChoice``; ``chosen`` is None when no candidate is admissible.
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    clock = time.perf_counter()
    scenes = _scenes(scene)
    if any(not np.allclose(s.size, scenes[0].size) for s in scenes):
        raise ValueError("scene: every Scene in the list must have the same size")
    if reference is None:
        reference = getattr(references, "model", "fem-neohookean") if isinstance(references, tuple) else (
            "baudet" if references is None or isinstance(references, dict) else "fem-neohookean")
    if reference not in REFERENCE_MODELS:
        raise ValueError(f"reference must be one of {REFERENCE_MODELS}, got {reference!r}")
    quantities = _quantities(quantities)
    tolerance = _tolerances(tolerance, quantities)
    try:
        given = list(resolutions)
        resolutions = [int(r) for r in given]
        exact = all(float(a) == b for a, b in zip(given, resolutions))
    except (TypeError, ValueError) as error:
        raise ValueError(f"resolutions must be integers >= 1, got {resolutions!r}") from error
    if not resolutions or not exact or min(resolutions) < 1:
        raise ValueError(f"resolutions must be a non-empty sequence of integers >= 1, got {resolutions!r}")
    resolutions = sorted(set(resolutions))
    hourglass_controls = _settings("hourglass_controls", hourglass_controls, 0.0)
    volume_stiffnesses = _settings("volume_stiffnesses", volume_stiffnesses, 0.0)
    reference_resolution, reference_shape = _reference_shape_arguments(reference_resolution, reference_shape)
    settings = [(alpha, kappa) for alpha in hourglass_controls for kappa in volume_stiffnesses]
    ref_map = _reference_map(references, reference, settings, scenes, reference_resolution, reference_shape)
    ref_of = (lambda setting: ref_map[None]) if reference == "fem-neohookean" else ref_map.__getitem__
    everything = list(ref_map.values())
    ref_converged = all(bool(np.all(s.converged)) for r in everything for s in r[0])
    ref_stable = all(all(v is True for v in s.stable) for r in everything for s in r[0])
    ref_shapes, ref_time = everything[0][1], float(sum(r[2] for r in everything))
    ref_nodes = int(np.prod(np.asarray(ref_shapes[0]) + 1))

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
                                 volume_stiffness=kappa, resolution=resolution)
            if reference == "baudet" and candidate.admissible and candidate.n_nodes >= ref_nodes:
                candidate.admissible, candidate.reason = False, "not coarser than the reference"
            here.append(candidate)
        candidates.extend(here)
        admissible = [c for c in here if c.admissible]
        if admissible and chosen is None:
            chosen = min(admissible, key=lambda c: (c.worst_ratio(tolerance), c.solve_time))
            if not full_scan:
                break
    sound = [c for c in candidates if c.converged and c.stable and c.errors is not None
             and (reference != "baudet" or c.n_nodes < ref_nodes)]
    best = None
    if sound:
        smallest = min(c.worst_ratio(tolerance) for c in sound)
        best = min((c for c in sound if c.worst_ratio(tolerance) <= 1.1 * smallest),
                   key=lambda c: (c.n_nodes, c.worst_ratio(tolerance)))
    convergence = None
    if reference == "baudet":
        convergence = []
        for alpha, kappa in settings:
            coarser = [c for c in candidates if c.errors is not None and c.n_nodes < ref_nodes
                       and (c.hourglass_control, c.volume_stiffness) == (alpha, kappa)]
            finest = max(coarser, key=lambda c: c.n_nodes, default=None)
            convergence.append(dict(
                hourglass_control=alpha, volume_stiffness=kappa, reference_shape=list(ref_shapes[0]),
                resolution=None if finest is None else finest.resolution,
                shape=None if finest is None else list(finest.shape),
                errors=None if finest is None else finest.errors))
    solutions = ref_map[None][0] if reference == "fem-neohookean" else {k: v[0] for k, v in ref_map.items()}
    return ResolutionChoice(chosen=chosen, best=best, candidates=candidates, tolerance=tolerance,
                            reference_shape=[list(s) for s in ref_shapes], reference_time=ref_time,
                            reference_stable=ref_stable, reference_converged=ref_converged,
                            total_time=time.perf_counter() - clock, reference=solutions,
                            reference_model=reference, reference_convergence=convergence)


# -- the stepping ----------------------------------------------------------------------------------------
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


def _int_at_least(name, value, low):
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    try:
        number = int(value)
        exact = float(value) == number
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}") from error
    if not exact or number < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return number


def dynamic_scene(scene, shape, *, dt, substeps, max_step, hold_steps, hourglass_control, volume_stiffness,
                  solver_tolerance, solver=None, damping_ratio=1.0, integrator="implicit"):
    """Observed quantities of ``scene`` as an environment produces them: from the static rest state
    (gravity, tool at rest) the tool moves towards each tested displacement by at most ``max_step``
    per component per env step (a scripted controller at full speed; the displacements of a path
    in order), each env step being ``substeps`` implicit Euler steps of ``dt`` (floor: y projected
    after each step, the floor nodes held at y = 0 in the step, as Retraction does), then is held
    ``hold_steps`` env steps; the observation
    is taken then. ``damping_ratio``: ``build_model``'s multiplier of the critical spring damping.
    ``integrator``: "implicit" (``ImplicitEuler`` with ``solver_tolerance`` and the ``solver``
    keywords) or "static" (``sim_core.static.QuasiStatic``, the ``solver`` keywords: an equilibrium
    per step, as the envs' ``integrator="static"``).
    Returns (SceneSolution, env steps, iterations, seconds, divergence reason)."""
    from ..forces import external_forces, internal_forces
    from ..integrators import make_integrator
    from ..model import State
    from ..static import STATIC_CONTACT_PASSES, same_contact

    if integrator not in ("implicit", "static"):
        raise ValueError(f"integrator must be 'implicit' or 'static', got {integrator!r}")
    mesh, material, fixed, tool, target_nodes, weights = scene.discretise(shape)
    nodes = mesh.nodes
    model = build_model(mesh, material, gravity=(0.0, -scene.gravity, 0.0), hourglass_control=hourglass_control,
                        volume_stiffness=volume_stiffness, damping_ratio=damping_ratio)
    solve, _ = _mss_solver(mesh, material, scene.gravity, hourglass_control, volume_stiffness, False)
    base = Control.free(mesh.n_nodes).impose(fixed, nodes[fixed])
    candidates = _contact_candidates(scene, mesh.n_nodes, fixed, tool)
    obstacle = scene.obstacle(mesh, candidates)
    rest = nodes.copy()
    if scene.gravity > 0:
        rest, _, ok, _, _, _ = _solve_with_contact(solve, _tool_control(scene, base, nodes, tool, np.zeros(3)), None,
                                                   obstacle, candidates, scene.probe_tip(np.zeros(3)), rest=nodes)
        rest = rest if ok else nodes.copy()
        obstacle = _from_surface(obstacle, rest[:, 1])
    rest_volume = float(mesh.element_volumes().sum())
    options = dict(solver or {}) if integrator == "static" else dict(tolerance=solver_tolerance, **(solver or {}))
    stepper = make_integrator(integrator, **options)
    passes = STATIC_CONTACT_PASSES if integrator == "static" else 1

    def formed(state, offset, contact):
        """The step's control at ``state``: the tool, and the contact's active set updated (nodes
        touching join, nodes the tissue pulls away leave) with their heights imposed."""
        control = _tool_control(scene, base, nodes, tool, offset)
        if obstacle is None:
            return control, contact
        tip = scene.probe_tip(offset)
        net = internal_forces(model, state.positions, state.velocities) + external_forces(model, control)
        contact = contact_.update(obstacle, contact, state.positions, net, candidates, tip)
        held = np.flatnonzero(contact)
        if len(held):
            target = state.positions[held].copy()
            target[:, 1] = contact_.targets(obstacle, state.positions, contact, tip)[held]
            control.impose(held, target, components=(1,))
        return control, contact
    observed = dict(force=[], target=[], volume=[])
    env_steps, iterations, reason = 0, 0, None
    clock = time.perf_counter()
    for path in scene.displacements:
        state = State(rest.copy(), np.zeros_like(rest))
        scratch = state.copy()
        offset = np.zeros(3)
        # contact as the environments (RetractionEnv's floor, PalpationEnv's probe): the nodes on
        # the obstacle have their height imposed in the step; a node it would pull is released; one
        # that goes through it joins (after a projection)
        contact = (np.zeros(mesh.n_nodes, bool) if obstacle is None else
                   contact_.touching(obstacle, state.positions, candidates, scene.probe_tip(offset), 1e-12))
        for displacement in path:
            moves = int(math.ceil(float(np.max(np.abs(displacement - offset))) / max_step - 1e-9))
            for k in range(moves + hold_steps):
                if k < moves:
                    offset = offset + np.clip(displacement - offset, -max_step, max_step)
                tip = scene.probe_tip(offset)
                control, contact = formed(state, offset, contact)
                for _ in range(substeps):
                    for attempt in range(passes):
                        with np.errstate(all="ignore"):
                            report = stepper.simulate(model, state, scratch, dt, control)
                        iterations += report.iterations
                        reason = report.unstable_reason
                        if reason is None and not np.all(np.isfinite(scratch.positions)):
                            reason = "non-finite positions"
                        if reason is not None:
                            return None, env_steps, iterations, time.perf_counter() - clock, reason
                        if obstacle is not None:
                            contact |= contact_.project(obstacle, scratch.positions, scratch.velocities, candidates, tip)
                        state, scratch = scratch, state
                        if obstacle is None or attempt + 1 == passes:
                            break
                        # quasi-static: the active set iterated within the step, as TissueEnv._advance
                        previous = control
                        control, contact = formed(state, offset, contact)
                        if same_contact(previous, control):
                            break
                env_steps += 1
            positions = state.positions
            forces = internal_forces(model, positions, state.velocities) + external_forces(model, control)
            observed["force"].append(_tool_force(scene, tool, contact, -forces))  # as TissueEnv._measure
            observed["target"].append(weights @ positions[target_nodes])
            observed["volume"].append(float(mesh.element_volumes(positions).sum()) / rest_volume - 1.0)
    elapsed = time.perf_counter() - clock
    count = len(observed["volume"])
    solution = SceneSolution(
        shape=tuple(shape), force=np.asarray(observed["force"]), target=np.asarray(observed["target"]),
        volume=np.asarray(observed["volume"]), target_rest=weights @ nodes[target_nodes],
        converged=np.ones(count, bool), stable=np.full(count, None, dtype=object),
        lowest_eigenvalue=np.full(count, np.nan), solve_time=elapsed)
    return solution, env_steps, iterations, elapsed, None


def stepping_error(scene, shape, *, dt=0.02, substeps=1, max_step=0.002, hold_steps=0, hourglass_control=1.0,
                   volume_stiffness=100.0, static=None, tolerance=0.05, solver_tolerance=1e-4,
                   solver=None) -> SteppingCandidate:
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
    Returns:
        ``SteppingCandidate`` (errors in the ``scene_errors`` convention against ``static``).
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    scenes = _scenes(scene)
    try:
        shape = tuple(int(s) for s in shape)
    except (TypeError, ValueError) as error:
        raise ValueError(f"shape must be three integers >= 1, got {shape!r}") from error
    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"shape must be three integers >= 1, got {shape!r}")
    dt = _scalar("dt", dt, low=0.0)
    substeps = _int_at_least("substeps", substeps, 1)
    max_step = _scalar("max_step", max_step, low=0.0)
    hold_steps = _int_at_least("hold_steps", hold_steps, 0)
    alpha = _scalar("hourglass_control", hourglass_control, low=0.0, strict=False)
    kappa = _scalar("volume_stiffness", volume_stiffness, low=0.0, strict=False)
    tolerance = tolerance if isinstance(tolerance, dict) and set(tolerance) <= set(QUANTITIES) and all(
        isinstance(v, float) for v in tolerance.values()) else _tolerances(tolerance, QUANTITIES)
    if static is None:
        static = [solve_scene(s, shape, hourglass_control=alpha, volume_stiffness=kappa, check_stability=False)
                  for s in scenes]
    errors, case_errors, steps, iterations, elapsed = {}, {q: [] for q in QUANTITIES}, 0, 0, 0.0
    for scene_, reference in zip(scenes, static):
        solution, n, its, seconds, reason = dynamic_scene(
            scene_, shape, dt=dt, substeps=substeps, max_step=max_step, hold_steps=hold_steps,
            hourglass_control=alpha, volume_stiffness=kappa, solver_tolerance=solver_tolerance, solver=solver)
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
                    static=None, solver_tolerance=1e-4, solver=None) -> SteppingChoice:
    """The cheapest env stepping (``dt``, ``substeps``) whose observations stay within ``tolerance``
    of the static equilibrium at the same tool position (``stepping_error``) on ``shape``.

    Cheapest: fewest implicit steps per env step (``substeps``), then fewest linear-solver
    iterations per env step, then the smallest worst error / tolerance. ``solver_tolerance`` and
    ``solver`` (``ImplicitEuler`` keywords) as in ``stepping_error``.
    Raises:
        ValueError naming the argument when an input is invalid.
    """
    clock = time.perf_counter()
    scenes = _scenes(scene)
    quantities = _quantities(quantities)
    tolerance = _tolerances(tolerance, quantities)
    try:
        dts = sorted({_scalar("dts", d, low=0.0) for d in dts})
        substeps = sorted({_int_at_least("substeps", s, 1) for s in substeps})
    except TypeError as error:
        raise ValueError(f"dts and substeps must be sequences, got {dts!r} and {substeps!r}") from error
    if not dts:
        raise ValueError("dts must hold at least one time step > 0 s")
    if not substeps:
        raise ValueError("substeps must hold at least one integer >= 1")
    shape = tuple(int(s) for s in shape)
    if static is None:
        static = [solve_scene(s, shape, hourglass_control=hourglass_control, volume_stiffness=volume_stiffness,
                              check_stability=False) for s in scenes]
    candidates = [stepping_error(scenes, shape, dt=dt, substeps=n, max_step=max_step, hold_steps=hold_steps,
                                 hourglass_control=hourglass_control, volume_stiffness=volume_stiffness,
                                 static=static, tolerance=tolerance, solver_tolerance=solver_tolerance, solver=solver)
                  for n in substeps for dt in dts]
    admissible = [c for c in candidates if c.admissible]
    chosen = None
    if admissible:
        chosen = min(admissible, key=lambda c: (c.substeps, round(c.iterations, 1),
                                                max(c.errors[q] / tolerance[q] for q in tolerance)))
    return SteppingChoice(chosen, candidates, tolerance, shape, float(max_step), int(hold_steps),
                          time.perf_counter() - clock)
