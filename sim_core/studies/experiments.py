"""Validation experiments: elongation, shear and flexion of a structured block.

Each experiment builds the block, imposes its boundary conditions, solves for static equilibrium
with the physics named by ``model`` and measures moduli the way a materials lab would. Mass-spring
models: "baudet", "baudet-original", "uniform-springs", "baudet-hyperelastic"; finite elements:
"fem-linear" and "fem-neohookean" (``hyperelastic.NeoHookeanFEM``, the large-deformation reference).
``element`` ("hex", default, or "tet") chooses the block's elements: its cubes as hexahedra, or
each cube split into 6 tetrahedra on the same nodes (``TetMesh.block``; the tetrahedral models are
``model.TET_MODELS`` and both FEM references).
Tool experiments (``indentation``, ``tool_patch``): a patch of top-face nodes of a block with its
bottom fixed is pressed, lifted or dragged; they report the volume change, the hourglass content of
the displacement (``hourglass_content``), the stability of the equilibrium and, for a saddle, where
the dynamics settles (``settle``).
SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from .._validate import finite_array
from ..solvers.fem import LinearFEM
from ..models.forces import stiffness_data
from ..solvers.hyperelastic import NeoHookeanFEM
from ..solvers.integrators import ImplicitEuler
from ..models.material import Material
from ..geometry.mesh import HexMesh
from ..models.model import MSS_MODELS, Control, State, build_model, hourglass_projectors
from ..geometry.tetmesh import TetMesh
from ..solvers.static import solve_static, zero_energy_modes
from ..models.validity import VALIDATED_SHEAR_DEG, VALIDATED_STRAIN  # noqa: F401  (public names here too)

FEM_MODELS = ("fem-linear", "fem-neohookean")
MODELS = MSS_MODELS + FEM_MODELS
_SOLVER_OPTIONS = ("tolerance", "max_iterations", "load_steps", "max_load_steps")
#: the block's element kinds of ``elongation``, ``shear`` and ``flexion``
ELEMENTS = ("hex", "tet")
@dataclass
class ExperimentResult:
    """What an experiment measured.

    Attributes:
        experiment, model: names.
        positions, rest_positions: (N, 3) final and rest node positions, m.
        converged, residual: static solve status and relative force residual.
        young_modulus, poisson_ratio: measured E (Pa) and nu (elongation).
        shear_modulus: measured G in Pa (shear).  tip_deflection: m, negative downward (flexion).
        strain: engineering strain along x (elongation).  reaction: total reaction force (N).
        zero_energy_modes: count of zero-energy modes under these constraints (mass-spring models
            when requested with ``count_modes=True``).
        wall_time: seconds spent in the solve.
    """

    experiment: str
    model: str
    positions: np.ndarray
    rest_positions: np.ndarray
    converged: bool
    residual: float
    young_modulus: float | None = None
    poisson_ratio: float | None = None
    shear_modulus: float | None = None
    tip_deflection: float | None = None
    strain: float | None = None
    reaction: float | None = None
    zero_energy_modes: int | None = None
    wall_time: float = 0.0
    parameters: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready scalars (no node arrays)."""
        out = {k: v for k, v in asdict(self).items() if k not in ("positions", "rest_positions")}
        return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in out.items()}


def position_errors(result, reference, rest_positions=None) -> tuple[float, float]:
    """(%e_dm, %e_max) of ``result`` against ``reference`` (docs/physics.md section 7).

    %e_dm = sqrt(mean_p |x_p - x_p^ref|^2) / o_max * 100, %e_max = max_p |x_p - x_p^ref| / o_max * 100,
    o_max = max_p |x_p^ref - X_p|. Arguments are ``ExperimentResult`` objects or (N, 3) arrays (then
    ``rest_positions`` X is required).
    """
    x = getattr(result, "positions", result)
    x_ref = getattr(reference, "positions", reference)
    rest = rest_positions if rest_positions is not None else getattr(reference, "rest_positions", None)
    if rest is None:
        raise ValueError("position_errors needs rest_positions when given plain arrays")
    x, x_ref, rest = (np.asarray(a, dtype=float) for a in (x, x_ref, rest))
    if x.shape != x_ref.shape or x.shape != rest.shape:
        raise ValueError(f"position arrays must have the same shape, got {x.shape}, {x_ref.shape}, {rest.shape}")
    o_max = np.linalg.norm(x_ref - rest, axis=1).max()
    if o_max == 0:
        raise ValueError("the reference solution does not move: o_max = 0")
    distance = np.linalg.norm(x - x_ref, axis=1)
    return float(np.sqrt(np.mean(distance**2)) / o_max * 100), float(distance.max() / o_max * 100)


