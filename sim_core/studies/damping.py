"""The released-cantilever study of damping (docs/physics.md section 14): a beam clamped at x = 0,
released from rest in its first mode shape, stepped by the implicit integrator; its modal amplitude
q(t), the damping ratio and natural frequency fitted to it, and the damped oscillator it is compared
with. ``tests/test_damping.py`` and ``benchmarks/damping.py`` use it. SI units: s, m, rad/s."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.optimize import curve_fit

from ..models.forces import stiffness_data
from ..models.model import Model, State
from ..solvers.worlds import make_solver


def clamped_nodes(model: Model) -> np.ndarray:
    """The nodes of the face x = 0 (the clamp), indices."""
    nodes = model.mesh.nodes
    return np.flatnonzero(np.isclose(nodes[:, 0], nodes[:, 0].min()))


def first_mode(model: Model) -> tuple[float, np.ndarray]:
    """(omega rad/s, mode shape (n, 3), its largest y component 1) of the clamped beam's lowest mode:
    the generalised eigenproblem K phi = omega^2 M phi (scipy's shift-invert Lanczos at 0) with K the
    model's stiffness at rest (its symmetric part) and M its lumped masses, on the free dofs."""
    clamp = clamped_nodes(model)
    rest = model.mesh.nodes
    free = np.setdiff1d(np.arange(rest.size), (3 * clamp[:, None] + np.arange(3)).ravel())
    stiffness = model.pattern.matrix(stiffness_data(model, rest)).tocsc()[free][:, free]
    mass = sp.diags(np.repeat(model.mass, 3)[free]).tocsc()
    values, vectors = spla.eigsh(0.5 * (stiffness + stiffness.T), k=1, M=mass, sigma=0.0, which="LM")
    shape = np.zeros(rest.size)
    shape[free] = vectors[:, 0]
    shape = shape.reshape(-1, 3)
    return float(np.sqrt(values[0])), shape / shape[np.argmax(np.abs(shape[:, 1])), 1]


def released(model: Model, shape: np.ndarray, dt: float, duration: float, scheme: str,
             amplitude: float = 0.01, tolerance: float = 1e-10):
    """Release ``model`` clamped at x = 0 from rest at rest positions + ``amplitude`` (m) x ``shape``
    (n, 3) and step it ``duration`` s with ``make_solver("implicit", model, scheme=scheme)``: (times
    (T,) s, modal amplitudes q (T,), 1 at release, q = phi^T M u / (phi^T M phi amplitude))."""
    rest = model.mesh.nodes
    clamp = clamped_nodes(model)
    solver = make_solver("implicit", model, scheme=scheme, tolerance=tolerance)
    control = model.new_control().impose(clamp, rest[clamp])
    state = State(rest + amplitude * shape, np.zeros_like(rest))
    weights = np.repeat(model.mass, 3) * shape.ravel()
    norm = weights @ shape.ravel() * amplitude
    amplitudes = [1.0]
    for _ in range(int(round(duration / dt))):
        out = State(None, None)
        report = solver.step(state, out, control, dt)
        if report.unstable:
            raise RuntimeError(f"the released beam diverged: {report.unstable_reason}")
        state = out
        amplitudes.append(weights @ (state.positions - rest).ravel() / norm)
    return dt * np.arange(len(amplitudes)), np.array(amplitudes)


def decay_fit(times, amplitudes, omega_guess: float) -> tuple[float, float]:
    """(damping ratio, natural frequency rad/s) of the least-squares fit of e^(-s t) (a cos wd t + b
    sin wd t) to ``amplitudes`` at ``times``: zeta = s / sqrt(s^2 + wd^2)."""
    def decay(t, s, wd, a, b):
        return np.exp(-s * t) * (a * np.cos(wd * t) + b * np.sin(wd * t))

    (s, wd, _, _), _ = curve_fit(decay, times, amplitudes, p0=[0.05 * omega_guess, omega_guess, 1.0, 0.0])
    natural = float(np.hypot(s, wd))
    return float(s) / natural, natural


def oscillator(times, zeta: float, omega: float):
    """The damped oscillator q'' + 2 zeta omega q' + omega^2 q = 0 from q = 1, q' = 0 (zeta < 1)."""
    sigma, damped = zeta * omega, omega * np.sqrt(1.0 - zeta**2)
    return np.exp(-sigma * times) * (np.cos(damped * times) + sigma / damped * np.sin(damped * times))
