"""The compiled topology operators on flat arrays (wcut.topology.arrays, wcut.kernels.topology)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wcut.errors import WcutError
from wcut.mesh import TetMesh, beam, tet_volumes
from wcut.topology import TetTopology, TopologyError, face_key, flip23, split_tet
from wcut.topology.arrays import TetArrays, face_neighbors
from wcut.topology.check import connected_components

from conftest import element_set, pyramid, ring, single_tet, two_tets


def small() -> TetMesh:
    return beam(4, 2, 2, size=(0.4, 0.2, 0.2))


def volume(mesh: TetMesh) -> float:
    return float(tet_volumes(mesh.vertices, mesh.tets).sum())


def slot_of_face(arrays: TetArrays, key) -> tuple[int, int]:
    """(element, corner opposite) of a face given by its vertices, in the arrays."""
    tets = arrays.tet_indices.numpy()
    for t in arrays.live_tets().tolist():
        tet = tets[t].tolist()
        if set(key) <= set(tet):
            return t, next(k for k in range(4) if tet[k] not in key)
    raise AssertionError(f"face {key} not found")


def test_face_neighbors_from_scratch_are_mutual_and_match_the_faces():
    mesh = small()
    neighbors = face_neighbors(mesh.tets)
    for t, tet in enumerate(mesh.tets.tolist()):
        for k in range(4):
            n = neighbors[t, k]
            face = set(tet) - {tet[k]}
            if n < 0:
                assert sum(face <= set(other) for other in mesh.tets.tolist()) == 1
            else:
                assert face <= set(mesh.tets[n].tolist())
                assert t in neighbors[n].tolist()


@pytest.mark.parametrize("offset", [0, 2**21])  # vertex numbers past 2**21: faces ranked, not coded
def test_face_neighbors_refuse_a_face_in_three_elements(offset):
    tets = np.array([[0, 1, 2, 3], [0, 1, 2, 4], [0, 1, 2, 5]]) + offset
    with pytest.raises(TopologyError, match=f"face \\[{offset}, {offset + 1}, {offset + 2}\\] is in more than two"):
        face_neighbors(tets)


def test_face_neighbors_do_not_depend_on_how_large_the_vertex_numbers_are():
    mesh = small()
    rng = np.random.default_rng(3)
    numbers = rng.permutation(2**22)[: mesh.vertex_count]  # past 2**21: the faces are ranked
    assert np.array_equal(face_neighbors(numbers[mesh.tets]), face_neighbors(mesh.tets))


def test_arrays_of_a_mesh_are_valid_and_give_it_back():
    mesh = small()
    arrays = TetArrays(mesh)
    arrays.check(volume(mesh))
    back = arrays.to_mesh()
    assert np.array_equal(back.tets, mesh.tets) and np.array_equal(back.vertices, mesh.vertices)


def test_check_catches_a_wrong_neighbour():
    arrays = TetArrays(small())
    neighbors = arrays.tet_neighbors.numpy()
    t = int(np.flatnonzero((neighbors >= 0).any(axis=1))[0])
    k = int(np.flatnonzero(neighbors[t] >= 0)[0])
    neighbors[t, k] = -1
    arrays.tet_neighbors.assign(neighbors)
    with pytest.raises(TopologyError, match="neighbours"):
        arrays.check()


def test_split_carries_attributes_and_records_the_vertex():
    mesh = small()
    rng = np.random.default_rng(0)
    positions = mesh.vertices + 0.01 * rng.standard_normal(mesh.vertices.shape)
    velocities = rng.standard_normal(mesh.vertices.shape)
    arrays = TetArrays(mesh, positions, velocities)
    w = np.array([0.1, 0.2, 0.3, 0.4])
    assert arrays.split_tets([5], [w]) == [None]
    v = mesh.vertex_count
    corners = mesh.tets[5]
    assert arrays.vertex_count == v + 1 and len(arrays.live_tets()) == mesh.tet_count + 3
    np.testing.assert_allclose(arrays.vertex_rest.numpy()[v], w @ mesh.vertices[corners], rtol=0, atol=1e-15)
    np.testing.assert_allclose(arrays.vertex_q.numpy()[v], w @ positions[corners], rtol=0, atol=1e-15)
    np.testing.assert_allclose(arrays.vertex_qd.numpy()[v], w @ velocities[corners], rtol=0, atol=1e-14)
    assert arrays.vertex_parents.numpy()[v].tolist() == corners.tolist()
    np.testing.assert_array_equal(arrays.vertex_weights.numpy()[v], w)
    live = arrays.live_tets()
    assert (arrays.tet_parent.numpy()[live][-3:] == 5).all() and arrays.tet_parent.numpy()[5] == 5
    arrays.check(volume(mesh), 1e-12)


@pytest.mark.parametrize("weights, reason", [
    ([0.5, 0.5, 0.0, 0.0], "inverted or flat"),  # on an edge: two flat children
    ([0.5, 0.5, 0.5, -0.5], "inverted or flat"),  # outside
    ([0.3, 0.3, 0.3, 0.3], "not an operator's input"),  # does not sum to 1
    ([np.nan, 0.5, 0.25, 0.25], "not an operator's input"),
])
def test_a_refused_split_changes_nothing(weights, reason):
    mesh = small()
    arrays = TetArrays(mesh)
    before = {name: getattr(arrays, name).numpy().copy() for name in TetArrays._TYPES}
    result = arrays.split_tets([3], [weights])
    assert result[0] is not None and reason in result[0]
    assert arrays.vertex_count == mesh.vertex_count and arrays.slot_count == mesh.tet_count
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(arrays, name).numpy(), value, err_msg=name)


def test_split_of_a_dead_or_missing_element_is_refused():
    arrays = TetArrays(small())
    assert "input" in arrays.split_tets([10_000], [[0.25] * 4])[0]
    assert arrays.split_tets([0, 0], [[0.25] * 4] * 2) == [None, None]  # slot 0 lives on: its first child
    assert "input" in arrays.split_tets([-1], [[0.25] * 4])[0]


def test_splits_grow_the_arrays_when_full_and_go_on():
    mesh = small()
    arrays = TetArrays(mesh, spare=2)
    slots = np.arange(mesh.tet_count)
    assert arrays.split_tets(slots, np.full((len(slots), 4), 0.25)) == [None] * len(slots)
    assert len(arrays.live_tets()) == 4 * mesh.tet_count and arrays.vertex_count == mesh.vertex_count + len(slots)
    arrays.check(volume(mesh), 1e-12)


def test_split_tets_rejects_mismatched_weights():
    with pytest.raises(WcutError, match="2 elements and 1 weights"):
        TetArrays(small()).split_tets([0, 1], [[0.25] * 4])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_splits_equal_the_python_operator(data):
    """Random 1-4 splits, children of earlier splits included: the same elements as
    ``operators.split_tet`` on ``TetTopology``, the same refusals, and valid arrays."""
    mesh = small()
    arrays, topo = TetArrays(mesh, spare=8), TetTopology(mesh)
    for _ in range(data.draw(st.integers(1, 12))):
        t = data.draw(st.integers(0, topo.slot_count - 1))
        raw = data.draw(st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4).filter(lambda w: sum(w) > 1e-3))
        w = np.array(raw) / sum(raw)
        w[3] = 1.0 - w[:3].sum()
        corners = set(topo.tet(t))
        slot = next(s for s in arrays.live_tets().tolist() if set(arrays.tet_indices.numpy()[s]) == corners)
        order = [arrays.tet_indices.numpy()[slot].tolist().index(v) for v in topo.tet(t)]
        w_arrays = np.zeros(4)
        w_arrays[order] = w  # the same point whatever the corner order of the two slots
        refused = arrays.split_tets([slot], [w_arrays])[0]
        try:
            split_tet(topo, t, w)
            assert refused is None
        except TopologyError:
            assert refused is not None
        arrays.check(volume(mesh), 1e-12)
        assert element_set(arrays.to_mesh()) == element_set(topo.to_mesh())


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_flips_equal_the_python_operator(data):
    """Splits then 2-3 flips of random interior faces: the same elements as ``operators.flip23``
    (quality drop included), the same refusals, the same parents, and valid arrays after
    every flip."""
    mesh = small()
    arrays, topo = TetArrays(mesh, spare=8), TetTopology(mesh)
    topo.begin_change()
    slots = data.draw(st.lists(st.integers(0, mesh.tet_count - 1), min_size=1, max_size=8, unique=True))
    weights = np.full((len(slots), 4), 0.25)
    assert arrays.split_tets(slots, weights) == [None] * len(slots)
    for t in slots:
        split_tet(topo, t, weights[0])
    drop = data.draw(st.sampled_from([0.0, 0.5]))
    for _ in range(data.draw(st.integers(1, 10))):
        interior = sorted(key for key, owners in topo.face_tets.items() if len(owners) == 2)
        key = data.draw(st.sampled_from(interior))
        refused = arrays.flip_faces([slot_of_face(arrays, key)], quality_drop=drop)[0]
        try:
            flip23(topo, key, quality_drop=drop or None)
            assert refused is None
        except TopologyError:
            assert refused is not None
        arrays.check(volume(mesh), 1e-12)
        assert element_set(arrays.to_mesh()) == element_set(topo.to_mesh())
    same_parents(arrays, topo)


def test_flip_of_a_boundary_face_is_refused():
    mesh = small()
    arrays = TetArrays(mesh)
    neighbors = arrays.tet_neighbors.numpy()
    t, k = map(int, np.argwhere(neighbors < 0)[0])
    assert "input" in arrays.flip_faces([(t, k)])[0]
    arrays.check(volume(mesh))


def test_flip_refused_when_the_new_edge_misses_the_face():
    # two elements on face (0, 1, 2) whose apices' segment passes outside the face
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2.0, 2.0, 1.0], [2.0, 2.0, -1.0]], dtype=float)
    mesh = TetMesh(vertices, np.array([[0, 1, 2, 3], [0, 2, 1, 4]]))
    arrays = TetArrays(mesh)
    t, k = slot_of_face(arrays, face_key(0, 1, 2))
    assert "does not cross" in arrays.flip_faces([(t, k)])[0]
    arrays.check(volume(mesh))


def same_parents(arrays: TetArrays, topo: TetTopology) -> None:
    """Every live element has the parent that ``topo``'s journal gives the element with the
    same corners (both take the removed element that holds the centroid by the same
    arithmetic, so that they agree on a centroid on a face two removed elements share)."""
    slot_of = {frozenset(topo.tet(t)): t for t in topo.live_tets().tolist()}
    tets, parents = arrays.tet_indices.numpy(), arrays.tet_parent.numpy()
    for t in arrays.live_tets().tolist():
        assert parents[t] == topo._journal.origin_of(slot_of[frozenset(tets[t])]), tets[t]


def random_weights(data, count: int) -> np.ndarray:
    raw = data.draw(st.lists(st.floats(0.0, 1.0), min_size=count, max_size=count).filter(lambda w: sum(w) > 1e-3))
    w = np.array(raw) / sum(raw)
    w[-1] = 1.0 - w[:-1].sum()
    return w


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_every_operator_equals_the_python_one(data):
    """Random sequences of all five operators (1-4 split, 2-3 flip, face split on the
    boundary and inside, general flip of interior and boundary edges, bisection): the same
    elements as the Python operators on ``TetTopology`` (the general flip's polygon started
    where the compiled one starts it), the same refusals, valid arrays after every operator,
    and the same parents."""
    from wcut.topology import bisect_edge, remove_edge, split_face

    mesh = small()
    arrays, topo = TetArrays(mesh, spare=8), TetTopology(mesh)
    topo.begin_change()
    for _ in range(data.draw(st.integers(1, 14))):
        kind = data.draw(st.sampled_from(["split_tet", "flip", "split_face", "remove_edge", "bisect"]))
        if kind == "split_tet":
            t = data.draw(st.sampled_from(topo.live_tets().tolist()))
            w = random_weights(data, 4)
            slot = next(s for s in arrays.live_tets().tolist() if set(arrays.tet_indices.numpy()[s]) == set(topo.tet(t)))
            order = [arrays.tet_indices.numpy()[slot].tolist().index(v) for v in topo.tet(t)]
            w_arrays = np.zeros(4)
            w_arrays[order] = w
            refused = arrays.split_tets([slot], [w_arrays])[0]
            python = lambda: split_tet(topo, t, w)  # noqa: E731
        elif kind in ("flip", "split_face"):
            keys = sorted(topo.face_tets)
            key = data.draw(st.sampled_from(keys))
            if kind == "flip":
                if len(topo.face_tets[key]) != 2:
                    continue
                refused = arrays.flip_faces([slot_of_face(arrays, key)], quality_drop=0.1)[0]
                python = lambda: flip23(topo, key, quality_drop=0.1)  # noqa: E731
            else:
                w = random_weights(data, 3)
                refused = arrays.split_faces([key], [w])[0]
                python = lambda: split_face(topo, key, w)  # noqa: E731
        else:
            edges = sorted({tuple(sorted((tet[i], tet[j]))) for t in topo.live_tets().tolist()
                            for tet in [topo.tet(t)] for i in range(4) for j in range(i + 1, 4)})
            a, b = data.draw(st.sampled_from(edges))
            if kind == "remove_edge":
                refused = arrays.remove_edges([(a, b)])[0]
                python = lambda: remove_edge(topo, a, b, canonical=True)  # noqa: E731
            else:
                s = data.draw(st.floats(0.05, 0.95))
                refused = arrays.bisect_edges([(a, b)], [s])[0]
                python = lambda: bisect_edge(topo, a, b, s)  # noqa: E731
        try:
            python()
            assert refused is None, (kind, refused)
        except TopologyError as exc:
            assert refused is not None, (kind, str(exc))
        arrays.check(volume(mesh), 1e-12)
        assert element_set(arrays.to_mesh()) == element_set(topo.to_mesh()), kind
    same_parents(arrays, topo)


def unchanged_after(arrays: TetArrays, operator, *args) -> str:
    """Run a refused operator; assert it changed nothing; return why it was refused."""
    before = {name: getattr(arrays, name).numpy().copy() for name in TetArrays._TYPES}
    counts = arrays.counts.numpy().copy()
    reason = operator(*args)[0]
    assert reason is not None
    np.testing.assert_array_equal(arrays.counts.numpy(), counts)
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(arrays, name).numpy(), value, err_msg=name)
    return reason


@pytest.mark.parametrize("n", [3, 4, 5, 6, 7])
def test_general_flip_of_a_ring_gives_2n_minus_4_elements(n):
    mesh = ring(n)
    arrays = TetArrays(mesh)
    assert arrays.remove_edges([(0, 1)]) == [None]
    assert len(arrays.live_tets()) == 2 * (n - 2)
    tets = arrays.tet_indices.numpy()[arrays.live_tets()]
    assert not any({0, 1} <= set(tet) for tet in tets.tolist())  # the edge is gone
    arrays.check(volume(mesh), 1e-12)


def test_general_flip_of_a_boundary_edge_keeps_a_flat_boundary_and_refuses_a_bent_one():
    flat = TetArrays(pyramid(0.0))
    assert flat.remove_edges([(0, 1)]) == [None]
    flat.check(volume(pyramid(0.0)), 1e-12)
    bent = TetArrays(pyramid(0.3))
    assert "change the volume" in unchanged_after(bent, bent.remove_edges, [(0, 1)])


@pytest.mark.parametrize("factory, operator, args, reason", [
    (single_tet, "remove_edges", ([(0, 1)],), "inverted or flat"),  # two vertices around it
    (two_tets, "remove_edges", ([(3, 4)],), "no such"),
    (two_tets, "bisect_edges", ([(3, 4)], [0.5]), "no such"),
    (two_tets, "bisect_edges", ([(0, 1)], [1.0]), "input"),
    (two_tets, "bisect_edges", ([(0, 1)], [np.nan]), "input"),
    (two_tets, "split_faces", ([(0, 3, 4)], [[0.2, 0.3, 0.5]]), "no such"),
    (two_tets, "split_faces", ([(0, 1, 2)], [[0.5, 0.5, 0.0]]), "inverted or flat"),
    (two_tets, "split_faces", ([(0, 1, 2)], [[0.5, 0.5, 0.5]]), "input"),
])
def test_refused_operators_change_nothing(factory, operator, args, reason):
    arrays = TetArrays(factory())
    assert reason in unchanged_after(arrays, getattr(arrays, operator), *args)


def test_face_splits_and_bisections_add_one_vertex_each():
    mesh = two_tets()
    arrays = TetArrays(mesh)
    assert arrays.split_faces([(0, 1, 2), (0, 1, 3)], [[0.2, 0.3, 0.5], [0.3, 0.3, 0.4]]) == [None, None]
    assert len(arrays.live_tets()) == 2 + 4 + 2  # 2-6 inside, then 1-3 of a boundary face
    assert arrays.bisect_edges([(3, 4)], [0.5]) == ["no such face or edge (or too many elements around it)"]
    assert arrays.bisect_edges([(0, 5)], [0.25]) == [None]  # an edge to the first new vertex
    assert arrays.vertex_count == mesh.vertex_count + 3
    v = mesh.vertex_count + 2
    assert arrays.vertex_parents.numpy()[v].tolist() == [0, 5, -1, -1]
    np.testing.assert_array_equal(arrays.vertex_weights.numpy()[v], [0.75, 0.25, 0.0, 0.0])
    arrays.check(volume(mesh), 1e-12)


def test_operators_grow_the_arrays_when_full():
    mesh = ring(6)
    arrays = TetArrays(mesh, spare=1)
    assert arrays.bisect_edges([(0, 1)], [0.5]) == [None]
    assert len(arrays.live_tets()) == 12
    arrays.check(volume(mesh), 1e-12)


def interior_faces_at(arrays: TetArrays, x: float) -> list[tuple[int, int]]:
    """(element, corner opposite) of the interior faces whose vertices all have rest x = ``x``,
    one side each."""
    rest, tets = arrays.vertex_rest.numpy(), arrays.tet_indices.numpy()
    neighbors = arrays.tet_neighbors.numpy()
    faces = []
    for t in arrays.live_tets().tolist():
        for k in range(4):
            corners = [v for i, v in enumerate(tets[t].tolist()) if i != k]
            if neighbors[t, k] > t and np.allclose(rest[corners, 0], x):
                faces.append((t, k))
    return faces


def test_disconnect_along_a_plane_of_faces_parts_the_mesh():
    mesh = small()
    arrays = TetArrays(mesh)
    faces = interior_faces_at(arrays, 0.2)
    tets = arrays.tet_indices.numpy()
    vertices = sorted({v for t, k in faces for i, v in enumerate(tets[t].tolist()) if i != k})
    assert len(vertices) == 9
    assert arrays.disconnect(faces, vertices) == 9
    arrays.check(volume(mesh), 1e-12)
    cut = arrays.to_mesh()
    assert cut.vertex_count == mesh.vertex_count + 9
    assert len(set(connected_components(cut).tolist())) == 2
    copies = np.arange(mesh.vertex_count, cut.vertex_count)
    originals = arrays.vertex_parents.numpy()[copies, 0]
    assert originals.tolist() == vertices
    np.testing.assert_array_equal(cut.vertices[copies], cut.vertices[originals])


def test_disconnect_sews_again_the_faces_at_the_front_of_a_partial_cut():
    mesh = small()
    arrays = TetArrays(mesh)
    rest, tets = arrays.vertex_rest.numpy(), arrays.tet_indices.numpy()
    faces = [(t, k) for t, k in interior_faces_at(arrays, 0.2)
             if rest[[v for i, v in enumerate(tets[t].tolist()) if i != k], 1].max() < 0.1 + 1e-9]
    vertices = sorted({v for t, k in faces for i, v in enumerate(tets[t].tolist()) if i != k})
    copies = arrays.disconnect(faces, vertices)
    arrays.check(volume(mesh), 1e-12)
    # the vertices on the boundary y = 0 open; those at y = 0.1 (the front) stay whole
    assert copies == int(np.sum(np.isclose(rest[vertices, 1], 0.0)))
    cut = arrays.to_mesh()
    assert len(set(connected_components(cut).tolist())) == 1


def test_disconnect_refuses_a_boundary_face_and_grows_when_full():
    mesh = small()
    arrays = TetArrays(mesh)
    neighbors = arrays.tet_neighbors.numpy()
    t, k = map(int, np.argwhere(neighbors < 0)[0])
    with pytest.raises(TopologyError, match="input"):
        arrays.disconnect([(t, k)], [])
    full = TetArrays(mesh, spare=1)
    faces = interior_faces_at(full, 0.2)
    tets = full.tet_indices.numpy()
    vertices = sorted({v for t, k in faces for i, v in enumerate(tets[t].tolist()) if i != k})
    assert full.disconnect(faces, vertices) == 9
    full.check(volume(mesh), 1e-12)


def plane_pieces(topo: TetTopology, pieces) -> list:
    """Keys of the interior faces of ``topo`` on pieces of planes: (axis, c, other, bound) for
    x_axis = c where x_other stays below the bound (crossing partial cuts)."""
    x = topo.rest_positions
    keys = set()
    for axis, c, other, bound in pieces:
        keys |= {key for key, owners in topo.face_tets.items() if len(owners) == 2
                 and np.allclose(x[list(key), axis], c) and x[list(key), other].max() <= bound + 1e-9}
    return sorted(keys)


def python_disconnect(topo: TetTopology, keys: list) -> list[int]:
    """``unsew_face`` for each key, ``duplicate_vertex`` of their vertices in increasing
    order, ``sew_unopened``: the copies."""
    from wcut.topology import duplicate_vertex, sew_unopened, unsew_face

    for key in keys:
        unsew_face(topo, key)
    copies = [w for v in sorted({v for key in keys for v in key}) for w in duplicate_vertex(topo, v)]
    sew_unopened(topo)
    return copies


def test_disconnect_sews_again_a_face_whose_elements_move_to_the_same_copy():
    """Two crossing partial cuts (x = 0.1 for y <= 0.2, y = 0.1 for z <= 0.1): a face unsewn
    at the front of one joins two elements of the same fan of a vertex of the other, whose
    copy they both take; ``TetTopology.retarget`` then sews it again, and so must the
    compiled one (otherwise it makes a copy more)."""
    mesh = beam(3, 3, 3, size=(0.3, 0.3, 0.3))
    arrays, topo = TetArrays(mesh), TetTopology(mesh)
    keys = plane_pieces(topo, [(0, 0.1, 1, 0.2), (1, 0.1, 2, 0.1)])
    copies = python_disconnect(topo, keys)
    assert arrays.disconnect([slot_of_face(arrays, key) for key in keys], sorted({v for k in keys for v in k})) \
        == len(copies) == 12
    np.testing.assert_array_equal(arrays.to_mesh().tets, topo.to_mesh().tets)
    arrays.check(volume(mesh), 1e-12)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_disconnect_equals_the_python_operators(data):
    """Interior faces (random ones, or on crossing pieces of planes) of a mesh split by a
    few random 1-4 splits, unsewn, then their vertices duplicated in increasing order: the
    same elements (slot by slot), copies and boundary as ``unsew_face``, ``duplicate_vertex``
    and ``sew_unopened`` on ``TetTopology``."""
    mesh = beam(3, 3, 3, size=(0.3, 0.3, 0.3))
    arrays, topo = TetArrays(mesh, spare=4), TetTopology(mesh)
    for t in data.draw(st.lists(st.sampled_from(range(mesh.tet_count)), max_size=3, unique=True)):
        w = random_weights(data, 4)
        if arrays.split_tets([t], [w])[0] is None:
            split_tet(topo, t, w)
    np.testing.assert_array_equal(arrays.to_mesh().tets, topo.to_mesh().tets)
    interior = sorted(key for key, owners in topo.face_tets.items() if len(owners) == 2)
    if data.draw(st.booleans()):
        piece = st.tuples(st.sampled_from([0, 1, 2]), st.sampled_from([0.1, 0.2]), st.sampled_from([0, 1, 2]),
                          st.sampled_from([0.1, 0.2, 0.3]))
        keys = plane_pieces(topo, data.draw(st.lists(piece.filter(lambda p: p[0] != p[2]), min_size=1, max_size=3)))
    else:
        keys = data.draw(st.lists(st.sampled_from(interior), min_size=1, max_size=25, unique=True))
    vertices = sorted({v for key in keys for v in key})
    copies = python_disconnect(topo, keys)
    assert arrays.disconnect([slot_of_face(arrays, key) for key in keys], vertices) == len(copies)
    arrays.check(volume(mesh), 1e-12)
    np.testing.assert_array_equal(arrays.to_mesh().tets, topo.to_mesh().tets)
    np.testing.assert_array_equal(arrays.to_mesh().vertices, topo.to_mesh().vertices)
    neighbors = arrays.tet_neighbors.numpy()
    for t in topo.live_tets().tolist():  # boundary where the topology has a face with one element
        for k, key in enumerate(face_key(*(topo.tet(t)[:k] + topo.tet(t)[k + 1:])) for k in range(4)):
            assert (neighbors[t, k] < 0) == (len(topo.face_tets[key]) == 1)
