"""The pair measure of cut detection and its outliers (thesis eq. 7.9-7.11).

For a pair (l, m) of features with spring vectors ``d = p^t - p^1``:
``mu_lm = |d_l - d_m| * |q_l - q_m| / delta^0_lm`` where ``q`` is the target ``p^1`` or the
current ``p^t`` (the two variants of eq. 7.10). The live pairs (in the graph, both features
pulling) are packed at the front of the pair arrays by the caller, grouped by their first
feature, so the pair loop has no branch. The kernels run in this order, as one captured graph: :func:`feature_motion`,
:func:`pair_measure`, :func:`count_outliers`, then, once there are enough outliers, the
cluster around the strongest one: :func:`strongest_outlier`, :func:`first_strongest`,
:func:`outlier_cluster`.

Each thread handles a run of ``chunk`` consecutive pairs (or features) and adds its partial
sums once: on the CPU a launch runs its threads one after another, and the caller gives one
thread all of them.
"""

import warp as wp


@wp.kernel
def feature_motion(
    feature_current: wp.array(dtype=wp.vec3),
    feature_target: wp.array(dtype=wp.vec3),
    use_target: int,
    feature_spring: wp.array(dtype=wp.vec3),
    feature_spread: wp.array(dtype=wp.vec3),
):
    """Per feature: the spring vector ``d = p^t - p^1`` (m) and the position ``q`` whose
    spread the measure uses (m): the target if ``use_target``, else the current position."""
    f = wp.tid()
    current = feature_current[f]
    target = feature_target[f]
    feature_spring[f] = current - target
    if use_target != 0:
        feature_spread[f] = target
    else:
        feature_spread[f] = current


@wp.kernel
def pair_measure(
    feature_pair_start: wp.array(dtype=wp.int32),
    pair_other: wp.array(dtype=wp.int32),
    pair_inverse_rest_length: wp.array(dtype=float),
    feature_spring: wp.array(dtype=wp.vec3),
    feature_spread: wp.array(dtype=wp.vec3),
    features_per_thread: int,
    pair_measure_out: wp.array(dtype=float),
    measure_sum: wp.array(dtype=float),
):
    """Writes ``pair_measure_out[p]`` (m) for the live pairs (l, m) of the features
    ``l = tid * features_per_thread ..`` (the pairs ``feature_pair_start[l] ..
    feature_pair_start[l + 1] - 1``, ``m = pair_other[p]``) and adds their sum to
    ``measure_sum[0]`` (clear it before the launch). ``pair_inverse_rest_length`` is
    ``1 / delta^0`` (1/m). Grouping the pairs by their first feature (l < m) reads its
    vectors once for all its pairs: 1.4x faster on the CPU than a flat list of pairs."""
    first = wp.tid() * features_per_thread
    last = wp.min(first + features_per_thread, feature_spring.shape[0])
    total = float(0.0)
    for l in range(first, last):
        spring = feature_spring[l]
        spread = feature_spread[l]
        for p in range(feature_pair_start[l], feature_pair_start[l + 1]):
            m = pair_other[p]
            mu = (wp.length(spring - feature_spring[m]) * wp.length(spread - feature_spread[m])
                  * pair_inverse_rest_length[p])
            pair_measure_out[p] = mu
            total += mu
    if total != 0.0:
        wp.atomic_add(measure_sum, 0, total)


@wp.kernel
def count_outliers(
    pair_measure: wp.array(dtype=float),
    pair_count: wp.array(dtype=wp.int32),
    measured_count: wp.array(dtype=wp.int32),
    measure_sum: wp.array(dtype=float),
    tau: float,
    min_measure: float,
    chunk: int,
    threshold_out: wp.array(dtype=float),
    outlier_count: wp.array(dtype=wp.int32),
):
    """The outlier threshold ``max(tau * mean, min_measure)`` (m) into ``threshold_out[0]``
    and the number of pairs above it added to ``outlier_count[0]`` (clear it before). The
    mean is over ``measured_count[0]`` pairs: packed pairs removed since their packing
    measure 0 and do not count."""
    count = pair_count[0]
    if measured_count[0] == 0:
        return
    threshold = wp.max(tau * (measure_sum[0] / float(measured_count[0])), min_measure)
    if wp.tid() == 0:
        threshold_out[0] = threshold
    first = wp.tid() * chunk
    last = wp.min(first + chunk, count)
    above = int(0)
    for p in range(first, last):
        if pair_measure[p] > threshold:
            above += 1
    if above > 0:
        wp.atomic_add(outlier_count, 0, above)


@wp.kernel
def strongest_outlier(
    pair_measure: wp.array(dtype=float),
    pair_count: wp.array(dtype=wp.int32),
    threshold: wp.array(dtype=float),
    outlier_count: wp.array(dtype=wp.int32),
    min_outliers: int,
    chunk: int,
    largest: wp.array(dtype=float),
):
    """The largest outlier measure into ``largest[0]`` (m; clear it before), once there are
    ``min_outliers`` outliers."""
    if outlier_count[0] < min_outliers:
        return
    first = wp.tid() * chunk
    last = wp.min(first + chunk, pair_count[0])
    top = float(0.0)
    for p in range(first, last):
        top = wp.max(top, pair_measure[p])
    if top > threshold[0]:
        wp.atomic_max(largest, 0, top)


@wp.kernel
def first_strongest(
    pair_measure: wp.array(dtype=float),
    pair_count: wp.array(dtype=wp.int32),
    outlier_count: wp.array(dtype=wp.int32),
    largest: wp.array(dtype=float),
    min_outliers: int,
    chunk: int,
    strongest: wp.array(dtype=wp.int32),
):
    """The first pair whose measure is ``largest[0]`` (as ``np.argmax``) into ``strongest[0]``
    (set it to the pair count before)."""
    if outlier_count[0] < min_outliers:
        return
    first = wp.tid() * chunk
    last = wp.min(first + chunk, pair_count[0])
    for p in range(first, last):
        if pair_measure[p] == largest[0]:
            wp.atomic_min(strongest, 0, p)
            return


@wp.kernel
def outlier_cluster(
    pair_measure: wp.array(dtype=float),
    pair_midpoint: wp.array(dtype=wp.vec3),
    pair_count: wp.array(dtype=wp.int32),
    threshold: wp.array(dtype=float),
    outlier_count: wp.array(dtype=wp.int32),
    strongest: wp.array(dtype=wp.int32),
    min_outliers: int,
    reach: float,
    chunk: int,
    cluster_weighted_sum: wp.array(dtype=wp.vec4),
    cluster_count: wp.array(dtype=wp.int32),
):
    """The outliers whose midpoint (m, rest) lies within ``reach`` of the strongest one's:
    their number into ``cluster_count[0]`` and ``(sum mu * midpoint, sum mu)`` into
    ``cluster_weighted_sum[0]`` (clear both before)."""
    if outlier_count[0] < min_outliers:
        return
    count = pair_count[0]
    centre = pair_midpoint[strongest[0]]
    first = wp.tid() * chunk
    last = wp.min(first + chunk, count)
    found = int(0)
    total = wp.vec4(0.0)
    for p in range(first, last):
        mu = pair_measure[p]
        offset = pair_midpoint[p] - centre
        if mu > threshold[0] and wp.dot(offset, offset) <= reach * reach:
            found += 1
            x = pair_midpoint[p]
            total += wp.vec4(mu * x[0], mu * x[1], mu * x[2], mu)
    if found > 0:
        wp.atomic_add(cluster_count, 0, found)
        wp.atomic_add(cluster_weighted_sum, 0, total)
