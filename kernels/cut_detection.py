"""The pair measure of cut detection and its outliers (thesis eq. 7.9-7.11).

For a pair (l, m) of features with spring vectors ``d = p^t - p^1``:
``mu_lm = |d_l - d_m| * |q_l - q_m| / delta^0_lm`` where ``q`` is the target ``p^1`` or the
current ``p^t`` (the two variants of eq. 7.10). The live pairs (in the graph, both features
pulling) are packed at the front of the pair arrays by the caller, grouped by their first
feature, so the pair loop has no branch. The kernels run in this order, as one captured
graph:

1. :func:`prepare_features`: each feature's two vectors; the pairs of features that stopped
   pulling leave the packing in place;
2. :func:`pair_measure`, then :func:`count_outliers` (with the largest outlier);
3. once there are enough outliers, the cluster around the strongest one:
   :func:`first_strongest`, :func:`outlier_cluster`;
4. when they put a cut point, :func:`cluster_cut_point` and
   :func:`remove_pairs_near_point`, which takes the pairs through it out of the graph.

Each thread handles a run of ``rows`` consecutive features (their rows of pairs; of ``chunk``
pairs in :func:`remove_pairs_near_point`) and adds its partial sums once: on the CPU a launch
runs its threads one after another, and the caller gives one thread all of them.
:func:`pair_measure` keeps each row's largest measure, so the later kernels read only the rows
that hold an outlier (a frame without a cut has a few).
"""

import warp as wp

from .ranges import thread_range


#: a feature's two vectors of the measure, as rows: its spring ``d`` and its spread ``q``
mat23 = wp.types.matrix(shape=(2, 3), dtype=float)


@wp.func
def take_out(pair: int, pair_slot: wp.array(dtype=wp.int32), pair_inverse_rest_length: wp.array(dtype=float)):
    """Take a pair out of the packing in place: its packed ``1 / delta^0`` becomes 0 (it
    measures 0) and its slot -1. Returns 1 if it was packed, else 0; the slot is exchanged
    atomically, so a pair taken out by two threads at once counts once."""
    slot = wp.atomic_exch(pair_slot, pair, -1)
    if slot < 0:
        return 0
    pair_inverse_rest_length[slot] = 0.0
    return 1


@wp.kernel
def prepare_features(
    feature_current: wp.array(dtype=wp.vec3),
    feature_target: wp.array(dtype=wp.vec3),
    use_target: int,
    feature_active: wp.array(dtype=wp.bool),
    feature_incident_start: wp.array(dtype=wp.int32),
    feature_incident: wp.array(dtype=wp.int32),
    rows: int,
    feature_vectors: wp.array(dtype=mat23),
    feature_packed: wp.array(dtype=wp.bool),
    pair_slot: wp.array(dtype=wp.int32),
    pair_inverse_rest_length: wp.array(dtype=float),
    measured_count: wp.array(dtype=wp.int32),
    repack: wp.array(dtype=wp.int32),
):
    """Per feature ``l = tid * rows ..``, the two things a frame changes before the measure.

    - ``feature_vectors[l]``: rows ``d = p^t - p^1`` and ``q`` (m), the target ``p^1`` if
      ``use_target``, else the current ``p^t`` (``feature_current``, ``feature_target``). Side
      by side, the measure reads both of a pair's other feature at once: 1.2x faster on the CPU
      than reading p^t and p^1 per pair.
    - A feature packed active (``feature_packed``) that is not ``feature_active`` now takes its
      pairs out of the packing (:func:`take_out`; ``pair_slot``: pair -> packed index) and
      ``measured_count[0]`` drops by one per pair. Its pairs are
      ``feature_incident[feature_incident_start[l] .. feature_incident_start[l + 1] - 1]``. A
      feature active now but not packed (tracked again) sets ``repack[0] = 1``: the caller
      packs the live pairs again (the outliers of this launch are not counted).
    """
    first, last = thread_range(wp.tid(), rows, feature_active.shape[0])
    dropped = int(0)
    for l in range(first, last):
        current = feature_current[l]
        target = feature_target[l]
        feature_vectors[l] = wp.matrix_from_rows(current - target, wp.where(use_target != 0, target, current))
        if feature_active[l] == feature_packed[l]:
            continue
        if feature_active[l]:
            repack[0] = 1
            continue
        feature_packed[l] = False
        for i in range(feature_incident_start[l], feature_incident_start[l + 1]):
            dropped += take_out(feature_incident[i], pair_slot, pair_inverse_rest_length)
    if dropped > 0:
        wp.atomic_sub(measured_count, 0, dropped)


