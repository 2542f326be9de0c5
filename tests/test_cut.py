"""The cutter (thesis chapter 5): validity after every cut, separation, counts, baselines."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wcut.cut import METHODS, CutError, Cutter, Plane, Polygon, TriangleSurface
from wcut.mesh import beam
from wcut.topology import TetTopology, check_topology, connected_components

REMESHING = ("paulus", "bielser", "snap")


def _cut(mesh, surface, method="paulus", epsilon=0.1, topo=None):
    topo = topo or TetTopology(mesh)
    result = Cutter(topo, method=method, epsilon=epsilon).cut(surface)
    return topo, result


def _sides(mesh, plane: Plane) -> np.ndarray:
    """Component label of each element's centroid side: +1 / -1 of the plane."""
    centroids = mesh.vertices[mesh.tets].mean(axis=1)
    return np.sign(plane.signed_distance(centroids))


def assert_separated(mesh, plane: Plane) -> None:
    """Elements on the two sides of a complete plane cut are in different components."""
    labels = connected_components(mesh)
    side = _sides(mesh, plane)
    assert not set(labels[side > 0]) & set(labels[side < 0])


@pytest.fixture(scope="module")
def cube():
    return beam(4, 4, 4, tets_per_hex=5)


@pytest.mark.parametrize("method", ("paulus", "bielser"))
@pytest.mark.parametrize("epsilon", (0.0, 0.1, 0.3))
def test_complete_plane_cut_is_valid_and_separates(cube, method, epsilon):
    plane = Plane([0.43, 0.5, 0.5], [1.0, 0.2, 0.1])
    topo, result = _cut(cube, plane, method, epsilon)
    check_topology(topo, cube.volumes().sum())
    after = topo.to_mesh()
    assert connected_components(after).max() == 1
    assert_separated(after, plane)
    assert result.stats.cut_elements > 0 and not result.stats.refused or epsilon > 0


def test_paulus_adds_fewer_nodes_than_bielser(cube):
    """Thesis 5.2.1: about 2 added nodes per cut element against 4.2-5.6 for Bielser."""
    plane = Plane([0.43, 0.5, 0.5], [1.0, 0.2, 0.1])
    added = {}
    for method in ("paulus", "bielser"):
        topo, result = _cut(cube, plane, method, 0.0)
        added[method] = (topo.vertex_count - cube.vertex_count) / result.stats.cut_elements
    assert 1.5 < added["paulus"] < 3.2
    assert 4.0 < added["bielser"] < 6.0


def test_snapping_reduces_added_nodes(cube):
    plane = Plane([0.43, 0.5, 0.5], [1.0, 0.2, 0.1])
    counts = [_cut(cube, plane, "paulus", e)[0].vertex_count for e in (0.0, 0.1, 0.3)]
    assert counts[0] > counts[1] > counts[2]


def test_cut_along_grid_plane_snaps_nothing_and_duplicates_the_plane(cube):
    """A plane exactly through a layer of vertices: nothing to remesh, every vertex on it
    (all in faces on the plane) is duplicated once."""
    plane = Plane([0.5, 0.0, 0.0], [1.0, 0.0, 0.0])
    topo, result = _cut(cube, plane, "paulus", 0.0)
    check_topology(topo, cube.volumes().sum())
    on_plane = np.sum(np.isclose(cube.vertices[:, 0], 0.5))
    assert topo.vertex_count == cube.vertex_count + on_plane
    assert topo.tet_count == cube.tet_count
    assert_separated(topo.to_mesh(), Plane([0.5, 0, 0], [1, 0, 0]))


def test_surface_missing_the_mesh_changes_nothing(cube):
    topo, result = _cut(cube, Plane([5.0, 0.0, 0.0], [1.0, 0.0, 0.0]))
    assert result.change.is_empty and result.stats.cut_elements == 0


def test_repeating_a_cut_changes_nothing(cube):
    plane = Plane([0.43, 0.5, 0.5], [1.0, 0.2, 0.1])
    topo, _ = _cut(cube, plane)
    vertices, tets = topo.vertex_count, topo.tet_count
    _, again = _cut(cube, plane, topo=topo)
    assert again.change.is_empty
    assert (topo.vertex_count, topo.tet_count) == (vertices, tets)


def test_crossing_cuts_make_four_pieces(cube):
    topo = TetTopology(cube)
    cutter = Cutter(topo, epsilon=0.1)
    a, b = Plane([0.47, 0.5, 0.5], [1.0, 0.1, 0.0]), Plane([0.5, 0.53, 0.5], [0.05, 1.0, 0.1])
    for plane in (a, b):
        cutter.cut(plane)
        check_topology(topo, cube.volumes().sum())
    after = topo.to_mesh()
    labels = connected_components(after)
    quadrant = (_sides(after, a) > 0) * 2 + (_sides(after, b) > 0)
    assert labels.max() == 3
    for q in range(4):
        assert len(set(labels[quadrant == q])) == 1