# -- plumbing ----------------------------------------------------------------------------------
def _setup(shape, spacing, young_modulus, poisson_ratio, density, model, element="hex"):
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    if element not in ELEMENTS:
        raise ValueError(f"element must be one of {ELEMENTS} (the block's cubes as hexahedra, or each split into "
                         f"6 tetrahedra on the same nodes), got {element!r}")
    mesh = HexMesh.block(shape, spacing) if element == "hex" else TetMesh.block(shape, spacing)
    material = Material(young_modulus, poisson_ratio, density)
    return mesh, material


def _solve(mesh, material, control, model, gravity, options):
    """Static solve with the named physics -> (positions, reaction (N, 3), converged, residual, modes)."""
    options = dict(options)
    count_modes = options.pop("count_modes", False)
    solver = {k: options.pop(k) for k in _SOLVER_OPTIONS if k in options}
    gravity_vector = (0.0, -gravity, 0.0)
    if model == "fem-neohookean":
        if options:
            raise ValueError(f"unknown options for {model}: {sorted(options)}")
        fem = NeoHookeanFEM(mesh, material).solve(control, gravity_vector, **solver)
        return fem.positions, fem.reaction, fem.converged, fem.residual, None
    if model in FEM_MODELS:
        if options or solver:
            raise ValueError(f"unknown options for {model}: {sorted({**options, **solver})}")
        positions, reaction = LinearFEM(mesh, material).solve(control, gravity_vector)
        return positions, reaction, True, 0.0, None
    mss = build_model(mesh, material, model=model, gravity=gravity_vector, **options)
    result = solve_static(mss, control, **solver)
    modes = zero_energy_modes(mss, control)[0] if count_modes else None
    return result.positions, result.reaction, result.converged, result.residual, modes


def _face(mesh, axis, at_end):
    coordinate = mesh.nodes[:, axis]
    target = coordinate.max() if at_end else coordinate.min()
    return np.flatnonzero(np.isclose(coordinate, target, rtol=0, atol=1e-9 * max(mesh.size.max(), 1e-300)))


def _face_area_shares(mesh, nodes, axis):
    """Fraction of the face area attributed to each node of a block face (quads split 1/4 each,
    triangles of a tetrahedral block 1/3 each: the consistent load of a uniform traction)."""
    if isinstance(mesh, TetMesh):
        triangles = mesh.surface_faces()
        on_face = np.all(np.isin(triangles, nodes), axis=1)
        corners = mesh.nodes[triangles[on_face]]
        area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
        share = np.bincount(triangles[on_face].ravel(), weights=np.repeat(area / 3.0, 3), minlength=mesh.n_nodes)
        return share[nodes] / share[nodes].sum()
    nx_ny_nz = np.array(mesh.shape)
    other = [a for a in range(3) if a != axis]
    counts = np.ones(len(nodes))
    for a in other:
        index = np.rint(mesh.nodes[nodes, a] / mesh.spacing[a]).astype(int)
        counts *= np.where((index == 0) | (index == nx_ny_nz[a]), 1.0, 2.0)
    return counts / counts.sum()


def _warn_beyond_validated(model, value, bound, subject, validation):
    """UserWarning (pointing at the experiment's caller) when a mass-spring ``model`` ran at
    |``value``| beyond the validated ``bound``; the FEM models are the references and not warned.
    ``subject`` names the value ("strain 5"), ``validation`` the range and where it is checked."""
    if model in MSS_MODELS and abs(value) > bound:
        warnings.warn(
            f"{subject} is beyond the range the mass-spring model is validated for "
            f"({validation}; docs/physics.md section 8): the result is a model extrapolation, "
            f"not a validated prediction", UserWarning, stacklevel=3)


