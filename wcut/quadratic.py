"""Quadratic tetrahedral meshes: validation, meshio I/O, conversion from linear meshes with
curved boundaries, and the tessellated surface that shows them smooth (thesis 6.1.1).

A :class:`QuadraticTetMesh` holds rest node positions (m) and 10-node elements in VTK
``tetra10`` order (:mod:`wcut.p2`). Construction validates it, so later stages can rely on:

- its corners form a valid linear mesh (:class:`wcut.mesh.TetMesh`: positively oriented,
  manifold faces);
- one edge node per corner edge, shared by every element around that edge, and no node is
  both a corner and an edge node;
- ``det J > 0`` at every Gauss point and every node of every element (no curved element folds).

:func:`to_quadratic` makes one from a linear mesh as Mezger et al. propose (thesis 6.1.1, figure
6.2): edge nodes at the edge midpoints, those of boundary edges moved onto a smooth surface,
interior ones relaxed by the harmonic extension of that motion, and any element that would
still fold made straighter until none does.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from . import p2
from .errors import MeshError
from .mesh import TET_FACES, TetMesh, _VertexQueries, check_mesh_format, notice_unused_vertices, read_meshio

#: Swapping corners 1 and 2 reorients an element; these are its ten nodes after the swap.
_REORIENT = np.array([0, 2, 1, 3, 6, 5, 4, 7, 9, 8])
#: Edge nodes of the boundary face opposite corner k, for the face TET_FACES[k] = (a, b, c):
#: nodes of edges (a, b), (b, c), (c, a).
_FACE_EDGE_NODES = np.array([[5, 9, 8], [7, 9, 6], [4, 8, 7], [6, 5, 4]])


def folded_elements(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which 10-node elements fold: ``det J`` at a Gauss point or a node is at most 1e-6 of
    the element's volume (a straight element has ``det J = 6 V`` everywhere). Returns the
    mask (M,) and the smallest ``det J`` (M,) (m^3 per unit reference volume)."""
    at_gauss, at_nodes = p2.jacobian_determinants(points, tets)
    worst = np.minimum(at_gauss.min(axis=1), at_nodes.min(axis=1))
    return worst <= 1e-6 * p2.volumes(points, tets), worst


@dataclass(frozen=True)
class QuadraticBoundary:
    """The boundary of a quadratic mesh as 6-node triangles (outward oriented).

    Attributes:
        triangles: (F, 6) node indices: corners a, b, c counter-clockwise seen from outside,
            then the nodes of edges (a, b), (b, c), (c, a).
        vertex_ids: (B,) sorted indices of the nodes on the boundary.
    """

    triangles: np.ndarray
    vertex_ids: np.ndarray


