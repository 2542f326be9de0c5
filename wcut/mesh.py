"""Tetrahedral meshes: validation, I/O through meshio, generators and boundary extraction.

A :class:`TetMesh` is the host-side (numpy, float64) description of a volumetric object:
rest vertex positions in metres and tetrahedra as four vertex indices, every one positively
oriented (``det[v1-v0, v2-v0, v3-v0] > 0``). It is what the topology manager edits and what
:class:`wcut.model.Model` is built from. Construction validates the input (thesis 3.2: the
elements must form a conforming discretization), so every later stage can rely on:

- finite coordinates, indices in range, every vertex referenced by some tetrahedron;
- no degenerate element (volume above a relative tolerance);
- positive orientation (negatively oriented input elements are reoriented);
- manifold faces: a triangle is shared by at most two tetrahedra.
"""

from __future__ import annotations

import contextlib
import io
import os
from dataclasses import dataclass

import numpy as np

from .errors import MeshError

#: Faces of a positively oriented tetrahedron (v0, v1, v2, v3), each ordered so its normal
#: (right-hand rule) points out of the tetrahedron. Face k is opposite vertex k.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)

#: Relative volume below which an element counts as degenerate: |V| < DEGENERATE_TOL * l^3,
#: with l the element's longest edge (a regular tetrahedron has 0.118). The simulation runs in
#: float32: flatter elements are not even stress-free at rest once their corners are rounded.
DEGENERATE_TOL = 1e-6


def tet_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes (m^3) of tetrahedra: det[v1-v0, v2-v0, v3-v0] / 6."""
    v0 = vertices[tets[:, 0]]
    d1 = vertices[tets[:, 1]] - v0
    d2 = vertices[tets[:, 2]] - v0
    d3 = vertices[tets[:, 3]] - v0
    return np.einsum("ij,ij->i", np.cross(d1, d2), d3) / 6.0


def edge_matrices(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Edge matrices ``[x0 - x3 | x1 - x3 | x2 - x3]`` (M, 3, 3) of tetrahedra, in metres.

    Of rest positions this is ``Dm``: ``Dm^{-1}`` maps positions to the barycentric coordinates
    of nodes 0..2 (thesis eq. 3.16), so its rows are the shape-function gradients. Of current
    positions it is ``Ds``, and ``F = Ds Dm^{-1}`` (eq. 3.20).
    """
    X = vertices[tets]
    return np.stack([X[:, 0] - X[:, 3], X[:, 1] - X[:, 3], X[:, 2] - X[:, 3]], axis=2)


