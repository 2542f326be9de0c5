"""Tests of wcut.mesh.ShellMesh: quadratic (6-node) triangle shells, their validation, areas,
boundaries, meshio I/O and the sheet generators (thesis 6.2)."""

from __future__ import annotations

import math

import meshio
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wcut.errors import ExportError, MeshError
from wcut.mesh import ShellMesh, l_shape_sheet, precut_sheet, rectangle_sheet
from wcut.shell import AREA_POINTS, AREA_WEIGHTS, REVERSED, SUBTRIANGLES, jacobians

# The unit square as two linear triangles sharing the diagonal (0, 2). As a quadratic mesh
# (from_linear) its edge nodes are 4: (0,1), 5: (1,2), 6: (2,0) shared, 7: (2,3), 8: (3,0).
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
SQUARE_TRIS = np.array([[0, 1, 2], [0, 2, 3]])
SQUARE6 = np.array([[0, 1, 2, 4, 5, 6], [0, 2, 3, 6, 7, 8]])


def _square() -> ShellMesh:
    return ShellMesh.from_linear(SQUARE, SQUARE_TRIS, name="square")


def _error(vertices, triangles) -> str:
    with pytest.raises(MeshError) as info:
        ShellMesh(vertices, triangles, name="m")
    message = str(info.value)
    assert message.startswith("m: ")
    return message


def _walk_loop(edges: np.ndarray) -> list[int]:
    """The corners of boundary edges (a, b, node) followed from a to b; asserts they form one
    closed loop."""
    following = {}
    for a, b, _ in edges.tolist():
        assert a not in following, f"corner {a} starts two boundary edges"
        following[a] = b
    start = edges[0, 0]
    loop, corner = [start], following[start]
    while corner != start:
        loop.append(corner)
        corner = following[corner]
        assert len(loop) <= len(edges)
    assert len(loop) == len(edges), "the boundary has more than one loop"
    return loop


def _boundary_length(mesh: ShellMesh) -> float:
    e = mesh.boundary_edges()
    x = mesh.vertices
    halves = np.linalg.norm(x[e[:, 0]] - x[e[:, 2]], axis=1) + np.linalg.norm(x[e[:, 2]] - x[e[:, 1]], axis=1)
    return float(halves.sum())


def _tessellated_area(vertices: np.ndarray, triangle: np.ndarray, n: int) -> float:
    """Area of one 6-node triangle as n^2 flat triangles at points of its quadratic map."""
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"))
    keep = i + j <= n
    i, j = i[keep], j[keep]
    la, lb, lc = 1.0 - (i + j) / n, i / n, j / n
    shape = np.stack([la * (2 * la - 1), lb * (2 * lb - 1), lc * (2 * lc - 1), 4 * la * lb, 4 * lb * lc, 4 * lc * la],
                     axis=1)
    points = shape @ vertices[triangle]
    index = np.full((n + 2, n + 2), -1)
    index[i, j] = np.arange(len(i))
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b = a.ravel(), b.ravel()
    up = a + b <= n - 1
    down = a + b <= n - 2
    tris = np.concatenate([
        np.stack([index[a[up], b[up]], index[a[up] + 1, b[up]], index[a[up], b[up] + 1]], axis=1),
        np.stack([index[a[down] + 1, b[down]], index[a[down] + 1, b[down] + 1], index[a[down], b[down] + 1]], axis=1),
    ])
    p = points[tris]
    return float(0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())


def _rotation(angles) -> np.ndarray:
    a, b, c = angles
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


# ---------------------------------------------------------------------------------------------
# construction and from_linear


def test_from_linear_numbers_corners_then_edge_nodes_in_order_of_appearance():
    mesh = _square()
    assert mesh.vertices.dtype == np.float64 and mesh.triangles.dtype == np.int64
    assert np.array_equal(mesh.triangles, SQUARE6)
    assert np.array_equal(mesh.vertices[:4], SQUARE)
    midpoints = [[0.5, 0, 0], [1, 0.5, 0], [0.5, 0.5, 0], [0.5, 1, 0], [0, 0.5, 0]]
    assert np.allclose(mesh.vertices[4:], midpoints, rtol=0, atol=1e-15)
    assert mesh.vertex_count == 4 + 5  # corners + unique edges: the diagonal's node is shared
    assert mesh.triangle_count == 2
    assert mesh.corner_ids.tolist() == [0, 1, 2, 3]
    assert mesh.name == "square" and mesh.source_vertex_ids is None


