"""sim_core.cutting.separate (-> Model) and separation (with the nodes' origin): cutting elements apart along shared faces gives the model of the mesh
born with that cut (checked against blocks built apart), duplicates exactly the nodes the cut
separates, and carries states across."""

import numpy as np
import pytest

import sim_core
from sim_core import HexMesh, Material, TetMesh, build_model, cutting
from sim_core.models.forces import internal_forces, stiffness_data
from sim_core.solvers.static import zero_energy_modes

MATERIAL = Material(1e4, 0.45, 1000.0)
CASES = [(HexMesh, "baudet"), (HexMesh, "baudet-hyperelastic"), (TetMesh, "baudet"), (TetMesh, "baudet-hyperelastic")]


def faces_across(mesh, x, below=None):
    """The shared faces between elements on either side of the plane at ``x`` (elements whose
    centroid has y below ``below`` only, when given)."""
    shared = cutting.shared_faces(mesh)
    centre = mesh.nodes[mesh.elements].mean(axis=1)
    side = centre[:, 0] < x
    across = side[shared[:, 0]] != side[shared[:, 1]]
    if below is not None:
        across &= (centre[shared[:, 0], 1] > below)
    return shared[across]


def matched(a, b):
    """(k,) the index in ``b`` (M, 3) of each point of ``a`` (k, 3) (to 0.1 um)."""
    where = {tuple(key): i for i, key in enumerate(np.round(b * 1e7).astype(np.int64))}
    return np.array([where[tuple(key)] for key in np.round(a * 1e7).astype(np.int64)])


@pytest.mark.parametrize("kind, name", CASES)
def test_a_cut_through_the_block_gives_the_two_blocks_built_apart(kind, name):
    """A 4x2x2 block cut along the plane x = 0.2 m is, node for node, the two 2x2x2 blocks built
    apart and moved 1 um along x (so that their nodes differ): the same forces at a random
    deformation (to 1e-9) and the same stiffness at rest; the 9 plane nodes get one copy each and the
    cut model has the zero-energy modes of two free bodies."""
    mesh = kind.block((4, 2, 2), 0.1)
    model = build_model(mesh, MATERIAL, model=name)
    separation = cutting.separation(model, faces_across(mesh, 0.2))
    cut = separation.model
    direct = cutting.separate(model, faces_across(mesh, 0.2))  # the contract's form: the Model alone
    assert isinstance(direct, sim_core.Model) and np.array_equal(direct.mesh.elements, cut.mesh.elements)
    assert cut.n_nodes == mesh.n_nodes + 9 and separation.added == 9
    left = kind.block((2, 2, 2), 0.1)
    right = kind(left.nodes + np.array([0.2, 0.0, 0.0]), left.elements)
    apart = kind(np.concatenate([left.nodes, right.nodes + np.array([1e-6, 0, 0])]),
                 np.concatenate([left.elements, right.elements + left.n_nodes]))
    reference = build_model(apart, MATERIAL, model=name)
    # two free bodies: their 12 rigid modes (hexahedral "baudet" without hourglass control adds its
    # blocks' hourglass modes, as the blocks built apart have them)
    assert zero_energy_modes(cut)[0] == zero_energy_modes(reference)[0]
    assert zero_energy_modes(cut)[0] == 12 or (kind is HexMesh and name == "baudet")
    # the cut model's nodes on the right of the plane (elements there) are the shifted ones
    on_right = np.zeros(cut.n_nodes, bool)
    centre = mesh.nodes[mesh.elements].mean(axis=1)[:, 0]
    on_right[np.unique(cut.mesh.elements[centre > 0.2])] = True
    shifted = cut.mesh.nodes + np.where(on_right[:, None], [1e-6, 0, 0], 0.0)
    index = matched(shifted, apart.nodes)
    np.testing.assert_allclose(apart.nodes[index], shifted, atol=1e-12)
    rng = np.random.default_rng(0)
    displacement = 0.005 * rng.standard_normal((cut.n_nodes, 3))
    ours = internal_forces(cut, cut.mesh.nodes + displacement)
    moved = np.empty_like(apart.nodes)
    moved[index] = apart.nodes[index] + displacement
    theirs = internal_forces(reference, moved)[index]
    assert np.abs(ours - theirs).max() < 1e-9 * np.abs(theirs).max()
    dofs = (3 * index[:, None] + np.arange(3)).ravel()
    ours = cut.pattern.matrix(stiffness_data(cut, cut.mesh.nodes)).toarray()
    theirs = reference.pattern.matrix(stiffness_data(reference, apart.nodes)).toarray()[np.ix_(dofs, dofs)]
    assert np.abs(ours - theirs).max() < 1e-9 * np.abs(theirs).max()


