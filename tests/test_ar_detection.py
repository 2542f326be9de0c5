"""Tests of wcut.ar.detection: the pair measure (eq. 7.9-7.11), outliers, cut points and polygons."""

from __future__ import annotations

import numpy as np
import pytest

from wcut.ar.detection import REPACK_BELOW, CutDetector, DetectionParams
from wcut.errors import WcutError


def grid_features(n: int = 21, size: float = 0.1) -> np.ndarray:
    """(n*n, 3) features on a square grid in the plane z = 0 (m)."""
    xs = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])


def opened(p0: np.ndarray, x_cut: float, y_end: float, gap: float):
    """Targets of a slit along x = x_cut for y < y_end opened by ``gap`` (m), and the
    current positions of a whole model that follows only half of it."""
    target = p0.copy()
    side = np.sign(p0[:, 0] - x_cut) * (p0[:, 1] < y_end)
    target[:, 0] += 0.5 * gap * side
    current = p0.copy()
    current[:, 0] += 0.25 * gap * np.tanh((p0[:, 0] - x_cut) / 0.002) * (p0[:, 1] < y_end)
    return current, target


def reference_measure(p0, pairs, current, target, active, alive, variant):
    l, m = pairs[:, 0], pairs[:, 1]
    d = current - target
    moved = target if variant == "target" else current
    mu = (np.linalg.norm(d[l] - d[m], axis=1) * np.linalg.norm(moved[l] - moved[m], axis=1)
          / np.linalg.norm(p0[l] - p0[m], axis=1))
    return np.where(alive & active[l] & active[m], mu, -1.0)


@pytest.mark.parametrize("variant", ["target", "current"])
def test_kernel_measure_equals_the_numpy_reference(variant):
    rng = np.random.default_rng(1)
    p0 = rng.uniform(0.0, 0.05, (300, 3))
    det = CutDetector(p0, DetectionParams(radius=0.01, cut_point_radius=0.004, measure=variant, tau=2.0))
    current = p0 + rng.normal(0, 1e-3, p0.shape)
    target = p0 + rng.normal(0, 1e-3, p0.shape)
    active = rng.uniform(size=len(p0)) > 0.1
    det.measure(current, target, active)
    det.remove_pairs(np.arange(0, len(det.pairs), 7))  # taken out of the packed pairs in place
    with pytest.raises(ValueError):
        det.alive[0] = False  # read-only: remove_pairs keeps the packed pairs in step
    mu, count, mean = det.measure(current, target, active)
    expected = reference_measure(p0, det.pairs, current, target, active, det.alive, variant)
    assert len(det.pairs) > 1000
    np.testing.assert_allclose(mu, expected, rtol=1e-4, atol=1e-9)
    assert count == int((expected >= 0).sum())
    assert mean == pytest.approx(expected[expected >= 0].mean(), rel=1e-4)
    det.update(current, target, active)  # the outliers are counted by a kernel of the same launch
    threshold = max(det.params.tau * mean, det.params.min_measure)
    assert abs(det.last_outliers - int((expected > threshold).sum())) <= int((abs(expected - threshold) < 1e-6).sum())
    assert det.last_outliers > 0
    for keep in (0.95, 0.5):  # features lost: their pairs leave in place, then (too few left) packed again
        packed = det._packed
        active = active & (rng.uniform(size=len(p0)) < keep)
        for repeat in range(2):  # the second frame packs again if the first left too few
            mu, count, mean = det.measure(current, target, active)
            expected = reference_measure(p0, det.pairs, current, target, active, det.alive, variant)
            np.testing.assert_allclose(mu, expected, rtol=1e-4, atol=1e-9)
            assert count == int((expected >= 0).sum())
            assert mean == pytest.approx(expected[expected >= 0].mean(), rel=1e-4)
        repacked = det._packed != packed
        assert repacked == (count < REPACK_BELOW * packed) and (repacked or keep > 0.5)
        assert det._packed == (count if repacked else packed)
    active[rng.uniform(size=len(p0)) < 0.3] = True  # features tracked again: their pairs come back
    mu, count, mean = det.measure(current, target, active)
    expected = reference_measure(p0, det.pairs, current, target, active, det.alive, variant)
    np.testing.assert_allclose(mu, expected, rtol=1e-4, atol=1e-9)
    assert count == int((expected >= 0).sum()) and mean == pytest.approx(expected[expected >= 0].mean(), rel=1e-4)


