"""Segments, points and elements against a cut surface, in double precision, with a BVH broad
phase: the sampling of a cut (thesis 5.1.1, the crossing contract of
``wcut.cut.surface.CutSurface``) and the elements a progressive blade is still in (5.3).

The cutter works in float64; Warp's BVH holds float32 boxes, so the host rounds the boxes
outwards (``wcut.cut.surface.box_tree``), a query box is grown by :data:`BOX_SLACK` of its
coordinates, and every exact test here runs in float64. Triangle j is given by its corners
``corners[3 j + k]``, its unit normal and twice its area.
"""

import warp as wp

from .point_location import barycentric, tet_corners

#: the relative slack (float32 rounding) by which a query box is grown before it is compared
#: with the float32 boxes of the triangles (themselves rounded outwards)
BOX_SLACK = wp.constant(1.0e-6)


@wp.func
def query_box(lo: wp.vec3d, hi: wp.vec3d, grow: wp.float64):
    """The float32 box that holds the float64 box ``lo``-``hi`` grown by ``grow`` (m)."""
    l = wp.vec3(float(lo[0] - grow), float(lo[1] - grow), float(lo[2] - grow))
    h = wp.vec3(float(hi[0] + grow), float(hi[1] + grow), float(hi[2] + grow))
    size = wp.max(wp.max(wp.abs(l[0]), wp.abs(l[1])), wp.abs(l[2]))
    size = wp.max(size, wp.max(wp.max(wp.abs(h[0]), wp.abs(h[1])), wp.abs(h[2])))
    return l - wp.vec3(size * BOX_SLACK), h + wp.vec3(size * BOX_SLACK)


@wp.func
def point_segment_distance(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d) -> wp.float64:
    ab = b - a
    s = wp.clamp(wp.dot(p - a, ab) / wp.max(wp.dot(ab, ab), wp.float64(2.2250738585072014e-308)),
                 wp.float64(0.0), wp.float64(1.0))
    return wp.length(p - a - s * ab)


@wp.func
def point_triangle_distance(p: wp.vec3d, v0: wp.vec3d, v1: wp.vec3d, v2: wp.vec3d, n: wp.vec3d) -> wp.float64:
    """Distance (m) from ``p`` to the triangle: |plane distance| where ``p`` projects into it,
    else that to the nearest edge."""
    d = wp.dot(p - v0, n)
    q = p - d * n
    zero = wp.float64(0.0)
    if wp.dot(wp.cross(v1 - v0, q - v0), n) >= zero and wp.dot(wp.cross(v2 - v1, q - v1), n) >= zero \
            and wp.dot(wp.cross(v0 - v2, q - v2), n) >= zero:
        return wp.abs(d)
    return wp.min(point_segment_distance(p, v0, v1),
                  wp.min(point_segment_distance(p, v1, v2), point_segment_distance(p, v2, v0)))


@wp.kernel
def segment_crossings(bvh: wp.uint64, corners: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                      area2: wp.array(dtype=wp.float64), a: wp.array(dtype=wp.vec3d), b: wp.array(dtype=wp.vec3d),
                      tol: wp.float64, bary_tol: wp.float64, t_out: wp.array(dtype=wp.float64),
                      triangle_out: wp.array(dtype=wp.int32)):
    """Per segment ``a[i]``-``b[i]``: the smallest parameter of a strict crossing of a triangle
    (both ends farther than ``tol`` from its plane, on either side, the crossing point inside
    it up to ``bary_tol`` of twice its area) and that triangle (of equal parameters, the
    smallest index); -1 where there is none or where an end lies within ``tol`` (m) of the
    surface."""
    i = wp.tid()
    pa = a[i]
    pb = b[i]
    lo, hi = query_box(wp.min(pa, pb), wp.max(pa, pb), tol)
    query = wp.bvh_query_aabb(bvh, lo, hi)
    j = int(0)
    best_t = wp.float64(2.0)
    best = int(-1)
    on = bool(False)
    while wp.bvh_query_next(query, j):
        v0 = corners[3 * j]
        v1 = corners[3 * j + 1]
        v2 = corners[3 * j + 2]
        n = normals[j]
        if point_triangle_distance(pa, v0, v1, v2, n) <= tol or point_triangle_distance(pb, v0, v1, v2, n) <= tol:
            on = True
        da = wp.dot(pa - v0, n)
        db = wp.dot(pb - v0, n)
        if wp.abs(da) > tol and wp.abs(db) > tol and (da > wp.float64(0.0)) != (db > wp.float64(0.0)):
            t = da / (da - db)
            p = pa + t * (pb - pa)
            slack = -bary_tol * area2[j]
            if wp.dot(wp.cross(v1 - v0, p - v0), n) >= slack and wp.dot(wp.cross(v2 - v1, p - v1), n) >= slack \
                    and wp.dot(wp.cross(v0 - v2, p - v2), n) >= slack:
                if t < best_t or (t == best_t and j < best):
                    best_t = t
                    best = j
    if on:
        best = -1
    t_out[i] = best_t
    triangle_out[i] = wp.int32(best)


