"""A tetrahedral mesh that changes: storage, local adjacency and the change journal.

:class:`TetTopology` is what the cutter edits (thesis 4.3). It keeps, and updates locally with
every change, the adjacency the operators need:

- the tetrahedra around a vertex (``vertex_tets``),
- the tetrahedra sharing a face (``face_tets``, keyed by the sorted vertex triple),
- from these, the ordered ring of tetrahedra around an edge (:meth:`edge_ring`) and the
  boundary faces.

The face adjacency may lag: a replacement written back from the compiled operators
(``replace_tets(link_faces=False)``) updates the vertex stars at once and leaves its faces to
be linked the first time ``face_tets`` or ``slot_face_keys`` is read, exactly as linking then
would have. The compiled cutter's own queries (boundary tests, the faces of a region) count a
face's elements from the vertex stars (:meth:`TetTopology.face_owner_count`), so a cut event
does not pay for dictionary work only the Python operators need.

A face can be *unsewn* (thesis 5.1.3, the combinatorial map's volume binding deleted): its
two tetrahedra still share the three vertices but no longer count as connected through it
when a vertex is split into one copy per connected fan (:meth:`duplicate_vertex`).

Vertex attributes are carried in one float64 table, ``vertex_data``: rest position (m),
current position (m) and velocity (m/s). A vertex created inside an element gets the
barycentric combination of the element's vertices, for all three at once: for linear
elements the map from rest to current configuration is affine per element, so this is exact
(thesis 3.2).

Element slots are reused once freed (as CGoGN's attribute containers do), so an element's
index is stable while it lives and the cost of a change follows the elements it touches.
:meth:`begin_change` / :meth:`end_change` bracket a topological event and produce the
:class:`~wcut.topology.change.TopologyChange` that :meth:`wcut.model.Model.rebuild` reads.
"""

from __future__ import annotations

import itertools
import math
import struct

import numpy as np
import warp as wp

from ..errors import WcutError
from ..kernels import point_location
from ..mesh import TET_FACES, TetMesh, unique_rows

#: per local vertex, the TET_FACES through it, each with the local indices of its two other
#: vertices: (i, j, k, a, b)
_FACES_THROUGH = tuple(tuple((*face, *[u for u in face if u != local]) for face in TET_FACES.tolist() if local in face)
                       for local in range(4))

#: Columns of ``vertex_data``.
REST, POSITION, VELOCITY = slice(0, 3), slice(3, 6), slice(6, 9)


#: Qualities, and rest coordinates, within this relative difference tie: the compiled
#: operators' positions can differ from the Python ones in their last bit, and a choice between
#: two equally good results must not turn on it (``kernels.topology.NEAR_TIE``).
NEAR_TIE = 1.0e-12


class TopologyError(WcutError):
    """An operator refused a change (it would invert or flatten an element, or its input is
    not what it needs); the mesh is left as it was."""


def face_key(a: int, b: int, c: int) -> tuple[int, int, int]:
    """The key of the face with vertices a, b, c: the sorted triple."""
    if a > b:
        a, b = b, a
    if b > c:
        b, c = c, b
    if a > b:
        a, b = b, a
    return (a, b, c)


def signed_volume(p0, p1, p2, p3) -> float:
    """Signed volume (m^3) of the tetrahedron p0 p1 p2 p3: det[p1-p0, p2-p0, p3-p0] / 6.
    (Plain float arithmetic: numpy's per-call overhead dominates for one tetrahedron.)"""
    x0, y0, z0 = p0[0], p0[1], p0[2]
    ax, ay, az = p1[0] - x0, p1[1] - y0, p1[2] - z0
    bx, by, bz = p2[0] - x0, p2[1] - y0, p2[2] - z0
    cx, cy, cz = p3[0] - x0, p3[1] - y0, p3[2] - z0
    return float(ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)) / 6.0


def point_tuples(points) -> tuple[list[tuple[float, float, float]], list[tuple[float, float, float]]]:
    """(N, 3) points as tuples of Python floats: as they are (float64), and rounded to float32
    (what the simulation sees). The operators check a handful of elements per call, where
    plain float arithmetic costs a fraction of numpy's per-call overhead."""
    rows = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    as_is = [tuple(p) for p in rows.tolist()]
    rounded = [tuple(p) for p in rows.astype(np.float32).astype(np.float64).tolist()]
    return as_is, rounded


def tet_quality(p0, p1, p2, p3) -> float:
    """Quality (volume / longest edge^3) of one tetrahedron, corners as (x, y, z) floats.

    The arithmetic of :func:`wcut.topology.operators.tet_qualities`, operation for operation,
    so the two agree to the last bit (use this one for a few elements: it avoids numpy's
    per-call overhead). Four coincident corners give NaN (0/0), as numpy does."""
    return tet_quality_and_length(p0, p1, p2, p3)[0]


def tet_quality_and_length(p0, p1, p2, p3) -> tuple[float, float]:
    """:func:`tet_quality` and the longest edge's length (m); (NaN, 0) for coincident corners."""
    x0, y0, z0 = p0
    x1, y1, z1 = p1
    x2, y2, z2 = p2
    x3, y3, z3 = p3
    ax, ay, az = x1 - x0, y1 - y0, z1 - z0
    bx, by, bz = x2 - x0, y2 - y0, z2 - z0
    cx, cy, cz = x3 - x0, y3 - y0, z3 - z0
    volume = (ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)) / 6.0
    dx, dy, dz = x2 - x1, y2 - y1, z2 - z1
    ex, ey, ez = x3 - x1, y3 - y1, z3 - z1
    fx, fy, fz = x3 - x2, y3 - y2, z3 - z2
    longest2 = max(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz, cx * cx + cy * cy + cz * cz,
                   dx * dx + dy * dy + dz * dz, ex * ex + ey * ey + ez * ez, fx * fx + fy * fy + fz * fz)
    if longest2 == 0.0:
        return math.nan, 0.0
    length = math.sqrt(longest2)
    return volume / (longest2 * length), length


_FLOAT32_XYZ = struct.Struct("3f")


def rounded32(p) -> tuple[float, float, float]:
    """Point (x, y, z) rounded to float32 and back, as ``astype(np.float32)`` rounds it: struct
    packs with the same C conversion (to nearest, ties to even), without numpy's overhead."""
    try:
        return _FLOAT32_XYZ.unpack(_FLOAT32_XYZ.pack(*p))
    except OverflowError:  # some Pythons refuse to pack beyond float32's range; numpy gives inf
        return point_tuples(p)[1][0]


