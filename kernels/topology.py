"""Compiled topology operators on flat arrays (thesis 5.1): the core the cutter is moving to.

A Python operator call costs some 70 us on this project's machine (adjacency in dicts and
sets, its checks in Python floats), and a plane crossing 100 elements takes about 700 of
them: 50-75 ms per cut event against the 20 ms of issue 3. Here the same operators are Warp
functions on flat arrays, run in order by one thread of one launch (a topological change is
sequential: each operator reads what the previous one wrote), so a batch costs one launch.

Layout (``wcut.topology.arrays.TetArrays`` owns the arrays):

- ``tet_indices[t]`` (vec4i): the corners of element slot t, positively oriented;
- ``tet_neighbors[t]`` (vec4i): the element across the face opposite corner k, -1 on the
  boundary (the face-neighbour arrays of Shewchuk's and CGoGN's tetrahedral maps);
- ``tet_alive[t]``: 1 for a live slot; ``tet_parent[t]``: the element of the mesh before the
  change that contains it (the change record's parent, as ``TetTopology``'s journal);
- ``vertex_rest`` / ``vertex_q`` / ``vertex_qd`` (vec3d): rest position, position (m) and
  velocity (m/s) in float64, as ``TetTopology.vertex_data``; a new vertex gets the
  barycentric combination of its element's corners for all three (exact for linear
  elements, thesis 3.2), and ``vertex_parents`` / ``vertex_weights`` record it;
- ``counts``: [vertex count, element slot count].

Every operator checks before it writes, and refuses (returns a :data:`REFUSED` code, arrays
untouched) unless every new element is well shaped in the rest configuration, in float64
and rounded to float32 (what the simulation sees): ``volume / longest edge^3 >
tolerance``, the rule of ``wcut.topology.operators._check``.
"""

import warp as wp

#: status codes of an operator
DONE = wp.constant(0)
REFUSED_SHAPE = wp.constant(1)  # a new element would be inverted or flat
REFUSED_FULL = wp.constant(2)  # no room left in the arrays (the host grows them and runs again)
REFUSED_INPUT = wp.constant(3)  # a dead element, a boundary face, bad weights
REFUSED_CROSSING = wp.constant(4)  # flip 2-3: the new edge does not cross the face
REFUSED_QUALITY_DROP = wp.constant(5)  # flip 2-3: its worst element is poorer than allowed


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
def corner_point(rest: wp.array(dtype=wp.vec3d), tet: wp.vec4i, k: int, skip: int, p: wp.vec3d):
    """Rest position of corner k of ``tet``, or p when k is ``skip``."""
    if k == skip:
        return p
    return rest[tet[k]]


@wp.func
def relink(tet_indices: wp.array(dtype=wp.vec4i), tet_neighbors: wp.array(dtype=wp.vec4i), n: int, a: int, b: int,
           c: int, new: int):
    """In element n (-1: none), make its face (a, b, c) point at element ``new``: found by its
    corners, not by the element it pointed at, whose slot a batch may already have reused."""
    if n >= 0:
        tet = tet_indices[n]
        back = tet_neighbors[n]
        for k in range(4):
            v = tet[k]
            if v != a and v != b and v != c:
                back[k] = new
        tet_neighbors[n] = back


@wp.func
def corner_of(tet: wp.vec4i, v: int):
    """Local index of vertex v in ``tet``, -1 if it is not a corner."""
    for k in range(4):
        if tet[k] == v:
            return k
    return -1