@pytest.mark.parametrize("kind", [HexMesh, TetMesh])
def test_a_crack_duplicates_its_faces_nodes_but_not_its_front(kind):
    """A crack from the top of a 4x2x2 block down to y = 0.1 m at x = 0.2 m: the nodes strictly above
    the front (y = 0.2: 3 of them) get a copy, the front's (y = 0.1) do not, and the block stays one
    body (6 zero-energy modes). States carry across: each copy where its original is."""
    mesh = kind.block((4, 2, 2), 0.1)
    model = build_model(mesh, MATERIAL, model="baudet-hyperelastic")
    separation = cutting.separation(model, faces_across(mesh, 0.2, below=0.1))
    assert separation.added == 3
    copied = separation.origin[mesh.n_nodes:]
    np.testing.assert_allclose(mesh.nodes[copied][:, [0, 1]], [[0.2, 0.2]] * 3)
    assert zero_energy_modes(separation.model)[0] == 6
    np.testing.assert_array_equal(separation.origin[:mesh.n_nodes], np.arange(mesh.n_nodes))
    state = model.new_state()
    state.positions = state.positions + np.random.default_rng(1).standard_normal(state.positions.shape)
    carried = separation.state(state)
    np.testing.assert_array_equal(carried.positions, state.positions[separation.origin])


def test_elements_touching_at_a_node_only_stay_joined_there():
    """Three hexahedra: A and B share a face, C touches B at one corner only. Cutting A from B copies
    the 4 nodes of their face and not the corner C shares with B."""
    block = HexMesh.block((2, 1, 1), 0.1)
    corner = int(np.flatnonzero(np.all(np.isclose(block.nodes, [0.2, 0.1, 0.1]), axis=1))[0])
    extra = HexMesh.block((1, 1, 1), 0.1)
    nodes = np.concatenate([block.nodes, extra.nodes[1:] + 0.1 + np.array([0.1, 0.0, 0.0])])
    mapping = np.r_[corner, block.n_nodes + np.arange(extra.n_nodes - 1)]
    mesh = HexMesh(nodes, np.concatenate([block.elements, mapping[extra.elements]]))
    model = build_model(mesh, MATERIAL, model="baudet-hyperelastic")
    separation = cutting.separation(model, [[0, 1]])
    assert separation.added == 4 and corner not in separation.origin[mesh.n_nodes:]


def test_bad_faces_name_what_is_wrong():
    model = build_model(TetMesh.block((2, 1, 1), 0.1), MATERIAL)
    with pytest.raises(ValueError, match="share no face"):
        cutting.separate(model, [[0, model.mesh.n_elements - 1]])
    with pytest.raises(ValueError, match=r"must lie in \[0, 11\]"):
        cutting.separate(model, [[0, 12]])
    with pytest.raises(ValueError, match=r"\(F, 2\) integer array"):
        cutting.separate(model, [0.5, 1.5])
    nothing = cutting.separation(model, np.zeros((0, 2), int))
    assert nothing.model is model and nothing.added == 0
    assert cutting.separate(model, np.zeros((0, 2), int)) is model


def test_a_cut_world_steps_in_a_stack_as_alone():
    """The cut model in one world of a ModelStack (spare node rows for its copies) steps, implicit,
    as the cut model alone, bit for bit, while the uncut worlds step as the uncut model."""
    mesh = TetMesh.block((4, 2, 2), 0.05)
    model = build_model(mesh, MATERIAL, gravity=(0, -9.81, 0))
    separation = cutting.separation(model, faces_across(mesh, 0.1, below=0.05))
    stack = sim_core.ModelStack(model, 2, spare_nodes=separation.added)
    stack.assign(1, separation.model)
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    control = stack.new_control()
    control.fixed[:, clamp] = True
    control.target[:, clamp] = mesh.nodes[clamp]
    solver = sim_core.make_solver("implicit", stack)
    state, scratch = stack.new_state(), stack.new_state()
    for _ in range(5):
        solver.step(state, scratch, control, 0.01)
        state, scratch = scratch, state
    cut = separation.model
    alone = sim_core.make_solver("implicit", cut)
    one, other = cut.new_state(), cut.new_state()
    single = cut.new_control()
    single.fixed[clamp], single.target[clamp] = True, mesh.nodes[clamp]
    for _ in range(5):
        alone.step(one, other, single, 0.01)
        one, other = other, one
    np.testing.assert_array_equal(state.positions[1, :cut.n_nodes], one.positions)
    assert np.abs(one.positions - cut.mesh.nodes).max() > 1e-4


