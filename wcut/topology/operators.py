"""Local topological operators on a :class:`~wcut.topology.mesh.TetTopology` (thesis 5.1).

Each operator checks its result before it changes anything: every new element must be
positively oriented with quality (volume / longest edge^3, rest configuration) above
``DEGENERATE_TOL``. If not, it raises :class:`TopologyError` saying why and leaves the mesh
as it was, so the cutter can fall back (to snapping, to a face split, to a bisection).
New vertices carry rest position, position and velocity by barycentric interpolation.

An operator checks a handful of elements: it computes in plain Python floats on the
topology's ``rest_tuples``, where numpy's per-call overhead would cost more than the arithmetic.

Except the general flip of a boundary edge (which may, when allowed, smooth the boundary),
every operator conserves the total rest volume exactly up to rounding.
"""

from __future__ import annotations

import math

import numpy as np

from ..mesh import DEGENERATE_TOL, tet_volumes
from .mesh import (NEAR_TIE, POSITION, REST, TetTopology, TopologyError, face_key, rounded32, signed_volume,
                   tet_quality, tet_quality_and_length)

#: Up to this many elements :func:`tet_qualities` loops in plain floats: numpy's per-call
#: overhead (some 40 array operations) exceeds the arithmetic of a few elements.
SMALL_BATCH = 16


_quality = tet_quality  # the short name the operators use


def tet_qualities(points: np.ndarray) -> np.ndarray:
    """Quality (volume / longest edge^3) of (M, 4, 3) tetrahedra.

    Written component by component, in the order of :func:`_quality`, so that a small float64
    batch can be computed in plain floats (faster) with the same result to the last bit."""
    points = np.asarray(points)
    if points.dtype == np.float64 and len(points) <= SMALL_BATCH:
        return np.array([_quality(*tet) for tet in points.tolist()], dtype=np.float64).reshape(len(points))
    x, y, z = points[..., 0], points[..., 1], points[..., 2]  # (M, 4) each
    ax, ay, az = x[:, 1] - x[:, 0], y[:, 1] - y[:, 0], z[:, 1] - z[:, 0]
    bx, by, bz = x[:, 2] - x[:, 0], y[:, 2] - y[:, 0], z[:, 2] - z[:, 0]
    cx, cy, cz = x[:, 3] - x[:, 0], y[:, 3] - y[:, 0], z[:, 3] - z[:, 0]
    volume = (ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)) / 6.0
    dx, dy, dz = x[:, 2] - x[:, 1], y[:, 2] - y[:, 1], z[:, 2] - z[:, 1]
    ex, ey, ez = x[:, 3] - x[:, 1], y[:, 3] - y[:, 1], z[:, 3] - z[:, 1]
    fx, fy, fz = x[:, 3] - x[:, 2], y[:, 3] - y[:, 2], z[:, 3] - z[:, 2]
    longest2 = np.maximum.reduce([ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz,
                                  cx * cx + cy * cy + cz * cz, dx * dx + dy * dy + dz * dz,
                                  ex * ex + ey * ey + ez * ez, fx * fx + fy * fy + fz * fz])
    return volume / (longest2 * np.sqrt(longest2))


def _smaller(a: float, b: float) -> float:
    """min(a, b) as ``np.minimum``: NaN when either is NaN."""
    return a if a < b or a != a else b


#: Largest displacement of a coordinate of magnitude M rounded to float32: M * 2^-24 (to
#: nearest; the subnormal range adds at most 2^-150).
_F32_STEP = 2.0**-24

#: :func:`_check` skips the float32 qualities of elements whose float64 quality q and longest
#: edge L satisfy ``rho = _F32_REACH * M / L <= 0.01`` and ``q > _FAST_TOL + 0.5051 rho``,
#: M bounding the coordinates' magnitudes. Rounding moves each corner by at most
#: r = sqrt(3) M 2^-24, each edge vector by 2r, so 6 |dV| <= (L + 2r)^3 - L^3 (the
#: determinant is multilinear, Hadamard's bound for each term) and the rounded element's
#: quality is at least q - ((1 + s)^3 - 1) / 6 - DEGENERATE_TOL ((1 + s)^3 - 1) with s = 2r/L:
#: above DEGENERATE_TOL when q > DEGENERATE_TOL (1 + s)^3 + ((1 + s)^3 - 1) / 6, implied (for
#: s <= 0.01, with twice s for margin over the float64 rounding of both qualities, some 1e-15)
#: by the condition above.
_F32_REACH = 4.0 * math.sqrt(3.0) * _F32_STEP
_FAST_TOL = 1.0304 * DEGENERATE_TOL + 1e-12


