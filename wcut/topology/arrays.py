"""A tetrahedral mesh in flat arrays with face neighbours, edited by compiled operators.

:class:`TetArrays` is the array form of :class:`~wcut.topology.mesh.TetTopology` that the
compiled operators of ``wcut.kernels.topology`` edit: a batch of operators is one Warp
launch, run in order by one thread, where ``TetTopology`` pays some 70 us of Python per
operator (see that module). It holds the 1-4 split, the face split (1-3, 2-6), the 2-3 flip,
the general flip, the bisection, and the disconnection (unsewing faces and duplicating their
vertices once per fan); the cutter runs them on the elements a cut touches
(``wcut.topology.region``).

Element slots only grow during a change (an operator's new elements take the slots of the
elements they replace, then new ones are appended), so a slot's index is stable while it lives and the cost
of a batch follows the elements it touches; :meth:`to_mesh` drops the dead slots.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import WcutError
from ..kernels import topology as kernels
from ..mesh import DEGENERATE_TOL, TetMesh, tet_volumes
from .mesh import TopologyError

#: why an operator was refused, by status code
REFUSALS = {
    kernels.REFUSED_SHAPE: "a new element would be inverted or flat",
    kernels.REFUSED_FULL: "no room left in the arrays",
    kernels.REFUSED_INPUT: "not an operator's input (a dead element, a boundary face, bad weights)",
    kernels.REFUSED_CROSSING: "the new edge does not cross the face",
    kernels.REFUSED_QUALITY_DROP: "its worst element would be too poor",
    kernels.REFUSED_VOLUME: "it would change the volume (the edge's boundary faces are not coplanar)",
    kernels.REFUSED_MISSING: "no such face or edge (or too many elements around it)",
    kernels.NO_POINT: "no split point",
}

#: operator names of :meth:`TetArrays.run`, and their kind
OPERATORS = {
    "split_tet": kernels.SPLIT_TET, "flip_face": kernels.FLIP_FACE, "split_face": kernels.SPLIT_FACE,
    "remove_edge": kernels.REMOVE_EDGE, "bisect_edge": kernels.BISECT_EDGE,
    "flip_or_split_face": kernels.FLIP_OR_SPLIT_FACE, "remove_or_bisect_edge": kernels.REMOVE_OR_BISECT_EDGE,
}


def face_neighbors(tets: np.ndarray) -> np.ndarray:
    """(M, 4) int32: for each element the element across its face opposite corner k, -1 on
    the boundary, from scratch (sorting the faces). Raises :class:`TopologyError` when a face
    is in more than two elements."""
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    m = len(tets)
    neighbors = np.full(4 * m, -1, dtype=np.int32)
    if not m:
        return neighbors.reshape(0, 4)
    codes = _face_codes(tets).reshape(-1)
    order = np.argsort(codes)
    sorted_codes = codes[order]
    same = sorted_codes[1:] == sorted_codes[:-1]
    if np.any(same[1:] & same[:-1]):
        i = int(order[np.flatnonzero(same[1:] & same[:-1])[0]])
        face = np.delete(tets[i // 4], i % 4)
        raise TopologyError(f"face {sorted(face.tolist())} is in more than two elements")
    pairs = np.flatnonzero(same)
    neighbors[order[pairs]] = order[pairs + 1] // 4
    neighbors[order[pairs + 1]] = order[pairs] // 4
    return neighbors.reshape(m, 4)


def _face_codes(tets: np.ndarray) -> np.ndarray:
    """(M, 4) int64: one number per face opposite corner k, equal for equal faces (its sorted
    vertices in base ``max + 1``): one sort key instead of three columns (a lexsort)."""
    base = int(tets.max()) + 1
    codes = np.empty(tets.shape, dtype=np.int64)
    if base > 2**21:  # the code would overflow: rank the sorted triples instead
        faces = np.sort(np.stack([np.delete(tets, k, axis=1) for k in range(4)], axis=1), axis=2).reshape(-1, 3)
        _, rank = np.unique(faces, axis=0, return_inverse=True)
        return rank.reshape(tets.shape)
    for k in range(4):
        x, y, z = (tets[:, i] for i in range(4) if i != k)
        low, high = np.minimum(np.minimum(x, y), z), np.maximum(np.maximum(x, y), z)
        codes[:, k] = (low * base + (x + y + z - low - high)) * base + high
    return codes


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
        n = mesh.vertex_count
        rest = np.asarray(mesh.vertices, dtype=np.float64)
        q = rest if positions is None else np.asarray(positions, dtype=np.float64).reshape(n, 3)
        qd = np.zeros((n, 3)) if velocities is None else np.asarray(velocities, dtype=np.float64).reshape(n, 3)
        self._setup(mesh.tets, face_neighbors(mesh.tets), np.arange(mesh.tet_count), rest, q, qd, spare, device)

    @classmethod
    def from_arrays(cls, tets, neighbors, parents, rest, q, qd, *, spare: int = 1024, device=None) -> "TetArrays":
        """Arrays of elements ``tets`` (M, 4) with face ``neighbors`` (M, 4), ``parents`` (M,)
        and vertex rest positions, positions and velocities (N, 3), taken as they are."""
        arrays = cls.__new__(cls)
        arrays._setup(tets, neighbors, parents, rest, q, qd, spare, device)
        return arrays

    def _setup(self, tets, neighbors, parents, rest, q, qd, spare: int, device) -> None:
        self.device = wp.get_device(device)
        n, m = len(rest), len(tets)
        host = {
            "tet_indices": np.asarray(tets, dtype=np.int32), "tet_neighbors": np.asarray(neighbors, dtype=np.int32),
            "tet_alive": np.ones(m, dtype=np.int32), "tet_parent": np.asarray(parents, dtype=np.int32),
            "vertex_rest": np.asarray(rest, dtype=np.float64), "vertex_q": np.asarray(q, dtype=np.float64),
            "vertex_qd": np.asarray(qd, dtype=np.float64),
            "vertex_parents": np.full((n, 4), -1, dtype=np.int32), "vertex_weights": np.zeros((n, 4)),
            "vertex_tet": np.full(n, -1, dtype=np.int32), "vertex_origin": np.full(n, -1, dtype=np.int32),
        }
        host["vertex_tet"][np.asarray(tets).reshape(-1)] = np.repeat(np.arange(m, dtype=np.int32), 4)
        self.counts = self._array(np.array([n, m], dtype=np.int32), wp.int32)
        self._allocate(host, n + spare, m + spare)

    _TYPES = {"tet_indices": wp.vec4i, "tet_neighbors": wp.vec4i, "tet_alive": wp.int32, "tet_parent": wp.int32,
              "vertex_rest": wp.vec3d, "vertex_q": wp.vec3d, "vertex_qd": wp.vec3d, "vertex_parents": wp.vec4i,
              "vertex_weights": wp.vec4d, "vertex_tet": wp.int32, "vertex_origin": wp.int32}
    _FILL = {"tet_neighbors": -1, "vertex_parents": -1, "vertex_tet": -1, "vertex_origin": -1}

    def _allocate(self, host: dict, vertex_capacity: int, tet_capacity: int) -> None:
        """(Re)create the arrays with these capacities, filled with ``host`` (name: numpy data)."""
        for name, dtype in self._TYPES.items():
            data = host[name]
            capacity = vertex_capacity if name.startswith("vertex") else tet_capacity
            full = np.full((capacity,) + data.shape[1:], self._FILL.get(name, 0), dtype=data.dtype)
            full[: len(data)] = data
            setattr(self, name, self._array(full, dtype))
        self._view = None

    def _array(self, host: np.ndarray, dtype):
        """A device array of ``host`` (a private numpy array of the matching scalar type): on the
        CPU it is wrapped, not copied (a launch's inputs are a few hundred rows, where a copy
        costs as much as the kernel)."""
        return wp.array(host, dtype=dtype, device=self.device, copy=not self.device.is_cpu)

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
        face is in more than two elements and that neighbours are mutual), every vertex's
        ``vertex_tet`` is a live element of it, and, when
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
        actual = np.maximum(self.tet_neighbors.numpy()[live], -1)  # a face to outside a region: none here
        if not np.array_equal(actual, expected):
            t = int(live[np.flatnonzero(np.any(actual != expected, axis=1))[0]])
            raise TopologyError(f"element {t}: neighbours {self.tet_neighbors.numpy()[t].tolist()}, "
                                f"from scratch {expected[np.searchsorted(live, t)].tolist()}")
        used = np.unique(tets)
        at = self.vertex_tet.numpy()[used]
        held = (at >= 0) & (at < self.slot_count)
        held[held] = (self.tet_alive.numpy()[at[held]] != 0) & (self.tet_indices.numpy()[at[held]]
                                                                 == used[held, None]).any(axis=1)
        if not held.all():
            v = int(used[np.argmin(held)])
            raise TopologyError(f"vertex {v}: vertex_tet {int(self.vertex_tet.numpy()[v])} is not a live element of it")
        if volume is not None:
            total = float(tet_volumes(rest, tets).sum())
            if abs(total - volume) > volume_tolerance * abs(volume):
                raise TopologyError(f"rest volume {total!r}, expected {volume!r}")

    # --------------------------------------------------------------- operators
    def split_tets(self, slots, weights) -> list[str | None]:
        """1-4 splits of elements ``slots`` (K,) at barycentric ``weights`` (K, 4), in order
        (a later one may split a child of an earlier one). Returns per split None when done,
        else why it was refused (the mesh is then as before that split)."""
        slots = np.asarray(slots, dtype=np.int32).reshape(-1)
        weights = np.asarray(weights, dtype=np.float64).reshape(-1, 4)
        if len(weights) != len(slots):
            raise WcutError(f"split_tets: {len(slots)} elements and {len(weights)} weights")
        return self.run("split_tet", _ints(slots[:, None]), weights)

    def flip_faces(self, faces, quality_drop: float = 0.0) -> list[str | None]:
        """2-3 flips of the faces ``(element, corner opposite the face)`` (K, 2), in order; with
        ``quality_drop`` > 0 a flip whose worst element's quality falls below that fraction of
        the worse of the two it replaces is refused. Returns as :meth:`split_tets`."""
        return self.run("flip_face", _ints(np.asarray(faces).reshape(-1, 2)), quality_drop=quality_drop)

    def split_faces(self, faces, weights) -> list[str | None]:
        """Splits of the faces given by their vertices (K, 3) at barycentric ``weights`` over
        them (K, 3): 1-3 on the boundary, 2-6 inside. Returns as :meth:`split_tets`."""
        faces = np.asarray(faces).reshape(-1, 3)
        weights = np.asarray(weights, dtype=np.float64).reshape(-1, 3)
        if len(weights) != len(faces):
            raise WcutError(f"split_faces: {len(faces)} faces and {len(weights)} weights")
        return self.run("split_face", _ints(faces), np.pad(weights, ((0, 0), (0, 1))))

    def remove_edges(self, edges, volume_tolerance: float = 1e-12) -> list[str | None]:
        """General flips of the edges given by their vertices (K, 2); that of a boundary edge is
        refused when it changes the volume by more than ``volume_tolerance`` (relative).
        Returns as :meth:`split_tets`."""
        return self.run("remove_edge", _ints(np.asarray(edges).reshape(-1, 2)), volume_tolerance=volume_tolerance)

    def bisect_edges(self, edges, s) -> list[str | None]:
        """Bisections of the edges (K, 2) at ``(1 - s) a + s b`` (K,). Returns as :meth:`split_tets`."""
        edges = np.asarray(edges).reshape(-1, 2)
        s = np.asarray(s, dtype=np.float64).reshape(-1)
        if len(s) != len(edges):
            raise WcutError(f"bisect_edges: {len(edges)} edges and {len(s)} parameters")
        return self.run("bisect_edge", _ints(edges), np.pad(s[:, None], ((0, 0), (0, 3))))

    def run(self, kinds, ints: np.ndarray, reals: np.ndarray | None = None, *, quality_drop: float = 0.0,
            volume_tolerance: float = 1e-12, resolve=None, details: bool = False) -> list:
        """Operators ``kinds`` (a name of :data:`OPERATORS`, or one per operator) on ``ints``
        (K, 4) and ``reals`` (K, 4) as ``kernels.topology.run_operators`` reads them, in
        order, in one launch (more when the arrays must grow, or when ``resolve(i)`` must
        give operator i's ``(ints, reals)`` row: a face split point not known before).
        Returns per operator None when done, else why it was refused; with ``details``
        (reason, vertex made or -1, whether the fallback operator ran)."""
        count = len(ints)
        names = [kinds] if isinstance(kinds, str) else kinds
        kinds = np.broadcast_to(np.asarray([OPERATORS[n] for n in names], dtype=np.int32), (count,))
        ints = np.array(ints, dtype=np.int32).reshape(-1, 4)
        reals = np.zeros((count, 4)) if reals is None else np.array(reals, dtype=np.float64).reshape(-1, 4)
        codes = np.zeros(count, dtype=np.int32)
        results = np.full((count, 2), -1, dtype=np.int32)
        first = 0
        while first < count:
            status = wp.zeros(count - first, dtype=wp.int32, device=self.device)
            made = wp.zeros(count - first, dtype=wp.vec2i, device=self.device)
            inputs = [self._array(np.ascontiguousarray(a[first:]), t)
                      for a, t in ((kinds, wp.int32), (ints, wp.vec4i), (reals, wp.vec4d))]
            wp.launch(kernels.run_operators, 1, device=self.device,
                      inputs=[self.view(), *inputs, wp.float64(DEGENERATE_TOL), wp.float64(quality_drop),
                              wp.float64(volume_tolerance)], outputs=[status, made])
            codes[first:] = status.numpy()
            results[first:] = made.numpy()
            stops = np.flatnonzero(np.isin(codes[first:], (kernels.REFUSED_FULL, kernels.NEEDS_POINT)))
            if not len(stops):
                break
            first += int(stops[0])
            if codes[first] == kernels.REFUSED_FULL:
                self._grow()
            else:
                ints[first], reals[first] = resolve(first)
        reasons = [None if c == kernels.DONE else REFUSALS[int(c)] for c in codes.tolist()]
        if not details:
            return reasons
        return [(r, int(v), bool(f == 1)) for r, (v, f) in zip(reasons, results.tolist())]

    def disconnect(self, faces, vertices) -> int:
        """Unsew ``faces`` (K, 2) (element, corner opposite the face; interior faces) and
        duplicate ``vertices`` in order, each into one copy per fan of elements connected
        through faces on it that are not unsewn (thesis 5.1.3 and figure 4.8); an unsewn face
        whose elements still share it afterwards is sewn again, the others become boundary.
        One launch; the same result as ``unsew_face``, ``duplicate_vertex`` (in that order)
        and ``sew_unopened`` on a ``TetTopology`` with the same slots. New vertex ``w`` is a
        copy of ``vertex_parents[w, 0]``. Returns how many copies were made."""
        faces = self._array(np.array(faces, dtype=np.int32).reshape(-1, 2), wp.vec2i)
        vertices = self._array(np.array(vertices, dtype=np.int32).reshape(-1), wp.int32)
        status = wp.zeros(3, dtype=wp.int32, device=self.device)
        first, copies = 0, 0
        while True:
            capacity, rows = len(self.tet_indices), len(vertices)
            scratch = [wp.zeros(capacity, dtype=wp.vec4i, device=self.device),
                       wp.full(capacity, -1, dtype=wp.int32, device=self.device),
                       wp.empty(capacity, dtype=wp.int32, device=self.device),
                       wp.full(len(self.vertex_rest), -1, dtype=wp.int32, device=self.device),
                       wp.zeros(rows + 1, dtype=wp.int32, device=self.device),
                       wp.zeros(rows, dtype=wp.int32, device=self.device),
                       wp.empty(4 * capacity, dtype=wp.int32, device=self.device)]
            wp.launch(kernels.disconnect, 1, inputs=[self.view(), faces, vertices, first, *scratch],
                      outputs=[status], device=self.device)
            code, first, made = status.numpy().tolist()
            copies += made
            if code == kernels.REFUSED_FULL:
                self._grow()
                continue
            if code != kernels.DONE:
                raise TopologyError(f"disconnect: {REFUSALS[code]}")
            return copies

    def view(self):
        """The arrays as the ``kernels.topology.TetMeshArrays`` struct the kernels take."""
        if self._view is None:
            view = kernels.TetMeshArrays()
            for name in self._TYPES:
                setattr(view, name, getattr(self, name))
            view.counts = self.counts
            scratch = {"removed": (wp.int32, kernels.MAX_RING), "added": (wp.vec4i, kernels.MAX_ADDED),
                       "added_parent": (wp.int32, kernels.MAX_ADDED), "outer_face": (wp.vec3i, 4 * kernels.MAX_RING),
                       "outer_tet": (wp.int32, 4 * kernels.MAX_RING), "star": (wp.int32, kernels.MAX_STAR),
                       "polygon": (wp.int32, kernels.POLYGON), "best": (wp.float64, kernels.POLYGON**2),
                       "apex": (wp.int32, kernels.POLYGON**2)}
            for name, (dtype, size) in scratch.items():
                setattr(view, name, wp.zeros(size, dtype=dtype, device=self.device))
            self._view = view
        return self._view


def _ints(columns: np.ndarray) -> np.ndarray:
    """(K, c) integers padded with -1 to the (K, 4) int32 rows of ``run_operators``."""
    columns = np.asarray(columns, dtype=np.int64)
    out = np.full((len(columns), 4), -1, dtype=np.int32)
    out[:, : columns.shape[1]] = columns
    return out