def _strain_or_force(strain, force):
    if (strain is None) == (force is None):
        raise ValueError("give exactly one of strain (imposed displacement) or force (imposed force, N)")
    if strain is not None:
        strain = float(finite_array("strain", strain))
        if strain == 0 or strain <= -1:
            raise ValueError(f"strain must be non-zero and > -1, got {strain}")
    else:
        force = float(finite_array("force", force))
        if force == 0:
            raise ValueError("force must be non-zero (N)")
    return strain, force


# -- experiments ---------------------------------------------------------------------------------
def elongation_control(mesh: HexMesh | TetMesh, strain=None) -> Control:
    """``elongation``'s boundary conditions on a block ``mesh`` (even ny and nz): face x = 0 held
    along x, its node (0, Ly/2, Lz/2) in y and z and its node (0, Ly/2, Lz) in y (no rigid motion),
    and, with ``strain``, face x = Lx moved by strain Lx along x (m); for stability checks and mode
    counts of the experiment's equilibrium too."""
    nx, ny, nz = mesh.shape
    nodes = mesh.nodes
    left, right = _face(mesh, 0, False), _face(mesh, 0, True)
    control = Control.free(mesh.n_nodes)
    control.impose(left, nodes[left], components=0)
    centre = mesh.node_index(0, ny // 2, nz // 2)
    control.impose([centre], nodes[centre], components=[1, 2])
    top = mesh.node_index(0, ny // 2, nz)
    control.impose([top], nodes[top], components=1)
    if strain is not None:
        control.impose(right, nodes[right] + [strain * mesh.size[0], 0, 0], components=0)
    return control


def elongation(shape, spacing, young_modulus, poisson_ratio, *, strain=None, force=None,
               model="baudet", density=1000.0, element="hex", **options) -> ExperimentResult:
    """Uniaxial pull along x: measured Young's modulus and Poisson's ratio.

    Args:
        shape: (nx, ny, nz) elements; ny and nz must be even (the rigid-motion anchors sit at
            mid-height and mid-depth of face x = 0).
        spacing: element size in m (float or (dx, dy, dz)).
        young_modulus: E in Pa.  poisson_ratio: nu.  density: kg/m^3 (unused by statics).
        strain: imposed engineering strain of face x = Lx (displacement control), or
        force: total force in N spread over face x = Lx by area (force control).
        model: physics name (see module docstring).
        element: "hex" (the block's cubes) or "tet" (each cube split into 6 tetrahedra on the same
            nodes, ``TetMesh.block``).
        **options: model options (``volume_conservation``, ``corrections``, ``nu_factor``, ...),
            solver options (``tolerance``, ``load_steps``, ...) and ``count_modes``.

    A mass-spring model whose strain (imposed, or measured under ``force``) exceeds
    ``VALIDATED_STRAIN`` in magnitude gives its result with a UserWarning: it is an extrapolation.
    """
    strain, force = _strain_or_force(strain, force)
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model, element)
    nx, ny, nz = mesh.shape
    if ny % 2 or nz % 2:
        raise ValueError(f"elongation needs even ny and nz (anchor nodes at mid-face), got shape {mesh.shape}")
    length = mesh.size
    nodes = mesh.nodes
    right = _face(mesh, 0, True)
    control = elongation_control(mesh, strain)
    if strain is None:
        control.force[right, 0] = force * _face_area_shares(mesh, right, 0)
    start = time.perf_counter()
    positions, reaction, converged, residual, modes = _solve(mesh, material, control, model, 0.0, options)
    wall = time.perf_counter() - start
    displacement = positions - nodes
    if strain is None:
        measured_strain = displacement[right, 0].mean() / length[0]
        pull = force
    else:
        measured_strain = strain
        pull = reaction[right, 0].sum()
    _warn_beyond_validated(
        model, measured_strain, VALIDATED_STRAIN,
        f"strain {strain:g}" if force is None else f"measured strain {measured_strain:.3g} (under force {force:g} N)",
        f"|strain| <= {VALIDATED_STRAIN:g} in tension and compression against neo-Hookean "
        "FEM, tests/test_validation.py and benchmarks/validation.py figures 1-2")
    area = length[1] * length[2]
    lateral = []
    for axis in (1, 2):
        low, high = _face(mesh, axis, False), _face(mesh, axis, True)
        change = displacement[high, axis].mean() - displacement[low, axis].mean()
        lateral.append(-change / length[axis] / measured_strain)
    return ExperimentResult(
        "elongation", model, positions, nodes.copy(), converged, residual,
        young_modulus=float(pull / area / measured_strain), poisson_ratio=float(np.mean(lateral)),
        strain=float(measured_strain), reaction=float(pull), zero_energy_modes=modes, wall_time=wall,
        parameters=dict(shape=list(mesh.shape), spacing=mesh.spacing.tolist(), imposed_young_modulus=young_modulus,
                        imposed_poisson_ratio=poisson_ratio, imposed_strain=strain, imposed_force=force,
                        element=element),
    )


def shear(shape, spacing, young_modulus, poisson_ratio, *, angle_deg, model="baudet",
          density=1000.0, element="hex", **options) -> ExperimentResult:
    """Simple shear: face y = 0 fixed, face y = Ly moved by tan(angle) Ly along x; ``element`` as in
    ``elongation``.

    Returns the measured shear modulus G = (x reaction on the top / (Lx Lz)) / tan(angle), Pa.
    A mass-spring model sheared beyond ``VALIDATED_SHEAR_DEG`` gives its result with a UserWarning.
    """
    angle = float(finite_array("angle_deg", angle_deg))
    if not 0 < abs(angle) < 80:
        raise ValueError(f"angle_deg must be non-zero and within (-80, 80) degrees, got {angle}")
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model, element)
    length, nodes = mesh.size, mesh.nodes
    bottom, top = _face(mesh, 1, False), _face(mesh, 1, True)
    shift = math.tan(math.radians(angle))
    control = Control.free(mesh.n_nodes)
    control.impose(bottom, nodes[bottom])
    control.impose(top, nodes[top] + [shift * length[1], 0, 0])
    start = time.perf_counter()
    positions, reaction, converged, residual, modes = _solve(mesh, material, control, model, 0.0, options)
    wall = time.perf_counter() - start
    pull = reaction[top, 0].sum()
    _warn_beyond_validated(
        model, angle, VALIDATED_SHEAR_DEG, f"angle_deg {angle:g}", f"|angle_deg| <= {VALIDATED_SHEAR_DEG:g} in shear, where "
        "tests/test_validation.py and benchmarks/validation.py figure 3 hold the 2% position-error floor "
        "against FEM; the springs stiffen with the angle beyond it")
    return ExperimentResult(
        "shear", model, positions, nodes.copy(), converged, residual,
        shear_modulus=float(pull / (length[0] * length[2]) / shift), reaction=float(pull),
        zero_energy_modes=modes, wall_time=wall,
        parameters=dict(shape=list(mesh.shape), spacing=mesh.spacing.tolist(), imposed_young_modulus=young_modulus,
                        imposed_poisson_ratio=poisson_ratio, angle_deg=angle, element=element),
    )


