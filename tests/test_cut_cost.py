"""What makes a cut cheap leaves the physics as it was: a model built with ``same_elements`` (the uncut
model's per-element terms) is the model built without it, a pattern padded for a stack's parked rows
is the pattern built on those rows, and the entry positions found through node blocks are those of
the matrix's own entries."""

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from sim_core import HexMesh, Material, TetMesh, build_model, cutting
from sim_core.models.model import Model, share_topology
from sim_core.models.sparse import BlockPattern, unique_keys
from sim_core.models.stack import with_spare_nodes
from sim_core.solvers.preconditioners import FreeStructure

MATERIAL = Material(1e4, 0.45, 1000.0)
CASES = [(HexMesh, "baudet", dict(hourglass_control=1.0)), (HexMesh, "baudet-hyperelastic", {}),
         (TetMesh, "baudet", {})]


def cut_mesh(kind):
    """A 4 x 2 x 2 block and the same block cut through at x = 2 elements (its nodes copied there)."""
    mesh = kind.block((4, 2, 2), 0.01)
    uncut = build_model(mesh, MATERIAL)
    shared = cutting.shared_faces(mesh)
    side = mesh.nodes[mesh.elements].mean(axis=1)[:, 0] < 0.02
    return mesh, cutting.separate(uncut, shared[side[shared[:, 0]] != side[shared[:, 1]]]).mesh


def model_arrays(model):
    """Every array field of ``model`` (the hourglass matrix dense), by name."""
    arrays = {}
    for field in dataclasses.fields(Model):
        value = getattr(model, field.name)
        if isinstance(value, np.ndarray):
            arrays[field.name] = value
        elif sp.issparse(value):
            arrays[field.name] = value.toarray()
        elif dataclasses.is_dataclass(value):
            arrays.update({f"{field.name}.{name}": item for name, item in vars(value).items()
                           if isinstance(item, np.ndarray)})
    return arrays


@pytest.mark.parametrize("kind, name, options", CASES)
def test_a_model_built_with_the_uncut_models_elements_is_the_model_built_alone(kind, name, options):
    mesh, cut = cut_mesh(kind)
    uncut = build_model(mesh, MATERIAL, model=name, **options)
    alone = build_model(cut, MATERIAL, model=name, **options)
    reused = build_model(cut, MATERIAL, model=name, same_elements=uncut, **options)
    expected, got = model_arrays(alone), model_arrays(reused)
    assert expected.keys() == got.keys()
    for key in expected:
        np.testing.assert_array_equal(got[key], expected[key], err_msg=key)


def test_same_elements_of_another_material_is_not_used():
    mesh, cut = cut_mesh(HexMesh)
    other = build_model(mesh, Material(2e4, 0.45, 1000.0), hourglass_control=1.0)
    alone = build_model(cut, MATERIAL, hourglass_control=1.0)
    reused = build_model(cut, MATERIAL, hourglass_control=1.0, same_elements=other)
    np.testing.assert_array_equal(reused.hourglass.toarray(), alone.hourglass.toarray())
    np.testing.assert_array_equal(reused.stiffness, alone.stiffness)


@pytest.mark.parametrize("kind", [HexMesh, TetMesh])
def test_a_padded_pattern_is_the_pattern_built_on_its_rows(kind):
    mesh = kind.block((3, 2, 2), 0.01)
    padded, built = BlockPattern(mesh.n_nodes, mesh.elements).padded(mesh.n_nodes + 7), BlockPattern(
        mesh.n_nodes + 7, mesh.elements)
    np.testing.assert_array_equal(padded.indptr, built.indptr)
    np.testing.assert_array_equal(padded.indices, built.indices)
    np.testing.assert_array_equal(padded.diagonal_positions, built.diagonal_positions)
    corners = mesh.elements
    np.testing.assert_array_equal(padded.block_positions(corners[:, :, None], corners[:, None, :]),
                                  built.block_positions(corners[:, :, None], corners[:, None, :]))