@wp.kernel
def pair_measure(
    feature_pair_start: wp.array(dtype=wp.int32),
    pair_other: wp.array(dtype=wp.int32),
    pair_inverse_rest_length: wp.array(dtype=float),
    feature_vectors: wp.array(dtype=mat23),
    rows: int,
    pair_measure_out: wp.array(dtype=float),
    feature_row_max: wp.array(dtype=float),
    measure_sum: wp.array(dtype=float),
    measure_max: wp.array(dtype=float),
):
    """Writes ``pair_measure_out[p]`` (m) for the live pairs (l, m) of the features
    ``l = tid * rows ..`` (the pairs ``feature_pair_start[l] .. feature_pair_start[l + 1] - 1``,
    ``m = pair_other[p]``) and the largest of each row into ``feature_row_max[l]`` (m), adds
    their sum to ``measure_sum[0]`` and raises ``measure_max[0]`` to their largest (clear both
    before the launch). ``feature_vectors`` are the rows ``(d, q)`` of
    :func:`prepare_features`; ``pair_inverse_rest_length`` is ``1 / delta^0`` (1/m). Grouping
    the pairs by their first feature (l < m) reads its vectors once for all its pairs: 1.4x
    faster on the CPU than a flat list of pairs."""
    first, last = thread_range(wp.tid(), rows, feature_vectors.shape[0])
    total = float(0.0)
    top = float(0.0)
    for l in range(first, last):
        a = feature_vectors[l]
        row_top = float(0.0)
        for p in range(feature_pair_start[l], feature_pair_start[l + 1]):
            b = feature_vectors[pair_other[p]]
            mu = wp.length(a[0] - b[0]) * wp.length(a[1] - b[1]) * pair_inverse_rest_length[p]
            pair_measure_out[p] = mu
            total += mu
            row_top = wp.max(row_top, mu)
        feature_row_max[l] = row_top
        top = wp.max(top, row_top)
    if total != 0.0:
        wp.atomic_add(measure_sum, 0, total)
        wp.atomic_max(measure_max, 0, top)


@wp.kernel
def count_outliers(
    pair_measure: wp.array(dtype=float),
    feature_pair_start: wp.array(dtype=wp.int32),
    feature_row_max: wp.array(dtype=float),
    measured_count: wp.array(dtype=wp.int32),
    measure_sum: wp.array(dtype=float),
    measure_max: wp.array(dtype=float),
    repack: wp.array(dtype=wp.int32),
    tau: float,
    min_measure: float,
    rows: int,
    mean_out: wp.array(dtype=float),
    threshold_out: wp.array(dtype=float),
    outlier_count: wp.array(dtype=wp.int32),
    largest: wp.array(dtype=float),
    strongest: wp.array(dtype=wp.int32),
):
    """The mean measure (m) into ``mean_out[0]``, the outlier threshold
    ``max(tau * mean, min_measure)`` (m) into ``threshold_out[0]``, the number of pairs above
    it added to ``outlier_count[0]`` and their largest measure (m) into ``largest[0]`` (clear
    them before). The mean is over ``measured_count[0]`` pairs: packed pairs removed since
    their packing measure 0 and do not count. Only the rows whose largest measure is above
    the threshold are read, none on most frames. A thread that sees every row (the CPU's)
    also writes the first pair of largest measure into ``strongest[0]``, which
    :func:`first_strongest` then leaves. No outlier is counted when ``repack[0]`` is set:
    the measure missed the pairs of a feature tracked again."""
    if measured_count[0] == 0:
        return
    mean = measure_sum[0] / float(measured_count[0])
    threshold = wp.max(tau * mean, min_measure)
    if wp.tid() == 0:
        mean_out[0] = mean
        threshold_out[0] = threshold
    if measure_max[0] <= threshold or repack[0] != 0:
        return
    features = feature_row_max.shape[0]
    first, last = thread_range(wp.tid(), rows, features)
    above = int(0)
    top = float(0.0)
    top_pair = int(0)
    for l in range(first, last):
        if feature_row_max[l] > threshold:
            for p in range(feature_pair_start[l], feature_pair_start[l + 1]):
                mu = pair_measure[p]
                if mu > threshold:
                    above += 1
                    if mu > top:  # strictly: the first of equal measures stays, as np.argmax
                        top = mu
                        top_pair = p
    if above > 0:
        wp.atomic_add(outlier_count, 0, above)
        wp.atomic_max(largest, 0, top)
        if first == 0 and last == features:
            strongest[0] = top_pair


@wp.kernel
def first_strongest(
    pair_measure: wp.array(dtype=float),
    feature_pair_start: wp.array(dtype=wp.int32),
    feature_row_max: wp.array(dtype=float),
    outlier_count: wp.array(dtype=wp.int32),
    largest: wp.array(dtype=float),
    min_outliers: int,
    rows: int,
    strongest: wp.array(dtype=wp.int32),
):
    """The first pair whose measure is ``largest[0]`` (as ``np.argmax``) into ``strongest[0]``
    (set it above the packed pairs before), unless one thread had every row and
    :func:`count_outliers` found it. (Whether it did is decided by ``rows``, not by reading
    ``strongest``, which other threads of this launch are lowering.)"""
    features = feature_row_max.shape[0]
    if outlier_count[0] < min_outliers or rows >= features:  # one thread saw every row: found
        return
    first, last = thread_range(wp.tid(), rows, features)
    top = largest[0]
    for l in range(first, last):
        if feature_row_max[l] == top:
            for p in range(feature_pair_start[l], feature_pair_start[l + 1]):
                if pair_measure[p] == top:
                    wp.atomic_min(strongest, 0, p)
                    return


