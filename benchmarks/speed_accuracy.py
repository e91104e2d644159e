"""Speed against accuracy: node-position error against wall time per simulated second.

    python -m benchmarks.speed_accuracy [--quick] [--resolutions 2 4 8 12 16] [--reference 20] [--replot]

The block: a 4 cm cube of soft tissue (E = 5 kPa, nu = 0.45, rho = 1060 kg/m^3), bottom face y = 0
fixed, no gravity (its 8% sag would mix a second load into the comparison). The tool is the set of
top-face nodes (y = 4 cm) inside the central 2 x 2 cm square ([1, 3] cm in x and z; at 2 elements
per side this is the single centre node). Two scenes:

* ``indentation`` (a): a frictionless flat probe (only u_y of the tool nodes imposed) pressed
  2 mm (5% of the height): small strains, nearly linear.
* ``pull`` (b): the tool glued (all components imposed), translated by (16, 12, 0) mm and turned
  by 30 degrees about z around the patch centre: large strains and large rotations.

The tool moves along its path with a smoothstep ramp s(t) = 3 r^2 - 2 r^3, r = t / 0.5 s, reaches
its end at t = 0.5 s and holds there until t = 1 s. Every configuration simulates that second:

* ``explicit``: symplectic Euler at 0.9x and 0.5x ``stable_time_step`` (eigen estimate with
  damping, at rest; the deformed block is stiffer, so 0.9x can diverge).
* ``implicit``: linearised implicit Euler at dt in {5, 20, 50} ms with two linear solves, both
  Jacobi-preconditioned BiCGSTAB on the whole system (corrections and volume forces implicit):
  ``bicgstab`` (tolerance 1e-6, at most 200 iterations: in practice converged) and
  ``bicgstab-15`` (the same, at most 15 iterations: the report's iteration budget).
* ``quasi-static``: ``solve_static`` once per control step, 10 control steps per simulated second
  (5 along the ramp, 5 holding), each warm-started from the previous equilibrium.
* ``fem-linear``: linear FEM with K_ff factorised once (set-up); a control step is a
  back-substitution, 10 per simulated second.
* ``fem-neohookean``: ``NeoHookeanFEM.solve`` once per control step, 10 per simulated second,
  warm-started.

Mass-spring models (all with ``hourglass_control=0.5``, the environments' default, so that the
comparison is about the spring law and not about hourglass buckling): ``baudet`` with every
stepping above, ``baudet-original`` and ``uniform-springs`` quasi-static and implicit (20 ms,
bicgstab); ``baudet-hyperelastic`` (docs/physics.md section 11) explicit, implicit with ``bicgstab`` and
``bicgstab-15`` and quasi-static, without hourglass control (it refuses it: its springs resist the
hourglass modes, and the control is not objective). Resolutions n = 2, 4, 8, 12, 16 elements per side (those whose nodes lie on the tool
square's edges; n = 6 would shrink the tool).

Error. The final positions (t = 1 s) are compared with the static ``fem-neohookean`` equilibrium
at the end of the path on a finer mesh (n = 20 by default), computed by ``reference_chain``:
n = 8 from rest with ``NeoHookeanFEM.solve``, then n = 12, 16 and 20 by Newton from the previous
solution interpolated to the finer mesh. The difference between the n = 16 and n = 20 solutions is
reported as the reference's convergence check. Every displacement field u (m) is evaluated at the same 125 material points,
the 5 x 5 x 5 grid {0, 1, 2, 3, 4} cm in each axis (it contains the tool centre), by trilinear
interpolation in each model's own hex mesh (the cell is found from the rest coordinates), and

    error_pct     = 100 * mean_p |u_p - u_ref_p| / max_p |u_ref_p|,
    error_max_pct = 100 * max_p  |u_p - u_ref_p| / max_p |u_ref_p|.

Speed. ``wall_per_sim_s`` = wall-clock seconds spent stepping (or solving) / simulated seconds (1 s).
Set-up (model build, time-step estimate, fem-linear's factorisation, numba compilation) is excluded
and listed as ``setup_s``. Runs faster than 1.5 s are repeated (3 runs in all) and the median is
kept; the machine is shared (2 cores, often with other jobs), so timings are noisy. A run that diverges (the integrators' divergence monitor: status ``unstable``),
whose static solve does not converge (``not converged``) or that raises (``failed``) is kept in the
CSV with its ``reason`` and is never on the Pareto front. Budget: a run is stopped after 30 s of
wall time (``over budget``, SIGALRM), and a run whose time predicted from the same configuration at
the previous resolution (x (n / n_prev)^4) exceeds 30 s is not started (``skipped``): this keeps the
default run near 20-30 minutes on 2 shared cores; ``--budget`` raises it.

Pareto front (per scene): the successful configurations that no other successful one beats on
both wall time and error (``pareto_front``).

Peer: MuJoCo's flex on the same scenes (``benchmarks/speed_accuracy_peers.py``, which needs the
``bench`` extra) is drawn as points of its own where its results file exists; they are not on the
front. ``--replot`` only redraws the figure from the results files.

Writes benchmarks/results/speed_accuracy.csv, benchmarks/results/speed_accuracy.json and
docs/figures/speed_accuracy.png (written to temporary files, then moved into place).
``--quick``: n = 2 and 4, reference n = 8, a subset of the implicit settings, budget 10 s (< 2 min).
SI units throughout: m, s, Pa, kg/m^3.
"""

from __future__ import annotations

import argparse
import csv
import functools
import io
import json
import math
import signal
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy.sparse.linalg as spla

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.solvers.fem import LinearFEM
from sim_core.files import atomic_write, finish_figure
from sim_core.solvers.hyperelastic import NeoHookeanFEM
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, stable_time_step
from sim_core.geometry.mesh import LOCAL_CORNERS
from sim_core.models.model import Control
from training.common import write_json

ROOT = Path(__file__).resolve().parents[1]