def test_neighbour_graph_is_every_pair_within_the_radius():
    p0 = grid_features(6, 0.05)  # spacing 0.01
    det = CutDetector(p0, DetectionParams(radius=0.0105, cut_point_radius=0.005))
    d = np.linalg.norm(p0[:, None] - p0[None], axis=2)
    expected = {(i, j) for i in range(len(p0)) for j in range(i + 1, len(p0)) if d[i, j] < 0.0105}
    assert {tuple(p) for p in det.pairs.tolist()} == expected
    assert det.pair_count == len(expected) == 2 * 6 * 5


def test_a_uniform_stretch_is_no_cut():
    p0 = grid_features()
    det = CutDetector(p0, DetectionParams(radius=0.012, cut_point_radius=0.006, tau=7.0, min_measure=1e-4))
    active = np.ones(len(p0), bool)
    for stretch in np.linspace(1.0, 1.86, 20):  # the control: 186%, the model lagging behind a little
        target = p0 * [stretch, 1.0, 1.0]
        current = p0 * [1.0 + 0.95 * (stretch - 1.0), 1.0, 1.0]
        assert det.update(current, target, active) is None
    assert det.polygons == []


def test_an_opening_slit_puts_cut_points_on_it_and_a_polygon_along_it():
    p0 = grid_features()
    params = DetectionParams(radius=0.012, cut_point_radius=0.008, tau=5.0, min_outliers=3, min_measure=1e-5)
    det = CutDetector(p0, params)
    active = np.ones(len(p0), bool)
    points = []
    for gap in np.linspace(0.0005, 0.01, 30):
        current, target = opened(p0, 0.0525, 0.06, gap)
        found = det.update(current, target, active)
        if found is not None:
            points.append(found)
    assert len(points) >= 2
    for found in points:  # on the slit: x near 0.0525, y below its end
        assert abs(found.point[0] - 0.0525) < 0.004
        assert found.point[1] < 0.06 + params.cut_point_radius
    assert len(det.polygons) == 1 and len(det.polygons[0]) == len(points)
    second = points[1]
    assert second.previous is not None and second.back is not None and second.look_ahead is not None
    step = second.point - second.previous
    np.testing.assert_allclose(second.look_ahead - second.point, params.cut_point_radius * step / np.linalg.norm(step),
                               atol=1e-12)
    np.testing.assert_allclose(second.previous - second.back, params.cut_point_radius * step / np.linalg.norm(step),
                               atol=1e-12)


def test_pairs_through_the_sphere_around_a_cut_point_leave_the_graph():
    p0 = grid_features()
    det = CutDetector(p0, DetectionParams(radius=0.012, cut_point_radius=0.008, tau=5.0, min_measure=1e-5))
    before = det.alive.copy()
    found = None
    for gap in np.linspace(0.0005, 0.01, 30):
        found = det.update(*opened(p0, 0.0525, 0.06, gap), np.ones(len(p0), bool))
        if found is not None:
            break
    assert found is not None
    removed = before & ~det.alive
    a, b = p0[det.pairs[:, 0]], p0[det.pairs[:, 1]]
    t = np.clip(np.einsum("pi,pi->p", found.point - a, b - a) / np.einsum("pi,pi->p", b - a, b - a), 0, 1)
    gap = np.linalg.norm(a + t[:, None] * (b - a) - found.point, axis=1)
    assert removed.any()
    np.testing.assert_array_equal(removed, before & (gap < det.params.cut_point_radius))
    current, target = opened(p0, 0.0525, 0.06, 0.01)
    active = np.ones(len(p0), bool)
    mu, count, mean = det.measure(current, target, active)  # removed from the packed pairs in place
    assert (mu[removed] == -1.0).all()
    expected = reference_measure(p0, det.pairs, current, target, active, det.alive, "target")
    np.testing.assert_allclose(mu, expected, rtol=1e-4, atol=1e-7)  # float32 positions of 0.1 m: 1e-8 m
    assert count == int((expected >= 0).sum()) and mean == pytest.approx(expected[expected >= 0].mean(), rel=1e-4)


def test_a_point_grows_the_nearest_end_or_starts_a_new_polygon():
    det = CutDetector(grid_features(5), DetectionParams(radius=0.03, cut_point_radius=0.01))
    first = det._extend(np.array([0.05, 0.05, 0.0]), 3)
    second = det._extend(np.array([0.05, 0.065, 0.0]), 3)
    third = det._extend(np.array([0.05, 0.035, 0.0]), 3)  # nearer the first point: before it
    far = det._extend(np.array([0.0, 0.0, 0.0]), 3)  # beyond join_radius (0.03) of both ends
    assert (first.previous, first.polygon) == (None, 0)
    assert second.polygon == 0 and not second.at_start and second.back is not None
    assert third.polygon == 0 and third.at_start and third.back is None
    np.testing.assert_allclose(det.polygons[0][:, 1], [0.035, 0.05, 0.065])
    assert far.polygon == 1 and far.previous is None and len(det.polygons) == 2


