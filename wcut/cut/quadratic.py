"""Cutting quadratic tetrahedra (thesis 6.1.2): the linear cutter on the corners, and every
new node placed by the isoparametric map of the mesh before the cut.

The thesis keeps the topology of a 10-node mesh as the topology of its corners, with the edge
nodes as attributes of the edges (6.1.1, figure 6.1), and runs the operators of chapter 5 on
it. :class:`QuadraticCutter` does the same: a :class:`~wcut.cut.Cutter` changes the corner
mesh, then the nodes of every new or reshaped element are placed.

The corner mesh lives in a *parameter domain*: straight tetrahedra whose barycentric
coordinates are those of the curved elements. The mesh before a cut maps it onto the object,
element by element, by the 10-node interpolation ``Phi`` (continuous across faces, since
neighbours share their face nodes). A node of the mesh after the cut, at parameter point
``y``, is put at ``Phi(y)``: a new corner at the image of its parameter position, a new edge
node at the image of the midpoint of its straight parameter edge. That is the thesis's
*interpolated barycentre* (figure 6.3), used everywhere, which 6.1.5 recommends over the
straight barycentre it used for interior edges. So:

- the pieces of a split element (1-4, 1-3, bisection, figure 6.5 and 6.6) represent exactly
  the element they come from: same geometry, same displacement field, and their Jacobian is
  the parent's times a positive constant;
- a new node on a cut boundary edge or face lies on the curved edge or face (figures 6.4-6.6);
- the boundary after the cut is the boundary before, face for face, as long as no boundary
  face is replaced by one spanning several curved faces: on a curved boundary the cutter runs
  with ``curved_boundary`` (no boundary flip, no boundary snap, thesis 6.1.4). Then the volume
  (the flux of x / 3 through the boundary) is conserved exactly, up to rounding;
- snapping (the thesis's future work, 6.1.5) moves a corner together with the edge nodes
  around it: they are all placed anew by ``Phi``, rest and current positions alike, so a body
  at rest stays stress-free.

Every value carried over (rest and current positions, velocities) is ``Phi`` of the state
before, which :class:`~wcut.topology.TopologyChange` expresses with the ten shape-function
weights of the element the point lies in; :meth:`wcut.model.Model.rebuild` applies it.

An element spanning several elements of before (a 2-3 or general flip) is only approximately
``Phi``; should one fold (``det J <= 0`` at a Gauss point or node), its new interior edges are
made straight (the thesis's straight barycentre). Should it still fold, a new edge on a curved
boundary would have to be made straight too, which would move the surface and change the
volume (by 7.5e-7 where two planes cross in the organ): instead the cut is made again by splits
only (no flip), whose pieces each lie in one element of before and never fold. On a flat
boundary the other new edges are made straight (they stay in the boundary's plane); the result
counts the straightened edges (``QuadraticCutResult.straightened_edges``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .. import p2
from ..quadratic import QuadraticTetMesh, folded_elements
from ..topology import TetTopology, TopologyChange
from .cutter import METHODS, Cutter, CutError, CutStats
from .surface import CutSurface

#: An edge node within this distance (relative to the mean edge length) of its edge's midpoint
#: is on a straight edge.
STRAIGHT_TOL = 1e-7


@dataclass
class QuadraticCutResult:
    """One cut of a quadratic mesh.

    Attributes:
        mesh: the mesh after the cut (rest configuration).
        change: how its nodes and elements derive from those before (node indices; weights
            are the ten shape functions of the element a new node lies in).
        stats: the corner cutter's counts.
        straightened_edges: new edges made straight because an element folded.
        straightened_boundary_edges: those of them on the boundary (they change the surface).
    """

    mesh: QuadraticTetMesh
    change: TopologyChange
    stats: CutStats
    straightened_edges: int = 0
    straightened_boundary_edges: int = 0


def has_flat_boundary(mesh: QuadraticTetMesh) -> bool:
    """Whether every boundary face of ``mesh`` is a flat triangle: each edge node on the
    boundary is at its edge's midpoint (within :data:`STRAIGHT_TOL`)."""
    faces = mesh.boundary().triangles
    return _at_midpoints(mesh, faces[:, [0, 1, 2]], faces[:, [1, 2, 0]], faces[:, 3:])


