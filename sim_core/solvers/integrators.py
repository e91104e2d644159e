"""Time integration: symplectic (semi-implicit) Euler (``SymplecticEuler``), implicit Euler
(``sim_core.solvers.implicit.ImplicitEuler``), the quasi-static solver by name
(``make_integrator``), the stable explicit time step and ``run``.

Each integrator is one class for one world or N: built on a ``ModelStack`` it steps (N, n, 3)
states; built on a ``Model`` (or bound to one) it steps (n, 3) states, the N = 1 case
(``sim_core.solvers.solver.WorldsSolver``). A diverging run is reported
(``StepReport.unstable_reason``), never left to produce an unexplained NaN. SI units: s, m, m/s, N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import kernels
from ..models.forces import ForceWorkspace, stiffness_data
from ..models.model import Control, Model, State
from ..models.stack import ModelStack
from .implicit import ImplicitEuler
from .solver import WorldsSolver
from .static import QuasiStatic


class SymplecticEuler(WorldsSolver):
    """Semi-implicit (symplectic) Euler: v += dt M^-1 f(x, v); x += dt v, on one world (a
    ``Model``, or None and ``bind`` later) or the N worlds of a ``ModelStack`` (every operation is
    per node, so the stacked step is exactly N single steps).

    Stable for dt below ``stable_time_step(model)`` (about 2 / omega_max, less with damping).

    Args:
        stack: the ``ModelStack``, a ``Model`` (one world) or None.
        threads: the divergence checks' threads (``DivergenceMonitors``); one world runs on one.
    """

    name = "explicit"

    def __init__(self, stack: ModelStack | Model | None = None, threads: int = 1):
        self.threads = int(threads)
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        if self._one_world(stack):
            return
        self._start_worlds(stack, self.threads)
        self._workspace = None  # (stacked model, its ForceWorkspace)

    def _options(self):
        return dict(threads=self.threads)

    def _prepare_shared(self, index, model, positions, dt, fixed):
        if model.damping_law is not None:
            # -beta K v needs the stiffness operator, which this force pass does not form, and its stiff
            # modes would cut the stable step to about 2 / (beta omega_max^2)
            raise ValueError("the explicit integrator does not take a material damping law (Material's "
                             "damping_ratio); use make_solver('implicit', ..., scheme='tr-bdf2')")
        super()._prepare_shared(index, model, positions, dt, fixed)

    def advance(self, positions, velocities, fixed, target, dt, active, force=None):
        model = self.stack.model
        count, n_nodes = positions.shape[:2]
        if self._workspace is None or self._workspace[0] is not model:
            self._workspace = (model, ForceWorkspace(model, implicit=False))
        x0 = np.ascontiguousarray(positions.reshape(-1, 3), dtype=float)
        v0 = np.ascontiguousarray(velocities.reshape(-1, 3), dtype=float)
        forces = self._workspace[1].compute(x0, v0)  # one fused kernel call
        force = (np.zeros_like(x0) if force is None else np.ascontiguousarray(force, dtype=float).reshape(-1, 3))
        new_positions, new_velocities = np.empty_like(x0), np.empty_like(v0)
        kernels.symplectic_update(x0, v0, forces, model.gravity_force, force, model.mass, dt,
                                  np.ascontiguousarray(fixed).reshape(-1, 3), np.ascontiguousarray(target).reshape(-1, 3),
                                  new_positions, new_velocities)
        new_positions = new_positions.reshape(count, n_nodes, 3)
        new_velocities = new_velocities.reshape(count, n_nodes, 3)
        keep = ~active
        new_positions[keep] = positions[keep]
        new_velocities[keep] = velocities[keep]
        return new_positions, new_velocities


INTEGRATORS = {"explicit": SymplecticEuler, "implicit": ImplicitEuler}


def make_integrator(name: str, model: Model | None = None, **options):
    """Integrator by name: "explicit" (symplectic Euler), "implicit" (Baraff-Witkin Euler) or "static"
    (``sim_core.solvers.static.QuasiStatic``: a static equilibrium per step), bound to ``model`` when given
    (its ``step`` verb, ``sim_core.solvers.solver``)."""
    if name == "static":
        solver = QuasiStatic(**options)
    elif name in INTEGRATORS:
        solver = INTEGRATORS[name](**options)
    else:
        raise ValueError(f"integrator must be one of {tuple(INTEGRATORS) + ('static',)}, got {name!r}")
    return solver if model is None else solver.bind(model)


# -- stable time step --------------------------------------------------------------------------
def _damped_limit(omega: float, zeta: float) -> float:
    """Symplectic Euler on x'' + 2 zeta omega x' + omega^2 x = 0 is stable for
    omega dt < 2 (sqrt(1 + zeta^2) - zeta) (Jury criterion on its 2x2 amplification matrix)."""
    return 2.0 * (np.sqrt(1.0 + zeta**2) - zeta) / omega


def stable_time_step(model: Model, control: Control | None = None, *, method: str = "eigen",
                     positions: np.ndarray | None = None, damping: bool = True) -> float:
    """Largest stable symplectic-Euler time step in s (docs/physics.md section 5).

    Args:
        method: "eigen" (Arnoldi on M^-1 K for omega_max, the damping ratio of that mode from its
            Rayleigh quotient) or "gershgorin" (row-sum bounds, cheap and conservative).
        positions: where to linearise (default rest), m.
        damping: account for the spring damping, which lowers the limit.
    Not the report's 2 sqrt(m_max / k_min), which is about 5x too large. Measured against the
    largest stable dt (benchmarks/stability.py): up to 10.8% optimistic, so step at 0.8x or less.
    A 10x10x10 block sagging under its own weight diverged at 0.9x (after 1.9 s) and ran 10 s
    stably at 0.8x; the limit at the loaded state was within 2% of the one at rest.
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
