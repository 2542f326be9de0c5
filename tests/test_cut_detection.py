"""Tests of wcut.kernels.cut_detection: each kernel against numpy, run as the CPU runs it (one
thread for all pairs) and as a GPU would (many threads, partial sums and atomics)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from wcut.kernels import cut_detection as k


def _pairs(rng, features: int, per_feature: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (l < m) grouped by l, as the detector packs them: CSR starts and the others."""
    pairs = {(int(a), int(b)) for a, b in rng.integers(0, features, (features * per_feature, 2)) if a < b}
    pairs = np.array(sorted(pairs), dtype=np.int64)
    start = np.searchsorted(pairs[:, 0], np.arange(features + 1))
    return pairs, start


def _feature_vectors(current, target, use_target: int, rows: int) -> wp.array:
    """:func:`prepare_features` of features all active and packed: their (d, q) rows."""
    F = len(current)
    vectors = wp.zeros(F, dtype=k.mat23)
    everyone = wp.array(np.ones(F, dtype=bool), dtype=wp.bool)
    none = wp.zeros(F + 1, dtype=wp.int32)
    wp.launch(k.prepare_features, -(-F // rows),
              inputs=[wp.array(current, dtype=wp.vec3), wp.array(target, dtype=wp.vec3), use_target, everyone, none,
                      none, rows],
              outputs=[vectors, everyone, none, wp.zeros(1), wp.zeros(1, dtype=wp.int32), wp.zeros(1, dtype=wp.int32)])
    return vectors


@pytest.mark.parametrize("use_target", [1, 0])
@pytest.mark.parametrize("split", ["one thread", "many threads"])
def test_measure_outliers_and_cluster_equal_numpy(use_target, split):
    rng = np.random.default_rng(5)
    F = 120
    pairs, start = _pairs(rng, F, 6)
    P = len(pairs)
    current = rng.normal(0.0, 0.01, (F, 3)).astype(np.float32)
    target = (current + rng.normal(0.0, 1e-3, (F, 3))).astype(np.float32)
    target[:20, 0] += 0.02  # a few features far off: outliers
    inverse = (1.0 / rng.uniform(0.005, 0.01, P)).astype(np.float32)
    midpoint = rng.uniform(0.0, 0.05, (P, 3)).astype(np.float32)
    tau, min_measure, reach = 3.0, 0.0, 0.02

    l, m = pairs[:, 0], pairs[:, 1]
    d = current.astype(np.float64) - target
    q = (target if use_target else current).astype(np.float64)
    expected = np.linalg.norm(d[l] - d[m], axis=1) * np.linalg.norm(q[l] - q[m], axis=1) * inverse

    rows = F if split == "one thread" else 7
    threads = -(-F // rows)
    mu, row_max = wp.zeros(P, dtype=float), wp.zeros(F, dtype=float)
    total, top = wp.zeros(1, dtype=float), wp.zeros(1, dtype=float)
    start_wp = wp.array(start, dtype=wp.int32)
    vectors = _feature_vectors(current, target, use_target, rows)
    wp.launch(k.pair_measure, threads, inputs=[start_wp, wp.array(m, dtype=wp.int32), wp.array(inverse), vectors, rows],
              outputs=[mu, row_max, total, top])
    values = mu.numpy()
    np.testing.assert_allclose(values, expected, rtol=1e-5)
    assert total.numpy()[0] == pytest.approx(expected.sum(), rel=1e-5)
    assert top.numpy()[0] == values.max()
    np.testing.assert_array_equal(row_max.numpy(), [values[a:b].max(initial=0.0) for a, b in zip(start, start[1:])])

    threshold, outliers = wp.zeros(1, dtype=float), wp.zeros(1, dtype=wp.int32)
    largest, strongest = wp.zeros(1, dtype=float), wp.array([P], dtype=wp.int32)
    count, mean, repack = wp.array([P], dtype=wp.int32), wp.zeros(1, dtype=float), wp.array([1], dtype=wp.int32)
    inputs = [mu, start_wp, row_max, count, total, top, repack, tau, min_measure, rows]
    wp.launch(k.count_outliers, threads, inputs=inputs, outputs=[mean, threshold, outliers, largest, strongest])
    assert outliers.numpy()[0] == 0  # a feature came back: the caller measures again
    repack.zero_()
    wp.launch(k.count_outliers, threads, inputs=inputs, outputs=[mean, threshold, outliers, largest, strongest])
    wp.launch(k.first_strongest, threads, inputs=[mu, start_wp, row_max, outliers, largest, 3, rows],
              outputs=[strongest])
    assert mean.numpy()[0] == pytest.approx(float(total.numpy()[0]) / P, rel=1e-6)
    assert threshold.numpy()[0] == pytest.approx(tau * mean.numpy()[0], rel=1e-6)
    above = values > threshold.numpy()[0]
    assert outliers.numpy()[0] == above.sum() >= 3
    assert largest.numpy()[0] == values.max() and strongest.numpy()[0] == np.argmax(values)

    weighted, found = wp.zeros(1, dtype=wp.vec4), wp.zeros(1, dtype=wp.int32)
    wp.launch(k.outlier_cluster, threads,
              inputs=[mu, wp.array(midpoint, dtype=wp.vec3), start_wp, row_max, threshold, outliers, strongest, 3,
                      reach, rows],
              outputs=[weighted, found])
    near = above & (np.sum((midpoint - midpoint[np.argmax(values)]) ** 2, axis=1) <= reach * reach)
    assert found.numpy()[0] == near.sum() >= 1
    expected_sum = np.concatenate([(values[near, None] * midpoint[near]).sum(axis=0), [values[near].sum()]])
    np.testing.assert_allclose(weighted.numpy()[0], expected_sum, rtol=1e-5)

    point = wp.zeros(1, dtype=wp.vec3d)
    wp.launch(k.cluster_cut_point, 1, inputs=[weighted, found, int(near.sum()) + 1], outputs=[point])
    assert not point.numpy().any()  # too few outliers near the strongest: no cut point
    wp.launch(k.cluster_cut_point, 1, inputs=[weighted, found, int(near.sum())], outputs=[point])
    total = weighted.numpy()[0].astype(np.float64)
    np.testing.assert_array_equal(point.numpy()[0], total[:3] / total[3])


@pytest.mark.parametrize("rows", [4, 1])
def test_the_first_of_equal_largest_measures_is_the_strongest(rows):
    start = np.arange(0, 21, 5)  # 4 features, 5 pairs each
    values = np.full(20, 1.0, dtype=np.float32)
    values[[7, 13, 16]] = 9.0  # equal largest measures in rows 1, 2 and 3
    mu, start_wp = wp.array(values), wp.array(start, dtype=wp.int32)
    row_max = wp.array([values[a:b].max() for a, b in zip(start, start[1:])], dtype=float)
    count, total = wp.array([20], dtype=wp.int32), wp.array([values.sum()], dtype=float)
    top = wp.array([9.0], dtype=float)
    threshold, outliers = wp.zeros(1, dtype=float), wp.zeros(1, dtype=wp.int32)
    largest, strongest = wp.zeros(1, dtype=float), wp.array([20], dtype=wp.int32)
    threads = -(-4 // rows)
    wp.launch(k.count_outliers, threads, inputs=[mu, start_wp, row_max, count, total, top, wp.zeros(1, dtype=wp.int32),
                                                 2.0, 0.0, rows],
              outputs=[wp.zeros(1, dtype=float), threshold, outliers, largest, strongest])
    wp.launch(k.first_strongest, threads, inputs=[mu, start_wp, row_max, outliers, largest, 3, rows],
              outputs=[strongest])
    assert outliers.numpy()[0] == 3 and largest.numpy()[0] == 9.0
    assert strongest.numpy()[0] == 7 == np.argmax(values)


def test_without_an_outlier_no_pair_is_counted():
    mu = wp.array(np.full(50, 2.0, dtype=np.float32))
    start = wp.array(np.arange(0, 51, 5), dtype=wp.int32)  # 10 features, 5 pairs each
    row_max = wp.array(np.full(10, 2.0, dtype=np.float32))
    count, total, top = wp.array([50], dtype=wp.int32), wp.array([100.0], dtype=float), wp.array([2.0], dtype=float)
    threshold, outliers = wp.zeros(1, dtype=float), wp.zeros(1, dtype=wp.int32)
    largest, strongest = wp.zeros(1, dtype=float), wp.array([50], dtype=wp.int32)
    wp.launch(k.count_outliers, 1, inputs=[mu, start, row_max, count, total, top, wp.zeros(1, dtype=wp.int32), 1.5,
                                           0.0, 10],
              outputs=[wp.zeros(1, dtype=float), threshold, outliers, largest, strongest])
    assert threshold.numpy()[0] == pytest.approx(3.0)
    assert outliers.numpy()[0] == 0 and strongest.numpy()[0] == 50


@pytest.mark.parametrize("chunk", [1000, 3])
def test_pairs_near_a_point_leave_the_graph_and_the_packing(chunk):
    rng = np.random.default_rng(2)
    a, b = rng.uniform(0.0, 0.05, (400, 3)), rng.uniform(0.0, 0.05, (400, 3))
    b[:10] = a[:10]  # zero-length pairs: their point
    point, radius = np.array([0.025, 0.02, 0.03]), 0.008
    alive = rng.uniform(size=len(a)) < 0.9
    slot = np.where(alive & (rng.uniform(size=len(a)) < 0.8), rng.permutation(len(a)), -1)
    inverse = rng.uniform(50.0, 100.0, len(a)).astype(np.float32)
    measured = int((slot >= 0).sum())
    outputs = [wp.array(alive, dtype=wp.bool), wp.array(slot, dtype=wp.int32), wp.array(inverse),
               wp.array([measured], dtype=wp.int32)]
    inputs = [wp.array(0.5 * (a + b), dtype=wp.vec3d), wp.array(0.5 * (b - a), dtype=wp.vec3d),
              wp.array(point[None], dtype=wp.vec3d), radius, wp.array([2], dtype=wp.int32)]
    wp.launch(k.remove_pairs_near_point, -(-len(a) // chunk), inputs=[*inputs, 3, chunk], outputs=outputs)
    np.testing.assert_array_equal(outputs[0].numpy(), alive)  # no cut point put: nothing removed
    wp.launch(k.remove_pairs_near_point, -(-len(a) // chunk), inputs=[*inputs, 2, chunk], outputs=outputs)
    ab = b - a
    s = np.clip(np.einsum("pi,pi->p", point - a, ab) / np.maximum(np.einsum("pi,pi->p", ab, ab), 1e-300), 0, 1)
    near = np.linalg.norm(a + s[:, None] * ab - point, axis=1) < radius
    assert 10 < near.sum() < 390 and (near & (slot >= 0)).sum() > 5
    np.testing.assert_array_equal(outputs[0].numpy(), alive & ~near)
    np.testing.assert_array_equal(outputs[1].numpy(), np.where(near, -1, slot))
    expected_inverse = inverse.copy()
    expected_inverse[slot[near & (slot >= 0)]] = 0.0
    np.testing.assert_array_equal(outputs[2].numpy(), expected_inverse)
    assert outputs[3].numpy()[0] == measured - (near & (slot >= 0)).sum()


@pytest.mark.parametrize("rows", [120, 7])
def test_features_that_leave_take_their_packed_pairs_out_once(rows):
    rng = np.random.default_rng(3)
    F = 120
    pairs, _ = _pairs(rng, F, 5)
    P = len(pairs)
    ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
    order = np.argsort(ends, kind="stable")
    incident_start = np.searchsorted(ends[order], np.arange(F + 1))
    slot = np.where(rng.uniform(size=P) < 0.9, rng.permutation(P), -1)  # a few pairs not packed
    packed = np.ones(F, dtype=bool)
    packed[:5] = False  # left before
    active = rng.uniform(size=F) > 0.3
    active[:5] = False
    inverse = rng.uniform(50.0, 100.0, P).astype(np.float32)
    arrays = dict(packed=wp.array(packed, dtype=wp.bool), slot=wp.array(slot, dtype=wp.int32),
                  inverse=wp.array(inverse), measured=wp.array([(slot >= 0).sum()], dtype=wp.int32),
                  repack=wp.zeros(1, dtype=wp.int32))
    current, target = rng.normal(0.0, 0.01, (F, 3)), rng.normal(0.0, 0.01, (F, 3))
    vectors = wp.zeros(F, dtype=k.mat23)
    positions = [wp.array(current, dtype=wp.vec3), wp.array(target, dtype=wp.vec3), 0]
    graph = [wp.array(incident_start, dtype=wp.int32), wp.array(order % P, dtype=wp.int32), rows]
    wp.launch(k.prepare_features, -(-F // rows), inputs=[*positions, wp.array(active, dtype=wp.bool), *graph],
              outputs=[vectors, *arrays.values()])
    np.testing.assert_allclose(vectors.numpy(), np.stack([current - target, current], axis=1), rtol=1e-6, atol=1e-9)

    leaving = packed & ~active
    gone = leaving[pairs[:, 0]] | leaving[pairs[:, 1]]
    assert (gone & (slot >= 0)).sum() > 20 and (leaving[pairs[:, 0]] & leaving[pairs[:, 1]] & (slot >= 0)).any()
    expected_inverse = inverse.copy()
    expected_inverse[slot[gone & (slot >= 0)]] = 0.0
    np.testing.assert_array_equal(arrays["slot"].numpy(), np.where(gone, -1, slot))
    np.testing.assert_array_equal(arrays["inverse"].numpy(), expected_inverse)
    assert arrays["measured"].numpy()[0] == ((slot >= 0) & ~gone).sum()
    np.testing.assert_array_equal(arrays["packed"].numpy(), packed & active)
    assert arrays["repack"].numpy()[0] == 0

    active[2] = True  # tracked again: its pairs are not packed
    wp.launch(k.prepare_features, -(-F // rows), inputs=[*positions, wp.array(active, dtype=wp.bool), *graph],
              outputs=[vectors, *arrays.values()])
    assert arrays["repack"].numpy()[0] == 1
    assert arrays["measured"].numpy()[0] == ((slot >= 0) & ~gone).sum()  # nothing more left
