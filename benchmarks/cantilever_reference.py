"""A locking-free, converged reference for the linear-elastic cantilever, computed with scikit-fem.

    nice -n 10 python -m benchmarks.cantilever_reference      # from the repository root: ~3 min on
                                                               # 2 shared cores, ~2 GB of memory

The problem (SI units throughout):

- a beam of length ``LENGTH`` = 1 m along x and square cross-section ``WIDTH`` x ``WIDTH`` =
  0.2 m x 0.2 m (y and z in [-0.1, 0.1] m), clamped at x = 0 (all three displacement components are
  zero on that face);
- a total tip load of ``LOAD`` = 10 N in -y, applied as the uniform traction (0, -10 / 0.04, 0) =
  (0, -250, 0) Pa on the x = 1 m face. The traction is integrated on each finite-element space, i.e.
  it enters as the consistent nodal forces of that uniform traction (the two are the same thing);
- small-strain isotropic linear elasticity, Young's modulus E (default 1e4 Pa; the deflection
  scales as 1/E and the frequency as sqrt(E)), Poisson's ratio nu in {0.3, 0.45, 0.49, 0.499}, no
  gravity; for the eigenfrequencies a density of 1000 kg/m^3.

Discretisation: an inf-sup stable mixed displacement-pressure (u-p) formulation, Taylor-Hood
tetrahedra: P2 (quadratic, continuous) displacement and P1 (linear, continuous) pressure, with the
stress split as sigma = 2 mu dev(eps(u)) - p I and the pressure equation p / K + div u = 0
(K = E / (3 (1 - 2 nu)) the bulk modulus, mu = E / (2 (1 + nu)) the shear modulus). Find (u, p) with

    int 2 mu dev(eps(u)) : dev(eps(v)) - p div v  dV = int_tip t . v dA      for all v,
    int -(div u + p / K) q  dV = 0                                          for all q,

the symmetric saddle-point system [[A, B^T], [B, -M_p / K]]. It stays well posed, with an error
bound independent of K, for every nu < 0.5 (and at nu = 0.5): it does not lock. Eliminating p gives
back the displacement form 2 mu eps : eps + lambda (div u)^2, so at moderate nu it agrees with a
pure-displacement solution (``formulation="p2"``; ``"p1"`` is the linear tetrahedron, which locks).

Meshes and symmetry: the beam's nx x ny x nz cubes (edge 1 / nx m = 0.2 / ny m; ny, nz even), each
split into 6 tetrahedra around its main diagonal (``skfem.MeshTet.init_tensor``) in the quarter
y, z >= 0 and mirrored into the other three quarters, so the tetrahedral mesh has the square
section's symmetries. The continuum problem and this mesh are symmetric about z = 0 and
antisymmetric about y = 0 (the load is in y), so ``model="quarter"`` (the default) solves the
quarter y, z in [0, 0.1] m with u_z = 0 on z = 0 and u_x = u_z = p = 0 on y = 0: the same discrete
solution as ``model="full"`` on the mirrored mesh (tests/test_cantilever_reference.py checks it), at
a quarter of the unknowns. The quarter's eigenmodes are those of that symmetry class: its first is
the first bending mode in y (the full mesh's z mode is its exact twin).

Convergence: Richardson extrapolation of the three finest meshes (``MESHES``: 10x2x2, 20x4x4,
40x8x8 and 60x12x12 cubes; the last three are used, refinement ratios 2 and 1.5): the observed order
p solves (f2 - f1) / (f3 - f2) = (h1^p - h2^p) / (h2^p - h3^p), the extrapolated value is
f3 + (f3 - f2) / ((h2 / h3)^p - 1), and Roache's grid convergence index
GCI = 1.25 |f3 - f2| / |f3| / ((h2 / h3)^p - 1) bounds the finest mesh's relative error. The three
coarser meshes give a second observed order, as a check. The observed order (~1.3 to 1.7) falls with
refinement towards ~1, the limit the clamped edges' stress singularities set, so the extrapolation is
repeated with order 1 and the spread is reported as the converged value's uncertainty.

Outputs (``benchmarks/results/cantilever_reference.json``, written atomically), per nu and mesh:

- ``tip_mean_uy``: the mean y-displacement of the tip face, (1 / A) int_tip u_y dA [m];
- ``tip_centre_uy``: u_y at the centre of the tip face, (1, 0, 0) m [m];
- ``bending_frequency``: the first bending eigenfrequency [Hz], f = omega / (2 pi), of
  K u = omega^2 M u on the mixed system: the pressure block has no mass, and the shift-invert
  solves of ``eigsh`` eliminate it (the Schur complement's eigenproblem);
- Timoshenko beam theory (:func:`timoshenko_tip_deflection`, :func:`timoshenko_frequency`) and the
  ratios reference / Timoshenko.

Only numpy, scipy, scikit-fem (a dev dependency of tissue-gym) and the standard library are imported:
this is an independent reference for sim_core, which it does not use.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import expm
from scipy.optimize import brentq

import skfem
from skfem import Basis, BilinearForm, ElementTetP1, ElementTetP2, ElementVector, FacetBasis, LinearForm, MeshTet
from skfem.helpers import ddot, div, dot, sym_grad

LENGTH = 1.0  # m, along x
WIDTH = 0.2  # m, the side of the square cross-section (y and z)
LOAD = 10.0  # N, the total tip load, in -y
YOUNG = 1e4  # Pa
DENSITY = 1000.0  # kg/m^3
POISSON = (0.3, 0.45, 0.49, 0.499)
MESHES = ((10, 2, 2), (20, 4, 4), (40, 8, 8), (60, 12, 12))  # cubes of 0.1, 0.05, 0.025, 0.0167 m
FORMULATIONS = ("mixed", "p2", "p1")  # Taylor-Hood u-p; pure-displacement P2; pure-displacement P1
MODELS = ("quarter", "full")
COMMAND = "python -m benchmarks.cantilever_reference"
RESULTS = Path(__file__).resolve().parent / "results" / "cantilever_reference.json"
STIFFNESS_ORDER = 2  # quadrature degree: exact for the stiffness, coupling and pressure-mass integrands
MASS_ORDER = 4  # exact for the P2 x P2 mass
RESIDUAL_TOLERANCE = 1e-8  # relative residual above which a solve is refactored with pivoting


def elastic_moduli(young: float, poisson: float) -> dict:
    """Shear modulus ``mu``, Lame's ``lam`` and the bulk modulus ``bulk`` (all Pa) of E (Pa) and nu."""
    return dict(mu=young / (2.0 * (1.0 + poisson)),
                lam=young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson)),
                bulk=young / (3.0 * (1.0 - 2.0 * poisson)))