# -- the physical block (SI) ---------------------------------------------------------------------
SIZE = 0.04  # m, cube side
YOUNG, POISSON, DENSITY = 5.0e3, 0.45, 1060.0  # Pa, -, kg/m^3
PATCH_HALF_WIDTH = 0.01  # m: the tool covers [L/2 - w, L/2 + w] in x and z on the top face
HOURGLASS = 0.5  # hourglass_control of every mass-spring model but HYPER
#: the finite-strain model (docs/physics.md section 11): no hourglass control (it refuses it; its
#: springs resist the hourglass modes)
HYPER = "baudet-hyperelastic"
MSS_METHODS = ("baudet", "baudet-original", "uniform-springs", HYPER)
RAMP_TIME, END_TIME = 0.5, 1.0  # s
CONTROL_RATE = 10  # static solves (control steps) per simulated second
EXPLICIT_SAFETIES = (0.9, 0.5)  # explicit dt = this x stable_time_step (at rest)
REPEAT_BELOW = 1.5  # s: runs faster than this are repeated and the median wall time kept
REPEATS = 3
STATIC_MAX_LOAD_STEPS = 32  # cap on load-step halvings per control step (bounds a failing solve)

RESOLUTIONS = (2, 4, 8, 12, 16)
REFERENCE_RESOLUTION = 20
IMPLICIT_DTS = (0.005, 0.02, 0.05)
BUDGET = 30.0  # s of wall time per run: longer runs are stopped ("over budget"), predicted ones skipped
GROWTH_EXPONENT = 4.0  # predicted wall time of a run at n from the same family at n_prev: (n / n_prev)^4
IMPLICIT_SOLVERS = {  # name: ImplicitEuler keywords
    "bicgstab": dict(preconditioner="jacobi", tolerance=1e-6, max_iterations=200),
    "bicgstab-15": dict(preconditioner="jacobi", tolerance=1e-6, max_iterations=15),
}
QUICK = dict(resolutions=(2, 4), reference_resolution=8, implicit_dts=(0.02, 0.05),
             implicit_solvers=("bicgstab", "bicgstab-15"), budget=10.0)

ERROR_DEFINITION = ("error_pct = 100 * mean_p |u_p - u_ref_p| / max_p |u_ref_p| and error_max_pct = 100 * max_p "
                    "|u_p - u_ref_p| / max_p |u_ref_p| over the 5x5x5 material points {0,1,2,3,4} cm, u = displacement "
                    "(m) at t = 1 s interpolated trilinearly in each model's mesh; reference = static fem-neohookean on "
                    "a finer mesh")
SPEED_DEFINITION = "wall_per_sim_s = wall-clock seconds of stepping / simulated seconds (1 s); set-up excluded (setup_s)"


@dataclass(frozen=True)
class SceneSpec:
    """A tool path: ``translation`` (3,) m and ``rotation_deg`` about z through the patch centre
    reached at t = RAMP_TIME; ``glued`` imposes all components of the tool nodes, otherwise u_y only."""

    name: str
    label: str
    translation: tuple
    rotation_deg: float
    glued: bool


SCENES = {
    "indentation": SceneSpec("indentation", "(a) indentation: frictionless probe pressed 2 mm (5%)",
                             (0.0, -0.002, 0.0), 0.0, False),
    "pull": SceneSpec("pull", "(b) pull: glued tool moved (16, 12, 0) mm and turned 30 deg",
                      (0.016, 0.012, 0.0), 30.0, True),
}


# -- geometry, tool and control ------------------------------------------------------------------
def block(n: int) -> HexMesh:
    """The n x n x n block of the 4 cm cube (element size SIZE / n m)."""
    return HexMesh.block((n, n, n), SIZE / n)


def tool_nodes(mesh: HexMesh) -> np.ndarray:
    """Top-face nodes inside the central tool square."""
    nodes, tol = mesh.nodes, 1e-6 * SIZE
    centre = 0.5 * SIZE
    inside = ((np.abs(nodes[:, 1] - SIZE) <= tol) & (np.abs(nodes[:, 0] - centre) <= PATCH_HALF_WIDTH + tol)
              & (np.abs(nodes[:, 2] - centre) <= PATCH_HALF_WIDTH + tol))
    return np.flatnonzero(inside)


def ramp(t: float) -> float:
    """Path parameter s in [0, 1] at time t (s): smoothstep over [0, RAMP_TIME], then 1."""
    r = min(max(t / RAMP_TIME, 0.0), 1.0)
    return r * r * (3.0 - 2.0 * r)


def ramp_rate(t: float) -> float:
    """ds/dt (1/s) of ``ramp`` at time t (s): 6 r (1 - r) / RAMP_TIME, 0 outside the ramp."""
    r = min(max(t / RAMP_TIME, 0.0), 1.0)
    return 6.0 * r * (1.0 - r) / RAMP_TIME


def tool_positions(scene: SceneSpec, rest: np.ndarray, s: float) -> np.ndarray:
    """(K, 3) tool node positions (m) at path parameter s: rotated by s * angle about the z axis
    through the patch centre (L/2, L, L/2), then translated by s * translation."""
    angle = math.radians(scene.rotation_deg) * s
    c, sn = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    centre = np.array([0.5 * SIZE, SIZE, 0.5 * SIZE])
    return (rest - centre) @ rotation.T + centre + s * np.asarray(scene.translation, float)


class ScenePath:
    """The constraints of ``scene`` on ``mesh``: ``control(s)`` updates one ``Control`` in place."""

    def __init__(self, scene: SceneSpec, mesh: HexMesh):
        self.scene, self.mesh = scene, mesh
        nodes = mesh.nodes
        self.bottom = np.flatnonzero(nodes[:, 1] <= 1e-9 * SIZE)
        self.tool = tool_nodes(mesh)
        self.components = [0, 1, 2] if scene.glued else [1]
        self._control = Control.free(mesh.n_nodes).impose(self.bottom, nodes[self.bottom])
        self._control.impose(self.tool, nodes[self.tool], components=self.components)
        self._index = np.ix_(self.tool, self.components)

    def control(self, s: float) -> Control:
        """The shared control with the tool at path parameter s (updated in place and returned)."""
        targets = tool_positions(self.scene, self.mesh.nodes[self.tool], s)
        self._control.target[self._index] = targets[:, self.components]
        return self._control

    def fresh(self, s: float) -> Control:
        return self.control(s).copy()


