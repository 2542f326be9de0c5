"""Tests of wcut.ar.embedding and wcut.ar.internal: material points carried through cuts."""

from __future__ import annotations

import numpy as np
import pytest

import wcut
from wcut.ar.embedding import Embedding, mapped_points
from wcut.ar.internal import InternalStructure
from wcut.ar.synth import tube
from wcut.cut import Cutter, Plane
from wcut.cut.surface import TriangleSurface
from wcut.errors import CaptureError, WcutError
from wcut.topology import TetTopology


@pytest.fixture
def block():
    return wcut.beam(4, 4, 4, size=(0.04, 0.04, 0.04))


def affine(points):
    A = np.array([[1.2, 0.1, 0.0], [-0.05, 0.9, 0.2], [0.0, 0.1, 1.1]])
    return points @ A.T + [0.01, -0.02, 0.03]


def test_embedded_points_follow_an_affine_motion_exactly(block):
    rng = np.random.default_rng(0)
    points = rng.uniform(0.001, 0.039, (200, 3))
    e = Embedding.locate(block.vertices, block.tets, points)
    np.testing.assert_allclose(e.positions(block.vertices, block.tets), points, atol=1e-12)
    np.testing.assert_allclose(e.positions(affine(block.vertices), block.tets), affine(points), atol=1e-12)
    np.testing.assert_allclose(e.weights.sum(axis=1), 1.0)


def test_points_outside_are_refused_or_dropped_and_can_be_extrapolated(block):
    outside = np.array([[0.02, 0.02, 0.08]])
    with pytest.raises(WcutError, match="outside the mesh"):
        Embedding.locate(block.vertices, block.tets, outside, what="feature")
    kept, inside = Embedding.locate_inside(block.vertices, block.tets, np.vstack([outside, [[0.02, 0.02, 0.02]]]))
    assert inside.tolist() == [False, True] and len(kept.element) == 1
    # extrapolated by its nearest element's affine map (a cut's look-ahead beyond the boundary)
    np.testing.assert_allclose(mapped_points(block.vertices, block.tets, affine(block.vertices), [[0.02, 0.02, 0.05]]),
                               affine(np.array([[0.02, 0.02, 0.05]])), atol=1e-12)


def test_after_a_cut_points_land_on_their_side_and_keep_their_place(block):
    rng = np.random.default_rng(1)
    points = rng.uniform(0.001, 0.039, (300, 3))
    points = points[np.abs(points[:, 0] - 0.0213) > 1e-4]
    e = Embedding.locate(block.vertices, block.tets, points)
    topo = TetTopology(block)
    change = Cutter(topo, epsilon=0.0).cut(Plane([0.0213, 0, 0], [1, 0, 0])).change
    mesh = topo.to_mesh()
    after = e.after(change, mesh.vertices, mesh.tets)
    np.testing.assert_allclose(after.positions(mesh.vertices, mesh.tets), points, atol=1e-12)
    # pull the two pieces apart: each point goes with its side of the cut
    left = mesh.vertices[:, 0] < 0.0213 - 1e-9
    on = np.abs(mesh.vertices[:, 0] - 0.0213) < 1e-9
    side_of_vertex = np.where(left, -1, 1)
    # a vertex on the cut belongs to the piece its elements are in
    tet_side = np.sign(mesh.vertices[mesh.tets].mean(axis=1)[:, 0] - 0.0213)
    for t, tet in enumerate(mesh.tets):
        side_of_vertex[tet[on[tet]]] = tet_side[t]
    moved = mesh.vertices + 0.01 * side_of_vertex[:, None] * [1.0, 0.0, 0.0]
    got = after.positions(moved, mesh.tets)
    expected = points + 0.01 * np.sign(points[:, 0] - 0.0213)[:, None] * [1.0, 0.0, 0.0]
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_an_internal_structure_loses_the_triangles_the_cut_crosses(block):
    vertices, triangles = tube([[0.005, 0.02, 0.02], [0.02, 0.02, 0.02], [0.035, 0.02, 0.02]], 0.004, 8)
    s = InternalStructure.embedded("vessel", vertices, triangles, block.vertices, block.tets)
    surface = TriangleSurface(np.array([[0.0213, -1, -1], [0.0213, 1, -1], [0.0213, 0, 1.0]]), np.array([[0, 1, 2]]))
    before = s.triangles.copy()
    deleted = s.cut(surface)
    a = vertices[before][:, :, 0]
    crossing = (a.min(axis=1) < 0.0213) & (a.max(axis=1) > 0.0213)
    assert deleted == int(crossing.sum()) == 16 and s.deleted == 16
    assert {tuple(t) for t in s.triangles.tolist()} == {tuple(t) for t in before[~crossing].tolist()}
    np.testing.assert_allclose(s.positions(block.vertices, block.tets), vertices, atol=1e-12)


def test_an_internal_structure_outside_the_model_is_a_capture_error(block, tmp_path):
    path = tmp_path / "tumour.obj"
    path.write_text("v 0 0 1\nv 1 0 1\nv 0 1 1\nf 1 2 3\n")
    with pytest.raises(CaptureError, match="tumour.obj"):
        InternalStructure.load(path, block.vertices, block.tets)
    path.write_text("v 0 0\n")
    with pytest.raises(CaptureError, match="tumour.obj"):
        InternalStructure.load(path, block.vertices, block.tets)
