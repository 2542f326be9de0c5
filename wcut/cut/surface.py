"""Separation surfaces: what a cutter intersects with the edges of a tetrahedral mesh.

Thesis 5.1: the first step of a cut samples the separation surface S on the mesh edges: for
every edge, the point where it crosses S and the unit normal of S there. For a partial cut
(one or two crossed edges of a tetrahedron) the remaining edges are intersected with the
*extension* of S (thesis 5.1.1). A :class:`CutSurface` answers both queries for M segments at
once (host side, float64, metres):

- :meth:`CutSurface.crossings` -- first strict crossing of each segment with the bounded S;
- :meth:`CutSurface.extension_crossings` -- the same against the extension of S;
- :meth:`CutSurface.distance` and :meth:`CutSurface.bounds`.

Crossing contract (the cutter relies on it). With a tolerance ``tol`` (m), an endpoint within
``tol`` of S is *on* S and never makes its segment cross: a segment crosses only where it goes
strictly from one side to the other, i.e. both endpoints are farther than ``tol`` from the
plane of the crossed piece of S, with opposite signs, and farther than ``tol`` from the bounded
S itself. A segment lying in S does not cross. The returned parameter ``t`` is in the open
interval (0, 1), the crossing point is ``a + t (b - a)``, and the normal is the surface's own
unit normal there (not flipped towards the segment: the side of ``a`` is
``sign(dot(normal, a - p))``).

Concrete surfaces: :class:`Plane` (infinite), :class:`TriangleSurface` (any triangulated
surface, open or closed; Wavefront .obj I/O), :class:`Polygon` (bounded planar polygon) and
:class:`SweptBlade` (the surface a straight blade sweeps over animation frames).
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod

import numpy as np
import warp as wp
from scipy.spatial import cKDTree

from ..errors import WcutError
from ..io import atomic_path
from ..kernels import surface_query
from ..topology.mesh import ball_pairs

#: Barycentric tolerance of the segment/triangle test: a crossing point up to this fraction of
#: the triangle's height outside an edge still counts, so a segment through a shared edge or
#: vertex of two triangles is never missed (it hits both; the first is reported once).
BARY_TOL = 1e-9
#: A triangle is degenerate when twice its area is below this times its longest edge squared.
DEGENERATE_TOL = 1e-12
#: A polygon is planar when no vertex is farther from its plane than this times its size.
PLANARITY_TOL = 1e-9
#: Most pieces the broad phase of a triangulated surface cuts it into.
MAX_PIECES = 1 << 21
#: Query points per block of a broad-phase k-d tree query (bounds the memory of one query).
_BLOCK = 4096
#: a point query of at most this many (point, triangle) pairs measures every pair
_ALL_PAIRS = 512


class SurfaceError(WcutError):
    """A cut surface is invalid: zero normal, NaN, bad shape, non-planar polygon, empty or
    degenerate triangulation, or an unreadable surface file."""


def _array(x, shape: tuple, what: str) -> np.ndarray:
    """``x`` as a finite float64 array of ``shape`` (-1 = any length), else SurfaceError."""
    try:
        arr = np.array(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SurfaceError(f"{what} is not numeric: {exc}") from None
    if arr.ndim != len(shape) or any(s not in (-1, n) for s, n in zip(shape, arr.shape)):
        want = "(" + ", ".join("M" if s == -1 else str(s) for s in shape) + ")"
        raise SurfaceError(f"{what} must have shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise SurfaceError(f"{what} contains NaN or infinite values")
    return arr


def _segments(a, b, tol) -> tuple[np.ndarray, np.ndarray, float]:
    a, b = _array(a, (-1, 3), "segment starts a"), _array(b, (-1, 3), "segment ends b")
    if a.shape != b.shape:
        raise SurfaceError(f"segment starts {a.shape} and ends {b.shape} differ in shape")
    try:
        value = float(tol)
    except (TypeError, ValueError):
        value = np.nan
    if not (np.isfinite(value) and value >= 0):
        raise SurfaceError(f"tolerance must be a finite number >= 0 m, got {tol!r}")
    return a, b, value


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", u, v)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (M, 3) arrays: ``np.cross``'s arithmetic, operation for
    operation (the same bits), without its axis handling, which costs more than the
    arithmetic for the few rows of a point query."""
    u0, u1, u2 = u[:, 0], u[:, 1], u[:, 2]
    v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=1)


