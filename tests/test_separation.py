"""Pieces as a simulation sees them, and whether a complete plane cut separated a mesh."""

import numpy as np

from wcut.cut import Plane
from wcut.cut.separation import pieces, plane_separation

# two tetrahedra on either side of x = 0 that share vertex 0 only (a hinge), and a third, apart
X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 1.0],
              [-1.0, 0.0, 0.0], [-1.0, 0.0, 1.0], [-1.0, 1.0, 0.0],
              [5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0], [5.0, 0.0, 1.0]])
HINGED = np.array([[0, 1, 2, 3], [0, 4, 5, 6], [7, 8, 9, 10]])
PLANE = Plane([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])


def test_elements_sharing_only_a_vertex_are_one_piece():
    assert pieces(HINGED).tolist() == [0, 0, 1]
    assert pieces(HINGED[[0, 2]]).tolist() == [0, 1]


def test_a_hinge_across_the_plane_is_not_a_separation():
    s = plane_separation(X, HINGED, PLANE, 1e-9)
    assert (s.pieces, s.joined_pieces, s.straddling_elements) == (2, 1, 0) and not s.separated
    assert "1 piece(s) still hold elements on both sides" in s.describe()


def test_apart_is_separated_and_a_straddling_element_is_measured():
    s = plane_separation(X, HINGED[[0, 2]], PLANE, 1e-9)
    assert s.separated and s.pieces == 2
    x = X.copy()
    x[0, 0] = -0.05  # vertex 0 pokes 0.05 m across: element 0 straddles
    s = plane_separation(x, HINGED, PLANE, 1e-9)
    assert s.straddling_elements == 1 and not s.separated
    mean_edge = np.mean([np.linalg.norm(x[a] - x[b]) for t in HINGED for a, b in
                         [(t[0], t[1]), (t[0], t[2]), (t[0], t[3]), (t[1], t[2]), (t[1], t[3]), (t[2], t[3])]])
    assert np.isclose(s.deepest_reach, 0.05 / mean_edge)


def test_a_flat_element_lying_in_the_plane_belongs_to_neither_side():
    x = np.vstack([X, [[1e-5, 0.5, 0.5]]])
    flat = np.vstack([HINGED[[0, 2]], [[0, 2, 3, 11]]])  # a sliver on the plane, on element 0's face
    x[[2, 3], 0] = 0.0
    x[1, 0] = 1.0
    s = plane_separation(x, np.vstack([flat, [[0, 4, 5, 6]]]), PLANE, 1e-9, mean_edge_length=1.0)
    assert s.joined_pieces == 1  # elements 0 and 3 hinge at vertex 0
    s = plane_separation(x, flat, PLANE, 1e-9, mean_edge_length=1.0)
    assert s.separated
