"""The pair measure of cut detection (thesis eq. 7.9-7.11).

For a pair (l, m) of features with spring vectors ``d = p^t - p^1``:
``mu_lm = |d_l - d_m| * |q_l - q_m| / delta^0_lm`` where ``q`` is the target ``p^1`` or the
current ``p^t`` (the two variants of eq. 7.10). Pairs out of the graph or with a feature that
no longer pulls get ``mu = -1`` and are left out of the sums.

Each thread measures a run of ``chunk`` consecutive pairs and adds its partial sums once:
on the CPU a launch runs its threads one after another, and the cost per thread is larger
than the arithmetic of one pair.
"""

import warp as wp


@wp.kernel
def pair_measure(
    pair_indices: wp.array(dtype=wp.vec2i),
    pair_rest_length: wp.array(dtype=float),
    pair_alive: wp.array(dtype=wp.int32),
    feature_active: wp.array(dtype=wp.int32),
    feature_current: wp.array(dtype=wp.vec3),
    feature_target: wp.array(dtype=wp.vec3),
    use_target: int,
    chunk: int,
    pair_measure_out: wp.array(dtype=float),
    measure_sum: wp.array(dtype=float),
):
    """Writes ``pair_measure_out[p]`` (m) for pairs ``tid * chunk .. tid * chunk + chunk - 1``
    and adds the sum of their live measures and their count to ``measure_sum[0]`` and
    ``measure_sum[1]`` (clear them before the launch)."""
    first = wp.tid() * chunk
    last = wp.min(first + chunk, pair_indices.shape[0])
    total = float(0.0)
    count = float(0.0)
    for p in range(first, last):
        pair = pair_indices[p]
        l = pair[0]
        m = pair[1]
        mu = float(-1.0)
        if pair_alive[p] != 0 and feature_active[l] != 0 and feature_active[m] != 0:
            cl = feature_current[l]
            cm = feature_current[m]
            tl = feature_target[l]
            tm = feature_target[m]
            spread = wp.length(cl - cm)
            if use_target != 0:
                spread = wp.length(tl - tm)
            mu = wp.length((cl - tl) - (cm - tm)) * spread / pair_rest_length[p]
            total += mu
            count += 1.0
        pair_measure_out[p] = mu
    wp.atomic_add(measure_sum, 0, total)
    wp.atomic_add(measure_sum, 1, count)
