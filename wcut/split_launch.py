"""Element kernels split over CPU threads.

Warp's CPU backend runs a launch's threads one after another on one core, and releases
Python's GIL while the compiled kernel runs. An element kernel over ``count`` elements can
therefore run as several launches, each over a contiguous range of elements, from several
Python threads at once (on the 2-core development machine: the quadratic element kernel 1.75x
faster, its product 1.3x; ``wcut bench``). Element arrays are passed as views of their range
(no copy); a node-to-element scatter (``atomic_add``, a plain add on the CPU) of range
``c >= 1`` goes to its own row of a scratch array, which
:func:`wcut.kernels.partial_sums.add_partials` sums into the real array and clears afterwards.
For a given thread count the result is deterministic (the order of additions is fixed); it
differs from a single launch by float rounding only.

Inside a graph capture (``wp.ScopedCapture``) the ranges run one after another on the calling
thread, so that all of them are recorded, in order: Warp records launches per thread. Kernels
that use tiles must not be split (Warp's CPU tile storage is one pointer per module, shared by
the threads), nor any kernel in Warp's debug mode, which sets that pointer for every kernel.

Only for CPU devices: on CUDA one launch already runs on the whole GPU.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, wait

import numpy as np
import warp as wp

from .kernels import partial_sums

#: at most this many threads for one launch, whatever the host has
MAX_THREADS = 8


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the system tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def element_ranges(count: int, thread_count: int) -> list[tuple[int, int]]:
    """``thread_count`` contiguous ranges ``[lo, hi)`` covering ``0..count``, sizes within one."""
    bounds = np.linspace(0, count, thread_count + 1).round().astype(int)
    return [(int(lo), int(hi)) for lo, hi in zip(bounds[:-1], bounds[1:])]


class ThreadTeam:
    """The threads that run the parts of a split launch: the caller's thread and
    ``size - 1`` workers, which live as long as the team (idle between launches)."""

    def __init__(self, size: int):
        self.size = int(size)
        self._executor = ThreadPoolExecutor(max_workers=self.size - 1, thread_name_prefix="wcut-launch") \
            if self.size > 1 else None
        if self._executor is not None:
            weakref.finalize(self, self._executor.shutdown, wait=False)

    def run(self, parts: Sequence[Callable[[], object]]) -> None:
        """Call every part, the first on this thread and the others on the workers; return
        when all are done, re-raising the first exception one of them raised. It returns only
        once every part has ended, even when interrupted (Ctrl-C): a worker must not go on
        writing into arrays the caller has moved on with."""
        futures = [self._executor.submit(part) for part in parts[1:]] if self._executor else []
        try:
            parts[0]()
        finally:
            _wait_uninterrupted(futures)
        for future in futures:
            if future.exception() is not None:
                raise future.exception()


def _wait_uninterrupted(futures) -> None:
    """Wait for every future; an interrupt while waiting is raised once they are all done."""
    interrupt = None
    while True:
        try:
            wait(futures)
            break
        except KeyboardInterrupt as error:
            interrupt = error
    if interrupt is not None:
        raise interrupt


class SplitLaunch:
    """An element kernel recorded as one launch per element range and run on a
    :class:`ThreadTeam`, followed (unless ``add_partials`` is False) by the sums of the
    scatter outputs.

    Args:
        team: the threads; one range per thread.
        count: number of elements.
        record: ``record(lo, hi, targets)`` returns the recorded launch (``wp.launch(...,
            record_cmd=True)``) of elements ``lo..hi-1``, with its element arrays sliced
            ``[lo:hi]`` and scattering into the nodal arrays ``targets``.
        targets: the nodal arrays the kernel scatters into (``wp.vec3``), in ``record``'s order.
        partials: one scratch array per target, shape ``(team.size - 1, len(target))`` and
            zero; it is zero again once the rows are added (after every :meth:`launch` that
            ends normally, or by the next kernel), so launches that never run at the same time
            may share it (clear it after an interruption).
        skip: optional; when it returns True, :meth:`launch` does nothing (e.g. the kernel
            would return at once for every element), saving the threads' hand-over. It is not
            asked inside a graph capture, where the decision would be frozen into the graph.
        add_partials: add the scratch rows into the targets after the ranges (and clear
            them); False leaves that to the kernel that reads the targets next, which saves
            a pass over the nodes (``wcut.kernels.cg.cg_apply_mass`` does it).
    """

    def __init__(self, team: ThreadTeam, count: int, record: Callable, targets: Sequence[wp.array],
                 partials: Sequence[wp.array], skip: Callable[[], bool] | None = None, add_partials: bool = True):
        if len(partials) != len(targets):
            raise ValueError(f"{len(targets)} targets but {len(partials)} scratch arrays")
        for target, partial in zip(targets, partials):
            if partial.shape != (team.size - 1, target.shape[0]):
                raise ValueError(f"scratch of shape {partial.shape}, expected {(team.size - 1, target.shape[0])}")
        self.team = team
        self._device = targets[0].device
        self._skip = skip
        ranges = element_ranges(count, team.size)
        self._parts = [record(*ranges[0], list(targets)).launch]
        self._parts += [record(lo, hi, [p[c] for p in partials]).launch for c, (lo, hi) in enumerate(ranges[1:])]
        self._sums = [wp.launch(partial_sums.add_partials, t.shape[0], device=t.device, record_cmd=True,
                                inputs=[p], outputs=[t]) for t, p in zip(targets, partials)] \
            if team.size > 1 and add_partials else []

    def launch(self) -> None:
        """Run the element ranges concurrently, then add the scratch rows into the targets."""
        if self._device.is_capturing:
            for part in self._parts:
                part()
        elif self._skip is not None and self._skip():
            return
        else:
            self.team.run(self._parts)
        for s in self._sums:
            s.launch()