def flexion(shape, spacing, young_modulus, poisson_ratio, *, density, gravity=9.81, model="baudet",
            element="hex", **options) -> ExperimentResult:
    """Cantilever under gravity: face x = 0 fixed, gravity (0, -gravity, 0); ``element`` as in
    ``elongation``.

    Returns ``tip_deflection``: mean y displacement of face x = Lx in m (negative downward).
    """
    gravity = float(finite_array("gravity", gravity))
    if gravity < 0:
        raise ValueError(f"gravity must be >= 0 m/s^2 (it acts along -y), got {gravity}")
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model, element)
    nodes = mesh.nodes
    clamp, tip = _face(mesh, 0, False), _face(mesh, 0, True)
    control = Control.free(mesh.n_nodes)
    control.impose(clamp, nodes[clamp])
    start = time.perf_counter()
    positions, reaction, converged, residual, modes = _solve(mesh, material, control, model, gravity, options)
    wall = time.perf_counter() - start
    return ExperimentResult(
        "flexion", model, positions, nodes.copy(), converged, residual,
        tip_deflection=float((positions[tip, 1] - nodes[tip, 1]).mean()), reaction=float(reaction[clamp, 1].sum()),
        zero_energy_modes=modes, wall_time=wall,
        parameters=dict(shape=list(mesh.shape), spacing=mesh.spacing.tolist(), imposed_young_modulus=young_modulus,
                        imposed_poisson_ratio=poisson_ratio, density=density, gravity=gravity, element=element),
    )