@wp.func
def split_tet(
    t: int,
    weights: wp.vec4d,
    tolerance: wp.float64,
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_neighbors: wp.array(dtype=wp.vec4i),
    tet_alive: wp.array(dtype=wp.int32),
    tet_parent: wp.array(dtype=wp.int32),
    vertex_rest: wp.array(dtype=wp.vec3d),
    vertex_q: wp.array(dtype=wp.vec3d),
    vertex_qd: wp.array(dtype=wp.vec3d),
    vertex_parents: wp.array(dtype=wp.vec4i),
    vertex_weights: wp.array(dtype=wp.vec4d),
    counts: wp.array(dtype=wp.int32),
):
    """1-4 split (thesis figure 5.1): a new vertex at barycentric ``weights`` of element t;
    child k has corner k replaced by it, keeps slot t for k = 0 and takes three new slots.
    Returns a status code."""
    if t < 0 or t >= counts[1] or tet_alive[t] == 0:
        return REFUSED_INPUT
    total = weights[0] + weights[1] + weights[2] + weights[3]
    if not (wp.abs(total - wp.float64(1.0)) <= wp.float64(1e-9)):  # NaN refused too
        return REFUSED_INPUT
    if counts[0] >= vertex_rest.shape[0] or counts[1] + 3 > tet_indices.shape[0]:
        return REFUSED_FULL
    tet = tet_indices[t]
    p = weights[0] * vertex_rest[tet[0]] + weights[1] * vertex_rest[tet[1]] + weights[2] * vertex_rest[tet[2]] \
        + weights[3] * vertex_rest[tet[3]]
    for k in range(4):
        if not well_shaped(corner_point(vertex_rest, tet, 0, k, p), corner_point(vertex_rest, tet, 1, k, p),
                           corner_point(vertex_rest, tet, 2, k, p), corner_point(vertex_rest, tet, 3, k, p),
                           tolerance):
            return REFUSED_SHAPE
    v = counts[0]
    counts[0] = v + 1
    vertex_rest[v] = p
    vertex_q[v] = weights[0] * vertex_q[tet[0]] + weights[1] * vertex_q[tet[1]] + weights[2] * vertex_q[tet[2]] \
        + weights[3] * vertex_q[tet[3]]
    vertex_qd[v] = weights[0] * vertex_qd[tet[0]] + weights[1] * vertex_qd[tet[1]] \
        + weights[2] * vertex_qd[tet[2]] + weights[3] * vertex_qd[tet[3]]
    vertex_parents[v] = tet
    vertex_weights[v] = weights
    first = counts[1]
    counts[1] = first + 3
    child = wp.vec4i(t, first, first + 1, first + 2)
    outer = tet_neighbors[t]
    parent = tet_parent[t]
    for k in range(4):
        s = child[k]
        # the face opposite the new vertex is the old face opposite corner k; child j shares
        # the face opposite corner j
        tet_indices[s] = wp.vec4i(wp.where(k == 0, v, tet[0]), wp.where(k == 1, v, tet[1]),
                                  wp.where(k == 2, v, tet[2]), wp.where(k == 3, v, tet[3]))
        tet_neighbors[s] = wp.vec4i(wp.where(k == 0, outer[0], child[0]), wp.where(k == 1, outer[1], child[1]),
                                    wp.where(k == 2, outer[2], child[2]), wp.where(k == 3, outer[3], child[3]))
        tet_alive[s] = 1
        tet_parent[s] = parent
        if k > 0:
            relink(tet_indices, tet_neighbors, outer[k], tet[(k + 1) % 4], tet[(k + 2) % 4], tet[(k + 3) % 4], s)
    return DONE


@wp.func
def sorted_face(tet_indices: wp.array(dtype=wp.vec4i), t0: int, k0: int):
    """The face of element t0 opposite corner k0, its vertices sorted ascending (a, b, c)."""
    tet = tet_indices[t0]
    a = tet[(k0 + 1) % 4]
    b = tet[(k0 + 2) % 4]
    c = tet[(k0 + 3) % 4]
    lo = wp.min(a, wp.min(b, c))
    hi = wp.max(a, wp.max(b, c))
    return wp.vec3i(lo, a + b + c - lo - hi, hi)


@wp.func
def smallest_barycentric(p: wp.vec3d, c0: wp.vec3d, c1: wp.vec3d, c2: wp.vec3d, c3: wp.vec3d):
    """The smallest barycentric coordinate of point p in tetrahedron c0 c1 c2 c3."""
    whole = signed_volume(c0, c1, c2, c3)
    w0 = signed_volume(p, c1, c2, c3) / whole
    w1 = signed_volume(c0, p, c2, c3) / whole
    w2 = signed_volume(c0, c1, p, c3) / whole
    return wp.min(wp.min(w0, w1), wp.min(w2, wp.float64(1.0) - w0 - w1 - w2))