class QuadraticTetMesh(_VertexQueries):
    """A validated mesh of 10-node tetrahedra in its rest configuration.

    Args:
        vertices: (N, 3) rest positions of all nodes (corners and edge nodes), in metres.
        tets: (M, 10) node indices in VTK tetra10 order. Negatively oriented elements are
            reoriented; ``reoriented_count`` says how many.
        name: used in error messages.

    Raises:
        MeshError: what :class:`~wcut.mesh.TetMesh` rejects for the corners, an edge node
            shared inconsistently, or a curved element whose Jacobian is not positive at a
            Gauss point or node. The message names the element.
    """

    order = 2

    def __init__(self, vertices, tets, *, name: str = "mesh"):
        self.name = name
        vertices = np.asarray(vertices, dtype=np.float64)
        tets = np.asarray(tets)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise MeshError(f"{name}: vertices must have shape (N, 3), got {vertices.shape}")
        if tets.ndim != 2 or tets.shape[1] != 10:
            raise MeshError(f"{name}: quadratic tetrahedra must have shape (M, 10), got {tets.shape}")
        if len(tets) and not np.issubdtype(tets.dtype, np.integer):
            raise MeshError(f"{name}: tetrahedron indices must be integers, got {tets.dtype}")
        tets = tets.astype(np.int64)
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if len(bad):
            raise MeshError(f"{name}: node {bad[0]} has a non-finite coordinate {vertices[bad[0]].tolist()}")
        out = np.flatnonzero(((tets < 0) | (tets >= len(vertices))).any(axis=1))
        if len(out):
            raise MeshError(f"{name}: element {out[0]} has a node index out of range {tets[out[0]].tolist()} "
                            f"(node count {len(vertices)})")
        corner_ids = np.unique(tets[:, :4])
        local = np.searchsorted(corner_ids, tets[:, :4])
        corners = TetMesh(vertices[corner_ids] if len(corner_ids) else np.zeros((0, 3)), local, name=name)
        flipped = np.flatnonzero((corners.tets != local).any(axis=1))
        tets[flipped] = tets[flipped][:, _REORIENT]
        self.reoriented_count = len(flipped)
        self._check_edge_nodes(tets, corner_ids, len(vertices))
        self.vertices = vertices
        self.tets = tets
        self._check_jacobians()
        self.corner_ids = corner_ids
        #: file index of each node when :meth:`load` dropped some, else None
        self.source_vertex_ids: np.ndarray | None = None
        self._boundary: QuadraticBoundary | None = None

    def _check_edge_nodes(self, tets: np.ndarray, corner_ids: np.ndarray, count: int) -> None:
        edges = np.sort(tets[:, p2.EDGES], axis=2).reshape(-1, 2)
        nodes = tets[:, 4:].reshape(-1)
        both = np.intersect1d(nodes, corner_ids)
        if len(both):
            raise MeshError(f"{self.name}: node {both[0]} is both a corner and an edge node")
        used = np.zeros(count, dtype=bool)
        used[tets.ravel()] = True
        if not used.all():
            unused = np.flatnonzero(~used)
            raise MeshError(f"{self.name}: node {unused[0]} is not used by any element ({len(unused)} unused)")
        pairs = np.unique(np.column_stack([edges, nodes]), axis=0)
        _, edge_counts = np.unique(pairs[:, :2], axis=0, return_counts=True)
        if (edge_counts > 1).any() or len(np.unique(pairs[:, 2])) != len(pairs):
            k = np.flatnonzero(np.unique(pairs[:, 2], return_counts=True)[1] > 1)
            what = f"node {np.unique(pairs[:, 2])[k[0]]} lies on two edges" if len(k) else \
                "an edge has two different edge nodes"
            raise MeshError(f"{self.name}: inconsistent edge nodes: {what}")

    def _check_jacobians(self) -> None:
        folded, worst = folded_elements(self.vertices, self.tets)
        bad = np.flatnonzero(folded)
        if len(bad):
            e = bad[0]
            raise MeshError(f"{self.name}: curved element {e} {self.tets[e].tolist()} folds: det J is "
                            f"{worst[e]:.3g} at a Gauss point or node ({len(bad)} such elements)")

    @classmethod
    def trusted(cls, vertices: np.ndarray, tets: np.ndarray, corner_ids: np.ndarray, *,
                name: str = "mesh") -> "QuadraticTetMesh":
        """A mesh from arrays already known to be valid, without validation."""
        mesh = cls.__new__(cls)
        mesh.name, mesh.reoriented_count, mesh._boundary, mesh.source_vertex_ids = name, 0, None, None
        mesh.vertices, mesh.tets, mesh.corner_ids = vertices, tets, corner_ids
        return mesh

    def volumes(self) -> np.ndarray:
        """Exact rest volumes (m^3) of the curved elements."""
        return p2.volumes(self.vertices, self.tets)

    def linear(self) -> TetMesh:
        """The linear mesh of the corners (vertex ``i`` is node ``corner_ids[i]``)."""
        local = np.searchsorted(self.corner_ids, self.tets[:, :4])
        return TetMesh.trusted(self.vertices[self.corner_ids], local, name=self.name)

    def mean_edge_length(self) -> float:
        """Mean rest length (m) of the straight corner edges."""
        return self.linear().mean_edge_length()

    def boundary(self) -> QuadraticBoundary:
        """The boundary faces as outward oriented 6-node triangles."""
        if self._boundary is None:
            faces = self.tets[:, TET_FACES].reshape(-1, 3)
            _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
            on_boundary = counts[inverse.ravel()] == 1
            six = np.concatenate([faces, self.tets[:, _FACE_EDGE_NODES].reshape(-1, 3)], axis=1)[on_boundary]
            self._boundary = QuadraticBoundary(six, np.unique(six))
        return self._boundary

    def surface_tessellation(self, level: int = 2) -> "SurfaceTessellation":
        """The curved boundary as flat triangles: each 6-node face split into ``4**level``
        (see :class:`SurfaceTessellation`)."""
        return SurfaceTessellation.of_quadratic(self.boundary().triangles, self.vertex_count, level)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "QuadraticTetMesh":
        """Read ``tetra10`` cells from any format :func:`~wcut.mesh.read_meshio` reads (other
        cells are ignored; nodes only they use are dropped, nodes no cell uses too, with a
        :class:`~wcut.errors.MeshNotice`)."""
        path = os.fspath(path)
        data = read_meshio(path)
        blocks = [np.asarray(b.data, dtype=np.int64) for b in data.cells if b.type == "tetra10"]
        name = os.path.basename(path)
        if not blocks:
            kinds = sorted({b.type for b in data.cells})
            raise MeshError(f"{name}: no quadratic tetrahedra (tetra10) in the file (cell types: "
                            f"{', '.join(kinds) or 'none'})")
        tets, points = np.concatenate(blocks), np.asarray(data.points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise MeshError(f"{name}: points must be three-dimensional, got shape {points.shape}")
        if tets.min() < 0 or tets.max() >= len(points):
            raise MeshError(f"{name}: element index out of range (node count {len(points)})")
        used = np.unique(tets)
        notice_unused_vertices(name, data)
        remap = np.full(len(points), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        mesh = cls(points[used], remap[tets], name=name)
        mesh.source_vertex_ids = used if len(used) < len(points) else None
        return mesh

    def save(self, path: str | os.PathLike) -> None:
        """Write the mesh (``tetra10`` cells) with meshio, atomically."""
        import meshio

        from .io import atomic_path

        check_mesh_format(path)

        with atomic_path(path) as tmp:
            meshio.write(tmp, meshio.Mesh(self.vertices, [("tetra10", self.tets)]))


@dataclass(frozen=True)
class SurfaceTessellation:
    """A flat-triangle rendering of a mesh's boundary whose points are fixed linear
    combinations of the mesh's nodes: ``points = weights @ q`` for node positions ``q``.

    Attributes:
        weights: (P, N) sparse matrix of shape-function values (rows sum to 1).
        triangles: (T, 3) indices into the points, outward oriented.
    """

    weights: sp.csr_matrix
    triangles: np.ndarray

    def points(self, q: np.ndarray) -> np.ndarray:
        """Rendered points (P, 3) for node positions ``q`` (N, 3); also works for any nodal
        field (N,) or (N, k), e.g. a stress to colour by."""
        return self.weights @ q

    @staticmethod
    def of_linear(mesh: TetMesh) -> "SurfaceTessellation":
        """A linear mesh's boundary triangles, unchanged (the weights select the vertices)."""
        b = mesh.boundary()
        rows = np.arange(len(b.vertex_ids))
        weights = sp.csr_matrix((np.ones(len(rows)), (rows, b.vertex_ids)), shape=(len(rows), mesh.vertex_count))
        return SurfaceTessellation(weights, b.local_triangles)

    @staticmethod
    def of_quadratic(faces: np.ndarray, node_count: int, level: int) -> "SurfaceTessellation":
        """6-node triangles ``faces`` (F, 6), each split into ``4**level`` flat triangles at
        points of the quadratic interpolation. Points on a shared edge are shared, so the
        rendered surface has no cracks."""
        if not isinstance(level, (int, np.integer)) or not 0 <= level <= 5:
            raise MeshError(f"subdivision level must be an integer in 0..5, got {level!r}")
        n = 2 ** int(level)
        ij = [(i, j) for i in range(n + 1) for j in range(n + 1 - i)]
        index = {p: k for k, p in enumerate(ij)}
        lam = np.array([[1.0 - (i + j) / n, i / n, j / n] for i, j in ij])  # weights of corners a, b, c
        la, lb, lc = lam.T
        # quadratic triangle: corners L(2L-1), edge nodes 4 L L'
        values = np.stack([la * (2 * la - 1), lb * (2 * lb - 1), lc * (2 * lc - 1),
                           4 * la * lb, 4 * lb * lc, 4 * lc * la], axis=1)
        local_tris = []
        for i in range(n):
            for j in range(n - i):
                local_tris.append((index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]))
                if i + j < n - 1:
                    local_tris.append((index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]))
        local_tris = np.array(local_tris)
        # A point is identified by its nonzero weights on nodes: equal keys are the same point.
        keys, rows, cols, vals, tris = {}, [], [], [], []
        for face in faces:
            ids = np.empty(len(ij), dtype=np.int64)
            for k in range(len(ij)):
                nz = np.flatnonzero(np.abs(values[k]) > 1e-14)
                key = tuple(sorted(zip(face[nz].tolist(), np.round(values[k, nz], 12).tolist())))
                found = keys.get(key)
                if found is None:
                    found = keys[key] = len(keys)
                    rows.extend([found] * len(nz))
                    cols.extend(face[nz].tolist())
                    vals.extend(values[k, nz].tolist())
                ids[k] = found
            tris.append(ids[local_tris])
        weights = sp.csr_matrix((vals, (rows, cols)), shape=(len(keys), node_count))
        return SurfaceTessellation(weights, np.concatenate(tris) if tris else np.zeros((0, 3), np.int64))


