"""Time integration: symplectic (semi-implicit) Euler, implicit Euler (Baraff and Witkin), the
stable explicit time step, and divergence detection.

Every integrator has one verb, ``simulate(model, state_in, state_out, dt, control) -> StepReport``
(Warp's convention, shared/STYLE.md). A diverging run is reported (``StepReport.unstable_reason``),
never left to produce an unexplained NaN. SI units: s, m, m/s, N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import kernels
from .forces import ForceWorkspace, stiffness_data
from .mesh import CORNER_NEIGHBOURS, CORNER_SIGN
from .model import Control, Model, State


@dataclass
class StepReport:
    """What one ``simulate`` call did: ``iterations`` of the linear solver (0 for explicit),
    its relative ``residual``, and ``unstable_reason`` (None while the run is healthy)."""

    iterations: int = 0
    residual: float = 0.0
    unstable_reason: str | None = None

    @property
    def unstable(self) -> bool:
        return self.unstable_reason is not None


def _check_dt(dt) -> float:
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a finite time step > 0 s, got {dt}")
    return dt


def _impose(control: Control, state_in: State, positions: np.ndarray, velocities: np.ndarray, dt: float):
    """Move imposed components to their targets, with the velocity that gets them there in dt."""
    fixed = control.fixed
    if np.any(fixed):
        velocities[fixed] = (control.target[fixed] - state_in.positions[fixed]) / dt
        positions[fixed] = control.target[fixed]


class DivergenceMonitor:
    """Detects a diverging simulation and says why.

    Checks (cheap ones every step, element inversion every ``inversion_every`` steps):
    non-finite positions or velocities; a node faster than ``speed_factor`` times the fastest
    elastic wave speed sqrt(E / rho) (no tissue motion a tool imposes comes near it); a node
    farther than ``extent_factor`` block sizes from the rest mesh; an inverted element (a corner
    Jacobian <= 0).
    """

    def __init__(self, model: Model, speed_factor: float = 100.0, extent_factor: float = 10.0,
                 inversion_every: int = 10):
        self.model = model
        self.max_speed = speed_factor * float(np.sqrt(np.max(model.young_modulus / model.density)))
        rest = model.rest_positions
        size = float(np.max(rest.max(axis=0) - rest.min(axis=0)))
        self.low = rest.min(axis=0) - extent_factor * size
        self.high = rest.max(axis=0) + extent_factor * size
        self.inversion_every = max(int(inversion_every), 1)
        self.count = 0

    def check(self, state: State, force_inversion_check: bool = False) -> str | None:
        self.count += 1
        positions = np.ascontiguousarray(state.positions, dtype=float)
        velocities = np.ascontiguousarray(state.velocities, dtype=float)
        finite, speed, inside = kernels.health(positions, velocities, self.low, self.high)
        if not finite:
            return "non-finite positions or velocities"
        if speed > self.max_speed:
            return f"node speed {speed:.3g} m/s exceeds {self.max_speed:.3g} m/s (100x the elastic wave speed)"
        if not inside:
            return "a node left the region of 10 block sizes around the rest mesh"
        if force_inversion_check or self.count % self.inversion_every == 0:
            if kernels.any_inverted(positions, self.model.mesh.elements, CORNER_NEIGHBOURS, CORNER_SIGN):
                return "inverted element (non-positive corner Jacobian)"
        return None


class SymplecticEuler:
    """Semi-implicit (symplectic) Euler: v += dt M^-1 f(x, v); x += dt v.

    Stable for dt below ``stable_time_step(model)`` (about 2 / omega_max, less with damping).
    """

    name = "explicit"

    def __init__(self, monitor: bool = True):
        self.monitor = monitor
        self._monitors: dict[int, DivergenceMonitor] = {}
        self._workspaces: dict[int, ForceWorkspace] = {}

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float, control: Control | None = None) -> StepReport:
        dt = _check_dt(dt)
        control = model.new_control() if control is None else control
        x0 = np.ascontiguousarray(state_in.positions, dtype=float)
        v0 = np.ascontiguousarray(state_in.velocities, dtype=float)
        forces = self._workspace(model, implicit=False).compute(x0, v0)  # one fused kernel call
        positions, velocities = np.empty_like(x0), np.empty_like(v0)
        kernels.symplectic_update(x0, v0, forces, model.gravity_force, control.force, model.mass, dt, control.fixed,
                                  control.target, positions, velocities)
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return StepReport(unstable_reason=self._check(model, state_out))

    def _workspace(self, model, implicit):
        """The preallocated arrays of the fused kernels for this model (kept between steps)."""
        workspace = self._workspaces.get(id(model))
        if workspace is None or workspace.model is not model:
            workspace = self._workspaces[id(model)] = ForceWorkspace(model, implicit=implicit)
        return workspace

    def _check(self, model, state):
        if not self.monitor:
            return None
        monitor = self._monitors.get(id(model))
        if monitor is None or monitor.model is not model:
            monitor = self._monitors[id(model)] = DivergenceMonitor(model)
        return monitor.check(state)


class ImplicitEuler(SymplecticEuler):
    """Linearised implicit Euler (Baraff and Witkin 1998), one linear solve per step:

        (M + dt D + dt^2 K) dv = dt (f(x0, v0) - dt K v0),   v1 = v0 + dv,   x1 = x0 + dt v1.

    K holds the springs (geometric term clamped at zero so the matrix is SPD) and the corrections'
    push along the current edges. The corrections' strain coupling is not symmetric (physics.md 3):
    ``corrections="explicit"`` leaves it in f only and solves with Jacobi-preconditioned conjugate
    gradient; ``corrections="implicit"`` adds it, and the volume forces' rank-one stiffness
    (matrix-free), to the system and solves with BiCGSTAB. Measured
    (tests/test_integrators.py): at 10x the explicit limit with nu = 0.45 the explicit-correction
    variant diverges while the implicit one stays bounded at a similar iteration count, so
    "implicit" is the default (with "explicit", volume forces stay explicit too). The matrix keeps
    the model's fixed sparsity pattern; only values change.

    Args:
        corrections: "implicit" (default, BiCGSTAB) or "explicit" (CG on the SPD part).
        tolerance: relative residual of the linear solve.
        max_iterations: cap on solver iterations (the report used 15).
    """

    name = "implicit"

    def __init__(self, corrections: str = "implicit", tolerance: float = 1e-6, max_iterations: int = 200,
                 monitor: bool = True):
        if corrections not in ("explicit", "implicit"):
            raise ValueError(f"corrections must be 'explicit' or 'implicit', got {corrections!r}")
        if not tolerance > 0:
            raise ValueError(f"tolerance must be > 0, got {tolerance}")
        if int(max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
        super().__init__(monitor=monitor)
        self.corrections = corrections
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self._warm: np.ndarray | None = None

    def simulate(self, model: Model, state_in: State, state_out: State, dt: float, control: Control | None = None) -> StepReport:
        dt = _check_dt(dt)
        control = model.new_control() if control is None else control
        x0 = np.ascontiguousarray(state_in.positions, dtype=float)
        v0 = np.ascontiguousarray(state_in.velocities, dtype=float)
        coupled = self.corrections == "implicit" and model.correction_mode is not None
        # Volume forces' rank-one stiffness, with the other non-symmetric terms (BiCGSTAB only).
        implicit_volume = self.corrections == "implicit" and model.has_volume_forces
        workspace = self._workspace(model, implicit=True)
        # one fused pass: forces, the springs' clamped geometric stiffness, the volume terms
        forces = workspace.compute(x0, v0, geometric=True, volume_jacobian=implicit_volume)
        forces += model.gravity_force + control.force
        has_hourglass = model.hourglass is not None
        data = workspace.operator_data
        n = x0.size

        def scales(mass, damping, stiffness):  # (mass, damping, stiffness, coupling, volume, hourglass)
            return (float(mass), float(damping), float(stiffness), stiffness if coupled else 0.0,
                    stiffness if implicit_volume else 0.0, stiffness if has_hourglass else 0.0)

        ones = np.ones(n)
        product = np.empty(n)
        kernels.apply_operator(data, scales(0.0, 0.0, 1.0), ones, v0.reshape(-1), product)  # K v0
        rhs = dt * (forces.reshape(-1) - dt * product)
        system = scales(1.0, dt, dt * dt)  # M + dt D + dt^2 K
        free = ~control.fixed.ravel()
        known = np.zeros(n)
        if not free.all():
            target_velocity = (control.target - x0) / dt
            known[~free] = (target_velocity - v0).ravel()[~free]
            kernels.apply_operator(data, system, ones, known, product)
            rhs -= product
        mask = free.astype(float)
        guess = self._warm if self._warm is not None and self._warm.shape == rhs.shape else np.zeros_like(rhs)
        dv = np.empty(n)
        iterations, residual = kernels.solve_springs(
            data, system, mask, rhs * mask, guess, self.tolerance, self.max_iterations,
            not (coupled or implicit_volume), workspace.work, dv)
        self._warm = dv
        dv = np.where(free, dv, known)
        velocities = v0 + dv.reshape(-1, 3)
        positions = x0 + dt * velocities
        _impose(control, state_in, positions, velocities, dt)
        state_out.positions, state_out.velocities, state_out.time = positions, velocities, state_in.time + dt
        return StepReport(int(iterations), float(residual), self._check(model, state_out))


INTEGRATORS = {"explicit": SymplecticEuler, "implicit": ImplicitEuler}


def make_integrator(name: str, **options):
    """Integrator by name: "explicit" (symplectic Euler) or "implicit" (Baraff-Witkin Euler)."""
    if name not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {tuple(INTEGRATORS)}, got {name!r}")
    return INTEGRATORS[name](**options)


# -- stable time step --------------------------------------------------------------------------
def _damped_limit(omega: float, zeta: float) -> float:
    """Symplectic Euler on x'' + 2 zeta omega x' + omega^2 x = 0 is stable for
    omega dt < 2 (sqrt(1 + zeta^2) - zeta) (Jury criterion on its 2x2 amplification matrix)."""
    return 2.0 * (np.sqrt(1.0 + zeta**2) - zeta) / omega


def stable_time_step(model: Model, control: Control | None = None, *, method: str = "eigen",
                     positions: np.ndarray | None = None, damping: bool = True) -> float:
    """Largest stable symplectic-Euler time step in s (physics.md section 5).

    Args:
        method: "eigen" (Arnoldi on M^-1 K for omega_max, the damping ratio of that mode from its
            Rayleigh quotient) or "gershgorin" (row-sum bounds, cheap and conservative).
        positions: where to linearise (default rest), m.
        damping: account for the spring damping, which lowers the limit.
    Not the report's 2 sqrt(m_max / k_min), which is about 5x too large.
    """
    control = model.new_control() if control is None else control
    positions = model.rest_positions if positions is None else positions
    free = np.flatnonzero(~control.fixed.ravel())
    stiffness = model.pattern.matrix(stiffness_data(model, positions)).tocsr()[free][:, free]
    damping_matrix = model.pattern.matrix(stiffness_data(model, positions, stiffness_scale=0.0, damping_scale=1.0,
                                                         corrections="none", volume=False)).tocsr()[free][:, free]
    inverse_mass = 1.0 / np.repeat(model.mass, 3)[free]
    if method == "gershgorin":
        omega = np.sqrt(np.max(inverse_mass * np.asarray(abs(stiffness).sum(axis=1)).ravel()))
        zeta = np.max(inverse_mass * np.asarray(abs(damping_matrix).sum(axis=1)).ravel()) / (2 * omega) if damping else 0.0
        return float(_damped_limit(omega, zeta))
    if method != "eigen":
        raise ValueError(f"method must be 'eigen' or 'gershgorin', got {method!r}")
    operator = sp.diags(inverse_mass) @ stiffness
    # The most restrictive mode is not always the stiffest one when damping ratios differ, so take
    # the smallest damped limit over the highest few modes.
    n_modes = min(8, len(free) - 2)
    values, vectors = spla.eigs(operator, k=n_modes, which="LM", tol=1e-6)
    limits = []
    for value, vector in zip(values, vectors.T):
        omega = float(np.sqrt(abs(value.real)))
        mode = vector.real if np.linalg.norm(vector.real) >= np.linalg.norm(vector.imag) else vector.imag
        mass_norm = mode @ (mode / inverse_mass)
        zeta = float(mode @ (damping_matrix @ mode) / (2.0 * omega * mass_norm)) if damping else 0.0
        limits.append(_damped_limit(omega, max(zeta, 0.0)))
    return float(min(limits))


@dataclass
class RunReport:
    """Outcome of ``run``: steps done, whether the run became unstable, at which step and why."""

    steps: int
    unstable: bool
    unstable_reason: str | None
    unstable_step: int | None
    iterations: list


def run(model: Model, state: State, integrator, dt: float, steps: int, control: Control | None = None) -> RunReport:
    """Advance ``state`` in place by ``steps`` steps of ``dt`` s; stops at the first instability."""
    iterations = []
    scratch = state.copy()
    for step in range(1, int(steps) + 1):
        report = integrator.simulate(model, state, scratch, dt, control)
        iterations.append(report.iterations)
        state.positions, state.velocities, state.time = scratch.positions, scratch.velocities, scratch.time
        if report.unstable:
            return RunReport(step, True, report.unstable_reason, step, iterations)
    return RunReport(int(steps), False, None, None, iterations)
