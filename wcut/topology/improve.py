"""Local mesh improvement after a topological change (beyond thesis chapter 5).

A cut leaves elements as flat as its geometry makes them: a crossing close to a vertex that
could not snap gives a sliver, and later cuts make it worse. Like the dynamic local remeshing
of Wicke et al. (2010), with the moves of Klingner and Shewchuk's Stellar (2007), this pass
improves the elements a change made, and their neighbours, in the rest configuration:

- *topological moves*: the general flip of an edge (``remove_edge``: the 3-2 and 4-4 flips
  and larger rings, the best triangulation of the ring by dynamic programming) and the 2-3
  flip of a face (``flip23``);
- *smoothing*: a vertex moves towards the centroid of its neighbours, or away from the
  opposite face of its worst element, or straight off that face's plane to the height of a
  regular element on it (a cap beside the face), or, where none of these helps, up the
  gradient of its worst element's measure (on ``organ_cut`` the worst angle after any cut
  event rises from 3.1 to 4.2 degrees), within its star (``move_vertex``, whose state
  is carried by interpolation in the change record). A boundary vertex moves only within a
  flat boundary (towards the centroid of its boundary neighbours or along one of its boundary
  edges), or, on a crease where two flat boundaries meet, along its edges (the move keeps the
  boundary and the volume to rounding; on 16 random blades through the perturbed beam, the
  smallest element rises from 3.7e-4 to 1.2e-3 of the median); *frozen*
  vertices (on the cut surface, its lips) never move alone;
- *sliding on the cut*: a vertex inside the wound and its copy on the other lip (*twins*, at
  the same rest position) move together towards the centroid of their neighbours on the lip,
  so the lips still meet face to face and the volume stays. Within a flat fan the wound's
  faces cover the same surface and each side keeps its volume. Where a boundary vertex holds
  the cut, the fans next to it are bent (split points averaged with the held vertex lie a few
  hundredths of an edge off the plane); there a vertex whose every boundary face is a lip's
  slides off its fan's planes where the caller allows it (``may_bend``: the cutter keeps it
  within the band its fan spans about the cut surface), and each side's volume changes by what
  the slide sweeps. A vertex at the wound's rim, where it meets the outer boundary, slides with
  its copy along an edge both lips share, where the rim is the straight line of a flat outer
  boundary and a flat wound (on 16 random blades through the organ and the perturbed beam, in
  30 increments each, the increments that leave an element below 5 degrees fall from 40 to 14
  of 223). A cut leaves its worst elements where the split point of an
  element lies a few hundredths of an edge from the split point of one of its faces (a plane
  passing close to an edge); sliding moves them apart: on ten random plane cuts of the organ,
  the worst dihedral angle rises from 1.5-4.0 to 4.3-5.2 degrees by sliding in flat fans alone,
  and over 20 cuts from 3.76 to 5.13 with bent fans too. Sliding comes first: flips and
  smoothing before it left the worst at 3.1 degrees;
- *edge contraction*, where nothing else helps: a vertex the change made merges into a
  neighbour (``contract_edge``), the elements on their edge go and the others around it take
  the neighbour instead; a vertex inside the wound only together with its twin, into the
  neighbour's twin, so the lips still meet face to face; the pair is one move, judged on both
  stars together (one lip may get worse, not below the worst of both); where the lips meet at
  a vertex the cut did not duplicate (a blade's front), it merges alone into another such
  vertex. Every contraction keeps the link condition (the mesh's topology and its
  boundary's). What no move can grow, the elements between vertices a few hundredths of an
  edge apart on the wound (a plane passing close to a vertex of the boundary, which may not
  move), goes. The contracted vertices are dropped when the improvement ends
  (``TetTopology.drop_orphans``): only vertices of the change, which the change record then
  never mentions.

The measure is the smallest sine of an element's six dihedral angles (:func:`min_sine`):
small for slivers, needles and caps alike (a dihedral angle near 0 or near 180 degrees both
make the element stiff). With a smallest volume, an element below it counts as a sliver whose
sine is the target's times its share of that volume: a plane passing a tenth of an edge from
a vertex cuts off well-shaped elements of 1e-5 to 1e-3 of the median volume (every smallest
element of ten plane cuts of four meshes made by others), and smoothing that vertex away
from the plane grows them. Each move is made only if it raises the worst measure of the
elements it replaces or reshapes and leaves no sine below the target or below theirs, and no
element below half the smallest volume or below theirs (:data:`SMALL_SHARE`), so the worst
element never gets worse, growing an element never makes a sliver and mending a sliver never
makes a small element; every move keeps
the rest volume, the outer boundary and the cut surface (a bent one within its band): a flip
of a boundary edge only where its boundary faces are coplanar, no flip removes an edge or a
face whose vertices are all on the cut surface or all under a progressive blade, nor an edge
of a wound's lip (:func:`_flip_lock`; an edge between vertices of earlier wounds through the
body may flip: on a chain of three cuts through a poor beam, locking those left a sliver of
1.4 degrees spanning two wounds). The caller keeps the sides of the cut apart: the cutter
refuses a smoothing move that ends within the surface's tolerance or crosses it, and a flip
that makes an element with an edge across it (without either, half of the organ's plane cuts
at epsilon 0 were left joined). In a deformed body (current positions not the rest ones) a
move must also leave its elements valid where the body is now, none compressed or stretched
more than 10% beyond the elements it came from before the improvement, however many moves
made it (:func:`~wcut.topology.operators.check_current`): the current positions follow the
rest moves by interpolation, and unchecked that inverted elements there (with the 10% per
move, many moves compressed elements by a third within one cut event of the S-example).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..mesh import tet_volumes
from .mesh import TetTopology, TopologyError, face_key
from .operators import (apply_contraction, boundary_plane_count, check_contraction, check_current, check_vertex_move,
                        flip23, move_vertex, remove_edge, replaced_volumes)

#: Elements whose smallest dihedral angle is below this (degrees) are improved.
TARGET_ANGLE = 6.0

#: Elements whose rest volume is below this fraction of the mesh's median are improved (by
#: :class:`wcut.cut.Cutter`, which passes the volume).
MIN_VOLUME_FRACTION = 2.0e-3

#: A move never makes an element smaller than this share of the smallest volume the
#: improvement aims for (``min_volume``), unless one it replaces is smaller: mending a sliver
#: never makes a small element (without it, on SOFA's logo, Bielser's cuts traded slivers for
#: elements of 5.6e-4 of the median).
SMALL_SHARE = 0.5

#: Passes over the elements still below the target, until one makes no move (each pass may
#: create new poor neighbours, and retries only elements whose neighbourhood changed). On 20
#: random Bielser plane cuts of the perturbed beam, 3 passes left 11 cuts below 5 degrees (worst
#: 3.1), 10 passes none (5.9): a cut's fans of thin elements improve over many passes.
PASSES = 20

#: A move must raise the worst measure by more than this (sines lie in [0, 1]): a smaller gain
#: is rounding, and a move made for it depends on the last bits of the positions.
MIN_GAIN = 1.0e-12

#: Smoothing tries these fractions of the step towards each candidate position.
STEPS = (1.0, 0.5, 0.25)

#: Sliding also tries moving a vertex away from its nearest neighbour on the lip by these
#: multiples of their distance.
AWAY = (1.0, 0.5)

#: Smoothing also tries the vertex moved up the gradient of its worst element's measure by
#: these multiples of that element's mean edge at the vertex (:func:`_ascent`).
ASCENT = (0.2, 0.04)

#: A vertex at the rim of the wound (with its copy), and one on the outer boundary, also move
#: along an edge by these fractions of it (towards its other end, or away from it): within a
#: flat boundary, or on a straight crease, the line where two flat surfaces meet, such a
#: move keeps them.
ALONG_EDGE = (0.5, 0.25, -0.25, -0.5)

#: The six edges of a tetrahedron, as local vertex pairs.
_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
_EDGE_TAILS, _EDGE_HEADS = np.array(_EDGES).T
#: twice the area of the face opposite corner k: |e_u x e_v| with these edges (min_sine's order)
_FACE_U, _FACE_V = np.array([3, 1, 0, 0]), np.array([4, 2, 2, 1])
#: the two faces (opposite these corners) that meet at each edge
_EDGE_FACE_A, _EDGE_FACE_B = np.array([2, 1, 1, 0, 0, 0]), np.array([3, 3, 2, 3, 2, 1])
_NEXT, _AFTER = np.array([1, 2, 0]), np.array([2, 0, 1])


@dataclass
class ImproveStats:
    """What :func:`improve` did; the worst dihedral angles (degrees) of the elements it
    looked at, before and after."""

    edge_flips: int = 0
    face_flips: int = 0
    smoothed: int = 0
    slid: int = 0
    contracted: int = 0
    worst_before: float = math.nan
    worst_after: float = math.nan


def min_sine(p0, p1, p2, p3, volume_scale: float | None = None) -> float:
    """The smallest sine of the six dihedral angles of a tetrahedron (corners as float
    triples, m): ``sin(theta_e) = 3 V l_e / (2 A_f A_g)`` at edge e between faces f and g.
    Signed as the volume (negative for an inverted element); 0.943 for the regular one. With
    ``volume_scale`` (1/m^3), at most ``volume_scale * 6 V``: the measure of the improvement
    (:func:`improve`)."""
    e01, e02, e03 = _sub(p1, p0), _sub(p2, p0), _sub(p3, p0)
    e12, e13, e23 = _sub(p2, p1), _sub(p3, p1), _sub(p3, p2)
    # twice the areas of the faces opposite corners 0..3
    f0, f1, f2, f3 = _norm(_cross(e12, e13)), _norm(_cross(e02, e03)), _norm(_cross(e01, e03)), _norm(_cross(e01, e02))
    if f0 * f1 * f2 * f3 == 0.0:
        return 0.0
    six_v = _dot(e01, _cross(e02, e03))
    # edge (i, j) joins the faces opposite its two other corners; with 6V and doubled areas F,
    # sin = 3 V l / (2 A A') = 6V l / (F F')
    pairs = ((e01, f2, f3), (e02, f1, f3), (e03, f1, f2), (e12, f0, f3), (e13, f0, f2), (e23, f0, f1))
    least = min(six_v * _norm(e) / (fa * fb) for e, fa, fb in pairs)
    return least if volume_scale is None else min(least, volume_scale * six_v)


def min_sines(corners: np.ndarray, volume_scale: float | None = None) -> np.ndarray:
    """:func:`min_sine` of many tetrahedra at once: ``corners`` (..., 4, 3) (m). The same
    arithmetic in the same order, so each value equals :func:`min_sine`'s to the last bit."""
    return _sines(corners, volume_scale)[0]


