"""The pair measure of cut detection (thesis eq. 7.9-7.11).

For a pair (l, m) of features with spring vectors ``d = p^t - p^1``:
``mu_lm = |d_l - d_m| * |q_l - q_m| / delta^0_lm`` where ``q`` is the target ``p^1`` or the
current ``p^t`` (the two variants of eq. 7.10). The caller gives ``d`` and ``q`` per feature
and the live pairs only (in the graph, both features pulling), packed at the front of the
pair arrays: the loop has no branch and reads 8 floats per pair.

Each thread measures a run of ``chunk`` consecutive pairs and adds its partial sum once:
on the CPU a launch runs its threads one after another, and the cost per thread is larger
than the arithmetic of one pair.
"""

import warp as wp


@wp.kernel
def pair_measure(
    pair_indices: wp.array(dtype=wp.vec2i),
    pair_inverse_rest_length: wp.array(dtype=float),
    pair_count: wp.array(dtype=wp.int32),
    feature_spring: wp.array(dtype=wp.vec3),
    feature_spread: wp.array(dtype=wp.vec3),
    chunk: int,
    pair_measure_out: wp.array(dtype=float),
    measure_sum: wp.array(dtype=float),
):
    """Writes ``pair_measure_out[p]`` (m) for the live pairs ``tid * chunk .. tid * chunk +
    chunk - 1`` below ``pair_count[0]`` and adds their sum to ``measure_sum[0]`` (clear it
    before the launch). ``feature_spring`` is ``d`` (m), ``feature_spread`` is ``q`` (m),
    ``pair_inverse_rest_length`` is ``1 / delta^0`` (1/m)."""
    first = wp.tid() * chunk
    last = wp.min(first + chunk, pair_count[0])
    if first >= last:
        return
    total = float(0.0)
    for p in range(first, last):
        pair = pair_indices[p]
        l = pair[0]
        m = pair[1]
        mu = (wp.length(feature_spring[l] - feature_spring[m]) * wp.length(feature_spread[l] - feature_spread[m])
              * pair_inverse_rest_length[p])
        pair_measure_out[p] = mu
        total += mu
    wp.atomic_add(measure_sum, 0, total)