@pytest.mark.parametrize("kind", [HexMesh, TetMesh])
def test_a_blade_swept_through_the_block_cuts_the_faces_on_its_path(kind):
    """A blade edge along z at x = 0.2 m moved from above the block to below it crosses exactly the
    faces between the elements on either side of the plane; stopped at y = 0.1 m it cuts the top
    layer only (a crack: the 3 nodes above its front get copies)."""
    mesh = kind.block((4, 2, 2), 0.1)
    model = build_model(mesh, MATERIAL, model="baudet-hyperelastic")
    edge = lambda y: [[0.2001, y, -0.1], [0.2001, y, 0.3]]  # noqa: E731
    through = cutting.blade_faces(model, mesh.nodes, edge(0.3), edge(-0.1))
    assert {tuple(pair) for pair in through} == {tuple(pair) for pair in faces_across(mesh, 0.2)}
    crack = cutting.blade_faces(model, mesh.nodes, edge(0.3), edge(0.1))
    assert {tuple(pair) for pair in crack} == {tuple(pair) for pair in faces_across(mesh, 0.2, below=0.1)}
    assert cutting.separation(model, crack).added == 3
    with pytest.raises(ValueError, match=r"edge_from must be the blade edge's two ends"):
        cutting.blade_faces(model, mesh.nodes, [0.0, 0.0, 0.0], edge(0.0))


def test_a_slanted_blade_cuts_along_faces_within_half_an_element_of_its_path():
    """A blade swept along a plane that no face lies in (normal (1, 0.3, 0.2)) through an 8x4x4 block
    of tetrahedra: every cut face's centroid lies within half an element (0.05 m) of the swept plane,
    the cut separates the block in two (12 zero-energy modes), and no element is lost."""
    mesh = TetMesh.block((8, 4, 4), 0.05)
    model = build_model(mesh, MATERIAL)
    normal = np.array([1.0, 0.3, 0.2]) / np.linalg.norm([1.0, 0.3, 0.2])
    point = np.array([0.2, 0.1, 0.1])
    along = np.cross(normal, [0.0, 1.0, 0.0])
    along /= np.linalg.norm(along)
    down = np.cross(normal, along)  # in the plane, across the block
    edge = lambda s: point + s * down + np.array([-1.0, 1.0])[:, None] * along  # noqa: E731
    faces = cutting.blade_faces(model, mesh.nodes, edge(-1.0), edge(1.0))
    shared_nodes = [np.intersect1d(mesh.elements[a], mesh.elements[b]) for a, b in faces]
    distance = np.array([abs((mesh.nodes[nodes].mean(axis=0) - point) @ normal) for nodes in shared_nodes])
    assert len(faces) > 0 and distance.max() <= 0.05
    separation = cutting.separation(model, faces)
    assert separation.model.mesh.n_elements == mesh.n_elements
    assert zero_energy_modes(separation.model)[0] == 12