def _boundary_edge_mask(linear: TetMesh, edges: np.ndarray) -> np.ndarray:
    """Which of the sorted corner pairs ``edges`` (E, 2) are edges of boundary triangles."""
    tris = linear.boundary().triangles
    boundary = np.unique(np.sort(tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1), axis=0)
    key = lambda e: e[:, 0] * (linear.vertex_count + 1) + e[:, 1]  # noqa: E731
    return np.isin(key(edges), key(boundary))


def project_to_implicit(points: np.ndarray, function: Callable[[np.ndarray], np.ndarray],
                        iterations: int = 20, step: float = 1e-7) -> np.ndarray:
    """Points (P, 3) moved onto the zero level set of ``function`` (vectorised: (P, 3) -> (P,))
    by Newton steps along its gradient (central differences, ``step`` in metres)."""
    x = np.array(points, dtype=np.float64)
    for _ in range(iterations):
        f = function(x)
        grad = np.stack([(function(x + step * e) - function(x - step * e)) / (2 * step) for e in np.eye(3)], axis=1)
        norm_sq = np.einsum("pi,pi->p", grad, grad)
        move = np.where(norm_sq > 0, f / np.maximum(norm_sq, 1e-300), 0.0)[:, None] * grad
        x -= move
        if np.abs(move).max(initial=0.0) < 1e-12:
            break
    return x


