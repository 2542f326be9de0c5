"""Tests of wcut.ar.camera: the pinhole camera model and camera.json."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from wcut.ar.camera import Camera
from wcut.errors import CaptureError, WcutError

from conftest import axis_angle_rotation


def _camera(**changes) -> Camera:
    """A camera with an off-centre principal point and unequal focal lengths."""
    R = axis_angle_rotation([0.3, -0.5, 0.8], 0.7)
    fields = dict(width=320, height=240, fx=400.0, fy=380.0, cx=150.3, cy=130.7)
    fields.update(rotation=R, translation=[0.01, -0.02, 0.4])
    fields.update(changes)
    return Camera(**fields)


def test_project_and_rays_round_trip():
    cam = _camera()
    rng = np.random.default_rng(1)
    pixels = rng.uniform([0, 0], [cam.width, cam.height], size=(50, 2))
    distance = rng.uniform(0.1, 2.0, size=50)
    rays = cam.rays(pixels)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    points = cam.center + distance[:, None] * rays
    back, depth = cam.project(points)
    np.testing.assert_allclose(back, pixels, atol=1e-9)
    np.testing.assert_allclose(depth, distance * (rays @ cam.view_direction), atol=1e-12)


def test_point_on_the_optical_axis_projects_to_the_principal_point():
    cam = _camera()
    pixels, depth = cam.project([cam.center + 0.7 * cam.view_direction])
    np.testing.assert_allclose(pixels[0], [cam.cx, cam.cy], atol=1e-9)
    assert depth[0] == pytest.approx(0.7)


def test_points_behind_the_camera_have_nan_pixels():
    cam = _camera()
    pixels, depth = cam.project([cam.center - 0.5 * cam.view_direction])
    assert depth[0] == pytest.approx(-0.5)
    assert np.all(np.isnan(pixels))


def test_look_at_puts_the_target_at_the_image_centre():
    eye, target = np.array([0.3, -0.2, 0.25]), np.array([0.01, 0.02, -0.03])
    cam = Camera.look_at(eye, target, width=480, height=360, fov_y_deg=45.0)
    np.testing.assert_allclose(cam.center, eye, atol=1e-12)
    forward = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(cam.view_direction, forward, atol=1e-12)
    pixels, depth = cam.project([target, target + [0, 0, 0.01]])
    np.testing.assert_allclose(pixels[0], [239.5, 179.5], atol=1e-9)
    assert depth[0] == pytest.approx(np.linalg.norm(target - eye))
    assert pixels[1, 1] < pixels[0, 1]  # world up is up in the image (v grows downwards)
    # the vertical field of view spans the image height
    assert 2 * np.degrees(np.arctan(0.5 * cam.height / cam.fy)) == pytest.approx(45.0)
    assert cam.fx == cam.fy


def test_look_at_rejects_degenerate_input():
    with pytest.raises(CaptureError, match="up"):
        Camera.look_at([0, 0, 1], [0, 0, 0], up=(0, 0, 1))
    with pytest.raises(CaptureError, match="target"):
        Camera.look_at([0, 0, 1], [0, 0, 1])
    with pytest.raises(CaptureError, match="fov_y_deg"):
        Camera.look_at([0, 0, 1], [0, 0, 0], up=(0, 1, 0), fov_y_deg=180)


def test_camera_is_immutable_and_compares_by_value():
    cam = _camera()
    with pytest.raises(ValueError):
        cam.rotation[0, 0] = 2.0
    with pytest.raises(AttributeError):
        cam.fx = 1.0
    assert cam == _camera()
    assert cam != _camera(fx=401.0)


@pytest.mark.parametrize(
    "changes, key",
    [
        (dict(width=0), "width"),
        (dict(height=2.5), "height"),
        (dict(fx=-1.0), "fx"),
        (dict(fy=float("nan")), "fy"),
        (dict(cx=float("inf")), "cx"),
        (dict(rotation=np.diag([1.0, 1.0, -1.0])), "rotation"),
        (dict(rotation=2 * np.eye(3)), "rotation"),
        (dict(rotation=np.eye(2)), "rotation"),
        (dict(translation=[0, 0]), "translation"),
    ],
)
def test_invalid_fields_are_rejected(changes, key):
    with pytest.raises(CaptureError, match=f"^{key}: "):
        _camera(**changes)


def test_json_round_trip(tmp_path):
    cam = _camera()
    path = tmp_path / "capture" / "camera.json"
    cam.to_json(path)
    assert Camera.from_json(path) == cam
    assert sorted(os.listdir(path.parent)) == ["camera.json"]  # no temporary file left
    data = json.loads(path.read_text())
    assert list(data) == ["width", "height", "fx", "fy", "cx", "cy", "rotation", "translation"]
    assert data["width"] == 320 and len(data["rotation"]) == 3


def _write(path, data):
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


@pytest.mark.parametrize(
    "edit, key, what",
    [
        (lambda d: d.update(fx="a"), "fx", "expected a positive number, got 'a'"),
        (lambda d: d.update(fy=0), "fy", "expected a positive number"),
        (lambda d: d.update(width=480.0), "width", "expected a positive integer"),
        (lambda d: d.update(height=True), "height", "expected a positive integer"),
        (lambda d: d.update(cx=None), "cx", "expected a finite number"),
        (lambda d: d.pop("cy"), "cy", "missing key"),
        (lambda d: d.update(rotation=[[1, 0, 0], [0, 1, 0]]), "rotation", "expected a 3x3 matrix"),
        (lambda d: d.update(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, "1"]]), "rotation", "expected a 3x3 matrix"),
        (lambda d: d.update(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "rotation", "not orthonormal"),
        (lambda d: d.update(translation="0 0 1"), "translation", "expected 3 numbers"),
        (lambda d: d.update(distortion=[0, 0, 0, 0]), "distortion", "unknown key"),
    ],
)
def test_bad_camera_json_names_file_and_key(tmp_path, edit, key, what):
    data = _camera().to_dict()
    edit(data)
    path = _write(tmp_path / "camera.json", data)
    with pytest.raises(CaptureError) as info:
        Camera.from_json(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key}: "), message
    assert what in message


def test_fx_error_message_reads_as_documented(tmp_path, monkeypatch):
    data = _camera().to_dict()
    data["fx"] = "a"
    monkeypatch.chdir(tmp_path)
    _write(tmp_path / "camera.json", data)
    with pytest.raises(CaptureError, match=r"^camera\.json: fx: expected a positive number, got 'a'$"):
        Camera.from_json("camera.json")


@pytest.mark.parametrize(
    "text, what",
    [
        (None, "not found"),
        ("{\"width\": 480,", "not valid JSON"),
        ("[1, 2, 3]", "expected a JSON object"),
    ],
)
def test_unreadable_camera_json_names_the_file(tmp_path, text, what):
    path = tmp_path / "camera.json"
    if text is not None:
        path.write_text(text)
    with pytest.raises(WcutError) as info:
        Camera.from_json(path)
    assert isinstance(info.value, CaptureError)
    assert str(info.value).startswith(f"{path}: ")
    assert what in str(info.value)
