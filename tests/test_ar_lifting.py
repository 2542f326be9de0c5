"""Tests of wcut.ar.lifting: projection plane and the intercept-theorem update (eq. 7.1)."""

from __future__ import annotations

import numpy as np

from wcut.ar.camera import Camera
from wcut.ar.lifting import intercept_update, plane_points

CAMERA = Camera.look_at([0.02, -0.01, 0.3], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0), width=320, height=240)


def test_plane_points_project_back_to_their_pixels_at_the_plane_depth():
    pixels = np.array([[10.0, 20.0], [160.0, 120.0], [300.5, 230.25]])
    points = plane_points(CAMERA, pixels, 0.25)
    back, depth = CAMERA.project(points)
    np.testing.assert_allclose(back, pixels, atol=1e-9)
    np.testing.assert_allclose(depth, 0.25)


def test_a_target_moving_parallel_to_the_image_at_the_surface_depth_is_recovered_exactly():
    axis = CAMERA.view_direction
    right = np.cross(axis, [0.0, 1.0, 0.0])
    surface = CAMERA.center + 0.2 * axis + np.array([[0.0, 0.0, 0.0], [0.01, 0.005, 0.0]]) @ np.eye(3)
    depth = (surface - CAMERA.center) @ axis
    motion = 0.003 * right / np.linalg.norm(right)
    moved = surface + motion
    assert np.allclose((moved - CAMERA.center) @ axis, depth)  # parallel to the image plane
    plane_before = plane_points(CAMERA, CAMERA.project(surface)[0], 0.3)
    plane_after = plane_points(CAMERA, CAMERA.project(moved)[0], 0.3)
    np.testing.assert_allclose(intercept_update(surface, plane_before, plane_after, CAMERA.center), moved, atol=1e-12)
    # eq. 7.1 as printed (ratio d_P / d_S) would scale the motion by (0.3 / 0.2)^2 instead
    printed = surface + (plane_after - plane_before) * 0.3 / depth[:, None] * 0.3 / depth[:, None] * 0 + (
        plane_after - plane_before) * (np.linalg.norm(plane_before - CAMERA.center, axis=1)
                                       / np.linalg.norm(surface - CAMERA.center, axis=1))[:, None]
    assert np.linalg.norm(printed - moved, axis=1).min() > 0.003
