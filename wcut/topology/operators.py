"""Local topological operators on a :class:`~wcut.topology.mesh.TetTopology` (thesis 5.1).

Each operator checks its result before it changes anything: every new element must be
positively oriented with quality (volume / longest edge^3, rest configuration) above
``DEGENERATE_TOL``. If not, it raises :class:`TopologyError` saying why and leaves the mesh
as it was, so the cutter can fall back (to snapping, to a face split, to a bisection).
New vertices carry rest position, position and velocity by barycentric interpolation.

Except the general flip of a boundary edge (which may, when allowed, smooth the boundary),
every operator conserves the total rest volume exactly up to rounding.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..mesh import DEGENERATE_TOL, TET_FACES
from .mesh import REST, TetTopology, TopologyError, face_key, signed_volume


def tet_qualities(points: np.ndarray) -> np.ndarray:
    """Quality (volume / longest edge^3) of (M, 4, 3) tetrahedra."""
    d1, d2, d3 = (points[:, i] - points[:, 0] for i in (1, 2, 3))
    volume = np.einsum("ij,ij->i", np.cross(d1, d2), d3) / 6.0
    diff = points[:, :, None, :] - points[:, None, :, :]
    longest = np.sqrt((diff * diff).sum(axis=3).max(axis=(1, 2)))
    return volume / longest**3


def _check(topo: TetTopology, tets: list[list[int]], what: str, extra: dict | None = None) -> None:
    """Refuse unless every tetrahedron of ``tets`` is well shaped in the rest configuration.

    ``extra`` maps a vertex not yet in the mesh (index -1, -2, ...) to its rest position."""
    rest = topo.vertex_data[:, REST]
    points = np.array([[extra[v] if v < 0 else rest[v] for v in tet] for tet in tets])
    # The simulation sees float32 rest positions: the element must survive that rounding.
    q = np.minimum(tet_qualities(points), tet_qualities(points.astype(np.float32).astype(np.float64)))
    worst = int(np.argmin(q))
    if not q[worst] > DEGENERATE_TOL:
        state = "inverted" if q[worst] < 0 else "flat"
        raise TopologyError(f"{what}: element {tets[worst]} would be {state} (quality {q[worst]:.2e})")


def _weights(weights, count: int, what: str) -> np.ndarray:
    """Barycentric weights: ``count`` finite numbers summing to 1."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) != count or not np.isfinite(w).all() or abs(w.sum() - 1.0) > 1e-9:
        raise TopologyError(f"{what}: expected {count} finite barycentric weights summing to 1, got {w.tolist()}")
    return w


def _point(topo: TetTopology, parents, weights) -> np.ndarray:
    return np.asarray(weights, float) @ topo.vertex_data[parents, REST]


def _containing(topo: TetTopology, removed: list[int], added: list[list[int]]) -> list[int]:
    """For each new element, the removed element that contains its centroid (the one whose
    smallest barycentric coordinate of it is largest): its parent in the change record."""
    rest = topo.vertex_data[:, REST]
    centroids = rest[np.asarray(added)].mean(axis=1)
    corners = rest[topo.tets[removed]]                       # (R, 4, 3)
    Dm = (corners[:, :3] - corners[:, 3:]).transpose(0, 2, 1)
    xi = np.einsum("rij,arj->ari", np.linalg.inv(Dm), centroids[:, None, :] - corners[None, :, 3])
    bary_min = np.minimum(xi.min(axis=2), 1.0 - xi.sum(axis=2))   # (A, R)
    return [removed[i] for i in np.argmax(bary_min, axis=1)]


def _substitute(tet: list[int], old: int, new: int) -> list[int]:
    return [new if v == old else v for v in tet]


def split_tet(topo: TetTopology, t: int, weights) -> tuple[int, list[int]]:
    """1-4 split (thesis figure 5.1): a new vertex at barycentric ``weights`` of element t
    replaces it by four elements sharing the vertex. Returns (vertex, new elements)."""
    tet = topo.tet(t)
    weights = _weights(weights, 4, f"split 1-4 of element {t}")
    added = [_substitute(tet, v, -1) for v in tet]
    _check(topo, added, f"split 1-4 of element {t}", {-1: _point(topo, tet, weights)})
    p = topo.add_vertex(tet, weights, origin_tet=t)
    return p, topo.replace_tets([t], [_substitute(s, -1, p) for s in added])