@wp.kernel
def point_distances(bvh: wp.uint64, corners: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                    p: wp.array(dtype=wp.vec3d), limit: wp.float64, distance_out: wp.array(dtype=wp.float64)):
    """Per point, the distance (m) to the nearest triangle within ``limit`` (m), else ``inf``."""
    i = wp.tid()
    x = p[i]
    lo, hi = query_box(x, x, limit)
    query = wp.bvh_query_aabb(bvh, lo, hi)
    j = int(0)
    best = wp.float64(wp.inf)
    while wp.bvh_query_next(query, j):
        d = point_triangle_distance(x, corners[3 * j], corners[3 * j + 1], corners[3 * j + 2], normals[j])
        best = wp.min(best, d)
    if best > limit:
        best = wp.float64(wp.inf)
    distance_out[i] = best


@wp.kernel
def elements_met(bvh: wp.uint64, segment_a: wp.array(dtype=wp.vec3d), segment_b: wp.array(dtype=wp.vec3d),
                 tets: wp.array(dtype=wp.vec4i), x: wp.array(dtype=wp.vec3d), tol: wp.float64,
                 met: wp.array(dtype=wp.int32)):
    """Whether any segment ``segment_a[k]``-``segment_b[k]`` meets element ``tets[i]`` (corners
    ``x``, m), up to ``tol`` (m): Cyrus-Beck clipping of the segment in the element's
    barycentric coordinates, each allowed down to ``-tol`` over the length of the element's
    box diagonal."""
    i = wp.tid()
    c0, c1, c2, c3 = tet_corners(tets, x, i)
    lower = wp.min(wp.min(c0, c1), wp.min(c2, c3))
    upper = wp.max(wp.max(c0, c1), wp.max(c2, c3))
    lo, hi = query_box(lower, upper, tol)
    query = wp.bvh_query_aabb(bvh, lo, hi)
    inverse = wp.inverse(wp.matrix_from_cols(c1 - c0, c2 - c0, c3 - c0))
    slack = tol / wp.length(upper - lower)
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    k = int(0)
    found = int(0)
    while wp.bvh_query_next(query, k):
        a = segment_a[k]
        b = segment_b[k]
        near = wp.min(a, b)
        far = wp.max(a, b)
        if near[0] > upper[0] + tol or near[1] > upper[1] + tol or near[2] > upper[2] + tol:
            continue
        if far[0] < lower[0] - tol or far[1] < lower[1] - tol or far[2] < lower[2] - tol:
            continue
        start = barycentric(inverse, c0, a)
        end = barycentric(inverse, c0, b)
        enter = zero
        leave = one
        blocked = bool(False)
        for c in range(4):
            rate = end[c] - start[c]
            if rate > zero:
                enter = wp.max(enter, -(start[c] + slack) / rate)
            elif rate < zero:
                leave = wp.min(leave, -(start[c] + slack) / rate)
            elif start[c] < -slack:
                blocked = True
        if not blocked and enter <= leave:
            found = 1
            break
    met[i] = found


@wp.kernel
def nearest_triangles(bvh: wp.uint64, corners: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                      lower: wp.vec3d, upper: wp.vec3d, p: wp.array(dtype=wp.vec3d), start: wp.float64,
                      limit: wp.float64, distance_out: wp.array(dtype=wp.float64),
                      triangle_out: wp.array(dtype=wp.int32)):
    """Per point, the nearest triangle (of equal distances, the smallest index) and its distance
    (m), or -1 and inf where none lies within ``limit`` (m). The triangles within a radius of
    the point are measured, the radius growing fourfold from ``start`` (m) until the nearest of
    them lies within it: it is then the nearest of all. ``lower``-``upper`` is the surface's
    box (m): a radius reaching its far corner holds every triangle."""
    i = wp.tid()
    x = p[i]
    outside = wp.max(wp.max(lower - x, x - upper), wp.vec3d(wp.float64(0.0)))
    every = wp.length(outside) + wp.length(upper - lower)
    radius = start
    best = wp.float64(wp.inf)
    best_j = int(-1)
    while True:
        reach = wp.min(wp.min(radius, limit), every)
        lo, hi = query_box(x, x, reach)
        query = wp.bvh_query_aabb(bvh, lo, hi)
        j = int(0)
        while wp.bvh_query_next(query, j):
            d = point_triangle_distance(x, corners[3 * j], corners[3 * j + 1], corners[3 * j + 2], normals[j])
            if d < best or (d == best and j < best_j):
                best = d
                best_j = j
        if best <= reach or reach >= limit or reach >= every:
            break
        radius = radius * wp.float64(4.0)
    if best > limit:
        best = wp.float64(wp.inf)
        best_j = -1
    distance_out[i] = best
    triangle_out[i] = wp.int32(best_j)