def _open_unit(t: np.ndarray) -> np.ndarray:
    """Clamp crossing parameters into the open interval (0, 1) (rounding can reach 0 or 1)."""
    return np.clip(t, np.nextafter(0.0, 1.0), np.nextafter(1.0, 0.0))


def _plane_crossings(a, b, tol, origin, normal) -> tuple[np.ndarray, np.ndarray]:
    """Strict crossings of segments with planes (one plane, or one per segment).

    A segment crosses when its signed distances d_a, d_b (m) to the plane through ``origin``
    with unit ``normal`` have opposite signs and |d| > tol at both ends; t = d_a / (d_a - d_b).
    """
    normal = np.broadcast_to(normal, a.shape)
    da, db = _dot(a - origin, normal), _dot(b - origin, normal)
    hit = (np.abs(da) > tol) & (np.abs(db) > tol) & ((da > 0) != (db > 0))
    t = np.full(len(a), np.nan)
    n = np.full(a.shape, np.nan)
    t[hit] = _open_unit(da[hit] / (da[hit] - db[hit]))
    n[hit] = normal[hit]
    return t, n


def _degenerate(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """Which triangles (rows of corners, m) have (numerically) zero area."""
    area2 = np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=-1)
    longest = np.max([np.sum((v1 - v0) ** 2, -1), np.sum((v2 - v1) ** 2, -1), np.sum((v0 - v2) ** 2, -1)], 0)
    return ~(area2 > DEGENERATE_TOL * longest)


def box_tree(lower: np.ndarray, upper: np.ndarray) -> wp.Bvh:
    """A CPU BVH of the boxes ``lower``-``upper`` (B, 3) (m, float64), rounded outwards to
    float32, for the compiled queries of :mod:`wcut.kernels.surface_query`."""
    low, up = lower.astype(np.float32), upper.astype(np.float32)
    low = np.where(low > lower, np.nextafter(low, np.float32(-np.inf)), low)
    up = np.where(up < upper, np.nextafter(up, np.float32(np.inf)), up)
    return wp.Bvh(wp.array(low, dtype=wp.vec3, device="cpu"), wp.array(up, dtype=wp.vec3, device="cpu"))


def _point_segment_distance(p, a, b) -> np.ndarray:
    ab = b - a
    s = np.clip(_dot(p - a, ab) / np.maximum(_dot(ab, ab), np.finfo(float).tiny), 0.0, 1.0)
    return np.linalg.norm(p - a - s[:, None] * ab, axis=1)


def _point_triangle_distance(p, v0, v1, v2, n) -> np.ndarray:
    """Distances (m) from points to triangles (rows), ``n`` the triangles' unit normals.

    If a point projects into its triangle the distance is |plane distance|, else the distance
    to the nearest of the three edges.
    """
    d = _dot(p - v0, n)
    q = p - d[:, None] * n
    inside = np.ones(len(p), dtype=bool)
    for vi, vj in ((v0, v1), (v1, v2), (v2, v0)):
        inside &= _dot(_cross(vj - vi, q - vi), n) >= 0.0
    edges = np.min([_point_segment_distance(p, v0, v1), _point_segment_distance(p, v1, v2),
                    _point_segment_distance(p, v2, v0)], axis=0)
    return np.where(inside, np.abs(d), edges)