@pytest.mark.parametrize("make", [
    lambda: rectangle_sheet(3, 2),
    lambda: rectangle_sheet(4, 3, pattern="right"),
    lambda: l_shape_sheet(2),
    lambda: precut_sheet(4, 4, notch_length=0.5),
], ids=["rectangle", "rectangle-right", "l-shape", "precut"])
def test_from_linear_shares_one_node_per_edge(make):
    mesh = make()
    corners = mesh.corner_ids
    assert corners.tolist() == list(range(len(corners)))  # corners first, edge nodes after
    assert mesh.vertex_count == len(corners) + len(mesh.edges())
    pairs = mesh.triangles[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    nodes = mesh.triangles[:, 3:].ravel()
    x = mesh.vertices
    assert np.allclose(x[nodes], 0.5 * (x[pairs[:, 0]] + x[pairs[:, 1]]), rtol=0, atol=1e-15)
    # a node is used by one triangle (boundary edge) or two (interior edge)
    assert set(np.bincount(nodes).tolist()[len(corners):]) <= {1, 2}


def test_from_linear_rejects_bad_linear_input():
    with pytest.raises(MeshError, match=r"triangles must have shape \(M, 3\)"):
        ShellMesh.from_linear(SQUARE, SQUARE6)
    with pytest.raises(MeshError, match="triangle 1 has a node index out of range"):
        ShellMesh.from_linear(SQUARE, [[0, 1, 2], [0, 2, 4]])
    with pytest.raises(MeshError, match="vertex 4 is not used"):
        ShellMesh.from_linear(np.vstack([SQUARE, [[3, 3, 3]]]), SQUARE_TRIS)


def test_trusted_skips_validation():
    mesh = ShellMesh.trusted(SQUARE, [[0, 1, 2, 0, 1, 2]], name="t")  # invalid: corners as edge nodes
    assert mesh.triangles.dtype == np.int64 and mesh.name == "t" and mesh.source_vertex_ids is None


def test_vertex_queries_and_counts():
    mesh = rectangle_sheet(2, 2, (2.0, 1.0))
    assert not hasattr(mesh, "tet_count") and not hasattr(mesh, "tets")
    with pytest.raises(AttributeError, match="triangle_count"):
        _ = mesh.tet_count
    assert mesh.triangle_count == 8 and mesh.vertex_count == 9 + 16
    corners = mesh.vertices_in_box([-0.1, -0.1, -0.1], [0.1, 1.1, 0.1])  # the left side x = 0
    assert np.allclose(mesh.vertices[corners, 0], 0.0) and len(corners) == 5  # 3 corners, 2 edge nodes
    assert mesh.vertex_from_source(3) == 3 and mesh.vertex_from_source(mesh.vertex_count) == -1
    # two-triangle square: four sides of 1 m and a diagonal
    assert _square().mean_edge_length() == pytest.approx((4 + math.sqrt(2)) / 5, rel=1e-15)


# ---------------------------------------------------------------------------------------------
# validation: one test per kind of error, each naming where


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinate_names_the_vertex(bad):
    x = _square().vertices.copy()
    x[5, 1] = bad
    assert "vertex 5 has a non-finite coordinate" in _error(x, SQUARE6)


@pytest.mark.parametrize("vertices, triangles, words", [
    (np.zeros((9, 2)), SQUARE6, r"vertices must have shape \(N, 3\)"),
    (None, SQUARE_TRIS, r"must have shape \(M, 6\)"),
    (None, np.zeros((0, 6), dtype=np.int64), "no triangles"),
    (None, SQUARE6.astype(float), "must be integers"),
], ids=["2d-vertices", "linear-triangles", "empty", "float-indices"])
def test_bad_shapes_and_types(vertices, triangles, words):
    vertices = _square().vertices if vertices is None else vertices
    with pytest.raises(MeshError, match=words):
        ShellMesh(vertices, triangles)


def test_index_out_of_range_names_the_triangle():
    message = _error(_square().vertices, [[0, 1, 2, 4, 5, 6], [0, 2, 3, 6, 7, 9]])
    assert "triangle 1 has a node index out of range" in message and "vertex count 9" in message


def test_repeated_node_names_the_triangle():
    assert "triangle 1 repeats a node" in _error(_square().vertices, [[0, 1, 2, 4, 5, 6], [0, 2, 3, 6, 7, 7]])


def test_unused_vertex_is_named():
    x = np.vstack([_square().vertices, [[2.0, 2.0, 0.0]]])
    assert "vertex 9 is not used by any triangle" in _error(x, SQUARE6)


def test_corner_used_as_edge_node_is_named():
    # triangle 1 takes corner 1 as the node of its edge (3, 0); node 8 is then not needed
    message = _error(_square().vertices[:8], [[0, 1, 2, 4, 5, 6], [0, 2, 3, 6, 7, 1]])
    assert "node 1 is both a corner (of triangle 0) and an edge node (of triangle 1)" in message


def test_degenerate_triangle_is_named():
    x = _square().vertices.copy()
    x[2] = [2.0, 0.0, 0.0]  # corner 2 on the line through corners 0 and 1: triangle 0 is flat
    assert "triangle 0 [0, 1, 2, 4, 5, 6] is degenerate" in _error(x, SQUARE6)


def test_degeneracy_is_relative_to_the_triangle_size():
    small = ShellMesh(_square().vertices * 1e-6, SQUARE6)  # a 1 um square is a valid mesh
    assert small.area() == pytest.approx(1e-12, rel=1e-12)
    x = _square().vertices.copy()
    x[3] = [0.0, 1e-11, 0.0]  # triangle 1 is a 1 m long sliver of height 1e-11 m
    x[7], x[8] = 0.5 * (x[2] + x[3]), 0.5 * x[3]
    assert "triangle 1 " in _error(x, SQUARE6)


def test_repeated_triangle_is_named():
    # triangle 1 covers triangle 0 again, traversed the other way round (so no edge is shared
    # in the same direction: only the corner check sees it)
    x = _square().vertices[[0, 1, 2, 4, 5, 6]]
    assert "triangle 1 repeats triangle 0" in _error(x, [[0, 1, 2, 3, 4, 5], [0, 2, 1, 5, 4, 3]])


def test_edge_in_three_triangles_is_non_manifold():
    x = np.vstack([_square().vertices, [[0.5, 0.5, 1.0], [0.75, 0.75, 0.5], [0.25, 0.25, 0.5]]])
    triangles = np.vstack([SQUARE6, [[0, 2, 9, 6, 10, 11]]])  # a fin on the diagonal (0, 2)
    assert "non-manifold edge (0, 2) is shared by 3 triangles [0, 1, 2]" in _error(x, triangles)


def test_shared_edge_with_two_edge_nodes_does_not_conform():
    x = np.vstack([_square().vertices, [[0.5, 0.5, 0.0]]])  # a second node on the diagonal
    message = _error(x, [[0, 1, 2, 4, 5, 6], [0, 2, 3, 9, 7, 8]])
    assert "triangles 0 and 1 share the edge (0, 2) but not its edge node (6 and 9)" in message


def test_edge_node_on_two_edges_is_named():
    # triangle 1 takes the node of edge (0, 1) for its edge (2, 3); old node 7 dropped, 8 -> 7
    x = _square().vertices[[0, 1, 2, 3, 4, 5, 6, 8]]
    message = _error(x, [[0, 1, 2, 4, 5, 6], [0, 2, 3, 6, 4, 7]])
    assert "node 4 is the edge node of two edges (0, 1) (triangle 0) and (2, 3) (triangle 1)" in message


def test_inconsistent_orientation_names_the_triangles():
    reversed_second = [[0, 1, 2, 4, 5, 6], SQUARE6[1, REVERSED].tolist()]
    message = _error(_square().vertices, reversed_second)
    assert "triangles 0 and 1 are inconsistently oriented" in message and "edge (0, 2)" in message


@pytest.mark.parametrize("node_position", [[0.5, 0.9, 0.0], [0.5, 0.3, 0.0], [0.25, 0.0, 0.0]],
                         ids=["past-the-opposite-corner", "inward-bulge", "quarter-point"])
def test_folded_curved_triangle_is_named(node_position):
    """Triangle 0 is (0,0), (1,0), (1,1). Bulging its edge (0, 1) inward by d scales the
    Jacobian at corner 0 by 1 - 4 d: d = 0.3 folds it though the node stays inside; the node at
    the quarter point makes it zero there (a bulge outward never folds)."""
    x = _square().vertices.copy()
    x[4] = node_position  # the node of edge (0, 1) of triangle 0
    assert "curved triangle 0 [0, 1, 2, 4, 5, 6] folds" in _error(x, SQUARE6)


def test_moderately_curved_triangles_are_valid():
    x = _square().vertices.copy()
    x[4] = [0.5, -0.2, 0.0]  # in plane
    x[6] = [0.55, 0.45, 0.3]  # the shared node, out of plane
    mesh = ShellMesh(x, SQUARE6)
    at_gauss, at_nodes = jacobians(mesh.vertices, mesh.triangles)
    assert (at_gauss > 0).all() and (at_nodes > 0).all()


def test_straight_triangle_jacobian_is_twice_its_area():
    mesh = rectangle_sheet(2, 3, (0.4, 0.9))
    at_gauss, at_nodes = jacobians(mesh.vertices, mesh.triangles)
    assert np.allclose(at_gauss, 2 * mesh.areas()[:, None], rtol=1e-12)
    assert np.allclose(at_nodes, 2 * mesh.areas()[:, None], rtol=1e-12)


def test_either_consistent_orientation_is_accepted():
    sheet = rectangle_sheet(3, 2)
    clockwise = ShellMesh(sheet.vertices, sheet.triangles[:, REVERSED])
    assert clockwise.area() == pytest.approx(sheet.area(), rel=1e-14)
    normals = np.cross(*(clockwise.vertices[clockwise.triangles[:, k]] - clockwise.vertices[clockwise.triangles[:, 0]]
                         for k in (1, 2)))
    assert (normals[:, 2] < 0).all()


@settings(max_examples=30, deadline=None)
@given(angles=st.tuples(*[st.floats(-math.pi, math.pi)] * 3),
       shift=st.tuples(*[st.floats(-10, 10)] * 3), flip=st.booleans())
def test_rigid_motions_keep_a_sheet_valid_and_its_area(angles, shift, flip):
    sheet = l_shape_sheet(2, 0.3)
    x = sheet.vertices @ _rotation(angles).T + np.asarray(shift)
    triangles = sheet.triangles[:, REVERSED] if flip else sheet.triangles
    moved = ShellMesh(x, triangles)
    assert moved.area() == pytest.approx(0.75 * 0.09, rel=1e-12)
    assert len(moved.boundary_edges()) == len(sheet.boundary_edges())


# ---------------------------------------------------------------------------------------------
# areas


def test_area_rule_is_exact_to_degree_five():
    r, s = AREA_POINTS[:, 1], AREA_POINTS[:, 2]
    for a in range(6):
        for b in range(6 - a):
            exact = math.factorial(a) * math.factorial(b) / math.factorial(a + b + 2)  # of r^a s^b
            assert (AREA_WEIGHTS * r**a * s**b).sum() == pytest.approx(exact, rel=1e-13, abs=1e-16)


@pytest.mark.parametrize("nx, ny, size, origin, pattern", [
    (1, 1, (1.0, 1.0), (0, 0, 0), "alternate"),
    (5, 3, (0.3, 0.07), (-1.0, 2.0, 0.5), "alternate"),
    (4, 6, (2.0, 3.0), (0.1, 0.2), "right"),
])
def test_flat_sheet_areas_are_exact(nx, ny, size, origin, pattern):
    mesh = rectangle_sheet(nx, ny, size, origin=origin, pattern=pattern)
    assert mesh.area() == pytest.approx(size[0] * size[1], rel=1e-12)
    assert np.allclose(mesh.areas(), size[0] * size[1] / (2 * nx * ny), rtol=1e-12)
    assert np.allclose(mesh.vertices[:, 2], (tuple(origin) + (0.0,))[2])


@pytest.mark.parametrize("tilted", [False, True], ids=["in-z-plane", "tilted-plane"])
def test_flat_curved_triangle_area_is_exact(tilted):
    """Edge nodes moved in the plane: each parabolic arc adds 2/3 * chord * sagitta."""
    x = ShellMesh.from_linear(SQUARE[[0, 1, 3]], [[0, 1, 2]]).vertices.copy()  # corners (0,0), (1,0), (0,1)
    d1, d2 = 0.1, 0.05
    x[3] += [0.0, -d1, 0.0]  # edge (0, 1) bulges outward by d1
    x[4] += d2 * np.array([1.0, 1.0, 0.0]) / math.sqrt(2)  # edge (1, 2) outward by d2
    exact = 0.5 + 2.0 / 3.0 * (1.0 * d1 + math.sqrt(2) * d2)
    if tilted:
        x = x @ _rotation((0.7, -0.4, 1.9)).T + [1.0, 2.0, 3.0]
    assert ShellMesh(x, [[0, 1, 2, 3, 4, 5]]).area() == pytest.approx(exact, rel=1e-12)


def test_curved_triangle_area_matches_a_fine_tessellation():
    """One element spanning a sphere octant, its edge nodes on the unit sphere. The area element
    is not polynomial: the 7-point rule is within 1e-4 (relative; it is 2e-5 off) of the area of
    tessellations into 256^2 and 512^2 flat triangles, extrapolated (error O(h^2)) to the limit."""
    corners = np.eye(3)
    nodes = corners[[0, 1, 2]] + corners[[1, 2, 0]]
    x = np.vstack([corners, nodes / np.linalg.norm(nodes, axis=1, keepdims=True)])
    mesh = ShellMesh(x, [[0, 1, 2, 3, 4, 5]])
    fine, finer = _tessellated_area(x, mesh.triangles[0], 256), _tessellated_area(x, mesh.triangles[0], 512)
    assert abs(finer - fine) < 1e-5 * finer  # the reference has converged
    reference = (4.0 * finer - fine) / 3.0
    assert mesh.area() == pytest.approx(reference, rel=1e-4)
    assert mesh.area() > math.sqrt(3) / 2  # larger than the flat corner triangle


# ---------------------------------------------------------------------------------------------
# boundary, sub-triangulation


@pytest.mark.parametrize("pattern", ["alternate", "right"])
def test_rectangle_boundary_is_one_closed_counter_clockwise_loop(pattern):
    w, h = 0.6, 0.4
    mesh = rectangle_sheet(3, 2, (w, h), origin=(1.0, 1.0, 0.0), pattern=pattern)
    edges = mesh.boundary_edges()
    assert edges.shape == (2 * (3 + 2), 3)
    loop = _walk_loop(edges)
    assert _boundary_length(mesh) == pytest.approx(2 * (w + h), rel=1e-12)
    xy = mesh.vertices[loop, :2]
    signed = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    assert signed == pytest.approx(w * h, rel=1e-12)  # counter-clockwise around the sheet
    x = mesh.vertices
    assert np.allclose(x[edges[:, 2]], 0.5 * (x[edges[:, 0]] + x[edges[:, 1]]))


def test_linear_triangles_split_each_element_in_four():
    mesh = rectangle_sheet(2, 1, (1.0, 0.5))
    sub = mesh.linear_triangles()
    assert sub.shape == (4 * mesh.triangle_count, 3)
    assert np.array_equal(sub[:4], mesh.triangles[0][SUBTRIANGLES])
    t = mesh.triangles[1]
    assert sub[4:8].tolist() == [[t[0], t[3], t[5]], [t[3], t[1], t[4]], [t[5], t[4], t[2]], [t[3], t[4], t[5]]]
    p = mesh.vertices[sub]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (normals[:, 2] > 0).all()  # oriented as the elements
    assert 0.5 * normals[:, 2].sum() == pytest.approx(mesh.area(), rel=1e-12)


# ---------------------------------------------------------------------------------------------
# generators


def test_rectangle_sheet_numbering_and_patterns():
    mesh = rectangle_sheet(3, 2, (0.3, 0.2), origin=(1.0, 2.0, 3.0))
    i, j = 2, 1
    assert np.allclose(mesh.vertices[i * 3 + j], [1.2, 2.1, 3.0])
    assert mesh.triangle_count == 12 and len(mesh.corner_ids) == 12
    right = rectangle_sheet(2, 2, pattern="right")
    diagonals = ({tuple(sorted(e)) for e in right.edges().tolist()}
                 - {tuple(sorted(e)) for e in right.boundary_edges()[:, :2].tolist()})
    x = right.vertices
    slopes = {round(float((x[b, 1] - x[a, 1]) / (x[b, 0] - x[a, 0])), 9) for a, b in diagonals
              if x[a, 0] != x[b, 0] and x[a, 1] != x[b, 1]}
    assert slopes == {1.0}
    alternate = rectangle_sheet(2, 2)
    x = alternate.vertices
    slopes = {round(float((x[b, 1] - x[a, 1]) / (x[b, 0] - x[a, 0])), 9) for a, b in alternate.edges().tolist()
              if x[a, 0] != x[b, 0] and x[a, 1] != x[b, 1]}
    assert slopes == {1.0, -1.0}  # criss-cross


def test_sheets_are_counter_clockwise_seen_from_above():
    for mesh in (rectangle_sheet(3, 4), l_shape_sheet(2), precut_sheet(4, 2, notch_length=0.5)):
        x, t = mesh.vertices, mesh.triangles
        normals = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
        assert (normals[:, 2] > 0).all() and np.allclose(x[:, 2], 0.0)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_l_shape_area_and_re_entrant_corner(n):
    size, origin = 2.0, np.array([-1.0, 0.5, 0.0])
    mesh = l_shape_sheet(n, size, origin=origin)
    assert mesh.triangle_count == 6 * n * n
    assert mesh.area() == pytest.approx(0.75 * size**2, rel=1e-12)
    edges = mesh.boundary_edges()
    _walk_loop(edges)
    assert _boundary_length(mesh) == pytest.approx(4 * size, rel=1e-12)
    corner = origin + [size / 2, size / 2, 0.0]
    found = np.flatnonzero(np.linalg.norm(mesh.vertices - corner, axis=1) < 1e-12)
    assert len(found) == 1 and found[0] in mesh.corner_ids
    v = found[0]
    incoming, outgoing = edges[edges[:, 1] == v], edges[edges[:, 0] == v]
    assert len(incoming) == 1 and len(outgoing) == 1
    x = mesh.vertices
    to_previous, to_next = x[incoming[0, 0]] - x[v], x[outgoing[0, 1]] - x[v]
    # interior angle: from the next edge counter-clockwise round to the previous one
    angle = math.degrees(math.atan2(to_previous[1], to_previous[0]) - math.atan2(to_next[1], to_next[0])) % 360
    assert angle == pytest.approx(270.0, abs=1e-9)


@pytest.mark.parametrize("nx, ny, size, notch, cells", [
    (4, 4, (1.0, 1.0), 0.5, 2),
    (10, 6, (2.0, 0.6), 0.65, 3),  # 3.25 cells of 0.2 m: rounds to 3
    (10, 2, (1.0, 0.1), 0.95, 9),  # 9.5 cells: halves round up
    (3, 2, (0.3, 0.2), 0.1, 1),
])
def test_precut_sheet_slit(nx, ny, size, notch, cells):
    w, h = size
    origin = np.array([0.5, -0.25, 0.0])
    mesh = precut_sheet(nx, ny, size, notch, origin=origin)
    assert mesh.name == "precut_sheet"
    assert mesh.area() == pytest.approx(w * h, rel=1e-12)
    length = cells * w / nx
    tip = origin + [length, h / 2, 0.0]
    x = mesh.vertices
    at_tip = np.flatnonzero(np.linalg.norm(x - tip, axis=1) < 1e-12)
    assert len(at_tip) == 1
    for i in range(cells):  # slit corners before the tip: two vertices each, in different triangles
        at = np.flatnonzero(np.linalg.norm(x - (origin + [i * w / nx, h / 2, 0.0]), axis=1) < 1e-12)
        assert len(at) == 2 and set(at) <= set(mesh.corner_ids)
        users = [set(np.flatnonzero((mesh.triangles == a).any(axis=1))) for a in at]
        assert not users[0] & users[1]
    for i in range(cells):  # slit edge nodes too
        at = np.flatnonzero(np.linalg.norm(x - (origin + [(i + 0.5) * w / nx, h / 2, 0.0]), axis=1) < 1e-12)
        assert len(at) == 2
    assert len(mesh.corner_ids) == (nx + 1) * (ny + 1) + cells
    _walk_loop(mesh.boundary_edges())  # the slit is part of the one boundary loop
    assert _boundary_length(mesh) == pytest.approx(2 * (w + h) + 2 * length, rel=1e-12)


def test_precut_sides_are_connected_only_around_the_tip():
    mesh = precut_sheet(6, 4, (0.6, 0.4), 0.3)
    below = mesh.vertices[mesh.triangles[:, :3]].mean(axis=1)[:, 1] < 0.2
    left_of_tip = mesh.vertices[mesh.triangles[:, :3]].mean(axis=1)[:, 0] < 0.3
    shared = set(mesh.triangles[below & left_of_tip].ravel()) & set(mesh.triangles[~below & left_of_tip].ravel())
    tip = np.flatnonzero(np.linalg.norm(mesh.vertices - [0.3, 0.2, 0.0], axis=1) < 1e-12)
    assert shared == set(tip.tolist())


@pytest.mark.parametrize("make, words", [
    (lambda: rectangle_sheet(0, 2), "nx must be an integer of at least 1"),
    (lambda: rectangle_sheet(2, -1), "ny must be an integer of at least 1"),
    (lambda: rectangle_sheet(2.5, 2), "nx must be an integer"),
    (lambda: rectangle_sheet(2, 2, (1.0, 0.0)), "size must be 2 positive lengths"),
    (lambda: rectangle_sheet(2, 2, (1.0,)), "size must be 2 positive lengths"),
    (lambda: rectangle_sheet(2, 2, (1.0, np.nan)), "size must be 2 positive lengths"),
    (lambda: rectangle_sheet(2, 2, origin=(0.0, np.inf)), "origin must be two or three finite"),
    (lambda: rectangle_sheet(2, 2, pattern="left"), "pattern must be one of alternate, right"),
    (lambda: l_shape_sheet(0), "l_shape_sheet: n must be an integer of at least 1"),
    (lambda: l_shape_sheet(2, -1.0), "l_shape_sheet: size must be a positive length"),
    (lambda: precut_sheet(4, 3), "ny must be even"),
    (lambda: precut_sheet(4, 4, (1.0, 1.0), 1.5), "notch_length 1.5 m is too long"),
    (lambda: precut_sheet(4, 4, (1.0, 1.0), 0.9), "too long"),  # 3.6 cells rounds to the full 4
    (lambda: precut_sheet(4, 4, (1.0, 1.0), 0.1), "shorter than half a cell"),
    (lambda: precut_sheet(4, 4, (1.0, 1.0), 0.0), "notch_length must be a positive length"),
], ids=lambda v: v if isinstance(v, str) else "")
def test_generators_reject_bad_arguments(make, words):
    with pytest.raises(MeshError, match=words):
        make()


# ---------------------------------------------------------------------------------------------
# I/O


@pytest.mark.parametrize("name", ["sheet.vtu", "sheet.vtk", "sheet.msh"])
def test_save_and_load_round_trip(tmp_path, name):
    x = precut_sheet(4, 2, (0.4, 0.2), 0.2).vertices.copy()
    mesh = precut_sheet(4, 2, (0.4, 0.2), 0.2)
    x[mesh.triangles[:, 3:]] += [0.0, 0.0, 0.01]  # curved out of plane: must survive as triangle6
    mesh = ShellMesh(x, mesh.triangles)
    target = tmp_path / "sub" / name
    mesh.save(target)
    assert sorted(p.name for p in target.parent.iterdir()) == [name]  # atomic: no temporary left
    loaded = ShellMesh.load(target)
    assert loaded.name == name and loaded.source_vertex_ids is None
    assert np.allclose(loaded.vertices, mesh.vertices, rtol=0, atol=1e-12)
    assert np.array_equal(loaded.triangles, mesh.triangles)
    assert loaded.area() == pytest.approx(mesh.area(), rel=1e-12)
    rectangle_sheet(1, 1).save(target)  # overwriting keeps one file
    assert sorted(p.name for p in target.parent.iterdir()) == [name]
    assert ShellMesh.load(target).triangle_count == 2


def test_save_refuses_formats_that_drop_quadratic_triangles(tmp_path):
    for name in ("sheet.obj", "sheet.stl", "sheet.mesh"):
        with pytest.raises(ExportError, match="cannot write 6-node triangles"):
            _square().save(tmp_path / name)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["flat.vtu", "flat.obj"])
