"""The augmented-reality loop: ``wcut ar DIR -o OUT.usdc`` (thesis chapter 7, figure 7.1).

Per frame: track the features (7.4.1), lift them to targets in 3D (7.4.2), pull the model
towards them with springs and one implicit corotational solve (eq. 7.2-7.3, 7.4.3), compare
the model's features with their targets to detect a cut (7.5.2-7.5.3), and where one is
found cut the model with the chapter 5 cutter along the cut polygon extruded along the
camera's rays, drop the springs near it, and update the internal structures (7.5.4).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..cut.surface import joined, strip
from ..errors import CaptureError, SimulationError
from ..io import atomic_path
from ..model import Attachments, Model
from ..scene import _progress, render_surface
from .capture import Capture
from .detection import CutDetector, DetectionParams
from .embedding import Embedding, mapped_points
from .features import FeatureTracker, detect_features
from .internal import InternalStructure
from .lifting import intercept_update, plane_points

#: samples along the extruded blade at a cut point (its ends stick out of the object)
BLADE_SAMPLES = 9
#: points along ``boundary_reach`` beyond a look-ahead tested for the object's boundary
BOUNDARY_SAMPLES = 21
#: directions, across the view, searched for the boundary nearest a polygon's first point
ENTRY_DIRECTIONS = 32
#: a vertex farther than this many rest sizes from the rest centre means divergence: a band
#: stretched to 186% reaches less than one, while an S-example run that blew up (a Dice of
#: 0.61) had a vertex 5 m out, about 40, under the former bound of 100
BOUNDED_REACH = 5.0


@dataclass
class ArResult:
    """What :func:`run_ar` measured; :meth:`metrics` is the JSON of ``--metrics``."""

    frames: int = 0
    features: int = 0
    features_lost: int = 0
    pairs_initial: int = 0
    pairs_final: int = 0
    cuts_detected: int = 0
    cut_events: int = 0
    first_detection_frame: int | None = None
    detection_ms: list = field(default_factory=list)
    frame_ms: list = field(default_factory=list)
    nodes_initial: int = 0
    nodes_final: int = 0
    elements_final: int = 0
    springs_removed: int = 0
    internal_deleted: int = 0
    dice_final: float | None = None
    dice_initial: float | None = None
    hausdorff_surface: tuple | None = None
    hausdorff_internal: tuple | None = None
    feature_error: tuple | None = None
    cut: bool = True

    def metrics(self) -> dict:
        """The per-run metrics (distances in m, times in ms)."""
        def pair(value, k):  # JSON has no NaN: a measure with nothing to measure is null
            return None if value is None or not np.isfinite(value[k]) else float(value[k])

        return {
            "dice_final": self.dice_final, "dice_initial": self.dice_initial,
            "hausdorff_surface_mean": pair(self.hausdorff_surface, 0),
            "hausdorff_surface_max": pair(self.hausdorff_surface, 1),
            "hausdorff_internal_mean": pair(self.hausdorff_internal, 0),
            "hausdorff_internal_max": pair(self.hausdorff_internal, 1),
            "feature_error_mean": pair(self.feature_error, 0), "feature_error_max": pair(self.feature_error, 1),
            "cuts_detected": self.cuts_detected, "cut_events": self.cut_events,
            "first_detection_frame": self.first_detection_frame,
            "detection_ms_mean": float(np.mean(self.detection_ms)) if self.detection_ms else 0.0,
            "detection_ms_max": float(np.max(self.detection_ms)) if self.detection_ms else 0.0,
            "fps_mean": 1e3 / float(np.mean(self.frame_ms)) if self.frame_ms else 0.0,
            "frame_ms_mean": float(np.mean(self.frame_ms)) if self.frame_ms else 0.0,
            "frames": self.frames, "features": self.features, "features_lost": self.features_lost,
            "pairs_initial": self.pairs_initial, "pairs_final": self.pairs_final,
            "nodes_initial": self.nodes_initial, "nodes_final": self.nodes_final,
            "elements_final": self.elements_final, "springs_removed": self.springs_removed,
            "internal_triangles_deleted": self.internal_deleted, "cut_handling": self.cut,
            "units": {"distances": "m", "times": "ms"},
        }


class ArTracker:
    """The registered model following the video, and its cut detection (one object per run).

    Args:
        capture: the :class:`Capture`.
        first_frame: (H, W, 3) uint8 BGR first frame (the model is registered to it).
        cut: detect and make cuts (False: the ``--no-cut`` comparison).
        device: Warp device.

    Attributes:
        model, state, control, solver: the simulation (rebuilt after every cut).
        mesh: the model's mesh (after the cuts so far).
        tracker: the :class:`FeatureTracker`; features (F,) index every per-feature array.
        embedding: the features' material points in the model.
        targets: (F, 3) the latest targets ``p^1`` (m).
        pulling: (F,) bool, features whose spring pulls (tracked and not near a cut).
        detector: the :class:`CutDetector` (None without cut handling).
        internal: the :class:`InternalStructure` list.
    """

    def __init__(self, capture: Capture, first_frame: np.ndarray, *, cut: bool = True, device=None):
        from ..cut import Cutter
        from ..topology import TetTopology
        from .render import Renderer

        self.capture, self.camera, p = capture, capture.camera, capture.params
        self.params, self.device, self.cut_enabled = p, device, cut
        self.mesh = capture.model
        rest, tets = self.mesh.vertices, self.mesh.tets
        self.dt = 1.0 / (p.video["fps"] * p.solver["substeps"])
        self._rest_centre = rest.mean(axis=0).astype(np.float32)
        self._rest_size = float(np.linalg.norm(np.ptp(rest, axis=0)))

        gray = cv2.cvtColor(first_frame, cv2.COLOR_BGR2GRAY)
        f = p.features
        pixels = detect_features(gray, capture.mask, max_count=f["max_count"], method=f["method"],
                                 min_distance=f["min_distance"], quality=f["quality"])
        centre_depth = float((rest.mean(axis=0) - self.camera.center) @ self.camera.view_direction)
        self.plane_depth = p.lifting["plane_depth"] or centre_depth
        self.surface_mode = p.lifting["mode"] == "surface"
        if self.surface_mode:  # 7.4.2: the ray's first hit on the model's surface
            surface = self.mesh.boundary()
            face, bary, _ = Renderer(self.camera, device=device).cast_pixels(pixels, rest, surface.triangles)
            hit = face >= 0
            corners = rest[surface.triangles[np.maximum(face, 0)]]
            points = np.einsum("kc,kcj->kj", bary, corners)
            embedding, inside = Embedding.locate_inside(rest, tets, points[hit])
            keep = np.flatnonzero(hit)[inside]
        else:
            points = plane_points(self.camera, pixels, self.plane_depth)
            embedding, inside = Embedding.locate_inside(rest, tets, points)
            keep = np.flatnonzero(inside)
        if len(keep) < 3:
            raise CaptureError(f"{capture.directory.name}: only {len(keep)} of {len(pixels)} features lie on the "
                               f"model: is the model registered to the first frame (camera.json, model)?")
        pixels = pixels[keep]
        self.embedding = embedding
        self.tracker = FeatureTracker(gray, pixels, window=f["window"], levels=f["levels"],
                                      fb_threshold=f["fb_threshold"], jump_factor=f["jump_factor"],
                                      jump_floor=f["jump_floor"])
        self.targets = embedding.rest_points.copy()
        self._plane = plane_points(self.camera, pixels, self.plane_depth)
        self.pulling = np.ones(len(pixels), dtype=bool)
        self.springs_removed = self.cuts_detected = self.cut_events = 0

        m = p.model
        self.model = Model(self.mesh, density=m["density"], youngs_modulus=m["youngs_modulus"],
                           poisson_ratio=m["poisson_ratio"], rayleigh_mass=m["rayleigh_mass"],
                           rayleigh_stiffness=m["rayleigh_stiffness"], gravity=(0.0, 0.0, 0.0),
                           attachments=self._attachments(), device=device)
        self.state, self._next, self.control = self.model.state(), self.model.state(), self.model.control()
        self.solver = self._solver()
        self.internal = [InternalStructure.embedded(name, v, t, rest, tets, what=f"internal/{name}.obj")
                         for name, v, t in capture.internal]

        d = p.detection
        spacing = _mean_spacing(self.embedding.rest_points)
        edge = self.mesh.mean_edge_length()
        self.cut_point_radius = d["cut_point_radius"] or edge
        self.margin = p.springs["margin"] or self.cut_point_radius
        self.boundary_reach = d["boundary_reach"] * self.cut_point_radius
        self.entry_reach = d["entry_reach"] * self.cut_point_radius
        self.extrusion = d["extrusion"] or float(np.linalg.norm(np.ptp(rest, axis=0)))
        self.detector = None
        if cut:
            self.detector = CutDetector(self.embedding.rest_points, DetectionParams(
                radius=d["radius"] or 2.5 * spacing, cut_point_radius=self.cut_point_radius, tau=d["tau"],
                min_outliers=d["min_outliers"], measure=d["measure"],
                min_measure=d["min_measure"] or 0.2 * spacing, max_turn=d["max_turn"]))
            self.topology = TetTopology(self.mesh)
            self.cutter = Cutter(self.topology, method=d["method"], epsilon=d["epsilon"])
            self._tips: dict[tuple[int, bool], tuple] = {}  # (polygon, at start) -> blade

    # ------------------------------------------------------------------ set-up
    def _attachments(self) -> Attachments:
        stiffness = np.where(self.pulling, self.params.springs["stiffness"], 0.0)
        return Attachments(self.mesh.tets[self.embedding.element].astype(np.int32), self.embedding.weights, stiffness)

    def _solver(self):
        from ..solver import SolverCorotational

        s = self.params.solver
        return SolverCorotational(self.model, cg_iterations=s["cg_iterations"], cg_tolerance=s["cg_tolerance"],
                                  rotation_stiffness=s["rotation_stiffness"])

    # ------------------------------------------------------------------ per frame
    def features_on_model(self) -> np.ndarray:
        """(F, 3) the features' current positions on the model ``p^t`` (m)."""
        return self.embedding.positions(self.state.particle_q.numpy().astype(np.float64), self.mesh.tets)

    def step(self, frame: np.ndarray) -> float:
        """Follow one more frame (BGR); returns the detection time (ms, 0 without cut handling)."""
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        was = self.tracker.active.copy()
        self.tracker.track(gray)
        plane = plane_points(self.camera, self.tracker.points, self.plane_depth)
        if self.surface_mode:  # eq. 7.1: surface targets move by the plane motion scaled to their depth
            self.targets = intercept_update(self.targets, self._plane, plane, self.camera.center)
        else:
            self.targets = plane
        self._plane = plane
        if (was != self.tracker.active).any():
            self._set_pulling(self.pulling & self.tracker.active)
        self.control.attachment_target.assign(self.targets.astype(np.float32))
        for _ in range(self.params.solver["substeps"]):
            self.solver.step(self.state, self._next, self.control, self.dt)
            self.state, self._next = self._next, self.state
        self.solver.check()
        self._check_bounded()
        if self.detector is None:
            return 0.0
        current = self.features_on_model()
        start = time.perf_counter()
        found = self.detector.update(current, self.targets, self.pulling)
        elapsed = 1e3 * (time.perf_counter() - start)
        if found is not None:
            self._cut(found)
        return elapsed

    def _check_bounded(self) -> None:
        """Raise :class:`wcut.SimulationError` when the model has left the scene: a vertex
        farther from the model's rest centre than :data:`BOUNDED_REACH` times its rest size
        (the diagonal of its rest bounding box). A finite but exploding model would otherwise
        go on into the cutter with absurd coordinates and give metrics that mean nothing."""
        x = self.state.particle_q.numpy()
        reach = np.abs(x - self._rest_centre).max()
        if not reach <= BOUNDED_REACH * self._rest_size:
            raise SimulationError(f"the model diverged: a vertex is {reach:.3g} m from its rest centre (rest size "
                                  f"{self._rest_size:.3g} m); try stiffer springs, other detection settings "
                                  f"or solver.substeps = 2")

    def _set_pulling(self, pulling: np.ndarray) -> None:
        self.pulling = pulling
        stiffness = np.where(pulling, self.params.springs["stiffness"], 0.0).astype(np.float32)
        self.model.attachment_stiffness.assign(stiffness)

    # ------------------------------------------------------------------ cutting
    def _blade(self, material_point: np.ndarray, x: np.ndarray) -> tuple:
        """The extruded cut at a material point (7.5.3): the segment along the camera ray
        through its current position, ``extrusion`` long either side, sampled in the current
        configuration and mapped to the rest configuration. Returns (point, current samples,
        rest samples)."""
        point = mapped_points(self.mesh.vertices, self.mesh.tets, x, material_point)[0]
        ray = point - self.camera.center
        ray /= np.linalg.norm(ray)
        s = np.linspace(-self.extrusion, self.extrusion, BLADE_SAMPLES)[:, None]
        current = point + s * ray
        return material_point, current, self.topology.rest_points(current)

    def _through_boundary(self, look_ahead: np.ndarray, direction: np.ndarray) -> np.ndarray | None:
        """Where a cut whose look-ahead is ``look_ahead`` (m, rest) ends instead when the
        object's boundary lies less than ``boundary_reach`` (m) beyond it along ``direction``:
        ``cut_point_radius`` past that boundary, so the blade leaves the object. None
        otherwise, and always when ``boundary_reach`` is 0 (the default).

        Features stop before the boundary and a cut point takes out the pairs within a radius
        of it, so no cut point comes much closer to the boundary than a radius, and a tear that
        ran out through it stays bridged by the last few millimetres (the look-ahead, one
        radius, does not always reach). The thesis's earlier rule ([78, 79], 7.5.3) lengthens
        the cut through the boundary when no features are left in front of it; this is that
        rule with ``boundary_reach`` as "in front". It cannot tell such a tear from a cut that
        stops just short of the boundary (a buttonhole slit 5 mm from the band's sides is cut
        through with a reach of one 4 mm radius), so it is a per-scene setting."""
        reach = self.boundary_reach
        if reach <= 0.0:
            return None
        unit = direction / np.linalg.norm(direction)
        exit_at = self._exit_distances(look_ahead, unit[None], reach)[0]
        if not np.isfinite(exit_at):
            return None
        return look_ahead + (exit_at + self.cut_point_radius) * unit

    def _exit_distances(self, point: np.ndarray, directions: np.ndarray, reach: float) -> np.ndarray:
        """(D,) distance (m) from ``point`` along each unit direction (D, 3) to where the rest
        mesh ends, sampled at ``BOUNDARY_SAMPLES`` points up to ``reach``; inf where it
        does not end within ``reach``."""
        s = np.linspace(0.0, reach, BOUNDARY_SAMPLES)
        samples = point + s[None, :, None] * directions[:, None, :]
        _, inside = Embedding.locate_inside(self.mesh.vertices, self.mesh.tets, samples.reshape(-1, 3))
        inside = inside.reshape(len(directions), BOUNDARY_SAMPLES)
        return np.where(inside.all(axis=1), np.inf, s[np.argmin(inside, axis=1)])

    def _entry(self, point: np.ndarray) -> tuple | None:
        """Where a cut whose first point is ``point`` (m, rest) comes in from the boundary:
        when the object's outline, searched across the view (perpendicular to the camera's
        axis), lies less than ``entry_reach`` (m) from the point, ``(outside, look_ahead)``:
        ``cut_point_radius`` beyond that boundary, and one radius past the point away from
        it. None otherwise, and always when ``entry_reach`` is 0 (the default).

        A cut from the side opens widest at the boundary, so its first point lies there, a
        radius or less inside (features stop before the boundary); the pairs this point takes
        out can leave too few outliers along the narrower rest of the slit for a second point,
        and a polygon of one point cuts nothing. This is :meth:`_through_boundary`'s rule at
        a polygon's start. It cannot tell a cut from the side from a first point that merely
        lies near the boundary (on the kidney, whose cut reaches the flank from inside, it
        cut the wrong way and the model diverged), so it is a per-scene setting."""
        reach = self.entry_reach
        if reach <= 0.0:
            return None
        axis = self.camera.view_direction
        helper = np.eye(3)[np.argmin(np.abs(axis))]
        e1 = np.cross(axis, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        angles = np.linspace(0.0, 2.0 * np.pi, ENTRY_DIRECTIONS, endpoint=False)
        directions = np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2
        exit_at = self._exit_distances(point, directions, reach)
        j = int(np.argmin(exit_at))
        if not np.isfinite(exit_at[j]):
            return None
        outward = directions[j]
        return point + (exit_at[j] + self.cut_point_radius) * outward, point - self.cut_point_radius * outward

    def _cut(self, found) -> None:
        """Cut the model along the polygon's new piece (figure 7.7) and carry everything over.

        The cut is the surface swept by the extruded blade from the polygon end's last tip
        through the new point to its look-ahead; the cutter cuts it progressively, so an
        element opens once the blade has gone through it. A look-ahead less than
        ``boundary_reach`` from the boundary carries the cut through it
        (:meth:`_through_boundary`) and closes that end of the polygon; a polygon's first
        point less than ``entry_reach`` from the boundary starts a cut from it (:meth:`_entry`)."""
        self.cuts_detected += 1
        x = self.state.particle_q.numpy().astype(np.float64)
        n = self.topology.vertex_count
        self.topology.positions[:] = x[:n]
        self.topology.velocities[:] = self.state.particle_qd.numpy()[:n]
        k = found.polygon
        if found.previous is None:  # a polygon's first point: a blade, nothing swept yet
            self._tips[(k, False)] = self._tips[(k, True)] = self._blade(found.point, x)
            entry = self._entry(found.point)
            if entry is None:
                return
            path = [self._blade(entry[0], x), self._tips[(k, False)], self._blade(entry[1], x)]
            self.detector.close_end(k, True)  # the polygon grows from its look-ahead only
            self._tips[(k, False)] = path[-1]
            self._cut_along(path)
            return
        tip = self._tips[(k, found.at_start)]
        path = [tip] if found.back is None else [self._blade(found.back, x), tip]
        direction = found.point - found.previous
        if (found.point - tip[0]) @ direction > 0:  # not behind the last look-ahead
            path.append(self._blade(found.point, x))
        if found.look_ahead is not None:
            path.append(self._blade(found.look_ahead, x))
            beyond = self._through_boundary(found.look_ahead, found.look_ahead - found.point)
            if beyond is not None:
                path.append(self._blade(beyond, x))
                self.detector.close_end(k, found.at_start)
        if found.back is not None:
            beyond = self._through_boundary(found.back, found.back - found.previous)
            if beyond is not None:
                path.insert(0, self._blade(beyond, x))
                self.detector.close_end(k, not found.at_start)
            self._tips[(k, not found.at_start)] = path[0]
        self._tips[(k, found.at_start)] = path[-1]
        self._cut_along(path)

    def _cut_along(self, path: list) -> None:
        """Cut progressively along the blades of ``path`` (see :meth:`_blade`), and carry the
        features, internal structures, springs, model and solver over to the cut mesh."""
        rest_pieces = [s for s in (strip(a[2], b[2]) for a, b in zip(path, path[1:])) if s is not None]
        current_pieces = [s for s in (strip(a[1], b[1]) for a, b in zip(path, path[1:])) if s is not None]
        if not rest_pieces:
            return
        increment = joined(rest_pieces)
        change = self.cutter.cut(increment, progressive=True, rest=True).change
        for s in self.internal:  # eq. 7.12: the structure's triangles the cut crosses go
            s.cut(increment)
        if current_pieces:  # springs near the cut would close it again (figure 7.8)
            near = joined(current_pieces).distance(self.features_on_model(), self.margin) <= self.margin
            self.springs_removed += int((self.pulling & near).sum())
            self.pulling = self.pulling & ~near
        if change.is_empty:
            self._set_pulling(self.pulling)
            return
        self.cut_events += 1
        mesh = self.topology.to_mesh()
        self.embedding = self.embedding.after(change, mesh.vertices, mesh.tets)
        for s in self.internal:
            s.after(change, mesh.vertices, mesh.tets)
        targets = self.control.attachment_target.numpy()
        self.model, self.state = self.model.rebuild(mesh, change, self.state, in_place=True)  # old ones dropped
        self.mesh = mesh
        attachments = self._attachments()
        self.model.attachment_indices.assign(attachments.indices)
        self.model.attachment_weights.assign(attachments.weights.astype(np.float32))
        self.model.attachment_stiffness.assign(attachments.stiffness.astype(np.float32))
        self._next, self.control = self.model.state(), self.model.control()
        self.control.attachment_target.assign(targets)
        self.solver = self._solver()


def _mean_spacing(points: np.ndarray) -> float:
    """Mean distance (m) from each point to its nearest neighbour."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 1.0
    d, _ = cKDTree(points).query(points, k=2)
    return float(d[:, 1].mean())


def run_ar(directory, output, *, overlay=None, metrics=None, cut: bool = True, frames: int | None = None,
           progress: bool | None = None, device=None) -> ArResult:
    """Run the pipeline on a capture directory; write the USD animation of the model and its
    internal structures to ``output``, and optionally the overlay video and the metrics JSON.

    ``frames`` limits the frames used (default: all). The frame rate reported (``fps_mean``)
    times the loop (tracking, lifting, solve, detection, cut), not the output.
    Every file is written atomically; on an error none is left behind.
    """
    import sys

    from ..io import check_writable
    from ..usd import UsdAnimationWriter
    from .metrics import dice, feature_error, hausdorff, rasterize
    from .overlay import VideoOut, draw_overlay

    capture = Capture(directory)
    output = Path(output)
    for path in (output, overlay, metrics):
        if path is not None:
            check_writable(Path(path))
    total = capture.frame_count if frames is None else min(int(frames), capture.frame_count)
    if total < 1:
        raise CaptureError(f"{capture.directory.name}: the video has no frame")
    writer = UsdAnimationWriter(output, fps=capture.params.video["fps"], up_axis="Z")
    camera = capture.camera
    video = VideoOut(overlay, capture.params.video["fps"], (camera.width, camera.height)) if overlay else None
    result = ArResult(cut=cut)
    show = sys.stderr.isatty() if progress is None else progress
    bar = _progress(total, show, f"ar {capture.directory.name}")
    frames_iter = capture.frames()
    try:
        if video is not None:
            video.__enter__()
        with writer:
            first = next(frames_iter)
            ar = ArTracker(capture, first, cut=cut, device=device)
            result.features, result.nodes_initial = len(ar.pulling), ar.model.particle_count
            result.pairs_initial = ar.detector.pair_count if ar.detector else 0
            mesh_id, surface = None, None
            index = 0
            frame = first
            while True:
                if mesh_id is not id(ar.mesh):
                    mesh_id, surface = id(ar.mesh), render_surface(ar.mesh)
                x = ar.state.particle_q.numpy().astype(np.float64)
                points = surface.points(x)
                writer.write_frame("model", index, points, surface.triangles)
                internal = [(s.positions(x, ar.mesh.tets), s.triangles) for s in ar.internal]
                for s, (p, t) in zip(ar.internal, internal):
                    if len(t):
                        writer.write_frame(s.name, index, p, t)
                if video is not None:
                    polygons = ar.detector.polygons if ar.detector is not None else []
                    drawn = draw_overlay(frame, camera, points, surface.triangles, internal,
                                         features=ar.tracker.points[ar.tracker.active])
                    for polygon in polygons:
                        if len(polygon) > 1:
                            pixels = camera.project(mapped_points(ar.mesh.vertices, ar.mesh.tets, x, polygon))[0]
                            pixels = pixels[np.isfinite(pixels).all(axis=1)]  # behind the camera: not drawn
                            cv2.polylines(drawn, [np.round(pixels).astype(np.int32)], False, (0, 0, 255), 2)
                    video.write(drawn)
                if index == 0 and capture.truth is not None:
                    truth_mask, _ = capture.truth_frame(0)
                    result.dice_initial = dice(rasterize(camera, points, surface.triangles), truth_mask)
                bar.update(1)
                index += 1
                if index >= total:
                    break
                frame = next(frames_iter, None)
                if frame is None:
                    break
                start = time.perf_counter()
                detection_ms = ar.step(frame)
                result.frame_ms.append(1e3 * (time.perf_counter() - start))
                if ar.detector is not None:
                    result.detection_ms.append(detection_ms)
                    if result.first_detection_frame is None and ar.detector.polygons:
                        result.first_detection_frame = index
            result.frames = index
            last = index - 1
            x = ar.state.particle_q.numpy().astype(np.float64)
            final = render_surface(ar.mesh)
            points, triangles = final.points(x), final.triangles
            if capture.truth is not None:
                truth_mask, truth = capture.truth_frame(last)
                result.dice_final = dice(rasterize(camera, points, triangles), truth_mask)
                spacing = 0.25 * ar.mesh.mean_edge_length()
                result.hausdorff_surface = hausdorff(points, triangles, truth["surface_points"],
                                                     truth["surface_triangles"], spacing)
                pairs = [(s.positions(x, ar.mesh.tets), s.triangles, truth.get(f"{s.name}_points"),
                          truth.get(f"{s.name}_triangles")) for s in ar.internal]
                pairs = [q for q in pairs if q[2] is not None and len(q[1]) and len(q[3])]
                if pairs:
                    measured = [hausdorff(*q, spacing) for q in pairs]
                    result.hausdorff_internal = (float(np.mean([m[0] for m in measured])),
                                                 float(np.max([m[1] for m in measured])))
            result.feature_error = feature_error(ar.features_on_model(), ar.targets, ar.pulling)
        if video is not None:
            video.__exit__(None, None, None)
            video = None
    except BaseException as exc:
        if video is not None:
            video.__exit__(type(exc), exc, exc.__traceback__)
        raise
    finally:
        bar.close()
    result.features_lost = int((~ar.tracker.active).sum())
    result.pairs_final = ar.detector.pair_count if ar.detector else 0
    result.cuts_detected, result.cut_events = ar.cuts_detected, ar.cut_events
    result.nodes_final, result.elements_final = ar.model.particle_count, ar.model.tet_count
    result.springs_removed = ar.springs_removed
    result.internal_deleted = sum(s.deleted for s in ar.internal)
    if metrics is not None:
        with atomic_path(metrics) as tmp:
            Path(tmp).write_text(json.dumps(result.metrics(), indent=1), encoding="utf-8")
    return result