@wp.func
def flip23(
    t0: int,
    k0: int,
    tolerance: wp.float64,
    quality_drop: wp.float64,
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_neighbors: wp.array(dtype=wp.vec4i),
    tet_alive: wp.array(dtype=wp.int32),
    tet_parent: wp.array(dtype=wp.int32),
    vertex_rest: wp.array(dtype=wp.vec3d),
    counts: wp.array(dtype=wp.int32),
):
    """2-3 flip (thesis figure 5.2) of the face of element t0 opposite its corner k0: with
    apices d (of t0) and e (of the element across), the two elements become (d, e, u, w) for
    the face's edges (u, w) = (a, b), (b, c), (c, a) of its sorted vertices, each oriented
    positively, in slots t0, the other element's and a new one (as ``operators.flip23``).
    Refused unless segment d-e crosses the face (all three of the same orientation) and every
    new element is well shaped; with ``quality_drop`` > 0 also unless the worst new quality is
    at least ``quality_drop`` times the worse of the two old ones. Returns a status code."""
    if t0 < 0 or t0 >= counts[1] or tet_alive[t0] == 0 or k0 < 0 or k0 > 3:
        return REFUSED_INPUT
    t1 = tet_neighbors[t0][k0]
    if t1 < 0:
        return REFUSED_INPUT
    if counts[1] + 1 > tet_indices.shape[0]:
        return REFUSED_FULL
    tet0 = tet_indices[t0]
    tet1 = tet_indices[t1]
    k1 = int(-1)
    for k in range(4):
        if tet_neighbors[t1][k] == t0:
            k1 = k
    d = tet0[k0]
    e = tet1[k1]
    face = sorted_face(tet_indices, t0, k0)
    pd = vertex_rest[d]
    pe = vertex_rest[e]
    positive = int(0)
    for i in range(3):
        if signed_volume(pd, pe, vertex_rest[face[i]], vertex_rest[face[(i + 1) % 3]]) > wp.float64(0.0):
            positive += 1
    if positive != 0 and positive != 3:
        return REFUSED_CROSSING
    # new element i is (d, e, first[i], second[i]) over the face's edge i, (a, b), (b, c) or
    # (c, a), in the order that orients it positively; third[i] the face's other vertex
    swap = positive == 0
    first = wp.vec3i(face[0], face[1], face[2])
    second = wp.vec3i(face[1], face[2], face[0])
    third = wp.vec3i(face[2], face[0], face[1])
    if swap:
        first = wp.vec3i(face[1], face[2], face[0])
        second = wp.vec3i(face[0], face[1], face[2])
    worst = wp.float64(1.0e300)
    for i in range(3):
        pu = vertex_rest[first[i]]
        pw = vertex_rest[second[i]]
        if not well_shaped(pd, pe, pu, pw, tolerance):
            return REFUSED_SHAPE
        worst = wp.min(worst, tet_quality(pd, pe, pu, pw))
    if quality_drop > wp.float64(0.0):
        before = wp.min(tet_quality(vertex_rest[tet0[0]], vertex_rest[tet0[1]], vertex_rest[tet0[2]],
                                    vertex_rest[tet0[3]]),
                        tet_quality(vertex_rest[tet1[0]], vertex_rest[tet1[1]], vertex_rest[tet1[2]],
                                    vertex_rest[tet1[3]]))
        if not (worst >= quality_drop * before):
            return REFUSED_QUALITY_DROP
    # the outer neighbours: across (d, u, w) from t0 and (e, u, w) from t1, opposite x in each
    outer0 = wp.vec3i()
    outer1 = wp.vec3i()
    parents = wp.vec3i()
    for i in range(3):
        x = third[i]
        outer0[i] = tet_neighbors[t0][corner_of(tet0, x)]
        outer1[i] = tet_neighbors[t1][corner_of(tet1, x)]
        # the parent: the old element that holds the new one's centroid (the one of larger
        # smallest barycentric coordinate; the first on a tie, as operators._containing)
        pu = vertex_rest[first[i]]
        pw = vertex_rest[second[i]]
        centre = (pd + pe + pu + pw) * wp.float64(0.25)
        in0 = smallest_barycentric(centre, vertex_rest[tet0[0]], vertex_rest[tet0[1]], vertex_rest[tet0[2]],
                                   vertex_rest[tet0[3]])
        in1 = smallest_barycentric(centre, vertex_rest[tet1[0]], vertex_rest[tet1[1]], vertex_rest[tet1[2]],
                                   vertex_rest[tet1[3]])
        parents[i] = wp.where(in1 > in0, tet_parent[t1], tet_parent[t0])
    slots = wp.vec3i(t0, t1, counts[1])
    counts[1] = counts[1] + 1
    for i in range(3):
        s = slots[i]
        # corners (d, e, u, w): opposite d lies t1's old face, opposite e t0's; opposite the
        # face's vertex of edge i the element of the next edge, opposite the other the previous
        after = slots[(i + 1) % 3]
        previous = slots[(i + 2) % 3]
        tet_indices[s] = wp.vec4i(d, e, first[i], second[i])
        tet_neighbors[s] = wp.vec4i(outer1[i], outer0[i], wp.where(swap, previous, after),
                                    wp.where(swap, after, previous))
        tet_alive[s] = 1
        tet_parent[s] = parents[i]
    for i in range(3):
        relink(tet_indices, tet_neighbors, outer0[i], d, first[i], second[i], slots[i])
        relink(tet_indices, tet_neighbors, outer1[i], e, first[i], second[i], slots[i])
    return DONE