def test_entry_positions_are_those_of_the_patterns_matrix():
    mesh = HexMesh.block((3, 2, 2), 0.01)
    model = with_spare_nodes(build_model(mesh, MATERIAL, hourglass_control=1.0), mesh.n_nodes + 5)
    pattern = model.pattern
    rows = np.repeat(np.arange(pattern.n_dofs), np.diff(pattern.indptr))
    np.testing.assert_array_equal(pattern.positions(rows, pattern.indices), np.arange(pattern.nnz))
    for free in (np.arange(pattern.n_dofs), np.flatnonzero(np.arange(pattern.n_dofs) % 5 != 2)):
        whole = FreeStructure(model, free)  # the CSC entries of the free dofs: their data positions
        columns = np.repeat(np.arange(len(free)), np.diff(whole.indptr))
        np.testing.assert_array_equal(whole.columns, columns)
        np.testing.assert_array_equal(whole.take, pattern.positions(free[whole.indices], free[columns]))
    hourglass = model.hourglass.tocoo()
    np.testing.assert_array_equal(pattern.csr_positions(model.hourglass.indptr, model.hourglass.indices),
                                  pattern.positions(hourglass.row, hourglass.col))
    values = np.zeros(pattern.nnz)
    values[pattern.csr_positions(model.hourglass.indptr, model.hourglass.indices)] = model.hourglass.data
    np.testing.assert_array_equal(pattern.matrix(values).toarray(), model.hourglass.toarray())
    with pytest.raises(ValueError, match="outside the fixed sparsity pattern"):
        pattern.positions(np.array([0]), np.array([3 * (mesh.n_nodes + 4)]))  # a parked row: no coupling


def test_topology_is_shared_only_between_models_of_one_topology():
    mesh, cut = cut_mesh(HexMesh)
    uncut, other = build_model(mesh, MATERIAL), build_model(mesh, Material(2e4, 0.4, 900.0))
    share_topology(uncut, other)
    assert other.pattern is uncut.pattern
    with pytest.raises(ValueError, match="one topology"):
        share_topology(uncut, build_model(cut, MATERIAL))


@pytest.mark.parametrize("kind", [HexMesh, TetMesh])
def test_a_mesh_on_other_node_rows_is_the_mesh_built_and_checked_on_them(kind):
    mesh, cut = cut_mesh(kind)
    built = kind(cut.nodes, cut.elements)
    moved = mesh.on_nodes(cut.nodes, cut.elements, shape=None, spacing=None)
    assert type(moved) is kind and moved.shape is None and moved.spacing is None
    np.testing.assert_array_equal(moved.nodes, built.nodes)
    np.testing.assert_array_equal(moved.elements, built.elements)
    assert not moved.nodes.flags.writeable and not moved.elements.flags.writeable
    np.testing.assert_array_equal(moved.element_volumes(), built.element_volumes())
    parked = mesh.on_nodes(np.concatenate([mesh.nodes, mesh.nodes[:3]]))  # parked rows: the same elements
    assert parked.n_nodes == mesh.n_nodes + 3 and parked.shape == mesh.shape
    shifted = cut.nodes.copy()
    shifted[cut.elements[0, 0]] += 1e-3
    with pytest.raises(ValueError, match="corner is not this mesh's"):
        mesh.on_nodes(shifted, cut.elements)
    with pytest.raises(ValueError, match="element indices"):
        mesh.on_nodes(cut.nodes, cut.elements + len(cut.nodes))
    with pytest.raises(ValueError, match="finite nodes"):
        mesh.on_nodes(np.concatenate([cut.nodes, [[np.nan, 0.0, 0.0]]]), cut.elements)
    with pytest.raises(ValueError, match="element_labels"):
        mesh.on_nodes(cut.nodes, cut.elements, element_labels=np.zeros(3, dtype=int))


def test_unique_keys_is_numpys_unique():
    keys = np.random.default_rng(0).integers(0, 500, 3000)
    np.testing.assert_array_equal(unique_keys(keys), np.unique(keys))
    values, inverse = unique_keys(keys, return_inverse=True)
    expected, expected_inverse = np.unique(keys, return_inverse=True)
    np.testing.assert_array_equal(values, expected)
    np.testing.assert_array_equal(inverse, expected_inverse)
    assert unique_keys(np.zeros(0, dtype=np.int64)).size == 0


