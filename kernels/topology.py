"""Compiled topology operators on flat arrays (thesis 5.1): the core of the cutter's remeshing.

A Python operator call costs some 70 us on this project's machine (adjacency in dicts and
sets, its checks in Python floats), and a plane crossing 100 elements takes about 700 of
them: 50-75 ms per cut event against the 20 ms of issue 3. Here the same operators are Warp
functions on flat arrays, run in order by one thread of one launch (a topological change is
sequential: each operator reads what the previous one wrote), so a batch costs one launch.

Layout (:class:`TetMeshArrays`; ``wcut.topology.arrays.TetArrays`` owns the arrays):

- ``tet_indices[t]`` (vec4i): the corners of element slot t, positively oriented;
- ``tet_neighbors[t]`` (vec4i): the element across the face opposite corner k, -1 on the
  boundary (the face-neighbour arrays of Shewchuk's and CGoGN's tetrahedral maps);
- ``tet_alive[t]``: 1 for a live slot; ``tet_parent[t]``: the element of the mesh before the
  change that contains it (the change record's parent, as ``TetTopology``'s journal);
- ``vertex_tet[v]``: a live element with corner v (-1 for an unused vertex), where the
  search for an edge or a face given by its vertices starts (:func:`find_tet`);
- ``vertex_rest`` / ``vertex_q`` / ``vertex_qd`` (vec3d): rest position, position (m) and
  velocity (m/s) in float64, as ``TetTopology.vertex_data``; a new vertex gets the
  barycentric combination of its parents for all three (exact for linear elements, thesis
  3.2), and ``vertex_parents`` / ``vertex_weights`` record it (parents padded with -1);
- ``vertex_origin[v]``: the parent of the element new vertex v was made in;
- ``counts``: [vertex count, element slot count];
- scratch rows for the one thread: the elements an operator removes and adds, the outer faces,
  the elements of a vertex's star, an edge's polygon and the triangulation tables.

The disconnection (thesis 5.1.3, :func:`disconnect`) is a kernel of its own: unsewn faces
are flags of a scratch array that only it reads, and it ends with faces either sewn again or
boundary, so the operators never see an unsewn face.

Every operator checks before it writes, and refuses (returns a ``REFUSED_*`` code, arrays
untouched) unless every new element is well shaped in the rest configuration, in float64
and rounded to float32 (what the simulation sees): ``volume / longest edge^3 >
tolerance``, the rule of ``wcut.topology.operators._check``. It then ends with
:func:`replace`, which writes the new elements and their neighbours (the primitive
``TetTopology.replace_tets`` is for the Python operators).

The module is compiled without adjoints (``enable_backward`` off): its integer bookkeeping
has no gradient, and the adjoints of these long sequential kernels multiplied the compile
time: 15.4 to 7.8 s on the CPU, 419 to 26-29 s for CUDA (PTX for sm_90 by NVRTC,
``tools/cuda_compile.py``).
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

#: status codes of an operator
DONE = wp.constant(0)
REFUSED_SHAPE = wp.constant(1)  # a new element would be inverted or flat
REFUSED_FULL = wp.constant(2)  # no room left in the arrays (the host grows them and runs again)
REFUSED_INPUT = wp.constant(3)  # a dead element, a boundary face, bad weights or parameter
REFUSED_CROSSING = wp.constant(4)  # flip 2-3: the new edge does not cross the face
REFUSED_QUALITY_DROP = wp.constant(5)  # flip 2-3: its worst element is poorer than allowed
REFUSED_VOLUME = wp.constant(6)  # general flip of a boundary edge whose faces are not coplanar
REFUSED_MISSING = wp.constant(7)  # no such face or edge (or its ring is too large or leaves the arrays)
NEEDS_POINT = wp.constant(8)  # flip_or_split_face: the split point is needed (the batch stops there)
NOT_RUN = wp.constant(9)  # after a stop of the batch
NO_POINT = wp.constant(10)  # flip_or_split_face: flip refused and the face has no split point

#: Qualities within this relative difference tie in a general flip's choice of triangulation
#: (the larger apex wins, as in ``operators.remove_edge``), and so do rest coordinates in
#: :func:`rest_before`: positions computed here and by the Python operators can differ in their
#: last bit, and a choice between two equally good triangulations must not turn on it
#: (``topology.mesh.NEAR_TIE``).
NEAR_TIE = wp.constant(wp.float64(1.0e-12))

#: operator kinds of a batch (:func:`run_operators`) and what their ``ints`` / ``reals`` hold
SPLIT_TET = wp.constant(0)  # element, -, -, - / barycentric weights (4)
FLIP_FACE = wp.constant(1)  # element, corner opposite the face / -
SPLIT_FACE = wp.constant(2)  # face vertices a, b, c / weights over them (3)
REMOVE_EDGE = wp.constant(3)  # edge vertices a, b / -
BISECT_EDGE = wp.constant(4)  # edge vertices a, b / parameter s of (1 - s) a + s b
FLIP_OR_SPLIT_FACE = wp.constant(5)  # face vertices a, b, c, point flag (POINT_*) / weights (3)
REMOVE_OR_BISECT_EDGE = wp.constant(6)  # edge vertices a, b, 1: never flip a boundary edge / s

#: FLIP_OR_SPLIT_FACE: the split point is not known yet, is known, is none (the face stays)
POINT_PENDING = wp.constant(0)
POINT_KNOWN = wp.constant(1)
POINT_NONE = wp.constant(2)

#: neighbour across a face to an element outside the arrays (``wcut.topology.region``): not
#: boundary, and not to be changed
OUTSIDE = wp.constant(-2)

#: most elements around an edge that the general flip and the bisection take on
MAX_RING = 32
#: most elements one operator adds (a bisection of the largest ring)
MAX_ADDED = 2 * MAX_RING
#: most elements searched around a vertex for an edge or a face (:func:`find_tet`)
MAX_STAR = 512
#: row length of the triangulation tables (polygon vertices: one more than a ring's elements)
POLYGON = MAX_RING + 1

#: a centroid whose smallest barycentric coordinate in a removed element exceeds this lies
#: in it (``wcut.topology.operators._INSIDE``)
INSIDE = wp.constant(wp.float64(1e-3))


@wp.struct
class TetMeshArrays:
    """The arrays of a ``TetArrays`` and the scratch rows of the thread that edits them."""

    tet_indices: wp.array(dtype=wp.vec4i)
    tet_neighbors: wp.array(dtype=wp.vec4i)
    tet_alive: wp.array(dtype=wp.int32)
    tet_parent: wp.array(dtype=wp.int32)
    vertex_tet: wp.array(dtype=wp.int32)
    vertex_rest: wp.array(dtype=wp.vec3d)
    vertex_q: wp.array(dtype=wp.vec3d)
    vertex_qd: wp.array(dtype=wp.vec3d)
    vertex_parents: wp.array(dtype=wp.vec4i)
    vertex_weights: wp.array(dtype=wp.vec4d)
    vertex_origin: wp.array(dtype=wp.int32)
    counts: wp.array(dtype=wp.int32)
    removed: wp.array(dtype=wp.int32)  # MAX_RING: the elements an operator replaces (a ring in order)
    added: wp.array(dtype=wp.vec4i)  # MAX_ADDED: the new elements
    added_parent: wp.array(dtype=wp.int32)  # MAX_ADDED: their parents in the mesh before the change
    outer_face: wp.array(dtype=wp.vec3i)  # 4 MAX_RING: faces of the removed elements to others
    outer_tet: wp.array(dtype=wp.int32)  # 4 MAX_RING: the element across each
    star: wp.array(dtype=wp.int32)  # MAX_STAR: elements searched, or any list of ints
    polygon: wp.array(dtype=wp.int32)  # POLYGON: the vertices around an edge
    best: wp.array(dtype=wp.float64)  # POLYGON^2: worst quality of the best triangulation of i..j
    apex: wp.array(dtype=wp.int32)  # POLYGON^2: its apex


# ------------------------------------------------------------------ geometry
@wp.func
def signed_volume(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, p3: wp.vec3d):
    """Signed volume (m^3) of p0 p1 p2 p3, as ``wcut.topology.mesh.signed_volume``."""
    a = p1 - p0
    b = p2 - p0
    c = p3 - p0
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0])) / wp.float64(6.0)


@wp.func
def tet_quality(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, p3: wp.vec3d):
    """Volume / longest edge^3 of tetrahedron p0 p1 p2 p3 (float64, signed), the measure of
    ``wcut.topology.mesh.tet_quality``; NaN for four coincident corners."""
    volume = signed_volume(p0, p1, p2, p3)
    a = p1 - p0
    b = p2 - p0
    c = p3 - p0
    d = p2 - p1
    e = p3 - p1
    f = p3 - p2
    longest2 = wp.max(wp.max(wp.max(wp.dot(a, a), wp.dot(b, b)), wp.max(wp.dot(c, c), wp.dot(d, d))),
                      wp.max(wp.dot(e, e), wp.dot(f, f)))
    return volume / (longest2 * wp.sqrt(longest2))


@wp.func
def rounded32(p: wp.vec3d):
    """Point p rounded to float32 (to nearest) and back."""
    return wp.vec3d(wp.float64(wp.float32(p[0])), wp.float64(wp.float32(p[1])), wp.float64(wp.float32(p[2])))


@wp.func
def well_shaped(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, p3: wp.vec3d, tolerance: wp.float64):
    """Whether the element is well shaped in float64 and once rounded to float32 (NaN: no)."""
    q = tet_quality(p0, p1, p2, p3)
    q32 = tet_quality(rounded32(p0), rounded32(p1), rounded32(p2), rounded32(p3))
    return q > tolerance and q32 > tolerance


@wp.func
def corner_point(m: TetMeshArrays, tet: wp.vec4i, k: int, new: int, p: wp.vec3d):
    """Rest position of corner k of ``tet``, p for the vertex ``new`` (not yet stored)."""
    if tet[k] == new:
        return p
    return m.vertex_rest[tet[k]]


@wp.func
def tet_well_shaped(m: TetMeshArrays, tet: wp.vec4i, new: int, p: wp.vec3d, tolerance: wp.float64):
    """:func:`well_shaped` of element ``tet``, whose vertex ``new`` (if a corner) is at p."""
    return well_shaped(corner_point(m, tet, 0, new, p), corner_point(m, tet, 1, new, p),
                       corner_point(m, tet, 2, new, p), corner_point(m, tet, 3, new, p), tolerance)


@wp.func
def quality_of(m: TetMeshArrays, tet: wp.vec4i):
    """:func:`tet_quality` of element ``tet`` (rest configuration)."""
    return tet_quality(m.vertex_rest[tet[0]], m.vertex_rest[tet[1]], m.vertex_rest[tet[2]], m.vertex_rest[tet[3]])


@wp.func
def volume_of(m: TetMeshArrays, tet: wp.vec4i):
    """Signed rest volume (m^3) of element ``tet``."""
    return signed_volume(m.vertex_rest[tet[0]], m.vertex_rest[tet[1]], m.vertex_rest[tet[2]],
                         m.vertex_rest[tet[3]])


@wp.func
def smallest_barycentric(p: wp.vec3d, c0: wp.vec3d, c1: wp.vec3d, c2: wp.vec3d, c3: wp.vec3d):
    """The smallest barycentric coordinate of point p in tetrahedron c0 c1 c2 c3, by Cramer's
    rule in the operations of ``operators._barycentric_frame`` and ``_containing`` (so that
    a centroid on a face two elements share goes to the same one)."""
    a = c0 - c3
    b = c1 - c3
    c = c2 - c3
    bc = wp.vec3d(b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2], b[0] * c[1] - b[1] * c[0])
    ca = wp.vec3d(c[1] * a[2] - c[2] * a[1], c[2] * a[0] - c[0] * a[2], c[0] * a[1] - c[1] * a[0])
    ab = wp.vec3d(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    det = a[0] * bc[0] + a[1] * bc[1] + a[2] * bc[2]
    d = p - c3
    x0 = (bc[0] * d[0] + bc[1] * d[1] + bc[2] * d[2]) / det
    x1 = (ca[0] * d[0] + ca[1] * d[1] + ca[2] * d[2]) / det
    x2 = (ab[0] * d[0] + ab[1] * d[1] + ab[2] * d[2]) / det
    return wp.min(wp.min(x0, x1), wp.min(x2, wp.float64(1.0) - (x0 + x1 + x2)))


@wp.func
def containing(m: TetMeshArrays, tet: wp.vec4i, removed_count: int, hint: int):
    """The parent (``tet_parent``) of the removed element that contains the centroid of new
    element ``tet``: the first, from removed element ``hint`` on (cyclically), whose smallest
    barycentric coordinate of it exceeds :data:`INSIDE`, else the first of largest smallest
    coordinate (as ``operators._containing``; the answer does not depend on ``hint``)."""
    centre = (m.vertex_rest[tet[0]] + m.vertex_rest[tet[1]] + m.vertex_rest[tet[2]] + m.vertex_rest[tet[3]]) \
        * wp.float64(0.25)
    best = int(0)
    best_min = wp.float64(-1.0e300)
    for step in range(removed_count):
        i = (hint + step) % removed_count
        r = m.tet_indices[m.removed[i]]
        smallest = smallest_barycentric(centre, m.vertex_rest[r[0]], m.vertex_rest[r[1]], m.vertex_rest[r[2]],
                                        m.vertex_rest[r[3]])
        if smallest > INSIDE:
            return m.tet_parent[m.removed[i]]
        if smallest > best_min or (smallest == best_min and i < best):
            best = i
            best_min = smallest
    return m.tet_parent[m.removed[best]]


# ------------------------------------------------------------------ topology
@wp.func
def corner_of(tet: wp.vec4i, v: int):
    """Local index of vertex v in ``tet``, -1 if it is not a corner."""
    for k in range(4):
        if tet[k] == v:
            return k
    return -1


@wp.func
def substitute(tet: wp.vec4i, old: int, new: int):
    """``tet`` with corner ``old`` (if any) replaced by ``new``."""
    return wp.vec4i(wp.where(tet[0] == old, new, tet[0]), wp.where(tet[1] == old, new, tet[1]),
                    wp.where(tet[2] == old, new, tet[2]), wp.where(tet[3] == old, new, tet[3]))


@wp.func
def face_opposite(tet: wp.vec4i, k: int):
    """The face of ``tet`` opposite its corner k, its vertices sorted ascending."""
    a = tet[(k + 1) % 4]
    b = tet[(k + 2) % 4]
    c = tet[(k + 3) % 4]
    lo = wp.min(a, wp.min(b, c))
    hi = wp.max(a, wp.max(b, c))
    return wp.vec3i(lo, a + b + c - lo - hi, hi)


@wp.func
def has_face(tet: wp.vec4i, face: wp.vec3i):
    return corner_of(tet, face[0]) >= 0 and corner_of(tet, face[1]) >= 0 and corner_of(tet, face[2]) >= 0


@wp.func
def relink(m: TetMeshArrays, n: int, face: wp.vec3i, new: int):
    """In element n (-1: none), make its face ``face`` point at element ``new``: found by its
    corners, not by the element it pointed at, whose slot a batch may already have reused."""
    if n >= 0:
        tet = m.tet_indices[n]
        back = m.tet_neighbors[n]
        for k in range(4):
            v = tet[k]
            if v != face[0] and v != face[1] and v != face[2]:
                back[k] = new
        m.tet_neighbors[n] = back


@wp.func
def has_room(m: TetMeshArrays, vertices: int, elements: int):
    """Whether ``vertices`` more vertices and ``elements`` more element slots fit."""
    return m.counts[0] + vertices <= m.vertex_rest.shape[0] and m.counts[1] + elements <= m.tet_indices.shape[0]


@wp.func
def live(m: TetMeshArrays, t: int):
    return t >= 0 and t < m.counts[1] and m.tet_alive[t] != 0


@wp.func
def replace(m: TetMeshArrays, removed_count: int, added_count: int):
    """Replace elements ``m.removed[:removed_count]`` by ``m.added[:added_count]`` (positively
    oriented, parents in ``m.added_parent``), which fill the same region: the new elements
    take the removed slots in order, then new slots (the caller checked the room). A new
    element's face is glued to the new element or the outer element that has it, and the
    outer element is relinked to it (unless :data:`OUTSIDE`); a face found nowhere is on the
    boundary. Every corner of
    a new element gets it as its ``vertex_tet``."""
    outer_count = int(0)
    for r in range(removed_count):
        t = m.removed[r]
        tet = m.tet_indices[t]
        for k in range(4):
            n = m.tet_neighbors[t][k]
            outer = n != -1
            for s in range(removed_count):
                if m.removed[s] == n:
                    outer = False
            if outer:
                m.outer_face[outer_count] = face_opposite(tet, k)
                m.outer_tet[outer_count] = n
                outer_count += 1
    first = m.counts[1]
    for i in range(added_count):
        s = first + i - removed_count
        if i < removed_count:
            s = m.removed[i]
        m.star[i] = s  # the slot of new element i
        m.tet_indices[s] = m.added[i]
        m.tet_alive[s] = 1
        m.tet_parent[s] = m.added_parent[i]
    for r in range(added_count, removed_count):
        m.tet_alive[m.removed[r]] = 0
    m.counts[1] = first + wp.max(0, added_count - removed_count)
    for i in range(added_count):
        tet = m.added[i]
        s = m.star[i]
        neighbors = wp.vec4i(-1, -1, -1, -1)
        for k in range(4):
            face = face_opposite(tet, k)
            for j in range(added_count):
                if j != i and neighbors[k] < 0 and has_face(m.added[j], face):
                    neighbors[k] = m.star[j]
            if neighbors[k] < 0:
                for o in range(outer_count):
                    f = m.outer_face[o]
                    if neighbors[k] < 0 and f[0] == face[0] and f[1] == face[1] and f[2] == face[2]:
                        neighbors[k] = m.outer_tet[o]
                        relink(m, m.outer_tet[o], face, s)
            m.vertex_tet[tet[k]] = s
        m.tet_neighbors[s] = neighbors


@wp.func
def add_vertex(m: TetMeshArrays, parents: wp.vec4i, weights: wp.vec4d, origin: int):
    """A new vertex at the barycentric combination of ``parents`` (-1: none) for rest
    position, position and velocity, journalled with ``origin``, the parent of the element
    it is made in; returns its index (the caller checked the room)."""
    v = m.counts[0]
    m.counts[0] = v + 1
    rest = wp.vec3d()
    q = wp.vec3d()
    qd = wp.vec3d()
    for i in range(4):
        if parents[i] >= 0:
            rest += weights[i] * m.vertex_rest[parents[i]]
            q += weights[i] * m.vertex_q[parents[i]]
            qd += weights[i] * m.vertex_qd[parents[i]]
    m.vertex_rest[v] = rest
    m.vertex_q[v] = q
    m.vertex_qd[v] = qd
    m.vertex_parents[v] = parents
    m.vertex_weights[v] = weights
    m.vertex_tet[v] = -1
    m.vertex_origin[v] = origin
    return v


@wp.func
def interpolated(m: TetMeshArrays, parents: wp.vec4i, weights: wp.vec4d):
    """The rest position :func:`add_vertex` would give (m)."""
    p = wp.vec3d()
    for i in range(4):
        if parents[i] >= 0:
            p += weights[i] * m.vertex_rest[parents[i]]
    return p


@wp.func
def find_tet(m: TetMeshArrays, a: int, b: int, c: int):
    """A live element with corners a, b and c (c = -1: with edge (a, b)), -1 if there is none:
    searched in the star of a from ``vertex_tet[a]`` on, through faces around a, then in all
    elements (where the star is larger than :data:`MAX_STAR` or, in a region, parted)."""
    if a < 0 or a >= m.counts[0]:
        return -1
    t = star_search(m, a, b, c)
    if t != -2:
        return t
    for s in range(m.counts[1]):
        tet = m.tet_indices[s]
        if m.tet_alive[s] != 0 and corner_of(tet, a) >= 0 and corner_of(tet, b) >= 0 \
                and (c < 0 or corner_of(tet, c) >= 0):
            return s
    return -1


@wp.func
def star_search(m: TetMeshArrays, a: int, b: int, c: int):
    """:func:`find_tet` in the star of a: the element, or -2 if not found."""
    start = m.vertex_tet[a]
    if start < 0:
        return -1
    m.star[0] = start
    count = int(1)
    i = int(0)
    while i < count:
        t = m.star[i]
        tet = m.tet_indices[t]
        if corner_of(tet, b) >= 0 and (c < 0 or corner_of(tet, c) >= 0):
            return t
        ka = corner_of(tet, a)
        for k in range(4):
            n = m.tet_neighbors[t][k]
            if k != ka and n >= 0:
                seen = bool(False)
                for j in range(count):
                    if m.star[j] == n:
                        seen = True
                if not seen:
                    if count == MAX_STAR:
                        return -2
                    m.star[count] = n
                    count += 1
        i += 1
    return -2


@wp.func
def rest_before(m: TetMeshArrays, u: int, v: int):
    """Whether vertex u's rest position comes before v's, coordinate by coordinate, two
    coordinates within ``NEAR_TIE`` of the points' size counting as equal (as
    ``TetTopology.rest_before``); by number where the positions are the same."""
    p = m.vertex_rest[u]
    q = m.vertex_rest[v]
    tolerance = NEAR_TIE * (wp.length(p) + wp.length(q))
    for k in range(3):
        if p[k] < q[k] - tolerance:
            return True
        if p[k] > q[k] + tolerance:
            return False
    return u < v


@wp.func
def other_corner(tet: wp.vec4i, a: int, b: int, w: int):
    """The corner of ``tet`` that is none of a, b, w."""
    for k in range(4):
        v = tet[k]
        if v != a and v != b and v != w:
            return v
    return -1


@wp.func
def across(m: TetMeshArrays, t: int, a: int, b: int, u: int):
    """The element across face (a, b, u) of element t (-1: boundary)."""
    tet = m.tet_indices[t]
    return m.tet_neighbors[t][corner_of(tet, other_corner(tet, a, b, u))]


@wp.func
def reverse(values: wp.array(dtype=wp.int32), count: int):
    for i in range(count // 2):
        x = values[i]
        values[i] = values[count - 1 - i]
        values[count - 1 - i] = x


@wp.func
def edge_ring(m: TetMeshArrays, a: int, b: int, start: int):
    """The ordered ring of elements around edge (a, b) from element ``start``, as
    ``TetTopology.edge_ring``: ``m.removed[i]`` is (a, b, polygon[i], polygon[i + 1]) up to
    orientation, with ``signed_volume(a, b, polygon[0], polygon[1]) > 0``; an open ring (a
    boundary edge) starts at a boundary face and has one more polygon vertex than elements; a
    closed one starts at its first polygon vertex by rest position (:func:`rest_before`), so
    that ties between its triangulations break alike whatever the vertices' numbers. Returns
    (elements, closed), elements -1 beyond :data:`MAX_RING` or where the ring leaves the
    arrays (:data:`OUTSIDE`)."""
    # an open ring is walked from one end: find it, walking the other way first
    tet = m.tet_indices[start]
    first = other_corner(tet, a, b, -1)
    begin = start
    t = start
    u = first
    ended = int(0)
    for step in range(MAX_RING + 1):
        if ended == 0:
            n = across(m, t, a, b, u)
            if n == OUTSIDE:
                return wp.vec2i(-1, 0)
            if n < 0:
                begin = t
                first = u
                ended = 1
            elif n == start:
                ended = 1
            else:
                u = other_corner(m.tet_indices[n], a, b, u)
                t = n
    if ended == 0:
        return wp.vec2i(-1, 0)
    count = int(0)
    closed = int(0)
    t = begin
    w = first
    m.polygon[0] = first
    while True:
        if count == MAX_RING:
            return wp.vec2i(-1, 0)
        u = other_corner(m.tet_indices[t], a, b, w)
        m.removed[count] = t
        count += 1
        m.polygon[count] = u
        n = across(m, t, a, b, u)
        if n == OUTSIDE:
            return wp.vec2i(-1, 0)
        if n < 0:
            break
        if n == begin:
            closed = 1
            break
        t = n
        w = u
    corners = count + 1 - closed
    if signed_volume(m.vertex_rest[a], m.vertex_rest[b], m.vertex_rest[m.polygon[0]],
                     m.vertex_rest[m.polygon[1]]) < wp.float64(0.0):
        reverse(m.removed, count)
        reverse(m.polygon, corners)
        if closed != 0:  # element i lay between polygon i and i - 1: shift the polygon by one
            last = m.polygon[corners - 1]
            for i in range(corners - 1, 0, -1):
                m.polygon[i] = m.polygon[i - 1]
            m.polygon[0] = last
    if closed != 0:  # start at the first vertex by rest position: the same ring whatever the start element
        r = int(0)
        for i in range(corners):
            if rest_before(m, m.polygon[i], m.polygon[r]):
                r = i
        for i in range(count):
            m.star[i] = m.removed[(i + r) % count]
            m.star[MAX_RING + i] = m.polygon[(i + r) % count]
        for i in range(count):
            m.removed[i] = m.star[i]
            m.polygon[i] = m.star[MAX_RING + i]
    return wp.vec2i(count, closed)


# ----------------------------------------------------------------- operators
@wp.func
def split_tet(m: TetMeshArrays, t: int, weights: wp.vec4d, tolerance: wp.float64):
    """1-4 split (thesis figure 5.1): a new vertex at barycentric ``weights`` of element t;
    child k has corner k replaced by it, keeps slot t for k = 0 and takes three new slots."""
    if not live(m, t):
        return REFUSED_INPUT
    total = weights[0] + weights[1] + weights[2] + weights[3]
    if not (wp.abs(total - wp.float64(1.0)) <= wp.float64(1e-9)):  # NaN refused too
        return REFUSED_INPUT
    if not has_room(m, 1, 3):
        return REFUSED_FULL
    tet = m.tet_indices[t]
    p = interpolated(m, tet, weights)
    for k in range(4):
        if not tet_well_shaped(m, substitute(tet, tet[k], -2), -2, p, tolerance):
            return REFUSED_SHAPE
    v = add_vertex(m, tet, weights, m.tet_parent[t])
    m.removed[0] = t
    for k in range(4):
        m.added[k] = substitute(tet, tet[k], v)
        m.added_parent[k] = m.tet_parent[t]
    replace(m, 1, 4)
    return DONE


@wp.func
def flip23(m: TetMeshArrays, t0: int, k0: int, tolerance: wp.float64, quality_drop: wp.float64):
    """2-3 flip (thesis figure 5.2) of the face of element t0 opposite its corner k0: with
    apices d (of t0) and e (of the element across), the two elements become (d, e, u, w) for
    the face's edges (u, w) = (a, b), (b, c), (c, a) of its sorted vertices, each oriented
    positively (as ``operators.flip23``). Refused unless segment d-e crosses the face (all
    three of the same orientation) and every new element is well shaped; with
    ``quality_drop`` > 0 also unless the worst new quality is at least ``quality_drop`` times
    the worse of the two old ones."""
    if not live(m, t0) or k0 < 0 or k0 > 3:
        return REFUSED_INPUT
    t1 = m.tet_neighbors[t0][k0]
    if t1 < 0:
        return REFUSED_INPUT
    if not has_room(m, 0, 1):
        return REFUSED_FULL
    tet0 = m.tet_indices[t0]
    tet1 = m.tet_indices[t1]
    face = face_opposite(tet0, k0)
    d = tet0[k0]
    e = other_corner(tet1, face[0], face[1], face[2])
    positive = int(0)
    for i in range(3):
        tet = wp.vec4i(d, e, face[i], face[(i + 1) % 3])
        m.added[i] = tet
        if volume_of(m, tet) > wp.float64(0.0):
            positive += 1
    if positive != 0 and positive != 3:
        return REFUSED_CROSSING
    worst = wp.float64(1.0e300)
    for i in range(3):
        if positive == 0:
            tet = m.added[i]
            m.added[i] = wp.vec4i(tet[0], tet[1], tet[3], tet[2])
        if not tet_well_shaped(m, m.added[i], -2, wp.vec3d(), tolerance):
            return REFUSED_SHAPE
        worst = wp.min(worst, quality_of(m, m.added[i]))
    if quality_drop > wp.float64(0.0):
        if not (worst >= quality_drop * wp.min(quality_of(m, tet0), quality_of(m, tet1))):
            return REFUSED_QUALITY_DROP
    m.removed[0] = t0
    m.removed[1] = t1
    for i in range(3):
        m.added_parent[i] = containing(m, m.added[i], 2, 0)
    replace(m, 2, 3)
    return DONE


@wp.func
def split_face(m: TetMeshArrays, a: int, b: int, c: int, weights: wp.vec3d, tolerance: wp.float64):
    """Split face (a, b, c) at barycentric ``weights`` over a, b, c: each element on it becomes
    three, each with one of a, b, c replaced by the new vertex (the 1-3 split of thesis figure
    5.5 on a boundary face, 2-6 on an interior one, as ``operators.split_face``)."""
    total = weights[0] + weights[1] + weights[2]
    if not (wp.abs(total - wp.float64(1.0)) <= wp.float64(1e-9)):
        return REFUSED_INPUT
    t0 = find_tet(m, a, b, c)
    if t0 < 0:
        return REFUSED_MISSING
    if not has_room(m, 1, 4):
        return REFUSED_FULL
    owners = wp.vec2i(t0, m.tet_neighbors[t0][corner_of(m.tet_indices[t0], other_corner(m.tet_indices[t0], a, b, c))])
    if owners[1] == OUTSIDE:
        return REFUSED_MISSING
    owner_count = wp.where(owners[1] >= 0, 2, 1)
    parents = wp.vec4i(a, b, c, -1)
    w = wp.vec4d(weights[0], weights[1], weights[2], wp.float64(0.0))
    p = interpolated(m, parents, w)
    face = wp.vec3i(a, b, c)
    for o in range(owner_count):
        tet = m.tet_indices[owners[o]]
        m.removed[o] = owners[o]
        for i in range(3):
            m.added[3 * o + i] = substitute(tet, face[i], -2)
            m.added_parent[3 * o + i] = m.tet_parent[owners[o]]
            if not tet_well_shaped(m, m.added[3 * o + i], -2, p, tolerance):
                return REFUSED_SHAPE
    v = add_vertex(m, parents, w, m.tet_parent[t0])
    for i in range(3 * owner_count):
        m.added[i] = substitute(m.added[i], -2, v)
    replace(m, owner_count, 3 * owner_count)
    return DONE


@wp.func
def bisect_edge(m: TetMeshArrays, a: int, b: int, s: wp.float64, tolerance: wp.float64):
    """Bisection of edge (a, b) (thesis figure 5.5, right) at ``(1 - s) a + s b``: every
    element around the edge is split in two (as ``operators.bisect_edge``)."""
    if not (s > wp.float64(0.0) and s < wp.float64(1.0)):
        return REFUSED_INPUT
    start = find_tet(m, a, b, -1)
    if start < 0:
        return REFUSED_MISSING
    ring = edge_ring(m, a, b, start)
    count = ring[0]
    if count < 0:
        return REFUSED_MISSING
    if not has_room(m, 1, count):
        return REFUSED_FULL
    parents = wp.vec4i(a, b, -1, -1)
    w = wp.vec4d(wp.float64(1.0) - s, s, wp.float64(0.0), wp.float64(0.0))
    p = interpolated(m, parents, w)
    for r in range(count):
        tet = m.tet_indices[m.removed[r]]
        m.added[2 * r] = substitute(tet, a, -2)
        m.added[2 * r + 1] = substitute(tet, b, -2)
        m.added_parent[2 * r] = m.tet_parent[m.removed[r]]
        m.added_parent[2 * r + 1] = m.tet_parent[m.removed[r]]
        if not (tet_well_shaped(m, m.added[2 * r], -2, p, tolerance)
                and tet_well_shaped(m, m.added[2 * r + 1], -2, p, tolerance)):
            return REFUSED_SHAPE
    v = add_vertex(m, parents, w, m.tet_parent[m.removed[0]])
    for i in range(2 * count):
        m.added[i] = substitute(m.added[i], -2, v)
    replace(m, count, 2 * count)
    return DONE


@wp.func
def pair_quality(m: TetMeshArrays, a: int, b: int, i: int, k: int, j: int):
    """The worse quality of the two elements over triangle (polygon i, k, j): (i, k, j, b)
    and (i, j, k, a)."""
    pi = m.vertex_rest[m.polygon[i]]
    pk = m.vertex_rest[m.polygon[k]]
    pj = m.vertex_rest[m.polygon[j]]
    qb = tet_quality(pi, pk, pj, m.vertex_rest[b])
    qa = tet_quality(pi, pj, pk, m.vertex_rest[a])
    q = wp.min(qa, qb)
    if not (qa == qa and qb == qb):
        q = wp.float64(-1.0e300)
    return q


@wp.func
def remove_edge(m: TetMeshArrays, a: int, b: int, tolerance: wp.float64, volume_tolerance: wp.float64):
    """General flip, or edge removal (thesis figure 5.3), as ``operators.remove_edge``: the n
    elements around edge (a, b) become 2(n - 2) elements (a, tau) and (b, tau) over the
    triangulation tau of their polygon that maximises the worst element quality (dynamic
    programming, Shewchuk's edge removal; on a tie within ``NEAR_TIE`` the larger apex). A
    boundary edge's open polygon is closed by one more edge, which replaces its two boundary
    faces: refused when the volume changes by more than ``volume_tolerance`` (relative), i.e.
    unless they are coplanar."""
    start = find_tet(m, a, b, -1)
    if start < 0:
        return REFUSED_MISSING
    ring = edge_ring(m, a, b, start)
    count = ring[0]
    closed = ring[1]
    if count < 0:
        return REFUSED_MISSING
    corners = count + 1 - closed
    if corners < 3:
        return REFUSED_SHAPE
    if not has_room(m, 0, wp.max(0, 2 * (corners - 2) - count)):
        return REFUSED_FULL
    for span in range(2, corners):
        for i in range(corners - span):
            j = i + span
            best = wp.float64(0.0)
            apex = int(-1)
            for k in range(i + 1, j):
                value = pair_quality(m, a, b, i, k, j)
                if k > i + 1:
                    value = wp.min(value, m.best[i * POLYGON + k])
                if j > k + 1:
                    value = wp.min(value, m.best[k * POLYGON + j])
                if apex < 0 or value >= best - NEAR_TIE * wp.abs(best):
                    best = value
                    apex = k
            m.best[i * POLYGON + j] = best
            m.apex[i * POLYGON + j] = apex
    if not (m.best[corners - 1] > tolerance):
        return REFUSED_SHAPE
    # the triangles, from the table (a stack of (i, j) in the star row)
    m.star[0] = corners - 1
    depth = int(1)
    added = int(0)
    while depth > 0:
        depth -= 1
        ij = m.star[depth]
        i = ij // POLYGON
        j = ij % POLYGON
        k = m.apex[ij]
        u = m.polygon[i]
        v = m.polygon[k]
        w = m.polygon[j]
        m.added[added] = wp.vec4i(u, v, w, b)
        m.added[added + 1] = wp.vec4i(u, w, v, a)
        m.added_parent[added] = k - 1  # where the parent search starts (see below)
        added += 2
        if k > i + 1:
            m.star[depth] = i * POLYGON + k
            depth += 1
        if j > k + 1:
            m.star[depth] = k * POLYGON + j
            depth += 1
    for i in range(added):
        if not tet_well_shaped(m, m.added[i], -2, wp.vec3d(), tolerance):
            return REFUSED_SHAPE
    if closed == 0:
        before = wp.float64(0.0)
        after = wp.float64(0.0)
        for r in range(count):
            before += volume_of(m, m.tet_indices[m.removed[r]])
        for i in range(added):
            after += volume_of(m, m.added[i])
        if wp.abs(after - before) > volume_tolerance * before:
            return REFUSED_VOLUME
    for i in range(0, added, 2):
        # ring elements k - 1 and k hold polygon vertex k: the search for the parent starts there
        hint = m.added_parent[i]
        m.added_parent[i] = containing(m, m.added[i], count, hint)
        m.added_parent[i + 1] = containing(m, m.added[i + 1], count, hint)
    replace(m, count, added)
    return DONE


@wp.func
def flip_or_split_face(m: TetMeshArrays, x: wp.vec4i, w: wp.vec4d, tolerance: wp.float64, quality_drop: wp.float64,
                       made: wp.array(dtype=wp.vec2i), i: int):
    """The cutter's step 4 on face (x[0], x[1], x[2]) (thesis 5.1.1, 5.1.2): a 2-3 flip of an
    interior face, and where it is refused or the face is on the boundary, a split of the face
    at weights ``w`` (x[3] says whether they are known: :data:`POINT_KNOWN`). ``made[i]``:
    the new vertex and 1 when the face split ran."""
    t0 = find_tet(m, x[0], x[1], x[2])
    if t0 < 0:
        return REFUSED_MISSING
    tet0 = m.tet_indices[t0]
    k0 = corner_of(tet0, other_corner(tet0, x[0], x[1], x[2]))
    if m.tet_neighbors[t0][k0] >= 0:
        code = flip23(m, t0, k0, tolerance, quality_drop)
        if code == DONE or code == REFUSED_FULL:
            return code
    if x[3] == POINT_PENDING:
        return NEEDS_POINT
    if x[3] == POINT_NONE:
        return NO_POINT
    code = split_face(m, x[0], x[1], x[2], wp.vec3d(w[0], w[1], w[2]), tolerance)
    made[i] = wp.vec2i(wp.where(code == DONE, m.counts[0] - 1, -1), 1)
    return code


@wp.func
def remove_or_bisect_edge(m: TetMeshArrays, x: wp.vec4i, s: wp.float64, tolerance: wp.float64,
                          volume_tolerance: wp.float64, made: wp.array(dtype=wp.vec2i), i: int):
    """The cutter's step 5 on edge (x[0], x[1]) (thesis 5.1.1, 5.1.2): a general flip, and
    where it is refused (or x[2] = 1 and the edge is on the boundary) a bisection at s.
    ``made[i]``: the new vertex and 1 when the bisection ran."""
    start = find_tet(m, x[0], x[1], -1)
    if start < 0:
        return REFUSED_MISSING
    flip = True
    if x[2] == 1:
        flip = edge_ring(m, x[0], x[1], start)[1] == 1  # a closed ring: an interior edge
    if flip:
        code = remove_edge(m, x[0], x[1], tolerance, volume_tolerance)
        if code == DONE or code == REFUSED_FULL:
            return code
    code = bisect_edge(m, x[0], x[1], s, tolerance)
    made[i] = wp.vec2i(wp.where(code == DONE, m.counts[0] - 1, -1), 1)
    return code


@wp.kernel
def run_operators(
    m: TetMeshArrays,
    kinds: wp.array(dtype=wp.int32),
    ints: wp.array(dtype=wp.vec4i),
    reals: wp.array(dtype=wp.vec4d),
    tolerance: wp.float64,
    quality_drop: wp.float64,
    volume_tolerance: wp.float64,
    status: wp.array(dtype=wp.int32),
    made: wp.array(dtype=wp.vec2i),
):
    """Operator i of kind ``kinds[i]`` (``SPLIT_TET`` ...) on ``ints[i]`` / ``reals[i]``, in
    order (launch one thread); ``status[i]`` its code, ``made[i]`` the vertex it made (-1:
    none) and 1 where a fused operator's fallback ran. After a :data:`REFUSED_FULL` or
    :data:`NEEDS_POINT` nothing more is done (:data:`NOT_RUN`), so that the host can grow the
    arrays or give the point and go on from there."""
    stop = int(0)
    for i in range(kinds.shape[0]):
        made[i] = wp.vec2i(-1, 0)
        if stop != 0:
            status[i] = NOT_RUN
            continue
        kind = kinds[i]
        x = ints[i]
        w = reals[i]
        code = REFUSED_INPUT
        if kind == SPLIT_TET:
            code = split_tet(m, x[0], w, tolerance)
            if code == DONE:
                made[i] = wp.vec2i(m.counts[0] - 1, 0)
        elif kind == FLIP_FACE:
            code = flip23(m, x[0], x[1], tolerance, quality_drop)
        elif kind == SPLIT_FACE:
            code = split_face(m, x[0], x[1], x[2], wp.vec3d(w[0], w[1], w[2]), tolerance)
        elif kind == REMOVE_EDGE:
            code = remove_edge(m, x[0], x[1], tolerance, volume_tolerance)
        elif kind == BISECT_EDGE:
            code = bisect_edge(m, x[0], x[1], w[0], tolerance)
        elif kind == FLIP_OR_SPLIT_FACE:
            code = flip_or_split_face(m, x, w, tolerance, quality_drop, made, i)
        elif kind == REMOVE_OR_BISECT_EDGE:
            code = remove_or_bisect_edge(m, x, w[0], tolerance, volume_tolerance, made, i)
        status[i] = code
        if code == REFUSED_FULL or code == NEEDS_POINT:
            stop = 1


# ------------------------------------------------------------ disconnection
@wp.func
def back_corner(m: TetMeshArrays, n: int, t: int):
    """The corner of element n whose opposite face is shared with element t (-1: none)."""
    for k in range(4):
        if m.tet_neighbors[n][k] == t:
            return k
    return -1


@wp.func
def set_opened(opened: wp.array(dtype=wp.vec4i), t: int, k: int, value: int):
    flags = opened[t]
    flags[k] = value
    opened[t] = flags


@wp.func
def duplicate_vertex(m: TetMeshArrays, v: int, members: wp.array(dtype=wp.int32), first: int, count: int,
                     opened: wp.array(dtype=wp.vec4i), fan: wp.array(dtype=wp.int32),
                     stack: wp.array(dtype=wp.int32)):
    """Split vertex v, whose elements are ``members[first:first + count]`` in increasing slot
    order, into one copy per fan: the elements around v connected through faces on v that are
    not ``opened`` (thesis figure 4.8, ``operators.duplicate_vertex``). The largest fan keeps
    v (the first by smallest slot among equals), each other fan gets a new vertex with v's
    attributes, in that order. An opened face whose two elements move to the same copy is
    sewn again (``TetTopology.retarget`` forgets it), one between two copies is apart for
    good. Returns the copies made, -1 without room for them (nothing changed)."""
    fans = int(0)
    for i in range(first, first + count):  # label the fans by a search from each element not reached yet
        if fan[members[i]] < 0:
            fan[members[i]] = fans
            stack[0] = members[i]
            depth = int(1)
            while depth > 0:
                depth -= 1
                t = stack[depth]
                tet = m.tet_indices[t]
                for k in range(4):
                    n = m.tet_neighbors[t][k]
                    if tet[k] != v and n >= 0 and opened[t][k] == 0:
                        if fan[n] < 0:
                            fan[n] = fans
                            stack[depth] = n
                            depth += 1
            fans += 1
    copies = fans - 1
    if copies > 0 and not has_room(m, copies, 0):
        copies = -1
    if copies > 0:
        for f in range(fans):  # sizes, in the stack (free now): fans are numbered by smallest slot
            stack[f] = 0
        for i in range(first, first + count):
            stack[fan[members[i]]] += 1
        keeper = int(0)
        for f in range(fans):
            if stack[f] > stack[keeper]:
                keeper = f
        stack[keeper] = -1
        for rank in range(copies):  # the others, largest first
            f = int(-1)
            for g in range(fans):
                if stack[g] >= 0 and (f < 0 or stack[g] > stack[f]):
                    f = g
            stack[f] = -1
            w = add_vertex(m, wp.vec4i(v, -1, -1, -1), wp.vec4d(1.0, 0.0, 0.0, 0.0), -1)
            for i in range(first, first + count):
                t = members[i]
                if fan[t] == f:
                    tet = m.tet_indices[t]
                    for k in range(4):
                        n = m.tet_neighbors[t][k]
                        if tet[k] != v and n >= 0 and opened[t][k] != 0 and fan[n] == f:
                            set_opened(opened, t, k, 0)
                            set_opened(opened, n, back_corner(m, n, t), 0)
                    m.tet_indices[t] = substitute(tet, v, w)
                    m.vertex_tet[w] = t
            for i in range(first, first + count):
                if fan[members[i]] == keeper:
                    m.vertex_tet[v] = members[i]
    for i in range(first, first + count):
        fan[members[i]] = -1
    return copies


@wp.kernel
def disconnect(
    m: TetMeshArrays,
    faces: wp.array(dtype=wp.vec2i),
    vertices: wp.array(dtype=wp.int32),
    first: int,
    opened: wp.array(dtype=wp.vec4i),
    fan: wp.array(dtype=wp.int32),
    stack: wp.array(dtype=wp.int32),
    row_of: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    cursor: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
):
    """Unsew ``faces`` (element, corner opposite) and duplicate ``vertices[first:]`` in order
    (:func:`duplicate_vertex`), then make the faces whose elements no longer share them
    boundary (the others are sewn again: ``operators.sew_unopened``). Launch one thread.
    Scratch: ``opened`` (zeros), ``fan`` (-1) and ``stack`` of the element capacity,
    ``row_of`` (-1) of the vertex capacity, ``offsets`` (zeros) of one more than
    ``vertices``, ``cursor`` (zeros) as ``vertices``, ``members`` of four times the element
    capacity. ``status``: [code,
    vertices done, copies made]; :data:`REFUSED_FULL` stops before the vertex without room
    (the host grows the arrays and runs from there), :data:`REFUSED_INPUT` at a face that is
    not interior (nothing changed)."""
    status[0] = DONE
    status[1] = first
    status[2] = 0
    for i in range(faces.shape[0]):  # (the flags are scratch: a refusal leaves the mesh as it was)
        t = faces[i][0]
        k = faces[i][1]
        if not live(m, t) or k < 0 or k > 3 or m.tet_neighbors[t][k] < 0:
            status[0] = REFUSED_INPUT
            return
        n = m.tet_neighbors[t][k]
        set_opened(opened, t, k, 1)
        set_opened(opened, n, back_corner(m, n, t), 1)
    # the elements of each vertex, in increasing slot order (a counting sort: one pass over the
    # elements, not one per vertex; a copy's elements keep the other vertices they have)
    for i in range(first, vertices.shape[0]):
        row_of[vertices[i]] = i
    for s in range(m.counts[1]):
        if m.tet_alive[s] != 0:
            for k in range(4):
                r = row_of[m.tet_indices[s][k]]
                if r >= 0:
                    offsets[r + 1] += 1
    for i in range(first, vertices.shape[0]):
        offsets[i + 1] += offsets[i]
    for s in range(m.counts[1]):
        if m.tet_alive[s] != 0:
            for k in range(4):
                r = row_of[m.tet_indices[s][k]]
                if r >= 0:
                    members[offsets[r] + cursor[r]] = s
                    cursor[r] += 1
    for i in range(first, vertices.shape[0]):
        copies = duplicate_vertex(m, vertices[i], members, offsets[i], offsets[i + 1] - offsets[i], opened, fan,
                                  stack)
        if copies < 0:
            status[0] = REFUSED_FULL
            return
        status[1] = i + 1
        status[2] += copies
    for i in range(faces.shape[0]):
        t = faces[i][0]
        k = faces[i][1]
        n = m.tet_neighbors[t][k]
        if n >= 0 and not has_face(m.tet_indices[n], face_opposite(m.tet_indices[t], k)):
            back = m.tet_neighbors[n]
            back[back_corner(m, n, t)] = -1
            m.tet_neighbors[n] = back
            mine = m.tet_neighbors[t]
            mine[k] = -1
            m.tet_neighbors[t] = mine