def beam_mesh(cells: tuple[int, int, int], model: str = "quarter") -> MeshTet:
    """The tetrahedral mesh of the beam's ``cells`` = (nx, ny, nz) cubes (ny and nz even).

    ``quarter``: [0, LENGTH] x [0, WIDTH/2] x [0, WIDTH/2] m, nx x ny/2 x nz/2 cubes, 6 tets each;
    ``full``: that quarter mirrored about y = 0 and z = 0, [0, LENGTH] x [-WIDTH/2, WIDTH/2]^2 m.
    Named boundaries: ``clamp`` (x = 0), ``tip`` (x = LENGTH) and, on the quarter, ``symmetry_y``
    (y = 0) and ``symmetry_z`` (z = 0).
    """
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    nx, ny, nz = cells
    if ny % 2 or nz % 2:
        raise ValueError(f"ny and nz must be even (the mesh is mirrored about y = 0 and z = 0), got {cells}")
    half = WIDTH / 2.0
    mesh = MeshTet.init_tensor(np.linspace(0.0, LENGTH, nx + 1), np.linspace(0.0, half, ny // 2 + 1),
                               np.linspace(0.0, half, nz // 2 + 1))
    boundaries = {"clamp": lambda x: np.isclose(x[0], 0.0), "tip": lambda x: np.isclose(x[0], LENGTH)}
    if model == "full":
        mesh = mesh + mesh.mirrored((0.0, 1.0, 0.0))
        mesh = mesh + mesh.mirrored((0.0, 0.0, 1.0))
    else:
        boundaries.update(symmetry_y=lambda x: np.isclose(x[1], 0.0), symmetry_z=lambda x: np.isclose(x[2], 0.0))
    return mesh.with_boundaries(boundaries)


@dataclass
class System:
    """An assembled cantilever: the stiffness (saddle-point for ``mixed``), the displacement mass,
    the load, the constraints and the operators that read the tip out of a displacement vector."""

    formulation: str
    model: str
    cells: tuple
    stiffness: sp.csr_matrix  # (n, n), N/m: displacement dofs first, then (mixed) the pressure dofs
    mass: sp.csr_matrix | None  # (n_u, n_u), kg: the displacement mass (None without a density)
    load: np.ndarray  # (n,), N
    n_u: int  # the number of displacement dofs
    free: np.ndarray  # the unconstrained dofs
    tip_mean: sp.csr_matrix  # (3, n_u): displacement vector -> the tip face's mean displacement, m
    tip_centre: np.ndarray  # (3,): the displacement dofs of the vertex at the tip face's centre


def assemble(cells, young: float = YOUNG, poisson: float = 0.3, formulation: str = "mixed",
             model: str = "quarter", density: float | None = None) -> System:
    """Assemble the cantilever of ``cells`` cubes for E (Pa), nu and, if given, density (kg/m^3).

    ``formulation``: ``mixed`` (Taylor-Hood P2-P1, p / K + div u = 0), ``p2`` or ``p1``
    (pure-displacement quadratic or linear tetrahedra, 2 mu eps : eps + lambda (div u)^2).
    ``model``: ``quarter`` (symmetry conditions on y = 0 and z = 0) or ``full``, see :func:`beam_mesh`.
    """
    if formulation not in FORMULATIONS:
        raise ValueError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    moduli = elastic_moduli(young, poisson)
    mu, lam, bulk = moduli["mu"], moduli["lam"], moduli["bulk"]
    mesh = beam_mesh(cells, model)
    element = ElementVector(ElementTetP1() if formulation == "p1" else ElementTetP2())
    ubasis = Basis(mesh, element, intorder=STIFFNESS_ORDER)

    if formulation == "mixed":
        @BilinearForm
        def deviatoric(u, v, w):  # 2 mu dev(eps(u)) : dev(eps(v))
            return 2.0 * mu * (ddot(sym_grad(u), sym_grad(v)) - div(u) * div(v) / 3.0)

        @BilinearForm
        def coupling(u, q, w):  # -div(u) q
            return -div(u) * q

        @BilinearForm
        def compliance(p, q, w):  # p q / K
            return p * q / bulk

        pbasis = ubasis.with_element(ElementTetP1())
        coupling_matrix = coupling.assemble(ubasis, pbasis)  # (n_p, n_u)
        stiffness = sp.bmat([[deviatoric.assemble(ubasis), coupling_matrix.T],
                             [coupling_matrix, -compliance.assemble(pbasis)]], format="csr")
    else:
        @BilinearForm
        def elastic(u, v, w):
            return 2.0 * mu * ddot(sym_grad(u), sym_grad(v)) + lam * div(u) * div(v)

        stiffness = elastic.assemble(ubasis).tocsr()
    n_u = ubasis.N

    fraction = 0.25 if model == "quarter" else 1.0  # of the tip face's area and of the load
    area = fraction * WIDTH * WIDTH
    fbasis = FacetBasis(mesh, element, facets=mesh.boundaries["tip"], intorder=STIFFNESS_ORDER)
    rows = []
    for component in range(3):
        @LinearForm
        def mean(v, w, component=component):
            value = v if isinstance(v, np.ndarray) else v.value  # scikit-fem >= 10 fields are arrays
            return value[component] / area

        rows.append(mean.assemble(fbasis))
    tip_mean = sp.csr_matrix(np.array(rows))
    load = np.zeros(stiffness.shape[0])
    # the traction (0, -LOAD / (WIDTH^2), 0) Pa on the tip face: int t . v dA = -LOAD * fraction * mean v_y
    load[:n_u] = -LOAD * fraction * tip_mean[1].toarray().ravel()

    constrained = [ubasis.get_dofs("clamp").all()]
    if model == "quarter":
        constrained += [ubasis.get_dofs("symmetry_y").all(["u^1", "u^3"]), ubasis.get_dofs("symmetry_z").all(["u^3"])]
        if formulation == "mixed":  # the pressure is odd in y
            constrained.append(n_u + pbasis.get_dofs("symmetry_y").all())
    free = np.setdiff1d(np.arange(stiffness.shape[0]), np.concatenate(constrained))

    mass = None
    if density is not None:
        @BilinearForm
        def inertia(u, v, w):
            return density * dot(u, v)

        mass = inertia.assemble(Basis(mesh, element, intorder=MASS_ORDER)).tocsr()

    centre = np.flatnonzero(np.all(np.isclose(mesh.p, np.array([[LENGTH], [0.0], [0.0]])), axis=0))
    assert centre.size == 1, centre
    return System(formulation, model, tuple(cells), stiffness, mass, load, n_u, free, tip_mean,
                  ubasis.nodal_dofs[:, centre[0]])


class Factorised:
    """The sparse LU factorisation of a system's stiffness on its free dofs, shared by the static
    solve and the eigen-solver's shift-invert (at shift 0, the same matrix).

    The matrix is symmetric positive definite (``p1``, ``p2``) or symmetric quasi-definite (``mixed``:
    A positive definite once clamped, -M_p / K negative definite), so a factorisation without
    pivoting exists for every symmetric ordering: SuperLU runs in symmetric mode (minimum degree on
    A^T + A, diagonal pivots), ~10x faster and ~5x less fill than its default. Every solve's relative
    residual is checked; above ``RESIDUAL_TOLERANCE`` the matrix is refactored with partial pivoting.
    """

    def __init__(self, matrix: sp.spmatrix):
        start = time.perf_counter()
        self.matrix = sp.csc_matrix(matrix)
        self.lu = spla.splu(self.matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                            options=dict(SymmetricMode=True))
        self.pivoted = False
        self.max_residual = 0.0
        self.seconds = time.perf_counter() - start

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        x = self.lu.solve(rhs)
        residual = np.linalg.norm(self.matrix @ x - rhs) / max(np.linalg.norm(rhs), 1e-300)
        if residual > RESIDUAL_TOLERANCE and not self.pivoted:
            self.lu, self.pivoted = spla.splu(self.matrix), True
            return self.solve(rhs)
        self.max_residual = max(self.max_residual, float(residual))
        return x


def solve_static(system: System, factorised: Factorised | None = None) -> np.ndarray:
    """The displacement (m, all ``n_u`` displacement dofs) of the tip-loaded cantilever."""
    factorised = factorised or Factorised(system.stiffness[system.free][:, system.free])
    solution = np.zeros(system.stiffness.shape[0])
    solution[system.free] = factorised.solve(system.load[system.free])
    return solution[:system.n_u]


def eigenmodes(system: System, count: int, factorised: Factorised | None = None):
    """The ``count`` lowest eigenpairs of K u = omega^2 M u: frequencies (Hz, ascending) and the
    modes (n_u x count, zero on the constrained dofs).

    For ``mixed`` the pressure has no mass: the shift-invert operator solves the saddle-point system
    [[A, B^T], [B, -M_p / K]] (x, p) = (M v, 0) and keeps x = (A + K B^T M_p^-1 B)^-1 M v, the
    operator of the displacement-only (Schur complement) eigenproblem, which eigsh solves with M.
    """
    if system.mass is None:
        raise ValueError("assemble the system with a density for its eigenmodes")
    free = system.free
    factorised = factorised or Factorised(system.stiffness[free][:, free])
    free_u = free[free < system.n_u]
    n, padding = free_u.size, free.size - free_u.size

    def shift_invert(x):
        return factorised.solve(np.concatenate([np.ravel(x), np.zeros(padding)]))[:n]

    def unused(x):  # eigsh's shift-invert mode (ARPACK mode 3) calls OPinv and M only
        raise RuntimeError("not used in shift-invert mode")

    values, vectors = spla.eigsh(spla.LinearOperator((n, n), matvec=unused, dtype=float), k=count,
                                 M=system.mass[free_u][:, free_u], sigma=0.0, which="LM", tol=1e-12,
                                 OPinv=spla.LinearOperator((n, n), matvec=shift_invert, dtype=float))
    order = np.argsort(values)
    modes = np.zeros((system.n_u, count))
    modes[free_u] = vectors[:, order]
    return np.sqrt(values[order]) / (2.0 * math.pi), modes


def analyse(cells, young: float = YOUNG, poisson: float = 0.3, formulation: str = "mixed",
            model: str = "quarter", density: float | None = None, modes: int = 0) -> dict:
    """Assemble, factorise once, solve the tip load and (``modes`` > 0, with a density) the modes.

    Returns ``tip_mean_uy`` and ``tip_centre_uy`` (m; negative, the load is in -y), ``dofs`` (free), ``residual`` (the largest relative residual of the solves), ``seconds`` and, with
    modes: ``modes`` (each of the ``modes`` lowest: frequency in Hz, kind, the bending direction's
    angle from the y axis in degrees, 0 to 90) and ``bending_frequency`` (Hz, the lowest bending mode's). A mode is a
    bending mode when its tip face translates sideways: |mean tip (u_y, u_z)| is over half the mode's
    largest nodal displacement (torsion and axial modes have ~0 there).
    """
    start = time.perf_counter()
    system = assemble(cells, young, poisson, formulation, model, density)
    factorised = Factorised(system.stiffness[system.free][:, system.free])
    u = solve_static(system, factorised)
    mean = system.tip_mean @ u
    result = dict(tip_mean_uy=float(mean[1]), tip_centre_uy=float(u[system.tip_centre[1]]),
                  dofs=int(system.free.size))
    if modes:
        freqs, vectors = eigenmodes(system, modes, factorised)
        rows = []
        for frequency, mode in zip(freqs, vectors.T):
            tip = system.tip_mean @ mode
            peak = np.max(np.linalg.norm(mode.reshape(-1, 3), axis=1))  # the dofs are x, y, z per node
            rows.append(dict(frequency=float(frequency),
                             kind="bending" if math.hypot(tip[1], tip[2]) > 0.5 * peak else "other",
                             direction_deg=float(math.degrees(math.atan2(abs(tip[2]), abs(tip[1]))))))
        bending = [row["frequency"] for row in rows if row["kind"] == "bending"]
        if not bending:
            raise RuntimeError(f"no bending mode among the {modes} lowest: {rows}")
        result.update(modes=rows, bending_frequency=bending[0])
    result.update(residual=factorised.max_residual, pivoted=factorised.pivoted,
                  factor_seconds=factorised.seconds, seconds=time.perf_counter() - start)
    return result


def shear_coefficient(poisson: float) -> float:
    """Timoshenko's shear coefficient of a square (rectangular) section: k = 10 (1 + nu) / (12 + 11 nu)."""
    return 10.0 * (1.0 + poisson) / (12.0 + 11.0 * poisson)


def _section(young: float, poisson: float) -> tuple[float, float, float, float]:
    """Area A (m^2), second moment I = a^4 / 12 (m^4), E I (N m^2) and k G A (N) of the square section."""
    area, inertia = WIDTH ** 2, WIDTH ** 4 / 12.0
    return area, inertia, young * inertia, shear_coefficient(poisson) * young / (2.0 * (1.0 + poisson)) * area


def timoshenko_tip_deflection(young: float = YOUNG, poisson: float = 0.3) -> float:
    """Tip deflection (m, positive in the load's direction) of the Timoshenko cantilever under the tip
    load P = LOAD: delta = P L^3 / (3 E I) + P L / (k G A), I = a^4 / 12, A = a^2, G = E / (2 (1 + nu))."""
    _, _, ei, kga = _section(young, poisson)
    return LOAD * LENGTH ** 3 / (3.0 * ei) + LOAD * LENGTH / kga


def _timoshenko_transfer(omega: float, young: float, poisson: float, density: float) -> np.ndarray:
    """The 4x4 transfer matrix over the beam's length of the free-vibration Timoshenko equations for
    the state (w, psi, M, V): w' = psi + V / (k G A), psi' = M / (E I), M' = -V - rho I omega^2 psi,
    V' = -rho A omega^2 w (deflection w, section rotation psi, moment M = E I psi', shear force
    V = k G A (w' - psi))."""
    area, inertia, ei, kga = _section(young, poisson)
    w2 = omega * omega
    system = np.array([[0.0, 1.0, 0.0, 1.0 / kga],
                       [0.0, 0.0, 1.0 / ei, 0.0],
                       [0.0, -density * inertia * w2, 0.0, -1.0],
                       [-density * area * w2, 0.0, 0.0, 0.0]])
    return expm(system * LENGTH)


def euler_bernoulli_frequency(young: float = YOUNG, density: float = DENSITY) -> float:
    """First bending eigenfrequency (Hz) of the Euler-Bernoulli cantilever: 1.8751^2 / (2 pi L^2) sqrt(E I / (rho A))."""
    area, inertia = WIDTH ** 2, WIDTH ** 4 / 12.0
    return 1.8751040687119611 ** 2 / (2.0 * math.pi * LENGTH ** 2) * math.sqrt(young * inertia / (density * area))


def timoshenko_frequency(young: float = YOUNG, poisson: float = 0.3, density: float = DENSITY) -> float:
    """First bending eigenfrequency (Hz) of the clamped-free Timoshenko beam (shear deformation with
    the k above, and rotary inertia rho I), solved exactly: with w = psi = 0 at the clamp and
    M = V = 0 at the free end, omega is the lowest root of det T[2:4, 2:4](omega) = 0, T the
    transfer matrix (a matrix exponential) of :func:`_timoshenko_transfer`."""
    euler = 2.0 * math.pi * euler_bernoulli_frequency(young, density)

    def determinant(omega):
        t = _timoshenko_transfer(omega, young, poisson, density)
        return t[2, 2] * t[3, 3] - t[2, 3] * t[3, 2]

    grid = np.linspace(0.05, 1.05, 201) * euler  # shear and rotary inertia lower omega below Euler's
    values = [determinant(w) for w in grid]
    for lo, hi, vlo, vhi in zip(grid[:-1], grid[1:], values[:-1], values[1:]):
        if vlo * vhi <= 0.0:
            return brentq(determinant, lo, hi, xtol=1e-15 * euler, rtol=1e-14) / (2.0 * math.pi)
    raise RuntimeError("no root of the Timoshenko frequency equation below the Euler-Bernoulli one")


def richardson(sizes, values, safety: float = 1.25, max_order: float = 4.0, low_order: float = 1.0) -> dict:
    """Richardson extrapolation of the last three (mesh size h, value) pairs, h decreasing, with
    Roache's grid convergence index.

    The observed order p solves (f2 - f1) / (f3 - f2) = (h1^p - h2^p) / (h2^p - h3^p), capped at
    ``max_order`` (a P2 energy functional's order: a higher one would make the estimate less
    conservative). Without monotone convergence (no p > 0 solves it), p = 2 and the safety factor
    is 3. ``extrapolated`` = f3 + (f3 - f2) / (r^p - 1), r = h2 / h3; ``relative_error_fine`` =
    |f3 - extrapolated| / |extrapolated|, the finest mesh's estimated relative discretisation error;
    ``gci_fine`` = safety |f3 - f2| / |f3| / (r^p - 1), its conservative bound (and that of the
    extrapolated value); ``relative_change_last`` = |f3 - f2| / |f3|.

    The clamped edges' stress singularities limit the asymptotic order of the tip's convergence to
    about 1 (twice the edge singularity's exponent): the observed order falls towards it as the mesh is
    refined (1.66, 1.29, then 1.14 for the triples of 10, 20, 40, 60 and, once, 80 cubes along the
    beam at nu = 0.499), so the observed-order extrapolation corrects slightly too little.
    ``extrapolated_low_order`` repeats it with the order ``low_order`` (1, or the observed order if
    lower), and ``extrapolation_uncertainty`` = |that - extrapolated| / |extrapolated| is the
    converged estimate's uncertainty from the order.
    """
    h1, h2, h3 = (float(h) for h in sizes[-3:])
    f1, f2, f3 = (float(v) for v in values[-3:])
    e21, e32 = f2 - f1, f3 - f2
    r21, r32 = h1 / h2, h2 / h3

    def ratio(p):  # (h1^p - h2^p) / (h2^p - h3^p), increasing in p, ln(r21) / ln(r32) at p -> 0
        return r32 ** p * (r21 ** p - 1.0) / (r32 ** p - 1.0)

    q = e21 / e32 if e32 != 0.0 else math.inf
    monotone = math.isfinite(q) and q > math.log(r21) / math.log(r32)
    if not monotone:
        order, safety = 2.0, 3.0
    elif ratio(max_order) <= q:
        order = max_order
    else:
        order = brentq(lambda p: ratio(p) - q, 1e-9, max_order, xtol=1e-12)
    extrapolated = f3 + e32 / (r32 ** order - 1.0)
    low_order = min(order, low_order)
    low = f3 + e32 / (r32 ** low_order - 1.0)
    return dict(extrapolated=extrapolated, observed_order=order, monotone=monotone,
                extrapolated_low_order=low, low_order=low_order,
                extrapolation_uncertainty=abs(low - extrapolated) / abs(extrapolated),
                relative_error_fine=abs(f3 - extrapolated) / abs(extrapolated),
                gci_fine=safety * abs(e32) / abs(f3) / (r32 ** order - 1.0),
                relative_change_last=abs(e32) / abs(f3))


def run(meshes=MESHES, poissons=POISSON, young: float = YOUNG, density: float = DENSITY, log=print) -> dict:
    """Every (nu, mesh) solve of the mixed quarter model, the convergence estimates, and Timoshenko."""
    start = time.perf_counter()
    sizes = [LENGTH / cells[0] for cells in meshes]
    rows = []
    for poisson in poissons:
        per_mesh = []
        for cells in meshes:
            result = analyse(cells, young, poisson, "mixed", "quarter", density, modes=3)
            per_mesh.append(dict(cells=list(cells), **result))
            log(f"nu={poisson} cells={cells} dofs={result['dofs']} mean_uy={result['tip_mean_uy']:.7e} m "
                f"centre_uy={result['tip_centre_uy']:.7e} m f={result['bending_frequency']:.7e} Hz "
                f"residual={result['residual']:.1e} ({result['seconds']:.1f} s)")
        convergence, coarser = {}, {}
        for key in ("tip_mean_uy", "tip_centre_uy", "bending_frequency"):
            values = [m[key] for m in per_mesh]
            convergence[key] = richardson(sizes, values)
            if len(values) >= 4:
                coarser[key] = richardson(sizes[:3], values[:3])
        timo_uy = -timoshenko_tip_deflection(young, poisson)
        timo_f = timoshenko_frequency(young, poisson, density)
        rows.append(dict(
            poisson_ratio=poisson, meshes=per_mesh, convergence=convergence, convergence_coarser_meshes=coarser,
            timoshenko=dict(shear_coefficient=shear_coefficient(poisson), tip_uy=timo_uy, bending_frequency=timo_f,
                            euler_bernoulli_tip_uy=-LOAD * LENGTH ** 3 / (3 * young * WIDTH ** 4 / 12),
                            euler_bernoulli_frequency=euler_bernoulli_frequency(young, density)),
            ratio_to_timoshenko=dict(tip_mean_uy=convergence["tip_mean_uy"]["extrapolated"] / timo_uy,
                                     tip_centre_uy=convergence["tip_centre_uy"]["extrapolated"] / timo_uy,
                                     bending_frequency=convergence["bending_frequency"]["extrapolated"] / timo_f)))
    return dict(rows=rows, seconds=time.perf_counter() - start)


def write_json(data: dict, path: Path) -> None:
    """Write ``data`` to ``path`` atomically: a temporary file in the same directory, then os.replace."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as handle:
            json.dump(data, handle, indent=1)
            handle.write("\n")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _skfem_version() -> str:
    try:
        from importlib.metadata import version
        return version("scikit-fem")
    except Exception:  # noqa: BLE001 - no metadata in an unusual install
        return getattr(skfem, "__version__", "unknown")


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description="Locking-free cantilever reference (scikit-fem, Taylor-Hood).")
    parser.add_argument("--young", type=float, default=YOUNG, help="Young's modulus, Pa (default 1e4)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="the JSON file written")
    args = parser.parse_args(argv)
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    results = run(young=args.young)
    command = COMMAND if (args.young, args.out) == (YOUNG, RESULTS) else f"{COMMAND} --young {args.young} --out {args.out}"
    data = dict(
        description="Static tip deflection and first bending eigenfrequency of a 1 x 0.2 x 0.2 m linear-elastic "
                    "cantilever clamped at x = 0: a converged, locking-free reference (scikit-fem, Taylor-Hood "
                    "P2-P1 tetrahedra, p / K + div u = 0) for the tetrahedral formulations. SI units.",
        command=command,
        problem=dict(length_m=LENGTH, section_m=[WIDTH, WIDTH], clamp="x = 0: u = 0",
                     load=f"{LOAD} N in -y: the uniform traction (0, -{LOAD / WIDTH ** 2:g}, 0) Pa on the x = "
                          f"{LENGTH:g} m face, integrated on the element space (its consistent nodal forces)",
                     young_modulus_pa=args.young, density_kg_m3=DENSITY, gravity=False,
                     strain="small (linear elasticity)"),
        discretisation=dict(
            element="Taylor-Hood tetrahedra: P2 vector displacement, P1 continuous pressure",
            pressure_equation="p / K + div u = 0, sigma = 2 mu dev(eps(u)) - p I",
            mesh="nx x ny x nz cubes of edge 1/nx m, 6 tetrahedra each (skfem MeshTet.init_tensor) in the "
                 "quarter y, z >= 0, mirrored about y = 0 and z = 0",
            model="quarter: u_z = 0 on z = 0 (symmetry), u_x = u_z = p = 0 on y = 0 (antisymmetry); the same "
                  "discrete solution as the full mirrored mesh. Its first mode is the first bending mode in y "
                  "(that in z is its exact twin)",
            meshes=[list(m) for m in MESHES], mesh_sizes_m=[LENGTH / m[0] for m in MESHES],
            quadrature_degree=dict(stiffness=STIFFNESS_ORDER, mass=MASS_ORDER),
            linear_solver="scipy.sparse.linalg.splu (SuperLU, symmetric mode, MMD on A^T + A) of the saddle-point "
                          "system; relative residuals recorded per mesh",
            eigen_solver="scipy.sparse.linalg.eigsh, shift-invert at 0 (the static factorisation), the massless "
                         "pressure eliminated in the solves"),
        convergence_method="Richardson extrapolation of the three finest meshes (observed order from them, capped "
                           "at 4) and Roache's grid convergence index (Fs = 1.25) of the finest mesh; "
                           "extrapolation_uncertainty: the spread to the first-order extrapolation (the clamped "
                           "edges' singularities limit the asymptotic order to ~1); convergence_coarser_meshes: "
                           "the same from the three coarsest meshes, to check the observed order. See richardson()",
        timoshenko=dict(deflection="P L^3 / (3 E I) + P L / (k G A), I = a^4 / 12, A = a^2, G = E / (2 (1 + nu))",
                        shear_coefficient="k = 10 (1 + nu) / (12 + 11 nu)",
                        frequency="lowest root of the clamped-free Timoshenko frequency equation (shear deformation "
                                  "and rotary inertia rho I) by transfer matrix: timoshenko_frequency()"),
        started=started, runtime_seconds=results["seconds"],
        environment=dict(python=platform.python_version(), numpy=np.__version__, scipy=scipy.__version__,
                         scikit_fem=_skfem_version(), machine=platform.machine(), cpus=os.cpu_count()),
        results=results["rows"])
    write_json(data, args.out)
    print(f"wrote {args.out} in {results['seconds']:.0f} s")
    return data


if __name__ == "__main__":
    main(sys.argv[1:])