def is_straight(mesh: QuadraticTetMesh) -> bool:
    """Whether every element of ``mesh`` is straight: each edge node at its edge's midpoint
    (within :data:`STRAIGHT_TOL`), so that the parametrization of the mesh is the identity."""
    tets = mesh.tets
    return _at_midpoints(mesh, tets[:, p2.EDGES[:, 0]], tets[:, p2.EDGES[:, 1]], tets[:, 4:])


def _at_midpoints(mesh: QuadraticTetMesh, ends_a: np.ndarray, ends_b: np.ndarray, nodes: np.ndarray) -> bool:
    """Whether each node ``nodes[...]`` lies at the midpoint of its edge (``ends_a[...]``,
    ``ends_b[...]``) within :data:`STRAIGHT_TOL` of the mean edge length."""
    x = mesh.vertices
    gap = np.abs(x[nodes] - 0.5 * (x[ends_a] + x[ends_b])).max(initial=0.0)
    return bool(gap <= STRAIGHT_TOL * mesh.mean_edge_length())


class QuadraticCutter:
    """Cuts a :class:`~wcut.quadratic.QuadraticTetMesh`, one event at a time (thesis 6.1.2).

    Args:
        mesh: the mesh to cut (rest configuration, m); :attr:`mesh` is the current one.
        method, epsilon, mean_edge_length: as for :class:`~wcut.cut.Cutter`; all four
            methods work (``bielser`` and ``snap`` too: every new node is placed by ``Phi``).
        positions, velocities: (N, 3) current node positions (m) and velocities (m/s); the
            rest positions and zero by default. A cut intersects the current configuration.

    The corner cutter runs with ``curved_boundary`` unless every boundary face is flat
    (:func:`has_flat_boundary`), where the linear method applies unchanged.

    ``improve``: the corner cutter's local mesh improvement (:class:`~wcut.cut.Cutter`); by
    default on where every element is straight (:func:`is_straight`: its nodes are placed
    exactly, and the volume kept), off on a curved mesh, which refuses it: the improvement's
    elements lie across those of before, and nodes placed on them by a curved
    parametrization would change the volume (by 1e-5 on the curved organ).
    """

    def __init__(self, mesh: QuadraticTetMesh, method: str = "paulus", epsilon: float = 0.1, *,
                 mean_edge_length: float | None = None, positions=None, velocities=None,
                 improve: bool | None = None):
        if method not in METHODS:
            raise CutError(f"unknown cut method {method!r} (expected one of {', '.join(METHODS)})")
        straight = is_straight(mesh)
        if improve and not straight:
            raise CutError("improve needs straight quadratic elements: the improvement's elements lie across "
                           "those of before, and the nodes of curved ones would change the volume; leave it "
                           "out (None or False) for this mesh")
        self.mesh = mesh
        self.positions = mesh.vertices.copy() if positions is None else np.array(positions, dtype=np.float64)
        self.velocities = np.zeros_like(self.positions) if velocities is None else \
            np.array(velocities, dtype=np.float64)
        if self.positions.shape != mesh.vertices.shape or self.velocities.shape != mesh.vertices.shape:
            raise CutError(f"positions and velocities must have shape {mesh.vertices.shape}")
        #: node of each corner-mesh vertex
        self.corner_nodes = mesh.corner_ids.copy()
        linear = mesh.linear()
        self.topology = TetTopology(linear, positions=self.positions[self.corner_nodes],
                                    velocities=self.velocities[self.corner_nodes])
        self.curved_boundary = not has_flat_boundary(mesh)
        self.cutter = _CornerCutter(self, method=method, epsilon=epsilon, mean_edge_length=mean_edge_length,
                                    improve=straight if improve is None else bool(improve))
        self._corner_tets = linear.tets  # elements of :attr:`mesh` by corner-mesh vertex
        self._slot_nodes = mesh.tets  # nodes of the element in each topology slot (-1: none)

    def set_state(self, positions, velocities=None) -> None:
        """Current node positions (N, 3) (m) and velocities (m/s) of :attr:`mesh`, e.g. from a
        simulation's state before the next cut."""
        self.positions[:] = positions
        if velocities is not None:
            self.velocities[:] = velocities
        self.topology.positions[:] = self.positions[self.corner_nodes]
        self.topology.velocities[:] = self.velocities[self.corner_nodes]

    def cut(self, surface: CutSurface, bounds=None, *, progressive: bool = False,
            rest: bool = False) -> QuadraticCutResult:
        """Insert ``surface`` and separate the mesh along it (arguments as
        :meth:`wcut.cut.Cutter.cut`). :attr:`mesh`, :attr:`positions` and
        :attr:`velocities` become those after the cut."""
        before = self.mesh
        parameters = self.topology.rest_positions.copy()
        # a curved element may fold where the corner cutter saw none: then the cut is made
        # again by splits only, or undone
        saved = copy.deepcopy(self.cutter, {id(self): self}) if self.curved_boundary else None
        result, placement = self._corner_cut(surface, bounds, progressive, rest, parameters)
        if placement is None:
            return QuadraticCutResult(before, _identity_change(before), result.stats)
        try:
            straightened, on_boundary = placement.unfold(self.topology)
        except CutError:
            if saved is None:
                raise
            straightened = on_boundary = None
        if saved is not None and (on_boundary is None or on_boundary > 0):
            # straightening a boundary edge moves the surface and changes the volume: the
            # pieces of split elements each lie in one curved element of before, so they
            # never fold (see the module docstring); the cut is made again by splits only
            self.cutter, self.topology = saved, saved.topology
            retry = copy.deepcopy(saved, {id(self): self})
            self.cutter.flips = False
            try:
                result, placement = self._corner_cut(surface, bounds, progressive, rest, parameters)
                if placement is None:
                    return QuadraticCutResult(before, _identity_change(before), result.stats)
                straightened, on_boundary = placement.unfold(self.topology)
            except CutError:
                self.cutter, self.topology = retry, retry.topology
                raise
            finally:
                self.cutter.flips = True
        mesh, change = placement.result(name=before.name)
        self.positions = _apply(change, self.positions)
        self.velocities = _apply(change, self.velocities)
        self.mesh, self.corner_nodes, self._corner_tets = mesh, placement.corner_nodes, placement.corner_tets
        self._slot_nodes = np.full((self.topology.slot_count, 10), -1, dtype=np.int64)
        self._slot_nodes[self.topology.live_tets()] = mesh.tets
        self.topology.positions[:] = self.positions[self.corner_nodes]
        self.topology.velocities[:] = self.velocities[self.corner_nodes]
        return QuadraticCutResult(mesh, change, result.stats, straightened, on_boundary)

    def _corner_cut(self, surface, bounds, progressive: bool, rest: bool, parameters: np.ndarray):
        """The corner cutter's cut and the placement of the nodes after it (None when the cut
        changed nothing)."""
        result = self.cutter.cut(surface, bounds, progressive=progressive, rest=rest)
        if result.change.is_empty:
            return result, None
        return result, _Placement(self.mesh, self._corner_tets, self.corner_nodes, parameters, self.topology,
                                  result.change)

    def snap_keeps_shape(self, v: int, other: int, s: float) -> bool:
        """Whether snapping corner ``v`` to ``(1 - s) v + s other`` (parameter positions)
        leaves every curved element around it unfolded, its corner and the nodes of its
        edges through ``v`` placed by ``Phi`` (the elements around ``v`` are still those of
        :attr:`mesh`: snapping comes first in a cut)."""
        topo = self.topology
        slots = np.array(sorted(topo.vertex_tets[v]), dtype=np.int64)
        if not len(slots) or slots.max() >= len(self._slot_nodes):
            return False
        rows = self._slot_nodes[slots]
        if (rows < 0).any():
            return False
        corners = topo.tets[slots]
        param = topo.rest_positions
        target = (1.0 - s) * param[v] + s * param[other]
        ends = np.where(corners[:, p2.EDGES[:, 0]] == v, corners[:, p2.EDGES[:, 1]], corners[:, p2.EDGES[:, 0]])
        through = (corners[:, p2.EDGES] == v).any(axis=2)  # (k, 6) edges through v
        element, bary = _locate(np.vstack([target, 0.5 * (target + param[ends[through]])]),
                                np.zeros(1 + int(through.sum()), dtype=np.int64), param, corners,
                                np.arange(len(slots)))
        x = self.mesh.vertices
        phi = np.einsum("pk,pkj->pj", p2.shape_functions(bary), x[rows[element]])
        shape = x[rows]
        shape[:, :4][corners == v] = phi[0]
        shape[:, 4:][through] = phi[1:]
        folded, _ = folded_elements(shape.reshape(-1, 3), np.arange(10 * len(slots)).reshape(-1, 10))
        return not folded.any()