class CutSurface(ABC):
    """A separation surface S (thesis 5.1). See the module docstring for the crossing contract."""

    @abstractmethod
    def crossings(self, a, b, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """First strict crossing of each segment a[i] -> b[i] (M, 3) (m) with the bounded S.

        Returns ``t`` (M,) in (0, 1), the smallest crossing parameter, nan where there is none,
        and ``normal`` (M, 3), the unit normal of S at that crossing (nan rows where none).
        Endpoints within ``tol`` (m) of S are on S and never make a crossing.
        """

    @abstractmethod
    def extension_crossings(self, a, b, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`crossings`, against the extension of S used for partial cuts (thesis 5.1.1)."""

    @abstractmethod
    def distance(self, points, limit: float = np.inf) -> np.ndarray:
        """Unsigned distance (M,) (m) from each point (M, 3) to the bounded surface.

        Distances above ``limit`` (m) are reported as inf; a finite limit keeps the cost of a
        triangulated surface local.
        """

    @abstractmethod
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(lower (3,), upper (3,))`` (m) of the bounded surface."""

    @abstractmethod
    def tangent_planes(self, points) -> tuple[np.ndarray, np.ndarray]:
        """The plane of S nearest to each point (M, 3) (m): a point on it (M, 3) (m) and its
        unit normal (M, 3). Projecting onto it, repeatedly, puts a point on S (the cutter
        places the vertices it inserts on a curved S this way)."""


class Plane(CutSurface):
    """The infinite plane through ``point`` (m) with normal ``normal`` (normalised here).

    Its extension is itself; its bounds are infinite.
    """

    def __init__(self, point, normal):
        self.point = _array(point, (3,), "plane point")
        normal = _array(normal, (3,), "plane normal")
        largest = np.abs(normal).max()
        if not largest > 0.0:
            raise SurfaceError("plane normal is the zero vector")
        normal = normal / largest  # first: the length of (1e308, 0, 0) would overflow
        self.normal = normal / np.linalg.norm(normal)

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance (M,) (m) of points (M, 3): positive on the side the normal points to."""
        return (_array(points, (-1, 3), "points") - self.point) @ self.normal

    def crossings(self, a, b, tol: float) -> tuple[np.ndarray, np.ndarray]:
        a, b, tol = _segments(a, b, tol)
        return _plane_crossings(a, b, tol, self.point, self.normal)

    extension_crossings = crossings

    def distance(self, points, limit: float = np.inf) -> np.ndarray:
        d = np.abs(self.signed_distance(points))
        d[d > limit] = np.inf
        return d

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.full(3, -np.inf), np.full(3, np.inf)

    def tangent_planes(self, points) -> tuple[np.ndarray, np.ndarray]:
        count = len(_array(points, (-1, 3), "points"))
        return np.tile(self.point, (count, 1)), np.tile(self.normal, (count, 1))


class TriangleSurface(CutSurface):
    """A triangulated surface, open or closed: ``vertices`` (N, 3) (m), ``triangles`` (K, 3).

    A triangle's normal is its unit normal by the right-hand rule, so crossings report the
    orientation the triangles were given in. A segment crosses a triangle when its endpoints
    are farther than ``tol`` from the triangle's plane on opposite sides and the crossing point
    is inside the triangle up to :data:`BARY_TOL` (a Möller–Trumbore-equivalent test), and
    neither endpoint is within ``tol`` of the surface. A segment through a shared edge or
    vertex is reported once; one that only touches a fold line from one side may be reported.

    The queries are compiled (:mod:`wcut.kernels.surface_query`): each segment or point visits
    the triangles whose boxes meet its own, through a BVH of the triangles' boxes, and every
    test runs in float64 (crossings: about 15 ms for 50k segments and 2k triangles, 25 ms
    when the triangles are 4k slivers of a slowly swept blade). :meth:`winding_jumps` matches
    points to triangles through a k-d tree of small pieces of the triangles (see
    :meth:`_pieces`).

    Its extension (:meth:`extension_crossings`) is, for each segment, the plane of the
    triangle nearest to the segment's midpoint (ties: the lowest triangle index).
    """

    def __init__(self, vertices, triangles):
        self.vertices = _array(vertices, (-1, 3), "surface vertices")
        tris = np.asarray(triangles)
        if tris.ndim != 2 or tris.shape[1] != 3 or not (tris.size == 0 or np.issubdtype(tris.dtype, np.integer)):
            raise SurfaceError(f"surface triangles must be an integer array of shape (K, 3), got {tris.shape}")
        if len(tris) == 0:
            raise SurfaceError("empty surface: no triangles")
        bad = np.flatnonzero(((tris < 0) | (tris >= len(self.vertices))).any(axis=1))
        if bad.size:
            raise SurfaceError(f"triangle {bad[0]} has a vertex index out of range 0..{len(self.vertices) - 1}")
        self.triangles = tris.astype(np.int64)
        self._v = self.vertices[self.triangles]  # (K, 3, 3) corners
        v0, v1, v2 = self._v[:, 0], self._v[:, 1], self._v[:, 2]
        bad = np.flatnonzero(_degenerate(v0, v1, v2))
        if bad.size:
            raise SurfaceError(f"triangle {bad[0]} is degenerate (zero area)")
        area_normal = np.cross(v1 - v0, v2 - v0)
        self._area2 = np.linalg.norm(area_normal, axis=1)
        self.normals = area_normal / self._area2[:, None]
        self._tree: cKDTree | None = None  # broad phase, built on first use by _pieces()
        self._bvh = None  # the compiled queries' arrays, built on first use by _compiled()

    def __len__(self) -> int:
        return len(self.triangles)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        corners = self._v.reshape(-1, 3)
        return corners.min(axis=0), corners.max(axis=0)

    def _compiled(self) -> tuple:
        """The triangles as CPU Warp arrays (corners, unit normals, twice the areas, float64)
        and a BVH of their boxes, rounded outwards to float32, for the compiled queries
        (:mod:`wcut.kernels.surface_query`); built on first use."""
        if self._bvh is None:
            self._bvh = (box_tree(self._v.min(axis=1), self._v.max(axis=1)),
                         wp.array(self._v.reshape(-1, 3), dtype=wp.vec3d, device="cpu"),
                         wp.array(self.normals, dtype=wp.vec3d, device="cpu"),
                         wp.array(self._area2, dtype=wp.float64, device="cpu"))
        return self._bvh

    def _pieces(self) -> cKDTree:
        """k-d tree of the centres of small pieces of the triangles (broad phase), built once.

        A triangle (v0, e1 its shortest edge, e2) is covered by the lattice cells
        ``v0 + [i, i+1]/n1 e1 + [j, j+1]/n2 e2`` that meet it, n1, n2 = ceil(edge length /
        spacing), the spacing being the typical triangle size (sqrt of mean area, doubled until
        at most :data:`MAX_PIECES` cells). Every point of a triangle is within ``self._reach``
        (m) of one of its cell centres, so a triangle within distance r of a point has a piece
        centre within r + reach of it. Slivers (a swept blade) are cut along their length, so
        queries stay local.
        """
        if self._tree is not None:
            return self._tree
        v = self._v
        lengths = np.linalg.norm(v - np.roll(v, -1, axis=1), axis=2)  # edge k: corner k -> k+1
        order = (np.argmin(lengths, axis=1)[:, None] + np.arange(3)) % 3
        v = np.take_along_axis(v, order[:, :, None], axis=1)
        e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
        l1, l2 = np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)
        spacing = np.sqrt(0.5 * self._area2.mean())
        while True:
            n1, n2 = np.ceil(l1 / spacing).astype(np.int64), np.ceil(l2 / spacing).astype(np.int64)
            if np.sum(n1 * n2) <= MAX_PIECES:
                break
            spacing *= 2.0
        counts = n1 * n2
        tri = np.repeat(np.arange(len(self)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        i, j = local // n2[tri], local % n2[tri]
        keep = i * n2[tri] + j * n1[tri] < (n1 * n2)[tri]  # the cell's lower corner is in the triangle
        tri, i, j = tri[keep], i[keep], j[keep]
        d1, d2 = e1 / n1[:, None], e2 / n2[:, None]
        centres = v[tri, 0] + (i + 0.5)[:, None] * d1[tri] + (j + 0.5)[:, None] * d2[tri]
        half_diagonal = 0.5 * np.maximum(np.linalg.norm(d1 + d2, axis=1), np.linalg.norm(d1 - d2, axis=1))
        self._reach = float(half_diagonal.max()) * (1.0 + 1e-9)
        self._piece_tri = tri
        self._tree = cKDTree(centres)
        return self._tree

    def _near_pairs(self, points, radius) -> tuple[np.ndarray, np.ndarray]:
        """Unique (point row, triangle) pairs with the triangle possibly within ``radius`` (M,) m."""
        tree, rows, tris = self._pieces(), [], []
        for start in range(0, len(points), _BLOCK):
            row, piece = ball_pairs(tree.query_ball_point(points[start:start + _BLOCK],
                                                          radius[start:start + _BLOCK] + self._reach))
            rows.append(start + row)
            tris.append(self._piece_tri[piece])
        key = np.sort(np.concatenate(rows) * len(self) + np.concatenate(tris))
        key = key[np.r_[True, key[1:] != key[:-1]]] if key.size else key  # unique, sorted
        return key // len(self), key % len(self)

    def crossings(self, a, b, tol: float) -> tuple[np.ndarray, np.ndarray]:
        a, b, tol = _segments(a, b, tol)
        t, normal = np.full(len(a), np.nan), np.full(a.shape, np.nan)
        if not len(a):
            return t, normal
        bvh, corners, normals, area2 = self._compiled()
        first = wp.empty(len(a), dtype=wp.float64, device="cpu")
        triangle = wp.empty(len(a), dtype=wp.int32, device="cpu")
        wp.launch(surface_query.segment_crossings, len(a), device="cpu",
                  inputs=[bvh.id, corners, normals, area2, wp.array(a, dtype=wp.vec3d, device="cpu"),
                          wp.array(b, dtype=wp.vec3d, device="cpu"), tol, BARY_TOL], outputs=[first, triangle])
        triangle = triangle.numpy()
        hit = triangle >= 0
        t[hit] = _open_unit(first.numpy()[hit])
        normal[hit] = self.normals[triangle[hit]]
        return t, normal

    def winding_jumps(self, a, b, radius) -> np.ndarray:
        """(M,) the change of the local winding number of S from ``a[i]`` to ``b[i]`` (M, 3) (m):
        the signed solid angles (over 4 pi, Van Oosterom and Strackee's formula) that the
        triangles within ``radius`` (M,) (m) of the pair's midpoint subtend at ``b`` less at
        ``a``. Across S the winding number jumps by one and elsewhere it varies smoothly, so
        the change is about +-1 for points on either side of S, near S and well inside its
        boundary, and about 0 for points on the same side, even on either side of a fold
        (two sheets). Far triangles subtend nearly the same angle at both points; leaving
        them out bounds the cost. Points on S get an angle of either side."""
        a, b = _array(a, (-1, 3), "points"), _array(b, (-1, 3), "points")
        jumps = np.zeros(len(a))
        if len(a) == 0:
            return jumps
        rows, j = self._near_pairs(0.5 * (a + b), np.broadcast_to(np.asarray(radius, float), (len(a),)))
        v = self._v[j]
        np.add.at(jumps, rows, _solid_angles(v, b[rows]) - _solid_angles(v, a[rows]))
        return jumps / (4.0 * np.pi)

    def winding_numbers(self, points, radius: float) -> np.ndarray:
        """(M,) the local winding number of S at ``points`` (M, 3) (m): the signed solid angle
        (over 4 pi) that the triangles within ``radius`` (m) of each point subtend there. It
        jumps by one across S and varies smoothly elsewhere: about +-1/2 on either side of a
        flat S well inside its boundary (0.45 at a tenth of ``radius`` from it), more inside
        a fold, 0 in S's plane beyond its boundary. Each point's own triangles, so the
        numbers of nearby points differ by :meth:`winding_jumps` up to the triangles only one
        of them reaches."""
        points = _array(points, (-1, 3), "points")
        numbers = np.zeros(len(points))
        if not len(points):
            return numbers
        rows, j = self._near_pairs(points, np.full(len(points), float(radius)))
        np.add.at(numbers, rows, _solid_angles(self._v[j], points[rows]))
        return numbers / (4.0 * np.pi)

    def extension_crossings(self, a, b, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """Crossings with, per segment, the plane of the triangle nearest its midpoint.

        Exact nearest triangle: cheap for segments near the surface (the partial cuts of thesis
        5.1.1), costlier far from it (see :meth:`nearest`).
        """
        a, b, tol = _segments(a, b, tol)
        _, j = self.nearest(0.5 * (a + b))
        return _plane_crossings(a, b, tol, self._v[j, 0], self.normals[j])

    def nearest(self, points, limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distance (M,) (m) from each point (M, 3) to the surface and the nearest triangle (M,).

        Exact (of equal distances, the lowest triangle index): compiled
        (:func:`wcut.kernels.surface_query.nearest_triangles`), the triangles within a radius of
        the point measured, the radius growing from the typical triangle size until the
        nearest of them lies within it. Points farther than ``limit`` (m) get distance inf and
        triangle -1. The cost grows with min(distance, limit), so pass a limit when only near
        points matter.
        """
        p = _array(points, (-1, 3), "points")
        dist, idx = np.full(len(p), np.inf), np.full(len(p), -1, dtype=np.int64)
        if len(p) == 0:
            return dist, idx
        if len(p) * len(self) > _ALL_PAIRS:  # (few pairs: measuring them all costs less than the search)
            bvh, corners, normals, _ = self._compiled()
            dist = wp.empty(len(p), dtype=wp.float64, device="cpu")
            triangle = wp.empty(len(p), dtype=wp.int32, device="cpu")
            wp.launch(surface_query.nearest_triangles, len(p), device="cpu",
                      inputs=[bvh.id, corners, normals, *(wp.vec3d(*b) for b in self.bounds()),
                              wp.array(p, dtype=wp.vec3d, device="cpu"), float(np.sqrt(0.5 * self._area2.mean())),
                              float(limit)], outputs=[dist, triangle])
            return dist.numpy(), triangle.numpy().astype(np.int64)
        rows, j = np.divmod(np.arange(len(p) * len(self)), len(self))
        v = self._v[j]
        d = _point_triangle_distance(p[rows], v[:, 0], v[:, 1], v[:, 2], self.normals[j])
        order = np.lexsort((d, rows))
        rows, j, d = rows[order], j[order], d[order]
        first = np.r_[True, rows[1:] != rows[:-1]] & (d <= limit)
        dist[rows[first]], idx[rows[first]] = d[first], j[first]
        return dist, idx

    def distance(self, points, limit: float = np.inf) -> np.ndarray:
        p = _array(points, (-1, 3), "points")
        if not np.isfinite(limit) or not len(p):
            return self.nearest(p, limit)[0]
        # within a finite limit, the triangles whose boxes come within it (compiled)
        bvh, corners, normals, _ = self._compiled()
        dist = wp.empty(len(p), dtype=wp.float64, device="cpu")
        wp.launch(surface_query.point_distances, len(p), device="cpu",
                  inputs=[bvh.id, corners, normals, wp.array(p, dtype=wp.vec3d, device="cpu"), float(limit)],
                  outputs=[dist])
        return dist.numpy()

    def tangent_planes(self, points) -> tuple[np.ndarray, np.ndarray]:
        _, j = self.nearest(points)
        return self._v[j, 0], self.normals[j]

    @classmethod
    def load(cls, path: str | os.PathLike) -> TriangleSurface:
        """Read a Wavefront .obj file: ``v x y z`` and ``f`` lines (m).

        Faces may use ``a``, ``a/b``, ``a//c``, ``a/b/c`` and negative (relative) indices; faces
        with more than three vertices are fan-triangulated; other lines are ignored.
        """
        path = os.fspath(path)
        try:
            with open(path, encoding="utf-8") as f:
                lines = f.readlines()
        except FileNotFoundError:
            raise SurfaceError(f"surface file {path} does not exist") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise SurfaceError(f"surface file {path} cannot be read: {exc}") from None
        vertices, triangles = [], []
        for number, line in enumerate(lines, 1):
            tokens = line.split("#", 1)[0].split()
            if tokens and tokens[0] == "v":
                try:
                    xyz = [float(x) for x in tokens[1:4]]
                except ValueError:
                    xyz = []
                if len(xyz) != 3 or not np.isfinite(xyz).all():
                    raise SurfaceError(f"{path}:{number}: bad vertex line {line.strip()!r}")
                vertices.append(xyz)
            elif tokens and tokens[0] == "f":
                face = [_obj_index(tok, len(vertices), f"{path}:{number}") for tok in tokens[1:]]
                if len(face) < 3:
                    raise SurfaceError(f"{path}:{number}: a face needs at least 3 vertices")
                triangles += [(face[0], face[i], face[i + 1]) for i in range(1, len(face) - 1)]
        if not triangles:
            raise SurfaceError(f"{path}: empty surface, no faces")
        try:
            return cls(np.array(vertices), np.array(triangles, dtype=np.int64))
        except SurfaceError as exc:
            raise SurfaceError(f"{path}: {exc}") from None

    def save(self, path: str | os.PathLike) -> None:
        """Write the surface as a Wavefront .obj file (m), atomically."""
        with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
            f.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in self.vertices.tolist())
            f.writelines(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in self.triangles.tolist())


def _obj_index(token: str, count: int, where: str) -> int:
    """0-based vertex index of an .obj face token (``a``, ``a/b``, ``a//c``, ``-1``)."""
    try:
        i = int(token.split("/", 1)[0])
    except ValueError:
        raise SurfaceError(f"{where}: bad face vertex {token!r}") from None
    i = i - 1 if i > 0 else count + i
    if not 0 <= i < count:
        raise SurfaceError(f"{where}: face vertex {token!r} out of range (have {count} vertices)")
    return i


class Polygon(TriangleSurface):
    """A bounded planar polygon: ``vertices`` (K >= 3, 3) (m) in order, convex or not.

    The vertices must lie in one plane within :data:`PLANARITY_TOL` times the polygon's size
    (they are then projected onto it exactly). The normal follows the vertex order by the
    right-hand rule (Newell's method). The polygon is ear-clipped in its plane, so it behaves
    as a :class:`TriangleSurface` whose triangles all carry the polygon normal; its extension
    is the supporting plane :attr:`plane`.
    """

    def __init__(self, vertices):
        v = _array(vertices, (-1, 3), "polygon vertices")
        if len(v) < 3:
            raise SurfaceError(f"a polygon needs at least 3 vertices, got {len(v)}")
        center = v.mean(axis=0)
        area_normal = 0.5 * np.cross(v - center, np.roll(v, -1, axis=0) - center).sum(axis=0)
        size = np.linalg.norm(v.max(axis=0) - v.min(axis=0))
        if not np.linalg.norm(area_normal) > DEGENERATE_TOL * size**2:
            raise SurfaceError("polygon has zero area: its normal is the zero vector")
        self.plane = Plane(center, area_normal)
        n = self.plane.normal
        offset = (v - center) @ n
        worst = int(np.argmax(np.abs(offset)))
        if abs(offset[worst]) > PLANARITY_TOL * size:
            raise SurfaceError(f"polygon is not planar: vertex {worst} is {abs(offset[worst]):.3g} m off its plane")
        v = v - offset[:, None] * n
        u = np.cross(n, np.eye(3)[np.argmin(np.abs(n))])
        u /= np.linalg.norm(u)
        xy = (v - center) @ np.stack([u, np.cross(n, u)], axis=1)  # counter-clockwise about n
        super().__init__(v, _ear_clip(xy))
        self.normals[:] = n

    def extension_crossings(self, a, b, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """Crossings with the supporting plane of the polygon."""
        return self.plane.crossings(a, b, tol)


def _cross2(p, q, r) -> np.ndarray:
    """z of (q - p) x (r - p) for 2D points (rows or single points)."""
    return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])


def _ear_clip(xy: np.ndarray) -> np.ndarray:
    """Triangles (K-2 at most, 3) of a simple counter-clockwise 2D polygon, by ear clipping.

    Polygons whose non-adjacent edges meet are rejected; collinear vertices are dropped first
    (they do not change the shape).
    """
    eps = DEGENERATE_TOL * np.sum(np.ptp(xy, axis=0) ** 2)
    p, q = xy[:, None], np.roll(xy, -1, axis=0)[:, None]  # edge i: p[i] -> q[i]
    cuts = (_cross2(p, q, p.transpose(1, 0, 2)) * _cross2(p, q, q.transpose(1, 0, 2)) <= 0)
    k = np.arange(len(xy))
    apart = (k[:, None] != k) & ((k[:, None] + 1) % len(xy) != k) & ((k + 1) % len(xy) != k[:, None])
    if np.any(cuts & cuts.T & apart):
        i, j = np.argwhere(cuts & cuts.T & apart)[0]
        raise SurfaceError(f"polygon is self-intersecting: edges {i} and {j} meet")
    turn = _cross2(np.roll(xy, 1, axis=0), xy, np.roll(xy, -1, axis=0))
    ring = [int(i) for i in np.flatnonzero(np.abs(turn) > eps)]
    triangles = []
    while len(ring) > 3:
        for k in range(len(ring)):
            i0, i1, i2 = ring[k - 1], ring[k], ring[(k + 1) % len(ring)]
            if _cross2(xy[i0], xy[i1], xy[i2]) <= eps:
                continue  # reflex corner: not an ear
            others = xy[[i for i in ring if i not in (i0, i1, i2)]]
            inside = (_cross2(xy[i0], xy[i1], others) >= -eps) & (_cross2(xy[i1], xy[i2], others) >= -eps) \
                & (_cross2(xy[i2], xy[i0], others) >= -eps)
            if not inside.any():
                triangles.append((i0, i1, i2))
                del ring[k]
                break
        else:
            raise SurfaceError("polygon is self-intersecting: it cannot be triangulated")
    if len(ring) < 3 or _cross2(*xy[ring]) <= eps:
        raise SurfaceError("polygon is self-intersecting or has zero area")
    return np.array(triangles + [tuple(ring)], dtype=np.int64)


class SweptBlade:
    """The surface swept by a straight blade over animation frames.

    ``blade`` (F, 2, 3) (m) holds the blade's two endpoints at frames 0..F-1. Between frames
    k-1 and k it sweeps the quad (blade[k-1, 0], blade[k-1, 1], blade[k, 1], blade[k, 0]),
    split into the triangles (q0, q1, q2) and (q0, q2, q3); its normal is blade direction x
    motion (right-hand rule). Zero-area triangles (a blade that does not move, or turns about
    an endpoint) are left out. Consecutive quads share their vertices, so the swept surface
    has no cracks.
    """

    def __init__(self, blade):
        self.blade = _array(blade, (-1, 2, 3), "blade endpoints")
        if len(self.blade) == 0:
            raise SurfaceError("a swept blade needs at least one frame")

    @classmethod
    def from_tip_path(cls, tip, handle_offset) -> SweptBlade:
        """A rigid blade translated along a path, like a scalpel held at a fixed orientation.

        At frame k the blade is the segment from ``tip[k]`` to ``tip[k] + handle_offset``
        (``tip`` (F, 3), ``handle_offset`` (3,), m).
        """
        tip = _array(tip, (-1, 3), "blade tip path")
        offset = _array(handle_offset, (3,), "blade handle offset")
        if not np.linalg.norm(offset) > 0.0:
            raise SurfaceError("blade handle offset is the zero vector: the blade has no length")
        return cls(np.stack([tip, tip + offset], axis=1))

    @property
    def frame_count(self) -> int:
        """Number of frames F."""
        return len(self.blade)

    def _check(self, frame: int) -> int:
        if not 1 <= frame < self.frame_count:
            raise SurfaceError(f"blade frame {frame} out of range 1..{self.frame_count - 1}")
        return int(frame)

    @staticmethod
    def _sweep(blade: np.ndarray) -> TriangleSurface | None:
        vertices = blade.reshape(-1, 3)  # blade[k, e] is vertex 2k + e
        k = 2 * np.arange(len(blade) - 1)
        return _quads(vertices, k, k + 1, k + 3, k + 2)

    def samples(self, frame: int, count: int) -> np.ndarray:
        """(max(count, 2), 3) points (m) evenly spaced along the blade at ``frame`` (0..F-1),
        its two ends included."""
        if not 0 <= frame < self.frame_count:
            raise SurfaceError(f"blade frame {frame} out of range 0..{self.frame_count - 1}")
        s = np.linspace(0.0, 1.0, max(int(count), 2))[:, None]
        return (1.0 - s) * self.blade[frame, 0] + s * self.blade[frame, 1]

    def increment(self, frame: int) -> TriangleSurface | None:
        """The quad swept between ``frame - 1`` and ``frame``; None if the blade did not move."""
        frame = self._check(frame)
        return self._sweep(self.blade[frame - 1:frame + 1])

    def surface_until(self, frame: int) -> TriangleSurface | None:
        """Everything swept from frame 0 to ``frame`` (>= 1); None if the blade never moved."""
        frame = self._check(frame)
        return self._sweep(self.blade[:frame + 1])


def joined(surfaces) -> TriangleSurface:
    """One :class:`TriangleSurface` of several (their vertices not welded)."""
    vertices, triangles, base = [], [], 0
    for s in surfaces:
        vertices.append(s.vertices)
        triangles.append(s.triangles + base)
        base += len(s.vertices)
    return TriangleSurface(np.concatenate(vertices), np.concatenate(triangles))


def strip(before, after) -> TriangleSurface | None:
    """The surface swept by a polyline moving from ``before`` to ``after`` ((n, 3) each, m):
    quads (before[i], before[i+1], after[i+1], after[i]) split in two triangles, oriented as
    in :class:`SweptBlade`; zero-area triangles left out. None if nothing has area."""
    before = _array(before, (-1, 3), "polyline before")
    after = _array(after, (len(before), 3), "polyline after")
    n = len(before)
    i = np.arange(n - 1)
    return _quads(np.concatenate([before, after]), i, i + 1, n + i + 1, n + i)


def _quads(vertices, q0, q1, q2, q3) -> TriangleSurface | None:
    tris = np.stack([np.stack([q0, q1, q2], 1), np.stack([q0, q2, q3], 1)], axis=1).reshape(-1, 3)
    tris = tris[~_degenerate(*(vertices[tris[:, c]] for c in range(3)))]
    return TriangleSurface(vertices, tris) if len(tris) else None


def _solid_angles(corners: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(K,) the signed solid angles of triangles ``corners`` (K, 3, 3) seen from points ``p``
    (K, 3) (m; Van Oosterom and Strackee's formula)."""
    c0, c1, c2 = corners[:, 0] - p, corners[:, 1] - p, corners[:, 2] - p
    l0, l1, l2 = (np.linalg.norm(c, axis=1) for c in (c0, c1, c2))
    den = l0 * l1 * l2 + _dot(c0, c1) * l2 + _dot(c0, c2) * l1 + _dot(c1, c2) * l0
    return 2.0 * np.arctan2(_dot(c0, _cross(c1, c2)), den)
