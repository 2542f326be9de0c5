"""Validity checks of a changing mesh: what every operator and every cut must keep.

:func:`check_topology` verifies, from scratch, what :class:`TetTopology` maintains
incrementally; tests call it after every operator. :func:`connected_components` labels the
pieces of a mesh (two elements are connected when they share a face).
"""

from __future__ import annotations

import numpy as np

from ..mesh import DEGENERATE_TOL, TET_FACES, TetMesh, unique_rows
from .mesh import TetTopology, TopologyError, face_key
from .operators import tet_qualities


def check_topology(topo: TetTopology, volume: float | None = None, volume_tolerance: float = 1e-9) -> None:
    """Raise :class:`TopologyError` unless the mesh is valid:

    - every live element well shaped and positively oriented (rest configuration);
    - ``vertex_tets``, ``face_tets`` and ``slot_face_keys`` equal to the adjacency rebuilt from
      the elements (reading the faces links those a compiled write-back left for later);
    - every face in one or two elements, unsewn faces interior;
    - the boundary closed: each directed boundary edge matched by its reverse;
    - when ``volume`` is given, total rest volume equal to it (relative ``volume_tolerance``).
    """
    slots = topo.live_tets()
    tets = topo.tets[slots]
    rest = topo.rest_positions
    q = tet_qualities(rest[tets])
    if len(q) and not q.min() > DEGENERATE_TOL:
        t = int(slots[np.argmin(q)])
        raise TopologyError(f"element {t} {topo.tet(t)} has quality {q.min():.2e}")
    vertex_tets = [set() for _ in range(topo.vertex_count)]
    face_tets: dict = {}
    for t, tet in zip(slots.tolist(), tets.tolist()):
        for v in tet:
            vertex_tets[v].add(t)
        for i, j, k in TET_FACES.tolist():
            face_tets.setdefault(face_key(tet[i], tet[j], tet[k]), []).append(t)
    if vertex_tets != topo.vertex_tets[: topo.vertex_count]:
        bad = next(v for v in range(topo.vertex_count) if vertex_tets[v] != topo.vertex_tets[v])
        raise TopologyError(f"elements around vertex {bad}: stored {sorted(topo.vertex_tets[bad])}, "
                            f"actual {sorted(vertex_tets[bad])}")
    for t, tet in zip(slots.tolist(), tets.tolist()):
        if set(topo.slot_face_keys[t]) != {face_key(tet[i], tet[j], tet[k]) for i, j, k in TET_FACES.tolist()}:
            raise TopologyError(f"element {t} {tet}: stored face keys {topo.slot_face_keys[t]} are stale")
    stored = {k: sorted(v) for k, v in topo.face_tets.items()}
    actual = {k: sorted(v) for k, v in face_tets.items()}
    if stored != actual:
        bad = next(k for k in set(stored) | set(actual) if stored.get(k) != actual.get(k))
        raise TopologyError(f"elements on face {bad}: stored {stored.get(bad)}, actual {actual.get(bad)}")
    over = [k for k, v in actual.items() if len(v) > 2]
    if over:
        raise TopologyError(f"face {over[0]} is shared by {len(actual[over[0]])} elements")
    lone = [k for k in topo.unsewn if len(actual.get(k, ())) != 2]
    if lone:
        raise TopologyError(f"unsewn face {lone[0]} is not an interior face")
    check_closed(topo.to_mesh())
    if volume is not None:
        total = float(topo.to_mesh().volumes().sum())
        if abs(total - volume) > volume_tolerance * abs(volume):
            raise TopologyError(f"total rest volume {total:.12g} m^3 differs from {volume:.12g} m^3 "
                                f"(relative {(total - volume) / volume:.1e})")


def check_closed(mesh: TetMesh) -> None:
    """Raise :class:`TopologyError` unless the boundary surface is closed and consistently
    oriented: every directed boundary edge (u, v) is matched by a (v, u)."""
    tri = mesh.boundary().triangles
    if not len(tri):
        return
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    base = int(tri.max()) + 1
    forward = unique_rows(directed, base, return_counts=True)
    backward = unique_rows(directed[:, ::-1], base, return_counts=True)
    if not (np.array_equal(forward[0], backward[0]) and np.array_equal(forward[1], backward[1])):
        fset = {tuple(e): c for e, c in zip(forward[0].tolist(), forward[1].tolist())}
        bset = {tuple(e): c for e, c in zip(backward[0].tolist(), backward[1].tolist())}
        bad = next(e for e in set(fset) | set(bset) if fset.get(e) != bset.get(e))
        raise TopologyError(f"the boundary is not closed at edge {bad}")


def connected_components(mesh) -> np.ndarray:
    """(M,) label of the connected component of each element, labels 0..C-1 in order of first
    element: tetrahedra (a TetMesh) sharing a face, or shell triangles (a ShellMesh) sharing a
    corner edge, are connected."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as scipy_components

    from .. import shell
    from ..mesh import ShellMesh

    elements, sides = (mesh.triangles, shell.EDGES) if isinstance(mesh, ShellMesh) else (mesh.tets, TET_FACES)
    count = len(elements)
    faces = np.sort(elements[:, sides].reshape(-1, sides.shape[1]), axis=1)
    _, inverse = unique_rows(faces, int(faces.max(initial=0)) + 1, return_inverse=True)
    inverse = inverse.ravel()
    owner = np.repeat(np.arange(count), len(sides))
    order = np.argsort(inverse, kind="stable")
    same = inverse[order[1:]] == inverse[order[:-1]]
    a, b = owner[order[:-1][same]], owner[order[1:][same]]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(count,) * 2)
    _, labels = scipy_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)  # relabel in order of first element
    remap = np.empty(labels.max() + 1, dtype=np.int64)
    remap[labels[np.sort(first)]] = np.arange(len(first))
    return remap[labels]
