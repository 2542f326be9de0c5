"""From 2D image features to 3D virtual features (thesis 7.4.2).

Two ways, chosen per scenario:

- ``plane``: the feature's ray meets a projection plane perpendicular to the optical axis
  (``p_{l,F_P}``); initial and target virtual features are computed the same way. Right for
  thin, flat objects facing the camera (the silicone bands).
- ``surface``: the initial virtual feature is where the ray first meets the model's surface
  (``p_{l,F_S}^0``); targets cannot be projected there later (the real object leaves the
  model's outline, figure 7.3), so they move by the plane displacement scaled to their depth
  (eq. 7.1).
"""

from __future__ import annotations

import numpy as np

from ..errors import WcutError

LIFTINGS = ("plane", "surface")


def plane_points(camera, pixels, depth: float) -> np.ndarray:
    """(K, 3) points (m) where the rays through ``pixels`` (K, 2) meet the plane perpendicular
    to the optical axis at ``depth`` (m) in front of the camera."""
    rays = camera.rays(np.asarray(pixels, dtype=np.float64).reshape(-1, 2))
    along = rays @ camera.view_direction  # cosine between each ray and the axis
    return camera.center + rays * (depth / along)[:, None]


def intercept_update(surface_before, plane_before, plane_after, center) -> np.ndarray:
    """Eq. 7.1: the target on the surface follows the target on the plane.

    A displacement seen at the plane's distance ``d_P`` from the camera centre ``v``
    corresponds, by the intercept theorem, to ``d_S / d_P`` times it at the surface point's
    distance ``d_S``: ``p_S(t+dt) = p_S(t) + (p_P(t+dt) - p_P(t)) d(p_S(t), v) / d(p_P(t), v)``.
    (Eq. 7.1 as printed has the inverse ratio ``d_P / d_S``; that scales a motion near the
    camera up instead of down. A target moving parallel to the image at the surface depth is
    recovered exactly with ``d_S / d_P``, which the tests check.)
    """
    surface_before = np.asarray(surface_before, dtype=np.float64)
    plane_before = np.asarray(plane_before, dtype=np.float64)
    d_s = np.linalg.norm(surface_before - center, axis=1)
    d_p = np.linalg.norm(plane_before - center, axis=1)
    if not (d_p > 0).all():
        raise WcutError("intercept update: a plane point is at the camera centre")
    return surface_before + (np.asarray(plane_after) - plane_before) * (d_s / d_p)[:, None]