# -- tool loading: indentation and pull by a patch of top-face nodes (issue 3, Fig. 5 and 6) ----
def hourglass_content(rest_positions, elements, positions) -> float:
    """Share of a displacement field that lies in the elements' hourglass spaces (docs/physics.md 6).

    Each element's nodal displacements u_e (8, 3) are projected on its hourglass space
    (``model.hourglass_projectors``: the nodal fields orthogonal to every affine one); the result
    is sqrt(sum_e |P_e u_e|^2 / sum_e |u_e|^2), between 0 (piecewise affine field) and 1. A smooth
    trilinear FEM field has some (bending and indentation use these fields); the ratio of a
    mass-spring field's content to the FEM's on the same mesh says whether its zero-energy modes
    are excited.
    """
    rest = np.asarray(rest_positions, float)
    displacement = (np.asarray(positions, float) - rest)[elements]  # (M, 8, 3)
    total = float(np.sum(displacement**2))
    if total == 0:
        return 0.0
    projected = np.einsum("mab,mbi->mai", hourglass_projectors(rest, elements), displacement)
    return float(np.sqrt(np.sum(projected**2) / total))


def tool_patch_nodes(mesh: HexMesh, patch: int) -> np.ndarray:
    """Indices of the ``patch`` x ``patch`` central nodes of the top face y = Ly of a block.

    The patch is centred when nx + 1 - patch and nz + 1 - patch are even (e.g. 3x3 nodes on a
    6x6 face of elements); otherwise it sits half an element towards the origin.
    """
    nx, ny, nz = mesh.shape
    patch = int(patch)
    if not 1 <= patch <= min(nx, nz) + 1:
        raise ValueError(f"patch must be between 1 and {min(nx, nz) + 1} nodes, got {patch}")
    i0, k0 = (nx + 1 - patch) // 2, (nz + 1 - patch) // 2
    i, k = np.meshgrid(np.arange(i0, i0 + patch), np.arange(k0, k0 + patch), indexing="ij")
    return np.asarray(mesh.node_index(i.ravel(), ny, k.ravel()), dtype=int)


def _fem_lowest_eigenvalue(fem: NeoHookeanFEM, control: Control, positions) -> float:
    """Smallest eigenvalue (N/m) of the neo-Hookean tangent on the free components."""
    free = np.flatnonzero(~control.fixed.ravel())
    stiffness = fem.tangent_stiffness(positions).tocsr()[free][:, free]
    return float(spla.eigsh(stiffness, k=1, which="SA", tol=1e-6, maxiter=50 * len(free))[0][0])