def _check(topo: TetTopology, tets: list[list[int]], what: str, extra: dict | None = None,
           qualities: list | None = None) -> float:
    """Refuse unless every tetrahedron of ``tets`` is well shaped in the rest configuration;
    return the smallest float64 quality among them (for an operator's own criteria, so that
    it need not compute the qualities again). ``qualities``, a list, receives each
    element's float64 quality (for :meth:`TetTopology.replace_tets` to remember).

    ``extra`` maps a vertex not yet in the mesh (index -1, -2, ...) to its rest position.
    The worst element is the first of smallest quality, or the first NaN (as ``np.argmin``).

    The float32 qualities are only computed where the float64 quality is not clearly above
    the threshold (see ``_F32_REACH``): the outcome is the same as computing all of them."""
    rest = topo.rest_tuples
    bound = topo.rest_bound
    if extra:
        extra64, extra32 = _extra_points(extra)
        for x, y, z in extra64.values():
            b = max(abs(x), abs(y), abs(z))
            if not b <= bound:
                bound = b if b == b else math.inf
    else:
        extra64 = extra32 = None
    reach = _F32_REACH * bound
    out = [] if qualities is None else qualities
    start = len(out)
    worst64 = math.inf
    for tet in tets:
        if extra64 is None:
            a, b, c, d = tet
            p0, p1, p2, p3 = rest[a], rest[b], rest[c], rest[d]
        else:
            p0, p1, p2, p3 = [extra64[v] if v < 0 else rest[v] for v in tet]
        q, length = tet_quality_and_length(p0, p1, p2, p3)
        if not q > _FAST_TOL:
            break
        rho = reach / length
        if not (rho <= 0.01 and q > _FAST_TOL + 0.5051 * rho):
            break
        out.append(q)
        if q < worst64:
            worst64 = q
    else:
        return worst64
    del out[start:]
    return _check_all(topo, tets, what, extra64, extra32, out)


def _check_all(topo: TetTopology, tets: list[list[int]], what: str, extra64, extra32, out: list) -> float:
    """:func:`_check` computing every element's float32 quality too."""
    rest, rest32 = topo.rest_tuples, topo.rest_tuples32
    if extra64 is None:
        extra64 = extra32 = {}
    worst, worst_q, worst64 = 0, math.inf, math.inf
    for i, tet in enumerate(tets):
        # The simulation sees float32 rest positions: the element must survive that rounding.
        q64 = _quality(*[extra64[v] if v < 0 else rest[v] for v in tet])
        out.append(q64)
        q = _smaller(q64, _quality(*[extra32[v] if v < 0 else rest32[v] for v in tet]))
        if q != q:
            worst, worst_q = i, q
            break
        if q < worst_q:
            worst, worst_q = i, q
        if q64 < worst64:
            worst64 = q64
    if not worst_q > DEGENERATE_TOL:
        state = "inverted" if worst_q < 0 else "flat"
        raise TopologyError(f"{what}: element {tets[worst]} would be {state} (quality {worst_q:.2e})")
    return worst64


def _extra_points(extra: dict) -> tuple[dict, dict]:
    """Rest positions of vertices not yet in the mesh (vertex -> any three floats) as float
    tuples, as they are and rounded to float32."""
    extra64, extra32 = {}, {}
    for v, p in extra.items():
        extra64[v] = tuple(p.tolist()) if isinstance(p, np.ndarray) else tuple(map(float, p))
        extra32[v] = rounded32(extra64[v])
    return extra64, extra32