def test_cut_world_cuts_one_world_mid_episode_without_adding_energy():
    """Three worlds sagging under gravity; world 1 is cut through at x = 0.1 m after 5 steps
    (cut_world): its nodes keep their positions and velocities (the kinetic energy is the same
    to the last bit), the other worlds step on as before, and the cut world then steps as its cut
    model alone from the carried state (the free part falls away from the clamped one)."""
    mesh = TetMesh.block((4, 2, 2), 0.05)
    model = build_model(mesh, MATERIAL, gravity=(0, -9.81, 0))
    stack = sim_core.ModelStack(model, 3, spare_nodes=9)
    clamp = np.flatnonzero(np.isclose(mesh.nodes[:, 0], 0.0))
    control = stack.new_control()
    control.fixed[:, clamp], control.target[:, clamp] = True, mesh.nodes[clamp]
    solver = sim_core.make_solver("implicit", stack)
    state, scratch = stack.new_state(), stack.new_state()
    for _ in range(5):
        solver.step(state, scratch, control, 0.01)
        state, scratch = scratch, state
    before = state.positions.copy(), state.velocities.copy()
    kinetic = 0.5 * np.sum(model.mass[:, None] * before[1][1, :mesh.n_nodes] ** 2)
    edge = lambda y: [[0.1001, y, -0.1], [0.1001, y, 0.2]]  # noqa: E731
    faces = cutting.blade_faces(model, state.positions[1, :mesh.n_nodes], edge(0.3), edge(-0.2))
    separation = cutting.cut_world(stack, state, 1, faces, solver)
    assert separation.added == 9 and not stack.shared[1]
    cut = separation.model
    after = 0.5 * np.sum(cut.mass[:, None] * state.velocities[1, :cut.n_nodes] ** 2)
    assert after == pytest.approx(kinetic, rel=1e-12)
    np.testing.assert_array_equal(state.positions[[0, 2]], before[0][[0, 2]])
    alone = sim_core.make_solver("implicit", cut)
    one = sim_core.State(state.positions[1, :cut.n_nodes].copy(), state.velocities[1, :cut.n_nodes].copy())
    other = cut.new_state()
    single = cut.new_control()
    single.fixed[clamp], single.target[clamp] = True, mesh.nodes[clamp]
    for _ in range(5):
        solver.step(state, scratch, control, 0.01)
        state, scratch = scratch, state
        alone.step(one, other, single, 0.01)
        one, other = other, one
    np.testing.assert_array_equal(state.positions[1, :cut.n_nodes], one.positions)
    free = cut.mesh.nodes[:, 0] > 0.1
    assert one.positions[free, 1].mean() < state.positions[0, :mesh.n_nodes][mesh.nodes[:, 0] > 0.1, 1].mean()
    with pytest.raises(ValueError, match="spare_nodes"):
        cutting.cut_world(sim_core.ModelStack(model, 1), sim_core.State(
            state.positions[:1, :mesh.n_nodes].copy(), state.velocities[:1, :mesh.n_nodes].copy()), 0, faces)


def test_cuts_in_steps_keep_a_crack_that_copied_no_node():
    """Three of the four faces around a node inside a 4x4x4 block (an L, the node on its front) copy no
    node: ``separation`` gives the model itself. Cut the fourth in a second step:
    ``cut_world(..., uncut=...)`` holds the uncut model cut along all four (the node copied), as one
    separation of the union does, and carries the state through ``carried_nodes``; cutting the
    current model with the fourth face alone would have copied nothing."""
    mesh = HexMesh.block((4, 4, 4), 0.05)
    model = build_model(mesh, MATERIAL, model="baudet-hyperelastic")
    plane = faces_across(mesh, 0.1)
    centre = mesh.nodes[mesh.elements].mean(axis=1)[plane[:, 0]]
    around = plane[np.all((centre[:, 1:] > 0.05) & (centre[:, 1:] < 0.15), axis=1)]  # the 4 faces at node (0.1, 0.1, 0.1)
    assert len(around) == 4
    first, last = around[:3], around[3:]
    assert cutting.separation(model, first).model is model
    assert cutting.separation(model, last).model is model  # the current model, cut on its own: nothing
    together = cutting.separation(model, around)
    assert together.added == 1
    stack = sim_core.ModelStack(model, 2, spare_nodes=1)
    state = stack.new_state()
    state.positions += np.random.default_rng(3).standard_normal(state.positions.shape) * 1e-3
    before = state.positions[1, :model.n_nodes].copy()
    cutting.cut_world(stack, state, 1, first, uncut=model)
    assert stack.given[1] is model
    cutting.cut_world(stack, state, 1, around, uncut=model)
    cut = stack.given[1]
    np.testing.assert_array_equal(cut.mesh.elements, together.model.mesh.elements)
    np.testing.assert_array_equal(cutting.carried_nodes(model, cut), together.origin)
    np.testing.assert_array_equal(state.positions[1, :cut.n_nodes], before[together.origin])