class _CornerCutter(Cutter):
    """The corner cutter of a :class:`QuadraticCutter`: a snap must also keep the curved
    elements around the snapped corner unfolded."""

    #: smoothing the corners of the elements a blade is still in made beam_cut_p2 diverge in
    #: the step after (a node at 2e4 m/s) though every element stayed valid at rest: kept here
    smooths_under_blade = False

    def __init__(self, owner: QuadraticCutter, **options):
        # the Python operators: the curved cutter is tested with their choice between equally
        # good triangulations of a general flip
        super().__init__(owner.topology, curved_boundary=owner.curved_boundary, compiled=False, **options)
        self._owner = owner

    def _move_keeps_quality(self, v: int, other: int, s: float) -> bool:
        return super()._move_keeps_quality(v, other, s) and self._owner.snap_keeps_shape(v, other, s)


def _apply(change: TopologyChange, values: np.ndarray) -> np.ndarray:
    """A node attribute (N_A, 3) after ``change``."""
    return np.einsum("vk,vkj->vj", change.vertex_weights, values[change.vertex_sources])


def _identity_change(mesh: QuadraticTetMesh) -> TopologyChange:
    n, m = mesh.vertex_count, mesh.tet_count
    empty = np.zeros(0, dtype=np.int64)
    return TopologyChange(n, n, m, m, np.arange(n)[:, None], np.ones((n, 1)), np.full(n, -1), empty, empty,
                          np.arange(m), np.zeros(m, dtype=bool), empty, empty)


