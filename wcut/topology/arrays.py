"""A tetrahedral mesh in flat arrays with face neighbours, edited by compiled operators.

:class:`TetArrays` is the array form of :class:`~wcut.topology.mesh.TetTopology` that the
compiled operators of ``wcut.kernels.topology`` edit: a batch of operators is one Warp
launch, run in order by one thread, where ``TetTopology`` pays some 70 us of Python per
operator (see that module). It holds the 1-4 split and the 2-3 flip so far; the cutter still
runs on ``TetTopology``.

Element slots only grow during a change (a split keeps its element's slot for one child, a
flip its two, new ones are appended), so a slot's index is stable while it lives and the cost
of a batch follows the elements it touches; :meth:`to_mesh` drops the dead slots.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import WcutError
from ..mesh import DEGENERATE_TOL, TetMesh, tet_volumes
from .mesh import TopologyError

#: why an operator was refused, by status code (``wcut.kernels.topology``)
REFUSALS = {1: "a new element would be inverted or flat", 2: "no room left in the arrays",
            3: "not an operator's input (a dead element, a boundary face, bad weights)",
            4: "the new edge does not cross the face", 5: "its worst element would be too poor"}
_FULL = 2


def face_neighbors(tets: np.ndarray) -> np.ndarray:
    """(M, 4) int32: for each element the element across its face opposite corner k, -1 on
    the boundary, from scratch (sorting the faces). Raises :class:`TopologyError` when a face
    is in more than two elements."""
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    m = len(tets)
    neighbors = np.full(4 * m, -1, dtype=np.int32)
    if not m:
        return neighbors.reshape(0, 4)
    faces = np.sort(np.stack([np.delete(tets, k, axis=1) for k in range(4)], axis=1), axis=2).reshape(-1, 3)
    order = np.lexsort(faces.T[::-1])
    sorted_faces = faces[order]
    same = np.all(sorted_faces[1:] == sorted_faces[:-1], axis=1)
    if np.any(same[1:] & same[:-1]):
        i = int(np.flatnonzero(same[1:] & same[:-1])[0])
        raise TopologyError(f"face {sorted_faces[i].tolist()} is in more than two elements")
    pairs = np.flatnonzero(same)
    neighbors[order[pairs]] = order[pairs + 1] // 4
    neighbors[order[pairs + 1]] = order[pairs] // 4
    return neighbors.reshape(m, 4)


class TetArrays:
    """A tetrahedral mesh as flat Warp arrays with face neighbours (see ``wcut.kernels.topology``
    for the layout), edited in batches by compiled operators.

    Args:
        mesh: the rest configuration.
        positions: (N, 3) current positions (m); the rest positions when omitted.
        velocities: (N, 3) velocities (m/s); zero when omitted.
        spare: room for this many more elements (and vertices) before the arrays grow.
        device: Warp device (the operators run on one thread of it).

    ``tet_parent[t]`` is the element of ``mesh`` that element slot t lies in, and
    ``vertex_parents[v]`` / ``vertex_weights[v]`` say which four vertices new vertex v is
    the barycentric combination of (-1 for the vertices of ``mesh``).
    """

    def __init__(self, mesh: TetMesh, positions=None, velocities=None, *, spare: int = 1024, device=None):
        self.device = wp.get_device(device)
        n, m = mesh.vertex_count, mesh.tet_count
        rest = np.asarray(mesh.vertices, dtype=np.float64)
        q = rest if positions is None else np.asarray(positions, dtype=np.float64).reshape(n, 3)
        qd = np.zeros((n, 3)) if velocities is None else np.asarray(velocities, dtype=np.float64).reshape(n, 3)
        host = {
            "tet_indices": np.asarray(mesh.tets, dtype=np.int32), "tet_neighbors": face_neighbors(mesh.tets),
            "tet_alive": np.ones(m, dtype=np.int32), "tet_parent": np.arange(m, dtype=np.int32),
            "vertex_rest": rest, "vertex_q": q, "vertex_qd": qd,
            "vertex_parents": np.full((n, 4), -1, dtype=np.int32), "vertex_weights": np.zeros((n, 4)),
        }
        self.counts = wp.array([n, m], dtype=wp.int32, device=self.device)
        self._allocate(host, n + spare, m + spare)

    _TYPES = {"tet_indices": wp.vec4i, "tet_neighbors": wp.vec4i, "tet_alive": wp.int32, "tet_parent": wp.int32,
              "vertex_rest": wp.vec3d, "vertex_q": wp.vec3d, "vertex_qd": wp.vec3d, "vertex_parents": wp.vec4i,
              "vertex_weights": wp.vec4d}
    _FILL = {"tet_neighbors": -1, "vertex_parents": -1}

    def _allocate(self, host: dict, vertex_capacity: int, tet_capacity: int) -> None:
        """(Re)create the arrays with these capacities, filled with ``host`` (name: numpy data)."""
        for name, dtype in self._TYPES.items():
            data = host[name]
            capacity = vertex_capacity if name.startswith("vertex") else tet_capacity
            full = np.full((capacity,) + data.shape[1:], self._FILL.get(name, 0), dtype=data.dtype)
            full[: len(data)] = data
            setattr(self, name, wp.array(full, dtype=dtype, device=self.device))

    def _grow(self) -> None:
        """Double both capacities, keeping the content."""
        vertex_count, slot_count = self.vertex_count, self.slot_count
        host = {name: getattr(self, name).numpy()[: vertex_count if name.startswith("vertex") else slot_count]
                for name in self._TYPES}
        self._allocate(host, 2 * len(self.vertex_rest), 2 * len(self.tet_indices))

    # ----------------------------------------------------------------- queries
    @property
    def vertex_count(self) -> int:
        return int(self.counts.numpy()[0])

    @property
    def slot_count(self) -> int:
        """Element slots in use, live or dead."""
        return int(self.counts.numpy()[1])

    def live_tets(self) -> np.ndarray:
        """Slots of the live elements, ascending (the order of :meth:`to_mesh`)."""
        return np.flatnonzero(self.tet_alive.numpy()[: self.slot_count])

    def to_mesh(self, name: str = "mesh") -> TetMesh:
        """The live elements as a :class:`TetMesh` (elements in slot order), not re-validated."""
        live = self.live_tets()
        rest = self.vertex_rest.numpy()[: self.vertex_count]
        return TetMesh.trusted(rest.copy(), self.tet_indices.numpy()[live].astype(np.int64), name=name)

    def check(self, volume: float | None = None, volume_tolerance: float = 1e-9) -> None:
        """Raise :class:`TopologyError` unless every live element is well shaped and positively
        oriented, the neighbours equal those computed from scratch (which also checks that no
        face is in more than two elements and that neighbours are mutual), and, when
        ``volume`` is given, the total rest volume equals it (relative ``volume_tolerance``)."""
        from .operators import tet_qualities

        live = self.live_tets()
        tets = self.tet_indices.numpy()[live]
        rest = self.vertex_rest.numpy()[: self.vertex_count]
        q = tet_qualities(rest[tets])
        if len(q) and not q.min() > DEGENERATE_TOL:
            raise TopologyError(f"element {int(live[np.argmin(q)])} has quality {q.min():.2e}")
        expected = face_neighbors(tets)
        expected = np.where(expected >= 0, live[np.maximum(expected, 0)], -1)  # back to slot numbers
        actual = self.tet_neighbors.numpy()[live]
        if not np.array_equal(actual, expected):
            t = int(live[np.flatnonzero(np.any(actual != expected, axis=1))[0]])
            raise TopologyError(f"element {t}: neighbours {self.tet_neighbors.numpy()[t].tolist()}, "
                                f"from scratch {expected[np.searchsorted(live, t)].tolist()}")
        if volume is not None:
            total = float(tet_volumes(rest, tets).sum())
            if abs(total - volume) > volume_tolerance * abs(volume):
                raise TopologyError(f"rest volume {total!r}, expected {volume!r}")

    # --------------------------------------------------------------- operators
    def split_tets(self, slots, weights) -> list[str | None]:
        """1-4 splits of elements ``slots`` (K,) at barycentric ``weights`` (K, 4), in order
        (a later one may split a child of an earlier one). Returns per split None when done,
        else why it was refused (the mesh is then as before that split)."""
        from ..kernels import topology as k

        slots = np.asarray(slots, dtype=np.int32).reshape(-1)
        weights = np.asarray(weights, dtype=np.float64).reshape(-1, 4)
        if len(weights) != len(slots):
            raise WcutError(f"split_tets: {len(slots)} elements and {len(weights)} weights")

        def launch(first: int, status: wp.array) -> None:
            wp.launch(k.split_tets, 1, device=self.device,
                      inputs=[wp.array(slots[first:], dtype=wp.int32, device=self.device),
                              wp.array(weights[first:], dtype=wp.vec4d, device=self.device),
                              wp.float64(DEGENERATE_TOL), self.tet_indices, self.tet_neighbors, self.tet_alive,
                              self.tet_parent, self.vertex_rest, self.vertex_q, self.vertex_qd, self.vertex_parents,
                              self.vertex_weights, self.counts], outputs=[status])

        return self._run(len(slots), launch)

    def flip_faces(self, faces, quality_drop: float = 0.0) -> list[str | None]:
        """2-3 flips of the faces ``(element, corner opposite the face)`` (K, 2), in order; with
        ``quality_drop`` > 0 a flip whose worst element's quality falls below that fraction of
        the worse of the two it replaces is refused. Returns as :meth:`split_tets`."""
        from ..kernels import topology as k

        faces = np.asarray(faces, dtype=np.int32).reshape(-1, 2)

        def launch(first: int, status: wp.array) -> None:
            wp.launch(k.flip_faces, 1, device=self.device,
                      inputs=[wp.array(faces[first:], dtype=wp.vec2i, device=self.device), wp.float64(DEGENERATE_TOL),
                              wp.float64(quality_drop), self.tet_indices, self.tet_neighbors, self.tet_alive,
                              self.tet_parent, self.vertex_rest, self.counts], outputs=[status])

        return self._run(len(faces), launch)

    def _run(self, count: int, launch) -> list[str | None]:
        """Launch a batch of ``count`` operators from the first not yet done, growing the
        arrays whenever the batch ran out of room; the reasons of the refusals."""
        codes = np.zeros(count, dtype=np.int32)
        first = 0
        while first < count:
            status = wp.zeros(count - first, dtype=wp.int32, device=self.device)
            launch(first, status)
            codes[first:] = status.numpy()
            full = np.flatnonzero(codes[first:] == _FULL)
            if not len(full):
                break
            first += int(full[0])
            self._grow()
        return [None if c == 0 else REFUSALS[int(c)] for c in codes.tolist()]