def test_load_linear_triangles_makes_them_quadratic(tmp_path, name):
    sheet = rectangle_sheet(3, 2)
    corners = sheet.vertices[sheet.corner_ids]
    linear = sheet.triangles[:, :3]
    meshio.write(tmp_path / name, meshio.Mesh(corners, [("triangle", linear)]))
    loaded = ShellMesh.load(tmp_path / name)
    expected = ShellMesh.from_linear(corners, linear)
    assert np.allclose(loaded.vertices, expected.vertices, rtol=0, atol=1e-12)
    assert np.array_equal(loaded.triangles, expected.triangles)
    # edge nodes are not in the file: only the corners have a file index
    assert loaded.source_vertex_ids.tolist() == list(range(len(corners)))
    assert loaded.vertex_from_source(len(corners)) == -1


def test_load_drops_vertices_of_other_cells_and_keeps_the_file_numbering(tmp_path):
    mesh = _square()
    x = np.vstack([mesh.vertices[:2], [[7.0, 7.0, 7.0]], mesh.vertices[2:]])  # file vertex 2: a line's
    renumber = np.array([0, 1, 3, 4, 5, 6, 7, 8, 9])
    path = tmp_path / "with_line.vtu"
    meshio.write(path, meshio.Mesh(x, [("triangle6", renumber[SQUARE6]), ("line", np.array([[2, 0]])),
                                       ("tetra", np.array([[0, 1, 2, 3]]))]))
    loaded = ShellMesh.load(path)
    assert np.allclose(loaded.vertices, mesh.vertices)
    assert np.array_equal(loaded.triangles, SQUARE6)
    assert loaded.source_vertex_ids.tolist() == renumber.tolist()
    assert [loaded.vertex_from_source(i) for i in range(11)] == [0, 1, -1, 2, 3, 4, 5, 6, 7, 8, -1]


