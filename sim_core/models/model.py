"""Build an immutable Baudet mass-spring model from a hexahedral or tetrahedral mesh and a material.

Model / State / Control follow Warp's split: the ``Model`` never changes
during a run, a ``State`` is what an integrator steps, a ``Control`` is what the user imposes.
Formulas cite ``docs/physics.md`` (sections in brackets). SI units throughout.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from . import terms
from .. import kernels
from .._validate import finite_array
from .elements import element_block_positions
from .laws import baudet_stiffness  # noqa: F401  (re-exported: the formulas' users import it from here)
from .material import Material, rayleigh_coefficients
from ..geometry.mesh import EDGES, HexMesh
from .smoothing import SMOOTHING, SmoothedStrain, cell_pairs, smoothed_strain
from .sparse import NODE_ORDERINGS, BlockPattern
from .stress_correction import SPRING_CHOICES, StressCorrection, mean_gradients
from .terms import (SPRING_SHEAR_MODELS, check_shear_error, correction_coefficients,  # noqa: F401  (re-exported)
                    correction_matrix, hourglass_matrix, hourglass_projectors)
from ..geometry.tetmesh import TET_EDGES, TetMesh

#: Mass-spring model names accepted by ``build_model``.
MSS_MODELS = ("baudet", "baudet-original", "uniform-springs", "baudet-hyperelastic")
#: The mass-spring models a ``TetMesh`` takes (docs/physics.md section 12).
TET_MODELS = ("baudet", "baudet-hyperelastic")
#: The largest relative shear-modulus error ``build_model`` accepts by default in any plane of an
#: element of the models whose springs set the shear modulus alone ("baudet", "baudet-original";
#: ``laws.baudet_shear_ratio``): elements 1:1:a with a in about [0.96, 1.04]. 5% is the project's
#: accuracy floor in shear against FEM (docs/physics.md section 2).
MAX_SHEAR_ERROR = 0.05


@dataclass(frozen=True, eq=False)
class Model:
    """Everything that stays fixed during a simulation (build with ``build_model``).

    Attributes (S springs, M elements, N nodes):
        mesh: the ``HexMesh`` or ``TetMesh``; ``rest_positions`` (N, 3) m.
        name: physics variant ("baudet", "baudet-original", "uniform-springs", "baudet-hyperelastic").
        mass: (N,) lumped node masses in kg [5].
        springs: (S, 2) node pairs, each shared spring merged once.
        rest_length: (S,) m.  stiffness: (S,) N/m (sum over the elements sharing it) [2].
        damping: (S,) N s/m, ``damping_ratio * 2 sqrt(mu k)`` with mu the reduced mass
            m_a m_b / (m_a + m_b) of the spring's two nodes (critical damping of that pair) [5].
        edge_spring: (M, 12) the spring of each element edge (EDGES order); tetrahedra: (M, 6)
            (``tetmesh.TET_EDGES`` order).
        axis_rest_length: (M, 3) mean rest length of the element's x-, y-, z-edges, m (tetrahedra,
            which have no axes: (M, 0)).
        correction_matrix: (M, 3, 3) W with T_j = sum_m W_jm eps_m, the push (N) applied along
            each of the element's four j-edges by the correction forces [3].
        correction_mode: "projected" (along current edges), "fixed" (rest directions), or None.
        rest_volume: (M,) m^3.  volume_stiffness: (M,) kappa in N, 0 where volume forces are off [4].
        gravity: (3,) m/s^2.
        young_modulus, poisson_ratio, density: (M,) per-element material.
        hourglass: (3N, 3N) constant CSR stiffness K_hg (N/m) of the hourglass control, or None;
            it adds f = -K_hg (x - X), which vanishes for every affine displacement [6].
        stress_correction: the per-element arrays of the finite-strain stress correction
            (``stress_correction.StressCorrection``) of "baudet-hyperelastic" [11] and of both
            tetrahedral models [12], or None; with ``smoothing``, one row per smoothing domain.
        smoothing: the smoothing domains (``smoothing.SmoothedStrain``) of a tetrahedral model
            built with smoothing="edge-node" [12], or None: the stress correction then acts on
            the domains' deformation gradients instead of the elements'.
        damping_law: the material's damping law, (damping_ratio, damping_frequency) of its
            ``Material`` (Rayleigh damping, ``rayleigh``) [14], or None (the springs' dashpots only).
    """

    mesh: HexMesh | TetMesh
    name: str
    mass: np.ndarray
    springs: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    edge_spring: np.ndarray
    axis_rest_length: np.ndarray
    correction_matrix: np.ndarray
    correction_mode: str | None
    rest_volume: np.ndarray
    volume_stiffness: np.ndarray
    gravity: np.ndarray
    young_modulus: np.ndarray
    poisson_ratio: np.ndarray
    density: np.ndarray
    hourglass: sp.csr_matrix | None = None
    options: dict = field(default_factory=dict)
    stress_correction: StressCorrection | None = None
    smoothing: SmoothedStrain | None = None
    damping_law: tuple | None = None

    def __post_init__(self):
        n_nodes = self.mesh.n_nodes
        hourglass = self.hourglass
        elements = self.mesh.elements
        # the value-derived arrays a stack rewrites in place (``stack.StackedModel``); the pattern and
        # the other topology arrays are built on first use (``TOPOLOGY_DERIVED``): a cut model that is
        # only measured (``cutting.separate``'s, before a stack pads it) never builds them
        derived = dict(
            hourglass_arrays=(
                (hourglass.indptr.astype(np.int64), hourglass.indices.astype(np.int64), hourglass.data)
                if hourglass is not None else
                (np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0))
            ),
            # a node of no element (a stack's parked row) carries no load: nothing would hold it
            gravity_force=np.where((np.bincount(elements.ravel(), minlength=n_nodes) > 0)[:, None],
                                   self.mass[:, None] * self.gravity[None, :], 0.0),
            rest_edge_direction=_edge_directions(self.mesh.nodes, elements),
        )
        for key, value in derived.items():
            object.__setattr__(self, key, value)

    @functools.cached_property
    def incidence(self) -> sp.csr_matrix:
        """(N, S) f = incidence @ (t u): +t u on node a, -t u on node b (t = tension, u from a to b)."""
        a, b = self.springs[:, 0], self.springs[:, 1]
        columns = np.arange(len(self.springs))
        return sp.csr_matrix((np.r_[np.ones(len(columns)), -np.ones(len(columns))],
                              (np.r_[a, b], np.r_[columns, columns])), shape=(self.n_nodes, len(columns)))

    @functools.cached_property
    def element_scatter(self) -> sp.csr_matrix:
        """(N, M n) the sum over each node's element corners."""
        elements = self.mesh.elements
        return sp.csr_matrix((np.ones(elements.size), (elements.ravel(), np.arange(elements.size))),
                             shape=(self.n_nodes, elements.size))

    @functools.cached_property
    def pattern(self) -> BlockPattern:
        """The (3N, 3N) block pattern of the nodes that share an element (a smoothing domain couples
        every pair of its nodes too: nodes two edges apart, outside the elements)."""
        return BlockPattern(self.n_nodes, self.mesh.elements,
                            None if self.smoothing is None else self.smoothing.pairs())

    @functools.cached_property
    def spring_positions(self) -> np.ndarray:
        """(S, 4, 3, 3) the pattern positions of each spring's blocks (a, a), (b, b), (a, b), (b, a)."""
        a, b = self.springs[:, 0], self.springs[:, 1]
        positions = self.pattern.block_positions(np.stack([a, b, a, b], axis=1), np.stack([a, b, b, a], axis=1))
        return np.ascontiguousarray(positions)

    @functools.cached_property
    def element_positions(self) -> np.ndarray:
        """(M, n, n, 3, 3) the pattern positions of each element's node-pair blocks."""
        return element_block_positions(self.pattern, self.mesh.elements)

    @functools.cached_property
    def mass_data(self) -> np.ndarray:
        """The pattern data of the lumped mass matrix (a stack rewrites its worlds' entries in place)."""
        return self.pattern.assemble(self.pattern.diagonal_positions, np.repeat(self.mass, 3))

    @functools.cached_property
    def node_blocks(self) -> tuple:
        """The node-pair blocks of the spring graph (block CSR) for the compiled implicit solver:
        (node_indptr, node_indices, diagonal_block, block_of_spring)."""
        n_nodes, n_springs = self.n_nodes, len(self.springs)
        a, b = self.springs[:, 0], self.springs[:, 1]
        columns = np.arange(n_springs)
        pairs = np.concatenate([np.stack([np.arange(n_nodes)] * 2, axis=1), self.springs, self.springs[:, ::-1]])
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        sorted_pairs = pairs[order]
        block_index = np.empty(len(pairs), dtype=np.int64)
        block_index[order] = np.arange(len(pairs))
        node_indptr = np.searchsorted(sorted_pairs[:, 0], np.arange(n_nodes + 1)).astype(np.int64)
        diagonal_block = block_index[:n_nodes]
        block_of_spring = np.stack(
            [diagonal_block[a], diagonal_block[b], block_index[n_nodes + columns],
             block_index[n_nodes + n_springs + columns]], axis=1,
        )
        return (node_indptr, np.ascontiguousarray(sorted_pairs[:, 1]).astype(np.int64), diagonal_block,
                np.ascontiguousarray(block_of_spring))

    node_indptr = property(lambda self: self.node_blocks[0])
    node_indices = property(lambda self: self.node_blocks[1])
    diagonal_block = property(lambda self: self.node_blocks[2])
    block_of_spring = property(lambda self: self.node_blocks[3])

    @property
    def rayleigh(self) -> tuple[float, float]:
        """(alpha in 1/s, beta in s) of the material's Rayleigh damping, forces -(alpha M + beta K) v
        with K the implicit step's stiffness [14]; (0, 0) without a damping law."""
        if self.damping_law is None:
            return (0.0, 0.0)
        return rayleigh_coefficients(*self.damping_law)

    @property
    def rest_positions(self) -> np.ndarray:
        return self.mesh.nodes

    @property
    def pattern_density(self) -> float:
        """The pattern's entries over those of the elements' node pairs alone: 1, or more where the
        smoothing domains couple nodes two edges apart (the implicit step's LU fills that much more,
        ``preconditioners.auto_switch_iterations``)."""
        if self.smoothing is None:
            return 1.0
        return self.derived.get("pattern_density",
                                lambda: self.pattern.nnz / BlockPattern(self.n_nodes, self.mesh.elements).nnz)

    @property
    def node_orderings(self) -> tuple:
        """The fill-reducing node orderings its node-block factors try (``sparse.block_structure``
        keeps the cheapest): MMD alone on the elements' pattern, also COLAMD on a wider one
        (``pattern_density`` > 1: the smoothed tetrahedra's, where MMD fills most)."""
        return NODE_ORDERINGS if self.pattern_density > 1.0 else NODE_ORDERINGS[:1]

    @property
    def stress_cells(self) -> tuple:
        """The cells the stress correction acts on, in compressed rows: (indptr (C + 1,), nodes
        (nnz,), gradients (nnz, 3) 1/m) with cell c's deformation gradient the sum over its entries
        of x_a (outer) b_a: the elements (n entries each, ``StressCorrection.mean_gradient``) or
        the smoothing domains. The implicit operator's and the assembly's view (``kernels.OperatorData``)."""
        def build():
            if self.smoothing is not None:
                return self.smoothing.indptr, self.smoothing.nodes, self.smoothing.gradient
            gradient = self.stress_correction.mean_gradient
            count, n = gradient.shape[:2]
            return (np.arange(0, count * n + 1, n, dtype=np.int64),
                    kernels.writeable(np.ascontiguousarray(self.mesh.elements.reshape(-1), dtype=np.int64)),
                    gradient.reshape(-1, 3))
        return self.derived.get("stress_cells", build)

    @property
    def stress_pair_rows(self) -> np.ndarray:
        """(P, 3) int64: for every cell's node pair (a, b) (cell by cell, a-major, ``stress_cells``'
        entry order), the positions in the ``pattern``'s data of the entries (3 a + i, 3 b), i = 0..2
        (the block's row i continues at + 1, + 2): where the assembly adds B^T T B."""
        def build():
            a, b = cell_pairs(*self.stress_cells[:2]).T
            return np.ascontiguousarray(self.pattern.positions(3 * a[:, None] + np.arange(3), 3 * b[:, None]))
        return self.derived.get("stress_pair_rows", build)

    @property
    def n_nodes(self) -> int:
        return self.mesh.n_nodes

    @property
    def has_volume_forces(self) -> bool:
        return bool(np.any(self.volume_stiffness > 0))

    @functools.cached_property
    def derived(self) -> "DerivedCache":
        """Data the solvers derive from this model on first use (pattern arrays, node-block forms,
        free-dof structures): a cache that lives, is copied and is pickled with the model, so a
        copy of a model (``copy.deepcopy``, ``pickle``) never consults another model's entries."""
        return DerivedCache()

    def new_state(self) -> "State":
        """A state at rest: positions = rest positions, zero velocities, time 0."""
        return State(self.rest_positions.copy(), np.zeros_like(self.rest_positions))

    def new_control(self) -> "Control":
        """A control with no imposed displacement and no external nodal force."""
        return Control.free(self.n_nodes)


class DerivedCache:
    """A model's derived data by name (``Model.derived``): ``get(name, build)`` returns the entry,
    computing it with ``build()`` once. Thread-safe (a vector env resets its copies on threads);
    ``peek``/``put`` read and set an entry built elsewhere, ``forget(name)`` drops one."""

    def __init__(self):
        self._entries: dict = {}
        self._lock = threading.Lock()

    def get(self, name, build):
        entry = self._entries.get(name, _MISSING)
        if entry is _MISSING:
            with self._lock:
                entry = self._entries.get(name, _MISSING)
                if entry is _MISSING:
                    entry = self._entries[name] = build()
        return entry

    def peek(self, name):
        """The entry ``name``, or None (nothing is built)."""
        return self._entries.get(name)

    def put(self, name, value):
        """Set the entry ``name`` (computed by the caller, e.g. outside any lock); returns ``value``."""
        with self._lock:
            self._entries[name] = value
        return value

    def forget(self, name):
        with self._lock:
            self._entries.pop(name, None)

    def __getstate__(self):  # a lock does not pickle
        return dict(entries=self._entries)

    def __setstate__(self, state):
        self._entries = state["entries"]
        self._lock = threading.Lock()


_MISSING = object()


@dataclass
class State:
    """What changes every step: ``positions`` (N, 3) m, ``velocities`` (N, 3) m/s, ``time`` s."""

    positions: np.ndarray
    velocities: np.ndarray
    time: float = 0.0

    def copy(self) -> "State":
        return State(self.positions.copy(), self.velocities.copy(), self.time)


@dataclass
class Control:
    """What the user imposes.

    Attributes:
        fixed: (N, 3) bool, True where a position component is imposed.
        target: (N, 3) imposed positions in m (read where ``fixed``).
        force: (N, 3) external nodal forces in N (added to gravity).
    """

    fixed: np.ndarray
    target: np.ndarray
    force: np.ndarray

    @classmethod
    def free(cls, n_nodes: int) -> "Control":
        return cls(np.zeros((n_nodes, 3), bool), np.zeros((n_nodes, 3)), np.zeros((n_nodes, 3)))

    def impose(self, nodes, positions, components=(0, 1, 2)) -> "Control":
        """Impose ``positions`` (broadcast to (len(nodes), 3), m) on the given components."""
        raw = np.atleast_1d(np.asarray(nodes))
        if raw.ndim != 1 or not (np.issubdtype(raw.dtype, np.integer) or (raw.size == 0 and raw.dtype == float)):
            raise ValueError(f"nodes must be a 1D sequence of integer node indices, got {raw.dtype} of shape {raw.shape}")
        nodes = raw.astype(int)
        n_nodes = len(self.fixed)
        if nodes.size and (nodes.min() < -n_nodes or nodes.max() >= n_nodes):
            raise ValueError(f"node indices must lie in [0, {n_nodes - 1}], got [{nodes.min()}, {nodes.max()}]")
        try:
            positions = np.broadcast_to(positions, (len(nodes), 3))
        except ValueError as error:
            raise ValueError(f"positions must broadcast to ({len(nodes)}, 3) (one (x, y, z) in m per node), "
                             f"got shape {np.shape(positions)}") from error
        positions = finite_array("positions", positions)
        components = list(np.atleast_1d(components))
        if not components or any(isinstance(c, (bool, np.bool_)) or c not in (0, 1, 2) for c in components):
            raise ValueError(f"components must be among 0, 1, 2 (x, y, z), got {components!r}")
        index = np.ix_(nodes, components)
        self.fixed[index] = True
        self.target[index] = positions[:, components]
        return self

    def copy(self) -> "Control":
        return Control(self.fixed.copy(), self.target.copy(), self.force.copy())


#: The derived data of a model that depends on its topology alone (node count, elements, springs,
#: smoothing domains), built on first use and never changed: models of one topology may share it
#: (``share_topology``).
TOPOLOGY_DERIVED = ("incidence", "element_scatter", "pattern", "spring_positions", "element_positions",
                    "node_blocks")
#: The topology data the implicit solver reads (the others serve the numpy reference forces).
SOLVER_TOPOLOGY = ("pattern", "spring_positions", "element_positions")


def share_topology(source: Model, target: Model) -> None:
    """Give ``target``, a model of ``source``'s topology (the same node count, elements, springs and
    smoothing domains; its values may differ), ``source``'s topology data (``TOPOLOGY_DERIVED``: the
    solver's, ``SOLVER_TOPOLOGY``, built now if it was not, and the rest it has built) instead of
    building its own: a stack of one world (``stack.ModelStack``) is its model's topology."""
    if not (source.n_nodes == target.n_nodes and np.array_equal(source.mesh.elements, target.mesh.elements)
            and np.array_equal(source.springs, target.springs)
            and (source.smoothing is None) == (target.smoothing is None)
            and (source.smoothing is None or (np.array_equal(source.smoothing.indptr, target.smoothing.indptr)
                                              and np.array_equal(source.smoothing.nodes, target.smoothing.nodes)))):
        raise ValueError("share_topology needs two models of one topology (node count, elements, springs, smoothing "
                         "domains)")
    for name in TOPOLOGY_DERIVED:  # what the solvers read, and what else the source has built already
        if name in SOLVER_TOPOLOGY or name in source.__dict__:
            target.__dict__[name] = getattr(source, name)


def extend_topology(source: Model, target: Model) -> None:
    """Give ``target``, ``source`` on more node rows (``source``'s nodes, then nodes of no element and
    no spring: a stack's parked rows, ``stack.with_spare_nodes``), the topology data ``source`` has
    built, extended to those rows (``BlockPattern.padded``: the entries of ``source``'s nodes keep
    their positions, so its spring and element positions hold) instead of building it again."""
    if not (target.n_nodes >= source.n_nodes and np.array_equal(source.mesh.elements, target.mesh.elements)
            and np.array_equal(source.springs, target.springs) and source.smoothing is None
            and target.smoothing is None):
        raise ValueError("extend_topology needs a model and the same model on more node rows (no smoothing domains)")
    if "pattern" not in source.__dict__:
        return
    target.__dict__["pattern"] = source.pattern.padded(target.n_nodes)
    for name in ("spring_positions", "element_positions"):
        if name in source.__dict__:
            target.__dict__[name] = source.__dict__[name]


def _edge_directions(positions, elements):
    edges = TET_EDGES if elements.shape[1] == 4 else EDGES
    vectors = positions[elements[:, edges[:, 1]]] - positions[elements[:, edges[:, 0]]]
    return vectors / np.linalg.norm(vectors, axis=2, keepdims=True)


# -- builder -------------------------------------------------------------------------------------
def _model_options(mesh, model, volume_conservation, volume_stiffness, nu_factor, damping_ratio, damping_law,
                   hourglass_control, springs, smoothing) -> dict:
    """``build_model``'s arguments checked for ``mesh`` (hexahedral or tetrahedral): its options dict."""
    if model not in MSS_MODELS:
        raise ValueError(f"model must be one of {MSS_MODELS}, got {model!r}")
    if not isinstance(mesh, (HexMesh, TetMesh)):
        raise ValueError(f"mesh must be a HexMesh or a TetMesh, got {type(mesh).__name__}")
    if damping_ratio is None:  # a damping law sets the damping alone; else the springs' dashpots [5]
        damping_ratio = 1.0 if damping_law is None else 0.0
    options = (_tet_options if isinstance(mesh, TetMesh) else _hex_options)(
        model, volume_conservation, volume_stiffness, nu_factor, damping_ratio, hourglass_control, springs)
    if isinstance(mesh, TetMesh):
        smoothing = "edge-node" if smoothing is None else smoothing
        if smoothing not in SMOOTHING:
            raise ValueError(f"smoothing must be one of {SMOOTHING} on a TetMesh, got {smoothing!r}")
        options["smoothing"] = smoothing
    elif smoothing is not None:
        raise ValueError(f"smoothing={smoothing!r} applies to a TetMesh only (a hexahedral model's stress correction "
                         "does not lock); leave it unset")
    return options


def _stress_correction_term(mesh, model, options, local_pairs, values, edge_spring, n_springs, young_modulus,
                            poisson_ratio):
    """(stress correction, smoothed strain domains or None) of a hyperelastic or tetrahedral model:
    on tetrahedra with smoothing "edge-node" the law on edge and node domains
    (``smoothing.smoothed_strain``) [12], else each element's own correction."""
    law = "neo-hookean" if model == "baudet-hyperelastic" else "linear"
    if options.get("smoothing") == "edge-node":
        gradient, volume = mean_gradients(mesh.nodes, mesh.elements)
        shear, lame = terms.lame_parameters(young_modulus, poisson_ratio)
        smoothed = smoothed_strain(mesh.nodes, mesh.elements, edge_spring, n_springs, gradient, volume, shear, lame,
                                   law)
        return smoothed.law, smoothed
    return terms.stress_correction(mesh, local_pairs, values, young_modulus, poisson_ratio, law), None


def _hourglass_term(mesh, same, young_modulus, poisson_ratio, alpha):
    """(hourglass matrix or None, its block pattern, the elements' block positions) for hourglass
    control ``alpha`` (0: none); the element matrices are taken from ``same`` where it has them."""
    if alpha <= 0:
        return None, None, None
    matrices = None
    if same is not None and same.hourglass is not None:  # computed once per uncut model, kept with it
        matrices = same.derived.get(("hourglass_elements", alpha), lambda: terms.hourglass_element_matrices(
            same.mesh, young_modulus, poisson_ratio, alpha))
    # the model's own pattern (a hexahedral model's couples the nodes of its elements, as this matrix)
    pattern = BlockPattern(mesh.n_nodes, mesh.elements)
    positions = element_block_positions(pattern, mesh.elements)
    hourglass = terms.hourglass_matrix(mesh, young_modulus, poisson_ratio, alpha, matrices, pattern, positions)
    return hourglass, pattern, positions


def build_model(
    mesh: HexMesh | TetMesh,
    material: Material,
    *,
    model: str = "baudet",
    corrections: bool = True,
    volume_conservation: bool | None = None,
    volume_stiffness: float = 1.0,
    nu_factor: bool = False,
    damping_ratio: float | None = None,
    gravity=(0.0, 0.0, 0.0),
    hourglass_control: float = 0.0,
    springs: str = "faces",
    max_shear_error: float | None = MAX_SHEAR_ERROR,
    smoothing: str | None = None,
    same_elements: Model | None = None,
) -> Model:
    """Build a mass-spring ``Model`` once from geometry and material.

    Args:
        mesh: hexahedral (``HexMesh``) or tetrahedral (``TetMesh``) mesh, rest positions in m. A
            ``TetMesh`` takes ``TET_MODELS`` [12]: "baudet" (each tetrahedron's 6 edge springs and
            a stress correction on its exact deformation gradient to the small-strain Hooke
            stress: linear elasticity at small strain, exact for every element shape and nu) and
            "baudet-hyperelastic" (the same to the neo-Hookean stress, at every strain); neither
            takes volume forces, hourglass control (no hourglass modes) or ``springs``.
        material: ``Material`` (scalars or one value per element).
        model: "baudet" (stress-based corrections projected on the deformed edges, volume
            forces), "baudet-original" (the report's corrections as published: half size,
            strain-based, along rest directions, no volume forces), "uniform-springs" (every
            spring k = E * element size / 4, no corrections: the naive baseline) or
            "baudet-hyperelastic" (springs plus the finite-strain stress correction on each
            element's mean deformation gradient: compressible neo-Hookean under every homogeneous
            deformation, objective, no volume forces) [11].
        corrections: False switches the correction forces off (ablations; "baudet-hyperelastic":
            the springs alone remain).
        volume_conservation: volume forces on/off; default on for "baudet" only.
        volume_stiffness: multiplier of kappa = K V0^(2/3), K = E / (3 (1 - 2 nu)) [4].
        nu_factor: "baudet-original" only: multiply the corrections by nu (report section 5.1).
        damping_ratio: multiplier (>= 0) of the critical spring damping 2 sqrt(mu k) [5]. None:
            1 for a material without a damping law, 0 for one with (the law damps alone [14]).
        gravity: (3,) acceleration in m/s^2; y is up, so Earth is (0, -9.81, 0).
        hourglass_control: alpha >= 0: alpha times the linear FEM element stiffness projected on
            the hourglass space (displacements orthogonal to every affine field), which leaves E, nu
            and G untouched and removes the zero-energy modes that buckle under compression [6]. Not
            objective: "baudet-hyperelastic" refuses it (its springs resist the hourglass modes).
        springs: "baudet-hyperelastic" only: the element's springs, "faces" (12 edges and 12 face
            diagonals matched to the hourglass modes' energy, ``stress_correction.element_spring_stiffness``),
            "isotropic" (12 edges and 4 inner diagonals of a nu = 1/4 solid, positive for every box)
            or "baudet" (Baudet's springs and formula, non-positive on elongated boxes) [11].
        max_shear_error: "baudet" and "baudet-original" on hexahedra: the largest accepted error
            |G_meas / G - 1| of the springs' shear modulus in any plane of any element
            (``laws.baudet_shear_ratio``; exact for cubes only); an element beyond it is a ValueError
            naming the models right on such elements. Default ``MAX_SHEAR_ERROR`` (5%: boxes 1:1:a,
            a in about [0.96, 1.04]); None accepts any box (ablations). Others ignore it [2].
        smoothing: ``TetMesh`` only: "edge-node" (default) evaluates the law on deformation
            gradients smoothed over edge domains (deviatoric part) and node domains (volumetric
            part): no locking near nu = 0.5, no stiffening in bending; the edge springs then only
            damp. "none": each tetrahedron's own F, linear-tetrahedron FEM (which locks) [12].
        same_elements: None, or a model whose elements have this mesh's rest corners and material
            in the same order (the mesh before a cut, ``cutting.separate``): its per-element terms
            (rest volumes, hourglass element matrices) are reused; the model is the same.
    """
    damping_law = None if material.damping_ratio is None else (material.damping_ratio, material.damping_frequency)
    options = _model_options(mesh, model, volume_conservation, volume_stiffness, nu_factor, damping_ratio,
                             damping_law, hourglass_control, springs, smoothing)
    gravity = finite_array("gravity", gravity, shape=(3,))
    tetrahedra = isinstance(mesh, TetMesh)
    props = material.per_element(mesh.n_elements)
    young_modulus, poisson_ratio, density = props["young_modulus"], props["poisson_ratio"], props["density"]
    same = same_elements if _has_same_elements(same_elements, mesh, props) else None
    axis_rest_length = terms.axis_rest_lengths(mesh)
    local_pairs, values = terms.element_springs(mesh, model, young_modulus, poisson_ratio, axis_rest_length,
                                                springs, max_shear_error)
    spring_pairs, stiffness, edge_spring, rest_length = terms.merge_springs(mesh, local_pairs, values)
    rest_volume = mesh.element_volumes() if same is None else same.rest_volume
    mass, damping = terms.masses_and_damping(mesh, density, rest_volume, spring_pairs, stiffness,
                                             options["damping_ratio"])
    w, correction_mode = np.zeros((mesh.n_elements, 3, 3)), None  # tetrahedra: the stress correction instead
    if corrections and not tetrahedra:
        w, correction_mode = terms.baudet_corrections(model, axis_rest_length, young_modulus, poisson_ratio, nu_factor)
    correction = smoothed = None
    if corrections and (model == "baudet-hyperelastic" or tetrahedra):
        correction, smoothed = _stress_correction_term(mesh, model, options, local_pairs, values, edge_spring,
                                                       len(spring_pairs), young_modulus, poisson_ratio)
    if smoothed is not None:
        stiffness = np.zeros_like(stiffness)  # the domains carry the whole elasticity; the springs damp [12]
    kappa = (terms.volume_stiffness(young_modulus, poisson_ratio, rest_volume, options["volume_stiffness"])
             if options["volume_conservation"] else np.zeros(mesh.n_elements))
    hourglass, pattern, positions = _hourglass_term(mesh, same, young_modulus, poisson_ratio,
                                                    options["hourglass_control"])
    built = Model(mesh=mesh, name=model, hourglass=hourglass, mass=mass, springs=spring_pairs, rest_length=rest_length,
                  stiffness=stiffness, damping=damping, edge_spring=edge_spring, axis_rest_length=axis_rest_length,
                  correction_matrix=w, correction_mode=correction_mode, rest_volume=rest_volume,
                  volume_stiffness=kappa, gravity=gravity, young_modulus=young_modulus, poisson_ratio=poisson_ratio,
                  density=density, options=dict(corrections=corrections, **options), stress_correction=correction,
                  smoothing=smoothed, damping_law=damping_law)
    if hourglass is not None:  # its pattern is the one the hourglass matrix was assembled on: not built again
        built.__dict__.update(pattern=pattern, element_positions=positions)
    return built


def _has_same_elements(model: Model | None, mesh, props) -> bool:
    """Whether ``model``'s elements have ``mesh``'s rest corners and the material ``props`` (per element)."""
    if model is None:
        return False
    if type(model.mesh) is not type(mesh) or model.mesh.elements.shape != mesh.elements.shape:
        return False
    return (np.array_equal(model.mesh.nodes[model.mesh.elements], mesh.nodes[mesh.elements])
            and all(np.array_equal(getattr(model, name), props[name])
                    for name in ("young_modulus", "poisson_ratio", "density")))


def _nonnegative(name, value) -> float:
    value = float(finite_array(name, value))
    if value < 0:
        raise ValueError(f"{name} must be >= 0, got {value}")
    return value


def _hex_options(model, volume_conservation, volume_stiffness, nu_factor, damping_ratio, hourglass_control,
                 springs) -> dict:
    """``build_model``'s options of a hexahedral model, checked (ValueError naming what is wrong and
    what is allowed), with the defaults filled in: the ``Model.options`` it records."""
    damping_ratio = _nonnegative("damping_ratio", damping_ratio)
    volume_stiffness = _nonnegative("volume_stiffness", volume_stiffness)
    hourglass_control = _nonnegative("hourglass_control", hourglass_control)
    if nu_factor and model != "baudet-original":
        raise ValueError("nu_factor only applies to model='baudet-original'")
    hyperelastic = model == "baudet-hyperelastic"
    if springs not in SPRING_CHOICES:
        raise ValueError(f"springs must be one of {SPRING_CHOICES}, got {springs!r}")
    if springs != "faces" and not hyperelastic:
        raise ValueError("springs only applies to model='baudet-hyperelastic' (the other models fix their springs)")
    if hyperelastic and hourglass_control > 0:
        raise ValueError("hourglass_control is a constant rest-frame stiffness (not objective) and does not apply to "
                         "model='baudet-hyperelastic', whose springs resist the hourglass modes; use hourglass_control=0")
    if hyperelastic and volume_conservation:
        raise ValueError("volume_conservation does not apply to model='baudet-hyperelastic': its neo-Hookean stress "
                         "correction already holds the volume (ln J pressure); leave volume_conservation unset")
    if volume_conservation is None:
        volume_conservation = model == "baudet"
    return dict(volume_conservation=bool(volume_conservation), volume_stiffness=volume_stiffness,
                nu_factor=nu_factor, damping_ratio=damping_ratio, hourglass_control=hourglass_control,
                **(dict(springs=springs) if hyperelastic else {}))


def _tet_options(model, volume_conservation, volume_stiffness, nu_factor, damping_ratio, hourglass_control,
                 springs) -> dict:
    """``build_model``'s options of a tetrahedral model (docs/physics.md section 12), checked: a
    ``TetMesh`` takes ``TET_MODELS`` and none of the hexahedral options."""
    if model not in TET_MODELS:
        raise ValueError(f"model={model!r} needs hexahedra (its springs and corrections are written for a hexahedron's "
                         f"axes); a TetMesh takes model in {TET_MODELS}")
    refused = [(hourglass_control != 0, f"hourglass_control={hourglass_control!r} (a linear tetrahedron has no "
                                        "hourglass modes: leave it 0)"),
               (bool(volume_conservation), "volume_conservation=True (the stress correction carries the whole "
                                           "volumetric stiffness: leave it unset)"),
               (volume_stiffness != 1.0, f"volume_stiffness={volume_stiffness!r} (no volume forces on tetrahedra)"),
               (bool(nu_factor), "nu_factor=True (a 'baudet-original' option)"),
               (springs != "faces", f"springs={springs!r} (a tetrahedron's springs are its 6 edges)")]
    for bad, what in refused:
        if bad:
            raise ValueError(f"{what} does not apply to a TetMesh (model={model!r})")
    return dict(volume_conservation=False, volume_stiffness=1.0, nu_factor=False,
                damping_ratio=_nonnegative("damping_ratio", damping_ratio), hourglass_control=0.0)
