"""Ray-cast rendering of a triangle surface through a pinhole camera (thesis chapter 7).

:class:`Renderer` casts one ray per pixel from the camera centre against a ``wp.Mesh`` of the
current surface (``wcut.kernels.raycast``). It makes the synthetic "real" object of a test
video (:meth:`Renderer.render`: a tissue-like texture attached to the rest configuration, Lambert
shading with the light at the camera, a flat dark background) and lifts 2D image features to
the model surface (:meth:`Renderer.cast_pixels`: the face and barycentrics hit by the ray
through a sub-pixel coordinate). The surface BVH is built once per triangle set and refitted
when only the points move.

Units: positions and distances in metres, pixels as in :class:`wcut.ar.camera.Camera`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..errors import WcutError
from ..kernels import raycast
from .camera import Camera

#: Colours in [0, 1], BGR (OpenCV's channel order): the texture mixes a dark and a light
#: tissue tint; misses get the flat background.
TISSUE_DARK_BGR = (0.10, 0.09, 0.45)
TISSUE_LIGHT_BGR = (0.62, 0.66, 0.98)
BACKGROUND_BGR = (0.09, 0.08, 0.07)

#: Rays end this far from the camera (m).
MAX_DISTANCE = 1.0e4


class RenderError(WcutError):
    """Input of the renderer is invalid: array shapes, NaN coordinates, triangle indices out
    of range, texture parameters; the message names the argument."""


@dataclass(frozen=True)
class Texture:
    """Procedural texture attached to the material (evaluated at rest positions).

    Attributes:
        seed: integer seed of the noise (different seeds give unrelated patterns).
        scale: feature size (m): the lattice spacing of the coarsest noise octave.
        contrast: stretch of the noise about its mean (1 = plain value noise; larger values
            give sharper, more trackable spots, clamped to the two tints).
    """

    seed: int = 0
    scale: float = 4.0e-3
    contrast: float = 3.0

    def __post_init__(self):
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise RenderError(f"texture.seed: expected an integer, got {self.seed!r}")
        for name in ("scale", "contrast"):
            value = getattr(self, name)
            ok = not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))
            if not ok or not np.isfinite(value) or value <= 0:
                raise RenderError(f"texture.{name}: expected a positive number, got {value!r}")


@dataclass
class RayHits:
    """What the ray through every pixel hits (arrays of the image's shape (H, W)).

    Attributes:
        face: (H, W) int32 triangle index, -1 where the ray misses.
        bary: (H, W, 2) barycentrics ``(u, v)``: the hit is ``u p0 + v p1 + (1 - u - v) p2``
            of the triangle's vertices (0 on a miss).
        distance: (H, W) distance (m) from the camera centre to the hit, ``inf`` on a miss.
    """

    face: np.ndarray
    bary: np.ndarray
    distance: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: the ray hits the surface."""
        return self.face >= 0


def _points(value, name: str, count: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RenderError(f"{name}: expected an (N, 3) array of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise RenderError(f"{name}: expected an (N, 3) array, got shape {arr.shape}")
    if count is not None and len(arr) != count:
        raise RenderError(f"{name}: expected {count} points (one per surface point), got {len(arr)}")
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if len(bad):
        raise RenderError(f"{name}: point {bad[0]} is not finite: {arr[bad[0]].tolist()}")
    return arr


def _triangles(value, point_count: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
        raise RenderError(f"triangles: expected a non-empty (T, 3) array, got shape {arr.shape}")
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.integer):
        raise RenderError(f"triangles: expected integer vertex indices, got {arr.dtype}")
    bad = np.flatnonzero(np.any((arr < 0) | (arr >= point_count), axis=1))
    if len(bad):
        raise RenderError(
            f"triangles: triangle {bad[0]} {arr[bad[0]].tolist()} has a vertex index out of range 0..{point_count - 1}"
        )
    return arr


class Renderer:
    """Ray casting through every pixel of ``camera`` (a :class:`~wcut.ar.camera.Camera`).

    The per-pixel ray directions and output buffers are allocated once, on ``device`` (a Warp
    device or its name; Warp's default when None). Every method takes the current surface as
    ``points`` (N, 3) (m) and ``triangles`` (T, 3) vertex indices; the ``wp.Mesh`` is rebuilt
    only when the triangles (or the point count) change, otherwise its points are updated and
    its BVH refitted. Returned arrays are copies: they stay valid after the next call.
    """

    def __init__(self, camera: Camera, device=None, ambient: float = 0.3):
        if not isinstance(camera, Camera):
            raise RenderError(f"camera: expected a wcut.ar.camera.Camera, got {type(camera).__name__}")
        if not (0.0 <= ambient <= 1.0):
            raise RenderError(f"ambient: expected a value in [0, 1], got {ambient!r}")
        self.camera = camera
        self.device = wp.get_device(device)
        self.ambient = float(ambient)
        self.shape = (camera.height, camera.width)
        n = camera.height * camera.width
        self._origin = wp.vec3(*camera.center.astype(np.float32))
        self._directions = wp.array(
            camera.pixel_rays().reshape(n, 3).astype(np.float32), dtype=wp.vec3, device=self.device
        )
        self._face = wp.empty(n, dtype=wp.int32, device=self.device)
        self._bary = wp.empty(n, dtype=wp.vec2, device=self.device)
        self._distance = wp.empty(n, dtype=float, device=self.device)
        self._image = wp.empty((n, 3), dtype=wp.uint8, device=self.device)
        self._mask = wp.empty(n, dtype=wp.uint8, device=self.device)
        self._mesh: wp.Mesh | None = None
        self._mesh_points: wp.array | None = None
        self._mesh_indices: wp.array | None = None
        self._triangles: np.ndarray | None = None
        self._rest: wp.array | None = None
        #: How many times the BVH was built from scratch / refitted (for tests and profiling).
        self.builds = 0
        self.refits = 0

    # -- surface -------------------------------------------------------------------------------

    def _surface(self, points, triangles) -> wp.Mesh:
        """The ``wp.Mesh`` of the surface, rebuilt or refitted as needed."""
        pts = _points(points, "points")
        tris = _triangles(triangles, len(pts))
        p32 = pts.astype(np.float32)
        same = (
            self._mesh is not None
            and self._mesh_points.shape[0] == len(pts)
            and self._triangles.shape == tris.shape
            and np.array_equal(self._triangles, tris)
        )
        if same:
            self._mesh_points.assign(p32)
            self._mesh.refit()
            self.refits += 1
        else:
            self._triangles = tris.astype(np.int32)  # a copy: the caller may edit its array
            self._mesh_points = wp.array(p32, dtype=wp.vec3, device=self.device)
            self._mesh_indices = wp.array(self._triangles.ravel(), dtype=wp.int32, device=self.device)
            self._mesh = wp.Mesh(points=self._mesh_points, indices=self._mesh_indices)
            self.builds += 1
        return self._mesh

    def _rest_points(self, rest_points, count: int) -> wp.array:
        rest = _points(rest_points, "rest_points", count).astype(np.float32)
        if self._rest is None or self._rest.shape[0] != count:
            self._rest = wp.array(rest, dtype=wp.vec3, device=self.device)
        else:
            self._rest.assign(rest)
        return self._rest

    # -- queries -------------------------------------------------------------------------------

    def cast(self, points, triangles) -> RayHits:
        """Cast the ray of every pixel centre against the surface; see :class:`RayHits`."""
        mesh = self._surface(points, triangles)
        wp.launch(
            raycast.cast_rays,
            dim=self._directions.shape[0],
            inputs=[mesh.id, self._origin, self._directions, MAX_DISTANCE],
            outputs=[self._face, self._bary, self._distance],
            device=self.device,
        )
        h, w = self.shape
        return RayHits(
            face=self._face.numpy().reshape(h, w).copy(),
            bary=self._bary.numpy().reshape(h, w, 2).copy(),
            distance=self._distance.numpy().reshape(h, w).copy(),
        )

    def silhouette(self, points, triangles) -> np.ndarray:
        """(H, W) bool: the pixels whose centre ray hits the surface."""
        return self.cast(points, triangles).mask

    def render(self, points, triangles, rest_points, texture: Texture | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The textured, shaded image of the surface and its pixel mask.

        Args:
            points: (N, 3) current positions (m).
            triangles: (T, 3) vertex indices.
            rest_points: (N, 3) rest positions (m): the texture is evaluated there, so it
                moves and deforms with the material.
            texture: the :class:`Texture` (default ``Texture()``).

        Returns:
            ``(image, mask)``: (H, W, 3) uint8 BGR (ready for ``cv2.imwrite``) and (H, W) bool.
        """
        if texture is None:
            texture = Texture()
        if not isinstance(texture, Texture):
            raise RenderError(f"texture: expected a wcut.ar.render.Texture, got {type(texture).__name__}")
        mesh = self._surface(points, triangles)
        rest = self._rest_points(rest_points, self._mesh_points.shape[0])
        wp.launch(
            raycast.render_textured,
            dim=self._directions.shape[0],
            inputs=[
                mesh.id,
                self._mesh_indices,
                rest,
                self._origin,
                self._directions,
                MAX_DISTANCE,
                int(texture.seed) % (1 << 31),
                1.0 / float(texture.scale),
                float(texture.contrast),
                self.ambient,
                wp.vec3(*TISSUE_DARK_BGR),
                wp.vec3(*TISSUE_LIGHT_BGR),
                wp.vec3(*BACKGROUND_BGR),
            ],
            outputs=[self._image, self._mask],
            device=self.device,
        )
        h, w = self.shape
        image = self._image.numpy().reshape(h, w, 3).copy()
        mask = self._mask.numpy().reshape(h, w).astype(bool)
        return image, mask

    def cast_pixels(self, pixels, points, triangles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cast the rays through arbitrary (sub-pixel) pixel coordinates ``(u, v)``.

        Args:
            pixels: (K, 2) pixel coordinates (pixel centres at integers).
            points, triangles: the surface, as in :meth:`cast`.

        Returns:
            ``(face, bary, distance)``: (K,) int32 triangle index (-1 on a miss); (K, 3) weights
            of the triangle's three vertices (the hit is ``sum_j bary[k, j] points[tri[j]]``; 0
            on a miss); (K,) distance (m) from the camera centre (``inf`` on a miss).
        """
        try:
            uv = np.asarray(pixels, dtype=np.float64)
        except (TypeError, ValueError):
            raise RenderError("pixels: expected a (K, 2) array of numbers") from None
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise RenderError(f"pixels: expected a (K, 2) array, got shape {uv.shape}")
        bad = np.flatnonzero(~np.all(np.isfinite(uv), axis=1))
        if len(bad):
            raise RenderError(f"pixels: pixel {bad[0]} is not finite: {uv[bad[0]].tolist()}")
        mesh = self._surface(points, triangles)
        k = len(uv)
        if k == 0:
            return np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros(0)
        directions = wp.array(self.camera.rays(uv).astype(np.float32), dtype=wp.vec3, device=self.device)
        face = wp.empty(k, dtype=wp.int32, device=self.device)
        bary = wp.empty(k, dtype=wp.vec2, device=self.device)
        distance = wp.empty(k, dtype=float, device=self.device)
        wp.launch(
            raycast.cast_rays,
            dim=k,
            inputs=[mesh.id, self._origin, directions, MAX_DISTANCE],
            outputs=[face, bary, distance],
            device=self.device,
        )
        f = face.numpy().copy()
        uv_hit = bary.numpy().astype(np.float64)
        weights = np.column_stack([uv_hit, 1.0 - uv_hit.sum(axis=1)])
        weights[f < 0] = 0.0
        return f, weights, distance.numpy().astype(np.float64)