def settle(model, control: Control, positions, *, amplitude: float = 0.02, dt: float = 0.01,
           max_steps: int = 2000, rest_speed: float = 1e-5):
    """Follow the dynamics away from an unstable equilibrium: where a simulation really ends up.

    A static solver can converge to a saddle (hourglass buckling under compression, docs/physics.md 6);
    any disturbance moves a dynamic simulation off it. This perturbs ``positions`` along the
    eigenvector of the lowest eigenvalue of the constrained tangent (largest nodal displacement
    ``amplitude`` times the smallest element edge), runs damped implicit Euler (``dt`` s) until
    every node is slower than ``rest_speed`` times the elastic wave speed sqrt(E / rho) (or for
    ``max_steps``), and polishes the result with ``solve_static`` from there.

    Returns ``(static.StaticResult with lowest_eigenvalue, steps run, unstable_reason or None)``.
    """
    free = np.flatnonzero(~control.fixed.ravel())
    stiffness = model.pattern.matrix(stiffness_data(model, positions)).tocsr()[free][:, free]
    _, vectors = spla.eigsh(0.5 * (stiffness + stiffness.T), k=1, which="SA", tol=1e-6, maxiter=50 * len(free))
    mode = vectors[:, 0] / np.abs(vectors[:, 0]).max()
    start = np.array(positions, dtype=float)
    # the smallest element edge: the mean edge lengths per axis of hexahedra, the springs of tetrahedra
    edge = model.axis_rest_length.min() if model.axis_rest_length.size else model.rest_length.min()
    start.ravel()[free] += amplitude * float(edge) * mode
    state, scratch = State(start, np.zeros_like(start)), State(start.copy(), np.zeros_like(start))
    integrator = ImplicitEuler()
    limit = rest_speed * float(np.sqrt(np.max(model.young_modulus / model.density)))
    reason, steps = None, 0
    for steps in range(1, int(max_steps) + 1):
        report = integrator.simulate(model, state, scratch, dt, control)
        state, scratch = scratch, state
        if report.unstable:
            reason = report.unstable_reason
            break
        if steps > 20 and np.abs(state.velocities).max() < limit:
            break
    if reason is not None:
        return None, steps, reason
    return solve_static(model, control, initial=state.positions, check_stability=True), steps, None


@dataclass
class ToolResult(ExperimentResult):
    """``ExperimentResult`` of a tool experiment, plus:

    Attributes:
        tool_force: (3,) total force (N) the block exerts on the tool patch (on its imposed
            components; minus the reaction).
        relative_volume_change: (V - V0) / V0 of the whole block.
        hourglass_content: share of the displacement field in the element hourglass spaces
            (``hourglass_content``).
        lowest_eigenvalue: smallest eigenvalue of the constrained tangent (N/m) at the
            equilibrium, with ``check_stability=True`` (mass-spring models, fem-neohookean);
            negative means a saddle (unstable equilibrium).
        settled: with ``settle_if_unstable=True`` and a saddle, where the dynamics goes from it
            (``settle``): a ``ToolResult`` of the polished equilibrium, or None when that run
            diverged (then ``settle_failure`` says why, e.g. an inverted element).
    """

    tool_force: np.ndarray | None = None
    relative_volume_change: float | None = None
    hourglass_content: float | None = None
    lowest_eigenvalue: float | None = None
    settled: "ToolResult | None" = None
    settle_failure: str | None = None

    @property
    def stable(self) -> bool | None:
        return None if self.lowest_eigenvalue is None else self.lowest_eigenvalue >= 0.0

    def summary(self) -> dict:
        """JSON-ready scalars (no node arrays; ``settled`` summarised the same way)."""
        skip = ("positions", "rest_positions", "settled")
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k not in skip}
        out["tool_force"] = None if self.tool_force is None else [float(v) for v in self.tool_force]
        out["settled"] = None if self.settled is None else self.settled.summary()
        return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in out.items()}