def _longest_edges(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    lengths = [np.linalg.norm(vertices[tets[:, a]] - vertices[tets[:, b]], axis=1) for a, b in pairs]
    return np.max(lengths, axis=0)


def _face_keys(faces: np.ndarray) -> np.ndarray:
    """Orientation-independent keys of triangles (sorted vertex triples), shape (F, 3)."""
    return np.sort(faces, axis=1)


@dataclass(frozen=True)
class BoundarySurface:
    """The boundary of a tetrahedral mesh as a triangle surface.

    Attributes:
        triangles: (F, 3) vertex indices into the volume mesh, counter-clockwise seen from
            outside (outward normals).
        vertex_ids: (B,) sorted indices of the volume vertices that lie on the boundary.
        local_triangles: (F, 3) the same triangles indexed into ``vertex_ids``.
    """

    triangles: np.ndarray
    vertex_ids: np.ndarray
    local_triangles: np.ndarray


class _VertexQueries:
    """Queries shared by linear and quadratic meshes (``vertices`` (N, 3), ``tets`` (M, k),
    ``source_vertex_ids``)."""

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def tet_count(self) -> int:
        return len(self.tets)

    def vertex_from_source(self, index: int) -> int:
        """This mesh's index of vertex ``index`` of the loaded file (see ``source_vertex_ids``);
        -1 if the file's vertex is not part of the mesh or out of range."""
        if self.source_vertex_ids is None:
            return index if 0 <= index < self.vertex_count else -1
        position = int(np.searchsorted(self.source_vertex_ids, index))
        found = position < len(self.source_vertex_ids) and self.source_vertex_ids[position] == index
        return position if found else -1

    def vertices_in_box(self, lower, upper) -> np.ndarray:
        """Indices of vertices inside the closed axis-aligned box [lower, upper] (metres)."""
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        inside = np.all((self.vertices >= lower) & (self.vertices <= upper), axis=1)
        return np.flatnonzero(inside)


def read_meshio(path: str | os.PathLike):
    """A file read by meshio, its messages silenced; MeshError when missing or unreadable."""
    import meshio

    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(f"{path}: no such file")
    try:
        # meshio prints its own messages and may call sys.exit() on a malformed file
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            return meshio.read(path)
    except (Exception, SystemExit) as exc:  # ReadError, KeyError, ValueError, SystemExit, ...
        detail = str(exc) if not isinstance(exc, SystemExit) else "malformed file"
        raise MeshError(f"{path}: cannot read mesh: {detail}") from None


class TetMesh(_VertexQueries):
    """A validated tetrahedral mesh in its rest configuration.

    Args:
        vertices: (N, 3) rest positions in metres.
        tets: (M, 4) vertex indices of the tetrahedra. Negatively oriented elements are
            reoriented (two vertices swapped); ``reoriented_count`` says how many.
        name: used in error messages (a file name, a generator call).

    Raises:
        MeshError: NaN or infinite coordinates, bad shapes or indices, unreferenced vertices,
            a degenerate element, or a face shared by more than two elements. The message names
            the offending vertex, element or face.
    """

    def __init__(self, vertices, tets, *, name: str = "mesh"):
        self.name = name
        vertices = np.asarray(vertices, dtype=np.float64)
        tets = np.asarray(tets)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise MeshError(f"{name}: vertices must have shape (N, 3), got {vertices.shape}")
        if tets.ndim != 2 or tets.shape[1] != 4:
            raise MeshError(f"{name}: tetrahedra must have shape (M, 4), got {tets.shape}")
        if len(tets) == 0:
            raise MeshError(f"{name}: the mesh has no tetrahedra")
        if not np.issubdtype(tets.dtype, np.integer):
            raise MeshError(f"{name}: tetrahedron indices must be integers, got {tets.dtype}")
        tets = tets.astype(np.int64)
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if len(bad):
            raise MeshError(f"{name}: vertex {bad[0]} has a non-finite coordinate {vertices[bad[0]].tolist()}"
                            f" ({len(bad)} such vertices)")
        out = np.flatnonzero(((tets < 0) | (tets >= len(vertices))).any(axis=1))
        if len(out):
            raise MeshError(f"{name}: element {out[0]} has a vertex index out of range "
                            f"{tets[out[0]].tolist()} (vertex count {len(vertices)})")
        repeated = np.flatnonzero((np.sort(tets, axis=1)[:, 1:] == np.sort(tets, axis=1)[:, :-1]).any(axis=1))
        if len(repeated):
            raise MeshError(f"{name}: element {repeated[0]} repeats a vertex {tets[repeated[0]].tolist()}")
        used = np.zeros(len(vertices), dtype=bool)
        used[tets.ravel()] = True
        unused = np.flatnonzero(~used)
        if len(unused):
            raise MeshError(f"{name}: vertex {unused[0]} is not used by any element "
                            f"({len(unused)} unreferenced vertices)")
        volumes = tet_volumes(vertices, tets)
        degenerate = np.flatnonzero(np.abs(volumes) <= DEGENERATE_TOL * _longest_edges(vertices, tets) ** 3)
        if len(degenerate):
            e = degenerate[0]
            raise MeshError(f"{name}: element {e} {tets[e].tolist()} is degenerate (volume {volumes[e]:.3g} m^3)"
                            f" ({len(degenerate)} degenerate elements)")
        negative = volumes < 0
        self.reoriented_count = int(negative.sum())
        tets[negative] = tets[negative][:, [0, 2, 1, 3]]
        self._check_manifold(tets)
        self.vertices = vertices
        self.tets = tets
        #: file index of each vertex when :meth:`load` dropped some, else None
        self.source_vertex_ids: np.ndarray | None = None
        self._boundary: BoundarySurface | None = None

    @classmethod
    def trusted(cls, vertices: np.ndarray, tets: np.ndarray, *, name: str = "mesh") -> "TetMesh":
        """A mesh from arrays already known to be valid (the topology manager's output),
        without the O(M log M) validation: a cut must cost what it touches, not the mesh size."""
        mesh = cls.__new__(cls)
        mesh.name = name
        mesh.vertices = np.asarray(vertices, dtype=np.float64)
        mesh.tets = np.asarray(tets, dtype=np.int64)
        mesh.reoriented_count = 0
        mesh.source_vertex_ids = None
        mesh._boundary = None
        return mesh

    def _check_manifold(self, tets: np.ndarray) -> None:
        """Every face in at most two elements, on opposite sides (so no element is repeated
        and no two elements overlap across a shared face)."""
        faces = tets[:, TET_FACES].reshape(-1, 3)  # outward oriented, tets positively oriented
        unique, inverse, counts = np.unique(_face_keys(faces), axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.ravel()
        over = np.flatnonzero(counts > 2)
        if len(over):
            owners = np.flatnonzero(inverse == over[0]) // 4
            raise MeshError(f"{self.name}: non-manifold face {unique[over[0]].tolist()} is shared by "
                            f"{counts[over[0]]} elements {owners.tolist()}")
        a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
        parity = ((a > b).astype(int) + (a > c) + (b > c)) % 2  # orientation relative to the sorted key
        shared = np.flatnonzero(counts[inverse] == 2)
        order = shared[np.argsort(inverse[shared], kind="stable")]
        first, second = order[0::2], order[1::2]
        same = np.flatnonzero(parity[first] == parity[second])
        if len(same):
            i, j = first[same[0]] // 4, second[same[0]] // 4
            what = "repeats" if np.array_equal(np.sort(tets[i]), np.sort(tets[j])) else "overlaps"
            raise MeshError(f"{self.name}: element {j} {what} element {i} (both on the same side of face "
                            f"{unique[inverse[first[same[0]]]].tolist()})")

    def volumes(self) -> np.ndarray:
        """Rest volumes (m^3) of the elements, all positive."""
        return tet_volumes(self.vertices, self.tets)

    def boundary(self) -> BoundarySurface:
        """The boundary triangles (faces owned by exactly one element), outward oriented."""
        if self._boundary is None:
            faces = self.tets[:, TET_FACES].reshape(-1, 3)
            _, inverse, counts = np.unique(_face_keys(faces), axis=0, return_inverse=True, return_counts=True)
            triangles = faces[counts[inverse.ravel()] == 1]
            vertex_ids, local = np.unique(triangles, return_inverse=True)
            self._boundary = BoundarySurface(triangles, vertex_ids, local.reshape(-1, 3))
        return self._boundary

    def edges(self) -> np.ndarray:
        """(E, 2) unique undirected edges, each as (low, high) vertex indices."""
        pairs = self.tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]].reshape(-1, 2)
        return np.unique(np.sort(pairs, axis=1), axis=0)

    def mean_edge_length(self) -> float:
        """Mean rest length (m) of the unique edges."""
        e = self.edges()
        return float(np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1).mean())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "TetMesh":
        """Read a tetrahedral mesh from any format meshio reads (.msh, .vtu, .vtk, .mesh, ...).

        Every ``tetra`` cell block is used; other cell types (surface triangles, lines) are
        ignored. Vertices only they reference are dropped, and then ``source_vertex_ids[i]`` is
        the file's index of vertex ``i`` (``None`` when the numbering is the file's). A vertex
        no cell uses is an error.
        """
        path = os.fspath(path)
        data = read_meshio(path)
        blocks = [block.data for block in data.cells if block.type == "tetra"]
        if not blocks:
            kinds = sorted({block.type for block in data.cells})
            raise MeshError(f"{path}: no tetrahedra in the file (cell types: {', '.join(kinds) or 'none'})")
        tets = np.concatenate(blocks).astype(np.int64)
        points = np.asarray(data.points, dtype=np.float64)
        if points.ndim == 2 and points.shape[1] == 2:
            raise MeshError(f"{path}: the mesh is two-dimensional")
        name = os.path.basename(path)
        if tets.min() < 0 or tets.max() >= len(points):
            raise MeshError(f"{name}: element index out of range (vertex count {len(points)})")
        in_any_cell = np.zeros(len(points), dtype=bool)
        for block in data.cells:
            ids = np.asarray(block.data, dtype=np.int64).ravel()
            in_any_cell[ids[(ids >= 0) & (ids < len(points))]] = True
        unused = np.flatnonzero(~in_any_cell)
        if len(unused):
            raise MeshError(f"{name}: vertex {unused[0]} is not used by any cell ({len(unused)} unreferenced vertices)")
        used = np.unique(tets)
        source_ids = None
        if len(used) < len(points):  # vertices of surface or line cells only: not part of the solid
            remap = np.full(len(points), -1, dtype=np.int64)
            remap[used] = np.arange(len(used))
            points, tets, source_ids = points[used], remap[tets], used
        mesh = cls(points, tets, name=name)
        mesh.source_vertex_ids = source_ids
        return mesh

    def save(self, path: str | os.PathLike) -> None:
        """Write the mesh with meshio (format from the extension), atomically."""
        import meshio

        from .io import atomic_path

        with atomic_path(path) as tmp:
            meshio.write(tmp, meshio.Mesh(self.vertices, [("tetra", self.tets)]))