# -- common material points and interpolation ------------------------------------------------------
def material_points(per_side: int = 5) -> np.ndarray:
    """(per_side^3, 3) rest coordinates (m) of the regular grid spanning the block (x fastest)."""
    axis = np.linspace(0.0, SIZE, per_side)
    k, j, i = np.meshgrid(axis, axis, axis, indexing="ij")
    return np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)


def interpolation_weights(shape, spacing, points):
    """Trilinear interpolation of nodal fields of a structured block (node (i, j, k) at index i + (nx+1)(j + (ny+1) k)) at
    material ``points`` (P, 3) m given in rest coordinates.

    The cell of a point is floor(X / h) clipped to the block (points on the far faces use the last
    cell); within it the eight corner weights are prod over axes of (xi or 1 - xi).
    Returns (node indices (P, 8) in VTK corner order, weights (P, 8)); exact for affine fields.
    """
    shape = np.asarray(shape, int)
    spacing = np.broadcast_to(np.asarray(spacing, float), (3,))
    local = np.asarray(points, float) / spacing
    cell = np.clip(np.floor(local).astype(int), 0, shape - 1)
    xi = local - cell  # (P, 3), in [0, 1] inside the block
    corners = cell[:, None, :] + LOCAL_CORNERS.astype(int)[None, :, :]  # (P, 8, 3)
    index = corners[..., 0] + (shape[0] + 1) * (corners[..., 1] + (shape[1] + 1) * corners[..., 2])
    weights = np.prod(np.where(LOCAL_CORNERS[None] > 0, xi[:, None, :], 1.0 - xi[:, None, :]), axis=2)
    return index, weights


def interpolate(field_values, index, weights):
    """(P, 3) values of the nodal field ``field_values`` (N, 3) at the points of ``interpolation_weights``."""
    return np.einsum("pc,pci->pi", weights, np.asarray(field_values, float)[index])


def displacement_at_points(mesh: HexMesh, positions, points) -> np.ndarray:
    """(P, 3) displacement (m) of a block solution at the material ``points``."""
    index, weights = interpolation_weights(mesh.shape, mesh.spacing, points)
    return interpolate(np.asarray(positions, float) - mesh.nodes, index, weights)


def field_errors(u, u_ref) -> tuple[float, float]:
    """(error_pct, error_max_pct) of displacements u (P, 3) against u_ref (module docstring)."""
    u, u_ref = np.asarray(u, float), np.asarray(u_ref, float)
    scale = float(np.linalg.norm(u_ref, axis=1).max())
    if scale == 0:
        raise ValueError("the reference displacement is zero everywhere")
    distance = np.linalg.norm(u - u_ref, axis=1)
    return float(100 * distance.mean() / scale), float(100 * distance.max() / scale)


def pareto_front(times, errors, ok=None) -> np.ndarray:
    """Boolean mask of the Pareto-optimal points (minimise both ``times`` and ``errors``).

    A point is on the front when it is valid (``ok``, finite) and no other valid point is at least
    as good on both and strictly better on one. Exact duplicates are all kept.
    """
    times, errors = np.asarray(times, float), np.asarray(errors, float)
    valid = np.isfinite(times) & np.isfinite(errors)
    if ok is not None:
        valid &= np.asarray(ok, bool)
    front = np.zeros(len(times), bool)
    for i in np.flatnonzero(valid):
        others = valid.copy()
        others[i] = False
        dominated = others & (times <= times[i]) & (errors <= errors[i]) & ((times < times[i]) | (errors < errors[i]))
        front[i] = not dominated.any()
    return front


# -- configurations --------------------------------------------------------------------------------
@dataclass
class Config:
    """One point of the chart: ``method`` (physics), ``stepping``, optional ``solver`` and ``dt`` (s)."""

    method: str
    stepping: str
    resolution: int
    solver: str = ""
    dt: float | None = None

    @property
    def family(self) -> str:
        """The curve a configuration belongs to (everything except the resolution)."""
        parts = [self.method, self.stepping] + ([self.solver] if self.solver else [])
        if self.dt is not None and self.stepping == "implicit":
            parts.append(f"dt={self.dt * 1e3:g}ms")
        return " ".join(parts)

    @property
    def label(self) -> str:
        return f"{self.family} n={self.resolution}"


def configurations(resolutions, implicit_dts=IMPLICIT_DTS, implicit_solvers=tuple(IMPLICIT_SOLVERS)) -> list[Config]:
    """Every configuration of the chart (module docstring), coarse to fine."""
    out = []
    for n in resolutions:
        for method in ("baudet", HYPER):
            for safety in EXPLICIT_SAFETIES:
                out.append(Config(method, "explicit", n, f"{safety:g}x limit"))
            for dt in implicit_dts:
                for solver in implicit_solvers:
                    out.append(Config(method, "implicit", n, solver, dt))
            out.append(Config(method, "quasi-static", n))
        for method in ("baudet-original", "uniform-springs"):
            out.append(Config(method, "quasi-static", n))
            out.append(Config(method, "implicit", n, "bicgstab", 0.02))
        out.append(Config("fem-linear", "static-per-step", n, "LU once"))
        out.append(Config("fem-neohookean", "static-per-step", n, "Newton"))
    return out


@dataclass
class Outcome:
    """What one run did: final ``positions`` (N, 3) m (None if unusable), ``status`` ("ok",
    "unstable", "not converged", "failed"), ``reason``, ``steps``, mean linear-solver ``iterations``."""

    positions: np.ndarray | None
    status: str = "ok"
    reason: str = ""
    steps: int = 0
    iterations: float = float("nan")
    extra: dict = field(default_factory=dict)


