"""Material points embedded in a tetrahedral mesh by barycentric coordinates (thesis 7.4.3, 7.5.4).

Surface features and the vertices of internal structures move with the model: each is a
point of the rest configuration, held by the element that contains it with its barycentric
coordinates there, so its current position is ``sum_k w_k x[tet_k]``. After a topological
change the points of removed elements are located again among the children of their parent
element (the re-initialisation of 7.5.4, local like the change itself): the pieces of a split
element tile its rest shape, and the two lips of a cut coincide at rest, so a point strictly on
one side of the cut lands in an element of that side.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import WcutError
from ..mesh import edge_matrices

#: how far (in barycentric units) a point may lie outside every element and still be embedded
OUTSIDE_TOLERANCE = 0.05


def _barycentric(rest: np.ndarray, tets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P, 4) barycentric coordinates of ``points`` (P, 3) in the elements ``tets`` (P, 4)."""
    corners = tets[:, :4]
    inverse = np.linalg.inv(edge_matrices(rest, corners))  # (P, 3, 3), Dm = [X0-X3 | X1-X3 | X2-X3]
    xi = np.einsum("pij,pj->pi", inverse, points - rest[corners[:, 3]])
    return np.concatenate([xi, 1.0 - xi.sum(axis=1, keepdims=True)], axis=1)


def _nearest(rest: np.ndarray, tets: np.ndarray, points: np.ndarray):
    """:func:`_best_of` over the 32 elements whose centroids are nearest each point."""
    count = min(len(tets), 32)
    _, candidates = cKDTree(rest[tets[:, :4]].mean(axis=1)).query(points, k=count)
    return _best_of(rest, tets, points, np.asarray(candidates).reshape(len(points), count))


def _best_of(rest: np.ndarray, tets: np.ndarray, points: np.ndarray, candidates: np.ndarray):
    """For each point, the candidate element (``candidates`` (P, C), -1 for none) whose
    barycentric coordinates it violates least: (element (P,), weights (P, 4), worst (P,))."""
    P, C = candidates.shape
    safe = np.maximum(candidates, 0)
    bary = _barycentric(rest, tets[safe.reshape(-1)], np.repeat(points, C, axis=0)).reshape(P, C, 4)
    worst = np.where(candidates >= 0, bary.min(axis=2), -np.inf)
    pick = worst.argmax(axis=1)
    rows = np.arange(P)
    return safe[rows, pick], bary[rows, pick], worst[rows, pick]


class Embedding:
    """Points (K, 3) of the rest configuration held by the elements of a tetrahedral mesh.

    Attributes:
        element: (K,) int64 element of each point.
        weights: (K, 4) barycentric weights on the element's four corners (clamped to [0, 1]
            and renormalised for points just outside the mesh, e.g. on a curved surface).
        rest_points: (K, 3) the points (m).
    """

    def __init__(self, element: np.ndarray, weights: np.ndarray, rest_points: np.ndarray):
        self.element, self.weights, self.rest_points = element, weights, rest_points

    @classmethod
    def locate(cls, rest: np.ndarray, tets: np.ndarray, points, *, what: str = "points") -> "Embedding":
        """Embed ``points`` (K, 3) (m, rest configuration) in the mesh (``rest`` (N, 3) vertex
        positions, ``tets`` (M, 4+) elements; a quadratic element is held by its corners).

        Raises a :class:`WcutError` naming the first point farther than
        :data:`OUTSIDE_TOLERANCE` (barycentric) outside every element.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(points).all():
            raise WcutError(f"{what}: non-finite coordinates")
        embedding, inside = cls.locate_inside(rest, tets, points)
        if not inside.all():
            bad = int(np.flatnonzero(~inside)[0])
            raise WcutError(f"{what}: point {bad} at {np.round(points[bad], 5).tolist()} m is outside the mesh")
        return embedding

    @classmethod
    def locate_inside(cls, rest: np.ndarray, tets: np.ndarray, points, tolerance: float = OUTSIDE_TOLERANCE):
        """``(embedding, inside)``: the points (K, 3) within ``tolerance`` (barycentric) of an
        element embedded, and the (K,) mask of those kept."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0:
            return cls(np.zeros(0, np.int64), np.zeros((0, 4)), points), np.zeros(0, bool)
        element, bary, worst = _nearest(rest, tets, points)
        inside = np.isfinite(points).all(axis=1) & (worst >= -tolerance)
        return cls(element[inside].astype(np.int64), _clamped(bary[inside]), points[inside]), inside

    def positions(self, x: np.ndarray, tets: np.ndarray) -> np.ndarray:
        """(K, 3) current positions of the points, given vertex positions ``x`` (N, 3)."""
        return np.einsum("kc,kcj->kj", self.weights, x[tets[self.element, :4]])

    def after(self, change, rest: np.ndarray, tets: np.ndarray) -> "Embedding":
        """The embedding in the mesh after ``change`` (a :class:`wcut.topology.TopologyChange`;
        ``rest``, ``tets``: the new mesh). A point of a kept element keeps its weights; a point
        of a removed element (or of one whose rest shape changed: a snapped vertex) is located
        among the added and reshaped elements, which tile the removed ones at rest (splits and flips keep the region, and the two lips of a cut coincide,
        so a point strictly on one side lands in an element of that side)."""
        if len(self.element) == 0:
            return self
        added = np.asarray(change.added_elements, dtype=np.int64)
        kept = np.ones(change.element_count_after, dtype=bool)
        kept[added] = False
        old_to_new = np.full(change.element_count_before, -1, dtype=np.int64)
        old_to_new[np.asarray(change.element_parent)[kept]] = np.flatnonzero(kept)
        element, weights = old_to_new[self.element], self.weights.copy()
        reshaped = np.asarray(change.element_rest_changed, dtype=bool)  # around a snapped vertex
        moved = element < 0
        moved[~moved] = reshaped[element[~moved]]
        added = np.union1d(added, np.flatnonzero(reshaped))
        if moved.any():
            if len(added) == 0:  # elements deleted without replacement: the nearest survivors
                again = Embedding.locate_inside(rest, tets, self.rest_points[moved], np.inf)[0]
                element[moved], weights[moved] = again.element, again.weights
            else:
                count = min(len(added), 32)
                _, near = cKDTree(rest[tets[added, :4]].mean(axis=1)).query(self.rest_points[moved], k=count)
                found, bary, _ = _best_of(rest, tets, self.rest_points[moved],
                                          added[np.asarray(near).reshape(int(moved.sum()), count)])
                element[moved], weights[moved] = found, _clamped(bary)
        return Embedding(element, weights, self.rest_points)


def _clamped(bary: np.ndarray) -> np.ndarray:
    w = np.clip(bary, 0.0, 1.0)
    return w / w.sum(axis=1, keepdims=True)


def mapped_points(rest: np.ndarray, tets: np.ndarray, x: np.ndarray, points) -> np.ndarray:
    """(K, 3) images under the current configuration ``x`` (N, 3) of rest points (K, 3) (m),
    each by the affine map of the element it violates least. A point outside the mesh (a
    cut's look-ahead beyond the boundary) is extrapolated by its nearest element's map rather
    than clamped onto the surface."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    element, bary, _ = _nearest(rest, tets, points)
    return np.einsum("kc,kcj->kj", bary, x[tets[element, :4]])