def test_a_closed_end_is_not_extended_again():
    det = CutDetector(grid_features(5), DetectionParams(radius=0.03, cut_point_radius=0.01, max_turn=180.0))
    det._extend(np.array([0.05, 0.05, 0.0]), 3)
    det._extend(np.array([0.05, 0.065, 0.0]), 3)
    det.close_end(0, False)  # the cut went out through the boundary past (0.05, 0.065)
    beyond = det._extend(np.array([0.05, 0.075, 0.0]), 3)  # nearest the closed end: the open one takes it
    assert beyond.polygon == 0 and beyond.at_start
    det.close_end(0, True)
    alone = det._extend(np.array([0.05, 0.085, 0.0]), 3)  # both ends closed: a polygon of its own
    assert alone.polygon == 1 and alone.previous is None and len(det.polygons[0]) == 3
    with pytest.raises(WcutError, match="no polygon 5"):
        det.close_end(5, True)


@pytest.mark.parametrize("max_turn, kept", [(45.0, (True, False, False)), (180.0, (True, True, True))])
def test_a_point_that_turns_its_polygon_too_far_is_dropped(max_turn, kept):
    det = CutDetector(grid_features(5), DetectionParams(radius=0.03, cut_point_radius=0.01, max_turn=max_turn))
    det._extend(np.array([0.05, 0.02, 0.0]), 3)
    det._extend(np.array([0.05, 0.035, 0.0]), 3)  # the polygon runs along +y
    tries = [np.array([0.055, 0.05, 0.0]),  # 18 degrees off: a smooth bend
             np.array([0.075, 0.04, 0.0]),  # 98 degrees off: back into the object
             np.array([0.035, 0.025, 0.0])]  # back beside the polygon, at its start
    got = [det._extend(point, 3) is not None for point in tries]
    assert tuple(got) == kept
    assert len(det.polygons) == 1 and len(det.polygons[0]) == 2 + sum(kept)


def test_a_polygon_whose_first_point_came_in_from_the_boundary_grows_without_a_back():
    det = CutDetector(grid_features(5), DetectionParams(radius=0.03, cut_point_radius=0.01))
    det._extend(np.array([0.05, 0.01, 0.0]), 3)
    det.close_end(0, True)  # its cut came in from the boundary below (0.05, 0.01)
    second = det._extend(np.array([0.05, 0.025, 0.0]), 3)
    assert second.polygon == 0 and not second.at_start and second.back is None
    np.testing.assert_allclose(second.look_ahead, [0.05, 0.035, 0.0])


def test_lost_features_are_left_out_and_the_floor_holds_noise():
    p0 = grid_features()
    det = CutDetector(p0, DetectionParams(radius=0.012, cut_point_radius=0.008, tau=2.0, min_measure=1e-3))
    rng = np.random.default_rng(3)
    noise = rng.normal(0, 1e-5, p0.shape)  # tracking noise: a few outliers of the relative rule
    assert det.update(p0, p0 + noise, np.ones(len(p0), bool)) is None
    mu, count, _ = det.measure(p0, p0 + noise, np.zeros(len(p0), bool))
    assert count == 0 and (mu == -1.0).all()


@pytest.mark.parametrize("key, value", [("radius", 0.0), ("cut_point_radius", -1.0), ("tau", float("nan")),
                                        ("min_outliers", 0), ("measure", "both"), ("join_radius", -0.1),
                                        ("max_turn", 0.0), ("max_turn", 270.0)])
def test_bad_parameters_name_the_key(key, value):
    settings = dict(radius=0.01, cut_point_radius=0.005)
    settings[key] = value
    with pytest.raises(WcutError, match=f"detection.{key}"):
        DetectionParams(**settings)


def test_a_cut_point_that_removes_every_pair_is_still_returned():
    p0 = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.0, 0.0], [0.03, 0.0, 0.0]])
    det = CutDetector(p0, DetectionParams(radius=0.011, cut_point_radius=0.5, tau=1.0, min_outliers=1))
    target = p0.copy()
    target[2:, 0] += 0.01  # the middle pair opens
    found = det.update(p0, target, np.ones(4, dtype=bool))
    assert found is not None and found.outliers >= 1
    np.testing.assert_allclose(found.point, [0.015, 0.0, 0.0], atol=1e-6)
    assert det.pair_count == 0 and len(det.polygons) == 1 and det.last_outliers >= 1