def split_face(topo: TetTopology, key: tuple[int, int, int], weights) -> tuple[int, list[int]]:
    """Split face ``key`` at barycentric ``weights`` of its sorted vertices: each element on
    the face becomes three. On a boundary face this is the 1-3 split of thesis figure 5.5;
    on an interior face it splits both elements (2-6), the fallback of a refused 2-3 flip.
    Returns (vertex, new elements)."""
    owners = list(topo.face_tets.get(key, ()))
    if not owners:
        raise TopologyError(f"split of face {key}: no such face")
    weights = _weights(weights, 3, f"split of face {key}")
    added = [_substitute(topo.tet(t), v, -1) for t in owners for v in key]
    _check(topo, added, f"split of face {key}", {-1: _point(topo, list(key), weights)})
    p = topo.add_vertex(list(key), weights, origin_tet=owners[0])
    return p, topo.replace_tets(owners, [_substitute(s, -1, p) for s in added], [t for t in owners for _ in key])


def flip23(topo: TetTopology, key: tuple[int, int, int]) -> list[int]:
    """2-3 flip (thesis figure 5.2): the two elements on interior face ``key`` = (a, b, c),
    with apices d and e, become (d, e, a, b), (d, e, b, c), (d, e, c, a) around edge (d, e).
    Refused unless segment d-e passes through the face. Returns the new elements."""
    owners = topo.face_tets.get(key, ())
    if len(owners) != 2 or key in topo.unsewn:
        raise TopologyError(f"flip 2-3 of face {key}: not an interior face")
    t0, t1 = owners
    d = next(v for v in topo.tet(t0) if v not in key)
    e = next(v for v in topo.tet(t1) if v not in key)
    a, b, c = key
    rest = dict(zip((a, b, c, d, e), topo.vertex_data[[a, b, c, d, e], REST].tolist()))
    volumes = [signed_volume(rest[d], rest[e], rest[u], rest[w]) for u, w in ((a, b), (b, c), (c, a))]
    added = [[d, e, u, w] if v > 0 else [d, e, w, u] for (u, w), v in zip(((a, b), (b, c), (c, a)), volumes)]
    # All three must lie on the same side of their edge d-e: same orientation of (u, w).
    if len({v > 0 for v in volumes}) != 1:
        raise TopologyError(f"flip 2-3 of face {key}: edge ({d}, {e}) does not cross the face")
    _check(topo, added, f"flip 2-3 of face {key}")
    return topo.replace_tets([t0, t1], added, _containing(topo, [t0, t1], added))


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
    _check(topo, added, f"bisection of edge ({a}, {b})", {-1: _point(topo, [a, b], [1 - s, s])})
    m = topo.add_vertex([a, b], [1 - s, s], origin_tet=around[0])
    return m, topo.replace_tets(around, [_substitute(t, -1, m) for t in added], [t for t in around for _ in (0, 1)])


def remove_edge(topo: TetTopology, a: int, b: int, *, allow_volume_change: bool = False,
                volume_tolerance: float = 1e-12) -> list[int]:
    """General flip, or edge removal (thesis figure 5.3): the n elements around edge (a, b)
    become 2(n - 2) elements (a, tau) and (b, tau) over a triangulation tau of the polygon of
    their other vertices (closed for an interior edge; closed by one more edge for a
    boundary edge, which replaces the two boundary faces on (a, b)).

    The triangulation maximises the worst element quality (dynamic programming over the
    polygon, as in Shewchuk's edge removal). A boundary edge's flip changes the volume unless
    its two boundary faces are coplanar: it is refused when the relative change exceeds
    ``volume_tolerance`` unless ``allow_volume_change``. Returns the new elements.
    """
    ring, polygon, closed = topo.edge_ring(a, b)
    rest = topo.vertex_data[:, REST]
    m = len(polygon)
    if m < 3:
        raise TopologyError(f"general flip of edge ({a}, {b}): only {m} vertices around it")
    # quality of the two tetrahedra over every triangle (i, j, k), i < j < k
    triples = np.array(list(itertools.combinations(range(m), 3)))
    poly = np.asarray(polygon)[triples]
    pts_b = rest[np.column_stack([poly, np.full(len(poly), b)])]
    pts_a = rest[np.column_stack([poly[:, [0, 2, 1]], np.full(len(poly), a)])]
    quality = np.minimum(tet_qualities(pts_a), tet_qualities(pts_b))
    q = {tuple(t): v for t, v in zip(triples.tolist(), quality.tolist())}
    best: dict[tuple[int, int], tuple[float, int]] = {}
    for span in range(2, m):
        for i in range(m - span):
            j = i + span
            best[i, j] = max(
                (min(q[i, k, j], best[i, k][0] if k > i + 1 else np.inf, best[k, j][0] if j > k + 1 else np.inf), k)
                for k in range(i + 1, j))
    if not best[0, m - 1][0] > DEGENERATE_TOL:
        raise TopologyError(f"general flip of edge ({a}, {b}): no triangulation of its {m}-gon "
                            f"gives valid elements (best quality {best[0, m - 1][0]:.2e})")
    triangles, stack = [], [(0, m - 1)]
    while stack:
        i, j = stack.pop()
        k = best[i, j][1]
        triangles.append((polygon[i], polygon[k], polygon[j]))
        stack += [(i, k)] * (k > i + 1) + [(k, j)] * (j > k + 1)
    added = [[u, v, w, b] for u, v, w in triangles] + [[u, w, v, a] for u, v, w in triangles]
    if not closed:
        before = sum(topo.rest_volume(t) for t in ring)
        after = sum(signed_volume(*rest[t].tolist()) for t in added)
        if abs(after - before) > volume_tolerance * before and not allow_volume_change:
            raise TopologyError(f"general flip of boundary edge ({a}, {b}) would change the volume by "
                                f"{(after - before) / before:.1e} (its boundary faces are not coplanar)")
    return topo.replace_tets(ring, added, _containing(topo, ring, added))