@lru_cache(maxsize=8)
def _mss_model(method, n):
    """The mass-spring model of the n^3 block (built once per method and resolution; immutable)."""
    return build_model(block(n), Material(YOUNG, POISSON, DENSITY), model=method,
                       hourglass_control=0.0 if method == HYPER else HOURGLASS)


@lru_cache(maxsize=16)
def _explicit_limit(method, n, scene_name):
    """``stable_time_step`` (s) of the model under the scene's constraints, at rest."""
    return stable_time_step(_mss_model(method, n), ScenePath(SCENES[scene_name], block(n)).fresh(0.0))


def _prepare(config: Config, scene: SceneSpec):
    """Set-up (untimed): returns (runner() -> Outcome, setup info dict)."""
    mesh = block(config.resolution)
    path = ScenePath(scene, mesh)
    info = {}
    if config.method in MSS_METHODS:
        model = _mss_model(config.method, config.resolution)
        if config.stepping == "quasi-static":
            return (lambda: _static_per_step(functools.partial(solve_static, model), path)), info
        if config.stepping == "explicit":
            limit = _explicit_limit(config.method, config.resolution, scene.name)
            safety = float(config.solver.split("x")[0])
            steps = int(math.ceil(END_TIME / (safety * limit)))
            info.update(dt_limit=limit, dt=END_TIME / steps, total_steps=steps)
            return (lambda: _dynamic(model, path, SymplecticEuler(), END_TIME / steps, steps)), info
        if config.stepping == "implicit":
            steps = int(round(END_TIME / config.dt))
            info.update(dt=END_TIME / steps, total_steps=steps)
            options = IMPLICIT_SOLVERS[config.solver]
            return (lambda: _dynamic(model, path, ImplicitEuler(**options), END_TIME / steps, steps)), info
    if config.method == "fem-linear":
        return _fem_linear(mesh, path), info
    if config.method == "fem-neohookean":
        fem = NeoHookeanFEM(mesh, Material(YOUNG, POISSON, DENSITY))
        return (lambda: _static_per_step(fem.solve, path)), info
    raise ValueError(f"unknown configuration {config}")


class BudgetExceeded(Exception):
    """Raised (by SIGALRM) when a run exceeds its wall-time budget."""


PROGRESS = {"t": 0.0}  # simulated time (s) the current run has reached


def _control_times():
    count = int(round(CONTROL_RATE * END_TIME))
    return [(k + 1) / CONTROL_RATE for k in range(count)]


def _dynamic(model, path: ScenePath, integrator, dt, steps) -> Outcome:
    state = model.new_state()
    scratch = state.copy()
    iterations = 0
    for step in range(1, steps + 1):
        control = path.control(ramp(step * dt))
        PROGRESS["t"] = (step - 1) * dt
        report = integrator.simulate(model, state, scratch, dt, control)
        iterations += report.iterations
        state, scratch = scratch, state
        if report.unstable:
            return Outcome(None, "unstable", f"step {step} (t = {step * dt:.3g} s): {report.unstable_reason}", step,
                           iterations / step)
    return Outcome(state.positions.copy(), steps=steps, iterations=iterations / steps)


def _static_per_step(solve, path: ScenePath) -> Outcome:
    """One static solve per control step, warm-started from the previous one: ``solve(control,
    initial, max_load_steps)`` is ``solve_static`` on a model (quasi-static mass-spring) or
    ``NeoHookeanFEM.solve``."""
    positions, newton = None, 0
    times = _control_times()
    for step, t in enumerate(times, 1):
        PROGRESS["t"] = t - 1.0 / CONTROL_RATE
        result = solve(path.control(ramp(t)), initial=positions, max_load_steps=STATIC_MAX_LOAD_STEPS)
        newton += result.iterations
        if not result.converged:
            return Outcome(None, "not converged", f"control step {step} (t = {t:.2g} s): {result.message}", step,
                           newton / step)
        positions = result.positions
    return Outcome(positions.copy(), steps=len(times), iterations=newton / len(times))


def _fem_linear(mesh, path: ScenePath):
    """fem-linear: assemble and factorise K_ff once (set-up); return the per-run stepper."""
    fem = LinearFEM(mesh, Material(YOUNG, POISSON, DENSITY))
    control = path.fresh(0.0)
    fixed = control.fixed.ravel()
    free, imposed = np.flatnonzero(~fixed), np.flatnonzero(fixed)
    k = fem.stiffness.tocsr()
    coupling = k[free][:, imposed]
    factor = spla.splu(k[free][:, free].tocsc(), permc_spec="MMD_AT_PLUS_A")
    rest = mesh.nodes.ravel()

    def runner():
        displacement = np.zeros(rest.size)
        times = _control_times()
        for t in times:
            target = path.control(ramp(t)).target.ravel()
            displacement[imposed] = target[imposed] - rest[imposed]
            displacement[free] = factor.solve(-(coupling @ displacement[imposed]))
        return Outcome((rest + displacement).reshape(-1, 3), steps=len(times), iterations=1.0)

    return runner


def _alarm(signum, frame):
    raise BudgetExceeded()