def superlu_fill(indptr, indices, nb):
    """(U indptr, U indices) of SuperLU's LU without pivoting of the symmetric pattern (A + A^T, a
    dominant diagonal, generic values: no cancellation), rows sorted: the reference fill."""
    generic = np.random.default_rng(1).uniform(0.1, 1.0, len(indices))
    matrix = sp.csr_matrix((generic, indices, indptr), shape=(nb, nb))
    matrix = (matrix + matrix.T + sp.diags(np.full(nb, 4.0 * nb))).tocsc()
    lu = sp.linalg.splu(matrix, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    assert np.array_equal(lu.perm_c, np.arange(nb)) and np.array_equal(lu.perm_r, np.arange(nb))
    upper = lu.U.tocsr()
    upper.sort_indices()
    return upper.indptr, upper.indices


@pytest.mark.parametrize("seed", range(4))
def test_the_symbolic_fill_is_superlus(seed):
    from sim_core import kernels
    rng = np.random.default_rng(seed)
    nb = int(rng.integers(20, 120))
    rows, columns = rng.integers(0, nb, (2, 3 * nb))
    keys = unique_keys(np.concatenate([rows * nb + columns, columns * nb + rows, np.arange(nb) * (nb + 1)]))
    indptr = np.zeros(nb + 1, np.int64)
    np.cumsum(np.bincount(keys // nb, minlength=nb), out=indptr[1:])
    u_indptr, u_indices = kernels.symbolic_fill(indptr, keys % nb, nb)
    expected_indptr, expected_indices = superlu_fill(indptr, keys % nb, nb)
    assert len(u_indices) > len(keys) // 2 + nb // 2  # the pattern fills
    np.testing.assert_array_equal(u_indptr, expected_indptr)
    np.testing.assert_array_equal(u_indices, expected_indices)


@pytest.mark.parametrize("spare", [0, 5])
def test_the_hourglass_layout_read_off_the_pattern_is_the_bsr_conversions(spare):
    from sim_core.models.forces import hourglass_block_map
    mesh, cut = cut_mesh(HexMesh)
    model = with_spare_nodes(build_model(cut, MATERIAL, hourglass_control=1.0), cut.n_nodes + spare)
    layout, converted = hourglass_block_map(model.hourglass, model.pattern), hourglass_block_map(model.hourglass)
    for got, expected in zip(layout, converted):
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == expected.dtype


@pytest.mark.parametrize("kind", [HexMesh, TetMesh])
def test_a_cuts_nodes_are_the_connected_corner_groups(kind):
    """Each node of a cut model is one connected group (scipy's connected components) of its
    original's element corners joined through the uncut faces."""
    from scipy.sparse.csgraph import connected_components
    mesh = kind.block((4, 3, 2), 0.01)
    uncut = build_model(mesh, MATERIAL)
    shared = cutting.shared_faces(mesh)
    rng = np.random.default_rng(2)
    for _ in range(5):
        faces = shared[rng.random(len(shared)) < 0.3]
        cut = cutting.separation(uncut, faces)
        kept = shared[~np.isin(shared[:, 0] * mesh.n_elements + shared[:, 1], faces[:, 0] * mesh.n_elements
                               + faces[:, 1])]
        n = mesh.elements.shape[1]
        a, b = kept[:, 0], kept[:, 1]
        row, i, j = np.nonzero(mesh.elements[a][:, :, None] == mesh.elements[b][:, None, :])
        size = mesh.elements.size
        graph = sp.coo_matrix((np.ones(len(row)), (a[row] * n + i, b[row] * n + j)), shape=(size, size))
        group = connected_components(graph, directed=False)[1]
        node = cut.model.mesh.elements.ravel()
        # corners of one group share a node; corners of one original in two groups do not (but for
        # groups that touched before the cut at a node only, which stay one node)
        assert all(len(np.unique(node[group == g])) == 1 for g in np.unique(group))
        np.testing.assert_array_equal(cut.origin[node], mesh.elements.ravel())