def _sines(corners: np.ndarray, volume_scale: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`min_sines` with and without ``volume_scale``, and the volume's part alone
    (``volume_scale * 6 V``; infinite without it): (measure, sine, volume measure)."""
    c = np.asarray(corners, dtype=np.float64)
    edges = c[..., _EDGE_HEADS, :] - c[..., _EDGE_TAILS, :]  # e01 e02 e03 e12 e13 e23
    doubled = _norms(_crosses(edges[..., _FACE_U, :], edges[..., _FACE_V, :]))  # F0..F3
    six_v = _dots(edges[..., 0, :], _crosses(edges[..., 1, :], edges[..., 2, :]))
    with np.errstate(divide="ignore", invalid="ignore"):
        sines = six_v[..., None] * _norms(edges) / (doubled[..., _EDGE_FACE_A] * doubled[..., _EDGE_FACE_B])
    degenerate = doubled.prod(axis=-1) == 0.0
    least = np.where(degenerate, 0.0, sines.min(axis=-1))
    if volume_scale is None:
        return least, least, np.full_like(least, np.inf)
    small = np.where(degenerate, 0.0, volume_scale * six_v)
    return np.minimum(least, small), least, small


def _volume_scale(target: float, min_volume: float) -> float | None:
    """The ``volume_scale`` (1/m^3) of :func:`min_sine` that counts an element of volume V
    below ``min_volume`` (m^3) as a sliver of sine ``sin(target) V / min_volume`` (``target``
    in degrees); None for ``min_volume`` 0 (the sine alone)."""
    return math.sin(math.radians(target)) / (6.0 * min_volume) if min_volume > 0.0 else None


def improve(topo: TetTopology, elements, frozen: set[int], *, target: float = TARGET_ANGLE,
            min_volume: float = 0.0, twins: dict[int, int] | None = None, pinned=frozenset(), may_move=None,
            may_bend=None, may_make=None, contract: bool = False, on_surface=None) -> ImproveStats:
    """Improve live elements ``elements`` (slots) whose smallest dihedral angle is below
    ``target`` (degrees) or whose rest volume is below ``min_volume`` (m^3), and what the
    moves make. ``frozen``: vertices that must not move alone (the cut surface). ``twins``: the
    copy on the other lip of each vertex inside the wound (both ways; a vertex the cut did not
    duplicate, where its lips meet at a blade's front, maps to itself), for sliding and
    contracting. ``pinned``: vertices that may move but between which no edge or face flips,
    and whose elements no contraction removes or reshapes, but for one of a vertex that is its
    own twin, which spares only the elements all of whose vertices are pinned (those of a
    progressive cut's elements still under the blade: flipping them made the two lips of a
    curved wound differ in their triangulation once the blade had passed); an edge from one
    of them to a vertex of ``on_surface`` may flip (:func:`_flip_lock`).
    ``may_move(vertices, parents, weights)``: per move of ``vertices[i]`` to the combination
    ``parents[i]``, ``weights[i]``, whether smoothing may make it (a boolean array; the cutter
    refuses a move onto or across the cut surface, which would join the sides);
    ``may_bend(vertices, parents, weights)``: the same for a slide of a vertex inside the wound
    off the planes of its lips' faces, whose fan is bent (without it, such a vertex slides only
    within a flat fan; the cutter allows a slide that ends no farther from the cut surface than
    the farthest vertex of the fan, ``parents[i]``);
    ``may_make(tets, replaced)``: whether a flip or a contraction may make these elements
    (vertex lists) in place of the live slots ``replaced`` (the cutter refuses one with an edge
    across the cut surface that ``replaced`` do not have). ``contract``: contract edges
    too, merging a vertex made in the change being recorded (``topo.begin_change``) into a
    neighbour; the caller drops the vertices left without elements (``topo.drop_orphans``).
    ``on_surface``: the vertices on the cut surface, between which no edge or face flips (a
    face of the surface the cut has not opened yet, or an edge on it); ``frozen`` by default.
    Those of an earlier wound are not among them: an edge between two of its lips' vertices
    through the body may flip, while one on a lip (a boundary edge between two ``frozen``
    vertices) stays, as the lip's twin does."""
    stats = ImproveStats()
    locked = _flip_lock(topo, set(frozen if on_surface is None else on_surface), set(pinned), frozen)
    goal = math.sin(math.radians(target))
    sine = _Sines(topo, goal, _volume_scale(target, min_volume))
    # a deformed body: every move keeps its elements valid in the current configuration too
    sine.current = not np.array_equal(topo.positions, topo.rest_positions)
    accept = _better(sine, may_make)
    work = [t for t in elements if topo.alive[t]]
    if not work:
        return stats
    values = sine.prime(work)
    stats.worst_before = _worst_degrees(topo, work)
    # only a move changes an element's sine, and a move reports every element it makes or
    # reshapes: the poor elements are those of the input and of the moves
    poor = {t for t, q in zip(work, values.tolist()) if q < goal}
    # Every move's outcome depends only on the elements around the element tried: one that
    # failed is tried again only once a move made or reshaped an element at one of its vertices
    # (or their twins'). The same moves, without the attempts bound to fail: on the poor beam's
    # chains of five cuts (tests/test_cut.py), 41.2 s of cutting became 38.2.
    moves = 0
    moved_at: dict[int, int] = {}  # vertex -> the count of moves when one last reached it
    failed_at: dict[int, int] = {}  # element -> the count of moves when it last failed
    for _ in range(PASSES):
        queue = sorted((sine(t), t) for t in poor if topo.alive[t])
        poor = {t for q, t in queue if q < goal}
        if not poor:
            break
        changed = False
        for _, t in queue:
            if not topo.alive[t] or sine(t) >= goal:
                continue
            if t in failed_at and all(moved_at.get(v, -1) < failed_at[t] for v in topo.tets[t].tolist()):
                continue
            made = (twins and _slide(topo, t, twins, pinned, sine, stats, may_bend)) \
                or _flip_edges(topo, t, locked, accept, stats) or _flip_faces(topo, t, locked, accept, stats) \
                or _smooth(topo, t, frozen, sine, stats, may_move) \
                or _smooth(topo, t, frozen, sine, stats, may_move, candidates=_ascent_candidates) \
                or (contract and _contract(topo, t, frozen, twins or {}, pinned, accept, stats))
            if made:
                moves += 1
                if sine.current:  # what the move made keeps the range of what it replaced
                    sine.spans.update((m, sine.last_span) for m in made)
                for v in set(topo.tets[made].ravel().tolist()):
                    moved_at[v] = moves
                    if twins and v in twins:
                        moved_at[twins[v]] = moves
                work += made
                poor.update(m for m, q in zip(made, sine.prime(made).tolist()) if q < goal)
                changed = True
            else:
                failed_at[t] = moves
        if not changed:
            break
    live = [t for t in set(work) if topo.alive[t]]
    stats.worst_after = _worst_degrees(topo, live) if live else math.nan
    return stats


def has_poor(topo: TetTopology, elements, target: float = TARGET_ANGLE, min_volume: float = 0.0) -> bool:
    """Whether one of live elements ``elements`` (slots) has a dihedral angle below ``target``
    (degrees) or a volume below ``min_volume`` (m^3): whether :func:`improve` has anything to do
    (a caller may skip setting it up)."""
    slots = np.fromiter(elements, np.int64)
    corners = topo.rest_positions[topo.tets[slots]]
    return len(slots) > 0 and float(min_sines(corners, _volume_scale(target, min_volume)).min()) < \
        math.sin(math.radians(target))


class _Sines:
    """The measure of live element slots (:func:`min_sine` with ``volume_scale``, rest
    configuration), remembered. The caller primes what each move makes or reshapes (moves
    report every such element), so a remembered value is always the element's current one.

    A move must raise the worst measure of what it replaces and keep the worst sine, and the
    worst volume measure, above ``goal`` or above what it was (:meth:`floor`): growing a small
    element never makes a sliver, and mending a sliver never makes a small element.
    """

    def __init__(self, topo: TetTopology, goal: float, volume_scale: float | None = None):
        self.topo = topo
        self.goal = goal
        self.volume_scale = volume_scale
        self.known: dict[int, float] = {}
        self.known_sines: dict[int, float] = {}  # the sines alone, where volume_scale is given
        self.known_smalls: dict[int, float] = {}  # and the volume measures alone
        self.current = False  # whether moves are checked in the current configuration too
        # per slot, the (lowest, highest) ratio of current to rest volume of the elements it
        # came from before this improvement (its own where no move made it): the range a move
        # must keep within, so that the check's slack does not compound over many moves
        self.spans: dict[int, tuple[float, float]] = {}
        self.last_span: tuple[float, float] | None = None  # that of the last move allowed

    def __call__(self, t: int) -> float:
        return self._remembered(self.known, t, self.volume_scale)

    def _remembered(self, known: dict[int, float], t: int, volume_scale: float | None) -> float:
        """Element t's :func:`min_sine` with ``volume_scale``, from ``known`` or computed there."""
        q = known.get(t)
        if q is None:
            rest = self.topo.rest_tuples
            q = known[t] = min_sine(*[rest[v] for v in self.topo.tets[t].tolist()], volume_scale)
        return q

    def prime(self, slots) -> np.ndarray:
        """The sines of live element slots ``slots``, computed at once and remembered."""
        values, sines, smalls = _sines(self.topo.rest_positions[self.topo.tets[slots]], self.volume_scale)
        self.known.update(zip(slots, values.tolist()))
        if self.volume_scale is not None:
            self.known_sines.update(zip(slots, sines.tolist()))
            self.known_smalls.update(zip(slots, smalls.tolist()))
        return values

    def span(self, slots) -> tuple[float, float]:
        """The (lowest, highest) :attr:`spans` of live element slots ``slots``."""
        unknown = [t for t in slots if t not in self.spans]
        if unknown:
            index = self.topo.tets[unknown]
            ratio = tet_volumes(self.topo.positions, index) / tet_volumes(self.topo.rest_positions, index)
            self.spans.update((t, (r, r)) for t, r in zip(unknown, ratio.tolist()))
        spans = [self.spans[t] for t in slots]
        return min(lo for lo, _ in spans), max(hi for _, hi in spans)

    def of(self, tets) -> tuple[float, float, float]:
        """The worst measure, sine and volume measure of elements ``tets`` (vertex lists)."""
        measure, sine, small = _sines(self.topo.rest_positions[np.asarray(tets)], self.volume_scale)
        return float(measure.min()), float(sine.min()), float(small.min())

    def floor(self, slots) -> tuple[float, float]:
        """The worst sine and the worst volume measure a move that replaces or reshapes live
        elements ``slots`` may leave: theirs, or where theirs is above, ``goal`` (for the volume
        measure :data:`SMALL_SHARE` of it)."""
        if self.volume_scale is None:
            return -math.inf, -math.inf
        sines = [self._remembered(self.known_sines, t, None) for t in slots]
        smalls = [self._small(t) for t in slots]
        return min([self.goal] + sines), min([SMALL_SHARE * self.goal] + smalls)

    def _small(self, t: int) -> float:
        """Element t's volume measure (``volume_scale * 6 V``), remembered."""
        q = self.known_smalls.get(t)
        if q is None:
            q = self.known_smalls[t] = self.volume_scale * 6.0 * self.topo.rest_volume(t)
        return q


def _better(sine: _Sines, may_make=None):
    """An ``accept`` for the flips and contractions: the new elements' worst measure exceeds
    the removed ones', their worst sine and worst volume measure stay above
    :meth:`_Sines.floor`, and ``may_make`` (if given) allows them in place of the removed."""
    def accept(removed, added) -> bool:
        measure, least, small = sine.of(added)
        floor, small_floor = sine.floor(removed)
        return measure > min(sine(t) for t in removed) + MIN_GAIN and least >= floor and small >= small_floor and \
            (may_make is None or may_make(added, removed)) and (not sine.current or _valid_now(sine, removed, added))
    return accept


def _valid_now(sine: _Sines, removed, added) -> bool:
    """Whether elements ``added`` (vertex lists) may replace live slots ``removed`` in the
    current configuration (:func:`check_current`, within the span of ``removed``)."""
    span = sine.span(removed)
    try:
        check_current(sine.topo, None, added, "a move", span=span)
    except TopologyError:
        return False
    sine.last_span = span
    return True


def _flip_lock(topo: TetTopology, on_surface: set[int], pinned: set[int], frozen: set[int]):
    """Whether the edge or face of vertices ``vs`` must not flip: it lies on the cut surface (an
    edge on it, or a face the cut has not opened yet), its vertices are all pinned (under the
    blade), or it is a boundary edge between two frozen vertices (an edge of a wound's lip,
    whose flip would triangulate that lip otherwise than its twin's). An edge from a vertex on
    the surface to one under the blade may flip: at a blade's exit through a curved boundary,
    that flip alone lifts the worst angle above 5 degrees (organ_cut: 4.28 -> 6.01). It also
    reshapes what the blade's next increment cuts: on thesis figure 5.11's beam at epsilon 0.1
    the last step then ends at 6.8 degrees instead of 9.0 (``tools/README.md``)."""
    def locked(vs) -> bool:
        if all(v in on_surface for v in vs) or all(v in pinned for v in vs):
            return True
        return len(vs) == 2 and vs[0] in frozen and vs[1] in frozen and topo.is_boundary_edge(*vs)
    return locked


def _flip_edges(topo: TetTopology, t: int, locked, accept, stats: ImproveStats) -> list[int]:
    """A general flip of one of element t's edges that raises the worst sine of its ring and
    that ``locked`` (:func:`_flip_lock`) allows."""
    tet = topo.tet(t)
    for i, j in _EDGES:
        a, b = tet[i], tet[j]
        if locked((a, b)):
            continue
        try:
            made = remove_edge(topo, a, b, accept=accept, link_faces=False)
        except TopologyError:
            continue
        stats.edge_flips += 1
        return made
    return []


def _flip_faces(topo: TetTopology, t: int, locked, accept, stats: ImproveStats) -> list[int]:
    """A 2-3 flip of one of element t's faces that raises the worst sine of the pair and that
    ``locked`` (:func:`_flip_lock`) allows."""
    tet = topo.tet(t)
    for k in range(4):
        key = face_key(*[tet[m] for m in range(4) if m != k])
        if locked(key):
            continue
        if key in topo.unsewn or topo.face_owner_count(*key) != 2:
            continue
        try:
            made = flip23(topo, key, accept=accept, link_faces=False)
        except TopologyError:
            continue
        stats.face_flips += 1
        return made
    return []


def _smooth(topo: TetTopology, t: int, frozen: set[int], sine: _Sines, stats: ImproveStats, may_move=None,
            candidates=None) -> list[int]:
    """Move one vertex of element t to where the worst sine of its star rises most (the best
    move that ``move_vertex`` accepts) among those ``candidates`` gives (:func:`_candidates`
    by default)."""
    candidates = candidates or _candidates
    rest = topo.rest_positions
    moves = []
    for v in topo.tet(t):
        if v in frozen:
            continue
        star = sorted(topo.vertex_tets[v])
        now, (floor, small_floor) = min(sine(s) for s in star), sine.floor(star)
        tried = [_merge([v] + parents, [1.0 - step] + [step * x for x in weights])
                 for parents, weights in candidates(topo, v, star, sine) for step in STEPS]
        if not tried:
            continue
        targets = np.array([np.asarray(w) @ rest[full] for full, w in tried])
        for q, least, small, (full, w) in zip(*_star_sines(sine, star, (v,), targets), tried):
            if q > now + MIN_GAIN and least >= floor and small >= small_floor:
                moves.append((q - now, v, full, w))
    moves.sort(key=lambda m: -m[0])
    if may_move is not None and moves:  # asked at once: one query of the cut surface
        _, vertices, parents, weights = zip(*moves)
        moves = [m for m, ok in zip(moves, may_move(vertices, parents, weights)) if ok]
    for _, v, parents, weights in moves:
        span = sine.span(sorted(topo.vertex_tets[v])) if sine.current else False
        try:
            move_vertex(topo, v, parents, weights, current=span)
        except TopologyError:
            continue
        stats.smoothed += 1
        sine.last_span = span or None
        return sorted(topo.vertex_tets[v])
    return []


def _contract(topo: TetTopology, t: int, frozen: set[int], twins: dict[int, int], pinned, accept,
              stats: ImproveStats) -> list[int]:
    """Contract one of element t's edges, shortest first, merging a vertex the change made
    into the other end (``contract_edge``), where that raises the worst measure around it: a
    frozen vertex only inside the wound (its copy on the other lip merges into the other
    end's copy, so the lips still meet; the two contractions are judged as one move, and where
    the lips are bent, :func:`_bent_contraction` checks them) or, where it is its own twin (the
    lips meet there, at a blade's front), into another such vertex alone. None removes or
    reshapes an element with a pinned vertex, but that one at the front, whose elements next
    to those the blade is still in may go (most elements a blade leaves below 5 degrees are
    there); it spares the elements of pinned vertices only. (Other contractions there changed
    what the blade's next increments cut: on the AR S-example, the worst cut event of Bielser's
    method at epsilon 0.1 fell from 3.5 to 1.2 degrees.)"""
    first = topo.first_new_vertex
    tet = topo.tet(t)
    rest = topo.rest_tuples
    edges = sorted(((tet[i], tet[j]) for i, j in _EDGES), key=lambda e: _norm(_sub(rest[e[0]], rest[e[1]])))
    for a, b in edges:
        for u, w in ((a, b), (b, a)):
            if u < first or u in pinned or (u in frozen and (u not in twins or not topo.boundary_faces_at(u))):
                continue
            alone = twins.get(u) == u  # (where the lips meet: a blade's front)
            if alone and twins.get(w) != w:
                continue  # (into a vertex with a copy, one lip would take the other's faces)
            pairs = [(u, w)]
            if twins.get(u, u) != u:  # and its copy on the other lip, made by the change too
                if w not in twins or twins[u] < first:
                    continue
                pairs.append((twins[u], twins[w]))
            if pinned and any((pinned.issuperset(topo.tets[s].tolist()) if alone
                               else not pinned.isdisjoint(topo.tets[s].tolist()))
                              for u_, _ in pairs for s in topo.vertex_tets[u_]):
                continue
            try:  # the two copies' contractions as one move: judged on both stars at once
                checked = [check_contraction(topo, u_, w_, accept=None if len(pairs) > 1 else accept)
                           for u_, w_ in pairs]
            except TopologyError:
                if len(pairs) == 1:
                    continue
                checked = _bent_contraction(topo, pairs, twins)
                if checked is None:
                    continue
            if len(pairs) > 1 and not accept([s for c in checked for s in c[0]], [a for c in checked for a in c[1]]):
                continue
            made = []
            for each in checked:
                made += apply_contraction(topo, each, link_faces=False)
            stats.contracted += len(pairs)
            return made
    return []


def _bent_contraction(topo: TetTopology, pairs: list, twins: dict[int, int]):
    """The two copies' contractions ``pairs`` where their lips are not flat (a wound bent
    through a held vertex, whose copies the plane check of ``check_contraction`` refuses):
    each lip moves as its copy does, so the two sides change their volumes by opposite amounts;
    the rest of each vertex's boundary (the outer boundary, at the wound's rim) must keep its
    planes. None where that fails or the total volume changes. (A split point of a face of the
    organ's curved boundary, 0.05 edges from a crossing at the rim, merges into it: the worst
    of 20 random Bielser cuts rises from 3.79 to 4.76 degrees.)"""
    checked = []
    for u, w in pairs:
        lips = _lip_faces(topo, u, twins[u], twins)
        try:
            checked.append(check_contraction(topo, u, w, lips=lips))
        except TopologyError:
            return None
    before, after = replaced_volumes(topo, [t for star, _, _ in checked for t in star],
                                     [tet for _, added, _ in checked for tet in added])
    return checked if abs(after - before) <= 1e-12 * before else None


def _lip_faces(topo: TetTopology, v: int, w: int, twins: dict[int, int]) -> set:
    """The boundary faces at v (sorted vertex triples) whose copy is a boundary face at w
    (:func:`_copies`): v's part of the wound's lips."""
    theirs = _faces_at(topo, w)
    return {face for face, copy in _copies(topo, v, w, twins).items() if copy in theirs}


def _faces_at(topo: TetTopology, v: int) -> set:
    """The boundary faces at v (sorted vertex triples)."""
    return {tuple(sorted(face)) for face in topo.boundary_faces_at(v)}


def _copies(topo: TetTopology, v: int, w: int, twins: dict[int, int]) -> dict:
    """Each boundary face at v and its copy, with v as w and each other vertex as its twin
    (sorted vertex triples)."""
    return {tuple(sorted(face)): tuple(sorted(w if u == v else twins.get(u, u) for u in face))
            for face in topo.boundary_faces_at(v)}


def _slide(topo: TetTopology, t: int, twins: dict[int, int], pinned, sine: _Sines, stats: ImproveStats,
           may_bend=None) -> list[int]:
    """Move a vertex of element t inside the wound and its twin on the other lip together,
    towards the centroid of its neighbours on its lip (the twins of those on the other), or a
    vertex at the rim with its twin along an edge both lips share (:data:`ALONG_EDGE`), to where
    the worst sine of both stars rises most; both moves must be ones ``move_vertex`` accepts:
    within the flat fans of the lips (and, at the rim, of the outer boundary), or, for a vertex
    whose every boundary face is a lip's (:func:`_inside_wound`), off their planes where
    ``may_bend`` allows it."""
    rest = topo.rest_tuples
    moves = []
    for v in topo.tet(t):
        w = twins.get(v, v)
        if w == v or v in pinned or w in pinned:
            continue
        on_lip = _boundary_neighbours(topo, v)
        lip = [u for u in {u for s in topo.vertex_tets[v] for u in topo.tets[s].tolist()} - {v} if u in on_lip]
        mirrored = [twins.get(u, u) for u in lip]
        theirs = _boundary_neighbours(topo, w)
        if not lip:
            continue
        if theirs.issuperset(mirrored):  # inside the wound: towards the centroid, or away
            nearest = min(range(len(lip)), key=lambda i: _norm(_sub(rest[lip[i]], rest[v])))
            targets = [[1.0 - step] + [step / len(lip)] * len(lip) for step in STEPS]
            targets += [_along(len(lip), nearest, -a) for a in AWAY]  # from the nearest neighbour
        else:  # at the rim, where the wound meets the outer boundary: along an edge both lips share
            shared = [i for i, u in enumerate(mirrored) if u in theirs]
            lip, mirrored = [lip[i] for i in shared], [mirrored[i] for i in shared]
            targets = _rim_targets(len(lip))
        if not targets:
            continue  # the lips' fans around v and w share no edge (they do not match)
        bends = may_bend is not None and _inside_wound(topo, v, w, twins)
        star = sorted(topo.vertex_tets[v] | topo.vertex_tets[w])
        now, (floor, small_floor) = min(sine(s) for s in star), sine.floor(star)
        points = np.array(targets) @ topo.rest_positions[[v] + lip]
        for q, least, small, weights in zip(*_star_sines(sine, star, (v, w), points), targets):
            if q > now + MIN_GAIN and least >= floor and small >= small_floor:
                moves.append((q - now, v, w, lip, mirrored, weights, bends))
    moves.sort(key=lambda m: -m[0])
    bent = [i for i, m in enumerate(moves) if m[6]]
    if bent:  # asked at once: one query of the cut surface
        allowed = may_bend([moves[i][1] for i in bent], [[moves[i][1]] + moves[i][3] for i in bent],
                           [moves[i][5] for i in bent])
        refused = {i for i, ok in zip(bent, allowed) if not ok}
        moves = [m for i, m in enumerate(moves) if i not in refused]
    for _, v, w, lip, mirrored, weights, bends in moves:
        span = sine.span(sorted(topo.vertex_tets[v] | topo.vertex_tets[w])) if sine.current else False
        try:  # both checked before either moves (w's star does not hold v: the checks stand)
            checked = (check_vertex_move(topo, v, [v] + lip, weights, keep_boundary=not bends, current=span),
                       check_vertex_move(topo, w, [w] + mirrored, weights, keep_boundary=not bends, current=span))
        except TopologyError:
            continue
        topo.set_vertex(v, [v] + lip, checked[0])
        topo.set_vertex(w, [w] + mirrored, checked[1])
        stats.slid += 1
        sine.last_span = span or None
        return sorted(topo.vertex_tets[v] | topo.vertex_tets[w])
    return []


def _rim_targets(count: int) -> list[list[float]]:
    """Weights over a vertex at the wound's rim and its ``count`` neighbours along edges both
    lips share: the vertex moved along each edge by the fractions :data:`ALONG_EDGE`."""
    return [_along(count, i, f) for i in range(count) for f in ALONG_EDGE]


def _along(count: int, i: int, f: float) -> list[float]:
    """Weights over a vertex and its ``count`` neighbours of the vertex moved by ``f`` times
    its edge towards neighbour i (away from it for ``f`` < 0)."""
    weights = [1.0 - f] + [0.0] * count
    weights[1 + i] = f
    return weights


def _inside_wound(topo: TetTopology, v: int, w: int, twins: dict[int, int]) -> bool:
    """Whether the boundary faces at v and at w are copies of each other (a face at v, with v
    as w and each other vertex as its twin, is one at w, and w has no other): every one is a
    lip of the wound. Then neither is on the outer boundary, and v and w moving together keep
    the lips meeting face to face and the volume, whatever the shape of their fans (a face at w
    alone, of a small cavity inside SOFA's ossicles, moved with w and changed the volume)."""
    return set(_copies(topo, v, w, twins).values()) == _faces_at(topo, w)


def _star_sines(sine: _Sines, star: list[int], moved, targets: np.ndarray) -> tuple[list, list, list]:
    """The worst measure, sine and volume measure of elements ``star`` with vertices ``moved``
    at each of ``targets`` (K, 3) (rest configuration, m): three lists of K."""
    tets = sine.topo.tets[star]
    corners = np.repeat(sine.topo.rest_positions[tets][None], len(targets), axis=0)  # (K, S, 4, 3)
    at = np.isin(tets, moved)
    corners[:, at] = targets[:, None]
    measure, least, small = _sines(corners, sine.volume_scale)
    return measure.min(axis=1).tolist(), least.min(axis=1).tolist(), small.min(axis=1).tolist()


def _candidates(topo: TetTopology, v: int, star: list[int], sine: _Sines):
    """Target positions of vertex v as combinations (parents, weights summing to 1) of
    vertices: the centroid of its neighbours (of its boundary neighbours for a boundary
    vertex, which keeps it in a flat boundary's plane, and, within that plane or on a crease
    of two planes, along each edge to one of them by :data:`ALONG_EDGE`) and, inside, v
    pushed away from the face opposite it in its worst element by a quarter of its distance
    from that face's centroid, and lifted off that face's plane (:func:`_lifted`)."""
    on_boundary = _boundary_neighbours(topo, v)
    boundary = bool(on_boundary)
    neighbours = sorted({u for s in star for u in topo.tets[s].tolist()} - {v})
    if boundary:
        neighbours = [u for u in neighbours if u in on_boundary]
    if neighbours:
        yield neighbours, [1.0 / len(neighbours)] * len(neighbours)
    if boundary:
        # along its boundary edges, within a flat boundary or on a crease (on 8 blades
        # through the perturbed beam in 30 increments, the worst angle rises from 1.7 to 2.3)
        if boundary_plane_count(topo, v) <= 2:
            for u in neighbours:
                for f in ALONG_EDGE:
                    yield [v, u], [1.0 - f, f]
        return
    face = _opposite_face(topo, v, star, sine)
    yield [v] + face, [1.25] + [-0.25 / 3.0] * 3
    lifted = _lifted(topo.rest_positions[[v] + face])
    if lifted is not None:
        yield [v] + face, lifted


def _ascent_candidates(topo: TetTopology, v: int, star: list[int], sine: _Sines):
    """:func:`_candidates` where none of those helps: an inner vertex v moved up the gradient
    of its worst element's measure (:func:`_ascent`)."""
    if _boundary_neighbours(topo, v):
        return
    face = _opposite_face(topo, v, star, sine)
    for weights in _ascent(topo.rest_positions[[v] + face], sine.volume_scale):
        yield [v] + face, weights


def _opposite_face(topo: TetTopology, v: int, star: list[int], sine: _Sines) -> list[int]:
    """The vertices of the face opposite v in the worst element of its star (slots)."""
    worst = min(star, key=sine)
    return [u for u in topo.tets[worst].tolist() if u != v]


def _ascent(corners: np.ndarray, volume_scale: float | None) -> list[list[float]]:
    """Weights (of the corners (4, 3), vertex first) of the vertex moved up the gradient of the
    element's measure (:func:`min_sine` with ``volume_scale``) by each of :data:`ASCENT` times
    its mean edge: the steepest ascent of Klingner and Shewchuk's smoothing for the worst
    element, which finds the way out of a wedge whose small angle lies at an edge through the
    vertex, where the centroid, the push and the lift all lower it. Empty where the gradient
    vanishes."""
    edge = float(np.linalg.norm(corners[1:] - corners[0], axis=1).mean())
    delta = 1e-7 * edge
    probes = np.repeat(corners[None], 4, axis=0)
    probes[1:, 0] += delta * np.eye(3)
    measure = _sines(probes, volume_scale)[0]
    gradient = (measure[1:] - measure[0]) / delta
    length = float(np.linalg.norm(gradient))
    frame = (corners[1:] - corners[0]).T
    if not length > 0.0 or not np.isfinite(length) or np.linalg.det(frame) == 0.0:
        return []
    local = np.linalg.solve(frame, np.outer(gradient / length, np.multiply(ASCENT, edge)))  # (3, K)
    return [[1.0 - float(column.sum())] + column.tolist() for column in local.T]


def _lifted(corners: np.ndarray) -> list[float] | None:
    """Weights (of the corners (4, 3), vertex first) of the vertex moved along the normal of
    the opposite face to the height of a regular element on that face (its mean edge): a cap,
    whose vertex lies near the plane of the face but beside it, is lifted off the plane, where
    pushing the vertex from the face's centroid only slides it along. None where the vertex is
    that high already."""
    a, b, c = corners[1:]
    normal = np.cross(b - a, c - a)
    area2 = float(np.linalg.norm(normal))
    if area2 == 0.0:
        return None
    normal /= area2
    height = float(normal @ (corners[0] - a))
    if height < 0.0:
        normal, height = -normal, -height
    edge = (np.linalg.norm(b - a) + np.linalg.norm(c - b) + np.linalg.norm(a - c)) / 3.0
    rise = math.sqrt(2.0 / 3.0) * edge - height
    if rise <= 0.0:
        return None
    # the step in the barycentric coordinates of the element: [a-v, b-v, c-v] l = rise * normal
    local = np.linalg.solve((corners[1:] - corners[0]).T, rise * normal)
    return [1.0 - float(local.sum())] + local.tolist()


def _boundary_neighbours(topo: TetTopology, v: int) -> set[int]:
    """The vertices joined to v by an edge of a boundary face (``TetTopology.is_boundary_edge``
    for all v's edges at once)."""
    found = {u for face in topo.boundary_faces_at(v) for u in face}
    found.discard(v)
    return found


def _merge(parents: list[int], weights: list[float]) -> tuple[list[int], list[float]]:
    """Parents without repeats (their weights summed), the weights renormalised to sum to 1."""
    merged: dict[int, float] = {}
    for u, w in zip(parents, weights):
        merged[u] = merged.get(u, 0.0) + w
    total = sum(merged.values())
    return list(merged), [w / total for w in merged.values()]


def _worst_degrees(topo: TetTopology, slots: list[int]) -> float:
    """The smallest dihedral angle (degrees) of live elements ``slots`` (rest configuration)."""
    sine = float(min_sines(topo.rest_positions[topo.tets[slots]]).min())
    return math.degrees(math.asin(max(-1.0, min(1.0, sine))))


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(a) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _crosses(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products along the last axis (a faster np.cross for small arrays, the same bits)."""
    return a[..., _NEXT] * b[..., _AFTER] - a[..., _AFTER] * b[..., _NEXT]


def _dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _norms(a: np.ndarray) -> np.ndarray:
    return np.sqrt(a[..., 0] * a[..., 0] + a[..., 1] * a[..., 1] + a[..., 2] * a[..., 2])
