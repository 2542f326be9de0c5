"""Image features: detection in the region of interest and pyramidal Lucas-Kanade tracking
with removal of jumping and sliding features (thesis 7.4.1).

The thesis detects SURF features; SURF is patented and absent from OpenCV's wheels. We use
Shi-Tomasi corners (``cv2.goodFeaturesToTrack``, the "good features to track" of the
Lucas-Kanade tracker itself) by default, or SIFT keypoints (``method="sift"``).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import WcutError

DETECTORS = ("gftt", "sift")


def detect_features(gray: np.ndarray, mask: np.ndarray, *, max_count: int = 500, method: str = "gftt",
                    min_distance: float = 5.0, quality: float = 0.005) -> np.ndarray:
    """(F, 2) float32 pixel positions (u, v) of features inside ``mask`` (H, W bool).

    Args:
        gray: (H, W) uint8 image.
        max_count: at most this many features (the strongest).
        method: ``"gftt"`` (Shi-Tomasi corners) or ``"sift"``.
        min_distance: pixels between two features (gftt).
        quality: corner quality relative to the best corner (gftt).
    """
    if method not in DETECTORS:
        raise WcutError(f"features.method: expected one of {', '.join(DETECTORS)}, got {method!r}")
    if gray.ndim != 2 or gray.dtype != np.uint8 or mask.shape != gray.shape:
        raise WcutError(f"features: expected a (H, W) uint8 image and a mask of the same shape, got "
                        f"{gray.shape} {gray.dtype} and {mask.shape}")
    roi = mask.astype(np.uint8) * 255
    if method == "gftt":
        found = cv2.goodFeaturesToTrack(gray, maxCorners=int(max_count), qualityLevel=float(quality),
                                        minDistance=float(min_distance), mask=roi, blockSize=5)
        return np.zeros((0, 2), np.float32) if found is None else found.reshape(-1, 2).astype(np.float32)
    keypoints = cv2.SIFT_create(nfeatures=int(max_count)).detect(gray, roi)
    points = np.array([k.pt for k in keypoints], dtype=np.float32).reshape(-1, 2)
    _, unique = np.unique(np.round(points, 2), axis=0, return_index=True)  # SIFT repeats a point per orientation
    return points[np.sort(unique)][:max_count]


class FeatureTracker:
    """Tracks features from frame to frame and drops those that cannot be trusted.

    A feature is lost for good when Lucas-Kanade fails (status 0), when tracking it back
    from the new frame misses its old position by more than ``fb_threshold`` pixels (a
    feature sliding along an edge or over a uniform patch does that), when it leaves the
    image, or when it jumps: its motion in one frame exceeds ``jump_factor`` times the mean
    motion of the features plus ``jump_floor`` pixels (7.4.1: "outliers comparing to the
    measures' average"; the floor keeps a nearly still scene from dropping everything).

    Args:
        gray: (H, W) uint8 first frame.
        points: (F, 2) features in it (pixels).

    Attributes:
        points: (F, 2) float32 latest positions (pixels; a lost feature keeps its last one).
        active: (F,) bool, still tracked.
        lost: (F,) int8 why a feature was dropped: 0 tracked, 1 tracking failed, 2 jumped.
    """

    def __init__(self, gray: np.ndarray, points: np.ndarray, *, window: int = 21, levels: int = 3,
                 fb_threshold: float = 1.0, jump_factor: float = 5.0, jump_floor: float = 2.0):
        self._gray = gray
        self.points = np.asarray(points, dtype=np.float32).reshape(-1, 2).copy()
        self.active = np.ones(len(self.points), dtype=bool)
        self.lost = np.zeros(len(self.points), dtype=np.int8)
        self._lk = dict(winSize=(window, window), maxLevel=levels,
                        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        self.fb_threshold, self.jump_factor, self.jump_floor = fb_threshold, jump_factor, jump_floor

    def track(self, gray: np.ndarray) -> None:
        """Follow the active features into ``gray`` (the next frame)."""
        index = np.flatnonzero(self.active)
        if len(index):
            old = self.points[index].reshape(-1, 1, 2)
            new, status, _ = cv2.calcOpticalFlowPyrLK(self._gray, gray, old, None, **self._lk)
            back, status_back, _ = cv2.calcOpticalFlowPyrLK(gray, self._gray, new, None, **self._lk)
            new, old = new.reshape(-1, 2), old.reshape(-1, 2)
            h, w = gray.shape
            ok = ((status.ravel() == 1) & (status_back.ravel() == 1)
                  & (np.linalg.norm(back.reshape(-1, 2) - old, axis=1) <= self.fb_threshold)
                  & (new[:, 0] >= 0) & (new[:, 0] <= w - 1) & (new[:, 1] >= 0) & (new[:, 1] <= h - 1))
            motion = np.linalg.norm(new - old, axis=1)
            jump = ok & (motion > self.jump_factor * (motion[ok].mean() if ok.any() else 0.0) + self.jump_floor)
            self.lost[index[~ok]] = 1
            self.lost[index[jump]] = 2
            self.active[index[~ok | jump]] = False
            keep = ok & ~jump
            self.points[index[keep]] = new[keep]
        self._gray = gray
