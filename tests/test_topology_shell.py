"""Tests of wcut.topology.shell: the local operators of quadratic shells (open an edge, move a
node, split a triangle), the change record they return, its composition, and the rebuild of a
shell model from it (thesis 6.2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wcut import shell
from wcut.mesh import SHEET_PATTERNS, ShellMesh, precut_sheet, rectangle_sheet
from wcut.topology import TopologyError, connected_components
from wcut.topology.change import compose
from wcut.topology.shell import (check_shell, edge_key, edge_users, locate, move_nodes, open_edges, shape_weights,
                                 split_triangle, triangle_qualities, vertex_fan_counts)

FAST = dict(deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow])

SIZE = 0.1  # m, side of the test sheets

# ---------------------------------------------------------------------------------------------
# helpers


def sheet(kind: str) -> ShellMesh:
    """The sheets the opening tests run on: 4x4-cell rectangles of both diagonal patterns and
    a precut sheet whose slit ends at (SIZE / 4, SIZE / 2)."""
    if kind == "precut":
        return precut_sheet(4, 4, (SIZE, SIZE), notch_length=SIZE / 4)
    return rectangle_sheet(4, 4, (SIZE, SIZE), pattern=kind)


SHEETS = ["alternate", "right", "precut"]


def cylinder(mesh: ShellMesh, radius: float) -> ShellMesh:
    """``mesh`` bent onto a cylinder of axis y: (x, y) -> (R sin(x/R), y, R (1 - cos(x/R))).
    Every node, edge nodes included, is on the cylinder, so the elements are curved."""
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    bent = np.column_stack([radius * np.sin(x / radius), y, radius * (1.0 - np.cos(x / radius))])
    return ShellMesh(bent, mesh.triangles, name=f"cylinder({radius})")


def components(mesh: ShellMesh) -> int:
    """Pieces of a sheet: triangles sharing a corner edge (not just a node) are connected."""
    return int(connected_components(mesh).max()) + 1


def carry(values: np.ndarray, change) -> np.ndarray:
    """Per-vertex ``values`` (N, k) after ``change``: the weighted sum of their sources."""
    return np.einsum("vk,vkj->vj", change.vertex_weights, values[change.vertex_sources])


def quadratic_field(X: np.ndarray) -> np.ndarray:
    """A vector field (N, 3) quadratic in the rest position, with every quadratic term."""
    x, y, z = X.T
    return np.column_stack([3.0 * x * x - 2.0 * x * y + y + 0.5,
                            x * y + 4.0 * y * y - x + 0.1 * z,
                            -x * x + y * y + 2.0 * x * y + z])


def node_at(mesh: ShellMesh, point) -> int:
    """The corner of ``mesh`` at ``point`` (the one of lowest index when duplicated)."""
    corners = mesh.corner_ids
    d = np.linalg.norm(mesh.vertices[corners] - np.asarray(point, dtype=np.float64), axis=1)
    hit = corners[d < 1e-12 * SIZE]
    assert len(hit), f"no corner at {point}"
    return int(hit.min())


def notch_tip(mesh: ShellMesh) -> int:
    """The tip of a precut sheet's slit: the boundary corner whose two boundary neighbours are
    two copies of one point (the slit's last vertex, below and above)."""
    neighbours: dict[int, list[int]] = {}
    for a, b, _ in mesh.boundary_edges().tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    X = mesh.vertices
    tips = [v for v, n in neighbours.items() if len(n) == 2 and n[0] != n[1] and np.array_equal(X[n[0]], X[n[1]])]
    assert len(tips) == 1, tips
    return tips[0]


def crack_start(mesh: ShellMesh, kind: str) -> int:
    """Where a crack along y = SIZE / 2 starts: the notch tip, or the middle of the left side."""
    return notch_tip(mesh) if kind == "precut" else node_at(mesh, (0.0, SIZE / 2, 0.0))


def line_edges(mesh: ShellMesh, start: int) -> list[tuple[int, int]]:
    """The corner edges along y = y(start) from ``start`` to the right side of the sheet."""
    X, y = mesh.vertices, mesh.vertices[start, 1]
    corners = [c for c in mesh.corner_ids.tolist() if abs(X[c, 1] - y) < 1e-12 and X[c, 0] >= X[start, 0] - 1e-12]
    by_x: dict[float, int] = {}
    for c in corners:  # one corner per x (the lowest index where the slit duplicated one)
        key = round(float(X[c, 0]) / SIZE, 9)
        by_x[key] = min(by_x.get(key, c), c)
    chain = [by_x[k] for k in sorted(by_x)]
    assert chain[0] == start
    return list(zip(chain[:-1], chain[1:]))


def arrays(mesh: ShellMesh) -> tuple[np.ndarray, np.ndarray]:
    return mesh.vertices.copy(), mesh.triangles.copy()


def assert_same_arrays(mesh: ShellMesh, saved) -> None:
    assert np.array_equal(mesh.vertices, saved[0]) and np.array_equal(mesh.triangles, saved[1])


def assert_duplicates_are_copies(before: ShellMesh, after: ShellMesh, change) -> None:
    """Every new vertex of an opening is a copy (weight 1) of one old vertex, at its place."""
    new = change.new_vertices
    assert np.array_equal(new, np.arange(before.vertex_count, after.vertex_count))
    assert np.array_equal(change.vertex_weights[new].sum(axis=1), np.ones(len(new)))
    assert (np.count_nonzero(change.vertex_weights[new], axis=1) == 1).all()
    np.testing.assert_array_equal(after.vertices[new], before.vertices[change.vertex_sources[new, 0]])
    np.testing.assert_array_equal(after.vertices[: before.vertex_count], before.vertices)


# ---------------------------------------------------------------------------------------------
# open_edges


@pytest.mark.parametrize("kind", SHEETS)
def test_opening_one_edge_from_the_crack_start_duplicates_the_start_and_the_edge_node(kind):
    mesh = sheet(kind)
    area = mesh.area()
    start = crack_start(mesh, kind)
    (a, b), *_ = line_edges(mesh, start)
    users = edge_users(mesh.triangles)[edge_key(a, b)]
    assert len(users) == 2
    (t0, k0), (t1, k1) = users
    edge_node = int(mesh.triangles[t0, 3 + k0])
    assert edge_node == mesh.triangles[t1, 3 + k1]

    after, change = open_edges(mesh, [(a, b)])
    check_shell(after, area, 1e-12)
    assert after.triangle_count == mesh.triangle_count
    assert after.vertex_count == mesh.vertex_count + 2  # the start and the edge node, not the far corner
    assert_duplicates_are_copies(mesh, after, change)
    assert sorted(change.vertex_sources[change.new_vertices, 0].tolist()) == sorted([a, edge_node])
    assert change.moved_vertices.size == 0 and not change.element_rest_changed.any()
    assert np.array_equal(change.element_parent, np.arange(mesh.triangle_count))
    # The two triangles of the edge no longer share a corner edge nor the edge node: they
    # meet at the far corner only, which stays whole (a crack tip).
    tri0, tri1 = after.triangles[t0], after.triangles[t1]
    keys0 = {edge_key(*tri0[e].tolist()) for e in shell.EDGES}
    keys1 = {edge_key(*tri1[e].tolist()) for e in shell.EDGES}
    assert not keys0 & keys1
    assert tri0[3 + k0] != tri1[3 + k1]
    assert set(tri0[:3].tolist()) & set(tri1[:3].tolist()) == {b}
    assert b < mesh.vertex_count and (after.triangles == b).any()
    # both sides of the opened edge are boundary now
    boundary = {edge_key(int(p), int(q)) for p, q, _ in after.boundary_edges()}
    assert edge_key(*tri0[shell.EDGES[k0]].tolist()) in boundary
    assert edge_key(*tri1[shell.EDGES[k1]].tolist()) in boundary
    assert components(after) == 1
    assert (vertex_fan_counts(after) == 1).all()


@pytest.mark.parametrize("kind", SHEETS)
def test_a_crack_opened_all_the_way_across_separates_the_sheet(kind):
    mesh = sheet(kind)
    area = mesh.area()
    edges = line_edges(mesh, crack_start(mesh, kind))
    assert components(mesh) == 1
    after, change = open_edges(mesh, edges)
    check_shell(after, area, 1e-12)
    assert components(after) == 2
    # every corner of the line (both ends on the boundary) and every edge node is duplicated
    assert after.vertex_count == mesh.vertex_count + 2 * len(edges) + 1
    assert_duplicates_are_copies(mesh, after, change)
    # the halves are the triangles below and above the line
    below = after.vertices[after.triangles[:, :3]][:, :, 1].mean(axis=1) < SIZE / 2
    for users in edge_users(after.triangles).values():
        if len(users) == 2:
            assert below[users[0][0]] == below[users[1][0]]
    # the same crack opened one edge at a time gives the same sheet up to numbering
    step = mesh
    for edge in edges:
        step, _ = open_edges(step, [edge])
        check_shell(step, area, 1e-12)
    assert step.vertex_count == after.vertex_count and components(step) == 2
    assert np.array_equal(np.sort(step.vertices, axis=0), np.sort(after.vertices, axis=0))


def test_opening_the_diagonal_of_a_single_cell_gives_two_triangles():
    mesh = rectangle_sheet(1, 1, (SIZE, SIZE), pattern="right")
    (key,) = [k for k, u in edge_users(mesh.triangles).items() if len(u) == 2]
    after, change = open_edges(mesh, [key])
    check_shell(after, mesh.area(), 1e-12)
    assert components(after) == 2 and after.vertex_count == mesh.vertex_count + 3


@pytest.mark.parametrize("kind", SHEETS)
def test_opening_a_lone_interior_edge_is_refused_and_changes_nothing(kind):
    mesh = sheet(kind)
    saved = arrays(mesh)
    a = node_at(mesh, (SIZE / 2, SIZE / 4, 0.0))  # inside, away from the slit
    b = node_at(mesh, (3 * SIZE / 4, SIZE / 4, 0.0))
    with pytest.raises(TopologyError, match="closed at both ends"):
        open_edges(mesh, [(a, b)])
    assert_same_arrays(mesh, saved)
    # with an edge that is fine beside it, the whole call is refused
    start = crack_start(mesh, kind)
    with pytest.raises(TopologyError):
        open_edges(mesh, [line_edges(mesh, start)[0], (a, b)])
    assert_same_arrays(mesh, saved)


@pytest.mark.parametrize("kind", SHEETS)
def test_opening_a_boundary_edge_or_a_non_edge_is_refused(kind):
    mesh = sheet(kind)
    saved = arrays(mesh)
    a, b, _ = mesh.boundary_edges()[0].tolist()
    with pytest.raises(TopologyError, match="boundary"):
        open_edges(mesh, [(a, b)])
    with pytest.raises(TopologyError, match="not an edge"):  # two corners of the sheet, far apart
        open_edges(mesh, [(node_at(mesh, (0, 0, 0)), node_at(mesh, (SIZE, SIZE, 0)))])
    edge_node = int(mesh.triangles[0, 3])
    with pytest.raises(TopologyError, match="not an edge"):  # a corner and an edge node
        open_edges(mesh, [(int(mesh.triangles[0, 0]), edge_node)])
    assert_same_arrays(mesh, saved)


@settings(max_examples=40, **FAST)
@given(pattern=st.sampled_from(SHEET_PATTERNS), cells=st.tuples(st.integers(2, 5), st.integers(2, 5)),
       start=st.integers(0, 10_000), choices=st.lists(st.integers(0, 10_000), min_size=1, max_size=10))
def test_random_crack_walks_keep_a_valid_sheet(pattern, cells, start, choices):
    """From a random boundary corner, open a random interior edge at the tip and go to its far
    corner, again and again: the sheet stays valid, with its area, after every opening."""
    mesh = rectangle_sheet(*cells, (SIZE, 0.8 * SIZE), pattern=pattern)
    area = mesh.area()
    boundary = np.unique(mesh.boundary_edges()[:, :2])
    tip = int(boundary[start % len(boundary)])
    for choice in choices:
        users = edge_users(mesh.triangles)
        options = sorted(key for key, u in users.items() if tip in key and len(u) == 2)
        if not options:
            break
        key = options[choice % len(options)]
        far = key[0] + key[1] - tip
        count = mesh.vertex_count
        after, change = open_edges(mesh, [key])
        check_shell(after, area, 1e-12)
        assert (vertex_fan_counts(after) == 1).all()
        assert_duplicates_are_copies(mesh, after, change)
        assert after.vertex_count > count  # the edge node at least
        after_users = edge_users(after.triangles)
        assert all(len(u) == 1 for k, u in after_users.items() if k == key)  # no longer interior
        mesh, tip = after, far


# ---------------------------------------------------------------------------------------------
# split_triangle


def neighbour_count(mesh: ShellMesh, t: int) -> int:
    users = edge_users(mesh.triangles)
    return sum(len(users[edge_key(*mesh.triangles[t, e].tolist())]) == 2 for e in shell.EDGES)


def assert_split_record(mesh: ShellMesh, after: ShellMesh, change, t: int) -> None:
    """The counts, parents and flags of a split of triangle ``t``."""
    users = edge_users(mesh.triangles)
    neighbours = sorted({u for e in shell.EDGES for u, _ in users[edge_key(*mesh.triangles[t, e].tolist())]} - {t})
    T = mesh.triangle_count
    assert after.triangle_count == T + 3 + len(neighbours)
    assert change.element_count_before == T and change.element_count_after == after.triangle_count
    assert change.vertex_count_after == after.vertex_count == mesh.vertex_count + 9 + len(neighbours)
    parent = change.element_parent
    assert np.array_equal(parent[:T], np.arange(T))
    assert sorted(parent[T:].tolist()) == sorted([t] * 3 + neighbours)
    assert np.array_equal(change.removed_elements, sorted([t] + neighbours))
    added = sorted([t] + neighbours + list(range(T, after.triangle_count)))
    assert np.array_equal(np.sort(change.added_elements), added)
    changed = np.zeros(after.triangle_count, dtype=bool)
    changed[[t] + neighbours] = True
    changed[T:] = True
    assert np.array_equal(change.element_rest_changed, changed)
    new = change.new_vertices
    assert set(change.vertex_parent_element[new].tolist()) <= {t, *neighbours}
    assert (change.vertex_parent_element[: mesh.vertex_count] == -1).all()
    np.testing.assert_allclose(change.vertex_weights.sum(axis=1), 1.0, rtol=0, atol=1e-14)
    # untouched triangles keep their nodes; pieces keep their parent's orientation
    others = np.setdiff1d(np.arange(T), [t] + neighbours)
    assert np.array_equal(after.triangles[others], mesh.triangles[others])
    before_normals = shell.corner_normals(mesh.vertices, mesh.triangles)[parent]
    after_normals = shell.corner_normals(after.vertices, after.triangles)
    assert (np.einsum("ij,ij->i", before_normals, after_normals) > 0.0).all()


@settings(max_examples=40, **FAST)
@given(pattern=st.sampled_from(SHEET_PATTERNS), index=st.integers(0, 10_000), cracked=st.booleans())
def test_split_triangle_on_a_flat_sheet_keeps_the_area_and_carries_quadratic_fields_exactly(pattern, index, cracked):
    mesh = rectangle_sheet(3, 3, (SIZE, SIZE), pattern=pattern)
    if cracked:  # neighbours missing across a crack
        mesh, _ = open_edges(mesh, line_edges(mesh, node_at(mesh, (0.0, SIZE / 3, 0.0)))[:2])
    area = mesh.area()
    t = index % mesh.triangle_count
    after, change = split_triangle(mesh, t)
    check_shell(after, area, 1e-12)
    assert after.triangle_count == mesh.triangle_count + 3 + neighbour_count(mesh, t)
    assert_split_record(mesh, after, change, t)
    # a quadratic field of the rest position is reproduced exactly on flat straight elements
    f = quadratic_field(mesh.vertices)
    np.testing.assert_allclose(carry(f, change), quadratic_field(after.vertices), rtol=0, atol=1e-13)
    # the rest positions themselves are what the weights give
    np.testing.assert_allclose(carry(mesh.vertices, change), after.vertices, rtol=0, atol=1e-15)
    assert triangle_qualities(after.vertices, after.triangles).min() > 0.2


def test_split_triangle_rejects_an_index_out_of_range():
    mesh = rectangle_sheet(1, 1)
    for t in (-1, 2):
        with pytest.raises(TopologyError, match="out of range"):
            split_triangle(mesh, t)


def fine_area(mesh: ShellMesh, triangles: np.ndarray, n: int = 8) -> float:
    """Area of the quadratic surface of ``triangles`` by the degree-5 rule on n^2 pieces of the
    reference triangle each: the reference against which quadrature errors are measured."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    i, j = i.ravel(), j.ravel()
    up = i + j <= n - 1
    down = i + j <= n - 2
    corners = np.concatenate([  # (pieces, 3 corners, 2) reference coordinates xi
        np.stack([np.stack([i, j], 1), np.stack([i + 1, j], 1), np.stack([i, j + 1], 1)], 1)[up],
        np.stack([np.stack([i + 1, j], 1), np.stack([i + 1, j + 1], 1), np.stack([i, j + 1], 1)], 1)[down],
    ]) / n
    xi = np.einsum("pc,scd->spd", shell.AREA_POINTS, corners).reshape(-1, 2)
    L = np.column_stack([1.0 - xi.sum(axis=1), xi])
    a = np.linalg.norm(shell.area_vectors(mesh.vertices, triangles, L), axis=-1)
    a = a.reshape(len(triangles), len(corners), -1)
    return float((a * shell.AREA_WEIGHTS / n**2).sum())


@pytest.mark.parametrize("radius", [0.5 * SIZE, 2.0 * SIZE])
@pytest.mark.parametrize("pattern", SHEET_PATTERNS)
def test_split_triangle_on_a_curved_sheet_keeps_the_geometry_exactly(radius, pattern):
    """On a cylinder the elements are curved: every piece of a split is the same quadratic
    surface as its parent (the map of a piece equals the parent's map at the corresponding
    points). The areas then differ only by the error of the degree-5 area rule (the area
    element of a curved quadratic triangle is the square root of a quartic): the refined
    sheet's area is at least as close to the surface's true area, and the change is below the
    coarse sheet's own quadrature error, which shrinks as O(h^6 / R^6)."""
    mesh = cylinder(rectangle_sheet(3, 3, (SIZE, SIZE), pattern=pattern), radius)
    for t in (0, 7, mesh.triangle_count - 1):
        after, change = split_triangle(mesh, t)
        check_shell(after)
        assert_split_record(mesh, after, change, t)
        # each piece is the parent's surface: its quadratic map at sample points lies on the
        # parent's map at the points of the parent it was cut from
        np.testing.assert_allclose(carry(mesh.vertices, change), after.vertices, rtol=0, atol=1e-15)
        samples = np.array([[0.2, 0.3, 0.5], [0.6, 0.2, 0.2], [0.1, 0.1, 0.8], [1 / 3, 1 / 3, 1 / 3]])
        for piece in np.flatnonzero(change.element_rest_changed):
            p = change.element_parent[piece]
            on_piece = shell.shape_functions(samples) @ after.vertices[after.triangles[piece]]
            for target in on_piece:
                found, L, outside = locate(mesh.vertices, mesh.triangles, [p], target)
                assert found == p and outside < 1e-12
                np.testing.assert_allclose(shell.shape_functions(L)[0] @ mesh.vertices[mesh.triangles[p]], target,
                                           rtol=0, atol=1e-12 * SIZE)
        # areas: only the quadrature differs
        pieces = after.triangles[change.element_rest_changed]
        parents = mesh.triangles[change.removed_elements]
        true = fine_area(mesh, parents, 16)  # the rule's error shrinks as n^-6: converged to ~1e-15
        np.testing.assert_allclose(fine_area(after, pieces, 16), true, rtol=1e-12)
        coarse = float(mesh.areas()[change.removed_elements].sum())
        refined = float(after.areas()[change.element_rest_changed].sum())
        assert abs(refined - true) <= abs(coarse - true) + 1e-16 * true
        assert abs(after.area() - mesh.area()) <= 2.0 * abs(coarse - true) + 1e-15 * mesh.area()
        if radius >= 2.0 * SIZE:  # a gentle curve (0.5 rad across the sheet): ~1e-12
            assert abs(after.area() - mesh.area()) <= 1e-10 * mesh.area()


# ---------------------------------------------------------------------------------------------
# move_nodes


def material_move(mesh: ShellMesh, v: int, target: np.ndarray) -> dict:
    """The move of node ``v`` to the material point at ``target`` (located among its triangles)."""
    around = np.flatnonzero((mesh.triangles == v).any(axis=1))
    t, L, outside = locate(mesh.vertices, mesh.triangles, around, target)
    assert outside < 1e-12
    return {v: (shell.shape_functions(L)[0] @ mesh.vertices[mesh.triangles[t]], shape_weights(mesh.triangles, t, L))}


@pytest.mark.parametrize("pattern", SHEET_PATTERNS)
def test_moving_an_interior_corner_a_little_keeps_a_valid_sheet(pattern):
    mesh = rectangle_sheet(4, 4, (SIZE, SIZE), pattern=pattern)
    area = mesh.area()
    v = node_at(mesh, (SIZE / 2, SIZE / 2, 0.0))
    moves = material_move(mesh, v, mesh.vertices[v] + np.array([0.04, 0.03, 0.0]) * SIZE)
    after, change = move_nodes(mesh, moves)
    check_shell(after, area, 1e-12)  # in-plane: the curved triangles still tile the square
    np.testing.assert_array_equal(after.vertices[v], moves[v][0])
    others = np.arange(mesh.vertex_count) != v
    np.testing.assert_array_equal(after.vertices[others], mesh.vertices[others])
    assert np.array_equal(after.triangles, mesh.triangles)
    assert change.moved_vertices.tolist() == [v] and change.new_vertices.size == 0
    assert np.array_equal(change.element_rest_changed, (mesh.triangles[:, :3] == v).any(axis=1))
    assert np.array_equal(change.element_parent, np.arange(mesh.triangle_count))
    # the weights read the old fields at the material point: the rest positions give the new one
    np.testing.assert_allclose(carry(mesh.vertices, change), after.vertices, rtol=0, atol=1e-15)
    np.testing.assert_allclose(carry(quadratic_field(mesh.vertices), change)[v], quadratic_field(after.vertices)[v],
                               rtol=0, atol=1e-13)


@pytest.mark.parametrize("pattern", SHEET_PATTERNS)
def test_a_move_that_folds_a_triangle_is_refused_and_changes_nothing(pattern):
    mesh = rectangle_sheet(4, 4, (SIZE, SIZE), pattern=pattern)
    saved = arrays(mesh)
    v = node_at(mesh, (SIZE / 2, SIZE / 2, 0.0))
    t = int(np.flatnonzero((mesh.triangles[:, :3] == v).any(axis=1))[0])
    tri = mesh.triangles[t, :3].tolist()
    k = tri.index(v)
    a, b = mesh.vertices[tri[(k + 1) % 3]], mesh.vertices[tri[(k + 2) % 3]]
    middle = 0.5 * (a + b)
    beyond = middle + 0.5 * (middle - mesh.vertices[v])  # across the opposite edge
    with pytest.raises(TopologyError, match="move_nodes"):
        move_nodes(mesh, {v: (beyond, {v: 1.0})})
    assert_same_arrays(mesh, saved)
    with pytest.raises(TopologyError, match="move_nodes"):  # onto the opposite edge: degenerate
        move_nodes(mesh, {v: (middle, {v: 1.0})})
    assert_same_arrays(mesh, saved)


# ---------------------------------------------------------------------------------------------
# locate


@pytest.mark.parametrize("L", [[0.2, 0.5, 0.3], [0.7, 0.1, 0.2], [0.05, 0.05, 0.9], [1 / 3, 1 / 3, 1 / 3]])
def test_locate_finds_the_barycentric_coordinates_of_a_point_of_a_curved_element(L):
    mesh = cylinder(rectangle_sheet(3, 3, (SIZE, SIZE)), 0.6 * SIZE)
    L = np.array(L)
    for t in (0, 5, 10):
        target = shell.shape_functions(L)[0] @ mesh.vertices[mesh.triangles[t]]
        corners = mesh.triangles[t, :3]
        candidates = np.flatnonzero(np.isin(mesh.triangles[:, :3], corners).any(axis=1))  # t and all around it
        found, got, outside = locate(mesh.vertices, mesh.triangles, candidates, target)
        assert found == t
        np.testing.assert_allclose(got, L, rtol=0, atol=1e-9)
        assert outside < 1e-9


def test_locate_clamps_a_point_outside_every_candidate():
    mesh = cylinder(rectangle_sheet(3, 3, (SIZE, SIZE)), 0.6 * SIZE)
    target = mesh.vertices[node_at(mesh, (0.0, 0.0, 0.0))] + np.array([-0.02, -0.03, 0.0])  # off a corner
    t, L, outside = locate(mesh.vertices, mesh.triangles, range(mesh.triangle_count), target)
    assert outside > 0.0
    assert 0 <= t < mesh.triangle_count
    assert (L >= 0.0).all() and (L <= 1.0).all()
    np.testing.assert_allclose(L.sum(), 1.0, rtol=0, atol=1e-15)
    # a point beside an element, in its plane, is found with its (negative) coordinate clamped
    flat = rectangle_sheet(2, 2, (SIZE, SIZE))
    x = flat.vertices[flat.triangles[0]]
    target = shell.shape_functions(np.array([1.2, -0.2, 0.0]))[0] @ x
    t, L, outside = locate(flat.vertices, flat.triangles, [0], target)
    assert t == 0 and outside == pytest.approx(0.2, abs=1e-9)
    np.testing.assert_allclose(L, [1.0, 0.0, 0.0], atol=1e-9)


# ---------------------------------------------------------------------------------------------
# compose


def three_changes():
    """open_edges, then split_triangle (of a triangle at the crack tip), then move_nodes (of an
    edge node of that triangle, which the split made a corner), on a 4x4 rectangle; the four
    meshes and the three changes."""
    m0 = rectangle_sheet(4, 4, (SIZE, SIZE))
    m1, c1 = open_edges(m0, line_edges(m0, node_at(m0, (0.0, SIZE / 2, 0.0)))[:2])
    tip = node_at(m1, (SIZE / 2, SIZE / 2, 0.0))
    t = int(np.flatnonzero((m1.triangles[:, :3] == tip).any(axis=1))[0])
    m2, c2 = split_triangle(m1, t)
    boundary = set(m2.boundary_edges()[:, :2].ravel().tolist())
    fans = {v: int((m2.triangles[:, :3] == v).any(axis=1).sum()) for v in m1.triangles[t, 3:].tolist()}
    v = max((v for v in fans if v not in boundary), key=lambda v: (fans[v], -v))
    assert fans[v] >= 4 and v < m0.vertex_count
    around = np.flatnonzero((m2.triangles[:, :3] == v).any(axis=1))
    centroid = m2.vertices[m2.triangles[around[0], :3]].mean(axis=0)
    m3, c3 = move_nodes(m2, material_move(m2, v, m2.vertices[v] + 0.15 * (centroid - m2.vertices[v])))
    return (m0, m1, m2, m3), (c1, c2, c3)


def test_compose_interpolates_like_the_changes_one_after_the_other():
    (m0, m1, m2, m3), (c1, c2, c3) = three_changes()
    for m in (m1, m2, m3):
        check_shell(m, m0.area(), 1e-12)
    f = np.random.default_rng(5).normal(size=(m0.vertex_count, 3))
    stepwise = carry(carry(carry(f, c1), c2), c3)
    for c in (compose(compose(c1, c2), c3), compose(c1, compose(c2, c3))):
        assert c.vertex_count_before == m0.vertex_count and c.vertex_count_after == m3.vertex_count
        assert c.element_count_before == m0.triangle_count and c.element_count_after == m3.triangle_count
        np.testing.assert_allclose(carry(f, c), stepwise, rtol=0, atol=1e-12)
        np.testing.assert_allclose(carry(m0.vertices, c), m3.vertices, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(c.element_parent, c1.element_parent[c2.element_parent[c3.element_parent]])
        assert np.array_equal(c.new_vertices, np.arange(m0.vertex_count, m3.vertex_count))
        assert c.moved_vertices.tolist() == c3.moved_vertices.tolist()  # an edge node of the first mesh
        rest_changed = c2.element_rest_changed[c3.element_parent] | c3.element_rest_changed
        np.testing.assert_array_equal(c.element_rest_changed, rest_changed)
        np.testing.assert_array_equal(c.removed_elements, c2.removed_elements)
        new = c.new_vertices
        created = new[c.vertex_parent_element[new] >= 0]
        assert set(created.tolist()) == set(c2.new_vertices.tolist())  # duplicates have no parent element
        np.testing.assert_array_equal(c.vertex_parent_element[created], c2.vertex_parent_element[created])
    with pytest.raises(ValueError, match="compose"):
        compose(c2, c1)


def test_compose_keeps_a_moved_old_vertex():
    m0 = rectangle_sheet(4, 4, (SIZE, SIZE))
    m1, c1 = open_edges(m0, line_edges(m0, node_at(m0, (0.0, SIZE / 2, 0.0)))[:1])
    v = node_at(m1, (SIZE / 2, SIZE / 4, 0.0))
    m2, c2 = move_nodes(m1, material_move(m1, v, m1.vertices[v] + np.array([0.02, -0.01, 0.0]) * SIZE))
    c = compose(c1, c2)
    assert c.moved_vertices.tolist() == [v]
    f = quadratic_field(m0.vertices)
    np.testing.assert_allclose(carry(f, c), carry(carry(f, c1), c2), rtol=0, atol=1e-14)


# ---------------------------------------------------------------------------------------------
# Model.rebuild of a shell


def shell_model(mesh, **kwargs):
    from wcut.model import Model

    T = mesh.triangle_count
    kwargs.setdefault("youngs_modulus", 1.0e6 * (1.0 + np.arange(T) / T))  # one value per triangle
    kwargs.setdefault("density", 1000.0)
    kwargs.setdefault("thickness", 1.0e-3 * (1.0 + 0.5 * np.cos(np.arange(T))))
    return Model(mesh, poisson_ratio=0.3, gravity=(0.0, 0.0, 0.0), **kwargs)


def test_rebuild_after_an_opening_carries_the_state_material_and_constraints():
    mesh = rectangle_sheet(4, 4, (SIZE, SIZE))
    X = mesh.vertices
    left = np.flatnonzero(X[:, 0] < 1e-12)
    model = shell_model(mesh, fixed=left)
    start = node_at(mesh, (0.0, SIZE / 2, 0.0))
    assert start in left
    state = model.state()
    q = X @ np.diag([1.03, 1.05, 1.0]) + np.array([0.0, 0.0, 0.002]) * np.sin(X[:, :1] / SIZE * 3.0)
    qd = X @ np.array([[0.1, -0.4, 0.2], [0.3, 0.0, 0.1], [-0.2, 0.5, 0.3]]) + 0.01
    state.particle_q.assign(q)
    state.particle_qd.assign(qd)
    edges = line_edges(mesh, start)[:2]
    after, change = open_edges(mesh, edges)
    new_model, new_state = model.rebuild(after, change, state)
    assert new_model.particle_count == after.vertex_count and new_model.tri_count == after.triangle_count
    q0, qd0 = state.particle_q.numpy(), state.particle_qd.numpy()
    source = change.vertex_sources[:, 0]
    np.testing.assert_array_equal(new_state.particle_q.numpy(), q0[source])  # duplicates: their originals
    np.testing.assert_array_equal(new_state.particle_qd.numpy(), qd0[source])
    np.testing.assert_array_equal(new_model.tri_youngs_modulus.numpy(),
                                  model.tri_youngs_modulus.numpy()[change.element_parent])
    fixed = new_model.particle_fixed.numpy() == 1
    np.testing.assert_array_equal(fixed, (model.particle_fixed.numpy() == 1)[source])
    start_copy = [v for v in change.new_vertices.tolist() if source[v] == start]
    assert len(start_copy) == 1 and fixed[start_copy[0]] and fixed[start]
    # two hinges (the halves of the corner edge at its edge node) per opened edge are gone
    assert new_model.edge_count == model.edge_count - 2 * len(edges)
    assert new_model.fixed_count == model.fixed_count + 1


def test_rebuild_after_a_split_gives_every_piece_its_parents_material():
    mesh = rectangle_sheet(3, 3, (SIZE, SIZE))
    model = shell_model(mesh, density=np.linspace(900.0, 1100.0, mesh.triangle_count))
    after, change = split_triangle(mesh, 7)
    new_model, _ = model.rebuild(after, change, None)
    parent = change.element_parent
    for name in ("tri_youngs_modulus", "tri_density", "tri_poisson_ratio", "tri_thickness"):
        np.testing.assert_array_equal(getattr(new_model, name).numpy(), getattr(model, name).numpy()[parent], name)
    # the mass of the sheet is kept (each piece has its parent's density and a share of its area)
    np.testing.assert_allclose(new_model.particle_mass.numpy().sum(), model.particle_mass.numpy().sum(), rtol=1e-6)


@pytest.mark.parametrize("operation", ["open", "open+split+move"])
def test_a_sheet_at_rest_stays_at_rest_after_a_change(operation):
    from wcut.solver import SolverCorotational

    if operation == "open":
        m0 = rectangle_sheet(4, 4, (SIZE, SIZE))
        m3, change = open_edges(m0, line_edges(m0, node_at(m0, (0.0, SIZE / 2, 0.0)))[:2])
    else:
        (m0, _, _, m3), (c1, c2, c3) = three_changes()
        change = compose(compose(c1, c2), c3)
    fixed = np.flatnonzero(m0.vertices[:, 0] < 1e-12)
    model = shell_model(m0, fixed=fixed, rayleigh_mass=1.0)
    new_model, state = model.rebuild(m3, change, model.state())
    np.testing.assert_allclose(state.particle_q.numpy(), m3.vertices, rtol=0, atol=1e-7 * SIZE)
    out = new_model.state()
    SolverCorotational(new_model, cg_iterations=30).step(state, out, new_model.control(), 1.0e-3)
    moved = np.abs(out.particle_q.numpy() - state.particle_q.numpy()).max()
    assert moved < 1e-6 * SIZE, moved
    assert np.abs(out.particle_qd.numpy()).max() < 1e-3 * SIZE


def test_compose_keeps_the_parent_of_a_copied_created_vertex():
    """A split creates an edge node in triangle t; opening that edge copies the node: through
    the composed change the copy's parent element is still t."""
    m = rectangle_sheet(2, 2, (0.1, 0.1))
    s = int(np.flatnonzero(np.all(np.isclose(m.vertices, [0, 0.05, 0]), axis=1))[0])
    t = int(np.flatnonzero((m.triangles[:, :3] == s).any(1))[0])
    m1, c1 = split_triangle(m, t)
    users = edge_users(m1.triangles)
    key = next(k for k, v in users.items()
               if s in k and len(v) == 2 and m1.triangles[v[0][0], 3 + v[0][1]] >= m.vertex_count)
    m2, c2 = open_edges(m1, [key])
    created = c2.vertex_sources[c2.new_vertices, 0]
    composed = compose(c1, c2)
    assert (composed.vertex_parent_element[c2.new_vertices] == c1.vertex_parent_element[created]).all()
    assert (composed.vertex_parent_element[c2.new_vertices][created >= m.vertex_count] == t).all()