def run_config(config: Config, scene: SceneSpec, points, budget: float = BUDGET, predicted: float | None = None):
    """Set up, run (repeated when cheap) and summarise one configuration.

    A run is stopped after ``budget`` s of wall time (SIGALRM; status "over budget"), and not
    started when ``predicted`` (s, extrapolated from the same family at a coarser resolution)
    exceeds the budget (status "skipped"). Returns (row without errors, the first run's outcome).
    """
    row = dict(scene=scene.name, method=config.method, stepping=config.stepping, solver=config.solver,
               dt_s=config.dt, resolution=config.resolution, n_nodes=(config.resolution + 1) ** 3,
               predicted_wall_s=predicted)
    if predicted is not None and predicted > budget:
        row.update(status="skipped", reason=f"predicted {predicted:.0f} s > budget {budget:g} s", setup_s=0.0,
                   wall_per_sim_s=np.nan)
        return row, Outcome(None, "skipped")
    start = time.perf_counter()
    try:
        runner, info = _prepare(config, scene)
    except Exception as error:  # noqa: BLE001 - recorded, not hidden
        row.update(status="failed", reason=f"set-up: {type(error).__name__}: {error}", setup_s=time.perf_counter() - start,
                   wall_per_sim_s=np.nan)
        return row, Outcome(None, "failed")
    row["setup_s"] = time.perf_counter() - start
    if "dt" in info:
        row["dt_s"] = info["dt"]
    walls, outcome = [], None
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        for _ in range(REPEATS):
            PROGRESS["t"] = 0.0
            clock = time.perf_counter()
            signal.setitimer(signal.ITIMER_REAL, budget)
            try:
                result = runner()
            except BudgetExceeded:
                result = Outcome(None, "over budget", f"stopped after {budget:g} s at t = {PROGRESS['t']:.3g} s")
            except Exception as error:  # noqa: BLE001 - e.g. an inverted element in a solver
                result = Outcome(None, "failed", f"{type(error).__name__}: {error}")
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            walls.append(time.perf_counter() - clock)
            if outcome is None:
                outcome, reached = result, PROGRESS["t"]
            if walls[-1] > REPEAT_BELOW or result.status != "ok":
                break
    finally:
        signal.signal(signal.SIGALRM, previous)
    wall = float(np.median(walls))
    sim_time = END_TIME if outcome.status == "ok" else reached
    row.update(status=outcome.status, reason=outcome.reason, steps=outcome.steps, mean_iterations=outcome.iterations,
               wall_s=wall, repeats=len(walls), sim_time_s=sim_time,
               wall_per_sim_s=wall / END_TIME if outcome.status == "ok" else np.nan)
    # the full run's cost, for predicting the next resolution (extrapolated when stopped early)
    row["_full_wall"] = wall * END_TIME / max(sim_time, 0.1 * END_TIME)
    if outcome.positions is not None:
        mesh = block(config.resolution)
        outcome.extra["u_points"] = displacement_at_points(mesh, outcome.positions, points)
        if not np.all(np.isfinite(outcome.extra["u_points"])):
            row.update(status="failed", reason="non-finite positions", wall_per_sim_s=np.nan)
    return row, outcome


# -- reference -------------------------------------------------------------------------------------
def solve_reference(scene: SceneSpec, n: int, initial=None, tolerance=1e-9, max_iterations=30):
    """Static neo-Hookean equilibrium of ``scene`` at the end of its path on the n^3 mesh.

    With ``initial`` (N, 3) positions (e.g. a coarser solution interpolated to this mesh): Newton
    with the consistent tangent, SuperLU and a backtracking line search (det F > 0), imposed components set
    to their targets first. Without it, or if that fails, ``NeoHookeanFEM.solve`` from rest with
    4 load steps. Returns (positions (N, 3), info dict).
    """
    mesh = block(n)
    fem = NeoHookeanFEM(mesh, Material(YOUNG, POISSON, DENSITY))
    control = ScenePath(scene, mesh).fresh(1.0)
    start = time.perf_counter()
    if initial is not None:
        x = np.array(initial, float)
        x[control.fixed] = control.target[control.fixed]
        free = np.flatnonzero(~control.fixed.ravel())
        if fem.min_jacobian(x) > 0:
            force = fem.internal_forces(x).ravel()
            for iteration in range(1, max_iterations + 1):
                residual = np.linalg.norm(force[free]) / max(np.linalg.norm(force), 1e-300)
                if residual < tolerance:
                    return x, dict(method="Newton from the prolonged coarser solution", iterations=iteration - 1,
                                   residual=float(residual), wall_s=time.perf_counter() - start)
                k = fem.tangent_stiffness(x).tocsr()[free][:, free].tocsc()
                step = spla.splu(k, permc_spec="MMD_AT_PLUS_A").solve(-force[free])
                scale, norm = 1.0, np.linalg.norm(force[free])
                for _ in range(20):
                    trial = x.copy()
                    trial.ravel()[free] += scale * step
                    if fem.min_jacobian(trial) > 0:
                        trial_force = fem.internal_forces(trial).ravel()
                        if np.linalg.norm(trial_force[free]) < (1 - 1e-4 * scale) * norm:
                            break
                    scale *= 0.5
                else:
                    break
                x, force = trial, trial_force
    result = fem.solve(control, load_steps=4)
    if not result.converged:
        raise RuntimeError(f"reference n={n} did not converge: {result.message}")
    return result.positions, dict(method="NeoHookeanFEM.solve from rest, 4 load steps", iterations=result.iterations,
                                  residual=result.residual, wall_s=time.perf_counter() - start)


def reference_chain(scene: SceneSpec, chain, points) -> list[dict]:
    """Neo-Hookean equilibria of ``scene`` at the resolutions ``chain`` (ascending): the first from
    rest (``NeoHookeanFEM.solve``), each next one by Newton from the previous one prolonged.
    Returns [{resolution, positions, u_points (P, 3) m, info}], finest last."""
    out, previous = [], None
    for n in chain:
        initial = None if previous is None else prolong(previous[0], previous[1], n)
        positions, info = solve_reference(scene, n, initial)
        out.append(dict(resolution=n, positions=positions, info=info,
                        u_points=displacement_at_points(block(n), positions, points)))
        previous = (n, positions)
    return out


def prolong(coarse_n: int, positions, fine_n: int) -> np.ndarray:
    """Positions (m) of a coarse block solution interpolated at the nodes of the fine block."""
    fine = block(fine_n)
    return fine.nodes + displacement_at_points(block(coarse_n), positions, fine.nodes)


# -- the benchmark -----------------------------------------------------------------------------------
def warm_up():
    """Compile the numba kernels (cached on disk after the first run) outside the timings."""
    for config in (Config("baudet", "explicit", 2, "0.9x limit"), Config("baudet", "implicit", 2, "bicgstab", 0.05),
                   Config("baudet", "implicit", 2, "bicgstab-15", 0.05), Config("baudet", "quasi-static", 2),
                   Config("baudet-original", "implicit", 2, "bicgstab", 0.05), Config(HYPER, "quasi-static", 2),
                   Config(HYPER, "explicit", 2, "0.9x limit"), Config(HYPER, "implicit", 2, "bicgstab", 0.05)):
        runner, _ = _prepare(config, SCENES["indentation"])
        runner()


