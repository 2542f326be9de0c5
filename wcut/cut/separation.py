"""Whether a complete cut separated a mesh, judged as a simulation sees it.

Two elements move together when they share a vertex, not only a face: a piece hinged at one
vertex or one edge across the cut swings with the other side. So the pieces of a mesh here are
its elements connected through shared vertices (:func:`pieces`), and a complete plane cut has
separated the mesh when no piece holds elements on both sides of the plane
(:func:`plane_separation`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .surface import Plane


#: An element whose corners are all this close to a cut plane (relative to the mean edge
#: length) lies in it: it belongs to neither side, and stays with a neighbour's.
IN_PLANE = 1e-3


def pieces(tets: np.ndarray, vertex_count: int | None = None) -> np.ndarray:
    """(M,) label of each element's piece (elements sharing a vertex are in one piece), labels
    0..C-1 in order of first element."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    tets = np.asarray(tets, dtype=np.int64)[:, :4]
    count = len(tets)
    vertex_count = int(tets.max(initial=-1)) + 1 if vertex_count is None else int(vertex_count)
    # the bipartite graph elements - vertices: elements are connected through their vertices
    rows = np.repeat(np.arange(count), tets.shape[1])
    graph = coo_matrix((np.ones(rows.size), (rows, count + tets.ravel())), shape=(count + vertex_count,) * 2)
    _, labels = connected_components(graph, directed=False)
    labels = labels[:count]
    _, first = np.unique(labels, return_index=True)
    remap = np.empty(labels.max(initial=0) + 1, dtype=np.int64)
    remap[labels[np.sort(first)]] = np.arange(len(first))
    return remap[labels]


def element_sides(distances: np.ndarray, in_plane: float) -> np.ndarray:
    """(M,) side of a plane (+1, -1) each element is on, from its corners' signed distances
    (M, 4) (m): the side of the corner farthest from the plane, 0 for an element lying in it
    (every corner within ``in_plane``, m). Not the centroid's side: where a cut passes through a
    vertex a little off the plane (held there, thesis 6.1.4, or refused a snap), an element on
    one side of the cut may have its centroid just across the plane."""
    far = np.take_along_axis(distances, np.abs(distances).argmax(axis=1)[:, None], axis=1)[:, 0]
    return np.where(np.abs(far) <= in_plane, 0, np.sign(far)).astype(np.int64)


@dataclass(frozen=True)
class Separation:
    """What a complete plane cut left (:func:`plane_separation`).

    Attributes:
        pieces: pieces as a simulation sees them (elements sharing a vertex move together).
        joined_pieces: pieces holding elements on both sides of the plane: 0 when the cut
            separated the mesh.
        straddling_elements: elements with corners on both sides, beyond the tolerance.
        deepest_reach: the farthest a straddling element reaches across the plane, on its
            shorter side, relative to the mean edge length (0 without one).
    """

    pieces: int
    joined_pieces: int
    straddling_elements: int
    deepest_reach: float

    @property
    def separated(self) -> bool:
        return self.joined_pieces == 0

    def describe(self) -> str:
        """One sentence for an error message."""
        return (f"{self.joined_pieces} piece(s) still hold elements on both sides of the plane "
                f"({self.straddling_elements} element(s) straddle it, reaching up to "
                f"{100.0 * self.deepest_reach:.2g}% of an edge across)")


def plane_separation(vertices: np.ndarray, tets: np.ndarray, plane: Plane, tolerance: float, *,
                     mean_edge_length: float | None = None, in_plane: float = IN_PLANE) -> Separation:
    """How a complete cut along ``plane`` left ``tets`` (linear corners; rest or current
    positions ``vertices`` (N, 3), m). A corner within ``tolerance`` (m) of the plane is on it;
    an element is on a side by :func:`element_sides`, lying in the plane within ``in_plane``
    times ``mean_edge_length`` (by default the mesh's): such a flat element belongs to neither
    side and may stay with either. A cutter's ``in_plane`` (:attr:`Cutter.in_plane`) is
    larger where it holds vertices off the plane (curved boundaries)."""
    vertices, tets = np.asarray(vertices, dtype=np.float64), np.asarray(tets, dtype=np.int64)[:, :4]
    labels = pieces(tets, len(vertices))
    d = plane.signed_distance(vertices)[tets]  # (M, 4)
    edges = vertices[tets[:, [0, 0, 0, 1, 1, 2]]] - vertices[tets[:, [1, 2, 3, 2, 3, 3]]]
    if mean_edge_length is None:
        mean_edge_length = float(np.linalg.norm(edges, axis=2).mean()) if len(tets) else 1.0
    side = element_sides(d, in_plane * mean_edge_length)
    count = labels.max(initial=-1) + 1
    above = np.bincount(labels[side > 0], minlength=count) > 0
    below = np.bincount(labels[side < 0], minlength=count) > 0
    straddle = (d.max(axis=1) > tolerance) & (d.min(axis=1) < -tolerance)
    reach = np.minimum(d.max(axis=1), -d.min(axis=1))[straddle]
    return Separation(pieces=int(count), joined_pieces=int((above & below).sum()),
                      straddling_elements=int(straddle.sum()),
                      deepest_reach=float(reach.max(initial=0.0)) / mean_edge_length)