def project_to_triangles(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The closest points (P, 3) on a triangle surface (vertices (V, 3), triangles (T, 3))."""
    from .topology.mesh import _closest_on_triangles

    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    out = np.empty((len(points), 3))
    for k, p in enumerate(np.asarray(points, dtype=np.float64)):
        bary, distance = _closest_on_triangles(p, a, b, c)
        t = int(np.argmin(distance))
        out[k] = bary[t] @ np.stack([a[t], b[t], c[t]])
    return out


def to_quadratic(mesh: TetMesh, surface=None, *, max_halvings: int = 20) -> QuadraticTetMesh:
    """The quadratic mesh of a linear one (thesis 6.1.1): nodes 0..N-1 are the linear mesh's
    vertices, then one node per edge.

    Args:
        mesh: the linear mesh (rest configuration, metres).
        surface: the smooth surface the boundary should follow: ``None`` (straight edges,
            edge nodes at the midpoints), a callable ``f(points (P, 3)) -> (P,)`` whose zero
            level set is the surface (e.g. a signed distance), or a triangle surface
            ``(vertices (V, 3), triangles (T, 3))`` finer than the mesh's boundary.
        max_halvings: how many times the curving of a folding element may be halved before
            it is made straight.

    Boundary edge nodes move to the surface (Newton projection on the level set, or the
    closest point of the triangle surface). Interior edge nodes follow by the harmonic
    extension of that motion (a graph Laplacian over edge nodes sharing an element), so
    elements near the boundary bend with it instead of folding. If an element still has
    ``det J <= 0`` at a Gauss point or node, the motion of its edge nodes is halved, up to
    ``max_halvings`` times, then removed: a straight element is valid whenever the linear one
    is, so the result always is.
    """
    edges, element_edges = p2.midpoint_edges(mesh.tets)
    n = mesh.vertex_count
    midpoints = 0.5 * (mesh.vertices[edges[:, 0]] + mesh.vertices[edges[:, 1]])
    tets = np.concatenate([mesh.tets, n + element_edges], axis=1)
    motion = np.zeros_like(midpoints)
    if surface is not None:
        on_boundary = _boundary_edge_mask(mesh, edges)
        targets = midpoints[on_boundary]
        if callable(surface):
            targets = project_to_implicit(targets, surface)
        else:
            vertices, triangles = surface
            targets = project_to_triangles(targets, np.asarray(vertices, float), np.asarray(triangles, np.int64))
        if not np.isfinite(targets).all():
            raise MeshError(f"{mesh.name}: projecting edge nodes onto the surface gave non-finite points")
        motion[on_boundary] = targets - midpoints[on_boundary]
        motion = _harmonic_extension(element_edges, motion, on_boundary)
    for _ in range(max_halvings + 1):
        points = np.concatenate([mesh.vertices, midpoints + motion])
        at_gauss, at_nodes = p2.jacobian_determinants(points, tets)
        scale = 6.0 * mesh.volumes()
        folding = np.flatnonzero((at_gauss.min(axis=1) <= 1e-3 * scale) | (at_nodes.min(axis=1) <= 1e-3 * scale))
        if not len(folding):
            break
        motion[np.unique(element_edges[folding])] *= 0.5
    else:
        motion[np.unique(element_edges[folding])] = 0.0
        points = np.concatenate([mesh.vertices, midpoints + motion])
    return QuadraticTetMesh(points, tets, name=mesh.name)


def load_mesh(path: str | os.PathLike, order: int = 1):
    """A mesh file (anything meshio reads) as elements of ``order``: a
    :class:`~wcut.mesh.TetMesh` for 1; for 2 a :class:`QuadraticTetMesh`, the file's
    ``tetra10`` cells as they are, or its linear cells made quadratic with straight edges
    (:func:`to_quadratic`)."""
    if order == 2 and _has_cells(path, "tetra10"):
        return QuadraticTetMesh.load(path)
    mesh = TetMesh.load(path)
    return to_quadratic(mesh) if order == 2 else mesh


def _has_cells(path, kind: str) -> bool:
    """Whether a mesh file holds cells of a meshio type (False when it cannot be read: the
    loader that follows reports why)."""
    try:
        return any(block.type == kind for block in read_meshio(path).cells)
    except MeshError:
        return False


def _harmonic_extension(element_edges: np.ndarray, motion: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """``motion`` (E, 3) of the fixed edge nodes extended to the others: each free node's
    motion is the mean of its neighbours' (nodes of a common element), solved exactly."""
    count = len(motion)
    a, b = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    off = a != b
    rows, cols = element_edges[:, a[off]].ravel(), element_edges[:, b[off]].ravel()
    adjacency = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(count, count))
    adjacency.data[:] = 1.0  # duplicates summed: a neighbour counts once
    laplacian = sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency
    free = np.flatnonzero(~fixed)
    if not len(free) or not fixed.any():
        return motion
    out = motion.copy()
    from scipy.sparse.linalg import splu

    solve = splu(laplacian[free][:, free].tocsc())
    rhs = -(laplacian[free][:, np.flatnonzero(fixed)] @ motion[fixed])
    out[free] = solve.solve(rhs)
    return out
