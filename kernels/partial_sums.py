"""Sum of nodal partial sums: the reduction after an element kernel split over CPU threads.

``wcut.split_launch.SplitLaunch`` runs an element kernel as one launch per contiguous range
of elements, concurrently; the first range scatters into the real nodal array and range
``c >= 1`` into row ``c - 1`` of a scratch array, so no two threads add to the same address.
"""

import warp as wp


@wp.func
def take_partials(partials: wp.array2d(dtype=wp.vec3), i: int, value: wp.vec3):
    """``value + sum_c partials[c, i]``, leaving ``partials[:, i] = 0`` (ready for the next launch)."""
    s = value
    for c in range(partials.shape[0]):
        s = s + partials[c, i]
        partials[c, i] = wp.vec3(0.0)
    return s


@wp.kernel
def add_partials(partials: wp.array2d(dtype=wp.vec3), total: wp.array(dtype=wp.vec3)):
    """``total[i] += sum_c partials[c, i]``, then ``partials[:, i] = 0``."""
    i = wp.tid()
    total[i] = take_partials(partials, i, total[i])