def _weights(weights, count: int, what: str) -> np.ndarray:
    """Barycentric weights: ``count`` finite numbers summing to 1."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    values = w.tolist()
    total = 0.0
    for x in values:  # plain left-to-right rounding (Python 3.12's sum() compensates)
        total += x
    if len(values) != count or not all(map(math.isfinite, values)) or abs(total - 1.0) > 1e-9:
        raise TopologyError(f"{what}: expected {count} finite barycentric weights summing to 1, got {values}")
    return w


def _point(topo: TetTopology, parents, weights) -> np.ndarray:
    return np.asarray(weights, float) @ topo.vertex_data.take(parents, axis=0)[:, REST]


#: A centroid whose smallest barycentric coordinate in a removed element exceeds this is
#: inside that element, whose coordinates' rounding errors are far smaller (below 1e-4 for
#: elements of quality above DEGENERATE_TOL sharing a face or an edge): every other removed
#: element (disjoint interiors) gets a smaller coordinate, so the search stops there.
_INSIDE = 1e-3


def _containing(topo: TetTopology, removed: list[int], added: list[list[int]],
                hints: list[int] | None = None) -> list[int]:
    """For each new element, the removed element that contains its centroid (the one whose
    smallest barycentric coordinate of it is largest, the first such): its parent in the
    change record. ``hints[i]``, when given, is the index in ``removed`` where the search for
    new element i starts (it stops at an element clearly containing the centroid, see
    ``_INSIDE``; the answer does not depend on the hint); else where the previous one's
    search ended (a 2-3 flip's new elements all lie in the element whose apex is farther
    from the face).

    Barycentric coordinates by Cramer's rule in plain floats. They may differ in the last bits
    from a matrix inverse's, which can only matter where a centroid lies on a face two removed
    elements share, and then either is a right parent."""
    rest = topo.rest_tuples
    tets = topo.tets
    frames = []
    for t in removed:
        c0, c1, c2, c3 = tets[t].tolist()
        frames.append(_barycentric_frame(rest[c0], rest[c1], rest[c2], rest[c3]))
    count = len(frames)
    parents = []
    found = 0
    for n, tet in enumerate(added):
        a, b, c, d = tet
        p0, p1, p2, p3 = rest[a], rest[b], rest[c], rest[d]
        cx, cy, cz = ((p0[0] + p1[0] + p2[0] + p3[0]) / 4.0, (p0[1] + p1[1] + p2[1] + p3[1]) / 4.0,
                      (p0[2] + p1[2] + p2[2] + p3[2]) / 4.0)
        start = hints[n] if hints is not None else found
        smallest_of = [0.0] * count
        found = -1
        for step in range(count):
            i = start + step
            if i >= count:
                i -= count
            r0, r1, r2, det, c3 = frames[i]
            # the smallest barycentric coordinate of the centroid in removed element i, inline:
            # a general flip asks for some fifty of these
            px, py, pz = cx - c3[0], cy - c3[1], cz - c3[2]
            x0 = (r0[0] * px + r0[1] * py + r0[2] * pz) / det
            x1 = (r1[0] * px + r1[1] * py + r1[2] * pz) / det
            x2 = (r2[0] * px + r2[1] * py + r2[2] * pz) / det
            smallest = min(x0, x1, x2, 1.0 - (x0 + x1 + x2))
            if smallest > _INSIDE:
                found = i
                break
            smallest_of[i] = smallest
        if found < 0:  # no clear container: the first of largest smallest coordinate
            best, best_min = 0, -math.inf
            for i, smallest in enumerate(smallest_of):
                if smallest > best_min:
                    best, best_min = i, smallest
            found = best
        parents.append(removed[found])
    return parents


def _barycentric_frame(c0, c1, c2, c3):
    """What :func:`_containing` needs of the element c0 c1 c2 c3: the rows of
    ``det(Dm) Dm^{-1}`` (cross products of the columns of ``Dm = [c0-c3 | c1-c3 | c2-c3]``),
    ``det(Dm)`` and c3."""
    a = (c0[0] - c3[0], c0[1] - c3[1], c0[2] - c3[2])
    b = (c1[0] - c3[0], c1[1] - c3[1], c1[2] - c3[2])
    c = (c2[0] - c3[0], c2[1] - c3[1], c2[2] - c3[2])
    bc = (b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2], b[0] * c[1] - b[1] * c[0])
    ca = (c[1] * a[2] - c[2] * a[1], c[2] * a[0] - c[0] * a[2], c[0] * a[1] - c[1] * a[0])
    ab = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    det = a[0] * bc[0] + a[1] * bc[1] + a[2] * bc[2]
    return bc, ca, ab, det, c3


def _substitute(tet: list[int], old: int, new: int) -> list[int]:
    return [new if v == old else v for v in tet]


def split_tet(topo: TetTopology, t: int, weights) -> tuple[int, list[int]]:
    """1-4 split (thesis figure 5.1): a new vertex at barycentric ``weights`` of element t
    replaces it by four elements sharing the vertex. Returns (vertex, new elements)."""
    tet = topo.tet(t)
    weights = _weights(weights, 4, f"split 1-4 of element {t}")
    data = topo.interpolate(tet, weights)  # the new vertex's attributes: checked, then stored
    added = [_substitute(tet, v, -1) for v in tet]
    qualities: list[float] = []
    _check(topo, added, f"split 1-4 of element {t}", {-1: data[REST]}, qualities)
    p = topo.add_vertex(tet, weights, origin_tet=t, data=data)
    return p, topo.replace_tets([t], [_substitute(s, -1, p) for s in added], qualities=qualities)


def split_face(topo: TetTopology, key: tuple[int, int, int], weights) -> tuple[int, list[int]]:
    """Split face ``key`` at barycentric ``weights`` of its sorted vertices: each element on
    the face becomes three. On a boundary face this is the 1-3 split of thesis figure 5.5;
    on an interior face it splits both elements (2-6), the fallback of a refused 2-3 flip.
    Returns (vertex, new elements)."""
    owners = list(topo.face_tets.get(key, ()))
    if not owners:
        raise TopologyError(f"split of face {key}: no such face")
    weights = _weights(weights, 3, f"split of face {key}")
    data = topo.interpolate(list(key), weights)
    added = [_substitute(topo.tet(t), v, -1) for t in owners for v in key]
    qualities: list[float] = []
    _check(topo, added, f"split of face {key}", {-1: data[REST]}, qualities)
    p = topo.add_vertex(list(key), weights, origin_tet=owners[0], data=data)
    return p, topo.replace_tets(owners, [_substitute(s, -1, p) for s in added], [t for t in owners for _ in key],
                                qualities)


def flip23(topo: TetTopology, key: tuple[int, int, int], quality_drop: float | None = None, *,
           accept=None, link_faces: bool = True) -> list[int]:
    """2-3 flip (thesis figure 5.2): the two elements on interior face ``key`` = (a, b, c),
    with apices d and e, become (d, e, a, b), (d, e, b, c), (d, e, c, a) around edge (d, e).
    Refused unless segment d-e passes through the face, and, with ``quality_drop``, unless
    the worst new element's quality (float64, rest) is at least ``quality_drop`` times that
    of the worse of the two elements it replaces (a flip can make a sliver next to a good
    element), and, with ``accept`` (mesh improvement), unless ``accept(removed, added)`` (slots,
    vertex lists) is true. ``link_faces``: as in :meth:`TetTopology.replace_tets`. Returns the
    new elements."""
    owners = topo.face_owners(key)
    if len(owners) != 2 or key in topo.unsewn:
        raise TopologyError(f"flip 2-3 of face {key}: not an interior face")
    t0, t1 = owners
    tet0, tet1 = topo.tet(t0), topo.tet(t1)
    d = next(v for v in tet0 if v not in key)
    e = next(v for v in tet1 if v not in key)
    a, b, c = key
    rest = topo.rest_tuples
    volumes = [signed_volume(rest[d], rest[e], rest[u], rest[w]) for u, w in ((a, b), (b, c), (c, a))]
    added = [[d, e, u, w] if v > 0 else [d, e, w, u] for (u, w), v in zip(((a, b), (b, c), (c, a)), volumes)]
    # All three must lie on the same side of their edge d-e: same orientation of (u, w).
    if len({v > 0 for v in volumes}) != 1:
        raise TopologyError(f"flip 2-3 of face {key}: edge ({d}, {e}) does not cross the face")
    qualities: list[float] = []
    worst = _check(topo, added, f"flip 2-3 of face {key}", None, qualities)
    if quality_drop is not None:
        before = _smaller(topo.quality(t0), topo.quality(t1))
        if not worst >= quality_drop * before:
            raise TopologyError(f"flip 2-3 of face {key}: its worst element would have {worst / before:.2g} "
                                f"of the quality of the worse element it replaces")
    if accept is not None and not accept([t0, t1], added):
        raise TopologyError(f"flip 2-3 of face {key}: not an improvement")
    return topo.replace_tets([t0, t1], added, _containing(topo, [t0, t1], added), qualities, link_faces=link_faces)


def bisect_edge(topo: TetTopology, a: int, b: int, s: float) -> tuple[int, list[int]]:
    """Bisection of edge (a, b) (thesis figure 5.5, right) at ``(1 - s) a + s b``: every
    element around the edge is split in two. Returns (vertex, new elements)."""
    around = sorted(topo.edge_tets(a, b))
    if not around:
        raise TopologyError(f"bisection of edge ({a}, {b}): no such edge")
    if not 0.0 < s < 1.0:
        raise TopologyError(f"bisection of edge ({a}, {b}): the parameter must be in (0, 1), got {s}")
    added = []
    for t in around:
        tet = topo.tet(t)
        added += [_substitute(tet, a, -1), _substitute(tet, b, -1)]
    data = topo.interpolate([a, b], [1 - s, s])
    qualities: list[float] = []
    _check(topo, added, f"bisection of edge ({a}, {b})", {-1: data[REST]}, qualities)
    m = topo.add_vertex([a, b], [1 - s, s], origin_tet=around[0], data=data)
    return m, topo.replace_tets(around, [_substitute(t, -1, m) for t in added], [t for t in around for _ in (0, 1)],
                                qualities)


def remove_edge(topo: TetTopology, a: int, b: int, *, allow_volume_change: bool = False,
                volume_tolerance: float = 1e-12, canonical: bool = False, accept=None,
                link_faces: bool = True) -> list[int]:
    """General flip, or edge removal (thesis figure 5.3): the n elements around edge (a, b)
    become 2(n - 2) elements (a, tau) and (b, tau) over a triangulation tau of the polygon of
    their other vertices (closed for an interior edge; closed by one more edge for a
    boundary edge, which replaces the two boundary faces on (a, b)).

    The triangulation maximises the worst element quality (dynamic programming over the
    polygon, as in Shewchuk's edge removal). A boundary edge's flip changes the volume unless
    its two boundary faces are coplanar: it is refused when the relative change exceeds
    ``volume_tolerance`` unless ``allow_volume_change``. Between equally good triangulations
    the choice depends on where the polygon starts: ``canonical`` starts it as the compiled
    operator does (``TetTopology.edge_ring``). With ``accept`` (mesh improvement) it is
    refused unless ``accept(removed, added)`` (slots, vertex lists) is true. ``link_faces``: as
    in :meth:`TetTopology.replace_tets`. Returns the new elements.
    """
    ring, polygon, closed = topo.edge_ring(a, b, canonical)
    rest = topo.rest_tuples
    m = len(polygon)
    if m < 3:
        raise TopologyError(f"general flip of edge ({a}, {b}): only {m} vertices around it")
    q = _polygon_qualities([rest[v] for v in polygon], rest[a], rest[b])
    # best[i][j]: (worst quality, apex k) of the best triangulation of polygon[i..j]
    best: list[list] = [[None] * m for _ in range(m)]
    inf = math.inf
    for span in range(2, m):
        for i in range(m - span):
            j = i + span
            qi, best_i = q[i], best[i]
            choice = None
            for k in range(i + 1, j):  # the best; within NEAR_TIE of it, the larger apex (as the kernel)
                value = min(qi[k][j], best_i[k][0] if k > i + 1 else inf, best[k][j][0] if j > k + 1 else inf)
                if choice is None or value >= choice[0] - NEAR_TIE * abs(choice[0]):
                    choice = (value, k)
            best_i[j] = choice
    if not best[0][m - 1][0] > DEGENERATE_TOL:
        raise TopologyError(f"general flip of edge ({a}, {b}): no triangulation of its {m}-gon "
                            f"gives valid elements (best quality {best[0][m - 1][0]:.2e})")
    triangles, stack, hints = [], [(0, m - 1)], []
    while stack:
        i, j = stack.pop()
        k = best[i][j][1]
        triangles.append((polygon[i], polygon[k], polygon[j]))
        hints.append(k - 1)  # ring[k - 1] and ring[k] hold polygon[k]: the centroid is near
        stack += [(i, k)] * (k > i + 1) + [(k, j)] * (j > k + 1)
    added = [[u, v, w, b] for u, v, w in triangles] + [[u, w, v, a] for u, v, w in triangles]
    qualities: list[float] = []
    _check(topo, added, f"general flip of edge ({a}, {b})", None, qualities)  # float32 too
    if accept is not None and not accept(ring, added):
        raise TopologyError(f"general flip of edge ({a}, {b}): not an improvement")
    if not closed:
        before, after = replaced_volumes(topo, ring, added)
        if abs(after - before) > volume_tolerance * before and not allow_volume_change:
            raise TopologyError(f"general flip of boundary edge ({a}, {b}) would change the volume by "
                                f"{(after - before) / before:.1e} (its boundary faces are not coplanar)")
    return topo.replace_tets(ring, added, _containing(topo, ring, added, hints + hints), qualities,
                             link_faces=link_faces)


def contract_edge(topo: TetTopology, u: int, w: int, *, accept=None, link_faces: bool = True) -> list[int]:
    """Edge contraction: vertex u, made by the change being recorded
    (:meth:`TetTopology.begin_change`), merges into its neighbour w. The elements on edge
    (u, w) go, the other elements around u take w instead of u; u is left without elements (the
    caller drops it: :meth:`TetTopology.drop_orphans`).

    Refused unless every new element is well shaped and their volume is that of u's star (they
    then tile it), w lies in the plane of every boundary face around u (u slides within a flat
    boundary or along a straight crease, so the boundary stays: as :func:`move_vertex`), the
    link condition holds (:func:`_link_condition`), no face on u is unsewn, and, with
    ``accept`` (mesh improvement), ``accept(removed, added)`` (slots, vertex lists).
    ``link_faces``: as in :meth:`TetTopology.replace_tets`. Returns the new elements."""
    return apply_contraction(topo, check_contraction(topo, u, w, accept=accept), link_faces=link_faces)


def check_contraction(topo: TetTopology, u: int, w: int, *, accept=None, lips=frozenset()) -> tuple:
    """Raise :class:`TopologyError` where :func:`contract_edge` would refuse; return what
    :func:`apply_contraction` makes. Changes nothing (a caller contracting two edges together,
    the two copies of an edge of a wound's lips, checks both first). ``lips``: boundary faces
    at u (sorted vertex triples) that may move, a wound's lip whose copy the other contraction
    moves the same way; the volume of u's star is then the caller's to check, with the other's."""
    star = sorted(topo.vertex_tets[u])
    tets = [topo.tet(t) for t in star]
    kept = [tet for tet in tets if w not in tet]
    if len(kept) == len(tets):
        raise TopologyError(f"contraction of edge ({u}, {w}): no such edge")
    if u < topo.first_new_vertex:  # the change record keeps every vertex of before
        raise TopologyError(f"contraction of edge ({u}, {w}): {u} was not made by the change being recorded "
                            f"(begin_change)")
    if topo.unsewn and any(face_key(*[x for x in tet if x != y]) in topo.unsewn for tet in tets for y in tet if y != u):
        raise TopologyError(f"contraction of edge ({u}, {w}): a face on {u} is unsewn")
    added = [_substitute(tet, u, w) for tet in kept]
    if _off_its_planes(_boundary_normals(topo, u, lips), topo.vertex_data[w, REST] - topo.vertex_data[u, REST]):
        raise TopologyError(f"contraction of edge ({u}, {w}) would take boundary vertex {u} off its boundary")
    if accept is not None and not (added and accept(star, added)):  # (asked first: it refuses most)
        raise TopologyError(f"contraction of edge ({u}, {w}): not an improvement")
    if not _link_condition(topo, u, w):
        raise TopologyError(f"contraction of edge ({u}, {w}) would change the mesh's topology (link condition)")
    qualities: list[float] = []
    _check(topo, added, f"contraction of edge ({u}, {w})", None, qualities)
    if not lips:
        before, after = replaced_volumes(topo, star, added)
        if not abs(after - before) <= 1e-12 * before:  # (the elements all on the edge: none left)
            raise TopologyError(f"contraction of edge ({u}, {w}) would change the volume by "
                                f"{(after - before) / before:.1e}")
    return star, added, qualities


def replaced_volumes(topo: TetTopology, removed, added: list[list[int]]) -> tuple[float, float]:
    """The rest volumes (m^3) of live elements ``removed`` (slots) and of the elements
    ``added`` (vertex lists) meant to replace them: equal where ``added`` tiles ``removed``."""
    rest = topo.rest_tuples
    return (sum(topo.rest_volume(t) for t in removed),
            sum(signed_volume(*[rest[v] for v in tet]) for tet in added))


def _link_condition(topo: TetTopology, u: int, w: int) -> bool:
    """Whether contracting edge (u, w) keeps the topology of the mesh and of its boundary: the
    links of u and w share only the link of the edge (Dey, Edelsbrunner, Guha and Nekhayev
    1999), the boundary coned to a vertex outside (-1). Tiling the star with its volume does
    not ensure it: where a wound's lips meet at u (a blade's front), a contraction that tiled
    the star left an element hanging loose, joined to nothing."""
    def closure(simplex: tuple, into: set) -> None:
        into.add(simplex)
        if len(simplex) > 1:
            for i in range(len(simplex)):
                closure(simplex[:i] + simplex[i + 1:], into)

    def link(v: int) -> set:
        found: set = set()
        for t in topo.vertex_tets[v]:
            closure(tuple(sorted(x for x in topo.tet(t) if x != v)), found)
        for face in topo.boundary_faces_at(v):
            closure(tuple(sorted([x for x in face if x != v] + [-1])), found)
        return found

    edge: set = set()
    for t in topo.vertex_tets[u] & topo.vertex_tets[w]:
        closure(tuple(sorted(x for x in topo.tet(t) if x != u and x != w)), edge)
    for face in topo.boundary_faces_at(u):
        if w in face:
            closure(tuple(sorted([x for x in face if x != u and x != w] + [-1])), edge)
    return (link(u) & link(w)) <= edge


def apply_contraction(topo: TetTopology, checked: tuple, *, link_faces: bool = True) -> list[int]:
    """Make the contraction :func:`check_contraction` checked; returns the new elements."""
    star, added, qualities = checked
    return topo.replace_tets(star, added, _containing(topo, star, added), qualities, link_faces=link_faces)


def _polygon_qualities(corners: list, rest_a, rest_b) -> list:
    """``q[i][j][k]`` for i < j < k: the worse quality of the two tetrahedra (i, k, j, a) and
    (i, j, k, b) (corners i, j, k of the polygon), each to the last bit as :func:`tet_quality`
    computes it: its edge vectors, their squared lengths and the cross products it takes
    are those of pairs of corners, computed once per pair, by the same operations."""
    m = len(corners)
    ax_, ay_, az_ = rest_a
    bx_, by_, bz_ = rest_b
    # per corner i: A - C_i, B - C_i and their squared lengths
    to_a, to_b, sa, sb = [], [], [], []
    for x, y, z in corners:
        u = (ax_ - x, ay_ - y, az_ - z)
        w = (bx_ - x, by_ - y, bz_ - z)
        to_a.append(u)
        to_b.append(w)
        sa.append(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
        sb.append(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    # per pair i < j: D = C_j - C_i, its squared length, and the cross terms of (D, A - C_i)
    # and (D, B - C_i) in tet_quality's form (by cz - bz cy, bx cz - bz cx, bx cy - by cx)
    diff = [[None] * m for _ in range(m)]
    sq = [[0.0] * m for _ in range(m)]
    cross_a = [[None] * m for _ in range(m)]
    cross_b = [[None] * m for _ in range(m)]
    for i in range(m):
        xi, yi, zi = corners[i]
        cax, cay, caz = to_a[i]
        cbx, cby, cbz = to_b[i]
        for j in range(i + 1, m):
            xj, yj, zj = corners[j]
            dx, dy, dz = xj - xi, yj - yi, zj - zi
            diff[i][j] = (dx, dy, dz)
            sq[i][j] = sq[j][i] = dx * dx + dy * dy + dz * dz
            cross_a[i][j] = (dy * caz - dz * cay, dx * caz - dz * cax, dx * cay - dy * cax)
            cross_b[i][j] = (dy * cbz - dz * cby, dx * cbz - dz * cbx, dx * cby - dy * cbx)
    q = [[[None] * m for _ in range(m)] for _ in range(m)]
    sqrt, nan = math.sqrt, math.nan
    for i in range(m):
        diff_i, sq_i, cross_ai, cross_bi, q_i = diff[i], sq[i], cross_a[i], cross_b[i], q[i]
        sai, sbi = sa[i], sb[i]
        for j in range(i + 1, m):
            dij = diff_i[j]
            sij = sq_i[j]
            xa = cross_ai[j]
            q_ij = q_i[j]
            sq_j = sq[j]
            for k in range(j + 1, m):
                # (C_i, C_k, C_j, A): edges C_k - C_i, C_j - C_i, A - C_i, C_j - C_k, A - C_k, A - C_j
                dik = diff_i[k]
                volume = (dik[0] * xa[0] - dik[1] * xa[1] + dik[2] * xa[2]) / 6.0
                longest2 = max(sq_i[k], sij, sai, sq_j[k], sa[k], sa[j])
                qa = nan if longest2 == 0.0 else volume / (longest2 * sqrt(longest2))
                # (C_i, C_j, C_k, B): edges C_j - C_i, C_k - C_i, B - C_i, C_k - C_j, B - C_j, B - C_k
                xb = cross_bi[k]
                volume = (dij[0] * xb[0] - dij[1] * xb[1] + dij[2] * xb[2]) / 6.0
                longest2 = max(sij, sq_i[k], sbi, sq_j[k], sb[j], sb[k])
                qb = nan if longest2 == 0.0 else volume / (longest2 * sqrt(longest2))
                q_ij[k] = qa if qa < qb or qa != qa else qb
    return q


def move_vertex(topo: TetTopology, v: int, parents, weights, *, feature_angle: float = 0.0,
                current: bool | tuple = False) -> None:
    """Move vertex v (snapping, thesis 5.1.3) to the barycentric combination of ``parents``.

    Refused when an element around v would invert or flatten, or, for a boundary vertex,
    unless the target lies in the plane of every boundary face around v (the vertex slides
    within a flat boundary or along a straight crease, so the boundary and the volume stay)
    or, with ``feature_angle`` (degrees) > 0, the vertex slides along one of its boundary
    edges (``parents`` = (v, other end)) on a smooth boundary: no two of its boundary faces'
    normals differ by ``feature_angle`` or more. That slide changes the volume slightly (as
    the thesis's boundary flips do, 5.1.2): in proportion to the step and to the boundary's
    curvature, about 1e-3 of the volume of the elements around v in the tests. ``current``: see
    :func:`check_vertex_move`."""
    weights = check_vertex_move(topo, v, parents, weights, feature_angle=feature_angle, current=current)
    topo.set_vertex(v, list(parents), weights)


def check_vertex_move(topo: TetTopology, v: int, parents, weights, *, feature_angle: float = 0.0,
                      keep_boundary: bool = True, current: bool | tuple = False) -> np.ndarray:
    """Raise :class:`TopologyError` where :func:`move_vertex` would refuse the move; return the
    weights as it takes them. Changes nothing (a caller moving two vertices together checks
    both first). ``keep_boundary`` False lets v leave the planes of its boundary faces: for a
    vertex inside a wound moving with its copy on the other lip, whose faces follow (the lips
    still meet and the volume stays); only the elements around v are checked then.
    ``current``: the elements around v must stay well shaped in the current configuration
    too, v's current position carried by the same weights (:func:`check_current`; a tuple is
    its ``span``)."""
    weights = _weights(weights, len(parents), f"moving vertex {v}")
    target = _point(topo, parents, weights)
    # (the boundary first: the cheaper test, and most snaps on a curved boundary fail it)
    normals = _boundary_normals(topo, v) if keep_boundary else np.zeros((0, 3))
    if _off_its_planes(normals, target - topo.vertex_data[v, REST]):
        along = len(parents) == 2 and v in parents and topo.is_boundary_edge(*parents)
        smooth = (normals @ normals.T).min() > np.cos(np.radians(feature_angle))
        if not (along and smooth and feature_angle > 0.0):
            raise TopologyError(f"moving boundary vertex {v} would take it off its boundary")
    around = sorted(topo.vertex_tets[v])
    _check(topo, [_substitute(topo.tet(t), v, -1) for t in around], f"moving vertex {v}", {-1: target})
    if current:
        star = [topo.tet(t) for t in around]
        check_current(topo, star, star, f"moving vertex {v}",
                      {v: (target, weights @ topo.vertex_data[list(parents), POSITION])},
                      span=current if isinstance(current, tuple) else None)
    return weights


#: A move checked in the current configuration (:func:`check_current`) keeps the ratio of
#: each element's current to rest volume within the range of those it replaces (and 1), or a
#: given span, widened by this fraction. On organ_cut the exact range left 51 of 61 cut events
#: with an element below 5 degrees (the blade's moves refused), this one 11, as without it.
STRAIN_SLACK = 0.1


def check_current(topo: TetTopology, before, after, what: str, moved: dict | None = None,
                  span: tuple | None = None) -> None:
    """Refuse a move that would replace elements ``before`` by ``after`` (vertex lists) unless
    ``after`` is well shaped in the current configuration, as :func:`_check` asks of the rest
    one, and no element of ``after`` is compressed or stretched beyond those of ``before``: the
    ratio of its current to rest volume stays within theirs (and 1), widened by
    :data:`STRAIN_SLACK`. ``moved`` maps a vertex to the (rest, current) positions (m) it
    would take. ``span``: the (lowest, highest) ratio to keep within instead of theirs (a
    caller making many moves passes the range of the elements before any of them, so that
    the slack does not compound).

    The improvement after a cut moves and flips in the rest configuration and carries the
    current positions by the same weights. In a body deformed far from rest, that can invert
    an element, or compress one to a few per cent of its volume, which the next steps invert
    and blow up (the S-example's synthetic capture, Bielser at epsilon 0, diverged so): strain,
    and energy, from nowhere."""
    def volumes(tets, moved):
        """Rest and current volumes of ``tets``, vertices ``moved`` substituted, and the
        current corners (M, 4, 3)."""
        index = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
        rest, now = topo.vertex_data[index, REST], topo.vertex_data[index, POSITION]
        for v, (x0, x) in (moved or {}).items():
            rest[index == v], now[index == v] = x0, x
        corners = np.arange(index.size).reshape(-1, 4)  # each element's own copies of its corners
        return [tet_volumes(c.reshape(-1, 3), corners) for c in (rest, now)], now

    if span is None:
        (rest0, now0), _ = volumes(before, None)
        span = (float((now0 / rest0).min()), float((now0 / rest0).max()))
    (rest1, now1), corners = volumes(after, moved)
    q = tet_qualities(corners)
    ratio1 = now1 / rest1
    low = min(1.0, span[0]) * (1.0 - STRAIN_SLACK)
    high = max(1.0, span[1]) * (1.0 + STRAIN_SLACK)
    bad = ~(q > DEGENERATE_TOL) | ~(ratio1 >= low) | ~(ratio1 <= high)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise TopologyError(f"{what}: element {list(after[i])} would have {ratio1[i]:.3g} of its rest volume in "
                            f"the current configuration (quality {q[i]:.2e}; allowed {low:.3g} to {high:.3g})")


def _off_its_planes(normals: np.ndarray, step: np.ndarray) -> bool:
    """Whether a boundary vertex's ``step`` (rest, m) leaves the plane of one of its boundary
    faces (unit ``normals`` (K, 3); none for an inner vertex), beyond rounding."""
    return len(normals) > 0 and bool(np.abs(normals @ step).max() > 1e-12 * (np.linalg.norm(step) + 1e-300))


def _boundary_normals(topo: TetTopology, v: int, leaving=frozenset()) -> np.ndarray:
    """Unit normals (K, 3) of the boundary faces around vertex v (but those in ``leaving``,
    sorted vertex triples)."""
    rest = topo.rest_tuples
    normals = [_unit_normal(rest[a], rest[b], rest[c]) for a, b, c in topo.boundary_faces_at(v)
               if not leaving or tuple(sorted((a, b, c))) not in leaving]
    return np.array(normals).reshape(-1, 3)


def boundary_plane_count(topo: TetTopology, v: int) -> int:
    """The number of distinct planes of the boundary faces around vertex v, counted up to three
    (0 for an inner vertex): 1 on a flat boundary, 2 on a straight crease (where v may move
    along the line the planes share), 3 where it may not move at all."""
    normals = _boundary_normals(topo, v)
    count = 0
    while len(normals) and count < 3:
        normals = normals[normals @ normals[0] < 1.0 - 1e-12]
        count += 1
    return count


def _unit_normal(p0, p1, p2) -> tuple[float, float, float]:
    """Unit normal of triangle p0 p1 p2 (right-hand rule)."""
    ax, ay, az = p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]
    bx, by, bz = p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx / length, ny / length, nz / length


def unsew_face(topo: TetTopology, key: tuple[int, int, int]) -> None:
    """Delete the binding between the two elements of interior face ``key`` (thesis 5.1.3):
    they stay on the same vertices until :func:`duplicate_vertex` separates them."""
    if len(topo.face_tets.get(key, ())) != 2:
        raise TopologyError(f"unsewing face {key}: not an interior face")
    topo.unsewn.add(key)


def vertex_fans(topo: TetTopology, v: int) -> list[list[int]]:
    """The elements around v grouped into fans connected through faces on v that are not
    unsewn; the largest fan first, each fan in the order of ``vertex_tets[v]``."""
    around = list(topo.vertex_tets[v])
    face_tets, unsewn, slot_face_keys = topo.face_tets, topo.unsewn, topo.slot_face_keys
    fan_of: dict[int, int] = {}
    count = 0
    for start in around:  # a search through the faces on v from each element not yet reached
        if start in fan_of:
            continue
        fan_of[start] = count
        stack = [start]
        while stack:
            t = stack.pop()
            for key in slot_face_keys[t]:
                if v in key and key not in unsewn:  # only the three faces on v, and sewn
                    owners = face_tets[key]
                    if len(owners) == 2:
                        s = owners[1] if owners[0] == t else owners[0]
                        if s not in fan_of:
                            fan_of[s] = count
                            stack.append(s)
        count += 1
    if count == 1:
        return [around]
    fans: list[list[int]] = [[] for _ in range(count)]
    for t in around:
        fans[fan_of[t]].append(t)
    return sorted(fans, key=lambda f: (-len(f), min(f)))


def duplicate_vertex(topo: TetTopology, v: int) -> list[int]:
    """Split vertex v into one copy per fan of elements (thesis figure 4.8): the largest fan
    keeps v, each other fan gets a new vertex with v's attributes. Returns the new vertices."""
    fans = vertex_fans(topo, v)
    copies = []
    for fan in fans[1:]:
        w = topo.add_vertex([v], [1.0])
        for t in fan:
            topo.retarget(t, v, w)
        copies.append(w)
    return copies


def sew_unopened(topo: TetTopology) -> int:
    """Bind again the unsewn faces that no vertex duplication opened (the two elements still
    share the three vertices, e.g. at the front of a partial cut). Returns how many."""
    count = len(topo.unsewn)
    topo.unsewn.clear()
    return count