def benchmark(resolutions=RESOLUTIONS, reference_resolution=REFERENCE_RESOLUTION, *, implicit_dts=IMPLICIT_DTS,
              implicit_solvers=tuple(IMPLICIT_SOLVERS), scenes=tuple(SCENES), configs=None, budget=BUDGET,
              verbose=True):
    """Run every configuration on every scene; returns (rows, summary dict).

    ``configs`` overrides the configuration list (a list of ``Config``); ``budget`` is the wall-time
    cap per run in s (``run_config``). The reference of each scene comes from ``reference_chain``
    over the chart's resolutions >= 8, its finest one and ``reference_resolution``; the difference
    between the last two is the convergence check."""
    points = material_points()
    resolutions = tuple(sorted(int(n) for n in resolutions))
    if reference_resolution <= max(resolutions):
        raise ValueError("the reference must be finer than every benchmarked resolution")
    configs = configs if configs is not None else configurations(resolutions, implicit_dts, implicit_solvers)
    rows, summary = [], dict(error_definition=ERROR_DEFINITION, speed_definition=SPEED_DEFINITION,
                             block=dict(size_m=SIZE, young_modulus_pa=YOUNG, poisson_ratio=POISSON,
                                        density_kg_m3=DENSITY, gravity=0.0, hourglass_control=HOURGLASS,
                                        tool_square_m=[0.5 * SIZE - PATCH_HALF_WIDTH, 0.5 * SIZE + PATCH_HALF_WIDTH]),
                             timing=dict(ramp_s=RAMP_TIME, end_s=END_TIME, control_steps_per_s=CONTROL_RATE,
                                         explicit_safeties=list(EXPLICIT_SAFETIES), repeats_below_s=REPEAT_BELOW,
                                         repeats=REPEATS, statistic="median", budget_s=budget,
                                         growth_exponent=GROWTH_EXPONENT),
                             resolutions=list(resolutions), reference_resolution=reference_resolution, scenes={})
    start = time.perf_counter()
    warm_up()
    for name in scenes:
        scene = SCENES[name]
        clock = time.perf_counter()
        scene_rows, fields, last = [], [], {}
        for config in configs:
            previous = last.get(config.family)
            predicted = None
            if previous is not None and previous[0] < config.resolution:
                predicted = previous[1] * (config.resolution / previous[0]) ** GROWTH_EXPONENT
            row, outcome = run_config(config, scene, points, budget, predicted)
            if row["status"] != "skipped":
                last[config.family] = (config.resolution, row.pop("_full_wall", np.inf))
            else:
                last[config.family] = (config.resolution, predicted)
            row.pop("_full_wall", None)
            scene_rows.append(row)
            fields.append(outcome.extra.get("u_points"))
            if verbose:
                print(f"{name:11s} {config.label:48s} {row['status']:12s} wall/sim-s {row.get('wall_per_sim_s', np.nan):9.4f}"
                      f"  setup {row['setup_s']:6.2f}s {row.get('reason', '')[:70]}", flush=True)
        chain = sorted({n for n in resolutions if n >= 8} | {max(resolutions), reference_resolution})
        references = reference_chain(scene, chain, points)
        u_ref = references[-1]["u_points"]
        reference_info = references[-1]["info"]
        for row, u in zip(scene_rows, fields):
            if u is not None and row["status"] == "ok":
                row["error_pct"], row["error_max_pct"] = field_errors(u, u_ref)
            else:
                row["error_pct"] = row["error_max_pct"] = np.nan
        ok = [r["status"] == "ok" for r in scene_rows]
        front = pareto_front([r["wall_per_sim_s"] for r in scene_rows], [r["error_pct"] for r in scene_rows], ok)
        for row, on in zip(scene_rows, front):
            row["on_pareto"] = bool(on)
        chain_errors = []
        for item in references:
            e, e_max = field_errors(item["u_points"], u_ref)
            chain_errors.append(dict(resolution=item["resolution"], error_pct=e, error_max_pct=e_max,
                                     method=item["info"]["method"], newton_iterations=item["info"]["iterations"],
                                     wall_s=item["info"]["wall_s"]))
        check = dict(coarser_resolution=chain_errors[-2]["resolution"], error_pct=chain_errors[-2]["error_pct"],
                     error_max_pct=chain_errors[-2]["error_max_pct"]) if len(chain_errors) > 1 else None
        pareto = sorted((r for r in scene_rows if r["on_pareto"]), key=lambda r: r["wall_per_sim_s"])
        cost = cost_to_reach(scene_rows, FLOOR_ERROR_PCT)
        summary["scenes"][name] = dict(
            label=scene.label, translation_m=list(scene.translation), rotation_deg=scene.rotation_deg, glued=scene.glued,
            reference=dict(resolution=reference_resolution, max_displacement_m=float(np.linalg.norm(u_ref, axis=1).max()),
                           **reference_info),
            reference_convergence=check, reference_chain=chain_errors,
            pareto=[dict(configuration=_label(r), wall_per_sim_s=r["wall_per_sim_s"], error_pct=r["error_pct"],
                         error_max_pct=r["error_max_pct"]) for r in pareto],
            counts={s: sum(r["status"] == s for r in scene_rows) for s in sorted({r["status"] for r in scene_rows})},
            cost_to_reach_error=dict(error_pct=FLOOR_ERROR_PCT, by_method=cost),
            floor=floor_verdict(cost),
            wall_s=time.perf_counter() - clock)
        rows.extend(scene_rows)
        if verbose:
            print(f"{name}: reference n={reference_resolution} ({reference_info['method']}, "
                  f"{reference_info['wall_s']:.0f} s); convergence {check}; scene {time.perf_counter() - clock:.0f} s",
                  flush=True)
    summary["total_wall_s"] = time.perf_counter() - start
    return rows, summary


