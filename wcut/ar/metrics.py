"""Error measures of a registered model against ground truth (thesis section 7.6, 7.8.2).

* :func:`dice` -- Dice's coefficient of two pixel masks (eq. 7.13): the overlap of the
  object seen in the image with the model's silhouette (:func:`rasterize`).
* :func:`hausdorff` -- the symmetric, sampled Hausdorff distance between two triangle
  surfaces (eq. 7.14), with the mean of both one-sided distance fields, which tells whether
  the maximum is an outlier; built on :func:`surface_samples` and the exact
  :func:`point_to_surface_distance`.
* :func:`feature_error` -- the Euclidean error of feature points (eq. 7.15).

Lengths are in metres (or whatever length unit the points are given in: every function is
unit-agnostic and returns distances in the unit of its input), pixels are image pixels with
the OpenCV convention: pixel ``(row, col)`` has its centre at ``u = col``, ``v = row``.

The camera is duck-typed: any object with ``width`` and ``height`` (pixels) and
``project(points (N, 3)) -> (pixels (N, 2) [u, v], depth (N,) m)``.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

from ..errors import WcutError

__all__ = [
    "MetricsError",
    "dice",
    "rasterize",
    "surface_samples",
    "point_to_surface_distance",
    "hausdorff",
    "feature_error",
]


class MetricsError(WcutError):
    """Input of an error measure is invalid: mismatched shapes, an empty surface, NaN,
    a triangle index out of range, a non-positive sample spacing."""


# --------------------------------------------------------------------------- input checks


def _points(name: str, points, *, allow_empty: bool = True) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MetricsError(f"{name}: expected an (N, 3) array of points, got shape {p.shape}")
    if not allow_empty and len(p) == 0:
        raise MetricsError(f"{name}: no points")
    if not np.all(np.isfinite(p)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(p), axis=1))[0])
        raise MetricsError(f"{name}: point {bad} is not finite ({p[bad].tolist()})")
    return p


def _triangles(name: str, triangles, n_points: int) -> np.ndarray:
    t = np.asarray(triangles)
    if t.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if t.ndim != 2 or t.shape[1] != 3:
        raise MetricsError(f"{name}: expected a (T, 3) array of vertex indices, got shape {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise MetricsError(f"{name}: vertex indices must be integers, got dtype {t.dtype}")
    t = t.astype(np.int64)
    if t.min() < 0 or t.max() >= n_points:
        bad = int(np.flatnonzero(np.any((t < 0) | (t >= n_points), axis=1))[0])
        raise MetricsError(
            f"{name}: triangle {bad} {t[bad].tolist()} indexes outside the {n_points} points"
        )
    return t


def _surface(name: str, points, triangles, *, allow_empty: bool = False):
    p = _points(f"{name} points", points)
    t = _triangles(f"{name} triangles", triangles, len(p))
    if not allow_empty and len(t) == 0:
        raise MetricsError(f"{name}: the surface has no triangles")
    return p, t


# --------------------------------------------------------------------------- Dice (7.13)


def dice(a, b) -> float:
    """Dice's coefficient ``2 |A n B| / (|A| + |B|)`` of two boolean pixel masks (eq. 7.13).

    ``a`` and ``b`` are arrays of the same shape (any non-zero value counts as inside).
    Returns a number in [0, 1]; 1.0 when both masks are empty (they agree perfectly).
    Raises :class:`MetricsError` naming both shapes when they differ.
    """
    a = np.asarray(a).astype(bool, copy=False)
    b = np.asarray(b).astype(bool, copy=False)
    if a.shape != b.shape:
        raise MetricsError(f"dice: mask shapes differ: a has shape {a.shape}, b has shape {b.shape}")
    na = int(np.count_nonzero(a))
    nb = int(np.count_nonzero(b))
    if na + nb == 0:
        return 1.0
    return 2.0 * int(np.count_nonzero(a & b)) / (na + nb)


# --------------------------------------------------------------------------- silhouette

_RASTER_CHUNK = 4096  # pixel rows of triangle parts handled at once by rasterize
_PAIR_BUDGET = 1 << 20  # (query, triangle) candidate pairs tested at once


def rasterize(camera, points, triangles) -> np.ndarray:
    """The pixel mask (``(height, width)`` bool) of a triangle surface seen by ``camera``.

    A pixel is set when its centre lies in (or on the border of) the projection of at least
    one triangle: the union of all triangles, i.e. the model's silhouette used for Dice's
    coefficient (eq. 7.13). Triangles with a vertex at or behind the camera (depth <= 0 m) or
    a non-finite projection are skipped.

    The convention is the one of a ray cast through every pixel centre, so a ray-cast
    silhouette of the same surface gives the same mask.

    Implementation: a vectorised scanline fill with float64 (sub-pixel) vertex positions.
    Every (triangle, pixel row) pair gives one span of pixel centres; the spans are added
    into a per-row difference array whose running sum is the number of triangles covering
    each pixel, so overlapping triangles give their union. ``cv2.fillPoly`` with all
    triangles in one call is not usable here: it fills with the even-odd rule, so where a
    front and a back face overlap the silhouette would get a hole; one
    ``cv2.fillConvexPoly`` call per triangle gives the union but also sets every pixel an
    edge touches (about half a pixel of dilation) and is no faster.

    ``points`` (N, 3) in metres in the camera's world frame, ``triangles`` (T, 3) indices.
    """
    width, height = int(camera.width), int(camera.height)
    p = _points("rasterize points", points)
    t = _triangles("rasterize triangles", triangles, len(p))
    mask = np.zeros((height, width), dtype=bool)
    if len(t) == 0 or width <= 0 or height <= 0:
        return mask
    pix, depth = camera.project(p)
    pix = np.asarray(pix, dtype=np.float64).reshape(len(p), 2)
    depth = np.asarray(depth, dtype=np.float64).reshape(len(p))
    vertex_ok = (depth > 0.0) & np.all(np.isfinite(pix), axis=1)
    t = t[np.all(vertex_ok[t], axis=1)]
    if len(t) == 0:
        return mask
    # Vertices sorted by v (row coordinate): y0 <= y1 <= y2 per triangle.
    order = np.argsort(pix[t, 1], axis=1, kind="stable")
    srt = np.take_along_axis(t, order, axis=1)
    x0, x1, x2 = (pix[srt[:, i], 0] for i in range(3))
    y0, y1, y2 = (pix[srt[:, i], 1] for i in range(3))
    keep = (np.maximum(np.maximum(x0, x1), x2) >= 0.0) & (np.minimum(np.minimum(x0, x1), x2) <= width - 1.0)
    keep &= (y2 >= 0.0) & (y0 <= height - 1.0)
    if not np.any(keep):
        return mask
    x0, x1, x2, y0, y1, y2 = (a[keep] for a in (x0, x1, x2, y0, y1, y2))

    def slope(xa, ya, xb, yb):
        dy = yb - ya
        return np.where(dy > 0.0, (xb - xa) / np.where(dy > 0.0, dy, 1.0), 0.0)

    # Each triangle is two parts: the pixel rows (centre v = row) of [y0, y1) and of
    # [y1, y2]. Along a row of a part, the span lies between the long edge 0-2 and the
    # short edge 0-1 (upper part) or 1-2 (lower part). Parameters of the parts:
    # first row, long edge (x, y, dx/dy), short edge (x, y, dx/dy).
    s02 = slope(x0, y0, x2, y2)
    r_first = np.concatenate([np.maximum(np.ceil(y0), 0.0), np.maximum(np.ceil(y1), 0.0)])
    r_last = np.concatenate([np.minimum(np.ceil(y1) - 1.0, height - 1.0), np.minimum(np.floor(y2), height - 1.0)])
    long_s = np.tile(s02, 2)
    short_s = np.concatenate([slope(x0, y0, x1, y1), slope(x1, y1, x2, y2)])
    # x of both edges on the first row of each part.
    long_x = np.tile(x0, 2) + long_s * (r_first - np.tile(y0, 2))
    short_x = np.concatenate([x0, x1]) + short_s * (r_first - np.concatenate([y0, y1]))
    counts = np.maximum(r_last - r_first + 1.0, 0.0).astype(np.int64)
    total = int(counts.sum())
    if total == 0:
        return mask
    # Difference array over the bounding box: its running sum along a row is the number of
    # triangles covering a pixel. Spans are added chunk by chunk so that the temporaries stay
    # small (large fresh allocations cost page faults that dominate the run time).
    r_min = int(r_first[counts > 0].min())
    r_max = int(r_last[counts > 0].max())
    c_min = int(max(np.floor(min(x0.min(), x1.min(), x2.min())), 0.0))
    c_max = int(min(np.ceil(max(x0.max(), x1.max(), x2.max())), width - 1.0))
    if c_min > c_max:
        return mask
    stride = c_max - c_min + 2
    diff = np.zeros((r_max - r_min + 1) * stride, dtype=np.int32)
    cum = np.cumsum(counts)
    cuts = np.searchsorted(cum, np.arange(_RASTER_CHUNK, total, _RASTER_CHUNK), side="right")
    bounds = np.unique(np.concatenate([[0], cuts, [len(counts)]]))
    plus = np.ones(0, dtype=np.int32)
    for a, b in zip(bounds[:-1], bounds[1:]):
        cnt = counts[a:b]
        m = int(cnt.sum())
        if m == 0:
            continue
        owner = np.repeat(np.arange(a, b), cnt)
        k = np.arange(m, dtype=np.float64)
        k -= np.repeat(np.cumsum(cnt) - cnt, cnt)  # row index within its part
        xa = long_s[owner]
        xa *= k
        xa += long_x[owner]  # x on the long edge
        xb = short_s[owner]
        xb *= k
        xb += short_x[owner]  # x on the short edge
        y = k
        y += r_first[owner]  # the pixel row
        lo = np.minimum(xa, xb)
        hi = np.maximum(xa, xb, out=xa)
        np.ceil(lo, out=lo)
        np.maximum(lo, c_min, out=lo)  # first pixel column
        np.floor(hi, out=hi)
        np.minimum(hi, c_max, out=hi)  # last pixel column
        span = lo <= hi
        if len(plus) < m:
            plus = np.ones(m, dtype=np.int32)
        y -= r_min
        y *= stride
        y -= c_min
        start = (y + lo)[span].astype(np.int64)
        end = (y + hi)[span].astype(np.int64)
        end += 1
        np.add.at(diff, start, plus[: len(start)])
        np.subtract.at(diff, end, plus[: len(end)])
    diff = diff.reshape(r_max - r_min + 1, stride)
    np.cumsum(diff, axis=1, out=diff)
    np.greater(diff[:, :-1], 0, out=mask[r_min : r_max + 1, c_min : c_max + 1])
    return mask


# --------------------------------------------------------------------------- sampling


def _unique_edges(t: np.ndarray) -> np.ndarray:
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0)


def surface_samples(points, triangles, spacing: float) -> np.ndarray:
    """Deterministic sample points (K, 3) covering a triangle surface, about ``spacing`` apart.

    The samples are: every vertex used by a triangle; on every edge, the points dividing it
    into ``ceil(length / spacing)`` equal parts; inside every triangle, the interior nodes of
    a barycentric grid with ``n = ceil(longest edge / spacing)`` divisions. Each point is
    stored once (shared edges and vertices are not repeated), and every grid cell has sides
    of at most ``spacing``, so no point of the surface is farther than ``spacing`` from a
    sample. ``points`` (N, 3) and ``spacing`` in metres (spacing > 0).

    Used for the sampled Hausdorff distance (eq. 7.14). The density follows the grid, not
    the area: slender triangles are sampled more densely than their area asks for.
    """
    p, t = _surface("surface_samples", points, triangles, allow_empty=True)
    spacing = float(spacing)
    if not np.isfinite(spacing) or spacing <= 0.0:
        raise MetricsError(f"surface_samples: spacing must be a positive length in m, got {spacing}")
    if len(t) == 0:
        return np.zeros((0, 3))
    out = [p[np.unique(t)]]
    # Edge interiors.
    e = _unique_edges(t)
    a, b = p[e[:, 0]], p[e[:, 1]]
    ne = np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(np.int64)
    for n in np.unique(ne[ne > 1]):
        sel = ne == n
        s = (np.arange(1, n) / n)[None, :, None]
        out.append((a[sel, None, :] * (1.0 - s) + b[sel, None, :] * s).reshape(-1, 3))
    # Triangle interiors (nodes with all three barycentric indices >= 1).
    v0, v1, v2 = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    longest = np.max(
        np.stack(
            [np.linalg.norm(v1 - v0, axis=1), np.linalg.norm(v2 - v1, axis=1), np.linalg.norm(v0 - v2, axis=1)]
        ),
        axis=0,
    )
    nt = np.ceil(longest / spacing).astype(np.int64)
    for n in np.unique(nt[nt > 2]):
        sel = nt == n
        i, j = np.meshgrid(np.arange(1, n), np.arange(1, n), indexing="ij")
        ok = i + j < n
        wi = (i[ok] / n)[None, :, None]
        wj = (j[ok] / n)[None, :, None]
        wk = 1.0 - wi - wj
        out.append((v0[sel, None] * wk + v1[sel, None] * wi + v2[sel, None] * wj).reshape(-1, 3))
    return np.concatenate(out)


# --------------------------------------------------------------------------- distances


def _segment_distance2(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = np.einsum("ij,ij->i", ab, ab)
    s = np.einsum("ij,ij->i", q - a, ab) / np.where(den > 0.0, den, 1.0)
    s = np.clip(np.where(den > 0.0, s, 0.0), 0.0, 1.0)
    d = q - (a + s[:, None] * ab)
    return np.einsum("ij,ij->i", d, d)


def _triangle_distance2(q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Squared distance from q[i] to the triangle (a[i], b[i], c[i]); exact, degenerate-safe."""
    ab, ac, aq = b - a, c - a, q - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    flat = nn > 1e-300
    safe = np.where(flat, nn, 1.0)
    # Barycentric coordinates of the projection of q onto the plane.
    w1 = np.einsum("ij,ij->i", np.cross(aq, ac), n) / safe
    w2 = np.einsum("ij,ij->i", np.cross(ab, aq), n) / safe
    inside = flat & (w1 >= 0.0) & (w2 >= 0.0) & (w1 + w2 <= 1.0)
    plane = np.einsum("ij,ij->i", aq, n) ** 2 / safe
    edge = np.minimum(
        np.minimum(_segment_distance2(q, a, b), _segment_distance2(q, b, c)), _segment_distance2(q, c, a)
    )
    return np.where(inside, plane, edge)


