"""Pinhole camera of a capture (thesis chapter 7: one calibrated camera sees the object).

OpenCV convention: a world point ``X`` (m) has camera coordinates ``x_c = R X + t`` with ``R``
the world-to-camera rotation and ``t`` (m) the translation; the camera looks along ``+z_c``,
``x_c`` points right and ``y_c`` down in the image. The pixel of ``x_c = (x, y, z)`` is
``u = fx x / z + cx``, ``v = fy y / z + cy`` (focal lengths and principal point in pixels;
pixel centres lie at integer coordinates, so the image spans ``[-0.5, width - 0.5]``).
No lens distortion: synthetic captures are rendered without it.

``camera.json`` of a capture directory holds::

    {"width": 480, "height": 360, "fx": 434.6, "fy": 434.6, "cx": 239.5, "cy": 179.5,
     "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [0, 0, 0.3]}
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass

import numpy as np

from ..errors import CaptureError
from ..io import atomic_path

_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "rotation", "translation")


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise CaptureError(f"{name}: expected a positive integer, got {value!r}")
    return int(value)


def _positive_number(value, name: str) -> float:
    if not _is_number(value) or not math.isfinite(value) or value <= 0:
        raise CaptureError(f"{name}: expected a positive number, got {value!r}")
    return float(value)


def _finite_number(value, name: str) -> float:
    if not _is_number(value) or not math.isfinite(value):
        raise CaptureError(f"{name}: expected a finite number, got {value!r}")
    return float(value)


def _finite_array(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    what = "a 3x3 matrix of numbers" if len(shape) == 2 else f"{shape[0]} numbers"
    if isinstance(value, (str, bytes, dict)):
        raise CaptureError(f"{name}: expected {what}, got {value!r}")
    try:
        cells = np.array(value, dtype=object)
    except (TypeError, ValueError):  # ragged nesting
        raise CaptureError(f"{name}: expected {what}, got {value!r}") from None
    if cells.shape != shape:
        raise CaptureError(f"{name}: expected {what}, got {value!r}")
    if not all(_is_number(c) for c in cells.flat):
        raise CaptureError(f"{name}: expected {what}, got {value!r}")
    arr = cells.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise CaptureError(f"{name}: expected finite numbers, got {value!r}")
    return arr


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera without distortion (OpenCV convention, see the module docstring).

    Attributes:
        width, height: image size (pixels).
        fx, fy: focal lengths (pixels).
        cx, cy: principal point (pixels; pixel centres at integer coordinates).
        rotation: (3, 3) world-to-camera rotation ``R`` (orthonormal, det +1).
        translation: (3,) ``t`` (m): camera coordinates are ``R X + t``.

    Arrays are stored as read-only float64 copies. Two cameras compare equal when every
    field is equal.

    Raises:
        CaptureError: a size or focal length not positive, a non-finite value, or a rotation
            that is not orthonormal with determinant +1 (to 1e-6); the message names the field.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    rotation: np.ndarray
    translation: np.ndarray

    def __post_init__(self):
        put = object.__setattr__
        put(self, "width", _positive_int(self.width, "width"))
        put(self, "height", _positive_int(self.height, "height"))
        put(self, "fx", _positive_number(self.fx, "fx"))
        put(self, "fy", _positive_number(self.fy, "fy"))
        put(self, "cx", _finite_number(self.cx, "cx"))
        put(self, "cy", _finite_number(self.cy, "cy"))
        R = _finite_array(self.rotation, (3, 3), "rotation")
        error = float(np.abs(R.T @ R - np.eye(3)).max())
        if error > 1e-6:
            raise CaptureError(f"rotation: not orthonormal (max |R^T R - I| = {error:.3g}, tolerance 1e-6)")
        det = float(np.linalg.det(R))
        if abs(det - 1.0) > 1e-6:
            raise CaptureError(f"rotation: determinant is {det:.6g}, expected +1 (a reflection, not a rotation)")
        put(self, "rotation", _frozen(R))
        put(self, "translation", _frozen(_finite_array(self.translation, (3,), "translation")))

    def __eq__(self, other):
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            (self.width, self.height, self.fx, self.fy, self.cx, self.cy)
            == (other.width, other.height, other.fx, other.fy, other.cx, other.cy)
            and np.array_equal(self.rotation, other.rotation)
            and np.array_equal(self.translation, other.translation)
        )

    __hash__ = None

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 0.0, 1.0), width: int = 480, height: int = 360, fov_y_deg: float = 45.0):
        """A camera at ``eye`` (m) looking at ``target`` (m), with ``up`` (world direction)
        pointing up in the image; square pixels, vertical field of view ``fov_y_deg`` (degrees),
        principal point at the image centre ``((width - 1) / 2, (height - 1) / 2)`` so
        ``target`` projects there.

        Raises:
            CaptureError: ``eye`` equals ``target``, ``up`` is parallel to the view direction,
                or the field of view is not in (0, 180) degrees.
        """
        eye = _finite_array(eye, (3,), "eye")
        target = _finite_array(target, (3,), "target")
        up = _finite_array(up, (3,), "up")
        fov = _positive_number(fov_y_deg, "fov_y_deg")
        if fov >= 180.0:
            raise CaptureError(f"fov_y_deg: expected a value in (0, 180) degrees, got {fov_y_deg!r}")
        forward = target - eye
        length = np.linalg.norm(forward)
        if length == 0.0:
            raise CaptureError(f"target: equals eye {eye.tolist()}, no view direction")
        z = forward / length
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9 * max(np.linalg.norm(up), 1e-300):
            raise CaptureError(f"up: {up.tolist()} is parallel to the view direction {z.tolist()}")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        width = _positive_int(width, "width")
        height = _positive_int(height, "height")
        f = 0.5 * height / math.tan(math.radians(fov) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, R, -R @ eye)

    @property
    def center(self) -> np.ndarray:
        """World position (m) of the optical centre, ``-R^T t``."""
        return -self.rotation.T @ self.translation

    @property
    def view_direction(self) -> np.ndarray:
        """World unit vector of the optical axis (``+z_c``)."""
        return self.rotation[2].copy()

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) ``(u, v)`` and depths (N,) ``z_c`` (m) of world points (N, 3) (m).

        Points at depth <= 0 (behind or in the plane of the camera) get NaN pixels; check the
        depth. Pixels outside the image are returned as they are.
        """
        X = np.asarray(points, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != 3:
            raise CaptureError(f"points: expected an (N, 3) array, got shape {X.shape}")
        xc = X @ self.rotation.T + self.translation
        depth = xc[:, 2]
        front = depth > 0
        z = np.where(front, depth, 1.0)
        pixels = np.stack([self.fx * xc[:, 0] / z + self.cx, self.fy * xc[:, 1] / z + self.cy], axis=1)
        pixels[~front] = np.nan
        return pixels, depth

    def rays(self, pixels) -> np.ndarray:
        """Unit world directions (N, 3) of the rays from :attr:`center` through pixel
        coordinates (N, 2) ``(u, v)`` (sub-pixel values allowed)."""
        uv = np.asarray(pixels, dtype=np.float64)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise CaptureError(f"pixels: expected an (N, 2) array, got shape {uv.shape}")
        d = np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy, np.ones(len(uv))], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d @ self.rotation

    def pixel_rays(self) -> np.ndarray:
        """Unit world directions (height, width, 3) of the rays through every pixel centre."""
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        return self.rays(pixels).reshape(self.height, self.width, 3)

    def to_dict(self) -> dict:
        """The ``camera.json`` layout as plain Python values."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
        }

    def to_json(self, path: str | os.PathLike) -> None:
        """Write ``camera.json`` atomically (a temporary file, then one rename)."""
        with atomic_path(path) as tmp:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(self.to_dict(), f, indent=2)
                f.write("\n")

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> Camera:
        """Read ``camera.json``.

        Raises:
            CaptureError: the file is missing or unreadable, is not a JSON object, lacks a
                key, has an unknown key, or a value of the wrong type or range; the message
                names the file and the key, e.g. ``camera.json: fx: expected a positive
                number, got 'a'``.
        """
        name = os.fspath(path)
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except FileNotFoundError:
            raise CaptureError(f"{name}: camera file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            reason = getattr(exc, "strerror", None) or exc
            raise CaptureError(f"{name}: cannot read the camera file: {reason}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CaptureError(f"{name}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
        if not isinstance(data, dict):
            keys = ", ".join(_KEYS)
            raise CaptureError(f"{name}: expected a JSON object with keys {keys}, got {type(data).__name__}")
        for key in _KEYS:
            if key not in data:
                raise CaptureError(f"{name}: {key}: missing key")
        for key in data:
            if key not in _KEYS:
                raise CaptureError(f"{name}: {key}: unknown key (expected {', '.join(_KEYS)})")
        try:
            return cls(**{key: data[key] for key in _KEYS})
        except CaptureError as exc:
            raise CaptureError(f"{name}: {exc}") from None