def tool_patch(shape, spacing, young_modulus, poisson_ratio, *, displacement, patch=3, glued=True,
               model="baudet", density=1000.0, check_stability=False, settle_if_unstable=False,
               **options) -> ToolResult:
    """A tool moves a patch of the top face of a block whose bottom face y = 0 is fixed.

    Args:
        shape, spacing, young_modulus, poisson_ratio, density: the block (as ``elongation``).
        displacement: (3,) tool displacement in m (y is up: (0, -d, 0) presses, (0, d, 0) pulls,
            (d, 0, 0) drags sideways).
        patch: the tool covers the ``patch`` x ``patch`` central nodes of face y = Ly
            (``tool_patch_nodes``).
        glued: True imposes all three components of the patch nodes (the tissue sticks to the
            tool); False imposes only the y component (a frictionless flat probe: the patch nodes
            slide freely in x and z).
        model: physics name.  check_stability: also compute the lowest tangent eigenvalue.
        settle_if_unstable: mass-spring models with ``check_stability``: when the equilibrium is a
            saddle, also follow the dynamics off it (``settle``) into ``result.settled``.
        **options: model and solver options as in ``elongation`` (default ``load_steps=4``).
    Returns:
        ``ToolResult`` (``reaction`` is the y component of ``tool_force``).
    """
    displacement = finite_array("displacement", displacement, shape=(3,))
    if not np.any(displacement):
        raise ValueError("displacement must be non-zero (m)")
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model)
    nodes = mesh.nodes
    bottom, tool = _face(mesh, 1, False), tool_patch_nodes(mesh, patch)
    if not glued and (displacement[0] or displacement[2]):
        raise ValueError("a frictionless probe (glued=False) only moves along y")
    control = Control.free(mesh.n_nodes)
    control.impose(bottom, nodes[bottom])
    control.impose(tool, nodes[tool] + displacement, components=(0, 1, 2) if glued else 1)
    options = dict(options)
    options.setdefault("load_steps", 4)
    start = time.perf_counter()
    lowest = None
    if model in MSS_MODELS:
        count_modes = options.pop("count_modes", False)
        solver = {k: options.pop(k) for k in _SOLVER_OPTIONS if k in options}
        mss = build_model(mesh, material, model=model, **options)
        solved = solve_static(mss, control, check_stability=check_stability, **solver)
        positions, reaction, converged, residual = solved.positions, solved.reaction, solved.converged, solved.residual
        lowest = solved.lowest_eigenvalue
        modes = zero_energy_modes(mss, control)[0] if count_modes else None
        settled = failure = None
        if settle_if_unstable and lowest is not None and lowest < 0:
            polished, steps, failure = settle(mss, control, positions)
            if polished is not None:
                settled = _tool_result(mesh, tool, polished.positions, polished.reaction, polished.converged,
                                       polished.residual, polished.lowest_eigenvalue, model, {"settle_steps": steps})
    else:
        if model == "fem-linear":
            options.pop("load_steps")
        positions, reaction, converged, residual, modes = _solve(mesh, material, control, model, 0.0, options)
        if check_stability and model == "fem-neohookean":
            lowest = _fem_lowest_eigenvalue(NeoHookeanFEM(mesh, material), control, positions)
        settled = failure = None
    wall = time.perf_counter() - start
    result = _tool_result(mesh, tool, positions, reaction, converged, residual, lowest, model,
                          dict(shape=list(mesh.shape), spacing=mesh.spacing.tolist(),
                               imposed_young_modulus=young_modulus, imposed_poisson_ratio=poisson_ratio,
                               displacement=displacement.tolist(), patch=int(patch), glued=bool(glued)))
    result.zero_energy_modes, result.wall_time = modes, wall
    result.settled, result.settle_failure = settled, failure
    return result


def _tool_result(mesh, tool, positions, reaction, converged, residual, lowest, model, parameters) -> ToolResult:
    nodes = mesh.nodes
    return ToolResult(
        "tool_patch", model, positions, nodes.copy(), converged, residual, reaction=float(reaction[tool, 1].sum()),
        parameters=parameters, tool_force=-reaction[tool].sum(axis=0),
        relative_volume_change=float(mesh.element_volumes(positions).sum() / mesh.element_volumes().sum() - 1),
        hourglass_content=hourglass_content(nodes, mesh.elements, positions), lowest_eigenvalue=lowest,
    )


def indentation(shape, spacing, young_modulus, poisson_ratio, *, depth, patch=3, glued=False, **options) -> ToolResult:
    """Press the central ``patch`` x ``patch`` top-face nodes down by ``depth`` times the block
    height Ly (0 < depth < 1), bottom face fixed; frictionless probe unless ``glued``. Same
    keywords and result as ``tool_patch``."""
    depth = float(finite_array("depth", depth))
    if not 0 < depth < 1:
        raise ValueError(f"depth must be a fraction of the block height in (0, 1), got {depth}")
    height = float(HexMesh.block(shape, spacing).size[1])
    result = tool_patch(shape, spacing, young_modulus, poisson_ratio, displacement=(0.0, -depth * height, 0.0),
                        patch=patch, glued=glued, **options)
    result.experiment = "indentation"
    result.parameters["depth"] = depth
    return result