#: issue 27's floor: in the pull scene baudet-hyperelastic reaches this error (%) at a lower cost than
#: fem-neohookean does
FLOOR_ERROR_PCT = 2.0


def cost_to_reach(rows, error_pct=FLOOR_ERROR_PCT) -> dict:
    """Per method: the cheapest successful configuration (wall s per simulated s) whose error is at
    most ``error_pct``, as {method: {configuration, wall_per_sim_s, error_pct}} (None: never)."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        good = [r for r in rows if r["method"] == method and r["status"] == "ok" and np.isfinite(r["error_pct"])
                and r["error_pct"] <= error_pct]
        best = min(good, key=lambda r: r["wall_per_sim_s"], default=None)
        out[method] = None if best is None else dict(configuration=_label(best), wall_per_sim_s=best["wall_per_sim_s"],
                                                     error_pct=best["error_pct"])
    return out


def floor_verdict(cost) -> dict:
    """Whether HYPER reaches FLOOR_ERROR_PCT cheaper than fem-neohookean (``cost_to_reach``'s output)."""
    hyper, neo = cost.get(HYPER), cost.get("fem-neohookean")
    holds = hyper is not None and (neo is None or hyper["wall_per_sim_s"] < neo["wall_per_sim_s"])
    return dict(statement=f"{HYPER} reaches {FLOOR_ERROR_PCT:g}% at a lower cost than fem-neohookean", holds=bool(holds),
                cost_ratio=(hyper["wall_per_sim_s"] / neo["wall_per_sim_s"]) if hyper and neo else None)


def _label(row) -> str:
    parts = [row["method"], row["stepping"]]
    if row["solver"]:
        parts.append(row["solver"])
    if row["stepping"] in ("implicit", "explicit") and row.get("dt_s") is not None and np.isfinite(row["dt_s"]):
        parts.append(f"dt={row['dt_s'] * 1e3:.3g}ms")
    return " ".join(parts) + f" n={row['resolution']}"


# -- output ----------------------------------------------------------------------------------------------
COLUMNS = ("scene", "method", "stepping", "solver", "dt_s", "resolution", "n_nodes", "status", "error_pct",
           "error_max_pct", "wall_per_sim_s", "wall_s", "repeats", "sim_time_s", "steps", "mean_iterations", "setup_s",
           "predicted_wall_s", "on_pareto", "reason")


def _cell(value):
    if value is None:
        return ""
    if isinstance(value, (float, np.floating)):
        return "" if not np.isfinite(value) else f"{float(value):.6g}"
    return value


def write_csv(rows, path: Path):
    """CSV (atomic). First line: a '#' comment with the error and speed definitions."""
    buffer = io.StringIO()
    buffer.write(f"# {ERROR_DEFINITION}; {SPEED_DEFINITION}; status != ok rows have no error and are not on the front\n")
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _cell(row.get(k)) for k in COLUMNS})
    atomic_write(path, buffer.getvalue().encode())


#: CSV columns read back as numbers by ``read_csv`` (the others stay strings)
_INTEGER_COLUMNS = ("resolution", "n_nodes", "repeats", "steps")
_FLOAT_COLUMNS = ("dt_s", "error_pct", "error_max_pct", "wall_per_sim_s", "wall_s", "sim_time_s", "mean_iterations",
                  "setup_s", "predicted_wall_s")


def read_csv(path: Path) -> list[dict]:
    """The rows ``write_csv`` wrote, with its numbers as numbers (an empty cell: NaN, or None for an
    integer) and ``on_pareto`` as a bool."""
    lines = [line for line in Path(path).read_text().splitlines() if not line.startswith("#")]
    rows = []
    for raw in csv.DictReader(lines):
        row = dict(raw)
        for key in _INTEGER_COLUMNS:
            row[key] = int(row[key]) if row[key] else None
        for key in _FLOAT_COLUMNS:
            row[key] = float(row[key]) if row[key] else float("nan")
        row["on_pareto"] = row["on_pareto"] == "True"
        rows.append(row)
    return rows


def write_summary(summary, path: Path):
    """The run's summary as JSON (atomic; numpy scalars as floats)."""
    write_json(path, summary, indent=1, default=lambda v: None if v is None else float(v))


MARKERS = {"explicit": "^", "implicit": "o", "quasi-static": "s"}
METHOD_MARKERS = {"baudet-original": "P", "uniform-springs": "X", HYPER: "h", "fem-linear": "D", "fem-neohookean": "*"}


PEERS = ROOT / "benchmarks" / "results" / "speed_accuracy_peers.json"
PEER_MARKER = "v"


