"""Pictures of a cut body: shaded and lit, the wound in its own colour, from a chosen camera.

The surface is ray cast through every pixel of a :class:`~wcut.ar.camera.Camera` by Warp
(:class:`wcut.ar.render.Renderer`), and each hit is shaded here: two directional lights (a
key light above the camera, a weaker fill from the side) on the face's normal, plus ambient.
The wound (the faces a cut opened, :func:`wound_faces`) is drawn in a dark red, the outer
surface in a pale tissue colour, so the opening shows from any side.
"""

from __future__ import annotations

import numpy as np

from .ar.camera import Camera
from .ar.render import Renderer

#: RGB in [0, 1]
SURFACE_RGB = (0.93, 0.72, 0.64)
WOUND_RGB = (0.62, 0.08, 0.10)
BACKGROUND_RGB = (1.0, 1.0, 1.0)
#: light weights: ambient, key (above the camera), fill (from the camera's right)
AMBIENT, KEY, FILL = 0.25, 0.65, 0.25


def wound_faces(rest_points: np.ndarray, triangles: np.ndarray, original_surface, tolerance: float) -> np.ndarray:
    """(T,) bool: the faces a cut opened. A boundary face of the cut mesh (corners' rest
    positions ``rest_points`` (N, 3), m; ``triangles`` (T, 3)) is on the wound when its centroid
    lies farther than ``tolerance`` (m) from the uncut mesh's boundary ``original_surface`` (a
    :class:`wcut.cut.TriangleSurface` in the rest configuration): the faces of the outer
    surface, however a cut subdivided them, lie in its triangles."""
    centroids = np.asarray(rest_points, dtype=np.float64)[np.asarray(triangles)].mean(axis=1)
    return original_surface.distance(centroids, 2.0 * tolerance) > tolerance


def render_picture(camera: Camera, points: np.ndarray, triangles: np.ndarray, wound: np.ndarray | None = None,
                   renderer: Renderer | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB picture of the surface ``points`` (N, 3) (m), ``triangles`` (T, 3),
    seen by ``camera``; ``wound`` (T,) bool marks the faces drawn in :data:`WOUND_RGB`. Both
    sides of a face are lit (a wound seen from behind is still a wound)."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    renderer = renderer or Renderer(camera)
    hits = renderer.cast(points, triangles)
    h, w = renderer.shape
    image = np.empty((h, w, 3))
    image[:] = BACKGROUND_RGB
    hit = hits.face >= 0
    faces = hits.face[hit]
    a, b, c = (points[triangles[faces, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    view = camera.rotation.T @ np.array([0.0, 0.0, 1.0])  # the camera's viewing direction (world)
    normal *= -np.sign(normal @ view)[:, None]  # facing the camera
    # the directions the lights shine in (camera axes: x right, y down, z forward)
    key = camera.rotation.T @ np.array([0.3, 0.8, 1.0])  # from above the camera, a little left
    fill = camera.rotation.T @ np.array([-1.0, 0.2, 0.6])  # from the right
    key /= np.linalg.norm(key)
    fill /= np.linalg.norm(fill)
    light = AMBIENT + KEY * np.clip(-(normal @ key), 0.0, None) + FILL * np.clip(-(normal @ fill), 0.0, None)
    colour = np.tile(np.asarray(SURFACE_RGB), (len(faces), 1))
    if wound is not None:
        colour[np.asarray(wound, dtype=bool)[faces]] = WOUND_RGB
    image[hit] = np.clip(colour * light[:, None], 0.0, 1.0)
    return (255.0 * image + 0.5).astype(np.uint8)


__all__ = ["render_picture", "wound_faces"]