def move_vertex(topo: TetTopology, v: int, parents, weights, *, feature_angle: float = 0.0) -> None:
    """Move vertex v (snapping, thesis 5.1.3) to the barycentric combination of ``parents``.

    Refused when an element around v would invert or flatten, or, for a boundary vertex,
    unless the target lies in the plane of every boundary face around v (the vertex slides
    within a flat boundary or along a straight crease, so the boundary and the volume stay)
    or, with ``feature_angle`` (degrees) > 0, the vertex slides along one of its boundary
    edges (``parents`` = (v, other end)) on a smooth boundary: no two of its boundary faces'
    normals differ by ``feature_angle`` or more. That slide changes the volume, by a
    fraction second order in the step, as the thesis's boundary flips do (5.1.2)."""
    weights = _weights(weights, len(parents), f"moving vertex {v}")
    target = _point(topo, parents, weights)
    around = sorted(topo.vertex_tets[v])
    _check(topo, [_substitute(topo.tet(t), v, -1) for t in around], f"moving vertex {v}", {-1: target})
    normals = _boundary_normals(topo, v)
    if len(normals):
        step = target - topo.vertex_data[v, REST]
        if np.abs(normals @ step).max() > 1e-12 * (np.linalg.norm(step) + 1e-300):
            along = len(parents) == 2 and v in parents and _is_boundary_edge(topo, *parents)
            smooth = (normals @ normals.T).min() > np.cos(np.radians(feature_angle))
            if not (along and smooth and feature_angle > 0.0):
                raise TopologyError(f"moving boundary vertex {v} would take it off its boundary")
    topo.set_vertex(v, list(parents), weights)


def _is_boundary_edge(topo: TetTopology, a: int, b: int) -> bool:
    ring = topo.edge_tets(a, b)
    return any(len(topo.face_tets[face_key(a, b, c)]) == 1 for t in ring for c in topo.tet(t) if c not in (a, b))


def _boundary_normals(topo: TetTopology, v: int) -> np.ndarray:
    """Unit normals (K, 3) of the boundary faces around vertex v."""
    rest = topo.vertex_data[:, REST]
    normals = []
    for t in topo.vertex_tets[v]:
        tet = topo.tet(t)
        for local in TET_FACES.tolist():
            tri = [tet[i] for i in local]
            if v in tri and len(topo.face_tets[face_key(*tri)]) == 1:
                n = np.cross(rest[tri[1]] - rest[tri[0]], rest[tri[2]] - rest[tri[0]])
                normals.append(n / np.linalg.norm(n))
    return np.array(normals).reshape(-1, 3)


def unsew_face(topo: TetTopology, key: tuple[int, int, int]) -> None:
    """Delete the binding between the two elements of interior face ``key`` (thesis 5.1.3):
    they stay on the same vertices until :func:`duplicate_vertex` separates them."""
    if len(topo.face_tets.get(key, ())) != 2:
        raise TopologyError(f"unsewing face {key}: not an interior face")
    topo.unsewn.add(key)


def vertex_fans(topo: TetTopology, v: int) -> list[list[int]]:
    """The elements around v grouped into fans connected through faces on v that are not
    unsewn; the largest fan first."""
    around = list(topo.vertex_tets[v])
    parent = {t: t for t in around}

    def find(t):
        while parent[t] != t:
            parent[t] = parent[parent[t]]
            t = parent[t]
        return t

    for t in around:
        tet = topo.tet(t)
        for local in TET_FACES.tolist():
            tri = [tet[i] for i in local]
            if v not in tri:
                continue
            key = face_key(*tri)
            if key in topo.unsewn:
                continue
            for s in topo.face_tets[key]:
                if s != t:
                    parent[find(s)] = find(t)
    fans: dict[int, list[int]] = {}
    for t in around:
        fans.setdefault(find(t), []).append(t)
    return sorted(fans.values(), key=lambda f: (-len(f), min(f)))


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