def point_to_surface_distance(query, points, triangles, *, chunk: int = 20000) -> np.ndarray:
    """Exact Euclidean distance (K,) in metres from each query point to a triangle surface.

    The distance to the nearest point of the nearest triangle (inside, on an edge or at a
    vertex). Candidate triangles come from a k-d tree over the triangle centroids: with
    ``d0`` the exact distance to the best of the few triangles with the nearest centroids
    and ``R`` the largest centroid-to-vertex distance of any triangle, every triangle at
    distance <= d0 has its centroid within ``d0 + R`` of the query point (a triangle lies in
    the ball of radius R around its centroid), so that ball query misses no closer triangle.

    ``query`` (K, 3) and ``points`` (N, 3) in metres, ``triangles`` (T, 3) vertex indices,
    T >= 1. ``chunk`` bounds the number of query points handled at once (memory).
    """
    q = _points("point_to_surface_distance query", query)
    p, t = _surface("point_to_surface_distance", points, triangles)
    if len(q) == 0:
        return np.zeros(0)
    v0, v1, v2 = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    cen = (v0 + v1 + v2) / 3.0
    rad = np.sqrt(np.max(np.stack([((v - cen) ** 2).sum(axis=1) for v in (v0, v1, v2)]), axis=0))
    r_max = float(rad.max())
    tree = cKDTree(cen)
    k = min(4, len(t))
    out = np.empty(len(q))
    for start in range(0, len(q), chunk):
        qc = q[start : start + chunk]
        _, near = tree.query(qc, k=k)
        near = np.asarray(near).reshape(len(qc), k)
        rows = np.repeat(np.arange(len(qc)), k)
        cand = near.ravel()
        d2 = _triangle_distance2(qc[rows], v0[cand], v1[cand], v2[cand]).reshape(len(qc), k)
        best = np.sqrt(d2.min(axis=1))
        radius = best + r_max * (1.0 + 1e-12) + 1e-12
        best2 = best**2
        # Candidate pairs are handled in groups of at most about `_PAIR_BUDGET` (memory).
        counts = np.asarray(tree.query_ball_point(qc, radius, return_length=True), dtype=np.int64)
        groups = np.searchsorted(np.cumsum(counts), np.arange(_PAIR_BUDGET, counts.sum(), _PAIR_BUDGET))
        edges = np.unique(np.concatenate([[0], groups, [len(qc)]]))
        for g0, g1 in zip(edges[:-1], edges[1:]):
            lists = tree.query_ball_point(qc[g0:g1], radius[g0:g1], return_sorted=False)
            cnt = counts[g0:g1]
            cand = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(cnt.sum()))
            rows = np.repeat(np.arange(g0, g1), cnt)
            # Prune with each candidate's own radius before the exact test.
            dc = np.linalg.norm(qc[rows] - cen[cand], axis=1)
            keep = dc - rad[cand] <= best[rows] * (1.0 + 1e-12) + 1e-12
            rows, cand = rows[keep], cand[keep]
            d2 = _triangle_distance2(qc[rows], v0[cand], v1[cand], v2[cand])
            np.minimum.at(best2, rows, d2)
        out[start : start + len(qc)] = np.sqrt(best2)
    return out