def figure(rows, summary, path: Path, peers: dict | None = None):
    """Two panels, log-log error against wall time per simulated second, Pareto front as a step line.
    ``peers``: benchmarks/speed_accuracy_peers.json's content (MuJoCo flex on the same scenes), drawn
    as points of their own (not on the front: their scene match is the peers' file's)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    scenes = list(summary["scenes"])
    resolutions = summary["resolutions"]
    cmap = plt.get_cmap("viridis")
    colour = {n: cmap(i / max(len(resolutions) - 1, 1)) for i, n in enumerate(resolutions)}

    def point(ax, row, marker, hollow):
        """One run: its marker, sized and coloured by its resolution (hollow: unfilled)."""
        ax.scatter(row["wall_per_sim_s"], max(row["error_pct"], 1e-3), s=18 + 10 * resolutions.index(row["resolution"]),
                   marker=marker, facecolors="none" if hollow else colour[row["resolution"]],
                   edgecolors=colour[row["resolution"]], linewidths=1.0, alpha=0.85, zorder=3)

    fig, axes = plt.subplots(1, len(scenes), figsize=(7.5 * len(scenes), 6.9), squeeze=False)
    for ax, name in zip(axes[0], scenes):
        scene_rows = [r for r in rows if r["scene"] == name]
        for row in scene_rows:
            if row["status"] == "ok":
                hollow = row["method"] in ("baudet", HYPER) and row["stepping"] == "implicit" and row["solver"] != "bicgstab"
                point(ax, row, METHOD_MARKERS.get(row["method"], MARKERS.get(row["stepping"], "o")), hollow)
        for row in (peers or {}).get("rows", []):
            if row["scene"] == name and row["status"] == "ok" and row["resolution"] in colour:
                point(ax, row, PEER_MARKER, row["damping"] == "none")
        ok = [r for r in scene_rows if r["status"] == "ok"]
        front = sorted((r for r in ok if r["on_pareto"]), key=lambda r: r["wall_per_sim_s"])
        if front:
            xs = [r["wall_per_sim_s"] for r in front]
            ys = [max(r["error_pct"], 1e-3) for r in front]
            ax.step(xs + [max(r["wall_per_sim_s"] for r in ok) * 1.5], ys + [ys[-1]], where="post", color="crimson",
                    lw=1.4, zorder=2, label="Pareto front")
            for i, r in enumerate(front):
                ax.annotate(_label(r), (r["wall_per_sim_s"], max(r["error_pct"], 1e-3)), fontsize=6.5, color="crimson",
                            xytext=(6, 4 + 7 * (i % 2)), textcoords="offset points", zorder=4)
        failed = [r for r in scene_rows if r["status"] != "ok"]
        reference = summary["scenes"][name]["reference"]
        check = summary["scenes"][name]["reference_convergence"]
        note = f"reference: fem-neohookean n={reference['resolution']}"
        if check:
            note += f"; n={check['coarser_resolution']} differs by {check['error_pct']:.2f}%"
        counts = {st: sum(r["status"] == st for r in failed) for st in sorted({r["status"] for r in failed})}
        note += "\nnot plotted (in the CSV): " + ", ".join(f"{v} {k}" for k, v in counts.items())
        ax.text(0.01, 0.01, note, transform=ax.transAxes, fontsize=7, va="bottom")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time per simulated second (s/s), median")
        ax.set_ylabel("position error: 100 mean|u - u_ref| / max|u_ref| (%)")
        ax.set_title(summary["scenes"][name]["label"], fontsize=10)
        ax.grid(alpha=0.3, which="both")
    handles = [Line2D([], [], ls="", marker=m, color="grey", label=f"baudet {s}") for s, m in MARKERS.items()]
    handles.append(Line2D([], [], ls="", marker="o", mfc="none", color="grey", label="implicit, 15-iteration cap"))
    handles += [Line2D([], [], ls="", marker=m, color="grey", label=k) for k, m in METHOD_MARKERS.items()]
    if peers:
        handles.append(Line2D([], [], ls="", marker=PEER_MARKER, color="grey",
                              label=f"MuJoCo {peers.get('mujoco_version', '')} flex (hollow: undamped)"))
    handles += [Line2D([], [], ls="", marker="o", color=colour[n], label=f"n = {n}") for n in resolutions]
    handles.append(Line2D([], [], color="crimson", label="Pareto front"))
    fig.legend(handles=handles, fontsize=7, loc="lower center", ncol=8)  # below the panels: no point hidden
    fig.suptitle(f"4 cm cube, E = {YOUNG / 1e3:g} kPa, nu = {POISSON}: final positions after 1 s (tool ramp 0.5 s) "
                 "against static neo-Hookean FEM", fontsize=10)
    finish_figure(fig, path, rect=(0, 0.09, 1, 1), dpi=110)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="n = 2, 4; reference n = 8; fewer implicit settings")
    parser.add_argument("--resolutions", type=int, nargs="+", help="elements per side")
    parser.add_argument("--reference", type=int, help="reference resolution (finer than every resolution)")
    parser.add_argument("--budget", type=float, help=f"wall-time cap per run in s (default {BUDGET:g})")
    parser.add_argument("--out", type=Path, default=ROOT, help="root under which results/ and figures/ are written")
    parser.add_argument("--replot", action="store_true",
                        help="only redraw the figure from the results files under --out (with MuJoCo's points of "
                             "benchmarks/speed_accuracy_peers.py where its results file exists)")
    args = parser.parse_args(argv)
    results = args.out / "benchmarks" / "results"
    peers = json.loads(PEERS.read_text()) if PEERS.exists() else None
    if args.replot:
        summary = json.loads((results / "speed_accuracy.json").read_text())
        rows = read_csv(results / "speed_accuracy.csv")
        figure(rows, summary, args.out / "docs" / "figures" / "speed_accuracy.png", peers)
        return rows, summary
    options = dict(resolutions=RESOLUTIONS, reference_resolution=REFERENCE_RESOLUTION)
    if args.quick:
        options = dict(QUICK)
    if args.resolutions:
        options["resolutions"] = tuple(args.resolutions)
    if args.reference:
        options["reference_resolution"] = args.reference
    if args.budget:
        options["budget"] = args.budget
    rows, summary = benchmark(**options)
    summary["quick"] = bool(args.quick)
    write_csv(rows, results / "speed_accuracy.csv")
    write_summary(summary, results / "speed_accuracy.json")
    figure(rows, summary, args.out / "docs" / "figures" / "speed_accuracy.png", peers)
    for name, scene in summary["scenes"].items():
        print(f"\n{name}: Pareto front")
        for p in scene["pareto"]:
            print(f"  {p['configuration']:52s} {p['wall_per_sim_s']:10.4f} s/s  {p['error_pct']:7.3f}%")
        print(f"  floor ({scene['floor']['statement']}): {scene['floor']['holds']}, cost ratio {scene['floor']['cost_ratio']}; "
              f"cheapest <= {FLOOR_ERROR_PCT:g}%: " + ", ".join(
                  f"{m}: {v['configuration']} {v['wall_per_sim_s']:.3g} s/s" for m, v in
                  scene["cost_to_reach_error"]["by_method"].items() if v))
    print(f"total {summary['total_wall_s']:.0f} s")
    return rows, summary


if __name__ == "__main__":
    main()