@wp.kernel
def outlier_cluster(
    pair_measure: wp.array(dtype=float),
    pair_midpoint: wp.array(dtype=wp.vec3),
    feature_pair_start: wp.array(dtype=wp.int32),
    feature_row_max: wp.array(dtype=float),
    threshold: wp.array(dtype=float),
    outlier_count: wp.array(dtype=wp.int32),
    strongest: wp.array(dtype=wp.int32),
    min_outliers: int,
    reach: float,
    rows: int,
    cluster_weighted_sum: wp.array(dtype=wp.vec4),
    cluster_count: wp.array(dtype=wp.int32),
):
    """The outliers whose midpoint (m, rest) lies within ``reach`` of the strongest one's:
    their number into ``cluster_count[0]`` and ``(sum mu * midpoint, sum mu)`` into
    ``cluster_weighted_sum[0]`` (clear both before)."""
    if outlier_count[0] < min_outliers:
        return
    centre = pair_midpoint[strongest[0]]
    limit = threshold[0]
    first, last = thread_range(wp.tid(), rows, feature_row_max.shape[0])
    found = int(0)
    total = wp.vec4(0.0)
    for l in range(first, last):
        if feature_row_max[l] > limit:  # the rows holding an outlier only
            for p in range(feature_pair_start[l], feature_pair_start[l + 1]):
                mu = pair_measure[p]
                if mu > limit:
                    x = pair_midpoint[p]
                    offset = x - centre
                    if wp.dot(offset, offset) <= reach * reach:
                        found += 1
                        total += wp.vec4(mu * x[0], mu * x[1], mu * x[2], mu)
    if found > 0:
        wp.atomic_add(cluster_count, 0, found)
        wp.atomic_add(cluster_weighted_sum, 0, total)


@wp.kernel
def cluster_cut_point(
    cluster_weighted_sum: wp.array(dtype=wp.vec4),
    cluster_count: wp.array(dtype=wp.int32),
    min_outliers: int,
    point: wp.array(dtype=wp.vec3d),
):
    """The cut point (thesis 7.5.3) into ``point[0]`` (m, rest, float64) once the cluster of
    :func:`outlier_cluster` has ``min_outliers`` outliers: their midpoints' barycentre weighted
    by their measure. One thread."""
    if cluster_count[0] < min_outliers:
        return
    total = cluster_weighted_sum[0]
    weight = wp.float64(total[3])
    point[0] = wp.vec3d(wp.float64(total[0]) / weight, wp.float64(total[1]) / weight, wp.float64(total[2]) / weight)


@wp.kernel
def remove_pairs_near_point(
    pair_midpoint: wp.array(dtype=wp.vec3d),
    pair_half: wp.array(dtype=wp.vec3d),
    point: wp.array(dtype=wp.vec3d),
    radius: wp.float64,
    found: wp.array(dtype=wp.int32),
    min_found: int,
    chunk: int,
    pair_alive: wp.array(dtype=wp.bool),
    pair_slot: wp.array(dtype=wp.int32),
    pair_inverse_rest_length: wp.array(dtype=float),
    measured_count: wp.array(dtype=wp.int32),
):
    """Once a cut point is put (``found[0] >= min_found``), every pair whose segment
    ``midpoint +- half`` (rest, m, float64) passes closer than ``radius`` (m) to ``point[0]``
    leaves the graph (thesis 7.5.3): ``pair_alive[p]`` becomes False, a packed one is taken
    out (:func:`take_out`) and ``measured_count[0]`` drops by one per pair taken out. All
    pairs are tested, in the graph or not: a feature tracked again must not bring back a pair
    through the cut. A pair whose midpoint is farther than ``radius`` plus its half length is
    rejected by one distance, without the projection."""
    if found[0] < min_found:
        return
    first, last = thread_range(wp.tid(), chunk, pair_midpoint.shape[0])
    c = point[0]
    dropped = int(0)
    for p in range(first, last):
        offset = c - pair_midpoint[p]
        half = pair_half[p]
        half_length2 = wp.dot(half, half)
        reach = radius + wp.sqrt(half_length2)
        if wp.dot(offset, offset) < reach * reach:
            u = wp.clamp(wp.dot(offset, half) / wp.max(half_length2, wp.float64(1.0e-300)),
                         wp.float64(-1.0), wp.float64(1.0))
            if wp.length(offset - u * half) < radius:
                pair_alive[p] = False
                dropped += take_out(p, pair_slot, pair_inverse_rest_length)
    if dropped > 0:
        wp.atomic_sub(measured_count, 0, dropped)
