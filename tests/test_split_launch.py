"""Element kernels split over CPU threads (wcut/split_launch.py, kernels/partial_sums.py)."""

import threading
import time

import numpy as np
import pytest
import warp as wp

from wcut.split_launch import SplitLaunch, ThreadTeam, element_ranges


@wp.kernel
def scatter_pairs(pairs: wp.array(dtype=wp.vec2i), weights: wp.array(dtype=float), y: wp.array(dtype=wp.vec3)):
    """Each element adds its weight times (1, 2, 3) to its two nodes."""
    e = wp.tid()
    w = weights[e] * wp.vec3(1.0, 2.0, 3.0)
    wp.atomic_add(y, pairs[e][0], w)
    wp.atomic_add(y, pairs[e][1], -w)


@pytest.mark.parametrize("count, threads", [(10, 3), (7, 7), (1000, 8), (5, 1)])
def test_ranges_cover_the_elements_once_with_sizes_within_one(count, threads):
    ranges = element_ranges(count, threads)
    assert len(ranges) == threads and ranges[0][0] == 0 and ranges[-1][1] == count
    assert all(a[1] == b[0] for a, b in zip(ranges[:-1], ranges[1:]))
    sizes = [hi - lo for lo, hi in ranges]
    assert max(sizes) - min(sizes) <= 1


def test_a_team_runs_every_part_and_on_more_than_one_thread():
    team = ThreadTeam(3)
    seen, lock = [], threading.Lock()
    barrier = threading.Barrier(3, timeout=10)  # passes only if the three parts run at the same time

    def part(k):
        def run():
            barrier.wait()
            with lock:
                seen.append((k, threading.get_ident()))
        return run

    team.run([part(k) for k in range(3)])
    assert sorted(k for k, _ in seen) == [0, 1, 2]
    assert len({ident for _, ident in seen}) == 3
    assert dict(seen)[0] == threading.get_ident()  # the first part runs on the caller's thread


def test_a_team_re_raises_an_error_of_a_worker_after_all_parts_end():
    team = ThreadTeam(2)
    done = []

    def fail():
        raise ValueError("part 1 failed")

    with pytest.raises(ValueError, match="part 1 failed"):
        team.run([lambda: done.append(0), fail])
    assert done == [0]
    team.run([lambda: done.append(1), lambda: done.append(2)])  # the team still works
    assert sorted(done) == [0, 1, 2]


def test_when_the_callers_part_fails_the_team_still_waits_for_the_workers():
    team = ThreadTeam(2)
    done = []

    def fail():
        raise ValueError("part 0 failed")

    def slow():
        time.sleep(0.05)
        done.append(1)

    with pytest.raises(ValueError, match="part 0 failed"):
        team.run([fail, slow])
    assert done == [1]  # the worker had ended before the error came back


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_a_split_scatter_equals_one_launch_and_leaves_its_scratch_zero(threads):
    rng = np.random.default_rng(threads)
    node_count, count = 50, 400
    pairs = wp.array(rng.integers(0, node_count, size=(count, 2)).astype(np.int32), dtype=wp.vec2i)
    weights = wp.array(rng.integers(1, 9, size=count).astype(np.float32), dtype=float)  # exact sums
    whole = wp.zeros(node_count, dtype=wp.vec3)
    wp.launch(scatter_pairs, count, inputs=[pairs, weights], outputs=[whole])

    y = wp.array(np.ones((node_count, 3), dtype=np.float32), dtype=wp.vec3)  # adds to what is there
    partials = wp.zeros((threads - 1, node_count), dtype=wp.vec3)

    def record(lo, hi, targets):
        return wp.launch(scatter_pairs, hi - lo, inputs=[pairs[lo:hi], weights[lo:hi]], outputs=targets,
                         record_cmd=True)

    split = SplitLaunch(ThreadTeam(threads), count, record, [y], [partials])
    for launch in range(2):
        split.launch()
        np.testing.assert_array_equal(y.numpy(), 1.0 + (launch + 1) * whole.numpy())
        assert not partials.numpy().any()
    assert np.abs(whole.numpy()).max() > 0.0


def test_a_split_launch_refuses_scratch_of_the_wrong_shape():
    y = wp.zeros(10, dtype=wp.vec3)
    with pytest.raises(ValueError, match="shape"):
        SplitLaunch(ThreadTeam(3), 20, lambda lo, hi, t: None, [y], [wp.zeros((1, 10), dtype=wp.vec3)])
    with pytest.raises(ValueError, match="targets"):
        SplitLaunch(ThreadTeam(3), 20, lambda lo, hi, t: None, [y], [])


def test_a_split_launch_does_nothing_while_told_to_skip():
    pairs = wp.array(np.array([[0, 1], [1, 2], [2, 3]], dtype=np.int32), dtype=wp.vec2i)
    weights = wp.array(np.ones(3, dtype=np.float32), dtype=float)
    y, partials = wp.zeros(4, dtype=wp.vec3), wp.zeros((1, 4), dtype=wp.vec3)
    skip = [True]

    def record(lo, hi, targets):
        return wp.launch(scatter_pairs, hi - lo, inputs=[pairs[lo:hi], weights[lo:hi]], outputs=targets,
                         record_cmd=True)

    split = SplitLaunch(ThreadTeam(2), 3, record, [y], [partials], skip=lambda: skip[0])
    split.launch()
    assert not y.numpy().any()
    skip[0] = False
    split.launch()
    assert y.numpy().any()


def test_without_add_partials_the_rows_wait_for_the_next_kernel():
    pairs = wp.array(np.array([[0, 1], [1, 2], [2, 3], [3, 0]], dtype=np.int32), dtype=wp.vec2i)
    weights = wp.array(np.array([1.0, 2.0, 3.0, 4.0], dtype=np.float32), dtype=float)
    whole = wp.zeros(4, dtype=wp.vec3)
    wp.launch(scatter_pairs, 4, inputs=[pairs, weights], outputs=[whole])
    y, partials = wp.zeros(4, dtype=wp.vec3), wp.zeros((1, 4), dtype=wp.vec3)

    def record(lo, hi, targets):
        return wp.launch(scatter_pairs, hi - lo, inputs=[pairs[lo:hi], weights[lo:hi]], outputs=targets,
                         record_cmd=True)

    SplitLaunch(ThreadTeam(2), 4, record, [y], [partials], add_partials=False).launch()
    assert partials.numpy().any()  # the second range's share, not yet added
    np.testing.assert_array_equal(y.numpy() + partials.numpy()[0], whole.numpy())
