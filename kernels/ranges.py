"""Contiguous ranges of items per thread, for kernels where one CPU thread loops over many.

Warp's CPU backend runs a launch's threads one after another, so a kernel that gives each
thread a run of consecutive items can keep a running sum in a register and add it once
(``wcut.kernels.cg``, ``wcut.kernels.cut_detection``); on CUDA the same kernels run with a
run of one item per thread.
"""

import warp as wp


@wp.func
def thread_range(thread: int, size: int, count: int):
    """The items ``[lo, hi)`` of ``thread``: ``size`` consecutive ones of ``count`` (fewer in
    the last thread's run, none past the end)."""
    lo = thread * size
    return lo, wp.min(lo + size, count)
