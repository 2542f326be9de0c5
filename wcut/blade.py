"""A blade that a user moves frame by frame through a simulated body (thesis 5.1.1, 5.3).

The blade is a straight segment in the world. What it cuts between two frames is what it met
on the way, which a moving body keeps changing. Each frame, points along the blade are mapped
from the current configuration to the rest configuration
(:meth:`~wcut.topology.TetTopology.rest_points`, thesis 3.2), and the cut is the strip between
the blade mapped last frame and the blade mapped now: consecutive strips share their edges in
the material, so the wound has no gaps however the body moves. The cuts are progressive
(:meth:`wcut.cut.Cutter.cut`): an element opens once the blade has passed through it.

Typical use, in one's own loop (see :func:`wcut.apply_change` for the rest)::

    blade = wcut.Blade(mesh)
    for frame in range(frames):
        solver.step(state, next_state, control, dt)
        state, next_state = next_state, state
        change = blade.cut(state, tip_start, tip_end)  # where the blade is now (m)
        if change is not None:
            model, solver, (state, next_state), control = wcut.apply_change(
                blade.mesh(), change, model, solver, (state, next_state), control)
"""

from __future__ import annotations

import numpy as np

from .cut import CutError, Cutter
from .cut.quadratic import QuadraticCutter
from .cut.surface import strip
from .topology import TetTopology

#: Most samples along the blade (its mapping to the rest configuration costs one point
#: location each).
MAX_SAMPLES = 65


class Blade:
    """A straight blade cutting a body progressively (see the module docstring).

    Args:
        mesh: the body's rest mesh, a :class:`~wcut.mesh.TetMesh` or a
            :class:`~wcut.quadratic.QuadraticTetMesh` (its corners are cut, its edge nodes
            placed after, thesis 6.1); the blade keeps its own copy of the topology.
        method, epsilon, improve: the cutter's (:class:`wcut.cut.Cutter`,
            :class:`wcut.cut.quadratic.QuadraticCutter`); ``improve`` (local mesh improvement
            after each increment) is on by default, but for curved quadratic elements, which
            refuse it.
        samples: points along the blade mapped to the rest configuration each frame; by
            default one every half mean edge length of the blade's first position (at least 3,
            at most :data:`MAX_SAMPLES`), so the mapped blade follows the body's bending.

    Attributes:
        refused: increments the quadratic cutter refused (an element would fold); what they
            swept is cut with the next increment.
        last_increment: the surface (rest configuration) swept in the last :meth:`cut`, or None.
    """

    def __init__(self, mesh, *, method: str = "paulus", epsilon: float = 0.1, improve: bool | None = None,
                 samples: int | None = None):
        if getattr(mesh, "order", 1) == 2:
            self.quadratic, self._linear = QuadraticCutter(mesh, method=method, epsilon=epsilon, improve=improve), None
        else:
            self.quadratic, self._linear = None, Cutter(TetTopology(mesh), method=method, epsilon=epsilon,
                                                        improve=improve is None or bool(improve))
        if samples is not None and not (isinstance(samples, (int, np.integer)) and samples >= 2):
            raise CutError(f"Blade: samples must be an integer of at least 2, got {samples!r}")
        self.samples = None if samples is None else int(samples)
        self.refused = 0
        self.last_increment = None
        self._mapped = None  # the blade of the last frame, in the rest configuration

    @property
    def cutter(self) -> Cutter:
        """The corner mesh's :class:`~wcut.cut.Cutter`."""
        return self.quadratic.cutter if self.quadratic is not None else self._linear

    @property
    def topology(self) -> TetTopology:
        """The corner mesh being cut."""
        return self.cutter.topology

    def mesh(self):
        """The mesh after the last cut (what :func:`wcut.apply_change` takes)."""
        return self.quadratic.mesh if self.quadratic is not None else self.topology.to_mesh()

    def lift(self) -> None:
        """Take the blade out of the body: the next :meth:`cut` starts a new stroke."""
        self._mapped = None

    def cut(self, state, start, end):
        """Move the blade to the segment ``start``-``end`` (m, world, the current
        configuration of ``state``, a :class:`~wcut.model.State` of the body's model) and cut
        what it swept since the last call. Returns the
        :class:`~wcut.topology.TopologyChange`, or None when nothing changed (the first call
        of a stroke only places the blade)."""
        a, b = _point(start, "start"), _point(end, "end")
        self._sync(state)
        if self._mapped is not None:
            count = len(self._mapped)  # a strip joins polylines of equal length
        else:
            count = self.samples or sample_count(np.linalg.norm(b - a), self.cutter.mean_edge_length)
        s = np.linspace(0.0, 1.0, count)[:, None]
        before, self._mapped = self._mapped, self.topology.rest_points((1.0 - s) * a + s * b)
        self.last_increment = None
        if before is None:
            return None
        increment = strip(before, self._mapped)
        if increment is None:
            return None
        self.last_increment = increment
        if self.quadratic is None:
            change = self.cutter.cut(increment, progressive=True, rest=True).change
        else:
            try:
                change = self.quadratic.cut(increment, progressive=True, rest=True).change
            except CutError:
                self.refused += 1
                return None
        return None if change.is_empty else change

    def _sync(self, state) -> None:
        """The topology's current positions and velocities from ``state``."""
        q, qd = state.particle_q.numpy(), state.particle_qd.numpy()
        if self.quadratic is not None:
            self.quadratic.set_state(q, qd)
            return
        n = self.topology.vertex_count
        if len(q) < n:
            raise CutError(f"Blade.cut: the state has {len(q)} particles, the body {n}: a state of the model "
                           "after the last change (wcut.apply_change) is needed")
        self.topology.positions[:] = q[:n]
        self.topology.velocities[:] = qd[:n]


def sample_count(length: float, mean_edge_length: float) -> int:
    """Samples along a blade of ``length`` (m): one every half mean edge length, both ends
    included, 3 to :data:`MAX_SAMPLES`."""
    return int(np.clip(np.ceil(2.0 * length / mean_edge_length), 2, MAX_SAMPLES - 1)) + 1


def _point(p, name: str) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise CutError(f"Blade.cut: {name} must be three finite coordinates (m), got {p.tolist()}")
    return p