def beam(nx: int, ny: int, nz: int, size=(1.0, 1.0, 1.0), *, origin=(0.0, 0.0, 0.0),
         tets_per_hex: int = 5) -> TetMesh:
    """A box of ``nx * ny * nz`` hexahedra, each split into tetrahedra.

    Args:
        nx, ny, nz: hexahedra along x, y and z.
        size: box extent (m) along x, y and z.
        origin: the box's lowest corner (m).
        tets_per_hex: 5 (a central regular-shaped tetrahedron and four corners, with the split
            mirrored on alternate cells so faces conform) or 6 (the Kuhn split along the main
            diagonal, the same in every cell).

    Returns:
        A mesh of ``(nx+1)(ny+1)(nz+1)`` vertices and ``tets_per_hex * nx * ny * nz`` tetrahedra.
        Vertex (i, j, k) has index ``(i * (ny + 1) + j) * (nz + 1) + k``.
    """
    if min(nx, ny, nz) < 1:
        raise MeshError(f"beam: cell counts must be at least 1, got ({nx}, {ny}, {nz})")
    if tets_per_hex not in (5, 6):
        raise MeshError(f"beam: tets_per_hex must be 5 or 6, got {tets_per_hex}")
    size = np.asarray(size, dtype=np.float64)
    if size.shape != (3,) or not np.all(size > 0):
        raise MeshError(f"beam: size must be three positive lengths, got {size.tolist()}")
    axes = [np.linspace(0.0, s, n + 1) for s, n in zip(size, (nx, ny, nz))]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3) + np.asarray(origin, float)

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()

    def corner(a, b, c):
        return ((i + a) * (ny + 1) + (j + b)) * (nz + 1) + (k + c)

    # corners[:, 4a + 2b + c] is the corner at offset (a, b, c)
    corners = np.stack([corner(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)], axis=1)
    if tets_per_hex == 5:
        even = np.array([[0, 4, 2, 1], [6, 2, 4, 7], [5, 1, 7, 4], [3, 7, 1, 2], [1, 2, 4, 7]])
        odd = np.array([[4, 0, 5, 6], [2, 6, 3, 0], [7, 5, 6, 3], [1, 3, 5, 0], [0, 3, 6, 5]])
        parity = ((i + j + k) % 2 == 0)[:, None, None]
        local = np.where(parity, even[None], odd[None])
        tets = np.take_along_axis(corners[:, None, :], local, axis=2)
    else:
        # Kuhn split: six tetrahedra around the diagonal from corner 0 to corner 7.
        paths = np.array([[0, 4, 6, 7], [0, 4, 5, 7], [0, 2, 6, 7], [0, 2, 3, 7], [0, 1, 5, 7], [0, 1, 3, 7]])
        tets = corners[:, paths]
    return TetMesh(grid, tets.reshape(-1, 4), name=f"beam({nx}, {ny}, {nz})")


def dihedral_angles(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(M, 6) interior dihedral angles (degrees) of tetrahedra at their six edges."""
    X = vertices[tets]
    normals = np.stack([np.cross(X[:, f[1]] - X[:, f[0]], X[:, f[2]] - X[:, f[0]]) for f in TET_FACES], axis=1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    # faces i and j meet at the edge of the two vertices that are neither i nor j
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    cos = np.stack([-np.einsum("mk,mk->m", normals[:, i], normals[:, j]) for i, j in pairs], axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
