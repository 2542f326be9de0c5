"""The remeshing cutter of thesis chapter 5, and its baselines behind the same interface.

:class:`Cutter` inserts a separation surface into a :class:`~wcut.topology.TetTopology` and
disconnects the mesh along it. The surface is intersected with the edges in the current
configuration; every vertex it creates is a barycentric combination of the vertices of the
element or edge it lies in, so the rest configuration follows exactly (thesis 3.2).

The ``paulus`` method (thesis 5.1):

1. *sampling* (5.1.1): each edge crossing the surface gets its crossing point and normal;
   vertices within a tolerance of the surface are *on* it;
2. *snapping* (5.1.3): the vertex of a crossed edge nearest to the plane of the crossing
   (point, normal) moves onto the crossing when its distance is below ``epsilon`` times the
   mean rest edge length and the move keeps every element valid;
3. *1-4 splits* (figure 5.1): each element crossed by the surface gets a vertex at the
   barycentre of its crossings (on-vertices included); an element cut only partly (one or two
   crossings, at the front of a bounded surface) uses the crossings of the surface's
   *extension* (5.1.1, 5.3), and that vertex is not on the cut;
4. *2-3 flips* (figure 5.2) of every interior face through a crossed edge; where a flip would
   invert an element the face is split at the barycentre of its crossings instead;
   *1-3 splits* (figure 5.5) of boundary faces through a crossed edge. A face that a plane
   crosses from one of its vertices to the opposite edge is not split: the cut there is the
   segment to the crossing, an edge once step 5 has split or flipped the crossed edge;
5. *general flips* (figure 5.3) of every crossed edge, which leaves triangles on the surface;
   a boundary edge is flipped only where its two boundary faces are coplanar (the volume is
   kept), else *bisected* at the crossing (5.1.2), as is any edge whose flip is refused;
6. *disconnection* (5.1.3): faces whose three vertices are on the cut, and which lie on it
   (on a plane: their centre is; on a triangulated surface: the elements they join are on
   opposite sides, by its winding number), are unsewn and every vertex on an unsewn face is
   duplicated once per fan of elements.

Baselines (thesis 5.2): ``snap`` moves the nearest vertex of every crossed edge onto the
surface, then disconnects; ``delete`` removes every crossed element; ``bielser`` is the
1:17-style subdivision of :mod:`wcut.cut.bielser`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..errors import WcutError
from ..kernels import surface_query
from ..kernels import topology as kernels
from ..mesh import TET_FACES, tet_volumes
from ..topology import (TetTopology, TopologyChange, TopologyError, bisect_edge, duplicate_vertex, face_key,
                        flip23, remove_edge, sew_unopened, split_face, split_tet, tet_qualities,
                        unsew_face)
from ..topology.improve import MIN_VOLUME_FRACTION as IMPROVE_MIN_VOLUME_FRACTION
from ..topology.improve import TARGET_ANGLE as IMPROVE_TARGET
from ..topology.improve import has_poor
from ..topology.improve import improve as improve_mesh
from ..topology.mesh import signed_volume
from ..topology.operators import boundary_plane_count, check_vertex_move
from ..topology.region import OUTSIDE, TetRegion
from .separation import IN_PLANE, element_sides
from .surface import CutSurface, Plane, TriangleSurface, _point_segment_distance, box_tree

METHODS = ("paulus", "bielser", "snap", "delete")

#: Pairs of local vertex indices of the six edges of a tetrahedron.
TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))

#: ``TET_FACES`` as tuples, for plain-Python loops.
_TET_FACES = tuple(tuple(face) for face in TET_FACES.tolist())
#: the corners of the face opposite each corner of an element (the arrays' face numbering)
_FACE_CORNERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])

#: Distance (relative to the mean rest edge length) within which a vertex is on the surface.
ON_SURFACE_TOL = 1e-6

#: A piece the cut would free with at most ``CRUMB_ELEMENTS`` elements, less than
#: ``CRUMB_VOLUME`` times the volume of a regular tetrahedron of the mean edge length, and only
#: slivers (quality below ``CRUMB_QUALITY`` times a regular tetrahedron's) stays attached: such
#: crumbs are flat elements lying in the surface, and alone they would be unstable. (A small
#: corner cut off by a plane is made of well-shaped elements: it comes off.)
CRUMB_ELEMENTS = 64
CRUMB_VOLUME = 0.5
CRUMB_QUALITY = 0.1
#: volume / longest edge^3 of the regular tetrahedron
REGULAR_QUALITY = 1.0 / (6.0 * np.sqrt(2.0))

#: A 2-3 flip or a snap must keep the worst quality of the elements it changes above this
#: fraction of what it was; else the face is split instead, or the vertex stays (either can
#: make a sliver next to a poor element).
QUALITY_DROP = 0.1


#: Triangles of S within this many face radii of a face (or distances from its centre to the
#: centroids of the elements it joins, where larger) decide whether the face separates them
#: (:meth:`Cutter._on_surface`): far enough that cutting S off there changes the jump of its
#: winding number between the two centroids by a few per cent, near enough to stay local.
WINDING_REACH = 8.0

#: Where a face lies in S, :meth:`Cutter._separate_sheets` compares S's winding numbers at
#: points this fraction of the way from the face's centre to its two elements' centroids.
NEAR_FACE = 0.05

#: :meth:`Cutter._separate_swept` leaves a vertex alone where S bends more than this (degrees)
#: within reach of its elements: a fold, which :meth:`Cutter._separate_sheets` opens.
SWEPT_BEND = 30.0

#: Snapping threshold (relative) applied even when ``epsilon`` is smaller: crossings closer
#: to a vertex than this would only make needle elements (thesis 5.1.4).
MIN_SNAP = 1e-3

#: A boundary vertex that may not snap holds the cut (:meth:`Cutter._hold`) when it is this
#: close (relative) to a crossing's plane on one of its edges, or within the snapping
#: threshold where that is smaller; with ``curved_boundary`` at this distance whatever
#: ``epsilon``.
CURVED_HOLD = 0.1

#: A boundary vertex holds the cut up to this many times the hold distance where the cut
#: would cut off one of its corners smaller than ``Cutter.least_corner`` (:meth:`Cutter._hold`).
#: Holding every boundary vertex that far made the perturbed beams' worst angles ten times
#: smaller (10 random plane cuts, Bielser: 4.0 -> 0.28 degrees).
CAP_HOLD = 2.0

#: The elements a corner cut off a vertex is split into are this many times smaller than the
#: corner, or more (the element's split point on the cut makes three of them): a corner below
#: this many times the improvement's smallest volume holds the cut (:meth:`Cutter._hold`).
#: Holding at the smallest volume alone left elements of 2.6e-4 to 9.9e-4 of the median on
#: SOFA's meshes, and 3.4e-4 on every plane cut of the organ with ``curved_boundary``; this
#: leaves 8e-4 to 2e-3, and 1.1e-3.
CORNER_PIECES = 3.0


class CutError(WcutError):
    """A cut cannot be made: unknown method, bad threshold, or a surface that misses the mesh."""


@dataclass
class CutStats:
    """Counts of one cut (elements and vertices of the mesh before it)."""

    cut_elements: int = 0
    snapped_vertices: int = 0
    split_elements: int = 0
    flips23: int = 0
    face_splits: int = 0
    general_flips: int = 0
    bisections: int = 0
    unsewn_faces: int = 0
    duplicated_vertices: int = 0
    deleted_elements: int = 0
    #: vertices where a complete cut was left joined and :meth:`Cutter._separate` (a plane) or
    #: :meth:`Cutter._separate_sheets` (a triangulated surface) split the elements around them
    #: by side
    separated_vertices: int = 0
    #: moves of the local mesh improvement after the cut (:mod:`wcut.topology.improve`)
    improved_edge_flips: int = 0
    improved_face_flips: int = 0
    #: vertices slid within the wound, counting both copies (:mod:`wcut.topology.improve`)
    slid_vertices: int = 0
    smoothed_vertices: int = 0
    #: edges contracted by the improvement, counting both copies of an edge inside the wound
    contracted_edges: int = 0
    refused: list[str] = field(default_factory=list)

    def add(self, other: "CutStats") -> None:
        for name, value in vars(other).items():
            setattr(self, name, getattr(self, name) + value)


@dataclass
class CutResult:
    change: TopologyChange
    stats: CutStats


@dataclass
class _Plan:
    """Steps 3-5 of a paulus cut (:meth:`Cutter._plan`), in the order they are applied."""

    #: elements to split 1-4: (slot, barycentric weights of the split vertex, whether it is on the cut)
    splits: list = field(default_factory=list)
    #: split vertices of earlier cuts that serve again (on the cut)
    reused: set = field(default_factory=set)
    #: faces through a crossed edge (sorted vertex triples): flipped 2-3, else split
    faces: list = field(default_factory=list)
    #: crossed edges and their crossing parameters: removed (general flip), else bisected
    edges: list = field(default_factory=list)


def _known_point(point) -> tuple[int, list[float]]:
    """The flag and reals of a face's split point (``Cutter._face_point``: None or (weights, on))
    for a ``flip_or_split_face`` operator."""
    if point is None:
        return kernels.POINT_NONE, [0.0, 0.0, 0.0, 0.0]
    return kernels.POINT_KNOWN, [*point[0].tolist(), 0.0]


class _Sampling:
    """Crossings of the surface with the edges of candidate elements (thesis 5.1.1)."""

    def __init__(self, topo: TetTopology, x: np.ndarray, surface: CutSurface, slots: np.ndarray, tol: float):
        tets = topo.tets[slots]
        pairs = np.sort(tets[:, TET_EDGES].reshape(-1, 2), axis=1)
        n = np.int64(topo.vertex_count)
        keys, inverse = np.unique(pairs[:, 0] * n + pairs[:, 1], return_inverse=True)
        edges = np.stack([keys // n, keys % n], axis=1)
        verts = np.unique(tets)
        self.on = set(verts[surface.distance(x[verts], tol) <= tol].tolist())
        t, normal = surface.crossings(x[edges[:, 0]], x[edges[:, 1]], tol)
        hit = np.isfinite(t)
        self.edges = {(a, b): (s, n) for (a, b), s, n in zip(edges[hit].tolist(), t[hit].tolist(), normal[hit])}
        self.cut_slots = slots[hit[inverse.reshape(-1)].reshape(-1, 6).any(axis=1)].tolist()


def _edge(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


class Cutter:
    """Cuts a :class:`TetTopology` with separation surfaces, one event at a time.

    Args:
        topology: the mesh to cut (edited in place).
        method: ``paulus`` (this thesis), ``bielser``, ``snap`` or ``delete``.
        epsilon: snapping threshold, a fraction of the mean rest edge length (thesis 5.1.3;
            0 disables snapping except for crossings closer than ``MIN_SNAP``).
        mean_edge_length: the length scale of ``epsilon`` (m); by default the mean rest edge
            length of the mesh when the cutter is made, kept fixed through later cuts.
        curved_boundary: the corners are those of curved (quadratic) elements whose boundary
            is not flat (thesis 6.1.2, 6.1.4): a crossed boundary edge is always bisected,
            never flipped, and no boundary vertex snaps. Either would replace boundary faces
            by others spanning several curved faces, which changes the surface and the volume.
        boundary_slide: snapping may slide a boundary vertex along a boundary edge where the
            normals of the boundary faces around it differ by less than this (degrees; the
            thesis's 5.1.2 choice is about 30), which saves a sliver at the boundary but moves
            the boundary and changes the volume (by up to some 1e-4 of it). 0, the default:
            a boundary vertex moves only within a flat boundary or along a straight crease, so
            the boundary and the rest volume stay exactly as they are; one that may not move
            holds the cut instead (:meth:`_hold`, within :attr:`hold_distance`, or twice that
            where the cut would leave a corner smaller than :attr:`least_corner`).
        compiled: insert the surface and disconnect along it (steps 3-6 of ``paulus``, step 6
            of ``snap``) with the compiled operators (``wcut.kernels.topology``) on the crossed
            elements and those around the vertices on the cut, two launches per cut, rather
            than the Python ones: the same operators in the same order, so the same mesh, but
            where two triangulations of a general flip are equally good the compiled one takes
            that of the polygon started at its smallest vertex, and where two fans of a vertex
            are equally large the copy that keeps its number may differ.
        improve: after each cut, improve the elements it made and those around them whose
            smallest dihedral angle is below 6 degrees (whatever the input mesh's worst), or
            whose rest volume is below 2e-3 of the input's median element, or below its
            smallest where that is smaller (:mod:`wcut.topology.improve`): the
            vertices inside the wound slide on it with their copies (those at the rim along a
            straight rim), the others move, edges and faces flip, and edges whose end the cut
            made contract; the cut surface (where a held boundary vertex bends it: within the
            band it spans there), the boundary, the lips' match and the volume stay as they
            are; no flip among their vertices alone, slide or contraction rearranges the
            elements a progressive blade is still in, though an edge from the cut surface to one
            of their vertices may flip and smoothing may move them (144 straight blades through
            the organ and a perturbed beam: 100 of 1469 increments leave an angle below 5
            degrees; none of organ_cut's 43 cut events). On by default; it
            costs some 2 ms per increment of ``organ_cut``'s blade and 20 ms per plane cut of
            the organ at epsilon 0.1 (``tools/cut_separation.py``). The corners of quadratic
            elements are improved only where every element is straight
            (:class:`~wcut.cut.quadratic.QuadraticCutter`).
    """

    #: the improvement may move (smooth) the vertices of the elements a progressive blade is
    #: still in; it never flips, slides or contracts them (:meth:`_improve`)
    smooths_under_blade = True

    def __init__(self, topology: TetTopology, method: str = "paulus", epsilon: float = 0.1,
                 mean_edge_length: float | None = None, curved_boundary: bool = False, boundary_slide: float = 0.0,
                 compiled: bool = True, improve: bool = True):
        if method not in METHODS:
            raise CutError(f"unknown cut method {method!r} (expected one of {', '.join(METHODS)})")
        if not (isinstance(epsilon, (int, float)) and 0.0 <= epsilon < 0.5):
            raise CutError(f"epsilon must be a number in [0, 0.5), got {epsilon!r}")
        if not (isinstance(boundary_slide, (int, float)) and 0.0 <= boundary_slide < 90.0):
            raise CutError(f"boundary_slide must be an angle in [0, 90) degrees, got {boundary_slide!r}")
        self.topology = topology
        self.method = method
        self.boundary_slide = float(boundary_slide)
        self.improve = bool(improve)
        self.epsilon = float(epsilon)
        self.curved_boundary = bool(curved_boundary)
        self.compiled = bool(compiled)
        #: the paulus insertion may flip (2-3 flips, general flips); False inserts by splits
        #: only (1-4, face splits, bisections), whose pieces each lie in one element of before
        #: (:class:`wcut.cut.quadratic.QuadraticCutter` falls back to it; Python operators only)
        self.flips = True
        if not self.compiled:
            topology.face_tets  # the Python operators walk the faces: linked now, not in the first cut
        if mean_edge_length is None:
            mean_edge_length = topology.to_mesh().mean_edge_length()
        self.mean_edge_length = float(mean_edge_length)
        #: the rest volume (m^3) below which the improvement counts an element as a sliver: a
        #: fraction of the input mesh's median element, or the input's smallest where that is
        #: smaller (its own small elements are not the cut's). Its target angle is
        #: :data:`IMPROVE_TARGET` whatever the input's worst: the elements a cut makes in a poor
        #: mesh are improved as in a good one (on SOFA's sea monster, whose worst is 0.45
        #: degrees, ten paulus cuts leave 6 new elements below 5 degrees, not 514)
        least = _improve_min_volume(topology)
        self.improve_min_volume = least if self.improve else 0.0
        #: a corner the surface would cut off a boundary vertex below this volume (m^3) holds
        #: the cut at the vertex (:meth:`_hold`): its pieces would be below ``least``
        self.least_corner = least
        self._longest = self._longest_edge()  # (m, rest; grown by the elements cuts make)
        #: vertices this cutter inserted by 1-4 splits, and their copies when a cut duplicated
        #: them: one on the surface serves again as the split vertex of its element's pieces when
        #: a later cut reaches them (thesis 5.1.1). Every copy counts: which copy keeps the
        #: number differs between the compiled and the Python disconnection.
        self.split_vertices: set[int] = set()
        #: vertices on the faces this cutter opened, and their copies: the lips of the wound
        #: coincide at rest, so snapping must not slide one of them off its plane alone
        self.wound_vertices: set[int] = set()
        #: the surface swept by the progressive cut so far: its vertices (the increments' shared
        #: vertices welded), their indices by coordinates, and its triangles per increment
        self._swept_points: list[list[float]] = []
        self._swept_index: dict[tuple[float, ...], int] = {}
        self._swept_triangles: list[np.ndarray] = []
        self._rest = False
        self._waiting_vertices: set[int] = set()  # of the elements a progressive cut leaves for later
        #: this cut event's vertices split in two by the disconnection, and their copies (both ways)
        self._split_pairs: dict[int, int] = {}
        #: vertices near a progressive cut that :meth:`_separate_swept` looks at again later
        self._unsettled: set[int] = set()

    def _longest_edge(self, slots: np.ndarray | None = None) -> float:
        """The longest rest edge (m) of the elements ``slots`` (default: all)."""
        tets = self.topology.tets[self.topology.live_tets() if slots is None else slots]
        x = self.topology.rest_positions
        return max(float(np.linalg.norm(x[tets[:, i]] - x[tets[:, j]], axis=1).max(initial=0.0)) for i, j in TET_EDGES)

    @property
    def _margin(self) -> float:
        """How far (m) from a surface a vertex of an element it crosses may lie: the longest
        edge in the rest configuration; twice that in the current one, which stretches. (Twice
        it in the rest configuration too gave a blade's late increments on the organ 2700-2900
        of its 4900 elements as candidates, against 1400-1570.)"""
        return self._longest if self._rest else 2.0 * self._longest

    # ------------------------------------------------------------------ public
    def cut(self, surface: CutSurface, bounds=None, *, progressive: bool = False, rest: bool = False) -> CutResult:
        """Insert ``surface`` (current configuration, m) and separate the mesh along it.

        Args:
            bounds: optional (lower, upper) box (m) outside which nothing is cut; the
                surface's own bounds otherwise.
            progressive: ``surface`` (a :class:`TriangleSurface`) is the part a blade swept
                since the last call with ``progressive``; the cut is along everything swept so
                far. An element is cut once the blade has passed through it: elements that the
                boundary of the swept surface (the blade's current position, the traces of its
                ends) passes through wait for a later increment. So the wound lags the blade by
                at most one element, and no element is split twice at a moving front (thesis
                5.1.1 moves a front split vertex instead; that vertex leaves the cut when the
                body deforms between increments, and the faces around it never open). The
                elements a blade adds are in proportion to the elements of the uncut mesh it
                crosses, whatever the number of increments: on a bent beam cut in 4 to 60
                increments, 1.6-8.3 per crossed element (paulus) and 6-15 (Bielser).
            rest: ``surface`` (and ``bounds``) are in the rest configuration: what a blade swept
                through a moving body, mapped there (:meth:`TetTopology.rest_points`), so
                that consecutive increments join in the material whatever the body did
                in between.

        Returns the :class:`TopologyChange` and the :class:`CutStats`. A surface that
        crosses no element gives an empty change.
        """
        topo = self.topology
        topo.begin_change()
        stats = CutStats()
        self._rest = rest
        self._waiting_vertices = set()
        self._split_pairs = {}
        try:
            if progressive:
                surface, slots = self._progressive_surface(surface, bounds)
            else:
                self._swept_points, self._swept_index, self._swept_triangles = [], {}, []
                self._unsettled = set()
                slots = self._candidates(surface, bounds)
            if self.method == "delete":
                self._delete(surface, slots, stats)
            elif self.method == "bielser":
                from .bielser import bielser_cut

                bielser_cut(self, surface, slots, stats)
            else:
                self._remesh(surface, slots, stats)
            improves = self.improve and self.flips and self.method != "delete"
            if improves:
                self._improve(surface, stats)
            if self.method != "delete" and isinstance(surface, TriangleSurface):
                self._separate_sheets(surface, stats)  # (after the improvement, as for a plane)
                self._separate_swept(surface, stats)
            if self.method != "delete" and type(surface) is Plane and bounds is None and not progressive:
                # (after the improvement: what a move joined, it splits; where it split, the
                # improvement goes on with the copies as twins, and what that joins is split)
                separated = self._separate(surface, stats)
                if separated and improves:
                    self._improve(surface, stats, near=separated)
                    self._separate(surface, stats)
        finally:
            change = topo.end_change()
        changed = change.rest_changed_elements()
        if len(changed):  # (a flip may join vertices farther apart than any edge before)
            self._longest = max(self._longest, self._longest_edge(topo.live_tets()[changed]))
        return CutResult(change, stats)

    # ---------------------------------------------------------------- helpers
    def coordinates(self) -> np.ndarray:
        """(N, 3) vertex positions (m) in the configuration of the cut being made (a view)."""
        return self.topology.rest_positions if self._rest else self.topology.positions

    @property
    def tolerance(self) -> float:
        """Distance (m) within which a vertex is on the surface."""
        return ON_SURFACE_TOL * self.mean_edge_length

    @property
    def hold_distance(self) -> float:
        """Distance (relative to the mean edge length) within which a boundary vertex that may
        not snap holds the cut (:meth:`_hold`): :data:`CURVED_HOLD`, or the snapping threshold
        where that is smaller (``epsilon``, at least :data:`MIN_SNAP`)."""
        if self.curved_boundary or self.method == "snap":
            return CURVED_HOLD
        return min(max(self.epsilon, MIN_SNAP), CURVED_HOLD)

    @property
    def wound_band(self) -> float:
        """Distance (m) from the surface within which a cut bent through held vertices
        (:meth:`_hold`, up to :data:`CAP_HOLD` times :attr:`hold_distance`) stays."""
        return CAP_HOLD * self.hold_distance * self.mean_edge_length + self.tolerance

    @property
    def in_plane(self) -> float:
        """Distance (relative to the mean edge length) within which an element lies in a cut
        plane, when a complete cut is checked (:mod:`wcut.cut.separation`): the distance at
        which it holds boundary vertices off the plane (:attr:`hold_distance`). Elements
        around a vertex held farther (a small corner's, :meth:`_hold`) that still reach across
        are split along their faces by :meth:`_separate`."""
        return max(IN_PLANE, self.hold_distance)

    def _candidates(self, surface: CutSurface, bounds) -> np.ndarray:
        """Live elements with a vertex near the surface (within :attr:`_margin` of a plane, or
        inside its box grown by it): every element the surface crosses: one vectorised pass
        over the vertices, then their elements by adjacency."""
        topo = self.topology
        x = self.coordinates()
        if isinstance(surface, Plane) and bounds is None:  # the mesh's own points: no validation pass
            near = np.abs(x @ surface.normal - float(surface.point @ surface.normal)) <= self._margin
        else:
            lower, upper = surface.bounds() if bounds is None else bounds
            lower = np.asarray(lower, float) - self._margin
            upper = np.asarray(upper, float) + self._margin
            near = np.all((x >= lower) & (x <= upper), axis=1)
        around: set[int] = set()
        for v in np.flatnonzero(near).tolist():
            around |= topo.vertex_tets[v]
        return np.array(sorted(around), dtype=np.int64)

    def _progressive_surface(self, increment: CutSurface, bounds) -> tuple[CutSurface, np.ndarray]:
        """The part of everything swept so far near the elements ``increment`` may cut, welded
        into one surface, and those of the elements the blade has passed through completely.

        Only swept triangles within ``_margin`` of the candidate elements' box are kept: no
        other can cross, touch or be nearest to anything the cut looks at, and an edge left
        open by dropping a triangle lies outside that box. So the cost stays local however
        long the cut has been going on."""
        if not isinstance(increment, TriangleSurface):
            raise CutError(f"a progressive cut takes a TriangleSurface increment, got {type(increment).__name__}")
        slots = self._candidates(increment, bounds)
        ids = []
        for point in increment.vertices.tolist():
            ids.append(self._swept_index.setdefault(tuple(point), len(self._swept_points)))
            if ids[-1] == len(self._swept_points):
                self._swept_points.append(point)
        self._swept_triangles.append(np.asarray(ids, dtype=np.int64)[increment.triangles])
        if not len(slots):
            return increment, slots
        swept = self._swept_near(self.coordinates()[self.topology.tets[slots]].reshape(-1, 3))
        if swept is None:  # the increment only grazes the candidates' box
            return increment, slots[:0]
        waiting = self._crossed_by(slots, swept.vertices[_boundary_edges(swept.triangles)])
        self._waiting_vertices = set(self.topology.tets[slots[waiting]].ravel().tolist())
        return swept, slots[~waiting]

    def _swept_near(self, points: np.ndarray) -> TriangleSurface | None:
        """The surface swept by the progressive cut so far, its triangles within ``_margin`` of
        the box of ``points`` (m); None where there are none."""
        vertices, triangles = np.asarray(self._swept_points), np.concatenate(self._swept_triangles)
        lower, upper = points.min(axis=0) - self._margin, points.max(axis=0) + self._margin
        spans = vertices[triangles]
        triangles = triangles[np.all((spans.max(axis=1) >= lower) & (spans.min(axis=1) <= upper), axis=1)]
        return TriangleSurface(vertices, triangles) if len(triangles) else None

    def _crossed_by(self, slots: np.ndarray, segments: np.ndarray) -> np.ndarray:
        """(M,) whether any of ``segments`` (B, 2, 3) (m) meets element ``slots[i]``, up to the
        on-surface tolerance (Cyrus-Beck clipping in barycentric coordinates, compiled:
        :func:`wcut.kernels.surface_query.elements_met`, with a BVH of the segments)."""
        if not len(slots) or not len(segments):
            return np.zeros(len(slots), dtype=bool)
        bvh = box_tree(segments.min(axis=1), segments.max(axis=1))
        met = wp.empty(len(slots), dtype=wp.int32, device="cpu")
        wp.launch(surface_query.elements_met, len(slots), device="cpu",
                  inputs=[bvh.id, wp.array(segments[:, 0], dtype=wp.vec3d, device="cpu"),
                          wp.array(segments[:, 1], dtype=wp.vec3d, device="cpu"),
                          wp.array(self.topology.tets[slots].astype(np.int32), dtype=wp.vec4i, device="cpu"),
                          wp.array(self.coordinates(), dtype=wp.vec3d, device="cpu"), self.tolerance],
                  outputs=[met])
        return met.numpy().astype(bool)

    def sample(self, surface: CutSurface, slots) -> _Sampling:
        """Crossings of ``surface`` with the edges of elements ``slots``."""
        return _Sampling(self.topology, self.coordinates(), surface, np.asarray(slots, dtype=np.int64),
                         self.tolerance)

    def snap(self, surface: CutSurface, slots, threshold: float, stats: CutStats) -> tuple[_Sampling, set[int]]:
        """Sample, snap (thesis 5.1.3) and sample again: the sampling after snapping and the
        vertices on the cut (on the surface or snapped)."""
        sampling = self.sample(surface, slots)
        stats.cut_elements = len(sampling.cut_slots)
        if not sampling.edges:
            return sampling, set(sampling.on)
        snapped = self._snap(sampling, threshold, stats)
        if snapped:
            sampling = self.sample(surface, slots)
        self._hold(sampling, self.hold_distance * self.mean_edge_length)
        return sampling, set(sampling.on) | snapped

    def _hold(self, sampling: _Sampling, threshold: float) -> None:
        """Where a boundary vertex may not snap (a curved boundary, whose surface and volume a
        slide would change): a boundary vertex within ``threshold`` (m) of the plane of a
        crossing on one of its edges is taken as on the surface, and the crossings of its
        edges are dropped. The cut bends through the vertex, by less than ``threshold``,
        instead of leaving next to it an edge of a few thousandths of the mean edge length on
        the boundary, whose elements are needles and wedges of a fraction of a degree (on the
        organ's 20 random plane cuts at epsilon 0.1, the worst dihedral angle rises from 0.02 to
        1.5 degrees). A boundary vertex within :data:`CAP_HOLD` times ``threshold`` holds the
        cut too where the surface would cut off a corner of one of its elements smaller than
        :attr:`least_corner` (:meth:`_small_corner`): no move of the improvement can grow that
        corner, all of whose vertices are on the boundary or the cut."""
        x = self.coordinates()
        held, near = set(), set()
        reach = CAP_HOLD * threshold
        for (a, b), (t, n) in sampling.edges.items():
            h = (1.0 - t) * x[a] + t * x[b]
            for v in (a, b):
                if v not in sampling.on:
                    d = abs(float(np.dot(n, x[v] - h)))
                    if d < threshold:
                        held.add(v)
                    elif d < reach:
                        near.add(v)
        is_boundary = self.topology.is_boundary_vertex
        held = {v for v in held if is_boundary(v)}
        held |= {v for v in near - held if is_boundary(v) and self._small_corner(v, sampling, x)}
        if not held:
            return
        sampling.on |= held
        sampling.edges = {e: c for e, c in sampling.edges.items() if e[0] not in held and e[1] not in held}
        tets = self.topology.tets
        sampling.cut_slots = [t for t in sampling.cut_slots
                              if any(_edge(int(tets[t][i]), int(tets[t][j])) in sampling.edges for i, j in TET_EDGES)]

    def _small_corner(self, v: int, sampling: _Sampling, x: np.ndarray) -> bool:
        """Whether the surface cuts off vertex v's corner of one of its elements (its three
        edges there crossed) with a volume below :attr:`least_corner` (m^3), or below
        :data:`CORNER_PIECES` times that where v may not move (a curved boundary: the corner's
        pieces stay as small as the cut makes them)."""
        least = self.least_corner
        if self.curved_boundary or boundary_plane_count(self.topology, v) > 2:
            least *= CORNER_PIECES
        for t in self.topology.vertex_tets[v]:
            others = [u for u in self.topology.tets[t].tolist() if u != v]
            crossings = [sampling.edges.get(_edge(v, u)) for u in others]
            if None in crossings:
                continue
            # (each crossing's parameter runs from the edge's smaller vertex)
            points = [x[v] + (t_ if v < u else 1.0 - t_) * (x[u] - x[v]) for u, (t_, _) in zip(others, crossings)]
            if abs(signed_volume(x[v], *points)) < least:
                return True
        return False

    def _snap(self, sampling: _Sampling, threshold: float, stats: CutStats) -> set[int]:
        """Snap the nearest vertex of each crossed edge onto its crossing when its distance to
        the plane (crossing, normal) is below ``threshold`` (m), nearest first (thesis 5.1.3).
        A boundary vertex may slide over a smooth curved boundary only with ``boundary_slide``.
        Returns the vertices moved."""
        x = self.coordinates()
        if not sampling.edges:
            return set()
        ab = np.array(list(sampling.edges))
        t = np.array([c[0] for c in sampling.edges.values()])
        normal = np.array([c[1] for c in sampling.edges.values()])
        xa, xb = x[ab[:, 0]], x[ab[:, 1]]
        h = (1.0 - t)[:, None] * xa + t[:, None] * xb
        da = np.abs(np.einsum("ij,ij->i", normal, xa - h))
        db = np.abs(np.einsum("ij,ij->i", normal, xb - h))
        near_a = da <= db
        v, s, d = np.where(near_a, ab[:, 0], ab[:, 1]), np.where(near_a, t, 1.0 - t), np.where(near_a, da, db)
        close = d < threshold
        moves = zip(d[close].tolist(), v[close].tolist(), (ab.sum(axis=1) - v)[close].tolist(), s[close].tolist())
        snapped: set[int] = set()
        for _, v, other, s in sorted(moves):
            if v in snapped or other in snapped or v in sampling.on:
                continue
            if self.curved_boundary and self.topology.is_boundary_vertex(v):
                continue  # it would leave the curved surface
            try:
                weights = check_vertex_move(self.topology, v, [v, other], [1.0 - s, s],
                                            feature_angle=0.0 if v in self.wound_vertices else self.boundary_slide)
            except TopologyError as exc:
                stats.refused.append(str(exc))
                continue
            if not self._move_keeps_quality(v, other, s):
                stats.refused.append(f"snapping vertex {v} would make a sliver")
                continue
            self.topology.set_vertex(v, [v, other], weights)
            snapped.add(v)
        stats.snapped_vertices += len(snapped)
        return snapped

    # ---------------------------------------------------------------- paulus
    def _remesh(self, surface: CutSurface, slots: np.ndarray, stats: CutStats) -> None:
        """Steps 1-6 of a paulus cut (the insertion of steps 3-5 left out for ``snap``), by the
        compiled operators (:meth:`_cut_compiled`) or the Python ones, which give the same mesh
        (up to which copy of a vertex keeps its number)."""
        epsilon = np.inf if self.method == "snap" else max(self.epsilon, MIN_SNAP)
        sampling, marked = self.snap(surface, slots, epsilon * self.mean_edge_length, stats)
        if not marked and not sampling.edges:
            return
        plan = self._plan(surface, sampling) if self.method == "paulus" else None
        if self.compiled and not self.topology.unsewn:
            self._cut_compiled(surface, sampling, plan, marked, stats)
            return
        if plan is not None:
            marked |= self._insert_python(surface, sampling, plan, stats)
        self._disconnect(surface, marked, stats)

    def _plan(self, surface: CutSurface, sampling: _Sampling) -> "_Plan":
        """The operators of steps 3-5, in the order they are applied."""
        topo = self.topology
        cut_tets = [topo.tet(t) for t in sampling.cut_slots]
        reused = self.split_vertices & sampling.on
        # a piece of an element split before: its split vertex serves again
        again = [reused.intersection(tet) for tet in cut_tets]
        points = iter(self._element_points(surface, sampling, [tet for tet, a in zip(cut_tets, again) if not a]))
        plan = _Plan()
        for t, old in zip(sampling.cut_slots, again):
            if old:
                plan.reused |= old
            else:
                weights, real = next(points)
                plan.splits.append((t, weights, real))
        faces = {}
        crossed = sampling.edges
        for tet in cut_tets:
            for i, j, k in _TET_FACES:
                a, b, c = tet[i], tet[j], tet[k]
                if reused and (a in reused or b in reused or c in reused):
                    continue  # its vertex on the surface already joins the polygon
                if ((a, b) if a < b else (b, a)) in crossed or ((b, c) if b < c else (c, b)) in crossed \
                        or ((a, c) if a < c else (c, a)) in crossed:
                    faces[face_key(a, b, c)] = None
        plan.faces = list(faces)
        plan.edges = [(edge, t) for edge, (t, _) in crossed.items()]
        return plan

    def _insert_python(self, surface: CutSurface, sampling: _Sampling, plan: "_Plan", stats: CutStats) -> set[int]:
        """:meth:`_insert_surface` by the Python operators on ``TetTopology``."""
        topo = self.topology
        marked = set(plan.reused)
        for t, weights, real in plan.splits:
            try:
                p, _ = split_tet(topo, t, weights)
            except TopologyError as exc:
                stats.refused.append(str(exc))
                continue
            stats.split_elements += 1
            self.split_vertices.add(p)
            if real:
                marked.add(p)
        for key in plan.faces:
            if key not in topo.face_tets:
                continue
            if len(topo.face_tets[key]) == 2 and self.flips:
                try:  # refused also where it would make a sliver: the face is split instead
                    flip23(topo, key, quality_drop=QUALITY_DROP)
                    stats.flips23 += 1
                    continue
                except TopologyError:
                    pass
            point = self._face_point(surface, sampling, key)
            if point is None:
                continue
            try:
                r, _ = split_face(topo, key, point[0])
            except TopologyError as exc:
                stats.refused.append(str(exc))
                continue
            stats.face_splits += 1
            if point[1]:
                marked.add(r)
        for (a, b), t in plan.edges:
            if not topo.edge_tets(a, b):
                continue
            if self.flips and not (self.curved_boundary and topo.is_boundary_edge(a, b)):
                try:
                    remove_edge(topo, a, b)
                    stats.general_flips += 1
                    continue
                except TopologyError:
                    pass
            try:
                m, _ = bisect_edge(topo, a, b, t)
            except TopologyError as exc:
                stats.refused.append(str(exc))
                continue
            stats.bisections += 1
            marked.add(m)
        return marked

    def _cut_compiled(self, surface: CutSurface, sampling: _Sampling, plan: "_Plan | None", marked: set[int],
                      stats: CutStats) -> None:
        """Steps 3-6 by the compiled operators on one :class:`TetRegion`, written back once:
        the crossed elements, every element around a crossed edge and the elements around the
        vertices already on the cut. That is everything they touch: each face or edge the plan
        names has a crossed edge, and a general flip re-triangulates the whole ring of its edge
        (which holds elements that are not cut yet where a progressive cut waits for the blade
        to pass through them; a plane crosses every element around a crossed edge); a face to
        open has three vertices on the cut, each one already on it or made inside the crossed
        elements, and every element around them is in the region."""
        topo = self.topology
        slots: set[int] = set()
        if plan is not None:
            slots.update(sampling.cut_slots)
            for (a, b), _ in plan.edges:
                slots |= topo.edge_tets(a, b)
        for v in marked:
            slots |= topo.vertex_tets[v]
        region = TetRegion(topo, sorted(slots))
        on_cut = {region.local_vertex(v) for v in marked}
        splits: list[int] = []
        if plan is not None:
            made_on_cut, splits = self._insert_compiled(region, surface, sampling, plan, stats)
            on_cut |= made_on_cut
        arrays = region.arrays
        first_copy = arrays.vertex_count
        faces, keys = self._faces_to_open(region, surface, on_cut)
        lips = sorted({v for key in keys for v in key})
        copies = arrays.disconnect(faces, lips) if faces else 0
        global_of = region.write_back()
        self.split_vertices.update(global_of[splits].tolist())
        self.wound_vertices.update(global_of[lips].tolist())  # duplicated or not (a crack's front)
        if copies:
            new = np.arange(first_copy, first_copy + copies)
            parents = global_of[arrays.vertex_parents.numpy()[new, 0]].tolist()
            self.wound_vertices.update(global_of[new].tolist(), parents)
            self.split_vertices.update(c for c, v in zip(global_of[new].tolist(), parents) if v in self.split_vertices)
            self._pair(zip(parents, global_of[new].tolist()))
        stats.unsewn_faces += len(faces)
        stats.duplicated_vertices += copies

    def _insert_compiled(self, region: TetRegion, surface: CutSurface, sampling: _Sampling, plan: "_Plan",
                         stats: CutStats) -> tuple[set[int], list[int]]:
        """Steps 3-5 in one launch on ``region``'s arrays. A face whose flip is refused gets its
        split point when the launch reaches it (the launch stops there: the point may cost a
        query of S), unless S is a plane (computed before, cheaply). Returns the region's
        vertices made on the cut (with the split vertices used again) and its new 1-4 split
        vertices."""
        local = region.local_vertex
        faces = plan.faces
        first_face = len(plan.splits)
        points = {}

        def face_row(i: int) -> tuple[list[int], np.ndarray]:
            """Operator i's row, face ``faces[i - first_face]`` with its split point."""
            key = faces[i - first_face]
            points[key] = self._face_point(surface, sampling, key)
            known, reals = _known_point(points[key])
            return [local(key[0]), local(key[1]), local(key[2]), known], reals

        ops = []
        for t, weights, _ in plan.splits:
            ops.append(("split_tet", [region.local_slot(t), -1, -1, -1], weights))
        if type(surface) is Plane:  # every split point known before the launch, all at once
            points = dict(zip(faces, self._plane_face_points(sampling, faces)))
        for key in faces:
            known, reals = _known_point(points[key]) if points else (kernels.POINT_PENDING, np.zeros(4))
            ops.append(("flip_or_split_face", [local(key[0]), local(key[1]), local(key[2]), known], reals))
        for (a, b), t in plan.edges:
            ops.append(("remove_or_bisect_edge", [local(a), local(b), int(self.curved_boundary), -1], [t, 0, 0, 0]))
        kinds, ints, reals = zip(*ops) if ops else ((), (), ())
        results = region.arrays.run(list(kinds), np.array(ints, dtype=np.int32).reshape(-1, 4),
                                    np.array(reals, dtype=np.float64).reshape(-1, 4),
                                    quality_drop=QUALITY_DROP, resolve=face_row, details=True)
        on_cut = {local(v) for v in plan.reused}
        splits = []
        for i, (reason, v, fallback) in enumerate(results):
            if i < first_face:
                t, _, real = plan.splits[i]
                if reason is None:
                    stats.split_elements += 1
                    splits.append(v)
                    if real:
                        on_cut.add(v)
                else:
                    stats.refused.append(f"split 1-4 of element {t}: {reason}")
            elif i < first_face + len(faces):
                key = faces[i - first_face]
                if reason is None and not fallback:
                    stats.flips23 += 1
                elif reason is None:
                    stats.face_splits += 1
                    if points[key][1]:
                        on_cut.add(v)
                elif fallback:
                    stats.refused.append(f"split of face {key}: {reason}")
            else:
                (a, b), _ = plan.edges[i - first_face - len(faces)]
                if reason is None and not fallback:
                    stats.general_flips += 1
                elif reason is None:
                    stats.bisections += 1
                    on_cut.add(v)
                elif fallback:
                    stats.refused.append(f"bisection of edge ({a}, {b}): {reason}")
        return on_cut, splits

    def _faces_to_open(self, region: TetRegion, surface: CutSurface, on_cut: set[int]) -> tuple[list, np.ndarray]:
        """:meth:`_disconnect`'s choice of faces on ``region``'s arrays: the interior faces whose
        three vertices are ``on_cut`` (region vertices) and which lie on the surface, less
        those that would cut a crumb loose. Returns them as (element, corner opposite) and as
        sorted vertex triples, in increasing order of the triples."""
        arrays = region.arrays
        live = arrays.live_tets()
        tets, neighbors = arrays.tet_indices.numpy()[live], arrays.tet_neighbors.numpy()[live]
        marked = np.zeros(arrays.vertex_count, dtype=bool)
        marked[list(on_cut)] = True
        corners = marked[tets]
        # face k has three vertices on the cut; one side of each (every such face is inside the region)
        rows, ks = np.nonzero((corners.sum(axis=1)[:, None] - corners == 3) & (neighbors > live[:, None]))
        keys = np.sort(np.take_along_axis(tets[rows], _FACE_CORNERS[ks], axis=1), axis=1)
        order = np.lexsort(keys.T[::-1])
        rows, ks, keys = rows[order], ks[order], keys[order]
        if not len(keys):
            return [], keys
        x = (arrays.vertex_rest if self._rest else arrays.vertex_q).numpy()[: arrays.vertex_count]
        centroids = None
        if isinstance(surface, TriangleSurface):
            sides = np.stack([live[rows], neighbors[rows, ks]], axis=1)
            centroids = x[arrays.tet_indices.numpy()[sides]].mean(axis=2)
        near = self._on_surface(surface, x[keys], centroids)
        rows, ks, keys = rows[near], ks[near], keys[near]
        faces = list(zip(live[rows].tolist(), neighbors[rows, ks].tolist()))  # (t, n), t < n
        # (a blade's: any small piece, as _separate_sheets keeps; one element of 6e-3 of the median,
        # well shaped, came loose from the organ where the blade bent through held vertices)
        opened = set(self._keep_attached(faces, _RegionFaces(arrays), any_shape=isinstance(surface, TriangleSurface)))
        kept = np.array([face in opened for face in faces], dtype=bool)
        return list(zip(live[rows[kept]].tolist(), ks[kept].tolist())), keys[kept]

    def _move_keeps_quality(self, v: int, other: int, s: float) -> bool:
        """Whether moving vertex v to ``(1 - s) v + s other`` (rest configuration) keeps the
        worst quality of its elements above ``QUALITY_DROP`` times what it was: a snap next to
        a poor element could flatten it."""
        topo = self.topology
        x = topo.rest_positions
        around = topo.tets[sorted(topo.vertex_tets[v])]
        before = x[around]
        after = before.copy()
        after[around == v] = (1.0 - s) * x[v] + s * x[other]
        return tet_qualities(after).min() >= QUALITY_DROP * tet_qualities(before).min()

    def _element_points(self, surface: CutSurface, sampling: _Sampling, tets: list[list[int]]) -> list:
        """For each element of ``tets`` (vertex lists), the barycentric weights of its 1-4 split
        vertex (thesis 5.1.1, 5.3) and whether it lies on the cut: the barycentre of the
        crossings and on-vertices, or, with fewer than three of them, of those of the surface's
        extension (:meth:`_extension_point`).

        A barycentre of crossings is on S where S is flat (a plane: always); one query of the
        tangent planes tells for all elements at once, and only the others are moved onto S
        one by one (:meth:`_onto_surface`)."""
        results: list = [None] * len(tets)
        totals, counts = _crossing_sums(tets, sampling.edges, sampling.on)
        rows = []
        for i, (tet, count) in enumerate(zip(tets, counts.tolist())):
            if count >= 3:
                rows.append(i)
            else:
                points = self._crossing_weights(tet, sampling.edges, sampling.on)
                results[i] = self._extension_point(surface, sampling, tet, points), False
        if rows:
            weights = totals[rows] / counts[rows, None]
            corners = self.coordinates()[np.array([tets[i] for i in rows])]  # (R, 4, 3)
            p = np.array([w @ c for w, c in zip(weights, corners)])  # as _onto_surface computes them
            origin, normal = surface.tangent_planes(p)
            on = (np.abs(np.einsum("rj,rj->r", normal, p - origin)) <= self.tolerance).tolist()
            for r, i in enumerate(rows):
                w = weights[r]
                results[i] = (w if on[r] else self._onto_surface(surface, corners[r], w, (origin[r], normal[r]))), True
        return results

    def _extension_point(self, surface: CutSurface, sampling: _Sampling, tet: list[int], points: list) -> np.ndarray:
        """Weights of the split vertex of element ``tet`` crossed at fewer than three
        ``points`` (the front of a bounded surface): the barycentre of the crossings of the
        surface's extension, pulled off the element's boundary where they are degenerate."""
        x = self.coordinates()
        pairs = [(tet[i], tet[j]) for i, j in TET_EDGES]
        a = x[[p[0] for p in pairs]]
        b = x[[p[1] for p in pairs]]
        t, normal = surface.extension_crossings(a, b, self.tolerance)
        extension = {_edge(*p): (s if p[0] < p[1] else 1.0 - s, n)
                     for p, s, n in zip(pairs, t, normal) if np.isfinite(s)}
        points = self._crossing_weights(tet, extension, sampling.on) or points
        weights = np.mean(points, axis=0)
        if len(points) < 3:  # degenerate: pull off the element's boundary
            weights = 0.75 * weights + 0.0625
        return weights

    def _onto_surface(self, surface: CutSurface, corners: np.ndarray, weights: np.ndarray,
                      plane: tuple | None = None) -> np.ndarray:
        return self._moved_onto_surface(surface, corners, weights, plane)[0]

    def _moved_onto_surface(self, surface: CutSurface, corners: np.ndarray, weights: np.ndarray,
                            plane: tuple | None = None) -> tuple[np.ndarray, bool]:
        """Barycentric weights over ``corners`` (4 of an element or 3 of a face, m) of the
        point ``weights @ corners`` moved onto a curved S within the element or face.
        ``plane``: S's tangent plane (point, unit normal) at that point when known.

        The barycentre of crossings is on S only where S is flat; a vertex placed off S is not
        on the cut for the next cut, which would split its elements again. So the point is
        projected onto S's nearest plane (within the face's plane for a face) a few times.
        The weights come back unchanged where S is nearly parallel to the face or the move
        would halve the point's smallest weight (the operators' quality check would refuse
        flatter elements). :meth:`_moved_onto_surface` also tells whether the point is on S
        (within the tolerance of S's nearest plane)."""
        p = weights @ corners
        if plane is not None:
            origin, normal = plane
        elif type(surface) is Plane:  # its tangent plane, without building (1, 3) arrays
            origin, normal = surface.point, surface.normal
        else:
            origin, normal = (a[0] for a in surface.tangent_planes(p[None]))
        gap = float(normal @ (p - origin))
        if abs(gap) <= self.tolerance:
            return weights, True  # on S already (S flat here)
        span = None
        if len(corners) == 3:
            span = np.cross(corners[1] - corners[0], corners[2] - corners[0])
            span /= np.linalg.norm(span)
        for i in range(4):
            if i:  # the first step starts from the plane found above (a query costs some 1 ms)
                origin, normal = (a[0] for a in surface.tangent_planes(p[None]))
                gap = float(normal @ (p - origin))
                if abs(gap) <= self.tolerance:
                    break
            step = normal if span is None else normal - (normal @ span) * span
            along = float(normal @ step)
            if along < 0.1:
                return weights, False
            p = p - gap / along * step
        else:
            return weights, False
        moved = barycentric(p, corners)
        return (moved, True) if moved.min() >= 0.5 * weights.min() else (weights, False)

    def _fold_point(self, surface: CutSurface, corners: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Weights over a face's ``corners`` (3, 3) (m) of the point where a fold of S goes
        through the face, nearest to ``weights @ corners``; ``weights`` where none does.

        Where the blade turned within the face (the joint of two increments of a progressive
        cut), S meets the face along two segments joined at the fold, and the barycentre of the
        face's crossings lies on the chord between them, off S: no projection onto one of S's
        planes puts it on S. The fold point, where an edge of S's triangulation pierces the face,
        is on both; a split there leaves every new edge of the face on S or uncrossed, where a
        split off S leaves edges crossing the cut, and the elements on them sewn across it."""
        if not isinstance(surface, TriangleSurface):
            return weights
        tol = self.tolerance
        edges, _ = _surface_edges(surface.triangles)
        a, b = surface.vertices[edges[:, 0]], surface.vertices[edges[:, 1]]
        lower, upper = corners.min(axis=0) - tol, corners.max(axis=0) + tol
        near = np.all((np.minimum(a, b) <= upper) & (np.maximum(a, b) >= lower), axis=1)
        if not near.any():
            return weights
        a, b = a[near], b[near]
        t, _ = TriangleSurface(corners, np.array([[0, 1, 2]])).crossings(a, b, tol)
        hit = np.isfinite(t)
        if not hit.any():
            return weights
        points = a[hit] + t[hit, None] * (b[hit] - a[hit])
        best = points[np.argmin(np.linalg.norm(points - weights @ corners, axis=1))]
        moved = barycentric(best, corners)
        return moved if moved.min() >= 0.5 * weights.min() else weights

    @staticmethod
    def _crossing_weights(vertices: list[int], edges: dict, on: set[int]) -> list[list[float]]:
        """Barycentric weights (over ``vertices``) of the crossings on their edges and of the
        vertices that are on the surface (lists of floats: a few per element, where numpy's
        per-array cost would dominate)."""
        k = len(vertices)
        points = []
        for i in range(k):
            vi = vertices[i]
            if vi in on:
                w = [0.0] * k
                w[i] = 1.0
                points.append(w)
            for j in range(i + 1, k):
                vj = vertices[j]
                key = (vi, vj) if vi < vj else (vj, vi)
                hit = edges.get(key)
                if hit is not None:
                    t = hit[0]
                    s = t if vi == key[0] else 1.0 - t  # parameter from vertex i
                    w = [0.0] * k
                    w[i], w[j] = 1.0 - s, s
                    points.append(w)
        return points

    @staticmethod
    def _plane_face_points(sampling: _Sampling, keys: list) -> list:
        """:meth:`_face_point` of faces ``keys`` (sorted vertex triples) of a plane, to the
        bit, for all of them at once."""
        totals, counts = _crossing_sums(keys, sampling.edges, sampling.on)
        means, halfway = totals / np.maximum(counts, 1)[:, None], 0.5 * totals + 0.5 / 3.0
        if len(keys):
            on = np.fromiter(sampling.on, dtype=np.int64, count=len(sampling.on))
            counts[(counts == 2) & (np.isin(np.asarray(keys), on).sum(axis=1) == 1)] = 0  # a segment: no point
        return [(mean, True) if count >= 2 else None if count == 0 else (half, False)
                for count, mean, half in zip(counts.tolist(), means, halfway)]

    def _face_point(self, surface, sampling, key):
        """Weights (over the sorted face vertices) of the point where a face is split, and
        whether it is on the cut: the barycentre of its crossings and on-vertices; None where
        there is nothing to split (no crossing, or a plane's segment from a vertex)."""
        points = self._crossing_weights(list(key), sampling.edges, sampling.on)
        if type(surface) is Plane and len(points) == 2 and sum(v in sampling.on for v in key) == 1:
            return None  # the plane crosses the face from a vertex to the opposite edge: a segment
        if len(points) >= 2:  # _mean: np.mean(points, axis=0), without its overhead
            if type(surface) is Plane:  # a mean of points on a plane is on it: nothing to move
                return np.array(_mean(points)), True
            corners = self.coordinates()[list(key)]
            weights, on = self._moved_onto_surface(surface, corners, np.array(_mean(points)))
            return (weights if on else self._fold_point(surface, corners, weights)), True
        if not points:
            return None
        return 0.5 * np.asarray(points[0]) + 0.5 / 3.0, False

    # ----------------------------------------------------------- disconnection
    def _disconnect(self, surface: CutSurface, marked: set[int], stats: CutStats) -> None:
        """Unsew interior faces whose three vertices are on the cut and which lie on the
        surface, then duplicate their vertices once per fan (thesis 5.1.3)."""
        topo = self.topology
        elements: set[int] = set()
        for v in marked:
            elements |= topo.vertex_tets[v]
        faces = set()
        keys_of = topo.slot_face_keys
        for t in elements:  # the faces of t with three vertices on the cut
            for key in keys_of[t]:
                if key[0] in marked and key[1] in marked and key[2] in marked:
                    faces.add(key)
        keys = [key for key in sorted(faces) if len(topo.face_tets.get(key, ())) == 2]
        opened = []
        if keys:
            x = self.coordinates()
            centroids = None
            if isinstance(surface, TriangleSurface):
                centroids = x[[[topo.tet(t) for t in sorted(topo.face_tets[key])] for key in keys]].mean(axis=2)
            near = self._on_surface(surface, x[np.asarray(keys)], centroids)
            opened = [key for key, ok in zip(keys, near.tolist()) if ok]
        self._open(self._keep_attached(opened, _TopologyFaces(topo), any_shape=isinstance(surface, TriangleSurface)),
                   stats)
        sew_unopened(topo)

    def _open(self, faces: list, stats: CutStats) -> int:
        """Unsew interior ``faces`` (vertex triples) and duplicate their vertices once per fan
        (thesis 5.1.3); returns how many of those vertices got copies."""
        for key in faces:
            unsew_face(self.topology, key)
        stats.unsewn_faces += len(faces)
        return sum(bool(self._duplicate(v, stats)) for v in sorted({v for key in faces for v in key}))

    def _duplicate(self, v: int, stats: CutStats) -> list[int]:
        """Split vertex v into one copy per fan of elements; the copies are on the wound (and
        made by a split where v was). Returns the new vertices."""
        copies = duplicate_vertex(self.topology, v)
        stats.duplicated_vertices += len(copies)
        self._pair((v, c) for c in copies)
        self.wound_vertices.update(copies, (v,))
        if v in self.split_vertices:
            self.split_vertices.update(copies)
        return copies

    def _pair(self, copies) -> None:
        """Record (original, copy) pairs of the disconnection: a vertex split into two fans and
        its copy are twins (:meth:`_improve`); one split into more has none."""
        count: dict[int, int] = {}
        made = list(copies)
        for v, _ in made:
            count[v] = count.get(v, 0) + 1
        for v, c in made:
            if count[v] == 1:
                self._split_pairs[v], self._split_pairs[c] = c, v

    def _separate_sheets(self, surface: TriangleSurface, stats: CutStats) -> None:
        """Make sure a triangulated S left no sewn face between elements on its two sides.

        Where S folds within an element (a blade turning inside it), the fold passes between
        the element's vertices: they may all lie on S or on one side of it, no edge crosses
        S, and the remeshing leaves the element whole, sewn to the elements on both sides
        (along 40 random paths with one turn through a plate, ``tools/cut_turns.py``, 11
        plates stayed in one piece so). Elements around a vertex held off a curved S do the
        same (2 of 8 straight blades through the organ in 30 increments).

        Each element around this cut's elements gets S's local winding number at its
        centroid (:meth:`TriangleSurface.winding_numbers`, over the triangles within
        :data:`WINDING_REACH` mean edge lengths): across S it jumps by one, elsewhere it
        varies smoothly. A sewn face between two elements whose numbers differ by more than a
        half is unsewn and its vertices are duplicated per fan (thesis 5.1.3): the element
        the fold passes through goes with the side of its centroid, and the cut follows its
        faces there. A face lying in S opens where the numbers at points next to it
        (:data:`NEAR_FACE`) jump by more than a half: near S's boundary (a blade's entry just
        above the body) those at centroids a few tenths of an edge away jump by less (0.35 on
        a beam cut by Bielser's method, which stayed joined at its top). The numbers are the
        elements', so the sides are consistent (and :meth:`_keep_attached` keeps any small
        piece attached); only the pairs whose
        centroids S lies between are looked at (one query of S). Elements the boundary of S
        meets (a progressive blade's front), or with a vertex of an element the blade is
        still in, wait for a later increment: their numbers change as the blade goes on.
        Nothing moves: the volume stays exactly."""
        topo = self.topology
        changed = topo.changed_tets()
        if not changed:
            return
        waiting = self._waiting_vertices
        elements = set()
        for v in np.unique(topo.tets[changed]).tolist():
            elements |= topo.vertex_tets[v]
        slots = np.array(sorted(t for t in elements if waiting.isdisjoint(topo.tets[t].tolist())), dtype=np.int64)
        # the faces two of these elements share (vectorised: reading the mesh's face table
        # would link it anew after every change)
        faces = np.sort(topo.tets[slots][:, TET_FACES], axis=2).reshape(-1, 3)
        order = np.lexsort(faces.T[::-1])
        same = np.flatnonzero(np.all(faces[order[1:]] == faces[order[:-1]], axis=1))
        first, second = order[same], order[same + 1]
        if not len(first):
            return
        # only elements whose centroids S lies between can be on its two sides: one query
        owners = np.c_[slots[first // 4], slots[second // 4]]
        centroids = self.coordinates()[topo.tets[owners]].mean(axis=2)  # (F, 2, 3)
        hit, _ = surface.crossings(centroids[:, 0], centroids[:, 1], self.tolerance)
        across = np.flatnonzero(np.isfinite(hit))
        keys = [face_key(*f) for f in faces[first[across]].tolist()]
        sewn = [key not in topo.unsewn for key in keys]
        pick, keys = across[sewn], [key for key, ok in zip(keys, sewn) if ok]
        if not keys:
            return
        slots, index = np.unique(owners[pick], return_index=True)  # each with its centroid
        rim = surface.vertices[_boundary_edges(surface.triangles)]
        met = self._crossed_by(slots, rim) if len(rim) else np.zeros(len(slots), dtype=bool)
        numbers = surface.winding_numbers(centroids[pick].reshape(-1, 3)[index], WINDING_REACH * self.mean_edge_length)
        winding = {s: w for s, w, m in zip(slots.tolist(), numbers.tolist(), met.tolist()) if not m}
        jump = np.array([winding[a] - winding[b] if a in winding and b in winding else np.nan
                         for a, b in owners[pick].tolist()])
        across_s = np.abs(jump) > 0.5  # (nan: an element that S's boundary meets)
        lying = np.isfinite(jump) & ~across_s
        if lying.any():  # a face lying in S: the jump between points next to it
            corners = self.coordinates()[faces[first[pick[lying]]]]  # (L, 3, 3)
            centre = corners.mean(axis=1)
            on_s = surface.distance(centre, self.tolerance) <= self.tolerance
            near = centre[:, None] + NEAR_FACE * (centroids[pick[lying]] - centre[:, None])  # (L, 2, 3)
            radius = WINDING_REACH * np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1)
            jumps = surface.winding_jumps(near[:, 0], near[:, 1], radius)
            across_s[np.flatnonzero(lying)[on_s & (np.abs(jumps) > 0.5)]] = True
        opened = [key for key, ok in zip(keys, across_s.tolist()) if ok]
        opened = self._keep_attached(sorted(opened), _TopologyFaces(topo), any_shape=True)
        stats.separated_vertices += self._open(opened, stats)
        if opened:
            sew_unopened(topo)

    def _separate_swept(self, surface: TriangleSurface, stats: CutStats) -> None:
        """Make sure no vertex a triangulated S has passed holds elements on both of its sides.

        Where a vertex held a little off S bends the cut through it, the elements around it
        may lie on both sides of S and still share it: through a flat element about in S,
        whose faces neither side's winding number claims (:meth:`_separate_sheets`), the two
        pieces stay hinged there (a straight blade through the organ in 20 increments left
        it in one piece so). As :meth:`_separate` does for a plane: each element around a
        vertex of this cut's elements gets a side, that of its corner farthest from S, by
        the nearest triangle of S (oriented; 0 within :attr:`in_plane` of S, then a sewn
        neighbour's side), and where both sides meet at a vertex the faces between them are
        unsewn (less those that would cut a crumb loose, :meth:`_keep_attached`) and their
        vertices duplicated per fan. Left alone until a later increment: vertices of elements
        the blade is still in, and vertices nearer S's boundary (beyond which S does not cut)
        or a bend of S (over :data:`SWEPT_BEND` degrees) than twice their elements' reach:
        folds are :meth:`_separate_sheets`' work. On 72 straight blades through the organ (12
        to 30 increments) 3 left it in one piece without this, none with it. Nothing moves:
        the volume stays exactly."""
        topo = self.topology
        changed = topo.changed_tets()
        if not (changed or self._unsettled) or not len(surface):
            return
        x = self.coordinates()
        waiting = self._waiting_vertices
        around = set(np.unique(topo.tets[changed]).tolist() if changed else []) | self._unsettled
        self._unsettled = around & waiting  # (looked at once the blade has passed)
        vertices = np.array(sorted(v for v in around - waiting if v < topo.vertex_count and topo.vertex_tets[v]),
                            dtype=np.int64)
        if not len(vertices):
            return
        if self._swept_triangles:  # what the blade swept around them, not only around this increment
            surface = self._swept_near(x[vertices])
            if surface is None:
                return
        band = self.wound_band
        vertices = vertices[surface.distance(x[vertices], band) <= band]
        if not len(vertices):
            return
        # first, who is far enough from S's boundary (twice its elements' reach): the others wait
        stars = [sorted(topo.vertex_tets[v]) for v in vertices.tolist()]
        rows = np.repeat(np.arange(len(vertices)), [len(star) for star in stars])
        reach = np.zeros(len(vertices))
        np.maximum.at(reach, rows, np.linalg.norm(x[topo.tets[np.concatenate(stars)]] - x[vertices][rows][:, None],
                                                  axis=2).max(axis=1))
        inside = _far_from_rim(surface, x[vertices], 2.0 * reach)
        self._unsettled.update(vertices[~inside].tolist())  # (S's boundary may move on: a blade's front)
        vertices, reach = vertices[inside], reach[inside]
        if not len(vertices):
            return
        slots = np.unique(np.concatenate([star for star, ok in zip(stars, inside.tolist()) if ok])).astype(np.int64)
        corners = x[topo.tets[slots]]  # (E, 4, 3)
        distance, nearest = surface.nearest(corners.reshape(-1, 3))
        distance, nearest = distance.reshape(-1, 4), nearest.reshape(-1, 4)
        far = distance.argmax(axis=1)
        farthest = corners[np.arange(len(slots)), far]
        triangle = nearest[np.arange(len(slots)), far]  # (S is oriented: the side of its nearest triangle)
        side = np.sign(np.einsum("ij,ij->i", farthest - surface.vertices[surface.triangles[triangle, 0]],
                                 surface.normals[triangle]))
        sides = np.where(distance.max(axis=1) > self.in_plane * self.mean_edge_length, side, 0).astype(np.int64)
        joined = np.intersect1d(_on_both_sides(topo.tets[slots], sides, topo.vertex_count), vertices)
        if not len(joined):
            return
        _, normal = surface.tangent_planes(x[joined])
        flat = _flat_near(surface, x[joined], normal, 2.0 * reach[np.searchsorted(vertices, joined)])
        self._unsettled.update(joined[~flat].tolist())
        joined = joined[flat]
        if not len(joined):
            return
        _, faces = self._between_sides(slots, sides, set(joined.tolist()))
        opened = self._keep_attached(faces, _TopologyFaces(topo), any_shape=True)
        stats.separated_vertices += self._open(opened, stats)
        if opened:
            sew_unopened(topo)

    def _between_sides(self, slots: np.ndarray, sides: np.ndarray, among=None) -> tuple[list[int], list]:
        """Where elements ``slots`` on sides ``sides`` (+1 / -1; 0 for one lying in the cut,
        which takes the side of a sewn neighbour) meet at a vertex (of ``among``, if given):
        those vertices, and the sewn faces at them between elements on opposite sides."""
        topo = self.topology
        side_of = dict(zip(slots.tolist(), sides.tolist()))
        stack = [t for t, side in side_of.items() if side]
        while stack:
            t = stack.pop()
            for key in topo.slot_face_keys[t]:
                owners = topo.face_tets[key]
                if len(owners) == 2 and key not in topo.unsewn:
                    n = owners[1] if owners[0] == t else owners[0]
                    if side_of.get(n, 1) == 0:
                        side_of[n] = side_of[t]
                        stack.append(n)
        sides = np.array([side_of[t] for t in slots.tolist()])
        joined = [v for v in _on_both_sides(topo.tets[slots], sides, topo.vertex_count).tolist()
                  if among is None or v in among]
        faces = set()
        for v in joined:
            for t in topo.vertex_tets[v]:
                for key in topo.slot_face_keys[t]:
                    owners = topo.face_tets[key]
                    if v in key and len(owners) == 2 and key not in topo.unsewn \
                            and side_of.get(owners[0], 0) * side_of.get(owners[1], 0) < 0:
                        faces.add(key)
        return joined, sorted(faces)

    def _on_surface(self, surface: CutSurface, corners: np.ndarray, centroids: np.ndarray | None) -> np.ndarray:
        """(F,) whether each face, with ``corners`` (F, 3, 3) (m) all on the cut, lies on the
        surface: a face with three vertices on the cut may still span across it.

        On a plane, a face spans across when its centre is off (``centroids`` is then unused).
        On a triangulated S, whose faces are chords where S bends or folds, a face opens when it
        separates the two elements it joins, whose ``centroids`` (F, 2, 3) (m) lie on opposite
        sides of S: the local winding number of S (:meth:`TriangleSurface.winding_jumps`, over
        the triangles within :data:`WINDING_REACH` times the face's radius, or the distance
        from its centre to the centroids where that is larger) changes by more than a half
        between them. A face across the inner corner of a fold (vertices on both sheets, centre
        off S) then opens, and one between two sheets, with both elements on the same side,
        stays sewn, whatever the distance of their centres. A flat element lying in S stays
        with the side its centroid is on (the faces to the other side open) instead of coming
        loose."""
        if isinstance(surface, TriangleSurface):
            centre = corners.mean(axis=1)
            size = np.maximum(np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1),
                              np.linalg.norm(centroids - centre[:, None], axis=2).max(axis=1))
            jumps = surface.winding_jumps(centroids[:, 0], centroids[:, 1], WINDING_REACH * size)
            return np.abs(jumps) > 0.5
        centre = corners.mean(axis=1)
        reach = 0.25 * np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1) + self.tolerance
        return surface.distance(centre, float(reach.max())) <= reach

    def _keep_attached(self, opened: list, mesh: "_TopologyFaces | _RegionFaces", any_shape: bool = False) -> list:
        """``opened`` (faces as ``mesh`` names them) less the faces that would cut a crumb
        loose (see ``CRUMB_ELEMENTS``): flat elements lying in the surface get all their
        faces on the cut. The crumb's largest opened face stays sewn, so it stays with the
        neighbour across it; that bridges nothing, its other faces being open. With
        ``any_shape``, a crumb is any few elements of small total volume, slivers or not."""
        opened_set = set(opened)
        crumb_volume = CRUMB_VOLUME * self.mean_edge_length**3 / (6.0 * np.sqrt(2.0))
        sliver_quality = CRUMB_QUALITY * REGULAR_QUALITY

        def sliver(t):
            return any_shape or mesh.quality(t) < sliver_quality

        def crumb_from(start):
            """The elements reachable from ``start`` through sewn faces if they are few slivers
            of small total volume; else None (the search stops at the first good element)."""
            seen, stack = {start}, [start]
            while stack:
                for face, across in mesh.faces(stack.pop()):
                    if across == -1 or face in opened_set or across in seen:
                        continue
                    if across == OUTSIDE or len(seen) == CRUMB_ELEMENTS or not sliver(across):
                        return None
                    seen.add(across)
                    stack.append(across)
            return seen if sum(mesh.volume(t) for t in seen) < crumb_volume else None

        for start in sorted({t for key in opened for t in mesh.owners(key)}):
            crumb = crumb_from(start) if sliver(start) else None
            if crumb is None:
                continue
            faces = {face for t in crumb for face, _ in mesh.faces(t)}
            mine = sorted(f for f in faces if f in opened_set)
            if mine:
                opened_set.discard(mine[int(np.argmax([mesh.area(f) for f in mine]))])
        return [key for key in opened if key in opened_set]

    def _separate(self, plane: Plane, stats: CutStats) -> list[int]:
        """Make sure a complete plane cut separated the mesh: where the remeshing refused an
        operator (a split or a snap that would have made a flat element next to a poor one) an
        element may still reach a little across the plane, and the pieces stay joined there.

        Each element near the plane gets a side (:func:`~wcut.cut.separation.element_sides`);
        one lying in the plane takes the side of a sewn neighbour. At every vertex whose
        elements lie on both sides, the faces between the sides are unsewn and the vertex is
        duplicated per fan (thesis 5.1.3), so no piece holds elements on both sides and none
        is hinged across at a vertex or an edge. The cut surface there follows element faces:
        it departs from the plane by at most how far those elements reached across. Nothing
        moves and nothing is added but vertex copies: the volume is kept exactly. Where the
        remeshing succeeded no vertex has elements on both sides, and this costs one
        vectorised pass. Returns the vertices it separated and their copies."""
        topo = self.topology
        slots = self._candidates(plane, None)
        if not len(slots):
            return []
        tets = topo.tets[slots]
        d = plane.signed_distance(self.coordinates()[tets].reshape(-1, 3)).reshape(-1, 4)
        sides = element_sides(d, self.in_plane * self.mean_edge_length)
        if not len(_on_both_sides(tets, sides, topo.vertex_count)):
            return []
        joined, faces = self._between_sides(slots, sides)
        for key in faces:
            unsew_face(topo, key)
        stats.unsewn_faces += len(faces)
        separated = list(joined)
        for v in joined:
            separated += self._duplicate(v, stats)
        stats.separated_vertices += len(joined)
        sew_unopened(topo)
        return separated

    def _improve(self, surface: CutSurface, stats: CutStats, near=None) -> None:
        """Local mesh improvement (:mod:`wcut.topology.improve`) of the elements this cut made
        or changed and of the elements around their vertices. Frozen: the vertices on the cut
        surface (within the tolerance, on the wound's lips or split on it), so the cut surface,
        and the lips' match, stay as they are; a vertex inside the wound slides with its copy,
        within its lips' fan where that is flat, else within the band the fan spans about the
        surface (``within_band`` below). ``near``: vertices (those :meth:`_separate` split and
        their copies) to whose elements, and the elements around their vertices, it keeps to."""
        topo = self.topology
        changed = topo.changed_tets() if near is None else sorted(set().union(*(topo.vertex_tets[v] for v in near)))
        if not changed:
            return
        candidates = np.unique(topo.tets[changed])
        vertices = set(candidates.tolist())
        work = set(changed)
        for v in vertices:
            work |= topo.vertex_tets[v]
        if not has_poor(topo, work, IMPROVE_TARGET, self.improve_min_volume):
            return  # (most of a clean mesh's cut events: nothing to set up)
        x = self.coordinates()[candidates]
        on = candidates[surface.distance(x, self.tolerance) <= self.tolerance].tolist()
        # every wound vertex the improvement reaches: one moved alone would slide one lip only
        reached = set(np.unique(topo.tets[sorted(work)]).tolist())
        frozen = set(on) | (reached & (self.wound_vertices | self.split_vertices))
        twins = None
        if self.curved_boundary:
            frozen |= {v for v in vertices if topo.is_boundary_vertex(v)}
        else:  # the two copies of a vertex inside the wound: at one rest position
            copies: dict[tuple, list[int]] = {}
            for v in frozen:
                copies.setdefault(topo.rest_tuples[v], []).append(v)
            twins = {v: w for pair in copies.values() if len(pair) == 2 for v, w in (pair, pair[::-1])}
            # where this cut meets an earlier wound, four copies share a rest position: the
            # pairs this cut split are the twins of its lips
            pairs = self._split_pairs
            twins.update((v, w) for v, w in pairs.items() if pairs.get(w) == v and v in frozen and w in frozen)
            if self.method == "paulus":  # a wound vertex on the cut with no copy (where the lips
                # meet: a blade's front) is its own twin; Bielser's cut bisects the front's
                # crossings again at each increment, and merging them away left a beam hinged
                on_cut = set(on)
                twins.update((v, v) for (v, *more) in copies.values() if not more and v in self.wound_vertices
                             and v in on_cut and v not in twins)
        if not self.smooths_under_blade:
            frozen |= self._waiting_vertices
        coordinates, tolerance = self.coordinates(), self.tolerance
        band = self.wound_band

        def targets(parents: list[list[int]], weights: list[list[float]]) -> np.ndarray:
            """(M, 3) where each move ends, in the cut's configuration (m)."""
            return np.array([np.asarray(w) @ coordinates[u] for u, w in zip(parents, weights)])

        def off_the_cut(vertices: list[int], parents: list[list[int]], weights: list[list[float]]) -> np.ndarray:
            """Per move of ``vertices[i]``: it neither crosses the surface nor ends within its
            tolerance, and a boundary vertex of an element the blade is still in does not come
            closer to the surface's nearest plane (there it meets the blade's next increment:
            where the blade turned, a face at the fold came out split off the surface, and an
            edge stayed across it, on one of 40 paths of tools/cut_turns.py and on the plate
            of the tests)."""
            p = targets(parents, weights)
            t, _ = surface.crossings(coordinates[list(vertices)], p, tolerance)
            ok = np.isnan(t) & (surface.distance(p, tolerance) > tolerance)
            waiting = np.array([v in self._waiting_vertices and topo.is_boundary_vertex(v) for v in vertices])
            if waiting.any():
                here = coordinates[np.asarray(vertices)[waiting]]
                origin, normal = surface.tangent_planes(here)
                before = np.abs(np.einsum("ij,ij->i", here - origin, normal))
                after = np.abs(np.einsum("ij,ij->i", p[waiting] - origin, normal))
                ok[np.flatnonzero(waiting)[after < before]] = False
            return ok

        def within_band(vertices: list[int], parents: list[list[int]], weights: list[list[float]]) -> np.ndarray:
            """Per slide of a wound vertex off its bent fan's planes: its fan, ``parents[i]``, is
            this cut's (within the farthest a held vertex lies from the surface), and it ends no
            farther from the surface than the fan's farthest vertex: the surface stays within
            the band that holding a boundary vertex bent it to."""
            p = targets(parents, weights)
            fans = sorted({u for each in parents for u in each})
            reach = dict(zip(fans, surface.distance(coordinates[fans], band).tolist()))
            farthest = np.array([max(reach[u] for u in each) for each in parents])
            return np.isfinite(farthest) & (surface.distance(p, band) <= farthest + tolerance)

        waiting = np.fromiter(self._waiting_vertices, np.int64, count=len(self._waiting_vertices))

        def apart(tets: list[list[int]], replaced: list[int]) -> bool:
            """No edge of ``tets`` crosses the surface (an element across the cut joins its
            sides) but one the elements ``replaced`` have, away from the elements the blade is
            still in: next to a held vertex the bent wound leaves such edges, which a move may
            keep (on 20 random Bielser cuts of the organ, the cuts below 5 degrees fall from 6
            to 4); one at the blade's front changes what its next increment cuts."""
            edges = np.unique(np.sort(np.asarray(tets)[:, TET_EDGES].reshape(-1, 2), axis=1), axis=0)
            t, _ = surface.crossings(coordinates[edges[:, 0]], coordinates[edges[:, 1]], tolerance)
            across = edges[~np.isnan(t)]
            if not len(across):
                return True
            if np.isin(across, waiting).any():
                return False
            had = np.sort(topo.tets[list(replaced)][:, TET_EDGES].reshape(-1, 2), axis=1)
            return bool(np.isin(across @ [topo.vertex_count, 1], had @ [topo.vertex_count, 1]).all())

        # the elements the blade is still in keep their connectivity until a later increment cuts them
        result = improve_mesh(topo, work, frozen, target=IMPROVE_TARGET, min_volume=self.improve_min_volume,
                              twins=twins, pinned=self._waiting_vertices, may_move=off_the_cut, may_bend=within_band,
                              may_make=apart, contract=True, on_surface=set(on))
        if result.contracted:  # the vertices merged into others go; the last ones take their numbers
            dropped, moved = topo.drop_orphans()
            for name in ("split_vertices", "wound_vertices", "_waiting_vertices", "_unsettled"):
                kept = getattr(self, name) - dropped
                setattr(self, name, {moved.get(v, v) for v in kept})
            self._split_pairs = {moved.get(v, v): moved.get(w, w) for v, w in self._split_pairs.items()
                                 if v not in dropped and w not in dropped}
        stats.improved_edge_flips += result.edge_flips
        stats.improved_face_flips += result.face_flips
        stats.smoothed_vertices += result.smoothed
        stats.slid_vertices += 2 * result.slid
        stats.contracted_edges += result.contracted

    # ---------------------------------------------------------------- delete
    def _delete(self, surface: CutSurface, slots: np.ndarray, stats: CutStats) -> None:
        """Remove every element the surface crosses (the simplest cut; loses volume)."""
        topo = self.topology
        sampling = self.sample(surface, slots)
        doomed = set(sampling.cut_slots)
        stats.cut_elements = len(doomed)
        if not doomed:
            return
        if len(doomed) == topo.tet_count:
            raise CutError("deleting the crossed elements would delete the whole mesh")
        topo.replace_tets(sorted(doomed), [])
        stats.deleted_elements = len(doomed)
        topo.drop_unused_vertices()


def _improve_min_volume(topology: TetTopology) -> float:
    """``MIN_VOLUME_FRACTION`` of the live elements' median rest volume, or their smallest
    where that is smaller (m^3; 0 without elements)."""
    volumes = tet_volumes(topology.rest_positions, topology.tets[topology.live_tets()])
    if not len(volumes):
        return 0.0
    return float(min(IMPROVE_MIN_VOLUME_FRACTION * np.median(volumes), volumes.min()))


def _far_from_rim(surface: TriangleSurface, points: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(M,) whether S's boundary is farther than ``reach`` (M,) (m) from ``points`` (M, 3) (m)."""
    rim = surface.vertices[_boundary_edges(surface.triangles)]  # (B, 2, 3)
    if not len(rim):
        return np.ones(len(points), dtype=bool)
    count = len(rim)  # every point against every rim edge, as rows
    distance = _point_segment_distance(np.repeat(points, count, axis=0), np.tile(rim[:, 0], (len(points), 1)),
                                       np.tile(rim[:, 1], (len(points), 1)))
    return distance.reshape(len(points), count).min(axis=1) > reach


def _flat_near(surface: TriangleSurface, points: np.ndarray, normals: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(M,) whether S's triangles within ``reach`` (M,) (m) of ``points`` (M, 3) (m) turn less than
    :data:`SWEPT_BEND` degrees from ``normals`` (M, 3) (S is oriented: the other sheet of a fold
    turns 180)."""
    rows, tri = surface._near_pairs(points, reach)
    flat = np.ones(len(points), dtype=bool)
    np.logical_and.at(flat, rows, np.einsum("pj,pj->p", surface.normals[tri], normals[rows])
                      >= np.cos(np.radians(SWEPT_BEND)))
    return flat


def _on_both_sides(tets: np.ndarray, sides: np.ndarray, vertex_count: int) -> np.ndarray:
    """Vertices with elements of ``tets`` on both sides (``sides`` +1 / -1 / 0 per element)."""
    low = np.zeros(vertex_count, dtype=np.int64)
    high = np.zeros(vertex_count, dtype=np.int64)
    np.minimum.at(low, tets.ravel(), np.repeat(sides, 4))
    np.maximum.at(high, tets.ravel(), np.repeat(sides, 4))
    return np.flatnonzero((low < 0) & (high > 0))


class _TopologyFaces:
    """What :meth:`Cutter._keep_attached` asks of a ``TetTopology``."""

    def __init__(self, topo: TetTopology):
        self.topo = topo

    def owners(self, key) -> list[int]:
        return self.topo.face_tets[key]

    def faces(self, t: int) -> list[tuple[tuple[int, int, int], int]]:
        """Element t's faces (sorted vertex triples) and the element across each, -1 on the
        boundary or where unsewn."""
        topo = self.topo
        out = []
        for key in topo.slot_face_keys[t]:
            owners = topo.face_tets[key]
            across = -1
            if len(owners) == 2 and key not in topo.unsewn:
                across = owners[1] if owners[0] == t else owners[0]
            out.append((key, across))
        return out

    def quality(self, t: int) -> float:
        return self.topo.quality(t)  # remembered by the topology

    def volume(self, t: int) -> float:
        return self.topo.rest_volume(t)

    def area(self, key) -> float:
        return _triangle_area(self.topo.rest_positions, key)


class _RegionFaces:
    """What :meth:`Cutter._keep_attached` asks of a region's :class:`TetArrays` (as
    :class:`_TopologyFaces`). An interior face is named by its two elements (the smaller slot
    first): cheaper than its vertices."""

    def __init__(self, arrays):
        slot_count = arrays.slot_count
        self.tets = arrays.tet_indices.numpy()[:slot_count]
        self.neighbors = arrays.tet_neighbors.numpy()[:slot_count].tolist()
        self.rest = arrays.vertex_rest.numpy()[: arrays.vertex_count]
        corners = self.rest[self.tets]  # dead slots too: cheaper than picking the live ones
        self.qualities, self.volumes = tet_qualities(corners).tolist(), tet_volumes(self.rest, self.tets).tolist()

    def owners(self, face) -> tuple[int, int]:
        return face

    def faces(self, t: int) -> list[tuple[tuple[int, int], int]]:
        """Element t's faces and the element across each: -1 on the boundary, ``OUTSIDE``
        for an element outside the region (not looked at)."""
        return [((t, n) if t < n else (n, t), n) for n in self.neighbors[t]]

    def quality(self, t: int) -> float:
        return self.qualities[t]

    def volume(self, t: int) -> float:
        return self.volumes[t]

    def area(self, face) -> float:
        key = sorted(set(self.tets[face[0]].tolist()) & set(self.tets[face[1]].tolist()))
        return _triangle_area(self.rest, key)


def _triangle_area(x: np.ndarray, key) -> float:
    """Twice the area (m^2) of triangle ``key`` of points ``x``."""
    return float(np.linalg.norm(np.cross(x[key[1]] - x[key[0]], x[key[2]] - x[key[0]])))


def _crossing_sums(rows: list, edges: dict, on: set[int]) -> tuple[np.ndarray, np.ndarray]:
    """For rows of k vertices (F, k), the sums (F, k) and the numbers (F,) of the points
    :meth:`Cutter._crossing_weights` lists for each, summed in its order, component by
    component (so ``sums / numbers`` is :func:`_mean` of them, to the bit: adding the zero
    weights of the points a row lacks changes no sum). Vectorised: the crossings are looked
    up by binary search in the sorted codes of the crossed edges."""
    if not len(rows):
        return np.zeros((0, 4)), np.zeros(0, dtype=np.int64)
    vertices = np.asarray(rows, dtype=np.int64)
    count, k = vertices.shape
    crossed = np.array(list(edges), dtype=np.int64).reshape(-1, 2)
    base = int(max(vertices.max(), crossed.max(initial=0))) + 1
    codes = crossed[:, 0] * base + crossed[:, 1]
    order = np.argsort(codes)
    codes, params = codes[order], np.array([c[0] for c in edges.values()], dtype=np.float64)[order]
    is_on = np.isin(vertices, np.fromiter(on, dtype=np.int64, count=len(on)))
    sums, numbers = np.zeros((count, k)), np.zeros(count, dtype=np.int64)
    for i in range(k):
        sums[is_on[:, i], i] += 1.0
        numbers += is_on[:, i]
        for j in range(i + 1, k):
            a, b = vertices[:, i], vertices[:, j]
            code = np.minimum(a, b) * base + np.maximum(a, b)
            at = np.minimum(np.searchsorted(codes, code), max(len(codes) - 1, 0))
            hit = codes[at] == code if len(codes) else np.zeros(count, dtype=bool)
            t = params[at[hit]]
            s = np.where(a[hit] < b[hit], t, 1.0 - t)  # the parameter from vertex i
            sums[hit, i] += 1.0 - s
            sums[hit, j] += s
            numbers += hit
    return sums, numbers


def _mean(points: list[list[float]]) -> list[float]:
    """Component-wise mean of equal-length float lists, summed in order and divided by their
    count, as ``np.mean(points, axis=0)`` rounds it."""
    total = list(points[0])
    for point in points[1:]:
        for i, value in enumerate(point):
            total[i] += value
    count = len(points)
    return [value / count for value in total]


def _surface_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(E, 2) sorted vertex pairs of the edges of a triangulated surface, and (E,) the number
    of its triangles on each."""
    pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    n = np.int64(pairs.max(initial=0)) + 1
    keys, counts = np.unique(pairs[:, 0] * n + pairs[:, 1], return_counts=True)  # (7x faster than np.unique(axis=0))
    return np.stack([keys // n, keys % n], axis=1), counts


def _boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """(B, 2) vertex pairs of the edges of a triangulated surface used by one triangle."""
    unique, count = _surface_edges(triangles)
    return unique[count == 1]


def barycentric(point: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric weights of ``point`` (3,) over the corners (k, 3) of a triangle (k = 3,
    least squares: the point's projection on its plane) or a tetrahedron (k = 4)."""
    local = np.linalg.lstsq((corners[1:] - corners[0]).T, point - corners[0], rcond=None)[0]
    return np.concatenate([[1.0 - local.sum()], local])
