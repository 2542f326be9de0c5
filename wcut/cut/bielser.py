"""Bielser's subdivision cut (thesis 5.2, figure 5.9 left), the baseline of figure 5.11.

Bielser et al. insert a vertex at the crossing on every cut edge and one on the cut line
inside every cut face, and subdivide each cut element into up to 17 elements joined on
these vertices. The same vertices and a conforming subdivision come out of edge bisections:

1. every crossed edge is bisected at its crossing (thesis figure 5.5, right), which leaves,
   on every cut face, an edge joining its two crossings (the face's cut line);
2. that edge is bisected at its midpoint: the face vertex;
3. the faces whose three vertices are on the cut are unsewn and their vertices duplicated.

So the counts of the thesis's analysis hold: n(e) + n(f) vertices on the surface before the
separation doubles them (5.2.1). Snapping with ``epsilon`` happens first, as in the
"Bielser with snapping" curves of figure 5.11.
"""

from __future__ import annotations

from ..mesh import TET_FACES
from ..topology import TopologyError, bisect_edge, face_key, move_vertex
from .cutter import MIN_SNAP, CutStats, Cutter, _edge, barycentric


def bielser_cut(cutter: Cutter, surface, slots, stats: CutStats) -> None:
    topo = cutter.topology
    threshold = max(cutter.epsilon, MIN_SNAP) * cutter.mean_edge_length
    sampling, marked = cutter.snap(surface, slots, threshold, stats)
    if not marked and not sampling.edges:
        return
    cut_faces = set()
    for t in sampling.cut_slots:
        tet = topo.tet(t)
        for local in TET_FACES.tolist():
            tri = [tet[i] for i in local]
            if any(_edge(tri[i], tri[j]) in sampling.edges for i, j in ((0, 1), (1, 2), (0, 2))):
                cut_faces.add(face_key(*tri))
    edge_vertex = {}
    for (a, b), (t, _) in sampling.edges.items():
        try:
            edge_vertex[a, b], _ = bisect_edge(topo, a, b, t)
        except TopologyError as exc:
            stats.refused.append(str(exc))
            continue
        stats.bisections += 1
        marked.add(edge_vertex[a, b])
    for key in sorted(cut_faces):
        ends = [edge_vertex.get(_edge(key[i], key[j])) for i, j in ((0, 1), (1, 2), (0, 2))]
        ends = [v for v in ends if v is not None] + [v for v in key if v in marked]
        if len(ends) != 2 or not topo.edge_tets(*ends):
            continue  # a partial cut ends in this face, or it has no single cut line
        try:
            f, _ = bisect_edge(topo, ends[0], ends[1], 0.5)
        except TopologyError as exc:
            stats.refused.append(str(exc))
            continue
        _onto_surface_in_face(cutter, surface, f, key)
        stats.face_splits += 1
        marked.add(f)
    cutter._disconnect(surface, marked, stats)


def _onto_surface_in_face(cutter: Cutter, surface, f: int, key) -> None:
    """Slide face vertex ``f`` within its face ``key`` onto a curved surface: the midpoint of the
    face's cut line is on the surface only where it is flat, and a vertex off the surface is
    cut again by the next cut along it (a progressive cut recuts everything swept so far).
    Left where it is if the move would spoil an element."""
    corners = cutter.coordinates()[list(key)]
    weights = barycentric(cutter.coordinates()[f], corners)
    moved = cutter._onto_surface(surface, corners, weights)
    if moved is not weights:
        try:
            move_vertex(cutter.topology, f, list(key), moved)
        except TopologyError:
            pass