def hausdorff(points_a, tris_a, points_b, tris_b, spacing: float) -> tuple[float, float]:
    """Symmetric sampled Hausdorff distance between surfaces A and B (eq. 7.14), in metres.

    A is sampled with :func:`surface_samples` (about ``spacing`` m apart) and the exact
    distance of every sample to surface B is taken (:func:`point_to_surface_distance`), and
    the other way round. Returns ``(mean, max)``: ``max`` is the larger of the two one-sided
    suprema (eq. 7.14); ``mean`` is the mean over all samples of both directions, which tells
    whether the maximum is an outlier (section 7.6). The suprema are taken over the samples,
    so ``max`` can underestimate the true one by at most about ``spacing``.

    Raises :class:`MetricsError` when a surface has no triangles or spacing <= 0.
    """
    pa, ta = _surface("hausdorff surface A", points_a, tris_a)
    pb, tb = _surface("hausdorff surface B", points_b, tris_b)
    sa = surface_samples(pa, ta, spacing)
    sb = surface_samples(pb, tb, spacing)
    dab = point_to_surface_distance(sa, pb, tb)
    dba = point_to_surface_distance(sb, pa, ta)
    both = np.concatenate([dab, dba])
    return float(both.mean()), float(max(dab.max(), dba.max()))


def feature_error(current, target, active) -> tuple[float, float]:
    """Euclidean error of feature points (eq. 7.15): ``||p_F^t - p_F^1||_2`` per feature.

    ``current`` and ``target`` (F, 3) in metres, ``active`` (F,) bool selects the features
    that count. Returns ``(mean, max)`` in metres over the active features, or
    ``(nan, nan)`` when none is active. Non-finite coordinates of an active feature raise
    :class:`MetricsError`.
    """
    c = np.asarray(current, dtype=np.float64)
    g = np.asarray(target, dtype=np.float64)
    m = np.asarray(active)
    if c.ndim != 2 or c.shape[1] != 3 or g.shape != c.shape:
        raise MetricsError(
            f"feature_error: current and target must both be (F, 3); got {c.shape} and {g.shape}"
        )
    if m.shape != (len(c),):
        raise MetricsError(f"feature_error: active must have shape ({len(c)},), got {m.shape}")
    m = m.astype(bool)
    if not np.any(m):
        return float("nan"), float("nan")
    e = np.linalg.norm(c[m] - g[m], axis=1)
    if not np.all(np.isfinite(e)):
        bad = int(np.flatnonzero(m)[np.flatnonzero(~np.isfinite(e))[0]])
        raise MetricsError(f"feature_error: active feature {bad} has a non-finite position")
    return float(e.mean()), float(e.max())
