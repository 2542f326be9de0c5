"""Topology manager: a tetrahedral mesh with local adjacency and local operators (thesis 4.3, 5.1).

- :class:`TetTopology` stores the mesh and keeps vertex/face adjacency up to date locally.
- ``operators``: split 1-4, split of a face (1-3 on the boundary), flip 2-3, general flip
  (edge removal), edge bisection, edge contraction, vertex move (snapping), unsew, vertex
  duplication.
- :class:`TopologyChange`: how the mesh after a change derives from the mesh before.
- ``check``: the invariants, verified from scratch.
- ``arrays``: :class:`~wcut.topology.arrays.TetArrays`, the mesh as flat arrays with face
  neighbours, edited by the compiled operators (``wcut.kernels.topology``: 1-4 split, face
  split, 2-3 flip, general flip, bisection; unsewing and vertex duplication), one launch
  per batch.
- ``region``: :class:`~wcut.topology.region.TetRegion`, the elements a cut touches copied into
  ``TetArrays`` and written back: the cutter's compiled insertion and disconnection.
- ``improve``: local mesh improvement after a change (flips, smoothing and contractions that
  keep the boundary, the cut surface and the volume).
- ``shell``: the operators of quadratic shells that fracture uses (open edges, move nodes,
  split a triangle into four) and their check (thesis 6.2).
"""

from .change import TopologyChange
from .check import check_closed, check_topology, connected_components
from .mesh import TetTopology, TopologyError, face_key
from .operators import (bisect_edge, contract_edge, duplicate_vertex, flip23, move_vertex, remove_edge,
                        sew_unopened, split_face, split_tet, tet_qualities, tet_quality, unsew_face, vertex_fans)

__all__ = [
    "TetTopology", "TopologyError", "TopologyChange", "face_key",
    "check_topology", "check_closed", "connected_components",
    "split_tet", "split_face", "flip23", "remove_edge", "contract_edge", "bisect_edge", "move_vertex",
    "unsew_face", "duplicate_vertex", "vertex_fans", "sew_unopened", "tet_qualities", "tet_quality",
]
