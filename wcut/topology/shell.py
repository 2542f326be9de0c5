"""Local topological operators of quadratic shells: open an edge, move a node, split a triangle
(thesis 6.2 and its future work).

A crack in a sheet of 6-node triangles runs along element edges (thesis 6.2, figure 6.13):

- :func:`open_edges` unsews corner edges and duplicates every node into one copy per fan of
  triangles still sewn around it (the edge node of an opened edge always, a corner when the
  crack passes through it or reaches the boundary there);
- :func:`move_nodes` moves nodes in the rest configuration (snapping a corner to the crack
  line, figure 6.14) and says where their current positions come from;
- :func:`split_triangle` splits a triangle into four along its six nodes and its neighbours
  into two (red-green refinement, the thesis's proposed future work), so a crack can follow
  finer edges while the sheet keeps its geometry exactly.

Each returns the new :class:`wcut.mesh.ShellMesh` and a :class:`TopologyChange` from which
:meth:`wcut.model.Model.rebuild` carries the state over. Vertex weights are quadratic shape
functions of an old element (or 1 on a duplicated node), so positions and velocities are
interpolated exactly where the old field was quadratic. An operator that would leave an
invalid mesh (a folded or degenerate triangle, a slit closed at both ends) raises
:class:`TopologyError` and changes nothing. :func:`check_shell` verifies a mesh from scratch.
"""

from __future__ import annotations

import numpy as np

from .. import shell
from ..errors import MeshError
from ..mesh import ShellMesh
from .change import TopologyChange
from .mesh import TopologyError

#: Smallest quality ``4 sqrt(3) A / sum l^2`` (1 for an equilateral triangle) that a moved
#: node may leave in any of its corner triangles.
MIN_MOVE_QUALITY = 0.15


def edge_key(a: int, b: int) -> tuple[int, int]:
    """The key of the corner edge between ``a`` and ``b`` (order-free)."""
    return (a, b) if a < b else (b, a)


def edge_users(triangles: np.ndarray) -> dict[tuple[int, int], list[tuple[int, int]]]:
    """Corner edge key -> ``[(triangle, local edge k), ...]`` (one or two entries in a valid
    mesh); local edge ``k`` joins corners ``EDGES[k]`` and has edge node ``3 + k``."""
    users: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for t, tri in enumerate(triangles.tolist()):
        for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
            users.setdefault(edge_key(tri[i], tri[j]), []).append((t, k))
    return users


