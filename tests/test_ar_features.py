"""Tests of wcut.ar.features: detection in the mask, Lucas-Kanade tracking, lost and jumping features."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from wcut.ar.features import FeatureTracker, detect_features
from wcut.errors import WcutError


def speckle(height=240, width=320, seed=0) -> np.ndarray:
    """A smooth random texture (uint8) with many corners."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (height // 4, width // 4)).astype(np.float32)
    return cv2.GaussianBlur(cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC), (0, 0), 1.0).clip(
        0, 255).astype(np.uint8)


def shifted(image, dx, dy):
    return cv2.warpAffine(image, np.float32([[1, 0, dx], [0, 1, dy]]), image.shape[::-1], flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("method", ["gftt", "sift"])
def test_features_are_found_only_inside_the_mask(method):
    image = speckle()
    mask = np.zeros(image.shape, bool)
    mask[60:180, 80:240] = True
    points = detect_features(image, mask, max_count=300, method=method)
    assert (100 if method == "gftt" else 40) <= len(points) <= 300
    u, v = np.round(points[:, 0]).astype(int), np.round(points[:, 1]).astype(int)
    assert mask[v, u].all()


def test_a_translation_is_tracked_to_a_tenth_of_a_pixel():
    image = speckle()
    mask = np.zeros(image.shape, bool)
    mask[40:200, 40:280] = True
    points = detect_features(image, mask, max_count=200)
    tracker = FeatureTracker(image, points)
    for k in range(1, 6):
        tracker.track(shifted(image, 1.5 * k, -0.75 * k))
    assert tracker.active.mean() > 0.95
    err = tracker.points[tracker.active] - (points[tracker.active] + [7.5, -3.75])
    assert np.abs(err).max() < 0.1


def test_a_lost_view_drops_the_features():
    image = speckle()
    mask = np.ones(image.shape, bool)
    tracker = FeatureTracker(image, detect_features(image, mask, max_count=150))
    tracker.track(speckle(seed=7))  # another scene: nothing can be followed back
    assert tracker.active.mean() < 0.2
    assert set(np.unique(tracker.lost[~tracker.active])) <= {1, 2}
    kept = tracker.points.copy()
    tracker.track(speckle(seed=8))
    np.testing.assert_array_equal(tracker.points[~tracker.active], kept[~tracker.active])  # lost for good


def test_a_jumping_feature_is_removed():
    image = speckle()
    points = detect_features(image, np.ones(image.shape, bool), max_count=150)
    tracker = FeatureTracker(image, points, jump_factor=3.0, jump_floor=1.0)
    moved = shifted(image, 1.0, 0.0)
    i = int(np.argmin(np.linalg.norm(points - [160, 120], axis=1)))  # the feature nearest the centre
    u, v = np.round(points[i]).astype(int)
    moved[v - 20:v + 21, u - 20:u + 21] = image[v - 20:v + 21, u - 32:u + 9]  # its patch jumps 12 pixels
    tracker.track(moved)
    assert not tracker.active[i] and tracker.lost[i] in (1, 2)
    far = np.abs(points - points[i]).max(axis=1) > 40
    assert tracker.active[far].mean() > 0.9


def test_bad_input_is_an_error():
    with pytest.raises(WcutError, match="method"):
        detect_features(speckle(), np.ones((240, 320), bool), method="surf")
    with pytest.raises(WcutError, match="same shape"):
        detect_features(speckle(), np.ones((10, 10), bool))