@wp.kernel
def split_tets(
    slots: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.vec4d),
    tolerance: wp.float64,
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_neighbors: wp.array(dtype=wp.vec4i),
    tet_alive: wp.array(dtype=wp.int32),
    tet_parent: wp.array(dtype=wp.int32),
    vertex_rest: wp.array(dtype=wp.vec3d),
    vertex_q: wp.array(dtype=wp.vec3d),
    vertex_qd: wp.array(dtype=wp.vec3d),
    vertex_parents: wp.array(dtype=wp.vec4i),
    vertex_weights: wp.array(dtype=wp.vec4d),
    counts: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
):
    """:func:`split_tet` of ``slots[i]`` at ``weights[i]``, in order (launch one thread);
    ``status[i]`` its code. After a :data:`REFUSED_FULL` nothing more is done (the later
    operators are marked full too) so that the host can grow the arrays and go on from there."""
    full = int(0)
    for i in range(slots.shape[0]):
        if full != 0:
            status[i] = REFUSED_FULL
            continue
        code = split_tet(slots[i], weights[i], tolerance, tet_indices, tet_neighbors, tet_alive, tet_parent,
                         vertex_rest, vertex_q, vertex_qd, vertex_parents, vertex_weights, counts)
        status[i] = code
        if code == REFUSED_FULL:
            full = 1


@wp.kernel
def flip_faces(
    faces: wp.array(dtype=wp.vec2i),
    tolerance: wp.float64,
    quality_drop: wp.float64,
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_neighbors: wp.array(dtype=wp.vec4i),
    tet_alive: wp.array(dtype=wp.int32),
    tet_parent: wp.array(dtype=wp.int32),
    vertex_rest: wp.array(dtype=wp.vec3d),
    counts: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
):
    """:func:`flip23` of the faces ``(element, corner opposite)`` in order (launch one
    thread); ``status[i]`` its code, and nothing more after a :data:`REFUSED_FULL`."""
    full = int(0)
    for i in range(faces.shape[0]):
        if full != 0:
            status[i] = REFUSED_FULL
            continue
        f = faces[i]
        code = flip23(f[0], f[1], tolerance, quality_drop, tet_indices, tet_neighbors, tet_alive, tet_parent,
                      vertex_rest, counts)
        status[i] = code
        if code == REFUSED_FULL:
            full = 1
