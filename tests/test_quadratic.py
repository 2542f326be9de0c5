"""Quadratic meshes (wcut/quadratic.py): validation, I/O, conversion with curved boundaries,
and the tessellated surface written to USD."""

import numpy as np
import pytest

import wcut
from wcut import p2
from wcut.errors import MeshError
from wcut.quadratic import QuadraticTetMesh, SurfaceTessellation, to_quadratic

CENTER, RADIUS = np.array([0.5, 0.5, 0.5]), 0.5


def sphere(points):
    """Signed distance to a sphere that passes through the cube's face centres."""
    return np.linalg.norm(points - CENTER, axis=1) - RADIUS


@pytest.fixture(scope="module")
def cube():
    return wcut.beam(3, 3, 3, size=(1.0, 1.0, 1.0))


@pytest.fixture(scope="module")
def ball():
    """A coarse ball: the cube's vertices inside the sphere, pushed onto it, then curved."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(3)
    directions = rng.standard_normal((60, 3))
    surface = CENTER + RADIUS * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    inner = CENTER + 0.25 * rng.uniform(-1, 1, (8, 3))
    points = np.vstack([surface, inner])
    tets = Delaunay(points).simplices
    linear = wcut.TetMesh(points, tets)
    keep = np.abs(linear.volumes()) > 1e-4  # drop slivers of the convex hull
    return wcut.TetMesh(points, tets[keep]) if keep.all() else linear


def test_straight_conversion_keeps_volume_and_shares_edge_nodes(cube):
    q = to_quadratic(cube)
    assert q.vertex_count == cube.vertex_count + len(cube.edges())
    assert q.tet_count == cube.tet_count
    np.testing.assert_array_equal(q.tets[:, :4], cube.tets)
    np.testing.assert_allclose(q.volumes(), cube.volumes(), rtol=1e-12)
    np.testing.assert_allclose(q.vertices[q.tets[:, 4:]],
                               0.5 * (q.vertices[q.tets[:, p2.EDGES[:, 0]]] + q.vertices[q.tets[:, p2.EDGES[:, 1]]]))
    np.testing.assert_array_equal(q.corner_ids, np.arange(cube.vertex_count))
    assert q.linear().tet_count == cube.tet_count


def test_curved_conversion_puts_boundary_edge_nodes_on_the_surface(ball):
    q = to_quadratic(ball, sphere)
    boundary = q.boundary().triangles
    edge_nodes = np.unique(boundary[:, 3:])
    np.testing.assert_allclose(sphere(q.vertices[edge_nodes]), 0.0, atol=1e-9)
    at_gauss, at_nodes = p2.jacobian_determinants(q.vertices, q.tets)
    assert at_gauss.min() > 0 and at_nodes.min() > 0
    exact = 4 / 3 * np.pi * RADIUS ** 3
    # the curved ball is far closer to the sphere's volume than the polyhedron
    assert abs(q.volumes().sum() - exact) < 0.25 * abs(ball.volumes().sum() - exact)


def test_curved_conversion_onto_a_triangle_surface(ball):
    """A fine triangulated sphere serves as the smooth surface, like the implicit one."""
    directions = np.random.default_rng(4).standard_normal((3000, 3))
    from scipy.spatial import ConvexHull

    vertices = CENTER + RADIUS * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    triangles = ConvexHull(vertices).simplices
    q = to_quadratic(ball, (vertices, triangles))
    edge_nodes = np.unique(q.boundary().triangles[:, 3:])
    assert np.abs(sphere(q.vertices[edge_nodes])).max() < 4e-3  # the facets' sag at that resolution


def test_a_surface_far_away_cannot_fold_elements(cube):
    """Edge nodes pulled 0.4 m off a 1/3 m grid would fold elements; the curving is halved
    where it does, and the mesh stays valid."""
    far = lambda x: np.linalg.norm(x - CENTER, axis=1) - 1.2  # noqa: E731
    q = to_quadratic(cube, far)
    at_gauss, at_nodes = p2.jacobian_determinants(q.vertices, q.tets)
    assert at_gauss.min() > 0 and at_nodes.min() > 0
    moved = np.linalg.norm(q.vertices[cube.vertex_count:] - 0.5 * (
        cube.vertices[p2.midpoint_edges(cube.tets)[0][:, 0]] + cube.vertices[p2.midpoint_edges(cube.tets)[0][:, 1]]),
        axis=1)
    assert moved.max() > 0.01  # it did curve where it could


def test_save_and_load_round_trip(tmp_path, ball):
    q = to_quadratic(ball, sphere)
    path = tmp_path / "ball.vtu"
    q.save(path)
    back = QuadraticTetMesh.load(path)
    np.testing.assert_allclose(back.vertices, q.vertices)
    np.testing.assert_array_equal(back.tets, q.tets)


def test_reoriented_elements_keep_their_edge_nodes(cube):
    q = to_quadratic(cube)
    flipped = q.tets.copy()
    flipped[::2] = flipped[::2][:, [0, 2, 1, 3, 6, 5, 4, 7, 9, 8]]
    again = QuadraticTetMesh(q.vertices, flipped)
    assert again.reoriented_count == (q.tet_count + 1) // 2
    np.testing.assert_array_equal(again.tets, q.tets)


@pytest.mark.parametrize("case, message", [
    ("shape", r"shape \(M, 10\)"),
    ("index", "out of range"),
    ("corner_is_edge_node", "both a corner and an edge node"),
    ("two_nodes_on_an_edge", "inconsistent edge nodes"),
    ("folded", "folds"),
    ("nan", "non-finite"),
])
def test_invalid_meshes_are_refused(cube, case, message):
    q = to_quadratic(cube)
    vertices, tets = q.vertices.copy(), q.tets.copy()
    if case == "shape":
        tets = tets[:, :8]
    elif case == "index":
        tets[3, 7] = len(vertices) + 5
    elif case == "corner_is_edge_node":
        tets[0, 4] = tets[1, 0]
    elif case == "two_nodes_on_an_edge":
        shared = np.bincount(tets[:, 4:].ravel()).argmax()  # an edge node of many elements
        e, k = np.argwhere(tets == shared)[0]
        vertices = np.vstack([vertices, vertices[shared]])
        tets[e, k] = len(vertices) - 1
    elif case == "folded":
        e = 7
        corner, node = tets[e, 1], tets[e, 4]  # pull the node of edge (0, 1) past corner 1
        vertices[node] = vertices[corner] + 0.6 * (vertices[corner] - vertices[tets[e, 0]])
    elif case == "nan":
        vertices[tets[2, 5], 1] = np.nan
    with pytest.raises(MeshError, match=message):
        QuadraticTetMesh(vertices, tets, name="broken")


def test_load_reports_a_file_without_quadratic_elements(tmp_path, cube):
    path = tmp_path / "linear.vtu"
    cube.save(path)
    with pytest.raises(MeshError, match="no quadratic tetrahedra"):
        QuadraticTetMesh.load(path)
    with pytest.raises(MeshError, match="no such file"):
        QuadraticTetMesh.load(tmp_path / "missing.vtu")


def _edge_use(triangles):
    edges = np.sort(triangles[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)[1]


@pytest.mark.parametrize("level", [0, 1, 2, 3])
def test_tessellation_is_closed_and_follows_the_curved_surface(ball, level):
    q = to_quadratic(ball, sphere)
    t = q.surface_tessellation(level)
    faces = len(q.boundary().triangles)
    assert len(t.triangles) == faces * 4 ** level
    assert (_edge_use(t.triangles) == 2).all()  # shared points: a closed surface, no cracks
    points = t.points(q.vertices)
    np.testing.assert_allclose(t.weights.sum(axis=1), 1.0)
    # every rendered point lies on the curved faces, which hug the sphere
    assert np.abs(sphere(points)).max() < (0.02 if level else 1e-9 + np.abs(sphere(q.vertices[np.unique(
        q.boundary().triangles[:, :3])])).max())
    normals = np.cross(points[t.triangles[:, 1]] - points[t.triangles[:, 0]],
                       points[t.triangles[:, 2]] - points[t.triangles[:, 0]])
    outward = np.einsum("ti,ti->t", normals, points[t.triangles].mean(axis=1) - CENTER)
    assert (outward > 0).all()


def test_tessellation_level_is_checked(ball):
    with pytest.raises(MeshError, match="subdivision level"):
        to_quadratic(ball).surface_tessellation(9)


def test_linear_tessellation_is_the_boundary(cube):
    t = SurfaceTessellation.of_linear(cube)
    b = cube.boundary()
    np.testing.assert_array_equal(t.points(cube.vertices), cube.vertices[b.vertex_ids])
    np.testing.assert_array_equal(t.triangles, b.local_triangles)