def triangle_qualities(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``4 sqrt(3) A / (l0^2 + l1^2 + l2^2)`` of the corner triangles (M,): 1 when
    equilateral, 0 when degenerate. ``A`` is unsigned."""
    x = points[triangles[:, :3]]
    area = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    lengths = sum(np.sum((x[:, a] - x[:, b]) ** 2, axis=1) for a, b in shell.EDGES)
    return 4.0 * np.sqrt(3.0) * area / np.maximum(lengths, 1e-300)


def _change(vertex_count_before: int, triangle_count_before: int, vertex_count_after: int,
            expression: dict[int, dict[int, float]], element_parent: np.ndarray, rest_changed: np.ndarray,
            vertex_parent: dict[int, int] | None = None, replaced=()) -> TopologyChange:
    """A TopologyChange of a shell: vertices of before keep their index unless ``expression``
    says otherwise (vertex after -> {vertex before: weight}); new vertices are appended.
    Triangles ``replaced`` by pieces keep their index for their first piece; the other pieces
    are appended (their parent in ``element_parent``)."""
    width = max([1] + [len(e) for e in expression.values()])
    sources = np.repeat(np.arange(vertex_count_after, dtype=np.int64)[:, None], width, axis=1)
    weights = np.zeros((vertex_count_after, width))
    weights[:, 0] = 1.0
    for v, expr in expression.items():
        keys, values = list(expr), list(expr.values())
        sources[v] = keys + [keys[0]] * (width - len(keys))
        weights[v] = values + [0.0] * (width - len(values))
    parent = np.full(vertex_count_after, -1, dtype=np.int64)
    for v, t in (vertex_parent or {}).items():
        parent[v] = t
    count = len(element_parent)
    replaced = np.array(sorted(replaced), dtype=np.int64)
    return TopologyChange(
        vertex_count_before=vertex_count_before, vertex_count_after=vertex_count_after,
        element_count_before=triangle_count_before, element_count_after=count,
        vertex_sources=sources, vertex_weights=weights, vertex_parent_element=parent,
        new_vertices=np.arange(vertex_count_before, vertex_count_after, dtype=np.int64),
        moved_vertices=np.array(sorted(v for v in expression if v < vertex_count_before), dtype=np.int64),
        element_parent=element_parent, element_rest_changed=rest_changed,
        removed_elements=replaced,
        added_elements=np.concatenate([replaced, np.arange(triangle_count_before, count, dtype=np.int64)]),
    )


def _fans(v: int, around: list[int], triangles: np.ndarray, opened: set) -> list[list[int]]:
    """The triangles ``around`` node ``v`` grouped into fans: two triangles are in one fan when
    a chain of them joins them, each sharing with the next an edge through ``v`` (or whose edge
    node is ``v``) that is not ``opened``. Fans in order of their smallest triangle."""
    parent = {t: t for t in around}

    def root(t):
        while parent[t] != t:
            parent[t] = parent[parent[t]]
            t = parent[t]
        return t

    seen: dict[tuple[int, int], int] = {}
    for t in around:
        tri = triangles[t]
        for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
            if v not in (tri[i], tri[j], tri[3 + k]):
                continue
            key = edge_key(int(tri[i]), int(tri[j]))
            if key in opened:
                continue
            if key in seen:
                parent[root(t)] = root(seen[key])
            else:
                seen[key] = t
    groups: dict[int, list[int]] = {}
    for t in sorted(around):
        groups.setdefault(root(t), []).append(t)
    return sorted(groups.values(), key=lambda g: g[0])


def open_edges(mesh: ShellMesh, edges) -> tuple[ShellMesh, TopologyChange]:
    """Unsew the interior corner edges ``edges`` ((a, b) pairs) and duplicate the nodes the
    opening disconnects (thesis 6.2: separation along existing edges, vertex duplication).

    Every node of an opened edge (its two corners and its edge node) is split into one copy
    per fan of triangles still sewn around it; the fan of the lowest-numbered triangle keeps
    the node, the others get new nodes appended in order. A corner inside the sheet with one
    opened edge stays whole: it is a crack tip.

    Raises:
        TopologyError: an edge is not a corner edge shared by two triangles, or an opened edge
            would keep both its corners whole (a slit closed at both ends, whose two sides
            would be one edge twice). Nothing is changed.
    """
    triangles = mesh.triangles.copy()
    users = edge_users(triangles)
    opened: set[tuple[int, int]] = set()
    for a, b in edges:
        key = edge_key(int(a), int(b))
        if len(users.get(key, ())) != 2:
            where = "is not an edge of the mesh" if key not in users else "is on the boundary"
            raise TopologyError(f"open_edges: edge {key} {where}")
        opened.add(key)
    nodes = set()
    for key in opened:
        nodes.update(key)
        nodes.update(int(triangles[t, 3 + k]) for t, k in users[key])

    vertex_count = len(mesh.vertices)
    expression: dict[int, dict[int, float]] = {}
    for v in sorted(nodes):
        around = np.flatnonzero((triangles == v).any(axis=1)).tolist()
        for fan in _fans(v, around, mesh.triangles, opened)[1:]:
            copy = vertex_count + len(expression)
            expression[copy] = {v: 1.0}
            rows = np.array(fan)
            triangles[rows] = np.where(triangles[rows] == v, copy, triangles[rows])
    for key in sorted(opened):
        (t0, k0), (t1, k1) = users[key]
        side0 = edge_key(*triangles[t0, shell.EDGES[k0]].tolist())
        side1 = edge_key(*triangles[t1, shell.EDGES[k1]].tolist())
        if side0 == side1:
            raise TopologyError(f"open_edges: opening edge {key} alone would leave a slit closed at both ends "
                                f"(open it from a crack tip or from the boundary)")
    vertices = np.concatenate([mesh.vertices, mesh.vertices[[next(iter(e)) for e in expression.values()]]]) \
        if expression else mesh.vertices.copy()
    count = len(triangles)
    change = _change(vertex_count, count, len(vertices), expression, np.arange(count),
                     np.zeros(count, dtype=bool))
    return ShellMesh.trusted(vertices, triangles, name=mesh.name), change


def locate(points: np.ndarray, triangles: np.ndarray, candidates, target: np.ndarray,
           iterations: int = 8) -> tuple[int, np.ndarray, float]:
    """The element among ``candidates`` that holds ``target`` (3,) best, the barycentric
    coordinates (3,) of the point of that element nearest to it, with node positions
    ``points`` (rest or current configuration), and how far outside it the target was (the
    most negative barycentric coordinate, negated; 0 inside).

    The quadratic map ``x(L) = sum N_a(L) x_a`` is inverted by Gauss-Newton from the flat
    corner triangle's solution (exact in one step for a straight element); a point outside
    every candidate goes to the one it is outside of least, its barycentric coordinates
    clipped to [0, 1] and renormalised (a point of that element near the target, not always
    the nearest).
    """
    best, best_L, best_violation = -1, None, np.inf
    for t in candidates:
        x = points[triangles[t]]
        L = _flat_barycentric(x[:3], target)
        for _ in range(iterations):
            residual = shell.shape_functions(L)[0] @ x - target
            J = np.einsum("ad,ai->id", shell.shape_gradients(L)[0], x)  # dx/dxi (3, 2)
            step = np.linalg.lstsq(J, -residual, rcond=None)[0]
            L = L + np.array([-step.sum(), step[0], step[1]])
            if np.abs(step).max() < 1e-13:
                break
        violation = -min(L.min(), 0.0)
        if violation < best_violation - 1e-12:
            best, best_L, best_violation = int(t), L, violation
    L = np.clip(best_L, 0.0, 1.0)
    return best, L / L.sum(), float(best_violation)


def _flat_barycentric(corners: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (3,) of the projection of ``point`` on the plane of
    ``corners`` (3, 3)."""
    e1, e2, d = corners[1] - corners[0], corners[2] - corners[0], point - corners[0]
    gram = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    l1, l2 = np.linalg.solve(gram, [d @ e1, d @ e2])
    return np.array([1.0 - l1 - l2, l1, l2])


def shape_weights(triangles: np.ndarray, t: int, L: np.ndarray) -> dict[int, float]:
    """{node: N_a(L)} of element ``t`` at barycentric point ``L``: the weights with which any
    quadratic field of that element is read there (zero weights dropped)."""
    N = shell.shape_functions(L)[0]
    weights: dict[int, float] = {}
    for node, w in zip(triangles[t].tolist(), N.tolist()):
        if w != 0.0:
            weights[node] = weights.get(node, 0.0) + w
    return weights


def move_nodes(mesh: ShellMesh, moves: dict[int, tuple[np.ndarray, dict[int, float]]],
               min_quality: float = MIN_MOVE_QUALITY) -> tuple[ShellMesh, TopologyChange]:
    """Move nodes in the rest configuration: ``moves`` maps a node to ``(rest position (3,),
    {old node: weight})``, the weights giving its current position and velocity from the old
    ones (e.g. :func:`shape_weights` at the material point it moves to, which moves the node
    through the material without straining it; figure 6.14).

    Raises:
        TopologyError: a triangle around a moved node would fold (non-positive Jacobian at a
            Gauss point or node), turn over (corner normal against its old one) or have a
            corner quality below ``min_quality``. Nothing is changed.
    """
    vertices = mesh.vertices.copy()
    for v, (position, _) in moves.items():
        vertices[v] = position
    touched = np.flatnonzero(np.isin(mesh.triangles, list(moves)).any(axis=1))
    tris = mesh.triangles[touched]
    before = shell.corner_normals(mesh.vertices, tris)
    after = shell.corner_normals(vertices, tris)
    quality = triangle_qualities(vertices, tris)
    at_gauss, at_nodes = shell.jacobians(vertices, tris)
    worst = np.minimum(at_gauss.min(axis=1), at_nodes.min(axis=1))
    bad = np.flatnonzero((np.einsum("ij,ij->i", before, after) <= 0.0) | (quality < min_quality) | (worst <= 0.0))
    if len(bad):
        t = int(touched[bad[0]])
        raise TopologyError(f"move_nodes: moving nodes {sorted(moves)} would leave triangle {t} with quality "
                            f"{quality[bad[0]]:.3f} (at least {min_quality}) or folded")
    count = len(mesh.triangles)
    rest_changed = np.zeros(count, dtype=bool)
    rest_changed[touched] = True
    change = _change(len(vertices), count, len(vertices), {v: w for v, (_, w) in moves.items()},
                     np.arange(count), rest_changed)
    return ShellMesh.trusted(vertices, mesh.triangles, name=mesh.name), change


#: Barycentric coordinates (in the parent) of the nodes a red split adds: the two halves of
#: each edge (corner i towards edge node of (i, j)), then the middles of the inner edges.
def _red_points() -> tuple[list[tuple[int, int]], np.ndarray]:
    e = np.eye(3)
    labels, points = [], []
    for k, (i, j) in enumerate(shell.EDGES.tolist()):
        for corner in (i, j):  # half (corner, edge node k)
            other = j if corner == i else i
            labels.append((corner, 3 + k))
            points.append(0.75 * e[corner] + 0.25 * e[other])
    mids = 0.5 * (e[shell.EDGES[:, 0]] + e[shell.EDGES[:, 1]])
    for a, b in ((3, 4), (4, 5), (5, 3)):  # inner edge between edge nodes a and b
        labels.append((a, b))
        points.append(0.5 * (mids[a - 3] + mids[b - 3]))
    return labels, np.array(points)


_RED_LABELS, _RED_POINTS = _red_points()


def split_triangle(mesh: ShellMesh, t: int) -> tuple[ShellMesh, TopologyChange]:
    """Split triangle ``t`` into four along its six nodes (its edge nodes become corners) and
    each neighbour into two through the shared edge node (red-green refinement), so the mesh
    stays conforming without hanging nodes.

    New nodes lie where the old element's quadratic map puts them (a quarter along each half
    edge, the middles of the inner edges): a quadratic restricted to a sub-triangle is again
    quadratic, so the refined sheet has exactly the old geometry, and positions and
    velocities carried by the shape-function weights are exactly the old fields. Sub-triangles
    keep their parent's orientation; ``t`` and each neighbour keep their index for their first
    piece, the others are appended.
    """
    triangles = mesh.triangles
    if not 0 <= t < len(triangles):
        raise TopologyError(f"split_triangle: triangle {t} out of range 0..{len(triangles) - 1}")
    users = edge_users(triangles)
    vertex_count = len(mesh.vertices)
    expression: dict[int, dict[int, float]] = {}
    vertex_parent: dict[int, int] = {}
    new_points: list[np.ndarray] = []

    def add(parent: int, L: np.ndarray) -> int:
        v = vertex_count + len(new_points)
        expression[v] = shape_weights(triangles, parent, L)
        vertex_parent[v] = parent
        new_points.append(sum(w * mesh.vertices[n] for n, w in expression[v].items()))
        return v

    node = triangles[t].tolist()
    new = {label: add(t, L) for label, L in zip(_RED_LABELS, _RED_POINTS)}
    half = {(node[a], node[b]): v for (a, b), v in new.items() if a < 3}  # (corner, edge node) -> node

    def inner(a, b):
        return new.get((a, b), new.get((b, a)))

    c0, c1, c2, m01, m12, m20 = node
    pieces = [
        [c0, m01, m20, half[c0, m01], inner(3, 5), half[c0, m20]],
        [m01, c1, m12, half[c1, m01], half[c1, m12], inner(3, 4)],
        [m20, m12, c2, inner(4, 5), half[c2, m12], half[c2, m20]],
        [m01, m12, m20, inner(3, 4), inner(4, 5), inner(3, 5)],
    ]
    out = [list(tri) for tri in triangles.tolist()]
    parent = list(range(len(out)))
    out[t] = pieces[0]
    for piece in pieces[1:]:
        out.append(piece)
        parent.append(t)
    for k, (i, j) in enumerate(shell.EDGES.tolist()):
        others = [u for u in users[edge_key(node[i], node[j])] if u[0] != t]
        if not others:
            continue
        n, kn = others[0]
        rot = [kn, (kn + 1) % 3, (kn + 2) % 3]  # the neighbour with the shared edge as its (0, 1)
        a, b, o = (int(triangles[n, r]) for r in rot)
        m_ab, m_bo, m_oa = (int(triangles[n, 3 + r]) for r in rot)
        L = np.zeros(3)
        L[rot[0]], L[rot[1]], L[rot[2]] = 0.25, 0.25, 0.5
        g = add(n, L)
        out[n] = [a, m_ab, o, half[a, m_ab], g, m_oa]
        out.append([m_ab, b, o, half[b, m_ab], m_bo, g])
        parent.append(n)
    vertices = np.concatenate([mesh.vertices, np.array(new_points)])
    element_parent = np.array(parent, dtype=np.int64)
    replaced = np.unique(element_parent[len(triangles):])
    rest_changed = np.arange(len(out)) >= len(triangles)
    rest_changed[replaced] = True
    change = _change(vertex_count, len(triangles), len(vertices), expression, element_parent, rest_changed,
                     vertex_parent, replaced)
    return ShellMesh.trusted(vertices, np.array(out, dtype=np.int64), name=mesh.name), change


def vertex_fan_counts(mesh: ShellMesh, nodes=None) -> np.ndarray:
    """The number of fans (edge-connected groups of triangles) around each of ``nodes``
    (default: every node); 1 everywhere on a valid sheet."""
    nodes = np.arange(mesh.vertex_count) if nodes is None else np.asarray(nodes)
    order = np.argsort(mesh.triangles, axis=None, kind="stable")
    flat = mesh.triangles.ravel()[order]
    starts = np.searchsorted(flat, nodes)
    ends = np.searchsorted(flat, nodes, side="right")
    tri_of = order // 6
    return np.array([len(_fans(int(v), np.unique(tri_of[s:e]).tolist(), mesh.triangles, set()))
                     for v, s, e in zip(nodes, starts, ends)], dtype=np.int64)


def check_shell(mesh: ShellMesh, area: float | None = None, area_tolerance: float = 1e-9) -> None:
    """Raise :class:`TopologyError` unless ``mesh`` is a valid sheet: everything
    :class:`ShellMesh` checks (every corner edge in at most two triangles with one edge node,
    consistent orientation, no degenerate or folded triangle, so positive rest areas), every
    node's triangles one fan (no two sheets pinched at a node), and, when ``area`` is given,
    the total rest area equal to it (relative ``area_tolerance``)."""
    try:
        ShellMesh(mesh.vertices, mesh.triangles, name=mesh.name)
    except MeshError as exc:
        raise TopologyError(str(exc)) from None
    fans = vertex_fan_counts(mesh)
    if (fans != 1).any():
        v = int(np.flatnonzero(fans != 1)[0])
        raise TopologyError(f"{mesh.name}: node {v} joins {fans[v]} fans of triangles (a pinched sheet)")
    if area is not None:
        now = mesh.area()
        if abs(now - area) > area_tolerance * abs(area):
            raise TopologyError(f"{mesh.name}: rest area {now!r} m^2, expected {area!r} (relative error "
                                f"{abs(now - area) / abs(area):.2e})")
