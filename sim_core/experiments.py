"""Validation experiments of DESIGN.md: elongation, shear and flexion of a structured block.

Each experiment builds the block, imposes its boundary conditions, solves for static equilibrium
with the physics named by ``model`` and measures moduli the way a materials lab would. Mass-spring
models: "baudet", "baudet-original", "uniform-springs"; finite elements: "fem-linear" and
"fem-neohookean" (``hyperelastic.NeoHookeanFEM``, the large-deformation reference).
SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ._validate import finite_array
from .fem import LinearFEM
from .hyperelastic import NeoHookeanFEM
from .material import Material
from .mesh import HexMesh
from .model import MSS_MODELS, Control, build_model
from .static import solve_static, zero_energy_modes

FEM_MODELS = ("fem-linear", "fem-neohookean")
MODELS = MSS_MODELS + FEM_MODELS
_SOLVER_OPTIONS = ("tolerance", "max_iterations", "load_steps", "max_load_steps")


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
    """(%e_dm, %e_max) of ``result`` against ``reference`` (physics.md section 7).

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
def _setup(shape, spacing, young_modulus, poisson_ratio, density, model):
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    mesh = HexMesh.block(shape, spacing)
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
    """Fraction of the face area attributed to each node of a block face (quads split 1/4 each)."""
    nx_ny_nz = np.array(mesh.shape)
    other = [a for a in range(3) if a != axis]
    counts = np.ones(len(nodes))
    for a in other:
        index = np.rint(mesh.nodes[nodes, a] / mesh.spacing[a]).astype(int)
        counts *= np.where((index == 0) | (index == nx_ny_nz[a]), 1.0, 2.0)
    return counts / counts.sum()


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
def elongation(shape, spacing, young_modulus, poisson_ratio, *, strain=None, force=None,
               model="baudet", density=1000.0, **options) -> ExperimentResult:
    """Uniaxial pull along x (DESIGN.md): measured Young's modulus and Poisson's ratio.

    Args:
        shape: (nx, ny, nz) elements; ny and nz must be even (the rigid-motion anchors sit at
            mid-height and mid-depth of face x = 0).
        spacing: element size in m (float or (dx, dy, dz)).
        young_modulus: E in Pa.  poisson_ratio: nu.  density: kg/m^3 (unused by statics).
        strain: imposed engineering strain of face x = Lx (displacement control), or
        force: total force in N spread over face x = Lx by area (force control).
        model: physics name (see module docstring).
        **options: model options (``volume_conservation``, ``corrections``, ``nu_factor``, ...),
            solver options (``tolerance``, ``load_steps``, ...) and ``count_modes``.
    """
    strain, force = _strain_or_force(strain, force)
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model)
    nx, ny, nz = mesh.shape
    if ny % 2 or nz % 2:
        raise ValueError(f"elongation needs even ny and nz (anchor nodes at mid-face), got shape {mesh.shape}")
    length = mesh.size
    nodes = mesh.nodes
    left, right = _face(mesh, 0, False), _face(mesh, 0, True)
    control = Control.free(mesh.n_nodes)
    control.impose(left, nodes[left], components=0)
    centre = mesh.node_index(0, ny // 2, nz // 2)
    control.impose([centre], nodes[centre], components=[1, 2])
    top = mesh.node_index(0, ny // 2, nz)
    control.impose([top], nodes[top], components=1)
    if strain is not None:
        control.impose(right, nodes[right] + [strain * length[0], 0, 0], components=0)
    else:
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
                        imposed_poisson_ratio=poisson_ratio, imposed_strain=strain, imposed_force=force),
    )


def shear(shape, spacing, young_modulus, poisson_ratio, *, angle_deg, model="baudet",
          density=1000.0, **options) -> ExperimentResult:
    """Simple shear (DESIGN.md): face y = 0 fixed, face y = Ly moved by tan(angle) Ly along x.

    Returns the measured shear modulus G = (x reaction on the top / (Lx Lz)) / tan(angle), Pa.
    """
    angle = float(finite_array("angle_deg", angle_deg))
    if not 0 < abs(angle) < 80:
        raise ValueError(f"angle_deg must be non-zero and within (-80, 80) degrees, got {angle}")
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model)
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
    return ExperimentResult(
        "shear", model, positions, nodes.copy(), converged, residual,
        shear_modulus=float(pull / (length[0] * length[2]) / shift), reaction=float(pull),
        zero_energy_modes=modes, wall_time=wall,
        parameters=dict(shape=list(mesh.shape), spacing=mesh.spacing.tolist(), imposed_young_modulus=young_modulus,
                        imposed_poisson_ratio=poisson_ratio, angle_deg=angle),
    )


def flexion(shape, spacing, young_modulus, poisson_ratio, *, density, gravity=9.81, model="baudet",
            **options) -> ExperimentResult:
    """Cantilever under gravity (DESIGN.md): face x = 0 fixed, gravity (0, -gravity, 0).

    Returns ``tip_deflection``: mean y displacement of face x = Lx in m (negative downward).
    """
    gravity = float(finite_array("gravity", gravity))
    if gravity < 0:
        raise ValueError(f"gravity must be >= 0 m/s^2 (it acts along -y), got {gravity}")
    mesh, material = _setup(shape, spacing, young_modulus, poisson_ratio, density, model)
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
                        imposed_poisson_ratio=poisson_ratio, density=density, gravity=gravity),
    )