def test_load_prefers_quadratic_triangles_and_accepts_2d_points(tmp_path):
    mesh = _square()
    path = tmp_path / "both.vtk"
    meshio.write(path, meshio.Mesh(mesh.vertices[:, :2], [("triangle", SQUARE_TRIS), ("triangle6", SQUARE6)]))
    loaded = ShellMesh.load(path)
    assert np.array_equal(loaded.triangles, SQUARE6)
    assert np.allclose(loaded.vertices, mesh.vertices)


def test_load_missing_file_names_the_path(tmp_path):
    path = tmp_path / "nowhere" / "sheet.vtu"
    with pytest.raises(MeshError, match="no such file") as info:
        ShellMesh.load(path)
    assert str(path) in str(info.value)


def test_load_file_without_triangles_is_an_error(tmp_path):
    path = tmp_path / "solid.vtu"
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    meshio.write(path, meshio.Mesh(x, [("tetra", np.array([[0, 1, 2, 3]]))]))
    with pytest.raises(MeshError, match="no triangles") as info:
        ShellMesh.load(path)
    assert str(path) in str(info.value) and "tetra" in str(info.value)


def test_load_validates_the_content(tmp_path):
    path = tmp_path / "twisted.vtu"
    twisted = np.array([SQUARE6[0], SQUARE6[1, REVERSED]])
    meshio.write(path, meshio.Mesh(_square().vertices, [("triangle6", twisted)]))
    with pytest.raises(MeshError, match="inconsistently oriented") as info:
        ShellMesh.load(path)
    assert str(info.value).startswith("twisted.vtu: ")