def test_partial_cut_with_a_polygon_opens_a_slit_but_keeps_one_piece(cube):
    """A bounded polygon that enters from one face and stops halfway: a crack, not a split."""
    poly = Polygon([[0.43, -0.1, -0.1], [0.43, 1.1, -0.1], [0.43, 1.1, 0.55], [0.43, -0.1, 0.55]])
    topo, result = _cut(cube, poly, "paulus", 0.1)
    check_topology(topo, cube.volumes().sum())
    after = topo.to_mesh()
    assert connected_components(after).max() == 0
    assert topo.vertex_count > cube.vertex_count + 10  # faces opened: vertices duplicated
    assert result.stats.unsewn_faces > 0


def test_triangulated_surface_cut(cube):
    """A folded (two-triangle strip, bent) surface spanning the cube separates it."""
    v = np.array([[0.3, -1, -1], [0.3, 2, -1], [0.6, -1, 2], [0.6, 2, 2]], float)
    surface = TriangleSurface(v, np.array([[0, 1, 3], [0, 3, 2]]))
    topo, _ = _cut(cube, surface, "paulus", 0.1)
    check_topology(topo, cube.volumes().sum())
    assert connected_components(topo.to_mesh()).max() == 1


def test_delete_removes_the_crossed_elements(cube):
    plane = Plane([0.43, 0.5, 0.5], [1.0, 0.2, 0.1])
    topo, result = _cut(cube, plane, "delete")
    check_topology(topo)
    after = topo.to_mesh()
    assert after.tet_count == cube.tet_count - result.stats.cut_elements
    assert after.volumes().sum() < cube.volumes().sum()
    assert connected_components(after).max() == 1


def test_change_interpolates_current_positions(cube):
    """Cuts in the current configuration: new vertices get rest AND current positions from
    the same weights, so an affinely deformed body stays affine."""
    A = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.2]])
    topo = TetTopology(cube, positions=cube.vertices @ A.T + [0.1, 0.2, 0.3])
    Cutter(topo, epsilon=0.1).cut(Plane([0.6, 0.7, 0.8], [1.0, 0.3, -0.2]))
    assert np.allclose(topo.positions, topo.rest_positions @ A.T + [0.1, 0.2, 0.3], atol=1e-12)


def test_bad_arguments():
    topo = TetTopology(beam(1, 1, 1))
    with pytest.raises(CutError, match="unknown cut method"):
        Cutter(topo, method="laser")
    with pytest.raises(CutError, match="epsilon"):
        Cutter(topo, epsilon=0.7)
    assert set(METHODS) == {"paulus", "bielser", "snap", "delete"}


# --- property-based: random planes, including planes through vertices, edges and faces -----

MESH = beam(3, 3, 3, tets_per_hex=6)
VOLUME = MESH.volumes().sum()


@st.composite
def planes(draw):
    kind = draw(st.sampled_from(["random", "vertex", "edge", "face"]))
    normal = np.array(draw(st.tuples(*[st.floats(-1, 1)] * 3)))
    if np.linalg.norm(normal) < 0.1:
        normal = np.array([1.0, 0.3, 0.2])
    if kind == "random":
        point = np.array(draw(st.tuples(*[st.floats(0.05, 0.95)] * 3)))
    else:
        t = draw(st.integers(0, MESH.tet_count - 1))
        corners = MESH.vertices[MESH.tets[t]]
        point = corners[0]
        if kind == "edge":  # the plane contains an edge
            normal = np.cross(corners[1] - corners[0], normal)
        elif kind == "face":  # the plane is a face's plane
            normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        if np.linalg.norm(normal) < 1e-9:
            normal = np.array([1.0, 0.3, 0.2])
    return Plane(point, normal)


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(plane=planes(), method=st.sampled_from(REMESHING), epsilon=st.sampled_from([0.0, 0.1, 0.3]))
def test_random_plane_cuts_keep_the_mesh_valid(plane, method, epsilon):
    topo = TetTopology(MESH)
    result = Cutter(topo, method=method, epsilon=epsilon).cut(plane)
    check_topology(topo, VOLUME)
    after = topo.to_mesh()
    if method != "snap" and not result.stats.refused:
        assert_separated(after, plane)


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(first=planes(), second=planes(), epsilon=st.sampled_from([0.0, 0.2]))
def test_successive_random_cuts_keep_the_mesh_valid(first, second, epsilon):
    topo = TetTopology(MESH)
    cutter = Cutter(topo, epsilon=epsilon)
    for plane in (first, second, first):
        cutter.cut(plane)
        check_topology(topo, VOLUME)


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(plane=planes(), depth=st.floats(0.2, 0.8))
def test_random_partial_cuts_keep_the_mesh_valid(plane, depth):
    """A square patch of the plane reaching ``depth`` into the mesh from outside."""
    n = plane.normal / np.linalg.norm(plane.normal)
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    centre = plane.point - w * (1.0 - depth)  # the patch's edge is `depth` into the cube
    corners = [centre + 2 * u - 1.0 * w, centre + 2 * u + 1.0 * w, centre - 2 * u + 1.0 * w, centre - 2 * u - 1.0 * w]
    topo = TetTopology(MESH)
    Cutter(topo, epsilon=0.1).cut(Polygon(corners))
    check_topology(topo, VOLUME)
