"""Tests of wcut.ar.metrics: Dice (eq. 7.13), silhouettes, surface distances, Hausdorff (7.14),
feature error (7.15)."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from wcut.ar import metrics
from wcut.ar.metrics import (
    MetricsError,
    dice,
    feature_error,
    hausdorff,
    point_to_surface_distance,
    rasterize,
    surface_samples,
)
from wcut.errors import WcutError

from conftest import Pinhole


def grid_square(x0, x1, y0, y1, z, n=2):
    """A square in the plane z, triangulated on an n x n grid (2 n^2 triangles)."""
    xs, ys = np.meshgrid(np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1), indexing="ij")
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
    tris = []
    for i in range(n):
        for j in range(n):
            a, b = i * (n + 1) + j, (i + 1) * (n + 1) + j
            tris += [[a, b, b + 1], [a, b + 1, a + 1]]
    return pts, np.array(tris, dtype=np.int64)


def icosphere(level=3):
    """A unit icosphere: 20 * 4**level triangles, vertices on the unit sphere."""
    t = (1.0 + 5**0.5) / 2.0
    verts = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
             [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    faces = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
             [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
             [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts = [np.array(v, float) / np.linalg.norm(v) for v in verts]
    for _ in range(level):
        cache, new = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = new
    return np.array(verts), np.array(faces, dtype=np.int64)


# --------------------------------------------------------------------------- Dice


def _block(cells):
    m = np.zeros((8, 8), bool)
    for r, c in cells:
        m[r, c] = True
    return m


SQUARE = [(r, c) for r in range(1, 5) for c in range(1, 5)]  # 16 pixels


@pytest.mark.parametrize(
    "b_cells, expected",
    [
        ([(r, c) for r in range(8) for c in range(8) if (r, c) not in SQUARE][:16], 0.0),
        ([(r, c + 2) for r, c in SQUARE], 0.5),  # shifted by two columns: 8 shared
        ([(r, c + 1) for r, c in SQUARE], 0.75),  # shifted by one column: 12 shared
        (SQUARE, 1.0),
        (SQUARE[1:], 2 * 15 / (16 + 15)),  # one pixel missing
        (SQUARE[1:] + [(0, 0)], 2 * 15 / (16 + 16)),  # one pixel moved out
        (SQUARE[2:], 2 * 14 / (16 + 14)),  # two pixels missing
    ],
)
def test_dice_thesis_figure_7_9(b_cells, expected):
    a = _block(SQUARE)
    b = _block(b_cells)
    assert dice(a, b) == pytest.approx(expected, abs=1e-12)
    assert dice(b, a) == pytest.approx(expected, abs=1e-12)


def test_dice_empty_and_shapes():
    assert dice(np.zeros((3, 4), bool), np.zeros((3, 4), bool)) == 1.0
    assert dice(np.zeros((3, 4), bool), np.ones((3, 4), bool)) == 0.0
    with pytest.raises(WcutError) as err:
        dice(np.zeros((3, 4)), np.zeros((4, 3)))
    assert "(3, 4)" in str(err.value) and "(4, 3)" in str(err.value)


# --------------------------------------------------------------------------- rasterize


def test_rasterize_square_area_matches_projection():
    cam = Pinhole()
    # A square facing the camera at z = 0.8 m: side 0.13 m -> 32.5 px, off-grid corners.
    pts, tris = grid_square(-0.0613, 0.0687, -0.052, 0.078, 0.8, n=3)
    mask = rasterize(cam, pts, tris)
    assert mask.shape == (120, 160) and mask.dtype == bool
    side = 200.0 * 0.13 / 0.8
    # Pixel-centre sampling: the error is bounded by the boundary pixels (perimeter x 1 px).
    assert abs(mask.sum() - side * side) <= 4 * side
    # The bounding box of the set pixels is the projected one.
    rows, cols = np.nonzero(mask)
    u0, v0 = 200 * -0.0613 / 0.8 + 80, 200 * -0.052 / 0.8 + 60
    assert cols.min() == int(np.ceil(u0)) and rows.min() == int(np.ceil(v0))
    assert cols.max() == int(np.floor(u0 + side)) and rows.max() == int(np.floor(v0 + side))


def test_rasterize_is_the_union_of_overlapping_triangles():
    cam = Pinhole()
    pts, tris = grid_square(-0.05, 0.05, -0.05, 0.05, 1.0, n=2)
    back = pts + [0.02, 0.01, 0.1]  # the same square behind it, overlapping in the image
    both_pts = np.vstack([pts, back])
    both_tris = np.vstack([tris, tris[:, ::-1] + len(pts)])
    union = rasterize(cam, pts, tris) | rasterize(cam, back, tris)
    assert np.array_equal(rasterize(cam, both_pts, both_tris), union)


def test_rasterize_matches_brute_force_pixel_centres():
    rng = np.random.default_rng(3)
    cam = Pinhole(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0)
    pts = np.column_stack([rng.uniform(-0.8, 0.8, 60), rng.uniform(-0.6, 0.6, 60), rng.uniform(0.8, 1.2, 60)])
    tris = rng.integers(0, 60, size=(25, 3))
    mask = rasterize(cam, pts, tris)
    pix, _ = cam.project(pts)
    vv, uu = np.mgrid[0:48, 0:64]
    q = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)
    expect = np.zeros(q.shape[0], bool)
    for a, b, c in pix[tris]:
        def side(p0, p1):
            return (p1[0] - p0[0]) * (q[:, 1] - p0[1]) - (p1[1] - p0[1]) * (q[:, 0] - p0[0])
        s = np.stack([side(a, b), side(b, c), side(c, a)], axis=1)
        expect |= np.all(s >= 0, axis=1) | np.all(s <= 0, axis=1)
    # Random float vertices: no pixel centre lies on an edge, so the masks agree exactly.
    assert np.array_equal(mask, expect.reshape(48, 64))


def test_rasterize_skips_triangles_behind_the_camera():
    cam = Pinhole()
    pts = np.array([[-0.1, -0.1, 1.0], [0.1, -0.1, 1.0], [0.0, 0.1, -0.5], [0.0, 0.1, 1.0]])
    assert not rasterize(cam, pts, [[0, 1, 2]]).any()
    assert rasterize(cam, pts, [[0, 1, 2], [0, 1, 3]]).sum() == rasterize(cam, pts, [[0, 1, 3]]).sum() > 0
    assert not rasterize(cam, pts, np.zeros((0, 3), int)).any()
    with pytest.raises(MetricsError, match="triangle 0"):
        rasterize(cam, pts, [[0, 1, 7]])


def test_rasterize_sphere_fast_and_close_to_opencv():
    cam = Pinhole(width=480, height=360, fx=500.0, fy=500.0, cx=240.0, cy=180.0)
    pts, tris = icosphere(3)  # 1280 triangles
    pts = pts * 0.1 + [0.01, -0.02, 0.4]
    mask = rasterize(cam, pts, tris)
    # Reference: OpenCV, one fillConvexPoly per triangle (it also fills the border pixels).
    ref = np.zeros((360, 480), np.uint8)
    pix, _ = cam.project(pts)
    for tri in np.round(pix[tris] * 16).astype(np.int32):
        cv2.fillConvexPoly(ref, tri, 1, cv2.LINE_8, 4)
    assert dice(mask, ref) > 0.99
    start = time.perf_counter()
    for _ in range(5):
        rasterize(cam, pts, tris)
    assert (time.perf_counter() - start) / 5 < 0.05  # ~1-2 ms expected; loose for slow CI


# --------------------------------------------------------------------------- sampling


def test_surface_samples_cover_the_surface():
    pts, tris = grid_square(0.0, 1.0, 0.0, 0.5, 0.0, n=2)
    s = surface_samples(pts, tris, 0.1)
    assert np.array_equal(s, surface_samples(pts, tris, 0.1))  # deterministic
    assert len(np.unique(np.round(s, 12), axis=0)) == len(s)  # no repeated points
    for v in pts:  # every vertex is a sample
        assert np.min(np.linalg.norm(s - v, axis=1)) < 1e-12
    assert np.all(np.abs(s[:, 2]) < 1e-15)
    rng = np.random.default_rng(0)
    probe = np.column_stack([rng.uniform(0, 1, 2000), rng.uniform(0, 0.5, 2000), np.zeros(2000)])
    from scipy.spatial import cKDTree

    d, _ = cKDTree(s).query(probe)
    assert d.max() <= 0.1
    with pytest.raises(MetricsError, match="spacing"):
        surface_samples(pts, tris, 0.0)


# --------------------------------------------------------------------------- distances


def test_point_to_surface_distance_known_cases():
    pts, tris = grid_square(0.0, 1.0, 0.0, 1.0, 0.0, n=1)
    q = np.array([[0.3, 0.4, 0.2], [0.3, 0.4, -0.7], [2.0, 2.0, 1.0], [0.5, -1.0, 0.0], [0.5, 0.5, 0.0]])
    d = point_to_surface_distance(q, pts, tris)
    np.testing.assert_allclose(d, [0.2, 0.7, np.sqrt(3.0), 1.0, 0.0], atol=1e-12)


def _brute_force(q, pts, tris):
    """Distance to every triangle: min over plane (if the projection is inside) and edges."""
    out = np.full(len(q), np.inf)
    for a, b, c in pts[tris]:
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        h = (q - a) @ n
        proj = q - h[:, None] * n
        # Inside test with the three edge normals.
        inside = np.ones(len(q), bool)
        for p0, p1 in ((a, b), (b, c), (c, a)):
            inside &= np.cross(p1 - p0, proj - p0) @ n >= 0
        best = np.where(inside, np.abs(h), np.inf)
        for p0, p1 in ((a, b), (b, c), (c, a)):
            e = p1 - p0
            s = np.clip((q - p0) @ e / (e @ e), 0, 1)
            best = np.minimum(best, np.linalg.norm(q - p0 - s[:, None] * e, axis=1))
        out = np.minimum(out, best)
    return out


@pytest.mark.parametrize("pair_budget", [1 << 20, 300])
def test_point_to_surface_distance_is_exact(monkeypatch, pair_budget):
    monkeypatch.setattr(metrics, "_PAIR_BUDGET", pair_budget)  # also in small groups
    rng = np.random.default_rng(7)
    # A soup of small triangles and a few big ones (large circumradius exercises the bound).
    centres = rng.uniform(-1, 1, size=(300, 3))
    small = centres[:, None, :] + rng.normal(scale=0.05, size=(300, 3, 3))
    big = rng.uniform(-1.5, 1.5, size=(3, 3, 3))
    pts = np.vstack([small, big]).reshape(-1, 3)
    tris = np.arange(len(pts)).reshape(-1, 3)
    q = rng.uniform(-2, 2, size=(400, 3))
    q = np.vstack([q, pts[:50] + rng.normal(scale=1e-3, size=(50, 3))])
    d = point_to_surface_distance(q, pts, tris)
    np.testing.assert_allclose(d, _brute_force(q, pts, tris), rtol=1e-9, atol=1e-12)


def test_point_to_surface_distance_errors():
    pts, tris = grid_square(0.0, 1.0, 0.0, 1.0, 0.0, n=1)
    with pytest.raises(MetricsError, match="no triangles"):
        point_to_surface_distance(np.zeros((2, 3)), pts, np.zeros((0, 3), int))
    with pytest.raises(MetricsError, match="query"):
        point_to_surface_distance(np.zeros((2, 2)), pts, tris)


# --------------------------------------------------------------------------- Hausdorff


def test_hausdorff_sphere_scaled():
    pts, tris = icosphere(3)
    # The flat triangles lie inside the sphere by at most the sagitta s (tessellation error).
    cen = pts[tris].mean(axis=1)
    sag = 1.0 - np.linalg.norm(cen, axis=1).min()
    mean, mx = hausdorff(pts, tris, pts * 1.1, tris, spacing=0.05)
    assert abs(mean - 0.1) <= 1.1 * sag + 1e-9
    assert abs(mx - 0.1) <= 1.1 * sag + 1e-9
    assert mean <= mx


def test_hausdorff_identical_is_zero():
    pts, tris = icosphere(2)
    mean, mx = hausdorff(pts, tris, pts, tris, spacing=0.1)
    assert mean == pytest.approx(0.0, abs=1e-12) and mx == pytest.approx(0.0, abs=1e-12)


def test_hausdorff_asymmetric_squares():
    small = grid_square(0.0, 1.0, 0.0, 1.0, 0.0, n=2)
    big = grid_square(-1.0, 2.0, -1.0, 2.0, 0.0, n=3)
    # A lies in B: sup_A inf_B = 0; the corner (-1, -1) of B is sqrt(2) from A.
    assert point_to_surface_distance(surface_samples(*small, 0.1), *big).max() < 1e-12
    mean, mx = hausdorff(*small, *big, spacing=0.1)
    assert mx == pytest.approx(np.sqrt(2.0), abs=1e-12)
    assert 0.0 < mean < mx
    assert hausdorff(*big, *small, spacing=0.1) == pytest.approx((mean, mx))


def test_hausdorff_empty_surface():
    pts, tris = grid_square(0.0, 1.0, 0.0, 1.0, 0.0, n=1)
    with pytest.raises(WcutError, match="surface B"):
        hausdorff(pts, tris, pts, np.zeros((0, 3), int), spacing=0.1)
    with pytest.raises(WcutError, match="surface A"):
        hausdorff(np.zeros((0, 3)), np.zeros((0, 3), int), pts, tris, spacing=0.1)


# --------------------------------------------------------------------------- features (7.15)


def test_feature_error():
    cur = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 5.0]])
    tgt = np.array([[0.0, 0.0, 0.003], [1.0, 0.004, 0.0], [0.0, 0.0, 0.0]])
    mean, mx = feature_error(cur, tgt, [True, True, False])
    assert mean == pytest.approx(0.0035) and mx == pytest.approx(0.004)
    assert feature_error(cur, tgt, np.ones(3, bool))[1] == pytest.approx(5.0)
    assert all(np.isnan(feature_error(cur, tgt, np.zeros(3, bool))))
    with pytest.raises(MetricsError, match="active"):
        feature_error(cur, tgt, [True, False])
    with pytest.raises(MetricsError):
        feature_error(cur, tgt[:2], [True, True, True])