class _Placement:
    """The nodes of the mesh after one cut of the corner mesh (see the module docstring).

    Every node after the cut is either a node of before, kept with its index, or new. A node
    is described by a *row*: node indices of before and weights (the value after is the
    weighted sum of the values before).

    Snapping comes first in a cut and moves corners: the mesh A' after it is A with each
    moved corner and the nodes of the edges through it placed by ``Phi`` of A (their rows,
    :attr:`_reused_rows`; the nodes keep their indices). The other operators split and flip
    the elements of A', so the new nodes are placed by ``Phi`` of A', in the parameter
    positions after snapping, and their rows expanded through those of A'."""

    def __init__(self, before: QuadraticTetMesh, corner_tets_before: np.ndarray, corner_nodes: np.ndarray,
                 parameters: np.ndarray, topo: TetTopology, linear: TopologyChange):
        self.before, self.linear = before, linear
        after_tets = topo.tets[topo.live_tets()]
        self.corner_tets = after_tets
        after = topo.rest_positions  # parameter positions of the corners after the cut
        v_b = linear.vertex_count_after
        sources, weights = linear.vertex_sources, linear.vertex_weights
        single = (weights[:, 0] == 1.0) & (weights[:, 1:] == 0.0).all(axis=1)
        is_new = np.zeros(v_b, dtype=bool)
        is_new[linear.new_vertices] = True
        moved = linear.moved_vertices[linear.moved_vertices < v_b]
        origin = np.where(single, sources[:, 0], -1)  # the vertex of before it stands for
        origin[moved] = moved
        primary = (origin >= 0) & ~is_new  # that vertex itself (possibly renumbered or moved)

        self._rows: list[tuple[np.ndarray, np.ndarray]] = []   # (sources, weights) of each new node
        self._x: list[np.ndarray] = []                         # its rest position (m)
        self._new_parent: list[int] = []
        self._reused_rows, self._reused_x = self._snapped(corner_tets_before, corner_nodes, parameters,
                                                          after, moved)
        snapped_parameters = parameters.copy()
        snapped_parameters[moved] = after[moved]

        parent = linear.element_parent
        added = np.zeros(len(after_tets), dtype=bool)
        added[linear.added_elements] = True
        same = ~added & ~linear.element_rest_changed & primary[after_tets].all(axis=1)
        same &= (origin[after_tets] == corner_tets_before[parent]).all(axis=1)
        self.touched = np.flatnonzero(~same)
        nodes = np.empty((len(after_tets), 10), dtype=np.int64)  # >= 0: node of before; < 0: ~new
        nodes[same] = before.tets[parent[same]]

        # corners: kept (with their index), copies of a kept one, or placed by Phi
        corner_node = np.full(v_b, -(2**62), dtype=np.int64)
        kept = np.flatnonzero(primary)
        corner_node[kept] = corner_nodes[origin[kept]]
        tets_t = after_tets[self.touched]
        used = np.unique(tets_t)
        for v in used[(origin[used] >= 0) & is_new[used]].tolist():
            o = int(corner_nodes[origin[v]])
            corner_node[v] = self._new_node(*self._row(o), -1, self._position(o))
        located_corners = used[origin[used] < 0]

        # edges of the touched elements: edges of before (kept, or copied where a vertex was
        # duplicated), or new ones placed by Phi
        pairs = np.sort(tets_t[:, p2.EDGES], axis=2).reshape(-1, 2)
        n = np.int64(max(v_b, len(parameters)) + 1)
        keys, inverse = np.unique(pairs[:, 0] * n + pairs[:, 1], return_inverse=True)
        edges = np.stack([keys // n, keys % n], axis=1)
        edge_node = np.full(len(edges), -(2**62), dtype=np.int64)
        old_edge = _edge_lookup(corner_tets_before, before.tets, origin[edges], len(parameters))
        found = old_edge >= 0
        both_primary = primary[edges].all(axis=1)
        edge_node[found & both_primary] = old_edge[found & both_primary]
        for e in np.flatnonzero(found & ~both_primary).tolist():
            o = int(old_edge[e])
            edge_node[e] = self._new_node(*self._row(o), -1, self._position(o))
        located_edges = np.flatnonzero(~found)

        # Phi of A' at the new corners and at the midpoints of the new edges, each tried
        # first in the parent of an element after the cut that has it
        points = np.concatenate([after[located_corners],
                                 0.5 * (after[edges[located_edges, 0]] + after[edges[located_edges, 1]])])
        hint_of_vertex = np.empty(v_b, dtype=np.int64)
        hint_of_vertex[tets_t.ravel()] = np.repeat(parent[self.touched], 4)
        hint_of_edge = np.empty(len(edges), dtype=np.int64)
        hint_of_edge[inverse] = np.repeat(parent[self.touched], 6)
        hints = np.concatenate([hint_of_vertex[located_corners], hint_of_edge[located_edges]])
        candidates = np.union1d(linear.removed_elements, parent[linear.element_rest_changed])
        element, bary = _locate(points, hints, snapped_parameters, corner_tets_before, candidates)
        shape = p2.shape_functions(bary)
        prime = before.tets[element]  # nodes of A' (rows in _reused_rows where snapped)
        prime_x = self._position(prime)
        phi = np.einsum("pk,pkj->pj", shape, prime_x)
        for i in range(len(points)):
            sources_i, weights_i = self._expand(prime[i], shape[i])
            node = self._new_node(sources_i, weights_i, element[i], phi[i])
            if i < len(located_corners):
                corner_node[located_corners[i]] = node
            else:
                edge_node[located_edges[i - len(located_corners)]] = node
        self._located_edges = located_edges
        self._edges = edges
        self._edge_node = edge_node

        nodes[self.touched, :4] = corner_node[tets_t]
        nodes[self.touched, 4:] = edge_node[inverse.reshape(-1, 6)]
        self.nodes = nodes
        self.corner_node = corner_node
        self._edge_of = inverse.reshape(-1, 6)  # (touched, 6) index into edges

    def _snapped(self, corner_tets: np.ndarray, corner_nodes: np.ndarray, before: np.ndarray, after: np.ndarray,
                 moved: np.ndarray) -> tuple[dict, dict]:
        """Rows and positions of the nodes snapping moved: each moved corner and the node of
        each edge through one, placed by ``Phi`` of A at their parameter points after the
        snap (``before``/``after``: parameter positions)."""
        if not len(moved):
            return {}, {}
        star = np.flatnonzero(np.isin(corner_tets, moved).any(axis=1))
        corners = corner_tets[star]
        through = np.isin(corners[:, p2.EDGES], moved).any(axis=2)  # (S, 6)
        edge_nodes, first = np.unique(self.before.tets[star, 4:][through], return_index=True)
        ends = corners[:, p2.EDGES][through][first]  # (E, 2)
        position = before.copy()
        position[moved] = after[moved]
        hint_of = np.zeros(len(before), dtype=np.int64)
        hint_of[corners.ravel()] = np.repeat(star, 4)
        hints = np.concatenate([hint_of[moved], star[np.nonzero(through)[0][first]]])
        points = np.concatenate([after[moved], 0.5 * (position[ends[:, 0]] + position[ends[:, 1]])])
        element, bary = _locate(points, hints, before, corner_tets, star)
        shape = p2.shape_functions(bary)
        phi = np.einsum("pk,pkj->pj", shape, self.before.vertices[self.before.tets[element]])
        nodes = np.concatenate([corner_nodes[moved], edge_nodes])
        rows = {int(node): (self.before.tets[e], w) for node, e, w in zip(nodes, element, shape)}
        return rows, {int(node): p for node, p in zip(nodes, phi)}

    def _expand(self, prime_nodes: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The row over nodes of A of ``sum_k shape[k] * node_k`` over nodes of A'."""
        if not any(int(k) in self._reused_rows for k in prime_nodes):
            return prime_nodes, shape
        parts = [self._row(int(k)) for k in prime_nodes]
        sources_all = np.concatenate([s for s, _ in parts])
        weights_all = np.concatenate([w * c for (_, w), c in zip(parts, shape)])
        sources_u, index = np.unique(sources_all, return_inverse=True)
        return sources_u, np.bincount(index, weights=weights_all)

    def _new_node(self, sources: np.ndarray, weights: np.ndarray, parent: int, x: np.ndarray) -> int:
        """Register a new node (its row and rest position, m); returns its provisional
        index (negative)."""
        self._rows.append((np.asarray(sources, dtype=np.int64), np.asarray(weights, dtype=np.float64)))
        self._x.append(x)
        self._new_parent.append(int(parent))
        return -len(self._rows)

    def _row(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        if node < 0:
            return self._rows[-node - 1]
        return self._reused_rows.get(node, (np.array([node]), np.ones(1)))

    def _position(self, rows) -> np.ndarray:
        """Rest positions (..., 3) (m) of provisional nodes ``rows``."""
        rows = np.asarray(rows)
        out = np.empty(rows.shape + (3,))
        kept = rows >= 0
        out[kept] = self.before.vertices[rows[kept]]
        if self._x:
            out[~kept] = np.asarray(self._x)[-rows[~kept] - 1]
        for node, x in self._reused_x.items():
            out[rows == node] = x
        return out

    def unfold(self, topo: TetTopology) -> tuple[int, int]:
        """Straighten new edges of folded elements (see the module docstring). Returns how
        many edges were straightened and how many of them are on the boundary."""
        straightened: set[int] = set()
        boundary_count = 0
        located = set(self._located_edges.tolist())
        for allow_boundary in (False, True):
            for _ in range(8):
                points = self._position(self.nodes[self.touched])
                local = np.arange(10)
                folded, _ = folded_elements(points.reshape(-1, 3), (np.arange(len(points))[:, None] * 10 + local))
                bad = np.flatnonzero(folded)
                if not len(bad):
                    return len(straightened), boundary_count
                candidates = {int(e) for e in self._edge_of[bad].ravel()} & located
                todo = []
                for e in sorted(candidates - straightened):
                    a, b = self._edges[e].tolist()
                    on_boundary = topo.is_boundary_edge(a, b)
                    if on_boundary and not allow_boundary:
                        continue
                    todo.append((e, on_boundary))
                if not todo:
                    break
                for e, on_boundary in todo:
                    self._straighten(e)
                    straightened.add(e)
                    boundary_count += on_boundary
        raise CutError(f"cutting quadratic elements: {len(bad)} element(s) would fold (det J <= 0) even with "
                       f"their new edges straight; the cut is refused: cut with another epsilon, move the "
                       f"surface by a fraction of an edge, or refine the mesh there")

    def _straighten(self, e: int) -> None:
        """Put the node of new edge ``e`` at the midpoint of its corners."""
        a, b = self._edges[e].tolist()
        (sa, wa), (sb, wb) = self._row(int(self.corner_node[a])), self._row(int(self.corner_node[b]))
        node = int(self._edge_node[e])
        self._rows[-node - 1] = (np.concatenate([sa, sb]), np.concatenate([0.5 * wa, 0.5 * wb]))
        ends = self._position(self.corner_node[[a, b]])
        self._x[-node - 1] = 0.5 * (ends[0] + ends[1])

    def result(self, name: str) -> tuple[QuadraticTetMesh, TopologyChange]:
        """The mesh after the cut and the change to it, with final node indices: kept nodes
        keep theirs, new nodes fill the indices freed, then follow."""
        before, linear = self.before, self.linear
        n_a = before.vertex_count
        nodes = self.nodes
        kept = np.unique(nodes[nodes >= 0])
        new_count = len(self._rows)
        count = len(kept) + new_count
        free = np.setdiff1d(np.arange(n_a), kept)
        index = np.full(n_a, -1, dtype=np.int64)
        index[kept] = kept
        if new_count <= len(free):
            new_index = free[:new_count]
            holes = free[new_count:]
            holes = holes[holes < count]
            movers = kept[kept >= count]  # as many as holes below the new count
            index[movers] = holes
        else:
            new_index = np.concatenate([free, np.arange(n_a, n_a + new_count - len(free))])
        final = _final_nodes(nodes, index, new_index)

        width = max([1] + [len(s) for s, _ in self._rows] + [len(s) for s, _ in self._reused_rows.values()])
        sources = np.zeros((count, width), dtype=np.int64)
        weights = np.zeros((count, width))
        sources[index[kept], 0] = kept
        weights[index[kept], 0] = 1.0
        for node, (s, w) in self._reused_rows.items():
            sources[index[node]] = np.concatenate([s, np.full(width - len(s), s[0])])
            weights[index[node]] = np.concatenate([w, np.zeros(width - len(w))])
        for k, (s, w) in enumerate(self._rows):
            sources[new_index[k]] = np.concatenate([s, np.full(width - len(s), s[0])])
            weights[new_index[k]] = np.concatenate([w, np.zeros(width - len(w))])
        parent_element = np.full(count, -1, dtype=np.int64)
        parent_element[new_index] = self._new_parent
        moved = np.sort(index[np.array(sorted(self._reused_rows), dtype=np.int64)])

        vertices = np.einsum("vk,vkj->vj", weights, before.vertices[sources])
        corner_ids = np.sort(final[:, :4].ravel())
        corner_ids = corner_ids[np.r_[True, corner_ids[1:] != corner_ids[:-1]]] if len(corner_ids) else corner_ids
        self.corner_nodes = _final_nodes(self.corner_node, index, new_index)
        mesh = QuadraticTetMesh.trusted(vertices, final, corner_ids, name=name)
        change = TopologyChange(
            vertex_count_before=n_a, vertex_count_after=count,
            element_count_before=linear.element_count_before, element_count_after=linear.element_count_after,
            vertex_sources=sources, vertex_weights=weights, vertex_parent_element=parent_element,
            new_vertices=np.sort(new_index), moved_vertices=moved,
            element_parent=linear.element_parent, element_rest_changed=linear.element_rest_changed,
            removed_elements=linear.removed_elements, added_elements=linear.added_elements)
        return mesh, change


def _final_nodes(provisional: np.ndarray, index: np.ndarray, new_index: np.ndarray) -> np.ndarray:
    """Final node indices from provisional ones (>= 0: kept node of before; < 0: ~new node)."""
    out = np.empty_like(provisional)
    kept = provisional >= 0
    out[kept] = index[provisional[kept]]
    out[~kept] = new_index[-provisional[~kept] - 1]
    return out


def _edge_lookup(corner_tets: np.ndarray, node_tets: np.ndarray, pairs: np.ndarray, vertex_count: int) -> np.ndarray:
    """Edge node (of before) of each corner pair (P, 2) (vertices of before, -1 for none), or
    -1 where the pair is not an edge of before."""
    n = np.int64(vertex_count + 1)
    ends = np.sort(corner_tets[:, p2.EDGES], axis=2).reshape(-1, 2)
    keys = ends[:, 0] * n + ends[:, 1]
    order = np.argsort(keys, kind="stable")
    keys, node = keys[order], node_tets[:, 4:].reshape(-1)[order]
    ok = (pairs >= 0).all(axis=1)
    p = np.sort(np.where(ok[:, None], pairs, 0), axis=1)
    query = p[:, 0] * n + p[:, 1]
    at = np.minimum(np.searchsorted(keys, query), len(keys) - 1)
    return np.where(ok & (keys[at] == query), node[at], -1) if len(keys) else np.full(len(pairs), -1)


def _locate(points: np.ndarray, hints: np.ndarray, corners_x: np.ndarray, tets: np.ndarray,
            candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each point (P, 3) (m), an element of ``tets`` (M, 4) (corner positions
    ``corners_x``) containing it and its barycentric coordinates (P, 4). The element
    ``hints[p]`` is tried first; a point outside it goes to the element of ``candidates``
    (among those whose bounding box holds it) that contains it best (largest smallest
    barycentric coordinate)."""
    element = hints.copy()
    bary = _barycentric(points, corners_x[tets[hints]])
    outside = np.flatnonzero(bary.min(axis=1) < -1e-9)
    if not len(outside):
        return element, bary
    x = corners_x[tets[candidates]]
    slack = 1e-9 * float(np.ptp(x.reshape(-1, 3), axis=0).max())
    lower, upper = x.min(axis=1) - slack, x.max(axis=1) + slack
    q = points[outside]
    inside = np.all((q[:, None] >= lower[None]) & (q[:, None] <= upper[None]), axis=2)
    rows, cols = np.nonzero(inside)
    if len(np.unique(rows)) < len(outside):
        raise CutError("cutting quadratic elements: a new edge node lies outside every element the cut changed "
                       "(the curved boundary bends too much there for these elements); cut with another "
                       "epsilon, move the surface by a fraction of an edge, or refine the mesh there")
    full = _barycentric(q[rows], x[cols])
    score = full.min(axis=1)
    order = np.lexsort((-score, rows))  # per point, best first
    first = order[np.r_[True, rows[order][1:] != rows[order][:-1]]]
    element[outside[rows[first]]] = candidates[cols[first]]
    bary[outside[rows[first]]] = full[first]
    return element, bary


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (P, 4) of points (P, 3) in tetrahedra (P, 4, 3)."""
    edges = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))
    local = np.linalg.solve(edges, (points - corners[:, 0])[:, :, None])[:, :, 0]
    return np.concatenate([1.0 - local.sum(axis=1, keepdims=True), local], axis=1)
