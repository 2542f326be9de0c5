"""Detection of cuts and tears from the motion of features (thesis 7.5.2 and 7.5.3).

Neighbouring features (initial distance below ``radius``, the graph ``C_F^0``) move alike
while the object deforms smoothly. Across a cut the model, still whole, cannot follow its
targets: the spring vectors ``d_l = p_l^t - p_l^1`` of the two sides point apart (eq. 7.9)
and the targets separate (eq. 7.10). A pair whose measure ``mu_lm = mu_lm,1 mu_lm,2``
(eq. 7.11) exceeds ``tau`` times the mean is an outlier; once ``min_outliers`` exist, a cut
point is put at their barycentre weighted by the measure, pairs through the sphere of radius
``cut_point_radius`` around it leave the graph, and the point extends a cut polygon at its
nearest end, with a look-ahead point one radius further (figure 7.7). When a polygon gets its
second point, its first end gets a look-ahead point too, so the cut reaches the object's
boundary at both ends (the thesis extends only the newest end; its first point, put where
the outliers are, lies inside the object, and a cut starting there could not open). A cut
point farther than ``join_radius`` from every polygon end starts a new polygon: a second
cut elsewhere, or a stray detection, is not joined to the first by a long straight cut.
An end whose cut went through the object's boundary is closed (:meth:`close_end`): later
points start a new polygon rather than turn a finished cut back into the object.

Positions are kept in the rest configuration: a feature's initial virtual point
``p_l^0`` is a material point of the model, so the cut points (barycentres of ``p^0``) and
the polygon are material too and stay put however the object moves. The thesis keeps its
cut lines in the current configuration and notes that they drift as the object deforms
(7.5.3, on [79]); material points do not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp
from scipy.spatial import cKDTree

from ..errors import WcutError

#: the two variants of eq. 7.10: ``target`` is delta^1 / delta^0 ([82], the image alone),
#: ``current`` is delta^t / delta^0 ([78], smoothed by the model)
MEASURES = ("target", "current")

#: The live pairs are packed again once fewer than this fraction of the packed ones is still
#: measured: the measure's pass goes over the pairs removed in place too (as zeros).
REPACK_BELOW = 0.6


@dataclass(frozen=True)
class DetectionParams:
    """Settings of :class:`CutDetector`.

    Attributes:
        radius: r_{P_F} (m): features closer than this at rest are neighbours.
        cut_point_radius: r_{p_c} (m): pairs through a sphere this large around a new cut
            point are removed, and the look-ahead point is this far beyond it.
        tau: outlier threshold: ``mu_lm > tau * mean(mu)`` (the thesis uses 7 and 8).
        min_outliers: n: outliers needed before a cut point is put.
        measure: ``"target"`` or ``"current"`` (:data:`MEASURES`).
        cluster_radius: outliers farther than this (m, rest) from the strongest one are left
            for later cut points, so that two separate openings do not average to a point
            between them; default ``2 * cut_point_radius``.
        join_radius: a cut point within this distance (m, rest) of a polygon's end extends that
            polygon, otherwise it starts a new one; default ``3 * cut_point_radius``.
        min_measure: an outlier's measure must also exceed this (m). While the object barely
            moves, every ``mu`` is tracking noise and ``tau`` times their mean is noise too;
            the thesis has no such floor, and without it its rule fires on the first frames.
        max_turn: a cut point that would turn a polygon of two or more points by more than
            this (degrees) at the end it is nearest is dropped (its pairs stay out of the
            graph); 180 turns anything. Beyond the thesis, which grows a polygon at its nearest
            end whatever the angle: a false point (outliers where the model, held by a cut it
            has not made yet, pulls against released features) turned the polygon back into
            the object, the wrong cut made the model differ more from the object, and more
            false points followed until the model was in pieces (an S-example rendering: Dice
            0.45 against 0.84 uncut; a V-example one diverged). The thesis's first version
            ([79]) restricted the angle of its cut lines and gave it up because a line fixed
            to the image turns with the object; a polygon here lies in the rest
            configuration, which does not turn. 45 degrees: true turns between cut points 10-20
            mm apart (the S-example's sine) measured up to 48, and 45 did better than 60 on
            every scene it changed, over up to eight textures each (README).
    """

    radius: float
    cut_point_radius: float
    tau: float = 7.0
    min_outliers: int = 3
    measure: str = "target"
    cluster_radius: float | None = None
    join_radius: float | None = None
    min_measure: float = 0.0
    max_turn: float = 45.0

    def __post_init__(self):
        for name in ("radius", "cut_point_radius", "tau"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise WcutError(f"detection.{name}: expected a positive number, got {value!r}")
        if not (isinstance(self.min_outliers, int) and self.min_outliers >= 1):
            raise WcutError(f"detection.min_outliers: expected an integer >= 1, got {self.min_outliers!r}")
        if self.measure not in MEASURES:
            raise WcutError(f"detection.measure: expected one of {', '.join(MEASURES)}, got {self.measure!r}")
        if not (isinstance(self.max_turn, (int, float)) and 0.0 < self.max_turn <= 180.0):
            raise WcutError(f"detection.max_turn: expected degrees in (0, 180], got {self.max_turn!r}")
        for name in ("cluster_radius", "join_radius"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise WcutError(f"detection.{name}: expected a positive number, got {value!r}")


@dataclass(frozen=True)
class CutPoint:
    """A cut point put by :meth:`CutDetector.update`.

    Attributes:
        point: the cut point (3,) (m, rest configuration).
        polygon: index of the polygon it belongs to (in :attr:`CutDetector.polygons`).
        previous: the polygon point it extends (3,), or None for a polygon's first point.
        look_ahead: the point one ``cut_point_radius`` beyond it along ``point - previous``
            (3,), or None for a polygon's first point.
        back: for a polygon's second point, the look-ahead beyond the first point
            (``previous - cut_point_radius * direction``), else None; None too when the
            first point's end is closed (its cut came in from the boundary).
        at_start: True if it was put before the first point of the polygon.
        outliers: number of outlier pairs it was computed from.
    """

    point: np.ndarray
    polygon: int
    previous: np.ndarray | None
    look_ahead: np.ndarray | None
    back: np.ndarray | None
    at_start: bool
    outliers: int


class CutDetector:
    """The neighbour graph of the features and the cut polygon growing in it.

    The pairs of features that stopped pulling, the measure of every live pair, its mean, the
    outliers, their cluster, the cut point and the pairs it removes are one captured graph of
    the kernels of ``wcut.kernels.cut_detection`` (its inputs copied into arrays allocated
    once): the detection's cost per frame is three copies (positions, targets, the features
    that pull), that graph's replay and a few reads. The live pairs are packed for the
    kernels at construction; pairs that leave (a feature lost, a cut point) are taken out in
    place, and the live pairs are packed again only when a feature comes back or fewer than
    :data:`REPACK_BELOW` of the packed ones are left.

    Args:
        rest_features: (F, 3) initial virtual features ``p^0`` (m), material points.
        params: :class:`DetectionParams`.
        device: Warp device of the measure's arrays.

    Attributes:
        pairs: (P, 2) neighbour pairs (l < m), ``C_F^0``.
        alive: (P,) pairs still in the graph ``C_F^t`` (read-only: :meth:`remove_pairs` changes it).
        polygons: list of (n, 3) cut polygons (m, rest), each in order.
        closed_ends: the polygon ends (polygon, at start) closed by :meth:`close_end`.
        last_mean: mean measure of the last update (0 before any).
        last_outliers: outlier pairs of the last update.
    """

    def __init__(self, rest_features, params: DetectionParams, device=None):
        p0 = np.asarray(rest_features, dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(p0).all():
            raise WcutError("cut detection: non-finite rest features")
        self.params = params
        self.rest_features = p0
        self.pairs = cKDTree(p0).query_pairs(params.radius, output_type="ndarray").astype(np.int64)
        self.pairs = self.pairs[np.lexsort((self.pairs[:, 1], self.pairs[:, 0]))]
        self._l, self._m = self.pairs[:, 0].copy(), self.pairs[:, 1].copy()
        self.rest_length = np.linalg.norm(p0[self._l] - p0[self._m], axis=1)
        self._midpoints = 0.5 * (p0[self._l] + p0[self._m])
        self._device = wp.get_device(device)
        self._setup_kernel()
        self._pack_live(np.ones(len(p0), dtype=bool))  # setup, not the first frame's work
        self.polygons: list[np.ndarray] = []
        self.closed_ends: set[tuple[int, bool]] = set()
        self.last_mean = 0.0
        self.last_outliers = 0

    @property
    def alive(self) -> np.ndarray:
        """(P,) bool, the pairs still in the graph (a read-only view)."""
        view = self._alive.view()
        view.flags.writeable = False
        return view

    @property
    def pair_count(self) -> int:
        """Pairs still in the graph."""
        return int(self._alive.sum())

    def remove_pairs(self, pairs) -> None:
        """Take pairs (indices into :attr:`pairs`) out of the graph for good, as a cut point
        does with the pairs through its sphere."""
        pairs = np.unique(np.asarray(pairs, dtype=np.int64).reshape(-1))
        gone = pairs[self._alive[pairs]]
        self._alive[gone] = False
        if not self._views:  # a copy: write it back
            self._copy_in(self._alive_wp, self._alive)
        self._drop_pairs(gone)

    def _setup_kernel(self) -> None:
        from ..kernels import cut_detection as k

        d, P, F = self._device, len(self.pairs), len(self.rest_features)
        # the pairs of each feature: feature f has incident[incident_start[f]:incident_start[f + 1]]
        ends = np.concatenate([self._l, self._m])
        order = np.argsort(ends, kind="stable")
        # every array the graphs read or write is held here: a captured graph keeps only pointers
        self._active_wp = wp.zeros(F, dtype=wp.bool, device=d)
        # the pairs in the graph; coincident features would divide by zero in eq. 7.10
        self._alive_wp = wp.array(self.rest_length > 0, dtype=wp.bool, device=d)
        self._mean_wp = wp.zeros(1, dtype=float, device=d)
        self._packed_active_wp = wp.zeros(F, dtype=wp.bool, device=d)  # the features packed for
        self._incident_start_wp = wp.array(np.searchsorted(ends[order], np.arange(F + 1)), dtype=wp.int32, device=d)
        self._incident_wp = wp.array(order % max(P, 1), dtype=wp.int32, device=d)
        self._slot_wp = wp.full(P, -1, dtype=wp.int32, device=d)  # pair -> its packed index, -1: not measured
        self._repack_wp = wp.zeros(1, dtype=wp.int32, device=d)
        self._pair_start_wp = wp.zeros(F + 1, dtype=wp.int32, device=d)
        self._pair_other_wp = wp.zeros(P, dtype=wp.int32, device=d)
        self._inverse_length_wp = wp.zeros(P, dtype=float, device=d)
        self._measured_wp = wp.zeros(1, dtype=wp.int32, device=d)  # of which not removed since the packing
        self._current_wp = wp.zeros(F, dtype=wp.vec3, device=d)
        self._target_wp = wp.zeros(F, dtype=wp.vec3, device=d)
        self._vectors_wp = wp.zeros(F, dtype=k.mat23, device=d)
        self._mu_wp = wp.zeros(P, dtype=float, device=d)
        self._sum_wp = wp.zeros(1, dtype=float, device=d)
        self._max_wp = wp.zeros(1, dtype=float, device=d)
        self._midpoint_wp = wp.zeros(P, dtype=wp.vec3, device=d)
        self._threshold_wp = wp.zeros(1, dtype=float, device=d)
        self._outliers_wp = wp.zeros(1, dtype=wp.int32, device=d)
        largest = self._largest_wp = wp.zeros(1, dtype=float, device=d)
        strongest = self._strongest_wp = wp.zeros(1, dtype=wp.int32, device=d)
        row_max = self._row_max_wp = wp.zeros(F, dtype=float, device=d)
        self._point_wp = wp.zeros(1, dtype=wp.vec3d, device=d)
        self._pair_rest_wp = (wp.array(self._midpoints, dtype=wp.vec3d, device=d),
                              wp.array(0.5 * (self.rest_features[self._m] - self.rest_features[self._l]),
                                       dtype=wp.vec3d, device=d))
        self._cluster_sum_wp = wp.zeros(1, dtype=wp.vec4, device=d)
        self._cluster_count_wp = wp.zeros(1, dtype=wp.int32, device=d)
        chunk = max(P, 1) if d.is_cpu else 1  # the CPU runs a launch's threads in turn: one thread, one pass
        rows = max(F, 1) if d.is_cpu else 1
        threads, row_threads, p = max(-(-P // chunk), 1), max(-(-F // rows), 1), self.params
        reach = p.cluster_radius or 2.0 * p.cut_point_radius

        def launch_measure():
            for array in (self._repack_wp, self._sum_wp, self._max_wp, self._mean_wp, self._outliers_wp, largest,
                          self._cluster_sum_wp, self._cluster_count_wp):
                array.zero_()
            strongest.fill_(P)
            wp.launch(k.prepare_features, row_threads, device=d,
                      inputs=[self._current_wp, self._target_wp, int(p.measure == "target"), self._active_wp,
                              self._incident_start_wp, self._incident_wp, rows],
                      outputs=[self._vectors_wp, self._packed_active_wp, self._slot_wp, self._inverse_length_wp,
                               self._measured_wp, self._repack_wp])
            wp.launch(k.pair_measure, row_threads, device=d,
                      inputs=[self._pair_start_wp, self._pair_other_wp, self._inverse_length_wp, self._vectors_wp,
                              rows],
                      outputs=[self._mu_wp, row_max, self._sum_wp, self._max_wp])
            wp.launch(k.count_outliers, row_threads, device=d,
                      inputs=[self._mu_wp, self._pair_start_wp, row_max, self._measured_wp, self._sum_wp,
                              self._max_wp, self._repack_wp, p.tau, p.min_measure, rows],
                      outputs=[self._mean_wp, self._threshold_wp, self._outliers_wp, largest, strongest])

        with wp.ScopedCapture(device=d) as capture:  # measure() inspects, it puts no cut point
            launch_measure()
        self._measure_graph = capture.graph
        # one graph per frame: on the CPU its replay costs about a microsecond of Python, against
        # some 5 us per recorded launch and more per numpy call when the loop has cooled the caches
        with wp.ScopedCapture(device=d) as capture:
            launch_measure()
            wp.launch(k.first_strongest, row_threads, device=d,
                      inputs=[self._mu_wp, self._pair_start_wp, row_max, self._outliers_wp, largest, p.min_outliers,
                              rows], outputs=[strongest])
            wp.launch(k.outlier_cluster, row_threads, device=d,
                      inputs=[self._mu_wp, self._midpoint_wp, self._pair_start_wp, row_max, self._threshold_wp,
                              self._outliers_wp, strongest, p.min_outliers, reach, rows],
                      outputs=[self._cluster_sum_wp, self._cluster_count_wp])
            wp.launch(k.cluster_cut_point, 1, device=d, inputs=[self._cluster_sum_wp, self._cluster_count_wp,
                                                                p.min_outliers], outputs=[self._point_wp])
            wp.launch(k.remove_pairs_near_point, threads, device=d,
                      inputs=[*self._pair_rest_wp, self._point_wp, float(p.cut_point_radius), self._cluster_count_wp,
                              p.min_outliers, chunk],
                      outputs=[self._alive_wp, self._slot_wp, self._inverse_length_wp, self._measured_wp])
        self._graph = capture.graph
        # CPU arrays are shared with numpy: inputs are written in place and results read without a call
        self._views = {id(a): a.numpy() for a in (self._active_wp, self._alive_wp, self._packed_active_wp,
                                                  self._slot_wp, self._repack_wp, self._pair_start_wp,
                                                  self._pair_other_wp, self._inverse_length_wp, self._measured_wp,
                                                  self._current_wp, self._target_wp, self._mu_wp, self._sum_wp,
                                                  self._mean_wp, self._midpoint_wp, self._outliers_wp,
                                                  self._cluster_count_wp, self._point_wp)} if d.is_cpu else {}
        self._alive = self._read(self._alive_wp)  # CPU: the graph's array; else a copy kept in step
        self._packed = 0  # pairs packed
        self._measured = 0  # of which not removed since
        self._repack_next = False  # pack again before the next frame's graph

    def _pack_live(self, active: np.ndarray) -> None:
        """Pack the live pairs (in the graph, both features active) at the front of the
        kernel's pair arrays. Between packings pairs leave in place: the graph takes out those
        of features that stop pulling (every change of a video but the first frame's) and those
        through a cut point's sphere, :meth:`remove_pairs` the ones it is given; the pairs are
        packed again when a feature comes back or fewer than :data:`REPACK_BELOW` of the packed
        ones are left."""
        P = len(self.pairs)
        live = np.flatnonzero(self._alive & active[self._l] & active[self._m])
        n = self._measured = self._packed = len(live)
        slot = np.full(P, -1, dtype=np.int32)
        slot[live] = np.arange(n)
        other = np.zeros(P, dtype=np.int32)
        other[:n] = self._m[live]
        start = np.searchsorted(self._l[live], np.arange(len(self.rest_features) + 1))  # pairs sorted by l
        inverse = np.zeros(P, dtype=np.float32)
        inverse[:n] = 1.0 / self.rest_length[live]
        midpoints = np.zeros((P, 3), dtype=np.float32)
        midpoints[:n] = self._midpoints[live]
        for array, value in ((self._pair_start_wp, start), (self._pair_other_wp, other),
                             (self._inverse_length_wp, inverse), (self._midpoint_wp, midpoints),
                             (self._slot_wp, slot), (self._packed_active_wp, active),
                             (self._measured_wp, np.array([n]))):
            self._copy_in(array, value)
        self._repack_next = False

    @property
    def _sparse(self) -> bool:
        """Whether fewer than :data:`REPACK_BELOW` of the packed pairs are still measured."""
        return self._measured < REPACK_BELOW * self._packed

    def _drop_pairs(self, pairs: np.ndarray) -> None:
        """Take distinct pairs out of the packed ones in place: their ``1 / delta^0`` becomes 0,
        so they measure 0, and the mean's count drops."""
        slot, inverse = self._read(self._slot_wp), self._read(self._inverse_length_wp)  # CPU: the arrays
        slots = slot[pairs]
        slots = slots[slots >= 0]
        if len(slots) == 0:
            return
        slot[pairs] = -1
        inverse[slots] = 0.0
        self._measured -= len(slots)
        if not self._views:  # copies: write them back
            self._copy_in(self._slot_wp, slot)
            self._copy_in(self._inverse_length_wp, inverse)
        self._copy_in(self._measured_wp, np.array([self._measured]))
        self._repack_next = self._sparse

    def _measure_live(self, current, target, active, graph) -> int:
        """Replay ``graph`` (the measure and the outlier count on the live pairs for these
        features, and the cut point if it is the update's); returns the live pairs' number."""
        if not (type(active) is np.ndarray and active.dtype == bool and active.ndim == 1):  # the loop's is
            active = np.asarray(active, dtype=bool).reshape(-1)
        if len(active) != len(self.rest_features):
            raise WcutError(f"cut detection: {len(active)} active flags for {len(self.rest_features)} features")
        if self._repack_next:
            self._pack_live(active)
        self._copy_in(self._active_wp, active)
        self._copy_in(self._current_wp, current)
        self._copy_in(self._target_wp, target)
        wp.capture_launch(graph)
        if self._read(self._repack_wp)[0]:  # a feature tracked again: its pairs were not measured
            self._pack_live(active)
            wp.capture_launch(graph)
        self._measured = int(self._read(self._measured_wp)[0])
        self._repack_next = self._sparse
        return self._measured

    def measure(self, current, target, active) -> tuple[np.ndarray, int, float]:
        """``(mu, live, mean)``: the measure of eq. 7.11 for every pair (P,), -1 where it is not
        defined (out of the graph, or a feature not active); the number of live pairs and their
        mean measure. ``current`` (F, 3) are the features on the model ``p^t``, ``target``
        (F, 3) their targets ``p^1`` (m), ``active`` (F,) bool."""
        n = self._measure_live(current, target, active, self._measure_graph)
        mu = np.full(len(self.pairs), -1.0, dtype=np.float32)
        slot = self._read(self._slot_wp)
        packed = slot >= 0
        mu[packed] = self._read(self._mu_wp)[slot[packed]]
        return mu, n, float(self._read(self._mean_wp)[0])

    def _copy_in(self, array: wp.array, value) -> None:
        """Copy a numpy array into a Warp array: in place through the shared view on the CPU
        (``assign`` costs some 30 us there, more than the measure itself), else by ``assign``."""
        view = self._views.get(id(array))
        if view is not None:
            view[...] = value  # casts, and fills a (1, 3) view from a (3,) point
        else:
            dtype = wp.dtype_to_numpy(getattr(array.dtype, "_wp_scalar_type_", array.dtype))
            array.assign(np.asarray(value, dtype=dtype))

    def _read(self, array: wp.array) -> np.ndarray:
        view = self._views.get(id(array))
        return view if view is not None else array.numpy()

    def update(self, current, target, active) -> CutPoint | None:
        """One detection step: the new cut point, or None.

        The measure, its mean, the outliers, their cluster around the strongest one, the cut
        point and the pairs it removes are one graph launch; Python reads a few numbers, and
        works (on the polygons) only when a cut point is put.

        Args:
            current: (F, 3) features on the model ``p^t`` (m).
            target: (F, 3) their targets ``p^1`` (m).
            active: (F,) bool, features still tracked and pulling.
        """
        # the count is read after the graph, whose cut point may have taken out every pair:
        # the graph clears the mean, outliers and cluster when there is nothing to measure
        self._measure_live(current, target, active, self._graph)
        self.last_mean = float(self._read(self._mean_wp)[0])
        self.last_outliers = int(self._read(self._outliers_wp)[0])
        if self.last_outliers < self.params.min_outliers:
            return None
        near = int(self._read(self._cluster_count_wp)[0])
        if near < self.params.min_outliers:
            return None
        point = np.array(self._read(self._point_wp)[0], dtype=np.float64)
        if not self._views:  # the graph took the pairs through the cut point out
            self._alive[:] = self._read(self._alive_wp)
        return self._extend(point, near)

    def close_end(self, polygon: int, at_start: bool) -> None:
        """Close an end of polygon ``polygon`` (its first point's end if ``at_start``): its cut
        went through the object's boundary, so no later cut point extends it."""
        if not 0 <= polygon < len(self.polygons):
            raise WcutError(f"cut detection: no polygon {polygon} (there are {len(self.polygons)})")
        self.closed_ends.add((polygon, bool(at_start)))

    def _extend(self, point: np.ndarray, outliers: int) -> CutPoint:
        """Put ``point`` at the nearest open polygon end within ``join_radius`` (figure 7.7,
        middle) with its look-ahead, or start a new polygon with it."""
        join = self.params.join_radius or 3.0 * self.params.cut_point_radius
        best, index, at_start = math.inf, -1, False
        at = point.tolist()  # plain floats: a few distances, where numpy's per-call cost dominates
        closed = self.closed_ends
        for k, polygon in enumerate(self.polygons):
            for start, end in ((False, polygon[-1]), (True, polygon[0])):
                if (k, start) in closed:
                    continue
                gap = math.dist(at, end.tolist())
                if gap < best and gap <= join and not (start and len(polygon) == 1):
                    best, index, at_start = gap, k, start
        if index < 0:
            self.polygons.append(point[None].copy())
            return CutPoint(point, len(self.polygons) - 1, None, None, None, False, outliers)
        polygon = self.polygons[index]
        previous = polygon[0] if at_start else polygon[-1]
        if len(polygon) >= 2 and self.params.max_turn < 180.0:
            before = polygon[1] if at_start else polygon[-2]
            d0, d1 = previous - before, point - previous
            n0, n1 = float(np.linalg.norm(d0)), float(np.linalg.norm(d1))
            if n0 > 0.0 and n1 > 0.0 and d0 @ d1 < math.cos(math.radians(self.params.max_turn)) * n0 * n1:
                return None
        self.polygons[index] = np.vstack([point, polygon] if at_start else [polygon, point])
        step = point - previous
        length = math.dist(at, previous.tolist())
        if length == 0.0:
            return CutPoint(point, index, previous.copy(), None, None, at_start, outliers)
        r = self.params.cut_point_radius * step / length
        back = previous - r if len(polygon) == 1 and (index, True) not in closed else None
        return CutPoint(point, index, previous.copy(), point + r, back, at_start, outliers)
