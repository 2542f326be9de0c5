"""The augmented video: the registered model drawn over the camera frames (thesis 7.6-7.8).

:func:`draw_overlay` draws, on a copy of a BGR frame, the internal structures (filled
semi-transparent, outlined darker), the outline of the model's silhouette in green, the
tracked features (blue dots) with lines to their targets, and a cut polyline in red.
:class:`VideoOut` writes such frames to an ``.mp4`` or ``.avi`` file atomically.

Pixels follow OpenCV: ``[u, v]`` = (column, row), pixel centres at integer coordinates;
colours are BGR. The camera is duck-typed as in :mod:`.metrics` (``width``, ``height``,
``project(points (N, 3) m) -> (pixels (N, 2), depth (N,) m)``).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import ExportError, WcutError
from ..io import atomic_path
from .metrics import rasterize

__all__ = ["OverlayError", "draw_overlay", "VideoOut", "last_frame", "INTERNAL_COLORS"]


class OverlayError(WcutError):
    """Input of :func:`draw_overlay` is invalid: a frame of the wrong shape or type, or
    feature / target / polyline arrays of the wrong shape."""


#: BGR fill colours of internal structures, in order (cycled when there are more).
INTERNAL_COLORS = (
    (255, 0, 255),  # magenta
    (0, 200, 255),  # orange
    (255, 255, 0),  # cyan
    (0, 255, 255),  # yellow
    (200, 120, 255),  # pink
    (255, 120, 0),  # light blue
)
ALPHA = 0.45  #: opacity of the internal structures
OUTLINE_COLOR = (0, 255, 0)  #: model outline, green
FEATURE_COLOR = (255, 0, 0)  #: features, blue
TARGET_COLOR = (0, 255, 255)  #: feature -> target lines, yellow
CUT_COLOR = (0, 0, 255)  #: cut polyline, red

_SHIFT = 4  # sub-pixel bits of the cv2 drawing calls
_SCALE = 1 << _SHIFT


def _fixed(pixels: np.ndarray) -> np.ndarray:
    return np.round(pixels * _SCALE).astype(np.int32)


def _pixels(name: str, arr, *, rows: int | None = None) -> np.ndarray:
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2 or (rows is not None and len(a) != rows):
        want = f"({rows}, 2)" if rows is not None else "(N, 2)"
        raise OverlayError(f"draw_overlay: {name} must be a {want} array of pixels [u, v], got shape {a.shape}")
    return a


def _outline(mask: np.ndarray) -> list:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return list(contours)


def draw_overlay(
    frame,
    camera,
    model_points,
    model_triangles,
    internal=(),
    features=None,
    targets=None,
    cut_polyline=None,
) -> np.ndarray:
    """Return the augmented frame: a new ``(H, W, 3)`` uint8 BGR image; ``frame`` is not modified.

    * ``internal``: a sequence of ``(points (N, 3) m, triangles (T, 3))`` internal structures,
      each filled semi-transparent (opacity 0.45, colour ``INTERNAL_COLORS[i]``) and outlined
      in a darker shade of it (the contour of its projected area).
    * The model surface ``model_points`` (N, 3) m / ``model_triangles`` (T, 3): its outline,
      the contours of :func:`~wcut.ar.metrics.rasterize` (outer border and holes), 2 px green.
    * ``features`` (F, 2) pixels: blue dots; ``targets`` (F, 2) pixels: a yellow line from each
      feature to its target (needs ``features``). Rows with NaN are not drawn.
    * ``cut_polyline`` (P, 2) pixels: an open red polyline, 2 px.

    The frame must have the camera's size (``camera.height``, ``camera.width``).
    """
    img = np.asarray(frame)
    h, w = int(camera.height), int(camera.width)
    if img.dtype != np.uint8 or img.shape != (h, w, 3):
        raise OverlayError(
            f"draw_overlay: frame must be a ({h}, {w}, 3) uint8 BGR image (the camera's size), "
            f"got shape {img.shape} dtype {img.dtype}"
        )
    out = img.copy()

    for i, item in enumerate(internal):
        try:
            pts, tris = item
        except (TypeError, ValueError):
            raise OverlayError(
                f"draw_overlay: internal structure {i} must be a (points, triangles) pair"
            ) from None
        mask = rasterize(camera, pts, tris)
        if not mask.any():
            continue
        color = np.array(INTERNAL_COLORS[i % len(INTERNAL_COLORS)], dtype=np.float64)
        blended = out[mask].astype(np.float64) * (1.0 - ALPHA) + color * ALPHA
        out[mask] = np.clip(np.round(blended), 0, 255).astype(np.uint8)
        dark = tuple(int(c * 0.55) for c in color)
        cv2.drawContours(out, _outline(mask), -1, dark, 1, cv2.LINE_8)

    mask = rasterize(camera, model_points, model_triangles)
    if mask.any():
        cv2.drawContours(out, _outline(mask), -1, OUTLINE_COLOR, 2, cv2.LINE_8)

    if targets is not None and features is None:
        raise OverlayError("draw_overlay: targets were given without features")
    if features is not None:
        f = _pixels("features", features)
        ok = np.all(np.isfinite(f), axis=1)
        if targets is not None:
            g = _pixels("targets", targets, rows=len(f))
            both = ok & np.all(np.isfinite(g), axis=1)
            if both.any():
                lines = np.stack([_fixed(f[both]), _fixed(g[both])], axis=1)
                cv2.polylines(out, list(lines), False, TARGET_COLOR, 1, cv2.LINE_AA, _SHIFT)
        for u, v in _fixed(f[ok]):
            cv2.circle(out, (int(u), int(v)), 2 * _SCALE, FEATURE_COLOR, -1, cv2.LINE_AA, _SHIFT)

    if cut_polyline is not None:
        c = _pixels("cut_polyline", cut_polyline)
        c = c[np.all(np.isfinite(c), axis=1)]
        if len(c) >= 2:
            cv2.polylines(out, [_fixed(c)], False, CUT_COLOR, 2, cv2.LINE_AA, _SHIFT)
    return out


def last_frame(path: str | os.PathLike) -> np.ndarray | None:
    """The last frame (BGR, uint8) of the video at ``path``, as OpenCV reads it; None when no
    frame can be read (a missing or empty file)."""
    reader, last = cv2.VideoCapture(str(path)), None
    while True:
        ok, frame = reader.read()
        if not ok:
            break
        last = frame
    reader.release()
    return last


class VideoOut:
    """Write BGR frames to a video file, atomically: ``with VideoOut(path, fps, (W, H)) as v:``.

    ``.mp4`` is written with the fourcc ``mp4v``, ``.avi`` with ``MJPG``. Frames go to a
    temporary file beside ``path`` (same extension) that replaces ``path`` only when the
    ``with`` block ends without an exception; otherwise it is deleted and ``path`` is left
    as it was. ``fps`` in frames per second, ``size`` = (width, height) in pixels.
    Raises :class:`~wcut.errors.ExportError` for an unsupported extension, a writer that
    cannot be opened, or a frame of the wrong size.
    """

    FOURCC = {".mp4": "mp4v", ".avi": "MJPG"}

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int]):
        self.path = Path(path)
        ext = self.path.suffix.lower()
        if ext not in self.FOURCC:
            raise ExportError(
                f"{self.path}: unsupported video extension {self.path.suffix!r}; "
                f"supported: {', '.join(self.FOURCC)}"
            )
        fps = float(fps)
        if not np.isfinite(fps) or fps <= 0.0:
            raise ExportError(f"{self.path}: fps must be a positive number, got {fps}")
        try:
            width, height = (int(s) for s in size)
        except (TypeError, ValueError):
            raise ExportError(f"{self.path}: size must be (width, height) in pixels, got {size!r}") from None
        if width <= 0 or height <= 0:
            raise ExportError(f"{self.path}: size must be positive (width, height), got {size!r}")
        self.fps = fps
        self.size = (width, height)
        self._fourcc = self.FOURCC[ext]
        self._atomic = None
        self._writer = None
        self.frames = 0  #: number of frames written so far

    def __enter__(self) -> "VideoOut":
        if self._writer is not None:
            raise ExportError(f"{self.path}: this VideoOut is already open")
        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*self._fourcc), self.fps, self.size, True)
        if not writer.isOpened():
            writer.release()
            err = ExportError(
                f"{self.path}: cannot open a video writer (fourcc {self._fourcc}, "
                f"{self.size[0]}x{self.size[1]} at {self.fps} fps)"
            )
            self._atomic.__exit__(ExportError, err, None)
            self._atomic = None
            raise err
        self._writer = writer
        self.frames = 0
        return self

    def write(self, frame) -> None:
        """Append one ``(height, width, 3)`` uint8 BGR frame."""
        if self._writer is None:
            raise ExportError(f"{self.path}: write() outside the 'with' block of VideoOut")
        img = np.asarray(frame)
        w, h = self.size
        if img.dtype != np.uint8 or img.shape != (h, w, 3):
            raise ExportError(
                f"{self.path}: frame {self.frames} must be ({h}, {w}, 3) uint8 BGR, "
                f"got shape {img.shape} dtype {img.dtype}"
            )
        self._writer.write(np.ascontiguousarray(img))
        self.frames += 1

    def __exit__(self, exc_type, exc, tb) -> bool:
        writer, atomic = self._writer, self._atomic
        self._writer = self._atomic = None
        if writer is not None:
            writer.release()
        if atomic is not None:
            # On an exception this deletes the temporary file and re-raises nothing itself;
            # on success it renames the temporary file over the target.
            atomic.__exit__(exc_type, exc, tb)
        return False