#: room in :meth:`TetTopology.rest_points`'s first launch for this many elements holding each
#: point (more than a vertex's star in a usable mesh; where it is not, the launch runs again)
HITS_PER_POINT = 64


class TetTopology:
    """A tetrahedral mesh with local adjacency that stays correct through every change.

    Args:
        mesh: the rest configuration.
        positions: (N, 3) current positions (m); the rest positions when omitted.
        velocities: (N, 3) velocities (m/s); zero when omitted.

    Invariants kept by every operator (checked by :func:`wcut.topology.check.check_topology`):
    live elements positively oriented with quality above ``DEGENERATE_TOL`` in the rest
    configuration, every face in at most two elements, adjacency equal to the adjacency
    rebuilt from the elements, total rest volume unchanged (only boundary operators that say
    so change it).

    Besides ``vertex_data``, the rest positions are kept as Python float tuples,
    ``rest_tuples`` and their float32-rounded values ``rest_tuples32`` (read them, never
    write them), for the operators' arithmetic on a few elements at a time. Rest positions
    change only through :meth:`add_vertex`, :meth:`set_vertex` and
    :meth:`drop_unused_vertices`, which keep both in step (:attr:`rest_positions` is a
    read-only view); code that writes ``vertex_data[:, REST]`` itself must call
    :meth:`sync_rest_tuples` afterwards.

    ``slot_face_keys[t]`` holds the keys of live element t's four faces (the sorted triples,
    as in ``face_tets``), set when t is linked: the adjacency walks read them instead of
    sorting vertices again. Read them, never write them; only the editing methods here change
    ``tets``. The vertex stars ``vertex_tets`` are always up to date; the faces are linked
    when ``face_tets`` or ``slot_face_keys`` is first read, and after the compiled cutter's
    write-backs (:meth:`replace_tets` with ``link_faces=False``), exactly as linking them at
    once would have: a session of compiled cuts never pays for them.
    """

    def __init__(self, mesh: TetMesh, positions=None, velocities=None):
        n = mesh.vertex_count
        data = np.zeros((max(2 * n, 16), 9))
        data[:n, REST] = mesh.vertices
        data[:n, POSITION] = mesh.vertices if positions is None else _per_vertex(positions, n, "positions", mesh)
        if velocities is not None:
            data[:n, VELOCITY] = _per_vertex(velocities, n, "velocities", mesh)
        self.vertex_data = data
        self.vertex_count = n
        self.sync_rest_tuples()
        m = mesh.tet_count
        self.tets = np.zeros((max(2 * m, 16), 4), dtype=np.int64)
        self.tets[:m] = mesh.tets
        self.alive = np.zeros(len(self.tets), dtype=bool)
        self.alive[:m] = True
        self.slot_count = m
        self._free: list[int] = []
        self.vertex_tets: list[set[int]] = [set() for _ in range(n)]
        self._face_tets: dict[tuple[int, int, int], list[int]] = {}
        #: per slot, the keys of its element's four faces (:func:`_face_keys`): kept by
        #: ``_link`` so that unlinking and the adjacency walks never sort vertices again
        self._slot_face_keys: list[tuple | None] = [None] * len(self.tets)
        #: replacements whose faces are not linked yet: (removed slots, [(slot, vertices)]) (the
        #: first: the mesh's elements), and how many elements they add; past the mesh's size the
        #: log is dropped and the faces are marked stale: linked anew from the live elements
        #: when next read
        self._unlinked_faces: list[tuple[list[int], list[tuple[int, list[int]]]]] = []
        self._unlinked_count = 0
        self._faces_stale = False
        #: per slot, the element's float64 rest quality (:func:`tet_quality` of its vertices in
        #: slot order) once computed, else None: see :meth:`quality`
        self._slot_quality: list[float | None] = [None] * len(self.tets)
        vertex_tets = self.vertex_tets
        for t, tet in enumerate(mesh.tets.tolist()):
            for v in tet:
                vertex_tets[v].add(t)
        # the faces are linked when first read (most of a large mesh's set-up, and a compiled
        # cut never reads them): the first batch of the log, ahead of any replacement
        self._unlinked_faces.append(([], _NumberedRows(mesh.tets.copy())))
        self.unsewn: set[tuple[int, int, int]] = set()
        self.name = mesh.name
        self._journal: _Journal | None = None
        #: :meth:`boundary_faces_at` per vertex asked, until any vertex's star changes (the mesh
        #: improvement asks for the same vertices over and over between two changes)
        self._boundary_at: dict[int, list[tuple[int, int, int]]] = {}

    # ----------------------------------------------------------------- queries
    @property
    def tet_count(self) -> int:
        """Number of live elements."""
        return self.slot_count - len(self._free)

    def unlinked_log_limit(self) -> int:
        """How many elements the log of replacements whose faces wait to be linked may add
        before it is dropped (the faces then linked anew when read): the mesh's size, at
        least 4096. It bounds the log's memory however long a session cuts."""
        return max(self.tet_count, 4096)

    @property
    def face_tets(self) -> dict[tuple[int, int, int], list[int]]:
        """The elements of each face (key: sorted vertex triple), in the order they were
        linked (read it, never write it)."""
        if self._unlinked_faces or self._faces_stale:
            self._link_faces()
        return self._face_tets

    @property
    def slot_face_keys(self) -> list:
        """Per slot, the keys of its element's four faces (read them, never write them)."""
        if self._unlinked_faces or self._faces_stale:
            self._link_faces()
        return self._slot_face_keys

    def face_owner_count(self, a: int, b: int, c: int) -> int:
        """How many elements have face (a, b, c): 1 on the boundary, 2 inside (unsewn or not),
        0 for no face. From the vertex stars, so it never waits for the face adjacency."""
        vertex_tets = self.vertex_tets
        return len(vertex_tets[a] & vertex_tets[b] & vertex_tets[c])

    def face_owners(self, key) -> list[int]:
        """The elements of face ``key`` (any vertex order), ascending: from the vertex stars, so
        it never waits for the face adjacency (the mesh improvement's flips read only these)."""
        a, b, c = key
        vertex_tets = self.vertex_tets
        return sorted(vertex_tets[a] & vertex_tets[b] & vertex_tets[c])

    def live_tets(self) -> np.ndarray:
        """Slots of the live elements, ascending (the order of :meth:`to_mesh`)."""
        if not self._free:  # no freed slot waits for reuse: every slot below slot_count lives
            return np.arange(self.slot_count)
        return np.flatnonzero(self.alive[: self.slot_count])

    @property
    def rest_positions(self) -> np.ndarray:
        """(N, 3) rest positions (m), a read-only view (the operators change them, keeping
        ``rest_tuples`` in step)."""
        view = self.vertex_data[: self.vertex_count, REST]
        view.flags.writeable = False
        return view

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) current positions (m), a view."""
        return self.vertex_data[: self.vertex_count, POSITION]

    @property
    def velocities(self) -> np.ndarray:
        """(N, 3) velocities (m/s), a view."""
        return self.vertex_data[: self.vertex_count, VELOCITY]

    def tet(self, t: int) -> list[int]:
        return self.tets[t].tolist()

    def rest_volume(self, t: int) -> float:
        """Signed rest volume (m^3) of element slot t."""
        rest = self.rest_tuples
        return signed_volume(*[rest[v] for v in self.tets[t].tolist()])

    def quality(self, t: int) -> float:
        """Quality (volume / longest edge^3, float64, rest configuration) of live element slot
        t: :func:`tet_quality` of its vertices in slot order, to the last bit. Remembered per
        slot until the element or one of its vertices' rest positions changes."""
        q = self._slot_quality[t]
        if q is None:
            rest = self.rest_tuples
            a, b, c, d = self.tets[t].tolist()
            q = self._slot_quality[t] = tet_quality(rest[a], rest[b], rest[c], rest[d])
        return q

    def neighbors(self, t: int, key: tuple[int, int, int]) -> list[int]:
        """The other element across face ``key`` of element t ([] on the boundary or unsewn)."""
        if key in self.unsewn:
            return []
        return [s for s in self.face_tets[key] if s != t]

    def is_boundary_face(self, key) -> bool:
        return self.face_owner_count(*key) == 1

    def boundary_faces(self) -> np.ndarray:
        """(F, 3) boundary triangles, outward oriented (faces of a single element)."""
        out = []
        for t in self.live_tets().tolist():
            tet = self.tets[t]
            for local in TET_FACES:
                tri = tet[local]
                if self.face_owner_count(*tri.tolist()) == 1:
                    out.append(tri)
        return np.array(out, dtype=np.int64).reshape(-1, 3)

    def edge_tets(self, a: int, b: int) -> set[int]:
        """Elements containing edge (a, b)."""
        return self.vertex_tets[a] & self.vertex_tets[b]

    def edge_ring(self, a: int, b: int, canonical: bool = False) -> tuple[list[int], list[int], bool]:
        """The ordered ring of elements around edge (a, b) (thesis figure 5.1).

        Returns ``(tets, polygon, closed)``: element ``tets[i]`` is ``(a, b, polygon[i],
        polygon[i+1])`` up to orientation, ordered so that ``signed_volume(a, b, polygon[i],
        polygon[i+1]) > 0``. For an interior edge the ring is closed (``polygon`` has one vertex
        per element, indices taken cyclically); for a boundary edge it is open and ``polygon``
        has one more vertex than there are elements. Unsewn faces count as boundary.
        ``canonical``: a closed ring starts at its first polygon vertex by rest position
        (:meth:`rest_before`), whatever the numbering of the elements and vertices (as the
        compiled operators walk it).
        """
        around = self.edge_tets(a, b)
        if not around:
            raise TopologyError(f"edge ({a}, {b}) is not in the mesh")
        tets, unsewn = self.tets, self.unsewn
        others = {t: [v for v in tets[t].tolist() if v != a and v != b] for t in around}
        holders: dict[int, list[int]] = {}  # the elements of face (a, b, w), by w: no face adjacency needed
        for t, (u, w) in others.items():
            holders.setdefault(u, []).append(t)
            holders.setdefault(w, []).append(t)

        def across(t, w):
            """The element across face (a, b, w) of element t; -1 on the boundary or unsewn."""
            if unsewn and face_key(a, b, w) in unsewn:
                return -1
            for s in holders[w]:
                if s != t:
                    return s
            return -1

        # An open ring starts at an element with a boundary face on the edge.
        start, first = next(iter(around)), None
        for t in around:
            for w in others[t]:
                if across(t, w) < 0:
                    start, first = t, w
                    break
            if first is not None:
                break
        if first is None:
            first = others[start][0]
        ring, polygon = [], [first]
        t, w = start, first
        while True:
            o0, o1 = others[t]
            u = o0 if o0 != w else o1
            ring.append(t)
            polygon.append(u)
            nxt = across(t, u)
            if nxt < 0 or nxt == start:
                break
            t, w = nxt, u
            if len(ring) > len(around):
                raise TopologyError(f"edge ({a}, {b}): its ring of elements is not a manifold fan")
        closed = nxt == start
        if closed:
            polygon.pop()
        if len(ring) != len(around):
            raise TopologyError(f"edge ({a}, {b}): its elements form more than one fan")
        rest = self.rest_tuples
        if signed_volume(rest[a], rest[b], rest[polygon[0]], rest[polygon[1]]) < 0:
            ring.reverse()
            polygon.reverse()
            if closed:  # keep polygon[i], polygon[i+1] the corners of ring[i]
                polygon = polygon[-1:] + polygon[:-1]
        if closed and canonical:
            r = 0
            for i in range(len(polygon)):
                if self.rest_before(polygon[i], polygon[r]):
                    r = i
            ring, polygon = ring[r:] + ring[:r], polygon[r:] + polygon[:r]
        return ring, polygon, closed

    def rest_before(self, u: int, v: int) -> bool:
        """Whether vertex u's rest position comes before v's, coordinate by coordinate, two
        coordinates within ``NEAR_TIE`` (1e-12) of the points' size counting as equal, so
        that positions differing in their last bits compare alike; by number where the
        positions are the same (as ``kernels.topology.rest_before``)."""
        p, q = self.rest_tuples[u], self.rest_tuples[v]
        tolerance = NEAR_TIE * (math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
                                + math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]))
        for a, b in zip(p, q):
            if a < b - tolerance:
                return True
            if a > b + tolerance:
                return False
        return u < v

    def is_boundary_edge(self, a: int, b: int) -> bool:
        """Whether edge (a, b) lies on a boundary face (unsewn faces are not counted)."""
        return any(self.face_owner_count(a, b, c) == 1
                   for t in self.edge_tets(a, b) for c in self.tets[t].tolist() if c != a and c != b)

    def boundary_faces_at(self, v: int) -> list[tuple[int, int, int]]:
        """The boundary faces through vertex v (unsewn faces are not counted), each ordered as
        its element's :data:`TET_FACES` order it (outward). Every element with a face through v
        is in v's star, so counting the faces there gives their owners: the cost of one star."""
        faces = self._boundary_at.get(v)
        if faces is not None:
            return faces
        found: dict[tuple, tuple | None] = {}  # by the face's two other vertices, sorted
        tets = self.tets
        for t in self.vertex_tets[v]:
            tet = tets[t].tolist()
            for i, j, k, a, b in _FACES_THROUGH[tet.index(v)]:
                key = (tet[a], tet[b]) if tet[a] < tet[b] else (tet[b], tet[a])
                found[key] = None if key in found else (tet[i], tet[j], tet[k])
        faces = self._boundary_at[v] = [tri for tri in found.values() if tri is not None]
        return faces

    def is_boundary_vertex(self, v: int) -> bool:
        """Whether vertex v lies on a boundary face (unsewn faces are not counted)."""
        return bool(self.boundary_faces_at(v))

    def rest_points(self, points) -> np.ndarray:
        """Map points of the current configuration (m) to the rest configuration (m).

        A point inside an element keeps its barycentric coordinates there (for linear elements
        the rest-to-current map is affine per element, thesis 3.2). A point outside the mesh (a
        blade's ends stick out of the body) is carried from the nearest boundary point q by
        the affine map of q's element: rest(q) + F^-1 (p - q). Extrapolating from q rather than
        from a nearby element's centre keeps an outside point outside under bending (the
        error grows with the distance from q, not from the element). q is the nearest point of
        the whole boundary, however far the point lies. The spheres about the elements' centres
        that hold them (:mod:`wcut.kernels.point_location`) give the elements each point may lie
        in, and the boundary faces that may hold q.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        slots = self.live_tets()
        if not len(p):
            return p.copy()
        # every point against every element's bounding sphere, compiled (a blade's 16 points
        # among the organ's 4900 elements: 0.8 ms, against 3.3 for a k-d tree of the centres)
        tets = wp.array(self.tets[slots].astype(np.int32), dtype=wp.vec4i, device="cpu")
        x = wp.array(self.positions, dtype=wp.vec3d, device="cpu")
        query = wp.array(p, dtype=wp.vec3d, device="cpu")
        nearest_sq = wp.full(len(p), np.inf, dtype=wp.float64, device="cpu")
        capacity = HITS_PER_POINT * len(p)
        while True:
            counter = wp.zeros(1, dtype=wp.int32, device="cpu")
            hits = [wp.empty(capacity, dtype=t, device="cpu") for t in (wp.int32, wp.int32, wp.vec4d)]
            wp.launch(point_location.locate_points, len(slots), device="cpu",
                      inputs=[tets, x, query], outputs=[nearest_sq, counter, *hits])
            count = int(counter.numpy()[0])
            if count <= capacity:
                break
            capacity = count
        hit_point, hit_element, weights = (h.numpy()[:count] for h in hits)
        first = _least_per_point(hit_point, -weights.min(axis=1), hit_element)  # the element holding it most deeply
        out = np.empty_like(p)
        inside = np.zeros(len(p), dtype=bool)
        inside[hit_point[first]] = True
        rest = self.rest_positions
        out[hit_point[first]] = np.einsum("pk,pkj->pj", weights[first], rest[self.tets[slots[hit_element[first]]]])
        if not inside.all():
            # the nearest boundary point q of an outside point is no farther than the nearest
            # centre (a point of the mesh), and q lies in the sphere of its element
            reach = np.sqrt(nearest_sq.numpy()[~inside])
            near = wp.empty(len(slots), dtype=wp.int32, device="cpu")
            wp.launch(point_location.elements_near, len(slots), device="cpu",
                      inputs=[tets, x, wp.array(p[~inside], dtype=wp.vec3d, device="cpu"),
                              wp.array(reach, dtype=wp.float64, device="cpu")], outputs=[near])
            out[~inside] = self._rest_points_outside(p[~inside], slots[near.numpy().astype(bool)])
        return out

    def _rest_points_outside(self, p: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """:meth:`rest_points` of points outside the mesh, by the boundary faces of ``slots``."""
        faces, owners = self._boundary_faces_of(slots)
        x, rest = self.positions, self.rest_positions
        corners = x[faces]  # (F, 3, 3)
        centre = corners.mean(axis=1)
        radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1)
        # a face's centre bounds the distance to the nearest face from above, its radius bounds
        # the distance to each face from below: only the faces that may be nearest are measured
        reach = np.linalg.norm(p[:, None] - centre[None], axis=2)  # (P, F)
        points, candidates = np.nonzero(reach - radius[None] <= reach.min(axis=1, keepdims=True))
        bary, gap = _closest_on_triangles(p[points], *(corners[candidates, k] for k in range(3)))
        first = _least_per_point(points, gap, candidates)
        weights, nearest = bary[first], candidates[first]
        face = faces[nearest]
        tets = self.tets[np.asarray(owners)[nearest]]
        current = np.transpose(x[tets[:, 1:]] - x[tets[:, :1]], (0, 2, 1))
        initial = np.transpose(rest[tets[:, 1:]] - rest[tets[:, :1]], (0, 2, 1))
        inverse_gradient = initial @ np.linalg.inv(current)  # F^-1 of the element owning the face
        q = np.einsum("pk,pkj->pj", weights, x[face])
        return np.einsum("pk,pkj->pj", weights, rest[face]) + np.einsum("pij,pj->pi", inverse_gradient, p - q)

    def _boundary_faces_of(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The boundary faces (F, 3) among the faces of elements ``slots``, and their elements.
        A face two of ``slots`` share is inside; only the others are looked up in the vertex
        stars (:meth:`face_owner_count`), the mesh's boundary and the region's rim."""
        tris = self.tets[slots][:, TET_FACES].reshape(-1, 3)  # (4M, 3), outward as TET_FACES
        owners = np.repeat(slots, 4)
        keys = np.sort(tris, axis=1)
        base = int(keys.max(initial=0)) + 1
        _, inverse, counts = unique_rows(keys, base, return_inverse=True, return_counts=True)
        alone = np.flatnonzero(counts[inverse.ravel()] == 1)
        boundary = [i for i in alone.tolist() if self.face_owner_count(*keys[i].tolist()) == 1]
        return tris[boundary].reshape(-1, 3), owners[boundary]

    def to_mesh(self, name: str | None = None) -> TetMesh:
        """The live elements as a :class:`TetMesh` (elements in slot order, vertices as
        numbered here), without re-validating: the operators keep the mesh valid."""
        # Without freed slots the live elements are the prefix: one copy, no gather.
        tets = self.tets[: self.slot_count].copy() if not self._free else self.tets[self.live_tets()]
        return TetMesh.trusted(self.rest_positions.copy(), tets, name=name or self.name)

    # ------------------------------------------------------- low-level editing
    def _link(self, t: int, tet: list[int]) -> None:
        """Enter element t, with vertices ``tet``, in the adjacency (t last in the element
        list of each of its faces) and remember its face keys."""
        vertex_tets = self.vertex_tets
        for v in tet:
            vertex_tets[v].add(t)
        _enter_faces(self._face_tets, self._slot_face_keys, t, tet)

    def _unlink(self, t: int) -> None:
        """Remove element t from the adjacency (its vertices read from its face keys); a face
        left with fewer than two elements is no longer unsewn."""
        vertex_tets = self.vertex_tets
        keys = self._slot_face_keys[t]
        first = keys[0]  # the three largest vertices; the smallest opens the second key
        vertex_tets[keys[1][0]].discard(t)
        vertex_tets[first[0]].discard(t)
        vertex_tets[first[1]].discard(t)
        vertex_tets[first[2]].discard(t)
        _leave_faces(self._face_tets, keys, t, self.unsewn)

    def _new_slot(self) -> int:
        if self._free:
            return self._free.pop()
        if self.slot_count == len(self.tets):
            self.tets = np.concatenate([self.tets, np.zeros_like(self.tets)])
            self.alive = np.concatenate([self.alive, np.zeros_like(self.alive)])
            self._slot_face_keys.extend([None] * (len(self.tets) - len(self._slot_face_keys)))
            self._slot_quality.extend([None] * (len(self.tets) - len(self._slot_quality)))
        self.slot_count += 1
        return self.slot_count - 1

    def replace_tets(self, removed: list[int], added: list[list[int]], parents: list[int] | None = None,
                     qualities: list[float] | None = None, *, link_faces: bool = True) -> list[int]:
        """Replace elements ``removed`` by ``added`` (vertex lists, positively oriented).

        The primitive every operator ends with; it checks nothing, the operators check first.
        New element i lies in removed element ``parents[i]`` (default ``removed[0]``), whose
        origin in the journal it inherits. ``qualities``, when given, are the new elements'
        :func:`tet_quality` (the operator computed them to check them), remembered for
        :meth:`quality`.

        ``link_faces=False`` (a write-back of the compiled operators, or a flip of the mesh
        improvement: their own queries use the vertex stars) leaves the face adjacency
        (``face_tets``, ``slot_face_keys``) to be brought up to date when it is next read,
        exactly as linking now would have left it; the vertex stars are up to date at once.
        Only while no face is unsewn (linking can then not change ``unsewn``).
        """
        self._boundary_at.clear()  # (the stars change)
        journal = self._journal
        parents = parents or [removed[0]] * len(added)
        quality_of, alive, vertex_tets, tets = self._slot_quality, self.alive, self.vertex_tets, self.tets
        later = not link_faces and not self.unsewn
        if not later and (self._unlinked_faces or self._faces_stale):
            self._link_faces()
        if journal:
            origin = journal.origin
            origins = [origin.get(t, t) for t in parents]
            removed_base = journal.removed_base
        for t in removed:
            if later:
                for v in tets[t].tolist():
                    vertex_tets[v].discard(t)
            else:
                self._unlink(t)
            alive[t] = False
            quality_of[t] = None
            if journal:
                if t in origin:
                    del origin[t]
                else:
                    removed_base.add(t)
                    journal.removed_vertices.update(tets[t].tolist())
        free = self._free
        free.extend(reversed(removed))
        if later:  # many elements (a write-back): their rows in one assignment
            slots = [free.pop() if free else self._new_slot() for _ in added]  # may grow tets and alive
            if slots:
                self.tets[slots] = added
                self.alive[slots] = True
            for t, tet in zip(slots, added):
                for v in tet:
                    vertex_tets[v].add(t)
            if qualities is not None:
                for t, q in zip(slots, qualities):
                    quality_of[t] = q
            if journal:
                origin.update(zip(slots, origins))
            if not self._faces_stale:
                self._unlinked_faces.append((list(removed), list(zip(slots, added))))
                self._unlinked_count += len(added)
                if self._unlinked_count > self.unlinked_log_limit():
                    self._unlinked_faces, self._unlinked_count, self._faces_stale = [], 0, True
                    self._face_tets = {}
            return slots
        slots = []
        for i, tet in enumerate(added):
            if free:
                t = free.pop()
            else:
                t = self._new_slot()  # may grow (reallocate) tets and alive
                alive, tets = self.alive, self.tets
            tets[t] = tet
            alive[t] = True
            self._link(t, tet)
            if qualities is not None:
                quality_of[t] = qualities[i]
            if journal:
                origin[t] = origins[i]
            slots.append(t)
        return slots

    def _link_faces(self) -> None:
        """Bring the face adjacency up to date with the replacements made with
        ``link_faces=False``, in order: what :meth:`_unlink` and :meth:`_link` would have done
        to the faces then (the vertex stars were done at once). After so many that their log
        was dropped, link the faces of the live elements anew, in slot order."""
        if self._faces_stale:
            self._face_tets, self._slot_face_keys = {}, [None] * len(self.tets)
            self._unlinked_faces, self._unlinked_count, self._faces_stale = [], 0, False
            live = self.live_tets()
            batches = [([], list(zip(live.tolist(), self.tets[live].tolist())))]
        else:
            batches, self._unlinked_faces, self._unlinked_count = self._unlinked_faces, [], 0
        face_tets, slot_face_keys = self._face_tets, self._slot_face_keys
        for removed, added in batches:
            for t in removed:
                _leave_faces(face_tets, slot_face_keys[t], t, self.unsewn)
            for t, tet in added:
                _enter_faces(face_tets, slot_face_keys, t, tet)

    def interpolate(self, parents: list[int], weights) -> np.ndarray:
        """The barycentric combination of the attributes (a ``vertex_data`` row: rest
        position, position, velocity) of ``parents`` with ``weights``, summed in order (as
        the compiled operators sum it, where a matrix product may pair the terms otherwise)."""
        rows = self.vertex_data.take(parents, axis=0)  # take: a fast gather
        weights = np.asarray(weights, dtype=np.float64).tolist()
        data = weights[0] * rows[0]
        for w, row in zip(weights[1:], rows[1:]):
            data += w * row
        return data

    def add_vertex(self, parents: list[int], weights, origin_tet: int = -1, data: np.ndarray | None = None) -> int:
        """A new vertex at the barycentric combination of ``parents`` with ``weights`` (all
        attributes: rest position, position, velocity). ``data``, when given, must be
        ``interpolate(parents, weights)`` (an operator that checked the new vertex's position
        passes what it computed). Returns its index."""
        weights = np.asarray(weights, dtype=np.float64)
        if self.vertex_count == len(self.vertex_data):
            self.vertex_data = np.concatenate([self.vertex_data, np.zeros_like(self.vertex_data)])
        v = self.vertex_count
        self.vertex_data[v] = self.interpolate(parents, weights) if data is None else data
        self.vertex_count += 1
        self.vertex_tets.append(set())
        rest, rest32 = self._rest_tuples_of(v)
        self.rest_tuples.append(rest)
        self.rest_tuples32.append(rest32)
        self._bound_rest(rest)
        if self._journal:
            self._journal.vertex_from(v, parents, weights, origin_tet)
        return v

    def add_vertices(self, parents: np.ndarray, weights: np.ndarray, data: np.ndarray, origin_tets) -> int:
        """:meth:`add_vertex` for several vertices at once, with their ``data`` (K, 9) given
        (each row ``interpolate(parents[i], weights[i])``): ``parents`` (K, P) vertices, -1
        where a row has fewer, a parent possibly an earlier vertex of the batch, ``weights``
        (K, P). Returns the index of the first."""
        count = len(data)
        first = self.vertex_count
        while first + count > len(self.vertex_data):
            self.vertex_data = np.concatenate([self.vertex_data, np.zeros_like(self.vertex_data)])
        self.vertex_data[first: first + count] = data
        self.vertex_count += count
        self.vertex_tets.extend([set() for _ in range(count)])
        rest, rest32 = point_tuples(data[:, REST])
        self.rest_tuples.extend(rest)
        self.rest_tuples32.extend(rest32)
        if count:
            self._bound_rest((float(np.abs(data[:, REST]).max()), 0.0, 0.0))
        if self._journal:
            self._journal.vertices_from(first, np.asarray(parents).tolist(),
                                        np.asarray(weights, dtype=np.float64).tolist(), list(origin_tets))
        return first

    def set_vertex(self, v: int, parents: list[int], weights) -> None:
        """Move vertex v (all attributes) to the barycentric combination of ``parents``."""
        weights = np.asarray(weights, dtype=np.float64)
        if self._journal:
            self._journal.vertex_from(v, parents, weights, -1)
        self.vertex_data[v] = self.interpolate(parents, weights)
        self.rest_tuples[v], self.rest_tuples32[v] = self._rest_tuples_of(v)
        self._bound_rest(self.rest_tuples[v])
        quality_of = self._slot_quality
        for t in self.vertex_tets[v]:  # its elements changed shape
            quality_of[t] = None

    def sync_rest_tuples(self) -> None:
        """Rebuild ``rest_tuples`` and ``rest_tuples32`` from ``vertex_data`` (O(N)): for code
        that wrote rest positions into ``vertex_data`` itself."""
        rest = self.vertex_data[: self.vertex_count, REST]
        self.rest_tuples, self.rest_tuples32 = point_tuples(rest)
        bound = float(np.abs(rest).max()) if len(rest) else 0.0
        #: an upper bound of the rest coordinates' magnitudes (m), inf if one is not finite:
        #: it bounds how far rounding to float32 moves a vertex (the operators' checks)
        self.rest_bound = bound if math.isfinite(bound) else math.inf
        if hasattr(self, "_slot_quality"):
            self._slot_quality = [None] * len(self._slot_quality)

    def _bound_rest(self, p) -> None:
        """Keep ``rest_bound`` above the coordinates of rest position p."""
        x, y, z = p
        b = max(abs(x), abs(y), abs(z))
        if not b <= self.rest_bound:  # larger, or NaN
            self.rest_bound = b if b == b and b != math.inf else math.inf

    def _rest_tuples_of(self, v: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Vertex v's rest position as a float tuple, and rounded to float32."""
        rest = tuple(self.vertex_data[v, REST].tolist())
        return rest, rounded32(rest)

    def retarget(self, t: int, old: int, new: int) -> None:
        """Replace vertex ``old`` by ``new`` in element t (same geometry: a duplicate).

        Unlinking and linking again leaves the adjacency as it would be had t been removed and
        added (t last in the element list of each of its faces), which later operators'
        choices depend on. Its unsewn faces without ``old`` stay unsewn (unlinking alone
        would sew them again, joining the fans of their vertices across a cut)."""
        self._boundary_at.clear()  # (the stars change)
        # The changes of unlinking then linking t, in the same order per set and list (set
        # iteration order, and so later choices, depend on it): t leaves and joins again the
        # sets of its vertices; t moves to the end of its faces without ``old``; its faces
        # with ``old`` go (no longer unsewn), those with ``new`` come.
        tet = self.tets[t].tolist()
        vertex_tets, face_tets, unsewn = self.vertex_tets, self.face_tets, self.unsewn  # faces linked first
        for v in tet:
            vertex_tets[v].discard(t)
        i = tet.index(old)
        tet[i] = new
        self.tets[t, i] = new
        if self._journal:
            self._journal.rewired.add(t)
        for v in tet:
            vertex_tets[v].add(t)
        for key in self._slot_face_keys[t]:
            owners = face_tets[key]
            if old in key:
                owners.remove(t)
                if not owners:
                    del face_tets[key]
                unsewn.discard(key)
            elif len(owners) == 2 and owners[0] == t:
                owners[0], owners[1] = owners[1], t
        _enter_faces(face_tets, self._slot_face_keys, t, tet, containing=new)
        if self.rest_tuples[old] != self.rest_tuples[new]:
            self._slot_quality[t] = None

    def drop_unused_vertices(self) -> int:
        """Remove vertices no element uses (after elements were deleted) and renumber the
        rest, keeping their order. O(mesh size): for deletions, not for the cutter's
        remeshing, which never orphans a vertex. Returns how many were dropped."""
        self._boundary_at.clear()  # (the stars change)
        keep = np.array([bool(s) for s in self.vertex_tets[: self.vertex_count]])
        dropped = int((~keep).sum())
        if not dropped:
            return 0
        if self._journal and self._journal.expression:
            raise TopologyError("cannot drop vertices after creating or moving some in the same change")
        if self._unlinked_faces or self._faces_stale:  # linked with the old numbering first
            self._link_faces()
        remap = np.cumsum(keep) - 1
        kept = np.flatnonzero(keep)
        live = self.live_tets()
        self.tets[live] = remap[self.tets[live]]
        self.vertex_data[: len(kept)] = self.vertex_data[kept]
        self.vertex_count = len(kept)
        order = kept.tolist()
        self.vertex_tets = [self.vertex_tets[v] for v in order]
        self.rest_tuples = [self.rest_tuples[v] for v in order]
        self.rest_tuples32 = [self.rest_tuples32[v] for v in order]
        self._face_tets = {face_key(*remap[list(k)].tolist()): owners for k, owners in self.face_tets.items()}
        for t, tet in zip(live.tolist(), self.tets[live].tolist()):
            self._slot_face_keys[t] = _face_keys(tet)
        self.unsewn = {face_key(*remap[list(k)].tolist()) for k in self.unsewn}
        if self._journal:
            self._journal.vertex_renumber = kept if self._journal.vertex_renumber is None \
                else self._journal.vertex_renumber[kept]
        return dropped

    def drop_orphans(self) -> tuple[set[int], dict[int, int]]:
        """Remove the vertices made since :meth:`begin_change` that no element uses any more
        (those an edge contraction merged into a neighbour), each replaced by the last vertex:
        every other vertex keeps its number but those moved. O(vertices dropped and the stars
        of those moved); the face adjacency is linked anew when next read, unless a face is
        unsewn (then it is renumbered at once). Returns the numbers dropped and, for each
        vertex moved, {number before: number now}."""
        journal = self._journal
        if journal is None or journal.vertex_renumber is not None:
            raise TopologyError("drop_orphans() needs a change begun with begin_change(), no vertex dropped by "
                                "drop_unused_vertices()")
        dropped = {v for v in range(journal.base_vertex_count, self.vertex_count) if not self.vertex_tets[v]}
        if not dropped:
            return dropped, {}
        if self.unsewn:
            self.face_tets  # linked, to be renumbered
        else:  # linked anew from the live elements when next read
            self._face_tets, self._unlinked_faces, self._unlinked_count, self._faces_stale = {}, [], 0, True
        expression, vertex_origin = journal.expression, journal.vertex_origin
        number_of: dict[int, int] = {}  # number now -> number at the start of this call
        moved: dict[int, int] = {}
        for u in sorted(dropped, reverse=True):
            last = self.vertex_count - 1
            expression.pop(u, None)
            vertex_origin.pop(u, None)
            if u != last:
                self._renumber(last, u)
                if last in expression:
                    expression[u] = expression.pop(last)
                if last in vertex_origin:
                    vertex_origin[u] = vertex_origin.pop(last)
                original = number_of.pop(last, last)
                number_of[u], moved[original] = original, u
            self.vertex_count -= 1
            self.vertex_tets.pop()
            self.rest_tuples.pop()
            self.rest_tuples32.pop()
        return dropped, moved

    def _renumber(self, old: int, new: int) -> None:
        """Give vertex ``old`` (data, star, elements, faces) the number ``new``, whose vertex
        has no element (:meth:`drop_orphans`)."""
        self._boundary_at.clear()  # (the stars change)
        self.vertex_data[new] = self.vertex_data[old]
        self.rest_tuples[new], self.rest_tuples32[new] = self.rest_tuples[old], self.rest_tuples32[old]
        star = self.vertex_tets[new] = self.vertex_tets[old]
        self.vertex_tets[old] = set()
        rows = sorted(star)
        tets = self.tets[rows]
        tets[tets == old] = new
        self.tets[rows] = tets
        if self._journal:
            self._journal.rewired.update(rows)
        if self._faces_stale:
            return
        renamed = lambda key: face_key(*[new if v == old else v for v in key])  # noqa: E731
        for t in rows:  # (linked: no replacement is waiting to be linked)
            for key in self._slot_face_keys[t]:
                if old in key and key in self._face_tets:
                    self._face_tets[renamed(key)] = self._face_tets.pop(key)
                    if key in self.unsewn:
                        self.unsewn.discard(key)
                        self.unsewn.add(renamed(key))
            self._slot_face_keys[t] = _face_keys(self.tets[t].tolist())

    # ------------------------------------------------------------- journal
    def begin_change(self) -> None:
        """Start recording a topological event (see :meth:`end_change`)."""
        self._journal = _Journal(self)

    @property
    def first_new_vertex(self) -> int:
        """The number of the first vertex made since :meth:`begin_change` (the vertex count
        when no change is recorded): from it on, a vertex that loses its elements may be
        dropped (:meth:`drop_orphans`)."""
        return self.vertex_count if self._journal is None else self._journal.base_vertex_count

    def changed_tets(self) -> list[int]:
        """Live element slots made, reshaped or rewired since :meth:`begin_change` (ascending):
        where work local to the change (mesh improvement) looks."""
        journal = self._journal
        if journal is None:
            raise TopologyError("changed_tets() without begin_change()")
        alive = self.alive
        return sorted(t for t in set(journal.origin) | journal.reshaped | journal.rewired if alive[t])

    def end_change(self):
        """Stop recording and return the :class:`~wcut.topology.change.TopologyChange` from
        the mesh at :meth:`begin_change` to the mesh now."""
        from .change import TopologyChange

        journal, self._journal = self._journal, None
        if journal is None:
            raise TopologyError("end_change() without begin_change()")
        return TopologyChange.from_journal(journal, self)


class _NumberedRows:
    """(slot, vertex list) of each row of ``tets``, made when iterated (a class, not a
    generator: a topology can be copied)."""

    def __init__(self, tets: np.ndarray):
        self.tets = tets

    def __iter__(self):
        return enumerate(self.tets.tolist())


def _per_vertex(values, count: int, what: str, mesh) -> np.ndarray:
    """``values`` as finite (count, 3) float64, or a TopologyError that says whose they may be."""
    values = np.asarray(values, dtype=float)
    if values.shape != (count, 3):
        raise TopologyError(f"TetTopology of {mesh.name}: {what} must have shape ({count}, 3), one row per vertex, "
                            f"got {values.shape} (a state of another mesh, e.g. of the model after a cut?)")
    if not np.isfinite(values).all():
        raise TopologyError(f"TetTopology of {mesh.name}: {what} are not all finite")
    return values


def _enter_faces(face_tets: dict, slot_face_keys: list, t: int, tet: list[int], containing: int = -1) -> None:
    """Enter element t, with vertices ``tet``, last in the element list of each of its faces
    (only those with vertex ``containing`` when given: the others hold it already), and
    remember its face keys."""
    keys = slot_face_keys[t] = _face_keys(tet)
    for key in keys:
        if containing >= 0 and containing not in key:
            continue
        owners = face_tets.get(key)
        if owners is None:
            face_tets[key] = [t]
        else:
            owners.append(t)


def _leave_faces(face_tets: dict, keys, t: int, unsewn: set) -> None:
    """Take element t out of the element lists of its faces ``keys``; a face left with fewer
    than two elements is no longer unsewn."""
    for key in keys:
        owners = face_tets[key]
        owners.remove(t)
        if len(owners) < 2:
            if not owners:
                del face_tets[key]
            if unsewn:  # most of the time nothing is unsewn: skip the hash of the key
                unsewn.discard(key)


def _face_keys(tet: list[int]) -> tuple[tuple[int, int, int], ...]:
    """The keys of the four faces of an element: the triples of its sorted vertices."""
    s0, s1, s2, s3 = sorted(tet)
    return (s1, s2, s3), (s0, s2, s3), (s0, s1, s3), (s0, s1, s2)


class _Journal:
    """What happened since :meth:`TetTopology.begin_change`: enough to express every vertex
    and element of the new mesh in terms of the old one."""

    def __init__(self, topo: TetTopology):
        self.base_slots = topo.live_tets()
        self.base_vertex_count = topo.vertex_count
        self.removed_base: set[int] = set()  # base slots no longer in the mesh
        self.removed_vertices: set[int] = set()  # the vertices of those, when removed
        self.origin: dict[int, int] = {}   # new slot -> base slot it lies in
        self.reshaped: set[int] = set()     # base slots whose rest shape may have changed
        self.rewired: set[int] = set()      # slots given another vertex in place (retarget)
        self.expression: dict[int, dict[int, float]] = {}  # vertex -> {base vertex: weight}
        self.vertex_origin: dict[int, int] = {}
        self.vertex_renumber: np.ndarray | None = None  # vertex -> base vertex after dropping
        self.topo = topo

    def origin_of(self, t: int) -> int:
        return self.origin.get(t, t)

    def removed(self, t: int) -> None:
        if t in self.origin:
            del self.origin[t]
        else:
            self.removed_base.add(t)
            self.removed_vertices.update(self.topo.tets[t].tolist())

    def added(self, t: int, origin: int) -> None:
        self.origin[t] = origin

    def vertex_from(self, v: int, parents, weights, origin_tet: int) -> None:
        self.expression[v] = _combined(self.expression, parents, weights.tolist())
        if origin_tet >= 0:
            self.vertex_origin[v] = self.origin.get(origin_tet, origin_tet)
        around = self.topo.vertex_tets[v]
        if around:  # a moved vertex reshapes its elements (a new one has none yet)
            self.reshaped.update(around)

    def vertices_from(self, first: int, parents: list, weights: list, origin_tets: list) -> None:
        """:meth:`vertex_from` of new vertices ``first``, ``first + 1``, ... (without elements
        yet): one row of ``parents`` and ``weights`` each (lists; a parent -1 is none)."""
        expression, origin, vertex_origin = self.expression, self.origin, self.vertex_origin
        for v, (row, row_weights, origin_tet) in enumerate(zip(parents, weights, origin_tets), start=first):
            if row_weights[0] == 1.0 and (len(row) == 1 or row[1] < 0):  # a copy: its original's expression
                of_p = expression.get(row[0])
                expr = {row[0]: 1.0} if of_p is None else dict(of_p)
            else:
                expr = _combined(expression, row, row_weights)
            expression[v] = expr
            if origin_tet >= 0:
                vertex_origin[v] = origin.get(origin_tet, origin_tet)


def _combined(expression: dict[int, dict[int, float]], parents, weights) -> dict[int, float]:
    """The expression {base vertex: weight} of ``sum weights[i] * parents[i]``, each parent
    by its own expression in ``expression`` (a vertex of the base mesh: itself with weight
    1, and w * 1.0 is w); parents -1 and zero weights are skipped."""
    expr: dict[int, float] = {}
    for p, w in zip(parents, weights):
        if p < 0 or w == 0.0:
            continue
        of_p = expression.get(p)
        if of_p is None:
            expr[p] = expr.get(p, 0.0) + w
        else:
            for q, wq in of_p.items():
                expr[q] = expr.get(q, 0.0) + w * wq
    return expr


def _closest_on_triangles(p, a, b, c) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of triangles (a, b, c) to points p (arrays (..., 3), m): their barycentric
    coordinates (..., 3) and the distances (...,). Inside the triangle the plane projection,
    else the nearest point of its three edges."""
    ab, ac, ap = b - a, c - a, p - a
    d00, d01, d11 = (np.einsum("...i,...i->...", u, v) for u, v in ((ab, ab), (ab, ac), (ac, ac)))
    d20, d21 = np.einsum("...i,...i->...", ap, ab), np.einsum("...i,...i->...", ap, ac)
    det = d00 * d11 - d01 * d01
    with np.errstate(divide="ignore", invalid="ignore"):  # a sliver triangle: its edges decide
        v = (d11 * d20 - d01 * d21) / det
        w = (d00 * d21 - d01 * d20) / det
    bary = np.stack([1.0 - v - w, v, w], axis=-1)
    inside = (bary >= 0.0).all(axis=-1)
    corners = np.stack((a, b, c))
    best, best_gap = bary, np.full(inside.shape, np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):  # outside: the nearest point of the three edges
        e = corners[j] - corners[i]
        s = np.clip(np.einsum("...i,...i->...", p - corners[i], e) / np.einsum("...i,...i->...", e, e), 0.0, 1.0)
        candidate = np.zeros_like(bary)
        candidate[..., i], candidate[..., j] = 1.0 - s, s
        gap = np.linalg.norm(p - np.einsum("...k,k...j->...j", candidate, corners), axis=-1)
        better = ~inside & (gap < best_gap)
        best = np.where(better[..., None], candidate, best)
        best_gap = np.where(better, gap, best_gap)
    bary = best
    return bary, np.linalg.norm(p - np.einsum("...k,k...j->...j", bary, corners), axis=-1)


def ball_pairs(neighbours) -> tuple[np.ndarray, np.ndarray]:
    """The (query, item) index pairs of a k-d tree's ``query_ball_point`` lists, flat: the
    queries in order, each with its items as listed."""
    counts = np.fromiter(map(len, neighbours), np.int64, len(neighbours))
    items = np.fromiter(itertools.chain.from_iterable(neighbours), np.int64, int(counts.sum()))
    return np.repeat(np.arange(len(neighbours)), counts), items


def _least_per_point(point_index: np.ndarray, cost: np.ndarray, tiebreak: np.ndarray) -> np.ndarray:
    """Of pairs (``point_index[k]``, an item), per point the pair of least ``cost`` (of equal
    costs, that of least ``tiebreak``), in ascending order of points."""
    order = np.lexsort((tiebreak, cost, point_index))
    if not len(order):
        return order
    return order[np.r_[True, point_index[order][1:] != point_index[order][:-1]]]
