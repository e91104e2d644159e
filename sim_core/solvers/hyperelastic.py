"""Compressible neo-Hookean finite elements: the large-deformation reference ("fem-neohookean").

Total-Lagrangian formulation on the same elements as ``fem.LinearFEM`` (trilinear hexahedra at
2x2x2 Gauss points, or linear tetrahedra at their one exact point; derivatives taken in the rest
configuration), with the strain-energy density
(Bonet & Wood, *Nonlinear Continuum Mechanics for Finite Element Analysis*, 2nd ed., eq. 6.28)

    W(F) = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2,    I1 = tr(F^T F),  J = det F,

whose first Piola-Kirchhoff stress and material tangent are

    P = mu (F - F^-T) + lambda ln J F^-T,
    dP_aB/dF_cD = mu d_ac d_BD + (mu - lambda ln J) F^-1_Bc F^-1_Da + lambda F^-1_Ba F^-1_Dc.

mu = G = E / (2 (1 + nu)) and lambda = E nu / ((1 + nu)(1 - 2 nu)) (docs/physics.md notation), so the
law reduces to linear isotropic elasticity with the same E and nu at small strain. Everything is
vectorised over elements and Gauss points (einsum); the tangent is assembled into the fixed CSR
pattern of ``sparse.BlockPattern`` and the equilibrium is found by Newton's method with a
backtracking line search and adaptive load stepping. SI units: m, Pa, N, kg/m^3, m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from ..models.laws import first_piola_stress, lame_parameters, material_tangent, strain_energy_density  # noqa: F401
from ..models.material import Material
from ..models.elements import element_block_positions, element_blocks, quadrature
from ..geometry.mesh import HexMesh
from ..models.model import Control
from ..models.sparse import BlockPattern
from .static import ramp_load
from ..geometry.tetmesh import TetMesh


# -- the finite-element model ------------------------------------------------------------------
@dataclass
class NeoHookeanResult:
    """Outcome of ``NeoHookeanFEM.solve``.

    Attributes:
        positions: (N, 3) equilibrium positions, m.
        reaction: (N, 3) forces (N) the imposed components exert on the nodes (0 where free),
            the same convention as ``fem.LinearFEM.solve`` and ``static.solve_static``.
        converged: relative force residual below the tolerance at the full load.
        residual: ||free-dof force residual|| / max(||internal forces||, ||applied loads||).
        iterations: total Newton iterations.  load_steps: accepted load increments.
        message: why it stopped.
    """

    positions: np.ndarray
    reaction: np.ndarray
    converged: bool
    residual: float
    iterations: int
    load_steps: int
    message: str = ""


class NeoHookeanFEM:
    """Total-Lagrangian neo-Hookean FEM of a hexahedral or tetrahedral mesh (module docstring for the law).

    Args:
        mesh: ``HexMesh`` of trilinear hexahedra or ``TetMesh`` of linear tetrahedra (rest positions in m).
        material: ``Material`` (E in Pa, nu, rho in kg/m^3; scalars or one value per element).

    Lumped masses are rho V / n per element node (n = 8 or 4; docs/physics.md section 5), so gravity
    on them equals the consistent body load of the elements.
    """

    def __init__(self, mesh: HexMesh | TetMesh, material: Material):
        self.mesh = mesh
        self.material = material
        props = material.per_element(mesh.n_elements)
        self.mu, self.lam = lame_parameters(props["young_modulus"], props["poisson_ratio"])
        elements = mesh.elements
        #: (M, P, n, 3) shape-function gradients dN/dX at the integration points, 1/m, and
        #: (M, P) their weights times the rest Jacobian determinant: the rest volume per point, m^3.
        self.gradients, self.weights = quadrature(mesh.nodes, elements)
        self.pattern = BlockPattern(mesh.n_nodes, elements)
        self._element_positions = element_block_positions(self.pattern, elements)
        volume = self.weights.sum(axis=1)
        n = elements.shape[1]
        self.mass = np.bincount(elements.ravel(), weights=np.repeat(props["density"] * volume / n, n),
                                minlength=mesh.n_nodes)

    # -- kinematics and element quantities -----------------------------------------------------
    def deformation_gradients(self, positions: np.ndarray) -> np.ndarray:
        """(M, P, 3, 3) F = dx/dX at the Gauss points: F_aB = sum_n x_na dN_n/dX_B."""
        corners = np.asarray(positions, float)[self.mesh.elements]
        return np.einsum("mna,mpnb->mpab", corners, self.gradients, optimize=True)

    def _point_parameters(self):
        return self.mu[:, None], self.lam[:, None]

    def energy(self, positions: np.ndarray) -> float:
        """Total strain energy sum_e sum_p w W(F) in J (+inf if an element is inverted)."""
        mu, lam = self._point_parameters()
        return float(np.sum(self.weights * strain_energy_density(self.deformation_gradients(positions), mu, lam)))

    def internal_forces(self, positions: np.ndarray) -> np.ndarray:
        """(N, 3) dE/dx in N: f_na = sum_e sum_p w P_aB dN_n/dX_B (minus the force on the nodes)."""
        mu, lam = self._point_parameters()
        stress = first_piola_stress(self.deformation_gradients(positions), mu, lam)
        element = np.einsum("mp,mpab,mpnb->mna", self.weights, stress, self.gradients, optimize=True)
        forces = np.zeros((self.mesh.n_nodes, 3))
        np.add.at(forces, self.mesh.elements, element)
        return forces

    def element_tangents(self, positions: np.ndarray) -> np.ndarray:
        """(M, 3n, 3n) consistent tangents d(f_e)/d(x_e) in N/m (node-major dofs, n nodes per element)."""
        # K[m, (n a), (k c)] = sum_p w_mp sum_BD G[m,p,n,B] A[m,p,a,B,c,D] G[m,p,k,D], contracted
        # by two batched matmuls (BLAS: much faster than the equivalent einsum on large meshes).
        mu, lam = self._point_parameters()
        tangent = material_tangent(self.deformation_gradients(positions), mu, lam)  # (M, P, 3,3,3,3)
        tangent = tangent * self.weights[..., None, None, None, None]
        m, p = self.weights.shape
        gradients = self.gradients  # (M, P, n, 3): dN_n / dX_B
        n = gradients.shape[2]
        t = np.matmul(gradients, tangent.transpose(0, 1, 3, 2, 4, 5).reshape(m, p, 3, 27))  # (m, p, n, (a c D))
        t = t.reshape(m, p, n, 3, 3, 3).transpose(0, 2, 3, 4, 1, 5).reshape(m, 9 * n, 3 * p)  # (n a c), (p D)
        k = np.matmul(t, gradients.transpose(0, 1, 3, 2).reshape(m, 3 * p, n))  # (m, (n a c), k)
        return k.reshape(m, n, 3, 3, n).transpose(0, 1, 2, 4, 3).reshape(m, 3 * n, 3 * n)

    def tangent_stiffness(self, positions: np.ndarray):
        """(3N, 3N) CSR consistent tangent K = d(internal_forces)/dx in N/m (symmetric)."""
        blocks = element_blocks(self.element_tangents(positions), self.mesh.elements.shape[1])
        return self.pattern.matrix(self.pattern.assemble(self._element_positions, blocks))

    def min_jacobian(self, positions: np.ndarray) -> float:
        """Smallest det F over all Gauss points (must stay > 0)."""
        return float(np.linalg.det(self.deformation_gradients(positions)).min())

    # -- static equilibrium ----------------------------------------------------------------------
    def solve(self, control: Control, gravity=(0.0, 0.0, 0.0), *, tolerance: float = 1e-8,
              max_iterations: int = 25, load_steps: int = 1, max_load_steps: int = 1024,
              initial: np.ndarray | None = None) -> NeoHookeanResult:
        """Static equilibrium under imposed components, nodal forces and gravity.

        Loads and imposed displacements are ramped together from ``initial`` (default: rest) in
        load increments; an increment starts with a Newton step that carries the imposed
        displacement increment into the free nodes through the tangent (so the boundary layer of
        elements is not distorted), then iterates Newton with a backtracking line search on the
        residual norm that also rejects any step making det F <= 0 at a Gauss point. A failed
        increment is halved (up to ``max_load_steps`` increments in total); a quick one doubles
        the next.

        Args:
            control: ``fixed`` (N, 3) bool, ``target`` (N, 3) m imposed positions, ``force``
                (N, 3) N nodal forces.
            gravity: (3,) acceleration in m/s^2 acting on the lumped masses rho V / n.
            tolerance: relative force residual to reach (see ``NeoHookeanResult.residual``).
            max_iterations: Newton iterations per increment before it is halved.
            load_steps: initial number of increments.
            max_load_steps: give up (converged=False) when an increment would be smaller than
                1 / max_load_steps of the full load.
            initial: (N, 3) starting positions in m (default rest).
        Returns:
            ``NeoHookeanResult``.
        """
        nodes = self.mesh.nodes
        start = nodes.copy() if initial is None else np.array(initial, dtype=float)
        if start.shape != nodes.shape or not np.all(np.isfinite(start)):
            raise ValueError(f"initial must be a finite ({len(nodes)}, 3) array")
        if self.min_jacobian(start) <= 0:
            raise ValueError("initial positions invert an element (det F <= 0)")
        load = control.force + self.mass[:, None] * np.asarray(gravity, float)[None, :]
        fixed = control.fixed.ravel()
        free = np.flatnonzero(~fixed)
        imposed = np.flatnonzero(fixed)
        target = control.target.ravel()
        state = {"positions": start.ravel().copy()}

        def advance(level):
            positions = state["positions"]
            boundary = start.ravel()[imposed] + level * (target[imposed] - start.ravel()[imposed])
            ok, trial, residual, used = self._increment(positions, boundary, free, imposed, level * load.ravel(),
                                                        tolerance, max_iterations)
            if ok:
                state["positions"] = trial
            return ok, residual, used

        converged, iterations, increments, residual, message = ramp_load(advance, load_steps, max_load_steps,
                                                                         fast_iterations=4)
        positions = state["positions"]
        internal = self.internal_forces(positions.reshape(-1, 3)).ravel()
        if converged:
            residual = _relative(internal, load.ravel(), free)
            message = "converged"
        reaction = np.where(fixed, internal - load.ravel(), 0.0).reshape(-1, 3)
        return NeoHookeanResult(positions.reshape(-1, 3), reaction, converged, float(residual), iterations,
                                increments, message)

    def _increment(self, positions, boundary, free, imposed, load, tolerance, max_iterations):
        """Newton on one load level. Returns (ok, positions, residual, iterations)."""
        x = positions.copy()
        boundary_step = np.zeros_like(x)
        boundary_step[imposed] = boundary - x[imposed]
        internal = self.internal_forces(x.reshape(-1, 3)).ravel()
        for iteration in range(1, max_iterations + 1):
            out_of_balance = internal - load
            residual = _relative(internal, load, free)
            if residual < tolerance and not boundary_step.any():
                return True, x, residual, iteration - 1
            stiffness = self.tangent_stiffness(x.reshape(-1, 3)).tocsr()
            rhs = -out_of_balance[free]
            if boundary_step.any():
                rhs = rhs - stiffness[free][:, imposed] @ boundary_step[imposed]
            try:
                solution = spla.splu(stiffness[free][:, free].tocsc()).solve(rhs)
            except RuntimeError:  # singular tangent (e.g. a buckling point): smaller increment
                return False, positions, residual, iteration
            direction = boundary_step.copy()
            direction[free] = solution
            norm = np.linalg.norm(out_of_balance[free])
            scale, accepted = 1.0, False
            for _ in range(20):
                trial = x + scale * direction
                if self.min_jacobian(trial.reshape(-1, 3)) > 0:
                    trial_internal = self.internal_forces(trial.reshape(-1, 3)).ravel()
                    trial_norm = np.linalg.norm((trial_internal - load)[free])
                    # the first step also moves the boundary: accept it whole if elements stay valid
                    if boundary_step.any() and scale == 1.0:
                        accepted = np.all(np.isfinite(trial_internal))
                    else:
                        accepted = trial_norm <= (1.0 - 1e-4 * scale) * norm or trial_norm == 0
                    if accepted:
                        break
                if boundary_step.any():
                    return False, positions, residual, iteration  # boundary increment too large
                scale *= 0.5
            if not accepted:
                return False, positions, residual, iteration
            x, internal = trial, trial_internal
            boundary_step[:] = 0.0
        residual = _relative(internal, load, free)
        return residual < tolerance, x, residual, max_iterations


def _relative(internal, load, free):
    scale = max(np.linalg.norm(internal), np.linalg.norm(load), 1e-300)
    return float(np.linalg.norm((internal - load)[free]) / scale)
