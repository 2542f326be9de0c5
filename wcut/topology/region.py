"""A part of a :class:`~wcut.topology.mesh.TetTopology` copied into flat arrays, edited there by
the compiled operators and written back in one replacement.

The cutter's insertion (thesis 5.1.1-5.1.2) only touches the elements the surface crosses:
each face or edge it names belongs to a crossed element, and every element around a crossed
edge is crossed; its disconnection (5.1.3) only the elements around the vertices on the cut.
So those elements alone go into a :class:`TetArrays` (a few hundred rows, whatever the size
of the mesh), the operators run there, and the result replaces them in the topology: the
cost follows the cut, not the mesh (issue 3's 20k and 100k-element cut events).

In the arrays a face to an element outside the region has neighbour :data:`OUTSIDE`: the
operators treat it as neither boundary nor theirs to change (an operator that would need
the element across refuses). Vertices are renumbered in increasing order, so that the
operators' choices that follow vertex order (a flip's face order, the start of an edge's
polygon) are those they make on the whole mesh; new vertices follow in order of creation,
as they do in the topology.
"""

from __future__ import annotations

import numpy as np

from .arrays import TetArrays, face_neighbors
from .mesh import POSITION, REST, VELOCITY, TetTopology

#: neighbour of a face whose element across is outside the region (``kernels.topology``)
OUTSIDE = -2
#: the corners of an element's face k: those other than corner k
_OTHER_CORNERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


class TetRegion:
    """Elements ``slots`` of ``topo`` as :class:`TetArrays` (``arrays``).

    Args:
        topo: the mesh (not changed until :meth:`write_back`).
        slots: live element slots of the region.
        spare: room for this many more elements and vertices before the arrays grow.
    """

    def __init__(self, topo: TetTopology, slots, spare: int = 1024):
        self.topo = topo
        self.slots = np.unique(np.asarray(slots, dtype=np.int64))
        tets = topo.tets[self.slots]
        self.vertices = np.unique(tets)
        self.tets = np.searchsorted(self.vertices, tets).astype(np.int32)
        neighbors = face_neighbors(self.tets)
        rows, ks = np.nonzero(neighbors < 0)  # the region's own boundary: the mesh's, or an element outside
        faces = np.sort(tets[rows[:, None], _OTHER_CORNERS[ks]], axis=1).tolist()
        stars, unsewn = topo.vertex_tets, topo.unsewn
        shared = np.array([len(stars[a] & stars[b] & stars[c]) == 2 and (a, b, c) not in unsewn for a, b, c in faces],
                          dtype=bool)
        neighbors[rows[shared], ks[shared]] = OUTSIDE
        data = topo.vertex_data[self.vertices]
        self.arrays = TetArrays.from_arrays(self.tets, neighbors, self.slots, data[:, REST], data[:, POSITION],
                                            data[:, VELOCITY], spare=spare)
        self._local = {v: i for i, v in enumerate(self.vertices.tolist())}
        self._local_slot = {t: i for i, t in enumerate(self.slots.tolist())}

    def local_vertex(self, v: int) -> int:
        """The arrays' index of vertex v of the topology."""
        return self._local[v]

    def local_slot(self, t: int) -> int:
        """The arrays' slot of element slot t of the topology."""
        return self._local_slot[t]

    def write_back(self) -> np.ndarray:
        """Replace, in the topology, the region's elements the operators changed by what they
        made (new vertices with their parents, weights and attributes as computed by the
        operators, new elements with their parents: the change record follows). Returns the
        topology's index of each vertex of the arrays."""
        topo, arrays = self.topo, self.arrays
        vertex_count, slot_count = arrays.counts.numpy().tolist()
        first_vertex, region_count = len(self.vertices), len(self.slots)
        tets = arrays.tet_indices.numpy()[:slot_count]
        alive = arrays.tet_alive.numpy()[:slot_count] != 0
        changed = ~alive[:region_count] | np.any(tets[:region_count] != self.tets, axis=1)
        added = np.flatnonzero(alive & np.concatenate([changed, np.ones(slot_count - region_count, dtype=bool)]))
        global_of = np.concatenate([self.vertices, topo.vertex_count + np.arange(vertex_count - first_vertex)])
        if vertex_count > first_vertex:
            new = slice(first_vertex, vertex_count)
            parents, weights = arrays.vertex_parents.numpy()[new], arrays.vertex_weights.numpy()[new]
            data = np.concatenate([arrays.vertex_rest.numpy()[new], arrays.vertex_q.numpy()[new],
                                   arrays.vertex_qd.numpy()[new]], axis=1)
            parents = np.where(parents >= 0, global_of[np.maximum(parents, 0)], -1)  # -1 after the last parent
            topo.add_vertices(parents, weights, data, arrays.vertex_origin.numpy()[new].tolist())
        if len(added) or changed.any():
            parent = arrays.tet_parent.numpy()[added]
            topo.replace_tets(self.slots[changed].tolist(), global_of[tets[added]].tolist(), parent.tolist(),
                              link_faces=False)  # the cutter's next queries use the vertex stars
        return global_of
