"""Tests of wcut.ar.overlay: the augmented frame and the atomic video writer."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from wcut.ar.overlay import ALPHA, INTERNAL_COLORS, OverlayError, VideoOut, draw_overlay
from wcut.errors import ExportError, WcutError

from conftest import Pinhole


def square(half, z):
    pts = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return pts, np.array([[0, 1, 2], [0, 2, 3]])


CAM = Pinhole()
GREEN = np.array([0, 255, 0], np.uint8)


def _frame():
    rng = np.random.default_rng(1)
    return rng.integers(60, 140, size=(120, 160, 3), dtype=np.uint8)


def test_overlay_outline_and_input_untouched():
    frame = _frame()
    keep = frame.copy()
    pts, tris = square(0.1, 1.0)  # pixels u in [60, 100], v in [40, 80]
    out = draw_overlay(frame, CAM, pts, tris)
    assert np.array_equal(frame, keep)
    assert out.shape == frame.shape and out.dtype == np.uint8 and out is not frame
    green = np.all(out == GREEN, axis=2)
    # Along the four sides, (nearly) every border pixel is green.
    border = [green[40:81, 60].mean(), green[40:81, 100].mean(), green[40, 60:101].mean(), green[80, 60:101].mean()]
    assert min(border) > 0.95
    # Interior far from the border and the outside far from it are unchanged.
    assert np.array_equal(out[45:76, 65:96], frame[45:76, 65:96])
    assert np.array_equal(out[:35], frame[:35]) and np.array_equal(out[:, :55], frame[:, :55])
    assert not green[45:76, 65:96].any()


def test_overlay_tints_internal_structures():
    frame = _frame()
    model = square(0.1, 1.0)
    inner = square(0.05, 1.02)  # about u in [70, 90], v in [50, 70]
    other = (inner[0] + [0.0, 0.3, 0.5], inner[1])  # a second structure elsewhere
    out = draw_overlay(frame, CAM, *model, internal=[inner, other])
    color = np.array(INTERNAL_COLORS[0], float)
    expect = np.round(frame[55:66, 75:86].astype(float) * (1 - ALPHA) + color * ALPHA)
    np.testing.assert_array_equal(out[55:66, 75:86], expect.astype(np.uint8))
    # Between the internal structure and the model outline nothing changes.
    assert np.array_equal(out[44:47, 64:96], frame[44:47, 64:96])
    # The second structure has the second colour.
    v = int(round(200 * 0.3 / 1.52 + 60))
    got = out[v, 80].astype(float)
    want = frame[v, 80].astype(float) * (1 - ALPHA) + np.array(INTERNAL_COLORS[1], float) * ALPHA
    np.testing.assert_allclose(got, want, atol=1)


def test_overlay_features_targets_and_cut():
    frame = np.full((120, 160, 3), 128, np.uint8)
    model = square(0.1, 1.0)
    feats = np.array([[70.0, 50.0], [np.nan, np.nan]])
    targets = np.array([[90.0, 50.0], [10.0, 10.0]])
    cut = np.array([[20.0, 100.0], [140.0, 100.0]])
    out = draw_overlay(frame, CAM, *model, features=feats, targets=targets, cut_polyline=cut)
    assert tuple(out[50, 70]) == (255, 0, 0)  # blue feature dot
    assert out[50, 80, 2] > 200 and out[50, 80, 0] < 100  # yellow target line
    assert np.all(out[100, 30:130] == [0, 0, 255])  # red cut line
    assert np.array_equal(out[10, 10], frame[10, 10])  # NaN feature: its target line not drawn


def test_overlay_bad_input():
    pts, tris = square(0.1, 1.0)
    with pytest.raises(OverlayError, match=r"\(120, 160, 3\)"):
        draw_overlay(np.zeros((100, 160, 3), np.uint8), CAM, pts, tris)
    with pytest.raises(WcutError, match="features"):
        draw_overlay(_frame(), CAM, pts, tris, features=np.zeros((3, 3)))
    with pytest.raises(WcutError, match="targets"):
        draw_overlay(_frame(), CAM, pts, tris, targets=np.zeros((3, 2)))


def _count_frames(path):
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    n, size = 0, None
    while True:
        ok, img = cap.read()
        if not ok:
            break
        n, size = n + 1, img.shape
    cap.release()
    return n, size


@pytest.mark.parametrize("ext", [".mp4", ".avi"])
def test_video_out_round_trip(tmp_path, ext):
    path = tmp_path / "sub" / f"overlay{ext}"
    with VideoOut(path, fps=10, size=(64, 48)) as video:
        for i in range(7):
            video.write(np.full((48, 64, 3), 30 * i, np.uint8))
    assert video.frames == 7
    assert _count_frames(path) == (7, (48, 64, 3))
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]


def test_video_out_exception_leaves_nothing(tmp_path):
    path = tmp_path / "out.mp4"
    with pytest.raises(RuntimeError):
        with VideoOut(path, 10, (32, 24)) as video:
            video.write(np.zeros((24, 32, 3), np.uint8))
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []
    # An existing file is left as it was.
    path.write_bytes(b"old")
    with pytest.raises(ExportError, match=r"\(24, 32, 3\).*\(32, 24, 3\)"):
        with VideoOut(path, 10, (32, 24)) as video:
            video.write(np.zeros((32, 24, 3), np.uint8))
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mp4"]


def test_video_out_bad_extension(tmp_path):
    with pytest.raises(ExportError) as err:
        VideoOut(tmp_path / "clip.mkv", 10, (32, 24))
    msg = str(err.value)
    assert "clip.mkv" in msg and ".mp4" in msg and ".avi" in msg
    with pytest.raises(ExportError, match="fps"):
        VideoOut(tmp_path / "clip.mp4", 0, (32, 24))
    with pytest.raises(ExportError, match="outside"):
        VideoOut(tmp_path / "clip.mp4", 10, (32, 24)).write(np.zeros((24, 32, 3), np.uint8))


def test_video_out_writer_that_does_not_open(tmp_path, monkeypatch):
    class Closed:
        def __init__(self, *args):
            pass

        def isOpened(self):
            return False

        def release(self):
            pass

    monkeypatch.setattr(cv2, "VideoWriter", Closed)
    with pytest.raises(ExportError, match="cannot open a video writer"):
        with VideoOut(tmp_path / "x.avi", 10, (32, 24)):
            pass
    assert list(tmp_path.iterdir()) == []
